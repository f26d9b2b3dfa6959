"""One parallel runner: local worker processes, this process, or a Dask cluster.

Fit ensembles (:mod:`pmabayes.inference.sampler`), robustness sweeps
(:mod:`pmabayes.control.robustness`) and the studies in ``analyses/`` all run their
tasks through :class:`Runner`.

Local workers are forked where the platform can (spawned elsewhere): they inherit
the loaded numba kernels, where spawn re-imports numba and xarray in each (seconds
per worker), and user effects (defined in a notebook or loaded with ``--plugin``,
not importable by name) reach them without pickling.

Local workers die with their parent. On Linux each asks the kernel for SIGKILL when
its parent dies (``prctl(PR_SET_PDEATHSIG)``); everywhere a watchdog thread ends
the worker once its parent has gone (its parent process id changes). Without this,
the workers of a ``kill -9``'d fit would finish their round, write chain files
after the parent is dead, and then block forever on the pool's pipe.

Ctrl-C is the parent's to handle: local workers ignore SIGINT (which the terminal
sends to the whole process group), and a runner left by an interrupt cancels the
tasks not started and ends its workers at once, so that the user sees one line
from the command, not a traceback from every worker. A task cut short this way
writes nothing half-done: the fit's chain rounds are written to a copy and renamed.
Workers show no progress (:func:`pmabayes.util.show_progress` is off in them).

This module sits at the bottom of the house with :mod:`pmabayes.util`: it imports
nothing else from pmabayes.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed

from pmabayes.util import _BUSY, _SHOWN, local_cores

__all__ = ["Runner", "background", "can_fork"]

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
_WATCH_INTERVAL_S = 0.5


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(_WATCH_INTERVAL_S)
        if os.getppid() != parent_pid:
            os._exit(1)  # no cleanup: the parent that would read our results is gone


def _start_worker(parent_pid: int, initializer: Callable | None, initargs: tuple,
                  busy=None) -> None:
    """Tie a local worker's life to its parent, share its siblings' count of running
    tasks (``busy``), then run the caller's initializer."""
    _BUSY[0] = busy
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no usable libc
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
    _SHOWN[0] = None  # a forked worker inherits the switch: workers are silent
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True,
                     name="pmabayes-parent-watch").start()
    if initializer is not None:
        initializer(*initargs)


def _counted(fn: Callable, job):
    """``fn(job)`` in a worker, counted among its siblings' running tasks meanwhile."""
    busy = _BUSY[0]
    with busy.get_lock():
        busy.value += 1
    try:
        return fn(job)
    finally:
        with busy.get_lock():
            busy.value -= 1


def _background_main(parent_pid: int, fn: Callable, args: tuple) -> None:
    _start_worker(parent_pid, None, ())
    fn(*args)


def can_fork() -> bool:
    """Whether local workers can be forked here (they then inherit what this process has
    loaded, rather than be sent it).

    Returns
    -------
    bool
    """
    return "fork" in mp.get_all_start_methods()


def background(fn: Callable, *args) -> mp.process.BaseProcess | None:
    """Run ``fn(*args)`` in one forked local process that dies with this one.

    For work whose only product is a side effect that this process can do without, such
    as compiling simulators into numba's disk cache ahead of their use: a fork shares
    everything this process has loaded, and nothing is sent back.

    Parameters
    ----------
    fn : callable
        Called in the child; whatever it raises ends the child only.
    *args
        Its arguments (inherited, not pickled).

    Returns
    -------
    multiprocessing.Process or None
        The started child (end it with ``terminate()`` when its work is no longer
        wanted); None where processes cannot be forked.
    """
    if not can_fork():
        return None
    with warnings.catch_warnings():  # as in Runner.map: the fork of a threaded process
        warnings.filterwarnings("ignore", message=r"This process .* is multi-threaded",
                                category=DeprecationWarning)
        proc = mp.get_context("fork").Process(target=_background_main,
                                              args=(os.getpid(), fn, args), daemon=True,
                                              name="pmabayes-background")
        proc.start()
    return proc


class Runner:
    """Runs tasks in local worker processes, in this process, or on a Dask client.

    Parameters
    ----------
    processes : int, optional
        Local worker processes; by default the cores this process may use
        (:func:`pmabayes.util.local_cores`). With 1 (or one task at most) the
        tasks run in this process. Ignored when ``client`` is given.
    client : dask.distributed.Client, optional
        Run the tasks on this Dask cluster instead.
    initializer : callable, optional
        Called with ``initargs`` once in every worker (and once here when the
        tasks run in this process); not available with a Dask client.
    initargs : tuple
        Its arguments.
    tasks : int, optional
        The most tasks that will ever run at once (caps the worker count).

    Examples
    --------
    >>> with Runner(processes=1) as runner:
    ...     list(runner.map(abs, [-1, 2, -3]))
    [1, 2, 3]
    """

    def __init__(self, processes: int | None = None, *, client=None,
                 initializer: Callable | None = None, initargs: tuple = (),
                 tasks: int | None = None) -> None:
        if processes is not None and (isinstance(processes, bool) or int(processes) < 1):
            raise ValueError(f"processes must be an integer >= 1, got {processes!r}")
        if client is not None and initializer is not None:
            raise ValueError("a worker initializer cannot be used with a Dask client")
        self.client = client
        n = local_cores() if processes is None else int(processes)
        if tasks is not None:
            n = min(n, max(int(tasks), 1))
        self.processes = n
        self._initializer = initializer
        self._initargs = tuple(initargs)
        self._pool: ProcessPoolExecutor | None = None
        self._busy = None  # the workers' count of running tasks
        self._initialised_here = False

    @property
    def local(self) -> bool:
        """Whether the tasks run in this process."""
        return self.client is None and self.processes == 1

    @property
    def description(self) -> str:
        """Who runs the tasks, e.g. ``"2 local processes"`` or ``"dask (4 workers)"``."""
        if self.client is not None:
            return f"dask ({len(self.client.scheduler_info().get('workers', {}))} workers)"
        return f"{self.processes} local process{'es' if self.processes > 1 else ''}"

    def _local_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            context = mp.get_context("fork" if can_fork() else "spawn")
            self._busy = context.Value("i", 0)
            self._pool = ProcessPoolExecutor(
                self.processes, mp_context=context, initializer=_start_worker,
                initargs=(os.getpid(), self._initializer, self._initargs, self._busy))
        return self._pool

    def map(self, fn: Callable, jobs: Iterable, *, ordered: bool = True) -> Iterator:
        """Run ``fn(job)`` for every job and yield the results.

        Parameters
        ----------
        fn : callable
            A module-level function (Dask and spawned workers pickle it by name).
        jobs : iterable
            One argument per task.
        ordered : bool
            Yield in the order of ``jobs``; otherwise as the tasks complete.

        Yields
        ------
        object
            ``fn(job)`` for each job.
        """
        jobs = list(jobs)
        if self.client is not None:
            yield from self._map_dask(fn, jobs, ordered)
            return
        if self.local:
            if self._initializer is not None and not self._initialised_here:
                self._initializer(*self._initargs)
                self._initialised_here = True
            for job in jobs:
                yield fn(job)
            return
        with warnings.catch_warnings():
            # Python warns about fork in a process with threads. Here the threads are
            # OpenBLAS's pool, which reinitialises in the child (pthread_atfork);
            # numba and h5py run none. The workers fork at the first submit.
            warnings.filterwarnings("ignore", message=r"This process .* is multi-threaded",
                                    category=DeprecationWarning)
            pool = self._local_pool()
            futures = [pool.submit(_counted, fn, job) for job in jobs]
        for fut in (futures if ordered else as_completed(futures)):
            yield fut.result()

    def _map_dask(self, fn: Callable, jobs: list, ordered: bool) -> Iterator:
        try:
            from distributed import as_completed as dask_completed
        except ImportError as exc:  # pragma: no cover - a client implies distributed
            raise RuntimeError("a Dask client needs `pip install pmabayes[dask]`") from exc
        futures = self.client.map(fn, jobs, pure=False)
        # the client's loop: as_completed would look for a default client otherwise
        for fut in (futures if ordered else dask_completed(futures, loop=self.client.loop)):
            yield fut.result()

    def close(self) -> None:
        """Shut the local workers down (they are started again on the next use)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> Runner:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if (exc_type is not None and issubclass(exc_type, KeyboardInterrupt)
                and self._pool is not None):
            # interrupted: drop the tasks not started and end the workers now, not
            # after they finish theirs (they ignore SIGINT themselves)
            pool, self._pool = self._pool, None
            workers = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for w in workers:
                w.terminate()
            for w in workers:
                w.join(timeout=5)
            return
        self.close()
