"""Wall time of ``diagnose`` with its discrepancy step: 10 trials of the 15 s chirp.

The data (synthetic) hide a quadratic drag that no library holds, so the diagnosis
goes through every step: the MAP, the score tests, the refits of the significant
candidates, and the discrepancy (the missing force estimated, its states ranked, a
closed form proposed, written and refitted). The simulator kernels are compiled or
loaded from the cache by a warm-up diagnosis on short data before the clock starts;
the proposal's own kernel (a new effect) is compiled inside the timed run the first
time, as it would be for a user.

Usage::

    python analyses/bench_diagnose.py [--trials 10] [--seed 0] [--no-discrepancy]

Prints the time of each step's share (the discrepancy's own time is measured apart)
and ``diagnose_seconds: <number>`` last. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace

from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.data import Dataset
from pmabayes.synthetic import Chirp, HiddenDrag, generate_chirp_dataset

#: the built-in library
CANDIDATES = ("regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
              "pressure_stiffness", "position_offset")


def data(n_trials: int, seed: int, chirp: Chirp | None = None) -> Dataset:
    """Trials of the base model plus a 300 N s^2/m^2 quadratic drag (synthetic)."""
    return generate_chirp_dataset(n_trials=n_trials, seed=seed, chirp=chirp,
                                  effects={HiddenDrag: {"c_hidden": 300.0}},
                                  description="base + quadratic drag (synthetic)")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print ``diagnose_seconds`` last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-discrepancy", action="store_true",
                        help="time diagnose without the discrepancy step")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        warm = data(3, args.seed + 1, Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=2.0))
        settings = DiagnoseSettings(candidates=CANDIDATES, discrepancy=not args.no_discrepancy)
        diagnose(warm, settings=replace(settings, max_refits=1), plugin_dir=folder, seed=0)
        ds = data(args.trials, args.seed)  # the paper's 15 s chirp
        start = time.perf_counter()
        d = diagnose(ds, settings=settings, plugin_dir=folder, seed=args.seed)
        seconds = time.perf_counter() - start
        print(d.verdict)
        if d.discrepancy is not None:
            from pmabayes.criticism.discrepancy import estimate_discrepancy

            t0 = time.perf_counter()
            e = d.experiments[0]
            estimate_discrepancy(_likelihood(d), e.noise, d.values, e.simulation,
                                 plugin_dir=folder)
            print(f"discrepancy step alone (kernels compiled): "
                  f"{time.perf_counter() - t0:.1f} s")
    print(f"{args.trials} trials x {ds.n_samples} samples")
    print(f"diagnose_seconds: {seconds:.1f}")
    return 0


def _likelihood(d):
    from pmabayes.inference.likelihood import Likelihood

    e = d.experiments[0]
    return Likelihood(e.model, e.dataset, substeps=d.settings["substeps"])


if __name__ == "__main__":
    raise SystemExit(main())
