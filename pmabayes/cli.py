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
``pmabayes simulate OUT.csv [--effects A,B] [--param NAME=VALUE ...]``
    Write a synthetic repeated-chirp data set from the paper's parameters, with
    hidden effects at their defaults or the values ``--param`` gives.
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

``--plugin FILE.py`` (before or after the command) imports a file that registers
user effects, so they work on the command line exactly like the built-in ones.

Every stage that takes more than a moment says so on stderr when it starts, with a
bar and the time left where it can (``--quiet`` silences them all): the command
turns on :func:`pmabayes.util.show_progress`, the one switch of progress.

Outputs. No command writes over a file it did not make. Every output path is
checked before the first computation: it must be writable, a folder where a folder
is meant and a file where a file is meant, not one of the command's inputs, and
either new or pmabayes' own output of the same kind: a fit file carries the root
attribute ``pmabayes``, a JSON output the key ``"pmabayes"`` (``{"kind": COMMAND,
"version": ...}``), a folder the file ``.pmabayes`` (the same JSON), and a data set
of ``simulate`` the generator ``pmabayes.synthetic...`` in its metadata. An empty
folder is new. Pages are written to a temporary folder beside the output and moved
in whole, the HTML last. Ctrl-C prints one line: what was saved and how to resume.

This module imports only the standard library at its top; the package's layers are
imported where a command needs them, so that ``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from pmabayes import __version__
from pmabayes.util import Progress, show_progress

__all__ = ["main", "CliError"]


class CliError(ValueError):
    """A command-line argument is wrong; the message names it and the fix."""


# The package's own errors: wrong input, told in one line. Any other exception is a
# bug and keeps its traceback. Named by module: an error class whose module was never
# imported cannot have been raised, so none is imported to check.
_USER_ERRORS = (
    ("pmabayes.data.dataset", "DataError"), ("pmabayes.model.model", "ModelError"),
    ("pmabayes.model.effects.base", "EffectError"),
    ("pmabayes.model.simulator", "SimulationError"),
    ("pmabayes.inference.likelihood", "LikelihoodError"),
    ("pmabayes.inference.errors", "FitError"), ("pmabayes.inference.fitfile", "FitFileError"),
    ("pmabayes.control.operating", "ControlError"),
)

# The choices of the options, as literals so that the parser needs no numpy;
# tests/test_cli_edges.py checks them against the package's constants.
NOISE_MODELS = ("auto", "ar1", "ar")  # pmabayes.inference.likelihood.NOISE_MODELS
CONTROLLERS = ("pid", "ct")  # pmabayes.control.CONTROLLERS
MODES = ("plant", "model")  # pmabayes.control.robustness.MODES
WALKERS = 32  # the command line's default (FitSettings' is 24: a library default)
STEPS = 20000  # FitSettings.max_steps
ENSEMBLES = 2  # FitSettings.n_ensembles

#: API names in the package's messages, and the flag each command takes for them
_FLAGS = {
    "fit": {"n_walkers": "--walkers", "max_steps": "--steps", "n_ensembles": "--ensembles",
            "substeps": "--substeps", "noise_model": "--noise-model"},
    "robustness": {"samples": "--samples", "duration_s": "--duration",
                   "frequencies": "--freqs", "processes": "--processes"},
    "track": {"duration_s": "--duration", "frequency_hz": "--freq"},
    "validate": {"n_draws": "--draws", "ci_prob": "--ci-prob", "substeps": "--substeps"},
}
_FLAGS["run"] = _FLAGS["batch"] = _FLAGS["fit"]


def _is_user_error(err: BaseException) -> bool:
    if isinstance(err, CliError):
        return True
    for module, name in _USER_ERRORS:
        mod = sys.modules.get(module)
        if mod is not None and isinstance(err, getattr(mod, name)):
            return True
    return False


def _in_flags(command: str, message: str) -> str:
    """A message of the package with its API names as the command's flags
    (``n_walkers must be ...`` as ``--walkers must be ...``)."""
    for name, flag in _FLAGS.get(command, {}).items():
        message = re.sub(rf"(?<![\w-]){name}(?=( must| >| <|=))(?! \(--)", flag, message)
        message = message.replace(f"{flag}=", f"{flag} ")
    return message


# ---------------------------------------------------------------------------------
# argument types


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


def _substeps(text: str) -> int | str:
    """argparse type of ``--substeps``: a count >= 1 or ``auto``."""
    return "auto" if text.strip().lower() == "auto" else _positive(text)


def _positive(text: str) -> int:
    """argparse type of a count that must be at least 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give an integer >= 1")
    return value


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


def _prior(text: str) -> tuple[str, object]:
    """argparse type of ``--prior NAME=SPEC``, e.g. ``alpha=LogNormal(5e4, 2)``."""
    from pmabayes.model.parameters import parse_prior

    name, sep, spec = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(
            f"{text!r} must look like NAME=SPEC, e.g. alpha='LogNormal(5e4, 2)'")
    try:
        return name.strip(), parse_prior(spec)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _effect_list(text: str) -> list[str]:
    return [e.strip() for e in text.split(",") if e.strip()]


def _trial_ids(text: str) -> list[int]:
    from pmabayes.inference.trials import parse_trial_ids

    try:
        return parse_trial_ids(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _check_effects(names: Sequence[str], option: str) -> None:
    """Refuse an unknown effect name before any work (the message suggests a near one)."""
    from pmabayes.model.effects import EffectError, get_effect

    for name in names:
        try:
            get_effect(name)
        except EffectError as err:
            raise CliError(f"{option}: {err}") from None


# ---------------------------------------------------------------------------------
# outputs: checked before any work, never over a file pmabayes did not make

_MARK = ".pmabayes"  # the file that marks a folder as pmabayes' own


def _stamp(kind: str) -> dict:
    """The mark of pmabayes' outputs: what made them, and its version."""
    return {"kind": kind, "version": __version__}


def _read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _json_kind(path: Path) -> str | None:
    """The command that wrote a JSON output (its ``"pmabayes"`` key), or None."""
    obj = _read_json(path)
    mark = obj.get("pmabayes") if isinstance(obj, dict) else None
    return mark.get("kind") if isinstance(mark, dict) else None


def _folder_kind(path: Path) -> str | None:
    """The command whose output a folder is (its ``.pmabayes`` file), or None."""
    obj = _read_json(path / _MARK)
    return obj.get("kind") if isinstance(obj, dict) else None


def _is_simulated(path: Path) -> bool:
    """Whether ``path`` is a data set that ``pmabayes simulate`` wrote."""
    from pmabayes.data import DataError, load

    try:
        generator = load(path).metadata.get("generator")
    except (DataError, OSError, ValueError):
        return False
    return isinstance(generator, dict) and str(generator.get("function", "")).startswith(
        "pmabayes.")


def _writable(path: Path, option: str, shown: Path) -> None:
    """Refuse a path where nothing can be written, by trying (before any work)."""
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise CliError(f"{option} {shown}: {probe} is a file, so nothing can be written "
                       "under it; give another path")
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as err:
        raise CliError(f"{option} {shown}: cannot write in {probe} ({err.strerror}); give a "
                       "place you can write to") from None


def _not_an_input(path: Path, option: str, inputs: Sequence[str]) -> None:
    for item in inputs:
        if Path(item).exists() and path.exists() and os.path.samefile(item, path):
            raise CliError(f"{option} {path} is one of the command's inputs; give a new name "
                           "for the output")


def _refuse_foreign(path: Path, option: str, what: str) -> None:
    raise CliError(f"{option} {path}: {what}; pmabayes writes only over its own outputs of "
                   "the same kind. Give a new name, or move that away first")


def _out_file(path: str | Path, kind: str, option: str, inputs: Sequence[str] = ()) -> Path:
    """An output file's path, checked before any work: writable, not a folder, not an
    input, and new or pmabayes' own output of ``kind`` (``"fit"``, ``"data"``, or the
    command of a JSON output)."""
    path = Path(path)
    if path.is_dir():
        raise CliError(f"{option} {path}: this is a folder; give the name of the file to "
                       "write")
    _not_an_input(path, option, inputs)
    if path.exists():
        _say().say(f"{path} exists: checking that it is pmabayes' own {kind} output")
        if kind == "fit":
            from pmabayes.inference.fitfile import is_fit_file

            if not is_fit_file(path):
                _refuse_foreign(path, option, "this file exists and is not a pmabayes fit")
        elif kind == "data":
            if not _is_simulated(path):
                _refuse_foreign(path, option, "this file exists and is not a data set that "
                                "`pmabayes simulate` wrote")
        elif _json_kind(path) != kind:
            _refuse_foreign(path, option, f"this file exists and is not the JSON output of "
                            f"`pmabayes {kind}`")
    if kind == "data" and path.suffix.lower() == ".csv":  # and its JSON sidecar
        sidecar = path.with_suffix(".json")
        _not_an_input(sidecar, option, inputs)
        if sidecar.exists() and not (path.exists() and _is_simulated(path)):
            _refuse_foreign(sidecar, f"{option} {path}: its sidecar", "this file exists and "
                            "is not one `pmabayes simulate` wrote")
    _writable(path.parent, option, path)
    return path


def _out_folder(path: str | Path, kind: str, option: str = "--out",
                inputs: Sequence[str] = ()) -> Path:
    """An output folder's path, checked before any work: writable, not a file, holding
    none of the inputs, and new, empty, or pmabayes' output of ``kind`` (its mark)."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise CliError(f"{option} {out}: this is a file, not a folder; give the name of a "
                       "folder (it is created if missing)")
    if out.is_dir() and any(out.iterdir()):
        for item in inputs:
            if Path(item).resolve().is_relative_to(out.resolve()):
                raise CliError(f"{option} {out} holds the input {item}; give another folder "
                               "for the outputs")
        found = _folder_kind(out)
        if found != kind:
            _refuse_foreign(out, option, "this folder exists and holds files that `pmabayes "
                            f"{kind}` did not write" + (f" (it is the output of `pmabayes "
                                                        f"{found}`)" if found else ""))
    _writable(out, option, out)
    return out


def _mark_folder(out: Path, kind: str) -> None:
    (out / _MARK).write_text(json.dumps(_stamp(kind)) + "\n")


@contextlib.contextmanager
def _created(out: Path, kind: str) -> Iterator[Path]:
    """Create the folder ``out``, marked as the output of ``kind``; on failure remove it
    again if this call made it and nothing else was written."""
    existed = out.exists()
    out.mkdir(parents=True, exist_ok=True)
    _mark_folder(out, kind)
    try:
        yield out
    except BaseException:
        if not existed and {p.name for p in out.iterdir()} <= {_MARK}:
            shutil.rmtree(out, ignore_errors=True)
        raise


@contextlib.contextmanager
def _staged(out: Path, kind: str, written: list[str]) -> Iterator[Path]:
    """A temporary folder beside ``out`` to write a page into. On success its files move
    into ``out`` (made and marked if missing), the HTML last; their names are appended
    to ``written``. On failure or Ctrl-C it is removed and ``out`` is as it was."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp's is private; the folder it becomes is not
    try:
        yield tmp
        _mark_folder(tmp, kind)
        names = sorted((p.name for p in tmp.iterdir() if p.name != _MARK),
                       key=lambda n: (n.endswith(".html"), n))
        if not out.exists():
            os.replace(tmp, out)  # the whole folder at once
        else:
            for name in [_MARK, *names]:
                os.replace(tmp / name, out / name)
        written += names
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _write_json(path: str | Path, obj: dict, kind: str) -> None:
    """Write a JSON output, marked as ``kind``'s (its ``"pmabayes"`` key)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"pmabayes": _stamp(kind), **obj}, indent=2) + "\n")


def _summary_and_page(summary: dict, js: Path | None, out: Path | None, kind: str,
                      write_page: Callable[[Path], object]) -> None:
    """A command's JSON summary and its page (written by ``write_page`` into a folder),
    each where an option asks for it, each named."""
    if js is not None:
        _write_json(js, summary, kind)
        print(f"wrote {js}")
    if out is not None:
        written: list[str] = []
        with _staged(out, kind, written) as tmp:
            write_page(tmp)
        _wrote(out, written)


def _wrote(out: Path, names: Sequence[str], what: str = "") -> None:
    """Name every file written into a folder."""
    print(f"wrote {what + ' ' if what else ''}{out}{os.sep}: {', '.join(names)}")


# ---------------------------------------------------------------------------------
# data and models


def _say() -> Progress:
    return Progress()


def _segments(path: str) -> list:
    """A data file's segments (:func:`pmabayes.data.load_segments`), said when several."""
    from pmabayes.data import load_segments

    segments = load_segments(path)
    if len(segments) > 1:
        print(f"{path} splits into {len(segments)} segments at gaps longer than its "
              f"max_gap_s = {segments[0].metadata['max_gap_s']:g} s: "
              + ", ".join(f"{Path(d.source).stem} ({d.n_samples} samples from "
                          f"{d.time_s[0]:.4g} s)" for d in segments)
              + "; each is an experiment of the same rig, from its own start")
    return segments


def _load_data(args: argparse.Namespace, path: str, *, min_trials: int = 1,
               first: Callable[[], None] | None = None) -> list:
    """A data file's segments, without the trials ``--exclude-trials`` names (said, not
    silent); ``first`` runs after the line that says so, before the reading."""
    _say().say(f"reading {path}")  # first: importing the data layer takes a moment
    if first is not None:
        first()
    datasets = _segments(path)
    exclude = getattr(args, "exclude_trials", None)
    if exclude:
        from pmabayes.inference.trials import exclude_trials

        datasets = [exclude_trials(d, exclude, min_trials=min_trials) for d in datasets]
        print(f"excluded trials {','.join(map(str, exclude))} of {path} "
              f"(--exclude-trials); {datasets[0].n_trials} remain")
    return datasets


def _load_all(args: argparse.Namespace, *effect_options: str) -> list:
    """The data files of a fit; ``--exclude-trials`` needs a single one (ids are per file).
    The effects the named options give are checked first (a typo costs no reading)."""
    if getattr(args, "exclude_trials", None) and len(args.data) > 1:
        raise CliError(f"--exclude-trials names trial ids of one data file, but {len(args.data)} "
                       "were given; leave the trials out of that file first "
                       "(pmabayes.inference.trials.exclude_trials, then pmabayes.data.save), or "
                       "fit it alone")
    paths = [args.data] if isinstance(args.data, str) else list(args.data)

    def check() -> None:
        for option in effect_options:
            _check_effects(getattr(args, option[2:].replace("-", "_")), option)

    return [d for k, p in enumerate(paths)
            for d in _load_data(args, p, first=check if k == 0 else None)]


def _model_for(dataset, args: argparse.Namespace):
    """The model of a fitting command: the data's rig, the effects and priors asked for."""
    from pmabayes.model.model import Model

    fixed = _parse_assignments(getattr(args, "fix", []), "--fix")
    return Model.for_dataset(dataset, args.effects, priors=dict(args.prior),
                             fixed=fixed or None)


def _fit_settings(args: argparse.Namespace):
    from pmabayes.inference.sampler import FitSettings

    return FitSettings(n_walkers=args.walkers, n_ensembles=args.ensembles,
                       max_steps=args.steps, substeps=args.substeps,
                       tie_noise=getattr(args, "tie_noise", False),
                       noise_model=getattr(args, "noise_model", "auto"),
                       steady_state_tol_m=getattr(args, "steady_state_tol", None),
                       max_warmup_periods=getattr(args, "max_warmup_periods", None),
                       tie_segments=not getattr(args, "own_segment_noise", False))


def _floor_text(floor_m, rms_m: float | None = None) -> str:
    """``noise floor X um``, with the digits that tell it from ``rms_m`` beside it."""
    if floor_m is None:
        return "no repeats"
    from pmabayes.util import format_together

    floor = format_together(floor_m * 1e6, *([] if rms_m is None else [rms_m * 1e6]))[0]
    return f"noise floor {floor} um"


def _nan(record: dict) -> float:
    """A fit record's noise floor, NaN where it has none (None in the file)."""
    floor = record.get("noise_floor_m")
    return math.nan if floor is None else floor


def _um(*values_m: float) -> list[str]:
    """Lengths in µm side by side, with the digits that show their ratio."""
    from pmabayes.util import format_together

    return format_together(*(v * 1e6 for v in values_m))


def _print_adequacy(tree, datasets) -> None:
    from pmabayes.inference.fitfile import fit_info
    from pmabayes.report.verdicts import experiment_adequacy

    several = len(fit_info(tree).get("experiments") or [None]) > 1
    for name, adequacy in experiment_adequacy(tree, datasets=datasets):
        prefix = f"[{name}] " if several else ""
        print("\n".join(prefix + line for line in adequacy.lines()))


# ---------------------------------------------------------------------------------
# the commands


def _cmd_predict(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    out = _out_folder(args.out, "predict", inputs=[args.data])
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
    written: list[str] = []
    with _staged(out, "predict", written) as tmp:
        plot_comparison(dataset, x, label="model (paper values)" if not params else "model",
                        path=tmp / "comparison.png")
        _write_json(tmp / "summary.json", summary, "predict")
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
    _wrote(out, written)
    print(f"({time.perf_counter() - start:.1f} s)")
    return 0


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
          f"MAP RMS cost {_um(info['map']['rms_cost_m'], _nan(info['data']))[0]} um "
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
                  f"RMS cost {_um(exp['rms_cost_m'], _nan(exp))[0]} um "
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
                     + (f"; the raw trials' spread makes {raw * 1e6:.1f} um" if raw else ""))
    start = exp.get("start")
    if start:
        lines.append("start estimated: " + ", ".join(
            f"{n} prior {p['prior']}" for n, p in start["parameters"].items()))
    return lines


def _fit_out(args: argparse.Namespace, out: Path) -> None:
    """The chains' folder beside a fit must be a folder too (checked before any work)."""
    chains = out.with_name(out.name + ".chains")
    if chains.exists() and not chains.is_dir():
        raise CliError(f"--out {out}: {chains}, where its chains go, is a file; move it away "
                       "or give another name")


def _cmd_fit(args: argparse.Namespace) -> int:
    out = _out_file(args.out, "fit", "--out", inputs=args.data)
    _fit_out(args, out)
    datasets = _load_all(args, "--effects")
    model = _model_for(datasets[0], args)
    out.parent.mkdir(parents=True, exist_ok=True)
    _do_fit(args, datasets, model, out)
    return 0


def _report_datasets(tree, paths: Sequence[str] | None, args: argparse.Namespace):
    """The data files given to ``report``, one per experiment of the fit, or None."""
    from pmabayes.inference.fitfile import fit_info

    if not paths:
        return None
    n_exp = len(fit_info(tree).get("experiments") or [None])
    if len(paths) != n_exp:
        raise CliError(f"--data got {len(paths)} file(s) but the fit has {n_exp} "
                       "experiment(s); give one data file per experiment, in the fit's order")
    return [d for p in paths for d in _load_data(args, p)]


def _write_report(tree, out: Path, datasets, kind: str) -> list[str]:
    from pmabayes.report.fit_page import write_report

    _say().say(f"writing the report (tables and figures) to {out}")
    written: list[str] = []
    with _staged(out, kind, written) as tmp:
        write_report(tree, tmp, dataset=datasets)
    return written


def _read_fit(path: str):
    """A fit file, said first (reading it imports the inference layer)."""
    _say().say(f"reading the fit {path}")
    from pmabayes.inference.fitfile import load_fit

    return load_fit(path)


def _cmd_report(args: argparse.Namespace) -> int:
    out = _out_folder(args.out, "report", inputs=[args.fit, *(args.data or [])])
    tree = _read_fit(args.fit)
    datasets = _report_datasets(tree, args.data, args)
    written = _write_report(tree, out, datasets, "report")
    _print_adequacy(tree, datasets)
    _wrote(out, written, "the report")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    out = _out_folder(args.out, "run", inputs=args.data)
    _fit_out(args, out / "fit.nc")
    datasets = _load_all(args, "--effects")  # read and checked before anything is made
    model = _model_for(datasets[0], args)
    with _created(out, "run"):
        tree = _do_fit(args, datasets, model, out / "fit.nc")
    args.interrupted = lambda: (f"the fit is saved in {out / 'fit.nc'}; the report was not "
                                "written: run `pmabayes report` on the fit, or this command "
                                "again")
    written = _write_report(tree, out, datasets, "run")
    _wrote(out, written, "the report")
    print(f"({time.perf_counter() - start:.1f} s in all)")
    return 0


def _print_ranking(ranking: Sequence, limit: int = 5) -> None:
    """The candidates in the order of the diagnosis, said: the refitted ones first, by
    their leave-one-trial-out ELPD, then the others by their score-test evidence."""
    from pmabayes.criticism.prose import elpd_short

    refitted = [f for f in ranking if f.refit is not None]
    print(f"candidates ({len(refitted)} refitted, ordered by their leave-one-trial-out ELPD "
          "gain; then the others, ordered by the score test's evidence):"
          if refitted else "candidates, ordered by the score test's evidence:")
    for f in ranking[:limit]:
        est = ", ".join(f"{k}={v:.4g}" for k, v in f.estimate.items())
        gain = (f"ΔELPD {elpd_short(f.refit):>16s}  " if f.refit is not None
                else " " * 24 if refitted else "")
        print(f"  {f.effect:<22s} {gain}evidence {f.evidence:10.4g}  "
              f"{'significant' if f.significant else 'n.s.':<11s}  {est}")
    if len(ranking) > limit:
        print(f"  ... and {len(ranking) - limit} more (all in --json and --out)")


def _cmd_diagnose(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    inputs = list(args.data)
    out = _out_folder(args.out, "diagnose", inputs=inputs) if args.out else None
    js = _out_file(args.json, "diagnose", "--json", inputs) if args.json else None
    if args.proposal_dir:
        if Path(args.proposal_dir).is_file():
            raise CliError(f"--proposal-dir {args.proposal_dir}: this is a file, not a folder")
        _writable(Path(args.proposal_dir), "--proposal-dir", Path(args.proposal_dir))
    datasets = _load_all(args, "--effects", "--candidates")
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings
    from pmabayes.inference.trials import check_trials

    for ds in datasets:  # the noise is learnt from their spread
        print(check_trials(ds).summary())
    model = _model_for(datasets[0], args)
    settings = DiagnoseSettings(candidates=args.candidates or None,
                                noise_model=args.noise_model, substeps=args.substeps)
    # a proposed effect's file goes where the options say; without one it is checked
    # in a temporary folder and not kept (nothing is written into the current folder)
    plugin_dir = args.proposal_dir or out or False
    with contextlib.ExitStack() as stack:
        if out is not None:
            stack.enter_context(_created(out, "diagnose"))
        result = diagnose(datasets if len(datasets) > 1 else datasets[0], model,
                          settings=settings, seed=args.seed, plugin_dir=plugin_dir)
    label = " + ".join(["base", *result.effects])
    print(f"model: {label}")
    for e in result.experiments:
        prefix = f"[{e.name}] " if len(result.experiments) > 1 else ""
        rms_um, floor_um = _um(e.rms_m, e.noise_floor_m)
        floor = (f"noise floor {floor_um} um" if math.isfinite(e.noise_floor_m)
                 else "no noise floor: a single record without repeats")
        print(f"{prefix}RMS error of the trial mean: {rms_um} um ({floor}); "
              f"adequate: {'yes' if e.adequate else 'no'}")
    if len(result.experiments) > 1:
        print(f"adequate in every experiment: {'yes' if result.adequate else 'no'}")
    _print_ranking(result.ranking)
    print(result.verdict)
    proposal = result.discrepancy.proposal if result.discrepancy is not None else None
    if proposal is not None and proposal.plugin:
        print(f"wrote {proposal.plugin} (the proposed effect)")
    from pmabayes.report.diagnosis_page import write_diagnosis

    _summary_and_page(result.to_dict(), js, out, "diagnose",
                      lambda folder: write_diagnosis(result, folder))
    print(f"({time.perf_counter() - start:.1f} s)")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    labels = args.labels.split(",") if args.labels else None
    if len(args.fits) < 2 or (labels is not None and len(labels) != len(args.fits)):
        raise CliError(f"compare got {len(args.fits)} fit(s) and "
                       f"{'no' if labels is None else len(labels)} --labels; give two or more "
                       "fits of the same data, and one label per fit if any")
    out = _out_folder(args.out, "compare", inputs=[*args.fits, *args.data])
    fits = [_read_fit(f) for f in args.fits]
    from pmabayes.criticism.compare import compare_fits
    from pmabayes.inference.fitfile import fit_info
    from pmabayes.report.comparison_page import write_comparison

    n_exp = [len(fit_info(t).get("experiments") or [None]) for t in fits]
    for path, n in zip(args.fits, n_exp, strict=True):
        if n != len(args.data):
            raise CliError(
                f"{path} is a fit of {n} experiment(s) but --data got {len(args.data)} file(s) "
                f"({', '.join(args.data)}); give the data file of each experiment the fits were "
                "made from, in the fit's order, and compare only fits of the same experiments")
    datasets = [d for p in args.data for d in _load_data(args, p)]
    result = compare_fits(fits, datasets if len(datasets) > 1 else datasets[0], labels=labels,
                          sources=args.fits)
    parts = result.experiments or {"": result}
    for name, c in parts.items():
        for k in c.labels:
            b = c.bands[k][-1]
            ratio = f"{b.ratio:7.3g}x floor" if math.isfinite(b.floor_m) else "(no floor)"
            print(f"{f'[{name}] ' if name else ''}{k:<40s} RMS {b.rms_m * 1e6:9.1f} um = "
                  f"{ratio}  Ljung-Box p {c.whiteness[k]['ljung_box_p']:.2g}")
    for k in result.labels:
        print(f"{k:<40s} ELPD {result.elpd[k]['elpd']:.1f} (leave one trial out"
              f"{' of all experiments' if result.experiments else ''})")
    for step in result.elpd_steps:
        print(f"{step['from']} -> {step['to']}: ELPD {step['elpd_diff']:+.1f} "
              f"+- {step['se']:.1f}")
    written: list[str] = []
    with _staged(out, "compare", written) as tmp:
        write_comparison(result, tmp, dataset=datasets)
    _wrote(out, written)
    return 0


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
    out = _out_file(args.out, "data", "OUT")
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


def _cmd_track(args: argparse.Namespace) -> int:
    js = _out_file(args.json, "track", "--json", [args.fit] if args.fit else []) \
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
    if js is not None:
        _write_json(js, result, "track")
        print(f"wrote {js}")
    return 0


def _cmd_robustness(args: argparse.Namespace) -> int:
    out = _out_folder(args.out, "robustness", inputs=[args.fit])
    _say().say(f"robustness of PID and computed torque over {args.samples} posterior samples of "
               f"{args.fit}")
    from pmabayes.control.robustness import robustness_sweep, summarise_robustness, write_robustness
    from pmabayes.report.figures import plot_robustness, plt

    ds = robustness_sweep(args.fit, samples=args.samples, frequencies_hz=args.freqs,
                          mode=args.mode, seed=args.seed, duration_s=args.duration,
                          processes=args.processes)
    written: list[str] = []
    with _staged(out, "robustness", written) as tmp:
        write_robustness(ds, tmp)
        plt.close(plot_robustness(ds, path=tmp / "robustness.png"))
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
    _wrote(out, written)
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    inputs = [args.fit, *args.data]
    out = _out_folder(args.out, "validate", inputs=inputs) if args.out else None
    js = _out_file(args.json, "validate", "--json", inputs) if args.json else None
    _say().say(f"validating {args.fit} on {', '.join(args.data)}")
    from pmabayes.criticism.validation import validate

    # the fit as a path names it in the outputs; a data file that splits at its
    # sidecar's max_gap_s gives one held-out experiment per segment
    held_out = [d for p in args.data for d in _segments(p)]
    result = validate(args.fit, held_out, n_draws=args.draws, ci_prob=args.ci_prob,
                      seed=args.seed, noise_from=args.noise_from, substeps=args.substeps,
                      start_fraction=args.start_fraction)
    print(f"validate {args.fit} (model: {' + '.join(['base', *result.effects])}) on "
          f"{len(result.experiments)} held-out experiment(s), {args.draws} posterior draws "
          "each:")
    for line in result.lines():
        print(f"  {line}")
    from pmabayes.report.validation_page import write_validation

    _summary_and_page(result.to_dict(), js, out, "validate",
                      lambda folder: write_validation(result, folder))
    print(f"({time.perf_counter() - start:.1f} s)")
    return 0


def _batch_out(args: argparse.Namespace) -> Path:
    """The batch's folder and every fit it will write, checked before any work."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CliError(f"--out {out}: this is a file, not a folder; give the name of a "
                       "folder (it is created if missing)")
    _say().say(f"a batch of {len(args.data)} data set(s), each fitted into {out}")
    from pmabayes.inference.batch import BatchJob
    from pmabayes.inference.fitfile import is_fit_file

    for d in args.data:
        path = out / f"{BatchJob(d).resolved_name()}.nc"
        if path.is_dir() or (path.exists() and not is_fit_file(path)):
            _refuse_foreign(path, "--out", f"{path.name} exists there and is not a pmabayes "
                            f"fit, and the fit of {d} would go there")
    _writable(out, "--out", out)
    return out


#: options of ``fit`` that a batch does not take, and why (hidden from its --help)
_NOT_IN_BATCH = {
    "tie_noise": "--tie-noise: each data set of a batch is fitted alone, as one experiment; "
                 "to fit experiments together use `pmabayes fit A B ...`",
    "exclude_trials": "--exclude-trials: trial ids belong to one data file; leave the trials "
                      "out of that file first, or fit it alone with `pmabayes fit`",
    "noise_model": "--noise-model: a batch fits with the default 'auto'; fit the data set "
                   "alone with `pmabayes fit` to choose",
}


def _cmd_batch(args: argparse.Namespace) -> int:
    for name, why in _NOT_IN_BATCH.items():
        if getattr(args, f"refused_{name}") is not None:
            raise CliError(why)
    if args.processes is not None and args.dask is not None:
        raise CliError("give --processes or --dask, not both")
    out = _batch_out(args)
    js = _out_file(args.json, "batch", "--json", args.data) if args.json else None
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
              f"{'n/a' if rms is None else f'{rms * 1e6:.1f} um'}, {conv} "
              f"({r['n_steps']} steps), {took}")
    print(f"{summary['n_datasets']} data sets: {summary['n_fitted']} fitted, "
          f"{summary['n_skipped']} skipped, {summary['n_failed']} failed, "
          f"{summary['n_not_converged']} not converged; {summary['seconds']:.1f} s on "
          f"{summary['runner']}")
    if js is not None:
        _write_json(js, summary, "batch")
        print(f"wrote {js}")
    return 0 if result.ok else 1


# ---------------------------------------------------------------------------------
# the parser: built from the standard library alone


def _common() -> argparse.ArgumentParser:
    """The options every command takes: ``--quiet`` and ``--plugin`` (after the command)."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines (the results are still printed)")
    p.add_argument("--plugin", action="append", default=[], dest="plugin_after",
                   metavar="FILE.py|MODULE",
                   help="import user effects before running (repeatable; before or after "
                   "the command)")
    return p


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pmabayes",
        description="Bayesian identification of pneumatic muscle actuators (Bouc-Wen).",
        epilog="Outputs: no command writes over a file it did not make; an existing --out "
        "must be pmabayes' own output of the same kind (see `pmabayes COMMAND --help`).",
    )
    parser.add_argument("--version", action="version", version=f"pmabayes {__version__}")
    parser.add_argument("--plugin", action="append", default=[], metavar="FILE.py|MODULE",
                        help="import user effects before running (repeatable; before or "
                        "after the command)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = _common()
    _fit_commands(sub, common)
    _batch_commands(sub, common)
    _criticism_commands(sub, common)
    _data_commands(sub, common)
    _control_commands(sub, common)
    _validation_commands(sub, common)
    return parser


def _prior_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--prior", action="append", default=[], type=_prior,
                   metavar="NAME=SPEC",
                   help="replace a parameter's prior, e.g. --prior 'K_e=LogNormal(5e4, 2)' "
                   "(Uniform(low, high), Normal(mu, sigma), LogNormal(median, sigma), "
                   "HalfNormal(sigma); repeatable); `pmabayes effects` lists the defaults")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="hold a parameter at a value instead of identifying it, e.g. "
                   "--fix v_c=0.002 (repeatable)")


def _exclude_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--exclude-trials", type=_trial_ids, default=[], metavar="ID,ID",
                   help="leave these trial ids out (e.g. 3,7: trials the check of the "
                   "trials names as drifting or outlying)")


def _noise_model_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--noise-model", choices=NOISE_MODELS, default="auto",
                   help="noise model of the likelihood where the noise comes from repeats: "
                   "'auto' (AR(1) + white unless the repeats reject it, then their AR(p)), "
                   "'ar1' or 'ar' (always one of them); records without repeats keep "
                   "AR(1) + white")


def _sampler_options(p: argparse.ArgumentParser) -> None:
    """The options of every command that fits: model, priors, sampler budget."""
    p.add_argument("--effects", default=[], type=_effect_list,
                   help="comma-separated effects to add to the base model")
    p.add_argument("--seed", type=_seed, default=0,
                   help="seed of everything random (0)")
    _prior_option(p)
    p.add_argument("--walkers", type=_positive, default=WALKERS,
                   help=f"walkers per ensemble ({WALKERS}; at least twice the number of "
                   "parameters, the fit says how many when too few)")
    p.add_argument("--ensembles", type=_positive, default=ENSEMBLES,
                   help=f"independent ensembles, for R-hat across them ({ENSEMBLES})")
    p.add_argument("--steps", type=_positive, default=STEPS,
                   help=f"budget of steps per ensemble ({STEPS}; at least 20); sampling stops "
                   "earlier when converged")
    p.add_argument("--restart", action="store_true",
                   help="discard saved chains instead of resuming them")
    p.add_argument("--substeps", type=_substeps, default="auto",
                   help="simulator steps per sample interval, or 'auto' (the default: the "
                   "fewest whose output changes by under 1e-4 of the data's motion when "
                   "doubled, at the prior's median; 1 for the muscle)")
    p.add_argument("--max-warmup-periods", type=_positive, default=None, metavar="N",
                   help="most periods simulated to find the periodic steady state of data "
                   "that start in it (the sidecar's max_warmup_periods, else 256)")
    p.add_argument("--steady-state-tol", type=float, default=None, metavar="M",
                   help="tolerance of that steady state in m (the sidecar's "
                   "steady_state_tol_m, else 1e-9)")


def _fit_options(p: argparse.ArgumentParser) -> None:
    """The options of ``fit`` and ``run``: a batch fits each data set alone, and takes
    only the sampler's."""
    _sampler_options(p)
    p.add_argument("--tie-noise", action="store_true",
                   help="one noise model for all experiments (same sensor and disturbance) "
                   "instead of one per experiment")
    p.add_argument("--own-segment-noise", action="store_true",
                   help="give each segment of a file that splits at its sidecar's max_gap_s "
                   "its own noise (by default the segments of one file share one)")
    _noise_model_option(p)
    _exclude_option(p)


_DATA_HELP = ("data files, one per experiment (.csv, .nc or MATLAB .mat v4-v7.3, each with "
              "an optional .json sidecar of the same stem); the experiments share the "
              "physical parameters")
_FOLDER_HELP = ("; created if missing; an existing one must be empty or this command's "
                "own output")


def _fit_commands(sub, common) -> None:
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

    rep = sub.add_parser("report", parents=[common],
                         help="summary tables, diagnostics and figures of a fit",
                         epilog="example: pmabayes report fit.nc --data data.csv --out report")
    rep.add_argument("fit", help="a fit written by `pmabayes fit`")
    rep.add_argument("--data", nargs="+", help="the data files (one per experiment, in the "
                     "fit's order), to check they match the fit")
    rep.add_argument("--out", required=True, help="output folder" + _FOLDER_HELP)
    rep.set_defaults(func=_cmd_report)

    pred = sub.add_parser("predict", parents=[common],
                          help="simulate the model on a data set's input and compare (no "
                          "fitting)")
    pred.add_argument("data", help="data file: .csv, .nc or MATLAB .mat (v4-v7.3), with an "
                      "optional .json sidecar of the same stem")
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
    bat.add_argument("data", nargs="+", help="data files: .csv, .nc or MATLAB .mat (v4-v7.3), "
                     "each with an optional .json sidecar of the same stem; each fit is "
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


def _criticism_commands(sub, common) -> None:
    diag = sub.add_parser("diagnose", parents=[common],
                          help="fit a model (MAP), criticise it and find which effect is "
                          "missing",
                          epilog="example: pmabayes diagnose data.csv --out diagnosis")
    diag.add_argument("data", nargs="+", help="data files (.csv, .nc or MATLAB .mat v4-v7.3, "
                      "each with an optional .json sidecar of the same stem), one per "
                      "experiment, each on the rig its sidecar gives; the experiments share "
                      "the physical parameters")
    diag.add_argument("--effects", default=[], type=_effect_list,
                      help="comma-separated effects to add to the base model")
    diag.add_argument("--candidates", default=[], type=_effect_list,
                      help="effects to test (all registered effects by default)")
    diag.add_argument("--out", help="folder for the figures and an HTML page" + _FOLDER_HELP)
    diag.add_argument("--json", help="write a machine-readable summary here")
    diag.add_argument("--proposal-dir", help="folder for the proposed effect's .py file when "
                      "the discrepancy step proposes one (default: --out; without either the "
                      "proposal is checked but not kept; an existing file is never "
                      "overwritten)")
    diag.add_argument("--seed", type=_seed, default=0, help="seed of everything random (0)")
    diag.add_argument("--substeps", type=_substeps, default="auto",
                      help="simulator steps per sample interval, or 'auto' (the default, as "
                      "for fit)")
    _noise_model_option(diag)
    _prior_option(diag)
    _exclude_option(diag)
    diag.set_defaults(func=_cmd_diagnose)

    comp = sub.add_parser("compare", parents=[common],
                          help="fits of the same data side by side: error per band, "
                          "whiteness, ELPD")
    comp.add_argument("fits", nargs="+", help="two or more fits (FIT.nc) of the same data")
    comp.add_argument("--data", required=True, nargs="+",
                      help="the data files the fits were made from, one per experiment, "
                      "in the fits' order")
    comp.add_argument("--out", required=True, help="output folder" + _FOLDER_HELP)
    comp.add_argument("--labels", help="comma-separated names of the fits (default: their "
                      "models, base + effect + ...)")
    comp.set_defaults(func=_cmd_compare)


def _data_commands(sub, common) -> None:
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


def _validation_commands(sub, common) -> None:
    """The ``validate`` subcommand: a fit's predictions of held-out experiments."""
    val = sub.add_parser("validate", parents=[common],
                         help="predict held-out experiments with a fit's posterior: error, "
                         "noise floor, predictive band and its coverage")
    val.add_argument("fit", help="a fit written by `pmabayes fit`")
    val.add_argument("data", nargs="+", help="held-out data files (.csv with optional .json "
                     "sidecar, or .nc), one experiment each, each on the rig its sidecar gives")
    val.add_argument("--json", help="write the numbers and bands per experiment here")
    val.add_argument("--out", help="folder for the figures and an HTML page" + _FOLDER_HELP)
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


def _one_line_warnings(command: str):
    """A ``warnings.showwarning`` that prints one line, without the source line."""
    def show(message, category, filename, lineno, file=None, line=None):
        kind = "warning" if issubclass(category, UserWarning) else category.__name__
        print(f"pmabayes {command}: {kind}: {message}", file=sys.stderr)
    return show


def _load_plugins(specs: Sequence[str]) -> None:
    for spec in specs:
        _say().say(f"loading the plugin {spec}")
        from pmabayes.model.effects import load_plugin

        load_plugin(spec)


def _interrupted(args: argparse.Namespace) -> str:
    """The one line of a command stopped by Ctrl-C: what was saved, how to resume."""
    saved: Callable[[], str] | None = getattr(args, "interrupted", None)
    if saved is not None:
        return f"interrupted: {saved()}"
    return ("interrupted: nothing was written (outputs are written whole, once the work is "
            "done); run the same command again")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Errors in the user's input (the package's own error classes: files, parameters,
    effects, fits) print one clear line to stderr and return 2 instead of a
    traceback, naming the command's flags where the package names its settings; any
    other exception is a bug and keeps its traceback. Warnings print as one line
    each. Ctrl-C prints one line (what was saved, how to resume) and returns 130.

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
    with warnings.catch_warnings(), show_progress(args.command, not args.quiet):
        warnings.showwarning = _one_line_warnings(args.command)
        try:
            _load_plugins([*args.plugin, *args.plugin_after])
            from pmabayes.model.simulator import collect_steady_state_misses

            # members without a periodic steady state: counted, said once at the end
            with collect_steady_state_misses():
                return args.func(args)
        except KeyboardInterrupt:
            print(f"\npmabayes {args.command}: {_interrupted(args)}", file=sys.stderr)
            return 130
        except BrokenPipeError:  # `pmabayes effects | head`: the reader has gone
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
        except Exception as err:
            if not _is_user_error(err):
                raise
            message = _in_flags(args.command, str(err))
            print(f"pmabayes {args.command}: error: {message}", file=sys.stderr)
            return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
