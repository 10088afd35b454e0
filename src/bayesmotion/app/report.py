"""A self-contained HTML report: figures and animations embedded as base64, no external files."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from bayesmotion.data.files import atomic_write_text
from bayesmotion.errors import BayesmotionError

_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
        "img{max-width:100%;border:1px solid #ddd;margin:4px}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;"
        "text-align:right}pre{background:#f6f6f6;padding:8px;overflow-x:auto}")


_MIME = {".gif": "image/gif", ".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg",
         ".svg": "image/svg+xml", ".webp": "image/webp"}


def _img(path: Path, alt: str) -> str:
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise BayesmotionError(f"cannot embed {path.name!r} in the report: the suffix must be "
                               f"one of {sorted(_MIME)}")
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img alt="{html.escape(alt)}" src="data:{mime};base64,{data}">'


def table(rows: list[list], header: list[str]) -> str:
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>"
                   for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def write_report(path: Path, title: str, sections: list[tuple[str, list]], summary: dict):
    """sections: (heading, items); an item is a Path (an image, embedded) or an HTML string,
    inserted as given: escape any text in it (:func:`html.escape`, :func:`table` does)."""
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             f"</title><style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    for heading, items in sections:
        parts.append(f"<h2>{html.escape(heading)}</h2>")
        for it in items:
            parts.append(_img(it, it.stem) if isinstance(it, Path) else it)
    text = json.dumps(summary, indent=1, default=float)
    parts.append("<h2>summary.json</h2><pre>" + html.escape(text)
                 + "</pre></body></html>")
    atomic_write_text(path, "\n".join(parts))
