"""Reproduce the paper's Fig. 5 (0.5, 1 and 2 Hz tracking, PID against computed torque).

Two cases, both with the controllers on the paper's identified base model:

* ``nominal``: the plant is that same model (a perfectly identified rig);
* ``lab``: the plant has the two effects hidden in ``data/pma_chirp_lab.csv``, a
  45 ms regulator lag and 0.8 N of Coulomb friction, that the paper's model lacks.

For each, the figure (reference, PID and computed-torque responses, the error below
each; :func:`pmabayes.report.figures.plot_figure5`), the metrics with the fraction of time the
command spends in the dead zone and at the upper limit and the difference between
the last two periods (``settle mm``; large when the loop never settles), and a check
of each of the
paper's claims (:func:`pmabayes.control.reproduction.figure5`), reproduced or not, with the
numbers.

Usage::

    python analyses/figure5.py [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pmabayes.control import inverse_model_pressure_pa
from pmabayes.control.reproduction import figure5
from pmabayes.model.model import Model, Rig
from pmabayes.report.figures import plot_figure5, plt


def main(argv: list[str] | None = None) -> int:
    """Write both figures and print the metrics and the claims."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("."))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    lab = Model(["regulator_lag", "coulomb_friction"], rig=Rig.control())
    cases = {
        "nominal": {},
        "lab": {"plant_model": lab, "plant_params": {"tau_reg": 0.045, "F_c": 0.8}},
    }
    results = {name: figure5(**kw) for name, kw in cases.items()}
    mean = results["nominal"]["reference_mean_m"]  # the controllers' model sets it
    print(f"reference: x_d = {mean:.4f} + 0.0225 sin(2 pi f t) m, 500 g load "
          "(mean by control.operating_mean_m on the controllers' model)")
    ranges = [(f, inverse_model_pressure_pa(f, mean_m=mean)) for f in (0.5, 1.0, 2.0)]
    print("pressure the paper's model needs along x_d: " + "; ".join(
        f"{f:g} Hz {p.min() / 1e6:.3f}-{p.max() / 1e6:.3f} MPa" for f, p in ranges)
        + f" (p_dz {Model(rig=Rig.control()).defaults['p_dz'] / 1e6:.3f} MPa, limit 0.9 MPa)")
    for name, result in results.items():
        path = args.out / f"figure5_{name}.png"
        plt.close(plot_figure5(result["run"], path=path))
        print(f"\n== {name} plant ({path}); gains {result['gains']}")
        print(f"{'f [Hz]':>6} {'ctrl':>4} {'RMS mm':>7} {'max mm':>7} {'amp':>6} "
              f"{'lag deg':>8} {'over %':>7} {'dead %':>7} {'sat %':>6} {'settle mm':>9}")
        for f, per in result["metrics"].items():
            for c, m in per.items():
                print(f"{f:6.2f} {c:>4} {1e3 * m['rms_error_m']:7.2f} "
                      f"{1e3 * m['max_error_m']:7.2f} {m['amplitude_ratio']:6.3f} "
                      f"{m['phase_lag_deg']:8.1f} {m['overshoot_pct']:7.1f} "
                      f"{100 * m['dead_zone_fraction']:7.1f} {100 * m['saturated_fraction']:6.1f} "
                      f"{1e3 * m['period_difference_m']:9.3f}")
        for claim in result["claims"]:
            verdict = "REPRODUCED" if claim["reproduced"] else "NOT reproduced"
            print(f"- {verdict}: {claim['claim']} ({claim['evidence']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
