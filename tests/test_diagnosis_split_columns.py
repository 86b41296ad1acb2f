"""A finite-difference Jacobian's columns split with a forked child (`fit.split_columns`):
the same columns, computed again here where the child fails, and no process left."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import bench.diagnosis.fit as fit
from bench.diagnosis.fit import fd_jacobian, split_columns


def _children() -> list[str]:
    p = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children")
    return p.read_text().split() if p.exists() else []


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


def test_no_split_outside_the_context_or_in_another_process(monkeypatch):
    """Must fork nothing: outside :func:`split_columns`, in a process other than the one that
    entered it (a pool worker forked later), and for fewer columns than SPLIT_MIN."""
    forks = []
    monkeypatch.setattr(fit, "fork_array", lambda fn, shape: forks.append(shape))
    fun, x, f0, steps, lo, hi, _ = _problem()
    fd_jacobian(fun, x, f0, steps, lo, hi)
    monkeypatch.setattr(fit, "_SPLIT_PID", os.getpid() + 1)
    fd_jacobian(fun, x, f0, steps, lo, hi)
    monkeypatch.setattr(fit, "_SPLIT_PID", os.getpid())
    small = _problem(fit.SPLIT_MIN - 1)
    fd_jacobian(*small[:6])
    assert forks == []
    fd_jacobian(fun, x, f0, steps, lo, hi)  # (fork_array stubbed: None, all columns here)
    assert len(forks) == 1


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
