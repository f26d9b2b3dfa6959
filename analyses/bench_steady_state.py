"""Benchmark: the periodic steady state of a 10,000-sample period, found by Newton's
method on the period map (:func:`pmabayes.model.simulator.simulate` with
``steady_state=True``) against simulating period after period from rest until the
position over a period stops changing (what the simulator did before).

The batch is what one generation of the MAP's global search simulates: 96 muscles
drawn from the plausible region (:data:`pmabayes.synthetic.PLAUSIBLE_REGION`) on a
periodic pressure of 10 s at 1 kHz (a slow swing with small fast loops on it, whose
hysteresis shakes down over many periods). Prints the seconds of each and, last,
the ratio.

Usage: ``python analyses/bench_steady_state.py [--batch 96] [--seed 0]``
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from pmabayes.model import Model, SteadyStateWarning, simulate
from pmabayes.synthetic import draw_plausible

PERIOD = 10_000
RATE_HZ = 1000.0
TOL_M = 1e-9
MAX_PERIODS = 256


def _input() -> np.ndarray:
    t = np.arange(PERIOD) / RATE_HZ
    return (2.2e5 + 1.2e5 * np.sin(2 * np.pi * t / 10.0)
            + 2e4 * np.sin(2 * np.pi * 7 * t / 10.0) + 1e4 * np.sin(2 * np.pi * 31 * t / 10.0))


def period_by_period(model: Model, theta: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, int]:
    """Simulate from rest one more period at a time until every member's position over
    the last period differs from the one before by at most ``TOL_M`` (or ``MAX_PERIODS``);
    the periods simulated (each try from rest, as the old warm-up did, doubling)."""
    k, total = 3, 0
    while True:
        x = simulate(model, theta, np.tile(u, k), dt_s=1 / RATE_HZ)
        total += k
        change = np.max(np.abs(x[:, -PERIOD:] - x[:, -2 * PERIOD:-PERIOD]))
        if change <= TOL_M or k >= MAX_PERIODS:
            return x[:, -PERIOD:], total
        k = min(2 * k, MAX_PERIODS)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=96)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    model = Model()
    draws = [draw_plausible(rng) for _ in range(args.batch)]
    theta = model.theta({k: np.array([d[k] for d in draws]) for k in draws[0]})
    u = _input()
    simulate(model, theta[:2], np.tile(u[:200], 2), dt_s=1 / RATE_HZ, period_samples=200,
             steady_state=True)  # compile both kernels first
    simulate(model, theta[:2], u[:600], dt_s=1 / RATE_HZ)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SteadyStateWarning)
        x_new = simulate(model, theta, u, dt_s=1 / RATE_HZ, period_samples=PERIOD,
                         steady_state=True, steady_state_tol_m=TOL_M,
                         max_warmup_periods=MAX_PERIODS)
    t_new = time.perf_counter() - t0
    t0 = time.perf_counter()
    x_old, periods = period_by_period(model, theta, u)
    t_old = time.perf_counter() - t0
    gap = float(np.max(np.abs(x_new - x_old)))
    print(f"{args.batch} muscles, period {PERIOD} samples: Newton on the period map "
          f"{t_new:.2f} s ({len(caught)} warnings); period after period {t_old:.2f} s "
          f"({periods} periods simulated from rest in all); largest difference of the "
          f"steady periods {gap:.2g} m")
    print(f"speed-up (period after period / Newton): {t_old / t_new:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
