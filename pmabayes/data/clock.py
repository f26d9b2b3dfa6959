"""The data's clock: a grid of times as the file stores it (printed to a precision, or in
single precision) rebuilt as the uniform grid it rounds; and a lab's clock with jitter
and gaps read as a uniform grid with samples not observed, split into segments at gaps
longer than a sidecar's ``"max_gap_s"``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pmabayes.data.dataset import (
    _REL_TOL,
    DataError,
    DataWarning,
    _check_increasing,
    _first_nonuniform,
    _fmt,
)

#: rounded times must lie this close (in units of the printed step) to the rebuilt grid:
#: half a step of rounding, plus the fitted line's own error on short trials
_ROUNDING_SLACK = 0.6


def _shifted_clock(time: np.ndarray, metadata: dict, where: str, first_line: int,
                   declare: str) -> np.ndarray:
    """The times with the sidecar's ``"clock_shifts"`` applied, said in a warning.

    A DAQ that logs in blocks may stamp one block wrongly (a whole second late, say), so
    that the clock steps back after it. The lab declares which lines to move and by how
    much: ``"clock_shifts": [{"lines": [9001, 10000], "shift_s": -1.0}]``; nothing is
    moved that the sidecar does not name.
    """
    shifts = metadata.get("clock_shifts")
    if shifts is None:
        return time
    example = '"clock_shifts": [{"lines": [9001, 10000], "shift_s": -1.0}]'
    if not isinstance(shifts, list) or not shifts:
        raise DataError(f"{declare}: metadata 'clock_shifts' is {shifts!r}; it must be a list "
                        f"of the blocks of lines whose times move, e.g. {example}")
    last_line = first_line + time.size - 1
    out = np.array(time, dtype=float)
    said = []
    for k, item in enumerate(shifts):
        lines = item.get("lines") if isinstance(item, dict) else None
        shift = item.get("shift_s") if isinstance(item, dict) else None
        ok = (isinstance(lines, list) and len(lines) == 2
              and all(isinstance(v, int) and not isinstance(v, bool) for v in lines)
              and first_line <= lines[0] <= lines[1] <= last_line
              and isinstance(shift, int | float) and not isinstance(shift, bool)
              and np.isfinite(shift) and set(item) == {"lines", "shift_s"})
        if not ok:
            raise DataError(
                f"{declare}: clock_shifts[{k}] is {item!r}; each shift names its first and "
                f"last line of data (between {first_line} and {last_line}, the header not "
                f"counted as data) and the seconds added to their times, e.g. {example}")
        out[lines[0] - first_line:lines[1] - first_line + 1] += float(shift)
        said.append(f"lines {lines[0]}-{lines[1]} by {_fmt(float(shift))} s")
    warnings.warn(DataWarning(f"{where}: the clock's times moved as the sidecar's "
                              f"clock_shifts declares: {'; '.join(said)}"), stacklevel=4)
    return out


def _trial_blocks(trial: np.ndarray) -> list[tuple[int, int]]:
    """``(start, end)`` rows of each run of equal trial ids, in file order."""
    starts = np.concatenate(([0], np.flatnonzero(trial[1:] != trial[:-1]) + 1))
    ends = np.concatenate((starts[1:], [trial.size]))
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def _rounded_grid(
    trial: np.ndarray,
    time: np.ndarray,
    step_of: Callable[[], float | None],
    rate_hz: float | None,
    where: str,
    stored: str = "is printed to",
    fix: str = "Write times with more digits (or sample_rate_hz in the "
    "sidecar) to make this exact.",
) -> np.ndarray:
    """The times, rebuilt as ``t0 + k / rate`` where they are a uniform grid rounded to
    the precision they are stored with; unchanged where they are uniform already, or
    where they are not uniform even to that precision (the grid check then says where).

    A 750 Hz clock printed to microseconds (0.001333, 0.002667, ...) moves each interval
    by far more than the grid check's 1e-6 relative tolerance, yet the grid is uniform.
    ``step_of()`` gives that precision in s (called only when the grid is not uniform:
    it may be slow), ``stored`` and ``fix`` complete the warning: how the times are
    stored (CSV: printed; MATLAB: single precision), and how to make them exact.
    """
    blocks = [(s, e) for s, e in _trial_blocks(trial) if e - s >= 3]
    if all(_first_nonuniform(time[s:e]) is None for s, e in blocks):
        return time
    step = step_of()
    if step is None:
        return time
    out = np.array(time, dtype=float)
    for s, e in blocks:
        k = np.arange(e - s, dtype=float)
        t = time[s:e]
        if rate_hz:
            dt = 1.0 / float(rate_hz)
            t0 = float(np.mean(t - k * dt))
        else:
            dt, t0 = (float(c) for c in np.polyfit(k, t, 1))
        grid = t0 + k * dt
        tol = _ROUNDING_SLACK * step + 8 * np.finfo(float).eps * float(np.abs(t).max())
        if step > 0.1 * dt or np.abs(t - grid).max() > tol:
            return time  # a gap or jitter beyond the rounding: let the grid check report it
        out[s:e] = grid
    source = (
        f"the sidecar's sample_rate_hz = {float(rate_hz):g}"
        if rate_hz
        else f"a straight-line fit of the times, {1.0 / dt:.7g} Hz"
    )
    warnings.warn(
        DataWarning(
            f"{where}: time_s {stored} {step:g} s, so its intervals vary by up to "
            f"{step:g} s; the times are a uniform grid to that precision, so the grid was "
            f"rebuilt as t0 + k / rate from {source}. {fix}"
        ),
        stacklevel=4,
    )
    return out


# ----------------------------------------------------------------------------- a lab's clock

#: a DAQ clock whose times lie within this fraction of a step of a uniform grid is
#: that grid (its jitter); two samples further off it are not one uniform clock
_JITTER_STEPS = 0.1


@dataclass(frozen=True)
class _Gap:
    """Samples missing between two rows of one trial: ``after`` and ``before``."""

    block: int  # the trial's position in file order
    after: int  # row of the last sample before the gap
    before: int  # row of the first sample after it
    duration_s: float  # time between those two samples
    n_missing: int


@dataclass(frozen=True)
class _Segment:
    """One stretch of the record on one uniform grid: where each row lies on it."""

    time_s: np.ndarray  # the grid, (n_samples,)
    rows: np.ndarray  # the table's rows in this segment, in file order
    block: np.ndarray  # each row's trial position (0 .. n_trials - 1)
    index: np.ndarray  # each row's sample on the grid
    gaps: list[_Gap]  # samples missing inside the segment
    origin_s: float | None  # the clock reading subtracted from time_s, if any

    @property
    def n_samples(self) -> int:
        """Samples per trial on the grid."""
        return int(self.time_s.size)


def _step_of(d: np.ndarray, rate_hz: float | None) -> float:
    """The clock's step: the sidecar's rate, else the mean of the intervals near the median
    (the single steps: a block of them telescopes, so jitter averages out)."""
    if rate_hz:
        return 1.0 / float(rate_hz)
    med = float(np.median(d))
    single = d[(d > 0.5 * med) & (d < 1.5 * med)]
    return float(single.mean())


def _split(blocks: list[tuple[int, int]], time: np.ndarray, max_gap_s: float | None,
           label: Callable[[int], str], locate: Callable[[int], str],
           dt: float) -> list[list[tuple[int, int]]]:
    """Each segment's ``(start, end)`` rows per trial, cut at gaps longer than max_gap_s."""
    cuts = []
    for s, e in blocks:
        d = np.diff(time[s:e])
        cuts.append([] if max_gap_s is None else (np.flatnonzero(d > max_gap_s) + s + 1).tolist())
    first = cuts[0]
    for b, cut in enumerate(cuts[1:], start=1):
        s0, sb = blocks[0][0], blocks[b][0]
        same = len(cut) == len(first) and all(
            abs((time[c] - time[sb]) - (time[c0] - time[s0])) <= _JITTER_STEPS * dt
            for c, c0 in zip(cut, first, strict=True))
        if not same:
            lines = ", ".join(locate(c) for c in first) or "nowhere"
            other = ", ".join(locate(c) for c in cut) or "nowhere"
            raise DataError(
                f"{label(b)}: its gaps longer than max_gap_s = {max_gap_s:g} s start new "
                f"segments at {other}, but {label(0)} at {lines}; the trials of one file "
                "share one clock: split the file by trial, or raise max_gap_s.")
    segments = []
    for g in range(len(first) + 1):
        segments.append([(([s] + cut)[g], (cut + [e])[g]) for (s, e), cut in
                         zip(blocks, cuts, strict=True)])
    return segments


def _on_grid(parts: list[tuple[int, int]], time: np.ndarray, dt: float, fixed_rate: bool,
             label: Callable[[int], str], locate: Callable[[int], str]
             ) -> tuple[np.ndarray, float, float, np.ndarray, list[_Gap]]:
    """Each row's sample index on one grid ``t0 + k dt`` of the trials' rows ``parts``:
    the indices, the fitted ``t0`` (relative to the first row) and ``dt``, the residuals,
    the gaps. Raises where two samples are not on one uniform clock."""
    ks, gaps = [], []
    bad: tuple[int, str] | None = None
    for b, (s, e) in enumerate(parts):
        d = np.diff(time[s:e])
        n = np.rint(d / dt)
        frac = np.abs(d / dt - n)
        off = np.flatnonzero((n < 1) | (frac > 2 * _JITTER_STEPS))
        if off.size and (bad is None or s + off[0] < bad[0]):
            i = int(off[0]) + s
            steps = d[off[0]] / dt
            what = (f"a gap of {steps:.3f} steps ({_fmt(d[off[0]])} s), not a whole number: the "
                    "clock restarted after it; declare \"max_gap_s\" below "
                    f"{_fmt(d[off[0]])} in the sidecar to start a new segment there, or "
                    "resample onto a uniform grid" if n[off[0]] >= 2 else
                    f"an interval of {steps:.3f} steps ({_fmt(d[off[0]])} s), more than "
                    f"{_JITTER_STEPS:.0%} of a step off; a DAQ's jitter stays well within "
                    "that: check the time column, or resample onto a uniform grid")
            bad = (i + 1, f"{label(b)}: {locate(i + 1)}: time_s = {_fmt(time[i + 1])} comes "
                          f"after {_fmt(time[i])} on {locate(i)}: {what}.")
        k = np.concatenate(([0], np.cumsum(n))).astype(np.int64)
        ks.append(k)
        for j in np.flatnonzero(n >= 2):
            gaps.append(_Gap(b, s + int(j), s + int(j) + 1, float(d[j]), int(n[j]) - 1))
    if bad is not None:
        raise DataError(bad[1])
    s0 = parts[0][0]
    for b, (s, _) in enumerate(parts[1:], start=1):
        if abs(time[s] - time[s0]) > _JITTER_STEPS * dt:
            raise DataError(
                f"{label(b)}: {locate(s)}: time_s = {_fmt(time[s])} but {label(0)} has "
                f"{_fmt(time[s0])} at the same sample ({locate(s0)}); all trials must share "
                "the same sample times (start every trial's clock at the same value).")
    ends = [int(k[-1]) for k in ks]
    if len(set(ends)) > 1:
        listed = ", ".join(f"{label(b)}: {ends[b] + 1} samples to {locate(e - 1)}"
                           for b, (_, e) in enumerate(parts[:12]))
        raise DataError(
            f"{label(0)}: trials have unequal lengths on the clock's grid ({listed}); all "
            "trials must cover the same sample times; trim or split them to a common grid.")
    k = np.concatenate(ks)
    t = np.concatenate([time[s:e] for s, e in parts]) - time[s0]
    if fixed_rate:
        c = float(np.mean(t - k * dt))
    else:
        dt, c = (float(v) for v in np.polyfit(k, t, 1))
    r = t - (c + k * dt)
    far = np.abs(r) > _JITTER_STEPS * dt
    if far.any():
        i = int(np.argmax(far))
        b = int(np.searchsorted(np.cumsum([e - s for s, e in parts]), i, side="right"))
        row = parts[b][0] + i - sum(e - s for s, e in parts[:b])
        raise DataError(
            f"{label(b)}: {locate(row)}: time_s = {_fmt(time[row])} is {_fmt(r[i])} s "
            f"({r[i] / dt:+.3f} steps) off the uniform grid fitted to the times "
            f"({1 / dt:.7g} Hz), more than the {_JITTER_STEPS:.0%} of a step a DAQ's jitter "
            "may be: the clock changes its rate or samples at uneven times; resample onto "
            "a uniform grid.")
    return k, c, dt, r, gaps


def _clock_segments(
    trial: np.ndarray,
    time: np.ndarray,
    *,
    rate_hz: float | None,
    max_gap_s: float | None,
    label: Callable[[int], str],
    locate: Callable[[int], str],
) -> tuple[list[_Segment], str]:
    """A lab's clock as uniform grids: jitter within 10% of the step, gaps as missing
    samples, a new segment after each gap longer than ``max_gap_s``.

    ``trial`` gives each row's trial id (each trial's rows contiguous), ``time`` its time
    in s; ``label(b)`` names trial ``b`` (its position) and ``locate(row)`` a row (a
    file's line) for messages. Returns the segments and the note that says what was
    found (the gaps first, then the jitter). Raises :class:`DataError` for a clock that
    runs backwards, an interval or a time more than 10% of a step off the grid, trials
    that do not share their times.
    """
    blocks = _trial_blocks(trial)
    for b, (s, e) in enumerate(blocks):
        _check_increasing(time[s:e], label(b), lambda j, s=s: locate(s + j))
    d = np.concatenate([np.diff(time[s:e]) for s, e in blocks])
    dt = _step_of(d, rate_hz)
    origin = float(time[0])
    segments, worst = [], (0.0, 0, 0.0)
    for i, parts in enumerate(_split(blocks, time, max_gap_s, label, locate, dt), start=1):
        short = [b for b, (s, e) in enumerate(parts) if e - s < 2]
        if short:
            s = parts[short[0]][0]
            raise DataError(
                f"{label(short[0])}: segment #{i} holds only one sample ({locate(s)}), "
                f"between gaps longer than max_gap_s = {max_gap_s:g} s; a segment needs at "
                "least 2 samples: raise max_gap_s, or remove the lone sample.")
        k, c, step, r, gaps = _on_grid(parts, time, dt, bool(rate_hz), label, locate)
        n = int(k[: parts[0][1] - parts[0][0]][-1]) + 1
        rows = np.concatenate([np.arange(s, e) for s, e in parts])
        first = float(time[parts[0][0]])
        clean = float(np.abs(r).max()) <= _REL_TOL * step
        own = np.array(time[parts[0][0]:parts[0][1]], dtype=float)
        if clean and gaps:
            grid = np.linspace(first, float(own[-1]), n)
        elif clean and _first_nonuniform(own) is None:  # exact: kept, as the strict path does
            grid = own
        else:
            grid = first + c + np.arange(n) * step
        shift = None
        if _first_nonuniform(np.linspace(grid[0], grid[-1], n) if gaps else grid) is not None:
            shift = origin  # a clock reading too large for its step in double precision
            grid = (first - origin) + c + np.arange(n) * step
        j = int(np.argmax(np.abs(r)))
        if abs(r[j]) / step > worst[0]:
            worst = (abs(r[j]) / step, int(rows[j]), abs(r[j]))
        block = np.concatenate([np.full(e - s, b) for b, (s, e) in enumerate(parts)])
        segments.append(_Segment(grid, rows, block, k, gaps, shift))
    return segments, _clock_note(segments, worst, bool(rate_hz), label, locate, max_gap_s, time)


def _clock_note(segments: list[_Segment], worst: tuple, fixed_rate: bool,
                label: Callable[[int], str], locate: Callable[[int], str],
                max_gap_s: float | None, time: np.ndarray) -> str:
    """What the clock analysis found, in one message: gaps, segments, jitter."""
    gaps = [g for seg in segments for g in seg.gaps]
    step = float(segments[0].time_s[1] - segments[0].time_s[0])
    multi = len({int(b) for seg in segments for b in seg.block}) > 1
    out = []
    if gaps:
        missing = sum(g.n_missing for g in gaps)
        total = sum(seg.n_samples * (int(seg.block.max()) + 1) for seg in segments)
        # the trial's name alone ("trial 2"), without the file's that label starts with
        who = (lambda g: f"{label(g.block).rsplit(': ', 1)[-1]}, ") if multi else (lambda g: "")
        g0 = gaps[0]
        text = (f"{len(gaps)} gap{'s' if len(gaps) > 1 else ''} in the clock, "
                f"{_samples(missing)} not observed ({100 * missing / total:.3g}% of the grid): "
                f"{who(g0)}{_dur(g0.duration_s)} after {locate(g0.after)} "
                f"({_samples(g0.n_missing)} missing)")
        rest = gaps[1:]
        if rest:
            lo = min(g.duration_s for g in rest)
            hi = max(g.duration_s for g in rest)
            span = _dur(lo) if lo == hi else f"{_dur(lo)} to {_dur(hi)}"
            after = ", ".join(f"{who(g)}{locate(g.after)}" for g in rest[:4])
            text += (f", then {len(rest)} more of {span} (after {after}"
                     f"{', ...' if len(rest) > 4 else ''})")
        out.append(text + ". They are missing samples, not invented ones: Dataset.observed "
                   "is False and position_m NaN there, and the input follows the data set's "
                   "input_between_samples across them.")
    if len(segments) > 1:
        def span(i: int, seg: _Segment) -> str:
            rows = seg.rows[seg.block == 0]
            text = f"#{i} {locate(int(rows[0]))} to {locate(int(rows[-1]))}"
            if i == 1:
                return text
            before = segments[i - 2].rows[segments[i - 2].block == 0][-1]
            return f"{text} (after {_dur(float(time[rows[0]] - time[before]))})"
        parts = ", ".join(span(i, seg) for i, seg in enumerate(segments[:6], start=1))
        out.append(f"The gaps longer than max_gap_s = {max_gap_s:g} s split the record into "
                   f"{len(segments)} segments, each on its own grid: {parts}"
                   f"{', ...' if len(segments) > 6 else ''}.")
    if worst[0] > _REL_TOL:  # beyond the floating point of a clean clock
        source = "the sidecar's sample_rate_hz" if fixed_rate else "a straight-line fit"
        out.append(f"The times deviate from the uniform grid by up to {_dur(worst[2])} "
                   f"({worst[0]:.2g} steps, {locate(worst[1])}), within the "
                   f"{_JITTER_STEPS:.0%} of a step a DAQ clock's jitter may be: read as the "
                   f"uniform grid t0 + k / {1 / step:.7g} Hz ({source}).")
    if any(seg.origin_s is not None for seg in segments):
        origin = next(seg.origin_s for seg in segments if seg.origin_s is not None)
        out.append(f"The clock reads {origin:.6f} s at the first sample, too large for "
                   "its step in double precision: time_s counts from there (metadata "
                   "'time_origin_s').")
    return " ".join(out)


def _samples(n: int) -> str:
    """``"1 sample"``, ``"2 samples"``."""
    return f"{n} sample{'' if n == 1 else 's'}"


def _dur(seconds: float) -> str:
    """A duration for messages, in s, ms or µs."""
    a = abs(seconds)
    if a >= 1:
        return f"{seconds:.4g} s"
    if a >= 1e-3:
        return f"{seconds * 1e3:.4g} ms"
    return f"{seconds * 1e6:.3g} µs"
