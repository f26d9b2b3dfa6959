"""The next experiment: :func:`design` scores candidate experiments and chooses one.

For ``goal="discriminate"`` each candidate model (the base model and one candidate
effect) is fitted on the data so far (or given), candidate experiments are drawn from
the families of :mod:`pmabayes.design.experiments`, each is simulated for posterior
draws of every model in one batched call per model, and scored by the expected log
Bayes factor of the true model over the strongest other one
(:func:`pmabayes.design.score.discrimination`). For ``goal="parameters"`` the model with
every candidate is fitted, and the experiments are scored by how much they shrink the
named parameters' 90% intervals (:func:`pmabayes.design.score.shrinkage`).

Everything that can be refused is refused before the first fit, each in one line
(:class:`~pmabayes.design.experiments.DesignError`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.data import Dataset
from pmabayes.data.dataset import dataset_list
from pmabayes.design.experiments import (
    MIN_SAMPLES,
    DesignError,
    Experiment,
    candidate_experiments,
    dead_load_kg,
    input_range,
    loaded_mass_kg,
)
from pmabayes.design.fits import GOOD_K_HAT, CandidateFit, does_not_act, fit_candidate
from pmabayes.design.score import discrimination, shrinkage, whiten_rows
from pmabayes.model.effects import get_effect
from pmabayes.model.model import Model
from pmabayes.model.simulator import position_reference, simulate
from pmabayes.util import Progress

__all__ = ["design", "DesignResult", "GOALS", "model_names", "given_fits"]

#: what a design may aim at
GOALS = ("discriminate", "parameters")

#: the most floats a batched simulation holds at once (about 240 MB): the experiments
#: are simulated in chunks of this size
_CHUNK_FLOATS = 30_000_000

#: posterior draws whose sensitivities give the expected shrinkage (each costs one
#: simulation per identified parameter)
_FISHER_DRAWS = 8


@dataclass
class DesignResult:
    """The chosen experiment and the scores of every candidate.

    Parameters
    ----------
    goal : str
        ``"discriminate"`` or ``"parameters"``.
    candidates : list of str
        The candidate models scored (their effects; for ``"parameters"`` one model).
    left_out : dict
        Candidates not scored, each with the reason.
    experiments : list of Experiment
        The candidate experiments, in the order scored.
    scores : list of dict
        Per experiment: ``score`` and ``mc_se`` (and the goal's own numbers), or
        ``score`` NaN with ``failed`` saying why it could not be scored.
    chosen : int
        Index of the chosen experiment (the highest score).
    predictions : dict
        Each candidate's predicted response to the chosen input: ``map``, ``low`` and
        ``high`` (the 5% and 95% of its posterior draws), in m.
    settings : dict
        What the design was made with (seed, draws, trials, range, duration, loads,
        noise).
    fits : dict
        Each candidate's :class:`~pmabayes.design.fits.CandidateFit`, to give again.
    rig : dict
        The first data set's rig (its dead load included; an experiment's load replaces
        it: :func:`~pmabayes.design.experiments.loaded_mass_kg`).
    input_name : str
        ``pressure_pa`` or ``force_n``.
    units : dict
        The SI name of time and input to the column name of the user's files.
    seconds : float
        Wall time of the design.
    notes : list of str
        What the fits of the data so far say that makes the scores less than they seem
        (a poor fit, experiments that disagree, a stand-in Laplace covariance, a fit
        that did not converge), one line each.
    """

    goal: str
    candidates: list
    left_out: dict
    experiments: list
    scores: list
    chosen: int
    predictions: dict
    settings: dict
    fits: dict = field(repr=False, default_factory=dict)
    rig: dict = field(default_factory=dict)
    input_name: str = "pressure_pa"
    units: dict = field(default_factory=dict)
    seconds: float = math.nan
    notes: list = field(default_factory=list)

    @property
    def experiment(self) -> Experiment:
        """The chosen experiment."""
        return self.experiments[self.chosen]

    def score_of(self, family: str) -> dict | None:
        """The score of the first experiment of a family (``"repeat"``,
        ``"default_chirp"``), None where none was scored."""
        for e, s in zip(self.experiments, self.scores, strict=True):
            if e.family == family:
                return s
        return None

    def to_dict(self) -> dict:
        """The JSON summary (``design.json``, less its ``"pmabayes"`` mark)."""
        return {
            "goal": self.goal,
            "candidates": list(self.candidates),
            "left_out": dict(self.left_out),
            "chosen": {"index": self.chosen, **self.experiment.to_dict(),
                       **self.scores[self.chosen]},
            "repeat_first_input": self.score_of("repeat"),
            "default_chirp": self.score_of("default_chirp"),
            "experiments": [{"index": i, **e.to_dict(), **s}
                            for i, (e, s) in enumerate(zip(self.experiments, self.scores,
                                                           strict=True))],
            "rig": self.rig,
            "settings": self.settings,
            "notes": list(self.notes),
            "seconds": self.seconds,
        }

    def lines(self) -> list[str]:
        """The result in a few lines, for the command line."""
        s = self.scores[self.chosen]
        out = [f"chosen: {self.experiment.label()}"]
        out.append(f"  score {_score_text(self.goal, s)}")
        for family, what in (("repeat", "repeating the first input"),
                             ("default_chirp", "a default chirp over the input range")):
            other = self.score_of(family)
            if other is not None:
                out.append(f"  {what}: {_score_text(self.goal, other)}")
        for name, why in self.left_out.items():
            out.append(f"  left out {name}: {why}")
        out += [f"  note: {note}" for note in self.notes]
        return out


def _score_text(goal: str, s: dict) -> str:
    if not math.isfinite(s["score"]):
        return f"not scored: {s.get('failed', 'no finite score')}"
    if goal == "discriminate":
        decisive = s.get("named_decisively_rate")
        return (f"expected log Bayes factor {s['score']:.3g} +- {s['mc_se']:.2g} (MC se); "
                f"true model named {100 * s['named_rate']:.1f}% +- "
                f"{100 * s['named_rate_mc_se']:.1f}%"
                + ("" if decisive is None or not math.isfinite(decisive) else
                   f", beyond two standard errors (as diagnose names it) "
                   f"{100 * decisive:.1f}% +- {100 * s['named_decisively_mc_se']:.1f}%"))
    return (f"interval shrinkage x{s['factor']:.3g} (geometric mean; log {s['score']:.3g} "
            f"+- {s['mc_se']:.2g} MC se)")


def _checked_budget(first: Dataset, duration_s, n_experiments: int, n_draws: int
                    ) -> float:
    """The experiments' duration, refused where nothing could be scored."""
    duration = (first.n_samples * first.dt_s) if duration_s is None else float(duration_s)
    n = int(round(duration * first.sample_rate_hz)) if math.isfinite(duration) else 0
    if n < MIN_SAMPLES:
        raise DesignError(
            f"a duration budget of {duration:g} s is {n} samples at the data's "
            f"{first.sample_rate_hz:g} Hz, too short to score anything (at least "
            f"{MIN_SAMPLES}); give a longer duration (--duration S)")
    if not (isinstance(n_experiments, int | np.integer) and n_experiments >= 1):
        raise DesignError(f"n_experiments must be an integer >= 1, got {n_experiments!r}")
    if not (isinstance(n_draws, int | np.integer) and n_draws >= 4):
        raise DesignError(f"n_draws must be an integer >= 4 (the draws' spread makes each "
                          f"model's predictive density), got {n_draws!r}")
    return duration


def _checked_loads(loads) -> tuple[float | None, ...]:
    """The dead loads to choose from; ``(None,)`` (the first data set's) where none are
    given."""
    if loads is None:
        return (None,)
    out = tuple(float(v) for v in loads)
    if not out or not all(math.isfinite(v) and v >= 0 for v in out):
        raise DesignError(f"loads must be dead loads in kg, each >= 0 (0: none), got "
                          f"{list(loads)!r}")
    return out


def _first_load(first: Dataset, loads_kg: Sequence[float]) -> float:
    """The first data set's declared dead load, which each of ``loads_kg`` replaces;
    refused where it is not declared, where the rig's moving mass is not a number, or
    where a load would leave the rig no moving mass.

    A rig's ``moving_mass_kg`` is everything that moves, the dead load included; without
    the load it was recorded with, the mass under another load is not known.
    """
    where = first.source or "the first data set"
    declared = dead_load_kg(first)
    if declared is None:
        raise DesignError(
            f"{where}: a dead load from --loads (loads=) hangs in place of the one this "
            "record was made with, which its sidecar does not declare; declare it "
            '("conditions": {"load_kg": 0.1}, kg, 0 for none), so that the moving mass '
            "under another load is known")
    rig = Model.for_dataset(first).rig
    if rig.prior_of("moving_mass_kg") is not None:
        raise DesignError(
            f"{where}: its rig's moving mass is identified (a prior), not known, so no dead "
            "load can replace its own; give no loads, or declare the moving mass as a "
            "number")
    for load in loads_kg:
        mass = loaded_mass_kg(rig.moving_mass_kg, declared, load)
        if not mass > 0:
            raise DesignError(
                f"{where}: a dead load of {load:g} kg in place of its {declared:g} kg leaves "
                f"the rig a moving mass of {mass:.6g} kg (its moving_mass_kg "
                f"{rig.moving_mass_kg:g} less {declared:g} plus {load:g}); give loads the "
                "rig can carry, or declare a moving_mass_kg that includes the carriage and "
                "the muscle")
    return declared


def _units(first: Dataset) -> dict:
    """The column name of time and input in the user's files (the first data set's)."""
    record = first.metadata.get("converted_units") or {}
    return {si: record[si]["from"] if si in record else si
            for si in ("time_s", first.input_name)}


def design(
    datasets: Dataset | Sequence[Dataset],
    base_effects: Sequence[str] | str = (),
    candidates: Sequence[str] | str = (),
    *,
    goal: str = "discriminate",
    parameters: Sequence[str] | None = None,
    loads: Sequence[float] | None = None,
    duration_s: float | None = None,
    input_range: tuple[float, float] | None = None,
    n_experiments: int = 50,
    n_draws: int = 32,
    n_trials: int | None = None,
    seed: int | None = 0,
    rng: np.random.Generator | None = None,
    fits: Mapping[str, CandidateFit] | None = None,
    noise_model: str = "auto",
    substeps: int | str = "auto",
) -> DesignResult:
    """Choose the next experiment: the one expected to tell the candidates apart best,
    or to shrink the named parameters' intervals most.

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        The data so far, one data set per experiment; the next experiment runs on the
        first one's rig (a dead load of ``loads`` in place of its own), at its sample
        rate, with its number of trials.
    base_effects : sequence of str or comma-separated str
        The effects every candidate model has.
    candidates : sequence of str or comma-separated str
        The candidate effects: with ``goal="discriminate"`` at least two, each added to
        the base model alone; with ``goal="parameters"`` all added together (none: the
        base model).
    goal : str
        ``"discriminate"`` or ``"parameters"``.
    parameters : sequence of str, optional
        With ``goal="parameters"``: the parameters whose intervals should shrink.
    loads : sequence of float, optional
        Dead loads in kg the lab can hang for the next experiment (0: none), each in
        place of the one the first data set was recorded with, which its sidecar must
        then declare (``"conditions": {"load_kg": ...}``; its rig's ``moving_mass_kg``
        includes it); by default the rig as the first data set has it.
    duration_s : float, optional
        The experiment's length; the first data set's by default.
    input_range : (float, float), optional
        The rig's safe input range in SI (Pa, or N on a force rig), inside the one the
        first data set's sidecar declares (``"input_range"``); that one where none is
        given. One of them is required: pmabayes never guesses how hard a rig may be
        driven.
    n_experiments : int
        Candidate experiments scored (the repeat of the first input and a default
        chirp among them).
    n_draws : int
        Posterior draws per model for the truths, and as many for its predictive
        density.
    n_trials : int, optional
        Trials the next experiment repeats; the first data set's by default.
    seed : int or None
        Seed of everything random; ignored where ``rng`` is given.
    rng : numpy.random.Generator, optional
        Source of randomness instead of ``seed``.
    fits : mapping of str to CandidateFit, optional
        Fits made before (a result's ``fits``), by candidate name; the others are fitted.
    noise_model : str
        As for :func:`pmabayes.fit`, for the fits made here.
    substeps : int or str
        As for :func:`pmabayes.fit`, for the fits made here.

    Returns
    -------
    DesignResult

    Raises
    ------
    DesignError
        With fewer than two candidates that can act on the rig, an input range that is
        missing or beyond the rig's, a budget too small to score anything, or an unknown
        goal, before any fit; a parameter the model does not identify, after its fit.

    Notes
    -----
    The noise of the next experiment is the fitted noise model of the first data set at
    the first model's MAP: learnt from the repeats, it is the same for every model.

    Examples
    --------
    Which of two effects a muscle lacks, a regulator lag or a transport delay: four
    candidate experiments scored with four draws per model, too few to trust but enough
    to show the result (about 10 s):

    >>> from pmabayes.design import design
    >>> from pmabayes.synthetic import example_data
    >>> data = example_data()  # three synthetic 4 s chirps at 200 Hz
    >>> result = design(data, candidates=["regulator_lag", "transport_delay"],
    ...                 input_range=(0.0, 5e5), n_experiments=4, n_draws=4, seed=0)
    >>> result.candidates
    ['regulator_lag', 'transport_delay']
    >>> [e.family for e in result.experiments]
    ['repeat', 'default_chirp', 'chirp', 'steps']
    >>> print(result.lines()[0])
    chosen: ...

    ``result.experiment.input()`` is the input to run next; ``pmabayes design`` writes it
    to a file with a report.
    """
    start = time.perf_counter()
    datasets = dataset_list(datasets, DesignError("no data: give the data so far (one "
                                                  "data set per experiment)"))
    first = datasets[0]
    base = _names(base_effects)
    cands = list(dict.fromkeys(_names(candidates)))
    for name in [*base, *cands]:
        get_effect(name)  # an unknown name: the registry's error, with a near one
    if goal not in GOALS:
        raise DesignError(f"goal must be one of {', '.join(GOALS)}, got {goal!r}")
    duration = _checked_budget(first, duration_s, n_experiments, n_draws)
    loads_kg = _checked_loads(loads)
    first_load = dead_load_kg(first) if loads is None else _first_load(first, loads_kg)
    low, high = input_range_checked(datasets, input_range)
    left_out: dict[str, str] = {}
    if goal == "discriminate":
        if len(cands) < 2:
            raise DesignError(f"a design that tells candidates apart needs at least two, got "
                              f"{len(cands)} ({', '.join(cands) or 'none'}); give two or "
                              "more effects (--candidates A,B)")
        for name in cands:
            why = does_not_act(datasets, base, name)
            if why is not None:
                left_out[name] = why
        models = {n: e for n, e in model_names(base, cands, goal).items() if n not in left_out}
        if len(models) < 2:
            raise DesignError(
                "fewer than two candidates can act on this rig: "
                + "; ".join(f"{n} {why}" for n, why in left_out.items())
                + "; give other candidates")
    else:
        if not parameters:
            raise DesignError('goal="parameters" needs the parameters whose intervals should '
                              "shrink (parameters=[...], --parameters a,b)")
        models = model_names(base, cands, goal)
    recorded_seed = seed if rng is None else None  # a given generator's state is not kept
    rng = np.random.default_rng(seed) if rng is None else rng
    fit_rng, exp_rng, draw_rng, noise_rng = rng.spawn(4)
    say = Progress()
    fitted: dict[str, CandidateFit] = {}
    # one stream per model, whether or not its fit is given: the others' stay the same
    for k, ((name, effects), stream) in enumerate(zip(models.items(),
                                                      fit_rng.spawn(len(models)),
                                                      strict=True)):
        if fits is not None and name in fits:
            fitted[name] = fits[name]
            continue
        say.say(f"fitting {name} on the data so far ({k + 1} of {len(models)})")
        fitted[name] = fit_candidate(datasets, effects, name, rng=stream,
                                     noise_model=noise_model, substeps=substeps)
    ref = next(iter(fitted.values()))
    columns = None
    if goal == "parameters":
        names = list(ref.posterior.names)
        unknown = [p for p in parameters if p not in names]
        if unknown:
            raise DesignError(f"parameters {', '.join(unknown)} are not identified in the "
                              f"model {ref.name}; it identifies {', '.join(names)}")
        columns = [names.index(p) for p in parameters]
    experiments = candidate_experiments(
        exp_rng, int(n_experiments), low=low, high=high, duration_s=duration,
        sample_rate_hz=first.sample_rate_hz, loads=loads_kg, first_input=first.input[0])
    trials = first.n_trials if n_trials is None else int(n_trials)
    noise_model_obj = ref.posterior.likelihoods[0].noise
    noise = ref.noise()
    whiten = lambda x: whiten_rows(noise_model_obj, noise, trials, x)  # noqa: E731
    noise_seed = int(noise_rng.integers(2**63))
    say.say(f"scoring {len(experiments)} candidate experiments")
    if goal == "discriminate":
        scores, predictions, weights = _discriminate(fitted, experiments, whiten, draw_rng,
                                                     int(n_draws), noise_seed, trials)
    else:
        scores, predictions = _parameters(ref, experiments, whiten, draw_rng, columns,
                                          list(parameters), int(n_draws))
        weights = {}
    finite = [i for i, s in enumerate(scores) if math.isfinite(s["score"])]
    if not finite:
        raise DesignError("no candidate experiment could be scored: "
                          + scores[0].get("failed", "no finite score"))
    chosen = max(finite, key=lambda i: scores[i]["score"])
    chosen_predictions = _predictions(fitted, experiments[chosen], predictions, draw_rng,
                                      int(n_draws))
    settings = {"seed": recorded_seed, "n_draws": int(n_draws),
                "n_experiments": len(experiments), "n_trials": trials,
                "input_range": [low, high], "duration_s": duration,
                "loads_kg": list(loads_kg), "first_load_kg": first_load,
                "base_effects": base,
                "parameters": list(parameters or []),
                "noise": {"model": noise_model_obj.name, "values": list(noise)},
                "importance": weights,
                "fitted": {n: {"values": _plain_values(f.map.values)}
                           for n, f in fitted.items()}}
    return DesignResult(goal, list(models), left_out, experiments, scores, chosen,
                        chosen_predictions, settings, fitted, ref.model.rig.to_dict(),
                        first.input_name, _units(first), time.perf_counter() - start,
                        _fit_notes(fitted) + _weight_notes(weights))


def _fit_notes(fitted: Mapping[str, CandidateFit]) -> list[str]:
    """What each fit of the data so far says that makes the scores less than they seem.

    The scores start from each model's posterior as fitted (its Laplace covariance, or a
    fit file's draws). Where the model misses much of the data, or the experiments so
    far disagree on one parameter set, that posterior is the model's certainty, narrower
    than what the data know (fits of one load and of three loads of a real muscle put its
    area three times apart, each to within a fraction of a percent:
    ``docs/studies/real_measurements.md``). A next experiment cannot show what the model
    lacks, so its expected gain is then small beside an interval already too narrow.
    """
    notes = []
    for name, fit in fitted.items():
        quality = fit.map.quality or {}
        if quality.get("poor") and quality.get("text"):
            notes.append(f"{name}: {quality['text']} The scores start from this fit's "
                         "posterior: read their ranking, not their size.")
        agreement = fit.map.agreement or {}
        if agreement.get("agree") is False:
            notes.append(
                f"{name}: the experiments so far disagree on one parameter set (likelihood "
                f"ratio {agreement['statistic']:.4g} on {agreement['df']} degrees of freedom), "
                "so the joint fit's posterior, which the scores start from, is narrower than "
                "what the data know: read their ranking, not their size; `pmabayes diagnose` "
                "says what differs between the experiments.")
        if fit.map.laplace_note:
            notes.append(f"{name}: {fit.map.laplace_note}")
        note = _convergence_note(name, fit)
        if note:
            notes.append(note)
    return notes


def _weight_notes(weights: Mapping[str, dict]) -> list[str]:
    """One line per model whose Laplace approximation is too far from its posterior on
    the data so far for importance resampling to mend (Pareto k-hat above
    :data:`~pmabayes.design.fits.GOOD_K_HAT`)."""
    return [f"{name}: its Laplace approximation is far from its posterior on the data so "
            f"far (Pareto k-hat {w['k_hat']:.2f} of its draws' importance weights, above "
            f"{GOOD_K_HAT:g}, even with its sds scaled by {w['scale']:g}; {w['ess']:.0f} "
            f"effective draws of {w['pool']}), so the draws every score starts from are few "
            "distinct ones: the expected factors are rough; fit it by `pmabayes fit` and "
            "give the file with --fit (fits= in Python)."
            for name, w in weights.items()
            if math.isfinite(w["k_hat"]) and w["k_hat"] > GOOD_K_HAT]


def _convergence_note(name: str, fit: CandidateFit) -> str | None:
    """One line where a candidate's fit did not converge: what, why it matters for the
    expected factors, and the fix; None where it converged or is not known to have."""
    record = fit.convergence
    if not record or record.get("converged", True):
        return None
    why = "; ".join(str(m) for m in record.get("messages") or []) or "no reason recorded"
    if fit.samples_z is not None:
        return (f"{name}: the fit file {fit.source} did NOT converge ({why}), so its draws, "
                "which every score starts from, need not be this model's posterior: the "
                "expected factors (and even their ranking) are not to be trusted; run "
                "`pmabayes fit` longer (more --steps) and give the new file with --fit.")
    return (f"{name}: its MAP search did NOT converge ({why}), so the draws every score "
            "starts from are centred off this model's posterior: the expected factors are "
            "biased; fit it by `pmabayes fit` and give the file with --fit (fits= in "
            "Python).")


def _plain_values(values: Mapping) -> dict:
    """A MAP's values for JSON: floats, and a joint fit's noise ``{experiment: value}``
    (one per experiment: :meth:`pmabayes.inference.density.Posterior.noise_values`)."""
    return {k: ({e: float(x) for e, x in v.items()} if isinstance(v, Mapping) else float(v))
            for k, v in values.items()}


def model_names(base: Sequence[str] | str, candidates: Sequence[str] | str,
                goal: str = "discriminate") -> dict[str, list[str]]:
    """The models a design fits, by the name its ``fits`` and scores use, with their effects.

    Parameters
    ----------
    base, candidates : sequence of str or comma-separated str
        As for :func:`design`.
    goal : str
        As for :func:`design`.

    Returns
    -------
    dict
        ``{candidate: base + [candidate]}`` to discriminate; ``{"base+A+B": base +
        candidates}`` for parameters.
    """
    base, cands = _names(base), list(dict.fromkeys(_names(candidates)))
    if goal == "parameters":
        return {"+".join(["base", *base, *cands]): [*base, *cands]}
    return {n: [*base, n] for n in cands}


def given_fits(fits: Sequence[CandidateFit], base: Sequence[str] | str,
               candidates: Sequence[str] | str, goal: str = "discriminate"
               ) -> dict[str, CandidateFit]:
    """Fits made before (e.g. :func:`~pmabayes.design.fits.fit_from_file`), each under the
    name of the model a design fits that has its effects.

    Raises
    ------
    DesignError
        For a fit whose effects are no candidate model's.
    """
    import dataclasses

    models = model_names(base, candidates, goal)
    out = {}
    for fit in fits:
        effects = sorted(fit.model.effect_names)
        match = [n for n, e in models.items() if sorted(e) == effects]
        if not match:
            raise DesignError(
                f"{fit.source or fit.name}: a fit of base + {' + '.join(effects) or 'nothing'}"
                f" is no candidate model's; the design fits "
                + "; ".join(f"{n}: base + {' + '.join(e) or 'nothing'}"
                            for n, e in models.items()))
        out[match[0]] = dataclasses.replace(fit, name=match[0])
    return out


def input_range_checked(datasets: Sequence[Dataset], given) -> tuple[float, float]:
    """:func:`~pmabayes.design.experiments.input_range` of the given range, inside the one
    the first data set's sidecar declares (its ``"input_range"``, SI), where it does.

    Raises
    ------
    DesignError
        Where the sidecar's ``"input_range"`` is not two numbers, or as
        :func:`~pmabayes.design.experiments.input_range` does.
    """
    declared = datasets[0].metadata.get("input_range")
    if declared is not None:
        where = datasets[0].source or "the first data set"
        try:
            declared = tuple(float(v) for v in declared)
        except (TypeError, ValueError):
            declared = ()
        if len(declared) != 2:
            raise DesignError(
                f"{where}: the sidecar's \"input_range\" is "
                f"{datasets[0].metadata['input_range']!r}; give two numbers [low, high] in SI "
                "(Pa, or N on a force rig)")
    return input_range(datasets, None if given is None else tuple(float(v) for v in given),
                       declared)


def _names(effects: Sequence[str] | str) -> list[str]:
    if isinstance(effects, str):
        return [e.strip() for e in effects.split(",") if e.strip()]
    return list(effects)


def _chunks(experiments: Sequence[Experiment], rows: int) -> list[list[int]]:
    """Experiments of one load, in chunks whose batched simulation fits in memory."""
    out: list[list[int]] = []
    for load in dict.fromkeys(e.load_kg for e in experiments):
        members = [i for i, e in enumerate(experiments) if e.load_kg == load]
        size = max(1, _CHUNK_FLOATS // max(1, rows * experiments[0].time_s.size))
        out += [members[k:k + size] for k in range(0, len(members), size)]
    return out


def _responses(fit: CandidateFit, theta: np.ndarray, experiments: Sequence[Experiment],
               chunk: list[int]) -> np.ndarray:
    """The model's responses ``(len(chunk), rows, n)`` to the chunk's inputs, one batched
    simulation: each input for every row of ``theta``, referred as the first data set's
    positions are (to the model's at the first sample where its sidecar says
    ``"position_reference": "start"``)."""
    exps = [experiments[i] for i in chunk]
    rows = theta.shape[0]
    model = fit.model_on(exps[0].load_kg)
    u = np.repeat(np.stack([e.input() for e in exps]), rows, axis=0)
    x = simulate(model, np.tile(theta, (len(exps), 1)), u, time_s=exps[0].time_s,
                 substeps=fit.substeps)
    if position_reference(fit.posterior.likelihoods[0].dataset) == "start":
        # a sensor zeroed at the record's start never sees the static sag of a load (or
        # any offset the model's zero has): scoring it would credit the next experiment
        # with information its record cannot hold
        x = x - x[:, :1]
    return x.reshape(len(exps), rows, -1)


def _failed(x: np.ndarray) -> str | None:
    bad = int(np.count_nonzero(~np.all(np.isfinite(x), axis=-1)))
    return (None if not bad else
            f"{bad} of {x.shape[0]} simulations of posterior draws did not stay finite")


def _discriminate(fitted: dict, experiments: list, whiten, rng: np.random.Generator,
                  n_draws: int, noise_seed: int, n_trials: int = 1
                  ) -> tuple[list[dict], dict, dict]:
    """Every experiment's discrimination score; each model's draws (the same for every
    experiment, and so is the noise: common random numbers make the experiments'
    scores differ by the experiments, not by the draws)."""
    # the truths and the predictive densities from two separate sets of draws of the
    # posterior on the data so far (Laplace draws importance-resampled to it)
    draws, weights = {}, {}
    for n, f in fitted.items():
        sets, w = f.weighted_draws(rng.spawn(1)[0], n_draws, sets=2)
        draws[n] = np.vstack(sets)
        if w is not None:
            weights[n] = w
    names = list(fitted)
    scores: list[dict | None] = [None] * len(experiments)
    for chunk in _chunks(experiments, 2 * n_draws):
        xs = {n: _responses(fitted[n], draws[n], experiments, chunk) for n in names}
        for j, i in enumerate(chunk):
            # a draw whose simulation does not stay finite on this input cannot be scored
            # here: it is left out of this experiment's sets, counted in its score
            ok = {n: np.all(np.isfinite(xs[n][j]), axis=-1) for n in names}
            truth = {n: xs[n][j][:n_draws][ok[n][:n_draws]] for n in names}
            evid = {n: xs[n][j][n_draws:][ok[n][n_draws:]] for n in names}
            failed = sum(int(np.count_nonzero(~ok[n])) for n in names)
            if min(min(len(truth[n]), len(evid[n])) for n in names) < 4:
                scores[i] = {"score": math.nan, "mc_se": math.nan, "failed_draws": failed,
                             "failed": f"{failed} of {2 * n_draws * len(names)} simulations "
                             "of posterior draws did not stay finite, leaving fewer than 4 "
                             "of a model"}
                continue
            d = discrimination([whiten(truth[n]) for n in names],
                               [whiten(evid[n]) for n in names],
                               np.random.default_rng(noise_seed), n_trials=n_trials)
            scores[i] = {"score": d.score, "mc_se": d.score_se, "named_rate": d.named_rate,
                         "named_rate_mc_se": d.named_se, "failed_draws": failed, **{
                             k: v for k, v in d.to_dict(names).items()
                             if k in ("n_monte_carlo", "log_bayes_factor_when_true",
                                      "named_decisively_rate", "named_decisively_mc_se")}}
    return scores, draws, weights


def _parameters(fit: CandidateFit, experiments: list, whiten, rng: np.random.Generator,
                columns: list[int], parameters: list[str], n_draws: int
                ) -> tuple[list[dict], dict]:
    """Every experiment's expected shrinkage of the parameters' intervals, by forward
    differences of the whitened response at a few posterior draws (in the fit's
    unconstrained coordinates, steps of a hundredth of each one's sd)."""
    post, cov = fit.posterior, np.asarray(fit.map.covariance_z, dtype=float)
    n_fisher = min(_FISHER_DRAWS, n_draws)
    zd, steps = _fisher_points(fit, rng, n_fisher)
    rows = np.concatenate([np.vstack([z, z + np.diag(h)]) for z, h in zip(zd, steps,
                                                                         strict=True)])
    theta = fit._model_theta(post.to_natural(rows))
    p = zd.shape[1]
    scores: list[dict | None] = [None] * len(experiments)
    for chunk in _chunks(experiments, theta.shape[0]):
        xs = _responses(fit, theta, experiments, chunk)
        for j, i in enumerate(chunk):
            why = _failed(xs[j])
            if why is not None:
                scores[i] = {"score": math.nan, "mc_se": math.nan, "failed": why}
                continue
            white = whiten(xs[j]).reshape(n_fisher, p + 1, -1)
            jac = [((w[1:] - w[0]) / h[:, None]).T for w, h in zip(white, steps, strict=True)]
            factors = shrinkage(cov, jac, columns)  # (draws, parameters)
            logs = np.log(factors).mean(axis=1)
            score = float(logs.mean())
            scores[i] = {"score": score,
                         "mc_se": float(logs.std(ddof=1) / math.sqrt(logs.size)),
                         "factor": math.exp(score),
                         "factors": {n: float(np.exp(np.log(factors[:, k]).mean()))
                                     for k, n in enumerate(parameters)},
                         "n_monte_carlo": int(logs.size)}
    return scores, {}


def _fisher_points(fit: CandidateFit, rng: np.random.Generator, n: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` draws of the fit's Laplace approximation inside the priors' support, in its
    unconstrained coordinates ``(n, p)``, and each one's finite-difference steps
    ``(n, p)``: a hundredth of each coordinate's sd, backwards where a step forwards
    would leave the support.

    A parameter whose prior's support is narrower than its coordinate (a dead-zone
    pressure's ``(0, inf)`` on an identity coordinate) would otherwise be simulated
    outside it, which the simulator refuses.

    Raises
    ------
    DesignError
        Where fewer than ``n`` of ``10 n`` draws fall inside the support.
    """
    post = fit.posterior
    cov = np.asarray(fit.map.covariance_z, dtype=float)
    z0 = np.asarray(fit.map.z, dtype=float)
    chol = np.linalg.cholesky(0.5 * (cov + cov.T) + 1e-12 * np.eye(z0.size))

    def inside(z: np.ndarray) -> np.ndarray:
        return np.isfinite(post.log_prior(post.to_natural(z)))

    kept: list[np.ndarray] = []
    for _ in range(10):
        z = z0 + rng.standard_normal((n, z0.size)) @ chol.T
        kept += list(z[inside(z)])
        if len(kept) >= n:
            break
    else:
        raise DesignError(f"the Laplace approximation of {fit.name!r} puts fewer than {n} of "
                          f"{10 * n} draws inside the priors' support; fit it by MCMC")
    zd = np.array(kept[:n])
    h = 1e-2 * np.sqrt(np.diag(cov))
    steps = np.tile(h, (n, 1))
    for d in range(n):
        forward = inside(zd[d] + np.diag(h))
        steps[d, ~forward] = -h[~forward]
    return zd, steps


def _predictions(fitted: dict, experiment: Experiment, draws: dict,
                 rng: np.random.Generator, n_draws: int) -> dict:
    """Each model's response to the chosen input: at its MAP, and the 5%-95% of its
    draws."""
    out = {}
    for name, fit in fitted.items():
        theta = draws.get(name)
        if theta is None:
            theta = fit.draws(rng.spawn(1)[0], n_draws)
        rows = np.vstack([fit.map_theta(), theta])
        x = _responses(fit, rows, [experiment], [0])[0]
        lo, hi = np.nanquantile(x[1:], [0.05, 0.95], axis=0)
        out[name] = {"map": x[0], "low": lo, "high": hi}
    return out
