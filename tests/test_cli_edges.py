"""The edges a new user hit: no data lost, no work lost, never silent, time units
checked, and a command line that is quick and consistent. Each test names the edge it
guards; the fast ones stop the command before any real work."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _no_work(monkeypatch, *targets: str) -> None:
    """Make the named functions fail the test if called: the command must stop first."""
    import importlib

    for target in targets:
        module, name = target.rsplit(".", 1)

        def fail(*args, _name=target, **kwargs):
            raise AssertionError(f"{_name} ran: the command did not stop before the work")

        monkeypatch.setattr(importlib.import_module(module), name, fail)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Three short noisy trials from the paper's model, as `pmabayes simulate` writes them."""
    from pmabayes.data import save
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    path = tmp_path_factory.mktemp("edges") / "d.csv"
    save(generate_chirp_dataset(n_trials=3, seed=1, chirp=Chirp(duration_s=1.0)), path)
    return path


def _one_line_error(capsys, code: int, *words: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [line for line in err.splitlines() if not line.startswith("[pmabayes")]
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


# ----------------------------------------------------------------------------- 1. data lost


def test_fit_out_never_replaces_the_input(tmp_path, capsys, monkeypatch):
    _no_work(monkeypatch, "pmabayes.inference.sampler.fit")
    csv = tmp_path / "v.csv"
    csv.write_text("time_s,pressure_pa,position_m\n0,1,2\n")
    before = csv.read_bytes()
    _one_line_error(capsys, main(["fit", str(csv), "--out", str(csv)]), "is one of the "
                    "command's inputs")
    other = tmp_path / "notes.nc"  # a file of the user's, not a fit
    other.write_text("my notes")
    _one_line_error(capsys, main(["fit", str(csv), "--out", str(other)]),
                    "exists and is not a pmabayes fit", "Give a new name")
    assert csv.read_bytes() == before and other.read_text() == "my notes"


def test_simulate_writes_over_its_own_data_only(tmp_path, capsys):
    mine = tmp_path / "measured.csv"
    mine.write_text("time_s,pressure_pa,position_m\n0,1,2\n")
    _one_line_error(capsys, main(["simulate", str(mine), "--trials", "2", "--duration", "1"]),
                    "not a data set that pmabayes wrote (`pmabayes simulate` or")
    assert mine.read_text() == "time_s,pressure_pa,position_m\n0,1,2\n"
    sim = tmp_path / "sim.csv"
    sidecar = tmp_path / "sim.json"
    sidecar.write_text('{"mine": true}')  # the sidecar it would write is the user's
    _one_line_error(capsys, main(["simulate", str(sim), "--duration", "1"]), "sim.json")
    assert sidecar.read_text() == '{"mine": true}' and not sim.exists()
    sidecar.unlink()
    args = ["simulate", str(sim), "--trials", "2", "--duration", "1", "--quiet"]
    assert main(args) == 0
    assert main([*args, "--seed", "3"]) == 0  # its own output: written again


def test_json_and_folder_outputs_are_marked_and_foreign_ones_refused(data, tmp_path, capsys):
    out = tmp_path / "pred"
    assert main(["predict", str(data), "--out", str(out), "--quiet"]) == 0
    assert json.loads((out / ".pmabayes").read_text())["kind"] == "predict"
    assert main(["predict", str(data), "--out", str(out), "--quiet"]) == 0  # its own
    capsys.readouterr()
    # another command's folder, and a folder of the user's files, are refused
    _one_line_error(capsys, main(["report", "f.nc", "--out", str(out)]),
                    "it is the output of `pmabayes predict`")
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "index.html").write_text("my page")
    _one_line_error(capsys, main(["predict", str(data), "--out", str(theirs)]),
                    "holds files that `pmabayes predict` did not write")
    assert (theirs / "index.html").read_text() == "my page"
    # a JSON output carries the key "pmabayes" with its kind; a user's JSON is refused
    js = tmp_path / "t.json"
    js.write_text('{"my": "numbers"}')
    _one_line_error(capsys, main(["track", "--freq", "1", "--json", str(js)]),
                    "not the JSON output of `pmabayes track`")
    assert js.read_text() == '{"my": "numbers"}'


def test_batch_refuses_a_foreign_file_where_a_fit_would_go(data, tmp_path, capsys, monkeypatch):
    _no_work(monkeypatch, "pmabayes.inference.batch.fit_batch")
    fits = tmp_path / "fits"
    fits.mkdir()
    (fits / "d.nc").write_text("not a fit")
    _one_line_error(capsys, main(["batch", str(data), "--out", str(fits)]),
                    "d.nc exists there and is not a pmabayes fit")


# ----------------------------------------------------------------------------- 2. work lost


@pytest.mark.parametrize("where", ["file", "proc"])
def test_output_paths_are_checked_before_any_work(data, tmp_path, capsys, monkeypatch, where):
    _no_work(monkeypatch, "pmabayes.criticism.diagnosis.diagnose",
             "pmabayes.inference.sampler.fit")
    afile = tmp_path / "afile"
    afile.write_text("x")
    # under a file, or where nothing can be written even by root (/proc)
    base = afile if where == "file" else Path("/proc/pmabayes-no-such-folder")
    _one_line_error(capsys, main(["diagnose", str(data), "--json", str(base / "d.json")]),
                    "--json")
    _one_line_error(capsys, main(["fit", str(data), "--out", str(base / "f.nc")]), "--out")
    _one_line_error(capsys, main(["run", str(data), "--out", str(base / "r")]), "--out")


def test_a_folder_where_a_file_is_meant_is_refused_first(data, tmp_path, capsys, monkeypatch):
    _no_work(monkeypatch, "pmabayes.inference.sampler.fit")
    _one_line_error(capsys, main(["fit", str(data), "--out", str(tmp_path)]),
                    "this is a folder; give the name of the file")


# ----------------------------------------------------------------------------- 3. Ctrl-C


def test_ctrl_c_in_a_fit_says_what_was_saved_in_one_line(data, tmp_path, capsys, monkeypatch):
    import pmabayes.inference.sampler as sampler

    def interrupted(*args, chains_dir, **kwargs):
        Path(chains_dir).mkdir()
        (Path(chains_dir) / "ensemble_0.h5").write_bytes(b"")
        raise KeyboardInterrupt

    monkeypatch.setattr(sampler, "fit", interrupted)
    out = tmp_path / "f.nc"
    assert main(["fit", str(data), "--out", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err.strip()
    assert err == (f"pmabayes fit: interrupted: chains saved in {out}.chains; run the same "
                   "command again to resume")


def test_an_interrupted_report_leaves_no_half_page(tmp_path, capsys, monkeypatch):
    from conftest import fake_fit

    import pmabayes.report.figures as figures

    fit = fake_fit(tmp_path / "f.nc")
    out = tmp_path / "rep"

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(figures, "plot_pair", interrupted)  # after trace and rank
    assert main(["report", str(fit), "--out", str(out), "--quiet"]) == 130
    assert "interrupted: nothing was written" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.nc"]  # no PNGs, no partial


def test_a_whole_report_moves_in_at_once_and_is_named(tmp_path, capsys):
    from conftest import fake_fit

    fit = fake_fit(tmp_path / "f.nc")
    out = tmp_path / "rep"
    assert main(["report", str(fit), "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    names = sorted(p.name for p in out.iterdir())
    assert "index.html" in names and ".pmabayes" in names
    assert f"wrote the report {out}{os.sep}: " in text
    for name in names:
        if name != ".pmabayes":
            assert name in text
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o777 & ~umask  # not the temporary folder's 0o700


def test_workers_leave_ctrl_c_to_the_parent_and_show_no_progress():
    from pmabayes.parallel import Runner
    from pmabayes.util import show_progress

    with show_progress("test"), Runner(2, tasks=2) as runner:
        seen = list(runner.map(_worker_state, [0, 1]))
    assert seen == [(True, False)] * 2


def _worker_state(_):
    from pmabayes.util import progress_shown

    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN, progress_shown()


@pytest.mark.slow
def test_ctrl_c_during_sampling_prints_one_line_and_the_fit_resumes(tmp_path):
    data = tmp_path / "d.csv"
    assert main(["simulate", str(data), "--trials", "3", "--duration", "4", "--seed", "2",
                 "--quiet"]) == 0
    cmd = [sys.executable, "-m", "pmabayes", "fit", str(data), "--out", str(tmp_path / "f.nc"),
           "--walkers", "16"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    err = ""
    start = time.time()
    while "step 100 " not in err and time.time() - start < 300:
        err += os.read(proc.stderr.fileno(), 4096).decode()
    proc.send_signal(signal.SIGINT)
    out, rest = proc.communicate(timeout=60)
    assert proc.returncode == 130, rest
    assert "Traceback" not in rest and out == ""
    assert rest.strip().splitlines()[-1] == (
        f"pmabayes fit: interrupted: chains saved in {tmp_path / 'f.nc'}.chains; run the same "
        "command again to resume")
    again = subprocess.run([*cmd, "--steps", "300"], capture_output=True, text=True)
    assert again.returncode == 0 and "resuming the chains" in again.stderr


# ----------------------------------------------------------------------------- 4. where files go


def test_diagnose_writes_the_proposal_only_where_asked(data, tmp_path, capsys, monkeypatch):
    import pmabayes.criticism.diagnosis as diagnosis
    from pmabayes.data import DataError

    asked = []

    def fake(*args, plugin_dir, **kwargs):
        asked.append(plugin_dir)
        raise DataError("stop here")  # a user error: one line, exit 2

    monkeypatch.setattr(diagnosis, "diagnose", fake)
    monkeypatch.chdir(tmp_path)
    main(["diagnose", str(data), "--quiet"])
    main(["diagnose", str(data), "--out", "page", "--quiet"])
    main(["diagnose", str(data), "--out", "page", "--proposal-dir", "mine", "--quiet"])
    assert asked == [False, Path("page"), "mine"]
    assert list(tmp_path.iterdir()) == []  # the failed diagnosis left no folder


@pytest.mark.slow
def test_a_proposal_goes_into_out_and_is_named(tmp_path, capsys, monkeypatch):
    from pmabayes.data import save
    from pmabayes.synthetic import Chirp, HiddenDrag, generate_chirp_dataset

    ds = generate_chirp_dataset(n_trials=6, seed=32, chirp=Chirp(duration_s=5.0, f0_hz=0.3,
                                                                 f1_hz=3.0),
                                effects={HiddenDrag: {"c_hidden": 300.0}})
    save(ds, tmp_path / "drag.csv")
    monkeypatch.chdir(tmp_path)
    candidates = "regulator_lag,coulomb_friction,position_offset"
    assert main(["diagnose", "drag.csv", "--out", "DIR", "--candidates", candidates]) == 0
    captured = capsys.readouterr()
    written = [p for p in tmp_path.iterdir() if p.suffix == ".py"]
    assert written == []  # nothing into the current folder
    plugins = list((tmp_path / "DIR").glob("proposed_*.py"))
    assert len(plugins) == 1
    assert f"wrote {Path('DIR') / plugins[0].name} (the proposed effect)" in captured.out
    print(captured.out, captured.err)
    assert "score tests" in captured.err  # the score tests' bar
    assert "100%" not in captured.out  # the linearised estimate is never "all"
    # without --out or --proposal-dir it is checked, and not kept
    assert main(["diagnose", "drag.csv", "--candidates", candidates, "--quiet"]) == 0
    assert "was not kept: diagnose again with --proposal-dir" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DIR", "drag.csv", "drag.json"]


# ----------------------------------------------------------------------------- 5. silence


def test_progress_is_one_switch_off_by_default_and_quiet_silences_the_command(data, tmp_path,
                                                                              capsys):
    from pmabayes.util import Progress, progress_shown, show_progress

    Progress().say("not shown")
    assert not progress_shown() and capsys.readouterr().err == ""
    with show_progress("demo"):
        bar = Progress()
        bar.start(4, "runs")
        bar.advance(1)
        Progress().say("a stage")  # ends the open bar's line first
    err = capsys.readouterr().err
    assert "[pmabayes demo] [" in err and "s left)" in err
    assert "\n[pmabayes demo] a stage\n" in err and not progress_shown()
    assert main(["predict", str(data), "--out", str(tmp_path / "p")]) == 0
    assert f"[pmabayes predict] reading {data}" in capsys.readouterr().err
    assert main(["predict", str(data), "--out", str(tmp_path / "p"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_the_library_is_silent_unless_asked():
    import inspect

    from pmabayes.control.robustness import robustness_sweep
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.inference.batch import fit_batch
    from pmabayes.inference.sampler import FitSettings

    for fn in (robustness_sweep, diagnose, fit_batch):
        assert inspect.signature(fn).parameters["progress"].default is False, fn
    assert FitSettings().progress is False


def test_a_first_compile_is_announced(tmp_path, capsys, monkeypatch):
    import uuid

    import pmabayes.model.simulator as simulator
    from pmabayes.util import show_progress

    monkeypatch.setenv("PMABAYES_CACHE_DIR", str(tmp_path))
    text = f"# {uuid.uuid4()}\ndef kernel():\n    return 1\n"
    with show_progress("demo"):
        assert simulator.compile_kernel(("edge", text), text, {})() == 1
        err = capsys.readouterr().err
        assert err == "[pmabayes demo] compiling the simulator for this model (cached after)\n"
        # numba's index on disk: cached, nothing to say
        module = next((tmp_path / "kernels").glob("pmabayes_kernel_*.py")).stem
        (tmp_path / "kernels" / "__pycache__").mkdir()
        (tmp_path / "kernels" / "__pycache__" / f"{module}.kernel-2.py312.nbi").write_bytes(b"")
        simulator.compile_kernel(("edge", text, "again"), text, {})
    assert capsys.readouterr().err == ""


def test_a_status_line_is_redrawn_in_place_and_ended(capsys, monkeypatch):
    from pmabayes.util import Progress, show_progress

    monkeypatch.setattr(Progress, "_live", lambda self: True)  # a terminal
    with show_progress("demo"):
        p = Progress()
        p.status("generation 1")
        p.status("generation 2")  # within 0.5 s of the last: not drawn
        p.end()
    assert capsys.readouterr().err == "\r[pmabayes demo] generation 1\n"


def test_progress_into_a_log_is_lines_not_redraws(capsys):
    """Written to a file or a pipe (pytest's capture is one), no line is redrawn: a
    status is a line at most every 10 s, a bar a line at its start, quarters and end."""
    from pmabayes.util import Progress, show_progress

    with show_progress("demo"):
        p = Progress()
        p.status("generation 1")
        p.status("generation 2")  # within 10 s of the last: not written
        p.start(8, "runs")
        for _ in range(8):
            p.advance()
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert lines[0] == "[pmabayes demo] generation 1"
    assert [line.split("] ")[2].split()[0] for line in lines[1:]] == [
        "0/8", "2/8", "4/8", "6/8", "8/8"]


# ----------------------------------------------------------------------------- 6. time units


def test_fit_on_a_time_column_in_ms_stops_with_the_advice_before_any_fit(tmp_path, capsys,
                                                                        monkeypatch):
    _no_work(monkeypatch, "pmabayes.inference.sampler.fit")
    t = np.arange(15000)  # 15 s at 1 kHz, written as ms in a column named time_s
    p = 2e5 + 1.5e5 * np.sin(2 * np.pi * 0.5 * t * 1e-3)
    rows = [f"{k},{pk:.1f},{0.02 + 1e-7 * pk:.6f}" for k, pk in zip(t, p, strict=True)]
    path = tmp_path / "ms.csv"
    path.write_text("time_s,pressure_pa,position_m\n" + "\n".join(rows) + "\n")
    _one_line_error(capsys, main(["fit", str(path), "--out", str(tmp_path / "f.nc")]),
                    "look like milliseconds", "name the column time_ms")
    assert not (tmp_path / "f.nc").exists()


# ----------------------------------------------------------------------------- 7. advice


def test_settings_errors_name_the_flags(tmp_path, capsys):
    from pmabayes.data import save
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    one = tmp_path / "one.csv"  # a single record: the noise is sampled with the model
    save(generate_chirp_dataset(n_trials=1, seed=1, chirp=Chirp(duration_s=2.0)), one)
    _one_line_error(capsys, main(["fit", str(one), "--out", str(tmp_path / "f.nc"),
                                  "--walkers", "12", "--quiet"]),
                    "--walkers must be at least 18 (twice the 9 parameters), got 12")
    _one_line_error(capsys, main(["fit", str(one), "--out", str(tmp_path / "f.nc"),
                                  "--steps", "10", "--quiet"]), "--steps must be at least 20")
    assert not list(tmp_path.glob("f.nc*"))


@pytest.mark.parametrize("argv", [
    ["fit", "D", "--out", "f.nc", "--effects", "regulator_lagg"],
    ["run", "D", "--out", "r", "--effects", "regulator_lagg"],
    ["batch", "D", "--out", "b", "--effects", "regulator_lagg"],
    ["predict", "D", "--out", "p", "--effects", "regulator_lagg"],
    ["diagnose", "D", "--effects", "regulator_lagg"],
    ["diagnose", "D", "--candidates", "coulomb_friction,regulator_lagg"],
    ["simulate", "s.csv", "--effects", "regulator_lagg"],
])
def test_every_effect_option_suggests_a_near_name(data, tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    argv = [str(data) if a == "D" else a for a in argv]
    _one_line_error(capsys, main(argv), "unknown effect 'regulator_lagg'; did "
                    "you mean 'regulator_lag'?")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- 8. words and numbers


def _sig(rms_m: float, floor_m: float, energy: float = 5.0):
    band = SimpleNamespace(rms_m=rms_m, floor_m=floor_m)
    return SimpleNamespace(bands=[band], ratio=rms_m / floor_m, energy=energy, energy_p=0.0,
                           ljung_box_p=0.0)


def test_excess_removed_agrees_with_the_rms_errors():
    from pmabayes.criticism.bands import excess_removed

    # from 20x to 8x the floor: (400 - 64) / (400 - 1) of the excess mean square
    assert excess_removed([20.0], [8.0], [1.0], [100]) == pytest.approx(336 / 399)
    assert excess_removed([20.0, 2.0], [8.0, 1.0], [1.0, 1.0], [100, 300]) == pytest.approx(
        (100 * 336 + 300 * 3) / (100 * 399 + 300 * 3))
    assert excess_removed([5.0], [1.0], [float("nan")], [10]) is None  # no floor
    assert excess_removed([1.0], [0.5], [1.0], [10]) is None  # no excess to remove


def test_without_a_floor_the_energy_share_says_it_can_exceed_the_rms_fall():
    """Fails before the cavatappi loop, where "removes 99% of the whitened
    residual's excess energy" stood beside an RMS error that fell by 10%."""
    from pmabayes.criticism.prose import removed_text

    text = removed_text(None, 0.995, float("nan"), False)
    assert text.startswith("removes 99% of the whitened residual's excess energy")
    assert "can exceed the RMS error's fall" in text


def test_the_words_never_say_all_while_the_error_is_above_the_floor():
    from pmabayes.criticism.prose import verdict_text
    from pmabayes.criticism.results import Refit

    # the whitened energy says "everything" while the RMS error is still 8x the floor
    refit = Refit(effect="regulator_lag", values={}, interval={}, rms_m=8e-4, explained=1.0,
                  elpd=0.0, elpd_diff=50.0, elpd_diff_se=5.0, contribution_m=np.zeros(3),
                  signatures=(_sig(8e-4, 1e-4),), explained_rms=0.998, adequate=False)
    exp = SimpleNamespace(name="d", signature=_sig(2e-2, 1e-4), adequate=False,
                          floor_note=lambda: "")
    text = verdict_text("base", (), (exp,), False, "regulator_lag", {"regulator_lag": refit},
                        [], 0.9)
    assert "100%" not in text and " all " not in text
    assert "removes 99% of the mean-square error above the floor, yet the error is still 8x " \
           "the floor" in text
    assert Refit.to_dict(refit)["explained_rms"] == 0.998  # beside "explained" in the JSON
    adequate = Refit(**{**refit.__dict__, "adequate": True,
                        "signatures": (_sig(1.05e-4, 1e-4),)})
    text = verdict_text("base", (), (exp,), False, "regulator_lag",
                        {"regulator_lag": adequate}, [], 0.9)
    assert "removes 100% of the mean-square error above the floor." in text


# ----------------------------------------------------------------------------- 9. startup


def _python(code: str) -> str:
    """What a fresh interpreter prints for ``code``."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout


def test_the_command_line_and_its_parser_import_no_numerics():
    assert _python("import sys; import pmabayes.cli as c; c._parser().parse_args(['fit', "
                   "'d.csv', '--out', 'f.nc']); print(sorted(m for m in ('numpy', 'numba', "
                   "'scipy', 'xarray', 'arviz', 'matplotlib', 'h5py') if m in sys.modules))"
                   ).strip() == "[]"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pmabayes", "--help"], capture_output=True, check=True)
    assert time.perf_counter() - t0 < 3.0  # 0.14 s measured; generous on a busy machine


def test_import_pmabayes_is_lazy_and_complete():
    out = _python("import sys, pmabayes as pb; lazy = 'numpy' not in sys.modules; "
                  "print(lazy, pb.Model.__name__, pb.fit.__module__, all(hasattr(pb, n) for n "
                  "in pb.__all__), pb.__version__)")
    assert out.split() == ["True", "Model", "pmabayes.inference.sampler", "True", pb.__version__]


def test_the_parsers_literals_are_the_package_constants():
    import pmabayes.cli as cli
    from pmabayes.control import CONTROLLERS
    from pmabayes.control.robustness import MODES
    from pmabayes.inference.likelihood import NOISE_MODELS
    from pmabayes.inference.sampler import FitSettings

    assert cli.NOISE_MODELS == NOISE_MODELS
    assert cli.CONTROLLERS == CONTROLLERS and cli.MODES == MODES
    assert (cli.STEPS, cli.ENSEMBLES) == (FitSettings().max_steps, FitSettings().n_ensembles)


# ----------------------------------------------------------------------------- 10. consistency


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"pmabayes {pb.__version__}\n"


def test_batch_offers_only_what_works(capsys):
    for cmd, offered in (("batch", False), ("fit", True)):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        text = capsys.readouterr().out
        for flag in ("--tie-noise", "--exclude-trials", "--noise-model"):
            assert (flag in text) is offered, (cmd, flag)
    _one_line_error(capsys, main(["batch", "x.csv", "--out", "b", "--exclude-trials", "3"]),
                    "--exclude-trials: trial ids belong to one data file")


def test_simulate_takes_effects_and_params_like_predict(tmp_path, capsys):
    line = _one_line_error(capsys, main(["simulate", "x.csv", "--effect", "regulator_lag=0.03"]),
                           "--effect NAME=VALUE is gone", "--effects regulator_lag --param")
    assert not Path("x.csv").exists(), line
    _one_line_error(capsys, main(["simulate", "x.csv", "--param", "tau_reg=0.03"]),
                    "tau_reg: not a parameter of the base model or of the --effects given; it is "
                    "a parameter of regulator_lag: add --effects regulator_lag")
    from pmabayes.data import load

    out = tmp_path / "lag.csv"
    assert main(["simulate", str(out), "--trials", "2", "--duration", "1", "--effects",
                 "regulator_lag", "--param", "tau_reg=0.03", "--param", "d=150"]) == 0
    gen = load(out).metadata["generator"]
    assert gen["effects"] == {"regulator_lag": {"tau_reg": 0.03}}
    assert gen["parameters"]["d"] == 150.0
    assert "hidden effects: regulator_lag (tau_reg=0.03)" in capsys.readouterr().out




def test_plugin_on_either_side_and_a_broken_one_in_one_line(tmp_path, capsys):
    from test_cli import PLUGIN

    import pmabayes.cli as cli

    plugin = tmp_path / "edge.py"
    plugin.write_text(PLUGIN.replace("cli_stiction", "edge_stiction"))  # test_cli's is taken
    assert main(["effects", "--plugin", str(plugin), "--quiet"]) == 0
    assert "edge_stiction [force]" in capsys.readouterr().out
    broken = tmp_path / "broken.py"
    broken.write_text("import pmabayes\n\ndef oops(:\n")
    _one_line_error(capsys, main(["--plugin", str(broken), "effects"]),
                    f"{broken}: line 3:")
    from pmabayes.model.effects import load_plugin

    assert getattr(cli, "load_plugin", load_plugin) is load_plugin  # one loader, not a copy


def test_the_examples_in_help_parse():
    import pmabayes.cli as cli

    parser = cli._parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    examples = [p.epilog for p in sub.choices.values() if p.epilog]
    assert len(examples) >= 5
    for text in examples:
        argv = text.split("example: pmabayes ", 1)[1].split()
        assert parser.parse_args(argv).command == argv[0]


# ----------------------------------------------------------------------------- 11. the ranking


def test_the_ranking_says_what_orders_it(capsys):
    import pmabayes.cli as cli

    def finding(effect, evidence, elpd_diff=None):
        refit = None if elpd_diff is None else SimpleNamespace(elpd_diff=elpd_diff,
                                                               elpd_diff_se=5.0, failed=None)
        return SimpleNamespace(effect=effect, evidence=evidence, significant=True,
                               estimate={"k": 1.0}, refit=refit)

    # refitted first by ELPD (their evidence need not be sorted), then by evidence
    ranking = [finding("b", 50.0, 120.0), finding("a", 900.0, 30.0), finding("c", 40.0),
               finding("d", 3.0)]
    cli._print_ranking(ranking)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == ("candidates (2 refitted, ordered by their leave-one-trial-out ELPD gain; "
                        "then the others, ordered by the score test's evidence):")
    assert [line.split()[0] for line in lines[1:]] == ["b", "a", "c", "d"]
    assert "ΔELPD     +120.0 ± 5.0" in lines[1]
    implausible = finding("e", 2.0)
    implausible.implausible = "F_k = 1971 lies outside its plausible range (0 to 6.6)"
    cli._print_ranking([implausible])
    assert capsys.readouterr().out.splitlines()[1].endswith("k=1 (implausible)")


def test_fix_holds_a_parameter_at_a_value(tmp_path, capsys):
    """The docs advise fixing a parameter (``v_c``), which only the
    Python API could; ``--fix NAME=VALUE`` holds it on fit, run and diagnose."""
    import warnings

    from pmabayes.inference.fitfile import fit_info, load_fit

    data = tmp_path / "s.csv"
    assert main(["simulate", str(data), "--duration", "2", "--trials", "2", "--seed", "1",
                 "--quiet"]) == 0
    out = tmp_path / "f.nc"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # 300 steps do not converge, and need not here
        assert main(["fit", str(data), "--out", str(out), "--fix", "p_dz=0", "--steps", "300",
                     "--quiet"]) == 0
    tree = load_fit(out)
    assert fit_info(tree)["model"]["fixed"] == {"p_dz": 0.0}
    assert "p_dz" not in tree["posterior"].data_vars
    capsys.readouterr()
    _one_line_error(capsys, main(["fit", str(data), "--out", str(tmp_path / "g.nc"),
                                  "--fix", "nope=1"]), "'nope' is not a parameter")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["batch", str(data), "--out", str(tmp_path / "b"), "--fix", "p_dz=0",
                     "--steps", "300", "--quiet", "--processes", "1"]) == 0
    assert fit_info(load_fit(tmp_path / "b" / "s.nc"))["model"]["fixed"] == {"p_dz": 0.0}
    for command in ("run", "diagnose"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "--fix NAME=VALUE" in capsys.readouterr().out
