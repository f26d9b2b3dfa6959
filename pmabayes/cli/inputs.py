"""The commands' inputs: data files (their segments, the trials left out), fits, and the
model and sampler settings the options ask for.

Each reader says what it reads first: reading imports the data or inference layer,
which takes a moment.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from pmabayes.cli.options import CliError, _check_effects, _parse_assignments
from pmabayes.util import Progress

__all__: list[str] = []


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
    keep = getattr(args, "trials", None)
    if keep and exclude:
        raise CliError("--trials and --exclude-trials both choose trials: give one of them")
    if keep:
        from pmabayes.inference.trials import keep_trials

        datasets = keep_trials(datasets, keep, min_trials=min_trials)
        print(f"fitting trials {','.join(map(str, keep))} of {path} (--trials)")
    if exclude:
        from pmabayes.inference.trials import exclude_trials

        datasets = [exclude_trials(d, exclude, min_trials=min_trials) for d in datasets]
        print(f"excluded trials {','.join(map(str, exclude))} of {path} "
              f"(--exclude-trials); {datasets[0].n_trials} remain")
    return datasets


def _load_all(args: argparse.Namespace, *effect_options: str) -> list:
    """The data files of a fit; ``--exclude-trials`` needs a single one (ids are per file).
    The effects the named options give are checked first (a typo costs no reading)."""
    if getattr(args, "trials", None) and len(args.data) > 1:
        raise CliError(f"--trials names trial ids of one data file, but {len(args.data)} "
                       "were given; fit that file alone, or choose its trials in Python "
                       "(pmabayes.fit(..., trials=[...]))")
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


def _read_fit(path: str):
    """A fit file, said first (reading it imports the inference layer)."""
    _say().say(f"reading the fit {path}")
    from pmabayes.inference.fitfile import load_fit

    return load_fit(path)
