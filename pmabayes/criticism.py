"""Model criticism: compare the model with the measurements and see where it fails.

Stage 7 (diagnostics). Everything here takes a data set and a model output (and,
for the whiteness tests, the identified noise) and measures how far the model is
from the data relative to what repeatability allows:

* :func:`band_errors`: RMS, normalised RMS and maximum error of the trial mean in
  bands of the chirp's instantaneous frequency, each beside the noise floor in
  that band (the error a perfect model would have, from the spread between
  repeated trials);
* :func:`innovations`, :func:`autocorrelation`, :func:`cross_correlation` and
  :func:`ljung_box`: the classic whiteness and independence tests of system
  identification, applied to the residual whitened by the identified noise model.
  That residual is independent N(0, 1) when the model describes the data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal, stats

from pmabayes.data import Dataset
from pmabayes.likelihood import Likelihood

__all__ = [
    "DEFAULT_BANDS_HZ",
    "BandError",
    "instantaneous_frequency",
    "band_errors",
    "innovations",
    "autocorrelation",
    "cross_correlation",
    "ljung_box",
]

#: Bands of the chirp's instantaneous frequency (Hz) for error tables.
DEFAULT_BANDS_HZ: tuple[tuple[float, float], ...] = (
    (0.1, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 3.0),
)


def instantaneous_frequency(dataset: Dataset) -> np.ndarray:
    """Instantaneous frequency of the commanded input at each sample, in Hz.

    From the generator's chirp settings when the data set records them (synthetic
    data), otherwise from the phase of the analytic signal of the input (Hilbert
    transform), which suits any slowly swept sinusoidal command.

    Parameters
    ----------
    dataset : Dataset
        The data.

    Returns
    -------
    numpy.ndarray
        ``(n_samples,)``.
    """
    chirp = dataset.metadata.get("generator", {}).get("chirp") if dataset.metadata else None
    t = dataset.time_s
    if chirp:
        f0, f1, dur = chirp["f0_hz"], chirp["f1_hz"], chirp["duration_s"]
        return f0 + (f1 - f0) * (t - t[0]) / dur
    u = dataset.input[0] - dataset.input[0].mean()
    phase = np.unwrap(np.angle(signal.hilbert(u)))
    freq = np.gradient(phase, t) / (2.0 * math.pi)
    # smooth over ~0.5 s: the phase derivative is noisy where the amplitude is small
    width = max(1, int(round(0.5 / dataset.dt_s)))
    return np.convolve(freq, np.ones(width) / width, mode="same")


@dataclass(frozen=True)
class BandError:
    """Error of the trial mean in one frequency band.

    Parameters
    ----------
    band_hz : tuple of float
        ``(low, high)`` instantaneous frequency.
    n_samples : int
        Samples in the band.
    rms_m : float
        RMS of trial mean minus model.
    nrms : float
        ``rms_m`` divided by the RMS of the trial mean's motion (about its mean)
        in the band.
    max_m : float
        Largest absolute error.
    floor_m : float
        RMS a perfect model would have: the spread between trials in the band,
        divided by the square root of the number of trials.
    """

    band_hz: tuple[float, float]
    n_samples: int
    rms_m: float
    nrms: float
    max_m: float
    floor_m: float

    @property
    def ratio(self) -> float:
        """``rms_m / floor_m``: about 1 for a model that describes the data."""
        return self.rms_m / self.floor_m


def band_errors(
    dataset: Dataset,
    model_position_m: np.ndarray,
    *,
    bands_hz: tuple[tuple[float, float], ...] = DEFAULT_BANDS_HZ,
) -> list[BandError]:
    """Errors of the trial mean against the model, per band and overall.

    Parameters
    ----------
    dataset : Dataset
        Repeated trials.
    model_position_m : numpy.ndarray
        Model output on the data's time grid, ``(n_samples,)``.
    bands_hz : tuple of (low, high)
        Frequency bands; a last row covers all samples.

    Returns
    -------
    list of BandError
        One per band that holds samples, then the overall one (band ``(0, inf)``).

    Raises
    ------
    ValueError
        If the model output does not match the data's length, or there is only
        one trial (no floor without repeats).
    """
    x = np.asarray(model_position_m, dtype=float).reshape(-1)
    if x.shape != (dataset.n_samples,):
        raise ValueError(f"model output has {x.size} samples, the data {dataset.n_samples}")
    if dataset.n_trials < 2:
        raise ValueError("the noise floor needs at least 2 repeated trials")
    freq = instantaneous_frequency(dataset)
    mean = dataset.mean_position_m
    resid = mean - x
    spread = dataset.position_m.var(axis=0, ddof=1) / dataset.n_trials
    rows = []
    for lo, hi in (*bands_hz, (0.0, math.inf)):
        sel = (freq >= lo) & (freq < hi)
        if not sel.any():
            continue
        r = resid[sel]
        motion = mean[sel] - mean[sel].mean()
        rows.append(BandError(
            band_hz=(lo, hi), n_samples=int(sel.sum()),
            rms_m=float(np.sqrt(np.mean(r * r))),
            nrms=float(np.sqrt(np.mean(r * r)) / max(np.sqrt(np.mean(motion**2)), 1e-300)),
            max_m=float(np.max(np.abs(r))),
            floor_m=float(np.sqrt(np.mean(spread[sel]))),
        ))
    return rows


def innovations(likelihood: Likelihood, model_position_m: np.ndarray, noise) -> np.ndarray:
    """The trial mean's residual whitened by the identified noise model.

    Parameters
    ----------
    likelihood : Likelihood
        Data and noise model.
    model_position_m : numpy.ndarray
        Model output ``(n_samples,)``.
    noise : object
        With attributes ``sigma``, ``rho`` and ``white`` (a
        :class:`pmabayes.fit.NoiseEstimate`).

    Returns
    -------
    numpy.ndarray
        Standardised innovations, independent N(0, 1) for an adequate model.
    """
    return likelihood.innovations(model_position_m, noise.sigma, noise.rho, noise.white)


def _corr(a: np.ndarray, b: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    a = (a - a.mean()) / a.std()
    b = (b - b.mean()) / b.std()
    n = a.size
    lags = np.arange(-max_lag, max_lag + 1)
    # lag k pairs a[t] with b[t - k]
    values = np.array([np.dot(a[max(0, k): n - max(0, -k)], b[max(0, -k): n - max(0, k)]) / n
                       for k in lags])
    return lags, values


def autocorrelation(e: np.ndarray, *, max_lag: int = 50, level: float = 0.99):
    """Autocorrelation of a series with its confidence bound for a white series.

    Parameters
    ----------
    e : numpy.ndarray
        The series (e.g. :func:`innovations`).
    max_lag : int
        Largest lag.
    level : float
        Confidence level of the bound.

    Returns
    -------
    lags : numpy.ndarray
        ``1 .. max_lag``.
    acf : numpy.ndarray
        Autocorrelation at those lags.
    bound : float
        ``z_{(1 + level) / 2} / sqrt(n)``: a white series stays within it at a
        fraction ``level`` of the lags.
    """
    lags, values = _corr(np.asarray(e, float), np.asarray(e, float), max_lag)
    keep = lags > 0
    bound = stats.norm.ppf(0.5 + level / 2) / math.sqrt(len(e))
    return lags[keep], values[keep], float(bound)


def cross_correlation(e: np.ndarray, u: np.ndarray, *, max_lag: int = 50,
                      level: float = 0.99):
    """Cross-correlation of a residual with an input, with a confidence bound.

    ``ccf[k]`` correlates ``e[t]`` with ``u[t - k]``: peaks at positive lags mean
    the residual still depends on past input, the signature of missing dynamics
    (a lag or delay). The input is best passed prewhitened or differenced (for
    example its rate of change), since a smooth input correlates with everything.

    Parameters
    ----------
    e, u : numpy.ndarray
        Residual and input, same length.
    max_lag : int
        Largest lag, both signs.
    level : float
        Confidence level of the bound (for independent series).

    Returns
    -------
    lags, ccf : numpy.ndarray
    bound : float
    """
    lags, values = _corr(np.asarray(e, float), np.asarray(u, float), max_lag)
    bound = stats.norm.ppf(0.5 + level / 2) / math.sqrt(len(e))
    return lags, values, float(bound)


def ljung_box(e: np.ndarray, *, max_lag: int = 25) -> tuple[float, float]:
    """Ljung-Box test that a series is white.

    Parameters
    ----------
    e : numpy.ndarray
        The series.
    max_lag : int
        Number of lags in the statistic.

    Returns
    -------
    statistic : float
        ``n (n + 2) sum_k acf_k^2 / (n - k)``, chi-squared with ``max_lag`` degrees
        of freedom for a white series.
    p_value : float
    """
    e = np.asarray(e, float)
    n = e.size
    lags, acf, _ = autocorrelation(e, max_lag=max_lag)
    q = float(n * (n + 2) * np.sum(acf**2 / (n - lags)))
    return q, float(stats.chi2.sf(q, max_lag))
