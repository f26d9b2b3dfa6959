"""The posterior to sample, built from a model and experiments: the experiments checked,
a likelihood per experiment on its own rig, the repeated trials checked, and each noise
group's estimate and noise model (:mod:`pmabayes.inference.noise`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pmabayes.data import Dataset, check_same_input_kind
from pmabayes.data.dataset import dataset_list
from pmabayes.inference.density import Posterior
from pmabayes.inference.errors import FitError
from pmabayes.inference.fitfile import experiment_names
from pmabayes.inference.likelihood import (
    Likelihood,
    LikelihoodError,
    NoiseChoice,
    check_noise_model_name,
)
from pmabayes.inference.noise import group_noise
from pmabayes.inference.trials import check_trials
from pmabayes.model.model import Model, ModelError, force_rig_priors
from pmabayes.model.simulator import SimulationError

__all__ = ["experiments", "build_posterior", "choose_substeps", "data_scaled_priors",
           "prior_median", "noise_groups", "SUBSTEP_CHOICES", "SUBSTEP_TOLERANCE"]


def experiments(datasets: Dataset | Sequence[Dataset], model: Model
                ) -> tuple[list[Dataset], list[Model], list[str]]:
    """The experiments of a fit or a diagnosis, checked, each with its model and name.

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        One data set per experiment, all with the same kind of input.
    model : Model
        The model. With one experiment it is used as given; with several, each
        experiment gets it on the rig its metadata records (:meth:`Model.on_rig`).

    Returns
    -------
    datasets : list of Dataset
    models : list of Model
    names : list of str
        The experiments' names (:func:`pmabayes.inference.fitfile.experiment_names`).

    Raises
    ------
    ValueError
        With no data set.
    TypeError
        If an item is not a Dataset.
    DataError
        With experiments of different input kinds.
    ModelError
        If a data set records a rig that is not valid.
    """
    datasets = dataset_list(datasets, ValueError("no data: give at least one data set"))
    check_same_input_kind(datasets)
    models = [model] if len(datasets) == 1 else [model.on_rig(ds) for ds in datasets]
    return datasets, models, experiment_names([ds.source for ds in datasets])


#: The substeps an automatic choice tries, in order (:func:`choose_substeps`).
SUBSTEP_CHOICES = (1, 2, 4, 8, 16, 32, 64)
#: An automatic choice takes the fewest substeps whose output changes, when they are
#: doubled, by at most this fraction of the data's motion (the RMS of the trial mean
#: about its mean), at the prior's median (:func:`choose_substeps`).
SUBSTEP_TOLERANCE = 1e-4


def prior_median(model: Model) -> dict[str, float]:
    """Every parameter at its prior's median (fixed ones at their value).

    Parameters
    ----------
    model : Model

    Returns
    -------
    dict
        By parameter name.
    """
    values = dict(model.defaults)
    values.update({n: model.priors[n].quantile(0.5) for n in model.free_names})
    return values


def choose_substeps(models: Sequence[Model], datasets: Sequence[Dataset]) -> dict:
    """The simulator's substeps per sample, from its own accuracy check.

    At the prior's median, each experiment is simulated with 1, 2, 4, ... substeps;
    the choice is the fewest whose output changes by at most
    :data:`SUBSTEP_TOLERANCE` of the data's motion when they are doubled, in every
    experiment (at most 64). The integration error falls as ``substeps**-2``, so the
    change on doubling is three quarters of the error.

    Parameters
    ----------
    models : sequence of Model
        Each experiment's model.
    datasets : sequence of Dataset
        The experiments.

    Returns
    -------
    dict
        ``chosen`` (int), ``requested`` (``"auto"``), ``tolerance_m`` per experiment
        and ``changes_m``: the largest RMS change on doubling, by substeps tried.
    """
    tolerance = [SUBSTEP_TOLERANCE * float(np.nanstd(ds.mean_position_m)) for ds in datasets]
    # as the likelihood simulates: each trial on its own input, from an estimated start
    runs = [(Likelihood(m, ds), m.theta(prior_median(m)))
            for m, ds in zip(models, datasets, strict=True)]

    def outputs(k: int) -> list[np.ndarray]:
        out = []
        for lik, th in runs:
            lik.substeps = k
            with np.errstate(all="ignore"):
                out.append(lik.simulate(th)[0])
        return out

    changes: dict[str, float] = {}
    chosen = SUBSTEP_CHOICES[-1]
    last = outputs(SUBSTEP_CHOICES[0])
    for k, k2 in zip(SUBSTEP_CHOICES[:-1], SUBSTEP_CHOICES[1:], strict=True):
        finer = outputs(k2)
        rms = [float(np.sqrt(np.mean((a - b) ** 2))) for a, b in zip(last, finer, strict=True)]
        changes[str(k)] = max(rms)
        if all(r <= t for r, t in zip(rms, tolerance, strict=True)):  # NaN: not accurate
            chosen = k
            break
        last = finer
    return {"requested": "auto", "chosen": int(chosen), "tolerance_m": tolerance,
            "changes_m": changes,
            "rule": f"fewest substeps whose output changes by at most {SUBSTEP_TOLERANCE:g} of "
                    "the data's motion (RMS) when doubled, at the prior's median"}


def data_scaled_priors(model: Model, datasets: Sequence[Dataset]) -> tuple[Model, dict | None]:
    """A force-input rig's default priors on the scale of its data.

    The static compliance comes from a linear fit of the force less the rig's
    inertia, ``u - m x''``, on position, velocity and a constant over all experiments
    (the ratio of the ranges where the fitted stiffness is not positive), the
    amplitude from the positions' largest range
    (:func:`pmabayes.model.model.force_rig_priors`). Priors the user chose win. A
    pressure rig's defaults are the muscle's and stay as they are.

    Parameters
    ----------
    model : Model
    datasets : sequence of Dataset

    Returns
    -------
    model : Model
        With the scaled defaults (the same model for a pressure rig).
    record : dict or None
        ``compliance_m_per_n``, ``amplitude_m`` and the ``priors`` chosen (text), for
        the fit file; None for a pressure rig.
    """
    if model.rig.input_kind != "force":
        return model, None
    rows, rhs = [], []
    for ds in datasets:  # u - m y'' = k y + d y' + c: the spring's share of the force
        y, dt = ds.mean_position_m, ds.grid_dt_s
        v = np.gradient(y, dt)
        rows.append(np.column_stack([y, v, np.ones_like(y)]))
        rhs.append(ds.input[0] - model.rig.moving_mass_kg * np.gradient(v, dt))
    stiffness = float(np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0][0])
    ranges = (max(float(np.ptp(ds.mean_position_m)) for ds in datasets),
              max(float(np.ptp(ds.input[0])) for ds in datasets))
    compliance = (1.0 / stiffness if stiffness > 0 and np.isfinite(stiffness)
                  else ranges[0] / max(ranges[1], 1e-300))
    amplitude = 0.5 * ranges[0]
    if not (compliance > 0 and amplitude > 0 and np.isfinite(compliance)):
        raise FitError(f"{datasets[0].source or 'the data'}: the force or the position never "
                       "changes, so the data give no scale for the oscillator's priors; "
                       "check the input and position columns")
    scaled = force_rig_priors(compliance, amplitude, model.rig.moving_mass_kg, model.effects)
    out = model.with_default_priors(scaled)
    chosen = model.chosen_priors()
    return out, {"compliance_m_per_n": compliance, "amplitude_m": amplitude,
                 "priors": {n: str(p) for n, p in scaled.items()
                            if n not in chosen and n in out.parameter_names},
                 "rule": "force-input rig: alpha and K_e around half the inverse static "
                         "compliance, beta and gamma from the motion's amplitude, d around "
                         "sqrt(mass / compliance); the noise's scale from the amplitude"}


def noise_groups(datasets: Sequence[Dataset], *, tie_noise: bool = False,
                 tie_segments: bool = True) -> list[int]:
    """The noise group of each experiment.

    One group for all with ``tie_noise``; else one per experiment, except that the
    segments of one record (:func:`pmabayes.data.load_segments`: the metadata's
    ``"segment"``, from one file) share one with ``tie_segments``: one sensor, one
    disturbance, split only by the DAQ's pauses.

    Parameters
    ----------
    datasets : sequence of Dataset
    tie_noise, tie_segments : bool

    Returns
    -------
    list of int
        Groups numbered from 0 in the order of their first experiment.
    """
    if tie_noise:
        return [0] * len(datasets)
    keys: dict = {}
    out = []
    for i, ds in enumerate(datasets):
        seg = ds.metadata.get("segment")
        key = (i,)
        if tie_segments and isinstance(seg, dict) and ds.source:
            key = (str(Path(ds.source).parent), str(seg.get("name", "")).rpartition("#")[0])
        out.append(keys.setdefault(key, len(keys)))
    return out


def build_posterior(model: Model, datasets: Dataset | Sequence[Dataset], *,
                    substeps: int | str = 1, tie_noise: bool = False,
                    noise_model: str = "auto", steady_state_tol_m: float | None = None,
                    max_warmup_periods: int | None = None,
                    tie_segments: bool = True) -> Posterior:
    """The posterior to sample.

    Parameters
    ----------
    model : Model
        The model (see :func:`experiments` for several experiments). On a
        force-input rig its default priors are first put on the data's scale
        (:func:`data_scaled_priors`).
    datasets : Dataset or sequence of Dataset
        The experiments.
    substeps : int or "auto"
        Simulator substeps per sample; ``"auto"`` chooses them from the simulator's
        accuracy check (:func:`choose_substeps`).
    tie_noise : bool
        One noise group for all experiments instead of one each.
    noise_model : str
        ``"auto"`` or a registered noise model's name: the noise model each group's
        repeats choose (:func:`pmabayes.inference.noise.choose_noise_model`), or the
        one asked for.
    steady_state_tol_m, max_warmup_periods : optional
        The periodic steady state's settings where the data start in it, over each
        sidecar's (:func:`pmabayes.model.simulator.warmup_settings`).
    tie_segments : bool
        The segments of one record share their noise (:func:`noise_groups`).

    Returns
    -------
    Posterior
        A likelihood per experiment, each noise group's estimate from its repeats
        (None where it has none: sampled with the model) and its noise model; its
        ``settings_record`` holds the substeps' choice and any data-scaled priors.

    Raises
    ------
    FitError
        For an unknown noise model, bad substeps, or experiments the model cannot
        describe.
    """
    try:
        check_noise_model_name(noise_model)
        datasets, models, names = experiments(datasets, model)
        scaled = data_scaled_priors(models[0], datasets)[1]
        models = [data_scaled_priors(m, datasets)[0] for m in models]
        if substeps == "auto":
            choice = choose_substeps(models, datasets)
        elif isinstance(substeps, int | np.integer) and not isinstance(substeps, bool) \
                and substeps >= 1:
            choice = {"requested": int(substeps), "chosen": int(substeps)}
        else:
            raise FitError(f"substeps must be a whole number >= 1 or 'auto', got {substeps!r}")
        liks = [Likelihood(m, ds, substeps=choice["chosen"],
                           steady_state_tol_m=steady_state_tol_m,
                           max_warmup_periods=max_warmup_periods)
                for m, ds in zip(models, datasets, strict=True)]
    except (ValueError, LikelihoodError, ModelError, SimulationError) as exc:
        raise FitError(str(exc)) from None  # DataError is a ValueError
    for ds, lik in zip(datasets, liks, strict=True):  # before their spread is taken for noise
        if not lik.own_inputs:  # those are checked on their residuals at the MAP
            check_trials(ds, warn=True)
    groups = noise_groups(datasets, tie_noise=tie_noise, tie_segments=tie_segments)
    noises = []
    choices: list[NoiseChoice | None] = [None] * len(liks)
    for g in range(max(groups) + 1):
        est, choice_g = group_noise([lik for lik, gg in zip(liks, groups, strict=True)
                                     if gg == g], noise_model)
        noises.append(est)
        for e, gg in enumerate(groups):
            if gg == g:
                choices[e] = choice_g
    posterior = Posterior(liks, noises, names=names, noise_groups=groups,
                          noise_choices=choices)
    posterior.settings_record = {"substeps": choice, "data_scaled_priors": scaled}
    return posterior
