"""The commands' outputs and their one ending.

Every output path is checked before any work by :mod:`pmabayes.outputs`, whose rules
the Python API obeys too (never over a file pmabayes did not make). A command ends in
:func:`_finish`: its JSON summary and its page, each where an option asks for it and
each named, the time it took, and its exit status. The numbers a command prints (µm
side by side, the noise floor) are written here once.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from pmabayes.outputs import staged, write_json

__all__: list[str] = []


def _wrote(out: Path, names: Sequence[str], what: str = "") -> None:
    """Name every file written into a folder."""
    print(f"wrote {what + ' ' if what else ''}{out}{os.sep}: {', '.join(names)}")


def _finish(kind: str, *, summary: Mapping | None = None, js: Path | None = None,
            out: Path | None = None, page: Callable[[Path], object] | None = None,
            what: str = "", start: float | None = None, ok: bool = True) -> int:
    """The end of a command: its JSON summary (``summary`` at ``js``) and its page
    (written by ``page`` into a folder staged beside ``out``, moved in whole), each
    where an option asks for it and each named; the seconds since ``start``; and the
    exit status, 1 where part of the work failed (``ok`` False)."""
    if js is not None:
        write_json(js, summary or {}, kind)
        print(f"wrote {js}")
    if out is not None and page is not None:
        written: list[str] = []
        with staged(out, kind, written) as tmp:
            page(tmp)
        _wrote(out, written, what)
    if start is not None:
        print(f"({time.perf_counter() - start:.1f} s)")
    return 0 if ok else 1


def _floor_text(floor_m, rms_m: float | None = None) -> str:
    """``noise floor X µm``, with the digits that tell it from ``rms_m`` beside it."""
    if floor_m is None:
        return "no repeats"
    from pmabayes.util import format_together

    floor = format_together(floor_m * 1e6, *([] if rms_m is None else [rms_m * 1e6]))[0]
    return f"noise floor {floor} µm"


def _nan(record: dict) -> float:
    """A fit record's noise floor, NaN where it has none (None in the file)."""
    floor = record.get("noise_floor_m")
    return math.nan if floor is None else floor


def _um(*values_m: float) -> list[str]:
    """Lengths in µm side by side, with the digits that show their ratio."""
    from pmabayes.util import format_together

    return format_together(*(v * 1e6 for v in values_m))


def _print_adequacy(tree, datasets) -> None:
    from pmabayes.inference.fitfile import fit_info
    from pmabayes.report.verdicts import experiment_adequacy

    several = len(fit_info(tree).get("experiments") or [None]) > 1
    for name, adequacy in experiment_adequacy(tree, datasets=datasets):
        prefix = f"[{name}] " if several else ""
        print("\n".join(prefix + line for line in adequacy.lines()))
