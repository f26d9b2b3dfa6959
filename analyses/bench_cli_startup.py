"""How long the command line takes to start: imports, ``--help`` and a first line.

Three measurements, each in fresh processes of this Python:

1. ``python -X importtime -c "import pmabayes.cli"``: the cumulative import time of
   ``pmabayes.cli`` and of the slowest modules it pulls in (the numbers are
   microseconds in Python's own report; printed here in seconds);
2. the wall time of ``pmabayes --help`` and of every subcommand's ``--help``
   (``python -m pmabayes ...``), the median of ``--repeats`` runs after one warm-up;
3. the wall time until the first line a working command prints: ``pmabayes fit``
   on a small synthetic data file (made once, beforehand), stopped as soon as its
   first line arrives on stdout or stderr.

Usage::

    python analyses/bench_cli_startup.py [--repeats 5] [--json OUT.json]

The last line printed is ``help_wall_s: <number>``, the median wall time of
``pmabayes --help``. A benchmark, not a test: nothing here asserts a time (the
tests check the import of the command line directly).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: every subcommand, for the ``--help`` timings
COMMANDS = ("run", "fit", "batch", "report", "predict", "simulate", "diagnose", "compare",
            "effects", "track", "robustness", "validate")


def import_times(module: str = "pmabayes.cli") -> tuple[float, list[tuple[float, str]]]:
    """The cumulative import time of ``module`` in s, and the ten slowest imports under it
    (cumulative, s), from ``python -X importtime``."""
    run = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                         capture_output=True, text=True, check=True)
    rows = []
    for line in run.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|(\s*)(\S+)", line)
        if m:
            rows.append((int(m.group(2)) * 1e-6, len(m.group(3)), m.group(4)))
    total = next(t for t, _, name in reversed(rows) if name == module)
    # the top-level imports of the report (one level under the module itself)
    slow = sorted(((t, name) for t, depth, name in rows if name != module), reverse=True)
    return total, slow[:10]


def wall(argv: list[str], repeats: int) -> float:
    """Median wall time of ``python -m pmabayes ARGV`` over ``repeats`` runs (one warm-up)."""
    times = []
    for k in range(repeats + 1):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "pmabayes", *argv], capture_output=True,
                       check=True)
        if k:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def first_line(argv: list[str], cwd: Path) -> float:
    """Seconds until ``python -m pmabayes ARGV`` prints its first line (stdout or stderr)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "pmabayes", *argv], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        proc.stdout.readline()
        return time.perf_counter() - t0
    finally:
        proc.kill()
        proc.wait()


def main(argv: list[str] | None = None) -> int:
    """Run the three measurements and print them, the ``--help`` figure last."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs per timing (5)")
    parser.add_argument("--json", help="also write the numbers here")
    args = parser.parse_args(argv)

    total, slow = import_times()
    print(f"python -X importtime -c 'import pmabayes.cli': {total:.3f} s cumulative")
    for t, name in slow:
        print(f"    {t:7.3f} s  {name}")
    helps = {"": wall(["--help"], args.repeats)}
    for cmd in COMMANDS:
        helps[cmd] = wall([cmd, "--help"], args.repeats)
    for cmd, t in helps.items():
        print(f"pmabayes {cmd + ' ' if cmd else ''}--help: {t:.3f} s (median of {args.repeats})")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([sys.executable, "-m", "pmabayes", "simulate", "d.csv", "--trials", "2",
                        "--duration", "1"], cwd=tmp, capture_output=True, check=True)
        firsts = [first_line(["fit", "d.csv", "--out", "f.nc"], tmp)
                  for _ in range(args.repeats)]
    first = statistics.median(firsts)
    print(f"pmabayes fit: first line after {first:.3f} s (median of {args.repeats})")
    if args.json:
        Path(args.json).write_text(json.dumps(
            {"import_s": total, "slowest_imports": slow, "help_s": helps,
             "fit_first_line_s": first, "python": sys.version, "cpus": os.cpu_count()},
            indent=2) + "\n")
    print(f"help_wall_s: {helps['']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
