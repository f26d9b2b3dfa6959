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

__all__ = ["SUMMARY_COLUMNS", "PAPER_RIGS", "summary_table", "paper_rig", "map_outside_hdi",
           "map_note", "write_summary", "pair_figure"]


#: Keys of a summary row, in CSV column order.
#:
#: :meta hide-value:
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
    "best_draw",
)

#: The rigs the paper's values were identified on: a pressure-driven muscle on the
#: characterisation or the control rig. Beside any other rig's parameters they mean
#: nothing, and the summary leaves them out.
PAPER_RIGS = ("characterisation", "control")


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
    ("map", "MAP (global search)"),
    ("best_draw", "highest-density draw"),
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
        autocorrelation time in steps); ``paper`` (the paper's point estimate, only
        for a fit of the paper's kind of rig, :func:`paper_rig`); ``map`` (the MAP
        the global search and its polish found: not a draw of the posterior, and it may
        lie outside the posterior's interval when the sampler found its mass elsewhere,
        :func:`map_outside_hdi`); ``global_search`` (the paper-style least-squares
        optimum); ``best_draw`` (the posterior draw of highest density, a point of the
        posterior). Values are Python floats, or None where the fit has no value.

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
    paper = info.get("paper_values") if paper_rig(info) else None
    best = _best_draw(tree)
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
                "paper": opt_float(paper, name),
                "map": map_value(point.get("values"), str(name)),
                "global_search": opt_float(
                    (point.get("global_search") or {}).get("values"), name
                ),
                "best_draw": opt_float(best, name),
            }
        )
    return rows


def paper_rig(info: Mapping) -> bool:
    """Whether a fit is of the paper's kind: a pressure-driven muscle on the
    characterisation or control rig, in every experiment (:data:`PAPER_RIGS`).

    Parameters
    ----------
    info : mapping
        The fit's metadata (:func:`pmabayes.inference.fitfile.fit_info`).

    Returns
    -------
    bool
    """
    rigs = [e.get("rig") for e in info.get("experiments") or [] if isinstance(e, Mapping)]
    rigs = rigs or [(info.get("model") or {}).get("rig")]
    return all(isinstance(r, Mapping) and r.get("name") in PAPER_RIGS
               and r.get("input_kind", "pressure") == "pressure" for r in rigs)


def _best_draw(tree: xr.DataTree) -> dict[str, float] | None:
    """Every posterior variable at the draw of highest log posterior (``sample_stats.lp``);
    None when the fit has no such statistic."""
    if "sample_stats" not in tree.children or "lp" not in tree["sample_stats"].data_vars:
        return None
    lp = tree["sample_stats"]["lp"]
    if set(lp.dims) != {"chain", "draw"}:
        return None
    lp = lp.transpose("chain", "draw")
    chain, draw = np.unravel_index(int(np.nanargmax(lp.values)), lp.shape)
    post = tree["posterior"]
    return {str(n): float(v.transpose("chain", "draw", ...).values[chain, draw])
            for n, v in post.data_vars.items() if set(v.dims) == {"chain", "draw"}}


def map_outside_hdi(rows: Sequence[Mapping]) -> list[str]:
    """The variables whose MAP lies outside their highest density interval.

    Parameters
    ----------
    rows : sequence of dict
        Rows of :func:`summary_table`.

    Returns
    -------
    list of str
        Their names, in the rows' order.
    """
    return [r["name"] for r in rows
            if r.get("map") is not None and r.get("hdi_low") is not None
            and not r["hdi_low"] <= r["map"] <= r["hdi_high"]]


def map_note(rows: Sequence[Mapping]) -> str:
    """A sentence when the MAP lies outside the posterior's interval; empty otherwise.

    Parameters
    ----------
    rows : sequence of dict
        As :func:`map_outside_hdi`'s.

    Returns
    -------
    str
    """
    names = map_outside_hdi(rows)
    if not names:
        return ""
    return (f"The MAP of {', '.join(names)} lies outside the posterior's {_hdi_label(rows)}: "
            "the global search's optimum is not where the sampler found the posterior's mass "
            "(another basin, or a mode the sampler left), so it is no point estimate of this "
            "posterior; the highest-density draw is.")


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
    note = map_note(rows)
    lines += [f"> {note}", ""] if note else []
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
