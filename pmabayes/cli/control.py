"""The closed-loop commands: ``track`` (the paper's sinusoid by PID and computed torque)
and ``robustness`` (posterior samples through both controllers)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pmabayes.cli.ending import _finish
from pmabayes.cli.inputs import _read_fit, _say
from pmabayes.cli.options import _FOLDER_HELP, CONTROLLERS, MODES, _positive, _seed
from pmabayes.outputs import check_file, check_folder

__all__: list[str] = []


def _cmd_track(args: argparse.Namespace) -> int:
    js = check_file(args.json, "track", "--json", [args.fit] if args.fit else []) \
        if args.json else None
    tree = _read_fit(args.fit) if args.fit else None
    _say().say(f"tracking {args.freq:g} Hz by {args.controller or 'PID and computed torque'}")
    from pmabayes.control import track
    from pmabayes.control.robustness import control_model_from_fit, posterior_mean

    model, params, source = None, None, "the paper's values"
    if tree is not None:
        model = control_model_from_fit(tree)
        params = posterior_mean(tree, model)
        source = f"the posterior mean of {args.fit} (gains tuned on it by the rule)"
    controllers = CONTROLLERS if args.controller is None else (args.controller,)
    result = track(args.freq, controllers=controllers, model=model, params=params,
                   duration_s=args.duration)
    print(f"tracking {args.freq:g} Hz on the control rig (500 g load), model: {source}; "
          f"reference mean {1e3 * result['reference_mean_m']:.1f} mm "
          "(control.operating_mean_m on it)")
    for name, m in result["controllers"].items():
        print(f"  {name:>3}: RMS error {1e3 * m['rms_error_m']:.3f} mm, max "
              f"{1e3 * m['max_error_m']:.3f} mm, amplitude ratio {m['amplitude_ratio']:.3f}, "
              f"phase lag {m['phase_lag_deg']:.1f} deg, overshoot {m['overshoot_pct']:.1f}%, "
              f"in the dead zone {100 * m['dead_zone_fraction']:.0f}% of the time, last two "
              f"periods {1e3 * m['period_difference_m']:.3f} mm apart; gains "
              f"{result['gains'][name]}")
    return _finish("track", summary=result, js=js)


def _cmd_robustness(args: argparse.Namespace) -> int:
    out = check_folder(args.out, "robustness", inputs=[args.fit])
    _say().say(f"robustness of PID and computed torque over {args.samples} posterior samples of "
               f"{args.fit}")
    from pmabayes.control.robustness import robustness_sweep, summarise_robustness, write_robustness
    from pmabayes.report.figures import plot_robustness, plt

    ds = robustness_sweep(args.fit, samples=args.samples, frequencies_hz=args.freqs,
                          mode=args.mode, seed=args.seed, duration_s=args.duration,
                          processes=args.processes)
    summary = summarise_robustness(ds)
    print(f"{ds.sizes['sample']} samples, mode {args.mode}, in {ds.attrs['sweep_seconds']:.1f} s "
          f"on {ds.attrs['runner']}")
    for f in summary["frequency"].values:
        med = summary["rms_error_m_median"].sel(frequency=f)
        print(f"  {f:6.3f} Hz: median RMS error PID {1e3 * float(med.sel(controller='pid')):.3f}"
              f" mm, CT {1e3 * float(med.sel(controller='ct')):.3f} mm; P(CT beats PID) "
              f"{float(summary['p_ct_beats_pid'].sel(frequency=f)):.3f} (MC error "
              f"{float(summary['p_ct_beats_pid_mc_error'].sel(frequency=f)):.3f})")
    print(f"gains ({ds.attrs['gains_source']}): {ds.attrs['gains']}")
    print(f"reference mean {1e3 * ds.attrs['reference_mean_m']:.1f} mm "
          f"({ds.attrs['reference_mean_source']})")

    def page(folder: Path) -> None:
        write_robustness(ds, folder)
        plt.close(plot_robustness(ds, path=folder / "robustness.png"))

    return _finish("robustness", out=out, page=page)


def _control_commands(sub, common) -> None:
    """The closed-loop subcommands (``track``, ``robustness``)."""
    tr = sub.add_parser("track", parents=[common],
                        help="closed-loop tracking of the paper's sinusoid by PID and "
                        "computed torque")
    tr.add_argument("--freq", type=float, required=True, help="reference frequency in Hz")
    tr.add_argument("--controller", help="pid or ct (both by default)")
    tr.add_argument("--fit", help="a fit: use its posterior mean (the paper's values by "
                    "default)")
    tr.add_argument("--duration", type=float, default=10.0, help="run length in s (10)")
    tr.add_argument("--json", help="write the metrics to this JSON file")
    tr.set_defaults(func=_cmd_track)

    rob = sub.add_parser("robustness", parents=[common],
                         help="posterior samples through both controllers across tracking "
                         "frequencies")
    rob.add_argument("fit", help="a fit written by `pmabayes fit`")
    rob.add_argument("--out", required=True, help="output folder" + _FOLDER_HELP)
    rob.add_argument("--samples", type=_positive, default=500,
                     help="posterior samples (500)")
    rob.add_argument("--freqs", type=float, nargs="+", metavar="F",
                     help="frequencies in Hz (8 from 0.25 to 3, geometric, by default)")
    rob.add_argument("--mode", choices=MODES, default="plant",
                     help="plant (plant drawn, controller nominal; default) or model "
                     "(controller's model drawn, plant nominal)")
    rob.add_argument("--seed", type=_seed, default=0, help="chooses the samples (0)")
    rob.add_argument("--duration", type=float, default=10.0, help="run length in s (10)")
    rob.add_argument("--processes", type=_positive, help="local worker processes (all cores)")
    rob.set_defaults(func=_cmd_robustness)


# ---------------------------------------------------------------------------------
# running a command
