"""Simulator throughput against the C reference, measured in one run.

Times a batch of 64 parameter sets over the paper's 15 s chirp at 1 kHz, for the
base model and with each built-in effect switched on (every registered one, the PMA's
``stribeck_friction``, ``mckibben_force`` and ``regulator_second_order`` included), as
microseconds per trial (best of 7 repetitions, after compilation), and divides by the
figure that
``../shared/bench/c_reference`` prints in the same run. Two more lines time the base
model with a band-limited input (``between_samples="bandlimited"``, the chirp not
declared periodic, so its degree-9 spline) at 1 and 4 substeps; the reconstruction is
memoised by content, as in a likelihood, so after the first call they time the
integration of the finer substeps.

Usage::

    python analyses/bench_simulator.py [--reference PATH] [--json OUT.json]

The last line printed is ``ratio_vs_c: <number>`` for the base model. A benchmark,
not a test: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pmabayes import Model, registered_effects, simulate
from pmabayes.synthetic import Chirp

BATCH = 64
REPEATS = 7
#: ``../shared`` beside the checkout (the main checkout, or a worktree one level deeper)
DEFAULT_REFERENCE = next(
    (p for p in (Path(__file__).resolve().parents[k] / "shared" / "bench" / "c_reference"
                 for k in (2, 3)) if p.exists()),
    Path(__file__).resolve().parents[2] / "shared" / "bench" / "c_reference")


def vector_extensions() -> str:
    """The CPU's widest vector extension, from ``/proc/cpuinfo`` (Linux), for the record.

    The batch loop's speed depends on it (AVX-512 vectors hold 8 doubles, AVX2 4);
    the scalar C reference's much less.
    """
    try:
        flags = next((line.split(":", 1)[1].split() for line in
                      Path("/proc/cpuinfo").read_text().splitlines()
                      if line.startswith("flags")), [])
    except OSError:
        return "unknown"
    for flag, label in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("sse2", "SSE2")):
        if flag in flags:
            return label
    return "unknown"


def c_reference_us(path: Path) -> float:
    """Run the C reference and parse its ``c_reference_us_per_trial`` figure."""
    out = subprocess.run([str(path)], check=True, capture_output=True, text=True).stdout
    for line in out.splitlines():
        if line.startswith("c_reference_us_per_trial:"):
            return float(line.split(":")[1])
    raise RuntimeError(f"{path} printed no c_reference_us_per_trial line:\n{out}")


def pmabayes_us(model: Model, pressure: np.ndarray, dt_s: float, **options) -> float:
    """Best-of-REPEATS microseconds per trial for a batch of BATCH parameter sets
    (``options`` go to :func:`simulate`)."""
    # like the C reference: 64 distinct stiffnesses so nothing is shared by accident
    params = {"K_e": 624.78 * (1 + 1e-4 * np.arange(BATCH))}
    simulate(model, params, pressure, dt_s=dt_s, **options)  # compile (or load the kernel)
    best = np.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        simulate(model, params, pressure, dt_s=dt_s, **options)
        best = min(best, time.perf_counter() - start)
    return best / BATCH * 1e6


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the table, then ``ratio_vs_c``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", type=Path, default=DEFAULT_REFERENCE,
                        help="path of the c_reference script")
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    args = parser.parse_args(argv)

    chirp = Chirp()
    pressure = chirp.pressure_pa()
    dt_s = 1.0 / chirp.sample_rate_hz
    rows = {"base": pmabayes_us(Model(), pressure, dt_s)}
    for name in sorted(registered_effects()):
        rows[name] = pmabayes_us(Model([name]), pressure, dt_s)
    # the effects that read z, carry a state or change the
    # hysteresis law are timed one by one above; here all three in one kernel
    rows["z, state and law"] = pmabayes_us(
        Model(["pressure_hysteresis", "maxwell_creep", "bouc_wen_exponent"]), pressure, dt_s)
    for substeps in (1, 4):
        rows[f"bandlimited x{substeps}"] = pmabayes_us(
            Model(), pressure, dt_s, between_samples="bandlimited", substeps=substeps)
    c_us = c_reference_us(args.reference)  # measured after ours, in the same run

    print(f"CPU vector extension: {vector_extensions()}")
    print(f"batch {BATCH} x 15 s chirp at 1 kHz, best of {REPEATS}; C reference "
          f"{c_us:.1f} us/trial")
    print(f"{'model':<22}{'us/trial':>10}{'ratio vs C':>12}")
    for name, us in rows.items():
        print(f"{name:<22}{us:>10.1f}{us / c_us:>12.2f}")
    worst = max((k for k in rows if k in registered_effects()), key=rows.get)
    result = {
        "c_reference_us_per_trial": c_us,
        "us_per_trial": rows,
        "ratio_vs_c": rows["base"] / c_us,
        "worst_effect": worst,
        "ratio_vs_c_worst_effect": rows[worst] / c_us,
        "ratio_vs_c_bandlimited": rows["bandlimited x1"] / c_us,
    }
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(f"ratio_vs_c_worst_effect: {result['ratio_vs_c_worst_effect']:.2f} ({worst})")
    print(f"ratio_vs_c_bandlimited: {result['ratio_vs_c_bandlimited']:.2f}")
    print(f"ratio_vs_c: {result['ratio_vs_c']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
