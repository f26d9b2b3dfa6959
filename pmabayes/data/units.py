"""Units in column names: ``pressure_psi``, ``position_mm``, ``time_ms`` ... read and
converted to the SI the package holds (``pressure_pa``, ``position_m``, ``time_s``,
``force_n``), each conversion said once and recorded in the metadata.

A column (a CSV header's name, a sidecar ``"columns"`` entry, a ``"mat_variables"``
role) is named ``<quantity>_<unit>``; :data:`UNITS` lists every name pmabayes reads.
A name whose quantity pmabayes reads but whose unit it does not know is refused with
the known units and the near match (``position_cm``: multiply by 10 and name the
column ``position_mm``). A CSV header may write the unit as people do:
``Pressure (psi)``, ``Position [mm]``, ``Time (s)``, ``Force [kN]``, ``TIME_MS`` (case
and spaces free) are read as ``pressure_psi``, ``position_mm``, ... (:func:`header_name`).
"""

from __future__ import annotations

import difflib
import re
from pathlib import Path

import numpy as np

from pmabayes.data.dataset import DataError, DataWarning, _fmt
from pmabayes.data.sidecar import say_once

#: warnings point at the caller's line, outside the data package
_HERE = (str(Path(__file__).parent),)

__all__ = ["UNITS"]

#: 1 psi in Pa: a pound-force (0.45359237 kg x 9.80665 m/s^2) over a square inch
_PSI_PA = 0.45359237 * 9.80665 / 0.0254 ** 2

#: Every column name pmabayes reads, to the SI name it becomes and the factor that
#: converts it (SI value = value x factor). Conversions by a power of ten below 1
#: divide by its inverse, so that 1.5 mm is exactly 1.5 / 1000 m.
#:
#: :meta hide-value:
UNITS: dict[str, tuple[str, float]] = {
    "time_s": ("time_s", 1.0),
    "time_ms": ("time_s", 1e-3),
    "time_us": ("time_s", 1e-6),
    "pressure_pa": ("pressure_pa", 1.0),
    "pressure_kpa": ("pressure_pa", 1e3),
    "pressure_bar": ("pressure_pa", 1e5),
    "pressure_psi": ("pressure_pa", _PSI_PA),
    "pressure_mpa": ("pressure_pa", 1e6),
    "position_m": ("position_m", 1.0),
    "position_mm": ("position_m", 1e-3),
    "position_um": ("position_m", 1e-6),
    "force_n": ("force_n", 1.0),
    "force_kn": ("force_n", 1e3),
}
_DIVISORS = {1e-3: 1e3, 1e-6: 1e6}
#: units named in messages the way people write them
_SYMBOL = {"s": "s", "ms": "ms", "us": "µs", "pa": "Pa", "kpa": "kPa", "bar": "bar",
           "psi": "psi", "mpa": "MPa", "m": "m", "mm": "mm", "um": "µm", "n": "N", "kn": "kN"}
#: what a unit pmabayes does not read comes to, and how to get there
_ADVICE = {
    "position_cm": "centimetres: multiply by 10 and name the column position_mm",
    "position_in": "inches: multiply by 25.4 and name the column position_mm",
    "time_min": "minutes: multiply by 60 and name the column time_s",
    "pressure_atm": "atmospheres: multiply by 101.325 and name the column pressure_kpa",
    "force_lbf": "pounds-force: multiply by 4.4482216152605 and name the column force_n",
    "pressure_psia": "absolute psi: name the column pressure_psi and declare "
                     "\"pressure_reference\": \"absolute\" in the sidecar",
    "pressure_bara": "absolute bar: name the column pressure_bar and declare "
                     "\"pressure_reference\": \"absolute\" in the sidecar",
}
#: units of a sensor's raw output: the quantity needs the sensor's calibration
_SIGNAL_UNITS = frozenset({"v", "mv", "volt", "volts", "ma", "counts", "count", "bits"})
#: a unit as a header may spell it out, to the name :data:`UNITS` gives it (gauge
#: pressures are what pmabayes reads: ``psig`` and ``barg`` are ``psi`` and ``bar``)
_UNIT_WORDS = {
    "sec": "s", "secs": "s", "second": "s", "seconds": "s",
    "msec": "ms", "millisecond": "ms", "milliseconds": "ms",
    "usec": "us", "microsecond": "us", "microseconds": "us",
    "pascal": "pa", "pascals": "pa", "psig": "psi", "barg": "bar", "kpag": "kpa",
    "meter": "m", "meters": "m", "metre": "m", "metres": "m",
    "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
    "micrometer": "um", "micrometers": "um", "micrometre": "um", "micrometres": "um",
    "micron": "um", "microns": "um",
    "newton": "n", "newtons": "n", "kilonewton": "kn", "kilonewtons": "kn",
}


def quantity(name: str) -> str | None:
    """``"pressure"`` for ``pressure_psi``: the quantity of a column name pmabayes knows
    the quantity of (time, pressure, position, force), else None."""
    head = name.split("_", 1)[0]
    return head if head in {n.split("_")[0] for n in UNITS} and "_" in name else None


#: a header's quantity and unit as people write them: ``Pressure (psi)``,
#: ``Position [mm]``, ``time_ms``, ``Time s``, ``Time/s`` (ISO 80000's quantity over its
#: unit), and a pressure's ``(kPa gauge)``
_HEADER = re.compile(r"([a-z]+)\s*(?:\(\s*([a-z]+)(?:[\s,]+gauge)?\s*\)"
                     r"|\[\s*([a-z]+)(?:[\s,]+gauge)?\s*\]|[_\s]+([a-z]+)|\s*/\s*([a-z]+))")
#: the same with words before the quantity, where the unit is bracketed or after a slash
#: (``Motor force (N)``, ``Measured displacement [mm]``): the last word is the quantity
_HEADER_WORDS = re.compile(r"(?:[a-z]+[\s_-]+)+([a-z]+)\s*(?:\(\s*([a-z]+)(?:[\s,]+gauge)?"
                           r"\s*\)|\[\s*([a-z]+)(?:[\s,]+gauge)?\s*\]|\s*/\s*([a-z]+))")
#: a quantity as a header may name it, to the name :data:`UNITS` gives it
_QUANTITY_WORDS = {"displacement": "position"}


def header_name(text: str) -> str | None:
    """The column name a CSV header's text stands for, as :data:`UNITS` spells it.

    ``Pressure (psi)`` -> ``pressure_psi``, ``Position [mm]`` -> ``position_mm``,
    ``Time (s)`` -> ``time_s``, ``TIME_MS`` -> ``time_ms``, ``Time/s`` -> ``time_s``,
    ``Trial`` -> ``trial``: case and spaces free, the unit after an underscore, a space
    or a slash, or in ``()`` or ``[]`` (``µm`` is ``um``; a unit spelt out, ``sec``,
    ``seconds``, ``millimetres``, ``psig``, is its symbol). Words before the quantity
    are passed over where the unit is bracketed (``Motor force (N)`` -> ``force_n``),
    and ``Displacement`` is the position. The result may name a unit pmabayes does not
    read (``pressure_atm``: :func:`quantity` and :func:`unknown_unit` say so) or a
    quantity it does not know (``stroke_mm``).

    Parameters
    ----------
    text : str
        A header field.

    Returns
    -------
    str or None
        ``quantity_unit`` or ``trial``; None for text of another shape.
    """
    t = text.strip().lower().replace("\u00b5", "u").replace("\u03bc", "u")
    if t == "trial":
        return t
    m = _HEADER.fullmatch(t) or _HEADER_WORDS.fullmatch(t)
    if m is None:
        return None
    unit = next(u for u in m.groups()[1:] if u)
    return f"{_QUANTITY_WORDS.get(m.group(1), m.group(1))}_{_UNIT_WORDS.get(unit, unit)}"


def unit_guess(text: str, roles: list[str]) -> str | None:
    """The name pmabayes reads that a header not recognised may stand for.

    Parameters
    ----------
    text : str
        The header field.
    roles : list of str
        The SI names the header does not give yet (``position_m``, ...).

    Returns
    -------
    str or None
        By the field's unit where that unit has one quantity among ``roles``
        (``Stroke (mm)`` -> ``position_mm``), else by spelling; None without a
        near match.
    """
    name = header_name(text)
    if name is not None and "_" in name:
        unit = name.split("_", 1)[1]
        by_unit = [n for n in UNITS if n.split("_", 1)[1] == unit and UNITS[n][0] in roles]
        if len(by_unit) == 1:
            return by_unit[0]
    match = difflib.get_close_matches(text.strip().lower(), roles, n=1, cutoff=0.6)
    return match[0] if match else None


def unknown_unit(name: str) -> str:
    """Why ``name`` (a known quantity with an unknown unit) is refused, and the fix."""
    q = quantity(name)
    known = [n for n in UNITS if n.startswith(f"{q}_")]
    advice = _ADVICE.get(name)
    if name.split("_", 1)[1] in _SIGNAL_UNITS:
        to = known[1] if len(known) > 1 else known[0]  # the SI one is rarely a sheet's
        return (f"column {name!r} holds the {q} sensor's raw signal, not the {q}: declare "
                f"the sensor's calibration (value = gain x signal + offset, from its data "
                f"sheet or your own calibration) in the sidecar, \"calibration\": "
                f"{{\"{name}\": {{\"to\": \"{to}\", \"gain\": ..., \"offset\": ...}}}}, to "
                f"read it as one of {', '.join(known)}")
    if advice is None:
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        advice = f"did you mean {close[0]}?" if close else f"convert it to {UNITS[known[0]][0]}"
    else:
        advice = f"if the values are in {advice}"
    return (f"column {name!r}: pmabayes does not know the unit {name.split('_', 1)[1]!r} "
            f"of {q}; it reads {', '.join(known)} ({advice})")


def to_si(values: np.ndarray, name: str) -> np.ndarray:
    """The values of column ``name`` in SI; the same array when it is SI already."""
    factor = UNITS[name][1]
    if factor == 1.0:
        return values
    if factor in _DIVISORS:
        return values / _DIVISORS[factor]
    return values * factor


def from_si(values: np.ndarray, name: str) -> np.ndarray:
    """SI values in the unit of column ``name``: the inverse of :func:`to_si`, for files
    written in the units a user's files use."""
    factor = UNITS[name][1]
    if factor == 1.0:
        return values
    if factor in _DIVISORS:
        return values * _DIVISORS[factor]
    return values / factor


def _said(record: dict[str, dict], headers: dict[str, str] | None = None) -> str:
    """The conversions of a record, for a message: ``pressure_psi (psi) x 6894.757 -> ...``,
    or ``'Pressure (psi)' x 6894.757 -> ...`` where ``headers`` gives the file's own text
    of a column name."""
    headers = headers or {}
    return "; ".join(
        (repr(headers[r["from"]]) if r["from"] in headers else
         f"{r['from']} ({_SYMBOL[r['from'].split('_', 1)[1]]})")
        + f" x {_fmt(r['factor'])} -> {si} "
        f"({_SYMBOL[si.split('_', 1)[1]]})"
        + (" (negated: the sidecar's position_sign is -1)" if r["factor"] < 0 else "")
        for si, r in record.items())


def _record(names: dict[str, str]) -> dict[str, dict]:
    """``{"pressure_pa": {"from": "pressure_psi", "factor": f}}`` for each conversion."""
    return {si: {"from": col, "factor": UNITS[col][1]} for si, col in names.items()
            if col != si}


#: The sidecar key that says which way the file's positions run: 1 (the default: as
#: pmabayes' ``x``, which grows as the pressure pushes) or -1 (the other way, e.g. a
#: sensor whose negative is the muscle's contraction).
POSITION_SIGN_KEY = "position_sign"


def position_sign(metadata: dict, declare: str) -> int:
    """The sidecar's ``"position_sign"`` (1 when not given), checked."""
    sign = metadata.get(POSITION_SIGN_KEY, 1)
    if isinstance(sign, bool) or sign not in (1, -1):
        raise DataError(
            f"{declare}: 'position_sign' is {sign!r}; it must be 1 (the file's positions run "
            "as pmabayes' x, which grows as the pressure or force pushes) or -1 (they run the "
            "other way: pmabayes negates them on reading).")
    return int(sign)


def signed(x: np.ndarray, metadata: dict, declare: str) -> np.ndarray:
    """Positions in SI as pmabayes' ``x`` runs: negated where the sidecar's
    ``"position_sign"`` is -1 (:func:`converted` says so and records it)."""
    return -x if position_sign(metadata, declare) < 0 else x


def converted(names: dict[str, str], where: str, metadata: dict, declare: str,
              headers: dict[str, str] | None = None) -> dict:
    """Warn once for a file's unit conversions; the metadata with their record added.

    ``names`` maps each SI name to the column it was read from; ``headers`` a column
    name to the header's own text where it differs (``Pressure (psi)``). The warning
    is said once per file and conversion in a process (:func:`~pmabayes.data.sidecar.say_once`:
    ``where`` is the file); the record is added at every reading. The record, under
    ``"converted_units"`` (only when something was converted), maps the SI name to
    ``{"from": column, "factor": f}``. A sidecar's ``"position_sign": -1`` (positions
    negated on reading, :func:`signed`) is a factor of -1 in the position's record, and
    the key leaves the metadata: the data set holds positions as pmabayes' ``x`` runs,
    so that a data set written back reads back the same.
    """
    record = _record(names)
    if position_sign(metadata, declare) < 0 and "position_m" in names:
        col = names["position_m"]
        record["position_m"] = {"from": col, "factor": -UNITS[col][1]}
        metadata = {k: v for k, v in metadata.items() if k != POSITION_SIGN_KEY}
    if not record:
        return metadata
    if "converted_units" in metadata:
        raise DataError(
            f"{declare}: 'converted_units' is written by pmabayes when it converts a file's "
            "units, and this file's columns are converted again; remove it.")
    said = _said(record, headers)
    say_once(where, f"units: {said}", DataWarning(
        f"{where}: units converted to SI on reading, as the column names say: "
        f"{said}. The data set holds SI values; its metadata 'converted_units' "
        "records the conversion."), _HERE)
    return {**metadata, "converted_units": record}


def role_problems(names: list[str]) -> list[str]:
    """What is wrong with the quantities of a file's column names: two columns for one
    quantity (``pressure_psi`` and ``pressure_kpa``), or both a pressure and a force."""
    by_si: dict[str, list[str]] = {}
    for n in names:
        if n in UNITS:
            by_si.setdefault(UNITS[n][0], []).append(n)
    problems = [f"{' and '.join(cols)} both give {si}: keep one column for "
                f"{si.split('_')[0]} (leave the other out, or rename it)"
                for si, cols in by_si.items() if len(cols) > 1]
    if "pressure_pa" in by_si and "force_n" in by_si:
        problems.append(f"both {by_si['pressure_pa'][0]} and {by_si['force_n'][0]} are present; "
                        "keep exactly one input column")
    return problems
