"""The summary table of a fit: estimates and diagnostics per posterior variable, written
as CSV and Markdown, and the corner plot marked from it.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import arviz as az
import numpy as np
import xarray as xr

from pmabayes.criticism.adequacy import Adequacy
from pmabayes.report.fit_data import (
    check_ci_prob,
    check_tree,
    flatten,
    map_value,
    opt_float,
    units_of,
)
from pmabayes.report.markup import fmt

__all__ = ["SUMMARY_COLUMNS", "summary_table", "write_summary", "pair_figure"]


#: Keys of a summary row, in CSV column order.
SUMMARY_COLUMNS: tuple[str, ...] = (
    "name",
    "unit",
    "mean",
    "sd",
    "hdi_low",
    "hdi_high",
    "ci_prob",
    "r_hat",
    "r_hat_ensembles",
    "ess",
    "ess_bulk",
    "tau",
    "paper",
    "map",
    "global_search",
)


# Markdown/HTML headers of the displayed columns (ci_prob is shown in the HDI header).
DISPLAY_COLUMNS = (
    ("name", "parameter"),
    ("unit", "unit (SI)"),
    ("mean", "mean"),
    ("sd", "sd"),
    ("hdi_low", "HDI low"),
    ("hdi_high", "HDI high"),
    ("r_hat", "R-hat"),
    ("r_hat_ensembles", "R-hat (ensembles)"),
    ("ess", "ESS (tau)"),
    ("ess_bulk", "ESS bulk"),
    ("paper", "paper"),
    ("map", "MAP"),
)


def summary_table(tree: xr.DataTree, *, ci_prob: float = 0.9) -> list[dict[str, Any]]:
    """One row of estimates and diagnostics per posterior variable.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    ci_prob : float, optional
        Probability mass of the highest density interval, default 0.9. It is passed
        to ArviZ explicitly with ``ci_kind="hdi"`` (ArviZ's own default is an 89%
        equal-tailed interval).

    Returns
    -------
    list of dict
        In the posterior's variable order, each with the keys of
        :data:`SUMMARY_COLUMNS`: ``name``; ``unit`` (SI, from the fit's parameter
        table; ``""`` if unknown); ``mean``, ``sd``, ``hdi_low``, ``hdi_high`` (over
        all walkers and draws) and ``ci_prob``; ``r_hat`` (ArviZ's rank-normalised
        split R-hat over walkers); ``r_hat_ensembles`` (R-hat across independent
        ensembles, from the fit's convergence record); ``ess`` (the
        autocorrelation-time ESS on which the fit's convergence decision rests);
        ``ess_bulk`` (ArviZ's bulk ESS over walkers); ``tau`` (integrated
        autocorrelation time in steps); ``paper`` (the paper's point estimate);
        ``map`` (the MAP); ``global_search`` (the paper-style least-squares
        optimum). Values are Python floats, or None where the fit has no value.

    Raises
    ------
    ValueError
        If ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` is not a pmabayes fit.
    """
    ci_prob = check_ci_prob(ci_prob)
    tree = flatten(tree)
    info = check_tree(tree, ["posterior"])
    stats = az.summary(
        tree,
        group="posterior",
        sample_dims=["chain", "draw"],
        ci_prob=ci_prob,
        ci_kind="hdi",
        fmt="xarray",
        round_to="none",
    )
    labels = [str(s) for s in stats["summary"].values]
    try:
        low = next(s for s in labels if s.startswith("hdi") and s.endswith("_lb"))
        high = next(s for s in labels if s.startswith("hdi") and s.endswith("_ub"))
    except StopIteration:
        raise RuntimeError(
            f"arviz.summary returned no HDI bounds (statistics {labels}); this ArviZ "
            "version names them differently"
        ) from None

    units = units_of(info)
    conv = info.get("convergence") or {}
    point = info.get("map") or {}
    rows = []
    for name in tree["posterior"].data_vars:
        s = stats[name]

        def get(label: str, s: xr.DataArray = s) -> float:
            return float(s.sel(summary=label).values)

        rows.append(
            {
                "name": str(name),
                "unit": str(units.get(str(name).split("[")[0], "")),
                "mean": get("mean"),
                "sd": get("sd"),
                "hdi_low": get(low),
                "hdi_high": get(high),
                "ci_prob": ci_prob,
                "r_hat": get("r_hat"),
                "r_hat_ensembles": opt_float(conv.get("rhat_ensembles"), name),
                "ess": opt_float(conv.get("ess"), name),
                "ess_bulk": get("ess_bulk"),
                "tau": opt_float(conv.get("tau"), name),
                "paper": opt_float(info.get("paper_values"), name),
                "map": map_value(point.get("values"), str(name)),
                "global_search": opt_float(
                    (point.get("global_search") or {}).get("values"), name
                ),
            }
        )
    return rows


def _hdi_label(rows: Sequence[Mapping]) -> str:
    probs = {r.get("ci_prob") for r in rows if r.get("ci_prob") is not None}
    return f"{100 * probs.pop():.4g}% HDI" if len(probs) == 1 else "HDI"


def display_headers(rows: Sequence[Mapping]) -> list[str]:
    hdi = _hdi_label(rows)
    return [
        f"{hdi} {head.split()[1]}" if key.startswith("hdi_") else head
        for key, head in DISPLAY_COLUMNS
    ]


def write_summary(rows: Sequence[Mapping[str, Any]], out_dir: str | Path, *,
                  adequacy: Adequacy | None = None) -> tuple[Path, Path]:
    """Write summary rows as ``summary.csv`` and ``summary.md``.

    Parameters
    ----------
    rows : sequence of dict
        Rows as returned by :func:`summary_table` (keys of :data:`SUMMARY_COLUMNS`;
        a missing key is written as empty).
    out_dir : str or Path
        Destination folder, created if needed; existing files are overwritten.
    adequacy : Adequacy, optional
        The model's adequacy verdict (:func:`~pmabayes.report.verdicts.fit_adequacy`),
        written as a quote above the Markdown table.

    Returns
    -------
    tuple of Path
        The CSV file (all columns, full precision, empty cells for missing values)
        and the Markdown file (a table with the SI unit in its own column, numbers
        as ``%.4g``, an em dash for missing values).

    Raises
    ------
    ValueError
        If a row has no ``name``.
    """
    for i, row in enumerate(rows):
        if not row.get("name"):
            raise ValueError(f"summary row {i} has no 'name'; pass rows from summary_table")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = out_dir / "summary.csv", out_dir / "summary.md"

    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(SUMMARY_COLUMNS)
        for row in rows:
            cells = []
            for key in SUMMARY_COLUMNS:
                v = row.get(key)
                cells.append("" if v is None else repr(float(v)) if isinstance(
                    v, (float, np.floating)) else str(v))
            writer.writerow(cells)

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    lines = [] if adequacy is None else [*_adequacy_markdown(adequacy), ""]
    lines += [
        "| " + " | ".join(display_headers(rows)) + " |",
        "|" + "|".join("---" if k in ("name", "unit") else "---:"
                       for k, _ in DISPLAY_COLUMNS) + "|",
    ]
    for row in rows:
        vals = [f"`{row['name']}`", row.get("unit") or "\u2014"]
        vals += [fmt(row.get(k)) for k, _ in DISPLAY_COLUMNS[2:]]
        lines.append("| " + " | ".join(cell(v) for v in vals) + " |")
    md_path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return csv_path, md_path


def pair_figure(tree: xr.DataTree, path: str | Path, *, names: Sequence[str] | None = None,
                ci_prob: float = 0.9) -> int:
    """Corner plot of the posterior draws with the MAP and the paper's values marked.

    The figure of the report's pair plot, for any subset of the posterior's
    variables. Values off the plotted range are marked by arrow-heads on the edge.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    path : str or Path
        Where to save the figure (format from the suffix).
    names : sequence of str, optional
        Posterior variables to show, in order; all by default.
    ci_prob : float, optional
        Interval probability of the summary the marks come from (0.9).

    Returns
    -------
    int
        The number of draws shown (at most 2000, evenly thinned).

    Raises
    ------
    ValueError
        If a name is not a posterior variable, or ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` is not a pmabayes fit.
    """
    rows = summary_table(tree, ci_prob=ci_prob)
    known = list(tree["posterior"].data_vars)
    if names is not None:
        bad = [n for n in names if n not in known]
        if bad:
            raise ValueError(f"not posterior variables: {bad}; the fit has {known}")
    from pmabayes.report.figures import plot_pair

    return plot_pair(tree, Path(path), rows, names)


def _adequacy_markdown(adequacy: Adequacy) -> list[str]:
    out = [f"> **{adequacy.headline}**: {adequacy.evidence()}."]
    for line in adequacy.advice():
        out += [">", f"> {line}"]
    return out + ([">", f"> Next: `{adequacy.next_step}`"] if adequacy.next_step else [])
