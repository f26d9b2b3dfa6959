"""The closed loop: one compiled kernel, generated from the simulator's plant code
(:class:`pmabayes.model.codegen.PlantCode`).

The kernel runs a batch of loops (plant, encoder, PID or computed torque, the
held regulator command) at the plant's rate; see :mod:`pmabayes.control` for the
rig it simulates. :func:`_generate` writes its source as a short sequence of
blocks: the setup, the controller's tick, the pressure-history block of the
plant's pressure effects, and the plant's step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.control.operating import (
    _PRESSURE_MAX_PA,
    REFERENCE_AMPLITUDE_M,
    ControlError,
    _initial_pressure,
    _mean,
    _nominal_model,
    _value,
    reference_m,
)
from pmabayes.model.codegen import PlantCode, module_text
from pmabayes.model.kernels import cached_kernel, compile_kernel, structure_key
from pmabayes.model.model import ENCODER_COUNTS_PER_M, Model

#: Controller names, in the order used by arrays and datasets.
CONTROLLERS = ("pid", "ct")

#: Gains from :func:`tune_gains` with its defaults on the paper's values. PID: ``kp``
#: in Pa/m, ``ki`` in Pa/(m s), ``kd`` in Pa s/m; computed torque: ``kp`` in 1/s^2,
#: ``kd`` in 1/s.
DEFAULT_GAINS: dict[str, dict[str, float]] = {
    "pid": {"kp": 5623413.251903491, "ki": 56234132.51903491, "kd": 0.0},
    "ct": {"kp": 632.7816954219094, "kd": 125.7757623135226},
}
_GAIN_NAMES = {"pid": ("kp", "ki", "kd"), "ct": ("kp", "kd")}


@dataclass(frozen=True)
class Timing:
    """Rates, limits and sensor of the closed loop (the paper's by default).

    Parameters
    ----------
    plant_dt_s : float
        Plant integration step (1 kHz).
    controller_period_s : float
        Controller period (100 Hz); a whole number of plant steps.
    command_period_s : float
        Period of the regulator's command (20 Hz), held in between; a whole number of
        controller periods.
    pressure_min_pa : float
        Lowest command.
    pressure_max_pa : float
        Highest command (0.9 MPa, the regulator's 10 V).
    encoder_counts_per_m : float
        Encoder resolution; 0 reads the position exactly.
    derivative_filter_s : float
        Time constant of the velocity estimate's first-order filter.

    Examples
    --------
    The paper's loop, and one whose controller runs at 200 Hz with an exact position:

    >>> from pmabayes.control import Timing, closed_loop
    >>> Timing().controller_period_s, Timing().command_period_s
    (0.01, 0.05)
    >>> fast = Timing(controller_period_s=0.005, encoder_counts_per_m=0.0)
    >>> run = closed_loop("ct", 1.0, duration_s=4.0, timing=fast)
    >>> run.metadata["timing"].controller_period_s
    0.005
    """

    plant_dt_s: float = 1e-3
    controller_period_s: float = 0.01
    command_period_s: float = 0.05
    pressure_min_pa: float = 0.0
    pressure_max_pa: float = _PRESSURE_MAX_PA
    encoder_counts_per_m: float = ENCODER_COUNTS_PER_M
    derivative_filter_s: float = 0.01

    def __post_init__(self) -> None:
        if not self.plant_dt_s > 0:
            raise ControlError(f"plant_dt_s must be > 0, got {self.plant_dt_s}")
        for name, base_name in (("controller_period_s", "plant_dt_s"),
                                ("command_period_s", "controller_period_s")):
            value, base = getattr(self, name), getattr(self, base_name)
            ratio = value / base
            if not (value > 0 and abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1):
                raise ControlError(f"{name}={value} must be a whole multiple (>= 1) of "
                                   f"{base_name}={base}")
        if not 0 <= self.pressure_min_pa < self.pressure_max_pa:
            raise ControlError("need 0 <= pressure_min_pa < pressure_max_pa")
        if self.encoder_counts_per_m < 0 or self.derivative_filter_s < 0:
            raise ControlError("encoder_counts_per_m and derivative_filter_s must be >= 0")

    @property
    def steps_per_control(self) -> int:
        """Plant steps per controller period."""
        return int(round(self.controller_period_s / self.plant_dt_s))

    @property
    def steps_per_command(self) -> int:
        """Plant steps per command period."""
        return int(round(self.command_period_s / self.plant_dt_s))


@dataclass(frozen=True)
class ClosedLoop:
    """Recorded closed-loop runs, each array ``(batch, n_samples)`` at the plant rate.

    Parameters
    ----------
    time_s : numpy.ndarray
        Sample times ``(n_samples,)``.
    frequency_hz : numpy.ndarray
        Reference frequency of each run ``(batch,)``.
    controller : tuple of str
        Controller of each run.
    reference_m : numpy.ndarray
        Reference.
    position_m : numpy.ndarray
        True position of the plant (before measurement effects).
    measured_m : numpy.ndarray
        The controller's reading, held between its samples (effects, quantisation).
    command_pa : numpy.ndarray
        Pressure command to the regulator, held between its updates (always recorded).
    controller_output_pa : numpy.ndarray
        Controller output, held between controller samples.
    initial_pressure_pa : numpy.ndarray
        The pressure the plant rests under at the start ``(batch,)``.
    dead_zone_pa : numpy.ndarray
        The plant's dead zone ``p_dz`` of each run ``(batch,)``.
    metadata : dict
        The timing, the gains of each run, the computed torque's prediction time and
        the reference's mean and amplitude.

    Examples
    --------
    >>> from pmabayes.control import closed_loop
    >>> run = closed_loop("pid", 0.5, duration_s=6.0)
    >>> run.controller, run.position_m.shape  # one run of 6 s at 1 kHz
    (('pid',), (1, 6001))
    >>> sorted(run.metadata)
    ['gains', 'prediction_s', 'reference_amplitude_m', 'reference_mean_m', 'timing']
    """

    time_s: np.ndarray
    frequency_hz: np.ndarray
    controller: tuple[str, ...]
    reference_m: np.ndarray
    position_m: np.ndarray
    measured_m: np.ndarray | None
    command_pa: np.ndarray
    controller_output_pa: np.ndarray | None
    initial_pressure_pa: np.ndarray
    dead_zone_pa: np.ndarray
    metadata: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------
# The generated kernel

_ARGS = ("theta_p, theta_c, freq_hz, kind, gains, t_pred, p_init, ref, cfg, steps, "
         "mass, f_grav, area, c_mass, c_f_grav, c_area, dt, window, out_x, out_hold, "
         "out_y, out_u")


def _sensor_inverses(ctrl_model: Model) -> list[tuple[str, type, slice]]:
    """``(injected name, effect, columns)`` of the controller model's invertible sensors.

    Last effect first: the reading is unwound in the reverse of the order the
    measurement effects were applied in.
    """
    out = [(f"_cinv{j}", e, s) for j, (e, s) in enumerate(ctrl_model.effect_slices())
           if e.stage == "measurement" and e.inverse is not None]
    return out[::-1]


def _setup_lines(plant: PlantCode, ctrl: PlantCode, inverses: list, lagged: bool) -> list[str]:
    """Constants, the initial rest state of plant and controller, the history buffers."""
    body = [
        "substeps = 1",
        "n = out_x.shape[0]",
        "batch = theta_p.shape[0]",
        "n_ctrl = steps[0]",
        "n_cmd = steps[1]",
        "t_ctrl = n_ctrl * dt",
        "t_filter = cfg[0]",
        "counts = cfg[1]",
        "p_lo = cfg[2]",
        "p_hi = cfg[3]",
        "w_f = t_ctrl / (t_filter + t_ctrl)",
    ]
    body += plant.setup() + ctrl.setup()
    body += [f"q{name} = theta_c[:, {s.start}:{s.stop}].copy()" for name, _, s in inverses]
    # controller state rows: 0 integral, 1 filtered velocity, 2 observer z, 3 last
    # reading, 4 controller output, 5 held command, then the observed states of the
    # controller model's stateful force effects and its hysteresis law's last factor g
    body += [
        f"st = np.zeros(({plant.n_rows}, batch))",
        f"cs = np.zeros(({6 + len(ctrl.state_row) + (1 if ctrl.law else 0)}, batch))",
        "for i in range(batch):",
        "    p0 = p_init[i]",
    ]
    body += ["    " + ln for ln in plant.rest("p0", "xi")]
    body += [
        "    st[0, i] = xi",
        "    cs[0, i] = p0",
        "    cs[4, i] = p0",
        "    cs[5, i] = p0",
        "ym = np.empty((1, batch))",
        "tt = np.empty(1)",
    ]
    if lagged:
        # raw command history with `wmax` rows of rest before the start. Run i looks
        # back window[i] rows (from its own parameters): the rows of its look-back
        # buffer before that repeat the value at its start, which a pressure effect
        # starting settled there leaves unchanged, so no run depends on its batch.
        body += [
            "wmax = 0",
            "for i in range(batch):",
            "    wmax = max(wmax, window[i])",
            "off = np.empty(batch, dtype=np.int64)",
            "for i in range(batch):",
            "    off[i] = wmax - window[i]",
            "hist = np.empty((wmax + n + n_cmd, batch))",
            "for k in range(wmax):",
            "    hist[k, :] = p_init",
            "wa = np.empty((wmax + n_cmd, batch))",
            "wb = np.empty((wmax + n_cmd, batch))",
            "pw = np.empty((2, n_cmd, batch))",
        ]
    return body


def _reading_lines(inverses: list) -> tuple[list[str], str]:
    """Lines reading the encoder into ``y`` and its increment ``dy``; the position's name.

    Computed torque maps the reading back through its model's sensor inverses
    (into ``xm``, the increment by the inverses' slope); PID reads the sensor as it is.
    """
    lines = [
        "y = ym[0, i]",
        "if counts > 0.0:",
        "    y = np.round(y * counts) / counts",
        "if k == 0:",
        "    cs[3, i] = y",
        "dy = y - cs[3, i]",
        "cs[3, i] = y",
    ]
    if not inverses:
        return lines, "y"
    lines += ["xm = y", "if kind[i] != 0:", "    gm = 1.0"]
    for name, _, _ in inverses:
        lines += [f"    ri = {name}(q{name}[i], t, xm)", "    xm = ri[0]", "    gm *= ri[1]"]
    lines += ["    dy = dy * gm"]
    return lines, "xm"


def _tick_lines(ctrl: PlantCode, inverses: list) -> list[str]:
    """One controller update of run ``i``: reading, velocity, PID or computed torque."""
    tick, position = _reading_lines(inverses)
    tick += [
        "cs[1, i] += w_f * (dy / t_ctrl - cs[1, i])",
        "vh = cs[1, i]",
        "om = 2.0 * np.pi * freq_hz[i]",
        "if kind[i] == 0:",
        "    xr = ref[0] + ref[1] * math.sin(om * t)",
        "    xr_d = ref[1] * om * math.cos(om * t)",
        "    er = xr - y",
        "    integ = cs[0, i] + gains[i, 1] * er * t_ctrl",
        "    u = gains[i, 0] * er + integ + gains[i, 2] * (xr_d - vh)",
        "    if (u > p_hi and er > 0.0) or (u < p_lo and er < 0.0):",
        "        integ = cs[0, i]",  # clamping anti-windup
        "        u = gains[i, 0] * er + integ + gains[i, 2] * (xr_d - vh)",
        "    cs[0, i] = integ",
        "else:",
        "    zo = cs[2, i]",
    ]
    g_last = f"cs[{ctrl.law_row + 3}, i]" if ctrl.law else "0.0"  # rows after the states
    tick += ["    " + ln for ln in ctrl.rate_lines("zo", "dy", g_last)]
    tick += ["    " + ln for ln in ctrl.update_lines("zo", "dy", "zn")]
    tick += [f"    {g_last} = gm"] if ctrl.law else []
    tick += [
        "    cs[2, i] = zn",
        "    tp = t + t_pred[i]",
        "    sn = math.sin(om * tp)",
        "    xr = ref[0] + ref[1] * sn",
        "    xr_d = ref[1] * om * math.cos(om * tp)",
        "    xr_dd = -ref[1] * om * om * sn",
        f"    xh = {position} + vh * t_pred[i]",
        "    acc = xr_dd + gains[i, 1] * (xr_d - vh) + gains[i, 0] * (xr - xh)",
    ]
    # the observer advances the model's force states along the reading, as it does z
    observed = {}
    for e, row in ctrl.state_row.items():
        observed[e] = f"cs[{row + 3}, i]"
        tick += ["    " + ln for ln in ctrl.advance_lines(e, observed[e], f"({position} - dy)",
                                                           position, "t_ctrl", "so")]
        tick += [f"    {observed[e]} = so"]
    tick += ["    " + ln for ln in ctrl.forces("xh", "vh", "cs[5, i]", "fc", False, "zn",
                                                observed)]
    tick += [
        f"    force = (c_mass * acc + {ctrl.col('d')} * vh + {ctrl.col('k_e')} * xh + zn + "
        "c_f_grav + fc)",
        f"    u = force / c_area + {ctrl.dead_zone_pa}",
        "u = p_lo if u < p_lo else (p_hi if u > p_hi else u)",
        "cs[4, i] = u",
    ]
    return tick


def _pressure_history_lines(plant: PlantCode) -> list[str]:
    """At a command update: append the held command, run the pressure effects over it.

    Each run's effects start ``window[i]`` rows back, so ``pw`` holds the pressure
    that acts over the next command period.
    """
    lines = [
        "for j in range(n_cmd):",
        "    for i in range(batch):",
        "        hist[wmax + k + j, i] = cs[5, i]",
        "for j in range(wmax + n_cmd):",
        "    for i in range(batch):",
        "        jj = j if j > off[i] else off[i]",
        "        wa[j, i] = hist[k + jj, i]",
        "        wb[j, i] = hist[k + jj, i]",
    ]
    lines += [f"{plant.name_of[e]}(theta_p[:, {s.start}:{s.stop}], wa, wb, dt)"
              for e, s in plant.pressure]
    lines += [
        "for j in range(n_cmd):",
        "    for i in range(batch):",
        "        pw[0, j, i] = wa[wmax + j, i]",
        "        pw[1, j, i] = wb[wmax + j, i]",
    ]
    return lines


def _plant_step_lines(plant: PlantCode, lagged: bool) -> list[str]:
    """The plant's step over one sample under the acting pressure."""
    lines = []
    if lagged:  # the same interpolation as the open-loop kernel, at fa = 0, fb = 1
        lines += ["jb = k % n_cmd", "fa = 0.0", "fb = 1.0"]
        p_start = "(pw[0, jb, i] + (pw[1, jb, i] - pw[0, jb, i]) * fa)"
        p_end = "(pw[0, jb, i] + (pw[1, jb, i] - pw[0, jb, i]) * fb)"
    else:
        p_start = p_end = "cs[5, i]"
    step = ["x0 = st[0, i]; v0 = st[1, i]; z0 = st[2, i]"]
    step += plant.step(p_start, p_end, "x0", "v0", "z0", "x1", "v1", "z1")
    step += ["st[0, i] = x1; st[1, i] = v1; st[2, i] = z1"]
    return lines + ["for i in range(batch):"] + ["    " + ln for ln in step]


def _loop_lines(plant: PlantCode, ctrl: PlantCode, inverses: list, lagged: bool,
                record: bool) -> list[str]:
    """The time loop: sensor and controller at their rate, the held command, the plant."""
    loop = [
        "for k in range(n):",
        "    t = k * dt",
        "    if k % n_ctrl == 0:",
        "        tt[0] = t",
        "        for i in range(batch):",
        "            ym[0, i] = st[0, i]",
    ]
    loop += [f"        {plant.name_of[e]}(theta_p[:, {s.start}:{s.stop}], tt, ym)"
             for e, s in plant.measure]
    loop += ["        for i in range(batch):"]
    loop += ["            " + ln for ln in _tick_lines(ctrl, inverses)]
    loop += [
        "        if k % n_cmd == 0:",
        "            for i in range(batch):",
        "                cs[5, i] = cs[4, i]",
        "                out_hold[k // n_cmd, i] = cs[5, i]",
    ]
    if lagged:
        loop += ["            " + ln for ln in _pressure_history_lines(plant)]
    loop += ["    for i in range(batch):", "        out_x[k, i] = st[0, i]"]
    if record:
        loop += [
            "        out_y[k, i] = cs[3, i]",
            "        out_u[k, i] = cs[4, i]",
        ]
    loop += ["    if k == n - 1:", "        break"]
    loop += ["    " + ln for ln in _plant_step_lines(plant, lagged)]
    return loop


def _module_text(plant_model: Model, ctrl_model: Model, record: bool, body: list[str],
                 inject: dict) -> str:
    """The generated module: header, imports, injected globals and the kernel."""
    comments = [
        "Generated by pmabayes.control: closed loop, plant effects: "
        f"{', '.join(plant_model.effect_names) or 'none'}; controller model effects: "
        f"{', '.join(ctrl_model.effect_names) or 'none'}; recording: {record}"]
    return module_text(comments, inject, "closed_loop", _ARGS, body)


def _generate(plant_model: Model, ctrl_model: Model, record: bool) -> tuple[str, dict]:
    """Source of the closed-loop kernel and the globals it needs injected."""
    plant = PlantCode(plant_model, theta="theta_p", cst="cst", prefix="_eff")
    ctrl = PlantCode(ctrl_model, theta="theta_c", cst="ccst", prefix="_ceff")
    inverses = _sensor_inverses(ctrl_model)
    inject = {**plant.inject, **ctrl.inject, **{n: e.inverse for n, e, _ in inverses}}
    lagged = bool(plant.pressure)
    body = _setup_lines(plant, ctrl, inverses, lagged)
    body += _loop_lines(plant, ctrl, inverses, lagged, record)
    return _module_text(plant_model, ctrl_model, record, body, inject), inject


def _kernel(plant_model: Model, ctrl_model: Model, record: bool):
    key = ("closed_loop", structure_key(plant_model, False, False),
           structure_key(ctrl_model, False, False), record)
    kernel = cached_kernel(key)
    if kernel is not None:
        return kernel
    text, inject = _generate(plant_model, ctrl_model, record)
    return compile_kernel(key, text, inject, name="closed_loop",
                          what="the closed loop for this model")


# ---------------------------------------------------------------------------------
# Python API


def _controller_codes(controller: str | Sequence[str], batch: int) -> tuple[np.ndarray, tuple]:
    names = (controller,) * batch if isinstance(controller, str) else tuple(controller)
    if len(names) != batch:
        raise ControlError(f"{len(names)} controllers given for a batch of {batch}")
    for c in names:
        if c not in CONTROLLERS:
            raise ControlError(f"unknown controller {c!r}; choose one of {', '.join(CONTROLLERS)}")
    return np.array([CONTROLLERS.index(c) for c in names], dtype=np.int64), names


def gain_array(controllers: Sequence[str], gains: Mapping | None = None) -> np.ndarray:
    """Gain rows ``(len(controllers), 3)`` for the kernel, checked.

    Parameters
    ----------
    controllers : sequence of str
        The controller of each row.
    gains : mapping, optional
        ``{"pid": {"kp": ...}, "ct": {...}}``; gains not given are
        :data:`DEFAULT_GAINS`.

    Returns
    -------
    numpy.ndarray
        Each row the controller's gains in the order of :data:`DEFAULT_GAINS`, zero
        padded.

    Raises
    ------
    ControlError
        On an unknown controller or gain name, or a gain that is negative or not finite.

    Examples
    --------
    >>> from pmabayes.control import ControlError, gain_array
    >>> gains = gain_array(["pid", "ct"], {"ct": {"kp": 400.0}})
    >>> gains.shape, gains[1].round(1)  # computed torque's kp given, kd the default
    ((2, 3), array([400. , 125.8,   0. ]))
    >>> try:
    ...     gain_array(["ct"], {"ct": {"kp": -1.0}})
    ... except ControlError as error:
    ...     print(error)
    gains must be finite and >= 0
    """
    names = tuple(controllers)
    _controller_codes(names, len(names))  # unknown controllers
    table = {c: dict(DEFAULT_GAINS[c]) for c in CONTROLLERS}
    for c, g in (gains or {}).items():
        if c not in CONTROLLERS:
            raise ControlError(f"gains for unknown controller {c!r}; use {CONTROLLERS}")
        unknown = set(g) - set(_GAIN_NAMES[c])
        if unknown:
            raise ControlError(f"unknown {c} gains {sorted(unknown)}; {c} has "
                               f"{', '.join(_GAIN_NAMES[c])}")
        table[c].update({k: float(v) for k, v in g.items()})
    out = np.zeros((len(names), 3))
    for i, c in enumerate(names):
        row = [table[c][k] for k in _GAIN_NAMES[c]]
        out[i, :len(row)] = row
    if not np.all(np.isfinite(out)) or np.any(out < 0):
        raise ControlError("gains must be finite and >= 0")
    return out


def _pressure_memory_steps(model: Model, theta: np.ndarray, dt: float,
                           memory_s: float | None) -> np.ndarray:
    """Look-back of each run's pressure effects in plant steps, ``(batch,)``.

    The sum of the pressure effects' :meth:`~pmabayes.model.effects.Effect.history_s`,
    from each run's own parameters (never the batch's), so that a run's result does
    not depend on the runs it shares a kernel call with.
    """
    batch = theta.shape[0]
    if memory_s is not None:
        mem = np.full(batch, float(memory_s))
    else:
        mem = np.zeros(batch)
        for eff, sl in model.effect_slices():
            if eff.stage == "pressure":
                mem += eff.history_s(theta[:, sl])
    return np.ascontiguousarray(np.ceil(mem / dt).astype(np.int64) + 4)


def _prediction_s(model: Model, theta: np.ndarray, timing: Timing) -> np.ndarray:
    """Computed torque's prediction time per run: half the hold plus the pressure leads.

    The leads (:meth:`~pmabayes.model.effects.Effect.lead_s`) are added in a fixed order,
    by effect name, descending, so that the sum (to its last bit) does not depend on
    the order the model lists its effects in.
    """
    leads = sorted(((e.name, e.lead_s(theta[:, sl])) for e, sl in model.effect_slices()
                    if e.stage == "pressure"), key=lambda item: item[0], reverse=True)
    t_pred = np.full(theta.shape[0], timing.command_period_s / 2)
    for _, lead in leads:
        t_pred = t_pred + lead
    return t_pred


def closed_loop_batch(
    plant_model: Model,
    plant_theta: np.ndarray,
    controller_model: Model,
    controller_theta: np.ndarray,
    frequency_hz: np.ndarray,
    controller: str | Sequence[str],
    *,
    duration_s: float = 10.0,
    gains: Mapping[str, Mapping[str, float]] | np.ndarray | None = None,
    timing: Timing | None = None,
    reference_mean_m: float | None = None,
    record: bool = True,
    pressure_memory_s: float | None = None,
) -> ClosedLoop:
    """Run a batch of closed loops in one compiled kernel (the engine behind the API).

    Parameters
    ----------
    plant_model : Model
        The plant's model (on :meth:`Rig.control` for the paper's rig).
    plant_theta : numpy.ndarray
        Full parameter arrays of the plants, ``(batch, n_parameters)``.
    controller_model : Model
        The model the computed-torque controller inverts.
    controller_theta : numpy.ndarray
        Its full parameter arrays, ``(batch, n_parameters)``.
    frequency_hz : numpy.ndarray
        Reference frequency of each run, ``(batch,)``.
    controller : str or sequence of str
        ``"pid"`` or ``"ct"``, for all runs or one per run.
    duration_s : float
        Length of each run in s.
    gains : mapping or numpy.ndarray, optional
        Overrides of :data:`DEFAULT_GAINS`, e.g. ``{"ct": {"kp": 200.0}}``; or one row
        of gains per run, ``(batch, 3)``, in the order of :data:`DEFAULT_GAINS`.
    timing : Timing, optional
        Rates, limits and sensor; the paper's by default.
    reference_mean_m : float, optional
        Mean of the reference; :data:`REFERENCE_MEAN_M` by default (see
        :func:`operating_mean_m`). The amplitude is the paper's 22.5 mm.
    record : bool
        Also record the reading and the controller output (the command always is).
    pressure_memory_s : float, optional
        How far back the plant's pressure effects look (see the README), the same
        for every run; by default each run's own, from its parameters (the sum of
        the pressure effects' :meth:`~pmabayes.model.effects.Effect.history_s`), so that
        no run depends on the batch it is in.

    Returns
    -------
    ClosedLoop
        The runs.

    Raises
    ------
    ControlError
        On an unknown controller, a frequency <= 0, a bad duration or bad gains.

    Examples
    --------
    Two runs in one call, PID at 0.5 Hz and computed torque at 1 Hz, on the paper's
    model (plant and controller alike):

    >>> import numpy as np
    >>> from pmabayes import Model, Rig
    >>> from pmabayes.control import closed_loop_batch, loop_metrics
    >>> model = Model(rig=Rig.control())
    >>> theta = np.repeat(model.theta(None), 2, axis=0)  # (2, n_parameters)
    >>> runs = closed_loop_batch(model, theta, model, theta, np.array([0.5, 1.0]), ["pid", "ct"],
    ...                          duration_s=6.0)
    >>> runs.controller, runs.position_m.shape
    (('pid', 'ct'), (2, 6001))
    >>> (loop_metrics(runs)["rms_error_m"] * 1e3).round(1)
    array([3.4, 5.2])
    """
    timing = Timing() if timing is None else timing
    reference_mean_m = _mean(reference_mean_m)
    theta_p, theta_c, freq, kind, names, gain_arr = _check_batch(
        plant_model, plant_theta, controller_model, controller_theta, frequency_hz,
        controller, gains, duration_s, reference_mean_m)
    batch = theta_p.shape[0]
    dt = timing.plant_dt_s
    n = int(round(duration_s / dt)) + 1
    t_pred = _prediction_s(controller_model, theta_c, timing)
    p_init = np.clip(_initial_pressure(controller_model, theta_c, reference_mean_m),
                     timing.pressure_min_pa, timing.pressure_max_pa)
    ref = np.array([reference_mean_m, REFERENCE_AMPLITUDE_M])
    cfg = np.array([timing.derivative_filter_s, timing.encoder_counts_per_m,
                    timing.pressure_min_pa, timing.pressure_max_pa])
    steps = np.array([timing.steps_per_control, timing.steps_per_command], dtype=np.int64)
    window = _pressure_memory_steps(plant_model, theta_p, dt, pressure_memory_s)
    out_x = np.empty((n, batch))
    out_hold = np.empty(((n - 1) // timing.steps_per_command + 1, batch))
    rec = [np.empty((n, batch)) for _ in range(2)] if record else [np.empty((1, 1))] * 2
    kernel = _kernel(plant_model, controller_model, record)
    kernel(theta_p, theta_c, freq, kind, gain_arr, np.ascontiguousarray(t_pred),
           np.ascontiguousarray(p_init), ref, cfg, steps,
           plant_model.rig.moving_mass_kg, plant_model.rig.gravity_force_n,
           plant_model.rig.area_m2, controller_model.rig.moving_mass_kg,
           controller_model.rig.gravity_force_n, controller_model.rig.area_m2, dt, window,
           out_x, out_hold, *rec)
    time_s = np.arange(n) * dt
    command = np.repeat(out_hold.T, timing.steps_per_command, axis=1)[:, :n]
    return ClosedLoop(
        time_s=time_s, frequency_hz=freq, controller=names,
        reference_m=reference_m(time_s[None, :], freq[:, None], mean_m=reference_mean_m),
        position_m=out_x.T, measured_m=rec[0].T if record else None, command_pa=command,
        controller_output_pa=rec[1].T if record else None, initial_pressure_pa=p_init,
        dead_zone_pa=_value(plant_model, theta_p, "p_dz"),
        metadata={"timing": timing, "gains": gain_arr, "prediction_s": t_pred,
                  "reference_mean_m": float(reference_mean_m),
                  "reference_amplitude_m": REFERENCE_AMPLITUDE_M},
    )


def _check_batch(plant_model: Model, plant_theta, controller_model: Model, controller_theta,
                 frequency_hz, controller, gains, duration_s: float, reference_mean_m: float):
    """The batch's checked inputs: ``(theta_p, theta_c, freq, kind, names, gains)``."""
    theta_p = plant_model.theta(np.asarray(plant_theta, dtype=float))
    theta_c = controller_model.theta(np.asarray(controller_theta, dtype=float))
    batch = theta_p.shape[0]
    if theta_c.shape[0] != batch:
        raise ControlError(f"{theta_c.shape[0]} controller parameter sets for {batch} plants")
    freq = np.ascontiguousarray(np.broadcast_to(np.asarray(frequency_hz, dtype=float), (batch,)))
    if not np.all(np.isfinite(freq) & (freq > 0)):
        raise ControlError(f"frequency must be > 0 Hz, got {np.unique(freq)[:4].tolist()}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ControlError(f"duration_s must be > 0, got {duration_s}")
    if not math.isfinite(reference_mean_m):
        raise ControlError(f"reference_mean_m must be finite, got {reference_mean_m}")
    for model in (plant_model, controller_model):
        if model.rig.input_kind != "pressure":
            raise ControlError("closed-loop control needs a pressure-driven rig "
                               "(e.g. Rig.control()); got a force-driven one")
    kind, names = _controller_codes(controller, batch)
    if isinstance(gains, np.ndarray):
        gain_arr = np.ascontiguousarray(gains, dtype=float)
        if gain_arr.shape != (batch, 3) or not np.all(np.isfinite(gain_arr) & (gain_arr >= 0)):
            raise ControlError(f"a gain array must be finite, >= 0 and ({batch}, 3)")
    else:
        gain_arr = gain_array(names, gains)
    return theta_p, theta_c, freq, kind, names, gain_arr


def closed_loop(
    controller: str,
    frequency_hz: float,
    *,
    model: Model | None = None,
    params: Mapping[str, float] | None = None,
    controller_model: Model | None = None,
    controller_params: Mapping[str, float] | None = None,
    duration_s: float = 10.0,
    gains: Mapping[str, Mapping[str, float]] | None = None,
    timing: Timing | None = None,
    reference_mean_m: float | None = None,
) -> ClosedLoop:
    """One closed-loop run of the paper's tracking experiment.

    Parameters
    ----------
    controller : str
        ``"pid"`` or ``"ct"``.
    frequency_hz : float
        Reference frequency, > 0.
    model : Model, optional
        The plant; the base model on :meth:`Rig.control` by default.
    params : mapping, optional
        The plant's parameters; the model's defaults (the paper's values) otherwise.
    controller_model : Model, optional
        The model the computed torque inverts; the plant's model by default.
    controller_params : mapping, optional
        Its parameters. By default the plant's when the controller uses the plant's
        model (a perfectly identified plant), else ``controller_model``'s defaults.
    duration_s : float
        Length of the run in s.
    gains : mapping, optional
        Overrides of :data:`DEFAULT_GAINS` (which are tuned on the paper's values; see
        :func:`nominal_gains` for gains tuned on another model).
    timing : Timing, optional
        Rates, limits and sensor; the paper's by default.
    reference_mean_m : float, optional
        Mean of the reference; :data:`REFERENCE_MEAN_M` by default.

    Returns
    -------
    ClosedLoop
        A batch of one run, with every recorded signal.

    Examples
    --------
    >>> from pmabayes.control import closed_loop, tracking_metrics
    >>> run = closed_loop("ct", 1.0, duration_s=6.0)
    >>> m = tracking_metrics(run.time_s, run.reference_m, run.position_m, 1.0)
    >>> bool(m["rms_error_m"][0] < 0.01)
    True
    """
    model = _nominal_model(model)
    cmodel = model if controller_model is None else controller_model
    theta_p = model.theta(params)
    cparams = params if controller_params is None and controller_model is None else (
        controller_params)
    theta_c = cmodel.theta(cparams)
    return closed_loop_batch(model, theta_p, cmodel, theta_c, np.array([float(frequency_hz)]),
                             controller, duration_s=duration_s, gains=gains, timing=timing,
                             reference_mean_m=reference_mean_m)
