"""What the reports read from a fit: its variables flattened per experiment, its metadata
checked, its data rebuilt, and its posterior predictive band.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr

from pmabayes.criticism.observed import mean_of_observed, share_inside, trial_weights
from pmabayes.data import DataError, Dataset
from pmabayes.inference.fitfile import (
    FitFileError,
    experiment_datasets,
    fit_info,
)

__all__ = ["predictive_band"]


_QUANTILE_BLOCK = 4_000_000  # values per block when taking quantiles of the predictive


def flatten(tree: xr.DataTree) -> xr.DataTree:
    """The fit with each per-experiment posterior variable split into one variable per
    experiment (``sigma_noise_m[NAME]``), as the tables and figures read it."""
    post = tree["posterior"].to_dataset()
    if not any("experiment" in v.dims for v in post.data_vars.values()):
        return tree
    flat = {}
    for name, var in post.data_vars.items():
        if "experiment" in var.dims:
            for e in post["experiment"].values:
                flat[f"{name}[{e}]"] = var.sel(experiment=e, drop=True)
        else:
            flat[name] = var
    out = tree.copy()
    out["posterior"] = xr.DataTree(xr.Dataset(flat).drop_vars("experiment", errors="ignore"))
    return out


def map_value(values: Mapping | None, name: str) -> float | None:
    """The MAP of a posterior variable, ``NAME[EXPERIMENT]`` for per-experiment noise."""
    base, _, exp = name.partition("[")
    if exp and values and isinstance(values.get(base), Mapping):
        return opt_float(values[base], exp.rstrip("]"))
    return opt_float(values, name)


def opt_float(mapping: Mapping | None, name: str) -> float | None:
    """``float(mapping[name])``, or None when the mapping or the entry is missing."""
    if not mapping or mapping.get(name) is None:
        return None
    return float(mapping[name])


def check_ci_prob(ci_prob: float) -> float:
    ci = float(ci_prob)
    if not 0.0 < ci < 1.0:
        raise ValueError(f"ci_prob must be in (0, 1), got {ci_prob!r}")
    return ci


def check_tree(tree: xr.DataTree, groups: Sequence[str]) -> dict:
    """Decode the fit's metadata and check that the groups the report reads exist."""
    if not isinstance(tree, xr.DataTree):
        raise TypeError(f"a fit is an xarray.DataTree, got {type(tree).__name__}")
    info = fit_info(tree)
    missing = [g for g in groups if g not in tree.children]
    if missing:
        raise FitFileError(
            f"the fit has no group(s) {', '.join(missing)}; a report needs the layout of "
            "pmabayes.inference.posterior (write the fit with `pmabayes fit`)"
        )
    for name, var in tree["posterior"].data_vars.items():
        if set(var.dims) - {"experiment"} != {"chain", "draw"}:
            raise FitFileError(
                f"posterior variable {name!r} has dims {var.dims}; expected (chain, draw), "
                "or (chain, draw, experiment) for a fit of several experiments"
            )
    return info


def _quantiles_over_samples(
    da: xr.DataArray, probs: Sequence[float], *, time_dim: str = "time"
) -> np.ndarray:
    """Quantiles over every dimension except ``time_dim``, block by block in time.

    Only one block of the (possibly lazily loaded, float32) array is in memory at a
    time. Returns shape ``(len(probs), n_time)``.
    """
    da = da.transpose(..., time_dim)
    n_time = da.sizes[time_dim]
    n_rows = max(1, int(da.size // max(n_time, 1)))
    step = max(1, _QUANTILE_BLOCK // n_rows)
    out = np.empty((len(probs), n_time))
    for a in range(0, n_time, step):
        block = np.asarray(da.isel({time_dim: slice(a, a + step)}).values)
        out[:, a : a + step] = np.quantile(block.reshape(n_rows, -1), probs, axis=0)
    return out


def units_of(info: dict) -> dict[str, str]:
    """Parameter name -> SI unit, from the fit's parameter table (noise included)."""
    params = (info.get("model") or {}).get("parameters") or []
    return {p["name"]: str(p.get("unit") or "") for p in params if "name" in p}


def source_name(info: dict, dataset: Dataset | None) -> str:
    if dataset is not None and dataset.source:
        return str(dataset.source)
    return str((info.get("data") or {}).get("source") or "unnamed data")


def predictive_band(tree: xr.DataTree, *, ci_prob: float = 0.9) -> dict[str, np.ndarray]:
    """The posterior predictive band of a fit, pooled over its stored draws.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit with ``observed_data`` and ``posterior_predictive`` groups.
    ci_prob : float, optional
        Central probability of the band (0.9).

    Returns
    -------
    dict
        ``time`` [s], ``trials``, ``data`` (``(n_trials, n_samples)`` in m),
        ``median`` (the median noise-free model position in m), ``low`` and
        ``high`` (the band's edges in m, with measurement noise) and ``coverage``
        (fraction of all measured samples inside the band).

    Raises
    ------
    ValueError
        If ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` lacks the groups.
    """
    ci_prob = check_ci_prob(ci_prob)
    check_tree(tree, ["observed_data", "posterior_predictive"])
    return predictive(tree, ci_prob)


def predictive(tree: xr.DataTree, ci_prob: float, experiment: str | None = None
               ) -> dict[str, np.ndarray]:
    """Time, data, median model and the pooled central predictive band (all in m), of the
    fit or of one experiment (by name) of a fit of several."""
    tag = "" if experiment is None else f"__{experiment}"
    trial, time_ = f"trial{tag}", f"time{tag}"
    obs = tree["observed_data"][f"position_m{tag}"].transpose(trial, time_)
    pp = tree["posterior_predictive"]
    q = (1.0 - ci_prob) / 2.0
    model = pp[f"model_position_m{tag}"]
    if trial in model.dims:  # trials with their own inputs: each its own band and model
        band = np.stack([_quantiles_over_samples(pp[f"position_m{tag}"].isel({trial: r}),
                                                 [q, 1.0 - q], time_dim=time_)
                         for r in range(model.sizes[trial])], axis=1)
        median = np.stack([_quantiles_over_samples(model.isel({trial: r}), [0.5],
                                                   time_dim=time_)[0]
                           for r in range(model.sizes[trial])])
    else:
        band = _quantiles_over_samples(pp[f"position_m{tag}"], [q, 1.0 - q], time_dim=time_)
        median = _quantiles_over_samples(model, [0.5], time_dim=time_)[0]
    data = np.asarray(obs.values, dtype=float)
    return {
        "time": np.asarray(obs[time_].values, dtype=float),
        "trials": np.asarray(obs[trial].values),
        "data": data,
        "median": median,
        "low": band[0],
        "high": band[1],
        "coverage": share_inside(data, band[0], band[1]),
    }


def trial_mean_residual(pred: Mapping[str, np.ndarray]) -> tuple[np.ndarray, float]:
    """The trial mean minus the median model's and its RMS, over the samples observed.

    Parameters
    ----------
    pred : mapping
        :func:`predictive`'s ``data`` and ``median`` (one row per trial where the trials
        have their own inputs).

    Returns
    -------
    residual_m : numpy.ndarray
        ``(n_samples,)``, NaN where no trial is observed.
    rms_m : float
    """
    data, med = pred["data"], pred["median"]
    seen = np.isfinite(data)
    if seen.all():
        residual = data.mean(axis=0) - (med.mean(axis=0) if med.ndim == 2 else med)
        return residual, float(np.sqrt(np.mean(residual**2)))
    w = trial_weights(seen)
    model = med if med.ndim == 1 else med.mean(axis=0) if w is None else np.sum(med * w, axis=0)
    residual = mean_of_observed(data) - model
    observed = seen.any(axis=0)
    return residual, float(np.sqrt(np.mean(residual[observed] ** 2)))


def check_experiment_data(tree: xr.DataTree, datasets) -> list[Dataset]:
    """The experiments' data sets: those given (checked against the fit), or the fit's."""
    stored = experiment_datasets(tree)
    if datasets is None:
        return stored
    datasets = list(datasets)
    if len(datasets) != len(stored):
        raise ValueError(f"{len(datasets)} data sets given for a fit of {len(stored)} "
                         "experiments; give one per experiment, in the fit's order")
    for ds, ref in zip(datasets, stored, strict=True):
        if not isinstance(ds, Dataset):
            raise TypeError(f"datasets must be pmabayes.data.Dataset objects, got "
                            f"{type(ds).__name__}")
        where = (f"dataset {ds.source or '(no source)'} does not match the observed data of "
                 f"the fit's experiment from {ref.source}")
        fix = "give the fit's data files in its order"
        if ds.position_m.shape != ref.position_m.shape:
            raise DataError(f"{where}: shape {ds.position_m.shape} (trials, samples) against "
                            f"{ref.position_m.shape}; {fix}")
        # samples not observed (gaps in the clock) are NaN in both
        if not np.allclose(ds.position_m, ref.position_m, rtol=0, atol=1e-12, equal_nan=True):
            raise DataError(f"{where}: the positions or the samples observed differ (tolerance "
                            f"1e-12 m); {fix}")
    return datasets


def dataset_from_fit(tree: xr.DataTree, info: dict) -> Dataset:
    """The trials of a fit of one experiment as a Dataset, with its metadata (the input
    only where the fit stores it; :func:`~pmabayes.inference.fitfile.experiment_datasets`)."""
    return experiment_datasets(tree)[0]


def noise_floor(info: dict, dataset: Dataset | None) -> float | None:
    """The trial-mean noise floor: from the data when given, else from the fit."""
    own = dataset is not None and not bool(np.all(dataset.input == dataset.input[0]))
    if dataset is not None and dataset.n_trials > 1 and not own:
        return dataset.noise_floor_m  # trials with their own inputs: the fit's, referred
    floor = (info.get("data") or {}).get("noise_floor_m")
    return float(floor) if floor is not None else None
