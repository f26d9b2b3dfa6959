"""The fit file: the sampler's draws as an ArviZ 1.x DataTree
(:func:`fit_tree`, :func:`set_fit_info`), written to NetCDF (:func:`save_fit`) and read
back (:func:`load_fit`, :func:`fit_info`), with each experiment's data set, model and noise
model rebuilt from it. The documentation's page on the fit file gives the layout, for
one experiment and for several.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from collections.abc import Sequence
from pathlib import Path

import arviz as az
import numpy as np
import xarray as xr

from pmabayes import __version__
from pmabayes.data import DataError, Dataset
from pmabayes.inference.density import Posterior
from pmabayes.inference.likelihood import NOISE_PARAMETERS, ArNoise, Likelihood
from pmabayes.inference.noise import NoiseModel, noise_model_from_record
from pmabayes.model.model import PAPER_VALUES, Model, Rig
from pmabayes.model.parameters import parse_prior
from pmabayes.util import finite_or_none

__all__ = [
    "fit_tree",
    "set_fit_info",
    "experiment_records",
    "experiment_names",
    "experiment_datasets",
    "as_fitted",
    "FIT_METADATA",
    "experiment_models",
    "noise_models",
    "fit_noise_models",
    "FitFileError",
    "is_fit_file",
    "save_fit",
    "load_fit",
    "fit_info",
    "model_from_fit",
    "check_dataset",
]


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
    n_chain, n_draw = z.shape[:2]
    flat_z = z.reshape(-1, posterior.ndim)
    theta = posterior.to_natural(flat_z)
    lp = (lp_z.reshape(-1) - posterior.log_jacobian(flat_z)).reshape(n_chain, n_draw)
    # the noise: sampled with the model where there are no repeats, else independent
    # draws from its posterior paired with the model draws (one set per noise group)
    group_draws = {g: est.draws(rng, theta.shape[0])
                   for g, est in enumerate(posterior.group_noise) if est is not None}
    noise = [group_draws[posterior.groups[e]] if not posterior.noise_sampled(e)
             else posterior.noise_of(e, theta) for e in range(posterior.n_experiments)]
    pointwise = [_pointwise(posterior, e, theta, *noise[e])
                 for e in range(posterior.n_experiments)]
    pick = rng.choice(theta.shape[0], size=min(ppc_draws, theta.shape[0]), replace=False)
    preds = [_predictive(posterior, e, theta, *noise[e], pick, rng=rng)
             for e in range(posterior.n_experiments)]
    model_post = {n: theta[:, j].reshape(n_chain, n_draw)
                  for j, n in enumerate(posterior.names[: posterior.n_model])}
    # estimated starts: x0_m, ... (one experiment) or x0_m__NAME, ... (several)
    for e, cols in posterior.start_columns.items():
        for c in cols:
            name = posterior.parameters[c].name
            if posterior.n_experiments > 1:
                name = f"{name}__{posterior.experiment_names[e]}"
            model_post[name] = theta[:, c].reshape(n_chain, n_draw)
    keys = posterior.noise_names()
    if posterior.n_experiments == 1:
        tree = _single_tree(posterior.likelihoods[0], model_post, keys, noise[0], lp,
                            pointwise[0], preds[0], n_chain, n_draw)
    else:
        tree = _multi_tree(posterior, model_post, keys, noise, lp, pointwise, preds,
                           n_chain, n_draw)
    ss = tree["sample_stats"].to_dataset()
    ss["ensemble"] = ("chain", np.asarray(ensemble))
    tree["sample_stats"] = xr.DataTree(ss)
    return tree


def _single_tree(lik: Likelihood, model_post: dict, keys, noise, lp, pointwise, pred,
                 n_chain: int, n_draw: int) -> xr.DataTree:
    """The layout of a one-experiment fit (unchanged since the first fit files)."""
    y_pp, x_pp = pred
    ds = lik.dataset
    # trials with their own inputs: each trial's input, and its model output
    own = lik.own_inputs
    data = {
        "posterior": {**model_post, **{k: np.asarray(v).reshape(n_chain, n_draw)
                                       for k, v in zip(keys, noise, strict=True)}},
        "sample_stats": {"lp": lp},
        "observed_data": {"position_m": ds.position_m},
        "constant_data": {ds.input_name: ds.input if own else ds.input[0]},
        "posterior_predictive": {
            "position_m": y_pp[None].astype(np.float32),
            "model_position_m": x_pp[None].astype(np.float32),
        },
    }
    dims = {"position_m": ["trial", "time"],
            "model_position_m": ["trial", "time"] if own else ["time"],
            ds.input_name: ["trial", "time"] if own else ["time"]}
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
    return tree


def _multi_tree(posterior: Posterior, model_post: dict, keys, noise, lp, pointwise, preds,
                n_chain: int, n_draw: int) -> xr.DataTree:
    """The layout of a fit of several experiments (see the module's docstring)."""
    names = posterior.experiment_names
    noise_post = {k: np.stack([np.broadcast_to(np.asarray(noise[e][j], dtype=float),
                                               (n_chain * n_draw,))
                               for e in range(len(names))], axis=1).reshape(n_chain, n_draw, -1)
                  for j, k in enumerate(keys)}
    tree = az.from_dict(
        {"posterior": {**model_post, **noise_post}, "sample_stats": {"lp": lp}},
        dims={k: ["experiment"] for k in keys}, coords={"experiment": names},
        check_conventions=False)
    chain_draw = {"chain": np.arange(n_chain), "draw": np.arange(n_draw)}
    obs, const, pp = {}, {}, {}
    coords: dict = {}
    for e, name in enumerate(names):
        ds = posterior.likelihoods[e].dataset
        trial, time_ = f"trial__{name}", f"time__{name}"
        coords[trial], coords[time_] = ds.trial_ids, ds.time_s
        obs[f"position_m__{name}"] = ((trial, time_), ds.position_m)
        own = posterior.likelihoods[e].own_inputs
        const[f"{ds.input_name}__{name}"] = (((trial, time_), ds.input) if own
                                             else ((time_,), ds.input[0]))
        y_pp, x_pp = preds[e]
        pp[f"position_m__{name}"] = (("chain", "draw", trial, time_),
                                     y_pp[None].astype(np.float32))
        pp[f"model_position_m__{name}"] = (("chain", "draw", *((trial,) if own else ()), time_),
                                           x_pp[None].astype(np.float32))
    n_pp = preds[0][1].shape[0]
    tree["observed_data"] = xr.DataTree(xr.Dataset(obs, coords=coords))
    tree["constant_data"] = xr.DataTree(xr.Dataset(const, coords=coords))
    tree["posterior_predictive"] = xr.DataTree(xr.Dataset(
        pp, coords={**coords, "chain": [0], "draw": np.arange(n_pp)}))
    # LOO over all trials: one trial dimension across the experiments
    ll = np.concatenate(pointwise, axis=1)
    trial_exp = np.concatenate([[name] * p.shape[1] for name, p in zip(names, pointwise,
                                                                        strict=True)])
    trial_id = np.concatenate([posterior.likelihoods[e].dataset.trial_ids
                               for e in range(len(names))])
    tree["log_likelihood"] = xr.DataTree(xr.Dataset(
        {"position_m": (("chain", "draw", "trial"), ll.reshape(n_chain, n_draw, -1))},
        coords={**chain_draw, "trial": np.arange(ll.shape[1]),
                "experiment": ("trial", trial_exp), "trial_id": ("trial", trial_id)}))
    return tree


def _pointwise(posterior: Posterior, e: int, theta, *noise) -> np.ndarray:
    """Per-trial log-likelihood of every draw for experiment ``e``, in chunks."""
    lik = posterior.likelihoods[e]
    noise = [np.broadcast_to(np.asarray(v, dtype=float), (theta.shape[0],)) for v in noise]
    out = np.empty((theta.shape[0], lik.n_trials))
    for a in range(0, theta.shape[0], 512):
        sl = slice(a, a + 512)
        x = posterior.simulate(theta[sl], e)
        out[sl] = lik.pointwise(x, *(v[sl] for v in noise))
    return out


def _predictive(posterior: Posterior, e: int, theta, *noise_and_pick,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Picked draws' model output for experiment ``e`` (per trial, ``(draws, trials,
    n)``, for trials with their own inputs), and trials made from it with fresh noise
    of the likelihood's own noise model (``noise_and_pick``: the noise parameters,
    then the picked draws' indices)."""
    *noise, pick = noise_and_pick
    lik = posterior.likelihoods[e]
    noise = [np.broadcast_to(np.asarray(v, dtype=float), (theta.shape[0],)) for v in noise]
    x_pp = posterior.simulate(theta[pick], e)
    x_pp = lik._by_trial(x_pp) if lik.own_inputs else x_pp
    noise = lik.noise.draw(len(pick) * lik.n_trials, lik.n_samples,
                           tuple(np.repeat(v[pick], lik.n_trials) for v in noise), rng)
    y_pp = ((x_pp if lik.own_inputs else x_pp[:, None, :])
            + noise.reshape(len(pick), lik.n_trials, lik.n_samples))
    return y_pp, x_pp


def set_fit_info(tree: xr.DataTree, posterior: Posterior, *, map_record: dict,
                 convergence: dict, seed, timings: dict,
                 noise_values: dict | None = None) -> dict:
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
    noise_values : dict, optional
        The noise to record (:meth:`Posterior.noise_values`): the posterior median
        where it is sampled with the model. The MAP's noise by default.

    Returns
    -------
    dict
        ``pmabayes_version``, ``model``, ``noise``, ``data``, ``experiments``
        (:func:`experiment_records`), ``paper_values``, ``map``, ``convergence``,
        ``seed`` and ``timings_s``.
    """
    model = posterior.model
    rows = model.describe()
    ident = dict(zip(posterior.names, zip(posterior.parameters, posterior.priors,
                                          strict=True), strict=True))
    for name in posterior.names[: posterior.n_model]:  # another experiment's own ones
        if name not in model.parameter_names:
            p, prior = ident[name]
            rows.append({"name": name, "unit": p.unit, "default": p.default,
                         "prior": str(prior), "bounds": p.bounds, "fixed": False,
                         "description": p.description, "source": "experiment"})
    sampled = {p.name: p for p in posterior.parameters[posterior.n_model:]}
    noise_names = posterior.noise_names()
    known = {p.name: p for p in (*posterior.likelihoods[0].noise_parameters(),
                                 *NOISE_PARAMETERS)}
    for name in noise_names:
        p = sampled.get(name, known[name])  # a sampled noise's prior (guarded, data's scale)
        rows.append({"name": p.name, "unit": p.unit, "default": p.default,
                     "prior": str(p.prior), "bounds": p.bounds, "fixed": False,
                     "description": p.description, "source": "noise"})
    for row in rows:
        row["bounds"] = [float(b) for b in row["bounds"]]
    source = noise_values if noise_values is not None else (map_record.get("values") or {})
    noise_map = {k: source.get(k) for k in noise_names}
    experiments = experiment_records(posterior, noise_map, map_record.get("values"))
    sources = {"sampled" if not c.model.from_repeats else
               "own inputs" if e.get("own_inputs") else e["noise_source"]
               for e, c in zip(experiments, posterior.noise_choices, strict=True)}
    estimated_from = "; ".join(
        text for key, text in (
            ("trials", "deviations of the trials from their mean (repeatability); posterior by "
                       "Laplace approximation, independent draws"),
            ("own inputs", "deviations of the trials' residuals from their mean at the MAP, "
                           "each trial's model simulated on its own measured input (the "
                           "model's response to the inputs' differences cancels); posterior "
                           "by Laplace approximation, independent draws"),
            ("periods", "deviations of the periods of a single periodic record from their "
                        "mean; posterior by Laplace approximation, independent draws"),
            ("record", "the record itself, jointly with the model (sampled), the disturbance's "
                       "correlation time bounded far below the input's time scales"),
            ("sampled", "the data themselves, jointly with the model (sampled)"))
        if key in sources)
    texts = list(dict.fromkeys(c.model.description for c in posterior.noise_choices))
    # a text another extends (AR(1) + white's, by the repeats' AR(p)'s) is said once
    texts = [t for t in texts if not any(o != t and o.startswith(t) for o in texts)]
    noise = {"model": "; ".join(texts), "parameters": noise_names,
             "estimated_from": estimated_from, **noise_map}
    if posterior.n_experiments == 1:
        ds = posterior.likelihoods[0].dataset
        data = {"source": ds.source, "n_trials": ds.n_trials, "n_samples": ds.n_samples,
                "dt_s": ds.dt_s, "input_name": ds.input_name,
                "synthetic": bool(ds.metadata.get("synthetic", False)),
                "noise_floor_m": finite_or_none(_noise_floor(posterior.likelihoods[0]))}
    else:
        dss = [lik.dataset for lik in posterior.likelihoods]
        noise["tied"] = len(set(posterior.groups)) == 1
        data = {"source": " + ".join(str(d.source or n) for d, n in
                                     zip(dss, posterior.experiment_names, strict=True)),
                "n_experiments": len(dss),
                "n_trials": int(sum(d.n_trials for d in dss)),
                "n_samples": int(sum(d.n_samples for d in dss)),
                "input_name": dss[0].input_name,
                "synthetic": all(bool(d.metadata.get("synthetic", False)) for d in dss),
                "noise_floor_m": None}
    info = {
        "pmabayes_version": __version__,
        "model": {"effects": list(model.effect_names), "rig": model.rig.to_dict(),
                  "free": list(model.free_names), "fixed": dict(model.fixed),
                  "parameters": rows},
        "noise": noise,
        "data": data,
        "experiments": experiments,
        "paper_values": dict(PAPER_VALUES),
        "map": map_record,
        "convergence": convergence,
        "seed": seed,
        "substeps": int(posterior.likelihoods[0].substeps),
        "timings_s": timings,
    }
    record = posterior.settings_record or {}
    if record.get("substeps"):
        info["substeps_choice"] = record["substeps"]
    if record.get("data_scaled_priors"):
        info["data_scaled_priors"] = record["data_scaled_priors"]
    tree.attrs["pmabayes"] = json.dumps(info)
    return info


def experiment_records(posterior: Posterior, noise_map: dict | None = None,
                       map_values: dict | None = None) -> list[dict]:
    """The ``experiments`` entry of a fit's metadata: one dict per experiment.

    Parameters
    ----------
    posterior : Posterior
        The density that was sampled.
    noise_map : dict, optional
        The noise at the MAP (:meth:`Posterior.noise_values`), for the noise that
        is sampled with the model.
    map_values : dict, optional
        The MAP (every identified parameter by name), for each experiment's RMS
        cost there.

    Returns
    -------
    list of dict
        Each with ``name``, ``source``, ``rig`` (dict), ``n_trials``,
        ``n_samples``, ``dt_s``, ``input_name``, ``input_between_samples``,
        ``period_samples``, ``starts_in_steady_state``, ``noise`` (``"own"`` or
        ``"tied"``), ``noise_source`` (``"trials"``, ``"periods"`` or
        ``"record"``), ``periods_referred_to_model`` (the periods of a record from
        rest taken from its residual at the MAP,
        :func:`pmabayes.inference.noise_start.refer_periods`), ``noise_estimate`` (the
        noise's mode), ``noise_model``
        (:meth:`pmabayes.inference.likelihood.NoiseChoice.to_dict`), ``rms_cost_m``
        (the paper's cost at the MAP, None without it),
        ``noise_floor_m`` (None without repeats; of the trials' residuals at
        the MAP for trials with their own inputs; of a periodic record's periods,
        :attr:`pmabayes.inference.likelihood.Likelihood.periods_noise_floor_m`), ``synthetic``,
        ``metadata`` (the data set's, to rebuild it), ``trial_ids`` (the trials fitted) and
        ``source_path`` (the resolved path of its file, None without a source).
    """
    noise_map = noise_map or {}
    map_values = map_values or {}
    theta = None
    searched = posterior.names[: posterior.n_searched]  # the model's and the starts'
    if all(n in map_values for n in searched):
        theta = np.zeros((1, posterior.ndim))
        theta[0, : posterior.n_searched] = [float(map_values[n]) for n in searched]
    out = []
    tied = len(set(posterior.groups)) < len(posterior.groups)
    for e, (lik, name) in enumerate(zip(posterior.likelihoods, posterior.experiment_names,
                                        strict=True)):
        ds = lik.dataset
        if posterior.noise_sampled(e):
            est = {}
            for k in posterior.noise_names():
                v = noise_map.get(k)
                est[k] = v.get(name) if isinstance(v, dict) else v
        else:
            g = posterior.group_noise[posterior.groups[e]]
            est = {"sigma_noise_m": g.sigma, "rho_noise": g.rho, "sigma_white_m": g.white}
        out.append({
            "name": name, "source": ds.source, "rig": lik.model.rig.to_dict(),
            "n_trials": int(ds.n_trials), "n_samples": int(ds.n_samples), "dt_s": ds.dt_s,
            "input_name": ds.input_name, "input_between_samples": ds.input_between_samples,
            "period_samples": ds.period_samples,
            "starts_in_steady_state": ds.starts_in_steady_state,
            "noise": "tied" if tied else "own", "noise_source": lik.noise_source,
            "periods_referred_to_model": lik.periods_referred, "noise_estimate": est,
            "noise_model": posterior.noise_choices[e].to_dict(),
            "noise_floor_m": finite_or_none(_noise_floor(lik)),
            "rms_cost_m": (None if theta is None else finite_or_none(
                lik.rms_cost(posterior.simulate(theta, e))[0])),
            "parameters": dict(posterior.identified[e]),
            "synthetic": bool(ds.metadata.get("synthetic", False)),
            "metadata": ds.metadata,
            # which trials of which file were fitted: validate refuses them as held out
            "trial_ids": [int(i) for i in ds.trial_ids],
            "source_path": ds.source_file and os.path.realpath(ds.source_file),
        })
        out[-1].update(_likelihood_record(posterior, e))
    return out


def _noise_floor(lik: Likelihood) -> float:
    """The data's noise floor: of the trials, or of their residuals at the MAP where
    the trials have their own inputs (the raw trials' spread holds the model's response
    to the inputs' differences); of a periodic record, of its periods (as ``diagnose``
    and the adequacy verdict take it)."""
    if lik.noise_source == "periods":
        return lik.periods_noise_floor_m
    return lik.referred_noise_floor_m if lik.trials_referred else lik.dataset.noise_floor_m


def _likelihood_record(posterior: Posterior, e: int) -> dict:
    """What an experiment's likelihood took beyond complete, shared, known-start trials:
    samples missing in it, trials with their own inputs, an estimated start (nothing
    for data that have none of them, so that their records stay as they were)."""
    lik = posterior.likelihoods[e]
    out: dict = {}
    if lik.observed is not None:
        out["missing_samples"] = {
            "not_observed": int(lik.dataset.n_missing), "warmup_s": lik.dataset.warmup_s,
            "left_out_of_likelihood": int((~lik.observed).sum()),
            "how": "missing in the likelihood: the Kalman filter predicts across them "
                   "(no update), the input follows input_between_samples"}
    if lik.own_inputs:
        out["own_inputs"] = True
        out["trials_referred_to_model"] = lik.trials_referred
        out["noise_floor_of_raw_trials_m"] = finite_or_none(lik.dataset.noise_floor_m)
    if e in posterior.start_columns:
        out["start"] = {"initial_state": "estimate",
                        "parameters": {posterior.names[c]: {
                            "unit": posterior.parameters[c].unit,
                            "prior": str(posterior.priors[c]),
                            "description": posterior.parameters[c].description}
                            for c in posterior.start_columns[e]}}
    return out


def experiment_names(sources) -> list[str]:
    """Unique experiment names from data sources: their file stems.

    Parameters
    ----------
    sources : sequence of str or None
        The data sets' sources (file paths).

    Returns
    -------
    list of str
        Each stem with characters other than letters, digits, ``_`` and ``-``
        replaced by ``_``; repeated stems get ``_2``, ``_3``, ...;
        ``experiment_N`` where there is no source.
    """
    out: list[str] = []
    for i, src in enumerate(sources):
        stem = Path(str(src)).stem if src else f"experiment_{i + 1}"
        base = re.sub(r"[^A-Za-z0-9_-]", "_", stem) or f"experiment_{i + 1}"
        name, k = base, 2
        while name in out:
            name, k = f"{base}_{k}", k + 1
        out.append(name)
    return out


def _experiments_of(tree: xr.DataTree) -> list[dict]:
    """The fit's experiment records; a fit written before them counts as one."""
    info = fit_info(tree)
    exps = info.get("experiments")
    if exps:
        return exps
    d = info.get("data") or {}
    return [{"name": experiment_names([d.get("source")])[0], "source": d.get("source"),
             "rig": (info.get("model") or {}).get("rig"), "input_name": d.get("input_name"),
             "metadata": {"synthetic": bool(d.get("synthetic", False))}}]


#: Metadata a fit adds to its data sets (a record's disturbance:
#: :func:`pmabayes.inference.disturbance.settle_disturbance`); a data set given beside a
#: fit takes them from the fit, so that its likelihood is the fit's.
FIT_METADATA: tuple[str, ...] = ("disturbance_max_s", "disturbance_check")


def as_fitted(tree: xr.DataTree, datasets: Sequence[Dataset]) -> list[Dataset]:
    """Data sets given beside a fit, with the metadata the fit added to them.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit.
    datasets : sequence of Dataset
        Its experiments' data, in its order (as read from their files).

    Returns
    -------
    list of Dataset
        Each with the fit's :data:`FIT_METADATA` keys over its own (unchanged where the
        fit added none).
    """
    out = []
    for exp, ds in zip(_experiments_of(tree), datasets, strict=False):
        stored = {k: v for k, v in (exp.get("metadata") or {}).items() if k in FIT_METADATA}
        out.append(dataclasses.replace(ds, metadata={**ds.metadata, **stored}) if stored
                   else ds)
    return out + list(datasets[len(out):])


def experiment_datasets(tree: xr.DataTree) -> list[Dataset]:
    """The data sets of a fit, one per experiment, rebuilt from the fit file.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit; its groups ``observed_data`` and ``constant_data`` hold the data.

    Returns
    -------
    list of Dataset
        Time, input, positions, trial ids, metadata and source of each experiment,
        in the fit's order.

    Examples
    --------
    A short fit (too short to converge, for the example), and the data it holds:

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.inference.fitfile import experiment_datasets
    >>> experiment_datasets(tree)
    [Dataset(n_trials=3, n_samples=800, dt_s=0.005, input_name='pressure_pa', trial_ids=[0, 1, 2],
             source=None)]
    >>> from pmabayes.synthetic import example_data
    >>> experiment_datasets(tree)[0] == example_data()  # the data it was fitted to
    True
    """
    exps = _experiments_of(tree)
    obs_g = tree["observed_data"]
    const = tree["constant_data"] if "constant_data" in tree.children else None
    out = []
    for exp in exps:
        single = len(exps) == 1
        var = "position_m" if single else f"position_m__{exp['name']}"
        time_dim = "time" if single else f"time__{exp['name']}"
        trial_dim = "trial" if single else f"trial__{exp['name']}"
        name = exp.get("input_name") or "pressure_pa"
        u_var = name if single else f"{name}__{exp['name']}"
        obs = obs_g[var].transpose(trial_dim, time_dim)
        # without the stored input (an old fit), zeros; trials with their own inputs
        # have one each
        u = (const[u_var].transpose(..., time_dim).values
             if const is not None and u_var in const.data_vars else np.zeros(obs.sizes[time_dim]))
        u = np.asarray(u, dtype=float)
        position = np.asarray(obs.values, dtype=float)
        seen = np.isfinite(position)  # a sample not observed is stored as NaN
        out.append(Dataset(time_s=np.asarray(obs[time_dim].values, dtype=float),
                           input=u if u.ndim == 2 else np.tile(u, (obs.sizes[trial_dim], 1)),
                           position_m=position,
                           trial_ids=np.asarray(obs[trial_dim].values), input_name=name,
                           metadata=dict(exp.get("metadata") or {}), source=exp.get("source"),
                           observed=None if seen.all() else seen))
    return out


def experiment_models(tree: xr.DataTree) -> list[Model]:
    """The fitted model on each experiment's rig (effects and fixed values shared).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit; its metadata names the model and each experiment's rig.

    Returns
    -------
    list of Model
        In the fit's experiment order; see :func:`model_from_fit`.

    Examples
    --------
    A short fit (too short to converge, for the example), and its model:

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.inference.fitfile import experiment_models
    >>> experiment_models(tree)
    [Model(rig=characterisation, effects=none, parameters=6)]
    """
    base = model_from_fit(tree)
    return [base.on_rig(Rig.from_dict(exp["rig"])) if isinstance(exp.get("rig"), dict)
            else base for exp in _experiments_of(tree)]


def noise_models(tree: xr.DataTree) -> list[ArNoise | None]:
    """The noise model each experiment's likelihood used, rebuilt from a fit.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit, read as by :func:`fit_noise_models`.

    Returns
    -------
    list of ArNoise or None
        In the fit's experiment order: the AR(p) of the repeats, or None for AR(1)
        + white (and for fits written before noise models were recorded).
    """
    return [getattr(m, "ar", None) for m in fit_noise_models(tree)]


def fit_noise_models(tree: xr.DataTree) -> list[NoiseModel]:
    """The noise model object each experiment's likelihood used, rebuilt from a fit
    (:func:`pmabayes.inference.noise.noise_model_from_record`).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit; its metadata records each experiment's noise model.

    Returns
    -------
    list of NoiseModel
        In the fit's experiment order; AR(1) + white for fits written before noise
        models were recorded.

    Raises
    ------
    FitFileError
        For a noise model no registered model has (a plugin's, not loaded).
    """
    out = []
    for exp in _experiments_of(tree):
        try:
            out.append(noise_model_from_record(exp.get("noise_model")))
        except KeyError as err:
            raise FitFileError(f"{err.args[0]}: load the plugin that registers it "
                               "(--plugin) before reading this fit") from None
    return out


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


def is_fit_file(path: str | Path) -> bool:
    """Whether ``path`` is a fit that :func:`save_fit` wrote: an HDF5 file whose root
    carries the ``pmabayes`` attribute. Only the attributes are read.

    Parameters
    ----------
    path : str or Path
        Any path, a fit or not.

    Returns
    -------
    bool
        False for a missing, unreadable or other file.
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "pmabayes" in f.attrs
    except (OSError, ValueError):  # not HDF5, or not readable
        return False


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

    Examples
    --------
    A fit written by ``pmabayes fit muscle_a.csv --out fit.nc`` (or by
    :func:`save_fit`), read back with its posterior, noise and data:

    >>> import pmabayes
    >>> tree = pmabayes.load_fit("fit.nc")  # doctest: +SKIP
    >>> "posterior" in tree.children, "observed_data" in tree.children  # doctest: +SKIP
    (True, True)
    >>> tree.posterior["tau_reg"].dims  # doctest: +SKIP
    ('chain', 'draw')
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
        A fit (:func:`load_fit`).

    Returns
    -------
    dict
        Decoded from the root attribute ``pmabayes``.

    Examples
    --------
    A short fit (too short to converge, for the example), and what it records:

    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # a short fit of synthetic chirps (warns: not converged)
    >>> from pmabayes.inference.fitfile import fit_info
    >>> info = fit_info(tree)
    >>> sorted(info)
    ['convergence', 'data', 'experiments', 'map', 'model', 'noise', 'paper_values', ...]
    >>> info["seed"], info["data"]["n_trials"], info["model"]["free"]
    (0, 3, ['alpha', 'beta', 'gamma', 'd', 'K_e', 'p_dz'])
    >>> info["convergence"]["converged"]
    False
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
        A fit; its metadata names the effects, the rig and the fixed values.

    Returns
    -------
    Model
        Priors are those the fit used; user effects must be registered first
        (``pmabayes --plugin FILE.py`` on the command line).
    """
    m = fit_info(tree).get("model") or {}
    rig = m.get("rig")
    # a parameter fixed by default that the fit freed is free again ("free"; older fits
    # did not record it)
    kwargs = {"rig": Rig.from_dict(rig) if isinstance(rig, dict) else None,
              "fixed": m.get("fixed") or None, "free": m.get("free") or None}
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
    a, b = np.asarray(obs.values, dtype=float), dataset.position_m
    if not np.array_equal(np.isnan(a), np.isnan(b)):  # samples not observed are NaN in both
        raise DataError(f"{where}: the samples observed differ")
    diff = float(np.max(np.abs(a - b), initial=0.0, where=~np.isnan(b)))
    if not diff <= 1e-12:
        raise DataError(f"{where}: position_m differs by up to {diff:.3g} m (tolerance 1e-12 m)")
    t = np.asarray(obs["time"].values, dtype=float)
    t_diff = float(np.max(np.abs(t - dataset.time_s)))
    if not t_diff <= 1e-12 * max(1.0, float(np.max(np.abs(t)))):
        raise DataError(f"{where}: the sample times differ by up to {t_diff:.3g} s")
