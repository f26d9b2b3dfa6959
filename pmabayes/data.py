"""Data stage: read, validate and write pneumatic-muscle (or oscillator) trial data.

A data set is a set of trials that share one uniformly sampled time grid. Each trial
has one input signal (commanded gauge pressure in Pa, or force in N for a generic
force-driven oscillator) and one measured position signal in m.

Two file formats are supported:

CSV
    Header ``trial,time_s,pressure_pa,position_m`` (any column order; ``force_n`` may
    replace ``pressure_pa``), one row per sample, each trial's rows contiguous. An
    optional JSON sidecar with the same stem (``foo.csv`` -> ``foo.json``) holds a
    free-form metadata object.
NetCDF
    Written and read through xarray with the ``h5netcdf`` engine; metadata is stored
    as a JSON string attribute. Intended for large data.

Bad input raises :class:`DataError` with a message that names the file, the line or
trial, and says how to fix it. Nothing is dropped, repaired or clipped silently.
Data that read but look suspect (pressure that looks absolute, not gauge) give a
:class:`DataWarning`. Two metadata entries declare what the checks cannot know:
``"pressure_reference"`` (``"gauge"``, or ``"absolute"`` to convert to gauge on
reading) and ``"check_units": false``.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import numbers
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike

__all__ = [
    "INPUT_NAMES",
    "DataError",
    "DataWarning",
    "Dataset",
    "check_time_grid",
    "load",
    "read_csv",
    "read_netcdf",
    "save",
    "write_csv",
    "write_netcdf",
]

INPUT_NAMES: tuple[str, ...] = ("pressure_pa", "force_n")
"""Allowed names of the input column: commanded gauge pressure (Pa) or force (N)."""

_UNITS = {"time_s": "s", "pressure_pa": "Pa", "force_n": "N", "position_m": "m"}
_REL_TOL = 1e-6  # relative tolerance on sample intervals, sample times and sample rates
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
_NC_ENGINE = "h5netcdf"

PathLike = str | os.PathLike[str]


class DataError(ValueError):
    """Invalid or inconsistent data.

    Every message names the file (or the data set's source), the line (1-based,
    header = line 1) or the trial, and says how to fix the problem.
    """


# ----------------------------------------------------------------------------- helpers


def _fmt(x: float) -> str:
    """Format a number compactly but unambiguously for messages."""
    return f"{float(x):.10g}"


def _first_nonuniform(t: np.ndarray) -> int | None:
    """Return the index ``i`` of the first interval ``t[i+1] - t[i]`` off the median.

    The median (not the mean) is the reference so that one glitch is reported where
    it occurs rather than shifting the reference for every other interval.
    """
    d = np.diff(t)
    if d.size == 0:
        return None
    ref = float(np.median(d))
    bad = np.abs(d - ref) > _REL_TOL * abs(ref)
    if not bad.any():
        return None
    return int(np.argmax(bad))


def check_time_grid(
    time_s: ArrayLike,
    *,
    source: str = "time_s",
    locate: Callable[[int], str] | None = None,
    error: type[Exception] = DataError,
) -> float:
    """Check that sample times are finite, strictly increasing and uniformly spaced.

    The one time-grid check of the package: data sets, CSV trials and the
    simulator's ``time_s`` all go through it.

    Parameters
    ----------
    time_s : array_like
        Sample times in s, 1-D, at least 2 samples.
    source : str, optional
        What the times belong to (a file, a trial), the start of every message.
    locate : callable, optional
        ``locate(j)`` describes sample ``j`` for messages (e.g. a CSV line);
        ``"sample j"`` by default.
    error : type, optional
        Exception class to raise (:class:`DataError` by default).

    Returns
    -------
    float
        The mean sample interval in s (``np.diff(time_s).mean()``).

    Raises
    ------
    DataError
        (or ``error``) If the times are not 1-D with 2 or more samples, not finite,
        not strictly increasing, or an interval differs from the median interval by
        more than 1e-6 relative.
    """
    t = np.asarray(time_s, dtype=float)
    where = locate or (lambda j: f"sample {j}")
    if t.ndim != 1 or t.size < 2:
        raise error(f"{source}: time_s must be 1-D with at least 2 samples; got shape {t.shape}.")
    bad = ~np.isfinite(t)
    if bad.any():
        j = int(np.argmax(bad))
        raise error(f"{source}: {where(j)}: time_s = {t[j]} is not finite; supply finite times.")
    d = np.diff(t)
    if (d <= 0).any():
        j = int(np.argmax(d <= 0)) + 1
        raise error(
            f"{source}: {where(j)}: time_s = {_fmt(t[j])} is not after {_fmt(t[j - 1])} "
            f"on {where(j - 1)}; times must be strictly increasing: sort by time and "
            "remove duplicate samples."
        )
    i = _first_nonuniform(t)
    if i is not None:
        raise error(
            f"{source}: {where(i + 1)}: time_s is not uniformly sampled: interval "
            f"{_fmt(d[i])} s from {where(i)} differs from the median interval "
            f"{_fmt(np.median(d))} s by more than {_REL_TOL:g} relative (missing or "
            "duplicated sample?); resample onto a uniform grid."
        )
    return float(d.mean())


def _check_metadata_rate(metadata: dict, rate_hz: float, where: str) -> None:
    """Check a metadata ``sample_rate_hz`` against the data's sample rate."""
    if "sample_rate_hz" not in metadata:
        return
    value = metadata["sample_rate_hz"]
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Real)
        or not math.isfinite(value)
        or value <= 0
    ):
        raise DataError(
            f"{where}: sample_rate_hz = {value!r} is not a positive finite number; "
            f"set it to the sample rate in Hz (the time_s column gives {_fmt(rate_hz)} Hz) "
            "or remove it."
        )
    if abs(float(value) - rate_hz) > _REL_TOL * rate_hz:
        raise DataError(
            f"{where}: sample_rate_hz = {_fmt(value)} Hz disagrees with the sample rate "
            f"of the time_s column, {_fmt(rate_hz)} Hz (relative tolerance {_REL_TOL:g}); "
            "correct sample_rate_hz or the time column."
        )


def _json_roundtrip_check(metadata: dict, where: str) -> str:
    """Serialize metadata to JSON, raising if it would not read back identically."""
    try:
        text = json.dumps(metadata, indent=2, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise DataError(
            f"{where}: metadata cannot be stored as JSON ({exc}); use only str keys and "
            "str/int/float/bool/None/list/dict values (no NaN, no numpy scalars)."
        ) from None
    if json.loads(text) != metadata:
        raise DataError(
            f"{where}: metadata would not read back identically from JSON (tuples or "
            "non-str keys?); use lists and str keys."
        )
    return text


class DataWarning(UserWarning):
    """Data that read correctly but look suspect (e.g. absolute instead of gauge pressure).

    Every message names the file, the trial and the fix, and how to declare the
    data right when the suspicion is wrong.
    """


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


def _first_in_file_order(mask: np.ndarray) -> tuple[int, int]:
    """First ``(trial index, sample index)`` where a 2-D mask is true, row-major."""
    k, j = np.unravel_index(int(np.argmax(mask)), mask.shape)
    return int(k), int(j)


# ----------------------------------------------------------------------------- Dataset


@dataclass(frozen=True, eq=False, repr=False)
class Dataset:
    """Trials sharing one uniform time grid: input signal and measured position.

    Parameters
    ----------
    time_s : numpy.ndarray
        Sample times in s, shape ``(n_samples,)``, strictly increasing and uniformly
        sampled (relative tolerance 1e-6 on the interval); shared by all trials. The
        first sample may be non-zero. At least 2 samples.
    input : numpy.ndarray
        Input signal, shape ``(n_trials, n_samples)``: commanded gauge pressure in Pa
        (``input_name="pressure_pa"``) or force in N (``input_name="force_n"``).
    position_m : numpy.ndarray
        Measured position in m, shape ``(n_trials, n_samples)``.
    trial_ids : numpy.ndarray
        Integer trial ids, shape ``(n_trials,)``, unique, in file order.
    input_name : str, optional
        ``"pressure_pa"`` (default) or ``"force_n"``.
    metadata : dict, optional
        Free-form metadata (e.g. ``synthetic``, ``description``, ``sample_rate_hz``,
        ``rig``, ``generator``). A ``sample_rate_hz`` entry must agree with the time
        grid to within 1e-6 relative.
    source : str or None, optional
        Path the data were read from; used in error messages.

    Raises
    ------
    DataError
        If shapes, dtypes or values are invalid: non-finite values, time not strictly
        increasing or not uniform, duplicate trial ids, unknown ``input_name``.

    Notes
    -----
    Arrays are stored as read-only float64 (``trial_ids``: int64) copies. Two data sets
    compare equal when all fields except ``source`` are equal.
    """

    time_s: np.ndarray
    input: np.ndarray
    position_m: np.ndarray
    trial_ids: np.ndarray
    input_name: str = "pressure_pa"
    metadata: dict = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        """Validate the fields and freeze the arrays."""
        source = self.source
        if source is not None:
            if not isinstance(source, (str, os.PathLike)):
                raise DataError(
                    f"Dataset: source must be a str path or None, got {type(source).__name__}."
                )
            source = os.fspath(source)
        where = f"Dataset from {source}" if source else "Dataset"

        if self.input_name not in INPUT_NAMES:
            raise DataError(
                f"{where}: input_name must be one of {', '.join(INPUT_NAMES)}; "
                f"got {self.input_name!r}."
            )
        if not isinstance(self.metadata, dict):
            raise DataError(
                f"{where}: metadata must be a dict, got {type(self.metadata).__name__}; "
                "pass a dict (possibly empty)."
            )

        time_s = self._as_float(self.time_s, "time_s", where)
        check_time_grid(time_s, source=where)
        n = time_s.size
        arrays = {}
        for name, value in (("input", self.input), ("position_m", self.position_m)):
            a = self._as_float(value, name, where)
            if a.ndim != 2 or a.shape[1] != n or a.shape[0] < 1:
                raise DataError(
                    f"{where}: {name} must have shape (n_trials, {n}) to match time_s; got "
                    f"{a.shape} (for one trial use a[np.newaxis, :])."
                )
            arrays[name] = a
        if arrays["input"].shape != arrays["position_m"].shape:
            raise DataError(
                f"{where}: input has shape {arrays['input'].shape} but position_m has "
                f"{arrays['position_m'].shape}; both must be (n_trials, n_samples)."
            )
        n_trials = arrays["input"].shape[0]

        ids = np.asarray(self.trial_ids)
        if ids.dtype.kind not in "iu" or ids.shape != (n_trials,):
            raise DataError(
                f"{where}: trial_ids must be an integer array of shape ({n_trials},); got "
                f"dtype {ids.dtype} and shape {ids.shape}."
            )
        if ids.dtype.kind == "u" and ids.size and int(ids.max()) > np.iinfo(np.int64).max:
            raise DataError(f"{where}: trial_ids exceed the int64 range; renumber the trials.")
        ids = np.array(ids, dtype=np.int64, copy=True)
        uniq, counts = np.unique(ids, return_counts=True)
        if (counts > 1).any():
            dup = int(uniq[np.argmax(counts > 1)])
            raise DataError(
                f"{where}: trial {dup} appears {int(counts.max())} times in trial_ids; "
                "trial ids must be unique."
            )

        for name, a in arrays.items():
            bad = ~np.isfinite(a)
            if bad.any():
                k, j = _first_in_file_order(bad)
                raise DataError(
                    f"{where}: {name} of trial {ids[k]} is {a[k, j]} at sample {j}; "
                    "all values must be finite (no NaN or inf)."
                )
        for name, a in (("time_s", time_s), ("trial_ids", ids), *arrays.items()):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "metadata", dict(self.metadata))
        object.__setattr__(self, "source", source)
        _check_metadata_rate(self.metadata, self.sample_rate_hz, f"{where}: metadata")

    @staticmethod
    def _as_float(value: Any, name: str, where: str) -> np.ndarray:
        """Return a float64 copy of a real numeric array, else raise DataError."""
        a = np.asarray(value)
        if a.dtype.kind not in "iuf":
            raise DataError(f"{where}: {name} must be a real numeric array; got dtype {a.dtype}.")
        return np.array(a, dtype=np.float64, copy=True)

    # -- properties

    @property
    def n_trials(self) -> int:
        """Number of trials."""
        return int(self.input.shape[0])

    @property
    def n_samples(self) -> int:
        """Number of samples per trial."""
        return int(self.time_s.size)

    @property
    def dt_s(self) -> float:
        """Uniform sample interval in s, ``(t[-1] - t[0]) / (n_samples - 1)``."""
        return float(self.time_s[-1] - self.time_s[0]) / (self.n_samples - 1)

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate in Hz, ``1 / dt_s``."""
        return 1.0 / self.dt_s

    @property
    def pressure_pa(self) -> np.ndarray:
        """Commanded gauge pressure in Pa, ``(n_trials, n_samples)``.

        Raises
        ------
        DataError
            If the input is force (``input_name == "force_n"``).
        """
        if self.input_name != "pressure_pa":
            where = self.source or "Dataset"
            raise DataError(
                f"{where}: this data set's input is {self.input_name!r}, not pressure; "
                "use Dataset.input."
            )
        return self.input

    @property
    def mean_position_m(self) -> np.ndarray:
        """Position averaged over trials, shape ``(n_samples,)``."""
        return self.position_m.mean(axis=0)

    @property
    def noise_floor_m(self) -> float:
        """RMS error a perfect model would have against the trial mean.

        Estimated from the spread between repeated trials: the root of the
        time-averaged sample variance across trials divided by the number of
        trials. NaN with a single trial (no spread to estimate it from).
        """
        if self.n_trials < 2:
            return math.nan
        var = self.position_m.var(axis=0, ddof=1).mean()
        return float(math.sqrt(var / self.n_trials))

    # -- methods

    def select_trials(self, indices: int | Sequence[int] | np.ndarray) -> Dataset:
        """Return a new data set with a subset of trials.

        Parameters
        ----------
        indices : int or sequence of int
            Positional trial indices (``0 .. n_trials - 1``; negative counts from the
            end), not trial ids. Order is kept; duplicates are not allowed.

        Returns
        -------
        Dataset
            The selected trials, with the same time grid, metadata and source.

        Raises
        ------
        DataError
            If no index is given, an index is out of range or repeated, or an index is
            not an integer.
        """
        where = self.source or "Dataset"
        idx = np.atleast_1d(np.asarray(indices))
        if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu":
            raise DataError(
                f"{where}: select_trials needs one or more integer trial indices "
                f"(positions 0..{self.n_trials - 1}); got {indices!r}."
            )
        out = (idx < -self.n_trials) | (idx >= self.n_trials)
        if out.any():
            raise DataError(
                f"{where}: trial index {int(idx[np.argmax(out)])} is out of range for "
                f"{self.n_trials} trials; use positions 0..{self.n_trials - 1} (not trial ids)."
            )
        idx = idx % self.n_trials
        if np.unique(idx).size != idx.size:
            raise DataError(
                f"{where}: select_trials got repeated trial indices {indices!r}; "
                "select each trial at most once."
            )
        return Dataset(
            time_s=self.time_s,
            input=self.input[idx],
            position_m=self.position_m[idx],
            trial_ids=self.trial_ids[idx],
            input_name=self.input_name,
            metadata=dict(self.metadata),
            source=self.source,
        )

    def to_xarray(self) -> xr.Dataset:
        """Convert to an :class:`xarray.Dataset`.

        Returns
        -------
        xarray.Dataset
            Dimensions ``("trial", "time_s")`` with coordinates ``trial`` (the trial
            ids) and ``time_s``; data variables named after the input (``pressure_pa``
            or ``force_n``) and ``position_m``, each with a ``units`` attribute;
            attributes ``input_name`` and ``metadata_json`` (the metadata as JSON).
            Arrays are writable copies.

        Raises
        ------
        DataError
            If the metadata cannot be stored as JSON exactly.
        """
        meta = _json_roundtrip_check(self.metadata, self.source or "Dataset")
        dims = ("trial", "time_s")
        return xr.Dataset(
            data_vars={
                self.input_name: (dims, self.input.copy(), {"units": _UNITS[self.input_name]}),
                "position_m": (dims, self.position_m.copy(), {"units": "m"}),
            },
            coords={
                "trial": ("trial", self.trial_ids.copy()),
                "time_s": ("time_s", self.time_s.copy(), {"units": "s"}),
            },
            attrs={"input_name": self.input_name, "metadata_json": meta},
        )

    @classmethod
    def from_xarray(cls, ds: xr.Dataset, *, source: str | None = None) -> Dataset:
        """Build a data set from an :class:`xarray.Dataset` made by :meth:`to_xarray`.

        Parameters
        ----------
        ds : xarray.Dataset
            Dimensions ``trial`` and ``time_s``; coordinates of the same names; data
            variables ``position_m`` and exactly one of ``pressure_pa`` or ``force_n``.
            An optional ``metadata_json`` attribute holds the metadata.
        source : str or None, optional
            Where the data came from, for messages.

        Returns
        -------
        Dataset
            The validated data set.

        Raises
        ------
        TypeError
            If ``ds`` is not an :class:`xarray.Dataset`.
        DataError
            If variables or coordinates are missing, extra or mis-shaped, or the
            metadata attribute is not a JSON object.
        """
        if not isinstance(ds, xr.Dataset):
            raise TypeError(f"from_xarray needs an xarray.Dataset, got {type(ds).__name__}")
        where = os.fspath(source) if source is not None else "xarray dataset"
        names = set(ds.data_vars)
        inputs = [n for n in INPUT_NAMES if n in names]
        expected = "position_m and exactly one of pressure_pa or force_n"
        if len(inputs) != 1 or "position_m" not in names:
            raise DataError(f"{where}: data variables are {sorted(names)}; expected {expected}.")
        extra = sorted(names - {"position_m", inputs[0]})
        if extra:
            raise DataError(
                f"{where}: unexpected data variable(s) {extra}; expected {expected}. Remove them."
            )
        input_name = inputs[0]
        for coord in ("trial", "time_s"):
            if coord not in ds.coords or ds[coord].dims != (coord,):
                raise DataError(
                    f"{where}: missing 1-D coordinate {coord!r} along dimension {coord!r}; "
                    "write the file with write_netcdf or Dataset.to_xarray."
                )
        for name in (input_name, "position_m"):
            if set(ds[name].dims) != {"trial", "time_s"}:
                raise DataError(
                    f"{where}: {name} has dimensions {ds[name].dims}; expected ('trial', 'time_s')."
                )
        attr_name = ds.attrs.get("input_name", input_name)
        if attr_name != input_name:
            raise DataError(
                f"{where}: attribute input_name={attr_name!r} but the data variable is "
                f"{input_name!r}; make them agree."
            )
        meta_text = ds.attrs.get("metadata_json", "{}")
        try:
            metadata = json.loads(meta_text)
        except (TypeError, json.JSONDecodeError) as exc:
            raise DataError(
                f"{where}: attribute metadata_json is not valid JSON ({exc}); "
                "store the metadata as a JSON object string."
            ) from None
        if not isinstance(metadata, dict):
            raise DataError(
                f"{where}: attribute metadata_json holds a JSON {type(metadata).__name__}, "
                "not an object; store a JSON object."
            )
        return cls(
            time_s=ds["time_s"].values,
            input=ds[input_name].transpose("trial", "time_s").values,
            position_m=ds["position_m"].transpose("trial", "time_s").values,
            trial_ids=ds["trial"].values,
            input_name=input_name,
            metadata=metadata,
            source=source,
        )

    # -- dunder

    def __eq__(self, other: object) -> bool:
        """Equal if all fields except ``source`` are equal (arrays by value)."""
        if not isinstance(other, Dataset):
            return NotImplemented
        return (
            self.input_name == other.input_name
            and self.metadata == other.metadata
            and np.array_equal(self.trial_ids, other.trial_ids)
            and np.array_equal(self.time_s, other.time_s)
            and np.array_equal(self.input, other.input)
            and np.array_equal(self.position_m, other.position_m)
        )

    __hash__ = None  # type: ignore[assignment]  # mutable metadata, array fields

    def __repr__(self) -> str:
        """Short summary (no array contents)."""
        return (
            f"Dataset(n_trials={self.n_trials}, n_samples={self.n_samples}, "
            f"dt_s={self.dt_s:.6g}, input_name={self.input_name!r}, "
            f"trial_ids={self.trial_ids.tolist()!r}, source={self.source!r})"
        )


# ----------------------------------------------------------------------------- CSV

_BASE_COLUMNS = ("trial", "time_s", "position_m")
_EXPECTED_TEXT = (
    "expected columns: trial, time_s, position_m and exactly one of pressure_pa "
    "(commanded gauge pressure, Pa) or force_n (force, N), in any order"
)


def _sidecar_path(path: Path) -> Path:
    return path.with_suffix(".json")


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


def _read_sidecar(sidecar: Path) -> dict:
    where = str(sidecar)
    try:
        text = sidecar.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError(
            f"{where}: metadata sidecar is not valid UTF-8 ({exc.reason}); save it as UTF-8."
        ) from None
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(
            f"{where}: line {exc.lineno}, column {exc.colno}: metadata sidecar is not "
            f"valid JSON ({exc.msg}); fix the JSON or remove the sidecar."
        ) from None
    if not isinstance(meta, dict):
        raise DataError(
            f"{where}: line 1: metadata sidecar holds a JSON {type(meta).__name__}, not an "
            'object; wrap the metadata in {...} (e.g. {"description": "..."}).'
        )
    return meta


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

    trial = np.ascontiguousarray(table["trial"])
    time = np.ascontiguousarray(table["time_s"])
    n_rows = trial.size
    starts = np.concatenate(([0], np.flatnonzero(trial[1:] != trial[:-1]) + 1))
    ends = np.concatenate((starts[1:], [n_rows]))
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

    metadata: dict = {}
    sidecar = _sidecar_path(path)
    if sidecar != path and sidecar.is_file():
        metadata = _read_sidecar(sidecar)
        _check_metadata_rate(metadata, 1.0 / dt_ref, f"{sidecar} (metadata sidecar of {path.name})")

    ds = Dataset(
        time_s=ref,
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


# ----------------------------------------------------------------------------- NetCDF


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


# ----------------------------------------------------------------------------- dispatch

_READERS: dict[str, Callable[..., Dataset]] = {".csv": read_csv, ".nc": read_netcdf}
_WRITERS: dict[str, Callable[[Dataset, PathLike], None]] = {
    ".csv": write_csv,
    ".nc": write_netcdf,
}


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _READERS:
        raise DataError(
            f"{path}: unsupported file type {path.suffix or '(no suffix)'!r}; use .csv or .nc."
        )
    return suffix


def load(path: PathLike, **kwargs: Any) -> Dataset:
    """Read a data file, choosing the reader from the suffix.

    Parameters
    ----------
    path : str or os.PathLike
        ``.csv`` (:func:`read_csv`) or ``.nc`` (:func:`read_netcdf`), any case.
    **kwargs
        Forwarded to the reader (e.g. ``check_units=False``); unknown names raise
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
    return _READERS[_suffix(path)](path, **kwargs)


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
    _WRITERS[_suffix(path)](dataset, path)
