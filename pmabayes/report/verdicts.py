"""Whether a fitted model describes its data: the adequacy verdict of a fit, and of each
of its experiments, with the command that diagnoses it.
"""

from __future__ import annotations

import shlex
from collections.abc import Mapping, Sequence
from types import SimpleNamespace

import xarray as xr

from pmabayes.criticism.adequacy import Adequacy, check_adequacy
from pmabayes.data import Dataset
from pmabayes.inference.fitfile import (
    FitFileError,
    as_fitted,
    check_dataset,
    experiment_models,
    model_from_fit,
)
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.effects import EffectError
from pmabayes.model.model import Model, ModelError
from pmabayes.report.fit_data import (
    check_ci_prob,
    check_experiment_data,
    check_tree,
    dataset_from_fit,
    predictive,
    source_name,
)

__all__ = ["fit_adequacy", "experiment_adequacy"]


def fit_adequacy(tree: xr.DataTree, *, dataset: Dataset | None = None,
                 ci_prob: float = 0.9) -> Adequacy:
    """Whether a fitted model describes its data: the verdict every report opens with.

    The sampler's convergence says that the posterior of the model is well sampled,
    not that the model fits. This judges the posterior median model (from the
    fit's posterior predictive draws) against the trials with the rule of
    :func:`pmabayes.criticism.adequacy.is_adequate`: its residual, whitened by the fit's
    noise estimate, must be as small and as white as pure noise. The error against
    the noise floor and the fraction of the data inside the predictive band are
    quoted beside it, and for a model that fails, the command that finds what is
    missing (``pmabayes diagnose DATA``).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    dataset : Dataset, optional
        The data the fit was made from (checked against it); its source names the
        data in the next command. Rebuilt from the fit's observed data if not given.
    ci_prob : float, optional
        Probability of the predictive band (0.9).

    Returns
    -------
    Adequacy
        Print its :meth:`~pmabayes.criticism.adequacy.Adequacy.lines`.

    Raises
    ------
    ValueError
        If ``dataset`` does not match the fit, or ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` is not a pmabayes fit with a posterior predictive group.

    Examples
    --------
    >>> from pmabayes import load_fit
    >>> tree = load_fit("results/lab/fit.nc")  # doctest: +SKIP
    >>> print("\\n".join(fit_adequacy(tree).lines()))  # doctest: +SKIP
    """
    ci_prob = check_ci_prob(ci_prob)
    info = check_tree(tree, ["observed_data", "posterior_predictive"])
    if len(info.get("experiments") or [None]) > 1:
        raise FitFileError(
            f"a fit of {len(info['experiments'])} experiments has a verdict per experiment; "
            "use pmabayes.report.verdicts.experiment_adequacy")
    if dataset is not None:
        check_dataset(tree, dataset)
    return judge_fit(tree, info, dataset, predictive(tree, ci_prob), ci_prob)


def experiment_adequacy(tree: xr.DataTree, *, datasets: Sequence[Dataset] | None = None,
                        ci_prob: float = 0.9) -> list[tuple[str, Adequacy]]:
    """The adequacy verdict of each experiment of a fit (:func:`fit_adequacy` for one).

    Each experiment's posterior median model is judged against its own trials with
    its own noise (see :func:`fit_adequacy`).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit of one or more experiments.
    datasets : sequence of Dataset, optional
        The experiments' data, in the fit's order (checked against it); rebuilt
        from the fit when not given.
    ci_prob : float, optional
        Probability of the predictive band (0.9).

    Returns
    -------
    list of (str, Adequacy)
        The experiment's name and its verdict.

    Raises
    ------
    ValueError
        If the data do not match the fit, or ``ci_prob`` is not in (0, 1).
    """
    ci_prob = check_ci_prob(ci_prob)
    info = check_tree(tree, ["observed_data", "posterior_predictive"])
    exps = info.get("experiments") or [{"name": source_name(info, None)}]
    datasets = as_fitted(tree, datasets) if datasets else datasets
    if len(exps) == 1:
        ds = datasets[0] if datasets else None
        return [(exps[0]["name"], fit_adequacy(tree, dataset=ds, ci_prob=ci_prob))]
    datasets = check_experiment_data(tree, datasets)
    try:
        models = experiment_models(tree)
    except (ModelError, EffectError, TypeError):  # an unregistered user effect, an odd rig
        models = [Model.for_dataset(ds) for ds in datasets]
    out = []
    for exp, ds, model in zip(exps, datasets, models, strict=True):
        pred = predictive(tree, ci_prob, exp["name"])
        nz = exp.get("noise_estimate") or {}
        noise = (SimpleNamespace(sigma=nz["sigma_noise_m"], rho=nz["rho_noise"],
                                 white=nz["sigma_white_m"])
                 if all(nz.get(k) is not None for k in
                        ("sigma_noise_m", "rho_noise", "sigma_white_m")) else None)
        command = _diagnose_command(info, datasets)  # diagnose takes them together
        out.append((exp["name"], check_adequacy(Likelihood(model, ds), pred["median"], noise,
                                                coverage=pred["coverage"], ci_prob=ci_prob,
                                                next_command=command)))
    return out


def judge_fit(tree: xr.DataTree, info: dict, dataset: Dataset | None, pred: Mapping,
              ci_prob: float) -> Adequacy:
    data = as_fitted(tree, [dataset])[0] if dataset is not None else dataset_from_fit(tree, info)
    try:
        model = model_from_fit(tree)
    except (ModelError, EffectError, TypeError):  # an unregistered user effect, an odd rig
        model = Model.for_dataset(data)  # whitening needs the data and the noise only
    lik = Likelihood(model, data)
    nz = info.get("noise") or {}
    keys = ("sigma_noise_m", "rho_noise", "sigma_white_m")
    noise = (SimpleNamespace(sigma=nz[keys[0]], rho=nz[keys[1]], white=nz[keys[2]])
             if all(nz.get(k) is not None for k in keys) else None)
    return check_adequacy(lik, pred["median"], noise, coverage=pred["coverage"],
                          ci_prob=ci_prob, next_command=_diagnose_command(info, data))


def _diagnose_command(info: dict, dataset: Dataset | Sequence[Dataset]) -> str:
    """``pmabayes diagnose FILE [FILE ...] [--effects ...]`` for the fit's data."""
    datasets = [dataset] if isinstance(dataset, Dataset) else list(dataset)
    sources = [ds.source or (info.get("data") or {}).get("source") or "DATA.csv"
               for ds in datasets]
    effects = (info.get("model") or {}).get("effects") or []
    command = "pmabayes diagnose " + " ".join(shlex.quote(str(s)) for s in sources)
    chosen = datasets[0].metadata.get("selected_trials") if len(datasets) == 1 else None
    if chosen:  # the trials held out of the fit stay out of its diagnosis
        command += f" --trials {','.join(map(str, chosen))}"
    return command + (f" --effects {','.join(effects)}" if effects else "")
