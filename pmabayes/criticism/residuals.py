"""Residual statistics: how far a model's output is from repeated trials, and how.

Stage 7 (diagnostics), below :mod:`pmabayes.criticism.diagnosis`. Everything here takes a
data set and a model output (and, for the whiteness tests, the identified noise)
and measures the misfit against what repeatability allows; nothing fits or
samples:

* :func:`band_errors`: RMS, normalised RMS and maximum error of the trial mean per
  frequency band, for any input, from the spectra of the residual and of the
  deviations between trials (:func:`power_spectrum`), each beside the noise floor
  in that band (the error a perfect model would have); the bands are octaves over
  the frequencies the command excites (:func:`input_bands`), and their mean
  squares add up to the total;
* :func:`innovations`, :func:`autocorrelation`, :func:`cross_correlation`,
  :func:`ljung_box` and :func:`whiteness`: the classic whiteness and independence
  tests of system identification, applied to the residual whitened by the
  identified noise model. That residual is independent N(0, 1) when the model
  describes the data;
* :func:`check_noise_model` and :func:`judged_whiteness`: whether the AR(1) +
  white noise model whitens the deviations between trials (model-free), and
  when it does not, an AR model of the repeats to whiten the trial mean's
  residual with, so that the adequacy verdict judges the physics and not the
  noise model;
* :func:`residual_signature`: all of these for one model, with the correlations
  that say where it fails;
* :func:`is_adequate` and :func:`check_adequacy`: the one adequacy rule (the
  whitened residual's energy within a tolerance of pure noise, and white), and a
  verdict with the numbers and the next command, for reports and the command line;
* :func:`whiteness_curves`: the correlation curves that the whiteness figure draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy import signal, stats

from pmabayes.data import Dataset
from pmabayes.inference.likelihood import (
    LEVEL_ADEQUATE,
    LJUNG_BOX_LAGS,
    MAX_AR_ORDER,
    ArNoise,
    Likelihood,
    _noise_repeats,
    ar1_whiteness_of_repeats,
    ar_noise_from_repeats,
    ljung_box_statistic,
)

__all__ = [
    "DEFAULT_BANDS_HZ",
    "ENERGY_TOLERANCE",
    "LEVEL_ADEQUATE",
    "BandErrors",
    "BandError",
    "EXCITED_POWER_FRACTION",
    "MIN_BINS",
    "band_label",
    "instantaneous_frequency",
    "power_spectrum",
    "excited_band",
    "input_bands",
    "band_rms",
    "band_errors",
    "innovations",
    "autocorrelation",
    "cross_correlation",
    "ljung_box",
    "whiteness",
    "MAX_AR_ORDER",
    "NoiseModelCheck",
    "check_noise_model",
    "judged_whiteness",
    "is_adequate",
    "Signature",
    "residual_signature",
    "WhitenessCurves",
    "whiteness_curves",
    "Adequacy",
    "check_adequacy",
]

#: Fixed frequency bands (Hz) of earlier versions, for callers that pass them as
#: ``bands_hz``; :func:`band_errors` now takes its bands from the input
#: (:func:`input_bands`).
DEFAULT_BANDS_HZ: tuple[tuple[float, float], ...] = (
    (0.1, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 3.0),
)

#: Largest excess of the whitened residual's mean square over pure noise (1) for an
#: adequate model. A tolerance, not a chi-squared test: with the noise parameters
#: estimated from a few trials the energy of pure noise scatters by about 0.03
#: around 1 (measured), twice the chi-squared spread. 0.1 means a model error below
#: about a third of the noise level.
ENERGY_TOLERANCE = 0.1

# LEVEL_ADEQUATE (the level of the Ljung-Box test of an adequate model's whitened
# residual) and MAX_AR_ORDER live with the noise model, in pmabayes.inference.likelihood, whose
# choice of noise model for the sampler uses them too.


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
        if math.isnan(self.floor_m):
            return math.nan
        return self.rms_m / self.floor_m if self.floor_m > 0 else math.inf

    @property
    def label(self) -> str:
        """The band in words: ``"0.5-1 Hz"``, ``"> 4 Hz"``, or ``"all"`` for the overall row."""
        return band_label(self.band_hz)

    def to_dict(self) -> dict:
        """JSON-ready values (an open upper edge, a missing floor and its ratio as None)."""
        lo, hi = self.band_hz
        return {"band_hz": [lo, hi if math.isfinite(hi) else None], "n_bins": self.n_samples,
                "rms_m": self.rms_m, "nrms": self.nrms, "max_m": self.max_m,
                "floor_m": _finite_or_none(self.floor_m), "ratio": _finite_or_none(self.ratio)}


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


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
        The data.

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

    Parameters
    ----------
    dataset : Dataset
        The trials.
    model_position_m : numpy.ndarray
        Model output on the data's time grid, ``(n_samples,)``.
    bands_hz : tuple of (low, high), optional
        Frequency bands in Hz; by default :func:`input_bands` (octaves over the
        band the command excites, then everything above). A last row covers all
        frequencies.

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
    mean = dataset.mean_position_m
    resid = mean - x
    spec = np.fft.rfft(resid)
    f, p_resid = power_spectrum(resid, dt)
    _, p_motion = power_spectrum(mean - mean.mean(), dt)
    f_floor, p_floor = _floor_spectrum(dataset, x)
    rows = []
    for lo, hi in (*bands, (0.0, math.inf)):
        sel = (f >= lo) & (f < hi)
        if not sel.any():
            continue
        rms = math.sqrt(float(p_resid[sel].sum()))
        motion = math.sqrt(float(p_motion[sel].sum()))
        part = resid if sel.all() else np.fft.irfft(np.where(sel, spec, 0.0), n=resid.size)
        rows.append(BandErrors(
            band_hz=(float(lo), float(hi)), n_samples=int(sel.sum()), rms_m=rms,
            nrms=rms / max(motion, 1e-300), max_m=float(np.max(np.abs(part))),
            floor_m=math.sqrt(float(p_floor[(f_floor >= lo) & (f_floor < hi)].sum())),
        ))
    return rows


def _floor_spectrum(dataset: Dataset, model_position_m: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The noise floor's spectrum: the power a perfect model's residual would have.

    From the trials' deviations from their mean (summed over ``R - 1``, divided by
    ``R`` for the trial mean); for a single periodic record, from its periods'
    deviations from their mean (the repeats :mod:`pmabayes.inference.likelihood` learns the
    noise from: of the residual at ``model_position_m`` where the record starts from
    rest), on the period's coarser frequency grid, not divided (the record is one
    series); NaN for a single record without repeats.
    """
    dt = dataset.dt_s
    n_trials = dataset.n_trials
    if n_trials >= 2:
        dev = dataset.position_m - dataset.mean_position_m
        f, p = power_spectrum(dev, dt)
        return f, p.sum(axis=0) / ((n_trials - 1) * n_trials)
    source, repeats = _noise_repeats(dataset, model_position_m)
    if source == "periods":
        f, p = power_spectrum(repeats - repeats.mean(axis=0), dt)
        return f, p.sum(axis=0) / (repeats.shape[0] - 1)
    f = np.fft.rfftfreq(dataset.n_samples, dt)
    return f, np.full(f.shape, np.nan)


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
        :class:`pmabayes.inference.noise.NoiseEstimate`).

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
    q = ljung_box_statistic(e, max_lag=max_lag)
    return q, float(stats.chi2.sf(q, max_lag))


@dataclass(frozen=True)
class Signature:
    """Where and how a model's trial-mean residual departs from the noise.

    Parameters
    ----------
    bands : list of BandErrors
        Errors per frequency band, the last one overall.
    ljung_box_p : float
        Ljung-Box p-value (25 lags) of the whitened residual.
    energy : float
        Mean square of the whitened residual: 1 for pure noise.
    energy_p : float
        p-value of ``energy`` against pure noise (chi-squared, one-sided).
    correlations : dict
        Correlation of the residual with the model's position, velocity and
        pressure and with the rate of change of the command.
    ccf_lag_s : float
        Lag at which the whitened residual correlates most with the earlier rate
        of change of the command (positive: the residual follows the command).
    ccf_peak : float
        That correlation.
    ccf_bound : float
        Its 99% bound for independent series.
    noise_model : str
        The noise model the residual was whitened with: ``"AR(1) + white"``, or an
        AR model of the repeats when those reject AR(1) + white
        (:func:`judged_whiteness`).
    """

    bands: list
    ljung_box_p: float
    energy: float
    energy_p: float
    correlations: dict
    ccf_lag_s: float
    ccf_peak: float
    ccf_bound: float
    noise_model: str = "AR(1) + white"

    @property
    def ratio(self) -> float:
        """Overall RMS error over the noise floor."""
        return self.bands[-1].ratio

    def is_adequate(self, energy_tolerance: float = ENERGY_TOLERANCE,
                    level_adequate: float = LEVEL_ADEQUATE) -> bool:
        """Whether the residual is consistent with the noise (see :func:`is_adequate`).

        Parameters
        ----------
        energy_tolerance : float
            Largest excess of the whitened residual's mean square over 1.
        level_adequate : float
            Level of the Ljung-Box test.

        Returns
        -------
        bool
        """
        return is_adequate(self.energy, self.ljung_box_p, energy_tolerance=energy_tolerance,
                           level_adequate=level_adequate)

    def describe(self) -> str:
        """The signature in one or two plain sentences, from the numbers."""
        # the band above the command's carries mostly noise, and the lowest one the
        # offset and the leakage of the ends' mismatch: either would hide a trend
        bands = [b for b in self.bands[:-1] if b.n_samples > 0 and math.isfinite(b.band_hz[1])]
        if sum(b.band_hz[0] > 0 for b in bands) >= 2:
            bands = [b for b in bands if b.band_hz[0] > 0]
        overall = self.bands[-1]
        if math.isnan(overall.floor_m):
            text = (f"The error is {overall.rms_m * 1e6:.4g} µm RMS ({overall.nrms:.3g} of the "
                    "motion; a single record without repeats, so no noise floor)")
            return text + "." + self._describe_correlations()
        ratios = [b.ratio for b in bands]
        text = (f"The error is {overall.rms_m * 1e6:.4g} µm RMS against a noise floor of "
                f"{overall.floor_m * 1e6:.4g} µm ({overall.ratio:.3g}x)")
        if len(bands) >= 2:
            lo, hi = bands[0], bands[-1]
            span = (f"from {lo.ratio:.3g}x the floor at {band_label(lo.band_hz)} to "
                    f"{hi.ratio:.3g}x at {band_label(hi.band_hz)}")
            if hi.ratio > 2.0 * lo.ratio:
                text += f"; it grows with frequency, {span}"
            elif lo.ratio > 2.0 * hi.ratio:
                text += f"; it is largest at low frequency, {span}"
            else:
                text += (f"; it is spread over the band the input excites ({min(ratios):.3g}x "
                         f"to {max(ratios):.3g}x the floor per band)")
        return text + "." + self._describe_correlations()

    def _describe_correlations(self) -> str:
        text = ""
        if self.correlations:
            name, value = max(self.correlations.items(), key=lambda kv: abs(kv[1]))
            text += f" The residual correlates most with the {name} (r = {value:+.2f})."
        if abs(self.ccf_peak) > self.ccf_bound and self.ccf_lag_s > 0:
            # residual = data - model; a response that trails the model's is
            # x(t - tau) - x(t) ~ -tau dx/dt: negative against the command's rate
            how = ("the measured response trails the model's, as if the pressure acted later "
                   "than the model assumes" if self.ccf_peak < 0 else
                   "the measured response runs ahead of the model's")
            text += (f" The whitened residual still correlates with the rate of change of the "
                     f"command {self.ccf_lag_s * 1e3:.0f} ms earlier (correlation "
                     f"{self.ccf_peak:+.2f}, {abs(self.ccf_peak) / self.ccf_bound:.0f}x its 99% "
                     f"bound): {how}.")
        if self.ljung_box_p < 0.01:
            text += f" The whitened residual is not white (Ljung-Box p = {self.ljung_box_p:.2g})."
        if self.noise_model != "AR(1) + white":
            text += (f" (Whitened with an {self.noise_model}: the deviations between trials "
                     "reject the AR(1) + white noise model.)")
        return text


def judged_whiteness(likelihood: Likelihood, model_position_m: np.ndarray, noise
                     ) -> tuple[np.ndarray, dict, NoiseModelCheck]:
    """The whitened residual and its whiteness, under the noise model the repeats support.

    With AR(1) + white when :func:`check_noise_model` finds that it whitens the
    deviations between trials (:func:`innovations`, :func:`whiteness`: as
    before); otherwise with the AR model of the repeats
    (:meth:`NoiseModelCheck.residual_whiteness`), so that the adequacy verdict
    judges the physics and not the noise model.

    Parameters
    ----------
    likelihood : Likelihood
        Data and noise model.
    model_position_m : numpy.ndarray
        Model output ``(n_samples,)``.
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``).

    Returns
    -------
    e : numpy.ndarray
        The whitened residual.
    white : dict
        ``ljung_box_p``, ``energy``, ``energy_p``.
    check : NoiseModelCheck
    """
    x = np.asarray(model_position_m, dtype=float).reshape(-1)
    check = check_noise_model(likelihood, noise)
    if check.adequate:
        e = innovations(likelihood, x, noise)
        return e, whiteness(e), check
    r = likelihood.y_mean - x
    return check.whiten_residual(r), check.residual_whiteness(r), check


def residual_signature(likelihood: Likelihood, noise, sim, *, max_lag_s: float = 0.2
                       ) -> Signature:
    """Measure the signature of a model's residual on the data.

    Parameters
    ----------
    likelihood : Likelihood
        Data and noise model.
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``).
    sim : pmabayes.model.simulator.Simulation
        The model's simulation (batch of one) with its states.
    max_lag_s : float
        Largest lag of the cross-correlation with the command's rate.

    Returns
    -------
    Signature
    """
    ds = likelihood.dataset
    x = sim.position_m[0]
    r = likelihood.y_mean - x
    e, white, noise_check = judged_whiteness(likelihood, x, noise)
    rate = np.gradient(ds.input[0], ds.time_s)
    signals = {"position": x, "velocity": sim.velocity_m_s[0], "pressure": sim.pressure_pa[0],
               "pressure rate": rate}
    corr = {}
    for name, s in signals.items():
        if np.std(s) > 0 and np.std(r) > 0:
            corr[name] = float(np.corrcoef(r, s)[0, 1])
    max_lag = max(1, int(round(max_lag_s / ds.dt_s)))
    lags_r, ccf_r, bound = cross_correlation(e, rate, max_lag=max_lag)
    pos = lags_r >= 0
    k = int(np.argmax(np.abs(ccf_r[pos])))
    return Signature(
        bands=band_errors(ds, x), ljung_box_p=white["ljung_box_p"], energy=white["energy"],
        energy_p=white["energy_p"], correlations=corr,
        ccf_lag_s=float(lags_r[pos][k] * ds.dt_s), ccf_peak=float(ccf_r[pos][k]),
        ccf_bound=bound, noise_model=noise_check.noise_model,
    )


@dataclass(frozen=True)
class NoiseModelCheck:
    """Does AR(1) + white describe the trial-to-trial noise? Result of :func:`check_noise_model`.

    Model-free: it looks at the deviations between the trials only (their Helmert
    contrasts, series of the noise process alone).

    Parameters
    ----------
    ljung_box_p : float
        Ljung-Box p-value (25 lags, pooled over the contrasts) of the contrasts'
        Kalman innovations under the identified AR(1) + white noise.
    energy : float
        Mean square of those innovations (about 1 whatever the model, since the
        noise was fitted to the same deviations).
    adequate : bool
        ``ljung_box_p >= level``: the AR(1) + white noise model whitens the
        deviations.
    ar_order : int
        Order of the autoregressive noise model fitted to the deviations
        (Yule-Walker, pooled over the contrasts, order by AIC up to
        :data:`MAX_AR_ORDER`): the spectrum of the repeats, used to whiten the
        trial mean's residual when AR(1) + white is rejected.
    ar_ljung_box_p : float
        Ljung-Box p-value of the contrasts whitened by that model.
    coefficients : numpy.ndarray
        Durbin-Levinson predictor coefficients of orders ``0 .. ar_order``
        (row ``m``, first ``m`` entries).
    variances : numpy.ndarray
        One-step prediction variances of those orders, in m^2 (of one trial's
        noise).
    n_trials : int
        Trials (the trial mean's residual is scaled by ``sqrt(n_trials)``).
    reference_acf : numpy.ndarray
        Autocorrelation at lags 1..25 of the contrasts whitened by the AR model,
        pooled: what the trial mean's whitened residual is compared with, so that
        the AR model's own small misfit cancels.
    reference_energy : float
        Mean square of the contrasts whitened by the AR model.
    reference_samples : int
        Samples in all the contrasts (0 without repeats: nothing tested).
    level : float
        Level of the test.
    ar : pmabayes.inference.likelihood.ArNoise or None
        The AR model of the repeats itself (None without repeats): what
        :meth:`whiten_series` whitens with, and what a fit's likelihood uses when
        the repeats reject AR(1) + white (:func:`pmabayes.inference.likelihood.choose_noise_model`).
    """

    ljung_box_p: float
    energy: float
    adequate: bool
    ar_order: int
    ar_ljung_box_p: float
    coefficients: np.ndarray
    variances: np.ndarray
    n_trials: int
    reference_acf: np.ndarray
    reference_energy: float
    reference_samples: int
    level: float = LEVEL_ADEQUATE
    ar: ArNoise | None = None

    @property
    def noise_model(self) -> str:
        """The noise model the adequacy verdict whitens with."""
        return "AR(1) + white" if self.adequate else f"AR({self.ar_order}) from the repeats"

    def whiten_series(self, v: np.ndarray) -> np.ndarray:
        """Exact standardised innovations of a series of one trial's noise (AR model).

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
        return self.ar.whiten(v)

    def whiten_residual(self, residual_m: np.ndarray) -> np.ndarray:
        """The trial mean's residual whitened by the AR model of the repeats.

        Parameters
        ----------
        residual_m : numpy.ndarray
            Trial mean minus model, ``(n_samples,)``.

        Returns
        -------
        numpy.ndarray
            Independent N(0, 1) when the model describes the data.
        """
        return self.whiten_series(math.sqrt(self.n_trials) * np.asarray(residual_m, float))

    def residual_whiteness(self, residual_m: np.ndarray) -> dict:
        """Whiteness of the trial mean's residual against the repeats, under the AR model.

        The residual and the contrasts are whitened by the same AR model; the
        residual's autocorrelation (lags 1..25) is compared with the contrasts'
        (a Ljung-Box-like statistic on the difference, chi-squared with 25
        degrees of freedom), and its energy is relative to theirs. Both are about
        those of pure noise for a model that describes the data.

        Parameters
        ----------
        residual_m : numpy.ndarray
            Trial mean minus model, ``(n_samples,)``.

        Returns
        -------
        dict
            As :func:`whiteness`: ``ljung_box_p``, ``energy`` and ``energy_p``.
        """
        e = self.whiten_residual(residual_m)
        n = e.size
        max_lag = self.reference_acf.size
        _, acf, _ = autocorrelation(e, max_lag=max_lag)
        var = 1.0 / n + 1.0 / self.reference_samples
        q = float(np.sum((acf - self.reference_acf) ** 2) / var)
        energy = float(np.mean(e * e)) / self.reference_energy
        return {"ljung_box_p": float(stats.chi2.sf(q, max_lag)), "energy": energy,
                "energy_p": float(stats.chi2.sf(energy * n, n))}

    def summary(self) -> str:
        """The verdict in one line."""
        if self.reference_samples == 0:
            return "Noise model AR(1) + white: not tested (no repeats to test it on)."
        if self.adequate:
            return (f"Noise model AR(1) + white: it whitens the deviations between trials "
                    f"(Ljung-Box {_p_text(self.ljung_box_p)}).")
        return (f"Noise model AR(1) + white is REJECTED by the deviations between trials "
                f"(Ljung-Box {_p_text(self.ljung_box_p)}): the disturbance has more "
                f"structure (several time scales, vibration, drift). The adequacy verdict "
                f"whitens with an AR({self.ar_order}) model of the repeats instead (its "
                f"Ljung-Box {_p_text(self.ar_ljung_box_p)}), and so does the sampler's "
                "likelihood (pmabayes fit --noise-model auto, the default).")

    def to_dict(self) -> dict:
        """JSON-ready values."""
        return {"noise_model": self.noise_model, "ljung_box_p": self.ljung_box_p,
                "energy": self.energy, "adequate": self.adequate, "ar_order": self.ar_order,
                "ar_ljung_box_p": self.ar_ljung_box_p, "level": self.level}


def _pooled_ljung_box(series: list, max_lag: int = LJUNG_BOX_LAGS) -> float:
    q = sum(ljung_box(e, max_lag=max_lag)[0] for e in series)
    return float(stats.chi2.sf(q, max_lag * len(series)))


def check_noise_model(likelihood: Likelihood, noise, *, max_order: int = MAX_AR_ORDER,
                      level: float = LEVEL_ADEQUATE) -> NoiseModelCheck:
    """Test the AR(1) + white noise model on the deviations between trials (model-free).

    The Helmert contrasts of the trials are series of the noise alone. Whitened
    by the identified noise (Kalman innovations, :meth:`Likelihood.whiten`) they
    are white when the noise model holds: a pooled Ljung-Box test says whether it
    does. Real disturbances often have more structure (two time scales,
    vibration, slow drift), and then the whiteness test of the trial mean's
    residual would reject the noise model, not the physics. So an autoregressive
    model of the repeats is also fitted (Yule-Walker on the contrasts, order by
    AIC), which :func:`check_adequacy` and :func:`residual_signature` whiten with
    when AR(1) + white is rejected.

    Parameters
    ----------
    likelihood : Likelihood
        The data (at least 2 trials).
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``).
    max_order : int
        Largest AR order tried.
    level : float
        Level of the Ljung-Box test.

    Returns
    -------
    NoiseModelCheck
    """
    contrasts = np.asarray(likelihood.contrasts, dtype=float)
    r = likelihood.n_trials
    if contrasts.shape[0] == 0:  # a single record without periods: nothing to test on
        return NoiseModelCheck(ljung_box_p=math.nan, energy=math.nan, adequate=True, ar_order=0,
                               ar_ljung_box_p=math.nan, coefficients=np.zeros((1, 1)),
                               variances=np.ones(1), n_trials=r,
                               reference_acf=np.zeros(LJUNG_BOX_LAGS), reference_energy=1.0,
                               reference_samples=0, level=level)
    # the test and the AR model are the sampler's own (pmabayes.inference.likelihood), so that the
    # verdict and the intervals judge with the same noise model
    lb_p, energy, _ = ar1_whiteness_of_repeats(likelihood, noise.sigma, noise.rho, noise.white)
    ar = ar_noise_from_repeats(contrasts, max_order=max_order)
    check = NoiseModelCheck(ljung_box_p=lb_p, energy=energy, adequate=bool(lb_p >= level),
                            ar_order=ar.order, ar_ljung_box_p=math.nan,
                            coefficients=ar.coefficients, variances=ar.variances,
                            n_trials=r, reference_acf=np.zeros(LJUNG_BOX_LAGS),
                            reference_energy=1.0, reference_samples=int(contrasts.size),
                            level=level, ar=ar)
    white = [check.whiten_series(c) for c in contrasts]
    pooled = np.mean([autocorrelation(w, max_lag=25)[1] for w in white], axis=0)
    return NoiseModelCheck(**{**check.__dict__, "ar_ljung_box_p": _pooled_ljung_box(white),
                              "reference_acf": pooled,
                              "reference_energy": float(np.mean(np.square(white)))})


def whiteness(e: np.ndarray) -> dict:
    """Whiteness statistics of a whitened residual.

    Parameters
    ----------
    e : numpy.ndarray
        The whitened residual (:func:`innovations`).

    Returns
    -------
    dict
        ``ljung_box_p`` (Ljung-Box p-value, 25 lags), ``energy`` (mean square: 1
        for pure noise) and ``energy_p`` (p-value of the energy against pure noise,
        chi-squared, one-sided).
    """
    e = np.asarray(e, dtype=float)
    energy = float(np.mean(e * e))
    return {"ljung_box_p": ljung_box(e)[1], "energy": energy,
            "energy_p": float(stats.chi2.sf(energy * e.size, e.size))}


def is_adequate(energy: float, ljung_box_p: float, *,
                energy_tolerance: float = ENERGY_TOLERANCE,
                level_adequate: float = LEVEL_ADEQUATE) -> bool:
    """The adequacy rule: the whitened residual is consistent with the noise.

    Its mean square is within ``1 + energy_tolerance`` of pure noise and its
    autocorrelation is not significant (Ljung-Box p at least ``level_adequate``).

    Parameters
    ----------
    energy : float
        Mean square of the whitened residual.
    ljung_box_p : float
        Its Ljung-Box p-value.
    energy_tolerance : float
        See :data:`ENERGY_TOLERANCE`.
    level_adequate : float
        See :data:`LEVEL_ADEQUATE`.

    Returns
    -------
    bool
    """
    return bool(energy <= 1.0 + energy_tolerance and ljung_box_p >= level_adequate)


@dataclass(frozen=True)
class WhitenessCurves:
    """Correlation curves of whitened residuals, one per model, for the whiteness figure.

    Parameters
    ----------
    acf_lags_s : numpy.ndarray
        Positive lags of the autocorrelation, in s.
    acf : dict
        Label to the autocorrelation at those lags.
    ccf_lags_s : numpy.ndarray
        Lags of the cross-correlation with the command's rate (both signs), in s.
    ccf : dict
        Label to the cross-correlation at those lags.
    bound : float
        Bound that a white, independent residual stays within at a fraction
        ``level`` of the lags.
    level : float
        Confidence level of ``bound``.
    """

    acf_lags_s: np.ndarray
    acf: dict
    ccf_lags_s: np.ndarray
    ccf: dict
    bound: float
    level: float


def whiteness_curves(innovations: dict, command_rate: np.ndarray, dt_s: float, *,
                     max_lag_s: float = 0.2, level: float = 0.99) -> WhitenessCurves:
    """Autocorrelation and cross-correlation with the command's rate of whitened residuals.

    Parameters
    ----------
    innovations : dict
        Label to whitened residual (:func:`innovations`), one per model; all of one
        length.
    command_rate : numpy.ndarray
        Rate of change of the commanded input.
    dt_s : float
        Sample interval.
    max_lag_s : float
        Largest lag.
    level : float
        Confidence level of the bound.

    Returns
    -------
    WhitenessCurves
    """
    max_lag = max(1, int(round(max_lag_s / dt_s)))
    acf, ccf = {}, {}
    lags = lags_c = np.arange(1, max_lag + 1)
    bound = 0.0
    for label, e in innovations.items():
        lags, acf[label], bound = autocorrelation(e, max_lag=max_lag, level=level)
        lags_c, ccf[label], _ = cross_correlation(e, command_rate, max_lag=max_lag, level=level)
    return WhitenessCurves(acf_lags_s=lags * dt_s, acf=acf, ccf_lags_s=lags_c * dt_s, ccf=ccf,
                           bound=float(bound), level=float(level))


@dataclass(frozen=True)
class Adequacy:
    """Whether a fitted model describes the data, in numbers and words.

    Convergence of a sampler says that the posterior of the model is well
    sampled; this says whether the model itself fits. A report or a command prints
    :meth:`lines` beside the convergence check.

    Parameters
    ----------
    adequate : bool or None
        The rule of :func:`is_adequate`; None when the whitened residual could not
        be computed (no noise estimate).
    rms_m : float
        RMS of the trial mean minus the model.
    floor_m : float
        Noise floor: the RMS a perfect model would have.
    energy : float or None
        Mean square of the whitened residual (1 for pure noise).
    ljung_box_p : float or None
        Ljung-Box p-value of the whitened residual.
    coverage : float or None
        Fraction of the measured samples inside the central posterior predictive
        band of probability ``ci_prob``, when known.
    ci_prob : float
        Probability of that band.
    next_command : str
        The command that diagnoses what is missing (``pmabayes diagnose DATA``).
    energy_tolerance : float
        Tolerance used for ``adequate``.
    level_adequate : float
        Ljung-Box level used for ``adequate``.
    noise_model : str
        The noise model the residual was whitened with (:func:`judged_whiteness`).
    """

    adequate: bool | None
    rms_m: float
    floor_m: float
    energy: float | None
    ljung_box_p: float | None
    coverage: float | None = None
    ci_prob: float = 0.9
    next_command: str = ""
    energy_tolerance: float = ENERGY_TOLERANCE
    level_adequate: float = LEVEL_ADEQUATE
    noise_model: str = "AR(1) + white"

    @property
    def ratio(self) -> float:
        """``rms_m / floor_m``: about 1 for a model that describes the data."""
        if math.isnan(self.floor_m):
            return math.nan
        return self.rms_m / self.floor_m if self.floor_m > 0 else math.inf

    @property
    def headline(self) -> str:
        """``MODEL INADEQUATE``, ``Model adequate`` or ``Model adequacy unknown``."""
        if self.adequate is None:
            return "Model adequacy unknown"
        return "Model adequate" if self.adequate else "MODEL INADEQUATE"

    def evidence(self) -> str:
        """The numbers behind the verdict in one sentence."""
        text = (f"the error of the trial mean is {self.ratio:.3g}x the noise floor (RMS "
                f"{self.rms_m * 1e6:.4g} µm against {self.floor_m * 1e6:.4g} µm)"
                if math.isfinite(self.floor_m) else
                f"the RMS error is {self.rms_m * 1e6:.4g} µm (no repeats: no noise floor)")
        if self.energy is not None:
            text += (f"; the whitened residual's energy is {self.energy:.3g} (1 for pure "
                     f"noise, at most {1 + self.energy_tolerance:g} allowed) and its "
                     f"Ljung-Box {_p_text(self.ljung_box_p)} (at least "
                     f"{self.level_adequate:g} needed)")
            if self.noise_model != "AR(1) + white":
                text += (f", whitened with an {self.noise_model} since the deviations between "
                         "trials reject AR(1) + white")
        if self.coverage is not None:
            text += (f"; {self.coverage:.1%} of the data lie inside the {self.ci_prob:.0%} "
                     "posterior predictive band")
        return text

    def advice(self) -> list[str]:
        """What the verdict means, in sentences (none for an adequate model).

        Returns
        -------
        list of str
        """
        if self.adequate is None:
            return ["The fit holds no noise estimate, so the whitened residual cannot be "
                    "judged."]
        if self.adequate is False:
            return ["The sampler's convergence is not the model's fit: the intervals are "
                    "those of a model that the data reject."]
        return []

    @property
    def next_step(self) -> str | None:
        """The command to run next: ``next_command`` unless the model is adequate."""
        return self.next_command if self.adequate is not True and self.next_command else None

    def lines(self) -> list[str]:
        """The verdict as lines of text, for a terminal.

        Returns
        -------
        list of str
            The headline with the evidence; for an inadequate model, what it
            means and the next command (``Next: pmabayes diagnose DATA``).
        """
        out = [f"{self.headline}: {self.evidence()}.", *self.advice()]
        return out + ([f"Next: {self.next_step}"] if self.next_step else [])

    def to_dict(self) -> dict:
        """JSON-ready values.

        Returns
        -------
        dict
        """
        return {"adequate": self.adequate, "rms_m": self.rms_m,
                "floor_m": _finite_or_none(self.floor_m), "ratio": _finite_or_none(self.ratio),
                "energy": self.energy, "ljung_box_p": self.ljung_box_p,
                "coverage": self.coverage, "ci_prob": self.ci_prob,
                "next_command": self.next_command, "energy_tolerance": self.energy_tolerance,
                "level_adequate": self.level_adequate, "noise_model": self.noise_model}


def _p_text(p: float) -> str:
    return "p < 1e-15" if p < 1e-15 else f"p = {p:.2g}"  # not "p = 0" after underflow


def check_adequacy(
    likelihood: Likelihood,
    model_position_m: np.ndarray,
    noise=None,
    *,
    coverage: float | None = None,
    ci_prob: float = 0.9,
    next_command: str = "",
) -> Adequacy:
    """Judge whether a model output describes the data (the rule of :func:`is_adequate`).

    Parameters
    ----------
    likelihood : Likelihood
        The data and its noise model.
    model_position_m : numpy.ndarray
        Model output on the data's time grid, ``(n_samples,)``.
    noise : object, optional
        Identified noise (``sigma``, ``rho``, ``white``); without it the whitened
        residual is not computed and the verdict is unknown.
    coverage : float, optional
        Fraction of the data inside the posterior predictive band, to quote.
    ci_prob : float
        Probability of that band.
    next_command : str
        The command that diagnoses the model, to quote when it is not adequate.

    Returns
    -------
    Adequacy
        With the default tolerance and level (:data:`ENERGY_TOLERANCE`,
        :data:`LEVEL_ADEQUATE`), as :func:`pmabayes.criticism.diagnosis.diagnose` uses.
    """
    x = np.asarray(model_position_m, dtype=float).reshape(-1)
    if likelihood.dataset.n_trials >= 2:
        overall = band_errors(likelihood.dataset, x, bands_hz=())[-1]
    else:  # a single record: its error, and no floor without repeats
        r = likelihood.y_mean - x
        overall = SimpleNamespace(rms_m=float(np.sqrt(np.mean(r * r))), floor_m=math.nan)
    energy = lb_p = adequate = None
    noise_model = "AR(1) + white"
    if noise is not None:
        _, white, noise_check = judged_whiteness(likelihood, x, noise)
        energy, lb_p = white["energy"], white["ljung_box_p"]
        adequate = is_adequate(energy, lb_p)
        noise_model = noise_check.noise_model
    return Adequacy(adequate=adequate, rms_m=overall.rms_m, floor_m=overall.floor_m,
                    energy=energy, ljung_box_p=lb_p, coverage=coverage, ci_prob=ci_prob,
                    next_command=next_command, noise_model=noise_model)
