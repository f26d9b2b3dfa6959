"""The commands that fit: ``run`` (fit and report), ``fit``, ``batch``, and ``predict``
(the model on a data set's input, without fitting)."""

from __future__ import annotations

import argparse
import math
import time
import warnings
from pathlib import Path

from pmabayes.cli.ending import _finish, _floor_text, _nan, _print_adequacy, _um
from pmabayes.cli.inputs import _fit_settings, _load_all, _model_for, _say
from pmabayes.cli.options import (
    _DATA_HELP,
    _DATA_KINDS,
    _FOLDER_HELP,
    CliError,
    _check_effects,
    _effect_list,
    _fit_options,
    _parse_assignments,
    _positive,
    _sampler_options,
)
from pmabayes.cli.report import _write_report
from pmabayes.outputs import (
    check_chains,
    check_file,
    check_fits_folder,
    check_folder,
    created,
    write_json,
)

__all__: list[str] = []


def _cmd_predict(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    out = check_folder(args.out, "predict", inputs=[args.data])
    dataset = _load_all(args, "--effects")[0]
    import numpy as np

    from pmabayes.criticism.bands import band_errors, band_label
    from pmabayes.model.model import Model
    from pmabayes.model.simulator import simulate_dataset
    from pmabayes.report.figures import plot_comparison

    model = Model.for_dataset(dataset, args.effects)
    params = _parse_assignments(args.param, "--param")
    x = simulate_dataset(model, params, dataset)[0]
    resid = dataset.mean_position_m - x
    floor = dataset.noise_floor_m
    summary = {
        "data": str(args.data),
        "synthetic": bool(dataset.metadata.get("synthetic", False)),
        "n_trials": dataset.n_trials,
        "n_samples": dataset.n_samples,
        "effects": list(model.effect_names),
        "parameters": {k: float(v) for k, v in {**model.defaults, **params}.items()},
        "rms_m": float(np.sqrt(np.mean(resid**2))),
        "max_error_m": float(np.max(np.abs(resid))),
        "noise_floor_m": None if math.isnan(floor) else floor,  # JSON has no NaN
        "bands": [b.to_dict() for b in band_errors(dataset, x)],
    }
    floor_text = ("no noise floor: one trial, repeat the trial to estimate it"
                  if math.isnan(floor) else f"noise floor {floor * 1e6:.1f} µm")
    print(f"data: {args.data} ({dataset.n_trials} trials x {dataset.n_samples} samples"
          f"{', synthetic' if summary['synthetic'] else ''})")
    print(f"model: base{' + ' + ' + '.join(model.effect_names) if model.effect_names else ''}")
    print(f"RMS error of the trial mean: {summary['rms_m'] * 1e6:.1f} µm "
          f"({floor_text}, max error {summary['max_error_m'] * 1e6:.1f} µm)")
    for b in summary["bands"][:-1]:
        print(f"  {band_label(tuple(b['band_hz'][:1]) + (b['band_hz'][1] or math.inf,)):>12s}: "
              f"RMS {b['rms_m'] * 1e6:.1f} µm = {b['nrms']:.3g} of the motion"
              + (f", {b['ratio']:.3g}x the floor" if b["ratio"] is not None else ""))

    def page(folder: Path) -> None:
        plot_comparison(dataset, x, label="model (paper values)" if not params else "model",
                        path=folder / "comparison.png")
        write_json(folder / "summary.json", summary, "predict")

    return _finish("predict", out=out, page=page, start=start)


def _do_fit(args: argparse.Namespace, datasets: list, model, out: Path):
    from pmabayes.inference.errors import ConvergenceWarning
    from pmabayes.inference.fitfile import fit_info, save_fit
    from pmabayes.inference.sampler import fit
    from pmabayes.model.model import Rig

    chains = out.with_name(out.name + ".chains")
    args.interrupted = lambda: (
        f"chains saved in {chains}; run the same command again to resume"
        if chains.is_dir() and any(chains.glob("*.h5")) else
        "before the first chains were saved (during the MAP); nothing to resume")
    with warnings.catch_warnings():  # the banner below says it once
        warnings.simplefilter("ignore", ConvergenceWarning)
        tree = fit(datasets if len(datasets) > 1 else datasets[0], model, seed=args.seed,
                   settings=_fit_settings(args), chains_dir=chains, restart=args.restart)
    save_fit(tree, out)
    info = fit_info(tree)
    conv = info["convergence"]
    data_text = " ".join(str(d) for d in args.data)
    print(f"fit: {data_text} with {' + '.join(['base', *model.effect_names])}: "
          f"MAP RMS cost {_um(info['map']['rms_cost_m'], _nan(info['data']))[0]} µm "
          + (f"({_floor_text(info['data']['noise_floor_m'], info['map']['rms_cost_m'])}); "
             if len(datasets) == 1
             else f"(combined over {len(datasets)} experiments); ")
          + f"{conv['n_steps']} steps x {conv['n_ensembles']} ensembles x "
          f"{conv['n_walkers']} walkers in {info['timings_s']['total']:.1f} s")
    choice = info.get("substeps_choice") or {}
    if choice.get("requested") == "auto":
        print(f"substeps: {choice['chosen']} (auto: {choice['rule']})")
    scaled = info.get("data_scaled_priors")
    if scaled:
        print(f"priors on the data's scale (static compliance "
              f"{scaled['compliance_m_per_n']:.3g} m/N, amplitude {scaled['amplitude_m']:.3g} m): "
              + ", ".join(f"{n} ~ {p}" for n, p in scaled["priors"].items()))
    if len(datasets) > 1:
        for exp in info["experiments"]:
            print(f"  experiment {exp['name']} ({exp['source']}): {exp['n_trials']} trial(s) x "
                  f"{exp['n_samples']} samples on the {Rig.from_dict(exp['rig']).name} rig, "
                  f"RMS cost {_um(exp['rms_cost_m'], _nan(exp))[0]} µm "
                  f"({_floor_text(exp['noise_floor_m'], exp['rms_cost_m'])}), noise "
                  f"{exp['noise']} "
                  f"from the {exp['noise_source']}")
    if not conv["converged"]:
        print("!" * 78 + "\nNOT CONVERGED: " + "; ".join(conv["messages"])
              + "\nThe fit is saved anyway; rerun the same command with more --steps to "
              "continue the chains.\n" + "!" * 78)
    for exp in info["experiments"]:
        for line in _likelihood_lines(exp):
            print(f"  {exp['name']}: {line}")
    _print_adequacy(tree, datasets)
    print(f"wrote {out} (chains in {chains})")
    return tree


def _likelihood_lines(exp: dict) -> list[str]:
    """What an experiment's likelihood took beyond complete, shared, known-start trials
    (the fit file's record, :mod:`pmabayes.inference.fitfile`)."""
    lines = []
    gaps = exp.get("missing_samples")
    if gaps:
        lines.append(f"{gaps['left_out_of_likelihood']} samples missing in the likelihood "
                     f"({gaps['not_observed']} not observed"
                     + (f", a warm-up of {gaps['warmup_s']:g} s" if gaps["warmup_s"] else "")
                     + "): the Kalman filter predicts across them")
    if exp.get("own_inputs"):
        raw = exp.get("noise_floor_of_raw_trials_m")
        lines.append("trials with their own inputs, each simulated on its own; noise and "
                     "noise floor from the trials' residuals at the MAP (the model's response "
                     "to the inputs' differences cancels)"
                     + (f"; the raw trials' spread makes {raw * 1e6:.1f} µm" if raw else ""))
    start = exp.get("start")
    if start:
        lines.append("start estimated: " + ", ".join(
            f"{n} prior {p['prior']}" for n, p in start["parameters"].items()))
    return lines


def _cmd_fit(args: argparse.Namespace) -> int:
    out = check_file(args.out, "fit", "--out", inputs=args.data)
    check_chains(out)
    datasets = _load_all(args, "--effects")
    model = _model_for(datasets[0], args)
    out.parent.mkdir(parents=True, exist_ok=True)
    _do_fit(args, datasets, model, out)
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    out = check_folder(args.out, "run", inputs=args.data)
    check_chains(out / "fit.nc")
    datasets = _load_all(args, "--effects")  # read and checked before anything is made
    model = _model_for(datasets[0], args)
    with created(out, "run"):
        tree = _do_fit(args, datasets, model, out / "fit.nc")
    args.interrupted = lambda: (f"the fit is saved in {out / 'fit.nc'}; the report was not "
                                "written: run `pmabayes report` on the fit, or this command "
                                "again")
    _write_report(tree, out, datasets, "run")
    print(f"({time.perf_counter() - start:.1f} s in all)")
    return 0


def _batch_out(args: argparse.Namespace) -> Path:
    """The batch's folder and every fit it will write, checked before any work."""
    if Path(args.out).is_file():  # refused before the import below, which takes a moment
        check_fits_folder(args.out, {})
    _say().say(f"a batch of {len(args.data)} data set(s), each fitted into {args.out}")
    from pmabayes.inference.batch import BatchJob

    return check_fits_folder(args.out, {f"{BatchJob(d).resolved_name()}.nc": d
                                        for d in args.data})


#: options of ``fit`` that a batch does not take, and why (hidden from its --help)
_NOT_IN_BATCH = {
    "tie_noise": "--tie-noise: each data set of a batch is fitted alone, as one experiment; "
                 "to fit experiments together use `pmabayes fit A B ...`",
    "exclude_trials": "--exclude-trials: trial ids belong to one data file; leave the trials "
                      "out of that file first, or fit it alone with `pmabayes fit`",
    "noise_model": "--noise-model: a batch fits with the default 'auto'; fit the data set "
                   "alone with `pmabayes fit` to choose",
    "trials": "--trials: trial ids belong to one data file; fit it alone with `pmabayes fit`",
}


def _cmd_batch(args: argparse.Namespace) -> int:
    for name, why in _NOT_IN_BATCH.items():
        if getattr(args, f"refused_{name}") is not None:
            raise CliError(why)
    if args.processes is not None and args.dask is not None:
        raise CliError("give --processes or --dask, not both")
    out = _batch_out(args)
    js = check_file(args.json, "batch", "--json", args.data) if args.json else None
    _check_effects(args.effects, "--effects")
    from pmabayes.inference.batch import BatchError, BatchJob, fit_batch

    args.interrupted = lambda: (f"the fits finished so far are in {out}; run the same "
                                "command again to resume (finished fits are skipped)")
    effects = tuple(args.effects)
    try:
        fixed = _parse_assignments(args.fix, "--fix") or None
        result = fit_batch([BatchJob(d, effects, priors=dict(args.prior), fixed=fixed)
                            for d in args.data],
                           out_dir=out, settings=_fit_settings(args), seed=args.seed,
                           processes=args.processes, dask=args.dask, restart=args.restart)
    except BatchError as err:
        raise CliError(str(err)) from None
    summary = result.summary()
    for r in summary["datasets"]:
        if r["status"] == "failed":  # the package's errors name the file already
            where = "" if r["data"] in r["error"] else f" ({r['data']})"
            print(f"{r['name']}: FAILED{where}: {r['error']}")
            continue
        rms = r["map_rms_cost_m"]
        conv = "converged" if r["converged"] else "NOT CONVERGED"
        took = (f"{r['seconds']:.1f} s" if r["status"] == "fitted"
                else "skipped, up to date")
        print(f"{r['name']}: {r['fit_file']}: MAP RMS cost "
              f"{'n/a' if rms is None else f'{rms * 1e6:.1f} µm'}, {conv} "
              f"({r['n_steps']} steps), {took}")
    print(f"{summary['n_datasets']} data sets: {summary['n_fitted']} fitted, "
          f"{summary['n_skipped']} skipped, {summary['n_failed']} failed, "
          f"{summary['n_not_converged']} not converged; {summary['seconds']:.1f} s on "
          f"{summary['runner']}")
    return _finish("batch", summary=summary, js=js, ok=result.ok)


def _fit_commands(sub, common) -> None:
    """The ``run`` and ``fit`` subcommands."""
    run = sub.add_parser("run", parents=[common],
                         help="the main job: fit a data set and write the report",
                         epilog="example: pmabayes run data.csv --out results")
    run.add_argument("data", nargs="+", help=_DATA_HELP)
    run.add_argument("--out", required=True,
                     help="output folder (fit.nc and the report)" + _FOLDER_HELP)
    _fit_options(run)
    run.set_defaults(func=_cmd_run)

    fitp = sub.add_parser("fit", parents=[common],
                          help="identify the parameters: MAP and posterior",
                          epilog="example: pmabayes fit data.csv --out fit.nc")
    fitp.add_argument("data", nargs="+", help=_DATA_HELP)
    fitp.add_argument("--out", required=True,
                      help="the fit, a NetCDF file (FIT.nc); an existing one must be a "
                      "pmabayes fit (its chains are resumed)")
    _fit_options(fitp)
    fitp.set_defaults(func=_cmd_fit)


def _predict_commands(sub, common) -> None:
    """The ``predict`` subcommand: the model on a data set's input, without fitting."""
    pred = sub.add_parser("predict", parents=[common],
                          help="simulate the model on a data set's input and compare (no "
                          "fitting)")
    pred.add_argument("data", help=f"data file: {_DATA_KINDS}")
    pred.add_argument("--out", required=True, help="output folder" + _FOLDER_HELP)
    pred.add_argument("--effects", default=[], type=_effect_list,
                      help="comma-separated effects to add to the base model")
    pred.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                      help="set a parameter, of the base model or of an effect (repeatable)")
    pred.set_defaults(func=_cmd_predict)


def _batch_commands(sub, common) -> None:
    """The ``batch`` subcommand: many independent data sets, one fit each."""
    bat = sub.add_parser("batch", parents=[common],
                         help="fit many independent data sets, each alone, on local "
                         "processes or a Dask cluster")
    bat.add_argument("data", nargs="+", help=f"data files: {_DATA_KINDS}; each fit is "
                     "written to OUT/<file stem>.nc")
    bat.add_argument("--out", required=True, help="output folder of the fits; a fit already "
                     "there is resumed or skipped, any other file of that name is refused")
    _sampler_options(bat)
    bat.add_argument("--processes", type=_positive, default=None,
                     help="local worker processes, one data set each (all cores)")
    bat.add_argument("--dask", metavar="ADDRESS", default=None,
                     help="run on the Dask scheduler at ADDRESS (tcp://HOST:8786) instead; "
                     "needs `pip install pmabayes[dask]`")
    bat.add_argument("--json", help="write the batch's summary here")
    for name in _NOT_IN_BATCH:  # refused with the reason, and not offered
        bat.add_argument(f"--{name.replace('_', '-')}", nargs="?", const=True, default=None,
                         dest=f"refused_{name}", help=argparse.SUPPRESS)
    bat.set_defaults(func=_cmd_batch)
