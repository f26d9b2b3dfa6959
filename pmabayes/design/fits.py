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

from pmabayes.design.experiments import DesignError, dead_load_kg, loaded_mass_kg
from pmabayes.inference.density import Posterior
from pmabayes.inference.importance import smoothed_log_weights
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.search import MapResult, find_map
from pmabayes.model.model import Model, ModelError

__all__ = ["CandidateFit", "fit_candidate", "fit_from_file", "does_not_act", "map_check",
           "MAP_GAIN_NATS"]

#: A MAP from which one Newton step (its gradient under its Laplace covariance) would
#: gain more than this much log posterior is not at the optimum: its search stopped
#: short (:func:`map_check`). One nat is a shift of the draws' centre by about 1.4 of
#: their sds along the gradient.
MAP_GAIN_NATS = 1.0


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
    convergence : dict or None
        Whether the fit converged: a fit file's sampler's record (``"converged"``,
        ``"messages"``: :func:`pmabayes.inference.fitfile.fit_info`), or for a MAP made
        here :func:`map_check`'s; None where not known (a fit made by hand).
    """

    name: str
    posterior: Posterior
    map: MapResult
    samples_z: np.ndarray | None = None
    source: str | None = None
    convergence: dict | None = None

    @property
    def model(self) -> Model:
        """The model on the first data set's rig."""
        return self.posterior.likelihoods[0].model

    @property
    def substeps(self) -> int:
        """The simulator's substeps the fit chose."""
        return int(self.posterior.likelihoods[0].substeps)

    def model_on(self, load_kg: float | None) -> Model:
        """The model on the first data set's rig with ``load_kg`` hung in place of its dead
        load (:func:`~pmabayes.design.experiments.loaded_mass_kg`); None: as it is.

        Raises
        ------
        DesignError
            Where the first data set declares no dead load (``"conditions":
            {"load_kg": ...}``), or the rig's moving mass is itself identified (a prior):
            the mass under another load is then not known.
        """
        model = self.model
        if load_kg is None:
            return model
        first = self.posterior.likelihoods[0].dataset
        declared = dead_load_kg(first)
        if declared is None:
            raise DesignError(
                f"{first.source or 'the first data set'}: a dead load of {load_kg:g} kg cannot "
                "replace this record's, which its sidecar does not declare; declare it "
                '("conditions": {"load_kg": 0.1}, kg, 0 for none)')
        if model.rig.prior_of("moving_mass_kg") is not None:
            raise DesignError(
                f"a dead load of {load_kg:g} kg cannot be hung on the rig "
                f"{model.rig.name!r}: its moving mass is identified (a prior), not known; "
                "give no loads, or declare the moving mass as a number")
        if load_kg == declared:
            return model
        mass = loaded_mass_kg(model.rig.moving_mass_kg, declared, load_kg)
        rig = dataclasses.replace(model.rig, moving_mass_kg=mass)
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

    def weighted_draws(self, rng: np.random.Generator, n: int, sets: int = 1, pool: int = 4
                       ) -> tuple[list[np.ndarray], dict | None]:
        """``sets`` separate sets of ``n`` draws of the posterior on the data so far, as
        the model's parameter arrays ``(n, n_parameters)``, and how far the Laplace
        approximation is from that posterior.

        A fit file's draws are the posterior's: :meth:`draws`, and None. Otherwise
        ``pool * n * sets`` draws of the Laplace approximation are importance-resampled
        to the posterior (Pareto-smoothed weights ``p(z | data) / q(z)`` in unconstrained
        coordinates; each set resampled systematically from its own part of the pool,
        in a random order). A Gaussian in those coordinates puts draws where the
        posterior has almost none (off a curved ridge of correlated parameters, in a
        poorly identified parameter's tail): such a draw responds to a new input as no
        parameter set that fits the data so far does, and as the true model it would be
        named on any experiment, even on the first one repeated. Where the weights of
        the Laplace draws are too uneven to mend (Pareto k-hat above
        :data:`GOOD_K_HAT`), the proposal is the Laplace approximation with its
        covariance scaled down (by 1/4, 1/16, 1/64: the draws then stay near the ridge)
        whose weights are the least uneven.

        Parameters
        ----------
        rng : numpy.random.Generator
            Draws the pool and the resampling.
        n : int
            Draws per set.
        sets : int
            Separate sets (the truths and the predictive densities of a design).
        pool : int
            Laplace draws per draw wanted.

        Returns
        -------
        draws : list of numpy.ndarray
            ``sets`` arrays ``(n, n_parameters)``.
        weights : dict or None
            ``"k_hat"`` (the weights' Pareto k-hat: above 0.7 the proposal is too far
            from the posterior for the weights to mend it), ``"ess"`` (their effective
            sample size), ``"pool"`` and ``"scale"`` (of the Laplace sds); None for a
            fit file.

        Raises
        ------
        DesignError
            Where fewer than ``n * sets`` of the pool fall inside the priors' support.
        """
        if self.samples_z is not None:
            return [self.draws(rng, n) for _ in range(sets)], None
        post = self.posterior
        z0 = np.asarray(self.map.z, dtype=float)
        cov = np.asarray(self.map.covariance_z, dtype=float)
        chol = np.linalg.cholesky(0.5 * (cov + cov.T) + 1e-12 * np.eye(z0.size))
        m = max(int(pool), 1) * int(n) * int(sets)
        best = None
        for scale in _PROPOSAL_SCALES:
            e = rng.standard_normal((m, z0.size))
            z = z0 + scale * e @ chol.T
            # log p(z) - log q(z), less a constant: q's density is exp(-|e|^2 / 2) / scale^p
            log_ratio = post.log_prob_z(z) + 0.5 * np.einsum("ij,ij->i", e, e)
            ok = np.isfinite(log_ratio)
            if int(ok.sum()) < n * sets:
                continue
            lr = log_ratio[ok] - np.max(log_ratio[ok])
            log_w, k_hat = smoothed_log_weights(lr)
            w = np.exp(log_w - np.max(log_w))
            w /= w.sum()
            ess = float(1.0 / np.sum(w**2))
            good = not k_hat > GOOD_K_HAT  # NaN: weights all alike
            rank = (good, ess if good else -k_hat)
            if best is None or rank > best[0]:
                best = (rank, scale, z[ok], w, k_hat, ess)
            if good and scale == 1.0:
                break  # the Laplace approximation itself will do
        if best is None:
            raise DesignError(f"the Laplace approximation of {self.name!r} puts fewer than "
                              f"{n * sets} of {m} draws inside the priors' support; fit it "
                              "by MCMC")
        _, scale, z, w, k_hat, ess = best
        parts = np.array_split(rng.permutation(w.size), int(sets))
        out = []
        for part in parts:
            wp = w[part] / w[part].sum()
            # systematic resampling: each draw kept about n w times, in a random order
            picks = np.searchsorted(np.cumsum(wp), (rng.uniform() + np.arange(n)) / n)
            picks = rng.permutation(part[np.minimum(picks, part.size - 1)])
            out.append(self._model_theta(post.to_natural(z[picks])))
        return out, {"k_hat": k_hat, "ess": ess, "pool": int(w.size), "scale": scale}

    def map_theta(self) -> np.ndarray:
        """The MAP as the model's parameter array ``(1, n_parameters)``."""
        return self._model_theta(self.posterior.to_natural(np.asarray(self.map.z)[None]))

    def _model_theta(self, theta: np.ndarray) -> np.ndarray:
        full = self.posterior.full_theta(theta)
        cols = self.posterior.likelihoods[0].columns
        return np.ascontiguousarray(full if cols is None else full[:, cols])


#: The largest Pareto k-hat of importance weights that resampling can mend (Vehtari et
#: al. 2024): above it the Laplace approximation is too far from the posterior.
GOOD_K_HAT = 0.7
#: Scales of the Laplace sds tried as importance proposals, the approximation itself
#: first (:meth:`CandidateFit.weighted_draws`).
_PROPOSAL_SCALES = (1.0, 0.25, 0.0625, 0.015625)


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
    found = find_map(posterior, rng=rng)
    return CandidateFit(name, posterior, found, convergence=map_check(posterior, found))


def map_check(posterior: Posterior, found: MapResult,
              threshold_nats: float = MAP_GAIN_NATS) -> dict:
    """Whether a MAP is at the optimum: the most log posterior a Newton step along one
    coordinate would gain from it, ``max_k g_k^2 / (2 c_k)`` for the gradient ``g`` and
    the curvature ``c`` there (central differences of a ten thousandth of each
    coordinate's Laplace sd).

    Each coordinate's gain is at most the full Newton step's (for a positive definite
    Hessian), so a MAP this calls unconverged is; the full step's is not used because it
    needs the Hessian's inverse, which a stand-in Laplace covariance (correlations
    dropped) does not give. A coordinate whose step leaves the prior's support (a MAP
    on its edge, where the gradient need not vanish), or along which the log posterior
    is not concave there (a kink), is left out.

    Parameters
    ----------
    posterior : Posterior
        The posterior the MAP was found in.
    found : MapResult
        The MAP and its Laplace covariance.
    threshold_nats : float
        The largest gain of a converged MAP.

    Returns
    -------
    dict
        ``"converged"``, ``"newton_gain_nats"`` and ``"messages"`` (why not, in words),
        as a fit file's convergence record has them.
    """
    z0 = np.asarray(found.z, dtype=float)
    p = z0.size
    sd = np.sqrt(np.clip(np.diag(np.asarray(found.covariance_z, dtype=float)), 0.0, None))
    h = 1e-4 * np.where(np.isfinite(sd) & (sd > 0), sd, 1e-6)
    pts = np.vstack([z0, z0 + np.diag(h), z0 - np.diag(h)])
    lp, ll, _ = posterior.evaluate(posterior.to_natural(pts), return_x=False)
    f = lp + ll
    up, down = f[1:p + 1], f[p + 1:]
    g = (up - down) / (2.0 * h)
    c = -(up + down - 2.0 * f[0]) / h**2
    ok = np.isfinite(g) & np.isfinite(c) & (c > 0) & bool(np.isfinite(f[0]))
    gains = np.where(ok, g**2 / (2.0 * np.where(ok, c, 1.0)), 0.0)
    k = int(np.argmax(gains))
    gain = float(gains[k])
    converged = bool(gain <= threshold_nats)
    messages = [] if converged else [
        f"a Newton step from the MAP along {posterior.names[k]} alone would gain "
        f"{gain:.3g} nats of log posterior (a converged search: at most "
        f"{threshold_nats:g})"]
    return {"converged": converged, "newton_gain_nats": gain, "messages": messages}


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
                        str(path), fit_info(tree).get("convergence"))
