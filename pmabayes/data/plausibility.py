"""Plausibility checks on data as read: units, and gauge rather than absolute pressure.

What a file's numbers can show about their units: pressure in MPa or bar, below
vacuum, or looking absolute (the lowest command about one atmosphere) or offset
(far below ambient); position in mm or no length at all. Errors for what cannot be
right, :class:`DataWarning` for what looks wrong. The metadata declares what the
checks cannot know: ``"check_units": false`` and ``"pressure_reference"``
(``"gauge"``, or ``"absolute"`` to convert to gauge on reading).
"""

from __future__ import annotations

import dataclasses
import numbers
import warnings
from collections.abc import Callable

import numpy as np

from pmabayes.data.dataset import DataError, Dataset, DataWarning, _first_in_file_order, _fmt

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


def _check_units(
    ds: Dataset, where: str, locate: Callable[[int, int], str], declare: str
) -> None:
    """Reject values that look like the wrong unit (pressure-driven data only).

    ``locate(k, j)`` describes trial index ``k``, sample ``j`` for the message;
    ``declare`` names where the metadata can switch the check off.
    """
    if ds.input_name != "pressure_pa":
        return
    p = ds.input
    absp = np.abs(p)
    pmax = float(absp.max())
    if 0.0 < pmax <= _MPA_BAR_MAX:
        k, j = np.unravel_index(int(np.argmax(absp)), p.shape)
        raise DataError(
            f"{where}: pressure_pa looks like MPa (multiply by 1e6) or bar (multiply by "
            f"1e5), not Pa: the largest |value| is {_fmt(pmax)} ({locate(k, j)}). "
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
    big = np.abs(x) > _MM_MIN
    if big.any():
        k, j = _first_in_file_order(big)
        value = f"{where}: position_m = {_fmt(x[k, j])} ({locate(k, j)}) exceeds {_MM_MIN:g} m"
        if abs(x[k, j]) <= _MM_MAX:
            raise DataError(
                f"{value} in magnitude and looks like millimetres, divide by 1000. "
                + _silence(declare)
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
) -> Dataset:
    """Apply the metadata's declarations and the plausibility checks to read data."""
    check, reference = _declarations(ds.metadata, declare)
    check = check and check_units
    if check:  # on the values as read: MPa or bar shows before any ambient shift
        _check_units(ds, where, locate, declare)
    if ds.input_name != "pressure_pa":
        return ds
    if reference == "absolute":
        return _absolute_to_gauge(ds, declare)
    if check and reference is None:
        _check_gauge(ds, where, locate, declare)
    return ds
