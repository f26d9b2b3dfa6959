"""The diagnosed model and its refits: the shared MAP over the experiments, each
candidate added and refitted, judged by the residual it removes and by its
leave-one-trial-out ELPD (PSIS-LOO over Laplace draws), and the choice of the missing
one.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from pmabayes.criticism.bands import excess_removed
from pmabayes.criticism.elpd import LaplaceLoo, laplace_loo, paired_difference, plugin_difference
from pmabayes.criticism.experiments import experiment_conditions_table
from pmabayes.criticism.observed import counted_samples, residual, simulate_states
from pmabayes.criticism.plausibility import implausible
from pmabayes.criticism.results import Refit, pooled_rms
from pmabayes.criticism.scores import rank_effects
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.criticism.signature import residual_signature
from pmabayes.criticism.transfer import Transfer, leave_experiments_out
from pmabayes.inference.density import Posterior
from pmabayes.inference.disturbance import settle_disturbance
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.noise import NoiseEstimate, group_noise
from pmabayes.inference.search import find_map
from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation
from pmabayes.parallel import Runner, can_fork
from pmabayes.util import Progress, side_stream

__all__ = ["BaseFit", "fit_base", "refit_significant", "missing_effect", "partial_effect",
           "near_twins", "improves", "ranking_key", "refit_failure", "physical_values"]


def physical_values(model: Model, values: dict) -> dict:
    """The model's own parameters of a MAP's values (without the noise's).

    Parameters
    ----------
    model : Model
        The model.
    values : dict
        Values of its parameters and perhaps others (the noise's).

    Returns
    -------
    dict
        Those of ``values`` that are the model's parameters.
    """
    return {k: v for k, v in values.items() if k in model.parameter_names}


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
class BaseFit:
    """The diagnosed model at its MAP over the experiments: what each refit is measured
    against.

    Parameters
    ----------
    likelihoods : list of Likelihood
        One per experiment, each with the model on its rig.
    names : list of str
        The experiments' names.
    repeat_noise : list
        Each experiment's noise learnt from its repeats (None where it was identified
        with the model), as the refits keep it.
    noise_choices : list
        Each experiment's noise model.
    noises : list of NoiseEstimate
        Each experiment's noise at the MAP.
    values : dict
        The MAP.
    simulations : list of Simulation
        The model at the MAP in each experiment, with its states.
    signatures : list of Signature
        Each experiment's residual signature.
    elpd : float
        Leave-one-trial-out ELPD over every trial of every experiment.
    elpd_i : numpy.ndarray
        Its per-trial terms.
    points : list of tuple
        Each experiment's model values and estimated start (None where declared) at
        the MAP (:meth:`pmabayes.inference.density.Posterior.experiment_point`).
    trial_models : list
        Each experiment's per-trial model positions where its trials have their own
        inputs, else None.
    log_likelihood : float
        The log-likelihood at the MAP, over every experiment: a refit, which holds the
        model (its effect at its null), reaches at least this where its search succeeds.
    agreement : dict or None
        With several experiments, whether they agree on one parameter set, with each
        one's own estimates (:func:`pmabayes.inference.search.experiments_agreement`).
    loo : LaplaceLoo or None
        The ELPD's whole estimate: whether it is reliable (``note``, the Pareto
        k-hats) and the units' log likelihoods at the MAP (the refits' witness).
    """

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
    points: list = field(default_factory=list)
    trial_models: list = field(default_factory=list)
    log_likelihood: float = math.nan
    agreement: dict | None = None
    loo: LaplaceLoo | None = None

    @property
    def excess(self) -> float:
        """The whitened residual's energy above pure noise, summed over the samples
        counted (and the experiments)."""
        total = sum(sig.energy * n - n
                    for sig, n in zip(self.signatures, counts(self.likelihoods), strict=True))
        return max(total, 1e-12)

    @property
    def residuals(self) -> list[np.ndarray]:
        """Each experiment's trial mean minus the model (NaN where no trial is counted)."""
        return [residual(lik, sim.position_m[0])
                for lik, sim in zip(self.likelihoods, self.simulations, strict=True)]


def counts(likelihoods: list) -> list[int]:
    """Each experiment's samples of the trial mean that are data (counted)."""
    return [int(np.count_nonzero(counted_samples(lik))) for lik in likelihoods]


def _simulate(model: Model, point: tuple, likelihood: Likelihood, substeps: int
              ) -> tuple[Simulation, np.ndarray | None]:
    """The model at an experiment's point (values, start), its trial mean and trials."""
    values, start = point
    return simulate_states(likelihood, model, physical_values(model, values), start, substeps)


def fit_base(models: list, datasets: list, names: list, s: DiagnoseSettings,
             rng: np.random.Generator) -> BaseFit:
    """Noise from the spread between repeats, the shared MAP, the signatures and the ELPD.

    Parameters
    ----------
    models : list of Model
        The diagnosed model on each experiment's rig.
    datasets : list of Dataset
        The experiments.
    names : list of str
        Their names.
    s : DiagnoseSettings
        The settings (substeps, noise model, draws, ``ci_prob``).
    rng : numpy.random.Generator
        Seeds the global search and the Laplace draws.

    Returns
    -------
    BaseFit
    """
    liks = [Likelihood(m, ds, substeps=s.substeps) for m, ds in zip(models, datasets, strict=True)]
    noise_and_choice = [group_noise([lik], s.noise_model) for lik in liks]
    posterior, best = _fit_map(liks, [n for n, _ in noise_and_choice], names, rng,
                               [c for _, c in noise_and_choice], refer=True)
    # as the fit: a record's disturbance slow where that leaves the fit as it was; the
    # refits and score tests then share its bound through the data sets' metadata
    posterior, best = settle_disturbance(posterior, best, rng=side_stream(rng, 1))
    liks = posterior.likelihoods
    # as the fit: a record from rest's noise from its periods' residual at the MAP
    repeat_noise = list(posterior.group_noise)
    values = dict(best.values)
    noises = _experiment_noises(posterior, best)
    points = [posterior.experiment_point(e, values) for e in range(len(liks))]
    runs = [_simulate(lik.model, pt, lik, s.substeps) for lik, pt in zip(liks, points,
                                                                          strict=True)]
    sims = [sim for sim, _ in runs]
    signatures = [residual_signature(lik, noise, sim, model_trials_m=trials)
                  for lik, noise, (sim, trials) in zip(liks, noises, runs, strict=True)]
    loo = laplace_loo(posterior, best, rng, s.n_draws, s.ci_prob)
    return BaseFit(liks, names, repeat_noise, list(posterior.noise_choices), noises, values,
                   sims, signatures, loo.elpd, loo.elpd_i, points, [trials for _, trials in runs],
                   _map_log_likelihood(posterior, best), best.agreement, loo)


def _map_log_likelihood(posterior: Posterior, best) -> float:
    """The log-likelihood of a posterior at its MAP (over every experiment)."""
    _, ll, _ = posterior.evaluate(posterior.to_natural(np.asarray(best.z)[None]),
                                  return_x=False)
    return float(ll[0])


def refit_failure(base_log_likelihood: float, log_likelihood: float, effect: str
                  ) -> str | None:
    """Why a refit's numbers are not the effect's, or None when its search succeeded.

    The refit holds the diagnosed model (its effect at its null), so its MAP fits at
    least as well; a search that ends lower has failed (lost in its larger space), and
    its ELPD and errors would be read as the effect's.

    Parameters
    ----------
    base_log_likelihood : float
        The diagnosed model's log-likelihood at its MAP.
    log_likelihood : float
        The refit's at its MAP.
    effect : str
        The added effect.

    Returns
    -------
    str or None
    """
    if not math.isfinite(base_log_likelihood):
        return None  # nothing to hold it against
    if not math.isfinite(log_likelihood):
        return "its MAP does not simulate"
    gap = base_log_likelihood - log_likelihood
    if gap > max(1.0, 1e-6 * abs(base_log_likelihood)):
        return (f"its search ended at a log-likelihood {gap:.4g} below the model without "
                f"{effect}, which the refit holds (at the effect's null)")
    return None


def _refit(base: BaseFit, effect: str, s: DiagnoseSettings, rng: np.random.Generator) -> Refit:
    """Add one effect, refit over every experiment, and measure what it explains and how
    it predicts."""
    ext_liks = _extended(base, effect, s.substeps)
    ext = ext_liks[0].model
    eff = ext.effects[-1]
    if s.refit_search == "global":
        ext_post, ext_map = _fit_map(ext_liks, base.repeat_noise, base.names, rng,
                                     base.noise_choices, refer=False)
    else:
        ext_post = Posterior(ext_liks, base.repeat_noise, names=base.names,
                             noise_choices=base.noise_choices)
        ext_map = _nested_map(ext_post, base, eff, rng, s.refit_searches)
    tested = tuple(p.name for p in eff.parameters if p.vary and p.name in ext.free_names)
    loo = laplace_loo(ext_post, ext_map, rng, s.n_draws, s.ci_prob, tested)
    e_elpd, e_elpd_i, interval = loo.elpd, loo.elpd_i, loo.interval
    ext_noises = _experiment_noises(ext_post, ext_map)
    nulls = {p.name: p.null for p in eff.parameters if p.vary and p.null is not None}
    points = [ext_post.experiment_point(e, ext_map.values) for e in range(len(ext_liks))]
    sigs, contributions = [], []
    for lik, ext_lik, noise, (own, start) in zip(base.likelihoods, ext_liks, ext_noises, points,
                                                  strict=True):
        ext_sim, trials = _simulate(ext_lik.model, (own, start), lik, s.substeps)
        off = _simulate(ext_lik.model, ({**own, **nulls}, start), lik, s.substeps)[0]
        contributions.append(ext_sim.position_m[0] - off.position_m[0])
        sigs.append(residual_signature(ext_lik, noise, ext_sim, model_trials_m=trials))
    sizes = counts(base.likelihoods)
    # with no excess over pure noise there is nothing to explain
    gain = sum((b.energy - x.energy) * n
               for b, x, n in zip(base.signatures, sigs, sizes, strict=True))
    over = sum((b.energy - 1.0) * n for b, n in zip(base.signatures, sizes, strict=True))
    explained = float(np.clip(gain / base.excess, 0.0, 1.0)) if over > 0 else 0.0
    nxt = None
    # one step of look-ahead: does another candidate account for what is left? Only
    # the share judges it, and only where every experiment has a noise floor
    # (:func:`_explaining`); elsewhere it would compile and score every candidate for
    # nothing
    if (explained < s.min_explained and not s.all_adequate(sigs)
            and _has_floors(sigs)):
        following = [e for e in rank_effects(ext_liks, ext_noises, [own for own, _ in points],
                                             candidates=s.candidates, level=s.level,
                                             starts=[start for _, start in points])
                     if e.significant]
        nxt = max(following, key=lambda e: e.explained) if following else None
    diff, diff_se = paired_difference(e_elpd_i, base.elpd_i)
    plugin, plugin_se = (plugin_difference(loo, base.loo) if base.loo is not None
                         else (math.nan, math.nan))
    rms = pooled_rms([sig.bands[-1].rms_m for sig in sigs], sizes)
    removed = excess_removed([b.bands[-1].rms_m for b in base.signatures],
                             [x.bands[-1].rms_m for x in sigs],
                             [b.bands[-1].floor_m for b in base.signatures], sizes)
    return Refit(
        effect=effect, values=dict(ext_map.values), interval=interval,
        rms_m=rms, explained=explained, explained_rms=removed,
        adequate=s.all_adequate(sigs),
        elpd=e_elpd, elpd_diff=diff, elpd_diff_se=diff_se,
        contribution_m=np.concatenate(contributions), next_effect=nxt.effect if nxt else None,
        explained_with_next=explained + (1.0 - explained) * (nxt.explained if nxt else 0.0),
        signatures=tuple(sigs),
        elpd_i=e_elpd_i,
        implausible=implausible(ext, ext_map.values, tested,
                                [lik.dataset for lik in base.likelihoods], refit=True),
        failed=refit_failure(base.log_likelihood, _map_log_likelihood(ext_post, ext_map),
                             effect),
        agreement=ext_map.agreement,
        elpd_note=_difference_note(loo, base.loo),
        plugin_diff=plugin, plugin_diff_se=plugin_se, loo=loo,
    )


def _extended(base: BaseFit, effect: str, substeps: int) -> list[Likelihood]:
    """Each experiment's likelihood with ``effect`` added to its model, under its noise."""
    ext_liks = [Likelihood(lik.model.with_effects(effect), lik.dataset, substeps=substeps)
                for lik in base.likelihoods]
    for ext, lik in zip(ext_liks, base.likelihoods, strict=True):
        ext.use_noise(lik.noise)
    return ext_liks


def _nested_map(posterior: Posterior, base: BaseFit, effect, rng: np.random.Generator,
                searches: int = 1):
    """The refit's MAP: ``searches`` global searches, and polishes from the diagnosed model's MAP,
    which the refit nests, with the effect at its null and at its default (a step away
    from a null that is a flat point); the highest kept, so the refit's likelihood is
    at least the model's wherever a polish climbs. Each experiment's own MAP (the
    agreement test, and a start of the joint polish) likewise: one search, and polishes
    from its own under the model (:func:`pmabayes.inference.search.find_map`'s
    ``starts`` and ``own``)."""
    starts = _starts_at(posterior, base.values, effect)
    own = None
    if base.agreement is not None and posterior.n_experiments > 1:
        mine = base.agreement["experiments"]
        own = [_starts_at(posterior.alone(e), {n: z[0] for n, z in mine[name]["z_own"].items()},
                          effect, unconstrained=True)
               for e, name in enumerate(posterior.experiment_names)]
    return find_map(posterior, rng=rng, refer=False, searches=searches, starts=starts,
                    own=own)


def _starts_at(posterior: Posterior, known: dict[str, float], effect, *,
               unconstrained: bool = False) -> np.ndarray:
    """Two natural starts at the parameters' defaults, with ``known``'s values where it
    names a column (given in unconstrained coordinates where ``unconstrained``), and the
    effect's parameters at their null in the first and their default in the second."""
    row = np.array([[p.default for p in posterior.parameters]])
    if unconstrained:
        row = posterior.to_unconstrained(row)
    for j, name in enumerate(posterior.names):
        if name in known:
            row[0, j] = known[name]
    if unconstrained:
        row = posterior.to_natural(row)
    return _at_null(posterior, np.repeat(row, 2, axis=0), effect)


def _at_null(posterior: Posterior, starts: np.ndarray, effect) -> np.ndarray:
    """``starts`` (two rows, natural) with the effect's parameters at their null in the
    first row and at their default in the second, in every experiment; changed in place."""
    for p in effect.parameters:
        for ident in posterior.identified:
            name = ident.get(p.name)
            if name is None or name not in posterior.names:
                continue
            j = posterior.names.index(name)
            starts[0, j] = p.default if p.null is None else p.null
            starts[1, j] = p.default
    return starts


def _difference_note(refit: LaplaceLoo, base: LaplaceLoo | None) -> str | None:
    """Why a refit's ΔELPD is not reliable, in a few words (each estimate's whole reason
    is in its :class:`~pmabayes.criticism.elpd.LaplaceLoo`): the largest Pareto k-hat of
    the refit's and of the model's draws against the threshold, and a Laplace
    covariance that is a stand-in; None when both estimates are reliable."""
    both = [(who, loo) for who, loo in (("refit", refit), ("model", base))
            if loo is not None and loo.note]
    if not both:
        return None
    parts, ks = [], []
    for who, loo in both:
        k = np.nanmax([loo.pareto_k, loo.correction_k, -np.inf])
        if k > loo.good_k:
            ks.append(f"{k:.2f} ({who})")
        if not math.isfinite(loo.elpd):
            parts.append(f"the {who}'s ELPD is not estimable")
        stand_in = loo.note.split("; ")[0] if "is a stand-in" in loo.note else None
        if stand_in:
            parts.append(f"the {who}'s {stand_in.removeprefix('the ')}")
    if ks:
        good = min(loo.good_k for _, loo in both)
        parts.insert(0, f"Pareto k-hat of the draws' importance weights {', '.join(ks)}, "
                        f"above {good:.2f}")
    return "; ".join(parts) or "; ".join(loo.note for _, loo in both)


def refit_significant(base: BaseFit, ranked: list, s: DiagnoseSettings,
                      rng: np.random.Generator, progress: Progress) -> dict[str, Refit]:
    """Refit the strongest significant candidates, ``max_refits`` of them; where none of
    those is named (missing, or a partial step), the next ``max_refits`` once.

    Parameters
    ----------
    base : BaseFit
        The diagnosed model.
    ranked : list of EffectEvidence
        The candidates' score tests, most evidence first.
    s : DiagnoseSettings
        The settings.
    rng : numpy.random.Generator
        Seeds the refits' searches and draws: each refit has its own stream spawned
        from it, so the numbers do not depend on ``s.processes``.
    progress : Progress
        Says which refits are running, and where.

    Returns
    -------
    dict
        Effect name to its :class:`~pmabayes.criticism.results.Refit`.
    """
    significant = [e.effect for e in ranked if e.significant]
    size = int(s.max_refits)
    refits: dict[str, Refit] = {}
    check = _TransferCheck(base, s, rng, progress) if leaves_out(base, s) else None
    # the score test is first order: where none of its strongest candidates, refitted,
    # is named, the next ones are refitted (once), before the verdict gives up
    for batch in (significant[:size], significant[size:2 * size]):
        if not batch or (refits and named(refits, s)):
            break
        refits.update(_refit_batch(base, batch, s, rng, progress))
        if check is not None:
            check.until_one_carries(refits)
    return refits


def named(refits: dict, s: DiagnoseSettings) -> str | None:
    """The effect a diagnosis names: the missing one, else the best partial step.

    Parameters
    ----------
    refits, s
        As :func:`missing_effect`'s.

    Returns
    -------
    str or None
        :func:`missing_effect`, else :func:`partial_effect`.
    """
    return missing_effect(refits, s) or partial_effect(refits)


def leaves_out(base: BaseFit, s: DiagnoseSettings) -> bool:
    """Whether the candidates named are checked on each experiment left out in turn
    (:attr:`DiagnoseSettings.leave_experiments_out`; by default where two or more
    experiments differ in a declared condition).

    Parameters
    ----------
    base : BaseFit
        The diagnosed model.
    s : DiagnoseSettings
        The settings.

    Returns
    -------
    bool
    """
    if s.leave_experiments_out is False or len(base.likelihoods) < 2:
        return False
    return bool(s.leave_experiments_out) or bool(
        experiment_conditions_table([lik.dataset for lik in base.likelihoods]))


class _TransferCheck:
    """Leaves each experiment out for the model once, and for each candidate about to be
    named, until one predicts them better (or none is left to name)."""

    def __init__(self, base: BaseFit, s: DiagnoseSettings, rng: np.random.Generator,
                 progress: Progress) -> None:
        self.base, self.s, self.progress = base, s, progress
        self.rng = side_stream(rng, 2)  # the refits' streams stay as they were
        self.model_nrmse: tuple[float, ...] | None = None

    def _left_out(self, likelihoods: list, values: dict) -> tuple[float, ...]:
        b = self.base
        return leave_experiments_out(likelihoods, b.repeat_noise, b.names, b.noise_choices,
                                     values, substeps=self.s.substeps,
                                     rng=self.rng.spawn(1)[0], processes=self.s.processes)

    def until_one_carries(self, refits: dict[str, Refit]) -> None:
        """Check the effect named, in place, until one carries or none is named."""
        while (name := named(refits, self.s)) is not None and refits[name].transfer is None:
            if self.model_nrmse is None:
                self.progress.say("leaving each experiment out in turn: the model")
                self.model_nrmse = self._left_out(self.base.likelihoods, self.base.values)
            self.progress.say(f"leaving each experiment out in turn: with {name}")
            nrmse = self._left_out(_extended(self.base, name, self.s.substeps),
                                   refits[name].values)
            refits[name] = dataclasses.replace(refits[name], transfer=Transfer(
                tuple(self.base.names), self.model_nrmse, nrmse))


def _refit_batch(base: BaseFit, chosen: list[str], s: DiagnoseSettings,
                 rng: np.random.Generator, progress: Progress) -> dict[str, Refit]:
    """Refit each of ``chosen`` in worker processes (or here), each on its own stream."""
    # the workers are forked, and read the model from here rather than be sent it
    processes = s.processes if can_fork() else 1
    _REFIT_JOB[:] = [(base, s)]
    try:
        with Runner(processes, tasks=len(chosen)) as runner:
            progress.say(f"refitting with {', '.join(chosen)} ({runner.description})")
            done = list(runner.map(_refit_task, zip(chosen, rng.spawn(len(chosen)),
                                                    strict=True)))
    finally:
        _REFIT_JOB.clear()
    return dict(zip(chosen, done, strict=True))


#: the diagnosed model and the settings of the refits running (a forked worker inherits
#: them: a model with its data sets is not pickled for each candidate)
_REFIT_JOB: list = []


def _refit_task(job: tuple[str, np.random.Generator]) -> Refit:
    """One candidate's refit, in a worker or here: ``(effect, its own stream)``."""
    effect, rng = job
    base, s = _REFIT_JOB[0]
    return _refit(base, effect, s, rng)


def improves(refit: Refit) -> bool:
    """Whether a refit clearly predicts held-out data better than the model without it.

    Its ELPD (leaving out trials, or stretches of a single record) rises by more than
    two standard errors of the paired difference, a real one (not NaN); the refit's
    search did not fail (:attr:`~pmabayes.criticism.results.Refit.failed`) and its
    estimates are physics (:mod:`~pmabayes.criticism.plausibility`). A ΔELPD whose
    estimate is not reliable (:attr:`~pmabayes.criticism.results.Refit.elpd_note`: the
    Pareto k-hats of its importance weights) does not decide on its own: the in-sample
    log likelihoods at the two MAPs, less the added parameters
    (:func:`pmabayes.criticism.elpd.plugin_difference`), must also rise by more than two
    of their standard errors. Where experiments were left out in turn
    (:attr:`~pmabayes.criticism.results.Refit.transfer`), the refit must also predict
    them better on average (:attr:`~pmabayes.criticism.results.Refit.carries`).

    Parameters
    ----------
    refit : Refit
        A candidate refitted, with its ELPD, its witness and its checks.

    Returns
    -------
    bool
        True where it clearly predicts held-out data better.
    """
    return bool(refit.failed is None and refit.implausible is None
                and math.isfinite(refit.elpd_diff) and math.isfinite(refit.elpd_diff_se)
                and refit.elpd_diff > 2.0 * refit.elpd_diff_se and refit.witnessed
                and refit.carries)


def ranking_key(refit: Refit) -> tuple:
    """The order of refits wherever they are ranked (the list, the verdict, the missing
    one): by ELPD gain, a failed or not estimable one last.

    Parameters
    ----------
    refit : Refit
        One refitted candidate.

    Returns
    -------
    tuple
        A sort key: smaller ranks first.
    """
    usable = refit.failed is None and math.isfinite(refit.elpd_diff)
    return (not usable, -refit.elpd_diff if usable else 0.0)


def _has_floors(signatures) -> bool:
    """Whether every experiment of these residual signatures has a noise floor."""
    return all(math.isfinite(sig.bands[-1].floor_m) for sig in signatures)


def _floors(refits: dict) -> bool:
    """Whether every experiment has a noise floor (else none of the shares means much)."""
    return all(_has_floors(r.signatures) for r in refits.values())


def _explaining(refits: dict, s: DiagnoseSettings) -> list[Refit]:
    """The refits that predict held-out data clearly better (:func:`improves`) and
    account for the misfit: the refit is adequate, or it removes at least
    ``min_explained`` of the excess alone or with the candidate its own score test finds
    next; where the ΔELPD has no standard error, a positive one
    (:func:`_gains_without_se`), as the floor judges the share. Only where every
    experiment has a floor: without one (a record without
    repeats) the noise is identified with each model and takes in what the model
    leaves, so neither the share nor the adequacy says that the misfit is accounted for
    (:func:`partial_effect` names the best step there)."""
    if not _floors(refits):
        return []
    return [r for r in refits.values() if (improves(r) or _gains_without_se(r))
            and (max(r.explained, r.explained_with_next) >= s.min_explained
                 or s.all_adequate(r.signatures))]


def _gains_without_se(refit: Refit) -> bool:
    """A refit whose ΔELPD is positive but has no standard error (one left-out unit: a
    single periodic record, whose noise from its periods cannot leave a stretch out).
    With a noise floor, the floor then judges it: :func:`_explaining` also asks that it
    account for the misfit."""
    return bool(refit.failed is None and refit.implausible is None
                and math.isfinite(refit.elpd_diff) and not math.isfinite(refit.elpd_diff_se)
                and refit.elpd_diff > 0.0 and refit.witnessed and refit.carries)


def missing_effect(refits: dict, s: DiagnoseSettings) -> str | None:
    """The refit that accounts for the misfit and predicts left-out trials best, if any.

    Parameters
    ----------
    refits : dict
        Effect name to refit.
    s : DiagnoseSettings
        The settings (``min_explained``, adequacy).

    Returns
    -------
    str or None
    """
    explaining = _explaining(refits, s)
    return min(explaining, key=ranking_key).effect if explaining else None


def partial_effect(refits: dict, missing: str | None = None) -> str | None:
    """The best partial step when nothing is named missing: the top-ranked refit that
    clearly predicts held-out data better (:func:`improves`) without accounting for all
    of the misfit (or, without a floor, without a way to tell whether it does).

    Parameters
    ----------
    refits : dict
        Effect name to refit.
    missing : str, optional
        The effect named missing; then there is no partial step (None).

    Returns
    -------
    str or None
    """
    if missing is not None:
        return None
    helping = [r for r in refits.values() if improves(r)]
    return min(helping, key=ranking_key).effect if helping else None


def near_twins(refits: dict, missing: str | None, s: DiagnoseSettings
               ) -> list[tuple[str, float, float]]:
    """The other explaining refits whose ELPD is within two standard errors of the
    missing one's (paired over trials), or above that only by an estimate that is not
    reliable and that the in-sample witness does not confirm.

    Parameters
    ----------
    refits : dict
        Effect name to refit.
    missing : str or None
        The effect found missing.
    s : DiagnoseSettings
        The settings.

    Returns
    -------
    list of tuple
        ``(effect, ELPD difference, its standard error)`` of each near twin.
    """
    if missing is None or refits[missing].elpd_i is None:
        return []
    best, out = refits[missing], []
    for r in _explaining(refits, s):
        if r.effect == missing or r.elpd_i is None:
            continue
        diff, se = paired_difference(best.elpd_i, r.elpd_i)
        if diff <= 2.0 * se or not _told_apart_in_sample(best, r):
            out.append((r.effect, diff, se))
    return out


def _told_apart_in_sample(a: Refit, b: Refit) -> bool:
    """Whether ``a``'s ELPD above ``b``'s may be read as it stands: both estimates are
    reliable, or their in-sample witness (:func:`pmabayes.criticism.elpd.plugin_difference`)
    also puts ``a`` above by more than two standard errors."""
    if not any(r.loo is not None and r.loo.note for r in (a, b)):
        return True
    if a.loo is None or b.loo is None:
        return False
    d, se = plugin_difference(a.loo, b.loo)
    return bool(d > 2.0 * se)
