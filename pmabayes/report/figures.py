"""Figures: the model beside the measurements, and the figures of every report.

Stage 8 (reports). Every figure of pmabayes is drawn here, from results that are
passed in: data sets, simulations, band errors, correlation curves, rankings,
predictive bands, posterior draws. Nothing here simulates, fits or computes a
statistic (those come from :mod:`pmabayes.criticism.residuals`, :mod:`pmabayes.criticism.diagnosis`,
:mod:`pmabayes.report.pages` and :mod:`pmabayes.control.robustness`).

The library never picks a matplotlib backend: figures are
:class:`matplotlib.figure.Figure` objects, saved with ``fig.savefig`` (which needs
no display and no pyplot), so inline figures in notebooks keep working. Only the
ArviZ trace and rank plots go through pyplot, inside their functions, and close
what they open.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import arviz as az
import matplotlib
import numpy as np
import xarray as xr
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from pmabayes.control import CONTROLLERS, ClosedLoop
from pmabayes.control.robustness import summarise_robustness
from pmabayes.data import Dataset

__all__ = [
    "plot_comparison",
    "plot_band_errors",
    "plot_residual_signature",
    "plot_whiteness",
    "plot_ranking",
    "plot_figure5",
    "plot_robustness",
    "plot_trace",
    "plot_rank",
    "plot_pair",
    "plot_predictive",
    "plot_residual",
    "plot_validation",
]

#: Resolution of the report's figures.
REPORT_DPI = 100
_PAIR_MAX_DRAWS = 2000
_RANK_MAX_DRAWS = 100  # per chain: the multi-chain rank test costs O(chains x draws)
_ZOOM_S = 1.0


def __getattr__(name: str):
    # ``from pmabayes.report.figures import plt`` worked while this module imported pyplot; it is
    # kept for old scripts, loaded only when asked for. Import matplotlib.pyplot instead.
    if name == "plt":
        import matplotlib.pyplot as plt

        return plt
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _cmap(name: str):
    return matplotlib.colormaps[name]


def plot_comparison(
    dataset: Dataset,
    model_position_m: np.ndarray,
    *,
    label: str = "model",
    path: str | Path | None = None,
) -> Figure:
    """Measured trials, their mean and the model: time series, residual and loop.

    Parameters
    ----------
    dataset : Dataset
        The measurements.
    model_position_m : numpy.ndarray
        Simulated position on the data's time grid, shape ``(n_samples,)``.
    label : str
        Legend label of the model.
    path : str or Path, optional
        Where to save the figure (format from the suffix).

    Returns
    -------
    matplotlib.figure.Figure
    """
    t = dataset.time_s
    mean = dataset.mean_position_m
    resid = mean - model_position_m
    floor = dataset.noise_floor_m
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    grid = fig.add_gridspec(3, 3)
    ax_p = fig.add_subplot(grid[0, :2])
    ax_x = fig.add_subplot(grid[1, :2], sharex=ax_p)
    ax_r = fig.add_subplot(grid[2, :2], sharex=ax_p)
    ax_loop = fig.add_subplot(grid[:, 2])

    is_pressure = dataset.input_name == "pressure_pa"
    u = dataset.input[0] / 1e6 if is_pressure else dataset.input[0]
    ax_p.plot(t, u, color="tab:gray", lw=0.8)
    ax_p.set_ylabel("pressure [MPa]" if is_pressure else "force [N]")
    for k in range(dataset.n_trials):
        ax_x.plot(t, dataset.position_m[k] * 1e3, color="tab:blue", alpha=0.15, lw=0.6)
    ax_x.plot(t, mean * 1e3, color="tab:blue", lw=1.0, label=f"trial mean (n={dataset.n_trials})")
    ax_x.plot(t, model_position_m * 1e3, color="tab:red", lw=0.9, ls="--", label=label)
    ax_x.set_ylabel("position x [mm]")
    ax_x.legend(loc="upper left", fontsize=8)
    ax_r.plot(t, resid * 1e6, color="k", lw=0.6)
    if np.isfinite(floor):
        ax_r.axhspan(-floor * 1e6, floor * 1e6, color="tab:green", alpha=0.25,
                     label=f"noise floor ±{floor * 1e6:.1f} µm")
        ax_r.legend(loc="upper left", fontsize=8)
    rms = float(np.sqrt(np.mean(resid**2)))
    ax_r.set_title(f"trial mean − {label}: RMS {rms * 1e6:.1f} µm", fontsize=9)
    ax_r.set_ylabel("residual [µm]")
    ax_r.set_xlabel("time [s]")

    ax_loop.plot(u, mean * 1e3, color="tab:blue", lw=0.7, label="trial mean")
    ax_loop.plot(u, model_position_m * 1e3, color="tab:red", lw=0.7, ls="--", label=label)
    ax_loop.set_xlabel(ax_p.get_ylabel())
    ax_loop.set_ylabel("position x [mm]")
    ax_loop.set_title("hysteresis loop", fontsize=9)
    ax_loop.legend(loc="upper left", fontsize=8)
    src = dataset.source or "data"
    tag = " (synthetic)" if dataset.metadata.get("synthetic") else ""
    fig.suptitle(f"{Path(src).name}{tag}: measurement and {label}", fontsize=11)
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def plot_band_errors(
    errors: dict,
    *,
    title: str = "",
    path: str | Path | None = None,
) -> Figure:
    """RMS error per frequency band for one or more models, beside the noise floor.

    The bands are those of :func:`pmabayes.criticism.bands.band_errors` (spectral, for
    any input); with a single trial there is no floor and no ratio to draw.

    Parameters
    ----------
    errors : dict
        Label to a list of :class:`pmabayes.criticism.bands.BandErrors` (same bands for
        every label, the last one overall), in the order to draw them: for
        example base, base + one effect, base + two effects.
    title : str
        Figure title.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    labels = list(errors)
    bands = errors[labels[0]]
    fig = Figure(figsize=(8.5, 4.6), layout="constrained")
    ax = fig.subplots()
    width = 0.8 / len(labels)
    xs = np.arange(len(bands))
    cmap = _cmap("viridis")
    for i, label in enumerate(labels):
        rms = [b.rms_m * 1e6 for b in errors[label]]
        bars = ax.bar(xs - 0.4 + width * (i + 0.5), rms, width,
                      color=cmap(i / max(len(labels) - 1, 1)), label=label)
        for bar, row in zip(bars, errors[label], strict=True):
            if not np.isfinite(row.ratio):  # one trial: no floor to compare with
                continue
            ax.annotate(f"{row.ratio:.3g}x", (bar.get_x() + bar.get_width() / 2,
                                               bar.get_height()),
                        ha="center", va="bottom", fontsize=7, rotation=90,
                        xytext=(0, 2), textcoords="offset points")
    floors = [b.floor_m * 1e6 for b in errors[labels[0]]]
    for x, f in zip(xs, floors, strict=True):
        if np.isfinite(f):
            ax.hlines(f, x - 0.45, x + 0.45, color="k", lw=2,
                      label="noise floor" if x == 0 else None)
    ax.set_yscale("log")
    ax.set_xticks(xs, [b.label for b in errors[labels[0]]])
    ax.set_xlabel("frequency band (octaves over the band the input excites; from the spectra "
                  "of the residual and of the deviations between trials)", fontsize=8)
    ax.set_ylabel("RMS error of the trial mean [µm]")
    ax.set_title(title or "error per frequency band (label: multiple of the floor)",
                 fontsize=10)
    fig.legend(loc="outside lower center", ncol=min(len(labels) + 1, 3), fontsize=8)
    ax.margins(y=0.25)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_residual_signature(
    dataset: Dataset,
    simulation,
    frequency_hz: np.ndarray,
    *,
    label: str = "model",
    path: str | Path | None = None,
) -> Figure:
    """The trial-mean residual against time, frequency, velocity, pressure and position.

    Parameters
    ----------
    dataset : Dataset
        The data.
    simulation : pmabayes.model.simulator.Simulation
        The model (batch of one) with its states.
    frequency_hz : numpy.ndarray
        Instantaneous frequency of the command at each sample
        (:func:`pmabayes.criticism.bands.instantaneous_frequency`, or
        :attr:`pmabayes.criticism.results.Diagnosis.frequency_hz`).
    label : str
        Name of the model in the title.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    resid = (dataset.mean_position_m - simulation.position_m[0]) * 1e6
    floor = dataset.noise_floor_m * 1e6
    is_pressure = dataset.input_name == "pressure_pa"
    against = [
        ("time [s]", dataset.time_s),
        ("instantaneous frequency [Hz]", np.asarray(frequency_hz)),
        ("model velocity [mm/s]", simulation.velocity_m_s[0] * 1e3),
        ("model pressure [MPa]" if is_pressure else "input force [N]",
         simulation.pressure_pa[0] / (1e6 if is_pressure else 1.0)),
        ("model position [mm]", simulation.position_m[0] * 1e3),
    ]
    fig = Figure(figsize=(15, 3.4), layout="constrained")
    axes = fig.subplots(1, 5, sharey=True)
    step = max(1, resid.size // 4000)
    for ax, (name, v) in zip(axes, against, strict=True):
        if name.startswith("time"):
            ax.plot(v, resid, color="k", lw=0.5)
        else:
            ax.scatter(v[::step], resid[::step], s=2, color="k", alpha=0.4, linewidths=0)
        ax.axhspan(-floor, floor, color="tab:green", alpha=0.3)
        ax.axhline(0.0, color="tab:gray", lw=0.5)
        ax.set_xlabel(name)
    axes[0].set_ylabel("trial mean − model [µm]")
    rms = float(np.sqrt(np.mean(resid**2)))
    fig.suptitle(f"where {label} fails: residual (RMS {rms:.3g} µm) against the noise floor "
                 f"±{floor:.3g} µm (green)", fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_whiteness(curves, *, path: str | Path | None = None) -> Figure:
    """Autocorrelation of whitened residuals and their cross-correlation with the input.

    Parameters
    ----------
    curves : pmabayes.criticism.whiteness.WhitenessCurves
        The curves, one per model (:func:`pmabayes.criticism.whiteness.whiteness_curves`,
        :meth:`pmabayes.criticism.results.Diagnosis.whiteness_curves` or
        :meth:`pmabayes.criticism.compare.FitComparison.whiteness_curves`).
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = Figure(figsize=(11, 3.6), layout="constrained")
    ax_a, ax_c = fig.subplots(1, 2)
    cmap = _cmap("viridis")
    labels = list(curves.acf)
    for i, label in enumerate(labels):
        color = cmap(i / max(len(labels) - 1, 1))
        ax_a.plot(curves.acf_lags_s * 1e3, curves.acf[label], color=color, lw=1.0,
                  label=label)
        ax_c.plot(curves.ccf_lags_s * 1e3, curves.ccf[label], color=color, lw=1.0,
                  label=label)
    for ax in (ax_a, ax_c):
        ax.axhspan(-curves.bound, curves.bound, color="tab:green", alpha=0.3,
                   label=f"{curves.level:.0%} bound (white)")
        ax.axhline(0.0, color="tab:gray", lw=0.5)
        ax.set_xlabel("lag [ms]")
        ax.legend(fontsize=7)
    ax_a.set_title("autocorrelation of the whitened residual", fontsize=10)
    ax_c.set_title("cross-correlation with the earlier command rate", fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_ranking(findings, *, threshold: float | None = None, level: float = 0.05,
                 path: str | Path | None = None) -> Figure:
    """Evidence that each candidate effect is missing.

    Parameters
    ----------
    findings : list of pmabayes.criticism.results.Finding
        The ranking of a diagnosis.
    threshold : float, optional
        The significance threshold of the score statistic, drawn as a line
        (:attr:`pmabayes.criticism.results.Diagnosis.score_threshold`); none drawn if not
        given.
    level : float
        Family-wise level of that threshold, for its legend.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    names = [f.effect for f in findings][::-1]
    values = [max(f.evidence, 1e-3) for f in findings][::-1]
    colors = ["tab:red" if f.significant else "tab:gray" for f in findings][::-1]
    fig = Figure(figsize=(7.5, 0.45 * len(names) + 1.2), layout="constrained")
    ax = fig.subplots()
    ax.barh(names, values, color=colors)
    if threshold is not None:
        ax.axvline(threshold, color="k", ls="--", lw=1,
                   label=f"significance threshold (level {level:g}, Bonferroni, 1 dof)")
        ax.legend(fontsize=7, loc="lower right")
    ax.set_xscale("log")
    ax.set_xlabel("score statistic (evidence that the effect is missing)")
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_discrepancy(discrepancy, *, path: str | Path | None = None) -> Figure:
    """The estimated missing force's partial dependence on each state.

    Parameters
    ----------
    discrepancy : pmabayes.criticism.discrepancy.Discrepancy
        The discrepancy of a diagnosis.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per state, most evidence first: the force against the state
        (centred along the trajectory) with a band of two posterior standard
        deviations, titled with the ELPD lost when the state is dropped.
    """
    states = discrepancy.states
    cols = min(3, len(states))
    rows = math.ceil(len(states) / cols)
    fig = Figure(figsize=(3.2 * cols, 2.5 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    for ax, st in zip(axes, states, strict=False):
        pd = discrepancy.partial_dependence[st.state]
        g, f, sd = pd["grid"], pd["force_n"], pd["sd_n"]
        color = "tab:red" if st.needed else "tab:gray"
        ax.fill_between(g, f - 2 * sd, f + 2 * sd, color=color, alpha=0.25, lw=0)
        ax.plot(g, f, color=color, marker="o" if g.size < 5 else None)
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel(f"{st.state} [{pd['unit']}]")
        ax.set_ylabel("force [N]")
        ax.set_title(f"{st.state}: ΔELPD {st.elpd_loss:+.1f} ± {st.se:.1f}", fontsize=8)
    for ax in axes[len(states):]:
        ax.set_visible(False)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


_CONTROLLER_STYLE = {"pid": ("C0", "$x_{FB}$ (PID)", "PID"),
                     "ct": ("C3", "$x_{CT}$ (computed torque)", "computed torque")}


def plot_figure5(run: ClosedLoop, *, path: str | Path | None = None) -> Figure:
    """The paper's Fig. 5: reference and responses per frequency, the error below each.

    Parameters
    ----------
    run : ClosedLoop
        Closed-loop runs (e.g. from :func:`pmabayes.control.reproduction.figure5`), one per
        frequency and controller.
    path : str or Path, optional
        Where to save the figure (PNG).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    freqs = list(dict.fromkeys(float(f) for f in run.frequency_hz))
    fig = Figure(figsize=(8, 3.2 * len(freqs)))
    axes = fig.subplots(2 * len(freqs), 1, sharex=True,
                        gridspec_kw={"height_ratios": [2, 1] * len(freqs)}, squeeze=False)[:, 0]
    t = run.time_s
    for k, f in enumerate(freqs):
        top, bottom = axes[2 * k], axes[2 * k + 1]
        rows = [j for j in range(len(run.controller)) if float(run.frequency_hz[j]) == f]
        top.plot(t, 1e3 * run.reference_m[rows[0]], "k--", lw=1, label="$x_d$")
        for j in rows:
            color, label, _ = _CONTROLLER_STYLE[run.controller[j]]
            top.plot(t, 1e3 * run.position_m[j], color=color, lw=1, label=label)
            bottom.plot(t, 1e3 * (run.reference_m[j] - run.position_m[j]), color=color, lw=1)
        top.set_ylabel("x [mm]")
        top.set_title(f"({'abc'[k] if k < 3 else k}) {f:g} Hz")
        bottom.set_ylabel("error [mm]")
        bottom.axhline(0, color="k", lw=0.5)
        if k == 0:
            top.legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def plot_robustness(summary, *, path: str | Path | None = None) -> Figure:
    """RMS error, phase lag and P(CT beats PID) of a robustness sweep against frequency.

    Parameters
    ----------
    summary : xarray.Dataset
        The sweep's summary (:func:`pmabayes.control.robustness.summarise_robustness`). A
        sweep itself (:func:`pmabayes.control.robustness.robustness_sweep`) is summarised by
        that function first.
    path : str or Path, optional
        Where to save the figure (PNG).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    if "p_ct_beats_pid" not in summary:
        summary = summarise_robustness(summary)
    f = summary["frequency"].values
    fig = Figure(figsize=(7, 8))
    axes = fig.subplots(3, 1, sharex=True, gridspec_kw={"height_ratios": [2, 2, 1]})
    for c in CONTROLLERS:
        color, _, label = _CONTROLLER_STYLE[c]
        for ax, m, scale in ((axes[0], "rms_error_m", 1e3), (axes[1], "phase_lag_deg", 1.0)):
            s = summary.sel(controller=c)
            ax.fill_between(f, scale * s[f"{m}_q05"], scale * s[f"{m}_q95"], color=color,
                            alpha=0.25, lw=0)
            ax.plot(f, scale * s[f"{m}_median"], "o-", color=color, label=f"{label} (median, "
                    "90% band)")
    axes[0].set_ylabel("RMS error [mm]")
    axes[0].legend(fontsize=8)
    axes[1].set_ylabel("phase lag [deg]")
    axes[2].errorbar(f, summary["p_ct_beats_pid"], yerr=summary["p_ct_beats_pid_mc_error"],
                     fmt="ko-", capsize=2)
    axes[2].set_ylim(-0.05, 1.05)
    axes[2].set_ylabel("P(CT beats PID)")
    axes[2].set_xlabel("reference frequency [Hz]")
    axes[2].set_xscale("log")
    axes[2].set_xticks(f, [f"{v:.2g}" for v in f], minor=False)
    axes[2].minorticks_off()
    axes[0].set_title(f"{summary.attrs.get('samples')} posterior samples, mode "
                      f"'{summary.attrs.get('mode')}'")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


# ------------------------------------------------------------------ report figures


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
        A fit (layout of :mod:`pmabayes.inference.posterior`).
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
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    path : str or Path
        Where to save the figure.
    rows : sequence of dict
        Summary rows (:func:`pmabayes.report.pages.summary_table`): ``name``, ``unit``,
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


def _zoom_slice(t: np.ndarray) -> slice:
    """The last ``_ZOOM_S`` seconds (the chirp's fast end), at most a quarter of the run."""
    span = float(t[-1] - t[0])
    width = min(_ZOOM_S, 0.25 * span)
    return slice(int(np.searchsorted(t, t[-1] - width)), None)


def plot_predictive(pred: Mapping[str, np.ndarray], path: str | Path, *, ci_prob: float
                    ) -> None:
    """Posterior predictive check: one pair of panels per trial, residual-scale panels.

    Parameters
    ----------
    pred : mapping
        The predictive band of :func:`pmabayes.report.pages.predictive_band` (``time``,
        ``trials``, ``data``, ``median``, ``low``, ``high``, ``coverage``).
    path : str or Path
        Where to save the figure.
    ci_prob : float
        Probability of the band, for the labels.
    """
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
    fig.savefig(path, dpi=REPORT_DPI)


def plot_validation(experiment, *, path: str | Path | None = None) -> Figure:
    """A held-out experiment: measurement, the posterior's prediction and its band.

    Parameters
    ----------
    experiment : pmabayes.criticism.validation.ExperimentValidation
        One experiment of :func:`pmabayes.criticism.validation.validate`.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
        Top: every trial (grey), the predictive band (blue, the model's draws plus the
        fit's noise) and the posterior-mean prediction (red), with the run's end
        enlarged; bottom: the same less the prediction, with the trial mean (black).
    """
    e = experiment
    t, data, pred = e.time_s, e.position_m, e.prediction_m
    lo, hi = e.low_m, e.high_m
    z = _zoom_slice(t)
    pct = f"{100 * e.ci_prob:.4g}%"
    fig = Figure(figsize=(12, 6), layout="constrained")
    axes = fig.subplots(2, 2, width_ratios=(3, 1))
    alpha = float(np.clip(2.0 / e.n_trials, 0.15, 0.8))
    for col, s in enumerate((slice(None), z)):
        top, bottom = axes[0, col], axes[1, col]
        top.fill_between(t[s], lo[s] * 1e3, hi[s] * 1e3, color="tab:blue", alpha=0.35, lw=0,
                         label=f"{pct} predictive band")
        for r in range(e.n_trials):
            top.plot(t[s], data[r, s] * 1e3, color="0.3", lw=0.5, alpha=alpha,
                     label="measured trials" if r == 0 else None)
        top.plot(t[s], pred[s] * 1e3, color="tab:red", lw=0.8, ls="--",
                 label="posterior-mean prediction")
        bottom.fill_between(t[s], (lo[s] - pred[s]) * 1e6, (hi[s] - pred[s]) * 1e6,
                            color="tab:blue", alpha=0.3, lw=0)
        for r in range(e.n_trials):
            bottom.plot(t[s], (data[r, s] - pred[s]) * 1e6, color="0.3", lw=0.4, alpha=alpha)
        if e.n_trials > 1:
            bottom.plot(t[s], (data[:, s].mean(axis=0) - pred[s]) * 1e6, color="k", lw=0.8,
                        label="trial mean − prediction")
        bottom.axhline(0.0, color="tab:red", lw=0.7, ls="--")
        bottom.set_xlabel("time [s]")
        for a in (top, bottom):
            a.tick_params(labelsize=8)
    axes[0, 0].set_ylabel("x [mm]")
    axes[1, 0].set_ylabel("minus prediction [µm]")
    axes[0, 0].legend(fontsize=7, loc="upper left", ncols=3)
    if e.n_trials > 1:
        axes[1, 0].legend(fontsize=7, loc="upper left")
    axes[0, 1].set_title(f"last {t[-1] - t[z][0]:.2g} s", fontsize=9, loc="left")
    floor = ("no floor (one trial)" if e.noise_floor_m is None
             else f"{e.ratio_to_floor:.3g}× floor")
    axes[0, 0].set_title(
        f"{e.name}: RMSE {e.rmse_m * 1e6:.3g} µm ({floor}), NRMSE {e.nrmse:.3g}, "
        f"{100 * e.band_coverage:.1f}% of the samples inside the {pct} band",
        fontsize=9, loc="left")
    if path is not None:
        fig.savefig(path, dpi=REPORT_DPI)
    return fig
