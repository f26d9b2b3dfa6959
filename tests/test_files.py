"""Tests for MATLAB ``.mat`` files (v5 through scipy, v7.3 through h5py), the rig's input
kind against the data's, and experiments of one input kind.

The .mat fixtures are written here: v5 with :func:`scipy.io.savemat`, v7.3 with h5py in
MATLAB's layout (a 512-byte text header, arrays transposed, ``MATLAB_class``
attributes, text as uint16, structs as groups). One test reads a real MATLAB file from
the optional shared Bouc-Wen benchmark folder.
"""

from __future__ import annotations

import builtins
import json
import re
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

from pmabayes.data import (
    DataError,
    Dataset,
    DataWarning,
    check_same_input_kind,
    load,
    read_csv,
    read_mat,
    save,
)
from pmabayes.data.matlab import _variables

RATE_HZ = 500.0
N = 200
T = np.arange(N) / RATE_HZ
P = 2e5 * (1.0 + np.sin(2 * np.pi * 2.0 * T))  # one command, gauge Pa, from 0 up
X = 0.01 * np.sin(2 * np.pi * 2.0 * T)[:, np.newaxis] * np.array([1.0, 1.01, 0.99])  # N x 3
#: the shared Bouc-Wen files, ``../shared`` beside the checkout (or a worktree one
#: level deeper), wherever the checkout is
REAL = next((p for p in (Path(__file__).resolve().parents[k] / "shared" / "external"
                         / "boucwen" / "original" for k in (2, 3)) if p.is_dir()),
            Path(__file__).resolve().parents[2] / "shared" / "external" / "boucwen" / "original")
FORCE_RIG = {"moving_mass_kg": 2.0, "gravity_sign": 0.0, "area_m2": 1.0,
             "input_kind": "force", "g_m_s2": 9.81, "name": "force_oscillator"}


def at(path: Path, rest: str) -> str:
    """Regex: the message starts with the file name, then ``rest``."""
    return "^" + re.escape(str(path)) + rest


def sidecar(path: Path, **meta: object) -> Path:
    path.with_suffix(".json").write_text(json.dumps(meta), encoding="utf-8")
    return path


def v5(path: Path, variables: dict, **meta: object) -> Path:
    scipy.io.savemat(path, variables)
    return sidecar(path, **meta) if meta else path


# ----------------------------------------------------------------------------- v7.3 writer


def _v73_write(group: h5py.Group, name: str, value: object) -> None:
    """One variable as MATLAB -v7.3 stores it."""
    if isinstance(value, dict):
        sub = group.create_group(name)
        sub.attrs["MATLAB_class"] = np.bytes_("struct")
        for key, item in value.items():
            _v73_write(sub, key, item)
        return
    if isinstance(value, list):  # a 1 x n struct array: each field an array of references
        sub = group.create_group(name)
        sub.attrs["MATLAB_class"] = np.bytes_("struct")
        refs = group.file.require_group("#refs#")
        for key in value[0]:
            targets = []
            for item in value:
                _v73_write(refs, f"r{len(refs)}", item[key])
                targets.append(refs[f"r{len(refs) - 1}"].ref)
            sub.create_dataset(key, data=np.array([targets], dtype=h5py.ref_dtype).T)
        return
    if isinstance(value, str):
        data = np.array([[ord(c) for c in value]], dtype=np.uint16)  # 1 x n char
        ds = group.create_dataset(name, data=data.T)
        ds.attrs["MATLAB_class"] = np.bytes_("char")
        ds.attrs["MATLAB_int_decode"] = np.int32(2)
        return
    a = np.asarray(value)
    if a.ndim == 1:  # MATLAB has no 1-D arrays: a row vector, 1 x n
        a = a[np.newaxis, :]
    cls = {"float64": "double", "float32": "single", "bool": "logical"}.get(str(a.dtype),
                                                                            str(a.dtype))
    ds = group.create_dataset(name, data=(a.astype(np.uint8) if a.dtype == bool else a).T)
    ds.attrs["MATLAB_class"] = np.bytes_(cls)


def v73(path: Path, variables: dict, *, objects: tuple[str, ...] = (), **meta: object) -> Path:
    """A MATLAB v7.3 file: HDF5 behind a 512-byte header, MATLAB's conventions."""
    with h5py.File(path, "w", userblock_size=512) as fh:
        for name, value in variables.items():
            _v73_write(fh, name, value)
        for name in objects:  # a MATLAB object (timeseries): a reference MATLAB decodes
            ds = fh.create_dataset(name, data=np.array([[3707764736, 2, 1, 1, 1, 1]],
                                                       dtype=np.uint32))
            ds.attrs["MATLAB_class"] = np.bytes_("timeseries")
            ds.attrs["MATLAB_object_decode"] = np.int32(3)
    header = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 23 12:00:00 "
              b"2026 HDF5 schema 1.00 .").ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM"
    with path.open("r+b") as fh:
        fh.write(header.ljust(512, b"\0"))
    return sidecar(path, **meta) if meta else path


WRITERS = {"v5": v5, "v7.3": v73}


def expected(x: np.ndarray = X, ids: list[int] | None = None) -> tuple:
    """Trials as (n_trials, N) rows and their ids, for a N x n position array."""
    rows = np.atleast_2d(x.T)
    return rows, ids or list(range(1, rows.shape[0] + 1))


# ----------------------------------------------------------------------------- reading


@pytest.mark.parametrize("version", WRITERS)
def test_columns_of_trials_with_a_time_vector(tmp_path: Path, version: str) -> None:
    path = WRITERS[version](
        tmp_path / "run.mat", {"t": T, "p_cmd": P, "x": X},
        mat_variables={"time_s": "t", "pressure_pa": "p_cmd", "position_m": "x"},
        pressure_reference="gauge", sample_rate_hz=RATE_HZ)
    ds = load(path)
    rows, ids = expected()
    assert ds.source == str(path) and ds.input_name == "pressure_pa"
    np.testing.assert_array_equal(ds.time_s, T)
    np.testing.assert_array_equal(ds.position_m, rows)
    np.testing.assert_array_equal(ds.input, np.tile(P, (3, 1)))  # one command, every trial
    assert ds.trial_ids.tolist() == ids
    assert ds.metadata["mat_variables"]["position_m"] == "x"


@pytest.mark.parametrize("version", WRITERS)
def test_simulink_structure_with_time(tmp_path: Path, version: str) -> None:
    """Simulink's To Workspace 'Structure With Time': time along the rows of values."""
    scope = {"time": T[:, np.newaxis], "blockName": "pma/To Workspace",
             "signals": {"values": X[:, :2], "dimensions": 2.0, "label": "x"}}
    path = WRITERS[version](tmp_path / "sim.mat", {"ScopeData": scope, "p": P})
    ds = read_mat(path, pressure_pa="p", position_m="ScopeData", check_units=False)
    np.testing.assert_array_equal(ds.time_s, T)
    np.testing.assert_array_equal(ds.position_m, X[:, :2].T)
    # a struct field and a column, MATLAB-style and 1-based
    one = read_mat(path, pressure_pa="p", position_m="ScopeData.signals.values(:,2)",
                   time_s="ScopeData.time", check_units=False)
    np.testing.assert_array_equal(one.position_m, X[:, 1][np.newaxis])
    same = read_mat(path, pressure_pa="p", position_m="ScopeData.signals.values(:,2)",
                    time_s="ScopeData", check_units=False)  # a structure's time is its time
    assert same == one


@pytest.mark.parametrize("version", WRITERS)
def test_a_scope_with_several_signals(tmp_path: Path, version: str) -> None:
    """A Scope of two inputs saves ``signals`` as a 1x2 struct array: name one."""
    signals = [{"values": P[:, np.newaxis], "label": "p"},
               {"values": X[:, :1], "label": "x"}]
    path = tmp_path / "scope.mat"
    if version == "v5":
        array = np.zeros((1, 2), dtype=[("values", object), ("label", object)])
        array[0, 0] = (signals[0]["values"], "p")
        array[0, 1] = (signals[1]["values"], "x")
        v5(path, {"ScopeData": {"time": T[:, np.newaxis], "signals": array}})
    else:
        v73(path, {"ScopeData": {"time": T[:, np.newaxis], "signals": signals}})
    ds = read_mat(path, time_s="ScopeData.time", pressure_pa="ScopeData.signals(1).values",
                  position_m="ScopeData.signals(2).values", check_units=False)
    np.testing.assert_array_equal(ds.input, P[np.newaxis])
    np.testing.assert_array_equal(ds.position_m, X[:, :1].T)
    with pytest.raises(DataError, match=r"'ScopeData' is a Simulink structure with 2 signals; "
                                        r"name one, e.g. 'ScopeData.signals\(1\).values'"):
        read_mat(path, pressure_pa="ScopeData.signals(1).values", position_m="ScopeData")
    with pytest.raises(DataError, match=r"ScopeData.signals\(3\) is out of range, it has 2"):
        read_mat(path, pressure_pa="ScopeData.signals(3).values", position_m="ScopeData")


def test_v73_is_read_as_v5(tmp_path: Path) -> None:
    """The same variables through both readers give the same data set."""
    variables = {"t": T, "p": P, "x": X.T.copy(), "note": "rig 2, 20 C",
                 "ok": np.array([True, False])}
    meta = {"mat_variables": {"time_s": "t", "pressure_pa": "p", "position_m": "x"},
            "mat_trials": "rows", "pressure_reference": "gauge"}
    a = load(v5(tmp_path / "a.mat", variables, **meta))
    b = load(v73(tmp_path / "b.mat", variables, **meta))
    assert a == b
    assert _variables(tmp_path / "b.mat", "b")[0]["note"] == "rig 2, 20 C"


def test_one_variable_per_trial_by_pattern_and_list(tmp_path: Path) -> None:
    variables = {"t": T, "x1": X[:, 0], "x2": X[:, 1], "x10": X[:, 2],
                 "p1": P, "p2": P * 0.9, "p10": P * 0.8}
    path = v5(tmp_path / "trials.mat", variables)
    ds = read_mat(path, time_s="t", pressure_pa="p*", position_m="x*", check_units=False)
    assert ds.trial_ids.tolist() == [1, 2, 10]  # the numbers in the names, x2 before x10
    np.testing.assert_array_equal(ds.position_m, X.T)
    np.testing.assert_array_equal(ds.input[2], P * 0.8)
    listed = read_mat(path, time_s="t", pressure_pa=["p2", "p1"], position_m=["x2", "x1"],
                      check_units=False)
    assert listed.trial_ids.tolist() == [2, 1]
    with pytest.raises(DataError, match=at(path, r".*numbers differ: p2/x1, p1/x2; map the "
                                                 "same trials")):
        read_mat(path, time_s="t", pressure_pa=["p2", "p1"], position_m=["x1", "x2"])


def test_default_names_and_sample_rate_from_the_sidecar(tmp_path: Path) -> None:
    path = v5(tmp_path / "plain.mat", {"force_n": P / 1e5, "position_m": X[:, 0]},
              sample_rate_hz=RATE_HZ)
    ds = load(path)
    assert ds.input_name == "force_n" and ds.n_trials == 1
    np.testing.assert_allclose(ds.time_s, T, rtol=0, atol=1e-15)
    no_rate = v5(tmp_path / "norate.mat", {"force_n": P / 1e5, "position_m": X[:, 0]})
    with pytest.raises(DataError, match=at(no_rate, r".*no time: no variable is mapped to "
                                                    r"time_s and no sidecar.*sample_rate_hz")):
        load(no_rate)


def test_layout_of_2d_arrays(tmp_path: Path) -> None:
    """Rows or columns: declared, or settled by the number of samples; else an error."""
    path = v5(tmp_path / "rows.mat", {"t": T, "p": P, "x": X.T.copy()})
    ds = read_mat(path, time_s="t", pressure_pa="p", position_m="x", check_units=False)
    np.testing.assert_array_equal(ds.position_m, X.T)  # 3 x N: the N axis is the samples
    sq = v5(tmp_path / "square.mat", {"p": np.ones((3, 3)) * 1e5, "x": np.zeros((3, 3))},
            sample_rate_hz=RATE_HZ, pressure_reference="gauge",
            mat_variables={"pressure_pa": "p", "position_m": "x"})
    with pytest.raises(DataError, match=at(sq, r".*'p' is 3x3 and no time vector .*declare "
                                               r"the layout: \"mat_trials\": \"columns\"")):
        load(sq)
    ok = load(sq, mat_trials="rows")
    assert ok.n_trials == 3 and ok.n_samples == 3
    with pytest.raises(DataError, match=r"mat_trials is 'diagonal'; it must be \"columns\""):
        load(sq, mat_trials="diagonal")


# ----------------------------------------------------------------------------- bad input


def test_a_missing_variable_lists_what_the_file_holds(tmp_path: Path) -> None:
    path = v5(tmp_path / "m.mat", {"t": T, "p_cmd": P, "xpos": X})
    with pytest.raises(DataError, match=at(path, r" \(MATLAB v5\): position_m: no variable "
                                                 r"'xpos1' in the file \(did you mean 'xpos'"
                                                 r"\?\); the file holds t \[200 float64\], "
                                                 r"p_cmd \[200 float64\], xpos \[200x3 "
                                                 r"float64\]\. Map position_m")):
        read_mat(path, time_s="t", pressure_pa="p_cmd", position_m="xpos1")
    with pytest.raises(DataError, match=at(path, r".*no variable is mapped to pressure_pa "
                                                 r"\(or force_n\) and position_m; the file "
                                                 r"holds t .*\"mat_variables\"")):
        load(path)


def test_shapes_that_are_not_accepted(tmp_path: Path) -> None:
    path = v5(tmp_path / "s.mat", {"t": T, "p": P, "cube": np.zeros((N, 2, 3)),
                                   "x5": X[:150, 0], "tt": np.tile(T, (2, 1)),
                                   "S": {"a": 1.0}, "txt": "hello"})
    accepted = r"accepted are a vector \(1xN or Nx1: one trial\) and a 2-D array of trials"
    with pytest.raises(DataError, match=at(path, r".*'cube' has shape 200x2x3; " + accepted)):
        read_mat(path, time_s="t", pressure_pa="p", position_m="cube")
    with pytest.raises(DataError, match=at(path, r".*samples per trial are x5: 150, not the "
                                                 r"record's 200")):
        read_mat(path, time_s="t", pressure_pa="p", position_m="x5")
    with pytest.raises(DataError, match=r"time_s: 'tt' is 2x200; it must be one vector"):
        read_mat(path, time_s="tt", pressure_pa="p", position_m="x5")
    with pytest.raises(DataError, match=r"'S' holds a struct, not real numbers"):
        read_mat(path, time_s="t", pressure_pa="p", position_m="S")
    with pytest.raises(DataError, match=r"'txt' holds a text, not real numbers"):
        read_mat(path, time_s="t", pressure_pa="p", position_m="txt")
    with pytest.raises(DataError, match=r"S has no field 'b' \(its fields: a\)"):
        read_mat(path, time_s="t", pressure_pa="p", position_m="S.b")


def test_mapping_errors(tmp_path: Path) -> None:
    path = v5(tmp_path / "k.mat", {"t": T, "p": P, "x": X},
              mat_variables={"time": "t", "pressure_pa": "p", "position_m": "x"})
    side = path.with_suffix(".json")
    with pytest.raises(DataError, match=re.escape(f"the JSON sidecar {side}: 'mat_variables' "
                                                  "has the key 'time' (did you mean 'time_s'?)")):
        load(path)
    sidecar(path, mat_variables={"time_s": "t", "pressure_pa": "p", "position_m": "x"})
    with pytest.raises(DataError, match=at(path, r".*position_m is mapped to 'x' in the JSON "
                                                 r"sidecar .* but to 'y' by the keyword")):
        load(path, position_m="y")
    with pytest.raises(DataError, match=r"both pressure_pa and force_n are mapped"):
        load(path, force_n="p")
    with pytest.raises(TypeError):
        load(path, positon_m="x")  # unknown keywords are refused
    sidecar(path, mat_variable={"time_s": "t", "pressure_pa": "p", "position_m": "x"})
    with pytest.raises(DataError, match=r"'mat_variable' looks like a misspelling of "
                                        r"'mat_variables'"):
        load(path)


def test_non_finite_samples_name_the_variable_and_sample(tmp_path: Path) -> None:
    x = X.copy()
    x[17, 2] = np.nan
    path = v5(tmp_path / "nan.mat", {"t": T, "p": P, "x": x})
    with pytest.raises(DataError, match=at(path, r".*position_m: x\(:,3\) is nan at sample 18 "
                                                 r"\(MATLAB's 1-based index\); missing")):
        read_mat(path, time_s="t", pressure_pa="p", position_m="x")


def test_a_matlab_object_says_how_to_save_it(tmp_path: Path) -> None:
    path = v73(tmp_path / "ts.mat", {"p": P}, objects=("x_ts",), sample_rate_hz=RATE_HZ)
    with pytest.raises(DataError, match=at(path, r" \(MATLAB v7.3\): position_m: variable "
                                                 r"'x_ts' is a MATLAB object \(timeseries.*"
                                                 r"'Structure With Time'")):
        read_mat(path, pressure_pa="p", position_m="x_ts")


def test_v73_without_h5py(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = v73(tmp_path / "big.mat", {"t": T, "p": P, "x": X})
    real_import = builtins.__import__

    def no_h5py(name: str, *args: object, **kwargs: object) -> object:
        if name == "h5py":
            raise ImportError("No module named 'h5py'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_h5py)
    with pytest.raises(DataError, match=at(path, r": this is a MATLAB v7.3 \(HDF5\) file; "
                                                 r"reading .* needs h5py: pip install h5py")):
        read_mat(path, time_s="t", pressure_pa="p", position_m="x")


def test_not_a_mat_file(tmp_path: Path) -> None:
    path = tmp_path / "junk.mat"
    path.write_bytes(b"not a MATLAB file at all" * 10)
    with pytest.raises(DataError, match=at(path, r": not a readable MATLAB .mat file")):
        load(path)
    with pytest.raises(DataError, match=at(tmp_path / "none.mat", r": file not found")):
        load(tmp_path / "none.mat")


def test_single_precision_clock_is_a_uniform_grid(tmp_path: Path) -> None:
    """A 750 Hz time vector saved as single: uniform to its precision, so rebuilt."""
    n = 7500
    t32 = (np.arange(n) / 750.0).astype(np.float32)
    path = v5(tmp_path / "single.mat", {"t": t32, "p": np.full(n, 1e5),
                                        "x": np.zeros(n)}, pressure_reference="gauge")
    with pytest.warns(DataWarning, match=r"variable 't': time_s is stored in single "
                      r"precision, with a resolution of .*rebuilt as t0 \+ k / rate"):
        ds = load(path, time_s="t", pressure_pa="p", position_m="x")
    np.testing.assert_allclose(np.diff(ds.time_s), 1 / 750.0, rtol=1e-9)
    gap = np.delete(np.arange(n + 1) / 750.0, 4000).astype(np.float32)  # one lost sample
    lost = v5(tmp_path / "gap.mat", {"t": gap, "p": np.full(n, 1e5), "x": np.zeros(n)},
              pressure_reference="gauge")
    with pytest.warns(DataWarning, match=at(lost, r".*: 1 gap in the clock, 1 sample not "
                                                  r"observed .*after sample 4000")):
        ds = load(lost, time_s="t", pressure_pa="p", position_m="x")
    assert ds.n_samples == n + 1 and np.flatnonzero(~ds.observed[0]).tolist() == [4000]


def test_unit_checks_and_declarations_apply_to_mat_files(tmp_path: Path) -> None:
    """The plausibility checks and the sidecar's declarations, as for CSV."""
    path = v5(tmp_path / "bar.mat", {"t": T, "p": P / 1e5, "x": X})  # pressure in bar
    with pytest.raises(DataError, match=at(path, r".*pressure_pa looks like MPa .* or bar .*"
                                                 r"x\(:,1\), trial 1, sample")):
        read_mat(path, time_s="t", pressure_pa="p", position_m="x")
    n = 4 * 50
    t = np.arange(n) / RATE_HZ
    variables = {"t": t, "p": 2e5 * (1 + np.sin(2 * np.pi * t * RATE_HZ / 50)),
                 "x": np.zeros(n)}
    mapped = {"time_s": "t", "pressure_pa": "p", "position_m": "x"}
    periodic = v5(tmp_path / "periodic.mat", variables, mat_variables=mapped,
                  input_between_samples="linear", period_samples=50,
                  starts_in_steady_state=True, pressure_reference="gauge")
    ds = load(periodic)
    assert ds.input_between_samples == "linear"
    assert ds.period_samples == 50 and ds.n_periods == 4 and ds.starts_in_steady_state
    sidecar(periodic, mat_variables=mapped, period_samples=60)
    with pytest.raises(DataError, match=r"'period_samples' is 60, which does not divide"):
        load(periodic)
    sidecar(periodic, mat_variables=mapped, input_between_sample="linear")
    with pytest.raises(DataError, match=r"looks like a misspelling of 'input_between_samples'"):
        load(periodic)


def test_unsupported_suffix_lists_the_formats(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"use one of \.csv, \.txt, \.dat, \.tsv, \.lvm, \.nc, "
                                        r"\.mat \(\.txt, \.dat, \.tsv and LabVIEW's \.lvm: text "
                                        r"read like \.csv; \.mat: MATLAB"):
        load(tmp_path / "x.xlsx")
    ds = load(v5(tmp_path / "w.mat", {"t": T, "p": P, "x": X}), time_s="t",
              pressure_pa="p", position_m="x", check_units=False)
    with pytest.raises(DataError, match=r"unsupported file type '\.mat'; use one of \.csv, "
                                        r"\.nc\.$"):
        save(ds, tmp_path / "out.mat")  # read only


# ----------------------------------------------------------------------------- rigs, kinds


def _pressure_csv(tmp_path: Path, name: str, **meta: object) -> Path:
    path = tmp_path / name
    lines = ["trial,time_s,pressure_pa,position_m"]
    lines += [f"1,{k / 100:g},{1e5 + 1e4 * k},{1e-3 * k}" for k in range(5)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return sidecar(path, **meta) if meta else path


def test_a_rig_must_drive_the_data_input(tmp_path: Path) -> None:
    path = _pressure_csv(tmp_path, "rig.csv", rig=FORCE_RIG, pressure_reference="gauge")
    message = ("^Dataset from " + re.escape(str(path)) + r": metadata 'rig' "
               r"\(force_oscillator\) has input_kind 'force', which drives 'force_n', but the "
               r"data's input is 'pressure_pa'; fix the rig in the sidecar \(a pressure-driven")
    with pytest.raises(DataError, match=message):
        read_csv(path)
    mat = v5(tmp_path / "rig.mat", {"t": T, "u": P / 1e5, "x": X}, rig={
        k: v for k, v in FORCE_RIG.items() if k != "input_kind"})  # a rig's default: pressure
    with pytest.raises(DataError, match=r"has input_kind 'pressure', which drives "
                                        r"'pressure_pa', but the data's input is 'force_n'"):
        read_mat(mat, time_s="t", force_n="u", position_m="x")
    with pytest.raises(DataError, match=r"^Dataset: metadata 'rig'"):
        Dataset(time_s=T, input=X.T, position_m=X.T, trial_ids=np.arange(3),
                input_name="force_n", metadata={"rig": {"input_kind": "pressure"}})
    # a matching rig, and free-form notes about a rig, are fine
    sidecar(mat, rig=FORCE_RIG)
    assert load(mat, time_s="t", force_n="u", position_m="x").input_name == "force_n"
    sidecar(mat, rig={"muscle": "DMSP-10"})
    assert load(mat, time_s="t", force_n="u", position_m="x").n_trials == 3


def test_check_same_input_kind_names_both_files(tmp_path: Path) -> None:
    a = read_csv(_pressure_csv(tmp_path, "a.csv", pressure_reference="gauge"))
    b = read_csv(_pressure_csv(tmp_path, "b.csv", pressure_reference="gauge"))
    f = read_mat(v5(tmp_path / "f.mat", {"t": T, "u": P / 1e5, "x": X}), time_s="t",
                 force_n="u", position_m="x")
    assert check_same_input_kind([a, b]) == "pressure_pa"
    assert check_same_input_kind([f]) == "force_n"
    with pytest.raises(DataError, match=at(tmp_path / "f.mat", r": its input is 'force_n' but "
                                           + re.escape(str(tmp_path / "a.csv")) +
                                           r" has 'pressure_pa'; .*fit them separately")):
        check_same_input_kind([a, b, f])
    with pytest.raises(DataError, match=r"no data sets given"):
        check_same_input_kind([])
    with pytest.raises(TypeError):
        check_same_input_kind([a, "b.csv"])


# ----------------------------------------------------------------------------- a real file


@pytest.mark.skipif(not REAL.is_dir(), reason="the shared Bouc-Wen files are optional")
def test_reads_a_real_matlab_file() -> None:
    """A file MATLAB wrote (v5, PCWIN64, 2015): the benchmark's test multisine input."""
    path = REAL / "uval_multisine.mat"
    with path.open("rb") as fh:
        assert fh.read(19) == b"MATLAB 5.0 MAT-file"
    variables, version = _variables(path, str(path))
    assert version == "v5" and list(variables) == ["uval_multisine"]
    u = variables["uval_multisine"]
    assert u.shape == (8192,) and u.dtype == np.float64
    assert 45 < float(np.sqrt(np.mean(u**2))) < 55  # the README's 50 N RMS
    npz = REAL.parent / "boucwen.npz"
    if npz.is_file():
        np.testing.assert_array_equal(u, np.load(npz)["u_test_multisine"])
    # the file holds the input only: the reader says so, and what the file holds
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match=at(path, r" \(MATLAB v5\): no variable is mapped "
                                                     r"to pressure_pa \(or force_n\) and "
                                                     r"position_m; the file holds "
                                                     r"uval_multisine \[8192 float64\]")):
            read_mat(path)
