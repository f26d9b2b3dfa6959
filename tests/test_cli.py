"""The command line is a thin layer over the API; test it through main()."""

import dataclasses
import json

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.cli import main
from pmabayes.data import read_csv


@pytest.mark.slow
def test_simulate_noise_none_is_exact(tmp_path):
    out = tmp_path / "sim.csv"
    assert main(["simulate", str(out), "--trials", "2", "--noise", "none",
                 "--duration", "2"]) == 0
    ds = read_csv(out)
    x = pb.simulate(pb.Model(), None, ds.input[0], time_s=ds.time_s)[0]
    assert np.array_equal(ds.position_m, np.stack([x, x]))
    assert ds.metadata["synthetic"] is True


@pytest.mark.slow
def test_simulate_with_effects_and_seed(tmp_path):
    args = ["--trials", "2", "--duration", "2", "--seed", "3",
            "--effects", "regulator_lag,coulomb_friction", "--param", "tau_reg=0.03",
            "--param", "F_c=0.5"]
    assert main(["simulate", str(tmp_path / "a.csv"), *args]) == 0
    assert main(["simulate", str(tmp_path / "b.csv"), *args]) == 0
    a, b = read_csv(tmp_path / "a.csv"), read_csv(tmp_path / "b.csv")
    assert np.array_equal(a.position_m, b.position_m)
    assert a.metadata["generator"]["parameters"]["tau_reg"] == 0.03
    assert a.metadata["generator"]["parameters"]["F_c"] == 0.5


def test_predict_writes_figure_and_summary(tmp_path, capsys):
    data = tmp_path / "d.csv"
    main(["simulate", str(data), "--trials", "3", "--duration", "2", "--seed", "1"])
    out = tmp_path / "out"
    assert main(["predict", str(data), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "comparison.png").stat().st_size > 10_000
    # data made by the paper's model: error of the order of the noise floor
    assert summary["rms_m"] < 3 * summary["noise_floor_m"]
    assert "RMS error of the trial mean" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "x.csv", "--effects", "nonsense"], "unknown effect 'nonsense'"),
        (["simulate", "x.csv", "--param", "tau_reg"], "must look like NAME=VALUE"),
        (["simulate", "x.csv", "--param", "d=abc"], "is not a number"),
        (["predict", "missing.csv", "--out", "o"], "missing.csv"),
        (["compare", "a.nc", "--data", "d.csv", "--out", "o"], "give two or more fits"),
        (["compare", "a.nc", "b.nc", "--data", "d.csv", "--out", "o", "--labels", "x"],
         "one label per fit"),
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


@pytest.mark.slow
def test_plugin_effect_works_like_a_builtin(tmp_path):
    plugin = tmp_path / "my_effects.py"
    plugin.write_text(PLUGIN)
    out = tmp_path / "plug.csv"
    assert main(["--plugin", str(plugin), "simulate", str(out), "--trials", "1",
                 "--duration", "2", "--noise", "none", "--effects", "cli_stiction",
                 "--param", "F_st=2.0"]) == 0
    ds = read_csv(out)
    assert ds.metadata["generator"]["effects"] == {"cli_stiction": {"F_st": 2.0}}
    base = pb.simulate(pb.Model(), None, ds.input[0], time_s=ds.time_s)[0]
    assert np.max(np.abs(ds.position_m[0] - base)) > 1e-4
    assert main(["--plugin", str(plugin), "predict", str(out), "--out", str(tmp_path / "o"),
                 "--effects", "cli_stiction", "--param", "F_st=2.0"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["rms_m"] < 1e-9  # the right model on noise-free data


@pytest.mark.slow
def test_fit_then_report_then_resume(tmp_path, capsys):
    data = tmp_path / "d.csv"
    main(["simulate", str(data), "--trials", "3", "--duration", "3", "--seed", "4"])
    fit_path = tmp_path / "fit.nc"
    args = ["fit", str(data), "--out", str(fit_path), "--walkers", "16", "--steps", "3000",
            "--seed", "2"]
    assert main(args) == 0
    out = capsys.readouterr()
    assert "MAP RMS cost" in out.out and "steps needed" in out.err  # progress bar lines
    assert (tmp_path / "fit.nc.chains" / "ensemble_0.h5").exists()
    assert main(["report", str(fit_path), "--data", str(data), "--out",
                 str(tmp_path / "rep")]) == 0
    html = (tmp_path / "rep" / "index.html").read_text()
    assert "data:image/png;base64," in html and "alpha" in html
    # the same command again resumes the saved chains instead of starting over
    assert main([*args, "--quiet"]) == 0
    assert "resuming" not in capsys.readouterr().err  # --quiet
    from pmabayes.inference.fitfile import fit_info, load_fit

    assert fit_info(load_fit(fit_path))["convergence"]["resumed"] is True


@pytest.mark.slow
def test_run_is_fit_plus_report(tmp_path):
    data = tmp_path / "d.csv"
    main(["simulate", str(data), "--trials", "3", "--duration", "3", "--seed", "5"])
    assert main(["run", str(data), "--out", str(tmp_path / "r"), "--walkers", "16",
                 "--quiet"]) == 0
    for name in ("fit.nc", "index.html", "summary.csv", "summary.md", "ppc.png"):
        assert (tmp_path / "r" / name).exists(), name


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda ds: __import__("pmabayes.data", fromlist=["Dataset"]).Dataset(
            time_s=ds.time_s, input=ds.input, position_m=ds.position_m * 0.0,
            trial_ids=ds.trial_ids), "every position is"),
    ],
)
def test_fit_refuses_data_it_cannot_fit(tmp_path, capsys, make, message):
    from pmabayes.data import save
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    ds = make(generate_chirp_dataset(n_trials=3, seed=1, chirp=Chirp(duration_s=1.0)))
    path = tmp_path / "bad.csv"
    save(ds, path)
    assert main(["fit", str(path), "--out", str(tmp_path / "f.nc"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_fit_rejects_mpa(tmp_path, capsys):
    path = tmp_path / "mpa.csv"
    rows = ["trial,time_s,pressure_pa,position_m"]
    rows += [f"{r},{k * 1e-3!r},{0.3 + 0.001 * k!r},{0.01 + 1e-5 * k!r}"
             for r in range(2) for k in range(20)]
    path.write_text("\n".join(rows) + "\n")
    assert main(["fit", str(path), "--out", str(tmp_path / "f.nc")]) == 2
    assert "looks like MPa" in capsys.readouterr().err


@pytest.fixture(scope="module")
def offset_data(tmp_path_factory):
    """Short data with a hidden 0.5 mm sensor offset."""
    data = tmp_path_factory.mktemp("offset") / "d.csv"
    main(["simulate", str(data), "--trials", "4", "--duration", "4", "--seed", "6",
          "--effects", "position_offset", "--param", "x_offset=5e-4"])
    return data


@pytest.mark.slow
def test_diagnose_writes_json_and_page(offset_data, tmp_path, capsys):
    out, js = tmp_path / "diag", tmp_path / "diag.json"
    assert main(["diagnose", str(offset_data), "--out", str(out), "--json", str(js),
                 "--candidates", "regulator_lag,coulomb_friction,position_offset",
                 "--quiet"]) == 0
    summary = json.loads(js.read_text())
    assert summary["missing"] == "position_offset" and summary["adequate"] is False
    assert summary["effects"] == [] and summary["rms_m"] > 2 * summary["noise_floor_m"]
    assert {r["effect"] for r in summary["ranking"]} == {"regulator_lag", "coulomb_friction",
                                                        "position_offset"}
    assert [e["name"] for e in summary["experiments"]] == [offset_data.stem]
    assert summary["experiments"][0]["bands"] and summary["misfit_experiments"]
    assert "position_offset is missing" in capsys.readouterr().out
    html = (out / "index.html").read_text()
    for name in ("bands", "signature", "whiteness", "ranking", "comparison"):
        assert (out / f"{name}.png").exists()
    assert html.count("data:image/png;base64,") == 5 and "Synthetic data" in html
    # the effect added: adequate, nothing missing
    assert main(["diagnose", str(offset_data), "--effects", "position_offset", "--json", str(js),
                 "--candidates", "regulator_lag,coulomb_friction", "--quiet"]) == 0
    summary = json.loads(js.read_text())
    assert summary["adequate"] is True and summary["missing"] is None


@pytest.mark.slow
def test_compare_two_fits(offset_data, tmp_path, capsys):
    fits = []
    for effects in ("", "position_offset"):
        path = tmp_path / f"fit{len(fits)}.nc"
        assert main(["fit", str(offset_data), "--out", str(path), "--effects", effects,
                     "--walkers", "16", "--quiet"]) == 0
        fits.append(str(path))
    out = tmp_path / "cmp"
    assert main(["compare", *fits, "--data", str(offset_data), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "base -> base + position_offset: ELPD +" in text
    summary = json.loads((out / "comparison.json").read_text())
    base, added = summary["fits"]
    assert added["rms_m"] < 0.5 * base["rms_m"] and added["ratio"] < 1.25
    assert summary["elpd_steps"][0]["elpd_diff"] > 3 * summary["elpd_steps"][0]["se"]
    assert (out / "error_falling.png").exists() and (out / "index.html").exists()
    # a fit of other data is refused with one line
    other = tmp_path / "other.csv"
    main(["simulate", str(other), "--trials", "4", "--duration", "4", "--seed", "7"])
    assert main(["compare", *fits, "--data", str(other), "--out", str(out)]) == 2
    assert "does not match the observed data" in capsys.readouterr().err


# ----------------------------------------------------------------------------- failures a
# new user hit: one clear line for bad input, a traceback for a bug, no debris


def test_a_bug_keeps_its_traceback_and_bad_input_is_one_line(tmp_path, monkeypatch, capsys):
    import pmabayes.data as data
    from pmabayes.data import DataError

    def bug(*args, **kwargs):
        raise ValueError("an internal bug")

    monkeypatch.setattr(data, "load_segments", bug)
    with pytest.raises(ValueError, match="an internal bug"):
        main(["predict", str(tmp_path / "d.csv"), "--out", str(tmp_path / "o")])

    def bad_input(*args, **kwargs):
        raise DataError("d.csv: line 3: bad; fix it")

    monkeypatch.setattr(data, "load_segments", bad_input)
    capsys.readouterr()
    assert main(["predict", str(tmp_path / "d.csv"), "--out", str(tmp_path / "o"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err == "pmabayes predict: error: d.csv: line 3: bad; fix it\n"
    assert not (tmp_path / "o").exists()


def test_model_for_is_gone():
    import pmabayes.cli as cli

    assert not hasattr(cli, "model_for") and "model_for" not in cli.__all__


@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    """Three short noisy trials from the paper's model."""
    data = tmp_path_factory.mktemp("small") / "d.csv"
    assert main(["simulate", str(data), "--trials", "3", "--duration", "1", "--seed", "1"]) == 0
    return data


def test_predict_out_is_an_existing_file(small_data, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    assert main(["predict", str(small_data), "--out", str(afile)]) == 2
    err = capsys.readouterr().err
    assert f"--out {afile}: this is a file, not a folder" in err and "Traceback" not in err
    assert afile.read_text() == "keep me"


def test_simulate_creates_the_missing_folder(tmp_path):
    out = tmp_path / "new" / "deeper" / "s.csv"
    assert main(["simulate", str(out), "--trials", "2", "--duration", "1"]) == 0
    assert read_csv(out).n_trials == 2


@pytest.mark.parametrize("argv", [["simulate", "x.csv", "--seed", "-1"],
                                  ["fit", "d.csv", "--out", "f.nc", "--seed", "-1"],
                                  ["fit", "d.csv", "--out", "f.nc", "--ensembles", "0"]])
def test_bad_counts_are_refused_by_the_parser(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "give an integer >= " in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "x.csv", "--duration", "-1"], "duration_s (--duration) > 0"),
        (["simulate", "x.csv", "--duration", "0.001"], "fewer than 2 samples"),
        (["simulate", "x.csv", "--trials", "0"], "(--trials)"),
    ],
)
def test_bad_simulate_settings_name_the_option(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_run_on_bad_data_leaves_no_folder(small_data, tmp_path, capsys):
    from pmabayes.data import Dataset, load, save

    bad = tmp_path / "bad.csv"
    bad.write_text("trial,time_s,pressure_pa,position_m\n1,0,0,0\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "r1")]) == 2
    assert "only 1 sample" in capsys.readouterr().err
    still = tmp_path / "still.csv"  # reads, but cannot be fitted: fails inside the fit
    ds = load(small_data)
    save(Dataset(time_s=ds.time_s, input=ds.input, position_m=ds.position_m * 0.0,
                 trial_ids=ds.trial_ids), still)
    assert main(["run", str(still), "--out", str(tmp_path / "r2"), "--quiet"]) == 2
    assert "every position is" in capsys.readouterr().err
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2").exists()


def test_predict_on_one_trial_says_there_is_no_noise_floor(small_data, tmp_path, capsys):
    from pmabayes.data import load, save

    one = tmp_path / "one.csv"
    save(load(small_data).select_trials([1]), one)
    assert main(["predict", str(one), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "no noise floor: one trial" in out and "nan" not in out
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())  # strict JSON
    assert summary["noise_floor_m"] is None and summary["n_trials"] == 1


@pytest.mark.parametrize(
    ("rig", "message"),
    [
        ({"colour": "red"}, "unknown rig keys ['colour']"),
        ({"area_m2": 0.0}, "area_m2 must be > 0"),
    ],
)
def test_rig_errors_name_the_file_and_the_fix(small_data, tmp_path, capsys, rig, message):
    from pmabayes.data import load, save

    ds = load(small_data)
    path = tmp_path / "rig.csv"
    save(ds, path)
    sidecar = path.with_suffix(".json")  # a rig this bad cannot be made in Python: edit it
    meta = json.loads(sidecar.read_text())
    sidecar.write_text(json.dumps({**meta, "rig": {**meta["rig"], **rig}}))
    assert main(["predict", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{path}: metadata 'rig': " in err and message in err
    assert "rename or remove" in err or "fix it" in err


def test_warnings_print_one_line_without_source(small_data, tmp_path, monkeypatch, capsys):
    import warnings

    import pmabayes.cli as cli
    from pmabayes.data import load, save

    ds = load(small_data)
    path = tmp_path / "abs.csv"
    save(dataclasses.replace(ds, input=ds.input + 101325.0), path)
    assert main(["predict", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"pmabayes predict: warning: {path}: the lowest commanded pressure")
    assert "looks like absolute pressure" in err and err.count("\n") == 1

    def noisy(args):
        warnings.warn("invalid value encountered in divide", RuntimeWarning, stacklevel=1)
        return 0

    monkeypatch.setattr(cli.data, "_cmd_effects", noisy)  # where the command lives
    assert main(["effects"]) == 0
    err = capsys.readouterr().err
    assert err == "pmabayes effects: RuntimeWarning: invalid value encountered in divide\n"


def test_unidentified_noise_names_the_file_and_the_fix(small_data, tmp_path, monkeypatch,
                                                       capsys):
    import pmabayes.inference.sampler as fit_module

    def singular(a):
        raise np.linalg.LinAlgError("singular matrix")

    # the Hessian of the noise posterior is singular when the trials do not identify it
    monkeypatch.setattr(fit_module.np.linalg, "inv", singular)
    assert main(["fit", str(small_data), "--out", str(tmp_path / "f.nc"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pmabayes fit: error: {small_data}: the noise parameters are not "
                          "identified")
    assert "record more repetitions" in err
