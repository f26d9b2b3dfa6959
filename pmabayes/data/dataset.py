"""Data sets: trials on one uniform time grid, and the package's one time-grid check.

:class:`Dataset` validates what it holds (shapes, finite values, unique trial ids,
the time grid, which samples were observed); :class:`DataError` and
:class:`DataWarning` are the stage's error and warning. Reading and writing files is
:mod:`pmabayes.data.files`.
"""

from __future__ import annotations

import difflib
import json
import math
import numbers
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike

from pmabayes.data.rig import DEFAULT_INPUT_KIND, INPUT_OF_KIND, is_declared_rig, rig_problem

__all__ = ["INPUT_NAMES", "BETWEEN_SAMPLES", "METADATA_KEYS", "DataError", "DataWarning",
           "Dataset", "check_same_input_kind", "check_time_grid", "experiment_conditions"]

INPUT_NAMES: tuple[str, ...] = tuple(INPUT_OF_KIND.values())  # pressure_pa, force_n
"""Allowed names of the input column: commanded gauge pressure (Pa) or force (N)."""

_UNITS = {"time_s": "s", "pressure_pa": "Pa", "force_n": "N", "position_m": "m"}
_REL_TOL = 1e-6  # relative tolerance on sample intervals, sample times and sample rates

#: What an input does between its samples, as a sidecar's ``input_between_samples``
#: declares it: ``"hold"`` (the default: a DAQ's zero-order hold of a commanded
#: pressure), ``"linear"`` (the samples of a continuous signal, joined by lines) or
#: ``"bandlimited"`` (the samples of a continuous band-limited signal, reconstructed
#: between them: exactly, by FFT interpolation, where ``period_samples`` is declared).
BETWEEN_SAMPLES = ("hold", "linear", "bandlimited")
#: The state each trial starts from, as a sidecar's ``initial_state`` declares it:
#: ``"rest"`` (the default: at rest in static equilibrium under the first input
#: sample, as after a long hold of it) or ``"zero"`` (position, velocity and
#: hysteresis all zero whatever the first input: a plant at rest at zero input,
#: switched on at the first sample, as the Bouc-Wen benchmark's simulations start) or
#: ``"estimate"`` (unknown, as in a record that starts mid-loop: position, velocity and
#: hysteretic force at the first sample are identified with the model, from priors
#: set by the first samples; see :mod:`pmabayes.inference.likelihood`).
INITIAL_STATES = ("rest", "zero", "estimate")
#: The metadata (sidecar) keys pmabayes reads or writes; a key close to one of
#: these is taken for a misspelling. Any other key is free-form and kept.
#:
#: :meta hide-value:
METADATA_KEYS = ("description", "generator", "rig", "sample_rate_hz", "synthetic",
                 "pressure_reference", "ambient_pressure_pa", "check_units",
                 "converted_from_absolute", "input_between_samples", "period_samples",
                 "starts_in_steady_state", "initial_state", "mat_variables", "mat_trials",
                 "columns", "columns_from", "read_columns", "converted_units", "max_gap_s",
                 "segment", "time_origin_s", "time_origin", "position_reference",
                 "steady_state_tol_m", "max_warmup_periods", "warmup_s", "position_sign",
                 "position_zero_s", "position_zero", "disturbance_max_s", "disturbance_check",
                 "conditions", "selected_trials", "input_range", "clock_shifts", "written_by",
                 "calibration", "calibrated")


class DataError(ValueError):
    """Invalid or inconsistent data.

    Every message names the file (or the data set's source), the line (1-based,
    header = line 1) or the trial, and says how to fix the problem.

    Examples
    --------
    A clock that stops is refused, with the sample and the fix:

    >>> import numpy as np
    >>> from pmabayes.data import DataError, Dataset
    >>> try:
    ...     Dataset(time_s=np.array([0.0, 0.01, 0.01]), input=np.zeros((1, 3)),
    ...             position_m=np.zeros((1, 3)), trial_ids=np.array([1]))
    ... except DataError as error:
    ...     print(error)
    Dataset: sample 2: time_s = 0.01 is not after 0.01 on sample 1; times must be strictly
    increasing: sort by time and remove duplicate samples.
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
    _check_increasing(t, source, where, error)
    d = np.diff(t)
    i = _first_nonuniform(t)
    if i is not None:
        raise error(
            f"{source}: {where(i + 1)}: time_s is not uniformly sampled: interval "
            f"{_fmt(d[i])} s from {where(i)} differs from the median interval "
            f"{_fmt(np.median(d))} s by more than {_REL_TOL:g} relative (missing or "
            "duplicated sample?); resample onto a uniform grid."
        )
    return float(d.mean())


def _check_increasing(t: np.ndarray, source: str, where: Callable[[int], str],
                      error: type[Exception] = DataError) -> None:
    """Times must be strictly increasing; a clock that runs backwards names its line."""
    d = np.diff(t)
    if (d <= 0).any():
        j = int(np.argmax(d <= 0)) + 1
        back = " (the clock runs backwards)" if d[j - 1] < 0 else ""
        raise error(
            f"{source}: {where(j)}: time_s = {_fmt(t[j])} is not after {_fmt(t[j - 1])} "
            f"on {where(j - 1)}{back}; times must be strictly increasing: "
            f"{_late_block(t, j, where)}sort by time and remove duplicate samples."
        )


def _late_block(t: np.ndarray, j: int, where: Callable[[int], str]) -> str:
    """Where the clock steps back at ``j``: the block before it that a shift would put in
    order (stamped late, as a DAQ logging in blocks may), as the sidecar declaration
    that moves it; empty when no earlier interval is long enough or lines are not known."""
    step = float(t[j - 1] - t[j])
    d = np.diff(t[:j])
    # a block of samples stepping back by several intervals, not one sample out of place
    # (at the second sample there is no interval before it to compare)
    if not d.size or step <= 2 * float(np.median(d)) or not where(j).startswith("line "):
        return ""
    longer = np.flatnonzero(d > step)
    if longer.size == 0:
        return ""
    a = int(longer[-1]) + 1  # the block's first sample
    if j - a < 2:
        return ""
    lo, hi = -float(d[a - 1]), -step  # a shift inside (lo, hi) puts both edges in order
    whole = math.ceil(lo)  # a logging fault is often a whole second
    shift = float(whole) if lo < whole < hi else round((lo + hi) / 2, 6)
    first, last = where(a)[len("line "):], where(j - 1)[len("line "):]
    if not (first.isdigit() and last.isdigit()):
        return ""
    return (f"if {where(a)} to {last} were stamped late (the interval before them is "
            f"{_fmt(d[a - 1])} s), declare it in the sidecar: \"clock_shifts\": "
            f"[{{\"lines\": [{first}, {last}], \"shift_s\": {_fmt(shift)}}}]; otherwise ")


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


def _check_choice(metadata: dict, key: str, allowed: tuple, where: str, why: str) -> str:
    """A metadata value that must be one of ``allowed`` (the first is the default)."""
    value = metadata.get(key, allowed[0])
    if value not in allowed:
        raise DataError(f"{where}: metadata {key!r} is {value!r}; it must be one of "
                        f"{', '.join(map(repr, allowed))} ({why}).")
    return value


def _check_declarations(metadata: dict, where: str) -> None:
    """Metadata keys that look misspelt, and declarations pmabayes cannot honour."""
    for key in metadata:
        if key in METADATA_KEYS or not isinstance(key, str):
            continue
        close = difflib.get_close_matches(key, METADATA_KEYS, n=1, cutoff=0.85)
        if close:
            raise DataError(
                f"{where}: metadata key {key!r} looks like a misspelling of {close[0]!r}, "
                f"which pmabayes reads; rename it to {close[0]!r} (keys not close to one "
                "pmabayes reads are kept as free-form metadata).")
    _check_choice(metadata, "input_between_samples", BETWEEN_SAMPLES, where,
                  "'hold' for a commanded input held by the DAQ, 'linear' or 'bandlimited' "
                  "for samples of a continuous signal")
    period = metadata.get("period_samples")
    if period is not None and (isinstance(period, bool) or not isinstance(period, int)
                               or period < 2):
        raise DataError(
            f"{where}: metadata 'period_samples' is {period!r}; it must be a whole number of "
            "samples, at least 2: the length of one period of a periodic input. Remove it "
            "for a record that is not periodic.")
    steady = metadata.get("starts_in_steady_state", False)
    if not isinstance(steady, bool):
        raise DataError(
            f"{where}: metadata 'starts_in_steady_state' is {steady!r}; it must be true or "
            "false (JSON booleans, not strings).")
    initial = _check_choice(
        metadata, "initial_state", INITIAL_STATES, where,
        "'rest' for a trial that starts at rest under its first input sample, 'zero' for "
        "one that starts at zero position, velocity and hysteresis with the input switched "
        "on at the first sample, 'estimate' for one whose starting state is unknown, e.g. "
        "mid-loop")
    if initial == "estimate" and steady:
        raise DataError(
            f"{where}: metadata 'initial_state' is 'estimate' but 'starts_in_steady_state' is "
            "true; a record in periodic steady state has a known start (the steady state): "
            "remove one of them.")
    warmup = metadata.get("warmup_s")
    if warmup is not None and (isinstance(warmup, bool) or not isinstance(warmup, numbers.Real)
                               or not math.isfinite(warmup) or warmup < 0):
        raise DataError(
            f"{where}: metadata 'warmup_s' is {warmup!r}; it must be a number of seconds, at "
            "least 0: the samples in the record's first warmup_s seconds are left out of the "
            "likelihood (they still drive the simulation). Fix it, or remove it.")
    _positive_seconds(metadata, "disturbance_max_s", where,
                      "the longest correlation time the disturbance of a record without "
                      "repeats may have (as the rig's repeated records show it). Fix it, or "
                      "remove it to let the fit choose.")
    if steady and period is None:
        raise DataError(
            f"{where}: metadata 'starts_in_steady_state' is true but no 'period_samples' is "
            "declared; a steady state needs a periodic input: declare 'period_samples' (the "
            "samples in one period), or set 'starts_in_steady_state' to false.")
    if "position_zero_s" in metadata and "position_zero" in metadata:
        raise DataError(
            f"{where}: metadata 'position_zero' says the positions were referred to their "
            "reading at rest when the file was read, and 'position_zero_s' asks for it again; "
            "remove 'position_zero_s'.")
    if metadata.get("position_sign", 1) != 1:
        raise DataError(
            f"{where}: metadata 'position_sign' is {metadata['position_sign']!r}; it is applied "
            "when a file is read (pmabayes.data.load negates the positions of a file whose "
            "sidecar gives -1). A data set made in Python holds positions as pmabayes' x runs "
            "(growing as the pressure pushes): negate them yourself and leave the key out.")
    _max_gap_s(metadata, where)
    experiment_conditions(metadata, where)


def experiment_conditions(metadata: dict, where: str = "the data") -> dict[str, float]:
    """The experiment's declared conditions: the sidecar's ``"conditions"``, checked.

    An object of named numbers (``{"load_kg": 0.3, "order": 2, "supply_pa": 6e5}``)
    that says how this experiment differed from the others fitted with it. The
    joint fit's criticism (:mod:`pmabayes.criticism.experiments`) relates the
    parameters that move between experiments to them; a name ending in a unit
    suffix (``_kg``, ``_pa``, ``_s``) is read in that unit.

    Parameters
    ----------
    metadata : dict
        A data set's metadata.
    where : str
        The file, for messages.

    Returns
    -------
    dict of str to float
        Empty where none are declared.

    Raises
    ------
    DataError
        If ``"conditions"`` is not an object of finite numbers.
    """
    conditions = metadata.get("conditions")
    if conditions is None:
        return {}
    if not isinstance(conditions, dict):
        raise DataError(
            f"{where}: metadata 'conditions' is {conditions!r}; it must be an object of "
            'named numbers, e.g. "conditions": {"load_kg": 0.3, "order": 2}.')
    out = {}
    for key, value in conditions.items():
        if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                or not math.isfinite(value)):
            raise DataError(
                f"{where}: metadata 'conditions' gives {key!r} as {value!r}; each condition "
                f'must be a finite number in SI units (e.g. "{key}": 0.3); put words in '
                "'description' instead.")
        out[str(key)] = float(value)
    return out


def _max_gap_s(metadata: dict, where: str) -> float | None:
    """The metadata's ``max_gap_s`` (None when not declared), checked."""
    return _positive_seconds(metadata, "max_gap_s", where,
                             "a gap in the clock longer than it starts a new segment "
                             "(pmabayes.data.load_segments). Fix it, or remove it to keep "
                             "every gap as missing samples of one record.")


def _positive_seconds(metadata: dict, key: str, where: str, meaning: str) -> float | None:
    """The metadata's ``key``, a positive number of seconds (None when not declared),
    checked; ``meaning`` ends the message of a bad one."""
    value = metadata.get(key)
    if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)
                              or not math.isfinite(value) or value <= 0):
        raise DataError(f"{where}: metadata '{key}' is {value!r}; it must be a positive "
                        f"number of seconds: {meaning}")
    return None if value is None else float(value)


def _check_period(metadata: dict, n_samples: int, where: str) -> None:
    """A declared period must fit the record: whole periods, at least one."""
    period = metadata.get("period_samples")
    if period is None:
        return
    if period > n_samples:
        state = ("starts in steady state, and is " if metadata.get("starts_in_steady_state")
                 else "")
        raise DataError(
            f"{where}: metadata 'period_samples' is {period} but the record {state}only "
            f"{n_samples} samples long, shorter than one period; record at least one whole "
            "period, or correct 'period_samples'.")
    if n_samples % period:
        raise DataError(
            f"{where}: metadata 'period_samples' is {period}, which does not divide the "
            f"record's {n_samples} samples ({n_samples / period:.4g} periods); keep whole "
            f"periods only (trim the record to {n_samples // period * period} samples) or "
            "correct 'period_samples'.")


def _check_rig(metadata: dict, input_name: str, where: str) -> None:
    """A sidecar ``rig`` must follow the rig's schema (:mod:`pmabayes.data.rig`) and drive
    the data's input column: pressure_pa or force_n. Free-form notes about the rig (no
    rig key) are kept unchecked."""
    rig = metadata.get("rig")
    if not is_declared_rig(rig):
        return
    problem = rig_problem(rig)
    if problem:
        raise DataError(f"{where}: metadata 'rig': {problem}")
    kind = rig.get("input_kind", DEFAULT_INPUT_KIND)
    expected = INPUT_OF_KIND[kind]
    if expected == input_name:
        return
    other = next(k for k, v in INPUT_OF_KIND.items() if v == input_name)
    name = rig.get("name", "the rig")
    raise DataError(
        f"{where}: metadata 'rig' ({name}) has input_kind {kind!r}, which drives "
        f"{expected!r}, but the data's input is {input_name!r}; fix the rig in the sidecar "
        f"(a {other}-driven rig has \"input_kind\": \"{other}\") or the data's input "
        f"(rename the column to {expected!r} if it really holds "
        f"{'pressure in Pa' if kind == 'pressure' else 'force in N'}).")


def dataset_list(datasets: Dataset | Iterable[Dataset], none_given: Exception
                 ) -> list[Dataset]:
    """One data set or several, as a list of at least one, each checked to be a Dataset.

    Parameters
    ----------
    datasets : Dataset or iterable of Dataset
        The data, one data set per experiment.
    none_given : Exception
        Raised when ``datasets`` is empty (its type and message are the caller's).

    Returns
    -------
    list of Dataset

    Raises
    ------
    Exception
        ``none_given``, with no data set.
    TypeError
        If an item is not a Dataset.
    """
    datasets = [datasets] if isinstance(datasets, Dataset) else list(datasets)
    if not datasets:
        raise none_given
    for ds in datasets:
        if not isinstance(ds, Dataset):
            raise TypeError(f"datasets must be pmabayes.data.Dataset objects, got "
                            f"{type(ds).__name__}")
    return datasets


def check_same_input_kind(datasets: Sequence[Dataset]) -> str:
    """Check that experiments fitted together have one input kind.

    Pressure-driven muscles and force-driven oscillators have different parameters
    (a force input has no dead zone ``p_dz``) and different units, so one fit cannot
    share parameters across them.

    Parameters
    ----------
    datasets : sequence of Dataset
        The experiments of one fit, at least one.

    Returns
    -------
    str
        Their common input name, ``"pressure_pa"`` or ``"force_n"``.

    Raises
    ------
    TypeError
        If an element is not a :class:`Dataset`.
    DataError
        If no data set is given, or two have different inputs; the message names the
        first file of each kind.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.data import Dataset, DataError, check_same_input_kind
    >>> t = np.arange(4) * 0.01
    >>> muscle = Dataset(time_s=t, input=np.full((1, 4), 2e5), position_m=np.zeros((1, 4)),
    ...                  trial_ids=np.array([1]))
    >>> oscillator = Dataset(time_s=t, input=np.ones((1, 4)), position_m=np.zeros((1, 4)),
    ...                      trial_ids=np.array([1]), input_name="force_n")
    >>> check_same_input_kind([muscle, muscle])
    'pressure_pa'
    >>> try:
    ...     check_same_input_kind([muscle, oscillator])
    ... except DataError as error:
    ...     print(error)
    experiment 2: its input is 'force_n' but experiment 1 has 'pressure_pa'; ... fit them
    separately.
    """
    datasets = list(datasets)
    for d in datasets:
        if not isinstance(d, Dataset):
            raise TypeError(f"check_same_input_kind needs Dataset objects, got "
                            f"{type(d).__name__}")
    if not datasets:
        raise DataError("no data sets given: a fit needs at least one experiment.")
    first = datasets[0]
    for i, d in enumerate(datasets[1:], start=2):
        if d.input_name != first.input_name:
            raise DataError(
                f"{d.source or f'experiment {i}'}: its input is {d.input_name!r} but "
                f"{first.source or 'experiment 1'} has {first.input_name!r}; the experiments "
                "of one fit share their physical parameters, so they must have one input "
                "kind (all pressure-driven, or all force-driven): fit them separately.")
    return first.input_name


class DataWarning(UserWarning):
    """Data that read correctly but look suspect (e.g. absolute instead of gauge pressure).

    Every message names the file, the trial and the fix, and how to declare the
    data right when the suspicion is wrong.

    Examples
    --------
    Converting a lab's units is said once, as a warning the caller may record (or turn
    into an error with ``warnings.simplefilter("error", DataWarning)``):

    >>> import warnings
    >>> from pathlib import Path
    >>> from pmabayes.data import DataWarning, read_csv
    >>> rows = [f"1,{10 * k},{k % 5},{k % 5 / 10}" for k in range(20)]
    >>> _ = Path("psi.csv").write_text("\\n".join(["Trial,Time (ms),Pressure (psi),Position (mm)",
    ...                                           *rows]))
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     data = read_csv("psi.csv")
    >>> caught[0].category is DataWarning
    True
    >>> print(caught[0].message)
    psi.csv: units converted to SI on reading, as the column names say: 'Time (ms)' x 0.001
    -> time_s (s); 'Pressure (psi)' x 6894.757293 -> pressure_pa (Pa); 'Position (mm)' x 0.001
    -> position_m (m). ...
    """


def _first_in_file_order(mask: np.ndarray) -> tuple[int, int]:
    """First ``(trial index, sample index)`` where a 2-D mask is true, row-major."""
    k, j = np.unravel_index(int(np.argmax(mask)), mask.shape)
    return int(k), int(j)


def _fill_unobserved(u: np.ndarray, observed: np.ndarray, between: str) -> np.ndarray:
    """The input at samples not observed, rebuilt from each trial's observed samples.

    ``"hold"``: the last observed value, held (a DAQ's zero-order hold);
    ``"linear"``: the line between the observed samples either side. Every trial's
    first and last samples are observed (checked before).
    """
    out = np.array(u, dtype=np.float64, copy=True)
    k = np.arange(u.shape[1])
    for row, seen in zip(out, observed, strict=True):
        if seen.all():
            continue
        if between == "hold":
            row[~seen] = row[np.maximum.accumulate(np.where(seen, k, 0))][~seen]
        else:
            row[~seen] = np.interp(k[~seen], k[seen], row[seen])
    return out


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
    observed : numpy.ndarray or None, optional
        Which samples were measured, boolean ``(n_trials, n_samples)``; None (the
        default) means all of them. A sample not observed is a sample the record
        does not hold (a gap in the lab's clock), never an invented one: its position
        is NaN, and its input is rebuilt from the trial's observed samples as
        ``input_between_samples`` says (``"hold"``: the last one held;
        ``"linear"``: the line between the two either side; ``"bandlimited"`` cannot
        cross a gap and is refused). Values passed at such samples are replaced. Each
        trial's first and last samples must be observed.

    Raises
    ------
    DataError
        If shapes, dtypes or values are invalid: non-finite values at observed
        samples, time not strictly increasing or not uniform, duplicate trial ids,
        unknown ``input_name``, a trial that does not start and end with an observed
        sample, or ``"bandlimited"`` input with samples not observed.

    Notes
    -----
    Arrays are stored as read-only float64 (``trial_ids``: int64; ``observed``: bool)
    copies. Two data sets compare equal when all fields except ``source`` are equal.
    With samples not observed, the time grid is stored as
    ``np.linspace(time_s[0], time_s[-1], n_samples)``: a file holds only the
    observed samples' times, so the grid is defined by its ends and written and read
    back exactly.

    Examples
    --------
    Two trials of four samples at 100 Hz, built in memory (:func:`pmabayes.data.save`
    writes them to a file pmabayes reads):

    >>> import numpy as np
    >>> from pmabayes.data import Dataset
    >>> data = Dataset(time_s=np.arange(4) * 0.01,
    ...                input=np.array([[0.0, 1e5, 2e5, 1e5]] * 2),
    ...                position_m=np.array([[0.0, 1.0, 3.0, 2.0], [0.0, 1.1, 3.1, 2.1]]) * 1e-3,
    ...                trial_ids=np.array([1, 2]))
    >>> data
    Dataset(n_trials=2, n_samples=4, dt_s=0.01, input_name='pressure_pa', trial_ids=[1, 2],
            source=None)
    >>> data.position_m.mean(axis=0)  # the trial mean, in m
    array([0.     , 0.00105, 0.00305, 0.00205])
    """

    time_s: np.ndarray
    input: np.ndarray
    position_m: np.ndarray
    trial_ids: np.ndarray
    input_name: str = "pressure_pa"
    metadata: dict = field(default_factory=dict)
    source: str | None = None
    observed: np.ndarray | None = None

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
        _check_declarations(self.metadata, where)
        _check_rig(self.metadata, self.input_name, where)

        time_s = self._as_float(self.time_s, "time_s", where)
        grid_dt_s = check_time_grid(time_s, source=where)
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

        observed = self._observed(arrays["position_m"].shape, ids, where)
        for name, a in arrays.items():
            bad = ~np.isfinite(a) & observed
            if bad.any():
                k, j = _first_in_file_order(bad)
                raise DataError(
                    f"{where}: {name} of trial {ids[k]} is {a[k, j]} at sample {j}; "
                    "all values must be finite (no NaN or inf); a sample that was not "
                    "measured is marked by observed=, not by its value."
                )
        if not observed.all():
            between = self.metadata.get("input_between_samples", "hold")
            if between == "bandlimited":
                raise DataError(
                    f"{where}: input_between_samples is 'bandlimited' but "
                    f"{int((~observed).sum())} samples are not observed; a band-limited "
                    "reconstruction needs every sample. Declare \"input_between_samples\": "
                    "\"linear\" (the samples joined by lines across a gap) or \"hold\", or "
                    "split the record at its gaps (\"max_gap_s\", pmabayes.data.load_segments).")
            arrays["input"] = _fill_unobserved(arrays["input"], observed, between)
            arrays["position_m"][~observed] = np.nan
            time_s = np.linspace(time_s[0], time_s[-1], n)
        for name, a in (("time_s", time_s), ("trial_ids", ids), ("observed", observed),
                        *arrays.items()):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "metadata", dict(self.metadata))
        object.__setattr__(self, "source", source)
        object.__setattr__(self, "_grid_dt_s", grid_dt_s)
        _check_metadata_rate(self.metadata, self.sample_rate_hz, f"{where}: metadata")
        _check_period(self.metadata, n, where)
        if self.warmup_s >= float(time_s[-1] - time_s[0]):
            raise DataError(
                f"{where}: metadata 'warmup_s' is {_fmt(self.warmup_s)} s but the record is "
                f"only {_fmt(time_s[-1] - time_s[0])} s long; the warm-up would leave nothing "
                "to fit: shorten 'warmup_s'.")

    def _observed(self, shape: tuple[int, int], ids: np.ndarray, where: str) -> np.ndarray:
        """The ``observed`` mask, checked: boolean, of the data's shape, each trial
        observed at its first and last sample."""
        if self.observed is None:
            return np.ones(shape, dtype=bool)
        mask = np.asarray(self.observed)
        if mask.dtype != bool or mask.shape != shape:
            raise DataError(
                f"{where}: observed must be a boolean array of shape {shape} (n_trials, "
                f"n_samples), True where a sample was measured; got dtype {mask.dtype} "
                f"and shape {mask.shape}.")
        ends = mask[:, [0, -1]].all(axis=1)
        if not ends.all():
            k = int(np.argmin(ends))
            which = "first" if not mask[k, 0] else "last"
            raise DataError(
                f"{where}: trial {ids[k]}: its {which} sample is not observed; a record "
                "starts and ends with a measured sample: trim the unobserved samples off "
                "its ends.")
        return np.array(mask, dtype=bool, copy=True)

    @staticmethod
    def _as_float(value: Any, name: str, where: str) -> np.ndarray:
        """Return a float64 copy of a real numeric array, else raise DataError."""
        a = np.asarray(value)
        if a.dtype.kind not in "iuf":
            raise DataError(f"{where}: {name} must be a real numeric array; got dtype {a.dtype}.")
        return np.array(a, dtype=np.float64, copy=True)

    # -- properties

    @property
    def input_between_samples(self) -> str:
        """What the input does between samples, from the metadata (``"hold"`` by default).

        See :data:`BETWEEN_SAMPLES`; :func:`pmabayes.simulate` takes it as
        ``between_samples``.
        """
        return self.metadata.get("input_between_samples", "hold")

    @property
    def period_samples(self) -> int | None:
        """Samples in one period of a periodic input, from the metadata; None if not periodic.

        A sidecar's ``"period_samples": N`` declares that each trial holds whole periods
        of one periodic input (N divides ``n_samples``).
        """
        return self.metadata.get("period_samples")

    @property
    def n_periods(self) -> int | None:
        """Whole periods per trial, or None when the input is not declared periodic."""
        period = self.period_samples
        return None if period is None else self.n_samples // period

    @property
    def starts_in_steady_state(self) -> bool:
        """Whether each trial starts in periodic steady state (metadata; default False).

        True: the plant had been driven by the periodic input long before the record
        began, so a simulation runs through periods from rest first. False: each trial
        starts from rest and its first period holds the transient.
        """
        return bool(self.metadata.get("starts_in_steady_state", False))

    @property
    def initial_state(self) -> str:
        """The state each trial starts from, from the metadata (``"rest"`` by default).

        See :data:`INITIAL_STATES`: ``"rest"`` is static equilibrium under the first
        input sample, ``"zero"`` is zero position, velocity and hysteresis. With
        ``starts_in_steady_state`` it is the state the warm-up starts from.
        :func:`pmabayes.simulate` takes it as ``initial_state``.
        """
        return self.metadata.get("initial_state", "rest")

    @property
    def warmup_s(self) -> float:
        """Seconds at the start of each trial left out of the likelihood (metadata; 0).

        A sidecar's ``"warmup_s"`` declares a warm-up: the samples with ``time_s <
        time_s[0] + warmup_s`` still drive the simulation, but the likelihood treats
        them as not observed (an unknown start's transient, a sensor settling).
        """
        return float(self.metadata.get("warmup_s", 0.0))

    @property
    def source_file(self) -> str | None:
        """The file the data were read from: :attr:`source`, less a segment's ``#i``
        (``dir/stem#2.csv`` is a segment of ``dir/stem.csv``); None without a source.

        Trial ids, and what is said once about a file, belong to the file.
        """
        if self.source is None:
            return None
        seg = self.metadata.get("segment")
        if isinstance(seg, dict) and isinstance(seg.get("name"), str) and "#" in seg["name"]:
            path = Path(self.source)
            return str(path.with_name(seg["name"].rpartition("#")[0] + path.suffix))
        return self.source

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
    def grid_dt_s(self) -> float:
        """The sample interval the simulator integrates with: the mean interval of
        ``time_s``, as :func:`check_time_grid` found it when the data set was made."""
        return self._grid_dt_s

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
    def n_missing(self) -> int:
        """Samples not observed, over all trials (0 for a complete record)."""
        return int(self.observed.size - np.count_nonzero(self.observed))

    @property
    def counted(self) -> np.ndarray:
        """The samples a likelihood and its criticism take, ``(n_trials, n_samples)``.

        :attr:`observed`, less the declared warm-up (:attr:`warmup_s`): those samples
        still drive the simulation but are not data for the model.
        """
        if not self.warmup_s:
            return np.array(self.observed)
        return self.observed & (self.time_s - self.time_s[0] >= self.warmup_s)[None, :]

    @property
    def mean_position_m(self) -> np.ndarray:
        """Position averaged over trials, shape ``(n_samples,)``.

        With samples not observed, the mean of the trials observed at each sample
        (NaN where none is).
        """
        if not self.n_missing:
            return self.position_m.mean(axis=0)
        n = self.observed.sum(axis=0)
        total = np.where(self.observed, self.position_m, 0.0).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, total / n, np.nan)

    @property
    def noise_floor_m(self) -> float:
        """RMS error a perfect model would have against the trial mean.

        Estimated from the spread between repeated trials: the root of the
        time-averaged sample variance across trials divided by the number of
        trials. NaN with a single trial (no spread to estimate it from). With
        samples not observed, each sample's variance is over the trials observed
        there and divided by their number, averaged over the samples observed in
        two trials or more (NaN if there are none).
        """
        if self.n_trials < 2:
            return math.nan
        if not self.n_missing:
            var = self.position_m.var(axis=0, ddof=1).mean()
            return float(math.sqrt(var / self.n_trials))
        n = self.observed.sum(axis=0)
        both = n >= 2
        if not both.any():
            return math.nan
        x = self.position_m[:, both]
        seen = self.observed[:, both]
        k = n[both]
        mean = np.where(seen, x, 0.0).sum(axis=0) / k
        var = np.where(seen, (x - mean) ** 2, 0.0).sum(axis=0) / (k - 1)
        return float(math.sqrt(float(np.mean(var / k))))

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
            observed=self.observed[idx] if self.n_missing else None,
        )

    def to_xarray(self) -> xr.Dataset:
        """Convert to an :class:`xarray.Dataset`.

        Returns
        -------
        xarray.Dataset
            Dimensions ``("trial", "time_s")`` with coordinates ``trial`` (the trial
            ids) and ``time_s``; data variables named after the input (``pressure_pa``
            or ``force_n``) and ``position_m``, each with a ``units`` attribute, and,
            only when samples are not observed, the boolean ``observed`` (position
            NaN where it is False); attributes ``input_name`` and ``metadata_json``
            (the metadata as JSON). Arrays are writable copies.

        Raises
        ------
        DataError
            If the metadata cannot be stored as JSON exactly.
        """
        meta = _json_roundtrip_check(self.metadata, self.source or "Dataset")
        dims = ("trial", "time_s")
        data_vars = {
            self.input_name: (dims, self.input.copy(), {"units": _UNITS[self.input_name]}),
            "position_m": (dims, self.position_m.copy(), {"units": "m"}),
        }
        if self.n_missing:
            data_vars["observed"] = (dims, self.observed.copy())
        return xr.Dataset(
            data_vars=data_vars,
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
            variables ``position_m`` and exactly one of ``pressure_pa`` or ``force_n``,
            and optionally the boolean ``observed``. An optional ``metadata_json``
            attribute holds the metadata.
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
        extra = sorted(names - {"position_m", inputs[0], "observed"})
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
        for name in (input_name, "position_m", *(["observed"] if "observed" in names else [])):
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
        observed = None
        if "observed" in names:
            observed = ds["observed"].transpose("trial", "time_s").values
            if observed.dtype.kind in "iu" and np.isin(observed, (0, 1)).all():
                observed = observed.astype(bool)  # a NetCDF writer may store bool as int
        return cls(
            time_s=ds["time_s"].values,
            input=ds[input_name].transpose("trial", "time_s").values,
            position_m=ds["position_m"].transpose("trial", "time_s").values,
            trial_ids=ds["trial"].values,
            input_name=input_name,
            metadata=metadata,
            source=source,
            observed=observed,
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
            and np.array_equal(self.observed, other.observed)
            and np.array_equal(self.position_m, other.position_m, equal_nan=True)
        )

    __hash__ = None  # type: ignore[assignment]  # mutable metadata, array fields

    def __repr__(self) -> str:
        """Short summary (no array contents)."""
        return (
            f"Dataset(n_trials={self.n_trials}, n_samples={self.n_samples}, "
            f"dt_s={self.dt_s:.6g}, input_name={self.input_name!r}, "
            f"trial_ids={self.trial_ids.tolist()!r}, source={self.source!r}"
            + (f", n_missing={self.n_missing})" if self.n_missing else ")")
        )
