"""Closed-loop control: controllers, the multi-rate loop, metrics, sweeps and the CLI."""

import json
import math
import subprocess
import sys
import warnings

import numpy as np
import pytest
import xarray as xr
from conftest import fake_fit

import pmabayes.control.robustness as robustness
from pmabayes import Effect, HalfNormal, Model, Normal, Parameter, Rig, simulate
from pmabayes.cli import main
from pmabayes.control import (
    DEFAULT_GAINS,
    METRICS,
    REFERENCE_AMPLITUDE_M,
    REFERENCE_MEAN_M,
    ControlError,
    GainGridWarning,
    closed_loop,
    closed_loop_batch,
    inverse_model_pressure_pa,
    loop_metrics,
    nominal_gains,
    operating_mean_m,
    period_difference_m,
    track,
    tracking_metrics,
    tune_gains,
)
from pmabayes.control.reproduction import figure5, paper_claims
from pmabayes.control.robustness import (
    posterior_mean,
    robustness_sweep,
    summarise_robustness,
    write_robustness,
)
from pmabayes.report.figures import plot_figure5, plot_robustness, plt

CONTROL = Model(rig=Rig.control())


# -- the operating point ------------------------------------------------------------


def test_operating_point_keeps_the_inverse_model_out_of_the_dead_zone():
    assert REFERENCE_MEAN_M == operating_mean_m() == pytest.approx(0.100)
    # the inverse-model pressure along x_d at 2 Hz, independently: quasi-static plus
    # inertia and damping bound it, hysteresis adds at most a few N
    rig, v = Rig.control(), CONTROL.defaults
    t = np.linspace(0, 0.5, 2001)
    x = REFERENCE_MEAN_M + REFERENCE_AMPLITUDE_M * np.sin(4 * np.pi * t)
    xd, xdd = np.gradient(x, t), np.gradient(np.gradient(x, t), t)
    p = v["p_dz"] + (rig.moving_mass_kg * xdd + v["d"] * xd + v["K_e"] * x
                     + rig.gravity_force_n) / rig.area_m2
    assert p.min() > v["p_dz"] + 30e3 and p.max() < 0.9e6 - 300e3
    # the rule's own pressure (with hysteresis) keeps its 50 kPa margins, close to that
    p_rule = inverse_model_pressure_pa(2.0)
    assert p_rule.min() >= v["p_dz"] + 50e3 and p_rule.max() <= 0.9e6 - 50e3
    assert abs(p_rule.min() - p.min()) < 20e3 and abs(p_rule.max() - p.max()) < 20e3
    # one mm lower and the rule's 50 kPa margin would be broken: the smallest such mean
    lower = operating_mean_m(resolution_m=1e-4)
    assert REFERENCE_MEAN_M - 1e-3 < lower <= REFERENCE_MEAN_M
    # the model's own values count (a stiffer muscle needs less offset), fixed ones too
    stiff = Model(rig=Rig.control(), fixed={"K_e": 900.0})
    assert operating_mean_m(stiff) < REFERENCE_MEAN_M
    assert operating_mean_m(CONTROL, {"K_e": 900.0}) == operating_mean_m(stiff)
    with pytest.raises(ControlError, match="lower the"):
        operating_mean_m(frequency_hz=6.0)


# -- the closed loop ----------------------------------------------------------------


@pytest.mark.parametrize("controller", ["pid", "ct"])
def test_nominal_loop_is_stable_and_tracks(controller):
    run = closed_loop(controller, 0.5)
    x = run.position_m[0]
    assert np.all(np.isfinite(x))
    m = loop_metrics(run)
    assert m["rms_error_m"][0] < 4e-3  # under 20% of the 22.5 mm amplitude
    assert 0.9 < m["amplitude_ratio"][0] < 1.1
    assert abs(m["phase_lag_deg"][0]) < 15
    assert m["dead_zone_fraction"][0] == 0 and m["saturated_fraction"][0] == 0
    # it settles: the last two periods agree with each other
    last, before = x[-2000:], x[-4000:-2000]
    assert np.max(np.abs(last - before)) < 5e-4
    assert period_difference_m(run.time_s, x, 0.5)[0] == pytest.approx(
        np.max(np.abs(last - before)), abs=1e-12)
    assert np.all((run.command_pa >= 0) & (run.command_pa <= 0.9e6))


@pytest.mark.parametrize("controller", ["pid", "ct"])
def test_default_gains_keep_their_margins(controller):
    """The README's claim: doubled gains, or 20 ms more delay, still settle and track."""
    nominal = closed_loop(controller, 0.5)
    doubled = closed_loop(controller, 0.5, gains={controller: {
        k: 2 * v for k, v in DEFAULT_GAINS[controller].items()}})
    delayed = closed_loop(controller, 0.5, model=Model(["transport_delay"], rig=Rig.control()),
                          params={"t_delay": 0.02}, controller_model=CONTROL,
                          controller_params={})
    rms = [tracking_metrics(r.time_s, r.reference_m, r.position_m, 0.5)["rms_error_m"][0]
           for r in (nominal, doubled, delayed)]
    for r in (nominal, doubled, delayed):
        assert period_difference_m(r.time_s, r.position_m, 0.5)[0] < 5e-4
    assert rms[1] <= 2 * rms[0] and rms[2] <= 2 * rms[0]


def test_metrics_report_the_dead_zone():
    run = closed_loop("pid", 1.0, reference_mean_m=0.0365)  # trough near the sag
    m = loop_metrics(run)
    cmd = run.command_pa[0][run.time_s >= 2.0][:-1]
    assert m["dead_zone_fraction"][0] == pytest.approx(np.mean(cmd <= run.dead_zone_pa[0]))
    assert m["dead_zone_fraction"][0] > 0.1
    assert run.reference_m[0, 0] == pytest.approx(0.0365)


def test_computed_torque_beats_pid_on_the_nominal_model():
    result = track(1.0)
    ct, pid = result["controllers"]["ct"], result["controllers"]["pid"]
    assert ct["rms_error_m"] < pid["rms_error_m"]
    assert result["gains"] == DEFAULT_GAINS
    assert track(np.float32(1.0))["controllers"]["ct"]["rms_error_m"] == ct["rms_error_m"]


def test_computed_torque_removes_a_known_sensor_offset():
    model = Model(["position_offset"], rig=Rig.control())
    run = closed_loop("ct", 0.5, model=model, params={"x_offset": 1e-3})
    bias = np.mean((run.position_m[0] - run.reference_m[0])[run.time_s >= 2.0])
    assert abs(bias) < 1e-4  # it was the whole 1 mm before the offset was inverted


def test_multirate_timing():
    run = closed_loop("ct", 1.0, duration_s=3.0)
    cmd, u = run.command_pa[0], run.controller_output_pa[0]
    k_cmd = np.nonzero(np.diff(cmd))[0] + 1
    k_u = np.nonzero(np.diff(u))[0] + 1
    assert len(k_cmd) > 30 and len(k_u) > 150  # both really move
    # true by construction of the record (the held values repeated); that the plant
    # really sees this held command is the replay test's job, below
    assert np.all(k_cmd % 50 == 0)  # 20 Hz regulator command, held
    assert np.all(k_u % 10 == 0)  # 100 Hz controller
    # the command is the controller output sampled at the 20 Hz instants
    ticks = np.arange(0, len(cmd), 50)
    np.testing.assert_array_equal(cmd[ticks], u[ticks])
    assert np.any(cmd[ticks[:-1] + 10] != u[ticks[:-1] + 10])
    # the reading is quantised to the encoder's counts and held between controller samples
    counts = run.measured_m[0] * (2000 / 0.0254)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.all(np.nonzero(np.diff(run.measured_m[0]))[0] % 10 == 9)


@pytest.mark.slow
@pytest.mark.parametrize("effects,params", [
    ([], {}),
    (["regulator_lag", "coulomb_friction", "position_offset"],
     {"tau_reg": 0.04, "F_c": 0.8, "x_offset": 3e-4}),
    (["transport_delay", "cubic_stiffness"], {"t_delay": 0.0235, "K3": 2e4}),
])
@pytest.mark.parametrize("controller", ["pid", "ct"])
def test_closed_loop_plant_equals_open_loop_replay(effects, params, controller):
    model = Model(effects, rig=Rig.control())
    run = closed_loop(controller, 1.0, model=model, params=params, duration_s=4.0)
    pre = 2000  # rest under the initial pressure before the loop starts
    u = np.concatenate([np.full(pre, run.initial_pressure_pa[0]), run.command_pa[0]])
    sim = simulate(model, params, u, dt_s=1e-3, states=True)
    np.testing.assert_allclose(sim.true_position_m[0, pre:], run.position_m[0], rtol=0,
                               atol=1e-12)


@pytest.mark.slow
def test_controller_model_sets_the_prediction_of_computed_torque():
    plant = Model(["regulator_lag"], rig=Rig.control())
    a = closed_loop("ct", 1.0, model=plant, params={"tau_reg": 0.045}, controller_model=CONTROL,
                    controller_params={}, duration_s=4.0)
    b = closed_loop("ct", 1.0, model=plant, params={"tau_reg": 0.045}, duration_s=4.0)
    assert a.metadata["prediction_s"][0] == pytest.approx(0.025)
    assert b.metadata["prediction_s"][0] == pytest.approx(0.025 + 0.045)
    assert not np.allclose(a.position_m, b.position_m)


# -- effects the closed loop knows only through their hooks ------------------------------
# Written here, outside the package, as a user would: the loop must compensate them
# from their hooks alone.


def first_order_lag(q, p_start, p_end, dt_s):
    """A first-order lag, exact at the samples for a piecewise-linear command."""
    n, batch = p_start.shape
    for i in range(batch):
        h = dt_s / q[i, 0]
        e = math.exp(-h)
        y = p_start[0, i]  # starts settled at the first command
        for k in range(n):
            a = p_start[k, i]
            ramp = (p_end[k, i] - a) / h
            y_end = p_end[k, i] - ramp + (y - a + ramp) * e
            p_start[k, i] = y
            p_end[k, i] = y_end
            y = y_end


class PlainLag(Effect):
    """A user's lag without hooks: simulated in the loop, not compensated."""

    name = "user_lag_plain"
    stage = "pressure"
    parameters = (Parameter("tau_user", "s", 0.045, HalfNormal(0.1), bounds=(0.0, np.inf)),)
    description = "A first-order lag of the pressure."
    physics = staticmethod(first_order_lag)


class UserLag(PlainLag):
    """The same lag, telling the loop its history and its lead."""

    name = "user_lag"
    physics = staticmethod(first_order_lag)

    @classmethod
    def history_s(cls, q):
        return 40.0 * q[:, 0]

    @classmethod
    def lead_s(cls, q):
        return q[:, 0]

    @classmethod
    def add_delay(cls, q, delay_s):  # not physical, only to see the margin find it
        return q + delay_s


def gain_offset(q, time_s, position_m):
    for k in range(position_m.shape[0]):
        for i in range(position_m.shape[1]):
            position_m[k, i] = q[i, 0] * position_m[k, i] + q[i, 1]


def gain_offset_inverse(q, time_s, reading_m):
    return (reading_m - q[1]) / q[0], 1.0 / q[0]


class RawSensor(Effect):
    """A sensor with a gain and an offset, without an inverse."""

    name = "user_sensor_raw"
    stage = "measurement"
    parameters = (Parameter("k_user", "1", 1.05, Normal(1.0, 0.1)),
                  Parameter("b_user", "m", 2e-3, Normal(0.0, 1e-3), bounds=(-0.01, 0.01)))
    description = "Sensor gain and offset."
    physics = staticmethod(gain_offset)


class UserSensor(RawSensor):
    """The same sensor with its inverse."""

    name = "user_sensor"
    physics = staticmethod(gain_offset)
    inverse = staticmethod(gain_offset_inverse)


def _ct_rms(effects, params=None, frequency_hz=0.5, controller="ct"):
    run = closed_loop(controller, frequency_hz, model=Model(effects, rig=Rig.control()),
                      params=params, duration_s=6.0)
    return loop_metrics(run)["rms_error_m"][0], run


def test_user_pressure_lag_is_compensated_as_well_as_the_builtin():
    builtin, _ = _ct_rms(["regulator_lag"], {"tau_reg": 0.045})
    user, run = _ct_rms([UserLag], {"tau_user": 0.045})
    plain, _ = _ct_rms([PlainLag], {"tau_user": 0.045})
    assert run.metadata["prediction_s"][0] == pytest.approx(0.025 + 0.045, rel=1e-12)
    assert abs(user / builtin - 1) < 0.01
    assert plain > 1.2 * user  # without its lead the same lag is tracked worse


def test_user_sensor_with_an_inverse_is_inverted_by_computed_torque():
    bare, _ = _ct_rms([])
    inverted, run = _ct_rms([UserSensor])
    raw, _ = _ct_rms([RawSensor])
    assert not np.allclose(run.measured_m[0], run.position_m[0], atol=1e-3)  # it does act
    assert inverted <= 1.02 * bare  # as good as with no sensor effect
    assert raw > 1.5 * bare
    # PID reads the sensor as it is: the inverse is computed torque's alone
    pid_inv = _ct_rms([UserSensor], controller="pid")[1]
    pid_raw = _ct_rms([RawSensor], controller="pid")[1]
    np.testing.assert_array_equal(pid_inv.position_m, pid_raw.position_m)


def test_effect_hooks_that_are_absent_keep_the_defaults():
    q = np.array([[0.045], [0.01]])
    np.testing.assert_array_equal(PlainLag.history_s(q), [2.0, 2.0])
    np.testing.assert_array_equal(PlainLag.lead_s(q), [0.0, 0.0])
    assert PlainLag.add_delay(q, 0.02) is None and RawSensor.inverse is None
    run = closed_loop("ct", 1.0, model=Model([PlainLag], rig=Rig.control()), duration_s=3.0)
    assert run.metadata["prediction_s"][0] == 0.025


def test_delay_margin_goes_to_the_effect_that_offers_it():
    from pmabayes.control import _delayed_plant

    model = Model([UserLag], rig=Rig.control())
    theta = model.theta({"tau_user": 0.03})
    plant, th = _delayed_plant(model, theta, 0.02)
    assert plant is model  # no delay effect added
    assert th[0, model.index("tau_user")] == pytest.approx(0.05)
    bare = Model([PlainLag], rig=Rig.control())
    plant, th = _delayed_plant(bare, bare.theta(None), 0.02)
    assert plant.effects[:-1] == (PlainLag,) and plant.effects[-1].add_delay is not None
    np.testing.assert_array_equal(th[:, :-1], bare.theta(None))
    assert plant.effects[-1].lead_s(th[:, -1:])[0] == pytest.approx(0.02)


def test_import_computes_no_reference_mean():
    code = ("import pmabayes.control as c, pmabayes.control.operating as o; "
            "assert o._reference_mean.cache_info().currsize == 0; "
            "from pmabayes.control import REFERENCE_MEAN_M; print(REFERENCE_MEAN_M)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert float(out.stdout) == REFERENCE_MEAN_M == operating_mean_m()


# -- metrics on known signals ---------------------------------------------------------


@pytest.mark.parametrize("ratio,lag_deg", [(0.8, 30.0), (1.1, 0.0), (0.5, 200.0), (1.0, -20.0)])
def test_metrics_exact_on_sinusoids(ratio, lag_deg):
    f, amp, mean = 1.3, 0.02, 0.03
    t = np.arange(0, 10.001, 1e-3)
    w = 2 * np.pi * f
    ref = mean + amp * np.sin(w * t)
    y = mean + ratio * amp * np.sin(w * t - np.radians(lag_deg))
    m = tracking_metrics(t, ref, y, f)
    assert m["amplitude_ratio"][0] == pytest.approx(ratio, rel=1e-9)
    assert m["phase_lag_deg"][0] == pytest.approx(lag_deg, abs=1e-7)
    assert m["overshoot_pct"][0] == pytest.approx(100 * (ratio - 1), abs=1e-3)
    err_amp = amp * abs(ratio * np.exp(-1j * np.radians(lag_deg)) - 1)
    # 1.3 Hz is not a whole number of samples per period: RMS and maximum to 1e-4
    assert m["rms_error_m"][0] == pytest.approx(err_amp / np.sqrt(2), rel=1e-4)
    assert m["max_error_m"][0] == pytest.approx(err_amp, rel=1e-4)


def test_metrics_window_is_whole_periods_after_startup():
    f = 0.25
    t = np.arange(0, 10.001, 1e-3)
    ref = np.sin(2 * np.pi * f * t)
    y = ref.copy()
    y[t < 5.999] += 1.0  # the start-up and the first kept... only before the window
    m = tracking_metrics(t, ref, y, f)  # window: the last whole 4 s period, 6-10 s
    assert m["rms_error_m"][0] < 1e-12
    with pytest.raises(ControlError, match="no whole period"):
        tracking_metrics(t[:3000], ref[:3000], y[:3000], f)
    with pytest.raises(ControlError, match="> 0"):
        tracking_metrics(t, ref, y, 0.0)


# -- gains --------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["ct", "pid"])
def test_gain_rule_reproduces_the_defaults(controller):
    with warnings.catch_warnings():
        warnings.simplefilter("error", GainGridWarning)  # and they are inside the grid
        assert tune_gains(controller) == pytest.approx(DEFAULT_GAINS[controller], rel=1e-12)


def test_gain_rule_rejects_unstable_gains_and_warns_on_the_grid_edge():
    pid = DEFAULT_GAINS["pid"]
    with pytest.warns(GainGridWarning, match="kp"):
        g = tune_gains("pid", grid={"kp": [pid["kp"] / 1.7782794100389228, pid["kp"]],
                                    "ki": [pid["ki"]], "kd": [pid["kd"]]})
    assert g == pid
    # the old rule's PID gains track with doubled gains but do not settle: refused
    with pytest.raises(ControlError, match="widen the grid"):
        tune_gains("pid", grid={"kp": [1.78e7], "ki": [3.16e8], "kd": [3.16e4]})
    with pytest.raises(ControlError, match="equal length"):
        tune_gains("ct", grid={"kp": [100.0, 400.0], "kd": [20.0]})
    with pytest.raises(ControlError, match="grid must give"):
        tune_gains("ct", grid={"kp": [100.0], "ki": [20.0]})


def test_gain_rule_caps_the_bandwidth_below_the_hold_nyquist():
    """Computed torque's w = sqrt(kp) stays under pi / (2 T_cmd) = 31.4 rad/s."""
    w = np.array([20.0, 25.0, 40.0])
    grid = {"kp": w**2, "kd": 2 * 1.0 * w}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GainGridWarning)
        g = tune_gains("ct", grid=grid)
        # with the cap lifted the faster gains are allowed, and (here) win
        fast = tune_gains("ct", grid=grid, max_bandwidth_rad_s=100.0)
    assert g["kp"] == 625.0
    assert fast["kp"] == 1600.0


def test_gain_rule_is_not_knife_edge():
    """Nominal models a hair apart (1e-3 relative) get the same gains."""
    rng = np.random.default_rng(4)
    base = CONTROL.theta(None)
    for _ in range(3):
        theta = base * (1 + 1e-3 * rng.standard_normal(base.shape))
        with warnings.catch_warnings():
            warnings.simplefilter("error", GainGridWarning)
            gains = tune_gains("ct", params=theta)
        # the same grid point; the gains may differ in the last bit between installs
        assert gains == pytest.approx(DEFAULT_GAINS["ct"], rel=1e-12)


def test_gain_rule_neighbours_must_be_stable_too():
    from pmabayes.control import _neighbours_pass

    ok = np.array([True, True, True, False, True])
    np.testing.assert_array_equal(_neighbours_pass(ok, (5,)), [True, True, False, False, False])
    mesh = np.ones((3, 3), dtype=bool)
    mesh[1, 2] = False
    out = _neighbours_pass(mesh.ravel(), (3, 3)).reshape(3, 3)
    assert out.sum() == 9 - 4  # the point, its neighbours along each axis
    assert not out[0, 2] and not out[2, 2] and not out[1, 1] and out[0, 0]


@pytest.mark.parametrize("fixed", [None, 0.01])
def test_delay_margin_adds_to_a_fixed_or_free_delay(fixed):
    from pmabayes.control import _delayed_plant

    model = Model(["transport_delay"], rig=Rig.control(),
                  fixed={} if fixed is None else {"t_delay": fixed})
    theta = model.theta(None if fixed is not None else {"t_delay": 0.005})
    plant, th = _delayed_plant(model, theta, 0.02)
    before = theta[0, model.index("t_delay")]
    assert th[0, plant.index("t_delay")] == pytest.approx(before + 0.02)
    # the closed loop really runs the delayed plant
    run = closed_loop_batch(plant, th, model, theta, np.array([0.5]), "ct", duration_s=4.0)
    same = closed_loop_batch(model, theta, model, theta, np.array([0.5]), "ct", duration_s=4.0)
    assert not np.array_equal(run.position_m, same.position_m)
    bare, th0 = _delayed_plant(CONTROL, CONTROL.theta(None), 0.02)
    assert th0[0, bare.index("t_delay")] == 0.02


# -- errors -------------------------------------------------------------------------


def test_bad_input_is_refused_clearly():
    with pytest.raises(ControlError, match="unknown controller 'lqr'"):
        closed_loop("lqr", 1.0)
    with pytest.raises(ControlError, match="frequency must be > 0"):
        closed_loop("pid", 0.0)
    with pytest.raises(ControlError, match="frequency must be > 0"):
        track(-1.0)
    with pytest.raises(ControlError, match="unknown ct gains"):
        closed_loop("ct", 1.0, gains={"ct": {"ki": 1.0}})
    with pytest.raises(TypeError):
        closed_loop("pid", 1.0, frequency=2.0)
    with pytest.raises(ControlError, match="pressure-driven"):
        closed_loop("pid", 1.0, model=Model(rig=Rig.force_oscillator(1.0)))


# -- robustness sweeps ----------------------------------------------------------------


# the paper's gains: tuning on each fake fit's posterior mean is tested once, below
SMALL = {"samples": 3, "frequencies_hz": (0.5, 2.0), "duration_s": 4.0, "progress": False,
         "gains": DEFAULT_GAINS}


def test_sweep_same_seed_same_numbers_however_chunked(tmp_path):
    path = fake_fit(tmp_path / "fit.nc")
    a = robustness_sweep(path, seed=7, chunk_size=12, processes=1, **SMALL)
    c = robustness_sweep(path, seed=8, chunk_size=12, processes=1, **SMALL)
    assert a["rms_error_m"].dims == ("sample", "frequency", "controller")
    assert a["rms_error_m"].shape == (3, 2, 2)
    for chunk_size in (1, 3, 5):
        b = robustness_sweep(path, seed=7, chunk_size=chunk_size, processes=1, **SMALL)
        for m in METRICS:
            np.testing.assert_array_equal(a[m].values, b[m].values, err_msg=f"{m}, "
                                          f"chunk_size {chunk_size}")
    for m in METRICS:
        assert np.all(np.isfinite(a[m].values))
    assert not np.array_equal(a["sample_parameters"].values, c["sample_parameters"].values)
    summary = summarise_robustness(a)
    assert summary["p_ct_beats_pid"].dims == ("frequency",)
    assert np.all(summary["rms_error_m_q05"] <= summary["rms_error_m_q95"])


def test_sweep_with_a_regulator_lag_same_numbers_however_chunked(tmp_path):
    """Each run's lag looks back over its own window, not its chunk's longest."""
    path = fake_fit(tmp_path / "fit.nc", spread=0.05, effects=["regulator_lag"],
                    values={"tau_reg": 0.045})
    kw = {**SMALL, "samples": 6, "seed": 2, "processes": 1, "mode": "plant",
          "frequencies_hz": (0.5, 1.0, 2.0)}
    full = robustness_sweep(path, chunk_size=36, **kw)
    assert np.ptp(full["sample_parameters"].sel(parameter="tau_reg").values) > 1e-3
    for chunk_size in (1, 3, 5):
        part = robustness_sweep(path, chunk_size=chunk_size, **kw)
        for m in METRICS:
            np.testing.assert_array_equal(full[m].values, part[m].values,
                                          err_msg=f"{m}, chunk_size {chunk_size}")


def test_sweep_uses_the_operating_point_of_its_nominal_model(tmp_path):
    path = fake_fit(tmp_path / "fit.nc", values={"K_e": 0.8 * CONTROL.defaults["K_e"]})
    from pmabayes.inference.fitfile import load_fit

    tree = load_fit(path)
    model = robustness.control_model_from_fit(tree)
    expected = operating_mean_m(model, posterior_mean(tree, model))
    assert expected != REFERENCE_MEAN_M
    ds = robustness_sweep(path, processes=1, **{**SMALL, "samples": 1,
                                                "frequencies_hz": (2.0,)})
    assert ds.attrs["reference_mean_m"] == expected
    assert "operating_mean_m" in ds.attrs["reference_mean_source"]


def test_sweep_on_local_processes_equals_one_process(tmp_path):
    path = fake_fit(tmp_path / "fit.nc")
    a = robustness_sweep(path, seed=3, chunk_size=4, processes=1, **SMALL)
    b = robustness_sweep(path, seed=3, chunk_size=4, processes=2, **SMALL)
    for m in METRICS:
        np.testing.assert_array_equal(a[m].values, b[m].values)


@pytest.mark.slow
def test_sweep_on_dask_equals_local(tmp_path):
    distributed = pytest.importorskip("distributed")
    path = fake_fit(tmp_path / "fit.nc")
    local = robustness_sweep(path, seed=5, chunk_size=12, processes=1, **SMALL)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        remote = robustness_sweep(path, seed=5, chunk_size=5, client=client, **SMALL)
    assert remote.attrs["runner"].startswith("dask")
    for m in METRICS:
        np.testing.assert_array_equal(local[m].values, remote[m].values)


@pytest.mark.parametrize("mode", ["plant", "model"])
def test_sweep_modes_draw_the_right_side(tmp_path, monkeypatch, mode):
    path = fake_fit(tmp_path / "fit.nc", spread=0.05)
    seen = []
    real = robustness.closed_loop_batch

    def spy(plant_model, plant_theta, controller_model, controller_theta, *args, **kw):
        seen.append((np.array(plant_theta), np.array(controller_theta)))
        return real(plant_model, plant_theta, controller_model, controller_theta, *args, **kw)

    monkeypatch.setattr(robustness, "closed_loop_batch", spy)
    ds = robustness_sweep(path, mode=mode, processes=1, chunk_size=1000, **SMALL)
    assert len(seen) == 1
    theta_plant, theta_controller = seen[0]
    drawn = np.repeat(ds["sample_parameters"].values, 2 * 2, axis=0)  # x frequency x ctrl
    mean = np.broadcast_to(ds["nominal_parameters"].values, drawn.shape)
    assert not np.allclose(drawn, mean)
    if mode == "plant":
        np.testing.assert_array_equal(theta_plant, drawn)
        np.testing.assert_array_equal(theta_controller, mean)
    else:
        np.testing.assert_array_equal(theta_plant, mean)
        np.testing.assert_array_equal(theta_controller, drawn)


@pytest.mark.slow
def test_sweep_tunes_both_controllers_on_the_posterior_mean(tmp_path):
    from pmabayes.inference.fitfile import load_fit

    path = fake_fit(tmp_path / "fit.nc", effects=["regulator_lag"], values={"tau_reg": 0.03})
    kw = {**SMALL, "samples": 2, "frequencies_hz": (1.0,)}
    del kw["gains"]
    ds = robustness_sweep(path, processes=1, **kw)
    tree = load_fit(path)
    model = robustness.control_model_from_fit(tree)
    mean = posterior_mean(tree, model)
    np.testing.assert_array_equal(ds["nominal_parameters"].values, mean)
    tuned = nominal_gains(model, mean, reference_mean_m=ds.attrs["reference_mean_m"])
    assert ds.attrs["reference_mean_m"] == operating_mean_m(model, mean)
    assert json.loads(ds.attrs["gains"]) == tuned
    assert ds.attrs["gains_source"].startswith("tune_gains")
    assert tuned != DEFAULT_GAINS  # the lag changes the best gains
    given = robustness_sweep(path, processes=1, gains=DEFAULT_GAINS, **kw)
    assert json.loads(given.attrs["gains"]) == DEFAULT_GAINS
    assert not np.array_equal(given["rms_error_m"].values, ds["rms_error_m"].values)


def test_sweep_refuses_bad_settings_before_simulating(tmp_path):
    path = fake_fit(tmp_path / "fit.nc")
    for bad in (0, -1, 1.5):
        with pytest.raises(ControlError, match="processes must be an integer >= 1"):
            robustness_sweep(path, processes=bad, **SMALL)
    with pytest.raises(ControlError, match="use at least 8 s"):
        robustness_sweep(path, **{**SMALL, "frequencies_hz": (0.25, 1.0)})
    with pytest.raises(ControlError, match="unknown controllers"):
        robustness_sweep(path, processes=1, **{**SMALL, "gains": {"lqr": {}}})
    ds = robustness_sweep(path, processes=1, seed=np.random.default_rng(1), **SMALL)
    assert "0x" not in str(ds.attrs["seed"])


def test_sweep_modes_at_zero_spread_are_the_nominal_loop(tmp_path):
    path = fake_fit(tmp_path / "fit.nc", spread=0.0)
    kw = {**SMALL, "samples": 2, "frequencies_hz": (1.0,), "duration_s": 10.0,
          "processes": 1}
    plant = robustness_sweep(path, mode="plant", **kw)
    model = robustness_sweep(path, mode="model", **kw)
    nominal = track(1.0, gains=DEFAULT_GAINS)["controllers"]
    for j, c in enumerate(("pid", "ct")):
        for m in METRICS:
            assert plant[m].values[0, 0, j] == pytest.approx(nominal[c][m], rel=1e-9)
            assert model[m].values[1, 0, j] == pytest.approx(nominal[c][m], rel=1e-9)
    with pytest.raises(ControlError, match="unknown mode"):
        robustness_sweep(path, mode="both", **kw)


def test_sweep_output_files(tmp_path):
    path = fake_fit(tmp_path / "fit.nc", effects=["regulator_lag"],
                    values={"tau_reg": 0.03})
    ds = robustness_sweep(path, processes=1, **SMALL)
    assert "tau_reg" in ds["parameter"].values
    paths = write_robustness(ds, tmp_path / "out")
    assert all(p.is_file() for p in paths.values())
    back = xr.open_dataset(paths["netcdf"], engine="h5netcdf")
    np.testing.assert_array_equal(back["rms_error_m"].values, ds["rms_error_m"].values)
    back.close()
    head = paths["summary_csv"].read_text().splitlines()[0]
    assert "p_ct_beats_pid" in head and "p_ct_beats_pid_mc_error" in head
    # the Monte-Carlo error on a hand-made sweep: CT wins 1 of 4, then 4 of 4
    rms = np.array([[[2.0, 1.0]], [[1.0, 2.0]], [[1.0, 2.0]], [[1.0, 2.0]]])
    hand = xr.Dataset({"rms_error_m": (("sample", "frequency", "controller"), rms),
                       "phase_lag_deg": (("sample", "frequency", "controller"), 0 * rms)},
                      coords={"frequency": [1.0], "controller": ["pid", "ct"]})
    summary = summarise_robustness(hand)
    assert float(summary["p_ct_beats_pid"][0]) == 0.25
    assert float(summary["p_ct_beats_pid_mc_error"][0]) == pytest.approx(
        np.sqrt(0.25 * 0.75 / 4))
    hand["rms_error_m"][:, :, 0] = 3.0
    assert float(summarise_robustness(hand)["p_ct_beats_pid_mc_error"][0]) == 0.25
    plt.close(plot_robustness(ds, path=tmp_path / "rob.png"))
    assert (tmp_path / "rob.png").stat().st_size > 10_000


# -- Fig. 5 and the command line -----------------------------------------------------


def test_figure5_reports_each_claim(tmp_path):
    result = figure5(duration_s=6.0)
    plt.close(plot_figure5(result["run"], path=tmp_path / "fig5.png"))
    assert (tmp_path / "fig5.png").stat().st_size > 10_000
    assert len(result["claims"]) == 3
    assert all(isinstance(c["reproduced"], bool) and c["evidence"] for c in result["claims"])
    assert set(result["metrics"]) == {0.5, 1.0, 2.0}
    assert set(result["metrics"][1.0]["ct"]) == set(METRICS)
    assert result["reference_mean_m"] == REFERENCE_MEAN_M


def _claim_metrics(rms_pid, rms_ct, lag_pid, lag_ct, over_ct, settle=0.0):
    return {f: {"pid": {"rms_error_m": rms_pid, "phase_lag_deg": lag_pid,
                        "overshoot_pct": 0.0, "period_difference_m": settle},
                "ct": {"rms_error_m": rms_ct, "phase_lag_deg": lag_ct,
                       "overshoot_pct": over_ct, "period_difference_m": 0.0}}
            for f in (0.5, 1.0, 2.0)}


def test_paper_claims_both_outcomes():
    yes = paper_claims(_claim_metrics(2e-3, 1e-3, 175.0, 60.0, 10.0))
    assert [c["reproduced"] for c in yes] == [True, True, True]
    assert all(c["unsettled"] == [] for c in yes)
    no = paper_claims(_claim_metrics(1e-3, 2e-3, 40.0, 60.0, 20.0))
    assert [c["reproduced"] for c in no] == [False, False, False]
    assert not paper_claims(_claim_metrics(2e-3, 1e-3, 175.0, 185.0, 4.0))[1]["reproduced"]
    unsettled = paper_claims(_claim_metrics(2e-3, 1e-3, 175.0, 60.0, 10.0, settle=0.01))
    assert unsettled[0]["unsettled"] == ["pid at 0.5 Hz", "pid at 1 Hz", "pid at 2 Hz"]
    assert "not settled" in unsettled[0]["evidence"]
    assert unsettled[2]["unsettled"] == []


def test_cli_track_json(tmp_path, capsys):
    out = tmp_path / "t.json"
    assert main(["track", "--freq", "1", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["frequency_hz"] == 1.0
    assert set(data["controllers"]) == {"pid", "ct"}
    for m in data["controllers"].values():
        assert {"rms_error_m", "max_error_m", "amplitude_ratio", "phase_lag_deg",
                "overshoot_pct"} <= set(m)
        assert set(m) == set(METRICS)
    assert main(["track", "--freq", "0.5", "--controller", "ct", "--json", str(out)]) == 0
    assert set(json.loads(out.read_text())["controllers"]) == {"ct"}


@pytest.mark.parametrize("argv,message", [
    (["track", "--freq", "1", "--controller", "lqr"], "unknown controller 'lqr'"),
    (["track", "--freq", "0"], "frequency must be > 0"),
    (["track", "--freq", "-2"], "frequency must be > 0"),
    (["track", "--freq", "1", "--fit", "nowhere.nc"], "no such fit file"),
    (["robustness", "nowhere.nc", "--out", "x"], "no such fit file"),
])
def test_cli_errors(argv, message, capsys):
    assert main(argv) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if not line.startswith("[pmabayes")]  # progress lines (--quiet drops them)
    assert len(err) == 1 and message in err[0]


@pytest.mark.slow
def test_cli_robustness_and_track_with_a_fit(tmp_path, capsys):
    path = fake_fit(tmp_path / "fit.nc")
    assert main(["robustness", str(path), "--samples", "2", "--freqs", "0.5", "1",
                 "--duration", "4", "--processes", "1", "--quiet", "--out",
                 str(tmp_path / "rob")]) == 0
    assert (tmp_path / "rob" / "robustness.nc").is_file()
    assert "P(CT beats PID)" in capsys.readouterr().out
    assert main(["track", "--freq", "1", "--fit", str(path), "--duration", "4"]) == 0
    assert "posterior mean" in capsys.readouterr().out
