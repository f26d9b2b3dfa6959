"""Calibration table: how often the 90% HDI covers the truth, per parameter.

Runs the study of ``analyses/calibration.py`` (its ``calibrate``, ``coverage`` and
``z_spread``: synthetic data sets with base parameters drawn from the plausible
region, each fitted) and writes the table for the paper with the numbers the text
needs.

Usage::

    python analyses/paper/paper_calibration.py [--out-root paper] [--quick] [--seed 1]
                                         [--datasets N] [--fits-from CSV]
                                         [--single-record-from CSV]
                                         [--single-periodic-from CSV]

Full mode: ``--datasets`` (default 20) data sets of 10 trials of the paper's 15 s
chirp with the default sampler settings, as ``calibration.py``. Quick mode: 3 data
sets of 3 trials of a 4 s chirp with short chains (not converged; the numbers then
only show that the pipeline runs). Writes ``tables/calibration.tex``,
``tables/calibration_fits.csv`` and ``tables/numbers_calibration.tex``; prints the
table's path last.

``--fits-from`` takes the per-fit rows (``calibration_fits.csv``) of a run of
``analyses/calibration.py`` with its defaults (10 trials of the 15 s chirp) instead of
fitting here. The single-record table (``tables/calibration_single.tex`` and its
numbers, ``pbCalSingle...``) comes from ``--single-record-from``, the rows of
``calibration.py --single record`` (``calibration_single_record_fits.csv``), or else
from fits made here (12 single records; 2 with short chains in quick mode); the
periodic records' (``tables/calibration_single_periodic.tex``, ``pbCalPeriodic...``)
likewise from ``--single-periodic-from`` (``calibration.py --single periodic``).
"""

from __future__ import annotations

import csv
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _paper import QUICK_SETTINGS, Numbers, out_dirs, parser, sig, symbol

from pmabayes.synthetic import Chirp


def calibration_table(coverage: dict[str, float], z_rms: dict[str, float], n: int,
                      oracle: tuple[dict, dict] | None = None) -> str:
    """The booktabs ``tabular`` of the coverage and RMS of ``z`` per parameter.

    Parameters
    ----------
    coverage : dict
        Fraction of the ``n`` data sets whose 90% HDI covers the truth, per parameter.
    z_rms : dict
        RMS over the data sets of the standardised error, per parameter.
    n : int
        Number of data sets.
    oracle : tuple of dict, optional
        The noise-known oracle's coverage and RMS of ``z`` on the same data sets
        (``analyses/single_record_oracle.py``), as two more columns.

    Returns
    -------
    str
        LaTeX source of the ``tabular``.
    """
    def cell(c: float, z: float) -> str:
        return f"{round(c * n)}/{n} ({100 * c:.0f}\\%) & {z:.2f}"

    body = [f"${symbol(k)}$ & {cell(c, z_rms[k])}"
            + ("" if oracle is None else f" & {cell(oracle[0][k], oracle[1][k])}") + r" \\"
            for k, c in coverage.items()]
    head = r"parameter & 90\% HDI covers truth & RMS of $z$"
    cols = "lrr"
    if oracle is not None:  # narrower headings: five columns in one column of the paper
        head = r"parameter & HDI covers & RMS $z$ & oracle covers & oracle RMS $z$"
        cols += "rr"
    table = [rf"\begin{{tabular}}{{{cols}}}", r"\toprule", head + r" \\", r"\midrule", *body,
             r"\bottomrule", r"\end{tabular}"]
    return "\n".join(table) + "\n"


def read_fits(path: Path) -> list[dict]:
    """The per-fit rows ``calibration.py`` writes (``*_fits.csv``), typed back.

    Parameters
    ----------
    path : Path
        The CSV file.

    Returns
    -------
    list of dict
        One row per data set and parameter, as :func:`calibration.calibrate` returns.
    """
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            rows.append({**r, "dataset": int(r["dataset"]), "truth": float(r["truth"]),
                         "z": float(r["z"]), "covered": r["covered"] == "True",
                         "converged": r["converged"] == "True"})
    if not rows:
        raise SystemExit(f"{path}: no rows; give the *_fits.csv of a calibration.py run")
    return rows


#: per single-record study: its table's file and its numbers' prefix
SINGLE_TABLES = {"record": ("calibration_single.tex", "pbCalSingle"),
                 "periodic": ("calibration_single_periodic.tex", "pbCalPeriodic")}


def _single_record(rows: list[dict], tables: Path, nums: Numbers, calibration,
                   single: str = "record") -> None:
    """The table and numbers of a single-record study (``calibration.py --single``),
    beside the noise-known oracle on the same data sets."""
    name, prefix = SINGLE_TABLES[single]
    cov = calibration.coverage(rows)
    spread = calibration.z_spread(rows)
    n = len({r["dataset"] for r in rows})
    # the best any method could do on these data sets: the noise known (Wald z)
    from single_record_oracle import Z90, oracle_z

    truths: dict[int, dict] = {}
    for r in rows:
        truths.setdefault(r["dataset"], {"seed": int(r["seed"])})[r["parameter"]] = r["truth"]
    z = [oracle_z({k: v for k, v in t.items() if k != "seed"}, t["seed"], single=single)["z"]
         for t in truths.values()]
    o_cov = {k: float(np.mean([abs(zi[k]) < Z90 for zi in z])) for k in cov}
    o_rms = {k: float(np.sqrt(np.mean([zi[k] ** 2 for zi in z]))) for k in cov}
    (tables / name).write_text(calibration_table(cov, spread, n, oracle=(o_cov, o_rms)))
    nums.add(f"{prefix}Datasets", n)
    nums.add(f"{prefix}Converged", len({r["dataset"] for r in rows if r["converged"]}))
    nums.add(f"{prefix}Covered", sum(r["covered"] for r in rows))
    nums.add(f"{prefix}Intervals", len(rows))
    nums.add(f"{prefix}CoverageMin", f"{100 * min(cov.values()):.0f}")
    nums.add(f"{prefix}CoverageMax", f"{100 * max(cov.values()):.0f}")
    nums.add(f"{prefix}ZMin", f"{min(spread.values()):.2f}")
    nums.add(f"{prefix}ZMax", f"{max(spread.values()):.2f}")
    nums.add(f"{prefix}OracleCoverageMin", f"{100 * min(o_cov.values()):.0f}")
    nums.add(f"{prefix}OracleCoverageMax", f"{100 * max(o_cov.values()):.0f}")
    nums.add(f"{prefix}OracleZMin", f"{min(o_rms.values()):.2f}")
    nums.add(f"{prefix}OracleZMax", f"{max(o_rms.values()):.2f}")


def main(argv: list[str] | None = None) -> int:
    """Fit the data sets (or read a run's fits) and write the tables and numbers."""
    p = parser(__doc__)
    p.add_argument("--datasets", type=int, default=None, help="data sets (20; quick 3)")
    p.add_argument("--fits-from", type=Path, default=None,
                   help="calibration_fits.csv of an analyses/calibration.py run (defaults)")
    p.add_argument("--single-record-from", type=Path, default=None,
                   help="calibration_single_record_fits.csv of calibration.py --single record")
    p.add_argument("--single-periodic-from", type=Path, default=None,
                   help="calibration_single_periodic_fits.csv of calibration.py --single "
                   "periodic")
    args = p.parse_args(argv)
    import calibration  # after _paper, which puts the checkout on the path

    _, tables = out_dirs(args.out_root)
    if args.fits_from is not None:
        rows = read_fits(args.fits_from)
        n, n_trials, chirp = len({r["dataset"] for r in rows}), 10, None
        seconds, settings = None, None
    elif args.quick:
        n = 3 if args.datasets is None else args.datasets
        chirp, n_trials, settings = Chirp(duration_s=4.0, f0_hz=0.3, f1_hz=2.0), 3, QUICK_SETTINGS
    else:
        n = 20 if args.datasets is None else args.datasets
        chirp, n_trials, settings = None, 10, None
    if args.fits_from is None:
        if n < 1:
            p.error("--datasets must be at least 1")
        start = time.perf_counter()
        rows = calibration.calibrate(n, args.seed, chirp=chirp, n_trials=n_trials,
                                     settings=settings)
        seconds = time.perf_counter() - start
    cov = calibration.coverage(rows)
    spread = calibration.z_spread(rows)
    with open(tables / "calibration_fits.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    path = tables / "calibration.tex"
    path.write_text(calibration_table(cov, spread, n))
    n_conv = len({r["dataset"] for r in rows if r["converged"]})
    nums = Numbers("calibration", args.quick)
    nums.add("pbCalDatasets", n)
    nums.add("pbCalConverged", n_conv)
    nums.add("pbCalTrials", n_trials)
    nums.add("pbCalChirp", sig((chirp or Chirp()).duration_s, 2))
    nums.add("pbCalCoverageMin", f"{100 * min(cov.values()):.0f}")
    nums.add("pbCalCoverageMax", f"{100 * max(cov.values()):.0f}")
    nums.add("pbCalZMin", f"{min(spread.values()):.2f}")
    nums.add("pbCalZMax", f"{max(spread.values()):.2f}")
    if seconds is not None:
        nums.add("pbCalSeconds", f"{seconds:.0f}")
    if args.single_record_from is not None:
        single = read_fits(args.single_record_from)
    else:  # the single-record study here: 2 short fits in quick mode, else 12
        # a single record samples its 3 noise parameters too: 9 parameters, 18+ walkers
        single = calibration.calibrate(
            2 if args.quick else 12, args.seed, single="record", verbose=False,
            settings=None if settings is None else replace(settings, n_walkers=24))
    _single_record(single, tables, nums, calibration)
    if args.single_periodic_from is not None:
        periodic = read_fits(args.single_periodic_from)
    else:  # the periodic study here: 2 short fits in quick mode, else 12
        periodic = calibration.calibrate(2 if args.quick else 12, args.seed, single="periodic",
                                         verbose=False, settings=settings)
    _single_record(periodic, tables, nums, calibration, "periodic")
    nums.write(tables)
    print(f"coverage {min(cov.values()):.2f}-{max(cov.values()):.2f}, RMS z "
          f"{min(spread.values()):.2f}-{max(spread.values()):.2f}, {n_conv}/{n} converged"
          + (f", {seconds:.0f} s" if seconds is not None else ""))
    print(f"table: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
