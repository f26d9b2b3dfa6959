"""The MAP, as the paper found its point estimate: a global search (differential
evolution, the paper's GlobalSearch) on the RMS error of the trial mean over the prior's
plausible region, then a local polish (L-BFGS-B, the paper's fmincon) of the negative
log posterior, and the Laplace approximation there. A second global search on a spawned
stream is kept only where it finds another, lower basin. Records from rest have their
noise referred to the model at the MAP (:func:`pmabayes.inference.noise_start.refer_periods`)
until the MAP settles. A joint fit of several experiments also starts from each
experiment's own MAP, keeps the highest, and tests whether the experiments agree on one
parameter set (:func:`experiments_agreement`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.optimize import differential_evolution, minimize
from scipy.stats import chi2

from pmabayes.inference.density import Posterior
from pmabayes.inference.errors import FitError
from pmabayes.inference.laplace import (
    PROBE_STEP,
    _fd_diagonal,
    _scaled_hessian,
    laplace_covariance,
)
from pmabayes.inference.likelihood import LEVEL_ADEQUATE, JointLikelihood, Likelihood, span
from pmabayes.inference.noise_start import _default_noise_z, _noise_start, refer_periods
from pmabayes.model.nested import static_line_values
from pmabayes.model.simulator import position_reference
from pmabayes.util import Progress

__all__ = ["MapResult", "find_map", "polish_map", "experiments_agreement", "disagreement_text",
           "fit_quality", "static_lines", "POOR_FIT_SHARE"]


@dataclass
class MapResult:
    """Point estimates.

    Parameters
    ----------
    values : dict
        MAP in natural units, for every identified parameter (the noise
        parameters at their mode from the deviations).
    log_posterior : float
        Log posterior density of the model parameters at the MAP (natural
        coordinates, trial-mean likelihood given the noise).
    rms_cost_m : float
        The paper's cost (RMS of trial mean minus model) at the MAP.
    global_values : dict
        The global search's optimum of the RMS cost (model parameters only).
    global_rms_cost_m : float
        The RMS cost there.
    z : numpy.ndarray
        MAP in unconstrained coordinates.
    covariance_z : numpy.ndarray
        Laplace covariance in unconstrained coordinates (inverse negative Hessian).
    period_reference_z : numpy.ndarray or None
        Where the periods of records from rest were last referred to the model
        (:func:`refer_periods`: the MAP of the pass before) before the noise was
        learnt again and the MAP polished again; None where no record needed it. A
        resumed fit rebuilds its noise from it.
    agreement : dict or None
        For several experiments, whether they agree on one parameter set
        (:func:`experiments_agreement`) and which start the MAP came from; None for
        one experiment, or where the own optima were not searched.
    disturbance : list of dict or None
        Per experiment, the metadata a record's slow-disturbance check added
        (:func:`pmabayes.inference.disturbance.settle_disturbance`), or None; None
        where no check ran. A resumed fit rebuilds its posterior from it.
    quality : dict or None
        How well the MAP describes the data beside the nested yardsticks
        (:func:`fit_quality`): its RMS cost, the motion, the RMS cost of the best
        static line and of the mean alone, whether the search started from the line's
        nested model, and the words a poor fit is reported with.
    laplace_note : str or None
        Why ``covariance_z`` is a stand-in and not the inverse Hessian (a Hessian that
        is not finite, or not positive definite once measured again:
        :func:`pmabayes.inference.laplace.laplace_covariance`); None where it is the
        inverse Hessian. What reads the covariance as the posterior's (the ELPD of
        :func:`pmabayes.criticism.elpd.laplace_loo`) says so.
    """

    values: dict
    log_posterior: float
    rms_cost_m: float
    global_values: dict
    global_rms_cost_m: float
    z: np.ndarray
    covariance_z: np.ndarray
    period_reference_z: np.ndarray | None = None
    agreement: dict | None = None
    disturbance: list | None = None
    quality: dict | None = None
    laplace_note: str | None = None

    def record(self) -> dict:
        """Everything, JSON-ready (arrays as lists), for the chains folder's stamp."""
        out = dict(self.__dict__)
        out["z"] = self.z.tolist()
        out["covariance_z"] = self.covariance_z.tolist()
        if self.period_reference_z is not None:
            out["period_reference_z"] = self.period_reference_z.tolist()
        return out

    @classmethod
    def from_record(cls, record: dict) -> MapResult:
        """The inverse of :meth:`record`."""
        ref = record.get("period_reference_z")
        return cls(**{**record, "z": np.array(record["z"]),
                      "covariance_z": np.array(record["covariance_z"]),
                      "period_reference_z": None if ref is None else np.array(ref)})

    def summary(self) -> dict:
        """The ``map`` entry of a fit's metadata."""
        out = {"values": self.values, "log_posterior": self.log_posterior,
               "rms_cost_m": self.rms_cost_m,
               "global_search": {"values": self.global_values,
                                 "rms_cost_m": self.global_rms_cost_m}}
        if self.agreement is not None:
            out["agreement"] = self.agreement
        if self.quality is not None:
            out["quality"] = self.quality
        if self.laplace_note is not None:
            out["laplace_note"] = self.laplace_note
        return out


#: Differential evolution's mutation strategy. ``currenttobest1bin`` moves every
#: member towards the best while keeping its own place, which keeps the population
#: spread over basins for longer than ``best1bin``: on a model with a 45 ms regulator
#: lag, where tau_reg trades off against alpha and K_e, ``best1bin`` alone landed in
#: a wrong basin in 3 of 12 seeds and ``currenttobest1bin`` in none.
_DE_STRATEGY = "currenttobest1bin"


#: The search stops when the population's RMS costs spread by at most this fraction
#: of their mean (scipy's ``tol``): the whole population is then in one basin, and
#: the local polish, not more generations, finds its bottom. Stopped so, it found
#: the right basin on 12 of 12 data sets of that lagged model (README, Speed).
_DE_TOL = 0.01


def find_map(
    posterior: Posterior,
    *,
    rng: np.random.Generator,
    popsize: int = 15,
    maxiter: int = 300,
    refer: bool = True,
    own_starts: bool = True,
    searches: int = 2,
    starts: np.ndarray | None = None,
    own: list[np.ndarray] | None = None,
) -> MapResult:
    """Global search on the paper's RMS cost, then the MAP by local polish.

    The global search is differential evolution (strategy ``currenttobest1bin``)
    over the prior's plausible box of the model's parameters, any estimated start at
    its prior means; its cost skips the samples not observed. It stops when the whole
    population has come together in one basin (the spread of its costs at most 1% of
    their mean), or after ``maxiter`` generations. A noise sampled with the model (no repeats) is
    not searched, since the cost does not depend on it: it starts at its mode
    given the search's optimum (:func:`_noise_start`). The optimum is polished
    (L-BFGS-B, then Newton steps whose Hessian gives the Laplace covariance).
    Where a periodic record starts from rest, or trials have their own inputs, their
    noise is then learnt again from their repeats' residual at that MAP
    (:func:`refer_periods`), and the MAP polished again under that noise, until a
    pass moves the MAP by less than 1% of its sd (at most six passes).

    The base model contains the linear lags that draw the best static line of
    position on input (:mod:`pmabayes.model.nested`); where one of them explains the
    data better than the search's optimum, the polish starts from it instead. A
    search whose population agrees at once on a model that explains no more than the
    data's mean is run again over a box three times as wide.

    With several experiments, the joint search's optimum can lie in another basin
    than each experiment's own (a loaded rig's sine and an unloaded chirp traded
    ``K_e`` against ``alpha``). So each experiment's own MAP is found first (its data
    alone, the same search), the joint MAP is polished from each of them as well as
    from the joint search's optimum, and the highest is kept. The experiments'
    agreement is then tested (:func:`experiments_agreement`).

    Parameters
    ----------
    posterior : Posterior
        The target; a record from rest's noise is updated in place.
    rng : numpy.random.Generator
        Seeds the global search.
    popsize : int
        Differential evolution population per dimension.
    maxiter : int
        Differential evolution generations at most.
    refer : bool
        Learn the noise of records from rest again at the MAP (:func:`refer_periods`).
        False keeps the posterior's noise as given: candidates compared by their
        likelihood must share one noise, or a wrong model's misfit, taken into its
        own noise, would raise its likelihood (:func:`pmabayes.criticism.diagnosis.diagnose`'s
        refits).
    own_starts : bool
        With several experiments, also start from each experiment's own MAP and test
        their agreement. False searches the joint posterior alone (as before).
    searches : int
        Global searches, each on its own stream (1 or 2).
    starts : numpy.ndarray or None
        Natural points ``(k, ndim)`` polished as well as the search's optimum, the
        highest kept: for example a model this posterior's nests, at its MAP, with
        the added parameters at their null (:func:`pmabayes.criticism.diagnose`'s
        refits). A value with no unconstrained coordinate (0 on a log scale) starts
        at the plausible box's edge.
    own : list of numpy.ndarray or None
        With several experiments, each one's ``starts`` for the search of its own MAP
        (``searches`` searches, as here).

    Returns
    -------
    MapResult
        The optimum, its searches' records and the fit's quality and agreement.

    Raises
    ------
    FitError
        If no parameter set in the plausible region gives a finite simulation, or
        the data show a sign or a scale that no model of this kind explains
        (:func:`fit_quality`). A poor fit, and experiments that disagree
        (:func:`disagreement_text`), are not errors: the result records them
        (``quality``, ``agreement``) and :func:`pmabayes.fit` warns.
    """
    box = posterior.plausible_box(rng, posterior.names)
    # the search's cost does not depend on a sampled noise: searched over the model's
    # parameters, it then starts the noise from the optimum's residual
    # an estimated start stays at its prior means (the first samples' line, the balance
    # of forces) in the search, and is polished with the rest: searched too, its three
    # dimensions per segment left a two-segment record in wrong basins on 4 of 4 seeds
    # (RMS 400-580 um against 20.5 um found so on 2 of 2; noise 20 um)
    n_model = posterior.n_model
    say = Progress()
    z_model, global_cost = _global_search(posterior, box[:n_model], rng, popsize, maxiter,
                                          say, f"1 of {searches}")
    # a second search on its own stream (spawning leaves rng's draws as they were): a
    # short record can hold a second basin of the hysteresis loop's shape (beta and
    # gamma traded at a near-constant beta + gamma), where one search may end
    if searches > 1:
        z_other, other_cost = _global_search(posterior, box[:n_model], rng.spawn(1)[0],
                                             popsize, maxiter, say, "2 of 2")
        if other_cost < (1.0 - _OTHER_BASIN) * global_cost:
            z_model, global_cost = z_other, other_cost
    say.end()
    say.say("polishing the MAP (L-BFGS-B, then Newton steps for the Laplace covariance)")
    # the base physics contains the static line (a linear lag): a search that ends worse
    # than it has failed, so the polish starts from the line's nested model instead
    z_model, global_cost, nested = _nested_start(posterior, box, z_model, global_cost)
    z_global = _noise_start(posterior, np.concatenate([z_model,
                                                       _default_noise_z(posterior, n_model)]))
    # optimise in coordinates scaled to the plausible box
    scale = box[:, 1] - box[:, 0]
    best = _polish_from(posterior, z_global, scale)
    if starts is not None:
        best = _best_polish(posterior, scale, [*_starts_z(posterior, box, starts)], best)
    agreement_of = None
    if posterior.n_experiments > 1 and (own is not None or own_starts):
        results = _own_optima(posterior, rng.spawn(1)[0], popsize, maxiter, searches, own)
        best, agreement_of = _best_of_starts(posterior, best, results, scale)
    z_map, cov_z, note = best
    return _finish(posterior, z_map, cov_z, note, scale, rng, refer=refer,
                   global_point=(z_global, global_cost), agreement_of=agreement_of,
                   nested_start=nested)


def polish_map(posterior: Posterior, theta: np.ndarray, *, rng: np.random.Generator,
               refer: bool = True) -> MapResult:
    """The MAP polished from given points instead of a global search.

    For a posterior that differs from one already searched only where the search
    does not look (a sampled noise's bounds; :mod:`pmabayes.inference.disturbance`):
    the polish, the noise learnt again at it (``refer``) and the fit's quality check
    run as in :func:`find_map`. A value with no unconstrained coordinate (0 on a log
    scale) starts at the prior's plausible box's edge.

    Parameters
    ----------
    posterior : Posterior
        The target.
    theta : numpy.ndarray
        The start, natural units, one value per ``posterior.names``; or several starts,
        one per row, each polished and the highest kept. The first is the result's
        global-search record.
    rng : numpy.random.Generator
        Seeds the plausible box (the polish's scale) and the climb out of a saddle.
    refer : bool
        As :func:`find_map`'s.

    Returns
    -------
    MapResult
        The highest polished start.

    Raises
    ------
    FitError
        As :func:`find_map`.
    """
    box = posterior.plausible_box(rng, posterior.names)
    scale = box[:, 1] - box[:, 0]
    first, *rest = _starts_z(posterior, box, theta)
    _, _, x = posterior.evaluate(posterior.to_natural(first[None]))
    cost = (float(posterior.likelihood.rms_cost(np.atleast_2d(x[0]))[0]) if x is not None
            else math.inf)
    z_map, cov_z, note = _best_polish(posterior, scale, rest,
                                      _polish_from(posterior, first, scale))
    return _finish(posterior, z_map, cov_z, note, scale, rng, refer=refer,
                   global_point=(first, cost), agreement_of=None)


def _starts_z(posterior: Posterior, box: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Natural starts ``theta`` (one row, or several) in unconstrained coordinates, a
    value with none (an effect's null at the end of a log scale) at the plausible
    ``box``'s nearer edge (unconstrained, one row per ``posterior.names``), and a sampled
    noise at its mode given the start's model (as after the search: from where another
    bound held it, a polish can stay there)."""
    z = posterior.to_unconstrained(np.atleast_2d(np.asarray(theta, dtype=float)))
    z = np.where(np.isfinite(z), z, np.where(z < 0, box[:, 0], box[:, 1]))
    return np.array([_noise_start(posterior, row) for row in z])


def _best_polish(posterior: Posterior, scale: np.ndarray, starts, best: _Polished
                 ) -> _Polished:
    """The highest, by log posterior, of ``best`` and the polishes from each
    unconstrained start in ``starts``."""
    lp = float(posterior.log_prob_z(best.z[None])[0])
    for z0 in starts:
        polished = _polish_from(posterior, z0, scale)
        lp_k = float(posterior.log_prob_z(polished.z[None])[0])
        if lp_k > lp or not math.isfinite(lp):
            best, lp = polished, lp_k
    return best


def _finish(posterior: Posterior, z_map: np.ndarray, cov_z: np.ndarray, note: str | None,
            scale: np.ndarray, rng: np.random.Generator, *, refer: bool, global_point: tuple,
            agreement_of: tuple | None, nested_start: bool = False) -> MapResult:
    """A polished MAP's noise learnt again, its climb out of saddles, its quality check
    and its record (:func:`find_map`, :func:`polish_map`); ``note`` says why ``cov_z``
    is a stand-in (None where it is the inverse Hessian)."""
    z_global, global_cost = global_point
    # the periods of a record from rest still hold the model's shakedown: the noise
    # is learnt again from the residual's periods, and the MAP polished again, until
    # the MAP settles (a first MAP under the inflated noise misses the drift)
    reference = None
    for k in range(_REFER_PASSES if refer else 0):
        if not refer_periods(posterior, z_map):
            break
        reference = z_map
        z_map, cov_z, note = _polish_from(posterior, reference, scale)
        moved = np.max(np.abs(z_map - reference) / np.sqrt(np.diag(cov_z)))
        if k > 0 and moved < _REFER_SETTLED:
            break
    z_map, cov_z, note = _climb(posterior, z_map, cov_z, note, scale, rng.spawn(1)[0])
    theta_map = posterior.to_natural(z_map[None])
    lp, ll, x = posterior.evaluate(theta_map)
    if x is None or not np.isfinite(ll[0]):
        raise FitError(_no_map_message(posterior, theta_map[0]))
    agreement = None
    if agreement_of is not None:
        own, best_start = agreement_of
        agreement = {**experiments_agreement(posterior, z_map, own), "start": best_start}
    quality = fit_quality(posterior.likelihood, x[0], nested_start=nested_start)
    cost = quality["rms_cost_m"]
    values = dict(zip(posterior.names, map(float, theta_map[0]), strict=True))
    values.update(posterior.noise_values(theta_map[0]))
    return MapResult(
        values=values,
        log_posterior=float(lp[0] + ll[0]),
        rms_cost_m=cost,
        global_values=dict(zip(posterior.names, map(float, posterior.to_natural(
            z_global[None])[0]), strict=True)),
        global_rms_cost_m=global_cost,
        z=z_map,
        covariance_z=cov_z,
        period_reference_z=reference,
        agreement=agreement,
        quality=quality,
        laplace_note=note,
    )


def _own_optima(posterior: Posterior, rng: np.random.Generator, popsize: int,
                maxiter: int, searches: int = 2, starts: list | None = None
                ) -> list[MapResult]:
    """Each experiment's own MAP (:func:`find_map` on its data alone, its noise kept,
    with its ``starts`` where given), each search on its own stream spawned from
    ``rng``."""
    starts = starts if starts is not None else [None] * posterior.n_experiments
    return [find_map(posterior.alone(e), rng=r, popsize=popsize, maxiter=maxiter,
                     refer=False, searches=searches, starts=start)
            for e, (r, start) in enumerate(zip(rng.spawn(posterior.n_experiments), starts,
                                               strict=True))]


def _joint_point(posterior: Posterior, z_joint: np.ndarray, experiment: int,
                 own: MapResult) -> np.ndarray:
    """The joint coordinates ``z_joint`` with an experiment's own MAP's values for its
    model's parameters and its start (the others' own parameters kept), its sampled
    noise started again from the residual there."""
    theta = posterior.to_natural(z_joint[None])[0]
    lik = posterior.likelihoods[experiment]
    ident = posterior.identified[experiment]
    for n in lik.model.free_names:
        theta[posterior.names.index(ident[n])] = own.values[n]
    for c, p in zip(posterior.start_columns.get(experiment, []), lik.start_parameters(),
                    strict=True):
        theta[c] = own.values[p.name]
    return _noise_start(posterior, posterior.to_unconstrained(theta[None])[0])


def _best_of_starts(posterior: Posterior, joint: _Polished, own: list[MapResult],
                    scale: np.ndarray) -> tuple[_Polished, tuple]:
    """The highest of the joint MAP and the joint MAPs polished from each
    experiment's own MAP, and the own MAPs with which start it came from
    (:func:`_finish`'s ``agreement_of``)."""
    best = (float(posterior.log_prob_z(joint.z[None])[0]), joint, "joint search")
    for e, result in enumerate(own):
        polished = _polish_from(posterior, _joint_point(posterior, joint.z, e, result), scale)
        lp = float(posterior.log_prob_z(polished.z[None])[0])
        if lp > best[0]:
            best = (lp, polished, f"own MAP of {posterior.experiment_names[e]}")
    return best[1], (own, best[2])


def experiments_agreement(posterior: Posterior, z_map: np.ndarray,
                          own: list[MapResult]) -> dict:
    """Whether several experiments' data agree on one shared parameter set.

    The likelihood-ratio test of one parameter set for all experiments against each
    its own: ``2 sum_e (log L_e(own MAP_e) - log L_e(joint MAP))``, chi-squared with
    as many degrees of freedom as the own fits have parameters beyond the joint
    one's, at level :data:`~pmabayes.inference.likelihood.LEVEL_ADEQUATE`. Each
    experiment's likelihood is under the joint's noise as it is now (a record from
    rest's referred to the model), at its own MAP as found before.

    Parameters
    ----------
    posterior : Posterior
        The joint posterior.
    z_map : numpy.ndarray
        The joint MAP, unconstrained.
    own : list of MapResult
        Each experiment's own MAP (:func:`find_map` on its data alone).

    Returns
    -------
    dict
        ``agree`` (bool, or None where the own fits have no parameter beyond the
        joint's), ``statistic``, ``df``, ``p_value``, ``level``, and per experiment
        (by name) ``log_likelihood_own``, ``log_likelihood_joint``,
        ``rms_cost_own_m``, ``rms_cost_joint_m``, ``values_own`` (the experiment's
        own MAP of its model's free parameters) and ``z_own`` (each parameter's own MAP
        and Laplace sd in the sampler's coordinates).
    """
    theta = posterior.to_natural(z_map[None])
    per: dict[str, dict] = {}
    gain, df = 0.0, -posterior.ndim
    for e, (name, lik, result) in enumerate(zip(posterior.experiment_names,
                                                posterior.likelihoods, own, strict=True)):
        alone = posterior.alone(e)
        own_theta = alone.to_natural(result.z[None])
        _, ll_own, x_own = alone.evaluate(own_theta)
        x = posterior.simulate(theta, e)
        ll = float(lik.mean_log_likelihood(x, *posterior.noise_of(e, theta))[0])
        gain += max(float(ll_own[0]) - ll, 0.0)
        df += alone.ndim
        per[name] = {"log_likelihood_own": float(ll_own[0]), "log_likelihood_joint": ll,
                     "rms_cost_own_m": float(lik.rms_cost(x_own)[0]),
                     "rms_cost_joint_m": float(lik.rms_cost(x)[0]),
                     "values_own": {n: float(result.values[n]) for n in lik.model.free_names
                                    if n in result.values},
                     "z_own": _own_z(alone, result)}
    stat = 2.0 * gain
    p = float(chi2.sf(stat, df)) if df > 0 else None
    return {"agree": None if p is None else bool(p >= LEVEL_ADEQUATE), "statistic": stat,
            "df": int(df), "p_value": p, "level": LEVEL_ADEQUATE, "experiments": per}


def _own_z(alone: Posterior, result: MapResult) -> dict[str, list[float]]:
    """Each parameter of an experiment's own MAP in the sampler's coordinates (log for a
    positive one) with its Laplace sd there: how far apart two experiments' estimates
    are, in units of their uncertainty."""
    sd = np.sqrt(np.clip(np.diag(result.covariance_z), 0.0, None))
    return {n: [float(result.z[j]), float(sd[j])] for j, n in enumerate(alone.names)}


def disagreement_text(agreement: dict) -> str:
    """The verdict on experiments that disagree, or an empty string when they agree.

    Parameters
    ----------
    agreement : dict
        :func:`experiments_agreement`'s.

    Returns
    -------
    str
    """
    if agreement.get("agree") is not False:
        return ""
    per = agreement["experiments"]
    worst = max(per, key=lambda n: per[n]["log_likelihood_own"] - per[n]["log_likelihood_joint"])
    w = per[worst]
    return (f"the experiments disagree: their own optima are not compatible with one shared "
            f"parameter set (likelihood ratio {agreement['statistic']:.4g} on "
            f"{agreement['df']} degrees of freedom, p = {agreement['p_value']:.2g}). "
            f"{worst} loses most: RMS {w['rms_cost_joint_m'] * 1e6:.3g} µm at the joint MAP "
            f"against {w['rms_cost_own_m'] * 1e6:.3g} µm alone. The joint posterior averages "
            "them into a model that is none of theirs: `pmabayes diagnose` of the same "
            "experiments shows which parameters move between them and tests the effects "
            "that could make them agree")


class _Polished:
    """A polished point ``z`` (unconstrained); unpacked, ``(z, cov, note)``: its Laplace
    covariance and why that is a stand-in (None where it is the inverse Hessian).

    The covariance is measured when first asked for: of several polishes only the
    highest's is kept, and its Hessians (one at the point, up to two more along their
    eigenvectors where it is indefinite) cost as much as the polish. Measured later, it
    is the same numbers: the log posterior it differences does not change in between
    (a record from rest's noise is learnt again only after the winner is unpacked).
    """

    def __init__(self, z: np.ndarray, *, neg_logpost, u: np.ndarray,
                 hess: np.ndarray | None, scale: np.ndarray) -> None:
        self.z = z
        self._at = (neg_logpost, u, hess, scale)

    @cached_property
    def laplace(self) -> tuple[np.ndarray, str | None]:
        """The Laplace covariance (unconstrained) and its note."""
        neg_logpost, u, hess, scale = self._at
        if hess is None:
            hess = _scaled_hessian(neg_logpost, u)
        hess, edges = _open_edges(hess, neg_logpost, u)
        cov, note = laplace_covariance(hess, None if edges else neg_logpost, u)
        return cov * np.outer(scale, scale), note

    def __iter__(self):
        return iter((self.z, *self.laplace))


def _polish_from(posterior: Posterior, z0: np.ndarray, scale: np.ndarray) -> _Polished:
    """The MAP polished from ``z0`` in coordinates scaled by ``scale``, and (unpacked) its
    Laplace covariance, both unconstrained, and why that covariance is a stand-in."""
    neg_logpost = _scaled_neg_log_posterior(posterior, z0, scale)
    u, hess = _polish(neg_logpost, posterior.ndim)
    return _Polished(z0 + u * scale, neg_logpost=neg_logpost, u=u, hess=hess, scale=scale)


#: A curvature (in units of the plausible box) above which a finite difference has
#: left the posterior's support (its 1e300 stand-in over a small step squared).
_EDGE_CURVATURE = 1e100
#: The Laplace sd, as a fraction of the plausible box, of a direction whose curvature
#: cannot be measured there (:func:`_open_edges`).
_EDGE_SD = 0.1


def _open_edges(hess: np.ndarray, neg_logpost, u: np.ndarray) -> tuple[np.ndarray, bool]:
    """The Hessian with the directions whose finite differences left the support
    given their curvature from steps of 1e-6 of the plausible box (which stay inside),
    or where that fails a spread of :data:`_EDGE_SD` of the box, uncorrelated.

    A MAP at the edge of a prior's support (a noise correlation at its guard), or in
    a direction the data do not see (a dead-zone pressure below every pressure of a
    record referred to its start) whose difference steps reach past the support,
    would otherwise get a curvature of 1e300 and a Laplace variance of 1e-300: the
    sampler's walkers would all start at one value there and never move in it.
    """
    d = np.abs(np.diag(hess))
    edge = ~np.isfinite(d) | (d > _EDGE_CURVATURE)
    # an entry that is not finite between coordinates whose own curvature was measured
    # (its row's edge columns do not count: they are opened anyway, and flagging every
    # row that meets one would drop the correlations of every coordinate)
    edge |= ~np.all(np.isfinite(hess[:, ~edge]), axis=1)
    if not edge.any():
        return hess, False
    near = _fd_diagonal(neg_logpost, u, PROBE_STEP * np.maximum(1.0, np.abs(u)))
    ok = np.isfinite(near) & (near > 0) & (near < _EDGE_CURVATURE)
    out = hess.copy()
    out[edge, :] = 0.0
    out[:, edge] = 0.0
    out[edge, edge] = np.where(ok, near, 1.0 / _EDGE_SD**2)[edge]
    return out, True


#: Draws of the Laplace approximation that check the polished MAP is the mode
#: (:func:`_climb`), the log density one of them must gain to be climbed from, and
#: the most climbs.
_CLIMB_DRAWS, _CLIMB_GAIN, _CLIMB_ROUNDS = 64, 1.0, 5


def _climb(posterior: Posterior, z_map: np.ndarray, cov_z: np.ndarray, note: str | None,
           scale: np.ndarray, rng: np.random.Generator
           ) -> tuple[np.ndarray, np.ndarray, str | None]:
    """The MAP polished again from a draw of its Laplace approximation that lies higher.

    On a rough posterior (a real record the model does not describe: creep, ringing)
    the local polish can stop short of the mode; the sampler's walkers, drawn from
    the Laplace approximation, then start above the MAP, and one that starts far
    above the others never moves, so the run never converges. Where a draw is
    :data:`_CLIMB_GAIN` higher than the MAP, the MAP is polished again from the
    highest draw (at most :data:`_CLIMB_ROUNDS` times). At a mode no draw is higher,
    and nothing changes.
    """
    best = float(posterior.log_prob_z(z_map[None])[0])
    for _ in range(_CLIMB_ROUNDS):
        draws = rng.multivariate_normal(z_map, cov_z, size=_CLIMB_DRAWS, method="eigh")
        lp = posterior.log_prob_z(draws)
        k = int(np.argmax(lp))
        if not lp[k] > best + _CLIMB_GAIN:
            break
        polished = _polish_from(posterior, draws[k], scale)
        lp_new = float(posterior.log_prob_z(polished.z[None])[0])
        if lp_new >= lp[k]:
            (z_map, cov_z, note), best = polished, lp_new
        else:
            z_map, best = draws[k], float(lp[k])
    return z_map, cov_z, note


#: Most passes of learning a record from rest's noise from its periods' residual at
#: the MAP and polishing the MAP again (:func:`refer_periods`); they stop once a pass
#: moves the MAP by under ``_REFER_SETTLED`` of its Laplace sd. On the periodic
#: calibration records three passes took the noise from 195 um (the shakedown of
#: 5.7 mm between periods 2 and 3 read as noise) to 61.6 um (60 um drawn).
_REFER_PASSES = 6


_REFER_SETTLED = 0.01


#: how much lower (relative) the second global search's cost must be to replace the
#: first's: a different basin, not the same one met to the search's tolerance
_OTHER_BASIN = 0.01


#: A search that ends within this many generations has agreed at once
#: (:func:`_global_search`) ...
_AT_ONCE = 3
#: ... and one whose cost is at least this share of the mean's explains nothing.
_EXPLAINS_NOTHING = 0.9
#: How many times as wide the box of a search run again is.
_WIDEN = 3.0


def _global_search(posterior: Posterior, box: np.ndarray, rng: np.random.Generator,
                   popsize: int, maxiter: int, say: Progress, which: str
                   ) -> tuple[np.ndarray, float]:
    """Differential evolution on the paper's RMS cost; the optimum and its cost. Its
    state is shown on one line: the length of a search is not known in advance."""
    lik = posterior.likelihood
    rest = _default_noise_z(posterior, box.shape[0])  # the starts' prior means, the noise

    def rms(z: np.ndarray) -> np.ndarray:
        z = np.hstack([z, np.repeat(rest[None], z.shape[0], axis=0)])
        theta = posterior.to_natural(z)
        lp = posterior.log_prior(theta)
        out = np.full(theta.shape[0], 1.0)  # 1 m: worse than anything real
        ok = np.isfinite(lp)
        if ok.any():
            some = theta[ok]
            cost = (lik.rms_cost_parts([posterior.simulate(some, e)
                                        for e in range(posterior.n_experiments)])
                    if isinstance(lik, JointLikelihood) else lik.rms_cost(posterior.output(some)))
            out[ok] = np.where(np.isfinite(cost), cost, 1.0)
        return out

    def show(intermediate_result) -> None:  # reads the state; changes nothing
        r = intermediate_result
        # scipy's convergence: tol over the spread of the costs; the search ends at 1
        say.status(f"global search {which}: generation {r.nit} (at most {maxiter}), best "
                   f"RMS cost {r.fun * 1e6:.4g} µm, the population "
                   f"{min(100 * r.convergence, 100):.0f}% of the way to agreeing (done at "
                   "100%)")

    def search(bounds: np.ndarray):
        return differential_evolution(
            lambda zt: rms(np.atleast_2d(zt.T)), bounds=list(map(tuple, bounds)),
            popsize=popsize, maxiter=maxiter, tol=_DE_TOL, seed=rng, polish=False,
            vectorized=True, updating="deferred", init="latinhypercube",
            strategy=_DE_STRATEGY, callback=show if say.enabled else None)

    best = search(box)
    flat = static_lines(lik, slope=False)
    if (flat is not None and best.nit <= _AT_ONCE
            and best.fun >= _EXPLAINS_NOTHING * float(lik.rms_cost(flat[2])[0])):
        # a population that agrees at once on a model no better than the data's mean
        # has seen one flat cost (every member's motion far too small or too large),
        # not a basin: the search is run again over a wider box
        centre, half = box.mean(axis=1), (box[:, 1] - box[:, 0]) / 2
        say.say(f"global search {which}: the population agreed at generation {best.nit} on "
                "a model that explains no more than the data's mean; searching again over "
                f"a box {_WIDEN:g} times as wide")
        wide = search(np.column_stack([centre - _WIDEN * half, centre + _WIDEN * half]))
        if wide.fun < best.fun:
            best = wide
    global_cost = float(best.fun)
    if global_cost >= 1.0:
        raise FitError("no parameter set in the prior's plausible region gives a finite "
                       "simulation of this data; check the data's units and the rig")
    return best.x, global_cost


def _scaled_neg_log_posterior(posterior: Posterior, z0: np.ndarray, scale: np.ndarray):
    """The negative log posterior of ``z0 + u * scale``, batched over rows of ``u``."""

    def neg_logpost(u: np.ndarray) -> np.ndarray:
        z = z0 + np.atleast_2d(u) * scale
        theta = posterior.to_natural(z)
        lp, ll, _ = posterior.evaluate(theta, return_x=False)  # the positions are not needed
        v = -(lp + ll)
        return np.where(np.isfinite(v), v, 1e300)

    return neg_logpost


def _polish(neg_logpost, ndim: int) -> tuple[np.ndarray, np.ndarray | None]:
    """L-BFGS-B from ``u = 0``, then Newton steps; the optimum and the Hessian there, or
    None where the last step moved it (:class:`_Polished` measures it when asked)."""
    h = np.full(ndim, 1e-7)

    def fun_and_grad(u: np.ndarray) -> tuple[float, np.ndarray]:
        pts = np.vstack([u, u + np.diag(h), u - np.diag(h)])
        vals = neg_logpost(pts)
        grad = (vals[1: ndim + 1] - vals[ndim + 1:]) / (2 * h)
        return float(vals[0]), np.where(np.isfinite(grad), grad, 0.0)

    u = np.zeros(ndim)
    for _ in range(3):  # restart: the first pass also learns the curvature's scale
        res = minimize(fun_and_grad, u, jac=True, method="L-BFGS-B",
                       options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-9})
        # a step across the support's edge (gradients of 1e300 stand-ins) can overflow
        # to a point that is not a number: the last finite point is kept, never a worse
        if not (np.all(np.isfinite(res.x)) and float(neg_logpost(res.x[None])[0])
                <= float(neg_logpost(u[None])[0])):
            break
        if np.allclose(res.x, u, rtol=0, atol=1e-12):
            break
        u = res.x
    # Newton polish with the finite-difference Hessian, whose inverse is the
    # Laplace covariance
    hess = None
    for _ in range(5):
        hess = _scaled_hessian(neg_logpost, u)
        f0, g0 = fun_and_grad(u)
        try:
            step = -np.linalg.solve(hess, g0)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        t = 1.0
        while t > 1e-4 and float(neg_logpost((u + t * step)[None])[0]) > f0:
            t *= 0.5
        if t <= 1e-4:
            break
        u = u + t * step
        curvature, hess = np.diag(hess), None  # measured where u was
        with np.errstate(invalid="ignore"):  # 0 * inf: a coordinate at the edge, unmoved
            moved = np.abs(t * step) * np.sqrt(np.abs(curvature))
        if np.max(np.nan_to_num(moved, nan=0.0, posinf=np.inf)) < 1e-3:
            break
    # a loop left without a step has the Hessian at u already (the same numbers)
    return u, hess


def _no_map_message(posterior: Posterior, theta: np.ndarray) -> str:
    """Why the search found no MAP: the point it ended at is outside the priors or its
    simulation failed (priors far from the data's scale)."""
    where = " and ".join(str(lik.dataset.source or "the data") for lik in
                         getattr(posterior.likelihood, "likelihoods", [posterior.likelihood]))
    bad = [n for n, v in zip(posterior.names, theta, strict=True) if not np.isfinite(v)]
    what = (f"it ended with {', '.join(bad)} not a number" if bad
            else "its simulation there is not finite")
    return (f"{where}: the search for the MAP found no point where the model simulates the "
            f"data under its priors ({what}): the priors are far from the data's scale. "
            "Check the units and the rig (mass, input kind), or give priors of the data's "
            "scale (--prior NAME=SPEC; `pmabayes effects` lists the defaults).")


def _parts(lik: Likelihood | JointLikelihood) -> list[Likelihood]:
    return list(lik.likelihoods) if isinstance(lik, JointLikelihood) else [lik]


def static_lines(lik: Likelihood | JointLikelihood, *, slope: bool = True
                 ) -> tuple[float, np.ndarray, np.ndarray] | None:
    """The best static line of position on input, one slope shared by the experiments
    and an offset for each, fitted by least squares to the observed trial means.

    Parameters
    ----------
    lik : Likelihood or JointLikelihood
        The data.
    slope : bool
        False fits the offsets alone: each experiment's mean, the yardstick that
        explains nothing.

    Returns
    -------
    tuple or None
        The slope (m per unit of input), the offsets ``(n_experiments,)`` and the
        line's positions as the model's output has them ``(1, n_outputs)``; None
        where trials have their own inputs (no one input to draw a line on).
    """
    parts = _parts(lik)
    if any(p.own_inputs for p in parts):
        return None
    n = len(parts)
    rows, ys = [], []
    for e, p in enumerate(parts):
        seen = np.isfinite(p.y_mean)
        design = np.zeros((int(seen.sum()), n + 1))
        design[:, 0] = p.input[seen] if slope else 0.0
        design[:, 1 + e] = 1.0
        rows.append(design)
        ys.append(p.y_mean[seen])
    coef = np.linalg.lstsq(np.vstack(rows), np.concatenate(ys), rcond=None)[0]
    b = float(coef[0]) if slope else 0.0
    x = np.concatenate([coef[1 + e] + b * p.input for e, p in enumerate(parts)])
    return b, coef[1:], x[None]


#: Time constants, as multiples of the record's duration, of the nested linear lags
#: the search also starts from (:func:`_nested_start`).
_NESTED_TAUS = (1e-3, 1e-2, 1e-1)


def _nested_points(posterior: Posterior, theta: np.ndarray, line: tuple) -> np.ndarray:
    """Natural points ``(k, ndim)``: ``theta`` with the base model set to the linear
    lags nested in it that draw the static ``line`` (:func:`static_line_values`)."""
    b, offsets, _ = line
    out = []
    for tau_share in _NESTED_TAUS:
        for share in (0.5, 0.9):
            point = theta.copy()
            for e, lik in enumerate(posterior.likelihoods):
                ident = posterior.identified[e]
                area_name = ident.get("rig_area_m2")
                area = (float(point[posterior.names.index(area_name)]) if area_name
                        else lik.model.rig.area_m2)
                duration = float(lik.dataset.time_s[-1] - lik.dataset.time_s[0])
                values = static_line_values(
                    lik.model, b, float(offsets[e]), float(np.min(lik.input)), area_m2=area,
                    tau_s=tau_share * max(duration, 1e-9), alpha_share=share,
                    relative=position_reference(lik.dataset) == "start")
                for name, value in values.items():
                    if name in ident:
                        point[posterior.names.index(ident[name])] = value
            out.append(point)
    return np.array(out)


def _nested_start(posterior: Posterior, box: np.ndarray, z_model: np.ndarray,
                  cost: float) -> tuple[np.ndarray, float, bool]:
    """The search's optimum, or the best linear model nested in the base physics where
    that explains the data better (the search then failed to find what the model
    contains): its model coordinates, its RMS cost, and whether it was taken.

    A value outside the plausible box (``beta = 0`` on a log scale, a dead zone below
    zero) is put at the box's edge: the polish goes on from there.
    """
    line = static_lines(posterior.likelihood)
    if line is None or not line[0] > 0:
        return z_model, cost, False
    n_model = posterior.n_model
    rest = _default_noise_z(posterior, n_model)
    theta = posterior.to_natural(np.concatenate([z_model, rest])[None])[0]
    points = _nested_points(posterior, theta, line)
    edges = posterior.to_natural(box.T)
    points[:, :n_model] = np.clip(points, edges.min(axis=0), edges.max(axis=0))[:, :n_model]
    z = posterior.to_unconstrained(points)
    z[:, n_model:] = rest
    theta = posterior.to_natural(z)
    ok = np.isfinite(posterior.log_prior(theta))
    if not ok.any():
        return z_model, cost, False
    costs = np.full(z.shape[0], np.inf)
    with np.errstate(all="ignore"):
        costs[ok] = posterior.likelihood.rms_cost(posterior.output(theta[ok]))
    k = int(np.argmin(np.where(np.isfinite(costs), costs, np.inf)))
    if not costs[k] < cost:
        return z_model, cost, False
    return z[k, :n_model], float(costs[k]), True


#: A fit whose RMS cost is above this share of the data's own RMS spread about its
#: mean (explaining under 75% of its variance) is reported as poor.
POOR_FIT_SHARE = 0.5
#: A fit whose RMS cost is above this share of the motion (largest minus smallest
#: position) is checked for a wrong sign or scale (:func:`_refuse_wrong_data`).
_WRONG_DATA_SHARE = 0.25


def fit_quality(lik: Likelihood | JointLikelihood, x: np.ndarray, *,
                nested_start: bool = False) -> dict:
    """How well a MAP describes the data, beside the nested yardsticks; refused only
    where the data cannot be this kind of model's at all.

    A poor fit is evidence for :func:`pmabayes.criticism.diagnosis.diagnose`, not a
    reason to stop: it is measured and said. What is refused is what no model of
    this kind can explain, and a user's file can: a simulation that is not finite;
    a position that falls as the input rises (a sign: the model's rises); a motion
    of metres (a scale off by 10^3).

    Parameters
    ----------
    lik : Likelihood or JointLikelihood
        The data.
    x : numpy.ndarray
        The MAP's positions, as the model's output has them.
    nested_start : bool
        The search had started from the best nested linear model
        (:func:`find_map`), since its own optimum was worse.

    Returns
    -------
    dict
        ``rms_cost_m``, ``motion_m``, ``share`` (cost over the data's RMS spread about
        its mean; a quarter of the motion without one input), ``poor`` (share above
        :data:`POOR_FIT_SHARE`), ``static_line_rms_m`` and ``mean_rms_m`` (the
        nested yardsticks; None without one input), ``search_failure`` (the MAP is
        worse than the static line), ``nested_start`` and ``text`` (the words of a
        poor fit or a failed search; empty otherwise).

    Raises
    ------
    FitError
        If the simulation is not finite, or the data show a sign or scale error.
    """
    x = np.atleast_2d(x)
    parts = _parts(lik)
    xs = lik.split(x[0]) if isinstance(lik, JointLikelihood) else [x[0]]
    for one, xe in zip(parts, xs, strict=True):
        _refuse_wrong_data(one, float(one.rms_cost(np.atleast_2d(xe))[0]))
    cost = float(lik.rms_cost(x)[0])
    motion = float(np.mean([span(p.y_mean) for p in parts]))
    line, flat = static_lines(lik), static_lines(lik, slope=False)
    line_rms = None if line is None else float(lik.rms_cost(line[2])[0])
    mean_rms = None if flat is None else float(lik.rms_cost(flat[2])[0])
    spread = mean_rms if mean_rms is not None else motion / 4.0
    share = cost / spread if spread > 0 else math.inf
    failure = line_rms is not None and cost > line_rms * (1.0 + 1e-6)
    where = " and ".join(str(p.dataset.source or "the data") for p in parts)
    text = ""
    if share > POOR_FIT_SHARE:
        text = (f"{where}: the best fit leaves an RMS error of {cost * 1e3:.3g} mm, "
                f"{100 * share:.0f}% of the data's own spread about its mean "
                f"({spread * 1e3:.3g} mm, on a motion of {motion * 1e3:.3g} mm)"
                + (f"; a static line of position on input leaves {line_rms * 1e3:.3g} mm"
                   if line_rms is not None else "")
                + ". The model misses much of the motion: `pmabayes diagnose` says where and "
                "what may be missing.")
    if failure:
        text += ((" " if text else f"{where}: ")
                 + f"The search ended worse than the static line ({cost * 1e3:.3g} against "
                 f"{line_rms * 1e3:.3g} mm), which the model contains (beta = gamma = 0): a "
                 "search failure, not a verdict on the data. Widen the priors or give a "
                 "start near the line (--prior).")
    return {"rms_cost_m": cost, "motion_m": motion, "share": share,
            "poor": bool(share > POOR_FIT_SHARE), "static_line_rms_m": line_rms,
            "mean_rms_m": mean_rms, "search_failure": bool(failure),
            "nested_start": bool(nested_start), "text": text}


#: A motion larger than this is no actuator's this model describes: a unit is wrong.
_LARGEST_MOTION_M = 1.0


def _refuse_wrong_data(one: Likelihood, cost: float) -> None:
    """Refuse a record whose fit shows a wrong sign or scale, not a wrong model."""
    where = one.dataset.source or "the data"
    motion = span(one.y_mean)
    if not np.isfinite(cost):
        raise FitError(f"{where}: the model's simulation at the best fit is not finite; check "
                       "the units (positions in m, pressure in Pa) and the rig (masses, "
                       "gravity direction).")
    if cost <= _WRONG_DATA_SHARE * motion:
        return
    if motion > _LARGEST_MOTION_M:
        raise FitError(
            f"{where}: the positions span {motion:.3g} m, more than any actuator this model "
            "describes moves, and the best fit misses most of it: a scale off by 10^3? "
            "Name the column with its unit (position_mm) or map it in the sidecar's "
            '"columns" ({"Position": "position_mm"}).')
    line = static_lines(one)
    if line is not None and line[0] < 0:
        flat = static_lines(one, slope=False)
        line_rms, mean_rms = float(one.rms_cost(line[2])[0]), float(one.rms_cost(flat[2])[0])
        if line_rms < 0.8 * mean_rms:
            raise FitError(
                f"{where}: the position falls as the input rises (a static line of position "
                f"on input, slope {line[0]:.3g} m per unit, leaves {line_rms * 1e3:.3g} mm "
                f"against {mean_rms * 1e3:.3g} mm for the mean), while the model's rises "
                f"with it, so the best fit leaves {cost * 1e3:.3g} mm on a motion of "
                f"{motion * 1e3:.3g} mm. If the file counts contraction as positive, declare "
                '"position_sign": -1 in its sidecar; check that the input column is the '
                "commanded input.")
