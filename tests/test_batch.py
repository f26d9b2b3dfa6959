"""Batches of independent fits: the same fits as alone, failures reported, resume, Dask."""

import contextlib
import json
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pmabayes import Model
from pmabayes.cli import main
from pmabayes.data import load, save
from pmabayes.inference import batch
from pmabayes.inference.batch import BatchError, BatchJob, dask_client, dataset_seed, fit_batch
from pmabayes.inference.errors import FitError
from pmabayes.inference.fitfile import fit_info, load_fit
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.model.effects import EffectError
from pmabayes.model.parameters import parse_prior
from pmabayes.synthetic import Chirp, generate_chirp_dataset

CHIRP = Chirp(duration_s=2.0, f0_hz=0.3, f1_hz=2.0, sample_rate_hz=500.0)
# what `pmabayes batch --walkers 12 --ensembles 2 --steps 40` asks for (so the CLI test
# finds these fits up to date): a short run, not converged, enough to compare bits
TINY = FitSettings(n_walkers=12, n_ensembles=2, max_steps=40)
NAMES = ("pma_a", "pma_b", "pma_c")


def _write_data(folder: Path, names=NAMES, seed0: int = 20) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, name in enumerate(names):
        save(generate_chirp_dataset(n_trials=3, seed=seed0 + i, chirp=CHIRP),
             folder / f"{name}.csv")
        paths.append(folder / f"{name}.csv")
    return paths


def _broken(folder: Path) -> Path:
    path = folder / "broken.csv"
    path.write_text("trial,time_s,pressure_pa\n0,0.0,1.0\n")  # no position column
    return path


@contextlib.contextmanager
def _stderr_to(path: Path):
    """Send standard error to a file, as ``sys.stderr`` and as file descriptor 2, so that
    what forked worker processes write is caught too."""
    saved = os.dup(2)
    with open(path, "w") as fh, contextlib.redirect_stderr(fh):
        os.dup2(fh.fileno(), 2)
        try:
            yield
        finally:
            fh.flush()
            os.dup2(saved, 2)
            os.close(saved)


# ---------------------------------------------------------------------------------
# fast: seeds, names, errors before any fit


def test_dataset_seed_depends_on_the_batch_seed_and_the_name_only():
    assert dataset_seed(0, "pma_a") == dataset_seed(0, "pma_a")
    seeds = {dataset_seed(s, n) for s in (0, 1) for n in ("pma_a", "pma_b")}
    assert len(seeds) == 4 and all(0 <= s < 2**63 for s in seeds)
    with pytest.raises(ValueError, match="integer >= 0"):
        dataset_seed(-1, "pma_a")


def test_the_fingerprint_changes_with_what_changes_a_fit():
    ds = generate_chirp_dataset(n_trials=2, seed=1, chirp=CHIRP)
    key = batch._fit_fingerprint(ds, Model(), 5, TINY)
    # the runner's processes and the progress do not change a fit
    assert batch._fit_fingerprint(ds, Model(), 5, replace(TINY, processes=1,
                                                          progress=True)) == key
    other_data = generate_chirp_dataset(n_trials=2, seed=2, chirp=CHIRP)
    changed = [
        batch._fit_fingerprint(other_data, Model(), 5, TINY),
        batch._fit_fingerprint(ds, Model(["regulator_lag"]), 5, TINY),
        batch._fit_fingerprint(ds, Model(priors={"K_e": parse_prior("LogNormal(5e4, 2)")}),
                               5, TINY),
        batch._fit_fingerprint(ds, Model(), 6, TINY),
        batch._fit_fingerprint(ds, Model(), 5, replace(TINY, max_steps=60)),
        batch._fit_fingerprint(ds, Model(), 5, replace(TINY, substeps=2)),
    ]
    assert key not in changed and len(set(changed)) == len(changed)


def test_names_must_be_unique_and_are_checked_before_any_work(tmp_path):
    a, b = tmp_path / "one" / "pma.csv", tmp_path / "two" / "pma.csv"
    out = tmp_path / "fits"
    with pytest.raises(BatchError, match=r"one/pma\.csv and .*two/pma\.csv would both write "
                                         r"pma\.nc"):
        fit_batch([a, b], out_dir=out, processes=1, progress=False)
    assert not out.exists()
    ds = generate_chirp_dataset(n_trials=2, seed=1, chirp=CHIRP)
    with pytest.raises(BatchError, match="needs a name"):
        fit_batch([ds], out_dir=out, processes=1, progress=False)
    with pytest.raises(BatchError, match="cannot name a fit file"):
        fit_batch([BatchJob(ds, name="sub/pma")], out_dir=out, processes=1, progress=False)
    with pytest.raises(EffectError):
        fit_batch([a], out_dir=out, effects=["no_such_effect"], processes=1, progress=False)
    with pytest.raises(ValueError, match="integer >= 0"):
        fit_batch([a], out_dir=out, seed=-1, processes=1, progress=False)
    with pytest.raises(BatchError, match="at most one"):
        fit_batch([a], out_dir=out, processes=1, dask="tcp://127.0.0.1:1", progress=False)
    assert not out.exists()


def test_unreadable_data_sets_are_reported_each_with_its_file(tmp_path):
    bad_rig = tmp_path / "bad_rig.csv"
    save(generate_chirp_dataset(n_trials=2, seed=1, chirp=CHIRP), bad_rig)
    sidecar = bad_rig.with_suffix(".json")
    meta = json.loads(sidecar.read_text())
    meta["rig"] = {"moving_mass_kg": -1.0}  # refused on reading, naming the file
    sidecar.write_text(json.dumps(meta))
    missing = tmp_path / "missing.csv"
    res = fit_batch([_broken(tmp_path), missing, bad_rig], out_dir=tmp_path / "fits",
                    processes=1, progress=False)
    assert not res.ok and [r["status"] for r in res.records] == ["failed"] * 3
    for rec, path in zip(res.records, ["broken.csv", "missing.csv", "bad_rig.csv"],
                         strict=True):
        assert rec["data"].endswith(path) and path in rec["error"], rec
        assert rec["fit_file"] is None and "traceback" not in rec
    assert "position_m" in res.records[0]["error"]
    json.dumps(res.summary())  # JSON-able as it is


def _fake_fit(dataset, model, *, seed, settings):
    """Stands in for the sampler (forked workers inherit it): a bug, or bad data."""
    if dataset.metadata.get("kind") == "bug":
        raise ZeroDivisionError("a bug")
    raise FitError(f"{dataset.source}: this data set cannot be fitted")


def _tiny_jobs(kinds) -> list[BatchJob]:
    jobs = []
    for i, kind in enumerate(kinds):
        ds = generate_chirp_dataset(n_trials=2, seed=i, chirp=CHIRP)
        ds = replace(ds, metadata={**ds.metadata, "kind": kind}, source=f"{kind}_{i}.csv")
        jobs.append(BatchJob(ds, name=f"{kind}_{i}"))
    return jobs


@pytest.mark.parametrize("processes", [1, 2])
def test_a_fit_that_raises_is_reported_and_a_bug_keeps_its_traceback(tmp_path, monkeypatch,
                                                                      processes):
    monkeypatch.setattr(batch, "fit", _fake_fit)
    res = fit_batch(_tiny_jobs(["bug", "bad"]), out_dir=tmp_path, processes=processes,
                    progress=False)
    bug, bad = res.records
    assert (bug["status"], bug["error_type"], bad["status"], bad["error_type"]) == (
        "failed", "ZeroDivisionError", "failed", "FitError")
    assert "ZeroDivisionError: a bug" in bug["traceback"] and "_fake_fit" in bug["traceback"]
    assert "traceback" not in bad and bad["error"] == "bad_1.csv: this data set cannot be fitted"
    assert list(tmp_path.iterdir()) == []


def test_a_worker_that_dies_fails_the_data_sets_left_with_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(batch, "fit", lambda *a, **k: os._exit(3))  # killed, out of memory
    res = fit_batch(_tiny_jobs(["dies", "dies"]), out_dir=tmp_path, processes=2,
                    progress=False)
    for rec in res.records:
        assert rec["status"] == "failed" and rec["error_type"] == "BrokenProcessPool"
        assert "not fitted: the runner failed" in rec["error"] and "again" in rec["error"]
        assert rec["data"] in rec["error"]


def test_cli_batch_reports_failures_and_exits_1(tmp_path, capsys):
    report = tmp_path / "batch.json"
    code = main(["batch", str(_broken(tmp_path)), "--out", str(tmp_path / "fits"),
                 "--json", str(report), "--quiet", "--processes", "1"])
    assert code == 1
    out = capsys.readouterr().out
    assert "broken: FAILED: " in out and "1 failed" in out
    summary = json.loads(report.read_text())
    assert summary["n_failed"] == 1 and summary["datasets"][0]["error_type"] == "DataError"
    assert main(["batch", "x.csv", "--out", str(tmp_path / "f"), "--processes", "2",
                 "--dask", "tcp://127.0.0.1:1"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["batch", "x.csv", "--out", str(tmp_path / "f"), "--tie-noise"]) == 2
    assert "fitted alone" in capsys.readouterr().err


def test_an_unreachable_scheduler_is_a_clear_error_within_the_timeout(tmp_path, capsys,
                                                                      monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(batch, "DASK_TIMEOUT_S", 1.0)  # the CLI's wait, shortened
    with pytest.raises(BatchError, match=r"tcp://127\.0\.0\.1:1: cannot reach a Dask "
                                         r"scheduler there within 1 s.*dask worker"):
        with dask_client("tcp://127.0.0.1:1", timeout_s=1.0):
            pass
    data = _write_data(tmp_path / "data", names=("pma_a",))
    code = main(["batch", str(data[0]), "--out", str(tmp_path / "fits"),
                 "--dask", "127.0.0.1:1"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--dask 127.0.0.1:1: cannot reach a Dask scheduler there within 1 s" in err
    assert "--processes N" in err
    assert not (tmp_path / "fits").exists()


# ---------------------------------------------------------------------------------
# slow: real fits


@pytest.fixture(scope="module")
def batch_run():
    """Three small data sets and a broken file, fitted on 2 local processes."""
    with tempfile.TemporaryDirectory(prefix="pmabayes-batch-test-") as tmp:
        root = Path(tmp)
        files = [*_write_data(root / "data"), _broken(root / "data")]
        log = root / "stderr.txt"
        with _stderr_to(log):
            result = fit_batch(files, out_dir=root / "fits", settings=TINY, seed=7,
                               processes=2, progress=True)
        yield {"root": root, "files": files, "result": result, "stderr": log.read_text()}


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::pmabayes.inference.ConvergenceWarning")  # tiny, on purpose
def test_batch_on_two_processes_gives_the_fits_made_alone(batch_run):
    res = batch_run["result"]
    assert res.runner == "2 local processes"
    assert [r["status"] for r in res.records] == ["fitted"] * 3 + ["failed"]
    for path, rec in zip(batch_run["files"][:3], res.records[:3], strict=True):
        assert rec["seed"] == dataset_seed(7, path.stem)
        ds = load(path)
        alone = fit(ds, Model.for_dataset(ds), seed=rec["seed"],
                    settings=replace(TINY, processes=1))
        batched = load_fit(rec["fit_file"])
        for group in ("posterior", "sample_stats", "log_likelihood"):
            for var in alone[group].data_vars:
                np.testing.assert_array_equal(batched[group][var].values,
                                              alone[group][var].values, err_msg=f"{group}/{var}")
        info = fit_info(batched)
        assert rec["map_rms_cost_m"] == info["map"]["rms_cost_m"] > 0
        assert rec["converged"] is info["convergence"]["converged"]
    # one progress bar, the batch's: the fits in the workers print nothing
    err = batch_run["stderr"]
    assert "3/3 data sets" in err and "[pmabayes fit]" not in err, err
    assert "ConvergenceWarning" not in err and "did NOT converge" not in err, err


@pytest.mark.slow
def test_a_broken_file_is_reported_and_the_others_fit(batch_run):
    res = batch_run["result"]
    broken = res.records[-1]
    assert broken["status"] == "failed" and broken["data"].endswith("broken.csv")
    assert "broken.csv" in broken["error"] and "position_m" in broken["error"]
    assert "FAILED" in batch_run["stderr"] and "broken.csv" in batch_run["stderr"]
    assert sorted(p.name for p in (batch_run["root"] / "fits").iterdir()) == [
        f"{n}.nc" for n in NAMES]
    summary = json.loads(json.dumps(res.summary()))
    assert (summary["n_fitted"], summary["n_failed"], summary["n_datasets"]) == (3, 1, 4)


@pytest.mark.slow
def test_resume_skips_fits_that_are_up_to_date_and_redoes_changed_data(batch_run, tmp_path,
                                                                        capfd):
    fits = tmp_path / "fits"
    shutil.copytree(batch_run["root"] / "fits", fits)
    files = batch_run["files"]
    before = {p.name: p.stat().st_mtime_ns for p in fits.iterdir()}
    again = fit_batch(files, out_dir=fits, settings=TINY, seed=7, processes=2, progress=True)
    assert [r["status"] for r in again.records] == ["skipped"] * 3 + ["failed"]
    assert {p.name: p.stat().st_mtime_ns for p in fits.iterdir()} == before
    assert [r["map_rms_cost_m"] for r in again.records[:3]] == [
        r["map_rms_cost_m"] for r in batch_run["result"].records[:3]]
    assert capfd.readouterr().err.count("skipped") == 3
    # the CLI with the same settings finds them up to date too
    code = main(["batch", *map(str, files), "--out", str(fits), "--seed", "7", "--walkers",
                 "12", "--ensembles", "2", "--steps", "40", "--json", str(tmp_path / "b.json")])
    assert code == 1  # the broken file
    out = capfd.readouterr().out
    assert out.count("skipped, up to date") == 3 and "broken: FAILED: " in out
    # other data under the same name: fitted again, the others still skipped
    changed = tmp_path / "data"
    new_files = _write_data(changed, names=("pma_b",), seed0=99)
    third = fit_batch([files[0], new_files[0], files[2]], out_dir=fits, settings=TINY,
                      seed=7, processes=1, progress=False)
    assert [r["status"] for r in third.records] == ["skipped", "fitted", "skipped"]
    assert fits.joinpath("pma_b.nc").stat().st_mtime_ns != before["pma_b.nc"]


@pytest.mark.slow
def test_dask_gives_the_local_fits(batch_run, tmp_path):
    distributed = pytest.importorskip("distributed")
    # one of the three files: a data set's fit does not depend on the others in its batch
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        res = fit_batch(batch_run["files"][1:2], out_dir=tmp_path / "fits", settings=TINY,
                        seed=7, dask=cluster.scheduler_address, progress=False)
    assert res.runner.startswith("dask") and res.records[0]["status"] == "fitted"
    local, remote = (load_fit(r["fit_file"]) for r in (batch_run["result"].records[1],
                                                       res.records[0]))
    for var in local["posterior"].data_vars:
        np.testing.assert_array_equal(remote["posterior"][var].values,
                                      local["posterior"][var].values)
