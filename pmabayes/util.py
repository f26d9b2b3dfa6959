"""Small pieces every stage shares: cache fingerprints, progress lines, core counts.

This module is at the bottom of the house: it imports nothing from pmabayes, so any
stage may use it. Each piece exists once here; do not write another.

Progress has one switch, :func:`show_progress`: inside it, every stage's
:class:`Progress` prints (the command line turns it on unless ``--quiet``; an API
call's ``progress=True`` turns it on for that call). Outside it the library is
silent, as a library should be.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import math
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy

__all__ = ["fingerprint", "source_text", "local_cores", "busy_workers", "Progress", "show_progress",
           "progress_shown", "finite_or_none", "side_stream", "format_together"]


def _feed(h, part) -> None:
    import numpy as np  # here, so that importing this module stays quick

    if isinstance(part, np.ndarray):
        h.update(str((part.dtype.str, part.shape)).encode())
        h.update(np.ascontiguousarray(part).tobytes())
    elif isinstance(part, bytes):
        h.update(part)
    elif isinstance(part, str):
        h.update(part.encode())
    else:
        h.update(json.dumps(part, sort_keys=True, default=str).encode())
    h.update(b"\x00")  # parts never run into each other


def finite_or_none(value) -> float | None:
    """A number as a JSON value: the float, or None where it is NaN or infinite.

    Parameters
    ----------
    value : float
        Any real number (a numpy scalar too).

    Returns
    -------
    float or None
    """
    value = float(value)
    return value if math.isfinite(value) else None


def format_together(*values: float, digits: int = 3, most: int = 8) -> list[str]:
    """Numbers printed side by side, with the significant digits that show their ratio.

    Each is printed to ``digits`` significant digits, more where two that differ by
    more than 0.1% would print the same (``1e+03`` twice for 1004 and 998 at one
    digit), up to ``most``. Values that are not finite print as ``nan``/``inf``.

    Parameters
    ----------
    *values : float
        The numbers, already in the unit they are printed in.
    digits : int
        Fewest significant digits.
    most : int
        Most significant digits.

    Returns
    -------
    list of str
        One per value, in order.
    """
    nums = [float(v) for v in values]

    def clash(n: int) -> bool:
        text = [f"{v:.{n}g}" for v in nums]
        return any(text[i] == text[j] and math.isfinite(a) and math.isfinite(b)
                   and abs(a - b) > 1e-3 * max(abs(a), abs(b))
                   for i, a in enumerate(nums) for j, b in enumerate(nums) if i < j)

    n = max(int(digits), 1)
    while n < most and clash(n):
        n += 1
    return [f"{v:.{n}g}" for v in nums]


def side_stream(rng: numpy.random.Generator, key: int) -> numpy.random.Generator:
    """A generator independent of ``rng`` that leaves ``rng`` as it was.

    ``rng.spawn`` advances the count of children its seed sequence has spawned, so a
    step added to a pipeline would change every later spawn's stream, and with it
    results that do not depend on that step. This child of the same entropy, keyed by
    ``key``, does not: the same ``rng`` and ``key`` give the same stream.

    Parameters
    ----------
    rng : numpy.random.Generator
        The caller's generator (made from a seed sequence, as ``default_rng`` makes it).
    key : int
        Which side stream (non-negative; distinct per purpose).

    Returns
    -------
    numpy.random.Generator
    """
    import numpy as np  # not at the top: the CLI's start does not need numpy

    seq = rng.bit_generator.seed_seq
    return np.random.default_rng(np.random.SeedSequence(
        seq.entropy, spawn_key=(*seq.spawn_key, 2**32 + int(key)),
        pool_size=seq.pool_size))


def fingerprint(*parts, length: int = 16) -> str:
    """A short SHA-256 hex digest of ``parts``, the one cache key of pmabayes.

    Parameters
    ----------
    *parts : object
        Arrays (dtype, shape and bytes are hashed), bytes, strings, or anything
        JSON can write (dicts with sorted keys; other objects by ``str``).
    length : int
        Number of hex digits to keep (at most 64).

    Returns
    -------
    str
        The digest's first ``length`` hex digits.
    """
    h = hashlib.sha256()
    for part in parts:
        _feed(h, part)
    return h.hexdigest()[:length]


def source_text(obj) -> str:
    """The source of the file that defines ``obj``, for keys that must change with code.

    The whole defining file is read, so helpers that ``obj`` calls are covered too.

    Parameters
    ----------
    obj : object
        A function (numba dispatchers are unwrapped), class or module.

    Returns
    -------
    str
        The file's text; where no source can be read, a string unique to this
        process (``module.qualname:id``), so that a cache entry is never reused.
    """
    fn = getattr(obj, "py_func", obj)
    try:
        return Path(inspect.getsourcefile(fn)).read_text()
    except (OSError, TypeError):
        name = getattr(fn, "__qualname__", getattr(fn, "__name__", type(fn).__name__))
        return f"{getattr(fn, '__module__', '?')}.{name}:{id(fn)}"


def local_cores() -> int:
    """The number of cores this process may use (its CPU affinity where known).

    Returns
    -------
    int
        At least 1.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


#: in a local worker of :class:`pmabayes.parallel.Runner`: the count, shared between
#: its workers, of their tasks running now (a ``multiprocessing`` value); else None
_BUSY: list = [None]


def busy_workers() -> int | None:
    """How many tasks the workers of this process's runner are running now (this one's
    among them); None outside a runner's worker.

    A worker simulates in the cores its busy siblings leave
    (:func:`pmabayes.model.simulator.simulation_threads`): at the end of a batch of
    uneven tasks, the last one left takes the idle cores.

    Returns
    -------
    int or None
    """
    busy = _BUSY[0]
    return None if busy is None else max(1, int(busy.value))


#: the progress switch: the task whose progress is shown, or None for silence
_SHOWN: list[str | None] = [None]
#: a status line (:meth:`Progress.status`) is redrawn at most this often on a terminal,
#: and written as a line of its own at most this often elsewhere (a log, a pipe)
_STATUS_EVERY_S = 0.5
_LOGGED_EVERY_S = 10.0
#: whether a bar is drawn on the current line (a line said meanwhile starts a new one)
_BAR_OPEN: list[bool] = [False]


@contextlib.contextmanager
def show_progress(task: str = "", enabled: bool = True) -> Iterator[None]:
    """Show the progress of every stage inside the block, the one switch of progress.

    Parameters
    ----------
    task : str
        Shown in the prefix of the stages that do not name their own
        (``[pmabayes TASK]``); the command's name on the command line.
    enabled : bool
        With False the block changes nothing (whatever is on stays on).

    Examples
    --------
    >>> with show_progress("fit"):
    ...     Progress().say("global search")  # doctest: +SKIP
    [pmabayes fit] global search
    """
    if not enabled:
        yield
        return
    before = _SHOWN[0]
    _SHOWN[0] = task
    try:
        yield
    finally:
        _SHOWN[0] = before


def progress_shown() -> bool:
    """Whether the progress switch is on (:func:`show_progress`).

    Returns
    -------
    bool
    """
    return _SHOWN[0] is not None


class Progress:
    """Progress lines and bars on stderr, all with one prefix: ``[pmabayes TASK]``.

    A stage makes one where it starts; it prints when the switch is on
    (:func:`show_progress`) or when ``enabled`` is True, and nothing otherwise. On a
    terminal a status line and a bar are redrawn in place; written to a file or a pipe,
    each state is a line of its own, a status at most every 10 s and a bar at its start,
    each quarter and its end, so that a log stays readable.

    Parameters
    ----------
    task : str, optional
        What runs (``"fit"``, ``"diagnose"``, ``"robustness"``...); by default the
        task the switch was turned on for.
    enabled : bool
        Print even with the switch off.
    stream : file-like, optional
        Where to write; standard error by default.

    Examples
    --------
    >>> p = Progress("fit")
    >>> p.say("global search and MAP ...")
    >>> p.start(10, "runs")
    >>> p.advance(10)
    """

    def __init__(self, task: str | None = None, enabled: bool = False, *, stream=None) -> None:
        self.task = task if task is not None else (_SHOWN[0] or "")
        self.enabled = bool(enabled) or _SHOWN[0] is not None
        self.stream = stream
        self.total = 0
        self.done = 0
        self.unit = ""
        self.label = ""
        self.t0 = time.perf_counter()

    @property
    def prefix(self) -> str:
        """The prefix of every line, ``[pmabayes TASK]``."""
        return f"[pmabayes {self.task}]" if self.task else "[pmabayes]"

    def _out(self):
        return self.stream if self.stream is not None else sys.stderr

    def _live(self) -> bool:
        """Whether the output is a terminal, where a line can be redrawn."""
        try:
            return bool(self._out().isatty())
        except (AttributeError, ValueError):
            return False

    def say(self, text: str) -> None:
        """Print one line.

        Parameters
        ----------
        text : str
            The message, without the prefix.
        """
        if self.enabled:
            head = "\n" if _BAR_OPEN[0] else ""
            _BAR_OPEN[0] = False
            print(f"{head}{self.prefix} {text}", file=self._out(), flush=True)

    def status(self, text: str) -> None:
        """Rewrite the current line with ``text``: the state of a stage whose length
        is not known in advance (the next line said, or :meth:`end`, ends it).

        Parameters
        ----------
        text : str
            The state, without the prefix.
        """
        now = time.perf_counter()
        live = self._live()
        every = _STATUS_EVERY_S if live else _LOGGED_EVERY_S
        if self.enabled and now - getattr(self, "_shown", -math.inf) >= every:
            self._shown = now
            if not live:
                self.say(text)
                return
            line = f"{self.prefix} {text}"
            pad = " " * max(getattr(self, "_width", 0) - len(line), 0)
            self._width = len(line)
            _BAR_OPEN[0] = True
            print(f"\r{line}{pad}", end="", file=self._out(), flush=True)

    def end(self) -> None:
        """End a line left open by :meth:`status` or an unfinished bar."""
        if self.enabled and _BAR_OPEN[0]:
            _BAR_OPEN[0] = False
            print(file=self._out(), flush=True)

    def start(self, total: int, unit: str = "steps", label: str = "") -> None:
        """Begin a bar of ``total`` units.

        Parameters
        ----------
        total : int
            Number of units to do.
        unit : str
            What a unit is, for the bar's text.
        label : str
            Shown after the count.
        """
        self.total, self.done, self.unit, self.label = int(total), 0, unit, label
        self.t0, self._quarter = time.perf_counter(), 0
        self._draw()

    def advance(self, n: int = 1) -> None:
        """Mark ``n`` more units done and redraw the bar.

        Parameters
        ----------
        n : int
            Units just finished.
        """
        self.done += int(n)
        self._draw()

    def _draw(self) -> None:
        if not self.enabled:
            return
        frac = self.done / max(self.total, 1)
        bar = "#" * int(round(30 * frac))
        elapsed = time.perf_counter() - self.t0
        finished = self.done >= self.total
        left = ""
        if 0 < self.done < self.total:  # the pace so far, for what remains
            left = f", about {elapsed / self.done * (self.total - self.done):.0f} s left"
        line = (f"{self.prefix} [{bar:-<30}] {self.done}/{self.total} {self.unit} "
                f"({elapsed:.0f} s{left}) {self.label}".rstrip())
        if not self._live():
            quarter = int(4 * frac)
            if self.done == 0 or finished or quarter > getattr(self, "_quarter", 0):
                self._quarter = quarter
                self.say(line.removeprefix(f"{self.prefix} "))
            return
        _BAR_OPEN[0] = not finished
        print(f"\r{line}", end="\n" if finished else "", file=self._out(), flush=True)
