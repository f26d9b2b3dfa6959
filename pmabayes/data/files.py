"""Data files: CSV with a JSON sidecar, NetCDF, and MATLAB (read only); reading,
checking and writing.

Bad input raises :class:`~pmabayes.data.DataError` naming the file, the line or
trial, and the fix; the plausibility checks of :mod:`pmabayes.data.plausibility`
run on everything read.
"""

from __future__ import annotations

import decimal
import difflib
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from pmabayes.data.clock import _rounded_grid, _trial_blocks
from pmabayes.data.dataset import (
    _REL_TOL,
    INPUT_NAMES,
    DataError,
    Dataset,
    _check_metadata_rate,
    _first_in_file_order,
    _fmt,
    _json_roundtrip_check,
    check_time_grid,
)
from pmabayes.data.matlab import read_mat
from pmabayes.data.plausibility import _checked
from pmabayes.data.sidecar import _read_sidecar, _sidecar_path

__all__ = ["read_csv", "write_csv", "read_netcdf", "write_netcdf", "load", "save"]


_NC_ENGINE = "h5netcdf"


PathLike = str | os.PathLike[str]


_BASE_COLUMNS = ("trial", "time_s", "position_m")


_EXPECTED_TEXT = (
    "expected columns: trial, time_s, position_m and exactly one of pressure_pa "
    "(commanded gauge pressure, Pa) or force_n (force, N), in any order"
)


def _parse_header(fields: list[str], where: str) -> tuple[list[str], str]:
    """Validate the header; return the column names and the input column name."""
    problems = []
    names = [f.strip() for f in fields]
    if all(_is_number(n) for n in names if n):
        raise DataError(
            f"{where}: line 1: expected a header line such as "
            f"'trial,time_s,pressure_pa,position_m', got {','.join(fields)!r}; "
            "add the header as the first line."
        )
    for i, n in enumerate(names):
        if not n:
            problems.append(f"column {i + 1} has an empty name (stray comma?)")
    seen: dict[str, int] = {}
    for i, n in enumerate(names):
        if n and n in seen:
            problems.append(f"column {n!r} appears twice (columns {seen[n] + 1} and {i + 1})")
        seen.setdefault(n, i)
    present = set(names)
    inputs = [n for n in INPUT_NAMES if n in present]
    missing = [n for n in _BASE_COLUMNS if n not in present]
    if len(inputs) == 2:
        problems.append("both pressure_pa and force_n are present; keep exactly one input column")
    candidates = missing + ([] if inputs else list(INPUT_NAMES))
    known = set(_BASE_COLUMNS) | set(INPUT_NAMES)
    for n in names:
        if n and n not in known:
            match = difflib.get_close_matches(n.lower(), candidates, n=1, cutoff=0.6)
            hint = f" ('{n}' looks like '{match[0]}')" if match else ""
            problems.append(f"unexpected column {n!r}{hint}")
    for n in missing:
        problems.append(f"missing column {n!r}")
    if not inputs:
        problems.append("missing input column: need one of 'pressure_pa' or 'force_n'")
    if problems:
        raise DataError(
            f"{where}: line 1 (header): " + "; ".join(problems) + f". The {_EXPECTED_TEXT}; "
            "rename, add or remove columns to match."
        )
    return names, inputs[0]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return "_" not in text


def _scan_rows(lines: list[str], names: list[str], where: str) -> None:
    """Slow row-by-row scan that raises for the first bad line (called on failure)."""
    ncol = len(names)
    i64 = np.iinfo(np.int64)
    for i, line in enumerate(lines):
        lineno = i + 2
        fields = line.split(",")
        if len(fields) != ncol:
            what = "is blank" if not line.strip() else f"has {len(fields)} fields"
            raise DataError(
                f"{where}: line {lineno} {what}; every row needs {ncol} comma-separated "
                f"fields ({','.join(names)}). Fix or remove the row."
            )
        for name, text in zip(names, fields, strict=True):
            t = text.strip()
            if name == "trial":
                try:
                    if "_" in t:
                        raise ValueError
                    value = int(t)
                except ValueError:
                    raise DataError(
                        f"{where}: line {lineno}, column trial: trial id {text!r} is not "
                        "an integer; use integer trial ids."
                    ) from None
                if not i64.min <= value <= i64.max:
                    raise DataError(
                        f"{where}: line {lineno}, column trial: trial id {t} is outside "
                        "the int64 range; renumber the trials."
                    )
                continue
            if not t or not _is_number(t):
                raise DataError(
                    f"{where}: line {lineno}, column {name}: {text!r} is not a number; "
                    "write plain decimal numbers (e.g. 0.25 or 1.5e5) in SI units."
                )
            if not math.isfinite(float(t)):
                _raise_nonfinite(where, lineno, name, text)


def _raise_nonfinite(where: str, lineno: int, name: str, text: str) -> None:
    raise DataError(
        f"{where}: line {lineno}, column {name}: value {text.strip()!r} is NaN or "
        "infinite; missing or saturated samples must be handled before import "
        "(nothing is dropped or filled in automatically)."
    )


def _read_text(path: Path, where: str) -> str:
    if not path.exists():
        raise DataError(f"{where}: file not found; check the path.")
    if not path.is_file():
        raise DataError(f"{where}: not a regular file; give the path of a data file.")
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        lineno = raw.count(b"\n", 0, exc.start) + 1
        raise DataError(
            f"{where}: line {lineno}: bytes are not valid UTF-8 ({exc.reason}); "
            "save the file as UTF-8 (or plain ASCII) text."
        ) from None


def _csv_rows(path: Path, where: str) -> tuple[list[str], str, list[str]]:
    """The header's column names, the input column's name, and the data rows."""
    text = _read_text(path, where)
    lines = text.replace("\r\n", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise DataError(
            f"{where}: file is empty; expected a header line "
            "'trial,time_s,pressure_pa,position_m' followed by one row per sample."
        )
    names, input_name = _parse_header(lines[0].split(","), where)
    rows = lines[1:]
    if not rows:
        raise DataError(
            f"{where}: line 2: header only, no data rows; add one row per sample "
            f"({','.join(names)})."
        )
    for i, line in enumerate(rows):
        if not line.strip():  # np.loadtxt would skip blank lines silently
            raise DataError(
                f"{where}: line {i + 2} is blank; remove blank lines between data rows."
            )

    return names, input_name, rows


def _parse_rows(rows: list[str], names: list[str], where: str) -> np.ndarray:
    """The rows as a structured array of finite values (``trial`` as int64)."""
    dtype = [(n, np.int64 if n == "trial" else np.float64) for n in names]
    try:
        table = np.loadtxt(rows, delimiter=",", dtype=dtype, comments=None, ndmin=1)
    except ValueError as exc:
        _scan_rows(rows, names, where)
        raise DataError(
            f"{where}: could not parse the data rows ({exc}; numpy counts rows from 0 at line 2). "
            "Write plain comma-separated numbers."
        ) from None

    value_cols = [n for n in names if n != "trial"]
    first_bad: tuple[int, str] | None = None
    for n in value_cols:
        bad = ~np.isfinite(table[n])
        if bad.any():
            r = int(np.argmax(bad))
            if first_bad is None or r < first_bad[0]:
                first_bad = (r, n)
    if first_bad is not None:
        r, n = first_bad
        _raise_nonfinite(where, r + 2, n, rows[r].split(",")[names.index(n)])

    return table


def _printed_step(rows: list[str], column: int) -> float | None:
    """The finest decimal step the time column is printed with (1e-6 for 0.001333)."""
    exponents = set()
    for line in rows:
        try:
            exponents.add(decimal.Decimal(line.split(",")[column].strip()).as_tuple().exponent)
        except (decimal.InvalidOperation, IndexError):
            return None
    finest = min(exponents)
    return 10.0 ** finest if isinstance(finest, int) else None


def _shared_grid(
    trial: np.ndarray, time: np.ndarray, where: str
) -> tuple[np.ndarray, np.ndarray, float]:
    """Trial ids in file order, the times as ``(n_trials, n_samples)``, the interval.

    Each trial's rows must be one contiguous block on a uniform grid, and all
    trials must share the first trial's sample times.
    """
    trial = np.ascontiguousarray(trial)
    time = np.ascontiguousarray(time)
    starts, ends = (np.array(c, dtype=np.int64) for c in zip(*_trial_blocks(trial), strict=True))
    run_ids = trial[starts]

    # Each trial must occupy one contiguous block of rows.
    first_line: dict[int, int] = {}
    for s, tid in zip(starts.tolist(), run_ids.tolist(), strict=True):
        if tid in first_line:
            raise DataError(
                f"{where}: line {s + 2}: trial {tid} reappears after trial "
                f"{int(trial[s - 1])} (first seen on line {first_line[tid]}); each "
                "trial's rows must be contiguous: sort the rows by trial, then time_s."
            )
        first_line[tid] = s + 2

    lengths = ends - starts
    dts = []
    for s, e, tid in zip(starts.tolist(), ends.tolist(), run_ids.tolist(), strict=True):
        if e - s < 2:
            raise DataError(
                f"{where}: trial {tid} has only 1 sample (line {s + 2}); every trial "
                "needs at least 2 samples."
            )
        dts.append(check_time_grid(time[s:e], source=f"{where}: trial {tid}",
                                   locate=lambda j, s=s: f"line {s + j + 2}"))
    dt_ref = dts[0]

    if not (lengths == lengths[0]).all():
        listed = ", ".join(
            f"trial {tid}: {ln} (lines {s + 2}-{s + ln + 1})"
            for tid, ln, s in zip(
                run_ids[:12].tolist(), lengths[:12].tolist(), starts[:12].tolist(), strict=True
            )
        )
        more = ", ..." if run_ids.size > 12 else ""
        raise DataError(
            f"{where}: trials have unequal lengths (samples): {listed}{more}; all trials "
            "must cover the same sample times; trim or split them to a common grid."
        )

    n_trials, n_samples = run_ids.size, int(lengths[0])
    times = time.reshape(n_trials, n_samples)
    ref = times[0]
    off = np.abs(times - ref) > _REL_TOL * dt_ref
    if off.any():
        k, j = _first_in_file_order(off)
        raise DataError(
            f"{where}: trial {int(run_ids[k])}: line {k * n_samples + j + 2}: time_s = "
            f"{_fmt(times[k, j])} but trial {int(run_ids[0])} has {_fmt(ref[j])} at the "
            f"same sample (line {j + 2}); all trials must share the same sample times "
            "(start every trial's clock at the same value)."
        )

    return run_ids, times, dt_ref


def read_csv(path: PathLike, *, check_units: bool = True) -> Dataset:
    """Read a CSV data file (and its optional JSON sidecar).

    Parameters
    ----------
    path : str or os.PathLike
        CSV file with header ``trial,time_s,pressure_pa,position_m`` (any column
        order; ``force_n`` may replace ``pressure_pa``) and one row per sample. Each
        trial's rows must be contiguous and in time order; all trials must have the
        same, uniformly spaced sample times (relative tolerance 1e-6 of the interval;
        the first trial's times are kept). If ``path`` with suffix ``.json`` exists it
        is read as a metadata object.
    check_units : bool, optional
        For pressure data, reject values that look like the wrong unit: pressure in
        MPa or bar (max ``|p| <= 20`` with some non-zero value), pressure below vacuum
        (``< -101325`` Pa gauge), or position not in m (``max |x| > 0.5`` m); and
        warn (:class:`DataWarning`) when the pressure looks absolute (lowest command
        80 to 110 kPa) or offset (below -20 kPa) instead of gauge. Default True. Not
        applied to force data, whose scale is arbitrary. The metadata entry
        ``"check_units": false`` switches the checks off as well.

    Returns
    -------
    Dataset
        The validated data, with ``source`` set to ``str(path)``. Pressure declared
        absolute (metadata ``"pressure_reference": "absolute"``) is converted to
        gauge by subtracting ``"ambient_pressure_pa"`` (101325 Pa by default); the
        metadata then says ``"pressure_reference": "gauge"`` and records the
        conversion under ``"converted_from_absolute"``.

    Raises
    ------
    DataError
        If the file or sidecar is missing pieces, malformed or inconsistent. The
        message names the file, the line (header = line 1) or trial, and the fix.

    Warns
    -----
    DataWarning
        If the pressure looks absolute or offset rather than gauge, unless the
        metadata declares ``"pressure_reference"``.
    """
    path = Path(path)
    where = str(path)
    names, input_name, rows = _csv_rows(path, where)
    table = _parse_rows(rows, names, where)
    metadata: dict = {}
    sidecar = _sidecar_path(path)
    if sidecar != path and sidecar.is_file():
        metadata = _read_sidecar(sidecar)
    rate = metadata.get("sample_rate_hz")
    column = names.index("time_s")
    time = _rounded_grid(table["trial"], table["time_s"], lambda: _printed_step(rows, column),
                         rate if isinstance(rate, int | float) and rate > 0 else None, where)
    run_ids, times, dt_s = _shared_grid(table["trial"], time, where)
    n_trials, n_samples = times.shape
    if metadata:
        _check_metadata_rate(metadata, 1.0 / dt_s, f"{sidecar} (metadata sidecar of {path.name})")

    ds = Dataset(
        time_s=times[0],
        input=np.ascontiguousarray(table[input_name]).reshape(n_trials, n_samples),
        position_m=np.ascontiguousarray(table["position_m"]).reshape(n_trials, n_samples),
        trial_ids=run_ids,
        input_name=input_name,
        metadata=metadata,
        source=where,
    )
    return _checked(
        ds,
        where,
        lambda k, j: f"line {k * n_samples + j + 2}, trial {int(run_ids[k])}",
        f"the JSON sidecar {sidecar}",
        check_units,
    )


def write_csv(dataset: Dataset, path: PathLike) -> None:
    """Write a data set as CSV, plus a JSON sidecar when it has metadata.

    Parameters
    ----------
    dataset : Dataset
        The data to write.
    path : str or os.PathLike
        Destination CSV file (overwritten). Columns are written as
        ``trial,time_s,<input_name>,position_m``; floats use the shortest repr that
        reads back bit-exactly. The sidecar is ``path`` with suffix ``.json``; if the
        metadata is empty, a sidecar left from an earlier write is removed so that
        :func:`read_csv` returns exactly ``dataset``.

    Raises
    ------
    TypeError
        If ``dataset`` is not a :class:`Dataset`.
    DataError
        If ``path`` ends in ``.json`` (it would clash with the sidecar) or the
        metadata cannot be stored as JSON exactly.
    """
    if not isinstance(dataset, Dataset):
        raise TypeError(f"write_csv needs a Dataset, got {type(dataset).__name__}")
    path = Path(path)
    sidecar = _sidecar_path(path)
    if sidecar == path:
        raise DataError(
            f"{path}: a CSV file cannot have the suffix .json (reserved for the metadata "
            "sidecar); use .csv."
        )
    meta_text = _json_roundtrip_check(dataset.metadata, f"{path} (metadata)")

    times = [repr(t) for t in dataset.time_s.tolist()]
    out = [f"trial,time_s,{dataset.input_name},position_m"]
    for tid, u_row, x_row in zip(
        dataset.trial_ids.tolist(),
        dataset.input.tolist(),
        dataset.position_m.tolist(),
        strict=True,
    ):
        out.extend(f"{tid},{t},{u!r},{x!r}" for t, u, x in zip(times, u_row, x_row, strict=True))
    out.append("")
    path.write_text("\n".join(out), encoding="utf-8", newline="\n")
    if dataset.metadata:
        sidecar.write_text(meta_text + "\n", encoding="utf-8", newline="\n")
    elif sidecar.is_file():
        sidecar.unlink()


def read_netcdf(path: PathLike, *, check_units: bool = True) -> Dataset:
    """Read a NetCDF file written by :func:`write_netcdf`.

    Parameters
    ----------
    path : str or os.PathLike
        NetCDF4/HDF5 file (read with xarray, engine ``h5netcdf``).
    check_units : bool, optional
        Apply the same unit plausibility checks, and the same metadata declarations
        (``check_units``, ``pressure_reference``), as :func:`read_csv`. Default True.

    Returns
    -------
    Dataset
        The validated data, with ``source`` set to ``str(path)``.

    Raises
    ------
    DataError
        If the file is missing, unreadable, lacks the expected variables, or holds
        invalid values. Messages name the file and the trial.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise DataError(f"{where}: file not found; check the path.")
    try:
        with xr.open_dataset(
            path, engine=_NC_ENGINE, decode_times=False, decode_timedelta=False
        ) as xds:
            xds.load()
    except (OSError, ValueError) as exc:
        raise DataError(
            f"{where}: not a readable NetCDF4/HDF5 file ({exc}); write it with "
            "pmabayes.data.write_netcdf."
        ) from None
    ds = Dataset.from_xarray(xds, source=where)
    ids = ds.trial_ids
    return _checked(
        ds,
        where,
        lambda k, j: f"trial {int(ids[k])}, sample {j}",
        f"the metadata of {where} (Dataset.metadata, written by write_netcdf)",
        check_units,
    )


def write_netcdf(dataset: Dataset, path: PathLike) -> None:
    """Write a data set as NetCDF (xarray, engine ``h5netcdf``).

    Parameters
    ----------
    dataset : Dataset
        The data to write.
    path : str or os.PathLike
        Destination file (overwritten). Layout as :meth:`Dataset.to_xarray`; the
        metadata is stored as the JSON string attribute ``metadata_json``.

    Raises
    ------
    TypeError
        If ``dataset`` is not a :class:`Dataset`.
    DataError
        If the metadata cannot be stored as JSON exactly.
    """
    if not isinstance(dataset, Dataset):
        raise TypeError(f"write_netcdf needs a Dataset, got {type(dataset).__name__}")
    xds = dataset.to_xarray()
    encoding = {name: {"_FillValue": None} for name in xds.variables}
    xds.to_netcdf(Path(path), engine=_NC_ENGINE, encoding=encoding)


_READERS: dict[str, Callable[..., Dataset]] = {
    ".csv": read_csv,
    ".nc": read_netcdf,
    ".mat": read_mat,
}


_WRITERS: dict[str, Callable[[Dataset, PathLike], None]] = {
    ".csv": write_csv,
    ".nc": write_netcdf,
}


def _suffix(path: Path, table: dict[str, Any]) -> str:
    suffix = path.suffix.lower()
    if suffix not in table:
        kinds = ", ".join(table)
        writes = "" if table is _WRITERS else " (.mat: MATLAB v4 to v7.3)"
        raise DataError(
            f"{path}: unsupported file type {path.suffix or '(no suffix)'!r}; use one of "
            f"{kinds}{writes}."
        )
    return suffix


def load(path: PathLike, **kwargs: Any) -> Dataset:
    """Read a data file, choosing the reader from the suffix.

    Three formats are read, each with an optional JSON sidecar of the same stem
    (``foo.csv`` -> ``foo.json``) holding the metadata:

    - ``.csv`` (:func:`read_csv`): ``trial,time_s,pressure_pa,position_m`` (or
      ``force_n``), one row per sample;
    - ``.nc`` (:func:`read_netcdf`): NetCDF written by :func:`write_netcdf`;
    - ``.mat`` (:func:`~pmabayes.data.matlab.read_mat`): MATLAB v4 to v7 (scipy) and
      v7.3 (HDF5, h5py), numeric arrays or Simulink structures; the sidecar's
      ``"mat_variables"`` (or keywords) say which variable is time, input and
      position.

    Parameters
    ----------
    path : str or os.PathLike
        ``.csv``, ``.nc`` or ``.mat``, any case.
    **kwargs
        Forwarded to the reader (e.g. ``check_units=False``; for ``.mat`` also
        ``time_s=``, ``pressure_pa=``, ``position_m=``, ...); unknown names raise
        TypeError.

    Returns
    -------
    Dataset
        The validated data.

    Raises
    ------
    DataError
        If the suffix is not supported, or the reader rejects the file.
    """
    path = Path(path)
    return _READERS[_suffix(path, _READERS)](path, **kwargs)


def save(dataset: Dataset, path: PathLike) -> None:
    """Write a data set, choosing the writer from the suffix.

    Parameters
    ----------
    dataset : Dataset
        The data to write.
    path : str or os.PathLike
        ``.csv`` (:func:`write_csv`) or ``.nc`` (:func:`write_netcdf`), any case.

    Raises
    ------
    DataError
        If the suffix is not supported, or the writer rejects the data.
    """
    path = Path(path)
    _WRITERS[_suffix(path, _WRITERS)](dataset, path)
