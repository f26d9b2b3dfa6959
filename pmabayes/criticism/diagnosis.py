"""The diagnosis: fit, criticise, rank, refit the candidates, explain.

:func:`diagnose` confronts a model with repeated trials in a short sequence of steps:
the shared MAP and each experiment's residual signature (:mod:`~pmabayes.criticism.refits`,
:mod:`~pmabayes.criticism.signature`), the score test of every candidate effect
(:mod:`~pmabayes.criticism.scores`), refits of the significant ones judged by the residual
they remove and by their leave-one-trial-out ELPD, the verdict in words
(:mod:`~pmabayes.criticism.prose`), and, when nothing in the library accounts for the
misfit, the missing force estimated from the data (:mod:`~pmabayes.criticism.discrepancy`).
Its settings are a :class:`~pmabayes.criticism.settings.DiagnoseSettings`; its result a
:class:`~pmabayes.criticism.results.Diagnosis`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from pmabayes.criticism.bands import input_bands
from pmabayes.criticism.baselines import fit_baselines, nrmse, yardstick_text
from pmabayes.criticism.discrepancy import Discrepancy, estimate_discrepancy
from pmabayes.criticism.experiments import (
    agreement_change,
    experiment_conditions_table,
    moving_parameters,
    trend_text,
)
from pmabayes.criticism.observed import observed_mean
from pmabayes.criticism.plausibility import implausible
from pmabayes.criticism.prose import (
    contribution_text,
    describe_signatures,
    explanation_text,
    paragraphs,
    transfer_words,
    verdict_text,
)
from pmabayes.criticism.refits import (
    BaseFit,
    fit_base,
    missing_effect,
    near_twins,
    partial_effect,
    ranking_key,
    refit_significant,
)
from pmabayes.criticism.results import Diagnosis, ExperimentDiagnosis, Finding
from pmabayes.criticism.scores import compile_candidates, rank_effects
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.data import Dataset
from pmabayes.inference.posterior import choose_substeps, data_scaled_priors
from pmabayes.inference.posterior import experiments as checked_experiments
from pmabayes.model.effects import get_effect
from pmabayes.model.linearise import LinearisationError
from pmabayes.model.model import Model
from pmabayes.outputs import check_folder_for_new_files
from pmabayes.util import Progress, show_progress

__all__ = ["diagnose"]


def _findings(ranked: list, refits: dict, base: BaseFit, ci_prob: float) -> list[Finding]:
    """Every candidate with its estimate and explanation; the refitted ones first, by ELPD."""
    residuals = base.residuals
    describe = describe_signatures(base.signatures, base.names)
    edges = np.cumsum([0, *(r.size for r in residuals)])
    datasets = [lik.dataset for lik in base.likelihoods]
    findings = []
    for ev in ranked:
        eff = get_effect(ev.effect)
        refit = refits.get(ev.effect)
        if ev.left_out is not None:
            findings.append(Finding(
                effect=ev.effect, evidence=ev.statistic, p_value=ev.p_value, significant=False,
                estimate={}, interval={}, explained=0.0, refit=None, left_out=ev.left_out,
                explanation=(f"{eff.name} ({eff.stage} stage): "
                             f"{' '.join(eff.description.split())} Left out of the score "
                             f"tests: it {ev.left_out}.")))
            continue
        if refit is not None:
            estimate = {k: refit.values[k] for k in refit.interval}
            interval, explained = refit.interval, refit.explained
            texts = []
            for e, lik in enumerate(base.likelihoods):
                part = contribution_text(refit.contribution_m[edges[e]:edges[e + 1]],
                                         residuals[e], lik.dataset.dt_s,
                                         input_bands(lik.dataset))
                texts.append(part if len(residuals) == 1 or not part
                             else f" In {base.names[e]}:{part}")
            contrib = "".join(texts)
        else:
            estimate, interval, explained, contrib = ev.estimate, ev.interval, ev.explained, ""
        odd = (refit.implausible if refit is not None else
               implausible(base.likelihoods[0].model.with_effects(ev.effect), estimate,
                           list(estimate), datasets))
        text = explanation_text(eff, ev.statistic, ev.p_value, ev.significant, describe, refit,
                                contrib, ci_prob, base.names)
        findings.append(Finding(
            effect=ev.effect, evidence=ev.statistic, p_value=ev.p_value,
            significant=ev.significant, estimate=estimate, interval=interval,
            explained=explained, refit=refit, implausible=odd,
            explanation=text + (f" Implausible, not a finding: {odd}." if odd else ""),
        ))
    # refitted candidates first, by how well they predict left-out data (ranking_key, the
    # order the verdict and the missing effect use too); those left out of the score tests
    # last
    findings.sort(key=lambda f: (f.left_out is not None, f.refit is None,
                                 *(ranking_key(f.refit) if f.refit else
                                   (False, 0.0 if f.left_out is not None else -f.evidence))))
    return findings


def _experiments(datasets, model: Model | None, effects: Iterable[str]
                 ) -> tuple[list[Dataset], list[Model], list[str]]:
    """The data sets, each one's model (on its rig) and the experiments' names."""
    dss, models, names = checked_experiments(datasets, model or Model())
    if model is None:
        models = [Model.for_dataset(ds) for ds in dss]
    effects = list(effects)
    if effects:
        models = [m.with_effects(*[e for e in effects if e not in m.effect_names])
                  for m in models]
    # a force-input rig's default priors on its data's scale, as the fit's: the muscle's
    # left the RC column chiu (185 kN, 1360 kg) with no finite simulation
    models = [data_scaled_priors(m, dss)[0] for m in models]
    return dss, models, names


def diagnose(
    datasets: Dataset | Sequence[Dataset],
    model: Model | None = None,
    *,
    effects: Iterable[str] = (),
    settings: DiagnoseSettings | None = None,
    seed: int | np.random.Generator = 0,
    progress: bool = False,
    plugin_dir: str | Path | None | bool = None,
) -> Diagnosis:
    """Fit a model, criticise it and find which effect in the library is missing.

    1. The noise comes from the spread between trials and the model's MAP from
       the trial mean (:func:`pmabayes.inference.search.find_map`).
    2. The residual's signature: errors per frequency band against the noise
       floor, whiteness of the residual whitened by the noise model, its
       correlation with the model's states and with the command's rate.
    3. Every candidate effect is ranked by the score test
       (:func:`~pmabayes.criticism.scores.rank_effects`), which needs no refit.
    4. The significant candidates (``settings.max_refits`` of them, strongest first;
       the next as many where none of those is named) are added one at a time and
       refitted, in worker processes; each refit is judged by the excess
       residual it removes and by its leave-one-trial-out ELPD (PSIS-LOO over
       draws from the refit's Laplace approximation). The refit also gives the
       effect's size with an interval. This separates effects that the first-order
       score test cannot (a regulator lag and a transport delay).
    5. The missing effect is the refitted candidate with the best ELPD among
       those that account for the misfit and predict left-out trials better than
       the diagnosed model by more than two standard errors of the ELPD
       difference (a refit whose search failed, ending below the model it holds,
       or with implausible estimates, never qualifies). Accounting for the misfit
       means: the refit is adequate, or it removes at least
       ``settings.min_explained`` of the excess residual alone or together with the
       candidate that the refit's own score test finds next (so that two missing
       effects of similar size are found one after the other). It needs a noise
       floor in every experiment: without one the shares and the adequacy are
       under noise identified with each model and say nothing of the misfit. When
       none qualifies but a refit predicts held-out data better by more than two
       standard errors, the best such refit is the diagnosis' ``partial`` step: the
       verdict says that it helps in part and to add it and diagnose again. If
       none does, nothing is named: a misfit above the floor is reported as
       unexplained instead of naming the least bad candidate. When
       another qualifying refit's ELPD is within two standard errors of the
       named one's (paired over the trials), the verdict says that the two cannot
       be told apart by these data (near twins, such as a regulator lag and a
       well-damped second-order regulator).
    6. Then, with ``settings.discrepancy``, the missing force is estimated from the data
       (:func:`pmabayes.criticism.discrepancy.estimate_discrepancy`): the states it
       depends on, with their evidence, and a closed form written as a ready user effect
       (a ``.py`` file for ``--plugin``, kept in ``plugin_dir`` when one is given).

    Several experiments (a sequence of data sets, each with its own input, rig
    and trials, as :func:`pmabayes.inference.sampler.fit` takes them) are diagnosed
    together: one MAP of the shared physical parameters, each experiment on its own rig
    with its own noise; a signature and an adequacy verdict per experiment (the
    model is adequate only if it is in every one); the score test with the
    experiments' scores and informations summed; the candidates refitted over
    all of them; the ELPD leaving out one trial at a time of all of them. The
    verdict names the experiments whose residual shows the misfit.

    Repeats: an experiment's noise comes from its trials, or from the periods of
    a single periodic record (``period_samples``), whose spread also gives its
    noise floor. A single record without either has no floor; its noise is
    identified with the model (with the bound of
    :meth:`pmabayes.inference.likelihood.Likelihood.noise_parameters`), and the
    verdict says that it is judged by its whitened residual alone, and, where its
    disturbance is slow, that one record cannot tell it from slow missing physics. Its
    ELPD leaves out one of ten contiguous stretches of the record at a time, given the
    rest (:meth:`~pmabayes.inference.likelihood.Likelihood.stretch_pointwise`), so that
    a refit's ΔELPD has a standard error.

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
    settings : DiagnoseSettings, optional
        Levels, thresholds, refits, draws, substeps, candidates, noise model and
        whether to estimate the discrepancy; the defaults of
        :class:`~pmabayes.criticism.settings.DiagnoseSettings` when not given.
    seed : int or numpy.random.Generator
        Seeds the global searches and the draws.
    progress : bool
        Print what is being done to stderr, every stage's progress included
        (:func:`pmabayes.util.show_progress`).
    plugin_dir : str or Path or False, optional
        The folder where the proposed effect's ``.py`` file is kept (created if
        missing; a file there is never overwritten: a numbered name is chosen). It is
        checked before any work (:func:`pmabayes.outputs.check_folder_for_new_files`).
        None or False (the default): the file is checked in a temporary folder and not
        kept; nothing is written anywhere else.

    Returns
    -------
    Diagnosis

    Raises
    ------
    TypeError
        If ``settings`` is not a :class:`~pmabayes.criticism.settings.DiagnoseSettings`.
    ValueError
        On no data, or experiments of different input kinds
        (:class:`pmabayes.data.DataError`, naming the files).
    pmabayes.outputs.OutputError
        If ``plugin_dir`` is a file or cannot be written in (before any work).

    Examples
    --------
    Diagnose the base model on four trials of a file (the others held out) and add
    what it names (about 30 s):

    >>> import pmabayes
    >>> from pmabayes.data import load
    >>> from pmabayes.inference.trials import exclude_trials
    >>> data = exclude_trials(load("muscle_a.csv"), [5, 6])  # doctest: +SKIP
    >>> d = pmabayes.diagnose(data)  # doctest: +SKIP
    >>> d.adequate, d.missing  # doctest: +SKIP
    (False, 'regulator_lag')
    >>> pmabayes.diagnose(data, effects=[d.missing]).adequate  # doctest: +SKIP
    True

    ``d.verdict`` says it in paragraphs, the conclusion and its next command first;
    ``d.ranking`` holds every candidate.
    """
    if plugin_dir is not None and plugin_dir is not False:
        check_folder_for_new_files(plugin_dir, "plugin_dir")
    with show_progress("diagnose", progress):
        return _diagnose(datasets, model, effects, _checked(settings), seed, plugin_dir)


def _diagnose(datasets, model: Model | None, effects: Iterable[str], s: DiagnoseSettings,
              seed, plugin_dir) -> Diagnosis:
    """:func:`diagnose`, its arguments checked and its progress switched."""
    say = Progress("diagnose")
    rng = np.random.default_rng(seed)
    datasets, models, names = _experiments(datasets, model, effects)
    if s.substeps == "auto":  # as fit does: the fewest substeps that are accurate
        s = dataclasses.replace(s, substeps=choose_substeps(models, datasets)["chosen"])
    label = " + ".join(["base", *models[0].effect_names])
    where = " and ".join(str(ds.source or "the data") for ds in datasets)
    say.say(f"fitting {label} to {where} (MAP)")
    compiling = compile_candidates(models, datasets, s.substeps, s.candidates)
    try:
        base = fit_base(models, datasets, names, s, rng)
        say.say("ranking the candidate effects (score test)")
        ranked = rank_effects(base.likelihoods, base.noises, [own for own, _ in base.points],
                              candidates=s.candidates, level=s.level,
                              starts=[start for _, start in base.points])
    finally:
        if compiling is not None:
            compiling.terminate()
    refits = refit_significant(base, ranked, s, rng, say)
    findings = _findings(ranked, refits, base, s.ci_prob)
    say.say("fitting the yardsticks (linear output-error, Prandtl-Ishlinskii)")
    experiments = _experiment_diagnoses(base, s, _yardsticks(base))
    adequate = all(e.adequate for e in experiments)
    missing = missing_effect(refits, s)
    partial = None if adequate else partial_effect(refits, missing)
    verdict = verdict_text(label, models[0].effect_names, experiments, adequate, missing,
                           refits, findings, s.min_explained, near_twins(refits, missing, s),
                           partial, data=" ".join(str(ds.source or "DATA.csv")
                                                  for ds in datasets))
    found, found_in, words = None, None, ""
    if s.discrepancy and not adequate and missing is None:
        found, found_in, words = _discrepancy_step(base, experiments, plugin_dir, say)
    agreement = _agreement(base, refits)
    verdict = paragraphs(verdict, transfer_words(refits, missing or partial), words,
                         _yardstick_words(experiments), agreement_words(agreement))
    say.say("diagnosis done: " + ("adequate" if adequate else f"{missing} is missing"
                                  if missing else f"{partial} helps in part" if partial
                                  else "not adequate"))
    return Diagnosis(
        experiments=experiments, values=base.values, adequate=adequate, missing=missing,
        ranking=findings, elpd=base.elpd, verdict=verdict,
        settings=_record(s, seed, findings, base), discrepancy=found,
        discrepancy_experiment=found_in, partial=partial, agreement=agreement,
        elpd_note=base.loo.note if base.loo is not None else None,
    )


def _agreement(base: BaseFit, refits: dict) -> dict | None:
    """Experiments that disagree as evidence: the test, each one's own estimates, the
    parameters that move with the declared conditions, and each candidate's test."""
    if base.agreement is None:
        return None
    conditions = experiment_conditions_table([lik.dataset for lik in base.likelihoods])
    moving = moving_parameters(base.agreement, conditions)
    return {**{k: base.agreement[k] for k in ("agree", "statistic", "df", "p_value", "level")},
            "experiments": {n: e.get("values_own", {})
                            for n, e in base.agreement["experiments"].items()},
            "conditions": conditions, "moving": moving, "trend": trend_text(moving),
            "candidates": agreement_change(base.agreement, list(refits.values()))}


def agreement_words(agreement: dict | None) -> str:
    """The verdict's sentences on experiments that disagree: what moves between them,
    with what, and which candidate makes them agree (or that none does).

    Parameters
    ----------
    agreement : dict or None
        :class:`~pmabayes.criticism.results.Diagnosis`'s ``agreement``.

    Returns
    -------
    str
        Empty where the experiments agree or there is one.
    """
    if not agreement or agreement.get("agree") is not False:
        return ""
    words = (f" The experiments disagree: one parameter set does not fit them all "
             f"(likelihood ratio {agreement['statistic']:.4g} on {agreement['df']} degrees of "
             f"freedom, p = {agreement['p_value']:.2g}); the report shows each one's own "
             "estimates side by side.")
    if agreement["trend"]:
        words += f" Between them {agreement['trend']}."
    elif agreement["moving"]:
        words += " No parameter moves in step with a declared condition (declare the "\
                 "experiments' conditions in their sidecars, \"conditions\": {\"load_kg\": ...})."
    agreeing = [c for c in agreement["candidates"] if c["agree"]]
    if agreeing:
        c = agreeing[0]
        words += (f" With {c['effect']} they agree (likelihood ratio {c['statistic'][0]:.4g} "
                  f"-> {c['statistic'][1]:.4g}, p = {c['p_value']:.2g}).")
    elif agreement["candidates"]:
        best = agreement["candidates"][0]
        words += (" No refitted candidate makes them agree (the closest, "
                  f"{best['effect']}: likelihood ratio {best['statistic'][0]:.4g} -> "
                  f"{best['statistic'][1]:.4g}): the model lacks what differs between "
                  "them.")
    return words


def _checked(settings: DiagnoseSettings | None) -> DiagnoseSettings:
    if settings is None:
        return DiagnoseSettings()
    if not isinstance(settings, DiagnoseSettings):
        raise TypeError(f"settings must be a DiagnoseSettings, got {type(settings).__name__}: "
                        "make one with DiagnoseSettings(level=..., ...)")
    return settings


def _experiment_diagnoses(base: BaseFit, s: DiagnoseSettings, yardsticks: list) -> tuple:
    """Each experiment's data, model, noise, simulation, signature, adequacy and
    yardsticks."""
    return tuple(
        ExperimentDiagnosis(name=n, dataset=lik.dataset, model=lik.model, noise=noise,
                            noise_source=lik.noise_source, simulation=sim, signature=sig,
                            adequate=s.is_adequate(sig), baselines=yard)
        for n, lik, noise, sim, sig, yard in zip(base.names, base.likelihoods, base.noises,
                                                 base.simulations, base.signatures, yardsticks,
                                                 strict=True))


def _yardsticks(base: BaseFit) -> list[dict]:
    """The yardsticks fitted to the diagnosis' data, each experiment's in-sample errors
    (empty where they could not be fitted): diagnose has no held-out data, so the physics
    is compared with them on the record both were fitted to."""
    datasets = [lik.dataset for lik in base.likelihoods]
    try:
        fitted = fit_baselines(datasets)
    except ValueError:
        return [{} for _ in datasets]
    return [fitted.scores(ds) for ds in datasets]


def _yardstick_words(experiments: tuple) -> str:
    """The verdict's sentence when the fitted model does not beat a yardstick on the
    training record (in-sample, as both were fitted to it)."""
    words = ""
    for e in experiments:
        if not e.baselines:
            continue
        rmse, normalised = nrmse(observed_mean(e.dataset), e.simulation.position_m[0])
        where = "on the training record" + (f" {e.name}" if len(experiments) > 1 else "")
        text = yardstick_text({"rmse_m": rmse, "nrmse": normalised}, e.baselines,
                              metric="rmse_m", where=where + " (in-sample, as both were fitted "
                              "to it)")
        words += f" {text}" if text else ""
    return words


def _discrepancy_step(base: BaseFit, experiments: tuple, plugin_dir, say: Progress
                      ) -> tuple[Discrepancy | None, str | None, str]:
    """The missing force estimated from the data: the discrepancy, the experiment it was
    estimated on, and what it adds to the verdict."""
    # the missing force is estimated on one experiment: with several, the one whose
    # residual is furthest above its floor (the others are named in the command that
    # checks the proposal on all of them). Its evidence leaves out one trial at a time,
    # or, on a record without repeats, one stretch of it under the noise identified with
    # the model.
    k = _worst_experiment(base.signatures, [e.adequate for e in experiments],
                          range(len(base.likelihoods)))
    several = len(experiments) > 1
    say.say(f"estimating the missing force from {base.names[k]} (discrepancy; the experiment "
            "furthest above its floor)" if several else
            "estimating the missing force from the data (discrepancy)")
    try:
        found = estimate_discrepancy(
            base.likelihoods[k], base.noises[k], base.points[k][0], base.simulations[k],
            plugin_dir=plugin_dir,
            command=" ".join(str(e.dataset.source or "DATA") for e in experiments),
            effects=experiments[0].model.effect_names, start=base.points[k][1])
    except LinearisationError as exc:
        say.say(f"discrepancy step skipped: {exc}")
        return None, None, f" The missing force was not estimated from the data: {exc}."
    words = (f" The missing force was estimated from {base.names[k]}, the experiment furthest "
             "above its floor; the command below checks the proposal on all of them."
             if several else "")
    return found, base.names[k], words + " " + found.text


def _record(s: DiagnoseSettings, seed, findings: list, base: BaseFit) -> dict:
    """The settings as used: the seed, the candidates tested, and each experiment's noise
    model (None where the noise was identified with the model)."""
    return {**s.to_dict(), "seed": seed if isinstance(seed, int) else None,
            "candidates": [f.effect for f in findings],
            "noise_model": [lik.noise_model_name if noise is not None else None
                            for lik, noise in zip(base.likelihoods, base.repeat_noise,
                                                  strict=True)]}


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
