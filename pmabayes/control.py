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
  pressure that the controller's model needs at the reference's mean; the
  integrator of the PID starts there too (bumpless start).

**Operating point** (an assumption: the paper gives no origin for ``x``). The paper
only says that the 5 mm bias of its reference compensates the load's offset, so its
``x`` is measured from an origin it does not state. Ours is the unloaded length,
and the reference keeps the paper's amplitude (22.5 mm) and frequencies with a mean
chosen by a dynamic rule, :func:`operating_mean_m`: the smallest mean, on a 1 mm
grid, at which the pressure the nominal model needs along ``x_d`` at 2 Hz (the
paper's fastest; inertia, damping, stiffness, hysteresis, gravity, dead zone) stays
50 kPa above the dead zone ``p_dz`` and 50 kPa under 0.9 MPa. With the paper's
values this is :data:`REFERENCE_MEAN_M` = 0.100 m (77.5 to 122.5 mm; the model
asks 0.118 to 0.538 MPa at 2 Hz). A mean closer to the sag under the load would
put the trough in the dead zone, where the actuator has no authority and the
controllers' verdicts would be set by the choice of mean. The same mean is used by
every run here unless ``reference_mean_m`` says otherwise.

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
* a sensor zero offset (``position_offset``) is subtracted from the reading; other
  measurement effects are not inverted.

The velocity is not predicted: ``d v_hat`` and the outer ``K_d`` term use the
filtered velocity of the reading, not the velocity ``t_pred`` ahead (a predicted
velocity needs the acceleration, which differencing a 12.7 um encoder at 100 Hz
gives too noisily).

**Gains** come from one rule, :func:`tune_gains`, run on the nominal model of the
experiment (the paper's values here, :data:`DEFAULT_GAINS`; a fit's posterior mean
in :func:`nominal_gains`): the gain set with the smallest RMS error at 0.5 Hz on a
log grid, among those that are robustly stable: with every gain doubled (a 6 dB
gain margin), and separately with an extra 20 ms transport delay in the plant (a
delay margin), the loop must still reach a periodic steady state (the last two
periods within 0.5 mm of each other) with an RMS error at most twice the
nominal; and so must its neighbours on the grid, so that the choice is not on the
knife edge of the stable set. Computed torque's natural frequency is capped at
``pi / (2 T_cmd)`` (31.4 rad/s), half the 20 Hz hold's Nyquist frequency (see
:func:`tune_gains`). ``tests/test_control.py`` checks that the rule reproduces
:data:`DEFAULT_GAINS`. With a fit, the operating point (:func:`operating_mean_m`)
and the gains are those of the rule on the fit's nominal model
(:func:`resolve_gains`).

**Metrics** (:func:`tracking_metrics`, :func:`loop_metrics`) use whole periods after
the start-up: the first ``max(2 s, one period)`` is dropped and the largest whole
number of periods that ends at the end of the run is kept. :func:`loop_metrics`
adds the fraction of that time the command sits in the plant's dead zone (no
actuator force) or at the upper pressure limit.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import sys
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmabayes import simulator as _simulator
from pmabayes.model import Model, Rig
from pmabayes.simulator import (  # the internal code-generation API
    FASTMATH,
    PlantCode,
    bw_rate_lines,
    bw_update_lines,
    cache_dir,
    cached_kernel,
    compile_kernel,
    indent_lines,
    structure_key,
)
from pmabayes.synthetic import ENCODER_COUNTS_PER_M

__all__ = [
    "CONTROLLERS",
    "METRICS",
    "PAPER_REFERENCE_MEAN_M",
    "REFERENCE_AMPLITUDE_M",
    "REFERENCE_MEAN_M",
    "DEFAULT_GAINS",
    "ControlError",
    "GainGridWarning",
    "Timing",
    "ClosedLoop",
    "operating_mean_m",
    "inverse_model_pressure_pa",
    "reference_m",
    "closed_loop",
    "closed_loop_batch",
    "tracking_metrics",
    "command_fractions",
    "gain_array",
    "period_difference_m",
    "loop_metrics",
    "minimum_duration_s",
    "tune_gains",
    "nominal_gains",
    "resolve_gains",
    "track",
]

#: Controller names, in the order used by arrays and datasets.
CONTROLLERS = ("pid", "ct")
#: Metrics of :func:`loop_metrics`, in the order used by datasets.
METRICS = ("rms_error_m", "max_error_m", "amplitude_ratio", "phase_lag_deg", "overshoot_pct",
           "dead_zone_fraction", "saturated_fraction", "period_difference_m")
_TRACKING = METRICS[:5]
#: The paper's reference mean, in its own (unstated) origin.
PAPER_REFERENCE_MEAN_M = 0.005
#: The paper's reference amplitude.
REFERENCE_AMPLITUDE_M = 0.0225
_PRESSURE_MAX_PA = 0.9e6


class ControlError(ValueError):
    """Bad input to a controller or a closed-loop simulation."""


class GainGridWarning(UserWarning):
    """The gain rule's best gains sit on the edge of its grid."""


def _nominal_model(model: Model | None) -> Model:
    return Model(rig=Rig.control()) if model is None else model


def _theta1(model: Model, params) -> np.ndarray:
    """One full parameter row from a mapping (model defaults for the rest) or an array."""
    theta = model.theta(params)
    if theta.shape[0] != 1:
        raise ControlError(f"one parameter set expected, got {theta.shape[0]}")
    return theta


def _inverse_pressure(model: Model | None, params, frequency_hz: float, amplitude_m: float):
    """``(pressure(mean), p_dz)``: the pressure the model needs over one period of x_d."""
    model = _nominal_model(model)
    theta = _theta1(model, params)[0]
    v = dict(zip(model.parameter_names, theta, strict=True))
    rig = model.rig
    n = 2000  # samples per period; two periods from z = 0, the second is periodic
    om = 2 * np.pi * frequency_hz
    phase = np.arange(2 * n + 1) * (2 * np.pi / n)
    s, c = np.sin(phase), np.cos(phase)
    z = np.zeros(phase.size)
    dxs = amplitude_m * np.diff(s)
    for k, dx in enumerate(dxs):  # midpoint rule for dz/dx = alpha - (beta sgn + gamma)|z|
        for corrector in (False, True):  # Euler predictor, then the midpoint
            zm = 0.5 * (z[k] + z[k + 1]) if corrector else z[k]
            sgn = 1.0 if dx * zm >= 0.0 else -1.0
            z[k + 1] = z[k] + dx * (v["alpha"] - (v["beta"] * sgn + v["gamma"]) * abs(zm))
    sl = slice(n, 2 * n)
    z = z[sl]
    vel = amplitude_m * om * c[sl]
    acc = -amplitude_m * om * om * s[sl]
    p_dz = v.get("p_dz", 0.0)
    force_effects = [(e, theta[sl_e]) for e, sl_e in model.effect_slices() if e.stage == "force"]

    def pressure(mean: float) -> np.ndarray:
        x = mean + amplitude_m * s[sl]
        base = rig.moving_mass_kg * acc + v["d"] * vel + v["K_e"] * x + z + rig.gravity_force_n
        return _pressure_with_forces([q for _, q in force_effects],
                                     [e for e, _ in force_effects], np.full(x.size, p_dz),
                                     base, x, vel, rig.area_m2)

    return pressure, p_dz


def _pressure_with_forces(params: list, effects: list, p_dz: np.ndarray, base: np.ndarray,
                          x: np.ndarray, v: np.ndarray, area_m2: float) -> np.ndarray:
    """``p = p_dz + (base + f_effects(x, v, p)) / A`` per sample, by fixed point.

    ``params`` holds each force effect's parameter row: one ``(n_params,)`` row for
    all samples, or ``(n, n_params)`` rows, one per sample. An effect may depend on
    ``p``, hence the iteration (50 at most, to a relative 1e-9).
    """
    p = p_dz + base / area_m2
    for k in range(p.size if effects else 0):
        rows = [np.ascontiguousarray(q if np.ndim(q) == 1 else q[k]) for q in params]
        for _ in range(50):
            extra = sum(e.physics(q, x[k], v[k], p[k])[0] for e, q in zip(effects, rows,
                                                                          strict=True))
            p_new = p_dz[k] + (base[k] + extra) / area_m2
            done = abs(p_new - p[k]) <= 1e-9 * (1.0 + abs(p_new))
            p[k] = p_new
            if done:
                break
    return p


def operating_mean_m(model: Model | None = None, params=None, *, frequency_hz: float = 2.0,
                     amplitude_m: float = REFERENCE_AMPLITUDE_M, margin_pa: float = 50e3,
                     pressure_max_pa: float = _PRESSURE_MAX_PA,
                     resolution_m: float = 1e-3) -> float:
    """Reference mean at which the model can follow the reference without the dead zone.

    Along ``x_d = mean + amplitude sin(2 pi f t)`` the model needs the pressure
    ``p = p_dz + (M_tot x_d'' + d x_d' + K_e x_d + z + F_g + f_effects) / A``, with
    ``z`` the Bouc-Wen force along ``x_d`` in its periodic state (rate independent,
    so it does not depend on the mean). The rule takes the smallest mean, rounded up
    to ``resolution_m``, at which ``p`` stays at least ``margin_pa`` above ``p_dz``;
    it must then also stay ``margin_pa`` under ``pressure_max_pa``.

    Parameters
    ----------
    model : Model, optional
        Model on the control rig; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters (the model's defaults, the paper's values, for those not given).
    frequency_hz : float
        The fastest reference to be tracked (the paper's 2 Hz).
    amplitude_m : float
        Reference amplitude in m.
    margin_pa : float
        Distance kept from the dead zone and from the upper limit, in Pa.
    pressure_max_pa : float
        Upper pressure limit (0.9 MPa).
    resolution_m : float
        The mean is rounded up to a multiple of this.

    Returns
    -------
    float
        The mean in m.

    Raises
    ------
    ControlError
        If no mean keeps the pressure inside both margins (lower the frequency, the
        amplitude or the margin).
    """
    if not (frequency_hz > 0 and amplitude_m > 0 and margin_pa >= 0 and resolution_m > 0):
        raise ControlError("need frequency_hz > 0, amplitude_m > 0, margin_pa >= 0 and "
                           "resolution_m > 0")
    pressure, p_dz = _inverse_pressure(model, params, frequency_hz, amplitude_m)
    low = p_dz + margin_pa
    lo, hi = 0.0, 1.0
    if pressure(hi).min() < low:
        raise ControlError(f"no mean up to {hi} m keeps the pressure {margin_pa:g} Pa above "
                           "the dead zone")
    for _ in range(60):  # the trough's pressure grows with the mean
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pressure(mid).min() < low else (lo, mid)
    mean = math.ceil(hi / resolution_m - 1e-9) * resolution_m
    p = pressure(mean)
    if p.min() < low or p.max() > pressure_max_pa - margin_pa:
        raise ControlError(
            f"at {frequency_hz:g} Hz the model needs {p.min():.4g} to {p.max():.4g} Pa: no "
            f"mean keeps it {margin_pa:g} Pa inside p_dz..{pressure_max_pa:g} Pa; lower the "
            "frequency, the amplitude or the margin")
    return round(mean, 12)


#: Mean of every reference here, by :func:`operating_mean_m` with the paper's values.
REFERENCE_MEAN_M = operating_mean_m()


def inverse_model_pressure_pa(frequency_hz: float, *, model: Model | None = None, params=None,
                              mean_m: float = REFERENCE_MEAN_M,
                              amplitude_m: float = REFERENCE_AMPLITUDE_M) -> np.ndarray:
    """The pressure a model needs to follow the reference exactly, over one period.

    ``p = p_dz + (M_tot x_d'' + d x_d' + K_e x_d + z + F_g + f_effects) / A`` along
    ``x_d = mean + amplitude sin(2 pi f t)``, with ``z`` the Bouc-Wen force in its
    periodic state (the rule of :func:`operating_mean_m` keeps it inside the limits).

    Parameters
    ----------
    frequency_hz : float
        Reference frequency.
    model : Model, optional
        Model on the control rig; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters (the model's defaults for those not given).
    mean_m : float
        Reference mean.
    amplitude_m : float
        Reference amplitude.

    Returns
    -------
    numpy.ndarray
        The pressure in Pa at 2000 phases over one period, from phase 0.
    """
    frequency_hz = _check_frequency(frequency_hz)
    pressure, _ = _inverse_pressure(model, params, frequency_hz, amplitude_m)
    return pressure(mean_m)

#: Gains from :func:`tune_gains` with its defaults on the paper's values. PID: ``kp``
#: in Pa/m, ``ki`` in Pa/(m s), ``kd`` in Pa s/m; computed torque: ``kp`` in 1/s^2,
#: ``kd`` in 1/s.
DEFAULT_GAINS: dict[str, dict[str, float]] = {
    "pid": {"kp": 5623413.251903491, "ki": 56234132.51903491, "kd": 0.0},
    "ct": {"kp": 632.7816954219094, "kd": 125.7757623135226},
}
_GAIN_NAMES = {"pid": ("kp", "ki", "kd"), "ct": ("kp", "kd")}


def reference_m(time_s: np.ndarray, frequency_hz, *, mean_m: float = REFERENCE_MEAN_M,
                amplitude_m: float = REFERENCE_AMPLITUDE_M) -> np.ndarray:
    """The tracking reference ``x_d = mean + amplitude sin(2 pi f t)``.

    Parameters
    ----------
    time_s : numpy.ndarray
        Times in s.
    frequency_hz : float or numpy.ndarray
        Reference frequency (an array broadcasts against ``time_s``).
    mean_m : float
        Mean, :data:`REFERENCE_MEAN_M` by default (see :func:`operating_mean_m`).
    amplitude_m : float
        Amplitude, the paper's 22.5 mm.

    Returns
    -------
    numpy.ndarray
        The reference in m.
    """
    return mean_m + amplitude_m * np.sin(2 * np.pi * np.asarray(frequency_hz)
                                         * np.asarray(time_s))


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
# The closed-loop kernel, generated from the simulator's plant code


def _generate(plant_model: Model, ctrl_model: Model, record: bool) -> tuple[str, dict]:
    plant = PlantCode(plant_model, theta="theta_p", cst="cst", prefix="_eff")
    ctrl = PlantCode(ctrl_model, theta="theta_c", cst="ccst", prefix="_ceff")
    inject = {**plant.inject, **ctrl.inject}
    lagged = bool(plant.pressure)
    # the one measurement effect computed torque inverts: a known zero offset
    offset = (f" - theta_c[i, {ctrl_model.index('x_offset')}]"
              if "position_offset" in ctrl_model.effect_names else "")
    args = ("theta_p, theta_c, freq_hz, kind, gains, t_pred, p_init, ref, cfg, steps, "
            "mass, f_grav, area, c_mass, c_f_grav, c_area, dt, window, out_x, out_hold, "
            "out_y, out_u")
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
        f"    xh = y{offset} + vh * t_pred[i]",
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
        "                out_hold[k // n_cmd, i] = cs[5, i]",
    ]
    if lagged:
        loop += [
            "            for j in range(n_cmd):",
            "                for i in range(batch):",
            "                    hist[wmax + k + j, i] = cs[5, i]",
            "            for j in range(wmax + n_cmd):",
            "                for i in range(batch):",
            "                    jj = j if j > off[i] else off[i]",
            "                    wa[j, i] = hist[k + jj, i]",
            "                    wb[j, i] = hist[k + jj, i]",
        ]
        loop += [f"            {plant.name_of[e]}(theta_p[:, {s.start}:{s.stop}], wa, wb, dt)"
                 for e, s in plant.pressure]
        loop += [
            "            for j in range(n_cmd):",
            "                for i in range(batch):",
            "                    pw[0, j, i] = wa[wmax + j, i]",
            "                    pw[1, j, i] = wb[wmax + j, i]",
        ]
    loop += ["    for i in range(batch):", "        out_x[k, i] = st[0, i]"]
    if record:
        loop += [
            "        out_y[k, i] = cs[3, i]",
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
    text += "from pmabayes.simulator import discretise as _discretise\n"
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


def _value(model: Model, theta: np.ndarray, name: str, default: float = 0.0) -> np.ndarray:
    if name in model.parameter_names:
        return theta[:, model.index(name)]
    return np.full(theta.shape[0], default)


def _initial_pressure(model: Model, theta: np.ndarray, x_m: float) -> np.ndarray:
    """Pressure holding ``model`` at rest at ``x_m`` with ``z = 0``."""
    rig = model.rig
    base = rig.gravity_force_n + theta[:, model.index("K_e")] * x_m
    force = [(e, s) for e, s in model.effect_slices() if e.stage == "force"]
    n = theta.shape[0]
    return _pressure_with_forces([theta[:, s] for _, s in force], [e for e, _ in force],
                                 np.array(_value(model, theta, "p_dz"), dtype=float), base,
                                 np.full(n, float(x_m)), np.zeros(n), rig.area_m2)


def _pressure_memory_steps(model: Model, theta: np.ndarray, dt: float,
                           memory_s: float | None) -> np.ndarray:
    """Look-back of each run's pressure effects in plant steps, ``(batch,)``.

    From each run's own parameters (never the batch's), so that a run's result does
    not depend on the runs it shares a kernel call with.
    """
    batch = theta.shape[0]
    if memory_s is not None:
        mem = np.full(batch, float(memory_s))
    else:
        mem = np.zeros(batch)
        for eff, _ in model.effect_slices():
            if eff.stage != "pressure":
                continue
            if eff.name == "regulator_lag":  # exp(-40) of the past remains
                mem += 40.0 * _value(model, theta, "tau_reg")
            elif eff.name == "transport_delay":
                mem += np.maximum(_value(model, theta, "t_delay"), 0.0)
            else:  # a user's pressure effect: assume 2 s of memory
                mem += 2.0
    return np.ascontiguousarray(np.ceil(mem / dt).astype(np.int64) + 4)


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
    reference_mean_m: float = REFERENCE_MEAN_M,
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
    reference_mean_m : float
        Mean of the reference (:data:`REFERENCE_MEAN_M`, see :func:`operating_mean_m`);
        the amplitude is the paper's 22.5 mm.
    record : bool
        Also record the reading and the controller output (the command always is).
    pressure_memory_s : float, optional
        How far back the plant's pressure effects look (see the README), the same
        for every run; by default each run's own, from its parameters (40
        ``tau_reg`` for a regulator lag, ``t_delay`` for a delay, 2 s for another
        pressure effect), so that no run depends on the batch it is in.

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
    dt = timing.plant_dt_s
    n = int(round(duration_s / dt)) + 1
    t_pred = (timing.command_period_s / 2 + _value(controller_model, theta_c, "t_delay")
              + _value(controller_model, theta_c, "tau_reg"))
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
    reference_mean_m: float = REFERENCE_MEAN_M,
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
    reference_mean_m : float
        Mean of the reference.

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


# ---------------------------------------------------------------------------------
# Metrics


def _check_frequency(frequency_hz) -> float:
    if isinstance(frequency_hz, bool) or not isinstance(frequency_hz, int | float | np.number):
        raise ControlError(f"frequency must be a number > 0 Hz, got {frequency_hz!r}")
    if not (math.isfinite(float(frequency_hz)) and frequency_hz > 0):
        raise ControlError(f"frequency must be > 0 Hz, got {frequency_hz}")
    return float(frequency_hz)


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


# ---------------------------------------------------------------------------------
# Gains


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


def _delayed_plant(model: Model, theta: np.ndarray, delay_s: float) -> tuple[Model, np.ndarray]:
    """The plant with ``delay_s`` more transport delay, whether ``t_delay`` is free or fixed.

    The delay is added to the ``t_delay`` column of the full parameter array (which
    the closed loop takes as given, fixed values included); a model without a delay
    gets the ``transport_delay`` effect with ``t_delay = delay_s``.
    """
    if "transport_delay" in model.effect_names:
        plant, out = model, np.array(theta, dtype=float, copy=True)
    else:
        plant = model.with_effects("transport_delay")
        out = np.repeat(plant.theta(None), theta.shape[0], axis=0)
        for j, name in enumerate(model.parameter_names):
            out[:, plant.index(name)] = theta[:, j]
        out[:, plant.index("t_delay")] = 0.0
    out[:, plant.index("t_delay")] += delay_s
    plant.check_bounds(out)
    return plant, np.ascontiguousarray(out)


def tune_gains(controller: str, *, model: Model | None = None, params=None,
               frequency_hz: float = 0.5, margin: float = 2.0, delay_margin_s: float = 0.02,
               rms_factor: float = 2.0, settle_tolerance_m: float = 5e-4,
               duration_s: float = 10.0, grid: Mapping[str, Sequence[float]] | None = None,
               timing: Timing | None = None,
               reference_mean_m: float = REFERENCE_MEAN_M,
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
    reference_mean_m : float
        Mean of the reference.
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
    rms, diff = [], []
    for plant, theta_p, gains in cases:
        r, d = np.empty(len(cand)), np.empty(len(cand))
        for lo in range(0, len(cand), 512):
            sl = slice(lo, min(lo + 512, len(cand)))
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
        rms.append(np.where(np.isfinite(r), r, np.inf))
        diff.append(d)
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
    # RMS errors within tie_rtol of the best are a tie (the grid's resolution and the
    # model's uncertainty do not separate them): the gentlest of them wins, the
    # smallest gains in the order of _GAIN_NAMES (for computed torque kp, then kd)
    best_rms = float(np.min(np.where(ok, rms[0], np.inf)))
    tied = np.flatnonzero(ok & (rms[0] <= (1.0 + tie_rtol) * best_rms))
    best = int(tied[np.lexsort(cand[tied].T[::-1])[0]])
    edge = _on_edge(controller, cand[~capped], cand[best])
    if capped.any() and "kp" in edge and cand[best, 0] >= cand[~capped, 0].max():
        edge.remove("kp")  # stopped by the bandwidth cap, not by the grid
    if edge:
        warnings.warn(f"the best {controller} gains sit on the grid's edge in "
                      f"{', '.join(edge)}; widen the grid there", GainGridWarning, stacklevel=2)
    return {k: float(v) for k, v in zip(names, cand[best], strict=True)}


_RULE_VERSION = "6"  # bump when tune_gains' rule or its defaults change


def nominal_gains(model: Model | None = None, params=None, *, timing: Timing | None = None,
                  reference_mean_m: float = REFERENCE_MEAN_M,
                  cache: bool = True) -> dict[str, dict[str, float]]:
    """Both controllers' gains by :func:`tune_gains` (its defaults) on a nominal model.

    :data:`DEFAULT_GAINS` for the paper's values; for another model (e.g. a fit's
    posterior mean with its effects) the rule is run on it, and the result cached on
    disk (under :func:`pmabayes.simulator.cache_dir`, keyed by the model, the values,
    the timing, the reference mean and the code), so each nominal model is tuned once.

    Parameters
    ----------
    model : Model, optional
        The nominal model; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters; the model's defaults by default.
    timing : Timing, optional
        Rates, limits and sensor.
    reference_mean_m : float
        Mean of the reference.
    cache : bool
        Read and write the disk cache.

    Returns
    -------
    dict
        ``{"pid": {...}, "ct": {...}}``.
    """
    model = _nominal_model(model)
    theta = _theta1(model, params)
    timing = Timing() if timing is None else timing
    paper = Model(rig=Rig.control())
    if (model.effect_names == () and model.rig == paper.rig and not model.fixed
            and np.array_equal(theta, paper.theta(None)) and timing == Timing()
            and reference_mean_m == REFERENCE_MEAN_M):
        return {c: dict(g) for c, g in DEFAULT_GAINS.items()}
    # the code behind the rule: this module, the simulator, the model and the source
    # of every effect of the model (a user's effect included)
    source = "".join(Path(m.__file__).read_text() for m in (
        sys.modules[__name__], _simulator, sys.modules[Model.__module__]))
    for e in model.effects:
        try:
            source += inspect.getsource(sys.modules[e.__module__])
        except (OSError, TypeError, KeyError):  # no source to read: the class's name only
            source += f"{e.__module__}.{e.__qualname__}"
    key = json.dumps({"effects": [f"{e.__module__}.{e.__qualname__}" for e in model.effects],
                      "rig": model.rig.to_dict(), "theta": theta[0].tolist(),
                      "timing": repr(timing), "mean": float(reference_mean_m),
                      "rule": _RULE_VERSION, "code": hashlib.sha256(source.encode()).hexdigest()},
                     sort_keys=True)
    path = cache_dir() / "gains" / f"{hashlib.sha256(key.encode()).hexdigest()[:24]}.json"
    if cache and path.is_file():
        return json.loads(path.read_text())
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
                  reference_mean_m: float = REFERENCE_MEAN_M) -> dict[str, dict[str, float]]:
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
    model : Model, optional
        The nominal model; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters; the model's defaults by default.
    timing : Timing, optional
        Rates, limits and sensor.
    reference_mean_m : float
        Mean of the reference the rule tunes at.

    Returns
    -------
    dict
        ``{controller: {gain: value}}`` for each controller given, every gain filled in
        (checked by :func:`gain_array`).

    Raises
    ------
    ControlError
        On an unknown controller or gain name, or a bad gain.
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


def track(frequency_hz: float, *, controllers: Sequence[str] = CONTROLLERS,
          model: Model | None = None, params=None, duration_s: float = 10.0,
          gains: Mapping[str, Mapping[str, float]] | None = None,
          reference_mean_m: float | None = None) -> dict:
    """Metrics of each controller tracking one frequency (``pmabayes track``).

    Parameters
    ----------
    frequency_hz : float
        Reference frequency, > 0.
    controllers : sequence of str
        Which controllers to run.
    model : Model, optional
        Plant and controller model; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters; the paper's values by default.
    duration_s : float
        Length of each run.
    gains : mapping, optional
        Gains per controller, in full or in part; the rest by :func:`nominal_gains` on
        the model (:func:`resolve_gains`; :data:`DEFAULT_GAINS` for the paper's values).
    reference_mean_m : float, optional
        Mean of the reference; by default :func:`operating_mean_m` on the model
        (0.100 m, :data:`REFERENCE_MEAN_M`, for the paper's values).

    Returns
    -------
    dict
        ``{"frequency_hz": f, "reference_mean_m": mean, "controllers": {name:
        {"rms_error_m": ..., "max_error_m": ..., "amplitude_ratio": ...,
        "phase_lag_deg": ..., "overshoot_pct": ..., "dead_zone_fraction": ...,
        "saturated_fraction": ..., "period_difference_m": ...}}, "gains": {...}}``,
        the gains being those the runs used.
    """
    frequency_hz = _check_frequency(frequency_hz)
    model = _nominal_model(model)
    theta = _theta1(model, params)
    names = tuple(controllers)
    _controller_codes(names, len(names))
    if reference_mean_m is None:
        reference_mean_m = operating_mean_m(model, theta)
    used = resolve_gains(names, gains, model=model, params=theta,
                         reference_mean_m=reference_mean_m)
    run = closed_loop_batch(model, np.repeat(theta, len(names), axis=0), model,
                            np.repeat(theta, len(names), axis=0),
                            np.full(len(names), frequency_hz), names,
                            duration_s=duration_s, gains=gain_array(names, used),
                            reference_mean_m=reference_mean_m, record=False)
    m = loop_metrics(run)
    rows = run.metadata["gains"]
    return {"frequency_hz": frequency_hz, "reference_mean_m": float(reference_mean_m),
            "controllers": {c: {k: float(v[j]) for k, v in m.items()}
                            for j, c in enumerate(names)},
            "gains": {c: {k: float(rows[j, i]) for i, k in enumerate(_GAIN_NAMES[c])}
                      for j, c in enumerate(names)}}
