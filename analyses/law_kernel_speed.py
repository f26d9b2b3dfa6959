"""How fast the compiled simulator runs a batch with a hysteresis law that carries a state
(``bouc_wen_baber_noori``), against the same model without it, and what LLVM's
vectoriser has to do with it.

The model is sample 2's third round (``maxwell_creep``, ``force_length_map``) with and
without the degrading, pinching law, on the muscle's default rig, driven by a 1.3 Hz
pressure sine at 1 kHz (``--duration`` seconds). Each case runs in a fresh process
with its own kernel cache, one simulation thread, and the best of ``--repeats`` batches
of ``--members`` members near the defaults (seed 0) is timed; the first call compiles.
Each case also checks the simulator's promise that a member simulated alone gives, to
the bit, what it gives inside the batch.

The cases:

- ``LLVM's defaults``: LLVM's own limits on the run-time overlap checks its loop
  vectoriser may add (``--runtime-memory-check-threshold=8``,
  ``--vectorize-memory-check-threshold=128``), as pmabayes compiled its kernels before
  it raised them: the law's batch loop stays scalar ("too many memory checks needed");
- ``as compiled``: the limits pmabayes sets
  (:data:`pmabayes.model.codegen.LLVM_OPTIONS`), which let LLVM vectorise that loop;
- ``as compiled, no arcp``: the same without the reciprocal approximation the kernels
  allow (the fast-math flag ``arcp``), the flag that makes the vectorised loop round a
  member differently from the scalar one.

A benchmark, not a test: synthetic input, nothing read or written outside the
temporary caches. The figure, the law's slowdown in each case, is printed last.

Usage::

    python analyses/law_kernel_speed.py [--members 300] [--duration 13] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

CASES = {"LLVM's defaults": (False, False), "as compiled": (True, False),
         "as compiled, no arcp": (True, True)}
LAW = "bouc_wen_baber_noori"
BASE = ["maxwell_creep", "force_length_map"]


def _child(wide: bool, no_arcp: bool, effects: list[str], members: int, duration_s: float,
           repeats: int) -> dict:
    """One case, in this (fresh) process: the batch's best time and the bit check."""
    import time

    import llvmlite.binding as llvm
    import numpy as np

    import pmabayes.model.codegen as codegen
    import pmabayes.model.kernels  # noqa: F401  (sets pmabayes's limits)

    if not wide:  # read when a kernel compiles: back to LLVM's own
        llvm.set_option("", "--runtime-memory-check-threshold=8")
        llvm.set_option("", "--vectorize-memory-check-threshold=128")

    if no_arcp:
        codegen.FASTMATH = {f for f in codegen.FASTMATH if f != "arcp"}
    import pmabayes as pb

    model = pb.Model(effects)
    rng = np.random.default_rng(0)
    defaults = np.array([model.defaults[n] for n in model.parameter_names])
    theta = defaults * rng.uniform(0.8, 1.2, (members, defaults.size))
    t = np.arange(0.0, duration_s, 1e-3)
    u = 2e5 + 1e5 * np.sin(2 * np.pi * 1.3 * t)
    batch = pb.simulate(model, theta, u, dt_s=1e-3)  # compiles
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        pb.simulate(model, theta, u, dt_s=1e-3)
        best = min(best, time.perf_counter() - start)
    alone = np.stack([pb.simulate(model, theta[i:i + 1], u, dt_s=1e-3)[0] for i in range(4)])
    gap = float(np.nanmax(np.abs(alone - batch[:4])))
    return {"seconds": best, "alone_equals_batch": bool(np.array_equal(alone, batch[:4],
                                                                       equal_nan=True)),
            "largest_gap_m": gap}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, default=300, help="members in the batch (300)")
    ap.add_argument("--duration", type=float, default=13.0, help="record length in s (13)")
    ap.add_argument("--repeats", type=int, default=3, help="timed batches, best kept (3)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        spec = json.loads(args.child)
        print(json.dumps(_child(**spec)))
        return
    rows = {}
    for case, (wide, no_arcp) in CASES.items():
        for label, effects in (("without", BASE), ("with", [*BASE, LAW])):
            spec = {"wide": wide, "no_arcp": no_arcp, "effects": effects,
                    "members": args.members, "duration_s": args.duration,
                    "repeats": args.repeats}
            with tempfile.TemporaryDirectory(prefix="pmabayes-law-") as cache:
                env = {**os.environ, "PMABAYES_THREADS": "1", "PMABAYES_CACHE_DIR": cache}
                out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)],
                                     env=env, capture_output=True, text=True, check=True)
            rows[case, label] = json.loads(out.stdout.strip().splitlines()[-1])
            r = rows[case, label]
            print(f"{case:21s} {label:7s} the law: {r['seconds']:.3f} s for {args.members} "
                  f"members; alone = in the batch: {r['alone_equals_batch']} (largest gap "
                  f"{r['largest_gap_m']:.2g} m)", flush=True)
    print("slowdown with the law: " + ", ".join(
        f"{case} {rows[case, 'with']['seconds'] / rows[case, 'without']['seconds']:.1f}x"
        for case in CASES))


if __name__ == "__main__":
    main()
