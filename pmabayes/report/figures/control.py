"""Figures of control: the paper's Fig. 5 and the robustness of the controllers over the
posterior.
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from pmabayes.control import CONTROLLERS, ClosedLoop
from pmabayes.control.robustness import summarise_robustness
from pmabayes.report.figures.common import finish

__all__ = ["plot_figure5", "plot_robustness"]


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
        Two panels per frequency: the positions over the reference, and the errors.
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
    return finish(fig, path, 120)


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
        Against the reference frequency: RMS error and phase lag (median and 90% band
        per controller), and P(CT beats PID) with its Monte Carlo error.
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
    return finish(fig, path, 120)
