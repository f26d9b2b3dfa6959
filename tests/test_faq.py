"""The messages that ``docs/faq.md`` quotes are the package's own, verbatim: each is
triggered again here, on the same small files, and must appear on the page as printed."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import pmabayes.data as d
from pmabayes.data import DataError, DataWarning
from pmabayes.model.model import assumed_rig

ROOT = Path(__file__).resolve().parents[1]
HEADER = "trial,time_s,pressure_pa,position_m"
RIG = {"rig": {"name": "b", "moving_mass_kg": 0.067, "gravity_sign": 1, "area_m2": 2e-4,
               "input_kind": "pressure"}}
T = np.arange(200) / 100
P = 2e5 * (1 - np.cos(2 * np.pi * 0.5 * T))
X = 0.01 * (1 - np.cos(2 * np.pi * 0.5 * T)) + 1e-5 * np.sin(40 * T)


def _rows(p=P, x=X, t=T):
    return [(k, f"{a:.3f}", f"{b:.1f}", f"{c:.6f}")
            for k in (1, 2) for a, b, c in zip(t, p, x, strict=True)]


def _changed(row: int, column: int, value: str) -> list:
    rows = _rows()
    rows[row] = tuple(value if i == column else v for i, v in enumerate(rows[row]))
    return rows


def _swapped() -> list:
    rows = _rows()
    rows[30], rows[31] = rows[31], rows[30]
    return rows


#: file name -> (header, rows, sidecar): the files the FAQ's messages come from
FILES = {
    "missing_column": (HEADER.rsplit(",", 1)[0], [r[:3] for r in _rows()], RIG),
    "stroke": ("Trial,Time (s),Pressure (psi),Stroke (mm)",
                     _rows(p=P / 6894.757, x=X * 1e3), RIG),
    "centimetres": ("trial,time_s,pressure_pa,position_cm", _rows(x=X * 100), RIG),
    "text_value": (HEADER, _changed(57, 2, "n/a"), RIG),
    "nan_value": (HEADER, _changed(120, 3, "nan"), RIG),
    "time_back": (HEADER, _swapped(), RIG),
    "unequal": (HEADER, _rows()[:-20], RIG),
    "empty": (HEADER, [], RIG),
    "jitter": (HEADER, _rows(t=T + np.where(np.arange(200) == 80, 0.004, 0)), RIG),
    "mpa": (HEADER, [(a, b, f"{float(c) / 1e6:.6f}", e) for a, b, c, e in _rows()], RIG),
    "mm": (HEADER, [(a, b, c, f"{float(e) * 1e3:.4f}") for a, b, c, e in _rows()], RIG),
    "misspelt": (HEADER, _rows(), {**RIG, "sample_rate": 100}),
    "force_rig": (HEADER, _rows(), {"rig": {**RIG["rig"], "input_kind": "force"}}),
    "absolute": (HEADER, _rows(p=P + 101325), RIG),
    "norig": (HEADER, _rows(), None),
}


def _write(name: str) -> str:
    header, rows, sidecar = FILES[name]
    Path(f"{name}.csv").write_text(
        header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    if sidecar is not None:
        Path(f"{name}.json").write_text(json.dumps(sidecar))
    return f"{name}.csv"


def _quoted() -> list[str]:
    """The messages of the page: the text of its ``message`` blocks."""
    text = (ROOT / "docs" / "faq.md").read_text()
    return re.findall(r"```\{code-block\} text\n:class: message\n\n(.*?)\n```", text, re.S)


def test_the_page_quotes_every_file_s_message():
    quoted = _quoted()
    assert len(quoted) == len(FILES) + 1  # and the refused validation, below
    for name in FILES:
        assert any(f"{name}.csv" in q for q in quoted), name


@pytest.mark.parametrize("name", sorted(FILES))
def test_a_quoted_message_is_what_pmabayes_prints(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = _write(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        try:
            assumed_rig(d.load(path))
        except (DataError, DataWarning) as caught:
            printed = f"{type(caught).__name__}: {caught}"
        else:
            pytest.fail(f"{path} raised and warned nothing")
    assert printed in _quoted(), printed


def test_the_refused_validation_is_quoted_as_the_package_words_it():
    """The fit it needs takes too long here (``tests/test_newcomer.py`` triggers the
    refusal); its fixed wording is checked against the source."""
    quoted = next(q for q in _quoted() if q.startswith("pmabayes validate: error:"))
    source = (ROOT / "pmabayes" / "criticism" / "validation.py").read_text()
    for words in ("not held out and the numbers would ", "(on the command line: "):
        assert words in source and words in quoted, words
