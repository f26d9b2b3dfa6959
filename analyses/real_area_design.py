"""Which dead load and pressure profile would identify the real muscle's area best?

On the cavatappi muscle of Higueras-Ruiz, Shafer and Feigenbaum (Science Robotics 2021;
real measurements, read from ``../shared/external/real/cavatappi`` and never copied into
the repository) the area on which the pressure acts is unpublished: the sidecars of
``analyses/real_cavatappi.py`` (:func:`real_cavatappi.declare`, written into ``--out``
beside links to the files) give it as a prior shared by the loads,
``"area_m2": "LogNormal(1e-5, 1.5)"``. This asks ``pmabayes design --goal parameters
--parameters rig_area_m2`` for the next experiment that would shrink the area's 90%
interval most, given the data so far:

1. the 100 g training file alone;
2. the three training loads together (100, 300 and 500 g), the area one parameter;
3. the 100 g file again, from the MCMC draws of its ``pmabayes fit`` (``--steps 1000
   --walkers 48``, as ``analyses/real_cavatappi.py`` fits one load) instead of the MAP
   and its Laplace covariance (``pmabayes design --fit FIT.nc``).

The design may use any of the five dead loads the lab has (0.1 to 0.5 kg; ``--loads``
hangs each in place of the first file's, which its sidecar declares) and any pressure
between 0 and 255 psi (just above the highest the records reach, 253.3 psi), for a
record as long as the first file (13.4 s at 1 kHz). The
first two fit the base model as ``pmabayes design`` does (the MAP and its Laplace
covariance); each design scores 50 candidate experiments (chirps, steps and holds,
band-limited noise, sines, each on a dead load, the default chirp over the range and
the first record repeated among them) and writes its files and page into
``--out/design_<loads>``.

Printed per design: the area's 90% interval on the data so far, the chosen experiment
with its expected shrinkage and Monte Carlo error, the default chirp's and the repeat's,
the best score on each dead load and of each family, and the design's notes on the fit
it started from; the designs' choices last.

Usage::

    python analyses/real_area_design.py [--out DIR] [--seed 0] [--experiments 50]
        [--draws 32] [--mcmc-steps 1000]

``--quick`` scores 10 candidate experiments with 8 draws, after 60 MCMC steps.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import numpy as np
from _real import pmabayes
from real_cavatappi import AREA_PRIOR, declare

from pmabayes.data import load
from pmabayes.data.units import to_si
from pmabayes.design import design
from pmabayes.design.api import given_fits
from pmabayes.design.fits import fit_from_file
from pmabayes.model.parameters import parse_prior
from pmabayes.report.design_page import write_design

#: the dead loads the lab has, g
LAB_LOADS_G = (100, 200, 300, 400, 500)
#: the data so far of each design, by the loads of its files (g); the first is the rig
DATA_SO_FAR = ((100,), (100, 300, 500))
#: the pressures the design may use, in the files' unit (psi)
RANGE_PSI = (0.0, 255.0)
TARGET = "rig_area_m2"


def _interval(fit, level: float = 0.9) -> tuple[float, float]:
    """The area's equal-tailed interval: of a fit file's draws, or under the fit's
    Laplace approximation."""
    post = fit.posterior
    k = list(post.names).index(TARGET)
    if fit.samples_z is not None:
        area = post.to_natural(fit.samples_z)[:, k]
        lo, hi = np.quantile(area, [0.5 - level / 2, 0.5 + level / 2])
        return float(lo), float(hi)
    sd = math.sqrt(float(np.asarray(fit.map.covariance_z)[k, k]))
    q = statistics.NormalDist().inv_cdf(0.5 + level / 2)
    z = np.repeat(np.asarray(fit.map.z, dtype=float)[None], 2, axis=0)
    z[:, k] += np.array([-q, q]) * sd
    lo, hi = post.to_natural(z)[:, k]
    return float(lo), float(hi)


def _score(s: dict) -> str:
    return f"x{s['factor']:.3f} (log {s['score']:.4f} +- {s['mc_se']:.4f} MC se)"


def run(paths: dict[int, Path], loads_g: tuple[int, ...], out: Path, seed: int,
        n_exp: int, n_draws: int, fit_file: Path | None = None) -> dict:
    """One design on the files of ``loads_g`` (from the MCMC draws of ``fit_file``, a
    ``pmabayes fit`` of them, where given); its files and page into ``out``."""
    datasets = [load(paths[g]) for g in loads_g]
    fits = (None if fit_file is None else
            given_fits([fit_from_file(fit_file, datasets)], [], [], "parameters"))
    first_g = loads_g[0]
    lab = [g / 1000.0 for g in LAB_LOADS_G if g >= first_g]
    low, high = (float(v) for v in to_si(np.array(RANGE_PSI), "pressure_psi"))
    tic = time.perf_counter()
    res = design(datasets, [], [], goal="parameters", parameters=[TARGET], loads=lab,
                 input_range=(low, high), n_experiments=n_exp, n_draws=n_draws, seed=seed,
                 fits=fits)
    write_design(res, out)
    fit = next(iter(res.fits.values()))
    lo, hi = _interval(fit)
    tag = " + ".join(f"{g} g" for g in loads_g) + ("" if fit_file is None else
                                                    f" (MCMC draws of {fit_file.name})")
    print(f"data so far: {tag} ({time.perf_counter() - tic:.0f} s; files and page in "
          f"{out})")
    prior = parse_prior(AREA_PRIOR)
    prior = prior.quantile(0.95) / prior.quantile(0.05)
    where = "median of the draws" if fit.samples_z is not None else "MAP"
    print(f"  area at the {where} {fit.map.values[TARGET]:.4g} m^2, 90% interval [{lo:.4g}, "
          f"{hi:.4g}] (x{hi / lo:.4g} from end to end; the prior's x{prior:.0f})")
    chosen = res.scores[res.chosen]
    total = {i: first_g if e.load_kg is None else round(1000 * e.load_kg)
             for i, e in enumerate(res.experiments)}
    print(f"  chosen: {res.experiment.label()} -> on the {total[res.chosen]} g load; "
          f"expected shrinkage {_score(chosen)}")
    for family, what in (("default_chirp", "default chirp"), ("repeat", "first record again")):
        s = res.score_of(family)
        if s is not None:
            print(f"  {what}: {_score(s)}")
    finite = [i for i, s in enumerate(res.scores) if math.isfinite(s["score"])]
    by_load = {g: max((res.scores[i]["factor"] for i in finite if total[i] == g),
                      default=math.nan) for g in LAB_LOADS_G if g >= first_g}
    print("  best expected shrinkage on each dead load: "
          + ", ".join(f"{g} g x{f:.3f}" for g, f in by_load.items()))
    families = dict.fromkeys(e.family for e in res.experiments)
    by_family = {f: max((res.scores[i]["factor"] for i in finite
                         if res.experiments[i].family == f), default=math.nan)
                 for f in families}
    print("  best expected shrinkage of each family: "
          + ", ".join(f"{f} x{v:.3f}" for f, v in by_family.items()))
    for note in res.notes:
        print(f"  note: {note}")
    return {"data": tag, "chosen": res.experiment.label(), "load_g": total[res.chosen],
            "factor": chosen["factor"], "interval": (lo, hi)}


def main(argv: list[str] | None = None) -> int:
    """Run the designs and print their choices."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("real_area_design"),
                    help="folder for the sidecars, links and the designs (real_area_design)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--experiments", type=int, default=None,
                    help="candidate experiments per design (50; 10 with --quick)")
    ap.add_argument("--draws", type=int, default=None,
                    help="posterior draws per design (32; 8 with --quick)")
    ap.add_argument("--mcmc-steps", type=int, default=None,
                    help="steps of the `pmabayes fit` of the first file whose draws a third "
                    "design starts from (1000, as real_cavatappi.py; 60 with --quick; 0: "
                    "none)")
    ap.add_argument("--quick", action="store_true",
                    help="10 experiments, 8 draws, 60 MCMC steps")
    args = ap.parse_args(argv)
    n_exp = args.experiments or (10 if args.quick else 50)
    n_draws = args.draws or (8 if args.quick else 32)
    steps = args.mcmc_steps if args.mcmc_steps is not None else (60 if args.quick else 1000)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    paths = declare(out)
    results = [run(paths, loads, out / ("design_" + "_".join(map(str, loads))), args.seed,
                   n_exp, n_draws) for loads in DATA_SO_FAR]
    if steps:
        first = DATA_SO_FAR[0]
        fit_path = out / f"fit_{'_'.join(map(str, first))}.nc"
        pmabayes("fit", *(str(paths[g]) for g in first), "--out", str(fit_path), "--restart",
                 "--steps", str(steps), "--walkers", "48", "--seed", str(args.seed),
                 "--quiet")
        results.append(run(paths, first, out / f"design_{'_'.join(map(str, first))}_mcmc",
                           args.seed, n_exp, n_draws, fit_file=fit_path))
    print(f"\nthe next experiment for the area ({n_exp} candidate experiments, {n_draws} "
          f"draws, seed {args.seed}):")
    for r in results:
        print(f"  after {r['data']}: {r['chosen']} (the {r['load_g']} g load), expected "
              f"to shrink the area's 90% interval x{r['factor']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
