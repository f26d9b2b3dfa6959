"""Report stage: the summary table, diagnostic figures and an offline HTML page of a fit.

The input is a fit as laid out in :mod:`pmabayes.inference.posterior` (an ArviZ 1.x
:class:`xarray.DataTree`, usually read back with :func:`pmabayes.inference.fitfile.load_fit`).
Nothing here simulates or samples: every number and curve comes from the fit file.
The figures are drawn by :mod:`pmabayes.report.figures` from what is computed here.

:func:`fit_adequacy`
    Whether the fitted model describes the data (error against the noise floor,
    whiteness of the residual, predictive coverage) and the next command when it
    does not: the verdict every report shows first, for the command line too.

:func:`summary_table`
    One row per posterior variable: posterior mean, sd and HDI, diagnostics, the
    paper's value and the MAP.
:func:`write_summary`
    The table as ``summary.csv`` and ``summary.md``.
:func:`write_report`
    Both tables, five figures (``trace.png``, ``rank.png``, ``pair.png``,
    ``ppc.png``, ``residual.png``) and ``index.html``, a single self-contained page
    (figures embedded as base64 PNG, inline CSS, no script, no external resource).
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import arviz as az
import numpy as np
import xarray as xr

from pmabayes.criticism.adequacy import Adequacy, check_adequacy
from pmabayes.data import DataError, Dataset
from pmabayes.inference.fitfile import (
    FitFileError,
    check_dataset,
    experiment_datasets,
    experiment_models,
    fit_info,
    model_from_fit,
)
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.trials import check_trials
from pmabayes.model.effects import EffectError
from pmabayes.model.model import Model, ModelError

__all__ = ["SUMMARY_COLUMNS", "summary_table", "write_summary", "write_report", "write_diagnosis",
           "write_comparison", "pair_figure", "predictive_band", "fit_adequacy",
           "experiment_adequacy", "write_validation"]

#: Keys of a summary row, in CSV column order.
SUMMARY_COLUMNS: tuple[str, ...] = (
    "name",
    "unit",
    "mean",
    "sd",
    "hdi_low",
    "hdi_high",
    "ci_prob",
    "r_hat",
    "r_hat_ensembles",
    "ess",
    "ess_bulk",
    "tau",
    "paper",
    "map",
    "global_search",
)

# Markdown/HTML headers of the displayed columns (ci_prob is shown in the HDI header).
_DISPLAY = (
    ("name", "parameter"),
    ("unit", "unit (SI)"),
    ("mean", "mean"),
    ("sd", "sd"),
    ("hdi_low", "HDI low"),
    ("hdi_high", "HDI high"),
    ("r_hat", "R-hat"),
    ("r_hat_ensembles", "R-hat (ensembles)"),
    ("ess", "ESS (tau)"),
    ("ess_bulk", "ESS bulk"),
    ("paper", "paper"),
    ("map", "MAP"),
)
_QUANTILE_BLOCK = 4_000_000  # values per block when taking quantiles of the predictive


# ----------------------------------------------------------------------------- helpers


def _flat(tree: xr.DataTree) -> xr.DataTree:
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


def _map_value(values: Mapping | None, name: str) -> float | None:
    """The MAP of a posterior variable, ``NAME[EXPERIMENT]`` for per-experiment noise."""
    base, _, exp = name.partition("[")
    if exp and values and isinstance(values.get(base), Mapping):
        return _opt_float(values[base], exp.rstrip("]"))
    return _opt_float(values, name)


def _opt_float(mapping: Mapping | None, name: str) -> float | None:
    """``float(mapping[name])``, or None when the mapping or the entry is missing."""
    if not mapping or mapping.get(name) is None:
        return None
    return float(mapping[name])


def _fmt(value: Any) -> str:
    """A number as ``%.4g`` (an em dash for a missing value); text unchanged."""
    if value is None:
        return "\u2014"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return str(value)


def _um(value_m: float | None) -> str:
    """A length in m shown in µm with 3 significant digits (em dash if missing)."""
    if value_m is None or not math.isfinite(value_m):
        return "\u2014"
    return f"{value_m * 1e6:.3g} µm"


def _check_ci_prob(ci_prob: float) -> float:
    ci = float(ci_prob)
    if not 0.0 < ci < 1.0:
        raise ValueError(f"ci_prob must be in (0, 1), got {ci_prob!r}")
    return ci


def _check_tree(tree: xr.DataTree, groups: Sequence[str]) -> dict:
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


def _units(info: dict) -> dict[str, str]:
    """Parameter name -> SI unit, from the fit's parameter table (noise included)."""
    params = (info.get("model") or {}).get("parameters") or []
    return {p["name"]: str(p.get("unit") or "") for p in params if "name" in p}


def _source_name(info: dict, dataset: Dataset | None) -> str:
    if dataset is not None and dataset.source:
        return str(dataset.source)
    return str((info.get("data") or {}).get("source") or "unnamed data")


# ----------------------------------------------------------------------------- table


def summary_table(tree: xr.DataTree, *, ci_prob: float = 0.9) -> list[dict[str, Any]]:
    """One row of estimates and diagnostics per posterior variable.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    ci_prob : float, optional
        Probability mass of the highest density interval, default 0.9. It is passed
        to ArviZ explicitly with ``ci_kind="hdi"`` (ArviZ's own default is an 89%
        equal-tailed interval).

    Returns
    -------
    list of dict
        In the posterior's variable order, each with the keys of
        :data:`SUMMARY_COLUMNS`: ``name``; ``unit`` (SI, from the fit's parameter
        table; ``""`` if unknown); ``mean``, ``sd``, ``hdi_low``, ``hdi_high`` (over
        all walkers and draws) and ``ci_prob``; ``r_hat`` (ArviZ's rank-normalised
        split R-hat over walkers); ``r_hat_ensembles`` (R-hat across independent
        ensembles, from the fit's convergence record); ``ess`` (the
        autocorrelation-time ESS on which the fit's convergence decision rests);
        ``ess_bulk`` (ArviZ's bulk ESS over walkers); ``tau`` (integrated
        autocorrelation time in steps); ``paper`` (the paper's point estimate);
        ``map`` (the MAP); ``global_search`` (the paper-style least-squares
        optimum). Values are Python floats, or None where the fit has no value.

    Raises
    ------
    ValueError
        If ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` is not a pmabayes fit.
    """
    ci_prob = _check_ci_prob(ci_prob)
    tree = _flat(tree)
    info = _check_tree(tree, ["posterior"])
    stats = az.summary(
        tree,
        group="posterior",
        sample_dims=["chain", "draw"],
        ci_prob=ci_prob,
        ci_kind="hdi",
        fmt="xarray",
        round_to="none",
    )
    labels = [str(s) for s in stats["summary"].values]
    try:
        low = next(s for s in labels if s.startswith("hdi") and s.endswith("_lb"))
        high = next(s for s in labels if s.startswith("hdi") and s.endswith("_ub"))
    except StopIteration:
        raise RuntimeError(
            f"arviz.summary returned no HDI bounds (statistics {labels}); this ArviZ "
            "version names them differently"
        ) from None

    units = _units(info)
    conv = info.get("convergence") or {}
    point = info.get("map") or {}
    rows = []
    for name in tree["posterior"].data_vars:
        s = stats[name]

        def get(label: str, s: xr.DataArray = s) -> float:
            return float(s.sel(summary=label).values)

        rows.append(
            {
                "name": str(name),
                "unit": str(units.get(str(name).split("[")[0], "")),
                "mean": get("mean"),
                "sd": get("sd"),
                "hdi_low": get(low),
                "hdi_high": get(high),
                "ci_prob": ci_prob,
                "r_hat": get("r_hat"),
                "r_hat_ensembles": _opt_float(conv.get("rhat_ensembles"), name),
                "ess": _opt_float(conv.get("ess"), name),
                "ess_bulk": get("ess_bulk"),
                "tau": _opt_float(conv.get("tau"), name),
                "paper": _opt_float(info.get("paper_values"), name),
                "map": _map_value(point.get("values"), str(name)),
                "global_search": _opt_float(
                    (point.get("global_search") or {}).get("values"), name
                ),
            }
        )
    return rows


def _hdi_label(rows: Sequence[Mapping]) -> str:
    probs = {r.get("ci_prob") for r in rows if r.get("ci_prob") is not None}
    return f"{100 * probs.pop():.4g}% HDI" if len(probs) == 1 else "HDI"


def _display_headers(rows: Sequence[Mapping]) -> list[str]:
    hdi = _hdi_label(rows)
    return [
        f"{hdi} {head.split()[1]}" if key.startswith("hdi_") else head for key, head in _DISPLAY
    ]


def write_summary(rows: Sequence[Mapping[str, Any]], out_dir: str | Path, *,
                  adequacy: Adequacy | None = None) -> tuple[Path, Path]:
    """Write summary rows as ``summary.csv`` and ``summary.md``.

    Parameters
    ----------
    rows : sequence of dict
        Rows as returned by :func:`summary_table` (keys of :data:`SUMMARY_COLUMNS`;
        a missing key is written as empty).
    out_dir : str or Path
        Destination folder, created if needed; existing files are overwritten.
    adequacy : Adequacy, optional
        The model's adequacy verdict (:func:`fit_adequacy`), written as a quote
        above the Markdown table.

    Returns
    -------
    tuple of Path
        The CSV file (all columns, full precision, empty cells for missing values)
        and the Markdown file (a table with the SI unit in its own column, numbers
        as ``%.4g``, an em dash for missing values).

    Raises
    ------
    ValueError
        If a row has no ``name``.
    """
    for i, row in enumerate(rows):
        if not row.get("name"):
            raise ValueError(f"summary row {i} has no 'name'; pass rows from summary_table")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = out_dir / "summary.csv", out_dir / "summary.md"

    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(SUMMARY_COLUMNS)
        for row in rows:
            cells = []
            for key in SUMMARY_COLUMNS:
                v = row.get(key)
                cells.append("" if v is None else repr(float(v)) if isinstance(
                    v, (float, np.floating)) else str(v))
            writer.writerow(cells)

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    lines = [] if adequacy is None else [*_adequacy_markdown(adequacy), ""]
    lines += [
        "| " + " | ".join(_display_headers(rows)) + " |",
        "|" + "|".join("---" if k in ("name", "unit") else "---:" for k, _ in _DISPLAY) + "|",
    ]
    for row in rows:
        vals = [f"`{row['name']}`", row.get("unit") or "\u2014"]
        vals += [_fmt(row.get(k)) for k, _ in _DISPLAY[2:]]
        lines.append("| " + " | ".join(cell(v) for v in vals) + " |")
    md_path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return csv_path, md_path


# ----------------------------------------------------------------------------- figures


def pair_figure(tree: xr.DataTree, path: str | Path, *, names: Sequence[str] | None = None,
                ci_prob: float = 0.9) -> int:
    """Corner plot of the posterior draws with the MAP and the paper's values marked.

    The figure of the report's pair plot, for any subset of the posterior's
    variables. Values off the plotted range are marked by arrow-heads on the edge.

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    path : str or Path
        Where to save the figure (format from the suffix).
    names : sequence of str, optional
        Posterior variables to show, in order; all by default.
    ci_prob : float, optional
        Interval probability of the summary the marks come from (0.9).

    Returns
    -------
    int
        The number of draws shown (at most 2000, evenly thinned).

    Raises
    ------
    ValueError
        If a name is not a posterior variable, or ``ci_prob`` is not in (0, 1).
    FitFileError
        If ``tree`` is not a pmabayes fit.
    """
    rows = summary_table(tree, ci_prob=ci_prob)
    known = list(tree["posterior"].data_vars)
    if names is not None:
        bad = [n for n in names if n not in known]
        if bad:
            raise ValueError(f"not posterior variables: {bad}; the fit has {known}")
    from pmabayes.report.figures import plot_pair

    return plot_pair(tree, Path(path), rows, names)


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
    ci_prob = _check_ci_prob(ci_prob)
    _check_tree(tree, ["observed_data", "posterior_predictive"])
    return _predictive(tree, ci_prob)


def _predictive(tree: xr.DataTree, ci_prob: float) -> dict[str, np.ndarray]:
    """Time, data, median model and the pooled central predictive band (all in m)."""
    obs = tree["observed_data"]["position_m"].transpose("trial", "time")
    pp = tree["posterior_predictive"]
    q = (1.0 - ci_prob) / 2.0
    band = _quantiles_over_samples(pp["position_m"], [q, 1.0 - q])
    median = _quantiles_over_samples(pp["model_position_m"], [0.5])[0]
    data = np.asarray(obs.values, dtype=float)
    return {
        "time": np.asarray(obs["time"].values, dtype=float),
        "trials": np.asarray(obs["trial"].values),
        "data": data,
        "median": median,
        "low": band[0],
        "high": band[1],
        "coverage": float(np.mean((data >= band[0]) & (data <= band[1]))),
    }


# ----------------------------------------------------------------------------- adequacy


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
    >>> from pmabayes.inference.posterior import load_fit
    >>> tree = load_fit("results/lab/fit.nc")  # doctest: +SKIP
    >>> print("\\n".join(fit_adequacy(tree).lines()))  # doctest: +SKIP
    """
    ci_prob = _check_ci_prob(ci_prob)
    info = _check_tree(tree, ["observed_data", "posterior_predictive"])
    if len(info.get("experiments") or [None]) > 1:
        raise FitFileError(
            f"a fit of {len(info['experiments'])} experiments has a verdict per experiment; "
            "use pmabayes.report.pages.experiment_adequacy")
    if dataset is not None:
        check_dataset(tree, dataset)
    return _adequacy(tree, info, dataset, _predictive(tree, ci_prob), ci_prob)


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
    ci_prob = _check_ci_prob(ci_prob)
    info = _check_tree(tree, ["observed_data", "posterior_predictive"])
    exps = info.get("experiments") or [{"name": _source_name(info, None)}]
    if len(exps) == 1:
        ds = datasets[0] if datasets else None
        return [(exps[0]["name"], fit_adequacy(tree, dataset=ds, ci_prob=ci_prob))]
    datasets = _check_experiment_data(tree, datasets)
    try:
        models = experiment_models(tree)
    except (ModelError, EffectError, TypeError):  # an unregistered user effect, an odd rig
        models = [Model.for_dataset(ds) for ds in datasets]
    out = []
    for exp, ds, model in zip(exps, datasets, models, strict=True):
        pred = _predictive_of(tree, exp["name"], ci_prob)
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


def _check_experiment_data(tree: xr.DataTree, datasets) -> list[Dataset]:
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
        if ds.position_m.shape != ref.position_m.shape or not np.allclose(
                ds.position_m, ref.position_m, rtol=0, atol=1e-12):
            raise DataError(f"dataset {ds.source or '(no source)'} does not match the observed "
                            f"data of the fit's experiment from {ref.source}: shape "
                            f"{ds.position_m.shape} against {ref.position_m.shape} or positions "
                            "differ by more than 1e-12 m; give the fit's data files in its order")
    return datasets


def _predictive_of(tree: xr.DataTree, name: str, ci_prob: float) -> dict[str, np.ndarray]:
    """:func:`_predictive` for one experiment of a fit of several."""
    trial, time_ = f"trial__{name}", f"time__{name}"
    obs = tree["observed_data"][f"position_m__{name}"].transpose(trial, time_)
    pp = tree["posterior_predictive"]
    q = (1.0 - ci_prob) / 2.0
    band = _quantiles_over_samples(pp[f"position_m__{name}"], [q, 1.0 - q], time_dim=time_)
    median = _quantiles_over_samples(pp[f"model_position_m__{name}"], [0.5], time_dim=time_)[0]
    data = np.asarray(obs.values, dtype=float)
    return {
        "time": np.asarray(obs[time_].values, dtype=float),
        "trials": np.asarray(obs[trial].values),
        "data": data,
        "median": median,
        "low": band[0],
        "high": band[1],
        "coverage": float(np.mean((data >= band[0]) & (data <= band[1]))),
    }


def _adequacy(tree: xr.DataTree, info: dict, dataset: Dataset | None, pred: Mapping,
              ci_prob: float) -> Adequacy:
    data = dataset if dataset is not None else _dataset_from_fit(tree, info)
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


def _dataset_from_fit(tree: xr.DataTree, info: dict) -> Dataset:
    """The trials of a fit as a Dataset (the input only where the fit stores it)."""
    obs = tree["observed_data"]["position_m"].transpose("trial", "time")
    d = info.get("data") or {}
    name = d.get("input_name") or "pressure_pa"
    const = tree["constant_data"] if "constant_data" in tree.children else None
    # without the stored input, zeros: the whitened residual does not depend on it
    u = (np.asarray(const[name].values, dtype=float)
         if const is not None and name in const.data_vars else np.zeros(obs.sizes["time"]))
    return Dataset(time_s=np.asarray(obs["time"].values, dtype=float),
                   input=np.tile(u, (obs.sizes["trial"], 1)),
                   position_m=np.asarray(obs.values, dtype=float),
                   trial_ids=np.asarray(obs["trial"].values), input_name=name,
                   metadata={"synthetic": bool(d.get("synthetic", False))},
                   source=d.get("source"))


def _diagnose_command(info: dict, dataset: Dataset | Sequence[Dataset]) -> str:
    """``pmabayes diagnose FILE [FILE ...] [--effects ...]`` for the fit's data."""
    datasets = [dataset] if isinstance(dataset, Dataset) else list(dataset)
    sources = [ds.source or (info.get("data") or {}).get("source") or "DATA.csv"
               for ds in datasets]
    effects = (info.get("model") or {}).get("effects") or []
    command = "pmabayes diagnose " + " ".join(shlex.quote(str(s)) for s in sources)
    return command + (f" --effects {','.join(effects)}" if effects else "")


def _adequacy_markdown(adequacy: Adequacy) -> list[str]:
    out = [f"> **{adequacy.headline}**: {adequacy.evidence()}."]
    for line in adequacy.advice():
        out += [">", f"> {line}"]
    return out + ([">", f"> Next: `{adequacy.next_step}`"] if adequacy.next_step else [])


# ----------------------------------------------------------------------------- HTML

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;
 max-width:1200px;margin:1.5em auto;padding:0 1em;color:#1b1b1b;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em}
.meta{color:#555;font-size:.92em}
.banner{padding:.8em 1.1em;border-radius:6px;margin:1em 0;font-size:1.05em}
.banner.bad{background:#fde2e1;border:3px solid #c62828;color:#7f0000}
.banner.bad strong{font-size:1.3em}
.banner.ok{background:#e6f4ea;border:1px solid #2e7d32;color:#1b5e20}
.verdict{padding:.9em 1.2em;border-radius:6px;margin:1em 0;font-size:1.1em}
.verdict p{margin:.5em 0 0}
.verdict.bad{background:#fde2e1;border:4px solid #c62828;color:#7f0000}
.verdict.bad strong{font-size:1.4em}
.verdict.ok{background:#e6f4ea;border:2px solid #2e7d32;color:#1b5e20}
.verdict.unknown{background:#fff8e1;border:3px solid #f9a825}
.verdict .next code{font-size:1.05em;background:#fff;border:1px solid #c62828;padding:.1em .4em}
.note{background:#fff8e1;border:1px solid #f9a825;padding:.6em 1em;border-radius:6px}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em} th{background:#f2f2f2}
td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1.5em 0} figure img{max-width:100%;border:1px solid #ddd}
figcaption{color:#444;font-size:.92em;margin-top:.3em}
code{background:#f4f4f4;padding:0 .2em}
"""


def _table(header: Sequence[str], body: Sequence[Sequence[Any]], num_from: int = 1) -> str:
    """An HTML table; cells from column ``num_from`` on are right-aligned numbers."""
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for row in body:
        cells = []
        for i, v in enumerate(row):
            cls = ' class="num"' if i >= num_from else ""
            cells.append(f"<td{cls}>{html.escape(_fmt(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _img(path: Path, alt: str, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure id="{html.escape(path.stem)}"><img src="data:image/png;base64,{data}" '
        f'alt="{html.escape(alt)}"><figcaption>{html.escape(caption)}</figcaption></figure>'
    )


def write_report(
    tree: xr.DataTree,
    out_dir: str | Path,
    *,
    dataset: Dataset | Sequence[Dataset] | None = None,
    ci_prob: float = 0.9,
) -> Path:
    """Write the tables, the figures and a self-contained HTML report of a fit.

    A fit of several experiments gets a section per experiment: its verdict, its
    errors (RMS against the posterior median, the MAP's cost, the noise floor or
    "no repeats", the predictive coverage) and its prediction-against-data and
    residual figures (``ppc_NAME.png``, ``residual_NAME.png``).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    out_dir : str or Path
        Destination folder, created if needed. Written: ``summary.csv``,
        ``summary.md``, ``trace.png``, ``rank.png``, ``pair.png``, ``ppc.png``,
        ``residual.png`` and ``index.html`` (overwritten if present).
    dataset : Dataset or sequence of Dataset, optional
        The data the fit was made from, one per experiment in the fit's order. When
        given, its trials must equal the fit's observed positions (same shape,
        values within 1e-12 m), and its source names the report.
    ci_prob : float, optional
        Probability of the HDIs in the table and of the central posterior predictive
        band, default 0.9.

    Returns
    -------
    Path
        The path of ``index.html``. The page embeds every figure as a base64 PNG and
        its CSS inline; it loads nothing from the network and has no script.

    Raises
    ------
    ValueError
        If ``dataset`` does not match the fit's observed data, or ``ci_prob`` is not
        in (0, 1).
    TypeError
        If ``dataset`` is not a :class:`~pmabayes.data.Dataset`.
    FitFileError
        If ``tree`` is not a pmabayes fit or lacks a group the report needs.

    Examples
    --------
    >>> from pmabayes.inference.posterior import load_fit
    >>> tree = load_fit("results/lab/fit.nc")  # doctest: +SKIP
    >>> write_report(tree, "results/lab/report")  # doctest: +SKIP
    PosixPath('results/lab/report/index.html')
    """
    ci_prob = _check_ci_prob(ci_prob)
    info = _check_tree(tree, ["posterior", "observed_data", "posterior_predictive"])
    if isinstance(dataset, Sequence) and not isinstance(dataset, str):
        datasets = list(dataset)
        if len(info.get("experiments") or [None]) > 1:
            return _write_experiments_report(tree, info, Path(out_dir), datasets, ci_prob)
        if len(datasets) != 1:
            raise ValueError(f"{len(datasets)} data sets given for a fit of one experiment")
        dataset = datasets[0]
    elif len(info.get("experiments") or [None]) > 1:
        return _write_experiments_report(
            tree, info, Path(out_dir), None if dataset is None else [dataset], ci_prob)
    if dataset is not None:
        check_dataset(tree, dataset)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summary_table(tree, ci_prob=ci_prob)
    pred = _predictive(tree, ci_prob)
    adequacy = _adequacy(tree, info, dataset, pred, ci_prob)
    write_summary(rows, out_dir, adequacy=adequacy)
    residual_m = pred["data"].mean(axis=0) - pred["median"]
    quality = {"floor_m": _noise_floor(info, dataset), "coverage": pred["coverage"],
               "rms_median_m": float(np.sqrt(np.mean(residual_m**2)))}
    captions = _report_figures(tree, rows, pred, residual_m, quality, out_dir, ci_prob)
    body = [
        _meta_block(info, _source_name(info, dataset)),
        _adequacy_box(adequacy),
        _trials_line(dataset if dataset is not None else _dataset_from_fit(tree, info)),
        _banner(info.get("convergence") or {}),
        _synthetic_note_of(info),
        *_parameter_section(rows, info, ci_prob),
        *_quality_section(info, quality, adequacy, ci_prob),
        *_convergence_section(info, tree),
        *_timings_section(info),
        "<h2>Figures</h2>",
        *[_img(out_dir / f"{name}.png", f"{name} plot", text) for name, text in captions.items()],
    ]
    index = out_dir / "index.html"
    title = f"pmabayes fit report: {Path(_source_name(info, dataset)).name}"
    index.write_text(_page(title, body), encoding="utf-8")
    return index


def _trials_line(dataset: Dataset) -> str:
    """The verdict of :func:`pmabayes.inference.trials.check_trials` on the fitted trials, one line."""
    check = check_trials(dataset)
    text = html.escape(check.summary())
    return f"<p>{text}</p>" if check.exchangeable else f'<p class="note">{text}</p>'


def _write_experiments_report(tree: xr.DataTree, info: dict, out_dir: Path,
                              datasets: list[Dataset] | None, ci_prob: float) -> Path:
    """:func:`write_report` for a fit of several experiments: shared parameters, then a
    section per experiment."""
    from pmabayes.report import figures as plots
    datasets = _check_experiment_data(tree, datasets)
    out_dir.mkdir(parents=True, exist_ok=True)
    flat = _flat(tree)
    rows = summary_table(tree, ci_prob=ci_prob)
    verdicts = experiment_adequacy(tree, datasets=datasets, ci_prob=ci_prob)
    worst = next((a for _, a in verdicts if a.adequate is False), verdicts[0][1])
    write_summary(rows, out_dir, adequacy=worst)
    plots.plot_trace(flat, out_dir / "trace.png", units={r["name"]: r["unit"] for r in rows})
    plots.plot_rank(flat, out_dir / "rank.png")
    n_pair = plots.plot_pair(flat, out_dir / "pair.png", rows)
    pct = f"{100 * ci_prob:.4g}%"
    sections = []
    for exp, (name, adequacy) in zip(info["experiments"], verdicts, strict=True):
        pred = _predictive_of(tree, name, ci_prob)
        residual = pred["data"].mean(axis=0) - pred["median"]
        rms = float(np.sqrt(np.mean(residual**2)))
        floor = exp.get("noise_floor_m")
        plots.plot_predictive(pred, out_dir / f"ppc_{name}.png", ci_prob=ci_prob)
        plots.plot_residual(pred["time"], residual, rms, floor, out_dir / f"residual_{name}.png")
        est = exp.get("noise_estimate") or {}
        table = _table(["quantity", "value"], [
            ["data", str(exp.get("source") or name)],
            ["rig", str((exp.get("rig") or {}).get("name", "?"))],
            ["trials × samples", f"{exp['n_trials']} × {exp['n_samples']}"],
            ["the paper's cost (RMS of trial mean − model) at the MAP",
             _um(exp.get("rms_cost_m"))],
            ["RMS of trial mean − posterior median model", _um(rms)],
            ["trial-mean noise floor", _um(floor) if floor is not None else "no repeats"],
            ["noise (own or tied), learnt from", f"{exp['noise']}, {exp['noise_source']}"],
            ["noise mode: σ, ρ, σ_w", ", ".join(_fmt(est.get(k)) for k in
                                                ("sigma_noise_m", "rho_noise", "sigma_white_m"))],
            [f"data inside the {pct} posterior predictive band", f"{100 * pred['coverage']:.1f}%"],
        ])
        sections += [
            f'<h2 id="experiment-{html.escape(name)}">Experiment {html.escape(name)}</h2>',
            _adequacy_box(adequacy), table,
            _img(out_dir / f"ppc_{name}.png", f"{name} predictive check",
                 f"{name}: data (black), {pct} predictive band (blue), median model (red)."),
            _img(out_dir / f"residual_{name}.png", f"{name} residual",
                 f"{name}: trial-mean residual against the posterior median model (RMS "
                 f"{rms * 1e6:.3g} µm)" + ("; no repeats, so no noise floor." if floor is None
                                           else " and the noise floor (green).")),
        ]
    source = " + ".join(str(e.get("source") or e["name"]) for e in info["experiments"])
    body = [
        _meta_block(info, source),
        *[f"<p><strong>{html.escape(n)}</strong></p>{_adequacy_box(a)}" for n, a in verdicts],
        _banner(info.get("convergence") or {}),
        _synthetic_note_of(info),
        *_parameter_section(rows, info, ci_prob),
        *sections,
        *_convergence_section(info, flat),
        *_timings_section(info),
        "<h2>Figures of the shared posterior</h2>",
        _img(out_dir / "trace.png", "trace plot", "Trace of every walker and the pooled "
             "marginal density."),
        _img(out_dir / "rank.png", "rank plot", "Fractional-rank Δ-ECDF per walker."),
        _img(out_dir / "pair.png", "pair plot", f"Corner plot of {n_pair} evenly spaced draws."),
    ]
    index = out_dir / "index.html"
    index.write_text(_page(f"pmabayes fit report: {len(datasets)} experiments", body),
                     encoding="utf-8")
    return index


def _noise_floor(info: dict, dataset: Dataset | None) -> float | None:
    """The trial-mean noise floor: from the data when given, else from the fit."""
    if dataset is not None and dataset.n_trials > 1:
        return dataset.noise_floor_m
    floor = (info.get("data") or {}).get("noise_floor_m")
    return float(floor) if floor is not None else None


def _report_figures(tree: xr.DataTree, rows: list, pred: Mapping, residual_m: np.ndarray,
                    quality: Mapping, out_dir: Path, ci_prob: float) -> dict[str, str]:
    """Draw the five figures of a fit report; returns each one's caption."""
    from pmabayes.report import figures as plots
    trace_note = plots.plot_trace(tree, out_dir / "trace.png",
                                  units={r["name"]: r["unit"] for r in rows})
    rank_thin, rank_note = plots.plot_rank(tree, out_dir / "rank.png")
    n_pair = plots.plot_pair(tree, out_dir / "pair.png", rows)
    plots.plot_predictive(pred, out_dir / "ppc.png", ci_prob=ci_prob)
    plots.plot_residual(pred["time"], residual_m, quality["rms_median_m"], quality["floor_m"],
                        out_dir / "residual.png")
    post = tree["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    pct = f"{100 * ci_prob:.4g}%"
    return {
        "trace": (
            f"Trace of every walker ({n_chain} chains × {n_draw} draws after burn-in and "
            "thinning) and the pooled marginal density."
            + (f" {trace_note}" if trace_note else "")
        ),
        "rank": (
            "Fractional-rank Δ-ECDF per walker (ArviZ multi-chain test); curves should "
            "overlap around zero"
            + (f", draws thinned by {rank_thin} for the test." if rank_thin > 1 else ".")
            + (f" {rank_note}" if rank_note else "")
        ),
        "pair": (
            f"Corner plot of {n_pair} evenly spaced draws: MAP (black ×, solid line), paper "
            "value (red ○, dashed line; an arrow-head at the edge when off scale)."
        ),
        "ppc": (
            f"Posterior predictive check: data (black), {pct} predictive band pooled over "
            "draws and trials (blue), median model (red); right: the fast end of the run; "
            "bottom: the same on the residual scale."
        ),
        "residual": (
            f"Trial-mean residual against the posterior median model (RMS "
            f"{quality['rms_median_m'] * 1e6:.3g} µm) and the trial-mean noise floor (green)."
        ),
    }


def _adequacy_box(adequacy: Adequacy) -> str:
    """The verdict on the model's fit, first on the page."""
    cls = {True: "ok", False: "bad", None: "unknown"}[adequacy.adequate]
    out = [f'<div class="verdict {cls}" id="adequacy"><strong>{html.escape(adequacy.headline)}'
           f"</strong>: {html.escape(adequacy.evidence())}."]
    out += [f"<p>{html.escape(line)}</p>" for line in adequacy.advice()]
    if adequacy.next_step:
        out.append(f'<p class="next">Next: <code>{html.escape(adequacy.next_step)}</code> '
                   "finds what the model is missing.</p>")
    return "".join(out) + "</div>"


def _synthetic_note_of(info: dict) -> str:
    if not (info.get("data") or {}).get("synthetic"):
        return ""
    return ('<p class="note"><strong>Synthetic data.</strong> These measurements were '
            "simulated, not measured on hardware; the estimates say nothing about a "
            "real actuator.</p>")


def _parameter_section(rows: list, info: dict, ci_prob: float) -> list[str]:
    pct = f"{100 * ci_prob:.4g}%"
    out = [f"<h2>Parameters</h2><p>Posterior mean, sd and {pct} highest density "
           "interval over all walkers; R-hat is ArviZ's rank-normalised split R-hat "
           "over walkers; ESS (tau) is the autocorrelation-time ESS used for the "
           "convergence decision.</p>",
           _table(_display_headers(rows),
                  [[r["name"], r.get("unit") or "\u2014"] + [r.get(k) for k, _ in _DISPLAY[2:]]
                   for r in rows], num_from=2)]
    fixed = (info.get("model") or {}).get("fixed") or {}
    if fixed:
        units = _units(info)
        out.append("<p>Fixed: " + ", ".join(
            f"<code>{html.escape(k)}</code> = {html.escape(_fmt(v))} "
            f"{html.escape(units.get(k, ''))}" for k, v in fixed.items()) + "</p>")
    return out


def _quality_section(info: dict, quality: Mapping, adequacy: Adequacy,
                     ci_prob: float) -> list[str]:
    point = info.get("map") or {}
    gs = point.get("global_search") or {}
    floor = quality["floor_m"]
    map_cost = _opt_float(point, "rms_cost_m")
    ratio = (f"{map_cost / floor:.3g}"
             if map_cost is not None and floor and math.isfinite(floor) else None)
    verdict = {True: "yes", False: "NO", None: "unknown (no noise estimate)"}
    rows = [
        ["the paper's cost (RMS of trial mean − model) at the MAP", _um(map_cost)],
        ["trial-mean noise floor (a perfect model's RMS cost)", _um(floor)],
        ["MAP cost / noise floor", ratio],
        ["the paper's cost at the paper-style global search optimum",
         _um(_opt_float(gs, "rms_cost_m"))],
        ["RMS of trial mean − posterior median model", _um(quality["rms_median_m"])],
        [f"data inside the {100 * ci_prob:.4g}% posterior predictive band",
         f"{100 * quality['coverage']:.1f}%"],
        ["whitened residual energy (1 for pure noise)", adequacy.energy],
        ["Ljung-Box p of the whitened residual", adequacy.ljung_box_p],
        ["model adequate (energy ≤ "
         f"{1 + adequacy.energy_tolerance:g}, Ljung-Box p ≥ {adequacy.level_adequate:g})",
         verdict[adequacy.adequate]],
        ["log posterior at the MAP", _opt_float(point, "log_posterior")],
    ]
    return ["<h2>Fit quality</h2>", _table(["quantity", "value"], rows)]


def _convergence_section(info: dict, tree: xr.DataTree) -> list[str]:
    conv = info.get("convergence") or {}
    post = tree["posterior"]
    settings = _table(["setting", "value"], [
        ["independent ensembles", conv.get("n_ensembles")],
        ["walkers per ensemble", conv.get("n_walkers")],
        ["steps per ensemble", conv.get("n_steps")],
        ["burn-in (steps)", conv.get("burn")],
        ["thin", conv.get("thin")],
        ["chains × draws kept", f"{post.sizes['chain']} × {post.sizes['draw']}"],
        ["required steps / tau (tau multiple)", conv.get("tau_multiple")],
        ["required ESS (min ESS)", conv.get("min_ess")],
    ])
    per_parameter = _table(
        ["parameter", "tau [steps]", "ESS (tau)", "R-hat (fit)", "R-hat (ensembles)"],
        [[n, _opt_float(conv.get("tau"), n), _opt_float(conv.get("ess"), n),
          _opt_float(conv.get("rhat"), n), _opt_float(conv.get("rhat_ensembles"), n)]
         for n in post.data_vars],
    )
    return ["<h2>Convergence</h2>", settings, per_parameter]


def _timings_section(info: dict) -> list[str]:
    timings = info.get("timings_s") or {}
    if not timings:
        return []
    return ["<h2>Timings</h2>", _table(["stage", "time [s]"], [[k, v] for k, v in timings.items()])]


def _meta_block(info: dict, source: str) -> str:
    d = info.get("data") or {}
    m = info.get("model") or {}
    noise = (info.get("noise") or {}).get("model")
    items = [
        f"data: <code>{html.escape(source)}</code>",
        f"{d.get('n_trials', '?')} trials × {d.get('n_samples', '?')} samples"
        + (f" at {1.0 / d['dt_s']:.4g} Hz" if d.get("dt_s") else ""),
        f"input: {html.escape(str(d.get('input_name', '?')))}",
        "effects: " + html.escape(", ".join(m.get("effects") or []) or "none"),
    ]
    if noise:
        items.append(f"noise: {html.escape(str(noise))}")
    items.append(f"pmabayes {html.escape(str(info.get('pmabayes_version', '?')))}, "
                 f"seed {html.escape(str(info.get('seed')))}")
    return '<p class="meta">' + " · ".join(items) + "</p>"


def _banner(conv: Mapping) -> str:
    messages = [str(m) for m in conv.get("messages") or []]
    listed = "".join(f"<li>{html.escape(m)}</li>" for m in messages)
    listed = f"<ul>{listed}</ul>" if listed else ""
    if conv.get("converged") is True:
        return (f'<div class="banner ok">Sampling converged: the posterior of this model is '
                "well sampled. Whether the model fits the data is the verdict above."
                f"{listed}</div>")
    return (
        '<div class="banner bad" id="not-converged"><strong>NOT CONVERGED.</strong> '
        "The sampler did not meet its convergence criteria; the intervals below are not "
        f"reliable.{listed}</div>"
    )


# ------------------------------------------------------------------- model criticism


def _page(title: str, body: Sequence[str]) -> str:
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>", f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>", *body, "</body></html>",
    ]) + "\n"


def _synthetic_note(dataset: Dataset) -> str:
    if not dataset.metadata.get("synthetic"):
        return ""
    return ('<p class="note"><strong>Synthetic data.</strong> These measurements were '
            "simulated, not measured on hardware.</p>")


def _band_rows(rows) -> list[list[Any]]:
    out = []
    for b in rows:
        floor = b.floor_m * 1e6 if np.isfinite(b.floor_m) else None  # one trial: no floor
        out.append([b.label, b.rms_m * 1e6, b.nrms, b.max_m * 1e6, floor,
                    b.ratio if floor is not None else None])
    return out


_BAND_HEADER = ["frequency band", "RMS [µm]", "RMS / motion RMS", "max [µm]", "floor [µm]",
                "RMS / floor"]


def write_diagnosis(diagnosis, out_dir: str | Path) -> Path:
    """Write the figures, ``diagnosis.json`` and an HTML page of a diagnosis.

    Parameters
    ----------
    diagnosis : pmabayes.criticism.results.Diagnosis
        The result of :func:`pmabayes.criticism.diagnosis.diagnose`.
    out_dir : str or Path
        Destination folder, created if needed. Written: ``comparison.png``,
        ``bands.png``, ``signature.png``, ``whiteness.png``, ``ranking.png``,
        ``discrepancy.png`` (when the diagnosis has a discrepancy), ``diagnosis.json``
        and ``index.html``. For several experiments the first four are per experiment
        (``comparison_NAME.png``, ...), and the page has a section per experiment
        (``id="experiment-NAME"``).

    Returns
    -------
    Path
        The path of ``index.html`` (self-contained: figures embedded).
    """
    from pmabayes.report import figures as plots
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    d = diagnosis
    exps = list(d.experiments) or [d]  # a Diagnosis made before experiments existed
    several = len(exps) > 1
    label = " + ".join(["base", *d.model.effect_names])
    summary = d.to_dict()
    (out_dir / "diagnosis.json").write_text(json.dumps(summary, indent=2) + "\n")
    cls = "ok" if d.adequate and d.missing is None else "bad"
    sources = [e.dataset.source or "(in memory)" for e in exps]
    if several:
        meta = (f"{len(exps)} experiments: "
                + ", ".join(f"<code>{html.escape(src)}</code> ({e.dataset.n_trials} trial(s) × "
                            f"{e.dataset.n_samples} samples, rig {html.escape(e.model.rig.name)})"
                            for src, e in zip(sources, exps, strict=True)))
    else:
        ds = exps[0].dataset
        meta = (f"data: <code>{html.escape(sources[0])}</code> · {ds.n_trials} trials × "
                f"{ds.n_samples} samples")
    body = [
        f'<p class="meta">{meta} · model: {html.escape(label)} · '
        f"seed {html.escape(str(d.settings.get('seed')))}</p>",
        *dict.fromkeys(_synthetic_note(e.dataset) for e in exps),
        f'<div class="banner {cls}">{html.escape(d.verdict)}</div>',
    ]
    figs: dict[str, str] = {}
    for e in exps:
        suffix = f"_{e.name}" if several else ""
        figs.update(_experiment_figures(e, label, out_dir, suffix))
        if several:
            body.append(f'<h2 id="experiment-{html.escape(e.name)}">Experiment '
                        f"{html.escape(e.name)}: <code>{html.escape(e.dataset.source or '')}"
                        f"</code> (adequate: {'yes' if e.adequate else 'no'})</h2>")
        body += _diagnosis_experiment_section(e, several)
        if several:
            for name in ("comparison", "bands", "signature", "whiteness"):
                body.append(_img(out_dir / f"{name}{suffix}.png", f"{name} plot of {e.name}",
                                 figs.pop(f"{name}{suffix}")))
    fig = plots.plot_ranking(d.ranking, threshold=d.score_threshold, level=d.settings["level"])
    fig.savefig(out_dir / "ranking.png", dpi=plots.REPORT_DPI)
    figs["ranking"] = ("Score-test evidence that each candidate effect is missing (red: "
                       "significant)" + (", all experiments together" if several else "") + ".")
    if d.discrepancy is not None:
        fig = plots.plot_discrepancy(d.discrepancy)
        fig.savefig(out_dir / "discrepancy.png", dpi=plots.REPORT_DPI)
        figs["discrepancy"] = ("The missing force estimated from the data"
                               + (f" of experiment {d.discrepancy_experiment}" if several
                                  else "")
                               + ": its partial dependence on each state (centred; band: two "
                               "posterior sd), red where dropping the state loses predictive "
                               "accuracy.")
    body += [
        "<h2>What is missing: the candidate effects</h2>",
        "<p>Refitted candidates first (by leave-one-trial-out ELPD"
        + (", over every trial of every experiment" if several else "")
        + "), then the others by score statistic"
        + (" (the experiments' scores and informations summed)" if several else "")
        + ". Estimates and intervals of refitted candidates come from the "
        f"refit's MAP and Laplace draws ({d.settings['ci_prob']:.0%} intervals); the others "
        "are the score test's one-step values.</p>",
        _table(["effect", "evidence", "p", "significant", "estimate", "interval",
                "explained", "ΔELPD ± se"],
               [[f.effect, f.evidence, f.p_value, "yes" if f.significant else "no",
                 ", ".join(f"{k} = {_fmt(v)}" for k, v in f.estimate.items()),
                 ", ".join(f"{_fmt(a)} to {_fmt(b)}" for a, b in f.interval.values()),
                 f"{f.explained:.0%}",
                 f"{f.refit.elpd_diff:+.1f} ± {f.refit.elpd_diff_se:.1f}" if f.refit else "—"]
                for f in d.ranking], num_from=1),
    ]
    for f in d.ranking:
        if f.significant:
            body.append(f"<h3>{html.escape(f.effect)}</h3><p>{html.escape(f.explanation)}</p>")
    if d.discrepancy is not None:
        body += _discrepancy_section(d.discrepancy)
    body.append("<h2>Figures</h2>")
    for name, caption in figs.items():
        body.append(_img(out_dir / f"{name}.png", f"{name} plot", caption))
    index = out_dir / "index.html"
    title = " + ".join(Path(src).name for src in sources) if sources else "data"
    index.write_text(_page(f"pmabayes diagnosis: {title}", body), encoding="utf-8")
    return index


def _discrepancy_section(disc) -> list[str]:
    """The discrepancy's states, evidence and proposal, for the diagnosis page."""
    out = ["<h2>Beyond the library: the missing force estimated from the data</h2>",
           f"<p>{html.escape(disc.text)}</p>",
           _table(["state", "ΔELPD if dropped ± se", "force amplitude [N]", "needed"],
                  [[s.state, f"{s.elpd_loss:+.1f} ± {s.se:.1f}", s.amplitude_n,
                    "yes" if s.needed else "no"] for s in disc.states], num_from=2)]
    if disc.proposal is not None:
        pr = disc.proposal
        out.append(f"<p>Proposed ({html.escape(pr.kind)}): <code>{html.escape(pr.expression)}"
                   f"</code>; ΔELPD against the flexible estimate {pr.elpd_diff:+.1f} ± "
                   f"{pr.elpd_diff_se:.1f}. Plugin: <code>{html.escape(str(pr.plugin))}</code>"
                   "</p>")
    return out


def _diagnosis_experiment_section(e, several: bool) -> list[str]:
    """One experiment's error table, whiteness and signature (h2 for one experiment,
    h3 under its heading for several)."""
    sig = e.signature
    h = "h3" if several else "h2"
    note = e.floor_note() if hasattr(e, "floor_note") else ""
    return [
        f"<{h}>Compare: error against the noise floor</{h}>",
        _table(_BAND_HEADER, _band_rows(sig.bands)),
        (f"<p>{html.escape(note)}.</p>" if note else ""),
        f"<p>Whitened residual: energy {sig.energy:.4g} (1 for pure noise, p = "
        f"{sig.energy_p:.2g}); Ljung-Box p = {sig.ljung_box_p:.2g}. "
        f"Adequate: <strong>{'yes' if e.adequate else 'no'}</strong>.</p>",
        f"<{h}>See where it fails</{h}>", f"<p>{html.escape(sig.describe())}</p>",
    ]


def _experiment_figures(e, label: str, out_dir: Path, suffix: str = "") -> dict[str, str]:
    """Draw an experiment's four figures of a diagnosis (``NAME{suffix}.png``); returns each
    one's caption."""
    from pmabayes.report import figures as plots
    ds = e.dataset
    figs = {
        "comparison": (plots.plot_comparison(ds, e.simulation.position_m[0],
                                             label=f"{label} (MAP)"),
                       "Trials, their mean and the model at its MAP; the residual beside the "
                       "noise floor; the hysteresis loop."),
        "bands": (plots.plot_band_errors({label: e.signature.bands}),
                  "RMS error of the trial mean per frequency band (octaves over the band the "
                  "input excites, from the residual's spectrum; the bands' mean squares add "
                  "up to the total), with the noise floor (black): the error a perfect model "
                  "would have, from the spectrum of the deviations between the trials."),
        "signature": (plots.plot_residual_signature(ds, e.simulation, e.frequency_hz,
                                                    label=label),
                      "Where the model fails: the residual against time, frequency, velocity, "
                      "pressure and position."),
        "whiteness": (plots.plot_whiteness(e.whiteness_curves()),
                      "Whiteness and independence tests: the residual whitened by the noise "
                      "model should stay inside the bounds at almost every lag."),
    }
    for name, (fig, _) in figs.items():
        fig.savefig(out_dir / f"{name}{suffix}.png", dpi=plots.REPORT_DPI)
    return {f"{name}{suffix}": caption for name, (_, caption) in figs.items()}


def write_comparison(comparison, out_dir: str | Path, *,
                     dataset: Dataset | Sequence[Dataset] | None = None) -> Path:
    """Write the error-falling figure, tables and an HTML page of a fit comparison.

    Parameters
    ----------
    comparison : pmabayes.criticism.compare.FitComparison
        From :func:`pmabayes.criticism.compare.compare_fits`.
    out_dir : str or Path
        Destination folder. Written: ``error_falling.png``, ``whiteness.png``,
        ``comparison.json``, ``comparison.md`` and ``index.html``. For fits of
        several experiments the figures are per experiment
        (``error_falling_NAME.png``, ``whiteness_NAME.png``), with a table and a
        section (``id="experiment-NAME"``) each, and one ELPD table over all trials.
    dataset : Dataset or sequence of Dataset, optional
        The data (one per experiment), to name it and mark it synthetic.

    Returns
    -------
    Path
        The path of ``index.html``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    c = comparison
    datasets = ([] if dataset is None else [dataset] if isinstance(dataset, Dataset)
                else list(dataset))
    (out_dir / "comparison.json").write_text(json.dumps(c.to_dict(), indent=2) + "\n")
    parts = c.experiments or {"": c}
    several = bool(c.experiments)
    elpd_header = ["fit", "ELPD (LOO)", "ΔELPD vs best ± se"]
    elpd_rows = [[k, c.elpd[k]["elpd"], f"{c.elpd[k]['elpd_diff']:.1f} ± {c.elpd[k]['dse']:.1f}"]
                 for k in c.labels]
    md: list[str] = []
    sections: list[str] = []
    for name, part in parts.items():
        suffix = f"_{name}" if several else ""
        header, rows = _comparison_rows(part, with_elpd=not several)
        if several:
            md += [f"## {name}", ""]
            sections.append(f'<h2 id="experiment-{html.escape(name)}">Experiment '
                            f"{html.escape(name)}: error per frequency band and whiteness</h2>")
        else:
            sections.append("<h2>Error per frequency band, whiteness and ELPD</h2>")
        md += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        md += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in rows]
        md.append("")
        sections.append(_table(header, rows))
        sections += _comparison_figures(part, out_dir, suffix, name)
    if several:
        md += ["## ELPD, leaving out one trial of all experiments at a time", "",
               "| " + " | ".join(elpd_header) + " |", "|" + "---|" * len(elpd_header)]
        md += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in elpd_rows]
        md.append("")
    md += ["| step | ΔELPD | se |", "|---|---|---|"]
    md += [f"| {st['from']} → {st['to']} | {st['elpd_diff']:+.1f} | {st['se']:.1f} |"
           for st in c.elpd_steps]
    (out_dir / "comparison.md").write_text("\n".join(md) + "\n")
    names = [Path(ds.source).name if ds.source else "data" for ds in datasets] or ["data"]
    name = " + ".join(names)
    body = [
        f'<p class="meta">{len(c.labels)} fits of '
        + ", ".join(f"<code>{html.escape(n)}</code>" for n in names)
        + (f" ({len(parts)} experiments)" if several else "") + "</p>",
        *dict.fromkeys(_synthetic_note(ds) for ds in datasets),
    ]
    if several:
        body += ["<h2>ELPD, leaving out one trial of all experiments at a time</h2>",
                 _table(elpd_header, elpd_rows)]
        body += sections
    else:
        body += sections[:2]
    body += [
        "<h2>Each step</h2>",
        _table(["step", "ΔELPD (leave one trial out)", "se"],
               [[f"{st['from']} → {st['to']}", st["elpd_diff"], st["se"]]
                for st in c.elpd_steps]),
    ]
    if not several:
        body += sections[2:]
    index = out_dir / "index.html"
    index.write_text(_page(f"pmabayes comparison: {name}", body), encoding="utf-8")
    return index


def _comparison_rows(c, *, with_elpd: bool) -> tuple[list[str], list[list[Any]]]:
    """The table of a comparison on one data set: RMS per band, ratio, whiteness (and ELPD)."""
    band_names = [b.label for b in c.bands[c.labels[0]]]
    header = ["fit", *[f"RMS {b} [µm]" for b in band_names], "RMS / floor",
              "Ljung-Box p", "energy"]
    if with_elpd:
        header += ["ELPD (LOO)", "ΔELPD vs best ± se"]
    rows = []
    for k in c.labels:
        ratio = c.bands[k][-1].ratio
        row = [k, *[b.rms_m * 1e6 for b in c.bands[k]], ratio if np.isfinite(ratio) else None,
               c.whiteness[k]["ljung_box_p"], c.whiteness[k]["energy"]]
        if with_elpd:
            row += [c.elpd[k]["elpd"], f"{c.elpd[k]['elpd_diff']:.1f} ± {c.elpd[k]['dse']:.1f}"]
        rows.append(row)
    floors = [b.floor_m * 1e6 if np.isfinite(b.floor_m) else None for b in c.bands[c.labels[0]]]
    rows.append(["noise floor", *floors, 1.0 if floors[-1] is not None else None, "", "",
                 *(["", ""] if with_elpd else [])])
    return header, rows


def _comparison_figures(c, out_dir: Path, suffix: str, name: str) -> list[str]:
    """Draw the error-falling and whiteness figures of one data set; their ``<img>``s."""
    from pmabayes.report import figures as plots
    plots.plot_band_errors(c.bands, title="the error falls as effects are added "
                                          "(label: multiple of the noise floor)"
                           + (f": {name}" if name else "")
                           ).savefig(out_dir / f"error_falling{suffix}.png", dpi=plots.REPORT_DPI)
    plots.plot_whiteness(c.whiteness_curves()).savefig(out_dir / f"whiteness{suffix}.png",
                                                       dpi=plots.REPORT_DPI)
    return [
        _img(out_dir / f"error_falling{suffix}.png", "error falling",
             "RMS error of the trial mean per frequency band for each fit, with the noise "
             "floor (black)."),
        _img(out_dir / f"whiteness{suffix}.png", "whiteness",
             "Whitened residual of each fit: autocorrelation and cross-correlation with the "
             "command's rate, against the bounds for a white residual."),
    ]


# ------------------------------------------------------------------- validation


def write_validation(validation, out_dir: str | Path) -> Path:
    """Write the figures, ``validation.json`` and an HTML page of a validation.

    Parameters
    ----------
    validation : pmabayes.criticism.validation.Validation
        The result of :func:`pmabayes.criticism.validation.validate`.
    out_dir : str or Path
        Destination folder, created if needed. Written: one
        ``validation_<i>_<name>.png`` per experiment, ``validation.json`` and
        ``index.html``.

    Returns
    -------
    Path
        The path of ``index.html`` (self-contained: figures embedded, no script).
    """
    from pmabayes.report import figures as plots
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    v = validation
    (out_dir / "validation.json").write_text(json.dumps(v.to_dict(), indent=2) + "\n")
    settings = v.settings
    pct = f"{100 * settings['ci_prob']:.4g}%"
    model = " + ".join(["base", *v.effects])
    body = [
        f'<p class="meta">fit: <code>{html.escape(str(v.fit_source or "(in memory)"))}</code>'
        f" · model: {html.escape(model)} · {len(v.experiments)} held-out experiment(s) · "
        f"{settings['n_draws']} posterior draws each · seed {html.escape(str(settings['seed']))}"
        "</p>",
    ]
    if any(e.synthetic for e in v.experiments):
        body.append('<p class="note"><strong>Synthetic data.</strong> Experiments marked '
                    "synthetic were simulated, not measured on hardware.</p>")
    body += [
        f"<p>Each experiment is simulated on its own rig with posterior draws of the fit. The "
        f"{pct} predictive band is the model's prediction plus the fit's noise (AR(1) "
        "disturbance and white sensor noise drawn from the fit's noise posterior), not the "
        "held-out data's own noise. RMSE: RMS of the trial mean minus the posterior-mean "
        "prediction. NRMSE: RMSE over the RMS of the trial mean's variation about its own "
        "mean. Noise floor: the error a perfect model would have, from the spread between "
        "repeated trials (none with one trial). Coverage: the share of all measured "
        f"samples inside the {pct} band (about {pct} for a model and noise that describe "
        "the data). The model-only band holds the parameters' uncertainty alone: what "
        "counts for noiseless held-out data.</p>",
        _table(["experiment", "rig", "noise from", "trials", "samples", "RMSE [µm]",
                "noise floor [µm]", "RMSE / floor", "NRMSE", f"inside the {pct} band",
                "trial mean inside the model-only band"],
               [[e.name, e.rig.get("name"), e.noise["from"], e.n_trials, e.n_samples,
                 e.rmse_m * 1e6, None if e.noise_floor_m is None else e.noise_floor_m * 1e6,
                 e.ratio_to_floor, e.nrmse, f"{100 * e.band_coverage:.1f}%",
                 f"{100 * e.model_band_coverage:.1f}%"]
                for e in v.experiments], num_from=3),
    ]
    for i, e in enumerate(v.experiments):
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in e.name)
        png = out_dir / f"validation_{i}_{safe}.png"
        plots.plot_validation(e, path=png)
        src = f" (<code>{html.escape(e.source)}</code>)" if e.source else ""
        body.append(f"<h2>{html.escape(e.name)}{src}</h2>")
        body.append(f"<p>{html.escape(e.summary())}.</p>")
        for note in e.notes:
            body.append(f'<p class="note">{html.escape(note)}</p>')
        if e.band_errors:
            body.append(_table(_BAND_HEADER, _band_rows(e.band_errors)))
        body.append(_img(png, f"validation of {e.name}",
                         f"{e.name}: measured trials (grey), the {pct} predictive band "
                         "(blue) and the posterior-mean prediction (red); bottom: the same "
                         "less the prediction, with the trial mean (black)."))
    index = out_dir / "index.html"
    index.write_text(_page("pmabayes validation on held-out experiments", body),
                     encoding="utf-8")
    return index
