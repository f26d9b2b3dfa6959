"""The paper's Fig. 5 redone (PID against computed torque at 0.5, 1, 2 Hz) with its claims.

The same two cases as ``analyses/figure5.py``, through the same API
(``pmabayes.control.reproduction.figure5`` and ``pmabayes.report.figures.plot_figure5``): the
controllers use the paper's base model and the gain rule's gains; the plant is that
model (``nominal``) or the model plus the 45 ms regulator lag and 0.8 N friction
hidden in ``data/pma_chirp_lab.csv`` (``lab``). The closed loops are cheap, so quick
and full mode are the same size.

Usage::

    python analyses/paper/paper_figure5.py [--out-root paper] [--quick]

Writes ``figures/fig5_nominal.png``, ``figures/fig5_lab.png``, ``tables/fig5.tex``
and ``tables/numbers_figure5.tex``; prints the last figure's path last.
"""

from __future__ import annotations

import inspect
import sys

from _paper import LAB_EFFECTS, Numbers, out_dirs, parser, sig

from pmabayes.control import (
    REFERENCE_AMPLITUDE_M,
    REFERENCE_MEAN_M,
    Timing,
    operating_mean_m,
    tune_gains,
)
from pmabayes.control.reproduction import figure5
from pmabayes.model.model import Model, Rig
from pmabayes.report.figures import plot_figure5, plt

CLAIM_NAMES = ("Better", "Phase", "Overshoot")


def main(argv: list[str] | None = None) -> int:
    """Run both cases, draw them, write the metrics table and the claims."""
    args = parser(__doc__).parse_args(argv)
    figures, tables = out_dirs(args.out_root)
    lab = Model(list(LAB_EFFECTS), rig=Rig.control())
    cases = {
        "nominal": {},
        "lab": {"plant_model": lab, "plant_params": {"tau_reg": LAB_EFFECTS["regulator_lag"],
                                                     "F_c": LAB_EFFECTS["coulomb_friction"]}},
    }
    nums = Numbers("figure5", args.quick)
    nums.add("pbFigFiveMeanMM", sig(REFERENCE_MEAN_M * 1e3, 3))
    # the loop's set-up and the rules' constants, from the code's defaults
    timing = Timing()
    rule = inspect.signature(tune_gains).parameters
    op = inspect.signature(operating_mean_m).parameters
    nums.add("pbCtlAmplitudeMM", sig(REFERENCE_AMPLITUDE_M * 1e3, 3))
    nums.add("pbCtlControllerHz", f"{1.0 / timing.controller_period_s:.0f}")
    nums.add("pbCtlCommandHz", f"{1.0 / timing.command_period_s:.0f}")
    nums.add("pbCtlPmaxMPa", sig(timing.pressure_max_pa / 1e6, 2))
    nums.add("pbCtlMarginKPa", f"{op['margin_pa'].default / 1e3:.0f}")
    nums.add("pbCtlRuleHz", sig(rule["frequency_hz"].default, 2))
    nums.add("pbCtlGainMargin", sig(rule["margin"].default, 2))
    nums.add("pbCtlDelayMs", f"{rule['delay_margin_s'].default * 1e3:.0f}")
    nums.add("pbCtlRMSFactor", sig(rule["rms_factor"].default, 2))
    body = []
    path = None
    for name, kw in cases.items():
        result = figure5(**kw)
        path = figures / f"fig5_{name}.png"
        plt.close(plot_figure5(result["run"], path=path))
        case = name.capitalize()
        for f, per in result["metrics"].items():
            fw = {0.5: "Half", 1.0: "One", 2.0: "Two"}[f]
            cells = []
            for c in ("pid", "ct"):
                m = per[c]
                cw = c.upper() if c == "pid" else "CT"
                cells += [f"{1e3 * m['rms_error_m']:.2f}", f"{m['phase_lag_deg']:.1f}",
                          f"{m['overshoot_pct']:.1f}", f"{100 * m['dead_zone_fraction']:.0f}"]
                nums.add(f"pb{case}{cw}{fw}RMS", f"{1e3 * m['rms_error_m']:.2f}")
                nums.add(f"pb{case}{cw}{fw}Lag", f"{m['phase_lag_deg']:.1f}")
                nums.add(f"pb{case}{cw}{fw}Over", f"{m['overshoot_pct']:.1f}")
            body.append(f"{name} & {f:g} & " + " & ".join(cells) + r" \\")
        nums.add(f"pb{case}ClaimsReproduced", sum(c["reproduced"] for c in result["claims"]))
        for cname, claim in zip(CLAIM_NAMES, result["claims"], strict=True):
            nums.add(f"pb{case}Claim{cname}",
                     "reproduced" if claim["reproduced"] else "not reproduced")
        g = result["gains"]
        nums.add(f"pb{case}GainsPID", ", ".join(f"${k.replace('k', 'K_')} = "
                                                f"{sig(v, 3)}$" for k, v in g["pid"].items()
                                                if k in ("kp", "ki", "kd")))
        print(f"{name}: gains {g}; claims " + "; ".join(
            f"{c['claim']}: {c['reproduced']}" for c in result["claims"]))
    table = [r"\begin{tabular}{lrrrrrrrrr}", r"\toprule",
             r" & & \multicolumn{4}{c}{PID} & \multicolumn{4}{c}{computed torque} \\",
             r"\cmidrule(lr){3-6}\cmidrule(lr){7-10}",
             r"plant & $f$ [Hz] & RMS & lag & over. & dead & RMS & lag & over. & dead \\",
             r" & & [mm] & [$^\circ$] & [\%] & [\%] & [mm] & [$^\circ$] & [\%] & [\%] \\",
             r"\midrule", *body, r"\bottomrule", r"\end{tabular}"]
    (tables / "fig5.tex").write_text("\n".join(table) + "\n")
    nums.write(tables)
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
