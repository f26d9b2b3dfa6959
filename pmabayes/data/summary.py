"""What a data set holds, in words: the reading a user checks before fitting.

:func:`describe` says how a file was read (trials, grid, samples not observed, units
converted, columns read), the ranges of its input and position in the units a lab
reads, and what the sidecar declared (the rig, the start, periods, conditions), so that
a wrong unit, a wrong column or a missing rig shows before any fit. ``pmabayes read``
prints it.
"""

from __future__ import annotations

import numpy as np

from pmabayes.data.calibration import Calibration
from pmabayes.data.dataset import Dataset

__all__ = ["describe"]


def _range(values: np.ndarray, scale: float, unit: str) -> str:
    seen = values[np.isfinite(values)]
    if not seen.size:
        return "no value observed"
    lo, hi = float(seen.min()) / scale, float(seen.max()) / scale
    return f"from {lo:.4g} to {hi:.4g} {unit}"


def _rig(rig: object) -> str:
    if not isinstance(rig, dict):
        return ("none declared: the paper's characterisation rig is assumed (a DataWarning "
                "says so on reading); declare yours in the sidecar's \"rig\"")
    parts = [f"{k} {v}" for k, v in rig.items() if k != "name"]
    return f"{rig.get('name', 'unnamed')}: " + ", ".join(parts)


def describe(dataset: Dataset) -> str:
    """A few lines saying what ``dataset`` holds and how it was read.

    Parameters
    ----------
    dataset : Dataset
        A data set, as :func:`pmabayes.data.load` reads it.

    Returns
    -------
    str
        One line each: the grid, the input, the position, the units converted and the
        columns read (where a sidecar named them), the rig, the start and periods, the
        conditions, and whether the data are synthetic.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.data import Dataset, describe
    >>> ds = Dataset(time_s=np.arange(4) * 0.01, input=np.array([[0.0, 1e5, 2e5, 1e5]]),
    ...              position_m=np.array([[0.0, 1e-3, 3e-3, 2e-3]]), trial_ids=np.array([1]),
    ...              metadata={"initial_state": "rest"})
    >>> print(describe(ds))  # doctest: +NORMALIZE_WHITESPACE
    Dataset: 1 trial x 4 samples, 10 ms apart (100 Hz), 0.03 s; every sample observed
    input: pressure from 0 to 200 kPa (gauge)
    position: from 0 to 3 mm, a stroke of 3 mm
    rig: none declared: the paper's characterisation rig is assumed (a DataWarning says
    so on reading); declare yours in the sidecar's "rig"
    start: rest
    """
    meta = dataset.metadata
    missing = dataset.n_missing
    grid = dataset.n_trials * dataset.n_samples
    seen = ("every sample observed" if not missing else
            f"{missing} samples not observed ({100 * missing / grid:.3g}% of the grid)")
    trials = "trial" if dataset.n_trials == 1 else "trials"
    duration = float(dataset.time_s[-1] - dataset.time_s[0])
    name = dataset.source or "Dataset"
    lines = [f"{name}: {dataset.n_trials} {trials} x {dataset.n_samples} samples, "
             f"{dataset.dt_s * 1e3:.4g} ms apart ({1.0 / dataset.dt_s:.4g} Hz), "
             f"{duration:.4g} s; {seen}"]
    if dataset.input_name == "force_n":
        lines.append(f"input: force {_range(dataset.input, 1.0, 'N')}")
    else:
        reference = ("converted from absolute" if meta.get("converted_from_absolute")
                     else "gauge")
        lines.append(f"input: pressure {_range(dataset.input, 1e3, 'kPa')} ({reference})")
    x = dataset.position_m
    stroke = float(np.nanmax(x) - np.nanmin(x)) * 1e3 if np.isfinite(x).any() else 0.0
    lines.append(f"position: {_range(x, 1e-3, 'mm')}, a stroke of {stroke:.4g} mm"
                 + (", referred to its start" if meta.get("position_reference") == "start"
                    else ""))
    converted = meta.get("converted_units")
    if converted:
        lines.append("units converted on reading: " + "; ".join(
            f"{c['from']} x {c['factor']:g} -> {si}" for si, c in converted.items()))
    if meta.get("calibrated"):
        lines.append("calibrated on reading: " + "; ".join(
            Calibration(signal, **c).text() for signal, c in meta["calibrated"].items()))
    if meta.get("read_columns"):
        lines.append("columns read: " + ", ".join(
            f"{k} as {n}" for k, n in meta["read_columns"].items()))
    lines.append(f"rig: {_rig(meta.get('rig'))}")
    start = f"start: {dataset.initial_state}"
    if dataset.period_samples:
        start += (f"; periodic, every {dataset.period_samples} samples "
                  f"({dataset.n_periods} periods)")
    lines.append(start)
    if meta.get("conditions"):
        lines.append("conditions: " + ", ".join(
            f"{k} = {v:g}" for k, v in meta["conditions"].items()))
    if meta.get("synthetic") or meta.get("generator"):
        lines.append("synthetic: made by pmabayes, not measured")
    return "\n".join(lines)
