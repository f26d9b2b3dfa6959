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
    "EffectEvidence",
    "rank_effects",
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


@dataclass(frozen=True)
class EffectEvidence:
    """The evidence in the data that one effect is missing from a model.

    Parameters
    ----------
    effect : str
        Registry name.
    statistic : float
        Efficient score (Lagrange multiplier) statistic at the model's MAP,
        chi-squared with ``dof`` degrees of freedom when the effect is absent
        (one-sided for parameters whose null value is a bound).
    dof : int
        Number of tested parameters.
    p_value : float
        Its p-value.
    significant : bool
        ``p_value`` below the level divided by the number of candidates
        (Bonferroni), so that a model that lacks nothing is flagged at most at the
        level.
    estimate : dict
        One-step estimate of each tested parameter.
    interval : dict
        90% interval ``(low, high)`` of each, from the score's information.
    explained : float
        Fraction of the whitened residual's excess energy (above pure noise) that
        the effect removes to first order: near 1 when it explains the misfit,
        near 0 when something else is missing.
    """

    effect: str
    statistic: float
    dof: int
    p_value: float
    significant: bool
    estimate: dict
    interval: dict
    explained: float


def rank_effects(
    likelihood: Likelihood,
    noise,
    values: dict,
    *,
    candidates=None,
    level: float = 0.05,
) -> list[EffectEvidence]:
    """Rank effects by the score-test evidence that they are missing.

    For each candidate the model is extended with the effect at its null value
    (where it vanishes), the whitened sensitivities of the trial mean to every
    free parameter come from one batched simulation (finite differences through
    the Kalman innovations, which are linear), and the efficient score of the
    effect's parameters, adjusted for the model's own, is tested. No refit is
    needed, and nothing in it is specific to an effect: user-registered effects
    are ranked like built-in ones.

    Limits of a first-order test: effects whose first-order signatures coincide
    are not told apart. A regulator lag and a transport delay both act as
    ``p - tau dp/dt`` for small ``tau``, so both rank at the top with nearly equal
    statistics; refitting each and comparing them (ELPD) is needed to choose. The
    one-step ``estimate`` is first order too, and is biased when the current fit
    has absorbed part of the effect; refit for a trustworthy interval.

    Parameters
    ----------
    likelihood : Likelihood
        Data and the current model.
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``), e.g. from
        :func:`pmabayes.fit.estimate_noise`.
    values : dict
        The current model's parameter values at its MAP.
    candidates : iterable of str, optional
        Effects to test; every registered effect not already in the model by
        default.
    level : float
        Family-wise false-alarm level.

    Returns
    -------
    list of EffectEvidence
        Most evidence first.
    """
    from pmabayes.effects import registered_effects

    model = likelihood.model
    present = set(model.effect_names)
    names = [n for n in (candidates or registered_effects()) if n not in present]

    def whiten(v: np.ndarray) -> np.ndarray:
        return likelihood.whiten(v, noise.sigma, noise.rho, noise.white)

    out = []
    for name in names:
        ext = model.with_effects(name)
        lik = Likelihood(ext, likelihood.dataset, substeps=likelihood.substeps)
        eff = ext.effects[-1]
        tested = [p.name for p in eff.parameters if p.vary]
        point = dict(ext.defaults)
        point.update({k: v for k, v in values.items() if k in point})  # not the noise
        point.update({p.name: p.null for p in eff.parameters if p.vary})
        free = list(ext.free_names)
        base = ext.theta(point)[0]
        steps, rows = [], [base]
        for n in free:
            j = ext.index(n)
            p = ext.parameter(n)
            h = 1e-6 * max(abs(base[j]), abs(p.default), 1e-12)
            up = base.copy()
            up[j] += h
            rows.append(up)
            steps.append(h)
        x = lik.simulate(np.array(rows))
        r_w = whiten(likelihood.y_mean - x[0])
        w = np.stack([whiten((x[k + 1] - x[0]) / steps[k]) for k in range(len(free))], axis=1)
        info = w.T @ w
        score = w.T @ r_w
        t_idx = [free.index(n) for n in tested]
        o_idx = [k for k in range(len(free)) if k not in t_idx]
        i_oo = info[np.ix_(o_idx, o_idx)]
        i_to = info[np.ix_(t_idx, o_idx)]
        eff_score = score[t_idx] - i_to @ np.linalg.solve(i_oo, score[o_idx])
        var = info[np.ix_(t_idx, t_idx)] - i_to @ np.linalg.solve(i_oo, i_to.T)
        step = np.linalg.solve(var, eff_score)
        sd = np.sqrt(np.diag(np.linalg.inv(var)))
        stat = float(eff_score @ step)
        one_sided = [ext.parameter(n).bounds[0] == ext.parameter(n).null for n in tested]
        if len(tested) == 1 and one_sided[0]:
            z = float(eff_score[0] / math.sqrt(var[0, 0]))
            stat = max(z, 0.0) ** 2
            p_value = float(stats.norm.sf(z))
        else:
            p_value = float(stats.chi2.sf(stat, len(tested)))
        estimate = {n: float(point[n] + step[i]) for i, n in enumerate(tested)}
        interval = {n: (estimate[n] - 1.645 * sd[i], estimate[n] + 1.645 * sd[i])
                    for i, n in enumerate(tested)}
        excess = max(float(r_w @ r_w) - r_w.size, 1e-12)
        out.append(EffectEvidence(name, stat, len(tested), p_value, False, estimate, interval,
                                  float(min(stat / excess, 1.0))))
    threshold = level / max(len(out), 1)
    out = [EffectEvidence(**{**e.__dict__, "significant": e.p_value < threshold}) for e in out]
    return sorted(out, key=lambda e: -e.statistic)
