"""``bench.parallel.run_each`` ends a finished pool waiting: once the last outcome is
yielded and the iterator ends, the pool's worker processes have exited and its manager
thread has ended (a pool left to end by itself races Python's exit hook, which writes to
the manager's wake-up pipe as the thread closes it: ``OSError: Bad file descriptor``)."""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import threading
import time

from bench.parallel import run_each

#: how long each worker process takes to exit after the pool tells it to [s]: far longer
#: than the consumer needs to look, so a shutdown that does not wait leaves them alive
SLOW_EXIT_S = 0.5


def _slow_to_exit(i: int) -> int:
    """The item back, the worker process made to take :data:`SLOW_EXIT_S` to exit (a
    finaliser run by multiprocessing as the process ends)."""
    multiprocessing.util.Finalize(None, time.sleep, args=(SLOW_EXIT_S,), exitpriority=0)
    return i


def _manager_threads() -> list[threading.Thread]:
    """The process pools' manager threads alive in this process."""
    return [t for t in threading.enumerate()
            if type(t).__name__ == "_ExecutorManagerThread" and t.is_alive()]


def test_a_finished_pool_has_ended_its_workers_and_its_manager_thread():
    before = set(multiprocessing.active_children())
    got = sorted(o.value for o in run_each(_slow_to_exit, range(4), jobs=2))
    assert got == [0, 1, 2, 3]
    left = [p for p in multiprocessing.active_children() if p not in before]
    assert left == [], "worker processes outlived the finished pool"
    assert _manager_threads() == []

