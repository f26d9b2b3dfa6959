"""Joint fits of several experiments: does the joint MAP land in the right basin, and
are experiments that disagree told apart from ones that agree?

Each data set is two experiments of one plant, drawn with its own seed and its own
base-model parameters from ``pmabayes.synthetic.PLAUSIBLE_REGION``: a repeated chirp
on the characterisation rig (3 trials, 0.2 to 3 Hz over 4 s at 500 Hz) and a
pressure sine on the loaded control rig (2 trials, 4 periods of 1 Hz from rest),
both with an AR(1) disturbance of 20 um and 2 ms plus encoder quantisation
(``--noise default``: the package's default measurement, 60 um and 0.1 s). Their
joint MAP is found twice on the same posterior and seed: ``before``, from the joint
global search alone (``find_map(..., own_starts=False)``), and ``after``, also from
each experiment's own MAP (the default). The oracle is the joint MAP polished from
the true parameters: a MAP is in the right basin when its log posterior is within
1 of the oracle's, or above it.

``--disagree`` draws the sine from another plant (its ``K_e`` times ``--factor``,
3 by default) and counts how often the fit says the experiments disagree
(:func:`pmabayes.inference.search.experiments_agreement`; a joint fit refused as
too poor for the data, with the error saying that they disagree, counts); without
it, that count is the false alarm rate on experiments that agree.

Usage::

    python analyses/joint_fits.py [--datasets 10] [--seed 0] [--disagree]
                                  [--factor 3] [--noise {fast,default}]
                                  [--design {short,cli}] [--paper-values] [--out DIR]

Writes ``joint_fits[_disagree][_default].csv`` into ``--out`` (default
``paper/tables``) and prints one line per data set, then the fractions.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

from pmabayes import Model, simulate
from pmabayes.data import Dataset
from pmabayes.inference.errors import FitError
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.search import _noise_start, _polish_from, find_map
from pmabayes.model.model import PAPER_VALUES, Rig
from pmabayes.synthetic import Chirp, MeasurementNoise, draw_plausible, generate_chirp_dataset

#: the experiments' measurement, by ``--noise``
NOISES = {"fast": MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002),
          "default": MeasurementNoise()}
CHIRP = Chirp(duration_s=4.0, f0_hz=0.2, f1_hz=3.0, sample_rate_hz=500.0)
#: the experiments' designs, by ``--design``: ``short`` (the chirp above, 3 trials, the
#: sine at 500 Hz) or ``cli`` (``pmabayes simulate``'s default chirp, 15 s at 1 kHz and
#: 10 trials, and the sine at 1 kHz, as a user of the command line would make them)
DESIGNS = {"short": (CHIRP, 3, 500.0), "cli": (Chirp(), 10, 1000.0)}
#: the log posterior below the oracle's at which a MAP is in another basin
BASIN_TOLERANCE = 1.0


def loaded_sine(truth: dict, seed: int, noise: MeasurementNoise, *, n_trials: int = 2,
                freq_hz: float = 1.0, n_periods: int = 4, rate_hz: float = 500.0) -> Dataset:
    """Trials of a pressure sine from rest (0 to 0.4 MPa) on the loaded control rig."""
    model = Model(rig=Rig.control())
    t = np.arange(int(round(n_periods * rate_hz / freq_hz))) / rate_hz
    p = 0.2e6 * (1.0 - np.cos(2.0 * np.pi * freq_hz * t))
    x = simulate(model, truth, p, time_s=t)[0]
    y = noise.apply(np.repeat(x[None], n_trials, axis=0), 1.0 / rate_hz,
                    np.random.default_rng(seed))
    meta = {"synthetic": True, "rig": model.rig.to_dict(), "sample_rate_hz": rate_hz,
            "description": "synthetic loaded sine made by analyses/joint_fits.py"}
    return Dataset(time_s=t, input=np.repeat(p[None], n_trials, axis=0), position_m=y,
                   trial_ids=np.arange(n_trials), metadata=meta, source="sine_loaded.csv")


def experiments(truth: dict, seed: int, factor: float | None,
                noise: MeasurementNoise, design: str = "short") -> list[Dataset]:
    """The chirp and the loaded sine of one data set (the sine's ``K_e`` times
    ``factor`` when given), of a design of :data:`DESIGNS`."""
    chirp_design, n_trials, rate_hz = DESIGNS[design]
    chirp = generate_chirp_dataset(n_trials=n_trials, seed=seed, chirp=chirp_design,
                                   noise=noise, params=truth)
    chirp = Dataset(time_s=chirp.time_s, input=chirp.input, position_m=chirp.position_m,
                    trial_ids=chirp.trial_ids, metadata=chirp.metadata,
                    source="chirp_unloaded.csv")
    other = truth if factor is None else {**truth, "K_e": truth["K_e"] * factor}
    return [chirp, loaded_sine(other, seed + 1, noise, rate_hz=rate_hz)]


def oracle(posterior, truth: dict) -> float:
    """The joint log posterior polished from the true parameters (the noise started
    from the residual there)."""
    theta = np.array([[truth[n] for n in posterior.names[:posterior.n_model]]])
    z = posterior.to_unconstrained(np.hstack([theta, np.ones((1, posterior.ndim
                                                                - posterior.n_model))]))[0]
    z = _noise_start(posterior, z)
    box = posterior.plausible_box(np.random.default_rng(0), posterior.names)
    z_map, _, _ = _polish_from(posterior, z, box[:, 1] - box[:, 0])
    return float(posterior.log_prob_z(z_map[None])[0])


def study_one(k: int, seed: int, factor: float | None, noise: MeasurementNoise,
              design: str = "short", paper_values: bool = False) -> dict:
    """One data set's row: log posteriors before, after and of the oracle, the loaded
    experiment's RMS at each MAP, and the agreement verdict."""
    rng = np.random.default_rng([seed, k])
    truth = draw_plausible(rng)
    data_seed = int(rng.integers(2**31))
    if paper_values:  # drawn all the same, so that the data seeds stay those of the draws
        truth = dict(PAPER_VALUES)
    row = {"dataset": k, "seed": data_seed, **{f"true_{n}": v for n, v in truth.items()}}
    for which, own in (("before", False), ("after", True)):
        post = build_posterior(Model(), experiments(truth, data_seed, factor, noise, design))
        try:
            result = find_map(post, rng=np.random.default_rng(data_seed), own_starts=own)
        except FitError as err:  # the joint model fits so badly that the fit refuses it
            row[f"refused_{which}"] = str(err)
            if own:
                row.update(agree=False if "disagree" in str(err) else None,
                           statistic=None, df=None, p_value=None, start=None)
            continue
        row[f"refused_{which}"] = ""
        x = post.output(post.to_natural(result.z[None]))
        rms = post.likelihood.rms_costs(x)[0]
        row[f"log_posterior_{which}"] = float(post.log_prob_z(result.z[None])[0])
        row[f"rms_sine_{which}_m"] = float(rms[1])
        row[f"K_e_{which}"] = result.values["K_e"]
        if own:
            a = result.agreement
            row.update(agree=a["agree"], statistic=a["statistic"], df=a["df"],
                       p_value=a["p_value"], start=a["start"])
    if factor is None:
        row["log_posterior_oracle"] = oracle(post, truth)
        for which in ("before", "after"):
            row[f"right_{which}"] = bool(not row[f"refused_{which}"] and (
                row[f"log_posterior_{which}"] >= row["log_posterior_oracle"] - BASIN_TOLERANCE))
    return row


def main(argv: list[str] | None = None) -> int:
    """Run the study, write the rows and print the fractions."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--disagree", action="store_true",
                        help="draw the loaded sine from another plant (K_e times --factor)")
    parser.add_argument("--factor", type=float, default=3.0)
    parser.add_argument("--noise", choices=tuple(NOISES), default="fast",
                        help="the measurement: 20 um of 2 ms (fast) or 60 um of 0.1 s")
    parser.add_argument("--design", choices=tuple(DESIGNS), default="short",
                        help="the experiments: short records (short) or the command "
                        "line's default chirp (cli)")
    parser.add_argument("--paper-values", action="store_true",
                        help="every data set of the paper's plant instead of drawn ones")
    parser.add_argument("--out", type=Path, default=Path("paper/tables"))
    args = parser.parse_args(argv)
    if args.datasets < 1:
        parser.error(f"--datasets must be >= 1, got {args.datasets}")
    factor = args.factor if args.disagree else None
    rows = []
    for k in range(args.datasets):
        start = time.perf_counter()
        row = study_one(k, args.seed, factor, NOISES[args.noise], args.design,
                        args.paper_values)
        rows.append(row)
        basin = ("" if factor is not None else
                 f"right basin before={row['right_before']} after={row['right_after']}, ")
        rms = {w: (f"{row[f'rms_sine_{w}_m'] * 1e6:.3g} um" if not row[f"refused_{w}"]
                   else "refused") for w in ("before", "after")}
        print(f"data set {k + 1}/{args.datasets}: {basin}sine RMS before {rms['before']} "
              f"after {rms['after']}, agree={row['agree']} (p={row['p_value']}, start: "
              f"{row['start']}), {time.perf_counter() - start:.0f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "joint_fits" + ("_disagree" if args.disagree else "") + (
        "" if args.noise == "fast" else f"_{args.noise}") + (
        "" if args.design == "short" else f"_{args.design}") + (
        "_paper" if args.paper_values else "")
    path = args.out / f"{stem}.csv"
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)),
                                restval="")
        writer.writeheader()
        writer.writerows(rows)
    n = len(rows)
    said = sum(r["agree"] is False for r in rows)
    if factor is None:
        for which in ("before", "after"):
            k = sum(r[f"right_{which}"] for r in rows)
            print(f"right basin {which}: {k}/{n} = {k / n:.0%}")
        print(f"said to disagree (false alarms): {said}/{n} = {said / n:.0%}")
    else:
        print(f"said to disagree (K_e of the sine x{factor:g}): {said}/{n} = {said / n:.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
