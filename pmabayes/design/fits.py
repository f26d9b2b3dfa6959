"""Each candidate model fitted on the data so far (the package's MAP and Laplace
covariance), and its posterior draws as the model's parameter arrays.

A :class:`CandidateFit` holds what the scores need: the model, the posterior it was
fitted in, the MAP and its Laplace covariance in the posterior's unconstrained
coordinates. Fits made once may be given to :func:`pmabayes.design.api.design` again
(``fits=``), so that a second design on the same data costs no fit; a fit file of
``pmabayes fit`` gives its MCMC draws (:func:`fit_from_file`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmabayes.design.experiments import DesignError
from pmabayes.inference.density import Posterior
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.search import MapResult, find_map
from pmabayes.model.model import Model, ModelError

__all__ = ["CandidateFit", "fit_candidate", "fit_from_file", "does_not_act"]


@dataclass(frozen=True)
class CandidateFit:
    """One candidate model at its MAP on the data so far.

    Parameters
    ----------
    name : str
        The candidate (its effect's name; ``"+".join`` of them for several).
    posterior : Posterior
        The posterior it was fitted in (built by
        :func:`pmabayes.inference.posterior.build_posterior`).
    map : MapResult
        Its MAP and Laplace covariance (``z``, ``covariance_z``); for a fit file, the
        mean and covariance of its draws.
    samples_z : numpy.ndarray or None
        A fit file's MCMC draws in unconstrained coordinates ``(draws, ndim)``, which
        :meth:`draws` then picks from instead of the Laplace approximation.
    source : str or None
        The fit file it was read from.
    """

    name: str
    posterior: Posterior
    map: MapResult
    samples_z: np.ndarray | None = None
    source: str | None = None

    @property
    def model(self) -> Model:
        """The model on the first data set's rig."""
        return self.posterior.likelihoods[0].model

    @property
    def substeps(self) -> int:
        """The simulator's substeps the fit chose."""
        return int(self.posterior.likelihoods[0].substeps)

    def model_on(self, load_kg: float) -> Model:
        """The model on the first data set's rig with a dead load added.

        Raises
        ------
        DesignError
            Where the rig's moving mass is itself identified (a prior): a load added to
            an unknown mass is not a known rig.
        """
        model = self.model
        if not load_kg:
            return model
        if model.rig.prior_of("moving_mass_kg") is not None:
            raise DesignError(
                f"a dead load of {load_kg:g} kg cannot be added to the rig "
                f"{model.rig.name!r}: its moving mass is identified (a prior), not known; "
                "give no loads, or declare the moving mass as a number")
        rig = dataclasses.replace(model.rig, moving_mass_kg=model.rig.moving_mass_kg + load_kg)
        return Model(model.effects, rig=rig, priors=model.chosen_priors(rig),
                     fixed=dict(model.fixed),
                     free=[n for n in model.free_names if not model.is_rig_parameter(n)])

    def noise(self) -> tuple:
        """The first experiment's noise parameters at the MAP, as floats."""
        theta = self.posterior.to_natural(np.asarray(self.map.z)[None])
        return tuple(float(np.asarray(v).reshape(-1)[0])
                     for v in self.posterior.noise_of(0, theta))

    def draws(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` posterior draws as the model's parameter arrays ``(n, n_parameters)``.

        A fit file's MCMC draws, picked at random without repeats (with repeats where it
        holds fewer than ``n``); otherwise the Laplace approximation's, where a draw
        outside the priors' support (none in unconstrained coordinates, but a prior's
        support may be narrower) is drawn again, at most ten times over.
        """
        if self.samples_z is not None:
            m = self.samples_z.shape[0]
            pick = rng.choice(m, size=n, replace=m < n)
            return self._model_theta(self.posterior.to_natural(self.samples_z[pick]))
        z0 = np.asarray(self.map.z, dtype=float)
        cov = np.asarray(self.map.covariance_z, dtype=float)
        chol = np.linalg.cholesky(0.5 * (cov + cov.T) + 1e-12 * np.eye(z0.size))
        kept: list[np.ndarray] = []
        for _ in range(10):
            z = z0 + rng.standard_normal((n, z0.size)) @ chol.T
            theta = self.posterior.to_natural(z)
            ok = np.isfinite(self.posterior.log_prior(theta))
            kept += list(self._model_theta(theta[ok]))
            if len(kept) >= n:
                return np.array(kept[:n])
        raise DesignError(f"the Laplace approximation of {self.name!r} puts fewer than {n} of "
                          f"{10 * n} draws inside the priors' support; fit it by MCMC")

    def map_theta(self) -> np.ndarray:
        """The MAP as the model's parameter array ``(1, n_parameters)``."""
        return self._model_theta(self.posterior.to_natural(np.asarray(self.map.z)[None]))

    def _model_theta(self, theta: np.ndarray) -> np.ndarray:
        full = self.posterior.full_theta(theta)
        cols = self.posterior.likelihoods[0].columns
        return np.ascontiguousarray(full if cols is None else full[:, cols])


def does_not_act(datasets: Sequence, base: Sequence[str], effect: str) -> str | None:
    """Why a candidate cannot be told apart on this rig, or None where it can act.

    It cannot where it cannot join the base model (a second hysteresis law, a clash of
    names), or where moving its parameters from their null (no effect) to their
    defaults changes the simulated output on the first data set's input at no sample.

    Parameters
    ----------
    datasets : sequence of Dataset
        The data so far; the first gives the rig and the input.
    base : sequence of str
        The base model's effects.
    effect : str
        The candidate.

    Returns
    -------
    str or None
    """
    try:
        model = Model.for_dataset(datasets[0], [*base, effect])
    except ModelError as err:
        return f"cannot be added to this model: {err}"
    eff = model.effects[-1]
    tested = [p for p in eff.parameters if p.vary and p.null is not None]
    if not tested:
        return None  # nothing to move: it is scored as fitted
    ds = datasets[0]
    on = model.defaults
    off = {**on, **{p.name: p.null for p in tested}}
    x = _simulate_input(model, [on, off], ds.input[0], ds.time_s)
    if np.all(np.isfinite(x)) and np.array_equal(x[0], x[1]):
        return (f"does not act on this rig: moving {', '.join(p.name for p in tested)} from "
                "no effect to the defaults changes the simulated output on the first data "
                "set's input at no sample")
    return None


def _simulate_input(model: Model, values: list[dict], u: np.ndarray, t: np.ndarray
                    ) -> np.ndarray:
    from pmabayes.model.simulator import simulate

    theta = np.vstack([model.theta(v) for v in values])
    return simulate(model, theta, u, time_s=t)


def fit_candidate(datasets: Sequence, effects: Sequence[str], name: str, *,
                  rng: np.random.Generator, noise_model: str = "auto",
                  substeps: int | str = "auto") -> CandidateFit:
    """Fit a model on the data so far: the package's MAP search and Laplace covariance
    (:func:`pmabayes.inference.search.find_map`).

    Parameters
    ----------
    datasets : sequence of Dataset
        The experiments so far, each on its own rig.
    effects : sequence of str
        The model's effects (the base's and the candidate's).
    name : str
        The candidate's name.
    rng : numpy.random.Generator
        Seeds the search.
    noise_model : str
        As for :func:`pmabayes.fit`.
    substeps : int or "auto"
        As for :func:`pmabayes.fit`.

    Returns
    -------
    CandidateFit
    """
    model = Model.for_dataset(datasets[0], list(effects))
    posterior = build_posterior(model, list(datasets), substeps=substeps,
                                noise_model=noise_model)
    return CandidateFit(name, posterior, find_map(posterior, rng=rng))


def fit_from_file(path, datasets: Sequence, *, noise_model: str = "auto") -> CandidateFit:
    """A candidate from a fit file of ``pmabayes fit`` on the same data: its model and
    its MCMC draws (the map: their mean and covariance in unconstrained coordinates).

    Parameters
    ----------
    path : str or Path
        The fit file.
    datasets : sequence of Dataset
        The data it was fitted on (the first one is checked against it).
    noise_model : str
        As for :func:`pmabayes.fit`: the noise is learnt again from the data's repeats.

    Returns
    -------
    CandidateFit
        Named by the fit's effects (``"+".join``).

    Raises
    ------
    DesignError
        If the fit holds no draws of a parameter the posterior identifies.
    """
    from pmabayes.inference.fitfile import check_dataset, fit_info, load_fit, model_from_fit

    tree = load_fit(path)
    if len(datasets) == 1:
        check_dataset(tree, datasets[0])
    model = model_from_fit(tree)
    substeps = int(fit_info(tree).get("substeps") or 1)
    posterior = build_posterior(model, list(datasets), substeps=substeps,
                                noise_model=noise_model)
    post = tree["posterior"].to_dataset()
    missing = [n for n in posterior.names if n not in post.data_vars]
    if missing:
        raise DesignError(f"{path}: the fit holds no draws of {', '.join(missing)}, which the "
                          "design's posterior identifies; give the fit of these data sets, "
                          "made by `pmabayes fit`")
    theta = np.stack([np.asarray(post[n]).reshape(-1) for n in posterior.names], axis=1)
    z = posterior.to_unconstrained(theta)
    mean = z.mean(axis=0)
    values = {n: float(v) for n, v in zip(posterior.names, np.median(theta, axis=0),
                                           strict=True)}
    result = MapResult(values, math.nan, math.nan, {}, math.nan, mean,
                       np.atleast_2d(np.cov(z, rowvar=False)))
    return CandidateFit("+".join(model.effect_names) or "base", posterior, result, z,
                        str(path))
