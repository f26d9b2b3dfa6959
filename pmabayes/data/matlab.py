"""MATLAB ``.mat`` files as labs and Simulink write them: v4/v5/v6/v7 and v7.3 (HDF5).

Versions 4 to 7 are read with :func:`scipy.io.loadmat`; version 7.3, an HDF5 file
behind a 512-byte MATLAB header, with :mod:`h5py` (MATLAB's layout: arrays stored
transposed, a ``MATLAB_class`` attribute on every variable, text as ``uint16``,
structs as groups, cells and struct arrays as references into ``#refs#``).

Which variable is what
----------------------
A ``.mat`` file has no columns, so its variables are mapped to the roles pmabayes
needs, by keyword (``read_mat(path, time_s="t", pressure_pa="p_cmd",
position_m="x")``) or in the JSON sidecar beside the file (``foo.mat`` ->
``foo.json``)::

    {
      "mat_variables": {"time_s": "t", "pressure_pa": "p_cmd", "position_m": ["x1", "x2"]},
      "mat_trials": "columns",
      "sample_rate_hz": 1000.0
    }

``"mat_variables"`` maps a role to the variables that hold it:

``time_s``
    One vector of sample times in s. Optional: without it, the time comes from a
    Simulink "Structure with time", or else from the sidecar's ``sample_rate_hz``
    (``t = k / rate``, from 0).
``pressure_pa`` or ``force_n`` (exactly one)
    The input: commanded gauge pressure in Pa, or force in N. The key says the input
    kind, as the CSV column's name does. One trial of input with several trials of
    position means the same command for every trial.
``position_m``
    The measured position in m.

Each value is a variable name, a list of names (one or more trials each, in order),
or a pattern with ``*`` / ``?`` (``"x_*"``: every matching variable, sorted by the
number the name ends with). A name may reach into a struct and index it the MATLAB
way, 1-based: ``"ScopeData.signals(2).values"``, ``"y(:,3)"`` (a column),
``"y(3,:)"`` (a row). Without a mapping, variables named ``time_s``,
``pressure_pa`` (or ``force_n``) and ``position_m`` are used, like CSV columns.
Keywords and the sidecar may both map roles; mapping one role to two different
things is an error.

What a variable may hold
------------------------
- a vector (``1 x N`` or ``N x 1``): one trial;
- a 2-D array of several trials: ``"mat_trials": "columns"`` (``N x n_trials``,
  MATLAB's usual layout) or ``"rows"`` (``n_trials x N``). Without the declaration the
  layout is taken from the number of samples, when a time vector or a 1-D variable
  fixes it and only one axis matches;
- a Simulink "Structure with time" or "Structure" (``x.time``, ``x.signals.values``):
  the values, ``N x k`` (time along the rows), and the time if it is stored.

Trials are numbered from 1 in the order read; variables per trial whose names end in
distinct numbers (``x1``, ``x2``, ``x10``) keep those numbers as trial ids.

Values must already be SI (the role's name says the unit); nothing is rescaled and no
unit is guessed. The unit plausibility checks, the sidecar's declarations
(``pressure_reference``, ``check_units``, ``input_between_samples``,
``period_samples``, ``rig``, ...) and the time-grid checks are those of every other
format. A time vector stored in single precision that is uniform to that precision
is rebuilt as ``t0 + k / rate`` with a :class:`~pmabayes.data.DataWarning`, as a CSV
clock printed with too few digits is.
"""

from __future__ import annotations

import difflib
import fnmatch
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmabayes.data.clock import _rounded_grid
from pmabayes.data.dataset import (
    _REL_TOL,
    INPUT_NAMES,
    DataError,
    Dataset,
    _check_declarations,
    check_time_grid,
)
from pmabayes.data.plausibility import _checked
from pmabayes.data.record import (
    _check_estimate,
    _clocked,
    _positive_rate,
    _segment_metadata,
    _segment_source,
    _uniform,
)
from pmabayes.data.sidecar import _read_sidecar, _sidecar_path
from pmabayes.data.units import (
    UNITS,
    converted,
    quantity,
    role_problems,
    signed,
    to_si,
    unknown_unit,
)

__all__ = ["MAT_ROLES", "MAT_TRIALS", "read_mat", "read_mat_segments"]

#: The roles a ``mat_variables`` mapping (or :func:`read_mat`'s keywords) can name.
MAT_ROLES: tuple[str, ...] = ("time_s", *INPUT_NAMES, "position_m")
#: What ``"mat_trials"`` may say about a 2-D variable: one trial per column or per row.
MAT_TRIALS: tuple[str, ...] = ("columns", "rows")

_V73_MAGIC = b"MATLAB 7.3 MAT-file"
_PART = re.compile(r"^(?P<name>[A-Za-z]\w*)(?:\((?P<index>[^()]*)\))?$")
_TRAILING_NUMBER = re.compile(r"(\d+)$")
_NO_H5PY = ("reading a MATLAB v7.3 file needs h5py: pip install h5py (or save the file "
            "in MATLAB with save(..., '-v7') to read it through scipy)")


@dataclass(frozen=True)
class _Opaque:
    """A variable neither reader can decode (a MATLAB object such as a timeseries)."""

    matlab_class: str


# ----------------------------------------------------------------------------- reading


def _is_v73(path: Path) -> bool:
    with path.open("rb") as fh:
        return fh.read(len(_V73_MAGIC)) == _V73_MAGIC


def _load_v5(path: Path, where: str) -> dict[str, Any]:
    import scipy.io

    try:
        raw = scipy.io.loadmat(path, simplify_cells=True)
    except NotImplementedError:  # a v7.3 file without the header text
        return _load_v73(path, where)
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, ...
        raise DataError(
            f"{where}: not a readable MATLAB .mat file ({type(exc).__name__}: {exc}); "
            "save it from MATLAB with save(FILE, ..., '-v7') or '-v7.3'.") from None
    out = {}
    for name, value in raw.items():
        if name.startswith("__"):
            continue
        out[name] = _simplify_v5(value)
    return out


def _simplify_v5(value: Any) -> Any:
    """scipy's opaque MATLAB objects as :class:`_Opaque`; everything else as loaded."""
    import scipy.io.matlab as sm

    opaque = getattr(sm, "MatlabOpaque", None)
    if opaque is not None and isinstance(value, opaque):
        return _Opaque("object")
    if isinstance(value, dict):
        return {k: _simplify_v5(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_simplify_v5(v) for v in value]
    if isinstance(value, np.ndarray) and value.dtype == object:
        return [_simplify_v5(v) for v in value.ravel(order="F")]
    return value


def _load_v73(path: Path, where: str) -> dict[str, Any]:
    try:
        import h5py
    except ImportError:
        raise DataError(f"{where}: this is a MATLAB v7.3 (HDF5) file; {_NO_H5PY}.") from None
    try:
        fh = h5py.File(path, "r")
    except OSError as exc:
        raise DataError(
            f"{where}: has a MATLAB v7.3 header but is not a readable HDF5 file ({exc}); "
            "save it again from MATLAB.") from None
    with fh:
        return {name: _h5_value(fh[name], fh) for name in fh if not name.startswith("#")}


def _h5_class(obj: Any) -> str | None:
    cls = obj.attrs.get("MATLAB_class")
    if cls is None:
        return None
    return cls.decode("ascii") if isinstance(cls, bytes) else str(cls)


def _h5_value(obj: Any, fh: Any) -> Any:
    """A v7.3 variable in the form scipy's ``simplify_cells`` gives a v5 one."""
    import h5py

    cls = _h5_class(obj)
    if isinstance(obj, h5py.Group):
        if cls not in (None, "struct"):
            return _Opaque(cls)
        fields = {k: obj[k] for k in obj if not k.startswith("#")}
        # a struct array stores each field as an array of references without a class
        refs = [f for f in fields.values() if isinstance(f, h5py.Dataset)
                and f.dtype == h5py.ref_dtype and _h5_class(f) is None]
        if fields and len(refs) == len(fields):
            n = refs[0].size
            columns = {k: [_h5_value(fh[r], fh) for r in f[()].T.ravel()]
                       for k, f in fields.items()}
            items = [{k: columns[k][i] for k in fields} for i in range(n)]
            return items[0] if n == 1 else items
        return {k: _h5_value(f, fh) for k, f in fields.items()}
    if "MATLAB_object_decode" in obj.attrs:
        return _Opaque(cls or "object")
    if obj.attrs.get("MATLAB_empty", 0):
        return np.zeros(0)
    data = obj[()]
    if cls == "cell" or obj.dtype == h5py.ref_dtype:
        items = [_h5_value(fh[r], fh) for r in np.asarray(data).T.ravel()]
        return items[0] if len(items) == 1 else items
    if cls == "char":
        return "".join(map(chr, np.asarray(data).T.ravel()))
    if data.dtype.names and {"real", "imag"} <= set(data.dtype.names):
        data = data["real"] + 1j * data["imag"]
    if cls == "logical":
        data = np.asarray(data, dtype=bool)
    # MATLAB writes column-major arrays, so HDF5 sees them transposed
    data = np.asarray(data).T
    return data.item() if data.size == 1 else np.squeeze(data)


def _variables(path: Path, where: str) -> tuple[dict[str, Any], str]:
    """The file's top-level variables, and which MATLAB format held them."""
    if not path.exists():
        raise DataError(f"{where}: file not found; check the path.")
    if not path.is_file():
        raise DataError(f"{where}: not a regular file; give the path of a .mat file.")
    if _is_v73(path):
        return _load_v73(path, where), "v7.3"
    return _load_v5(path, where), "v5"


# ----------------------------------------------------------------------------- mapping


def _check_names(value: Any, role: str, declared: str) -> str | list[str]:
    ok = isinstance(value, str) and value.strip() or (
        isinstance(value, list) and value and all(isinstance(v, str) and v for v in value))
    if not ok or (role == "time_s" and not isinstance(value, str)):
        shape = ("a variable name" if role == "time_s"
                 else "a variable name, a pattern such as \"x_*\", or a list of names")
        raise DataError(f"{declared}: {role} is {value!r}; it must be {shape}.")
    return value


def _mapping(metadata: dict, given: dict[str, Any], declare: str, where: str
             ) -> tuple[dict[str, Any], dict[str, str]]:
    """The role -> variable mapping from the sidecar's ``mat_variables`` and keywords,
    and the role -> name (with its unit: ``pressure_psi``) the variable was mapped as."""
    from_sidecar = metadata.get("mat_variables", {})
    if not isinstance(from_sidecar, dict):
        raise DataError(
            f"{declare}: 'mat_variables' is {from_sidecar!r}; it must be an object mapping "
            f'roles to variable names, e.g. {{"time_s": "t", "pressure_pa": "p", '
            f'"position_m": "x"}}.')
    for key in from_sidecar:
        if key not in UNITS:
            if isinstance(key, str) and quantity(key):
                raise DataError(f"{declare}: 'mat_variables': {unknown_unit(key)}.")
            close = difflib.get_close_matches(str(key), MAT_ROLES, n=1, cutoff=0.5)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise DataError(
                f"{declare}: 'mat_variables' has the key {key!r}{hint}; the roles are "
                f"{', '.join(MAT_ROLES)} (the name carries the unit of the values: "
                "time_ms, pressure_psi, position_mm, ... are converted to SI).")
    problems = role_problems(list(from_sidecar))
    if problems:
        raise DataError(f"{declare}: 'mat_variables': " + "; ".join(problems) + ".")
    names = {role: role for role in MAT_ROLES}
    sidecar_roles = {}
    for key, value in from_sidecar.items():
        sidecar_roles[UNITS[key][0]] = value
        names[UNITS[key][0]] = key
    from_sidecar = sidecar_roles
    mapping = {}
    for role in MAT_ROLES:
        a, b = from_sidecar.get(role), given.get(role)
        if a is not None and b is not None and a != b:
            raise DataError(
                f"{where}: {role} is mapped to {a!r} in {declare} but to {b!r} by the "
                f"keyword {role}=; give it in one place.")
        value = b if b is not None else a
        if value is not None:
            mapping[role] = _check_names(value, role, declare if b is None else
                                         f"{where}: keyword {role}=")
    inputs = [r for r in INPUT_NAMES if r in mapping]
    if len(inputs) > 1:
        raise DataError(
            f"{where}: both pressure_pa and force_n are mapped (in {declare} or by keyword); "
            "map exactly one input.")
    return mapping, names


def _natural_key(name: str) -> tuple[str, int]:
    m = _TRAILING_NUMBER.search(name)
    return (name[: m.start()], int(m.group(1))) if m else (name, -1)


def _expand(spec: str | list[str], names: Sequence[str]) -> list[str]:
    """A list of names, with a pattern expanded (sorted by trailing number) in its place."""
    out = []
    for item in [spec] if isinstance(spec, str) else spec:
        if any(c in item for c in "*?["):
            out.extend(sorted(fnmatch.filter(names, item), key=_natural_key) or [item])
        else:
            out.append(item)
    return out


def _listing(variables: dict[str, Any]) -> str:
    if not variables:
        return "the file holds no variables"
    shown = []
    for name, value in list(variables.items())[:20]:
        if isinstance(value, np.ndarray):
            what = f"{'x'.join(map(str, value.shape)) or 'scalar'} {value.dtype}"
        elif isinstance(value, dict):
            what = "struct (" + ", ".join(list(value)[:6]) + ")"
        elif isinstance(value, _Opaque):
            what = f"MATLAB object {value.matlab_class}"
        else:
            what = type(value).__name__
        shown.append(f"{name} [{what}]")
    more = ", ..." if len(variables) > 20 else ""
    return "the file holds " + ", ".join(shown) + more


def _resolve(spec: str, variables: dict[str, Any], role: str, where: str) -> Any:
    """The value a name such as ``"S.signals(2).values(:,1)"`` points to."""
    value: Any = variables
    walked = ""
    for part in spec.split("."):
        m = _PART.match(part.strip())
        if m is None:
            raise DataError(
                f"{where}: {role} = {spec!r}: cannot read {part!r}; write a MATLAB name, "
                "optionally with a 1-based index: name, name(2), name(:,2), name(2,:).")
        name, index = m.group("name"), m.group("index")
        if not isinstance(value, dict) or name not in value:
            if walked:
                fields = list(value) if isinstance(value, dict) else []
                raise DataError(
                    f"{where}: {role} = {spec!r}: {walked} has no field {name!r} (its fields: "
                    f"{', '.join(fields) or 'none, it is not a struct'}); fix the name.")
            close = difflib.get_close_matches(name, list(variables), n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise DataError(
                f"{where}: {role}: no variable {name!r} in the file{hint}; "
                f"{_listing(variables)}. Map {role} to one of them (\"mat_variables\" in the "
                "sidecar, or the keyword).")
        value = value[name]
        walked = f"{walked}.{name}" if walked else name
        if index is not None:
            value = _index(value, index.replace(" ", ""), f"{walked}({index})", spec, role,
                           where)
            walked = f"{walked}({index})"
    if isinstance(value, _Opaque):
        raise DataError(
            f"{where}: {role}: variable {walked!r} is a MATLAB object ({value.matlab_class}, "
            "e.g. a timeseries or Simulink.SimulationData.Dataset), which cannot be read "
            "outside MATLAB; save its data as plain arrays (x = ts.Data; t = ts.Time) or set "
            "the To Workspace block's save format to 'Array' or 'Structure With Time'.")
    return value


def _index(value: Any, index: str, what: str, spec: str, role: str, where: str) -> Any:
    if isinstance(value, list) and index.isdigit():
        i = int(index)
        if not 1 <= i <= len(value):
            raise DataError(f"{where}: {role} = {spec!r}: {what} is out of range, it has "
                            f"{len(value)} elements (1-based).")
        return value[i - 1]
    if isinstance(value, dict) and index == "1":
        return value
    a = np.asarray(value) if not isinstance(value, dict | list) else None
    col = re.fullmatch(r":,(\d+)", index)
    row = re.fullmatch(r"(\d+),:", index)
    if a is not None and a.ndim == 2 and (col or row):
        axis, i = (1, int(col.group(1))) if col else (0, int(row.group(1)))
        if not 1 <= i <= a.shape[axis]:
            raise DataError(f"{where}: {role} = {spec!r}: {what} is out of range for a "
                            f"{a.shape[0]}x{a.shape[1]} array (1-based).")
        return a[:, i - 1] if col else a[i - 1, :]
    raise DataError(
        f"{where}: {role} = {spec!r}: cannot index {what}; use name(i) for an element of a "
        "struct or cell array, name(:,j) for a column, name(j,:) for a row (1-based).")


@dataclass
class _Signal:
    """One mapped variable: its values, its own time if stored with it, and layout."""

    name: str
    values: np.ndarray
    time: np.ndarray | None
    time_rows: bool  # a Simulink structure: time runs along the rows


def _signal(spec: str, variables: dict[str, Any], role: str, where: str) -> _Signal:
    value = _resolve(spec, variables, role, where)
    time = None
    time_rows = False
    if isinstance(value, dict) and "signals" in value:  # Simulink "Structure (with time)"
        signals = value["signals"]
        if isinstance(signals, list):
            raise DataError(
                f"{where}: {role}: {spec!r} is a Simulink structure with {len(signals)} "
                f"signals; name one, e.g. '{spec}.signals(1).values', and map time_s to "
                f"'{spec}.time'.")
        if not isinstance(signals, dict) or "values" not in signals:
            raise DataError(f"{where}: {role}: {spec!r}.signals has no 'values' field; map "
                            f"{role} to the variable that holds the samples.")
        t = value.get("time")
        if t is not None and np.size(t) > 0:
            time = np.asarray(t)
        value = signals["values"]
        time_rows = True
    if isinstance(value, dict | list | str) or np.asarray(value).dtype.kind not in "iuf":
        kind = (type(value).__name__ if isinstance(value, dict | list | str)
                else f"{np.asarray(value).dtype} array")
        kind = {"dict": "struct", "list": "cell or struct array", "str": "text"}.get(kind, kind)
        raise DataError(
            f"{where}: {role}: {spec!r} holds a {kind}, not real numbers; map {role} to a "
            "numeric array (a struct's field: 'name.field').")
    a = np.asarray(value)
    if a.ndim == 3:  # a Simulink signal of a 1x1 matrix over time: 1 x 1 x N
        a = np.squeeze(a)
    if a.ndim not in (1, 2) or a.size < 2:
        raise DataError(
            f"{where}: {role}: {spec!r} has shape {'x'.join(map(str, a.shape)) or 'scalar'}; "
            "accepted are a vector (1xN or Nx1: one trial) and a 2-D array of trials "
            "(N x n_trials or n_trials x N, as \"mat_trials\" says).")
    return _Signal(spec, a, time, time_rows)


# ----------------------------------------------------------------------------- layout


def _n_samples_hint(signals: list[_Signal], time: np.ndarray | None) -> int | None:
    if time is not None:
        return time.size
    for s in signals:
        if s.time is not None:
            return s.time.size
    for s in signals:
        if s.values.ndim == 1:
            return s.values.size
    return None


def _trials(s: _Signal, role: str, layout: str | None, n: int | None, where: str,
            ) -> tuple[np.ndarray, list[str]]:
    """The signal as ``(n_trials, n_samples)``, and a MATLAB description of each trial."""
    a = s.values
    if a.ndim == 1:
        return a[np.newaxis, :], [s.name]
    rows, cols = a.shape
    if s.time_rows:
        layout = "columns"
    if layout is None and n is not None and (rows == n) != (cols == n):
        layout = "columns" if rows == n else "rows"
    if layout is None:
        why = (f"both of its dimensions are {n}, the number of samples" if n is not None
               and rows == cols == n else
               f"neither dimension matches the record's {n} samples" if n is not None
               else "no time vector or 1-D variable fixes the number of samples")
        raise DataError(
            f"{where}: {role}: {s.name!r} is {rows}x{cols} and {why}; declare the layout: "
            '"mat_trials": "columns" (N samples x n_trials, MATLAB\'s usual) or "rows" '
            "(n_trials x N) in the sidecar, or the keyword mat_trials=.")
    if layout == "columns":
        return a.T, [f"{s.name}(:,{j + 1})" for j in range(cols)]
    return a, [f"{s.name}({j + 1},:)" for j in range(rows)]


def _stack(signals: list[_Signal], role: str, layout: str | None, n: int | None,
           where: str) -> tuple[np.ndarray, list[str]]:
    blocks, labels = [], []
    for s in signals:
        block, names = _trials(s, role, layout, n, where)
        blocks.append(block)
        labels.extend(names)
    lengths = {b.shape[1] for b in blocks}
    if n is not None and lengths != {n} or len(lengths) > 1:
        listed = ", ".join(f"{lab}: {b.shape[1]}" for b, lab in
                           zip(blocks, [s.name for s in signals], strict=True))
        ref = f"not the record's {n}" if n is not None else "not one length"
        turned = [(s, b) for s, b in zip(signals, blocks, strict=True)
                  if s.values.ndim == 2 and b.shape[0] == n]
        if turned:  # its trials run along the other axis
            s, b = turned[0]
            other = "rows" if s.values.shape[1] == n else "columns"
            raise DataError(
                f"{where}: {role}: {s.name!r} is {s.values.shape[0]}x{s.values.shape[1]}, "
                f"read as {b.shape[0]} trials of {b.shape[1]} samples, but the record has "
                f"{n} samples: its trials run along the other axis. Declare "
                f'"mat_trials": "{other}" in the sidecar (or the keyword '
                f'mat_trials="{other}").')
        raise DataError(
            f"{where}: {role}: samples per trial are {listed}, {ref}; every trial needs "
            "one sample per time step: trim the records to a common length.")
    return np.concatenate(blocks, axis=0), labels


def _trial_ids(signals: list[_Signal], n_trials: int) -> np.ndarray:
    """Numbers at the end of per-trial variable names, when distinct; else 1, 2, ..."""
    if len(signals) == n_trials and len(signals) > 1:
        numbers = [_TRAILING_NUMBER.search(s.name) for s in signals]
        if all(numbers) and len({int(m.group(1)) for m in numbers}) == n_trials:
            return np.array([int(m.group(1)) for m in numbers], dtype=np.int64)
    return np.arange(1, n_trials + 1, dtype=np.int64)


def _check_finite(a: np.ndarray, labels: list[str], role: str, where: str) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        k, j = np.unravel_index(int(np.argmax(bad)), a.shape)
        raise DataError(
            f"{where}: {role}: {labels[k]} is {a[k, j]} at sample {j + 1} (MATLAB's 1-based "
            "index); missing or saturated samples must be handled before import (nothing "
            "is dropped or filled in automatically).")


# ----------------------------------------------------------------------------- entry point


def read_mat(
    path: str | os.PathLike[str],
    *,
    time_s: str | None = None,
    pressure_pa: str | list[str] | None = None,
    force_n: str | list[str] | None = None,
    position_m: str | list[str] | None = None,
    mat_trials: str | None = None,
    check_units: bool = True,
) -> Dataset:
    """Read a MATLAB ``.mat`` file (v4 to v7 through scipy, v7.3 through h5py).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mat`` file. A JSON sidecar with the same stem (``foo.json``) is read
        as the metadata, as for CSV; its ``"mat_variables"`` and ``"mat_trials"``
        say which variable is what (see the module docstring).
    time_s : str, optional
        Variable of sample times in s (a vector). Without it: the time of a Simulink
        structure, else the sidecar's ``sample_rate_hz`` (times ``k / rate`` from 0).
    pressure_pa, force_n : str or list of str, optional
        Variable(s) of the input, commanded gauge pressure in Pa or force in N (give
        at most one of the two): a name, a pattern (``"p_*"``) or a list of names.
    position_m : str or list of str, optional
        Variable(s) of the measured position in m, as for the input.
    mat_trials : {"columns", "rows"}, optional
        Layout of 2-D variables: one trial per column (``N x n_trials``) or per row.
        Needed only when the number of samples does not settle it.
    check_units : bool, optional
        The unit plausibility checks of :func:`pmabayes.data.read_csv`. Default True.

    Returns
    -------
    Dataset
        The validated data, with ``source`` set to ``str(path)`` and the sidecar as
        its metadata.

    Raises
    ------
    DataError
        If the file cannot be read, a mapped variable is missing (the message lists
        the file's variables), has a shape that is not accepted (the message says
        which are, and a transposed one which ``"mat_trials"`` reads it), holds
        non-numbers or non-finite values, or the data fail the checks every format
        shares (a time vector with gaps is read as for CSV: see
        :func:`pmabayes.data.read_csv`). Messages name the file, the variable and
        the fix.

    Warns
    -----
    DataWarning
        As :func:`pmabayes.data.read_csv` (units converted, the clock's jitter and
        gaps, pressure that looks absolute or offset), and when a single-precision
        time vector is rebuilt as a uniform grid.
    """
    return _mat_datasets(path, dict(time_s=time_s, pressure_pa=pressure_pa, force_n=force_n,
                                    position_m=position_m), mat_trials, check_units, False)[0]


def read_mat_segments(path: str | os.PathLike[str], **kwargs: Any) -> list[Dataset]:
    """Read a MATLAB ``.mat`` file as its segments (see :func:`pmabayes.data.load_segments`).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mat`` file, with its optional JSON sidecar.
    **kwargs
        The keywords of :func:`read_mat` (``time_s``, ``pressure_pa``, ``force_n``,
        ``position_m``, ``mat_trials``, ``check_units``).

    Returns
    -------
    list of Dataset
        One per segment between gaps longer than the sidecar's ``"max_gap_s"``.

    Raises
    ------
    TypeError
        For a keyword :func:`read_mat` does not take.
    DataError
        As :func:`read_mat`.
    """
    given = {role: kwargs.pop(role, None) for role in MAT_ROLES}
    mat_trials, check_units = kwargs.pop("mat_trials", None), kwargs.pop("check_units", True)
    if kwargs:
        raise TypeError(f"read_mat_segments got unexpected keyword(s) {sorted(kwargs)}")
    return _mat_datasets(path, given, mat_trials, check_units, True)


def _mat_datasets(path: str | os.PathLike[str], given: dict[str, Any], mat_trials: str | None,
                  check_units: bool, split: bool) -> list[Dataset]:
    """The body of :func:`read_mat` and :func:`read_mat_segments`."""
    path = Path(path)
    where = str(path)
    sidecar = _sidecar_path(path)
    metadata: dict = _read_sidecar(sidecar) if sidecar.is_file() else {}
    declare = f"the JSON sidecar {sidecar}"
    _check_declarations(metadata, declare)  # a misspelt key before it misleads the mapping
    text_only = [k for k in ("columns", "columns_from", "calibration") if k in metadata]
    if text_only:
        raise DataError(
            f"{declare}: {', '.join(repr(k) for k in text_only)} read the columns of a text "
            "file, and a .mat file has variables: name them with \"mat_variables\" (their "
            "values in the units the variables' names say, or SI), and remove "
            f"{', '.join(repr(k) for k in text_only)}.")
    variables, version = _variables(path, where)
    where_v = f"{where} (MATLAB {version})"

    mapping, names_as = _mapping(metadata, given, declare, where_v)
    for role, default in (("time_s", "time_s"), ("position_m", "position_m")):
        if role not in mapping and default in variables:
            mapping[role] = default
    if not any(r in mapping for r in INPUT_NAMES):
        present = [r for r in INPUT_NAMES if r in variables]
        if len(present) == 1:
            mapping[present[0]] = present[0]
    missing = [r for r in ("position_m",) if r not in mapping]
    if not any(r in mapping for r in INPUT_NAMES):
        missing.insert(0, "pressure_pa (or force_n)")
    if missing:
        raise DataError(
            f"{where_v}: no variable is mapped to {' and '.join(missing)}; "
            f"{_listing(variables)}. Map them in {declare}, e.g. \"mat_variables\": "
            '{"time_s": "t", "pressure_pa": "p", "position_m": "x"}, or by keyword '
            "(read_mat(path, pressure_pa=..., position_m=...)).")
    layout = mat_trials if mat_trials is not None else metadata.get("mat_trials")
    if mat_trials is not None and "mat_trials" in metadata and metadata["mat_trials"] != layout:
        raise DataError(f"{where_v}: mat_trials is {metadata['mat_trials']!r} in {declare} "
                        f"but {mat_trials!r} by keyword; give it in one place.")
    if layout is not None and layout not in MAT_TRIALS:
        raise DataError(
            f"{where_v}: mat_trials is {layout!r}; it must be \"columns\" (one trial per "
            "column, N x n_trials) or \"rows\" (one trial per row).")

    names = list(variables)
    input_name = next(r for r in INPUT_NAMES if r in mapping)
    inputs = [_signal(s, variables, input_name, where_v)
              for s in _expand(mapping[input_name], names)]
    positions = [_signal(s, variables, "position_m", where_v)
                 for s in _expand(mapping["position_m"], names)]

    time, time_name, time_stored = None, None, None
    if "time_s" in mapping:
        time_name = mapping["time_s"]
        sig = _signal(time_name, variables, "time_s", where_v)
        t = sig.values
        if sig.time_rows:  # a Simulink structure: its time, not its values
            if sig.time is None:
                raise DataError(
                    f"{where_v}: time_s: {time_name!r} is a Simulink structure saved without "
                    "time ('Structure', not 'Structure With Time'); map time_s to a time "
                    "vector, or remove it and give sample_rate_hz in the sidecar.")
            t, time_name = np.squeeze(sig.time), f"{time_name}.time"
        if t.ndim != 1:
            raise DataError(
                f"{where_v}: time_s: {time_name!r} is {t.shape[0]}x{t.shape[1]}; it must be "
                "one vector (1xN or Nx1) shared by all trials; save one time vector.")
        time, time_stored = t.astype(float), t.dtype
    for s in inputs + positions:
        if s.time is None:
            continue
        if time is None:
            time, time_name, time_stored = s.time.astype(float).ravel(), f"{s.name}.time", \
                s.time.dtype
        else:
            _same_time(time, time_name, s, where_v)

    n = _n_samples_hint(inputs + positions, time)
    u, u_labels = _stack(inputs, input_name, layout, n, where_v)
    x, x_labels = _stack(positions, "position_m", layout, n, where_v)
    if u.shape[1] != x.shape[1]:
        raise DataError(
            f"{where_v}: the input has {u.shape[1]} samples per trial but position_m has "
            f"{x.shape[1]}; map variables of the same record, or trim them to one length.")
    if u.shape[0] == 1 and x.shape[0] > 1:
        u = np.repeat(u, x.shape[0], axis=0)  # one command for every trial
        u_labels = u_labels * x.shape[0]
    elif u.shape[0] != x.shape[0]:
        raise DataError(
            f"{where_v}: {u.shape[0]} trials of {input_name} ({', '.join(u_labels[:6])}) "
            f"but {x.shape[0]} of position_m ({', '.join(x_labels[:6])}); map one input "
            "per position trial, or one input shared by all.")
    _check_pairs(inputs, positions, input_name, where_v)
    _check_finite(u, u_labels, input_name, where_v)
    _check_finite(x, x_labels, "position_m", where_v)

    u = to_si(u, names_as[input_name])
    x = signed(to_si(x, names_as["position_m"]), metadata, declare)
    metadata = converted({r: names_as[r] for r in (input_name, "position_m", *(
        ["time_s"] if time is not None else []))}, where_v, metadata, declare)
    n_samples = x.shape[1]
    if time is None:
        rate = metadata.get("sample_rate_hz")
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
            raise DataError(
                f"{where_v}: no time: no variable is mapped to time_s and "
                f"{declare if metadata else 'no sidecar'} gives no positive "
                f"'sample_rate_hz'{f' (it has {rate!r})' if rate is not None else ''}; map "
                f"time_s to the time vector ({_listing(variables)}), or add "
                f"\"sample_rate_hz\" to {declare}.")
        time = np.arange(n_samples) / float(rate)
        time_name = f"sample_rate_hz = {rate:g} in {declare}"
    else:
        step = float(np.spacing(np.float32(np.abs(time).max())))
        time = to_si(time, names_as["time_s"])
        if time_stored is not None and time_stored == np.float32:
            time = _rounded_grid(
                np.zeros(time.size, dtype=np.int64), time,
                lambda: step * UNITS[names_as["time_s"]][1], _positive_rate(metadata),
                f"{where_v}: variable {time_name!r}",
                "is stored in single precision, with a resolution of",
                "Save the time in double precision (or drop it and give sample_rate_hz) "
                "to make this exact.")
    if time.size != n_samples:
        raise DataError(
            f"{where_v}: time_s ({time_name}) has {time.size} samples but the trials have "
            f"{n_samples}; map the time vector of the same record.")
    columns = {r: names_as[r] for r in ("position_m", input_name)}
    if "sample_rate_hz" not in time_name:
        columns["time_s"] = names_as["time_s"]
    ids = _trial_ids(positions, x.shape[0])
    source = f"{where_v}: time_s ({time_name})"
    if _uniform(np.zeros(time.size, dtype=np.int64), time):
        check_time_grid(time, source=source, locate=lambda j: f"sample {j + 1}")
        ds = Dataset(time_s=time, input=u, position_m=x, trial_ids=ids, input_name=input_name,
                     metadata=metadata, source=where)
        return [_checked(
            ds, where_v,
            lambda k, j: f"{x_labels[k]}, trial {int(ids[k])}, sample {j + 1}",
            declare, check_units, columns)]

    def locate(j: int) -> str:
        return f"sample {j + 1}"

    segments = _clocked(np.zeros(time.size, dtype=np.int64), time, metadata, where=where_v,
                        split=split, label=lambda b: source, locate=locate, declare=declare)
    out = []
    for i, seg in enumerate(segments, start=1):
        shape = (x.shape[0], seg.n_samples)
        arrays = [np.full(shape, np.nan) for _ in range(2)]
        for a, values in zip(arrays, (u, x), strict=True):
            a[:, seg.index] = values[:, seg.rows]
        observed = np.zeros(shape, dtype=bool)
        observed[:, seg.index] = True
        seg_meta = _segment_metadata(metadata, seg, i, len(segments), path, locate)
        _check_estimate(seg_meta, seg, time, lambda b: source, locate)
        ds = Dataset(time_s=seg.time_s, input=arrays[0], position_m=arrays[1], trial_ids=ids,
                     input_name=input_name, metadata=seg_meta,
                     source=_segment_source(path, i, len(segments)), observed=observed)
        at = np.full(seg.n_samples, -1)
        at[seg.index] = seg.rows
        out.append(_checked(
            ds, where_v,
            lambda k, j, at=at: f"{x_labels[k]}, trial {int(ids[k])}, "
            + (f"sample {at[j] + 1}" if at[j] >= 0 else f"grid sample {j + 1}, not observed"),
            declare, check_units, columns))
    return out


def _same_time(time: np.ndarray, name: str, s: _Signal, where: str) -> None:
    t = s.time.astype(float).ravel()
    dt = abs(float(time[1] - time[0])) if time.size > 1 else 1.0
    if t.size != time.size or np.abs(t - time).max() > _REL_TOL * dt:
        raise DataError(
            f"{where}: {s.name}.time differs from {name} (both are sample times of the "
            "data); map variables of one record, all sampled on the same clock.")


def _check_pairs(inputs: list[_Signal], positions: list[_Signal], input_name: str,
                 where: str) -> None:
    """Per-trial input and position variables pair by order: their numbers must agree."""
    if len(inputs) != len(positions) or len(inputs) < 2:
        return
    a = [_TRAILING_NUMBER.search(s.name) for s in inputs]
    b = [_TRAILING_NUMBER.search(s.name) for s in positions]
    if all(a) and all(b) and [m.group(1) for m in a] != [m.group(1) for m in b]:
        pairs = ", ".join(f"{i.name}/{p.name}" for i, p in zip(inputs, positions, strict=True)
                          if _natural_key(i.name)[1] != _natural_key(p.name)[1])
        raise DataError(
            f"{where}: {input_name} and position_m variables pair up in order, but their "
            f"numbers differ: {pairs}; map the same trials for both (list them in matching "
            "order).")
