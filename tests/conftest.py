"""Shared test helpers: THE fake fit, and the ``slow`` marker's documentation.

``fake_fit`` builds a small fit with the layout of ``pmabayes fit`` (posterior,
sample_stats, observed and constant data, posterior predictive, log likelihood and
the ``pmabayes`` attributes) without sampling. Tests import it
(``from conftest import fake_fit``); ``tests/test_conftest.py`` checks it.

Tests marked ``@pytest.mark.slow`` take long; ``python -m pytest -q -m "not slow"``
leaves them out. Tests marked ``@pytest.mark.extended`` (and ``slow``) are the long
studies that would push CI past its 30 minutes: they are skipped, with the reason
shown, unless ``--extended`` is given (``python -m pytest -q -m extended
--extended`` runs just them). CI runs everything else.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import arviz as az
import numpy as np
import pytest
import xarray as xr

from pmabayes.inference.fitfile import save_fit
from pmabayes.inference.likelihood import NOISE_PARAMETERS
from pmabayes.model.model import PAPER_VALUES, Model


def pytest_addoption(parser: pytest.Parser) -> None:
    """``--extended``: also run the tests marked ``extended``."""
    parser.addoption("--extended", action="store_true", default=False,
                     help="also run the tests marked extended (long studies, skipped "
                     "by default to keep CI under 30 minutes)")


def pytest_collection_modifyitems(config: pytest.Config, items: list) -> None:
    """Skip the ``extended`` tests, saying how to run them, unless ``--extended``."""
    if config.getoption("--extended"):
        return
    skip = pytest.mark.skip(reason="extended tier: run with --extended")
    for item in items:
        if "extended" in item.keywords:
            item.add_marker(skip)


#: the disturbance of a fake fit whose posterior does not hold the noise
_SIGMA_M, _RHO = 5e-5, 0.9


@pytest.fixture(autouse=True)
def _in_own_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test runs in its own folder: what pmabayes writes by default into the
    working directory (a diagnosis' proposed plugin) stays out of the checkout."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture(autouse=True)
def _effect_registry_restored() -> object:
    """Effects a test registers are forgotten after it: the library's candidates (and
    so every ranking) do not depend on which tests ran before."""
    from pmabayes.model.effects import registry

    before = dict(registry._REGISTRY)
    yield
    registry._REGISTRY.clear()
    registry._REGISTRY.update(before)


def _chirp_pressure(t: np.ndarray) -> np.ndarray:
    """0.1 -> 3 Hz linear chirp around 0.2 MPa."""
    f0, f1, span = 0.1, 3.0, t[-1] - t[0]
    phase = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / span * t**2)
    return 0.2e6 + 0.15e6 * np.sin(phase)


def _response(p: np.ndarray, t: np.ndarray, gain: float, lag: float) -> np.ndarray:
    """A smooth stand-in for the model: delayed, scaled pressure (about 80 mm of motion)."""
    return gain * (np.interp(t - lag, t, p) - 0.05e6) / 0.3e6 * 0.08


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], sigma: float, rho: float):
    """Stationary AR(1) noise along the last axis."""
    w = rng.standard_normal(shape)
    e = np.empty(shape)
    e[..., 0] = sigma * w[..., 0]
    c = sigma * np.sqrt(1 - rho**2)
    for k in range(1, shape[-1]):
        e[..., k] = rho * e[..., k - 1] + c * w[..., k]
    return e


def _default_params(model: Model, values: Mapping[str, float] | None,
                    spread: float) -> dict[str, tuple[str, float, float]]:
    """The model's free parameters around its defaults (``values`` override them)."""
    centre = {**model.defaults, **(values or {})}
    out = {n: (model.parameter(n).unit, centre[n], spread * abs(centre[n]))
           for n in model.free_names}
    out["sigma_noise_m"] = ("m", _SIGMA_M, 0.0)
    return out


def _info(model: Model, names: list[str], params: Mapping, *, n_chain: int, n_trial: int,
          n_time: int, dt_s: float, noise_floor: float, converged: bool, synthetic: bool,
          seed: int) -> dict:
    """The ``pmabayes`` attributes, as ``fit.py`` writes them."""
    rows = model.describe()
    rows += [{"name": p.name, "unit": p.unit, "default": p.default, "prior": str(p.prior),
              "bounds": p.bounds, "fixed": False, "description": p.description,
              "source": "noise"} for p in NOISE_PARAMETERS]
    for row in rows:
        row["bounds"] = [float(b) for b in row["bounds"]]
    map_values = {n: params[n][1] + 0.1 * params[n][2] for n in names}
    messages = (["all checks passed"] if converged
                else ["R-hat over walkers 1.07 > 1.01 for alpha", "ESS 212 < 400 for beta"])
    return {
        "pmabayes_version": "0.1.0",
        "model": {"effects": list(model.effect_names), "rig": model.rig.to_dict(),
                  "free": list(model.free_names), "fixed": dict(model.fixed),
                  "parameters": rows},
        "noise": {"model": "AR(1) per trial",
                  "parameters": [p.name for p in NOISE_PARAMETERS]},
        "data": {"source": "data/pma_chirp_fake.csv", "n_trials": n_trial,
                 "n_samples": n_time, "dt_s": dt_s, "input_name": "pressure_pa",
                 "synthetic": synthetic, "noise_floor_m": noise_floor},
        "experiments": [{
            "name": "pma_chirp_fake", "source": "data/pma_chirp_fake.csv",
            "rig": model.rig.to_dict(), "n_trials": n_trial, "n_samples": n_time, "dt_s": dt_s,
            "input_name": "pressure_pa", "input_between_samples": "hold",
            "period_samples": None, "starts_in_steady_state": False, "noise": "own",
            "noise_source": "trials" if n_trial > 1 else "record",
            "noise_estimate": {"sigma_noise_m": None, "rho_noise": None,
                               "sigma_white_m": None},
            "noise_floor_m": noise_floor, "rms_cost_m": 3.1e-5, "synthetic": synthetic,
            "metadata": {"synthetic": synthetic}}],
        "paper_values": dict(PAPER_VALUES),
        "map": {"values": map_values, "log_posterior": 1234.5, "rms_cost_m": 3.1e-5,
                "global_search": {"values": {n: map_values[n] for n in names[:6]},
                                  "rms_cost_m": 2.9e-5}},
        "convergence": {
            "converged": converged, "messages": messages, "n_ensembles": 2,
            "n_walkers": n_chain // 2, "n_steps": 4000, "burn": 1000, "thin": 30,
            "tau": {n: 40.0 + j for j, n in enumerate(names)},
            "ess": {n: 900.0 + 10 * j for j, n in enumerate(names)},
            "rhat": {n: 1.001 for n in names},
            "rhat_ensembles": {n: 1.002 + 0.001 * j for j, n in enumerate(names)},
            "min_ess": 400.0, "tau_multiple": 50.0,
        },
        "seed": seed,
        "timings_s": {"map": 12.5, "sampling": 340.0, "total": 360.2},
    }


def fake_fit(
    path: str | Path | None = None,
    *,
    params: Mapping[str, tuple[str, float, float]] | None = None,
    effects: Sequence[str] = (),
    values: Mapping[str, float] | None = None,
    spread: float = 0.01,
    n_chain: int = 4,
    n_draw: int = 25,
    n_trial: int = 3,
    n_time: int = 500,
    n_pp: int = 12,
    dt_s: float = 0.02,
    converged: bool = True,
    synthetic: bool = True,
    seed: int = 0,
) -> xr.DataTree | Path:
    """A fake fit with the layout of ``pmabayes fit``, from draws around given values.

    Parameters
    ----------
    path : str or Path, optional
        Where to save it (``save_fit``); the tree is returned when not given.
    params : mapping, optional
        Posterior variables in order, ``name: (unit, mean, sd)``. By default the free
        parameters of ``Model(effects)`` at its defaults (overridden by ``values``),
        with sd ``spread * |value|``, and ``sigma_noise_m`` fixed at 50 um.
    effects : sequence of str
        The fit's effects (characterisation rig).
    values, spread
        Centre and relative spread of the default ``params``.
    n_chain, n_draw : int
        Posterior shape (``n_chain`` even: two ensembles).
    n_trial, n_time, n_pp : int
        Trials and samples of the observed data, predictive draws.
    dt_s : float
        Sample interval of the observed data.
    converged, synthetic : bool
        What the attributes say about the sampler and the data.
    seed : int
        Seed of every random draw.

    Returns
    -------
    xarray.DataTree or Path
        The fit, or the path it was saved to.
    """
    rng = np.random.default_rng(seed)
    model = Model(list(effects))
    params = dict(params) if params is not None else _default_params(model, values, spread)
    names = list(params)
    t = np.arange(n_time) * dt_s
    p = _chirp_pressure(t)
    z = rng.standard_normal((n_chain, n_draw, len(names)))
    if "d" in params and "K_e" in params:  # they trade off, as in real fits
        i, j = names.index("d"), names.index("K_e")
        z[..., j] = 0.8 * z[..., i] + 0.6 * z[..., j]
    posterior = {n: params[n][1] + params[n][2] * z[..., j] for j, n in enumerate(names)}
    sigma = params["sigma_noise_m"][1] if "sigma_noise_m" in params else _SIGMA_M
    rho = params["rho_noise"][1] if "rho_noise" in params else _RHO
    observed = _response(p, t, 1.0, 0.05) + _ar1(rng, (n_trial, n_time), sigma, rho)
    gains = 1.0 + 1e-4 * rng.standard_normal(n_pp)
    model_pp = np.stack([_response(p, t, g, 0.05) for g in gains])  # (n_pp, time)
    pred = model_pp[:, None, :] + _ar1(rng, (n_pp, n_trial, n_time), sigma, rho)
    trials = np.arange(1, n_trial + 1)
    tree = az.from_dict(
        {
            "posterior": posterior,
            "sample_stats": {"lp": -0.5 * (z**2).sum(axis=-1)},
            "observed_data": {"position_m": observed},
            "constant_data": {"pressure_pa": p},
            "posterior_predictive": {
                "position_m": pred[None].astype(np.float32),
                "model_position_m": model_pp[None].astype(np.float32),
            },
        },
        dims={"position_m": ["trial", "time"], "model_position_m": ["time"],
              "pressure_pa": ["time"]},
        coords={"trial": trials, "time": t},
    )
    ll = xr.Dataset(
        {"position_m": (("chain", "draw", "trial"),
                        rng.normal(-100, 1, (n_chain, n_draw, n_trial)))},
        coords={"chain": np.arange(n_chain), "draw": np.arange(n_draw), "trial": trials},
    )
    tree["log_likelihood"] = xr.DataTree(ll)
    ss = tree["sample_stats"].to_dataset()
    ss["ensemble"] = ("chain", np.repeat([0, 1], n_chain // 2))
    tree["sample_stats"] = xr.DataTree(ss)
    noise_floor = float(np.sqrt(observed.var(axis=0, ddof=1).mean() / n_trial))
    tree.attrs["pmabayes"] = json.dumps(_info(
        model, names, params, n_chain=n_chain, n_trial=n_trial, n_time=n_time, dt_s=dt_s,
        noise_floor=noise_floor, converged=converged, synthetic=synthetic, seed=seed))
    return tree if path is None else save_fit(tree, path)
