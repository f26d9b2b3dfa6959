"""pmabayes design: the next experiment that tells candidate effects apart.

A regulator's lag and a transport delay of ~30 ms are indistinguishable on a slow,
small chirp (both are a phase lag there); a design must find an input that separates
them, and score it above repeating the first input.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from pmabayes.data import read_columns
from pmabayes.design import DesignError, design, write_design_files
from pmabayes.design.experiments import FAMILIES, candidate_experiments, input_range
from pmabayes.design.fits import CandidateFit
from pmabayes.design.score import discrimination
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.search import MapResult
from pmabayes.model.model import Model
from pmabayes.synthetic import Chirp, generate_chirp_dataset

PAIR = ["regulator_lag", "transport_delay"]
RANGE = (0.0, 5e5)


@pytest.fixture(scope="module")
def first():
    """A small, slow first experiment (0.1-0.5 Hz, 100-160 kPa) of a 30 ms regulator lag."""
    chirp = Chirp(f0_hz=0.1, f1_hz=0.5, duration_s=6.0, p_min_pa=1.0e5, p_max_pa=1.6e5,
                  sample_rate_hz=200.0)
    return generate_chirp_dataset(n_trials=4, seed=3, chirp=chirp,
                                  effects={"regulator_lag": 0.03})


@pytest.fixture(scope="module")
def fits(first):
    # the two twins fitted on the first experiment (the package's MAP and Laplace
    # covariance, about 10 s): they agree there, a 30 ms lag and a delay of about 26 ms
    from pmabayes.design import fit_candidate

    return {name: fit_candidate([first], [name], name, rng=np.random.default_rng(0))
            for name in PAIR}


@pytest.fixture(scope="module")
def result(first, fits):
    return design(first, [], PAIR, input_range=RANGE, n_experiments=8, n_draws=16, seed=1,
                  fits=fits)


def test_designed_experiment_beats_repeating_the_first(result):
    repeat = result.score_of("repeat")
    chosen = result.scores[result.chosen]
    assert result.experiment.family != "repeat"
    # repeating the slow small chirp cannot tell them apart; the design can, by more
    # than the Monte Carlo error of either score
    assert chosen["score"] - repeat["score"] > 3 * (chosen["mc_se"] + repeat["mc_se"])
    assert chosen["named_rate"] > repeat["named_rate"]
    assert repeat["named_rate"] < 0.8


def test_scores_have_finite_monte_carlo_errors(result):
    for s in result.scores:
        assert math.isfinite(s["score"]) and math.isfinite(s["mc_se"]) and s["mc_se"] > 0
        assert 0.0 < s["named_rate_mc_se"] < 0.5


def test_same_seed_same_numbers(first, fits, result):
    again = design(first, [], PAIR, input_range=RANGE, n_experiments=8, n_draws=16, seed=1,
                   fits=fits)
    assert [s["score"] for s in again.scores] == [s["score"] for s in result.scores]
    other = design(first, [], PAIR, input_range=RANGE, n_experiments=8, n_draws=16, seed=2,
                   fits=fits)
    assert [s["score"] for s in other.scores] != [s["score"] for s in result.scores]


def test_outputs_are_written_and_next_csv_round_trips(result, tmp_path):
    names = write_design_files(result, tmp_path)
    assert set(names) == {"next.csv", "next.json", "design.json"}
    summary = json.loads((tmp_path / "design.json").read_text())
    assert summary["pmabayes"]["kind"] == "design"
    assert summary["chosen"]["index"] == result.chosen
    assert len(summary["experiments"]) == len(result.experiments)
    assert all("mc_se" in e for e in summary["experiments"])
    sidecar = json.loads((tmp_path / "next.json").read_text())
    back = read_columns(tmp_path / "next.csv", sidecar["columns"])
    np.testing.assert_array_equal(back["time_s"], result.experiment.time_s)
    np.testing.assert_array_equal(back["pressure_pa"], result.experiment.input())
    assert RANGE[0] <= back["pressure_pa"].min() and back["pressure_pa"].max() <= RANGE[1]


def test_next_csv_in_the_users_units(result, tmp_path):
    from dataclasses import replace

    kpa = replace(result, units={"time_s": "time_ms", "pressure_pa": "pressure_kpa"})
    write_design_files(kpa, tmp_path)
    header = (tmp_path / "next.csv").read_text().splitlines()[0]
    assert header == "time_ms,pressure_kpa"
    sidecar = json.loads((tmp_path / "next.json").read_text())
    with pytest.warns(UserWarning, match="converted"):
        back = read_columns(tmp_path / "next.csv", sidecar["columns"])
    np.testing.assert_allclose(back["pressure_pa"], result.experiment.input(), rtol=1e-12)
    np.testing.assert_allclose(back["time_s"], result.experiment.time_s, rtol=1e-12,
                               atol=1e-15)


def test_page_is_written(result, tmp_path):
    from pmabayes.report.design_page import write_design

    index = write_design(result, tmp_path / "page")
    text = index.read_text()
    assert "Next experiment" in text and "design.png" not in text  # the figure embedded
    assert (tmp_path / "page" / "next.csv").exists()


def test_goal_parameters_reports_a_shrinkage_factor(first, fits):
    res = design(first, [], ["regulator_lag"], goal="parameters", parameters=["tau_reg"],
                 input_range=RANGE, n_experiments=4, n_draws=8, seed=0,
                 fits={"base+regulator_lag": fits["regulator_lag"]})
    chosen = res.scores[res.chosen]
    assert chosen["factor"] >= 1.0 and math.isfinite(chosen["mc_se"])
    assert set(chosen["factors"]) == {"tau_reg"}


# -- bad input: one clear line each, before any fit -----------------------------------


def test_fewer_than_two_candidates(first):
    with pytest.raises(DesignError, match="at least two"):
        design(first, [], ["regulator_lag"], input_range=RANGE)


def test_candidate_that_cannot_act_is_left_out_and_too_few_remain(first):
    # a second hysteresis law cannot join a model that has one
    with pytest.raises(DesignError, match="fewer than two candidates can act.*"
                       "bouc_wen_baber_noori cannot be added"):
        design(first, ["bouc_wen_exponent"], ["bouc_wen_baber_noori", "regulator_lag"],
               input_range=RANGE)


def test_input_range_is_required_and_kept_inside_the_rigs(first):
    with pytest.raises(DesignError, match="input range is not known"):
        design(first, [], PAIR)
    with pytest.raises(DesignError, match="beyond the rig's declared"):
        input_range([first], (0.0, 8e5), declared=(0.0, 6e5))
    with pytest.raises(DesignError, match="not a range"):
        design(first, [], PAIR, input_range=(5e5, 0.0))
    assert input_range([first], (1e5, 2e5), declared=(0.0, 6e5)) == (1e5, 2e5)


def test_a_candidate_that_cannot_act_is_left_out_with_its_reason(first):
    # the base's hysteresis law is the paper's Bouc-Wen; a second law cannot join a
    # model that already has one (bouc_wen_exponent in the base)
    base = ["bouc_wen_exponent"]
    res = design(first, base, [*PAIR, "bouc_wen_baber_noori"], input_range=RANGE,
                 n_experiments=3, n_draws=8, seed=0)
    assert set(res.left_out) == {"bouc_wen_baber_noori"}
    assert "cannot be added" in res.left_out["bouc_wen_baber_noori"]
    assert res.candidates == PAIR
    assert any("left out bouc_wen_baber_noori" in line for line in res.lines())


def test_the_sidecars_input_range_bounds_the_design(first, fits):
    from dataclasses import replace

    declared = replace(first, metadata={**first.metadata, "input_range": [0.0, 4e5]})
    with pytest.raises(DesignError, match=r"beyond the rig's declared 0 to 400000 Pa"):
        design(declared, [], PAIR, input_range=RANGE, fits=fits)
    res = design(declared, [], PAIR, n_experiments=3, n_draws=8, seed=0, fits=fits)
    assert res.settings["input_range"] == [0.0, 4e5]
    assert all(e.input().max() <= 4e5 + 1e-6 for e in res.experiments)
    broken = replace(first, metadata={**first.metadata, "input_range": "0 to 4e5"})
    with pytest.raises(DesignError, match="give two numbers"):
        design(broken, [], PAIR, fits=fits)


def test_budget_too_small(first):
    with pytest.raises(DesignError, match="too short to score anything"):
        design(first, [], PAIR, input_range=RANGE, duration_s=0.05)
    with pytest.raises(DesignError, match="n_draws"):
        design(first, [], PAIR, input_range=RANGE, n_draws=2)


# -- the pieces ----------------------------------------------------------------------


def test_experiments_stay_in_range_and_budget():
    rng = np.random.default_rng(0)
    exps = candidate_experiments(rng, 12, low=1e5, high=3e5, duration_s=4.0,
                                 sample_rate_hz=100.0, loads=(0.0, 0.5),
                                 first_input=np.full(400, 2e5))
    assert [e.family for e in exps[:2]] == ["repeat", "default_chirp"]
    assert set(FAMILIES) <= {e.family for e in exps}
    for e in exps:
        u = e.input()
        assert u.shape == (400,) and np.all(np.isfinite(u))
        assert 1e5 - 1e-6 <= u.min() and u.max() <= 3e5 + 1e-6
        assert e.load_kg in (0.0, 0.5)


def test_discrimination_of_twins_and_of_separated_models():
    rng = np.random.default_rng(0)
    n = 200
    same = [rng.normal(0, 0.1, (16, n)) for _ in range(2)]
    twins = discrimination(same, [rng.normal(0, 0.1, (16, n)) for _ in range(2)],
                           np.random.default_rng(1))
    assert abs(twins.score) < 1.0 and 0.3 < twins.named_rate < 0.7
    apart = discrimination([same[0], same[1] + 1.0],
                           [rng.normal(0, 0.1, (16, n)), rng.normal(1.0, 0.1, (16, n))],
                           np.random.default_rng(1))
    assert apart.named_rate == 1.0 and apart.score > 50
    assert math.isfinite(apart.score_se) and apart.named_se > 0
    assert math.isnan(apart.decisive_rate)  # one trial: no paired standard error


def test_a_decisive_naming_needs_more_than_a_higher_density():
    # two models whose means differ by |delta| (whitened mean of 4 trials), parameters
    # known: the true one has the higher density Phi(|delta| / 2) of the time, but
    # diagnose names it only where its per-trial differences, paired, sum to more than two
    # standard errors (pmabayes.criticism.elpd.paired_difference): a rate counted here
    # by brute force on independent trials
    from statistics import NormalDist

    from pmabayes.criticism.elpd import paired_difference

    rng = np.random.default_rng(0)
    n, r = 400, 4
    for size in (1.0, 3.0, 7.0):
        delta = np.full(n, size / math.sqrt(n))
        truths = [rng.normal(0, 1e-4, (64, n)), rng.normal(0, 1e-4, (64, n)) + delta]
        evidence = [rng.normal(0, 1e-4, (16, n)), rng.normal(0, 1e-4, (16, n)) + delta]
        d = discrimination(truths, evidence, np.random.default_rng(1), n_trials=r)
        assert abs(d.named_rate - NormalDist().cdf(size / 2)) < 0.08, (size, d.named_rate)
        named = []
        for _ in range(4000):  # model 0 true; one trial's noise is sqrt(R) the mean's
            y = math.sqrt(r) * rng.standard_normal((r, n))
            ll = [-0.5 * np.sum((y - m) ** 2, axis=1) / r for m in (0.0, delta)]
            diff, se = paired_difference(ll[0], ll[1])
            named.append(diff > 2.0 * se)
        brute = float(np.mean(named))
        assert abs(d.decisive_rate - brute) < 0.06, (size, d.decisive_rate, brute)
        assert d.decisive_rate <= d.named_rate and 0 < d.decisive_se < 0.1


def test_design_fits_the_candidates_itself(first):
    res = design(first, [], PAIR, input_range=RANGE, n_experiments=6, n_draws=8, seed=0)
    assert set(res.fits) == set(PAIR)
    assert res.scores[res.chosen]["score"] > res.score_of("repeat")["score"]
    # its own MAPs are checked, found at their optima, and no note says otherwise
    assert all(f.convergence["converged"] for f in res.fits.values())
    assert not any("converge" in note for note in res.notes)
    # one moved off its optimum (by a Laplace sd in every coordinate) is not
    from dataclasses import replace

    from pmabayes.design.fits import map_check

    fit = res.fits["regulator_lag"]
    sd = np.sqrt(np.diag(fit.map.covariance_z))
    off = map_check(fit.posterior, replace(fit.map, z=np.asarray(fit.map.z) + sd))
    assert not off["converged"] and off["newton_gain_nats"] > 1.0
    assert "Newton step" in off["messages"][0]


@pytest.mark.parametrize("what, extra, message", [
    ("one candidate", ["--candidates", "regulator_lag", "--input-range", "0,4e5"],
     "at least two"),
    ("no candidate can act", ["--effects", "bouc_wen_exponent", "--candidates",
                              "bouc_wen_baber_noori,regulator_lag", "--input-range", "0,4e5"],
     "fewer than two candidates can act"),
    ("beyond the rig", ["--candidates", ",".join(PAIR), "--input-range", "0,6e5"],
     "beyond the rig's declared"),
    ("no range", ["--candidates", ",".join(PAIR)], None),
    ("budget", ["--candidates", ",".join(PAIR), "--input-range", "0,4e5", "--duration",
                "0.05"], "too short to score anything"),
    ("loads without the first file's", ["--candidates", ",".join(PAIR), "--input-range",
                                        "0,4e5", "--loads", "0.3"],
     r'declare it \("conditions": \{"load_kg": 0.1\}'),
])
def test_bad_input_on_the_command_line_is_one_line_and_writes_nothing(
        first, tmp_path, capsys, what, extra, message):
    from dataclasses import replace

    from pmabayes.cli import main
    from pmabayes.data import save

    path = tmp_path / "first.csv"
    # the rig declares 0-400 kPa in the sidecar, except for the case that needs none
    meta = {**first.metadata} if what == "no range" else {**first.metadata,
                                                           "input_range": [0.0, 4e5]}
    save(replace(first, metadata=meta), path)
    out = tmp_path / "out"
    assert main(["design", "--quiet", str(path), *extra, "--out", str(out)]) == 2
    # the data file's own warnings may come first; the refusal is one line
    err = [line for line in capsys.readouterr().err.splitlines() if " error" in line]
    assert len(err) == 1 and err[0].startswith("pmabayes design: error:"), err
    assert re.search(message or "input range is not known", err[0]), err
    assert not out.exists()


def test_command_line(first, tmp_path):
    from pmabayes.cli import main
    from pmabayes.data import save

    path = tmp_path / "first.csv"
    save(first, path)
    out = tmp_path / "next"
    code = main(["design", "--quiet", str(path), "--candidates", ",".join(PAIR),
                 "--input-range", "0,500000", "--experiments", "4", "--draws", "8",
                 "--out", str(out)])
    assert code == 0
    assert {"next.csv", "next.json", "design.json", "index.html"} <= {
        p.name for p in out.iterdir()}
    assert main(["design", str(path), "--candidates", "regulator_lag", "--input-range",
                 "0,5e5", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


def test_fit_files_give_their_mcmc_draws(first, tmp_path):
    import warnings
    from dataclasses import replace

    from pmabayes.design.api import given_fits
    from pmabayes.design.fits import fit_from_file
    from pmabayes.inference.fitfile import save_fit
    from pmabayes.inference.sampler import FitSettings, fit

    settings = FitSettings(n_walkers=16, n_ensembles=1, max_steps=40, substeps=1)
    paths = []
    for name in PAIR:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a 40-step run is not converged: said, known
            tree = fit(first, Model.for_dataset(first, [name]), seed=0, settings=settings,
                       chains_dir=tmp_path / f"{name}.chains")
        paths.append(save_fit(tree, tmp_path / f"{name}.nc"))
    fits = given_fits([fit_from_file(p, [first]) for p in paths], [], PAIR)
    assert set(fits) == set(PAIR) and fits["regulator_lag"].samples_z is not None
    res = design(first, [], PAIR, input_range=RANGE, n_experiments=4, n_draws=8, seed=0,
                 fits=fits)
    assert res.fits["transport_delay"] is fits["transport_delay"]
    assert all(math.isfinite(s["score"]) for s in res.scores)
    # a 40-step run did not converge: one line per fit file says so, why it matters and
    # the fix, in the lines printed, design.json and the page
    said = [n for n in res.notes if "did NOT converge" in n]
    assert len(said) == 2, res.notes
    for name, note in zip(PAIR, sorted(said), strict=True):
        assert note.startswith(f"{name}: the fit file {tmp_path / name}.nc did NOT converge")
        assert "expected factors" in note and "--steps" in note and "\n" not in note
    assert all(f"  note: {n}" in res.lines() for n in said)
    from pmabayes.report.design_page import write_design

    write_design(res, tmp_path / "page")
    assert json.loads((tmp_path / "page" / "design.json").read_text())["notes"] == res.notes
    page = (tmp_path / "page" / "index.html").read_text()
    assert page.count("did NOT converge") == 2
    # a converged one is not noted
    done = replace(fits["regulator_lag"], convergence={"converged": True, "messages": []})
    res = design(first, [], PAIR, input_range=RANGE, n_experiments=2, n_draws=8, seed=0,
                 fits={**fits, "regulator_lag": done})
    assert [n.split(":")[0] for n in res.notes if "converge" in n] == ["transport_delay"]
    with pytest.raises(DesignError, match="no candidate model's"):
        given_fits([fits["regulator_lag"]], [], ["coulomb_friction", "transport_delay"])


# -- diagnose points at the design where its top candidates are near twins ----------


@pytest.mark.parametrize("gap, tied", [(0.3, True), (40.0, False)])
def test_diagnose_verdict_offers_the_design_for_near_twins(gap, tied):
    from types import SimpleNamespace

    from pmabayes.criticism.prose import verdict_text
    from pmabayes.criticism.refits import missing_effect, near_twins
    from pmabayes.criticism.results import Refit
    from pmabayes.criticism.settings import DiagnoseSettings

    s = DiagnoseSettings(level=0.05, level_adequate=0.01, energy_tolerance=0.1, max_refits=3,
                         min_explained=0.9, ci_prob=0.9, n_draws=400, substeps=1,
                         candidates=None)
    band = SimpleNamespace(rms_m=1e-3, floor_m=25e-6)
    signature = SimpleNamespace(bands=[band], energy=20.0, energy_p=0.0, ljung_box_p=0.0)

    def refit(effect, elpd_i):
        sig = SimpleNamespace(ratio=1.1, bands=[SimpleNamespace(rms_m=30e-6, floor_m=27e-6)])
        return Refit(effect=effect, values={}, interval={}, rms_m=30e-6, signatures=(sig,),
                     explained=0.99, elpd=float(elpd_i.sum()), elpd_diff=float(elpd_i.sum()),
                     elpd_diff_se=float(math.sqrt(elpd_i.size * np.var(elpd_i))),
                     contribution_m=np.zeros(3), elpd_i=elpd_i)

    rng = np.random.default_rng(0)
    lag = 1000.0 + rng.normal(0.0, 5.0, 6)
    refits = {"transport_delay": refit("transport_delay", lag),
              "regulator_lag": refit("regulator_lag", lag + gap + rng.normal(0.0, 2.0, 6))}
    missing = missing_effect(refits, s)
    findings = [SimpleNamespace(effect=k, refit=r) for k, r in refits.items()]
    experiment = SimpleNamespace(name="chirp", signature=signature, adequate=False,
                                 floor_note=lambda: "")
    text = verdict_text("base + coulomb_friction", ("coulomb_friction",), (experiment,), False,
                        missing, refits, findings, 0.9, near_twins(refits, missing, s),
                        data="a.csv b.csv")
    command = ("pmabayes design a.csv b.csv --effects coulomb_friction --candidates "
               "regulator_lag,transport_delay --input-range LO,HI --out next")
    assert (command in text) is tied, text
    assert ("cannot be told apart" in text) is tied


# -- the design simulates as the data were recorded ----------------------------------


def _area_first(reference: str):
    """The fixture's kind of first experiment on a rig with a 0.1 kg dead load and the
    area as a prior, its positions referred as ``reference`` says."""
    from dataclasses import replace

    from pmabayes.model.model import CARRIAGE_MASS_KG, PAPER_AREA_M2, PMA_MASS_KG, Rig

    rig = Rig(CARRIAGE_MASS_KG + PMA_MASS_KG + 0.1, 1.0, PAPER_AREA_M2, name="load_0.1kg")
    chirp = Chirp(f0_hz=0.1, f1_hz=0.5, duration_s=6.0, p_min_pa=1.0e5, p_max_pa=1.6e5,
                  sample_rate_hz=200.0)
    ds = generate_chirp_dataset(n_trials=4, seed=3, chirp=chirp, rig=rig)
    meta = {**ds.metadata, "rig": {**ds.metadata["rig"], "area_m2": "LogNormal(1e-4, 1.5)"},
            "position_reference": reference, "conditions": {"load_kg": 0.1}}
    return replace(ds, metadata=meta)


def _base_fit(ds, sd: dict[str, float] | None = None,
              at: dict[str, float] | None = None) -> CandidateFit:
    """The base model 'fitted' at the generator's values (the paper's area) or ``at``'s,
    sd 0.05 in every unconstrained coordinate but those ``sd`` names."""
    from pmabayes.model.model import PAPER_AREA_M2

    post = build_posterior(Model.for_dataset(ds), ds, substeps=1)
    truth = {**ds.metadata["generator"]["parameters"], "rig_area_m2": PAPER_AREA_M2,
             **(at or {})}
    values = {n: truth.get(n, p.quantile(0.5)) for n, p in zip(post.names, post.priors,
                                                               strict=True)}
    z = post.to_unconstrained(np.array([[values[n] for n in post.names]]))[0]
    var = np.full(z.size, 0.05**2)
    for name, s in (sd or {}).items():
        var[list(post.names).index(name)] = s**2
    return CandidateFit("base", post, MapResult(values, math.nan, math.nan, {}, math.nan, z,
                                                np.diag(var)))


def test_a_sensor_zeroed_at_the_start_is_simulated_so():
    # with "position_reference": "start" the records never see a load's static sag: the
    # design's responses are referred to their first sample, as the likelihood's are,
    # and a heavier load is not credited with the sag's information about the area
    factors = {}
    for reference in ("absolute", "start"):
        ds = _area_first(reference)
        res = design(ds, [], [], goal="parameters", parameters=["rig_area_m2"],
                     loads=(0.6,), input_range=RANGE, n_experiments=3, n_draws=8, seed=0,
                     fits={"base": _base_fit(ds)})
        start = res.predictions["base"]["map"][0]
        assert bool(start == 0.0) is (reference == "start"), start
        factors[reference] = res.score_of("default_chirp")["factors"]["rig_area_m2"]
    assert factors["absolute"] > 2 * factors["start"], factors


def test_parameter_draws_stay_inside_the_priors_support(first):
    # a dead-zone pressure near 0 with a wide Laplace sd on its identity coordinate: half
    # its draws would be negative pressures, which the simulator refuses
    post = build_posterior(Model.for_dataset(first), first, substeps=1)
    assert post.kinds[list(post.names).index("p_dz")] == "identity"
    fit = _base_fit(first, sd={"p_dz": 5e4}, at={"p_dz": 1e4})
    res = design(first, [], [], goal="parameters", parameters=["K_e"], input_range=RANGE,
                 n_experiments=3, n_draws=8, seed=0, fits={"base": fit})
    assert all(math.isfinite(s["score"]) and s["factor"] >= 1.0 for s in res.scores)


def test_data_so_far_of_several_experiments(tmp_path):
    # a joint fit's noise is one value per experiment ({experiment: value}): the design's
    # summary and page take it as the fit gives it
    from dataclasses import replace

    from pmabayes.report.design_page import write_design

    first, other = (replace(_area_first("start"), source=f"{name}.csv")
                    for name in ("first", "second"))
    post = build_posterior(Model.for_dataset(first), [first, other], substeps=1)
    one = _base_fit(first)
    theta = post.to_natural(one.map.z[None])
    values = {**one.map.values, **post.noise_values(theta[0])}
    assert isinstance(values["sigma_noise_m"], dict)
    fit = CandidateFit("base", post, replace(one.map, values=values))
    res = design([first, other], [], [], goal="parameters", parameters=["rig_area_m2"],
                 loads=(0.1, 0.5), input_range=RANGE, n_experiments=3, n_draws=8, seed=0,
                 fits={"base": fit})
    noise = res.settings["fitted"]["base"]["values"]["sigma_noise_m"]
    assert set(noise) == {"first", "second"}
    write_design(res, tmp_path)
    summary = json.loads((tmp_path / "design.json").read_text())
    assert summary["settings"]["fitted"]["base"]["values"]["sigma_noise_m"] == noise


def test_a_fit_whose_experiments_disagree_is_said_beside_the_scores(first, tmp_path):
    from dataclasses import replace

    fit = _base_fit(first)
    res = design(first, [], [], goal="parameters", parameters=["K_e"], input_range=RANGE,
                 n_experiments=2, n_draws=8, seed=0, fits={"base": fit})
    assert res.notes == [] and not any("note:" in line for line in res.lines())
    torn = replace(fit, map=replace(fit.map, agreement={"agree": False, "statistic": 4.85e4,
                                                        "df": 14}))
    res = design(first, [], [], goal="parameters", parameters=["K_e"], input_range=RANGE,
                 n_experiments=2, n_draws=8, seed=0, fits={"base": torn})
    assert len(res.notes) == 1 and "disagree" in res.notes[0] and "4.85e+04" in res.notes[0]
    assert any(line.startswith("  note: base: the experiments so far disagree")
               for line in res.lines())
    write_design_files(res, tmp_path)
    assert json.loads((tmp_path / "design.json").read_text())["notes"] == res.notes


# -- a dead load from --loads hangs in place of the first record's ---------------------


def test_a_load_replaces_the_first_records_dead_load(tmp_path):
    # the first record hangs 0.1 kg (its rig's moving mass includes it); the lab's 0.3 kg
    # weight hung instead moves 0.2 kg more, not 0.3 kg more
    from pmabayes.model.model import CARRIAGE_MASS_KG, PMA_MASS_KG

    ds = _area_first("start")
    mass = CARRIAGE_MASS_KG + PMA_MASS_KG + 0.1
    assert ds.metadata["rig"]["moving_mass_kg"] == pytest.approx(mass)
    res = design(ds, [], [], goal="parameters", parameters=["rig_area_m2"], loads=(0.1, 0.3),
                 input_range=RANGE, n_experiments=6, n_draws=8, seed=0,
                 fits={"base": _base_fit(ds)})
    fit = res.fits["base"]
    assert fit.model_on(0.1) is fit.model  # the first record's own load: its rig
    assert fit.model_on(0.3).rig.moving_mass_kg == pytest.approx(mass + 0.2, abs=1e-12)
    assert fit.model_on(0.0).rig.moving_mass_kg == pytest.approx(mass - 0.1, abs=1e-12)
    heavy = next(i for i, e in enumerate(res.experiments) if e.load_kg == 0.3)
    res.chosen = heavy
    assert res.experiment.label().endswith(", 0.3 kg dead load")
    write_design_files(res, tmp_path)
    sidecar = json.loads((tmp_path / "next.json").read_text())
    assert sidecar["rig"]["moving_mass_kg"] == pytest.approx(mass + 0.2, abs=1e-12)
    assert sidecar["conditions"] == {"load_kg": 0.3}


def test_loads_need_the_first_records_declared_load(first):
    # without the load the first record was made with, the mass under another is unknown
    with pytest.raises(DesignError, match=r'"conditions": \{"load_kg": 0.1\}'):
        design(first, [], PAIR, loads=(0.3,), input_range=RANGE, n_experiments=2,
               n_draws=4, seed=0)


def test_a_load_that_leaves_no_moving_mass_is_refused():
    from dataclasses import replace

    ds = _area_first("start")
    # a rig whose moving mass is its load alone (the real cavatappi records' sidecars)
    meta = {**ds.metadata, "rig": {**ds.metadata["rig"], "moving_mass_kg": 0.1}}
    with pytest.raises(DesignError, match="moving mass of 0 kg"):
        design(replace(ds, metadata=meta), [], [], goal="parameters",
               parameters=["rig_area_m2"], loads=(0.0, 0.3), input_range=RANGE,
               n_experiments=2, n_draws=4, seed=0)


# -- the scores start from draws of the posterior, not of its Laplace approximation ----


def test_draws_follow_the_posterior_where_the_laplace_approximation_does_not(fits):
    # a Laplace covariance a hundred times too wide: its draws spread ten times the
    # posterior's sd, and as truths they would be named on any experiment; importance-
    # resampled (from a narrower proposal where its weights are too uneven) they keep
    # to the posterior's spread
    from dataclasses import replace

    fit = fits["regulator_lag"]
    k = list(fit.posterior.names).index("tau_reg")
    j = fit.model.index("tau_reg")
    sd = math.sqrt(fit.map.covariance_z[k, k])  # of log tau_reg
    sets, weights = fit.weighted_draws(np.random.default_rng(0), 64, sets=2)
    assert weights["scale"] == 1.0 and weights["k_hat"] <= 0.7  # a MAP's own: it does
    assert [s.shape for s in sets] == [(64, len(fit.model.parameters))] * 2
    wide = replace(fit, map=replace(fit.map, covariance_z=100.0 * fit.map.covariance_z))
    plain = np.log(wide.draws(np.random.default_rng(0), 256)[:, j])
    assert plain.std() > 5 * sd
    sets, weights = wide.weighted_draws(np.random.default_rng(0), 64, sets=2)
    spread = np.log(np.vstack(sets)[:, j]).std()
    assert weights["scale"] < 1.0 and 0.3 * sd < spread < 2.5 * sd, (spread / sd, weights)
