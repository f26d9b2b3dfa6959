"""How fast the compiled simulator runs a batch with a hysteresis law that carries a state
(``bouc_wen_baber_noori``), against the same model without it, and what LLVM's
vectoriser has to do with it.

The model is sample 2's third round (``maxwell_creep``, ``force_length_map``) with and
without the degrading, pinching law, on the muscle's default rig, driven by a 1.3 Hz
pressure sine at 1 kHz (``--duration`` seconds). Each case runs in a fresh process
with its own kernel cache, one simulation thread, and the best of ``--repeats`` batches
of ``--members`` members near the defaults (seed 0) is timed; the first call compiles.
Each case also says whether a member simulated alone gives, to
the bit, what it gives inside the batch: a vectorised loop may round a member in its
vector body differently from its scalar remainder (what the simulator promises is that
the threads never change the numbers, not this).

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

With ``--bits``, it first says which kernels the raised limits change at all: the
positions and recorded states of 37 members for every built-in effect alone and beside
the creep element and the map, compiled under LLVM's limits and under pmabayes's,
compared to the bit.

A benchmark, not a test: synthetic input, nothing read or written outside the
temporary caches. The figure, the law's slowdown in each case, is printed last.

Usage::

    python analyses/law_kernel_speed.py [--members 300] [--duration 13] [--repeats 3] [--bits]
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


def _pmabayes(wide: bool, no_arcp: bool):
    """pmabayes in this (fresh) process, its kernels to be compiled as the case says."""
    import llvmlite.binding as llvm

    import pmabayes.model.codegen as codegen
    import pmabayes.model.kernels  # noqa: F401  (sets pmabayes's limits)

    if not wide:  # read when a kernel compiles: back to LLVM's own
        llvm.set_option("", "--runtime-memory-check-threshold=8")
        llvm.set_option("", "--vectorize-memory-check-threshold=128")
    if no_arcp:
        codegen.FASTMATH = {f for f in codegen.FASTMATH if f != "arcp"}
    import pmabayes as pb

    return pb


def _batch(pb, effects: list[str], members: int, duration_s: float):
    """A model, a batch of members near its defaults (seed 0) and the pressure sine."""
    import numpy as np

    model = pb.Model(effects)
    rng = np.random.default_rng(0)
    defaults = np.array([model.defaults[n] for n in model.parameter_names])
    theta = defaults * rng.uniform(0.8, 1.2, (members, defaults.size))
    t = np.arange(0.0, duration_s, 1e-3)
    return model, theta, 2e5 + 1e5 * np.sin(2 * np.pi * 1.3 * t)


def _child(wide: bool, no_arcp: bool, effects: list[str], members: int, duration_s: float,
           repeats: int) -> dict:
    """One case, in this (fresh) process: the batch's best time and the bit check."""
    import time

    import numpy as np

    pb = _pmabayes(wide, no_arcp)
    model, theta, u = _batch(pb, effects, members, duration_s)
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


def _bits(wide: bool, duration_s: float) -> dict:
    """A digest of the positions and recorded states of 37 members for every built-in
    effect alone and beside ``BASE``, compiled as the case says."""
    import dataclasses
    import hashlib

    import numpy as np

    pb = _pmabayes(wide, False)
    names = [e.name for e in pb.registered_effects().values()]
    compositions = [[]] + [[n] for n in names] + [[*BASE, n] for n in names if n not in BASE]
    digests = {}
    for effects in compositions:
        model, theta, u = _batch(pb, effects, 37, duration_s)
        sim = pb.simulate(model, theta, u, dt_s=1e-3, states=True)
        h = hashlib.sha1(np.ascontiguousarray(pb.simulate(model, theta, u, dt_s=1e-3)).data)
        for f in dataclasses.fields(sim):
            h.update(np.ascontiguousarray(getattr(sim, f.name)).data)
        digests["+".join(effects) or "base"] = h.hexdigest()
    return digests


def _run_child(spec: dict) -> dict:
    """``spec``'s case in a fresh process with its own kernel cache and one thread."""
    with tempfile.TemporaryDirectory(prefix="pmabayes-law-") as cache:
        env = {**os.environ, "PMABAYES_THREADS": "1", "PMABAYES_CACHE_DIR": cache}
        out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)],
                             env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _compare_bits(duration_s: float) -> None:
    """Print the compositions whose numbers differ between LLVM's limits and pmabayes's."""
    own, raised = (_run_child({"wide": wide, "duration_s": duration_s})
                   for wide in (False, True))
    moved = [c for c in own if own[c] != raised[c]]
    print(f"compositions whose positions or states change with the raised limits: "
          f"{len(moved)} of {len(own)} ({', '.join(moved) or 'none'})", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, default=300, help="members in the batch (300)")
    ap.add_argument("--duration", type=float, default=13.0, help="record length in s (13)")
    ap.add_argument("--repeats", type=int, default=3, help="timed batches, best kept (3)")
    ap.add_argument("--bits", action="store_true",
                    help="first say which kernels the raised limits change: every built-in "
                         "effect alone and beside the creep and the map, compiled both ways")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        spec = json.loads(args.child)
        print(json.dumps(_bits(**spec) if "no_arcp" not in spec else _child(**spec)))
        return
    if args.bits:
        _compare_bits(args.duration)
    rows = {}
    for case, (wide, no_arcp) in CASES.items():
        for label, effects in (("without", BASE), ("with", [*BASE, LAW])):
            spec = {"wide": wide, "no_arcp": no_arcp, "effects": effects,
                    "members": args.members, "duration_s": args.duration,
                    "repeats": args.repeats}
            rows[case, label] = _run_child(spec)
            r = rows[case, label]
            print(f"{case:21s} {label:7s} the law: {r['seconds']:.3f} s for {args.members} "
                  f"members; alone = in the batch: {r['alone_equals_batch']} (largest gap "
                  f"{r['largest_gap_m']:.2g} m)", flush=True)
    print("slowdown with the law: " + ", ".join(
        f"{case} {rows[case, 'with']['seconds'] / rows[case, 'without']['seconds']:.1f}x"
        for case in CASES))


if __name__ == "__main__":
    main()
