"""A record as data sets: the rows of a file on its clock, placed on one uniform grid,
or, where the clock has gaps, on grids with samples not observed, one data set per
segment (a sidecar's ``"max_gap_s"`` splits the record at longer gaps).

A record whose every trial is uniformly sampled takes the strict path it always took
(the same arrays, the same metadata). Otherwise :func:`~pmabayes.data.clock._clock_segments`
reads the clock: jitter within 10% of a step, gaps as missing samples; what it found
is said in one :class:`~pmabayes.data.DataWarning`. The metadata records what was
read and converted (``"read_columns"``, ``"converted_units"``), which segment a data
set is (``"segment"``) and a clock origin subtracted (``"time_origin_s"``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pmabayes.data.clock import (
    _clock_segments,
    _dur,
    _rounded_grid,
    _samples,
    _Segment,
    _shifted_clock,
    _trial_blocks,
)
from pmabayes.data.dataset import (
    _REL_TOL,
    DataError,
    Dataset,
    DataWarning,
    _check_metadata_rate,
    _first_in_file_order,
    _first_nonuniform,
    _fmt,
    _max_gap_s,
    check_time_grid,
)
from pmabayes.data.plausibility import _checked
from pmabayes.data.text import _Table
from pmabayes.data.units import _HERE, converted, signed

#: how long a record must run without a gap for its initial state to be estimated
_ESTIMATE_S = 1.0


def _check_blocks(trial: np.ndarray, where: str, first: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each trial's first and end rows and its id; each trial contiguous, 2 rows or more."""
    starts, ends = (np.array(c, dtype=np.int64) for c in zip(*_trial_blocks(trial), strict=True))
    run_ids = trial[starts]
    first_line: dict[int, int] = {}
    for s, tid in zip(starts.tolist(), run_ids.tolist(), strict=True):
        if tid in first_line:
            raise DataError(
                f"{where}: line {s + first}: trial {tid} reappears after trial "
                f"{int(trial[s - 1])} (first seen on line {first_line[tid]}); each "
                "trial's rows must be contiguous: sort the rows by trial, then time_s."
            )
        first_line[tid] = s + first
    for s, e, tid in zip(starts.tolist(), ends.tolist(), run_ids.tolist(), strict=True):
        if e - s < 2:
            raise DataError(
                f"{where}: trial {tid} has only 1 sample (line {s + first}); every trial "
                "needs at least 2 samples."
            )
    return starts, ends, run_ids


def _shared_grid(
    trial: np.ndarray, time: np.ndarray, where: str, first: int = 2
) -> tuple[np.ndarray, np.ndarray, float]:
    """Trial ids in file order, the times as ``(n_trials, n_samples)``, the interval.

    Each trial's rows must be one contiguous block on a uniform grid, and all
    trials must share the first trial's sample times. ``first`` is the file's line
    of row 0.
    """
    trial = np.ascontiguousarray(trial)
    time = np.ascontiguousarray(time)
    starts, ends, run_ids = _check_blocks(trial, where, first)
    lengths = ends - starts
    dts = []
    for s, e, tid in zip(starts.tolist(), ends.tolist(), run_ids.tolist(), strict=True):
        dts.append(check_time_grid(time[s:e], source=f"{where}: trial {tid}",
                                   locate=lambda j, s=s: f"line {s + j + first}"))
    dt_ref = dts[0]

    if not (lengths == lengths[0]).all():
        listed = ", ".join(
            f"trial {tid}: {ln} (lines {s + first}-{s + ln + first - 1})"
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
            f"{where}: trial {int(run_ids[k])}: line {k * n_samples + j + first}: time_s = "
            f"{_fmt(times[k, j])} but trial {int(run_ids[0])} has {_fmt(ref[j])} at the "
            f"same sample (line {j + first}); all trials must share the same sample times "
            "(start every trial's clock at the same value)."
        )

    return run_ids, times, dt_ref


def _uniform(trial: np.ndarray, time: np.ndarray) -> bool:
    """Whether every trial's times are strictly increasing and uniform (the strict check)."""
    for s, e in _trial_blocks(trial):
        t = time[s:e]
        if (np.diff(t) <= 0).any() or _first_nonuniform(t) is not None:
            return False
    return True


def _positive_rate(metadata: dict) -> float | None:
    rate = metadata.get("sample_rate_hz")
    ok = isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0
    return float(rate) if ok else None


def _segment_source(path: Path, index: int, of: int) -> str:
    """``dir/stem#2.csv`` for segment 2 of ``dir/stem.csv``: ``Path(source).stem`` names it."""
    return str(path) if of == 1 else str(path.with_name(f"{path.stem}#{index}{path.suffix}"))


def _segment_metadata(metadata: dict, seg: _Segment, index: int, of: int, path: Path,
                      locate: Callable[[int], str]) -> dict:
    """The metadata of one segment: which one it is, and any clock origin subtracted."""
    meta = dict(metadata)
    if of > 1:
        first_trial = seg.rows[seg.block == 0]
        meta["segment"] = {"name": f"{path.stem}#{index}", "index": index, "of": of,
                           "first": locate(int(first_trial[0])),
                           "last": locate(int(first_trial[-1])),
                           "start_s": float(seg.time_s[0])}
    if seg.origin_s is not None:
        meta["time_origin_s"] = seg.origin_s
    return meta


def _check_estimate(metadata: dict, seg: _Segment, time: np.ndarray,
                    label: Callable[[int], str], locate: Callable[[int], str]) -> None:
    """An initial state estimated from a record's first second needs that second whole."""
    if metadata.get("initial_state") != "estimate":
        return
    for g in seg.gaps:
        start = time[seg.rows[seg.block == g.block][0]]
        if time[g.after] - start < _ESTIMATE_S:
            raise DataError(
                f"{label(g.block)}: initial_state 'estimate' estimates the state each trial "
                f"starts in from its first {_ESTIMATE_S:g} s, but the clock has a gap of "
                f"{_dur(g.duration_s)} after {locate(g.after)} ({_samples(g.n_missing)} "
                f"missing, {_dur(float(time[g.after] - start))} after the start); start the "
                f"record after the gap (a \"max_gap_s\" below {_fmt(g.duration_s)} s starts "
                "a new segment there) or declare another initial_state.")


def _clocked(
    trial: np.ndarray, time: np.ndarray, metadata: dict, *, where: str, split: bool,
    label: Callable[[int], str], locate: Callable[[int], str], declare: str,
) -> list[_Segment]:
    """The clock's segments, said once; refused when they are several and not asked for."""
    segments, note = _clock_segments(
        trial, time, rate_hz=_positive_rate(metadata),
        max_gap_s=_max_gap_s(metadata, declare), label=label, locate=locate)
    if len(segments) > 1 and not split:
        firsts = ", ".join(locate(int(seg.rows[0])) for seg in segments[:6])
        raise DataError(
            f"{where}: the record splits into {len(segments)} segments at gaps longer than "
            f"max_gap_s = {metadata['max_gap_s']:g} s (starting at {firsts}); read them "
            "with pmabayes.data.load_segments(path), one data set each, or remove max_gap_s "
            "to read one record with every gap as missing samples.")
    if note:
        warnings.warn(DataWarning(f"{where}: {note}"), skip_file_prefixes=_HERE)
    return segments


def _table_datasets(table: _Table, metadata: dict, path: Path, declare: str,
                    check_units: bool, split: bool = False) -> list[Dataset]:
    """A text file's table as data sets: one, or one per segment when ``split``."""
    where = str(path)
    _max_gap_s(metadata, declare)  # a bad declaration named where it is, before it is used
    first = table.first_line
    v = table.values
    rows = v["position_m"].size
    trial = v["trial"] if "trial" in v else np.ones(rows, dtype=np.int64)
    meta = dict(metadata)
    if table.read_columns is not None:
        # directives for reading this file, not for what is written
        del meta["columns"]
        meta.pop("columns_from", None)
        meta["read_columns"] = table.read_columns
    meta = converted(table.columns, where, meta, declare, table.headers)
    if table.time_origin is not None:
        meta["time_origin"] = table.time_origin
    rate = _positive_rate(metadata)
    starts, ends, run_ids = _check_blocks(trial, where, first)
    if "time_s" in v:
        stamped = _shifted_clock(v["time_s"], metadata, where, first, declare)
        time = _rounded_grid(trial, stamped, table.printed_step, rate, where)
    else:  # no time column: the sidecar's rate gives each trial its grid from 0
        time = np.concatenate([np.arange(e - s) for s, e in zip(starts, ends, strict=True)])
        time = time / rate
    columns = table.columns if "time_s" in v else {
        k: c for k, c in table.columns.items() if k != "time_s"}
    u, x = v[table.input_name], signed(v["position_m"], metadata, declare)
    if _uniform(trial, time):
        run_ids, times, dt_s = _shared_grid(trial, time, where, first)
        n_trials, n_samples = times.shape
        if metadata:
            _check_metadata_rate(metadata, 1.0 / dt_s,
                                 f"{path.with_suffix('.json')} (metadata sidecar of {path.name})")
        ds = Dataset(
            time_s=times[0],
            input=np.ascontiguousarray(u).reshape(n_trials, n_samples),
            position_m=np.ascontiguousarray(x).reshape(n_trials, n_samples),
            trial_ids=run_ids,
            input_name=table.input_name,
            metadata=meta,
            source=where,
        )
        return [_checked(ds, where,
                         lambda k, j: f"line {k * n_samples + j + first}, trial {int(run_ids[k])}",
                         declare, check_units, columns)]

    def label(b: int) -> str:
        return f"{where}: trial {int(run_ids[b])}" if "trial" in v else where

    def locate(r: int) -> str:
        return f"line {r + first}"

    segments = _clocked(trial, time, metadata, where=where, split=split, label=label,
                        locate=locate, declare=declare)
    out = []
    for i, seg in enumerate(segments, start=1):
        shape = (run_ids.size, seg.n_samples)
        arrays = [np.full(shape, np.nan) for _ in range(2)]
        for a, values in zip(arrays, (u, x), strict=True):
            a[seg.block, seg.index] = values[seg.rows]
        observed = np.zeros(shape, dtype=bool)
        observed[seg.block, seg.index] = True
        row_of = np.full(shape, -1)
        row_of[seg.block, seg.index] = seg.rows
        seg_meta = _segment_metadata(meta, seg, i, len(segments), path, locate)
        _check_estimate(seg_meta, seg, time, label, locate)
        ds = Dataset(time_s=seg.time_s, input=arrays[0], position_m=arrays[1],
                     trial_ids=run_ids, input_name=table.input_name, metadata=seg_meta,
                     source=_segment_source(path, i, len(segments)), observed=observed)

        def at(k: int, j: int, row_of: np.ndarray = row_of) -> str:
            r = int(row_of[k, j])
            where_j = locate(r) if r >= 0 else f"sample {j}, not observed"
            return f"{where_j}, trial {int(run_ids[k])}"

        out.append(_checked(ds, where, at, declare, check_units, columns))
    return out
