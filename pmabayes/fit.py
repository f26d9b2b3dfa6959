"""Bayesian identification: point estimates and posterior sampling.

The pipeline of :func:`fit`:

0. **Noise**: ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m`` are learnt
   from the deviations of the trials from their mean, i.e. from repeatability
   alone (see :mod:`pmabayes.likelihood` for why). That gives their posterior from
   (R - 1) x n_samples values, by a Laplace approximation in (log sigma, atanh rho,
   log sigma_w). The model parameters are then identified given the noise at its
   posterior mode. The repeats also test that AR(1) + white noise model
   (:func:`pmabayes.likelihood.choose_noise_model`); where they reject it, the
   trial mean's likelihood uses their AR(p) model instead (``noise_model``).
1. **Global search** (the paper's GlobalSearch): differential evolution on the
   paper's cost, the RMS error of the trial mean, over the prior's plausible
   region (0.5% to 99.5% prior quantiles) of the model's free parameters. A noise
   sampled with the model (a record without repeats), which that cost does not
   see, starts at its posterior mode given the optimum, from its residual.
2. **Local polish** (the paper's fmincon): L-BFGS-B on the negative log
   posterior from the global optimum. This is the MAP. Gradients and the
   Hessian come from central differences evaluated in one batched simulation
   (measured again along its own eigenvectors where it comes out indefinite).
3. **Sampling**: emcee's ``EnsembleSampler``, vectorised over walkers through the
   batched simulator. Walkers start from the Laplace approximation at the MAP.
   Several independent ensembles run in parallel processes (one per core by
   default, :class:`pmabayes.parallel.Runner`), each writing an HDF5 backend so a
   killed run resumes where it stopped. A round of steps is written to a copy of
   the ensemble's file that replaces it only when complete, so a resumed run never
   reads half a round.
4. **Convergence**, judged after every round of steps. The kept chain (after
   burn-in) must be at least ``tau_multiple`` (50) integrated autocorrelation
   times long. The ESS of every parameter (walkers x kept steps / tau, summed
   over ensembles) must reach ``min_ess``. With two or more ensembles, the
   rank-normalised split R-hat across the independent ensembles must be below
   1.01. An autocorrelation time that cannot be estimated yet (a walker that has
   not moved, in a short run) counts as not converged. R-hat over walkers is also
   reported, as indicative only: emcee's walkers are coupled by the moves, so they
   are not independent chains; it is computed on the stored draws, as ArviZ
   computes it from the fit file. A run that spends its budget warns once
   (:class:`ConvergenceWarning`) and still returns what it has.

Sampling uses unconstrained coordinates: log for positive scale parameters and
atanh for the noise correlation, with the Jacobian in the density
(:class:`pmabayes.posterior.Posterior`). Results are reported in natural units.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import arviz as az
import emcee
import numpy as np
import xarray as xr
from scipy.optimize import differential_evolution, minimize

from pmabayes.data import DataError, Dataset, check_same_input_kind
from pmabayes.likelihood import (
    NOISE_PARAMETERS,
    JointLikelihood,
    Likelihood,
    LikelihoodError,
    NoiseChoice,
    check_noise_model_name,
    choose_noise_model,
)
from pmabayes.model import Model, ModelError, Rig
from pmabayes.parallel import Runner
from pmabayes.posterior import (
    NoiseEstimate,
    Posterior,
    _log_sech2,
    experiment_names,
    fit_tree,
    set_fit_info,
)
from pmabayes.trials import check_trials
from pmabayes.util import Progress, fingerprint, local_cores

__all__ = [
    "FitError",
    "ConvergenceWarning",
    "FitSettings",
    "NoiseEstimate",
    "estimate_noise",
    "Posterior",
    "MapResult",
    "find_map",
    "refer_periods",
    "fit",
]


class FitError(RuntimeError):
    """A fit cannot proceed or produced nonsense (the data does not fit the model)."""


class ConvergenceWarning(RuntimeWarning):
    """A fit spent its budget before the sampler converged (its result is still returned)."""


# ---------------------------------------------------------------------------------
# the noise, from repeatability


def estimate_noise(likelihood: Likelihood | Sequence[Likelihood]) -> NoiseEstimate:
    """Posterior of the noise parameters from the deviations of the repeats from their mean.

    The repeats are an experiment's trials, or the periods of a single periodic
    record (:attr:`pmabayes.likelihood.Likelihood.noise_source`).

    Parameters
    ----------
    likelihood : Likelihood or sequence of Likelihood
        Data and noise model; several experiments that share (tie) their noise.

    Returns
    -------
    NoiseEstimate

    Raises
    ------
    FitError
        If there are no repeats, or their spread does not identify the noise.
    """
    liks = [likelihood] if isinstance(likelihood, Likelihood) else list(likelihood)
    where = ", ".join(str(lik.dataset.source or "the data set") for lik in liks)
    liks = [lik for lik in liks if lik.n_repeats >= 2]
    if not liks:
        raise FitError(f"{where}: a single record without repeats (no second trial, no declared "
                       "periods): its noise cannot be learnt from repeats; pmabayes.fit.fit "
                       "identifies it with the model instead")
    sig_p, rho_p, white_p = NOISE_PARAMETERS

    def neg(u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u)
        sigma, rho, white = np.exp(u[:, 0]), np.tanh(u[:, 1]), np.exp(u[:, 2])
        ll = sum(lik.deviation_log_likelihood(sigma, rho, white) for lik in liks)
        lp = sig_p.log_prior(sigma) + rho_p.log_prior(rho) + white_p.log_prior(white)
        jac = u[:, 0] + u[:, 2] + _log_sech2(u[:, 1])
        v = -(ll + lp + jac)
        return np.where(np.isfinite(v), v, 1e300)

    # start from moments of the deviations: total variance, lag-one correlation, and
    # the white part from the drop of the autocorrelation at lag one
    def moment(lag: int) -> float:
        each = [float(np.mean(lik._d[:, lag:] * lik._d[:, : lik._d.shape[1] - lag]))
                * (lik.n_repeats / (lik.n_repeats - 1)) for lik in liks]
        if len(each) == 1:
            return each[0]
        sizes = [lik._d[:, lag:].size for lik in liks]
        return float(np.average(each, weights=sizes))

    u = _minimise_noise(neg, _moment_start(moment(0), moment(1), moment(2)))
    hess = _fd_hessian(neg, u, np.full(3, 1e-4))
    try:
        cov = np.linalg.inv(hess)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise FitError(f"{where}: the noise parameters "
                       "are not identified by the spread between the trials; the trials must "
                       "be repeated measurements of one input with independent noise: check "
                       "that they are not copies of one another, and record more repetitions"
                       ) from None
    return NoiseEstimate(float(np.exp(u[0])), float(np.tanh(u[1])), float(np.exp(u[2])), u, cov)


def _moment_start(var: float, c1: float, c2: float, rho_high: float = 0.9999) -> np.ndarray:
    """A start ``(log sigma, atanh rho, log sigma_w)`` for the noise from a series'
    moments: its variance ``var`` and autocovariances ``c1``, ``c2`` at lags 1 and 2.

    The disturbance's correlation from the decay of the autocovariance between lags
    1 and 2 (clipped to ``[0, rho_high]``), its variance from lag 1, and the white
    part from the drop of the autocovariance at lag one.
    """
    rho0 = float(np.clip(c2 / c1, 0.0, rho_high)) if c1 > 0 else min(0.5, rho_high)
    ar_var = min(max(c1 / max(rho0, 1e-3), 1e-3 * var), var)
    white_var = max(var - ar_var, 1e-4 * var)
    return np.array([0.5 * math.log(max(ar_var, 1e-24)), math.atanh(rho0),
                     0.5 * math.log(max(white_var, 1e-24))])


def _minimise_noise(neg, u0: np.ndarray) -> np.ndarray:
    """Minimise ``neg`` (batched) over noise coordinates from ``u0``, and from ``u0``
    with every white part ``e^2`` times smaller (it may be tiny); the better optimum."""
    best = None
    shift = np.zeros(u0.size)
    shift[2::3] = -2.0  # (log sigma, atanh rho, log sigma_w) per noise
    for start in (u0, u0 + shift):
        res = minimize(lambda u: float(neg(u)[0]), start, method="Nelder-Mead",
                       options={"xatol": 1e-9, "fatol": 1e-9, "maxiter": 6000})
        if best is None or res.fun < best.fun:
            best = res
    return best.x


def _default_noise_z(posterior: Posterior) -> np.ndarray:
    """The sampled noise parameters' defaults in unconstrained coordinates (none when
    the noise comes from repeats)."""
    theta = np.array([[p.default for p in posterior.parameters]])
    return posterior.to_unconstrained(theta)[0, posterior.n_model:]


def _noise_start(posterior: Posterior, z: np.ndarray) -> np.ndarray:
    """``z`` with the noise sampled with the model (records without repeats) set to
    its posterior mode given the model's parameters in ``z``.

    The global search's cost does not depend on the noise, so it leaves the noise
    anywhere; a polish started there can stop in a mode of the noise alone (all of
    it white, or a negative correlation) far below the posterior's. The residual of
    the search's optimum is a series of the noise (plus what misfit is left): its
    moments start the search, over the noise coordinates only, of the posterior.
    """
    cols = np.arange(posterior.n_model, posterior.ndim)
    if cols.size == 0:
        return z
    x = posterior.likelihood.simulate(posterior.full_theta(posterior.to_natural(z[None])))
    parts = (posterior.likelihood.split(x) if isinstance(posterior.likelihood, JointLikelihood)
             else [x])
    starts: dict[int, np.ndarray] = {}  # per sampled group, from its first experiment
    for e, (lik, xe) in enumerate(zip(posterior.likelihoods, parts, strict=True)):
        g = posterior.groups[e]
        if posterior.noise_sampled(e) and g not in starts:
            r = lik.y_mean - xe[0]
            c = [float(np.mean(r[k:] * r[: r.size - k])) for k in range(3)]
            starts[g] = _moment_start(*c, rho_high=0.99 * lik.rho_max)
    u0 = np.concatenate([starts[g] for g in sorted(starts)])  # the columns' order

    def neg(u: np.ndarray) -> np.ndarray:
        zz = np.repeat(z[None], np.atleast_2d(u).shape[0], axis=0)
        zz[:, cols] = np.atleast_2d(u)
        return -posterior.log_prob_z(zz)

    out = z.copy()
    out[cols] = _minimise_noise(neg, u0)
    # a correlation at its guard (a disturbance slower than the guard allows) starts
    # the polish just inside it, where its finite differences stay in the support
    rho = cols[1::3]
    edge = np.arctanh(0.99 * posterior.upper[rho])
    out[rho] = np.clip(out[rho], -edge, edge)
    return out


# ---------------------------------------------------------------------------------
# point estimates


@dataclass
class MapResult:
    """Point estimates.

    Parameters
    ----------
    values : dict
        MAP in natural units, for every identified parameter (the noise
        parameters at their mode from the deviations).
    log_posterior : float
        Log posterior density of the model parameters at the MAP (natural
        coordinates, trial-mean likelihood given the noise).
    rms_cost_m : float
        The paper's cost (RMS of trial mean minus model) at the MAP.
    global_values : dict
        The global search's optimum of the RMS cost (model parameters only).
    global_rms_cost_m : float
        The RMS cost there.
    z : numpy.ndarray
        MAP in unconstrained coordinates.
    covariance_z : numpy.ndarray
        Laplace covariance in unconstrained coordinates (inverse negative Hessian).
    period_reference_z : numpy.ndarray or None
        Where the periods of records from rest were last referred to the model
        (:func:`refer_periods`: the MAP of the pass before) before the noise was
        learnt again and the MAP polished again; None where no record needed it. A
        resumed fit rebuilds its noise from it.
    """

    values: dict
    log_posterior: float
    rms_cost_m: float
    global_values: dict
    global_rms_cost_m: float
    z: np.ndarray
    covariance_z: np.ndarray
    period_reference_z: np.ndarray | None = None

    def record(self) -> dict:
        """Everything, JSON-ready (arrays as lists), for the chains folder's stamp."""
        out = dict(self.__dict__)
        out["z"] = self.z.tolist()
        out["covariance_z"] = self.covariance_z.tolist()
        if self.period_reference_z is not None:
            out["period_reference_z"] = self.period_reference_z.tolist()
        return out

    @classmethod
    def from_record(cls, record: dict) -> MapResult:
        """The inverse of :meth:`record`."""
        ref = record.get("period_reference_z")
        return cls(**{**record, "z": np.array(record["z"]),
                      "covariance_z": np.array(record["covariance_z"]),
                      "period_reference_z": None if ref is None else np.array(ref)})

    def summary(self) -> dict:
        """The ``map`` entry of a fit's metadata."""
        return {"values": self.values, "log_posterior": self.log_posterior,
                "rms_cost_m": self.rms_cost_m,
                "global_search": {"values": self.global_values,
                                  "rms_cost_m": self.global_rms_cost_m}}


def _fd_hessian(f, u0: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Central-difference Hessian of ``f`` (batched callable) at ``u0``."""
    n = u0.size
    pts = [u0]
    for i in range(n):
        for j in range(i, n):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                u = u0.copy()
                u[i] += si * h[i]
                u[j] += sj * h[j]
                pts.append(u)
    vals = f(np.array(pts))
    hess = np.empty((n, n))
    k = 1
    for i in range(n):
        for j in range(i, n):
            pp, pm, mp_, mm = vals[k: k + 4]
            k += 4
            hess[i, j] = hess[j, i] = (pp - pm - mp_ + mm) / (4.0 * h[i] * h[j])
    return hess


#: Differential evolution's mutation strategy. ``currenttobest1bin`` moves every
#: member towards the best while keeping its own place, which keeps the population
#: spread over basins for longer than ``best1bin``: on a model with a 45 ms regulator
#: lag, where tau_reg trades off against alpha and K_e, ``best1bin`` alone landed in
#: a wrong basin in 3 of 12 seeds and ``currenttobest1bin`` in none.
_DE_STRATEGY = "currenttobest1bin"
#: The search stops when the population's RMS costs spread by at most this fraction
#: of their mean (scipy's ``tol``): the whole population is then in one basin, and
#: the local polish, not more generations, finds its bottom. Stopped so, it found
#: the right basin on 12 of 12 data sets of that lagged model (README, Speed).
_DE_TOL = 0.01


def find_map(
    posterior: Posterior,
    *,
    rng: np.random.Generator,
    popsize: int = 15,
    maxiter: int = 300,
    refer: bool = True,
) -> MapResult:
    """Global search on the paper's RMS cost, then the MAP by local polish.

    The global search is differential evolution (strategy ``currenttobest1bin``)
    over the prior's plausible box. It stops when the whole population has come
    together in one basin (the spread of its costs at most 1% of their mean), or
    after ``maxiter`` generations. A noise sampled with the model (no repeats) is
    not searched, since the cost does not depend on it: it starts at its mode
    given the search's optimum (:func:`_noise_start`). The optimum is polished
    (L-BFGS-B, then Newton steps whose Hessian gives the Laplace covariance).
    Where a periodic record starts from rest, its noise is then learnt again from
    its periods' residual at that MAP (:func:`refer_periods`), and the MAP polished
    again under that noise, until a pass moves the MAP by less than 1% of its sd
    (at most six passes).

    Parameters
    ----------
    posterior : Posterior
        The target; a record from rest's noise is updated in place.
    rng : numpy.random.Generator
        Seeds the global search.
    popsize : int
        Differential evolution population per dimension.
    maxiter : int
        Differential evolution generations at most.
    refer : bool
        Learn the noise of records from rest again at the MAP (:func:`refer_periods`).
        False keeps the posterior's noise as given: candidates compared by their
        likelihood must share one noise, or a wrong model's misfit, taken into its
        own noise, would raise its likelihood (:func:`pmabayes.criticism.diagnose`'s
        refits).

    Returns
    -------
    MapResult

    Raises
    ------
    FitError
        If no parameter set in the plausible region gives a finite simulation, or
        the best model still explains the data so badly that the data cannot be
        what the model describes (wrong units, wrong rig, wrong column).
    """
    box = posterior.plausible_box(rng, posterior.names)
    # the search's cost does not depend on a sampled noise: searched over the model's
    # parameters, it then starts the noise from the optimum's residual
    n_model = posterior.n_model
    z_model, global_cost = _global_search(posterior, box[:n_model], rng, popsize, maxiter)
    # a second search on its own stream (spawning leaves rng's draws as they were): a
    # short record can hold a second basin of the hysteresis loop's shape (beta and
    # gamma traded at a near-constant beta + gamma), where one search may end
    z_other, other_cost = _global_search(posterior, box[:n_model], rng.spawn(1)[0], popsize,
                                         maxiter)
    if other_cost < (1.0 - _OTHER_BASIN) * global_cost:
        z_model, global_cost = z_other, other_cost
    z_global = _noise_start(posterior, np.concatenate([z_model, _default_noise_z(posterior)]))
    # optimise in coordinates scaled to the plausible box
    scale = box[:, 1] - box[:, 0]
    z_map, cov_z = _polish_from(posterior, z_global, scale)
    # the periods of a record from rest still hold the model's shakedown: the noise
    # is learnt again from the residual's periods, and the MAP polished again, until
    # the MAP settles (a first MAP under the inflated noise misses the drift)
    reference = None
    for k in range(_REFER_PASSES if refer else 0):
        if not refer_periods(posterior, z_map):
            break
        reference = z_map
        z_map, cov_z = _polish_from(posterior, reference, scale)
        moved = np.max(np.abs(z_map - reference) / np.sqrt(np.diag(cov_z)))
        if k > 0 and moved < _REFER_SETTLED:
            break
    theta_map = posterior.to_natural(z_map[None])
    lp, ll, x = posterior.evaluate(theta_map)
    cost = _check_fit_quality(posterior.likelihood, x[0])
    values = dict(zip(posterior.names, map(float, theta_map[0]), strict=True))
    values.update(posterior.noise_values(theta_map[0]))
    return MapResult(
        values=values,
        log_posterior=float(lp[0] + ll[0]),
        rms_cost_m=cost,
        global_values=dict(zip(posterior.names, map(float, posterior.to_natural(
            z_global[None])[0]), strict=True)),
        global_rms_cost_m=global_cost,
        z=z_map,
        covariance_z=cov_z,
        period_reference_z=reference,
    )


def _polish_from(posterior: Posterior, z0: np.ndarray, scale: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The MAP polished from ``z0`` in coordinates scaled by ``scale``, and its Laplace
    covariance, both unconstrained."""
    neg_logpost = _scaled_neg_log_posterior(posterior, z0, scale)
    u, hess = _polish(neg_logpost, posterior.ndim)
    return z0 + u * scale, _laplace_covariance(hess, neg_logpost, u) * np.outer(scale, scale)


#: Most passes of learning a record from rest's noise from its periods' residual at
#: the MAP and polishing the MAP again (:func:`refer_periods`); they stop once a pass
#: moves the MAP by under ``_REFER_SETTLED`` of its Laplace sd. On the periodic
#: calibration records three passes took the noise from 195 um (the shakedown of
#: 5.7 mm between periods 2 and 3 read as noise) to 61.6 um (60 um drawn).
_REFER_PASSES = 6
_REFER_SETTLED = 0.01

#: how much lower (relative) the second global search's cost must be to replace the
#: first's: a different basin, not the same one met to the search's tolerance
_OTHER_BASIN = 0.01


def _global_search(posterior: Posterior, box: np.ndarray, rng: np.random.Generator,
                   popsize: int, maxiter: int) -> tuple[np.ndarray, float]:
    """Differential evolution on the paper's RMS cost; the optimum and its cost."""
    lik = posterior.likelihood
    rest = _default_noise_z(posterior)  # the cost does not depend on a sampled noise

    def rms(z: np.ndarray) -> np.ndarray:
        z = np.hstack([z, np.repeat(rest[None], z.shape[0], axis=0)])
        theta = posterior.to_natural(z)
        lp = posterior.log_prior(theta)
        out = np.full(theta.shape[0], 1.0)  # 1 m: worse than anything real
        ok = np.isfinite(lp)
        if ok.any():
            x = lik.simulate(posterior.full_theta(theta[ok]))
            cost = lik.rms_cost(x)
            out[ok] = np.where(np.isfinite(cost), cost, 1.0)
        return out

    best = differential_evolution(
        lambda zt: rms(np.atleast_2d(zt.T)), bounds=list(map(tuple, box)),
        popsize=popsize, maxiter=maxiter, tol=_DE_TOL, seed=rng, polish=False,
        vectorized=True, updating="deferred", init="latinhypercube", strategy=_DE_STRATEGY,
    )
    global_cost = float(best.fun)
    if global_cost >= 1.0:
        raise FitError("no parameter set in the prior's plausible region gives a finite "
                       "simulation of this data; check the data's units and the rig")
    return best.x, global_cost


def _scaled_neg_log_posterior(posterior: Posterior, z0: np.ndarray, scale: np.ndarray):
    """The negative log posterior of ``z0 + u * scale``, batched over rows of ``u``."""

    def neg_logpost(u: np.ndarray) -> np.ndarray:
        z = z0 + np.atleast_2d(u) * scale
        theta = posterior.to_natural(z)
        lp, ll, _ = posterior.evaluate(theta)
        v = -(lp + ll)
        return np.where(np.isfinite(v), v, 1e300)

    return neg_logpost


def _polish(neg_logpost, ndim: int) -> tuple[np.ndarray, np.ndarray]:
    """L-BFGS-B from ``u = 0``, then Newton steps; the optimum and the Hessian there."""
    h = np.full(ndim, 1e-7)

    def fun_and_grad(u: np.ndarray) -> tuple[float, np.ndarray]:
        pts = np.vstack([u, u + np.diag(h), u - np.diag(h)])
        vals = neg_logpost(pts)
        grad = (vals[1: ndim + 1] - vals[ndim + 1:]) / (2 * h)
        return float(vals[0]), np.where(np.isfinite(grad), grad, 0.0)

    u = np.zeros(ndim)
    for _ in range(3):  # restart: the first pass also learns the curvature's scale
        res = minimize(fun_and_grad, u, jac=True, method="L-BFGS-B",
                       options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-9})
        if np.allclose(res.x, u, rtol=0, atol=1e-12):
            break
        u = res.x
    # Newton polish with the finite-difference Hessian, whose inverse is the
    # Laplace covariance
    for _ in range(5):
        hess = _scaled_hessian(neg_logpost, u)
        f0, g0 = fun_and_grad(u)
        try:
            step = -np.linalg.solve(hess, g0)
        except np.linalg.LinAlgError:
            break
        t = 1.0
        while t > 1e-4 and float(neg_logpost((u + t * step)[None])[0]) > f0:
            t *= 0.5
        if t <= 1e-4:
            break
        u = u + t * step
        if np.max(np.abs(t * step) * np.sqrt(np.abs(np.diag(hess)))) < 1e-3:
            break
    return u, _scaled_hessian(neg_logpost, u)


def _scaled_hessian(neg_logpost, u: np.ndarray) -> np.ndarray:
    """The Hessian at ``u``, with steps of 0.2 of the curvature's length scale."""
    hd = np.abs(np.diag(_fd_hessian(neg_logpost, u, np.full(u.size, 1e-6))))
    return _fd_hessian(neg_logpost, u, 0.2 / np.sqrt(np.where(hd > 0, hd, 1.0)))


def _laplace_covariance(hess: np.ndarray, neg_logpost=None, u: np.ndarray | None = None,
                        passes: int = 2) -> np.ndarray:
    """The inverse Hessian, or a diagonal stand-in where that is not a covariance.

    A posterior whose parameters are strongly correlated has curvatures many orders
    of magnitude apart; steps along the axes measure its flattest directions with
    the rounding of its steepest, and the Hessian may come out indefinite. Given
    ``neg_logpost`` and the point ``u``, the Hessian is then measured again (up to
    ``passes`` times) along its own eigenvectors, each with steps of 0.2 of that
    direction's curvature length, where it is near the identity, before the
    diagonal stand-in (which drops the correlations) is taken.
    """
    h = hess
    for k in range(passes + 1):
        if not np.all(np.isfinite(h)):  # a step left the support: nothing to refine
            break
        try:
            cov = np.linalg.inv(h)
            np.linalg.cholesky(cov)
            return cov
        except np.linalg.LinAlgError:
            if neg_logpost is None or k == passes:
                break
        lam, vec = np.linalg.eigh(h)
        lam = np.abs(lam)
        if not lam.max() > 0:
            break
        t = vec / np.sqrt(np.maximum(lam, 1e-12 * lam.max()))  # columns: unit curvature

        def along(w: np.ndarray, t=t) -> np.ndarray:
            return neg_logpost(u + np.atleast_2d(w) @ t.T)

        hw = _fd_hessian(along, np.zeros(u.size), np.full(u.size, 0.2))
        tinv = np.linalg.inv(t)
        h = tinv.T @ hw @ tinv
    return np.diag(1.0 / np.where(np.diag(hess) > 0, np.diag(hess), 1e6))


def _check_fit_quality(lik: Likelihood | JointLikelihood, x: np.ndarray) -> float:
    """The RMS cost of the MAP's output ``x``, refused when the data cannot be this model's.

    For several experiments, each is judged on its own part of ``x``, and the
    combined cost (:meth:`JointLikelihood.rms_cost`) is returned.
    """
    parts = (zip(lik.likelihoods, lik.split(x), strict=True) if isinstance(lik, JointLikelihood)
             else [(lik, x)])
    for one, xe in parts:
        cost = float(one.rms_cost(xe)[0])
        if not np.isfinite(cost) or cost > 0.25 * np.ptp(one.y_mean):
            raise FitError(
                f"{one.dataset.source or 'the data'}: the best fit leaves an RMS error of "
                f"{cost * 1e3:.3g} mm on a motion of {np.ptp(one.y_mean) * 1e3:.3g} mm, so the "
                "data cannot be what this model describes. Check the units (positions in m, "
                "pressure in Pa), that the input column is the commanded input, and the rig "
                "(masses, gravity direction)."
            )
    return float(lik.rms_cost(np.atleast_2d(x))[0])


# ---------------------------------------------------------------------------------
# sampling: the ensembles, one HDF5 file each


@dataclass(frozen=True)
class FitSettings:
    """How to sample.

    Parameters
    ----------
    n_walkers : int
        Walkers per ensemble, at least twice the number of parameters: the
        default, 24, allows 12 (the base model with every built-in effect, or
        with three one-parameter effects on a single record, whose noise is
        sampled too); larger models need more. The run's length is set by
        ``tau_multiple``, not by ``min_ess``: on the bundled data 2 x 24 walkers
        reach an ESS of about 1,100 where 400 is asked, so more walkers than the
        parameters need cost time and buy ESS no one asked for.
    n_ensembles : int
        Independent ensembles (R-hat across them needs two or more).
    max_steps : int
        Budget of steps per ensemble.
    max_seconds : float or None
        Budget of wall time for sampling.
    check_every : int
        Steps between convergence checks: a run stops at most this many steps
        after it has converged.
    tau_multiple : float
        Required kept chain length in integrated autocorrelation times, each
        estimated on the whole kept chain (the burn-in, three of them, dropped),
        averaged over the ensemble's walkers. At 20 the estimate of ``tau`` runs
        somewhat short (on the bundled data 14-16 steps at the 400 steps where the
        run stops, against 18-21 from 1,100 steps), and the ESS, about
        ``n_walkers * n_ensembles * 20`` (reported 1,100, at least 850 with the
        longer run's ``tau``), stays well above ``min_ess``; R-hat across the
        independent ensembles guards against a chain that has not mixed. The
        calibration study (README, Calibration) checks the intervals at this
        setting.
    min_ess : float
        Required effective sample size of every parameter.
    max_rhat : float
        Required R-hat across ensembles (when there are several).
    processes : int or None
        Parallel processes for the ensembles (default: one per ensemble, at most
        the number of cores).
    ppc_draws : int
        Posterior draws stored in the posterior predictive.
    moves : str
        ``"de"`` (differential-evolution moves, 80% DEMove and 20% DESnookerMove;
        shorter autocorrelation times on these near-Gaussian posteriors) or
        ``"stretch"`` (emcee's default).
    progress : bool
        Print progress to stderr.
    """

    n_walkers: int = 24
    n_ensembles: int = 2
    max_steps: int = 20000
    max_seconds: float | None = None
    check_every: int = 100
    tau_multiple: float = 20.0
    min_ess: float = 400.0
    max_rhat: float = 1.01
    processes: int | None = None
    ppc_draws: int = 40
    moves: str = "de"
    progress: bool = False


_WORKER_POSTERIOR: Posterior | None = None


def _init_worker(posterior: Posterior) -> None:
    global _WORKER_POSTERIOR
    _WORKER_POSTERIOR = posterior


def _moves(kind: str):
    if kind == "stretch":
        return None  # emcee's default StretchMove
    if kind == "de":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    raise FitError(f"unknown moves {kind!r}; use 'de' or 'stretch'")


def _advance(job: tuple) -> int:
    """Advance one ensemble by ``n_steps`` and append them to its HDF5 file.

    ``job`` is ``(path, n_steps, initial, seed, moves)``. The file has emcee's
    ``HDFBackend`` layout (readable with ``emcee.backends.HDFBackend(path,
    name="mcmc")``) and records the random state after every round, so a run
    resumed from it continues exactly as an uninterrupted one. Steps run in
    memory and are written once per round: emcee's backend reopens the file at
    every step, which costs more than a step. The round is written to a copy that
    replaces the file only when complete: a process killed mid-write leaves the
    last complete round behind, never half of one.
    """
    path, n_steps, initial, seed, moves = job
    posterior = _WORKER_POSTERIOR
    tmp = path + ".tmp"
    if os.path.exists(path):
        shutil.copyfile(path, tmp)
    elif os.path.exists(tmp):
        os.remove(tmp)  # the debris of a round that never completed
    store = emcee.backends.HDFBackend(tmp, name="mcmc")
    if store.initialized and store.iteration > 0:
        state = store.get_last_sample()
    else:
        # emcee has no seed argument: its RandomState comes from our seed
        state = emcee.State(initial, random_state=np.random.RandomState(seed).get_state())
        store.reset(initial.shape[0], posterior.ndim)
    if n_steps <= 0:  # already ahead (another ensemble's round was cut short)
        done = store.iteration  # read before the copy it reads from goes
        os.remove(tmp)
        return done
    sampler = emcee.EnsembleSampler(state.coords.shape[0], posterior.ndim,
                                    posterior.log_prob_z, vectorize=True, moves=_moves(moves))
    final = sampler.run_mcmc(state, n_steps, progress=False)
    store.grow(n_steps, None)
    with store.open("a") as f:
        g = f[store.name]
        it = int(g.attrs["iteration"])
        g["chain"][it: it + n_steps] = sampler.get_chain()
        g["log_prob"][it: it + n_steps] = sampler.get_log_prob()
        g["accepted"][:] += sampler.backend.accepted
        for i, v in enumerate(final.random_state):
            g.attrs[f"random_state_{i}"] = v
        g.attrs["iteration"] = it + n_steps
    os.replace(tmp, path)  # the commit
    return it + n_steps


class _Chains:
    """A chains folder: the stamp ``fit.json`` (fingerprint and MAP) and one HDF5
    file per ensemble. The folder is made only when the MAP is there to stamp."""

    def __init__(self, folder: Path, n_ensembles: int, key: str) -> None:
        self.folder = folder
        self.key = key
        self.stamp = folder / "fit.json"
        self.paths = [str(folder / f"ensemble_{e}.h5") for e in range(n_ensembles)]

    def _files(self) -> list[str]:
        return [p + s for p in self.paths for s in ("", ".tmp")]

    def clear(self) -> None:
        """Discard the chains and the stamp (a restart)."""
        for p in [*self._files(), str(self.stamp)]:
            if os.path.exists(p):
                os.remove(p)

    def saved_map(self) -> tuple[MapResult, float] | None:
        """The stamped MAP and its time, or None for a fresh start."""
        if not self.stamp.exists():
            return None
        saved = json.loads(self.stamp.read_text())
        if saved.get("fingerprint") != self.key:
            raise FitError(
                f"{self.folder} holds chains of a different fit (other data, model, seed or "
                "sampler settings); pass restart=True (--restart) or choose another output"
            )
        return MapResult.from_record(saved["map"]), saved["timings_s"]["map"]

    def start(self, map_result: MapResult, t_map: float) -> None:
        """Stamp a fresh start (atomically), discarding chains of any earlier one."""
        self.folder.mkdir(parents=True, exist_ok=True)
        for p in self._files():
            if os.path.exists(p):
                os.remove(p)
        tmp = self.stamp.with_name(self.stamp.name + ".tmp")
        tmp.write_text(json.dumps({"fingerprint": self.key, "map": map_result.record(),
                                   "timings_s": {"map": t_map}}, indent=1))
        os.replace(tmp, self.stamp)

    def iterations(self) -> list[int]:
        """Completed steps of each ensemble."""
        return [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).iteration
                if os.path.exists(p) else 0 for p in self.paths]

    def read(self) -> list[np.ndarray]:
        """Every ensemble's chain ``(steps, walkers, ndim)``."""
        return [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).get_chain()
                for p in self.paths]

    def kept(self, diag: _Diagnostics) -> tuple[np.ndarray, np.ndarray]:
        """Kept draws ``(chain, draw, ndim)`` and their log density ``(chain, draw)``:
        burn-in dropped, thinned, a chain per walker, ensemble after ensemble."""
        zs, lps = [], []
        for p in self.paths:
            b = emcee.backends.HDFBackend(p, name="mcmc", read_only=True)
            zs.append(b.get_chain(discard=diag.burn, thin=diag.thin)[
                : (diag.n_steps - diag.burn) // diag.thin])
            lps.append(b.get_log_prob(discard=diag.burn, thin=diag.thin)[: zs[-1].shape[0]])
        n_draw = min(z.shape[0] for z in zs)
        z = np.concatenate([zz[:n_draw].transpose(1, 0, 2) for zz in zs])
        lp_z = np.concatenate([ll[:n_draw].T for ll in lps])
        return z, lp_z


@contextlib.contextmanager
def _chains_folder(chains_dir: str | Path | None) -> Iterator[Path]:
    """The folder for the chains: a temporary one when none is given. A failure
    before any chain is written leaves no folder this call made."""
    if chains_dir is None:
        with tempfile.TemporaryDirectory(prefix="pmabayes-chains-") as tmp:
            yield Path(tmp)
        return
    folder = Path(chains_dir)
    existed = folder.exists()
    try:
        yield folder
    except BaseException:
        if not existed and folder.is_dir() and not any(folder.glob("ensemble_*.h5")):
            shutil.rmtree(folder, ignore_errors=True)
        raise


@dataclass
class _Diagnostics:
    converged: bool
    messages: list
    burn: int
    thin: int
    tau: np.ndarray
    ess: np.ndarray
    rhat_ensembles: np.ndarray | None
    n_steps: int

    def record(self, settings: FitSettings, names, rhat: np.ndarray, resumed: bool) -> dict:
        """The ``convergence`` entry of a fit's metadata (undefined values as None)."""

        def named(values):
            return None if values is None else {
                n: (float(v) if np.isfinite(v) else None)
                for n, v in zip(names, values, strict=True)}

        return {"converged": self.converged, "messages": self.messages,
                "n_ensembles": settings.n_ensembles, "n_walkers": settings.n_walkers,
                "n_steps": self.n_steps, "burn": self.burn, "thin": self.thin,
                "tau": named(self.tau), "ess": named(self.ess), "rhat": named(rhat),
                "rhat_ensembles": named(self.rhat_ensembles),
                "min_ess": settings.min_ess, "tau_multiple": settings.tau_multiple,
                "resumed": resumed}


def _convergence(chains: list[np.ndarray], names, settings: FitSettings) -> _Diagnostics:
    """Convergence of ensembles' chains ``(steps, walkers, ndim)`` (unconstrained)."""
    n = min(c.shape[0] for c in chains)
    ndim = chains[0].shape[2]
    names = np.array(names)
    # tau from the second half (past any transient), per ensemble and parameter; NaN
    # where a walker has not moved there (nothing to estimate it from yet)
    with np.errstate(invalid="ignore", divide="ignore"):
        taus = np.array([
            emcee.autocorr.integrated_time(c[n // 2: n], tol=0, quiet=True) for c in chains
        ])
    tau = taus.max(axis=0)
    undefined = ~np.isfinite(tau)
    tau_max = float(tau[~undefined].max()) if not undefined.all() else float(n)
    burn = n // 2 if undefined.any() else min(int(math.ceil(3 * tau_max)), n // 2)
    kept = n - burn
    if burn < n // 2:
        # re-estimated on the whole kept chain: a short window underestimates tau
        with np.errstate(invalid="ignore", divide="ignore"):
            taus = np.array([emcee.autocorr.integrated_time(c[burn:n], tol=0, quiet=True)
                             for c in chains])
        tau = np.fmax(taus.max(axis=0), tau)
        undefined = ~np.isfinite(tau)
        tau_max = float(tau[~undefined].max()) if not undefined.all() else float(n)
    ess = np.sum([c.shape[1] * kept / t for c, t in zip(chains, taus, strict=True)], axis=0)
    kept_chains = [c[burn:n] for c in chains]
    rhat_ens = None
    if len(chains) > 1:
        per_ens = np.stack([k.reshape(-1, ndim) for k in kept_chains])  # step-major
        rhat_ens = np.array([float(az.rhat(per_ens[:, :, j], method="rank"))
                             for j in range(ndim)])
    messages = []
    if undefined.any():
        messages.append(
            f"the autocorrelation time of {', '.join(names[undefined])} cannot be estimated "
            f"yet (a walker has not moved in the last {n - n // 2} of {n} steps); the run is "
            "too short to judge"
        )
    short = kept < settings.tau_multiple * tau  # False where tau is undefined
    if short.any():
        messages.append(
            f"kept chain of {kept} steps is shorter than {settings.tau_multiple:g} "
            f"autocorrelation times for {', '.join(names[short])} "
            f"(tau up to {tau_max:.0f} steps)"
        )
    low = ess < settings.min_ess
    if low.any():
        messages.append(
            f"ESS below {settings.min_ess:g} for "
            + ", ".join(f"{nm} ({e:.0f})" for nm, e in zip(names[low], ess[low], strict=True))
        )
    # R-hat is defined across independent ensembles; emcee's walkers are coupled
    # by the moves, so their R-hat is reported as indicative only
    if rhat_ens is not None and (rhat_ens >= settings.max_rhat).any():
        bad = rhat_ens >= settings.max_rhat
        messages.append(
            f"R-hat across ensembles at or above {settings.max_rhat} for "
            + ", ".join(f"{nm} ({r:.4f})" for nm, r in zip(names[bad], rhat_ens[bad],
                                                           strict=True))
        )
    # stored draws: thinned by at least tau/2 and to about 8000 in all (convergence
    # and ESS are judged on the full chain; the store feeds summaries and LOO)
    n_chains = sum(c.shape[1] for c in chains)
    thin = max(1, int(tau_max // 2), math.ceil(kept * n_chains / 8000))
    return _Diagnostics(not messages, messages, burn, thin, tau, ess, rhat_ens, n)


def _walker_rhat(theta: np.ndarray) -> np.ndarray:
    """Rank-normalised split R-hat over walkers of stored draws ``(chain, draw, ndim)``
    in natural units: the value ArviZ computes from the fit file."""
    return np.array([float(az.rhat(theta[:, :, j], method="rank"))
                     for j in range(theta.shape[2])])


def _fingerprint(posterior: Posterior, settings: FitSettings, seed) -> str:
    """What makes chains resumable: the data, the models, the noise, the seed and the
    ensembles."""
    liks = posterior.likelihoods
    model = posterior.model
    extra = {"model": model.describe(), "rig": model.rig.to_dict(),
             "effects": model.effect_names, "seed": seed, "n_walkers": settings.n_walkers,
             "n_ensembles": settings.n_ensembles, "substeps": liks[0].substeps}
    if len(liks) > 1 or posterior.noise_sampled(0):
        # a fit of one experiment with repeats keeps the fingerprint it always had
        extra.update(rigs=[lik.model.rig.to_dict() for lik in liks],
                     names=posterior.experiment_names, groups=posterior.groups,
                     sampled_noise=list(posterior.names[posterior.n_model:]))
    if any(lik.ar_noise is not None for lik in liks):
        # chains of an AR(1) + white likelihood are not those of an AR(p) one
        extra["noise_models"] = [None if lik.ar_noise is None
                                 else lik.ar_noise.autocovariance_m2.tolist() for lik in liks]
    arrays = [a for lik in liks for a in (lik.dataset.position_m, lik.input)]
    return fingerprint(*arrays, extra)


def _round_line(diag: _Diagnostics, settings: FitSettings, seconds: float) -> str:
    """One progress line: a bar towards convergence (the run stops when the chain is
    long enough, not at a known step count) and where the run stands."""
    tau = diag.tau[np.isfinite(diag.tau)]
    tau_max = float(tau.max()) if tau.size else math.nan
    kept = diag.n_steps - diag.burn
    ess_min = float(np.nanmin(diag.ess)) if np.isfinite(diag.ess).any() else 0.0
    frac = min(1.0, kept / (settings.tau_multiple * tau_max), ess_min / settings.min_ess)
    bar = "#" * int(round(20 * frac)) if np.isfinite(frac) else ""
    needed = (f"{kept} of {settings.tau_multiple * tau_max:.0f} steps needed "
              f"({settings.tau_multiple:g} x tau {tau_max:.0f})" if tau.size == diag.tau.size
              else f"{kept} steps (tau cannot be estimated yet)")
    return (f"[{bar:-<20}] step {diag.n_steps} (budget {settings.max_steps}) x "
            f"{settings.n_ensembles} ensembles x {settings.n_walkers} walkers: kept "
            f"{needed}, ESS min {ess_min:.0f}"
            + (f", R-hat across ensembles max {diag.rhat_ensembles.max():.4f}"
               if diag.rhat_ensembles is not None else "")
            + f", {seconds:.0f} s")


def _sample_rounds(posterior: Posterior, chains: _Chains, initials: list[np.ndarray],
                   ens_seeds: list[int], settings: FitSettings, runner: Runner,
                   say: Progress) -> _Diagnostics:
    """Advance all ensembles round by round until converged or out of budget."""
    t_sample = time.perf_counter()
    diag = None
    while True:
        done = chains.iterations()
        n_done = min(done)
        budget_left = settings.max_steps - n_done
        if diag is not None and (diag.converged or budget_left <= 0):
            break
        elapsed = time.perf_counter() - t_sample
        if diag is not None and settings.max_seconds and elapsed > settings.max_seconds:
            break
        step = min(settings.check_every, budget_left) if budget_left > 0 else 0
        if step > 0:
            jobs = [(p, step - (d - n_done), initials[e] if d == 0 else None, ens_seeds[e],
                     settings.moves)
                    for e, (p, d) in enumerate(zip(chains.paths, done, strict=True))]
            for _ in runner.map(_advance, jobs):
                pass
        current = chains.read()
        if min(c.shape[0] for c in current) < 20:
            continue
        diag = _convergence(current, posterior.names, settings)
        say.say(_round_line(diag, settings, time.perf_counter() - t_sample))
        if step == 0:
            break
    return diag


def fit(
    datasets: Dataset | Sequence[Dataset],
    model: Model | None = None,
    *,
    seed: int | None = 0,
    settings: FitSettings | None = None,
    chains_dir: str | Path | None = None,
    restart: bool = False,
    substeps: int = 1,
    tie_noise: bool = False,
    noise_model: str = "auto",
) -> xr.DataTree:
    """Identify a model's parameters from one or more experiments: MAP, then posterior.

    Each data set is an experiment: its own input, length, rig (its metadata's
    ``rig``) and trials (one or more). The physical parameters are shared; the
    noise belongs to each experiment unless ``tie_noise``. An experiment's noise is
    learnt from its repeats (trials, or the periods of a single periodic record);
    a record without repeats has it identified jointly with the model under a guard
    (see :mod:`pmabayes.likelihood`).

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        The experiments, all with the same kind of input (pressure or force).
    model : Model, optional
        The model (effects, priors, fixed values); the base model by default. With
        one experiment it is used as given. With several, each experiment gets it
        on the rig its metadata records (``Model.for_dataset``), or on the
        model's rig where the metadata records none.
    seed : int or None
        Seed of everything random (global search, walkers, emcee, predictive
        noise). The same seed gives the same numbers, to the bit.
    settings : FitSettings, optional
        Sampler settings.
    chains_dir : str or Path, optional
        Where the ensembles' HDF5 chains live. A run pointed at the chains of an
        interrupted run with the same data, model, seed and settings resumes them;
        without it a temporary folder is used. It is made once the MAP is found,
        and a failure before any chain is written removes it again.
    restart : bool
        Discard existing chains in ``chains_dir`` instead of resuming.
    substeps : int
        Simulator substeps per sample.
    tie_noise : bool
        One noise for all experiments (same sensor, same disturbance) instead of
        one per experiment.
    noise_model : {"auto", "ar1", "ar"}
        The noise model of the trial mean's likelihood where the noise comes from
        repeats (:func:`pmabayes.likelihood.choose_noise_model`): ``"auto"`` keeps
        AR(1) + white unless the repeats' deviations reject it (then their AR(p)
        model), ``"ar1"`` always keeps it, ``"ar"`` always uses the AR(p). Records
        without repeats keep the sampled AR(1) + white under its guard. The fit
        file records each experiment's (``experiments[i]["noise_model"]``).

    Returns
    -------
    xarray.DataTree
        The fit (layout in :mod:`pmabayes.posterior`).

    Raises
    ------
    FitError
        When the data cannot be fitted, the experiments' inputs are of different
        kinds, or the chains belong to another fit.

    Warns
    -----
    ConvergenceWarning
        Once, when the budget ran out before the sampler converged.
    """
    start = time.perf_counter()
    settings = FitSettings() if settings is None else settings
    model = Model() if model is None else model
    posterior = _posterior(model, datasets, substeps, tie_noise=tie_noise,
                           noise_model=noise_model)
    _check_settings(settings, posterior)
    s_map, s_walkers, s_ppc = np.random.SeedSequence(seed).spawn(3)
    ens_seeds = [int(s.generate_state(1)[0]) for s in s_walkers.spawn(settings.n_ensembles)]
    say = Progress("fit", settings.progress)
    for name, lik, choice in zip(posterior.experiment_names, posterior.likelihoods,
                                 posterior.noise_choices, strict=True):
        if lik.n_repeats >= 2:
            say.say(f"noise of {name}: {choice.describe()}")
    with _chains_folder(chains_dir) as folder:
        chains = _Chains(folder, settings.n_ensembles,
                         _fingerprint(posterior, settings, seed))
        if restart:
            chains.clear()
        map_result, t_map, resumed = _map_or_resume(chains, posterior, s_map, say, start)
        initials = _initial_walkers(posterior, map_result, ens_seeds, settings.n_walkers)
        t_sample = time.perf_counter()
        n_proc = settings.processes or min(settings.n_ensembles, local_cores())
        with Runner(n_proc, initializer=_init_worker, initargs=(posterior,),
                    tasks=settings.n_ensembles) as runner:
            _sample_rounds(posterior, chains, initials, ens_seeds, settings, runner, say)
        t_sampling = time.perf_counter() - t_sample
        diag = _convergence(chains.read(), posterior.names, settings)
        z, lp_z = chains.kept(diag)
    _warn_if_not_converged(diag)
    ensemble = np.repeat(np.arange(settings.n_ensembles), settings.n_walkers)
    tree = fit_tree(posterior, z, lp_z, ensemble, ppc_draws=settings.ppc_draws,
                    rng=np.random.default_rng(s_ppc))
    theta = posterior.to_natural(z.reshape(-1, posterior.ndim))
    rhat = _walker_rhat(theta.reshape(z.shape))
    # a noise sampled with the model is recorded at its posterior median (robust where
    # the MAP's noise is poorly polished); a noise from repeats at its mode
    noise = (posterior.noise_values(np.median(theta, axis=0))
             if any(posterior.noise_sampled(e) for e in range(posterior.n_experiments))
             else None)
    set_fit_info(tree, posterior, map_record=map_result.summary(),
                 convergence=diag.record(settings, posterior.names, rhat, resumed), seed=seed,
                 timings={"map": t_map, "sampling": t_sampling,
                          "total": time.perf_counter() - start}, noise_values=noise)
    return tree


def _posterior(model: Model, datasets, substeps: int, *, tie_noise: bool = False,
               noise_model: str = "auto") -> Posterior:
    """The posterior to sample: a likelihood per experiment, each noise group's
    estimate from its repeats (None where it has none: sampled with the model), and
    the noise model each group's repeats choose (``noise_model``)."""
    try:
        check_noise_model_name(noise_model)
    except ValueError as err:
        raise FitError(str(err)) from None
    datasets = [datasets] if isinstance(datasets, Dataset) else list(datasets)
    if not datasets:
        raise FitError("no data: give at least one data set")
    for ds in datasets:
        if not isinstance(ds, Dataset):
            raise TypeError(f"datasets must be pmabayes.data.Dataset objects, got "
                            f"{type(ds).__name__}")
    try:
        check_same_input_kind(datasets)
    except DataError as err:
        raise FitError(str(err)) from None
    names = experiment_names([ds.source for ds in datasets])
    try:
        models = [model] if len(datasets) == 1 else [_on_rig(model, ds) for ds in datasets]
        liks = [Likelihood(m, ds, substeps=substeps)
                for m, ds in zip(models, datasets, strict=True)]
    except (LikelihoodError, ModelError) as exc:
        raise FitError(str(exc)) from None
    for ds in datasets:  # before their spread is taken for noise
        check_trials(ds, warn=True)
    groups = [0] * len(liks) if tie_noise else list(range(len(liks)))
    noises = []
    choices: list[NoiseChoice | None] = [None] * len(liks)
    for g in range(max(groups) + 1):
        est, choice = _group_noise([lik for lik, gg in zip(liks, groups, strict=True)
                                    if gg == g], noise_model)
        noises.append(est)
        for e, gg in enumerate(groups):
            if gg == g:
                choices[e] = choice
    return Posterior(liks, noises, names=names, noise_groups=groups, noise_choices=choices)


def _group_noise(members: list[Likelihood], noise_model: str
                 ) -> tuple[NoiseEstimate | None, NoiseChoice]:
    """A noise group's estimate from its repeats (None without any) and its noise model,
    which its likelihoods are set to use."""
    est = (estimate_noise(members) if any(lik.n_repeats >= 2 for lik in members)
           else None)
    # the repeats test AR(1) + white; where they reject it the trial mean's
    # likelihood uses their AR(p) (fixed, as the AR(1) noise from repeats is)
    choice = (choose_noise_model(members, est.sigma, est.rho, est.white, noise_model)
              if est is not None else NoiseChoice(noise_model, None, math.nan))
    for lik in members:
        lik.use_ar_noise(choice.ar)
    return est, choice


def refer_periods(posterior: Posterior, z: np.ndarray) -> bool:
    """Learn the noise of records from rest from their periods' residual at ``z``.

    Each experiment whose noise comes from the periods of a record that starts
    from rest (:attr:`pmabayes.likelihood.Likelihood.periods_from_rest`) takes its
    periods from the residual at ``z``
    (:meth:`~pmabayes.likelihood.Likelihood.refer_periods_to`), and the noise of its
    group is estimated again, its noise model chosen again as first requested.
    Other experiments keep theirs.

    Parameters
    ----------
    posterior : Posterior
        Updated in place (:meth:`~pmabayes.posterior.Posterior.set_group_noise`).
    z : numpy.ndarray
        The point, in unconstrained coordinates ``(ndim,)``: a MAP.

    Returns
    -------
    bool
        Whether any experiment's periods were referred to the model.
    """
    liks = posterior.likelihoods
    shaken = [e for e, lik in enumerate(liks) if lik.periods_from_rest]
    if not shaken:
        return False
    full = posterior.full_theta(posterior.to_natural(np.asarray(z, dtype=float)[None]))
    for e in shaken:
        liks[e].refer_periods_to(liks[e].simulate(full)[0])
    for g in sorted({posterior.groups[e] for e in shaken}):
        members = [e for e, gg in enumerate(posterior.groups) if gg == g]
        est, choice = _group_noise([liks[e] for e in members],
                                   posterior.noise_choices[members[0]].requested)
        posterior.set_group_noise(g, est, choice)
    return True


def _on_rig(model: Model, dataset: Dataset) -> Model:
    """``model`` (effects, priors, fixed values) on the rig the data set's metadata
    records, or on its own rig where it records none."""
    rig_meta = dataset.metadata.get("rig") if dataset.metadata else None
    if not isinstance(rig_meta, dict):
        return model
    try:
        rig = Rig.from_dict(rig_meta)
    except ModelError as err:  # name the file: the rig comes from its sidecar
        raise ModelError(f"{dataset.source or 'data set'}: metadata 'rig': {err}") from None
    kept_priors = {n: p for n, p in model.priors.items() if p is not model.parameter(n).prior}
    return Model(model.effects, rig=rig, priors=kept_priors, fixed=dict(model.fixed),
                 free=model.free_names)


def _check_settings(settings: FitSettings, posterior: Posterior) -> None:
    if settings.max_steps < 20:
        raise FitError(f"max_steps must be at least 20 (the autocorrelation time needs a "
                       f"chain), got {settings.max_steps}")
    if settings.n_walkers < 2 * posterior.ndim:
        raise FitError(f"n_walkers must be at least {2 * posterior.ndim} (twice the "
                       f"{posterior.ndim} parameters), got {settings.n_walkers}")
    if settings.n_ensembles < 1:
        raise FitError(f"n_ensembles must be at least 1 (2 or more for R-hat across "
                       f"ensembles), got {settings.n_ensembles}")


def _map_or_resume(chains: _Chains, posterior: Posterior, seed: np.random.SeedSequence,
                   say: Progress, start: float) -> tuple[MapResult, float, bool]:
    """The stamped MAP of resumable chains, or a fresh MAP that starts new ones."""
    saved = chains.saved_map()
    if saved is not None:
        say.say(f"resuming the chains in {chains.folder}")
        if saved[0].period_reference_z is not None:  # the noise the chains were run with
            refer_periods(posterior, saved[0].period_reference_z)
        return (*saved, True)
    say.say("global search and MAP ...")
    map_result = find_map(posterior, rng=np.random.default_rng(seed))
    t_map = time.perf_counter() - start
    say.say(f"MAP in {t_map:.1f} s: RMS cost {map_result.rms_cost_m * 1e6:.1f} um "
            f"(global search {map_result.global_rms_cost_m * 1e6:.1f} um)")
    if map_result.period_reference_z is not None:
        for name, lik, choice in zip(posterior.experiment_names, posterior.likelihoods,
                                     posterior.noise_choices, strict=True):
            if lik.periods_referred:
                say.say(f"noise of {name} from its periods' residual at the MAP (the "
                        f"model's shakedown from rest removed): {choice.describe()}")
    chains.start(map_result, t_map)
    return map_result, t_map, False


def _initial_walkers(posterior: Posterior, map_result: MapResult, ens_seeds: list[int],
                     n_walkers: int) -> list[np.ndarray]:
    """Each ensemble's walkers, drawn from the Laplace approximation at the MAP."""
    initials = []
    for seed in ens_seeds:
        rng = np.random.default_rng(seed)
        pts = rng.multivariate_normal(map_result.z, map_result.covariance_z,
                                      size=n_walkers, method="eigh")
        lp = posterior.log_prob_z(pts)
        for _ in range(100):  # redraw any walker that starts outside the support
            bad = ~np.isfinite(lp)
            if not bad.any():
                break
            pts[bad] = rng.multivariate_normal(map_result.z, 0.25 * map_result.covariance_z,
                                               size=int(bad.sum()), method="eigh")
            lp[bad] = posterior.log_prob_z(pts[bad])
        initials.append(pts)
    return initials


def _warn_if_not_converged(diag: _Diagnostics) -> None:
    # said once, as a warning: a caller that reports it its own way (the CLI's
    # banner) filters ConvergenceWarning
    if not diag.converged:
        warnings.warn(
            "pmabayes fit did NOT converge: " + "; ".join(diag.messages)
            + ". The result is saved anyway; run longer (more steps) before trusting it.",
            ConvergenceWarning, stacklevel=3,
        )
