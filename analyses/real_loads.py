"""Loads the model never saw: the cavatappi muscle (real measurements of Higueras-Ruiz,
Shafer and Feigenbaum, Science Robotics 2021; two samples, five dead loads each) fitted
on three loads together and predicting the other two.

For each sample, as a user would, with pmabayes' own commands:

1. ``pmabayes diagnose`` of the 100, 300 and 500 g loads together (each its own
   experiment, its load declared as a condition, the unpublished area one shared prior):
   the effect it names (``missing``, else its partial step) is added and the loads
   diagnosed again, ``--rounds`` times at most, while it names one;
2. ``pmabayes fit`` of the three loads with the effects found;
3. ``pmabayes validate`` of that fit on the held-out 200 and 400 g loads, beside the
   three yardsticks ``validate`` fits on the same training loads (a linear
   output-error model, a Prandtl-Ishlinskii play model and a polynomial NARX model
   with the load as an input).

The targets: on every held-out load, NRMSE below every yardstick and the 90% band holding
80-97% of the samples. With ``--leave-one-out`` each load is also left out in turn (fit
four, predict the fifth) with the final effects. The data stay in
``../shared/external/real/cavatappi`` (read-only, never copied); the sidecars and links
go into ``--out``.

Usage::

    python analyses/real_loads.py [--samples 1,2] [--rounds 2] [--out DIR] [--seed 0]
        [--steps 600] [--leave-one-out] [--candidates A,B] [--effects A,B]
        [--prior NAME=SPEC]

``--effects maxwell_creep,force_length_map --rounds -1`` repeats the final fit and the
held-out predictions of the effects sample 1's two diagnoses named, without diagnosing.

The table is printed last; ``--out`` keeps the diagnoses, fits, JSON and ``table.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

from _real import pmabayes
from real_cavatappi import HELD_OUT_G, TRAIN_G, declare, named_effect, rows_of


def loop(paths: dict[int, Path], out: Path, args) -> tuple[list[str], list[dict], list[dict]]:
    """Diagnose the training loads together until nothing more is named, fit, validate.

    Returns the effects added, the diagnoses' summaries and the held-out rows.
    """
    train = [str(paths[g]) for g in TRAIN_G]
    held = [str(paths[g]) for g in HELD_OUT_G]
    seed, quiet = ["--seed", str(args.seed)], ["--quiet"]
    priors = [a for p in args.prior for a in ("--prior", p)]
    candidates = ["--candidates", args.candidates] if args.candidates else []
    effects: list[str] = [e for e in args.effects.split(",") if e]
    rounds = []
    for round_ in range(args.rounds + 1):  # none when --rounds is -1
        fx = ["--effects", ",".join(effects)] if effects else []
        diag = out / f"diagnose_{round_}.json"
        took, _ = pmabayes("diagnose", *train, "--json", str(diag), *fx, *candidates,
                           "--proposal-dir", str(out), *priors, *seed, *quiet)
        d = json.loads(diag.read_text())
        agreement = d.get("agreement") or {}
        rounds.append({"effects": list(effects), "seconds": took, "adequate": d["adequate"],
                       "missing": d.get("missing"), "partial": d.get("partial"),
                       "agreement_statistic": agreement.get("statistic"),
                       "trend": agreement.get("trend"), "rms_m": d.get("rms_m")})
        print(f"round {round_}: {d['verdict']}", flush=True)
        effect = named_effect(d, effects)
        if effect is None or round_ == args.rounds:
            break
        effects.append(effect)
    fx = ["--effects", ",".join(effects)] if effects else []
    tag = "+".join(["base", *effects])
    fit = out / "fit_final.nc"
    pmabayes("fit", *train, "--out", str(fit), "--restart", *fx, "--steps", str(args.steps),
             "--walkers", "48", *priors, *seed, *quiet)
    val = out / "validate_final.json"
    pmabayes("validate", str(fit), *held, "--json", str(val), "--draws", "200", *seed, *quiet)
    rows = rows_of(json.loads(val.read_text()), tag)
    if args.leave_one_out:
        for g in sorted(TRAIN_G + HELD_OUT_G):
            rest = [str(paths[h]) for h in sorted(TRAIN_G + HELD_OUT_G) if h != g]
            f_out = out / f"fit_without_{g}g.nc"
            pmabayes("fit", *rest, "--out", str(f_out), "--restart", *fx, "--steps",
                     str(args.steps), "--walkers", "48", *priors, *seed, *quiet)
            v_out = out / f"validate_{g}g.json"
            pmabayes("validate", str(f_out), str(paths[g]), "--json", str(v_out), "--draws",
                     "200", *seed, *quiet)
            rows += [{**r, "model": tag + " (leave one out)"}
                     for r in rows_of(json.loads(v_out.read_text()), tag)]
    return effects, rounds, rows


def write_paper_table(results: Path, tables: Path) -> Path:
    """The paper's table of the held-out loads (``real_loads.tex``) from a finished run's
    ``table.csv``: per sample and held-out load, the final model's NRMSE beside the three
    yardsticks', and its 90% band's coverage.

    Parameters
    ----------
    results : Path
        The run's ``--out`` folder.
    tables : Path
        Where ``real_loads.tex`` is written.

    Returns
    -------
    Path
        Its path.
    """
    with open(results / "table.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if "leave one out" not in r["model"]]

    def num(r: dict, key: str) -> str:
        v = float(r[key])
        best = min(float(r[k]) for k in ("nrmse", "linear_nrmse", "play_nrmse", "narx_nrmse")
                   if r[k] not in ("", None))
        return f"\\textbf{{{v:.3f}}}" if v == best else f"{v:.3f}"

    body = "".join(
        f"{r['sample']} & {r['held_out'].split('_')[-1].replace('g', '~g')} & "
        f"{num(r, 'nrmse')} & {num(r, 'linear_nrmse')} & {num(r, 'play_nrmse')} & "
        f"{num(r, 'narx_nrmse')} & {100 * float(r['coverage']):.1f}\\% \\\\\n" for r in rows)
    model = rows[0]["model"].replace("_", "\\_").replace("+", " + ")
    tables.mkdir(parents=True, exist_ok=True)
    path = tables / "real_loads.tex"
    path.write_text(
        "% written by analyses/real_loads.py --tables-from RESULTS\n"
        "\\begin{tabular}{llrrrrr}\n\\toprule\n"
        "sample & held out & model & linear & play & NARX & 90\\% band \\\\\n\\midrule\n"
        + body + "\\bottomrule\n\\end{tabular}\n"
        f"% model: {model}\n")
    return path


def _fmt(v, pct: bool = False) -> str:
    if v is None or v == "":
        return "-"
    v = float(v)
    return f"{100 * v:.1f}%" if pct else f"{v:.3f}"


def main(argv: list[str] | None = None) -> int:
    """Run the loop on each sample and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", default="1,2", help="which samples (1,2)")
    ap.add_argument("--rounds", type=int, default=2, help="most diagnose rounds (2)")
    ap.add_argument("--out", type=Path, default=Path("real_loads"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=600, help="sampler steps of the fits (600)")
    ap.add_argument("--effects", default="",
                    help="effects to start from (e.g. those an earlier run's diagnoses "
                    "named); with --rounds -1 no diagnosis is run: fit and validate only")
    ap.add_argument("--prior", action="append", default=[], metavar="NAME=SPEC",
                    help="replace a parameter's prior in every diagnosis and fit, as "
                    "pmabayes' own --prior (repeatable)")
    ap.add_argument("--candidates", default="",
                    help="the candidates diagnose tests (default: all it has)")
    ap.add_argument("--leave-one-out", action="store_true",
                    help="also leave each load out in turn (fit four, predict the fifth)")
    ap.add_argument("--tables-from", type=Path, metavar="RESULTS",
                    help="only write the paper's table (real_loads.tex, into --tables) from "
                         "a finished run's --out folder")
    ap.add_argument("--tables", type=Path, default=Path(__file__).resolve().parents[1]
                    / "paper" / "tables", help="where --tables-from writes (paper/tables)")
    args = ap.parse_args(argv)
    if args.tables_from:
        print(write_paper_table(args.tables_from, args.tables))
        return 0
    rows, summaries = [], []
    for sample in (int(s) for s in args.samples.split(",")):
        out = (args.out / f"sample{sample}").resolve()
        out.mkdir(parents=True, exist_ok=True)
        started = time.perf_counter()
        effects, rounds, sample_rows = loop(declare(out, sample), out, args)
        summaries.append((sample, effects, rounds, time.perf_counter() - started))
        rows += [{"sample": sample, **r} for r in sample_rows]
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "table.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    for sample, effects, rounds, took in summaries:
        print(f"\nsample {sample} ({took:.0f} s): effects added "
              f"{', '.join(effects) or 'none'}")
        for k, r in enumerate(rounds):
            stat = r["agreement_statistic"]
            print(f"  diagnose {k} ({r['seconds']:.0f} s): RMS {1e3 * r['rms_m']:.3g} mm, "
                  f"agreement statistic {stat:.4g}" if stat is not None else "",
                  f"missing {r['missing']}, partial {r['partial']}; {r['trend'] or ''}")
    print("\nheld-out loads (real measurements, Higueras-Ruiz, Shafer & Feigenbaum)")
    print(f"{'sample':<7} {'model':<40} {'held out':<14} {'NRMSE':>7} {'linear':>7} "
          f"{'play':>7} {'narx':>7} {'90% band':>9}")
    for r in rows:
        print(f"{r['sample']:<7} {r['model']:<40} {r['held_out']:<14} {_fmt(r['nrmse']):>7} "
              f"{_fmt(r['linear_nrmse']):>7} {_fmt(r['play_nrmse']):>7} "
              f"{_fmt(r['narx_nrmse']):>7} {_fmt(r['coverage'], True):>9}")
    final = [r for r in rows if "leave one out" not in r["model"]]
    beats = all(r["nrmse"] is not None and r["nrmse"] < min(
        x for x in (r["linear_nrmse"], r["play_nrmse"], r["narx_nrmse"]) if x is not None)
        for r in final)
    covered = all(r["coverage"] is not None and 0.80 <= r["coverage"] <= 0.97 for r in final)
    print(f"final models beat every yardstick on every held-out load: {beats}")
    print(f"final models' 90% bands hold 80-97% on every held-out load: {covered}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
