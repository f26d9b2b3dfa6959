"""The criticism of lab records: samples not observed (gaps, a warm-up),
trials with their own measured inputs and estimated starts are judged by the same
statistics as complete records, over the samples observed, never invented ones.

All data are synthetic, made here: a record with 5% of its samples removed (30 ms gaps
every 0.5 s, as a DAQ that pauses between blocks) is compared with the same record
complete.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from test_validate import held_out, plant_fit, steps_pa

import pmabayes as pb
from pmabayes.cli import main
from pmabayes.criticism.bands import band_errors
from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.criticism.validation import validate
from pmabayes.criticism.whiteness import autocorrelation, whiteness_statistics
from pmabayes.data import Dataset, DataWarning, save
from pmabayes.inference.likelihood import _ljung_box_observed, ljung_box_statistic
from pmabayes.report.figures import plot_comparison, plot_residual
from pmabayes.report.figures.common import GAP_COLOUR
from pmabayes.synthetic import Chirp, MeasurementNoise, Regulator, generate_chirp_dataset

CHIRP = Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=2.0)


def blocks_seen(n: int, every: int = 500, gap: int = 30) -> np.ndarray:
    """True except 30 samples before every 500th (and never the last ones)."""
    k = np.arange(n)
    return ~((k % every >= every - gap) & (k < n - gap))


def held(p: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """The input across gaps as the data layer rebuilds it (the last value held)."""
    k = np.arange(p.size)
    return p[np.maximum.accumulate(np.where(seen, k, 0))]


def with_gaps(ds: Dataset, seen: np.ndarray, source: str = "gappy.csv") -> Dataset:
    """The same trials with the samples not ``seen`` removed."""
    return Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                   trial_ids=ds.trial_ids, metadata=ds.metadata, source=source,
                   observed=np.tile(seen, (ds.n_trials, 1)))


def lagged_pair(n_trials: int = 3, seed: int = 11) -> tuple[Dataset, Dataset]:
    """A chirp record of a muscle with a 30 ms regulator lag, complete and with gaps (the
    input held across them in both)."""
    t = CHIRP.time_s
    seen = blocks_seen(t.size)
    p = held(CHIRP.pressure_pa(t), seen)
    x = pb.simulate(pb.Model().with_effects("regulator_lag"), {"tau_reg": 0.03}, p,
                    time_s=t)[0]
    y = MeasurementNoise().apply(np.repeat(x[None], n_trials, axis=0), 1e-3,
                                 np.random.default_rng(seed))
    full = Dataset(time_s=t, input=np.tile(p, (n_trials, 1)), position_m=y,
                   trial_ids=np.arange(n_trials), source="full.csv")
    return full, with_gaps(full, seen)


# ----------------------------------------------------------------------------- statistics


def test_whiteness_statistics_take_the_samples_observed():
    rng = np.random.default_rng(0)
    e = rng.standard_normal(20000)
    seen = blocks_seen(e.size)
    gappy = np.where(seen, e, np.nan)
    # nothing missing: the general statistic is the classic Ljung-Box one
    assert _ljung_box_observed(e, np.ones(e.size, bool), 25) == pytest.approx(
        ljung_box_statistic(e), rel=1e-10)
    white = whiteness_statistics(gappy)
    assert white["energy"] == pytest.approx(np.mean(e[seen] ** 2), rel=1e-12)
    assert 0.001 < white["ljung_box_p"] and 0.001 < white["energy_p"] < 0.999
    lags, acf, bound = autocorrelation(gappy, max_lag=30)
    assert bound == pytest.approx(2.5758 / math.sqrt(seen.sum()), rel=1e-3)
    np.testing.assert_allclose(acf, autocorrelation(e, max_lag=30)[1], atol=0.01)
    # an autocorrelated series is still caught, its gaps notwithstanding
    ar = np.zeros(e.size)
    for k in range(1, e.size):
        ar[k] = 0.3 * ar[k - 1] + e[k]
    assert whiteness_statistics(np.where(seen, ar, np.nan))["ljung_box_p"] < 1e-10


def test_band_errors_with_gaps_are_those_of_the_complete_record():
    full, gappy = lagged_pair()
    x = pb.simulate(pb.Model(), None, full.input[0], time_s=full.time_s)[0]  # no lag
    a, b = band_errors(full, x), band_errors(gappy, x)
    assert [r.band_hz for r in a] == [r.band_hz for r in b]
    seen = gappy.observed[0]
    assert b[-1].rms_m == pytest.approx(
        math.sqrt(np.mean((gappy.mean_position_m - x)[seen] ** 2)), rel=1e-9)
    for ra, rb in zip(a, b, strict=True):
        assert np.isfinite([rb.rms_m, rb.floor_m, rb.max_m, rb.nrms]).all()
        assert rb.rms_m == pytest.approx(ra.rms_m, rel=0.05), ra.band_hz
        assert rb.floor_m == pytest.approx(ra.floor_m, rel=0.1), ra.band_hz
    # the bands still add up to the error over the samples observed
    assert math.sqrt(sum(r.rms_m**2 for r in b[:-1])) == pytest.approx(b[-1].rms_m, rel=1e-9)


# ----------------------------------------------------------------------------- validation


def test_validation_of_held_out_records_with_gaps_and_with_their_own_inputs():
    tree = plant_fit()
    full = held_out(steps_pa(), source="steps.csv", seed=11)
    seen = blocks_seen(full.n_samples)
    gappy = held_out(held(steps_pa(), seen), source="steps.csv", seed=11)
    gappy = with_gaps(gappy, seen, source="steps_gaps.csv")
    v = validate(tree, [full, gappy], n_draws=100, seed=0)
    a, b = v.experiments
    assert abs(b.band_coverage - a.band_coverage) < 0.03
    assert 0.8 <= b.band_coverage <= 0.97
    assert b.rmse_m == pytest.approx(a.rmse_m, rel=0.1)
    assert b.nrmse == pytest.approx(a.nrmse, rel=0.1)
    assert b.band_errors is not None and np.isfinite([r.rms_m for r in b.band_errors]).all()
    assert np.isfinite([b.max_error_m, b.model_band_coverage]).all()
    # two trials on inputs of their own: each predicted on its own, each its own band
    other = held_out(0.8 * steps_pa(), source="steps_low.csv", seed=12, n_trials=2)
    own = Dataset(time_s=full.time_s, input=np.concatenate([full.input[:2], other.input]),
                  position_m=np.concatenate([full.position_m[:2], other.position_m]),
                  trial_ids=np.arange(4), metadata=full.metadata, source="own.csv")
    e = validate(tree, own, n_draws=100, seed=0).experiments[0]
    assert e.low_m.shape == (4, own.n_samples) and e.prediction_m.shape == (own.n_samples,)
    assert 0.8 <= e.band_coverage <= 0.97
    assert e.noise_floor_m is not None and e.rmse_m < 1.5 * e.noise_floor_m
    assert any("their own inputs" in n for n in e.notes)
    assert e.to_dict()["predictive_band"]["low_m"][3][0] == pytest.approx(e.low_m[3, 0])


# ----------------------------------------------------------------------------- the report


def test_the_figures_shade_what_was_not_observed():
    full, gappy = lagged_pair()
    x = pb.simulate(pb.Model(), None, full.input[0], time_s=full.time_s)[0]

    def shaded(fig) -> int:
        return sum(1 for ax in fig.axes for patch in ax.patches
                   if np.allclose(patch.get_facecolor()[:3], float(GAP_COLOUR)))

    assert shaded(plot_comparison(full, x)) == 0
    # five gaps, shaded on the positions and on the residual
    assert shaded(plot_comparison(gappy, x)) == 2 * 5
    resid = gappy.mean_position_m - x  # NaN in the gaps
    plot_residual(gappy.time_s, resid, 1e-4, 1e-5, "residual.png")
    assert Path("residual.png").stat().st_size > 0


# ----------------------------------------------------------------------------- diagnosis


@pytest.mark.slow
def test_diagnose_a_record_with_samples_removed_as_the_complete_one():
    full, gappy = lagged_pair()
    settings = DiagnoseSettings(candidates=("regulator_lag", "coulomb_friction",
                                            "cubic_stiffness"), discrepancy=False)
    a, b = (diagnose(d, seed=0, settings=settings) for d in (full, gappy))
    assert a.missing == b.missing == "regulator_lag"
    ea, eb = a.experiments[0], b.experiments[0]
    print(f"\ngaps (5% removed) against complete: RMS {eb.rms_m * 1e6:.1f} / "
          f"{ea.rms_m * 1e6:.1f} um, floor {eb.noise_floor_m * 1e6:.2f} / "
          f"{ea.noise_floor_m * 1e6:.2f} um, energy {eb.signature.energy:.3g} / "
          f"{ea.signature.energy:.3g}, score {b.ranking[0].evidence:.4g} / "
          f"{a.ranking[0].evidence:.4g}")
    assert eb.rms_m == pytest.approx(ea.rms_m, rel=0.03)
    assert eb.noise_floor_m == pytest.approx(ea.noise_floor_m, rel=0.05)
    assert eb.signature.energy == pytest.approx(ea.signature.energy, rel=0.1)
    assert b.ranking[0].evidence == pytest.approx(a.ranking[0].evidence, rel=0.1)
    lag_a, lag_b = (d.ranking[0].refit for d in (a, b))
    assert lag_b.values["tau_reg"] == pytest.approx(lag_a.values["tau_reg"], rel=0.02)
    assert lag_b.rms_m < 1.25 * eb.noise_floor_m


@pytest.mark.slow
def test_diagnose_trials_with_their_own_inputs_and_an_estimated_start():
    """Trials on measured inputs of their own: the hidden friction is found. A record
    that starts mid-loop, its start estimated: the right model is adequate there (the
    criticism simulates it from its estimated start, not from rest)."""
    settings = DiagnoseSettings(candidates=("coulomb_friction", "cubic_stiffness"),
                                discrepancy=False)
    own = generate_chirp_dataset(n_trials=4, seed=11, chirp=Chirp(duration_s=2.0, f0_hz=0.3,
                                                                   f1_hz=2.0),
                                 regulator=Regulator(), effects={"coulomb_friction": {"F_c": 0.8}})
    d = diagnose(own, seed=0, settings=settings)
    assert d.missing == "coulomb_friction"
    e = d.experiments[0]
    raw = own.noise_floor_m
    assert e.noise_floor_m < 0.5 * raw  # the floor of the residuals, not of the inputs
    assert d.ranking[0].refit.rms_m < 1.25 * e.noise_floor_m
    rate = 500.0
    t = np.arange(int(5 * rate)) / rate
    p = 0.2e6 * (1 - np.cos(2 * np.pi * 0.5 * t)) + 0.05e6 * np.sin(2 * np.pi * 1.3 * t) ** 2
    x = pb.simulate(pb.Model(), None, p, time_s=t)[0]
    y = MeasurementNoise().apply(np.repeat(x[None], 3, axis=0), 1 / rate,
                                 np.random.default_rng(3))
    tail = Dataset(time_s=t[1000:], input=np.tile(p[1000:], (3, 1)), position_m=y[:, 1000:],
                   trial_ids=np.arange(3), source="tail.csv",
                   metadata={"sample_rate_hz": rate, "initial_state": "estimate"})
    s = diagnose(tail, seed=0, settings=settings)
    assert s.adequate, s.verdict
    assert s.experiments[0].rms_m < 1.25 * s.experiments[0].noise_floor_m


@pytest.mark.slow
def test_the_command_line_criticises_records_with_gaps(tmp_path, capsys):
    full, gappy = lagged_pair()
    save(gappy, tmp_path / "gappy.csv")
    held_seen = blocks_seen(full.n_samples, every=400)
    save(with_gaps(lagged_pair(seed=12)[0], held_seen, "held.csv"), tmp_path / "held.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        assert main(["diagnose", str(tmp_path / "gappy.csv"), "--candidates",
                     "regulator_lag,coulomb_friction", "--effects", "regulator_lag",
                     "--quiet", "--json", str(tmp_path / "d.json")]) == 0
        out = capsys.readouterr().out
        assert "adequate: yes" in out
        assert main(["run", str(tmp_path / "gappy.csv"), "--effects", "regulator_lag",
                     "--steps", "400", "--quiet", "--out", str(tmp_path / "run")]) == 0
        out = capsys.readouterr().out
        assert "Model adequate" in out and (tmp_path / "run" / "index.html").is_file()
        assert main(["validate", str(tmp_path / "run" / "fit.nc"), str(tmp_path / "held.csv"),
                     "--draws", "50", "--quiet", "--out", str(tmp_path / "val")]) == 0
    out = capsys.readouterr().out
    assert "held: 3 trial(s)" in out and (tmp_path / "val" / "index.html").is_file()
