"""Which noise model a likelihood uses: the choice between AR(1) + white and the
repeats' AR(p) by a whiteness test of the repeats, or a model asked for by name; the
Ljung-Box statistic the test uses.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pmabayes.inference.noise.ar1 import AR1_WHITE
from pmabayes.inference.noise.ar_repeats import (
    MAX_AR_ORDER,
    ArFromRepeats,
    ArNoise,
    ar_noise_from_repeats,
)
from pmabayes.inference.noise.base import NoiseModel, noise_model_class, registered_noise_models

__all__ = ["NOISE_MODELS", "LEVEL_ADEQUATE", "LJUNG_BOX_LAGS", "ljung_box_statistic",
           "NoiseChoice", "noise_model_from_record", "check_noise_model_name",
           "ar1_whiteness_of_repeats", "choose_noise_model"]


def _as_list(likelihoods) -> list:
    """One likelihood or several, as a list (a likelihood is not iterable; its module
    imports this one, so it is not imported here)."""
    return list(likelihoods) if isinstance(likelihoods, Iterable) else [likelihoods]


#: Noise models a fit may use (:func:`choose_noise_model`): ``"auto"`` keeps AR(1) +
#: white unless the repeats reject it, ``"ar1"`` always keeps it, ``"ar"`` always uses
#: the AR(p) of the repeats, ``"student_t"`` is white noise with heavy tails (outliers),
#: sampled with the model. A plugin's registered model is accepted too
#: (:func:`check_noise_model_name`).
NOISE_MODELS: tuple[str, ...] = ("auto", "ar1", "ar", "student_t")

#: Level of the Ljung-Box tests of whiteness: of an adequate model's whitened residual
#: (:mod:`pmabayes.criticism.whiteness`), and of the repeats whitened by AR(1) + white
#: (:func:`choose_noise_model`).
LEVEL_ADEQUATE = 0.01

#: Lags of the Ljung-Box statistic.
LJUNG_BOX_LAGS = 25


def ljung_box_statistic(e: np.ndarray, *, max_lag: int = LJUNG_BOX_LAGS) -> float:
    """The Ljung-Box statistic ``n (n + 2) sum_k acf_k^2 / (n - k)``, ``k = 1..max_lag``.

    Chi-squared with ``max_lag`` degrees of freedom for a white series
    (:func:`pmabayes.criticism.whiteness.ljung_box` adds its p-value). A series with
    samples not observed (NaN: the innovations of a filter that predicts across gaps)
    takes its ``n`` observed samples and, at each lag, the ``n_k`` pairs both observed:
    ``(n + 2) / n sum_k n_k r_k^2`` with ``r_k`` the mean product over those pairs, the
    same statistic when nothing is missing (``n_k = n - k``).

    Parameters
    ----------
    e : numpy.ndarray
        The series (NaN where not observed).
    max_lag : int
        Number of lags.

    Returns
    -------
    float
    """
    e = np.asarray(e, float)
    seen = np.isfinite(e)
    if not seen.all():
        return _ljung_box_observed(e, seen, max_lag)
    n = e.size
    a = (e - e.mean()) / e.std()
    lags = np.arange(1, max_lag + 1)
    acf = np.array([np.dot(a[k:n], a[0:n - k]) / n for k in lags])
    return float(n * (n + 2) * np.sum(acf**2 / (n - lags)))


def _ljung_box_observed(e: np.ndarray, seen: np.ndarray, max_lag: int) -> float:
    """:func:`ljung_box_statistic` over the samples observed and the pairs both observed."""
    n = int(seen.sum())
    v = e[seen]
    a = np.where(seen, (e - v.mean()) / v.std(), 0.0)
    q = 0.0
    for k in range(1, max_lag + 1):
        pairs = int(np.count_nonzero(seen[k:] & seen[:-k]))
        if pairs:
            r = float(np.dot(a[k:], a[:-k])) / pairs
            q += pairs * r * r
    return float((n + 2.0) / n * q)



@dataclass(frozen=True)
class NoiseChoice:
    """Which noise model an experiment's likelihood uses, and why (:func:`choose_noise_model`).

    Parameters
    ----------
    requested : str
        ``"auto"`` or a registered noise model's name (:data:`NOISE_MODELS`).
    ar : ArNoise or None
        The AR model of the repeats the trial-mean likelihood uses, or None.
    ljung_box_p : float
        Pooled Ljung-Box p-value of the repeats' contrasts whitened by AR(1) + white
        (NaN without repeats, or when not tested).
    level : float
        The test's level.
    note : str
        Why the choice was not the test's (samples not observed), or empty.
    model : NoiseModel, optional
        The noise model object; by default the repeats' AR(p) where ``ar`` is set,
        else AR(1) + white.
    """

    requested: str
    ar: ArNoise | None
    ljung_box_p: float
    level: float = LEVEL_ADEQUATE
    note: str = ""
    model: NoiseModel = None  # type: ignore[assignment]  # set in __post_init__

    def __post_init__(self) -> None:
        if self.model is None:
            object.__setattr__(self, "model", AR1_WHITE if self.ar is None
                               else ArFromRepeats(self.ar))

    @property
    def name(self) -> str:
        """The noise model in words."""
        return self.model.label

    def describe(self) -> str:
        """One sentence for the progress line and reports."""
        if self.note:
            return f"AR(1) + white: {self.note}"
        if not self.model.from_repeats:
            return f"{self.model.label}, as asked (its parameters sampled with the model's)"
        tested = (f"Ljung-Box of the repeats whitened by AR(1) + white p = "
                  f"{self.ljung_box_p:.2g}" if math.isfinite(self.ljung_box_p) else "")
        if self.ar is None:
            if self.requested == "ar1":
                return "AR(1) + white (as asked" + (f"; {tested})" if tested else ")")
            if not tested:
                return "AR(1) + white (no repeats to test it on)"
            return f"AR(1) + white: the repeats accept it ({tested})"
        if self.requested == "ar":
            return f"{self.ar.name}, as asked" + (f" ({tested})" if tested else "")
        return f"{self.ar.name}: the repeats reject AR(1) + white ({tested})"

    def to_dict(self) -> dict:
        """JSON-ready record: ``model``, ``requested``, ``ljung_box_p``, ``level``, and
        the model's own :meth:`~NoiseModel.to_dict` (for an AR model ``order``,
        ``coefficients``, ...; nothing for AR(1) + white); :func:`noise_model_from_record`
        rebuilds the model from it."""
        out = {"model": self.name, "requested": self.requested,
               "ljung_box_p": self.ljung_box_p if math.isfinite(self.ljung_box_p) else None,
               "level": self.level, "order": 1}
        if self.note:
            out["note"] = self.note
        out.update(self.model.to_dict())
        return out


def noise_model_from_record(record: dict | None) -> NoiseModel:
    """The noise model of a fit file's record (:meth:`NoiseChoice.to_dict`).

    Its ``noise_model`` names the registered model; a record without one is the
    repeats' AR(p) where it holds ``autocovariance_m2``, else AR(1) + white (every fit
    file written before noise models had names).

    Parameters
    ----------
    record : dict or None

    Returns
    -------
    NoiseModel

    Raises
    ------
    KeyError
        For a name no registered model has (a plugin's model not loaded).
    """
    record = record or {}
    name = record.get("noise_model") or ("ar" if record.get("autocovariance_m2") else "ar1")
    return noise_model_class(name).from_dict(record)


def check_noise_model_name(noise_model: str) -> str:
    """``noise_model`` if it is ``"auto"`` or a registered noise model's name
    (:data:`NOISE_MODELS`, and any a plugin registered), else a clear error.

    Parameters
    ----------
    noise_model : str

    Returns
    -------
    str

    Raises
    ------
    ValueError
        Naming the allowed values.
    """
    names = ("auto", *registered_noise_models())
    if not isinstance(noise_model, str) or noise_model not in names:
        raise ValueError(f"noise_model must be one of {', '.join(map(repr, names))}, "
                         f"got {noise_model!r}: 'auto' tests AR(1) + white on the repeats and "
                         "uses their AR(p) when it is rejected")
    return noise_model


def ar1_whiteness_of_repeats(likelihoods, sigma: float, rho: float, white: float
                             ) -> tuple[float, float, list[np.ndarray]]:
    """Whiten the repeats' contrasts by AR(1) + white and test them (pooled Ljung-Box).

    Parameters
    ----------
    likelihoods : Likelihood or sequence of Likelihood
        Experiments sharing the noise (only those with repeats count).
    sigma, rho, white : float
        The AR(1) + white noise (from the repeats, :func:`pmabayes.inference.noise.estimate_noise`).

    Returns
    -------
    ljung_box_p : float
        Pooled over the contrasts (:data:`LJUNG_BOX_LAGS` lags each); NaN without
        repeats.
    energy : float
        Mean square of the whitened contrasts (over the samples they observe).
    innovations : list of numpy.ndarray
        The whitened contrasts
        (:meth:`~pmabayes.inference.likelihood.Likelihood.whiten_contrasts`), each on its
        repeats' grid: the trials', or one period of a periodic record.
    """
    from scipy import stats

    liks = _as_list(likelihoods)
    innov = [e for lik in liks for e in lik.whiten_contrasts(sigma, rho, white)]
    if not innov:
        return math.nan, math.nan, innov
    q = sum(ljung_box_statistic(e) for e in innov)
    p = float(stats.chi2.sf(q, LJUNG_BOX_LAGS * len(innov)))
    # experiments of different lengths: the mean over every whitened sample observed
    every = np.concatenate(innov)
    return p, float(np.mean(np.square(every[np.isfinite(every)]))), innov


def choose_noise_model(likelihoods, sigma: float, rho: float, white: float,
                       noise_model: str = "auto", *, level: float = LEVEL_ADEQUATE,
                       max_order: int = MAX_AR_ORDER) -> NoiseChoice:
    """The noise model of experiments whose noise comes from repeats.

    ``"auto"``: AR(1) + white unless the repeats' contrasts whitened by it fail a
    pooled Ljung-Box test at ``level`` (:func:`ar1_whiteness_of_repeats`); then the
    AR(p) of the repeats (:func:`ar_noise_from_repeats`). ``"ar1"`` and ``"ar"`` force
    one or the other. Without repeats the choice is AR(1) + white, and with samples not
    observed (gaps, a warm-up) too, said in the choice's ``note``: the AR(p) density is
    exact for complete series (Durbin-Levinson over the record); with samples missing
    it would need a state of ``p`` lags in a Kalman filter (``p`` up to
    :data:`MAX_AR_ORDER`, ``p^2`` times the work a sample), and its Yule-Walker
    estimate and the whiteness test are made for complete series too.

    Parameters
    ----------
    likelihoods : Likelihood or sequence of Likelihood
        Experiments that share the noise.
    sigma, rho, white : float
        Their AR(1) + white noise from the repeats.
    noise_model : str
        One of :data:`NOISE_MODELS`.
    level : float
        Level of the test.
    max_order : int
        Largest AR order tried.

    Returns
    -------
    NoiseChoice
    """
    check_noise_model_name(noise_model)
    if noise_model != "auto" and not noise_model_class(noise_model).from_repeats:
        return NoiseChoice(noise_model, None, math.nan, level,
                           model=noise_model_class(noise_model)())
    liks = _as_list(likelihoods)
    contrasts = [lik.contrasts for lik in liks if lik.contrasts.shape[0] > 0]
    if not contrasts:
        return NoiseChoice(noise_model, None, math.nan, level)
    gaps = sum(int((~lik.observed).sum()) for lik in liks if lik.observed is not None)
    if gaps:
        return NoiseChoice(noise_model, None, math.nan, level, note=(
            f"{gaps} samples are not observed (gaps or a warm-up), and the repeats' AR(p) "
            "is exact for complete series only; the filter takes missing samples as they "
            "are"))
    p = ar1_whiteness_of_repeats(liks, sigma, rho, white)[0]
    if noise_model == "ar1" or (noise_model == "auto" and p >= level):
        return NoiseChoice(noise_model, None, p, level)
    return NoiseChoice(noise_model, ar_noise_from_repeats(contrasts, max_order=max_order),
                       p, level)
