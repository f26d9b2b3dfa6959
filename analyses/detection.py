"""Detection of hidden effects: false alarms on null data and detection rate against size.

Diagnoses (``pmabayes.criticism.diagnosis.diagnose``) many synthetic data sets with the base
model, each drawn with its own seed and its own base-model parameters from
``pmabayes.synthetic.PLAUSIBLE_REGION``, with the default measurement (AR(1)
disturbance and encoder quantisation):

* null data sets (no hidden effect): how often is anything flagged (a candidate
  significant or named missing) and how often is the model judged inadequate;
* data with one hidden effect of a given size, swept across the detection limit:
  how often is anything flagged, how often is that effect named missing (a tiny
  regulator lag is indistinguishable from a transport delay of the same time, so
  "another" is mostly that twin), and how often does the 90% interval of its
  refit cover the true size.

Usage::

    python analyses/detection.py [--null 20] [--seeds 5] [--sizes 4] [--max-refits 3]
                                 [--effects NAME ...] [--seed 0] [--out DIR] [--quick]
                                 [--processes N | --dask ADDRESS]

Writes ``detection.csv``, ``detection.md`` and ``null.md`` into ``--out`` (default
``paper/tables``). The last line printed is ``false_alarm_rate: <fraction>``.
``--quick`` runs 3 null data sets and 1 seed per size (the two largest sizes) on
short data, for CI; ``--null``, ``--seeds`` and ``--sizes`` given explicitly override
those counts (``--sizes k`` keeps the k largest sizes of each effect); ``--effects``
sweeps only the named effects (of ``regulator_lag``, ``coulomb_friction``,
``position_offset``). ``--dask tcp://HOST:8786`` runs the diagnoses on that Dask
scheduler's workers instead of local processes (``pip install pmabayes[dask]`` here and
on the workers); the rows are the same.

The discrepancy part (``--discrepancy``) studies the step that estimates a missing
force outside the library (:mod:`pmabayes.criticism.discrepancy`) instead of the sweeps:

* ``--null`` null data sets (20): a proposed effect is a false alarm;
* ``--outside`` data sets (12) with one hidden effect that no library holds, cycling
  through a rail detent periodic in position, a quadratic drag and a spring acting only
  in compression (below 5 mm), each at a size drawn log-uniformly over a decade: a proposal is
  correct when the state the force depends on most is the right one (position,
  velocity, position) and the written effect, refitted (the step's own nonlinear
  check), brings the model to adequate within 1.5x the floor. As a user would, a
  data set whose diagnosis names a library effect missing (a hidden effect can look
  partly like one) has it added and is diagnosed again, once
  (``MAX_LIBRARY_ROUNDS``); the ``missing`` column lists what was named.

Writes ``discrepancy.csv`` and ``discrepancy.md``; prints
``discrepancy_false_alarm_rate`` and ``correct_proposal_rate`` last. Usage::

    python analyses/detection.py --discrepancy [--null 20] [--outside 12] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats

from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.inference.batch import dask_client
from pmabayes.parallel import Runner
from pmabayes.synthetic import (
    Chirp,
    HiddenCompressionSpring,
    HiddenDetent,
    HiddenDrag,
    draw_plausible,
    generate_chirp_dataset,
)

#: the round-one library, as the paper's detection table was made with (a user's plugins,
#: and the effects added since, would join the candidates otherwise)
CANDIDATES = ("regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
              "pressure_stiffness", "position_offset")
#: effect, parameter, unit shown, scale to that unit, sizes swept (SI)
SWEEPS = (
    ("regulator_lag", "tau_reg", "ms", 1e3, (0.05e-3, 0.1e-3, 0.2e-3, 0.5e-3)),
    ("coulomb_friction", "F_c", "N", 1.0, (0.02, 0.05, 0.1, 0.2)),
    ("position_offset", "x_offset", "µm", 1e6, (20e-6, 50e-6, 100e-6, 200e-6)),
)


def _draw(rng: np.random.Generator, chirp: Chirp, n_trials: int, effects: dict | None,
          max_refits: int) -> dict:
    """One data set's recipe, drawn in order from the study's seed."""
    truth = draw_plausible(rng)
    return {"truth": truth, "seed": int(rng.integers(2**31)), "chirp": chirp,
            "n_trials": n_trials, "effects": effects, "max_refits": max_refits}


def _run(job: dict) -> tuple[int, dict, float]:
    """Diagnose one data set (in a worker); its seed, what the study reads of the
    diagnosis (plain values, cheap to send back) and the seconds."""
    ds = generate_chirp_dataset(n_trials=job["n_trials"], seed=job["seed"], chirp=job["chirp"],
                                params=job["truth"], effects=job["effects"])
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:  # any proposal is written there, not in cwd
        d = diagnose(ds, settings=DiagnoseSettings(candidates=CANDIDATES,
                                                   max_refits=job["max_refits"]),
                     seed=job["seed"], plugin_dir=folder)
    found = {"missing": d.missing, "adequate": d.adequate,
             "ratio": d.experiments[0].signature.ratio,
             "ranking": [{"effect": f.effect, "significant": f.significant,
                          "p_value": f.p_value, "interval": dict(f.interval)}
                         for f in d.ranking]}
    return job["seed"], found, time.perf_counter() - start


# ---------------------------------------------------------------------------------
# the discrepancy part: effects in no library


#: Library effects a data set may have added (each named missing in turn) before the
#: discrepancy step is judged.
MAX_LIBRARY_ROUNDS = 1

#: effect, its size parameter, sizes drawn log-uniformly in (low, high), the state
#: its force depends on most
OUTSIDE = (
    (HiddenDetent, "F_det", (1.0, 10.0), "position"),
    (HiddenDrag, "c_hidden", (150.0, 1500.0), "velocity"),
    (HiddenCompressionSpring, "k_cs", (1500.0, 6000.0), "position"),
)


def _run_discrepancy(job: dict) -> tuple[int, dict, float]:
    """Diagnose one data set with a hidden effect outside the library (or none)."""
    effects = None
    if job["outside"] is not None:
        effect, param, _, _ = OUTSIDE[job["outside"]]
        effects = {effect: {param: job["size"]}}
    ds = generate_chirp_dataset(n_trials=job["n_trials"], seed=job["seed"], chirp=job["chirp"],
                                params=job["truth"], effects=effects)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        d, added, first_ratio = diagnose_as_a_user(
            ds, DiagnoseSettings(candidates=CANDIDATES, max_refits=job["max_refits"]),
            job["seed"], folder, MAX_LIBRARY_ROUNDS)
    disc = d.discrepancy
    prop = None if disc is None else disc.proposal
    found = {"missing": "+".join(added + ([d.missing] if d.missing else [])),
             "adequate": d.adequate, "ratio": first_ratio,
             "top_state": disc.states[0].state if disc is not None else "",
             "proposal": "" if prop is None else prop.expression,
             "verified_ratio": (prop.verified["ratio"] if prop is not None and prop.verified
                                else float("nan")),
             "verified_adequate": bool(prop is not None and prop.verified
                                       and prop.verified["adequate"])}
    return job["seed"], found, time.perf_counter() - start


def _discrepancy_study(args, chirp: Chirp, n_trials: int, n_null: int, n_outside: int,
                       rng: np.random.Generator) -> int:
    jobs = []
    for i in range(n_null):
        jobs.append(({"effect": "none", "state": "", "size": 0.0, "i": i},
                     {**_draw(rng, chirp, n_trials, None, args.max_refits), "outside": None}))
    for i in range(n_outside):
        k = i % len(OUTSIDE)
        effect, _, (lo, hi), state = OUTSIDE[k]
        size = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        jobs.append(({"effect": effect.name, "state": state, "size": size, "i": i},
                     {**_draw(rng, chirp, n_trials, None, args.max_refits), "outside": k,
                      "size": size}))
    rows = []
    with (dask_client(args.dask) if args.dask is not None
          else contextlib.nullcontext()) as client, \
            Runner(args.processes, client=client, tasks=len(jobs)) as runner:
        for (what, _), (data_seed, d, secs) in zip(
                jobs, runner.map(_run_discrepancy, [job for _, job in jobs]), strict=True):
            proposed = d["proposal"] != ""
            correct = (what["effect"] != "none" and proposed
                       and d["top_state"] == what["state"] and d["verified_adequate"]
                       and d["verified_ratio"] <= 1.5)
            rows.append({"effect": what["effect"], "size": what["size"], "seed": data_seed,
                         "missing": d["missing"] or "", "adequate": d["adequate"],
                         "ratio": d["ratio"], "top_state": d["top_state"],
                         "proposal": d["proposal"], "verified_ratio": d["verified_ratio"],
                         "verified_adequate": d["verified_adequate"], "correct": correct,
                         "seconds": secs})
            print(f"{what['effect']} size {what['size']:.4g} (seed {data_seed}): ratio "
                  f"{d['ratio']:.3g}, state {d['top_state'] or '-'}, proposal "
                  f"{d['proposal'] or '-'}, refit ratio {d['verified_ratio']:.3g}, "
                  f"correct {correct}, {secs:.0f} s", flush=True)
    write_rows(args.out / "discrepancy.csv", rows)
    null = [r for r in rows if r["effect"] == "none"]
    k_false = sum(r["proposal"] != "" for r in null)
    lines = ["| data sets | proposals | correct | rate (90% CI) |", "|---|---|---|---|"]
    if null:
        lo, hi = clopper_pearson(k_false, len(null))
        lines.append(f"| {len(null)} null | {k_false} (false alarms) | - | "
                     f"{k_false / len(null):.0%} ({lo:.0%}-{hi:.0%}) |")
    out = [r for r in rows if r["effect"] != "none"]
    for effect, *_ in OUTSIDE:
        sel = [r for r in out if r["effect"] == effect.name]
        if sel:
            k = sum(r["correct"] for r in sel)
            lines.append(f"| {len(sel)} {effect.name} | {sum(r['proposal'] != '' for r in sel)}"
                         f" | {k} | {k / len(sel):.0%} |")
    k_ok = sum(r["correct"] for r in out)
    if out:
        lo, hi = clopper_pearson(k_ok, len(out))
        lines.append(f"| {len(out)} outside the library | "
                     f"{sum(r['proposal'] != '' for r in out)} | {k_ok} | "
                     f"{k_ok / len(out):.0%} ({lo:.0%}-{hi:.0%}) |")
    (args.out / "discrepancy.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"discrepancy_false_alarm_rate: {k_false / max(len(null), 1):.3f}")
    print(f"correct_proposal_rate: {k_ok / max(len(out), 1):.3f}")
    return 0


def diagnose_as_a_user(ds, settings: DiagnoseSettings, seed: int, folder: str,
                       rounds: int) -> tuple:
    """The user's loop: a library effect named missing is added and the data diagnosed
    again (a hidden effect may look partly like one in the library), ``rounds`` times
    at most. The last diagnosis, the effects added, and the first one's ratio to the
    floor."""
    added: list[str] = []
    first_ratio = float("nan")
    for _ in range(1 + rounds):
        d = diagnose(ds, effects=added, settings=settings, seed=seed, plugin_dir=folder)
        first_ratio = first_ratio if added else d.experiments[0].signature.ratio
        if d.missing is None or d.adequate or len(added) == rounds:
            break
        added.append(d.missing)
    return d, added, first_ratio


def write_rows(path: Path, rows: list[dict]) -> None:
    """Rows as a CSV file, the first row's keys as its columns (its folder made)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def clopper_pearson(k: int, n: int, prob: float = 0.9) -> tuple[float, float]:
    """Exact binomial interval of a rate ``k / n``."""
    a = (1.0 - prob) / 2.0
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def _row(what: dict, data_seed: int, d: dict, secs: float, n_null: int) -> dict:
    """One data set's row of detection.csv, printed as it comes."""
    effect, size = what["effect"], what["size"]
    flagged = d["missing"] is not None or any(f["significant"] for f in d["ranking"])
    covered = ""
    if effect == "none":
        top = d["ranking"][0]
        print(f"null {what['i'] + 1}/{n_null} (seed {data_seed}): flagged={flagged}, "
              f"adequate={d['adequate']}, top {top['effect']} p={top['p_value']:.2g}, "
              f"{secs:.0f} s", flush=True)
    else:
        top = next((f for f in d["ranking"] if f["effect"] == effect), None)
        if d["missing"] == effect and top is not None and what["param"] in top["interval"]:
            lo, hi = top["interval"][what["param"]]
            covered = bool(lo <= size <= hi)
        print(f"{effect} {what['param']}={size * what['scale']:g} {what['unit']} (seed "
              f"{data_seed}): missing {d['missing']}, covered {covered}, RMS/floor "
              f"{d['ratio']:.3g}, {secs:.0f} s", flush=True)
    return {"effect": effect, "size": size, "seed": data_seed, "flagged": flagged,
            "missing": d["missing"] or "", "adequate": d["adequate"], "covered": covered,
            "ratio": d["ratio"], "seconds": secs}


def _write_tables(rows: list[dict], sweeps, out: Path) -> float:
    """Write detection.csv, null.md and detection.md, print the tables; the false-alarm rate."""
    write_rows(out / "detection.csv", rows)

    null = [r for r in rows if r["effect"] == "none"]
    k_flag = sum(r["flagged"] for r in null)
    k_inad = sum(not r["adequate"] for r in null)
    lo, hi = clopper_pearson(k_flag, len(null))
    null_md = [
        "| null data sets | anything flagged | judged inadequate |", "|---|---|---|",
        f"| {len(null)} | {k_flag}/{len(null)} = {k_flag / len(null):.0%} (90% CI "
        f"{lo:.0%}-{hi:.0%}) | {k_inad}/{len(null)} |",
    ]
    lines = ["| hidden effect | size | flagged | named missing: the hidden one | named: another "
             "| 90% interval covers | base RMS / floor (median) |",
             "|---|---|---|---|---|---|---|"]
    for effect, _param, unit, scale, sizes in sweeps:
        for size in sizes:
            sel = [r for r in rows if r["effect"] == effect and r["size"] == size]
            flagged = sum(r["flagged"] for r in sel)
            hit = sum(r["missing"] == effect for r in sel)
            others = sorted({r["missing"] for r in sel if r["missing"] not in ("", effect)})
            other_n = sum(r["missing"] not in ("", effect) for r in sel)
            cov = [r["covered"] for r in sel if r["covered"] != ""]
            lines.append(f"| {effect} | {size * scale:g} {unit} | {flagged}/{len(sel)} | "
                         f"{hit}/{len(sel)} | {other_n}/{len(sel)}"
                         f"{' (' + ', '.join(others) + ')' if others else ''} | "
                         f"{sum(cov)}/{len(cov)} | "
                         f"{np.median([r['ratio'] for r in sel]):.3g} |")
    (out / "null.md").write_text("\n".join(null_md) + "\n")
    (out / "detection.md").write_text("\n".join(lines) + "\n")
    print("\n".join(null_md))
    print("\n".join(lines))
    return k_flag / len(null)


def main(argv: list[str] | None = None) -> int:
    """Run the study, write the tables and print ``false_alarm_rate`` last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--null", type=int, default=None, help="null data sets (20)")
    parser.add_argument("--seeds", type=int, default=None,
                        help="data sets per effect size (5)")
    parser.add_argument("--sizes", type=int, default=None,
                        help="sizes per effect, the largest kept (all 4)")
    parser.add_argument("--effects", nargs="+", choices=[e for e, *_ in SWEEPS],
                        default=None, help="effects to sweep (all three)")
    parser.add_argument("--max-refits", type=int, default=3,
                        help="refits per diagnosis (diagnose's max_refits, 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1]
                        / "paper" / "tables")
    parser.add_argument("--quick", action="store_true", help="a small version for CI")
    parser.add_argument("--discrepancy", action="store_true",
                        help="study the discrepancy step instead of the sweeps")
    parser.add_argument("--outside", type=int, default=None,
                        help="data sets with an effect outside the library (12)")
    parser.add_argument("--processes", type=int, default=None,
                        help="local worker processes (every core by default)")
    parser.add_argument("--dask", metavar="ADDRESS", default=None,
                        help="run the diagnoses on this Dask scheduler (tcp://HOST:8786)")
    args = parser.parse_args(argv)
    if args.dask is not None and args.processes is not None:
        parser.error("give --processes or --dask, not both")
    chirp, n_trials = Chirp(duration_s=8.0, f0_hz=0.3, f1_hz=3.0), 6
    n_null, n_seeds, n_sizes = 20, 5, 4
    if args.quick:
        chirp, n_trials = Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=2.0), 4
        n_null, n_seeds, n_sizes = 3, 1, 2
    if args.discrepancy:
        n_null = (3 if args.quick else 20) if args.null is None else args.null
        n_outside = (3 if args.quick else 12) if args.outside is None else args.outside
        return _discrepancy_study(args, chirp, n_trials, n_null, n_outside,
                                  np.random.default_rng(args.seed))
    n_null = n_null if args.null is None else args.null
    n_seeds = n_seeds if args.seeds is None else args.seeds
    n_sizes = n_sizes if args.sizes is None else args.sizes
    if n_null < 1 or n_seeds < 1 or n_sizes < 1:
        parser.error("--null, --seeds and --sizes must be at least 1")
    sweeps = tuple((e, p, u, s, sizes[-n_sizes:]) for e, p, u, s, sizes in SWEEPS
                   if args.effects is None or e in args.effects)
    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    # every recipe is drawn first, in order, so the rows do not depend on who runs them
    jobs = [({"effect": "none", "size": 0.0, "i": i},
             _draw(rng, chirp, n_trials, None, args.max_refits)) for i in range(n_null)]
    for effect, param, unit, scale, sizes in sweeps:
        for size in sizes:
            for _ in range(n_seeds):
                jobs.append(({"effect": effect, "param": param, "unit": unit, "scale": scale,
                              "size": size},
                             _draw(rng, chirp, n_trials, {effect: size}, args.max_refits)))
    rows = []
    with (dask_client(args.dask) if args.dask is not None
          else contextlib.nullcontext()) as client, \
            Runner(args.processes, client=client, tasks=len(jobs)) as runner:
        for (what, _), (data_seed, d, secs) in zip(
                jobs, runner.map(_run, [job for _, job in jobs]), strict=True):
            rows.append(_row(what, data_seed, d, secs, n_null))
    false_alarm = _write_tables(rows, sweeps, args.out)
    print(f"{len(rows)} diagnoses in {time.perf_counter() - start:.0f} s")
    print(f"false_alarm_rate: {false_alarm:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
