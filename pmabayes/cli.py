"""Command-line interface: a thin layer over the Python API.

``pmabayes run DATA.csv --out DIR``
    The main job: fit the data (MAP and posterior) and write the report.
``pmabayes fit DATA.csv --out FIT.nc``
    Identify the parameters; chains are kept beside the fit and resumed.
``pmabayes batch A.csv B.csv ... --out DIR [--processes N | --dask ADDRESS]``
    Fit many independent data sets, each alone, to ``DIR/<stem>.nc``; one progress
    bar, failures reported per file, resumable.
``pmabayes report FIT.nc --out DIR``
    Summary tables (CSV, Markdown), diagnostics and figures in an HTML page.
``pmabayes predict DATA.csv --out DIR``
    Simulate the model (paper values or ``--param``) on the data's input and
    compare, without fitting.
``pmabayes simulate OUT.csv``
    Write a synthetic repeated-chirp data set from the paper's parameters.
``pmabayes diagnose DATA.csv [DATA2.csv ...] [--effects A,B] [--out DIR] [--json OUT.json]``
    Fit a model (MAP), compare it with the measurements against the noise floor,
    show where it fails and rank the library's effects by the evidence that they
    are missing; the best candidates are refitted and compared by ELPD. Several
    files are experiments diagnosed together, each on its own rig.
``pmabayes compare FIT_A.nc FIT_B.nc ... --data DATA.csv [DATA2.csv ...] --out DIR``
    Fits of the same data side by side: error per band against the floor,
    whiteness tests and leave-one-trial-out ELPD; the error-falling figure. Fits
    of several experiments take one data file per experiment.
``pmabayes effects``
    List the registered physical effects and their parameters.
``pmabayes track --freq F``
    Closed-loop tracking of the paper's sinusoid by PID and computed torque.
``pmabayes robustness FIT.nc --out DIR``
    Posterior samples through both controllers across tracking frequencies.
``pmabayes validate FIT.nc DATA.csv [DATA2.csv ...] [--json OUT.json] [--out DIR]``
    Predict held-out experiments with the fit's posterior, each on its own rig:
    error against the noise floor, NRMSE, error per band, predictive band coverage.

``--plugin FILE.py`` (before the command) imports a file that registers user
effects, so they work on the command line exactly like the built-in ones.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from pmabayes.control import ControlError
from pmabayes.data import DataError, Dataset, load, load_segments, save
from pmabayes.inference.errors import ConvergenceWarning, FitError
from pmabayes.inference.fitfile import (
    FitFileError,
    experiment_datasets,
    fit_info,
    load_fit,
    save_fit,
)
from pmabayes.inference.likelihood import LikelihoodError
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.inference.trials import check_trials, exclude_trials, parse_trial_ids
from pmabayes.model.effects import EffectError, get_effect, registered_effects
from pmabayes.model.model import BASE_PARAMETERS, Model, ModelError, Rig
from pmabayes.model.parameters import Prior, parse_prior
from pmabayes.model.simulator import SimulationError, simulate_dataset
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

__all__ = ["main", "load_plugin", "CliError"]


class CliError(ValueError):
    """A command-line argument is wrong; the message names it and the fix."""


# The package's own errors: wrong input, told in one line. Any other exception is a
# bug and keeps its traceback.
_USER_ERRORS = (DataError, ModelError, EffectError, SimulationError, LikelihoodError,
                FitError, FitFileError, ControlError, CliError)


def _parse_assignments(items: Sequence[str], what: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise CliError(f"{what} {item!r} must look like NAME=VALUE")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise CliError(f"{what} {item!r}: {value!r} is not a number") from None
    return out


def _seed(text: str) -> int:
    """argparse type of ``--seed``: numpy's generators take integers >= 0."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a seed: give an integer >= 0 (e.g. --seed 0)")
    return value


def _positive(text: str) -> int:
    """argparse type of a count that must be at least 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give an integer >= 1")
    return value


def _out_folder(path: str, option: str = "--out") -> Path:
    """An output folder's path, refused early (before any work) if it names a file."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise CliError(f"{option} {out}: this is a file, not a folder; give the name of a "
                       "folder (it is created if missing)")
    return out


@contextlib.contextmanager
def _created(out: Path) -> Iterator[Path]:
    """Create the folder ``out``; on failure remove it again if it is new and empty."""
    existed = out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        yield out
    except BaseException:
        if not existed and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise


def _write_json(path: str | Path, obj: object) -> None:
    """Write JSON, creating the file's folder if missing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=2) + "\n")


def _prior(text: str) -> tuple[str, Prior]:
    """argparse type of ``--prior NAME=SPEC``, e.g. ``alpha=LogNormal(5e4, 2)``."""
    name, sep, spec = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(
            f"{text!r} must look like NAME=SPEC, e.g. alpha='LogNormal(5e4, 2)'")
    try:
        return name.strip(), parse_prior(spec)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _model_for(dataset: Dataset, args: argparse.Namespace) -> Model:
    """The model of a fitting command: the data's rig, the effects and priors asked for."""
    return Model.for_dataset(dataset, args.effects, priors=dict(args.prior))


def _effect_list(text: str) -> list[str]:
    return [e.strip() for e in text.split(",") if e.strip()]


def _trial_ids(text: str) -> list[int]:
    try:
        return parse_trial_ids(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _exclude_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--exclude-trials", type=_trial_ids, default=[], metavar="ID,ID",
                   help="leave these trial ids out (e.g. 3,7: trials the check of the "
                   "trials names as drifting or outlying)")


def _segments(path: str) -> list[Dataset]:
    """A data file's segments (:func:`pmabayes.data.load_segments`), said when several."""
    segments = load_segments(path)
    if len(segments) > 1:
        print(f"{path} splits into {len(segments)} segments at gaps longer than its "
              f"max_gap_s = {segments[0].metadata['max_gap_s']:g} s: "
              + ", ".join(f"{Path(d.source).stem} ({d.n_samples} samples from "
                          f"{d.time_s[0]:.4g} s)" for d in segments)
              + "; each is an experiment of the same rig, from its own start")
    return segments


def _load_data(args: argparse.Namespace, path: str, *, min_trials: int = 1) -> list[Dataset]:
    """A data file's segments, without the trials ``--exclude-trials`` names (said, not
    silent)."""
    datasets = _segments(path)
    if args.exclude_trials:
        datasets = [exclude_trials(d, args.exclude_trials, min_trials=min_trials)
                    for d in datasets]
        print(f"excluded trials {','.join(map(str, args.exclude_trials))} of {path} "
              f"(--exclude-trials); {datasets[0].n_trials} remain")
    return datasets


def _load_all(args: argparse.Namespace) -> list[Dataset]:
    """The data files of a fit, a file that splits into segments as several experiments;
    ``--exclude-trials`` needs a single file (ids are per file)."""
    if args.exclude_trials and len(args.data) > 1:
        raise CliError(f"--exclude-trials names trial ids of one data file, but {len(args.data)} "
                       "were given; leave the trials out of that file first (pmabayes.inference.trials."
                       "exclude_trials, then pmabayes.data.save), or fit it alone")
    return [d for p in args.data for d in _load_data(args, p)]


def _not_yet_criticised(datasets: Sequence[Dataset]) -> str:
    """Why the model criticism cannot judge these data yet (empty when it can)."""
    gaps = [d for d in datasets if d.n_missing or d.warmup_s]
    own = [d for d in datasets if d.n_trials > 1 and not np.all(d.input == d.input[0])]
    return "; ".join(
        text for text, hit in ((f"{len(gaps)} data set(s) with samples not observed (gaps or "
                                "a warm-up)", gaps),
                               (f"{len(own)} data set(s) whose trials have their own inputs",
                                own)) if hit)


def _parse_effects(items: Sequence[str]) -> dict[str, dict[str, float]]:
    """``NAME=VALUE`` (first varying parameter) or ``NAME.PARAM=VALUE``."""
    effects: dict[str, dict[str, float]] = {}
    for key, value in _parse_assignments(items, "--effect").items():
        name, _, param = key.partition(".")
        eff = get_effect(name)
        if not param:
            param = next(p.name for p in eff.parameters if p.vary)
        effects.setdefault(name, {})[param] = value
    return effects


def load_plugin(spec: str) -> None:
    """Import a module or ``.py`` file that registers user effects.

    Parameters
    ----------
    spec : str
        A path to a Python file, or an importable module name.
    """
    if spec.endswith(".py"):
        path = Path(spec)
        if not path.is_file():
            raise CliError(f"--plugin {spec}: no such file; check the path")
        module_spec = importlib.util.spec_from_file_location(f"pmabayes_plugin_{path.stem}", path)
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[module_spec.name] = module
        module_spec.loader.exec_module(module)
    else:
        importlib.import_module(spec)


def _cmd_predict(args: argparse.Namespace) -> int:
    from pmabayes.criticism.residuals import band_errors, band_label
    from pmabayes.report.figures import plot_comparison  # matplotlib only where figures are made

    start = time.perf_counter()
    out = _out_folder(args.out)
    dataset = load(args.data)
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
    with _created(out):
        plot_comparison(dataset, x, label="model (paper values)" if not params else "model",
                        path=out / "comparison.png")
        _write_json(out / "summary.json", summary)
    floor_text = ("no noise floor: one trial, repeat the trial to estimate it"
                  if math.isnan(floor) else f"noise floor {floor * 1e6:.1f} um")
    print(f"data: {args.data} ({dataset.n_trials} trials x {dataset.n_samples} samples"
          f"{', synthetic' if summary['synthetic'] else ''})")
    print(f"model: base{' + ' + ' + '.join(model.effect_names) if model.effect_names else ''}")
    print(f"RMS error of the trial mean: {summary['rms_m'] * 1e6:.1f} um "
          f"({floor_text}, max error {summary['max_error_m'] * 1e6:.1f} um)")
    for b in summary["bands"][:-1]:
        print(f"  {band_label(tuple(b['band_hz'][:1]) + (b['band_hz'][1] or math.inf,)):>12s}: "
              f"RMS {b['rms_m'] * 1e6:.1f} um = {b['nrms']:.3g} of the motion"
              + (f", {b['ratio']:.3g}x the floor" if b["ratio"] is not None else ""))
    print(f"wrote {out / 'comparison.png'} and {out / 'summary.json'} "
          f"in {time.perf_counter() - start:.1f} s")
    return 0


def _fit_settings(args: argparse.Namespace) -> FitSettings:
    return FitSettings(n_walkers=args.walkers, n_ensembles=args.ensembles,
                       max_steps=args.steps, progress=not args.quiet, substeps=args.substeps,
                       tie_noise=getattr(args, "tie_noise", False),
                       noise_model=getattr(args, "noise_model", "auto"),
                       tie_segments=not getattr(args, "own_segment_noise", False))


def _floor_text(floor_m) -> str:
    return "no repeats" if floor_m is None else f"noise floor {floor_m * 1e6:.1f} um"


def _do_fit(args: argparse.Namespace, datasets: list[Dataset], model: Model, out: Path):
    chains = out.with_name(out.name + ".chains")
    with warnings.catch_warnings():  # the banner below says it once
        warnings.simplefilter("ignore", ConvergenceWarning)
        tree = fit(datasets if len(datasets) > 1 else datasets[0], model, seed=args.seed,
                   settings=_fit_settings(args), chains_dir=chains, restart=args.restart)
    save_fit(tree, out)
    info = fit_info(tree)
    conv = info["convergence"]
    data_text = " ".join(str(d) for d in args.data)
    print(f"fit: {data_text} with {' + '.join(['base', *model.effect_names])}: "
          f"MAP RMS cost {info['map']['rms_cost_m'] * 1e6:.1f} um "
          + (f"({_floor_text(info['data']['noise_floor_m'])}); " if len(datasets) == 1
             else f"(combined over {len(datasets)} experiments); ")
          + f"{conv['n_steps']} steps x {conv['n_ensembles']} ensembles x "
          f"{conv['n_walkers']} walkers in {info['timings_s']['total']:.1f} s")
    if len(datasets) > 1:
        for exp in info["experiments"]:
            print(f"  experiment {exp['name']} ({exp['source']}): {exp['n_trials']} trial(s) x "
                  f"{exp['n_samples']} samples on the {Rig.from_dict(exp['rig']).name} rig, "
                  f"RMS cost {exp['rms_cost_m'] * 1e6:.1f} um "
                  f"({_floor_text(exp['noise_floor_m'])}), noise {exp['noise']} "
                  f"from the {exp['noise_source']}")
    for exp in info["experiments"]:
        for line in _likelihood_lines(exp):
            print(f"  {exp['name']}: {line}")
    if not conv["converged"]:
        print("!" * 78 + "\nNOT CONVERGED: " + "; ".join(conv["messages"])
              + "\nThe fit is saved anyway; rerun the same command with more --steps to "
              "continue the chains.\n" + "!" * 78)
    from pmabayes.report.pages import experiment_adequacy  # the model's fit, not the sampler's

    pending = _not_yet_criticised(datasets)
    if pending:  # the model criticism's statistics take complete, shared-input trials
        print(f"the model's adequacy is not judged here: {pending} (the criticism of such "
              "data comes next)")
    else:
        for name, adequacy in experiment_adequacy(tree, datasets=datasets):
            prefix = f"[{name}] " if len(datasets) > 1 else ""
            print("\n".join(prefix + line for line in adequacy.lines()))
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
                     + (f"; the raw trials' spread makes {raw * 1e6:.1f} um" if raw else ""))
    start = exp.get("start")
    if start:
        lines.append("start estimated: " + ", ".join(
            f"{n} prior {p['prior']}" for n, p in start["parameters"].items()))
    return lines


def _cmd_fit(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.is_dir():
        raise CliError(f"--out {out}: this is a folder; give the name of the fit file "
                       "to write (e.g. fit.nc)")
    datasets = _load_all(args)
    model = _model_for(datasets[0], args)
    with _created(out.parent):
        _do_fit(args, datasets, model, out)
    return 0


def _report_datasets(tree, paths: Sequence[str] | None) -> list[Dataset] | None:
    """The data files given to ``report``, one per experiment of the fit, or None."""
    if not paths:
        return None
    n_exp = len(fit_info(tree).get("experiments") or [None])
    if len(paths) != n_exp:
        raise CliError(f"--data got {len(paths)} file(s) but the fit has {n_exp} "
                       "experiment(s); give one data file per experiment, in the fit's order")
    return [load(p) for p in paths]


def _cmd_report(args: argparse.Namespace) -> int:
    from pmabayes.report.pages import experiment_adequacy, write_report

    _out_folder(args.out)
    tree = load_fit(args.fit)
    datasets = _report_datasets(tree, args.data)
    pending = _not_yet_criticised(datasets or experiment_datasets(tree))
    if pending:
        raise CliError(f"report: {pending}; the report of such data (gaps shaded, each "
                       "trial's own input) comes next. The fit file holds the posterior: "
                       "read it with pmabayes.inference.fitfile.load_fit")
    index = write_report(tree, Path(args.out), dataset=datasets)
    for name, adequacy in experiment_adequacy(tree, datasets=datasets):
        prefix = f"[{name}] " if len(fit_info(tree).get("experiments") or [None]) > 1 else ""
        print("\n".join(prefix + line for line in adequacy.lines()))
    print(f"wrote the report {index}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from pmabayes.report.pages import write_report

    start = time.perf_counter()
    out = _out_folder(args.out)
    datasets = _load_all(args)  # read and checked before anything is made
    model = _model_for(datasets[0], args)
    with _created(out):
        tree = _do_fit(args, datasets, model, out / "fit.nc")
    pending = _not_yet_criticised(datasets)
    if pending:
        print(f"no report: {pending}; the report of such data (gaps shaded, each trial's own "
              f"input) comes next ({time.perf_counter() - start:.1f} s in all)")
        return 0
    index = write_report(tree, out, dataset=datasets)
    print(f"wrote the report {index} ({time.perf_counter() - start:.1f} s in all)")
    return 0


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from pmabayes.criticism.diagnosis import diagnose

    start = time.perf_counter()
    if args.out:
        _out_folder(args.out)
    datasets = _load_all(args)
    pending = "; ".join(filter(None, [
        _not_yet_criticised(datasets),
        (f"{sum(d.initial_state == 'estimate' for d in datasets)} data set(s) whose start "
         "is estimated (initial_state 'estimate')"
         if any(d.initial_state == "estimate" for d in datasets) else "")]))
    if pending:
        raise CliError(f"diagnose: {pending}; the criticism of such data comes next. Fit them "
                       "(pmabayes fit), or diagnose a stretch without gaps (a sidecar "
                       "\"max_gap_s\" below the shortest gap splits the record there)")
    for ds in datasets:  # the noise is learnt from their spread
        print(check_trials(ds).summary())
    model = _model_for(datasets[0], args)
    result = diagnose(datasets if len(datasets) > 1 else datasets[0], model,
                      candidates=args.candidates or None, seed=args.seed,
                      progress=not args.quiet, noise_model=args.noise_model,
                      plugin_dir=args.proposal_dir or args.out or Path.cwd())
    summary = result.to_dict()
    label = " + ".join(["base", *result.model.effect_names])
    print(f"model: {label}")
    for e in result.experiments:
        prefix = f"[{e.name}] " if len(result.experiments) > 1 else ""
        floor = (f"noise floor {e.noise_floor_m * 1e6:.1f} um" if np.isfinite(e.noise_floor_m)
                 else "no noise floor: a single record without repeats")
        print(f"{prefix}RMS error of the trial mean: {e.rms_m * 1e6:.1f} um ({floor}); "
              f"adequate: {'yes' if e.adequate else 'no'}")
    if len(result.experiments) > 1:
        print(f"adequate in every experiment: {'yes' if result.adequate else 'no'}")
    for f in result.ranking[:5]:
        est = ", ".join(f"{k}={v:.4g}" for k, v in f.estimate.items())
        print(f"  {f.effect:<22s} evidence {f.evidence:10.4g}  "
              f"{'significant' if f.significant else 'n.s.':<11s}  {est}")
    print(result.verdict)
    if args.json:
        _write_json(args.json, summary)
        print(f"wrote {args.json}")
    if args.out:
        from pmabayes.report.pages import write_diagnosis

        index = write_diagnosis(result, Path(args.out))
        print(f"wrote {index}")
    print(f"({time.perf_counter() - start:.1f} s)")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from pmabayes.criticism.diagnosis import compare_fits
    from pmabayes.report.pages import write_comparison

    labels = args.labels.split(",") if args.labels else None
    if len(args.fits) < 2 or (labels is not None and len(labels) != len(args.fits)):
        raise CliError(f"compare got {len(args.fits)} fit(s) and "
                       f"{'no' if labels is None else len(labels)} --labels; give two or more "
                       "fits of the same data, and one label per fit if any")
    _out_folder(args.out)
    fits = [load_fit(f) for f in args.fits]
    n_exp = [len(fit_info(t).get("experiments") or [None]) for t in fits]
    for path, n in zip(args.fits, n_exp, strict=True):
        if n != len(args.data):
            raise CliError(
                f"{path} is a fit of {n} experiment(s) but --data got {len(args.data)} file(s) "
                f"({', '.join(args.data)}); give the data file of each experiment the fits were "
                "made from, in the fit's order, and compare only fits of the same experiments")
    datasets = [load(p) for p in args.data]
    result = compare_fits(fits, datasets if len(datasets) > 1 else datasets[0], labels=labels,
                          sources=args.fits)
    parts = result.experiments or {"": result}
    for name, c in parts.items():
        for k in c.labels:
            b = c.bands[k][-1]
            ratio = f"{b.ratio:7.3g}x floor" if np.isfinite(b.floor_m) else "(no floor)"
            print(f"{f'[{name}] ' if name else ''}{k:<40s} RMS {b.rms_m * 1e6:9.1f} um = "
                  f"{ratio}  Ljung-Box p {c.whiteness[k]['ljung_box_p']:.2g}")
    for k in result.labels:
        print(f"{k:<40s} ELPD {result.elpd[k]['elpd']:.1f} (leave one trial out"
              f"{' of all experiments' if result.experiments else ''})")
    for step in result.elpd_steps:
        print(f"{step['from']} -> {step['to']}: ELPD {step['elpd_diff']:+.1f} "
              f"+- {step['se']:.1f}")
    index = write_comparison(result, Path(args.out), dataset=datasets)
    print(f"wrote {index}")
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    effects = _parse_effects(args.effect)
    params = _parse_assignments(args.param, "--param")
    noise = None if args.noise == "none" else MeasurementNoise()
    chirp = Chirp(duration_s=args.duration, sample_rate_hz=args.rate)
    dataset = generate_chirp_dataset(
        n_trials=args.trials, seed=args.seed, chirp=chirp, noise=noise, params=params,
        effects=effects, description=args.description,
    )
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)  # like --json elsewhere
    save(dataset, args.out)
    hidden = ", ".join(f"{k}={v}" for e in effects.values() for k, v in e.items()) or "none"
    print(f"wrote {args.out}: {dataset.n_trials} trials x {dataset.n_samples} samples, "
          f"noise {args.noise}, hidden effects: {hidden} (synthetic)")
    return 0


def _cmd_effects(args: argparse.Namespace) -> int:
    groups = [("base model (p_dz only with a pressure input)", BASE_PARAMETERS)]
    groups += [(f"{name} [{eff.stage}]", eff.parameters)
               for name, eff in sorted(registered_effects().items())]
    for title, parameters in groups:
        print(title)
        for p in parameters:
            fixed = " (fixed by default)" if not p.vary else ""
            print(f"    {p.name} [{p.unit}] default {p.default:g}, prior {p.prior}{fixed}: "
                  f"{p.description}")
    return 0


def _cmd_track(args: argparse.Namespace) -> int:
    from pmabayes.control import CONTROLLERS, track
    from pmabayes.control.robustness import control_model_from_fit, posterior_mean

    model, params, source = None, None, "the paper's values"
    if args.fit:
        tree = load_fit(args.fit)
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
    if args.json:
        _write_json(args.json, result)
        print(f"wrote {args.json}")
    return 0


def _cmd_robustness(args: argparse.Namespace) -> int:
    from pmabayes.control.robustness import robustness_sweep, summarise_robustness, write_robustness
    from pmabayes.report.figures import (  # matplotlib only where figures are made
        plot_robustness,
        plt,
    )

    _out_folder(args.out)
    ds = robustness_sweep(args.fit, samples=args.samples, frequencies_hz=args.freqs,
                          mode=args.mode, seed=args.seed, duration_s=args.duration,
                          processes=args.processes, progress=not args.quiet)
    paths = write_robustness(ds, args.out)
    paths["figure"] = Path(args.out) / "robustness.png"
    plt.close(plot_robustness(ds, path=paths["figure"]))
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
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    from pmabayes.criticism.validation import validate

    start = time.perf_counter()
    if args.out:
        _out_folder(args.out)
    # the fit as a path names it in the outputs; a data file that splits at its
    # sidecar's max_gap_s gives one held-out experiment per segment
    held_out = [d for p in args.data for d in _segments(p)]
    pending = _not_yet_criticised(held_out)
    if pending:
        raise CliError(f"validate: held-out {pending}; validation of such data comes next. "
                       "Validate a stretch without gaps (a sidecar \"max_gap_s\" below the "
                       "shortest gap splits the record there)")
    result = validate(args.fit, held_out, n_draws=args.draws, ci_prob=args.ci_prob,
                      seed=args.seed, noise_from=args.noise_from, substeps=args.substeps,
                      start_fraction=args.start_fraction)
    print(f"validate {args.fit} (model: {' + '.join(['base', *result.effects])}) on "
          f"{len(result.experiments)} held-out experiment(s), {args.draws} posterior draws "
          "each:")
    for line in result.lines():
        print(f"  {line}")
    if args.json:
        _write_json(args.json, result.to_dict())
        print(f"wrote {args.json}")
    if args.out:
        from pmabayes.report.pages import write_validation

        print(f"wrote {write_validation(result, Path(args.out))}")
    print(f"({time.perf_counter() - start:.1f} s)")
    return 0


def _probability(text: str) -> float:
    """argparse type of ``--ci-prob``: a probability strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: give a probability between 0 and 1 "
                                         "(e.g. 0.9)")
    return value


def _validation_commands(sub) -> None:
    """The ``validate`` subcommand: a fit's predictions of held-out experiments."""
    val = sub.add_parser("validate", help="predict held-out experiments with a fit's "
                         "posterior: error, noise floor, predictive band and its coverage")
    val.add_argument("fit", help="a fit written by `pmabayes fit`")
    val.add_argument("data", nargs="+", help="held-out data files (.csv with optional .json "
                     "sidecar, or .nc), one experiment each, each on the rig its sidecar gives")
    val.add_argument("--json", help="write the numbers and bands per experiment here")
    val.add_argument("--out", help="folder for the figures and an HTML page")
    val.add_argument("--draws", type=_positive, default=300,
                     help="posterior draws simulated per experiment (300)")
    val.add_argument("--ci-prob", type=_probability, default=0.9,
                     help="probability of the predictive band (0.9)")
    val.add_argument("--noise-from", metavar="NAME",
                     help="for a fit of several experiments: the fitted experiment whose "
                     "noise makes the band (default: the one on the held-out data's rig, "
                     "else all pooled)")
    val.add_argument("--seed", type=_seed, default=0,
                     help="seed of the draws' choice and the predictive noise (0)")
    val.add_argument("--substeps", type=_positive, default=None,
                     help="simulator steps per sample interval (default: as the fit used)")
    val.add_argument("--start-fraction", type=_probability, default=0.05,
                     help="for held-out data whose start is declared 'estimate': the first "
                     "part of the record (a fraction of it, 0.05) from which each posterior "
                     "draw's start is estimated by least squares")
    val.set_defaults(func=_cmd_validate)


def _control_commands(sub) -> None:
    """The closed-loop subcommands (``track``, ``robustness``)."""
    tr = sub.add_parser("track", help="closed-loop tracking of the paper's sinusoid by PID "
                        "and computed torque")
    tr.add_argument("--freq", type=float, required=True, help="reference frequency in Hz")
    tr.add_argument("--controller", help="pid or ct (both by default)")
    tr.add_argument("--fit", help="a fit: use its posterior mean (the paper's values by "
                    "default)")
    tr.add_argument("--duration", type=float, default=10.0, help="run length in s (10)")
    tr.add_argument("--json", help="write the metrics to this JSON file")
    tr.set_defaults(func=_cmd_track)

    rob = sub.add_parser("robustness", help="posterior samples through both controllers "
                         "across tracking frequencies")
    rob.add_argument("fit", help="a fit written by `pmabayes fit`")
    rob.add_argument("--out", required=True, help="output folder")
    rob.add_argument("--samples", type=int, default=500, help="posterior samples (500)")
    rob.add_argument("--freqs", type=float, nargs="+", metavar="F",
                     help="frequencies in Hz (8 from 0.25 to 3, geometric, by default)")
    rob.add_argument("--mode", default="plant",
                     help="plant (plant drawn, controller nominal; default) or model "
                     "(controller's model drawn, plant nominal)")
    rob.add_argument("--seed", type=_seed, default=0, help="chooses the samples (0)")
    rob.add_argument("--duration", type=float, default=10.0, help="run length in s (10)")
    rob.add_argument("--processes", type=int, help="local worker processes (all cores)")
    rob.add_argument("--quiet", action="store_true", help="no progress bar")
    rob.set_defaults(func=_cmd_robustness)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pmabayes",
        description="Bayesian identification of pneumatic muscle actuators (Bouc-Wen).",
    )
    parser.add_argument("--plugin", action="append", default=[], metavar="FILE.py|MODULE",
                        help="import user effects before running (repeatable)")
    sub = parser.add_subparsers(dest="command", required=True)

    _fit_commands(sub)
    _batch_commands(sub)
    _criticism_commands(sub)
    _data_commands(sub)
    _control_commands(sub)
    _validation_commands(sub)
    return parser


def _prior_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--prior", action="append", default=[], type=_prior,
                   metavar="NAME=SPEC",
                   help="replace a parameter's prior, e.g. --prior 'K_e=LogNormal(5e4, 2)' "
                   "(Uniform(low, high), Normal(mu, sigma), LogNormal(median, sigma), "
                   "HalfNormal(sigma); repeatable); `pmabayes effects` lists the defaults")


def _fit_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--effects", default="", type=_effect_list,
                   help="comma-separated effects to add to the base model")
    p.add_argument("--seed", type=_seed, default=0,
                   help="seed of everything random (0)")
    _prior_option(p)
    p.add_argument("--walkers", type=int, default=32, help="walkers per ensemble (32)")
    p.add_argument("--ensembles", type=_positive, default=2,
                   help="independent ensembles, for R-hat across them (2)")
    p.add_argument("--steps", type=int, default=20000,
                   help="budget of steps per ensemble (20000); sampling stops earlier "
                   "when converged")
    p.add_argument("--restart", action="store_true",
                   help="discard saved chains instead of resuming them")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--substeps", type=_positive, default=1,
                   help="simulator steps per sample interval (1; more for a lightly damped "
                   "oscillator near the sample rate, e.g. 16 for the Bouc-Wen benchmark)")
    p.add_argument("--tie-noise", action="store_true",
                   help="one noise model for all experiments (same sensor and disturbance) "
                   "instead of one per experiment")
    p.add_argument("--own-segment-noise", action="store_true",
                   help="give each segment of a file that splits at its sidecar's max_gap_s "
                   "its own noise (by default the segments of one file share one)")
    _noise_model_option(p)
    _exclude_option(p)



def _noise_model_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--noise-model", choices=("auto", "ar1", "ar"), default="auto",
                   help="noise model of the likelihood where the noise comes from repeats: "
                   "'auto' (AR(1) + white unless the repeats reject it, then their AR(p)), "
                   "'ar1' or 'ar' (always one of them); records without repeats keep "
                   "AR(1) + white")


def _fit_commands(sub) -> None:
    run = sub.add_parser("run", help="the main job: fit a data set and write the report")
    run.add_argument("data", nargs="+", help="data files, one per experiment (.csv, .nc or "
                     "MATLAB .mat v4-v7.3, each with an optional .json sidecar of the same "
                     "stem); the experiments share the physical parameters")
    run.add_argument("--out", required=True, help="output folder (fit.nc and the report)")
    _fit_options(run)
    run.set_defaults(func=_cmd_run)

    fitp = sub.add_parser("fit", help="identify the parameters: MAP and posterior")
    fitp.add_argument("data", nargs="+", help="data files, one per experiment (.csv, .nc or "
                      "MATLAB .mat v4-v7.3, each with an optional .json sidecar of the same "
                      "stem); the experiments share the physical parameters")
    fitp.add_argument("--out", required=True, help="the fit, a NetCDF file (FIT.nc)")
    _fit_options(fitp)
    fitp.set_defaults(func=_cmd_fit)

    rep = sub.add_parser("report", help="summary tables, diagnostics and figures of a fit")
    rep.add_argument("fit", help="a fit written by `pmabayes fit`")
    rep.add_argument("--data", nargs="+", help="the data files (one per experiment, in the "
                     "fit's order), to check they match the fit")
    rep.add_argument("--out", required=True, help="output folder")
    rep.set_defaults(func=_cmd_report)

    pred = sub.add_parser("predict", help="simulate the model on a data set's input and "
                          "compare (no fitting)")
    pred.add_argument("data", help="data file: .csv, .nc or MATLAB .mat (v4-v7.3), with an "
                      "optional .json sidecar of the same stem")
    pred.add_argument("--out", required=True, help="output folder")
    pred.add_argument("--effects", default="", type=_effect_list,
                      help="comma-separated effects to add to the base model")
    pred.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                      help="override a parameter value (repeatable)")
    pred.set_defaults(func=_cmd_predict)



def _cmd_batch(args: argparse.Namespace) -> int:
    from pmabayes.inference.batch import BatchError, BatchJob, fit_batch

    out = _out_folder(args.out)
    if args.processes is not None and args.dask is not None:
        raise CliError("give --processes or --dask, not both")
    if args.tie_noise:
        raise CliError("--tie-noise: each data set of a batch is fitted alone, as one "
                       "experiment; to fit experiments together use `pmabayes fit A B ...`")
    if args.noise_model != "auto":
        raise CliError(f"--noise-model {args.noise_model}: a batch fits with the default "
                       "'auto'; fit the data set alone with `pmabayes fit` to choose")
    effects = tuple(args.effects)
    try:
        result = fit_batch([BatchJob(d, effects, priors=dict(args.prior)) for d in args.data],
                           out_dir=out,
                           settings=_fit_settings(args), seed=args.seed,
                           processes=args.processes, dask=args.dask, restart=args.restart,
                           progress=not args.quiet)
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
              f"{'n/a' if rms is None else f'{rms * 1e6:.1f} um'}, {conv} "
              f"({r['n_steps']} steps), {took}")
    print(f"{summary['n_datasets']} data sets: {summary['n_fitted']} fitted, "
          f"{summary['n_skipped']} skipped, {summary['n_failed']} failed, "
          f"{summary['n_not_converged']} not converged; {summary['seconds']:.1f} s on "
          f"{summary['runner']}")
    if args.json:
        _write_json(args.json, summary)
        print(f"wrote {args.json}")
    return 0 if result.ok else 1


def _batch_commands(sub) -> None:
    """The ``batch`` subcommand: many independent data sets, one fit each."""
    bat = sub.add_parser("batch", help="fit many independent data sets, each alone, on local "
                         "processes or a Dask cluster")
    bat.add_argument("data", nargs="+", help="data files: .csv, .nc or MATLAB .mat (v4-v7.3), "
                     "each with an optional .json sidecar of the same stem; each fit is "
                     "written to OUT/<file stem>.nc")
    bat.add_argument("--out", required=True, help="output folder of the fits")
    _fit_options(bat)
    bat.add_argument("--processes", type=_positive, default=None,
                     help="local worker processes, one data set each (all cores)")
    bat.add_argument("--dask", metavar="ADDRESS", default=None,
                     help="run on the Dask scheduler at ADDRESS (tcp://HOST:8786) instead; "
                     "needs `pip install pmabayes[dask]`")
    bat.add_argument("--json", help="write the batch's summary here")
    bat.set_defaults(func=_cmd_batch)


def _criticism_commands(sub) -> None:
    diag = sub.add_parser("diagnose", help="fit a model (MAP), criticise it and find which "
                          "effect is missing")
    diag.add_argument("data", nargs="+", help="data files (.csv, .nc or MATLAB .mat v4-v7.3, "
                      "each with an optional .json sidecar of the same stem), one per "
                      "experiment, each on the rig its sidecar gives; the experiments share "
                      "the physical parameters")
    diag.add_argument("--effects", default="", type=_effect_list,
                      help="comma-separated effects to add to the base model")
    diag.add_argument("--candidates", default="", type=_effect_list,
                      help="effects to test (all registered effects by default)")
    diag.add_argument("--out", help="folder for the figures and an HTML page")
    diag.add_argument("--json", help="write a machine-readable summary here")
    diag.add_argument("--proposal-dir", help="folder for the proposed effect's .py file when "
                      "the discrepancy step proposes one (default: --out, else the current "
                      "folder; an existing file is never overwritten)")
    diag.add_argument("--seed", type=_seed, default=0, help="seed of everything random (0)")
    _noise_model_option(diag)
    _prior_option(diag)
    diag.add_argument("--quiet", action="store_true", help="no progress lines")
    _exclude_option(diag)
    diag.set_defaults(func=_cmd_diagnose)

    comp = sub.add_parser("compare", help="fits of the same data side by side: error per "
                          "band, whiteness, ELPD")
    comp.add_argument("fits", nargs="+", help="two or more fits (FIT.nc) of the same data")
    comp.add_argument("--data", required=True, nargs="+",
                      help="the data files the fits were made from, one per experiment, "
                      "in the fits' order")
    comp.add_argument("--out", required=True, help="output folder")
    comp.add_argument("--labels", help="comma-separated names of the fits (default: their "
                      "models, base + effect + ...)")
    comp.set_defaults(func=_cmd_compare)


def _data_commands(sub) -> None:
    simu = sub.add_parser("simulate", help="write a synthetic repeated-chirp data set")
    simu.add_argument("out", help="output file (.csv with a .json sidecar, or .nc); its "
                      "folder is created if missing")
    simu.add_argument("--trials", type=int, default=10, help="number of trials (10)")
    simu.add_argument("--seed", type=_seed, default=0, help="seed of the noise (0)")
    simu.add_argument("--noise", choices=["default", "none"], default="default",
                      help="'none' writes the exact model output")
    simu.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                      help="hidden effect: NAME=VALUE sets its first parameter, "
                      "NAME.PARAM=VALUE any parameter (repeatable)")
    simu.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                      help="base parameter value (repeatable); paper values by default")
    simu.add_argument("--duration", type=float, default=15.0, help="chirp length in s (15)")
    simu.add_argument("--rate", type=float, default=1000.0, help="sample rate in Hz (1000)")
    simu.add_argument("--description", default="", help="text stored in the JSON sidecar")
    simu.set_defaults(func=_cmd_simulate)

    eff = sub.add_parser("effects", help="list the registered physical effects")
    eff.set_defaults(func=_cmd_effects)


def _one_line_warnings(command: str):
    """A ``warnings.showwarning`` that prints one line, without the source line."""
    def show(message, category, filename, lineno, file=None, line=None):
        kind = "warning" if issubclass(category, UserWarning) else category.__name__
        print(f"pmabayes {command}: {kind}: {message}", file=sys.stderr)
    return show


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Errors in the user's input (the package's own error classes: files, parameters,
    effects, fits) print one clear line to stderr and return 2 instead of a
    traceback; any other exception is a bug and keeps its traceback. Warnings
    print as one line each.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; ``sys.argv[1:]`` by default.

    Returns
    -------
    int
        Exit status.
    """
    args = _parser().parse_args(argv)
    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warnings(args.command)
        try:
            for plugin in args.plugin:
                load_plugin(plugin)
            return args.func(args)
        except _USER_ERRORS as err:
            print(f"pmabayes {args.command}: error: {err}", file=sys.stderr)
            return 2
        except BrokenPipeError:  # `pmabayes effects | head`: the reader has gone
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
