"""The posterior to sample, built from a model and experiments: the experiments checked,
a likelihood per experiment on its own rig, the repeated trials checked, and each noise
group's estimate and noise model (:mod:`pmabayes.inference.noise`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from pmabayes.data import Dataset, check_same_input_kind
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
from pmabayes.model.model import Model, ModelError

__all__ = ["experiments", "build_posterior", "noise_groups"]


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
    datasets = [datasets] if isinstance(datasets, Dataset) else list(datasets)
    if not datasets:
        raise ValueError("no data: give at least one data set")
    for ds in datasets:
        if not isinstance(ds, Dataset):
            raise TypeError(f"datasets must be pmabayes.data.Dataset objects, got "
                            f"{type(ds).__name__}")
    check_same_input_kind(datasets)
    models = [model] if len(datasets) == 1 else [model.on_rig(ds) for ds in datasets]
    return datasets, models, experiment_names([ds.source for ds in datasets])


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


def build_posterior(model: Model, datasets: Dataset | Sequence[Dataset], *, substeps: int = 1,
                    tie_noise: bool = False, noise_model: str = "auto",
                    tie_segments: bool = True) -> Posterior:
    """The posterior to sample.

    Parameters
    ----------
    model : Model
        The model (see :func:`experiments` for several experiments).
    datasets : Dataset or sequence of Dataset
        The experiments.
    substeps : int
        Simulator substeps per sample.
    tie_noise : bool
        One noise group for all experiments instead of one each.
    noise_model : {"auto", "ar1", "ar"}
        The noise model each group's repeats choose
        (:func:`pmabayes.inference.likelihood.choose_noise_model`).
    tie_segments : bool
        The segments of one record share their noise (:func:`noise_groups`).

    Returns
    -------
    Posterior
        A likelihood per experiment, each noise group's estimate from its repeats
        (None where it has none: sampled with the model) and its noise model.

    Raises
    ------
    FitError
        For an unknown noise model, or experiments the model cannot describe.
    """
    try:
        check_noise_model_name(noise_model)
        datasets, models, names = experiments(datasets, model)
        liks = [Likelihood(m, ds, substeps=substeps)
                for m, ds in zip(models, datasets, strict=True)]
    except (ValueError, LikelihoodError, ModelError) as exc:  # DataError is a ValueError
        raise FitError(str(exc)) from None
    for ds, lik in zip(datasets, liks, strict=True):  # before their spread is taken for noise
        if not lik.own_inputs:  # those are checked on their residuals at the MAP
            check_trials(ds, warn=True)
    groups = noise_groups(datasets, tie_noise=tie_noise, tie_segments=tie_segments)
    noises = []
    choices: list[NoiseChoice | None] = [None] * len(liks)
    for g in range(max(groups) + 1):
        est, choice = group_noise([lik for lik, gg in zip(liks, groups, strict=True)
                                   if gg == g], noise_model)
        noises.append(est)
        for e, gg in enumerate(groups):
            if gg == g:
                choices[e] = choice
    return Posterior(liks, noises, names=names, noise_groups=groups, noise_choices=choices)
