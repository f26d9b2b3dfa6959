"""Bayesian identification: point estimates and posterior sampling.

The pipeline of :func:`fit`:

0. **Noise**: ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m`` are learnt
   from the deviations of the trials from their mean, i.e. from repeatability
   alone (see :mod:`pmabayes.likelihood` for why). That gives their posterior from
   (R - 1) x n_samples values, by a Laplace approximation in (log sigma, atanh rho,
   log sigma_w). The model parameters are then identified given the noise at its
   posterior mode.
1. **Global search** (the paper's GlobalSearch): differential evolution on the
   paper's cost, the RMS error of the trial mean, over the prior's plausible
   region (0.5% to 99.5% prior quantiles) of the model's free parameters.
2. **Local polish** (the paper's fmincon): L-BFGS-B on the negative log
   posterior from the global optimum. This is the MAP. Gradients and the
   Hessian come from central differences evaluated in one batched simulation.
3. **Sampling**: emcee's ``EnsembleSampler``, vectorised over walkers through the
   batched simulator. Walkers start from the Laplace approximation at the MAP.
   Several independent ensembles run in parallel processes (one per core by
   default), each writing an HDF5 backend so a killed run resumes where it stopped.
4. **Convergence**, judged after every round of steps. The kept chain (after
   burn-in) must be at least ``tau_multiple`` (50) integrated autocorrelation
   times long. The ESS of every parameter (walkers x kept steps / tau, summed
   over ensembles) must reach ``min_ess``. With two or more ensembles, the
   rank-normalised split R-hat across the independent ensembles must be below
   1.01. R-hat over walkers is also reported, as indicative only: emcee's walkers
   are coupled by the moves, so they are not independent chains. A run that
   spends its budget first warns loudly and still returns (and saves) what it
   has.

Sampling uses unconstrained coordinates: log for positive scale parameters and
atanh for the noise correlation, with the Jacobian in the density. Results are
reported in natural units.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing as mp
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np
import xarray as xr
from scipy.optimize import differential_evolution, minimize

from pmabayes import __version__
from pmabayes.data import Dataset
from pmabayes.likelihood import NOISE_PARAMETERS, Likelihood, LikelihoodError
from pmabayes.model import PAPER_VALUES, Model
from pmabayes.parameters import HalfNormal, LogNormal, Parameter, Prior

__all__ = [
    "FitError",
    "FitSettings",
    "NoiseEstimate",
    "estimate_noise",
    "Posterior",
    "MapResult",
    "find_map",
    "fit",
]


class FitError(RuntimeError):
    """A fit cannot proceed or produced nonsense (the data does not fit the model)."""


# ---------------------------------------------------------------------------------
# the posterior in unconstrained coordinates


def _log_sech2(z: np.ndarray) -> np.ndarray:
    """``log(1 - tanh(z)^2) = -2 log cosh z``, without overflow: the log Jacobian of
    the atanh coordinate."""
    a = np.abs(z)
    return -2.0 * (a + np.log1p(np.exp(-2.0 * a)) - math.log(2.0))


def _transform_kind(p: Parameter, prior: Prior) -> str:
    if p.name == "rho_noise":
        return "atanh"
    if p.bounds[0] >= 0.0 and isinstance(prior, LogNormal | HalfNormal):
        return "log"
    return "identity"


@dataclass(frozen=True)
class NoiseEstimate:
    """The noise parameters' posterior from the spread between repeated trials.

    Parameters
    ----------
    sigma, rho, white : float
        Posterior mode of ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m``.
    mean_u : numpy.ndarray
        Mode in ``(log sigma, atanh rho, log white)``.
    cov_u : numpy.ndarray
        Laplace covariance there.
    """

    sigma: float
    rho: float
    white: float
    mean_u: np.ndarray
    cov_u: np.ndarray

    def draws(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
        """``n`` independent posterior draws of ``(sigma, rho, white)``."""
        u = rng.multivariate_normal(self.mean_u, self.cov_u, size=n, method="eigh")
        return np.exp(u[:, 0]), np.tanh(u[:, 1]), np.exp(u[:, 2])


def estimate_noise(likelihood: Likelihood) -> NoiseEstimate:
    """Posterior of the noise parameters from the deviations from the trial mean.

    Parameters
    ----------
    likelihood : Likelihood
        Data and noise model.

    Returns
    -------
    NoiseEstimate

    Raises
    ------
    FitError
        If the spread between trials does not identify the noise.
    """
    sig_p, rho_p, white_p = NOISE_PARAMETERS

    def neg(u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u)
        sigma, rho, white = np.exp(u[:, 0]), np.tanh(u[:, 1]), np.exp(u[:, 2])
        ll = likelihood.deviation_log_likelihood(sigma, rho, white)
        lp = sig_p.log_prior(sigma) + rho_p.log_prior(rho) + white_p.log_prior(white)
        jac = u[:, 0] + u[:, 2] + _log_sech2(u[:, 1])
        v = -(ll + lp + jac)
        return np.where(np.isfinite(v), v, 1e300)

    # start from moments of the deviations: total variance, lag-one correlation, and
    # the white part from the drop of the autocorrelation at lag one
    d = likelihood._d
    scale = likelihood.n_trials / (likelihood.n_trials - 1)
    var = float(np.mean(d * d)) * scale
    c1 = float(np.mean(d[:, 1:] * d[:, :-1])) * scale
    c2 = float(np.mean(d[:, 2:] * d[:, :-2])) * scale
    rho0 = float(np.clip(c2 / c1, 0.0, 0.9999)) if c1 > 0 else 0.5
    ar_var = min(max(c1 / max(rho0, 1e-3), 1e-3 * var), var)
    white_var = max(var - ar_var, 1e-4 * var)
    u0 = np.array([0.5 * math.log(max(ar_var, 1e-24)), math.atanh(rho0),
                   0.5 * math.log(max(white_var, 1e-24))])
    best = None
    for start in (u0, u0 + np.array([0.0, 0.0, -2.0])):  # the white part may be tiny
        res = minimize(lambda u: float(neg(u)[0]), start, method="Nelder-Mead",
                       options={"xatol": 1e-9, "fatol": 1e-9, "maxiter": 6000})
        if best is None or res.fun < best.fun:
            best = res
    u = best.x
    hess = _fd_hessian(neg, u, np.full(3, 1e-4))
    try:
        cov = np.linalg.inv(hess)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise FitError(f"{likelihood.dataset.source or 'the data set'}: the noise parameters "
                       "are not identified by the spread between the trials; the trials must "
                       "be repeated measurements of one input with independent noise: check "
                       "that they are not copies of one another, and record more repetitions"
                       ) from None
    return NoiseEstimate(float(np.exp(u[0])), float(np.tanh(u[1])), float(np.exp(u[2])), u, cov)


class Posterior:
    """Log posterior of a model's free parameters, given the noise.

    Parameters
    ----------
    likelihood : Likelihood
        Data, model and noise model.
    noise : NoiseEstimate
        The noise parameters (from :func:`estimate_noise`); the trial mean's
        likelihood is evaluated at their mode.

    Attributes
    ----------
    names : tuple of str
        Identified model parameters (the model's free parameters).
    """

    def __init__(self, likelihood: Likelihood, noise: NoiseEstimate) -> None:
        self.likelihood = likelihood
        self.noise = noise
        self.model = likelihood.model
        model = self.model
        self.parameters: tuple[Parameter, ...] = tuple(
            model.parameter(n) for n in model.free_names
        )
        self.names: tuple[str, ...] = tuple(p.name for p in self.parameters)
        self.priors: tuple[Prior, ...] = tuple(model.priors[n] for n in model.free_names)
        self.kinds = tuple(
            _transform_kind(p, pr) for p, pr in zip(self.parameters, self.priors, strict=True)
        )
        self._free_cols = np.array([model.index(n) for n in model.free_names], dtype=int)
        self._template = model.theta(model.defaults)[0]
        self.lower = np.array([p.bounds[0] for p in self.parameters])
        self.upper = np.array([p.bounds[1] for p in self.parameters])

    @property
    def ndim(self) -> int:
        """Number of identified parameters."""
        return len(self.names)

    # -- coordinates ------------------------------------------------------------
    def to_natural(self, z: np.ndarray) -> np.ndarray:
        """Natural parameter values from unconstrained coordinates ``(batch, ndim)``."""
        z = np.atleast_2d(np.asarray(z, dtype=float))
        out = z.copy()
        with np.errstate(over="ignore"):
            for j, kind in enumerate(self.kinds):
                if kind == "log":
                    out[:, j] = np.exp(z[:, j])
                elif kind == "atanh":
                    out[:, j] = np.tanh(z[:, j])
        return out

    def to_unconstrained(self, theta: np.ndarray) -> np.ndarray:
        """Unconstrained coordinates from natural values ``(batch, ndim)``."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        out = theta.copy()
        with np.errstate(divide="ignore"):
            for j, kind in enumerate(self.kinds):
                if kind == "log":
                    out[:, j] = np.log(theta[:, j])
                elif kind == "atanh":
                    out[:, j] = np.arctanh(theta[:, j])
        return out

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log |d theta / d z|`` per batch member."""
        z = np.atleast_2d(z)
        total = np.zeros(z.shape[0])
        for j, kind in enumerate(self.kinds):
            if kind == "log":
                total += z[:, j]
            elif kind == "atanh":
                total += _log_sech2(z[:, j])
        return total

    def full_theta(self, theta: np.ndarray) -> np.ndarray:
        """The model's full parameter array for identified values ``(batch, ndim)``."""
        theta = np.atleast_2d(theta)
        full = np.repeat(self._template[None, :], theta.shape[0], axis=0)
        full[:, self._free_cols] = theta
        return full

    # -- densities ----------------------------------------------------------------
    def log_prior(self, theta: np.ndarray) -> np.ndarray:
        """Log prior density in natural coordinates, ``-inf`` outside the bounds."""
        theta = np.atleast_2d(theta)
        inside = np.all((theta >= self.lower) & (theta <= self.upper), axis=1)
        total = np.where(inside, 0.0, -np.inf)
        for j, prior in enumerate(self.priors):
            with np.errstate(all="ignore"):
                total = total + np.where(inside, prior.logpdf(theta[:, j]), 0.0)
        return total

    def evaluate(
        self, theta: np.ndarray, *, return_x: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Log prior, log likelihood and model output for natural values.

        Parameters
        ----------
        theta : numpy.ndarray
            ``(batch, ndim)`` natural values.
        return_x : bool
            Whether to return the model output (the sampler does not need it).

        Returns
        -------
        log_prior, log_likelihood : numpy.ndarray
            ``(batch,)``; ``-inf`` where out of bounds or the simulation failed. The
            likelihood is that of the trial mean given the noise (the deviations'
            part does not depend on the model).
        x : numpy.ndarray or None
            Model positions of the valid members (NaN rows elsewhere), or None if no
            member was valid or ``return_x`` is false.
        """
        theta = np.atleast_2d(theta)
        lp = self.log_prior(theta)
        ll = np.full(theta.shape[0], -np.inf)
        ok = np.isfinite(lp)
        if not ok.any():
            return lp, ll, None
        sub = theta[ok]
        x_ok = self.likelihood.simulate(self.full_theta(sub))
        finite = np.all(np.isfinite(x_ok), axis=1)
        ll_ok = np.full(sub.shape[0], -np.inf)
        if finite.any():
            ll_ok[finite] = self.likelihood.mean_log_likelihood(
                x_ok[finite], self.noise.sigma, self.noise.rho, self.noise.white
            )
        ll[ok] = ll_ok
        if not return_x:
            return lp, ll, None
        x = np.full((theta.shape[0], self.likelihood.n_samples), np.nan)
        x[ok] = x_ok
        return lp, ll, x

    def log_prob_z(self, z: np.ndarray) -> np.ndarray:
        """Log posterior density in unconstrained coordinates (what emcee samples)."""
        z = np.atleast_2d(z)
        theta = self.to_natural(z)
        lp, ll, _ = self.evaluate(theta, return_x=False)
        out = lp + ll + self.log_jacobian(z)
        return np.where(np.isfinite(out), out, -np.inf)

    def plausible_box(self, rng: np.random.Generator, names: tuple[str, ...]) -> np.ndarray:
        """Unconstrained ``(lower, upper)`` of the 0.5-99.5% prior range of ``names``."""
        idx = [self.names.index(n) for n in names]
        box = np.empty((len(idx), 2))
        for row, j in enumerate(idx):
            draws = self.priors[j].sample(rng, 20000)
            lo, hi = np.quantile(draws, [0.005, 0.995])
            lo = max(lo, self.lower[j] + 1e-12 * max(1.0, abs(self.lower[j])))
            hi = min(hi, self.upper[j])
            ends = np.ones((2, self.ndim))
            ends[:, j] = lo, hi
            box[row] = self.to_unconstrained(ends)[:, j]
        return box


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
    """

    values: dict
    log_posterior: float
    rms_cost_m: float
    global_values: dict
    global_rms_cost_m: float
    z: np.ndarray
    covariance_z: np.ndarray


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


_DE_STRATEGIES = ("currenttobest1bin", "best1bin")


def find_map(
    posterior: Posterior,
    *,
    rng: np.random.Generator,
    popsize: int = 15,
    maxiter: int = 300,
) -> MapResult:
    """Global search on the paper's RMS cost, then the MAP by local polish.

    The global search is differential evolution over the prior's plausible box,
    run twice with different mutation strategies (``currenttobest1bin`` and
    ``best1bin``); the better optimum is polished (L-BFGS-B, then Newton steps
    whose Hessian gives the Laplace covariance).

    Parameters
    ----------
    posterior : Posterior
        The target.
    rng : numpy.random.Generator
        Seeds the global search.
    popsize : int
        Differential evolution population per dimension.
    maxiter : int
        Differential evolution generations at most.

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
    lik = posterior.likelihood
    box = posterior.plausible_box(rng, posterior.names)

    def rms(z: np.ndarray) -> np.ndarray:
        theta = posterior.to_natural(z)
        lp = posterior.log_prior(theta)
        out = np.full(theta.shape[0], 1.0)  # 1 m: worse than anything real
        ok = np.isfinite(lp)
        if ok.any():
            x = lik.simulate(posterior.full_theta(theta[ok]))
            cost = lik.rms_cost(x)
            out[ok] = np.where(np.isfinite(cost), cost, 1.0)
        return out

    # two searches with different strategies: one alone lands in a wrong basin in
    # about one run in four on a model with a regulator lag (tau_reg trading off
    # against alpha and K_e); both failing together was not seen
    best = None
    for strategy in _DE_STRATEGIES:
        de = differential_evolution(
            lambda zt: rms(np.atleast_2d(zt.T)), bounds=list(map(tuple, box)),
            popsize=popsize, maxiter=maxiter, tol=1e-8, seed=rng, polish=False,
            vectorized=True, updating="deferred", init="latinhypercube", strategy=strategy,
        )
        if best is None or de.fun < best.fun:
            best = de
    z_global = best.x
    global_cost = float(rms(z_global[None])[0])
    if global_cost >= 1.0:
        raise FitError("no parameter set in the prior's plausible region gives a finite "
                       "simulation of this data; check the data's units and the rig")
    z0 = z_global

    # optimise in coordinates scaled to the plausible box
    scale = box[:, 1] - box[:, 0]

    def neg_logpost(u: np.ndarray) -> np.ndarray:
        z = z0 + np.atleast_2d(u) * scale
        theta = posterior.to_natural(z)
        lp, ll, _ = posterior.evaluate(theta)
        v = -(lp + ll)
        return np.where(np.isfinite(v), v, 1e300)

    h = np.full(posterior.ndim, 1e-7)

    def fun_and_grad(u: np.ndarray) -> tuple[float, np.ndarray]:
        pts = np.vstack([u, u + np.diag(h), u - np.diag(h)])
        vals = neg_logpost(pts)
        n = posterior.ndim
        grad = (vals[1: n + 1] - vals[n + 1:]) / (2 * h)
        return float(vals[0]), np.where(np.isfinite(grad), grad, 0.0)

    u = np.zeros(posterior.ndim)
    for _ in range(3):  # restart: the first pass also learns the curvature's scale
        res = minimize(fun_and_grad, u, jac=True, method="L-BFGS-B",
                       options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-9})
        if np.allclose(res.x, u, rtol=0, atol=1e-12):
            break
        u = res.x
    # Newton polish with the finite-difference Hessian, whose inverse is the
    # Laplace covariance
    for _ in range(5):
        hd = np.abs(np.diag(_fd_hessian(neg_logpost, u, np.full(posterior.ndim, 1e-6))))
        step_h = 0.2 / np.sqrt(np.where(hd > 0, hd, 1.0))
        hess = _fd_hessian(neg_logpost, u, step_h)
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
    hd = np.abs(np.diag(_fd_hessian(neg_logpost, u, np.full(posterior.ndim, 1e-6))))
    hess = _fd_hessian(neg_logpost, u, 0.2 / np.sqrt(np.where(hd > 0, hd, 1.0)))
    z_map = z0 + u * scale
    try:
        cov_u = np.linalg.inv(hess)
        np.linalg.cholesky(cov_u)
    except np.linalg.LinAlgError:
        cov_u = np.diag(1.0 / np.where(np.diag(hess) > 0, np.diag(hess), 1e6))
    cov_z = cov_u * np.outer(scale, scale)
    theta_map = posterior.to_natural(z_map[None])
    lp, ll, x = posterior.evaluate(theta_map)
    cost = float(lik.rms_cost(x[0])[0])
    if not np.isfinite(cost) or cost > 0.25 * np.ptp(lik.y_mean):
        raise FitError(
            f"{lik.dataset.source or 'the data'}: the best fit leaves an RMS error of "
            f"{cost * 1e3:.3g} mm on a motion of {np.ptp(lik.y_mean) * 1e3:.3g} mm, so the data "
            "cannot be what this model describes. Check the units (positions in m, pressure "
            "in Pa), that the input column is the commanded input, and the rig (masses, "
            "gravity direction)."
        )
    values = dict(zip(posterior.names, map(float, theta_map[0]), strict=True))
    values.update(sigma_noise_m=posterior.noise.sigma, rho_noise=posterior.noise.rho,
                  sigma_white_m=posterior.noise.white)
    return MapResult(
        values=values,
        log_posterior=float(lp[0] + ll[0]),
        rms_cost_m=cost,
        global_values=dict(zip(posterior.names, map(float, posterior.to_natural(
            z_global[None])[0]), strict=True)),
        global_rms_cost_m=global_cost,
        z=z_map,
        covariance_z=cov_z,
    )


# ---------------------------------------------------------------------------------
# sampling


@dataclass(frozen=True)
class FitSettings:
    """How to sample.

    Parameters
    ----------
    n_walkers : int
        Walkers per ensemble (at least twice the number of parameters).
    n_ensembles : int
        Independent ensembles (R-hat across them needs two or more).
    max_steps : int
        Budget of steps per ensemble.
    max_seconds : float or None
        Budget of wall time for sampling.
    check_every : int
        Steps between convergence checks.
    tau_multiple : float
        Required kept chain length in integrated autocorrelation times.
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

    n_walkers: int = 32
    n_ensembles: int = 2
    max_steps: int = 20000
    max_seconds: float | None = None
    check_every: int = 250
    tau_multiple: float = 50.0
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


def _advance(path: str, n_steps: int, initial: np.ndarray | None, seed: int | None,
             moves: str) -> int:
    """Advance one ensemble by ``n_steps`` and append them to its HDF5 file.

    The file has emcee's ``HDFBackend`` layout (readable with
    ``emcee.backends.HDFBackend(path, name="mcmc")``) and records the random state
    after every chunk, so a run resumed from it continues exactly as an
    uninterrupted one. Steps run in memory and are written once per chunk:
    emcee's backend reopens the file at every step, which costs more than a step.
    """
    posterior = _WORKER_POSTERIOR
    store = emcee.backends.HDFBackend(path, name="mcmc")
    if store.initialized and store.iteration > 0:
        state = store.get_last_sample()
    else:
        # emcee has no seed argument: its RandomState comes from our seed
        state = emcee.State(initial, random_state=np.random.RandomState(seed).get_state())
        store.reset(initial.shape[0], posterior.ndim)
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
        g.attrs["iteration"] = it + n_steps  # last: a kill before this keeps the old state
    return it + n_steps


@dataclass
class _Diagnostics:
    converged: bool
    messages: list
    burn: int
    thin: int
    tau: np.ndarray
    ess: np.ndarray
    rhat: np.ndarray
    rhat_ensembles: np.ndarray | None
    n_steps: int


def _diagnose(chains: list[np.ndarray], names, settings: FitSettings, *,
              final: bool = False) -> _Diagnostics:
    """Convergence of ensembles' chains ``(steps, walkers, ndim)`` (unconstrained).

    The indicative R-hat over walkers is computed only when ``final``.
    """
    import arviz as az

    n = min(c.shape[0] for c in chains)
    ndim = chains[0].shape[2]
    # tau from the second half (past any transient), per ensemble and parameter
    taus = np.array([
        emcee.autocorr.integrated_time(c[n // 2: n], tol=0, quiet=True) for c in chains
    ])
    tau = taus.max(axis=0)
    tau_max = float(tau.max())
    burn = min(int(math.ceil(3 * tau_max)), n // 2)
    kept = n - burn
    ess = np.sum([c.shape[1] * kept / t for c, t in zip(chains, taus, strict=True)], axis=0)
    kept_chains = [c[burn:n] for c in chains]
    rhat = np.full(ndim, np.nan)
    if final:
        walkers = np.concatenate([k.transpose(1, 0, 2) for k in kept_chains], axis=0)
        rhat = np.array([float(az.rhat(walkers[:, :, j], method="rank"))
                         for j in range(ndim)])
    rhat_ens = None
    if len(chains) > 1:
        per_ens = np.stack([k.reshape(-1, ndim) for k in kept_chains])  # step-major
        rhat_ens = np.array([float(az.rhat(per_ens[:, :, j], method="rank"))
                             for j in range(ndim)])
    messages = []
    short = kept < settings.tau_multiple * tau
    if short.any():
        messages.append(
            f"kept chain of {kept} steps is shorter than {settings.tau_multiple:g} "
            f"autocorrelation times for {', '.join(np.array(names)[short])} "
            f"(tau up to {tau_max:.0f} steps)"
        )
    low = ess < settings.min_ess
    if low.any():
        messages.append(
            f"ESS below {settings.min_ess:g} for "
            + ", ".join(f"{nm} ({e:.0f})" for nm, e in zip(np.array(names)[low], ess[low],
                                                          strict=True))
        )
    # R-hat is defined across independent ensembles; emcee's walkers are coupled
    # by the moves, so their R-hat is reported as indicative only
    if rhat_ens is not None and (rhat_ens >= settings.max_rhat).any():
        bad = rhat_ens >= settings.max_rhat
        messages.append(
            f"R-hat across ensembles at or above {settings.max_rhat} for "
            + ", ".join(f"{nm} ({r:.4f})" for nm, r in zip(np.array(names)[bad],
                                                           rhat_ens[bad], strict=True))
        )
    # stored draws: thinned by at least tau/2 and to about 8000 in all (convergence
    # and ESS are judged on the full chain; the store feeds summaries and LOO)
    n_chains = sum(c.shape[1] for c in chains)
    thin = max(1, int(tau_max // 2), math.ceil(kept * n_chains / 8000))
    return _Diagnostics(not messages, messages, burn, thin, tau, ess, rhat, rhat_ens, n)


def _fingerprint(likelihood: Likelihood, settings: FitSettings, seed) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(likelihood.dataset.position_m).tobytes())
    h.update(np.ascontiguousarray(likelihood.input).tobytes())
    desc = {
        "model": likelihood.model.describe(), "rig": likelihood.model.rig.to_dict(),
        "effects": likelihood.model.effect_names, "seed": seed,
        "n_walkers": settings.n_walkers, "n_ensembles": settings.n_ensembles,
        "substeps": likelihood.substeps,
    }
    h.update(json.dumps(desc, sort_keys=True, default=str).encode())
    return h.hexdigest()[:16]


def _progress(settings: FitSettings, text: str) -> None:
    if settings.progress:
        print(f"[pmabayes fit] {text}", file=sys.stderr, flush=True)


def _sample_rounds(posterior: Posterior, paths: list[str], initials: list[np.ndarray],
                   ens_seeds: list[int], settings: FitSettings, pool,
                   t_sample: float) -> _Diagnostics:
    """Advance all ensembles round by round until converged or out of budget."""
    diag = None
    while True:
        done = [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).iteration
                if os.path.exists(p) else 0 for p in paths]
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
                    for e, (p, d) in enumerate(zip(paths, done, strict=True))]
            if pool is None:
                for job in jobs:
                    _advance(*job)
            else:
                list(pool.map(_advance, *zip(*jobs, strict=True)))
        chains = [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).get_chain()
                  for p in paths]
        if min(c.shape[0] for c in chains) < 20:
            continue
        diag = _diagnose(chains, posterior.names, settings)
        # a bar towards convergence: the run stops when the chain is long
        # enough, not at a known step count
        done_frac = min(1.0, (diag.n_steps - diag.burn) / (settings.tau_multiple
                                                          * diag.tau.max()),
                        diag.ess.min() / settings.min_ess)
        bar = "#" * int(round(20 * done_frac))
        _progress(settings, (
            f"[{bar:-<20}] step {diag.n_steps} (budget {settings.max_steps}) x "
            f"{settings.n_ensembles} ensembles x {settings.n_walkers} walkers: kept "
            f"{diag.n_steps - diag.burn} of {settings.tau_multiple * diag.tau.max():.0f} "
            f"steps needed ({settings.tau_multiple:g} x tau {diag.tau.max():.0f}), "
            f"ESS min {diag.ess.min():.0f}"
            + (f", R-hat across ensembles max {diag.rhat_ensembles.max():.4f}"
               if diag.rhat_ensembles is not None else "")
            + f", {time.perf_counter() - t_sample:.0f} s"
        ))
        if step == 0:
            break
    return diag


def fit(
    dataset: Dataset,
    model: Model | None = None,
    *,
    seed: int | None = 0,
    settings: FitSettings | None = None,
    chains_dir: str | Path | None = None,
    restart: bool = False,
    substeps: int = 1,
) -> xr.DataTree:
    """Identify a model's parameters from repeated trials: MAP, then posterior.

    Parameters
    ----------
    dataset : Dataset
        Repeated trials sharing one input.
    model : Model, optional
        The model; the base model on the characterisation rig by default.
    seed : int or None
        Seed of everything random (global search, walkers, emcee, predictive
        noise). The same seed gives the same numbers, to the bit.
    settings : FitSettings, optional
        Sampler settings.
    chains_dir : str or Path, optional
        Where the ensembles' HDF5 chains live. A run pointed at the chains of an
        interrupted run with the same data, model, seed and settings resumes them;
        without it a temporary folder is used.
    restart : bool
        Discard existing chains in ``chains_dir`` instead of resuming.
    substeps : int
        Simulator substeps per sample.

    Returns
    -------
    xarray.DataTree
        The fit (layout in :mod:`pmabayes.posterior`).

    Raises
    ------
    FitError
        When the data cannot be fitted or the chains belong to another fit.
    """
    import tempfile

    start = time.perf_counter()
    settings = FitSettings() if settings is None else settings
    model = Model() if model is None else model
    try:
        likelihood = Likelihood(model, dataset, substeps=substeps)
    except LikelihoodError as exc:
        raise FitError(str(exc)) from None
    posterior = Posterior(likelihood, estimate_noise(likelihood))
    if settings.max_steps < 20:
        raise FitError(f"max_steps must be at least 20 (the autocorrelation time needs a "
                       f"chain), got {settings.max_steps}")
    if settings.n_walkers < 2 * posterior.ndim:
        raise FitError(f"n_walkers must be at least {2 * posterior.ndim} (twice the "
                       f"{posterior.ndim} parameters), got {settings.n_walkers}")
    seeds = np.random.SeedSequence(seed)
    s_map, s_walkers, s_ppc = seeds.spawn(3)
    ens_seeds = [int(s.generate_state(1)[0]) for s in s_walkers.spawn(settings.n_ensembles)]

    tmp = None
    if chains_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="pmabayes-chains-")
        chains_dir = Path(tmp.name)
    chains_dir = Path(chains_dir)
    chains_dir.mkdir(parents=True, exist_ok=True)
    stamp = chains_dir / "fit.json"
    fingerprint = _fingerprint(likelihood, settings, seed)
    paths = [str(chains_dir / f"ensemble_{e}.h5") for e in range(settings.n_ensembles)]
    if restart:
        for p in [*paths, str(stamp)]:
            if os.path.exists(p):
                os.remove(p)
    resumed = stamp.exists()
    if resumed:
        saved = json.loads(stamp.read_text())
        if saved.get("fingerprint") != fingerprint:
            raise FitError(
                f"{chains_dir} holds chains of a different fit (other data, model, seed or "
                "sampler settings); pass restart=True (--restart) or choose another output"
            )
        map_result = MapResult(**{**saved["map"], "z": np.array(saved["map"]["z"]),
                                  "covariance_z": np.array(saved["map"]["covariance_z"])})
        t_map = saved["timings_s"]["map"]
        _progress(settings, f"resuming the chains in {chains_dir}")
    else:
        _progress(settings, "global search and MAP ...")
        map_result = find_map(posterior, rng=np.random.default_rng(s_map))
        t_map = time.perf_counter() - start
        _progress(settings, f"MAP in {t_map:.1f} s: RMS cost {map_result.rms_cost_m * 1e6:.1f} um "
                  f"(global search {map_result.global_rms_cost_m * 1e6:.1f} um)")
        record = {k: v for k, v in map_result.__dict__.items()}
        record["z"] = map_result.z.tolist()
        record["covariance_z"] = map_result.covariance_z.tolist()
        for p in paths:
            if os.path.exists(p):
                os.remove(p)
        stamp.write_text(json.dumps({"fingerprint": fingerprint, "map": record,
                                     "timings_s": {"map": t_map}}, indent=1))

    # initial walkers from the Laplace approximation
    initials = []
    for e in range(settings.n_ensembles):
        rng = np.random.default_rng(ens_seeds[e])
        pts = rng.multivariate_normal(map_result.z, map_result.covariance_z,
                                      size=settings.n_walkers, method="eigh")
        lp = posterior.log_prob_z(pts)
        for _ in range(100):  # redraw any walker that starts outside the support
            bad = ~np.isfinite(lp)
            if not bad.any():
                break
            pts[bad] = rng.multivariate_normal(map_result.z, 0.25 * map_result.covariance_z,
                                               size=int(bad.sum()), method="eigh")
            lp[bad] = posterior.log_prob_z(pts[bad])
        initials.append(pts)

    t_sample = time.perf_counter()
    n_proc = settings.processes or min(settings.n_ensembles, os.cpu_count() or 1)
    _init_worker(posterior)
    # Workers are forked so that user effects (defined in a notebook or loaded with
    # --plugin, not importable by name) reach them without pickling. Python warns
    # about fork in a process with threads; here the threads are OpenBLAS's pool,
    # which reinitialises in the child (pthread_atfork), and numba and h5py run none.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"This process .* is multi-threaded",
                                category=DeprecationWarning)
        pool = None
        if n_proc > 1 and settings.n_ensembles > 1:
            ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
            pool = ProcessPoolExecutor(max_workers=n_proc, mp_context=ctx,
                                       initializer=_init_worker, initargs=(posterior,))
        try:
            _sample_rounds(posterior, paths, initials, ens_seeds, settings, pool, t_sample)
        finally:
            if pool is not None:
                pool.shutdown()
    t_sampling = time.perf_counter() - t_sample
    chains = [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).get_chain()
              for p in paths]
    diag = _diagnose(chains, posterior.names, settings, final=True)
    if not diag.converged:
        warnings.warn(
            "pmabayes fit did NOT converge: " + "; ".join(diag.messages)
            + ". The result is saved anyway; run longer (more steps) before trusting it.",
            RuntimeWarning, stacklevel=2,
        )
        _progress(settings, "NOT CONVERGED: " + "; ".join(diag.messages))
    tree = _build_tree(posterior, paths, diag, settings, map_result,
                       np.random.default_rng(s_ppc))
    info = _info(posterior, diag, settings, map_result, seed,
                 {"map": t_map, "sampling": t_sampling,
                  "total": time.perf_counter() - start}, resumed)
    tree.attrs["pmabayes"] = json.dumps(info)
    if tmp is not None:
        tmp.cleanup()
    return tree


def _build_tree(posterior: Posterior, paths, diag: _Diagnostics, settings: FitSettings,
                map_result: MapResult, rng: np.random.Generator) -> xr.DataTree:
    import arviz as az

    lik = posterior.likelihood
    zs, lps = [], []
    for p in paths:
        b = emcee.backends.HDFBackend(p, name="mcmc", read_only=True)
        zs.append(b.get_chain(discard=diag.burn, thin=diag.thin)[: (diag.n_steps - diag.burn)
                                                                  // diag.thin])
        lps.append(b.get_log_prob(discard=diag.burn, thin=diag.thin)[: zs[-1].shape[0]])
    n_draw = min(z.shape[0] for z in zs)
    z = np.concatenate([zz[:n_draw].transpose(1, 0, 2) for zz in zs])  # (chain, draw, ndim)
    lp_z = np.concatenate([ll[:n_draw].T for ll in lps])
    n_chain = z.shape[0]
    flat_z = z.reshape(-1, posterior.ndim)
    theta = posterior.to_natural(flat_z)
    lp = (lp_z.reshape(-1) - posterior.log_jacobian(flat_z)).reshape(n_chain, n_draw)
    # the noise: independent draws from its posterior, paired with the model draws
    sigma, rho, white = posterior.noise.draws(rng, theta.shape[0])
    # per-trial log-likelihood for every kept draw, in chunks
    pointwise = np.empty((theta.shape[0], lik.n_trials))
    for a in range(0, theta.shape[0], 512):
        sl = slice(a, a + 512)
        x = lik.simulate(posterior.full_theta(theta[sl]))
        pointwise[sl] = lik.pointwise(x, sigma[sl], rho[sl], white[sl])
    # posterior predictive: random draws with fresh AR(1) noise
    from pmabayes.likelihood import ar1_noise

    pick = rng.choice(theta.shape[0], size=min(settings.ppc_draws, theta.shape[0]),
                      replace=False)
    x_pp = lik.simulate(posterior.full_theta(theta[pick]))
    noise = ar1_noise(len(pick) * lik.n_trials, lik.n_samples,
                      np.repeat(sigma[pick], lik.n_trials), np.repeat(rho[pick], lik.n_trials),
                      rng)
    noise += np.repeat(white[pick], lik.n_trials)[:, None] * rng.standard_normal(noise.shape)
    y_pp = x_pp[:, None, :] + noise.reshape(len(pick), lik.n_trials, lik.n_samples)
    ds = lik.dataset
    data = {
        "posterior": {
            **{n: theta[:, j].reshape(n_chain, n_draw) for j, n in enumerate(posterior.names)},
            "sigma_noise_m": sigma.reshape(n_chain, n_draw),
            "rho_noise": rho.reshape(n_chain, n_draw),
            "sigma_white_m": white.reshape(n_chain, n_draw),
        },
        "sample_stats": {"lp": lp},
        "log_likelihood": {"position_m": pointwise.reshape(n_chain, n_draw, lik.n_trials)},
        "observed_data": {"position_m": ds.position_m},
        "constant_data": {ds.input_name: ds.input[0]},
        "posterior_predictive": {
            "position_m": y_pp[None].astype(np.float32),
            "model_position_m": x_pp[None].astype(np.float32),
        },
    }
    dims = {"position_m": ["trial", "time"], "model_position_m": ["time"],
            ds.input_name: ["time"]}
    coords = {"trial": ds.trial_ids, "time": ds.time_s}
    tree = az.from_dict(data, dims=dims, coords=coords)
    # log_likelihood's position_m is per trial only
    ll_ds = xr.Dataset(
        {"position_m": (("chain", "draw", "trial"), pointwise.reshape(n_chain, n_draw,
                                                                      lik.n_trials))},
        coords={"chain": np.arange(n_chain), "draw": np.arange(n_draw), "trial": ds.trial_ids},
    )
    tree["log_likelihood"] = xr.DataTree(ll_ds)
    ss = tree["sample_stats"].to_dataset()
    ss["ensemble"] = ("chain", np.repeat(np.arange(len(paths)), settings.n_walkers))
    tree["sample_stats"] = xr.DataTree(ss)
    return tree


def _info(posterior: Posterior, diag: _Diagnostics, settings: FitSettings,
          map_result: MapResult, seed, timings: dict, resumed: bool) -> dict:
    lik = posterior.likelihood
    model = posterior.model
    rows = model.describe()
    for p in NOISE_PARAMETERS:
        rows.append({"name": p.name, "unit": p.unit, "default": p.default,
                     "prior": str(p.prior), "bounds": p.bounds, "fixed": False,
                     "description": p.description, "source": "noise"})
    for row in rows:
        row["bounds"] = [float(b) for b in row["bounds"]]
    names = posterior.names

    def named(values):
        return None if values is None else {n: float(v) for n, v in
                                            zip(names, values, strict=True)}

    ds = lik.dataset
    return {
        "pmabayes_version": __version__,
        "model": {"effects": list(model.effect_names), "rig": model.rig.to_dict(),
                  "free": list(model.free_names), "fixed": dict(model.fixed),
                  "parameters": rows},
        "noise": {"model": "AR(1) disturbance plus white sensor noise per trial, stationary, "
                           "independent between trials",
                  "parameters": [p.name for p in NOISE_PARAMETERS],
                  "estimated_from": "deviations of the trials from their mean (repeatability); "
                                    "posterior by Laplace approximation, independent draws",
                  "sigma_noise_m": posterior.noise.sigma, "rho_noise": posterior.noise.rho,
                  "sigma_white_m": posterior.noise.white},
        "data": {"source": ds.source, "n_trials": ds.n_trials, "n_samples": ds.n_samples,
                 "dt_s": ds.dt_s, "input_name": ds.input_name,
                 "synthetic": bool(ds.metadata.get("synthetic", False)),
                 "noise_floor_m": ds.noise_floor_m},
        "paper_values": dict(PAPER_VALUES),
        "map": {"values": map_result.values, "log_posterior": map_result.log_posterior,
                "rms_cost_m": map_result.rms_cost_m,
                "global_search": {"values": map_result.global_values,
                                  "rms_cost_m": map_result.global_rms_cost_m}},
        "convergence": {"converged": diag.converged, "messages": diag.messages,
                        "n_ensembles": settings.n_ensembles, "n_walkers": settings.n_walkers,
                        "n_steps": diag.n_steps, "burn": diag.burn, "thin": diag.thin,
                        "tau": named(diag.tau), "ess": named(diag.ess),
                        "rhat": named(diag.rhat), "rhat_ensembles": named(diag.rhat_ensembles),
                        "min_ess": settings.min_ess, "tau_multiple": settings.tau_multiple,
                        "resumed": resumed},
        "seed": seed,
        "timings_s": timings,
    }
