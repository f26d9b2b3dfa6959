"""Where one round of ``diagnose`` spends its time on real measurements: the base model's
MAP, then each candidate's refit one after another in this process, and each global
search's length.

Real measurements of Higueras-Ruiz, Shafer and Feigenbaum (the cavatappi muscle,
Science Robotics 2021): one sample's 100, 300 and 500 g loads together, the model with
``--effects`` (by default the round that sample 2's loop ran third). The round is the
one ``pmabayes diagnose`` runs, with its settings, but the refits run here, serially
(``processes=1``), so each one's own time shows; ``diagnose`` runs them in worker
processes, side by side. Every differential-evolution search is recorded: its
generations (at most 300) and its best RMS cost after 50, 100, 150 generations and at
its end, which says whether stopping it sooner would give the same optimum.

A benchmark, not a test: the data stay in ``../shared/external/real/cavatappi``
(read-only, never copied); the sidecars and links go into ``--out``. The times and each
refit's ΔELPD are printed, the figure ``total_seconds`` last.

Usage::

    python analyses/refit_times.py [--sample 2] [--effects A,B] [--seed 0] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import time
import warnings
from pathlib import Path

import numpy as np
from real_cavatappi import TRAIN_G, declare

import pmabayes.inference.search as search
from pmabayes.criticism import diagnosis, refits
from pmabayes.criticism.scores import rank_effects
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.data import load
from pmabayes.inference.posterior import choose_substeps
from pmabayes.util import Progress

#: generations after which a search's best cost is printed
MARKS = (50, 100, 150)


def _recording(searches: list) -> None:
    """Record each differential-evolution search's best cost per generation into
    ``searches`` (one list each); the search itself is unchanged."""
    de = search.differential_evolution

    @functools.wraps(de)
    def recorded(*args, **kwargs):
        costs: list[float] = []
        searches.append(costs)
        shown = kwargs.get("callback")

        def callback(intermediate_result):
            costs.append(float(intermediate_result.fun))
            if shown is not None:
                shown(intermediate_result)

        kwargs["callback"] = callback
        return de(*args, **kwargs)

    search.differential_evolution = recorded


def _searches_text(searches: list) -> list[str]:
    """One line per search: its generations and its best cost (µm) at the marks."""
    lines = []
    for costs in searches:
        marks = ", ".join(f"{costs[min(g, len(costs)) - 1] * 1e6:.1f} @{g}" for g in MARKS)
        lines.append(f"    {len(costs):3d} generations; best RMS cost {marks}, "
                     f"{costs[-1] * 1e6:.1f} µm at its end")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sample", type=int, default=2, choices=(1, 2))
    ap.add_argument("--effects", default="maxwell_creep,force_length_map",
                    help="the diagnosed model's effects (comma-separated)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("refit_times"))
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    paths = declare(args.out, args.sample)
    warnings.simplefilter("ignore")  # the files' notes are diagnose's, said there
    datasets = [load(paths[g]) for g in TRAIN_G]
    effects = [e for e in args.effects.split(",") if e]
    s = DiagnoseSettings(processes=1)
    datasets, models, names = diagnosis._experiments(datasets, None, effects)
    s = dataclasses.replace(s, substeps=choose_substeps(models, datasets)["chosen"])
    searches: list = []
    _recording(searches)
    rng = np.random.default_rng(args.seed)
    started = time.perf_counter()
    base = refits.fit_base(models, datasets, names, s, rng)
    print(f"MAP of base + {' + '.join(effects)} and its ELPD: "
          f"{time.perf_counter() - started:.0f} s, {len(searches)} global searches")
    print("\n".join(_searches_text(searches)), flush=True)
    ranked = rank_effects(base.likelihoods, base.noises, [own for own, _ in base.points],
                          candidates=s.candidates, level=s.level,
                          starts=[start for _, start in base.points])
    took: dict[str, float] = {}
    refit = refits._refit

    def timed(base_fit, effect, settings, stream):
        searches.clear()
        t0 = time.perf_counter()
        out = refit(base_fit, effect, settings, stream)
        took[effect] = time.perf_counter() - t0
        print(f"refit with {effect}: {took[effect]:.0f} s, {len(searches)} global searches")
        print("\n".join(_searches_text(searches)), flush=True)
        return out

    refits._refit = timed
    t0 = time.perf_counter()
    done = refits.refit_significant(base, ranked, s, rng, Progress("refit_times"))
    total_refits = time.perf_counter() - t0
    for name, r in done.items():
        print(f"  {name}: ΔELPD {r.elpd_diff:+.1f} ± {r.elpd_diff_se:.1f}, "
              f"RMS {r.rms_m * 1e6:.1f} µm")
    print(f"refits one after another: {sum(took.values()):.0f} s; with the checks of "
          f"left-out loads: {total_refits:.0f} s")
    print(f"total_seconds: {time.perf_counter() - started:.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
