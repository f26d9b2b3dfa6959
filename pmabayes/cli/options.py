"""The command line's shared options: argument types, the options several commands
take, their defaults and choices, and :class:`CliError`.

Built from the standard library alone, so that the parser (and ``--help``) needs no
numerics; a type that checks against the package (a prior, an effect's name) imports
its layer when called.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

__all__: list[str] = []


class CliError(ValueError):
    """A command-line argument is wrong; the message names it and the fix."""


# The choices of the options, as literals so that the parser needs no numpy;
# tests/test_cli_edges.py checks them against the package's constants.
NOISE_MODELS = ("auto", "ar1", "ar", "student_t")  # pmabayes.inference.noise.NOISE_MODELS
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


def _trials_option(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--trials", type=_trial_ids, default=[], metavar="ID,ID",
                   help=f"{what} only these trial ids of the data file (e.g. 1,2,3), so "
                   "that one file serves fitting and validation")


def _noise_model_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--noise-model", choices=NOISE_MODELS, default="auto",
                   help="noise model of the likelihood where the noise comes from repeats: "
                   "'auto' (AR(1) + white unless the repeats reject it, then their AR(p)), "
                   "'ar1' or 'ar' (always one of them); records without repeats keep "
                   "AR(1) + white; 'student_t': white noise with heavy tails (outliers), "
                   "sampled with the model")


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
    _trials_option(p, "fit")


#: The data files every command reads, as its help says them.
_DATA_KINDS = ("text (.csv, .txt, .dat, .tsv, LabVIEW's .lvm), .nc or MATLAB .mat v4-v7.3, "
               "each with an optional .json sidecar of the same stem")
_DATA_HELP = (f"data files, one per experiment ({_DATA_KINDS}); the experiments share the "
              "physical parameters")
_FOLDER_HELP = ("; created if missing; an existing one must be empty or this command's "
                "own output")
