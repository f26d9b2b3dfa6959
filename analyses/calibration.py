"""Calibration of the posterior intervals: do 90% intervals cover the truth 90% of the time?

Fits many synthetic data sets, each drawn with its own seed and its own base-model
parameters from ``pmabayes.synthetic.PLAUSIBLE_REGION``, with the default
measurement (AR(1) disturbance and encoder quantisation), and counts per parameter
how often the 90% HDI covers the true value. Well calibrated: between 80% and 97%
for every parameter (20 data sets give a binomial standard error of 6.7%).

Usage::

    python analyses/calibration.py [--datasets 20] [--seed 0] [--out DIR] [--quick]
                                   [--processes N | --dask ADDRESS]
                                   [--single {record,periodic}]
                                   [--noise {default,two-scale}]
                                   [--noise-model {auto,ar1,ar}]
                                   [--measured-inputs]
                                   [--disturbance-ms MS] [--diagnose]

Writes ``calibration.csv`` and ``calibration.md`` into ``--out`` (default
``paper/tables``). The last line printed is ``coverage_min: <fraction>``. ``--quick``
uses 4 short data sets (as in the tests). ``--dask tcp://HOST:8786`` runs the fits on
that Dask scheduler's workers instead of local processes (``pip install pmabayes[dask]``
here and on the workers); the rows are the same.

``--single`` calibrates fits of single records instead of repeated chirps (files
``calibration_single_MODE.*``):

* ``record``: one chirp record, no repeats, not periodic (0.2 to 3 Hz over 8 s at
  500 Hz). Its noise is identified with the model under the bound of
  :mod:`pmabayes.inference.likelihood` (a correlation time of at most a tenth of the
  record): the measurement is an AR(1) disturbance of 20 um and 2 ms correlation
  time, plus encoder quantisation.
* ``periodic``: one record of 4 periods of a 2 s multisine (harmonics 1 to 4 of
  0.5 Hz, phases from the data set's seed) from rest, at 500 Hz, with the default
  measurement (AR(1) of 60 um and 0.1 s, quantised). Periods 2 to 4 are the
  noise's repeats.

``--measured-inputs`` draws repeated chirps whose inputs are measured, as a lab's are
(files ``calibration_measured_inputs.*``): each trial is driven by the command through
a regulator, a first-order lag whose time constant is drawn per trial in 2-6 ms, and
records the pressure a transducer measures, with white noise of 0.3% of its 0.5 MPa
full scale (:class:`pmabayes.synthetic.Regulator`). Each trial is then simulated on its
own measured input, and the noise is learnt from the trials' residuals at the MAP
(:mod:`pmabayes.inference.likelihood`). Its rows add each data set's noise floor from
those residuals (``noise_floor_referred_m``: the fit's ``noise_floor_m``) beside the
floor of the drawn noise alone (``noise_floor_drawn_m``).

``--disturbance-ms MS`` sets a single record's disturbance correlation time (the
``record``'s 2 ms or the ``periodic``'s 100 ms by default; its standard deviation
stays the mode's), and the files get ``_MSms`` in their name. ``--diagnose`` also
judges each fit's adequacy (:func:`pmabayes.report.verdicts.fit_adequacy`) and
diagnoses each data set (:func:`pmabayes.diagnose` with :data:`FAST_CANDIDATES`,
one refit, no discrepancy step), and prints the fractions called adequate and
with an effect named missing.

``--noise two-scale`` draws the repeated chirps' disturbance with two time scales
(:data:`TWO_SCALE_NOISE`: 20 um of 10 ms correlation time plus 50 um of 1 s, then
encoder quantisation), which the likelihood's AR(1) + white noise model does not
describe; ``--noise-model`` chooses the fits' noise model (:func:`pmabayes.inference.sampler.fit`'s
``noise_model``: ``auto``, the default, uses the repeats' AR(p) where they reject
AR(1) + white). Its files are ``calibration_two-scale_NOISEMODEL.*``. With
``--quick``, ``--datasets`` still sets the number of (short) data sets.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import arviz as az
import numpy as np

from pmabayes import Model, simulate
from pmabayes.data import Dataset
from pmabayes.inference.batch import dask_client
from pmabayes.inference.fitfile import fit_info
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.parallel import Runner
from pmabayes.synthetic import (
    Chirp,
    MeasurementNoise,
    Regulator,
    draw_plausible,
    generate_chirp_dataset,
)

PARAMS = ("alpha", "beta", "gamma", "d", "K_e", "p_dz")  # the noise has no single truth
SINGLE_MODES = ("record", "periodic")
#: the single non-periodic record's chirp and measurement (a fast disturbance)
RECORD_CHIRP = Chirp(duration_s=8.0, f0_hz=0.2, f1_hz=3.0, sample_rate_hz=500.0)
RECORD_NOISE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002)
#: a disturbance of two time scales (``--noise two-scale``)
TWO_SCALE_NOISE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.010,
                                   slow_std_m=50e-6, slow_corr_time_s=1.0)
NOISES = {"default": MeasurementNoise(), "two-scale": TWO_SCALE_NOISE}
#: the periodic single record's measurement (the default: 60 um, 0.1 s)
PERIODIC_NOISE = MeasurementNoise()
#: ``--diagnose``'s candidates: a slow state (creep), a force (friction) and a lag,
#: the kinds a slow disturbance could be taken for
FAST_CANDIDATES = ("maxwell_creep", "coulomb_friction", "regulator_lag")


def single_noise(single: str, disturbance_ms: float | None) -> MeasurementNoise:
    """A single record's measurement: the mode's, with its disturbance's correlation
    time set to ``disturbance_ms`` when given."""
    noise = RECORD_NOISE if single == "record" else PERIODIC_NOISE
    if disturbance_ms is None:
        return noise
    return replace(noise, disturbance_corr_time_s=disturbance_ms * 1e-3)


def periodic_record(truth: dict, seed: int, *, period_s: float = 2.0, n_periods: int = 4,
                    rate_hz: float = 500.0, noise: MeasurementNoise = PERIODIC_NOISE
                    ) -> Dataset:
    """One synthetic record of ``n_periods`` periods of a multisine, from rest.

    Harmonics 1 to 4 of ``1 / period_s`` with phases drawn from ``seed``, scaled to
    0.05-0.45 MPa; the measurement ``noise`` (the default :class:`MeasurementNoise`).
    Declared periodic (``period_samples``), starting from rest.
    """
    rng = np.random.default_rng(seed)
    period = int(round(period_s * rate_hz))
    t = np.arange(n_periods * period) / rate_hz
    phases = rng.uniform(0, 2 * np.pi, 4)
    u = sum(np.sin(2 * np.pi * (k + 1) * t / period_s + phases[k]) for k in range(4))
    u = 0.05e6 + 0.4e6 * (u - u.min()) / (u.max() - u.min())
    model = Model()
    x = simulate(model, truth, u, time_s=t)[0]
    y = noise.apply(x[None], 1.0 / rate_hz, rng)
    meta = {"synthetic": True, "sample_rate_hz": rate_hz, "rig": model.rig.to_dict(),
            "period_samples": period, "starts_in_steady_state": False,
            "description": "synthetic periodic multisine record made by analyses/calibration.py "
                           "(not measured)"}
    return Dataset(time_s=t, input=u[None], position_m=y, trial_ids=np.arange(1),
                   metadata=meta, source=f"periodic_{seed}.csv")


def draw_jobs(n_datasets: int, seed: int) -> list[dict]:
    """The study's data sets, drawn in order from ``seed``: per data set its
    ``index``, ``truth`` (:func:`pmabayes.synthetic.draw_plausible`) and data ``seed``."""
    rng = np.random.default_rng(seed)
    jobs = []
    for i in range(n_datasets):
        truth = draw_plausible(rng)
        jobs.append({"index": i, "truth": truth, "seed": int(rng.integers(2**31))})
    return jobs


def calibrate(n_datasets: int, seed: int, *, chirp: Chirp | None = None, n_trials: int = 10,
              settings: FitSettings | None = None, verbose: bool = True,
              processes: int | None = None, single: str | None = None,
              client=None, noise: str = "default", noise_model: str = "auto",
              measured_inputs: bool = False, disturbance_ms: float | None = None,
              judge: bool = False) -> list[dict]:
    """Fit ``n_datasets`` synthetic data sets; one row per data set and parameter.

    The data sets are drawn here, in order, from ``seed``; their fits run on
    :class:`pmabayes.parallel.Runner` (``processes`` local workers, every core by
    default, or the Dask ``client``'s workers), each fit in one process, so the rows do
    not depend on how they ran. Run as a script, Dask sends this module's functions by
    value; called from Python with a client, the scheduler and the workers must be able
    to import this module (``analyses/`` on their ``PYTHONPATH``).
    ``single`` (``"record"`` or ``"periodic"``) fits single records instead of
    ``n_trials`` repeated chirps (see the module's docstring). ``noise`` (a key of
    :data:`NOISES`) is the repeated chirps' measurement, and ``noise_model`` the fits'
    (:func:`pmabayes.inference.sampler.fit`). ``measured_inputs`` gives each trial its
    own measured input (:class:`pmabayes.synthetic.Regulator`). ``disturbance_ms`` sets a
    single record's disturbance correlation time (:func:`single_noise`); ``judge`` adds
    each fit's adequacy and its diagnosis (``--diagnose``) to the rows.
    """
    if single is not None and single not in SINGLE_MODES:
        raise ValueError(f"single must be one of {SINGLE_MODES} or None, got {single!r}")
    jobs = [{**job, "chirp": chirp, "n_trials": n_trials, "single": single, "noise": noise,
             "noise_model": noise_model, "measured_inputs": measured_inputs,
             "disturbance_ms": disturbance_ms, "judge": judge}
            for job in draw_jobs(n_datasets, seed)]
    runner = Runner(processes, client=client, tasks=n_datasets)
    settings = FitSettings() if settings is None else settings
    if not runner.local:  # the data sets share the cores; a fit needs no pool of its own
        settings = replace(settings, processes=1)
    rows = []
    with runner:
        for job_rows, seconds in runner.map(_calibrate_one,
                                            [{**j, "settings": settings} for j in jobs]):
            rows += job_rows
            if verbose:
                first = job_rows[0]
                covered = sum(r["covered"] for r in job_rows)
                judged = (f", adequate={first['adequate']}, named={first['named'] or '-'}"
                          if "adequate" in first else "")
                print(f"data set {first['dataset'] + 1}/{n_datasets} (seed {first['seed']}): "
                      f"{covered}/{len(PARAMS)} covered, converged={first['converged']}"
                      f"{judged}, {seconds:.0f} s", flush=True)
    return rows


def _calibrate_one(job: dict) -> tuple[list[dict], float]:
    """Fit one data set; its rows and the seconds it took."""
    truth, data_seed = job["truth"], job["seed"]
    if job.get("single") == "periodic":
        ds = periodic_record(truth, data_seed,
                             noise=single_noise("periodic", job.get("disturbance_ms")))
    elif job.get("single") == "record":
        ds = generate_chirp_dataset(n_trials=1, seed=data_seed, chirp=RECORD_CHIRP,
                                    noise=single_noise("record", job.get("disturbance_ms")),
                                    params=truth)
    else:
        regulator = Regulator() if job.get("measured_inputs") else None
        ds = generate_chirp_dataset(n_trials=job["n_trials"], seed=data_seed,
                                    chirp=job["chirp"], params=truth,
                                    noise=NOISES[job.get("noise", "default")],
                                    regulator=regulator)
    extra = {}
    if job.get("measured_inputs"):  # the drawn noise alone: the same draws without it
        clean = generate_chirp_dataset(n_trials=job["n_trials"], seed=data_seed,
                                       chirp=job["chirp"], params=truth, noise=None,
                                       regulator=Regulator())
        e = ds.position_m - clean.position_m
        extra["noise_floor_drawn_m"] = float(np.sqrt(np.mean(e.var(axis=0, ddof=1))
                                                     / e.shape[0]))
    start = time.perf_counter()
    tree = fit(ds, Model(), seed=data_seed,
               settings=replace(job["settings"], noise_model=job.get("noise_model", "auto")))
    info = fit_info(tree)
    check = info["experiments"][0].get("metadata", {}).get("disturbance_check")
    if check is not None:  # a record whose noise sat at the fast bound (settle_disturbance)
        slow = check["rms_slow_m"]
        extra["disturbance_kept"] = check["kept"]
        extra["slow_rms_ratio"] = math.nan if slow is None else slow / check["rms_fast_m"]
    hdi = az.hdi(tree, prob=0.9)
    rows = []
    for name in PARAMS:
        lo, hi = (float(v) for v in hdi[name].values)
        draws = tree["posterior"][name].values
        rows.append({"dataset": job["index"], "seed": data_seed, "parameter": name,
                     "truth": truth[name], "hdi90_low": lo, "hdi90_high": hi,
                     "covered": bool(lo <= truth[name] <= hi),
                     "z": float((truth[name] - draws.mean()) / draws.std()),
                     "converged": info["convergence"]["converged"],
                     "noise_model": info["experiments"][0]["noise_model"]["model"], **extra})
        if job.get("measured_inputs"):
            rows[-1]["noise_floor_referred_m"] = info["experiments"][0]["noise_floor_m"]
    if job.get("judge"):
        verdict = _judge(tree, ds, data_seed)
        rows = [{**r, **verdict} for r in rows]
    return rows, time.perf_counter() - start


def _judge(tree, ds: Dataset, seed: int) -> dict:
    """The fit's adequacy verdict (and whether it says the noise is slow), and the effect
    a fast diagnosis names missing (empty when none)."""
    from pmabayes import diagnose
    from pmabayes.criticism import DiagnoseSettings
    from pmabayes.report.verdicts import fit_adequacy

    adequacy = fit_adequacy(tree, dataset=ds)
    found = diagnose(ds, seed=seed, plugin_dir=False, settings=DiagnoseSettings(
        candidates=FAST_CANDIDATES, max_refits=1, discrepancy=False))
    return {"adequate": bool(adequacy.adequate), "slow_noise_said": bool(adequacy.noise_note),
            "diagnosis_adequate": bool(found.adequate), "named": found.missing or ""}


def coverage(rows: list[dict]) -> dict[str, float]:
    """Fraction of covering intervals per parameter."""
    return {p: float(np.mean([r["covered"] for r in rows if r["parameter"] == p]))
            for p in PARAMS}


def z_spread(rows: list[dict]) -> dict[str, float]:
    """Standard deviation over data sets of (truth - posterior mean) / posterior sd.

    About 1 when calibrated; above 1 when intervals are too narrow. More sensitive
    than coverage counts.
    """
    return {p: float(np.sqrt(np.mean([r["z"] ** 2 for r in rows if r["parameter"] == p])))
            for p in PARAMS}


def judged_line(rows: list[dict]) -> str:
    """``--diagnose``'s fractions over data sets: called adequate by the fit's verdict,
    told that the noise is slow, called adequate by ``diagnose``, and with an effect
    named missing."""
    first = {r["dataset"]: r for r in rows}.values()
    n = len(first)

    def frac(key) -> str:
        k = sum(1 for r in first if key(r))
        return f"{k}/{n} = {k / n:.0%}"

    named = sorted({r["named"] for r in first if r["named"]})
    return (f"adequate (fit): {frac(lambda r: r['adequate'])}; slow noise said: "
            f"{frac(lambda r: r['slow_noise_said'])}; adequate (diagnose): "
            f"{frac(lambda r: r['diagnosis_adequate'])}; an effect named: "
            f"{frac(lambda r: r['named'])}" + (f" ({', '.join(named)})" if named else ""))


def main(argv: list[str] | None = None) -> int:
    """Run the study, write the tables and print ``coverage_min`` last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=None,
                        help="number of data sets (20; 4 with --quick)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1]
                        / "paper" / "tables")
    parser.add_argument("--quick", action="store_true", help="4 short data sets")
    parser.add_argument("--processes", type=int, default=None,
                        help="local worker processes (every core by default)")
    parser.add_argument("--single", choices=SINGLE_MODES, default=None,
                        help="calibrate fits of single records: 'record' (one chirp, no "
                        "repeats) or 'periodic' (one multisine record, its periods as repeats)")
    parser.add_argument("--steps", type=int, default=None,
                        help="budget of sampler steps per ensemble (FitSettings' default)")
    parser.add_argument("--noise", choices=tuple(NOISES), default="default",
                        help="the repeated chirps' measurement: 'default' (AR(1) disturbance) "
                        "or 'two-scale' (a disturbance of two time scales)")
    parser.add_argument("--noise-model", choices=("auto", "ar1", "ar"), default="auto",
                        help="the fits' noise model (pmabayes fit --noise-model)")
    parser.add_argument("--measured-inputs", action="store_true",
                        help="repeated chirps whose trials each record their own measured "
                        "pressure (a regulator's lag of 2-6 ms drawn per trial, a "
                        "transducer's noise of 0.3%% of full scale)")
    parser.add_argument("--disturbance-ms", type=float, default=None, metavar="MS",
                        help="a single record's disturbance correlation time in ms (the "
                        "record's 2, the periodic record's 100 by default)")
    parser.add_argument("--diagnose", action="store_true",
                        help="judge each fit's adequacy and diagnose each data set (fast "
                        "candidates), and print the fractions adequate and named")
    parser.add_argument("--dask", metavar="ADDRESS", default=None,
                        help="run the fits on this Dask scheduler (tcp://HOST:8786)")
    args = parser.parse_args(argv)
    if args.dask is not None and args.processes is not None:
        parser.error("give --processes or --dask, not both")
    if args.single is not None and (args.noise != "default" or args.measured_inputs):
        parser.error("--noise and --measured-inputs apply to repeated chirps, not to --single")
    if args.single is None and args.disturbance_ms is not None:
        parser.error("--disturbance-ms applies to --single records")
    if args.disturbance_ms is not None and not args.disturbance_ms > 0:
        parser.error(f"--disturbance-ms must be > 0, got {args.disturbance_ms}")
    chirp, n_trials, n = None, 10, args.datasets or 20
    if args.quick:
        chirp, n_trials, n = Chirp(duration_s=5.0, f1_hz=2.0), 4, args.datasets or 4
    settings = FitSettings() if args.steps is None else FitSettings(max_steps=args.steps)
    stem = "calibration" if args.single is None else f"calibration_single_{args.single}"
    if args.disturbance_ms is not None:
        stem += f"_{args.disturbance_ms:g}ms"
    if args.noise != "default":
        stem = f"calibration_{args.noise}_{args.noise_model}"
    if args.measured_inputs:
        stem = "calibration_measured_inputs" + (
            "" if args.noise == "default" else f"_{args.noise}_{args.noise_model}")
    start = time.perf_counter()
    with (dask_client(args.dask) if args.dask is not None
          else contextlib.nullcontext()) as client:
        rows = calibrate(n, args.seed, chirp=chirp, n_trials=n_trials,
                         processes=args.processes, single=args.single, settings=settings,
                         client=client, noise=args.noise, noise_model=args.noise_model,
                         measured_inputs=args.measured_inputs,
                         disturbance_ms=args.disturbance_ms, judge=args.diagnose)
    cov = coverage(rows)
    spread = z_spread(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / f"{stem}_fits.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        writer.writeheader()
        writer.writerows(rows)
    with open(args.out / f"{stem}.csv", "w", newline="") as fh:
        fh.write("parameter,coverage_90,rms_z,n_datasets\n")
        for p, c in cov.items():
            fh.write(f"{p},{c:.3f},{spread[p]:.3f},{n}\n")
    lines = ["| parameter | 90% HDI coverage | RMS of z (1 if calibrated) |", "|---|---|---|"]
    lines += [f"| `{p}` | {c:.0%} ({round(c * n)}/{n}) | {spread[p]:.2f} |"
              for p, c in cov.items()]
    (args.out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if args.measured_inputs:
        floors = {r["dataset"]: (r["noise_floor_referred_m"], r["noise_floor_drawn_m"])
                  for r in rows}
        ratio = np.array([a / b for a, b in floors.values() if a is not None])
        print(f"noise floor from the trials' residuals at the MAP over the drawn noise's: "
              f"median {np.median(ratio):.3f}, range {ratio.min():.3f}-{ratio.max():.3f}")
    n_conv = len({r["dataset"] for r in rows if r["converged"]})
    print(f"{n} data sets, {n_conv} converged, {time.perf_counter() - start:.0f} s")
    checked = {r["dataset"]: r for r in rows if "disturbance_kept" in r}
    if checked:
        ratios = [r["slow_rms_ratio"] for r in checked.values()]
        kept = sum(r["disturbance_kept"] == "slow" for r in checked.values())
        print(f"noise at the fast bound in {len(checked)}/{n} records; slow disturbance kept "
              f"in {kept}; model RMS error slow/fast {min(ratios):.4f}-{max(ratios):.4f}")
    if args.diagnose:
        print(judged_line(rows))
    print(f"coverage_min: {min(cov.values()):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
