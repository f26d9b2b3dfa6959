"""The noise model of the sampler's likelihood: AR(1) + white, or the repeats' AR(p).

The AR(p) likelihood is checked against the dense multivariate normal density, the
choice against disturbances of one and of two time scales, and the AR(1) path
against itself (bit for bit) where the repeats accept it.
"""

import math
import warnings

import arviz as az
import numpy as np
import pytest
from scipy import stats
from scipy.linalg import toeplitz

import pmabayes as pb
from pmabayes.data import Dataset
from pmabayes.inference.density import Posterior
from pmabayes.inference.errors import FitError
from pmabayes.inference.fitfile import fit_info, load_fit, noise_models, save_fit
from pmabayes.inference.likelihood import (
    ArNoise,
    Likelihood,
    ar_noise_from_repeats,
    check_noise_model_name,
    choose_noise_model,
    levinson,
)
from pmabayes.inference.noise import estimate_noise
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

CHIRP = Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=2.0)
#: two time scales (10 ms and 1 s) that AR(1) + white does not describe
TWO_SCALE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.010,
                             slow_std_m=50e-6, slow_corr_time_s=1.0)
BASE = ("alpha", "beta", "gamma", "d", "K_e", "p_dz")


def ar2_acov(n_lags: int) -> np.ndarray:
    """Autocovariance of a stationary AR(2) with a resonance, from its recursion."""
    a1, a2, s2 = 1.2, -0.5, 1e-12
    # Yule-Walker for gamma_0, gamma_1, then the recursion
    r1 = a1 / (1.0 - a2)
    g0 = s2 / (1.0 - a1 * r1 - a2 * (a1 * r1 + a2))
    g = [g0, r1 * g0]
    while len(g) < n_lags:
        g.append(a1 * g[-1] + a2 * g[-2])
    return np.array(g)


def short_dataset(n: int = 40, r: int = 3, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = np.tile(np.linspace(1e5, 3e5, n), (r, 1))
    y = 1e-3 * np.sin(t * 50)[None] + 1e-6 * rng.standard_normal((r, n))
    return Dataset(time_s=t, input=u, position_m=y, trial_ids=np.arange(r) + 1)


# -- the likelihood -------------------------------------------------------------------

def test_ar_likelihood_is_the_dense_gaussian_density():
    ar = ArNoise(ar2_acov(4))  # order 3, the third coefficient ~0
    assert ar.order == 3
    rng = np.random.default_rng(1)
    v = 1e-6 * rng.standard_normal((4, 25))
    cov = toeplitz(ar.autocovariance(25))
    dense = np.array([stats.multivariate_normal(np.zeros(25), cov).logpdf(x) for x in v])
    np.testing.assert_allclose(ar.log_likelihood(v), dense, rtol=1e-10)
    # the whitened series are the same innovations
    w = ar.whiten(v[0])
    var = ar.variances[np.minimum(np.arange(25), ar.order)]
    direct = -0.5 * np.sum(w * w) - 0.5 * np.sum(np.log(2 * math.pi * var))
    assert direct == pytest.approx(dense[0], rel=1e-10)


def test_the_trial_mean_likelihood_in_the_simulators_layout():
    """Likelihood.mean_log_likelihood with an AR(p): the dense density of sqrt(R)(ybar - x)
    for every member of a batch given in the simulator's (n, batch) layout."""
    ds = short_dataset()
    lik = Likelihood(pb.Model(), ds)
    ar = ArNoise(ar2_acov(3))
    lik.use_ar_noise(ar)
    rng = np.random.default_rng(2)
    xt = np.ascontiguousarray(ds.mean_position_m[:, None]
                               + 1e-6 * rng.standard_normal((ds.n_samples, 5)))
    x = xt.T  # the simulator's layout seen as (batch, n)
    got = lik.mean_log_likelihood(x, 1.0, 0.5, 1.0)  # the AR(1) values are ignored
    cov = toeplitz(ar.autocovariance(ds.n_samples))
    mvn = stats.multivariate_normal(np.zeros(ds.n_samples), cov)
    want = [mvn.logpdf(math.sqrt(ds.n_trials) * (ds.mean_position_m - xb)) for xb in x]
    np.testing.assert_allclose(got, want, rtol=1e-10)
    # a C-ordered (batch, n) array gives the same numbers
    np.testing.assert_array_equal(lik.mean_log_likelihood(np.ascontiguousarray(x), 0, 0, 0), got)
    # per trial: each trial's residual is a series of the noise
    per = lik.pointwise(x[:2], 0, 0, 0)
    assert per.shape == (2, ds.n_trials)
    assert per[1, 2] == pytest.approx(mvn.logpdf(ds.position_m[2] - x[1]), rel=1e-10)


def test_ar_draws_have_the_models_autocovariance():
    ar = ArNoise(ar2_acov(3))
    d = ar.draw(20000, 30, np.random.default_rng(3))
    emp = np.mean(d[:, :, None] * d[:, None, :], axis=0)
    want = toeplitz(ar.autocovariance(30))
    # stationary from the first sample: same covariance at the start as later on
    assert np.max(np.abs(emp - want)) < 0.05 * want[0, 0]
    np.testing.assert_array_equal(ar.draw(3, 10, np.random.default_rng(4)),
                                  ar.draw(3, 10, np.random.default_rng(4)))


def test_yule_walker_recovers_an_ar_process_and_round_trips():
    ar_true = ArNoise(ar2_acov(3))
    series = ar_true.draw(6, 4000, np.random.default_rng(5))
    est = ar_noise_from_repeats(series, max_order=20)
    assert 2 <= est.order <= 8
    np.testing.assert_allclose(est.coefficients[est.order, :2], [1.2, -0.5], atol=0.05)
    again = ArNoise.from_dict(est.to_dict())
    np.testing.assert_array_equal(again.coefficients, est.coefficients)
    np.testing.assert_array_equal(again.variances, est.variances)
    phi, var = levinson(est.autocovariance_m2, est.order)
    np.testing.assert_array_equal(phi, est.coefficients)


# -- the choice -----------------------------------------------------------------------

def test_auto_picks_ar_p_on_two_time_scales_and_ar1_on_the_default():
    default = generate_chirp_dataset(n_trials=4, seed=21, chirp=CHIRP)
    two = generate_chirp_dataset(n_trials=4, seed=21, chirp=CHIRP, noise=TWO_SCALE)
    for ds, expect_ar in ((default, False), (two, True)):
        lik = Likelihood(pb.Model(), ds)
        nz = estimate_noise(lik)
        choice = choose_noise_model(lik, nz.sigma, nz.rho, nz.white, "auto")
        assert (choice.ar is not None) is expect_ar, choice.describe()
        if expect_ar:
            assert choice.ljung_box_p < 0.01 and choice.ar.order >= 2
            assert "reject" in choice.describe()
        else:
            assert choice.ljung_box_p >= 0.01 and "accept" in choice.describe()
        # forced choices
        assert choose_noise_model(lik, nz.sigma, nz.rho, nz.white, "ar1").ar is None
        assert choose_noise_model(lik, nz.sigma, nz.rho, nz.white, "ar").ar is not None


@pytest.mark.parametrize("which", ["generated", "bundled"])
def test_the_ar1_path_is_bit_identical_when_the_repeats_accept_it(which):
    """Where the repeats accept AR(1) + white (the bundled data set does), the posterior
    density is the one of before, bit for bit."""
    from pathlib import Path

    from pmabayes.data import load

    ds = (generate_chirp_dataset(n_trials=3, seed=11, chirp=CHIRP) if which == "generated"
          else load(Path(__file__).resolve().parents[1] / "data" / "pma_chirp_lab.csv"))
    auto = build_posterior(pb.Model(), ds, noise_model="auto")
    assert auto.likelihoods[0].ar_noise is None
    assert auto.noise_choices[0].name == "AR(1) + white"
    # the posterior as it was built before noise models: AR(1) + white from the repeats
    lik = Likelihood(pb.Model(), ds)
    before = Posterior(lik, estimate_noise(lik))
    rng = np.random.default_rng(0)
    theta = pb.Model().theta(None)[:, before._free_cols]
    z = before.to_unconstrained(np.repeat(theta, 16, axis=0))
    z = z + 0.02 * rng.standard_normal(z.shape)
    np.testing.assert_array_equal(auto.log_prob_z(z), before.log_prob_z(z))
    forced = build_posterior(pb.Model(), ds, noise_model="ar1")
    np.testing.assert_array_equal(forced.log_prob_z(z), before.log_prob_z(z))
    # with the AR(p) the density is another one
    ar = build_posterior(pb.Model(), ds, noise_model="ar")
    assert ar.likelihoods[0].ar_noise is not None
    assert not np.array_equal(ar.log_prob_z(z), before.log_prob_z(z))


def test_a_record_without_repeats_keeps_the_guarded_ar1():
    ds = generate_chirp_dataset(n_trials=1, seed=2, chirp=CHIRP, noise=TWO_SCALE)
    post = build_posterior(pb.Model(), ds, noise_model="ar")
    assert post.likelihoods[0].ar_noise is None and post.noise_sampled(0)
    assert "no repeats" in post.noise_choices[0].describe()


# -- bad input -------------------------------------------------------------------------

def test_an_unknown_noise_model_is_a_clear_error():
    ds = generate_chirp_dataset(n_trials=3, seed=11, chirp=CHIRP)
    with pytest.raises(FitError, match="noise_model must be one of 'auto', 'ar1', 'ar'"):
        fit(ds, settings=FitSettings(noise_model="arma"))
    with pytest.raises(ValueError, match="got 'AR1'"):
        check_noise_model_name("AR1")
    with pytest.raises(ValueError, match="positive variance at lag 0"):
        ArNoise(np.array([0.0, 0.1]))
    with pytest.raises(ValueError, match="not positive definite"):
        ArNoise(np.array([1.0, 1.5]))
    with pytest.raises(TypeError, match="ArNoise or None"):
        Likelihood(pb.Model(), ds).use_ar_noise([1.0, 0.5])


def test_cli_rejects_an_unknown_noise_model(capsys):
    from pmabayes.cli import main

    with pytest.raises(SystemExit):
        main(["fit", "x.csv", "--out", "f.nc", "--noise-model", "arma"])
    assert "invalid choice: 'arma'" in capsys.readouterr().err


# -- the fit file ------------------------------------------------------------------------

@pytest.mark.slow
def test_a_two_time_scale_fit_uses_the_ar_model_and_covers_the_truth(tmp_path, capsys):
    """A fit of two-time-scale data with "auto": the repeats' AR(p) in the likelihood,
    the fit file and the predictive noise, and 90% intervals that cover the truth."""
    ds = generate_chirp_dataset(n_trials=4, seed=5, chirp=CHIRP, noise=TWO_SCALE)
    settings = FitSettings(n_walkers=16, n_ensembles=2, max_steps=3000, check_every=200,
                           progress=True)
    tree = fit(ds, pb.Model(), seed=3, settings=settings)
    assert "reject AR(1) + white" in capsys.readouterr().err
    info = fit_info(tree)
    assert info["convergence"]["converged"], info["convergence"]["messages"]
    rec = info["experiments"][0]["noise_model"]
    assert rec["model"].startswith("AR(") and rec["order"] >= 2
    assert len(rec["coefficients"]) == rec["order"] and rec["ljung_box_p"] < 0.01
    path = save_fit(tree, tmp_path / "fit.nc")
    (ar,) = noise_models(load_fit(path))
    assert ar is not None and ar.order == rec["order"]
    hdi = az.hdi(tree, prob=0.9)
    missed = [n for n in BASE if not hdi[n].values[0] <= pb.PAPER_VALUES[n] <= hdi[n].values[1]]
    assert not missed, missed
    # the predictive trials scatter around the model as the AR(p) says
    pp = tree["posterior_predictive"]
    dev = (pp["position_m"] - pp["model_position_m"]).values.reshape(-1, ds.n_samples)
    assert np.std(dev) == pytest.approx(math.sqrt(ar.autocovariance_m2[0]), rel=0.25)


def _tree_from_draws(posterior, n_chain: int = 8, n_draw: int = 6, seed: int = 0):
    """A fit file from draws scattered about the generator's values, as the sampler's."""
    from pmabayes.inference.fitfile import fit_tree, set_fit_info

    rng = np.random.default_rng(seed)
    theta = pb.Model().theta(None)[:, posterior._free_cols]
    z = posterior.to_unconstrained(np.repeat(theta, n_chain * n_draw, axis=0))
    z = (z + 1e-3 * rng.standard_normal(z.shape)).reshape(n_chain, n_draw, -1)
    lp = posterior.log_prob_z(z.reshape(-1, z.shape[-1])).reshape(n_chain, n_draw)
    tree = fit_tree(posterior, z, lp, np.zeros(n_chain, dtype=int), ppc_draws=20, rng=rng)
    set_fit_info(tree, posterior, map_record={}, convergence={}, seed=0, timings={})
    return tree


def test_the_fit_file_records_the_noise_model_and_predicts_with_it(tmp_path):
    from pmabayes.criticism.validation import validate

    ds = generate_chirp_dataset(n_trials=4, seed=21, chirp=CHIRP, noise=TWO_SCALE)
    post = build_posterior(pb.Model(), ds)
    ar = post.likelihoods[0].ar_noise
    assert ar is not None
    tree = _tree_from_draws(post)
    rec = fit_info(tree)["experiments"][0]["noise_model"]
    assert rec["model"] == ar.name and rec["order"] == ar.order and rec["requested"] == "auto"
    np.testing.assert_allclose(rec["coefficients"], ar.coefficients[ar.order, : ar.order])
    (back,) = noise_models(load_fit(save_fit(tree, tmp_path / "fit.nc")))
    np.testing.assert_array_equal(back.variances, ar.variances)
    # the predictive trials scatter as the AR(p) does, not as the AR(1) estimate would
    pp = tree["posterior_predictive"]
    dev = (pp["position_m"] - pp["model_position_m"]).values.reshape(-1, ds.n_samples)
    assert np.std(dev) == pytest.approx(math.sqrt(ar.autocovariance_m2[0]), rel=0.15)
    # the per-trial log likelihood is the AR(p)'s
    first = np.array([[float(tree["posterior"][n].values[0, 0]) for n in post.names]])
    x = post.likelihoods[0].simulate(post.full_theta(first))
    np.testing.assert_allclose(tree["log_likelihood"]["position_m"].values[0, 0],
                               post.likelihoods[0].pointwise(x, 0, 0, 0)[0], rtol=1e-5)
    # validation's predictive band uses it too
    other = generate_chirp_dataset(n_trials=4, seed=22, chirp=CHIRP, noise=TWO_SCALE)
    v = validate(tree, other, n_draws=20).experiments[0]
    assert any("AR(" in note for note in v.notes), v.notes


def test_a_fit_with_ar1_noise_records_it_and_predicts_as_before():
    ds = generate_chirp_dataset(n_trials=3, seed=11, chirp=CHIRP)
    post = build_posterior(pb.Model(), ds)
    tree = _tree_from_draws(post)
    rec = fit_info(tree)["experiments"][0]["noise_model"]
    assert rec["model"] == "AR(1) + white" and rec["order"] == 1 and rec["ljung_box_p"] >= 0.01
    assert "coefficients" not in rec and noise_models(tree) == [None]


# -- diagnose --------------------------------------------------------------------------

def test_diagnose_rejects_an_unknown_noise_model_before_fitting():
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings

    ds = generate_chirp_dataset(n_trials=2, seed=1, chirp=CHIRP)
    with pytest.raises(ValueError, match="noise_model"):
        diagnose(ds, settings=DiagnoseSettings(noise_model="ar2"))


@pytest.mark.slow
def test_diagnose_refits_with_the_repeats_noise_model():
    """On two-time-scale data a refit's interval and ELPD use the repeats' AR(p) with
    "auto" (the same as "ar", not as "ar1"), and its interval covers the hidden lag."""
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings

    lag = 0.03
    ds = generate_chirp_dataset(n_trials=4, seed=5, chirp=CHIRP, noise=TWO_SCALE,
                                effects={"regulator_lag": lag})
    kw = dict(candidates=("regulator_lag",), max_refits=1, discrepancy=False, n_draws=100)
    runs = {m: diagnose(ds, settings=DiagnoseSettings(noise_model=m, **kw), seed=0)
            for m in ("auto", "ar", "ar1")}
    refits = {m: d.ranking[0].refit for m, d in runs.items()}
    assert all(r is not None and r.effect == "regulator_lag" for r in refits.values())
    assert refits["auto"].interval == refits["ar"].interval
    assert refits["auto"].elpd == refits["ar"].elpd
    assert refits["auto"].interval != refits["ar1"].interval
    lo, hi = refits["auto"].interval["tau_reg"]
    assert lo <= lag <= hi
    assert runs["auto"].missing == "regulator_lag"
    assert runs["auto"].settings["noise_model"][0].startswith("AR(")
    assert runs["ar1"].settings["noise_model"] == ["AR(1) + white"]


def test_the_noise_search_outside_its_support_warns_of_nothing():
    # a cost that is inf on half the space: from a start whose whole first simplex is
    # there, scipy's convergence test subtracts inf from inf (the NaN is "not
    # converged", as it should be); from one beside the edge, the search finds the optimum
    from pmabayes.inference.noise.repeats import _minimise_noise

    def neg(u):
        u = np.atleast_2d(u)
        inside = u[:, 0] < 0.0
        return np.where(inside, np.sum((u - [-1.0, 0.5, 0.0]) ** 2, axis=1), np.inf)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stuck = _minimise_noise(neg, np.array([5.0, 0.5, 0.0]), shift=np.zeros(3))
        best = _minimise_noise(neg, np.array([-1e-4, 0.5, 0.0]), shift=np.zeros(3))
    assert np.array_equal(stuck, [5.0, 0.5, 0.0])  # it cannot leave its start
    assert np.allclose(best, [-1.0, 0.5, 0.0], atol=1e-6)


def test_the_noise_search_keeps_the_costs_own_warnings():
    from pmabayes.inference.noise.repeats import _minimise_noise

    def neg(u):
        u = np.atleast_2d(u)
        return np.sum(u**2, axis=1) + (np.zeros(1) / np.zeros(1) if u[0, 0] > 5 else 0.0)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _minimise_noise(neg, np.array([6.0, 0.0, 0.0]), shift=np.zeros(3))
    assert any("invalid value" in str(w.message) for w in caught)
