"""Model criticism: which effect is missing, with what evidence, and what adding it does.

Stage 7 (diagnostics), above :mod:`pmabayes.criticism.residuals` (the residual statistics:
band errors against the noise floor, whiteness and independence tests, the
residual signature and the adequacy rule). Here the model is confronted with the
candidate effects:

* :func:`rank_effects`: the score (Lagrange multiplier) test of every candidate
  effect at the model's MAP, with no refit;
* :func:`diagnose`: fit, criticise, rank, refit the significant candidates, judge
  them by the residual they remove and by their leave-one-trial-out ELPD, and say
  in words what is missing;
* :func:`compare_fits`: fits of the same data side by side.

The residual statistics are re-exported here, so ``from pmabayes.criticism.diagnosis import
band_errors`` (and every other name that lived here) keeps working.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pmabayes.criticism.discrepancy import Discrepancy, estimate_discrepancy
from pmabayes.criticism.residuals import (
    DEFAULT_BANDS_HZ,  # noqa: F401
    ENERGY_TOLERANCE,
    LEVEL_ADEQUATE,
    BandError,  # noqa: F401
    BandErrors,  # noqa: F401
    Signature,
    WhitenessCurves,
    autocorrelation,  # noqa: F401
    band_errors,
    band_label,
    band_rms,
    cross_correlation,  # noqa: F401
    innovations,
    input_bands,
    instantaneous_frequency,
    judged_whiteness,
    ljung_box,  # noqa: F401
    residual_signature,
    whiteness_curves,
)
from pmabayes.data import DataError, Dataset
from pmabayes.inference.density import Posterior
from pmabayes.inference.fitfile import (
    check_dataset,
    experiment_datasets,
    experiment_models,
    fit_info,
    model_from_fit,
)
from pmabayes.inference.likelihood import Likelihood, check_noise_model_name
from pmabayes.inference.noise import NoiseEstimate, group_noise
from pmabayes.inference.posterior import experiments
from pmabayes.inference.search import find_map
from pmabayes.model.effects import get_effect, registered_effects
from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation, simulate_dataset
from pmabayes.util import Progress

#: the residual statistics of the old single module, still importable from here
_REEXPORTED = ("DEFAULT_BANDS_HZ", "BandErrors", "BandError", "band_label",
               "instantaneous_frequency", "band_errors", "innovations", "autocorrelation",
               "cross_correlation", "ljung_box", "Signature", "residual_signature")
__all__ = [*_REEXPORTED, "EffectEvidence", "rank_effects", "Refit", "Finding", "Diagnosis",
           "ExperimentDiagnosis", "diagnose", "significance_threshold", "FitComparison",
           "compare_fits"]


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
    likelihood: Likelihood | Sequence[Likelihood],
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

    Over several experiments (independent, with shared physical parameters) the
    scores and the Fisher informations of the experiments add, so one test is
    made with all the data, each experiment simulated on its own rig and whitened
    by its own noise.

    Limits of a first-order test: effects whose first-order signatures coincide
    are not told apart. A regulator lag and a transport delay both act as
    ``p - tau dp/dt`` for small ``tau``, so both rank at the top with nearly equal
    statistics; refitting each and comparing them (ELPD) is needed to choose. The
    one-step ``estimate`` is first order too, and is biased when the current fit
    has absorbed part of the effect; refit for a trustworthy interval.

    Parameters
    ----------
    likelihood : Likelihood or sequence of Likelihood
        Data and the current model; one per experiment, whose models share their
        parameters (their rigs may differ).
    noise : object or sequence of object
        Identified noise (``sigma``, ``rho``, ``white``), e.g. from
        :func:`pmabayes.inference.noise.estimate_noise`; one per experiment with several.
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

    Raises
    ------
    ValueError
        If the numbers of experiments and noises differ.
    """
    liks = [likelihood] if isinstance(likelihood, Likelihood) else list(likelihood)
    noises = list(noise) if isinstance(noise, list | tuple) else [noise]
    if len(noises) != len(liks):
        raise ValueError(f"{len(liks)} experiment(s) need one noise each, got {len(noises)}")
    present = set(liks[0].model.effect_names)
    names = [n for n in (candidates or registered_effects()) if n not in present]
    out = [_score_test(liks, noises, values, name) for name in names]
    threshold = level / max(len(out), 1)
    out = [EffectEvidence(**{**e.__dict__, "significant": e.p_value < threshold}) for e in out]
    return sorted(out, key=lambda e: -e.statistic)


def _score_test(likelihoods: list, noises: list, values: dict, name: str) -> EffectEvidence:
    """The score test of one candidate effect over the experiments (``significant`` is set
    by the caller): their scores and informations add."""
    exts = [lik.model.with_effects(name) for lik in likelihoods]
    ext = exts[0]  # the parameters are shared; only the rigs differ
    eff = ext.effects[-1]
    # a parameter without a null (a shape, such as a damping ratio) is not identified
    # when the effect vanishes: it stays at its default and is not tested
    tested = [p.name for p in eff.parameters if p.vary and p.null is not None]
    point = dict(ext.defaults)
    point.update({k: v for k, v in values.items() if k in point})  # not the noise
    point.update({n: ext.parameter(n).null for n in tested})
    shapes = {p.name for p in eff.parameters if p.null is None}
    free = [n for n in ext.free_names if n not in shapes]
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
    info = np.zeros((len(free), len(free)))
    score = np.zeros(len(free))
    energy, n_samples = 0.0, 0
    for lik, ext_e, noise in zip(likelihoods, exts, noises, strict=True):
        def whiten(v: np.ndarray, lik=lik, noise=noise) -> np.ndarray:
            return lik.whiten(v, noise.sigma, noise.rho, noise.white)

        x = Likelihood(ext_e, lik.dataset, substeps=lik.substeps).simulate(np.array(rows))
        r_w = whiten(lik.y_mean - x[0])
        w = np.stack([whiten((x[k + 1] - x[0]) / steps[k]) for k in range(len(free))], axis=1)
        info += w.T @ w
        score += w.T @ r_w
        energy += float(r_w @ r_w)
        n_samples += r_w.size
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
    estimate, interval = {}, {}
    for i, n in enumerate(tested):
        est = point[n] + step[i]
        lo, hi = est - 1.645 * sd[i], est + 1.645 * sd[i]
        if one_sided[i]:  # the constrained estimate: a bound is the smallest value
            est, lo, hi = max(est, point[n]), max(lo, point[n]), max(hi, point[n])
        estimate[n], interval[n] = float(est), (float(lo), float(hi))
    excess = max(energy - n_samples, 1e-12)
    return EffectEvidence(name, stat, len(tested), p_value, False, estimate, interval,
                          float(min(stat / excess, 1.0)))


def significance_threshold(level: float, n_candidates: int) -> float:
    """The score statistic above which one candidate is significant (1 dof, Bonferroni).

    Parameters
    ----------
    level : float
        Family-wise level.
    n_candidates : int
        Number of candidates tested.

    Returns
    -------
    float
        ``chi2.isf(level / n_candidates, 1)``: the line the ranking figure draws.
    """
    return float(stats.chi2.isf(level / max(n_candidates, 1), 1))


# ---------------------------------------------------------------------------------
# the diagnosis: fit, criticise, rank, refit the candidates, explain


@dataclass(frozen=True)
class Refit:
    """A model refitted with one more effect (MAP with a Laplace posterior).

    Parameters
    ----------
    effect : str
        The added effect.
    values : dict
        MAP of every parameter of the extended model.
    interval : dict
        ``(low, high)`` equal-tailed interval of each of the effect's free
        parameters at the diagnosis' ``ci_prob``, from Laplace draws.
    rms_m : float
        RMS error of the trial mean at the MAP.
    signature : Signature
        The refitted model's residual signature.
    explained : float
        Fraction of the base model's excess whitened residual energy (above pure
        noise) that the refit removes.
    elpd : float
        Leave-one-trial-out ELPD (PSIS-LOO over Laplace draws).
    elpd_diff : float
        ``elpd`` minus the base model's: positive when the effect predicts left-out
        trials better.
    elpd_diff_se : float
        Standard error of ``elpd_diff`` from the per-trial differences.
    contribution_m : numpy.ndarray
        The effect's contribution to the model output at the MAP: the output minus
        the output with the effect switched off (its null values).
    next_effect : str or None
        The significant candidate that best explains what the refit leaves (score
        test on the refit), if any; looked for only when the refit alone does not
        account for the misfit.
    explained_with_next : float
        Fraction of the base model's excess removed by the refit and, to first
        order, by ``next_effect`` after it: near 1 when the two together account
        for the misfit.
    signatures : tuple of Signature
        The refitted model's residual signature in each experiment, in the
        diagnosis' order (one experiment: ``(signature,)``).
    elpd_i : numpy.ndarray or None
        Per-trial leave-one-out ELPD, for paired comparisons of refits.

    Notes
    -----
    With several experiments, ``rms_m`` is pooled over every sample of every
    experiment, ``signature`` is the first experiment's (each is in
    ``signatures``), and ``contribution_m`` is the experiments' contributions
    concatenated along time, in order.
    """

    effect: str
    values: dict
    interval: dict
    rms_m: float
    signature: Signature
    explained: float
    elpd: float
    elpd_diff: float
    elpd_diff_se: float
    contribution_m: np.ndarray
    next_effect: str | None = None
    explained_with_next: float = 0.0
    signatures: tuple = ()
    elpd_i: np.ndarray | None = None


@dataclass(frozen=True)
class Finding:
    """One candidate effect in a diagnosis: its evidence, size and meaning.

    Parameters
    ----------
    effect : str
        Registry name.
    evidence : float
        Score (Lagrange multiplier) statistic that the effect is missing.
    p_value : float
        Its p-value.
    significant : bool
        Below the family-wise level (Bonferroni over the candidates).
    estimate : dict
        The effect's parameters: MAP of the refit when refitted, else the
        score test's one-step estimate.
    interval : dict
        ``(low, high)`` for each: Laplace interval of the refit, else the
        one-step interval.
    explained : float
        Fraction of the excess residual energy removed (refit, else first order).
    refit : Refit or None
        The refit, for significant candidates.
    explanation : str
        A paragraph in physical terms: what the effect is, the residual's
        signature, and what adding it does.
    """

    effect: str
    evidence: float
    p_value: float
    significant: bool
    estimate: dict
    interval: dict
    explained: float
    refit: Refit | None
    explanation: str

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        out = {
            "effect": self.effect, "evidence": self.evidence, "p_value": self.p_value,
            "significant": self.significant, "estimate": dict(self.estimate),
            "interval": {k: [float(a), float(b)] for k, (a, b) in self.interval.items()},
            "explained": self.explained, "explanation": self.explanation,
            "refit": None,
        }
        if self.refit is not None:
            out["refit"] = {"rms_m": self.refit.rms_m, "elpd_diff": self.refit.elpd_diff,
                            "elpd_diff_se": self.refit.elpd_diff_se,
                            "ljung_box_p": self.refit.signature.ljung_box_p,
                            "noise_ratio": _finite_or_none(self.refit.signature.ratio)}
            if len(self.refit.signatures) > 1:
                out["refit"]["experiments"] = [
                    {"rms_m": sig.bands[-1].rms_m, "noise_ratio": _finite_or_none(sig.ratio),
                     "ljung_box_p": sig.ljung_box_p, "energy": sig.energy}
                    for sig in self.refit.signatures]
        return out


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


@dataclass(frozen=True)
class ExperimentDiagnosis:
    """One experiment of a diagnosis: its data, its model's fit there, and its verdict.

    Parameters
    ----------
    name : str
        The experiment's name (its file's stem, :func:`pmabayes.inference.fitfile.experiment_names`).
    dataset : Dataset
        Its data.
    model : Model
        The diagnosed model on the experiment's rig.
    noise : NoiseEstimate
        Its noise: from its repeats (trials, or the periods of a periodic record),
        or, for a single record without repeats, identified with the model at the
        MAP (``mean_u`` and ``cov_u`` None).
    noise_source : str
        ``"trials"``, ``"periods"`` or ``"record"``
        (:attr:`pmabayes.inference.likelihood.Likelihood.noise_source`).
    simulation : Simulation
        The model at the shared MAP, on this experiment's rig and input.
    signature : Signature
        The residual's signature here. Its noise floor is NaN for a record without
        repeats (nothing to measure it with).
    adequate : bool
        The adequacy rule on this experiment's whitened residual.
    """

    name: str
    dataset: Dataset
    model: Model
    noise: NoiseEstimate
    noise_source: str
    simulation: Simulation
    signature: Signature
    adequate: bool

    @property
    def rms_m(self) -> float:
        """RMS error of the trial mean at the MAP."""
        return self.signature.bands[-1].rms_m

    @property
    def noise_floor_m(self) -> float:
        """RMS error a perfect model would have (NaN without repeats)."""
        return self.signature.bands[-1].floor_m

    @property
    def residual_m(self) -> np.ndarray:
        """Trial mean minus model, ``(n_samples,)``."""
        return self.dataset.mean_position_m - self.simulation.position_m[0]

    @property
    def innovations(self) -> np.ndarray:
        """The residual whitened by the identified noise model."""
        lik = Likelihood(self.model, self.dataset)
        return innovations(lik, self.simulation.position_m[0], self.noise)

    @property
    def frequency_hz(self) -> np.ndarray:
        """Instantaneous frequency of the command at each sample (for the figures)."""
        return instantaneous_frequency(self.dataset)

    def whiteness_curves(self) -> WhitenessCurves:
        """The whiteness figure's curves of the whitened residual (lags to 0.2 s, 99% bound)."""
        label = " + ".join(["base", *self.model.effect_names])
        rate = np.gradient(self.dataset.input[0], self.dataset.time_s)
        return whiteness_curves({label: self.innovations}, rate, self.dataset.dt_s)

    def floor_note(self) -> str:
        """Why there is no noise floor, or an empty string when there is one."""
        if math.isfinite(self.noise_floor_m):
            return ""
        return (f"{self.dataset.source or self.name} is a single record without repeats (no "
                "second trial, no declared periods), so it has no noise floor: its error is "
                "judged by the whiteness of its residual under the noise identified with the "
                "model, whose correlation time is bounded far below the input's time scales")

    def to_dict(self) -> dict:
        """JSON-ready summary of this experiment (an entry of ``experiments``)."""
        sig = self.signature
        return {
            "name": self.name, "data": self.dataset.source,
            "synthetic": bool(self.dataset.metadata.get("synthetic", False)),
            "rig": self.model.rig.to_dict(), "n_trials": int(self.dataset.n_trials),
            "n_samples": int(self.dataset.n_samples), "noise_source": self.noise_source,
            "noise": {"sigma_noise_m": float(self.noise.sigma),
                      "rho_noise": float(self.noise.rho),
                      "sigma_white_m": float(self.noise.white)},
            "rms_m": self.rms_m, "noise_floor_m": _finite_or_none(self.noise_floor_m),
            "ratio": _finite_or_none(sig.ratio), "adequate": self.adequate,
            "floor_note": self.floor_note() or None,
            "whiteness": {"ljung_box_p": sig.ljung_box_p, "energy": sig.energy,
                          "energy_p": sig.energy_p},
            "signature": sig.describe(),
            "bands": [b.to_dict() for b in sig.bands],
        }


@dataclass(frozen=True)
class Diagnosis:
    """A model confronted with repeated trials: how good, where it fails, what is missing.

    Parameters
    ----------
    dataset : Dataset
        The data (with several experiments, the first one's; see ``experiments``).
    model : Model
        The diagnosed model (with several experiments, on the first one's rig).
    values : dict
        Its MAP, with the noise parameters (with several experiments, each noise
        parameter maps the experiments' names to their values).
    noise : NoiseEstimate
        The noise identified from the spread between trials (with several
        experiments, the first one's).
    simulation : Simulation
        The model at the MAP, with its states (the first experiment's).
    signature : Signature
        The residual's signature (the first experiment's).
    adequate : bool
        The whitened residual is consistent with the noise: its mean square is
        within ``1 + energy_tolerance`` of pure noise and its autocorrelation is
        not significant (Ljung-Box at ``level_adequate``). With several
        experiments: in every one of them.
    missing : str or None
        The effect found missing: the refitted significant candidate with the best
        ELPD among those that account for the misfit and improve the ELPD by more
        than two standard errors (see :func:`diagnose`). None when nothing
        significant is missing, or when no candidate explains the misfit (see
        ``verdict``, which also says when another candidate cannot be told apart
        from it).
    ranking : list of Finding
        Every candidate, most evidence first: the refitted ones by ELPD, then the
        others by score statistic.
    elpd : float
        Leave-one-trial-out ELPD of the model (PSIS-LOO over Laplace draws), over
        every trial of every experiment.
    verdict : str
        The conclusion in words; with several experiments it names those whose
        residual shows the misfit.
    settings : dict
        The settings used (level, thresholds, ci_prob, seed).
    experiments : tuple of ExperimentDiagnosis
        Each experiment's data, model, noise, simulation, signature and verdict, in
        the given order (one entry for one data set).
    discrepancy : Discrepancy or None
        The missing force estimated from the data, when the model is above the floor
        and no candidate in the library accounts for it (see
        :func:`pmabayes.criticism.discrepancy.estimate_discrepancy`); None otherwise. With
        several experiments it is estimated on one of them.
    discrepancy_experiment : str or None
        The experiment the discrepancy was estimated on (the inadequate one furthest
        above its floor); None without a discrepancy.
    """

    dataset: Dataset
    model: Model
    values: dict
    noise: NoiseEstimate
    simulation: Simulation
    signature: Signature
    adequate: bool
    missing: str | None
    ranking: list
    elpd: float
    verdict: str
    settings: dict
    experiments: tuple = ()
    discrepancy: Discrepancy | None = None
    discrepancy_experiment: str | None = None

    @property
    def rms_m(self) -> float:
        """RMS error of the trial mean at the MAP (pooled over all samples of all experiments)."""
        if len(self.experiments) > 1:
            return _pooled([e.rms_m for e in self.experiments],
                           [e.dataset.n_samples for e in self.experiments])
        return self.signature.bands[-1].rms_m

    @property
    def noise_floor_m(self) -> float:
        """RMS error a perfect model would have (from the spread between trials; pooled
        over the experiments, NaN when one of them has no repeats)."""
        if len(self.experiments) > 1:
            return _pooled([e.noise_floor_m for e in self.experiments],
                           [e.dataset.n_samples for e in self.experiments])
        return self.signature.bands[-1].floor_m

    @property
    def misfit_experiments(self) -> list[str]:
        """Names of the experiments whose residual is not consistent with the noise."""
        return [e.name for e in self.experiments if not e.adequate]

    def _first(self) -> ExperimentDiagnosis:
        """The first experiment (built from the fields of a Diagnosis made without them)."""
        if self.experiments:
            return self.experiments[0]
        return ExperimentDiagnosis(
            name=self.dataset.source or "data", dataset=self.dataset, model=self.model,
            noise=self.noise, noise_source="trials", simulation=self.simulation,
            signature=self.signature, adequate=self.adequate)

    @property
    def residual_m(self) -> np.ndarray:
        """Trial mean minus model, ``(n_samples,)`` (the first experiment's)."""
        return self._first().residual_m

    @property
    def innovations(self) -> np.ndarray:
        """The residual whitened by the identified noise model (the first experiment's)."""
        return self._first().innovations

    @property
    def frequency_hz(self) -> np.ndarray:
        """Instantaneous frequency of the command at each sample (for the figures)."""
        return self._first().frequency_hz

    @property
    def score_threshold(self) -> float:
        """The score statistic above which a candidate is significant (1 dof)."""
        return significance_threshold(self.settings["level"], len(self.ranking))

    def whiteness_curves(self) -> WhitenessCurves:
        """The whiteness figure's curves of the whitened residual (lags to 0.2 s, 99% bound;
        the first experiment's)."""
        return self._first().whiteness_curves()

    def to_dict(self) -> dict:
        """JSON-ready summary (the keys of ``pmabayes diagnose --json``).

        One experiment: ``data``, ``synthetic``, ``effects``, ``rms_m``,
        ``noise_floor_m``, ``adequate``, ``missing``, ``verdict``, ``ranking``,
        ``values``, ``elpd_loo``, ``whiteness``, ``signature``, ``bands``,
        ``settings`` and ``discrepancy``. Several: the same keys, with ``data`` the
        sources joined by `` + ``, ``rms_m`` and ``noise_floor_m`` pooled over the
        experiments (the floor None when one has no repeats), ``whiteness`` and
        ``bands`` None (they are per experiment), ``discrepancy`` with one more key,
        ``experiment`` (the one it was estimated on), ``signature`` each experiment's
        in turn, and two more:
        ``experiments`` (one :meth:`ExperimentDiagnosis.to_dict` each) and
        ``misfit_experiments`` (the names of those that are not adequate).
        """
        if len(self.experiments) > 1:
            exps = self.experiments
            return {
                "data": " + ".join(str(e.dataset.source or e.name) for e in exps),
                "synthetic": all(bool(e.dataset.metadata.get("synthetic", False))
                                 for e in exps),
                "effects": list(self.model.effect_names),
                "rms_m": self.rms_m,
                "noise_floor_m": _finite_or_none(self.noise_floor_m),
                "adequate": self.adequate,
                "missing": self.missing,
                "verdict": self.verdict,
                "ranking": [f.to_dict() for f in self.ranking],
                "values": dict(self.values),
                "elpd_loo": self.elpd,
                "whiteness": None,
                "signature": " ".join(f"{e.name}: {e.signature.describe()}" for e in exps),
                "bands": None,
                "settings": dict(self.settings),
                "discrepancy": (None if self.discrepancy is None else
                                {**self.discrepancy.to_dict(),
                                 "experiment": self.discrepancy_experiment}),
                "experiments": [e.to_dict() for e in exps],
                "misfit_experiments": self.misfit_experiments,
            }
        sig = self.signature
        return {
            "data": self.dataset.source,
            "synthetic": bool(self.dataset.metadata.get("synthetic", False)),
            "effects": list(self.model.effect_names),
            "rms_m": self.rms_m,
            "noise_floor_m": _finite_or_none(self.noise_floor_m),
            "adequate": self.adequate,
            "missing": self.missing,
            "verdict": self.verdict,
            "ranking": [f.to_dict() for f in self.ranking],
            "values": dict(self.values),
            "elpd_loo": self.elpd,
            "whiteness": {"ljung_box_p": sig.ljung_box_p, "energy": sig.energy,
                          "energy_p": sig.energy_p},
            "signature": sig.describe(),
            "bands": [b.to_dict() for b in sig.bands],
            "settings": dict(self.settings),
            "discrepancy": None if self.discrepancy is None else self.discrepancy.to_dict(),
        }


def _pooled(rms: Sequence[float], sizes: Sequence[int]) -> float:
    """RMS over several series from each one's RMS and length (NaN if one is NaN)."""
    total = sum(r * r * n for r, n in zip(rms, sizes, strict=True))
    return float(math.sqrt(total / sum(sizes)))


def _laplace_loo(posterior, map_result, rng: np.random.Generator, n_draws: int, ci_prob: float,
                 names: tuple[str, ...] = ()):
    """PSIS-LOO (by trial, over every trial of every experiment) and intervals from draws
    of the MAP's Laplace approximation."""
    import arviz as az

    z = rng.multivariate_normal(map_result.z, map_result.covariance_z, size=n_draws,
                                method="eigh")
    theta = posterior.to_natural(z)
    theta = theta[np.isfinite(posterior.log_prior(theta))]
    full = posterior.full_theta(theta)
    group_draws: dict = {}
    parts = []
    for e, lik in enumerate(posterior.likelihoods):
        x = lik.simulate(full)
        if posterior.noise_sampled(e):  # no repeats: the noise is in the draws
            noise = posterior.noise_of(e, theta)
        else:  # from the repeats: independent draws of its posterior, one set per group
            g = posterior.groups[e]
            if g not in group_draws:
                group_draws[g] = posterior.group_noise[g].draws(rng, theta.shape[0])
            noise = group_draws[g]
        parts.append(lik.pointwise(x, *noise))
    pointwise = np.concatenate(parts, axis=1)
    ok = np.all(np.isfinite(pointwise), axis=1)
    tree = az.from_dict({"posterior": {"theta": theta[ok][None, :, 0]},
                         "log_likelihood": {"position_m": pointwise[ok][None]}},
                        dims={"position_m": ["trial"]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pareto k is reported in the summary instead
        loo = az.loo(tree, var_name="position_m")
    tail = (1.0 - ci_prob) / 2.0
    interval = {}
    for n in names:
        j = posterior.names.index(n)
        lo, hi = np.quantile(theta[ok][:, j], [tail, 1.0 - tail])
        interval[n] = (float(lo), float(hi))
    return float(loo.elpd), np.asarray(loo.elpd_i).reshape(-1), interval


def _model_values(model, values: dict) -> dict:
    return {k: v for k, v in values.items() if k in model.parameter_names}


def _contribution_text(contribution_m: np.ndarray, base_residual_m: np.ndarray,
                       dt_s: float, bands_hz) -> str:
    if not np.std(contribution_m) > 0:
        return ""
    corr = float(np.corrcoef(contribution_m, base_residual_m)[0, 1])
    rms = band_rms(contribution_m, dt_s, bands_hz)
    k = int(np.argmax(rms))
    return (f" Its contribution to the output correlates {corr:+.2f} with the base model's "
            f"residual and is largest at {band_label(bands_hz[k])} ({rms[k] * 1e6:.4g} µm RMS).")


def _after_text(signatures: Sequence[Signature], names: Sequence[str]) -> str:
    """The refit's RMS error against the floor: ``X µm (Yx the floor)``, per experiment."""
    def one(sig: Signature) -> str:
        floor = (f"{sig.ratio:.3g}x the floor" if math.isfinite(sig.bands[-1].floor_m)
                 else "no floor")
        return f"{sig.bands[-1].rms_m * 1e6:.4g} µm ({floor})"

    if len(signatures) == 1:
        return one(signatures[0])
    return ", ".join(f"{one(sig)} in {n}" for sig, n in zip(signatures, names, strict=True))


def _describe(signatures: Sequence[Signature], names: Sequence[str]) -> str:
    if len(signatures) == 1:
        return signatures[0].describe()
    return " ".join(f"In {n}: {sig.describe()}" for sig, n in zip(signatures, names, strict=True))


def _explanation(eff, evidence: float, p_value: float, significant: bool,
                 describe: str, refit: Refit | None, contribution_text: str,
                 ci_prob: float, names: Sequence[str]) -> str:
    text = f"{eff.name} ({eff.stage} stage): {' '.join(eff.description.split())} "
    text += describe
    text += (f" Score test that {eff.name} is missing: statistic {evidence:.3g}, "
             f"p = {p_value:.2g}, {'significant' if significant else 'not significant'}.")
    if refit is None:
        return text
    parts = []
    for p in eff.parameters:
        if p.name in refit.interval:
            lo, hi = refit.interval[p.name]
            parts.append(f"{p.name} = {refit.values[p.name]:.4g} {p.unit} "
                         f"({ci_prob:.0%} interval {lo:.4g} to {hi:.4g})")
    text += (f" Added and refitted, it takes {', '.join(parts)}; the RMS error falls to "
             f"{_after_text(refit.signatures, names)}, "
             f"{refit.explained:.0%} of the excess residual is removed, and the "
             f"leave-one-trial-out {_elpd_text(refit, 'changes by')}.")
    return text + contribution_text


def _fit_map(likelihoods: list, repeat_noise: list, names: list, rng: np.random.Generator,
             choices: list, *, refer: bool):
    """The MAP of the experiments together: physical parameters shared, each experiment's
    noise from its repeats (fixed) or, for a record without repeats (None), with the model
    (``choices``: each one's noise model). ``refer``: learn a record from rest's noise
    from its periods' residual at the MAP, as the fit does (the base model); the refits
    keep the base's, so that their likelihoods compare."""
    posterior = Posterior(likelihoods, repeat_noise, names=names, noise_choices=choices)
    return posterior, find_map(posterior, rng=rng, refer=refer)


def _experiment_noises(posterior: Posterior, best) -> list[NoiseEstimate]:
    """Each experiment's noise at the MAP: its estimate from repeats, or the MAP's values
    where it was identified with the model (no Laplace part: ``mean_u``, ``cov_u`` None)."""
    theta = posterior.to_natural(np.asarray(best.z)[None])
    out = []
    for e in range(posterior.n_experiments):
        if not posterior.noise_sampled(e):
            out.append(posterior.group_noise[posterior.groups[e]])
            continue
        sigma, rho, white = (float(np.asarray(v).reshape(-1)[0])
                             for v in posterior.noise_of(e, theta))
        out.append(NoiseEstimate(sigma, rho, white, None, None))
    return out


@dataclass(frozen=True)
class _Settings:
    """The settings of one diagnosis, checked."""

    level: float
    level_adequate: float
    energy_tolerance: float
    max_refits: int
    min_explained: float
    ci_prob: float
    n_draws: int
    substeps: int
    candidates: tuple | None
    noise_model: str = "auto"

    def __post_init__(self) -> None:
        check_noise_model_name(self.noise_model)
        if not 0.0 < self.level < 1.0 or not 0.0 < self.level_adequate < 1.0:
            raise ValueError("level and level_adequate must be in (0, 1)")
        if not 0.0 < self.ci_prob < 1.0:
            raise ValueError(f"ci_prob must be in (0, 1), got {self.ci_prob}")
        if not 0.0 <= self.min_explained <= 1.0:
            raise ValueError(f"min_explained must be in [0, 1], got {self.min_explained}")
        if int(self.max_refits) < 0 or int(self.n_draws) < 50:
            raise ValueError("max_refits must be >= 0 and n_draws >= 50")
        for c in self.candidates or ():
            get_effect(c)  # unknown names fail here, before any fitting

    def adequate(self, signature: Signature) -> bool:
        return signature.is_adequate(self.energy_tolerance, self.level_adequate)

    def all_adequate(self, signatures: Sequence[Signature]) -> bool:
        """Adequate in every experiment."""
        return all(self.adequate(sig) for sig in signatures)


@dataclass(frozen=True)
class _Base:
    """The diagnosed model at its MAP over the experiments: what each refit is measured
    against."""

    likelihoods: list
    names: list
    repeat_noise: list
    noise_choices: list
    noises: list
    values: dict
    simulations: list
    signatures: list
    elpd: float
    elpd_i: np.ndarray

    @property
    def excess(self) -> float:
        """The whitened residual's energy above pure noise, summed over the samples (and
        the experiments)."""
        total = sum(sig.energy * lik.n_samples - lik.n_samples
                    for sig, lik in zip(self.signatures, self.likelihoods, strict=True))
        return max(total, 1e-12)

    @property
    def residuals(self) -> list[np.ndarray]:
        """Each experiment's trial mean minus the model."""
        return [lik.y_mean - sim.position_m[0]
                for lik, sim in zip(self.likelihoods, self.simulations, strict=True)]


def _simulate(model: Model, values: dict, likelihood: Likelihood, substeps: int) -> Simulation:
    return simulate_dataset(model, _model_values(model, values), likelihood.dataset,
                            substeps=substeps, states=True)


def _fit_base(models: list, datasets: list, names: list, s: _Settings,
              rng: np.random.Generator) -> _Base:
    """Noise from the spread between repeats, the shared MAP, the signatures and the ELPD."""
    liks = [Likelihood(m, ds, substeps=s.substeps) for m, ds in zip(models, datasets, strict=True)]
    noise_and_choice = [group_noise([lik], s.noise_model) for lik in liks]
    posterior, best = _fit_map(liks, [n for n, _ in noise_and_choice], names, rng,
                               [c for _, c in noise_and_choice], refer=True)
    # as the fit: a record from rest's noise from its periods' residual at the MAP
    repeat_noise = list(posterior.group_noise)
    values = dict(best.values)
    noises = _experiment_noises(posterior, best)
    sims = [_simulate(lik.model, values, lik, s.substeps) for lik in liks]
    signatures = [residual_signature(lik, noise, sim)
                  for lik, noise, sim in zip(liks, noises, sims, strict=True)]
    elpd, elpd_i, _ = _laplace_loo(posterior, best, rng, s.n_draws, s.ci_prob)
    return _Base(liks, names, repeat_noise, list(posterior.noise_choices), noises, values,
                 sims, signatures, elpd, elpd_i)


def _refit(base: _Base, effect: str, s: _Settings, rng: np.random.Generator) -> Refit:
    """Add one effect, refit over every experiment, and measure what it explains and how
    it predicts."""
    ext_liks = [Likelihood(lik.model.with_effects(effect), lik.dataset, substeps=s.substeps)
                for lik in base.likelihoods]
    for ext, lik in zip(ext_liks, base.likelihoods, strict=True):
        ext.use_ar_noise(lik.ar_noise)
    ext_post, ext_map = _fit_map(ext_liks, base.repeat_noise, base.names, rng,
                                 base.noise_choices, refer=False)
    ext = ext_liks[0].model
    eff = ext.effects[-1]
    tested = tuple(p.name for p in eff.parameters if p.vary and p.name in ext.free_names)
    e_elpd, e_elpd_i, interval = _laplace_loo(ext_post, ext_map, rng, s.n_draws, s.ci_prob,
                                              tested)
    ext_noises = _experiment_noises(ext_post, ext_map)
    off = dict(ext_map.values)
    off.update({p.name: p.null for p in eff.parameters if p.vary and p.null is not None})
    sigs, contributions = [], []
    for lik, ext_lik, noise in zip(base.likelihoods, ext_liks, ext_noises, strict=True):
        ext_sim = _simulate(ext_lik.model, ext_map.values, lik, s.substeps)
        contributions.append(ext_sim.position_m[0]
                             - _simulate(ext_lik.model, off, lik, s.substeps).position_m[0])
        sigs.append(residual_signature(ext_lik, noise, ext_sim))
    # with no excess over pure noise there is nothing to explain
    gain = sum((b.energy - x.energy) * lik.n_samples
               for b, x, lik in zip(base.signatures, sigs, base.likelihoods, strict=True))
    over = sum((b.energy - 1.0) * lik.n_samples
               for b, lik in zip(base.signatures, base.likelihoods, strict=True))
    explained = float(np.clip(gain / base.excess, 0.0, 1.0)) if over > 0 else 0.0
    nxt = None
    if explained < s.min_explained and not s.all_adequate(sigs):
        # one step of look-ahead: does another candidate account for what is left?
        following = [e for e in rank_effects(ext_liks, ext_noises, ext_map.values,
                                             candidates=s.candidates, level=s.level)
                     if e.significant]
        nxt = max(following, key=lambda e: e.explained) if following else None
    diff = e_elpd_i - base.elpd_i
    sq = [sig.bands[-1].rms_m for sig in sigs]
    rms = sq[0] if len(sq) == 1 else _pooled(sq, [lik.n_samples for lik in base.likelihoods])
    return Refit(
        effect=effect, values=dict(ext_map.values), interval=interval,
        rms_m=rms, signature=sigs[0], explained=explained,
        elpd=e_elpd, elpd_diff=float(diff.sum()),
        elpd_diff_se=float(math.sqrt(diff.size * np.var(diff))),
        contribution_m=np.concatenate(contributions), next_effect=nxt.effect if nxt else None,
        explained_with_next=explained + (1.0 - explained) * (nxt.explained if nxt else 0.0),
        signatures=tuple(sigs),
        elpd_i=e_elpd_i,
    )


def _refit_significant(base: _Base, ranked: list, s: _Settings, rng: np.random.Generator,
                       progress: Progress) -> dict[str, Refit]:
    """Refit the strongest significant candidates, at most ``max_refits`` of them."""
    refits: dict[str, Refit] = {}
    for ev in [e for e in ranked if e.significant][: int(s.max_refits)]:
        progress.say(f"refitting with {ev.effect} ({len(refits) + 1} of at most "
                     f"{s.max_refits})")
        refits[ev.effect] = _refit(base, ev.effect, s, rng)
    return refits


def _findings(ranked: list, refits: dict, base: _Base, ci_prob: float) -> list[Finding]:
    """Every candidate with its estimate and explanation; the refitted ones first, by ELPD."""
    residuals = base.residuals
    describe = _describe(base.signatures, base.names)
    edges = np.cumsum([0, *(r.size for r in residuals)])
    findings = []
    for ev in ranked:
        eff = get_effect(ev.effect)
        refit = refits.get(ev.effect)
        if refit is not None:
            estimate = {k: refit.values[k] for k in refit.interval}
            interval, explained = refit.interval, refit.explained
            texts = []
            for e, lik in enumerate(base.likelihoods):
                part = _contribution_text(refit.contribution_m[edges[e]:edges[e + 1]],
                                          residuals[e], lik.dataset.dt_s,
                                          input_bands(lik.dataset))
                texts.append(part if len(residuals) == 1 or not part
                             else f" In {base.names[e]}:{part}")
            contrib = "".join(texts)
        else:
            estimate, interval, explained, contrib = ev.estimate, ev.interval, ev.explained, ""
        findings.append(Finding(
            effect=ev.effect, evidence=ev.statistic, p_value=ev.p_value,
            significant=ev.significant, estimate=estimate, interval=interval,
            explained=explained, refit=refit,
            explanation=_explanation(eff, ev.statistic, ev.p_value, ev.significant,
                                     describe, refit, contrib, ci_prob, base.names),
        ))
    # refitted candidates first, by how well they predict left-out trials
    findings.sort(key=lambda f: (f.refit is None, -(f.refit.elpd if f.refit else f.evidence)))
    return findings


def _explaining(refits: dict, s: _Settings) -> list[Refit]:
    """The refits that account for the misfit and predict left-out trials better."""
    return [r for r in refits.values()
            if (max(r.explained, r.explained_with_next) >= s.min_explained
                or s.all_adequate(r.signatures))
            and r.elpd_diff > 2.0 * r.elpd_diff_se]


def _missing(refits: dict, s: _Settings) -> str | None:
    """The refit that accounts for the misfit and predicts left-out trials best, if any."""
    explaining = _explaining(refits, s)
    return max(explaining, key=lambda r: r.elpd).effect if explaining else None


def _twins(refits: dict, missing: str | None, s: _Settings) -> list[tuple[str, float, float]]:
    """The other explaining refits whose ELPD is within two standard errors of the
    missing one's (paired over trials): ``(effect, elpd difference, its SE)``."""
    if missing is None or refits[missing].elpd_i is None:
        return []
    best, out = refits[missing], []
    for r in _explaining(refits, s):
        if r.effect == missing or r.elpd_i is None:
            continue
        diff = best.elpd_i - r.elpd_i
        se = float(math.sqrt(diff.size * np.var(diff)))
        if float(diff.sum()) <= 2.0 * se:
            out.append((r.effect, float(diff.sum()), se))
    return out


def _experiments(datasets, model: Model | None, effects: Iterable[str]
                 ) -> tuple[list[Dataset], list[Model], list[str]]:
    """The data sets, each one's model (on its rig) and the experiments' names."""
    dss, models, names = experiments(datasets, model or Model())
    if model is None:
        models = [Model.for_dataset(ds) for ds in dss]
    effects = list(effects)
    if effects:
        models = [m.with_effects(*[e for e in effects if e not in m.effect_names])
                  for m in models]
    return dss, models, names


def diagnose(
    datasets: Dataset | Sequence[Dataset],
    model: Model | None = None,
    *,
    effects: Iterable[str] = (),
    candidates: Iterable[str] | None = None,
    level: float = 0.05,
    level_adequate: float = LEVEL_ADEQUATE,
    energy_tolerance: float = ENERGY_TOLERANCE,
    max_refits: int = 3,
    min_explained: float = 0.9,
    ci_prob: float = 0.9,
    n_draws: int = 400,
    seed: int | np.random.Generator = 0,
    substeps: int = 1,
    progress: bool = False,
    discrepancy: bool = True,
    plugin_dir=None,
    noise_model: str = "auto",
) -> Diagnosis:
    """Fit a model, criticise it and find which effect in the library is missing.

    1. The noise comes from the spread between trials and the model's MAP from
       the trial mean (:func:`pmabayes.inference.search.find_map`).
    2. The residual's signature: errors per frequency band against the noise
       floor, whiteness of the residual whitened by the noise model, its
       correlation with the model's states and with the command's rate.
    3. Every candidate effect is ranked by the score test
       (:func:`rank_effects`), which needs no refit.
    4. The significant candidates (at most ``max_refits``, strongest first) are
       added one at a time and refitted; each refit is judged by the excess
       residual it removes and by its leave-one-trial-out ELPD (PSIS-LOO over
       draws from the refit's Laplace approximation). The refit also gives the
       effect's size with an interval. This separates effects that the first-order
       score test cannot (a regulator lag and a transport delay).
    5. The missing effect is the refitted candidate with the best ELPD among
       those that account for the misfit and predict left-out trials better than
       the diagnosed model by more than two standard errors of the ELPD
       difference. Accounting for the misfit means: the refit is adequate, or it
       removes at least ``min_explained`` of the excess residual alone or
       together with the candidate that the refit's own score test finds next
       (so that two missing effects of similar size are found one after the
       other). If none qualifies, nothing is named: a misfit above the floor is
       reported as unexplained instead of naming the least bad candidate. When
       another qualifying refit's ELPD is within two standard errors of the
       named one's (paired over the trials), the verdict says that the two cannot
       be told apart by these data (near twins, such as a regulator lag and a
       well-damped second-order regulator).
    6. Then, with ``discrepancy``, the missing force is estimated from the data
       (:func:`pmabayes.criticism.discrepancy.estimate_discrepancy`): the states it depends
       on, with their evidence, and a closed form written as a ready user effect
       (a ``.py`` file for ``--plugin``, in ``plugin_dir``).

    Several experiments (a sequence of data sets, each with its own input, rig
    and trials, as :func:`pmabayes.inference.sampler.fit` takes them) are diagnosed together:
    one MAP of the shared physical parameters, each experiment on its own rig
    with its own noise; a signature and an adequacy verdict per experiment (the
    model is adequate only if it is in every one); the score test with the
    experiments' scores and informations summed; the candidates refitted over
    all of them; the ELPD leaving out one trial at a time of all of them. The
    verdict names the experiments whose residual shows the misfit.

    Repeats: an experiment's noise comes from its trials, or from the periods of
    a single periodic record (``period_samples``), whose spread also gives its
    noise floor. A single record without either has no floor; its noise is
    identified with the model (under the guard of
    :meth:`pmabayes.inference.likelihood.Likelihood.noise_parameters`), and the verdict
    says that it is judged by its whitened residual alone.

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        Repeated trials of one input, or several experiments (one input kind).
    model : Model, optional
        The model to diagnose; the base model on each data set's rig by default.
        With several experiments it is put on each one's rig (as
        :func:`pmabayes.inference.sampler.fit` does).
    effects : iterable of str
        Effects to add to ``model`` first (as ``--effects`` on the command line).
    candidates : iterable of str, optional
        Effects to test; every registered effect not in the model by default.
    level : float
        Family-wise false-alarm level of the ranking.
    level_adequate : float
        Level of the Ljung-Box test of ``adequate``.
    energy_tolerance : float
        ``adequate`` also needs the whitened residual's mean square within
        ``1 + energy_tolerance`` of pure noise. A tolerance, not a chi-squared
        test: with the noise parameters estimated from a few trials the energy of
        pure noise scatters by about 0.03 around 1 (measured), twice the
        chi-squared spread, so an exact test would reject correct models. 0.1
        means a model error below about a third of the noise level.
    max_refits : int
        Significant candidates refitted at most.
    min_explained : float
        Fraction of the excess residual that a refit (alone or with the next
        candidate) must remove for its effect to be named missing.
    ci_prob : float
        Probability of the intervals.
    n_draws : int
        Laplace draws for the ELPD and the intervals.
    seed : int or numpy.random.Generator
        Seeds the global searches and the draws.
    substeps : int
        Simulator substeps per sample.
    progress : bool
        Print what is being done to stderr.
    discrepancy : bool
        Estimate the missing force from the data when the model is above the floor
        and no candidate accounts for it.
    plugin_dir : str or Path, optional
        Where the proposed effect's ``.py`` file is written (the current folder by
        default; an existing file is never overwritten).
    noise_model : str
        The likelihood's noise model where the noise comes from repeats, as in
        :func:`pmabayes.inference.sampler.fit`: ``"auto"`` (AR(1) + white unless the repeats reject
        it, then their AR(p)), ``"ar1"`` or ``"ar"``. It is what the MAP, the refits,
        their intervals and the ELPD use; the score tests and the discrepancy step
        whiten with AR(1) + white.

    Returns
    -------
    Diagnosis

    Raises
    ------
    ValueError
        On settings out of range, no data, or experiments of different input
        kinds (:class:`pmabayes.data.DataError`, naming the files).
    """

    s = _Settings(level=level, level_adequate=level_adequate,
                  energy_tolerance=energy_tolerance, max_refits=max_refits,
                  min_explained=min_explained, ci_prob=ci_prob, n_draws=n_draws,
                  substeps=substeps, candidates=None if candidates is None else tuple(candidates),
                  noise_model=noise_model)
    say = Progress("diagnose", progress)
    rng = np.random.default_rng(seed)
    datasets, models, names = _experiments(datasets, model, effects)
    model = models[0]
    name = " + ".join(["base", *model.effect_names])
    where = " and ".join(str(ds.source or "the data") for ds in datasets)
    say.say(f"fitting {name} to {where} (MAP)")
    base = _fit_base(models, datasets, names, s, rng)
    say.say("ranking the candidate effects (score test)")
    ranked = rank_effects(base.likelihoods, base.noises, base.values, candidates=s.candidates,
                          level=level)
    refits = _refit_significant(base, ranked, s, rng, say)
    findings = _findings(ranked, refits, base, ci_prob)
    each = [s.adequate(sig) for sig in base.signatures]
    adequate = all(each)
    missing = _missing(refits, s)
    experiments = tuple(
        ExperimentDiagnosis(name=n, dataset=lik.dataset, model=lik.model, noise=noise,
                            noise_source=lik.noise_source, simulation=sim, signature=sig,
                            adequate=ok)
        for n, lik, noise, sim, sig, ok in zip(base.names, base.likelihoods, base.noises,
                                               base.simulations, base.signatures, each,
                                               strict=True))
    verdict = _verdict(name, model.effect_names, experiments, adequate, missing, refits,
                       findings, min_explained, _twins(refits, missing, s))
    found = None
    # its evidence leaves one trial out: it needs an experiment with repeated trials
    repeated = [e for e, lik in enumerate(base.likelihoods) if lik.dataset.n_trials >= 2]
    if discrepancy and not adequate and missing is None and not repeated:
        verdict += (" The data-driven discrepancy step needs repeated trials (its evidence "
                    "leaves one trial out), and these data have none; record repeats to "
                    "estimate the missing force.")
    elif discrepancy and not adequate and missing is None:
        # the missing force is estimated on one experiment: with several, the one whose
        # residual is furthest above its floor (the others are named in the command
        # that checks the proposal on all of them)
        k = _worst_experiment(base.signatures, each, repeated)
        if len(datasets) > 1:
            say.say(f"estimating the missing force from {base.names[k]} (discrepancy; "
                    "the experiment furthest above its floor)")
        else:
            say.say("estimating the missing force from the data (discrepancy)")
        found = estimate_discrepancy(base.likelihoods[k], base.noises[k], base.values,
                                     base.simulations[k], plugin_dir=plugin_dir,
                                     command=" ".join(str(ds.source or "DATA")
                                                      for ds in datasets),
                                     effects=model.effect_names)
        if len(datasets) > 1:
            verdict += (f" The missing force was estimated from {base.names[k]}, the "
                        "experiment furthest above its floor; the command below checks the "
                        "proposal on all of them.")
        verdict += " " + found.text
    say.say(verdict)
    return Diagnosis(
        dataset=datasets[0], model=model, values=base.values, noise=base.noises[0],
        simulation=base.simulations[0], signature=base.signatures[0], adequate=adequate,
        missing=missing, ranking=findings, elpd=base.elpd, verdict=verdict,
        settings={"level": level, "level_adequate": level_adequate,
                  "energy_tolerance": energy_tolerance, "max_refits": max_refits,
                  "min_explained": min_explained, "ci_prob": ci_prob, "n_draws": n_draws,
                  "seed": seed if isinstance(seed, int) else None, "substeps": substeps,
                  "candidates": [f.effect for f in findings],
                  "noise_model": [lik.noise_model_name if noise is not None else None
                                  for lik, noise in zip(base.likelihoods, base.repeat_noise,
                                                        strict=True)]},
        experiments=experiments,
        discrepancy=found,
        discrepancy_experiment=None if found is None else base.names[k],
    )


def _worst_experiment(signatures, adequate_each, among) -> int:
    """Index, of those in ``among``, of the inadequate experiment furthest above its
    floor (by the ratio of its RMS error to its floor; by the whitened residual energy
    where it has none)."""
    def excess(k: int) -> tuple:
        sig = signatures[k]
        ratio = sig.ratio
        return (not adequate_each[k], math.isfinite(ratio),
                ratio if math.isfinite(ratio) else sig.energy)
    return max(among, key=excess)


def _elpd_text(refit, verb: str = "") -> str:
    """``ΔELPD +d ± se`` of a refit, or that it could not be estimated (PSIS-LOO over
    the refit's Laplace draws gave no finite value, e.g. when its draws do not
    simulate)."""
    if not (math.isfinite(refit.elpd_diff) and math.isfinite(refit.elpd_diff_se)):
        return "ΔELPD not estimable: PSIS-LOO over the refit's Laplace draws gave no finite value"
    head = f"ELPD {verb} " if verb else "ΔELPD "
    return f"{head}{refit.elpd_diff:+.1f} ± {refit.elpd_diff_se:.1f}"


def _sig_text(signature: Signature) -> str:
    overall = signature.bands[-1]
    floor = (f"against a floor of {overall.floor_m * 1e6:.4g} µm"
             if math.isfinite(overall.floor_m) else "with no noise floor (no repeats)")
    return (f"RMS error {overall.rms_m * 1e6:.4g} µm {floor}; whitened residual energy "
            f"{signature.energy:.3g} (p = {signature.energy_p:.2g}), Ljung-Box "
            f"p = {signature.ljung_box_p:.2g}")


def _verdict(name: str, effects: tuple, experiments: tuple, adequate: bool,
             missing: str | None, refits: dict, findings: list, min_explained: float,
             twins: list | None = None) -> str:
    names = [e.name for e in experiments]
    if len(experiments) == 1:
        sig = _sig_text(experiments[0].signature)
    else:
        sig = "; ".join(f"{e.name}: {_sig_text(e.signature)}" for e in experiments)
    notes = " ".join(f"({e.floor_note()}.)" for e in experiments if e.floor_note())
    where = ""
    if len(experiments) > 1 and not adequate:
        bad = [e.name for e in experiments if not e.adequate]
        good = [e.name for e in experiments if e.adequate]
        where = (f" The misfit shows in {', '.join(bad)}"
                 + (f"; {', '.join(good)} {'is' if len(good) == 1 else 'are'} consistent with "
                    "the noise." if good else "."))
    text = _verdict_core(name, effects, sig, adequate, missing, refits, findings,
                         min_explained, names, twins)
    return text + where + (f" {notes}" if notes else "")


def _verdict_core(name: str, effects: tuple, sig: str, adequate: bool, missing: str | None,
                  refits: dict, findings: list, min_explained: float, names: list,
                  twins: list | None = None) -> str:
    if missing is not None:
        r = refits[missing]
        tied = [t[0] for t in twins or ()]
        others = [f.effect for f in findings
                  if f.refit is not None and f.effect != missing and f.effect not in tied]
        text = (f"{name}: {missing} is missing ({sig}). Adding it lowers the RMS error to "
                f"{_after_text(r.signatures, names)} and removes "
                f"{r.explained:.0%} of the excess residual.")
        for twin, diff, se in twins or ():
            text += (f" But {missing} and {twin} cannot be told apart by these data: both "
                     f"account for the misfit and their leave-one-trial-out ELPDs differ by "
                     f"only {diff:+.1f} ± {se:.1f} (less than two standard errors), so "
                     f"{missing} is named for its slightly better ELPD, not proven; data "
                     "that excite where they differ would separate them.")
        if others:
            text += (f" It predicts left-out trials better than the other refitted "
                     f"candidate(s) ({', '.join(others)}).")
        return text + (f" Next: add it (--effects {','.join([*effects, missing])}) and "
                       "diagnose again.")
    significant = [f for f in findings if f.significant]
    if adequate and not significant:
        return (f"{name} is adequate: the residual is consistent with the noise floor ({sig}) "
                "and no candidate effect is significantly missing.")
    if not significant:
        return (f"{name}: the residual is above the noise floor ({sig}), but no effect in "
                "the library is significantly missing; something outside the library is. "
                "See the residual signature figures, and register an effect that describes "
                "it.")
    if adequate:
        named = ", ".join(f"{f.effect} (p = {f.p_value:.2g}" + (
            f", refit {_elpd_text(f.refit)})"
            if f.refit else ")") for f in significant)
        return (f"{name} is adequate: the residual is consistent with the noise floor ({sig}). "
                f"The score test flags {named}, but no refit predicts left-out trials "
                "clearly better, so nothing is named; with a family-wise level of 5%, this "
                "is what a false alarm looks like.")
    best = (max(refits.values(), key=lambda r: max(r.explained, r.explained_with_next))
            if refits else None)
    detail = ""
    if best is not None:
        detail = (f" the best refit ({best.effect}) removes only {best.explained:.0%} of the "
                  "excess residual")
        if best.next_effect:
            detail += f" ({best.explained_with_next:.0%} with {best.next_effect} after it)"
        detail += (f", and at least {min_explained:.0%} is required "
                   f"({_elpd_text(best)})")
    return (f"{name}: the residual is above the noise "
            f"floor ({sig}); candidates are significant but none explains the misfit:"
            f"{detail}. Something outside the library is missing; no candidate is named.")


# ---------------------------------------------------------------------------------
# watching the error fall: fits of the same data side by side


@dataclass(frozen=True)
class FitComparison:
    """Fits of one data set side by side (base, base + effect, ...).

    Parameters
    ----------
    labels : list of str
        One per fit, in the given order (``base``, ``base + regulator_lag``...).
    bands : dict
        Label to :func:`band_errors` of the MAP model.
    whiteness : dict
        Label to ``{"ljung_box_p", "energy", "energy_p"}`` of the whitened residual.
    innovations : dict
        Label to the whitened residual.
    elpd : dict
        Label to ``{"elpd", "se", "elpd_diff", "dse", "rank", "max_pareto_k"}``:
        leave-one-trial-out PSIS-LOO (:func:`arviz.loo`) on the fits' posterior
        draws; ``elpd_diff`` and its standard error ``dse`` are relative to the best
        fit, from the paired per-trial differences (as :func:`arviz.compare`).
    elpd_steps : list of dict
        Each fit against the one before it: ``{"from", "to", "elpd_diff", "se"}``
        with the standard error of the paired per-trial differences.
    command_rate : numpy.ndarray
        Rate of change of the commanded input (for the cross-correlation figure).
    dt_s : float
        Sample interval.
    experiments : dict
        For fits of several experiments: experiment name to the comparison on that
        experiment alone (its ``bands``, ``whiteness``, ``innovations``,
        ``command_rate`` and ``dt_s``; ``elpd`` and ``elpd_steps`` are the
        overall ones), in the fits' order. Then ``bands``, ``whiteness`` and
        ``innovations`` are empty, ``command_rate`` is empty and ``dt_s`` NaN:
        errors and whiteness are per experiment, and only the ELPD (leaving out
        one trial at a time of all experiments) is overall. Empty for one
        experiment.
    """

    labels: list
    bands: dict
    whiteness: dict
    innovations: dict
    elpd: dict
    elpd_steps: list
    command_rate: np.ndarray
    dt_s: float
    experiments: dict | None = None

    def whiteness_curves(self) -> WhitenessCurves:
        """The whiteness figure's curves of each fit (lags to 0.2 s, 99% bound).

        Raises
        ------
        ValueError
            For fits of several experiments: take each experiment's from
            ``experiments[name].whiteness_curves()``.
        """
        if self.experiments:
            raise ValueError("a comparison of fits of several experiments has whiteness curves "
                             "per experiment: use experiments[name].whiteness_curves()")
        return whiteness_curves(self.innovations, self.command_rate, self.dt_s)

    def rmse_m(self, label: str) -> dict:
        """RMS error of the trial mean at a fit's MAP, per experiment.

        Parameters
        ----------
        label : str
            The fit.

        Returns
        -------
        dict
            Experiment name to RMS error in m (one experiment: ``{"data": ...}``).
        """
        if self.experiments:
            return {n: c.bands[label][-1].rms_m for n, c in self.experiments.items()}
        return {"data": self.bands[label][-1].rms_m}

    def to_dict(self) -> dict:
        """JSON-ready summary.

        One experiment: ``fits`` (``label``, ``rms_m``, ``noise_floor_m``, ``ratio``,
        ``bands``, ``whiteness``, ``elpd`` each) and ``elpd_steps``. Several: each
        fit has ``label``, ``elpd`` (over all trials) and ``experiments`` (name to
        ``rms_m``, ``noise_floor_m``, ``ratio``, ``bands``, ``whiteness``), and
        ``experiments`` lists the names.
        """
        if self.experiments:
            return {
                "fits": [
                    {"label": k, "elpd": self.elpd[k],
                     "experiments": {n: c._fit_dict(k) for n, c in self.experiments.items()}}
                    for k in self.labels
                ],
                "elpd_steps": self.elpd_steps,
                "experiments": list(self.experiments),
            }
        return {
            "fits": [{"label": k, **self._fit_dict(k), "elpd": self.elpd[k]}
                     for k in self.labels],
            "elpd_steps": self.elpd_steps,
        }

    def _fit_dict(self, k: str) -> dict:
        last = self.bands[k][-1]
        return {"rms_m": last.rms_m, "noise_floor_m": _finite_or_none(last.floor_m),
                "ratio": _finite_or_none(last.ratio),
                "bands": [b.to_dict() for b in self.bands[k]], "whiteness": self.whiteness[k]}


def compare_fits(fits, dataset: Dataset | Sequence[Dataset], *, labels=None,
                 sources: Sequence[str] | None = None) -> FitComparison:
    """Compare fits of the same data: error per band, whiteness and ELPD.

    Fits of several experiments compare too, when every fit has the same
    experiments (names, data, in the same order): the errors and whiteness per
    experiment, the ELPD leaving out one trial at a time of all of them.

    Parameters
    ----------
    fits : sequence of xarray.DataTree
        Fits written by :func:`pmabayes.inference.sampler.fit` (same data, different models).
    dataset : Dataset or sequence of Dataset
        The data they were made from (checked against each fit): one data set, or
        one per experiment in the fits' order.
    labels : sequence of str, optional
        Names of the fits; ``base + effect + ...`` from their models by default.
    sources : sequence of str, optional
        Where each fit came from (file names), to name them in errors.

    Returns
    -------
    FitComparison

    Raises
    ------
    ValueError
        With fewer than two fits, labels that do not match, a fit made from other
        data, or fits of different experiments (:class:`pmabayes.data.DataError`,
        naming the fits and the files).
    """
    fits = list(fits)
    if len(fits) < 2:
        raise ValueError("compare needs at least two fits of the same data")
    sources = list(sources) if sources is not None else [f"fit {i + 1}" for i in range(len(fits))]
    datasets = [dataset] if isinstance(dataset, Dataset) else list(dataset)
    exps = [[e["name"] for e in (fit_info(t).get("experiments") or [{"name": None}])]
            for t in fits]
    for src, names in zip(sources, exps, strict=True):
        # one experiment each: the data check below decides (its name is only a file stem)
        if len(names) != len(exps[0]) or (len(names) > 1 and names != exps[0]):
            raise DataError(
                f"{src} is a fit of {len(names)} experiment(s) {names}, but {sources[0]} of "
                f"{len(exps[0])} {exps[0]}; compare takes fits of the same experiments, in "
                "the same order: refit one of them with the other's data files")
    if labels is None:
        labels = [" + ".join(["base", *model_from_fit(t).effect_names]) for t in fits]
    labels = list(labels)
    if len(labels) != len(fits) or len(set(labels)) != len(labels):
        raise ValueError(f"need {len(fits)} distinct labels, got {labels}")
    if len(exps[0]) == 1:
        if len(datasets) != 1:
            raise DataError(f"the fits are of one data set, but {len(datasets)} were given: "
                            "give the one they were made from")
        return _compare_one(fits, labels, datasets[0], [model_from_fit(t) for t in fits])
    if len(datasets) != len(exps[0]):
        raise DataError(
            f"the fits are of {len(exps[0])} experiments ({', '.join(exps[0])}) but "
            f"{len(datasets)} data set(s) were given: give one per experiment, in that order")
    per = {}
    models = [experiment_models(t) for t in fits]
    for e, name in enumerate(exps[0]):
        for src, tree in zip(sources, fits, strict=True):
            _check_experiment(tree, e, datasets[e], src)
        per[name] = _compare_one(fits, labels, datasets[e], [m[e] for m in models],
                                 experiment=e, loo=False)
    elpd, steps = _loo_table(fits, labels)
    per = {n: FitComparison(**{**c.__dict__, "elpd": elpd, "elpd_steps": steps})
           for n, c in per.items()}
    return FitComparison(labels=labels, bands={}, whiteness={}, innovations={}, elpd=elpd,
                         elpd_steps=steps, command_rate=np.zeros(0), dt_s=math.nan,
                         experiments=per)


def _compare_one(fits: list, labels: list, dataset: Dataset, models: list, *,
                 experiment: int | None = None, loo: bool = True) -> FitComparison:
    """The comparison on one data set: one experiment's part of each fit, or the fit."""
    bands, white, innov = {}, {}, {}
    for label, tree, model in zip(labels, fits, models, strict=True):
        if experiment is None:
            check_dataset(tree, dataset)
        bands[label], white[label], innov[label] = _map_residual(tree, model, dataset,
                                                                 experiment)
    elpd, steps = _loo_table(fits, labels) if loo else ({}, [])
    return FitComparison(labels=labels, bands=bands, whiteness=white, innovations=innov,
                         elpd=elpd, elpd_steps=steps,
                         command_rate=np.gradient(dataset.input[0], dataset.time_s),
                         dt_s=dataset.dt_s)


def _check_experiment(tree, e: int, dataset: Dataset, src: str) -> None:
    """That ``dataset`` is experiment ``e`` of a fit of several (trials, times, positions)."""
    stored = experiment_datasets(tree)[e]
    name = fit_info(tree)["experiments"][e]["name"]
    where = (f"{dataset.source or '(no source)'} does not match experiment {name} of {src} "
             f"(made from {stored.source})")
    if stored.position_m.shape != dataset.position_m.shape:
        raise DataError(f"{where}: position_m has shape {dataset.position_m.shape} (trials, "
                        f"samples), the fit's has {stored.position_m.shape}; give the data "
                        "files in the fit's experiment order")
    diff = float(np.max(np.abs(stored.position_m - dataset.position_m)))
    t_diff = float(np.max(np.abs(stored.time_s - dataset.time_s)))
    if not diff <= 1e-12 or not t_diff <= 1e-12 * max(1.0, float(np.max(np.abs(stored.time_s)))):
        raise DataError(f"{where}: positions differ by up to {diff:.3g} m and times by up to "
                        f"{t_diff:.3g} s; give the data files in the fit's experiment order")


def _map_residual(tree, model: Model, dataset: Dataset, experiment: int | None = None):
    """Band errors, whiteness and whitened residual of a fit's MAP model (on one
    experiment of a fit of several)."""
    info = fit_info(tree)
    substeps = int(info.get("substeps", 1))
    lik = Likelihood(model, dataset, substeps=substeps)
    vals = _model_values(model, info["map"]["values"])
    x = simulate_dataset(model, vals, dataset, substeps=substeps)[0]
    nz = (info["noise"] if experiment is None
          else info["experiments"][experiment]["noise_estimate"])
    noise = NoiseEstimate(nz["sigma_noise_m"], nz["rho_noise"], nz["sigma_white_m"], None, None)
    e, white, _ = judged_whiteness(lik, x, noise)  # AR(1) + white unless the repeats reject it
    return band_errors(dataset, x), white, e


def _loo_table(fits: list, labels: list) -> tuple[dict, list]:
    """Leave-one-trial-out ELPD of each fit against the best, and of each step."""
    import arviz as az

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the largest Pareto k is kept in the table
        loos = {label: az.loo(tree, var_name="position_m")
                for label, tree in zip(labels, fits, strict=True)}
    elpd_i = {label: np.asarray(loos[label].elpd_i).reshape(-1) for label in labels}
    best = max(labels, key=lambda k: float(loos[k].elpd))
    order = sorted(labels, key=lambda k: -float(loos[k].elpd))
    elpd = {}
    for label in labels:
        d = elpd_i[label] - elpd_i[best]
        elpd[label] = {"elpd": float(loos[label].elpd), "se": float(loos[label].se),
                       "elpd_diff": float(d.sum()), "dse": float(math.sqrt(d.size * np.var(d))),
                       "rank": order.index(label),
                       "max_pareto_k": float(np.max(np.asarray(loos[label].pareto_k)))}
    steps = []
    for a, b in zip(labels[:-1], labels[1:], strict=True):
        d = elpd_i[b] - elpd_i[a]
        steps.append({"from": a, "to": b, "elpd_diff": float(d.sum()),
                      "se": float(math.sqrt(d.size * np.var(d)))})
    return elpd, steps
