"""Plausibility checks on data as read: units, and gauge rather than absolute pressure.

What a file's numbers can show about their units: pressure in MPa or bar, below
vacuum, or looking absolute (the lowest command about one atmosphere) or offset
(far below ambient); position in mm, cm or µm, or no length at all; times in ms or us
read as s (a sample rate, and an input, far slower than a muscle on a rig). Errors for
what cannot be right, :class:`DataWarning` for what looks wrong; each names the unit
the numbers look like and the column name that reads them (:data:`~pmabayes.data.UNITS`).
The metadata declares what the checks cannot know: ``"check_units": false``,
``"sample_rate_hz"`` and ``"pressure_reference"`` (``"gauge"``, or ``"absolute"`` to
convert to gauge on reading).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings
from collections.abc import Callable

import numpy as np

from pmabayes.data.dataset import DataError, Dataset, DataWarning, _first_in_file_order, _fmt
from pmabayes.data.units import UNITS
from pmabayes.data.zero import zeroed_at_start

_VACUUM_PA = -101325.0  # lowest possible gauge pressure (absolute vacuum at 1 atm)
_ATM_PA = 101325.0  # standard atmosphere: the default ambient of "pressure_reference"
# ambient pressure from about 2000 m altitude to sea-level highs: a lowest command in
# this band means the record never vents the muscle, as absolute pressure would show
_AMBIENT_BAND_PA = (80e3, 110e3)
_BELOW_AMBIENT_PA = -20e3  # a muscle vents to 0 gauge; commands far below are an offset
_MPA_BAR_MAX = 20.0  # max |p| at or below which pressure looks like MPa or bar
_MM_MIN = 0.5  # max |x| above which position looks like mm
_MM_MAX = 500.0  # max |x| above which position is not mm either (a PMA strokes < 0.5 m)
_REFERENCES = ("gauge", "absolute")
_STROKE_M = (1e-4, 0.2)  # a muscle's plausible motion (max - min position), m
#: what position values too large for m may be: unit, m per unit, how to read them
_LENGTHS = (("millimetres", 1e-3, "name the column position_mm"),
            ("centimetres", 1e-2, "multiply by 10 and name the column position_mm "
                                  "(pmabayes has no position_cm)"),
            ("micrometres", 1e-6, "name the column position_um"))
#: a muscle on a rig responds from about 0.01 to 50 Hz and is logged at 10 Hz to 100 kHz
_MUSCLE_HZ = (0.01, 50.0)
_RATE_HZ = (10.0, 1e5)
_TIMES = (("seconds", 1.0, "time_s"), ("milliseconds", 1e-3, "time_ms"),
          ("microseconds", 1e-6, "time_us"))


def _silence(declare: str) -> str:
    """How to switch the unit checks off, for a file user and for an API user."""
    return (
        f'If the values really are in SI units, add "check_units": false to {declare} '
        "(or pass check_units=False to pmabayes.data.load)."
    )


def _declarations(metadata: dict, declare: str) -> tuple[bool, str | None]:
    """The metadata's ``check_units`` (bool) and ``pressure_reference`` (or None)."""
    check = metadata.get("check_units", True)
    if not isinstance(check, bool):
        raise DataError(
            f"{declare}: check_units = {check!r} must be true or false (JSON booleans); "
            "fix or remove it."
        )
    reference = metadata.get("pressure_reference")
    if reference is not None and reference not in _REFERENCES:
        raise DataError(
            f'{declare}: pressure_reference = {reference!r} must be "gauge" or "absolute"; '
            "fix or remove it."
        )
    return check, reference


def _absolute_to_gauge(ds: Dataset, declare: str) -> Dataset:
    """Subtract the ambient pressure from data declared ``"pressure_reference": "absolute"``."""
    ambient = ds.metadata.get("ambient_pressure_pa", _ATM_PA)
    if isinstance(ambient, bool) or not isinstance(ambient, numbers.Real) or not (
        _AMBIENT_BAND_PA[0] / 2 <= ambient <= 2 * _AMBIENT_BAND_PA[1]
    ):
        raise DataError(
            f"{declare}: ambient_pressure_pa = {ambient!r} is not an ambient pressure in Pa "
            f"(about {_fmt(_ATM_PA)}); fix it, or remove it to use {_fmt(_ATM_PA)} Pa."
        )
    metadata = {**ds.metadata, "pressure_reference": "gauge",
                "converted_from_absolute": {"ambient_pressure_pa": float(ambient)}}
    metadata.pop("ambient_pressure_pa", None)
    return dataclasses.replace(ds, input=ds.input - float(ambient), metadata=metadata)


def _cycles_hz(u: np.ndarray, duration_s: float) -> float:
    """How fast an input cycles: its swings between the lower and upper quarters of its
    range, per second (half a cycle for a record that never swings)."""
    lo, hi = float(u.min()), float(u.max())
    if hi <= lo or duration_s <= 0:
        return 0.5 / duration_s if duration_s > 0 else math.inf
    state = np.where(u > lo + 0.75 * (hi - lo), 1, np.where(u < lo + 0.25 * (hi - lo), -1, 0))
    state = state[state != 0]
    swings = int(np.count_nonzero(np.diff(state)))
    return max(swings / 2.0, 0.5) / duration_s


def _check_clock_unit(ds: Dataset, where: str, declare: str, column: str) -> None:
    """Refuse times whose unit looks wrong: a sample rate and an input far slower (or
    faster) than a muscle on a rig, where another time unit makes both plausible."""
    n = ds.n_samples
    fs = ds.sample_rate_hz
    duration = (n - 1) / fs
    f_in = _cycles_hz(ds.input[0], duration)
    slow = fs < _RATE_HZ[0] and f_in < _MUSCLE_HZ[0]
    fast = fs > _RATE_HZ[1] and f_in > _MUSCLE_HZ[1]
    if not (slow or fast):
        return
    declared = UNITS[column][1]
    fits = [(name, declared / per_unit, col) for name, per_unit, col in _TIMES
            if col != column
            and _RATE_HZ[0] <= fs * declared / per_unit <= _RATE_HZ[1]
            and _MUSCLE_HZ[0] <= f_in * declared / per_unit <= _MUSCLE_HZ[1]]
    given = (f"{where}: {column} gives a sample rate of {fs:.4g} Hz and an input that "
             f"cycles at about {f_in:.2g} Hz over {duration:.4g} s; a pneumatic muscle on a "
             f"rig responds from about {_MUSCLE_HZ[0]:g} to {_MUSCLE_HZ[1]:g} Hz and is "
             f"logged at {_RATE_HZ[0]:g} Hz to {_RATE_HZ[1] / 1e3:g} kHz, ")
    rate = (f'or give the sample rate, "sample_rate_hz", in {declare} if the times really '
            f"are in {column.split('_')[1]}. ")
    if not fits:
        raise DataError(given + "and no time unit makes this record one: check the time "
                        "column (it may not hold times), " + rate + _silence(declare))
    name, scale, col = fits[0]
    raise DataError(
        given + f"so the times look like {name}: a sample rate of {fs * scale:.4g} Hz, the "
        f"input cycling at about {f_in * scale:.2g} Hz over {duration / scale:.4g} s. Fix: "
        f"name the column {col}, " + rate + _silence(declare))


def _check_units(
    ds: Dataset, where: str, locate: Callable[[int, int], str], declare: str,
    columns: dict[str, str] | None = None,
) -> None:
    """Reject values that look like the wrong unit (pressure-driven data only).

    ``locate(k, j)`` describes trial index ``k``, sample ``j`` for the message;
    ``declare`` names where the metadata can switch the check off; ``columns`` maps
    an SI name to the file's column name for it (``pressure_psi``), when it differs.
    """
    if ds.input_name != "pressure_pa":
        return
    columns = columns or {}
    p = ds.input
    absp = np.abs(p)
    pmax = float(absp.max())
    if 0.0 < pmax <= _MPA_BAR_MAX:
        k, j = np.unravel_index(int(np.argmax(absp)), p.shape)
        col = columns.get("pressure_pa", "pressure_pa")
        fix = ("" if col == "pressure_pa" else
               f" ({col} gives {_fmt(pmax)} Pa at most)")
        raise DataError(
            f"{where}: {col} looks like MPa (multiply by 1e6) or bar (multiply by "
            f"1e5), not Pa{fix}: the largest |value| is {_fmt(pmax)} ({locate(k, j)}); or "
            "name the column pressure_mpa or pressure_bar to have it converted. "
            + _silence(declare)
        )
    below = p < _VACUUM_PA
    if below.any():
        k, j = _first_in_file_order(below)
        raise DataError(
            f"{where}: pressure_pa = {_fmt(p[k, j])} Pa ({locate(k, j)}) is below vacuum "
            f"({_fmt(_VACUUM_PA)} Pa), impossible for a gauge pressure; convert absolute "
            "pressure to gauge (subtract ambient) or check the unit. " + _silence(declare)
        )
    x = ds.position_m
    with np.errstate(invalid="ignore"):
        big = np.abs(x) > _MM_MIN  # NaN (a sample not observed) is not big
    if big.any():
        k, j = _first_in_file_order(big)
        col = columns.get("position_m", "position_m")
        per_unit = UNITS[col][1]
        shown = x[k, j] / per_unit
        value = (f"{where}: {col} = {_fmt(shown)} ({locate(k, j)}) exceeds {_MM_MIN:g} m"
                 + ("" if col == "position_m" else f" ({_fmt(x[k, j])} m)"))
        raw = x[ds.observed] / per_unit
        fits = [(name, m, fix) for name, m, fix in _LENGTHS
                if m != per_unit and np.abs(raw).max() * m <= _MM_MIN
                and _STROKE_M[0] <= np.ptp(raw) * m <= _STROKE_M[1]]
        if fits:
            said = " or ".join(f"{name} (a stroke of {np.ptp(raw) * m * 1e3:.3g} mm: {fix})"
                               for name, m, fix in fits)
            raise DataError(
                f"{value} in magnitude: not a muscle's position in m. The values look like "
                f"{said}. " + _silence(declare)
            )
        raise DataError(
            f"{value} in magnitude: not a muscle's position in m, nor in mm (over "
            f"{_MM_MAX:g} mm); check that the column holds the position, and convert "
            "encoder counts or other units to m. " + _silence(declare)
        )


def _check_gauge(
    ds: Dataset, where: str, locate: Callable[[int, int], str], declare: str
) -> None:
    """Warn when pressure looks absolute or offset rather than gauge.

    A vented muscle is at 0 gauge, and trials start at rest: so the lowest command
    sits near 0, and the first samples, where the muscle rests, near the lowest.
    """
    if ds.input_name != "pressure_pa":
        return
    p = ds.input
    k, j = np.unravel_index(int(np.argmin(p)), p.shape)
    lowest = float(p[k, j])
    at_rest = bool(np.all(p[:, 0] - p.min(axis=1) <= -_BELOW_AMBIENT_PA))
    declare_gauge = (
        f'If it really is gauge pressure, declare "pressure_reference": "gauge" in {declare}.'
    )
    if _AMBIENT_BAND_PA[0] <= lowest <= _AMBIENT_BAND_PA[1]:
        start = ", and every trial starts there, at rest" if at_rest else ""
        warnings.warn(
            f"{where}: the lowest commanded pressure, {lowest / 1e3:.1f} kPa "
            f"({locate(k, j)}), is about one atmosphere{start}: pressure_pa looks like "
            "absolute pressure. pmabayes needs gauge pressure (0 = ambient, a vented "
            "muscle); absolute pressure would be absorbed into the dead zone p_dz. Fix: "
            f"subtract the ambient pressure ({_fmt(_ATM_PA)} Pa), or declare "
            f'"pressure_reference": "absolute" in {declare} (with "ambient_pressure_pa" '
            f"if not {_fmt(_ATM_PA)}) to convert on reading. " + declare_gauge,
            DataWarning,
            stacklevel=4,
        )
    elif lowest < _BELOW_AMBIENT_PA:
        warnings.warn(
            f"{where}: pressure_pa goes down to {lowest / 1e3:.1f} kPa ({locate(k, j)}): "
            "a pneumatic muscle is vented at 0 gauge and not driven below ambient, so the "
            f"pressure looks offset by about {lowest / 1e3:.0f} kPa (a wrong zero, or the "
            "ambient subtracted twice), and the offset would be absorbed into the dead "
            "zone p_dz. Fix: correct the zero so that the muscle at rest reads 0 Pa. "
            + declare_gauge,
            DataWarning,
            stacklevel=4,
        )


def _checked(
    ds: Dataset,
    where: str,
    locate: Callable[[int, int], str],
    declare: str,
    check_units: bool,
    columns: dict[str, str] | None = None,
) -> Dataset:
    """Apply the metadata's declarations and the plausibility checks to read data.

    ``columns`` maps an SI name to the file's column name for it; the time unit is
    checked when the times come from a column (``"time_s"`` in it, the default) and
    no ``sample_rate_hz`` is declared.
    """
    check, reference = _declarations(ds.metadata, declare)
    check = check and check_units
    columns = {"time_s": "time_s"} if columns is None else columns
    if check:  # on the values as read: MPa or bar shows before any ambient shift
        _check_units(ds, where, locate, declare, columns)
        if (ds.input_name == "pressure_pa" and "time_s" in columns
                and "sample_rate_hz" not in ds.metadata):
            _check_clock_unit(ds, where, declare, columns["time_s"])
    if ds.input_name != "pressure_pa":
        return zeroed_at_start(ds, declare)
    if reference == "absolute":
        return zeroed_at_start(_absolute_to_gauge(ds, declare), declare)
    if check and reference is None:
        _check_gauge(ds, where, locate, declare)
    return zeroed_at_start(ds, declare)
