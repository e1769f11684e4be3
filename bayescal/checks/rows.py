"""Naming input rows in a message (shared by the checks)."""

__all__ = ["rows_text"]


def rows_text(rows, limit=10):
    rows = [int(r) for r in rows]
    more = f" and {len(rows) - limit} more" if len(rows) > limit else ""
    return ", ".join(map(str, rows[:limit])) + more
