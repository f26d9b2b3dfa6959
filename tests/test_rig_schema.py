"""One rig schema: a sidecar's ``"rig"`` is checked when the data are read, the model's
:class:`Rig` is built from it by one conversion and checked by the same rules, and a fit's
experiments are the fitted model on their rigs (:meth:`Model.on_rig`)."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import fake_fit

from pmabayes.data import DataError, Dataset, DataWarning, read_csv
from pmabayes.data.rig import (
    DEFAULT_INPUT_KIND,
    INPUT_OF_KIND,
    RIG_DICT_KEYS,
    RIG_KEYS,
    declared_rig,
    rig_problem,
)
from pmabayes.inference.fitfile import experiment_models, fit_info, model_from_fit
from pmabayes.model.model import G_M_S2, PAPER_AREA_M2, Model, ModelError, Rig
from pmabayes.model.parameters import LogNormal

GOOD = Rig.characterisation().to_dict()


def _csv(tmp_path: Path, rig: object, name: str = "bench.csv") -> Path:
    path = tmp_path / name
    lines = ["trial,time_s,pressure_pa,position_m"]
    lines += [f"{i},{k / 100:g},{1e5 + 1e4 * k},{1e-3 * k}" for i in (1, 2)
              for k in range(5)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    path.with_suffix(".json").write_text(json.dumps({"rig": rig,
                                                     "pressure_reference": "gauge"}))
    return path


@pytest.mark.parametrize(("change", "message"), [
    ({"colour": "red"}, r"unknown rig keys \['colour'\]; expected .*: rename or remove"),
    ({"gravity_sign": 2}, r"gravity_sign must be -1, 0 or \+1 .*got 2; fix it"),
    ({"gravity_sign": "Normal(1, 1)"}, r"'gravity_sign' is 'Normal\(1, 1\)'; it must be a "
                                       r"number \(only moving_mass_kg, area_m2 may be given"),
    ({"area_m2": 0.0}, r"area_m2 must be > 0 .*; fix it"),
    ({"moving_mass_kg": -1}, r"rig mass must be > 0 kg .*; fix it"),
    ({"input_kind": "torque"}, r"input_kind must be 'pressure' or 'force', got 'torque'"),
    ({"g_m_s2": float("nan")}, r"'g_m_s2' is nan; it must be a finite number"),
    ({"name": 3}, r"name must be a string"),
])
def test_a_bad_rig_is_refused_when_the_file_is_read(tmp_path, change, message):
    path = _csv(tmp_path, {**GOOD, **change})
    with pytest.raises(DataError, match="^Dataset from " + re.escape(str(path)) +
                       r": metadata 'rig': " + message):
        read_csv(path)
    # the model's Rig is checked by the same rules
    with pytest.raises(ModelError, match=message):
        Rig.from_dict({**GOOD, **change})


def test_a_misspelt_rig_key_alone_is_a_rig_not_notes(tmp_path):
    path = _csv(tmp_path, {"moving_mas_kg": 0.1})
    with pytest.raises(DataError, match=r"unknown rig keys \['moving_mas_kg'\]"):
        read_csv(path)
    with pytest.raises(DataError, match=r"no 'moving_mass_kg'.*add it"):
        read_csv(_csv(tmp_path, {"gravity_sign": 1}, "g.csv"))


def test_notes_about_a_rig_declare_none_and_the_model_says_so(tmp_path):
    ds = read_csv(_csv(tmp_path, {"muscle": "DMSP-10"}))
    assert declared_rig(ds.metadata) is None
    with pytest.warns(DataWarning, match=r'its sidecar\'s "rig" holds notes, not the rig\'s '
                                         r"constants, so the paper's characterisation rig"):
        model = Model.for_dataset(ds)
    assert model.rig == Rig.characterisation()
    declared = read_csv(_csv(tmp_path, {**GOOD, "name": "bench"}, "b.csv"))
    assert declared_rig(declared.metadata) == {**GOOD, "name": "bench"}
    assert Model.for_dataset(declared).rig.name == "bench"


def test_a_rig_prior_passes_the_data_check_and_is_parsed_by_the_model(tmp_path):
    ds = read_csv(_csv(tmp_path, {**GOOD, "area_m2": "LogNormal(2e-4, 1.5)"}))
    assert "rig_area_m2" in Model.for_dataset(ds).free_names
    bad = read_csv(_csv(tmp_path, {**GOOD, "area_m2": "LogNorm(2e-4, 1.5)"}, "bad.csv"))
    with pytest.raises(ModelError, match=r"bad\.csv: metadata 'rig': 'area_m2'"):
        Model.for_dataset(bad)


def test_a_rig_value_given_as_a_prior_holds_the_priors_median_however_made():
    """``Rig(priors=...)`` made in Python holds each prior's median in the value's field,
    as ``Rig.from_dict`` does: what prints or reads ``rig.area_m2`` (the start's scale,
    the control layer, a report) agrees with the prior, not with the paper's area."""
    area, mass = LogNormal(1e-4, 1.5), LogNormal(0.3, 1.0)
    direct = Rig(0.25, priors=(("area_m2", area),))
    assert direct.area_m2 == pytest.approx(1e-4, rel=1e-12) != PAPER_AREA_M2
    assert direct == Rig.from_dict({"moving_mass_kg": 0.25, "area_m2": str(area)})
    assert Rig.from_dict(direct.to_dict()) == direct
    assert Model(rig=direct).defaults["rig_area_m2"] == direct.area_m2
    both = Rig(0.25, area_m2=5e-4, priors=(("area_m2", area), ("moving_mass_kg", mass)))
    assert (both.area_m2, both.moving_mass_kg) == pytest.approx((1e-4, 0.3), rel=1e-12)
    assert both.gravity_force_n == pytest.approx(0.3 * G_M_S2)
    # a rig's other values are untouched, and a rig without priors keeps its numbers
    assert Rig(0.25, area_m2=5e-4).area_m2 == 5e-4 and direct.moving_mass_kg == 0.25


def test_the_schema_and_the_models_rig_agree():
    rig = Rig.characterisation()
    assert RIG_DICT_KEYS == tuple(f.name for f in dataclasses.fields(Rig)
                                  if f.name != "priors")
    assert list(rig.to_dict()) == list(RIG_DICT_KEYS)
    # the defaults the reference states are the constants the model applies
    assert float(RIG_KEYS["moving_mass_kg"].default.split()[0]) == rig.moving_mass_kg
    assert float(RIG_KEYS["area_m2"].default.split()[0]) == pytest.approx(PAPER_AREA_M2,
                                                                         rel=1e-5)
    assert float(RIG_KEYS["g_m_s2"].default) == G_M_S2 == Rig(1.0).g_m_s2
    assert RIG_KEYS["input_kind"].default == DEFAULT_INPUT_KIND == Rig(1.0).input_kind
    assert RIG_KEYS["name"].default == Rig(1.0).name
    assert {k: Rig(1.0, 0.0, 1.0, input_kind=k).input_name for k in INPUT_OF_KIND} == \
        INPUT_OF_KIND
    assert rig_problem(rig.to_dict()) is None and rig_problem("bench-2") is not None
    with pytest.raises(ModelError, match="gravity_sign must be -1, 0 or"):
        Rig(1.0, gravity_sign=0.5)


def test_a_data_set_made_in_python_is_checked_too():
    t = np.arange(5) / 100
    with pytest.raises(DataError, match=r"^Dataset: metadata 'rig': unknown rig keys"):
        Dataset(time_s=t, input=np.ones((2, 5)), position_m=np.zeros((2, 5)),
                trial_ids=np.arange(2), metadata={"rig": {**GOOD, "mass": 1.0}})


def test_experiment_models_are_the_fitted_model_on_each_rig():
    tree = fake_fit(effects=["coulomb_friction"])
    info = fit_info(tree)
    # the fit freed a parameter fixed by default: its model and experiments keep it free
    info["model"]["free"] = [*info["model"]["free"], "v_c"]
    del info["model"]["fixed"]["v_c"]
    control = Rig.control().to_dict()
    info["experiments"][0]["rig"] = control
    tree.attrs["pmabayes"] = json.dumps(info)
    base = model_from_fit(tree)
    assert "v_c" in base.free_names
    (model,) = experiment_models(tree)
    assert model.rig == Rig.control() and "v_c" in model.free_names
    assert model.free_names == base.on_rig(Rig.control()).free_names
    assert base.on_rig(base.rig) is base
