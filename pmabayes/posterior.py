"""The posterior: its density, and the fit file that holds its draws.

:class:`Posterior` is the log posterior density of a model's free parameters given
the noise, in the unconstrained coordinates the sampler (:mod:`pmabayes.fit`)
explores. :func:`fit_tree` turns the sampler's draws into the fit, an ArviZ 1.x
DataTree, which :func:`save_fit` writes to NetCDF and :func:`load_fit` reads.
The sampler fills what this module defines, so it sits below the sampler:
likelihood -> posterior -> sampler (fit) -> diagnostics.

Layout of a fit (what :func:`fit_tree` builds for :func:`pmabayes.fit.fit` and
the reports read):

``/posterior``
    One variable per identified parameter (the model's free parameters plus the
    noise parameters ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m``), dims
    ``(chain, draw)``.
    A *chain* is one emcee walker; walkers of all independent ensembles are
    stacked, ensemble after ensemble.
``/sample_stats``
    ``lp`` (log posterior, ``(chain, draw)``) and ``ensemble`` (``(chain,)``: the
    independent ensemble each walker belongs to).
``/log_likelihood``
    ``position_m``, ``(chain, draw, trial)``: the log-likelihood of each trial, for
    leave-one-trial-out comparison.
``/observed_data``
    ``position_m``, ``(trial, time)``.
``/constant_data``
    The input, ``pressure_pa`` or ``force_n``, ``(time,)``.
``/posterior_predictive``
    ``position_m``, ``(chain, draw, trial, time)`` (float32: one chain of
    randomly chosen posterior draws, each with fresh measurement noise) and
    ``model_position_m`` (the noise-free model output for the same draws).
root attribute ``pmabayes``
    A JSON string: the model (effects, rig, fixed values, priors), the data
    source, the noise model, the MAP and the paper's RMS cost, convergence
    diagnostics, seed and timings. :func:`fit_info` decodes it.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import arviz as az
import numpy as np
import xarray as xr

from pmabayes import __version__
from pmabayes.data import DataError, Dataset
from pmabayes.likelihood import NOISE_PARAMETERS, Likelihood, ar1_noise
from pmabayes.model import PAPER_VALUES, Model, Rig
from pmabayes.parameters import HalfNormal, LogNormal, Parameter, Prior, parse_prior

__all__ = ["Posterior", "NoiseEstimate", "fit_tree", "set_fit_info", "save_fit", "load_fit",
           "fit_info", "model_from_fit", "check_dataset", "FitFileError"]


# ---------------------------------------------------------------------------------
# the density, in unconstrained coordinates


def _log_sech2(z: np.ndarray) -> np.ndarray:
    """``log(1 - tanh(z)^2) = -2 log cosh z``, without overflow: the log Jacobian of
    the atanh coordinate."""
    a = np.abs(z)
    return -2.0 * (a + np.log1p(np.exp(-2.0 * a)) - math.log(2.0))


def _transform_kind(p: Parameter, prior: Prior) -> str:
    if p.name == "rho_noise":
        return "atanh"
    if p.bounds[0] >= 0.0 and isinstance(prior, LogNormal | HalfNormal):
        return "log"
    return "identity"


@dataclass(frozen=True)
class NoiseEstimate:
    """The noise parameters' posterior from the spread between repeated trials.

    Parameters
    ----------
    sigma, rho, white : float
        Posterior mode of ``sigma_noise_m``, ``rho_noise`` and ``sigma_white_m``.
    mean_u : numpy.ndarray
        Mode in ``(log sigma, atanh rho, log white)``.
    cov_u : numpy.ndarray
        Laplace covariance there.
    """

    sigma: float
    rho: float
    white: float
    mean_u: np.ndarray
    cov_u: np.ndarray

    def draws(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
        """``n`` independent posterior draws of ``(sigma, rho, white)``."""
        u = rng.multivariate_normal(self.mean_u, self.cov_u, size=n, method="eigh")
        return np.exp(u[:, 0]), np.tanh(u[:, 1]), np.exp(u[:, 2])


class Posterior:
    """Log posterior of a model's free parameters, given the noise.

    Parameters
    ----------
    likelihood : Likelihood
        Data, model and noise model.
    noise : NoiseEstimate
        The noise parameters (from :func:`estimate_noise`); the trial mean's
        likelihood is evaluated at their mode.

    Attributes
    ----------
    names : tuple of str
        Identified model parameters (the model's free parameters).
    """

    def __init__(self, likelihood: Likelihood, noise: NoiseEstimate) -> None:
        self.likelihood = likelihood
        self.noise = noise
        self.model = likelihood.model
        model = self.model
        self.parameters: tuple[Parameter, ...] = tuple(
            model.parameter(n) for n in model.free_names
        )
        self.names: tuple[str, ...] = tuple(p.name for p in self.parameters)
        self.priors: tuple[Prior, ...] = tuple(model.priors[n] for n in model.free_names)
        self.kinds = tuple(
            _transform_kind(p, pr) for p, pr in zip(self.parameters, self.priors, strict=True)
        )
        self._free_cols = np.array([model.index(n) for n in model.free_names], dtype=int)
        self._template = model.theta(model.defaults)[0]
        self.lower = np.array([p.bounds[0] for p in self.parameters])
        self.upper = np.array([p.bounds[1] for p in self.parameters])

    @property
    def ndim(self) -> int:
        """Number of identified parameters."""
        return len(self.names)

    # -- coordinates ------------------------------------------------------------
    def to_natural(self, z: np.ndarray) -> np.ndarray:
        """Natural parameter values from unconstrained coordinates ``(batch, ndim)``."""
        return self._map(z, 0)

    def to_unconstrained(self, theta: np.ndarray) -> np.ndarray:
        """Unconstrained coordinates from natural values ``(batch, ndim)``."""
        return self._map(theta, 1)

    #: each transform's (to natural, to unconstrained) maps
    _MAPS = {"log": (np.exp, np.log), "atanh": (np.tanh, np.arctanh)}

    def _map(self, values: np.ndarray, direction: int) -> np.ndarray:
        values = np.atleast_2d(np.asarray(values, dtype=float))
        out = values.copy()
        with np.errstate(over="ignore", divide="ignore"):
            for j, kind in enumerate(self.kinds):
                if kind in self._MAPS:
                    out[:, j] = self._MAPS[kind][direction](values[:, j])
        return out

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log |d theta / d z|`` per batch member."""
        z = np.atleast_2d(z)
        total = np.zeros(z.shape[0])
        for j, kind in enumerate(self.kinds):
            if kind == "log":
                total += z[:, j]
            elif kind == "atanh":
                total += _log_sech2(z[:, j])
        return total

    def full_theta(self, theta: np.ndarray) -> np.ndarray:
        """The model's full parameter array for identified values ``(batch, ndim)``."""
        theta = np.atleast_2d(theta)
        full = np.repeat(self._template[None, :], theta.shape[0], axis=0)
        full[:, self._free_cols] = theta
        return full

    # -- densities ----------------------------------------------------------------
    def log_prior(self, theta: np.ndarray) -> np.ndarray:
        """Log prior density in natural coordinates, ``-inf`` outside the bounds.

        The one joint log prior of pmabayes: the sum of each parameter's
        :meth:`~pmabayes.parameters.Parameter.log_prior` under the model's priors.
        """
        theta = np.atleast_2d(theta)
        total = np.zeros(theta.shape[0])
        with np.errstate(all="ignore"):  # densities are evaluated out of bounds too
            for j, (p, prior) in enumerate(zip(self.parameters, self.priors, strict=True)):
                total = total + p.log_prior(theta[:, j], prior)
        return total

    def evaluate(
        self, theta: np.ndarray, *, return_x: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Log prior, log likelihood and model output for natural values.

        Parameters
        ----------
        theta : numpy.ndarray
            ``(batch, ndim)`` natural values.
        return_x : bool
            Whether to return the model output (the sampler does not need it).

        Returns
        -------
        log_prior, log_likelihood : numpy.ndarray
            ``(batch,)``; ``-inf`` where out of bounds or the simulation failed. The
            likelihood is that of the trial mean given the noise (the deviations'
            part does not depend on the model).
        x : numpy.ndarray or None
            Model positions of the valid members (NaN rows elsewhere), or None if no
            member was valid or ``return_x`` is false.
        """
        theta = np.atleast_2d(theta)
        lp = self.log_prior(theta)
        ll = np.full(theta.shape[0], -np.inf)
        ok = np.isfinite(lp)
        if not ok.any():
            return lp, ll, None
        sub = theta[ok]
        x_ok = self.likelihood.simulate(self.full_theta(sub))
        finite = np.all(np.isfinite(x_ok), axis=1)
        ll_ok = np.full(sub.shape[0], -np.inf)
        if finite.any():
            ll_ok[finite] = self.likelihood.mean_log_likelihood(
                x_ok[finite], self.noise.sigma, self.noise.rho, self.noise.white
            )
        ll[ok] = ll_ok
        if not return_x:
            return lp, ll, None
        x = np.full((theta.shape[0], self.likelihood.n_samples), np.nan)
        x[ok] = x_ok
        return lp, ll, x

    def log_prob_z(self, z: np.ndarray) -> np.ndarray:
        """Log posterior density in unconstrained coordinates (what emcee samples)."""
        z = np.atleast_2d(z)
        theta = self.to_natural(z)
        lp, ll, _ = self.evaluate(theta, return_x=False)
        out = lp + ll + self.log_jacobian(z)
        return np.where(np.isfinite(out), out, -np.inf)

    def plausible_box(self, rng: np.random.Generator, names: tuple[str, ...]) -> np.ndarray:
        """Unconstrained ``(lower, upper)`` of the 0.5-99.5% prior range of ``names``."""
        idx = [self.names.index(n) for n in names]
        box = np.empty((len(idx), 2))
        for row, j in enumerate(idx):
            draws = self.priors[j].sample(rng, 20000)
            lo, hi = np.quantile(draws, [0.005, 0.995])
            lo = max(lo, self.lower[j] + 1e-12 * max(1.0, abs(self.lower[j])))
            hi = min(hi, self.upper[j])
            ends = np.ones((2, self.ndim))
            ends[:, j] = lo, hi
            box[row] = self.to_unconstrained(ends)[:, j]
        return box


# ---------------------------------------------------------------------------------
# the fit file


def fit_tree(posterior: Posterior, z: np.ndarray, lp_z: np.ndarray, ensemble: np.ndarray, *,
             ppc_draws: int, rng: np.random.Generator) -> xr.DataTree:
    """The fit: the sampler's kept draws, with the noise, likelihood and predictions.

    Parameters
    ----------
    posterior : Posterior
        The density that was sampled.
    z : numpy.ndarray
        Kept draws in unconstrained coordinates, ``(chain, draw, ndim)``; a chain is
        one walker.
    lp_z : numpy.ndarray
        Their log density in unconstrained coordinates, ``(chain, draw)``.
    ensemble : numpy.ndarray
        The independent ensemble of each chain, ``(chain,)``.
    ppc_draws : int
        Posterior draws in the posterior predictive.
    rng : numpy.random.Generator
        Draws the noise parameters, picks the predictive draws and their noise.

    Returns
    -------
    xarray.DataTree
        The layout at the top of this module, but for the root attribute
        ``pmabayes`` (:func:`set_fit_info`).
    """
    lik = posterior.likelihood
    n_chain, n_draw = z.shape[:2]
    flat_z = z.reshape(-1, posterior.ndim)
    theta = posterior.to_natural(flat_z)
    lp = (lp_z.reshape(-1) - posterior.log_jacobian(flat_z)).reshape(n_chain, n_draw)
    # the noise: independent draws from its posterior, paired with the model draws
    sigma, rho, white = posterior.noise.draws(rng, theta.shape[0])
    pointwise = _pointwise(posterior, theta, sigma, rho, white)
    y_pp, x_pp = _predictive(posterior, theta, sigma, rho, white, ppc_draws, rng)
    ds = lik.dataset
    data = {
        "posterior": {
            **{n: theta[:, j].reshape(n_chain, n_draw) for j, n in enumerate(posterior.names)},
            "sigma_noise_m": sigma.reshape(n_chain, n_draw),
            "rho_noise": rho.reshape(n_chain, n_draw),
            "sigma_white_m": white.reshape(n_chain, n_draw),
        },
        "sample_stats": {"lp": lp},
        "log_likelihood": {"position_m": pointwise.reshape(n_chain, n_draw, lik.n_trials)},
        "observed_data": {"position_m": ds.position_m},
        "constant_data": {ds.input_name: ds.input[0]},
        "posterior_predictive": {
            "position_m": y_pp[None].astype(np.float32),
            "model_position_m": x_pp[None].astype(np.float32),
        },
    }
    dims = {"position_m": ["trial", "time"], "model_position_m": ["time"],
            ds.input_name: ["time"]}
    coords = {"trial": ds.trial_ids, "time": ds.time_s}
    # a chain is one walker: more chains than draws is intended, so ArviZ's check
    # that would warn "chain dimension longer than draw" is off
    tree = az.from_dict(data, dims=dims, coords=coords, check_conventions=False)
    # log_likelihood's position_m is per trial only
    ll_ds = xr.Dataset(
        {"position_m": (("chain", "draw", "trial"), pointwise.reshape(n_chain, n_draw,
                                                                      lik.n_trials))},
        coords={"chain": np.arange(n_chain), "draw": np.arange(n_draw), "trial": ds.trial_ids},
    )
    tree["log_likelihood"] = xr.DataTree(ll_ds)
    ss = tree["sample_stats"].to_dataset()
    ss["ensemble"] = ("chain", np.asarray(ensemble))
    tree["sample_stats"] = xr.DataTree(ss)
    return tree


def _pointwise(posterior: Posterior, theta, sigma, rho, white) -> np.ndarray:
    """Per-trial log-likelihood of every draw, simulated in chunks."""
    lik = posterior.likelihood
    out = np.empty((theta.shape[0], lik.n_trials))
    for a in range(0, theta.shape[0], 512):
        sl = slice(a, a + 512)
        x = lik.simulate(posterior.full_theta(theta[sl]))
        out[sl] = lik.pointwise(x, sigma[sl], rho[sl], white[sl])
    return out


def _predictive(posterior: Posterior, theta, sigma, rho, white, ppc_draws: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Random draws' model output, and trials made from it with fresh noise."""
    lik = posterior.likelihood
    pick = rng.choice(theta.shape[0], size=min(ppc_draws, theta.shape[0]), replace=False)
    x_pp = lik.simulate(posterior.full_theta(theta[pick]))
    noise = ar1_noise(len(pick) * lik.n_trials, lik.n_samples,
                      np.repeat(sigma[pick], lik.n_trials), np.repeat(rho[pick], lik.n_trials),
                      rng)
    noise += np.repeat(white[pick], lik.n_trials)[:, None] * rng.standard_normal(noise.shape)
    y_pp = x_pp[:, None, :] + noise.reshape(len(pick), lik.n_trials, lik.n_samples)
    return y_pp, x_pp


def set_fit_info(tree: xr.DataTree, posterior: Posterior, *, map_record: dict,
                 convergence: dict, seed, timings: dict) -> dict:
    """Store a fit's metadata: the root attribute ``pmabayes`` (read by :func:`fit_info`).

    Parameters
    ----------
    tree : xarray.DataTree
        The fit (:func:`fit_tree`); its attribute is set as a JSON string.
    posterior : Posterior
        The density that was sampled: its model, noise and data.
    map_record : dict
        Point estimates (``values``, ``log_posterior``, ``rms_cost_m``,
        ``global_search``).
    convergence : dict
        The sampler's convergence record.
    seed : int or None
        The fit's seed.
    timings : dict
        Wall times in seconds.

    Returns
    -------
    dict
        ``pmabayes_version``, ``model``, ``noise``, ``data``, ``paper_values``,
        ``map``, ``convergence``, ``seed`` and ``timings_s``.
    """
    model = posterior.model
    rows = model.describe()
    for p in NOISE_PARAMETERS:
        rows.append({"name": p.name, "unit": p.unit, "default": p.default,
                     "prior": str(p.prior), "bounds": p.bounds, "fixed": False,
                     "description": p.description, "source": "noise"})
    for row in rows:
        row["bounds"] = [float(b) for b in row["bounds"]]
    ds = posterior.likelihood.dataset
    info = {
        "pmabayes_version": __version__,
        "model": {"effects": list(model.effect_names), "rig": model.rig.to_dict(),
                  "free": list(model.free_names), "fixed": dict(model.fixed),
                  "parameters": rows},
        "noise": {"model": "AR(1) disturbance plus white sensor noise per trial, stationary, "
                           "independent between trials",
                  "parameters": [p.name for p in NOISE_PARAMETERS],
                  "estimated_from": "deviations of the trials from their mean (repeatability); "
                                    "posterior by Laplace approximation, independent draws",
                  "sigma_noise_m": posterior.noise.sigma, "rho_noise": posterior.noise.rho,
                  "sigma_white_m": posterior.noise.white},
        "data": {"source": ds.source, "n_trials": ds.n_trials, "n_samples": ds.n_samples,
                 "dt_s": ds.dt_s, "input_name": ds.input_name,
                 "synthetic": bool(ds.metadata.get("synthetic", False)),
                 "noise_floor_m": ds.noise_floor_m},
        "paper_values": dict(PAPER_VALUES),
        "map": map_record,
        "convergence": convergence,
        "seed": seed,
        "timings_s": timings,
    }
    tree.attrs["pmabayes"] = json.dumps(info)
    return info


class FitFileError(ValueError):
    """A file is not a pmabayes fit."""


def save_fit(tree: xr.DataTree, path: str | Path) -> Path:
    """Write a fit to NetCDF (engine ``h5netcdf``).

    Parameters
    ----------
    tree : xarray.DataTree
        The fit.
    path : str or Path
        Destination, conventionally ``*.nc``; its folder is created.

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # write beside and rename: a crash never leaves half a fit, and a reader that
    # still has the old file open is not disturbed
    tmp = path.with_name(path.name + ".tmp")
    tree.to_netcdf(tmp, engine="h5netcdf")
    os.replace(tmp, path)
    return path


def load_fit(path: str | Path) -> xr.DataTree:
    """Read a fit written by :func:`save_fit`.

    Parameters
    ----------
    path : str or Path
        The NetCDF file.

    Returns
    -------
    xarray.DataTree

    Raises
    ------
    FitFileError
        If the file is missing or is not a pmabayes fit.
    """
    path = Path(path)
    if not path.is_file():
        raise FitFileError(f"{path}: no such fit file; make one with `pmabayes fit`")
    try:
        lazy = az.from_netcdf(path, engine="h5netcdf")
        tree = lazy.load()  # into memory, so the file is not held open
        lazy.close()
    except Exception as exc:  # h5py/xarray raise many types for a bad file
        raise FitFileError(f"{path}: not a readable NetCDF fit ({exc})") from None
    if "pmabayes" not in tree.attrs or "posterior" not in tree.children:
        raise FitFileError(
            f"{path}: a NetCDF file, but not a pmabayes fit (no posterior or no 'pmabayes' "
            "attribute); make one with `pmabayes fit`"
        )
    return tree


def fit_info(tree: xr.DataTree) -> dict:
    """The fit's metadata: model, data, MAP, convergence, seed and timings.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit.

    Returns
    -------
    dict
        Decoded from the root attribute ``pmabayes``.
    """
    try:
        return json.loads(tree.attrs["pmabayes"])
    except (KeyError, json.JSONDecodeError) as exc:
        raise FitFileError(f"not a pmabayes fit: {exc}") from None


def model_from_fit(tree: xr.DataTree) -> Model:
    """Rebuild the fitted model (effects, rig, fixed values) from a fit.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit.

    Returns
    -------
    Model
        Priors are those the fit used; user effects must be registered first
        (``pmabayes --plugin FILE.py`` on the command line).
    """
    m = fit_info(tree).get("model") or {}
    rig = m.get("rig")
    kwargs = {"rig": Rig.from_dict(rig) if isinstance(rig, dict) else None,
              "fixed": m.get("fixed") or None}
    model = Model(list(m.get("effects") or []), **kwargs)
    # the priors the fit used (a user's --prior), where they differ from the defaults
    priors = {row["name"]: parse_prior(row["prior"]) for row in m.get("parameters") or []
              if row.get("name") in model.priors and row.get("prior")
              and row["prior"] != str(model.priors[row["name"]])}
    return Model(list(m.get("effects") or []), priors=priors, **kwargs) if priors else model


def check_dataset(tree: xr.DataTree, dataset: Dataset) -> None:
    """Check that a data set is the one a fit was made from.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit.
    dataset : Dataset
        The data.

    Raises
    ------
    DataError
        If the trials' shape, positions (within 1e-12 m) or times differ.
    """
    if not isinstance(dataset, Dataset):
        raise TypeError(f"dataset must be a pmabayes.data.Dataset, got {type(dataset).__name__}")
    fit_src = (fit_info(tree).get("data") or {}).get("source") or "the fit"
    obs = tree["observed_data"]["position_m"].transpose("trial", "time")
    where = (f"dataset {dataset.source or '(no source)'} does not match the observed data "
             f"of the fit (made from {fit_src})")
    if obs.shape != dataset.position_m.shape:
        raise DataError(
            f"{where}: position_m has shape {dataset.position_m.shape} (trials, samples), "
            f"the fit's has {obs.shape}"
        )
    diff = float(np.max(np.abs(np.asarray(obs.values, dtype=float) - dataset.position_m)))
    if not diff <= 1e-12:
        raise DataError(f"{where}: position_m differs by up to {diff:.3g} m (tolerance 1e-12 m)")
    t = np.asarray(obs["time"].values, dtype=float)
    t_diff = float(np.max(np.abs(t - dataset.time_s)))
    if not t_diff <= 1e-12 * max(1.0, float(np.max(np.abs(t)))):
        raise DataError(f"{where}: the sample times differ by up to {t_diff:.3g} s")
