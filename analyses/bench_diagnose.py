"""Wall time of ``diagnose`` with its discrepancy step: 10 trials of the 15 s chirp, or one
11 s record without repeats.

The data (synthetic) hide a quadratic drag that no library holds, so the diagnosis
goes through every step: the MAP, the score tests, the refits of the significant
candidates, and the discrepancy (the missing force estimated, its states ranked, a
closed form proposed, written and refitted). The simulator kernels are compiled or
loaded from the cache by a warm-up diagnosis on short data before the clock starts;
the proposal's own kernel (a new effect) is compiled inside the timed run the first
time, as it would be for a user.

``--single-record`` times what a user with one measured file meets (a user reported "a
fit of one 11,000-sample file took 12 minutes and diagnose 14"): one 11 s record at 1 kHz
(``generate_chirp_dataset(n_trials=1, chirp=Chirp(duration_s=11))``) with the hidden
drag, diagnosed with every registered candidate (``--hidden lag`` hides a 45 ms
regulator lag instead). Its noise is identified with the model, and the discrepancy
step cross-validates over stretches of the record.

Usage::

    python analyses/bench_diagnose.py [--trials 10] [--seed 0] [--no-discrepancy]
    python analyses/bench_diagnose.py --single-record [--hidden drag|lag]

Prints where the time goes (the wall time of each step of ``diagnose``, from the
profiler, and the process's CPU time) and ``diagnose_seconds: <number>`` last. A
benchmark, not a test.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
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

#: the steps of ``diagnose`` whose time is reported: (module file, function, label)
STEPS = (("refits.py", "fit_base", "MAP of the diagnosed model, signature, ELPD"),
         ("scores.py", "rank_effects", "score tests (all calls, the refits' look-ahead too)"),
         ("refits.py", "refit_significant", "refits of the significant candidates"),
         ("search.py", "find_map", "  of which MAP searches (all calls)"),
         ("diagnosis.py", "_yardsticks", "yardsticks (linear, play)"),
         ("diagnosis.py", "_discrepancy_step", "discrepancy step"))


def data(n_trials: int, seed: int, chirp: Chirp | None = None, hidden: str = "drag") -> Dataset:
    """Trials of the base model plus a 300 N s^2/m^2 quadratic drag, or a 45 ms regulator
    lag (synthetic)."""
    effects = ({HiddenDrag: {"c_hidden": 300.0}} if hidden == "drag"
               else {"regulator_lag": 0.045})
    return generate_chirp_dataset(n_trials=n_trials, seed=seed, chirp=chirp, effects=effects,
                                  description=f"base + hidden {hidden} (synthetic)")


def breakdown(profile: cProfile.Profile) -> list[str]:
    """Cumulative wall time of each of :data:`STEPS` in a profile of ``diagnose``."""
    stats = pstats.Stats(profile).stats
    out = []
    for file, func, label in STEPS:
        total = sum(v[3] for (f, _, name), v in stats.items()
                    if f.endswith(file) and name == func)
        out.append(f"  {label:<52s} {total:7.1f} s")
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print ``diagnose_seconds`` last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-discrepancy", action="store_true",
                        help="time diagnose without the discrepancy step")
    parser.add_argument("--single-record", action="store_true",
                        help="one 11 s record without repeats, every registered candidate")
    parser.add_argument("--hidden", choices=("drag", "lag"), default="drag")
    args = parser.parse_args(argv)
    single = args.single_record
    with tempfile.TemporaryDirectory() as folder:
        warm = data(1 if single else 3, args.seed + 1,
                    Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=2.0), args.hidden)
        settings = DiagnoseSettings(candidates=None if single else CANDIDATES,
                                    discrepancy=not args.no_discrepancy)
        diagnose(warm, settings=replace(settings, max_refits=1), plugin_dir=folder, seed=0)
        ds = (data(1, args.seed, Chirp(duration_s=11.0), args.hidden) if single
              else data(args.trials, args.seed, hidden=args.hidden))  # the paper's 15 s chirp
        profile = cProfile.Profile()
        start, cpu = time.perf_counter(), time.process_time()
        profile.enable()
        d = diagnose(ds, settings=settings, plugin_dir=folder, seed=args.seed)
        profile.disable()
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        print(d.verdict)
        print("where the time goes (wall, under the profiler):")
        print("\n".join(breakdown(profile)))
        if d.discrepancy is not None and not single:
            from pmabayes.criticism.discrepancy import estimate_discrepancy

            t0 = time.perf_counter()
            e = d.experiments[0]
            estimate_discrepancy(_likelihood(d), e.noise, d.values, e.simulation,
                                 plugin_dir=folder)
            print(f"discrepancy step alone (kernels compiled): "
                  f"{time.perf_counter() - t0:.1f} s")
    print(f"{ds.n_trials} trial(s) x {ds.n_samples} samples; CPU time of this process "
          f"{cpu:.1f} s")
    print(f"diagnose_seconds: {seconds:.1f}")
    return 0


def _likelihood(d):
    from pmabayes.inference.likelihood import Likelihood

    e = d.experiments[0]
    return Likelihood(e.model, e.dataset, substeps=d.settings["substeps"])


if __name__ == "__main__":
    raise SystemExit(main())
