"""The AR(1) likelihood of repeated trials."""

import dataclasses
import math

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.data import DataError, Dataset
from pmabayes.inference.likelihood import Likelihood, LikelihoodError, slow_disturbance_note
from pmabayes.synthetic import Chirp, generate_chirp_dataset

CHIRP = Chirp(duration_s=0.4, f0_hz=1.0, f1_hz=3.0)  # short: the reference is dense


def brute_force(y, x, sigma, rho, white=0.0):
    """Exact Gaussian log-likelihood of one series, from its dense covariance:
    AR(1) sigma^2 rho^|i-j| plus white^2 on the diagonal."""
    e = np.asarray(y - x, dtype=float)
    n = e.size
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    cov = sigma**2 * rho**lag + white**2 * np.eye(n)
    sign, logdet = np.linalg.slogdet(cov)
    return -0.5 * (n * math.log(2 * math.pi) + logdet + e @ np.linalg.solve(cov, e))


@pytest.fixture(scope="module")
def lik():
    ds = generate_chirp_dataset(n_trials=4, seed=3, chirp=CHIRP)
    return Likelihood(pb.Model(), ds)


def test_matches_the_dense_gaussian(lik):
    theta = pb.Model().theta({"K_e": [600.0, 624.78, 650.0]})
    x = lik.simulate(theta)
    sigma = np.array([5e-5, 6e-5, 7e-5])
    rho = np.array([0.95, 0.99, -0.3])
    white = np.array([4e-6, 0.0, 2e-5])
    expected = np.array([[brute_force(lik.dataset.position_m[t], x[b], sigma[b], rho[b],
                                      white[b]) for t in range(4)] for b in range(3)])
    pointwise = lik.pointwise(x, sigma, rho, white)
    assert np.allclose(pointwise, expected, rtol=1e-10, atol=1e-6)
    assert np.allclose(lik.log_likelihood(x, sigma, rho, white), expected.sum(axis=1),
                       rtol=1e-10, atol=1e-6)


def test_rms_cost_is_the_papers(lik):
    x = lik.simulate(pb.Model().theta())
    expected = np.sqrt(np.mean((lik.dataset.position_m.mean(axis=0) - x[0]) ** 2))
    assert lik.rms_cost(x)[0] == pytest.approx(expected, rel=1e-12)


def make(position, inputs=None, input_name="pressure_pa", metadata=None):
    n = position.shape[1]
    inputs = np.full(position.shape, 2e5) if inputs is None else inputs
    return Dataset(time_s=np.arange(n) * 1e-3, input=inputs, position_m=position,
                   trial_ids=np.arange(position.shape[0]), input_name=input_name,
                   source="test.csv", metadata=metadata or {})


@pytest.mark.parametrize(
    ("dataset", "model", "match"),
    [
        (make(np.zeros((3, 50))), pb.Model(), "every position is 0.0 m"),
        (make(np.ones((2, 50)) * 0.01, input_name="force_n"), pb.Model(),
         "'force_n' but the model's rig"),
    ],
)
def test_data_that_cannot_be_fitted(dataset, model, match):
    with pytest.raises(LikelihoodError, match=match):
        Likelihood(model, dataset)


def test_factorises_into_deviations_and_mean(lik):
    """total = deviations (model-free, R - 1 series) + trial mean (sqrt(R) g)."""
    x = lik.simulate(pb.Model().theta({"K_e": [600.0, 650.0]}))
    sigma, rho, white = np.array([5e-5, 8e-5]), np.array([0.97, 0.5]), np.array([3e-6, 1e-5])
    total = lik.pointwise(x, sigma, rho, white).sum(axis=1)
    parts = (lik.deviation_log_likelihood(sigma, rho, white)
             + lik.mean_log_likelihood(x, sigma, rho, white))
    assert np.allclose(total, parts, rtol=1e-10)
    # the deviation part is what Helmert contrasts of the trials give, written plainly
    r = lik.n_trials
    helmert = np.array([[1.0] * (j + 1) + [-(j + 1.0)] + [0.0] * (r - j - 2)
                        for j in range(r - 1)])
    helmert /= np.linalg.norm(helmert, axis=1, keepdims=True)
    contrasts = helmert @ lik.dataset.position_m
    expected = sum(brute_force(c, 0.0, 7e-5, 0.9, 5e-6) for c in contrasts)
    assert lik.deviation_log_likelihood(7e-5, 0.9, 5e-6)[0] == pytest.approx(expected,
                                                                             rel=1e-10)


def _periodic_record(steady: bool, n_periods: int = 4, period: int = 100):
    rng = np.random.default_rng(5)
    t = np.arange(n_periods * period) * 1e-3
    u = 2e5 + 1e5 * np.sin(2 * np.pi * t / (period * 1e-3))
    y = 0.01 + 1e-3 * np.sin(2 * np.pi * t / (period * 1e-3)) + 1e-5 * rng.standard_normal(t.size)
    return make(y[None], inputs=u[None],
                metadata={"period_samples": period, "starts_in_steady_state": steady})


@pytest.mark.parametrize(("steady", "n_repeats", "first"), [(True, 4, 0), (False, 3, 1)])
def test_periods_of_a_single_record_are_its_repeats(steady, n_repeats, first):
    """All periods in steady state, periods 2..P from rest (the first holds the transient);
    the model's likelihood is that of the whole record."""
    ds = _periodic_record(steady)
    lik = Likelihood(pb.Model(), ds)
    assert lik.noise_source == "periods" and lik.n_repeats == n_repeats
    segs = ds.position_m[0, first * 100:].reshape(n_repeats, 100)
    r = n_repeats
    helmert = np.array([[1.0] * (j + 1) + [-(j + 1.0)] + [0.0] * (r - j - 2)
                        for j in range(r - 1)])
    helmert /= np.linalg.norm(helmert, axis=1, keepdims=True)
    expected = sum(brute_force(c, 0.0, 2e-5, 0.3, 5e-6) for c in helmert @ segs)
    assert lik.deviation_log_likelihood(2e-5, 0.3, 5e-6)[0] == pytest.approx(expected, rel=1e-10)
    x = np.full((1, ds.n_samples), 0.01)
    whole = brute_force(ds.position_m[0], x[0], 2e-5, 0.3, 5e-6)
    assert lik.log_likelihood(x, 2e-5, 0.3, 5e-6)[0] == pytest.approx(whole, rel=1e-10)
    assert math.isnan(ds.noise_floor_m)


def test_a_record_without_repeats_gets_a_bounded_noise_model():
    """One non-periodic record: no model-free repeats; the disturbance's correlation
    time is bounded far below the input's time scales, and a noise at that bound is
    said to be confounded with slow physics."""
    t = np.arange(2000) * 1e-3
    u = 2e5 + 1e5 * np.sin(2 * np.pi * 2.0 * t)  # 2 Hz
    ds = make((0.01 + 1e-3 * np.sin(2 * np.pi * 2.0 * t))[None], inputs=u[None])
    lik = Likelihood(pb.Model(), ds)
    assert lik.noise_source == "record" and lik.n_repeats == 1
    assert lik.deviation_log_likelihood(1e-5, 0.5, 1e-6)[0] == 0.0
    assert lik.input_frequency_hz == pytest.approx(2.0, abs=0.5)
    tau_flat = 1.0 / (2 * np.pi * 10.0 * lik.input_frequency_hz)
    assert lik.rho_max == lik.rho_flat
    assert lik.rho_flat == pytest.approx(math.exp(-1e-3 / tau_flat), rel=1e-12)
    rho = lik.noise_parameters()[1]
    assert rho.bounds == (-lik.rho_max, lik.rho_max)
    assert np.isneginf(rho.log_prior(np.array([0.99])))[0]
    # a noise at the bound: the verdict says that one record cannot tell it apart
    assert slow_disturbance_note(lik, 0.5) == ""
    note = slow_disturbance_note(lik, lik.rho_max)
    assert f"{tau_flat * 1e3:.2g} ms" in note and "cannot tell" in note
    # with repeats the noise model is unbounded as before
    lik2 = Likelihood(pb.Model(), make(np.vstack([ds.position_m, ds.position_m + 1e-6]),
                                       inputs=np.vstack([u, u])))
    assert lik2.noise_parameters()[1].bounds[1] > 0.999


def test_a_records_declared_or_settled_disturbance_bound_and_its_words():
    """A lab declares its disturbance's correlation time (``disturbance_max_s``), or
    the fit's check (:func:`settle_disturbance`) keeps a slow one; the bound follows,
    and the verdict says which and why."""
    t = np.arange(2000) * 1e-3
    u = 2e5 + 1e5 * np.sin(2 * np.pi * 2.0 * t)
    ds = make((0.01 + 1e-3 * np.sin(2 * np.pi * 2.0 * t))[None], inputs=u[None])
    declared = dataclasses.replace(ds, metadata={**ds.metadata, "disturbance_max_s": 0.2})
    lik = Likelihood(pb.Model(), declared)
    assert lik.rho_max == pytest.approx(math.exp(-1e-3 / 0.2), rel=1e-12)
    assert lik.rho_max > lik.rho_flat
    assert lik.noise_parameters()[1].bounds[1] == lik.rho_max
    assert "disturbance_max_s = 0.2 s" in slow_disturbance_note(lik, lik.rho_max)
    assert slow_disturbance_note(lik, 0.5) == ""
    for bad in (0, -1.0, True, "slow", math.inf):
        with pytest.raises(DataError, match="disturbance_max_s"):
            dataclasses.replace(ds, metadata={**ds.metadata, "disturbance_max_s": bad})
    check = {"bound_s": 0.2, "rms_fast_m": 50e-6, "rms_slow_m": 50.5e-6,
             "ljung_box_p_slow": 0.3, "ratio_allowed": 1.1, "kept": "slow"}
    kept = Likelihood(pb.Model(), dataclasses.replace(ds, metadata={
        **ds.metadata, "disturbance_max_s": 0.2, "disturbance_check": check}))
    note = slow_disturbance_note(kept, 0.99)
    assert "is slow" in note and "50.5 µm against 50 µm" in note
    assert "would look the same on one record" in note
    for change, words in (({"rms_slow_m": 80e-6}, "takes in misfit"),
                          ({"rms_slow_m": None}, "refused"),
                          ({"ljung_box_p_slow": 1e-5}, "left the residual coloured")):
        fast = Likelihood(pb.Model(), dataclasses.replace(ds, metadata={
            **ds.metadata, "disturbance_check": {**check, "kept": "fast", **change}}))
        assert fast.rho_max == fast.rho_flat
        text = slow_disturbance_note(fast, fast.rho_flat)
        assert words in text and "kept fast" in text, text


def test_the_search_cost_of_experiments_apart_is_the_joint_cost_to_the_bit(monkeypatch):
    """The global search's cost of several experiments, their outputs given apart (no
    concatenation), is :meth:`JointLikelihood.rms_cost`'s to the bit, for a record with
    samples not observed and one without; and a sampled noise's filters run in threads
    give the likelihood of one run after another, to the bit."""
    from pmabayes.inference.likelihood import JointLikelihood

    full = generate_chirp_dataset(n_trials=1, seed=5, chirp=CHIRP)
    gappy = generate_chirp_dataset(n_trials=1, seed=6, chirp=CHIRP)
    seen = np.ones(gappy.position_m.shape, dtype=bool)
    seen[:, 100:130] = False
    gappy = Dataset(time_s=gappy.time_s, input=gappy.input,
                    position_m=np.where(seen, gappy.position_m, np.nan),
                    trial_ids=gappy.trial_ids, input_name=gappy.input_name, source="gappy.csv",
                    observed=seen)
    liks = [Likelihood(pb.Model(), ds) for ds in (full, gappy)]
    assert liks[1].observed is not None and liks[0].observed is None
    joint = JointLikelihood(liks, ["full", "gappy"])
    theta = pb.Model().theta({"K_e": np.linspace(550.0, 700.0, 9)})
    xs = [lik.simulate(theta) for lik in liks]
    assert np.array_equal(joint.rms_cost_parts(xs), joint.rms_cost(np.concatenate(xs, axis=1)))
    sigma, rho, white = np.linspace(4e-5, 8e-5, 9), np.linspace(0.5, 0.9, 9), np.full(9, 5e-6)
    monkeypatch.setattr("pmabayes.inference.noise.ar1.simulation_threads", lambda: 1)
    one = liks[1].mean_log_likelihood(xs[1], sigma, rho, white)
    monkeypatch.setattr("pmabayes.inference.noise.ar1.simulation_threads", lambda: 2)
    monkeypatch.setattr("pmabayes.inference.noise.ar1._RUN_WORK", 1)  # threads however short
    assert np.array_equal(liks[1].mean_log_likelihood(xs[1], sigma, rho, white), one)


def test_prior_terms_known_before_give_the_same_log_prior_to_the_bit():
    """The noise's own search evaluates the other columns' prior terms once
    (``Posterior.prior_terms``): its log prior is the one evaluated in full, bit for bit,
    also out of bounds; and the columns it knows are not evaluated again."""
    from pmabayes.inference.posterior import build_posterior

    ds = generate_chirp_dataset(n_trials=1, chirp=Chirp(duration_s=1.0), seed=3)
    posterior = build_posterior(pb.Model(["coulomb_friction"]), ds, substeps=1)
    rng = np.random.default_rng(4)
    box = posterior.plausible_box(rng, posterior.names)
    z = rng.uniform(box[:, 0] - 1.0, box[:, 1] + 1.0, size=(50, posterior.ndim))
    theta = posterior.to_natural(z)
    theta[3, 0] = -1.0  # out of its domain: -inf either way
    cols = list(range(0, posterior.ndim, 2))
    for row in theta:
        row = row[None]
        known = posterior.prior_terms(row, cols)
        assert np.array_equal(posterior.log_prior(row, known=known), posterior.log_prior(row))
    # a known term is used as given, not evaluated again
    inside = posterior.to_natural(box.mean(axis=1)[None])
    shifted = posterior.log_prior(inside, known={0: np.array([123.0])})
    assert np.isfinite(shifted[0]) and shifted[0] != posterior.log_prior(inside)[0]
