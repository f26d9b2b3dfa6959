"""The command line is a thin layer over the API; test it through main()."""

import json

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.cli import main
from pmabayes.data import read_csv


def test_simulate_noise_none_is_exact(tmp_path):
    out = tmp_path / "sim.csv"
    assert main(["simulate", str(out), "--trials", "2", "--noise", "none",
                 "--duration", "2"]) == 0
    ds = read_csv(out)
    x = pb.simulate(pb.Model(), None, ds.input[0], time_s=ds.time_s)[0]
    assert np.array_equal(ds.position_m, np.stack([x, x]))
    assert ds.metadata["synthetic"] is True


def test_simulate_with_effects_and_seed(tmp_path):
    args = ["--trials", "2", "--duration", "2", "--seed", "3",
            "--effect", "regulator_lag=0.03", "--effect", "coulomb_friction.F_c=0.5"]
    assert main(["simulate", str(tmp_path / "a.csv"), *args]) == 0
    assert main(["simulate", str(tmp_path / "b.csv"), *args]) == 0
    a, b = read_csv(tmp_path / "a.csv"), read_csv(tmp_path / "b.csv")
    assert np.array_equal(a.position_m, b.position_m)
    assert a.metadata["generator"]["parameters"]["tau_reg"] == 0.03
    assert a.metadata["generator"]["parameters"]["F_c"] == 0.5


def test_run_writes_figure_and_summary(tmp_path, capsys):
    data = tmp_path / "d.csv"
    main(["simulate", str(data), "--trials", "3", "--duration", "2", "--seed", "1"])
    out = tmp_path / "out"
    assert main(["run", str(data), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "comparison.png").stat().st_size > 10_000
    # data made by the paper's model: error of the order of the noise floor
    assert summary["rms_m"] < 3 * summary["noise_floor_m"]
    assert "RMS error of the trial mean" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "x.csv", "--effect", "nonsense=1"], "unknown effect 'nonsense'"),
        (["simulate", "x.csv", "--effect", "regulator_lag"], "must look like NAME=VALUE"),
        (["simulate", "x.csv", "--param", "d=abc"], "is not a number"),
        (["run", "missing.csv", "--out", "o"], "missing.csv"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_unknown_option_is_rejected(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "x.csv", "--trails", "3"])
    assert "unrecognized arguments" in capsys.readouterr().err


def test_effects_lists_builtins(capsys):
    assert main(["effects"]) == 0
    out = capsys.readouterr().out
    for name in ("regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
                 "pressure_stiffness", "position_offset"):
        assert name in out


PLUGIN = '''
import pmabayes as pb

def stiction(q, x, v, p):
    return q[0] * v / (abs(v) + 1e-3), 0.0, q[0] * 1e-3 / (abs(v) + 1e-3) ** 2

class CliStiction(pb.Effect):
    name = "cli_stiction"
    stage = "force"
    parameters = (pb.Parameter("F_st", "N", 1.0, pb.HalfNormal(2.0), bounds=(0.0, 50.0),
                               null=0.0, description="rational friction"),)
    description = "Friction with a rational sign function."
    physics = staticmethod(stiction)

pb.register_effect(CliStiction)
'''


def test_plugin_effect_works_like_a_builtin(tmp_path):
    plugin = tmp_path / "my_effects.py"
    plugin.write_text(PLUGIN)
    out = tmp_path / "plug.csv"
    assert main(["--plugin", str(plugin), "simulate", str(out), "--trials", "1",
                 "--duration", "2", "--noise", "none", "--effect", "cli_stiction=2.0"]) == 0
    ds = read_csv(out)
    assert ds.metadata["generator"]["effects"] == {"cli_stiction": {"F_st": 2.0}}
    base = pb.simulate(pb.Model(), None, ds.input[0], time_s=ds.time_s)[0]
    assert np.max(np.abs(ds.position_m[0] - base)) > 1e-4
    assert main(["--plugin", str(plugin), "run", str(out), "--out", str(tmp_path / "o"),
                 "--effects", "cli_stiction", "--param", "F_st=2.0"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["rms_m"] < 1e-9  # the right model on noise-free data
