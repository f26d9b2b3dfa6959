"""Calibration table: how often the 90% HDI covers the truth, per parameter.

Runs the study of ``analyses/calibration.py`` (its ``calibrate``, ``coverage`` and
``z_spread``: synthetic data sets with base parameters drawn from the plausible
region, each fitted) and writes the table for the paper with the numbers the text
needs.

Usage::

    python analyses/paper_calibration.py [--out-root paper] [--quick] [--seed 1]
                                         [--datasets N]

Full mode: ``--datasets`` (default 20) data sets of 10 trials of the paper's 15 s
chirp with the default sampler settings, as ``calibration.py``. Quick mode: 3 data
sets of 3 trials of a 4 s chirp with short chains (not converged; the numbers then
only show that the pipeline runs). Writes ``tables/calibration.tex``,
``tables/calibration_fits.csv`` and ``tables/numbers_calibration.tex``; prints the
table's path last.
"""

from __future__ import annotations

import csv
import sys
import time

from _paper import QUICK_SETTINGS, Numbers, out_dirs, parser, sig, symbol

from pmabayes.synthetic import Chirp


def calibration_table(coverage: dict[str, float], z_rms: dict[str, float], n: int) -> str:
    """The booktabs ``tabular`` of the coverage and RMS of ``z`` per parameter.

    Parameters
    ----------
    coverage : dict
        Fraction of the ``n`` data sets whose 90% HDI covers the truth, per parameter.
    z_rms : dict
        RMS over the data sets of the standardised error, per parameter.
    n : int
        Number of data sets.

    Returns
    -------
    str
        LaTeX source of the ``tabular``.
    """
    body = [f"${symbol(k)}$ & {round(c * n)}/{n} ({100 * c:.0f}\\%) & {z_rms[k]:.2f} \\\\"
            for k, c in coverage.items()]
    table = [r"\begin{tabular}{lrr}", r"\toprule",
             r"parameter & 90\% HDI covers truth & RMS of $z$ \\", r"\midrule", *body,
             r"\bottomrule", r"\end{tabular}"]
    return "\n".join(table) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Fit the data sets and write the table and its numbers."""
    p = parser(__doc__)
    p.add_argument("--datasets", type=int, default=None, help="data sets (20; quick 3)")
    args = p.parse_args(argv)
    import calibration  # after _paper, which puts the checkout on the path

    _, tables = out_dirs(args.out_root)
    if args.quick:
        n = 3 if args.datasets is None else args.datasets
        chirp, n_trials, settings = Chirp(duration_s=4.0, f0_hz=0.3, f1_hz=2.0), 3, QUICK_SETTINGS
    else:
        n = 20 if args.datasets is None else args.datasets
        chirp, n_trials, settings = None, 10, None
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
    nums.add("pbCalSeconds", f"{seconds:.0f}")
    nums.write(tables)
    print(f"coverage {min(cov.values()):.2f}-{max(cov.values()):.2f}, RMS z "
          f"{min(spread.values()):.2f}-{max(spread.values()):.2f}, {n_conv}/{n} converged, "
          f"{seconds:.0f} s")
    print(f"table: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
