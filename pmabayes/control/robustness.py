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
PID, and :func:`pmabayes.report.figures.plot_robustness` draws the bands against frequency.

Both controllers are tuned by the same rule, :func:`pmabayes.control.tune_gains`, on
the sweep's nominal model (the fit's model at its posterior mean, with its effects;
:func:`pmabayes.control.nominal_gains`, cached), unless ``gains`` are given, and
the reference mean is that of the operating-point rule on the same nominal model
(:func:`pmabayes.control.operating_mean_m`) unless ``reference_mean_m`` is given.
The gains and the mean are stored in the result's attributes.

The samples are chosen by the seed alone, and every run is deterministic, so the
same seed gives the same numbers however the runs are split into chunks and
whoever runs them: the local process pool (default), this process
(``processes=1``) or a ``dask.distributed`` client (the optional ``dask`` extra).
"The same numbers" means bit for bit on one CPU and one set of numba, LLVM and
numpy versions: the kernels' fastmath flags (``contract``, ``afn``) let another
CPU or version round differently in the last bits.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from pmabayes.control import (
    CONTROLLERS,
    DEFAULT_GAINS,
    METRICS,
    REFERENCE_AMPLITUDE_M,
    ControlError,
    Timing,
    closed_loop_batch,
    gain_array,
    loop_metrics,
    minimum_duration_s,
    operating_mean_m,
    resolve_gains,
)
from pmabayes.inference.fitfile import fit_info, load_fit
from pmabayes.model.model import Model, Rig
from pmabayes.parallel import Runner
from pmabayes.util import Progress, show_progress

__all__ = [
    "DEFAULT_FREQUENCIES_HZ",
    "METRICS",
    "MODES",
    "control_model_from_fit",
    "posterior_mean",
    "posterior_samples",
    "robustness_sweep",
    "summarise_robustness",
    "write_robustness",
    "example_sweep",
]

#: 8 frequencies, geometrically spaced from 0.25 to 3 Hz.
DEFAULT_FREQUENCIES_HZ = tuple(float(f) for f in np.geomspace(0.25, 3.0, 8))
#: The two sweep modes: which side is drawn from the posterior.
MODES = ("plant", "model")


def control_model_from_fit(tree: xr.DataTree) -> Model:
    """The fit's model (effects and fixed values) moved onto the control rig.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (:func:`pmabayes.inference.fitfile.load_fit`).

    Returns
    -------
    Model
        The same effects and fixings on :meth:`Rig.control` (500 g load).

    Examples
    --------
    A short fit (too short to converge, for the example) on the characterisation rig,
    its model moved to the control rig:

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.control.robustness import control_model_from_fit
    >>> model = control_model_from_fit(tree)
    >>> model, model.rig.moving_mass_kg
    (Model(rig=control, effects=none, parameters=6), 0.567)
    """
    info = fit_info(tree).get("model") or {}
    model = Model(info.get("effects") or [], rig=Rig.control(),
                  fixed=info.get("fixed") or {})
    missing = [n for n in model.free_names if n not in tree["posterior"].data_vars]
    if missing:
        raise ControlError(f"the fit's posterior lacks {missing}; refit with `pmabayes fit`")
    return model


def posterior_mean(tree: xr.DataTree, model: Model) -> np.ndarray:
    """The posterior mean of a fit as a full parameter array.

    Parameters
    ----------
    tree : xarray.DataTree
        The fit.
    model : Model
        The model whose free parameters to average (see :func:`control_model_from_fit`);
        its fixed parameters keep their values.

    Returns
    -------
    numpy.ndarray
        ``(n_parameters,)``, in ``model.parameter_names`` order.

    Examples
    --------
    A short fit (too short to converge, for the example):

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.control.robustness import control_model_from_fit, posterior_mean
    >>> model = control_model_from_fit(tree)
    >>> mean = posterior_mean(tree, model)
    >>> mean.shape, model.parameter_names
    ((6,), ('alpha', 'beta', 'gamma', 'd', 'K_e', 'p_dz'))
    """
    post = tree["posterior"]
    return model.theta({n: float(np.asarray(post[n].values, dtype=float).mean())
                        for n in model.free_names})[0]


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
        The posterior mean (:func:`posterior_mean`), ``(n_parameters,)``.
    where : numpy.ndarray
        ``(samples, 2)``: the chain and draw of each sample.

    Examples
    --------
    A short fit (too short to converge, for the example), and three draws of it:

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.control.robustness import control_model_from_fit, posterior_samples
    >>> theta, mean, where = posterior_samples(tree, control_model_from_fit(tree), 3, seed=0)
    >>> theta.shape, mean.shape, where.shape
    ((3, 6), (6,), (3, 2))
    """
    if isinstance(samples, bool) or not (isinstance(samples, int | np.integer) and samples >= 1):
        raise ControlError(f"samples must be an integer >= 1, got {samples!r}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    post = tree["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    total = n_chain * n_draw
    flat = rng.choice(total, size=int(samples), replace=samples > total)
    values = {n: np.asarray(post[n].values, dtype=float).reshape(-1) for n in model.free_names}
    theta = model.theta({n: v[flat] for n, v in values.items()})
    where = np.column_stack([flat // n_draw, flat % n_draw])
    return theta, posterior_mean(tree, model), where


def _run_chunk(job: dict) -> tuple[int, dict]:
    """Run one contiguous block of members (in a worker or here)."""
    model = Model(job["effects"], rig=Rig.from_dict(job["rig"]), fixed=job["fixed"])
    run = closed_loop_batch(model, job["theta_p"], model, job["theta_c"], job["freq"],
                            [CONTROLLERS[k] for k in job["kind"]],
                            duration_s=job["duration_s"], gains=job["gains"],
                            timing=job["timing"], reference_mean_m=job["reference_mean_m"],
                            record=False)
    return job["start"], loop_metrics(run)


def robustness_sweep(
    fit,
    *,
    samples: int = 500,
    frequencies_hz: Sequence[float] | None = None,
    mode: str = "plant",
    seed: int | np.random.Generator = 0,
    duration_s: float = 10.0,
    gains: dict | None = None,
    reference_mean_m: float | None = None,
    chunk_size: int = 400,
    processes: int | None = None,
    client=None,
    progress: bool = False,
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
        Length of each closed-loop run (10 s); at least one whole period after the
        start-up at the lowest frequency.
    gains : dict, optional
        ``{"pid": {...}, "ct": {...}}`` to use instead of the gains tuned on the
        nominal model (:func:`pmabayes.control.nominal_gains`); a controller left out,
        or gains left out, are tuned (:func:`pmabayes.control.resolve_gains`).
    reference_mean_m : float, optional
        Mean of the reference; by default the operating-point rule
        (:func:`pmabayes.control.operating_mean_m`) on the nominal model, the same for
        every sample (stored in the attributes).
    chunk_size : int
        Runs per task.
    processes : int, optional
        Local worker processes, >= 1; by default the cores this process may use; 1
        runs in this process. Ignored when ``client`` is given.
    client : dask.distributed.Client, optional
        Run the chunks on this Dask cluster instead.
    progress : bool
        Show what is being done on stderr, with a bar for the sweep (every stage's
        progress: :func:`pmabayes.util.show_progress`).
    timing : Timing, optional
        Rates, limits and sensor of the loop.

    Returns
    -------
    xarray.Dataset
        The metrics of :data:`pmabayes.control.METRICS` over ``(sample, frequency,
        controller)``, the parameter values of every sample (``sample`` x
        ``parameter``) and the nominal (mean) parameters, with the settings and the
        gains (JSON) in the attributes.

    Raises
    ------
    ControlError
        On a bad mode, frequency, duration, sample count, chunk size or process count.

    Examples
    --------
    Four plants drawn from a short fit (too short to converge, for the example), each
    tracking 1 Hz with both controllers at the paper's gains (given, so none is tuned):

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.control import DEFAULT_GAINS
    >>> from pmabayes.control.robustness import robustness_sweep
    >>> sweep = robustness_sweep(tree, samples=4, frequencies_hz=[1.0], duration_s=4.0,
    ...                          gains=DEFAULT_GAINS, reference_mean_m=0.1, processes=1)
    >>> dict(sweep.sizes)
    {'sample': 4, 'frequency': 1, 'controller': 2, 'parameter': 6}
    >>> sweep["rms_error_m"].dims
    ('sample', 'frequency', 'controller')
    """
    with show_progress("robustness", progress):
        return _sweep(fit, samples, frequencies_hz, mode, seed, duration_s, gains,
                      reference_mean_m, chunk_size, processes, client, timing)


def _sweep(fit, samples, frequencies_hz, mode, seed, duration_s, gains, reference_mean_m,
           chunk_size, processes, client, timing) -> xr.Dataset:
    """:func:`robustness_sweep`, its progress switched."""
    freqs = _check_sweep(mode, frequencies_hz, duration_s, chunk_size, processes)
    source = str(fit) if isinstance(fit, str | Path) else "(in memory)"
    tree = load_fit(fit) if isinstance(fit, str | Path) else fit
    model = control_model_from_fit(tree)
    timing = Timing() if timing is None else timing
    theta, mean, where = posterior_samples(tree, model, samples, seed)
    given = dict(gains or {})
    unknown = set(given) - set(CONTROLLERS)
    if unknown:
        raise ControlError(f"gains for unknown controllers {sorted(unknown)}; use "
                           f"{', '.join(CONTROLLERS)}")
    mean_source = "given"
    if reference_mean_m is None:
        reference_mean_m = operating_mean_m(model, mean, pressure_max_pa=timing.pressure_max_pa)
        mean_source = "control.operating_mean_m on the posterior mean"
    gains_used = resolve_gains(CONTROLLERS, given, model=model, params=mean, timing=timing,
                               reference_mean_m=reference_mean_m)
    spec = {"effects": list(model.effect_names), "rig": model.rig.to_dict(),
            "fixed": dict(model.fixed), "duration_s": float(duration_s), "timing": timing,
            "reference_mean_m": float(reference_mean_m)}
    jobs = _sweep_jobs(spec, theta, mean, freqs, mode, gain_array(CONTROLLERS, gains_used),
                       int(chunk_size))
    label = (f"({theta.shape[0]} samples x {freqs.size} frequencies x {len(CONTROLLERS)} "
             "controllers)")
    t0 = time.perf_counter()
    flat, runner = _run_sweep(jobs, theta.shape[0] * freqs.size * len(CONTROLLERS), processes,
                              client, Progress("robustness"), label)
    ds = _sweep_dataset(flat, theta, mean, where, freqs, model)
    all_given = all(set(given.get(c, {})) >= set(gains_used[c]) for c in CONTROLLERS)
    seed_attr = (int(seed) if isinstance(seed, int | np.integer)
                 else "a numpy Generator (its state is not stored)")
    ds.attrs.update({
        "mode": mode, "seed": seed_attr, "fit": source,
        "effects": ",".join(model.effect_names) or "none",
        "duration_s": float(duration_s), "reference_mean_m": float(reference_mean_m),
        "reference_mean_source": mean_source,
        "reference_amplitude_m": REFERENCE_AMPLITUDE_M,
        "gains": json.dumps(gains_used),
        "gains_source": ("given" if all_given else
                         "tune_gains on the posterior mean" + (" (some given)" if given else "")),
        "timing": repr(timing), "runner": runner,
        "sweep_seconds": time.perf_counter() - t0,
    })
    return ds


def _check_sweep(mode: str, frequencies_hz, duration_s: float, chunk_size,
                 processes) -> np.ndarray:
    """Refuse bad sweep settings; the frequencies as an array."""
    if mode not in MODES:
        raise ControlError(f"unknown mode {mode!r}; choose 'plant' or 'model'")
    freqs = np.asarray(DEFAULT_FREQUENCIES_HZ if frequencies_hz is None else frequencies_hz,
                       dtype=float).ravel()
    if freqs.size == 0 or not np.all(np.isfinite(freqs) & (freqs > 0)):
        raise ControlError(f"frequencies must be > 0 Hz, got {freqs.tolist()}")
    need = minimum_duration_s(float(freqs.min()))
    if not duration_s >= need:
        raise ControlError(f"duration_s={duration_s} holds no whole period of "
                           f"{freqs.min():g} Hz after the start-up; use at least {need:.3g} s")
    if isinstance(chunk_size, bool) or not (isinstance(chunk_size, int | np.integer)
                                            and chunk_size >= 1):
        raise ControlError(f"chunk_size must be an integer >= 1, got {chunk_size!r}")
    if processes is not None and (isinstance(processes, bool) or not (
            isinstance(processes, int | np.integer) and processes >= 1)):
        raise ControlError(f"processes must be an integer >= 1 (or left out for every core), "
                           f"got {processes!r}")
    return freqs


def _sweep_jobs(spec: dict, theta: np.ndarray, mean: np.ndarray, freqs: np.ndarray, mode: str,
                gain_rows: np.ndarray, chunk_size: int) -> list[dict]:
    """The sweep's members in contiguous chunks; member (s, f, c) is at
    ``(s * n_f + f) * n_c + c``."""
    n_s, n_f, n_c = theta.shape[0], freqs.size, len(CONTROLLERS)
    s_idx, f_idx, c_idx = (a.ravel() for a in np.meshgrid(
        np.arange(n_s), np.arange(n_f), np.arange(n_c), indexing="ij"))
    drawn = theta[s_idx]
    fixed_theta = np.repeat(mean[None, :], len(s_idx), axis=0)
    theta_p, theta_c = (drawn, fixed_theta) if mode == "plant" else (fixed_theta, drawn)
    jobs = []
    for lo in range(0, len(s_idx), chunk_size):
        sl = slice(lo, min(lo + chunk_size, len(s_idx)))
        jobs.append({**spec, "start": lo, "theta_p": theta_p[sl], "theta_c": theta_c[sl],
                     "freq": freqs[f_idx[sl]], "kind": c_idx[sl].copy(),
                     "gains": gain_rows[c_idx[sl]]})
    return jobs


def _run_sweep(jobs: list[dict], n_runs: int, processes, client, bar: Progress,
               label: str) -> tuple[dict, str]:
    """Every chunk's metrics, placed by member index (so the order of completion
    does not matter); and who ran them."""
    flat = {m: np.empty(n_runs) for m in METRICS}
    bar.start(n_runs, "runs", label)
    with Runner(processes, client=client, tasks=len(jobs)) as runner:
        for start, out in runner.map(_run_chunk, jobs, ordered=False):
            n = len(out[METRICS[0]])
            for m in METRICS:
                flat[m][start:start + n] = out[m]
            bar.advance(n)
        return flat, runner.description


def _sweep_dataset(flat: dict, theta: np.ndarray, mean: np.ndarray, where: np.ndarray,
                   freqs: np.ndarray, model: Model) -> xr.Dataset:
    """The metrics over ``(sample, frequency, controller)`` with the parameters and units."""
    shape = (theta.shape[0], freqs.size, len(CONTROLLERS))
    ds = xr.Dataset(
        {m: (("sample", "frequency", "controller"), flat[m].reshape(shape)) for m in METRICS},
        coords={"sample": np.arange(shape[0]), "frequency": freqs,
                "controller": list(CONTROLLERS), "parameter": list(model.parameter_names),
                "chain": ("sample", where[:, 0]), "draw": ("sample", where[:, 1])},
    )
    ds["sample_parameters"] = (("sample", "parameter"), theta)
    ds["nominal_parameters"] = (("parameter",), mean)
    units = {"rms_error_m": "m", "max_error_m": "m", "amplitude_ratio": "1",
             "phase_lag_deg": "deg", "overshoot_pct": "%", "dead_zone_fraction": "1",
             "saturated_fraction": "1", "period_difference_m": "m"}
    for m, u in units.items():
        ds[m].attrs["units"] = u
    ds["frequency"].attrs["units"] = "Hz"
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
        and the same for ``phase_lag_deg``, and the mean ``dead_zone_fraction``; over
        ``frequency``: ``p_ct_beats_pid``, the fraction of samples where computed
        torque has the smaller RMS error, and ``p_ct_beats_pid_mc_error``, its Monte
        Carlo standard error ``sqrt(p (1 - p) / S)``, or ``1 / S`` when ``p`` is 0 or 1
        (where the binomial error vanishes; the 95% bound on the other outcome's
        probability is then about ``3 / S``).

    Examples
    --------
    The sweep of :func:`robustness_sweep`'s example (:func:`example_sweep`), summarised:

    >>> from pmabayes.synthetic import example_fit
    >>> from pmabayes.control.robustness import example_sweep
    >>> sweep = example_sweep(example_fit())  # warns: the fit has not converged
    >>> from pmabayes.control.robustness import summarise_robustness
    >>> summary = summarise_robustness(sweep)
    >>> float(summary["p_ct_beats_pid"].sel(frequency=1.0))
    1.0
    >>> float(summary["p_ct_beats_pid_mc_error"].sel(frequency=1.0))  # 1 / S: 4 samples
    0.25
    """
    out = xr.Dataset(coords={"frequency": ds["frequency"], "controller": ds["controller"]})
    for m in ("rms_error_m", "phase_lag_deg"):
        q = ds[m].quantile([0.05, 0.5, 0.95], dim="sample")
        out[f"{m}_q05"] = q.sel(quantile=0.05, drop=True)
        out[f"{m}_median"] = q.sel(quantile=0.5, drop=True)
        out[f"{m}_q95"] = q.sel(quantile=0.95, drop=True)
    if "dead_zone_fraction" in ds:
        out["dead_zone_fraction_mean"] = ds["dead_zone_fraction"].mean("sample")
    rms = ds["rms_error_m"]
    beats = rms.sel(controller="ct") < rms.sel(controller="pid")
    p = beats.mean("sample")
    n = int(ds.sizes["sample"])
    out["p_ct_beats_pid"] = p
    out["p_ct_beats_pid_mc_error"] = xr.where((p == 0) | (p == 1), 1.0 / n,
                                              np.sqrt(p * (1 - p) / n))
    out.attrs.update({k: ds.attrs[k] for k in ("mode", "seed") if k in ds.attrs})
    out.attrs["samples"] = n
    return out


def write_robustness(ds: xr.Dataset, out_dir) -> dict[str, Path]:
    """Write a sweep and its summary (CSV and Markdown).

    Parameters
    ----------
    ds : xarray.Dataset
        A sweep from :func:`robustness_sweep`.
    out_dir : str or Path
        Output folder (created).

    Returns
    -------
    dict of str to Path
        ``netcdf``, ``summary_csv`` and ``summary_md`` (the figure is
        :func:`pmabayes.report.figures.plot_robustness`).

    Examples
    --------
    The sweep of :func:`robustness_sweep`'s example (:func:`example_sweep`), written:

    >>> from pmabayes.synthetic import example_fit
    >>> from pmabayes.control.robustness import example_sweep
    >>> sweep = example_sweep(example_fit())  # warns: the fit has not converged
    >>> from pmabayes.control.robustness import write_robustness
    >>> paths = write_robustness(sweep, "robustness")
    >>> sorted(str(p) for p in paths.values())
    ['robustness/robustness.nc', 'robustness/summary.csv', 'robustness/summary.md']
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"netcdf": out / "robustness.nc", "summary_csv": out / "summary.csv",
             "summary_md": out / "summary.md"}
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
                         f"{float(s['dead_zone_fraction_mean']):.3f}",
                         f"{float(summary['p_ct_beats_pid'].sel(frequency=f)):.3f}",
                         f"{float(summary['p_ct_beats_pid_mc_error'].sel(frequency=f)):.3f}"])
    head = ["frequency_hz", "controller", "rms_error_mm_median", "rms_error_mm_q05",
            "rms_error_mm_q95", "phase_lag_deg_median", "phase_lag_deg_q05",
            "phase_lag_deg_q95", "dead_zone_fraction_mean", "p_ct_beats_pid",
            "p_ct_beats_pid_mc_error"]
    paths["summary_csv"].write_text("\n".join(",".join(r) for r in [head, *rows]) + "\n")
    md = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    md += ["| " + " | ".join(r) + " |" for r in rows]
    paths["summary_md"].write_text(
        f"Robustness sweep: {ds.sizes['sample']} samples, mode '{ds.attrs.get('mode')}', "
        f"seed {ds.attrs.get('seed')}, fit {ds.attrs.get('fit')}\n\n" + "\n".join(md) + "\n")
    return paths


def example_sweep(tree: xr.DataTree) -> xr.Dataset:
    """The sweep of :func:`robustness_sweep`'s example, for examples and tests.

    Four plants drawn from a fit, each tracking 1 Hz for 4 s with both controllers at
    the paper's gains, in this process.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (:func:`pmabayes.synthetic.example_fit` in the examples).

    Returns
    -------
    xarray.Dataset
        As :func:`robustness_sweep` returns it (seed 0).

    Examples
    --------
    >>> from pmabayes.synthetic import example_fit
    >>> from pmabayes.control.robustness import example_sweep
    >>> dict(example_sweep(example_fit()).sizes)  # warns: the fit has not converged
    {'sample': 4, 'frequency': 1, 'controller': 2, 'parameter': 6}
    """
    return robustness_sweep(tree, samples=4, frequencies_hz=[1.0], duration_s=4.0,
                            gains=DEFAULT_GAINS, reference_mean_m=0.1, processes=1)
