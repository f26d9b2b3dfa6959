"""Model criticism: which effect is missing, with what evidence, and what adding it does.

Stage 7 (diagnostics), above :mod:`pmabayes.residuals` (the residual statistics:
band errors against the noise floor, whiteness and independence tests, the
residual signature and the adequacy rule). Here the model is confronted with the
candidate effects:

* :func:`rank_effects`: the score (Lagrange multiplier) test of every candidate
  effect at the model's MAP, with no refit;
* :func:`diagnose`: fit, criticise, rank, refit the significant candidates, judge
  them by the residual they remove and by their leave-one-trial-out ELPD, and say
  in words what is missing;
* :func:`compare_fits`: fits of the same data side by side.

The residual statistics are re-exported here, so ``from pmabayes.criticism import
band_errors`` (and every other name that lived here) keeps working.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pmabayes.data import Dataset
from pmabayes.effects import get_effect, registered_effects
from pmabayes.fit import NoiseEstimate, Posterior, estimate_noise, find_map
from pmabayes.likelihood import Likelihood
from pmabayes.model import Model
from pmabayes.posterior import check_dataset, fit_info, model_from_fit
from pmabayes.residuals import (
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
from pmabayes.simulator import Simulation, simulate_dataset
from pmabayes.util import Progress

#: the residual statistics of the old single module, still importable from here
_REEXPORTED = ("DEFAULT_BANDS_HZ", "BandErrors", "BandError", "band_label",
               "instantaneous_frequency", "band_errors", "innovations", "autocorrelation",
               "cross_correlation", "ljung_box", "Signature", "residual_signature")
__all__ = [*_REEXPORTED, "EffectEvidence", "rank_effects", "Refit", "Finding", "Diagnosis",
           "diagnose", "significance_threshold", "FitComparison", "compare_fits"]


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
    model = likelihood.model
    present = set(model.effect_names)
    names = [n for n in (candidates or registered_effects()) if n not in present]
    out = [_score_test(likelihood, noise, values, name) for name in names]
    threshold = level / max(len(out), 1)
    out = [EffectEvidence(**{**e.__dict__, "significant": e.p_value < threshold}) for e in out]
    return sorted(out, key=lambda e: -e.statistic)


def _score_test(likelihood: Likelihood, noise, values: dict, name: str) -> EffectEvidence:
    """The score test of one candidate effect (``significant`` is set by the caller)."""

    def whiten(v: np.ndarray) -> np.ndarray:
        return likelihood.whiten(v, noise.sigma, noise.rho, noise.white)

    ext = likelihood.model.with_effects(name)
    lik = Likelihood(ext, likelihood.dataset, substeps=likelihood.substeps)
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
    estimate, interval = {}, {}
    for i, n in enumerate(tested):
        est = point[n] + step[i]
        lo, hi = est - 1.645 * sd[i], est + 1.645 * sd[i]
        if one_sided[i]:  # the constrained estimate: a bound is the smallest value
            est, lo, hi = max(est, point[n]), max(lo, point[n]), max(hi, point[n])
        estimate[n], interval[n] = float(est), (float(lo), float(hi))
    excess = max(float(r_w @ r_w) - r_w.size, 1e-12)
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
    elpd_i : numpy.ndarray or None
        Per-trial leave-one-out ELPD, for paired comparisons of refits.
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
                            "noise_ratio": self.refit.signature.ratio}
        return out


@dataclass(frozen=True)
class Diagnosis:
    """A model confronted with repeated trials: how good, where it fails, what is missing.

    Parameters
    ----------
    dataset : Dataset
        The data.
    model : Model
        The diagnosed model.
    values : dict
        Its MAP, with the noise parameters.
    noise : NoiseEstimate
        The noise identified from the spread between trials.
    simulation : Simulation
        The model at the MAP, with its states.
    signature : Signature
        The residual's signature.
    adequate : bool
        The whitened residual is consistent with the noise: its mean square is
        within ``1 + energy_tolerance`` of pure noise and its autocorrelation is
        not significant (Ljung-Box at ``level_adequate``).
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
        Leave-one-trial-out ELPD of the model (PSIS-LOO over Laplace draws).
    verdict : str
        The conclusion in words.
    settings : dict
        The settings used (level, thresholds, ci_prob, seed).
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

    @property
    def rms_m(self) -> float:
        """RMS error of the trial mean at the MAP."""
        return self.signature.bands[-1].rms_m

    @property
    def noise_floor_m(self) -> float:
        """RMS error a perfect model would have (from the spread between trials)."""
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

    @property
    def score_threshold(self) -> float:
        """The score statistic above which a candidate is significant (1 dof)."""
        return significance_threshold(self.settings["level"], len(self.ranking))

    def whiteness_curves(self) -> WhitenessCurves:
        """The whiteness figure's curves of the whitened residual (lags to 0.2 s, 99% bound)."""
        label = " + ".join(["base", *self.model.effect_names])
        rate = np.gradient(self.dataset.input[0], self.dataset.time_s)
        return whiteness_curves({label: self.innovations}, rate, self.dataset.dt_s)

    def to_dict(self) -> dict:
        """JSON-ready summary (the keys of ``pmabayes diagnose --json``)."""
        sig = self.signature
        return {
            "data": self.dataset.source,
            "synthetic": bool(self.dataset.metadata.get("synthetic", False)),
            "effects": list(self.model.effect_names),
            "rms_m": self.rms_m,
            "noise_floor_m": self.noise_floor_m,
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
        }


def _laplace_loo(posterior, map_result, rng: np.random.Generator, n_draws: int, ci_prob: float,
                 names: tuple[str, ...] = ()):
    """PSIS-LOO (by trial) and intervals from draws of the MAP's Laplace approximation."""
    import arviz as az

    lik = posterior.likelihood
    z = rng.multivariate_normal(map_result.z, map_result.covariance_z, size=n_draws,
                                method="eigh")
    theta = posterior.to_natural(z)
    theta = theta[np.isfinite(posterior.log_prior(theta))]
    x = lik.simulate(posterior.full_theta(theta))
    sigma, rho, white = posterior.noise.draws(rng, theta.shape[0])
    pointwise = lik.pointwise(x, sigma, rho, white)
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


def _explanation(eff, evidence: float, p_value: float, significant: bool,
                 signature: Signature, refit: Refit | None, contribution_text: str,
                 ci_prob: float) -> str:
    text = f"{eff.name} ({eff.stage} stage): {' '.join(eff.description.split())} "
    text += signature.describe()
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
             f"{refit.rms_m * 1e6:.4g} µm ({refit.signature.ratio:.3g}x the floor), "
             f"{refit.explained:.0%} of the excess residual is removed, and the "
             f"leave-one-trial-out ELPD changes by {refit.elpd_diff:+.1f} "
             f"± {refit.elpd_diff_se:.1f}.")
    return text + contribution_text


def _fit_map(likelihood: Likelihood, noise, rng: np.random.Generator):
    posterior = Posterior(likelihood, noise)
    return posterior, find_map(posterior, rng=rng)


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

    def __post_init__(self) -> None:
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


@dataclass(frozen=True)
class _Base:
    """The diagnosed model at its MAP: what each refit is measured against."""

    likelihood: Likelihood
    noise: NoiseEstimate
    values: dict
    simulation: Simulation
    signature: Signature
    elpd: float
    elpd_i: np.ndarray

    @property
    def excess(self) -> float:
        """The whitened residual's energy above pure noise, summed over the samples."""
        n = self.likelihood.n_samples
        return max(self.signature.energy * n - n, 1e-12)


def _simulate(model: Model, values: dict, likelihood: Likelihood, substeps: int) -> Simulation:
    return simulate_dataset(model, _model_values(model, values), likelihood.dataset,
                            substeps=substeps, states=True)


def _fit_base(model: Model, dataset: Dataset, s: _Settings, rng: np.random.Generator) -> _Base:
    """Noise from the spread between trials, the MAP, its signature and its ELPD."""
    lik = Likelihood(model, dataset, substeps=s.substeps)
    noise = estimate_noise(lik)
    posterior, best = _fit_map(lik, noise, rng)
    values = dict(best.values)
    sim = _simulate(model, values, lik, s.substeps)
    signature = residual_signature(lik, noise, sim)
    elpd, elpd_i, _ = _laplace_loo(posterior, best, rng, s.n_draws, s.ci_prob)
    return _Base(lik, noise, values, sim, signature, elpd, elpd_i)


def _refit(base: _Base, effect: str, s: _Settings, rng: np.random.Generator) -> Refit:
    """Add one effect, refit, and measure what it explains and how it predicts."""
    model, dataset, noise = base.likelihood.model, base.likelihood.dataset, base.noise
    ext = model.with_effects(effect)
    ext_lik = Likelihood(ext, dataset, substeps=s.substeps)
    ext_post, ext_map = _fit_map(ext_lik, noise, rng)
    eff = ext.effects[-1]
    tested = tuple(p.name for p in eff.parameters if p.vary and p.name in ext.free_names)
    e_elpd, e_elpd_i, interval = _laplace_loo(ext_post, ext_map, rng, s.n_draws, s.ci_prob,
                                              tested)
    ext_sim = _simulate(ext, ext_map.values, base.likelihood, s.substeps)
    off = dict(ext_map.values)
    off.update({p.name: p.null for p in eff.parameters if p.vary and p.null is not None})
    contribution = (ext_sim.position_m[0]
                    - _simulate(ext, off, base.likelihood, s.substeps).position_m[0])
    ext_sig = residual_signature(ext_lik, noise, ext_sim)
    energy, n = base.signature.energy, dataset.n_samples
    # with no excess over pure noise there is nothing to explain
    explained = (float(np.clip((energy - ext_sig.energy) * n / base.excess, 0.0, 1.0))
                 if energy > 1.0 else 0.0)
    nxt = None
    if explained < s.min_explained and not s.adequate(ext_sig):
        # one step of look-ahead: does another candidate account for what is left?
        following = [e for e in rank_effects(ext_lik, noise, ext_map.values,
                                             candidates=s.candidates, level=s.level)
                     if e.significant]
        nxt = max(following, key=lambda e: e.explained) if following else None
    diff = e_elpd_i - base.elpd_i
    return Refit(
        effect=effect, values=dict(ext_map.values), interval=interval,
        rms_m=ext_sig.bands[-1].rms_m, signature=ext_sig, explained=explained,
        elpd=e_elpd, elpd_diff=float(diff.sum()),
        elpd_diff_se=float(math.sqrt(diff.size * np.var(diff))),
        contribution_m=contribution, next_effect=nxt.effect if nxt else None,
        explained_with_next=explained + (1.0 - explained) * (nxt.explained if nxt else 0.0),
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
    dataset = base.likelihood.dataset
    base_resid = base.likelihood.y_mean - base.simulation.position_m[0]
    bands = input_bands(dataset)
    findings = []
    for ev in ranked:
        eff = get_effect(ev.effect)
        refit = refits.get(ev.effect)
        if refit is not None:
            estimate = {k: refit.values[k] for k in refit.interval}
            interval, explained = refit.interval, refit.explained
            contrib = _contribution_text(refit.contribution_m, base_resid, dataset.dt_s,
                                         bands)
        else:
            estimate, interval, explained, contrib = ev.estimate, ev.interval, ev.explained, ""
        findings.append(Finding(
            effect=ev.effect, evidence=ev.statistic, p_value=ev.p_value,
            significant=ev.significant, estimate=estimate, interval=interval,
            explained=explained, refit=refit,
            explanation=_explanation(eff, ev.statistic, ev.p_value, ev.significant,
                                     base.signature, refit, contrib, ci_prob),
        ))
    # refitted candidates first, by how well they predict left-out trials
    findings.sort(key=lambda f: (f.refit is None, -(f.refit.elpd if f.refit else f.evidence)))
    return findings


def _explaining(refits: dict, s: _Settings) -> list[Refit]:
    """The refits that account for the misfit and predict left-out trials better."""
    return [r for r in refits.values()
            if (max(r.explained, r.explained_with_next) >= s.min_explained
                or s.adequate(r.signature))
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


def diagnose(
    dataset: Dataset,
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
) -> Diagnosis:
    """Fit a model, criticise it and find which effect in the library is missing.

    1. The noise comes from the spread between trials and the model's MAP from
       the trial mean (:func:`pmabayes.fit.find_map`).
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

    Parameters
    ----------
    dataset : Dataset
        Repeated trials of one input.
    model : Model, optional
        The model to diagnose; the base model on the data's rig by default.
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

    Returns
    -------
    Diagnosis

    Raises
    ------
    ValueError
        On settings out of range.
    """

    s = _Settings(level=level, level_adequate=level_adequate,
                  energy_tolerance=energy_tolerance, max_refits=max_refits,
                  min_explained=min_explained, ci_prob=ci_prob, n_draws=n_draws,
                  substeps=substeps, candidates=None if candidates is None else tuple(candidates))
    say = Progress("diagnose", progress)
    rng = np.random.default_rng(seed)
    model = Model.for_dataset(dataset) if model is None else model
    if effects:
        model = model.with_effects(*[e for e in effects if e not in model.effect_names])
    name = " + ".join(["base", *model.effect_names])
    say.say(f"fitting {name} to {dataset.source or 'the data'} (MAP)")
    base = _fit_base(model, dataset, s, rng)
    say.say("ranking the candidate effects (score test)")
    ranked = rank_effects(base.likelihood, base.noise, base.values, candidates=s.candidates,
                          level=level)
    refits = _refit_significant(base, ranked, s, rng, say)
    findings = _findings(ranked, refits, base, ci_prob)
    adequate = s.adequate(base.signature)
    missing = _missing(refits, s)
    verdict = _verdict(name, model.effect_names, base.signature, adequate, missing, refits,
                       findings, min_explained, _twins(refits, missing, s))
    say.say(verdict)
    return Diagnosis(
        dataset=dataset, model=model, values=base.values, noise=base.noise,
        simulation=base.simulation, signature=base.signature, adequate=adequate,
        missing=missing, ranking=findings, elpd=base.elpd, verdict=verdict,
        settings={"level": level, "level_adequate": level_adequate,
                  "energy_tolerance": energy_tolerance, "max_refits": max_refits,
                  "min_explained": min_explained, "ci_prob": ci_prob, "n_draws": n_draws,
                  "seed": seed if isinstance(seed, int) else None, "substeps": substeps,
                  "candidates": [f.effect for f in findings]},
    )


def _verdict(name: str, effects: tuple, signature: Signature, adequate: bool,
             missing: str | None, refits: dict, findings: list, min_explained: float,
             twins: list | None = None) -> str:
    sig = (f"RMS error {signature.bands[-1].rms_m * 1e6:.4g} µm against a floor of "
           f"{signature.bands[-1].floor_m * 1e6:.4g} µm; whitened residual energy "
           f"{signature.energy:.3g} (p = {signature.energy_p:.2g}), Ljung-Box "
           f"p = {signature.ljung_box_p:.2g}")
    if missing is not None:
        r = refits[missing]
        tied = [t[0] for t in twins or ()]
        others = [f.effect for f in findings
                  if f.refit is not None and f.effect != missing and f.effect not in tied]
        text = (f"{name}: {missing} is missing ({sig}). Adding it lowers the RMS error to "
                f"{r.rms_m * 1e6:.4g} µm ({r.signature.ratio:.3g}x the floor) and removes "
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
            f", refit ΔELPD {f.refit.elpd_diff:+.1f} ± {f.refit.elpd_diff_se:.1f})"
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
        detail += (f", and at least {min_explained:.0%} is required (ΔELPD "
                   f"{best.elpd_diff:+.1f} ± {best.elpd_diff_se:.1f})")
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
    """

    labels: list
    bands: dict
    whiteness: dict
    innovations: dict
    elpd: dict
    elpd_steps: list
    command_rate: np.ndarray
    dt_s: float

    def whiteness_curves(self) -> WhitenessCurves:
        """The whiteness figure's curves of each fit (lags to 0.2 s, 99% bound)."""
        return whiteness_curves(self.innovations, self.command_rate, self.dt_s)

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {
            "fits": [
                {"label": k, "rms_m": self.bands[k][-1].rms_m,
                 "noise_floor_m": self.bands[k][-1].floor_m,
                 "ratio": self.bands[k][-1].ratio,
                 "bands": [b.to_dict() for b in self.bands[k]],
                 "whiteness": self.whiteness[k], "elpd": self.elpd[k]}
                for k in self.labels
            ],
            "elpd_steps": self.elpd_steps,
        }


def compare_fits(fits, dataset: Dataset, *, labels=None) -> FitComparison:
    """Compare fits of the same data: error per band, whiteness and ELPD.

    Parameters
    ----------
    fits : sequence of xarray.DataTree
        Fits written by :func:`pmabayes.fit.fit` (same data, different models).
    dataset : Dataset
        The data they were made from (checked against each fit).
    labels : sequence of str, optional
        Names of the fits; ``base + effect + ...`` from their models by default.

    Returns
    -------
    FitComparison

    Raises
    ------
    ValueError
        With fewer than two fits, labels that do not match, or a fit made from
        other data.
    """
    fits = list(fits)
    if len(fits) < 2:
        raise ValueError("compare needs at least two fits of the same data")
    models = [model_from_fit(t) for t in fits]
    if labels is None:
        labels = [" + ".join(["base", *m.effect_names]) for m in models]
    labels = list(labels)
    if len(labels) != len(fits) or len(set(labels)) != len(labels):
        raise ValueError(f"need {len(fits)} distinct labels, got {labels}")
    bands, white, innov = {}, {}, {}
    for label, tree, model in zip(labels, fits, models, strict=True):
        check_dataset(tree, dataset)
        bands[label], white[label], innov[label] = _map_residual(tree, model, dataset)
    elpd, steps = _loo_table(fits, labels)
    return FitComparison(labels=labels, bands=bands, whiteness=white, innovations=innov,
                         elpd=elpd, elpd_steps=steps,
                         command_rate=np.gradient(dataset.input[0], dataset.time_s),
                         dt_s=dataset.dt_s)


def _map_residual(tree, model: Model, dataset: Dataset):
    """Band errors, whiteness and whitened residual of a fit's MAP model."""
    info = fit_info(tree)
    substeps = int(info.get("substeps", 1))
    lik = Likelihood(model, dataset, substeps=substeps)
    vals = _model_values(model, info["map"]["values"])
    x = simulate_dataset(model, vals, dataset, substeps=substeps)[0]
    nz = info["noise"]
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
