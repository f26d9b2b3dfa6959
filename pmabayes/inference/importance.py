"""Pareto-smoothed importance weights (PSIS; Vehtari et al. 2024), the one place that
smooths them: the criticism's leave-one-out ELPDs weight Laplace draws by them, and the
design resamples its draws to the posterior with them."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

__all__ = ["smoothed_log_weights"]


def smoothed_log_weights(log_ratios: np.ndarray) -> tuple[np.ndarray, float]:
    """Pareto-smoothed, normalised log importance weights and their k-hat.

    Parameters
    ----------
    log_ratios : numpy.ndarray
        Log importance ratios (target over proposal density, up to a constant), one per
        draw.

    Returns
    -------
    log_weights : numpy.ndarray
        The smoothed log weights; where the ratios' tail has no spread (ArviZ raises:
        they are alike, nothing to smooth), the plain normalised ones.
    k_hat : float
        The tail's Pareto shape (above 0.7 the weights are not to be relied on); NaN
        where there is no tail to fit.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.inference.importance import smoothed_log_weights
    >>> log_w, k_hat = smoothed_log_weights(np.random.default_rng(0).normal(size=400))
    >>> bool(np.isclose(np.exp(log_w).sum(), 1.0)), bool(k_hat < 0.7)
    (True, True)
    """
    from arviz_stats.base import array_stats

    lr = np.asarray(log_ratios, dtype=float)
    lr = lr - np.max(lr)
    try:
        # a tail far from Pareto (k-hat of several) overflows the smoothing's quantiles:
        # the k-hat says so, and the weights are then not relied on
        with np.errstate(over="ignore", invalid="ignore"):
            lw, k = array_stats.psislw(-lr, r_eff=1.0)
        return np.asarray(lw, dtype=float), float(k)
    except ValueError:
        return lr - logsumexp(lr), math.nan
