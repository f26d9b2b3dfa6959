"""The user's loop on data like real measurements: a force-input record whose
candidates cannot all act on it, estimates outside their physical range, a record without
repeats for the data-driven discrepancy, and the fit summary's MAP and paper columns.
Everything here is synthetic.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import fake_fit

from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.plausibility import implausible, plausible_range
from pmabayes.criticism.refits import missing_effect
from pmabayes.criticism.results import Refit
from pmabayes.criticism.scores import rank_effects
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.noise import NoiseEstimate
from pmabayes.model.model import Model, Rig
from pmabayes.report.summary import map_note, summary_table
from pmabayes.synthetic import Chirp, HiddenDrag, MeasurementNoise, generate_chirp_dataset


def force_record(n_trials: int = 3, duration_s: float = 3.0):
    """The Bouc-Wen oscillator rig, driven by a force chirp of +-60 N."""
    return generate_chirp_dataset(
        n_trials=n_trials, seed=0, rig=Rig.force_oscillator(2.0),
        chirp=Chirp(duration_s=duration_s, p_min_pa=-60.0, p_max_pa=60.0, f0_hz=0.2,
                    f1_hz=2.0),
        noise=MeasurementNoise(disturbance_std_m=20e-6), description="force oscillator")


def test_a_force_effect_that_cannot_act_is_left_out_with_its_reason():
    """Fails on the code that raised numpy.linalg.LinAlgError here (mckibben_force's
    sensitivity is zero on a force below its fixed p_mck)."""
    ds = force_record()
    model = Model(rig=Rig.force_oscillator(2.0))
    lik = Likelihood(model, ds)
    noise = NoiseEstimate(20e-6, math.exp(-1e-3 / 0.1), 6e-6, None, None)
    ranked = rank_effects(lik, noise, model.defaults,
                          candidates=["mckibben_force", "cubic_stiffness", "regulator_lag"])
    assert [e.effect for e in ranked][-1] == "mckibben_force"
    left = ranked[-1]
    assert left.left_out.startswith("cannot act on these data") and "p_mck" in left.left_out
    assert "force_n spans" in left.left_out
    assert not left.significant and math.isnan(left.statistic)
    assert all(e.left_out is None and math.isfinite(e.statistic) for e in ranked[:-1])


def test_diagnose_runs_on_a_force_record_with_the_default_candidates():
    """Fails on the code where the LinAlgError escaped diagnose on every force record."""
    d = diagnose(force_record(), settings=DiagnoseSettings(max_refits=0), seed=0)
    out = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    rows = {r["effect"]: r for r in out["ranking"]}
    assert rows["mckibben_force"]["left_out"].startswith("cannot act on these data")
    assert rows["mckibben_force"]["evidence"] is None
    assert "Left out of the score tests" in rows["mckibben_force"]["explanation"]
    assert out["ranking"][-1]["effect"] == "mckibben_force"
    assert out["experiments"][0]["baselines"]["linear"]["order"] >= 1


def test_plausible_ranges_from_the_prior_the_bounds_and_the_data():
    m = Model(["position_offset", "bouc_wen_exponent", "regulator_lag",
               "regulator_second_order"])
    ds = generate_chirp_dataset(n_trials=2, seed=0, chirp=Chirp(duration_s=1.0))
    # the prior's central 1 - 1e-6 of Normal(1, 0.1), inside its domain n_bw >= 0
    assert plausible_range(m, "n_bw") == pytest.approx((0.511, 1.489), abs=1e-3)
    lo, hi = plausible_range(m, "x_offset", [ds])
    assert hi == pytest.approx(-lo) == pytest.approx(2 * np.max(np.abs(ds.position_m)))
    text = implausible(m, {"n_bw": -2.65, "x_offset": -71.9, "tau_reg": 0.045},
                       ["n_bw", "x_offset", "tau_reg"], [ds])
    assert "n_bw = -2.65 lies outside" in text and "x_offset = -71.9 m lies outside" in text
    assert "tau_reg" not in text
    # the null (the effect vanishing) is plausible; a refit run to a bound is not
    assert implausible(m, {"tau_reg": 0.0, "tau_n": 1e-7}, ["tau_reg", "tau_n"]) is None
    # priors own the support: zeta_reg's only bound is 0, outside its plausible range
    assert "zeta_reg = 1e-09 lies outside" in implausible(m, {"zeta_reg": 1e-9}, ["zeta_reg"],
                                                          refit=True)
    assert implausible(m, {"zeta_reg": 14.1}, ["zeta_reg"], refit=True) is None


def test_an_implausible_refit_is_never_named_missing():
    s = DiagnoseSettings()
    good = dict(values={}, interval={}, rms_m=1e-5, explained=1.0, elpd=10.0, elpd_diff=50.0,
                elpd_diff_se=1.0, contribution_m=np.zeros(3))
    refits = {"bouc_wen_exponent": Refit(effect="bouc_wen_exponent", **good,
                                         implausible="n_bw = 1.5 ran to its bound"),
              "regulator_lag": Refit(effect="regulator_lag", **{**good, "elpd": 5.0})}
    assert missing_effect(refits, s) == "regulator_lag"
    del refits["regulator_lag"]
    assert missing_effect(refits, s) is None


def test_one_step_estimates_outside_their_range_are_called_implausible():
    """A base model missing a 45 ms lag: the exponent's one-step estimate runs negative."""
    ds = generate_chirp_dataset(n_trials=3, seed=1, chirp=Chirp(duration_s=4.0),
                                effects={"regulator_lag": 0.045})
    d = diagnose(ds, settings=DiagnoseSettings(
        candidates=("bouc_wen_exponent", "regulator_lag"), max_refits=0, discrepancy=False),
        seed=0)
    m = Model(["bouc_wen_exponent"])
    for f in d.ranking:
        lo, hi = (plausible_range(m, "n_bw") if f.effect == "bouc_wen_exponent"
                  else (0.0, 1.0))
        outside = any(not lo <= v <= hi for v in f.estimate.values())
        assert (f.implausible is not None) == outside, (f.effect, f.estimate)
        if outside:
            assert "Implausible, not a finding" in f.explanation
    assert any(f.implausible for f in d.ranking)


@pytest.mark.slow
def test_the_discrepancy_step_runs_on_a_record_without_repeats():
    """Fails on the code where cubic_stiffness was named missing though its refit
    removed 0% of the excess (the refit's own noise took the rest in, and its adequacy
    counted), and the discrepancy step refused a record without repeats. A single 6 s
    record with a quadratic drag that no library holds; its noise is identified with
    the model."""
    ds = generate_chirp_dataset(n_trials=1, seed=0, chirp=Chirp(duration_s=6.0),
                                effects={HiddenDrag: {"c_hidden": 300.0}})
    d = diagnose(ds, settings=DiagnoseSettings(candidates=(
        "regulator_lag", "coulomb_friction", "cubic_stiffness", "stribeck_friction")), seed=0)
    # no floor: nothing is "missing"; a clear held-out gain is at most a partial step
    assert d.missing is None and "after it" not in d.verdict and "best" not in d.verdict
    assert ("adds a partial improvement" in d.verdict) is (d.partial is not None)
    assert d.discrepancy is not None
    assert d.discrepancy.states[0].state == "velocity" and d.discrepancy.states[0].needed
    assert "left-out stretches" not in d.discrepancy.text  # the gain is significant
    assert d.discrepancy.proposal is not None and "v|v|" in d.discrepancy.proposal.expression
    coef = d.discrepancy.proposal.terms[0]["coefficient"]
    assert coef == pytest.approx(300.0, rel=0.1)
    out = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    assert out["discrepancy"]["ratio_after"] is None and out["discrepancy"]["energy_after"] > 0


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # a noise held constant
def test_the_summary_labels_its_map_and_adds_the_highest_density_draw():
    tree = fake_fit()
    info = json.loads(tree.attrs["pmabayes"])
    info["map"]["values"]["alpha"] = 741.0  # far outside the posterior, as a real fit did
    tree.attrs["pmabayes"] = json.dumps(info)
    rows = {r["name"]: r for r in summary_table(tree)}
    assert not rows["alpha"]["hdi_low"] <= rows["alpha"]["map"] <= rows["alpha"]["hdi_high"]
    assert "alpha" in map_note(list(rows.values()))
    lp = tree["sample_stats"]["lp"].values
    c, k = np.unravel_index(np.argmax(lp), lp.shape)
    for name, r in rows.items():
        assert r["best_draw"] == float(tree["posterior"][name].values[c, k])
        assert r["hdi_low"] <= r["best_draw"] <= r["hdi_high"] or name == "sigma_noise_m"
    assert rows["alpha"]["paper"] is not None  # the characterisation rig: the paper's rig


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # a noise held constant
def test_the_paper_column_only_beside_the_papers_rig():
    tree = fake_fit()
    info = json.loads(tree.attrs["pmabayes"])
    for rig in (info["model"], *info["experiments"]):
        rig["rig"] = Rig.force_oscillator(2.0).to_dict()
    tree.attrs["pmabayes"] = json.dumps(info)
    assert all(r["paper"] is None for r in summary_table(tree))
