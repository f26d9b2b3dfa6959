"""A higher-order noise model: the AR(p) of the repeats (disturbance and sensor together).

Learnt model-free from the repeats' Helmert contrasts (Yule-Walker, order by AIC) and
then fixed; its exact density, whitening and draws come from the Durbin-Levinson
predictors of orders ``0 .. p``. :class:`ArNoise` is the AR model itself,
:class:`ArFromRepeats` the noise model object a likelihood uses (chosen by
:func:`pmabayes.inference.noise.choose_noise_model` where the repeats reject AR(1) + white).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba
import numpy as np
from scipy import signal

from pmabayes.inference.noise.ar1 import AR1_WHITE
from pmabayes.inference.noise.base import NoiseModel, register_noise_model

if TYPE_CHECKING:
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.model.parameters import Parameter

__all__ = ["MAX_AR_ORDER", "levinson", "ArNoise", "ar_noise_from_repeats", "ArFromRepeats"]

#: Largest order of the autoregressive noise model fitted to the repeats
#: (:func:`ar_noise_from_repeats`).
MAX_AR_ORDER = 60


def levinson(acov: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Durbin-Levinson: predictor coefficients and innovation variances of orders 0..order.

    Parameters
    ----------
    acov : numpy.ndarray
        Autocovariance at lags ``0 .. order`` (at least).
    order : int
        Largest order.

    Returns
    -------
    coefficients : numpy.ndarray
        ``(order + 1, max(order, 1))``: row ``m`` holds the order-``m`` one-step
        predictor's coefficients (of lags 1..m) in its first ``m`` entries.
    variances : numpy.ndarray
        ``(order + 1,)``: the one-step prediction variances of those orders.
    """
    phi = np.zeros((order + 1, max(order, 1)))
    var = np.empty(order + 1)
    var[0] = acov[0]
    for m in range(1, order + 1):
        prev = phi[m - 1, : m - 1]
        k = (acov[m] - prev @ acov[m - 1:0:-1]) / var[m - 1]
        phi[m, : m - 1] = prev - k * prev[::-1]
        phi[m, m - 1] = k
        var[m] = var[m - 1] * (1.0 - k * k)
    return phi, var


@numba.njit(cache=True, error_model="numpy")
def _ar_loglik_fixed_noise(y, xt, scale, phi, var):
    """Exact Gaussian log-likelihood of ``scale * (y[m] - xt[:, b])`` under a stationary
    AR(p) noise, ``(series, batch)``; ``xt`` is ``(n, batch)`` (the simulator's layout).

    The innovations come from the Durbin-Levinson predictors of orders 0..p: the
    order-``k`` one for sample ``k < p`` and the order-``p`` one after, so the density
    is exact, not conditional on the first ``p`` samples. The batch is the inner loop,
    so that its members' filters run side by side.
    """
    n = y.shape[1]
    n_series = y.shape[0]
    batch = xt.shape[1]
    p = var.shape[0] - 1
    out = np.zeros((n_series, batch))
    const = 0.0
    for k in range(n):
        const += math.log(var[k if k < p else p])
    v = np.empty((n, batch))
    e = np.empty(batch)
    for m in range(n_series):
        acc = out[m]
        for k in range(n):
            y_mk = y[m, k]
            x_k = xt[k]
            v_k = v[k]
            for b in range(batch):
                v_k[b] = scale * (y_mk - x_k[b])
        for k in range(n):
            o = k if k < p else p
            v_k = v[k]
            for b in range(batch):
                e[b] = v_k[b]
            for j in range(o):
                c = phi[o, j]
                v_j = v[k - 1 - j]
                for b in range(batch):
                    e[b] -= c * v_j[b]
            inv = 1.0 / var[o]
            for b in range(batch):
                acc[b] -= 0.5 * e[b] * e[b] * inv
        for b in range(batch):
            acc[b] -= 0.5 * (const + n * math.log(2.0 * math.pi))
    return out


@numba.njit(cache=True, error_model="numpy")
def _ar_filter_draws(white, phi, var):
    """Stationary AR(p) series from standard normal ``white`` ``(series, n)``, in place:
    each sample is its Durbin-Levinson prediction from the past plus the innovation
    (orders 0..p, as in :func:`_ar_loglik_fixed_noise`), so the series are exact draws."""
    n_series, n = white.shape
    p = var.shape[0] - 1
    for m in range(n_series):
        w = white[m]
        for k in range(n):
            o = k if k < p else p
            pred = 0.0
            for j in range(o):
                pred += phi[o, j] * w[k - 1 - j]
            w[k] = pred + math.sqrt(var[o]) * w[k]
    return white


@dataclass(frozen=True, eq=False)
class ArNoise:
    """A stationary AR(p) model of one trial's noise (disturbance and sensor together).

    Defined by its autocovariance at lags ``0 .. order`` (from the repeats,
    :func:`ar_noise_from_repeats`); its predictors of orders ``0 .. order`` and their
    variances follow by :func:`levinson`, so the exact likelihood
    (:class:`ArFromRepeats`), the
    whitening (:meth:`whiten`) and the draws (:meth:`draw`) are exact from the first
    sample.

    Parameters
    ----------
    autocovariance_m2 : numpy.ndarray
        Autocovariance at lags ``0 .. order``, in m^2.

    Attributes
    ----------
    order : int
    coefficients : numpy.ndarray
        ``(order + 1, max(order, 1))``, Durbin-Levinson predictor coefficients (row
        ``m``: order ``m``, first ``m`` entries).
    variances : numpy.ndarray
        ``(order + 1,)``, one-step prediction variances in m^2.
    """

    autocovariance_m2: np.ndarray
    order: int = field(init=False)
    coefficients: np.ndarray = field(init=False, repr=False)
    variances: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        acov = np.ascontiguousarray(np.asarray(self.autocovariance_m2, dtype=float).reshape(-1))
        if acov.size < 1 or not np.all(np.isfinite(acov)) or not acov[0] > 0:
            raise ValueError(f"an AR noise needs a finite autocovariance with a positive "
                             f"variance at lag 0, got {acov[:3]}...")
        order = acov.size - 1
        phi, var = levinson(acov, order)
        if not np.all(var > 0):
            raise ValueError("the autocovariance is not positive definite (a prediction "
                             "variance is not positive); it cannot define an AR noise")
        object.__setattr__(self, "autocovariance_m2", acov)
        object.__setattr__(self, "order", order)
        object.__setattr__(self, "coefficients", np.ascontiguousarray(phi))
        object.__setattr__(self, "variances", np.ascontiguousarray(var))

    @property
    def name(self) -> str:
        """The model in words, e.g. ``"AR(7) from the repeats"``."""
        return f"AR({self.order}) from the repeats"

    def autocovariance(self, n_lags: int) -> np.ndarray:
        """The model's autocovariance at lags ``0 .. n_lags - 1`` (m^2).

        Lags up to :attr:`order` are the defining ones; beyond, the AR recursion
        extends them.

        Parameters
        ----------
        n_lags : int

        Returns
        -------
        numpy.ndarray
        """
        p = self.order
        out = np.zeros(max(n_lags, p + 1))
        out[: p + 1] = self.autocovariance_m2
        a = self.coefficients[p, :p]
        for k in range(p + 1, out.size):
            out[k] = a @ out[k - 1:k - 1 - p:-1]  # lags k-1 .. k-p
        return out[:n_lags]

    def log_likelihood(self, v: np.ndarray) -> np.ndarray:
        """Exact log density of series of this noise.

        Parameters
        ----------
        v : numpy.ndarray
            ``(n_samples,)`` or ``(series, n_samples)``.

        Returns
        -------
        numpy.ndarray
            ``(series,)``.
        """
        v = np.ascontiguousarray(np.atleast_2d(np.asarray(v, dtype=float)))
        zero = np.zeros((v.shape[1], 1))
        return _ar_loglik_fixed_noise(v, zero, 1.0, self.coefficients, self.variances)[:, 0]

    def whiten(self, v: np.ndarray) -> np.ndarray:
        """Exact standardised innovations of a series of one trial's noise.

        Parameters
        ----------
        v : numpy.ndarray
            ``(n_samples,)``, e.g. a Helmert contrast, or ``sqrt(R)`` times the
            trial mean's residual.

        Returns
        -------
        numpy.ndarray
            ``(n_samples,)``; independent N(0, 1) when the AR model holds.
        """
        v = np.asarray(v, dtype=float).reshape(-1)
        p = min(self.order, v.size)
        out = np.empty(v.size)
        for t in range(p):  # the start: predictors of growing order (Durbin-Levinson)
            out[t] = (v[t] - self.coefficients[t, :t] @ v[t - 1::-1][:t]) / math.sqrt(
                self.variances[t])
        a = np.concatenate(([1.0], -self.coefficients[p, :p]))
        out[p:] = signal.lfilter(a, [1.0], v)[p:] / math.sqrt(self.variances[p])
        return out

    def draw(self, n_series: int, n_samples: int, rng: np.random.Generator) -> np.ndarray:
        """Draw stationary series of this noise, exact from the first sample.

        Parameters
        ----------
        n_series, n_samples : int
            Output shape.
        rng : numpy.random.Generator

        Returns
        -------
        numpy.ndarray
            ``(n_series, n_samples)``.
        """
        white = rng.standard_normal((n_series, n_samples))
        return _ar_filter_draws(white, self.coefficients, self.variances)

    def to_dict(self) -> dict:
        """JSON-ready record: ``model``, ``order``, ``coefficients`` (the order-p
        predictor's), ``innovation_std_m`` and ``autocovariance_m2`` (what defines it,
        :meth:`from_dict`)."""
        return {"model": self.name, "order": self.order,
                "coefficients": [float(c) for c in self.coefficients[self.order, : self.order]],
                "innovation_std_m": float(math.sqrt(self.variances[self.order])),
                "autocovariance_m2": [float(c) for c in self.autocovariance_m2]}

    @classmethod
    def from_dict(cls, record: dict) -> ArNoise:
        """Rebuild from :meth:`to_dict`'s record (its ``autocovariance_m2``).

        Parameters
        ----------
        record : dict

        Returns
        -------
        ArNoise
        """
        return cls(np.asarray(record["autocovariance_m2"], dtype=float))


def ar_noise_from_repeats(contrasts, *, max_order: int = MAX_AR_ORDER) -> ArNoise:
    """The AR model of one trial's noise from the repeats' contrasts (model-free).

    Yule-Walker: the autocovariance of the Helmert contrasts (series of the noise
    alone), pooled over them, then the order by AIC from 1 up to ``max_order``
    (at most a tenth of the shortest series).

    Parameters
    ----------
    contrasts : numpy.ndarray or sequence of them
        ``(n_contrasts, n_samples)``
        (:attr:`pmabayes.inference.likelihood.Likelihood.contrasts`), or several such arrays
        (experiments that share their noise) pooled together.
    max_order : int
        Largest order tried.

    Returns
    -------
    ArNoise
    """
    arrays = [np.asarray(contrasts, dtype=float)] if isinstance(contrasts, np.ndarray) else [
        np.asarray(c, dtype=float) for c in contrasts]
    arrays = [c for c in arrays if c.shape[0] > 0]
    if not arrays:
        raise ValueError("no repeats: an AR noise is estimated from two or more repeats")
    n_min = min(c.shape[1] for c in arrays)
    order_max = int(max(1, min(max_order, n_min // 10)))
    raw = 0.0
    for c in arrays:
        n = c.shape[1]
        spec = np.fft.rfft(c, n=2 * n, axis=1)
        raw = raw + np.fft.irfft(np.sum(np.abs(spec) ** 2, axis=0), axis=0)[: order_max + 1]
    n_eff = sum(c.shape[0] * c.shape[1] for c in arrays)
    acov = raw / n_eff
    _, var = levinson(acov, order_max)
    aic = n_eff * np.log(np.maximum(var, 1e-300)) + 2.0 * np.arange(order_max + 1)
    order = int(np.argmin(aic[1:]) + 1)
    return ArNoise(acov[: order + 1])




@register_noise_model
class ArFromRepeats(NoiseModel):
    """The AR(p) of the repeats as a likelihood's noise: fixed, no parameters of its own.

    Its density ignores the noise parameters it is given (the AR(1) + white estimate
    the noise group carries from the repeats). Its :meth:`whiten` is AR(1) + white
    with those parameters, as the criticism's whitening of a fit has always been: the
    criticism whitens by the repeats' AR(p) itself where they reject AR(1) + white
    (:class:`pmabayes.criticism.whiteness.NoiseModelCheck`). The exact AR(p)
    density is for complete series: samples not observed are refused.

    Parameters
    ----------
    ar : ArNoise
    """

    name = "ar"
    takes_missing = False
    from_repeats = True
    description = (AR1_WHITE.description + "; where the repeats reject it, the likelihood "
                   "uses their AR(p) model (experiments[i].noise_model)")

    def __init__(self, ar: ArNoise) -> None:
        if not isinstance(ar, ArNoise):
            raise TypeError(f"ar must be an ArNoise, got {type(ar).__name__}")
        self.ar = ar

    @property
    def label(self) -> str:
        """E.g. ``"AR(7) from the repeats"``."""
        return self.ar.name

    def parameters(self, likelihood: Likelihood) -> tuple[Parameter, ...]:
        """AR(1) + white's (the estimate from the repeats the group carries)."""
        return AR1_WHITE.parameters(likelihood)

    def log_likelihood(self, y: np.ndarray, x: np.ndarray, scale: float, noise: tuple,
                       observed: np.ndarray | None = None) -> np.ndarray:
        """The exact AR(p) density, ``(batch, series)``; ``noise`` is ignored.

        Raises
        ------
        ValueError
            With samples not observed.
        """
        if observed is not None:
            raise ValueError("the AR(p) of the repeats is exact for complete series only: "
                             "samples not observed need AR(1) + white")
        if x.shape[1] == 1:
            return self._series(y, x[:, 0, :], scale)
        return np.concatenate([self._series(y[r:r + 1], x[:, r], scale)
                               for r in range(y.shape[0])], axis=1)

    def _series(self, y: np.ndarray, x: np.ndarray, scale: float) -> np.ndarray:
        xt = np.ascontiguousarray(x.T)  # the simulator's (n, batch): no copy
        out = _ar_loglik_fixed_noise(np.ascontiguousarray(y), xt, scale, self.ar.coefficients,
                                     self.ar.variances)
        return np.ascontiguousarray(out.T)

    def whiten(self, v: np.ndarray, scale: float, noise: tuple,
               seen: np.ndarray | None = None) -> np.ndarray:
        """AR(1) + white's, with the parameters given (see the class)."""
        return AR1_WHITE.whiten(v, scale, noise, seen)

    def draw(self, n_series: int, n_samples: int, noise: tuple,
             rng: np.random.Generator) -> np.ndarray:
        """:meth:`ArNoise.draw` (``noise`` is ignored)."""
        return self.ar.draw(n_series, n_samples, rng)

    def to_dict(self) -> dict:
        """:meth:`ArNoise.to_dict`, as fit files have recorded it (its
        ``autocovariance_m2`` names the model,
        :func:`pmabayes.inference.noise.noise_model_from_record`)."""
        return self.ar.to_dict()

    @classmethod
    def from_dict(cls, record: dict) -> ArFromRepeats:
        """From :meth:`to_dict`'s record (its ``autocovariance_m2``)."""
        return cls(ArNoise.from_dict(record))
