"""The paper's Fig. 2 redone: chirp input, measured response, posterior predictive band.

Fits ``data/pma_chirp_paper.csv`` (synthetic: the paper's model and values with the
default measurement noise) with the base model, or loads the cached fit, and draws
the commanded pressure, the ten measured trials with the posterior predictive band
and the residual of the trial mean against the noise floor.

Usage::

    python analyses/paper/paper_fig2.py [--out-root paper] [--quick] [--seed 1]

Writes ``figures/fig2_predictive.png`` and ``tables/numbers_fig2.tex``; prints the
figure's path last.
"""

from __future__ import annotations

import json
import sys

import matplotlib.pyplot as plt
import numpy as np
from _paper import DATA_DIR, Numbers, cached_fit, out_dirs, paper_dataset, parser, sig

from pmabayes.model.model import CARRIAGE_MASS_KG, CONTROL_LOAD_KG, PAPER_AREA_M2, PMA_MASS_KG
from pmabayes.report.fit_data import predictive_band


def main(argv: list[str] | None = None) -> int:
    """Fit (or load), draw the figure and write its numbers."""
    args = parser(__doc__).parse_args(argv)
    figures, tables = out_dirs(args.out_root)
    ds = paper_dataset(args.quick)
    tree, _ = cached_fit(args.out_root, "paper_base", ds, (), quick=args.quick, seed=args.seed)
    pred = predictive_band(tree, ci_prob=0.9)
    t, data, med, lo, hi = (pred[k] for k in ("time", "data", "median", "low", "high"))
    mean = data.mean(axis=0)
    floor = ds.noise_floor_m
    resid = mean - med
    rms = float(np.sqrt(np.mean(resid**2)))

    fig, axes = plt.subplots(3, 1, figsize=(7.0, 6.4), sharex=True, layout="constrained",
                             gridspec_kw={"height_ratios": [1, 2, 1.3]})
    axes[0].plot(t, ds.input[0] / 1e6, color="0.3", lw=0.7)
    axes[0].set_ylabel("pressure [MPa]")
    axes[0].set_title(f"commanded chirp {ds.time_s[0]:.0f}-{ds.time_s[-1]:.0f} s "
                      "(synthetic data)", fontsize=9, loc="left")
    axes[1].fill_between(t, lo * 1e3, hi * 1e3, color="tab:blue", alpha=0.35, lw=0,
                         label="90% posterior predictive")
    for k in range(data.shape[0]):
        axes[1].plot(t, data[k] * 1e3, color="k", lw=0.3, alpha=0.4,
                     label=f"{data.shape[0]} measured trials" if k == 0 else None)
    axes[1].plot(t, med * 1e3, color="tab:red", lw=0.7, ls="--", label="median model")
    axes[1].set_ylabel("position x [mm]")
    axes[1].legend(fontsize=7, loc="upper left", ncols=3)
    axes[2].fill_between(t, (lo - med) * 1e6, (hi - med) * 1e6, color="tab:blue", alpha=0.25,
                         lw=0, label="90% predictive (one trial) − median")
    axes[2].axhspan(-floor * 1e6, floor * 1e6, color="tab:green", alpha=0.35,
                    label=f"trial-mean noise floor ±{floor * 1e6:.3g} µm")
    axes[2].plot(t, resid * 1e6, color="k", lw=0.5, label=f"trial mean − median model "
                 f"(RMS {rms * 1e6:.3g} µm)")
    axes[2].set_ylabel("residual [µm]")
    axes[2].set_xlabel("time [s]")
    axes[2].legend(fontsize=7, loc="upper left", ncols=2)
    path = figures / "fig2_predictive.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)

    nums = Numbers("fig2", args.quick)
    nums.add("pbFigTwoTrials", ds.n_trials)
    nums.add("pbFigTwoDuration", sig(ds.time_s[-1] + ds.dt_s, 3))
    nums.add("pbFigTwoCoverage", f"{100 * pred['coverage']:.1f}")
    nums.add("pbFigTwoResidRMS", sig(rms * 1e6, 3))
    nums.add("pbFigTwoFloor", sig(floor * 1e6, 3))
    nums.add("pbFigTwoRatio", sig(rms / floor, 2))
    nums.add("pbFigTwoRange", sig(data.max() * 1e3, 3))
    # how the bundled data were made, from their sidecars (whatever the mode)
    gen_paper = json.loads((DATA_DIR / "pma_chirp_paper.json").read_text())["generator"]
    gen_lab = json.loads((DATA_DIR / "pma_chirp_lab.json").read_text())["generator"]
    chirp, noise = gen_paper["chirp"], gen_paper["noise"]
    nums.add("pbDataTrials", gen_paper["n_trials"])
    nums.add("pbDataDuration", sig(chirp["duration_s"], 2))
    nums.add("pbDataFzero", sig(chirp["f0_hz"], 1))
    nums.add("pbDataFone", sig(chirp["f1_hz"], 1))
    nums.add("pbDataPmax", sig(chirp["p_max_pa"] / 1e6, 1))
    nums.add("pbDataRate", sig(chirp["sample_rate_hz"] / 1e3, 1))
    nums.add("pbDataNoiseUm", sig(noise["disturbance_std_m"] * 1e6, 2))
    nums.add("pbDataCorrS", sig(noise["disturbance_corr_time_s"], 1))
    nums.add("pbDataCountsInch", f"{noise['encoder_counts_per_m'] * 0.0254:.0f}")
    nums.add("pbDataQuantUm", sig(1e6 / noise["encoder_counts_per_m"], 3))
    nums.add("pbDataSeedPaper", gen_paper["seed"])
    nums.add("pbDataSeedLab", gen_lab["seed"])
    nums.add("pbDataLagMs", sig(gen_lab["effects"]["regulator_lag"]["tau_reg"] * 1e3, 2))
    nums.add("pbDataFrictionN", sig(gen_lab["effects"]["coulomb_friction"]["F_c"], 1))
    nums.add("pbDataFrictionVc", sig(gen_lab["parameters"]["v_c"] * 1e3, 1))
    nums.add("pbAreaMM", sig(PAPER_AREA_M2 * 1e6, 4))
    nums.add("pbMassKg", sig(PMA_MASS_KG + CARRIAGE_MASS_KG, 3))
    nums.add("pbLoadKg", sig(CONTROL_LOAD_KG, 1))
    nums.write(tables)
    print(f"predictive coverage {pred['coverage']:.3f}, residual RMS {rms * 1e6:.3g} um, "
          f"floor {floor * 1e6:.3g} um")
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
