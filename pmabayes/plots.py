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
from pmabayes.data import Dataset  # noqa: E402
from pmabayes.robustness import summarise_robustness  # noqa: E402

__all__ = ["plot_comparison", "plot_figure5", "plot_robustness"]


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
