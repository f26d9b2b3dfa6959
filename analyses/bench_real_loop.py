"""Wall and CPU time of the user's loop on real measurements: the cavatappi muscle of
Higueras-Ruiz, Shafer and Feigenbaum (Science Robotics 2021), one sample's five dead
loads, read as the lab logged them (13,400-16,500 samples each at 1 kHz, gaps in the
clock).

The loop, as :mod:`real_loads` runs it and a user would, each step one ``pmabayes``
command in its own process (numba's kernels loaded from the disk cache, as a user's
are after the first run):

1. ``pmabayes diagnose`` of the 100, 300 and 500 g loads together, at most ``--rounds``
   times (three by default), adding the effect each names (``missing``, else its
   partial step), while it names a new one;
2. ``pmabayes fit`` of the three loads with the effects found (``--steps``, 48 walkers,
   as :mod:`real_loads`);
3. ``pmabayes validate`` of that fit on the held-out 200 and 400 g loads;
4. ``pmabayes fit`` of one load alone (300 g) with the same effects.

The targets: steps 1-3 under 15 minutes on this machine, step 4 under 2. The
machine may be shared, so each step's CPU time (the command's and its worker
processes') is printed beside its wall time: it is the honest figure. Each command runs
under :mod:`cProfile` (not with ``--no-profile``, which gives the times a user sees);
the table of where the time goes (the package's stages, from the profile of the
command's own process: the sampler's ensembles run in worker processes and show only
as the time waited for them) is printed per step, and the top entries of the slowest
step's profile. ``total_seconds: <wall> (CPU <cpu>)`` is printed last. A
benchmark, not a test: the data stay in ``../shared/external/real/cavatappi``
(read-only, never copied); the sidecars, links, fits and profiles go into ``--out``.

Usage::

    python analyses/bench_real_loop.py [--sample 1] [--rounds 3] [--steps 600]
        [--effects A,B] [--out DIR] [--seed 0] [--top 25] [--only fit_one] [--warm]
        [--no-profile]

``--effects maxwell_creep,force_length_map --rounds 0`` times the final fit, the
validation and the fit of one load with the effects sample 1's diagnoses named, without
diagnosing.
"""

from __future__ import annotations

import argparse
import io
import json
import pstats
import resource
import subprocess
import sys
import time
from pathlib import Path

from real_cavatappi import HELD_OUT_G, TRAIN_G, declare, named_effect, rows_of

#: the load fitted alone in the last step: between the held-out loads
ONE_G = 300

#: stages of a command whose cumulative time is reported: (module file, function, label)
STAGES = (("search.py", "_global_search", "global searches (differential evolution)"),
          ("search.py", "_polish_from", "local polishes (L-BFGS-B, Newton, Laplace)"),
          ("search.py", "_own_optima", "  of which each experiment's own MAP"),
          ("search.py", "_best_of_starts", "  of which polishes from the own MAPs"),
          ("search.py", "_climb", "  of which the climb from Laplace draws"),
          ("disturbance.py", "settle_disturbance", "slow-disturbance check"),
          ("sampler.py", "_sample_rounds", "sampling (waiting for the ensembles)"),
          ("fitfile.py", "fit_tree", "fit file (posterior predictive, log likelihood)"),
          ("refits.py", "fit_base", "diagnose: MAP of the diagnosed model, ELPD"),
          ("scores.py", "rank_effects", "diagnose: score tests"),
          ("refits.py", "refit_significant", "diagnose: refits of the candidates"),
          ("diagnosis.py", "_discrepancy_step", "diagnose: discrepancy step"),
          ("diagnosis.py", "_yardsticks", "diagnose: yardsticks"),
          ("validation.py", "validate", "validate"),
          ("simulator.py", "simulate_dataset", "simulations (all calls)"),
          ("likelihood.py", "mean_log_likelihood", "likelihoods (all calls)"))


def _children_cpu() -> float:
    """CPU time (user + system) of the finished child processes and their children."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: compiles the simulator's kernels of each composition given (one per line of stdin:
#: comma-separated effects) on a training load, as a user's are cached after a first run
WARM = """
import sys, warnings
from pmabayes.data import load
from pmabayes.model.model import Model
from pmabayes.model.simulator import simulate_dataset
warnings.simplefilter("ignore")
ds = load(sys.argv[1])
for line in sys.stdin.read().split():
    model = Model.for_dataset(ds, effects=[e for e in line.split(",") if e])
    simulate_dataset(model, None, ds)
    simulate_dataset(model, None, ds, states=True)
"""


def warm(path: Path, effects: list[str], out: Path) -> float:
    """Compile (or load from the disk cache) the kernels of the base model with
    ``effects`` and with each registered effect added, outside the timed steps; its wall
    time."""
    started = time.perf_counter()
    names = subprocess.run([sys.executable, "-c", "from pmabayes.model.effects import "
                            "registered_effects; print(' '.join(registered_effects()))"],
                           cwd=out, capture_output=True, text=True, check=True).stdout.split()
    lines = [",".join(effects)] + [",".join([*effects, n]) for n in names if n not in effects]
    subprocess.run([sys.executable, "-c", WARM, str(path)], input="\n".join(lines) + "\n",
                   cwd=out, capture_output=True, text=True, check=True)
    return time.perf_counter() - started


def run(name: str, args: list[str], out: Path, profile: bool = True) -> dict:
    """Run one pmabayes command (under cProfile unless ``profile`` is false) in its own
    process; its wall and CPU time.

    Parameters
    ----------
    name : str
        The step's name (the profile is ``out/NAME.prof``).
    args : list of str
        The command and its arguments.
    out : Path
        Folder of the profile and the command's stderr (``NAME.log``).
    profile : bool
        Profile the command (which slows its Python parts).

    Returns
    -------
    dict
        ``name``, ``command``, ``wall_s``, ``cpu_s`` and ``profile`` (its path, or None).
    """
    prof = out / f"{name}.prof" if profile else None
    print("$ pmabayes " + " ".join(args), flush=True)
    profiler = ["-m", "cProfile", "-o", str(prof)] if profile else []
    cpu, wall = _children_cpu(), time.perf_counter()
    with open(out / f"{name}.log", "w") as log:
        done = subprocess.run([sys.executable, *profiler, "-m", "pmabayes", *args], cwd=out,
                              stdout=log, stderr=log, check=False)
    wall, cpu = time.perf_counter() - wall, _children_cpu() - cpu
    if done.returncode != 0:
        raise SystemExit(f"pmabayes {args[0]} failed (exit status {done.returncode}); see "
                         f"{out / f'{name}.log'}")
    print(f"  {name}: wall {wall:.1f} s, CPU {cpu:.1f} s", flush=True)
    return {"name": name, "command": "pmabayes " + " ".join(args), "wall_s": wall,
            "cpu_s": cpu, "profile": prof}


def stages(profile: Path) -> list[str]:
    """Cumulative time of each of :data:`STAGES` found in a command's profile."""
    stats = pstats.Stats(str(profile)).stats
    lines = []
    for file, func, label in STAGES:
        hits = [v for (f, _, fn), v in stats.items() if f.endswith(file) and fn == func]
        if hits:
            # the outermost call's cumulative time: a recursive function (find_map's own
            # optima call it again) is counted once
            lines.append(f"    {label:<50s} {max(v[3] for v in hits):8.1f} s "
                         f"({sum(v[1] for v in hits)} calls)")
    return lines


def top(profile: Path, n: int) -> str:
    """The ``n`` entries of a profile with the most internal time."""
    text = io.StringIO()
    pstats.Stats(str(profile), stream=text).sort_stats("tottime").print_stats(n)
    return "\n".join(line for line in text.getvalue().splitlines()[6:] if line.strip())


def loop(paths: dict[int, Path], out: Path, args) -> tuple[list[dict], list[str], list[dict]]:
    """The timed steps: the diagnoses, the final fit, the validation, the fit of one."""
    train = [str(paths[g]) for g in TRAIN_G]
    held = [str(paths[g]) for g in HELD_OUT_G]
    seed, quiet = ["--seed", str(args.seed)], ["--quiet"]
    effects = [e for e in args.effects.split(",") if e]
    steps: list[dict] = []
    only = set(args.only.split(",")) if args.only else None
    for round_ in range(args.rounds):
        if only is not None and "diagnose" not in only:
            break
        fx = ["--effects", ",".join(effects)] if effects else []
        diag = out / f"diagnose_{round_}.json"
        steps.append(run(f"diagnose_{round_}", ["diagnose", *train, "--json", str(diag), *fx,
                                                "--proposal-dir", str(out), *seed, *quiet], out,
                         args.profile))
        d = json.loads(diag.read_text())
        print(f"  verdict: {d['verdict']}", flush=True)
        effect = named_effect(d, effects)
        if effect is None:
            break
        effects.append(effect)
    fx = ["--effects", ",".join(effects)] if effects else []
    sampler = ["--steps", str(args.steps), "--walkers", "48", *seed, *quiet]
    rows: list[dict] = []
    if only is None or "fit" in only or "validate" in only:
        fit = out / "fit_final.nc"
        steps.append(run("fit", ["fit", *train, "--out", str(fit), "--restart", *fx, *sampler],
                         out, args.profile))
        val = out / "validate_final.json"
        steps.append(run("validate", ["validate", str(fit), *held, "--json", str(val),
                                      "--draws", "200", *seed, *quiet], out, args.profile))
        rows = rows_of(json.loads(val.read_text()), "+".join(["base", *effects]))
    if only is None or "fit_one" in only:
        steps.append(run("fit_one", ["fit", str(paths[ONE_G]), "--out",
                                     str(out / f"fit_{ONE_G}g.nc"), "--restart", *fx,
                                     *sampler], out, args.profile))
    return steps, effects, rows


def main(argv: list[str] | None = None) -> int:
    """Run the loop and print each step's time, where it goes, and the total last."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sample", type=int, default=1, help="which sample (1)")
    ap.add_argument("--rounds", type=int, default=3, help="most diagnose rounds (3)")
    ap.add_argument("--steps", type=int, default=600, help="sampler steps of the fits (600)")
    ap.add_argument("--effects", default="", help="effects to start from")
    ap.add_argument("--out", type=Path, default=Path("bench_real_loop"),
                    help="folder of the sidecars, links, fits, logs and profiles")
    ap.add_argument("--seed", type=int, default=0, help="seed of every command (0)")
    ap.add_argument("--top", type=int, default=25,
                    help="profile entries shown for the slowest step (25)")
    ap.add_argument("--only", default="",
                    help="only these steps (diagnose, fit, validate, fit_one; comma-separated)")
    ap.add_argument("--warm", action="store_true",
                    help="compile the kernels of the starting effects, and of each registered "
                         "effect added to them, before the clock starts")
    ap.add_argument("--no-profile", dest="profile", action="store_false",
                    help="run the commands without the profiler (no table of where the time "
                         "goes)")
    args = ap.parse_args(argv)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    paths = declare(out, args.sample)
    if args.warm:
        took = warm(paths[TRAIN_G[0]], [e for e in args.effects.split(",") if e], out)
        print(f"kernels compiled or loaded from the cache beforehand: {took:.0f} s")
    steps, effects, rows = loop(paths, out, args)
    print(f"\nsample {args.sample}: effects {', '.join(effects) or 'none'}")
    for r in rows:
        print(f"  held out {r['held_out']}: NRMSE {r['nrmse']:.3f} (linear "
              f"{r['linear_nrmse']:.3f}, play {r['play_nrmse']:.3f}, narx "
              f"{r['narx_nrmse']:.3f}), 90% band {100 * r['coverage']:.1f}%")
    if args.profile:
        print("\nwhere the time goes (wall, under the profiler, the command's own process):")
        for s in steps:
            print(f"  {s['name']}: wall {s['wall_s']:.1f} s, CPU {s['cpu_s']:.1f} s")
            print("\n".join(stages(s["profile"])))
        slowest = max(steps, key=lambda s: s["cpu_s"])
        print(f"\ntop {args.top} entries by internal time of the slowest step "
              f"({slowest['name']}):")
        print(top(slowest["profile"], args.top))
    loop_steps = [s for s in steps if s["name"] != "fit_one"]
    print("\nstep              wall (s)   CPU (s)")
    for s in steps:
        print(f"{s['name']:<16s} {s['wall_s']:9.1f} {s['cpu_s']:9.1f}")
    print(f"loop (target < 900 s): wall {sum(s['wall_s'] for s in loop_steps):.1f} s, CPU "
          f"{sum(s['cpu_s'] for s in loop_steps):.1f} s")
    print(f"total_seconds: {sum(s['wall_s'] for s in steps):.1f} "
          f"(CPU {sum(s['cpu_s'] for s in steps):.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
