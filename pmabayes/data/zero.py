"""The sensor's zero read at rest at the start: a sidecar's ``"position_zero_s"``.

A lab's displacement sensor is often not zeroed before each record: its reading with
the muscle at rest under its load differs from file to file. A sidecar's
``"position_zero_s": 0.02`` says that the muscle rests for at least the first 0.02 s of
each trial (of each segment, where the record splits at long gaps), before the input
moves it. On reading, each trial's positions are referred to their mean over those
samples, said in a :class:`~pmabayes.data.DataWarning` and recorded in the metadata as
``"position_zero"`` (``{"first_s": ..., "subtracted_m": [one per trial]}``); the key
leaves the metadata, so that a data set written back reads back the same. Declare
``"position_reference": "start"`` beside it, so that the model is referred to its own
start too.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings

import numpy as np

from pmabayes.data.dataset import DataError, Dataset, DataWarning
from pmabayes.data.units import _HERE

__all__ = ["ZERO_KEY", "zeroed_at_start"]

#: The sidecar key of the seconds at rest at each trial's start.
ZERO_KEY = "position_zero_s"


def zeroed_at_start(ds: Dataset, declare: str) -> Dataset:
    """The data set with each trial's positions referred to its reading at rest at the
    start, where the metadata declares ``"position_zero_s"``; as it is otherwise.

    Parameters
    ----------
    ds : Dataset
        A data set as read.
    declare : str
        Where the metadata was declared, for messages.

    Returns
    -------
    Dataset

    Raises
    ------
    DataError
        For a value that is not a positive number of seconds, or a trial with no
        sample observed in that time.
    """
    span = ds.metadata.get(ZERO_KEY)
    if span is None:
        return ds
    if (isinstance(span, bool) or not isinstance(span, numbers.Real) or not math.isfinite(span)
            or span <= 0):
        raise DataError(
            f"{declare}: '{ZERO_KEY}' is {span!r}; it must be a positive number of seconds: "
            "how long the muscle rests at each trial's start, before the input moves it "
            "(the positions are referred to their mean there).")
    first = ds.time_s - ds.time_s[0] < span
    first[0] = True
    seen = ds.observed & first[None, :]
    empty = ~seen.any(axis=1)
    if empty.any():
        raise DataError(
            f"{ds.source or declare}: trial {int(ds.trial_ids[np.argmax(empty)])} has no "
            f"sample observed in its first {span:g} s ({ZERO_KEY}); lengthen it.")
    zero = np.where(seen, ds.position_m, 0.0).sum(axis=1) / seen.sum(axis=1)
    metadata = {k: v for k, v in ds.metadata.items() if k != ZERO_KEY}
    metadata["position_zero"] = {"first_s": float(span), "subtracted_m": zero.tolist()}
    warnings.warn(DataWarning(
        f"{ds.source or declare}: positions referred to the sensor's reading at rest, their "
        f"mean over each trial's first {span:g} s ({ZERO_KEY}): "
        + ", ".join(f"{z * 1e3:.4g} mm" for z in zero[:6]) + (" ..." if zero.size > 6 else "")
        + " subtracted; the metadata's 'position_zero' records it."), skip_file_prefixes=_HERE)
    return dataclasses.replace(ds, position_m=ds.position_m - zero[:, None], metadata=metadata)
