"""What a real-time dry run asks of its process (bench/dryrun/realtime.py)."""

from __future__ import annotations

import gc
import os
import sys
import threading

import pytest

from bench.dryrun.realtime import realtime_interpreter, realtime_scheduling

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


@needs_sched
def test_fifo_for_the_calling_thread_only_and_restored_after():
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    ask, seen = threading.Event(), {}
    answered = threading.Event()

    def other() -> None:  # a HAL thread made before the loop starts
        ask.wait(5)
        seen["policy"] = os.sched_getscheduler(0)
        answered.set()

    t = threading.Thread(target=other)
    t.start()
    try:
        with realtime_scheduling(10) as got:
            if not got.startswith("SCHED_FIFO"):
                pytest.skip(f"real-time scheduling not permitted here: {got}")
            assert got == "SCHED_FIFO 10"
            assert os.sched_getscheduler(0) == os.SCHED_FIFO
            assert os.sched_getparam(0).sched_priority == 10
            ask.set()
            assert answered.wait(5)
            assert seen["policy"] == before[0]
    finally:
        ask.set()
        t.join(5)
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before


@needs_sched
def test_an_impossible_priority_is_refused():
    with pytest.raises(ValueError, match="priority must be 1 to"):
        with realtime_scheduling(1000):
            pass


def test_interpreter_settings_are_restored():
    interval, enabled = sys.getswitchinterval(), gc.isenabled()
    with realtime_interpreter():
        assert not gc.isenabled() and sys.getswitchinterval() == pytest.approx(5e-4)
    assert sys.getswitchinterval() == interval and gc.isenabled() == enabled
