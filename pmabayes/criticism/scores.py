"""Score (Lagrange multiplier) tests: the evidence in the data that an effect is missing
from a model, at the model's MAP and with no refit (:func:`rank_effects`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pmabayes.criticism.observed import model_mean
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.effects import registered_effects
from pmabayes.model.model import Model, ModelError
from pmabayes.parallel import background
from pmabayes.util import Progress

__all__ = ["EffectEvidence", "rank_effects", "significance_threshold", "compile_candidates"]

#: A tested parameter whose Fisher information is at most this fraction of the largest
#: one's has no effect on the output: the effect cannot act on the data.
_SILENT = 1e-20


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
    left_out : str or None
        Why the effect was left out of the score tests (``"cannot act on these data:
        ..."``, or a score matrix that is singular there); None when it was tested.
        A left-out effect has NaN ``statistic`` and ``p_value``, is not significant and
        does not count among the candidates of the Bonferroni level.
    """

    effect: str
    statistic: float
    dof: int
    p_value: float
    significant: bool
    estimate: dict
    interval: dict
    explained: float
    left_out: str | None = None


def rank_effects(
    likelihood: Likelihood | Sequence[Likelihood],
    noise,
    values: dict,
    *,
    candidates=None,
    level: float = 0.05,
    starts: Sequence | None = None,
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
    values : dict or sequence of dict
        The current model's parameter values at its MAP; one per experiment where
        they differ (an experiment's own offset,
        :meth:`~pmabayes.inference.density.Posterior.experiment_point`).
    candidates : iterable of str, optional
        Effects to test; every registered effect not already in the model by
        default.
    level : float
        Family-wise false-alarm level.
    starts : sequence, optional
        Each experiment's estimated start ``(3,)`` at the MAP, or None where it is
        declared; all declared by default.

    Notes
    -----
    The score and the information are sums over the samples: a sample where no trial
    is counted (a gap, a warm-up) has no innovation and adds nothing. Trials on their
    own inputs enter through the model's trial mean
    (:func:`~pmabayes.criticism.observed.model_mean`), whose residual the noise of the
    trial mean whitens.

    Returns
    -------
    list of EffectEvidence
        Most evidence first; the effects left out (:attr:`EffectEvidence.left_out`:
        an effect that cannot act on these data, whose sensitivities are zero at every
        sample, or one whose score matrix is singular there) last, in the given order.

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
    bar = Progress()
    bar.start(len(names), "candidates", "score tests (a new effect compiles its simulator "
              "once)")
    points = [values] * len(liks) if isinstance(values, dict) else list(values)
    starts = [None] * len(liks) if starts is None else list(starts)
    out = []
    for name in names:
        out.append(_score_test(liks, noises, points, starts, name))
        bar.advance()
    threshold = level / max(sum(e.left_out is None for e in out), 1)
    out = [EffectEvidence(**{**e.__dict__, "significant": e.p_value < threshold}) for e in out]
    return sorted(out, key=lambda e: (e.left_out is not None,
                                      0.0 if e.left_out is not None else -e.statistic))


def compile_candidates(models: Sequence[Model], datasets: Sequence, substeps,
                       candidates=None):
    """Compile the simulators that :func:`rank_effects` will need, in a background process.

    Each candidate effect added to the model is a new simulator, compiled at its first
    use (seconds each, a minute or more for all of them); compiled in a forked process
    while this one fits the model, they are in numba's disk cache by the time the
    score tests load them. Nothing depends on it: a simulator not compiled yet is
    compiled where it is needed, as without it.

    Parameters
    ----------
    models, datasets : sequence
        Each experiment's model (as diagnosed) and data set.
    substeps : int
        The simulator's substeps per sample.
    candidates : iterable of str, optional
        As :func:`rank_effects`'s.

    Returns
    -------
    multiprocessing.Process or None
        The process (terminate it once the score tests are done), or None where
        processes cannot be forked.
    """
    present = set(models[0].effect_names)
    names = [n for n in (candidates or registered_effects()) if n not in present]
    return background(_compile_all, list(models), list(datasets), substeps, names)


def _compile_all(models: list, datasets: list, substeps, names: list[str]) -> None:
    """Simulate each experiment once at the defaults with each candidate added (which
    compiles its simulator); a candidate that fails is left to the score test, which
    says why."""
    warnings.simplefilter("ignore")  # this process's; what it meets, the user hears there
    for name in names:
        for model, dataset in zip(models, datasets, strict=True):
            try:
                ext = model.with_effects(name)
                Likelihood(ext, dataset, substeps=substeps).simulate(ext.theta(ext.defaults))
            except Exception:  # noqa: BLE001 - the score test meets it and reports it
                break


def _left_out(name: str, tested: list, why: str) -> EffectEvidence:
    """A candidate left out of the score tests, with the reason."""
    nan = math.nan
    return EffectEvidence(name, nan, len(tested), nan, False, {}, {}, 0.0, why)


def _cannot_act(ext, eff, tested: list, likelihoods: list) -> str:
    """Why an effect whose sensitivities are all zero cannot act on these data."""
    unit = {"pressure_pa": "Pa", "force_n": "N"}
    spans = "; ".join(
        f"{lik.dataset.input_name} spans {float(np.min(lik.dataset.input)):.4g} to "
        f"{float(np.max(lik.dataset.input)):.4g} {unit.get(lik.dataset.input_name, '')}"
        .rstrip() for lik in likelihoods)
    fixed = [f"{p.name} = {ext.fixed.get(p.name, p.default):.6g} {p.unit}".rstrip()
             for p in eff.parameters if p.name in ext.fixed]
    return (f"cannot act on these data: moving {', '.join(tested)} from "
            f"{', '.join(f'{ext.parameter(n).null:g}' for n in tested)} changes the simulated "
            f"output at no sample ({spans}"
            + (f"; its fixed {', '.join(fixed)}" if fixed else "") + ")")


def _rows(ext, values: dict, tested: list, free: list) -> tuple[list, list, dict]:
    """The point of a score test (the MAP, the effect at its null) and the same with
    each free parameter moved by a small step: the rows, the steps and the point."""
    point = dict(ext.defaults)
    point.update({k: v for k, v in values.items() if k in point})  # not the noise
    point.update({n: ext.parameter(n).null for n in tested})
    rows, steps = _stepped_rows(ext, ext.theta(point)[0], free)
    return rows, steps, point


def _stepped_rows(model: Model, base: np.ndarray, names: Sequence[str]
                  ) -> tuple[list[np.ndarray], list[float]]:
    """``base`` and, for each of ``names``, ``base`` with that parameter moved by a small
    forward step: the rows (``base`` first) and the steps."""
    rows, steps = [base], []
    for name in names:
        j = model.index(name)
        # the default sets the scale where the value is 0 (an effect at its null)
        h = 1e-6 * max(abs(base[j]), abs(model.parameter(name).default), 1e-12)
        up = base.copy()
        up[j] += h
        rows.append(up)
        steps.append(h)
    return rows, steps


def _score_test(likelihoods: list, noises: list, points: list, starts: list,
                name: str) -> EffectEvidence:
    """The score test of one candidate effect over the experiments (``significant`` is set
    by the caller): their scores and informations add."""
    try:
        exts = [lik.model.with_effects(name) for lik in likelihoods]
    except ModelError as err:  # e.g. a second hysteresis law: it cannot join this model
        return _left_out(name, [], f"cannot be added to this model: {err}")
    ext = exts[0]  # the parameters are shared; only the rigs differ
    eff = ext.effects[-1]
    # a parameter without a null (a shape, such as a damping ratio) is not identified
    # when the effect vanishes: it stays at its default and is not tested
    tested = [p.name for p in eff.parameters if p.vary and p.null is not None]
    shapes = {p.name for p in eff.parameters if p.null is None}
    free = [n for n in ext.free_names if n not in shapes]
    rows, steps, point = _rows(ext, points[0], tested, free)
    info = np.zeros((len(free), len(free)))
    score = np.zeros(len(free))
    energy, n_samples = 0.0, 0
    for e, (lik, ext_e, noise) in enumerate(zip(likelihoods, exts, noises, strict=True)):
        def whiten(v: np.ndarray, lik=lik, noise=noise) -> np.ndarray:
            return lik.whiten(v, noise.sigma, noise.rho, noise.white)

        if e and points[e] is not points[0]:
            rows, steps, _ = _rows(ext_e, points[e], tested, free)
        ext_lik = Likelihood(ext_e, lik.dataset, substeps=lik.substeps)
        # the base model's start in the extended model's columns (a state it adds at
        # its prior mean: at the null tested it does not act)
        start = ext_lik.start_from(starts[e], lik.model)
        start = None if start is None else np.broadcast_to(start, (len(rows), start.shape[1]))
        x = model_mean(lik, ext_lik.simulate(np.array(rows), start))
        r_w = whiten(lik.y_mean - x[0])
        w = np.stack([whiten((x[k + 1] - x[0]) / steps[k]) for k in range(len(free))], axis=1)
        seen = np.isfinite(r_w)
        if not seen.all():  # a sample not counted has no innovation: it adds nothing
            r_w, w = r_w[seen], w[seen]
        info += w.T @ w
        score += w.T @ r_w
        energy += float(r_w @ r_w)
        n_samples += r_w.size
    t_idx = [free.index(n) for n in tested]
    o_idx = [k for k in range(len(free)) if k not in t_idx]
    scale = float(np.max(np.diag(info))) if info.size else 0.0
    if not all(info[i, i] > _SILENT * scale for i in t_idx):
        if not any(info[i, i] > _SILENT * scale for i in t_idx):
            return _left_out(name, tested, _cannot_act(ext, eff, tested, likelihoods))
        silent = [n for n, i in zip(tested, t_idx, strict=True) if not info[i, i] > _SILENT * scale]
        return _left_out(name, tested, f"cannot act on these data through {', '.join(silent)}, "
                         "whose sensitivities are zero at every sample, so its parameters "
                         "cannot be tested together")
    i_oo = info[np.ix_(o_idx, o_idx)]
    i_to = info[np.ix_(t_idx, o_idx)]
    try:
        eff_score = score[t_idx] - i_to @ np.linalg.solve(i_oo, score[o_idx])
        var = info[np.ix_(t_idx, t_idx)] - i_to @ np.linalg.solve(i_oo, i_to.T)
        step = np.linalg.solve(var, eff_score)
        sd = np.sqrt(np.diag(np.linalg.inv(var)))
    except np.linalg.LinAlgError:
        return _left_out(name, tested, "not testable on these data: its score matrix is "
                         "singular (its sensitivities repeat those of the model's own "
                         "parameters here)")
    if not (np.all(np.isfinite(step)) and np.all(np.isfinite(sd))):
        return _left_out(name, tested, "not testable on these data: its score matrix is "
                         "numerically singular (its sensitivities all but repeat the model's "
                         "own parameters' here)")
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
