"""Verification of :func:`pmabayes.simulate` against an independent RK4 reference.

The yardstick is ``tests/reference_solver.py``: classical RK4 on 64 substeps per
sample interval of the continuous-time model, sharing no code with pmabayes. Rig
constants are typed in here from the paper (67 g moving mass, g = 9.81 m/s^2),
not read from the package, except the derived area, which is checked separately
against an independent root-find of the static balance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from reference_solver import paper_chirp, reference_simulate
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import pmabayes as pb

DT = 1e-3
T, CHIRP = paper_chirp()  # 15 s, 0.1 -> 3 Hz, 0 -> 0.5 MPa at 1 kHz
P = dict(pb.PAPER_VALUES)
MASS = 0.067  # carriage 45 g + muscle 22 g
G = 9.81
WEIGHT = MASS * G  # gravity opposes extension on the characterisation rig (s_g = +1)
AREA = pb.PAPER_AREA_M2
RIG_KW = dict(mass=MASS, area=AREA, gravity_force=WEIGHT)

#: Effects at sizes a lab would care about (t_delay is not a multiple of dt).
LAB_EFFECTS = {
    "regulator_lag": {"tau_reg": 0.04},
    "transport_delay": {"t_delay": 0.0235},
    # v_c given explicitly: the package's default smoothing velocity (2 mm/s)
    "coulomb_friction": {"F_c": 1.0, "v_c": 2e-3},
    "cubic_stiffness": {"K3": 2e4},
    "pressure_stiffness": {"K_p": 3e-4},
    "position_offset": {"x_offset": 5e-4},
}
ALL_EFFECTS = list(LAB_EFFECTS)
ALL_LAB_VALUES = {k: v for kw in LAB_EFFECTS.values() for k, v in kw.items()}

#: Benchmark values of the force-driven Bouc-Wen oscillator (Noel & Schoukens 2016):
#: beta = beta_bench * gamma_bench, gamma = beta_bench * delta_bench.
BENCH = {"alpha": 5e4, "beta": 800.0, "gamma": -1100.0, "d": 10.0, "K_e": 5e4}
BENCH_MASS = 2.0
BENCH_FS = 750.0


def max_err(a, b) -> float:
    """Largest absolute difference of two arrays."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def multisine(seed: int = 7, fs: float = BENCH_FS, duration: float = 2.0, rms: float = 50.0):
    """Random-phase multisine on the 5-150 Hz bins of a ``duration`` record.

    Returns
    -------
    numpy.ndarray
        Force in N, ``rms`` N root mean square.
    """
    n = int(round(duration * fs))
    t = np.arange(n) / fs
    freqs = np.arange(1, n // 2) / duration
    freqs = freqs[(freqs >= 5.0) & (freqs <= 150.0)]
    phases = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, freqs.size)
    u = np.cos(2.0 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0)
    return u * rms / np.sqrt(np.mean(u**2))


def z_loading(x, x0):
    """Bouc-Wen loading branch from ``z(x0) = 0`` by numerical integration of dz/dx.

    Uses the full law ``dz/dx = alpha - (beta sgn(z) + gamma) |z|`` (``dx > 0``)
    with a tight-tolerance ODE solver, not the closed form.
    """
    def dzdx(_, z):
        return [P["alpha"] - (P["beta"] * np.sign(z[0]) + P["gamma"]) * abs(z[0])]

    sol = solve_ivp(dzdx, (x0, x), [0.0], method="DOP853", rtol=1e-13, atol=1e-14)
    return float(sol.y[0, -1])


# ---------------------------------------------------------------------------------
# the yardstick itself


def test_rig_constants_are_the_papers():
    """The characterisation rig carries the paper's 67 g, s_g = +1 and g = 9.81."""
    rig = pb.Rig.characterisation()
    assert rig.moving_mass_kg == pytest.approx(MASS, abs=1e-15)
    assert rig.gravity_sign == 1.0
    assert rig.g_m_s2 == G
    assert rig.area_m2 == AREA


@pytest.mark.parametrize("effects", [{}, ALL_LAB_VALUES], ids=["base", "all_effects"])
def test_reference_self_convergence(effects):
    """64 and 128 RK4 substeps agree to 1e-8 m over the paper's chirp."""
    coarse = reference_simulate(CHIRP, DT, substeps=64, **RIG_KW, **P, **effects)
    fine = reference_simulate(CHIRP, DT, substeps=128, **RIG_KW, **P, **effects)
    assert max_err(coarse.position_m, fine.position_m) < 1e-8


def test_reference_agrees_with_scipy_dop853():
    """The RK4 yardstick against scipy's adaptive 8th-order DOP853, interval by interval."""
    dt, n = 0.01, 250  # 2.5 s of the chirp, sampled coarsely so the check is quick
    t = np.arange(n) * dt
    u = 0.25e6 * (1.0 - np.cos(2.0 * np.pi * (0.1 * t + 2.9 / 30.0 * t**2)))

    def rhs(_, y, p):
        x, v, z = y
        acc = (AREA * max(p - P["p_dz"], 0.0) - WEIGHT - P["d"] * v - P["K_e"] * x - z) / MASS
        sgn = 1.0 if v * z >= 0.0 else -1.0
        return [v, acc, v * (P["alpha"] - (P["beta"] * sgn + P["gamma"]) * abs(z))]

    y = np.array([-WEIGHT / P["K_e"], 0.0, 0.0])
    dop = [y[0]]
    for k in range(n - 1):
        y = solve_ivp(rhs, (0.0, dt), y, args=(u[k],), method="DOP853", rtol=1e-12,
                      atol=1e-14).y[:, -1]
        dop.append(y[0])
    ref = reference_simulate(u, dt, substeps=640, **RIG_KW, **P)
    assert np.ptp(dop) > 0.05  # the muscle does move
    assert max_err(ref.position_m, dop) < 1e-9


def test_reference_delay_is_the_base_trial_shifted():
    """A half-sample delay at 1 kHz equals the undelayed trial read 23.5 ms earlier.

    The undelayed trial is run at 0.5 ms on the same held input, so that
    ``t_k - t_delay`` falls on its grid (sample ``2k - 47``).
    """
    delayed = reference_simulate(CHIRP, DT, t_delay=0.0235, **RIG_KW, **P)
    half = reference_simulate(np.repeat(CHIRP, 2), DT / 2, substeps=32, **RIG_KW, **P)
    k = np.arange(24, CHIRP.size)
    assert max_err(delayed.position_m[k], half.position_m[2 * k - 47]) < 1e-12
    assert max_err(delayed.pressure_pa[k], CHIRP[k - 24]) == 0.0


def test_reference_lag_follows_the_exponential_step_response():
    """The reference's regulator state is the exact first-order step response."""
    u = np.full(200, 3e5)
    u[0] = 1e5
    ref = reference_simulate(u, DT, tau_reg=0.04, **RIG_KW, **P)
    t = np.arange(200) * DT
    exact = 3e5 - 2e5 * np.exp(-np.maximum(t - DT, 0.0) / 0.04)  # command steps at t = 1 ms
    assert max_err(ref.pressure_pa, exact) < 1e-6  # Pa


# ---------------------------------------------------------------------------------
# accuracy against the reference


@pytest.mark.parametrize(
    "rig",
    [pb.Rig.characterisation(), pb.Rig.control()],
    ids=["characterisation", "control"],
)
def test_base_model_accuracy_on_the_paper_chirp(rig, record_property):
    """Base model within 1e-5 m of RK4 on the 15 s chirp at 1 kHz, on both rigs."""
    x = pb.simulate(pb.Model(rig=rig), None, CHIRP, dt_s=DT)[0]
    mass = MASS + (0.5 if rig.gravity_sign < 0 else 0.0)
    ref = reference_simulate(CHIRP, DT, mass=mass, area=AREA,
                             gravity_force=mass * G * rig.gravity_sign, **P)
    err = max_err(x, ref.position_m)
    record_property("max_abs_error_m", err)
    assert np.ptp(ref.position_m) > 0.05
    assert err <= 1e-5  # measured 6.3e-8 m (characterisation), 1 kHz


@pytest.mark.parametrize("effect", [*ALL_EFFECTS, "all"])
def test_effect_accuracy_on_the_paper_chirp(effect, record_property):
    """Each effect at a lab-relevant size (and all together) within 1e-5 m of RK4.

    Measured at 1 kHz: regulator_lag 5.1e-7, transport_delay 1.65e-6,
    coulomb_friction 2.2e-6 (v_c = 2 mm/s; 1.0e-5 at v_c = 1 mm/s, which needs
    substeps=2), cubic_stiffness 1.4e-7, pressure_stiffness 5.1e-8,
    position_offset 6.3e-8, all six together 1.0e-6 m.
    """
    names = ALL_EFFECTS if effect == "all" else [effect]
    values = ALL_LAB_VALUES if effect == "all" else LAB_EFFECTS[effect]
    x = pb.simulate(pb.Model(names), values, CHIRP, dt_s=DT)[0]
    ref = reference_simulate(CHIRP, DT, **RIG_KW, **P, **values)
    err = max_err(x, ref.position_m)
    record_property("max_abs_error_m", err)
    assert err <= 1e-5


def test_recorded_states_match_the_reference():
    """Velocity, z and acting pressure of the base model and of the pressure effects."""
    sim = pb.simulate(pb.Model(), None, CHIRP, dt_s=DT, states=True)
    ref = reference_simulate(CHIRP, DT, **RIG_KW, **P)
    assert max_err(sim.time_s, T) == 0.0
    assert np.array_equal(sim.position_m, sim.true_position_m)
    assert max_err(sim.velocity_m_s[0], ref.velocity_m_s) < 1e-5  # measured 6.3e-7 of 0.26 m/s
    assert max_err(sim.hysteresis_n[0], ref.hysteresis_n) < 1e-3  # measured 4.9e-5 of 17 N
    assert np.array_equal(sim.pressure_pa[0], CHIRP)
    assert np.all(sim.effect_force_n == 0.0)

    lag = pb.simulate(pb.Model(["regulator_lag"]), {"tau_reg": 0.04}, CHIRP, dt_s=DT,
                      states=True)
    ref = reference_simulate(CHIRP, DT, tau_reg=0.04, **RIG_KW, **P)
    assert max_err(lag.pressure_pa[0], ref.pressure_pa) < 20.0  # Pa, of 0.5 MPa; measured 8

    delay = pb.simulate(pb.Model(["transport_delay"]), {"t_delay": 0.0235}, CHIRP, dt_s=DT,
                        states=True)
    ref = reference_simulate(CHIRP, DT, t_delay=0.0235, **RIG_KW, **P)
    # the delayed command jumps mid-interval; the package represents it by a linear
    # piece, so at a sample it lies within half a sample's command change (measured 1165 Pa)
    assert max_err(delay.pressure_pa[0], ref.pressure_pa) <= 0.5 * np.max(np.abs(np.diff(CHIRP)))
    assert max_err(delay.position_m[0], ref.position_m) <= 1e-5


def test_recorded_effect_force_is_the_sum_of_the_physical_forces():
    """``effect_force_n`` is F_c tanh(v/v_c) + K3 x^3 + K_p p x on the recorded states."""
    names = ["coulomb_friction", "cubic_stiffness", "pressure_stiffness"]
    values = {"F_c": 1.0, "K3": 2e4, "K_p": 3e-4}
    sim = pb.simulate(pb.Model(names), values, CHIRP, dt_s=DT, states=True)
    x, v, p = sim.true_position_m[0], sim.velocity_m_s[0], sim.pressure_pa[0]
    v_c = pb.Model(names).defaults["v_c"]
    assert v_c == 2e-3
    expected = 1.0 * np.tanh(v / v_c) + 2e4 * x**3 + 3e-4 * p * x
    assert np.abs(expected).max() > 1.0
    assert max_err(sim.effect_force_n[0], expected) < 1e-9


# ---------------------------------------------------------------------------------
# statics


def test_derived_area_against_an_independent_static_root_find():
    """``derive_area`` puts the static balance's root at 85 mm for 0.4 MPa."""
    x0 = -WEIGHT / P["K_e"]
    assert pb.derive_area() == AREA

    def balance(x):
        return P["K_e"] * x + z_loading(x, x0) + WEIGHT - AREA * (0.4e6 - P["p_dz"])

    x_static = brentq(balance, 0.05, 0.12, xtol=1e-13)
    assert x_static == pytest.approx(0.085, abs=1e-9)
    assert 2.1e-4 < AREA < 2.2e-4


def test_reference_step_response_reaches_the_papers_extension():
    """Validates the yardstick and the derived area: RK4 ends at 85 mm."""
    u = np.full(20001, 0.4e6)
    u[0] = 0.0  # start at rest at zero pressure, step at t = 1 ms
    ref = reference_simulate(u, DT, **RIG_KW, **P)
    assert np.all(np.diff(ref.position_m) > -1e-12)  # monotone: z stays on the loading branch
    assert ref.position_m[-1] == pytest.approx(0.085, abs=1e-9)


def step_response(dt: float, seconds: float, states: bool = False):
    """0 -> 0.4 MPa step of the base model, held for ``seconds``."""
    u = np.full(int(round(seconds / dt)) + 1, 0.4e6)
    u[0] = 0.0
    return pb.simulate(pb.Model(), None, u, dt_s=dt, states=states)


def test_steady_state_extension_at_1khz():
    """A 0.4 MPa step held 100 s at 1 kHz ends at the paper's 85 mm within 1e-6 m."""
    x = step_response(DT, 100.0)[0]
    assert x[-1] == pytest.approx(0.085, abs=1e-6)


@pytest.mark.parametrize("dt", [DT / 2, 2 * DT, 10 * DT])
def test_steady_state_extension_does_not_depend_on_the_step(dt):
    """The hysteresis keeps no memory of the step size: 85 mm at any dt.

    A step that carried z through zero on the wrong Bouc-Wen branch once left a
    bias of 1.9e-6 m at 1 ms and 3.9e-4 m at 10 ms; now all ends are within 1e-13 m.
    """
    assert step_response(dt, 100.0)[0, -1] == pytest.approx(0.085, abs=1e-9)


def test_hysteresis_is_rate_independent_on_a_monotone_path():
    """On a monotone loading path Bouc-Wen z is a function of x alone."""
    sim = step_response(DT, 20.0, states=True)
    x, z = sim.true_position_m[0], sim.hysteresis_n[0]
    assert np.all(np.diff(x) > -1e-12)
    x0 = -WEIGHT / P["K_e"]
    c = P["beta"] + P["gamma"]  # z > 0 and x' > 0 on this path
    branch = P["alpha"] / c * -np.expm1(-c * (x - x0))
    assert max_err(z, branch) < 1e-6


def test_gravity_alone_sags_by_weight_over_stiffness():
    """Below the dead zone the muscle rests at x = -(M+m) g / K_e."""
    x = pb.simulate(pb.Model(), None, np.full(2000, 0.5 * P["p_dz"]), dt_s=DT)[0]
    sag = -WEIGHT / P["K_e"]
    assert x[0] == pytest.approx(sag, rel=1e-15)
    np.testing.assert_allclose(x, sag, rtol=1e-12, atol=0.0)  # measured 2.7e-16 m


def test_force_oscillator_at_rest_stays_at_zero():
    """A force oscillator driven by zero force never moves."""
    model = pb.Model(rig=pb.Rig.force_oscillator(BENCH_MASS))
    x = pb.simulate(model, BENCH, np.zeros(1500), dt_s=1 / BENCH_FS)
    assert np.array_equal(x, np.zeros((1, 1500)))


# ---------------------------------------------------------------------------------
# batches


def batch_of_16(model: pb.Model) -> np.ndarray:
    """16 parameter sets drawn within +-20% of the model's defaults (seeded)."""
    rng = np.random.default_rng(20240917)
    defaults = np.array([model.defaults[n] for n in model.parameter_names])
    return defaults * rng.uniform(0.8, 1.2, (16, defaults.size))


@pytest.mark.parametrize(
    "effects",
    [[], ["coulomb_friction", "cubic_stiffness", "pressure_stiffness", "regulator_lag"]],
    ids=["base", "force_effects_and_lag"],
)
def test_batch_equals_one_by_one(effects, record_property):
    """A batch of 16 equals 16 single runs, by array, dict and repeated input."""
    model = pb.Model(effects)
    theta = batch_of_16(model)
    together = pb.simulate(model, theta, CHIRP, dt_s=DT)
    alone = np.vstack([pb.simulate(model, row, CHIRP, dt_s=DT) for row in theta])
    as_dict = pb.simulate(model, dict(zip(model.parameter_names, theta.T, strict=True)),
                          CHIRP, dt_s=DT)
    repeated = pb.simulate(model, theta, np.tile(CHIRP, (16, 1)), dt_s=DT)
    record_property("batch_vs_single_max_abs_diff_m", max_err(together, alone))
    assert together.shape == (16, CHIRP.size)
    assert np.ptp(together[:, -1]) > 1e-3  # the members really differ
    assert max_err(together, alone) <= 1e-12  # measured: exactly 0
    assert np.array_equal(together, as_dict)
    assert max_err(together, repeated) <= 1e-12  # measured: exactly 0


def test_per_member_inputs_are_used_per_member():
    """A ``(B, N)`` input drives each member with its own row."""
    inputs = np.vstack([CHIRP, 0.5 * CHIRP])
    x = pb.simulate(pb.Model(), {"K_e": [P["K_e"], 700.0]}, inputs, dt_s=DT)
    ref0 = reference_simulate(CHIRP, DT, **RIG_KW, **P)
    ref1 = reference_simulate(0.5 * CHIRP, DT, **RIG_KW, **{**P, "K_e": 700.0})
    assert max_err(x[0], ref0.position_m) <= 1e-5
    assert max_err(x[1], ref1.position_m) <= 1e-5


# ---------------------------------------------------------------------------------
# stability at the data's sample rate


def explicit_euler(p, dt):
    """Forward Euler on the base model; returns the largest |x| reached."""
    x, v, z, worst = -WEIGHT / P["K_e"], 0.0, 0.0, 0.0
    for pk in p:
        a = (AREA * max(pk - P["p_dz"], 0.0) - WEIGHT - P["d"] * v - P["K_e"] * x - z) / MASS
        dz = v * (P["alpha"] - (P["beta"] * math.copysign(1.0, v * z) + P["gamma"]) * abs(z))
        x, v, z = x + dt * v, v + dt * a, z + dt * dz
        worst = max(worst, abs(x)) if math.isfinite(x) else math.inf
        if worst > 1e3:
            break
    return worst


def test_explicit_euler_diverges_but_pmabayes_does_not():
    # the stiff pole near -d/(M+m) = -2300 rad/s gives |1 + h lambda| = 1.3 at 1 kHz
    """At 1 kHz explicit Euler blows up; pmabayes stays bounded and accurate."""
    assert explicit_euler(CHIRP, DT) > 1e3
    x = pb.simulate(pb.Model(), None, CHIRP, dt_s=DT)[0]
    assert np.all(np.isfinite(x)) and np.abs(x).max() < 0.2
    assert max_err(x, reference_simulate(CHIRP, DT, **RIG_KW, **P).position_m) <= 1e-5


def test_coarse_5ms_steps_stay_finite_and_close(record_property):
    """At 5 ms steps the result is finite and within 5e-4 m of RK4."""
    _, p5 = paper_chirp(3000, 5e-3)
    x = pb.simulate(pb.Model(), None, p5, dt_s=5e-3)[0]
    ref = reference_simulate(p5, 5e-3, substeps=320, **RIG_KW, **P)
    assert explicit_euler(p5, 5e-3) > 1e3
    assert np.all(np.isfinite(x))
    err = max_err(x, ref.position_m)
    record_property("max_abs_error_m", err)
    assert err <= 5e-4  # measured 2.2e-6 m


# ---------------------------------------------------------------------------------
# the generic force-driven Bouc-Wen oscillator (Noel-Schoukens benchmark values)


def bench_runs(upsample: int = 1, values=None, substeps: int = 1):
    """pmabayes at ``BENCH_FS * upsample`` (same held input) and the RK4 reference."""
    values = BENCH if values is None else values
    u = multisine()
    model = pb.Model(rig=pb.Rig.force_oscillator(BENCH_MASS))
    x = pb.simulate(model, values, np.repeat(u, upsample), dt_s=1 / BENCH_FS / upsample,
                    substeps=substeps)
    ref = reference_simulate(u, 1 / BENCH_FS, mass=BENCH_MASS, area=1.0, gravity_force=0.0,
                             dead_zone=False, **values)
    return x[0, ::upsample], ref.position_m


def test_force_oscillator_documented_accuracy(record_property):
    """At fs = 750 Hz with one step per sample, and second-order convergence.

    Measured: 1.08e-4 m for a 1.9e-3 m peak response at 750 Hz (one step per
    sample; 2.97e-4 m before alpha joined the exact linear part), 2.7e-6 m with
    4 substeps, 5.1e-7 m with 8.
    """
    x, ref = bench_runs()
    err = max_err(x, ref)
    record_property("max_abs_error_m", err)
    assert 1e-3 < np.abs(ref).max() < 3e-3
    assert err <= 1.5e-4
    x4, _ = bench_runs(substeps=4)
    assert max_err(x4, ref) <= err / 10
    x4u, _ = bench_runs(upsample=4)  # substeps and a 4x faster sampled held input agree
    assert max_err(x4, x4u) <= 1e-12


def test_force_oscillator_linear_spring_in_K_e_is_exact():
    """With all stiffness in K_e (alpha = 0) the exact linear discretisation is exact."""
    x, ref = bench_runs(values={"alpha": 0.0, "beta": 0.0, "gamma": 0.0, "d": 10.0, "K_e": 1e5})
    assert np.abs(ref).max() > 1e-3
    assert max_err(x, ref) <= 1e-10  # measured 7e-13 m


@pytest.mark.parametrize(
    ("values", "substeps", "bound"),
    [(BENCH, 8, 1e-6), ({**BENCH, "beta": 0.0, "gamma": 0.0}, 1, 1e-10)],
    ids=["benchmark_8_substeps", "linear_spring_alpha"],
)
def test_force_oscillator_matches_the_reference_at_the_benchmark_rate(values, substeps, bound):
    """The benchmark oscillator within 1e-6 m of RK4 at 750 Hz with 8 substeps
    (measured 5.1e-7 m); a linear alpha spring is exact with one (7e-13 m)."""
    x, ref = bench_runs(values=values, substeps=substeps)
    assert max_err(x, ref) <= bound


def test_force_oscillator_reference_self_convergence():
    """The reference converges on the lightly damped oscillator too."""
    u = multisine()
    kw = dict(mass=BENCH_MASS, area=1.0, gravity_force=0.0, dead_zone=False, **BENCH)
    a = reference_simulate(u, 1 / BENCH_FS, substeps=64, **kw).position_m
    b = reference_simulate(u, 1 / BENCH_FS, substeps=128, **kw).position_m
    assert max_err(a, b) < 1e-8  # measured 4.6e-9 m


# ---------------------------------------------------------------------------------
# bad input


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: pb.simulate(pb.Model(), None, np.zeros((3, 100)), dt_s=DT),
         pb.SimulationError, r"input_signal has shape \(3, 100\)"),
        (lambda: pb.simulate(pb.Model(), None, np.array([0.0, np.nan, 1.0]), dt_s=DT),
         pb.SimulationError, "NaN or inf"),
        (lambda: pb.simulate(pb.Model(), {"K_elastic": 600.0}, CHIRP[:10], dt_s=DT),
         pb.ModelError, "'K_elastic' is not a parameter"),
        (lambda: pb.simulate(pb.Model(), {"d": -1.0}, CHIRP[:10], dt_s=DT),
         pb.ModelError, "parameter d = -1.0 .*outside its bounds"),
        (lambda: pb.simulate(pb.Model(), None, CHIRP[:10]),
         pb.SimulationError, "give dt_s"),
        (lambda: pb.simulate(pb.Model(), None, CHIRP[:4], time_s=[0.0, 1e-3, 2e-3, 4e-3]),
         pb.SimulationError, "uniformly sampled"),
        (lambda: pb.simulate(pb.Model(), None, None, dt_s=DT),
         pb.SimulationError, "input_signal is required"),
        (lambda: pb.simulate(pb.Model(), None, CHIRP[:4], dt_s=DT, time_s=T[:4] * 2),
         pb.SimulationError, "disagrees with the spacing"),
    ],
    ids=["shape", "nan", "unknown_name", "negative_damping", "no_dt", "nonuniform_time",
         "no_input", "dt_vs_time"],
)
def test_bad_input_raises_a_helpful_error(call, error, match):
    """Each bad input raises the package's error with a telling message."""
    with pytest.raises(error, match=match):
        call()


def test_time_axis_equals_dt():
    """A uniform ``time_s`` gives the same result as ``dt_s``."""
    a = pb.simulate(pb.Model(), None, CHIRP, dt_s=DT)
    b = pb.simulate(pb.Model(), None, CHIRP, time_s=T + 3.0)  # spacing 1e-3 +- rounding
    assert max_err(a, b) <= 1e-12


def test_reproducible_bit_for_bit():
    """Two identical calls give bit-identical positions."""
    model = pb.Model(["coulomb_friction", "transport_delay"])
    theta = model.theta({"F_c": [0.5, 1.0, 2.0], "t_delay": [0.0, 0.0235, 0.05]})
    a = pb.simulate(model, theta, CHIRP, dt_s=DT)
    b = pb.simulate(model, theta, CHIRP, dt_s=DT)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("effects", [[], ["maxwell_creep", "regulator_lag"],
                                     ["maxwell_creep", "force_length_map", "stribeck_friction"]],
                         ids=["base", "creep_and_lag", "creep_map_stribeck"])
def test_the_threads_never_change_a_batch(effects, monkeypatch):
    """A large batch is split into runs of members by its size and the machine's cores
    alone, and the runs go to however many threads there are: the positions are the
    same, to the bit, with one, two or three threads. The third model's member loop is
    vectorised and rounds the loop's remainder differently from its vector body, so a
    split that followed the threads would change its numbers."""
    from pmabayes.model import simulator

    model = pb.Model(effects)
    rng = np.random.default_rng(7)
    defaults = np.array([model.defaults[n] for n in model.parameter_names])
    theta = defaults * rng.uniform(0.8, 1.2, (61, defaults.size))
    monkeypatch.setattr(simulator, "local_cores", lambda: 3)
    runs, results = set(), []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("PMABAYES_THREADS", threads)
        runs.add(tuple(simulator._member_chunks(61, CHIRP.size)))
        results.append(pb.simulate(model, theta, CHIRP, dt_s=DT))
    assert len(runs) == 1 and len(runs.pop()) == 3  # really split, the same way each time
    for other in results[1:]:
        assert np.array_equal(other, results[0])
    monkeypatch.setenv("PMABAYES_THREADS", "many")
    with pytest.raises(pb.SimulationError, match="PMABAYES_THREADS"):
        pb.simulate(model, theta, CHIRP, dt_s=DT)
