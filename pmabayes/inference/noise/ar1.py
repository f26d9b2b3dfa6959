"""The default noise model: a stationary AR(1) disturbance plus white sensor noise.

Its exact likelihood is a scalar Kalman filter with the disturbance as its state,
started from the stationary distribution; samples not observed are missing in the
filter (no update, the prediction carried on). The numba kernels live here;
:class:`Ar1White` is the model object that
:class:`pmabayes.inference.likelihood.Likelihood` delegates to.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numba
import numpy as np

from pmabayes.inference.noise.base import NoiseModel, register_noise_model
from pmabayes.model.parameters import LogNormal, Parameter, Uniform
from pmabayes.model.simulator import side_by_side, simulation_threads

if TYPE_CHECKING:
    from pmabayes.inference.likelihood import Likelihood

__all__ = ["NOISE_PARAMETERS", "NOISE_PER_AMPLITUDE", "ar1_noise", "measurement_noise",
           "Ar1White", "AR1_WHITE"]

#: The noise model's parameters, identified with every fit.
#:
#: :meta hide-value:
NOISE_PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "sigma_noise_m", "m", 5e-5, LogNormal(5e-5, 2.0), bounds=(0.0, math.inf),
        description="standard deviation of each trial's disturbance (stationary AR(1))",
        latex=r"\sigma",
    ),
    Parameter(
        "rho_noise", "1", 0.9, Uniform(-1.0, 1.0), bounds=(-0.999999, 0.999999),
        description="lag-one autocorrelation of the disturbance (per sample)",
        latex=r"\rho",
    ),
    Parameter(
        "sigma_white_m", "m", 5e-6, LogNormal(5e-6, 2.0), bounds=(0.0, math.inf),
        description="standard deviation of the sensor's white noise (quantisation)",
        latex=r"\sigma_w",
    ),
)


#: A force-input rig's noise priors follow its data: the disturbance's median is this
#: fraction of the positions' amplitude (half their range), the sensor's a tenth of
#: it; the muscle's defaults (50 um on a 40 mm amplitude) give the fraction.
NOISE_PER_AMPLITUDE = 5e-5 / 0.04


def scaled_to_motion(parameter: Parameter, likelihood: Likelihood, per_amplitude: float
                     ) -> Parameter:
    """A noise scale centred on ``per_amplitude`` times the data's amplitude of motion
    (half its range), for a force-input rig whose scale is the data's.

    Parameters
    ----------
    parameter : Parameter
        The noise scale, with a log-normal prior.
    likelihood : Likelihood
        The record's (its ``motion_m``).
    per_amplitude : float
        Noise per metre of amplitude (:data:`NOISE_PER_AMPLITUDE` for the disturbance).

    Returns
    -------
    Parameter
        ``parameter`` with that default and prior median, the prior's width kept.
    """
    s = per_amplitude * (0.5 * likelihood.motion_m)
    return dataclasses.replace(parameter, default=s, prior=LogNormal(s, parameter.prior.sigma))


def ar1_noise(
    n_series: int, n_samples: int, sigma, rho, rng: np.random.Generator
) -> np.ndarray:
    """Draw stationary AR(1) series, the disturbance of :class:`Ar1White`.

    Parameters
    ----------
    n_series, n_samples : int
        Output shape.
    sigma, rho : float or array_like
        Stationary standard deviation and lag-one autocorrelation, scalars or one
        per series.
    rng : numpy.random.Generator
        Source of the white noise.

    Returns
    -------
    numpy.ndarray
        ``(n_series, n_samples)``.
    """
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (n_series,))
    rho = np.broadcast_to(np.asarray(rho, dtype=float), (n_series,))
    white = rng.standard_normal((n_series, n_samples))
    innov = sigma * np.sqrt(1.0 - rho * rho)
    e = np.empty((n_series, n_samples))
    e[:, 0] = sigma * white[:, 0]
    for k in range(1, n_samples):
        e[:, k] = rho * e[:, k - 1] + innov * white[:, k]
    return e


def measurement_noise(n_series: int, n_samples: int, sigma, rho, white,
                      rng: np.random.Generator) -> np.ndarray:
    """Draw the noise model's whole noise: the AR(1) disturbance plus white sensor noise.

    Parameters
    ----------
    n_series, n_samples : int
        Output shape.
    sigma, rho, white : float or array_like
        ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m``, scalars or one per
        series.
    rng : numpy.random.Generator
        Source of the noise (the disturbance's draws first, then the sensor's).

    Returns
    -------
    numpy.ndarray
        ``(n_series, n_samples)``.
    """
    e = ar1_noise(n_series, n_samples, sigma, rho, rng)
    w = rng.standard_normal(e.shape)  # in place: long records times many series are large
    w *= np.broadcast_to(np.asarray(white, dtype=float), (n_series,))[:, None]
    e += w
    return e


@numba.njit(cache=True, error_model="numpy")
def _kalman_gains(sigma, rho, white, gains, variances):
    """Fill the filter's gains and innovation variances (``(n,)`` each) for complete data
    and one noise (scalars); returns the sum of the log variances."""
    return _masked_gains(sigma, rho, white, np.empty(0, dtype=np.bool_), gains, variances)[0]


@numba.njit(cache=True, error_model="numpy")
def _kalman_loglik(y, x, scale, sigma, rho, white):
    """Exact log-likelihood of ``scale * (y[r] - x[b])`` under the noise model.

    ``y`` is ``(series, n)``, ``x`` is ``(batch, n)`` or ``(1, n)`` (shared), and
    the noise parameters are ``(batch,)``. Returns ``(batch, series)``. A scalar
    Kalman filter, with the AR(1) disturbance as its state, started from the
    stationary distribution. The gains and innovation variances depend only on the
    noise, not on the data: they are computed once for each run of batch members with
    the same noise (the whole batch when the noise is fixed) and shared by the series.
    """
    batch = sigma.shape[0]
    n = y.shape[1]
    n_series = y.shape[0]
    shared = x.shape[0] == 1
    out = np.zeros((batch, n_series))
    est = np.empty(n_series)
    gains = np.empty(n)
    variances = np.empty(n)
    log2pi = math.log(2.0 * math.pi)
    const = 0.0
    for b in range(batch):
        if b == 0 or not (sigma[b] == sigma[b - 1] and rho[b] == rho[b - 1]
                          and white[b] == white[b - 1]):
            const = _kalman_gains(sigma[b], rho[b], white[b], gains, variances)
        for m in range(n_series):
            est[m] = 0.0
        for k in range(n):
            s_k = variances[k]
            gain = gains[k]
            for m in range(n_series):
                v = scale * (y[m, k] - x[0 if shared else b, k]) - est[m]
                out[b, m] -= 0.5 * v * v / s_k
                est[m] = rho[b] * (est[m] + gain * v)
        for m in range(n_series):
            out[b, m] -= 0.5 * (const + n * log2pi)
    return out


@numba.njit(cache=True, error_model="numpy")
def _kalman_loglik_fixed_noise(y, xt, scale, sigma, rho, white):
    """:func:`_kalman_loglik` for a batch that shares one noise: ``xt`` is ``(n, batch)``
    (the simulator's own layout) and the noise parameters are scalars.

    The gains are computed once, and the batch is the inner loop, so that the filters
    of its members run side by side (vectorised); each member's arithmetic is the
    same as in :func:`_kalman_loglik`, so the results are equal bit for bit. Returns
    ``(series, batch)``.
    """
    n = y.shape[1]
    n_series = y.shape[0]
    batch = xt.shape[1]
    out = np.zeros((n_series, batch))
    est = np.empty(batch)
    gains = np.empty(n)
    variances = np.empty(n)
    const = _kalman_gains(sigma, rho, white, gains, variances)
    for m in range(n_series):
        est[:] = 0.0
        acc = out[m]
        for k in range(n):
            s_k = variances[k]
            gain = gains[k]
            y_mk = y[m, k]
            x_k = xt[k]
            for b in range(batch):
                v = scale * (y_mk - x_k[b]) - est[b]
                acc[b] -= 0.5 * v * v / s_k
                est[b] = rho * (est[b] + gain * v)
        for b in range(batch):
            acc[b] -= 0.5 * (const + n * math.log(2.0 * math.pi))
    return out


def _noise_loglik(y: np.ndarray, x: np.ndarray, scale: float, sigma: np.ndarray,
                  rho: np.ndarray, white: np.ndarray) -> np.ndarray:
    """:func:`_kalman_loglik` (same arguments and result, ``(batch, series)``), by the
    fastest of equal routes: a batch that shares one noise (the noise fixed by
    repeats) computes its gains once and runs its members side by side, or only once
    when the model output is shared too."""
    batch = sigma.shape[0]
    if batch > 1 and bool(np.all(sigma == sigma[0]) and np.all(rho == rho[0])
                          and np.all(white == white[0])):
        if x.shape[0] == 1:
            one = _kalman_loglik(y, np.ascontiguousarray(x), scale, sigma[:1], rho[:1],
                                 white[:1])
            return np.repeat(one, batch, axis=0)
        # x is usually the simulator's (n, batch) array seen transposed: no copy
        out = _kalman_loglik_fixed_noise(y, np.ascontiguousarray(x.T), scale,
                                         float(sigma[0]), float(rho[0]), float(white[0]))
        return np.ascontiguousarray(out.T)
    return _kalman_loglik(y, np.ascontiguousarray(x), scale, sigma, rho, white)



@numba.njit(cache=True, error_model="numpy")
def _kalman_innovations(y, scale, sigma, rho, white, seen):
    """Standardised innovations ``v_k / sqrt(S_k)`` of ``scale * y`` (one series).

    For data the model and noise describe, these are independent N(0, 1): the
    whitened residual that system identification's classic tests expect. At samples
    not ``seen`` there is none (NaN): the filter carries its prediction across them.
    """
    n = y.shape[0]
    out = np.full(n, np.nan)
    s2 = sigma * sigma
    q = s2 * (1.0 - rho * rho)
    r = white * white
    p = s2
    est = 0.0
    for k in range(n):
        if seen[k]:
            s_k = p + r
            gain = p / s_k
            v = scale * y[k] - est
            out[k] = v / math.sqrt(s_k)
            est = rho * (est + gain * v)
            p = rho * rho * (1.0 - gain) * p + q
        else:
            est = rho * est
            p = rho * rho * p + q
    return out


# -- samples not observed: the filter predicts across them --------------------------
# A Kalman filter takes a missing observation as it is: no update, the prediction
# carried on. The kernels below are the masked forms of those above (``obs`` True where
# a sample enters the likelihood); complete data keep the kernels above, bit for bit.


@numba.njit(cache=True, error_model="numpy")
def _masked_gains(sigma, rho, white, seen, gains, variances):
    """Fill the filter's gains and innovation variances for one mask ``seen`` (``(n,)``,
    or empty where every sample is seen); returns the sum of the log variances and the
    number of samples seen.

    The Riccati recursion of the state's variance ``p`` meets, to the bit, a fixed
    point or a cycle of two values within a few samples (hundreds with a correlation
    near 1); from there every step
    repeats one already taken, so its numbers are copied, not computed again (a
    division and a logarithm a sample, most of a likelihood's time on a long record):
    the same numbers, in the same order.
    """
    s2 = sigma * sigma
    q = s2 * (1.0 - rho * rho)
    r = white * white
    p = s2
    const = 0.0
    count = 0
    every = seen.shape[0] == 0
    # the last two steps taken: their p on entry, s_k, gain and log s_k
    p_a = s_a = g_a = l_a = math.nan
    p_b = s_b = g_b = l_b = math.nan
    period = 0  # 0: computing; 1 or 2: repeating the last one or two steps
    for k in range(gains.shape[0]):
        if every or seen[k]:
            if period == 0:
                s_k = p + r
                gain = p / s_k
                log_s = math.log(s_k)
                p_next = rho * rho * (1.0 - gain) * p + q
                # the step before entered at p_b: one entering there again repeats it
                period = 1 if p_next == p else (2 if p_next == p_b else 0)
                p_a, s_a, g_a, l_a = p_b, s_b, g_b, l_b
                p_b, s_b, g_b, l_b = p, s_k, gain, log_s
                p = p_next
            elif period == 1:
                s_k, gain, log_s = s_b, g_b, l_b
            else:  # p is p_a or p_b: take that step, and enter the other
                if p == p_a:
                    s_k, gain, log_s, p = s_a, g_a, l_a, p_b
                else:
                    s_k, gain, log_s, p = s_b, g_b, l_b, p_a
            const += log_s
            count += 1
            variances[k] = s_k
            gains[k] = gain
        else:
            p = rho * rho * p + q
            period = 0
            p_b = math.nan  # the step before is no longer the last
    return const, count


@numba.njit(cache=True, error_model="numpy", nogil=True)  # members' runs side by side
def _kalman_loglik_masked_fixed(y, xt, scale, sigma, rho, white, obs):
    """Exact log-likelihood of ``scale * (y[m] - xt[:, m or 0, b])`` with samples not
    seen, for a batch that shares one noise (scalars).

    ``y`` is ``(series, n)`` (any value where not seen), ``xt`` ``(n, 1 or series,
    batch)``, ``obs`` ``(1 or series, n)`` (True where seen). Returns ``(series,
    batch)``. The gains are computed once per mask row, and the batch is the inner
    loop, so that its members' filters run side by side.
    """
    n = y.shape[1]
    n_series = y.shape[0]
    batch = xt.shape[2]
    own_x = xt.shape[1] > 1
    own_obs = obs.shape[0] > 1
    out = np.zeros((n_series, batch))
    est = np.empty(batch)
    gains = np.empty(n)
    variances = np.empty(n)
    const, count = 0.0, 0
    for m in range(n_series):
        seen = obs[m if own_obs else 0]
        if m == 0 or own_obs:
            const, count = _masked_gains(sigma, rho, white, seen, gains, variances)
        xi = m if own_x else 0
        est[:] = 0.0
        acc = out[m]
        for k in range(n):
            if seen[k]:
                s_k = variances[k]
                gain = gains[k]
                y_mk = y[m, k]
                x_k = xt[k, xi]
                for b in range(batch):
                    v = scale * (y_mk - x_k[b]) - est[b]
                    acc[b] -= 0.5 * v * v / s_k
                    est[b] = rho * (est[b] + gain * v)
            else:
                for b in range(batch):
                    est[b] = rho * est[b]
        for b in range(batch):
            acc[b] -= 0.5 * (const + count * math.log(2.0 * math.pi))
    return out


#: The fewest member-samples per thread for which a sampled noise's filters (one per
#: member) run in threads (:func:`_masked_loglik`): some 2 ms of work against a thread's
#: start of some 50 us.
_RUN_WORK = 100_000


def _masked_loglik(y: np.ndarray, x3: np.ndarray, scale: float, sigma: np.ndarray,
                   rho: np.ndarray, white: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """The log-likelihood of ``scale * (y[m] - x3[b, m or 0])`` with samples not seen,
    ``(batch, series)``; ``x3`` is ``(batch, 1 or series, n)``, ``obs`` ``(1 or series,
    n)``."""
    xt = np.transpose(x3, (2, 1, 0))
    y = np.ascontiguousarray(np.where(np.broadcast_to(obs, y.shape), y, 0.0))
    obs = np.ascontiguousarray(obs)
    # one filter's gains per run of batch members that share their noise
    change = (np.diff(sigma) != 0) | (np.diff(rho) != 0) | (np.diff(white) != 0)
    edges = [0, *(np.flatnonzero(change) + 1).tolist(), sigma.size]
    out = np.empty((sigma.size, y.shape[0]))
    runs = list(zip(edges[:-1], edges[1:], strict=True))

    def filtered(some: list) -> None:  # each run's filter is its own arithmetic
        for a, b in some:
            out[a:b] = _kalman_loglik_masked_fixed(
                y, np.ascontiguousarray(xt[:, :, a:b]), scale, float(sigma[a]),
                float(rho[a]), float(white[a]), obs).T

    # runs of members with their own noise (a sampled noise) in threads, where there
    # are enough of them to pay for the threads
    k = min(simulation_threads(), len(runs) // 2, (len(runs) * y.shape[1]) // _RUN_WORK)
    side_by_side(filtered, [runs[i::k] for i in range(k)] if k > 1 else [runs])
    return out




def _lag_moment(d: np.ndarray, observed: np.ndarray | None, lag: int) -> float:
    """Mean of ``d[:, k] d[:, k - lag]`` over series ``d`` ``(series, n)``: over every
    pair, or over the pairs of samples both ``observed`` (``(1 or series, n)``; ``d`` is
    0 where a sample is not)."""
    n = d.shape[1]
    if observed is None:
        return float(np.mean(d[:, lag:] * d[:, : n - lag]))
    pairs = np.broadcast_to(observed[:, lag:] & observed[:, : n - lag], (d.shape[0], n - lag))
    return float(np.sum(d[:, lag:] * d[:, : n - lag]) / max(int(pairs.sum()), 1))


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


@register_noise_model
class Ar1White(NoiseModel):
    """AR(1) disturbance plus white sensor noise per trial (the default).

    Parameters :data:`NOISE_PARAMETERS` (``sigma_noise_m``, ``rho_noise``,
    ``sigma_white_m``); learnt from the repeats where there are some
    (:func:`pmabayes.inference.noise.estimate_noise`), else sampled with the model
    under the bound of :attr:`pmabayes.inference.likelihood.Likelihood.rho_max`.
    """

    name = "ar1"
    from_repeats = True
    description = ("AR(1) disturbance plus white sensor noise per trial, stationary, "
                   "independent between trials")
    label = "AR(1) + white"

    def parameters(self, likelihood: Likelihood) -> tuple[Parameter, ...]:
        """:data:`NOISE_PARAMETERS`, with the noise's scale on the data's for a
        force-input rig (:data:`NOISE_PER_AMPLITUDE`), except for a record without
        repeats (``noise_source == "record"``): there ``rho_noise`` is bounded by
        :attr:`~pmabayes.inference.likelihood.Likelihood.rho_max` (uniform prior on
        ``[-rho_max, rho_max]``).

        Parameters
        ----------
        likelihood : Likelihood
            The record's.

        Returns
        -------
        tuple of Parameter
            ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m``.
        """
        sig, rho, white = NOISE_PARAMETERS
        force = likelihood.model.rig.input_kind == "force"
        if force:  # an oscillator's scale is the data's
            sig = scaled_to_motion(sig, likelihood, NOISE_PER_AMPLITUDE)
            white = scaled_to_motion(white, likelihood, 0.1 * NOISE_PER_AMPLITUDE)
        if likelihood.noise_source != "record":
            return (sig, rho, white) if force else NOISE_PARAMETERS
        r = likelihood.rho_max
        bounded = Parameter(
            "rho_noise", "1", 0.0, Uniform(-r, r), bounds=(-r, r),
            description=(f"lag-one autocorrelation of the disturbance, at most {r:.6g} (a "
                         "correlation time of "
                         f"{-likelihood.dataset.dt_s / math.log(r) * 1e3:.3g} ms)"),
            latex=r"\rho",
        )
        return (sig, bounded, white)

    def log_likelihood(self, y: np.ndarray, x: np.ndarray, scale: float, noise: tuple,
                       observed: np.ndarray | None = None) -> np.ndarray:
        """The Kalman filter's exact log density, ``(batch, series)`` (see
        :meth:`NoiseModel.log_likelihood`): complete series with one model output by the
        unmasked kernels, others by the masked ones."""
        if observed is None and x.shape[1] == 1:
            return _noise_loglik(y, x[:, 0, :], scale, *noise)
        if observed is None:
            observed = np.ones((1, y.shape[1]), dtype=bool)
        x = np.broadcast_to(x, (noise[0].size, *x.shape[1:]))  # a shared output (zeros)
        return _masked_loglik(y, x, scale, *noise, observed)

    def whiten(self, v: np.ndarray, scale: float, noise: tuple,
               seen: np.ndarray | None = None) -> np.ndarray:
        """Standardised Kalman innovations of ``scale * v`` (NaN where not ``seen``)."""
        seen = np.ones(v.size, dtype=bool) if seen is None else seen
        sigma, rho, white = (float(np.asarray(p).reshape(-1)[0]) for p in noise)
        return _kalman_innovations(np.ascontiguousarray(np.where(seen, v, 0.0)), scale,
                                   sigma, rho, white, seen)

    def draw(self, n_series: int, n_samples: int, noise: tuple,
             rng: np.random.Generator) -> np.ndarray:
        """:func:`measurement_noise`."""
        return measurement_noise(n_series, n_samples, *noise, rng)

    def to_dict(self) -> dict:
        """Nothing: a fit file's record without a ``noise_model`` is AR(1) + white, as
        every fit file has been (:func:`pmabayes.inference.noise.noise_model_from_record`)."""
        return {}

    def start(self, residual: np.ndarray, observed: np.ndarray | None,
              likelihood: Likelihood) -> tuple[np.ndarray, np.ndarray]:
        """From the residual's moments (variance, autocovariance at lags 1 and 2), the
        correlation within 99% of the record's bound; the second start's white part
        ``e^2`` times smaller (it may be tiny)."""
        c = [_lag_moment(residual[None], observed, k) for k in range(3)]
        return (_moment_start(*c, rho_high=0.99 * likelihood.rho_max),
                np.array([0.0, 0.0, -2.0]))

    def clip_start(self, z: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """A correlation at its guard (a disturbance slower than the guard allows)
        starts the polish just inside it, where its finite differences stay in the
        support."""
        edge = np.arctanh(0.99 * upper[1])
        out = z.copy()
        out[1] = np.clip(out[1], -edge, edge)
        return out


#: The default noise model (stateless: one object serves every likelihood).
AR1_WHITE = Ar1White()
