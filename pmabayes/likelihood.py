"""The likelihood of an experiment's trials under a model and an AR(1) noise model.

Noise model
-----------
Every trial ``r`` of a data set is driven by the same commanded input, so the
model predicts the same position ``x_k(theta)`` for all of them. What differs
from trial to trial is a disturbance that is autocorrelated in time (supply
pressure, temperature, the braid settling), seen through a sensor that adds
white noise of its own (encoder quantisation, electronics)::

    y_rk = x_k(theta) + e_rk + w_rk
    e_rk = rho e_r,k-1 + sqrt(1 - rho^2) sigma eps_rk,    w_rk ~ N(0, sigma_w^2)

with ``eps`` standard normal. Everything is independent between trials, and each
trial's disturbance is stationary from its first sample. The three noise
parameters are estimated, never fixed: ``sigma_noise_m`` (the disturbance's
standard deviation), ``rho_noise`` (its lag-one autocorrelation) and
``sigma_white_m`` (the sensor's white noise). The exact likelihood comes from a
scalar Kalman filter.

Why not i.i.d. Gaussian: with 10^5 strongly correlated samples an i.i.d.
likelihood counts each sample as new information and yields intervals far too
narrow (90% intervals that miss every true value). Why not AR(1) alone: white
sensor noise makes an AR(1) fit lower its correlation, which understates the
low-frequency noise where a slow chirp carries its information. The intervals
are then too narrow too. The assumptions that remain: the disturbance is the
same stationary process in every trial, independent between trials, with
exponentially decaying correlation. ``analyses/calibration.py`` measures how well
the resulting intervals cover the truth.

Computation, and what the noise is learnt from
----------------------------------------------
Write each trial as the trial mean plus a deviation, ``y_rk = ybar_k + d_rk``
(``sum_r d_rk = 0``), and let ``g_k = ybar_k - x_k(theta)``. The likelihood of
the ``R`` trials factorises exactly into two parts:

* the deviations, which do not depend on the model at all: rotated by Helmert
  contrasts they are ``R - 1`` independent series of the same noise process
  (:meth:`Likelihood.deviation_log_likelihood`); and
* the trial mean's residual, ``sqrt(R) g``, one more series of that process
  (:meth:`Likelihood.mean_log_likelihood`).

An evaluation for the model costs one simulation and one filter pass over ``g``
(O(n_samples)), whatever the number of trials.

:mod:`pmabayes.fit` learns the noise from the deviations alone, i.e. from the
spread between repeated trials, and the model given that noise. If the noise were
fitted to the mean residual too, a model that cannot describe the data would
have its error explained away as slow noise (``rho -> 1``, ``sigma`` inflated):
the AR(1) likelihood barely penalises a slowly varying residual. With the noise
fixed by repeatability, model error stays visible. When the model is right, this
and the joint posterior agree to O(1/R).

Single records
--------------
A record without repeated trials (:attr:`Likelihood.noise_source`):

* **periodic** (``period_samples`` declared): its periods are the repeats. All of
  them when the record starts in steady state; from the second on when it starts
  from rest, since the first holds the transient. The noise is learnt from the
  periods' deviations from their mean, model-free as for trials; the model's
  likelihood is that of the whole record.
* **not periodic**: nothing but the record identifies the noise, so it is fitted
  with the model, and the guard above is replaced by one on the noise model
  itself (:meth:`Likelihood.noise_parameters`): the disturbance's correlation
  time is bounded by ``1 / (2 pi GUARD_FACTOR f_in)``, ``f_in`` the frequency
  below which 99% of the input's variance lies. Its spectrum is then flat up to
  ten times the input's band, where a model's misfit lives (the input's band and
  the harmonics hysteresis makes of it). To absorb a misfit there the noise would
  have to rise at all frequencies, against the record's own high-frequency
  residual; what it cannot absorb stays in the innovations, whose whiteness test
  then judges the model. The price: a disturbance that really is slow cannot be
  told from model error in one record, and is not modelled; repeat the record, or
  make it periodic.

Several experiments
-------------------
Each experiment (a data set with its own input, rig and trials) has its own
:class:`Likelihood`; :class:`pmabayes.posterior.Posterior` sums their log
likelihoods, each given its experiment's noise. :class:`JointLikelihood` presents
them as one output for the global search (a cost that weighs every experiment the
same) and the quality check.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pmabayes.data import Dataset
from pmabayes.model import Model
from pmabayes.parameters import LogNormal, Parameter, Uniform
from pmabayes.simulator import simulate_dataset

__all__ = ["NOISE_PARAMETERS", "NOISE_SOURCES", "GUARD_FACTOR", "Likelihood", "JointLikelihood",
           "LikelihoodError", "ar1_noise", "measurement_noise"]

#: The noise model's parameters, identified with every fit.
NOISE_PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "sigma_noise_m", "m", 5e-5, LogNormal(5e-5, 2.0), bounds=(1e-9, 1e-2),
        description="standard deviation of each trial's disturbance (stationary AR(1))",
        latex=r"\sigma",
    ),
    Parameter(
        "rho_noise", "1", 0.9, Uniform(-1.0, 1.0), bounds=(-0.999999, 0.999999),
        description="lag-one autocorrelation of the disturbance (per sample)",
        latex=r"\rho",
    ),
    Parameter(
        "sigma_white_m", "m", 5e-6, LogNormal(5e-6, 2.0), bounds=(1e-12, 1e-2),
        description="standard deviation of the sensor's white noise (quantisation)",
        latex=r"\sigma_w",
    ),
)


def ar1_noise(
    n_series: int, n_samples: int, sigma, rho, rng: np.random.Generator
) -> np.ndarray:
    """Draw stationary AR(1) series, the noise model of :class:`Likelihood`.

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
            s2 = sigma[b] * sigma[b]
            q = s2 * (1.0 - rho[b] * rho[b])
            r = white[b] * white[b]
            p = s2
            const = 0.0
            for k in range(n):
                s_k = p + r
                gain = p / s_k
                const += math.log(s_k)
                variances[k] = s_k
                gains[k] = gain
                p = rho[b] * rho[b] * (1.0 - gain) * p + q
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
    s2 = sigma * sigma
    q = s2 * (1.0 - rho * rho)
    r = white * white
    p = s2
    const = 0.0
    for k in range(n):
        s_k = p + r
        gain = p / s_k
        const += math.log(s_k)
        variances[k] = s_k
        gains[k] = gain
        p = rho * rho * (1.0 - gain) * p + q
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
def _rms_by_time(y, xt):
    """RMS of ``y - xt[:, b]`` per column of ``xt`` ``(n, batch)``, in one pass over
    memory in its own order (NumPy's reduction across the strided axis is slow)."""
    n, batch = xt.shape
    out = np.zeros(batch)
    for k in range(n):
        yk = y[k]
        for b in range(batch):
            d = yk - xt[k, b]
            out[b] += d * d
    for b in range(batch):
        out[b] = math.sqrt(out[b] / n)
    return out


@numba.njit(cache=True, error_model="numpy")
def _kalman_innovations(y, scale, sigma, rho, white):
    """Standardised innovations ``v_k / sqrt(S_k)`` of ``scale * y`` (one series).

    For data the model and noise describe, these are independent N(0, 1): the
    whitened residual that system identification's classic tests expect.
    """
    n = y.shape[0]
    out = np.empty(n)
    s2 = sigma * sigma
    q = s2 * (1.0 - rho * rho)
    r = white * white
    p = s2
    est = 0.0
    for k in range(n):
        s_k = p + r
        gain = p / s_k
        v = scale * y[k] - est
        out[k] = v / math.sqrt(s_k)
        est = rho * (est + gain * v)
        p = rho * rho * (1.0 - gain) * p + q
    return out


#: What identifies the noise without the model, per experiment (see :class:`Likelihood`).
NOISE_SOURCES: tuple[str, ...] = ("trials", "periods", "record")

#: For a record without repeats, the disturbance's spectrum must stay flat up to this
#: multiple of the input's upper frequency (see :attr:`Likelihood.rho_max`).
GUARD_FACTOR: float = 10.0


def _noise_repeats(dataset: Dataset) -> tuple[str, np.ndarray]:
    """The noise source of a data set and the repeated series it offers.

    Trials when there are two or more; else the periods in steady state of a
    periodic record (all of them when it starts in steady state, from the second
    on when it starts from rest); else the record alone.
    """
    if dataset.n_trials >= 2:
        return "trials", np.ascontiguousarray(dataset.position_m)
    y = dataset.position_m[0]
    period, n_per = dataset.period_samples, dataset.n_periods
    if period is not None and n_per is not None:
        first = 0 if dataset.starts_in_steady_state else 1
        if n_per - first >= 2:
            segs = y[first * period: n_per * period].reshape(n_per - first, period)
            return "periods", np.ascontiguousarray(segs)
    return "record", np.ascontiguousarray(y[None, :])


class LikelihoodError(ValueError):
    """The data cannot be fitted as given (too few trials, no motion, wrong rig)."""


class Likelihood:
    """AR(1) likelihood of the trials of one experiment, which share one input.

    Parameters
    ----------
    model : Model
        The composed model, on this experiment's rig.
    dataset : Dataset
        One experiment: one or more trials, all sharing the input (the commanded
        pressure or force).
    substeps : int
        Simulator substeps per sample (see :func:`pmabayes.simulate`).

    Attributes
    ----------
    noise_source : str
        What identifies the noise without the model (:data:`NOISE_SOURCES`):
        ``"trials"`` (two or more repeated trials), ``"periods"`` (one record of a
        declared periodic input, its periods in steady state taken as repeats) or
        ``"record"`` (one record without repeats: the noise is identified jointly
        with the model, under :meth:`noise_parameters`' guard).
    n_repeats : int
        The number of repeated series the noise is learnt from without the model
        (trials or periods; 1 for ``"record"``).

    Raises
    ------
    LikelihoodError
        With trials of different inputs, an input kind that does not match the rig,
        or positions that never change.
    """

    def __init__(self, model: Model, dataset: Dataset, *, substeps: int = 1) -> None:
        where = dataset.source or "the data set"
        if dataset.input_name != model.rig.input_name:
            raise LikelihoodError(
                f"{where}: the input column is {dataset.input_name!r} but the model's rig "
                f"({model.rig.name}) expects {model.rig.input_name!r}; use a matching rig"
            )
        same = np.all(dataset.input == dataset.input[0], axis=1)
        if not same.all():
            bad = int(dataset.trial_ids[np.argmin(same)])
            raise LikelihoodError(
                f"{where}: trial {bad} has a different input from trial "
                f"{int(dataset.trial_ids[0])}; repeated trials must share the commanded input"
            )
        motion = float(np.ptp(dataset.position_m))
        if motion == 0.0:
            raise LikelihoodError(
                f"{where}: every position is {float(dataset.position_m.flat[0])!r} m, so there is "
                "nothing to fit; check the position column and that the sensor was recording"
            )
        self.model = model
        self.dataset = dataset
        self.substeps = int(substeps)
        self.n_trials, self.n_samples = dataset.position_m.shape
        self.input = np.ascontiguousarray(dataset.input[0])
        self.y_mean = dataset.mean_position_m
        self._trials = np.ascontiguousarray(dataset.position_m)
        self.noise_source, repeats = _noise_repeats(dataset)
        self.n_repeats = repeats.shape[0]
        self._repeats = repeats
        if self.n_repeats >= 2:
            # Helmert contrasts: R - 1 orthonormal combinations of the repeats that
            # remove their mean; each is a series of the noise process alone
            r = self.n_repeats
            helmert = np.zeros((r - 1, r))
            for j in range(r - 1):
                helmert[j, : j + 1] = 1.0
                helmert[j, j + 1] = -(j + 1.0)
                helmert[j] /= math.sqrt((j + 1.0) * (j + 2.0))
            self._contrasts = np.ascontiguousarray(helmert @ repeats)
            self._d = repeats - repeats.mean(axis=0)
        else:
            self._contrasts = np.zeros((0, self.n_samples))
            self._d = np.zeros((0, self.n_samples))
        self.motion_m = motion

    # -- the noise guard for records without repeats ----------------------------
    @property
    def input_frequency_hz(self) -> float:
        """The input's upper frequency: 99% of its variance lies below it.

        Where a model's misfit lives (with the harmonics that hysteresis makes of
        it); the noise guard of :meth:`noise_parameters` keeps the disturbance's
        spectrum flat far above it.
        """
        u = self.input - self.input.mean()
        power = np.abs(np.fft.rfft(u)) ** 2
        power[0] = 0.0
        total = power.sum()
        if not total > 0:  # a constant input: no time scale of its own
            return 0.5 * self.dataset.sample_rate_hz
        freq = np.fft.rfftfreq(self.n_samples, self.dataset.dt_s)
        k = int(np.searchsorted(np.cumsum(power) / total, 0.99))
        return float(freq[min(k, freq.size - 1)])

    @property
    def rho_max(self) -> float:
        """Largest lag-one correlation the noise of a record without repeats may have.

        The disturbance's correlation time is bounded by
        ``1 / (2 pi GUARD_FACTOR f_in)`` (``f_in``: :attr:`input_frequency_hz`),
        i.e. its spectrum is flat up to ``GUARD_FACTOR`` times the input's upper
        frequency. Returned for any noise source; used for ``"record"``.
        """
        f_in = max(self.input_frequency_hz, self.dataset.sample_rate_hz / self.n_samples)
        tau_max = 1.0 / (2.0 * math.pi * GUARD_FACTOR * f_in)
        return float(min(math.exp(-self.dataset.dt_s / tau_max), 0.999999))

    def noise_parameters(self) -> tuple[Parameter, ...]:
        """The noise parameters with their priors for this experiment.

        :data:`NOISE_PARAMETERS`, except for a record without repeats
        (``noise_source == "record"``): there ``rho_noise`` is bounded by
        :attr:`rho_max` (uniform prior on ``[-rho_max, rho_max]``), so that the
        disturbance cannot become the slow process that would explain a model's
        misfit away.

        Returns
        -------
        tuple of Parameter
        """
        if self.noise_source != "record":
            return NOISE_PARAMETERS
        sig, rho, white = NOISE_PARAMETERS
        r = self.rho_max
        guarded = Parameter(
            "rho_noise", "1", 0.0, Uniform(-r, r), bounds=(-r, r),
            description=(f"lag-one autocorrelation of the disturbance, at most {r:.4g} (its "
                         "correlation time far below the input's time scales)"),
            latex=r"\rho",
        )
        return (sig, guarded, white)

    # -- model output ---------------------------------------------------------
    def simulate(self, theta: np.ndarray) -> np.ndarray:
        """Model positions ``(batch, n_samples)`` for a full parameter array."""
        return simulate_dataset(self.model, theta, self.dataset, substeps=self.substeps)

    def rms_cost(self, x: np.ndarray) -> np.ndarray:
        """The paper's cost: RMS of the trial mean minus the model, per batch member."""
        x = np.atleast_2d(x)
        if x.shape[0] > 1 and x.T.flags.c_contiguous:  # the simulator's own layout
            return _rms_by_time(self.y_mean, x.T)
        return np.sqrt(np.mean((self.y_mean - x) ** 2, axis=1))

    # -- likelihood -------------------------------------------------------------
    @staticmethod
    def _params(sigma, rho, white, batch: int):
        return tuple(
            np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), (batch,)))
            for v in (sigma, rho, white)
        )

    def deviation_log_likelihood(self, sigma, rho, white) -> np.ndarray:
        """Log-likelihood of the deviations from the trial mean (model-free).

        The deviations are ``R - 1`` independent series of the noise process in
        disguise: their Helmert contrasts. The repeats are the trials, or the
        periods of a single periodic record (:attr:`noise_source`); a record
        without repeats has none (the result is 0).

        Parameters
        ----------
        sigma, rho, white : array_like
            Noise parameters (``sigma_noise_m``, ``rho_noise``, ``sigma_white_m``),
            scalars or ``(batch,)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        batch = np.broadcast(np.asarray(sigma), np.asarray(rho), np.asarray(white)).size
        pars = self._params(sigma, rho, white, batch)
        zero = np.zeros((1, self._contrasts.shape[1]))
        return _noise_loglik(self._contrasts, zero, 1.0, *pars).sum(axis=1)

    def mean_log_likelihood(self, x: np.ndarray, sigma, rho, white) -> np.ndarray:
        """Log-likelihood of the trial mean given the model.

        The density of ``sqrt(R) (ybar - x)``, one more series of the noise process
        and the orthonormal complement of the contrasts, so that it adds to
        :meth:`deviation_log_likelihood` exactly.

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(batch, n_samples)``.
        sigma, rho, white : array_like
            Noise parameters, scalars or ``(batch,)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        x = np.atleast_2d(x)
        pars = self._params(sigma, rho, white, x.shape[0])
        return _noise_loglik(self.y_mean[None, :], x, math.sqrt(self.n_trials), *pars)[:, 0]

    def log_likelihood(self, x: np.ndarray, sigma, rho, white) -> np.ndarray:
        """Total log-likelihood of all trials, per batch member.

        Equal to :meth:`deviation_log_likelihood` plus :meth:`mean_log_likelihood`
        for repeated trials; for a single record (periodic or not) the record's
        likelihood, :meth:`mean_log_likelihood` (its periods identify the noise but
        are not data beside the record).

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(batch, n_samples)``.
        sigma, rho, white : array_like
            Noise parameters, scalars or ``(batch,)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        x = np.atleast_2d(x)
        mean = self.mean_log_likelihood(x, sigma, rho, white)
        if self.noise_source != "trials":
            return mean
        return self.deviation_log_likelihood(*self._params(sigma, rho, white, x.shape[0])) + mean

    def whiten(self, v: np.ndarray, sigma: float, rho: float, white: float) -> np.ndarray:
        """Standardised Kalman innovations of ``sqrt(R) v`` under the noise model.

        Linear in ``v``. Applied to the trial mean's residual it gives
        :meth:`innovations`; applied to sensitivities, their whitened versions.

        Parameters
        ----------
        v : numpy.ndarray
            A series on the data's time grid, ``(n_samples,)``.
        sigma, rho, white : float
            Noise parameters.

        Returns
        -------
        numpy.ndarray
            ``(n_samples,)``.
        """
        v = np.ascontiguousarray(np.asarray(v, dtype=float).reshape(-1))
        return _kalman_innovations(v, math.sqrt(self.n_trials), float(sigma), float(rho),
                                   float(white))

    def innovations(self, x: np.ndarray, sigma: float, rho: float, white: float) -> np.ndarray:
        """Standardised innovations of the trial mean's residual under the noise model.

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(n_samples,)``.
        sigma, rho, white : float
            Noise parameters.

        Returns
        -------
        numpy.ndarray
            ``(n_samples,)``; independent N(0, 1) when the model describes the data.
        """
        return self.whiten(self.y_mean - np.asarray(x, dtype=float).reshape(-1),
                           sigma, rho, white)

    def pointwise(self, x: np.ndarray, sigma, rho, white) -> np.ndarray:
        """Log-likelihood of each trial, ``(batch, n_trials)``; sums to :meth:`log_likelihood`.

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(batch, n_samples)``.
        sigma, rho, white : array_like
            Noise parameters, scalars or ``(batch,)``.

        Returns
        -------
        numpy.ndarray
        """
        x = np.atleast_2d(x)
        pars = self._params(sigma, rho, white, x.shape[0])
        return _noise_loglik(self._trials, x, 1.0, *pars)



class JointLikelihood:
    """Several experiments seen as one, for the global search and the quality check.

    Physical parameters are shared, so one parameter array simulates every
    experiment; the outputs are concatenated along time. Each experiment keeps its
    own :class:`Likelihood` (its data, rig, input and noise).

    Parameters
    ----------
    likelihoods : sequence of Likelihood
        One per experiment, with models that share their parameters (same effects
        and fixed values; the rigs may differ).
    names : sequence of str
        The experiments' names.

    Raises
    ------
    LikelihoodError
        If the experiments' models do not share their parameters.
    """

    def __init__(self, likelihoods, names) -> None:
        self.likelihoods = list(likelihoods)
        self.names = list(names)
        first = self.likelihoods[0].model
        for lik in self.likelihoods[1:]:
            if [p.name for p in lik.model.parameters] != [p.name for p in first.parameters]:
                raise LikelihoodError(
                    f"{lik.dataset.source or 'an experiment'}: its model has parameters "
                    f"{[p.name for p in lik.model.parameters]}, the first experiment's "
                    f"{[p.name for p in first.parameters]}; experiments of one fit share the "
                    "model's effects")
        self.model = first
        self.dataset = self.likelihoods[0].dataset
        self.substeps = self.likelihoods[0].substeps
        self.sizes = [lik.n_samples for lik in self.likelihoods]
        self._edges = np.cumsum([0, *self.sizes])
        self.n_samples = int(self._edges[-1])
        self.y_mean = np.concatenate([lik.y_mean for lik in self.likelihoods])
        self.input = np.concatenate([lik.input for lik in self.likelihoods])
        self.motions_m = np.array([float(np.ptp(lik.y_mean)) for lik in self.likelihoods])

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """Concatenated outputs ``(batch, n_samples)`` cut into each experiment's.

        Parameters
        ----------
        x : numpy.ndarray
            ``(batch, n_samples)`` or ``(n_samples,)``.

        Returns
        -------
        list of numpy.ndarray
        """
        x = np.atleast_2d(x)
        return [x[:, a:b] for a, b in zip(self._edges[:-1], self._edges[1:], strict=True)]

    def simulate(self, theta: np.ndarray) -> np.ndarray:
        """Every experiment's model positions, concatenated: ``(batch, n_samples)``."""
        return np.concatenate([lik.simulate(theta) for lik in self.likelihoods], axis=1)

    def rms_costs(self, x: np.ndarray) -> np.ndarray:
        """Each experiment's RMS cost, ``(batch, n_experiments)``."""
        return np.stack([lik.rms_cost(xe) for lik, xe in
                         zip(self.likelihoods, self.split(x), strict=True)], axis=1)

    def rms_cost(self, x: np.ndarray) -> np.ndarray:
        """The combined cost: the experiments' RMS costs, each relative to its motion.

        ``mean_motion * sqrt(mean_e (rms_e / motion_e)^2)``, in metres: every
        experiment weighs the same whatever its length or amplitude, and with one
        experiment it is the paper's RMS cost.

        Parameters
        ----------
        x : numpy.ndarray
            Concatenated model positions ``(batch, n_samples)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        rel = self.rms_costs(x) / self.motions_m
        return self.motions_m.mean() * np.sqrt(np.mean(rel * rel, axis=1))
