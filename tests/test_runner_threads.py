"""A runner's workers share the cores: one simulation thread each while all of them
run, and the idle cores for the last task of an uneven batch (the threads change only
how fast a batch is simulated, never its numbers)."""

from __future__ import annotations

import multiprocessing as mp
import time

import pytest

from pmabayes.model.simulator import simulation_threads
from pmabayes.parallel import Runner, can_fork
from pmabayes.util import busy_workers, local_cores

pytestmark = pytest.mark.skipif(not can_fork(), reason="the workers inherit the barrier")

#: both tasks wait here, so that each sees the other running (inherited by the fork)
_BOTH: list = [None]


def _task(long: bool) -> tuple[int | None, int, int | None, int | None]:
    _BOTH[0].wait(timeout=30)
    together = (busy_workers(), simulation_threads())
    _BOTH[0].wait(timeout=30)  # both have looked before either ends
    if not long:
        return (*together, None, None)
    deadline = time.monotonic() + 30
    while busy_workers() > 1 and time.monotonic() < deadline:  # the short one ends
        time.sleep(0.01)
    return (*together, busy_workers(), simulation_threads())


def test_the_last_task_of_a_batch_takes_the_idle_cores(monkeypatch):
    monkeypatch.delenv("PMABAYES_THREADS", raising=False)
    _BOTH[0] = mp.get_context("fork").Barrier(2)
    try:
        with Runner(2) as runner:
            short, long = runner.map(_task, [False, True])
    finally:
        _BOTH[0] = None
    cores = local_cores()
    assert short[:2] == (2, max(1, cores // 2)), short
    assert long[:2] == (2, max(1, cores // 2)), long
    assert long[2:] == (1, cores), long
    # this process is no runner's worker: all its cores, and no count
    assert busy_workers() is None and simulation_threads() == cores
