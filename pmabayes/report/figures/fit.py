"""Figures of a fit's report: trace, rank and corner plots of the posterior draws, the
posterior predictive check, and the residual against the noise floor.
"""

from __future__ import annotations

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

from pmabayes.report.figures.common import REPORT_DPI, shade_gaps, zoom_slice

__all__ = ["plot_trace", "plot_rank", "plot_pair", "plot_predictive", "plot_residual"]


_PAIR_MAX_DRAWS = 2000


_RANK_MAX_DRAWS = 100  # per chain: the multi-chain rank test costs O(chains x draws)


def _draws(tree: xr.DataTree, name: str) -> np.ndarray:
    """A posterior variable as a ``(chain, draw)`` float array."""
    return np.asarray(tree["posterior"][name].transpose("chain", "draw").values, dtype=float)


def _save_arviz(make: Callable[[], Any], path: Path) -> None:
    """Draw an ArviZ plot (matplotlib backend), save it and close its pyplot figures.

    Figures the call opened are closed even when it fails, and only those.
    """
    import matplotlib.pyplot as plt  # ArviZ draws through pyplot

    before = set(plt.get_fignums())
    try:
        fig = make().get_viz("figure")
        fig = fig.item() if hasattr(fig, "item") else fig
        fig.savefig(path, dpi=REPORT_DPI)
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


def plot_trace(tree: xr.DataTree, path: str | Path, *, units: Mapping[str, str]) -> str | None:
    """Trace and marginal of every posterior variable (ArviZ, or matplotlib if ArviZ fails).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    path : str or Path
        Where to save the figure.
    units : mapping
        Variable name to SI unit, to scale small lengths to µm.

    Returns
    -------
    str or None
        A note when the matplotlib fallback was used.
    """
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
    fig.savefig(path, dpi=REPORT_DPI)
    return note


def plot_rank(tree: xr.DataTree, path: str | Path) -> tuple[int, str | None]:
    """Rank (fractional-rank Δ-ECDF) plots per walker (ArviZ, or matplotlib if it fails).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`); its draws per walker.
    path : str or Path
        Where to save the figure.

    Returns
    -------
    factor : int
        The thinning of the draws for the test.
    note : str or None
        A note when the matplotlib fallback was used.
    """
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
    fig.savefig(path, dpi=REPORT_DPI)
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


def plot_pair(tree: xr.DataTree, path: str | Path, rows: Sequence[Mapping],
              names: Sequence[str] | None = None) -> int:
    """Corner plot of posterior draws with the MAP and the paper's values marked.

    Values off the plotted range are marked by arrow-heads on the edge.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`); its pooled draws.
    path : str or Path
        Where to save the figure.
    rows : sequence of dict
        Summary rows (:func:`pmabayes.report.summary.summary_table`): ``name``, ``unit``,
        ``map`` and ``paper`` of each variable.
    names : sequence of str, optional
        Variables to show, in order; all by default.

    Returns
    -------
    int
        The number of draws shown (at most 2000, evenly thinned).
    """
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
    fig.savefig(path, dpi=REPORT_DPI)
    return int(keep.size)


def plot_predictive(pred: Mapping[str, np.ndarray], path: str | Path, *, ci_prob: float
                    ) -> None:
    """Posterior predictive check: one pair of panels per trial, residual-scale panels.

    Parameters
    ----------
    pred : mapping
        The predictive band of :func:`pmabayes.report.fit_data.predictive_band` (``time``,
        ``trials``, ``data``, ``median``, ``low``, ``high``, ``coverage``).
    path : str or Path
        Where to save the figure.
    ci_prob : float
        Probability of the band, for the labels.
    """
    t, data, med, lo, hi = (pred[k] for k in ("time", "data", "median", "low", "high"))
    n_trial = data.shape[0]
    z = zoom_slice(t)
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
        lo_r, hi_r, med_r = (v[r] if v.ndim == 2 else v for v in (lo, hi, med))
        for a, s in ((ax, slice(None)), (axz, z)):
            shade_gaps(a, t[s], np.isfinite(data[r, s]))
            a.fill_between(t[s], lo_r[s] * 1e3, hi_r[s] * 1e3, color="tab:blue", alpha=0.35,
                           lw=0, label=f"{pct} predictive")
            a.plot(t[s], data[r, s] * 1e3, color="k", lw=0.5, label="data")
            a.plot(t[s], med_r[s] * 1e3, color="tab:red", lw=0.7, ls="--",
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
    if med.ndim == 2:  # trials with their own inputs: the first trial's band on this scale
        lo, hi = lo[0] - med[0], hi[0] - med[0]
        resid = data - med
        med = np.zeros_like(lo)
    else:
        resid = data - med
    for a, s in ((axr, slice(None)), (axrz, z)):
        shade_gaps(a, t[s], np.isfinite(data[:, s]).any(axis=0))
        a.fill_between(t[s], (lo[s] - med[s]) * 1e6, (hi[s] - med[s]) * 1e6,
                       color="tab:blue", alpha=0.3, lw=0, label=f"{pct} predictive − median")
        for r in range(n_trial):
            a.plot(t[s], resid[r, s] * 1e6, lw=0.4, alpha=alpha, color="0.2",
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
    fig.savefig(path, dpi=REPORT_DPI)


def plot_residual(time_s: np.ndarray, residual_m: np.ndarray, rms_m: float,
                  noise_floor_m: float | None, path: str | Path) -> None:
    """The trial-mean residual against a model, with the noise floor, and its fast end.

    Parameters
    ----------
    time_s : numpy.ndarray
        Sample times.
    residual_m : numpy.ndarray
        Trial mean minus the model.
    rms_m : float
        Its RMS, for the legend.
    noise_floor_m : float or None
        The trial-mean noise floor, drawn as a band when known.
    path : str or Path
        Where to save the figure.
    """
    t = time_s
    resid = np.asarray(residual_m) * 1e6
    rms = rms_m * 1e6
    z = zoom_slice(t)
    fig = Figure(figsize=(12, 3.4), layout="constrained")
    ax, axz = fig.subplots(1, 2, width_ratios=(3, 1), sharey=True)
    for a, s in ((ax, slice(None)), (axz, z)):
        shade_gaps(a, t[s], np.isfinite(resid[s]))
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
    fig.savefig(path, dpi=REPORT_DPI)
