"""Whether a model carries to experiments it was not fitted to (:func:`leave_experiments_out`,
:class:`Transfer`).

A refit's ELPD leaves out trials, or stretches of a record: every experiment is still
in its fit. A dead load differs from another by more than its mass, so an effect can
predict the loads it was fitted to better and the next load worse. Here each
experiment is left out in turn: the model is fitted to the others (a polish from the
joint MAP, which is near) and predicts the one left out from its declared start, as
``validate`` predicts a held-out load.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from pmabayes.criticism.observed import residual, simulate_states
from pmabayes.criticism.yardsticks.base import nrmse
from pmabayes.inference.density import Posterior
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.search import FitError, polish_map
from pmabayes.parallel import Runner, can_fork
from pmabayes.util import finite_or_none

__all__ = ["Transfer", "leave_experiments_out"]


@dataclass(frozen=True)
class Transfer:
    """A refit and the model without its effect, each fitted to all experiments but one
    and predicting the one left out, in turn.

    Parameters
    ----------
    names : tuple of str
        The experiments, in the diagnosis' order.
    model_nrmse : tuple of float
        The model's NRMSE on each experiment when it is left out (NaN where the fit to
        the others failed).
    refit_nrmse : tuple of float
        The refit's.
    """

    names: tuple[str, ...]
    model_nrmse: tuple[float, ...]
    refit_nrmse: tuple[float, ...]

    def _both(self) -> tuple[np.ndarray, np.ndarray]:
        a, b = np.asarray(self.model_nrmse, float), np.asarray(self.refit_nrmse, float)
        seen = np.isfinite(a) & np.isfinite(b)
        return a[seen], b[seen]

    @property
    def means(self) -> tuple[float, float]:
        """The mean NRMSE over the experiments left out, the model's and the refit's (over
        those both predict; NaN where there is none)."""
        a, b = self._both()
        return (float(a.mean()), float(b.mean())) if a.size else (math.nan, math.nan)

    @property
    def ratio(self) -> float:
        """The refit's NRMSE over the model's, geometric mean over the experiments left
        out (those both predict; NaN where there is none): each experiment weighs alike,
        so one that neither predicts (an extrapolation far off) does not decide."""
        a, b = self._both()
        return float(np.exp(np.mean(np.log(b / a)))) if a.size else math.nan

    @property
    def carries(self) -> bool | None:
        """Whether the effect predicts the experiments left out better (:attr:`ratio`
        below 1); None where no experiment could be predicted by both."""
        ratio = self.ratio
        return None if not math.isfinite(ratio) else bool(ratio < 1.0)

    def text(self) -> str:
        """The comparison in words, for the verdict."""
        each = ", ".join(f"{n} {r:.3g} against {m:.3g}" for n, m, r in
                         zip(self.names, self.model_nrmse, self.refit_nrmse, strict=True))
        return (f"fitted to all experiments but one, it predicts the one left out with "
                f"{self.ratio:.3g} times the NRMSE without it (geometric mean; {each})")

    def to_dict(self) -> dict:
        """JSON-ready: ``experiments`` (name to ``{"model_nrmse", "refit_nrmse"}``, None
        where not predicted), ``mean_model_nrmse``, ``mean_refit_nrmse``, ``ratio`` and
        ``carries``.

        Returns
        -------
        dict
        """
        model, refit = self.means
        return {"experiments": {n: {"model_nrmse": finite_or_none(m),
                                    "refit_nrmse": finite_or_none(r)}
                                for n, m, r in zip(self.names, self.model_nrmse,
                                                   self.refit_nrmse, strict=True)},
                "mean_model_nrmse": finite_or_none(model),
                "mean_refit_nrmse": finite_or_none(refit),
                "ratio": finite_or_none(self.ratio), "carries": self.carries}


def leave_experiments_out(likelihoods: list[Likelihood], repeat_noise: list,
                          names: list[str], noise_choices: list, values: dict, *,
                          substeps: int, rng: np.random.Generator,
                          processes: int | None = None) -> tuple[float, ...]:
    """Each experiment's NRMSE predicted by the model fitted to the others alone.

    For each experiment in turn, the posterior of the others
    (:meth:`~pmabayes.inference.density.Posterior.subset`) is polished from the joint
    MAP (:func:`~pmabayes.inference.search.polish_map`, the noise kept as given), and
    the experiment is simulated at those values. Its own parameters (an offset, an
    estimated start), which the others cannot give, are the joint MAP's, as
    ``validate`` estimates them on the held-out record.

    Parameters
    ----------
    likelihoods : list of Likelihood
        The experiments, each with the model on its rig (two or more).
    repeat_noise, names, noise_choices : list
        As the joint posterior's (:class:`~pmabayes.inference.density.Posterior`).
    values : dict
        The joint MAP, by the joint posterior's parameter names.
    substeps : int
        The simulator's substeps per sample.
    rng : numpy.random.Generator
        Seeds each polish (one stream each).
    processes : int, optional
        Worker processes, one experiment each (all cores by default).

    Returns
    -------
    tuple of float
        One NRMSE per experiment, in order: NaN where the fit to the others or the
        prediction failed.
    """
    if len(likelihoods) < 2:
        raise ValueError("leaving experiments out needs two or more experiments, got "
                         f"{len(likelihoods)}")
    # copies: a posterior sets its likelihoods' columns
    joint = Posterior([copy.copy(lik) for lik in likelihoods], list(repeat_noise),
                      names=list(names), noise_choices=list(noise_choices))
    theta = np.array([values[n] for n in joint.names], dtype=float)
    jobs = list(zip(range(joint.n_experiments), rng.spawn(joint.n_experiments), strict=True))
    _JOB[:] = [(joint, theta, substeps)]
    try:
        with Runner(processes if can_fork() else 1, tasks=len(jobs)) as runner:
            return tuple(runner.map(_left_out_task, jobs))
    finally:
        _JOB.clear()


#: the joint posterior, its MAP and the substeps of the folds running (forked workers
#: inherit them rather than be sent the data)
_JOB: list = []


def _left_out_task(job: tuple[int, np.random.Generator]) -> float:
    """One experiment left out: ``(its index, its stream)`` to its NRMSE."""
    left, rng = job
    joint, theta, substeps = _JOB[0]
    keep = [e for e in range(joint.n_experiments) if e != left]
    others, columns = joint.subset(keep)
    try:
        fitted = polish_map(others, theta[columns], rng=rng, refer=False)
    except FitError:
        return math.nan
    point = theta.copy()
    point[columns] = [fitted.values[n] for n in others.names]
    own, start = joint.experiment_point(left, dict(zip(joint.names, point, strict=True)))
    lik = joint.likelihoods[left]
    # ``own`` holds the model's free parameters only (no noise): simulated as it is
    sim, _ = simulate_states(lik, lik.model, own, start, substeps)
    resid = residual(lik, sim.position_m[0])
    if not np.isfinite(resid).any():
        return math.nan
    measured = resid + sim.position_m[0]  # NaN where no trial is counted
    return nrmse(measured, sim.position_m[0])[1]
