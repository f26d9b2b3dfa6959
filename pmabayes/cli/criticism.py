"""The commands that criticise: ``diagnose`` (what is missing from a model), ``compare``
(fits of the same data side by side) and ``validate`` (held-out experiments)."""

from __future__ import annotations

import argparse
import contextlib
import math
import time
from collections.abc import Sequence

from pmabayes.cli.ending import _finish, _um
from pmabayes.cli.inputs import _load_all, _load_data, _model_for, _read_fit, _say, _segments
from pmabayes.cli.options import (
    _DATA_KINDS,
    _FOLDER_HELP,
    CliError,
    _effect_list,
    _exclude_option,
    _noise_model_option,
    _positive,
    _prior_option,
    _probability,
    _seed,
    _substeps,
    _trials_option,
)
from pmabayes.outputs import check_file, check_folder, check_folder_for_new_files, created

__all__: list[str] = []


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
        if getattr(f, "implausible", None):  # outside the plausible range: not physics
            est += " (implausible)"
        gain = (f"ΔELPD {elpd_short(f.refit):>16s}  " if f.refit is not None
                else " " * 24 if refitted else "")
        print(f"  {f.effect:<22s} {gain}evidence {f.evidence:10.4g}  "
              f"{'significant' if f.significant else 'n.s.':<11s}  {est}")
    if len(ranking) > limit:
        print(f"  ... and {len(ranking) - limit} more (all in --json and --out)")


#: ``diagnose --leave-experiments-out`` to :attr:`DiagnoseSettings.leave_experiments_out`
_LEAVE_OUT = {"auto": None, "yes": True, "no": False}


def _cmd_diagnose(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    inputs = list(args.data)
    out = check_folder(args.out, "diagnose", inputs=inputs) if args.out else None
    js = check_file(args.json, "diagnose", "--json", inputs) if args.json else None
    if args.proposal_dir:
        check_folder_for_new_files(args.proposal_dir, "--proposal-dir")
    datasets = _load_all(args, "--effects", "--candidates")
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings
    from pmabayes.inference.trials import check_trials

    for ds in datasets:  # the noise is learnt from their spread
        print(check_trials(ds).summary())
    model = _model_for(datasets[0], args)
    settings = DiagnoseSettings(candidates=args.candidates or None,
                                noise_model=args.noise_model, substeps=args.substeps,
                                refit_search=args.refit_search,
                                refit_searches=args.refit_searches, processes=args.processes,
                                leave_experiments_out=_LEAVE_OUT[args.leave_experiments_out])
    # a proposed effect's file goes where the options say; without one it is checked
    # in a temporary folder and not kept (nothing is written into the current folder)
    plugin_dir = args.proposal_dir or out or False
    with contextlib.ExitStack() as stack:
        if out is not None:
            stack.enter_context(created(out, "diagnose"))
        result = diagnose(datasets if len(datasets) > 1 else datasets[0], model,
                          settings=settings, seed=args.seed, plugin_dir=plugin_dir)
    label = " + ".join(["base", *result.effects])
    print(f"model: {label}")
    for e in result.experiments:
        prefix = f"[{e.name}] " if len(result.experiments) > 1 else ""
        rms_um, floor_um = _um(e.rms_m, e.noise_floor_m)
        floor = (f"noise floor {floor_um} µm" if math.isfinite(e.noise_floor_m)
                 else "no noise floor: a single record without repeats")
        print(f"{prefix}RMS error of the trial mean: {rms_um} µm ({floor}); "
              f"adequate: {'yes' if e.adequate else 'no'}")
    if len(result.experiments) > 1:
        print(f"adequate in every experiment: {'yes' if result.adequate else 'no'}")
    _print_ranking(result.ranking)
    print(result.verdict)
    proposal = result.discrepancy.proposal if result.discrepancy is not None else None
    if proposal is not None and proposal.plugin:
        print(f"wrote {proposal.plugin} (the proposed effect)")
    from pmabayes.report.diagnosis_page import write_diagnosis

    return _finish("diagnose", summary=result.to_dict(), js=js, out=out, start=start,
                   page=lambda folder: write_diagnosis(result, folder))


def _cmd_compare(args: argparse.Namespace) -> int:
    labels = args.labels.split(",") if args.labels else None
    if len(args.fits) < 2 or (labels is not None and len(labels) != len(args.fits)):
        raise CliError(f"compare got {len(args.fits)} fit(s) and "
                       f"{'no' if labels is None else len(labels)} --labels; give two or more "
                       "fits of the same data, and one label per fit if any")
    out = check_folder(args.out, "compare", inputs=[*args.fits, *args.data])
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
            print(f"{f'[{name}] ' if name else ''}{k:<40s} RMS {b.rms_m * 1e6:9.1f} µm = "
                  f"{ratio}  Ljung-Box p {c.whiteness[k]['ljung_box_p']:.2g}")
    for k in result.labels:
        print(f"{k:<40s} ELPD {result.elpd[k]['elpd']:.1f} (leave one trial out"
              f"{' of all experiments' if result.experiments else ''})")
    for step in result.elpd_steps:
        print(f"{step['from']} -> {step['to']}: ELPD {step['elpd_diff']:+.1f} "
              f"+- {step['se']:.1f}")
    return _finish("compare", out=out,
                   page=lambda folder: write_comparison(result, folder, dataset=datasets))


def _cmd_validate(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    inputs = [args.fit, *args.data]
    out = check_folder(args.out, "validate", inputs=inputs) if args.out else None
    js = check_file(args.json, "validate", "--json", inputs) if args.json else None
    _say().say(f"validating {args.fit} on {', '.join(args.data)}")
    from pmabayes.criticism.validation import validate

    # the fit as a path names it in the outputs; a data file that splits at its
    # sidecar's max_gap_s gives one held-out experiment per segment
    held_out = [d for p in args.data for d in _segments(p)]
    result = validate(args.fit, held_out, n_draws=args.draws, ci_prob=args.ci_prob,
                      seed=args.seed, noise_from=args.noise_from, substeps=args.substeps,
                      start_fraction=args.start_fraction, trials=args.trials or None,
                      in_sample=args.in_sample)
    print(f"validate {args.fit} (model: {' + '.join(['base', *result.effects])}) on "
          f"{len(result.experiments)} held-out experiment(s), {args.draws} posterior draws "
          "each:")
    for line in result.lines():
        print(f"  {line}")
    from pmabayes.report.validation_page import write_validation

    return _finish("validate", summary=result.to_dict(), js=js, out=out, start=start,
                   page=lambda folder: write_validation(result, folder))


def _criticism_commands(sub, common) -> None:
    diag = sub.add_parser("diagnose", parents=[common],
                          help="fit a model (MAP), criticise it and find which effect is "
                          "missing",
                          epilog="example: pmabayes diagnose data.csv --out diagnosis")
    diag.add_argument("data", nargs="+", help=f"data files ({_DATA_KINDS}), one per "
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
    diag.add_argument("--refit-search", default="nested",
                      help="how each candidate's refit finds its MAP: 'nested' (the "
                      "default) runs one global search and also polishes from the model's "
                      "MAP with the effect at its null (each experiment's own MAP "
                      "likewise); 'global' runs the fit's searches in full (slower)")
    diag.add_argument("--refit-searches", type=int, choices=(1, 2), default=1,
                      help="global searches of each refit's MAP on the nested path, each "
                      "on its own stream, the highest kept (1, the default; 2 takes about "
                      "twice as long)")
    diag.add_argument("--processes", type=_positive, default=None,
                      help="local worker processes for the candidates' refits, one each "
                      "(all cores); the numbers do not depend on it")
    diag.add_argument("--leave-experiments-out", choices=tuple(_LEAVE_OUT), default="auto",
                      help="before naming a candidate, fit it to all experiments but one and "
                      "predict the one left out, in turn; one that predicts them worse is "
                      "not named ('auto', the default: where the experiments' declared "
                      "conditions differ)")
    _noise_model_option(diag)
    _prior_option(diag)
    _exclude_option(diag)
    _trials_option(diag, "diagnose")
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


def _validation_commands(sub, common) -> None:
    """The ``validate`` subcommand: a fit's predictions of held-out experiments."""
    val = sub.add_parser("validate", parents=[common],
                         help="predict held-out experiments with a fit's posterior: error, "
                         "noise floor, predictive band and its coverage")
    val.add_argument("fit", help="a fit written by `pmabayes fit`")
    val.add_argument("data", nargs="+", help=f"held-out data files ({_DATA_KINDS}), one "
                     "experiment each, each on the rig its sidecar gives")
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
    _trials_option(val, "predict")
    val.add_argument("--substeps", type=_positive, default=None,
                     help="simulator steps per sample interval (default: as the fit used)")
    val.add_argument("--start-fraction", type=_probability, default=0.05,
                     help="for held-out data whose start is declared 'estimate': the first "
                     "part of the record (a fraction of it, 0.05) from which each posterior "
                     "draw's start is estimated by least squares")
    val.add_argument("--in-sample", action="store_true",
                     help="allow trials the fit was fitted on: the numbers then measure "
                     "the fit on its own data (beside the yardsticks), not a prediction")
    val.set_defaults(func=_cmd_validate)
