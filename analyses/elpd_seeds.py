"""Does the leave-one-trial-out ELPD from Laplace draws move with the seed of its draws?

The case of ``design_study.py``'s first pair (a regulator's lag against a transport
delay), the truth the lag: its small, slow first experiment (a 0.1-0.5 Hz chirp over
100-160 kPa, 6 s at 200 Hz, 4 trials) and a repeat of it (the same input, other noise),
on which the two candidates fit alike. Both are fitted on the two experiments together
(the MAP and Laplace covariance of ``pmabayes design`` and ``diagnose``), then their ELPD
(:func:`pmabayes.criticism.elpd.laplace_loo`) is estimated with each of ``--seeds`` seeds
of the draws. Printed: per seed, each candidate's ELPD with the standard error of its
per-trial terms, the Pareto k-hats and whether the estimate is reliable, and the paired
ΔELPD (lag minus delay); last, the spread of each over the seeds.

Usage: ``python analyses/elpd_seeds.py [--seeds 5] [--draws 400] [--pair 0]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from design_study import PAIRS  # noqa: E402  (the study's pairs, from its own file)

from pmabayes.criticism.elpd import laplace_loo, paired_difference  # noqa: E402
from pmabayes.design import fit_candidate  # noqa: E402
from pmabayes.synthetic import Chirp, generate_chirp_dataset  # noqa: E402

#: design_study.py's first experiment
CHIRP = Chirp(f0_hz=0.1, f1_hz=0.5, duration_s=6.0, p_min_pa=1.0e5, p_max_pa=1.6e5,
              sample_rate_hz=200.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds of the draws (5)")
    parser.add_argument("--draws", type=int, default=400,
                        help="Laplace draws per estimate (400, diagnose's default)")
    parser.add_argument("--pair", type=int, default=0,
                        help=f"index into design_study.py's {len(PAIRS)} pairs (0)")
    args = parser.parse_args()
    pair = PAIRS[args.pair]
    names = [p[0] for p in pair]
    truth = {pair[0][0]: pair[0][1]}
    data = [generate_chirp_dataset(n_trials=4, seed=s, chirp=CHIRP, effects=truth)
            for s in (100, 200)]
    fits = {}
    for n in names:
        tic = time.perf_counter()
        fits[n] = fit_candidate(data, [n], n, rng=np.random.default_rng(0))
        note = fits[n].map.laplace_note
        print(f"fitted {n} ({time.perf_counter() - tic:.0f} s); its Laplace covariance "
              + (f"is a stand-in: {note}" if note else "is the inverse Hessian"), flush=True)
    elpd: dict[str, list[float]] = {n: [] for n in names}
    diffs = []
    for seed in range(args.seeds):
        got = {n: laplace_loo(f.posterior, f.map, np.random.default_rng(seed), args.draws, 0.9)
               for n, f in fits.items()}
        for n in names:
            elpd[n].append(got[n].elpd)
        d, se = paired_difference(got[names[0]].elpd_i, got[names[1]].elpd_i)
        diffs.append(d)
        print(f"seed {seed}: " + "; ".join(
            f"{n} ELPD {g.elpd:.1f} ± {math.sqrt(g.elpd_i.size * np.var(g.elpd_i)):.1f} "
            f"(k-hat {g.pareto_k:.2f}, of the correction {g.correction_k:.2f}, "
            f"{g.ess:.0f} effective draws, {'reliable' if g.reliable else 'not reliable'})"
            for n, g in got.items())
            + f"; ΔELPD {names[0]} - {names[1]} {d:+.1f} ± {se:.1f}", flush=True)
    for n in names:
        print(f"{n}: ELPD from {min(elpd[n]):.1f} to {max(elpd[n]):.1f} over {args.seeds} "
              f"seeds (spread {np.ptp(elpd[n]):.1f})")
    print(f"ΔELPD from {min(diffs):+.1f} to {max(diffs):+.1f} (spread {np.ptp(diffs):.1f})")


if __name__ == "__main__":
    main()
