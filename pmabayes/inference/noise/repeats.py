"""The noise, learnt from repeatability: the posterior of the AR(1) + white noise from
the deviations of the repeats from their mean (trials, or the periods of a periodic
record), and each noise group's estimate and noise model. The start of a noise sampled
with the model and the periods of a record from rest referred to the model's residual
work on the posterior density, above this package
(:mod:`pmabayes.inference.noise_start`). The noise models themselves are the package's
other modules; their choice is :mod:`pmabayes.inference.noise.choice`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import minimize

from pmabayes.inference.errors import FitError
from pmabayes.inference.laplace import _fd_hessian
from pmabayes.inference.noise.ar1 import NOISE_PARAMETERS, _lag_moment, _moment_start
from pmabayes.inference.noise.base import noise_model_class
from pmabayes.inference.noise.choice import NoiseChoice, _as_list, choose_noise_model

if TYPE_CHECKING:  # the likelihood holds a noise model
    from pmabayes.inference.likelihood import Likelihood

__all__ = [
    "estimate_noise",
    "group_noise",
    "NoiseEstimate",
]


def estimate_noise(likelihood: Likelihood | Sequence[Likelihood]) -> NoiseEstimate:
    """Posterior of the noise parameters from the deviations of the repeats from their mean.

    The repeats are an experiment's trials, or the periods of a single periodic
    record (:attr:`pmabayes.inference.likelihood.Likelihood.noise_source`).

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
    liks = _as_list(likelihood)
    where = ", ".join(str(lik.dataset.source or "the data set") for lik in liks)
    liks = [lik for lik in liks if lik.n_repeats >= 2]
    if not liks:
        raise FitError(f"{where}: a single record without repeats (no second trial, no declared "
                       "periods): its noise cannot be learnt from repeats; pmabayes.fit "
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
        each = [_lag_moment(lik._d, lik._contrast_obs, lag)
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
        # inv and cholesky pass a NaN matrix silently: a Hessian that is not finite (a
        # step that left the support) is no covariance either
        if not (np.all(np.isfinite(hess)) and np.all(np.isfinite(cov))):
            raise np.linalg.LinAlgError("not finite")
    except np.linalg.LinAlgError:
        raise FitError(f"{where}: the noise parameters "
                       "are not identified by the spread between the trials; the trials must "
                       "be repeated measurements of one input with independent noise: check "
                       "that they are not copies of one another, and record more repetitions"
                       ) from None
    return NoiseEstimate(float(np.exp(u[0])), float(np.tanh(u[1])), float(np.exp(u[2])), u, cov)


def _minimise_noise(neg, u0: np.ndarray, shift: np.ndarray | None = None) -> np.ndarray:
    """Minimise ``neg`` (batched) over noise coordinates from ``u0``, and from ``u0 +
    shift`` (by default: every AR(1) + white noise's white part ``e^2`` times smaller,
    as it may be tiny); the better optimum."""
    best = None
    if shift is None:
        shift = np.zeros(u0.size)
        shift[2::3] = -2.0  # (log sigma, atanh rho, log sigma_w) per noise
    with warnings.catch_warnings():
        # a simplex with two vertices outside the support (cost inf) makes scipy's own
        # convergence test subtract inf from inf: the NaN is read as "not converged",
        # as it should be, and is no news to the user; the cost's own warnings stay on
        warnings.filterwarnings("ignore", "invalid value encountered", RuntimeWarning,
                                module=r"scipy\.optimize")
        for start in (u0, u0 + shift):
            res = minimize(lambda u: float(neg(u)[0]), start, method="Nelder-Mead",
                           options={"xatol": 1e-9, "fatol": 1e-9, "maxiter": 6000})
            if best is None or res.fun < best.fun:
                best = res
    return best.x


def group_noise(members: list[Likelihood], noise_model: str
                ) -> tuple[NoiseEstimate | None, NoiseChoice]:
    """A noise group's estimate from its repeats and its noise model.

    Parameters
    ----------
    members : list of Likelihood
        The experiments that share one noise; they are set to use the chosen model
        (:meth:`~pmabayes.inference.likelihood.Likelihood.use_noise`).
    noise_model : str
        The requested noise model, ``"auto"`` or a registered one's name
        (:func:`~pmabayes.inference.noise.choose_noise_model`).

    Returns
    -------
    estimate : NoiseEstimate or None
        From the repeats; None where no member has repeats, or the model is not
        learnt from repeats (its noise is then sampled with the model).
    choice : NoiseChoice
        The noise model chosen.
    """
    repeats = noise_model == "auto" or noise_model_class(noise_model).from_repeats
    est = (estimate_noise(members)
           if repeats and any(lik.n_repeats >= 2 for lik in members) else None)
    # the repeats test AR(1) + white; where they reject it the trial mean's
    # likelihood uses their AR(p) (fixed, as the AR(1) noise from repeats is)
    if not repeats:  # a model asked for by name, sampled with the model's parameters
        choice = choose_noise_model(members, math.nan, math.nan, math.nan, noise_model)
    else:
        choice = (choose_noise_model(members, est.sigma, est.rho, est.white, noise_model)
                  if est is not None else NoiseChoice(noise_model, None, math.nan))
    for lik in members:
        lik.use_noise(choice.model)
    return est, choice


def _log_sech2(z: np.ndarray) -> np.ndarray:
    """``log(1 - tanh(z)^2) = -2 log cosh z``, without overflow: the log Jacobian of
    the atanh coordinate."""
    a = np.abs(z)
    return -2.0 * (a + np.log1p(np.exp(-2.0 * a)) - math.log(2.0))


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
