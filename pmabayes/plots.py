"""Figures: the model beside the measurements.

Stage 8 (reports). Functions take arrays and data sets, return a matplotlib
figure, and save it when given a path; they never simulate or fit themselves.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pmabayes.control import CONTROLLERS, ClosedLoop  # noqa: E402
from pmabayes.criticism import (  # noqa: E402
    autocorrelation,
    band_label,
    cross_correlation,
    instantaneous_frequency,
)
from pmabayes.data import Dataset  # noqa: E402
from pmabayes.robustness import summarise_robustness  # noqa: E402

__all__ = [
    "plot_comparison",
    "plot_band_errors",
    "plot_residual_signature",
    "plot_whiteness",
    "plot_ranking",
    "plot_figure5",
    "plot_robustness",
]


def plot_comparison(
    dataset: Dataset,
    model_position_m: np.ndarray,
    *,
    label: str = "model",
    path: str | Path | None = None,
) -> plt.Figure:
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
    fig = plt.figure(figsize=(11, 7.5), layout="constrained")
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
) -> plt.Figure:
    """RMS error per frequency band for one or more models, beside the noise floor.

    Parameters
    ----------
    errors : dict
        Label to a list of :class:`pmabayes.criticism.BandError` (same bands for
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
    bands = [b.band_hz for b in errors[labels[0]]]
    fig, ax = plt.subplots(figsize=(8.5, 4.6), layout="constrained")
    width = 0.8 / len(labels)
    xs = np.arange(len(bands))
    cmap = plt.get_cmap("viridis")
    for i, label in enumerate(labels):
        rms = [b.rms_m * 1e6 for b in errors[label]]
        bars = ax.bar(xs - 0.4 + width * (i + 0.5), rms, width,
                      color=cmap(i / max(len(labels) - 1, 1)), label=label)
        for bar, row in zip(bars, errors[label], strict=True):
            ax.annotate(f"{row.ratio:.3g}x", (bar.get_x() + bar.get_width() / 2,
                                               bar.get_height()),
                        ha="center", va="bottom", fontsize=7, rotation=90,
                        xytext=(0, 2), textcoords="offset points")
    floors = [b.floor_m * 1e6 for b in errors[labels[0]]]
    for x, f in zip(xs, floors, strict=True):
        ax.hlines(f, x - 0.45, x + 0.45, color="k", lw=2,
                  label="noise floor" if x == 0 else None)
    ax.set_yscale("log")
    ax.set_xticks(xs, [band_label(b) for b in bands])
    ax.set_xlabel("instantaneous frequency of the chirp")
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
    *,
    label: str = "model",
    path: str | Path | None = None,
) -> plt.Figure:
    """The trial-mean residual against time, frequency, velocity, pressure and position.

    Parameters
    ----------
    dataset : Dataset
        The data.
    simulation : pmabayes.simulator.Simulation
        The model (batch of one) with its states.
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
        ("instantaneous frequency [Hz]", instantaneous_frequency(dataset)),
        ("model velocity [mm/s]", simulation.velocity_m_s[0] * 1e3),
        ("model pressure [MPa]" if is_pressure else "input force [N]",
         simulation.pressure_pa[0] / (1e6 if is_pressure else 1.0)),
        ("model position [mm]", simulation.position_m[0] * 1e3),
    ]
    fig, axes = plt.subplots(1, 5, figsize=(15, 3.4), layout="constrained", sharey=True)
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


def plot_whiteness(
    innovations: dict,
    command_rate: np.ndarray,
    dt_s: float,
    *,
    max_lag_s: float = 0.2,
    level: float = 0.99,
    path: str | Path | None = None,
) -> plt.Figure:
    """Autocorrelation of the whitened residual and its cross-correlation with the input.

    Parameters
    ----------
    innovations : dict
        Label to whitened residual (:func:`pmabayes.criticism.innovations`), one
        curve per model.
    command_rate : numpy.ndarray
        Rate of change of the commanded input.
    dt_s : float
        Sample interval.
    max_lag_s : float
        Largest lag shown.
    level : float
        Confidence level of the bounds for a white, independent residual.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    max_lag = max(1, int(round(max_lag_s / dt_s)))
    fig, (ax_a, ax_c) = plt.subplots(1, 2, figsize=(11, 3.6), layout="constrained")
    cmap = plt.get_cmap("viridis")
    labels = list(innovations)
    bound = 0.0
    for i, label in enumerate(labels):
        e = innovations[label]
        color = cmap(i / max(len(labels) - 1, 1))
        lags, acf, bound = autocorrelation(e, max_lag=max_lag, level=level)
        ax_a.plot(lags * dt_s * 1e3, acf, color=color, lw=1.0, label=label)
        lags_c, ccf, _ = cross_correlation(e, command_rate, max_lag=max_lag, level=level)
        ax_c.plot(lags_c * dt_s * 1e3, ccf, color=color, lw=1.0, label=label)
    for ax in (ax_a, ax_c):
        ax.axhspan(-bound, bound, color="tab:green", alpha=0.3,
                   label=f"{level:.0%} bound (white)")
        ax.axhline(0.0, color="tab:gray", lw=0.5)
        ax.set_xlabel("lag [ms]")
        ax.legend(fontsize=7)
    ax_a.set_title("autocorrelation of the whitened residual", fontsize=10)
    ax_c.set_title("cross-correlation with the earlier command rate", fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_ranking(findings, *, level: float = 0.05, path: str | Path | None = None
                 ) -> plt.Figure:
    """Evidence that each candidate effect is missing.

    Parameters
    ----------
    findings : list of pmabayes.criticism.Finding
        The ranking of a diagnosis.
    level : float
        Family-wise level; the Bonferroni threshold is drawn.
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from scipy import stats

    names = [f.effect for f in findings][::-1]
    values = [max(f.evidence, 1e-3) for f in findings][::-1]
    colors = ["tab:red" if f.significant else "tab:gray" for f in findings][::-1]
    fig, ax = plt.subplots(figsize=(7.5, 0.45 * len(names) + 1.2), layout="constrained")
    ax.barh(names, values, color=colors)
    threshold = stats.chi2.isf(level / max(len(findings), 1), 1)
    ax.axvline(threshold, color="k", ls="--", lw=1,
               label=f"significance threshold (level {level:g}, Bonferroni, 1 dof)")
    ax.set_xscale("log")
    ax.set_xlabel("score statistic (evidence that the effect is missing)")
    ax.legend(fontsize=7, loc="lower right")
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


_CONTROLLER_STYLE = {"pid": ("C0", "$x_{FB}$ (PID)", "PID"),
                     "ct": ("C3", "$x_{CT}$ (computed torque)", "computed torque")}


def plot_figure5(run: ClosedLoop, *, path: str | Path | None = None) -> plt.Figure:
    """The paper's Fig. 5: reference and responses per frequency, the error below each.

    Parameters
    ----------
    run : ClosedLoop
        Closed-loop runs (e.g. from :func:`pmabayes.reproduction.figure5`), one per
        frequency and controller.
    path : str or Path, optional
        Where to save the figure (PNG).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    freqs = list(dict.fromkeys(float(f) for f in run.frequency_hz))
    fig, axes = plt.subplots(2 * len(freqs), 1, figsize=(8, 3.2 * len(freqs)), sharex=True,
                             gridspec_kw={"height_ratios": [2, 1] * len(freqs)}, squeeze=False)
    axes = axes[:, 0]
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


def plot_robustness(ds, *, path: str | Path | None = None) -> plt.Figure:
    """RMS error, phase lag and P(CT beats PID) of a robustness sweep against frequency.

    Parameters
    ----------
    ds : xarray.Dataset
        A sweep from :func:`pmabayes.robustness.robustness_sweep`.
    path : str or Path, optional
        Where to save the figure (PNG).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    summary = summarise_robustness(ds)
    f = summary["frequency"].values
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True,
                             gridspec_kw={"height_ratios": [2, 2, 1]})
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
    axes[0].set_title(f"{ds.sizes['sample']} posterior samples, mode '{ds.attrs.get('mode')}'")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig
