"""Report stage: the summary table, diagnostic figures and an offline HTML page of a fit.

The input is a fit as laid out in :mod:`pmabayes.posterior` (an ArviZ 1.x
:class:`xarray.DataTree`, usually read back with :func:`pmabayes.posterior.load_fit`).
Nothing here simulates or samples: every number and curve comes from the fit file.

:func:`summary_table`
    One row per posterior variable: posterior mean, sd and HDI, diagnostics, the
    paper's value and the MAP.
:func:`write_summary`
    The table as ``summary.csv`` and ``summary.md``.
:func:`write_report`
    Both tables, five figures (``trace.png``, ``rank.png``, ``pair.png``,
    ``ppc.png``, ``residual.png``) and ``index.html``, a single self-contained page
    (figures embedded as base64 PNG, inline CSS, no script, no external resource).
"""

from __future__ import annotations

import base64
import csv
import html
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import arviz as az
import numpy as np
import xarray as xr
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from pmabayes.data import Dataset
from pmabayes.posterior import FitFileError, check_dataset, fit_info

__all__ = ["SUMMARY_COLUMNS", "summary_table", "write_summary", "write_report", "write_diagnosis",
           "write_comparison", "pair_figure", "predictive_band"]

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
_DISPLAY = (
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
_PNG_DPI = 100
_PAIR_MAX_DRAWS = 2000
_RANK_MAX_DRAWS = 100  # per chain: the multi-chain rank test costs O(chains x draws)
_ZOOM_S = 1.0
_QUANTILE_BLOCK = 4_000_000  # values per block when taking quantiles of the predictive


# ----------------------------------------------------------------------------- helpers


def _opt_float(mapping: Mapping | None, name: str) -> float | None:
    """``float(mapping[name])``, or None when the mapping or the entry is missing."""
    if not mapping or mapping.get(name) is None:
        return None
    return float(mapping[name])


def _fmt(value: Any) -> str:
    """A number as ``%.4g`` (an em dash for a missing value); text unchanged."""
    if value is None:
        return "\u2014"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return str(value)


def _um(value_m: float | None) -> str:
    """A length in m shown in µm with 3 significant digits (em dash if missing)."""
    if value_m is None or not math.isfinite(value_m):
        return "\u2014"
    return f"{value_m * 1e6:.3g} µm"


def _check_ci_prob(ci_prob: float) -> float:
    ci = float(ci_prob)
    if not 0.0 < ci < 1.0:
        raise ValueError(f"ci_prob must be in (0, 1), got {ci_prob!r}")
    return ci


def _check_tree(tree: xr.DataTree, groups: Sequence[str]) -> dict:
    """Decode the fit's metadata and check that the groups the report reads exist."""
    if not isinstance(tree, xr.DataTree):
        raise TypeError(f"a fit is an xarray.DataTree, got {type(tree).__name__}")
    info = fit_info(tree)
    missing = [g for g in groups if g not in tree.children]
    if missing:
        raise FitFileError(
            f"the fit has no group(s) {', '.join(missing)}; a report needs the layout of "
            "pmabayes.posterior (write the fit with `pmabayes fit`)"
        )
    for name, var in tree["posterior"].data_vars.items():
        if set(var.dims) != {"chain", "draw"}:
            raise FitFileError(
                f"posterior variable {name!r} has dims {var.dims}; expected (chain, draw)"
            )
    return info


def _draws(tree: xr.DataTree, name: str) -> np.ndarray:
    """A posterior variable as a ``(chain, draw)`` float array."""
    return np.asarray(tree["posterior"][name].transpose("chain", "draw").values, dtype=float)


def _quantiles_over_samples(
    da: xr.DataArray, probs: Sequence[float], *, time_dim: str = "time"
) -> np.ndarray:
    """Quantiles over every dimension except ``time_dim``, block by block in time.

    Only one block of the (possibly lazily loaded, float32) array is in memory at a
    time. Returns shape ``(len(probs), n_time)``.
    """
    da = da.transpose(..., time_dim)
    n_time = da.sizes[time_dim]
    n_rows = max(1, int(da.size // max(n_time, 1)))
    step = max(1, _QUANTILE_BLOCK // n_rows)
    out = np.empty((len(probs), n_time))
    for a in range(0, n_time, step):
        block = np.asarray(da.isel({time_dim: slice(a, a + step)}).values)
        out[:, a : a + step] = np.quantile(block.reshape(n_rows, -1), probs, axis=0)
    return out


def _units(info: dict) -> dict[str, str]:
    """Parameter name -> SI unit, from the fit's parameter table (noise included)."""
    params = (info.get("model") or {}).get("parameters") or []
    return {p["name"]: str(p.get("unit") or "") for p in params if "name" in p}


def _source_name(info: dict, dataset: Dataset | None) -> str:
    if dataset is not None and dataset.source:
        return str(dataset.source)
    return str((info.get("data") or {}).get("source") or "unnamed data")


# ----------------------------------------------------------------------------- table


def summary_table(tree: xr.DataTree, *, ci_prob: float = 0.9) -> list[dict[str, Any]]:
    """One row of estimates and diagnostics per posterior variable.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.posterior`).
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
    ci_prob = _check_ci_prob(ci_prob)
    info = _check_tree(tree, ["posterior"])
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

    units = _units(info)
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
                "unit": str(units.get(name, "")),
                "mean": get("mean"),
                "sd": get("sd"),
                "hdi_low": get(low),
                "hdi_high": get(high),
                "ci_prob": ci_prob,
                "r_hat": get("r_hat"),
                "r_hat_ensembles": _opt_float(conv.get("rhat_ensembles"), name),
                "ess": _opt_float(conv.get("ess"), name),
                "ess_bulk": get("ess_bulk"),
                "tau": _opt_float(conv.get("tau"), name),
                "paper": _opt_float(info.get("paper_values"), name),
                "map": _opt_float(point.get("values"), name),
                "global_search": _opt_float(
                    (point.get("global_search") or {}).get("values"), name
                ),
            }
        )
    return rows


def _hdi_label(rows: Sequence[Mapping]) -> str:
    probs = {r.get("ci_prob") for r in rows if r.get("ci_prob") is not None}
    return f"{100 * probs.pop():.4g}% HDI" if len(probs) == 1 else "HDI"


def _display_headers(rows: Sequence[Mapping]) -> list[str]:
    hdi = _hdi_label(rows)
    return [
        f"{hdi} {head.split()[1]}" if key.startswith("hdi_") else head for key, head in _DISPLAY
    ]


def write_summary(rows: Sequence[Mapping[str, Any]], out_dir: str | Path) -> tuple[Path, Path]:
    """Write summary rows as ``summary.csv`` and ``summary.md``.

    Parameters
    ----------
    rows : sequence of dict
        Rows as returned by :func:`summary_table` (keys of :data:`SUMMARY_COLUMNS`;
        a missing key is written as empty).
    out_dir : str or Path
        Destination folder, created if needed; existing files are overwritten.

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

    lines = [
        "| " + " | ".join(_display_headers(rows)) + " |",
        "|" + "|".join("---" if k in ("name", "unit") else "---:" for k, _ in _DISPLAY) + "|",
    ]
    for row in rows:
        vals = [f"`{row['name']}`", row.get("unit") or "\u2014"]
        vals += [_fmt(row.get(k)) for k, _ in _DISPLAY[2:]]
        lines.append("| " + " | ".join(cell(v) for v in vals) + " |")
    md_path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return csv_path, md_path


# ----------------------------------------------------------------------------- figures


def _save_arviz(make: Callable[[], Any], path: Path) -> None:
    """Draw an ArviZ plot (matplotlib backend), save it and close its pyplot figures.

    Figures the call opened are closed even when it fails, and only those.
    """
    import matplotlib.pyplot as plt  # ArviZ draws through pyplot

    before = set(plt.get_fignums())
    try:
        fig = make().get_viz("figure")
        fig = fig.item() if hasattr(fig, "item") else fig
        fig.savefig(path, dpi=_PNG_DPI)
    finally:
        for num in set(plt.get_fignums()) - before:
            plt.close(num)


def _display_posterior(tree: xr.DataTree, units: Mapping[str, str]) -> xr.DataTree:
    """The posterior with variables scaled and renamed for short tick labels.

    A variable needing a scale (see :func:`_display_scale`) is renamed, e.g.
    ``sigma_noise_m [µm]``, so that no offset text crowds the figure.
    """
    post = tree["posterior"].to_dataset()
    renamed = {}
    for name in list(post.data_vars):
        values = post[name].values
        unit = units.get(name, "")
        factor, shown = _display_scale(values, unit)
        if factor != 1.0:
            shown = shown if shown == "µm" else f"1e{-round(math.log10(factor))} {unit}"
            renamed[name] = f"{name} [{shown.replace('/', '∕')}]"
            post[name] = post[name] * factor
    return xr.DataTree.from_dict({"posterior": post.rename(renamed)})


def _trace_figure(tree: xr.DataTree, path: Path, units: Mapping[str, str]) -> str | None:
    """Trace and marginal of every variable; returns a note if the fallback was used."""
    tree = _display_posterior(tree, units)
    names = list(tree["posterior"].data_vars)
    n_chain = tree["posterior"].sizes["chain"]
    alpha = float(np.clip(12.0 / n_chain, 0.1, 0.8))
    width = 0.3 if n_chain > 16 else 0.6
    figsize = (11, 1.5 * len(names) + 0.8)
    try:
        _save_arviz(
            lambda: az.plot_trace_dist(
                tree,
                var_names=names,
                sample_dims=["chain", "draw"],
                compact=True,
                combined=True,
                backend="matplotlib",
                visuals={"trace": {"alpha": alpha, "width": width}},
                figure_kwargs={"figsize": figsize, "layout": "constrained"},
            ),
            path,
        )
        return None
    except Exception as exc:  # ArviZ plotting is outside our control
        # Fallback: plain matplotlib traces if arviz_plots fails on this tree/version.
        note = f"ArviZ plot_trace_dist failed ({type(exc).__name__}: {exc}); matplotlib fallback."
    fig = Figure(figsize=figsize, layout="constrained")
    axes = fig.subplots(len(names), 2, squeeze=False, width_ratios=(1, 2.5))
    for i, name in enumerate(names):
        x = _draws(tree, name)
        axes[i, 0].hist(x.ravel(), bins=40, color=f"C{i % 10}", alpha=0.8)
        axes[i, 0].set_yticks([])
        axes[i, 0].set_xlabel(name, fontsize=8)
        axes[i, 1].plot(x.T, color=f"C{i % 10}", alpha=alpha, lw=width)
        axes[i, 1].set_ylabel(name, fontsize=8)
    axes[-1, 1].set_xlabel("draw")
    fig.savefig(path, dpi=_PNG_DPI)
    return note


def _rank_figure(tree: xr.DataTree, path: Path) -> tuple[int, str | None]:
    """Rank (fractional-rank Δ-ECDF) plots; returns the thinning factor and a note."""
    post = tree["posterior"]
    names = list(post.data_vars)
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    factor = max(1, math.ceil(n_draw / _RANK_MAX_DRAWS))
    ncols = min(4, len(names))
    nrows = math.ceil(len(names) / ncols)
    figsize = (3.2 * ncols, 2.6 * nrows)
    alpha = float(np.clip(10.0 / n_chain, 0.15, 0.9))
    try:
        _save_arviz(
            lambda: az.plot_rank(
                tree,
                var_names=names,
                sample_dims=["chain", "draw"],  # emcee walkers are the chains
                thin=factor > 1,
                stats={"thin": {"factor": factor}} if factor > 1 else None,
                backend="matplotlib",
                visuals={"ecdf_lines": {"alpha": alpha, "width": 0.7}},
                col_wrap=ncols,
                figure_kwargs={"figsize": figsize, "layout": "constrained"},
            ),
            path,
        )
        return factor, None
    except Exception as exc:  # ArviZ plotting is outside our control
        # Fallback: per-walker rank histograms in plain matplotlib.
        note = f"ArviZ plot_rank failed ({type(exc).__name__}: {exc}); matplotlib fallback."
    fig = Figure(figsize=figsize, layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    for ax, name in zip(axes, names, strict=False):
        x = _draws(tree, name)[:, ::factor]
        ranks = x.ravel().argsort().argsort().reshape(x.shape) / x.size
        bins = np.linspace(0, 1, 21)
        for c in range(n_chain):
            h, _ = np.histogram(ranks[c], bins=bins)
            ax.stairs(h / ranks.shape[1] * 20, bins, alpha=alpha, lw=0.7)  # 1 = uniform
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("fractional rank", fontsize=8)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    fig.savefig(path, dpi=_PNG_DPI)
    return factor, note


def _edge_mark(ax: Any, x: float | None, y: float | None, **style: Any) -> None:
    """Mark a point, or a triangle at the edge pointing towards it when it is outside."""
    if x is None or y is None or not (math.isfinite(x) and math.isfinite(y)):
        return
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    cx, cy = min(max(x, x0), x1), min(max(y, y0), y1)
    if (cx, cy) == (x, y):
        ax.plot(x, y, **style)
        return
    marker = ">" if x > x1 else "<" if x < x0 else "^" if y > y1 else "v"
    ax.plot(cx, cy, **{**style, "marker": marker, "mfc": style.get("color"), "clip_on": False})


def _edge_vline(ax: Any, x: float | None, **style: Any) -> None:
    """A vertical line at ``x``, or an arrow-head at the edge when ``x`` is outside."""
    if x is None or not math.isfinite(x):
        return
    x0, x1 = ax.get_xlim()
    if x0 <= x <= x1:
        ax.axvline(x, **style)
    else:
        ax.plot(x1 if x > x1 else x0, 0.5, transform=ax.get_xaxis_transform(),
                marker=">" if x > x1 else "<", color=style.get("color"), ms=8, clip_on=False)


def _display_scale(values: np.ndarray, unit: str) -> tuple[float, str]:
    """A factor and unit label that keep tick labels short (µm for small lengths)."""
    big = float(np.max(np.abs(values))) if values.size else 0.0
    if big == 0.0 or not math.isfinite(big):
        return 1.0, unit
    if unit == "m" and big < 1e-3:
        return 1e6, "µm"
    e = math.floor(math.log10(big))
    if -3 < e < 5:
        return 1.0, unit
    return 10.0**-e, rf"$\times 10^{{{e}}}$ {unit}".strip()


def _pair_figure(tree: xr.DataTree, path: Path, rows: Sequence[Mapping],
                 names: Sequence[str] | None = None) -> int:
    """Corner plot of posterior variables (all by default); returns the draws shown."""
    names = list(tree["posterior"].data_vars) if names is None else list(names)
    k = len(names)
    flat = np.stack([_draws(tree, n).ravel() for n in names])  # (k, chain*draw)
    n_total = flat.shape[1]
    keep = np.unique(np.linspace(0, n_total - 1, min(n_total, _PAIR_MAX_DRAWS)).astype(int))
    flat = flat[:, keep]
    by_name = {r["name"]: r for r in rows}
    labels, paper, mapv, lims = [], [], [], []
    for i, n in enumerate(names):
        unit = by_name[n].get("unit") or ""
        factor, shown_unit = _display_scale(flat[i], unit)
        flat[i] *= factor
        labels.append(f"{n} [{shown_unit}]" if shown_unit else n)
        for out, key in ((paper, "paper"), (mapv, "map")):
            v = by_name[n].get(key)
            out.append(None if v is None else v * factor)
        lo, hi = float(flat[i].min()), float(flat[i].max())
        pad = 0.06 * (hi - lo) if hi > lo else max(abs(lo) * 1e-3, 1e-12)
        lims.append((lo - pad, hi + pad))

    size = min(1.55 * k + 1.0, 18.0)
    fig = Figure(figsize=(size, size), layout="constrained")
    axes = fig.subplots(k, k, squeeze=False)
    map_style = {"color": "k", "marker": "x", "ms": 7, "mew": 1.5, "ls": "none", "zorder": 4}
    paper_style = {"color": "tab:red", "marker": "o", "ms": 6, "mfc": "none", "mew": 1.5,
                   "ls": "none", "zorder": 4}
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            ax.tick_params(labelsize=6)
            ax.xaxis.set_major_locator(MaxNLocator(3))
            if i == j:
                ax.hist(flat[i], bins=30, range=lims[i], color="tab:blue", alpha=0.7)
                ax.set_xlim(lims[i])
                ax.set_yticks([])
                _edge_vline(ax, mapv[i], color="k", lw=1.2)
                _edge_vline(ax, paper[i], color="tab:red", lw=1.2, ls="--")
            else:
                ax.scatter(flat[j], flat[i], s=1.5, alpha=0.25, color="tab:blue",
                           rasterized=True, linewidths=0)
                ax.set_xlim(lims[j])
                ax.set_ylim(lims[i])
                ax.yaxis.set_major_locator(MaxNLocator(3))
                _edge_mark(ax, mapv[j], mapv[i], **map_style)
                _edge_mark(ax, paper[j], paper[i], **paper_style)
                if j == 0:
                    ax.set_ylabel(labels[i], fontsize=8)
                else:
                    ax.set_yticklabels([])
            if i < k - 1:
                ax.set_xticklabels([])
            else:
                ax.set_xlabel(labels[j], fontsize=8)
                ax.tick_params(axis="x", labelrotation=45)
    handles = [
        Line2D([], [], **map_style, label="MAP"),
        Line2D([], [], **paper_style, label="paper (arrow-head: off scale)"),
    ]
    fig.legend(handles=handles, loc="upper right", fontsize=9, frameon=False)
    fig.savefig(path, dpi=_PNG_DPI)
    return int(keep.size)


def pair_figure(tree: xr.DataTree, path: str | Path, *, names: Sequence[str] | None = None,
                ci_prob: float = 0.9) -> int:
    """Corner plot of the posterior draws with the MAP and the paper's values marked.

    The figure of the report's pair plot, for any subset of the posterior's
    variables. Values off the plotted range are marked by arrow-heads on the edge.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.posterior`).
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
    return _pair_figure(tree, Path(path), rows, names)


def predictive_band(tree: xr.DataTree, *, ci_prob: float = 0.9) -> dict[str, np.ndarray]:
    """The posterior predictive band of a fit, pooled over its stored draws.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit with ``observed_data`` and ``posterior_predictive`` groups.
    ci_prob : float, optional
        Central probability of the band (0.9).

    Returns
    -------
    dict
        ``time`` [s], ``trials``, ``data`` (``(n_trials, n_samples)`` in m),
        ``median`` (the median noise-free model position in m), ``low`` and
        ``high`` (the band's edges in m, with measurement noise) and ``coverage``
        (fraction of all measured samples inside the band).

    Raises
    ------
    ValueError
        If ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` lacks the groups.
    """
    ci_prob = _check_ci_prob(ci_prob)
    _check_tree(tree, ["observed_data", "posterior_predictive"])
    return _predictive(tree, ci_prob)


def _predictive(tree: xr.DataTree, ci_prob: float) -> dict[str, np.ndarray]:
    """Time, data, median model and the pooled central predictive band (all in m)."""
    obs = tree["observed_data"]["position_m"].transpose("trial", "time")
    pp = tree["posterior_predictive"]
    q = (1.0 - ci_prob) / 2.0
    band = _quantiles_over_samples(pp["position_m"], [q, 1.0 - q])
    median = _quantiles_over_samples(pp["model_position_m"], [0.5])[0]
    data = np.asarray(obs.values, dtype=float)
    return {
        "time": np.asarray(obs["time"].values, dtype=float),
        "trials": np.asarray(obs["trial"].values),
        "data": data,
        "median": median,
        "low": band[0],
        "high": band[1],
        "coverage": float(np.mean((data >= band[0]) & (data <= band[1]))),
    }


def _zoom_slice(t: np.ndarray) -> slice:
    """The last ``_ZOOM_S`` seconds (the chirp's fast end), at most a quarter of the run."""
    span = float(t[-1] - t[0])
    width = min(_ZOOM_S, 0.25 * span)
    return slice(int(np.searchsorted(t, t[-1] - width)), None)


def _ppc_figure(pred: dict[str, np.ndarray], path: Path, ci_prob: float) -> None:
    """Posterior predictive check: one pair of panels per trial, residual-scale panels."""
    t, data, med, lo, hi = (pred[k] for k in ("time", "data", "median", "low", "high"))
    n_trial = data.shape[0]
    z = _zoom_slice(t)
    pairs = 2 if n_trial > 1 else 1
    nrows = math.ceil(n_trial / pairs)
    fig = Figure(figsize=(13, 2.1 * nrows + 3.2), layout="constrained")
    grid = fig.add_gridspec(nrows + 1, 2 * pairs, width_ratios=(3, 1) * pairs,
                            height_ratios=(1,) * nrows + (1.5,))
    pct = f"{100 * ci_prob:.4g}%"
    for r in range(n_trial):
        row, col = divmod(r, pairs)
        ax = fig.add_subplot(grid[row, 2 * col])
        axz = fig.add_subplot(grid[row, 2 * col + 1])
        for a, s in ((ax, slice(None)), (axz, z)):
            a.fill_between(t[s], lo[s] * 1e3, hi[s] * 1e3, color="tab:blue", alpha=0.35,
                           lw=0, label=f"{pct} predictive")
            a.plot(t[s], data[r, s] * 1e3, color="k", lw=0.5, label="data")
            a.plot(t[s], med[s] * 1e3, color="tab:red", lw=0.7, ls="--",
                   label="median model")
            a.tick_params(labelsize=7)
        ax.set_title(f"trial {pred['trials'][r]}", fontsize=8, loc="left")
        axz.set_title(f"last {t[-1] - t[z][0]:.2g} s", fontsize=8, loc="left")
        ax.set_ylabel("x [mm]", fontsize=8)
        if r == 0:
            ax.legend(fontsize=6, loc="upper left", ncols=3)
    axr = fig.add_subplot(grid[nrows, : 2 * pairs - 1])
    axrz = fig.add_subplot(grid[nrows, 2 * pairs - 1])
    alpha = float(np.clip(2.0 / n_trial, 0.15, 0.6))
    for a, s in ((axr, slice(None)), (axrz, z)):
        a.fill_between(t[s], (lo[s] - med[s]) * 1e6, (hi[s] - med[s]) * 1e6,
                       color="tab:blue", alpha=0.3, lw=0, label=f"{pct} predictive − median")
        for r in range(n_trial):
            a.plot(t[s], (data[r, s] - med[s]) * 1e6, lw=0.4, alpha=alpha, color="0.2",
                   label="data − median model" if r == 0 else None)
        for edge in (lo, hi):  # band edges drawn over the data, so the band stays visible
            a.plot(t[s], (edge[s] - med[s]) * 1e6, color="tab:blue", lw=0.8)
        a.axhline(0.0, color="tab:red", lw=0.7, ls="--")
        a.set_xlabel("time [s]", fontsize=8)
        a.tick_params(labelsize=7)
    axr.set_ylabel("residual [µm]", fontsize=8)
    axr.legend(fontsize=7, loc="upper left", ncols=2)
    axr.set_title(
        f"residual scale, every trial: {100 * pred['coverage']:.1f}% of the data inside the "
        f"{pct} band", fontsize=8, loc="left",
    )
    fig.savefig(path, dpi=_PNG_DPI)


def _residual_figure(
    pred: dict[str, np.ndarray], noise_floor_m: float | None, path: Path
) -> float:
    """Trial-mean residual against the median model with the noise floor; returns its RMS."""
    t = pred["time"]
    resid = (pred["data"].mean(axis=0) - pred["median"]) * 1e6
    rms = float(np.sqrt(np.mean(resid**2)))
    z = _zoom_slice(t)
    fig = Figure(figsize=(12, 3.4), layout="constrained")
    ax, axz = fig.subplots(1, 2, width_ratios=(3, 1), sharey=True)
    for a, s in ((ax, slice(None)), (axz, z)):
        if noise_floor_m is not None and math.isfinite(noise_floor_m):
            a.axhspan(-noise_floor_m * 1e6, noise_floor_m * 1e6, color="tab:green", alpha=0.25,
                      label=f"trial-mean noise floor ±{noise_floor_m * 1e6:.3g} µm")
        a.plot(t[s], resid[s], color="k", lw=0.6, label=f"trial mean − median model "
               f"(RMS {rms:.3g} µm)")
        a.axhline(0.0, color="tab:red", lw=0.6, ls="--")
        a.set_xlabel("time [s]")
    ax.set_ylabel("residual [µm]")
    ax.legend(fontsize=8, loc="upper left")
    axz.set_title(f"last {t[-1] - t[z][0]:.2g} s", fontsize=9, loc="left")
    fig.savefig(path, dpi=_PNG_DPI)
    return rms


# ----------------------------------------------------------------------------- HTML

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;
 max-width:1200px;margin:1.5em auto;padding:0 1em;color:#1b1b1b;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em}
.meta{color:#555;font-size:.92em}
.banner{padding:.8em 1.1em;border-radius:6px;margin:1em 0;font-size:1.05em}
.banner.bad{background:#fde2e1;border:3px solid #c62828;color:#7f0000}
.banner.bad strong{font-size:1.3em}
.banner.ok{background:#e6f4ea;border:1px solid #2e7d32;color:#1b5e20}
.note{background:#fff8e1;border:1px solid #f9a825;padding:.6em 1em;border-radius:6px}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em} th{background:#f2f2f2}
td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1.5em 0} figure img{max-width:100%;border:1px solid #ddd}
figcaption{color:#444;font-size:.92em;margin-top:.3em}
code{background:#f4f4f4;padding:0 .2em}
"""


def _table(header: Sequence[str], body: Sequence[Sequence[Any]], num_from: int = 1) -> str:
    """An HTML table; cells from column ``num_from`` on are right-aligned numbers."""
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for row in body:
        cells = []
        for i, v in enumerate(row):
            cls = ' class="num"' if i >= num_from else ""
            cells.append(f"<td{cls}>{html.escape(_fmt(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _img(path: Path, alt: str, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure id="{html.escape(path.stem)}"><img src="data:image/png;base64,{data}" '
        f'alt="{html.escape(alt)}"><figcaption>{html.escape(caption)}</figcaption></figure>'
    )


def write_report(
    tree: xr.DataTree,
    out_dir: str | Path,
    *,
    dataset: Dataset | None = None,
    ci_prob: float = 0.9,
) -> Path:
    """Write the tables, the figures and a self-contained HTML report of a fit.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.posterior`).
    out_dir : str or Path
        Destination folder, created if needed. Written: ``summary.csv``,
        ``summary.md``, ``trace.png``, ``rank.png``, ``pair.png``, ``ppc.png``,
        ``residual.png`` and ``index.html`` (overwritten if present).
    dataset : Dataset, optional
        The data the fit was made from. When given, its trials must equal the fit's
        observed positions (same shape, values within 1e-12 m), and its source names
        the report.
    ci_prob : float, optional
        Probability of the HDIs in the table and of the central posterior predictive
        band, default 0.9.

    Returns
    -------
    Path
        The path of ``index.html``. The page embeds every figure as a base64 PNG and
        its CSS inline; it loads nothing from the network and has no script.

    Raises
    ------
    ValueError
        If ``dataset`` does not match the fit's observed data, or ``ci_prob`` is not
        in (0, 1).
    TypeError
        If ``dataset`` is not a :class:`~pmabayes.data.Dataset`.
    FitFileError
        If ``tree`` is not a pmabayes fit or lacks a group the report needs.

    Examples
    --------
    >>> from pmabayes.posterior import load_fit
    >>> tree = load_fit("results/lab/fit.nc")  # doctest: +SKIP
    >>> write_report(tree, "results/lab/report")  # doctest: +SKIP
    PosixPath('results/lab/report/index.html')
    """
    ci_prob = _check_ci_prob(ci_prob)
    info = _check_tree(tree, ["posterior", "observed_data", "posterior_predictive"])
    if dataset is not None:
        check_dataset(tree, dataset)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    rows = summary_table(tree, ci_prob=ci_prob)
    write_summary(rows, out_dir)

    data_info = info.get("data") or {}
    conv = info.get("convergence") or {}
    point = info.get("map") or {}
    noise_floor = data_info.get("noise_floor_m")
    noise_floor = float(noise_floor) if noise_floor is not None else None
    if dataset is not None and dataset.n_trials > 1:
        noise_floor = dataset.noise_floor_m

    paths = {name: out_dir / f"{name}.png" for name in ("trace", "rank", "pair", "ppc",
                                                          "residual")}
    trace_note = _trace_figure(tree, paths["trace"], {r["name"]: r["unit"] for r in rows})
    rank_thin, rank_note = _rank_figure(tree, paths["rank"])
    n_pair = _pair_figure(tree, paths["pair"], rows)
    pred = _predictive(tree, ci_prob)
    _ppc_figure(pred, paths["ppc"], ci_prob)
    rms_median = _residual_figure(pred, noise_floor, paths["residual"])
    coverage = pred["coverage"]
    del pred

    post = tree["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    pct = f"{100 * ci_prob:.4g}%"
    captions = {
        "trace": (
            f"Trace of every walker ({n_chain} chains × {n_draw} draws after burn-in and "
            "thinning) and the pooled marginal density."
            + (f" {trace_note}" if trace_note else "")
        ),
        "rank": (
            "Fractional-rank Δ-ECDF per walker (ArviZ multi-chain test); curves should "
            "overlap around zero"
            + (f", draws thinned by {rank_thin} for the test." if rank_thin > 1 else ".")
            + (f" {rank_note}" if rank_note else "")
        ),
        "pair": (
            f"Corner plot of {n_pair} evenly spaced draws: MAP (black ×, solid line), paper "
            "value (red ○, dashed line; an arrow-head at the edge when off scale)."
        ),
        "ppc": (
            f"Posterior predictive check: data (black), {pct} predictive band pooled over "
            "draws and trials (blue), median model (red); right: the fast end of the run; "
            "bottom: the same on the residual scale."
        ),
        "residual": (
            f"Trial-mean residual against the posterior median model (RMS {rms_median:.3g} "
            "µm) and the trial-mean noise floor (green)."
        ),
    }

    source = _source_name(info, dataset)
    title = f"pmabayes fit report: {Path(source).name}"
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        _meta_block(info, source),
        _banner(conv),
    ]
    if data_info.get("synthetic"):
        parts.append(
            '<p class="note"><strong>Synthetic data.</strong> These measurements were '
            "simulated, not measured on hardware; the estimates say nothing about a "
            "real actuator.</p>"
        )
    parts.append(f"<h2>Parameters</h2><p>Posterior mean, sd and {pct} highest density "
                 "interval over all walkers; R-hat is ArviZ's rank-normalised split R-hat "
                 "over walkers; ESS (tau) is the autocorrelation-time ESS used for the "
                 "convergence decision.</p>")
    parts.append(_table(
        _display_headers(rows),
        [[r["name"], r.get("unit") or "\u2014"] + [r.get(k) for k, _ in _DISPLAY[2:]]
         for r in rows],
        num_from=2,
    ))
    fixed = (info.get("model") or {}).get("fixed") or {}
    if fixed:
        units = _units(info)
        parts.append("<p>Fixed: " + ", ".join(
            f"<code>{html.escape(k)}</code> = {html.escape(_fmt(v))} "
            f"{html.escape(units.get(k, ''))}" for k, v in fixed.items()) + "</p>")

    parts.append("<h2>Fit quality</h2>")
    gs = point.get("global_search") or {}
    map_cost = _opt_float(point, "rms_cost_m")
    ratio = (
        f"{map_cost / noise_floor:.3g}"
        if map_cost is not None and noise_floor and math.isfinite(noise_floor)
        else None
    )
    quality = [
        ["the paper's cost (RMS of trial mean − model) at the MAP", _um(map_cost)],
        ["trial-mean noise floor (a perfect model's RMS cost)", _um(noise_floor)],
        ["MAP cost / noise floor", ratio],
        ["the paper's cost at the paper-style global search optimum",
         _um(_opt_float(gs, "rms_cost_m"))],
        ["RMS of trial mean − posterior median model", _um(rms_median * 1e-6)],
        [f"data inside the {pct} posterior predictive band", f"{100 * coverage:.1f}%"],
        ["log posterior at the MAP", _opt_float(point, "log_posterior")],
    ]
    parts.append(_table(["quantity", "value"], quality))

    parts.append("<h2>Convergence</h2>")
    parts.append(_table(["setting", "value"], [
        ["independent ensembles", conv.get("n_ensembles")],
        ["walkers per ensemble", conv.get("n_walkers")],
        ["steps per ensemble", conv.get("n_steps")],
        ["burn-in (steps)", conv.get("burn")],
        ["thin", conv.get("thin")],
        ["chains × draws kept", f"{n_chain} × {n_draw}"],
        ["required steps / tau (tau multiple)", conv.get("tau_multiple")],
        ["required ESS (min ESS)", conv.get("min_ess")],
    ]))
    parts.append(_table(
        ["parameter", "tau [steps]", "ESS (tau)", "R-hat (fit)", "R-hat (ensembles)"],
        [[n, _opt_float(conv.get("tau"), n), _opt_float(conv.get("ess"), n),
          _opt_float(conv.get("rhat"), n), _opt_float(conv.get("rhat_ensembles"), n)]
         for n in post.data_vars],
    ))
    timings = info.get("timings_s") or {}
    if timings:
        parts.append("<h2>Timings</h2>")
        parts.append(_table(["stage", "time [s]"], [[k, v] for k, v in timings.items()]))

    parts.append("<h2>Figures</h2>")
    for name, path in paths.items():
        parts.append(_img(path, f"{name} plot", captions[name]))
    parts.append("</body></html>")
    index = out_dir / "index.html"
    index.write_text("\n".join(parts) + "\n", encoding="utf-8")
    return index


def _meta_block(info: dict, source: str) -> str:
    d = info.get("data") or {}
    m = info.get("model") or {}
    noise = (info.get("noise") or {}).get("model")
    items = [
        f"data: <code>{html.escape(source)}</code>",
        f"{d.get('n_trials', '?')} trials × {d.get('n_samples', '?')} samples"
        + (f" at {1.0 / d['dt_s']:.4g} Hz" if d.get("dt_s") else ""),
        f"input: {html.escape(str(d.get('input_name', '?')))}",
        "effects: " + html.escape(", ".join(m.get("effects") or []) or "none"),
    ]
    if noise:
        items.append(f"noise: {html.escape(str(noise))}")
    items.append(f"pmabayes {html.escape(str(info.get('pmabayes_version', '?')))}, "
                 f"seed {html.escape(str(info.get('seed')))}")
    return '<p class="meta">' + " · ".join(items) + "</p>"


def _banner(conv: Mapping) -> str:
    messages = [str(m) for m in conv.get("messages") or []]
    listed = "".join(f"<li>{html.escape(m)}</li>" for m in messages)
    listed = f"<ul>{listed}</ul>" if listed else ""
    if conv.get("converged") is True:
        return f'<div class="banner ok">Sampling converged.{listed}</div>'
    return (
        '<div class="banner bad" id="not-converged"><strong>NOT CONVERGED.</strong> '
        "The sampler did not meet its convergence criteria; the intervals below are not "
        f"reliable.{listed}</div>"
    )


# ------------------------------------------------------------------- model criticism


def _page(title: str, body: Sequence[str]) -> str:
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>", f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>", *body, "</body></html>",
    ]) + "\n"


def _synthetic_note(dataset: Dataset) -> str:
    if not dataset.metadata.get("synthetic"):
        return ""
    return ('<p class="note"><strong>Synthetic data.</strong> These measurements were '
            "simulated, not measured on hardware.</p>")


def _band_rows(rows) -> list[list[Any]]:
    out = []
    for b in rows:
        out.append([b.label, b.rms_m * 1e6, b.nrms, b.max_m * 1e6, b.floor_m * 1e6, b.ratio])
    return out


_BAND_HEADER = ["band", "RMS [µm]", "normalised RMS", "max [µm]", "floor [µm]", "RMS / floor"]


def write_diagnosis(diagnosis, out_dir: str | Path) -> Path:
    """Write the figures, ``diagnosis.json`` and an HTML page of a diagnosis.

    Parameters
    ----------
    diagnosis : pmabayes.criticism.Diagnosis
        The result of :func:`pmabayes.criticism.diagnose`.
    out_dir : str or Path
        Destination folder, created if needed. Written: ``comparison.png``,
        ``bands.png``, ``signature.png``, ``whiteness.png``, ``ranking.png``,
        ``diagnosis.json`` and ``index.html``.

    Returns
    -------
    Path
        The path of ``index.html`` (self-contained: figures embedded).
    """
    import json

    import matplotlib.pyplot as plt

    from pmabayes.plots import (
        plot_band_errors,
        plot_comparison,
        plot_ranking,
        plot_residual_signature,
        plot_whiteness,
    )

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    d = diagnosis
    ds = d.dataset
    label = " + ".join(["base", *d.model.effect_names])
    x = d.simulation.position_m[0]
    e = d.innovations
    rate = np.gradient(ds.input[0], ds.time_s)
    figs = {
        "comparison": (plot_comparison(ds, x, label=f"{label} (MAP)"),
                       "Trials, their mean and the model at its MAP; the residual beside the "
                       "noise floor; the hysteresis loop."),
        "bands": (plot_band_errors({label: d.signature.bands}),
                  "RMS error of the trial mean per band of the chirp's instantaneous "
                  "frequency, with the noise floor (black): the error a perfect model would "
                  "have, from the spread between the trials."),
        "signature": (plot_residual_signature(ds, d.simulation, label=label),
                      "Where the model fails: the residual against time, frequency, velocity, "
                      "pressure and position."),
        "whiteness": (plot_whiteness({label: e}, rate, ds.dt_s),
                      "Whiteness and independence tests: the residual whitened by the noise "
                      "model should stay inside the bounds at almost every lag."),
        "ranking": (plot_ranking(d.ranking, level=d.settings["level"]),
                    "Score-test evidence that each candidate effect is missing (red: "
                    "significant)."),
    }
    for name, (fig, _) in figs.items():
        fig.savefig(out_dir / f"{name}.png", dpi=_PNG_DPI)
        plt.close(fig)
    summary = d.to_dict()
    (out_dir / "diagnosis.json").write_text(json.dumps(summary, indent=2) + "\n")
    sig = d.signature
    cls = "ok" if d.adequate and d.missing is None else "bad"
    body = [
        f'<p class="meta">data: <code>{html.escape(ds.source or "(in memory)")}</code> · '
        f"{ds.n_trials} trials × {ds.n_samples} samples · model: {html.escape(label)} · "
        f"seed {html.escape(str(d.settings.get('seed')))}</p>",
        _synthetic_note(ds),
        f'<div class="banner {cls}">{html.escape(d.verdict)}</div>',
        "<h2>Compare: error against the noise floor</h2>",
        _table(_BAND_HEADER, _band_rows(sig.bands)),
        f"<p>Whitened residual: energy {sig.energy:.4g} (1 for pure noise, p = "
        f"{sig.energy_p:.2g}); Ljung-Box p = {sig.ljung_box_p:.2g}. "
        f"Adequate: <strong>{'yes' if d.adequate else 'no'}</strong>.</p>",
        "<h2>See where it fails</h2>", f"<p>{html.escape(sig.describe())}</p>",
        "<h2>What is missing: the candidate effects</h2>",
        "<p>Refitted candidates first (by leave-one-trial-out ELPD), then the others by "
        "score statistic. Estimates and intervals of refitted candidates come from the "
        f"refit's MAP and Laplace draws ({d.settings['ci_prob']:.0%} intervals); the others "
        "are the score test's one-step values.</p>",
        _table(["effect", "evidence", "p", "significant", "estimate", "interval",
                "explained", "ΔELPD ± se"],
               [[f.effect, f.evidence, f.p_value, "yes" if f.significant else "no",
                 ", ".join(f"{k} = {_fmt(v)}" for k, v in f.estimate.items()),
                 ", ".join(f"{_fmt(a)} to {_fmt(b)}" for a, b in f.interval.values()),
                 f"{f.explained:.0%}",
                 f"{f.refit.elpd_diff:+.1f} ± {f.refit.elpd_diff_se:.1f}" if f.refit else "—"]
                for f in d.ranking], num_from=1),
    ]
    for f in d.ranking:
        if f.significant:
            body.append(f"<h3>{html.escape(f.effect)}</h3><p>{html.escape(f.explanation)}</p>")
    body.append("<h2>Figures</h2>")
    for name, (_, caption) in figs.items():
        body.append(_img(out_dir / f"{name}.png", f"{name} plot", caption))
    index = out_dir / "index.html"
    index.write_text(_page(f"pmabayes diagnosis: {Path(ds.source or 'data').name}", body),
                     encoding="utf-8")
    return index


def write_comparison(comparison, out_dir: str | Path, *, dataset: Dataset | None = None
                     ) -> Path:
    """Write the error-falling figure, tables and an HTML page of a fit comparison.

    Parameters
    ----------
    comparison : pmabayes.criticism.FitComparison
        From :func:`pmabayes.criticism.compare_fits`.
    out_dir : str or Path
        Destination folder. Written: ``error_falling.png``, ``whiteness.png``,
        ``comparison.json``, ``comparison.md`` and ``index.html``.
    dataset : Dataset, optional
        The data, to name it and mark it synthetic.

    Returns
    -------
    Path
        The path of ``index.html``.
    """
    import json

    import matplotlib.pyplot as plt

    from pmabayes.plots import plot_band_errors, plot_whiteness

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    c = comparison
    fig = plot_band_errors(c.bands, title="the error falls as effects are added "
                                           "(label: multiple of the noise floor)")
    fig.savefig(out_dir / "error_falling.png", dpi=_PNG_DPI)
    plt.close(fig)
    fig = plot_whiteness(c.innovations, c.command_rate, c.dt_s)
    fig.savefig(out_dir / "whiteness.png", dpi=_PNG_DPI)
    plt.close(fig)
    (out_dir / "comparison.json").write_text(json.dumps(c.to_dict(), indent=2) + "\n")
    band_names = [b.label for b in c.bands[c.labels[0]]]
    header = ["fit", *[f"RMS {b} [µm]" for b in band_names], "RMS / floor",
              "Ljung-Box p", "energy", "ELPD (LOO)", "ΔELPD vs best ± se"]
    rows = [[k, *[b.rms_m * 1e6 for b in c.bands[k]], c.bands[k][-1].ratio,
             c.whiteness[k]["ljung_box_p"], c.whiteness[k]["energy"], c.elpd[k]["elpd"],
             f"{c.elpd[k]['elpd_diff']:.1f} ± {c.elpd[k]['dse']:.1f}"] for k in c.labels]
    rows.append(["noise floor", *[b.floor_m * 1e6 for b in c.bands[c.labels[0]]], 1.0,
                 "", "", "", ""])
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in rows]
    md += ["", "| step | ΔELPD | se |", "|---|---|---|"]
    md += [f"| {s['from']} → {s['to']} | {s['elpd_diff']:+.1f} | {s['se']:.1f} |"
           for s in c.elpd_steps]
    (out_dir / "comparison.md").write_text("\n".join(md) + "\n")
    name = Path(dataset.source).name if dataset is not None and dataset.source else "data"
    body = [
        f'<p class="meta">{len(c.labels)} fits of <code>{html.escape(name)}</code></p>',
        _synthetic_note(dataset) if dataset is not None else "",
        "<h2>Error per frequency band, whiteness and ELPD</h2>",
        _table(header, rows),
        "<h2>Each step</h2>",
        _table(["step", "ΔELPD (leave one trial out)", "se"],
               [[f"{s['from']} → {s['to']}", s["elpd_diff"], s["se"]] for s in c.elpd_steps]),
        _img(out_dir / "error_falling.png", "error falling",
             "RMS error of the trial mean per frequency band for each fit, with the noise "
             "floor (black)."),
        _img(out_dir / "whiteness.png", "whiteness",
             "Whitened residual of each fit: autocorrelation and cross-correlation with the "
             "command's rate, against the bounds for a white residual."),
    ]
    index = out_dir / "index.html"
    index.write_text(_page(f"pmabayes comparison: {name}", body), encoding="utf-8")
    return index
