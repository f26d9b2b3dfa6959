"""What the best intervals cover on the single records of ``calibration.py --single``.

The oracle knows the noise: the likelihood's AR(1) + white noise at the generator's
values (for ``--single record`` 20 um, lag-one correlation ``exp(-dt / 2 ms)``; for
``--single periodic`` the default 60 um and 0.1 s; and the encoder's quantisation as
white noise of ``step / sqrt(12)``). For each data set it finds the
maximum likelihood of the six physical parameters (Gauss-Newton on the Kalman-whitened
residual, :meth:`pmabayes.inference.likelihood.Likelihood.whiten`, in the sampler's log
coordinates), and reports the Wald z of the truth, ``(truth - estimate) / sd``, with
``sd`` from the inverse Fisher information ``J'J`` of the whitened residual, and the
likelihood ratio ``2 (log L(estimate) - log L(truth))``. With a right likelihood the z
are N(0, 1) and the ratio chi-squared with 6 degrees of freedom (mean 6). A fit can
at best match these z; where the oracle misses, so does any calibrated method.

Usage::

    python analyses/single_record_oracle.py --seeds 2 3 [--datasets 12]
                                            [--single {record,periodic}]
                                            [--no-quantisation] [--rows FILE]

The data sets are those of ``calibration.py --single SINGLE --seed S --datasets N``
(the same draws, in order). Prints per parameter the RMS of z and the Wald 90%
coverage, and the mean ratio; ``--rows`` writes one CSV row per data set.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
from calibration import (  # noqa: E402
    PARAMS,
    RECORD_CHIRP,
    RECORD_NOISE,
    SINGLE_MODES,
    draw_jobs,
    periodic_record,
)

from pmabayes import Model  # noqa: E402
from pmabayes.inference.likelihood import Likelihood  # noqa: E402
from pmabayes.synthetic import MeasurementNoise, generate_chirp_dataset  # noqa: E402

#: the parameters sampled in log coordinates (:mod:`pmabayes.inference.posterior`)
LOG = np.array([True, True, False, True, True, False])
#: the 90% interval's half-width in sd
Z90 = 1.6448536269514722


def true_noise(noise: MeasurementNoise, dt_s: float) -> tuple[float, float, float]:
    """The likelihood's ``(sigma, rho, white)`` that the measurement ``noise`` draws."""
    step = 0.0 if noise.encoder_counts_per_m is None else 1.0 / noise.encoder_counts_per_m
    return (noise.disturbance_std_m, math.exp(-dt_s / noise.disturbance_corr_time_s),
            max(step / math.sqrt(12.0), 1e-12))


def oracle(lik: Likelihood, truth: dict, noise: tuple[float, float, float]) -> dict:
    """Wald z of the truth and the likelihood ratio, the noise known.

    Parameters
    ----------
    lik : Likelihood
        One record's likelihood.
    truth : dict
        The physical parameters the record was made with.
    noise : tuple of float
        ``(sigma_noise_m, rho_noise, sigma_white_m)``.

    Returns
    -------
    dict
        ``z`` (per parameter of :data:`PARAMS`) and ``ratio``.
    """
    model = lik.model
    t = np.array([truth[n] for n in PARAMS])
    u_true = t.copy()
    u_true[LOG] = np.log(t[LOG])
    h = np.where(LOG, 1e-6, 1e-6 * np.abs(u_true))

    def whitened(u: np.ndarray) -> np.ndarray:
        values = np.atleast_2d(u).copy()
        values[:, LOG] = np.exp(values[:, LOG])
        x = lik.simulate(model.theta({n: values[:, j] for j, n in enumerate(PARAMS)}))
        return np.stack([lik.whiten(lik.y_mean - xb, *noise) for xb in x])

    def jac(u: np.ndarray) -> np.ndarray:
        r = whitened(np.vstack([u + np.diag(h), u - np.diag(h)]))
        return ((r[: u.size] - r[u.size:]) / (2.0 * h[:, None])).T

    sol = least_squares(lambda u: whitened(u)[0], u_true, jac=jac, method="lm",
                        xtol=1e-12, ftol=1e-12)
    cov = np.linalg.inv(jac(sol.x).T @ jac(sol.x))
    z = (u_true - sol.x) / np.sqrt(np.diag(cov))
    r_true = whitened(u_true)[0]
    return {"z": dict(zip(PARAMS, map(float, z), strict=True)),
            "ratio": float(r_true @ r_true - sol.fun @ sol.fun)}


def oracle_z(truth: dict, data_seed: int, noise: MeasurementNoise = RECORD_NOISE, *,
             single: str = "record") -> dict:
    """The oracle on one data set of ``calibration.py --single SINGLE``.

    Parameters
    ----------
    truth : dict
        The data set's physical parameters.
    data_seed : int
        Its data seed (the ``seed`` column of the study's rows).
    noise : MeasurementNoise
        Its measurement (``"record"``; a periodic record has the default one,
        :func:`calibration.periodic_record`).
    single : {"record", "periodic"}
        Which study's data set.

    Returns
    -------
    dict
        As :func:`oracle`.
    """
    if single == "periodic":
        ds = periodic_record(truth, data_seed)
        noise = MeasurementNoise()
    elif single == "record":
        ds = generate_chirp_dataset(n_trials=1, seed=data_seed, chirp=RECORD_CHIRP,
                                    noise=noise, params=truth)
    else:
        raise ValueError(f"single must be 'record' or 'periodic', got {single!r}")
    return oracle(Likelihood(Model(), ds), truth, true_noise(noise, ds.dt_s))


def main(argv: list[str] | None = None) -> int:
    """Run the oracle over the data sets and print its calibration."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    parser.add_argument("--datasets", type=int, default=12, help="data sets per seed")
    parser.add_argument("--no-quantisation", action="store_true",
                        help="the same records without the encoder's quantisation")
    parser.add_argument("--single", choices=SINGLE_MODES, default="record",
                        help="the data sets of calibration.py --single record (default) or "
                        "--single periodic")
    parser.add_argument("--rows", type=Path, default=None, help="CSV, one row per data set")
    args = parser.parse_args(argv)
    if args.no_quantisation and args.single != "record":
        parser.error("--no-quantisation applies to --single record")
    noise = (replace(RECORD_NOISE, encoder_counts_per_m=None) if args.no_quantisation
             else RECORD_NOISE)
    start = time.perf_counter()
    rows = []
    for seed in args.seeds:
        for job in draw_jobs(args.datasets, seed):
            out = oracle_z(job["truth"], job["seed"], noise, single=args.single)
            rows.append({"calibration_seed": seed, "dataset": job["index"], "seed": job["seed"],
                         "ratio": out["ratio"], **{f"z_{p}": out["z"][p] for p in PARAMS}})
    z = np.array([[r[f"z_{p}"] for p in PARAMS] for r in rows])
    n = len(rows)
    print("| parameter | oracle's Wald 90% coverage | RMS of z |\n|---|---|---|")
    for j, p in enumerate(PARAMS):
        covered = int(np.sum(np.abs(z[:, j]) < Z90))
        rms = np.sqrt(np.mean(z[:, j] ** 2))
        print(f"| `{p}` | {covered / n:.0%} ({covered}/{n}) | {rms:.2f} |")
    ratio = np.array([r["ratio"] for r in rows])
    print(f"likelihood ratio at the truth: mean {ratio.mean():.2f} (6 if the likelihood is "
          f"right, standard error {math.sqrt(12.0 / n):.2f}), {n} data sets, "
          f"{time.perf_counter() - start:.0f} s")
    if args.rows is not None:
        args.rows.parent.mkdir(parents=True, exist_ok=True)
        with open(args.rows, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
