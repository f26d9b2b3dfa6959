"""diagnose and compare over several experiments (each on its own rig), and single records.

All data are generated here with seeds: an unloaded chirp on the characterisation rig
and a loaded sine on the control rig, as in ``tests/test_experiments.py``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.criticism.bands import band_errors
from pmabayes.criticism.compare import compare_fits
from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.scores import rank_effects
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.data import DataError, Dataset, save
from pmabayes.inference.fitfile import save_fit
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.noise import estimate_noise
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.model.model import PAPER_VALUES, Rig
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

BASE = ("alpha", "beta", "gamma", "d", "K_e", "p_dz")
TRUE = {k: PAPER_VALUES[k] for k in BASE}
BUILTINS = ("regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
            "pressure_stiffness", "position_offset")
#: a disturbance much faster than the inputs
NOISE = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002)
QUICK = FitSettings(n_walkers=16, n_ensembles=2, max_steps=1200, check_every=200,
                    min_ess=100)
LAG = {"regulator_lag": 0.045}


def chirp(*, effects=None, n_trials: int = 4, seed: int = 1,
          source: str = "lab/chirp_unloaded.csv") -> Dataset:
    """Trials of a 0.2-3 Hz pressure chirp on the characterisation rig."""
    ds = generate_chirp_dataset(n_trials=n_trials, seed=seed, noise=NOISE, effects=effects,
                                chirp=Chirp(duration_s=4.0, f0_hz=0.2, f1_hz=3.0,
                                            sample_rate_hz=500.0))
    return Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                   trial_ids=ds.trial_ids, metadata=ds.metadata, source=source)


def sine(*, effects=None, n_trials: int = 3, seed: int = 2, n_periods: int = 3,
         freq_hz: float = 1.0, periodic: bool = False, rig: Rig | None = None,
         noise: MeasurementNoise = NOISE, source: str = "lab/sine_loaded.csv") -> Dataset:
    """Trials of a 1 Hz pressure sine from rest on the loaded control rig; ``periodic``: one
    record of whole periods in periodic steady state, declared so."""
    rig = Rig.control() if rig is None else rig
    model = pb.Model(list(effects or {}), rig=rig)
    rate = 500.0
    period = int(round(rate / freq_hz))
    t = np.arange(n_periods * period) / rate
    p = 0.2e6 * (1.0 - np.cos(2.0 * np.pi * freq_hz * t))
    params = dict(TRUE)
    for name, value in (effects or {}).items():
        eff = pb.get_effect(name)
        params[next(q.name for q in eff.parameters if q.vary)] = value
    # a periodic record is taken in periodic steady state (the hysteresis creeps towards
    # it over many periods from rest)
    x = pb.simulate(model, params, p, time_s=t, period_samples=period if periodic else None,
                    steady_state=periodic)[0]
    y = noise.apply(np.repeat(x[None], n_trials, axis=0), 1.0 / rate,
                    np.random.default_rng(seed))
    meta = {"synthetic": True, "rig": rig.to_dict(), "sample_rate_hz": rate,
            "description": "synthetic sine trials made by tests/test_multidiag.py"}
    if periodic:
        meta.update(period_samples=period, starts_in_steady_state=True)
    return Dataset(time_s=t, input=np.repeat(p[None], n_trials, axis=0), position_m=y,
                   trial_ids=np.arange(n_trials), metadata=meta, source=source)


# ----------------------------------------------------------------------------- fast


def test_the_score_test_adds_the_experiments_scores_and_informations():
    """Two independent copies of one experiment carry twice its score and information,
    so every candidate's statistic doubles; a second rig adds its own."""
    a = chirp(effects=LAG, n_trials=3)
    lik = Likelihood(pb.Model(), a)
    noise = estimate_noise(lik)
    one = {e.effect: e for e in rank_effects(lik, noise, TRUE, candidates=BUILTINS)}
    two = {e.effect: e for e in rank_effects([lik, lik], [noise, noise], TRUE,
                                             candidates=BUILTINS)}
    for name in BUILTINS:
        assert two[name].statistic == pytest.approx(2.0 * one[name].statistic, rel=1e-9)
    assert one["regulator_lag"].significant
    b = sine(effects=LAG)
    lik_b = Likelihood(pb.Model(rig=Rig.control()), b)
    both = rank_effects([lik, lik_b], [noise, estimate_noise(lik_b)], TRUE,
                        candidates=BUILTINS)
    assert both[0].effect in {"regulator_lag", "transport_delay"} and both[0].significant
    assert {e.effect: e for e in both}["regulator_lag"].statistic > one[
        "regulator_lag"].statistic
    with pytest.raises(ValueError, match="one noise each"):
        rank_effects([lik, lik_b], noise, TRUE)


def test_a_periodic_record_has_a_floor_from_its_periods_and_a_plain_record_none():
    """The floor of a single record comes from its periods when it declares them (as its
    noise does in the fit), and is absent, not invented, when it has no repeats."""
    white = MeasurementNoise(disturbance_std_m=30e-6, disturbance_corr_time_s=0.002,
                             encoder_counts_per_m=None)
    per = sine(n_trials=1, n_periods=6, periodic=True, noise=white, seed=5)
    x = pb.simulate(pb.Model(rig=Rig.control()), TRUE, per.input[0], time_s=per.time_s,
                    period_samples=500, steady_state=True)[0]
    rows = band_errors(per, x)
    assert rows[-1].floor_m == pytest.approx(30e-6, rel=0.1)
    # the bands' floors add up to the total, as the errors do
    total = np.sqrt(sum(r.floor_m ** 2 for r in rows[:-1]))
    assert total == pytest.approx(rows[-1].floor_m, rel=1e-9)
    assert rows[-1].ratio == pytest.approx(1.0, abs=0.15)
    plain = sine(n_trials=1, n_periods=6, noise=white, seed=5)
    assert all(np.isnan(r.floor_m) for r in band_errors(plain, x))


def test_bad_input_is_refused_before_anything_is_fitted(tmp_path, capsys):
    from conftest import fake_fit

    from pmabayes.cli import main

    a = chirp(n_trials=2)
    f = Dataset(time_s=a.time_s, input=np.full((2, a.n_samples), 1.0),
                position_m=a.position_m, trial_ids=np.arange(2), input_name="force_n",
                source="lab/force.csv")
    with pytest.raises(DataError, match=r"lab/force.csv.*force_n"):
        diagnose([a, f])
    with pytest.raises(ValueError, match="at least one data set"):
        diagnose([])
    with pytest.raises(TypeError, match="Dataset"):
        diagnose([a, "b.csv"])
    # compare: a fit of one experiment given two data files
    fit_path = tmp_path / "one.nc"
    fake_fit(fit_path)
    save(a, tmp_path / "a.csv")
    save(sine(), tmp_path / "b.csv")
    code = main(["compare", str(fit_path), str(fit_path), "--data", str(tmp_path / "a.csv"),
                 str(tmp_path / "b.csv"), "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err
    assert code == 2 and "one.nc is a fit of 1 experiment(s)" in err and "b.csv" in err


# ----------------------------------------------------------------------------- slow


@pytest.fixture(scope="module")
def lagged():
    """A 45 ms regulator lag hidden in both experiments."""
    return chirp(effects=LAG, seed=11), sine(effects=LAG, seed=12)


@pytest.fixture(scope="module")
def lagged_diagnosis(lagged):
    return diagnose(list(lagged), settings=DiagnoseSettings(candidates=BUILTINS, max_refits=2),
                    seed=0)


@pytest.mark.slow
def test_the_users_loop_on_a_periodic_record_from_rest():
    """One record of 5 periods from rest, with a hidden 45 ms regulator lag. Its raw
    periods 2-5 differ by the hysteresis' shakedown (a noise of 787 um where 20 um was
    drawn; under it the lagged model's MAP was 110 um off, and passed). Round 1 names
    the lag; round 2, the lag added, is adequate at the noise actually drawn."""
    rig = Rig.characterisation()
    rate, period = 500.0, 500
    t = np.arange(5 * period) / rate
    p = 0.2e6 * (1.0 - np.cos(2.0 * np.pi * t)) + 0.03e6 * np.sin(6.0 * np.pi * t)
    x = pb.simulate(pb.Model(["regulator_lag"], rig=rig), {**TRUE, "tau_reg": 0.045}, p,
                    time_s=t)[0]
    y = NOISE.apply(x[None], 1.0 / rate, np.random.default_rng(3))
    ds = Dataset(time_s=t, input=p[None], position_m=y, trial_ids=np.arange(1),
                 source="lab/two_tone_from_rest.csv",
                 metadata={"synthetic": True, "rig": rig.to_dict(), "sample_rate_hz": rate,
                           "period_samples": period, "starts_in_steady_state": False})
    first = diagnose(ds, pb.Model(rig=rig), seed=1)
    assert first.adequate is False and first.missing == "regulator_lag", first.verdict
    second = diagnose(ds, pb.Model(["regulator_lag"], rig=rig), seed=1)
    assert second.adequate, second.verdict
    assert 0.8 < second.noise_floor_m / NOISE.disturbance_std_m < 1.25, second.verdict
    assert second.rms_m < 1.1 * second.noise_floor_m, second.verdict


@pytest.mark.slow
def test_a_lag_hidden_in_both_experiments_is_found_and_named(lagged_diagnosis):
    d = lagged_diagnosis
    assert [e.name for e in d.experiments] == ["chirp_unloaded", "sine_loaded"]
    assert [e.model.rig for e in d.experiments] == [Rig.characterisation(), Rig.control()]
    assert not d.adequate and d.missing == "regulator_lag", d.verdict
    # the misfit shows in both, and the verdict says so
    assert d.misfit_experiments == ["chirp_unloaded", "sine_loaded"]
    assert "The misfit shows in chirp_unloaded, sine_loaded" in d.verdict
    for e in d.experiments:
        assert e.rms_m > 2.0 * e.noise_floor_m
    top = d.ranking[0]
    assert top.effect == "regulator_lag" and top.refit is not None
    lo, hi = top.interval["tau_reg"]
    assert lo < 0.045 < hi
    # the refit is judged in each experiment
    assert len(top.refit.signatures) == 2
    for sig, e in zip(top.refit.signatures, d.experiments, strict=True):
        assert sig.bands[-1].rms_m < 0.5 * e.rms_m
    # JSON: the one-experiment keys, and the experiments
    out = json.loads(json.dumps(d.to_dict()))
    for key in ("data", "effects", "rms_m", "noise_floor_m", "adequate", "missing",
                "verdict", "ranking", "elpd_loo", "settings", "experiments",
                "misfit_experiments"):
        assert key in out
    assert [e["name"] for e in out["experiments"]] == ["chirp_unloaded", "sine_loaded"]
    assert out["experiments"][1]["rig"] == Rig.control().to_dict()
    assert all(e["adequate"] is False and e["ratio"] > 2 for e in out["experiments"])
    assert len(out["ranking"][0]["refit"]["experiments"]) == 2


@pytest.mark.slow
def test_with_the_lag_added_the_model_is_adequate_in_both(lagged):
    d = diagnose(list(lagged), effects=["regulator_lag"],
                 settings=DiagnoseSettings(candidates=BUILTINS, max_refits=2), seed=0)
    assert d.adequate and d.missing is None, d.verdict
    assert all(e.adequate for e in d.experiments) and d.misfit_experiments == []
    for e in d.experiments:
        assert e.rms_m <= 1.25 * e.noise_floor_m
    assert d.values["tau_reg"] == pytest.approx(0.045, rel=0.1)
    # the ELPD leaves out one trial at a time of both experiments
    assert np.isfinite(d.elpd)


@pytest.mark.slow
@pytest.mark.extended  # extended tier: CI stays under 30 minutes
def test_a_perfect_model_is_adequate_across_the_experiments():
    d = diagnose([chirp(seed=21), sine(seed=22)],
                 settings=DiagnoseSettings(candidates=BUILTINS, max_refits=2), seed=0)
    assert d.adequate and d.missing is None, d.verdict
    assert not any(f.significant for f in d.ranking)
    assert "adequate" in d.verdict and "misfit shows" not in d.verdict


@pytest.mark.slow
@pytest.mark.extended  # extended tier: CI stays under 30 minutes
def test_one_data_set_is_diagnosed_as_before():
    """A Dataset and a list of one give the same diagnosis, to the bit, and the JSON of
    one experiment has the shape of several."""
    a = chirp(effects={"position_offset": 5e-4}, n_trials=3, seed=31)
    settings = DiagnoseSettings(candidates=BUILTINS, max_refits=1)
    one = diagnose(a, settings=settings, seed=0)
    listed = diagnose([a], settings=settings, seed=0)
    assert one.verdict == listed.verdict and one.elpd == listed.elpd
    assert one.missing == "position_offset"
    assert json.dumps(one.to_dict()) == json.dumps(listed.to_dict())
    # one experiment has the JSON shape of several
    out = json.loads(json.dumps(one.to_dict()))
    assert len(out["experiments"]) == 1 and out["misfit_experiments"] == ["chirp_unloaded"]
    assert out["rms_m"] == out["experiments"][0]["rms_m"] == one.experiments[0].rms_m
    assert out["discrepancy"] is None or "experiment" in out["discrepancy"]


@pytest.mark.slow
@pytest.mark.extended  # extended tier: CI stays under 30 minutes
def test_records_without_repeats_say_they_have_no_floor():
    """A single non-periodic record beside a repeated experiment: its noise is identified
    with the model, and the diagnosis says it has no floor instead of failing."""
    rec = sine(n_trials=1, seed=41, n_periods=4, source="lab/sine_record.csv")
    d = diagnose([chirp(seed=42), rec],
                 settings=DiagnoseSettings(candidates=BUILTINS, max_refits=1), seed=0)
    e = d.experiments[1]
    assert e.noise_source == "record" and np.isnan(e.noise_floor_m)
    assert "no noise floor" in d.verdict and "sine_record.csv is a single record" in d.verdict
    out = json.loads(json.dumps(d.to_dict()))
    assert out["experiments"][1]["noise_floor_m"] is None and out["noise_floor_m"] is None
    assert out["experiments"][1]["floor_note"].startswith("lab/sine_record.csv is a single")


@pytest.mark.slow
@pytest.mark.extended  # extended tier: CI stays under 30 minutes
def test_cli_diagnose_several_files(lagged, tmp_path, capsys):
    from pmabayes.cli import main

    files = []
    for ds in lagged:
        path = tmp_path / ds.source.split("/")[-1]
        save(ds, path)
        files.append(str(path))
    out = tmp_path / "diag"
    assert main(["diagnose", *files, "--candidates", ",".join(BUILTINS), "--quiet",
                 "--json", str(tmp_path / "d.json"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "[chirp_unloaded] RMS error" in text and "[sine_loaded] RMS error" in text
    assert "regulator_lag is missing" in text
    summary = json.loads((tmp_path / "d.json").read_text())
    assert summary["missing"] == "regulator_lag" and len(summary["experiments"]) == 2
    page = (out / "index.html").read_text()
    for name in ("chirp_unloaded", "sine_loaded"):
        assert f'id="experiment-{name}"' in page
        assert (out / f"bands_{name}.png").is_file()
    assert (out / "ranking.png").is_file()


@pytest.fixture(scope="module")
def joint_fits(lagged):
    base = fit(list(lagged), pb.Model(), seed=1, settings=QUICK)
    lag = fit(list(lagged), pb.Model(["regulator_lag"]), seed=1, settings=QUICK)
    return base, lag


@pytest.mark.slow
def test_compare_fits_of_several_experiments(joint_fits, lagged, tmp_path):
    from pmabayes.report.comparison_page import write_comparison

    base, lag = joint_fits
    c = compare_fits([base, lag], list(lagged))
    assert list(c.experiments) == ["chirp_unloaded", "sine_loaded"]
    assert c.labels == ["base", "base + regulator_lag"]
    for name, part in c.experiments.items():
        rms = c.rmse_m("base")[name], c.rmse_m("base + regulator_lag")[name]
        assert rms[1] < 0.5 * rms[0], (name, rms)
        assert part.bands["base + regulator_lag"][-1].ratio < 1.3
    # LOO over all trials of both experiments: the lag predicts them better
    assert c.elpd["base + regulator_lag"]["rank"] == 0
    assert c.elpd_steps[0]["elpd_diff"] > 2 * c.elpd_steps[0]["se"]
    out = c.to_dict()
    assert out["experiments"] == ["chirp_unloaded", "sine_loaded"]
    assert set(out["fits"][0]["experiments"]) == {"chirp_unloaded", "sine_loaded"}
    with pytest.raises(ValueError, match="per experiment"):
        c.whiteness_curves()
    index = write_comparison(c, tmp_path / "cmp", dataset=list(lagged))
    page = index.read_text()
    assert 'id="experiment-sine_loaded"' in page
    assert (tmp_path / "cmp" / "error_falling_chirp_unloaded.png").is_file()


@pytest.mark.slow
@pytest.mark.extended  # extended tier: CI stays under 30 minutes
def test_compare_refuses_fits_of_other_experiments(joint_fits, lagged, tmp_path, capsys):
    from pmabayes.cli import main

    base, lag = joint_fits
    a, b = lagged
    # the data files in the wrong order
    with pytest.raises(DataError, match="does not match experiment chirp_unloaded"):
        compare_fits([base, lag], [b, a])
    # a fit of other experiments (the same two, the other way round)
    swapped = fit([b, a], pb.Model(), seed=1, settings=QUICK)
    with pytest.raises(DataError, match=r"swapped.nc is a fit of 2 experiment\(s\)"):
        compare_fits([base, swapped], [a, b], sources=["base.nc", "swapped.nc"])
    # on the command line, naming the files
    paths = [save_fit(t, tmp_path / f"{n}.nc") for n, t in (("base", base), ("swapped", swapped))]
    save(a, tmp_path / "chirp_unloaded.csv")
    save(b, tmp_path / "sine_loaded.csv")
    code = main(["compare", *map(str, paths), "--data", str(tmp_path / "chirp_unloaded.csv"),
                 str(tmp_path / "sine_loaded.csv"), "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err
    assert code == 2 and "swapped.nc is a fit of 2 experiment(s)" in err
