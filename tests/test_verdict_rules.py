"""The rule that names a missing effect (or a partial step), and the words and numbers
that report it: built from result objects directly, so that each rule is checked in
milliseconds, plus the pieces under them (the ELPD's standard error on one record, the
noise floor of a periodic record, the formatter of numbers side by side)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from pmabayes.criticism.adequacy import check_adequacy
from pmabayes.criticism.bands import band_errors
from pmabayes.criticism.elpd import paired_difference
from pmabayes.criticism.prose import elpd_short, elpd_text, verdict_text
from pmabayes.criticism.refits import (
    improves,
    missing_effect,
    partial_effect,
    ranking_key,
    refit_failure,
)
from pmabayes.criticism.results import Refit
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.data import Dataset
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.model import Model
from pmabayes.util import format_together

S = DiagnoseSettings()


def _sig(rms_m: float, floor_m: float = math.nan, energy: float = 3.0) -> SimpleNamespace:
    band = SimpleNamespace(rms_m=rms_m, floor_m=floor_m)
    return SimpleNamespace(bands=[band], ratio=rms_m / floor_m, energy=energy, energy_p=0.0,
                           ljung_box_p=0.0, is_adequate=lambda *_: False)


def _refit(effect: str, diff: float, se: float, explained: float, *, floor_m=math.nan,
           rms_m: float = 5e-4, explained_rms=None, failed=None) -> Refit:
    return Refit(effect=effect, values={}, interval={}, rms_m=rms_m, explained=explained,
                 elpd=1000.0 + diff, elpd_diff=diff, elpd_diff_se=se,
                 contribution_m=np.zeros(3), signatures=(_sig(rms_m, floor_m),),
                 explained_rms=explained_rms, failed=failed)


def _verdict(refits: dict, *, floor_m=math.nan, rms_m=6e-4) -> tuple[str, str | None]:
    """The verdict and the partial step, as diagnose makes them (findings in the list's
    order)."""
    missing = missing_effect(refits, S)
    partial = partial_effect(refits, missing)
    findings = [SimpleNamespace(effect=r.effect, refit=r, significant=True, p_value=1e-9)
                for r in sorted(refits.values(), key=ranking_key)]
    exp = SimpleNamespace(name="d", signature=_sig(rms_m, floor_m), adequate=False,
                          floor_note=lambda: "")
    return verdict_text("base", (), (exp,), False, missing, refits, findings, 0.9, None,
                        partial), partial


def test_without_a_floor_the_step_rests_on_the_elpd_and_a_worse_refit_is_never_best():
    """The real record's verdict said "the best refit (regulator_second_order) removes only
    100% of the whitened residual's excess energy, and at least 90% is required (ΔELPD
    -440.0 ± 0.0)" while regulator_lag, above it in the list, had ΔELPD +1062.9."""
    refits = {"regulator_second_order": _refit("regulator_second_order", -440.0, 30.0, 1.0),
              "regulator_lag": _refit("regulator_lag", 1062.9, 40.0, 0.5)}
    text, partial = _verdict(refits)
    assert missing_effect(refits, S) is None  # no floor: the share says nothing
    assert partial == "regulator_lag"
    assert "regulator_lag adds a partial improvement" in text
    assert "cannot tell whether a candidate accounts for all of the misfit" in text
    assert "--effects regulator_lag" in text and "ΔELPD +1062.9 ± 40.0" in text
    assert "best" not in text and "100%" not in text and "required" not in text
    # nothing predicts better: the list's first is named as such, never "best"
    worse = {"regulator_second_order": _refit("regulator_second_order", -440.0, 30.0, 1.0),
             "regulator_lag": _refit("regulator_lag", -12.0, 40.0, 0.5)}
    text, partial = _verdict(worse)
    assert partial is None and "best" not in text
    assert "the top-ranked refit, regulator_lag, has ΔELPD -12.0 ± 40.0" in text
    assert "no candidate is named" in text


def test_a_clear_partial_improvement_is_named_as_a_step_not_as_adequate():
    """The force rig: position_offset removed 78% of the excess with a clear ELPD gain and
    was not named because the rule asks for 90%."""
    floor = 1e-4
    refits = {"position_offset": _refit("position_offset", 500.0, 50.0, 0.78, floor_m=floor,
                                        rms_m=1.5e-4, explained_rms=0.78),
              "bouc_wen_exponent": _refit("bouc_wen_exponent", 30.0, 40.0, 0.9,
                                          floor_m=floor, rms_m=1.9e-4, explained_rms=0.2)}
    text, partial = _verdict(refits, floor_m=floor, rms_m=2e-4)
    assert missing_effect(refits, S) is None and partial == "position_offset"
    assert ("position_offset adds a partial improvement: adding it lowers the RMS error to "
            "150 µm (1.5x the floor) and removes 78% of the mean-square error above the "
            "floor, yet the error is still 1.5x the floor") in text
    assert "Next: add it (--effects position_offset) and diagnose again" in text
    assert "adequate" not in text.split("(")[0]
    # one that accounts for the misfit is missing, and then there is no partial step
    full = {"position_offset": _refit("position_offset", 500.0, 50.0, 0.95, floor_m=floor)}
    assert missing_effect(full, S) == "position_offset"
    assert partial_effect(full, "position_offset") is None


def test_one_ranking_everywhere():
    """The verdict called bouc_wen_exponent the best refit (by its energy share) while the
    list ranked pressure_hysteresis first (+704 against +258)."""
    refits = {"bouc_wen_exponent": _refit("bouc_wen_exponent", 258.0, 200.0, 0.85),
              "pressure_hysteresis": _refit("pressure_hysteresis", 704.0, 400.0, 0.3)}
    assert [r.effect for r in sorted(refits.values(), key=ranking_key)] == [
        "pressure_hysteresis", "bouc_wen_exponent"]
    text, partial = _verdict(refits)
    assert partial is None  # neither gain is above two standard errors
    assert "the top-ranked refit, pressure_hysteresis, has ΔELPD +704.0 ± 400.0" in text
    assert "bouc_wen_exponent" not in text


def test_standard_errors_are_real_or_absent_and_a_failed_refit_has_no_number():
    # one left-out unit: no spread, so no standard error (it was 0.0, "± 0.0")
    diff, se = paired_difference(np.array([-5.0]), np.array([-10.0]))
    assert diff == 5.0 and math.isnan(se)
    assert paired_difference(np.array([1.0, 3.0]), np.zeros(2)) == (
        4.0, pytest.approx(math.sqrt(2.0)))
    lone = _refit("regulator_lag", 1062.9, math.nan, 0.5)
    assert "ΔELPD +1062.9 ± n/a (one left-out unit" in elpd_text(lone)
    assert elpd_short(lone) == "+1062.9 ± n/a" and not improves(lone)
    js = lone.to_dict()
    assert js["elpd_diff_se"] is None and js["elpd_diff_se_note"].startswith("one left-out")
    # a search that ends below the model it holds has failed: no ΔELPD, never named
    why = refit_failure(-1000.0, -1.6e8, "regulator_second_order")
    assert why is not None and "below the model without regulator_second_order" in why
    assert refit_failure(-1000.0, -999.5, "x") is None and refit_failure(-1e3, -1e3 - 0.5,
                                                                          "x") is None
    failed = _refit("regulator_second_order", -158538350.9, 2.0, 1.0, failed=why)
    assert elpd_text(failed).startswith("refit failed (its search ended")
    assert "158538350" not in elpd_text(failed) and elpd_short(failed) == "refit failed"
    assert failed.to_dict()["failed"] == why
    good = _refit("regulator_lag", 40.0, 10.0, 0.2)
    assert ranking_key(failed) > ranking_key(good)  # a failed refit ranks last
    assert partial_effect({"a": failed, "regulator_lag": good}) == "regulator_lag"


def test_one_record_has_stretches_to_leave_out():
    """The ELPD of a single record leaves out one stretch at a time, given the rest: under
    white noise the stretches are independent, so their terms add up to the record's."""
    rng = np.random.default_rng(3)
    n = 400
    t = np.arange(n) * 1e-3
    y = 0.01 + 1e-3 * np.sin(2 * np.pi * 2 * t) + 1e-5 * rng.standard_normal(n)
    ds = Dataset(time_s=t, input=np.full((1, n), 2e5), position_m=y[None],
                 trial_ids=np.arange(1), input_name="pressure_pa", source="one.csv")
    lik = Likelihood(Model(), ds)
    x = np.stack([np.full(n, 0.01), np.full(n, 0.0101)])
    parts = lik.stretch_pointwise(x, 1e-7, 0.0, 1e-3, 10)
    assert parts.shape == (2, 10)
    assert parts.sum(axis=1) == pytest.approx(lik.pointwise(x, 1e-7, 0.0, 1e-3)[:, 0],
                                              rel=1e-9)
    # correlated noise: the stretches are predicted from their neighbours, so more
    corr = lik.stretch_pointwise(x, 1e-3, 0.99, 1e-5, 10)
    assert np.all(corr.sum(axis=1) > lik.pointwise(x, 1e-3, 0.99, 1e-5)[:, 0])
    two = Dataset(time_s=t, input=np.full((2, n), 2e5), position_m=np.stack([y, y]),
                  trial_ids=np.arange(2), input_name="pressure_pa", source="two.csv")
    assert Likelihood(Model(), two).stretch_pointwise(x, 1e-5, 0.0, 1e-5, 10) is None


def test_a_periodic_record_has_one_floor_in_fit_diagnose_and_the_verdict():
    """``fit`` reported no noise floor on a declared periodic record while ``diagnose``
    gave one."""
    rng = np.random.default_rng(5)
    period, n_per = 100, 4
    t = np.arange(n_per * period) * 1e-3
    u = 2e5 + 1e5 * np.sin(2 * np.pi * t / (period * 1e-3))
    y = 0.01 + 1e-3 * np.sin(2 * np.pi * t / (period * 1e-3)) + 1e-5 * rng.standard_normal(
        t.size)
    ds = Dataset(time_s=t, input=u[None], position_m=y[None], trial_ids=np.arange(1),
                 input_name="pressure_pa", source="periodic.csv",
                 metadata={"period_samples": period, "starts_in_steady_state": True})
    lik = Likelihood(Model(), ds)
    x = 0.01 + 1e-3 * np.sin(2 * np.pi * t / (period * 1e-3))
    floor = band_errors(ds, x, bands_hz=())[-1].floor_m  # diagnose's
    assert math.isfinite(floor) and floor == pytest.approx(1e-5, rel=0.3)
    assert lik.periods_noise_floor_m == pytest.approx(floor, rel=1e-9)  # the fit file's
    verdict = check_adequacy(lik, x, SimpleNamespace(sigma=1e-5, rho=0.0, white=1e-6))
    assert verdict.floor_m == pytest.approx(floor, rel=1e-9)  # the fit's verdict
    assert "noise floor" in verdict.evidence() and "no repeats" not in verdict.evidence()


def test_numbers_side_by_side_show_their_ratio():
    """"RMS error 0.1 µm (noise floor 0.1 µm)" where the ratio was 1.98."""
    rms, floor = format_together(0.0988, 0.0499)
    assert rms != floor and float(rms) / float(floor) == pytest.approx(1.98, rel=0.01)
    one, other = format_together(1004.0, 998.0, digits=1)
    assert one != other
    assert format_together(1.0, 1.0000001) == ["1", "1"]  # equal to 0.1%: printed equal
    assert format_together(553.3, math.nan, digits=4) == ["553.3", "nan"]


def test_the_signature_figure_omits_a_floor_that_is_not_finite():
    from pmabayes.report.figures import criticism as figs

    n = 200
    t = np.arange(n) * 1e-3
    ds = Dataset(time_s=t, input=np.full((1, n), 2e5), position_m=0.01 + 1e-4 * np.sin(t)[None],
                 trial_ids=np.arange(1), input_name="pressure_pa", source="one.csv")
    sim = SimpleNamespace(position_m=np.full((1, n), 0.01), velocity_m_s=np.zeros((1, n)),
                          pressure_pa=np.full((1, n), 2e5))
    fig = figs.plot_residual_signature(ds, sim, np.ones(n))
    assert "nan" not in fig._suptitle.get_text() and "no noise floor" in fig._suptitle.get_text()
    fig = figs.plot_residual_signature(ds, sim, np.ones(n), floor_m=5e-5)
    assert "±50 µm" in fig._suptitle.get_text()


def test_a_proposal_its_own_refit_makes_worse_is_not_advised():
    """The force rig's verdict said "To add it: ... proposed_shape_v" while the proposal's
    own refit was 5.52x the floor, worse than without it."""
    from pmabayes.criticism.discrepancy.estimate import _text

    verified = {"rms_m": 5.52e-4, "ratio": 5.52, "energy": 30.0, "ljung_box_p": 0.0,
                "adequate": False, "values": {}}
    proposal = SimpleNamespace(description="a force in v", expression="c v",
                               verified=verified, plugin="proposed_shape_v.py",
                               effect="proposed_shape_v")
    state = SimpleNamespace(state="velocity", needed=True, elpd_loss=50.0, se=5.0)
    args = ([state], 0.5, 0.5, 2.0, "2x the floor", 100.0, 10.0, proposal, None, "d.csv", ())
    worse = _text(*args, "left-out trials", 3.1e-4)
    assert "To add it" not in worse and "it is not advised" in worse
    assert "RMS error 552 µm against 310 µm" in worse
    better = _text(*args, "left-out trials", 9e-4)
    assert "To add it: pmabayes --plugin proposed_shape_v.py" in better


def test_an_adequate_verdict_says_a_failed_refit_once():
    # the score test flags an effect whose refit failed, on an adequate model: the words
    # say "refit failed" once, never "refit refit failed"
    why = refit_failure(-1000.0, -1015.3, "force_length_map")
    failed = _refit("force_length_map", -15.3, 2.0, 0.0, failed=why)
    findings = [SimpleNamespace(effect="force_length_map", refit=failed, significant=True,
                                p_value=2e-11)]
    exp = SimpleNamespace(name="d", signature=_sig(1e-3, 1e-3, energy=1.0), adequate=True,
                          floor_note=lambda: "")
    text = verdict_text("base", (), (exp,), True, None, {"force_length_map": failed},
                        findings, 0.9, None, None)
    assert "force_length_map (p = 2e-11, refit failed (its search ended" in text
    assert "refit refit" not in text
