"""The discrepancy step on a family of hidden effects it was not shaped on.

The data-driven discrepancy (:mod:`pmabayes.criticism.discrepancy`) was developed beside
the four hidden effects of :data:`pmabayes.synthetic.OUTSIDE_LIBRARY`. This study hides
nineteen others, written for it without reference to the step's dictionary of terms,
and asks of each diagnosis what a user would:

* a **force** (twelve effects: forces of other shapes and other states, a second
  hysteresis loop that is not symmetric, a Maxwell creep element of 150 N/m with a
  2 s damper): is the model brought within 1.5x the noise floor, by a library effect
  the diagnosis names or by the written proposal (its nonlinear refit, which is what
  adding it with ``--plugin`` does)?
* a **sensor or timing error** (seven: backlash of the position sensor, a gain error,
  a drift of its zero in time, a delay of the measurement, a first-order lag of the
  sensor, a quadratic calibration error, a slip of its mounting): does the diagnosis
  say that the missing piece is not a force (a measurement or pressure effect of the
  library named, or the discrepancy's verdict "not a force of the states tried"),
  without a force proposal that claims it?

Each data set draws its muscle from :data:`pmabayes.synthetic.PLAUSIBLE_REGION` and
the effect's size log-uniformly in its range, with its own seed. As a user would, a
library effect named missing is added and the data diagnosed again, once
(``MAX_LIBRARY_ROUNDS``); every registered effect is a candidate.

The family was split in two halves before the method was tuned on it
(:attr:`Member.half`): the tuning half was used while changing the method, the
held-out half run only at the end. Once run, the held-out half was no longer unseen,
so a third part (``fresh``: three forces and two sensor errors) was written before the
method was changed again, and run first on the method as it stood.

Usage::

    python analyses/discrepancy_family.py [--seeds 2] [--half tuning|held-out|fresh|all]
                                          [--effects NAME ...] [--seed 0]
                                          [--processes N] [--out DIR] [--quick]

Writes ``discrepancy_family.csv`` and ``discrepancy_family.md`` into ``--out``
(default ``paper/tables``) and prints the table last, then ``success_rate:``.
``--quick`` runs one data set per effect on 5 s chirps with 4 trials.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.model.effects import Effect, get_effect
from pmabayes.model.parameters import HalfNormal, Normal, Parameter
from pmabayes.parallel import Runner
from pmabayes.synthetic import Chirp, draw_plausible, generate_chirp_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent))
from detection import diagnose_as_a_user, write_rows  # noqa: E402

# ---------------------------------------------------------------------------------
# the hidden forces (never registered)


def _power_damping(q, x, v, p):
    # a damping force growing as |v|^1.5, against the motion in either direction
    r = math.sqrt(abs(v))
    return q[0] * v * r, 0.0, 1.5 * q[0] * r


class PowerDamping(Effect):
    """Damping growing as ``v |v|^0.5`` (between viscous and quadratic)."""

    __test__ = False
    name = "family_power_damping"
    stage = "force"
    parameters = (Parameter("c_pow", "N (s/m)^1.5", 10.0, HalfNormal(50.0),
                            bounds=(0.0, math.inf), null=0.0,
                            description="damping per |v|^1.5"),)
    description = "Damping growing as v |v|^0.5 (hidden; synthetic data)."
    physics = staticmethod(_power_damping)


def _squared_speed(q, x, v, p):
    # a force growing with the squared speed, always the same way (a jet, a pump)
    return q[0] * v * v, 0.0, 2.0 * q[0] * v


class SquaredSpeed(Effect):
    """A force ``c v^2`` opposing extension whichever way the muscle moves."""

    __test__ = False
    name = "family_squared_speed"
    stage = "force"
    parameters = (Parameter("c_v2", "N s^2/m^2", 15.0, HalfNormal(50.0),
                            bounds=(0.0, math.inf), null=0.0,
                            description="force per squared speed"),)
    description = "A force growing with the squared speed, sign-free (hidden)."
    physics = staticmethod(_squared_speed)


def _asym_loop(q, x, v, p, z, w):
    return w, 0.0, 0.0, 0.0, 1.0


def _asym_loop_advance(q, w, x0, x1, h):
    # a Dahl-like loop: w runs towards +W_up while extending and -W_down while
    # contracting, over a length delta; the two saturations differ
    dx = x1 - x0
    target = q[0] if dx >= 0.0 else -q[1]
    a = math.exp(-abs(dx) / q[2])
    sign = 1.0 if dx >= 0.0 else -1.0
    return target + (w - target) * a, -(w - target) * a * sign / q[2]


class AsymmetricLoop(Effect):
    """A second hysteresis loop (braid on bladder) saturating at different levels
    in extension and in contraction."""

    __test__ = False
    name = "family_asymmetric_loop"
    stage = "force"
    state = "w_loop_n"
    parameters = (
        Parameter("W_up", "N", 3.0, HalfNormal(10.0), bounds=(0.0, math.inf), null=0.0,
                  description="saturation while extending"),
        Parameter("W_down", "N", 1.0, HalfNormal(10.0), bounds=(0.0, math.inf), vary=False,
                  description="saturation while contracting"),
        Parameter("delta_loop", "m", 0.003, HalfNormal(0.01), bounds=(0.0, math.inf),
                  vary=False, description="length over which the loop saturates"),
    )
    description = "An asymmetric hysteresis loop (hidden; synthetic data)."
    physics = staticmethod(_asym_loop)
    advance = staticmethod(_asym_loop_advance)


def _maxwell(q, x, v, p, z, u):
    # the spring's stretch u (0 when relaxed, as at rest) pulls with k u
    return q[0] * u, 0.0, 0.0, 0.0, q[0]


def _maxwell_advance(q, u, x0, x1, h):
    # the dashpot gives way: u' = x' - u / tau, by the trapezoidal rule
    r = 0.5 * h / q[1]
    return (u * (1.0 - r) + (x1 - x0)) / (1.0 + r), 1.0 / (1.0 + r)


class MaxwellElement(Effect):
    """A spring in series with a dashpot (time constant ``tau_mx``), beside the muscle,
    its stretch integrated by the trapezoidal rule."""

    __test__ = False
    name = "family_maxwell"
    stage = "force"
    state = "u_stretch_m"
    parameters = (
        Parameter("k_mx", "N/m", 150.0, HalfNormal(500.0), bounds=(0.0, math.inf), null=0.0,
                  description="the element's spring"),
        Parameter("tau_mx", "s", 2.0, HalfNormal(5.0), bounds=(0.0, math.inf), vary=False,
                  description="its relaxation time"),
    )
    description = "A Maxwell element, 150 N/m with a 2 s damper (hidden)."
    physics = staticmethod(_maxwell)
    advance = staticmethod(_maxwell_advance)


def _position_friction(q, x, v, p):
    # friction whose level grows with the extension (the braid's normal force)
    level = q[0] * (0.3 + x / 0.05)
    t = math.tanh(v / 0.003)
    return level * t, q[0] / 0.05 * t, level * (1.0 - t * t) / 0.003


class PositionFriction(Effect):
    """Friction ``F0 (0.3 + x / 50 mm) tanh(v / 3 mm/s)``."""

    __test__ = False
    name = "family_position_friction"
    stage = "force"
    parameters = (Parameter("F_pf", "N", 2.0, HalfNormal(5.0), bounds=(0.0, math.inf),
                            null=0.0, description="friction level at 50 mm"),)
    description = "Friction growing with the extension (hidden)."
    physics = staticmethod(_position_friction)


def _sqrt_pressure_stiffness(q, x, v, p):
    s = math.sqrt(max(p, 0.0) / 5e5)
    return q[0] * s * x, q[0] * s, 0.0


class SqrtPressureStiffness(Effect):
    """A stiffness growing as the square root of the pressure."""

    __test__ = False
    name = "family_sqrt_pressure_stiffness"
    stage = "force"
    parameters = (Parameter("k_sp", "N/m", 100.0, HalfNormal(500.0), bounds=(0.0, math.inf),
                            null=0.0, description="stiffness at 0.5 MPa"),)
    description = "Stiffness growing with sqrt(p) (hidden)."
    physics = staticmethod(_sqrt_pressure_stiffness)


def _threshold_hardening(q, x, v, p):
    d = x - 0.045
    if d > 0.0:
        return q[0] * d * d * d, 3.0 * q[0] * d * d, 0.0
    return 0.0, 0.0, 0.0


class ThresholdHardening(Effect):
    """A cubic hardening acting only beyond 45 mm of extension."""

    __test__ = False
    name = "family_threshold_hardening"
    stage = "force"
    parameters = (Parameter("k3_th", "N/m^3", 4e4, HalfNormal(1e5), bounds=(0.0, math.inf),
                            null=0.0, description="cubic stiffness beyond 45 mm"),)
    description = "Cubic hardening beyond a threshold (hidden)."
    physics = staticmethod(_threshold_hardening)


def _bump(q, x, v, p):
    u = (x - 0.03) / 0.004
    e = math.exp(-u * u)
    return q[0] * e, -2.0 * q[0] * u * e / 0.004, 0.0


class PositionBump(Effect):
    """A local obstacle: a Gaussian bump of force around 30 mm (4 mm wide)."""

    __test__ = False
    name = "family_position_bump"
    stage = "force"
    parameters = (Parameter("A_bump", "N", 2.0, HalfNormal(5.0), bounds=(0.0, math.inf),
                            null=0.0, description="height of the bump"),)
    description = "A bump of force at one position (hidden)."
    physics = staticmethod(_bump)


def _exponential_friction(q, x, v, p):
    e = math.exp(-abs(v) / 0.03)
    s = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return q[0] * (1.0 - e) * s, 0.0, q[0] * e / 0.03


class ExponentialFriction(Effect):
    """Friction rising to its level as ``1 - exp(-|v| / 30 mm/s)``."""

    __test__ = False
    name = "family_exponential_friction"
    stage = "force"
    parameters = (Parameter("F_ef", "N", 2.0, HalfNormal(5.0), bounds=(0.0, math.inf),
                            null=0.0, description="friction level"),)
    description = "Friction saturating exponentially with speed (hidden)."
    physics = staticmethod(_exponential_friction)


# ---------------------------------------------------------------------------------
# the hidden sensor and timing errors (measurement stage; never registered)


def _backlash(q, time_s, position_m):
    # the reading stays until the position leaves a band of width b around it
    n, batch = position_m.shape
    for i in range(batch):
        half = 0.5 * q[i, 0]
        r = position_m[0, i]
        for k in range(n):
            x = position_m[k, i]
            if x - r > half:
                r = x - half
            elif r - x > half:
                r = x + half
            position_m[k, i] = r


class SensorBacklash(Effect):
    """Backlash (play) between the muscle and the position sensor."""

    __test__ = False
    name = "family_sensor_backlash"
    stage = "measurement"
    parameters = (Parameter("b_play", "m", 5e-4, HalfNormal(1e-3), bounds=(0.0, 0.01),
                            null=0.0, description="width of the play"),)
    description = "Backlash of the position sensor (hidden)."
    physics = staticmethod(_backlash)


def _gain(q, time_s, position_m):
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            position_m[k, i] *= 1.0 + q[i, 0]


class SensorGain(Effect):
    """A gain error of the position sensor."""

    __test__ = False
    name = "family_sensor_gain"
    stage = "measurement"
    parameters = (Parameter("g_sensor", "1", 0.05, Normal(0.0, 0.1), null=0.0,
                            description="relative gain error"),)
    description = "Gain error of the position sensor (hidden)."
    physics = staticmethod(_gain)


def _drift(q, time_s, position_m):
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            position_m[k, i] += q[i, 0] * (time_s[k] - time_s[0])


class SensorDrift(Effect):
    """The sensor's zero drifting in time (thermal), the same in every trial."""

    __test__ = False
    name = "family_sensor_drift"
    stage = "measurement"
    parameters = (Parameter("r_drift", "m/s", 4e-5, Normal(0.0, 1e-4), null=0.0,
                            description="drift rate"),)
    description = "A drift of the sensor's zero (hidden)."
    physics = staticmethod(_drift)


def _delay(q, time_s, position_m):
    # the reading of time t is the position of t - d (linear interpolation; the
    # first position before the start)
    n, batch = position_m.shape
    dt = time_s[1] - time_s[0]
    for i in range(batch):
        shift = q[i, 0] / dt
        m = int(math.floor(shift))
        frac = shift - m
        for k in range(n - 1, -1, -1):
            a = k - m
            b = a - 1
            xa = position_m[max(a, 0), i] if a < n else position_m[n - 1, i]
            xb = position_m[max(b, 0), i]
            position_m[k, i] = (1.0 - frac) * xa + frac * xb


class MeasurementDelay(Effect):
    """The position read late by a fixed delay (a sensor's buffer)."""

    __test__ = False
    name = "family_measurement_delay"
    stage = "measurement"
    parameters = (Parameter("d_meas", "s", 0.01, HalfNormal(0.01), bounds=(0.0, 0.1),
                            null=0.0, description="delay of the reading"),)
    description = "A delay of the measurement (hidden)."
    physics = staticmethod(_delay)


def _sensor_lag(q, time_s, position_m):
    n, batch = position_m.shape
    dt = time_s[1] - time_s[0]
    for i in range(batch):
        a = math.exp(-dt / q[i, 0])
        r = position_m[0, i]
        for k in range(n):
            r = a * r + (1.0 - a) * position_m[k, i]
            position_m[k, i] = r


class SensorLag(Effect):
    """A first-order low-pass of the position reading (the sensor's filter)."""

    __test__ = False
    name = "family_sensor_lag"
    stage = "measurement"
    parameters = (Parameter("tau_sensor", "s", 0.005, HalfNormal(0.01), bounds=(0.0, 0.1),
                            null=0.0, description="the filter's time constant"),)
    description = "A first-order lag of the sensor (hidden)."
    physics = staticmethod(_sensor_lag)


# ---------------------------------------------------------------------------------
# the third part ("fresh"), written after the held-out half had been run and before the
# method was changed again: its first run is the baseline of that change


def _saturating_spring(q, x, v, p):
    # a spring (a strap, a sleeve) that stops pulling harder past its travel
    t = math.tanh((x - 0.03) / 0.01)
    return q[0] * t, q[0] * (1.0 - t * t) / 0.01, 0.0


class SaturatingSpring(Effect):
    """A spring force ``F_s tanh((x - 30 mm) / 10 mm)`` that saturates either side."""

    __test__ = False
    name = "family_saturating_spring"
    stage = "force"
    parameters = (Parameter("F_sat", "N", 2.0, HalfNormal(5.0), bounds=(0.0, math.inf),
                            null=0.0, description="the spring's saturated force"),)
    description = "A saturating spring (hidden; synthetic data)."
    physics = staticmethod(_saturating_spring)


def _pressure_friction(q, x, v, p):
    # friction pressed by the pressure (the bladder on the braid), smoothed at rest
    s = max(p, 0.0) / 5e5
    t = math.tanh(v / 0.002)
    return q[0] * s * t, 0.0, q[0] * s * (1.0 - t * t) / 0.002


class PressureFriction(Effect):
    """Friction ``F_p (p / 0.5 MPa) tanh(v / 2 mm/s)``, growing with the pressure."""

    __test__ = False
    name = "family_pressure_friction"
    stage = "force"
    parameters = (Parameter("F_pfr", "N", 2.0, HalfNormal(5.0), bounds=(0.0, math.inf),
                            null=0.0, description="friction level at 0.5 MPa"),)
    description = "Friction growing with the pressure (hidden; synthetic data)."
    physics = staticmethod(_pressure_friction)


def _asymmetric_friction(q, x, v, p):
    # a seal rubbing harder one way than the other
    t = math.tanh(v / 0.002)
    level = q[0] * (1.5 if v > 0.0 else 0.5)
    return level * t, 0.0, level * (1.0 - t * t) / 0.002


class AsymmetricFriction(Effect):
    """Friction three times stronger while extending than while contracting."""

    __test__ = False
    name = "family_asymmetric_friction"
    stage = "force"
    parameters = (Parameter("F_afr", "N", 1.5, HalfNormal(5.0), bounds=(0.0, math.inf),
                            null=0.0, description="mean friction level"),)
    description = "Friction that differs with the direction (hidden; synthetic data)."
    physics = staticmethod(_asymmetric_friction)


def _sensor_curve(q, time_s, position_m):
    # a string potentiometer's nonlinearity: the reading bends away over its range
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            x = position_m[k, i]
            position_m[k, i] = x + q[i, 0] * x * x / 0.05


class SensorCurve(Effect):
    """A quadratic calibration error of the position sensor (``k x^2 / 50 mm``)."""

    __test__ = False
    name = "family_sensor_curve"
    stage = "measurement"
    parameters = (Parameter("k_curve", "1", 0.05, Normal(0.0, 0.1), null=0.0,
                            description="bend of the reading at 50 mm"),)
    description = "A nonlinear sensor calibration (hidden; synthetic data)."
    physics = staticmethod(_sensor_curve)


def _sensor_offset_jump(q, time_s, position_m):
    # the sensor slips on its mounting half-way through each trial
    n, batch = position_m.shape
    t_mid = 0.5 * (time_s[0] + time_s[n - 1])
    for k in range(n):
        if time_s[k] >= t_mid:
            for i in range(batch):
                position_m[k, i] += q[i, 0]


class SensorSlip(Effect):
    """The position reading jumps by a fixed amount half-way through each trial."""

    __test__ = False
    name = "family_sensor_slip"
    stage = "measurement"
    parameters = (Parameter("j_slip", "m", 5e-4, Normal(0.0, 1e-3), null=0.0,
                            description="the jump of the reading"),)
    description = "A slip of the sensor's mounting (hidden; synthetic data)."
    physics = staticmethod(_sensor_offset_jump)


# ---------------------------------------------------------------------------------
# the family, and its halves


@dataclass(frozen=True)
class Member:
    """One hidden effect of the family: its class, its size parameter and range, and
    whether it is a force or a sensor/timing error."""

    effect: type
    parameter: str
    low: float
    high: float
    kind: str  # "force" or "sensor"
    half: str  # "tuning", "held-out" or "fresh"


#: the family; the halves were fixed before the method was tuned on any of it
FAMILY = (
    Member(PowerDamping, "c_pow", 8.0, 25.0, "force", "tuning"),
    Member(AsymmetricLoop, "W_up", 2.0, 5.0, "force", "tuning"),
    Member(MaxwellElement, "k_mx", 150.0, 150.0, "force", "tuning"),
    Member(PositionFriction, "F_pf", 1.0, 4.0, "force", "tuning"),
    Member(ThresholdHardening, "k3_th", 2e4, 8e4, "force", "tuning"),
    Member(SensorBacklash, "b_play", 3e-4, 1e-3, "sensor", "tuning"),
    Member(SensorDrift, "r_drift", 2e-5, 6e-5, "sensor", "tuning"),
    Member(SquaredSpeed, "c_v2", 10.0, 30.0, "force", "held-out"),
    Member(SqrtPressureStiffness, "k_sp", 50.0, 150.0, "force", "held-out"),
    Member(PositionBump, "A_bump", 1.0, 4.0, "force", "held-out"),
    Member(ExponentialFriction, "F_ef", 1.0, 3.0, "force", "held-out"),
    Member(SensorGain, "g_sensor", 0.03, 0.08, "sensor", "held-out"),
    Member(MeasurementDelay, "d_meas", 0.005, 0.015, "sensor", "held-out"),
    Member(SensorLag, "tau_sensor", 0.003, 0.01, "sensor", "held-out"),
    Member(SaturatingSpring, "F_sat", 1.0, 4.0, "force", "fresh"),
    Member(PressureFriction, "F_pfr", 1.0, 4.0, "force", "fresh"),
    Member(AsymmetricFriction, "F_afr", 1.0, 3.0, "force", "fresh"),
    Member(SensorCurve, "k_curve", 0.03, 0.08, "sensor", "fresh"),
    Member(SensorSlip, "j_slip", 3e-4, 1e-3, "sensor", "fresh"),
)

#: library effects a data set may have added (each named missing in turn) before the
#: discrepancy step is judged, as in ``analyses/detection.py``
MAX_LIBRARY_ROUNDS = 1

#: a force is fixed when the model reaches this ratio of RMS error to the floor
WITHIN_FLOOR = 1.5


def member(name: str) -> Member:
    """The family's member of that effect name."""
    return next(m for m in FAMILY if m.effect.name == name)


def dataset(m: Member, size: float, truth: dict, seed: int, chirp: Chirp, n_trials: int):
    """The data set of one member at one size, muscle and seed."""
    extra = {"W_down": size / 3.0} if m.effect is AsymmetricLoop else {}
    return generate_chirp_dataset(n_trials=n_trials, seed=seed, chirp=chirp, params=truth,
                                  effects={m.effect: {m.parameter: size, **extra}},
                                  description=f"base model plus {m.effect.name} (synthetic)")


def not_a_force(disc) -> bool:
    """Whether the discrepancy's verdict says the missing piece is not a force of the
    states tried (older versions: that it may not be one)."""
    if disc is None:
        return False
    flag = getattr(disc, "not_a_force", None)
    return bool(disc.other_cause is not None) if flag is None else bool(flag)


def run_one(job: dict) -> dict:
    """Diagnose one data set as a user would; what the study reads of it."""
    m = member(job["effect"])
    ds = dataset(m, job["size"], job["truth"], job["seed"], job["chirp"], job["n_trials"])
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        d, added, first_ratio = diagnose_as_a_user(ds, DiagnoseSettings(max_refits=3),
                                                   job["seed"], folder, MAX_LIBRARY_ROUNDS)
    disc = d.discrepancy
    prop = None if disc is None else disc.proposal
    verified = None if prop is None else prop.verified
    return {"first_ratio": first_ratio, "added": added,
            "missing": d.missing or "", "adequate": d.adequate,
            "ratio": d.experiments[0].signature.ratio,
            "top_state": disc.states[0].state if disc is not None and disc.states else "",
            "explained": disc.explained if disc is not None else math.nan,
            "proposal": "" if prop is None else prop.expression,
            "verified_ratio": verified["ratio"] if verified else math.nan,
            "not_a_force": not_a_force(disc),
            "other_cause": (disc.other_cause or "") if disc is not None else "",
            "seconds": time.perf_counter() - start}


def judge(m: Member, r: dict) -> tuple[bool, str]:
    """Whether the diagnosis got this member right, and what it did, in a few words."""
    named = [*r["added"], *([r["missing"]] if r["missing"] else [])]
    stages = {get_effect(e).stage for e in named}
    if r["first_ratio"] <= WITHIN_FLOOR and not r["added"] and r["adequate"]:
        return False, "invisible (adequate at once)"
    if m.kind == "force":
        if r["adequate"] and r["ratio"] <= WITHIN_FLOOR:
            return True, f"library {'+'.join(named)} ({r['ratio']:.2f}x)"
        v = r["verified_ratio"]
        if math.isfinite(v) and v <= WITHIN_FLOOR:
            return True, f"proposal {v:.2f}x"
        if r["not_a_force"]:
            return False, "called not a force" + (f" (proposal {v:.2f}x)"
                                                  if math.isfinite(v) else "")
        return False, (f"proposal {v:.2f}x" if math.isfinite(v)
                       else f"no proposal ({r['ratio']:.2f}x)")
    # a sensor or timing error: not a force
    if stages and stages <= {"measurement", "pressure"}:
        return True, f"library {'+'.join(named)} (not a force)"
    v = r["verified_ratio"]
    if r["not_a_force"] and not (math.isfinite(v) and v <= WITHIN_FLOOR):
        return True, "not a force" + (f" ({'+'.join(named)} first)" if named else "")
    if math.isfinite(v) and v <= WITHIN_FLOOR:
        return False, f"force proposal {v:.2f}x"
    if r["adequate"]:
        return False, f"a force named: {'+'.join(named)}"
    return False, (f"not called not a force (proposal {v:.2f}x)" if math.isfinite(v)
                   else "not called not a force")


def _jobs(members, n_seeds: int, chirp: Chirp, n_trials: int, rng) -> list[dict]:
    """Every data set's recipe, drawn in order from the study's seed."""
    jobs = []
    for m in FAMILY:  # drawn for every member, so a member's data do not depend on
        for _ in range(n_seeds):  # which others were asked for
            size = float(np.exp(rng.uniform(np.log(m.low), np.log(m.high))))
            job = {"effect": m.effect.name, "size": size, "truth": draw_plausible(rng),
                   "seed": int(rng.integers(2**31)), "chirp": chirp, "n_trials": n_trials}
            if m in members:
                jobs.append(job)
    return jobs


def table(rows: list[dict]) -> list[str]:
    """The table: per member its data sets, what the diagnosis did, and the success
    rate per half and overall."""
    lines = ["| half | hidden effect | kind | data sets | right | what the diagnosis did |",
             "|---|---|---|---|---|---|"]
    for m in FAMILY:
        sel = [r for r in rows if r["effect"] == m.effect.name]
        if sel:
            what = "; ".join(r["outcome"] for r in sel)
            lines.append(f"| {m.half} | {m.effect.name.removeprefix('family_')} | {m.kind} | "
                         f"{len(sel)} | {sum(r['right'] for r in sel)} | {what} |")
    for half in ("tuning", "held-out", "fresh"):
        sel = [r for r in rows if r["half"] == half]
        if sel:
            k = sum(r["right"] for r in sel)
            lines.append(f"| {half} | all | | {len(sel)} | {k} | {k / len(sel):.0%} |")
    k = sum(r["right"] for r in rows)
    lines.append(f"| every part | all | | {len(rows)} | {k} | {k / max(len(rows), 1):.0%} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    """Run the study, write its table and print it last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="data sets per effect (2)")
    parser.add_argument("--half", choices=("tuning", "held-out", "fresh", "all"), default="all")
    parser.add_argument("--effects", nargs="+", default=None,
                        choices=[m.effect.name for m in FAMILY])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--processes", type=int, default=None,
                        help="local worker processes (every core by default)")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1]
                        / "paper" / "tables")
    parser.add_argument("--quick", action="store_true", help="one short data set each")
    args = parser.parse_args(argv)
    chirp, n_trials, n_seeds = Chirp(duration_s=8.0, f0_hz=0.3, f1_hz=3.0), 6, args.seeds
    if args.quick:
        chirp, n_trials, n_seeds = Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=3.0), 4, 1
    if n_seeds < 1:
        parser.error("--seeds must be at least 1")
    members = [m for m in FAMILY if (args.half in ("all", m.half))
               and (args.effects is None or m.effect.name in args.effects)]
    jobs = _jobs(members, n_seeds, chirp, n_trials, np.random.default_rng(args.seed))
    rows = []
    start = time.perf_counter()
    with Runner(args.processes, tasks=len(jobs)) as runner:
        for job, r in zip(jobs, runner.map(run_one, jobs), strict=True):
            m = member(job["effect"])
            right, outcome = judge(m, r)
            rows.append({"effect": m.effect.name, "half": m.half, "kind": m.kind,
                         "size": job["size"], "seed": job["seed"],
                         "first_ratio": r["first_ratio"], "added": "+".join(r["added"]),
                         "missing": r["missing"], "ratio": r["ratio"],
                         "top_state": r["top_state"], "explained": r["explained"],
                         "proposal": r["proposal"], "verified_ratio": r["verified_ratio"],
                         "not_a_force": r["not_a_force"], "right": right, "outcome": outcome,
                         "other_cause": r["other_cause"], "seconds": r["seconds"]})
            print(f"{m.effect.name} {m.parameter}={job['size']:.4g} (seed {job['seed']}): "
                  f"{r['first_ratio']:.3g}x at first, state {r['top_state'] or '-'}, "
                  f"proposal {r['proposal'] or '-'}; {outcome}; right {right}; "
                  f"{r['seconds']:.0f} s", flush=True)
    write_rows(args.out / "discrepancy_family.csv", rows)
    lines = table(rows)
    (args.out / "discrepancy_family.md").write_text("\n".join(lines) + "\n")
    print(f"{len(rows)} data sets in {time.perf_counter() - start:.0f} s")
    print("\n".join(lines))
    print(f"success_rate: {sum(r['right'] for r in rows) / len(rows):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
