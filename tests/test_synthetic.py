"""Synthetic chirp data: the commanded chirp, the noise model and reproducibility."""

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.data import DataError, read_csv, write_csv
from pmabayes.synthetic import (
    ENCODER_COUNTS_PER_M,
    Chirp,
    MeasurementNoise,
    generate_chirp_dataset,
)

SHORT = Chirp(duration_s=3.0, f0_hz=0.5, f1_hz=2.0)


def test_paper_chirp():
    chirp = Chirp()
    p = chirp.pressure_pa()
    assert p.shape == (15000,)
    assert p[0] == 0.0 and p.max() == pytest.approx(0.5e6, rel=1e-6) and p.min() >= 0.0
    assert chirp.frequency_hz(0.0) == 0.1 and chirp.frequency_hz(15.0) == 3.0
    # the instantaneous frequency is the derivative of the phase
    t = chirp.time_s
    assert np.allclose(np.gradient(chirp.phase_cycles(t), t)[1:-1],
                       chirp.frequency_hz(t)[1:-1], atol=1e-9)


def test_same_seed_same_numbers_and_different_seed_differs():
    a = generate_chirp_dataset(n_trials=3, seed=5, chirp=SHORT)
    b = generate_chirp_dataset(n_trials=3, seed=5, chirp=SHORT)
    c = generate_chirp_dataset(n_trials=3, seed=6, chirp=SHORT)
    assert np.array_equal(a.position_m, b.position_m)
    assert not np.array_equal(a.position_m, c.position_m)
    d = generate_chirp_dataset(n_trials=3, rng=np.random.default_rng(5), chirp=SHORT)
    assert np.array_equal(a.position_m, d.position_m)
    assert d.metadata["generator"]["seed"] is None


def test_noise_none_is_the_exact_model_output():
    ds = generate_chirp_dataset(n_trials=2, noise=None, chirp=SHORT)
    x = pb.simulate(pb.Model(), None, SHORT.pressure_pa(), dt_s=1e-3)[0]
    assert np.array_equal(ds.position_m[0], x) and np.array_equal(ds.position_m[1], x)


def test_disturbance_is_autocorrelated_as_specified():
    noise = MeasurementNoise(disturbance_std_m=1e-4, disturbance_corr_time_s=0.05,
                             encoder_counts_per_m=None)
    e = noise.disturbance(40, 5000, 1e-3, np.random.default_rng(0))
    assert e.std() == pytest.approx(1e-4, rel=0.05)
    lag = 10
    rho = np.mean(e[:, lag:] * e[:, :-lag]) / np.mean(e * e)
    assert rho == pytest.approx(np.exp(-lag * 1e-3 / 0.05), abs=0.03)  # 0.82, not white


def test_quantisation_to_encoder_counts():
    ds = generate_chirp_dataset(n_trials=2, seed=1, chirp=SHORT)
    counts = ds.position_m * ENCODER_COUNTS_PER_M
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    assert ENCODER_COUNTS_PER_M == pytest.approx(2000 / 0.0254)


def test_hidden_effects_recorded_and_applied(tmp_path):
    ds = generate_chirp_dataset(n_trials=2, seed=1, chirp=SHORT, noise=None,
                                effects={"regulator_lag": 0.045,
                                         "coulomb_friction": {"F_c": 0.8}})
    gen = ds.metadata["generator"]
    assert gen["effects"] == {"regulator_lag": {"tau_reg": 0.045},
                              "coulomb_friction": {"F_c": 0.8, "v_c": 1e-3}} or gen[
        "effects"] == {"regulator_lag": {"tau_reg": 0.045}, "coulomb_friction": {"F_c": 0.8}}
    assert gen["parameters"]["tau_reg"] == 0.045 and ds.metadata["synthetic"] is True
    model = pb.Model(["regulator_lag", "coulomb_friction"])
    x = pb.simulate(model, {"tau_reg": 0.045, "F_c": 0.8}, SHORT.pressure_pa(), dt_s=1e-3)[0]
    assert np.array_equal(ds.position_m[0], x)
    path = tmp_path / "lab.csv"
    write_csv(ds, path)
    assert read_csv(path) == ds


def test_bad_generator_settings():
    with pytest.raises(pb.ModelError, match="has no parameter 'tau'"):
        generate_chirp_dataset(effects={"regulator_lag": {"tau": 0.1}}, chirp=SHORT)
    with pytest.raises(pb.EffectError, match="unknown effect 'lag'"):
        generate_chirp_dataset(effects={"lag": 0.1}, chirp=SHORT)
    # DataError (a ValueError): the command line reports the package's own errors
    # in one line and lets any other exception show as a bug
    with pytest.raises(DataError, match=r"n_trials.*\(--trials\)"):
        generate_chirp_dataset(n_trials=0, chirp=SHORT)
    with pytest.raises(DataError, match="p_min_pa < p_max_pa"):
        Chirp(p_min_pa=1.0, p_max_pa=0.0)
    with pytest.raises(DataError, match=r"duration_s \(--duration\) > 0"):
        Chirp(duration_s=-1.0)
    with pytest.raises(DataError, match=r"fewer than 2 samples; lengthen it \(--duration\)"):
        Chirp(duration_s=1e-3)
    with pytest.raises(DataError, match="disturbance_std_m must be >= 0"):
        MeasurementNoise(disturbance_std_m=-1.0)


def test_bundled_datasets_are_synthetic_and_regenerable():
    from pathlib import Path

    data = Path(__file__).resolve().parents[1] / "data"
    for name in ("pma_chirp_paper", "pma_chirp_lab"):
        ds = read_csv(data / f"{name}.csv")
        meta = ds.metadata
        assert meta["synthetic"] is True and "SYNTHETIC" in meta["description"]
        gen = meta["generator"]
        again = generate_chirp_dataset(
            n_trials=gen["n_trials"], seed=gen["seed"], chirp=Chirp(**gen["chirp"]),
            noise=MeasurementNoise(**gen["noise"]), effects=gen["effects"],
            params=gen["parameters"],
        )
        assert np.array_equal(again.position_m, ds.position_m), name
