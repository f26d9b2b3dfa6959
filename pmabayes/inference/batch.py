"""Fits of many independent data sets at once: local processes or a Dask cluster.

A batch (a set of actuators, the data sets of a study) fits each data set alone,
with :func:`pmabayes.inference.sampler.fit`, and writes each fit to ``OUT_DIR/<name>.nc``. The
parallelism is over data sets, on the one :class:`pmabayes.parallel.Runner`: local
worker processes, or the workers of a ``dask.distributed`` cluster. A fit inside a
worker runs its ensembles one after another (``processes=1``) with its own progress
off, so that the cores go to data sets and there is one progress bar, the batch's.

What a batch promises:

- **The same fit as alone.** Each data set's seed is derived from the batch's seed
  and the data set's name (:func:`dataset_seed`), so adding or removing a file does
  not change the other fits, and ``fit(dataset, model, seed=dataset_seed(seed,
  name))`` gives the batch's fit to the bit, wherever it ran.
- **One failure stops nothing.** A file that cannot be read, a rig that is wrong, a
  data set the model cannot describe: the data set is reported (its file and the
  error) and the others still fit.
- **Resumable.** Each fit file carries a fingerprint of what made it (the data, the
  model, the derived seed, the sampler settings and the pmabayes version). A data
  set whose fit file exists with the same fingerprint is skipped, and said so; one
  whose file holds another fit is fitted again and the file replaced.

The parent process reads the data and writes the fit files; the workers receive data
and return fits. So a Dask cluster needs no file system shared with this machine,
only pmabayes installed on its workers (user effects too: ``--plugin`` files are not
sent to a cluster).
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import time
import traceback
import warnings
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import h5py
import numpy as np

from pmabayes import __version__
from pmabayes.data import DataError, Dataset, load
from pmabayes.inference.errors import FitError
from pmabayes.inference.fitfile import fit_info, save_fit
from pmabayes.inference.likelihood import LikelihoodError
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.model.effects import EffectError, get_effect
from pmabayes.model.model import Model, ModelError
from pmabayes.model.parameters import Prior
from pmabayes.model.simulator import SimulationError
from pmabayes.parallel import Runner
from pmabayes.util import Progress, fingerprint

__all__ = ["BatchError", "BatchJob", "BatchResult", "dask_client", "dataset_seed", "fit_batch"]

#: the root attribute of a batch's fit file that says what made it
BATCH_ATTR = "pmabayes_batch"
#: seconds to wait for a Dask scheduler (and for its first worker) before giving up
DASK_TIMEOUT_S = 10.0

# errors that a data set's own content or declarations cause: reported in one line
_DATA_ERRORS = (DataError, ModelError, EffectError, SimulationError, LikelihoodError, FitError)


class BatchError(RuntimeError):
    """A batch cannot start: its jobs, its output folder or its Dask cluster are wrong."""


@dataclass(frozen=True)
class BatchJob:
    """One data set of a batch and the model to fit to it.

    Parameters
    ----------
    data : str, Path or Dataset
        A data file (read with :func:`pmabayes.data.load`) or a data set.
    effects : tuple of str
        Effects added to the base model (on the rig the data's sidecar records).
    name : str, optional
        Names the fit file (``<name>.nc``) and derives the seed; by default the
        file's stem (the data set's ``source`` stem for a Dataset).
    priors : mapping of str to Prior, optional
        Overrides of the default priors, by parameter name.
    fixed : mapping of str to float, optional
        Parameters held at these values, by name.
    """

    data: str | Path | Dataset
    effects: tuple[str, ...] = ()
    name: str | None = None
    priors: Mapping[str, Prior] | None = None
    fixed: Mapping[str, float] | None = None

    def resolved_name(self) -> str:
        """The data set's name: ``name``, else the stem of its file.

        Returns
        -------
        str

        Raises
        ------
        BatchError
            For a Dataset without ``source`` and without a name.
        """
        if self.name is not None:
            name = str(self.name)
        elif isinstance(self.data, Dataset):
            if not self.data.source:
                raise BatchError("a Dataset in a batch needs a name: pass "
                                 "BatchJob(dataset, name='...') (it has no source file)")
            name = Path(self.data.source).stem
        else:
            name = Path(self.data).stem
        if not name or name in (".", "..") or "/" in name or "\\" in name:
            raise BatchError(f"{name!r} cannot name a fit file; give the job another name")
        return name

    @property
    def where(self) -> str:
        """The data's file (or its source), for messages."""
        if isinstance(self.data, Dataset):
            return self.data.source or f"data set {self.name}"
        return str(self.data)


def dataset_seed(seed: int, name: str) -> int:
    """The seed of one data set's fit: from the batch's seed and the data set's name.

    Parameters
    ----------
    seed : int
        The batch's seed (>= 0).
    name : str
        The data set's name (:meth:`BatchJob.resolved_name`).

    Returns
    -------
    int
        A seed in ``[0, 2**63)``, the same for the same pair on any machine.

    Examples
    --------
    >>> dataset_seed(0, "pma_a") == dataset_seed(0, "pma_a") != dataset_seed(1, "pma_a")
    True
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"a batch's seed must be an integer >= 0, got {seed!r}")
    return int(fingerprint("pmabayes batch seed", int(seed), str(name), length=16), 16) >> 1


@contextlib.contextmanager
def dask_client(address: str, *, timeout_s: float | None = None) -> Iterator:
    """A ``dask.distributed`` client of the scheduler at ``address``, closed on exit.

    Parameters
    ----------
    address : str
        The scheduler, e.g. ``tcp://10.0.0.5:8786``.
    timeout_s : float, optional
        Seconds to wait for the scheduler, and then for at least one worker
        (:data:`DASK_TIMEOUT_S`, 10 s, by default).

    Yields
    ------
    distributed.Client

    Raises
    ------
    BatchError
        If dask.distributed is not installed, the scheduler cannot be reached in
        time, or it has no worker.
    """
    timeout_s = DASK_TIMEOUT_S if timeout_s is None else float(timeout_s)
    try:
        import distributed
    except ImportError:
        raise BatchError(f"--dask {address}: dask.distributed is not installed; "
                         "`pip install pmabayes[dask]`, or run on local processes "
                         "(--processes N)") from None
    try:
        client = distributed.Client(address, timeout=timeout_s, set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - refused, timed out, malformed, not Dask
        raise BatchError(
            f"--dask {address}: cannot reach a Dask scheduler there within {timeout_s:g} s "
            f"({type(exc).__name__}: {exc}). Start one (`dask scheduler`, then `dask worker "
            f"{address}` on each machine), check the address (tcp://HOST:8786), or run on "
            "local processes (--processes N)") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except (OSError, TimeoutError) as exc:
            raise BatchError(
                f"--dask {address}: the scheduler has no worker after {timeout_s:g} s "
                f"({type(exc).__name__}); start one with `dask worker {address}`") from None
        yield client
    finally:
        client.close()


@dataclass
class BatchResult:
    """What a batch did, data set by data set.

    Parameters
    ----------
    records : list of dict
        One per job, in the jobs' order (see :func:`fit_batch` for the keys).
    out_dir : Path
        Where the fit files are.
    seed : int
        The batch's seed.
    runner : str
        Who ran the fits (``"2 local processes"``, ``"dask (4 workers)"``).
    seconds : float
        Wall time of the batch.
    settings : dict
        The sampler settings every fit was asked for.
    """

    records: list[dict]
    out_dir: Path
    seed: int
    runner: str
    seconds: float
    settings: dict = field(default_factory=dict)

    @property
    def failed(self) -> list[dict]:
        """The records of the data sets that failed."""
        return [r for r in self.records if r["status"] == "failed"]

    @property
    def ok(self) -> bool:
        """Whether every data set has its fit (fitted now or before)."""
        return not self.failed

    def summary(self) -> dict:
        """Everything, JSON-ready (undefined numbers as None).

        Returns
        -------
        dict
            ``out_dir``, ``seed``, ``runner``, ``seconds``, ``settings``, the counts
            ``n_datasets``, ``n_fitted``, ``n_skipped``, ``n_failed``,
            ``n_not_converged``, and ``datasets``: the records.
        """
        count = {s: sum(r["status"] == s for r in self.records)
                 for s in ("fitted", "skipped", "failed")}
        return _jsonable({
            "pmabayes_version": __version__, "out_dir": str(self.out_dir), "seed": self.seed,
            "runner": self.runner, "seconds": self.seconds, "settings": self.settings,
            "n_datasets": len(self.records), "n_fitted": count["fitted"],
            "n_skipped": count["skipped"], "n_failed": count["failed"],
            "n_not_converged": sum(r.get("converged") is False for r in self.records),
            "datasets": self.records,
        })


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _as_job(item, effects: tuple[str, ...], priors: Mapping[str, Prior] | None) -> BatchJob:
    if isinstance(item, BatchJob):
        return item
    if isinstance(item, (str, Path, Dataset)):
        return BatchJob(item, effects, priors=priors)
    raise TypeError(f"a batch job is a data file, a Dataset or a BatchJob, got "
                    f"{type(item).__name__}")


def _fit_fingerprint(dataset: Dataset, model: Model, seed: int, settings: FitSettings) -> str:
    """What makes a fit file this data set's fit: the data, the model, the seed, the
    sampler settings that change the numbers, and the code's version."""
    sampling = {f.name: getattr(settings, f.name) for f in fields(settings)
                if f.name not in ("processes", "progress")}  # they do not change a fit
    return fingerprint(
        dataset.time_s, dataset.input, dataset.position_m, dataset.trial_ids,
        {"input_name": dataset.input_name, "metadata": dataset.metadata,
         "model": model.describe(), "rig": model.rig.to_dict(),
         "effects": list(model.effect_names), "fixed": dict(model.fixed), "seed": seed,
         "settings": sampling, "pmabayes_version": __version__},
    )


def _read_stamp(path: Path) -> tuple[dict, dict] | None:
    """The batch stamp and fit metadata of an existing fit file (None if unreadable):
    two root attributes, read without loading the draws."""
    try:
        with h5py.File(path, "r") as f:
            stamp, info = f.attrs.get(BATCH_ATTR), f.attrs.get("pmabayes")
    except OSError:
        return None
    if stamp is None or info is None:
        return None
    try:
        return json.loads(stamp), json.loads(info)
    except (TypeError, ValueError):
        return None


def _outcome(info: dict) -> dict:
    """A record's numbers from a fit's metadata."""
    conv = info.get("convergence") or {}
    return {"converged": conv.get("converged"), "messages": conv.get("messages", []),
            "n_steps": conv.get("n_steps"),
            "map_rms_cost_m": (info.get("map") or {}).get("rms_cost_m"),
            "noise_floor_m": (info.get("data") or {}).get("noise_floor_m"),
            "fit_seconds": (info.get("timings_s") or {}).get("total")}


def _failure(exc: BaseException) -> dict:
    """A failed record's error: the package's own errors in one line; anything else is a
    bug, so its traceback is kept."""
    out = {"status": "failed", "error": str(exc) or type(exc).__name__,
           "error_type": type(exc).__name__}
    if not isinstance(exc, _DATA_ERRORS + (OSError,)):
        out["traceback"] = "".join(traceback.format_exception(exc))
    return out


def _fit_one(task: dict) -> dict:
    """Fit one data set in a worker; the fit, or the error, never raised (one data set's
    failure must not stop the others)."""
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tree = fit(task["dataset"], task["model"], seed=task["seed"],
                       settings=task["settings"])
        # a convergence warning is in the record already (converged, messages)
        notes = sorted({str(w.message) for w in caught
                        if type(w.message).__name__ != "ConvergenceWarning"})
        return {"name": task["name"], "tree": tree, "warnings": notes,
                "seconds": time.perf_counter() - start}
    except Exception as exc:  # reported with the data set's file; see _failure
        return {"name": task["name"], **_failure(exc), "seconds": time.perf_counter() - start}


def fit_batch(
    jobs: Iterable[str | Path | Dataset | BatchJob],
    *,
    out_dir: str | Path,
    settings: FitSettings | None = None,
    seed: int = 0,
    effects: Iterable[str] = (),
    priors: Mapping[str, Prior] | None = None,
    processes: int | None = None,
    dask: str | None = None,
    runner: Runner | None = None,
    restart: bool = False,
    progress: bool = False,
) -> BatchResult:
    """Fit independent data sets in parallel, each to ``out_dir/<name>.nc``.

    Parameters
    ----------
    jobs : iterable
        Data files, data sets or :class:`BatchJob` (a data set with its own
        effects or name). Names (file stems by default) must be unique.
    out_dir : str or Path
        Folder of the fit files; created if missing.
    settings : FitSettings, optional
        Settings of every fit (sampler, substeps, noise model). Its ``progress`` is
        ignored (the batch draws one bar); its ``processes`` is used only when the
        batch runs in this process, otherwise each fit samples its ensembles one
        after another.
    seed : int
        The batch's seed; each data set's is :func:`dataset_seed` of it and the
        data set's name.
    effects : iterable of str
        Effects added to the base model of jobs given as files or data sets.
    priors : mapping of str to Prior, optional
        Prior overrides of jobs given as files or data sets.
    processes : int, optional
        Local worker processes (the cores this process may use by default).
    dask : str, optional
        Address of a Dask scheduler to run the fits on instead
        (``pip install pmabayes[dask]``).
    runner : Runner, optional
        Run on this runner instead (it is not closed here).
    restart : bool
        Fit every data set again, even those whose fit file is up to date.
    progress : bool
        One progress line on stderr: data sets done of those to fit, elapsed
        time and an estimate of the time left (also shown whenever
        :func:`pmabayes.util.show_progress` is on).
    Returns
    -------
    BatchResult
        A record per job, in order, with ``name``, ``data`` (the file), ``status``
        (``"fitted"``, ``"skipped"`` or ``"failed"``), ``seed``, ``effects``; a fit's
        ``fit_file``, ``converged``, ``messages``, ``n_steps``, ``map_rms_cost_m``,
        ``noise_floor_m``, ``fit_seconds`` and ``seconds`` (wall time in the
        worker, this run only); a failure's ``error`` and ``error_type`` (and
        ``traceback`` for an unexpected exception, which is a bug).

    Raises
    ------
    BatchError
        Before any fit: duplicate names, an output path that is a file, more than
        one of ``processes``, ``dask`` and ``runner``, or an unreachable Dask
        scheduler.
    EffectError
        An unknown effect.

    Examples
    --------
    Two files of three short chirps each, fitted one after the other in this process
    (short runs, too short to converge, for the example):

    >>> from pmabayes.data import save
    >>> from pmabayes.inference.batch import fit_batch
    >>> from pmabayes.inference.sampler import FitSettings
    >>> from pmabayes.synthetic import example_data
    >>> for seed in (1, 2):
    ...     save(example_data(seed), f"muscle_{seed}.csv")
    >>> quick = FitSettings(n_walkers=16, n_ensembles=1, max_steps=50)
    >>> result = fit_batch(["muscle_1.csv", "muscle_2.csv"], out_dir="fits", settings=quick,
    ...                    processes=1)
    >>> [(r["name"], r["status"], r["fit_file"]) for r in result.records]
    [('muscle_1', 'fitted', 'fits/muscle_1.nc'), ('muscle_2', 'fitted', 'fits/muscle_2.nc')]

    Run again, a fit whose file is up to date is skipped (``restart=True`` redoes it).
    """
    start = time.perf_counter()
    if sum(x is not None for x in (processes, dask, runner)) > 1:
        raise BatchError("give at most one of processes, dask and runner")
    dataset_seed(seed, "")  # a bad seed is refused before any work
    settings = FitSettings() if settings is None else settings
    jobs = [_as_job(j, tuple(effects), priors) for j in jobs]
    for job in jobs:
        for name in job.effects:
            get_effect(name)  # a wrong name is the call's error, not a data set's
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise BatchError(f"out_dir {out_dir}: this is a file, not a folder; give the name of "
                         "a folder (it is created if missing)")
    names = _unique_names(jobs)
    say = Progress("batch", progress)
    records, tasks = _prepare(jobs, names, out_dir, settings, seed, restart, say)
    description = "nothing to fit"
    if tasks:
        with contextlib.ExitStack() as stack:
            if runner is None:
                client = stack.enter_context(dask_client(dask)) if dask is not None else None
                runner = stack.enter_context(Runner(processes, client=client,
                                                    tasks=len(tasks)))
            description = runner.description
            out_dir.mkdir(parents=True, exist_ok=True)
            fit_settings = replace(settings, progress=False,
                                   processes=settings.processes if runner.local else 1)
            _run(runner, tasks, fit_settings, records, out_dir, say, description)
    elif runner is not None:
        description = runner.description
    for r in records.values():
        if r["status"] == "failed":  # the package's errors name the file already
            say.say(f"FAILED{'' if r['data'] in r['error'] else ' ' + r['data']}: "
                    f"{r['error']}")
    return BatchResult(records=[records[n] for n in names], out_dir=out_dir, seed=seed,
                       runner=description, seconds=time.perf_counter() - start,
                       settings=_jsonable({f.name: getattr(settings, f.name)
                                           for f in fields(settings)}))


def _unique_names(jobs: list[BatchJob]) -> list[str]:
    names, seen = [], {}
    for job in jobs:
        name = job.resolved_name()
        if name in seen:
            raise BatchError(f"{seen[name]} and {job.where} would both write {name}.nc; "
                             "rename one, or give the jobs names (BatchJob(..., name=...))")
        seen[name] = job.where
        names.append(name)
    return names


def _prepare(jobs: list[BatchJob], names: list[str], out_dir: Path, settings: FitSettings,
             seed: int, restart: bool, say: Progress) -> tuple[dict, list[dict]]:
    """Read every data set here: the records of those that fail or are up to date, and
    the tasks of the others."""
    records, tasks = {}, []
    for job, name in zip(jobs, names, strict=True):
        s = dataset_seed(seed, name)
        path = out_dir / f"{name}.nc"
        rec = {"name": name, "data": job.where, "status": None, "seed": s,
               "effects": list(job.effects),
               "priors": {k: str(v) for k, v in (job.priors or {}).items()},
               "fixed": dict(job.fixed or {}), "fit_file": str(path)}
        records[name] = rec
        try:
            dataset = job.data if isinstance(job.data, Dataset) else load(job.data)
            model = Model.for_dataset(dataset, job.effects, priors=job.priors,
                                      fixed=job.fixed or None)
        except (*_DATA_ERRORS, OSError) as exc:
            rec.update(_failure(exc), fit_file=None)
            continue
        key = _fit_fingerprint(dataset, model, s, settings)
        stamp = _read_stamp(path) if path.exists() else None
        if stamp is not None and stamp[0].get("fingerprint") == key and not restart:
            rec.update(status="skipped", **_outcome(stamp[1]))
            say.say(f"{name}: {path} is this fit already (same data, model, seed and "
                    "settings); skipped")
            continue
        if path.exists():
            say.say(f"{name}: {path} holds another fit (or none readable); fitting again, "
                    "it will be replaced" if not restart else f"{name}: fitting again")
        rec["fingerprint"] = key
        tasks.append({"name": name, "dataset": dataset, "model": model, "seed": s})
    return records, tasks


def _run(runner: Runner, tasks: list[dict], settings: FitSettings, records: dict,
         out_dir: Path, say: Progress, description: str) -> None:
    """Fit the tasks on ``runner``, writing each fit as it arrives."""
    say.say(f"fitting {len(tasks)} data set{'s' if len(tasks) != 1 else ''} on {description}")
    say.start(len(tasks), "data sets")
    t0 = time.perf_counter()
    results = runner.map(_fit_one, [{**t, "settings": settings} for t in tasks], ordered=False)
    for k in range(1, len(tasks) + 1):
        try:
            out = next(results)
        except Exception as exc:  # noqa: BLE001 - the runner itself: a worker died
            _runner_failed(exc, tasks, records, say)
            return
        rec = records[out["name"]]
        if "tree" in out:
            _save(out, rec, out_dir)
        else:
            rec.pop("fingerprint", None)
            rec.update({k2: v for k2, v in out.items() if k2 != "name"}, fit_file=None)
        elapsed = time.perf_counter() - t0
        say.label = (f"ETA {elapsed / k * (len(tasks) - k):.0f} s" if k < len(tasks)
                     else "done")
        say.advance()


def _save(out: dict, rec: dict, out_dir: Path) -> None:
    """Write a worker's fit, stamped with what made it, and fill in its record."""
    tree = out["tree"]
    tree.attrs[BATCH_ATTR] = json.dumps({"fingerprint": rec.pop("fingerprint"),
                                         "name": rec["name"], "seed": rec["seed"],
                                         "data": rec["data"]})
    path = out_dir / f"{out['name']}.nc"
    try:
        save_fit(tree, path)
    except OSError as exc:  # a full disk, a read-only folder: this fit is lost, not others
        rec.update(_failure(exc), fit_file=None,
                   error=f"{path}: cannot write the fit of {rec['data']}: {exc}")
        return
    rec.update(status="fitted", **_outcome(fit_info(tree)), seconds=out["seconds"],
               warnings=out["warnings"])


def _runner_failed(exc: Exception, tasks: list[dict], records: dict, say: Progress) -> None:
    """Mark the data sets left when the runner broke (a worker killed, out of memory):
    the fits written so far stay, and the same call fits the others."""
    if say.enabled:  # end the progress line
        print(file=say.stream if say.stream is not None else sys.stderr, flush=True)
    say.say(f"the runner failed ({type(exc).__name__}); the data sets left are reported")
    for t in tasks:
        rec = records[t["name"]]
        if rec["status"] is None:
            rec.pop("fingerprint", None)
            rec.update(status="failed", fit_file=None, error_type=type(exc).__name__,
                       error=f"{rec['data']}: not fitted: the runner failed before this data "
                             f"set's fit came back ({type(exc).__name__}: {exc}); a worker "
                             "may have been killed or run out of memory. Run the same batch "
                             "again: the fits written are kept and the others are fitted")
