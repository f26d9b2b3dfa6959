"""The scores of a candidate experiment, from the candidates' predicted responses.

Everything is computed on *whitened* responses: the fitted noise model's standardised
innovations of the trial mean of the experiment's ``R`` trials
(:meth:`pmabayes.inference.noise.base.NoiseModel.whiten`, linear). There the noise is
independent N(0, 1) at every sample, so that a measured trial mean is a whitened model
response plus a standard normal vector.

Discrimination (:func:`discrimination`). Each candidate model's predictive distribution
of the new data, given the data so far, is taken Gaussian: the mean and the covariance
of its posterior draws' whitened responses, plus the unit noise (Box and Hill's
criterion, 1967, and Buzzi-Ferraris' in its Gaussian form: a model whose parameters are
uncertain predicts with the spread of its draws added to the noise). Its log density is
exact for that Gaussian by the Woodbury identity (the draws' spread has the rank of
their number). The expected discrimination is estimated by Monte Carlo over (the true
model, a posterior draw of it, the noise): the data such a truth gives are scored by
every model's predictive density, and the log Bayes factor of the true model over the
strongest other one (equal prior odds) is averaged; the rate at which the true model
wins is the rate at which it is named. The draws that make the truths are not those that
make the predictive densities, so a truth is never scored by its own draw. The Monte
Carlo standard error is the spread over the truths over their number's square root (a
truth's noise replicates averaged first: they are not independent of each other).

A true model with the higher predictive density is not yet one ``pmabayes diagnose``
names: it names the better of two candidates only where their difference, paired over
the trials, exceeds two of its standard errors. So each Monte Carlo trial mean is also
split into the experiment's ``R`` trials (its deviations from the mean drawn anew: for
Gaussian noise they are independent of it), each trial scored by every model's
predictive density of one trial (the draws' spread plus ``R`` times the unit noise),
and the true model counts as *named decisively* where its sum of per-trial differences
over each other model exceeds two of their standard errors, ``sqrt(R var)``, as
:func:`pmabayes.criticism.elpd.paired_difference` takes it. That rate, not the rate of a
higher density, is what a user's diagnose would report (on the next experiment's trials
alone: the first experiment's trials, on which the candidates fit alike, add little).

Parameters (:func:`shrinkage`). The Laplace covariance ``C`` of the data so far and the
whitened sensitivities ``J`` of the experiment at a posterior draw give the covariance
after it, ``(C^-1 + J^T J)^-1``; a parameter's 90% interval shrinks (in the fit's
unconstrained coordinates: a positive parameter's log) by the square root of the ratio
of its variances.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

__all__ = ["Discrimination", "discrimination", "shrinkage", "whiten_rows"]


def whiten_rows(noise_model, noise: tuple, n_trials: int, x: np.ndarray) -> np.ndarray:
    """The standardised innovations of each row's trial mean of ``n_trials`` trials.

    Parameters
    ----------
    noise_model : NoiseModel
        The fitted noise model (a likelihood's ``noise``).
    noise : tuple of float
        Its parameters at the MAP.
    n_trials : int
        Trials the experiment repeats: their mean's noise is the model's over
        ``sqrt(n_trials)``.
    x : numpy.ndarray
        Responses ``(rows, n_samples)``.

    Returns
    -------
    numpy.ndarray
        ``(rows, n_samples)``.
    """
    scale = math.sqrt(n_trials)
    return np.array([noise_model.whiten(np.ascontiguousarray(row), scale, noise)
                     for row in np.atleast_2d(x)])


@dataclass(frozen=True)
class Discrimination:
    """How well an experiment tells the candidates apart.

    Parameters
    ----------
    score : float
        Expected log Bayes factor of the true model over the strongest other one.
    score_se : float
        Its Monte Carlo standard error.
    named_rate : float
        Expected rate at which the true model has the highest predictive density.
    named_se : float
        Its Monte Carlo standard error.
    pairs : numpy.ndarray
        ``(K, K)``: the mean log Bayes factor of model ``i`` over model ``j`` when ``i``
        is true (0 on the diagonal).
    n_samples : int
        Monte Carlo samples (truths) behind the numbers.
    decisive_rate : float
        Expected rate at which the true model is named beyond two standard errors of
        its per-trial differences from every other (diagnose's rule); NaN with fewer
        than two trials.
    decisive_se : float
        Its Monte Carlo standard error.
    """

    score: float
    score_se: float
    named_rate: float
    named_se: float
    pairs: np.ndarray
    n_samples: int
    decisive_rate: float = math.nan
    decisive_se: float = math.nan

    def to_dict(self, names: Sequence[str]) -> dict:
        """JSON-ready, the pairs by the candidates' names."""
        return {"expected_log_bayes_factor": self.score, "mc_se": self.score_se,
                "named_rate": self.named_rate, "named_rate_mc_se": self.named_se,
                "n_monte_carlo": self.n_samples,
                "named_decisively_rate": self.decisive_rate,
                "named_decisively_mc_se": self.decisive_se,
                "log_bayes_factor_when_true": {
                    a: {b: float(self.pairs[i, j]) for j, b in enumerate(names) if j != i}
                    for i, a in enumerate(names)}}


def _log_predictive(evidence: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Log density (less the constant ``n log(2 pi) / 2``) of rows ``y`` under
    N(mean of ``evidence``, I + covariance of ``evidence``), by Woodbury."""
    m = evidence.mean(axis=0)
    u = (evidence - m).T / math.sqrt(max(evidence.shape[0] - 1, 1))  # (n, draws)
    chol = np.linalg.cholesky(np.eye(u.shape[1]) + u.T @ u)
    logdet = 2.0 * float(np.sum(np.log(np.diag(chol))))
    r = y - m
    s = solve_triangular(chol, (r @ u).T, lower=True)
    return -0.5 * (np.einsum("ij,ij->i", r, r) - np.einsum("ij,ij->j", s, s) + logdet)


def discrimination(truths: Sequence[np.ndarray], evidence: Sequence[np.ndarray],
                   rng: np.random.Generator, n_noise: int = 4,
                   n_trials: int = 1) -> Discrimination:
    """Monte Carlo of the expected discrimination between ``K`` candidate models.

    Parameters
    ----------
    truths : sequence of numpy.ndarray
        Per model, whitened responses ``(n_truth, n)`` of posterior draws that play the
        true model.
    evidence : sequence of numpy.ndarray
        Per model, whitened responses ``(n_draws, n)`` of other posterior draws, that
        make its predictive density.
    rng : numpy.random.Generator
        Draws the noise.
    n_noise : int
        Noise vectors per truth (cheap: they need no simulation).
    n_trials : int
        Trials whose mean the whitened responses are (``R``); with two or more, the
        rate of a decisive naming is estimated too (module docstring).

    Returns
    -------
    Discrimination
    """
    k = len(truths)
    labels = np.repeat(np.concatenate([np.full(t.shape[0], i) for i, t in enumerate(truths)]),
                       n_noise)
    y = np.repeat(np.concatenate(truths, axis=0), n_noise, axis=0)
    y = y + rng.standard_normal(y.shape)
    lp = np.stack([_log_predictive(e, y) for e in evidence], axis=1)  # (samples, K)
    own = lp[np.arange(y.shape[0]), labels]
    others = lp.copy()
    others[np.arange(y.shape[0]), labels] = -np.inf
    margin = own - others.max(axis=1)
    named = margin > 0
    pairs = np.zeros((k, k))
    for i in range(k):
        rows = labels == i
        pairs[i] = (lp[rows, i][:, None] - lp[rows]).mean(axis=0)
    # a truth's noise replicates are not independent of each other: the standard errors
    # are over the truths (each one's mean over its replicates)
    per_margin = margin.reshape(-1, n_noise).mean(axis=1)
    per_named = named.reshape(-1, n_noise).mean(axis=1)
    n = per_margin.size
    rate = float(named.mean())
    decisive_rate, decisive_se = math.nan, math.nan
    if n_trials >= 2:
        decisive = _decisive(y, labels, evidence, rng, int(n_trials))
        decisive_rate = float(decisive.mean())
        decisive_se = _rate_se(decisive.reshape(-1, n_noise).mean(axis=1), decisive_rate)
    return Discrimination(
        score=float(margin.mean()), score_se=float(per_margin.std(ddof=1) / math.sqrt(n)),
        named_rate=rate, named_se=_rate_se(per_named, rate),
        pairs=pairs, n_samples=int(n), decisive_rate=decisive_rate,
        decisive_se=decisive_se)


def _rate_se(per_truth: np.ndarray, rate: float) -> float:
    """The Monte Carlo standard error of a rate from its per-truth means; at a rate of 0
    or 1 the spread is 0, but ``n`` truths resolve no better than ``1/n``."""
    n = per_truth.size
    return float(per_truth.std(ddof=1)) / math.sqrt(n) if 0 < rate < 1 else 1.0 / n


def _decisive(y: np.ndarray, labels: np.ndarray, evidence: Sequence[np.ndarray],
              rng: np.random.Generator, n_trials: int) -> np.ndarray:
    """Whether each Monte Carlo trial mean ``y`` (rows) names its true model (``labels``)
    beyond two standard errors of the per-trial differences from every other model.

    The ``R`` trials are the mean plus deviations ``sqrt(R) (e_r - mean(e))``: one trial's
    noise is ``sqrt(R)`` in units of the trial mean's. A trial's predictive density under
    a model is N(mean of its draws, their covariance + R I), that of ``evidence / sqrt(R)``
    at ``y_r / sqrt(R)`` less a constant the same for every model.
    """
    r = n_trials
    e = rng.standard_normal((r, *y.shape))
    trials = y[None] + math.sqrt(r) * (e - e.mean(axis=0))  # (R, samples, n)
    flat = trials.reshape(-1, y.shape[1]) / math.sqrt(r)
    lp = np.stack([_log_predictive(ev / math.sqrt(r), flat).reshape(r, -1)
                   for ev in evidence], axis=2)  # (R, samples, K)
    rows = np.arange(y.shape[0])
    own = lp[:, rows, labels]  # (R, samples)
    out = np.ones(y.shape[0], dtype=bool)
    for k in range(len(evidence)):
        d = own - lp[:, :, k]
        total = d.sum(axis=0)
        se = np.sqrt(r * d.var(axis=0))
        out &= (labels == k) | (total > 2.0 * se)
    return out


def shrinkage(covariance: np.ndarray, jacobians: Sequence[np.ndarray],
              columns: Sequence[int]) -> np.ndarray:
    """Factors by which the experiment shrinks the parameters' 90% intervals.

    Parameters
    ----------
    covariance : numpy.ndarray
        The Laplace covariance of the data so far, ``(p, p)``, unconstrained coordinates.
    jacobians : sequence of numpy.ndarray
        Per posterior draw, the whitened sensitivities ``(n, p)`` of the experiment's
        response to the same coordinates.
    columns : sequence of int
        The parameters asked about.

    Returns
    -------
    numpy.ndarray
        ``(draws, len(columns))``: each width before over width after (>= 1).
    """
    cov = 0.5 * (covariance + covariance.T)
    precision = np.linalg.inv(cov)
    before = np.diag(cov)[list(columns)]
    out = []
    for jac in jacobians:
        after = np.linalg.inv(precision + jac.T @ jac)
        out.append(np.sqrt(before / np.diag(after)[list(columns)]))
    return np.array(out)
