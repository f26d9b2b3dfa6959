"""Robustness of the controllers to identification uncertainty.

Posterior samples are pushed through both controllers across tracking frequencies
(:func:`robustness_sweep`), in one of two modes:

``"plant"``
    The plant is drawn from the posterior; the controller keeps the nominal model
    (the posterior mean). How much does the uncertainty about the real muscle cost?
``"model"``
    The controller's model is drawn from the posterior; the plant is fixed at the
    posterior mean. How much does a different, equally credible identification
    change the tracking?

Each run is a 10 s closed loop of :mod:`pmabayes.control` on :meth:`Rig.control`
(the 500 g load), with the fit's effects in both plant and controller model. The
result is an ``xarray.Dataset`` over ``(sample, frequency, controller)`` with the
metrics of :func:`pmabayes.control.tracking_metrics`; :func:`summarise_robustness`
reduces it to medians, 90% bands and the probability that computed torque beats
PID, and :func:`plot_robustness` draws the bands against frequency.

The samples are chosen by the seed alone, and every run is deterministic, so the
same seed gives the same numbers however the runs are split into chunks and
whoever runs them: the local process pool (default), this process
(``processes=1``) or a ``dask.distributed`` client (the optional ``dask`` extra).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_all_start_methods, get_context
from pathlib import Path

import numpy as np
import xarray as xr

from pmabayes.control import (
    CONTROLLERS,
    DEFAULT_GAINS,
    OPERATING_OFFSET_M,
    REFERENCE_AMPLITUDE_M,
    REFERENCE_MEAN_M,
    ControlError,
    Timing,
    closed_loop_batch,
    tracking_metrics,
)
from pmabayes.model import Model, Rig
from pmabayes.posterior import fit_info, load_fit

__all__ = [
    "DEFAULT_FREQUENCIES_HZ",
    "METRICS",
    "MODES",
    "control_model_from_fit",
    "posterior_samples",
    "robustness_sweep",
    "summarise_robustness",
    "plot_robustness",
    "write_robustness",
]

#: 8 frequencies, geometrically spaced from 0.25 to 3 Hz.
DEFAULT_FREQUENCIES_HZ = tuple(float(f) for f in np.geomspace(0.25, 3.0, 8))
METRICS = ("rms_error_m", "max_error_m", "amplitude_ratio", "phase_lag_deg", "overshoot_pct")
MODES = ("plant", "model")


def control_model_from_fit(tree: xr.DataTree) -> Model:
    """The fit's model (effects and fixed values) moved onto the control rig.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (:func:`pmabayes.posterior.load_fit`).

    Returns
    -------
    Model
        The same effects and fixings on :meth:`Rig.control` (500 g load).
    """
    info = fit_info(tree).get("model") or {}
    model = Model(info.get("effects") or [], rig=Rig.control(),
                  fixed=info.get("fixed") or {})
    missing = [n for n in model.free_names if n not in tree["posterior"].data_vars]
    if missing:
        raise ControlError(f"the fit's posterior lacks {missing}; refit with `pmabayes fit`")
    return model


def posterior_samples(tree: xr.DataTree, model: Model, samples: int,
                      seed: int | np.random.Generator = 0) -> tuple[np.ndarray, np.ndarray,
                                                                    np.ndarray]:
    """Draw parameter sets from a fit's posterior.

    Parameters
    ----------
    tree : xarray.DataTree
        The fit.
    model : Model
        The model whose free parameters to take (see :func:`control_model_from_fit`).
    samples : int
        How many; without replacement when the posterior has enough draws.
    seed : int or numpy.random.Generator
        Chooses the draws.

    Returns
    -------
    theta : numpy.ndarray
        Full parameter arrays ``(samples, n_parameters)``.
    mean : numpy.ndarray
        The posterior mean as a full parameter array ``(n_parameters,)``.
    where : numpy.ndarray
        ``(samples, 2)``: the chain and draw of each sample.
    """
    if not (isinstance(samples, int | np.integer) and samples >= 1):
        raise ControlError(f"samples must be an integer >= 1, got {samples!r}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    post = tree["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    total = n_chain * n_draw
    flat = rng.choice(total, size=int(samples), replace=samples > total)
    values = {n: np.asarray(post[n].values, dtype=float).reshape(-1) for n in model.free_names}
    theta = model.theta({n: v[flat] for n, v in values.items()})
    mean = model.theta({n: float(v.mean()) for n, v in values.items()})[0]
    where = np.column_stack([flat // n_draw, flat % n_draw])
    return theta, mean, where


def _run_chunk(job: dict) -> tuple[int, dict]:
    """Run one contiguous block of members (in a worker or here)."""
    plant = Model(job["effects"], rig=Rig.from_dict(job["rig"]), fixed=job["fixed"])
    freq, kind = job["freq"], job["kind"]
    run = closed_loop_batch(plant, job["theta_p"], plant, job["theta_c"], freq,
                            [CONTROLLERS[k] for k in kind], duration_s=job["duration_s"],
                            gains=job["gains"], timing=job["timing"], record=False)
    out = {m: np.empty(len(freq)) for m in METRICS}
    for f in np.unique(freq):
        sel = freq == f
        met = tracking_metrics(run.time_s, run.reference_m[sel], run.position_m[sel], f)
        for m in METRICS:
            out[m][sel] = met[m]
    return job["start"], out


class _Bar:
    """A progress bar on stderr."""

    def __init__(self, total: int, enabled: bool, label: str) -> None:
        self.total, self.enabled, self.label = total, enabled, label
        self.done = 0
        self.t0 = time.perf_counter()
        self._draw()

    def update(self, n: int) -> None:
        self.done += n
        self._draw()

    def _draw(self) -> None:
        if not self.enabled:
            return
        frac = self.done / max(self.total, 1)
        bar = "#" * int(round(30 * frac))
        end = "\n" if self.done >= self.total else ""
        print(f"\r[pmabayes robustness] [{bar:-<30}] {self.done}/{self.total} runs "
              f"({time.perf_counter() - self.t0:.0f} s) {self.label}", end=end,
              file=sys.stderr, flush=True)


def robustness_sweep(
    fit,
    *,
    samples: int = 500,
    frequencies_hz: Sequence[float] | None = None,
    mode: str = "plant",
    seed: int | np.random.Generator = 0,
    duration_s: float = 10.0,
    chunk_size: int = 400,
    processes: int | None = None,
    client=None,
    progress: bool = True,
    timing: Timing | None = None,
) -> xr.Dataset:
    """Push posterior samples through both controllers across tracking frequencies.

    Parameters
    ----------
    fit : str, Path or xarray.DataTree
        A fit file or a loaded fit.
    samples : int
        Number of posterior samples ``S`` (500).
    frequencies_hz : sequence of float, optional
        Reference frequencies; :data:`DEFAULT_FREQUENCIES_HZ` by default.
    mode : str
        ``"plant"`` (plant drawn, controller at the posterior mean) or ``"model"``
        (controller's model drawn, plant at the posterior mean).
    seed : int or numpy.random.Generator
        Chooses the samples; nothing else is random.
    duration_s : float
        Length of each closed-loop run (10 s).
    chunk_size : int
        Runs per task.
    processes : int, optional
        Local worker processes; all cores by default, 1 runs in this process.
        Ignored when ``client`` is given.
    client : dask.distributed.Client, optional
        Run the chunks on this Dask cluster instead.
    progress : bool
        Show a progress bar on stderr.
    timing : Timing, optional
        Rates, limits and sensor of the loop.

    Returns
    -------
    xarray.Dataset
        The metrics over ``(sample, frequency, controller)``, the parameter values
        of every sample (``sample`` x ``parameter``) and the nominal (mean)
        parameters, with the settings in the attributes.

    Raises
    ------
    ControlError
        On a bad mode, frequency, sample count or chunk size.
    """
    if mode not in MODES:
        raise ControlError(f"unknown mode {mode!r}; choose 'plant' or 'model'")
    freqs = np.asarray(DEFAULT_FREQUENCIES_HZ if frequencies_hz is None else frequencies_hz,
                       dtype=float).ravel()
    if freqs.size == 0 or not np.all(np.isfinite(freqs) & (freqs > 0)):
        raise ControlError(f"frequencies must be > 0 Hz, got {freqs.tolist()}")
    if not (isinstance(chunk_size, int | np.integer) and chunk_size >= 1):
        raise ControlError(f"chunk_size must be an integer >= 1, got {chunk_size!r}")
    source = str(fit) if isinstance(fit, str | Path) else "(in memory)"
    tree = load_fit(fit) if isinstance(fit, str | Path) else fit
    model = control_model_from_fit(tree)
    timing = Timing() if timing is None else timing
    theta, mean, where = posterior_samples(tree, model, samples, seed)
    n_s, n_f, n_c = theta.shape[0], freqs.size, len(CONTROLLERS)
    # member (s, f, c) at (s * n_f + f) * n_c + c
    s_idx, f_idx, c_idx = (a.ravel() for a in np.meshgrid(
        np.arange(n_s), np.arange(n_f), np.arange(n_c), indexing="ij"))
    drawn = theta[s_idx]
    fixed_theta = np.repeat(mean[None, :], len(s_idx), axis=0)
    theta_p, theta_c = (drawn, fixed_theta) if mode == "plant" else (fixed_theta, drawn)
    gains = np.zeros((n_c, 3))
    for j, c in enumerate(CONTROLLERS):
        row = list(DEFAULT_GAINS[c].values())
        gains[j, :len(row)] = row
    spec = {"effects": list(model.effect_names), "rig": model.rig.to_dict(),
            "fixed": dict(model.fixed), "duration_s": float(duration_s), "timing": timing}
    jobs = []
    for lo in range(0, len(s_idx), int(chunk_size)):
        sl = slice(lo, min(lo + int(chunk_size), len(s_idx)))
        jobs.append({**spec, "start": lo, "theta_p": theta_p[sl], "theta_c": theta_c[sl],
                     "freq": freqs[f_idx[sl]], "kind": c_idx[sl].copy(),
                     "gains": gains[c_idx[sl]]})
    flat = {m: np.empty(len(s_idx)) for m in METRICS}
    bar = _Bar(len(s_idx), progress, f"({n_s} samples x {n_f} frequencies x {n_c} controllers)")

    def collect(start: int, out: dict) -> None:
        n = len(out[METRICS[0]])
        for m in METRICS:
            flat[m][start:start + n] = out[m]
        bar.update(n)

    t0 = time.perf_counter()
    if client is not None:
        try:
            from distributed import as_completed as dask_completed
        except ImportError as exc:  # pragma: no cover - a client implies distributed
            raise ControlError("a Dask client needs `pip install pmabayes[dask]`") from exc
        futures = client.map(_run_chunk, jobs, pure=False)
        for fut in dask_completed(futures):
            collect(*fut.result())
        runner = f"dask ({len(client.scheduler_info().get('workers', {}))} workers)"
    else:
        n_proc = (os.cpu_count() or 1) if processes is None else int(processes)
        n_proc = max(1, min(n_proc, len(jobs)))
        if n_proc == 1:
            for job in jobs:
                collect(*_run_chunk(job))
        else:
            # fork where there is one: workers inherit the loaded kernels, where spawn
            # re-imports numba and xarray in each (seconds per worker)
            method = "fork" if "fork" in get_all_start_methods() else "spawn"
            with ProcessPoolExecutor(n_proc, mp_context=get_context(method)) as pool:
                for fut in as_completed([pool.submit(_run_chunk, j) for j in jobs]):
                    collect(*fut.result())
        runner = f"{n_proc} local process{'es' if n_proc > 1 else ''}"
    seconds = time.perf_counter() - t0
    shape = (n_s, n_f, n_c)
    names = list(model.parameter_names)
    ds = xr.Dataset(
        {m: (("sample", "frequency", "controller"), flat[m].reshape(shape)) for m in METRICS},
        coords={"sample": np.arange(n_s), "frequency": freqs,
                "controller": list(CONTROLLERS), "parameter": names,
                "chain": ("sample", where[:, 0]), "draw": ("sample", where[:, 1])},
    )
    ds["sample_parameters"] = (("sample", "parameter"), theta)
    ds["nominal_parameters"] = (("parameter",), mean)
    units = {"rms_error_m": "m", "max_error_m": "m", "amplitude_ratio": "1",
             "phase_lag_deg": "deg", "overshoot_pct": "%"}
    for m, u in units.items():
        ds[m].attrs["units"] = u
    ds["frequency"].attrs["units"] = "Hz"
    ds.attrs.update({
        "mode": mode, "seed": str(seed) if not isinstance(seed, int) else seed,
        "fit": source, "effects": ",".join(model.effect_names) or "none",
        "duration_s": float(duration_s), "reference_mean_m": REFERENCE_MEAN_M,
        "reference_amplitude_m": REFERENCE_AMPLITUDE_M,
        "operating_offset_m": OPERATING_OFFSET_M,
        "gains": repr(DEFAULT_GAINS), "timing": repr(timing), "runner": runner,
        "sweep_seconds": seconds,
    })
    return ds


def summarise_robustness(ds: xr.Dataset) -> xr.Dataset:
    """Median and 90% band of the RMS error and phase lag, and P(CT beats PID).

    Parameters
    ----------
    ds : xarray.Dataset
        A sweep from :func:`robustness_sweep`.

    Returns
    -------
    xarray.Dataset
        Over ``(frequency, controller)``: ``rms_error_m_median``, ``_q05``, ``_q95``
        and the same for ``phase_lag_deg``; over ``frequency``: ``p_ct_beats_pid``,
        the fraction of samples where computed torque has the smaller RMS error.
    """
    out = xr.Dataset(coords={"frequency": ds["frequency"], "controller": ds["controller"]})
    for m in ("rms_error_m", "phase_lag_deg"):
        q = ds[m].quantile([0.05, 0.5, 0.95], dim="sample")
        out[f"{m}_q05"] = q.sel(quantile=0.05, drop=True)
        out[f"{m}_median"] = q.sel(quantile=0.5, drop=True)
        out[f"{m}_q95"] = q.sel(quantile=0.95, drop=True)
    rms = ds["rms_error_m"]
    beats = rms.sel(controller="ct") < rms.sel(controller="pid")
    out["p_ct_beats_pid"] = beats.mean("sample")
    out.attrs.update({k: ds.attrs[k] for k in ("mode", "seed") if k in ds.attrs})
    out.attrs["samples"] = int(ds.sizes["sample"])
    return out


def plot_robustness(ds: xr.Dataset, path) -> Path:
    """Figure of the RMS error, phase lag and P(CT beats PID) against frequency.

    Parameters
    ----------
    ds : xarray.Dataset
        A sweep from :func:`robustness_sweep`.
    path : str or Path
        The PNG to write.

    Returns
    -------
    Path
        The file written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = summarise_robustness(ds)
    f = summary["frequency"].values
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True,
                             gridspec_kw={"height_ratios": [2, 2, 1]})
    for c, color in zip(CONTROLLERS, ("C0", "C3"), strict=True):
        label = {"pid": "PID", "ct": "computed torque"}[c]
        for ax, m, scale in ((axes[0], "rms_error_m", 1e3), (axes[1], "phase_lag_deg", 1.0)):
            s = summary.sel(controller=c)
            ax.fill_between(f, scale * s[f"{m}_q05"], scale * s[f"{m}_q95"], color=color,
                            alpha=0.25, lw=0)
            ax.plot(f, scale * s[f"{m}_median"], "o-", color=color, label=f"{label} (median, "
                    "90% band)")
    axes[0].set_ylabel("RMS error [mm]")
    axes[0].legend(fontsize=8)
    axes[1].set_ylabel("phase lag [deg]")
    axes[2].plot(f, summary["p_ct_beats_pid"], "ko-")
    axes[2].set_ylim(-0.05, 1.05)
    axes[2].set_ylabel("P(CT beats PID)")
    axes[2].set_xlabel("reference frequency [Hz]")
    axes[2].set_xscale("log")
    axes[2].set_xticks(f, [f"{v:.2g}" for v in f], minor=False)
    axes[2].minorticks_off()
    axes[0].set_title(f"{ds.sizes['sample']} posterior samples, mode '{ds.attrs.get('mode')}'")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_robustness(ds: xr.Dataset, out_dir) -> dict[str, Path]:
    """Write a sweep, its summary (CSV and Markdown) and its figure.

    Parameters
    ----------
    ds : xarray.Dataset
        A sweep from :func:`robustness_sweep`.
    out_dir : str or Path
        Output folder (created).

    Returns
    -------
    dict of str to Path
        ``netcdf``, ``summary_csv``, ``summary_md`` and ``figure``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"netcdf": out / "robustness.nc", "summary_csv": out / "summary.csv",
             "summary_md": out / "summary.md", "figure": out / "robustness.png"}
    ds.to_netcdf(paths["netcdf"], engine="h5netcdf")
    summary = summarise_robustness(ds)
    rows = []
    for f in summary["frequency"].values:
        for c in CONTROLLERS:
            s = summary.sel(frequency=f, controller=c)
            rows.append([f"{f:.3f}", c,
                         *(f"{1e3 * float(s[f'rms_error_m_{q}']):.3f}"
                           for q in ("median", "q05", "q95")),
                         *(f"{float(s[f'phase_lag_deg_{q}']):.1f}"
                           for q in ("median", "q05", "q95")),
                         f"{float(summary['p_ct_beats_pid'].sel(frequency=f)):.3f}"])
    head = ["frequency_hz", "controller", "rms_error_mm_median", "rms_error_mm_q05",
            "rms_error_mm_q95", "phase_lag_deg_median", "phase_lag_deg_q05",
            "phase_lag_deg_q95", "p_ct_beats_pid"]
    paths["summary_csv"].write_text("\n".join(",".join(r) for r in [head, *rows]) + "\n")
    md = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    md += ["| " + " | ".join(r) + " |" for r in rows]
    paths["summary_md"].write_text(
        f"Robustness sweep: {ds.sizes['sample']} samples, mode '{ds.attrs.get('mode')}', "
        f"seed {ds.attrs.get('seed')}, fit {ds.attrs.get('fit')}\n\n" + "\n".join(md) + "\n")
    plot_robustness(ds, paths["figure"])
    return paths
