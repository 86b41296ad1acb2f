"""A finite-difference Jacobian's columns split with a forked child (`fit.split_columns`):
the same columns, computed again here where the child fails, and no process left."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import bench.diagnosis.fit as fit
import bench.parallel as parallel
from bench.diagnosis.fit import fd_jacobian, split_columns


def _children() -> list[str]:
    """This process's child processes, but for multiprocessing's resource tracker (started
    once by any spawned process, e.g. an earlier test's estimator, and kept for the life of
    this process by design)."""
    p = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children")
    pids = p.read_text().split() if p.exists() else []
    return [pid for pid in pids if b"resource_tracker" not in _cmdline(pid)]


def _cmdline(pid: str) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # ended meanwhile
        return b""


def _problem(n: int = 9):
    rng = np.random.default_rng(3)
    A = rng.normal(size=(40, n))
    state = {"calls": 0}

    def fun(x):
        state["calls"] += 1  # state the columns read as the parent left it
        return np.sin(A @ x) + 0.1 * (A @ x) ** 2

    x = rng.normal(size=n) * 0.3
    return fun, x, fun(x), np.full(n, 1e-6), np.full(n, -10.0), np.full(n, 10.0), state


def test_split_columns_are_the_columns():
    fun, x, f0, steps, lo, hi, state = _problem()
    plain = fd_jacobian(fun, x, f0, steps, lo, hi)
    calls = state["calls"]
    with split_columns():
        split = fd_jacobian(fun, x, f0, steps, lo, hi)
    np.testing.assert_array_equal(split, plain)
    # this process computed only its half; the child the other
    assert state["calls"] - calls == (len(x) + 1) // 2
    assert _children() == []


def test_a_child_that_fails_leaves_its_columns_to_the_parent():
    fun, x, f0, steps, lo, hi, _ = _problem()
    parent = os.getpid()

    def fragile(z):
        if os.getpid() != parent:
            raise RuntimeError("the child fails")
        return fun(z)

    plain = fd_jacobian(fun, x, f0, steps, lo, hi)
    with split_columns():
        got = fd_jacobian(fragile, x, f0, steps, lo, hi)
    np.testing.assert_array_equal(got, plain)
    assert _children() == []


def test_no_split_outside_the_context_with_no_idle_core_or_few_columns(monkeypatch):
    """Must fork nothing: outside :func:`split_columns`, where every core computes already
    (the pool's jobs, other helpers), and for fewer columns than SPLIT_MIN."""
    forks = []
    monkeypatch.setattr(fit, "fork_array", lambda fn, shape: forks.append(shape))
    monkeypatch.setattr(parallel, "_cores", lambda: 2)
    fun, x, f0, steps, lo, hi, _ = _problem()
    fd_jacobian(fun, x, f0, steps, lo, hi)
    assert forks == []
    with split_columns():
        parallel._BUSY.value = 1  # (a pool's job runs: with this process, both cores)
        fd_jacobian(fun, x, f0, steps, lo, hi)
        assert forks == [] and parallel._BUSY.value == 1
        parallel._BUSY.value = 0
        fd_jacobian(*_problem(fit.SPLIT_MIN - 1)[:6])
        assert forks == []
        fd_jacobian(fun, x, f0, steps, lo, hi)  # (fork_array stubbed: None, all columns here)
        assert len(forks) == 1 and parallel._BUSY.value == 0  # the core given back


def test_cores_claimed_and_given_back(monkeypatch):
    """The pool's creator counts itself; a worker is counted while its job runs; a helper
    forked from either claims nothing."""
    monkeypatch.setattr(parallel, "_cores", lambda: 2)
    assert not parallel.claim_core()  # no sharing here
    with split_columns():
        assert parallel.claim_core()  # this process and one helper: both cores
        assert not parallel.claim_core()
        parallel.release_core()
        assert parallel.claim_core()
        parallel.release_core()
        child = parallel.fork_array(lambda: [float(parallel.claim_core())], (1,))
        assert parallel.join_array(child)[0] == 0.0
    assert parallel._BUSY is None
    monkeypatch.setattr(parallel, "_BUSY", parallel._Private())
    monkeypatch.setattr(parallel, "_WORKER", True)
    with parallel.job_running():  # a worker's job: itself counted, one core left
        assert parallel._BUSY.value == 1
        assert parallel.claim_core()
        assert not parallel.claim_core()
        parallel.release_core()
    assert parallel._BUSY.value == 0


def _worker_view(_):
    with parallel.job_running():
        busy = parallel._BUSY
        return (None if busy is None else busy.value), parallel._WORKER


def test_a_core_sharing_pool_counts_its_running_jobs():
    pool = parallel.worker_pool(1, share_cores=True)
    try:
        assert pool.submit(_worker_view, 0).result() == (1, True)
        assert pool.busy.value == 0  # the job ended
    finally:
        parallel.terminate_workers(pool)
    plain = parallel.worker_pool(1)
    try:  # a plain pool's workers count nothing
        assert plain.submit(_worker_view, 0).result() == (None, False)
    finally:
        parallel.terminate_workers(plain)


def test_an_interrupted_parent_ends_its_child():
    """Ctrl-C (or any exception) in this process's half: the child is ended and reaped,
    the exception goes on."""
    import pytest

    fun, x, f0, steps, lo, hi, _ = _problem()
    parent = os.getpid()

    def interrupted(z):
        if os.getpid() == parent:
            raise KeyboardInterrupt
        return fun(z)

    with split_columns(), pytest.raises(KeyboardInterrupt):
        fd_jacobian(interrupted, x, f0, steps, lo, hi)
    assert _children() == []
