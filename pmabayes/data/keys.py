"""The sidecar's keys, one fact sheet each: what :data:`~pmabayes.data.METADATA_KEYS` read.

:data:`SIDECAR_KEYS` gives each key pmabayes reads or writes in a data file's JSON
sidecar its type, unit, default, meaning and the guide page that explains it; the
rig's own keys (``"rig": {...}``) are :data:`pmabayes.data.rig.RIG_KEYS`, the rig's
schema. The documentation's sidecar reference is generated from
both, and a test fails when a key the code reads has no entry here.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["KeyDoc", "SIDECAR_KEYS"]


@dataclass(frozen=True)
class KeyDoc:
    """One sidecar key, as the reference tells it.

    Parameters
    ----------
    type : str
        Its JSON type (``number``, ``string``, ``object``, ...), with the values allowed.
    unit : str
        Its unit, ``""`` where it has none.
    default : str
        What pmabayes takes when the key is absent.
    meaning : str
        One or two sentences.
    page : str
        The guide page that explains it (a document name under ``docs/``,
        e.g. ``guide/data``).
    written : bool
        Whether pmabayes writes it on reading (a record of what it did), rather than
        a user declaring it.
    """

    type: str
    unit: str
    default: str
    meaning: str
    page: str
    written: bool = False


#: Every key of :data:`~pmabayes.data.METADATA_KEYS`, in that order.
#:
#: :meta hide-value:
SIDECAR_KEYS: dict[str, KeyDoc] = {
    "description": KeyDoc(
        "string", "", "none", "Free text about the record (what, where, when); shown in "
        "reports.", "guide/data"),
    "generator": KeyDoc(
        "object", "", "none", "How synthetic data were made (the generator's settings); "
        "written by `pmabayes simulate`, beside the rig it simulated. Data with it (or "
        "with `synthetic`) are not warned about a missing `rig`.", "guide/data"),
    "rig": KeyDoc(
        "object", "", "the paper's characterisation rig, said in a `DataWarning`",
        "The test rig's known constants (table below). Without it the model runs on the "
        "paper's characterisation rig, and the first model built on the file says so.",
        "guide/rig_priors"),
    "sample_rate_hz": KeyDoc(
        "number > 0", "Hz", "from the time column",
        "The sample rate; checked against the time column, or giving each trial's clock "
        "from 0 in a file without one.", "guide/data"),
    "synthetic": KeyDoc(
        "boolean", "", "false", "The data are simulated, not measured; reports say so.",
        "guide/data"),
    "pressure_reference": KeyDoc(
        '`"gauge"` or `"absolute"`', "", "gauge (checked: a file that looks absolute "
        "warns)", "Whether the pressure column is gauge or absolute; absolute pressure is "
        "converted to gauge on reading.", "guide/data"),
    "ambient_pressure_pa": KeyDoc(
        "number", "Pa", "101325", "The ambient pressure subtracted from absolute "
        "pressure.", "guide/data"),
    "check_units": KeyDoc(
        "boolean", "", "true", "`false` turns off the checks that values look like the "
        "column's unit.", "guide/data"),
    "converted_from_absolute": KeyDoc(
        "object", "", "none", "Written on reading absolute pressure: the ambient pressure "
        "subtracted.", "guide/data", written=True),
    "input_between_samples": KeyDoc(
        '`"hold"`, `"linear"` or `"bandlimited"`', "", "hold",
        "What the input does between its samples (a DAQ's zero-order hold, or the samples "
        "of a continuous signal).", "guide/simulation"),
    "period_samples": KeyDoc(
        "integer >= 2", "samples", "none (not periodic)", "The samples in one period of a "
        "periodic input; it must divide the record.", "guide/simulation"),
    "starts_in_steady_state": KeyDoc(
        "boolean", "", "false", "Each trial starts in the periodic steady state (needs "
        "`period_samples`).", "guide/simulation"),
    "initial_state": KeyDoc(
        '`"rest"`, `"zero"` or `"estimate"`', "", "rest", "The state each trial starts "
        "from: at rest under the first input, all zero, or unknown and identified.",
        "guide/simulation"),
    "mat_variables": KeyDoc(
        "object", "", "none", "Which variables of a `.mat` file are time, input and "
        "position (role to variable name).", "guide/lab_files"),
    "mat_trials": KeyDoc(
        '`"columns"` or `"rows"`', "", "columns", "How a 2-D array of a `.mat` file holds "
        "its trials.", "guide/lab_files"),
    "columns": KeyDoc(
        "object", "", "none (the CSV header names the columns)",
        'Column number (from 1, as a string) to the name read: `"trial"` (the trial ids) '
        'or a name of `pmabayes.data.UNITS` (`"time_ms"`, `"pressure_psi"`, '
        '`"position_mm"`, ...). Columns not named are not read; a header line is '
        "skipped.", "guide/lab_files"),
    "columns_from": KeyDoc(
        "object", "", "none (every signal in this file)",
        "Signals kept in other files, one row per sample of this file's clock: each "
        "file's name (beside the sidecar) to a map of its columns like `columns`' "
        '(`{"load_kN.txt": {"1": "force_kn"}}`). Needs `columns`; files of different '
        "lengths are refused.", "guide/lab_files"),
    "read_columns": KeyDoc(
        "object", "", "none", "Written on reading through `columns`: the map read (a "
        "column of another file as `file:number`).",
        "guide/lab_files", written=True),
    "converted_units": KeyDoc(
        "object", "", "none", "Written on reading a column in another unit than SI: each "
        "SI name, the column it came from and the factor. A fit file keeps it in its "
        "experiments' metadata.", "guide/lab_files", written=True),
    "max_gap_s": KeyDoc(
        "number > 0", "s", "none (every gap is missing samples of one record)",
        "A gap in the clock longer than this starts a new segment.", "guide/lab_records"),
    "segment": KeyDoc(
        "object", "", "none", "Written for each segment of a record split at gaps: its "
        "name, index and first line.", "guide/lab_records", written=True),
    "time_origin_s": KeyDoc(
        "number", "s", "none", "Written when a clock's origin is subtracted on reading.",
        "guide/lab_files", written=True),
    "time_origin": KeyDoc(
        "string (ISO 8601)", "", "none", "Written when a time column of dates and times "
        "(`Timestamp`: `2024-03-01 12:00:00.001`) is read as seconds from its first: that "
        "first date and time.", "guide/lab_files", written=True),
    "position_reference": KeyDoc(
        '`"absolute"` or `"start"`', "", "absolute", "How positions are referred: from the "
        "model's zero, or to the sensor's reading at rest at the record's start.",
        "guide/rig_priors"),
    "steady_state_tol_m": KeyDoc(
        "number > 0", "m", "1e-9", "Tolerance of the periodic steady state's warm-up.",
        "guide/rig_priors"),
    "max_warmup_periods": KeyDoc(
        "integer >= 3", "periods", "256", "Most periods simulated to reach the periodic "
        "steady state.", "guide/rig_priors"),
    "warmup_s": KeyDoc(
        "number >= 0", "s", "0", "Seconds at the start of each trial left out of the "
        "likelihood (they still drive the simulation).", "guide/lab_records"),
    "position_sign": KeyDoc(
        "1 or -1", "", "1", "-1: the file's positions run against pmabayes' `x` (which "
        "grows as the pressure pushes) and are negated on reading.", "guide/identification"),
    "position_zero_s": KeyDoc(
        "number > 0", "s", "none", "The muscle rests for at least this long at each "
        "trial's start: positions are referred to their mean there on reading.",
        "guide/sidecar"),
    "position_zero": KeyDoc(
        "object", "", "none", "Written on reading with `position_zero_s`: the reading "
        "subtracted from each trial.", "guide/sidecar", written=True),
    "disturbance_max_s": KeyDoc(
        "number > 0", "s", "chosen by the fit", "The longest correlation time the "
        "disturbance of a record without repeats may have.", "guide/lab_records"),
    "disturbance_check": KeyDoc(
        "object", "", "none", "Written by a fit: the check of a record's disturbance "
        "bound.", "guide/lab_records", written=True),
    "conditions": KeyDoc(
        "object of numbers", "SI (by the name's suffix)", "none",
        "How this experiment differed from the others fitted with it "
        '(`{"load_kg": 0.3}`); the joint fit\'s criticism relates moving parameters to '
        "them.", "guide/identification"),
    "selected_trials": KeyDoc(
        "list of integers", "", "none", "Written when some of a file's trials are left "
        "out (`trials=`, `--trials`, `--exclude-trials`): the trial ids kept, so that the "
        "next command a fit suggests chooses them too.", "guide/validation", written=True),
    "input_range": KeyDoc(
        "list of two numbers, low < high", "Pa (N on a force rig)", "none",
        "The rig's safe input range: `pmabayes design` keeps its experiments inside it, "
        "and refuses an `--input-range` beyond it.", "guide/design"),
    "clock_shifts": KeyDoc(
        "list of objects", "s", "none",
        'Blocks of lines whose time stamps a logging fault moved, and the seconds to add '
        '(`[{"lines": [9001, 10000], "shift_s": -1.0}]`, lines of the file); applied on '
        "reading and said. A clock that steps back gets an error that proposes it.",
        "guide/lab_records"),
    "written_by": KeyDoc(
        "string", "", "none", "Written by `pmabayes read --out`: the command and version "
        "that wrote the lab's file again in pmabayes' own format (so that the command may "
        "write over it again).", "guide/lab_files", written=True),
    "calibration": KeyDoc(
        "object", "the `to` unit", "none", "A sensor's signal read through its "
        "calibration: the column as pmabayes spells it (a header `Pressure (V)` is "
        '`pressure_v`) to `{"to": "pressure_kpa", "gain": 100.0, "offset": 0.0}`: '
        "`to` = `gain` x signal + `offset`, then SI. Text files.", "guide/lab_files"),
    "calibrated": KeyDoc(
        "object", "", "none", "Written on reading through `calibration`: the "
        "calibrations applied.", "guide/lab_files", written=True),
}
