"""Physics of the built-in effects, user-defined effects, and composition errors.

Each effect is checked against what its physics predicts (a lag delays and
attenuates, a dead time shifts, friction widens the loop, stiffening reduces
large extensions, an offset shifts), at its null value against the base model,
and near the null for continuity and smoothness. Numbers to compare against
come from the RK4 reference in ``tests/reference_solver.py``, closed-form
physics, or independent root-finds.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from reference_solver import paper_chirp, reference_simulate
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq, minimize_scalar

import pmabayes as pb

DT = 1e-3
T, CHIRP = paper_chirp()
P = dict(pb.PAPER_VALUES)
MASS = 0.067
WEIGHT = MASS * 9.81
AREA = pb.PAPER_AREA_M2
RIG_KW = dict(mass=MASS, area=AREA, gravity_force=WEIGHT)

NULLS = {
    "regulator_lag": {"tau_reg": 0.0},
    "transport_delay": {"t_delay": 0.0},
    "coulomb_friction": {"F_c": 0.0},
    "cubic_stiffness": {"K3": 0.0},
    "pressure_stiffness": {"K_p": 0.0},
    "position_offset": {"x_offset": 0.0},
}
NEAR_NULLS = {
    "regulator_lag": {"tau_reg": 1e-9},
    "transport_delay": {"t_delay": 1e-9},
    "coulomb_friction": {"F_c": 1e-9},
    "cubic_stiffness": {"K3": 1e-9},
    "pressure_stiffness": {"K_p": 1e-12},
    "position_offset": {"x_offset": 1e-9},
}


def sim(effects, values, u=CHIRP, dt=DT, states=False):
    """One simulation of ``Model(effects)``; positions ``(n,)`` or the Simulation."""
    out = pb.simulate(pb.Model(effects), values, u, dt_s=dt, states=states)
    return out if states else out[0]


def base_positions():
    """The base model on the paper's chirp."""
    return sim([], None)


def xcorr_lag(a, b, max_lag=200):
    """Lag (samples) at which ``a`` best matches ``b`` delayed; > 0 when ``a`` trails."""
    a, b = a - a.mean(), b - b.mean()
    lags = np.arange(-max_lag, max_lag + 1)
    corr = [np.dot(a[max(k, 0):a.size + min(k, 0)], b[max(-k, 0):b.size - max(k, 0)])
            for k in lags]
    return int(lags[np.argmax(corr)])


def loop_area(x, p):
    """Area enclosed by the closed pressure-position curve (shoelace formula)."""
    return 0.5 * abs(np.sum(x * np.roll(p, -1) - np.roll(x, -1) * p))


def z_loading(x, x0):
    """Closed-form Bouc-Wen loading branch from ``z(x0) = 0`` (z > 0, x' > 0)."""
    c = P["beta"] + P["gamma"]
    return P["alpha"] / c * -np.expm1(-c * (x - x0))


def static_extension(pressure, extra_force, x0):
    """Root of ``K_e x + f(x, p) + z(x) + W = A (p - p_dz)`` on the loading branch."""
    def balance(x):
        return (P["K_e"] * x + extra_force(x, pressure) + z_loading(x, x0) + WEIGHT
                - AREA * (pressure - P["p_dz"]))

    return brentq(balance, 0.0, 0.2, xtol=1e-14)


def staircase(dt=DT, hold=20.0):
    """0 Pa for one sample, then 0.15 MPa and 0.45 MPa, each held ``hold`` s."""
    n = int(round(hold / dt))
    u = np.concatenate([[0.0], np.full(n, 0.15e6), np.full(n, 0.45e6)])
    return u, n  # sample n ends the low stair, sample 2n the high one


# ---------------------------------------------------------------------------------
# each built-in effect does what its physics says


def test_regulator_lag_delays_and_attenuates():
    """A 40 ms lag delays the response and shrinks it at 2-3 Hz by the lag's gain."""
    x0 = base_positions()
    lagged = sim(["regulator_lag"], {"tau_reg": 0.04}, states=True)
    x1 = lagged.position_m[0]
    lag = xcorr_lag(x1, x0)
    assert 0 < lag <= 40  # phase delay of a first-order lag is at most tau (40 samples)
    end = T >= 13.0  # 2.6-3 Hz
    assert np.ptp(x1[end]) < 0.95 * np.ptp(x0[end])  # measured 0.876
    # the acting pressure of the last cycle (~2.95 Hz) has the lag's gain 1/|1 + i w tau|
    last = T >= 15.0 - 1 / 2.95
    gain = np.ptp(lagged.pressure_pa[0][last]) / np.ptp(CHIRP[last])
    assert gain == pytest.approx(1 / np.hypot(1.0, 2 * np.pi * 2.95 * 0.04), rel=0.02)


def test_transport_delay_shifts_the_response():
    """A dead time shifts the whole response by t_delay without attenuating it."""
    t_delay = 0.0235
    x0, x1 = base_positions(), sim(["transport_delay"], {"t_delay": t_delay})
    shifted = CubicSpline(T, x0)
    low = (T > 0.5) & (T < 5.0)  # 0.2-1 Hz

    def misfit(s):
        return np.sum((x1[low] - shifted(T[low] - s)) ** 2)

    best = minimize_scalar(misfit, bounds=(0.0, 0.1), method="bounded",
                           options={"xatol": 1e-8}).x
    assert best == pytest.approx(t_delay, abs=1e-4)  # measured 0.0234999
    # a time-invariant system: the delayed trial is the base trial, later
    assert np.max(np.abs(x1[low] - shifted(T[low] - t_delay))) < 1e-6  # measured 2.7e-7
    end = T >= 13.0
    assert np.ptp(x1[end]) == pytest.approx(np.ptp(x0[end]), rel=0.01)  # no attenuation


def test_coulomb_friction_widens_the_hysteresis_loop():
    """Friction widens the pressure-position loop, as much as in the RK4 reference."""
    t = np.arange(6000) * DT
    u = 0.25e6 * (1.0 - np.cos(2 * np.pi * 0.5 * t))  # three slow cycles, 0-0.5 MPa
    last = t >= 4.0
    areas, ref_areas = [], []
    for f_c in (0.0, 1.0):
        x = sim(["coulomb_friction"], {"F_c": f_c}, u)
        areas.append(loop_area(x[last], u[last]))
        ref = reference_simulate(u, DT, F_c=f_c, **RIG_KW, **P).position_m
        ref_areas.append(loop_area(ref[last], u[last]))
    growth = areas[1] - areas[0]
    assert growth > 0.0
    # friction shifts x by at most F_c / K_e each way while p exceeds the dead zone
    assert growth < 2 * 1.0 / P["K_e"] * (0.5e6 - P["p_dz"])
    assert growth == pytest.approx(ref_areas[1] - ref_areas[0], rel=0.02)  # 333.2 vs 333.8


@pytest.mark.parametrize(
    ("effect", "values", "force"),
    [
        ("cubic_stiffness", {"K3": 2e4}, lambda x, p: 2e4 * x**3),
        ("pressure_stiffness", {"K_p": 3e-4}, lambda x, p: 3e-4 * p * x),
    ],
)
def test_stiffening_reduces_large_extensions_more(effect, values, force):
    """Extra stiffness cuts the high stair more, landing on the static balance."""
    u, n = staircase()
    x0 = sim([], None, u)
    x1 = sim([effect], values, u)
    low, high = x0[n] - x1[n], x0[2 * n] - x1[2 * n]
    assert 0.0 < low < high
    assert high > 3 * low  # measured 16x (cubic), 4.7x (pressure)
    # and the stairs end at the static balance including the extra stiffness
    x_rest = -WEIGHT / P["K_e"]
    assert x1[n] == pytest.approx(static_extension(0.15e6, force, x_rest), abs=1e-6)
    assert x1[2 * n] == pytest.approx(static_extension(0.45e6, force, x_rest), abs=1e-6)


def test_position_offset_shifts_every_sample_exactly():
    """The offset is added to every sample, bit for bit."""
    x0 = base_positions()
    x1 = sim(["position_offset"], {"x_offset": 5e-4})
    assert np.array_equal(x1, x0 + 5e-4)


# ---------------------------------------------------------------------------------
# null values, continuity and smoothness


@pytest.mark.parametrize("effect", list(NULLS))
def test_effect_at_its_null_value_is_the_base_model(effect):
    """At its null value an effect reproduces the base model to 1e-12 m."""
    assert pb.get_effect(effect).null_values() == NULLS[effect]
    x = sim([effect], NULLS[effect])
    assert np.max(np.abs(x - base_positions())) <= 1e-12


@pytest.mark.parametrize("effect", list(NEAR_NULLS))
def test_output_is_continuous_near_the_null(effect):
    """A tiny effect changes the output by at most 1e-6 m."""
    x = sim([effect], NEAR_NULLS[effect])
    assert np.max(np.abs(x - base_positions())) <= 1e-6  # t_delay: measured 3.3e-10 m


def test_output_is_smooth_in_the_delay():
    """Central differences at t_delay = 9.5, 10, 10.5 ms (10 ms is a whole sample).

    For the exact system dx/dt_delay = -x'(t): the first difference must match
    the reference velocity, and the second difference must be small.
    """
    h = 5e-4
    x = pb.simulate(pb.Model(["transport_delay"]), {"t_delay": np.array([0.0095, 0.01, 0.0105])},
                    CHIRP, dt_s=DT)
    d1 = x[2] - x[0]
    d2 = x[2] - 2 * x[1] + x[0]
    assert np.max(np.abs(d2)) < 0.05 * np.max(np.abs(d1))  # measured 0.014
    v = reference_simulate(CHIRP, DT, t_delay=0.01, **RIG_KW, **P).velocity_m_s
    assert np.max(np.abs(d1 / (2 * h) + v)) < 0.01 * np.max(np.abs(v))  # measured 0.4%


# ---------------------------------------------------------------------------------
# effects written outside the package


def quadratic_drag(q, x, v, p):
    """Drag ``c_quad v |v|`` and its derivatives with respect to x and v."""
    return q[0] * v * abs(v), 0.0, 2.0 * q[0] * abs(v)


class QuadraticDrag(pb.Effect):
    """Turbulent drag on the carriage, growing with the square of velocity."""

    name = "quadratic_drag"
    stage = "force"
    parameters = (
        pb.Parameter("c_quad", "N s^2/m^2", 200.0, pb.HalfNormal(500.0), bounds=(0.0, 1e5),
                     null=0.0, description="drag force per squared velocity"),
    )
    description = "Drag c_quad v |v| opposing motion."
    physics = staticmethod(quadratic_drag)


pb.register_effect(QuadraticDrag)


def pressure_bias(q, p_start, p_end, dt_s):
    """Add a constant bias to the pressure reaching the muscle."""
    n, batch = p_start.shape
    for k in range(n):
        for i in range(batch):
            p_start[k, i] += q[i, 0]
            p_end[k, i] += q[i, 0]


class PressureBias(pb.Effect):
    """Regulator with a constant pressure bias."""

    name = "test_pressure_bias"
    stage = "pressure"
    parameters = (pb.Parameter("p_bias", "Pa", 1e4, pb.Normal(0.0, 2e4), null=0.0),)
    description = "The regulator delivers p_bias more than commanded."
    physics = staticmethod(pressure_bias)


def sensor_drift(q, time_s, position_m):
    """Add a drift growing linearly with time to the measured position."""
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            position_m[k, i] += q[i, 0] * time_s[k]


class SensorDrift(pb.Effect):
    """Encoder zero drifting linearly in time."""

    name = "test_sensor_drift"
    stage = "measurement"
    parameters = (pb.Parameter("drift", "m/s", 1e-4, pb.Normal(0.0, 1e-3), null=0.0),)
    description = "The encoder's zero drifts by drift metres per second."
    physics = staticmethod(sensor_drift)


def test_user_force_effect_is_compiled_and_slows_the_muscle():
    """A user's quadratic drag is jitted, usable by name, and slows the muscle."""
    assert not isinstance(quadratic_drag, numba.core.registry.CPUDispatcher)
    assert isinstance(QuadraticDrag.physics, numba.core.registry.CPUDispatcher)
    assert pb.get_effect("quadratic_drag") is QuadraticDrag
    model = pb.Model(["quadratic_drag"])
    assert model.parameter_names[-1] == "c_quad"
    fast = pb.simulate(model, {"c_quad": 0.0}, CHIRP, dt_s=DT, states=True)
    slow = pb.simulate(model, {"c_quad": 200.0}, CHIRP, dt_s=DT, states=True)
    assert np.max(np.abs(fast.position_m - base_positions())) <= 1e-12
    v0, v1 = np.abs(fast.velocity_m_s).max(), np.abs(slow.velocity_m_s).max()
    assert v1 < 0.9 * v0  # measured 0.77
    # the recorded effect force is the drag law on the recorded velocity
    v = slow.velocity_m_s[0]
    assert np.max(np.abs(slow.effect_force_n[0] - 200.0 * v * np.abs(v))) < 1e-9


def test_user_pressure_effect_acts_like_a_lower_dead_zone():
    """A user's pressure bias b equals the base model with p_dz - b."""
    bias = 1.5e4
    x = sim([PressureBias], {"p_bias": bias})
    x_ref = pb.simulate(pb.Model(), {"p_dz": P["p_dz"] - bias}, CHIRP, dt_s=DT)[0]
    assert np.max(np.abs(x - base_positions())) > 1e-3
    assert np.max(np.abs(x - x_ref)) <= 1e-12


def test_user_measurement_effect_sees_time_and_batch():
    """A user's sensor drift gets the time axis and per-member parameters."""
    drift = np.array([0.0, 1e-4, -2e-4])
    out = pb.simulate(pb.Model([SensorDrift]), {"drift": drift}, CHIRP, dt_s=DT, states=True)
    x0 = base_positions()
    assert np.max(np.abs(out.true_position_m - x0)) <= 1e-15
    assert np.max(np.abs(out.position_m - (x0 + drift[:, None] * T))) <= 1e-15


# ---------------------------------------------------------------------------------
# composition errors


def test_parameter_clash_with_the_base_model_names_both_owners():
    """An effect declaring ``d`` is refused, naming the effect and the base model."""
    class ExtraDamping(pb.Effect):
        name = "extra_damping"
        stage = "force"
        parameters = (pb.Parameter("d", "N s/m", 1.0, pb.HalfNormal(1.0), null=0.0),)
        physics = staticmethod(quadratic_drag)

    with pytest.raises(pb.ModelError, match=r"'d' of effect 'extra_damping' .*the base model"):
        pb.Model([ExtraDamping])


def test_parameter_clash_between_effects_names_both_owners():
    """Two effects declaring ``F_c`` are refused, naming both."""
    class Stiction(pb.Effect):
        name = "stiction"
        stage = "force"
        parameters = (pb.Parameter("F_c", "N", 1.0, pb.HalfNormal(1.0), null=0.0),)
        physics = staticmethod(quadratic_drag)

    with pytest.raises(pb.ModelError, match="'F_c' of effect 'stiction' .*'coulomb_friction'"):
        pb.Model(["coulomb_friction", Stiction])


def test_registering_two_classes_under_one_name_raises():
    """A second class under a taken name is refused; the first stays registered."""
    class First(pb.Effect):
        name = "test_twice_registered"
        stage = "force"
        physics = staticmethod(quadratic_drag)

    class Second(pb.Effect):
        name = "test_twice_registered"
        stage = "force"
        physics = staticmethod(quadratic_drag)

    pb.register_effect(First)
    pb.register_effect(First)  # the same class again is harmless
    with pytest.raises(pb.EffectError, match="'test_twice_registered' is already registered"):
        pb.register_effect(Second)
    assert pb.get_effect("test_twice_registered") is First


def test_listing_an_effect_twice_raises():
    """The same effect listed twice (by name or class) is refused."""
    with pytest.raises(pb.EffectError, match="listed twice"):
        pb.Model(["coulomb_friction", "coulomb_friction"])
    with pytest.raises(pb.EffectError, match="listed twice"):
        pb.Model([QuadraticDrag, "quadratic_drag"])


def test_unknown_effect_name_lists_the_known_ones():
    """An unknown effect name is refused with the list of known ones."""
    with pytest.raises(pb.EffectError, match="unknown effect 'stickslip'.*regulator_lag"):
        pb.Model(["stickslip"])


def test_bad_stage_raises_at_class_definition():
    """An effect with an unknown stage fails when its class is defined."""
    with pytest.raises(pb.EffectError, match="stage 'input' must be one of"):
        class BadStage(pb.Effect):
            name = "bad_stage"
            stage = "input"
            physics = staticmethod(quadratic_drag)


def test_missing_physics_raises_at_class_definition():
    """An effect without physics fails when its class is defined."""
    with pytest.raises(pb.EffectError, match="physics = staticmethod"):
        class NoPhysics(pb.Effect):
            name = "no_physics"
            stage = "force"
            parameters = (pb.Parameter("k_np", "N/m", 1.0, pb.HalfNormal(1.0)),)


# -- what the closed loop asks of an effect ------------------------------------------


def test_builtin_hooks_give_history_lead_and_delay():
    q = np.array([[0.04], [0.0]])
    lag, delay = pb.get_effect("regulator_lag"), pb.get_effect("transport_delay")
    np.testing.assert_array_equal(lag.history_s(q), [1.6, 0.0])  # exp(-40) left
    np.testing.assert_array_equal(lag.lead_s(q), q[:, 0])
    np.testing.assert_array_equal(delay.history_s(np.array([[0.02], [-1e-3]])), [0.02, 0.0])
    np.testing.assert_array_equal(delay.lead_s(q), q[:, 0])
    longer = delay.add_delay(q, 0.02)
    np.testing.assert_array_equal(longer[:, 0], q[:, 0] + 0.02)
    assert q[0, 0] == 0.04  # the rows passed in are left alone
    assert lag.add_delay(q, 0.02) is None
    for name in ("coulomb_friction", "cubic_stiffness", "pressure_stiffness",
                 "position_offset"):
        eff = pb.get_effect(name)
        rows = np.ones((2, len(eff.parameters)))
        np.testing.assert_array_equal(eff.history_s(rows), [0.0, 0.0])
        np.testing.assert_array_equal(eff.lead_s(rows), [0.0, 0.0])
        assert eff.add_delay(rows, 0.02) is None


def test_delay_effect_is_registered_and_takes_delay():
    eff = pb.model.effects.delay_effect()
    assert pb.get_effect(eff.name) is eff and eff.stage == "pressure"
    q = np.array([[eff.null_values()[n] for n in eff.parameter_names()]])
    assert eff.add_delay(q, 0.02) is not None
    assert eff.lead_s(eff.add_delay(q, 0.02))[0] == pytest.approx(0.02)


def test_position_offset_inverse_undoes_its_physics():
    eff = pb.get_effect("position_offset")
    q = np.array([[3e-4], [-1e-3]])
    x = np.linspace(0.0, 0.05, 12).reshape(6, 2)
    y = x.copy()
    eff.physics(q, np.arange(6) * 1e-3, y)
    for k in range(6):
        for i in range(2):
            back, slope = eff.inverse(q[i], k * 1e-3, y[k, i])
            assert back == pytest.approx(x[k, i], abs=1e-15) and slope == 1.0
    for name in ("regulator_lag", "transport_delay", "coulomb_friction"):
        assert pb.get_effect(name).inverse is None


def test_user_inverse_is_compiled_and_only_for_measurements():
    def unwind(q, time_s, reading_m):
        return reading_m - q[0], 1.0

    class Offset2(pb.Effect):
        name = "offset_two"
        stage = "measurement"
        parameters = (pb.Parameter("x_off2", "m", 0.0, pb.Normal(0.0, 1e-3)),)
        physics = staticmethod(sensor_drift)
        inverse = staticmethod(unwind)

    assert isinstance(Offset2.inverse, numba.core.registry.CPUDispatcher)
    assert Offset2.inverse(np.array([1e-3]), 0.0, 0.5) == (0.499, 1.0)
    with pytest.raises(pb.EffectError, match="only a measurement effect may set"):
        class ForceInverse(pb.Effect):
            name = "force_inverse"
            stage = "force"
            parameters = (pb.Parameter("c_fi", "N s/m", 1.0, pb.HalfNormal(1.0)),)
            physics = staticmethod(quadratic_drag)
            inverse = staticmethod(unwind)
