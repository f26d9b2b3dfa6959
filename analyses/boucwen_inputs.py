"""What the input convention costs on the Bouc-Wen benchmark, at its true parameters.

Simulates the Noel-Schoukens hysteretic benchmark's force oscillator (mass 2 kg,
c 10 N s/m, k 5e4 N/m, alpha 5e4 N/m, and in pmabayes' form beta = 800 and
gamma = -1100 /m) on the benchmark's two noiseless test inputs
(``../shared/external/boucwen/boucwen.npz``, 750 Hz) and prints the RMS error
against the test outputs for each convention of what the input does between
samples (hold, linear, bandlimited) and several substeps:

* the multisine: one period of 8192 samples in periodic steady state
  (``period_samples=8192, steady_state=True``; bandlimited is the FFT reconstruction);
* the sine sweep: 153000 samples from rest (not periodic; bandlimited is the degree-9
  spline).

The test sets are noiseless outputs of the benchmark's own integrator, so at the true
parameters what remains is the simulators' disagreement. Targets: multisine <= 1e-6 m,
sweep <= 3e-6 m.

Usage::

    python analyses/boucwen_inputs.py [--data PATH] [--substeps 1 2 4 8 16 32]
                                      [--json OUT.json] [--figure OUT.png]

The last line printed is the figure's path when ``--figure`` is given, otherwise
``bandlimited_at_default_substeps: multisine <m> sweep <m>``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from pmabayes import Model, Rig, simulate
from pmabayes.model.simulator import BETWEEN_SAMPLES

#: the benchmark's true values in pmabayes' form (beta = beta_b gamma_b, gamma = beta_b delta_b)
TRUTH = {"alpha": 5e4, "beta": 800.0, "gamma": -1100.0, "d": 10.0, "K_e": 5e4}
MASS_KG = 2.0
PERIOD = 8192
#: the substeps the benchmark runs use (see the README: the smallest that meets both
#: targets with a margin; past it the error no longer falls)
DEFAULT_SUBSTEPS = 16
#: ``../shared`` beside the checkout (the main checkout, or a worktree one level deeper)
DEFAULT_DATA = next(
    (p for p in (Path(__file__).resolve().parents[k] / "shared" / "external" / "boucwen"
                 / "boucwen.npz" for k in (2, 3)) if p.exists()),
    Path(__file__).resolve().parents[2] / "shared" / "external" / "boucwen" / "boucwen.npz")


def rms_errors(data: dict, substeps: list[int]) -> list[dict]:
    """RMS error (m) and wall time (s) of every convention and substep count on both
    test sets, one row per (convention, substeps)."""
    fs = float(data["fs"])
    model = Model(rig=Rig.force_oscillator(MASS_KG))
    sets = {
        "multisine": (data["u_test_multisine"], data["y_test_multisine"],
                      dict(period_samples=PERIOD, steady_state=True)),
        "sweep": (data["u_test_sinesweep"], data["y_test_sinesweep"], {}),
    }
    rows = []
    for between in BETWEEN_SAMPLES:
        for s in substeps:
            row = {"between_samples": between, "substeps": s}
            for name, (u, y, kw) in sets.items():
                start = time.perf_counter()
                x = simulate(model, TRUTH, u, dt_s=1.0 / fs, substeps=s, between_samples=between,
                             **kw)[0]
                row[f"{name}_s"] = time.perf_counter() - start
                row[f"{name}_rms_m"] = float(np.sqrt(np.mean((x - y) ** 2)))
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Print the table of RMS errors; optionally write JSON and a figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help="the benchmark's boucwen.npz")
    parser.add_argument("--substeps", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    parser.add_argument("--json", type=Path, help="also write the rows to this file")
    parser.add_argument("--figure", type=Path, help="draw RMS error against substeps here")
    args = parser.parse_args(argv)
    if not args.data.exists():
        parser.error(f"{args.data} not found: pass --data PATH of the benchmark's boucwen.npz")
    data = dict(np.load(args.data))
    rows = rms_errors(data, sorted(set(args.substeps)))

    print("Bouc-Wen benchmark at its true parameters: RMS error against the noiseless "
          "test outputs (m)")
    print(f"{'input':<13}{'substeps':>9}{'multisine':>12}{'sweep':>12}{'time (s)':>10}")
    for r in rows:
        print(f"{r['between_samples']:<13}{r['substeps']:>9}{r['multisine_rms_m']:>12.3g}"
              f"{r['sweep_rms_m']:>12.3g}{r['multisine_s'] + r['sweep_s']:>10.2f}")
    print("targets: multisine <= 1e-06, sweep <= 3e-06; output RMS: multisine "
          f"{np.sqrt(np.mean(data['y_test_multisine'] ** 2)):.3g}, sweep "
          f"{np.sqrt(np.mean(data['y_test_sinesweep'] ** 2)):.3g}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), sharey=True)
        for ax, name, target in zip(axes, ("multisine", "sweep"), (1e-6, 3e-6), strict=True):
            for between in BETWEEN_SAMPLES:
                sel = [r for r in rows if r["between_samples"] == between]
                ax.loglog([r["substeps"] for r in sel], [r[f"{name}_rms_m"] for r in sel],
                          "o-", label=between)
            ax.axhline(target, color="k", ls=":", label="target")
            ax.set_xlabel("substeps per sample")
            ax.set_title(f"test {name}")
        axes[0].set_ylabel("RMS error at the true parameters (m)")
        axes[0].legend()
        fig.tight_layout()
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.figure, dpi=120)
        print(args.figure)
        return 0
    best = [r for r in rows if r["between_samples"] == "bandlimited"
            and r["substeps"] == DEFAULT_SUBSTEPS]
    if best:
        print(f"bandlimited_at_default_substeps: multisine {best[0]['multisine_rms_m']:.3g} "
              f"sweep {best[0]['sweep_rms_m']:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
