"""The RC columns' later cycles predicted from their earlier ones: real measurements of
Ortiz, Alvarez and Bedoya-Ruiz (Computers & Structures 2015), each record's first 70%
fitted and its last 30% predicted from an estimated start.

For each specimen, as a user would: ``pmabayes diagnose`` of the first 70% (the effect
it names, ``missing`` or else its partial step, added and the record diagnosed again,
``--rounds`` times at most), ``pmabayes fit`` with the effects found, and ``pmabayes
validate`` of that fit on the first 70% (in-sample) and on the last 30% (its state at
the split unknown: ``"initial_state": "estimate"``; every state is estimated from its
first samples, a degrading law's dissipated energy too), beside the three yardsticks
``validate`` fits on the same training part. The targets: below every yardstick on at
least three of the four specimens, both on the fitted part and on the held-out 30%.

The records have no time; the paper reads them on a fictitious 0.02 s step with a mass
per specimen (``real_rc_columns.py``). The data stay in ``../shared/external/real``.

Usage::

    python analyses/real_columns_split.py [--specimens chiu gill ...] [--rounds 2]
        [--out DIR] [--seed 0] [--steps 600] [--candidates A,B]

The table is printed last; ``--out`` keeps the data files, diagnoses, fits and JSON.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
import warnings
from pathlib import Path

import numpy as np
from _real import pmabayes, real_folder
from real_cavatappi import named_effect
from real_rc_columns import MASS_KG, STEP_S

SHARE = 0.7


def declare(out: Path, name: str) -> tuple[Path, Path]:
    """The specimen's first 70% and last 30%, as SI data files with their sidecars."""
    from pmabayes.data import DataWarning, read_columns

    folder = real_folder("rc_columns", "real_columns_split.py")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)  # kN -> N, mm -> m: said in the files
        force_n = read_columns(folder / f"load_kN_{name}.txt", {"1": "force_kn"})["force_n"]
        x_m = read_columns(folder / f"displ_{name}.txt", {"1": "position_mm"})["position_m"]
    n = min(force_n.size, x_m.size)
    cut = int(SHARE * n)
    t = np.arange(n) * STEP_S
    rig = {"name": name, "input_kind": "force", "moving_mass_kg": MASS_KG[name],
           "gravity_sign": 0, "area_m2": 1.0}
    paths = []
    for part, sl, start in (("train", slice(0, cut), "rest"), ("held", slice(cut, n),
                                                               "estimate")):
        path = out / f"{name}_{part}.csv"
        rows = np.column_stack([t[sl], force_n[:n][sl], x_m[:n][sl]])
        path.write_text("time_s,force_n,position_m\n" + "\n".join(
            ",".join(repr(float(v)) for v in row) for row in rows) + "\n")
        meta = {"description": f"RC column {name}, {part} part (Ortiz, Alvarez & "
                               "Bedoya-Ruiz, Computers & Structures 2015; kN and mm "
                               "converted to N and m), on a fictitious 0.02 s step",
                "rig": rig, "initial_state": start}
        path.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
        paths.append(path)
    return paths[0], paths[1]


def _nrmse_row(validation: dict) -> dict:
    e = validation["experiments"][0]
    base = e.get("baselines") or {}
    return {"nrmse": e["nrmse"], **{f"{k}_nrmse": (base.get(k) or {}).get("nrmse")
                                    for k in ("linear", "play", "narx")}}


def _start_text(start: dict) -> str:
    """The estimated start of a held-out part: the samples it was fitted to, and its
    effects' states (a degrading law's dissipated energy at the cut)."""
    if start.get("initial_state") != "estimate":
        return "-"
    states = ", ".join(f"{n} {start.get(n + '_median', float('nan')):.4g}"
                       for n in start.get("states_estimated") or ())
    return (f"{start['samples']} samples ({100 * start['fraction']:.3g}%; "
            f"{start.get('window', 'start_fraction')})" + (f"; {states}" if states else ""))


def run(name: str, out: Path, args) -> dict:
    """The loop on one specimen; its row of the table."""
    train, held = declare(out, name)
    seed, quiet = ["--seed", str(args.seed)], ["--quiet"]
    candidates = ["--candidates", args.candidates] if args.candidates else []
    effects: list[str] = []
    started = time.perf_counter()
    for round_ in range(args.rounds + 1):
        fx = ["--effects", ",".join(effects)] if effects else []
        diag = out / f"{name}_diagnose_{round_}.json"
        pmabayes("diagnose", str(train), "--json", str(diag), *fx, *candidates,
                 "--proposal-dir", str(out), *seed, *quiet)
        d = json.loads(diag.read_text())
        print(f"{name} round {round_}: {d['verdict']}", flush=True)
        effect = named_effect(d, effects)
        if effect is None or round_ == args.rounds:
            break
        effects.append(effect)
    fx = ["--effects", ",".join(effects)] if effects else []
    fit = out / f"{name}_fit.nc"
    pmabayes("fit", str(train), "--out", str(fit), "--restart", *fx, "--steps",
             str(args.steps), *seed, *quiet)
    row = {"specimen": name, "effects": "+".join(effects) or "-"}
    for part, path in (("fitted", train), ("held_out", held)):
        val = out / f"{name}_validate_{part}.json"
        own = ["--in-sample"] if part == "fitted" else []
        pmabayes("validate", str(fit), str(path), "--json", str(val), "--draws", "100",
                 *own, *seed, *quiet)
        validation = json.loads(val.read_text())
        row |= {f"{part}_{k}": v for k, v in _nrmse_row(validation).items()}
        if part == "held_out":  # how the held-out part's start was estimated
            row["held_out_start"] = _start_text(validation["experiments"][0].get("start") or {})
    row["seconds"] = time.perf_counter() - started
    return row


def _beats(row: dict, part: str) -> bool:
    others = [row[f"{part}_{k}_nrmse"] for k in ("linear", "play", "narx")
              if row[f"{part}_{k}_nrmse"] is not None]
    return row[f"{part}_nrmse"] is not None and row[f"{part}_nrmse"] < min(others)


def main(argv: list[str] | None = None) -> int:
    """Run the loop on each specimen and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--specimens", nargs="+", choices=sorted(MASS_KG), default=sorted(MASS_KG))
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("real_columns_split"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--candidates", default="")
    args = ap.parse_args(argv)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    rows = [run(name, out, args) for name in args.specimens]
    with open(out / "table.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)

    def f(v):
        return "-" if v is None else f"{v:.3f}"

    print("\nRC columns (real measurements, Ortiz, Alvarez & Bedoya-Ruiz): NRMSE on the fitted "
          "70% and the held-out 30%")
    print(f"{'specimen':<9} {'effects':<40} {'part':<9} {'model':>6} {'linear':>7} {'play':>6} "
          f"{'narx':>6}")
    for r in rows:
        for part in ("fitted", "held_out"):
            print(f"{r['specimen']:<9} {r['effects']:<40} {part:<9} {f(r[part + '_nrmse']):>6} "
                  f"{f(r[part + '_linear_nrmse']):>7} {f(r[part + '_play_nrmse']):>6} "
                  f"{f(r[part + '_narx_nrmse']):>6}")
    print("held-out starts, estimated from the first samples of each last 30%:")
    for r in rows:
        print(f"  {r['specimen']}: {r.get('held_out_start', '-')}")
    for part in ("fitted", "held_out"):
        won = sum(_beats(r, part) for r in rows)
        print(f"below every yardstick on the {part.replace('_', '-')} part: {won} of {len(rows)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
