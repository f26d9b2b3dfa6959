"""The commands of data and the library: ``read`` (a data file as pmabayes reads it),
``simulate`` (a synthetic data set) and ``effects`` (the registered effects and their
parameters)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from pmabayes.cli.inputs import _say, _segments
from pmabayes.cli.options import (
    _DATA_KINDS,
    CliError,
    _check_effects,
    _effect_list,
    _parse_assignments,
    _seed,
)
from pmabayes.outputs import check_file

__all__: list[str] = []


#: the old spelling of hidden effects in ``simulate``
_OLD_EFFECT = ("--effect NAME=VALUE is gone: name the effects with --effects NAME,NAME and "
               "set any parameter (the effects' too) with --param PARAM=VALUE")


def _simulate_effects(args: argparse.Namespace) -> tuple[dict, dict]:
    """``--effects`` and ``--param`` as the generator takes them: the base parameters, and
    each effect's parameters (the defaults where ``--param`` gives none)."""
    from pmabayes.model.effects import get_effect
    from pmabayes.model.model import BASE_PARAMETERS

    if args.effect:
        first = args.effect[0].partition("=")[0].partition(".")[0] or "NAME"
        raise CliError(f"{_OLD_EFFECT}, e.g. --effects {first} --param PARAM=VALUE "
                       "(`pmabayes effects` lists each effect's parameters)")
    _check_effects(args.effects, "--effects")
    owner = {p.name: "base" for p in BASE_PARAMETERS}
    effects: dict[str, dict[str, float]] = {}
    for name in args.effects:
        effects[name] = {}
        owner.update({p.name: name for p in get_effect(name).parameters})
    params: dict[str, float] = {}
    for name, value in _parse_assignments(args.param, "--param").items():
        if name not in owner:
            from pmabayes.model.effects import registered_effects

            hosts = [e for e, cls in registered_effects().items()
                     if name in cls.parameter_names()]
            hint = (f"it is a parameter of {', '.join(hosts)}: add --effects {hosts[0]}"
                    if hosts else "`pmabayes effects` lists every parameter")
            raise CliError(f"--param {name}: not a parameter of the base model or of the "
                           f"--effects given; {hint}")
        if owner[name] == "base":
            params[name] = value
        else:
            effects[owner[name]][name] = value
    return params, effects


def _cmd_simulate(args: argparse.Namespace) -> int:
    out = check_file(args.out, "data", "OUT")
    _say().say(f"simulating {args.trials} trials of a {args.duration:g} s chirp")
    params, effects = _simulate_effects(args)
    from pmabayes.data import save
    from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

    noise = None if args.noise == "none" else MeasurementNoise()
    chirp = Chirp(duration_s=args.duration, sample_rate_hz=args.rate)
    dataset = generate_chirp_dataset(
        n_trials=args.trials, seed=args.seed, chirp=chirp, noise=noise, params=params,
        effects=effects, description=args.description,
    )
    out.parent.mkdir(parents=True, exist_ok=True)  # like --json elsewhere
    save(dataset, out)
    values = dataset.metadata["generator"]["parameters"]
    hidden = "; ".join(
        f"{name} ({', '.join(f'{p}={values[p]:g}' for p in _effect_parameters(name))})"
        for name in effects) or "none"
    sidecar = out.with_suffix(".json") if out.suffix.lower() == ".csv" else None
    print(f"wrote {out}{f' and {sidecar}' if sidecar else ''}: {dataset.n_trials} trials x "
          f"{dataset.n_samples} samples, noise {args.noise}, hidden effects: {hidden} "
          "(synthetic)")
    return 0


def _cmd_read(args: argparse.Namespace) -> int:
    out = check_file(args.out, "data", "--out") if args.out else None
    from pmabayes.data import describe, save

    datasets = []
    for path in args.data:
        _say().say(f"reading {path}")
        for ds in _segments(path):
            print(describe(ds))
            datasets.append(ds)
    if out is not None:
        if len(datasets) > 1:
            raise CliError(f"--out writes one data set, but {len(datasets)} were read (files "
                           "or segments); read one file, or write each segment in Python "
                           "(pmabayes.data.load_segments, then pmabayes.data.save)")
        from pmabayes import __version__

        ds = dataclasses.replace(datasets[0], metadata={
            **datasets[0].metadata,
            "written_by": f"pmabayes read {__version__}, from {datasets[0].source}"})
        out.parent.mkdir(parents=True, exist_ok=True)
        save(ds, out)
        print(f"wrote {out}: the data set in pmabayes' own format (SI columns, the "
              "sidecar's declarations kept)")
    first = args.out or args.data[0]
    print(f"next: pmabayes fit {first} --out results/{Path(first).stem}/fit.nc")
    return 0


def _effect_parameters(name: str) -> list[str]:
    from pmabayes.model.effects import get_effect

    return [p.name for p in get_effect(name).parameters]


def _cmd_effects(args: argparse.Namespace) -> int:
    _say().say("reading the registry of effects")
    from pmabayes.model.effects import registered_effects
    from pmabayes.model.model import BASE_PARAMETERS

    groups = [("base model (p_dz only with a pressure input)", BASE_PARAMETERS)]
    groups += [(f"{name} [{eff.stage}]", eff.parameters)
               for name, eff in sorted(registered_effects().items())]
    for title, parameters in groups:
        print(title)
        for p in parameters:
            fixed = " (fixed by default)" if not p.vary else ""
            print(f"    {p.name} [{p.unit}] default {p.default:g}, prior {p.prior}{fixed}: "
                  f"{p.description}")
    print("A force-input rig's alpha, beta, gamma, d, K_e and noise take priors on its data's "
          "scale instead (the fit file's data_scaled_priors; e.g. alpha, K_e ~ LogNormal(half "
          "the inverse static compliance, 2)). A sidecar's rig may give moving_mass_kg or "
          "area_m2 as a prior (identified as rig_moving_mass_kg, rig_area_m2).")
    return 0


def _data_commands(sub, common) -> None:
    read = sub.add_parser("read", parents=[common],
                          help="read data files as pmabayes reads them and say what they "
                          "hold (grid, gaps, units converted, ranges, rig), before a fit",
                          epilog="example: pmabayes read lab/muscle_b.csv")
    read.add_argument("data", nargs="+", help=f"data files: {_DATA_KINDS}")
    read.add_argument("--out", help="write the one data set read in pmabayes' own format "
                      "(.csv with a .json sidecar, or .nc); an existing file must be one "
                      "pmabayes wrote")
    read.set_defaults(func=_cmd_read)

    simu = sub.add_parser("simulate", parents=[common],
                          help="write a synthetic repeated-chirp data set",
                          epilog="example: pmabayes simulate lagged.csv --effects "
                          "regulator_lag --param tau_reg=0.03")
    simu.add_argument("out", help="output file (.csv with a .json sidecar, or .nc); its "
                      "folder is created if missing; an existing one must be a data set "
                      "`pmabayes simulate` wrote")
    simu.add_argument("--trials", type=int, default=10, help="number of trials (10)")
    simu.add_argument("--seed", type=_seed, default=0, help="seed of the noise (0)")
    simu.add_argument("--noise", choices=("default", "none"), default="default",
                      help="'none' writes the exact model output")
    simu.add_argument("--effects", default=[], type=_effect_list,
                      help="comma-separated hidden effects, at their defaults unless "
                      "--param sets their parameters")
    simu.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                      help="set a parameter, of the base model or of an effect in --effects "
                      "(repeatable); paper values and effect defaults otherwise")
    simu.add_argument("--effect", action="append", default=[], help=argparse.SUPPRESS)
    simu.add_argument("--duration", type=float, default=15.0, help="chirp length in s (15)")
    simu.add_argument("--rate", type=float, default=1000.0, help="sample rate in Hz (1000)")
    simu.add_argument("--description", default="", help="text stored in the JSON sidecar")
    simu.set_defaults(func=_cmd_simulate)

    eff = sub.add_parser("effects", parents=[common],
                         help="list the registered physical effects")
    eff.set_defaults(func=_cmd_effects)
