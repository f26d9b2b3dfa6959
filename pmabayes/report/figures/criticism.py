"""Figures of model criticism: the model beside the measurements, errors per band, the
residual's signature and whiteness, the candidates' evidence, the discrepancy, and
the prediction of a held-out experiment.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from pmabayes.criticism.observed import mean_of_observed
from pmabayes.criticism.yardsticks import REGISTRY
from pmabayes.data import Dataset
from pmabayes.report.figures.common import REPORT_DPI, colormap, finish, shade_gaps, zoom_slice
from pmabayes.util import format_together

__all__ = [
    "plot_comparison",
    "plot_band_errors",
    "plot_residual_signature",
    "plot_whiteness",
    "plot_ranking",
    "plot_validation",
]


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
    seen = dataset.counted.any(axis=0)
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
    shade_gaps(ax_x, t, seen)
    ax_x.legend(loc="upper left", fontsize=8)
    shade_gaps(ax_r, t, seen, label=False)
    ax_r.plot(t, resid * 1e6, color="k", lw=0.6)
    if np.isfinite(floor):
        ax_r.axhspan(-floor * 1e6, floor * 1e6, color="tab:green", alpha=0.25,
                     label=f"noise floor ±{format_together(floor * 1e6)[0]} µm")
        ax_r.legend(loc="upper left", fontsize=8)
    rms = float(np.sqrt(np.mean(resid**2) if seen.all() else np.mean(resid[seen] ** 2)))
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
    return finish(fig, path, 120)


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
    cmap = colormap("viridis")
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
    return finish(fig, path, 110)


def plot_residual_signature(
    dataset: Dataset,
    simulation,
    frequency_hz: np.ndarray,
    *,
    label: str = "model",
    path: str | Path | None = None,
    floor_m: float | None = None,
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
        :attr:`pmabayes.criticism.results.ExperimentDiagnosis.frequency_hz`).
    label : str
        Name of the model in the title.
    path : str or Path, optional
        Where to save the figure.
    floor_m : float, optional
        The noise floor to draw (a diagnosis' own, which a periodic record takes from
        its periods); the trials' spread (:attr:`pmabayes.data.Dataset.noise_floor_m`)
        by default. Not drawn, nor named in the title, when it is not finite (a record
        without repeats).

    Returns
    -------
    matplotlib.figure.Figure
    """
    seen = dataset.counted.any(axis=0)
    resid = np.where(seen, dataset.mean_position_m - simulation.position_m[0], np.nan) * 1e6
    floor = (dataset.noise_floor_m if floor_m is None else float(floor_m)) * 1e6
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
            shade_gaps(ax, v, seen, label=False)
            ax.plot(v, resid, color="k", lw=0.5)
        else:
            ax.scatter(v[::step], resid[::step], s=2, color="k", alpha=0.4, linewidths=0)
        if math.isfinite(floor):
            ax.axhspan(-floor, floor, color="tab:green", alpha=0.3)
        ax.axhline(0.0, color="tab:gray", lw=0.5)
        ax.set_xlabel(name)
    axes[0].set_ylabel("trial mean − model [µm]")
    rms = float(np.sqrt(np.mean(resid**2) if seen.all() else np.mean(resid[seen] ** 2)))
    if math.isfinite(floor):
        rms_text, floor_text = format_together(rms, floor)
        against_floor = f"against the noise floor ±{floor_text} µm (green)"
    else:
        rms_text, against_floor = format_together(rms)[0], "(no noise floor: no repeats)"
    fig.suptitle(f"where {label} fails: residual (RMS {rms_text} µm) {against_floor}",
                 fontsize=10)
    return finish(fig, path, 110)


def plot_whiteness(curves, *, path: str | Path | None = None) -> Figure:
    """Autocorrelation of whitened residuals and their cross-correlation with the input.

    Parameters
    ----------
    curves : pmabayes.criticism.whiteness.WhitenessCurves
        The curves, one per model (:func:`pmabayes.criticism.whiteness.whiteness_curves`,
        :meth:`pmabayes.criticism.results.ExperimentDiagnosis.whiteness_curves` or
        :meth:`pmabayes.criticism.compare.FitComparison.whiteness_curves`).
    path : str or Path, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = Figure(figsize=(11, 3.6), layout="constrained")
    ax_a, ax_c = fig.subplots(1, 2)
    cmap = colormap("viridis")
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
    return finish(fig, path, 110)


def plot_ranking(findings, *, threshold: float | None = None, level: float = 0.05,
                 path: str | Path | None = None) -> Figure:
    """Evidence that each candidate effect is missing.

    Parameters
    ----------
    findings : list of pmabayes.criticism.results.Finding
        The ranking of a diagnosis (a candidate left out of the score tests is drawn
        pale at the axis' foot, "(left out)").
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
    left = [getattr(f, "left_out", None) is not None for f in findings]
    names = [f.effect + (" (left out)" if out else "")
             for f, out in zip(findings, left, strict=True)][::-1]
    values = [1e-3 if out else max(f.evidence, 1e-3)
              for f, out in zip(findings, left, strict=True)][::-1]
    colors = ["0.85" if out else "tab:red" if f.significant else "tab:gray"
              for f, out in zip(findings, left, strict=True)][::-1]
    fig = Figure(figsize=(7.5, 0.45 * len(names) + 1.2), layout="constrained")
    ax = fig.subplots()
    ax.barh(names, values, color=colors)
    if threshold is not None:
        ax.axvline(threshold, color="k", ls="--", lw=1,
                   label=f"significance threshold (level {level:g}, Bonferroni, 1 dof)")
        ax.legend(fontsize=7, loc="lower right")
    ax.set_xscale("log")
    ax.set_xlabel("score statistic (evidence that the effect is missing)")
    return finish(fig, path, 110)


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
    return finish(fig, path, 110)


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
        fit's noise), the wider band with the model's learnt discrepancy (light blue),
        the posterior-mean prediction (red) and the yardsticks' predictions (linear
        output-error green, Prandtl-Ishlinskii purple), with the run's end enlarged;
        bottom: the same less the prediction, with the trial mean (black).
    """
    e = experiment
    t, data, pred = e.time_s, e.position_m, e.prediction_m
    lo, hi = e.low_m, e.high_m
    own = np.ndim(lo) == 2  # trials with their own inputs: each its own band
    if own:  # the first trial's band is drawn
        lo, hi = lo[0], hi[0]
    seen = np.isfinite(data).any(axis=0)
    z = zoom_slice(t)
    pct = f"{100 * e.ci_prob:.4g}%"
    fig = Figure(figsize=(12, 6), layout="constrained")
    axes = fig.subplots(2, 2, width_ratios=(3, 1))
    alpha = float(np.clip(2.0 / e.n_trials, 0.15, 0.8))
    wide = (None if e.low_with_discrepancy_m is None
            else (e.low_with_discrepancy_m, e.high_with_discrepancy_m))
    if wide is not None and own:
        wide = (wide[0][0], wide[1][0])
    yard = {name: kind.colour for name, kind in REGISTRY.items()}
    for col, s in enumerate((slice(None), z)):
        top, bottom = axes[0, col], axes[1, col]
        shade_gaps(top, t[s], seen[s])
        shade_gaps(bottom, t[s], seen[s], label=False)
        if wide is not None:
            top.fill_between(t[s], wide[0][s] * 1e3, wide[1][s] * 1e3, color="tab:blue",
                             alpha=0.12, lw=0, label=f"{pct} band with the discrepancy")
            bottom.fill_between(t[s], (wide[0][s] - pred[s]) * 1e6,
                                (wide[1][s] - pred[s]) * 1e6, color="tab:blue", alpha=0.1,
                                lw=0)
        top.fill_between(t[s], lo[s] * 1e3, hi[s] * 1e3, color="tab:blue", alpha=0.35, lw=0,
                         label=f"{pct} predictive band")
        for name, b in e.baselines.items():
            top.plot(t[s], b["prediction_m"][s] * 1e3, color=yard.get(name, "k"), lw=0.7,
                     ls=":", label=f"{name} yardstick (NRMSE {b['nrmse']:.3g})")
            bottom.plot(t[s], (b["prediction_m"][s] - pred[s]) * 1e6, color=yard.get(name, "k"),
                        lw=0.6, ls=":")
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
            bottom.plot(t[s], (mean_of_observed(data[:, s]) - pred[s]) * 1e6, color="k", lw=0.8,
                        label="trial mean − prediction")
        bottom.axhline(0.0, color="tab:red", lw=0.7, ls="--")
        # the scale of the data and the bands: a far-off yardstick runs off the panel
        shown = [(data[:, s] - pred[s]), (lo[s] - pred[s]), (hi[s] - pred[s])]
        shown += [] if wide is None else [wide[0][s] - pred[s], wide[1][s] - pred[s]]
        ends = [float(np.nanmin([np.nanmin(v) for v in shown])),
                float(np.nanmax([np.nanmax(v) for v in shown]))]
        pad = 0.1 * (ends[1] - ends[0]) or 1e-6
        bottom.set_ylim((ends[0] - pad) * 1e6, (ends[1] + pad) * 1e6)
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
        f"{100 * e.band_coverage:.1f}% of the samples inside the {pct} band"
        + ("" if e.coverage is None else f", {100 * e.coverage:.1f}% with the discrepancy")
        + (" (each trial has its own input and band: trial 1's shown)" if own else ""),
        fontsize=9, loc="left")
    return finish(fig, path, REPORT_DPI)

