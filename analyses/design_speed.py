"""How long ``pmabayes design`` takes to score candidate experiments (the target:
about 50 in under 5 minutes on two cores).

A synthetic first experiment (a 0.1-3 Hz chirp over 100-400 kPa, ``--duration`` s at
``--rate`` Hz, ``--trials`` trials, made with the first candidate at its defaults) is
fitted once with each candidate of a pair (``--candidates``, a regulator's lag and a
transport delay by default): that is the fits' time. Then the design
is made again from those fits, scoring ``--experiments`` candidate experiments of the
same length with ``--draws`` posterior draws per model: that is the scoring time (every
model's draws simulated on every experiment, 2 x draws x models simulations each).

Usage: ``python analyses/design_speed.py [--candidates A,B] [--experiments 50]
[--draws 32] [--duration 15] [--rate 1000] [--trials 10] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import os
import time

from pmabayes.design import design
from pmabayes.synthetic import Chirp, generate_chirp_dataset

RANGE_PA = (0.0, 5e5)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--candidates", default="regulator_lag,transport_delay")
    parser.add_argument("--experiments", type=int, default=50)
    parser.add_argument("--draws", type=int, default=32)
    parser.add_argument("--duration", type=float, default=15.0, help="s")
    parser.add_argument("--rate", type=float, default=1000.0, help="Hz")
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    pair = [c.strip() for c in args.candidates.split(",")]
    chirp = Chirp(f0_hz=0.1, f1_hz=3.0, duration_s=args.duration, p_min_pa=1.0e5,
                  p_max_pa=4.0e5, sample_rate_hz=args.rate)
    first = generate_chirp_dataset(n_trials=args.trials, seed=args.seed, chirp=chirp,
                                   effects={pair[0]: {}})
    tic = time.perf_counter()
    fitted = design(first, [], pair, input_range=RANGE_PA, n_experiments=2, n_draws=args.draws,
                    seed=args.seed)
    fit_s = time.perf_counter() - tic
    tic = time.perf_counter()
    res = design(first, [], pair, input_range=RANGE_PA, n_experiments=args.experiments,
                 n_draws=args.draws, seed=args.seed, fits=fitted.fits)
    score_s = time.perf_counter() - tic
    n_sim = 2 * args.draws * len(pair) * len(res.experiments)
    print(f"machine: {os.cpu_count()} cores, load average "
          f"{', '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print(f"first experiment: {args.duration:g} s at {args.rate:g} Hz, {args.trials} trials")
    print(f"fits of {len(pair)} candidates (MAP + Laplace, with 2 experiments scored): "
          f"{fit_s:.1f} s")
    print(f"scoring {len(res.experiments)} candidate experiments of {args.duration:g} s with "
          f"{args.draws} draws per model ({n_sim} simulations): {score_s:.1f} s "
          f"({score_s / len(res.experiments):.2f} s each)")
    print(f"chosen: {res.experiment.label()}")


if __name__ == "__main__":
    main()
