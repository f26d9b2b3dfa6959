"""The JSON sidecar beside a data file: where it is and how it is read (one object, UTF-8)."""

from __future__ import annotations

import json
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
