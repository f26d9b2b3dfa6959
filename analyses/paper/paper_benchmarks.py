"""Benchmark figures: simulator throughput against the C reference, and posterior time.

Throughput comes from ``analyses/bench_simulator.py``'s functions (a batch of 64
over the paper's 15 s chirp at 1 kHz, best of 7, base model and each built-in
effect, and the C reference ``../shared/bench/c_reference`` run in the same
process). The posterior time is the wall time that the cached fit of
``pma_chirp_paper.csv`` recorded (global search and MAP, then emcee ensembles to
convergence), as ``analyses/bench_posterior.py`` measures it; the fit is made if it
is not cached. If the C reference is missing, its bar is left out and the ratios
are reported as unavailable.

Usage::

    python analyses/paper/paper_benchmarks.py [--out-root paper] [--quick] [--seed 1]

Writes ``figures/bench_simulator.png``, ``tables/bench.tex`` and
``tables/numbers_benchmarks.tex``; prints the figure's path last.
"""

from __future__ import annotations

import os
import sys

import matplotlib.pyplot as plt
from _paper import Numbers, cached_fit, out_dirs, paper_dataset, parser, sig

from pmabayes import Model
from pmabayes.inference.fitfile import fit_info
from pmabayes.model.effects import BUILTIN
from pmabayes.synthetic import Chirp


def main(argv: list[str] | None = None) -> int:
    """Time the simulator, read the posterior time, write figure, table and numbers."""
    args = parser(__doc__).parse_args(argv)
    import bench_simulator  # after _paper, which puts the checkout on the path

    figures, tables = out_dirs(args.out_root)
    chirp = Chirp()
    pressure, dt_s = chirp.pressure_pa(), 1.0 / chirp.sample_rate_hz
    rows = {"base": bench_simulator.pmabayes_us(Model(), pressure, dt_s)}
    # the built-ins only: run_all's other steps may have registered a user effect
    for name in sorted(e.name for e in BUILTIN):
        rows[f"+ {name}"] = bench_simulator.pmabayes_us(Model([name]), pressure, dt_s)
    ref = bench_simulator.DEFAULT_REFERENCE
    c_us = bench_simulator.c_reference_us(ref) if os.access(ref, os.X_OK) else None

    fig, ax = plt.subplots(figsize=(6.5, 3.2), layout="constrained")
    names = list(rows)
    ax.barh(names, [rows[n] for n in names], color="tab:blue")
    if c_us is not None:
        ax.axvline(c_us, color="tab:red", ls="--", label=f"C reference ({c_us:.0f} µs)")
        ax.legend(fontsize=8, loc="lower right")
    ax.invert_yaxis()
    ax.set_xlabel("µs per 15 s trial at 1 kHz (batch of 64)")
    ax.tick_params(labelsize=8)
    path = figures / "bench_simulator.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)

    body = [f"{n.replace('_', r'\_')} & {us:.1f} & "
            f"{'--' if c_us is None else f'{us / c_us:.2f}'} \\\\" for n, us in rows.items()]
    table = [r"\begin{tabular}{lrr}", r"\toprule", r"model & \textmu s/trial & ratio to C \\",
             r"\midrule", *body, r"\bottomrule", r"\end{tabular}"]
    (tables / "bench.tex").write_text("\n".join(table) + "\n")

    tree, _ = cached_fit(args.out_root, "paper_base", paper_dataset(args.quick), (),
                         quick=args.quick, seed=args.seed)
    info = fit_info(tree)
    t = info["timings_s"]
    worst = max((k for k in rows if k != "base"), key=rows.get)
    nums = Numbers("benchmarks", args.quick)
    nums.add("pbBenchBaseUs", f"{rows['base']:.1f}")
    nums.add("pbBenchCUs", "n/a" if c_us is None else f"{c_us:.1f}")
    nums.add("pbBenchRatioBase", "n/a" if c_us is None else f"{rows['base'] / c_us:.2f}")
    nums.add("pbBenchWorst", worst.removeprefix("+ ").replace("_", r"\_"))
    nums.add("pbBenchRatioWorst", "n/a" if c_us is None else f"{rows[worst] / c_us:.2f}")
    nums.add("pbBenchPosteriorSeconds", f"{t['total']:.1f}")
    nums.add("pbBenchMapSeconds", f"{t['map']:.1f}")
    nums.add("pbBenchSamplingSeconds", f"{t['sampling']:.1f}")
    nums.add("pbBenchCores", os.cpu_count() or 1)
    nums.add("pbBenchSimd", bench_simulator.vector_extensions())
    nums.add("pbBenchPosteriorTrials", info["data"]["n_trials"])
    nums.add("pbBenchPosteriorSamples", info["data"]["n_samples"])
    nums.add("pbBenchPosteriorSteps", info["convergence"]["n_steps"])
    nums.add("pbBenchPosteriorConverged",
             "converged" if info["convergence"]["converged"] else "not converged")
    nums.write(tables)
    print(f"base {rows['base']:.1f} us/trial, C {c_us} us/trial; posterior "
          f"{sig(t['total'], 3)} s")
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
