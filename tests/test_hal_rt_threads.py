"""Raised priority of the HAL's producer threads (hal/rt_threads.py): FIFO, else nice, else
normal, always said."""

from __future__ import annotations

import os
import threading

import pytest

from hal import rt_threads
from hal.rt_threads import FALLBACK_NICE, raise_thread


def _refuse(*_):
    raise PermissionError(1, "Operation not permitted")


def test_zero_leaves_the_thread_alone():
    assert raise_thread(0).startswith("normal (raised priority not requested")


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling")
def test_out_of_range_is_refused_naming_the_range():
    with pytest.raises(ValueError, match=r"0 \(normal\) to 99"):
        raise_thread(100)


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling")
def test_fifo_where_permitted_and_not_inherited_by_threads_it_starts():
    got: dict = {}

    def producer() -> None:
        got["text"] = raise_thread(7)
        got["policy"] = os.sched_getscheduler(0)
        child = threading.Thread(target=lambda: got.update(child=os.sched_getscheduler(0)))
        child.start()
        child.join(5)

    t = threading.Thread(target=producer)
    t.start()
    t.join(5)
    if not got["text"].startswith("SCHED_FIFO"):
        pytest.skip(f"SCHED_FIFO not permitted here: {got['text']}")
    assert got["text"] == "SCHED_FIFO 7"
    assert got["policy"] & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO
    assert got["child"] == os.SCHED_OTHER  # SCHED_RESET_ON_FORK


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling")
def test_fifo_refused_falls_back_to_nice_then_to_normal_saying_why(monkeypatch):
    monkeypatch.setattr(rt_threads.os, "sched_setscheduler", _refuse)
    asked: list = []
    monkeypatch.setattr(rt_threads.os, "setpriority", lambda *a: asked.append(a))
    text = raise_thread(5, tid=12345)
    assert text.startswith(f"nice {FALLBACK_NICE} (SCHED_FIFO 5 not permitted")
    assert asked == [(os.PRIO_PROCESS, 12345, FALLBACK_NICE)]
    monkeypatch.setattr(rt_threads.os, "setpriority", _refuse)
    text = raise_thread(5)
    assert text.startswith("normal (SCHED_FIFO 5 not permitted: Operation not permitted; "
                           f"nice {FALLBACK_NICE} not permitted")
    assert "CAP_SYS_NICE" in text


def test_check_priority_names_the_range():
    assert rt_threads.check_priority(0) == 0
    with pytest.raises(ValueError, match=r"must be 0 \(normal\) to"):
        rt_threads.check_priority(-1)
