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
``pmabayes design DATA.csv [DATA2.csv ...] --candidates A,B --input-range LO,HI --out DIR``
    The next experiment that tells candidate effects apart (or, with ``--goal
    parameters``, shrinks chosen parameters' intervals): each candidate fitted on the
    data so far, candidate experiments scored by Monte Carlo; writes ``next.csv`` (the
    input, in the data's units), ``next.json``, ``design.json`` and a page.
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
in whole, the HTML last. These rules are :mod:`pmabayes.outputs`', below the command
line, and the Python API obeys them too. Ctrl-C prints one line: what was saved and
how to resume.

The package: this module holds :func:`main` and the parser; ``options`` the shared
options and argument types; ``inputs`` the reading of data files and fits; ``ending``
the one ending of every command (its JSON summary and page where asked, each named,
the time, the exit status); and one module per group of commands: ``fit`` (run, fit,
batch, predict), ``report``, ``criticism`` (diagnose, compare, validate), ``data``
(read, simulate, effects), ``design`` (design) and ``control`` (track, robustness). A command
is a function ``_cmd_NAME(args) -> int`` and its parser in its group's module.

Its modules import only the standard library at their top; the package's layers are
imported where a command needs them, so that ``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import warnings
from collections.abc import Callable, Sequence

from pmabayes import __version__
from pmabayes.cli.control import _control_commands
from pmabayes.cli.criticism import _criticism_commands, _print_ranking, _validation_commands
from pmabayes.cli.data import _data_commands
from pmabayes.cli.design import _design_commands
from pmabayes.cli.fit import _batch_commands, _fit_commands, _predict_commands
from pmabayes.cli.inputs import _load_all, _load_data, _say
from pmabayes.cli.options import (
    _FLAGS,
    CONTROLLERS,
    ENSEMBLES,
    MODES,
    NOISE_MODELS,
    STEPS,
    WALKERS,
    CliError,
    _common,
)
from pmabayes.cli.report import _report_commands
from pmabayes.util import show_progress

__all__ = ["main", "CliError"]

#: reached through this module (by the tests): the parser's defaults and choices, the
#: reading of data files, the ranking's lines
_REEXPORTED = (CONTROLLERS, ENSEMBLES, MODES, NOISE_MODELS, STEPS, WALKERS, _load_all,
               _load_data, _print_ranking)

# The package's own errors: wrong input, told in one line. Any other exception is a
# bug and keeps its traceback. Named by module: an error class whose module was never
# imported cannot have been raised, so none is imported to check.
_USER_ERRORS = (
    ("pmabayes.data.dataset", "DataError"), ("pmabayes.model.model", "ModelError"),
    ("pmabayes.model.effects.base", "EffectError"),
    ("pmabayes.model.simulator", "SimulationError"),
    ("pmabayes.inference.likelihood", "LikelihoodError"),
    ("pmabayes.inference.errors", "FitError"), ("pmabayes.inference.fitfile", "FitFileError"),
    ("pmabayes.control.operating", "ControlError"), ("pmabayes.outputs", "OutputError"),
    ("pmabayes.design.experiments", "DesignError"),
)


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
    _report_commands(sub, common)
    _predict_commands(sub, common)
    _batch_commands(sub, common)
    _criticism_commands(sub, common)
    _data_commands(sub, common)
    _control_commands(sub, common)
    _design_commands(sub, common)
    _validation_commands(sub, common)
    return parser


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
