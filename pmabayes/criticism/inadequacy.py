"""The model's inadequacy learnt from its training residual, for predictive bands that
still mean what they say when the model is wrong.

Kennedy and O'Hagan write a measurement as the model plus a *discrepancy* plus noise.
Here the discrepancy ``delta(t)`` is a zero-mean stationary Gaussian process with an
exponential covariance (continuous-time AR(1), a Matérn-1/2 kernel)::

    cov(delta(t), delta(t + h)) = sigma_d^2 exp(-|h| / tau_d)

and its two hyperparameters are fitted to the fit's training residual (the trial mean
minus the posterior-mean prediction) *beyond the measurement noise*: the residual is
modelled as ``delta`` plus the noise of a trial mean (the fit's AR(1) disturbance and
white sensor noise, their variances divided by the number of trials, held at the fit's
posterior medians).

* ``sigma_d^2`` by moments: the residual's mean square less the noise's variance. The
  band's coverage is about the errors' marginal spread, which this matches; the
  likelihood's own estimate of the variance is poorly determined when the correlation
  time comes out as long as the record (a wrong model's residual is slow), and gave
  bands that covered less evenly in the study ``analyses/discrepancy_bands.py``.
* ``tau_d`` by maximum likelihood, the variance held, the likelihood exact (a two-state
  Kalman filter; samples not observed are skipped).

When the likelihood ratio against no discrepancy is not significant (:data:`LEVEL`,
two degrees of freedom), the discrepancy is zero: an adequate model keeps its bands as
they were.

:func:`learn_inadequacy` does the fit; :meth:`Inadequacy.draw` draws discrepancies to
add to a posterior-predictive band (:mod:`~pmabayes.criticism.validation`). The
discrepancy is stationary: it says how large and how slow the model's errors were on
the training data, not where they fall on new data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from scipy import optimize, stats

from pmabayes.inference.likelihood import ar1_noise

__all__ = ["LEVEL", "ResidualRecord", "Inadequacy", "learn_inadequacy"]

#: Level of the likelihood-ratio test of a discrepancy against none.
LEVEL = 0.01


@dataclass(frozen=True)
class ResidualRecord:
    """One training experiment's residual and the noise of its trial mean.

    Parameters
    ----------
    residual_m : numpy.ndarray
        Trial mean minus the posterior-mean prediction (NaN where not observed).
    dt_s : float
        Sample interval.
    sigma_m, rho, white_m : float
        The fit's noise of one trial (AR(1) disturbance sd, its lag-one correlation,
        white sensor noise sd).
    n_trials : int
        Trials averaged in the trial mean.
    """

    residual_m: np.ndarray
    dt_s: float
    sigma_m: float
    rho: float
    white_m: float
    n_trials: int


@numba.njit(cache=True)
def _loglik(r, phi, var_d, rho, var_e, var_w):
    """Exact log-likelihood of ``r = delta + e + w``: AR(1) ``delta`` (lag-one ``phi``,
    variance ``var_d``), AR(1) ``e`` (``rho``, ``var_e``), white ``w`` (``var_w``); NaN
    samples skipped (prediction only)."""
    m0 = 0.0
    m1 = 0.0
    p00 = var_d
    p01 = 0.0
    p11 = var_e
    q0 = var_d * (1.0 - phi * phi)
    q1 = var_e * (1.0 - rho * rho)
    out = 0.0
    for k in range(r.size):
        if k > 0:
            m0 *= phi
            m1 *= rho
            p00 = phi * phi * p00 + q0
            p01 = phi * rho * p01
            p11 = rho * rho * p11 + q1
        y = r[k]
        if y != y:
            continue
        s = p00 + 2.0 * p01 + p11 + var_w
        v = y - m0 - m1
        out += -0.5 * (math.log(2.0 * math.pi * s) + v * v / s)
        k0 = (p00 + p01) / s
        k1 = (p01 + p11) / s
        m0 += k0 * v
        m1 += k1 * v
        a00 = p00 - k0 * (p00 + p01)
        a01 = p01 - k0 * (p01 + p11)
        a11 = p11 - k1 * (p01 + p11)
        p00, p01, p11 = a00, a01, a11
    return out


@dataclass(frozen=True)
class Inadequacy:
    """The learnt discrepancy (see the module's docstring).

    Parameters
    ----------
    sigma_m : float
        Its stationary standard deviation (0: no discrepancy).
    corr_time_s : float
        Its correlation time ``tau_d`` (NaN when ``sigma_m`` is 0).
    log_lr : float
        Log-likelihood ratio of the fitted discrepancy against none (0 when the residual
        has no spread beyond the noise).
    significant : bool
        Whether ``2 log_lr`` exceeds the chi-squared quantile of :data:`LEVEL` (2 dof).
    residual_rms_m : float
        RMS of the training residual, over the samples and experiments.
    noise_rms_m : float
        RMS of the trial mean's noise under the fit's noise (for comparison).
    n_samples : int
        Residual samples it was learnt from.
    """

    sigma_m: float
    corr_time_s: float
    log_lr: float
    significant: bool
    residual_rms_m: float
    noise_rms_m: float
    n_samples: int

    def draw(self, n_series: int, n_samples: int, dt_s: float, rng: np.random.Generator
             ) -> np.ndarray:
        """Draw discrepancies on a grid of interval ``dt_s``: ``(n_series, n_samples)``
        (zeros when there is none).

        Parameters
        ----------
        n_series, n_samples : int
            Output shape.
        dt_s : float
            Sample interval of the grid (the correlation is continuous in time).
        rng : numpy.random.Generator
            Source of the draws (not used when there is no discrepancy).

        Returns
        -------
        numpy.ndarray
        """
        if not self.sigma_m > 0:
            return np.zeros((n_series, n_samples))
        return ar1_noise(n_series, n_samples, self.sigma_m,
                         math.exp(-dt_s / self.corr_time_s), rng)

    def to_dict(self) -> dict:
        """JSON-ready values: the fields, NaN as None, and a one-line ``model``."""
        return {"model": "zero-mean stationary Gaussian process, covariance sigma_m^2 "
                         "exp(-|h| / corr_time_s), fitted to the training residual beyond "
                         "the fit's noise (maximum likelihood)",
                "sigma_m": self.sigma_m,
                "corr_time_s": None if math.isnan(self.corr_time_s) else self.corr_time_s,
                "log_lr": self.log_lr, "significant": self.significant,
                "residual_rms_m": self.residual_rms_m, "noise_rms_m": self.noise_rms_m,
                "n_samples": self.n_samples}


def _total(records: Sequence[ResidualRecord], sigma_d: float, tau_d: float) -> float:
    out = 0.0
    for rec in records:
        var_d = sigma_d * sigma_d
        phi = math.exp(-rec.dt_s / tau_d) if var_d > 0 else 0.0
        n = max(int(rec.n_trials), 1)
        out += _loglik(rec.residual_m, phi, var_d, rec.rho, rec.sigma_m**2 / n,
                       rec.white_m**2 / n)
    return out


def learn_inadequacy(records: Sequence[ResidualRecord]) -> Inadequacy:
    """Fit the discrepancy's size and correlation time to training residuals.

    Parameters
    ----------
    records : sequence of ResidualRecord
        One per training experiment (the hyperparameters are shared).

    Returns
    -------
    Inadequacy

    Raises
    ------
    ValueError
        Without a record or an observed residual sample.
    """
    records = [ResidualRecord(np.ascontiguousarray(r.residual_m, dtype=float), float(r.dt_s),
                              float(r.sigma_m), float(r.rho), float(r.white_m),
                              int(r.n_trials)) for r in records]
    seen = np.concatenate([r.residual_m[np.isfinite(r.residual_m)] for r in records]) \
        if records else np.zeros(0)
    if not seen.size:
        raise ValueError("no observed residual sample to learn the model's discrepancy from")
    rms = float(np.sqrt(np.mean(seen**2)))
    noise_var = sum((r.sigma_m**2 + r.white_m**2) / max(r.n_trials, 1)
                    * np.isfinite(r.residual_m).sum() for r in records) / seen.size
    null = _total(records, 0.0, 1.0)
    dt = min(r.dt_s for r in records)
    span = max(r.dt_s * r.residual_m.size for r in records)
    size = math.sqrt(max(rms * rms - noise_var, 0.0))
    if not size > 0:  # no spread beyond the noise at all
        return Inadequacy(0.0, math.nan, 0.0, False, rms, float(math.sqrt(noise_var)),
                          int(seen.size))

    def neg(log_tau: float) -> float:
        value = _total(records, size, math.exp(log_tau))
        return -value if math.isfinite(value) else 1e300

    grid = np.log(np.geomspace(3.0 * dt, max(10.0 * span, 10.0 * dt), 16))
    k = int(np.argmin([neg(g) for g in grid]))
    sol = optimize.minimize_scalar(neg, bracket=None, bounds=(grid[max(k - 1, 0)],
                                                              grid[min(k + 1, grid.size - 1)]),
                                   method="bounded", options={"xatol": 1e-4})
    log_tau = float(sol.x) if sol.fun <= neg(grid[k]) else float(grid[k])
    log_lr = float(-neg(log_tau) - null)
    significant = bool(2.0 * log_lr > stats.chi2.isf(LEVEL, 2))
    return Inadequacy(sigma_m=size if significant else 0.0,
                      corr_time_s=float(math.exp(log_tau)) if significant else math.nan,
                      log_lr=log_lr, significant=significant, residual_rms_m=rms,
                      noise_rms_m=float(math.sqrt(noise_var)), n_samples=int(seen.size))
