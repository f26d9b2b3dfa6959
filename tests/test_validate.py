"""Validation on held-out experiments (``pmabayes.criticism.validation``, ``pmabayes validate``).

The held-out data are made here from one plant (the paper's values) with the
synthetic generator's measurement (AR(1) disturbance and encoder quantisation):
steps and sines, on the characterisation rig and on the loaded control rig. The
fast tests validate a fit-like tree (``conftest.fake_fit``) whose posterior is
tight around the plant's values and whose noise posterior is the generator's
noise; the slow test fits a chirp for real first.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from conftest import fake_fit

from pmabayes.cli import main
from pmabayes.criticism.validation import ValidationError, validate
from pmabayes.data import Dataset, DataWarning, save
from pmabayes.model.model import Model, Rig
from pmabayes.model.simulator import simulate
from pmabayes.synthetic import MeasurementNoise, generate_chirp_dataset, hidden_effects_model

RATE_HZ = 1000.0
NOISE = MeasurementNoise()  # 60 um, 0.1 s, the paper's encoder
RHO = math.exp(-1.0 / RATE_HZ / NOISE.disturbance_corr_time_s)
WHITE_M = 1.0 / NOISE.encoder_counts_per_m / math.sqrt(12.0)  # quantisation


def steps_pa(duration_s: float = 8.0) -> np.ndarray:
    t = np.arange(int(duration_s * RATE_HZ)) / RATE_HZ
    levels = np.array([0.0, 0.15e6, 0.4e6, 0.25e6, 0.1e6, 0.45e6, 0.3e6, 0.05e6])
    return levels[np.minimum((t / (duration_s / levels.size)).astype(int), levels.size - 1)]


def sine_pa(freq_hz: float = 1.0, duration_s: float = 8.0) -> np.ndarray:
    t = np.arange(int(duration_s * RATE_HZ)) / RATE_HZ
    return 0.3e6 + 0.15e6 * np.sin(2 * np.pi * freq_hz * t)


def held_out(pressure: np.ndarray, *, n_trials: int = 5, seed: int = 1, rig: Rig | None = None,
             effects: dict | None = None, source: str | None = None,
             input_name: str = "pressure_pa", rate_hz: float = RATE_HZ) -> Dataset:
    """Trials of one input from the plant (plus hidden effects), measured like the generator."""
    model, values = hidden_effects_model(effects, rig=rig)
    t = np.arange(pressure.size) / rate_hz
    x = simulate(model, values, pressure, time_s=t)[0]
    y = NOISE.apply(np.repeat(x[None], n_trials, axis=0), 1.0 / rate_hz,
                    np.random.default_rng(seed))
    return Dataset(time_s=t, input=np.repeat(pressure[None], n_trials, axis=0), position_m=y,
                   trial_ids=np.arange(n_trials), input_name=input_name,
                   metadata={"synthetic": True, "rig": model.rig.to_dict(),
                             "sample_rate_hz": rate_hz},
                   source=source)


def plant_fit(effects=(), values=None, spread: float = 2e-4, seed: int = 0, n_time: int = 400,
              **kw):
    """A fit-like tree tight around the plant's values, with the generator's noise."""
    model = Model(list(effects))
    centre = {**model.defaults, **(values or {})}
    params = {n: (model.parameter(n).unit, v, spread * abs(v))
              for n, v in centre.items() if n in model.free_names}
    params["sigma_noise_m"] = ("m", NOISE.disturbance_std_m, 0.03 * NOISE.disturbance_std_m)
    params["rho_noise"] = ("1", RHO, 1e-4)
    params["sigma_white_m"] = ("m", WHITE_M, 0.03 * WHITE_M)
    return fake_fit(params=params, effects=effects, n_chain=8, n_draw=60, n_time=n_time,
                    dt_s=1.0 / RATE_HZ, seed=seed, **kw)


@pytest.fixture(scope="module")
def fit_tree():
    return plant_fit()


@pytest.fixture(scope="module")
def held_out_sets():
    return [held_out(steps_pa(), source="steps.csv", seed=11),
            held_out(sine_pa(1.0), source="sine_1hz.csv", seed=12),
            held_out(sine_pa(0.5), source="sine_loaded.csv", seed=13, rig=Rig.control())]


def test_right_model_covers_near_90_and_sits_at_the_floor(fit_tree, held_out_sets):
    v = validate(fit_tree, held_out_sets, n_draws=200, seed=0)
    assert [e.name for e in v.experiments] == ["steps", "sine_1hz", "sine_loaded"]
    for e in v.experiments:
        assert 0.8 <= e.band_coverage <= 0.97, (e.name, e.band_coverage)
        assert e.noise_floor_m is not None
        assert e.rmse_m < 1.5 * e.noise_floor_m, (e.name, e.rmse_m, e.noise_floor_m)
        assert 0 < e.nrmse < 0.05
        # the error per band (spectral) adds up to the overall error, each near its floor
        assert e.band_errors[-1].rms_m == pytest.approx(e.rmse_m, rel=1e-6)
        assert all(b.ratio < 2.0 for b in e.band_errors if b.floor_m > 0.1 * e.noise_floor_m)
        # the parameters' band alone is far narrower than the predictive band
        assert np.mean(e.model_high_m - e.model_low_m) < 0.5 * np.mean(e.high_m - e.low_m)
    assert v.experiments[2].rig["name"] == "control"


def test_a_wrong_model_is_far_above_the_floor_with_low_coverage(fit_tree):
    lagged = held_out(sine_pa(1.0), source="lagged.csv", effects={"regulator_lag": 0.045})
    e = validate(fit_tree, lagged, n_draws=100, seed=0).experiments[0]
    assert e.rmse_m > 10 * e.noise_floor_m
    assert e.band_coverage < 0.5
    assert max(b.ratio for b in e.band_errors) > 10


def test_the_model_with_the_missing_effects_predicts_to_the_floor():
    lab = {"regulator_lag": 0.045, "coulomb_friction": 0.8}
    tree = plant_fit(tuple(lab), values={"tau_reg": 0.045, "F_c": 0.8})
    data = held_out(sine_pa(1.0, 4.0), source="lab_sine.csv", effects=lab, rig=Rig.control())
    e = validate(tree, data, n_draws=100, seed=0).experiments[0]
    assert 0.8 <= e.band_coverage <= 0.97 and e.rmse_m < 1.5 * e.noise_floor_m


def test_another_sample_rate_rescales_the_noise_correlation(fit_tree):
    slow = held_out(sine_pa(1.0, 16.0)[::4], rate_hz=250.0, source="sine_250hz.csv")
    e = validate(fit_tree, slow, n_draws=100, seed=0).experiments[0]
    assert any("rescaled" in note for note in e.notes)
    assert e.noise["rho_noise_median"] == pytest.approx(RHO**4, rel=1e-3)
    assert 0.8 <= e.band_coverage <= 0.97


def test_json_keys_and_nulls(fit_tree):
    single = held_out(steps_pa(4.0), n_trials=1, source="one_step.csv")
    v = validate(fit_tree, single, n_draws=50, seed=0)
    d = json.loads(json.dumps(v.to_dict(), allow_nan=False))  # JSON-ready: no NaN, no numpy
    e = d["experiments"][0]
    for key in ("rmse_m", "nrmse", "noise_floor_m", "band_coverage", "band_errors",
                "predictive_band", "source", "rig", "n_trials", "n_samples", "synthetic"):
        assert key in e
    assert e["noise_floor_m"] is None and e["ratio_to_floor"] is None
    assert e["band_errors"] and all(b["floor_m"] is None for b in e["band_errors"])
    assert e["band_errors"][-1]["rms_m"] == pytest.approx(e["rmse_m"], rel=1e-6)
    assert e["n_trials"] == 1 and e["synthetic"] is True and e["source"] == "one_step.csv"
    assert len(e["predictive_band"]["low_m"]) == e["n_samples"] == 4000
    assert d["settings"]["ci_prob"] == 0.9 and "nrmse" in d["definitions"]


def test_same_seed_same_numbers_and_ci_prob_changes_coverage(fit_tree, held_out_sets):
    a = validate(fit_tree, held_out_sets[1], n_draws=60, seed=3).experiments[0]
    b = validate(fit_tree, held_out_sets[1], n_draws=60, seed=3).experiments[0]
    assert a.rmse_m == b.rmse_m and np.array_equal(a.low_m, b.low_m)
    c = validate(fit_tree, held_out_sets[1], n_draws=60, rng=np.random.default_rng(3))
    assert np.array_equal(c.experiments[0].low_m, a.low_m) and c.settings["seed"] is None
    other = validate(fit_tree, held_out_sets[1], n_draws=60, seed=4).experiments[0]
    assert not np.array_equal(other.low_m, a.low_m)
    wide = validate(fit_tree, held_out_sets[1], n_draws=60, seed=3, ci_prob=0.99).experiments[0]
    assert wide.band_coverage > a.band_coverage


def test_refusals(fit_tree, held_out_sets, tmp_path):
    force = held_out(sine_pa() * 1e-4, source="force.csv", rig=Rig.force_oscillator(2.0),
                     input_name="force_n")
    with pytest.raises(ValidationError, match="force.csv.*input kind"):
        validate(fit_tree, force)
    ds = held_out_sets[0]
    with pytest.raises(ValidationError, match="rho_noise, sigma_white_m"):
        validate(fake_fit(), ds)  # the default fake fit holds no noise posterior
    with pytest.raises(ValidationError, match="ci_prob"):
        validate(fit_tree, ds, ci_prob=90)
    with pytest.raises(ValidationError, match="n_draws"):
        validate(fit_tree, ds, n_draws=1)
    with pytest.raises(ValidationError, match="one noise"):
        validate(fit_tree, ds, noise_from="chirp")
    with pytest.raises(TypeError):
        validate(fit_tree, ds, draws=10)  # unknown keyword


def multi_experiment_fit():
    """A fit of two experiments: the unloaded one with the plant's noise, the loaded one
    with ten times more (the layout: noise variables with an ``experiment`` dimension)."""
    tree = plant_fit()
    post = tree["posterior"].to_dataset()
    for name in ("sigma_noise_m", "sigma_white_m"):
        post[name] = post[name].expand_dims(experiment=["chirp", "sine_loaded"], axis=-1) * \
            np.array([1.0, 10.0])
    post["rho_noise"] = post["rho_noise"].expand_dims(experiment=["chirp", "sine_loaded"],
                                                      axis=-1)
    tree["posterior"] = type(tree)(post)
    info = json.loads(tree.attrs["pmabayes"])
    info["experiments"] = [
        {"name": "chirp", "rig": Rig.characterisation().to_dict(), "dt_s": 1e-3},
        {"name": "sine_loaded", "rig": Rig.control().to_dict(), "dt_s": 1e-3}]
    tree.attrs["pmabayes"] = json.dumps(info)
    return tree


def test_multi_experiment_fit_takes_the_noise_of_the_matching_rig(held_out_sets):
    tree = multi_experiment_fit()
    loaded = held_out_sets[2]
    auto = validate(tree, [held_out_sets[0], loaded], n_draws=100, seed=0).experiments
    assert "'chirp'" in auto[0].noise["from"] and 0.8 <= auto[0].band_coverage <= 0.97
    assert "'sine_loaded'" in auto[1].noise["from"] and auto[1].band_coverage > 0.99
    chosen = validate(tree, loaded, n_draws=100, seed=0, noise_from="chirp").experiments[0]
    assert "chosen" in chosen.noise["from"] and 0.8 <= chosen.band_coverage <= 0.97
    oscillator = Rig(0.067, 1.0, name="other_bench")
    other = held_out(sine_pa(), rig=oscillator, source="other.csv")
    pooled = validate(tree, other, n_draws=100, seed=0).experiments[0]
    assert "pooled over all" in pooled.noise["from"]
    with pytest.raises(ValidationError, match="names no fitted experiment.*chirp, sine_loaded"):
        validate(tree, loaded, noise_from="nope")
    post = tree["posterior"].to_dataset()
    post["K_e"] = post["K_e"].expand_dims(experiment=["chirp", "sine_loaded"], axis=-1)
    tree["posterior"] = type(tree)(post)
    with pytest.raises(ValidationError, match="K_e differ between its experiments"):
        validate(tree, loaded)


def test_the_fit_own_data_is_flagged_as_not_held_out(tmp_path):
    tree = plant_fit(n_time=1000)
    obs = tree["observed_data"]["position_m"]
    own = Dataset(time_s=obs["time"].values,
                  input=np.repeat(tree["constant_data"]["pressure_pa"].values[None], 3, axis=0),
                  position_m=obs.values, trial_ids=np.arange(3), source="own.csv")
    with pytest.warns(DataWarning, match="not held-out"):
        validate(tree, own, n_draws=20)


def test_html_page_and_figure(fit_tree, held_out_sets, tmp_path):
    from pmabayes.report.validation_page import write_validation

    v = validate(fit_tree, [held_out(steps_pa(3.0), source="steps.csv"),
                            held_out(sine_pa(1.0, 3.0), source="sine_1hz.csv"),
                            held_out(steps_pa(3.0), n_trials=1, source="single.csv")],
                 n_draws=50, seed=0)
    index = write_validation(v, tmp_path / "val")
    page = index.read_text()
    for name in ("steps", "sine_1hz", "single"):
        assert name in page
    assert "data:image/png;base64," in page and "http" not in page.replace(
        "http-equiv", "")
    assert "Synthetic data" in page and "not the held-out data's own noise" in page
    assert (tmp_path / "val" / "validation.json").is_file()


def test_cli_end_to_end(tmp_path, capsys, held_out_sets):
    fit_path = plant_fit(path=tmp_path / "fit.nc")
    files = []
    for ds, name in ((held_out_sets[0], "steps.csv"),
                     (held_out(sine_pa(), n_trials=1, seed=5), "sine_single.csv")):
        save(ds, tmp_path / name)
        files.append(str(tmp_path / name))
    out_json = tmp_path / "v.json"
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        code = main(["validate", str(fit_path), *files, "--json", str(out_json),
                     "--out", str(tmp_path / "page"), "--draws", "80", "--seed", "2"])
    assert code == 0
    text = capsys.readouterr().out
    assert "steps:" in text and "sine_single:" in text and "no noise floor" in text
    d = json.loads(out_json.read_text())
    steps, single = d["experiments"]
    assert d["fit"] == str(fit_path) and d["settings"]["seed"] == 2
    assert steps["noise_floor_m"] > 0 and single["noise_floor_m"] is None
    assert 0.8 <= steps["band_coverage"] <= 0.97
    assert (tmp_path / "page" / "index.html").is_file()
    force = held_out(sine_pa() * 1e-4, rig=Rig.force_oscillator(2.0), input_name="force_n")
    save(force, tmp_path / "force.csv")
    assert main(["validate", str(fit_path), str(tmp_path / "force.csv")]) == 2
    assert "force.csv" in capsys.readouterr().err


@pytest.mark.slow
def test_validation_after_a_real_fit():
    """Fit a chirp from the plant, then validate on steps and sines of the same plant."""
    from pmabayes.inference.sampler import FitSettings, fit
    from pmabayes.synthetic import Chirp

    chirp = generate_chirp_dataset(n_trials=6, seed=4, chirp=Chirp(duration_s=8.0))
    tree = fit(chirp, seed=0, settings=FitSettings(progress=False))
    v = validate(tree, [held_out(steps_pa(), seed=21, source="steps.csv"),
                        held_out(sine_pa(2.0), seed=22, source="sine_2hz.csv"),
                        held_out(sine_pa(0.5), seed=23, rig=Rig.control(),
                                 source="sine_loaded.csv")], seed=0)
    for e in v.experiments:
        assert 0.8 <= e.band_coverage <= 0.97, (e.name, e.band_coverage)
        assert e.rmse_m < 1.5 * e.noise_floor_m, (e.name, e.rmse_m, e.noise_floor_m)


def test_noiseless_held_out_data_are_judged_by_the_model_only_band(fit_tree):
    """A benchmark's noiseless test set: the predictive band (with the fit's noise) holds
    it trivially; the band of the parameters alone tells a right model from a wrong one."""
    model, values = hidden_effects_model(None)
    p = sine_pa(1.0)
    t = np.arange(p.size) / RATE_HZ
    truth = simulate(model, values, p, time_s=t)
    clean = Dataset(time_s=t, input=p[None], position_m=truth, trial_ids=np.array([1]),
                    metadata={"synthetic": True, "rig": model.rig.to_dict()},
                    source="clean.csv")
    right = validate(fit_tree, clean, n_draws=200, seed=0).experiments[0]
    assert right.band_coverage == 1.0
    assert right.model_band_coverage > 0.8
    lag_model, lag_values = hidden_effects_model({"regulator_lag": 0.045})
    lagged = Dataset(time_s=t, input=p[None],
                     position_m=simulate(lag_model, lag_values, p, time_s=t),
                     trial_ids=np.array([1]), metadata=dict(clean.metadata), source="lag.csv")
    wrong = validate(fit_tree, lagged, n_draws=200, seed=0).experiments[0]
    assert wrong.model_band_coverage < 0.2
    assert json.loads(json.dumps(right.to_dict()))["model_band_coverage"] > 0.8


def test_validate_gives_the_adequacy_verdict_fit_and_diagnose_use(fit_tree, held_out_sets):
    """The held-out verdict by the one adequacy rule, in the object and in the JSON: the
    right model is adequate on held-out data, a model missing a 45 ms lag is not."""
    right = validate(fit_tree, held_out_sets[0], n_draws=100, seed=0).experiments[0]
    lagged = held_out(sine_pa(1.0), source="lagged.csv", effects={"regulator_lag": 0.045})
    wrong = validate(fit_tree, lagged, n_draws=100, seed=0)
    assert right.adequacy is not None and right.adequacy.adequate is True
    assert right.adequacy.floor_m == pytest.approx(right.noise_floor_m, rel=1e-6)
    e = json.loads(json.dumps(wrong.to_dict(arrays=False), allow_nan=False))["experiments"][0]
    assert e["adequacy"]["adequate"] is False
    assert e["adequacy"]["verdict"].startswith("MODEL INADEQUATE")
    assert e["adequacy"]["rms_m"] == pytest.approx(e["rmse_m"], rel=1e-6)
