"""What a fit's posterior says about identifiability: precision and trade-offs.

Reads a fit written by ``pmabayes fit`` and prints, for the model's parameters, the
relative standard deviation of each (sd over |mean|), the largest correlations
between them, the smallest eigenvalue of their correlation matrix (a nearly
degenerate direction when small), and the posterior of ``beta + gamma`` (below zero,
the hysteretic force grows without bound on loading).

Usage::

    python analyses/identifiability.py FIT.nc [--pairs 4]

The docs' Identification page quotes its output for ``data/pma_chirp_paper.csv``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pmabayes import load_fit
from pmabayes.inference.fitfile import fit_info


def main(argv: list[str] | None = None) -> int:
    """Print the precision and the trade-offs of a fit's parameters."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit", type=Path, help="a fit written by pmabayes fit")
    parser.add_argument("--pairs", type=int, default=4, help="correlations to print (4)")
    args = parser.parse_args(argv)
    tree = load_fit(args.fit)
    names = fit_info(tree)["model"]["free"]
    post = tree["posterior"].to_dataset()
    draws = np.stack([post[n].values.ravel() for n in names])
    mean, sd = draws.mean(axis=1), draws.std(axis=1, ddof=1)
    order = np.argsort(sd / np.abs(mean))
    print("relative sd: " + ", ".join(f"{names[i]} {100 * sd[i] / abs(mean[i]):.3f}%"
                                      for i in order))
    corr = np.corrcoef(draws)
    pairs = sorted(((abs(corr[i, j]), i, j) for i in range(len(names))
                    for j in range(i + 1, len(names))), reverse=True)[:args.pairs]
    print("largest correlations: " + ", ".join(f"{names[i]}-{names[j]} {corr[i, j]:+.3f}"
                                               for _, i, j in pairs))
    print(f"smallest eigenvalue of the correlation matrix: {np.linalg.eigvalsh(corr)[0]:.4f}")
    if {"beta", "gamma"} <= set(names):
        s = post["beta"].values.ravel() + post["gamma"].values.ravel()
        lo, hi = np.quantile(s, [0.05, 0.95])
        print(f"beta + gamma: mean {s.mean():.3f} 1/m, 90% interval [{lo:.3f}, {hi:.3f}], "
              f"P(< 0) = {np.mean(s < 0):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
