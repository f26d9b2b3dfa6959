"""Regenerate every figure, table and number of the paper, and time each step.

Runs the paper's analyses in order, in this process (so the compiled simulator
kernels are loaded once), each writing into ``<out-root>/figures`` and
``<out-root>/tables`` (``<out-root>`` is ``paper/`` by default):

=============  ==========================================================
step           script
=============  ==========================================================
fig2           ``paper_fig2.py``: chirp, response, posterior predictive
posterior      ``paper_posterior.py``: summary table and corner plot
criticism      ``paper_criticism.py``: base -> + lag -> + friction
discrepancy    ``paper_discrepancy.py``: a force outside the library, proposed
robustness     ``paper_robustness.py``: bands and P(CT beats PID)
figure5        ``paper_figure5.py``: PID vs computed torque, claims
detection      ``paper_detection.py`` (wraps ``detection.py``)
calibration    ``paper_calibration.py`` (wraps ``calibration.py``)
benchmarks     ``paper_benchmarks.py``: simulator vs C, posterior time
=============  ==========================================================

Usage::

    python analyses/run_all.py [--quick] [--out-root DIR] [--seed 1] [--only STEP ...]
                               [--skip STEP ...] [--calibration-datasets N]
                               [--detection-null N] [--detection-seeds N]
                               [--detection-sizes K]

``--quick`` uses small sizes (short synthetic chirps, short chains, few data sets;
for CI, a few minutes). The full mode is for the paper. Fits are cached in
``<out-root>/fits`` and reused by later steps and later runs (delete the folder to
refit). Prints the wall time of every step, last the total.
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "paper"))  # the paper's steps
import _paper  # noqa: E402  (puts the checkout on the path)

STEPS = ("fig2", "posterior", "criticism", "discrepancy", "robustness", "figure5", "detection",
         "calibration", "benchmarks")
MODULES = {s: f"paper_{s}" for s in STEPS}


def main(argv: list[str] | None = None) -> int:
    """Run the selected steps and print how long each took."""
    p = _paper.parser(__doc__)
    p.add_argument("--only", nargs="+", choices=STEPS, help="run only these steps")
    p.add_argument("--skip", nargs="+", choices=STEPS, default=[], help="skip these steps")
    p.add_argument("--calibration-datasets", type=int, default=None)
    p.add_argument("--detection-null", type=int, default=None)
    p.add_argument("--detection-seeds", type=int, default=None)
    p.add_argument("--detection-sizes", type=int, default=None)
    args = p.parse_args(argv)
    steps = [s for s in STEPS if (args.only is None or s in args.only) and s not in args.skip]
    common = ["--out-root", str(args.out_root), "--seed", str(args.seed)]
    common += ["--quick"] if args.quick else []
    extra = {s: [] for s in STEPS}
    if args.calibration_datasets is not None:
        extra["calibration"] += ["--datasets", str(args.calibration_datasets)]
    for opt in ("null", "seeds", "sizes"):
        value = getattr(args, f"detection_{opt}")
        if value is not None:
            extra["detection"] += [f"--{opt}", str(value)]
    timings = {}
    failed = []
    total = time.perf_counter()
    for step in steps:
        print(f"\n=== {step} ({MODULES[step]}.py {' '.join(common + extra[step])})", flush=True)
        start = time.perf_counter()
        try:
            rc = importlib.import_module(MODULES[step]).main(common + extra[step])
        except Exception as exc:  # report the step and go on with the others
            print(f"step {step} FAILED: {type(exc).__name__}: {exc}", flush=True)
            rc = 1
        timings[step] = time.perf_counter() - start
        if rc:
            failed.append(step)
        print(f"=== {step}: {timings[step]:.1f} s", flush=True)
    print(f"\n{'step':<12}{'seconds':>10}  ({'quick' if args.quick else 'full'} mode, "
          f"out-root {args.out_root})")
    for step, secs in timings.items():
        print(f"{step:<12}{secs:>10.1f}" + ("  FAILED" if step in failed else ""))
    print(f"{'total':<12}{time.perf_counter() - total:>10.1f}")
    if failed:
        print(f"failed steps: {', '.join(failed)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
