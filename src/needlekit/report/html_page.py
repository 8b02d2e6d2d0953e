"""One HTML page of plotly figures, tables and text (opens offline).

:func:`write_report_html` loads plotly.js once, in the page's head (inlined, or shared
beside the page: :mod:`needlekit.report.plotly_js`), escapes all text, formats table
numbers by their column's unit suffix, and writes the page atomically. Tables fit the
page: their headers wrap, and a table wider than the page scrolls in its own box. Each
figure notes when it has drawn (``window.needlekitDrawn``: how many figures the page
has, how many drew, and ``performance.now()`` when the last one did), the figure the
browser benchmark reads.
"""

from __future__ import annotations

import base64
import html
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from needlekit import __version__
from needlekit.errors import InvalidInputError
from needlekit.io.files import atomic_write
from needlekit.report.plotly_js import plotly_script

__all__ = [
    "FigureSection",
    "ImageSection",
    "ListSection",
    "PartSection",
    "TableSection",
    "TextSection",
    "write_report_html",
]

_MINUS, _DASH = "\N{MINUS SIGN}", "\N{EN DASH}"


@dataclass(frozen=True)
class FigureSection:
    """A plotly figure under a heading, with an optional caption below it."""

    heading: str
    figure: object
    caption: str | None = None


@dataclass(frozen=True)
class TableSection:
    """A table of rows (mappings; columns in order of first appearance) under a heading."""

    heading: str
    rows: Sequence[Mapping]
    caption: str | None = None


@dataclass(frozen=True)
class ImageSection:
    """A PNG image (its bytes, inlined in the page) under a heading, with a caption."""

    heading: str
    png: bytes
    caption: str | None = None


@dataclass(frozen=True)
class ListSection:
    """A bulleted list of plain-text items under an optional heading."""

    items: Sequence[str]
    heading: str | None = None
    caption: str | None = None


@dataclass(frozen=True)
class TextSection:
    """A paragraph of plain text, with an optional heading."""

    text: str
    heading: str | None = None


@dataclass(frozen=True)
class PartSection:
    """The start of a part of the page (e.g. one result of several), with an optional
    paragraph: the sections after it, up to the next part, are its own (their headings one
    level down), and a page with parts opens with a list of links to them."""

    heading: str
    text: str | None = None


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;
margin:0;background:#f4f5f7;color:#222;line-height:1.5}
main{max-width:1280px;margin:0 auto;padding:1.5rem 2.5rem 3rem;background:#fff;min-height:100vh}
h1{font-weight:600;font-size:1.7rem;margin:.3rem 0 1rem;border-bottom:2px solid #e5e5e5;
padding-bottom:.4rem}h2{font-weight:600;font-size:1.2rem;margin:2rem 0 .6rem}
h2.part{font-size:1.45rem;margin-top:3rem;padding-top:.8rem;border-top:2px solid #e5e5e5}
h3{font-weight:600;font-size:1.1rem;margin:1.6rem 0 .5rem}nav li{margin:.15rem 0}
p{max-width:60rem}p.caption{color:#555;font-size:.9rem;margin-top:.3rem}
table{border-collapse:collapse;font-size:.92rem;font-variant-numeric:tabular-nums}
.table-box{max-width:100%;overflow-x:auto}
th,td{padding:.35rem .6rem;border-bottom:1px solid #e3e3e3;text-align:left;white-space:nowrap}
th{white-space:normal;vertical-align:bottom;min-width:3.5em;max-width:9em}
th{background:#f3f5f7;font-weight:600;border-bottom:2px solid #cfd4da}td.num{text-align:right}
tbody tr:nth-child(even){background:#fafbfc}tbody tr:hover{background:#eef4fb}
.figure{border:1px solid #eee;border-radius:6px;padding:.3rem}
footer{margin-top:2.5rem;color:#888;font-size:.8rem}
"""


def _header(key: str) -> str:
    for suffix, unit in (("_mm", "mm"), ("_s", "s"), ("_deg", "°"), ("_rad", "rad")):
        if key.endswith(suffix):
            return f"{key[: -len(suffix)].replace('_', ' ')} ({unit})"
    return key.replace("_", " ")


def _cell(key: str, value) -> tuple[str, bool]:
    """Text of a table cell and whether it is a number (right-aligned)."""
    decimals = ".3f" if key.endswith(("_mm", "_s", "_deg", "_rad", "direction")) else ".4g"
    if value is None or (isinstance(value, (float, np.floating)) and not math.isfinite(value)):
        return _DASH, True
    if isinstance(value, str):
        return value, False
    if isinstance(value, (bool, np.bool_)):
        return ("yes" if value else "no"), False
    if isinstance(value, (int, np.integer)):
        return str(int(value)), True
    if isinstance(value, (float, np.floating)):
        return format(float(value), decimals).replace("-", _MINUS), True
    arr = np.asarray(value) if isinstance(value, (list, tuple, np.ndarray)) else None
    if arr is not None and arr.dtype.kind in "iuf" and arr.ndim == 1:
        return "(" + ", ".join(_cell(key, float(a))[0] for a in arr) + ")", True
    return str(value), False


def _table_html(rows: Sequence[Mapping]) -> str:
    keys = list(dict.fromkeys(str(k) for r in rows for k in r))
    head = "".join(f"<th>{html.escape(_header(k))}</th>" for k in keys)
    body = []
    for r in rows:
        cells = [_cell(k, r.get(k)) for k in keys]
        tds = "".join(f"<td{' class=num' * num}>{html.escape(t)}</td>" for t, num in cells)
        body.append(f"<tr>{tds}</tr>")
    return (
        f"<div class='table-box'><table><thead><tr>{head}</tr></thead>"
        f"<tbody>{''.join(body)}</tbody></table></div>"
    )


def _check_sections(sections) -> list:
    import plotly.graph_objects as go

    if isinstance(sections, (str, bytes)) or not isinstance(sections, Sequence):
        raise InvalidInputError("sections", "expected a sequence of sections")
    out = []
    for i, s in enumerate(sections):
        s = TextSection(s) if isinstance(s, str) else s
        if isinstance(s, FigureSection) and not isinstance(s.figure, go.Figure):
            msg = f"expected a plotly Figure, got {type(s.figure).__name__}"
            raise InvalidInputError(f"sections[{i}].figure", msg)
        if isinstance(s, TableSection) and (
            isinstance(s.rows, (str, bytes, Mapping))
            or not all(isinstance(r, Mapping) for r in s.rows)
        ):
            raise InvalidInputError(f"sections[{i}].rows", "expected a sequence of dicts")
        if isinstance(s, ListSection) and (
            isinstance(s.items, (str, bytes)) or not all(isinstance(t, str) for t in s.items)
        ):
            raise InvalidInputError(f"sections[{i}].items", "expected a sequence of str")
        if isinstance(s, ImageSection) and not (
            isinstance(s.png, bytes) and s.png.startswith(b"\x89PNG\r\n\x1a\n")
        ):
            raise InvalidInputError(f"sections[{i}].png", "expected the bytes of a PNG image")
        known = (FigureSection, ImageSection, ListSection, TableSection, TextSection, PartSection)
        if not isinstance(s, known):
            kinds = (
                "a FigureSection, ImageSection, ListSection, TableSection, TextSection, "
                "PartSection or str"
            )
            raise InvalidInputError(f"sections[{i}]", f"expected {kinds}, got {type(s).__name__}")
        for name in ("heading", "text", "caption"):
            value = getattr(s, name, None)
            if value is not None and not isinstance(value, str):
                raise InvalidInputError(f"sections[{i}].{name}", "expected text (str)")
        out.append(s)
    return out


#: Put in each page's head, before plotly.js: 2D canvas contexts are created with
#: ``willReadFrequently``. plotly.js reads its text canvases back with ``getImageData``,
#: and Chromium otherwise warns in the console, once per page, that such readbacks are
#: faster with the hint; with it the reads stay on the CPU, as the warning advises.
CANVAS_READBACK_HINT = (
    "<script>(function(){var g=HTMLCanvasElement.prototype.getContext;"
    "HTMLCanvasElement.prototype.getContext=function(t,o){if(t==='2d'){"
    "o=Object.assign({willReadFrequently:true},o||{});}return g.call(this,t,o);};})();"
    "</script>"
)


def drawn_note(figures: int) -> str:
    """Put in a page's head: ``window.needlekitDrawn`` counts the page's figures and, as
    each draws (:data:`DRAWN_SCRIPT`, its plot's ``post_script``), the figures drawn and
    ``performance.now()`` at the last (ms from the page's start)."""
    return f"<script>window.needlekitDrawn={{figures:{int(figures)},drawn:0,ms:null}};</script>"


#: Each figure's ``post_script`` (run once plotly drew it): see :func:`drawn_note`.
DRAWN_SCRIPT = (
    "var d=window.needlekitDrawn;if(d){d.drawn+=1;if(d.drawn>=d.figures){d.ms=performance.now();}}"
)


def write_report_html(
    path: str | os.PathLike, *, title: str, sections, plotly: str | None = None
) -> Path:
    """Write figures, tables and text as one HTML page, atomically.

    plotly.js is loaded once, in the head: inlined (the page needs no network nor any
    other file) or from ``plotly.min.js`` beside the page (``plotly="shared"``). The
    page is written to a temporary file that replaces ``path`` only when complete: on any
    error ``path`` keeps its old content.

    Parameters
    ----------
    path : path-like
        Destination (``.html``); its directory is created if missing.
    title : str
        Page title and top heading (plain text, escaped).
    sections : sequence of FigureSection, ImageSection, ListSection, TableSection, TextSection,
        PartSection or str
        In page order; a plain string is a paragraph; a :class:`PartSection` starts a part
        (the page then opens with links to its parts). Headings, text and table cells are
        plain text (escaped). Table numbers are formatted: 3 decimals in ``*_mm``, ``*_s``,
        ``*_deg`` and ``*direction`` columns, 4 significant digits elsewhere, missing
        values (None, NaN, inf) as an en dash.
    plotly : {"inline", "shared"}, optional
        Where plotly.js comes from (:func:`needlekit.report.plotly_js.plotly_script`);
        default: the mode in force (``--plotly``; ``inline`` outside the command line).

    Returns
    -------
    Path
        The destination.
    """
    if not isinstance(title, str):
        raise InvalidInputError("title", f"expected text (str), got {type(title).__name__}")
    items, esc = _check_sections(sections), html.escape
    figures = sum(isinstance(s, FigureSection) for s in items)
    library = plotly_script(path, plotly) if figures else ""

    def write(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>")
            f.write("<meta name='viewport' content='width=device-width, initial-scale=1'>")
            f.write(f"<title>{esc(title)}</title><style>{_CSS}</style>")
            f.write(f"{CANVAS_READBACK_HINT}{drawn_note(figures)}{library}</head>\n")
            f.write(f"<body><main><h1>{esc(title)}</h1>\n")
            parts = [s.heading for s in items if isinstance(s, PartSection)]
            if parts:
                links = "".join(
                    f"<li><a href='#part-{i}'>{esc(h)}</a></li>" for i, h in enumerate(parts, 1)
                )
                f.write(f"<nav><ol>{links}</ol></nav>\n")
            level, part = "h2", 0
            for s in items:
                if isinstance(s, PartSection):
                    part, level = part + 1, "h3"
                    f.write(f"<section id='part-{part}'><h2 class='part'>{esc(s.heading)}</h2>")
                    f.write(f"<p>{esc(s.text)}</p></section>\n" if s.text else "</section>\n")
                    continue
                head = f"<{level}>{esc(s.heading)}</{level}>" if s.heading else ""
                f.write(f"<section>{head}")
                if isinstance(s, TextSection):
                    f.write(f"<p>{esc(s.text)}</p>")
                elif isinstance(s, TableSection):
                    f.write(_table_html(s.rows))
                elif isinstance(s, ImageSection):
                    data = base64.b64encode(s.png).decode("ascii")
                    alt = esc(s.heading, quote=True)
                    f.write(
                        f"<div class='figure'><img alt='{alt}' style='max-width:100%' "
                        f"src='data:image/png;base64,{data}'></div>"
                    )
                elif isinstance(s, ListSection):
                    f.write("<ul>" + "".join(f"<li>{esc(t)}</li>" for t in s.items) + "</ul>")
                else:
                    config = {"displaylogo": False, "responsive": True}
                    div = s.figure.to_html(
                        full_html=False,
                        include_plotlyjs=False,
                        config=config,
                        post_script=DRAWN_SCRIPT,
                        auto_play=False,  # an animation waits for its play button
                    )
                    f.write(f"<div class='figure'>{div}</div>")
                if getattr(s, "caption", None):
                    f.write(f"<p class='caption'>{esc(s.caption)}</p>")
                f.write("</section>\n")
            f.write(f"<footer>needlekit {esc(__version__)}</footer></main></body></html>\n")

    return atomic_write(path, write)
