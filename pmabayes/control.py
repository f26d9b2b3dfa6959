"""Closed-loop position control of the PMA: PID and computed torque, as in the paper.

The paper (Godage et al., section IV) tracks ``x_d = 0.005 + 0.0225 sin(2 pi f t)`` m
with a 500 g load hanging so that gravity pulls toward extension, a joint-space PID
and a computed-torque controller built on the identified Bouc-Wen model. This module
simulates that rig as faithfully as the paper describes it:

* **Plant**: the identified model (any composition of effects) on
  :meth:`Rig.control`, integrated at 1 kHz by exactly the scheme and the same
  generated code as :func:`pmabayes.simulate` (``pmabayes.simulator.PlantCode``),
  so replaying the closed loop's pressure command open loop reproduces its position.
* **Controller**: runs at 100 Hz on the encoder reading (quantised to the paper's
  2000 counts per inch, after the plant's measurement effects).
* **Regulator command**: the controller output is sampled at 20 Hz and held
  (zero-order hold), limited to 0..0.9 MPa (the regulator's 0-10 V range). The
  controller's output at a 20 Hz instant is applied at once (no computation delay).
* **Start**: the plant rests at the static equilibrium (``z = 0``) under the
  pressure that the controller's model needs at the reference's start; the
  integrator of the PID starts there too (bumpless start).

**Operating point.** With the load, ``x`` cannot go below the sag under the load at
zero pressure, ``(M + m) g / K_e = 8.9 mm`` with the paper's values, but the paper's
reference reaches down to -17.5 mm (the paper's ``x`` is measured from the loaded
rest, ours from the unloaded length). The reference is therefore shifted by
:data:`OPERATING_OFFSET_M` = 31.5 mm (:func:`operating_offset_m`: the trough is
lifted to the sag plus a 5 mm margin, 13.9 mm, rounded up to 0.1 mm), so that the
trough stays above the dead zone and the controller keeps authority there. Every
run here, for every controller, frequency and posterior sample, uses
``x_d = 0.0365 + 0.0225 sin(2 pi f t)`` m (14.0 to 59.0 mm).

**PID** (joint space, on the error ``e = x_d - y``)::

    u = K_p e + K_i int(e) + K_d (x_d' - v_hat)

``v_hat`` is the backward difference of the reading filtered by a first-order
filter of time constant ``derivative_filter_s`` (10 ms). The integrator stops while
the output saturates (clamping anti-windup).

**Computed torque** inverts the controller's model::

    F = (M + m) a + d v_hat + K_e x_hat + z_hat + (M + m) g s_g + f_effects(x_hat, v_hat, p)
    a = x_d'' + K_d (x_d' - v_hat) + K_p (x_d - x_hat)
    u = p_dz + F / A

so that for an exact model the error obeys ``e'' + K_d e' + K_p e = 0`` (the outer
error dynamics, with their own gains). ``z_hat`` comes from a Bouc-Wen observer
driven by the reading: ``z`` is rate independent, so the exact update of the
simulator is applied to each 10 ms increment of the reading. The dead zone is
inverted by adding ``p_dz``; a negative force asks for a pressure below ``p_dz``,
which vents faster. Effects of the controller's model are inverted where possible:

* force effects (friction, cubic or pressure stiffness) are added to ``F``;
* the zero-order hold (mean delay half the command period), a transport delay
  ``t_delay`` and a regulator lag ``tau_reg`` are inverted by prediction: the
  reference and the position are evaluated ``t_pred = T_cmd / 2 + t_delay + tau_reg``
  ahead (``x_hat = y + v_hat t_pred``). For a delay this is exact in phase; for a
  lag it is the first-order lead ``1 + tau s ~ exp(tau s)``, right in phase at low
  frequency and without the lead's high-frequency gain;
* measurement effects are not inverted.

**Gains** come from one rule, :func:`tune_gains`: on the nominal model (the paper's
values, no effects) the gains that give the smallest RMS error at 0.5 Hz on a log
grid, among those whose loop still tracks (RMS error below 10% of the amplitude)
with every gain doubled, a gain margin of 2 (6 dB). :data:`DEFAULT_GAINS` holds the
result; ``tests/test_control.py`` checks that the rule reproduces it.

**Metrics** (:func:`tracking_metrics`) use whole periods after the start-up: the
first ``max(2 s, one period)`` is dropped and the largest whole number of periods
that ends at the end of the run is kept.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.model import PAPER_VALUES, Model, Rig
from pmabayes.simulator import (  # the internal code-generation API
    FASTMATH,
    PlantCode,
    bw_rate_lines,
    bw_update_lines,
    cached_kernel,
    compile_kernel,
    indent_lines,
    structure_key,
)
from pmabayes.synthetic import ENCODER_COUNTS_PER_M

__all__ = [
    "CONTROLLERS",
    "PAPER_REFERENCE_MEAN_M",
    "REFERENCE_AMPLITUDE_M",
    "OPERATING_OFFSET_M",
    "REFERENCE_MEAN_M",
    "DEFAULT_GAINS",
    "ControlError",
    "Timing",
    "ClosedLoop",
    "operating_offset_m",
    "reference_m",
    "closed_loop",
    "closed_loop_batch",
    "tracking_metrics",
    "tune_gains",
    "track",
    "figure5",
]

#: Controller names, in the order used by arrays and datasets.
CONTROLLERS = ("pid", "ct")
PAPER_REFERENCE_MEAN_M = 0.005
REFERENCE_AMPLITUDE_M = 0.0225
_MARGIN_M = 0.005


class ControlError(ValueError):
    """Bad input to a controller or a closed-loop simulation."""


def operating_offset_m(model: Model | None = None, params: Mapping[str, float] | None = None,
                       *, margin_m: float = _MARGIN_M) -> float:
    """Offset that makes the paper's reference feasible with the control rig's load.

    The load pulls the muscle to its sag ``x_0 = -(M + m) g s_g / K_e`` at zero
    pressure, and no pressure makes it shorter (the muscle only extends). The
    offset lifts the reference's trough ``0.005 - 0.0225`` m to ``x_0 + margin_m``.

    Parameters
    ----------
    model : Model, optional
        Model on the control rig; the base model on :meth:`Rig.control` by default.
    params : mapping, optional
        Parameter values (only ``K_e`` matters); the paper's by default.
    margin_m : float
        Height of the trough above the sag, in m.

    Returns
    -------
    float
        The offset in m, rounded up to 0.1 mm.
    """
    model = Model(rig=Rig.control()) if model is None else model
    values = {**model.defaults, **PAPER_VALUES, **dict(params or {})}
    sag = -model.rig.gravity_force_n / values["K_e"]
    trough = PAPER_REFERENCE_MEAN_M - REFERENCE_AMPLITUDE_M
    return math.ceil((sag + margin_m - trough) * 1e4 - 1e-9) / 1e4


#: The operating offset with the paper's values: 31.5 mm.
OPERATING_OFFSET_M = operating_offset_m()
#: Mean of every reference here: 0.005 m + :data:`OPERATING_OFFSET_M`.
REFERENCE_MEAN_M = PAPER_REFERENCE_MEAN_M + OPERATING_OFFSET_M

#: Gains from :func:`tune_gains` with its defaults. PID: ``kp`` in Pa/m, ``ki`` in
#: Pa/(m s), ``kd`` in Pa s/m; computed torque: ``kp`` in 1/s^2, ``kd`` in 1/s.
DEFAULT_GAINS: dict[str, dict[str, float]] = {
    "pid": {"kp": 17782794.100389227, "ki": 316227766.01683795, "kd": 31622.776601683792},
    "ct": {"kp": 3995.8775124988906, "kd": 151.7110888234397},
}
_GAIN_NAMES = {"pid": ("kp", "ki", "kd"), "ct": ("kp", "kd")}


def reference_m(time_s: np.ndarray, frequency_hz: float, *, mean_m: float = REFERENCE_MEAN_M,
                amplitude_m: float = REFERENCE_AMPLITUDE_M) -> np.ndarray:
    """The tracking reference ``x_d = mean + amplitude sin(2 pi f t)``.

    Parameters
    ----------
    time_s : numpy.ndarray
        Times in s.
    frequency_hz : float
        Reference frequency.
    mean_m : float
        Mean, :data:`REFERENCE_MEAN_M` (the paper's 5 mm plus the operating offset).
    amplitude_m : float
        Amplitude, the paper's 22.5 mm.

    Returns
    -------
    numpy.ndarray
        The reference in m.
    """
    return mean_m + amplitude_m * np.sin(2 * np.pi * frequency_hz * np.asarray(time_s))


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
    """

    plant_dt_s: float = 1e-3
    controller_period_s: float = 0.01
    command_period_s: float = 0.05
    pressure_min_pa: float = 0.0
    pressure_max_pa: float = 0.9e6
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
        Pressure command to the regulator, held between its updates.
    controller_output_pa : numpy.ndarray
        Controller output, held between controller samples.
    initial_pressure_pa : numpy.ndarray
        The pressure the plant rests under at the start ``(batch,)``.
    metadata : dict
        The timing, the gains of each run and the computed torque's prediction time.
    """

    time_s: np.ndarray
    frequency_hz: np.ndarray
    controller: tuple[str, ...]
    reference_m: np.ndarray
    position_m: np.ndarray
    measured_m: np.ndarray | None
    command_pa: np.ndarray | None
    controller_output_pa: np.ndarray | None
    initial_pressure_pa: np.ndarray
    metadata: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------
# The closed-loop kernel, generated from the simulator's plant code


def _generate(plant_model: Model, ctrl_model: Model, record: bool) -> tuple[str, dict]:
    plant = PlantCode(plant_model, theta="theta_p", cst="cst", prefix="_eff")
    ctrl = PlantCode(ctrl_model, theta="theta_c", cst="ccst", prefix="_ceff")
    inject = {**plant.inject, **ctrl.inject}
    lagged = bool(plant.pressure)
    args = ("theta_p, theta_c, freq_hz, kind, gains, t_pred, p_init, ref, cfg, steps, "
            "mass, f_grav, area, c_mass, c_f_grav, c_area, dt, window, out_x, out_y, "
            "out_cmd, out_u")
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
    # controller state rows: 0 integral, 1 filtered velocity, 2 observer z, 3 last
    # reading, 4 controller output, 5 held command
    body += [
        "st = np.zeros((3, batch))",
        "cs = np.zeros((6, batch))",
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
    if lagged:  # raw command history with `window` rows of rest before the start
        body += [
            "hist = np.empty((window + n + n_cmd, batch))",
            "for k in range(window):",
            "    hist[k, :] = p_init",
            "wa = np.empty((window + n_cmd, batch))",
            "wb = np.empty((window + n_cmd, batch))",
            "pw = np.empty((2, n_cmd, batch))",
        ]
    tick = [
        "y = ym[0, i]",
        "if counts > 0.0:",
        "    y = np.round(y * counts) / counts",
        "if k == 0:",
        "    cs[3, i] = y",
        "dy = y - cs[3, i]",
        "cs[3, i] = y",
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
    tick += ["    " + ln for ln in bw_rate_lines("zo", "dy", "ccst")]
    tick += ["    " + ln for ln in bw_update_lines("zo", "dy", "zn", "ccst")]
    tick += [
        "    cs[2, i] = zn",
        "    tp = t + t_pred[i]",
        "    sn = math.sin(om * tp)",
        "    xr = ref[0] + ref[1] * sn",
        "    xr_d = ref[1] * om * math.cos(om * tp)",
        "    xr_dd = -ref[1] * om * om * sn",
        "    xh = y + vh * t_pred[i]",
        "    acc = xr_dd + gains[i, 1] * (xr_d - vh) + gains[i, 0] * (xr - xh)",
    ]
    tick += ["    " + ln for ln in ctrl.forces("xh", "vh", "cs[5, i]", "fc", False)]
    tick += [
        "    force = (c_mass * acc + theta_c[i, 3] * vh + theta_c[i, 4] * xh + zn + c_f_grav"
        " + fc)",
        "    u = force / c_area + ccst[11, i]",
        "u = p_lo if u < p_lo else (p_hi if u > p_hi else u)",
        "cs[4, i] = u",
    ]
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
    loop += ["            " + ln for ln in tick]
    loop += [
        "        if k % n_cmd == 0:",
        "            for i in range(batch):",
        "                cs[5, i] = cs[4, i]",
    ]
    if lagged:
        loop += [
            "            for j in range(n_cmd):",
            "                for i in range(batch):",
            "                    hist[window + k + j, i] = cs[5, i]",
            "            for j in range(window + n_cmd):",
            "                for i in range(batch):",
            "                    wa[j, i] = hist[k + j, i]",
            "                    wb[j, i] = hist[k + j, i]",
        ]
        loop += [f"            {plant.name_of[e]}(theta_p[:, {s.start}:{s.stop}], wa, wb, dt)"
                 for e, s in plant.pressure]
        loop += [
            "            for j in range(n_cmd):",
            "                for i in range(batch):",
            "                    pw[0, j, i] = wa[window + j, i]",
            "                    pw[1, j, i] = wb[window + j, i]",
        ]
    loop += ["    for i in range(batch):", "        out_x[k, i] = st[0, i]"]
    if record:
        loop += [
            "        out_y[k, i] = cs[3, i]",
            "        out_cmd[k, i] = cs[5, i]",
            "        out_u[k, i] = cs[4, i]",
        ]
    loop += ["    if k == n - 1:", "        break"]
    if lagged:  # the same interpolation as the open-loop kernel, at fa = 0, fb = 1
        loop += ["    jb = k % n_cmd", "    fa = 0.0", "    fb = 1.0"]
        p_start = "(pw[0, jb, i] + (pw[1, jb, i] - pw[0, jb, i]) * fa)"
        p_end = "(pw[0, jb, i] + (pw[1, jb, i] - pw[0, jb, i]) * fb)"
    else:
        p_start = p_end = "cs[5, i]"
    step = ["x0 = st[0, i]; v0 = st[1, i]; z0 = st[2, i]"]
    step += plant.step(p_start, p_end, "x0", "v0", "z0", "x1", "v1", "z1")
    step += ["st[0, i] = x1; st[1, i] = v1; st[2, i] = z1"]
    loop += ["    for i in range(batch):"] + ["        " + ln for ln in step]
    body += loop

    text = "# Generated by pmabayes.control: closed loop, plant effects: "
    text += (", ".join(plant_model.effect_names) or "none") + "; controller model effects: "
    text += (", ".join(ctrl_model.effect_names) or "none") + f"; recording: {record}\n"
    text += "import math\nimport numpy as np\nfrom numba import njit\n"
    text += "from pmabayes.simulator import _discretise\n"
    text += f"FASTMATH = set({sorted(FASTMATH)!r})\n"
    for g in inject:
        text += f"{g} = None  # injected before the first call\n"
    text += "\n\n@njit(cache=True, fastmath=FASTMATH, error_model='numpy')\n"
    text += f"def closed_loop({args}):\n" + indent_lines(body, 4) + "\n"
    return text, inject


def _kernel(plant_model: Model, ctrl_model: Model, record: bool):
    key = ("closed_loop", structure_key(plant_model, False, False),
           structure_key(ctrl_model, False, False), record)
    kernel = cached_kernel(key)
    if kernel is not None:
        return kernel
    text, inject = _generate(plant_model, ctrl_model, record)
    return compile_kernel(key, text, inject, name="closed_loop")


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


def _gain_array(names: tuple, gains: Mapping | None) -> np.ndarray:
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


def _value(model: Model, theta: np.ndarray, name: str, default: float = 0.0) -> np.ndarray:
    if name in model.parameter_names:
        return theta[:, model.index(name)]
    return np.full(theta.shape[0], default)


def _initial_pressure(model: Model, theta: np.ndarray, x_m: float) -> np.ndarray:
    """Pressure holding ``model`` at rest at ``x_m`` with ``z = 0``."""
    rig = model.rig
    base = rig.gravity_force_n + theta[:, model.index("K_e")] * x_m
    p_dz = _value(model, theta, "p_dz")
    p = p_dz + base / rig.area_m2
    force = [(e, s) for e, s in model.effect_slices() if e.stage == "force"]
    if not force:
        return p
    for i in range(theta.shape[0]):  # fixed point: a force effect may depend on p
        for _ in range(50):
            extra = sum(e.physics(np.ascontiguousarray(theta[i, s]), x_m, 0.0, p[i])[0]
                        for e, s in force)
            p_new = p_dz[i] + (base[i] + extra) / rig.area_m2
            done = abs(p_new - p[i]) <= 1e-9 * (1.0 + abs(p_new))
            p[i] = p_new
            if done:
                break
    return p


def _pressure_memory_steps(model: Model, theta: np.ndarray, dt: float,
                           memory_s: float | None) -> int:
    if memory_s is None:
        memory_s = 0.0
        for eff, _ in model.effect_slices():
            if eff.stage != "pressure":
                continue
            if eff.name == "regulator_lag":  # exp(-40) of the past remains
                memory_s += 40.0 * float(np.max(_value(model, theta, "tau_reg")))
            elif eff.name == "transport_delay":
                memory_s += float(np.max(_value(model, theta, "t_delay")))
            else:  # a user's pressure effect: assume 2 s of memory
                memory_s += 2.0
    return int(math.ceil(memory_s / dt)) + 4


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
    record : bool
        Also record the reading, the command and the controller output.
    pressure_memory_s : float, optional
        How far back the plant's pressure effects look (see the README); derived
        from the built-in effects' parameters by default.

    Returns
    -------
    ClosedLoop
        The runs.

    Raises
    ------
    ControlError
        On an unknown controller, a frequency <= 0, a bad duration or bad gains.
    """
    timing = Timing() if timing is None else timing
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
        gain_arr = _gain_array(names, gains)
    dt = timing.plant_dt_s
    n = int(round(duration_s / dt)) + 1
    t_pred = (timing.command_period_s / 2 + _value(controller_model, theta_c, "t_delay")
              + _value(controller_model, theta_c, "tau_reg"))
    p_init = np.clip(_initial_pressure(controller_model, theta_c, REFERENCE_MEAN_M),
                     timing.pressure_min_pa, timing.pressure_max_pa)
    ref = np.array([REFERENCE_MEAN_M, REFERENCE_AMPLITUDE_M])
    cfg = np.array([timing.derivative_filter_s, timing.encoder_counts_per_m,
                    timing.pressure_min_pa, timing.pressure_max_pa])
    steps = np.array([timing.steps_per_control, timing.steps_per_command], dtype=np.int64)
    window = _pressure_memory_steps(plant_model, theta_p, dt, pressure_memory_s)
    out_x = np.empty((n, batch))
    rec = [np.empty((n, batch)) for _ in range(3)] if record else [np.empty((1, 1))] * 3
    kernel = _kernel(plant_model, controller_model, record)
    kernel(theta_p, theta_c, freq, kind, gain_arr, np.ascontiguousarray(t_pred),
           np.ascontiguousarray(p_init), ref, cfg, steps,
           plant_model.rig.moving_mass_kg, plant_model.rig.gravity_force_n,
           plant_model.rig.area_m2, controller_model.rig.moving_mass_kg,
           controller_model.rig.gravity_force_n, controller_model.rig.area_m2, dt, window,
           out_x, *rec)
    time_s = np.arange(n) * dt
    reference = REFERENCE_MEAN_M + REFERENCE_AMPLITUDE_M * np.sin(
        2 * np.pi * freq[:, None] * time_s[None, :])
    return ClosedLoop(
        time_s=time_s, frequency_hz=freq, controller=names, reference_m=reference,
        position_m=out_x.T, measured_m=rec[0].T if record else None,
        command_pa=rec[1].T if record else None,
        controller_output_pa=rec[2].T if record else None, initial_pressure_pa=p_init,
        metadata={"timing": timing, "gains": gain_arr, "prediction_s": t_pred},
    )


def _nominal_model(model: Model | None) -> Model:
    return Model(rig=Rig.control()) if model is None else model


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
        Overrides of :data:`DEFAULT_GAINS`.
    timing : Timing, optional
        Rates, limits and sensor; the paper's by default.

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
                             controller, duration_s=duration_s, gains=gains, timing=timing)


_METRIC_NAMES = ("rms_error_m", "max_error_m", "amplitude_ratio", "phase_lag_deg",
                 "overshoot_pct")


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
    return np.arange(first, len(time_s))


def tracking_metrics(time_s: np.ndarray, reference_m: np.ndarray, position_m: np.ndarray,
                     frequency_hz: float, *, settle_s: float = 2.0) -> dict[str, np.ndarray]:
    """Tracking metrics over whole periods after the start-up.

    The window drops the first ``max(settle_s, one period)`` and keeps the largest
    whole number of periods ending at the last sample (the last sample excluded,
    so the window spans whole periods exactly).

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
    """
    if not (np.isfinite(frequency_hz) and frequency_hz > 0):
        raise ControlError(f"frequency must be > 0 Hz, got {frequency_hz}")
    time_s = np.asarray(time_s, dtype=float)
    ref = np.atleast_2d(np.asarray(reference_m, dtype=float))
    pos = np.atleast_2d(np.asarray(position_m, dtype=float))
    if ref.shape[-1] != time_s.size or pos.shape[-1] != time_s.size:
        raise ControlError("reference, position and time must have the same number of samples")
    idx = _analysis_window(time_s, frequency_hz, settle_s)[:-1]
    t = time_s[idx]
    ref = np.broadcast_to(ref, pos.shape)[:, idx]
    pos = pos[:, idx]
    om = 2 * np.pi * frequency_hz
    basis = np.column_stack([np.ones_like(t), np.sin(om * t), np.cos(om * t)])
    proj = np.ascontiguousarray(np.linalg.pinv(basis))  # least squares by the pseudo-inverse
    out = {k: np.empty(pos.shape[0]) for k in _METRIC_NAMES}
    # Row by row on contiguous 1-D copies, by numpy's pairwise sums (not BLAS, whose
    # threads and blocking may vary): reductions over an axis of a 2-D array block (and
    # so round) differently with the batch's shape, and a run's numbers must not depend
    # on the batch it came in.
    for i in range(pos.shape[0]):
        r = np.ascontiguousarray(ref[i])
        y = np.ascontiguousarray(pos[i])
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


def tune_gains(controller: str, *, model: Model | None = None,
               params: Mapping[str, float] | None = None, frequency_hz: float = 0.5,
               margin: float = 2.0, tolerance: float = 0.1, duration_s: float = 10.0,
               grid: Mapping[str, Sequence[float]] | None = None,
               timing: Timing | None = None) -> dict[str, float]:
    """The documented gain rule: best tracking at 0.5 Hz with a gain margin.

    Every gain set on a log grid is simulated on the nominal model. Among those whose
    loop still tracks with every gain multiplied by ``margin`` (RMS error below
    ``tolerance`` times the amplitude), the one with the smallest RMS error at
    ``frequency_hz`` wins.

    Parameters
    ----------
    controller : str
        ``"pid"`` or ``"ct"``.
    model : Model, optional
        The nominal model; the base model on :meth:`Rig.control` by default.
    params : mapping, optional
        Its parameters; the paper's values by default.
    frequency_hz : float
        Tuning frequency.
    margin : float
        Factor all gains must tolerate.
    tolerance : float
        RMS error, as a fraction of the amplitude, that counts as still tracking.
    duration_s : float
        Length of each run.
    grid : mapping of str to sequence of float, optional
        Values per gain; by default PID ``kp`` 10^5..10^9 Pa/m, ``ki`` 10^5..10^10
        Pa/(m s), ``kd`` 0 and 10^2..10^6 Pa s/m (4 values per decade); computed torque
        ``kp = w^2``, ``kd = 2 zeta w`` with ``w`` 1..200 rad/s (24 values) and
        ``zeta`` 0.4..2 (8 values).
    timing : Timing, optional
        Rates, limits and sensor.

    Returns
    -------
    dict of str to float
        The chosen gains, by name.

    Raises
    ------
    ControlError
        If no gain set on the grid meets the margin.
    """
    _controller_codes(controller, 1)
    model = _nominal_model(model)
    if grid is None:
        if controller == "pid":
            grid = {"kp": np.geomspace(1e5, 1e9, 17), "ki": np.geomspace(1e5, 1e10, 21),
                    "kd": np.concatenate([[0.0], np.geomspace(1e2, 1e6, 9)])}
        else:
            w = np.geomspace(1.0, 200.0, 24)
            zeta = np.array([0.4, 0.55, 0.7, 0.85, 1.0, 1.2, 1.5, 2.0])
            ww, zz = np.meshgrid(w, zeta, indexing="ij")
            grid = {"kp": (ww**2).ravel(), "kd": (2 * zz * ww).ravel()}
    names = _GAIN_NAMES[controller]
    if set(grid) != set(names):
        raise ControlError(f"grid must give {names} for {controller}, got {sorted(grid)}")
    if controller == "pid":
        mesh = np.meshgrid(*[np.asarray(grid[k], float) for k in names], indexing="ij")
        cand = np.column_stack([m.ravel() for m in mesh])
    else:  # paired values (w, zeta)
        cand = np.column_stack([np.asarray(grid[k], float) for k in names])
    both = np.concatenate([cand, margin * cand])
    theta = model.theta(params)
    rms = np.empty(len(both))
    for lo in range(0, len(both), 512):
        sl = slice(lo, min(lo + 512, len(both)))
        b = sl.stop - sl.start
        g = np.zeros((b, 3))
        g[:, :len(names)] = both[sl]
        th = np.repeat(theta, b, axis=0)
        run = closed_loop_batch(model, th, model, th, np.full(b, float(frequency_hz)),
                                controller, gains=g, duration_s=duration_s, timing=timing,
                                record=False)
        rms[sl] = tracking_metrics(run.time_s, run.reference_m, run.position_m,
                                   frequency_hz)["rms_error_m"]
    rms = np.where(np.isfinite(rms), rms, np.inf)
    nominal, doubled = rms[:len(cand)], rms[len(cand):]
    ok = doubled < tolerance * REFERENCE_AMPLITUDE_M
    if not ok.any():
        raise ControlError(f"no {controller} gains on the grid keep a gain margin of {margin}")
    best = int(np.argmin(np.where(ok, nominal, np.inf)))
    return {k: float(v) for k, v in zip(names, cand[best], strict=True)}


def track(frequency_hz: float, *, controllers: Sequence[str] = CONTROLLERS,
          model: Model | None = None, params: Mapping[str, float] | None = None,
          duration_s: float = 10.0) -> dict:
    """Metrics of each controller tracking one frequency (``pmabayes track``).

    Parameters
    ----------
    frequency_hz : float
        Reference frequency, > 0.
    controllers : sequence of str
        Which controllers to run.
    model : Model, optional
        Plant and controller model; the base model on :meth:`Rig.control` by default.
    params : mapping, optional
        Its parameters; the paper's values by default.
    duration_s : float
        Length of each run.

    Returns
    -------
    dict
        ``{"frequency_hz": f, "controllers": {name: {"rms_error_m": ..., "max_error_m":
        ..., "amplitude_ratio": ..., "phase_lag_deg": ..., "overshoot_pct": ...}}}``.
    """
    if not (isinstance(frequency_hz, int | float) and math.isfinite(frequency_hz)
            and frequency_hz > 0):
        raise ControlError(f"frequency must be > 0 Hz, got {frequency_hz}")
    model = _nominal_model(model)
    theta = model.theta(params)
    names = tuple(controllers)
    _controller_codes(names, len(names))
    run = closed_loop_batch(model, np.repeat(theta, len(names), axis=0), model,
                            np.repeat(theta, len(names), axis=0),
                            np.full(len(names), float(frequency_hz)), names,
                            duration_s=duration_s, record=False)
    m = tracking_metrics(run.time_s, run.reference_m, run.position_m, frequency_hz)
    return {"frequency_hz": float(frequency_hz),
            "controllers": {c: {k: float(v[j]) for k, v in m.items()}
                            for j, c in enumerate(names)}}


def figure5(out_path=None, *, model: Model | None = None,
            params: Mapping[str, float] | None = None, plant_model: Model | None = None,
            plant_params: Mapping[str, float] | None = None,
            frequencies_hz: Sequence[float] = (0.5, 1.0, 2.0),
            duration_s: float = 10.0) -> dict:
    """Reproduce the paper's Fig. 5 and check its claims.

    Parameters
    ----------
    out_path : str or Path, optional
        Where to write the figure (PNG); no figure if None.
    model : Model, optional
        The controller's model (and the plant's unless ``plant_model`` is given); the
        base model on :meth:`Rig.control` by default.
    params : mapping, optional
        Its parameters; the paper's values by default.
    plant_model : Model, optional
        A plant that differs from the controller's model, e.g. with a regulator lag
        the model lacks.
    plant_params : mapping, optional
        The plant's parameters (the model's defaults for those not given).
    frequencies_hz : sequence of float
        The panels' frequencies (the paper's 0.5, 1 and 2 Hz).
    duration_s : float
        Length of each run.

    Returns
    -------
    dict
        ``metrics`` (per frequency and controller, as :func:`track`) and ``claims``,
        a list of ``{"claim", "reproduced", "evidence"}``.
    """
    model = _nominal_model(model)
    theta = model.theta(params)
    if plant_model is None:
        plant_model, theta_p = model, theta
    else:
        theta_p = plant_model.theta(plant_params)
    freqs = [float(f) for f in frequencies_hz]
    names = [c for _ in freqs for c in CONTROLLERS]
    fr = np.repeat(freqs, len(CONTROLLERS))
    batch = len(names)
    run = closed_loop_batch(plant_model, np.repeat(theta_p, batch, axis=0), model,
                            np.repeat(theta, batch, axis=0), fr, names, duration_s=duration_s)
    metrics: dict[float, dict[str, dict[str, float]]] = {}
    for j, (f, c) in enumerate(zip(fr, names, strict=True)):
        m = tracking_metrics(run.time_s, run.reference_m[j], run.position_m[j], f)
        metrics.setdefault(float(f), {})[c] = {k: float(v[0]) for k, v in m.items()}
    claims = []
    if all(f in metrics for f in (0.5, 1.0, 2.0)):
        rms = {f: (metrics[f]["pid"]["rms_error_m"], metrics[f]["ct"]["rms_error_m"])
               for f in (0.5, 1.0, 2.0)}
        claims.append({
            "claim": "computed torque tracks better (lower RMS error) than PID at 0.5, 1 "
                     "and 2 Hz",
            "reproduced": all(ct < pid for pid, ct in rms.values()),
            "evidence": "; ".join(f"{f:g} Hz: PID {1e3 * p:.2f} mm, CT {1e3 * c:.2f} mm"
                                  for f, (p, c) in rms.items())})
        lag_pid = metrics[2.0]["pid"]["phase_lag_deg"]
        lag_ct = metrics[2.0]["ct"]["phase_lag_deg"]
        claims.append({
            "claim": "at 2 Hz PID is close to 180 degrees out of phase (150-210 taken as "
                     "close) while computed torque stays under 180",
            "reproduced": bool(150.0 <= lag_pid <= 210.0 and lag_ct < 180.0),
            "evidence": f"phase lag at 2 Hz: PID {lag_pid:.0f} deg, CT {lag_ct:.0f} deg"})
        over = metrics[1.0]["ct"]["overshoot_pct"]
        claims.append({
            "claim": "computed torque overshoots by about 10% at 1 Hz (5-15% taken as about)",
            "reproduced": bool(5.0 <= over <= 15.0),
            "evidence": f"CT overshoot at 1 Hz: {over:.1f}% of the amplitude"})
    if out_path is not None:
        _plot_figure5(run, freqs, out_path)
    return {"metrics": metrics, "claims": claims}


def _plot_figure5(run: ClosedLoop, freqs: list[float], out_path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2 * len(freqs), 1, figsize=(8, 3.2 * len(freqs)), sharex=True,
                             gridspec_kw={"height_ratios": [2, 1] * len(freqs)})
    t = run.time_s
    for k, f in enumerate(freqs):
        top, bottom = axes[2 * k], axes[2 * k + 1]
        j_pid = 2 * k
        top.plot(t, 1e3 * run.reference_m[j_pid], "k--", lw=1, label="$x_d$")
        for j, (c, style) in enumerate(zip(CONTROLLERS, ("C0", "C3"), strict=True)):
            label = {"pid": "$x_{FB}$ (PID)", "ct": "$x_{CT}$ (computed torque)"}[c]
            top.plot(t, 1e3 * run.position_m[2 * k + j], style, lw=1, label=label)
            bottom.plot(t, 1e3 * (run.reference_m[2 * k + j] - run.position_m[2 * k + j]),
                        style, lw=1)
        top.set_ylabel("x [mm]")
        top.set_title(f"({'abc'[k] if k < 3 else k}) {f:g} Hz")
        bottom.set_ylabel("error [mm]")
        bottom.axhline(0, color="k", lw=0.5)
        if k == 0:
            top.legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(out_path, dpi=120)
    plt.close(fig)
