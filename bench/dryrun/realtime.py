"""What a real-time control loop asks of its process and operating system.

- The interpreter (:func:`realtime_interpreter`): no automatic garbage collection (the loop
  collects the young generation in its slack) and a short GIL switch interval, so that the
  loop gets the interpreter back quickly from the HAL's threads (CAN receive, load-cell
  poller, tracker).
- The scheduler (:func:`realtime_scheduling`): the loop's thread in ``SCHED_FIFO`` at a
  given priority when the system permits it (root, ``CAP_SYS_NICE``, or an ``rtprio``
  limit in ``/etc/security/limits.conf``), as ``ros2_control``'s controller manager does
  for its update thread, and the process's other threads (the HAL's CAN receiver,
  load-cell poller, tracker reader, heartbeat producer) one priority below: the loop
  waits for what they receive, and on a loaded machine a thread under the normal
  scheduler waits behind other runnable threads for tens of milliseconds now and then,
  long enough for the drives' answers to look late. Otherwise the normal scheduler, said
  plainly. The loop's policy carries ``SCHED_RESET_ON_FORK``: what it starts (a thread of
  the HAL's start-up, the recorder's or the estimator's process) runs normally until
  raised on purpose (:func:`helper_threads` for threads started since). The loop never
  spins with the interpreter held (see :class:`bench.dryrun.loop.CycleClock`), so a
  real-time thread cannot starve the threads it needs.
- The simulated robot in its own process (:func:`simulator_scheduling`, ``cdpr sim
  --rt-priority``): all its threads in ``SCHED_FIFO`` one priority below the loop's (the
  simulator stands for hardware, which never waits for a busy host) and the same short
  switch interval.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import threading
from collections.abc import Iterator

from hal.rt_threads import check_priority, fifo_policy

#: ``SCHED_FIFO`` priority of a real-time dry run's loop thread (1..99; 0: normal
#: scheduling); ros2_control's default for its update thread is 50
DEFAULT_RT_PRIORITY = 50
#: the GIL switch interval of a real-time process [s]
SWITCH_INTERVAL_S = 5e-4


def helper_priority(priority: int) -> int:
    """The ``SCHED_FIFO`` priority of the threads a loop at ``priority`` waits for (the
    HAL's threads, the simulated robot): one below, at least 1; 0 stays 0 (normal)."""
    return 0 if priority <= 0 else max(1, priority - 1)


@contextlib.contextmanager
def realtime_interpreter() -> Iterator[None]:
    """No automatic GC and a 0.5 ms GIL switch interval inside; restored after."""
    was_enabled = gc.isenabled()
    interval = sys.getswitchinterval()
    gc.collect()
    gc.disable()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        yield
    finally:
        sys.setswitchinterval(interval)
        if was_enabled:
            gc.enable()


def _other_threads() -> list[int]:
    """Kernel ids of this process's threads but the calling one (Linux: every thread in
    ``/proc/self/task``; elsewhere the Python threads)."""
    me = threading.get_native_id()
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [t.native_id for t in threading.enumerate() if t.native_id is not None]
    return [t for t in tids if t != me]


def _set_fifo(tids: list[int], priority: int, reset_on_fork: bool = True
              ) -> list[tuple[int, int, os.sched_param]]:
    """Threads ``tids`` to SCHED_FIFO at ``priority`` where permitted (a thread that ended
    meanwhile is skipped); their (tid, policy, param) before, for :func:`_restore`."""
    saved = []
    for tid in tids:
        try:
            before = os.sched_getscheduler(tid), os.sched_getparam(tid)
            os.sched_setscheduler(tid, fifo_policy(reset_on_fork), os.sched_param(priority))
        except OSError:
            continue
        saved.append((tid, *before))
    return saved


def _restore(saved: list[tuple[int, int, os.sched_param]]) -> None:
    for tid, policy, param in saved:
        try:
            os.sched_setscheduler(tid, policy, param)
        except OSError:  # the thread ended
            pass


def _enter_fifo(priority: int, reset_on_fork: bool = True
                ) -> tuple[str | None, tuple | None]:
    """The calling thread in ``SCHED_FIFO`` at ``priority`` (threads it starts inherit it
    unless ``reset_on_fork``): ``(None, its policy and
    parameters before)`` when done, else ``(why not, None)`` as the text the scheduling
    context managers yield (``"normal (...why...)"``)."""
    if priority <= 0:
        return "normal (real-time priority not requested)", None
    if not hasattr(os, "sched_setscheduler"):
        return "normal (this system has no SCHED_FIFO)", None
    check_priority(priority)
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, fifo_policy(reset_on_fork), os.sched_param(priority))
    except OSError as exc:
        return (f"normal (SCHED_FIFO {priority} not permitted: {exc.strerror}; grant "
                f"CAP_SYS_NICE or an rtprio limit)"), None
    return None, before


@contextlib.contextmanager
def realtime_scheduling(priority: int) -> Iterator[str]:
    """The calling thread in ``SCHED_FIFO`` at ``priority`` inside and the process's other
    threads at :func:`helper_priority`, when permitted; yields what it got as text
    (``"SCHED_FIFO 50"``, or ``"normal (...why...)"``) and restores every thread's policy
    after. ``priority`` 0: leave the scheduling alone."""
    refused, before = _enter_fifo(priority)
    if refused is not None:
        yield refused
        return
    others = _set_fifo(_other_threads(), helper_priority(priority))
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        _restore(others)
        try:
            os.sched_setscheduler(0, before[0], before[1])
        except OSError:
            pass


@contextlib.contextmanager
def helper_threads(priority: int) -> Iterator[int]:
    """The process's threads but the calling one at :func:`helper_priority` of
    ``priority`` inside, where permitted (again: threads started since
    :func:`realtime_scheduling` began, e.g. by the HAL's start-up, run under the normal
    scheduler); yields how many were raised; restored after. 0: nothing changes."""
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        yield 0
        return
    saved = _set_fifo(_other_threads(), helper_priority(priority))
    try:
        yield len(saved)
    finally:
        _restore(saved)


@contextlib.contextmanager
def simulator_scheduling(priority: int) -> Iterator[str]:
    """The simulated robot's process inside (enter before it starts its threads, which
    inherit the policy): the calling thread and any thread already running in
    ``SCHED_FIFO`` at ``priority`` when permitted, and a 0.5 ms GIL switch interval so that
    the thread a frame wakes gets the interpreter quickly. Yields what it got as text,
    like :func:`realtime_scheduling`; restored after. 0: nothing changes."""
    me = threading.get_native_id()
    refused, before = _enter_fifo(priority, reset_on_fork=False)
    if refused is not None:
        yield refused
        return
    saved = [(me, *before), *_set_fifo(_other_threads(), priority, reset_on_fork=False)]
    interval = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        sys.setswitchinterval(interval)
        _restore(saved)


__all__ = ["DEFAULT_RT_PRIORITY", "SWITCH_INTERVAL_S", "helper_priority", "helper_threads",
           "realtime_interpreter", "realtime_scheduling", "simulator_scheduling"]
