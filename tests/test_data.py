"""Tests for pmabayes.data: formats, round trips and every rejected input."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from pmabayes.data import (
    DataError,
    Dataset,
    DataWarning,
    check_time_grid,
    load,
    read_csv,
    read_netcdf,
    save,
    write_csv,
    write_netcdf,
)

HEADER = "trial,time_s,pressure_pa,position_m"


def make_dataset(
    n_trials: int = 3, n_samples: int = 50, *, input_name: str = "pressure_pa", **kw
) -> Dataset:
    rng = np.random.default_rng(42)
    t = 0.25 + np.arange(n_samples) * 2e-3  # non-zero start, awkward binary interval
    u = rng.uniform(0.0, 6e5, (n_trials, n_samples))
    if input_name == "force_n":
        u = rng.normal(0.0, 3.0, (n_trials, n_samples))
    x = rng.normal(0.0, 0.01, (n_trials, n_samples))
    x[0, 0] = -0.0  # sign of zero must survive
    x[0, 1] = 1.2345678901234567e-300  # subnormal-ish extremes must survive
    return Dataset(
        time_s=t,
        input=u,
        position_m=x,
        trial_ids=np.arange(n_trials) * 10 + 7,
        input_name=input_name,
        **kw,
    )


def write(tmp_path: Path, text: str, name: str = "d.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def rows(*lines: str, header: str = HEADER) -> str:
    return "\n".join((header, *lines)) + "\n"


# Two trials x 3 samples at 100 Hz; lines 2-4 are trial 1, lines 5-7 are trial 2.
GOOD = [
    "1,0.00,1000,0.001",
    "1,0.01,2000,0.002",
    "1,0.02,3000,0.003",
    "2,0.00,1500,0.001",
    "2,0.01,2500,0.002",
    "2,0.02,3500,0.003",
]


def with_line(lineno: int, text: str) -> list[str]:
    """GOOD with file line `lineno` (header = 1) replaced."""
    out = list(GOOD)
    out[lineno - 2] = text
    return out


def at(path: Path, rest: str) -> str:
    """Regex: message starts with the file name, then `rest` (a regex)."""
    return re.escape(str(path)) + rest


def bitwise_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


# ----------------------------------------------------------------------------- round trips


def test_good_csv_reads(tmp_path: Path) -> None:
    ds = read_csv(write(tmp_path, rows(*GOOD)))
    assert ds.n_trials == 2 and ds.n_samples == 3
    assert ds.trial_ids.dtype == np.int64 and ds.trial_ids.tolist() == [1, 2]
    np.testing.assert_array_equal(ds.time_s, [0.0, 0.01, 0.02])
    np.testing.assert_array_equal(ds.input, [[1000, 2000, 3000], [1500, 2500, 3500]])
    assert ds.input.dtype == np.float64 and ds.position_m.dtype == np.float64
    assert ds.input_name == "pressure_pa"
    assert ds.metadata == {}
    assert ds.source == str(tmp_path / "d.csv")


def test_csv_round_trip_bit_exact_with_sidecar(tmp_path: Path) -> None:
    meta = {
        "synthetic": True,
        "description": "unit test \u2013 \u00fcn\u00efcode",
        "sample_rate_hz": 500.0,
        "rig": {"muscle": "DMSP-10", "length_m": 0.2},
        "generator": [1, 2, 3],
    }
    ds = make_dataset(metadata=meta)
    path = tmp_path / "run.csv"
    write_csv(ds, path)
    assert json.loads((tmp_path / "run.json").read_text(encoding="utf-8")) == meta
    back = read_csv(path)
    for name in ("time_s", "input", "position_m", "trial_ids"):
        assert bitwise_equal(getattr(back, name), getattr(ds, name)), name
    assert back.metadata == meta
    assert back == ds
    assert path.read_text().splitlines()[0] == HEADER


def test_csv_without_metadata_writes_no_sidecar_and_removes_stale_one(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    write_csv(make_dataset(metadata={"description": "old"}), path)
    assert (tmp_path / "run.json").exists()
    write_csv(make_dataset(), path)
    assert not (tmp_path / "run.json").exists()
    assert read_csv(path).metadata == {}


def test_csv_round_trip_force(tmp_path: Path) -> None:
    ds = make_dataset(input_name="force_n")
    path = tmp_path / "osc.csv"
    write_csv(ds, path)
    assert path.read_text().splitlines()[0] == "trial,time_s,force_n,position_m"
    back = read_csv(path)  # small forces must not trip the pressure unit check
    assert back.input_name == "force_n"
    assert bitwise_equal(back.input, ds.input)


@pytest.mark.parametrize("input_name", ["pressure_pa", "force_n"])
def test_netcdf_round_trip_exact(tmp_path: Path, input_name: str) -> None:
    meta = {"synthetic": False, "sample_rate_hz": 500.0, "nested": {"a": [1, None, "x"]}}
    ds = make_dataset(input_name=input_name, metadata=meta)
    path = tmp_path / "run.nc"
    write_netcdf(ds, path)
    back = read_netcdf(path)
    for name in ("time_s", "input", "position_m", "trial_ids"):
        assert bitwise_equal(getattr(back, name), getattr(ds, name)), name
    assert back.metadata == meta
    assert back.input_name == input_name
    assert back.source == str(path)


def test_xarray_round_trip() -> None:
    ds = make_dataset(metadata={"rig": "A"})
    xds = ds.to_xarray()
    assert set(xds.data_vars) == {"pressure_pa", "position_m"}
    assert xds["pressure_pa"].attrs["units"] == "Pa"
    assert xds["trial"].values.tolist() == ds.trial_ids.tolist()
    assert json.loads(xds.attrs["metadata_json"]) == {"rig": "A"}
    xds["position_m"].values[0, 0] = 1.0  # to_xarray gives independent, writable copies
    assert ds.position_m[0, 0] != 1.0
    # dimension order in the xarray object must not matter
    back = Dataset.from_xarray(ds.to_xarray().transpose("time_s", "trial"))
    assert back == ds


def test_from_xarray_rejects_bad_structure() -> None:
    xds = make_dataset().to_xarray()
    with pytest.raises(TypeError):
        Dataset.from_xarray({"a": 1})  # type: ignore[arg-type]
    with pytest.raises(DataError, match=r"src\.nc: unexpected data variable.*temperature"):
        Dataset.from_xarray(xds.assign(temperature=xds["position_m"]), source="src.nc")
    with pytest.raises(DataError, match=r"exactly one of pressure_pa or force_n"):
        Dataset.from_xarray(xds.drop_vars("pressure_pa"))
    bad = xds.assign_attrs(metadata_json="{not json")
    with pytest.raises(DataError, match=r"metadata_json is not valid JSON"):
        Dataset.from_xarray(bad)


@pytest.mark.parametrize("suffix", [".csv", ".nc", ".CSV"])
def test_load_save_dispatch(tmp_path: Path, suffix: str) -> None:
    ds = make_dataset(metadata={"description": "dispatch"})
    path = tmp_path / f"x{suffix}"
    save(ds, path)
    assert load(path) == ds
    assert load(str(path)) == ds


def test_load_save_reject_unknown_suffix(tmp_path: Path) -> None:
    ds = make_dataset()
    pattern = r": unsupported file type '\.txt'.*\.csv, \.nc"
    with pytest.raises(DataError, match=at(tmp_path / "x.txt", pattern)):
        save(ds, tmp_path / "x.txt")
    path = write(tmp_path, rows(*GOOD), "x.xlsx")
    with pytest.raises(DataError, match=at(path, r": unsupported file type")):
        load(path)
    with pytest.raises(DataError, match=r"no suffix"):
        load(tmp_path / "x")


def test_load_forwards_kwargs(tmp_path: Path) -> None:
    path = write(tmp_path, rows("1,0,0.5,0.001", "1,0.01,0.6,0.001"))
    with pytest.raises(DataError, match="MPa"):
        load(path)
    assert load(path, check_units=False).input.max() == 0.6
    nc = tmp_path / "x.nc"
    write_netcdf(load(path, check_units=False), nc)
    with pytest.raises(DataError, match=at(nc, r": pressure_pa looks like MPa.*trial 1")):
        load(nc)
    assert load(nc, check_units=False).n_samples == 2


def test_column_order_bom_crlf_and_whitespace(tmp_path: Path) -> None:
    text = "\ufeffposition_m, pressure_pa ,trial,time_s\r\n0.001,1000,1,0\r\n0.002, 2000 ,1,0.01"
    ds = read_csv(write(tmp_path, text))
    np.testing.assert_array_equal(ds.input, [[1000, 2000]])
    np.testing.assert_array_equal(ds.position_m, [[0.001, 0.002]])


# ----------------------------------------------------------------------------- Dataset API


def test_properties() -> None:
    ds = make_dataset(n_trials=3, n_samples=50)
    assert ds.n_trials == 3 and ds.n_samples == 50
    assert ds.dt_s == pytest.approx(2e-3, rel=1e-12)
    assert ds.sample_rate_hz == pytest.approx(500.0, rel=1e-12)
    assert ds.pressure_pa is ds.input
    np.testing.assert_allclose(ds.mean_position_m, ds.position_m.mean(axis=0))
    assert ds.mean_position_m.shape == (50,)
    assert "n_trials=3" in repr(ds)


def test_pressure_pa_rejected_for_force_data() -> None:
    ds = make_dataset(input_name="force_n", source="osc.csv")
    with pytest.raises(DataError, match=r"osc\.csv: .*'force_n', not pressure"):
        _ = ds.pressure_pa


def test_select_trials() -> None:
    ds = make_dataset(n_trials=4, metadata={"rig": "A"}, source="s.csv")
    sub = ds.select_trials([2, 0])
    assert sub.trial_ids.tolist() == [ds.trial_ids[2], ds.trial_ids[0]]
    np.testing.assert_array_equal(sub.input, ds.input[[2, 0]])
    np.testing.assert_array_equal(sub.time_s, ds.time_s)
    assert sub.metadata == {"rig": "A"} and sub.source == "s.csv"
    assert ds.select_trials(-1).trial_ids.tolist() == [ds.trial_ids[-1]]
    assert ds.select_trials(np.array([1])).n_trials == 1
    with pytest.raises(DataError, match=r"s\.csv: trial index 4 is out of range for 4 trials"):
        ds.select_trials([4])
    with pytest.raises(DataError, match="repeated"):
        ds.select_trials([1, -3])
    with pytest.raises(DataError, match="one or more integer"):
        ds.select_trials([])
    with pytest.raises(DataError, match="one or more integer"):
        ds.select_trials([0.5])


def test_arrays_read_only_and_copied() -> None:
    t = np.arange(4) * 0.1
    u = np.full((1, 4), 1e5)
    ds = Dataset(time_s=t, input=u, position_m=np.zeros((1, 4)), trial_ids=[3])
    u[0, 0] = 0.0
    assert ds.input[0, 0] == 1e5
    for name in ("time_s", "input", "position_m", "trial_ids"):
        arr = getattr(ds, name)
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        ds.input_name = "force_n"  # type: ignore[misc]
    assert ds.trial_ids.dtype == np.int64 and ds.input.dtype == np.float64


def test_unknown_kwargs_rejected(tmp_path: Path) -> None:
    ds = make_dataset()
    csv = tmp_path / "a.csv"
    nc = tmp_path / "a.nc"
    write_csv(ds, csv)
    write_netcdf(ds, nc)
    calls = [
        lambda: read_csv(csv, check_unit=False),
        lambda: read_netcdf(nc, bogus=1),
        lambda: write_csv(ds, csv, precision=3),
        lambda: write_netcdf(ds, nc, engine="netcdf4"),
        lambda: load(csv, strict=True),
        lambda: load(nc, strict=True),
        lambda: save(ds, csv, overwrite=True),
        lambda: ds.select_trials([0], copy=True),
        lambda: Dataset.from_xarray(ds.to_xarray(), path="x"),
        lambda: Dataset(ds.time_s, ds.input, ds.position_m, ds.trial_ids, units="Pa"),
    ]
    for call in calls:
        with pytest.raises(TypeError):
            call()


def test_writers_reject_non_dataset(tmp_path: Path) -> None:
    with pytest.raises(TypeError):
        write_csv({"time_s": []}, tmp_path / "a.csv")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        write_netcdf(None, tmp_path / "a.nc")  # type: ignore[arg-type]


def test_write_rejects_non_json_metadata(tmp_path: Path) -> None:
    ds = make_dataset(metadata={"gain": np.int64(3)})
    with pytest.raises(DataError, match=r"a\.csv \(metadata\): metadata cannot be stored as JSON"):
        write_csv(ds, tmp_path / "a.csv")
    ds = make_dataset(metadata={"pair": (1, 2)})
    with pytest.raises(DataError, match="would not read back identically"):
        write_netcdf(ds, tmp_path / "a.nc")
    assert not (tmp_path / "a.csv").exists()


def test_write_csv_rejects_json_suffix(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"suffix \.json"):
        write_csv(make_dataset(), tmp_path / "a.json")


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"input": np.zeros((2, 4))}, r"x\.csv: input must have shape \(n_trials, 5\)"),
        ({"input": np.zeros(5)}, r"np\.newaxis"),
        ({"position_m": np.zeros((3, 5))}, r"input has shape \(2, 5\) but position_m"),
        ({"time_s": np.array([0.0])}, r"at least 2 samples"),
        ({"time_s": np.array([0, 1, 2, 4, 5.0])},
         r"sample 3: time_s is not uniformly sampled.*from sample 2"),
        ({"time_s": np.array([0, 1, 1, 2, 3.0])},
         r"sample 2: time_s = 1 is not after 1 on sample 1; .*strictly increasing"),
        ({"time_s": np.array([0, 1, np.nan, 3, 4])}, r"sample 2: time_s = nan is not finite"),
        ({"input": np.array([[0, 1, 2, 3, np.inf]] * 2)}, r"input of trial 1 is inf at sample 4"),
        ({"trial_ids": np.array([1, 1])}, r"trial 1 appears 2 times"),
        ({"trial_ids": np.array([1.0, 2.0])}, r"trial_ids must be an integer array"),
        ({"input": np.array([["a"] * 5] * 2)}, r"input must be a real numeric array"),
        ({"input_name": "pressure"}, r"input_name must be one of pressure_pa, force_n"),
        ({"metadata": [("a", 1)]}, r"metadata must be a dict"),
        ({"metadata": {"sample_rate_hz": 999.0}}, r"sample_rate_hz = 999 Hz disagrees.* 1 Hz"),
        ({"metadata": {"sample_rate_hz": "1 kHz"}}, r"is not a positive finite number"),
    ],
)
def test_dataset_validation(kwargs: dict, pattern: str) -> None:
    args = {
        "time_s": np.arange(5.0),
        "input": np.ones((2, 5)),
        "position_m": np.zeros((2, 5)),
        "trial_ids": np.array([1, 2]),
        "source": "x.csv",
    }
    args.update(kwargs)
    with pytest.raises(DataError, match=pattern):
        Dataset(**args)


def test_equality() -> None:
    a = make_dataset(source="a.csv")
    b = make_dataset(source="b.csv")
    assert a == b  # source is provenance, not data
    assert a != make_dataset(metadata={"x": 1})
    assert a != a.select_trials([0, 1])
    assert a != "a"


# ----------------------------------------------------------------------------- bad files


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.csv"
    with pytest.raises(DataError, match=at(path, ": file not found")):
        read_csv(path)
    with pytest.raises(DataError, match=at(tmp_path / "nope.nc", ": file not found")):
        read_netcdf(tmp_path / "nope.nc")
    with pytest.raises(DataError, match=at(tmp_path, ": not a regular file")):
        read_csv(tmp_path)


@pytest.mark.parametrize("text", ["", "\n\n", "   \n"])
def test_empty_file(tmp_path: Path, text: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(DataError, match=at(path, r": file is empty; expected a header")):
        read_csv(path)


def test_header_only(tmp_path: Path) -> None:
    path = write(tmp_path, HEADER + "\n")
    with pytest.raises(DataError, match=at(path, r": line 2: header only, no data rows")):
        read_csv(path)


def test_missing_header(tmp_path: Path) -> None:
    path = write(tmp_path, "\n".join(GOOD))
    with pytest.raises(DataError, match=at(path, r": line 1: expected a header line")):
        read_csv(path)


@pytest.mark.parametrize(
    ("header", "pattern"),
    [
        ("trial,time_s,pressure,position_m", r"'pressure' looks like 'pressure_pa'"),
        ("trial,time,pressure_pa,position_m", r"'time' looks like 'time_s'.*ing column 'time_s'"),
        ("Trials,time_s,pressure_pa,position_m", r"'Trials' looks like 'trial'"),
        ("trial,time_s,force,position_m", r"'force' looks like 'force_n'"),
        ("trial,time_s,pressure_pa,position_cm",
         r"pmabayes does not know the unit 'cm' of position; it reads position_m, position_mm, "
         r"position_um \(if the values are in centimetres: multiply by 10 and name the column "
         r"position_mm\)"),
        ("trial,time_min,pressure_pa,position_m",
         r"unit 'min' of time.*minutes: multiply by 60 and name the column time_s"),
        ("trial,time_s,pressure_psi,pressure_kpa,position_m",
         r"pressure_psi and pressure_kpa both give pressure_pa: keep one column for pressure"),
        ("trial,time_s,pressure_pa", r"missing column 'position_m'"),
        ("trial,time_s,pressure_pa,position_m,temp_c", r"unexpected column 'temp_c'"),
        ("trial,time_s,pressure_pa,position_m,time_s", r"'time_s' appears twice \(columns 2 and 5"),
        ("trial,time_s,pressure_pa,force_n,position_m", r"both pressure_pa and force_n"),
        ("trial,time_s,position_m", r"missing input column: need one of 'pressure_pa' or 'f"),
        ("trial,time_s,pressure_pa,position_m,", r"column 5 has an empty name"),
    ],
)
def test_bad_header(tmp_path: Path, header: str, pattern: str) -> None:
    path = write(tmp_path, rows("1,0,1000,0.001", header=header))
    with pytest.raises(DataError, match=at(path, r": line 1 \(header\): .*" + pattern)) as info:
        read_csv(path)
    assert "expected columns: trial, time_s, position_m and exactly one of" in str(info.value)


@pytest.mark.parametrize(
    ("lineno", "text", "pattern"),
    [
        (4, "1,0.02,3000", r"line 4 has 3 fields; every row needs 4"),
        (3, "1,0.01,2000,0.002,9", r"line 3 has 5 fields"),
        (5, "2,0.00,abc,0.001", r"line 5, column pressure_pa: 'abc' is not a number"),
        (6, "2,0.01,2500,", r"line 6, column position_m: '' is not a number"),
        (3, "1,0.01,2000,1_0", r"line 3, column position_m: '1_0' is not a number"),
        (7, "2,0.02,3500,nan", r"line 7, column position_m: value 'nan' is NaN or infinite"),
        (2, "1,0.00,inf,0.001", r"line 2, column pressure_pa: value 'inf' is NaN or infinite"),
        (4, "1,0.02,-Infinity,0.003", r"line 4, column pressure_pa: .*NaN or infinite"),
        (5, "2.5,0.00,1500,0.001", r"line 5, column trial: trial id '2\.5' is not an integer"),
        (6, "x,0.01,2500,0.002", r"line 6, column trial: trial id 'x' is not an integer"),
        (3, "1e0,0.01,2000,0.002", r"line 3, column trial: trial id '1e0' is not an integer"),
        (2, "1,0.00,1000,0.001 # note", r"line 2, column position_m: '0.001 # note'"),
        (3, "", r"line 3 is blank; remove blank lines"),
    ],
)
def test_bad_rows(tmp_path: Path, lineno: int, text: str, pattern: str) -> None:
    path = write(tmp_path, rows(*with_line(lineno, text)))
    with pytest.raises(DataError, match=at(path, ": " + pattern)):
        read_csv(path)


def test_first_bad_row_is_reported(tmp_path: Path) -> None:
    # Later errors of other kinds must not mask the first one in file order.
    lines = with_line(3, "1,0.01,nan,0.002")
    lines[4] = "2,0.00,zzz,0.001"
    path = write(tmp_path, rows(*lines))
    with pytest.raises(DataError, match=at(path, r": line 3, column pressure_pa")):
        read_csv(path)


def test_trial_not_contiguous(tmp_path: Path) -> None:
    lines = ["1,0.00,1000,0.001", "2,0.00,1500,0.001", "1,0.01,2000,0.002", "2,0.01,2500,0.002"]
    path = write(tmp_path, rows(*lines))
    with pytest.raises(
        DataError, match=at(path, r": line 4: trial 1 reappears after trial 2 \(first .* line 2\)")
    ):
        read_csv(path)


@pytest.mark.parametrize(
    ("lineno", "text", "pattern"),
    [
        (4, "1,0.005,3000,0.003", r"trial 1: line 4: time_s = 0.005 is not after 0.01 on line 3"),
        (6, "2,0.00,2500,0.002", r"trial 2: line 6: time_s = 0 is not after 0 on line 5"),
    ],
)
def test_time_not_increasing(tmp_path: Path, lineno: int, text: str, pattern: str) -> None:
    path = write(tmp_path, rows(*with_line(lineno, text)))
    with pytest.raises(DataError, match=at(path, ": " + pattern)):
        read_csv(path)


def test_non_uniform_sampling(tmp_path: Path) -> None:
    lines = [f"3,{k * 0.01!r},1000,0.001" for k in range(6)]
    lines[4] = "3,0.043,1000,0.001"  # 30% of a step off: not a DAQ's jitter
    path = write(tmp_path, rows(*lines))
    with pytest.raises(
        DataError,
        match=at(path, r": trial 3: line 6: time_s = 0.043 comes after 0.03 on line 5: an "
                       r"interval of 1.300 steps .* more than 10% of a step off"),
    ):
        read_csv(path)
    lines[4] = "3,0.0400001,1000,0.001"  # 1e-5 of a step: jitter, read as the grid
    with pytest.warns(DataWarning, match=r"deviate from the uniform grid by up to"):
        assert read_csv(write(tmp_path, rows(*lines))).n_samples == 6
    lines[4] = "3,0.04000000000001,1000,0.001"  # within 1e-6: accepted as it is
    assert read_csv(write(tmp_path, rows(*lines))).n_samples == 6


def test_a_missing_sample_is_not_observed(tmp_path: Path) -> None:
    lines = [f"1,{k * 0.01!r},{1000 + k},0.001" for k in (0, 1, 2, 4, 5, 6)]
    path = write(tmp_path, rows(*lines))
    with pytest.warns(DataWarning, match=at(path, r": 1 gap in the clock, 1 sample not "
                                                  r"observed .*after line 4")):
        ds = read_csv(path)
    assert ds.n_samples == 7 and ds.n_missing == 1
    assert ds.observed.tolist() == [[True, True, True, False, True, True, True]]
    assert math.isnan(ds.position_m[0, 3]) and ds.input[0, 3] == 1002  # held


def _rounded_rows(rate_hz: float, n: int, trials=(1, 2), decimals: int = 6, drop=None,
                  jitter_s: float = 0.0) -> list[str]:
    """A lab's CSV rows: the clock printed to ``decimals`` places (0.001333, ...)."""
    rng = np.random.default_rng(3)
    out = []
    for tid in trials:
        for k in range(n):
            if k == drop:
                continue
            t = k / rate_hz + (jitter_s * rng.standard_normal() if jitter_s else 0.0)
            out.append(f"{tid},{t:.{decimals}f},{1000 + k},{1e-3 * math.sin(k / 7)!r}")
    return out


def test_a_clock_rounded_to_its_printed_precision_is_a_uniform_grid(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*_rounded_rows(750.0, 400)))
    with pytest.raises(DataError, match="not uniformly sampled"):  # the strict check alone
        check_time_grid(np.round(np.arange(400) / 750.0, 6))
    with pytest.warns(DataWarning, match=r"printed to 1e-06 s.*rebuilt as t0 \+ k / rate "
                      r"from a straight-line fit of the times, 750"):
        ds = read_csv(path)
    assert ds.n_samples == 400 and ds.n_trials == 2
    # the fitted line is off by far less than the 1 us rounding (1% of it)
    assert np.abs(ds.time_s - np.arange(400) / 750.0).max() < 1e-8
    assert np.abs(np.diff(ds.time_s) - 1 / 750.0).max() < 1e-11


def test_the_rounded_grid_comes_from_the_sidecar_rate(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*_rounded_rows(750.0, 60)))
    path.with_suffix(".json").write_text(json.dumps({"sample_rate_hz": 750.0}))
    with pytest.warns(DataWarning, match="from the sidecar's sample_rate_hz = 750"):
        ds = read_csv(path)
    assert np.abs(ds.time_s - np.arange(60) / 750.0).max() < 1e-12


def test_exact_times_are_kept_without_a_note(tmp_path: Path) -> None:
    import warnings

    lines = [f"1,{k / 750.0!r},1000,0.001" for k in range(50)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = read_csv(write(tmp_path, rows(*lines)))
    assert np.array_equal(ds.time_s, np.array([k / 750.0 for k in range(50)]))


@pytest.mark.parametrize("kind", ["gap", "jitter"])
def test_gaps_and_jitter_beyond_the_rounding_are_a_lab_clock(tmp_path: Path, kind: str) -> None:
    lab = (_rounded_rows(750.0, 300, trials=(1,), drop=120) if kind == "gap"
           else _rounded_rows(750.0, 300, trials=(1,), jitter_s=5e-6))
    path = write(tmp_path, rows(*lab))
    found = r"1 gap in the clock" if kind == "gap" else r"The times deviate from the uniform grid"
    with pytest.warns(DataWarning, match=at(path, ": " + found)):
        ds = read_csv(path)
    assert ds.n_samples == 300 and ds.n_missing == (kind == "gap")
    np.testing.assert_allclose(ds.time_s, np.arange(300) / 750.0, rtol=0, atol=2e-6)


def test_single_sample_trial(tmp_path: Path) -> None:
    path = write(tmp_path, rows("4,0,1000,0.001"))
    with pytest.raises(DataError, match=at(path, r": trial 4 has only 1 sample \(line 2\)")):
        read_csv(path)


def test_unequal_trial_lengths(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*GOOD[:5]))
    with pytest.raises(
        DataError,
        match=at(path, r": trials have unequal lengths .*trial 1: 3 \(lines 2-4\), trial 2: 2"),
    ):
        read_csv(path)


def test_different_sample_times(tmp_path: Path) -> None:
    lines = [*GOOD[:3], "2,0.10,1500,0.001", "2,0.11,2500,0.002", "2,0.12,3500,0.003"]
    path = write(tmp_path, rows(*lines))
    with pytest.raises(
        DataError, match=at(path, r": trial 2: line 5: time_s = 0.1 but trial 1 has 0 .*line 2")
    ):
        read_csv(path)


def test_invalid_utf8(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    path.write_bytes((rows(*GOOD[:2]) + "1,0.02,3000,0.003\xff\n").encode("latin-1"))
    with pytest.raises(DataError, match=at(path, r": line 4: bytes are not valid UTF-8")):
        read_csv(path)


# ----------------------------------------------------------------------------- unit checks


@pytest.mark.parametrize("p", ["0.6", "6", "-0.2", "20"])
def test_pressure_looks_like_mpa_or_bar(tmp_path: Path, p: str) -> None:
    path = write(tmp_path, rows("1,0,0,0.001", f"1,0.01,{p},0.001", "1,0.02,0.1,0.001"))
    pattern = r": pressure_pa looks like MPa \(multiply by 1e6\) or bar \(multiply by 1e5\)"
    with pytest.raises(DataError, match=at(path, pattern + r".*line 3, trial 1")) as info:
        read_csv(path)
    assert "check_units=False" in str(info.value)
    assert read_csv(path, check_units=False).input[0, 1] == float(p)


def test_pressure_in_pa_accepted(tmp_path: Path) -> None:
    for p in ("20.5", "0"):  # just above the threshold; all-zero is a valid (unpressurised) run
        path = write(tmp_path, rows(f"1,0,{p},0.001", f"1,0.01,{p},0.001"))
        assert read_csv(path).input[0, 0] == float(p)


def test_pressure_below_vacuum(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*with_line(6, "2,0.01,-101326,0.002")))
    with pytest.raises(
        DataError, match=at(path, r": pressure_pa = -101326 Pa \(line 6, trial 2\) is below vacuum")
    ) as info:
        read_csv(path)
    assert "check_units=False" in str(info.value)
    assert read_csv(path, check_units=False).input.min() == -101326
    with pytest.warns(DataWarning, match="looks offset"):
        read_csv(write(tmp_path, rows(*with_line(6, "2,0.01,-101325,0.002")), "vac.csv"))


def test_position_looks_like_mm(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*with_line(4, "1,0.02,3000,12.5")))
    with pytest.raises(
        DataError,
        match=at(
            path,
            r": position_m = 12.5 \(line 4, trial 1\) exceeds 0.5 m in magnitude: not a "
            r"muscle's position in m. The values look like millimetres \(a stroke of 12.5 mm: "
            r"name the column position_mm\) or centimetres \(a stroke of 125 mm: multiply by 10 "
            r"and name the column position_mm \(pmabayes has no position_cm\)\)",
        ),
    ) as info:
        read_csv(path)
    assert "check_units=False" in str(info.value)
    assert read_csv(path, check_units=False).position_m[0, 2] == 12.5


def test_no_unit_checks_for_force(tmp_path: Path) -> None:
    text = rows("1,0,0.5,3.0", "1,0.01,-0.5,2.0", header="trial,time_s,force_n,position_m")
    ds = read_csv(write(tmp_path, text))
    assert ds.input_name == "force_n" and ds.position_m.max() == 3.0


# ----------------------------------------------------------------------------- sidecar


def test_sidecar_loaded(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*GOOD))
    meta = {"synthetic": True, "sample_rate_hz": 100, "rig": "bench-2"}
    (tmp_path / "d.json").write_text(json.dumps(meta))
    assert read_csv(path).metadata == meta


def test_sidecar_invalid_json(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*GOOD))
    sidecar = tmp_path / "d.json"
    sidecar.write_text('{\n  "synthetic": true,\n  "rig": bench\n}\n')
    pattern = r": line 3, column \d+: metadata sidecar is not valid JSON"
    with pytest.raises(DataError, match=at(sidecar, pattern)):
        read_csv(path)


def test_sidecar_not_object(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*GOOD))
    sidecar = tmp_path / "d.json"
    sidecar.write_text("[1, 2]")
    pattern = r": line 1: metadata sidecar holds a JSON list"
    with pytest.raises(DataError, match=at(sidecar, pattern)):
        read_csv(path)


def test_sidecar_sample_rate_mismatch(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*GOOD))
    sidecar = tmp_path / "d.json"
    sidecar.write_text(json.dumps({"sample_rate_hz": 1000}))
    pattern = r" \(metadata sidecar of d\.csv\): sample_rate_hz = 1000 Hz disagrees .* 100 Hz"
    with pytest.raises(DataError, match=at(sidecar, pattern)):
        read_csv(path)
    sidecar.write_text(json.dumps({"sample_rate_hz": 100.00001}))  # 1e-7 relative: fine
    assert read_csv(path).metadata["sample_rate_hz"] == 100.00001


# ----------------------------------------------------------------------------- NetCDF errors


def test_netcdf_not_netcdf(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*GOOD), "fake.nc")
    with pytest.raises(DataError, match=at(path, r": not a readable NetCDF4/HDF5 file")):
        read_netcdf(path)


def test_netcdf_wrong_variables(tmp_path: Path) -> None:
    path = tmp_path / "odd.nc"
    xds = make_dataset().to_xarray().rename({"pressure_pa": "pressure"})
    xds.to_netcdf(path, engine="h5netcdf")
    with pytest.raises(DataError, match=at(path, r": data variables are .*'pressure'")):
        read_netcdf(path)


def test_netcdf_invalid_values(tmp_path: Path) -> None:
    path = tmp_path / "nan.nc"
    xds = make_dataset().to_xarray()
    xds["position_m"].values[1, 4] = np.nan
    xds.to_netcdf(path, engine="h5netcdf")
    with pytest.raises(DataError, match=at(path, r": position_m of trial 17 is nan at sample 4")):
        read_netcdf(path)


# ----------------------------------------------------------------------------- size


def test_read_150k_rows(tmp_path: Path) -> None:
    """A full-size file (10 trials x 15000 samples) parses into the right shape."""
    n = 15000
    t = [repr(k * 1e-3) for k in range(n)]
    lines = [HEADER]
    for trial in range(10):
        lines += [f"{trial},{t[k]},{2e5 + k},{1e-6 * k!r}" for k in range(n)]
    path = write(tmp_path, "\n".join(lines) + "\n")
    ds = read_csv(path)
    assert ds.input.shape == (10, n)
    assert ds.position_m[3, -1] == 1e-6 * (n - 1)


def test_position_far_beyond_mm_is_not_called_millimetres(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*with_line(4, "1,0.02,3000,1e300")))
    pattern = r": position_m = 1e\+300 \(line 4, trial 1\)"
    with pytest.raises(DataError, match=at(path, pattern)) as info:
        read_csv(path)
    text = str(info.value)
    assert "millimetres" not in text and "not a muscle's position in m, nor in mm" in text


def test_unit_check_advice_works_from_the_sidecar(tmp_path: Path) -> None:
    path = write(tmp_path, rows(*with_line(4, "1,0.02,3000,12.5")))
    with pytest.raises(DataError) as info:
        read_csv(path)
    sidecar = tmp_path / "d.json"
    assert f'add "check_units": false to the JSON sidecar {sidecar}' in str(info.value)
    sidecar.write_text('{"check_units": false}')  # what a command-line user can do
    assert read_csv(path).position_m[0, 2] == 12.5
    sidecar.write_text('{"check_units": "no"}')
    with pytest.raises(DataError, match=re.escape(f"{sidecar}: check_units = 'no' must be")):
        read_csv(path)


# ----------------------------------------------------------------------------- gauge pressure


def chirp_csv(tmp_path: Path, offset_pa: float = 0.0, meta: dict | None = None) -> Path:
    """Two short synthetic chirp trials (trials start at rest), pressure shifted by offset_pa."""
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    ds = generate_chirp_dataset(n_trials=2, seed=3, chirp=Chirp(duration_s=1.0))
    metadata = {**ds.metadata, **(meta or {})}
    path = tmp_path / "chirp.csv"
    write_csv(dataclasses.replace(ds, input=ds.input + offset_pa, metadata=metadata), path)
    return path


@pytest.mark.parametrize("offset_pa", [101325.0, 95e3])
def test_absolute_pressure_is_flagged(tmp_path: Path, offset_pa: float) -> None:
    path = chirp_csv(tmp_path, offset_pa)
    with pytest.warns(DataWarning) as record:
        ds = read_csv(path)
    (w,) = record
    text = str(w.message)
    assert text.startswith(f"{path}: the lowest commanded pressure, {offset_pa / 1e3:.1f} kPa")
    assert "(line 2, trial 0)" in text and "every trial starts there, at rest" in text
    assert "looks like absolute pressure" in text and "subtract the ambient pressure" in text
    assert f'"pressure_reference": "absolute" in the JSON sidecar {tmp_path / "chirp.json"}' in text
    assert ds.input.min() == offset_pa  # a warning: nothing is changed


def test_negative_offset_is_flagged(tmp_path: Path) -> None:
    path = chirp_csv(tmp_path, -100e3)
    with pytest.warns(DataWarning, match=re.escape(f"{path}: pressure_pa goes down to -100.0 kPa "
                                                   "(line 2, trial 0)")) as record:
        read_csv(path)
    assert "correct the zero" in str(record[0].message)


def test_gauge_data_and_declared_data_read_quietly(tmp_path: Path) -> None:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_csv(chirp_csv(tmp_path))  # like the bundled data: starts at rest at 0 Pa
        read_csv(write(tmp_path, rows(*GOOD)))
        read_csv(chirp_csv(tmp_path, 101325.0, {"pressure_reference": "gauge"}))
        for name in ("pma_chirp_lab.csv", "pma_chirp_paper.csv"):
            read_csv(Path(__file__).parents[1] / "data" / name)


@pytest.mark.parametrize(("declared", "ambient"), [({}, 101325.0),
                                                   ({"ambient_pressure_pa": 95e3}, 95e3)])
def test_declared_absolute_pressure_is_converted(tmp_path: Path, declared: dict,
                                                 ambient: float) -> None:
    gauge = read_csv(chirp_csv(tmp_path))
    path = chirp_csv(tmp_path, ambient, {"pressure_reference": "absolute", **declared})
    ds = read_csv(path)
    np.testing.assert_allclose(ds.input, gauge.input, rtol=0, atol=1e-9)
    assert ds.metadata["pressure_reference"] == "gauge"
    assert ds.metadata["converted_from_absolute"] == {"ambient_pressure_pa": ambient}
    save(ds, tmp_path / "again.csv")  # written as gauge, read back unchanged
    assert read_csv(tmp_path / "again.csv") == ds


def test_bad_pressure_reference_is_refused(tmp_path: Path) -> None:
    path = chirp_csv(tmp_path, 0.0, {"pressure_reference": "relative"})
    with pytest.raises(DataError, match=re.escape(
            f"the JSON sidecar {tmp_path / 'chirp.json'}: pressure_reference = 'relative'")):
        read_csv(path)


# ----------------------------------------------------------------------------- time grid


def test_one_time_grid_check_for_data_files_and_the_simulator() -> None:
    import pmabayes as pb

    t = 0.25 + np.arange(6) * 2e-3
    assert check_time_grid(t) == np.diff(t).mean()
    bad = t.copy()
    bad[3] += 1e-6
    with pytest.raises(DataError, match=r"^x: sample 3: time_s is not uniformly sampled.*"
                                        r"from sample 2"):
        check_time_grid(bad, source="x")
    with pytest.raises(DataError, match=r"^x: line 5: time_s = nan is not finite"):
        check_time_grid(np.where(np.arange(6) == 3, np.nan, t), source="x",
                        locate=lambda j: f"line {j + 2}")
    with pytest.raises(pb.SimulationError, match=r"^simulate: sample 3: time_s is not uniformly"):
        pb.simulate(pb.Model(), None, np.zeros(6), time_s=bad)
    with pytest.raises(pb.SimulationError, match=r"time_s = nan is not finite"):
        pb.simulate(pb.Model(), None, np.zeros(3), time_s=[0.0, np.nan, 2e-3])
