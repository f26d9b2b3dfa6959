"""What a diagnosis finds, and its JSON: the refits (:class:`Refit`), the candidates
(:class:`Finding`), each experiment (:class:`ExperimentDiagnosis`) and the whole
(:class:`Diagnosis`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.criticism.bands import (
    instantaneous_frequency,
)
from pmabayes.criticism.discrepancy import Discrepancy
from pmabayes.criticism.observed import observed_mean, shared_input
from pmabayes.criticism.refit import Refit
from pmabayes.criticism.scores import significance_threshold
from pmabayes.criticism.signature import Signature
from pmabayes.criticism.whiteness import (
    WhitenessCurves,
    innovations,
    whiteness_curves,
)
from pmabayes.data import Dataset
from pmabayes.inference.likelihood import Likelihood, slow_disturbance_note
from pmabayes.inference.noise import NoiseEstimate
from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation
from pmabayes.util import finite_or_none

__all__ = ["Refit", "Finding", "ExperimentDiagnosis", "Diagnosis"]


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
    left_out : str or None
        Why it was left out of the score tests (``"cannot act on these data: ..."``);
        then ``evidence`` and ``p_value`` are NaN. None when it was tested.
    implausible : str or None
        Why its estimates are not physics (outside their plausible range; a refit's on
        a bound): an implausible estimate is not a finding. None when plausible.
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
    left_out: str | None = None
    implausible: str | None = None

    def to_dict(self) -> dict:
        """JSON-ready summary (an entry of a diagnosis' ``ranking``).

        Returns
        -------
        dict
            ``effect``, ``evidence``, ``p_value`` (None when left out), ``significant``,
            ``estimate``, ``interval``, ``explained`` (whitened residual energy),
            ``explained_rms`` (mean square above the floor, for a refit with one; else
            None), ``explanation``, ``left_out``, ``implausible`` and ``refit``
            (:meth:`Refit.to_dict`, or None).
        """
        return {
            "effect": self.effect, "evidence": finite_or_none(self.evidence),
            "p_value": finite_or_none(self.p_value),
            "significant": self.significant, "estimate": dict(self.estimate),
            "interval": {k: [float(a), float(b)] for k, (a, b) in self.interval.items()},
            "explained": self.explained,
            "explained_rms": None if self.refit is None else self.refit.explained_rms,
            "explanation": self.explanation,
            "left_out": self.left_out, "implausible": self.implausible,
            "refit": None if self.refit is None else self.refit.to_dict(),
        }


@dataclass(frozen=True)
class ExperimentDiagnosis:
    """One experiment of a diagnosis: its data, its model's fit there, and its verdict.

    Parameters
    ----------
    name : str
        The experiment's name (its file's stem,
        :func:`pmabayes.inference.fitfile.experiment_names`).
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
    baselines : dict
        The yardsticks fitted to the diagnosis' data, on this experiment
        (:meth:`pmabayes.criticism.baselines.Baselines.scores`): ``"linear"``,
        ``"play"`` and ``"narx"`` (those fitted), each with its in-sample ``rmse_m`` and
        ``nrmse``; empty when they could not be fitted.
    """

    name: str
    dataset: Dataset
    model: Model
    noise: NoiseEstimate
    noise_source: str
    simulation: Simulation
    signature: Signature
    adequate: bool
    baselines: dict = field(default_factory=dict)

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
        """Trial mean minus model, ``(n_samples,)`` (NaN where no trial is counted)."""
        return observed_mean(self.dataset) - self.simulation.position_m[0]

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
        rate = np.gradient(shared_input(self.dataset), self.dataset.time_s)
        return whiteness_curves({label: self.innovations}, rate, self.dataset.dt_s)

    def floor_note(self) -> str:
        """Why there is no noise floor, or an empty string when there is one."""
        if math.isfinite(self.noise_floor_m):
            return ""
        text = (f"{self.dataset.source or self.name} is a single record without repeats (no "
                "second trial, no declared periods), so it has no noise floor: its error is "
                "judged by the whiteness of its residual under the noise identified with the "
                "model")
        slow = slow_disturbance_note(Likelihood(self.model, self.dataset), self.noise.rho)
        return text + (f"; and {slow}" if slow else "")

    def to_dict(self) -> dict:
        """JSON-ready summary of this experiment (an entry of a diagnosis' ``experiments``).

        Returns
        -------
        dict
            ``name``, ``data`` (its source), ``synthetic``, ``rig``, ``n_trials``,
            ``n_samples``, ``noise_source``, ``noise`` (``sigma_noise_m``,
            ``rho_noise``, ``sigma_white_m``), ``rms_m``, ``noise_floor_m`` and
            ``ratio`` (None without repeats), ``adequate``, ``floor_note`` (None with
            a floor), ``whiteness`` (``ljung_box_p``, ``energy``, ``energy_p``),
            ``signature`` (:meth:`~pmabayes.criticism.signature.Signature.describe`),
            ``bands`` (one :meth:`~pmabayes.criticism.bands.BandErrors.to_dict`
            each, the last overall) and ``baselines`` (the yardsticks' in-sample
            errors here, beside the model's ``rms_m``).
        """
        sig = self.signature
        return {
            "name": self.name, "data": self.dataset.source,
            "synthetic": bool(self.dataset.metadata.get("synthetic", False)),
            "rig": self.model.rig.to_dict(), "n_trials": int(self.dataset.n_trials),
            "n_samples": int(self.dataset.n_samples), "noise_source": self.noise_source,
            "noise": {"sigma_noise_m": float(self.noise.sigma),
                      "rho_noise": float(self.noise.rho),
                      "sigma_white_m": float(self.noise.white)},
            "rms_m": self.rms_m, "noise_floor_m": finite_or_none(self.noise_floor_m),
            "ratio": finite_or_none(sig.ratio), "adequate": self.adequate,
            "floor_note": self.floor_note() or None,
            "whiteness": {"ljung_box_p": sig.ljung_box_p, "energy": sig.energy,
                          "energy_p": sig.energy_p},
            "signature": sig.describe(),
            "bands": [b.to_dict() for b in sig.bands],
            "baselines": {n: {k: finite_or_none(v) if isinstance(v, float) else v
                              for k, v in b.items()} for n, b in self.baselines.items()},
        }


@dataclass(frozen=True)
class Diagnosis:
    """A model confronted with repeated trials: how good, where it fails, what is missing.

    Parameters
    ----------
    experiments : tuple of ExperimentDiagnosis
        Each experiment's data, model on its rig, noise, simulation, signature and
        verdict, in the given order (one entry for one data set).
    values : dict
        The model's MAP, with the noise parameters (with several experiments, each
        noise parameter maps the experiments' names to their values).
    adequate : bool
        The whitened residual is consistent with the noise in every experiment:
        its mean square is within ``1 + energy_tolerance`` of pure noise and its
        autocorrelation is not significant (Ljung-Box at ``level_adequate``).
    missing : str or None
        The effect found missing: the refitted significant candidate with the best
        ELPD among those that account for the misfit and improve the ELPD by more
        than two standard errors (see :func:`pmabayes.criticism.diagnosis.diagnose`).
        None when nothing significant is missing, or when no candidate explains the
        misfit (see ``verdict``, which also says when another candidate cannot be
        told apart from it).
    ranking : list of Finding
        Every candidate, most evidence first: the refitted ones by ELPD, then the
        others by score statistic.
    elpd : float
        Leave-one-trial-out ELPD of the model (PSIS-LOO over Laplace draws), over
        every trial of every experiment (a single record's: one of its stretches at a
        time, :func:`pmabayes.criticism.elpd.laplace_loo`).
    verdict : str
        The conclusion in words; with several experiments it names those whose
        residual shows the misfit.
    settings : dict
        The settings used (:meth:`pmabayes.criticism.settings.DiagnoseSettings.to_dict`
        with the seed, the candidates tested and each experiment's noise model).
    discrepancy : Discrepancy or None
        The missing force estimated from the data, when the model is above the floor
        and no candidate in the library accounts for it (see
        :func:`pmabayes.criticism.discrepancy.estimate_discrepancy`); None otherwise.
        It is estimated on one experiment.
    discrepancy_experiment : str or None
        The experiment the discrepancy was estimated on (the inadequate one furthest
        above its floor); None without a discrepancy.
    partial : str or None
        When nothing is named ``missing``: the best partial step, the top-ranked refit
        that predicts held-out data clearly better (ΔELPD above two standard errors)
        without accounting for all of the misfit, or, on a record without a noise floor,
        without a way to tell whether it does
        (:func:`pmabayes.criticism.refits.partial_effect`); the verdict says to add it
        and diagnose again. None otherwise.
    agreement : dict or None
        With several experiments: whether they agree on one parameter set (the
        likelihood-ratio test's ``agree``, ``statistic``, ``df``, ``p_value``), each
        one's own estimates (``experiments``), the declared ``conditions`` that
        differ, the parameters that ``moving`` between them and the ``trend`` in
        words (:mod:`pmabayes.criticism.experiments`), and each refitted candidate's
        test (``candidates``). None for one experiment.
    elpd_note : str or None
        Why ``elpd`` is not a reliable estimate (the Pareto k-hats of its draws'
        importance weights, a Laplace covariance that is a stand-in:
        :class:`pmabayes.criticism.elpd.LaplaceLoo`); None when it is.
    """

    experiments: tuple
    values: dict
    adequate: bool
    missing: str | None
    ranking: list
    elpd: float
    verdict: str
    settings: dict
    discrepancy: Discrepancy | None = None
    discrepancy_experiment: str | None = None
    partial: str | None = None
    agreement: dict | None = None
    elpd_note: str | None = None

    @property
    def effects(self) -> tuple[str, ...]:
        """The diagnosed model's effects (the same in every experiment)."""
        return self.experiments[0].model.effect_names

    @property
    def rms_m(self) -> float:
        """RMS error of the trial mean at the MAP (pooled over all samples of all experiments)."""
        return pooled_rms([e.rms_m for e in self.experiments],
                          [e.dataset.n_samples for e in self.experiments])

    @property
    def noise_floor_m(self) -> float:
        """RMS error a perfect model would have (from the spread between trials; pooled
        over the experiments, NaN when one of them has no repeats)."""
        return pooled_rms([e.noise_floor_m for e in self.experiments],
                          [e.dataset.n_samples for e in self.experiments])

    @property
    def misfit_experiments(self) -> list[str]:
        """Names of the experiments whose residual is not consistent with the noise."""
        return [e.name for e in self.experiments if not e.adequate]

    @property
    def score_threshold(self) -> float:
        """The score statistic above which a candidate is significant (1 dof; Bonferroni
        over the candidates tested, those left out not counted)."""
        return significance_threshold(self.settings["level"],
                                      sum(f.left_out is None for f in self.ranking))

    def to_dict(self) -> dict:
        """JSON-ready summary (``pmabayes diagnose --json``), one shape for any number of
        experiments.

        Returns
        -------
        dict
            ``data``
                The experiments' sources joined by `` + `` (a name where a data set
                has no source).
            ``synthetic``
                Whether every experiment is synthetic.
            ``effects``
                The diagnosed model's effects.
            ``rms_m``, ``noise_floor_m``
                Pooled over the experiments (the floor None when one has no
                repeats).
            ``adequate``, ``missing``, ``partial``, ``verdict``, ``elpd_loo``, ``elpd_loo_note``
                As the fields ``adequate``, ``missing``, ``partial``, ``verdict``,
                ``elpd``, ``elpd_note``.
            ``ranking``
                One :meth:`Finding.to_dict` per candidate.
            ``values``
                The MAP.
            ``settings``
                As the field.
            ``discrepancy``
                None, or :meth:`pmabayes.criticism.discrepancy.Discrepancy.to_dict`
                with one more key, ``experiment``, the one it was estimated on.
            ``experiments``
                One :meth:`ExperimentDiagnosis.to_dict` each: the name, data, rig,
                noise, error against the floor, whiteness, signature and bands.
            ``misfit_experiments``
                The names of those that are not adequate.
            ``agreement``
                As the field (None for one experiment).
        """
        exps = self.experiments
        return {
            "data": " + ".join(str(e.dataset.source or e.name) for e in exps),
            "synthetic": all(bool(e.dataset.metadata.get("synthetic", False)) for e in exps),
            "effects": list(self.effects),
            "rms_m": self.rms_m,
            "noise_floor_m": finite_or_none(self.noise_floor_m),
            "adequate": self.adequate,
            "missing": self.missing,
            "partial": self.partial,
            "verdict": self.verdict,
            "ranking": [f.to_dict() for f in self.ranking],
            "values": dict(self.values),
            "elpd_loo": finite_or_none(self.elpd),
            "elpd_loo_note": self.elpd_note,
            "settings": dict(self.settings),
            "discrepancy": (None if self.discrepancy is None else
                            {**self.discrepancy.to_dict(),
                             "experiment": self.discrepancy_experiment}),
            "experiments": [e.to_dict() for e in exps],
            "misfit_experiments": self.misfit_experiments,
            "agreement": self.agreement,
        }


def pooled_rms(rms: Sequence[float], sizes: Sequence[int]) -> float:
    """RMS over several series from each one's RMS and length.

    Parameters
    ----------
    rms : sequence of float
        Each series' RMS.
    sizes : sequence of int
        Each series' length.

    Returns
    -------
    float
        The RMS of all the samples together; one series' own RMS as it is, NaN if
        one is NaN.
    """
    if len(rms) == 1:
        return float(rms[0])
    total = sum(r * r * n for r, n in zip(rms, sizes, strict=True))
    return float(math.sqrt(total / sum(sizes)))
