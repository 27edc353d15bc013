"""A tiny, dependency-free HTML writer for the self-contained report: inline CSS, images as base64 PNG."""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Sequence
from typing import Any

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0;color:#1b1b1b;background:#fafafa}
header{background:#1f4e79;color:#fff;padding:1.2em 2em}header h1{margin:0;font-size:1.5em}
main{padding:1em 2em;max-width:1200px}nav a{margin-right:1em;color:#cfe3f5}
h2{border-bottom:2px solid #1f4e79;padding-bottom:.2em;margin-top:2em}h3{margin-top:1.4em}
table{border-collapse:collapse;margin:.6em 0;font-size:.85em;background:#fff;max-width:100%}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right;vertical-align:top;overflow-wrap:break-word}
th{background:#e8eef5}td.k,th.k{text-align:left}p.cap{font-size:.85em;margin:.8em 0 .2em;max-width:60em}
img{max-width:100%;border:1px solid #ddd;background:#fff;margin:.4em 0}
.warn{color:#a40000}.muted{color:#666;font-size:.85em}pre{background:#f0f0f0;padding:.6em;overflow:auto}
figure{margin:.6em 0}figcaption{font-size:.85em;color:#333}figcaption b,p.cap b{color:#1f4e79}
.tw{overflow-x:auto;max-width:100%}.box{border:2px solid #1f4e79;background:#fff;padding:.4em 1em;margin:1em 0}
.note{border-left:4px solid #e0a000;background:#fff8e1;padding:.4em .8em;margin:.6em 0}
.files a{margin-right:.8em}
@media print{header{background:none;color:#000}nav,.files{display:none}main{max-width:none;padding:0}
.tw{overflow:visible}table{font-size:.7em;width:100%}th,td{padding:.1em .3em}
figure,table,.box{break-inside:avoid}p.cap{break-after:avoid}h2,h3{break-after:avoid}img{max-width:100%}}
"""


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def fmt(value: Any) -> str:
    """A cell: numbers with 4 significant digits, None as an em dash, dicts as ``key: value; …``, lists of
    scalars comma-separated, lists of records counted (never raw JSON)."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        return f"{value:.4g}"
    if isinstance(value, dict):
        text = "; ".join(f"{k}: {fmt(v)}" for k, v in value.items())
        return text if len(text) <= 160 else text[:157] + "…"
    if isinstance(value, list):
        if value and all(isinstance(v, dict) for v in value):
            return f"{len(value)} records"
        text = ", ".join(fmt(v) for v in value)
        return text if len(text) <= 160 else text[:157] + "…"
    return str(value)


def table(rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None, caption: str | None = None) -> str:
    """An HTML table from records; the first column is left-aligned (a key)."""
    if not rows:
        return '<p class="muted">(empty)</p>'
    if columns is None:
        columns = list(dict.fromkeys(k for row in rows for k in row))
    head = "".join(f'<th class="{"k" if i == 0 else ""}">{esc(c)}</th>' for i, c in enumerate(columns))
    body = []
    for row in rows:
        cells = "".join(f'<td class="{"k" if i == 0 else ""}">{esc(fmt(row.get(c)))}</td>'
                        for i, c in enumerate(columns))
        body.append(f"<tr>{cells}</tr>")
    cap = f"<p class='cap'>{_caption(caption)}</p>" if caption else ""  # not <caption>: it widens the table
    return f"{cap}<div class='tw'><table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table></div>"


def kv_table(mapping: dict[str, Any], key: str = "key", value: str = "value") -> str:
    return table([{key: k, value: v} for k, v in mapping.items()], [key, value])


def _caption(text: str) -> str:
    """A caption; a leading ``Table II — …:`` or ``Fig. 4 — …:`` title (up to the first colon) is set in bold."""
    head, sep, rest = text.partition(": ")
    if sep and (head.startswith(("Table ", "Fig. ")) or "—" in head):
        return f"<b>{esc(head)}.</b> {esc(rest)}"
    return esc(text)


def mean_sd(mean: Any, sd: Any, digits: int = 3) -> str | None:
    """``0.820 ± 0.133`` (None when there is no mean)."""
    if not isinstance(mean, (int, float)) or isinstance(mean, bool):
        return None
    if isinstance(sd, (int, float)) and not isinstance(sd, bool) and math.isfinite(sd):
        return f"{mean:.{digits}f} ± {sd:.{digits}f}"
    return f"{mean:.{digits}f}"


def links(paths: Sequence[tuple[str, str]]) -> str:
    """Links to the artifacts on disk (relative to the report), for download; hidden in print."""
    if not paths:
        return ""
    items = "".join(f'<a href="{esc(href)}">{esc(label)}</a>' for href, label in paths)
    return f"<p class='files muted'>Data: {items}</p>"


def image(png: bytes, alt: str, caption: str | None = None) -> str:
    data = base64.b64encode(png).decode("ascii")
    cap = f"<figcaption>{_caption(caption)}</figcaption>" if caption else ""
    return f'<figure><img alt="{esc(alt)}" src="data:image/png;base64,{data}">{cap}</figure>'


def markdown_tables(text: str) -> list[str]:
    """Pipe tables of a Markdown file as HTML tables (other Markdown goes in a <pre>)."""
    out, block = [], []
    for line in [*text.splitlines(), ""]:
        if line.strip().startswith("|"):
            block.append(line.strip())
            continue
        if len(block) >= 2:
            cells = [[c.strip() for c in row.strip("|").split("|")] for row in block]
            header, rows = cells[0], [r for r in cells[1:] if not all(set(c) <= set("-: ") for c in r)]
            out.append(table([dict(zip(header, r, strict=False)) for r in rows], header))
        block = []
    return out


def json_tables(doc: Any, max_rows: int = 60) -> list[str]:
    """Readable tables of a JSON document: a dict of dicts becomes one row per key, scalars a key/value table."""
    if isinstance(doc, list) and doc and all(isinstance(r, dict) for r in doc):
        return [table([_flat(r) for r in doc[:max_rows]])]
    if not isinstance(doc, dict):
        return [f"<p>{esc(fmt(doc))}</p>"]
    scalars = {k: v for k, v in doc.items() if not isinstance(v, (dict, list))}
    nested = {k: v for k, v in doc.items() if isinstance(v, dict)}
    lists = {k: v for k, v in doc.items() if isinstance(v, list)}
    parts = [kv_table(scalars)] if scalars else []
    if nested:
        rows = [{"": k, **_flat(v)} for k, v in list(nested.items())[:max_rows]]
        parts.append(table(rows))
    for k, v in lists.items():
        if v and all(isinstance(r, dict) for r in v):
            parts.append(f"<h4>{esc(k)}</h4>" + table([_flat(r) for r in v[:max_rows]]))
        elif v:
            parts.append(kv_table({k: v}))
    return parts


def _flat(obj: dict[str, Any], prefix: str = "", depth: int = 0) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in obj.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and depth < 2:
            out.update(_flat(v, f"{key}.", depth + 1))
        else:
            out[key] = v
    return out


def page(title: str, sections: Iterable[tuple[str, str, str]], subtitle: str = "") -> str:
    """The whole document. ``sections``: (anchor id, heading, html body)."""
    sections = list(sections)
    nav = "".join(f'<a href="#{esc(a)}">{esc(h)}</a>' for a, h, _ in sections)
    body = "".join(f'<section id="{esc(a)}"><h2>{esc(h)}</h2>{b}</section>' for a, h, b in sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
            f'<meta name="viewport" content="width=device-width, initial-scale=1"><style>{CSS}</style></head>'
            f"<body><header><h1>{esc(title)}</h1><div>{esc(subtitle)}</div><nav>{nav}</nav></header>"
            f"<main>{body}</main></body></html>\n")
