"""Delimited text files read into a table of SI columns: a CSV whose header names its
columns, or a headerless file whose columns a sidecar's ``"columns"`` map names.

Column names carry their unit (:data:`pmabayes.data.units.UNITS`): ``time_ms``,
``pressure_psi``, ``position_mm`` are read and converted to ``time_s``,
``pressure_pa``, ``position_m``; a header may write them as people do
(``Time (s)``, ``Pressure (psi)``, ``Position [mm]``, ``Trial``: case and spaces free,
:func:`pmabayes.data.units.header_name`). A header pmabayes does not recognise is
refused with a sidecar ``"columns"`` map for it as the alternative. A headerless file
(comma- or whitespace-separated, one value a line included) is read only through
``"columns"``, which names columns by number from 1, e.g. ``{"columns": {"3":
"time_s", "4": "pressure_psi", "5": "position_mm"}}`` (and ``"trial"`` for a column of
trial ids); columns it does not name are not read, and a first line that is not
numbers (the lab's own header) is skipped. Signals kept in separate files are read
beside it, row for row, through the sidecar's ``"columns_from"`` (each other file's
name to a map of its columns), or in Python with :func:`read_columns`.

Fields may be separated by commas, semicolons, tabs or (a headerless file) white
space, as the first line shows (:func:`_separator`); where they are not separated by
commas, a comma in a number is its decimal mark (``0,5``, as a spreadsheet saves in
many locales; said once per file). Lines starting with ``#`` above the header (an
instrument's preamble) are skipped and said; double quotes around fields are CSV's
own syntax and are read through.
"""

from __future__ import annotations

import decimal
import difflib
import json
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmabayes.data.dataset import INPUT_NAMES, DataError, DataWarning
from pmabayes.data.sidecar import say_once
from pmabayes.data.units import (
    _HERE,
    UNITS,
    _record,
    _said,
    header_name,
    quantity,
    role_problems,
    to_si,
    unit_guess,
    unknown_unit,
)

__all__ = ["read_columns"]

_EXPECTED_TEXT = (
    "expected columns: trial, time_s, position_m and exactly one of pressure_pa "
    "(commanded gauge pressure, Pa) or force_n (force, N), in any order; a name may "
    "carry another unit (time_ms, pressure_kpa, pressure_psi, position_mm, force_kn, ...: "
    "pmabayes.data.UNITS), trial may be left out for one trial, and time_s when the "
    "sidecar gives sample_rate_hz"
)
_ROLES = ("trial", "time_s", "position_m")


@dataclass(frozen=True)
class _Table:
    """A text file's rows as SI columns, and how they were read."""

    values: dict[str, np.ndarray]  # SI name (or "trial") -> one value per row
    columns: dict[str, str]  # SI name -> the file's name for it
    input_name: str
    first_line: int  # the file's line of row 0
    printed_step: Callable[[], float | None]  # the time column's printed precision, in s
    read_columns: dict[str, str] | None = None  # a headerless file's "columns" map
    headers: dict[str, str] = field(default_factory=dict)  # name -> the header's own text
    time_origin: str | None = None  # a time column of dates: its first, ISO 8601


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return "_" not in text


#: What a position column's bad value may be fixed with: a row missing from the clock.
_DROPOUT = (" A position the sensor did not measure (a dropout) is a sample not observed: "
            "delete its row, and the gap it leaves in the time column is read as one (said "
            "on reading; nothing is filled in).")


def _raise_nonfinite(where: str, lineno: int, name: str, text: str) -> None:
    raise DataError(
        f"{where}: line {lineno}, column {name}: value {text.strip()!r} is NaN or "
        "infinite; missing or saturated samples must be handled before import "
        "(nothing is dropped or filled in automatically)."
        + (_DROPOUT if "position" in name else "")
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


def _lines(path: Path, where: str) -> tuple[list[str], int]:
    """The file's lines below its preamble (lines starting with ``#`` at the top, said
    once), trailing blank lines dropped, and how many preamble lines there were."""
    lines = _read_text(path, where).replace("\r\n", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    skipped = 0
    while skipped < len(lines) and lines[skipped].lstrip().startswith("#"):
        skipped += 1
    if skipped and skipped == len(lines):
        raise DataError(f"{where}: every line starts with '#' (notes, no data); the header "
                        "and the rows of samples go below the notes.")
    if skipped:
        say_once(where, "preamble", DataWarning(
            f"{where}: lines 1-{skipped} start with '#' (the instrument's or the lab's "
            f"notes above the data) and were skipped; line {skipped + 1} is read as the "
            "first line."), _HERE)
    return lines[skipped:], skipped


#: Field separators looked for in a file's first line, in this order: a file that has
#: semicolons or tabs there is separated by them (a spreadsheet's export where the comma
#: is the decimal mark; LabVIEW's spreadsheet files), else by commas; a line with none
#: is split at white space.
_SEPARATORS = (";", "\t", ",")
_SEPARATOR_NAMES = {";": "semicolon", "\t": "tab", ",": "comma", None: "whitespace"}


def _separator(line: str) -> str | None:
    """The field separator of a file whose first line (header or data) is ``line``:
    :data:`_SEPARATORS`' first that it holds between its first and last field (a tab
    or a space a logger leaves at a line's end separates nothing), or None (white
    space)."""
    line = line.strip()
    return next((sep for sep in _SEPARATORS if sep in line), None)


def _headerless_separator(line: str) -> str | None:
    # numbers only: tabs are white space, however many stand between two columns
    separator = _separator(line)
    return None if separator == "\t" else separator


def _numeric(line: str, columns: list[int]) -> bool:
    """Whether ``line`` holds numbers in those of ``columns`` (from 1) it has, however it
    is separated (a column beyond its width is the caller's clearer error)."""
    separator = _headerless_separator(line)
    fields = _split(_plain(line, separator), separator)
    # a line narrower than every column named: its own fields tell
    held = [fields[k - 1].strip() for k in columns if k <= len(fields)] or fields
    return bool(held) and all(_is_number(f.strip()) for f in held)


def _split(line: str, separator: str | None) -> list[str]:
    return line.split(separator) if separator else line.split()


def _plain(line: str, separator: str | None) -> str:
    """``line`` as numpy reads it: quotes removed, and a comma read as the decimal mark
    where it does not separate the fields."""
    line = line.replace('"', "")
    return line if separator == "," else line.replace(",", ".")


def _read_through(rows: list[str], separator: str | None, where: str,
                  first_line: int) -> list[str]:
    """The data rows as numpy reads them: CSV's double quotes removed (a number has
    none to lose) and, where the fields are not separated by commas, a comma in a
    number read as its decimal mark (said once per file)."""
    if separator == "," or not any("," in r for r in rows):
        return [_plain(r, separator) for r in rows] if any('"' in r for r in rows) else rows
    both = next((i for i, r in enumerate(rows) if "." in r and "," in r), None)
    if both is not None:
        raise DataError(
            f"{where}: line {both + first_line}: numbers written with both '.' and ',' "
            f"({rows[both].strip()!r}): with {_SEPARATOR_NAMES[separator]}-separated "
            "fields ',' is read as the decimal mark, so a '.' cannot be one too; save the "
            "file with one decimal mark and no thousands separator.")
    say_once(where, "decimal comma", DataWarning(
        f"{where}: numbers read with ',' as the decimal mark (0,5 is 0.5), as the fields "
        f"are {_SEPARATOR_NAMES[separator]}-separated."), _HERE)
    return [_plain(r, separator) for r in rows]


def _check_blank(rows: list[str], where: str, first_line: int) -> None:
    for i, line in enumerate(rows):
        if not line.strip():  # np.loadtxt would skip blank lines silently
            raise DataError(
                f"{where}: line {i + first_line} is blank; remove blank lines between data rows."
            )


def _printed_step(rows: list[str], column: int, delimiter: str | None = ",") -> float | None:
    """The finest decimal step the time column is printed with (1e-6 for 0.001333)."""
    exponents = set()
    for line in rows:
        try:
            exponents.add(decimal.Decimal(_split(line, delimiter)[column].strip())
                          .as_tuple().exponent)
        except (decimal.InvalidOperation, IndexError):
            return None
    finest = min(exponents)
    return 10.0 ** finest if isinstance(finest, int) else None


# ----------------------------------------------------------------------------- with a header


def _canonical(text: str) -> str:
    """The name pmabayes reads for a header field (``Pressure (psi)`` -> ``pressure_psi``),
    or the field itself where it is not one (named as it is in messages)."""
    name = header_name(text)
    if name is not None and (name in UNITS or name == "trial" or quantity(name)):
        return name
    return text.strip()


def _columns_example(raw: list[str], names: list[str], roles: list[str]) -> str:
    """A sidecar ``"columns"`` map for this header: each column recognised by its
    name, each other by a guess from its unit or spelling (left out without one)."""
    spec = {}
    for i, (text, name) in enumerate(zip(raw, names, strict=True)):
        guess = name if name in UNITS or name == "trial" else unit_guess(text, roles)
        if guess is not None and guess not in spec.values():  # a second one: not read
            spec[str(i + 1)] = guess
    return json.dumps({"columns": spec})


def _unquoted(field: str) -> str:
    field = field.strip()
    return field[1:-1].strip() if len(field) > 1 and field[0] == field[-1] == '"' else field


def _parse_header(fields: list[str], where: str, has_rate: bool = False, line: int = 1,
                  rename: Callable[[list[str]], list[str]] | None = None
                  ) -> tuple[list[str], str, dict[str, str]]:
    """Validate the header (file line ``line``); return the column names (as
    :data:`UNITS` spells them), the input's SI name and the header's own text of each
    name it spells otherwise. ``rename`` reads a sensor's signal as the quantity its
    calibration gives (:class:`~pmabayes.data.calibration.SignalNames`)."""
    problems = []
    raw = [_unquoted(f) for f in fields]
    if all(_is_number(n) for n in raw if n):
        raise DataError(
            f"{where}: line {line}: expected a header line such as "
            f"'trial,time_s,pressure_pa,position_m', got {','.join(fields)!r}; "
            "add the header as the first line (or name a headerless file's columns in the "
            'sidecar: "columns": {"1": "time_s", ...}).'
        )
    spelt = [_canonical(n) if n else n for n in raw]
    names = rename(spelt) if rename is not None else spelt
    for i, n in enumerate(names):
        if not n:
            problems.append(f"column {i + 1} has an empty name (a stray separator?)")
    seen: dict[str, int] = {}
    unread = False
    for i, n in enumerate(names):
        if n and n in seen:
            j = seen[n]
            both = (f" ({raw[j]!r} and {raw[i]!r} are both {n})" if raw[i] != raw[j] else "")
            problems.append(f"column {n!r} appears twice (columns {j + 1} and {i + 1}){both}: "
                            "read one, the one measured")
            unread = True  # the map below reads the first; the message says which to read
        seen.setdefault(n, i)
    present = {UNITS[n][0] for n in names if n in UNITS} | ({"trial"} & set(names))
    inputs = [n for n in INPUT_NAMES if n in present]
    problems += role_problems(list(dict.fromkeys(n for n in names if n)))
    absent = [n for n in _ROLES if n not in present]
    candidates = absent + ([] if inputs else list(INPUT_NAMES))
    for text, n in zip(raw, names, strict=True):
        if not n or n in UNITS or n == "trial":
            continue
        if quantity(n):  # a unit no map can convert: the fix is in the values
            read = f"{text!r} is {n}: " if text != n else ""
            problems.append(read + unknown_unit(n))
            continue
        unread = True
        guess = unit_guess(text, candidates)
        hint = f" ('{text}' looks like '{guess}')" if guess else ""
        problems.append(f"unexpected column {text!r}{hint}")
    for n in absent:
        if n == "position_m" or (n == "time_s" and not has_rate):
            problems.append(f"missing column {n!r}")
    if not inputs:
        problems.append("missing input column: need one of 'pressure_pa' or 'force_n' (or "
                        "the same in other units)")
    if problems:
        columns = ""
        if unread:
            columns = (
                " Or keep the header and name the columns in a sidecar "
                f"{Path(where).with_suffix('.json').name} beside it, by number from 1 (the "
                "header line is then skipped, and columns it does not name are not read), e.g. "
                f"{_columns_example(raw, names, candidates)}")
        raise DataError(
            f"{where}: line {line} (header): " + "; ".join(problems) + f". The {_EXPECTED_TEXT}; "
            "rename, add or remove columns to match." + columns
        )
    headers = {n: text for text, n, m in zip(raw, names, spelt, strict=True)
               if text != n and n == m}  # a calibrated signal's conversion is its own
    return names, inputs[0], headers


def _scan_rows(lines: list[str], names: list[str], where: str, first_line: int = 2,
               separator: str | None = ",") -> None:
    """Slow row-by-row scan that raises for the first bad line (called on failure)."""
    ncol = len(names)
    i64 = np.iinfo(np.int64)
    for i, line in enumerate(lines):
        lineno = i + first_line
        fields = _split(line, separator)
        if len(fields) != ncol:
            what = "is blank" if not line.strip() else f"has {len(fields)} fields"
            raise DataError(
                f"{where}: line {lineno} {what}; every row needs {ncol} "
                f"{_SEPARATOR_NAMES[separator]}-separated fields ({','.join(names)}). Fix "
                "or remove the row."
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
                    "write plain decimal numbers (e.g. 0.25 or 1.5e5) in the column's unit."
                    + (_DROPOUT if not t and "position" in name else "")
                )
            if not math.isfinite(float(t)):
                _raise_nonfinite(where, lineno, name, text)


def _parse_rows(rows: list[str], names: list[str], where: str, first_line: int = 2,
                separator: str | None = ",") -> np.ndarray:
    """The rows (file line ``first_line`` on) as a structured array of finite values
    (``trial`` as int64)."""
    dtype = [(n, np.int64 if n == "trial" else np.float64) for n in names]
    try:
        table = np.loadtxt(rows, delimiter=separator, dtype=dtype, comments=None, ndmin=1)
    except ValueError as exc:
        _scan_rows(rows, names, where, first_line, separator)
        raise DataError(
            f"{where}: could not parse the data rows ({exc}; numpy counts rows from 0 at "
            f"line {first_line}). Write plain {_SEPARATOR_NAMES[separator]}-separated "
            "numbers."
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
        _raise_nonfinite(where, r + first_line, n, _split(rows[r], separator)[names.index(n)])

    return table


def _units_row(line: str, separator: str | None, width: int) -> list[str] | None:
    """A line of units under the header (``s,kPa,mm`` or ``[s];[bar];[mm]``, a field
    empty where a column has none), or None where ``line`` is not one."""
    units = [_unquoted(u).strip("[]() ") for u in _split(line, separator)]
    if len(units) != width or not any(units) or any(_is_number(u) for u in units):
        return None
    return units


def _parse_header_lines(lines: list[str], separator: str | None, where: str, has_rate: bool,
                        header: int, clock: int | None = None,
                        rename: Callable[[list[str]], list[str]] | None = None
                        ) -> tuple[list[str], str, dict[str, str], int]:
    """:func:`_parse_header` of the header line, or of it with the line of units below it
    where the names alone are not read and the two together are (``Time`` over ``s``
    reads as ``Time (s)``); also how many lines below the header it took (0 or 1).
    Where a line of units is there and the two together are not read either, their
    error is raised: it names the units it read."""
    fields = _split(lines[0], separator)
    if clock is not None:  # a clock of dates, read as seconds from its first
        names, input_name, headers = _parse_header(
            [f if i != clock else "time_s" for i, f in enumerate(fields)], where, has_rate,
            header, rename)
        return names, input_name, {**headers, "time_s": _unquoted(fields[clock])}, 0
    try:
        return (*_parse_header(fields, where, has_rate, header, rename), 0)
    except DataError:
        units = _units_row(lines[1], separator, len(fields)) if len(lines) > 1 else None
        if units is None:
            raise
        joined = [f"{_unquoted(f)} ({u})" if u else f for f, u in zip(fields, units,
                                                                         strict=True)]
        # where both fail, the error of the two together: it names the units it read
        return (*_parse_header(joined, where, has_rate, header, rename), 1)


#: A date and a time of day, ISO 8601 (``2024-03-01 12:00:00.001``, ``T`` or a space
#: between them; a comma may be the seconds' decimal mark).
_DATETIME = re.compile(r"\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}(:\d{2}([.,]\d+)?)?")
#: A time column's names without a unit that may hold dates and times (letters only).
_CLOCK_NAMES = ("time", "timestamp", "datetime", "date", "datum", "zeit")


def _clock_column(fields: list[str], row: str, separator: str | None) -> int | None:
    """The column a header names as a clock without a unit (``Timestamp``) and whose
    value in ``row`` is a date and time, or None."""
    values = _split(row.replace('"', ""), separator)
    for i, f in enumerate(fields):
        if (re.sub(r"[^a-z]", "", _unquoted(f).lower()) in _CLOCK_NAMES and i < len(values)
                and _DATETIME.fullmatch(values[i].strip())):
            return i
    return None


def _clock_seconds(rows: list[str], column: int, separator: str | None, where: str,
                   first_line: int) -> tuple[list[str], str]:
    """The rows with the dates of ``column`` written as seconds from the first (to the
    nanosecond), and the first, as ISO 8601."""
    split = [_split(r, separator) for r in rows]
    texts = [f[column].strip() if column < len(f) else "" for f in split]
    bad = next((i for i, t in enumerate(texts) if not _DATETIME.fullmatch(t)), None)
    if bad is not None:
        raise DataError(
            f"{where}: line {bad + first_line}, column {column + 1}: {texts[bad]!r} is not "
            f"a date and time as the column's first, {texts[0]!r}, is (ISO 8601: "
            "2024-03-01 12:00:00.001); write every row's time the same way.")
    stamps = np.array([t.replace(" ", "T").replace(",", ".") for t in texts],
                      dtype="datetime64[ns]")
    seconds = (stamps - stamps[0]).astype(np.int64) / 1e9
    sep = separator if separator is not None else " "
    # written with the decimal mark of the file's other numbers, which are read next
    comma = separator != "," and any("," in v for f in split
                                     for j, v in enumerate(f) if j != column)
    for f, value in zip(split, seconds.tolist(), strict=True):
        f[column] = repr(value).replace(".", ",") if comma else repr(value)
    return [sep.join(f) for f in split], texts[0].replace(" ", "T").replace(",", ".")


def _header_table(path: Path, where: str, has_rate: bool,
                  rename: Callable[[list[str]], list[str]] | None = None) -> _Table:
    """A CSV file with a header line: its columns in SI."""
    lines, skipped = _lines(path, where)
    if not lines:
        raise DataError(
            f"{where}: file is empty; expected a header line "
            "'trial,time_s,pressure_pa,position_m' followed by one row per sample."
        )
    header, first = skipped + 1, skipped + 2
    separator = _separator(lines[0])
    clock = _clock_column(_split(lines[0], separator), lines[1], separator) \
        if len(lines) > 1 else None
    names, input_name, headers, below = _parse_header_lines(lines, separator, where, has_rate,
                                                            header, clock, rename)
    first += below
    rows = lines[1 + below:]
    if not rows:
        raise DataError(
            f"{where}: line {first}: header only, no data rows; add one row per sample "
            f"({','.join(names)})."
        )
    _check_blank(rows, where, first)
    origin = None
    if clock is not None:  # before a decimal comma is read: a date has no decimal mark
        rows, origin = _clock_seconds(rows, clock, separator, where, first)
        say_once(where, "dates", DataWarning(
            f"{where}: column {clock + 1}, {headers.get('time_s', 'time')!r}, holds dates "
            f"and times: read as seconds from its first, {origin} (the metadata's "
            "'time_origin' records it)."), _HERE)
    rows = _read_through(rows, separator, where, first)
    table = _parse_rows(rows, names, where, first, separator)
    si = {UNITS[n][0] if n in UNITS else n: n for n in names}
    values = {s: table[n] if s == "trial" else to_si(table[n], n) for s, n in si.items()}
    step = None
    if "time_s" in si:
        col, factor = names.index(si["time_s"]), UNITS[si["time_s"]][1]
        step = _scaled(lambda: _printed_step(rows, col, separator), factor)
    return _Table(values, {s: n for s, n in si.items() if s != "trial"}, input_name, first,
                  step or (lambda: None), headers=headers, time_origin=origin)


def _scaled(step: Callable[[], float | None], factor: float) -> Callable[[], float | None]:
    def in_s() -> float | None:
        value = step()
        return None if value is None else value * factor
    return in_s


# ----------------------------------------------------------------------------- named by index


def _column_spec(spec: object, declare: str,
                 rename: Callable[[list[str]], list[str]] | None = None) -> dict[int, str]:
    """The sidecar's ``"columns"``: column number (from 1) to a name pmabayes reads (a
    calibrated signal's as ``rename`` reads it)."""
    example = '{"1": "time_s", "3": "pressure_psi", "4": "position_mm"}'
    if not isinstance(spec, dict) or not spec:
        raise DataError(
            f"{declare}: 'columns' is {spec!r}; it must map column numbers (from 1, as "
            f"strings) to column names, e.g. {example}.")
    out: dict[int, str] = {}
    problems = []
    for key, name in spec.items():
        if rename is not None and isinstance(name, str):
            name = rename([name])[0]
        if not (isinstance(key, str) and key.strip().isdigit() and int(key) >= 1):
            problems.append(f"key {key!r} is not a column number (columns are numbered from "
                            "1: \"1\", \"2\", ...)")
            continue
        if not isinstance(name, str) or not (name in UNITS or name == "trial"):
            if isinstance(name, str) and quantity(name):
                problems.append(unknown_unit(name))
            else:
                close = difflib.get_close_matches(str(name), [*UNITS, "trial"], n=1, cutoff=0.6)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                problems.append(f"column {key} is named {name!r}{hint}, not a name pmabayes "
                                f"reads: trial, {', '.join(UNITS)}")
            continue
        out[int(key)] = name
    names = list(out.values())
    seen = [n for n in set(names) if names.count(n) > 1]
    problems += [f"{n} names two columns" for n in seen]
    problems += role_problems([n for n in names if n not in seen])
    if problems:
        raise DataError(f"{declare}: 'columns': " + "; ".join(problems) +
                        f". Fix the map, e.g. {example}.")
    return out


def _numbers(path: Path, where: str, spec: dict[int, str]
             ) -> tuple[dict[str, np.ndarray], list[str], int, str | None]:
    """The named columns of a headerless text file, as read (not converted): the values
    by name, the data lines, the line of the first, the delimiter."""
    lines, skipped = _lines(path, where)
    if not lines:
        raise DataError(f"{where}: file is empty; expected one row of numbers per sample.")
    # the lab's own header, or an instrument's header block (LabVIEW's .lvm): every line
    # above the first row of numbers, skipped (said where it is more than one line)
    text = next((i for i, line in enumerate(lines) if _numeric(line, list(spec))),
                len(lines))
    first_line = skipped + text + 1
    if text == len(lines):
        raise DataError(f"{where}: no line of numbers below line {first_line - 1}: a "
                        "header only, no data rows.")
    if text > 1:
        say_once(where, "header block", DataWarning(
            f"{where}: lines {skipped + 1}-{skipped + text} are not rows of numbers (the "
            f"file's own header) and were skipped; line {first_line} is the first row "
            "read."), _HERE)
    lines = lines[text:]
    delimiter = _headerless_separator(lines[0])
    _check_blank(lines, where, first_line)
    lines = _read_through(lines, delimiter, where, first_line)
    width = len(_split(lines[0], delimiter))
    beyond = [k for k in spec if k > width]
    if beyond:
        sep = f"{_SEPARATOR_NAMES[delimiter]}-separated"
        raise DataError(
            f"{where}: line {first_line}: the sidecar's 'columns' names column "
            f"{beyond[0]} ({spec[beyond[0]]}) but the line has {width} {sep} fields; "
            f"columns are numbered from 1 to {width}: fix the column numbers.")
    cols = sorted(spec)
    try:
        table = np.loadtxt(lines, delimiter=delimiter, usecols=[k - 1 for k in cols],
                           comments=None, ndmin=2, dtype=np.float64)
    except ValueError:
        table = None
    if table is None or not np.isfinite(table).all():
        for i, line in enumerate(lines):
            fields = _split(line, delimiter)
            for k in cols:
                text = fields[k - 1].strip() if k <= len(fields) else ""
                if k > len(fields):
                    raise DataError(
                        f"{where}: line {i + first_line} has {len(fields)} fields; column {k} "
                        f"({spec[k]}) is missing. Fix or remove the row.")
                if not _is_number(text):
                    raise DataError(
                        f"{where}: line {i + first_line}, column {k} ({spec[k]}): {text!r} "
                        "is not a number; write plain decimal numbers."
                        + (_DROPOUT if not text and "position" in spec[k] else ""))
                if not math.isfinite(float(text)):
                    _raise_nonfinite(where, i + first_line, f"{k} ({spec[k]})", text)
        raise DataError(f"{where}: could not parse the rows; write plain numbers.")
    values = {spec[k]: table[:, j] for j, k in enumerate(cols)}
    return values, lines, first_line, delimiter


def _other_files(spec_in: object, folder: Path, declare: str,
                 rename: Callable[[list[str]], list[str]] | None = None
                 ) -> list[tuple[Path, dict[int, str]]]:
    """The sidecar's ``"columns_from"``: each other file (relative to ``folder``, the
    sidecar's) and the map of its columns."""
    example = '{"load_kN.txt": {"1": "force_kn"}}'
    if not isinstance(spec_in, dict) or not spec_in:
        raise DataError(
            f"{declare}: 'columns_from' is {spec_in!r}; it must map each other file's name "
            f"(beside the sidecar) to a map of its columns, e.g. {example}.")
    out = []
    for name, spec in spec_in.items():
        other = folder / str(name)
        if not other.is_file():
            raise DataError(
                f"{declare}: 'columns_from' names {name!r}, but {other} is not a file; "
                "give its name relative to the sidecar's folder.")
        out.append((other, _column_spec(spec, f"{declare}: 'columns_from' {name!r}",
                                        rename)))
    return out


def _columns_table(path: Path, where: str, spec_in: object, declare: str,
                   has_rate: bool, others: list[tuple[Path, dict[int, str]]] = (),
                   rename: Callable[[list[str]], list[str]] | None = None) -> _Table:
    """A headerless text file whose columns the sidecar's ``"columns"`` names, with the
    columns ``others`` name in other files read beside it, row for row."""
    spec = _column_spec(spec_in, declare, rename)
    names = list(spec.values()) + [n for _, s in others for n in s.values()]
    problems = [f"{n} is named twice" for n in sorted(set(names)) if names.count(n) > 1]
    problems += role_problems(sorted(set(names)))
    if problems:
        raise DataError(f"{declare}: 'columns' and 'columns_from': " + "; ".join(problems)
                        + ": name each quantity in one file.")
    si = {UNITS[n][0]: n for n in names if n in UNITS}
    missing = [r for r in ("position_m",) if r not in si]
    if not any(r in si for r in INPUT_NAMES):
        missing.insert(0, "pressure_pa or force_n")
    if "time_s" not in si and not has_rate:
        missing.insert(0, "time_s")
    if missing:
        raise DataError(
            f"{declare}: 'columns'{' and columns_from name' if others else ' names'} no "
            f"column for {' and '.join(missing)} (in any unit: pmabayes.data.UNITS); name one"
            + (", or give sample_rate_hz for a file without time" if "time_s" in missing
               else "") + ".")
    raw, lines, first_line, delimiter = _numbers(path, where, spec)
    read = {str(k): n for k, n in sorted(spec.items())}
    files = [(where, spec, lines, first_line, delimiter)]  # which file holds which column
    for other, other_spec in others:
        values, other_lines, other_first, other_delimiter = _numbers(other, str(other),
                                                                     other_spec)
        if len(other_lines) != len(lines):
            raise DataError(
                f"{other}: {len(other_lines)} rows of numbers (lines {other_first}-"
                f"{other_first + len(other_lines) - 1}), against {len(lines)} in {where} "
                f"(lines {first_line}-{first_line + len(lines) - 1}): files read side by "
                "side hold one row per sample of one clock. Check that they are the same "
                "test, and cut the longer one where the other ends if the logger ran on "
                "(nothing is cut on reading).")
        raw.update(values)
        read.update({f"{other.name}:{k}": n for k, n in sorted(other_spec.items())})
        files.append((str(other), other_spec, other_lines, other_first, other_delimiter))

    def holder(name: str) -> tuple[str, dict[int, str], list[str], int, str | None]:
        return next(f for f in files if name in f[1].values())

    values = {s: to_si(raw[n], n) for s, n in si.items()}
    if "trial" in names:
        t = raw["trial"]
        bad = t != np.round(t)
        if bad.any():
            i = int(np.argmax(bad))
            at, _, _, first, _ = holder("trial")
            raise DataError(f"{at}: line {i + first}, column trial: trial id "
                            f"{t[i]!r} is not an integer; use integer trial ids.")
        values["trial"] = t.astype(np.int64)
    step = None
    if "time_s" in si:
        _, clock, clock_lines, _, clock_delimiter = holder(si["time_s"])
        col = next(k for k, n in clock.items() if n == si["time_s"]) - 1
        step = _scaled(lambda: _printed_step(clock_lines, col, clock_delimiter),
                       UNITS[si["time_s"]][1])
    input_name = next(r for r in INPUT_NAMES if r in si)
    return _Table(values, si, input_name, first_line, step or (lambda: None), read)


def read_columns(path: str | os.PathLike[str], columns: dict[str, str]) -> dict[str, np.ndarray]:
    """Read named columns of a text file, in SI: for signals kept in separate files.

    Parameters
    ----------
    path : str or os.PathLike
        A comma-, semicolon- or whitespace-separated text file of numbers (one value a line
        included), optionally with one header line of text, which is skipped.
    columns : dict
        Column number (from 1, as a string) to a name pmabayes reads
        (:data:`pmabayes.data.UNITS`, e.g. ``{"1": "force_kn"}``). Columns not named
        are not read.

    Returns
    -------
    dict
        The SI name (``force_n``, ``position_m``, ...) to its values, float64.

    Raises
    ------
    DataError
        If the map names an unknown unit, two columns for one quantity, or a column
        beyond the file's width, or a value is not a finite number; the message
        names the file, the line and the fix.

    Warns
    -----
    DataWarning
        Once per file and process, naming each unit converted to SI.

    Examples
    --------
    A displacement kept in its own one-column file, in mm:

    >>> from pathlib import Path
    >>> from pmabayes.data import read_columns
    >>> _ = Path("displ.txt").write_text("displacement\\n0.0\\n1.5\\n3.0\\n")
    >>> read_columns("displ.txt", {"1": "position_mm"})
    {'position_m': array([0.    , 0.0015, 0.003 ])}
    """
    path = Path(path)
    where = str(path)
    spec = _column_spec(columns, f"{where}: columns=")
    raw, _, _, _ = _numbers(path, where, spec)
    names = {UNITS[n][0]: n for n in spec.values() if n in UNITS}
    record = _record(names)
    if record:
        said = _said(record)
        say_once(where, f"units: {said}", DataWarning(
            f"{where}: units converted to SI on reading: {said}; the arrays returned are "
            "SI (said once per file)."), _HERE)
    out = {s: to_si(raw[n], n) for s, n in names.items()}
    if "trial" in raw:
        out["trial"] = raw["trial"]
    return out
