"""A sensor's raw signal read through its calibration, as the sidecar declares it.

A logger may save a sensor's output (volts, millivolts, milliamperes, counts) rather
than the quantity. The sidecar's ``"calibration"`` names such a column (as pmabayes
spells it: a header ``Pressure (V)`` is ``pressure_v``) and the line that turns it into
a unit pmabayes reads::

    "calibration": {"pressure_v": {"to": "pressure_kpa", "gain": 100.0, "offset": -12.5}}

reads each value as ``gain x signal + offset`` kPa, then in SI. It is said once per
file, and the declaration moves to the metadata's ``"calibrated"`` record (the data set
holds the quantity, so a data set written back reads back the same).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmabayes.data.dataset import DataError, DataWarning
from pmabayes.data.sidecar import say_once
from pmabayes.data.units import _HERE, UNITS, quantity

__all__ = ["Calibration", "SignalNames", "calibrations", "apply"]

_SPELT = {"v": "V", "mv": "mV", "ma": "mA"}
_EXAMPLE = '{"pressure_v": {"to": "pressure_kpa", "gain": 100.0, "offset": 0.0}}'


@dataclass(frozen=True)
class Calibration:
    """One column's calibration: ``to`` (a name of :data:`~pmabayes.data.UNITS`) =
    ``gain`` x signal + ``offset``."""

    signal: str
    to: str
    gain: float
    offset: float = 0.0

    def si(self, values_in_to_si: np.ndarray) -> np.ndarray:
        """The quantity in SI from the signal read as if it were in ``to``'s unit and
        converted to SI (the reader's own path): ``gain`` x that + ``offset`` in SI."""
        return self.gain * values_in_to_si + self.offset * UNITS[self.to][1]

    def text(self) -> str:
        unit = self.signal.split("_", 1)[1]
        unit = _SPELT.get(unit, unit)
        return f"{self.to} = {self.gain:g} x {unit} {'-' if self.offset < 0 else '+'} " \
               f"{abs(self.offset):g}"

    def to_dict(self) -> dict:
        return {"to": self.to, "gain": self.gain, "offset": self.offset}


def calibrations(spec: object, declare: str) -> dict[str, Calibration]:
    """The sidecar's ``"calibration"``, checked: the signal's column name to its
    :class:`Calibration`. An empty dict where ``spec`` is None."""
    if spec is None:
        return {}
    if not isinstance(spec, dict) or not spec:
        raise DataError(f"{declare}: 'calibration' is {spec!r}; it must map a column of a "
                        f"sensor's signal to its calibration, e.g. {_EXAMPLE}.")
    out = {}
    for signal, entry in spec.items():
        where = f"{declare}: 'calibration' {signal!r}"
        q = quantity(str(signal))
        if not q or signal in UNITS:
            raise DataError(
                f"{where}: not a column of a sensor's signal (a quantity and the signal's "
                f"unit, as pmabayes spells the header: pressure_v, position_mv, force_ma); a "
                f"column already in a unit pmabayes reads needs no calibration.")
        if not isinstance(entry, dict) or set(entry) - {"to", "gain", "offset"} \
                or not {"to", "gain"} <= set(entry):
            raise DataError(f"{where} is {entry!r}; give \"to\" (a unit pmabayes reads), "
                            f"\"gain\" and, if not 0, \"offset\", e.g. {_EXAMPLE}.")
        to, gain, offset = entry["to"], entry["gain"], entry.get("offset", 0.0)
        if to not in UNITS or quantity(to) != q:
            known = ", ".join(n for n in UNITS if quantity(n) == q)
            raise DataError(f"{where}: \"to\" is {to!r}; it must be a unit of {q} pmabayes "
                            f"reads: {known}.")
        for name, value in (("gain", gain), ("offset", offset)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise DataError(f"{where}: \"{name}\" is {value!r}; it must be a finite "
                                "number.")
        if gain == 0:
            raise DataError(f"{where}: \"gain\" is 0, which reads every sample as the "
                            "offset; give the sensor's gain.")
        out[str(signal)] = Calibration(str(signal), to, float(gain), float(offset))
    return out


class SignalNames:
    """The column names a file spells, with each calibrated signal's read as its
    ``to``; it keeps which signals it met, for :func:`apply`."""

    def __init__(self, calibrated: dict[str, Calibration]) -> None:
        self.calibrated = calibrated
        self.met: set[str] = set()

    def __call__(self, names: list[str]) -> list[str]:
        self.met |= {n for n in names if n in self.calibrated}
        return [self.calibrated[n].to if n in self.calibrated else n for n in names]


def apply(names: SignalNames, values: dict[str, np.ndarray], where: str,
          declare: str) -> dict:
    """``values`` (SI name to the column as read) with each calibration applied, in
    place, and said once; a calibration that names no column is refused. Returns the
    record for the metadata's ``"calibrated"``."""
    unused = sorted(set(names.calibrated) - names.met)
    if unused:
        raise DataError(f"{declare}: 'calibration' names {', '.join(unused)}, which no column "
                        f"of {where} is: fix the name (as pmabayes spells the column: a header "
                        "Pressure (V) is pressure_v).")
    for c in names.calibrated.values():
        si = UNITS[c.to][0]
        values[si] = c.si(values[si])
    said = "; ".join(c.text() for c in names.calibrated.values())
    say_once(where, f"calibration: {said}", DataWarning(
        f"{where}: sensor signals read through the sidecar's calibration: {said}; the "
        "metadata's 'calibrated' records it."), _HERE)
    return {s: c.to_dict() for s, c in names.calibrated.items()}
