"""Watching the error fall: fits of the same data side by side (errors per band,
whiteness, and leave-one-trial-out ELPD).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmabayes.criticism.bands import (
    band_errors,
)
from pmabayes.criticism.elpd import loo_table
from pmabayes.criticism.refits import physical_values
from pmabayes.criticism.whiteness import (
    WhitenessCurves,
    judged_whiteness,
    whiteness_curves,
)
from pmabayes.data import DataError, Dataset
from pmabayes.inference.fitfile import (
    check_dataset,
    experiment_datasets,
    experiment_models,
    fit_info,
    model_from_fit,
)
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.noise import NoiseEstimate
from pmabayes.model.model import Model
from pmabayes.model.simulator import simulate_dataset
from pmabayes.util import finite_or_none

__all__ = ["FitComparison", "compare_fits"]


@dataclass(frozen=True)
class FitComparison:
    """Fits of one data set side by side (base, base + effect, ...).

    Parameters
    ----------
    labels : list of str
        One per fit, in the given order (``base``, ``base + regulator_lag``...).
    bands : dict
        Label to :func:`~pmabayes.criticism.bands.band_errors` of the MAP model.
    whiteness : dict
        Label to ``{"ljung_box_p", "energy", "energy_p"}`` of the whitened residual.
    innovations : dict
        Label to the whitened residual.
    elpd : dict
        Label to ``{"elpd", "se", "elpd_diff", "dse", "rank", "max_pareto_k"}``:
        leave-one-trial-out PSIS-LOO (:func:`arviz.loo`) on the fits' posterior
        draws; ``elpd_diff`` and its standard error ``dse`` are relative to the best
        fit, from the paired per-trial differences (as :func:`arviz.compare`).
    elpd_steps : list of dict
        Each fit against the one before it: ``{"from", "to", "elpd_diff", "se"}``
        with the standard error of the paired per-trial differences.
    command_rate : numpy.ndarray
        Rate of change of the commanded input (for the cross-correlation figure).
    dt_s : float
        Sample interval.
    experiments : dict
        For fits of several experiments: experiment name to the comparison on that
        experiment alone (its ``bands``, ``whiteness``, ``innovations``,
        ``command_rate`` and ``dt_s``; ``elpd`` and ``elpd_steps`` are the
        overall ones), in the fits' order. Then ``bands``, ``whiteness`` and
        ``innovations`` are empty, ``command_rate`` is empty and ``dt_s`` NaN:
        errors and whiteness are per experiment, and only the ELPD (leaving out
        one trial at a time of all experiments) is overall. Empty for one
        experiment.
    """

    labels: list
    bands: dict
    whiteness: dict
    innovations: dict
    elpd: dict
    elpd_steps: list
    command_rate: np.ndarray
    dt_s: float
    experiments: dict | None = None

    def whiteness_curves(self) -> WhitenessCurves:
        """The whiteness figure's curves of each fit (lags to 0.2 s, 99% bound).

        Raises
        ------
        ValueError
            For fits of several experiments: take each experiment's from
            ``experiments[name].whiteness_curves()``.
        """
        if self.experiments:
            raise ValueError("a comparison of fits of several experiments has whiteness curves "
                             "per experiment: use experiments[name].whiteness_curves()")
        return whiteness_curves(self.innovations, self.command_rate, self.dt_s)

    def rmse_m(self, label: str) -> dict:
        """RMS error of the trial mean at a fit's MAP, per experiment.

        Parameters
        ----------
        label : str
            The fit.

        Returns
        -------
        dict
            Experiment name to RMS error in m (one experiment: ``{"data": ...}``).
        """
        if self.experiments:
            return {n: c.bands[label][-1].rms_m for n, c in self.experiments.items()}
        return {"data": self.bands[label][-1].rms_m}

    def to_dict(self) -> dict:
        """JSON-ready summary.

        One experiment: ``fits`` (``label``, ``rms_m``, ``noise_floor_m``, ``ratio``,
        ``bands``, ``whiteness``, ``elpd`` each) and ``elpd_steps``. Several: each
        fit has ``label``, ``elpd`` (over all trials) and ``experiments`` (name to
        ``rms_m``, ``noise_floor_m``, ``ratio``, ``bands``, ``whiteness``), and
        ``experiments`` lists the names.
        """
        if self.experiments:
            return {
                "fits": [
                    {"label": k, "elpd": self.elpd[k],
                     "experiments": {n: c._fit_dict(k) for n, c in self.experiments.items()}}
                    for k in self.labels
                ],
                "elpd_steps": self.elpd_steps,
                "experiments": list(self.experiments),
            }
        return {
            "fits": [{"label": k, **self._fit_dict(k), "elpd": self.elpd[k]}
                     for k in self.labels],
            "elpd_steps": self.elpd_steps,
        }

    def _fit_dict(self, k: str) -> dict:
        last = self.bands[k][-1]
        return {"rms_m": last.rms_m, "noise_floor_m": finite_or_none(last.floor_m),
                "ratio": finite_or_none(last.ratio),
                "bands": [b.to_dict() for b in self.bands[k]], "whiteness": self.whiteness[k]}


def compare_fits(fits, dataset: Dataset | Sequence[Dataset], *, labels=None,
                 sources: Sequence[str] | None = None) -> FitComparison:
    """Compare fits of the same data: error per band, whiteness and ELPD.

    Fits of several experiments compare too, when every fit has the same
    experiments (names, data, in the same order): the errors and whiteness per
    experiment, the ELPD leaving out one trial at a time of all of them.

    Parameters
    ----------
    fits : sequence of xarray.DataTree
        Fits written by :func:`pmabayes.inference.sampler.fit` (same data, different models).
    dataset : Dataset or sequence of Dataset
        The data they were made from (checked against each fit): one data set, or
        one per experiment in the fits' order.
    labels : sequence of str, optional
        Names of the fits; ``base + effect + ...`` from their models by default.
    sources : sequence of str, optional
        Where each fit came from (file names), to name them in errors.

    Returns
    -------
    FitComparison

    Raises
    ------
    ValueError
        With fewer than two fits, labels that do not match, a fit made from other
        data, or fits of different experiments (:class:`pmabayes.data.DataError`,
        naming the fits and the files).
    """
    fits = list(fits)
    if len(fits) < 2:
        raise ValueError("compare needs at least two fits of the same data")
    sources = list(sources) if sources is not None else [f"fit {i + 1}" for i in range(len(fits))]
    datasets = [dataset] if isinstance(dataset, Dataset) else list(dataset)
    exps = [[e["name"] for e in (fit_info(t).get("experiments") or [{"name": None}])]
            for t in fits]
    for src, names in zip(sources, exps, strict=True):
        # one experiment each: the data check below decides (its name is only a file stem)
        if len(names) != len(exps[0]) or (len(names) > 1 and names != exps[0]):
            raise DataError(
                f"{src} is a fit of {len(names)} experiment(s) {names}, but {sources[0]} of "
                f"{len(exps[0])} {exps[0]}; compare takes fits of the same experiments, in "
                "the same order: refit one of them with the other's data files")
    if labels is None:
        labels = [" + ".join(["base", *model_from_fit(t).effect_names]) for t in fits]
    labels = list(labels)
    if len(labels) != len(fits) or len(set(labels)) != len(labels):
        raise ValueError(f"need {len(fits)} distinct labels, got {labels}")
    if len(exps[0]) == 1:
        if len(datasets) != 1:
            raise DataError(f"the fits are of one data set, but {len(datasets)} were given: "
                            "give the one they were made from")
        return _compare_one(fits, labels, datasets[0], [model_from_fit(t) for t in fits])
    if len(datasets) != len(exps[0]):
        raise DataError(
            f"the fits are of {len(exps[0])} experiments ({', '.join(exps[0])}) but "
            f"{len(datasets)} data set(s) were given: give one per experiment, in that order")
    per = {}
    models = [experiment_models(t) for t in fits]
    for e, name in enumerate(exps[0]):
        for src, tree in zip(sources, fits, strict=True):
            _check_experiment(tree, e, datasets[e], src)
        per[name] = _compare_one(fits, labels, datasets[e], [m[e] for m in models],
                                 experiment=e, loo=False)
    elpd, steps = loo_table(fits, labels)
    per = {n: FitComparison(**{**c.__dict__, "elpd": elpd, "elpd_steps": steps})
           for n, c in per.items()}
    return FitComparison(labels=labels, bands={}, whiteness={}, innovations={}, elpd=elpd,
                         elpd_steps=steps, command_rate=np.zeros(0), dt_s=math.nan,
                         experiments=per)


def _compare_one(fits: list, labels: list, dataset: Dataset, models: list, *,
                 experiment: int | None = None, loo: bool = True) -> FitComparison:
    """The comparison on one data set: one experiment's part of each fit, or the fit."""
    bands, white, innov = {}, {}, {}
    for label, tree, model in zip(labels, fits, models, strict=True):
        if experiment is None:
            check_dataset(tree, dataset)
        bands[label], white[label], innov[label] = _map_residual(tree, model, dataset,
                                                                 experiment)
    elpd, steps = loo_table(fits, labels) if loo else ({}, [])
    return FitComparison(labels=labels, bands=bands, whiteness=white, innovations=innov,
                         elpd=elpd, elpd_steps=steps,
                         command_rate=np.gradient(dataset.input[0], dataset.time_s),
                         dt_s=dataset.dt_s)


def _check_experiment(tree, e: int, dataset: Dataset, src: str) -> None:
    """That ``dataset`` is experiment ``e`` of a fit of several (trials, times, positions)."""
    stored = experiment_datasets(tree)[e]
    name = fit_info(tree)["experiments"][e]["name"]
    where = (f"{dataset.source or '(no source)'} does not match experiment {name} of {src} "
             f"(made from {stored.source})")
    if stored.position_m.shape != dataset.position_m.shape:
        raise DataError(f"{where}: position_m has shape {dataset.position_m.shape} (trials, "
                        f"samples), the fit's has {stored.position_m.shape}; give the data "
                        "files in the fit's experiment order")
    diff = float(np.max(np.abs(stored.position_m - dataset.position_m)))
    t_diff = float(np.max(np.abs(stored.time_s - dataset.time_s)))
    if not diff <= 1e-12 or not t_diff <= 1e-12 * max(1.0, float(np.max(np.abs(stored.time_s)))):
        raise DataError(f"{where}: positions differ by up to {diff:.3g} m and times by up to "
                        f"{t_diff:.3g} s; give the data files in the fit's experiment order")


def _map_residual(tree, model: Model, dataset: Dataset, experiment: int | None = None):
    """Band errors, whiteness and whitened residual of a fit's MAP model (on one
    experiment of a fit of several)."""
    info = fit_info(tree)
    substeps = int(info.get("substeps", 1))
    lik = Likelihood(model, dataset, substeps=substeps)
    vals = physical_values(model, info["map"]["values"])
    x = simulate_dataset(model, vals, dataset, substeps=substeps)[0]
    nz = (info["noise"] if experiment is None
          else info["experiments"][experiment]["noise_estimate"])
    noise = NoiseEstimate(nz["sigma_noise_m"], nz["rho_noise"], nz["sigma_white_m"], None, None)
    e, white, _ = judged_whiteness(lik, x, noise)  # AR(1) + white unless the repeats reject it
    return band_errors(dataset, x), white, e
