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

from pmabayes.data import Dataset  # noqa: E402

__all__ = ["plot_comparison"]


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
