"""Validation on held-out experiments: the posterior's predictions against new data.

Stage 8 (diagnostics). :func:`validate` takes a fit and data sets the fit has not
seen (other inputs, other rigs) and, for each of them:

* simulates a seeded random subset of the posterior's draws on that data set's
  input, on **its own rig** (from its sidecar's ``rig``) with the fit's effects
  and fixed values, through :func:`pmabayes.model.simulator.simulate_dataset` (which
  applies the data set's input conventions), all draws in one batched call;
* adds the fit's noise to each simulated draw (AR(1) disturbance plus white sensor
  noise, drawn from the fit's noise posterior) to make the *predictive band*: the
  central ``ci_prob`` interval of what one measured trial should look like. The
  band is the model's prediction plus **the fit's noise**, not the held-out data's
  own noise: a held-out experiment noisier than the fitted ones falls outside it
  more often, and that is part of what validation checks;
* compares with the measurements (:class:`ExperimentValidation`).

Definitions (per held-out experiment, ``ybar`` its trial mean and ``xbar`` the
posterior-mean prediction, the mean over the simulated draws of the model's
noise-free position):

``rmse_m``
    ``sqrt(mean_k (ybar_k - xbar_k)^2)``: the RMS error of the trial mean.
``nrmse``
    ``rmse_m / sqrt(mean_k (ybar_k - mean(ybar))^2)``: the RMS error over the RMS of
    the measured trial mean's variation about its own mean (0 for a perfect
    prediction, about 1 for predicting nothing but the mean).
``noise_floor_m``
    The RMS error a perfect model would have against the trial mean, from the
    spread between repeated trials (:attr:`pmabayes.data.Dataset.noise_floor_m`);
    None with a single trial.
``band_coverage``
    The fraction of all measured samples (every trial) inside the predictive band.
    About ``ci_prob`` when the model and the fit's noise describe the data.
``band_errors``
    The error of the trial mean per frequency band, from
    :func:`pmabayes.criticism.bands.band_errors`.

Held-out data whose start is declared ``"estimate"`` (a record that starts mid-loop)
have it estimated from the record itself, as MATLAB's ``compare`` does with estimated
initial conditions: for each posterior draw, every state at the first sample
(:func:`pmabayes.simulate`'s ``initial_values``: the position, velocity and hysteretic
force, and each effect's state its effect gives a prior for, such as a degrading
law's dissipated energy) that fits the first ``start_fraction`` of the record (5% by
default; with effects' states, extended to its first reversal of motion and as many
samples after it) best in least squares, the velocity bounded by the largest speed
of those samples. A draw whose simulation from the start's prior means is not finite
keeps those means, and is counted and said. The numbers above are over the whole
record; ``start`` says how much of it the start used and why, and
``rmse_after_start_m`` is the error over the rest alone.

Fits of several experiments (one noise per fitted experiment, the noise variables
then having an ``experiment`` dimension): the noise of the fitted experiment whose
rig has the held-out data's rig name is used; when several match, their draws are
pooled; when none does, the draws are pooled over all fitted experiments.
``noise_from=NAME`` picks a fitted experiment by name instead. The disturbance's
lag-one correlation ``rho`` is per sample: for held-out data sampled at another
rate it is rescaled as a continuous-time exponential correlation,
``rho ** (dt_held_out / dt_fit)``.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import xarray as xr

from pmabayes.criticism.adequacy import Adequacy, check_adequacy
from pmabayes.criticism.bands import band_errors
from pmabayes.criticism.baselines import Baselines, fit_baselines, nrmse, yardstick_text
from pmabayes.criticism.inadequacy import Inadequacy, ResidualRecord, learn_inadequacy
from pmabayes.criticism.observed import observed_mean, share_inside, shared_input, trials_mean
from pmabayes.data import DataError, Dataset, DataWarning, load
from pmabayes.inference.fitfile import (
    check_dataset,
    experiment_datasets,
    experiment_models,
    fit_info,
    load_fit,
    model_from_fit,
    noise_models,
)
from pmabayes.inference.likelihood import (
    Likelihood,
    estimated_states,
    full_start,
    measurement_noise,
)
from pmabayes.inference.trials import keep_trials
from pmabayes.model.codegen import state_effects
from pmabayes.model.effects import EffectError
from pmabayes.model.model import RIG_PREFIX, Model, ModelError, Rig
from pmabayes.model.simulator import simulate, simulate_dataset

__all__ = ["DEFAULT_DRAWS", "START_FRACTION", "NOISE_NAMES", "ValidationError",
           "ExperimentValidation", "Validation", "validate"]

#: Posterior draws simulated per held-out experiment by default.
DEFAULT_DRAWS = 300
#: The fit's noise variables, in the order :func:`pmabayes.inference.likelihood.measurement_noise`
#: takes them.
NOISE_NAMES: tuple[str, str, str] = ("sigma_noise_m", "rho_noise", "sigma_white_m")
#: Predictive noise series per simulated draw: more series make the band's edges
#: steadier at no extra simulation.
_NOISE_PER_DRAW = 2


class ValidationError(DataError):
    """A held-out data set that a fit cannot validate (wrong input kind, a rig the
    fit's parameters do not cover, trials with different inputs, a fit without its
    noise). The message names the file and the fix."""


@dataclass(frozen=True, eq=False)
class ExperimentValidation:
    """The posterior's prediction of one held-out experiment, against its data.

    Parameters
    ----------
    name : str
        The experiment's name (the file's stem).
    source : str or None
        The file it was read from.
    synthetic : bool
        Whether its metadata says the data are synthetic.
    rig : dict
        The rig it was simulated on (:meth:`pmabayes.model.model.Rig.to_dict`).
    input_name : str
        ``"pressure_pa"`` or ``"force_n"``.
    time_s : numpy.ndarray
        Sample times, ``(n_samples,)``.
    input : numpy.ndarray
        The input shared by the trials, ``(n_samples,)`` (their mean where the trials
        have their own inputs).
    position_m : numpy.ndarray
        The measured trials, ``(n_trials, n_samples)``.
    prediction_m : numpy.ndarray
        The posterior-mean prediction (mean model position over the draws).
    model_low_m, model_high_m : numpy.ndarray
        Central ``ci_prob`` band of the noise-free model position over the draws
        (the parameters' uncertainty alone).
    low_m, high_m : numpy.ndarray
        Central ``ci_prob`` predictive band of one measured trial (parameters and
        the fit's noise); ``(n_trials, n_samples)``, each trial's own, where the trials
        have their own inputs.
    rmse_m : float
        RMS error of the trial mean against ``prediction_m``.
    nrmse : float
        ``rmse_m`` over the RMS of the trial mean's variation about its mean.
    max_error_m : float
        Largest absolute error of the trial mean.
    noise_floor_m : float or None
        The trial mean's noise floor; None with a single trial.
    band_coverage : float
        Fraction of measured samples inside ``[low_m, high_m]``.
    model_band_coverage : float
        Fraction of the trial mean's samples inside ``[model_low_m, model_high_m]``,
        the band of the parameters alone: the telling number for noiseless held-out
        data (a benchmark's test set), where the predictive band's noise makes
        ``band_coverage`` trivially high.
    band_errors : list of pmabayes.criticism.bands.BandErrors or None
        Error of the trial mean per frequency band and overall
        (:func:`pmabayes.criticism.bands.band_errors`), None when they cannot be computed
        (see ``notes``).
    noise : dict
        Where the predictive noise came from, and its median values.
    n_draws : int
        Posterior draws simulated.
    ci_prob : float
        Probability of the bands.
    notes : list of str
        What the numbers need said beside them (a rescaled noise correlation, band
        errors not available, the yardsticks beating the physics, ...).
    coverage : float or None
        Fraction of the measured samples inside the band with the model's learnt
        discrepancy (``low_with_discrepancy_m`` to ``high_with_discrepancy_m``); None
        when the discrepancy could not be learnt (see ``notes``).
    coverage_parameters_only : float or None
        Fraction of the measured samples inside ``[low_m, high_m]`` (the parameters
        and the fit's noise, no discrepancy), over the observed samples:
        ``band_coverage`` for a record without gaps.
    low_with_discrepancy_m, high_with_discrepancy_m : numpy.ndarray or None
        Central ``ci_prob`` band of one measured trial with draws of the discrepancy
        added (:mod:`~pmabayes.criticism.inadequacy`).
    baselines : dict
        The yardsticks on this experiment (:meth:`pmabayes.criticism.baselines.Baselines.scores`
        with their predictions): ``"linear"``, ``"play"`` and ``"narx"`` (those fitted);
        empty when they could not be fitted.
    start : dict
        The held-out record's start: ``initial_state``, and for ``"estimate"`` how it
        was estimated (``samples`` and ``seconds`` of the record used, ``fraction``,
        ``window``: why that many, ``rmse_after_start_m``: the error of the trial mean
        after them, the draws' median start, ``states_estimated``: the effects' states
        in it, ``states_at_rest``: those started at 0, ``v0_bound_m_s``: the bound of
        the start velocity, the largest speed of those samples, and ``v0_at_bound``
        the draws that reached it, and
        ``not_estimated``: the draws whose start could not be estimated, their
        simulation from the start's prior means not being finite, which start there).
    adequacy : Adequacy or None
        The adequacy verdict on these held-out data, by the one rule ``fit`` and
        ``diagnose`` use (:func:`pmabayes.criticism.adequacy.check_adequacy`): the
        prediction's residual whitened with the fit's noise (its draws' medians). None
        when it could not be judged (the reason in ``notes``).
    """

    name: str
    source: str | None
    synthetic: bool
    rig: dict
    input_name: str
    time_s: np.ndarray
    input: np.ndarray
    position_m: np.ndarray
    prediction_m: np.ndarray
    model_low_m: np.ndarray
    model_high_m: np.ndarray
    low_m: np.ndarray
    high_m: np.ndarray
    rmse_m: float
    nrmse: float
    max_error_m: float
    noise_floor_m: float | None
    band_coverage: float
    model_band_coverage: float
    band_errors: list | None
    noise: dict
    n_draws: int
    ci_prob: float
    notes: list = field(default_factory=list)
    start: dict = field(default_factory=dict)
    coverage: float | None = None
    coverage_parameters_only: float | None = None
    low_with_discrepancy_m: np.ndarray | None = None
    high_with_discrepancy_m: np.ndarray | None = None
    baselines: dict = field(default_factory=dict)
    adequacy: Adequacy | None = None

    @property
    def n_trials(self) -> int:
        """Number of measured trials."""
        return int(self.position_m.shape[0])

    @property
    def n_samples(self) -> int:
        """Samples per trial."""
        return int(self.time_s.size)

    @property
    def ratio_to_floor(self) -> float | None:
        """``rmse_m / noise_floor_m`` (about 1 for a model that describes the data);
        None without a floor."""
        if self.noise_floor_m is None or not self.noise_floor_m > 0:
            return None
        return self.rmse_m / self.noise_floor_m

    def summary(self) -> str:
        """One line for the command line: error, floor, NRMSE and coverage."""
        floor = ("(no noise floor: one trial)" if self.noise_floor_m is None
                 else f"= {self.ratio_to_floor:.3g}x the noise floor "
                      f"{self.noise_floor_m * 1e6:.3g} µm")
        synth = ", synthetic" if self.synthetic else ""
        with_d = ("" if self.coverage is None else
                  f" ({100 * self.coverage:.1f}% with the model's discrepancy)")
        yard = "".join(f"; {name} yardstick ({b.get('order_text', '')}) NRMSE {b['nrmse']:.3g}"
                       for name, b in self.baselines.items())
        return (f"{self.name}: {self.n_trials} trial(s) x {self.n_samples} samples"
                f"{synth}, rig {self.rig.get('name')}: RMSE {self.rmse_m * 1e6:.3g} µm "
                f"{floor}; NRMSE {self.nrmse:.3g}{yard}; {100 * self.band_coverage:.1f}% "
                f"of the samples inside the {100 * self.ci_prob:.4g}% predictive band"
                f"{with_d}, {100 * self.model_band_coverage:.1f}% of the trial mean inside "
                "the model-only band"
                + (f"; start estimated from the first {self.start['samples']} samples "
                   f"({100 * self.start['fraction']:.3g}% of the record, "
                   f"{self.start['seconds']:.3g} s"
                   + (f"; {self.start['window']}" if self.start.get("window", "").startswith(
                       "the first reversal") else "")
                   + ")"
                   + (", with " + ", ".join(self.start.get("states_estimated", ()))
                      if self.start.get("states_estimated") else "")
                   + ", RMSE after them "
                   f"{self.start['rmse_after_start_m'] * 1e6:.3g} µm"
                   + (f"; the start of {self.start['not_estimated']} draw(s) could not be "
                      "estimated (not finite): they start from its prior means"
                      if self.start.get("not_estimated") else "")
                   + (f"; the start velocity of {self.start['v0_at_bound']} draw(s) at its "
                      f"bound {self.start['v0_bound_m_s']:.3g} m/s (the largest speed of "
                      "those samples)" if self.start.get("v0_at_bound") else "")
                   if self.start.get("initial_state") == "estimate" else ""))

    def to_dict(self, *, arrays: bool = True) -> dict:
        """JSON-ready values (no NaN: a missing number is None).

        Parameters
        ----------
        arrays : bool
            Include the bands over time (``predictive_band``).

        Returns
        -------
        dict
            ``name``, ``source``, ``synthetic``, ``rig``, ``input_name``,
            ``n_trials``, ``n_samples``, ``dt_s``, ``rmse_m``, ``nrmse``,
            ``max_error_m``, ``noise_floor_m``, ``ratio_to_floor``,
            ``band_coverage``, ``coverage`` (with the discrepancy),
            ``coverage_parameters_only``, ``ci_prob``, ``n_draws``, ``band_errors``,
            ``noise``, ``notes``, ``baselines`` (``linear``, ``play`` and ``narx``
            where fitted, each with ``rmse_m``, ``nrmse``, ``order_text`` and its
            description; ``failed`` with the reason where its free run diverges, its
            errors then null),
            ``adequacy`` (:meth:`pmabayes.criticism.adequacy.Adequacy.to_dict` with
            ``verdict``, its words; None when it could not be judged) and, with
            ``arrays``,
            ``predictive_band`` (``time_s``, ``prediction_m``, ``low_m``, ``high_m``,
            ``model_low_m``, ``model_high_m``, ``low_with_discrepancy_m``,
            ``high_with_discrepancy_m`` and each yardstick's prediction,
            ``linear_m``, ``play_m``, ``narx_m``).
        """
        out = {
            "name": self.name, "source": self.source, "synthetic": self.synthetic,
            "rig": dict(self.rig), "input_name": self.input_name,
            "n_trials": self.n_trials, "n_samples": self.n_samples,
            "dt_s": float(self.time_s[-1] - self.time_s[0]) / (self.n_samples - 1),
            "rmse_m": _json_float(self.rmse_m), "nrmse": _json_float(self.nrmse),
            "max_error_m": _json_float(self.max_error_m),
            "noise_floor_m": _json_float(self.noise_floor_m),
            "ratio_to_floor": _json_float(self.ratio_to_floor),
            "band_coverage": _json_float(self.band_coverage),
            "model_band_coverage": _json_float(self.model_band_coverage),
            "ci_prob": self.ci_prob, "n_draws": self.n_draws,
            "band_errors": None if self.band_errors is None else [
                # JSON has no NaN: a number that cannot be had (a floor without repeats)
                {k: _json_float(v) if isinstance(v, float) else v for k, v in b.to_dict().items()}
                for b in self.band_errors],
            "noise": dict(self.noise),
            "notes": list(self.notes),
            "start": {k: _json_float(v) if isinstance(v, float) else v
                      for k, v in self.start.items()},
            "coverage": _json_float(self.coverage),
            "coverage_parameters_only": _json_float(self.coverage_parameters_only),
            "baselines": {n: {k: _json_float(v) if isinstance(v, float) else v
                              for k, v in b.items() if k != "prediction_m"}
                          for n, b in self.baselines.items()},
            "adequacy": None if self.adequacy is None else {
                **self.adequacy.to_dict(), "verdict": " ".join(self.adequacy.lines())},
        }
        if arrays:
            out["predictive_band"] = {
                k: np.asarray(getattr(self, a), dtype=float).tolist()
                for k, a in (("time_s", "time_s"), ("prediction_m", "prediction_m"),
                             ("low_m", "low_m"), ("high_m", "high_m"),
                             ("model_low_m", "model_low_m"), ("model_high_m", "model_high_m"),
                             ("low_with_discrepancy_m", "low_with_discrepancy_m"),
                             ("high_with_discrepancy_m", "high_with_discrepancy_m"))
                if getattr(self, a) is not None
            }
            out["predictive_band"].update({f"{n}_m": [float(v) for v in b["prediction_m"]]
                                           for n, b in self.baselines.items()})
        return out


@dataclass(frozen=True, eq=False)
class Validation:
    """The validation of one fit on held-out experiments.

    Parameters
    ----------
    experiments : list of ExperimentValidation
        One per held-out data set, in the order given.
    fit_source : str or None
        The fit file, or the data the fit was made from.
    effects : tuple of str
        The fit's effects.
    settings : dict
        ``n_draws``, ``ci_prob``, ``seed`` and ``noise_from``.
    discrepancy : Inadequacy or None
        The model's discrepancy learnt from the fit's training residual
        (:func:`pmabayes.criticism.inadequacy.learn_inadequacy`), which widens the bands
        of ``coverage``; None when it could not be learnt.
    baselines : Baselines or None
        The yardsticks fitted to the fit's training data
        (:func:`pmabayes.criticism.baselines.fit_baselines`); None when they could not
        be fitted.
    """

    experiments: list
    fit_source: str | None
    effects: tuple
    settings: dict
    discrepancy: Inadequacy | None = None
    baselines: Baselines | None = None

    def to_dict(self, *, arrays: bool = True) -> dict:
        """JSON-ready values.

        Parameters
        ----------
        arrays : bool
            Include each experiment's bands over time.

        Returns
        -------
        dict
            ``fit``, ``effects``, ``settings``, ``definitions``, ``discrepancy``
            (:meth:`~pmabayes.criticism.inadequacy.Inadequacy.to_dict`, or None),
            ``baselines`` (``trained_on``, ``seconds``, ``fitted``: each yardstick's
            orders, ``left_out``: each one not fitted, with the reason; or None) and
            ``experiments``
            (:meth:`ExperimentValidation.to_dict` of each).
        """
        return {
            "fit": self.fit_source, "effects": list(self.effects),
            "settings": dict(self.settings), "definitions": dict(DEFINITIONS),
            "discrepancy": None if self.discrepancy is None else self.discrepancy.to_dict(),
            "baselines": None if self.baselines is None else self.baselines.to_dict(),
            "experiments": [e.to_dict(arrays=arrays) for e in self.experiments],
        }

    def lines(self) -> list[str]:
        """The command line's short per-experiment summary.

        Returns
        -------
        list of str
            One per experiment, then one per yardstick left out (why, and the fix).
        """
        return ([e.summary() for e in self.experiments]
                + ([] if self.baselines is None else self.baselines.lines()))


#: The numbers' definitions, as the JSON states them.
#:
#: :meta hide-value:
DEFINITIONS = {
    "rmse_m": "RMS over samples of (trial mean - posterior-mean prediction), in m",
    "nrmse": "rmse_m / RMS of (trial mean - its time average): 0 is perfect, 1 predicts "
             "only the mean",
    "noise_floor_m": "RMS error a perfect model would have against the trial mean, from "
                     "the spread between repeated trials; null with one trial",
    "band_coverage": "fraction of all measured samples inside the central ci_prob "
                     "predictive band (model draws plus the fit's noise, not the held-out "
                     "data's own noise)",
    "model_band_coverage": "fraction of the trial mean's samples inside the central "
                           "ci_prob band of the noise-free model draws (parameters alone)",
    "prediction": "mean over the simulated posterior draws of the noise-free model position",
    "coverage": "fraction of the measured samples inside the central ci_prob band of the "
                "model draws plus the fit's noise plus draws of the model's discrepancy "
                "learnt from the training residual (see discrepancy)",
    "coverage_parameters_only": "fraction of the measured samples inside the predictive "
                                "band without the discrepancy (band_coverage over the "
                                "observed samples)",
    "baselines": "yardsticks fitted to the fit's training data in seconds, predicting the "
                 "same held-out input by free-run simulation: a linear output-error model, "
                 "a Prandtl-Ishlinskii model of play operators and a polynomial NARX model "
                 "(terms chosen by forward regression with orthogonal least squares), each "
                 "of an order chosen on the training data; their rmse_m and nrmse as the "
                 "physics' (see pmabayes.criticism.baselines)",
}


def _json_float(value) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


# ----------------------------------------------------------------------------- the fit


@dataclass(frozen=True)
class _FitDraws:
    """What validation reads from a fit: the model's recipe and flattened draws."""

    effects: tuple       # Effect classes
    fixed: dict
    input_kind: str | None
    draws: dict          # posterior variable -> DataArray (chain, draw[, experiment])
    noise: dict          # noise name -> (n_total,) or (n_total, n_experiment)
    experiments: list    # [{"name", "rig_name", "dt_s"}], one per noise column
    dt_s: float | None   # the fit's sample interval (single-experiment fits)
    source: str | None
    n_total: int
    # the noise model of each fitted experiment: the repeats' AR(p), or None (AR(1) + white)
    noise_models: list = field(default_factory=list)
    # (rig key, prior text) -> the posterior variable of that rig value, for every rig
    # value a fitted experiment gave as a prior
    rig_priors: dict = field(default_factory=dict)


def _flat(da: xr.DataArray, name: str, where: str) -> np.ndarray:
    dims = [d for d in da.dims if d not in ("chain", "draw")]
    if "chain" not in da.dims or "draw" not in da.dims or len(dims) > 1:
        raise ValidationError(
            f"{where}: posterior variable {name!r} has dims {da.dims}; expected (chain, draw) "
            "or (chain, draw, experiment); write the fit with `pmabayes fit`")
    arr = np.asarray(da.transpose("chain", "draw", *dims).values, dtype=float)
    return arr.reshape(arr.shape[0] * arr.shape[1], *arr.shape[2:])


def _experiments(info: dict, names: Sequence[str]) -> list[dict]:
    """Name, rig name and sample interval of each fitted experiment (noise column)."""
    raw = info.get("experiments") or []
    if isinstance(raw, Mapping):
        raw = [{"name": k, **(v if isinstance(v, Mapping) else {})} for k, v in raw.items()]
    by_name = {}
    for i, e in enumerate(raw):
        if isinstance(e, Mapping):
            by_name[str(e.get("name", i))] = e
    out = []
    for i, n in enumerate(names):
        e = by_name.get(str(n)) or (raw[i] if i < len(raw) and isinstance(raw[i], Mapping)
                                    else {})
        rig = e.get("rig")
        rig_name = rig.get("name") if isinstance(rig, Mapping) else rig
        out.append({"name": str(n), "rig_name": None if rig_name is None else str(rig_name),
                    "dt_s": e.get("dt_s"), "source": e.get("source")})
    return out


def _read_fit(tree: xr.DataTree, where: str) -> _FitDraws:
    info = fit_info(tree)
    if "posterior" not in tree.children:
        raise ValidationError(f"{where}: the fit has no posterior group; write it with "
                              "`pmabayes fit`")
    post = tree["posterior"].to_dataset()
    try:  # the fit's effects and fixed values, read where every command reads them
        fitted = model_from_fit(tree)
    except EffectError as err:
        raise ValidationError(f"{where}: the fit's effects cannot be built: {err}; register "
                              "a user effect first (pmabayes --plugin FILE.py)") from None
    except ModelError as err:
        raise ValidationError(f"{where}: the fit's model cannot be rebuilt: {err}") from None
    rig = (info.get("model") or {}).get("rig")
    input_kind = fitted.rig.input_kind if isinstance(rig, Mapping) else None
    exp_names: list = []
    missing = [n for n in NOISE_NAMES if n not in post.data_vars]
    if missing:
        raise ValidationError(
            f"{where}: the fit's posterior has no {', '.join(missing)}, so it holds no noise "
            "to make a predictive band from; validate a fit written by `pmabayes fit`")
    noise = {n: _flat(post[n], n, where) for n in NOISE_NAMES}
    shapes = {v.shape for v in noise.values()}
    if len(shapes) != 1:
        raise ValidationError(f"{where}: the noise variables have different shapes "
                              f"{sorted(shapes)}; the fit file is inconsistent")
    for n in NOISE_NAMES:
        if "experiment" in post[n].dims:
            coord = post[n]["experiment"].values if "experiment" in post[n].coords else \
                np.arange(post[n].sizes["experiment"])
            exp_names = [str(c) for c in coord]
            break
    experiments = _experiments(info, exp_names) if exp_names else []
    kinds = set()
    for e in info.get("experiments") or []:
        if isinstance(e, Mapping) and isinstance(e.get("rig"), Mapping):
            kinds.add(e["rig"].get("input_kind"))
    if input_kind is None and len(kinds) == 1:
        input_kind = kinds.pop()
    # the model's parameters are flattened when a held-out data set asks for them: other
    # variables a fit may hold are not this module's business
    draws = {n: v for n, v in post.data_vars.items() if n not in NOISE_NAMES}
    data = info.get("data") or {}
    dt_s = data.get("dt_s")
    recorded = [e for e in info.get("experiments") or [] if isinstance(e, Mapping)]
    if dt_s is None and len(recorded) == 1:
        dt_s = recorded[0].get("dt_s")
    n_total = next(iter(noise.values())).shape[0]
    rig_priors = {}
    for e in recorded:
        rig, names = e.get("rig"), e.get("parameters") or {}
        for key, value in (rig.items() if isinstance(rig, Mapping) else ()):
            if isinstance(value, str) and f"{RIG_PREFIX}{key}" in names:
                rig_priors.setdefault((key, value), names[f"{RIG_PREFIX}{key}"])
    return _FitDraws(
        effects=fitted.effects, fixed=dict(fitted.fixed),
        input_kind=input_kind, draws=draws, noise=noise, experiments=experiments,
        dt_s=dt_s, source=data.get("source"), n_total=n_total, noise_models=noise_models(tree),
        rig_priors=rig_priors)


def _draw_names(fit: _FitDraws, model: Model, where: str) -> dict[str, str]:
    """The posterior variable of each free parameter of a held-out data set's model: its
    own name, or for a rig value its sidecar gives as a prior, the fit's variable of a
    fitted experiment that gave the same value the same prior."""
    out = {}
    for n in model.free_names:
        if not model.is_rig_parameter(n):
            out[n] = n
            continue
        key = n[len(RIG_PREFIX):]
        text = model.rig.to_dict()[key]
        if (key, text) not in fit.rig_priors:
            raise ValidationError(
                f"{where}: its sidecar gives the rig's {key} as the prior {text}, but no "
                "fitted experiment gave that prior, so the fit has no posterior for it: give "
                f"the same prior as a fitted experiment of the same rig, or {key} as a number")
        out[n] = fit.rig_priors[(key, text)]
    return out


# ----------------------------------------------------------------------------- checks


def _check_dataset(fit: _FitDraws, ds: Dataset, where: str) -> Model:
    """The model for a held-out data set, or a clear refusal."""
    kind = "pressure" if ds.input_name == "pressure_pa" else "force"
    if fit.input_kind is not None and kind != fit.input_kind:
        raise ValidationError(
            f"{where}: its input is {ds.input_name!r} ({kind}), but the fit was made on a "
            f"{fit.input_kind}-driven rig; a fit can only predict data of its own input kind: "
            "validate it on data with the same input column")
    try:
        model = Model.for_dataset(ds, fit.effects, fixed=fit.fixed)
    except ModelError as err:
        raise ValidationError(f"{where}: the fit's model cannot be built on this data set's "
                              f"rig: {err}") from None
    if model.rig.input_name != ds.input_name:
        raise ValidationError(
            f"{where}: the sidecar's rig ({model.rig.name}) is {model.rig.input_kind}-driven "
            f"but the input column is {ds.input_name!r}; correct the sidecar's 'rig' or the "
            "input column")
    names = _draw_names(fit, model, where)
    per_experiment = [n for n in model.free_names
                      if (names[n] in fit.draws
                          and set(fit.draws[names[n]].dims) - {"chain", "draw"})
                      or (names[n] not in fit.draws
                          and any(v.startswith(f"{n}__") for v in fit.draws))]
    if per_experiment:
        raise ValidationError(
            f"{where}: the fit's {', '.join(per_experiment)} differ between its experiments, "
            "so there is no one value to predict a new experiment with; validation needs "
            "physical parameters shared by the fitted experiments (a sensor zeroed at the "
            "record's start: declare \"position_reference\": \"start\" instead of an offset)")
    lacking = [n for n in model.free_names if names[n] not in fit.draws]
    if lacking:
        raise ValidationError(
            f"{where}: the fit has no posterior for {', '.join(lacking)}, which the model "
            f"needs on this data set's rig ({model.rig.name}); the fit's effects cannot "
            "simulate it: validate data from a rig of the fit's kind, or refit with them")
    return model


def _noise_columns(fit: _FitDraws, rig: Rig, noise_from: str | None
                   ) -> tuple[list[int] | None, str]:
    """Which fitted experiments' noise a held-out data set takes, and why."""
    if not fit.experiments:
        if noise_from is not None:
            raise ValidationError(
                f"noise_from={noise_from!r}: this fit has one noise for all its data (one "
                "experiment, or a noise tied across experiments), so there is nothing to "
                "choose; leave --noise-from out")
        return None, "the fit's noise"
    names = [e["name"] for e in fit.experiments]
    if noise_from is not None:
        hits = [i for i, e in enumerate(fit.experiments)
                if noise_from in (e["name"], e.get("source"),
                                  Path(str(e.get("source") or "")).stem)]
        if not hits:
            raise ValidationError(
                f"noise_from={noise_from!r} names no fitted experiment; the fit's experiments "
                f"are {', '.join(names)}")
        return hits[:1], f"fitted experiment {names[hits[0]]!r} (chosen)"
    hits = [i for i, e in enumerate(fit.experiments) if e["rig_name"] == rig.name]
    if len(hits) == 1:
        return hits, f"fitted experiment {names[hits[0]]!r} (same rig, {rig.name!r})"
    if hits:
        return hits, (f"pooled over the fitted experiments on rig {rig.name!r}: "
                      + ", ".join(names[i] for i in hits))
    return list(range(len(names))), (f"pooled over all fitted experiments ({', '.join(names)}):"
                                     f" none was on rig {rig.name!r}")


def _noise_draws(fit: _FitDraws, pick: np.ndarray, columns: list[int] | None,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                    float | None]:
    """The noise parameters paired with the chosen draws, their sample interval, and the
    fitted experiment each draw's noise comes from."""
    if columns is None:
        return (*(fit.noise[n][pick] for n in NOISE_NAMES), fit.dt_s,
                np.zeros(pick.size, dtype=int))
    col = np.asarray(columns)[rng.integers(len(columns), size=pick.size)]
    dts = {fit.experiments[c]["dt_s"] for c in columns}
    dt = dts.pop() if len(dts) == 1 else None
    return (*(fit.noise[n][pick, col] for n in NOISE_NAMES), dt, col)


def _ar_noise(y: np.ndarray, col: np.ndarray, k: int, fit: _FitDraws, same_rate: bool,
              rng: np.random.Generator, notes: list) -> None:
    """Redraw, in place, the noise of the draws whose fitted experiment used the
    repeats' AR(p) noise model (``y``: ``(draws * k, n)``), as its likelihood did."""
    used = sorted({int(c) for c in col if c < len(fit.noise_models)
                   and fit.noise_models[int(c)] is not None})
    if not used:
        return
    if not same_rate:  # an AR(p) per sample does not rescale to another rate
        notes.append("the fit's AR(p) noise model (from the repeats) is per sample at the "
                     "fit's rate; at this data set's rate the band uses its AR(1) + white "
                     "estimate instead")
        return
    for c in used:
        ar = fit.noise_models[c]
        rows = np.flatnonzero(np.repeat(col == c, k))
        y[rows] = ar.draw(rows.size, y.shape[1], rng)
    notes.append("the predictive noise is the fit's " + ", ".join(
        sorted({fit.noise_models[c].name for c in used})) + ", as its likelihood used")


# ----------------------------------------------------------------------------- validate


def _band_errors(ds: Dataset, prediction: np.ndarray, notes: list,
                 trials: np.ndarray | None = None) -> list | None:
    try:
        return band_errors(ds, prediction, model_trials_m=trials)
    except ValueError as err:
        notes.append(f"error per frequency band not available: {err}")
        return None


#: The first part of a held-out record whose start is estimated (a fraction of it), by
#: default.
START_FRACTION = 0.05


@dataclass(frozen=True)
class _Starts:
    """Each draw's estimated start and what the estimate could not do."""

    values: np.ndarray  # (draws, 3 + k): x0_m, v0_m_s, z0_offset_n, the effects' states
    names: tuple  # the columns' names (the start's parameters)
    samples: int  # the first samples of the record the start was fitted to
    window: str  # why that many (_start_samples)
    speed_bound_m_s: float  # |v0| is kept below it
    at_bound: int  # draws whose v0 ended within 1% of that bound
    not_estimated: int  # draws simulated non-finite from the prior means: kept there


#: The start velocity's bound over the largest speed of the samples the start is fitted
#: to (:func:`_speed_bound`): a speed between two samples is an average, and the
#: velocity at a sample of a record that starts at its fastest exceeds it.
SPEED_MARGIN = 1.25


def _speed_bound(ds: Dataset, n: int, v_prior: float) -> float:
    """The largest start velocity the record allows: :data:`SPEED_MARGIN` times the
    largest speed of its first ``n`` samples, where the start is fitted (the trial
    mean's differences), or the start's prior mean if larger. (The record's largest
    speed anywhere let a misfit of the first samples ask for a start 8 times faster
    than they ever move.)"""
    y, t = ds.mean_position_m[:n], ds.time_s[:n]
    with np.errstate(invalid="ignore"):
        speed = np.abs(np.diff(y)) / np.diff(t)
    seen = speed[np.isfinite(speed)]
    return max(SPEED_MARGIN * float(seen.max()) if seen.size else 0.0, 1.01 * abs(v_prior),
               1e-12)


#: The turn of motion that counts as a reversal where a start's window is extended to
#: one (:func:`_start_samples`), as a fraction of the record's range.
REVERSAL_FRACTION = 0.1


def _first_reversal(y: np.ndarray, turn: float) -> tuple[int, int] | None:
    """The first reversal of the motion ``y`` (NaN: not observed) by at least ``turn``:
    the index of its extreme and the index where the motion had turned back by
    ``turn``; None if the motion never turns so."""
    hi = lo = None
    i_hi = i_lo = 0
    for i, v in enumerate(y):
        if not np.isfinite(v):
            continue
        if hi is None:
            hi = lo = v
            i_hi = i_lo = i
            continue
        if v > hi:
            hi, i_hi = v, i
        if v < lo:
            lo, i_lo = v, i
        # an extreme at the first observed sample is where the record starts, not a turn
        if v <= hi - turn and i_hi > i_lo:
            return i_hi, i
        if v >= lo + turn and i_lo > i_hi:
            return i_lo, i
    return None


def _start_samples(ds: Dataset, fraction: float, states: bool) -> tuple[int, str]:
    """The first samples of a record its start is fitted to, and why that many: the
    first ``fraction`` of it (at least 10 samples), and with effects' states to
    estimate at least its first reversal of motion (by :data:`REVERSAL_FRACTION` of
    its range) and as many samples again after it: a degradation's state shows in the
    stiffness just after a reversal, which a window in one direction of motion cannot
    tell from the hysteretic force's (on the RC columns' last 30% a 5% window put
    the dissipated energy at an eighth of what the first 70% had left)."""
    n = min(ds.n_samples, max(int(round(fraction * ds.n_samples)), 10))
    if not states:
        return n, "start_fraction"
    y = ds.mean_position_m
    seen = y[np.isfinite(y)]
    turn = REVERSAL_FRACTION * (float(np.ptp(seen)) if seen.size else 0.0)
    found = _first_reversal(y, turn) if turn > 0 else None
    if found is None:
        return n, "start_fraction (the record does not reverse)"
    extreme, back = found
    m = min(ds.n_samples, max(n, back + 1, extreme + n))
    return m, ("start_fraction" if m == n else
               f"the first reversal of motion (sample {extreme}) and {m - extreme} after it")


#: The effects' states' trial values at an estimated start, in their priors' spreads
#: (a state bounded below: above its bound), from which the least squares starts too:
#: a degradation's energy moves the fit of the first samples little near its prior
#: mean, and one start from there alone stays in whatever basin it is in.
STATE_TRIALS = (0.01, 0.1, 0.3, 1.0, 3.0)


def _softplus(q: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, q)


def _estimated_starts(model: Model, theta: np.ndarray, ds: Dataset, fraction: float,
                      substeps: int) -> _Starts:
    """Each draw's start ``(draws, 3 + k)`` fitted to the first samples of the record
    (:func:`_start_samples`: the first ``fraction``, with effects' states extended to
    its first reversal of motion).

    The start is every state of the model
    (:meth:`pmabayes.inference.likelihood.Likelihood.start_parameters`): the position,
    the velocity, the hysteretic force's offset from the balance, and each effect's
    state that its effect gives a prior for (the dissipated energy of a degrading
    law: restarted at 0, a column cut from a long test would be predicted as it was
    before any damage). Levenberg-Marquardt on all draws at once, in coordinates
    scaled by the start's prior spreads, from its prior means and, with effects'
    states, from each of :data:`STATE_TRIALS` of them (the best kept per draw), with
    forward-difference Jacobians; it stops when no draw's step moves by more than
    1e-6 of a spread, after at most 50 steps. The velocity is bounded by the largest
    speed of those samples (:func:`_speed_bound`; as ``V tanh(w)``), so that a misfit
    cannot ask for a start faster than the record moves there; a state
    bounded below stays above its bound (as ``lo + s softplus(w)``). A draw whose
    simulation from the prior means is not finite cannot be estimated: it keeps the
    prior means, and is counted (its bands then drop it if it fails on the record too).
    A step that is not finite is not taken.
    """
    prior = Likelihood(model, ds).start_parameters()
    k = len(prior)
    n, why = _start_samples(ds, fraction, k > 3)
    s0 = np.array([p.default for p in prior])
    scale = np.array([p.prior.sigma for p in prior])
    bound = _speed_bound(ds, n, s0[1])
    # a state bounded below (an energy): lo + scale softplus(w); the others linear
    lower = np.array([j >= 3 and np.isfinite(p.bounds[0]) and not np.isfinite(p.bounds[1])
                      for j, p in enumerate(prior)])
    lo = np.array([p.bounds[0] if lower[j] else 0.0 for j, p in enumerate(prior)])
    y = ds.mean_position_m[:n]
    seen = np.isfinite(y)
    batch = theta.shape[0]
    run = dict(time_s=ds.time_s[:n], substeps=substeps, initial_state="estimate",
               between_samples=ds.input_between_samples)

    def start_of(q: np.ndarray) -> np.ndarray:
        s = s0 + q * scale
        s[:, 1] = bound * np.tanh(q[:, 1])  # q[:, 1] is w, the bounded velocity's
        s[:, lower] = lo[lower] + scale[lower] * _softplus(q[:, lower])
        return s

    def coordinates(s: np.ndarray) -> np.ndarray:
        q = (s - s0) / scale
        q[:, 1] = np.arctanh(s[:, 1] / bound)
        with np.errstate(divide="ignore"):  # softplus's inverse, exact far from 0
            u = np.maximum((s[:, lower] - lo[lower]) / scale[lower], 1e-300)
            q[:, lower] = u + np.log(-np.expm1(-u))
        return q

    def residual(q: np.ndarray, th: np.ndarray) -> np.ndarray:
        x = simulate(model, th, ds.input[0, :n], initial_values=full_start(model, start_of(q)),
                     **run)
        return (y - x)[:, seen]

    def least_squares(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = q.copy()
        r = residual(q, theta)
        cost = np.sum(r * r, axis=1)
        lam = np.full(batch, 1e-3)
        h = 1e-4
        eye = np.eye(k)
        tiled = np.tile(theta, (k + 1, 1))
        for _ in range(50):
            qs = np.concatenate([q] + [q + h * eye[j] for j in range(k)])
            rs = residual(qs, tiled).reshape(k + 1, batch, -1)
            jac = (rs[0][:, :, None] - np.stack(rs[1:], axis=2)) / h  # d(model)/dq
            a = np.einsum("bkj,bkl->bjl", jac, jac)
            g = np.einsum("bkj,bk->bj", jac, rs[0])
            damped = a + lam[:, None, None] * (eye * np.diagonal(a, axis1=1, axis2=2)[:, None]
                                                + 1e-12 * eye)
            bad = ~(np.isfinite(damped).all(axis=(1, 2)) & np.isfinite(g).all(axis=1))
            damped[bad], g[bad] = eye, 0.0  # a Jacobian that is not finite: no step
            step = np.linalg.solve(damped, g[:, :, None])[:, :, 0]
            step[~np.isfinite(step).all(axis=1)] = 0.0
            r_new = residual(q + step, theta)
            new = np.sum(r_new * r_new, axis=1)
            better = np.isfinite(new) & (new < cost) & ~bad
            q[better] += step[better]
            cost[better] = new[better]
            lam = np.where(better, lam / 3.0, lam * 4.0)
            done = np.where(better, np.max(np.abs(step), axis=1) < 1e-6, lam > 1e8)
            if done.all():
                break
        return q, cost

    means = np.broadcast_to(s0, (batch, k)).copy()
    means[:, 1] = np.clip(means[:, 1], -0.999 * bound, 0.999 * bound)
    q, cost = least_squares(coordinates(means))
    lost = ~np.isfinite(cost)  # never better: these keep the prior means
    for trial in STATE_TRIALS if k > 3 else ():
        other = means.copy()
        other[:, 3:] = np.where(lower[3:], lo[3:] + trial * scale[3:],
                                s0[3:] + (trial - 1.0) * scale[3:])
        q_other, c_other = least_squares(coordinates(other))
        better = np.isfinite(c_other) & ~(c_other >= cost)  # a lost draw found too
        q[better], cost[better] = q_other[better], c_other[better]
        lost &= ~better
    q[lost] = coordinates(means)[lost]
    at_bound = int(np.count_nonzero(~lost & (np.abs(np.tanh(q[:, 1])) > 0.99)))
    return _Starts(start_of(q), tuple(p.name for p in prior), n, why, bound, at_bound,
                   int(np.count_nonzero(lost)))


#: Posterior draws simulated on the training data for its residual (evenly spaced over
#: the fit's draws, so that no random draw is taken).
_TRAINING_DRAWS = 100


@dataclass(frozen=True, eq=False)
class _Training:
    """What validation learns from the fit's own training data: the yardsticks, the
    model's discrepancy, what could not be had, and the discrepancy's generator."""

    baselines: Baselines | None
    inadequacy: Inadequacy | None
    notes: list
    rng: np.random.Generator | None


def _column(values: np.ndarray, e: int) -> np.ndarray:
    """An experiment's column of a per-experiment variable; a shared one as it is."""
    return values if values.ndim == 1 else values[:, min(e, values.shape[1] - 1)]


def _draw_positions(model: Model, theta: np.ndarray, ds: Dataset, substeps: int,
                    starts: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """The draws' positions on a data set from their starts (None: its declared one),
    and whether its trials have their own inputs: then each draw on each trial's input,
    ``(draws, trials, n)``."""
    own = not bool(np.all(ds.input == ds.input[0]))
    x = simulate_dataset(model, theta, ds, substeps=substeps,
                         initial_values=None if starts is None else full_start(model, starts),
                         per_trial=own)
    return x, own


def _residual_records(fit: _FitDraws, training: list, models: list, substeps: int,
                      where: str, identified: list, starts_named: list
                      ) -> list[ResidualRecord]:
    """Each training experiment's trial mean minus the posterior-mean prediction (NaN
    where no trial is counted), with the fit's noise (posterior medians) of that
    experiment; ``identified`` maps each experiment's parameters to the fit's variables
    (its own offset, a rig prior's), ``starts_named`` names each one's estimated start's
    variables (none where its start is declared)."""
    idx = np.unique(np.linspace(0, fit.n_total - 1, min(_TRAINING_DRAWS, fit.n_total))
                    .astype(int))
    out = []
    for e, (ds, model) in enumerate(zip(training, models, strict=True)):
        names = {n: identified[e].get(n, n) for n in model.free_names}
        theta = model.theta({n: _column(_flat(fit.draws[v], v, where)[idx], e)
                             for n, v in names.items()})
        starts = None
        if starts_named[e]:  # the draws' own estimated starts
            starts = np.stack([_flat(fit.draws[v], v, where)[idx] for v in starts_named[e]],
                              axis=1)
        x, own = _draw_positions(model, theta, ds, substeps, starts)
        if own:  # each draw's trial mean, averaged as the trials are
            x = trials_mean(ds, x)
        ok = np.all(np.isfinite(x), axis=1)
        if not ok.any():
            raise ValueError(f"no posterior draw simulates training experiment {e + 1}")
        noise = (float(np.median(_column(fit.noise[n], e))) for n in NOISE_NAMES)
        out.append(ResidualRecord(observed_mean(ds) - x[ok].mean(axis=0), ds.dt_s, *noise,
                                  ds.n_trials))
    return out


def _learn_from_training(fit: _FitDraws, tree: xr.DataTree, substeps: int, where: str,
                         rng: np.random.Generator) -> _Training:
    """The yardsticks and the model's discrepancy, both from the fit's training data."""
    notes: list[str] = []
    try:
        training, models = experiment_datasets(tree), experiment_models(tree)
    except (DataError, ModelError, EffectError, KeyError, ValueError) as err:
        notes.append(f"the fit's training data could not be rebuilt ({err}): no yardsticks "
                     "and no discrepancy band")
        return _Training(None, None, notes, None)
    baselines = inadequacy = None
    try:
        baselines = fit_baselines(training)
    except ValueError as err:
        notes.append(f"the yardsticks could not be fitted to the training data: {err}")
    try:
        exps = fit_info(tree).get("experiments") or [{}]
        identified = [exp.get("parameters") or {} for exp in exps]
        starts_named = [list((exp.get("start") or {}).get("parameters") or {})
                        for exp in exps]
        inadequacy = learn_inadequacy(_residual_records(fit, training, models, substeps, where,
                                                        identified, starts_named))
    except (KeyError, ValueError, ModelError) as err:
        notes.append(f"the model's discrepancy could not be learnt from the training data: "
                     f"{err}")
    # its own stream: spawning leaves the draws and the noise of the bands as they were
    return _Training(baselines, inadequacy, notes, rng.spawn(1)[0])


def _with_training(training: _Training, ds: Dataset, y: np.ndarray, q: float,
                   physics: dict, notes: list) -> dict:
    """The band with the discrepancy (``y``: the predictive draws, changed in place) and
    the yardsticks on a held-out data set, as :class:`ExperimentValidation` fields."""
    data = np.where(ds.counted, ds.position_m, np.nan)
    out: dict = {"baselines": {}}
    notes.extend(training.notes)
    if training.inadequacy is not None:
        y += training.inadequacy.draw(int(np.prod(y.shape[:-1])), y.shape[-1], ds.dt_s,
                                      training.rng).reshape(y.shape)
        low, high = np.quantile(y, [q, 1.0 - q], axis=0)
        out.update(low_with_discrepancy_m=low, high_with_discrepancy_m=high,
                   coverage=share_inside(data, low, high))
    if training.baselines is not None:
        out["baselines"] = training.baselines.scores(ds, arrays=True)
        notes.extend(b["failed"] for b in out["baselines"].values() if "failed" in b)
        text = yardstick_text(physics, out["baselines"], where="on these held-out data")
        if text:
            notes.append(text)
    return out


def _fitted_trials(tree: xr.DataTree) -> dict[str, set[int]]:
    """The trial ids a fit was fitted on, by the resolved path of their file (a fit
    made before its file recorded them: from its stored data and their sources)."""
    out: dict[str, set[int]] = {}
    rebuilt: list[Dataset] | None = None
    for k, exp in enumerate(fit_info(tree).get("experiments") or []):
        path, ids = exp.get("source_path"), exp.get("trial_ids")
        if ids is None or (path is None and exp.get("source")):
            try:
                rebuilt = experiment_datasets(tree) if rebuilt is None else rebuilt
            except (DataError, KeyError, ValueError):
                return out  # no data stored to tell: nothing to refuse
            ds = rebuilt[k]
            ids = [int(i) for i in ds.trial_ids] if ids is None else ids
            path = path or (ds.source_file and os.path.realpath(ds.source_file))
        if path:
            out.setdefault(path, set()).update(int(i) for i in ids)
    return out


def _refuse_fitted(ds: Dataset, fitted: dict[str, set[int]], fit_where: str,
                   in_sample: bool = False) -> None:
    """A trial the fit was fitted on is not held out: refused, naming it and the fix;
    only said when ``in_sample`` asks for the fit on its own data."""
    if not ds.source_file:
        return
    ids = fitted.get(os.path.realpath(ds.source_file))
    have = [int(i) for i in ds.trial_ids]
    both = [i for i in have if ids and i in ids]
    if not both:
        return
    if in_sample:
        warnings.warn(f"{ds.source_file}: trial{'s' if len(both) > 1 else ''} "
                      f"{', '.join(map(str, both))} {'were' if len(both) > 1 else 'was'} "
                      f"fitted ({fit_where}); in_sample: these are not held-out data, and "
                      "the numbers say how well it fits, not how well it predicts",
                      DataWarning, stacklevel=3)
        return
    left = [i for i in have if i not in both]
    fix = (f"validate on the trials it left out: trials={left} (on the command line: "
           f"--trials {','.join(map(str, left))})" if left else
           "hold trials out when fitting (pmabayes.fit(data, trials=[...])) and validate on "
           "the others (validate(fit, data, trials=[...])); to measure the fit on its "
           "own data instead, say so: validate(..., in_sample=True), --in-sample")
    raise ValidationError(
        f"{ds.source_file}: trial{'s' if len(both) > 1 else ''} {', '.join(map(str, both))} "
        f"{'were' if len(both) > 1 else 'was'} fitted ({fit_where} was made from trials "
        f"{', '.join(map(str, sorted(ids)))} of this file), so "
        f"{'they are' if len(both) > 1 else 'it is'} not held out and the numbers would "
        f"measure the fit, not a prediction; {fix}")


def _one(fit: _FitDraws, ds: Dataset, *, n_draws: int, ci_prob: float, noise_from: str | None,
         substeps: int, rng: np.random.Generator, tree: xr.DataTree,
         training: _Training, start_fraction: float = START_FRACTION) -> ExperimentValidation:
    where = ds.source or "held-out data set"
    model = _check_dataset(fit, ds, where)
    try:
        check_dataset(tree, ds)
    except (DataError, KeyError, ValueError):
        pass  # different from the fit's data, as held-out data should be
    else:
        warnings.warn(f"{where}: these are the data the fit was made from, not held-out "
                      "data; the numbers say how well it fits, not how well it predicts",
                      DataWarning, stacklevel=3)
    columns, noise_text = _noise_columns(fit, model.rig, noise_from)
    pick = rng.choice(fit.n_total, size=min(n_draws, fit.n_total), replace=False)
    names = _draw_names(fit, model, where)
    theta = model.theta({n: _flat(fit.draws[names[n]], names[n], where)[pick]
                         for n in model.free_names})
    starts, start = None, {"initial_state": ds.initial_state}
    if ds.initial_state == "estimate":
        est = _estimated_starts(model, theta, ds, start_fraction, substeps)
        starts, n_start = est.values, est.samples
        start.update(samples=n_start, fraction=n_start / ds.n_samples,
                     seconds=float(ds.time_s[n_start - 1] - ds.time_s[0]), window=est.window,
                     states_estimated=list(est.names[3:]),
                     states_at_rest=[e.state for e in state_effects(model)
                                     if e not in estimated_states(model)],
                     **{f"{k}_median": float(v) for k, v in
                        zip(est.names, np.median(starts, axis=0), strict=True)},
                     v0_bound_m_s=est.speed_bound_m_s, v0_at_bound=est.at_bound,
                     not_estimated=est.not_estimated)
        if est.not_estimated:
            warnings.warn(f"{where}: the start of {est.not_estimated} of {pick.size} posterior "
                          "draws could not be estimated (their simulation from the start's "
                          f"prior means is not finite over the first {n_start} samples): they "
                          "start from those prior means", DataWarning, stacklevel=3)
    x, own = _draw_positions(model, theta, ds, substeps, starts)
    sigma, rho, white, fit_dt, col = _noise_draws(fit, pick, columns, rng)
    notes: list[str] = []
    ok = np.all(np.isfinite(x.reshape(x.shape[0], -1)), axis=1)
    if not ok.any():
        raise ValidationError(f"{where}: the simulation failed (non-finite positions) for "
                              f"every one of {pick.size} posterior draws on this input")
    if not ok.all():
        warnings.warn(f"{where}: {int((~ok).sum())} of {pick.size} posterior draws gave "
                      "non-finite positions on this input and are left out of the bands",
                      DataWarning, stacklevel=3)
        notes.append(f"{int((~ok).sum())} of {pick.size} draws failed to simulate (left out)")
        x, sigma, rho, white, col = x[ok], sigma[ok], rho[ok], white[ok], col[ok]
    x_mean = trials_mean(ds, x) if own else x  # each draw's trial mean
    ybar = observed_mean(ds)
    if "samples" in start:
        after = (ybar - x_mean.mean(axis=0))[start["samples"]:]
        start["rmse_after_start_m"] = float(np.sqrt(np.mean(after[np.isfinite(after)]**2)))
        notes.append(f"the start was estimated for each draw from the first {start['samples']} "
                     f"samples ({100 * start['fraction']:.3g}% of the record, "
                     f"{start['seconds']:.3g} s; {start['window']}); the numbers are over the "
                     "whole record, rmse_after_start_m over the rest")
        if start["states_estimated"]:
            notes.append("the start holds the effects' states too, estimated with it: "
                         + ", ".join(start["states_estimated"]))
        if start["states_at_rest"]:
            notes.append("effects' states started at 0, at rest (their effects give no prior "
                         "for an estimated start): " + ", ".join(start["states_at_rest"]))
        if start["not_estimated"]:
            notes.append(f"the start of {start['not_estimated']} of {pick.size} draws could not "
                         "be estimated (their simulation from the start's prior means is not "
                         "finite): they start from those prior means (not_estimated)")
        if start["v0_at_bound"]:
            notes.append(f"the start velocity of {start['v0_at_bound']} of {pick.size} draws "
                         f"reached its bound, {start['v0_bound_m_s']:.3g} m/s (the largest "
                         "speed of the samples it was fitted to): they ask for a start the "
                         "record does not allow, a sign of misfit there (v0_at_bound)")
    if fit_dt is not None and abs(ds.dt_s - fit_dt) > 1e-9 * fit_dt:
        ratio = ds.dt_s / fit_dt
        rho = np.sign(rho) * np.abs(rho) ** ratio
        notes.append(f"the fit's noise correlation (per sample at {1 / fit_dt:.6g} Hz) is "
                     f"rescaled to this data set's {ds.sample_rate_hz:.6g} Hz as rho ** "
                     f"{ratio:.6g}")
    elif fit_dt is None:
        notes.append("the fit's sample interval is not recorded; its noise correlation is "
                     "used per sample as it is")
    k = _NOISE_PER_DRAW
    n = ds.n_samples
    # one noise series per draw, copy and trial: each trial its own band where the
    # trials have their own inputs
    per = k * (ds.n_trials if own else 1)
    y = measurement_noise(x.shape[0] * per, n,
                          *(np.repeat(v, per) for v in (sigma, rho, white)), rng)
    _ar_noise(y, col, per, fit,
              fit_dt is not None and abs(ds.dt_s - fit_dt) <= 1e-9 * fit_dt, rng, notes)
    if own:
        y = y.reshape(x.shape[0], k, ds.n_trials, n)
        y += x[:, None]
        y = y.reshape(-1, ds.n_trials, n)
        notes.append("the trials have their own inputs: each is predicted on its own, with "
                     "its own predictive band (low_m, high_m: one row per trial); the "
                     "prediction, the errors and the model-only band are the trial mean's")
    else:
        y.reshape(x.shape[0], k, n)[...] += x[:, None, :]
    q = (1.0 - ci_prob) / 2.0
    low, high = np.quantile(y, [q, 1.0 - q], axis=0)
    model_low, model_high = np.quantile(x_mean, [q, 1.0 - q], axis=0)
    prediction = x_mean.mean(axis=0)
    resid = ybar - prediction
    rmse, normalised = nrmse(ybar, prediction)
    floor = ds.noise_floor_m
    data = np.where(ds.counted, ds.position_m, np.nan)
    coverage = share_inside(data, low, high)
    per_band = _band_errors(ds, prediction, notes, x.mean(axis=0) if own else None)
    if own and ds.n_trials > 1:  # the raw trials' spread holds the inputs' differences
        notes.append("the noise floor is the spread of the trials' residuals from the "
                     "posterior-mean prediction on each one's input")
    extra = _with_training(training, ds, y, q, {"rmse_m": rmse, "nrmse": normalised}, notes)
    adequacy = _adequacy(model, ds, x.mean(axis=0) if own else prediction,
                         (sigma, rho, white), coverage, ci_prob, notes)
    return ExperimentValidation(
        name=Path(ds.source).stem if ds.source else "data set",
        source=ds.source, synthetic=bool(ds.metadata.get("synthetic", False)),
        rig=model.rig.to_dict(), input_name=ds.input_name, time_s=np.array(ds.time_s),
        input=np.array(shared_input(ds)),
        position_m=np.array(ds.position_m), prediction_m=prediction,
        model_low_m=model_low, model_high_m=model_high, low_m=low, high_m=high,
        rmse_m=rmse, nrmse=normalised,
        max_error_m=float(np.nanmax(np.abs(resid))),
        noise_floor_m=None if math.isnan(floor) else float(floor),
        band_coverage=coverage,
        model_band_coverage=share_inside(ybar, model_low, model_high),
        band_errors=per_band,
        noise={"from": noise_text,
               **{f"{n}_median": float(np.median(v))
                  for n, v in zip(NOISE_NAMES, (sigma, rho, white), strict=True)}},
        n_draws=int(x.shape[0]), ci_prob=ci_prob, notes=notes, start=start,
        coverage_parameters_only=share_inside(data, low, high), adequacy=adequacy, **extra)


def _adequacy(model: Model, ds: Dataset, prediction: np.ndarray, noise: tuple,
              coverage: float, ci_prob: float, notes: list) -> Adequacy | None:
    """The adequacy verdict on held-out data (the one rule of ``fit`` and ``diagnose``),
    the prediction's residual whitened with the fit's noise (its draws' medians); None,
    with the reason in ``notes``, when it cannot be judged."""
    sigma, rho, white = (float(np.median(v)) for v in noise)
    try:
        return check_adequacy(Likelihood(model, ds), prediction,
                              SimpleNamespace(sigma=sigma, rho=rho, white=white),
                              coverage=coverage, ci_prob=ci_prob)
    except (ValueError, np.linalg.LinAlgError) as err:
        notes.append(f"the adequacy verdict could not be judged on these data: {err}")
        return None


def validate(
    tree: xr.DataTree | str | os.PathLike,
    datasets: Dataset | str | os.PathLike | Sequence[Dataset | str | os.PathLike],
    *,
    n_draws: int = DEFAULT_DRAWS,
    ci_prob: float = 0.9,
    seed: int | None = 0,
    rng: np.random.Generator | None = None,
    noise_from: str | None = None,
    substeps: int | None = None,
    start_fraction: float = START_FRACTION,
    trials: Sequence[int] | None = None,
    in_sample: bool = False,
) -> Validation:
    """Predict held-out experiments with a fit's posterior and compare with their data.

    Parameters
    ----------
    tree : xarray.DataTree or path
        A fit (:func:`pmabayes.inference.fitfile.load_fit` reads a path).
    datasets : Dataset, path, or a sequence of them
        The held-out experiments, one per data set (a path is read with
        :func:`pmabayes.data.load`). Each is simulated on the rig its metadata gives.
    n_draws : int
        Posterior draws to simulate per experiment (all of them if the fit has fewer),
        a seeded random subset, simulated in one batch.
    ci_prob : float
        Probability of the central bands and of ``band_coverage`` (0.9).
    seed : int or None
        Seed of the draws' choice and of the predictive noise; ignored when ``rng``
        is given.
    rng : numpy.random.Generator, optional
        The generator to draw from instead.
    noise_from : str, optional
        For a fit of several experiments: the fitted experiment whose noise makes the
        predictive band (by default the one on the held-out data's rig; see the
        module's docstring).
    substeps : int, optional
        Simulator steps per sample interval (see :func:`pmabayes.simulate`); by default
        as many as the fit used (its file records them).
    start_fraction : float
        For a held-out data set whose start is declared ``"estimate"``: the first part
        of its record (a fraction, :data:`START_FRACTION`) from which each draw's start
        is estimated (see the module's docstring).
    trials : sequence of int, optional
        Validate only these trials (ids, as in the file's ``trial`` column) of the
        data, which must come from one file: the trials a fit held out of it
        (:func:`pmabayes.fit` with ``trials=``). All of them by default.
    in_sample : bool
        Allow trials the fit was fitted on (False). Their numbers then measure how well
        the model fits, not how well it predicts (a warning says so); this is for
        comparing a fit with the yardsticks on its own data, not for validation.

    Returns
    -------
    Validation
        One :class:`ExperimentValidation` per data set.

    Raises
    ------
    ValidationError
        For a data set the fit cannot predict (a different input kind, a rig whose
        parameters the fit lacks, trials with different inputs), a fit without
        noise draws, or bad settings; and for a trial the fit was fitted on (the same
        file and trial id, as the fit file records them), which is not held out,
        unless ``in_sample`` is True.
    DataError
        When ``trials`` names an id the data do not hold, or data of several files.

    Examples
    --------
    Predict the two trials a fit held out of its file (the example of
    :func:`pmabayes.fit`):

    >>> import pmabayes
    >>> from pmabayes.data import load
    >>> data = load("muscle_a.csv")  # doctest: +SKIP
    >>> model = pmabayes.Model.for_dataset(data, effects=["regulator_lag"])  # doctest: +SKIP
    >>> tree = pmabayes.fit(data, model, trials=[1, 2, 3, 4])  # doctest: +SKIP
    >>> v = pmabayes.validate(tree, data, trials=[5, 6])  # doctest: +SKIP
    >>> e = v.experiments[0]  # doctest: +SKIP
    >>> round(e.ratio_to_floor, 2), e.band_coverage  # doctest: +SKIP
    (0.99, 0.9033)
    >>> print(e.summary())  # doctest: +SKIP

    ``validate(tree, data)`` without ``trials=`` is refused: trials 1 to 4 were
    fitted, so they are not held out (``in_sample=True`` allows them, to measure the
    fit).
    """
    if not (isinstance(n_draws, int | np.integer) and not isinstance(n_draws, bool)
            and n_draws >= 2):
        raise ValidationError(f"n_draws must be an integer >= 2, got {n_draws!r}")
    ci_prob = float(ci_prob)
    if not 0.0 < ci_prob < 1.0:
        raise ValidationError(f"ci_prob must be in (0, 1), got {ci_prob!r} (e.g. 0.9)")
    if not 0.0 < float(start_fraction) <= 1.0:
        raise ValidationError(f"start_fraction must be in (0, 1], got {start_fraction!r} "
                              "(e.g. 0.05: the first 5% of the record)")
    fit_path = None
    if isinstance(tree, str | os.PathLike):
        fit_path = os.fspath(tree)
        tree = load_fit(tree)
    if isinstance(datasets, Dataset | str | os.PathLike):
        datasets = [datasets]
    datasets = [load(d) if isinstance(d, str | os.PathLike) else d for d in datasets]
    if not datasets:
        raise ValidationError("no held-out data set given; give one or more data files")
    for d in datasets:
        if not isinstance(d, Dataset):
            raise TypeError(f"datasets must be Datasets or paths, got {type(d).__name__}")
    if trials is not None:
        datasets = keep_trials(datasets, trials)
    fitted = _fitted_trials(tree)
    for d in datasets:
        _refuse_fitted(d, fitted, fit_path or "the fit", in_sample)
    fit = _read_fit(tree, fit_path or "the fit")
    if substeps is None:
        substeps = int(fit_info(tree).get("substeps", 1))
    recorded_seed = None if rng is not None else seed
    if rng is None:
        rng = np.random.default_rng(seed)
    training = _learn_from_training(fit, tree, substeps, fit_path or "the fit", rng)
    experiments = [_one(fit, ds, n_draws=int(n_draws), ci_prob=ci_prob,
                        noise_from=noise_from, substeps=substeps, rng=rng, tree=tree,
                        training=training, start_fraction=float(start_fraction))
                   for ds in datasets]
    return Validation(
        experiments=experiments, fit_source=fit_path or fit.source,
        effects=tuple(e.name for e in fit.effects),
        settings={"n_draws": int(n_draws), "ci_prob": ci_prob,
                  "seed": recorded_seed,
                  "noise_from": noise_from, "substeps": substeps,
                  **({"start_fraction": float(start_fraction)}
                     if any(d.initial_state == "estimate" for d in datasets) else {})},
        discrepancy=training.inadequacy, baselines=training.baselines)
