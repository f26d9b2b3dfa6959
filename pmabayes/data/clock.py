"""The data's clock: a grid of times as the file stores it (printed to a precision, or in
single precision) rebuilt as the uniform grid it rounds.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from pmabayes.data.dataset import (
    DataWarning,
    _first_nonuniform,
)

#: rounded times must lie this close (in units of the printed step) to the rebuilt grid:
#: half a step of rounding, plus the fitted line's own error on short trials
_ROUNDING_SLACK = 0.6


def _trial_blocks(trial: np.ndarray) -> list[tuple[int, int]]:
    """``(start, end)`` rows of each run of equal trial ids, in file order."""
    starts = np.concatenate(([0], np.flatnonzero(trial[1:] != trial[:-1]) + 1))
    ends = np.concatenate((starts[1:], [trial.size]))
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def _rounded_grid(
    trial: np.ndarray,
    time: np.ndarray,
    step_of: Callable[[], float | None],
    rate_hz: float | None,
    where: str,
    stored: str = "is printed to",
    fix: str = "Write times with more digits (or sample_rate_hz in the "
    "sidecar) to make this exact.",
) -> np.ndarray:
    """The times, rebuilt as ``t0 + k / rate`` where they are a uniform grid rounded to
    the precision they are stored with; unchanged where they are uniform already, or
    where they are not uniform even to that precision (the grid check then says where).

    A 750 Hz clock printed to microseconds (0.001333, 0.002667, ...) moves each interval
    by far more than the grid check's 1e-6 relative tolerance, yet the grid is uniform.
    ``step_of()`` gives that precision in s (called only when the grid is not uniform:
    it may be slow), ``stored`` and ``fix`` complete the warning: how the times are
    stored (CSV: printed; MATLAB: single precision), and how to make them exact.
    """
    blocks = [(s, e) for s, e in _trial_blocks(trial) if e - s >= 3]
    if all(_first_nonuniform(time[s:e]) is None for s, e in blocks):
        return time
    step = step_of()
    if step is None:
        return time
    out = np.array(time, dtype=float)
    for s, e in blocks:
        k = np.arange(e - s, dtype=float)
        t = time[s:e]
        if rate_hz:
            dt = 1.0 / float(rate_hz)
            t0 = float(np.mean(t - k * dt))
        else:
            dt, t0 = (float(c) for c in np.polyfit(k, t, 1))
        grid = t0 + k * dt
        tol = _ROUNDING_SLACK * step + 8 * np.finfo(float).eps * float(np.abs(t).max())
        if step > 0.1 * dt or np.abs(t - grid).max() > tol:
            return time  # a gap or jitter beyond the rounding: let the grid check report it
        out[s:e] = grid
    source = (
        f"the sidecar's sample_rate_hz = {float(rate_hz):g}"
        if rate_hz
        else f"a straight-line fit of the times, {1.0 / dt:.7g} Hz"
    )
    warnings.warn(
        DataWarning(
            f"{where}: time_s {stored} {step:g} s, so its intervals vary by up to "
            f"{step:g} s; the times are a uniform grid to that precision, so the grid was "
            f"rebuilt as t0 + k / rate from {source}. {fix}"
        ),
        stacklevel=4,
    )
    return out
