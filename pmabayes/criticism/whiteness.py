"""Whiteness and independence of the whitened residual, and the check of the noise model.

The classic tests of system identification (:func:`innovations`,
:func:`autocorrelation`, :func:`cross_correlation`, :func:`ljung_box`,
:func:`whiteness`), applied to the residual whitened by the identified noise model,
which is independent N(0, 1) when the model describes the data; and
:func:`check_noise_model` and :func:`judged_whiteness`: whether the AR(1) + white noise
model whitens the deviations between trials (model-free), and when it does not, an AR
model of the repeats to whiten the trial mean's residual with, so that the adequacy
verdict judges the physics and not the noise model. :func:`whiteness_curves` gives the
curves the whiteness figure draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pmabayes.inference.likelihood import (
    LEVEL_ADEQUATE,
    LJUNG_BOX_LAGS,
    MAX_AR_ORDER,
    ArNoise,
    Likelihood,
    ar1_whiteness_of_repeats,
    ar_noise_from_repeats,
    ljung_box_statistic,
)

__all__ = [
    "innovations",
    "autocorrelation",
    "cross_correlation",
    "ljung_box",
    "judged_whiteness",
    "NoiseModelCheck",
    "check_noise_model",
    "whiteness_statistics",
    "WhitenessCurves",
    "whiteness_curves",
]


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
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return _corr_observed(a, b, max_lag)
    a = (a - a.mean()) / a.std()
    b = (b - b.mean()) / b.std()
    n = a.size
    lags = np.arange(-max_lag, max_lag + 1)
    # lag k pairs a[t] with b[t - k]
    values = np.array([np.dot(a[max(0, k): n - max(0, -k)], b[max(0, -k): n - max(0, k)]) / n
                       for k in lags])
    return lags, values


def _corr_observed(a: np.ndarray, b: np.ndarray, max_lag: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_corr` of series with samples not observed (NaN): each standardised over
    its observed samples, each lag the mean product over the pairs both observed."""
    seen_a, seen_b = np.isfinite(a), np.isfinite(b)
    a = np.where(seen_a, (a - a[seen_a].mean()) / a[seen_a].std(), 0.0)
    b = np.where(seen_b, (b - b[seen_b].mean()) / b[seen_b].std(), 0.0)
    n = a.size
    lags = np.arange(-max_lag, max_lag + 1)
    values = []
    for k in lags:
        sa, sb = slice(max(0, k), n - max(0, -k)), slice(max(0, -k), n - max(0, k))
        pairs = np.count_nonzero(seen_a[sa] & seen_b[sb])
        values.append(np.dot(a[sa], b[sb]) / pairs if pairs else 0.0)
    return lags, np.array(values)


def _n_observed(e: np.ndarray) -> int:
    return int(np.count_nonzero(np.isfinite(e)))


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
    bound = stats.norm.ppf(0.5 + level / 2) / math.sqrt(_n_observed(np.asarray(e, float)))
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
    bound = stats.norm.ppf(0.5 + level / 2) / math.sqrt(_n_observed(np.asarray(e, float)))
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
    likelihood, model_position_m, noise : Likelihood, numpy.ndarray, object
        As :func:`innovations`'s.

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
    if check.adequate or check.ar is None:
        e = innovations(likelihood, x, noise)
        return e, whiteness_statistics(e), check
    r = likelihood.y_mean - x
    return check.whiten_residual(r), check.residual_whiteness(r), check


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
        :data:`~pmabayes.inference.likelihood.MAX_AR_ORDER`): the spectrum of the
        repeats, used to whiten the trial mean's residual when AR(1) + white is
        rejected.
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
        if self.adequate:
            return "AR(1) + white"
        if self.ar is None:  # samples not observed: the likelihood's own noise model
            return ("AR(1) + white (rejected by the deviations between trials, but the "
                    "repeats' AR(p) takes complete records only)")
        return f"AR({self.ar_order}) from the repeats"

    def whiten_series(self, v: np.ndarray) -> np.ndarray:
        """A series of one trial's noise whitened by the AR model of the repeats
        (:meth:`pmabayes.inference.likelihood.ArNoise.whiten`)."""
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
            Trial mean minus model, as for :meth:`whiten_residual`.

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
                    f"(Ljung-Box {p_text(self.ljung_box_p)}).")
        if self.ar is None:
            return (f"Noise model AR(1) + white is REJECTED by the deviations between trials "
                    f"(Ljung-Box {p_text(self.ljung_box_p)}), but with samples not observed "
                    "the repeats' AR(p) is not available (it takes complete records): the "
                    "adequacy verdict whitens with AR(1) + white, as the likelihood does, and "
                    "may then find a misfit that is the noise's.")
        return (f"Noise model AR(1) + white is REJECTED by the deviations between trials "
                f"(Ljung-Box {p_text(self.ljung_box_p)}): the disturbance has more "
                f"structure (several time scales, vibration, drift). The adequacy verdict "
                f"whitens with an AR({self.ar_order}) model of the repeats instead (its "
                f"Ljung-Box {p_text(self.ar_ljung_box_p)}), and so does the sampler's "
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
    by the identified noise (Kalman innovations,
    :meth:`~pmabayes.inference.likelihood.Likelihood.whiten`) they are white when the
    noise model holds: a pooled Ljung-Box test says whether it does. Real
    disturbances often have more structure (two time scales, vibration, slow drift),
    and then the whiteness test of the trial mean's residual would reject the noise
    model, not the physics. So an autoregressive model of the repeats is also fitted
    (Yule-Walker on the contrasts, order by AIC), which
    :func:`~pmabayes.criticism.adequacy.check_adequacy` and
    :func:`~pmabayes.criticism.signature.residual_signature` whiten with when AR(1) +
    white is rejected.

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
    if likelihood.observed is not None:
        # samples not observed: the repeats' AR(p) is for complete series, and the
        # likelihood keeps AR(1) + white (choose_noise_model); so does the verdict
        return NoiseModelCheck(ljung_box_p=lb_p, energy=energy, adequate=bool(lb_p >= level),
                               ar_order=1, ar_ljung_box_p=math.nan,
                               coefficients=np.zeros((1, 1)), variances=np.ones(1),
                               n_trials=r, reference_acf=np.zeros(LJUNG_BOX_LAGS),
                               reference_energy=1.0, reference_samples=int(contrasts.size),
                               level=level)
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


def whiteness_statistics(e: np.ndarray) -> dict:
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
    n = _n_observed(e)
    energy = float(np.mean(e * e) if n == e.size else np.mean(e[np.isfinite(e)] ** 2))
    return {"ljung_box_p": ljung_box(e)[1], "energy": energy,
            "energy_p": float(stats.chi2.sf(energy * n, n))}


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


def p_text(p: float) -> str:
    """A p-value in words: ``p = 0.012``, or ``p < 1e-15`` (not ``p = 0`` after underflow)."""
    return "p < 1e-15" if p < 1e-15 else f"p = {p:.2g}"
