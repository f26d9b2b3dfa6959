"""Does an experiment designed for a parameter shrink its interval more than a default chirp?

For two targets and several seeds: synthetic data of a small, slow first experiment (a
0.1-0.5 Hz chirp over 100-160 kPa, 6 s at 200 Hz, 4 trials, of a muscle drawn from
:data:`pmabayes.synthetic.PLAUSIBLE_REGION` by the seed) on which the target is poorly
identified. ``pmabayes design --goal parameters`` fits the model on it (the MAP and its
Laplace covariance) and chooses the next experiment of the same length within 0-500 kPa,
which is then simulated from the true model and measured with the generator's noise
(:class:`~pmabayes.synthetic.MeasurementNoise`). The same is done with a default chirp
over the input range (0.33-3 Hz, the design's own ``default_chirp``) in its place. The
model is fitted on the first and the next experiment together as the design fits
(:func:`pmabayes.design.fit_candidate`: the MAP search and its Laplace covariance, the
same settings for every arm), and the target's 90% equal-tailed interval is read from
that Laplace approximation (in the fit's unconstrained coordinates, a positive
parameter's log, mapped back: the interval's ends are exact quantiles of that
approximation). Printed per case: the widths, the design's expected factor and the one
reached; printed last: on how many cases the designed experiment left the narrower
interval, and the median factor ``width after the default chirp / width after the
designed experiment``.

The targets:

``area``
    The muscle's area ``rig_area_m2``, declared as a prior (``LogNormal(1e-4, 1.5)``)
    on a rig with one dead load of 0.1 kg whose sensor is zeroed at rest at the record's
    start (``"position_reference": "start"``, as the real cavatappi records are): the
    static sag of a load is not seen, and the area is identified only through the load's
    inertia. The design may hang any dead load of 0.1 to 0.5 kg (as that lab has) in
    place of the first record's (its sidecar declares it: ``"conditions": {"load_kg":
    0.1}``); the default chirp runs on the first load, as the rig stands. A third arm, the
    default chirp on the load the design chose, says how much of the gain is the load
    and how much the pressure profile.
``K_e``
    The linear spring ``K_e`` of the base model on the characterisation rig (absolute
    positions): on a small chirp the muscle stays near its pre-yield stiffness
    ``K_e + alpha``, which the data fix, not ``K_e`` alone. No loads.

Usage: ``python analyses/design_parameters_study.py [--seeds N] [--cases area,K_e]
[--experiments N] [--draws N]``; ``--quick`` is one seed, 10 candidate experiments and
16 draws.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time

import numpy as np

from pmabayes.data import Dataset
from pmabayes.design import design, fit_candidate
from pmabayes.model.model import CARRIAGE_MASS_KG, PAPER_AREA_M2, PMA_MASS_KG, Model, Rig
from pmabayes.model.simulator import simulate
from pmabayes.synthetic import Chirp, MeasurementNoise, draw_plausible

RANGE_PA = (0.0, 5e5)
NOISE = MeasurementNoise()
N_TRIALS = 4
FIRST = Chirp(f0_hz=0.1, f1_hz=0.5, duration_s=6.0, p_min_pa=1.0e5, p_max_pa=1.6e5,
              sample_rate_hz=200.0)
AREA_PRIOR = "LogNormal(1e-4, 1.5)"
#: dead loads the design may hang in place of the first record's, kg
AREA_LOADS_KG = (0.1, 0.2, 0.3, 0.4, 0.5)

#: per target: the dead load of the first rig (kg), its area prior or None (the area
#: known), whether the sensor is zeroed at the start, and the loads the design may hang
CASES = {
    "area": {"parameter": "rig_area_m2", "load_kg": 0.1, "prior": AREA_PRIOR,
             "relative": True, "loads": AREA_LOADS_KG},
    "K_e": {"parameter": "K_e", "load_kg": 0.0, "prior": None, "relative": False,
            "loads": None},
}


def _rig(case: dict, load_kg: float | None = None) -> Rig:
    """The true rig: the characterisation rig's carriage and muscle, the dead load (the
    case's first one, or the one an experiment hangs instead), the paper's area."""
    load = case["load_kg"] if load_kg is None else load_kg
    return Rig(CARRIAGE_MASS_KG + PMA_MASS_KG + load, 1.0, PAPER_AREA_M2,
               name=f"dead_load_{load:g}kg")


def _measure(case: dict, truth: dict, u: np.ndarray, t: np.ndarray, load_kg: float | None,
             rng: np.random.Generator, name: str) -> Dataset:
    """An experiment simulated from the true model and measured: the generator's noise
    and encoder; the sensor zeroed at the true rest position where the case says so; the
    sidecar's rig with the area as the case's prior where it has one."""
    rig = _rig(case, load_kg)
    model = Model([], rig=rig)
    x = simulate(model, {**model.defaults, **truth}, u, time_s=t)[0]
    if case["relative"]:
        x = x - x[0]  # the sensor reads zero at rest under the load
    y = NOISE.apply(np.repeat(x[None], N_TRIALS, axis=0), t[1] - t[0], rng)
    declared = rig.to_dict()
    if case["prior"] is not None:
        declared["area_m2"] = case["prior"]
    meta = {"synthetic": True, "rig": declared,
            "conditions": {"load_kg": case["load_kg"] if load_kg is None else load_kg}}
    if case["relative"]:
        meta["position_reference"] = "start"
    return Dataset(time_s=t, input=np.repeat(u[None], N_TRIALS, axis=0), position_m=y,
                   trial_ids=np.arange(N_TRIALS), input_name="pressure_pa", metadata=meta,
                   source=f"{name}.csv")


def _interval(fit, parameter: str, level: float = 0.9) -> tuple[float, float]:
    """The parameter's equal-tailed interval under the fit's Laplace approximation."""
    post = fit.posterior
    k = list(post.names).index(parameter)
    sd = math.sqrt(float(np.asarray(fit.map.covariance_z)[k, k]))
    q = statistics.NormalDist().inv_cdf(0.5 + level / 2)
    z = np.repeat(np.asarray(fit.map.z, dtype=float)[None], 2, axis=0)
    z[:, k] += np.array([-q, q]) * sd
    lo, hi = post.to_natural(z)[:, k]
    return float(lo), float(hi)


def _words(lo: float, hi: float, true: float) -> str:
    return (f"[{lo:.4g}, {hi:.4g}] width {hi - lo:.3g}"
            f"{'' if lo <= true <= hi else ' (truth outside)'}")


def run_case(name: str, seed: int, n_exp: int, n_draws: int) -> dict:
    """One case: the design, the arms' experiments and fits, their widths."""
    case = CASES[name]
    target = case["parameter"]
    truth = draw_plausible(np.random.default_rng(seed))
    true_value = PAPER_AREA_M2 if target == "rig_area_m2" else truth[target]
    streams = np.random.default_rng(1000 + seed).spawn(4)
    first = _measure(case, truth, FIRST.pressure_pa(), FIRST.time_s, None, streams[0],
                     "first")
    res = design(first, [], [], goal="parameters", parameters=[target],
                 loads=case["loads"], input_range=RANGE_PA, n_experiments=n_exp,
                 n_draws=n_draws, seed=seed)
    before = _interval(next(iter(res.fits.values())), target)
    default = next(e for e in res.experiments if e.family == "default_chirp")
    arms = {"designed": res.experiment, "default chirp": default}
    if case["loads"] is not None and res.experiment.load_kg != default.load_kg:
        arms["default chirp on the designed load"] = dataclasses.replace(
            default, load_kg=res.experiment.load_kg)
    out = {"case": name, "seed": seed, "first": before, "truth": true_value,
           "expected": res.scores[res.chosen]["factor"]}
    print(f"{name} seed {seed}: true {target} {true_value:.4g}; first experiment alone "
          f"{_words(*before, true_value)}", flush=True)
    for (arm, exp), stream in zip(arms.items(), streams[1:], strict=False):
        second = _measure(case, truth, exp.input(), exp.time_s, exp.load_kg, stream,
                          arm.replace(" ", "_"))
        fit = fit_candidate([first, second], [], "base", rng=np.random.default_rng(seed))
        lo, hi = _interval(fit, target)
        out[arm] = (lo, hi)
        factor = (before[1] - before[0]) / (hi - lo)
        print(f"  {arm} ({exp.label()}): {_words(lo, hi, true_value)}, x{factor:.3g} "
              f"narrower than the first alone"
              + (f" (the design expected x{out['expected']:.3g})" if arm == "designed"
                 else ""), flush=True)
    width = {a: out[a][1] - out[a][0] for a in arms}
    out["ratio"] = width["default chirp"] / width["designed"]
    print(f"  width after the default chirp / after the designed experiment: "
          f"{out['ratio']:.3g}", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="one seed (unless --seeds), 10 candidate experiments, 16 draws")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per case (5; 1 with "
                        "--quick); the seed draws the muscle, the noise and the design")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated targets among {', '.join(CASES)} (all)")
    parser.add_argument("--experiments", type=int, default=None,
                        help="candidate experiments per design (50; 10 with --quick)")
    parser.add_argument("--draws", type=int, default=None,
                        help="posterior draws of the design (32; 16 with --quick)")
    args = parser.parse_args()
    seeds = args.seeds or (1 if args.quick else 5)
    n_exp = args.experiments or (10 if args.quick else 50)
    n_draws = args.draws or (16 if args.quick else 32)
    names = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in names if c not in CASES]
    if unknown:
        parser.error(f"unknown cases {', '.join(unknown)}; the cases are {', '.join(CASES)}")
    start = time.perf_counter()
    results = []
    for name in names:
        for seed in range(seeds):
            tic = time.perf_counter()
            results.append(run_case(name, seed, n_exp, n_draws))
            print(f"  ({time.perf_counter() - tic:.0f} s)", flush=True)
    print(f"total {time.perf_counter() - start:.0f} s")
    for name in names:
        mine = [r for r in results if r["case"] == name]
        ratios = [r["ratio"] for r in mine]
        print(f"{name}: designed narrower than the default chirp on "
              f"{sum(x > 1 for x in ratios)}/{len(ratios)} seeds, median factor "
              f"x{statistics.median(ratios):.3g} (each: "
              + ", ".join(f"{x:.3g}" for x in ratios) + ")")
        arm = "default chirp on the designed load"
        on_load = [(r[arm][1] - r[arm][0]) / (r["designed"][1] - r["designed"][0])
                   for r in mine if arm in r]
        if on_load:
            print(f"  the {arm} against the designed experiment ({len(on_load)} seeds where "
                  f"the design chose another load): median x{statistics.median(on_load):.3g}")
        arms = ["first", "designed", "default chirp"]
        print("  truth inside the 90% interval: " + ", ".join(
            f"{a} {sum(r[a][0] <= r['truth'] <= r[a][1] for r in mine)}/{len(mine)}"
            for a in arms))
    ratios = [r["ratio"] for r in results]
    wins = sum(x > 1 for x in ratios)
    print(f"target's 90% interval narrower after the designed experiment than after a "
          f"default chirp of the same length: {wins}/{len(ratios)} cases "
          f"({100 * wins / len(ratios):.0f}%; {len(names)} targets x {seeds} seeds, "
          f"{n_exp} candidate experiments, {n_draws} draws); median width_default / "
          f"width_designed x{statistics.median(ratios):.3g}")


if __name__ == "__main__":
    main()
