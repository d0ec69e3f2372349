"""A small HTML report: sections of text, tables and PNG figures in one ``index.html``.

Plain HTML with inline CSS and relative image links, so a report folder can be zipped, mailed
or served as it is.  All text is escaped.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8em 0; } td, th { border: 1px solid #bbb;
padding: 4px 9px; text-align: right; } th { background: #eee; } td:first-child,
th:first-child { text-align: left; } img { max-width: 100%; border: 1px solid #ddd;
margin: 0.5em 0; } .note { color: #555; font-size: 0.92em; } pre { background: #f6f6f6;
padding: 0.6em; overflow-x: auto; }
"""


@dataclass
class Report:
    """An HTML report being assembled; :meth:`write` saves ``index.html`` in ``folder``."""

    title: str
    folder: Path
    parts: list[str] = field(default_factory=list)

    def heading(self, text: str) -> None:
        """Start a section."""
        self.parts.append(f"<h2>{html.escape(text)}</h2>")

    def text(self, text: str, note: bool = False) -> None:
        """A paragraph (``note`` renders it smaller and grey)."""
        cls = ' class="note"' if note else ""
        self.parts.append(f"<p{cls}>{html.escape(text)}</p>")

    def pre(self, text: str) -> None:
        """Preformatted text (e.g. a printed table)."""
        self.parts.append(f"<pre>{html.escape(text)}</pre>")

    def table(self, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        """A table; floats are shown with two decimals."""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(_cell(c))}</td>" for c in row) + "</tr>"
            for row in rows
        )
        self.parts.append(f"<table><tr>{head}</tr>{body}</table>")

    def figure(self, path: str | Path, caption: str = "") -> None:
        """An image (stored in the report folder or below it) with a caption."""
        p = Path(path)
        try:
            rel = p.resolve().relative_to(self.folder.resolve())
        except ValueError:
            rel = p
        cap = f"<div class='note'>{html.escape(caption)}</div>" if caption else ""
        self.parts.append(
            f"<figure><img src='{html.escape(str(rel))}' alt='{html.escape(caption)}'>{cap}</figure>"
        )

    def write(self) -> Path:
        """Write ``index.html`` and return its path."""
        self.folder.mkdir(parents=True, exist_ok=True)
        doc = (
            "<!DOCTYPE html><html><head><meta charset='utf-8'>"
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1>" + "\n".join(self.parts) + "</body></html>"
        )
        path = self.folder / "index.html"
        path.write_text(doc, encoding="utf-8")
        return path


def _cell(c: Any) -> str:
    if isinstance(c, float):
        return f"{c:.2f}" if abs(c) < 1e6 else f"{c:.3g}"
    return str(c)
