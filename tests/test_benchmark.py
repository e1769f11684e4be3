"""The benchmark harness's output file (no timing here: ``make bench`` runs the rows).

An ``--only`` run must keep the other benchmarks' rows of the earlier
docs/performance.md, replace its own, say where the kept rows come from, and
leave no hand-written section behind.
"""

import importlib
import pathlib
import sys

STUDIES = pathlib.Path(__file__).resolve().parents[1] / "studies"


def _benchmark():
    if str(STUDIES) not in sys.path:
        sys.path.insert(0, str(STUDIES))
    return importlib.import_module("benchmark")


def _table_rows(text):
    return [t for t in text.splitlines() if t.startswith("| ") and not t.startswith("| bench")]


def test_only_run_carries_other_rows_and_replaces_its_own(tmp_path):
    b = _benchmark()
    out = tmp_path / "performance.md"
    facts = {"date (UTC)": "2000-01-01 00:00"}
    full = [b.Row("project", "580 points, loop", 0.1, 1.0, "baseline"),
            b.Row("posterior sampling", "old sampler row", 5.0, 1.0, "old"),
            b.Row("simultaneous fit", "580 pts", 0.2, 3.0, "")]
    b.write_markdown(out, full, facts, [])
    out.write_text(out.read_text() + "\n## Measured by hand\n\n| setting | wall |\n|---|---|\n"
                   "| measured row | 1 s |\n")
    new = [b.Row("posterior sampling", "new sampler row", 2.0, 2.5, "new"),
           b.Row("posterior sampling", "NUTS skipped", float("nan"), float("nan"), "skipped")]
    b.write_markdown(out, new, {"date (UTC)": "2000-01-02 00:00"}, ["--only", "sampler"],
                     carried=True)
    text = out.read_text()
    rows = _table_rows(text)
    assert [r.split(" | ")[1] for r in rows] == ["580 points, loop", "new sampler row",
                                                  "NUTS skipped", "580 pts"]
    assert "| - | - |" in rows[2]
    assert "Measured by hand" not in text and "measured row" not in text
    assert f"{b.CARRIED_PREFIX} the run of 2000-01-01 00:00" in text
    # a second --only run keeps the first provenance (the carried rows did not change)
    b.write_markdown(out, new, {"date (UTC)": "2000-01-03 00:00"}, ["--only", "sampler"],
                     carried=True)
    text = out.read_text()
    assert f"{b.CARRIED_PREFIX} the run of 2000-01-01 00:00" in text
    assert len(_table_rows(text)) == 4


def test_full_run_carries_nothing(tmp_path):
    b = _benchmark()
    out = tmp_path / "performance.md"
    b.write_markdown(out, [b.Row("project", "old", 0.1, 1.0, "")], {}, [])
    b.write_markdown(out, [b.Row("sampler", "new", 1.0, 1.0, "")], {}, [])
    text = out.read_text()
    assert [r.split(" | ")[1] for r in _table_rows(text)] == ["new"]
    assert b.CARRIED_PREFIX not in text
