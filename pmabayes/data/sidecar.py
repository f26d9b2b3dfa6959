"""The JSON sidecar beside a data file: where it is and how it is read (one object, UTF-8);
and what is said about a file once per process (:func:`say_once`)."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

from pmabayes.data.dataset import (
    DataError,
)


def _sidecar_path(path: Path) -> Path:
    return path.with_suffix(".json")


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


#: What has been said, this process: (the file, what) pairs (:func:`say_once`).
_SAID: set[tuple[str, str]] = set()


def say_once(file: str, what: str, warning: Warning, skip: tuple[str, ...] = ()) -> bool:
    """Warn ``warning`` once per process for a file and a subject.

    A file read again by the same process (a command's second reading, a notebook's
    second cell) says nothing new, so it is said the first time only.

    Parameters
    ----------
    file : str
        The file the warning is about; its resolved path is the key, so that
        ``data/a.csv`` and ``./data/a.csv`` are one file.
    what : str
        What is said (e.g. the conversion), the key's second part: something new
        about the same file is said.
    warning : Warning
        The warning.
    skip : tuple of str
        Folders whose frames the warning skips (``skip_file_prefixes``), so that it
        points at the caller's line.

    Returns
    -------
    bool
        Whether it was said now.
    """
    key = (os.path.realpath(file), what)
    if key in _SAID:
        return False
    _SAID.add(key)
    warnings.warn(warning, skip_file_prefixes=skip)
    return True
