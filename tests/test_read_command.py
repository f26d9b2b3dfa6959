"""``pmabayes read``: a lab's file as pmabayes reads it, said before any fit
(:func:`pmabayes.data.describe`), and written again in pmabayes' own format."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from pmabayes.cli import main
from pmabayes.data import Dataset, DataWarning, describe, load


def _lab_file(folder: Path) -> Path:
    """A headerless logger file in ms, kPa and mm with a gap, and its sidecar."""
    t_ms = np.delete(np.arange(400) * 2.0, np.s_[100:110])  # 10 samples not logged
    p_kpa = 150.0 + 100.0 * np.sin(2 * np.pi * t_ms / 400.0)
    x_mm = 3.0 + 2.0 * np.sin(2 * np.pi * t_ms / 400.0 - 0.3)
    path = folder / "bench.txt"
    path.write_text("\n".join(f"{a:g}\t{b:.3f}\t{c:.4f}" for a, b, c in zip(t_ms, p_kpa, x_mm,
                                                                            strict=True)))
    path.with_suffix(".json").write_text(json.dumps({
        "columns": {"1": "time_ms", "2": "pressure_kpa", "3": "position_mm"},
        "pressure_reference": "gauge", "conditions": {"load_kg": 0.2},
        "rig": {"name": "bench", "moving_mass_kg": 0.2, "gravity_sign": 1.0,
                "area_m2": 2e-4, "input_kind": "pressure"}}))
    return path


def test_describe_says_what_was_read(tmp_path):
    path = _lab_file(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        text = describe(load(path))
    lines = text.splitlines()
    assert lines[0] == (f"{path}: 1 trial x 400 samples, 2 ms apart (500 Hz), 0.798 s; 10 "
                        "samples not observed (2.5% of the grid)")
    assert lines[1] == "input: pressure from 50 to 250 kPa (gauge)"
    assert lines[2].startswith("position: from 1 to 5 mm, a stroke of 4 mm")
    assert "time_ms x 0.001 -> time_s" in text and "3 as position_mm" in text
    assert "rig: bench: moving_mass_kg 0.2" in text and "conditions: load_kg = 0.2" in text
    assert "synthetic" not in text


def test_describe_names_a_force_and_an_assumed_rig():
    ds = Dataset(time_s=np.arange(3) * 0.5, input=np.array([[-2e3, 0.0, 5e3]]),
                 position_m=np.array([[0.0, 2e-3, 1e-3]]), trial_ids=np.array([4]),
                 input_name="force_n", source="rc.csv")
    text = describe(ds)
    assert text.splitlines()[1] == "input: force from -2000 to 5000 N"
    assert "rig: none declared: the paper's characterisation rig is assumed" in text


def test_read_prints_each_file_and_the_next_command(tmp_path, capsys):
    path = _lab_file(tmp_path)
    assert main(["read", str(path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"{path}: 1 trial x 400 samples")
    assert out.rstrip().endswith(f"next: pmabayes fit {path} --out results/bench/fit.nc")


def test_read_out_writes_the_data_set_and_only_over_its_own(tmp_path, capsys):
    path = _lab_file(tmp_path)
    out = tmp_path / "own" / "bench.csv"
    assert main(["read", str(path), "--out", str(out), "--quiet"]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        lab, own = load(path), load(out)
    np.testing.assert_array_equal(own.position_m, lab.position_m)
    np.testing.assert_array_equal(own.observed, lab.observed)
    assert own.metadata["written_by"] == f"pmabayes read {__import__('pmabayes').__version__}" \
        f", from {path}"
    assert main(["read", str(path), "--out", str(out), "--quiet"]) == 0  # its own: again
    capsys.readouterr()
    foreign = tmp_path / "notes.csv"
    foreign.write_text("my notes")
    assert main(["read", str(path), "--out", str(foreign), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "is not a data set that pmabayes wrote" in err and foreign.read_text() == "my notes"
    assert main(["read", str(path), str(out), "--out", str(tmp_path / "both.csv"),
                 "--quiet"]) == 2
    assert "--out writes one data set, but 2 were read" in capsys.readouterr().err
    assert not (tmp_path / "both.csv").exists()
