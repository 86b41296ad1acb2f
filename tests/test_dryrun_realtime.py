"""What a real-time dry run asks of its process (bench/dryrun/realtime.py)."""

from __future__ import annotations

import gc
import os
import subprocess
import sys
import threading

import pytest

from bench.dryrun.realtime import (
    helper_priority,
    helper_threads,
    realtime_interpreter,
    realtime_scheduling,
    simulator_scheduling,
)

needs_sched = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"),
                                 reason="no POSIX scheduling on this system")


def test_priority_zero_leaves_the_scheduling_alone():
    with realtime_scheduling(0) as got:
        assert got.startswith("normal")


@needs_sched
def test_a_refused_real_time_policy_runs_normally_and_says_why(monkeypatch):
    before = os.sched_getscheduler(0)

    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with realtime_scheduling(50) as got:
        assert got.startswith("normal (SCHED_FIFO 50 not permitted")
        assert "CAP_SYS_NICE" in got
        assert os.sched_getscheduler(0) == before


def _policy(tid: int) -> tuple[int, int]:
    """(policy without SCHED_RESET_ON_FORK, priority) of a thread."""
    flag = getattr(os, "SCHED_RESET_ON_FORK", 0)
    return os.sched_getscheduler(tid) & ~flag, os.sched_getparam(tid).sched_priority


@needs_sched
def test_fifo_for_the_loop_and_one_below_for_the_threads_it_waits_for_restored_after():
    before = _policy(0)
    ready, ask, answered = threading.Event(), threading.Event(), threading.Event()
    release = threading.Event()
    seen: dict = {}

    def other() -> None:  # a HAL thread made before the loop starts (CAN receive, poller)
        seen["tid"] = threading.get_native_id()
        seen["before"] = _policy(0)
        ready.set()
        ask.wait(5)
        seen["inside"] = _policy(0)
        answered.set()
        release.wait(5)  # still running when the loop's scheduling ends

    t = threading.Thread(target=other)
    t.start()
    assert ready.wait(5)
    try:
        with realtime_scheduling(10) as got:
            if not got.startswith("SCHED_FIFO"):
                pytest.skip(f"real-time scheduling not permitted here: {got}")
            assert got == "SCHED_FIFO 10"
            assert _policy(0) == (os.SCHED_FIFO, 10)
            ask.set()
            assert answered.wait(5)
            assert seen["inside"] == (os.SCHED_FIFO, 9)
        assert _policy(seen["tid"]) == seen["before"]  # restored while it still runs
    finally:
        ask.set()
        release.set()
        t.join(5)
    assert _policy(0) == before


@needs_sched
def test_threads_started_by_the_real_time_loop_run_normal_until_raised_as_helpers():
    """A thread the loop starts inside (the HAL's start-up) does not inherit its FIFO
    priority (SCHED_RESET_ON_FORK: neither does a process it spawns); helper_threads puts
    it one below the loop, and restores it after."""
    before = _policy(0)
    ask, answered, release = threading.Event(), threading.Event(), threading.Event()
    seen: dict = {}

    def started_inside() -> None:
        seen["tid"] = threading.get_native_id()
        seen["at_start"] = _policy(0)
        ask.wait(5)
        seen["raised"] = _policy(0)
        answered.set()
        release.wait(5)

    with realtime_scheduling(10) as got:
        if not got.startswith("SCHED_FIFO"):
            pytest.skip(f"real-time scheduling not permitted here: {got}")
        t = threading.Thread(target=started_inside)
        t.start()
        try:
            child = subprocess.run([sys.executable, "-c", "import os; print("
                                    "os.sched_getscheduler(0))"], capture_output=True,
                                   text=True, check=True)
            assert int(child.stdout) == os.SCHED_OTHER
            with helper_threads(10) as n:
                assert n >= 1
                ask.set()
                assert answered.wait(5)
            assert seen["at_start"] == (os.SCHED_OTHER, 0)
            assert seen["raised"] == (os.SCHED_FIFO, 9)
            assert _policy(seen["tid"]) == (os.SCHED_OTHER, 0)  # restored
        finally:
            ask.set()
            release.set()
            t.join(5)
    assert _policy(0) == before


def test_helper_priority_is_one_below_and_never_below_one():
    assert [helper_priority(p) for p in (0, -3, 1, 2, 50, 99)] == [0, 0, 1, 1, 49, 98]


@needs_sched
def test_simulator_scheduling_every_thread_and_the_switch_interval_restored_after():
    before, interval = _policy(0), sys.getswitchinterval()
    ready, done = threading.Event(), threading.Event()
    seen: dict = {}

    def other() -> None:  # a thread already running when the simulator asks
        seen["tid"] = threading.get_native_id()
        seen["before"] = _policy(0)
        ready.set()
        done.wait(5)

    t = threading.Thread(target=other)
    t.start()
    assert ready.wait(5)
    try:
        with simulator_scheduling(7) as got:
            if not got.startswith("SCHED_FIFO"):
                pytest.skip(f"real-time scheduling not permitted here: {got}")
            assert got == "SCHED_FIFO 7"
            assert _policy(0) == (os.SCHED_FIFO, 7)
            assert _policy(seen["tid"]) == (os.SCHED_FIFO, 7)
            assert sys.getswitchinterval() == pytest.approx(5e-4)
            child: dict = {}
            c = threading.Thread(target=lambda: child.update(p=_policy(0)))  # made inside
            c.start()
            c.join(5)
            assert child["p"] == (os.SCHED_FIFO, 7)
        assert _policy(seen["tid"]) == seen["before"]
    finally:
        done.set()
        t.join(5)
    assert _policy(0) == before and sys.getswitchinterval() == interval


def test_simulator_scheduling_zero_and_refused(monkeypatch):
    with simulator_scheduling(0) as got:
        assert got.startswith("normal (real-time priority not requested")
    if not hasattr(os, "sched_setscheduler"):
        return

    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    interval = sys.getswitchinterval()
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with simulator_scheduling(20) as got:
        assert got.startswith("normal (SCHED_FIFO 20 not permitted") and "CAP_SYS_NICE" in got
        assert sys.getswitchinterval() == interval


@needs_sched
def test_an_impossible_priority_is_refused():
    with pytest.raises(ValueError, match="priority must be 0 \\(normal\\) to"):
        with realtime_scheduling(1000):
            pass


def test_interpreter_settings_are_restored():
    interval, enabled = sys.getswitchinterval(), gc.isenabled()
    with realtime_interpreter():
        assert not gc.isenabled() and sys.getswitchinterval() == pytest.approx(5e-4)
    assert sys.getswitchinterval() == interval and gc.isenabled() == enabled
