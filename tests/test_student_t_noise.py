"""Student-t white noise, the noise model that is one file (pmabayes/inference/noise/student_t.py):
its density, its selection by name, and a fit of a record with outliers."""

import numpy as np
import pytest
from scipy import special, stats

import pmabayes as pb
from pmabayes.data import Dataset
from pmabayes.inference.fitfile import fit_info, fit_noise_models, load_fit, save_fit
from pmabayes.inference.likelihood import Likelihood, check_noise_model_name
from pmabayes.inference.noise import (
    AR1_WHITE,
    NoiseModel,
    StudentT,
    group_noise,
    noise_model_class,
    register_noise_model,
)
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

CHIRP = Chirp(duration_s=1.0, f0_hz=0.5, f1_hz=2.0)
#: white noise only (no disturbance): the outliers are what departs from a Gaussian
WHITE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=1e-4,
                         encoder_counts_per_m=None)
FREE = ("K_e", "d")


def with_outliers(seed: int, n_trials: int = 1):
    """A short chirp record with 2% of its samples 2 mm off (a sensor's spikes)."""
    ds = generate_chirp_dataset(n_trials=n_trials, seed=seed, chirp=CHIRP, noise=WHITE)
    rng = np.random.default_rng(seed + 100)
    y = ds.position_m.copy()
    hit = rng.random(y.shape) < 0.02
    y[hit] += rng.choice([-2e-3, 2e-3], size=int(hit.sum()))
    return Dataset(time_s=ds.time_s, input=ds.input, position_m=y, trial_ids=ds.trial_ids,
                   input_name=ds.input_name, source=f"outliers-{seed}",
                   metadata=dict(ds.metadata))


def test_the_density_is_scipys_and_takes_samples_not_observed():
    ds = generate_chirp_dataset(n_trials=3, seed=2, chirp=CHIRP, noise=WHITE)
    lik = Likelihood(pb.Model(), ds)
    lik.use_noise(StudentT())
    assert lik.per_trial and lik.noise_parameters()[1].name == "nu_t"
    x = lik.simulate(pb.Model().theta())
    sigma, nu = np.array([3e-5, 5e-5]), np.array([3.0, 40.0])
    got = lik.pointwise(np.repeat(x, 2, axis=0), sigma, nu)
    want = np.array([[stats.t.logpdf(ds.position_m[r] - x[0], nu[b], scale=sigma[b]).sum()
                      for r in range(3)] for b in range(2)])
    np.testing.assert_allclose(got, want, rtol=1e-12)
    np.testing.assert_allclose(lik.log_likelihood(np.repeat(x, 2, axis=0), sigma, nu),
                               want.sum(axis=1), rtol=1e-12)
    # a stretch left out is its samples' own density: the noise is independent
    one = Likelihood(pb.Model(), generate_chirp_dataset(n_trials=1, seed=3, chirp=CHIRP))
    one.use_noise(StudentT())
    x1 = one.simulate(pb.Model().theta())
    parts = one.stretch_pointwise(x1, 4e-5, 5.0, 4)
    e = one.dataset.position_m[0] - x1[0]
    edges = np.linspace(0, e.size, 5).astype(int)
    expected = [stats.t.logpdf(e[a:b], 5.0, scale=4e-5).sum()
                for a, b in zip(edges[:-1], edges[1:], strict=True)]
    np.testing.assert_allclose(parts[0], expected, rtol=1e-9)
    # whitening is the probability integral transform: standard normal for t noise
    draws = StudentT().draw(1, 20000, (4e-5, 4.0), np.random.default_rng(0))[0]
    w = StudentT().whiten(draws, 1.0, (4e-5, 4.0))
    assert abs(np.mean(w)) < 0.03 and abs(np.std(w) - 1.0) < 0.03


def test_student_t_is_selected_by_name_and_sampled_with_the_model():
    assert check_noise_model_name("student_t") == "student_t"
    assert noise_model_class("student_t") is StudentT
    lik = Likelihood(pb.Model(), generate_chirp_dataset(n_trials=3, seed=4, chirp=CHIRP))
    est, choice = group_noise([lik], "student_t")
    # not learnt from the repeats: its parameters are the posterior's own columns
    assert est is None and isinstance(lik.noise, StudentT)
    assert choice.to_dict()["noise_model"] == "student_t"
    assert "Student-t" in choice.describe()
    with pytest.raises(ValueError, match="already registered"):
        @register_noise_model
        class Other(NoiseModel):  # noqa: F841  (a second model of the same name)
            name = "student_t"
    assert AR1_WHITE.to_dict() == {}  # the default adds nothing to old fit files


def test_a_record_with_outliers_is_predicted_better_and_the_fit_file_round_trips(tmp_path):
    """Held-out log predictive density of a second record with outliers: Student-t
    beats AR(1) + white, whose white part must swell to take the spikes in; and the
    fit file keeps the model (saved, loaded, rebuilt)."""
    train, held = with_outliers(seed=31), with_outliers(seed=32)
    truth = pb.Model().defaults
    model = pb.Model(fixed={n: v for n, v in truth.items() if n not in FREE})
    settings = dict(n_walkers=12, n_ensembles=1, max_steps=300, check_every=100,
                    substeps=1, ppc_draws=10)
    scores, medians = {}, {}
    for name in ("ar1", "student_t"):
        tree = fit(train, model, seed=5, settings=FitSettings(**settings, noise_model=name))
        path = save_fit(tree, tmp_path / f"{name}.nc")
        back = load_fit(path)
        (noise,) = fit_noise_models(back)
        assert noise.name == name
        assert fit_info(back)["experiments"][0]["noise_model"]["requested"] == name
        post = back["posterior"]
        lik = Likelihood(model, held)
        lik.use_noise(noise)
        draws = np.stack([post[n].values.reshape(-1) for n in FREE], axis=1)[::10]
        noise_draws = [post[p.name].values.reshape(-1)[::10] for p in lik.noise_parameters()]
        theta = model.theta(dict(zip(FREE, draws.T, strict=True)))
        ll = lik.pointwise(lik.simulate(theta), *noise_draws)
        scores[name] = float(special.logsumexp(ll[:, 0]) - np.log(ll.shape[0]))
        medians[name] = {n: float(np.median(post[n].values)) for n in FREE}
    print("held-out log predictive density:", scores, "medians:", medians)
    assert scores["student_t"] > scores["ar1"] + 100.0, scores
    # the robust fit recovers the stiffness at least as well
    err = {k: abs(m["K_e"] - truth["K_e"]) for k, m in medians.items()}
    assert err["student_t"] <= err["ar1"] * 1.05 + 1.0, (medians, truth["K_e"])
