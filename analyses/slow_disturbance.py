"""Two single records with a slow disturbance, fitted as a user would.

One record without repeats whose disturbance is slow once pinned the noise at its
bound, the correct model was called inadequate and no interval covered
the truth: an 8 s chirp with the package's default disturbance (60 um, 0.1 s;
``pmabayes simulate single.csv --duration 8 --trials 1 --seed 23``) and a 60 s chirp
with a 0.3 s one (max |z| 12). This script fits both with the defaults of
:func:`pmabayes.inference.sampler.fit` and prints, per record, the record's
disturbance check (:func:`pmabayes.inference.disturbance.settle_disturbance`), the
fit's verdict, and each parameter's 90% HDI and z against the truth (the paper's
values, which the records were simulated with; synthetic data).

Usage::

    python analyses/slow_disturbance.py [--records 8s 60s] [--seed 0]

Prints a table per record, then ``covered: K of N`` last.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import arviz as az

import pmabayes as pb
from pmabayes.inference.errors import ConvergenceWarning
from pmabayes.inference.fitfile import fit_info
from pmabayes.inference.sampler import fit
from pmabayes.model.model import PAPER_VALUES
from pmabayes.report.verdicts import fit_adequacy
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

#: the two records: chirp length (s) and the disturbance's correlation time (s)
RECORDS = {"8s": (8.0, 0.1), "60s": (60.0, 0.3)}


def run(name: str, seed: int) -> int:
    """Fit one record; print what a user reads of it; return how many intervals cover."""
    duration, corr = RECORDS[name]
    ds = generate_chirp_dataset(n_trials=1, seed=23, chirp=Chirp(duration_s=duration),
                                noise=MeasurementNoise(disturbance_corr_time_s=corr))
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        tree = fit(ds, pb.Model(), seed=seed)
    check = fit_info(tree)["experiments"][0]["metadata"].get("disturbance_check")
    adequacy = fit_adequacy(tree, dataset=ds)
    print(f"\n{name}: {duration:g} s chirp, disturbance 60 um of {corr * 1e3:g} ms "
          f"(synthetic), fitted in {time.perf_counter() - start:.0f} s")
    print(f"  disturbance check: {check}")
    print(f"  {adequacy.headline}: {adequacy.evidence()}")
    print(f"  {adequacy.noise_note}")
    hdi = az.hdi(tree, prob=0.9)
    covered = 0
    print(f"  {'parameter':<10} {'truth':>10} {'90% HDI':>25} {'z':>6}")
    for n, v in PAPER_VALUES.items():
        lo, hi = (float(x) for x in hdi[n].values)
        draws = tree["posterior"][n].values
        covered += lo <= v <= hi
        print(f"  {n:<10} {v:>10.5g} {lo:>12.5g} {hi:>12.5g} "
              f"{(v - draws.mean()) / draws.std():>6.2f}")
    return covered


def main(argv: list[str] | None = None) -> int:
    """Fit the records asked for and print the intervals covering the truth last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", nargs="+", choices=tuple(RECORDS), default=list(RECORDS))
    parser.add_argument("--seed", type=int, default=0, help="the fits' seed (0)")
    args = parser.parse_args(argv)
    covered = sum(run(name, args.seed) for name in args.records)
    print(f"covered: {covered} of {len(PAPER_VALUES) * len(args.records)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
