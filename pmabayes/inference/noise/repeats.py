"""The noise, learnt from repeatability: the posterior of the AR(1) + white noise from
the deviations of the repeats from their mean (trials, or the periods of a periodic
record), each noise group's estimate and noise model, the start of a noise sampled with
the model (a record without repeats, or a model that is not learnt from repeats), and
the periods of a record from rest referred to the model's residual. The noise models
themselves are the package's other modules; their choice is
:mod:`pmabayes.inference.noise.choice`.
"""

from __future__ import annotations

import math
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

if TYPE_CHECKING:  # the density holds a NoiseEstimate, and the likelihood a noise model
    from pmabayes.inference.density import Posterior
    from pmabayes.inference.likelihood import Likelihood

__all__ = [
    "estimate_noise",
    "group_noise",
    "refer_periods",
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
    for start in (u0, u0 + shift):
        res = minimize(lambda u: float(neg(u)[0]), start, method="Nelder-Mead",
                       options={"xatol": 1e-9, "fatol": 1e-9, "maxiter": 6000})
        if best is None or res.fun < best.fun:
            best = res
    return best.x


def _default_noise_z(posterior: Posterior, first: int | None = None) -> np.ndarray:
    """The defaults, in unconstrained coordinates, of the columns from ``first`` on: by
    default the sampled noise parameters' (none when the noise comes from repeats)."""
    theta = np.array([[p.default for p in posterior.parameters]])
    first = posterior.n_searched if first is None else first
    return posterior.to_unconstrained(theta)[0, first:]


def _noise_start(posterior: Posterior, z: np.ndarray) -> np.ndarray:
    """``z`` with the noise sampled with the model (records without repeats, noise
    models not learnt from repeats) set to its posterior mode given the model's
    parameters in ``z``.

    The global search's cost does not depend on the noise, so it leaves the noise
    anywhere; a polish started there can stop in a mode of the noise alone (all of
    it white, or a negative correlation) far below the posterior's. The residual of
    the search's optimum is a series of the noise (plus what misfit is left): each
    noise model starts the search, over the noise coordinates only, of the posterior
    from it (:meth:`~pmabayes.inference.noise.NoiseModel.start`).
    """
    cols = np.arange(posterior.n_searched, posterior.ndim)
    if cols.size == 0:
        return z
    x = posterior.output(posterior.to_natural(z[None]))
    # several experiments are seen as one JointLikelihood, which splits the output
    parts = posterior.likelihood.split(x) if posterior.n_experiments > 1 else [x]
    # per sampled group, from its first experiment: (start, shift, noise model, its lik)
    starts: dict[int, tuple] = {}
    for e, (lik, xe) in enumerate(zip(posterior.likelihoods, parts, strict=True)):
        g = posterior.groups[e]
        if posterior.noise_sampled(e) and g not in starts:
            r = lik.y_mean - xe[0]
            if lik.observed is not None:  # a single record: its samples observed
                r = np.where(lik.observed[0], r, 0.0)
            starts[g] = (*lik.noise.start(r, lik.observed, lik), lik.noise)
    order = sorted(starts)  # the columns' order
    u0 = np.concatenate([starts[g][0] for g in order])
    shift = np.concatenate([starts[g][1] for g in order])

    def neg(u: np.ndarray) -> np.ndarray:
        zz = np.repeat(z[None], np.atleast_2d(u).shape[0], axis=0)
        zz[:, cols] = np.atleast_2d(u)
        return -posterior.log_prob_z(zz)

    out = z.copy()
    out[cols] = _minimise_noise(neg, u0, shift)
    a = posterior.n_searched
    for g in order:
        width = starts[g][0].size
        sl = slice(a, a + width)
        out[sl] = starts[g][2].clip_start(out[sl], posterior.upper[sl])
        a += width
    return out


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


def refer_periods(posterior: Posterior, z: np.ndarray) -> bool:
    """Learn the noise of records from rest, and of trials with their own inputs, from
    their repeats' residual at ``z``.

    Each experiment whose repeats must be referred to the model
    (:attr:`pmabayes.inference.likelihood.Likelihood.refers_to_model`: the periods of a
    record that starts from rest, or trials with their own inputs) takes its repeats
    from the residual at ``z``
    (:meth:`~pmabayes.inference.likelihood.Likelihood.refer_periods_to`), and the noise of its
    group is estimated again, its noise model chosen again as first requested.
    Other experiments keep theirs.

    Parameters
    ----------
    posterior : Posterior
        Updated in place (:meth:`~pmabayes.inference.density.Posterior.set_group_noise`).
    z : numpy.ndarray
        The point, in unconstrained coordinates ``(ndim,)``: a MAP.

    Returns
    -------
    bool
        Whether any experiment's periods were referred to the model.
    """
    liks = posterior.likelihoods
    shaken = [e for e, lik in enumerate(liks) if lik.refers_to_model]
    if not shaken:
        return False
    theta = posterior.to_natural(np.asarray(z, dtype=float)[None])
    for e in shaken:
        liks[e].refer_periods_to(posterior.simulate(theta, e)[0])
    for g in sorted({posterior.groups[e] for e in shaken}):
        members = [e for e, gg in enumerate(posterior.groups) if gg == g]
        est, choice = group_noise([liks[e] for e in members],
                                   posterior.noise_choices[members[0]].requested)
        posterior.set_group_noise(g, est, choice)
    return True


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
