"""The ``report`` command: summary tables, diagnostics and figures of a fit, in an HTML
page (``run`` ends in the same page)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from pmabayes.cli.ending import _finish, _print_adequacy
from pmabayes.cli.inputs import _load_data, _read_fit, _say
from pmabayes.cli.options import _FOLDER_HELP, CliError
from pmabayes.outputs import check_folder

__all__: list[str] = []


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


def _write_report(tree, out: Path, datasets, kind: str) -> int:
    """The fit's page, written whole into ``out`` as the output of ``kind``, and named."""
    from pmabayes.report.fit_page import write_report

    _say().say(f"writing the report (tables and figures) to {out}")
    return _finish(kind, out=out, what="the report",
                   page=lambda folder: write_report(tree, folder, dataset=datasets))


def _cmd_report(args: argparse.Namespace) -> int:
    out = check_folder(args.out, "report", inputs=[args.fit, *(args.data or [])])
    tree = _read_fit(args.fit)
    datasets = _report_datasets(tree, args.data, args)
    _print_adequacy(tree, datasets)
    return _write_report(tree, out, datasets, "report")


def _report_commands(sub, common) -> None:
    """The ``report`` subcommand."""
    rep = sub.add_parser("report", parents=[common],
                         help="summary tables, diagnostics and figures of a fit",
                         epilog="example: pmabayes report fit.nc --data data.csv --out report")
    rep.add_argument("fit", help="a fit written by `pmabayes fit`")
    rep.add_argument("--data", nargs="+", help="the data files (one per experiment, in the "
                     "fit's order), to check they match the fit")
    rep.add_argument("--out", required=True, help="output folder" + _FOLDER_HELP)
    rep.set_defaults(func=_cmd_report)
