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


RANK_CHIRP = Chirp(duration_s=8.0, f0_hz=0.3, f1_hz=3.0)
#: the built-in library; other tests register user effects (a near-twin of Coulomb
#: friction among them), which would rightly compete here
BUILTINS = ("regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
            "pressure_stiffness", "position_offset")


def ranking(hidden):
    from pmabayes.criticism import rank_effects
    from pmabayes.fit import Posterior, find_map

    ds = generate_chirp_dataset(n_trials=6, seed=3, chirp=RANK_CHIRP, effects=hidden)
    lik = Likelihood(pb.Model(), ds)
    noise = estimate_noise(lik)
    values = find_map(Posterior(lik, noise), rng=np.random.default_rng(0)).values
    return rank_effects(lik, noise, values, candidates=BUILTINS)


def test_nothing_flagged_without_a_hidden_effect():
    ranked = ranking(None)
    assert not any(e.significant for e in ranked), ranked[0]
    assert {e.effect for e in ranked} == set(BUILTINS)


@pytest.mark.parametrize(
    ("hidden", "name", "truth"),
    [
        ({"coulomb_friction": 0.8}, "coulomb_friction", ("F_c", 0.8)),
        ({"position_offset": 5e-4}, "position_offset", ("x_offset", 5e-4)),
        ({"pressure_stiffness": 3e-4}, "pressure_stiffness", None),
        ({"cubic_stiffness": 2e4}, "cubic_stiffness", None),
    ],
)
def test_a_hidden_effect_ranks_first_and_is_significant(hidden, name, truth):
    ranked = ranking(hidden)
    top = ranked[0]
    assert top.effect == name and top.significant and top.explained > 0.8
    if truth is not None:  # one-step estimates are first order: loose check
        param, value = truth
        assert top.estimate[param] == pytest.approx(value, rel=0.1)


@pytest.mark.parametrize("hidden", [{"regulator_lag": 0.045}, {"transport_delay": 0.02}])
def test_lag_and_delay_are_flagged_together(hidden):
    """Same first-order signature: both top the ranking, nearly tied (documented)."""
    top_two = ranking(hidden)[:2]
    assert {e.effect for e in top_two} == {"regulator_lag", "transport_delay"}
    assert all(e.significant for e in top_two)
    assert top_two[1].statistic > 0.99 * top_two[0].statistic


def _drag(q, x, v, p):
    return q[0] * v * abs(v), 0.0, 2.0 * q[0] * abs(v)


class CritQuadraticDrag(pb.Effect):
    """A user effect defined outside the package (turbulent drag)."""

    name = "crit_quadratic_drag"
    stage = "force"
    parameters = (pb.Parameter("c_drag", "N s^2/m^2", 100.0, pb.HalfNormal(500.0),
                               bounds=(0.0, 1e5), null=0.0,
                               description="drag force per squared velocity"),)
    description = "Drag growing with the square of the velocity."
    physics = staticmethod(_drag)


pb.register_effect(CritQuadraticDrag)


def test_a_hidden_user_effect_is_found():
    from pmabayes.criticism import rank_effects
    from pmabayes.fit import Posterior, find_map

    ds = generate_chirp_dataset(n_trials=6, seed=4, chirp=RANK_CHIRP,
                                effects={"crit_quadratic_drag": 300.0})
    lik = Likelihood(pb.Model(), ds)
    noise = estimate_noise(lik)
    values = find_map(Posterior(lik, noise), rng=np.random.default_rng(0)).values
    ranked = rank_effects(lik, noise, values,
                          candidates=(*BUILTINS, "crit_quadratic_drag"))
    assert ranked[0].effect == "crit_quadratic_drag" and ranked[0].significant
