"""The design's files: the chosen input as a plan in the user's units, its sidecar, and
the scores.

``next.csv`` has a header line and two columns, time and the rig's input, named and
scaled as the first data file's columns were (``time_ms``, ``pressure_kpa``, ...: the
units it was read in); :func:`pmabayes.data.text.read_columns` reads it back in SI with the
sidecar's ``"columns"``. ``next.json`` is its sidecar: the columns, the sample rate, the
rig (its moving mass with the experiment's dead load in place of the first record's),
the dead load (``"conditions"``), the trials to repeat and the experiment.
``design.json`` holds every candidate's score.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pmabayes.data.units import from_si
from pmabayes.design.experiments import loaded_mass_kg
from pmabayes.outputs import stamp, write_json

__all__ = ["write_design_files", "NEXT_CSV", "NEXT_JSON", "DESIGN_JSON"]

NEXT_CSV, NEXT_JSON, DESIGN_JSON = "next.csv", "next.json", "design.json"


def write_design_files(result, folder: str | Path) -> list[str]:
    """Write ``next.csv``, its sidecar ``next.json`` and ``design.json`` into ``folder``.

    Parameters
    ----------
    result : DesignResult
        A design.
    folder : str or Path
        An existing folder (a staged one: :func:`pmabayes.outputs.staged`).

    Returns
    -------
    list of str
        The names written.
    """
    folder = Path(folder)
    exp = result.experiment
    time_col = result.units.get("time_s", "time_s")
    input_col = result.units.get(result.input_name, result.input_name)
    t = from_si(exp.time_s, time_col)
    u = from_si(exp.input(), input_col)
    lines = [f"{time_col},{input_col}"]
    lines += [f"{a!r},{b!r}" for a, b in zip(t.tolist(), u.tolist(), strict=True)]
    (folder / NEXT_CSV).write_text("\n".join(lines) + "\n")
    rig = dict(result.rig)
    first_load = result.settings.get("first_load_kg")
    load = first_load if exp.load_kg is None else exp.load_kg
    if exp.load_kg is not None and exp.load_kg != first_load:
        # the load hangs in place of the first record's (whose mass the rig's includes)
        rig["moving_mass_kg"] = loaded_mass_kg(float(rig["moving_mass_kg"]), first_load,
                                               exp.load_kg)
        rig["name"] = f"{rig.get('name', 'custom')}_{exp.load_kg:g}kg"
    sidecar = {
        "pmabayes": stamp("design"),
        "description": (f"The next experiment pmabayes design chose: {exp.label()}. Run it "
                        f"{result.settings['n_trials']} times on the rig below and record "
                        "the position beside each input sample."),
        "columns": {"1": time_col, "2": input_col},
        "sample_rate_hz": exp.sample_rate_hz,
        "rig": rig,
        **({} if load is None else {"conditions": {"load_kg": load}}),
        "n_trials": result.settings["n_trials"],
        "experiment": exp.to_dict(),
    }
    (folder / NEXT_JSON).write_text(json.dumps(sidecar, indent=2) + "\n")
    write_json(folder / DESIGN_JSON, _jsonable(result.to_dict()), "design")
    return [NEXT_CSV, NEXT_JSON, DESIGN_JSON]


def _jsonable(obj):
    """NaN and infinities as None (JSON has none), numpy scalars as floats."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj
