"""A newcomer's own CSV: header unit styles, what is said once, the rig assumed, trials held
out of one file, and the sidecar reference generated from the code that reads it."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import fake_fit

import pmabayes.inference.sampler as sampler
from pmabayes.criticism.validation import ValidationError, validate
from pmabayes.data import METADATA_KEYS, DataError, Dataset, DataWarning, load, save
from pmabayes.data.keys import SIDECAR_KEYS
from pmabayes.inference.fitfile import experiment_records, fit_info
from pmabayes.inference.posterior import build_posterior
from pmabayes.model.model import RIG_DICT_KEYS, RIG_KEYS, Model, Rig
from pmabayes.model.simulator import MAX_WARMUP_PERIODS, STEADY_STATE_TOL_M

ROOT = Path(__file__).resolve().parents[1]
# each file's conversion is said once; the tests that count it record it themselves
pytestmark = pytest.mark.filterwarnings("ignore:.*units converted to SI:pmabayes.data.DataWarning")


def lab_csv(path: Path, header: str, n_trials: int = 4, n: int = 200, force: bool = False,
            sidecar: dict | None = None) -> Path:
    """A CSV as a lab writes it: values in the units its header names, 1 kHz."""
    t = np.arange(n) * 1e-3
    lines = [header]
    for trial in range(1, n_trials + 1):
        for k in range(n):
            u = (2.0 if force else 40.0) * (1 - np.cos(2 * np.pi * t[k]))  # kN or psi
            x = 10.0 * (1 - np.cos(2 * np.pi * t[k])) + 0.01 * trial  # mm
            time_text = f"{t[k] * 1e3:g}" if "ms" in header.lower() else f"{t[k]:.3f}"
            lines.append(",".join(([] if header.lower().startswith("time") else [str(trial)])
                                  + [time_text, f"{u:.6f}", f"{x:.6f}"]))
    path.write_text("\n".join(lines) + "\n")
    if sidecar is not None:
        path.with_suffix(".json").write_text(json.dumps(sidecar))
    return path


def read(path: Path) -> tuple[Dataset, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = load(path)
    return ds, [str(w.message) for w in caught]


# ----------------------------------------------------------------------------- 1. headers


@pytest.mark.parametrize(("header", "declared"), [
    ("Trial,Time (s),Pressure (psi),Position (mm)", "trial,time_s,pressure_psi,position_mm"),
    ("trial , TIME_MS , pressure[psi] , Position [mm]", "trial,time_ms,pressure_psi,position_mm"),
    ("TRIAL,time s,Pressure ( PSI ),position_mm", "trial,time_s,pressure_psi,position_mm"),
])
def test_header_unit_styles_read_as_the_declared_units(tmp_path, header, declared):
    ours = lab_csv(tmp_path / "ours.csv", header)
    plain = lab_csv(tmp_path / "plain.csv", declared)
    a, said = read(ours)
    b, _ = read(plain)
    np.testing.assert_array_equal(a.input, b.input)
    np.testing.assert_array_equal(a.position_m, b.position_m)
    np.testing.assert_array_equal(a.time_s, b.time_s)
    assert a.trial_ids.tolist() == [1, 2, 3, 4]
    assert a.metadata["converted_units"] == b.metadata["converted_units"]
    assert a.metadata["converted_units"]["pressure_pa"]["from"] == "pressure_psi"
    # the warning quotes the file's own header for what it converted
    assert any("'Position (mm)' x 0.001 -> position_m" in s for s in said) == (
        "Position (mm)" in header)


def test_force_in_kn_header(tmp_path):
    ds, _ = read(lab_csv(tmp_path / "f.csv", "Trial,Time (s),Force [kN],Position [mm]",
                         force=True))
    plain, _ = read(lab_csv(tmp_path / "p.csv", "trial,time_s,force_kn,position_mm",
                            force=True))
    assert ds.input_name == "force_n"
    np.testing.assert_array_equal(ds.input, plain.input)
    assert ds.input.max() == pytest.approx(2e3 * (1 - np.cos(2 * np.pi * 0.199)))  # N


def test_an_unrecognised_header_offers_a_columns_map_for_the_files_own_header(tmp_path):
    path = lab_csv(tmp_path / "lab.csv", "Trial,Time (s),Pressure (psi),Stroke (mm)")
    with pytest.raises(DataError) as info:
        load(path)
    text = str(info.value)
    assert "'Stroke (mm)' looks like 'position_mm'" in text
    assert '"columns"' in text and "lab.json" in text
    example = json.loads(re.search(r"e\.g\. (\{.*\})$", text).group(1))
    assert example == {"columns": {"1": "trial", "2": "time_s", "3": "pressure_psi",
                                   "4": "position_mm"}}
    # and the map it offers reads the file as it is, header and all
    path.with_suffix(".json").write_text(json.dumps(example))
    ds, _ = read(path)
    assert ds.trial_ids.tolist() == [1, 2, 3, 4] and ds.input_name == "pressure_pa"
    assert ds.metadata["read_columns"] == example["columns"]


def test_a_unit_no_map_converts_is_refused_without_offering_the_map(tmp_path):
    path = lab_csv(tmp_path / "atm.csv", "Trial,Time (s),Pressure (atm),Position (mm)")
    with pytest.raises(DataError, match=r"'Pressure \(atm\)' is pressure_atm: .*multiply by "
                                        r"101.325") as info:
        load(path)
    assert '"columns"' not in str(info.value)


def test_the_trial_role_of_columns_is_documented():
    assert '"trial"' in SIDECAR_KEYS["columns"].meaning
    assert '`"trial"` (a column of integer trial' in (ROOT / "docs/guide/lab_files.md").read_text()


# ----------------------------------------------------------------------------- 2. said once


def test_a_conversion_is_said_once_per_file_and_recorded_in_the_fit_file(tmp_path,
                                                                           monkeypatch):
    path = lab_csv(tmp_path / "psi.csv", "trial,time_s,pressure_psi,position_mm",
                   sidecar={"rig": Rig.characterisation().to_dict()})
    first, said = read(path)
    assert sum("units converted" in s for s in said) == 1
    monkeypatch.chdir(tmp_path)
    for again in (path, Path("psi.csv"), Path("./psi.csv")):  # the same file, said once
        ds, said = read(again)
        assert not [s for s in said if "units converted" in s]
        assert ds.metadata["converted_units"] == first.metadata["converted_units"]
    other = lab_csv(tmp_path / "psi2.csv", "trial,time_s,pressure_psi,position_mm")
    assert any("units converted" in s for s in read(other)[1])
    # the fit file's experiment keeps the record, the trials fitted and the file
    records = experiment_records(build_posterior(Model(), [first]))
    assert records[0]["metadata"]["converted_units"] == first.metadata["converted_units"]
    assert records[0]["trial_ids"] == [1, 2, 3, 4]
    assert records[0]["source_path"] == str(path.resolve())


# ----------------------------------------------------------------------------- 3. the rig


def test_no_rig_is_said_once_with_a_complete_example(tmp_path):
    ds, _ = read(lab_csv(tmp_path / "bench.csv", "trial,time_s,pressure_psi,position_mm"))
    with pytest.warns(DataWarning, match=r'bench\.csv: no "rig" in its sidecar, so the '
                                         r"paper's characterisation rig is assumed \(moving "
                                         r"mass 0\.067 kg, gravity against extension, area "
                                         r"A=0\.0002183 m\^2\); declare yours") as said:
        model = Model.for_dataset(ds)
    assert model.rig.name == "characterisation"
    text = str(said[0].message)
    example = json.loads("{" + re.search(r'("rig": \{.*?\})', text).group(1) + "}")
    assert Rig.from_dict(example["rig"]).moving_mass_kg == pytest.approx(0.067)
    assert set(example["rig"]) == set(RIG_DICT_KEYS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Model.for_dataset(ds)  # once per file
        Model.for_dataset(ds.select_trials([0, 1]))


def test_no_rig_warning_for_bundled_synthetic_or_declared_data(tmp_path):
    declared = lab_csv(tmp_path / "d.csv", "trial,time_s,pressure_psi,position_mm",
                       sidecar={"rig": Rig.control().to_dict()})
    synthetic = lab_csv(tmp_path / "s.csv", "trial,time_s,pressure_psi,position_mm",
                        sidecar={"synthetic": True})
    force = lab_csv(tmp_path / "f.csv", "trial,time_s,force_kn,position_mm", force=True)
    sets = [load(p) for p in (declared, synthetic, force)]
    sets += [load(ROOT / "data" / n) for n in ("pma_chirp_paper.csv", "pma_chirp_lab.csv")]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for ds in sets:
            Model.for_dataset(ds)


# ----------------------------------------------------------------------------- 4. trials


def test_fit_trials_keeps_those_trials_and_builds_the_model_on_the_files_rig(tmp_path,
                                                                          monkeypatch):
    ds, _ = read(lab_csv(tmp_path / "m.csv", "trial,time_s,pressure_psi,position_mm",
                         sidecar={"rig": Rig.control().to_dict()}))
    seen = {}

    def fake(datasets, model, *args):
        seen.update(datasets=datasets, model=model)
        return "tree"

    monkeypatch.setattr(sampler, "_fit", fake)
    assert sampler.fit(ds, trials=[1, 2, 3]) == "tree"
    assert [d.trial_ids.tolist() for d in seen["datasets"]] == [[1, 2, 3]]
    assert seen["model"].rig.name == "control"  # the sidecar's rig, not the paper's
    with pytest.raises(DataError, match=r"m\.csv: trials=\[5\]: no trial with id 5; the "
                                        r"trial ids are \[1, 2, 3, 4\]"):
        sampler.fit(ds, trials=[5])
    other = Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m,
                    trial_ids=ds.trial_ids, metadata=ds.metadata, source="other.csv")
    with pytest.raises(DataError, match="trial ids belong to one data file"):
        sampler.fit([ds, other], trials=[1])


def _fit_of(path: Path, trial_ids: list[int]):
    """A fit-like tree whose file records that it was fitted on these trials of ``path``."""
    model = Model()
    params = {n: (model.parameter(n).unit, v, 2e-4 * abs(v))
              for n, v in model.defaults.items() if n in model.free_names}
    params.update(sigma_noise_m=("m", 6e-5, 2e-6), rho_noise=("1", 0.99, 1e-4),
                  sigma_white_m=("m", 3e-6, 1e-7))
    tree = fake_fit(params=params, n_trial=len(trial_ids), n_time=200, dt_s=1e-3, n_chain=8,
                    n_draw=20)
    info = fit_info(tree)
    info["experiments"][0].update(source=str(path), trial_ids=trial_ids,
                                  source_path=str(path.resolve()))
    tree.attrs["pmabayes"] = json.dumps(info)
    return tree


def test_validate_refuses_fitted_trials_and_takes_the_held_out_ones(tmp_path):
    path = lab_csv(tmp_path / "m.csv", "trial,time_s,pressure_psi,position_mm",
                   sidecar={"rig": Rig.characterisation().to_dict()})
    tree = _fit_of(path, [1, 2, 3])
    with pytest.raises(ValidationError, match=r"m\.csv: trials 1, 2, 3 were fitted \(the fit "
                                              r"was made from trials 1, 2, 3 of this file\), "
                                              r"so they are not held out.*trials=\[4\] \(on "
                                              r"the command line: --trials 4\)"):
        validate(tree, path, n_draws=10)
    with pytest.raises(ValidationError, match=r"trial 2 was fitted.*trials=\[4\]"):
        validate(tree, path, trials=[2, 4], n_draws=10)
    with pytest.raises(ValidationError, match=r"trial 1 was fitted"):  # the same file, renamed
        validate(tree, tmp_path / "." / "m.csv", trials=[1],
                 n_draws=10)
    v = validate(tree, path, trials=[4], n_draws=10)
    assert v.experiments[0].n_trials == 1
    # every trial fitted: the fix is to hold some out when fitting
    with pytest.raises(ValidationError, match=r"hold trials out when fitting.*in_sample=True"):
        validate(_fit_of(path, [1, 2, 3, 4]), path, n_draws=10)
    # asked for, the fit on its own trials is measured, and said to be so
    with pytest.warns(DataWarning, match=r"trials 1, 2, 3, 4 were fitted.*not held-out"):
        v = validate(_fit_of(path, [1, 2, 3, 4]), path, n_draws=10, in_sample=True)
    assert v.experiments[0].n_trials == 4


def test_validate_trials_must_exist(tmp_path):
    path = lab_csv(tmp_path / "m.csv", "trial,time_s,pressure_psi,position_mm",
                   sidecar={"rig": Rig.characterisation().to_dict()})
    with pytest.raises(DataError, match=r"no trial with id 7"):
        validate(_fit_of(path, [1, 2]), path, trials=[7])


# ----------------------------------------------------------------------------- 5. reference


def test_every_key_the_code_reads_is_in_the_sidecar_reference():
    assert list(SIDECAR_KEYS) == list(METADATA_KEYS)
    assert list(RIG_KEYS) == list(RIG_DICT_KEYS)
    # the rig's keys are what Rig.from_dict reads and Rig.to_dict writes
    assert set(Rig.characterisation().to_dict()) == set(RIG_DICT_KEYS)
    with pytest.raises(Exception, match=re.escape(str(sorted(RIG_DICT_KEYS)))):
        Rig.from_dict({"moving_mass_kg": 0.1, "not_a_key": 1})
    for key, doc in {**SIDECAR_KEYS, **RIG_KEYS}.items():
        assert (ROOT / "docs" / f"{doc.page}.md").is_file(), (key, doc.page)
        assert doc.type and doc.default and doc.meaning, key
    # defaults stated in the data layer agree with the constants that apply them
    assert float(SIDECAR_KEYS["steady_state_tol_m"].default) == STEADY_STATE_TOL_M
    assert int(SIDECAR_KEYS["max_warmup_periods"].default) == MAX_WARMUP_PERIODS
    page = (ROOT / "docs/guide/sidecar.md").read_text()
    assert "```{sidecar-keys}\n```" in page and "```{sidecar-keys}\n:rig:\n```" in page
    assert "\nsidecar\n" in (ROOT / "docs/guide/index.md").read_text()


def test_the_newcomer_end_to_end_reads_once_and_is_told(tmp_path):
    """The four-trial CSV with no sidecar: read, converted, told about the rig once."""
    path = lab_csv(tmp_path / "new.csv", "Trial,Time (s),Pressure (psi),Position (mm)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(2):
            Model.for_dataset(load(path))
    said = [str(w.message) for w in caught]
    assert sum("units converted" in s for s in said) == 1
    assert sum('no "rig"' in s for s in said) == 1
    save(load(path), tmp_path / "si.csv")  # the SI data set writes back


def test_one_file_serves_fit_and_validate_on_the_command_line(tmp_path, capsys):
    """`fit --trials` and `validate --trials` hold trials of one file out; validating on
    a fitted trial is refused, naming it."""
    from pmabayes.cli import main

    data = tmp_path / "lab.csv"
    assert main(["simulate", str(data), "--trials", "4", "--duration", "1", "--seed", "2"]) == 0
    fit_path = tmp_path / "fit.nc"
    assert main(["fit", str(data), "--trials", "0,1,2", "--out", str(fit_path), "--walkers",
                 "16", "--steps", "60", "--quiet"]) == 0
    assert "fitting trials 0,1,2 of" in capsys.readouterr().out
    from pmabayes.inference.fitfile import load_fit

    ids = [tuple(r["trial_ids"]) for r in fit_info(load_fit(fit_path))["experiments"]]
    assert ids == [(0, 1, 2)]
    # the next command the fit suggests keeps trial 3 out of the diagnosis, and diagnose
    # takes the option
    from pmabayes.cli import _parser
    from pmabayes.inference.fitfile import experiment_datasets
    from pmabayes.report.verdicts import _diagnose_command

    tree = load_fit(fit_path)
    (kept,) = experiment_datasets(tree)
    assert kept.metadata["selected_trials"] == [0, 1, 2]
    assert _diagnose_command(fit_info(tree), kept).endswith(f"{data} --trials 0,1,2")
    assert _parser().parse_args(["diagnose", str(data), "--trials", "0,1,2"]).trials == [0, 1, 2]
    out = tmp_path / "val.json"
    assert main(["validate", str(fit_path), str(data), "--trials", "3", "--json", str(out),
                 "--draws", "20", "--quiet"]) == 0
    assert json.loads(out.read_text())["experiments"][0]["nrmse"] is not None
    assert main(["validate", str(fit_path), str(data), "--trials", "2", "--draws", "20",
                 "--quiet"]) == 2
    assert "2" in capsys.readouterr().err
    assert main(["fit", str(data), "--trials", "0", "--exclude-trials", "1", "--out",
                 str(tmp_path / "g.nc"), "--quiet"]) == 2
    assert "--trials and --exclude-trials" in capsys.readouterr().err
