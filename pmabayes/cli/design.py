"""The command that plans: ``design`` (the next experiment that tells candidate effects
apart, or that shrinks chosen parameters' intervals)."""

from __future__ import annotations

import argparse
import time

from pmabayes.cli.ending import _finish
from pmabayes.cli.inputs import _load_all, _say
from pmabayes.cli.options import (
    _FOLDER_HELP,
    CliError,
    _effect_list,
    _noise_model_option,
    _positive,
    _seed,
    _substeps,
)
from pmabayes.outputs import check_folder

__all__: list[str] = []


def _numbers(text: str) -> list[float]:
    """argparse type of a comma-separated list of numbers."""
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give numbers separated by commas "
                                         "(e.g. 0,0.5)") from None


def _input_range_si(values: list[float] | None, dataset) -> tuple[float, float] | None:
    """``--input-range`` in SI: given in the units of the first data file's input column."""
    if values is None:
        return None
    if len(values) != 2:
        raise CliError(f"--input-range takes two numbers LO,HI, got {len(values)}")
    import numpy as np

    from pmabayes.data.units import to_si

    record = dataset.metadata.get("converted_units") or {}
    column = record.get(dataset.input_name, {}).get("from", dataset.input_name)
    low, high = (float(v) for v in to_si(np.array(values), column))
    return low, high


def _cmd_design(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    out = check_folder(args.out, "design", inputs=[*args.data, *args.fit])
    if args.goal == "parameters" and not args.parameters:
        raise CliError("--goal parameters needs --parameters a,b (the parameters whose "
                       "intervals should shrink)")
    datasets = _load_all(args, "--effects", "--candidates")
    from pmabayes.design import design
    from pmabayes.report.design_page import write_design

    fits = None
    if args.fit:
        from pmabayes.design.api import given_fits
        from pmabayes.design.fits import fit_from_file

        fits = given_fits([fit_from_file(p, datasets, noise_model=args.noise_model)
                           for p in args.fit], args.effects, args.candidates, args.goal)
    _say().say("designing the next experiment")
    result = design(datasets, args.effects, args.candidates, goal=args.goal, fits=fits,
                    parameters=args.parameters or None, loads=args.loads,
                    duration_s=args.duration,
                    input_range=_input_range_si(args.input_range, datasets[0]),
                    n_experiments=args.experiments, n_draws=args.draws, seed=args.seed,
                    noise_model=args.noise_model, substeps=args.substeps)
    for line in result.lines():
        print(line)
    return _finish("design", out=out, start=start, page=lambda folder: write_design(result,
                                                                                     folder))


def _design_commands(sub, common) -> None:
    """The ``design`` subcommand."""
    des = sub.add_parser(
        "design", parents=[common],
        help="the next experiment that tells candidate effects apart (or shrinks chosen "
        "parameters' intervals)",
        epilog="example: pmabayes design first.csv --candidates regulator_lag,transport_delay "
        "--input-range 0,500000 --out next")
    des.add_argument("data", nargs="+", help="the data so far, one file per experiment; the "
                     "next experiment runs on the first one's rig, rate and trials")
    des.add_argument("--effects", default=[], type=_effect_list,
                     help="comma-separated effects of the base model, shared by every "
                     "candidate")
    des.add_argument("--candidates", default=[], type=_effect_list,
                     help="comma-separated candidate effects: at least two to tell apart; "
                     "with --goal parameters, added to the model together")
    des.add_argument("--out", required=True,
                     help="folder for next.csv, next.json, design.json and the page"
                     + _FOLDER_HELP)
    des.add_argument("--fit", action="append", default=[], metavar="FIT.nc",
                     help="a candidate model's fit of these data by `pmabayes fit` (its MCMC "
                     "draws are used instead of a MAP fit; repeatable, one per candidate)")
    des.add_argument("--goal", choices=("discriminate", "parameters"), default="discriminate",
                     help="tell the candidates apart (the default), or shrink --parameters' "
                     "intervals")
    des.add_argument("--parameters", default=[], type=_effect_list,
                     help="with --goal parameters: comma-separated parameters")
    des.add_argument("--input-range", type=_numbers, default=None, metavar="LO,HI",
                     help="the rig's safe input range, in the units of the first data "
                     "file's input column; inside the sidecar's \"input_range\" (SI) where "
                     "it declares one, which is taken where this is not given (one of them "
                     "is required: pmabayes never guesses it)")
    des.add_argument("--duration", type=float, default=None, metavar="S",
                     help="the experiment's length in s (default: the first data set's)")
    des.add_argument("--loads", type=_numbers, default=None, metavar="KG,KG",
                     help="dead loads in kg the lab can hang for the next experiment (0: "
                     "none), each in place of the first file's own, which its sidecar must "
                     "declare (\"conditions\": {\"load_kg\": 0.1}); default: the first "
                     "file's rig as it is")
    des.add_argument("--experiments", type=_positive, default=50,
                     help="candidate experiments scored (50)")
    des.add_argument("--draws", type=_positive, default=32,
                     help="posterior draws per model for the truths, and as many for its "
                     "predictive density (32)")
    des.add_argument("--seed", type=_seed, default=0, help="seed of everything random (0)")
    des.add_argument("--substeps", type=_substeps, default="auto",
                     help="simulator steps per sample interval, or 'auto' (as for fit)")
    _noise_model_option(des)
    des.set_defaults(func=_cmd_design)
