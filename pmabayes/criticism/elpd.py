"""Leave-one-trial-out ELPD: PSIS-LOO over a MAP's Laplace draws weighed to the posterior
(with the Pareto k-hats that say whether it holds), tables of fits side by side, and the
paired difference of two models' per-trial ELPDs with its standard error.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pmabayes.inference.importance import smoothed_log_weights

__all__ = ["paired_difference", "laplace_loo", "LaplaceLoo", "good_k", "plugin_difference",
           "psis_loo", "loo_table"]

#: Fewest usable draws for PSIS-LOO (its Pareto tail needs at least 5 of them).
_MIN_LOO_DRAWS = 25

#: Contiguous stretches a single record is cut into for its leave-one-out ELPD: with
#: one trial, leaving it out predicts the record from nothing, and its one term has no
#: spread to give a standard error.
LOO_STRETCHES = 10

#: Eigenvalues of a Laplace covariance below this share of its largest are raised to
#: it: the draws and their density (:func:`_gaussian`) then agree, and a direction
#: measured as flat to rounding is not a point mass.
_EIG_FLOOR = 1e-14


def paired_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The ELPD of one model minus another's, paired over the left-out trials.

    Parameters
    ----------
    a, b : numpy.ndarray
        Per-trial ELPDs of the two models, over the same trials.

    Returns
    -------
    difference : float
        ``sum(a - b)``.
    se : float
        Its standard error from the per-trial differences, ``sqrt(n var(a - b))``; NaN
        with fewer than two (one difference has no spread to estimate it from, and
        ``0`` would claim a certainty the data do not give).
    """
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if d.size < 2:
        return float(d.sum()), math.nan
    return float(d.sum()), float(math.sqrt(d.size * np.var(d)))


def good_k(n_draws: int) -> float:
    """The largest Pareto k-hat of importance weights over ``n_draws`` draws at which a
    PSIS estimate is reliable: ``min(1 - 1/log10(S), 0.7)`` (Vehtari et al. 2024, as
    ArviZ takes it).

    Parameters
    ----------
    n_draws : int
        The draws ``S``.

    Returns
    -------
    float

    Examples
    --------
    >>> round(good_k(400), 3), good_k(5000)
    (0.616, 0.7)
    """
    return float(min(1.0 - 1.0 / math.log10(max(n_draws, 11)), 0.7))


@dataclass(frozen=True)
class LaplaceLoo:
    """A leave-one-trial-out ELPD from a MAP's Laplace draws, and whether to trust it.

    Parameters
    ----------
    elpd : float
        The sum of ``elpd_i``; NaN where it could not be estimated.
    elpd_i : numpy.ndarray
        Per left-out trial (or stretch of a single record).
    interval : dict
        ``(low, high)`` equal-tailed interval of each parameter asked for, from the
        Laplace draws.
    pareto_k : float
        The largest Pareto k-hat of the units' leave-one-out importance ratios (NaN
        where none could be smoothed: every unit's ratios alike, then exact).
    correction_k : float
        Pareto k-hat of the importance weights that take the Laplace draws to the
        posterior itself (how far the Laplace approximation is from it).
    good_k : float
        The threshold both k-hats are held to (:func:`good_k` of ``n_draws``).
    ess : float
        Effective draws of the posterior among the Laplace draws (Kish, from the
        correction's weights).
    n_draws : int
        Draws used (inside the prior's support, with a finite likelihood).
    note : str or None
        Why the estimate is not reliable, in words; None when it is.
    map_i : numpy.ndarray or None
        Each unit's log likelihood at the MAP (in-sample), the draws' witness
        (:func:`plugin_difference`).
    n_parameters : int
        The posterior's parameters (its dimension).
    """

    elpd: float
    elpd_i: np.ndarray
    interval: dict
    pareto_k: float = math.nan
    correction_k: float = math.nan
    good_k: float = 0.7
    ess: float = math.nan
    n_draws: int = 0
    note: str | None = None
    map_i: np.ndarray | None = None
    n_parameters: int = 0

    @property
    def reliable(self) -> bool:
        """A finite ELPD with no note against it."""
        return self.note is None and math.isfinite(self.elpd)


def _gaussian(mean: np.ndarray, cov: np.ndarray):
    """The draws and the log density of the normal ``N(mean, cov)``, from one
    eigendecomposition (eigenvalues raised to :data:`_EIG_FLOOR` of the largest, so
    that a direction measured as flat to rounding is drawn and weighed alike)."""
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    top = float(np.max(np.abs(lam))) if lam.size else 1.0
    lam = np.maximum(lam, _EIG_FLOOR * top if top > 0 else 1.0)
    root = vec * np.sqrt(lam)
    log_det = float(np.sum(np.log(lam)))

    def draw(rng: np.random.Generator, n: int) -> np.ndarray:
        return mean + rng.standard_normal((n, mean.size)) @ root.T

    def log_pdf(z: np.ndarray) -> np.ndarray:
        w = (z - mean) @ vec / np.sqrt(lam)
        return -0.5 * (np.sum(w * w, axis=1) + log_det + mean.size * math.log(2.0 * math.pi))

    return draw, log_pdf


def laplace_loo(posterior, map_result, rng: np.random.Generator, n_draws: int, ci_prob: float,
                names: tuple[str, ...] = ()) -> LaplaceLoo:
    """PSIS-LOO by trial and intervals, from draws of a MAP's Laplace approximation,
    importance-weighted to the posterior.

    The Laplace draws are not draws of the posterior: where it is not Gaussian (a
    ridge that curves, a direction flat at the mode and steep further out), many of
    them lie where the posterior is thousands of nats lower. Taken as posterior draws,
    each unit's leave-one-out estimate (a harmonic mean of its likelihood) is set by the
    worst of them, and moved by thousands of nats with the seed. Each draw is weighed
    by the posterior over the Laplace density instead (PSIS for approximate
    posteriors, Magnusson et al. 2019): the unit's log ratio is
    ``log p(theta | y) - log q(theta) - log p(y_i | theta)``. The Pareto k-hat of
    those weights and of the correction alone say whether the estimate holds
    (``note``); the noise learnt from repeats is held at its estimate, as in the
    posterior the MAP and the Laplace covariance are of.

    Parameters
    ----------
    posterior : pmabayes.inference.density.Posterior
        The posterior of one or more experiments.
    map_result : pmabayes.inference.search.MapResult
        Its MAP, with the covariance of the Laplace approximation (and the note of a
        covariance that is a stand-in, ``laplace_note``, where it has one).
    rng : numpy.random.Generator
        Draws the parameters.
    n_draws : int
        Laplace draws (those outside the prior's support are dropped).
    ci_prob : float
        Probability of the equal-tailed intervals.
    names : tuple of str
        Parameters to give intervals of.

    Returns
    -------
    LaplaceLoo
        The leave-one-trial-out ELPD over every trial of every experiment (an
        experiment of a single record: one of its :data:`LOO_STRETCHES` contiguous
        stretches at a time, given the rest,
        :meth:`~pmabayes.inference.likelihood.Likelihood.stretch_pointwise`, where its
        noise model allows), its per-unit terms and the intervals; NaN (with the
        reason in ``note``) when fewer than 25 draws are inside the support with a
        finite likelihood.
    """
    z_map = np.asarray(map_result.z, dtype=float)
    draw, log_q = _gaussian(z_map, np.atleast_2d(np.asarray(map_result.covariance_z, float)))
    z = draw(rng, n_draws)
    theta = posterior.to_natural(z)
    inside = np.isfinite(posterior.log_prior(theta))
    z = z[inside]
    # the MAP rides along as row 0: its units' in-sample log likelihood is the witness
    units, log_post = _units(posterior, np.vstack([z_map[None], z]))
    map_i, pointwise, log_post = units[0], units[1:], log_post[1:]
    ok = np.all(np.isfinite(pointwise), axis=1) & np.isfinite(log_post)
    s = int(ok.sum())
    tail = (1.0 - ci_prob) / 2.0
    if s < _MIN_LOO_DRAWS:
        # PSIS cannot smooth so few draws (arviz raises); the ELPD is not known (NaN,
        # reported as null) rather than a crash, as on the RC column chiu's base model
        interval = {n: (float("nan"), float("nan")) for n in names}
        return LaplaceLoo(math.nan, np.full(pointwise.shape[1], np.nan), interval,
                          n_draws=s, map_i=map_i, n_parameters=posterior.ndim,
                          note=f"only {s} of {n_draws} Laplace draws are inside the prior's "
                               "support with a finite likelihood")
    theta = posterior.to_natural(z[ok])
    interval = {}
    for n in names:
        j = posterior.names.index(n)
        lo, hi = np.quantile(theta[:, j], [tail, 1.0 - tail])
        interval[n] = (float(lo), float(hi))
    log_weights = log_post[ok] - log_q(z[ok])
    elpd, elpd_i, k_units = psis_loo(pointwise[ok], log_weights, with_k=True)
    k_corr = _pareto_k(log_weights)
    normed = log_weights - logsumexp(log_weights)
    ess = float(1.0 / np.sum(np.exp(2.0 * normed)))
    k_max = float(np.nanmax(k_units)) if np.any(np.isfinite(k_units)) else math.nan
    threshold = good_k(s)
    reasons = []
    if getattr(map_result, "laplace_note", None):
        reasons.append(f"the Laplace covariance is a stand-in: {map_result.laplace_note}")
    if not k_corr <= threshold and math.isfinite(k_corr):
        reasons.append(f"the Laplace draws are far from the posterior (Pareto k-hat "
                       f"{k_corr:.2f} of their importance weights, above {threshold:.2f}; "
                       f"{ess:.0f} effective of {s} draws)")
    if not k_max <= threshold and math.isfinite(k_max):
        reasons.append(f"leaving a unit out moves the posterior beyond what the draws cover "
                       f"(largest Pareto k-hat {k_max:.2f}, above {threshold:.2f})")
    return LaplaceLoo(elpd, elpd_i, interval, k_max, k_corr, threshold, ess, s,
                      "; ".join(reasons) or None, map_i, posterior.ndim)


def _units(posterior, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The leave-one-out units' log likelihoods ``(batch, units)`` and the log posterior
    in unconstrained coordinates ``(batch,)`` (``log_prob_z``'s, from the same
    simulations) at points ``z`` inside the prior's support.

    The units are each experiment's trials, or a single record's
    :data:`LOO_STRETCHES` stretches given the rest, under the noise the posterior holds
    (learnt from repeats: its estimate, as in the fit), so that the log posterior is the
    units' sum up to terms that do not depend on the parameters.
    """
    theta = posterior.to_natural(z)
    log_post = posterior.log_prior(theta) + posterior.log_jacobian(z)
    parts = []
    for e, lik in enumerate(posterior.likelihoods):
        x = posterior.simulate(theta, e)
        noise = posterior.noise_of(e, theta)
        log_post = log_post + lik.mean_log_likelihood(x, *noise)
        # a single record: leave out a stretch of it at a time, given the rest
        stretches = lik.stretch_pointwise(x, *noise, LOO_STRETCHES)
        parts.append(lik.pointwise(x, *noise) if stretches is None else stretches)
    return np.concatenate(parts, axis=1), log_post


def plugin_difference(a: LaplaceLoo, b: LaplaceLoo) -> tuple[float, float]:
    """A second witness to ``a``'s ELPD minus ``b``'s that needs no draws: the units'
    in-sample log likelihoods at the two MAPs, paired, less the parameters ``a`` adds
    (the optimism of an in-sample fit, one nat per parameter, as in AIC).

    Parameters
    ----------
    a, b : LaplaceLoo
        Two models' estimates over the same units.

    Returns
    -------
    difference : float
        ``sum(a.map_i - b.map_i) - (a.n_parameters - b.n_parameters)``; NaN without
        both MAPs' log likelihoods.
    se : float
        Its standard error from the per-unit differences (:func:`paired_difference`).
    """
    if a.map_i is None or b.map_i is None:
        return math.nan, math.nan
    diff, se = paired_difference(a.map_i, b.map_i)
    return diff - (a.n_parameters - b.n_parameters), se


def _pareto_k(log_weights: np.ndarray) -> float:
    """Pareto k-hat of importance weights given by their logs (NaN where their tail has
    no spread: then they are alike, and need no smoothing)."""
    return smoothed_log_weights(log_weights)[1]


def psis_loo(pointwise: np.ndarray, log_weights: np.ndarray | None = None, *,
             with_k: bool = False):
    """The leave-one-unit-out ELPD of draws' pointwise log likelihoods, by PSIS.

    Each unit's term is ``log sum_s w_s p(y_i | theta_s)`` with ``w`` the Pareto-smoothed,
    normalised importance weights of the ratios ``log_weights - ll_i`` (draws of the
    posterior itself: ``log_weights`` zero). Where Pareto smoothing cannot run (ArviZ
    raises when a unit's tail of importance ratios has no spread: every draw gives that
    unit one log likelihood, as on a loaded muscle's record whose stretch the draws all
    fit alike), the unit's term is the plain importance-sampling estimate, exact for a
    unit whose log likelihood does not vary.

    Parameters
    ----------
    pointwise : numpy.ndarray
        ``(draws, units)`` finite log likelihoods.
    log_weights : numpy.ndarray, optional
        ``(draws,)`` log importance weights of draws that are not the posterior's (up
        to a constant: log posterior minus log proposal density); zero by default.
    with_k : bool
        Also return each unit's Pareto k-hat.

    Returns
    -------
    elpd : float
    elpd_i : numpy.ndarray
        Per unit.
    pareto_k : numpy.ndarray
        Per unit (NaN where not smoothed), with ``with_k`` only.

    Examples
    --------
    >>> ll = np.tile([-1.0, -2.0], (40, 1))
    >>> elpd, elpd_i = psis_loo(ll)
    >>> round(elpd, 6), elpd_i.round(6).tolist()
    (-3.0, [-1.0, -2.0])
    """
    pointwise = np.asarray(pointwise, dtype=float)
    lw = (np.zeros(pointwise.shape[0]) if log_weights is None
          else np.asarray(log_weights, dtype=float))
    elpd_i = np.empty(pointwise.shape[1])
    k = np.empty(pointwise.shape[1])
    for i in range(pointwise.shape[1]):
        smoothed, k[i] = smoothed_log_weights(lw - pointwise[:, i])
        elpd_i[i] = logsumexp(smoothed + pointwise[:, i])
    if with_k:
        return float(elpd_i.sum()), elpd_i, k
    return float(elpd_i.sum()), elpd_i


def loo_table(fits: list, labels: list) -> tuple[dict, list]:
    """Leave-one-trial-out ELPD of fits, each against the best and each against the last.

    Parameters
    ----------
    fits : list of xarray.DataTree
        Fits of the same trials, with their pointwise log likelihoods.
    labels : list of str
        One per fit.

    Returns
    -------
    elpd : dict
        Label to ``{"elpd", "se", "elpd_diff", "dse", "rank", "max_pareto_k"}``
        (the difference and its standard error against the best fit).
    steps : list of dict
        ``{"from", "to", "elpd_diff", "se"}`` of each fit against the one before it.
    """
    import arviz as az

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the largest Pareto k is kept in the table
        loos = {label: az.loo(tree, var_name="position_m")
                for label, tree in zip(labels, fits, strict=True)}
    elpd_i = {label: np.asarray(loos[label].elpd_i).reshape(-1) for label in labels}
    best = max(labels, key=lambda k: float(loos[k].elpd))
    order = sorted(labels, key=lambda k: -float(loos[k].elpd))
    elpd = {}
    for label in labels:
        diff, dse = paired_difference(elpd_i[label], elpd_i[best])
        elpd[label] = {"elpd": float(loos[label].elpd), "se": float(loos[label].se),
                       "elpd_diff": diff, "dse": dse,
                       "rank": order.index(label),
                       "max_pareto_k": float(np.max(np.asarray(loos[label].pareto_k)))}
    steps = []
    for a, b in zip(labels[:-1], labels[1:], strict=True):
        diff, se = paired_difference(elpd_i[b], elpd_i[a])
        steps.append({"from": a, "to": b, "elpd_diff": diff, "se": se})
    return elpd, steps
