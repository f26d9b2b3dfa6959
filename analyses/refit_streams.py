"""How much a candidate's refit moves with its random stream, on real measurements: the
cavatappi muscle of Higueras-Ruiz, Shafer and Feigenbaum (Science Robotics 2021), one
sample's 100, 300 and 500 g loads together.

``diagnose`` gives each refit its own stream spawned from the seed. This fits the
diagnosed model once (``--effects``, seed 0, as ``pmabayes diagnose --seed 0``), then
refits each candidate (``--candidates``) on ``--streams`` other streams, each as
``diagnose`` refits it (``--searches`` global searches, one by default, and polishes
from the model's MAP), and
leaves each load out in turn for the model and for each refit
(:func:`pmabayes.criticism.transfer.leave_experiments_out`). It prints one row per
refit: the stream, the ΔELPD with its standard error, the in-sample witness, the NRMSE
of each load left out and their geometric-mean ratio to the model's (below 1: the
effect carries to loads it was not fitted to), and the seconds it took; the spread
of the ΔELPD over the streams, per candidate, is printed last.

The data stay in ``../shared/external/real/cavatappi`` (read-only, never copied); the
sidecars and links go into ``--out``.

Usage::

    python analyses/refit_streams.py [--sample 1] [--effects force_length_map]
        [--candidates maxwell_creep,stribeck_friction] [--streams 3] [--searches 1]
        [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from real_cavatappi import TRAIN_G, declare

from pmabayes.criticism import refits
from pmabayes.criticism.diagnosis import _experiments
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.criticism.transfer import leave_experiments_out
from pmabayes.data import read_csv
from pmabayes.inference.posterior import choose_substeps


def _names(text: str) -> list[str]:
    return [n for n in text.split(",") if n]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sample", type=int, default=1)
    ap.add_argument("--effects", type=_names, default=["force_length_map"])
    ap.add_argument("--candidates", type=_names,
                    default=["maxwell_creep", "stribeck_friction", "pressure_hysteresis"])
    ap.add_argument("--streams", type=int, default=3, help="refit streams per candidate")
    ap.add_argument("--searches", type=int, default=1, choices=(1, 2),
                    help="global searches per refit (DiagnoseSettings.refit_searches)")
    ap.add_argument("--out", type=Path, default=None, help="folder for the sidecars")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="refit_streams_"))
    out.mkdir(parents=True, exist_ok=True)
    files = declare(out, args.sample)
    with warnings.catch_warnings():  # the files' conversions, said once by the loop
        warnings.simplefilter("ignore")
        data = [read_csv(files[g]) for g in TRAIN_G]
    datasets, models, names = _experiments(data, None, args.effects)
    s = DiagnoseSettings(refit_searches=args.searches)
    s = dataclasses.replace(s, substeps=choose_substeps(models, datasets)["chosen"])
    start = time.time()
    base = refits.fit_base(models, datasets, names, s, np.random.default_rng(0))
    model = np.array(leave_experiments_out(
        base.likelihoods, base.repeat_noise, base.names, base.noise_choices, base.values,
        substeps=s.substeps, rng=np.random.default_rng(1)))
    print(f"model {' + '.join(['base', *args.effects])}: fitted in "
          f"{time.time() - start:.0f} s; each load left out, NRMSE "
          + ", ".join(f"{n} {v:.3f}" for n, v in zip(names, model, strict=True)), flush=True)
    print("candidate            stream  dELPD +- se          witness    left out (NRMSE)"
          "            ratio   s", flush=True)
    spread: dict[str, list[float]] = {}
    for effect in args.candidates:
        for stream in range(args.streams):
            t = time.time()
            r = refits._refit(base, effect, s, np.random.default_rng([args.sample, stream]))
            left = np.array(leave_experiments_out(
                refits._extended(base, effect, s.substeps), base.repeat_noise, base.names,
                base.noise_choices, r.values, substeps=s.substeps,
                rng=np.random.default_rng(1)))
            ratio = float(np.exp(np.nanmean(np.log(left / model))))
            spread.setdefault(effect, []).append(r.elpd_diff)
            failed = " (search failed)" if r.failed else ""
            print(f"{effect:20s} {stream:6d}  {r.elpd_diff:+9.0f} +- {r.elpd_diff_se:6.0f}  "
                  f"{r.plugin_diff:+9.0f}  {' '.join(f'{v:.3f}' for v in left):26s}  "
                  f"{ratio:5.2f}  {time.time() - t:4.0f}{failed}", flush=True)
    for effect, values in spread.items():
        print(f"{effect}: dELPD from {min(values):+.0f} to {max(values):+.0f} over "
              f"{len(values)} streams")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
