"""Each experiment left out in turn: the posterior of some experiments carries this one's
parameters by name, a model fitted to the others predicts the one left out, and a
candidate that predicts the experiments left out worse is never named.

All data are generated here with seeds.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.criticism import refits as refits_module
from pmabayes.criticism.prose import transfer_words
from pmabayes.criticism.refits import improves, missing_effect, named, partial_effect
from pmabayes.criticism.results import Refit
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.criticism.transfer import Transfer, leave_experiments_out
from pmabayes.data import Dataset
from pmabayes.inference.posterior import build_posterior
from pmabayes.model.model import PAPER_VALUES, Rig
from pmabayes.synthetic import MeasurementNoise
from pmabayes.util import Progress


def _loaded(load_kg: float, seed: int, *, k_e: float = PAPER_VALUES["K_e"],
            trials: int = 2) -> Dataset:
    """Two trials of one dead load (a raised cosine of pressure, 500 Hz), its load declared."""
    rig = Rig.characterisation()
    rig = pb.Rig(rig.moving_mass_kg + load_kg, rig.gravity_sign, rig.area_m2)
    t = np.arange(3 * 500) / 500.0
    p = 0.2e6 * (1.0 - np.cos(2.0 * np.pi * t))
    x = pb.simulate(pb.Model(rig=rig), {**PAPER_VALUES, "K_e": k_e}, p, time_s=t)[0]
    noise = MeasurementNoise(disturbance_std_m=20e-6, disturbance_corr_time_s=0.002)
    y = noise.apply(np.repeat(x[None], trials, axis=0), 1 / 500.0, np.random.default_rng(seed))
    return Dataset(time_s=t, input=np.repeat(p[None], trials, axis=0), position_m=y,
                   trial_ids=np.arange(trials), source=f"load_{round(load_kg * 1e3)}g.csv",
                   metadata={"synthetic": True, "rig": rig.to_dict(),
                             "conditions": {"load_kg": load_kg}})


@pytest.fixture(scope="module")
def loads() -> list[Dataset]:
    return [_loaded(0.1, 1), _loaded(0.3, 2), _loaded(0.5, 3, trials=1)]


def test_a_subset_posterior_carries_the_parameters_by_name(loads):
    """A record without repeats (its noise sampled) and an offset per experiment (no
    suffix alone): the subset's columns find each parameter, and its likelihood is that
    of the experiments kept."""
    model = pb.Model().with_effects("position_offset")
    post = build_posterior(model, loads)
    theta = np.array([[p.default for p in post.parameters]])
    theta[0] *= np.linspace(0.9, 1.1, post.ndim)
    for keep in ([1, 2], [0, 2], [2], [0]):
        sub, columns = post.subset(keep)
        assert (columns >= 0).all() and len(set(columns)) == sub.ndim
        for j, c in enumerate(columns):  # one parameter: one meaning
            assert sub.parameters[j].name == post.parameters[c].name
        _, ll_sub, _ = sub.evaluate(theta[:, columns], return_x=False)
        _, ll, _ = post.evaluate(theta, return_x=False, experiments=keep)
        assert ll_sub[0] == pytest.approx(ll[0], rel=1e-12)
    assert "x_offset" in post.subset([1])[0].names and "x_offset__load_300g" in post.names
    assert post.alone(1).names == post.subset([1])[0].names


def test_experiments_left_out_are_predicted_from_the_others(loads):
    """The true model, fitted to two loads, predicts the third to about its noise; a
    model whose stiffness each load's own fit would change (K_e wrong by x1.5 and held
    there by the data of the others) predicts it worse."""
    post = build_posterior(pb.Model(), loads)
    values = {n: float(PAPER_VALUES.get(n, p.default))
              for n, p in zip(post.names, post.parameters, strict=True)}
    noise = [post.group_noise[g] for g in range(len(loads))]
    args = (post.likelihoods, noise, post.experiment_names, post.noise_choices)
    truth = leave_experiments_out(*args, values, substeps=post.likelihoods[0].substeps,
                                  rng=np.random.default_rng(0), processes=1)
    motion = [np.std(ds.mean_position_m) for ds in loads]
    assert len(truth) == 3 and all(np.isfinite(truth))
    # a noise of 20 um on motions of several mm
    assert max(truth) < 5 * 20e-6 / min(motion) + 0.02
    again = leave_experiments_out(*args, values, substeps=post.likelihoods[0].substeps,
                                  rng=np.random.default_rng(0), processes=2)
    assert again == truth  # each fold its own stream: the workers do not change them


def _refit(effect: str, diff: float, transfer: Transfer | None = None) -> Refit:
    from types import SimpleNamespace

    band = SimpleNamespace(rms_m=5e-4, floor_m=math.nan)
    sig = SimpleNamespace(bands=[band], ratio=math.nan, energy=3.0, energy_p=0.0,
                          ljung_box_p=0.0, is_adequate=lambda *_: False)
    return Refit(effect=effect, values={}, interval={}, rms_m=5e-4, explained=0.5,
                 elpd=1000.0 + diff, elpd_diff=diff, elpd_diff_se=10.0,
                 contribution_m=np.zeros(3), signatures=(sig,), transfer=transfer)


def test_a_candidate_that_predicts_the_experiments_left_out_worse_is_not_named():
    names = ("load_100g", "load_300g", "load_500g")
    worse = Transfer(names, (0.20, 0.18, 0.25), (0.30, 0.17, 0.40))
    better = Transfer(names, (0.20, 0.18, 0.25), (0.15, 0.16, 0.20))
    assert worse.carries is False and better.carries is True
    assert worse.means == pytest.approx((0.21, 0.29))
    assert worse.ratio == pytest.approx((1.5 * 0.17 / 0.18 * 1.6) ** (1 / 3))
    # one load neither predicts does not decide: relative to each experiment's own
    far = Transfer(names, (0.20, 0.18, 3.0), (0.30, 0.27, 2.5))
    assert far.means[1] < far.means[0] and far.carries is False
    # one experiment the model could not be fitted without: compared where both predict
    gap = Transfer(names, (math.nan, 0.18, 0.25), (0.1, 0.17, 0.30))
    assert gap.means == pytest.approx((0.215, 0.235)) and gap.carries is False
    assert gap.ratio == pytest.approx((0.17 / 0.18 * 0.30 / 0.25) ** 0.5)
    assert Transfer(names, (math.nan,) * 3, (0.1,) * 3).carries is None
    record = worse.to_dict()
    assert record["carries"] is False and record["experiments"]["load_300g"] == {
        "model_nrmse": 0.18, "refit_nrmse": 0.17}
    assert Transfer(names, (math.nan, 0.2, 0.2), (0.1,) * 3).to_dict()[
        "experiments"]["load_100g"]["model_nrmse"] is None
    refits = {"pressure_hysteresis": _refit("pressure_hysteresis", 500.0, worse),
              "maxwell_creep": _refit("maxwell_creep", 100.0, better)}
    assert not refits["pressure_hysteresis"].carries
    assert not improves(refits["pressure_hysteresis"]) and improves(refits["maxwell_creep"])
    assert partial_effect(refits) == "maxwell_creep"
    assert named(refits, DiagnoseSettings()) == "maxwell_creep"
    words = transfer_words(refits, "maxwell_creep")
    assert "maxwell_creep carries to the experiments it was not fitted to" in words
    assert "with 0.811 times the NRMSE without it (geometric mean; load_100g 0.15" in words
    assert ("pressure_hysteresis (ΔELPD +500.0 ± 10.0) is not named: fitted to all "
            "experiments but one, it predicts the one left out with 1.31 times the NRMSE "
            "without it") in words
    # not checked: the ELPD alone decides, as before
    assert improves(_refit("a", 500.0)) and transfer_words({"a": _refit("a", 500.0)}, "a") == ""


def test_the_check_runs_until_a_candidate_carries(monkeypatch, loads):
    """The named candidate is checked first; one that does not carry is passed over and
    the next one named is checked; the model's own folds are run once."""
    calls = []

    def fake(likelihoods, repeat_noise, names, noise_choices, values, **_):
        effects = likelihoods[0].model.effect_names
        calls.append(effects)
        if not effects:
            return (0.2, 0.2, 0.2)
        return (0.3, 0.3, 0.3) if effects == ("a",) else (0.1, 0.1, 0.1)

    monkeypatch.setattr(refits_module, "leave_experiments_out", fake)
    monkeypatch.setattr(refits_module, "_extended", lambda base, effect, substeps: [
        type("L", (), {"model": type("M", (), {"effect_names": (effect,)})()})()])
    base = type("B", (), {"likelihoods": [type("L", (), {"model": pb.Model(),
                                                          "dataset": d})() for d in loads],
                          "names": ["x", "y", "z"], "repeat_noise": [None] * 3,
                          "noise_choices": [None] * 3, "values": {}})()
    s = DiagnoseSettings(processes=1, substeps=1)
    assert refits_module.leaves_out(base, s)
    assert not refits_module.leaves_out(base, dataclasses.replace(
        s, leave_experiments_out=False))
    check = refits_module._TransferCheck(base, s, np.random.default_rng(0), Progress())
    refits = {"a": _refit("a", 500.0), "b": _refit("b", 100.0), "c": _refit("c", 50.0)}
    check.until_one_carries(refits)
    assert calls == [(), ("a",), ("b",)]
    assert named(refits, s) == "b" and refits["c"].transfer is None
    assert missing_effect(refits, s) is None  # no floor here: a partial step


def test_the_settings_are_checked():
    with pytest.raises(ValueError, match="leave_experiments_out must be True, False or None"):
        DiagnoseSettings(leave_experiments_out="yes")
    for bad in (0, 3, True, 1.5):
        with pytest.raises(ValueError, match="refit_searches must be 1 or 2"):
            DiagnoseSettings(refit_searches=bad)


def test_the_command_line_turns_the_check_on_or_off(tmp_path, monkeypatch, loads):
    """``--leave-experiments-out yes|no|auto`` and ``--refit-searches`` reach the
    settings; another word is an argparse error that lists the choices."""
    import pmabayes.criticism.diagnosis as diagnosis
    from pmabayes.cli import main

    files = []
    for ds in loads[:2]:
        path = tmp_path / (ds.source or "x.csv")
        pb.data.write_csv(ds, path)
        files.append(str(path))
    seen, searches = [], []

    def stop(datasets, model=None, effects=(), *, settings=None, **_):
        seen.append(settings.leave_experiments_out)
        searches.append(settings.refit_searches)
        raise SystemExit(0)

    monkeypatch.setattr(diagnosis, "diagnose", stop)
    for word in ("yes", "no", "auto"):
        with pytest.raises(SystemExit):
            main(["diagnose", *files, "--leave-experiments-out", word])
    assert seen == [True, False, None]
    with pytest.raises(SystemExit):
        main(["diagnose", *files, "--refit-searches", "2"])
    assert searches == [1, 1, 1, 2]
    with pytest.raises(SystemExit) as err:
        main(["diagnose", *files, "--leave-experiments-out", "maybe"])
    assert err.value.code == 2
