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
    than the record ever moves: it stops at the record's largest speed, and is counted."""
    ds, _ = held_out()
    model = pb.Model()
    d = model.defaults["d"]
    est = _estimated_starts(model, model.theta({"d": np.array([d, d / 30])}), ds, 0.05, 1)
    speed = np.max(np.abs(np.diff(ds.mean_position_m)) * RATE)
    assert est.speed_bound_m_s == pytest.approx(speed)
    assert np.all(np.abs(est.values[:, 1]) <= est.speed_bound_m_s)
    assert est.at_bound == 1 and abs(est.values[1, 1]) > 0.99 * speed


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
