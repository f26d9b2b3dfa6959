"""Real measurements: gaps as missing samples in the likelihood, a record's
segments as experiments of one rig, trials with their own measured inputs, a start
that is estimated (a record that starts mid-loop), and a declared warm-up."""

from __future__ import annotations

import json
import math
from pathlib import Path

import arviz as az
import numpy as np
import pytest

import pmabayes as pb
from pmabayes.data import DataError, Dataset, load_segments
from pmabayes.inference.fitfile import experiment_datasets, fit_info, load_fit
from pmabayes.inference.likelihood import (
    Likelihood,
    LikelihoodError,
    _masked_loglik,
    _noise_loglik,
    choose_noise_model,
    levinson,
)
from pmabayes.inference.posterior import noise_groups
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.model.simulator import SimulationError, simulate_dataset
from pmabayes.synthetic import Chirp, MeasurementNoise, Regulator, generate_chirp_dataset

BASE = ("alpha", "beta", "gamma", "d", "K_e", "p_dz")
TRUE = {k: pb.PAPER_VALUES[k] for k in BASE}
QUICK = FitSettings(n_walkers=24, n_ensembles=2, max_steps=3000, check_every=200)
SHORT = Chirp(duration_s=0.4, f0_hz=1.0, f1_hz=3.0)  # short: the reference is dense
CHIRP = Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=2.0)
#: a disturbance much faster than the inputs
FAST_NOISE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002)


def dense(e: np.ndarray, seen: np.ndarray, sigma: float, rho: float, white: float) -> float:
    """Exact Gaussian log density of the samples ``seen`` of one series ``e`` of AR(1) +
    white noise, from its dense covariance."""
    k = np.arange(e.size)
    cov = sigma**2 * rho ** np.abs(np.subtract.outer(k, k)) + white**2 * np.eye(e.size)
    c = cov[np.ix_(seen, seen)]
    r = e[seen]
    return -0.5 * (r @ np.linalg.solve(c, r) + np.linalg.slogdet(c)[1]
                   + seen.sum() * math.log(2 * math.pi))


def with_mask(ds: Dataset, observed: np.ndarray, **meta) -> Dataset:
    return Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                   trial_ids=ds.trial_ids, metadata={**ds.metadata, **meta},
                   source="gappy.csv", observed=observed)


def held(p: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """The input across gaps as a DAQ's hold makes it (the data layer's default)."""
    k = np.arange(p.size)
    return p[np.maximum.accumulate(np.where(seen, k, 0))]


# ----------------------------------------------------------------------------- gaps


def test_the_masked_filter_is_the_exact_density_of_the_samples_observed():
    rng = np.random.default_rng(1)
    n = 60
    y = rng.normal(size=(3, n))
    x = 0.1 * rng.normal(size=(2, 3, n))
    obs = np.ones((3, n), dtype=bool)
    obs[0, 10:20] = obs[1, 5] = False
    obs[2, 40:-1] = False
    sigma, rho, white = np.array([2.0, 2.2]), np.array([0.9, 0.9]), np.array([0.5, 0.5])
    out = _masked_loglik(y, x, 1.0, sigma, rho, white, obs)
    for b in range(2):
        for m in range(3):
            assert out[b, m] == pytest.approx(dense(y[m] - x[b, m], obs[m], sigma[b], rho[b],
                                                    white[b]), rel=1e-12)
    # one noise for the batch (the sampler's case): the same numbers
    same = _masked_loglik(y, x, 1.0, sigma[:1].repeat(2), rho, white, obs)
    assert same[0] == pytest.approx(out[0], rel=1e-13)
    # every sample observed: the filter of complete data
    full = _masked_loglik(y, x[:, :1], 1.0, sigma, rho, white, np.ones((1, n), dtype=bool))
    np.testing.assert_allclose(full, _noise_loglik(y, np.ascontiguousarray(x[:, 0]), 1.0,
                                                   sigma, rho, white), rtol=1e-13)


def test_samples_not_observed_are_missing_in_the_likelihood_not_invented():
    ds = generate_chirp_dataset(n_trials=3, seed=3, chirp=Chirp(duration_s=0.2, f0_hz=1.0,
                                                                f1_hz=3.0))
    n = ds.n_samples
    common = np.ones((3, n), dtype=bool)
    common[:, 100:130] = False
    gappy = with_mask(ds, common)
    lik = Likelihood(pb.Model(), gappy)
    assert lik.observed is not None and not lik.per_trial and lik.noise_source == "trials"
    x = lik.simulate(pb.Model().theta({"K_e": [600.0, 650.0]}))
    noise = (np.array([5e-5, 8e-5]), np.array([0.97, 0.5]), np.array([3e-6, 1e-5]))
    each = np.array([[dense(ds.position_m[r] - x[b], common[r], *(v[b] for v in noise))
                      for r in range(3)] for b in range(2)])
    # each trial's own density, and the trial mean and contrasts still split it exactly
    np.testing.assert_allclose(lik.pointwise(x, *noise), each, rtol=1e-10)
    np.testing.assert_allclose(lik.log_likelihood(x, *noise), each.sum(axis=1), rtol=1e-10)
    np.testing.assert_allclose(lik.deviation_log_likelihood(*noise)
                               + lik.mean_log_likelihood(x, *noise), each.sum(axis=1),
                               rtol=1e-10)
    # the cost over the samples observed; the innovations NaN where nothing is
    mean = ds.position_m.mean(axis=0)
    seen = common[0]
    assert lik.rms_cost(x)[0] == pytest.approx(
        np.sqrt(np.mean((mean - x[0])[seen] ** 2)), rel=1e-12)
    innov = lik.innovations(x[0], 5e-5, 0.9, 3e-6)
    assert np.isnan(innov[~seen]).all() and np.isfinite(innov[seen]).all()
    # trials observed at different samples: the sum of each trial's likelihood
    own = common.copy()
    own[1, 100:130] = True
    own[2, 150:155] = False
    lik2 = Likelihood(pb.Model(), with_mask(ds, own))
    assert lik2.per_trial
    each2 = np.array([[dense(ds.position_m[r] - x[b], own[r], *(v[b] for v in noise))
                       for r in range(3)] for b in range(2)])
    np.testing.assert_allclose(lik2.log_likelihood(x, *noise), each2.sum(axis=1), rtol=1e-10)


def test_the_repeats_ar_model_falls_back_to_ar1_with_gaps():
    ds = generate_chirp_dataset(n_trials=3, seed=4, chirp=SHORT)
    observed = np.ones(ds.position_m.shape, dtype=bool)
    observed[:, 50:60] = False
    lik = Likelihood(pb.Model(), with_mask(ds, observed))
    choice = choose_noise_model(lik, 5e-5, 0.9, 3e-6, "ar")
    assert choice.ar is None and "10 samples" not in choice.note and "30 samples" in choice.note
    assert choice.describe().startswith("AR(1) + white: 30 samples are not observed")
    from pmabayes.inference.likelihood import ArNoise

    phi, var = levinson(np.array([1.0, 0.5]), 1)
    with pytest.raises(LikelihoodError, match="AR\\(1\\) \\+ white as the noise model"):
        lik.use_ar_noise(ArNoise(np.array([1.0, 0.5])))
    assert var[1] > 0 and phi.shape == (2, 1)


def test_a_warm_up_is_left_out_of_the_likelihood_but_drives_the_simulation():
    ds = generate_chirp_dataset(n_trials=2, seed=5, chirp=SHORT)
    warm = Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                   trial_ids=ds.trial_ids, metadata={**ds.metadata, "warmup_s": 0.05})
    lik, lik_w = Likelihood(pb.Model(), ds), Likelihood(pb.Model(), warm)
    x = lik.simulate(pb.Model().theta())
    np.testing.assert_array_equal(lik_w.simulate(pb.Model().theta()), x)
    k = int(np.sum(ds.time_s - ds.time_s[0] < 0.05))
    assert k == 50 and int((~lik_w.observed).sum()) == 2 * k
    noise = (5e-5, 0.9, 3e-6)
    seen = np.arange(ds.n_samples) >= k
    expected = sum(dense(ds.position_m[r] - x[0], seen, *noise) for r in range(2))
    assert lik_w.log_likelihood(x, *noise)[0] == pytest.approx(expected, rel=1e-10)
    # the positions in the warm-up do not count
    moved = ds.position_m.copy()
    moved[:, :k] += 1e-3
    warm2 = Dataset(time_s=ds.time_s, input=ds.input, position_m=moved, trial_ids=ds.trial_ids,
                    metadata=warm.metadata)
    assert Likelihood(pb.Model(), warm2).log_likelihood(x, *noise)[0] == pytest.approx(
        expected, rel=1e-12)
    with pytest.raises(DataError, match="'warmup_s' is 0.4 s but the record is only 0.399 s"):
        Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                trial_ids=ds.trial_ids, metadata={"warmup_s": 0.4})
    with pytest.raises(DataError, match="'warmup_s' is -1; it must be a number of seconds"):
        Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                trial_ids=ds.trial_ids, metadata={"warmup_s": -1})


@pytest.mark.slow
def test_a_record_with_gaps_gives_the_gap_free_posterior_to_within_what_is_lost():
    """3 trials of a 3 s chirp, 5% of the samples removed (30 ms gaps every 0.5 s, as a
    DAQ that pauses between blocks); the input is held across the gaps in both."""
    t = CHIRP.time_s
    k = np.arange(t.size)
    seen = ~((k % 500 >= 470) & (k < t.size - 30))
    p = held(CHIRP.pressure_pa(t), seen)
    x = pb.simulate(pb.Model(), None, p, time_s=t)[0]
    y = MeasurementNoise().apply(np.repeat(x[None], 3, axis=0), 1e-3,
                                 np.random.default_rng(11))
    full = Dataset(time_s=t, input=np.tile(p, (3, 1)), position_m=y, trial_ids=np.arange(3),
                   source="full.csv")
    gappy = with_mask(full, np.tile(seen, (3, 1)))
    fits = [fit(d, pb.Model(), seed=1, settings=QUICK) for d in (full, gappy)]
    info = fit_info(fits[1])
    assert info["convergence"]["converged"]
    assert info["experiments"][0]["missing_samples"]["left_out_of_likelihood"] == 450
    assert experiment_datasets(fits[1])[0] == with_mask(gappy, gappy.observed)
    hdi = az.hdi(fits[1], prob=0.99)
    print("\ngaps (5% of samples missing) against the gap-free record, per parameter: "
          "shift of the posterior mean / its sd, sd ratio: " + ", ".join(
              f"{n} {(f1 - f0) / s0:+.2f} {s1 / s0:.3f}" for n, f0, s0, f1, s1 in (
                  (n, *(v for f in fits for v in (f["posterior"][n].values.mean(),
                                                  f["posterior"][n].values.std())))
                  for n in BASE)))
    for name in BASE:
        a, b = (f["posterior"][name].values for f in fits)
        lo, hi = hdi[name].values
        assert lo <= TRUE[name] <= hi, name
        # 5% of the samples lost: the same posterior, its spread a few % wider at most
        assert abs(b.mean() - a.mean()) < 0.3 * a.std(), name
        assert 0.9 < b.std() / a.std() < 1.15, name


# ----------------------------------------------------------------------------- segments


def test_the_segments_of_one_record_share_their_noise_by_default():
    def seg(source, name):
        return Dataset(time_s=np.arange(3) * 1e-3, input=np.full((1, 3), 2e5),
                       position_m=np.array([[0.0, 1e-3, 2e-3]]), trial_ids=np.arange(1),
                       metadata={"segment": {"name": name}}, source=source)

    a1, a2 = seg("d/a#1.csv", "a#1"), seg("d/a#2.csv", "a#2")
    b = Dataset(time_s=np.arange(3) * 1e-3, input=np.full((1, 3), 2e5),
                position_m=np.array([[0.0, 1e-3, 2e-3]]), trial_ids=np.arange(1),
                source="d/b.csv")
    c1 = seg("e/a#1.csv", "a#1")  # another folder's record of the same name
    assert noise_groups([a1, b, a2, c1]) == [0, 1, 0, 2]
    assert noise_groups([a1, b, a2, c1], tie_segments=False) == [0, 1, 2, 3]
    assert noise_groups([a1, b, a2, c1], tie_noise=True) == [0, 0, 0, 0]


def segment_file(folder: Path, *, n_trials: int = 3, seed: int = 21) -> tuple[Path, dict]:
    """Trials of one record at 500 Hz with a 0.5 s pause in the DAQ (a new segment at
    ``max_gap_s`` = 0.3 s): the second segment starts mid-loop. Returns the file and the
    true state at each segment's start."""
    rate = 500.0
    t = np.arange(int(5.0 * rate)) / rate
    p = 0.2e6 * (1 - np.cos(2 * np.pi * 0.6 * t)) + 0.04e6 * np.sin(2 * np.pi * 1.7 * t) ** 2
    sim = pb.simulate(pb.Model(), None, p, time_s=t, states=True)
    y = FAST_NOISE.apply(np.repeat(sim.position_m, n_trials, axis=0), 1 / rate,
                         np.random.default_rng(seed))
    keep = (t < 2.0) | (t >= 2.5)
    rows = ["trial,time_s,pressure_pa,position_m"]
    rows += [f"{r + 1},{t[j]:.4f},{p[j]:.3f},{y[r, j]:.9f}" for r in range(n_trials)
             for j in np.flatnonzero(keep)]
    path = folder / "rec.csv"
    path.write_text("\n".join(rows) + "\n")
    path.with_suffix(".json").write_text(json.dumps({"max_gap_s": 0.3,
                                                     "initial_state": "estimate"}))
    j2 = int(np.flatnonzero(t >= 2.5)[0])
    starts = {"rec_1": (sim.position_m[0, 0], 0.0), "rec_2": (sim.true_position_m[0, j2],
                                                             sim.velocity_m_s[0, j2])}
    return path, starts


@pytest.mark.slow
def test_a_record_that_splits_into_segments_is_fitted_as_experiments_of_one_rig(tmp_path,
                                                                                 capsys):
    from pmabayes.cli import main

    path, starts = segment_file(tmp_path)
    with pytest.warns(pb.data.DataWarning, match="split the record into 2 segments"):
        assert len(load_segments(path)) == 2
    out = tmp_path / "fit.nc"
    assert main(["fit", str(path), "--out", str(out), "--walkers", "32", "--steps", "3000",
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "splits into 2 segments at gaps longer than its max_gap_s = 0.3 s" in text
    assert "each is an experiment of the same rig, from its own start" in text
    tree = load_fit(out)
    info = fit_info(tree)
    assert [e["name"] for e in info["experiments"]] == ["rec_1", "rec_2"]
    assert [e["noise"] for e in info["experiments"]] == ["tied", "tied"]
    post = tree["posterior"]
    for name in BASE:
        lo, hi = np.quantile(post[name].values, [0.005, 0.995])
        assert lo <= TRUE[name] <= hi, name
    # each segment from its own start: the second mid-loop, found to within the noise
    for seg, (x0, v0) in starts.items():
        assert "start" in info["experiments"][[e["name"] for e in info["experiments"]]
                                              .index(seg)]
        x = post[f"x0_m__{seg}"].values
        assert abs(x.mean() - x0) < 4 * x.std() + 2e-6, seg
        v = post[f"v0_m_s__{seg}"].values
        assert abs(v.mean() - v0) < 4 * v.std(), seg
    assert abs(starts["rec_2"][1]) > 0.05  # it is mid-loop: moving


# ----------------------------------------------------------------------------- own inputs


def test_trials_with_their_own_inputs_are_each_simulated_on_their_own():
    ds = generate_chirp_dataset(n_trials=3, seed=6, chirp=SHORT, regulator=Regulator())
    assert not np.all(ds.input == ds.input[0])
    lik = Likelihood(pb.Model(), ds)
    assert lik.own_inputs and lik.per_trial and lik.refers_to_model
    assert lik.n_outputs == 3 * ds.n_samples
    theta = pb.Model().theta({"K_e": [600.0, 650.0]})
    x = lik.simulate(theta)
    assert x.shape == (2, 3 * ds.n_samples)
    noise = (np.array([5e-5, 8e-5]), np.array([0.97, 0.5]), np.array([3e-6, 1e-5]))
    total = np.zeros(2)
    for r in range(3):
        one = ds.select_trials([r])
        lik_r = Likelihood(pb.Model(), one)
        x_r = lik_r.simulate(theta)
        np.testing.assert_array_equal(x[:, r * ds.n_samples:(r + 1) * ds.n_samples], x_r)
        total += lik_r.log_likelihood(x_r, *noise)
    np.testing.assert_allclose(lik.log_likelihood(x, *noise), total, rtol=1e-12)
    np.testing.assert_allclose(lik.mean_log_likelihood(x, *noise), total, rtol=1e-12)


def test_trials_referred_to_the_model_leave_the_noise_alone():
    """Referred to the model's output on each trial's own input, the trials' contrasts
    are those of the drawn noise: the response to the inputs' differences cancels."""
    chirp = Chirp(duration_s=1.0, f0_hz=0.5, f1_hz=2.0)
    noisy = generate_chirp_dataset(n_trials=4, seed=7, chirp=chirp, regulator=Regulator())
    clean = generate_chirp_dataset(n_trials=4, seed=7, chirp=chirp, regulator=Regulator(),
                                   noise=None)
    lik = Likelihood(pb.Model(), noisy)
    raw = lik.contrasts.copy()
    noise = noisy.position_m - clean.position_m
    lik.refer_periods_to(clean.position_m.reshape(-1))
    assert lik.trials_referred
    helmert = Likelihood(pb.Model(), Dataset(time_s=noisy.time_s, input=np.tile(
        noisy.input[0], (4, 1)), position_m=noise, trial_ids=noisy.trial_ids)).contrasts
    np.testing.assert_allclose(lik.contrasts, helmert, atol=1e-15)
    floor = math.sqrt(np.mean(noise.var(axis=0, ddof=1)) / 4)
    assert lik.referred_noise_floor_m == pytest.approx(floor, rel=1e-9)
    # the raw trials hold the model's response to the inputs' differences too
    assert np.std(raw) > 1.5 * np.std(lik.contrasts)
    assert lik.referred_trials().position_m == pytest.approx(noise, abs=1e-15)


@pytest.mark.slow
def test_trials_with_measured_inputs_are_identified_and_their_noise_floor_found():
    ds = generate_chirp_dataset(n_trials=4, seed=11, chirp=CHIRP, regulator=Regulator())
    clean = generate_chirp_dataset(n_trials=4, seed=11, chirp=CHIRP, regulator=Regulator(),
                                   noise=None)
    e = ds.position_m - clean.position_m
    drawn = math.sqrt(np.mean(e.var(axis=0, ddof=1)) / 4)
    tree = fit(ds, pb.Model(), seed=1, settings=QUICK)
    info = fit_info(tree)
    exp = info["experiments"][0]
    assert info["convergence"]["converged"]
    assert exp["own_inputs"] and exp["trials_referred_to_model"]
    # the floor of the trials' residuals at the MAP is the drawn noise's; the raw
    # trials' is not (it holds the model's response to the inputs' differences)
    print(f"\nmeasured inputs: noise floor of the trials' residuals at the MAP "
          f"{exp['noise_floor_m'] * 1e6:.1f} um, of the drawn noise {drawn * 1e6:.1f} um, of "
          f"the raw trials {exp['noise_floor_of_raw_trials_m'] * 1e6:.1f} um")
    assert exp["noise_floor_m"] == pytest.approx(drawn, rel=0.15)
    assert exp["noise_floor_of_raw_trials_m"] > 2 * drawn
    assert "measured input" in info["noise"]["estimated_from"]
    hdi = az.hdi(tree, prob=0.99)
    for name in BASE:
        lo, hi = hdi[name].values
        assert lo <= TRUE[name] <= hi, name
    back = experiment_datasets(tree)[0]
    np.testing.assert_array_equal(back.input, ds.input)
    assert tree["posterior_predictive"]["model_position_m"].dims == ("chain", "draw",
                                                                     "trial", "time")


# ----------------------------------------------------------------------------- starts


def test_the_simulator_starts_from_given_states():
    t = np.arange(3000) / 1000.0
    u = 0.1e6 + 0.2e6 * (1 - np.cos(2 * np.pi * t))
    model = pb.Model()
    sim = pb.simulate(model, None, u, time_s=t, states=True)
    k = 1500
    # from the balance of forces at the true position and velocity, offset to the true z
    at = pb.simulate(model, None, u[k:], time_s=t[k:], initial_state="estimate",
                     initial_values=[sim.true_position_m[0, k], sim.velocity_m_s[0, k], 0.0],
                     states=True)
    offset = sim.hysteresis_n[0, k] - at.hysteresis_n[0, 0]
    assert abs(offset) < 1.0  # the balance is near the state mid-loop
    again = pb.simulate(model, None, u[k:], time_s=t[k:], initial_state="estimate",
                        initial_values=[sim.true_position_m[0, k], sim.velocity_m_s[0, k],
                                        offset])
    np.testing.assert_allclose(again[0], sim.position_m[0, k:], atol=1e-12)
    # a batch, each its own start; the rest state given is the rest start
    both = pb.simulate(model, model.theta({"K_e": [600.0, 650.0]}), u, time_s=t,
                       initial_state="estimate",
                       initial_values=[[0.0, 0.0, 0.0], [sim.position_m[0, 0], 0.0, 0.0]])
    assert both[0, 0] == 0.0 and both[1, 0] == sim.position_m[0, 0]
    with pytest.raises(SimulationError, match="needs initial_values"):
        pb.simulate(model, None, u, time_s=t, initial_state="estimate")
    with pytest.raises(SimulationError, match="leave them out"):
        pb.simulate(model, None, u, time_s=t, initial_values=[0.0, 0.0, 0.0])
    with pytest.raises(DataError, match="'estimate' but 'starts_in_steady_state' is true"):
        Dataset(time_s=t[:100], input=u[None, :100], position_m=u[None, :100] * 1e-7,
                trial_ids=np.arange(1), metadata={"initial_state": "estimate",
                                                  "period_samples": 50,
                                                  "starts_in_steady_state": True})


def test_an_estimated_start_has_priors_from_the_first_samples():
    t = np.arange(1000) / 500.0
    u = 0.2e6 * (1 - np.cos(2 * np.pi * 0.8 * t))
    x = pb.simulate(pb.Model(), None, u, time_s=t)[0]
    y = FAST_NOISE.apply(np.repeat(x[None, 400:], 2, axis=0), 1 / 500.0,
                         np.random.default_rng(2))
    ds = Dataset(time_s=t[400:], input=np.tile(u[400:], (2, 1)), position_m=y,
                 trial_ids=np.arange(2), metadata={"initial_state": "estimate"})
    lik = Likelihood(pb.Model(), ds)
    x0, v0, dz = lik.start_parameters()
    assert [p.name for p in (x0, v0, dz)] == ["x0_m", "v0_m_s", "z0_offset_n"]
    slope = (x[402] - x[398]) / (4 / 500.0)
    assert abs(x0.prior.mu - x[400]) < 3 * x0.prior.sigma and x0.prior.sigma < 1e-4
    assert abs(v0.prior.mu - slope) < 0.2 * abs(slope)
    assert dz.prior.mu == 0.0 and dz.prior.sigma == pytest.approx(
        pb.Model().rig.area_m2 * np.ptp(u[400:]))
    # simulated from the prior means unless a start is given
    np.testing.assert_array_equal(lik.simulate(pb.Model().theta()),
                                  simulate_dataset(pb.Model(), None, ds,
                                                   initial_values=lik.start_defaults()[None]))


@pytest.mark.slow
def test_an_estimated_start_recovers_a_record_that_starts_mid_loop():
    """Fit the first 70% of a record; its last 30%, which starts mid-loop, held out: an
    estimated start is off at t = 0 by about the noise, a start from rest by mm."""
    from pmabayes.criticism.validation import validate

    rate = 500.0
    t = np.arange(int(8 * rate)) / rate
    p = 0.2e6 * (1 - np.cos(2 * np.pi * 0.5 * t)) + 0.05e6 * np.sin(2 * np.pi * 1.3 * t) ** 2
    sim = pb.simulate(pb.Model(), None, p, time_s=t, states=True)
    x = sim.position_m[0]
    y = FAST_NOISE.apply(np.repeat(x[None], 3, axis=0), 1 / rate, np.random.default_rng(3))
    cut = int(0.7 * t.size)

    def part(sl, source, **meta):
        return Dataset(time_s=t[sl], input=np.tile(p[sl], (3, 1)), position_m=y[:, sl],
                       trial_ids=np.arange(3), metadata={"sample_rate_hz": rate, **meta},
                       source=source)

    head = part(slice(None, cut), "head.csv")
    tail_estimate = part(slice(cut, None), "tail.csv", initial_state="estimate")
    tail_rest = part(slice(cut, None), "tail_rest.csv")
    tree = fit(head, pb.Model(), seed=1, settings=QUICK)
    noise_of_mean = 20e-6 / math.sqrt(3)
    est, rest = (validate(tree, d, n_draws=100).experiments[0]
                 for d in (tail_estimate, tail_rest))
    print(f"\nheld-out last 30% (mid-loop): error at t = 0 with an estimated start "
          f"{abs(est.prediction_m[0] - x[cut]) * 1e6:.1f} um, from rest "
          f"{abs(rest.prediction_m[0] - x[cut]) * 1e6:.0f} um (noise of the mean "
          f"{noise_of_mean * 1e6:.1f} um); RMSE {est.rmse_m * 1e6:.1f} um against "
          f"{rest.rmse_m * 1e6:.0f} um")
    assert abs(est.prediction_m[0] - x[cut]) < 2 * noise_of_mean
    assert abs(rest.prediction_m[0] - x[cut]) > 1e-3
    assert est.start["samples"] == round(0.05 * t[cut:].size) and est.start["fraction"] == 0.05
    assert est.to_dict()["start"]["rmse_after_start_m"] < 2 * noise_of_mean
    assert any("start was estimated" in n for n in est.notes)
    # the start as parameters of a fit of the held-out part itself
    tail = fit(tail_estimate, pb.Model(), seed=1, settings=QUICK)
    post = tail["posterior"]
    truth = {"x0_m": sim.true_position_m[0, cut], "v0_m_s": sim.velocity_m_s[0, cut]}
    for name, value in truth.items():
        lo, hi = np.quantile(post[name].values, [0.005, 0.995])
        assert lo <= value <= hi, name
    for name in BASE:
        lo, hi = np.quantile(post[name].values, [0.005, 0.995])
        assert lo <= TRUE[name] <= hi, name
