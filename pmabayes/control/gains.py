"""The gain rule: the best tracking among robustly stable gains, and its disk cache.

:func:`tune_gains` is the one rule (see :mod:`pmabayes.control`);
:func:`nominal_gains` runs it on a nominal model once and caches the result;
:func:`resolve_gains` fills in the gains a caller did not give.
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pmabayes.control.kernel import (
    _GAIN_NAMES,
    CONTROLLERS,
    DEFAULT_GAINS,
    Timing,
    _controller_codes,
    closed_loop_batch,
    gain_array,
)
from pmabayes.control.metrics import period_difference_m, tracking_metrics
from pmabayes.control.operating import (
    ControlError,
    _check_frequency,
    _mean,
    _nominal_model,
    _reference_mean,
    _theta1,
)
from pmabayes.model import boucwen as _boucwen
from pmabayes.model import codegen as _codegen
from pmabayes.model import kernels as _kernels
from pmabayes.model import simulator as _simulator
from pmabayes.model.effects import delay_effect
from pmabayes.model.model import Model, Rig
from pmabayes.model.simulator import cache_dir
from pmabayes.util import Progress, fingerprint, source_text


class GainGridWarning(UserWarning):
    """The gain rule's best gains sit on the edge of its grid.

    Examples
    --------
    A grid too narrow for PID: the best gains are its largest, so it should be widened.

    >>> import warnings
    >>> from pmabayes.control import GainGridWarning, tune_gains
    >>> grid = {"kp": [1e6, 3e6], "ki": [1e7, 3e7], "kd": [0.0]}
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     gains = tune_gains("pid", grid=grid, duration_s=6.0)
    >>> caught[0].category is GainGridWarning
    True
    >>> print(caught[0].message)
    the best pid gains sit on the grid's edge in kp, ki; widen the grid there
    """


def _default_grid(controller: str) -> dict[str, np.ndarray]:
    if controller == "pid":
        return {"kp": np.geomspace(1e5, 1e9, 17), "ki": np.geomspace(1e5, 1e10, 21),
                "kd": np.concatenate([[0.0], np.geomspace(1e2, 1e8, 13)])}
    w = np.geomspace(1.0, 200.0, 24)
    zeta = np.array([0.4, 0.55, 0.7, 0.85, 1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0])
    ww, zz = np.meshgrid(w, zeta, indexing="ij")
    return {"kp": (ww**2).ravel(), "kd": (2 * zz * ww).ravel()}


def _candidates(controller: str, grid: Mapping[str, Sequence[float]]) -> np.ndarray:
    names = _GAIN_NAMES[controller]
    if set(grid) != set(names):
        raise ControlError(f"grid must give {names} for {controller}, got {sorted(grid)}")
    values = [np.asarray(grid[k], dtype=float).ravel() for k in names]
    if any(v.size == 0 or not np.all(np.isfinite(v) & (v >= 0)) for v in values):
        raise ControlError("grid values must be finite, >= 0 and not empty")
    if controller == "pid":  # every combination
        mesh = np.meshgrid(*values, indexing="ij")
        return np.column_stack([m.ravel() for m in mesh])
    if len({v.size for v in values}) != 1:  # computed torque: (kp, kd) pairs
        raise ControlError(f"a computed-torque grid pairs kp[j] with kd[j]: give lists of "
                           f"equal length, got {[v.size for v in values]}")
    return np.column_stack(values)


def _mesh_shape(controller: str, grid: Mapping[str, Sequence[float]],
                cand: np.ndarray) -> tuple[int, ...] | None:
    """Shape of the candidates as a mesh (C order), or None when they form none.

    PID candidates are always the mesh of the ``kp``, ``ki``, ``kd`` lists. Computed
    torque pairs form a mesh when they are every ``(w, zeta)`` combination of some
    lists of natural frequencies and damping ratios, in ``w``-major order (as the
    default grid).
    """
    if controller == "pid":
        return tuple(np.asarray(grid[k], dtype=float).ravel().size for k in _GAIN_NAMES["pid"])
    kp, kd = cand.T
    if np.any(kp <= 0):
        return None
    w = np.sqrt(kp)
    zeta = kd / (2 * w)
    uw = np.unique(np.round(w, 9))
    uz = np.unique(np.round(zeta, 9))
    if uw.size * uz.size != cand.shape[0]:
        return None
    ww, zz = np.meshgrid(uw, uz, indexing="ij")
    if not (np.allclose(ww.ravel(), w, rtol=1e-9) and np.allclose(zz.ravel(), zeta, rtol=1e-9)):
        return None
    return (uw.size, uz.size)


def _neighbours_pass(ok: np.ndarray, shape: tuple[int, ...] | None) -> np.ndarray:
    """``ok`` where the next grid point on either side along every axis is ok too.

    A point at the grid's edge has no neighbour beyond it, which counts as passing
    (the rule warns about a choice on the edge instead).
    """
    if shape is None:
        return ok.copy()
    mesh = ok.reshape(shape)
    out = mesh.copy()
    for ax in range(mesh.ndim):
        n = mesh.shape[ax]
        if n < 2:
            continue
        lo = [slice(None)] * mesh.ndim
        hi = [slice(None)] * mesh.ndim
        lo[ax], hi[ax] = slice(0, n - 1), slice(1, n)
        out[tuple(lo)] &= mesh[tuple(hi)]  # the neighbour above
        out[tuple(hi)] &= mesh[tuple(lo)]  # the neighbour below
    return out.ravel()


def _on_edge(controller: str, cand: np.ndarray, best: np.ndarray) -> list[str]:
    """Names of the best gains that sit on the grid's edge (a zero gain is no edge)."""
    if controller == "pid":
        axes = dict(zip(_GAIN_NAMES["pid"], cand.T, strict=True))
        value = dict(zip(_GAIN_NAMES["pid"], best, strict=True))
    else:  # the pairs' stiffness and damping ratio
        kp, kd = cand.T
        with np.errstate(divide="ignore", invalid="ignore"):
            axes = {"kp": kp, "zeta": np.where(kp > 0, kd / (2 * np.sqrt(kp)), 0.0)}
        value = {"kp": best[0], "zeta": best[1] / (2 * math.sqrt(best[0])) if best[0] else 0.0}
    return [k for k, a in axes.items()  # zeta from (kp, kd) pairs carries rounding
            if np.unique(np.round(a, 9)).size > 1 and value[k] != 0
            and (np.isclose(value[k], a.min(), rtol=1e-9, atol=0)
                 or np.isclose(value[k], a.max(), rtol=1e-9, atol=0))]


def _grid_runs(controller: str, model: Model, theta: np.ndarray, cases: list,
               frequency_hz: float, *, duration_s: float, timing: Timing,
               reference_mean_m: float | None) -> tuple[list, list]:
    """RMS error and period difference of every candidate in every case, in chunks.

    ``cases`` holds ``(plant model, plant theta, gain rows)``; the controller's model
    is always ``model`` at ``theta``. Non-finite RMS errors become inf.
    """
    names = _GAIN_NAMES[controller]
    rms, diff = [], []
    bar = Progress()
    bar.start(sum(len(g) for _, _, g in cases), "runs",
              f"{controller} gains: nominal and margin runs of the grid")
    for plant, theta_p, gains in cases:
        n_cand = len(gains)
        r, d = np.empty(n_cand), np.empty(n_cand)
        for lo in range(0, n_cand, 512):
            sl = slice(lo, min(lo + 512, n_cand))
            b = sl.stop - sl.start
            g = np.zeros((b, 3))
            g[:, :len(names)] = gains[sl]
            run = closed_loop_batch(plant, np.repeat(theta_p, b, axis=0), model,
                                    np.repeat(theta, b, axis=0), np.full(b, frequency_hz),
                                    controller, gains=g, duration_s=duration_s, timing=timing,
                                    reference_mean_m=reference_mean_m, record=False)
            r[sl] = tracking_metrics(run.time_s, run.reference_m, run.position_m,
                                     frequency_hz)["rms_error_m"]
            d[sl] = period_difference_m(run.time_s, run.position_m, frequency_hz)
            bar.advance(b)
        rms.append(np.where(np.isfinite(r), r, np.inf))
        diff.append(d)
    return rms, diff


def _gentlest_best(cand: np.ndarray, ok: np.ndarray, rms: np.ndarray, tie_rtol: float) -> int:
    """Index of the chosen candidate among the qualifying ones.

    RMS errors within ``tie_rtol`` of the best are a tie (the grid's resolution and
    the model's uncertainty do not separate them): the gentlest of them wins, the
    smallest gains in the order of ``_GAIN_NAMES`` (for computed torque kp, then kd).
    """
    best_rms = float(np.min(np.where(ok, rms, np.inf)))
    tied = np.flatnonzero(ok & (rms <= (1.0 + tie_rtol) * best_rms))
    return int(tied[np.lexsort(cand[tied].T[::-1])[0]])


def _delayed_plant(model: Model, theta: np.ndarray, delay_s: float) -> tuple[Model, np.ndarray]:
    """The plant with ``delay_s`` more delay on its pressure path, free or fixed.

    The first of the model's effects that can absorb a delay
    (:meth:`~pmabayes.model.effects.Effect.add_delay`) takes it, in the full parameter
    array (which the closed loop takes as given, fixed values included). A model
    with none gains :func:`pmabayes.model.effects.delay_effect` at its null values.
    """
    out = np.array(theta, dtype=float, copy=True)
    plant = model
    for eff, sl in model.effect_slices():
        q = eff.add_delay(out[:, sl], delay_s)
        if q is not None:
            break
    else:
        eff = delay_effect()
        plant = model.with_effects(eff)
        out = np.repeat(plant.theta(None), theta.shape[0], axis=0)
        for j, name in enumerate(model.parameter_names):
            out[:, plant.index(name)] = theta[:, j]
        for name, value in eff.null_values().items():
            out[:, plant.index(name)] = value
        sl = plant.effect_slices()[-1][1]
        q = eff.add_delay(out[:, sl], delay_s)
    out[:, sl] = q
    plant.check_bounds(out)
    return plant, np.ascontiguousarray(out)


def tune_gains(controller: str, *, model: Model | None = None, params=None,
               frequency_hz: float = 0.5, margin: float = 2.0, delay_margin_s: float = 0.02,
               rms_factor: float = 2.0, settle_tolerance_m: float = 5e-4,
               duration_s: float = 10.0, grid: Mapping[str, Sequence[float]] | None = None,
               timing: Timing | None = None,
               reference_mean_m: float | None = None,
               max_bandwidth_rad_s: float | None = None,
               tie_rtol: float = 0.02) -> dict[str, float]:
    """The documented gain rule: best tracking at 0.5 Hz among robustly stable gains.

    Every gain set on the grid is simulated on the nominal model at ``frequency_hz``,
    then again with every gain multiplied by ``margin`` (a gain margin), and again
    with the nominal gains and ``delay_margin_s`` of extra transport delay in the
    plant (a delay margin; the controller's model, and so its prediction, unchanged).
    A gain set is stable when all three runs reach a periodic steady state (the last
    two periods within ``settle_tolerance_m``, :func:`period_difference_m`) and the
    two perturbed runs' RMS errors are at most ``rms_factor`` times the nominal run's.
    It qualifies when, in addition, its neighbours on the grid (the next value on
    either side along each gain's axis; for computed torque along ``w`` and
    ``zeta``) are stable too, and, for computed torque, when its natural frequency
    ``w = sqrt(kp)`` is at most ``max_bandwidth_rad_s`` (the cap is an edge of the
    grid: points beyond it are not checked as neighbours). Among the qualifying sets
    whose nominal RMS error is within ``tie_rtol`` (2%) of the smallest, the gentlest
    wins: the smallest ``kp``, then ``ki``, then ``kd``.

    Why the two extra conditions: the smallest RMS error lies on the boundary of the
    stable set, so without them a model perturbed in the fourth digit can flip the
    choice (the margins pass or fail by a hair). Requiring the neighbours keeps the
    choice one grid step inside the boundary. And the command is held for
    ``T = command_period_s`` (20 Hz): the hold delays it by ``T / 2`` on average, a
    phase lag ``w T / 2`` at the error dynamics' frequency, which reaches 90 degrees
    at the hold's Nyquist frequency ``pi / T`` (62.8 rad/s), where a sampled loop can
    no longer shape the error at all. The default cap ``pi / (2 T)`` (31.4 rad/s)
    keeps that lag at 45 degrees.

    Parameters
    ----------
    controller : str
        ``"pid"`` or ``"ct"``.
    model : Model, optional
        The nominal model; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters (a mapping, or a full parameter array); the model's defaults
        (the paper's values) by default.
    frequency_hz : float
        Tuning frequency.
    margin : float
        Factor all gains must tolerate (2: 6 dB).
    delay_margin_s : float
        Extra plant delay the gains must tolerate, in s (0 skips the check).
    rms_factor : float
        Largest RMS error of a perturbed run, relative to the nominal run's.
    settle_tolerance_m : float
        Largest difference between the last two periods of every run.
    duration_s : float
        Length of each run.
    grid : mapping of str to sequence of float, optional
        Values per gain. For PID every combination of the ``kp``, ``ki`` and ``kd``
        lists (a mesh); by default ``kp`` 10^5..10^9 Pa/m and ``ki`` 10^5..10^10
        Pa/(m s), 4 values per decade, ``kd`` 0 and 10^2..10^8 Pa s/m, 2 per
        decade. For computed
        torque ``kp[j]`` goes with ``kd[j]`` (pairs; the lists must be of equal
        length); by default ``kp = w^2``, ``kd = 2 zeta w`` for ``w`` 1..200 rad/s (24
        values, geometric) by ``zeta`` 0.4..5 (12 values).
    timing : Timing, optional
        Rates, limits and sensor.
    reference_mean_m : float, optional
        Mean of the reference; :data:`REFERENCE_MEAN_M` by default.
    max_bandwidth_rad_s : float, optional
        Largest natural frequency ``sqrt(kp)`` of computed torque's error dynamics,
        in rad/s; ``pi / (2 command_period_s)`` by default (ignored for PID).
    tie_rtol : float
        RMS errors within this fraction of the smallest count as a tie, which the
        smallest gains win (near the optimum the error is flat, and the exact
        minimum would move with the model's last digits).

    Returns
    -------
    dict of str to float
        The chosen gains, by name.

    Raises
    ------
    ControlError
        If the grid is malformed or no gain set on it qualifies.

    Warns
    -----
    GainGridWarning
        If a chosen gain (for computed torque: ``kp`` or the damping ratio) sits on
        the edge of the grid: the grid should be widened.

    Examples
    --------
    The rule on a small grid of computed torque's gains (the default grid, 288 pairs,
    takes about a minute); its best sits on the grid's edge, which a
    :class:`GainGridWarning` says:

    >>> from pmabayes.control import tune_gains
    >>> tune_gains("ct", grid={"kp": [100.0, 400.0, 900.0], "kd": [20.0, 40.0, 60.0]},
    ...            duration_s=6.0)
    {'kp': 900.0, 'kd': 60.0}
    """
    _controller_codes(controller, 1)
    timing = Timing() if timing is None else timing
    if max_bandwidth_rad_s is None:
        max_bandwidth_rad_s = math.pi / (2 * timing.command_period_s)
    if not (margin >= 1 and delay_margin_s >= 0 and rms_factor >= 1
            and settle_tolerance_m > 0 and max_bandwidth_rad_s > 0 and tie_rtol >= 0):
        raise ControlError("need margin >= 1, delay_margin_s >= 0, rms_factor >= 1, "
                           "settle_tolerance_m > 0, max_bandwidth_rad_s > 0 and "
                           "tie_rtol >= 0")
    frequency_hz = _check_frequency(frequency_hz)
    model = _nominal_model(model)
    grid = _default_grid(controller) if grid is None else grid
    names = _GAIN_NAMES[controller]
    cand = _candidates(controller, grid)
    shape = _mesh_shape(controller, grid, cand)
    theta = _theta1(model, params)
    cases = [(model, theta, cand), (model, theta, margin * cand)]
    if delay_margin_s > 0:
        cases.append((*_delayed_plant(model, theta, delay_margin_s), cand))
    rms, diff = _grid_runs(controller, model, theta, cases, frequency_hz,
                           duration_s=duration_s, timing=timing,
                           reference_mean_m=reference_mean_m)
    stable = np.all([d <= settle_tolerance_m for d in diff], axis=0) & np.isfinite(rms[0])
    for r in rms[1:]:
        stable &= r <= rms_factor * rms[0]
    capped = np.zeros(len(cand), dtype=bool)
    if controller == "ct":
        capped = np.sqrt(cand[:, 0]) > max_bandwidth_rad_s * (1 + 1e-12)
    # the cap is an edge of the grid: a point beyond it is no neighbour to be checked
    ok = _neighbours_pass(stable | capped, shape) & stable & ~capped
    if not ok.any():
        raise ControlError(
            f"no {controller} gains on the grid keep a gain margin of {margin:g} and a delay "
            f"margin of {delay_margin_s:g} s with their grid neighbours"
            + (f" and w <= {max_bandwidth_rad_s:g} rad/s" if controller == "ct" else "")
            + "; widen the grid or relax the margins")
    best = _gentlest_best(cand, ok, rms[0], tie_rtol)
    edge = _on_edge(controller, cand[~capped], cand[best])
    if capped.any() and "kp" in edge and cand[best, 0] >= cand[~capped, 0].max():
        edge.remove("kp")  # stopped by the bandwidth cap, not by the grid
    if edge:
        warnings.warn(f"the best {controller} gains sit on the grid's edge in "
                      f"{', '.join(edge)}; widen the grid there", GainGridWarning, stacklevel=2)
    return {k: float(v) for k, v in zip(names, cand[best], strict=True)}


_RULE_VERSION = "6"  # bump when tune_gains' rule or its defaults change
# the modules whose code the rule runs: the cache key holds their source
_RULE_MODULES = ("pmabayes.control.operating", "pmabayes.control.kernel",
                 "pmabayes.control.metrics", "pmabayes.control.gains", _simulator.__name__,
                 _codegen.__name__, _kernels.__name__, _boucwen.__name__, Model.__module__)


def _gains_cache_path(model: Model, theta: np.ndarray, timing: Timing,
                      reference_mean_m: float) -> Path:
    """Cache file of the rule's gains for one nominal model.

    Keyed by the effects, the rig, the values, the timing, the reference mean, the
    rule's version and the code behind the rule: its modules and the module of
    every effect of the model (a user's effect included).
    """
    code = [source_text(sys.modules[m]) for m in _RULE_MODULES]
    code += [source_text(e) for e in model.effects]
    key = fingerprint({"effects": [f"{e.__module__}.{e.__qualname__}" for e in model.effects],
                       "rig": model.rig.to_dict(), "timing": repr(timing),
                       "mean": float(reference_mean_m), "rule": _RULE_VERSION},
                      theta[0], *code, length=24)
    return cache_dir() / "gains" / f"{key}.json"


def nominal_gains(model: Model | None = None, params=None, *, timing: Timing | None = None,
                  reference_mean_m: float | None = None,
                  cache: bool = True) -> dict[str, dict[str, float]]:
    """Both controllers' gains by :func:`tune_gains` (its defaults) on a nominal model.

    :data:`DEFAULT_GAINS` for the paper's values; for another model (e.g. a fit's
    posterior mean with its effects) the rule is run on it, and the result cached on
    disk (under :func:`pmabayes.model.simulator.cache_dir`, keyed by the model, the values,
    the timing, the reference mean and the code), so each nominal model is tuned once.

    Parameters
    ----------
    model : Model, optional
        The nominal model; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters; the model's defaults by default.
    timing : Timing, optional
        Rates, limits and sensor.
    reference_mean_m : float, optional
        Mean of the reference; :data:`REFERENCE_MEAN_M` by default.
    cache : bool
        Read and write the disk cache.

    Returns
    -------
    dict
        ``{"pid": {...}, "ct": {...}}``.

    Examples
    --------
    On the paper's values the rule's result is :data:`DEFAULT_GAINS`, without tuning:

    >>> from pmabayes.control import DEFAULT_GAINS, nominal_gains
    >>> nominal_gains() == DEFAULT_GAINS
    True
    >>> {name: round(g["kp"], 1) for name, g in nominal_gains().items()}
    {'pid': 5623413.3, 'ct': 632.8}
    """
    model = _nominal_model(model)
    theta = _theta1(model, params)
    timing = Timing() if timing is None else timing
    reference_mean_m = _mean(reference_mean_m)
    paper = Model(rig=Rig.control())
    if (model.effect_names == () and model.rig == paper.rig and not model.fixed
            and np.array_equal(theta, paper.theta(None)) and timing == Timing()
            and reference_mean_m == _reference_mean()):
        return {c: dict(g) for c, g in DEFAULT_GAINS.items()}
    path = _gains_cache_path(model, theta, timing, reference_mean_m)
    if cache and path.is_file():
        return json.loads(path.read_text())
    Progress().say("tuning the PID and computed-torque gains on the nominal model by the "
                   "rule (a grid search; cached after)")
    gains = {c: tune_gains(c, model=model, params=theta, timing=timing,
                           reference_mean_m=reference_mean_m) for c in CONTROLLERS}
    if cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{id(gains)}.tmp")
            tmp.write_text(json.dumps(gains))
            tmp.replace(path)
        except OSError:  # a read-only cache: tune again next time
            pass
    return gains


def resolve_gains(controllers: Sequence[str], gains: Mapping | None = None, *,
                  model: Model | None = None, params=None, timing: Timing | None = None,
                  reference_mean_m: float | None = None) -> dict[str, dict[str, float]]:
    """The gains each controller will use: the given ones over those of the rule.

    A controller whose gains are given in full uses them; one left out, or given in
    part, takes the rest from :func:`nominal_gains` on the nominal model (tuned only
    when needed).

    Parameters
    ----------
    controllers : sequence of str
        The controllers that will run.
    gains : mapping, optional
        ``{"pid": {...}, "ct": {...}}``, in full or in part.
    model, params, timing, reference_mean_m : optional
        The nominal model and what the rule tunes it at, as :func:`nominal_gains`'s.

    Returns
    -------
    dict
        ``{controller: {gain: value}}`` for each controller given, every gain filled in
        (checked by :func:`gain_array`).

    Raises
    ------
    ControlError
        On an unknown controller or gain name, or a bad gain.

    Examples
    --------
    Computed torque's ``kp`` given, its ``kd`` from the rule (on the paper's values,
    :data:`DEFAULT_GAINS`):

    >>> from pmabayes.control import resolve_gains
    >>> gains = resolve_gains(["ct"], {"ct": {"kp": 200.0}})
    >>> gains["ct"]["kp"], round(gains["ct"]["kd"], 1)
    (200.0, 125.8)
    """
    names = tuple(dict.fromkeys(controllers))
    given = {c: dict(g) for c, g in (gains or {}).items()}
    gain_array(names, given)  # checks names and values
    need = [c for c in names if set(given.get(c, {})) != set(_GAIN_NAMES[c])]
    tuned = nominal_gains(model, params, timing=timing,
                          reference_mean_m=reference_mean_m) if need else {}
    out = {c: {**tuned.get(c, {}), **given.get(c, {})} for c in names}
    rows = gain_array(names, out)
    return {c: {k: float(v) for k, v in zip(_GAIN_NAMES[c], rows[i], strict=False)}
            for i, c in enumerate(names)}
