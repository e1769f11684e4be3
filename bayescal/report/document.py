"""One document structure, rendered to Markdown and to self-contained HTML by one code path.

A :class:`Document` is a title and a list of blocks: headings, paragraphs
(with ``**bold**`` and ``code`` spans marked by backticks), warnings, tables
(with flagged rows), preformatted text and figures. :func:`render` walks the
blocks once and asks a small :class:`_Markdown` or :class:`_Html` writer for
each; the calibration report and the demo index are both built this way.
"""

from __future__ import annotations

import base64
import html
import pathlib
from dataclasses import dataclass, field

from ..errors import InvalidValueError

__all__ = ["Document", "render", "write_document"]


@dataclass
class Document:
    """A report: ``title`` and ``blocks`` (tuples, see the ``add_*`` methods)."""

    title: str
    blocks: list = field(default_factory=list)

    def heading(self, text):
        """A section heading."""
        self.blocks.append(("heading", text))

    def paragraph(self, text):
        """A paragraph; ``**bold**`` and backtick spans are kept in both renderings."""
        self.blocks.append(("paragraph", text))

    def warning(self, text):
        """A highlighted warning paragraph."""
        self.blocks.append(("warning", text))

    def table(self, head, rows, *, flags=None, links=None):
        """A table: ``head`` (list of str), ``rows`` (list of lists of str).

        ``flags`` (bool per row) highlights rows; ``links`` maps a cell text to
        a relative link target.
        """
        self.blocks.append(("table", list(head), [list(r) for r in rows],
                            list(flags or [False] * len(rows)), dict(links or {})))

    def preformatted(self, text):
        """A block of fixed-width text."""
        self.blocks.append(("pre", str(text)))

    def figure(self, caption, path):
        """A figure (a PNG file written beside the document)."""
        self.blocks.append(("figure", caption, pathlib.Path(path)))


def _inline_html(text):
    text = html.escape(text)
    parts = text.split("**")
    text = "".join(f"<b>{p}</b>" if i % 2 else p for i, p in enumerate(parts))
    parts = text.split("`")
    return "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))


class _Markdown:
    def start(self, title):
        return [f"# {title}", ""]

    def heading(self, text):
        return [f"## {text}", ""]

    def paragraph(self, text):
        return [text, ""]

    def warning(self, text):
        return [f"> **Warning.** {text}", ""]

    def table(self, head, rows, flags, links):
        def cell(c):
            return f"[{c}]({links[c]})" if c in links else c
        out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        out += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
        return out + [""]

    def pre(self, text):
        return ["```", text, "```", ""]

    def figure(self, caption, path):
        return [f"### {caption}", "", f"![{caption}]({path.name})", ""]

    def end(self):
        return []


class _Html:
    _STYLE = ("body{font-family:sans-serif;max-width:1150px;margin:auto;padding:1em}"
              "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:3px 8px;"
              "text-align:right}td:first-child{text-align:left}tr.flag{background:#fff3cd}"
              ".warn{background:#fde2e1;border-left:4px solid #c0392b;padding:.5em}"
              "img{max-width:100%}pre{background:#f4f4f4;padding:.5em;overflow-x:auto}")

    def start(self, title):
        t = html.escape(title)
        return ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'>", f"<title>{t}</title>",
                f"<style>{self._STYLE}</style></head><body>", f"<h1>{t}</h1>"]

    def heading(self, text):
        return [f"<h2>{html.escape(text)}</h2>"]

    def paragraph(self, text):
        return [f"<p>{_inline_html(text)}</p>"]

    def warning(self, text):
        return [f"<p class='warn'><b>Warning.</b> {_inline_html(text)}</p>"]

    def table(self, head, rows, flags, links):
        def cell(c):
            if c in links:
                return f"<a href='{html.escape(links[c])}'>{html.escape(c)}</a>"
            return _inline_html(c)
        out = ["<table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head) + "</tr>"]
        for r, flag in zip(rows, flags, strict=True):
            cls = " class='flag'" if flag else ""
            out.append(f"<tr{cls}>" + "".join(f"<td>{cell(c)}</td>" for c in r) + "</tr>")
        return out + ["</table>"]

    def pre(self, text):
        return [f"<pre>{html.escape(text)}</pre>"]

    def figure(self, caption, path):
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return [f"<h3>{html.escape(caption)}</h3>",
                f"<img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"]

    def end(self):
        return ["</body></html>"]


def render(doc, kind):
    """Render ``doc`` as ``"markdown"`` or ``"html"`` (figures embedded); returns str."""
    writers = {"markdown": _Markdown, "html": _Html}
    if kind not in writers:
        raise InvalidValueError(f"kind must be 'markdown' or 'html', got {kind!r}")
    w = writers[kind]()
    lines = w.start(doc.title)
    for block in doc.blocks:
        lines += getattr(w, block[0])(*block[1:])
    return "\n".join(lines + w.end()) + "\n"


def write_document(doc, folder, stem):
    """Write ``STEM.md`` and ``STEM.html`` into ``folder``; returns both paths."""
    folder = pathlib.Path(folder)
    md, ht = folder / f"{stem}.md", folder / f"{stem}.html"
    md.write_text(render(doc, "markdown"), encoding="utf-8")
    ht.write_text(render(doc, "html"), encoding="utf-8")
    return md, ht
