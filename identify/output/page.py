"""The HTML of the reports: numbers as table text, cells, tables, figures (embedded or linked PNG) and
the pages' style sheet (one home for :mod:`identify.output.report` and
:mod:`identify.output.use_report`).

Every string that reaches a page from outside the code (units, record and column names,
file names, messages, values read from a results folder) goes through :func:`escape`, the
one escaping helper: the cells, table headers, captions and figures here call it, and the
pages call it for any such string they put into their own markup."""

from __future__ import annotations

import base64
import html
import io
import math
import re
import urllib.parse
from pathlib import Path

import numpy as np

__all__ = [
    "DIGITS",
    "CSS",
    "escape",
    "plain_text",
    "IDENTIFIER",
    "number_text",
    "number_cell",
    "text_cell",
    "html_table",
    "embedded_figure",
    "linked_figure",
    "png_bytes",
    "PNG_COLOURS",
    "html_page",
]

#: Significant digits of the numbers in the tables.
DIGITS = 6


def escape(value) -> str:
    """``value`` as page text: ``str(value)`` with ``& < > " '`` as HTML entities, so it shows as
    written and never becomes markup (safe in element content and in quoted attributes)."""
    return html.escape(str(value), quote=True)


#: A name from the code or the files that a person types as it is (an effect, a parameter, a
#: file, a manifest key): snake_case or dotted words, file names. Shown in ``<code>`` by
#: :func:`plain_text`, never as prose.
IDENTIFIER = re.compile(r"(?<![\w.\[\]/-])(?:\.{0,2}/)?[A-Za-z][\w\[\]./-]*[\w\]]")


def plain_text(value) -> str:
    """``value`` as page text for a person: None is "—", a bool "yes"/"no", a float with
    :data:`DIGITS` digits; the rest escaped (:func:`escape`) with every name a person types as
    it is (:data:`IDENTIFIER`: ``thermal_tau``, ``diagnosis.json``, ``settings.n_starts``)
    wrapped in ``<code>``, so no Python repr and no bare identifier reads as prose."""
    if value is None or isinstance(value, (bool, np.bool_)) or isinstance(value, (float, np.floating)):
        return number_text(value)
    parts, last = [], 0
    text = str(value)
    for match in IDENTIFIER.finditer(text):
        word = match.group(0)
        dotted = "." in word and max(len(part) for part in re.split(r"[./\[\]-]", word)) >= 2  # not "e.g"
        if "_" not in word and not dotted:
            continue  # a plain word, "µm/A", "e.g"
        parts.append(escape(text[last : match.start()]))
        parts.append(f"<code>{escape(match.group(0))}</code>")
        last = match.end()
    parts.append(escape(text[last:]))
    return "".join(parts)


def number_text(value, digits=DIGITS) -> str:
    """Table text of a number: ``digits`` significant digits; "—" for None/NaN; a string escaped."""
    if value is None:
        return "—"
    if isinstance(value, str):
        return escape(value)
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    try:
        value = float(value)
    except (TypeError, ValueError):  # not a number (a value read from a results folder): shown as text
        return escape(value)
    if not math.isfinite(value):
        return "—"
    return f"{value:.{digits}g}"


def number_cell(value, key=None, digits=DIGITS, css=None) -> str:
    attributes = ""
    if key is not None:
        attributes += f' data-key="{escape(key)}"'
    if css:
        attributes += f' class="{escape(css)}"'
    return f"<td{attributes}>{number_text(value, digits)}</td>"


def text_cell(value, css=None) -> str:
    """A table cell of text for a person (:func:`plain_text`: no Python reprs, names in ``<code>``)."""
    attributes = f' class="{escape(css)}"' if css else ""
    return f"<td{attributes}>{plain_text(value)}</td>"


def html_table(table_id, header, rows, caption=None, row_classes=None) -> str:
    """An HTML table; ``header`` and ``caption`` are plain text (escaped here), ``rows`` lists
    of ready cell strings (:func:`number_cell`, :func:`text_cell`), ``row_classes`` optional
    CSS classes. The table sits in a box that scrolls sideways when the table is wider than
    the page (a table of many columns), so it never widens the page."""
    parts = [f'<div class="table-box"><table id="{escape(table_id)}">']
    if caption:
        parts.append(f"<caption>{escape(caption)}</caption>")
    parts.append("<thead><tr>" + "".join(f"<th>{escape(h)}</th>" for h in header) + "</tr></thead><tbody>")
    for i, row in enumerate(rows):
        css = (row_classes or {}).get(i)
        parts.append((f'<tr class="{escape(css)}">' if css else "<tr>") + "".join(row) + "</tr>")
    parts.append("</tbody></table></div>")
    return "\n".join(parts)


def embedded_figure(stem, alt, png_bytes, caption) -> str:
    """A ``<figure>`` whose PNG is inside the page (base64): the page is one file that shows its
    figures wherever it is copied, at 4/3 of the PNG's bytes."""
    encoded = base64.b64encode(png_bytes).decode("ascii")
    return _figure(stem, alt, f"data:image/png;base64,{encoded}", caption)


def linked_figure(stem, alt, relative_path, caption) -> str:
    """A ``<figure>`` showing the PNG file at ``relative_path`` (``"fig5_input.png"``,
    ``"diagnosis/residual.png"``), relative to the page's folder: the page and its PNGs are read
    together from that folder (opened from it, or copied with it), and each figure is stored
    once, as the PNG file, instead of also as base64 text in the page."""
    return _figure(stem, alt, urllib.parse.quote(Path(relative_path).as_posix()), caption)


def _figure(stem, alt, source, caption) -> str:
    return (
        f'<figure id="figure-{escape(stem)}"><img alt="{escape(alt)}" src="{escape(source)}">'
        f"<figcaption><b>{plain_text(alt)}.</b> {plain_text(caption)}</figcaption></figure>"
    )


def html_page(title: str, body_parts, *, heading: bool = True) -> str:
    """A whole page: the head (charset, viewport, the title escaped, :data:`CSS`), an ``h1`` of the
    title (``heading``) and ``body_parts`` (ready markup) in order. Every page the project writes
    is made here."""
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{escape(title)}</title><style>{CSS}</style></head><body>",
            *([f"<h1>{plain_text(title)}</h1>"] if heading else []),
            *body_parts,
            "</body></html>",
        ]
    )


#: Colours of a PNG's palette (:func:`png_bytes`).
PNG_COLOURS = 256


def png_bytes(figure, dpi) -> bytes:
    """``figure`` drawn at ``dpi`` as PNG bytes with a palette of :data:`PNG_COLOURS` colours.

    The figure is drawn once on an Agg canvas (``savefig`` draws a figure with a layout engine
    twice) and its pixels quantised to a palette (PIL's fast octree, alpha kept): a plot holds a
    few colours and their anti-aliased blends, which 256 colours show without a visible
    difference, in about a third of the bytes of the 32-bit image and with a faster encoding.
    """
    # deferred: `diagnose --json` loads this module (its HTML helpers), not matplotlib (+0.19 s CPU)
    import PIL.Image
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    figure.set_dpi(dpi)
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    image = PIL.Image.frombuffer("RGBA", (rgba.shape[1], rgba.shape[0]), rgba, "raw", "RGBA", 0, 1)
    buffer = io.BytesIO()
    image.quantize(PNG_COLOURS, method=PIL.Image.Quantize.FASTOCTREE).save(buffer, format="png", dpi=(dpi, dpi))
    return buffer.getvalue()


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1250px;
margin:1.5em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em} h2{border-bottom:2px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.8em 0;font-size:.92em}
div.table-box{max-width:100%;overflow-x:auto}
td.parameters{text-align:left;white-space:nowrap} td.parameters ul{margin:0;padding-left:1.1em}
pre,code{overflow-wrap:anywhere;white-space:pre-wrap}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right}
th{background:#f2f2f2} td:first-child,th:first-child{text-align:left}
caption{text-align:left;font-weight:bold;padding:.3em 0}
tr.failed td{background:#fde8e8} tr.interrupted td{background:#fff4d6}
tr.worst td{background:#ffe3e0} tr.pinned td{color:#777;background:#f7f7f7}
td.alert{background:#fdecea;font-weight:bold} td.ok{background:#e8f5e9}
figure{margin:1.2em 0} img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{font-size:.92em;color:#444;margin-top:.3em}
div.alert{background:#fdecea;border-left:6px solid #d93025;padding:.6em 1em;margin:1em 0}
div.ok{background:#e8f5e9;border-left:6px solid #2e7d32;padding:.6em 1em;margin:1em 0}
div.note{background:#fff8e1;border-left:6px solid #f9a825;padding:.6em 1em;margin:1em 0}
code{background:#f4f4f4;padding:0 .2em}
"""
