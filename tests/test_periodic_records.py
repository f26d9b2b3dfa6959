"""Periodic records declared in a sidecar: a record from rest whose periods are its
repeats, parameter sets whose step overflows, and members that find no steady state."""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.data import Dataset
from pmabayes.inference.likelihood import (
    Likelihood,
    _kalman_innovations,
    ar1_whiteness_of_repeats,
)
from pmabayes.model import simulator as sim


def _from_rest(warmup_s: float, period: int = 100, n_periods: int = 5) -> Dataset:
    """A record from rest of a periodic input at 100 Hz (seeded noise)."""
    fs = 100.0
    t = np.arange(period * n_periods) / fs
    u = 3e5 + 1.5e5 * np.sin(2 * np.pi * t * fs / period)
    x = pb.simulate(pb.Model(), None, u, dt_s=1 / fs)[0]
    y = x + 2e-5 * np.random.default_rng(3).standard_normal(x.size)
    return Dataset(time_s=t, input=u[None], position_m=y[None], trial_ids=np.arange(1),
                   input_name="pressure_pa", source="rest.csv",
                   metadata={"period_samples": period, "warmup_s": warmup_s,
                             "initial_state": "rest"})


@pytest.mark.parametrize("warmup_periods", [1.0, 1.5])
def test_periods_of_a_record_from_rest_are_whitened_on_their_own_grid(warmup_periods):
    """A record from rest with a warm-up: its periods (not the whole record) are the
    repeats whose contrasts the whiteness check whitens, with the samples every period
    observes (a warm-up into the second period leaves some out)."""
    ds = _from_rest(warmup_s=warmup_periods * 1.0)
    lik = Likelihood(pb.Model(), ds)
    assert lik.noise_source == "periods" and lik.observed is not None
    p, energy, innov = ar1_whiteness_of_repeats(lik, 2e-5, 0.3, 1e-6)
    assert len(innov) == lik.n_repeats - 1 == 3
    assert all(e.shape == (100,) for e in innov)
    assert 0.0 <= p <= 1.0 and math.isfinite(energy)
    seen = np.all(np.isfinite(innov), axis=0)
    # the samples left out are those a period after the first does not observe
    assert int((~seen).sum()) == (50 if warmup_periods == 1.5 else 0)
    expected = _kalman_innovations(np.ascontiguousarray(lik.contrasts[0]), 1.0, 2e-5, 0.3,
                                   1e-6, seen)
    np.testing.assert_array_equal(innov[0], expected)


def test_an_overflowing_step_is_bounded_and_said_once(monkeypatch):
    """A damping so large over the moving mass that the exact step overflows once made
    the matrix exponential halve an infinite norm for ever: now the member simulates to
    NaN at once, the others are unchanged, and a warning says so once a process."""
    model = pb.Model()
    monkeypatch.setattr(sim, "_OVERFLOW_SAID", [False])
    u = np.full(200, 3e5)
    good = model.theta(model.defaults)
    extreme = model.theta(dict(model.defaults, d=1.7e308))
    alone = pb.simulate(model, good, u, dt_s=2e-4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        x = pb.simulate(model, np.vstack([good, extreme, extreme]), u, dt_s=2e-4)
        pb.simulate(model, extreme, u, dt_s=2e-4)
        seconds = time.perf_counter() - t0
    assert seconds < 20.0
    np.testing.assert_array_equal(x[0], alone[0])
    assert np.isnan(x[1:, -1]).all()
    said = [w for w in caught if issubclass(w.category, sim.OverflowingStepWarning)]
    assert len(said) == 1 and "d = 1.7e+308" in str(said[0].message)


def _steady_case(scales: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    model = pb.Model()
    fs, period = 1000.0, 1000
    t = np.arange(2 * period) / fs
    u = 3e5 + 1.5e5 * np.sin(2 * np.pi * t)
    theta = np.vstack([model.theta({k: v * s.get(k, 1.0) for k, v in model.defaults.items()})
                       for s in scales])
    return theta, u


def test_members_that_cannot_settle_stop_early_and_are_counted_once():
    """A member whose change stays put (a drift from period to period, a very soft
    bladder) stops long before the budget; the members that settle are unchanged; within
    collect_steady_state_misses one warning counts them all."""
    theta, u = _steady_case([{}, {"K_e": 1.0 / 624.78}, {"d": 1e-3}])
    run = dict(model=pb.Model(), theta=theta, u=u, t=np.arange(u.size) * 1e-3, dt=1e-3,
               substeps=1, between_samples="hold", period=1000, initial_state="rest")
    calls = []
    real = sim._periods

    def counted(run_, state, members):
        calls.append(members.copy())
        return real(run_, state, members)

    with warnings.catch_warnings(record=True) as caught, pytest.MonkeyPatch.context() as mp:
        warnings.simplefilter("always")
        mp.setattr(sim, "_periods", counted)
        with sim.collect_steady_state_misses():
            sim._steady_state(run, 1e-9, 256)
            sim._steady_state(run, 1e-9, 256)
    periods_of_drift = sum(int((c == 1).sum()) for c in calls) // 2
    assert periods_of_drift < 128  # it used all 255 before
    said = [w for w in caught if issubclass(w.category, sim.SteadyStateWarning)]
    assert len(said) == 1
    assert "2 of 6 parameter sets" in str(said[0].message)
    assert "2 of them stopped before" in str(said[0].message)


def test_settling_members_do_not_change():
    """The early stop leaves the members that settle to the last bit: each simulated
    alone and beside members that cannot settle."""
    theta, u = _steady_case([{}, {"K_e": 1.0 / 624.78}, {"d": 1e-3}, {"beta": 1e-3}])
    model = pb.Model()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sim.SteadyStateWarning)
        together = pb.simulate(model, theta, u, dt_s=1e-3, period_samples=1000,
                               steady_state=True)
        for i in (0, 2, 3):
            alone = pb.simulate(model, theta[i], u, dt_s=1e-3, period_samples=1000,
                                steady_state=True)
            np.testing.assert_array_equal(together[i], alone[0])
