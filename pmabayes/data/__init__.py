"""Data stage: read, validate and write pneumatic-muscle (or oscillator) trial data.

A data set is a set of trials that share one uniformly sampled time grid. Each trial
has one input signal (commanded gauge pressure in Pa, or force in N for a generic
force-driven oscillator) and one measured position signal in m.

Three file formats are supported:

CSV
    Header ``trial,time_s,pressure_pa,position_m`` (any column order; ``force_n`` may
    replace ``pressure_pa``), one row per sample, each trial's rows contiguous. An
    optional JSON sidecar with the same stem (``foo.csv`` -> ``foo.json``) holds a
    free-form metadata object. Column names may carry other units
    (:data:`UNITS`: ``time_ms``, ``pressure_psi``, ``position_mm``, ``force_kn``,
    ...), converted to SI on reading, said once in a :class:`DataWarning` and
    recorded in the metadata (``"converted_units"``).
Headerless text (``.csv``, ``.txt``, ``.dat``, ``.tsv``, LabVIEW's ``.lvm``)
    Comma-, semicolon-, tab- or whitespace-separated numbers, one value a line
    included, below any lines of text (the file's own header); the sidecar's
    ``"columns"`` names the columns read by number from 1 (``{"columns": {"3":
    "time_s", "4": "pressure_psi", "5": "position_mm"}}``); columns it does not name
    are not read. :func:`read_columns` reads named columns of any such file, for
    signals kept in separate files.
NetCDF
    Written and read through xarray with the ``h5netcdf`` engine; metadata is stored
    as a JSON string attribute. Intended for large data.
MATLAB (read only)
    ``.mat`` v4 to v7 through scipy, v7.3 (HDF5) through h5py (:func:`read_mat`):
    numeric arrays (a vector per trial, or a 2-D array of trials, one per column or
    per row), one variable per trial (a list or a pattern), and Simulink's
    "Structure with time". The JSON sidecar's ``"mat_variables"`` (or keywords) maps
    the roles to variables, e.g. ``{"time_s": "t", "pressure_pa": "p_cmd",
    "position_m": ["x1", "x2"]}``, and ``"mat_trials"`` (``"columns"`` or ``"rows"``)
    says how a 2-D array holds its trials. Without a time variable,
    ``"sample_rate_hz"`` gives the grid. Values must be SI; see
    :mod:`pmabayes.data.matlab` for the full schema.

:func:`load` picks the reader from the suffix (``.csv``, ``.txt``, ``.dat``, ``.tsv``,
``.lvm``, ``.nc``, ``.mat``). Text fields may be separated by commas, semicolons or
tabs (a comma in a number is then its decimal mark, said once per file) and quoted;
``#`` lines above the header are skipped and said.

A lab's clock: times within 10% of a step of a uniform grid (a DAQ's jitter) are that
grid, and a gap in the clock is samples not observed, never invented ones:
:attr:`Dataset.observed` is False there, the position NaN, and the input follows
``input_between_samples`` across the gap. A sidecar ``"max_gap_s"`` splits a record
at longer gaps into segments, each on its own grid: :func:`load_segments` returns
them as data sets named ``stem#1``, ``stem#2``, ... (metadata ``"segment"``).

Bad input raises :class:`DataError` with a message that names the file, the line or
trial, and says how to fix it. Nothing is dropped, repaired or clipped silently.
Data that read but look suspect (pressure that looks absolute, not gauge) give a
:class:`DataWarning`. Two metadata entries declare what the checks cannot know:
``"pressure_reference"`` (``"gauge"``, or ``"absolute"`` to convert to gauge on
reading) and ``"check_units": false``; ``"input_between_samples"`` says what the
input does between samples (:data:`BETWEEN_SAMPLES`), ``"initial_state"`` the state
each trial starts from (:data:`INITIAL_STATES`). A metadata key close to one
pmabayes reads (:data:`METADATA_KEYS`) is taken for a misspelling and refused. A
``"rig"`` is checked against the rig's schema (:mod:`pmabayes.data.rig`: its keys,
their values, and that its ``input_kind`` drives the data's input column), and
:func:`check_same_input_kind` refuses experiments of different input kinds in one fit.
"""

from pmabayes.data.dataset import (
    BETWEEN_SAMPLES,
    INITIAL_STATES,
    INPUT_NAMES,
    METADATA_KEYS,
    DataError,
    Dataset,
    DataWarning,
    check_same_input_kind,
    check_time_grid,
    experiment_conditions,
)
from pmabayes.data.files import (
    load,
    load_segments,
    read_csv,
    read_netcdf,
    save,
    write_csv,
    write_netcdf,
)
from pmabayes.data.matlab import MAT_ROLES, MAT_TRIALS, read_mat, read_mat_segments
from pmabayes.data.summary import describe
from pmabayes.data.text import read_columns
from pmabayes.data.units import UNITS

__all__ = [
    "INPUT_NAMES",
    "BETWEEN_SAMPLES",
    "INITIAL_STATES",
    "METADATA_KEYS",
    "DataError",
    "DataWarning",
    "Dataset",
    "MAT_ROLES",
    "MAT_TRIALS",
    "UNITS",
    "check_same_input_kind",
    "check_time_grid",
    "describe",
    "experiment_conditions",
    "load",
    "load_segments",
    "read_columns",
    "read_csv",
    "read_mat",
    "read_mat_segments",
    "read_netcdf",
    "save",
    "write_csv",
    "write_netcdf",
]
