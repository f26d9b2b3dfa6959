"""The page of a comparison of fits: the error falling per band, whiteness and ELPD."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pmabayes.data import Dataset
from pmabayes.report.markup import (
    fmt,
    html_figure,
    html_table,
    result_folder,
    synthetic_note,
    write_page,
)

__all__ = ["write_comparison"]


def write_comparison(comparison, out_dir: str | Path, *,
                     dataset: Dataset | Sequence[Dataset] | None = None) -> Path:
    """Write the error-falling figure, tables and an HTML page of a fit comparison.

    Parameters
    ----------
    comparison : pmabayes.criticism.compare.FitComparison
        From :func:`pmabayes.criticism.compare.compare_fits`.
    out_dir : str or Path
        Destination folder. Written: ``error_falling.png``, ``whiteness.png``,
        ``comparison.json``, ``comparison.md`` and ``index.html``. For fits of
        several experiments the figures are per experiment
        (``error_falling_NAME.png``, ``whiteness_NAME.png``), with a table and a
        section (``id="experiment-NAME"``) each, and one ELPD table over all trials.
    dataset : Dataset or sequence of Dataset, optional
        The data (one per experiment), to name it and mark it synthetic.

    Returns
    -------
    Path
        The path of ``index.html``.
    """
    c = comparison
    out_dir = result_folder(out_dir, "comparison.json", c.to_dict())
    datasets = ([] if dataset is None else [dataset] if isinstance(dataset, Dataset)
                else list(dataset))
    parts = c.experiments or {"": c}
    several = bool(c.experiments)
    elpd_header = ["fit", "ELPD (LOO)", "ΔELPD vs best ± se"]
    elpd_rows = [[k, c.elpd[k]["elpd"], f"{c.elpd[k]['elpd_diff']:.1f} ± {c.elpd[k]['dse']:.1f}"]
                 for k in c.labels]
    md: list[str] = []
    sections: list[str] = []
    for name, part in parts.items():
        suffix = f"_{name}" if several else ""
        header, rows = _comparison_rows(part, with_elpd=not several)
        if several:
            md += [f"## {name}", ""]
            sections.append(f'<h2 id="experiment-{html.escape(name)}">Experiment '
                            f"{html.escape(name)}: error per frequency band and whiteness</h2>")
        else:
            sections.append("<h2>Error per frequency band, whiteness and ELPD</h2>")
        md += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        md += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
        md.append("")
        sections.append(html_table(header, rows))
        sections += _comparison_figures(part, out_dir, suffix, name)
    if several:
        md += ["## ELPD, leaving out one trial of all experiments at a time", "",
               "| " + " | ".join(elpd_header) + " |", "|" + "---|" * len(elpd_header)]
        md += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in elpd_rows]
        md.append("")
    md += ["| step | ΔELPD | se |", "|---|---|---|"]
    md += [f"| {st['from']} → {st['to']} | {st['elpd_diff']:+.1f} | {st['se']:.1f} |"
           for st in c.elpd_steps]
    (out_dir / "comparison.md").write_text("\n".join(md) + "\n")
    names = [Path(ds.source).name if ds.source else "data" for ds in datasets] or ["data"]
    name = " + ".join(names)
    body = [
        f'<p class="meta">{len(c.labels)} fits of '
        + ", ".join(f"<code>{html.escape(n)}</code>" for n in names)
        + (f" ({len(parts)} experiments)" if several else "") + "</p>",
        *dict.fromkeys(synthetic_note(ds) for ds in datasets),
    ]
    if several:
        body += ["<h2>ELPD, leaving out one trial of all experiments at a time</h2>",
                 html_table(elpd_header, elpd_rows)]
        body += sections
    else:
        body += sections[:2]
    body += [
        "<h2>Each step</h2>",
        html_table(["step", "ΔELPD (leave one trial out)", "se"],
               [[f"{st['from']} → {st['to']}", st["elpd_diff"], st["se"]]
                for st in c.elpd_steps]),
    ]
    if not several:
        body += sections[2:]
    return write_page(out_dir, f"pmabayes comparison: {name}", body)


def _comparison_rows(c, *, with_elpd: bool) -> tuple[list[str], list[list[Any]]]:
    """The table of a comparison on one data set: RMS per band, ratio, whiteness (and ELPD)."""
    band_names = [b.label for b in c.bands[c.labels[0]]]
    header = ["fit", *[f"RMS {b} [µm]" for b in band_names], "RMS / floor",
              "Ljung-Box p", "energy"]
    if with_elpd:
        header += ["ELPD (LOO)", "ΔELPD vs best ± se"]
    rows = []
    for k in c.labels:
        ratio = c.bands[k][-1].ratio
        row = [k, *[b.rms_m * 1e6 for b in c.bands[k]], ratio if np.isfinite(ratio) else None,
               c.whiteness[k]["ljung_box_p"], c.whiteness[k]["energy"]]
        if with_elpd:
            row += [c.elpd[k]["elpd"], f"{c.elpd[k]['elpd_diff']:.1f} ± {c.elpd[k]['dse']:.1f}"]
        rows.append(row)
    floors = [b.floor_m * 1e6 if np.isfinite(b.floor_m) else None for b in c.bands[c.labels[0]]]
    rows.append(["noise floor", *floors, 1.0 if floors[-1] is not None else None, "", "",
                 *(["", ""] if with_elpd else [])])
    return header, rows


def _comparison_figures(c, out_dir: Path, suffix: str, name: str) -> list[str]:
    """Draw the error-falling and whiteness figures of one data set; their ``<img>``s."""
    from pmabayes.report import figures as plots
    plots.plot_band_errors(c.bands, title="the error falls as effects are added "
                                          "(label: multiple of the noise floor)"
                           + (f": {name}" if name else "")
                           ).savefig(out_dir / f"error_falling{suffix}.png", dpi=plots.REPORT_DPI)
    plots.plot_whiteness(c.whiteness_curves()).savefig(out_dir / f"whiteness{suffix}.png",
                                                       dpi=plots.REPORT_DPI)
    return [
        html_figure(out_dir / f"error_falling{suffix}.png", "error falling",
             "RMS error of the trial mean per frequency band for each fit, with the noise "
             "floor (black)."),
        html_figure(out_dir / f"whiteness{suffix}.png", "whiteness",
             "Whitened residual of each fit: autocorrelation and cross-correlation with the "
             "command's rate, against the bounds for a white residual."),
    ]
