"""Data files: CSV (or a headerless text file) with a JSON sidecar, NetCDF, and MATLAB
(read only); reading, checking and writing, and a record's segments
(:func:`load_segments`).

Bad input raises :class:`~pmabayes.data.DataError` naming the file, the line or
trial, and the fix; the plausibility checks of :mod:`pmabayes.data.plausibility`
run on everything read.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import xarray as xr

from pmabayes.data.calibration import SignalNames, apply, calibrations
from pmabayes.data.dataset import (
    DataError,
    Dataset,
    _json_roundtrip_check,
)
from pmabayes.data.matlab import read_mat, read_mat_segments
from pmabayes.data.plausibility import _checked
from pmabayes.data.record import _positive_rate, _table_datasets
from pmabayes.data.sidecar import _read_sidecar, _sidecar_path
from pmabayes.data.text import _columns_table, _header_table, _other_files

__all__ = ["read_csv", "write_csv", "read_netcdf", "write_netcdf", "load", "save",
           "load_segments"]


_NC_ENGINE = "h5netcdf"


PathLike = str | os.PathLike[str]


def _text_segments(path: PathLike, check_units: bool = True, split: bool = False
                   ) -> list[Dataset]:
    """A text file (a CSV with a header, or columns named by the sidecar) as data sets."""
    path = Path(path)
    where = str(path)
    sidecar = _sidecar_path(path)
    metadata: dict = {}
    if sidecar != path and sidecar.is_file():
        metadata = _read_sidecar(sidecar)
    declare = f"the JSON sidecar {sidecar}"
    has_rate = _positive_rate(metadata) is not None
    if "columns_from" in metadata and "columns" not in metadata:
        raise DataError(f"{declare}: 'columns_from' reads columns of other files beside "
                        f"this file's own, which 'columns' must name (e.g. {{\"columns\": "
                        f"{{\"1\": \"position_mm\"}}}}): add it.")
    calibrated = calibrations(metadata.get("calibration"), declare)
    signals = SignalNames(calibrated) if calibrated else None
    if "columns" in metadata:
        others = (_other_files(metadata["columns_from"], sidecar.parent, declare, signals)
                  if "columns_from" in metadata else [])
        table = _columns_table(path, where, metadata["columns"], declare, has_rate, others,
                               signals)
    else:
        table = _header_table(path, where, has_rate, signals)
    if signals is not None:  # the declaration becomes a record: the data set holds SI
        record = apply(signals, table.values, where, declare)
        metadata = {**{k: v for k, v in metadata.items() if k != "calibration"},
                    "calibrated": record}
    return _table_datasets(table, metadata, path, declare, check_units, split)


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
        is read as a metadata object. Column names may carry other units
        (:data:`pmabayes.data.UNITS`: ``time_ms``, ``pressure_psi``,
        ``position_mm``, ...), converted to SI once, with one :class:`DataWarning`
        naming each conversion and the metadata's ``"converted_units"`` recording
        them. ``trial`` may be left out (one trial, id 1), and ``time_s`` when the
        sidecar gives ``sample_rate_hz``. Fields may be separated by commas,
        semicolons or tabs (a comma in a number is then its decimal mark, said once),
        fields may be quoted, and ``#`` lines above the header are skipped (said).
        A file without a header (``.txt`` and ``.dat`` too; white space may separate
        its fields) is read through the sidecar's
        ``"columns"``, which names its columns by number from 1, e.g. ``{"columns":
        {"3": "time_s", "4": "pressure_psi", "5": "position_mm"}}``; columns not
        named are not read (the metadata records the map as ``"read_columns"``).
        A lab's clock need not be exact: times within 10% of a step of a uniform grid
        (a DAQ's jitter) are that grid, and a gap in the clock is samples not
        observed (:attr:`Dataset.observed`), said in one :class:`DataWarning`, gaps
        first. A sidecar ``"max_gap_s"`` splits the record at longer gaps into
        segments: read them with :func:`load_segments`.
    check_units : bool, optional
        For pressure data, reject values that look like the wrong unit: pressure in
        MPa or bar (max ``|p| <= 20`` with some non-zero value), pressure below vacuum
        (``< -101325`` Pa gauge), position not in m (``max |x| > 0.5`` m: the message
        names the unit the values look like), or times not in the column's unit (a
        sample rate below 10 Hz with an input cycling slower than 0.01 Hz, or above
        100 kHz with one faster than 50 Hz, when no ``sample_rate_hz`` is declared);
        and warn (:class:`DataWarning`) when the pressure looks absolute (lowest command
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
        If the file or sidecar is missing pieces, malformed or inconsistent (a clock
        that runs backwards, a unit pmabayes does not know, two columns for one
        quantity, a ``"columns"`` number beyond the file's width, a record that
        splits into several segments). The message names the file, the line (header
        = line 1) or trial, and the fix.

    Warns
    -----
    DataWarning
        If units are converted, if the clock has jitter or gaps, or if the pressure
        looks absolute or offset rather than gauge, unless the metadata declares
        ``"pressure_reference"``.

    Examples
    --------
    A lab's file with its own header style: the units are read from it and converted to
    SI, once (a :class:`DataWarning` says so):

    >>> from pathlib import Path
    >>> from pmabayes.data import read_csv
    >>> rows = [f"{trial},{10 * k},{k % 5},{k % 5 / 10 + trial / 100}"
    ...         for trial in (1, 2) for k in range(20)]
    >>> _ = Path("lab.csv").write_text("\\n".join(["Trial,Time (ms),Pressure (psi),Position (mm)",
    ...                                           *rows]))
    >>> data = read_csv("lab.csv")
    >>> data
    Dataset(n_trials=2, n_samples=20, dt_s=0.01, input_name='pressure_pa', trial_ids=[1, 2],
            source='lab.csv')
    >>> data.metadata["converted_units"]["pressure_pa"]["from"]
    'pressure_psi'
    >>> round(float(data.input.max()))  # 4 psi, in Pa
    27579
    """
    return _text_segments(path, check_units, split=False)[0]


def write_csv(dataset: Dataset, path: PathLike) -> None:
    """Write a data set as CSV, plus a JSON sidecar when it has metadata.

    Parameters
    ----------
    dataset : Dataset
        The data to write.
    path : str or os.PathLike
        Destination CSV file (overwritten). Columns are written as
        ``trial,time_s,<input_name>,position_m``; floats use the shortest repr that
        reads back bit-exactly. Samples not observed are not written: the clock
        shows the gaps, and :func:`read_csv` rebuilds them exactly. The sidecar is
        ``path`` with suffix ``.json``; if the metadata is empty, a sidecar left from
        an earlier write is removed so that :func:`read_csv` returns exactly
        ``dataset``.

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
    for tid, u_row, x_row, seen in zip(
        dataset.trial_ids.tolist(),
        dataset.input.tolist(),
        dataset.position_m.tolist(),
        dataset.observed.tolist(),
        strict=True,
    ):
        out.extend(f"{tid},{t},{u!r},{x!r}" for t, u, x, s in
                   zip(times, u_row, x_row, seen, strict=True) if s)
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
    ".txt": read_csv,
    ".dat": read_csv,
    ".tsv": read_csv,
    ".lvm": read_csv,
    ".nc": read_netcdf,
    ".mat": read_mat,
}


_WRITERS: dict[str, Callable[[Dataset, PathLike], None]] = {
    ".csv": write_csv,
    ".nc": write_netcdf,
}


_SHEETS = (".xlsx", ".xls", ".xlsm", ".ods", ".numbers")


def _suffix(path: Path, table: dict[str, Any]) -> str:
    suffix = path.suffix.lower()
    if suffix not in table:
        kinds = ", ".join(table)
        writes = ("" if table is _WRITERS else
                  " (.txt, .dat, .tsv and LabVIEW's .lvm: text read like .csv; .mat: "
                  "MATLAB v4 to v7.3)")
        sheet = (" A spreadsheet's own format is not read: save the sheet as CSV "
                 "(File > Save As), one column per signal." if suffix in _SHEETS else "")
        raise DataError(
            f"{path}: unsupported file type {path.suffix or '(no suffix)'!r}; use one of "
            f"{kinds}{writes}.{sheet}"
        )
    return suffix


def load(path: PathLike, **kwargs: Any) -> Dataset:
    """Read a data file, choosing the reader from the suffix.

    Three formats are read, each with an optional JSON sidecar of the same stem
    (``foo.csv`` -> ``foo.json``) holding the metadata:

    - ``.csv``, ``.txt``, ``.dat``, ``.tsv``, ``.lvm`` (:func:`read_csv`):
      ``trial,time_s,pressure_pa,position_m``
      (or ``force_n``, or the same in other units), one row per sample; or a
      headerless file whose columns the sidecar's ``"columns"`` names;
    - ``.nc`` (:func:`read_netcdf`): NetCDF written by :func:`write_netcdf`;
    - ``.mat`` (:func:`~pmabayes.data.matlab.read_mat`): MATLAB v4 to v7 (scipy) and
      v7.3 (HDF5, h5py), numeric arrays or Simulink structures; the sidecar's
      ``"mat_variables"`` (or keywords) say which variable is time, input and
      position.

    Parameters
    ----------
    path : str or os.PathLike
        ``.csv``, ``.txt``, ``.dat``, ``.tsv``, ``.lvm``, ``.nc`` or ``.mat``, any case.
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
        If the suffix is not supported, or the reader rejects the file (a record
        that splits into segments at gaps longer than ``"max_gap_s"`` is read with
        :func:`load_segments`).

    Examples
    --------
    The bundled synthetic chirps (``data/`` of a checkout), with their sidecar's rig:

    >>> from pmabayes.data import load
    >>> data = load("data/pma_chirp_lab.csv")
    >>> data
    Dataset(n_trials=10, n_samples=15000, dt_s=0.001, input_name='pressure_pa',
            trial_ids=[0, 1, 2, 3, 4, 5, 6, 7, 8, 9], source='data/pma_chirp_lab.csv')
    >>> data.metadata["rig"]["moving_mass_kg"], data.metadata["synthetic"]
    (0.067, True)
    """
    path = Path(path)
    return _READERS[_suffix(path, _READERS)](path, **kwargs)


def load_segments(path: PathLike, **kwargs: Any) -> list[Dataset]:
    """Read a data file as its segments: one data set per stretch of the record between
    gaps longer than the sidecar's ``"max_gap_s"``.

    A lab's DAQ may stop between blocks of samples. Gaps up to ``"max_gap_s"`` (s)
    are samples not observed (:attr:`Dataset.observed`); a longer gap ends a segment,
    and the next starts on its own grid (its own first time and phase). Without
    ``"max_gap_s"``, or without such a gap, the record is one segment, returned as
    :func:`load` returns it.

    Parameters
    ----------
    path : str or os.PathLike
        As for :func:`load`. A NetCDF file holds one segment.
    **kwargs
        Forwarded to the reader, as for :func:`load`.

    Returns
    -------
    list of Dataset
        The segments in time order. With more than one, each has ``source``
        ``dir/stem#i.suffix`` (so that ``Path(source).stem`` is ``stem#i``) and the
        metadata ``"segment"``: ``{"name": "stem#i", "index": i, "of": n, "first":
        "line ...", "last": "line ...", "start_s": ...}``, so that the segments can be
        fitted as experiments of one rig.

    Raises
    ------
    DataError
        As :func:`load`; also when a segment holds a single sample, or the trials of
        a file do not split at the same times.

    Warns
    -----
    DataWarning
        Once per file for the clock (its gaps, segments and jitter), as :func:`load`.

    Examples
    --------
    A record whose DAQ stopped for 0.4 s between two blocks, and a sidecar that says gaps
    over 0.1 s end a segment:

    >>> import json
    >>> from pathlib import Path
    >>> from pmabayes.data import load_segments
    >>> times = [k / 100 for k in [*range(20), *range(60, 80)]]
    >>> rows = [f"1,{t:.2f},{2e5 + 1e5 * (k % 4)},{(k % 4) / 1000}" for k, t in enumerate(times)]
    >>> header = "trial,time_s,pressure_pa,position_m"
    >>> _ = Path("blocks.csv").write_text("\\n".join([header, *rows]))
    >>> _ = Path("blocks.json").write_text(json.dumps({"max_gap_s": 0.1}))
    >>> first, second = load_segments("blocks.csv")
    >>> first.source, second.source, float(second.time_s[0])
    ('blocks#1.csv', 'blocks#2.csv', 0.6)
    >>> second.metadata["segment"]["first"]
    'line 22'
    """
    path = Path(path)
    suffix = _suffix(path, _READERS)
    if suffix == ".mat":
        return read_mat_segments(path, **kwargs)
    if suffix == ".nc":
        return [read_netcdf(path, **kwargs)]
    return _text_segments(path, split=True, **kwargs)


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

    Examples
    --------
    >>> from pmabayes.data import load, save
    >>> data = load("data/pma_chirp_paper.csv")
    >>> save(data, "chirp.nc")  # NetCDF: smaller, and read faster than the CSV
    >>> load("chirp.nc") == data
    True
    """
    path = Path(path)
    _WRITERS[_suffix(path, _WRITERS)](dataset, path)
