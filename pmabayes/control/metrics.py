"""Tracking metrics of closed-loop runs, over whole periods after the start-up.

The first ``max(2 s, one period)`` is dropped and the largest whole number of
periods that ends at the end of the run is kept. Each run is reduced on its own
contiguous row, so its numbers do not depend on the batch it came in.
"""

from __future__ import annotations

import math

import numpy as np

from pmabayes.control.kernel import ClosedLoop
from pmabayes.control.operating import _PRESSURE_MAX_PA, ControlError, _check_frequency

#: Metrics of :func:`loop_metrics`, in the order used by datasets.
METRICS = ("rms_error_m", "max_error_m", "amplitude_ratio", "phase_lag_deg", "overshoot_pct",
           "dead_zone_fraction", "saturated_fraction", "period_difference_m")
_TRACKING = METRICS[:5]


def _analysis_window(time_s: np.ndarray, frequency_hz: float, settle_s: float) -> np.ndarray:
    period = 1.0 / frequency_hz
    dt = time_s[1] - time_s[0]
    end = time_s[-1]
    start = max(settle_s, period)
    n_periods = math.floor((end - start) / period + 1e-9)
    if n_periods < 1:
        raise ControlError(
            f"the run ({end:.3g} s) holds no whole period of {frequency_hz:g} Hz after the "
            f"first {start:.3g} s of start-up; run for at least {start + period:.3g} s")
    first = int(round((end - n_periods * period - time_s[0]) / dt))
    # the last sample excluded, so the window spans whole periods exactly
    return np.arange(first, len(time_s) - 1)


def minimum_duration_s(frequency_hz: float, settle_s: float = 2.0) -> float:
    """Shortest run whose metrics have one whole period after the start-up.

    Parameters
    ----------
    frequency_hz : float
        Reference frequency, > 0.
    settle_s : float
        Start-up the metrics drop (at least one period is dropped).

    Returns
    -------
    float
        ``max(settle_s, 1 / f) + 1 / f`` in s.

    Examples
    --------
    >>> from pmabayes.control import minimum_duration_s
    >>> minimum_duration_s(2.0), minimum_duration_s(0.25)
    (2.5, 8.0)
    """
    return max(settle_s, 1.0 / frequency_hz) + 1.0 / frequency_hz


def _rows(time_s, *signals) -> tuple[np.ndarray, ...]:
    time_s = np.asarray(time_s, dtype=float)
    rows = [np.atleast_2d(np.asarray(x, dtype=float)) for x in signals]
    if any(r.shape[-1] != time_s.size for r in rows):
        raise ControlError("every signal must have as many samples as time_s")
    batch = max(r.shape[0] for r in rows)
    return (time_s, *(np.broadcast_to(r, (batch, time_s.size)) for r in rows))


def tracking_metrics(time_s: np.ndarray, reference_m: np.ndarray, position_m: np.ndarray,
                     frequency_hz: float, *, settle_s: float = 2.0) -> dict[str, np.ndarray]:
    """Tracking metrics over whole periods after the start-up.

    The window drops the first ``max(settle_s, one period)`` and keeps the largest
    whole number of periods ending at the last sample (the last sample excluded,
    so the window spans whole periods exactly). Each run is reduced on its own
    contiguous row, so its numbers do not depend on the batch it came in.

    Parameters
    ----------
    time_s : numpy.ndarray
        Uniform times ``(n,)``.
    reference_m : numpy.ndarray
        Reference ``(n,)`` or ``(batch, n)``.
    position_m : numpy.ndarray
        Response ``(n,)`` or ``(batch, n)``.
    frequency_hz : float
        The reference frequency; the sinusoid fits use it.
    settle_s : float
        Start-up to drop, at least one period.

    Returns
    -------
    dict of str to numpy.ndarray
        Each ``(batch,)``: ``rms_error_m`` and ``max_error_m`` (of position minus
        reference); ``amplitude_ratio`` and ``phase_lag_deg`` of the response's
        least-squares sinusoid at ``frequency_hz`` relative to the reference's (the
        lag is in [-90, 270) degrees, positive when the response is late);
        ``overshoot_pct``, the response's highest point above the reference's, in %
        of the reference amplitude (negative when it falls short).

    Raises
    ------
    ControlError
        If the frequency is not > 0 or the run holds no whole period after start-up.

    Examples
    --------
    >>> from pmabayes.control import closed_loop, tracking_metrics
    >>> run = closed_loop("ct", 1.0, duration_s=6.0)
    >>> m = tracking_metrics(run.time_s, run.reference_m, run.position_m, 1.0)
    >>> sorted(m)
    ['amplitude_ratio', 'max_error_m', 'overshoot_pct', 'phase_lag_deg', 'rms_error_m']
    >>> round(float(m["rms_error_m"][0]) * 1e3, 1), round(float(m["phase_lag_deg"][0]))
    (5.2, 18)
    """
    frequency_hz = _check_frequency(frequency_hz)
    time_s, ref, pos = _rows(time_s, reference_m, position_m)
    idx = _analysis_window(time_s, frequency_hz, settle_s)
    t = time_s[idx]
    om = 2 * np.pi * frequency_hz
    basis = np.column_stack([np.ones_like(t), np.sin(om * t), np.cos(om * t)])
    proj = np.ascontiguousarray(np.linalg.pinv(basis))  # least squares by the pseudo-inverse
    out = {k: np.empty(pos.shape[0]) for k in _TRACKING}
    # Row by row on contiguous 1-D copies, by numpy's pairwise sums (not BLAS, whose
    # threads and blocking may vary): reductions over an axis of a 2-D array block (and
    # so round) differently with the batch's shape.
    for i in range(pos.shape[0]):
        r = np.ascontiguousarray(ref[i, idx])
        y = np.ascontiguousarray(pos[i, idx])
        err = y - r
        c_r = [float(np.sum(r * proj[j])) for j in range(3)]
        c_y = [float(np.sum(y * proj[j])) for j in range(3)]
        amp_r = math.hypot(c_r[1], c_r[2])
        amp_y = math.hypot(c_y[1], c_y[2])
        lag = math.degrees(math.atan2(c_r[2], c_r[1]) - math.atan2(c_y[2], c_y[1]))
        out["rms_error_m"][i] = math.sqrt(float(np.sum(err * err)) / err.size)
        out["max_error_m"][i] = float(np.max(np.abs(err)))
        out["amplitude_ratio"][i] = amp_y / amp_r
        out["phase_lag_deg"][i] = (lag + 90.0) % 360.0 - 90.0
        out["overshoot_pct"][i] = 100.0 * (float(y.max()) - float(r.max())) / amp_r
    return out


def command_fractions(time_s: np.ndarray, command_pa: np.ndarray, frequency_hz: float, *,
                      dead_zone_pa, pressure_max_pa: float = _PRESSURE_MAX_PA,
                      settle_s: float = 2.0) -> dict[str, np.ndarray]:
    """Fractions of the metrics' window with the command in the dead zone or at the limit.

    Parameters
    ----------
    time_s : numpy.ndarray
        Uniform times ``(n,)``.
    command_pa : numpy.ndarray
        Pressure command ``(n,)`` or ``(batch, n)``.
    frequency_hz : float
        The reference frequency (sets the window, as in :func:`tracking_metrics`).
    dead_zone_pa : float or numpy.ndarray
        The plant's ``p_dz``, one or one per run.
    pressure_max_pa : float
        The command's upper limit.
    settle_s : float
        Start-up to drop.

    Returns
    -------
    dict of str to numpy.ndarray
        ``dead_zone_fraction`` (command at or below ``p_dz``: no actuator force) and
        ``saturated_fraction`` (command at the upper limit), each ``(batch,)``.

    Examples
    --------
    >>> from pmabayes.control import closed_loop, command_fractions
    >>> run = closed_loop("ct", 1.0, duration_s=6.0)
    >>> command_fractions(run.time_s, run.command_pa, 1.0, dead_zone_pa=run.dead_zone_pa)
    {'dead_zone_fraction': array([0.]), 'saturated_fraction': array([0.])}
    """
    frequency_hz = _check_frequency(frequency_hz)
    time_s, cmd = _rows(time_s, command_pa)
    idx = _analysis_window(time_s, frequency_hz, settle_s)
    p_dz = np.broadcast_to(np.asarray(dead_zone_pa, dtype=float), (cmd.shape[0],))
    window = cmd[:, idx]
    return {"dead_zone_fraction": np.mean(window <= p_dz[:, None], axis=1),
            "saturated_fraction": np.mean(window >= pressure_max_pa, axis=1)}


def period_difference_m(time_s: np.ndarray, position_m: np.ndarray,
                        frequency_hz: float) -> np.ndarray:
    """Largest difference between the last period of a response and the one before.

    A loop in a periodic steady state repeats itself (up to the encoder's
    quantisation); one still settling, or oscillating at another frequency, does not.

    Parameters
    ----------
    time_s : numpy.ndarray
        Uniform times ``(n,)``, spanning at least two periods.
    position_m : numpy.ndarray
        Response ``(n,)`` or ``(batch, n)``.
    frequency_hz : float
        The reference frequency.

    Returns
    -------
    numpy.ndarray
        ``max |x(t) - x(t - T)|`` over the last period ``T``, in m, ``(batch,)``
        (the earlier period linearly interpolated; inf for a non-finite response).

    Examples
    --------
    A loop at 1 Hz after 6 s repeats itself to within about the encoder's step
    (12.7 µm):

    >>> from pmabayes.control import closed_loop, period_difference_m
    >>> run = closed_loop("ct", 1.0, duration_s=6.0)
    >>> bool(period_difference_m(run.time_s, run.position_m, 1.0)[0] < 1e-4)
    True
    """
    frequency_hz = _check_frequency(frequency_hz)
    time_s, pos = _rows(time_s, position_m)
    period = 1.0 / frequency_hz
    if time_s[-1] - time_s[0] < 2 * period:
        raise ControlError(f"need two periods of {frequency_hz:g} Hz, got "
                           f"{time_s[-1] - time_s[0]:.3g} s")
    last = time_s >= time_s[-1] - period
    out = np.empty(pos.shape[0])
    for i in range(pos.shape[0]):
        x = pos[i]
        before = np.interp(time_s[last] - period, time_s, x)
        d = np.abs(x[last] - before)
        out[i] = float(d.max()) if np.all(np.isfinite(d)) else np.inf
    return out


def loop_metrics(run: ClosedLoop, *, settle_s: float = 2.0) -> dict[str, np.ndarray]:
    """Every metric of :data:`METRICS` for each run of a closed-loop batch.

    Parameters
    ----------
    run : ClosedLoop
        Runs from :func:`closed_loop_batch` (any mix of frequencies).
    settle_s : float
        Start-up to drop.

    Returns
    -------
    dict of str to numpy.ndarray
        The metrics of :func:`tracking_metrics` and :func:`command_fractions`, and
        ``period_difference_m`` (:func:`period_difference_m`: how far the loop is
        from a periodic steady state), each ``(batch,)``.

    Examples
    --------
    >>> from pmabayes.control import closed_loop, loop_metrics
    >>> metrics = loop_metrics(closed_loop("ct", 1.0, duration_s=6.0))
    >>> list(metrics)
    ['rms_error_m', 'max_error_m', 'amplitude_ratio', 'phase_lag_deg', 'overshoot_pct',
     'dead_zone_fraction', 'saturated_fraction', 'period_difference_m']
    >>> round(float(metrics["overshoot_pct"][0]), 1)
    5.6
    """
    batch = run.position_m.shape[0]
    out = {m: np.empty(batch) for m in METRICS}
    p_max = run.metadata["timing"].pressure_max_pa
    for f in np.unique(run.frequency_hz):
        sel = np.flatnonzero(run.frequency_hz == f)
        met = tracking_metrics(run.time_s, run.reference_m[sel], run.position_m[sel], float(f),
                               settle_s=settle_s)
        met |= command_fractions(run.time_s, run.command_pa[sel], float(f),
                                 dead_zone_pa=run.dead_zone_pa[sel], pressure_max_pa=p_max,
                                 settle_s=settle_s)
        met["period_difference_m"] = period_difference_m(run.time_s, run.position_m[sel],
                                                         float(f))
        for m in METRICS:
            out[m][sel] = met[m]
    return out
