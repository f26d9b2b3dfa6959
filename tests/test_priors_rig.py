"""Priors own the support, force rigs' priors follow the data, rig values as priors,
position references and per-experiment offsets, automatic substeps and the periodic
steady state."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.criticism.validation import ValidationError
from pmabayes.data import Dataset
from pmabayes.inference import FitSettings, build_posterior, find_map
from pmabayes.inference.density import Posterior
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.posterior import choose_substeps
from pmabayes.model import (
    BASE_PARAMETERS,
    CARRIAGE_MASS_KG,
    PAPER_AREA_M2,
    PMA_MASS_KG,
    LogNormal,
    Model,
    ModelError,
    Normal,
    Rig,
    SimulationError,
    SteadyStateWarning,
    simulate,
    simulate_dataset,
    warmup_settings,
)
from pmabayes.synthetic import Chirp, generate_chirp_dataset

#: the Bouc-Wen benchmark's oscillator in pmabayes' form (2 kg)
BENCHMARK = {"K_e": 5e4, "d": 10.0, "alpha": 5e4, "beta": 800.0, "gamma": -1100.0}


def _force_dataset(scale: float = 1.0, *, n: int = 3000, rate_hz: float = 750.0,
                   seed: int = 0, noise_m: float = 2e-6) -> Dataset:
    """A force oscillator's record (the benchmark's parameters) with its force and mass
    in units ``scale`` times the newton's reciprocal (0.01: hectonewtons)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    force = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in
                ((60.0, 3.0, 0.0), (25.0, 11.0, 1.0), (15.0, 23.0, 2.0)))
    model = Model(rig=Rig.force_oscillator(2.0))
    x = simulate(model, BENCHMARK, force, time_s=t, substeps=16)[0]
    y = x + noise_m * rng.standard_normal(n)
    rig = Rig.force_oscillator(2.0 * scale)
    values = {k: v * (scale if k in ("K_e", "d", "alpha") else 1.0)
              for k, v in BENCHMARK.items()}
    return Dataset(time_s=t, input=(force * scale)[None], position_m=y[None],
                   trial_ids=np.array([1]), input_name="force_n",
                   metadata={"rig": rig.to_dict(), "truth": values},
                   source=f"oscillator_{scale:g}.csv")


# -- the priors own the support ----------------------------------------------------------

def test_a_prior_beyond_an_old_hidden_bound_is_honoured():
    # d <= 1e5 and K_e <= 1e6 were hard bounds; a prior beyond them is now the support
    model = Model(rig=Rig.force_oscillator(2.0),
                  priors={"d": LogNormal(3e5, 0.5), "K_e": LogNormal(5e6, 0.5)})
    ds = _force_dataset(n=400)
    post = Posterior(Likelihood(model, ds), None)
    theta = np.array([[p.quantile(0.5) for p in post.priors]])
    theta[0, post.names.index("d")] = 2e5
    theta[0, post.names.index("K_e")] = 4e6
    assert np.isfinite(post.log_prior(theta)[0])
    box = post.to_natural(post.plausible_box(np.random.default_rng(0), post.names).T)
    assert box[1, post.names.index("d")] > 1e5 and box[1, post.names.index("K_e")] > 1e6
    assert model.theta({"K_e": 4e6, "d": 2e5}).shape == (1, 5)  # no ModelError


def test_a_prior_outside_the_physical_domain_is_refused():
    with pytest.raises(ModelError, match="alpha.*outside the parameter's physical domain"):
        Model(priors={"alpha": Normal(25.0, 50.0)})
    with pytest.raises(ModelError, match="area_m2.*LogNormal"):
        Rig.from_dict({"moving_mass_kg": 0.1, "area_m2": "Normal(1e-5, 1e-5)"})


@pytest.mark.slow
def test_force_in_newtons_and_hectonewtons_give_the_same_fit():
    nrmse = []
    for scale in (1.0, 0.01):
        ds = _force_dataset(scale)
        post = build_posterior(Model.for_dataset(ds), ds, substeps=8)
        best = find_map(post, rng=np.random.default_rng(3))
        nrmse.append(best.rms_cost_m / float(np.std(ds.mean_position_m)))
    assert nrmse[0] < 0.05  # a real fit, not two equal failures
    assert abs(nrmse[0] - nrmse[1]) <= 0.03 * nrmse[0]


def test_force_rig_default_priors_follow_the_data_and_are_recorded():
    ds, ds_h = _force_dataset(1.0, n=1500), _force_dataset(0.01, n=1500)
    p1, p2 = (build_posterior(Model.for_dataset(d), d, substeps=1) for d in (ds, ds_h))
    a1, a2 = (p.priors[p.names.index("alpha")] for p in (p1, p2))
    assert a2.median == pytest.approx(0.01 * a1.median, rel=1e-6)
    # within a factor of 5 of the truth (the muscle's default is 2000 times too small)
    assert 1e4 < a1.median < 2.5e5
    record = p1.settings_record["data_scaled_priors"]
    assert record["priors"]["alpha"] == str(a1)
    # the muscle's defaults stay the muscle's
    muscle = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=2.0))
    pm = build_posterior(Model.for_dataset(muscle), muscle)
    assert pm.priors[:6] == tuple(p.prior for p in BASE_PARAMETERS)
    assert pm.settings_record["data_scaled_priors"] is None


# -- rig values given as priors ----------------------------------------------------------

def _loads(loads=(0.1, 0.5, 1.0), prior="LogNormal(1e-4, 1.5)", duration_s=6.0):
    out = []
    for k, load in enumerate(loads):
        rig = Rig(CARRIAGE_MASS_KG + PMA_MASS_KG + load, 1.0, PAPER_AREA_M2,
                  name=f"load_{load:g}kg")
        ds = generate_chirp_dataset(n_trials=3, seed=k, chirp=Chirp(duration_s=duration_s),
                                    rig=rig)
        meta = dict(ds.metadata)
        meta["rig"] = {**meta["rig"], "area_m2": prior}
        out.append(dataclasses.replace(ds, metadata=meta, source=f"load_{load:g}kg.csv"))
    return out


def test_a_rig_prior_is_one_parameter_shared_by_the_experiments():
    dss = _loads(duration_s=1.0)
    post = build_posterior(Model(), dss)
    assert post.names.count("rig_area_m2") == 1
    truth = {**dss[0].metadata["generator"]["parameters"], "rig_area_m2": PAPER_AREA_M2}
    theta = np.array([[truth.get(n, p.quantile(0.5))
                       for n, p in zip(post.names, post.priors, strict=True)]])
    x = post.likelihood.split(post.likelihood.simulate(post.full_theta(theta)))
    for xe, lik in zip(x, post.likelihoods, strict=True):
        rig = dataclasses.replace(lik.model.rig, priors=(), area_m2=PAPER_AREA_M2)
        model = Model(rig=rig)
        ref = simulate_dataset(model, {n: truth[n] for n in model.parameter_names},
                               lik.dataset)
        np.testing.assert_allclose(xe, ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(xe[0], lik.dataset.mean_position_m, rtol=0, atol=5e-4)
    # another prior for the same value: another parameter, named after its experiment
    other = _loads(loads=(0.3,), prior="LogNormal(3e-4, 1)", duration_s=1.0)
    post2 = build_posterior(Model(), dss + other)
    assert {"rig_area_m2__load_0_1kg", "rig_area_m2__load_0_3kg"} <= set(post2.names)


def test_a_rig_prior_that_does_not_parse_is_one_clear_error():
    ds = _loads(loads=(0.1,), prior="LogNorm(1e-5, 1.5)", duration_s=1.0)[0]
    with pytest.raises(ModelError) as err:
        Model.for_dataset(ds)
    text = str(err.value)
    assert "\n" not in text
    assert "load_0.1kg.csv" in text and "'area_m2'" in text and "LogNormal(median" in text
    with pytest.raises(ModelError, match="gravity_sign.*must be a number"):
        Rig.from_dict({"moving_mass_kg": 0.1, "gravity_sign": "Normal(1, 1)"})


@pytest.mark.slow
def test_a_rig_prior_is_identified_at_several_loads_and_validated():
    dss = _loads()
    tree = pb.fit(dss, Model(), seed=1,
                  settings=FitSettings(n_walkers=16, n_ensembles=2, max_steps=400))
    area = tree["posterior"]["rig_area_m2"].values.ravel()
    lo, hi = np.quantile(area, [0.05, 0.95])
    assert lo <= PAPER_AREA_M2 <= hi
    assert hi - lo < 0.05 * PAPER_AREA_M2  # identified, not the prior (a factor of 90)
    held_out = _loads(loads=(0.7,), duration_s=3.0)[0]
    val = pb.validate(tree, held_out, n_draws=20)
    assert val.experiments[0].nrmse < 0.05
    other = _loads(loads=(0.7,), prior="LogNormal(2e-4, 1)", duration_s=3.0)[0]
    with pytest.raises(ValidationError, match="no fitted experiment gave that prior"):
        pb.validate(tree, other, n_draws=20)


# -- position references and per-experiment offsets --------------------------------------

def test_position_reference_start_subtracts_the_models_first_position():
    ds = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=1.0))
    model = Model.for_dataset(ds)
    absolute = simulate_dataset(model, None, ds)
    start = dataclasses.replace(ds, metadata={**ds.metadata, "position_reference": "start"})
    relative = simulate_dataset(model, None, start)
    assert relative[0, 0] == 0.0
    np.testing.assert_allclose(relative, absolute - absolute[:, :1], rtol=0, atol=1e-15)
    states = simulate_dataset(model, None, start, states=True)
    np.testing.assert_array_equal(states.position_m, relative)
    bad = dataclasses.replace(ds, metadata={**ds.metadata, "position_reference": "first"},
                              source="zeroed.csv")
    with pytest.raises(SimulationError, match="zeroed.csv.*'start'"):
        Likelihood(model, bad)


def test_offsets_are_per_experiment_in_a_joint_fit():
    dss = []
    for k, offset in enumerate((1e-3, -2e-3)):
        ds = generate_chirp_dataset(n_trials=2, seed=k, chirp=Chirp(duration_s=1.0),
                                    effects={"position_offset": offset})
        dss.append(dataclasses.replace(ds, source=f"zero_{k}.csv"))
    post = build_posterior(Model(["position_offset"]), dss)
    assert "x_offset__zero_0" in post.names and "x_offset__zero_1" in post.names
    assert "x_offset" not in post.names
    theta = np.array([[p.quantile(0.5) for p in post.priors]])
    theta[0, post.names.index("x_offset__zero_0")] = 1e-3
    theta[0, post.names.index("x_offset__zero_1")] = -2e-3
    x = post.likelihood.split(post.likelihood.simulate(post.full_theta(theta)))
    for xe, ds, lik in zip(x, dss, post.likelihoods, strict=True):
        truth = {**dict(zip(post.names, theta[0], strict=False)),
                 "x_offset": ds.metadata["generator"]["parameters"]["x_offset"]}
        ref = simulate_dataset(lik.model, {n: truth[n] for n in lik.model.free_names}, ds)
        np.testing.assert_allclose(xe, ref, rtol=0, atol=1e-15)
    # one experiment keeps the name it always had
    assert "x_offset" in build_posterior(Model(["position_offset"]), dss[0]).names


# -- substeps chosen by the simulator's accuracy check -----------------------------------

def test_substeps_auto_picks_more_for_the_benchmark_oscillator_and_one_for_the_muscle():
    osc = _force_dataset(n=1500)
    model = build_posterior(Model.for_dataset(osc), osc, substeps=1).likelihoods[0].model
    assert choose_substeps([model], [osc])["chosen"] > 1
    muscle = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=5.0))
    post = build_posterior(Model.for_dataset(muscle), muscle, substeps="auto")
    assert post.settings_record["substeps"]["chosen"] == 1
    assert post.likelihoods[0].substeps == 1
    assert build_posterior(Model.for_dataset(osc), osc, substeps=3).likelihoods[0].substeps == 3


# -- the periodic steady state -----------------------------------------------------------

def test_the_steady_state_of_a_10000_sample_period_is_found():
    n = 10_000
    t = np.arange(2 * n) / 1000.0
    u = (2.2e5 + 1.2e5 * np.sin(2 * np.pi * t / 10.0) + 2e4 * np.sin(2 * np.pi * 7 * t / 10.0)
         + 1e4 * np.sin(2 * np.pi * 31 * t / 10.0))
    model = Model()
    with warnings.catch_warnings():
        warnings.simplefilter("error", SteadyStateWarning)
        x = simulate(model, None, u, time_s=t, period_samples=n, steady_state=True,
                     max_warmup_periods=60)
    assert np.max(np.abs(x[0, n:] - x[0, :n])) <= 1e-9
    # period after period from rest needs far more than the 60 periods allowed here
    slow = simulate(model, None, np.tile(u[:n], 60), time_s=np.arange(60 * n) / 1000.0)
    assert np.max(np.abs(slow[0, -n:] - slow[0, -2 * n:-n])) > 1e-9


def test_warmup_settings_come_from_the_sidecar_and_the_caller():
    ds = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=1.0))
    assert warmup_settings(ds) == (1e-9, 256)
    meta = {**ds.metadata, "steady_state_tol_m": 1e-7, "max_warmup_periods": 40}
    declared = dataclasses.replace(ds, metadata=meta, source="warm.csv")
    assert warmup_settings(declared) == (1e-7, 40)
    assert warmup_settings(declared, max_warmup_periods=9) == (1e-7, 9)
    bad = dataclasses.replace(ds, metadata={**ds.metadata, "max_warmup_periods": 2},
                              source="warm.csv")
    with pytest.raises(SimulationError, match="warm.csv: max_warmup_periods"):
        warmup_settings(bad)


@pytest.mark.slow
def test_diagnose_chooses_substeps_and_scales_a_force_rigs_priors_as_fit_does():
    """Fails on the code where diagnose simulated a force rig with one substep and the
    muscle's priors (its settings held ``substeps: 1``)."""
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings

    osc = _force_dataset(n=1500)
    d = diagnose(osc, settings=DiagnoseSettings(candidates=("coulomb_friction",),
                                                discrepancy=False, max_refits=0), seed=0)
    assert d.settings["substeps"] > 1
    scaled = build_posterior(Model.for_dataset(osc), osc).likelihoods[0].model
    assert d.experiments[0].model.priors == scaled.priors
    with pytest.raises(ValueError, match="substeps must be a whole number"):
        DiagnoseSettings(substeps="fine")
