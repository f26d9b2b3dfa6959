"""Honest bands when the model is wrong: the band with the learnt discrepancy, over many
independent synthetic data sets.

Each data set is a muscle of its own, drawn from ``pmabayes.synthetic.PLAUSIBLE_REGION``
with its own seed, measured as the generator measures (AR(1) disturbance, encoder
quantisation), in two cases:

* ``lag``: the plant has a regulator lag (drawn from 30 to 60 ms) that the fitted base
  model lacks. The base model is fitted (``pmabayes.inference.sampler.fit``, MAP and
  emcee posterior) on 6 trials of the 8 s chirp, then validated
  (``pmabayes.criticism.validation.validate``) on 5 trials of each of three other
  inputs: ``chirp``, another chirp over the same band (up or down, 6-12 s long, to a peak
  of 0.35-0.5 MPa: another input of the training input's kind); ``multisine``, a
  random-phase multisine over the chirp's band (0.1-3 Hz) and pressure range; and
  ``steps``, 16 random pressure steps over that range (other kinds of input).
* ``adequate``: the same muscle without the lag, fitted and validated the same way.

For each it records the coverage of the 90% predictive band without the discrepancy
(``coverage_parameters_only``: the parameters and the fit's noise) and with it
(``coverage``), the discrepancy learnt from the training residual (its sd and
correlation time, zero when not significant), and the NRMSE of the physics and of the
two yardsticks on the held-out data.

Usage::

    python analyses/discrepancy_bands.py [--datasets 10] [--seed 0] [--out DIR] [--quick]

``--quick`` runs 2 data sets (CI). ``--out`` writes ``discrepancy_bands.csv`` there.
The table is printed last, after one line per data set and case; its last lines are
``lag_coverage_median: <fraction>`` and ``adequate_coverage_median: <fraction>`` (on the
held-out chirps).
"""

from __future__ import annotations

import argparse
import csv
import math
import time
import warnings
from pathlib import Path

import numpy as np

from pmabayes.criticism.validation import validate
from pmabayes.data import Dataset
from pmabayes.inference.errors import ConvergenceWarning
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.model.simulator import simulate
from pmabayes.synthetic import (
    Chirp,
    MeasurementNoise,
    draw_plausible,
    generate_chirp_dataset,
    hidden_effects_model,
)

RATE_HZ = 1000.0
TRAIN = Chirp(duration_s=8.0)
HELD_OUT_S = 8.0
LAG_RANGE_S = (0.03, 0.06)
COLUMNS = ("dataset", "case", "held_out", "tau_reg_s", "sigma_d_um", "corr_time_s",
           "coverage_parameters_only", "coverage", "nrmse", "nrmse_linear", "nrmse_play",
           "converged", "seconds")


def multisine_pa(rng: np.random.Generator, duration_s: float = HELD_OUT_S) -> np.ndarray:
    """Random-phase multisine over the chirp's band and pressure range, from rest."""
    t = np.arange(int(round(duration_s * RATE_HZ))) / RATE_HZ
    f = np.geomspace(TRAIN.f0_hz, TRAIN.f1_hz, 12)
    s = np.sum(np.sin(2 * np.pi * f[:, None] * t + rng.uniform(0, 2 * np.pi, f.size)[:, None])
               / np.sqrt(f[:, None]), axis=0)
    s = (s - s.min()) / (s.max() - s.min())
    return TRAIN.p_min_pa + (TRAIN.p_max_pa - TRAIN.p_min_pa) * s * np.minimum(t / 0.5, 1.0)


def chirp_pa(rng: np.random.Generator) -> np.ndarray:
    """Another chirp over the training band: up or down, 6-12 s, to 0.35-0.5 MPa."""
    f0, f1 = (TRAIN.f0_hz, TRAIN.f1_hz) if rng.uniform() < 0.5 else (TRAIN.f1_hz, TRAIN.f0_hz)
    return Chirp(f0_hz=f0, f1_hz=f1, duration_s=float(rng.uniform(6.0, 12.0)),
                 p_max_pa=float(rng.uniform(0.35e6, TRAIN.p_max_pa))).pressure_pa()


def steps_pa(rng: np.random.Generator, duration_s: float = HELD_OUT_S) -> np.ndarray:
    """Sixteen random pressure steps over the chirp's range, from rest."""
    t = np.arange(int(round(duration_s * RATE_HZ))) / RATE_HZ
    levels = np.r_[TRAIN.p_min_pa, rng.uniform(TRAIN.p_min_pa, TRAIN.p_max_pa, 15)]
    return levels[np.minimum((t / (duration_s / 16)).astype(int), 15)]


def held_out(params: dict, effects: dict | None, pressure: np.ndarray,
             rng: np.random.Generator, source: str) -> Dataset:
    """Five trials of the plant on a held-out input, measured as the generator does."""
    model, values = hidden_effects_model(effects)
    values = {**model.defaults, **params, **values}
    t = np.arange(pressure.size) / RATE_HZ
    x = simulate(model, values, pressure, time_s=t)[0]
    y = MeasurementNoise().apply(np.repeat(x[None], 5, axis=0), 1.0 / RATE_HZ, rng)
    return Dataset(time_s=t, input=np.repeat(pressure[None], 5, axis=0), position_m=y,
                   trial_ids=np.arange(5), metadata={"synthetic": True,
                                                     "rig": model.rig.to_dict()},
                   source=source)


def one(dataset: int, seed: int, case: str, settings: FitSettings) -> list[dict]:
    """Fit one data set in one case and validate it on both held-out inputs; its rows."""
    rng = np.random.default_rng([seed, dataset])
    params = draw_plausible(rng)
    tau = float(rng.uniform(*LAG_RANGE_S))
    inputs = {"chirp": chirp_pa(rng), "multisine": multisine_pa(rng), "steps": steps_pa(rng)}
    effects = {"regulator_lag": tau} if case == "lag" else None
    train = generate_chirp_dataset(n_trials=6, seed=int(rng.integers(2**31)), chirp=TRAIN,
                                   params=params, effects=effects)
    tests = [held_out(params, effects, u, np.random.default_rng([seed, dataset, k]),
                      f"{kind}_{dataset}.csv")
             for k, (kind, u) in enumerate(inputs.items())]
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        tree = fit(train, seed=seed + dataset, settings=settings)
    v = validate(tree, tests, seed=seed + dataset)
    d = v.discrepancy
    converged = not any(issubclass(w.category, ConvergenceWarning) for w in caught)
    return [{"dataset": dataset, "case": case, "held_out": kind,
             "tau_reg_s": tau if case == "lag" else 0.0, "sigma_d_um": d.sigma_m * 1e6,
             "corr_time_s": d.corr_time_s if d.significant else math.nan,
             "coverage_parameters_only": e.coverage_parameters_only, "coverage": e.coverage,
             "nrmse": e.nrmse, "nrmse_linear": e.baselines["linear"]["nrmse"],
             "nrmse_play": e.baselines["play"]["nrmse"], "converged": converged,
             "seconds": time.perf_counter() - start}
            for kind, e in zip(inputs, v.experiments, strict=True)]


def table(rows: list[dict]) -> list[str]:
    """The study's table: one line per case and held-out input."""
    out = ["| case | held out | data sets | coverage without the discrepancy (median, "
           "min-max) | with (median, min-max) | inside 80-97% with | discrepancy sd [um] "
           "(median) | NRMSE physics / linear / play (median) |",
           "|---|---|---:|---|---|---:|---:|---|"]
    for case, kind in [(c, k) for c in ("lag", "adequate")
                       for k in ("chirp", "multisine", "steps")]:
        rs = [r for r in rows if r["case"] == case and r["held_out"] == kind]
        if not rs:
            continue
        p = np.array([r["coverage_parameters_only"] for r in rs])
        c = np.array([r["coverage"] for r in rs])
        inside = int(np.sum((c >= 0.8) & (c <= 0.97)))
        nr = [np.median([r[k] for r in rs]) for k in ("nrmse", "nrmse_linear", "nrmse_play")]
        out.append(f"| {case} | {kind} | {len(rs)} | {np.median(p):.3f} ({p.min():.3f}-"
                   f"{p.max():.3f}) | "
                   f"{np.median(c):.3f} ({c.min():.3f}-{c.max():.3f}) | {inside} of {len(rs)} | "
                   f"{np.median([r['sigma_d_um'] for r in rs]):.4g} | "
                   + " / ".join(f"{v:.3g}" for v in nr) + " |")
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the study and print its table last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    n = args.datasets if args.datasets is not None else (2 if args.quick else 10)
    settings = FitSettings(progress=False)
    rows = []
    for k in range(n):
        for case in ("lag", "adequate"):
            for row in one(k, args.seed, case, settings):
                rows.append(row)
                print(" ".join(f"{c}={row[c]:.4g}" if isinstance(row[c], float)
                               else f"{c}={row[c]}" for c in COLUMNS), flush=True)
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        with (Path(args.out) / "discrepancy_bands.csv").open("w", newline="") as fh:
            w = csv.DictWriter(fh, COLUMNS, lineterminator="\n")
            w.writeheader()
            w.writerows(rows)
    print("\n".join(table(rows)))
    for case in ("lag", "adequate"):
        cov = [r["coverage"] for r in rows if r["case"] == case and r["held_out"] == "chirp"]
        print(f"{case}_coverage_median: {np.median(cov):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
