"""Model criticism: band errors against the floor, whiteness and independence tests."""

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.criticism import (
    autocorrelation,
    band_errors,
    cross_correlation,
    innovations,
    instantaneous_frequency,
    ljung_box,
)
from pmabayes.data import Dataset
from pmabayes.fit import estimate_noise
from pmabayes.likelihood import Likelihood
from pmabayes.synthetic import Chirp, generate_chirp_dataset

CHIRP = Chirp(duration_s=6.0, f0_hz=0.5, f1_hz=3.0)


@pytest.fixture(scope="module")
def perfect():
    ds = generate_chirp_dataset(n_trials=6, seed=21, chirp=CHIRP)
    return ds, pb.Model(), None


@pytest.fixture(scope="module")
def lagged():
    """Data with a hidden 45 ms regulator lag, to be judged by the base model."""
    ds = generate_chirp_dataset(n_trials=6, seed=22, chirp=CHIRP,
                                effects={"regulator_lag": 0.045})
    return ds, pb.Model(), None


def judge(case):
    ds, model, params = case
    lik = Likelihood(model, ds)
    x = lik.simulate(model.theta(params))[0]
    return ds, lik, x, innovations(lik, x, estimate_noise(lik))


def test_instantaneous_frequency_from_metadata_and_from_the_input(perfect):
    ds = perfect[0]
    f = instantaneous_frequency(ds)
    assert f[0] == pytest.approx(0.5) and f[-1] == pytest.approx(3.0, abs=1e-3)
    bare = Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                   trial_ids=ds.trial_ids)  # no sidecar: estimated from the input
    g = instantaneous_frequency(bare)
    middle = slice(1000, 5000)
    assert np.max(np.abs(g[middle] - f[middle])) < 0.1


def test_a_perfect_model_sits_on_the_floor_and_leaves_white_innovations(perfect):
    ds, lik, x, e = judge(perfect)
    for row in band_errors(ds, x):
        assert 0.6 < row.ratio < 1.6, row
    assert e.std() == pytest.approx(1.0, abs=0.05)
    assert ljung_box(e)[1] > 0.01


def test_a_missing_lag_is_above_the_floor_and_not_white(lagged):
    ds, lik, x, e = judge(lagged)
    rows = band_errors(ds, x)
    assert rows[-1].ratio > 20  # overall
    # a lag hurts more as frequency rises
    assert rows[-2].ratio > rows[0].ratio
    assert ljung_box(e)[1] < 1e-6
    lags, ccf, bound = cross_correlation(e, np.gradient(ds.input[0]), max_lag=100)
    assert np.max(np.abs(ccf)) > 3 * bound


def test_autocorrelation_bound_and_ljung_box_on_white_noise():
    rng = np.random.default_rng(0)
    w = rng.standard_normal(20000)
    lags, acf, bound = autocorrelation(w, max_lag=200, level=0.99)
    assert bound == pytest.approx(2.5758 / np.sqrt(20000), rel=1e-4)
    assert np.mean(np.abs(acf) > bound) < 0.03
    assert ljung_box(w)[1] > 0.01
    ar = np.zeros(20000)
    for k in range(1, 20000):
        ar[k] = 0.5 * ar[k - 1] + w[k]
    assert ljung_box(ar)[1] < 1e-10


def test_cross_correlation_finds_a_delay():
    rng = np.random.default_rng(1)
    u = rng.standard_normal(5000)
    e = np.roll(u, 7) + 0.5 * rng.standard_normal(5000)  # e[t] depends on u[t - 7]
    lags, ccf, bound = cross_correlation(e, u, max_lag=20)
    assert lags[np.argmax(ccf)] == 7 and ccf.max() > 10 * bound


def test_band_errors_reject_bad_input(perfect):
    ds = perfect[0]
    with pytest.raises(ValueError, match="model output has 10 samples"):
        band_errors(ds, np.zeros(10))
    with pytest.raises(ValueError, match="at least 2 repeated trials"):
        band_errors(ds.select_trials([0]), np.zeros(ds.n_samples))
