"""The figure of a design: the candidates' predicted responses to the chosen input, and
where they differ."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from pmabayes.report.figures.common import REPORT_DPI, finish

__all__ = ["plot_design"]


def plot_design(result, path: str | Path | None = None, dpi: int = REPORT_DPI) -> Figure:
    """The chosen input (top), each candidate's predicted response at its MAP with the
    5%-95% band of its posterior draws (middle), and each one's MAP response less the
    first's (bottom: where they differ).

    Parameters
    ----------
    result : DesignResult
        A design (:func:`pmabayes.design.api.design`).
    path : str or Path, optional
        Where to save it.
    dpi : int
        Resolution of the saved figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    exp = result.experiment
    t = exp.time_s
    fig = Figure(figsize=(10, 8), layout="constrained")
    ax_u, ax_x, ax_d = fig.subplots(3, 1, sharex=True)
    unit, scale = ("kPa", 1e-3) if result.input_name == "pressure_pa" else ("N", 1.0)
    ax_u.plot(t, exp.input() * scale, color="k", lw=0.8)
    ax_u.set_ylabel(f"input [{unit}]")
    ax_u.set_title(exp.label(), fontsize=10)
    names = list(result.predictions)
    first = result.predictions[names[0]]["map"]
    for k, name in enumerate(names):
        p = result.predictions[name]
        colour = f"C{k}"
        ax_x.fill_between(t, p["low"] * 1e3, p["high"] * 1e3, color=colour, alpha=0.25, lw=0)
        ax_x.plot(t, p["map"] * 1e3, color=colour, lw=0.9, label=name)
        if k:
            ax_d.plot(t, (p["map"] - first) * 1e6, color=colour, lw=0.9,
                      label=f"{name} less {names[0]}")
    ax_x.set_ylabel("position [mm]")
    ax_x.legend(fontsize=8, loc="upper right")
    ax_d.axhline(0.0, color="k", lw=0.5)
    ax_d.set_ylabel("difference [µm]")
    ax_d.set_xlabel("time [s]")
    if len(names) > 1:
        ax_d.legend(fontsize=8, loc="upper right")
    spread = [np.nanmax(np.abs(result.predictions[n]["map"] - first)) for n in names[1:]]
    if spread and not np.nanmax(spread) > 0:
        ax_d.text(0.5, 0.5, "no difference at the MAPs", transform=ax_d.transAxes,
                  ha="center")
    return finish(fig, path, dpi)
