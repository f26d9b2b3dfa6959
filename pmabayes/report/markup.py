"""The pieces every page is built of: its CSS and frame, tables, embedded figures, number
formats, the note on synthetic data, and the rows of a band-error table.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pmabayes.data import Dataset


def fmt(value: Any) -> str:
    """A number as ``%.4g`` (an em dash for a missing value); text unchanged."""
    if value is None:
        return "\u2014"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return str(value)


def um(value_m: float | None) -> str:
    """A length in m shown in µm with 3 significant digits (em dash if missing)."""
    if value_m is None or not math.isfinite(value_m):
        return "\u2014"
    return f"{value_m * 1e6:.3g} µm"


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;
 max-width:1200px;margin:1.5em auto;padding:0 1em;color:#1b1b1b;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em}
.meta{color:#555;font-size:.92em}
.banner{padding:.8em 1.1em;border-radius:6px;margin:1em 0;font-size:1.05em}
.banner p{margin:.4em 0}
.banner p:first-child{margin-top:0;font-weight:600}
.banner.bad{background:#fde2e1;border:3px solid #c62828;color:#7f0000}
.banner.bad strong{font-size:1.3em}
.banner.ok{background:#e6f4ea;border:1px solid #2e7d32;color:#1b5e20}
.verdict{padding:.9em 1.2em;border-radius:6px;margin:1em 0;font-size:1.1em}
.verdict p{margin:.5em 0 0}
.verdict.bad{background:#fde2e1;border:4px solid #c62828;color:#7f0000}
.verdict.bad strong{font-size:1.4em}
.verdict.ok{background:#e6f4ea;border:2px solid #2e7d32;color:#1b5e20}
.verdict.unknown{background:#fff8e1;border:3px solid #f9a825}
.verdict .next code{font-size:1.05em;background:#fff;border:1px solid #c62828;padding:.1em .4em}
.note{background:#fff8e1;border:1px solid #f9a825;padding:.6em 1em;border-radius:6px}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em} th{background:#f2f2f2}
td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1.5em 0} figure img{max-width:100%;border:1px solid #ddd}
figcaption{color:#444;font-size:.92em;margin-top:.3em}
code{background:#f4f4f4;padding:0 .2em}
"""


def html_table(header: Sequence[str], body: Sequence[Sequence[Any]], num_from: int = 1) -> str:
    """An HTML table; cells from column ``num_from`` on are right-aligned numbers."""
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for row in body:
        cells = []
        for i, v in enumerate(row):
            cls = ' class="num"' if i >= num_from else ""
            cells.append(f"<td{cls}>{html.escape(fmt(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def html_figure(path: Path, alt: str, caption: str) -> str:
    """A PNG file embedded as a figure with its caption (``id``: the file's stem)."""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure id="{html.escape(path.stem)}"><img src="data:image/png;base64,{data}" '
        f'alt="{html.escape(alt)}"><figcaption>{html.escape(caption)}</figcaption></figure>'
    )


def html_page(title: str, body: Sequence[str]) -> str:
    """A self-contained page: the title as heading, the body's pieces in order."""
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>", f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>", *body, "</body></html>",
    ]) + "\n"


def synthetic_note(dataset: Dataset) -> str:
    """A note that the data were simulated (empty for measured data)."""
    if not dataset.metadata.get("synthetic"):
        return ""
    return ('<p class="note"><strong>Synthetic data.</strong> These measurements were '
            "simulated, not measured on hardware.</p>")


def band_rows(rows) -> list[list[Any]]:
    """The rows of a band-error table (:data:`BAND_HEADER`) from band errors, in µm."""
    out = []
    for b in rows:
        floor = b.floor_m * 1e6 if np.isfinite(b.floor_m) else None  # one trial: no floor
        out.append([b.label, b.rms_m * 1e6, b.nrms, b.max_m * 1e6, floor,
                    b.ratio if floor is not None else None])
    return out


#: the header of a band-error table
BAND_HEADER = ["frequency band", "RMS [µm]", "RMS / motion RMS", "max [µm]", "floor [µm]",
               "RMS / floor"]


def result_folder(out_dir: str | Path, json_name: str, summary: dict) -> Path:
    """Make a page's folder and write its result's JSON summary there (``json_name``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / json_name).write_text(json.dumps(summary, indent=2) + "\n")
    return out_dir


def write_page(out_dir: Path, title: str, body: Sequence[str]) -> Path:
    """Write ``index.html`` (:func:`html_page`) in ``out_dir``; its path."""
    index = out_dir / "index.html"
    index.write_text(html_page(title, body), encoding="utf-8")
    return index
