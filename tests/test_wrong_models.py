"""A wrong model is measured and criticised, never refused: poor fits go on, a search
that ends worse than the static line the model contains starts from that line, and
only data no model of this kind explains (a sign, a scale) is refused.

All data are generated here with seeds.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.data import DataError, Dataset, experiment_conditions
from pmabayes.inference import search
from pmabayes.inference.errors import FitError, PoorFitWarning
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.inference.search import find_map, fit_quality, static_lines
from pmabayes.model.nested import static_line_values
from pmabayes.synthetic import Chirp, generate_chirp_dataset

CHIRP = Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=2.0)


@pytest.fixture(scope="module")
def chirps() -> Dataset:
    return generate_chirp_dataset(n_trials=3, seed=11, chirp=CHIRP)


def _drifting(data: Dataset, size_m: float) -> Dataset:
    """The data with a motion the input does not drive (two sines of ``size_m``, one
    falling as the chirp's pressure rises)."""
    t = data.time_s - data.time_s[0]
    extra = size_m * (np.sin(2 * np.pi * 0.4 * t) - np.sin(2 * np.pi * 1.1 * t + 1.0))
    return Dataset(time_s=data.time_s, input=data.input, position_m=data.position_m + extra,
                   trial_ids=data.trial_ids, metadata=data.metadata, source="drifting.csv")


def test_a_poor_fit_goes_on_and_says_how_poor(chirps):
    """A motion the input does not drive leaves a poor fit: recorded, warned once, not
    refused."""
    data = _drifting(chirps, 1.5 * np.ptp(chirps.mean_position_m))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tree = fit(data, pb.Model(), seed=0,
                   settings=FitSettings(n_walkers=16, max_steps=40, check_every=40))
    poor = [w for w in caught if issubclass(w.category, PoorFitWarning)]
    assert len(poor) == 1, [str(w.message) for w in caught]
    text = str(poor[0].message)
    assert "drifting.csv: the best fit leaves an RMS error" in text
    assert "static line" in text and "pmabayes diagnose" in text
    quality = pb.inference.fit_info(tree)["map"]["quality"]
    assert quality["poor"] and quality["share"] > search.POOR_FIT_SHARE
    assert quality["rms_cost_m"] <= quality["static_line_rms_m"] * (1 + 1e-6)


def test_a_search_that_ends_worse_than_the_static_line_starts_from_it(chirps, monkeypatch):
    """The base physics contains the static line: a search stuck far worse than it is
    replaced by the line's nested model before the polish, and the MAP is no worse than
    the line."""
    post = build_posterior(pb.Model(), chirps)
    real = search._global_search

    def stuck(posterior, box, rng, popsize, maxiter, say, which):
        z, _ = real(posterior, box, rng, popsize, 2, say, which)
        # a model that barely moves: the stiffest corner of the box
        z = box[:, 1].copy()
        theta = posterior.to_natural(np.concatenate([z, search._default_noise_z(
            posterior, box.shape[0])])[None])
        return z, float(posterior.likelihood.rms_cost(posterior.output(theta))[0])

    monkeypatch.setattr(search, "_global_search", stuck)
    result = find_map(post, rng=np.random.default_rng(0))
    q = result.quality
    assert q["nested_start"] is True
    assert q["search_failure"] is False
    assert result.rms_cost_m <= q["static_line_rms_m"]


def test_the_nested_values_draw_the_static_line():
    """Simulated at static_line_values, a slow ramp of force follows the line."""
    rig = pb.Rig(moving_mass_kg=1.0, gravity_sign=0.0, area_m2=1.0, input_kind="force")
    model = pb.Model(rig=rig)
    t = np.arange(4000) * 1e-3
    f = 50.0 * t  # N
    values = static_line_values(model, 2e-4, 0.0, 0.0, area_m2=1.0, tau_s=0.05)
    values["beta"] = values["gamma"] = 0.0
    x = pb.simulate(model, values, f, time_s=t)[0]
    # past a few time constants the lag trails the line by slope * rate * tau
    late = t > 0.5
    np.testing.assert_allclose(x[late], 2e-4 * (f[late] - 50.0 * 0.05), rtol=0, atol=1e-5)


def test_the_static_line_is_shared_with_an_offset_per_experiment(chirps):
    post = build_posterior(pb.Model(), chirps)
    b, offsets, x = static_lines(post.likelihood)
    y, u = chirps.mean_position_m, chirps.input[0]
    coef = np.polyfit(u, y, 1)
    assert b == pytest.approx(coef[0]) and offsets[0] == pytest.approx(coef[1])
    q = fit_quality(post.likelihood, x)
    assert q["static_line_rms_m"] == pytest.approx(q["rms_cost_m"])
    assert q["mean_rms_m"] == pytest.approx(np.std(y))


def test_positions_of_metres_are_refused_as_a_scale(chirps):
    data = Dataset(time_s=chirps.time_s, input=chirps.input,
                   position_m=chirps.position_m * 1e3, trial_ids=chirps.trial_ids,
                   source="millimetres.csv")
    post = build_posterior(pb.Model(), data)
    x = np.zeros((1, data.time_s.size))
    with pytest.raises(FitError, match=r"millimetres.csv: the positions span .* m.*10\^3"):
        fit_quality(post.likelihood, x)


@pytest.mark.parametrize("conditions, word", [
    ({"load_kg": "heavy"}, "'load_kg' as 'heavy'"),
    ([0.1, 0.2], "must be an object of named numbers"),
    ({"load_kg": float("nan")}, "'load_kg' as nan"),
])
def test_conditions_that_are_not_numbers_are_refused(chirps, conditions, word):
    with pytest.raises(DataError, match="heavy.csv.*" + word.replace("(", r"\(")):
        experiment_conditions({"conditions": conditions}, "heavy.csv")
    with pytest.raises(DataError, match="conditions"):
        Dataset(time_s=chirps.time_s, input=chirps.input, position_m=chirps.position_m,
                trial_ids=chirps.trial_ids, metadata={"conditions": conditions},
                source="heavy.csv")
    assert experiment_conditions({"conditions": {"load_kg": 0.3}}) == {"load_kg": 0.3}


# ---- experiments that disagree, read as evidence

def _agreement(k_e: list[float], alpha: list[float], agree: bool = False) -> dict:
    names = [f"load{i}" for i in range(len(k_e))]
    return {"agree": agree, "statistic": 6.55e4, "df": 12, "p_value": 0.0, "level": 0.01,
            "experiments": {n: {"values_own": {"K_e": k, "alpha": a, "beta": 2.0}}
                            for n, k, a in zip(names, k_e, alpha, strict=True)}}


def test_a_parameter_that_moves_with_the_load_is_named_with_its_trend():
    from pmabayes.criticism.experiments import moving_parameters, trend_text

    agreement = _agreement([400.0, 610.0, 850.0], [20.0, 21.0, 20.5])
    moving = moving_parameters(agreement, {"load_kg": [0.1, 0.3, 0.5]})
    assert [m["parameter"] for m in moving] == ["K_e"]  # alpha and beta stay within x1.25
    assert moving[0]["follows"]["condition"] == "load_kg"
    assert trend_text(moving) == "K_e rises with load_kg, about x2.1 from 0.1 to 0.5 (400 to 850)"
    # no condition that it follows: said so
    loose = moving_parameters(agreement, {"order": [2.0, 1.0, 3.0]})
    assert "moves by x2.1 with no declared condition" in trend_text(loose)


def test_conditions_that_differ_come_from_the_sidecars_and_the_rigs(chirps):
    from pmabayes.criticism.experiments import experiment_conditions_table

    def with_meta(meta, source):
        return Dataset(time_s=chirps.time_s, input=chirps.input,
                       position_m=chirps.position_m, trial_ids=chirps.trial_ids,
                       metadata={**chirps.metadata, **meta}, source=source)

    rig = chirps.metadata["rig"]
    a = with_meta({"conditions": {"load_kg": 0.1, "order": 1},
                   "rig": {**rig, "moving_mass_kg": 0.167}}, "a.csv")
    b = with_meta({"conditions": {"load_kg": 0.5, "order": 1},
                   "rig": {**rig, "moving_mass_kg": 0.567}}, "b.csv")
    table = experiment_conditions_table([a, b])
    assert table == {"load_kg": [0.1, 0.5], "moving_mass_kg": [0.167, 0.567]}


def test_the_verdict_on_disagreeing_experiments_says_what_moves_and_what_makes_them_agree():
    from types import SimpleNamespace

    from pmabayes.criticism.diagnosis import agreement_words
    from pmabayes.criticism.experiments import agreement_change, moving_parameters, trend_text

    base = _agreement([400.0, 610.0, 850.0], [20.0, 21.0, 20.5])
    moving = moving_parameters(base, {"load_kg": [0.1, 0.3, 0.5]})
    fixed = SimpleNamespace(effect="load_stiffness", agreement={
        **base, "agree": True, "statistic": 9.1, "p_value": 0.69})
    other = SimpleNamespace(effect="regulator_lag", agreement={**base, "statistic": 5.1e4})
    untested = SimpleNamespace(effect="cubic_stiffness", agreement=None)
    candidates = agreement_change(base, [other, untested, fixed])
    assert [c["effect"] for c in candidates] == ["load_stiffness", "regulator_lag"]
    record = {**{k: base[k] for k in ("agree", "statistic", "df", "p_value", "level")},
              "experiments": {}, "conditions": {}, "moving": moving,
              "trend": trend_text(moving), "candidates": candidates}
    words = agreement_words(record)
    assert "The experiments disagree" in words and "6.55e+04 on 12 degrees" in words
    assert "K_e rises with load_kg" in words
    assert "With load_stiffness they agree (likelihood ratio 6.55e+04 -> 9.1" in words
    none = agreement_words({**record, "candidates": candidates[1:]})
    assert "No refitted candidate makes them agree" in none and "regulator_lag" in none
    assert agreement_words({**record, "agree": True}) == "" and agreement_words(None) == ""


@pytest.mark.slow
def test_diagnose_goes_on_where_experiments_disagree_and_names_what_moves():
    """Two loads of a plant whose stiffness triples with the load: diagnose goes on
    (before, the joint fit's refusal stopped it) and shows K_e moving with the load."""
    from pmabayes.criticism.settings import DiagnoseSettings
    from pmabayes.model.model import PAPER_VALUES, Rig
    from pmabayes.synthetic import MeasurementNoise

    def loaded(load_kg: float, k_e: float, seed: int) -> Dataset:
        rig = Rig.characterisation()
        rig = pb.Rig(rig.moving_mass_kg + load_kg, rig.gravity_sign, rig.area_m2)
        t = np.arange(3 * 500) / 500.0
        p = 0.2e6 * (1.0 - np.cos(2.0 * np.pi * t))
        truth = {**PAPER_VALUES, "K_e": k_e}
        x = pb.simulate(pb.Model(rig=rig), truth, p, time_s=t)[0]
        noise = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002)
        y = noise.apply(np.repeat(x[None], 2, axis=0), 1 / 500.0, np.random.default_rng(seed))
        return Dataset(time_s=t, input=np.repeat(p[None], 2, axis=0), position_m=y,
                       trial_ids=np.arange(2), source=f"load_{int(load_kg * 1e3)}g.csv",
                       metadata={"synthetic": True, "rig": rig.to_dict(),
                                 "conditions": {"load_kg": load_kg}})

    data = [loaded(0.1, PAPER_VALUES["K_e"], 1), loaded(0.5, 3 * PAPER_VALUES["K_e"], 2)]
    result = pb.diagnose(data, settings=DiagnoseSettings(max_refits=1, discrepancy=False),
                         seed=0)
    agreement = result.to_dict()["agreement"]
    assert agreement["agree"] is False
    assert agreement["conditions"]["load_kg"] == [0.1, 0.5]
    k_e = next(m for m in agreement["moving"] if m["parameter"] == "K_e")
    assert k_e["follows"]["condition"] in ("load_kg", "moving_mass_kg")
    assert 2.0 < k_e["factor"] < 4.5
    assert "The experiments disagree" in result.verdict and "K_e rises with" in result.verdict


def test_an_elpd_whose_unit_has_no_spread_is_estimated_not_a_crash():
    """ArviZ's PSIS raises where every draw gives a unit one log likelihood (seen on the
    real loaded muscle's joint fit); that unit's term is then its plain estimate."""
    import arviz as az

    from pmabayes.criticism.elpd import psis_loo

    rng = np.random.default_rng(0)
    ll = rng.normal(size=(200, 5)) * 0.1 - 3.0
    tree = az.from_dict({"posterior": {"t": np.zeros((1, 200))},
                         "log_likelihood": {"y": ll[None]}}, dims={"y": ["unit"]})
    elpd, elpd_i = psis_loo(ll)
    assert elpd == pytest.approx(float(az.loo(tree, var_name="y").elpd))
    ll[:, 2] = -7.0
    elpd, elpd_i = psis_loo(ll)
    assert elpd_i[2] == pytest.approx(-7.0) and np.all(np.isfinite(elpd_i))


def test_a_parameter_one_experiment_cannot_identify_does_not_move():
    from pmabayes.criticism.experiments import moving_parameters

    agreement = _agreement([400.0, 610.0, 850.0], [20.0, 21.0, 20.5])
    sd = {"load0": 0.05, "load1": 0.05, "load2": 0.05}
    for n, e in agreement["experiments"].items():
        e["z_own"] = {"K_e": [float(np.log(e["values_own"]["K_e"])), sd[n]]}
    assert [m["parameter"] for m in moving_parameters(agreement, {})] == ["K_e"]
    for e in agreement["experiments"].values():
        e["z_own"]["K_e"][1] = 1.0  # as wide as the move itself: it wanders, not moves
    assert moving_parameters(agreement, {}) == []
