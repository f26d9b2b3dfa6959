"""Batched, compiled simulation of a composed :class:`~pmabayes.model.model.Model`: the
Python API (:func:`simulate`, :func:`simulate_dataset`, :class:`Simulation`).

Each sample interval is integrated by a second-order scheme that is stable at any
step: the linear mass-spring-damper discretised exactly for a force linear over the
interval, the remaining force found by one linearly implicit step, and the Bouc-Wen
force ``z`` advanced by the exact solution of its law (:mod:`pmabayes.model.boucwen`)
over the step's displacement. Kernels are generated per composition of effects
(:mod:`pmabayes.model.codegen`), compiled with numba and cached on disk
(:mod:`pmabayes.model.kernels`; ``$PMABAYES_CACHE_DIR``, default
``~/.cache/pmabayes``). This module prepares the inputs and the initial state, runs
the kernels and checks what they return. A record starts at rest, at zero, from a
given (estimated) state, or in a periodic steady state found by Newton's method on
the period map. The documentation's page "The simulator"
(``docs/theory/simulator.rst``) gives the scheme and the input conventions.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import multiprocessing
import os
import threading
import warnings
from dataclasses import dataclass

import numpy as np

from pmabayes.data import BETWEEN_SAMPLES, INITIAL_STATES, check_time_grid
from pmabayes.model.boucwen import BoucWenColumns

# the code generation and the compiled kernels, importable from here as before
from pmabayes.model.codegen import (  # noqa: F401
    FASTMATH,
    PlantCode,
    SimulationError,
    _check_initial_state,
    indent_lines,
    state_effects,
    state_rows,
)
from pmabayes.model.codegen import generate as _generate  # noqa: F401
from pmabayes.model.kernels import (  # noqa: F401
    cache_dir,
    cached_kernel,
    compile_kernel,
    discretise,
    kernel_for,
    structure_key,
)
from pmabayes.model.model import Model
from pmabayes.util import busy_workers, fingerprint, local_cores

__all__ = ["simulate", "simulate_dataset", "Simulation", "kernel_for", "cache_dir",
           "SimulationError", "SteadyStateWarning", "OverflowingStepWarning",
           "collect_steady_state_misses", "BETWEEN_SAMPLES", "INITIAL_STATES",
           "STEADY_STATE_TOL_M", "MAX_WARMUP_PERIODS", "POSITION_REFERENCES",
           "warmup_settings", "position_reference", "simulation_threads", "side_by_side"]

_LOCK = threading.Lock()  # guards the memo of reconstructed inputs

# ---------------------------------------------------------------------------------
# Python API


@dataclass(frozen=True)
class Simulation:
    """Recorded states of a simulation, each ``(batch, n_samples)``.

    Parameters
    ----------
    time_s : numpy.ndarray
        Sample times, ``(n_samples,)``.
    position_m : numpy.ndarray
        Position as measured (after measurement effects).
    true_position_m : numpy.ndarray
        Position before measurement effects.
    velocity_m_s : numpy.ndarray
        Velocity.
    hysteresis_n : numpy.ndarray
        Bouc-Wen force ``z``.
    pressure_pa : numpy.ndarray
        Input acting on the actuator at each sample time (after pressure effects):
        pressure in Pa, or force in N for a force-driven rig.
    effect_force_n : numpy.ndarray
        Sum of the force effects at each sample.
    """

    time_s: np.ndarray
    position_m: np.ndarray
    true_position_m: np.ndarray
    velocity_m_s: np.ndarray
    hysteresis_n: np.ndarray
    pressure_pa: np.ndarray
    effect_force_n: np.ndarray


def _time_axis(n: int, dt_s: float | None, time_s: np.ndarray | None) -> tuple[np.ndarray, float]:
    if time_s is not None:
        time_s = np.asarray(time_s, dtype=float)
        if time_s.shape != (n,):
            raise SimulationError(f"time_s has shape {time_s.shape}, expected ({n},)")
        dt = (check_time_grid(time_s, source="simulate", error=SimulationError) if n > 1
              else (dt_s or 1.0))
        if dt_s is not None and abs(dt - dt_s) > 1e-9 * dt:
            raise SimulationError(f"dt_s={dt_s} disagrees with the spacing of time_s ({dt})")
        return time_s, dt
    if dt_s is None or not dt_s > 0:
        raise SimulationError("give dt_s > 0 (the sample interval in s) or time_s")
    return np.arange(n) * float(dt_s), float(dt_s)


#: Default tolerance of the periodic steady state in m: the position over a period
#: from the state found differs from that over the next period by at most this.
STEADY_STATE_TOL_M = 1e-9
#: Default most periods simulated to find the state of a record that starts in
#: periodic steady state.
MAX_WARMUP_PERIODS = 256
#: Degree of the interpolating spline that reconstructs a band-limited input that is
#: not declared periodic (odd, so its knots sit on the samples).
SPLINE_DEGREE = 9

_FINE: dict[tuple, np.ndarray] = {}  # reconstructed inputs, keyed by content
_FINE_MAX = 8


def _fine_periodic(u: np.ndarray, substeps: int) -> np.ndarray:
    """Trigonometric interpolation of ``u`` (period: its whole length) at ``substeps``
    points per sample interval; ``(..., n * substeps)``, exact for a periodic input
    without content at the Nyquist frequency."""
    n = u.shape[-1]
    spec = np.fft.rfft(u, axis=-1)
    fine = np.zeros((*u.shape[:-1], n * substeps // 2 + 1), dtype=complex)
    fine[..., : n // 2 + 1] = spec
    if n % 2 == 0:  # the Nyquist line is a cosine: split it between +- fs / 2
        fine[..., n // 2] *= 0.5
    return np.fft.irfft(fine, n * substeps, axis=-1) * substeps


def _fine_spline(u: np.ndarray, substeps: int) -> np.ndarray:
    """Degree-``SPLINE_DEGREE`` interpolating spline of ``u`` at ``substeps`` points per
    sample interval, ``(..., (n - 1) * substeps + 1)``; not-a-knot ends."""
    from scipy.interpolate import make_interp_spline

    n = u.shape[-1]
    degree = min(SPLINE_DEGREE, n - 1)
    degree -= 1 - degree % 2  # odd
    spline = make_interp_spline(np.arange(n, dtype=float), u, k=degree, axis=-1)
    return spline(np.arange((n - 1) * substeps + 1) / substeps)


def _fine_input(u: np.ndarray, substeps: int, periodic: bool) -> np.ndarray:
    """Band-limited reconstruction of ``u`` at every substep boundary, memoised by
    content (a likelihood simulates the same input many times)."""
    key = (fingerprint(u.tobytes(), str(u.shape), length=20), substeps, periodic)
    with _LOCK:
        hit = _FINE.get(key)
    if hit is not None:
        return hit
    n = u.shape[-1]
    if substeps == 1:
        fine = u.copy()
    elif periodic:
        fine = _fine_periodic(u, substeps)[..., : (n - 1) * substeps + 1]
    else:
        fine = _fine_spline(u, substeps)
    fine[..., ::substeps] = u  # the samples themselves, not their rounding
    fine.flags.writeable = False
    with _LOCK:
        if len(_FINE) >= _FINE_MAX:
            _FINE.pop(next(iter(_FINE)))
        _FINE[key] = fine
    return fine


def _kernel_input(u: np.ndarray, substeps: int, between_samples: str, period: int | None,
                  warmup: int) -> np.ndarray:
    """The array the kernel reads: the samples, or the band-limited reconstruction at
    every substep boundary; preceded by ``warmup`` copies of the first period."""
    if between_samples != "bandlimited":
        if warmup:
            u = np.concatenate([np.tile(u[..., :period], warmup), u], axis=-1)
        return u
    if not warmup:
        return _fine_input(u, substeps, period is not None)
    one = _fine_periodic(u[..., :period], substeps) if substeps > 1 else u[..., :period]
    # the record is the same periodic signal (whole periods, or one period and its next
    # sample): the period's reconstruction, repeated
    m = (u.shape[-1] - 1) * substeps + 1
    fine = np.tile(one, (1,) * (u.ndim - 1) + (-(-m // one.shape[-1]),))[..., :m]
    fine[..., ::substeps] = u
    return np.concatenate([np.tile(one, warmup), fine], axis=-1)


def _check_period(period_samples, steady_state, n: int) -> int | None:
    if not isinstance(steady_state, bool | np.bool_):
        raise SimulationError(f"steady_state must be True or False, got {steady_state!r}")
    if period_samples is None:
        if steady_state:
            raise SimulationError(
                "steady_state=True needs period_samples (the samples in one period of the "
                "periodic input): a steady state exists only for a periodic input")
        return None
    if not (isinstance(period_samples, int | np.integer) and not isinstance(period_samples, bool)
            and period_samples >= 2):
        raise SimulationError(
            f"period_samples must be an integer >= 2 (samples in one period), got "
            f"{period_samples!r}")
    if n % period_samples:
        raise SimulationError(
            f"period_samples={period_samples} does not divide the input's {n} samples "
            f"({n / period_samples:.4g} periods); pass whole periods only")
    return int(period_samples)


def simulate(
    model: Model,
    params=None,
    input_signal=None,
    *,
    dt_s: float | None = None,
    time_s: np.ndarray | None = None,
    substeps: int = 1,
    states: bool = False,
    between_samples: str = "hold",
    period_samples: int | None = None,
    steady_state: bool = False,
    steady_state_tol_m: float = STEADY_STATE_TOL_M,
    max_warmup_periods: int = MAX_WARMUP_PERIODS,
    initial_state: str = "rest",
    initial_values=None,
):
    """Simulate ``model`` for a batch of parameter sets.

    Parameters
    ----------
    model : Model
        The composed model.
    params : mapping or array, optional
        Parameters, as accepted by :meth:`Model.theta` (defaults if None). A batch
        of ``B`` parameter sets gives ``B`` simulations.
    input_signal : array_like
        Commanded pressure in Pa (force in N for a force-driven rig), shape
        ``(n_samples,)`` shared by the batch or ``(B, n_samples)``.
    dt_s : float, optional
        Sample interval in s (or give ``time_s``).
    time_s : array_like, optional
        Uniform sample times, shape ``(n_samples,)``.
    substeps : int
        Integration steps per sample interval (the input is held, or interpolated
        after pressure effects). 1 is accurate to better than 1e-6 m for the PMA at
        1 kHz. A lightly damped oscillator whose hysteretic stiffness is comparable
        to its spring and whose response nears the sample rate needs more. The error
        falls as ``substeps**-2``; see the README.
    states : bool
        Return a :class:`Simulation` with all recorded states instead of positions.
    between_samples : str
        What the input does between samples (see :data:`BETWEEN_SAMPLES`):
        ``"hold"`` (the default: a DAQ's zero-order hold of a commanded pressure,
        each sample acting until the next); ``"linear"`` (straight lines between
        samples); or ``"bandlimited"`` (the samples of a continuous band-limited
        signal, such as a measured pressure or a generated multisine). A
        band-limited input is reconstructed at every substep boundary, and each
        substep takes the straight line between two of those values: by
        trigonometric (FFT) interpolation of the record when ``period_samples`` is
        given (exact for a periodic input), otherwise by a degree-9 interpolating
        spline with not-a-knot ends (near the first and last few samples it is the
        polynomial through the end samples, less accurate than inside). Give it
        substeps: with ``substeps=1`` it is ``"linear"``. With pressure effects or
        per-member inputs the kernel keeps the reconstruction per member (16 bytes
        per substep and member).
    period_samples : int, optional
        Samples in one period, when the input is whole periods of a periodic signal
        (it must divide ``n_samples``). Used by ``"bandlimited"`` and
        ``steady_state``.
    steady_state : bool
        The record starts in periodic steady state of its first period, repeated
        (reached from ``initial_state``): the record starts from that state, after
        one period that settles the pressure effects. False (default): the record
        starts from ``initial_state``.
    steady_state_tol_m : float
        Tolerance of the steady state in m (default :data:`STEADY_STATE_TOL_M`): the
        position over a period from the state found differs from that over the next
        period by at most this.
    max_warmup_periods : int
        Most periods simulated to find the steady state (default
        :data:`MAX_WARMUP_PERIODS`). It is found by Newton's method on the period map
        (the state after one period from a state at the period's start), a few
        steps of ``rows + 2`` periods each, where simulating period after period
        from rest needs as many periods as the transient is slow (the muscle's
        hysteresis shakes down by about 0.84 a period, slower on short periods). If
        the tolerance is not reached, a :class:`SteadyStateWarning` says by how much,
        and the record starts from the last state.
    initial_state : str
        The state each trial (or its warm-up, with ``steady_state``) starts from (see
        :data:`INITIAL_STATES`): ``"rest"`` (the default: ``x' = 0``, ``z = 0`` and
        ``x`` at static equilibrium under the first input sample, as after a long
        hold of it) or ``"zero"`` (``x = x' = z = 0`` whatever the first input: a
        plant at rest at zero input that the input switches on at the first sample,
        as the Bouc-Wen benchmark's simulations start) or ``"estimate"`` (the state
        ``initial_values`` gives). Pressure effects start as under ``"rest"``.
    initial_values : array_like, optional
        With ``initial_state="estimate"`` (and only then): each member's start,
        ``(3,)`` shared or ``(B, 3)``: the position in m (before measurement effects),
        the velocity in m/s, and the hysteretic force ``z`` in N as an offset from the
        balance at that position and velocity (the ``z`` at which the actuator, spring,
        damper and force effects leave no acceleration; 0 starts from that balance);
        then, optionally, ``(3 + k,)`` or ``(B, 3 + k)``, the ``k`` effects' own states
        (:func:`~pmabayes.model.codegen.state_effects`: each force effect with a state,
        then a hysteresis law with one, such as the dissipated energy of a degrading
        law), which otherwise start at 0, their value at rest.

    Returns
    -------
    numpy.ndarray or Simulation
        Positions in m, shape ``(B, n_samples)``; or the recorded states.

    Raises
    ------
    SimulationError
        On inconsistent shapes, a bad time axis, non-finite inputs or a bad period.
    ModelError
        On bad parameters (unknown names, out of bounds).

    Examples
    --------
    The paper's model with a 45 ms regulator lag, driven by a 1 Hz pressure cycle
    sampled at 1 kHz; then three lags at once, as a batch:

    >>> import numpy as np
    >>> import pmabayes
    >>> model = pmabayes.Model(["regulator_lag"])
    >>> t = np.arange(2000) * 1e-3
    >>> pressure_pa = 2e5 * (1 - np.cos(2 * np.pi * t))
    >>> x = pmabayes.simulate(model, {"tau_reg": 0.045}, pressure_pa, dt_s=1e-3)
    >>> x.shape
    (1, 2000)
    >>> round(float(x.max()) * 1e3, 1)  # mm
    74.1
    >>> x = pmabayes.simulate(model, {"tau_reg": [0.0, 0.045, 0.09]}, pressure_pa, dt_s=1e-3)
    >>> (x.max(axis=1) * 1e3).round(1)  # the longer the lag, the less the rise
    array([75.4, 74.1, 71. ])
    """
    if input_signal is None:
        raise SimulationError("input_signal is required (pressure in Pa or force in N)")
    if between_samples not in BETWEEN_SAMPLES:
        raise SimulationError(
            f"between_samples must be one of {', '.join(map(repr, BETWEEN_SAMPLES))}, got "
            f"{between_samples!r}")
    if not (isinstance(substeps, int | np.integer) and substeps >= 1):
        raise SimulationError(f"substeps must be an integer >= 1, got {substeps!r}")
    _check_initial_state(initial_state)
    theta = model.theta(params)
    u = np.asarray(input_signal, dtype=float)
    if not (u.ndim == 1 or (u.ndim == 2 and u.shape[0] == theta.shape[0])):
        raise SimulationError(
            f"input_signal has shape {u.shape}; expected (n_samples,) or "
            f"({theta.shape[0]}, n_samples) for a batch of {theta.shape[0]}"
        )
    if not np.all(np.isfinite(u)):
        raise SimulationError("input_signal contains NaN or inf")
    n = u.shape[-1]
    if n < 2:
        raise SimulationError("need at least 2 samples")
    if steady_state:
        if not steady_state_tol_m > 0:
            raise SimulationError(f"steady_state_tol_m must be > 0, got {steady_state_tol_m!r}")
        if not (isinstance(max_warmup_periods, int | np.integer) and max_warmup_periods >= 3):
            raise SimulationError(
                f"max_warmup_periods must be an integer >= 3, got {max_warmup_periods!r}")
    t, dt = _time_axis(n, dt_s, time_s)
    init = _initial_values(initial_state, initial_values, theta.shape[0], steady_state,
                           model)
    return _simulate_on_grid(model, theta, u, t, dt, substeps=int(substeps), states=states,
                             between_samples=between_samples,
                             period=_check_period(period_samples, steady_state, n),
                             steady_state=steady_state, steady_state_tol_m=steady_state_tol_m,
                             max_warmup_periods=max_warmup_periods,
                             initial_state=initial_state, init=init)


def _initial_values(initial_state: str, values, batch: int, steady_state: bool,
                    model: Model) -> np.ndarray | None:
    """The kernel's ``init`` ``(3 + k, batch)`` for a given start, checked (``k``: the
    model's effect states, :func:`~pmabayes.model.codegen.state_effects`; 0 where only
    three values are given); None otherwise."""
    if initial_state != "estimate":
        if values is not None:
            raise SimulationError(
                f"initial_values are the start of initial_state='estimate'; with "
                f"initial_state={initial_state!r} the start is fixed: leave them out")
        return None
    if steady_state:
        raise SimulationError("initial_state='estimate' gives the record's start, which a "
                              "steady state would replace: use one or the other")
    if values is None:
        raise SimulationError(
            "initial_state='estimate' needs initial_values: (position m, velocity m/s, "
            "z offset N) per member, (3,) or (batch, 3)")
    states = [e.state for e in state_effects(model)]
    cols = 3 + len(states)
    v = np.asarray(values, dtype=float)
    if v.ndim in (1, 2) and v.shape[-1] == 3 and states:  # the effects' states at rest
        v = np.concatenate([v, np.zeros(v.shape[:-1] + (len(states),))], axis=-1)
    if v.shape == (cols,):
        v = np.broadcast_to(v, (batch, cols))
    if v.shape != (batch, cols):
        if not states:
            raise SimulationError(f"initial_values must be 3 values, or ({batch}, 3) for a "
                                  f"batch of {batch}; got shape {v.shape}")
        named = "position, velocity and z offset" + "".join(f", {n}" for n in states)
        raise SimulationError(f"initial_values must be 3 or {cols} values ({named}), or "
                              f"({batch}, 3 or {cols}) for a batch of {batch}; got shape "
                              f"{v.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if bad.size:
        shown = ", ".join(str(i) for i in bad[:10]) + (", ..." if bad.size > 10 else "")
        raise SimulationError(
            f"initial_values must be finite: {bad.size} of {batch} rows are not (rows "
            f"{shown}; first {v[bad[0]].tolist()} as position m, velocity m/s, z offset N"
            + "".join(f", {n}" for n in states) + ")")
    return np.ascontiguousarray(v.T)


def _simulate_on_grid(model: Model, theta: np.ndarray, u: np.ndarray, t: np.ndarray,
                      dt: float, *, substeps: int, states: bool, between_samples: str,
                      period: int | None, steady_state: bool, steady_state_tol_m: float,
                      max_warmup_periods: int, initial_state: str,
                      init: np.ndarray | None = None):
    """:func:`simulate` on a checked input and time grid (the data set's own, checked
    when it was made: the sampler calls this thousands of times)."""
    run = dict(model=model, theta=theta, u=u, t=t, dt=dt, substeps=substeps,
               between_samples=between_samples, period=period, initial_state=initial_state)
    if init is not None:  # a given start (never with a steady state)
        run["init"] = init
    if not steady_state:
        return _run(**run, states=states)
    start = _steady_state(run, float(steady_state_tol_m), int(max_warmup_periods))
    # the record from the periodic state, after one period that settles the pressure path
    return _run(**run, states=states, lead=1, state=start)


#: The early stop of a steady-state search that cannot settle (:func:`_steady_state`): a
#: member whose change over a period has shrunk by a steady ratio (within this factor
#: of each other) over this many iterations, and which at its fastest ratio would need
#: more than this multiple of the budget, gives up. Chosen on the searches of 2800
#: parameter sets around the plausible muscle (a 1 Hz sine, 5000 samples a period):
#: no member that settles within the budget gives up; the others cost about half.
TREND_ITERATIONS, TREND_SPREAD, TREND_MARGIN = 6, 1.1, 2.0


def _beyond_budget(trail: np.ndarray, used: int, budget: int, tol: float, cost: int
                   ) -> np.ndarray:
    """Which members' changes (``trail``: ``(TREND_ITERATIONS + 1, members)``, the last
    iterations' changes, the newest last; NaN before a member's first) have shrunk by
    a steady ratio and project beyond :data:`TREND_MARGIN` times the budget, at the
    fastest ratio seen and ``cost`` periods an iteration."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = trail[1:] / trail[:-1]
        fastest, slowest = ratio.min(axis=0), ratio.max(axis=0)
        steady = np.all(np.isfinite(ratio), axis=0) & (slowest <= TREND_SPREAD * fastest)
        needed = np.where(fastest < 1.0, np.log(tol / trail[-1]) / np.log(fastest), np.inf)
    return steady & (used + needed * cost > TREND_MARGIN * budget)


def _steady_state(run: dict, tol: float, budget: int) -> np.ndarray:
    """The state at the start of a period in periodic steady state, ``(rows, B)``.

    Newton's method on the period map ``P`` (the state after one period from a state
    at the period's start): from the state after one period from rest, each step
    solves ``(I - J) ds = P(s) - s`` with ``J`` the map's Jacobian by finite
    differences (one period per state row, the batch side by side). A member is
    done when its position over a period differs from that over the period before
    by at most ``tol``. This finds the state in a few steps where simulating period
    after period needs as many as the transient is slow (the muscle's hysteresis
    shakes down by a factor of about 0.84 a period, slower on short periods). A
    member whose step does not shrink its change is advanced period by period
    instead. ``budget`` bounds the periods simulated per member (Newton's steps
    count ``rows + 2`` each). A member whose change has shrunk by a steady ratio
    over :data:`TREND_ITERATIONS` steps, too slowly to settle within
    :data:`TREND_MARGIN` times the budget (a change that stays put: a drift that
    has no periodic state), stops there. A member that did not settle starts the
    record from its last state, and a :class:`SteadyStateWarning` counts them (one
    for a whole command within :func:`collect_steady_state_misses`).
    """
    period = run["period"]
    batch = run["theta"].shape[0]
    state = _periods(run, None, np.arange(batch))[1]
    rows = state.shape[0]
    change = np.full(batch, np.inf)
    previous = np.full(batch, np.inf)
    trail = np.full((TREND_ITERATIONS + 1, batch), np.nan)
    gave_up = np.zeros(batch, dtype=bool)
    left = np.arange(batch)
    used = 1
    while left.size and used + 2 <= budget:
        s0 = state[:, left]
        x1, s1 = _periods(run, s0, left)
        x2, s2 = _periods(run, s1, left)
        used += 2
        delta = np.max(np.abs(x2 - x1), axis=1)
        change[left] = delta
        trail[:-1] = trail[1:]
        trail[-1] = np.nan
        trail[-1, left] = delta
        going = (delta > tol) & np.isfinite(delta)  # a failed simulation stops too
        # one that cannot settle in time stops here, from its last state
        hopeless = going & _beyond_budget(trail[:, left], used, budget, tol, rows + 2)
        gave_up[left[hopeless]] = True
        going &= ~hopeless
        state[:, left] = np.where(going, s0, s2)  # a settled member starts at P(P(s))
        left, s0, s1, s2, delta = (left[going], s0[:, going], s1[:, going], s2[:, going],
                                   delta[going])
        if not left.size:
            break
        if used + rows + 2 > budget:  # no budget for a Newton step: one plain one
            state[:, left] = s2
            continue
        residual = s1 - s0  # P(s) - s
        h = 1e-7 * (np.abs(s0) + np.abs(residual)) + 1e-15
        perturbed = np.repeat(s0[:, None, :], rows, axis=1)  # (rows, rows, members)
        for j in range(rows):
            perturbed[j, j] += h[j]
        pj = _periods(run, perturbed.reshape(rows, -1), np.tile(left, rows))[1]
        used += rows
        jac = (pj.reshape(rows, rows, -1) - s1[:, None, :]) / h[None, :, :]
        step = residual.copy()
        for m in range(left.size):  # Newton: (I - J) ds = P(s) - s
            try:
                step[:, m] = np.linalg.solve(np.eye(rows) - jac[:, :, m], residual[:, m])
            except np.linalg.LinAlgError:
                pass
        step[:, ~np.all(np.isfinite(step), axis=0)] = 0.0
        # a member whose last Newton step did not halve its change goes on from
        # P(P(s)) instead (plain iteration), then tries Newton again
        stalled = delta > 0.5 * previous[left]
        previous[left] = delta
        state[:, left] = np.where(stalled, s2, s0 + step)
    missed = ~(change <= tol)
    if missed.any():
        finite = change[missed & np.isfinite(change)]
        _miss(SteadyMisses(batch, int(missed.sum()), int((gave_up & missed).sum()),
                           float(finite.max()) if finite.size else np.nan, budget, period,
                           tol))
    return state


@dataclass
class SteadyMisses:
    """A tally of members whose periodic steady state was not found (see
    :func:`collect_steady_state_misses`)."""

    members: int
    missed: int
    gave_up: int
    worst_m: float
    budget: int
    period: int
    tol: float

    def add(self, other: SteadyMisses) -> None:
        """Count ``other``'s members in this tally."""
        self.members += other.members
        self.missed += other.missed
        self.gave_up += other.gave_up
        self.worst_m = float(np.fmax(self.worst_m, other.worst_m))
        self.budget, self.period, self.tol = other.budget, other.period, other.tol

    def message(self) -> str:
        """What the warning says."""
        early = (f" ({self.gave_up} of them stopped before: their change shrank too slowly "
                 f"to settle within {TREND_MARGIN:g} times that, or not at all, a drift "
                 "from period to period)" if self.gave_up else "")
        worst = ("" if not np.isfinite(self.worst_m) else
                 f"; the position over the last period still changed by up to "
                 f"{self.worst_m:.3g} m")
        return (f"simulate: {self.missed} of {self.members} parameter sets found no periodic "
                f"steady state within {self.tol:g} m after {self.budget} warm-up periods of "
                f"{self.period} samples{early}{worst}. They start from their last state; "
                "raise max_warmup_periods or steady_state_tol_m (the data's sidecar, or "
                "pmabayes fit --max-warmup-periods / --steady-state-tol) if the fitted ones "
                "are among them.")


_COLLECTING: list = []  # [(pid, SteadyMisses or None)] while collect_steady_state_misses runs
_ONCE_IN_WORKER = [False]


def _miss(tally: SteadyMisses) -> None:
    """Say, or count, a steady-state search's members that did not settle."""
    with _LOCK:
        if _COLLECTING and _COLLECTING[-1][0] == os.getpid():
            pid, total = _COLLECTING[-1]
            if total is None:
                _COLLECTING[-1] = (pid, tally)
            else:
                total.add(tally)
            return
        # a forked worker of a collecting command: said once in this process
        if _COLLECTING:
            if _ONCE_IN_WORKER[0]:
                return
            _ONCE_IN_WORKER[0] = True
    warnings.warn(tally.message(), SteadyStateWarning, stacklevel=4)


@contextlib.contextmanager
def collect_steady_state_misses():
    """Count the members that find no periodic steady state, and say so once, at the end.

    Within it, :func:`simulate` does not warn for each batch whose members did not
    settle; one :class:`SteadyStateWarning` at the end counts them all (the command
    line runs every command within it). A worker process forked within it says so
    once itself.

    Yields
    ------
    None
    """
    with _LOCK:
        _COLLECTING.append((os.getpid(), None))
    try:
        yield
    finally:
        with _LOCK:
            tally = _COLLECTING.pop()[1]
        if tally is not None:
            warnings.warn(tally.message(), SteadyStateWarning, stacklevel=3)


def _periods(run: dict, state: np.ndarray | None, members: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Positions over the first period of the input from ``state`` (rest where None),
    after a lead period for the pressure path, and the state after it, for the batch
    members ``members``."""
    period = run["period"]
    u = run["u"]
    u = u[:period] if u.ndim == 1 else u[members, :period]
    # the period and the next one's first sample: the state at the next period's start
    u = np.ascontiguousarray(np.concatenate([u, u[..., :1]], axis=-1))
    sub = dict(run, theta=np.ascontiguousarray(run["theta"][members]), u=u,
               t=run["t"][0] + run["dt"] * np.arange(period + 1))
    x, final = _run(**sub, states=False, lead=1, state=state, periodic_input=True)
    return x[:, :period], final


def _run(*, model: Model, theta: np.ndarray, u: np.ndarray, t: np.ndarray, dt: float,
         substeps: int, states: bool, between_samples: str, period: int | None,
         initial_state: str = "rest", lead: int = 0, state: np.ndarray | None = None,
         periodic_input: bool = False, init: np.ndarray | None = None):
    """One kernel call over the record, after ``lead`` periods of its first period that
    only drive the pressure path.

    Returns the positions ``(B, n)`` (or the :class:`Simulation`) of the record; with a
    lead, the plant starts after it from ``state`` (``(rows, B)``; rest where None),
    and for ``periodic_input`` (the input is whole periods) ``(positions, final
    state)``.
    """
    n = u.shape[-1]
    p_in = _kernel_input(u, substeps, between_samples, period, lead)
    shared = u.ndim == 1
    p_in = np.ascontiguousarray(p_in[:, None] if shared else p_in)
    ahead = lead * (period or 0)
    if ahead:
        t = np.concatenate([t[0] + dt * np.arange(-ahead, 0), t])
    rig = model.rig
    batch = theta.shape[0]
    out_x = np.zeros((n + ahead, batch)) if lead else np.empty((n + ahead, batch))
    args = (theta, p_in, t, dt, substeps, rig.moving_mass_kg, rig.gravity_force_n,
            rig.area_m2, *(() if init is None else (init,)), out_x)
    kernel = dict(shared_input=shared, between_samples=between_samples,
                  initial_state=initial_state, resume=bool(lead))
    rows = state_rows(model) if lead else 0
    io = (np.array(state, dtype=float, order="C") if state is not None
          else np.zeros((rows, batch)))
    extra = (io, ahead, state is None) if lead else ()
    if not states:
        compiled = kernel_for(model, **kernel)
        chunks = _member_chunks(batch, n + ahead)
        if len(chunks) == 1:
            compiled(*args, *extra)
        else:
            out_x, io = _run_in_threads(compiled, chunks, args, extra, shared,
                                        init is not None)
        _say_overflow(model, theta, dt / substeps, out_x[-1])
        x = out_x.T[:, ahead:]
        return (x, io) if periodic_input else x
    rec = [np.zeros((n + ahead, batch)) for _ in range(5)]
    kernel_for(model, record=True, **kernel)(*args, *rec, *extra)
    _say_overflow(model, theta, dt / substeps, out_x[-1])
    v, z, p, f, true_x = (a.T[:, ahead:] for a in rec)
    return Simulation(t[ahead:], out_x.T[:, ahead:], true_x, v, z, p, f)


#: A batch is simulated in threads only where each thread gets at least this many
#: members and this many member-samples: below that, starting the threads costs more
#: than it saves (a thread's start and join take some 50 us; a member-sample some 20 ns).
_THREAD_MEMBERS, _THREAD_WORK = 4, 200_000

_POOL: list = [None, 0, 0]  # the simulation threads' executor, its size, its process
_POOL_LOCK = threading.Lock()
_THREAD_PREFIX = "pmabayes-simulate"


def simulation_threads() -> int:
    """How many threads a large batch of members is simulated in.

    The threads never change the numbers: a batch is split into runs of members by its
    size and the machine's cores alone (:func:`_member_chunks`), and the runs are shared
    out between the threads. The cores this process may
    use (:func:`pmabayes.util.local_cores`), or ``$PMABAYES_THREADS`` where set. In a
    worker process (the sampler's ensembles, a batch's fits, the refits of ``diagnose``)
    the cores its busy siblings leave, shared evenly (:func:`pmabayes.util.busy_workers`):
    one while they all run, more for the last tasks of an uneven batch; one in any
    other child process.

    Returns
    -------
    int
        At least 1.
    """
    env = os.environ.get("PMABAYES_THREADS")
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            raise SimulationError(f"PMABAYES_THREADS must be a whole number >= 1, got "
                                  f"{env!r}") from None
    if multiprocessing.parent_process() is not None:
        busy = busy_workers()
        return 1 if busy is None else max(1, local_cores() // busy)
    return local_cores()


def _member_chunks(batch: int, samples: int) -> list[tuple[int, int]]:
    """The batch's members split into contiguous runs, one per core this process may use
    (one run where threads would not pay).

    The split depends on the batch, its length and the machine's cores, never on how
    many threads run it now (:func:`simulation_threads`): a kernel whose member loop LLVM
    vectorises may round a member differently in the loop's vector body than in its
    remainder, so the split is part of the numbers and must not follow the load."""
    k = min(local_cores(), batch // _THREAD_MEMBERS, (batch * samples) // _THREAD_WORK)
    if k <= 1:
        return [(0, batch)]
    edges = np.linspace(0, batch, k + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _executor(k: int):
    """The process's simulation threads (made once, again after a fork)."""
    with _POOL_LOCK:
        pool, size, pid = _POOL
        if pool is None or pid != os.getpid() or size < k:
            pool = concurrent.futures.ThreadPoolExecutor(
                max_workers=k, thread_name_prefix=_THREAD_PREFIX)
            _POOL[:] = [pool, k, os.getpid()]
        return pool


def side_by_side(fn, parts: list) -> list:
    """``[fn(part) for part in parts]``, the parts in threads (:func:`simulation_threads`
    of them at most) where there are several: for compiled kernels that release the GIL,
    each part its own arithmetic, so that the results are those of one call after
    another, to the bit.

    Parameters
    ----------
    fn : callable
        Called once per part.
    parts : list
        Its arguments.

    Returns
    -------
    list
        The results, in the order of ``parts``.
    """
    k = min(len(parts), simulation_threads())
    # one of the threads itself (fn simulating again) waits for none: no deadlock
    if k <= 1 or threading.current_thread().name.startswith(_THREAD_PREFIX):
        return [fn(p) for p in parts]
    pool = _executor(k)
    # k threads at most, each running every k-th part in turn
    groups = [pool.submit(lambda i: [fn(p) for p in parts[i::k]], i) for i in range(k)]
    done = [g.result() for g in groups]
    return [done[i % k][i // k] for i in range(len(parts))]


def _run_in_threads(kernel, chunks: list[tuple[int, int]], args: tuple, extra: tuple,
                    shared: bool, has_init: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """One kernel call per run of members, side by side in threads (the kernels release
    the GIL); the positions ``(n, batch)`` and the final state rows put together.

    ``args`` and ``extra`` are the whole batch's (:func:`_run`); each run gets its own
    contiguous slices, since a strided view would compile (and run) another kernel.
    """
    theta, p_in, t, dt, substeps, mass, f_grav, area, *rest = args
    init = rest[0] if has_init else None
    out_x = rest[-1]
    io = extra[0] if extra else None

    def part(a: int, b: int) -> tuple[np.ndarray, np.ndarray | None]:
        own_x = np.empty((out_x.shape[0], b - a)) if not extra else np.zeros(
            (out_x.shape[0], b - a))
        own_io = None if io is None else np.ascontiguousarray(io[:, a:b])
        head = (np.ascontiguousarray(theta[a:b]),
                p_in if shared else np.ascontiguousarray(p_in[a:b]),
                t, dt, substeps, mass, f_grav, area)
        mid = () if init is None else (np.ascontiguousarray(init[:, a:b]),)
        tail = () if io is None else (own_io, *extra[1:])
        kernel(*head, *mid, own_x, *tail)
        return own_x, own_io

    parts = side_by_side(lambda ab: part(*ab), chunks)
    x = np.concatenate([px for px, _ in parts], axis=1)
    if io is not None:
        io[:] = np.concatenate([pio for _, pio in parts], axis=1)
    return x, io


class SteadyStateWarning(RuntimeWarning):
    """The periodic steady state was not reached within the warm-up allowed."""


class OverflowingStepWarning(RuntimeWarning):
    """A parameter set's exact step of the moving mass overflows (said once a process)."""


_OVERFLOW_SAID = [False]


def _say_overflow(model: Model, theta: np.ndarray, h: float, last: np.ndarray) -> None:
    """Warn, once a process, where a member's simulation is not finite because the exact
    step of its mass-spring-damper (:func:`~pmabayes.model.kernels.discretise`, step
    ``h``) overflows: a
    stiffness or damping so large over the moving mass that the step's matrix
    exponential is not finite. ``last`` is the members' final positions."""
    bad = np.flatnonzero(~np.isfinite(last))
    if _OVERFLOW_SAID[0] or not bad.size:
        return
    col = model.rig_columns.get("moving_mass_kg")
    base = BoucWenColumns.of(model)
    coefficients = np.empty(8)
    for i in bad:
        mass = model.rig.moving_mass_kg if col is None else float(theta[i, col])
        damping = float(theta[i, base.d])
        stiffness = float(theta[i, base.k_e] + theta[i, base.alpha])
        discretise(mass, damping, stiffness, h, coefficients)
        if np.all(np.isfinite(coefficients)):
            continue  # non-finite for another reason: the likelihood's -inf covers it
        _OVERFLOW_SAID[0] = True
        warnings.warn(
            f"simulate: a parameter set with damping d = {damping:.4g} N s/m and "
            f"stiffness K_e + alpha = {stiffness:.4g} N/m on a moving mass of {mass:.4g} kg "
            f"has no finite step of {h:.4g} s: its stiffness or damping over the mass "
            "overflows. Such parameter sets simulate to NaN and a likelihood gives them "
            "-inf, so a search or a sampler that steps there moves on; this is news only "
            "where a fit's estimates end near them (said once).",
            OverflowingStepWarning, stacklevel=2)
        return


#: How a data set's positions are referred, as a sidecar's ``position_reference``
#: declares it: ``"absolute"`` (the default: positions from the model's zero, the
#: unloaded length, up to any ``position_offset``) or ``"start"`` (the sensor was
#: zeroed with the actuator at rest at the record's start: the model's position at
#: the first sample is subtracted from its trajectory).
POSITION_REFERENCES = ("absolute", "start")


def warmup_settings(dataset, steady_state_tol_m: float | None = None,
                    max_warmup_periods: int | None = None) -> tuple[float, int]:
    """The periodic steady state's tolerance and warm-up budget for a data set.

    Parameters
    ----------
    dataset : Dataset
        Its sidecar may declare ``steady_state_tol_m`` and ``max_warmup_periods``.
    steady_state_tol_m, max_warmup_periods : optional
        Settings that win over the sidecar's (the command line's).

    Returns
    -------
    tuple
        ``(steady_state_tol_m, max_warmup_periods)``; :data:`STEADY_STATE_TOL_M` and
        :data:`MAX_WARMUP_PERIODS` where neither gives one.

    Raises
    ------
    SimulationError
        For a value that is not a positive number (a whole number >= 3 for the
        budget), naming the file.
    """
    meta = dataset.metadata or {}
    tol = meta.get("steady_state_tol_m", STEADY_STATE_TOL_M) if steady_state_tol_m is None \
        else steady_state_tol_m
    budget = meta.get("max_warmup_periods", MAX_WARMUP_PERIODS) if max_warmup_periods is None \
        else max_warmup_periods
    where = dataset.source or "the data set"
    if isinstance(tol, bool) or not isinstance(tol, int | float) or not tol > 0:
        raise SimulationError(f"{where}: steady_state_tol_m is {tol!r}; it must be a positive "
                              "number of metres (e.g. 1e-9)")
    if isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget < 3:
        raise SimulationError(f"{where}: max_warmup_periods is {budget!r}; it must be a whole "
                              "number of periods, at least 3 (e.g. 256)")
    return float(tol), int(budget)


def position_reference(dataset) -> str:
    """The data set's ``position_reference`` (:data:`POSITION_REFERENCES`), checked.

    Parameters
    ----------
    dataset : Dataset

    Returns
    -------
    str

    Raises
    ------
    SimulationError
        For another value, naming the file and the fix.
    """
    ref = (dataset.metadata or {}).get("position_reference", "absolute")
    if ref not in POSITION_REFERENCES:
        raise SimulationError(
            f"{dataset.source or 'the data set'}: metadata 'position_reference' is {ref!r}; it "
            f"must be one of {', '.join(map(repr, POSITION_REFERENCES))} ('start' where the "
            "sensor was zeroed with the actuator at rest at the record's start)")
    return ref


def simulate_dataset(model: Model, params, dataset, *, substeps: int = 1,
                     states: bool = False, steady_state_tol_m: float | None = None,
                     max_warmup_periods: int | None = None, per_trial: bool = False,
                     initial_values=None):
    """Simulate ``model`` on a data set's input, as the data set declares it.

    The one place where a data set's declarations become simulator options: what
    its input does between samples (:attr:`pmabayes.data.Dataset.input_between_samples`),
    its period (:attr:`~pmabayes.data.Dataset.period_samples`), whether each trial
    starts in periodic steady state
    (:attr:`~pmabayes.data.Dataset.starts_in_steady_state`, with the sidecar's
    ``steady_state_tol_m`` and ``max_warmup_periods``), from which state
    (:attr:`~pmabayes.data.Dataset.initial_state`) and to what its positions are
    referred (``position_reference``, :data:`POSITION_REFERENCES`). The likelihood,
    diagnostics and validation all simulate through it.

    Parameters
    ----------
    model : Model
        The composed model (on the data set's rig).
    params : mapping or array, optional
        Parameters, as accepted by :meth:`Model.theta`.
    dataset : Dataset
        The data: its first trial's input and its time grid are used (repeated
        trials share the input), or with ``per_trial`` every trial's own input.
    substeps : int
        Integration steps per sample interval.
    states : bool
        Return a :class:`Simulation` instead of positions.
    steady_state_tol_m, max_warmup_periods : optional
        The steady state's settings, over the sidecar's (:func:`warmup_settings`).
    per_trial : bool
        Simulate each trial on its own input (trials with measured inputs): ``R``
        trials and ``B`` parameter sets make ``R * B`` simulations, trial-major
        (member ``r * B + b``).
    initial_values : array_like, optional
        For a data set whose start is estimated (``initial_state == "estimate"``):
        ``(B, 3)`` or ``(B, 3 + k)`` starts, as :func:`simulate` takes them (shared by
        the trials).

    Returns
    -------
    numpy.ndarray or Simulation
        As :func:`simulate`, with ``per_trial`` positions ``(B, R, n_samples)`` (a
        :class:`Simulation`'s members stay trial-major); with ``position_reference``
        ``"start"`` the measured positions are relative to the model's at the first
        sample.

    Examples
    --------
    The model on a data set's input and grid, against its trial mean:

    >>> import numpy as np
    >>> from pmabayes import Model
    >>> from pmabayes.model.simulator import simulate_dataset
    >>> from pmabayes.synthetic import example_data
    >>> data = example_data()  # three synthetic 4 s chirps at 200 Hz
    >>> x = simulate_dataset(Model.for_dataset(data), None, data)  # at the paper's values
    >>> x.shape
    (1, 800)
    >>> rms_m = np.sqrt(np.mean((data.position_m.mean(axis=0) - x[0]) ** 2))
    >>> bool(rms_m < 1e-4)  # the noise of the mean of 3 trials, no model error
    True
    """
    if not (isinstance(substeps, int | np.integer) and substeps >= 1):
        raise SimulationError(f"substeps must be an integer >= 1, got {substeps!r}")
    steady = dataset.starts_in_steady_state
    tol, budget = (warmup_settings(dataset, steady_state_tol_m, max_warmup_periods) if steady
                   else (STEADY_STATE_TOL_M, MAX_WARMUP_PERIODS))
    relative = position_reference(dataset) == "start"
    theta = model.theta(params)
    batch = theta.shape[0]
    init = _initial_values(dataset.initial_state, initial_values, batch, steady, model)
    u = dataset.input[0]
    if per_trial:
        trials = dataset.n_trials
        theta = np.tile(theta, (trials, 1))
        u = np.repeat(dataset.input, batch, axis=0)
        init = None if init is None else np.tile(init, (1, trials))
    out = _simulate_on_grid(model, theta, u, dataset.time_s,
                            dataset.grid_dt_s, substeps=int(substeps), states=states,
                            between_samples=dataset.input_between_samples,
                            period=(None if dataset.period_samples is None
                                    else int(dataset.period_samples)),
                            steady_state=steady, steady_state_tol_m=tol,
                            max_warmup_periods=budget, initial_state=dataset.initial_state,
                            init=init)
    if relative:
        if states:
            out = dataclasses.replace(out, position_m=out.position_m - out.position_m[:, :1])
        else:  # in place: the simulation's own array, not copied again (same numbers)
            out -= out[:, :1].copy()
    if not per_trial or states:
        return out
    return out.reshape(trials, batch, -1).transpose(1, 0, 2)
