"""Leave-one-trial-out ELPD: PSIS-LOO over a MAP's Laplace draws, tables of fits side by
side, and the paired difference of two models' per-trial ELPDs with its standard error.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.special import logsumexp

__all__ = ["paired_difference", "laplace_loo", "psis_loo", "loo_table"]

#: Fewest usable draws for PSIS-LOO (its Pareto tail needs at least 5 of them).
_MIN_LOO_DRAWS = 25

#: Contiguous stretches a single record is cut into for its leave-one-out ELPD: with
#: one trial, leaving it out predicts the record from nothing, and its one term has no
#: spread to give a standard error.
LOO_STRETCHES = 10


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


def laplace_loo(posterior, map_result, rng: np.random.Generator, n_draws: int, ci_prob: float,
                names: tuple[str, ...] = ()) -> tuple[float, np.ndarray, dict]:
    """PSIS-LOO by trial and intervals, from draws of a MAP's Laplace approximation.

    Parameters
    ----------
    posterior : pmabayes.inference.density.Posterior
        The posterior of one or more experiments.
    map_result : pmabayes.inference.search.MapResult
        Its MAP, with the covariance of the Laplace approximation.
    rng : numpy.random.Generator
        Draws the parameters and, where the noise comes from repeats, the noise.
    n_draws : int
        Laplace draws (those outside the prior's support are dropped).
    ci_prob : float
        Probability of the equal-tailed intervals.
    names : tuple of str
        Parameters to give intervals of.

    Returns
    -------
    elpd : float
        Leave-one-trial-out ELPD over every trial of every experiment (an experiment of
        a single record: one of its :data:`LOO_STRETCHES` contiguous stretches at a time,
        given the rest, :meth:`~pmabayes.inference.likelihood.Likelihood.stretch_pointwise`,
        where its noise model allows); NaN when fewer than 25 draws are inside the support
        with a finite likelihood.
    elpd_i : numpy.ndarray
        Its per-trial (per-stretch) terms (NaN then too).
    interval : dict
        ``(low, high)`` of each of ``names`` (NaN then too).
    """
    z = rng.multivariate_normal(map_result.z, map_result.covariance_z, size=n_draws,
                                method="eigh")
    theta = posterior.to_natural(z)
    theta = theta[np.isfinite(posterior.log_prior(theta))]
    full = posterior.full_theta(theta)
    group_draws: dict = {}
    parts = []
    for e, lik in enumerate(posterior.likelihoods):
        x = lik.simulate(full)
        if posterior.noise_sampled(e):  # no repeats: the noise is in the draws
            noise = posterior.noise_of(e, theta)
        else:  # from the repeats: independent draws of its posterior, one set per group
            g = posterior.groups[e]
            if g not in group_draws:
                group_draws[g] = posterior.group_noise[g].draws(rng, theta.shape[0])
            noise = group_draws[g]
        # a single record: leave out a stretch of it at a time, given the rest
        stretches = lik.stretch_pointwise(x, *noise, LOO_STRETCHES)
        parts.append(lik.pointwise(x, *noise) if stretches is None else stretches)
    pointwise = np.concatenate(parts, axis=1)
    ok = np.all(np.isfinite(pointwise), axis=1)
    tail = (1.0 - ci_prob) / 2.0
    if ok.sum() < _MIN_LOO_DRAWS:
        # PSIS cannot smooth so few draws (arviz raises); the ELPD is not known (NaN,
        # reported as null) rather than a crash, as on the RC column chiu's base model
        interval = {n: (float("nan"), float("nan")) for n in names}
        return float("nan"), np.full(pointwise.shape[1], np.nan), interval
    interval = {}
    for n in names:
        j = posterior.names.index(n)
        lo, hi = np.quantile(theta[ok][:, j], [tail, 1.0 - tail])
        interval[n] = (float(lo), float(hi))
    return (*psis_loo(pointwise[ok], theta[ok][:, 0]), interval)


def psis_loo(pointwise: np.ndarray, draws: np.ndarray | None = None
             ) -> tuple[float, np.ndarray]:
    """The leave-one-unit-out ELPD of draws' pointwise log likelihoods, by PSIS.

    Where Pareto smoothing cannot run (ArviZ raises when a unit's tail of importance
    ratios has no spread: every draw gives that unit one log likelihood, as on a loaded
    muscle's record whose stretch the draws all fit alike), each unit's term is the
    plain importance-sampling estimate ``log S - logsumexp(-ll_i)``, exact for a unit
    whose log likelihood does not vary.

    Parameters
    ----------
    pointwise : numpy.ndarray
        ``(draws, units)`` finite log likelihoods.
    draws : numpy.ndarray, optional
        One parameter's draws ``(draws,)``, the posterior group ArviZ asks for (zeros
        by default).

    Returns
    -------
    elpd : float
    elpd_i : numpy.ndarray
        Per unit.

    Examples
    --------
    >>> ll = np.tile([-1.0, -2.0], (40, 1))
    >>> elpd, elpd_i = psis_loo(ll)
    >>> round(elpd, 6), elpd_i.round(6).tolist()
    (-3.0, [-1.0, -2.0])
    """
    import arviz as az

    draws = np.zeros(pointwise.shape[0]) if draws is None else draws
    tree = az.from_dict({"posterior": {"theta": draws[None]},
                         "log_likelihood": {"position_m": pointwise[None]}},
                        dims={"position_m": ["trial"]})
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pareto k is reported in the summary instead
            loo = az.loo(tree, var_name="position_m")
        return float(loo.elpd), np.asarray(loo.elpd_i).reshape(-1)
    except ValueError:
        elpd_i = math.log(pointwise.shape[0]) - logsumexp(-pointwise, axis=0)
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
