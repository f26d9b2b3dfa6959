"""Wall time to a converged posterior on the bundled 10-trial data set.

Fits ``data/pma_chirp_paper.csv`` (synthetic, made by the paper's model) with the
base model and the default sampler settings: global search, MAP, then emcee
ensembles until every parameter has R-hat across ensembles below 1.01, an ESS of at
least 400 and a kept chain at least 20 autocorrelation times long. Compiling the
simulator (first use on a machine) is done before the clock starts and reported
separately.

It also prints the work done, which load on a shared machine does not change: the
model simulations of the global search and MAP (counted in this process) and the
walker-steps of the sampler (each at most one simulation).

With ``--single-record`` it fits instead one synthetic 60 s record without repeats
(a 0.1-3 Hz chirp at 1 kHz, 60,000 samples, from the paper's parameters, with the fast
AR(1) disturbance of ``analyses/calibration.py --single record``, 20 um and 2 ms, plus
encoder quantisation), whose noise is sampled with the model.

Usage::

    python analyses/bench_posterior.py [--data PATH | --single-record] [--seed S]

The last line printed is ``posterior_seconds: <number>``. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

from pmabayes import Model, simulate
from pmabayes.data import load
from pmabayes.inference.fitfile import fit_info
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

DEFAULT_DATA = Path(__file__).resolve().parents[1] / "data" / "pma_chirp_paper.csv"
#: the fast disturbance of a record without repeats (calibration.py's RECORD_NOISE)
SINGLE_RECORD_NOISE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002)


def main(argv: list[str] | None = None) -> int:
    """Fit, print the diagnostics, and print ``posterior_seconds`` last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--single-record", action="store_true",
                        help="fit one synthetic 60 s record without repeats instead")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.single_record:
        dataset = generate_chirp_dataset(
            n_trials=1, seed=args.seed, noise=SINGLE_RECORD_NOISE,
            chirp=Chirp(duration_s=60.0, f0_hz=0.1, f1_hz=3.0, sample_rate_hz=1000.0),
            description="synthetic 60 s single record made by analyses/bench_posterior.py "
                        "(not measured)")
        args.data = "synthetic 60 s single record"
    else:
        dataset = load(args.data)
    start = time.perf_counter()
    simulate(Model(), None, dataset.input[0][:10], dt_s=dataset.dt_s)  # compile or load
    compile_s = time.perf_counter() - start

    counted = _count_simulations()
    cpu_start = _cpu_seconds()
    start = time.perf_counter()
    tree = fit(dataset, Model(), seed=args.seed, settings=FitSettings(progress=True))
    seconds = time.perf_counter() - start
    cpu = _cpu_seconds() - cpu_start
    info = fit_info(tree)
    conv = info["convergence"]
    print(f"data: {args.data} ({dataset.n_trials} trials x {dataset.n_samples} samples)")
    print(f"kernel compile/load before timing: {compile_s:.1f} s")
    print(f"converged: {conv['converged']} after {conv['n_steps']} steps x "
          f"{conv['n_ensembles']} ensembles x {conv['n_walkers']} walkers"
          + ("" if conv["converged"] else " -- " + "; ".join(conv["messages"])))
    print(f"{'parameter':<15}{'tau':>8}{'ESS':>9}{'R-hat ens':>11}{'R-hat walkers':>15}")
    for name in conv["tau"]:
        rhat_e = conv["rhat_ensembles"][name] if conv["rhat_ensembles"] else float("nan")
        print(f"{name:<15}{conv['tau'][name]:>8.1f}{conv['ess'][name]:>9.0f}"
              f"{rhat_e:>11.4f}{conv['rhat'][name]:>15.4f}")
    n_walker_steps = conv["n_steps"] * conv["n_ensembles"] * conv["n_walkers"]
    print(f"work: {counted['map']} simulations in the global search and MAP, "
          f"{n_walker_steps} walker-steps in sampling; {cpu:.1f} CPU s (this process and "
          f"its sampler processes; less sensitive than the wall time to a shared machine)")
    t = info["timings_s"]
    print(f"MAP {t['map']:.1f} s, sampling {t['sampling']:.1f} s, total {t['total']:.1f} s; "
          f"min ESS {min(conv['ess'].values()):.0f}, "
          f"max R-hat across ensembles {max(conv['rhat_ensembles'].values()):.4f}")
    print(f"posterior_seconds: {seconds:.1f}")
    return 0 if np.isfinite(seconds) else 1


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished child processes."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _count_simulations() -> dict:
    """Count the parameter sets simulated in this process (the global search and MAP;
    the sampler runs in its own processes and is counted by its walker-steps)."""
    counted = {"map": 0}
    simulate_rows = Likelihood.simulate

    def counting(self, theta):
        counted["map"] += int(np.atleast_2d(theta).shape[0])
        return simulate_rows(self, theta)

    Likelihood.simulate = counting
    return counted


if __name__ == "__main__":
    sys.exit(main())
