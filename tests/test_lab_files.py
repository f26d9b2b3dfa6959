"""Files as labs save them: units in column names, headerless files named by the sidecar's
``"columns"``, a DAQ clock with jitter and gaps (samples not observed, segments at
``"max_gap_s"``), and the advice for a unit that is wrong (times in ms read as s,
positions in cm, a transposed ``.mat``).

Two real data sets are read from ``../shared/external/real`` beside the checkout (never
copied into the repository); those tests are skipped when the folder is absent.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io

import pmabayes.data as data
from pmabayes.data import (
    UNITS,
    DataError,
    Dataset,
    DataWarning,
    load,
    load_segments,
    read_columns,
    read_csv,
    save,
)

#: the shared real data, ``../shared`` beside the checkout (or a worktree one level deeper)
REAL = next((p for p in (Path(__file__).resolve().parents[k] / "shared" / "external" / "real"
                         for k in (2, 3)) if p.is_dir()),
            Path(__file__).resolve().parents[2] / "shared" / "external" / "real")
PSI_PA = 6894.757293168361
#: the conversion and clock notes of files read only for an error are not the point there
pytestmark = pytest.mark.filterwarnings("ignore::pmabayes.data.DataWarning")


def at(path: Path, rest: str) -> str:
    """Regex: the message starts with the file name, then ``rest``."""
    return "^" + re.escape(str(path)) + rest


def lab_file(tmp_path: Path, name: str, lines: list[str], **meta: object) -> Path:
    """A data file as a lab wrote it, with a sidecar when ``meta`` is given."""
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    if meta:
        path.with_suffix(".json").write_text(json.dumps(meta), encoding="utf-8")
    return path


def clock_rows(times_s: np.ndarray, unit: float = 1.0, sep: str = ",") -> list[str]:
    """Rows ``time, pressure (kPa, from 0), position (mm)`` of a slow pressure pulse train."""
    k = np.arange(times_s.size)
    p = 150.0 * (1 + np.sign(np.sin(2 * np.pi * 0.5 * times_s))) + k % 3
    x = 2.0 * np.sin(2 * np.pi * 0.5 * times_s) + 0.01 * (k % 5)
    return [f"{float(t) / unit!r}{sep}{float(a)!r}{sep}{float(b)!r}"
            for t, a, b in zip(times_s, p, x, strict=True)]


def read_quietly(path: Path, **kwargs: object) -> tuple[Dataset, list[str]]:
    """Read ``path``, returning the data set and every DataWarning's text."""
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        ds = load(path, **kwargs)
    return ds, [str(w.message) for w in record if issubclass(w.category, DataWarning)]


# ----------------------------------------------------------------------------- units


@pytest.mark.parametrize("name", sorted(n for n, (si, _) in UNITS.items() if n != si))
def test_every_unit_name_is_read_and_converted_to_si(tmp_path: Path, name: str) -> None:
    si, factor = UNITS[name]
    columns = {"time_s": "time_s", "pressure_pa": "pressure_pa", "position_m": "position_m"}
    if si == "force_n":
        columns.pop("pressure_pa")
    columns[si] = name
    raw = {"time_s": np.arange(40) * 0.01, "pressure_pa": 2e5 + 1e3 * np.arange(40),
           "force_n": np.sin(np.arange(40) / 3.0), "position_m": 1e-3 * np.cos(np.arange(40) / 4)}
    # the numbers as the file holds them: the one column in its unit
    values = {s: raw[s] / (factor if s == si else 1.0) for s in columns}
    header = ["trial", *columns.values()]
    lines = [",".join(header)] + [",".join(["1", *(repr(float(values[s][k])) for s in columns)])
                                  for k in range(40)]
    path = lab_file(tmp_path, "u.csv", lines, pressure_reference="gauge")
    ds, said = read_quietly(path)
    got = {"time_s": ds.time_s, "position_m": ds.position_m[0], ds.input_name: ds.input[0]}
    expected = values[si] / round(1 / factor) if factor in (1e-3, 1e-6) else values[si] * factor
    np.testing.assert_array_equal(got[si], expected)
    np.testing.assert_allclose(got[si], raw[si], rtol=1e-12)
    (note,) = said  # said once
    assert f": units converted to SI on reading, as the column names say: {name} (" in note
    assert f" -> {si} (" in note
    assert ds.metadata["converted_units"] == {si: {"from": name, "factor": factor}}


def test_units_are_said_once_per_file_and_recorded(tmp_path: Path) -> None:
    t = np.arange(300) * 1e-3
    rows = clock_rows(t, unit=1e-3)
    path = lab_file(tmp_path, "lab.csv", ["time_ms,pressure_psi,position_mm", *rows],
                    pressure_reference="gauge")
    ds, said = read_quietly(path)
    assert len(said) == 1
    assert said[0] == (f"{path}: units converted to SI on reading, as the column names say: "
                       "time_ms (ms) x 0.001 -> time_s (s); pressure_psi (psi) x 6894.757293 "
                       "-> pressure_pa (Pa); position_mm (mm) x 0.001 -> position_m (m). The "
                       "data set holds SI values; its metadata 'converted_units' records the "
                       "conversion.")
    psi = np.array([float(r.split(",")[1]) for r in rows])
    np.testing.assert_array_equal(ds.input[0], psi * PSI_PA)
    assert ds.trial_ids.tolist() == [1] and ds.n_samples == 300  # no trial column: one trial
    assert ds.metadata["converted_units"]["pressure_pa"] == {"from": "pressure_psi",
                                                             "factor": PSI_PA}
    save(ds, tmp_path / "si.csv")  # written in SI, with the record, read back unchanged
    assert read_csv(tmp_path / "si.csv") == ds


def test_mat_variables_carry_units(tmp_path: Path) -> None:
    t = np.arange(200) / 500.0
    p = 2e5 * (1 + np.sin(2 * np.pi * 2 * t))
    x = 0.01 * np.sin(2 * np.pi * 2 * t)
    path = tmp_path / "lab.mat"
    scipy.io.savemat(path, {"t": t * 1e3, "p": p / 1e5, "x": x * 1e3})
    path.with_suffix(".json").write_text(json.dumps(
        {"mat_variables": {"time_ms": "t", "pressure_bar": "p", "position_mm": "x"}}))
    ds, said = read_quietly(path)
    np.testing.assert_allclose(ds.time_s, t, rtol=1e-15)
    np.testing.assert_allclose(ds.input[0], p, rtol=1e-15)
    assert "pressure_bar (bar) x 100000 -> pressure_pa (Pa)" in said[0]
    assert set(ds.metadata["converted_units"]) == {"time_s", "pressure_pa", "position_m"}
    path.with_suffix(".json").write_text(json.dumps(
        {"mat_variables": {"time_s": "t", "pressure_kpsi": "p", "position_mm": "x"}}))
    with pytest.raises(DataError, match=r"'mat_variables': column 'pressure_kpsi': pmabayes "
                                        r"does not know the unit 'kpsi'.*did you mean "
                                        r"pressure_psi\?"):
        load(path)


# ----------------------------------------------------------------------------- headerless


def test_a_headerless_file_is_read_through_columns(tmp_path: Path) -> None:
    t = np.arange(200) * 2e-3
    rows = [f"note{k} {r}" for k, r in enumerate(clock_rows(t, sep="  "))]  # col 1: text
    path = lab_file(tmp_path, "rig.txt", ["Stamp  Time  P  X", *rows],
                    columns={"2": "time_s", "3": "pressure_kpa", "4": "position_mm"},
                    pressure_reference="gauge")
    ds, said = read_quietly(path)  # column 1 is not named, so not read; line 1 is skipped
    assert ds.n_samples == 200 and ds.n_missing == 0
    np.testing.assert_array_equal(ds.time_s, t)
    assert ds.input[0, 0] == float(rows[0].split()[2]) * 1e3
    assert ds.metadata["read_columns"] == {"2": "time_s", "3": "pressure_kpa",
                                           "4": "position_mm"}
    assert "columns" not in ds.metadata and len(said) == 1
    save(ds, tmp_path / "rig.csv")  # written with a header: the map is a record now
    assert read_csv(tmp_path / "rig.csv") == ds


def test_one_value_a_line_and_a_sample_rate(tmp_path: Path) -> None:
    x = 1e-3 * np.sin(np.arange(100) / 5.0)
    lab_file(tmp_path, "x.txt", [repr(float(v) * 1e6) for v in x])
    assert np.allclose(read_columns(tmp_path / "x.txt", {"1": "position_um"})["position_m"], x,
                       rtol=1e-15, atol=0)
    path = lab_file(tmp_path, "px.csv", [f"{2e5 + 1e3 * k},{float(v)!r}" for k, v in enumerate(x)],
                    columns={"1": "pressure_pa", "2": "position_m"}, sample_rate_hz=100.0,
                    pressure_reference="gauge")
    ds = load(path)
    np.testing.assert_array_equal(ds.time_s, np.arange(100) / 100.0)
    np.testing.assert_array_equal(ds.position_m[0], x)



# ----------------------------------------------------------------------------- separators


def _as_saved(rows: list[str], sep: str, decimal: str = ".") -> list[str]:
    return [r.replace(",", sep).replace(".", decimal) for r in rows]


@pytest.mark.parametrize(("sep", "decimal", "said"), [
    (";", ",", "decimal mark"),  # a spreadsheet in a locale that writes 0,5
    (";", ".", None),
    ("\t", ".", None),  # LabVIEW's spreadsheet file
    ("\t", ",", "decimal mark"),
])
def test_semicolons_tabs_and_decimal_commas_read_as_the_comma_file(
        tmp_path: Path, sep: str, decimal: str, said: str | None) -> None:
    t = np.arange(300) * 2e-3
    rows = clock_rows(t)
    ref = load(lab_file(tmp_path, "ref.csv", ["Time (s),Pressure (kPa),Position (mm)", *rows],
                        pressure_reference="gauge"))
    header = sep.join(["Time (s)", "Pressure (kPa)", "Position (mm)"])
    path = lab_file(tmp_path, "saved.csv", [header, *_as_saved(rows, sep, decimal)],
                    pressure_reference="gauge")
    ds, notes = read_quietly(path)
    assert ds == ref
    decimal_notes = [n for n in notes if "decimal mark" in n]
    assert len(decimal_notes) == (1 if said else 0)
    # a headerless file named by "columns" is split the same way
    bare = lab_file(tmp_path, "bare.txt", _as_saved(rows, sep, decimal),
                    columns={"1": "time_s", "2": "pressure_kpa", "3": "position_mm"},
                    pressure_reference="gauge")
    np.testing.assert_array_equal(load(bare).position_m, ref.position_m)


def test_a_tab_left_at_the_end_of_a_comma_file_s_lines_separates_nothing(tmp_path: Path) -> None:
    rows = clock_rows(np.arange(30) * 2e-3)
    ref = load(lab_file(tmp_path, "ref.csv", ["time_s,pressure_kpa,position_mm", *rows],
                        pressure_reference="gauge"))
    assert load(lab_file(tmp_path, "tabbed.csv", ["time_s,pressure_kpa,position_mm\t",
                                                  *(r + "\t" for r in rows)],
                         pressure_reference="gauge")) == ref


def test_quoted_fields_and_a_preamble_are_read_through_and_lines_still_count(
        tmp_path: Path) -> None:
    t = np.arange(50) * 2e-3
    rows = clock_rows(t)
    ref = load(lab_file(tmp_path, "ref.csv", ["time_s,pressure_kpa,position_mm", *rows],
                        pressure_reference="gauge"))
    quoted = ['"time_s","pressure_kpa","position_mm"',
              *('"' + r.replace(",", '","') + '"' for r in rows)]
    preamble = ["# exported by the rig's logger", "# operator: A. N. Other"]
    path = lab_file(tmp_path, "logged.csv", [*preamble, *quoted], pressure_reference="gauge")
    ds, notes = read_quietly(path)
    assert ds == ref
    assert any("lines 1-2 start with '#'" in n and "line 3 is read" in n for n in notes)
    with pytest.raises(DataError, match=r"every line starts with '#' \(notes, no data\)"):
        load(lab_file(tmp_path, "notes.csv", preamble))
    bad = [*preamble, *quoted]
    bad[9] = bad[9].replace(bad[9].split(",")[1], '"abc"')  # file line 10
    with pytest.raises(DataError, match=at(tmp_path / "bad.csv",
                                           r": line 10, column pressure_kpa: 'abc'")):
        load(lab_file(tmp_path, "bad.csv", bad, pressure_reference="gauge"))




@pytest.mark.parametrize(("names", "units"), [
    ("Time,Pressure,Position", "s,kPa,mm"),
    ('"Time";"Pressure";"Position"', '"[s]";"[kPa]";"[mm]"'),
])
def test_a_line_of_units_under_the_names_is_read_with_them(tmp_path: Path, names: str,
                                                           units: str) -> None:
    rows = clock_rows(np.arange(50) * 2e-3)
    ref = load(lab_file(tmp_path, "ref.csv", ["time_s,pressure_kpa,position_mm", *rows],
                        pressure_reference="gauge"))
    sep = ";" if ";" in names else ","
    path = lab_file(tmp_path, "named.csv", [names, units, *_as_saved(rows, sep)],
                    pressure_reference="gauge")
    assert load(path) == ref
    bad = [names, units, *_as_saved(rows, sep)]
    bad[4] = bad[4].replace(bad[4].split(sep)[0], "t")  # file line 5
    with pytest.raises(DataError, match=at(tmp_path / "bad.csv", r": line 5, column time_s")):
        load(lab_file(tmp_path, "bad.csv", bad, pressure_reference="gauge"))
    # names that are not read with their units either: the error names both
    with pytest.raises(DataError, match=r"line 1 \(header\): unexpected column 'Stroke \(mm\)' "
                                        r"\('Stroke \(mm\)' looks like 'position_mm'\)"):
        load(lab_file(tmp_path, "stroke.csv", ["Time,Pressure,Stroke", units.replace(";", ","),
                                               *rows], pressure_reference="gauge"))



@pytest.mark.parametrize("lost", ["nan", "", "NaN"])
def test_a_position_dropout_is_told_the_fix_and_the_fix_reads(tmp_path: Path, lost: str) -> None:
    rows = clock_rows(np.arange(60) * 2e-3)
    bad = [*rows]
    bad[20] = ",".join(bad[20].split(",")[:2] + [lost])  # file line 22
    with pytest.raises(DataError, match=at(tmp_path / "lost.csv", r": line 22, column "
                                           r"position_mm: .*delete its row, and the gap")):
        load(lab_file(tmp_path, "lost.csv", ["time_s,pressure_kpa,position_mm", *bad],
                      pressure_reference="gauge"))
    del bad[20]  # as the message says
    ds, notes = read_quietly(lab_file(tmp_path, "kept.csv",
                                      ["time_s,pressure_kpa,position_mm", *bad],
                                      pressure_reference="gauge"))
    assert ds.n_missing == 1 and not ds.observed[0, 20] and np.isnan(ds.position_m[0, 20])
    assert any("1 sample not observed" in n or "1 sample missing" in n for n in notes)



@pytest.mark.parametrize(("name", "sep", "decimal"), [
    ("Timestamp", ",", "."), ("Time", "\t", "."), ("Zeit", ";", ","),
])
def test_a_time_column_of_dates_is_read_as_seconds_from_its_first(
        tmp_path: Path, name: str, sep: str, decimal: str) -> None:
    t = np.arange(400) * 2e-3
    rows = clock_rows(t)
    ref = load(lab_file(tmp_path, "ref.csv", ["time_s,pressure_kpa,position_mm", *rows],
                        pressure_reference="gauge"))
    start = np.datetime64("2024-03-01T23:59:59.500", "ns")  # across midnight
    stamps = [str(start + np.timedelta64(round(s * 1e9), "ns")).replace("T", " ")[:23]
              for s in t]
    saved = [sep.join([d.replace(".", decimal), *r.split(",")[1:]]).replace(
        ".", decimal if decimal == "," else ".") for d, r in zip(stamps, rows, strict=True)]
    header = sep.join([name, "Pressure (kPa)", "Position (mm)"])
    ds, notes = read_quietly(lab_file(tmp_path, "stamped.csv", [header, *saved],
                                      pressure_reference="gauge"))
    # the reference's times are printed as repr (0.018000000000000002), the dates' to the ms
    np.testing.assert_allclose(ds.time_s, ref.time_s, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ds.position_m, ref.position_m)
    assert ds.metadata["time_origin"] == "2024-03-01T23:59:59.500"
    assert any(f"{name!r}, holds dates and times" in n for n in notes)
    saved[99] = saved[99].replace(stamps[99][:10], "01/03/2024")  # file line 101
    with pytest.raises(DataError, match=at(tmp_path / "bad.csv", r": line 101, column 1: "
                                           r"'01/03/2024 .*' is not a date and time")):
        load(lab_file(tmp_path, "bad.csv", [header, *saved], pressure_reference="gauge"))



@pytest.mark.parametrize("header", [
    "Time/s,Pressure/kPa,Position/mm",  # ISO 80000's quantity over its unit
    "Time / s,Pressure / kPa,Position / mm",
    "Time (sec),Pressure (kPa gauge),Position (millimetres)",
    "Time [seconds],Pressure [kPag],Position [mm]",
    "time_s,pressure_kpa,position_mm",
    "Time (s),Muscle pressure (kPa),Displacement (mm)",  # words before the quantity
])
def test_units_in_a_header_as_people_write_them(tmp_path: Path, header: str) -> None:
    rows = clock_rows(np.arange(40) * 2e-3)
    ref = load(lab_file(tmp_path, "ref.csv", ["time_s,pressure_kpa,position_mm", *rows],
                        pressure_reference="gauge"))
    assert load(lab_file(tmp_path, "named.csv", [header, *rows],
                         pressure_reference="gauge")) == ref


def test_two_columns_of_one_quantity_are_offered_a_map_that_reads_one(tmp_path: Path) -> None:
    rows = [r + "," + r.split(",")[2] for r in clock_rows(np.arange(40) * 2e-3)]
    path = lab_file(tmp_path, "two.csv", ["Time (s),Pressure (kPa),Desired position (mm),"
                                          "Measured position (mm)", *rows])
    with pytest.raises(DataError) as info:
        load(path)
    text = str(info.value)
    assert "appears twice (columns 3 and 4)" in text and "read one, the one measured" in text
    example = json.loads(re.search(r"e\.g\. (\{.*\})$", text).group(1))
    assert example == {"columns": {"1": "time_s", "2": "pressure_kpa", "3": "position_mm"}}


def test_a_labview_measurement_file_is_read_below_its_header_block(tmp_path: Path) -> None:
    t = np.arange(100) * 1e-3
    rows = [r.replace(",", "\t") + "\t" for r in clock_rows(t)]  # an empty comment column
    block = ["LabVIEW Measurement\t", "Writer_Version\t2", "Separator\tTab",
             "Decimal_Separator\t.", "***End_of_Header***\t", "", "Channels\t2\t",
             "Samples\t100\t100\t", "X_Dimension\tTime\tTime\t",
             "***End_of_Header***\t", "X_Value\tPressure\tDisplacement\tComment"]
    path = lab_file(tmp_path, "run.lvm", [*block, *rows],
                    columns={"1": "time_s", "2": "pressure_kpa", "3": "position_mm"},
                    pressure_reference="gauge")
    ds, notes = read_quietly(path)
    np.testing.assert_array_equal(ds.time_s, t)
    assert ds.position_m[0, 5] == float(rows[5].split()[2]) * 1e-3
    assert any("lines 1-11 are not rows of numbers" in n and "line 12 is the first" in n
               for n in notes)
    rows[40] = rows[40].replace(rows[40].split()[1], "x")  # file line 52
    with pytest.raises(DataError, match=at(tmp_path / "bad.lvm",
                                           r": line 52, column 2 \(pressure_kpa\): 'x'")):
        load(lab_file(tmp_path, "bad.lvm", [*block, *rows],
                      columns={"1": "time_s", "2": "pressure_kpa", "3": "position_mm"},
                      pressure_reference="gauge"))


def test_a_spreadsheet_is_told_to_be_saved_as_csv(tmp_path: Path) -> None:
    path = tmp_path / "run.xlsx"
    path.write_bytes(b"PK")
    with pytest.raises(DataError, match=r"unsupported file type '\.xlsx'.*save the sheet as CSV"):
        load(path)


def test_a_number_with_both_decimal_marks_is_refused_on_its_line(tmp_path: Path) -> None:
    rows = _as_saved(clock_rows(np.arange(20) * 2e-3), ";", ",")
    rows[6] = rows[6] + ".5"  # file line 8
    path = lab_file(tmp_path, "mixed.csv", ["time_s;pressure_kpa;position_mm", *rows],
                    pressure_reference="gauge")
    with pytest.raises(DataError, match=at(path, r": line 8: numbers written with both '\.' "
                                                 r"and ','.*one decimal mark")):
        load(path)


def test_a_position_sign_negates_and_a_zero_at_rest_refers_the_positions(tmp_path: Path
                                                                          ) -> None:
    """A sensor whose negative is the muscle's contraction, not zeroed before the record:
    ``"position_sign": -1`` negates on reading, ``"position_zero_s"`` subtracts each
    trial's mean over its first samples at rest; both said, recorded, and not applied
    again when the data set is written back and read."""
    t = np.arange(400) * 1e-3
    x_mm = -(3.0 + np.where(t > 0.05, 2.0 * np.sin(2 * np.pi * (t - 0.05)), 0.0))
    rows = [f"{float(a)!r},{150.0 + 100.0 * float(b < -3)!r},{float(b)!r}" for a, b in zip(t, x_mm,
                                                                               strict=True)]
    path = lab_file(tmp_path, "flip.csv", rows, pressure_reference="gauge",
                    columns={"1": "time_s", "2": "pressure_kpa", "3": "position_mm"},
                    position_sign=-1, position_zero_s=0.02)
    ds, said = read_quietly(path)
    np.testing.assert_allclose(ds.position_m[0], -(x_mm - x_mm[:20].mean()) / 1e3, atol=1e-15)
    assert ds.metadata["converted_units"]["position_m"] == {"from": "position_mm",
                                                           "factor": -1e-3}
    assert ds.metadata["position_zero"]["subtracted_m"][0] == pytest.approx(3e-3, rel=1e-12)
    assert "position_sign" not in ds.metadata and "position_zero_s" not in ds.metadata
    assert any("negated: the sidecar's position_sign is -1" in w for w in said)
    assert any("positions referred to the sensor's reading at rest" in w for w in said)
    save(ds, tmp_path / "again.csv")
    assert read_csv(tmp_path / "again.csv") == ds
    for key, value, pattern in (("position_sign", 2, "'position_sign' is 2; it must be 1"),
                                ("position_zero_s", -1, "'position_zero_s' is -1")):
        bad = lab_file(tmp_path, f"bad_{key}.csv", rows, pressure_reference="gauge",
                       columns={"1": "time_s", "2": "pressure_kpa", "3": "position_mm"},
                       **{key: value})
        with pytest.raises(DataError, match=pattern):
            read_quietly(bad)
    with pytest.raises(DataError, match="'position_sign' is -1; it is applied when a file is"):
        Dataset(time_s=t, input=np.ones((1, t.size)), position_m=x_mm[None] / 1e3,
                trial_ids=np.array([1]), metadata={"position_sign": -1})


# ----------------------------------------------------------------------------- the clock


def test_a_daq_clock_with_jitter_is_a_uniform_grid(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    t = np.arange(2000) * 1e-3 + rng.uniform(-8e-5, 8e-5, 2000)  # up to 8% of a step
    path = lab_file(tmp_path, "j.csv", ["time_s,pressure_kpa,position_mm", *clock_rows(t)],
                    pressure_reference="gauge")
    worst = int(np.argmax(np.abs(t - np.polyval(np.polyfit(np.arange(2000), t, 1),
                                                np.arange(2000)))))
    ds, said = read_quietly(path)
    assert ds.n_missing == 0 and ds.n_samples == 2000
    np.testing.assert_allclose(np.diff(ds.time_s), 1e-3, rtol=1e-6)
    (clock,) = [s for s in said if "uniform grid" in s]
    m = re.search(r"deviate from the uniform grid by up to ([\d.]+) µs \(([\d.]+) steps, "
                  r"line (\d+)\)", clock)
    assert m and 70 < float(m.group(1)) < 90 and 0.07 < float(m.group(2)) < 0.09
    assert int(m.group(3)) == worst + 2
    t[1500] += 4e-4  # 40% of a step: not jitter
    path = lab_file(tmp_path, "j.csv", ["time_s,pressure_kpa,position_mm", *clock_rows(t)])
    with pytest.raises(DataError, match=at(path, r": line 1502: time_s = .* comes after .* on "
                                                 r"line 1501: an interval of 1\.[34]\d\d steps")):
        load(path)


@pytest.mark.parametrize("between", ["hold", "linear"])
def test_gaps_are_samples_not_observed(tmp_path: Path, between: str) -> None:
    t = np.arange(1000) * 1e-3
    keep = np.ones(1000, dtype=bool)
    keep[300:330] = keep[700] = False  # 30 samples, then 1
    rows = clock_rows(t)
    path = lab_file(tmp_path, "g.csv", ["time_s,pressure_kpa,position_mm",
                                        *(r for r, k in zip(rows, keep, strict=True) if k)],
                    input_between_samples=between, pressure_reference="gauge")
    ds, said = read_quietly(path)
    assert ds.n_samples == 1000 and ds.n_missing == 31
    assert (ds.observed[0] == keep).all()
    assert np.isnan(ds.position_m[0, ~keep]).all() and np.isfinite(ds.position_m[0, keep]).all()
    p = np.array([float(r.split(",")[1]) * 1e3 for r in rows])
    gap = np.arange(300, 330)
    expected = (np.full(30, p[299]) if between == "hold"
                else p[299] + (p[330] - p[299]) * (gap - 299) / 31)
    np.testing.assert_allclose(ds.input[0, gap], expected, rtol=1e-12)
    assert ds.input[0, 700] == (p[699] if between == "hold" else (p[699] + p[701]) / 2)
    assert said[-1].startswith(f"{path}: 2 gaps in the clock, 31 samples not observed (3.1% "
                               "of the grid): 31 ms after line 301 (30 samples missing), then 1 "
                               "more of 2 ms (after line 671)"), said
    path.with_suffix(".json").write_text(json.dumps({"input_between_samples": "bandlimited",
                                                     "pressure_reference": "gauge"}))
    with pytest.raises(DataError, match=r"'bandlimited' but 31 samples are not observed; .*"
                                        r"Declare \"input_between_samples\": \"linear\""):
        load(path)


def test_the_first_message_names_the_gap_not_the_jitter(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    t = np.concatenate([np.arange(1000), np.arange(2190, 3190)]) * 1e-3
    t = t + rng.uniform(-1e-6, 1e-6, t.size)  # a DAQ's microsecond jitter from line 2 on
    path = lab_file(tmp_path, "blocks.csv", ["time_s,pressure_kpa,position_mm",
                                             *clock_rows(t)], pressure_reference="gauge")
    ds, said = read_quietly(path)
    assert said[-1].startswith(f"{path}: 1 gap in the clock, 1190 samples not observed")
    assert "1.191 s after line 1001" in said[-1]
    assert said[-1].index("gap") < said[-1].index("deviate")
    assert ds.n_samples == 3190


def test_a_clock_that_runs_backwards_names_its_line(tmp_path: Path) -> None:
    t = np.arange(100) * 1e-3
    t[60] = t[58]  # the clock steps back
    path = lab_file(tmp_path, "b.csv", ["time_s,pressure_kpa,position_mm", *clock_rows(t)])
    with pytest.raises(DataError, match=at(path, r": line 62: time_s = 0\.058 is not after "
                                                 r"0\.059 on line 61 \(the clock runs "
                                                 r"backwards\)")):
        load(path)


def test_a_block_stamped_a_second_late_is_proposed_and_moved_only_when_declared(
        tmp_path: Path) -> None:
    """As in a real DAQ log: blocks of 100 samples 20 ms apart, the third stamped 1 s late,
    so the clock steps back after it. The error names the block and the declaration;
    declared, the record reads as one grid with the blocks' gaps, and says so."""
    blocks = [np.arange(100) * 1e-3 + b * 0.12 for b in range(5)]
    truth = np.concatenate(blocks)
    stamped = truth.copy()
    stamped[200:300] += 1.0
    rows = ["time_s,pressure_kpa,position_mm", *clock_rows(stamped)]
    path = lab_file(tmp_path, "late.csv", rows, pressure_reference="gauge")
    proposed = (r": line 302: .*clock runs backwards.*if line 202 to 301 were stamped late "
                r".*\"clock_shifts\": \[\{\"lines\": \[202, 301\], \"shift_s\": -1\}\]")
    with pytest.raises(DataError, match=at(path, proposed)):
        load(path)
    path = lab_file(tmp_path, "late.csv", rows, pressure_reference="gauge",
                    clock_shifts=[{"lines": [202, 301], "shift_s": -1}])
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        ds = load(path)
    assert any("clock_shifts declares: lines 202-301 by -1 s" in str(w.message) for w in said)
    assert ds.n_samples == 580 and int(ds.observed.sum()) == 500
    assert np.allclose(ds.time_s[ds.observed[0]], truth - truth[0], atol=1e-9)
    # a shift that names no line of data, or is not a number: one line naming the fix
    for bad in ([{"lines": [1, 50], "shift_s": -1}], [{"lines": [202, 301], "shift_s": "1s"}],
                {"lines": [202, 301]}):
        path = lab_file(tmp_path, "late.csv", rows, pressure_reference="gauge",
                        clock_shifts=bad)
        with pytest.raises(DataError, match=r"late\.json.*clock_shifts.*e\.g\. \"clock_shifts\""):
            load(path)


def test_max_gap_s_splits_the_record_into_segments(tmp_path: Path) -> None:
    # a block, a restart 0.7005 s later (not a whole number of steps), a block with a gap
    first = np.arange(500) * 1e-3
    second = 1.1995 + np.delete(np.arange(800), np.arange(400, 425)) * 1e-3
    t = np.concatenate([first, second])
    lines = ["time_s,pressure_kpa,position_mm", *clock_rows(t)]
    path = lab_file(tmp_path, "rec.csv", lines, pressure_reference="gauge")
    with pytest.raises(DataError, match=at(path, r": line 502: .* a gap of 700\.500 steps .*not "
                                                 r"a whole number: the clock restarted after "
                                                 r"it; declare \"max_gap_s\" below 0\.7005")):
        load(path)
    path = lab_file(tmp_path, "rec.csv", lines, pressure_reference="gauge", max_gap_s=0.5)
    with pytest.raises(DataError, match=at(path, r": the record splits into 2 segments .* "
                                                 r"pmabayes\.data\.load_segments\(path\)")):
        load(path)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        one, two = load_segments(path)
    (note,) = [str(w.message) for w in record if "segments" in str(w.message)]
    assert "split the record into 2 segments, each on its own grid: #1 line 2 to line 501, #2 " \
           "line 502 to line 1276 (after 700.5 ms)" in note
    assert (one.n_samples, one.n_missing, two.n_samples, two.n_missing) == (500, 0, 800, 25)
    assert one.time_s[0] == 0.0 and two.time_s[0] == pytest.approx(1.1995, abs=1e-12)
    assert Path(two.source).stem == "rec#2" and two.source == str(tmp_path / "rec#2.csv")
    assert two.metadata["segment"] == {"name": "rec#2", "index": 2, "of": 2,
                                       "first": "line 502", "last": "line 1276",
                                       "start_s": two.time_s[0]}
    assert one.metadata["max_gap_s"] == 0.5 and "segment" in one.metadata
    path.with_suffix(".json").write_text(json.dumps({"max_gap_s": 5.0}))
    with pytest.raises(DataError, match=r"a gap of 700\.500 steps"):  # not split there
        load_segments(path)
    path = lab_file(tmp_path, "one.csv", lines[:400], max_gap_s=0.5, pressure_reference="gauge")
    assert load_segments(path) == [load(path)]  # no longer gap: one record, as load reads it


def test_a_mat_time_vector_with_gaps_and_segments(tmp_path: Path) -> None:
    k = np.concatenate([np.arange(300), np.arange(900, 1500)])  # a 0.6 s stop
    k = np.delete(k, np.arange(600, 610))  # and 10 lost samples
    t = k * 2e-3
    x = 1e-3 * np.sin(t)[np.newaxis, :] * np.array([[1.0], [1.02]])
    path = tmp_path / "daq.mat"
    scipy.io.savemat(path, {"t": t, "p": 2e5 * (1 + np.sin(3 * t)), "x": x})
    mapping = {"time_s": "t", "pressure_pa": "p", "position_m": "x"}
    path.with_suffix(".json").write_text(json.dumps({"mat_variables": mapping,
                                                     "max_gap_s": 0.1}))
    with pytest.raises(DataError, match=r"splits into 2 segments .*load_segments"):
        load(path)
    with pytest.warns(DataWarning, match=r"1 gap in the clock, 10 samples not observed .*after "
                                         r"sample 600.* 2 segments.*#2 sample 301 to sample "
                                         r"890 \(after 1\.202 s\)"):
        first, second = load_segments(path)
    assert (first.n_samples, second.n_samples, second.n_missing) == (300, 600, 20)
    assert second.observed.sum(axis=1).tolist() == [590, 590]
    assert second.metadata["segment"]["name"] == "daq#2"


def test_missing_samples_round_trip_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n = 300
    observed = np.ones((3, n), dtype=bool)
    observed[0, 40:55] = observed[1, 100] = False
    observed[:, 200:230] = False
    for between in ("hold", "linear"):
        ds = Dataset(time_s=0.25 + np.arange(n) * 2e-3, input=rng.uniform(1e5, 4e5, (3, n)),
                     position_m=rng.normal(0.0, 1e-3, (3, n)), trial_ids=np.array([3, 5, 9]),
                     metadata={"input_between_samples": between}, observed=observed)
        assert ds.n_missing == 15 + 1 + 90
        for name in ("d.csv", "d.nc"):
            save(ds, tmp_path / name)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DataWarning)
                back = load(tmp_path / name, check_units=False)
            assert back == ds and np.array_equal(back.observed, ds.observed)
            assert np.array_equal(back.time_s, ds.time_s)
        assert Dataset.from_xarray(ds.to_xarray()) == ds
        assert ds.select_trials([2, 0]).observed.tolist() == observed[[2, 0]].tolist()


def test_statistics_skip_samples_not_observed() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 1e-3, (4, 50))
    observed = np.ones((4, 50), dtype=bool)
    observed[0, 10:20] = observed[1, 15] = False
    observed[:, 30] = False
    observed[1:, 31] = False  # one trial only: no spread there
    ds = Dataset(time_s=np.arange(50) * 1e-3, input=np.full((4, 50), 2e5), position_m=x,
                 trial_ids=np.arange(4), observed=observed)
    masked = np.ma.masked_array(x, ~observed)
    np.testing.assert_allclose(ds.mean_position_m[observed.any(axis=0)],
                               masked.mean(axis=0).compressed(), rtol=1e-14)
    assert np.isnan(ds.mean_position_m[30]) and ds.mean_position_m[31] == x[0, 31]
    two = observed.sum(axis=0) >= 2
    var = masked.var(axis=0, ddof=1)[two] / observed.sum(axis=0)[two]
    assert ds.noise_floor_m == pytest.approx(math.sqrt(float(var.mean())), rel=1e-12)
    complete = Dataset(time_s=ds.time_s, input=ds.input, position_m=x, trial_ids=np.arange(4))
    assert complete.n_missing == 0 and complete.observed.all()
    assert complete.noise_floor_m == math.sqrt(x.var(axis=0, ddof=1).mean() / 4)


def test_check_trials_compares_the_samples_every_trial_observed() -> None:
    from pmabayes.inference.trials import check_trials

    rng = np.random.default_rng(4)
    x = rng.normal(0.0, 1e-4, (5, 400)) + np.sin(np.arange(400) / 30.0) * 1e-3
    x[4] += 5e-4  # an outlier trial
    observed = np.ones_like(x, dtype=bool)
    observed[2, 100:140] = False
    ds = Dataset(time_s=np.arange(400) * 1e-3, input=np.full((5, 400), 2e5), position_m=x,
                 trial_ids=np.arange(1, 6), observed=observed)
    check = check_trials(ds)
    keep = observed.all(axis=0)
    same = check_trials(Dataset(time_s=np.arange(keep.sum()) * 1e-3,
                                input=np.full((5, keep.sum()), 2e5), position_m=x[:, keep],
                                trial_ids=np.arange(1, 6)))
    assert check.to_dict() == same.to_dict() and 5 in check.flagged


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(("header", "pattern"), [
    ("time_s,pressure_kpsi,position_mm",
     r"pmabayes does not know the unit 'kpsi' of pressure; it reads pressure_pa, pressure_kpa, "
     r"pressure_bar, pressure_psi, pressure_mpa \(did you mean pressure_psi\?\)"),
    ("time_s,pressure_psi,pressure_kpa,position_mm",
     r"pressure_psi and pressure_kpa both give pressure_pa: keep one column for pressure"),
    ("time_s,time_ms,pressure_pa,position_m", r"time_s and time_ms both give time_s"),
    ("time_s,pressure_bar,force_kn,position_m",
     r"both pressure_bar and force_kn are present; keep exactly one input column"),
    ("Time (s),Pressure (psia),Position (mm)",
     r"unit 'psia' of pressure.*name the column pressure_psi and declare "
     r"\"pressure_reference\": \"absolute\""),
    ("Time (s),Pressure (V),Position (mm)",
     r"'Pressure \(V\)' is pressure_v: column 'pressure_v' holds the pressure sensor's raw "
     r"signal, not the pressure: declare the sensor's calibration \(value = gain x signal \+ "
     r"offset.*in the sidecar, \"calibration\": \{\"pressure_v\": \{\"to\": \"pressure_kpa\", "
     r"\"gain\": ..., \"offset\": ...\}\}, to read it as one of pressure_pa, pressure_kpa"),
])
def test_bad_unit_names_in_a_header(tmp_path: Path, header: str, pattern: str) -> None:
    path = lab_file(tmp_path, "h.csv", [header, "0,1,2,3", "0.01,1,2,3"])
    with pytest.raises(DataError, match=at(path, r": line 1 \(header\): .*" + pattern)):
        load(path)


@pytest.mark.parametrize(("columns", "pattern"), [
    ({"1": "time_s", "2": "pressure_kpa", "6": "position_mm"},
     r"^{path}: line 1: the sidecar's 'columns' names column 6 \(position_mm\) but the line has 3 "
     r"comma-separated fields; columns are numbered from 1 to 3"),
    ({"0": "time_s", "2": "pressure_kpa", "3": "position_mm"},
     r"^the JSON sidecar {sidecar}: 'columns': key '0' is not a column number \(columns are "
     r"numbered from 1"),
    ({"1": "time_s", "2": "pressure_psi", "3": "pressure_kpa"},
     r"'columns': pressure_psi and pressure_kpa both give pressure_pa"),
    ({"1": "time_s", "2": "pressure_kpa", "3": "position_cm"},
     r"unit 'cm' of position.*centimetres: multiply by 10 and name the column position_mm"),
    ({"1": "time_s", "2": "pressure_kpa"},
     r"'columns' names no column for position_m"),
])
def test_bad_columns_maps(tmp_path: Path, columns: dict, pattern: str) -> None:
    path = lab_file(tmp_path, "c.csv", ["0,1,2", "0.01,1,2"], columns=columns)
    pattern = pattern.format(path=re.escape(str(path)),
                             sidecar=re.escape(str(path.with_suffix(".json"))))
    with pytest.raises(DataError, match=pattern):
        load(path)


@pytest.mark.parametrize("gap", [0, -1.0, "1 s", True, [1]])
def test_max_gap_s_must_be_a_positive_number(tmp_path: Path, gap: object) -> None:
    lines = ["time_s,pressure_kpa,position_mm", *clock_rows(np.arange(20) * 1e-3)]
    path = lab_file(tmp_path, "m.csv", lines, max_gap_s=gap)
    with pytest.raises(DataError, match=re.escape(f"the JSON sidecar {path.with_suffix('.json')}"
                                                  f": metadata 'max_gap_s' is {gap!r}; it must "
                                                  "be a positive number of seconds")):
        load(path)


def test_an_estimated_initial_state_needs_a_first_second_without_gaps(tmp_path: Path) -> None:
    t = np.delete(np.arange(3000), np.arange(400, 410)) * 1e-3
    lines = ["time_s,pressure_kpa,position_mm", *clock_rows(t)]
    path = lab_file(tmp_path, "e.csv", lines, initial_state="estimate")
    with pytest.raises(DataError, match=at(path, r": initial_state 'estimate' estimates the state "
                                                 r"each trial starts in from its first 1 s, but "
                                                 r"the clock has a gap of 11 ms after line 401 "
                                                 r"\(10 samples missing, 399 ms after the "
                                                 r"start\)")):
        load(path)


# ----------------------------------------------------------------------------- unit advice


@pytest.mark.parametrize(("column", "unit", "looks", "fix"), [
    ("time_s", 1e-3, "milliseconds", "name the column time_ms"),
    ("time_s", 1e-6, "microseconds", "name the column time_us"),
    ("time_ms", 1.0, "seconds", "name the column time_s"),
])
def test_times_in_the_wrong_unit_are_caught(tmp_path: Path, column: str, unit: float,
                                            looks: str, fix: str) -> None:
    t = np.arange(15000) * 1e-3  # 15 s at 1 kHz, the input at 0.5 Hz
    path = lab_file(tmp_path, "t.csv", [f"{column},pressure_kpa,position_mm",
                                        *clock_rows(t, unit=unit)], pressure_reference="gauge")
    with pytest.raises(DataError, match=at(path, rf": {column} gives a sample rate of .* so the "
                                                 rf"times look like {looks}: a sample rate of "
                                                 rf"1000 Hz, the input cycling at about 0\.\d+ Hz "
                                                 rf"over 15 s\. Fix: {fix}, or give the sample "
                                                 r"rate, \"sample_rate_hz\"")):
        load(path)
    rate = 1.0 / (1e-3 * (UNITS[column][1] / unit))
    path.with_suffix(".json").write_text(json.dumps({"sample_rate_hz": rate,
                                                     "pressure_reference": "gauge"}))
    assert load(path).sample_rate_hz == pytest.approx(rate)  # declared: taken as it is


def test_positions_in_centimetres_get_the_right_advice(tmp_path: Path) -> None:
    t = np.arange(500) * 1e-3
    rows = [f"{a},{b},{25.0 + float(c)!r}" for a, b, c in
            (r.split(",") for r in clock_rows(t))]  # 25 cm from the sensor, 2 cm stroke
    path = lab_file(tmp_path, "cm.csv", ["time_s,pressure_kpa,position_m", *rows],
                    pressure_reference="gauge")
    with pytest.raises(DataError) as info:
        load(path)
    text = str(info.value)
    assert "centimetres (a stroke of 20.4 mm: multiply by 10 and name the column position_mm " \
           "(pmabayes has no position_cm))" in text
    assert "divide by 1000" not in text


def test_a_transposed_mat_file_is_told_mat_trials(tmp_path: Path) -> None:
    t = np.arange(200) / 500.0
    x = 0.01 * np.sin(2 * np.pi * 2 * t)[np.newaxis, :] * np.array([[1.0], [1.01], [0.99]])
    path = tmp_path / "rows.mat"
    scipy.io.savemat(path, {"t": t, "p": 2e5 * (1 + np.sin(2 * np.pi * 2 * t)), "x": x})
    path.with_suffix(".json").write_text(json.dumps({
        "mat_trials": "columns",
        "mat_variables": {"time_s": "t", "pressure_pa": "p", "position_m": "x"}}))
    with pytest.raises(DataError, match=r"'x' is 3x200, read as 200 trials of 3 samples, but "
                                        r"the record has 200 samples: its trials run along the "
                                        r"other axis\. Declare \"mat_trials\": \"rows\""):
        load(path)


# ----------------------------------------------------------------------------- real files


def test_without_gaps_a_file_reads_as_before() -> None:
    """The bundled data: no new metadata key, every sample observed, no warning."""
    path = Path(__file__).parents[1] / "data" / "pma_chirp_lab.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = read_csv(path)
    assert ds.metadata == json.loads(path.with_suffix(".json").read_text())
    assert ds.n_missing == 0 and ds.observed.all() and ds.observed.shape == ds.position_m.shape


@pytest.mark.skipif(not (REAL / "cavatappi").is_dir(), reason=f"{REAL} is not there")
def test_the_real_cavatappi_file(tmp_path: Path) -> None:
    """A headerless DAQ file: the LabVIEW clock (column 2), psi and mm, blocks with gaps."""
    path = tmp_path / "sample1_100g.csv"
    shutil.copy(REAL / "cavatappi" / "sample1_100g.csv", path)  # the sidecar goes beside it
    columns = {"2": "time_s", "4": "pressure_psi", "5": "position_mm"}
    path.with_suffix(".json").write_text(json.dumps({"columns": columns}))
    ds, said = read_quietly(path)
    assert ds.observed.sum() == 12000  # every row read, none invented
    assert ds.n_samples - 12000 == ds.n_missing > 0
    assert ds.sample_rate_hz == pytest.approx(1000.0, rel=1e-6)
    gaps = re.search(r"11 gaps in the clock, (\d+) samples not observed .*: ([\d.]+) s after "
                     r"line 1000 \(\d+ samples missing\), then 10 more of (\d+) ms to (\d+) ms",
                     said[-1])
    assert gaps, said[-1]
    assert 1.18 < float(gaps.group(2)) < 1.2  # the muscle at rest, then the DAQ restarts
    assert 20 <= int(gaps.group(3)) and int(gaps.group(4)) <= 43  # between blocks
    assert "time_origin_s" in ds.metadata  # the LabVIEW clock reads 3.8e9 s
    raw = np.loadtxt(REAL / "cavatappi" / "sample1_100g.csv", delimiter=",")
    np.testing.assert_array_equal(ds.input[ds.observed], raw[:, 3] * PSI_PA)
    np.testing.assert_array_equal(ds.position_m[ds.observed], raw[:, 4] / 1e3)
    assert ds.metadata["converted_units"]["pressure_pa"]["from"] == "pressure_psi"

    path.with_suffix(".json").write_text(json.dumps({"columns": columns, "max_gap_s": 0.5}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        rest, pulses = load_segments(path)
    assert (rest.n_samples, rest.n_missing) == (1000, 0)
    assert pulses.observed.sum() == 11000 and pulses.metadata["segment"]["name"] == \
        "sample1_100g#2"
    assert rest.pressure_pa.max() < 2 * PSI_PA  # at rest: about 1.3 psi
    assert np.ptp(rest.position_m) < 0.5e-3  # still, under its load (noise, no stroke)
    assert np.nanmax(pulses.pressure_pa) > 200 * PSI_PA and np.nanmin(pulses.position_m) < -5e-3


def test_signals_in_separate_files_are_read_side_by_side(tmp_path: Path) -> None:
    """``"columns_from"``: a logger's time and position in one file, the pressure in
    another (with its own header line); the same data set as the one file holding all."""
    t = np.arange(300) * 5e-3
    rows = clock_rows(t)
    whole = lab_file(tmp_path, "whole.csv", rows, pressure_reference="gauge",
                     columns={"1": "time_s", "2": "pressure_kpa", "3": "position_mm"})
    lab_file(tmp_path, "x.txt", [f"{r.split(',')[0]} {r.split(',')[2]}" for r in rows])
    lab_file(tmp_path, "p.txt", ["pressure", *[r.split(",")[1] for r in rows]])
    path = lab_file(tmp_path, "x.txt", (tmp_path / "x.txt").read_text().splitlines(),
                    pressure_reference="gauge", columns={"1": "time_s", "2": "position_mm"},
                    columns_from={"p.txt": {"1": "pressure_kpa"}})
    ds, said = read_quietly(path)
    ref, _ = read_quietly(whole)
    for name in ("time_s", "input", "position_m"):
        np.testing.assert_array_equal(getattr(ds, name), getattr(ref, name))
    assert ds.metadata["read_columns"] == {"1": "time_s", "2": "position_mm",
                                           "p.txt:1": "pressure_kpa"}
    assert "columns_from" not in ds.metadata and any("pressure_kpa" in w for w in said)


@pytest.mark.parametrize("meta, pattern", [
    ({"columns_from": {"p.txt": {"1": "pressure_kpa"}}}, "'columns' must name"),
    ({"columns": {"1": "time_s", "2": "position_mm"}, "columns_from": {"q.txt": {"1":
      "pressure_kpa"}}}, r"names 'q.txt', but .*q.txt is not a file"),
    ({"columns": {"1": "time_s", "2": "position_mm"}, "columns_from": ["p.txt"]},
     "must map each other file's name"),
    ({"columns": {"1": "time_s", "2": "position_mm"}, "columns_from": {"p.txt": {"1":
      "position_mm"}}}, "position_mm is named twice"),
    ({"columns": {"1": "time_s", "2": "position_mm"}, "columns_from": {"p.txt": {"1":
      "force_kn"}, "short.txt": {"1": "pressure_kpa"}}}, "both pressure_kpa and force_kn"),
    ({"columns": {"1": "time_s", "2": "position_mm"}, "columns_from": {"short.txt": {"1":
      "pressure_kpa"}}}, r"short.txt: 299 rows of numbers \(lines 1-299\), against 300 in "
     r".*x.txt \(lines 1-300\).*cut the longer one"),
    ({"columns": {"1": "time_s", "2": "position_mm"}, "columns_from": {"p.txt": {"2":
      "pressure_kpa"}}}, r"p.txt: line 2: the sidecar's 'columns' names column 2"),
])
def test_bad_columns_from(tmp_path: Path, meta: dict, pattern: str) -> None:
    t = np.arange(300) * 5e-3
    rows = clock_rows(t)
    lab_file(tmp_path, "p.txt", ["pressure", *[r.split(",")[1] for r in rows]])
    lab_file(tmp_path, "short.txt", [r.split(",")[1] for r in rows[:-1]])
    path = lab_file(tmp_path, "x.txt", [f"{r.split(',')[0]} {r.split(',')[2]}" for r in rows],
                    pressure_reference="gauge", **meta)
    with pytest.raises(DataError, match=pattern):
        read_quietly(path)


def test_a_sensors_signal_is_read_through_its_calibration(tmp_path: Path) -> None:
    """``"calibration"``: a header's ``Pressure (V)``, a map's ``position_mv`` in another
    file; each read as gain x signal + offset, said, recorded, and written back as SI."""
    t = np.arange(200) * 1e-3
    volts = 1.0 + 0.5 * np.sin(2 * np.pi * 2.0 * t)
    mm = 2.0 + np.sin(2 * np.pi * 2.0 * t - 0.4)
    path = lab_file(tmp_path, "v.csv", ["Time (s),Pressure (V),Position (mm)"] + [
        f"{a!r},{b!r},{c!r}" for a, b, c in zip(t.tolist(), volts.tolist(), mm.tolist(),
                                                strict=True)],
        pressure_reference="gauge",
        calibration={"pressure_v": {"to": "pressure_kpa", "gain": 100.0, "offset": -12.5}})
    ds, said = read_quietly(path)
    np.testing.assert_allclose(ds.input[0], (100.0 * volts - 12.5) * 1e3, rtol=1e-14)
    np.testing.assert_array_equal(ds.position_m[0], mm / 1e3)
    assert ds.metadata["calibrated"] == {"pressure_v": {"to": "pressure_kpa", "gain": 100.0,
                                                        "offset": -12.5}}
    assert "calibration" not in ds.metadata
    assert any("calibration: pressure_kpa = 100 x V - 12.5" in w for w in said), said
    assert not any("'Pressure (V)' x" in w for w in said), said  # not a unit's factor
    save(ds, tmp_path / "own.csv")
    assert read_csv(tmp_path / "own.csv") == ds  # SI now: the record is not applied again
    assert "calibrated on reading: pressure_kpa = 100 x V - 12.5" in data.describe(ds)
    # the position's signal in a file of its own, named by a map
    lab_file(tmp_path, "x.txt", [f"{c * 250.0!r}" for c in mm.tolist()])  # 250 mV per mm
    path = lab_file(tmp_path, "p.txt", [f"{a!r} {b!r}" for a, b in zip(t.tolist(), volts.tolist(),
                                                                       strict=True)],
                    pressure_reference="gauge", columns={"1": "time_s", "2": "pressure_v"},
                    columns_from={"x.txt": {"1": "position_mv"}},
                    calibration={"pressure_v": {"to": "pressure_kpa", "gain": 100.0,
                                                "offset": -12.5},
                                 "position_mv": {"to": "position_mm", "gain": 0.004}})
    other, _ = read_quietly(path)
    np.testing.assert_allclose(other.input, ds.input, rtol=1e-14)
    np.testing.assert_allclose(other.position_m, ds.position_m, rtol=1e-14)


@pytest.mark.parametrize(("calibration", "pattern"), [
    ("100 kPa/V", r"'calibration' is '100 kPa/V'; it must map a column"),
    ({"pressure_kpa": {"to": "pressure_kpa", "gain": 1.0}},
     r"'calibration' 'pressure_kpa': not a column of a sensor's signal.*needs no calibration"),
    ({"pressure_v": {"to": "position_mm", "gain": 1.0}},
     r"\"to\" is 'position_mm'; it must be a unit of pressure pmabayes reads"),
    ({"pressure_v": {"to": "pressure_kpa"}}, r"give \"to\" .*, \"gain\" and"),
    ({"pressure_v": {"to": "pressure_kpa", "gain": 100.0, "zero": 1.0}}, r"give \"to\""),
    ({"pressure_v": {"to": "pressure_kpa", "gain": "100"}}, r"\"gain\" is '100'; it must be a "
     r"finite number"),
    ({"pressure_v": {"to": "pressure_kpa", "gain": 0}}, r"\"gain\" is 0"),
    ({"pressure_v": {"to": "pressure_kpa", "gain": 100.0},
      "pressure_mv": {"to": "pressure_kpa", "gain": 0.1}},
     r"'calibration' names pressure_mv, which no column of .*v.csv is"),
])
def test_bad_calibrations(tmp_path: Path, calibration: object, pattern: str) -> None:
    path = lab_file(tmp_path, "v.csv", ["Time (s),Pressure (V),Position (mm)", "0,1,2",
                                        "0.001,1,2"], calibration=calibration)
    with pytest.raises(DataError, match=r"the JSON sidecar .*v\.json: .*" + pattern):
        load(path)


def test_a_mat_files_sidecar_may_not_name_columns(tmp_path: Path) -> None:
    path = tmp_path / "m.mat"
    scipy.io.savemat(path, {"time_s": np.arange(5) * 0.01, "pressure_pa": np.ones(5),
                            "position_m": np.zeros(5)})
    path.with_suffix(".json").write_text(json.dumps(
        {"calibration": {"pressure_v": {"to": "pressure_kpa", "gain": 1.0}}}))
    with pytest.raises(DataError, match="'calibration' read the columns of a text file, and a "
                       ".mat file has variables: name them with \"mat_variables\""):
        load(path)


@pytest.mark.skipif(not (REAL / "rc_columns").is_dir(), reason=f"{REAL} is not there")
def test_the_real_rc_columns_as_the_docs_read_them(tmp_path: Path) -> None:
    """A load file (kN) and a displacement file (mm): one data set, as the user guide shows."""
    folder = REAL / "rc_columns"
    with pytest.warns(DataWarning, match="force_kn \\(kN\\) x 1000 -> force_n \\(N\\)"):
        force_n = read_columns(folder / "load_kN_chiu.txt", {"1": "force_kn"})["force_n"]
    with pytest.warns(DataWarning, match="position_mm \\(mm\\) x 0.001 -> position_m"):
        x_m = read_columns(folder / "displ_chiu.txt", {"1": "position_mm"})["position_m"]
    rig = {"name": "chiu", "input_kind": "force", "moving_mass_kg": 1360.0,
           "gravity_sign": 0.0, "area_m2": 1.0, "g_m_s2": 9.81}
    ds = data.Dataset(time_s=np.arange(force_n.size) * 0.02, input=force_n[np.newaxis],
                      position_m=x_m[np.newaxis], trial_ids=np.array([1]),
                      input_name="force_n", metadata={"rig": rig, "sample_rate_hz": 50.0})
    assert ds.n_samples == 2671 and ds.input_name == "force_n"
    assert np.abs(ds.input).max() == pytest.approx(185.28e3) and np.ptp(ds.position_m) < 1.0
    save(ds, tmp_path / "chiu.csv")
    assert load(tmp_path / "chiu.csv") == ds
    # the same two files read by a sidecar beside them, with no Python (linked, not copied)
    for name in ("displ_chiu.txt", "load_kN_chiu.txt"):
        (tmp_path / name).symlink_to(folder / name)
    (tmp_path / "displ_chiu.json").write_text(json.dumps({
        "columns": {"1": "position_mm"}, "columns_from": {"load_kN_chiu.txt": {"1": "force_kn"}},
        "sample_rate_hz": 50.0, "rig": rig}))
    side_by_side, _ = read_quietly(tmp_path / "displ_chiu.txt")
    np.testing.assert_array_equal(side_by_side.time_s, np.arange(2671) / 50.0)
    for name in ("input", "position_m"):
        np.testing.assert_array_equal(getattr(side_by_side, name), getattr(ds, name))
