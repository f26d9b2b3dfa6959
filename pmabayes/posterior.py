"""The posterior of a fit: an ArviZ 1.x DataTree and its NetCDF file.

Layout of a fit (what :func:`pmabayes.fit.fit` writes and the reports read):

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
import os
from pathlib import Path

import arviz as az
import numpy as np
import xarray as xr

from pmabayes.data import DataError, Dataset
from pmabayes.likelihood import NOISE_PARAMETERS
from pmabayes.model import Model, Rig

__all__ = ["NOISE_NAMES", "save_fit", "load_fit", "fit_info", "model_from_fit", "check_dataset",
           "FitFileError"]

#: Names of the noise parameters added to every fit.
NOISE_NAMES = tuple(p.name for p in NOISE_PARAMETERS)


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
        Priors are the effects' defaults; user effects must be registered first
        (``pmabayes --plugin FILE.py`` on the command line).
    """
    m = fit_info(tree).get("model") or {}
    rig = m.get("rig")
    return Model(list(m.get("effects") or []),
                 rig=Rig.from_dict(rig) if isinstance(rig, dict) else None,
                 fixed=m.get("fixed") or None)


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
