"""The PMA's own physics in the effect library.

``stribeck_friction`` and ``mckibben_force`` (force stage) and
``regulator_second_order`` (pressure stage): their physics against finite differences,
closed forms and an independent RK4 reference (``tests/reference_solver.py``), and, in
the slow tier, the diagnosis loop on data that hide them, including their near twins
``coulomb_friction`` and ``regulator_lag``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from reference_solver import paper_chirp, reference_simulate

import pmabayes as pb
from pmabayes.model.effects.force import _mckibben_force, _stribeck_friction
from pmabayes.model.effects.pressure import _regulator_lag, _regulator_second_order
from pmabayes.synthetic import Chirp, generate_chirp_dataset

DT = 1e-3
T, CHIRP = paper_chirp()  # 15 s, 0.1 -> 3 Hz, 0 -> 0.5 MPa at 1 kHz
P = dict(pb.PAPER_VALUES)
MASS = 0.067  # carriage 45 g + muscle 22 g, typed in as in test_simulator
RIG_KW = dict(mass=MASS, area=pb.PAPER_AREA_M2, gravity_force=MASS * 9.81)

#: each effect at a size a lab would care about (see the README's table)
LAB = {
    # breakaway 1 N, sliding 0.5 N, over 10 mm/s: the size of the Coulomb friction
    # that test_criticism hides (0.8 N), split into its static and kinetic parts
    "stribeck_friction": {"F_k": 0.5, "F_s": 0.5, "v_s": 0.01, "v_st": 2e-3},
    # about 11% of the push per unit pressure lost at the paper's 85 mm
    "mckibben_force": {"a_mck": 2e-5, "l_0": 0.17, "p_mck": 66922.0},
    # a 16 Hz proportional regulator that overshoots (zeta 0.3)
    "regulator_second_order": {"tau_n": 0.01, "zeta_reg": 0.3},
}


def max_err(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def run_pressure(fn, q, u, dt=DT):
    """A pressure effect on held input ``u`` for one parameter row: (start, end) values."""
    ps = np.array(u[:, None], dtype=float)  # copies: the effect works in place
    pe = ps.copy()
    fn(np.atleast_2d(np.asarray(q, dtype=float)), ps, pe, dt)
    return ps[:, 0], pe[:, 0]


def run_linear(fn, q, u, dt=DT):
    """A pressure effect on input ``u`` linear between samples."""
    ps = np.array(u[:-1, None], dtype=float)  # copies: the effect works in place
    pe = np.array(u[1:, None], dtype=float)
    fn(np.atleast_2d(np.asarray(q, dtype=float)), ps, pe, dt)
    return ps[:, 0], pe[:, 0]


# ---------------------------------------------------------------------------------
# the physics, fast


def test_every_new_effect_is_registered_with_nulls_units_and_meaning():
    for name in LAB:
        eff = pb.get_effect(name)
        assert eff.__module__.startswith("pmabayes.model.effects.")
        assert len(eff.description) > 200
        assert "residual" in eff.description.lower()
        for p in eff.parameters:
            assert p.unit and p.description and p.latex
            assert p.bounds[0] <= p.default <= p.bounds[1]
        assert eff.null_values()  # something vanishes the effect
    # a model may hold each with its twin: no parameter names clash
    both = pb.Model(["coulomb_friction", "stribeck_friction", "regulator_lag",
                     "regulator_second_order", "pressure_stiffness", "mckibben_force"])
    assert len(set(both.parameter_names)) == len(both.parameter_names)
    assert "Chou" in pb.get_effect("mckibben_force").description
    assert set(pb.model.effects.__all__) >= {"StribeckFriction", "McKibbenForce",
                                       "RegulatorSecondOrder"}


@pytest.mark.parametrize(("fn", "q"), [
    (_stribeck_friction, [0.5, 0.8, 0.01, 2e-3]),
    (_stribeck_friction, [0.0, 2.0, 3e-3, 1e-3]),
    (_mckibben_force, [2e-5, 0.17, 66922.0]),
])
def test_force_derivatives_match_finite_differences(fn, q):
    q = np.array(q)
    rng = np.random.default_rng(0)
    for x, v, p in zip(rng.uniform(-0.01, 0.1, 40), rng.uniform(-0.05, 0.05, 40),
                       rng.uniform(1e5, 5e5, 40), strict=True):
        f, fx, fv = fn(q, x, v, p)
        hx, hv = 1e-7, 1e-8
        fd_x = (fn(q, x + hx, v, p)[0] - fn(q, x - hx, v, p)[0]) / (2 * hx)
        fd_v = (fn(q, x, v + hv, p)[0] - fn(q, x, v - hv, p)[0]) / (2 * hv)
        assert fx == pytest.approx(fd_x, rel=1e-6, abs=1e-6)
        assert fv == pytest.approx(fd_v, rel=1e-5, abs=1e-6)


def test_stribeck_breaks_away_above_its_sliding_level_and_vanishes_at_its_null():
    q = np.array([0.5, 0.8, 0.01, 2e-3])
    v = np.linspace(-0.2, 0.2, 4001)
    f = np.array([_stribeck_friction(q, 0.0, vi, 2e5)[0] for vi in v])
    # breakaway near F_k + F_s (smoothed by tanh at v_st), between v_st and v_s
    assert 1.05 < f.max() < 1.3 and 2e-3 < v[np.argmax(f)] < 0.01
    assert f[-1] == pytest.approx(0.5, abs=1e-9)  # sliding: F_k
    assert np.allclose(f, -f[::-1])  # opposes motion either way
    null = np.array([0.0, 0.0, 0.01, 2e-3])
    assert all(_stribeck_friction(null, 0.01, vi, 3e5) == (0.0, 0.0, 0.0) for vi in v[::100])
    # no static excess: exactly coulomb_friction's F_c tanh(v / v_c)
    coulomb = np.array([0.5, 2e-3])
    kin = np.array([0.5, 0.0, 0.01, 2e-3])
    for vi in v[::50]:
        assert _stribeck_friction(kin, 0.0, vi, 0.0) == pytest.approx(
            pb.get_effect("coulomb_friction").physics(coulomb, 0.0, vi, 0.0), abs=1e-15)


def chou_hannaford_push_n(length_m, p_pa, braid_m, turns):
    """Chou-Hannaford's force of an ideal braided muscle, as the push of an extensor:
    ``(pi D0^2 / 4) p (1 - 3 cos^2 theta)``, ``cos theta = L / b``, ``D0 = b / (n pi)``."""
    d0 = braid_m / (turns * math.pi)
    return math.pi * d0**2 / 4.0 * p_pa * (1.0 - 3.0 * (length_m / braid_m) ** 2)


def test_mckibben_is_the_chou_hannaford_force_length_law():
    """The force lost with extension is exactly Chou-Hannaford's, with a_mck = 3 l0^2 /
    (4 pi n^2), for a braid of the paper's muscle wound at 80 degrees."""
    l0, theta0 = 0.17, math.radians(80.0)
    braid = l0 / math.cos(theta0)
    turns = braid * math.sin(theta0) / (math.pi * 0.014)  # 14 mm braid diameter
    a_mck = 3.0 * l0**2 / (4.0 * math.pi * turns**2)
    q = np.array([a_mck, l0, 0.0])  # no engagement pressure: the ideal law
    for x in (-0.001, 0.02, 0.085):
        for p in (1e5, 4e5):
            lost = chou_hannaford_push_n(l0, p, braid, turns) - chou_hannaford_push_n(
                l0 + x, p, braid, turns)
            assert _mckibben_force(q, x, 0.0, p)[0] == pytest.approx(lost, rel=1e-12)
    # and below the braid's engagement pressure nothing is lost, nor at its null
    q = np.array([2e-5, 0.17, 66922.0])
    assert _mckibben_force(q, 0.05, 0.1, 6e4) == (0.0, 0.0, 0.0)
    assert _mckibben_force(np.array([0.0, 0.17, 66922.0]), 0.05, 0.1, 4e5)[0] == 0.0
    # the push per unit pressure falls with extension (11% at 85 mm at the lab size)
    f = _mckibben_force(q, 0.085, 0.0, 4e5)[0]
    assert 0.08 < f / (pb.PAPER_AREA_M2 * (4e5 - 66922.0)) < 0.14


def test_second_order_regulator_null_is_the_input_and_a_ramp_lags_by_2_zeta_tau():
    rng = np.random.default_rng(3)
    u = 2e5 + np.cumsum(rng.normal(0.0, 2e3, 500))
    for zeta in (0.3, 1.0, 4.0):
        start, end = run_linear(_regulator_second_order, [0.0, zeta], u)
        assert max_err(start, u[:-1]) < 1e-6 and max_err(end, u[1:]) < 1e-6  # Pa
    # after settling, a ramp comes out as the ramp delayed by 2 zeta tau_n, exactly
    ramp = 1e5 + 3e6 * np.arange(3000) * DT
    for tau, zeta in ((0.01, 0.3), (0.005, 1.0), (0.002, 3.0)):
        start, end = run_linear(_regulator_second_order, [tau, zeta], ramp)
        lag = 2.0 * zeta * tau
        assert max_err(start[-500:], ramp[:-1][-500:] - 3e6 * lag) < 1e-6
        assert max_err(end[-500:], ramp[1:][-500:] - 3e6 * lag) < 1e-6


def test_second_order_regulator_matches_the_exact_step_response():
    """A held step: the interval means are those of the closed-form step response."""
    u = np.r_[np.full(5, 1e5), np.full(400, 3e5)]
    for tau, zeta in ((0.01, 0.3), (0.01, 1.0), (0.004, 2.5)):
        start, end = run_pressure(_regulator_second_order, [tau, zeta], u)
        t0 = 5 * DT
        t = np.linspace(0.0, 405 * DT, 405 * 400 + 1)
        s = np.clip(t - t0, 0.0, None) / tau
        if zeta < 1:
            wd = math.sqrt(1 - zeta**2)
            y = 1 - np.exp(-zeta * s) * (np.cos(wd * s) + zeta / wd * np.sin(wd * s))
        elif zeta == 1:
            y = 1 - np.exp(-s) * (1 + s)
        else:
            r = math.sqrt(zeta**2 - 1)
            l1, l2 = -zeta + r, -zeta - r
            y = 1 - (l2 * np.exp(l1 * s) - l1 * np.exp(l2 * s)) / (l2 - l1)
        y = 1e5 + 2e5 * y
        means = np.array([np.trapezoid(y[k * 400:(k + 1) * 400 + 1], dx=DT / 400) / DT
                          for k in range(405)])
        assert max_err(0.5 * (start + end), means) < 0.05  # Pa, of a 2e5 Pa step
        if zeta < 1:
            assert end.max() > 3e5 + 0.3 * 2e5  # it rings: overshoot
        else:
            assert end.max() < 3e5 + 1.0


def test_second_order_regulator_is_smooth_across_critical_damping_and_tends_to_the_lag():
    rng = np.random.default_rng(4)
    u = 2e5 + np.cumsum(rng.normal(0.0, 2e3, 2000))
    ref = run_linear(_regulator_second_order, [0.01, 1.0], u)[1]
    for zeta in (1.0 - 1e-9, 1.0 + 1e-9):
        assert max_err(run_linear(_regulator_second_order, [0.01, zeta], u)[1], ref) < 1e-4
    # across the switch between its two closed forms (roots 2 intervals apart)
    tau = 0.001  # w = (zeta^2 - 1) / (tau / dt)^2 = 1 at zeta = sqrt(2)
    zs = math.sqrt(1.0 + tau**2 / DT**2)
    a = run_linear(_regulator_second_order, [tau, zs * (1 - 1e-12)], u)[1]
    b = run_linear(_regulator_second_order, [tau, zs * (1 + 1e-12)], u)[1]
    assert max_err(a, b) < 1e-6
    # heavily damped: a first-order lag of 2 zeta tau_n (its fast root ~ tau / (2 zeta))
    zeta, tau = 20.0, 0.001
    lag = run_linear(_regulator_lag, [[2 * zeta * tau]], u)[1]
    so = run_linear(_regulator_second_order, [tau, zeta], u)[1]
    assert max_err(so, lag) < 2e-3 * np.max(np.abs(np.diff(u)))


def test_second_order_regulator_hooks_for_the_closed_loop():
    eff = pb.get_effect("regulator_second_order")
    q = np.array([[0.01, 0.3], [0.01, 1.0], [0.01, 3.0], [0.0, 0.7]])
    assert np.allclose(eff.lead_s(q), [0.006, 0.02, 0.06, 0.0])
    slow = [0.01 / 0.3, 0.01, 0.01 * (3 + math.sqrt(8)), 0.0]
    assert np.allclose(eff.history_s(q), 40 * np.array(slow))


# ---------------------------------------------------------------------------------
# the simulator against the RK4 reference


@pytest.mark.parametrize("name", list(LAB))
def test_simulator_accuracy_against_the_reference(name, record_property):
    """Within 1e-5 m of RK4 on the paper's 15 s chirp at 1 kHz (measured: stribeck
    1.7e-6, mckibben 5.4e-8, second-order regulator 1.2e-6 m)."""
    values = LAB[name]
    x = pb.simulate(pb.Model([name]), values, CHIRP, dt_s=DT)[0]
    ref = reference_simulate(CHIRP, DT, **RIG_KW, **P, **values)
    base = reference_simulate(CHIRP, DT, **RIG_KW, **P)
    err = max_err(x, ref.position_m)
    record_property("max_abs_error_m", err)
    assert max_err(ref.position_m, base.position_m) > 5e-4  # the effect is there
    assert err <= 1e-5


def test_a_pronounced_stribeck_hump_needs_two_substeps():
    """Breakaway 1.3 N over 0.5 N sliding sticks the muscle at reversals: 1.7e-5 m at
    one step per sample, 1.5e-6 m with two (measured; README, Friction smoothing)."""
    values = {"F_k": 0.5, "F_s": 0.8, "v_s": 0.01, "v_st": 2e-3}
    ref = reference_simulate(CHIRP, DT, **RIG_KW, **P, **values).position_m
    model = pb.Model(["stribeck_friction"])
    one = max_err(pb.simulate(model, values, CHIRP, dt_s=DT)[0], ref)
    two = max_err(pb.simulate(model, values, CHIRP, dt_s=DT, substeps=2)[0], ref)
    assert two <= 1e-5 < one


def test_recorded_effect_force_and_pressure_match_the_reference():
    names = ["stribeck_friction", "mckibben_force"]
    values = {**LAB["stribeck_friction"], **LAB["mckibben_force"]}
    sim = pb.simulate(pb.Model(names), values, CHIRP, dt_s=DT, states=True)
    x, v, p = sim.true_position_m[0], sim.velocity_m_s[0], sim.pressure_pa[0]
    expected = ((0.5 + 0.5 * np.exp(-(v / 0.01) ** 2)) * np.tanh(v / 2e-3)
                + 2e-5 * ((1 + x / 0.17) ** 2 - 1) * np.maximum(p - 66922.0, 0.0))
    assert np.abs(expected).max() > 1.0
    assert max_err(sim.effect_force_n[0], expected) < 1e-9
    reg = pb.simulate(pb.Model(["regulator_second_order"]), LAB["regulator_second_order"],
                      CHIRP, dt_s=DT, states=True)
    ref = reference_simulate(CHIRP, DT, **RIG_KW, **P, **LAB["regulator_second_order"])
    assert max_err(reg.pressure_pa[0], ref.pressure_pa) < 20.0  # Pa, of 0.5 MPa


def test_the_null_of_each_effect_is_the_base_model():
    base = pb.simulate(pb.Model(), None, CHIRP[:3000], dt_s=DT)[0]
    for name in LAB:
        model = pb.Model([name])
        x = pb.simulate(model, {**LAB[name], **pb.get_effect(name).null_values()},
                        CHIRP[:3000], dt_s=DT)[0]
        assert max_err(x, base) < 1e-12, name


# ---------------------------------------------------------------------------------
# near twins: what the verdict says when two refits predict equally well


def _refit(effect, elpd_i, explained=0.99):
    from types import SimpleNamespace

    from pmabayes.criticism.results import Refit

    elpd_i = np.asarray(elpd_i, dtype=float)
    base_i = np.zeros_like(elpd_i)
    diff = elpd_i - base_i
    sig = SimpleNamespace(ratio=1.1, bands=[SimpleNamespace(rms_m=30e-6, floor_m=27e-6)])
    return Refit(effect=effect, values={}, interval={}, rms_m=30e-6,
                 signatures=(sig,), explained=explained,
                 elpd=float(elpd_i.sum()), elpd_diff=float(diff.sum()),
                 elpd_diff_se=float(math.sqrt(diff.size * np.var(diff))),
                 contribution_m=np.zeros(3), elpd_i=elpd_i)


def test_the_verdict_says_when_two_refits_cannot_be_told_apart():
    from types import SimpleNamespace

    from pmabayes.criticism.prose import verdict_text
    from pmabayes.criticism.refits import missing_effect, near_twins
    from pmabayes.criticism.settings import DiagnoseSettings

    s = DiagnoseSettings(level=0.05, level_adequate=0.01, energy_tolerance=0.1, max_refits=3,
                         min_explained=0.9, ci_prob=0.9, n_draws=400, substeps=1,
                         candidates=None)
    signature = SimpleNamespace(bands=[SimpleNamespace(rms_m=1e-3, floor_m=25e-6)],
                                energy=20.0, energy_p=0.0, ljung_box_p=0.0)
    rng = np.random.default_rng(0)
    lag = 1000.0 + rng.normal(0.0, 5.0, 6)
    cases = {
        # within two paired standard errors: a tie, said in the verdict
        "tie": (lag + rng.normal(0.3, 2.0, 6), True),
        # far apart: the better one is named, no tie
        "apart": (lag + 40.0 + rng.normal(0.0, 2.0, 6), False),
    }
    for what, (second, tied) in cases.items():
        refits = {"regulator_lag": _refit("regulator_lag", lag),
                  "regulator_second_order": _refit("regulator_second_order", second)}
        missing = missing_effect(refits, s)
        twins = near_twins(refits, missing, s)
        findings = [SimpleNamespace(effect=k, refit=r) for k, r in refits.items()]
        experiment = SimpleNamespace(name="chirp", signature=signature, adequate=False,
                                     floor_note=lambda: "")
        text = verdict_text("base", (), (experiment,), False, missing, refits, findings, 0.9,
                            twins)
        assert missing in text
        assert ("cannot be told apart" in text) is tied, (what, text)
        if tied:
            assert len(twins) == 1 and abs(twins[0][1]) <= 2 * twins[0][2]
        else:
            assert missing == "regulator_second_order" and twins == []
            assert "predicts left-out trials better" in text


# ---------------------------------------------------------------------------------
# the diagnosis loop on data that hide them (slow)

RANK_CHIRP = Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=3.0)
#: the built-in library: the first six and the PMA's three (other tests register user
#: effects, which would rightly compete)
LIBRARY = ("regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
           "pressure_stiffness", "position_offset", *LAB)

#: hidden at sizes a lab would care about, with the parameter whose interval must
#: cover the truth, and the near twin that must lose by ELPD:
#: - a pronounced Stribeck hump: breakaway 1.2 N against 0.4 N sliding, decaying over
#:   30 mm/s (the rail and braid of the paper's rig, whose Coulomb friction
#:   test_criticism puts at 0.8 N);
#: - Chou-Hannaford's law with 11% of the push per unit pressure lost at 85 mm (a
#:   braid wound at 80 degrees);
#: - a 16 Hz regulator with damping 0.3: proportional regulators with 10-20 Hz
#:   bandwidth that overshoot are common.
HIDDEN = [
    ("stribeck_friction", {"F_k": 0.4, "F_s": 0.8, "v_s": 0.03}, "F_s", "coulomb_friction"),
    ("mckibben_force", {"a_mck": 2e-5}, "a_mck", "pressure_stiffness"),
    ("regulator_second_order", {"tau_n": 0.01, "zeta_reg": 0.3}, "tau_n", "regulator_lag"),
]


def diagnosis(ds, effects=(), **kw):
    from pmabayes.criticism.diagnosis import diagnose

    # three refits: the regulators and the delay share their first-order signature,
    # so all three tie in the score test and each must be refitted
    from pmabayes.criticism.settings import DiagnoseSettings

    kw.setdefault("max_refits", 3)
    return diagnose(ds, effects=effects, settings=DiagnoseSettings(candidates=LIBRARY, **kw),
                    seed=0)


#: cases in the extended tier (run with --extended), so that CI stays under 30 minutes
EXTENDED = ("stribeck_friction", "regulator_second_order")


@pytest.mark.slow
@pytest.mark.parametrize(("name", "values", "param", "twin"), [
    pytest.param(*h, id=h[0], marks=[pytest.mark.extended] if h[0] in EXTENDED else [])
    for h in HIDDEN])
def test_a_hidden_pma_effect_is_found_added_and_the_error_falls_to_the_floor(
        name, values, param, twin):
    ds = generate_chirp_dataset(n_trials=6, seed=3, chirp=RANK_CHIRP, effects={name: values})
    before = diagnosis(ds, ci_prob=0.99)
    assert not before.adequate and before.rms_m > 2 * before.noise_floor_m
    top = before.ranking[0]
    assert (top.effect, before.missing) == (name, name), before.verdict
    assert top.significant and top.refit is not None
    lo, hi = top.interval[param]  # a 99% interval from the refit
    assert lo < values[param] < hi, (param, values[param], top.interval)
    # its near twin, when refitted, predicts left-out trials clearly worse
    rival = next((f for f in before.ranking if f.effect == twin and f.refit), None)
    if rival is not None:
        diff = top.refit.elpd_i - rival.refit.elpd_i
        assert diff.sum() > 2 * math.sqrt(diff.size * np.var(diff)), before.verdict
    assert "cannot be told apart" not in before.verdict
    after = diagnosis(ds, effects=[name], max_refits=2)
    assert after.adequate and after.missing is None, after.verdict
    assert after.rms_m <= 1.25 * after.noise_floor_m
    assert after.rms_m < 0.5 * before.rms_m


#: where the data cannot tell the twins apart: a critically damped regulator of 1 ms
#: (a 2 ms lag whose second-order part is below the noise up to 3 Hz: the lag, the
#: delay and the second-order regulator tie), and a Stribeck hump narrower than the
#: friction's smoothing (v_s 0.5 mm/s under v_st 2 mm/s), which is Coulomb friction
#: to these data
TIES = [
    ("regulator_second_order", {"tau_n": 0.001, "zeta_reg": 1.0},
     {"regulator_second_order", "regulator_lag"}),
    ("stribeck_friction", {"F_k": 0.5, "F_s": 0.8, "v_s": 5e-4},
     {"stribeck_friction", "coulomb_friction"}),
]


@pytest.mark.slow
@pytest.mark.extended
@pytest.mark.parametrize(("name", "values", "twins"), TIES, ids=[t[0] for t in TIES])
def test_near_twins_the_data_cannot_separate_are_not_told_apart(name, values, twins):
    """Either the verdict says the two cannot be told apart, or it names the simpler
    one, never the richer one on a worse ELPD (measured: the regulators tie, +4.8 ±
    3.8, and so do lag and delay; for the hidden hump the Stribeck refit settles in a
    worse optimum (v_s 4 mm/s) and Coulomb friction is named, +37 ± 4.8)."""
    ds = generate_chirp_dataset(n_trials=6, seed=3, chirp=RANK_CHIRP, effects={name: values})
    d = diagnosis(ds)
    assert d.missing in twins | {"transport_delay"}, d.verdict
    refits = {f.effect: f.refit for f in d.ranking if f.refit is not None}
    assert twins <= set(refits)
    a, b = sorted(twins)
    diff = refits[a].elpd_i - refits[b].elpd_i
    tie = abs(diff.sum()) <= 2 * math.sqrt(diff.size * np.var(diff))
    if tie:  # said of every twin that the named effect cannot be told from
        for other in sorted(twins - {d.missing}):
            assert f"{d.missing} and {other} cannot be told apart" in d.verdict, d.verdict
    else:  # the better predictor is named, and it is the simpler, Coulomb friction
        assert d.missing == "coulomb_friction" and "cannot be told apart" not in d.verdict
