"""The start of a held-out record declared "estimate", per posterior draw: draws whose
start cannot be estimated, and a start velocity bounded by the record's own."""

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.criticism.validation import _estimated_starts
from pmabayes.data import Dataset
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.simulator import SimulationError

RATE = 500.0
CUT = 1000  # the held-out part starts mid-cycle, moving


def held_out():
    """The second half of a record of the base model, declared to start where it is."""
    t = np.arange(int(4 * RATE)) / RATE
    p = 0.2e6 * (1 - np.cos(2 * np.pi * 0.5 * t))
    sim = pb.simulate(pb.Model(), None, p, time_s=t, states=True)
    y = sim.position_m[0] + 1e-6 * np.random.default_rng(0).standard_normal(t.size)
    ds = Dataset(time_s=t[CUT:], input=p[None, CUT:], position_m=y[None, CUT:],
                 trial_ids=np.arange(1),
                 metadata={"sample_rate_hz": RATE, "initial_state": "estimate"})
    return ds, sim


def test_a_draw_whose_start_cannot_be_estimated_starts_from_the_prior_and_is_counted():
    """A draw whose simulation is not finite (z runs away: gamma far below -beta) used to
    stop the whole validation; it now keeps the prior means, counted, and the others'
    estimates are what they are without it."""
    ds, sim = held_out()
    model = pb.Model()
    good = model.defaults["gamma"]
    theta = model.theta({"gamma": np.array([good, -1e6, good])})
    prior = Likelihood(model, ds).start_defaults()
    assert not np.isfinite(pb.simulate(model, theta[1:2], ds.input[0, :50],
                                       time_s=ds.time_s[:50], initial_state="estimate",
                                       initial_values=prior)).all()
    est = _estimated_starts(model, theta, ds, 0.05, 1)
    assert np.isfinite(est.values).all()
    assert est.not_estimated == 1
    np.testing.assert_allclose(est.values[1], prior, rtol=1e-12)
    alone = _estimated_starts(model, theta[[0]], ds, 0.05, 1)
    np.testing.assert_allclose(est.values[[0, 2]], np.repeat(alone.values, 2, axis=0),
                               rtol=1e-6, atol=1e-9)  # the batch may take more steps
    assert abs(est.values[0, 1] - sim.velocity_m_s[0, CUT]) < 0.2 * abs(sim.velocity_m_s[0, CUT])


def test_the_start_velocity_is_bounded_by_the_records_speed():
    """A draw far from the data (30 times too little damping) would take a start faster
    than the record moves where the start is fitted: it stops at the largest speed of
    those samples (the whole record's, 3.5 times more here, let a start run off), and
    is counted."""
    ds, _ = held_out()
    model = pb.Model()
    d = model.defaults["d"]
    est = _estimated_starts(model, model.theta({"d": np.array([d, d / 30])}), ds, 0.05, 1)
    speed = np.max(np.abs(np.diff(ds.mean_position_m[:est.samples])) * RATE)
    assert speed < 0.5 * np.max(np.abs(np.diff(ds.mean_position_m)) * RATE)
    slope = Likelihood(model, ds).start_defaults()[1]  # the start's prior mean
    assert est.speed_bound_m_s == pytest.approx(max(1.25 * speed, 1.01 * abs(slope)))
    assert est.speed_bound_m_s < 1.3 * speed
    assert np.all(np.abs(est.values[:, 1]) <= est.speed_bound_m_s)
    assert est.at_bound == 1 and abs(est.values[1, 1]) > 0.99 * est.speed_bound_m_s


def test_a_start_that_is_not_finite_is_named_by_its_rows():
    """The simulator says which rows of initial_values are not finite (the shape was
    right, and its message used to say only the shape)."""
    model = pb.Model()
    theta = model.theta({"d": np.full(3, model.defaults["d"])})
    start = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.0, np.inf, 0.0]])
    with pytest.raises(SimulationError, match=r"2 of 3 rows are not \(rows 1, 2; first "
                                              r"\[nan, 0.0, 0.0\]"):
        pb.simulate(model, theta, np.full(20, 2e5), dt_s=0.002, initial_state="estimate",
                    initial_values=start)
    with pytest.raises(SimulationError, match=r"3 values, or \(3, 3\) for a batch of 3; got "
                                              r"shape \(2, 3\)"):
        pb.simulate(model, theta, np.full(20, 2e5), dt_s=0.002, initial_state="estimate",
                    initial_values=start[:2])


# --- every state of the model: a degrading law's dissipated energy ------------------

DEGRADING = {"delta_nu": 20.0, "delta_eta": 20.0, "zeta_s": 0.0}


def degrading_record():
    """A record of the base model with Baber-Noori degradation (8 s, four cycles), its
    states, and its dissipated energy e = int z dx (the law's state) at each sample."""
    t = np.arange(int(8 * RATE)) / RATE
    p = 0.2e6 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = pb.Model(["bouc_wen_baber_noori"])
    sim = pb.simulate(model, DEGRADING, p, time_s=t, states=True)
    z, x = sim.hysteresis_n[0], sim.true_position_m[0]
    # the law's own step (substeps=1): the trapezoid of z over each sample's dx
    e = np.concatenate([[0.0], np.cumsum(0.5 * (z[1:] + z[:-1]) * np.diff(x))])
    return model, t, p, sim, e


def test_a_start_given_with_the_effects_state_continues_the_record():
    """From a given start holding every state (x, v, the z offset and the dissipated
    energy) the simulation continues the record as it was; restarted undegraded
    (energy 0, all the simulator allowed before) it is far off."""
    model, t, p, sim, e = degrading_record()
    cut = 2 * CUT  # mid-record, after two cycles of degradation
    assert DEGRADING["delta_eta"] * e[cut] > 0.5  # the law's stiffness down by a third
    rest = dict(time_s=t[cut:], initial_state="estimate")
    x0, v0 = sim.true_position_m[0, cut], sim.velocity_m_s[0, cut]
    z_balance = pb.simulate(model, DEGRADING, p[cut:], initial_values=[x0, v0, 0.0, e[cut]],
                            states=True, **rest).hysteresis_n[0, 0]
    start = [x0, v0, sim.hysteresis_n[0, cut] - z_balance]
    on = pb.simulate(model, DEGRADING, p[cut:], initial_values=start + [e[cut]], **rest)[0]
    fresh = pb.simulate(model, DEGRADING, p[cut:], initial_values=start, **rest)[0]
    truth = sim.position_m[0, cut:]
    motion = np.ptp(truth)
    assert np.max(np.abs(on - truth)) < 1e-4 * motion
    assert np.max(np.abs(fresh - truth)) > 0.02 * motion  # the state restarted at 0
    np.testing.assert_array_equal(  # three values: the effects' states at rest
        fresh, pb.simulate(model, DEGRADING, p[cut:], initial_values=start + [0.0], **rest)[0])
    with pytest.raises(SimulationError, match=r"3 or 4 values \(position, velocity and z "
                                              r"offset, e_bwbn\)"):
        pb.simulate(model, DEGRADING, p[cut:], initial_values=start + [0.0, 1.0], **rest)


def test_the_estimated_start_estimates_the_dissipated_energy():
    """The held-out second half of a degrading record: the estimated start holds the
    energy dissipated before it (a prior from the data, through the effect's
    start_state), found within 10% of the record's own, and the prediction after the
    start follows the data; with the energy at 0 (the old start) it does not."""
    model, t, p, sim, e = degrading_record()
    cut = 2 * CUT
    y = sim.position_m[0] + 1e-6 * np.random.default_rng(0).standard_normal(t.size)
    ds = Dataset(time_s=t[cut:], input=p[None, cut:], position_m=y[None, cut:],
                 trial_ids=np.arange(1),
                 metadata={"sample_rate_hz": RATE, "initial_state": "estimate"})
    names = [q.name for q in Likelihood(model, ds).start_parameters()]
    assert names == ["x0_m", "v0_m_s", "z0_offset_n", "e_bwbn0_j"]
    theta = model.theta(DEGRADING)
    est = _estimated_starts(model, theta, ds, 0.05, 1)
    assert est.names[3] == "e_bwbn0_j"
    assert est.values[0, 3] == pytest.approx(e[cut], rel=0.1)
    assert est.samples > 0.05 * ds.n_samples and "reversal" in est.window
    run = dict(time_s=ds.time_s, initial_state="estimate")
    after = slice(est.samples, None)
    x = pb.simulate(model, theta, ds.input[0], initial_values=est.values, **run)[0]
    undegraded = est.values.copy()
    undegraded[:, 3] = 0.0
    x_old = pb.simulate(model, theta, ds.input[0], initial_values=undegraded, **run)[0]
    motion = np.ptp(ds.mean_position_m)
    err = np.sqrt(np.mean((x[after] - ds.mean_position_m[after]) ** 2))
    err_old = np.sqrt(np.mean((x_old[after] - ds.mean_position_m[after]) ** 2))
    assert err < 0.01 * motion
    assert err_old > 5 * err


def test_the_first_reversal_and_the_start_window():
    from pmabayes.criticism.validation import _first_reversal

    y = np.array([0.0, 1.0, 2.0, 1.9, 2.5, 3.0, 2.0, 1.0, np.nan, 0.0])
    assert _first_reversal(y, 0.5) == (5, 6)  # the dip at 3 is smaller than the turn
    assert _first_reversal(-y, 0.5) == (5, 6)
    assert _first_reversal(np.arange(10.0), 0.5) is None
    assert _first_reversal(np.array([3.0, 2.0, 1.0, 2.0]), 0.5) == (2, 3)  # not the start
