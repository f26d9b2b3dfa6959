"""Robustness bands against frequency and the probability that computed torque wins.

Pushes posterior samples of the case study's final lab fit (base + regulator lag +
Coulomb friction on ``data/pma_chirp_lab.csv``; fitted here if
``paper_criticism.py`` has not cached it) through both controllers at several
reference frequencies (``pmabayes.control.robustness.robustness_sweep``, mode ``plant``:
the plant is drawn from the posterior and the controllers use the posterior mean),
and draws the RMS error and phase lag bands with P(CT beats PID)
(``pmabayes.report.figures.plot_robustness``).

Usage::

    python analyses/paper/paper_robustness.py [--out-root paper] [--quick] [--seed 1]
                                        [--samples S]

Full mode: 500 samples at the 8 default frequencies (0.25-3 Hz); quick mode: 16
samples at 4 frequencies, on the quick fit, with ``pmabayes.control.DEFAULT_GAINS``
(the paper model's gains) instead of tuning both controllers on the posterior mean,
which is what costs most in a small sweep. Writes ``figures/robustness.png``,
``tables/robustness.tex`` and ``tables/numbers_robustness.tex``; prints the figure's
path last.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from _paper import LAB_EFFECTS, Numbers, cached_fit, lab_dataset, out_dirs, parser, sig

from pmabayes.control import DEFAULT_GAINS
from pmabayes.control.robustness import robustness_sweep, summarise_robustness
from pmabayes.report.figures import plot_robustness, plt


def main(argv: list[str] | None = None) -> int:
    """Run the sweep, draw it and write its table and numbers."""
    p = parser(__doc__)
    p.add_argument("--samples", type=int, default=None, help="posterior samples (500)")
    args = p.parse_args(argv)
    figures, tables = out_dirs(args.out_root)
    tree, _ = cached_fit(args.out_root, "lab_final", lab_dataset(args.quick),
                         list(LAB_EFFECTS), quick=args.quick, seed=args.seed)
    samples = args.samples or (16 if args.quick else 500)
    freqs = tuple(np.geomspace(0.25, 3.0, 4)) if args.quick else None
    start = time.perf_counter()
    ds = robustness_sweep(tree, samples=samples, frequencies_hz=freqs, mode="plant",
                          seed=args.seed, progress=False,
                          gains=DEFAULT_GAINS if args.quick else None)
    seconds = time.perf_counter() - start
    path = figures / "robustness.png"
    plt.close(plot_robustness(ds, path=path))
    s = summarise_robustness(ds)
    body = []
    for f in s["frequency"].values:
        row = [f"{f:.2f}"]
        for c in ("pid", "ct"):
            x = s.sel(frequency=f, controller=c)
            row.append(f"{1e3 * float(x['rms_error_m_median']):.3f} "
                       f"[{1e3 * float(x['rms_error_m_q05']):.3f}, "
                       f"{1e3 * float(x['rms_error_m_q95']):.3f}]")
        pf = float(s["p_ct_beats_pid"].sel(frequency=f))
        row.append(f"{pf:.3f}")
        body.append(" & ".join(row) + r" \\")
    table = [r"\begin{tabular}{lllr}", r"\toprule",
             r"$f$ [Hz] & PID RMS [mm] & CT RMS [mm] & P(CT wins) \\",
             r" & median [90\% band] & median [90\% band] & \\", r"\midrule", *body,
             r"\bottomrule", r"\end{tabular}"]
    (tables / "robustness.tex").write_text("\n".join(table) + "\n")
    p_win = s["p_ct_beats_pid"].values
    ratio = (s["rms_error_m_median"].sel(controller="pid")
             / s["rms_error_m_median"].sel(controller="ct")).values
    nums = Numbers("robustness", args.quick)
    nums.add("pbRobSamples", int(ds.sizes["sample"]))
    nums.add("pbRobFreqs", int(ds.sizes["frequency"]))
    nums.add("pbRobFreqMin", sig(float(s["frequency"].min()), 2))
    nums.add("pbRobFreqMax", sig(float(s["frequency"].max()), 2))
    nums.add("pbRobPWinMin", f"{float(p_win.min()):.3f}")
    nums.add("pbRobMCError", f"{float(s['p_ct_beats_pid_mc_error'].max()):.3f}")
    nums.add("pbRobRatioMin", f"{float(ratio.min()):.1f}")
    nums.add("pbRobRatioMax", f"{float(ratio.max()):.1f}")
    nums.add("pbRobSeconds", f"{seconds:.1f}")
    nums.add("pbRobGainsSource", "the paper model's default gains (quick mode)" if args.quick
             else "gains tuned by the rule on the posterior mean")
    g = ds.attrs.get("gains")
    if isinstance(g, str):
        g = json.loads(g)
    nums.add("pbRobCTKp", sig(g["ct"]["kp"], 4))
    nums.add("pbRobCTKd", sig(g["ct"]["kd"], 4))
    nums.add("pbRobPIDKp", sig(g["pid"]["kp"], 3))
    nums.add("pbRobPIDKi", sig(g["pid"]["ki"], 3))
    nums.add("pbRobPIDKd", sig(g["pid"]["kd"], 3))
    nums.write(tables)
    print(f"gains: {g}")
    print(f"{ds.sizes['sample']} samples x {ds.sizes['frequency']} frequencies in "
          f"{seconds:.1f} s; min P(CT beats PID) {p_win.min():.3f}")
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
