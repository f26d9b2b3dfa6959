"""Posterior summary table and corner plot of the base model, beside the paper's values.

Uses the same (cached) fit of ``data/pma_chirp_paper.csv`` as ``paper_fig2.py``:
the table has, per parameter, the paper's point value, the posterior mean and sd,
the 90% HDI, R-hat across ensembles and the ESS (``pmabayes.report.summary.summary_table``);
the corner plot (``pmabayes.report.summary.pair_figure``) shows the six model parameters
with the MAP and the paper's values marked.

Usage::

    python analyses/paper/paper_posterior.py [--out-root paper] [--quick] [--seed 1]

Writes ``tables/posterior.tex``, ``figures/corner.png`` and
``tables/numbers_posterior.tex``; prints the figure's path last.
"""

from __future__ import annotations

import sys

import numpy as np
from _paper import Numbers, cached_fit, out_dirs, paper_dataset, parser, sig, symbol, tex_escape

from pmabayes.inference.fitfile import fit_info
from pmabayes.inference.sampler import FitSettings
from pmabayes.model.model import PAPER_VALUES
from pmabayes.report.summary import pair_figure, summary_table

#: display unit and factor from SI of each posterior variable (symbols: Parameter.latex)
UNITS = {"alpha": ("N/m", 1.0), "beta": ("1/m", 1.0), "gamma": ("1/m", 1.0),
         "d": ("N\\,s/m", 1.0), "K_e": ("N/m", 1.0), "p_dz": ("kPa", 1e-3),
         "sigma_noise_m": ("\\textmu m", 1e6), "rho_noise": ("--", 1.0),
         "sigma_white_m": ("\\textmu m", 1e6)}


def _display(row: dict) -> tuple[str, str, float]:
    """Symbol, unit and factor from SI of one summary row."""
    name = row["name"]
    unit, k = UNITS.get(name, (row["unit"], 1.0))
    try:
        return f"${symbol(name)}$", unit, k
    except KeyError:  # not a parameter of the package: its name
        return tex_escape(name), unit, k


def _fmt(value: float | None, digits: int = 5) -> str:
    if value is None or not np.isfinite(value):
        return "--"
    return f"${sig(value, digits)}$"


def posterior_table(rows: list[dict]) -> str:
    """The booktabs table body (a ``tabular``) of a fit's summary rows.

    Parameters
    ----------
    rows : list of dict
        From :func:`pmabayes.report.summary.summary_table`.

    Returns
    -------
    str
        LaTeX source of the ``tabular``.
    """
    out = [r"\begin{tabular}{llrrrrr}", r"\toprule",
           r"par. & unit & paper & mean & sd & 90\% HDI & $\hat R_{\mathrm{ens}}$ \\",
           r"\midrule"]
    for r in rows:
        sym, unit, k = _display(r)
        paper = None if r["paper"] is None else r["paper"] * k
        hdi = f"[{sig(r['hdi_low'] * k, 5)}, {sig(r['hdi_high'] * k, 5)}]"
        rhat = r["r_hat_ensembles"]
        out.append(f"{sym} & {unit} & {_fmt(paper)} & {_fmt(r['mean'] * k)} & "
                   f"{_fmt(r['sd'] * k, 2)} & ${hdi}$ & "
                   f"{'--' if rhat is None else f'{rhat:.3f}'} \\\\")
    out += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Fit (or load), write the table, the corner plot and their numbers."""
    args = parser(__doc__).parse_args(argv)
    figures, tables = out_dirs(args.out_root)
    ds = paper_dataset(args.quick)
    tree, _ = cached_fit(args.out_root, "paper_base", ds, (), quick=args.quick, seed=args.seed)
    rows = summary_table(tree, ci_prob=0.9)
    (tables / "posterior.tex").write_text(posterior_table(rows))
    path = figures / "corner.png"
    pair_figure(tree, path, names=list(PAPER_VALUES))

    info = fit_info(tree)
    conv = info["convergence"]
    by = {r["name"]: r for r in rows}
    inside = sum(by[n]["hdi_low"] <= v <= by[n]["hdi_high"] for n, v in PAPER_VALUES.items())
    rel = {n: by[n]["sd"] / abs(by[n]["mean"]) for n in PAPER_VALUES}
    post = tree["posterior"]
    flat = {n: post[n].values.ravel() for n in PAPER_VALUES}
    corr_ag = float(np.corrcoef(flat["alpha"], flat["gamma"])[0, 1])
    corr_kp = float(np.corrcoef(flat["K_e"], flat["p_dz"])[0, 1])
    bg = flat["beta"] + flat["gamma"]
    t = info["timings_s"]
    nums = Numbers("posterior", args.quick)
    nums.add("pbPostConverged", "converged" if conv["converged"] else "did not converge")
    nums.add("pbPostSteps", conv["n_steps"])
    nums.add("pbPostWalkers", conv["n_walkers"])
    nums.add("pbPostEnsembles", conv["n_ensembles"])
    nums.add("pbPostMinESS", f"{min(conv['ess'].values()):.0f}")
    rhat_e = conv["rhat_ensembles"] or {}
    nums.add("pbPostMaxRhat", f"{max(rhat_e.values()):.3f}" if rhat_e else "n/a")
    nums.add("pbPostTauMultiple", f"{conv['tau_multiple']:g}")
    nums.add("pbPostMinESSRequired", f"{conv['min_ess']:g}")
    nums.add("pbPostMaxRhatRequired", f"{FitSettings().max_rhat:g}")
    nums.add("pbPostMaxTau", f"{max(conv['tau'].values()):.0f}")
    nums.add("pbPostPaperInside", inside)
    nums.add("pbPostRelSdMin", sig(100 * min(rel.values()), 2))
    nums.add("pbPostRelSdMax", sig(100 * max(rel.values()), 2))
    nums.add("pbPostRelSdMaxName", f"${symbol(max(rel, key=rel.get))}$")
    nums.add("pbPostCorrAlphaGamma", f"{corr_ag:.3f}")
    nums.add("pbPostCorrKePdz", f"{corr_kp:.2f}")
    nums.add("pbPostBetaGammaMean", sig(bg.mean(), 4))
    nums.add("pbPostBetaGammaLow", sig(np.quantile(bg, 0.05), 4))
    nums.add("pbPostBetaGammaHigh", sig(np.quantile(bg, 0.95), 4))
    nums.add("pbPostMapSeconds", f"{t['map']:.1f}")
    nums.add("pbPostSamplingSeconds", f"{t['sampling']:.1f}")
    nums.add("pbPostTotalSeconds", f"{t['total']:.1f}")
    nums.add("pbPostRMSCost", sig(info["map"]["rms_cost_m"] * 1e6, 3))
    nums.add("pbPostSigmaNoise", sig(by["sigma_noise_m"]["mean"] * 1e6, 3))
    nums.add("pbPostRhoNoise", f"{by['rho_noise']['mean']:.4f}")
    nums.add("pbPostSigmaWhite", sig(by["sigma_white_m"]["mean"] * 1e6, 3))
    nums.write(tables)
    print(f"paper values inside the 90% HDI: {inside}/{len(PAPER_VALUES)}; "
          f"converged {conv['converged']} after {conv['n_steps']} steps")
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
