"""Errors of the trial mean per frequency band, against the noise floor.

For any input (chirp, steps, sines, multisines): :func:`band_errors` gives the RMS,
normalised RMS and maximum error of the trial mean per frequency band, from the spectra
of the residual and of the deviations between trials (:func:`power_spectrum`), each
beside the noise floor in that band (the error a perfect model would have). The bands
are octaves over the frequencies the command excites (:func:`input_bands`), and their
mean squares add up to the total. Nothing here fits or samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from pmabayes.criticism.observed import bridged
from pmabayes.data import Dataset
from pmabayes.inference.likelihood import (
    _noise_repeats,
    _repeat_mask,
)
from pmabayes.util import finite_or_none

__all__ = [
    "DEFAULT_BANDS_HZ",
    "excess_removed",
    "instantaneous_frequency",
    "BandErrors",
    "BandError",
    "band_label",
    "power_spectrum",
    "EXCITED_POWER_FRACTION",
    "MIN_BINS",
    "excited_band",
    "input_bands",
    "band_rms",
    "band_errors",
    "observed_spectrum",
]


#: Fixed frequency bands (Hz) of earlier versions, for callers that pass them as
#: ``bands_hz``; :func:`band_errors` now takes its bands from the input
#: (:func:`input_bands`).
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


def excess_removed(before_m, after_m, floors_m, sizes) -> float | None:
    """The share of the mean-square error above the noise floor that a change removes.

    With ``b``, ``a`` and ``f`` the RMS errors before and after and the floor, pooled
    over experiments by their sizes: ``((b² - f²) - (a² - f²)) / (b² - f²)``, clipped
    to [0, 1]. It agrees with the RMS errors reported beside it (a model still at 8x
    its floor has not removed all of its excess), where the whitened residual energy
    may not.

    Parameters
    ----------
    before_m, after_m, floors_m : sequence of float
        RMS error before and after, and the noise floor, of each experiment.
    sizes : sequence of int
        Each experiment's number of samples.

    Returns
    -------
    float or None
        None where an experiment has no floor, or there is no excess to remove.
    """
    rows = list(zip(before_m, after_m, floors_m, sizes, strict=True))
    if not rows or any(not math.isfinite(f) for _, _, f, _ in rows):
        return None
    excess = sum(n * (b * b - f * f) for b, _, f, n in rows)
    if not excess > 0:
        return None
    gain = sum(n * (b * b - a * a) for b, a, _, n in rows)
    return float(min(max(gain / excess, 0.0), 1.0))


def floor_ratio(rms_m: float, floor_m: float) -> float:
    """An RMS error over the noise floor: about 1 for a model that describes the data.

    Parameters
    ----------
    rms_m : float
        RMS error.
    floor_m : float
        Noise floor, the RMS a perfect model would have; NaN when there is none.

    Returns
    -------
    float
        ``rms_m / floor_m``; NaN without a floor, infinite for a zero floor.
    """
    if math.isnan(floor_m):
        return math.nan
    return rms_m / floor_m if floor_m > 0 else math.inf


@dataclass(frozen=True)
class BandErrors:
    """Errors of the trial mean in one frequency band: a result row of :func:`band_errors`.

    The band's share of each quantity comes from a spectrum (periodogram), so
    the mean squares of bands that partition the frequency axis add up to the
    overall one (Parseval). ``BandError`` is a deprecated alias of this class (the
    same class under its old name, which read like an exception's).

    Parameters
    ----------
    band_hz : tuple of float
        ``(low, high)`` frequency in Hz, ``low <= f < high``.
    n_samples : int
        Periodogram bins (frequencies ``k / T``) in the band.
    rms_m : float
        RMS of the part of trial mean minus model in the band.
    nrms : float
        ``rms_m`` divided by the RMS of the trial mean's motion (about its mean)
        in the band.
    max_m : float
        Largest absolute value of the residual's part in the band (the residual
        with its other frequencies removed); for the overall row, of the residual.
    floor_m : float
        RMS a perfect model would have in the band: the spectrum of the
        deviations between trials divided by the number of trials; for a single
        periodic record (``period_samples``), that of the deviations between its
        periods in steady state (the repeats its noise is learnt from); NaN for a
        single record without repeats (no floor).
    """

    band_hz: tuple[float, float]
    n_samples: int
    rms_m: float
    nrms: float
    max_m: float
    floor_m: float

    @property
    def ratio(self) -> float:
        """``rms_m / floor_m``: about 1 for a model that describes the data (NaN, no floor)."""
        return floor_ratio(self.rms_m, self.floor_m)

    @property
    def label(self) -> str:
        """The band in words: ``"0.5-1 Hz"``, ``"> 4 Hz"``, or ``"all"`` for the overall row."""
        return band_label(self.band_hz)

    def to_dict(self) -> dict:
        """JSON-ready values (an open upper edge, a missing floor and its ratio as None)."""
        lo, hi = self.band_hz
        return {"band_hz": [lo, hi if math.isfinite(hi) else None], "n_bins": self.n_samples,
                "rms_m": self.rms_m, "nrms": self.nrms, "max_m": self.max_m,
                "floor_m": finite_or_none(self.floor_m), "ratio": finite_or_none(self.ratio)}


#: Deprecated alias of :class:`BandErrors` (a result, not an exception); kept so that
#: ``from pmabayes.criticism.diagnosis import BandError`` goes on working.
BandError = BandErrors


def band_label(band: tuple[float, float]) -> str:
    """A frequency band in words: ``"0.5-1 Hz"``, ``"> 4 Hz"``, or ``"all"`` for ``(0, inf)``.

    Parameters
    ----------
    band : tuple of float
        ``(low, high)`` in Hz.

    Returns
    -------
    str
    """
    lo, hi = band
    if not math.isfinite(hi):
        return "all" if lo == 0.0 else f"> {lo:g} Hz"
    return f"{lo:g}-{hi:g} Hz"


def power_spectrum(x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided periodogram scaled so that its sum is the mean square of ``x``.

    Parameters
    ----------
    x : numpy.ndarray
        Series along the last axis.
    dt_s : float
        Sample interval.

    Returns
    -------
    freq_hz : numpy.ndarray
        ``k / (n dt)`` for ``k = 0 .. n // 2``.
    power_m2 : numpy.ndarray
        Mean square at each frequency (same leading axes as ``x``): summed over
        any set of frequencies it is the mean square of the part of ``x`` at those
        frequencies (Parseval), with no window, so nothing is lost or counted twice.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    p = np.abs(np.fft.rfft(x, axis=-1)) ** 2 / float(n) ** 2
    # the negative frequencies fold onto the positive ones, except DC and Nyquist
    p[..., 1:] *= 2.0
    if n % 2 == 0:
        p[..., -1] /= 2.0
    return np.fft.rfftfreq(n, dt_s), p


#: Power, relative to the command's strongest frequency, above which a frequency
#: counts as excited by :func:`excited_band` (-20 dB).
EXCITED_POWER_FRACTION = 0.01


#: Fewest periodogram bins in a band of :func:`input_bands`: narrower low octaves are
#: merged, since an RMS over one or two bins is mostly chance.
MIN_BINS = 4


def excited_band(dataset: Dataset) -> tuple[float, float]:
    """The frequencies the command excites: where its power is within 20 dB of its peak.

    From the periodogram of the command (about its mean): the band runs from the
    lowest to the highest frequency whose power is at least
    :data:`EXCITED_POWER_FRACTION` of the largest. Any input will do (chirp,
    steps, sines, multisines); no generator settings are needed.

    Parameters
    ----------
    dataset : Dataset
        The data (the command is averaged over the trials).

    Returns
    -------
    tuple of float
        ``(low, high)`` in Hz; the whole axis above 0 Hz for a constant command.

    Raises
    ------
    ValueError
        With fewer than 3 samples (no frequency above 0 Hz).
    """
    u = np.asarray(dataset.input, dtype=float).mean(axis=0)  # the command, over the trials
    f, p = power_spectrum(u - u.mean(), dataset.dt_s)
    f, p = f[1:], p[1:]
    if f.size == 0:
        raise ValueError(f"{dataset.source or 'the data'} has too few samples for a spectrum")
    if not p.max() > 0:
        return float(f[0]), float(f[-1])
    excited = np.flatnonzero(p >= EXCITED_POWER_FRACTION * p.max())
    return float(f[excited[0]]), float(f[excited[-1]])


def input_bands(dataset: Dataset) -> tuple[tuple[float, float], ...]:
    """Frequency bands for error tables: octaves over the band the command excites.

    Octaves ``[2^k, 2^(k+1))`` Hz that span :func:`excited_band`; the lowest reaches
    down to 0 Hz (so that an offset counts), low octaves holding fewer than
    :data:`MIN_BINS` periodogram bins are merged with the next, and a last band
    holds everything above. The bands partition the frequency axis, so their mean
    squares add up to the total.

    Parameters
    ----------
    dataset : Dataset
        The data; :func:`excited_band` reads its input.

    Returns
    -------
    tuple of (low, high)
        In Hz, the last one ``(high edge, inf)``.
    """
    lo, hi = excited_band(dataset)
    k0 = math.floor(math.log2(lo))
    k1 = math.floor(math.log2(hi)) + 1
    edges = [0.0, *(2.0 ** k for k in range(k0 + 1, k1 + 1))]
    df = 1.0 / (dataset.n_samples * dataset.dt_s)
    inner = list(zip(edges[:-1], edges[1:], strict=True))
    merged: list[tuple[float, float]] = []
    for band in inner:
        if merged and _n_bins(merged[-1], df) < MIN_BINS:
            band = (merged.pop()[0], band[1])
        merged.append(band)
    if len(merged) > 1 and _n_bins(merged[-1], df) < MIN_BINS:
        last = merged.pop()
        merged[-1] = (merged[-1][0], last[1])
    return (*merged, (edges[-1], math.inf))


def _n_bins(band: tuple[float, float], df: float) -> int:
    return int(np.ceil(band[1] / df - 1e-9) - np.ceil(band[0] / df - 1e-9))


def band_rms(x: np.ndarray, dt_s: float,
             bands_hz: tuple[tuple[float, float], ...]) -> np.ndarray:
    """RMS of a series' part in each frequency band (from :func:`power_spectrum`).

    Parameters
    ----------
    x : numpy.ndarray
        The series, ``(n_samples,)``.
    dt_s : float
        Sample interval.
    bands_hz : tuple of (low, high)
        Bands in Hz, ``low <= f < high``.

    Returns
    -------
    numpy.ndarray
        ``(len(bands_hz),)``.
    """
    f, p = power_spectrum(x, dt_s)
    return np.array([math.sqrt(float(p[(f >= lo) & (f < hi)].sum())) for lo, hi in bands_hz])


def band_errors(
    dataset: Dataset,
    model_position_m: np.ndarray,
    *,
    bands_hz: tuple[tuple[float, float], ...] | None = None,
    model_trials_m: np.ndarray | None = None,
) -> list[BandErrors]:
    """Errors of the trial mean against the model, per frequency band and overall.

    For any input (chirp, steps, sines, multisines): each band's share comes
    from the periodogram of the residual (trial mean minus model), of the trial
    mean's motion (for the normalised RMS) and of the deviations of the trials
    from their mean (for the noise floor: their summed spectrum over ``R - 1``,
    divided by ``R``, which is the variance of the mean; for a single periodic
    record, the same from its periods, not divided). No window is applied, so
    over bands that partition the frequency axis the mean squares add up exactly
    to the overall one (Parseval); the price is that a residual's component
    between two bins leaks a little into the neighbouring ones.

    A record with samples not counted (:attr:`pmabayes.data.Dataset.counted`: gaps in
    its clock, a warm-up) has its errors from the samples counted alone: the overall
    row is over them, and each band's share comes from the spectrum of the series with
    its gaps bridged by straight lines (:func:`~pmabayes.criticism.observed.bridged`,
    for the spectrum only), scaled to the mean square of the samples counted; the
    largest error is over those samples too.

    Parameters
    ----------
    dataset : Dataset
        The trials.
    model_position_m : numpy.ndarray
        The model's trial mean on the data's time grid, ``(n_samples,)``.
    bands_hz : tuple of (low, high), optional
        Frequency bands in Hz; by default :func:`input_bands` (octaves over the
        band the command excites, then everything above). A last row covers all
        frequencies.
    model_trials_m : numpy.ndarray, optional
        Each trial's model output ``(n_trials, n_samples)`` for trials with their own
        inputs: the noise floor then comes from the deviations of the trials'
        residuals from their mean (the model's response to the inputs' differences is
        not noise).

    Returns
    -------
    list of BandErrors
        One per band that holds a periodogram bin, then the overall one (band
        ``(0, inf)``). For a single record the floors come from its periods when
        it declares them, and are NaN (ratios too) when it has no repeats.

    Raises
    ------
    ValueError
        If the model output does not match the data's length.
    """
    x = np.asarray(model_position_m, dtype=float).reshape(-1)
    if x.shape != (dataset.n_samples,):
        raise ValueError(f"model output has {x.size} samples, the data {dataset.n_samples}")
    bands = input_bands(dataset) if bands_hz is None else tuple(bands_hz)
    dt = dataset.dt_s
    counted = dataset.counted
    seen = counted.any(axis=0)
    mean = dataset.mean_position_m
    if seen.all():
        resid = mean - x
        f, p_resid = power_spectrum(resid, dt)
        _, p_motion = power_spectrum(mean - mean.mean(), dt)
    else:
        mean = np.where(seen, mean, np.nan)
        resid = mean - x
        f, p_resid = observed_spectrum(resid, dt)
        _, p_motion = observed_spectrum(mean - np.nanmean(mean), dt)
    bridged_resid = bridged(resid)
    spec = np.fft.rfft(bridged_resid)
    f_floor, p_floor = _floor_spectrum(dataset, x, model_trials_m)
    rows = []
    for lo, hi in (*bands, (0.0, math.inf)):
        sel = (f >= lo) & (f < hi)
        if not sel.any():
            continue
        rms = math.sqrt(float(p_resid[sel].sum()))
        motion = math.sqrt(float(p_motion[sel].sum()))
        part = (bridged_resid if sel.all()
                else np.fft.irfft(np.where(sel, spec, 0.0), n=resid.size))
        rows.append(BandErrors(
            band_hz=(float(lo), float(hi)), n_samples=int(sel.sum()), rms_m=rms,
            nrms=rms / max(motion, 1e-300),
            max_m=float(np.max(np.abs(part if seen.all() else part[seen]))),
            floor_m=math.sqrt(float(p_floor[(f_floor >= lo) & (f_floor < hi)].sum())),
        ))
    return rows


def observed_spectrum(series: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`power_spectrum` of series with samples not observed (NaN).

    Each row's gaps are bridged by straight lines
    (:func:`~pmabayes.criticism.observed.bridged`) for the spectrum only, and its
    periodogram scaled so that its sum is the mean square of the row's observed
    samples: the bands keep the shares of the bridged series' spectrum and add up to
    the error over the samples observed.

    Parameters
    ----------
    series : numpy.ndarray
        ``(n_samples,)`` or ``(n_series, n_samples)``, NaN where not observed.
    dt_s : float
        Sample interval.

    Returns
    -------
    freq_hz, power_m2 : numpy.ndarray
        As :func:`power_spectrum`; a row with no sample observed has zero power.
    """
    a = np.asarray(series, dtype=float)
    f, p = power_spectrum(np.nan_to_num(bridged(a)), dt_s)
    rows = p.reshape(-1, p.shape[-1])
    for row, values in zip(rows, a.reshape(-1, a.shape[-1]), strict=True):
        seen = np.isfinite(values)
        total = float(row.sum())
        row *= (float(np.mean(values[seen] ** 2)) / total) if seen.any() and total > 0 else 0.0
    return f, p


def _floor_spectrum(dataset: Dataset, model_position_m: np.ndarray,
                    model_trials_m: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The noise floor's spectrum: the power a perfect model's residual would have.

    From the trials' deviations from their mean (summed over ``R - 1``, divided by
    ``R`` for the trial mean); with trials on their own inputs (``model_trials_m``),
    from the deviations of their residuals; for a single periodic record, from its
    periods' deviations from their mean (the repeats :mod:`pmabayes.inference.likelihood`
    learns the noise from: of the residual at ``model_position_m`` where the record
    starts from rest), on the period's coarser frequency grid, not divided (the record
    is one series); NaN for a single record without repeats. Samples not counted are
    missing in the deviations (:func:`observed_spectrum`).
    """
    dt = dataset.dt_s
    n_trials = dataset.n_trials
    counted = dataset.counted
    if n_trials >= 2:
        y = dataset.position_m
        if model_trials_m is not None:
            y = y - np.asarray(model_trials_m, dtype=float).reshape(y.shape)
        if counted.all():
            f, p = power_spectrum(y - y.mean(axis=0), dt)
        else:
            f, p = observed_spectrum(_deviations(y, counted), dt)
        return f, p.sum(axis=0) / ((n_trials - 1) * n_trials)
    source, repeats = _noise_repeats(dataset, model_position_m)
    if source == "periods":
        mask = _repeat_mask(dataset, counted)
        if mask is None or mask.all():
            f, p = power_spectrum(repeats - repeats.mean(axis=0), dt)
        else:
            f, p = observed_spectrum(_deviations(repeats, mask), dt)
        return f, p.sum(axis=0) / (repeats.shape[0] - 1)
    f = np.fft.rfftfreq(dataset.n_samples, dt)
    return f, np.full(f.shape, np.nan)


def _deviations(rows: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Each row's deviation from the mean of the rows seen at each sample (NaN where the
    row is not seen)."""
    n = seen.sum(axis=0)
    mean = np.where(seen, rows, 0.0).sum(axis=0) / np.maximum(n, 1)
    return np.where(seen, rows - mean, np.nan)
