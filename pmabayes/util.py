"""Small pieces every stage shares: cache fingerprints, progress lines, core counts.

This module is at the bottom of the house: it imports nothing from pmabayes, so any
stage may use it. Each piece exists once here; do not write another.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["fingerprint", "source_text", "local_cores", "Progress", "finite_or_none"]


def _feed(h, part) -> None:
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


class Progress:
    """Progress lines and bars on stderr, all with one prefix: ``[pmabayes TASK]``.

    Parameters
    ----------
    task : str
        What runs (``"fit"``, ``"diagnose"``, ``"robustness"``...).
    enabled : bool
        Print nothing when False.
    stream : file-like, optional
        Where to write; standard error by default.

    Examples
    --------
    >>> p = Progress("fit", enabled=False)
    >>> p.say("global search and MAP ...")
    >>> p.start(10, "runs")
    >>> p.advance(10)
    """

    def __init__(self, task: str, enabled: bool = True, *, stream=None) -> None:
        self.task = task
        self.enabled = bool(enabled)
        self.stream = stream
        self.total = 0
        self.done = 0
        self.unit = ""
        self.label = ""
        self.t0 = time.perf_counter()

    @property
    def prefix(self) -> str:
        """The prefix of every line, ``[pmabayes TASK]``."""
        return f"[pmabayes {self.task}]"

    def _out(self):
        return self.stream if self.stream is not None else sys.stderr

    def say(self, text: str) -> None:
        """Print one line.

        Parameters
        ----------
        text : str
            The message, without the prefix.
        """
        if self.enabled:
            print(f"{self.prefix} {text}", file=self._out(), flush=True)

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
        self.t0 = time.perf_counter()
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
        end = "\n" if self.done >= self.total else ""
        print(f"\r{self.prefix} [{bar:-<30}] {self.done}/{self.total} {self.unit} "
              f"({time.perf_counter() - self.t0:.0f} s) {self.label}".rstrip(), end=end,
              file=self._out(), flush=True)
