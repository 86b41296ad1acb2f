"""What a real-time control loop asks of its process and operating system.

- The interpreter (:func:`realtime_interpreter`): no automatic garbage collection (the loop
  collects the young generation in its slack) and a short GIL switch interval, so that the
  loop gets the interpreter back quickly from the HAL's threads (CAN receive, load-cell
  poller, tracker).
- The scheduler (:func:`realtime_scheduling`): the loop's thread in ``SCHED_FIFO`` at a
  given priority when the system permits it (root, ``CAP_SYS_NICE``, or an ``rtprio``
  limit in ``/etc/security/limits.conf``), as ``ros2_control``'s controller manager does
  for its update thread; otherwise the normal scheduler, said plainly. Only the calling
  thread changes: the HAL's threads started before keep the normal policy, and so does
  the simulated robot (``cdpr sim``) in its own process. On a loaded machine a woken loop
  otherwise waits behind other runnable threads for milliseconds now and then, and the
  drives' RPDO deadline (a few periods) stops the robot. The loop never spins with the
  interpreter held (see :class:`bench.dryrun.loop.CycleClock`), so a real-time thread
  cannot starve the threads it needs.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
from collections.abc import Iterator

#: ``SCHED_FIFO`` priority of a real-time dry run's loop thread (1..99; 0: normal
#: scheduling); ros2_control's default for its update thread is 50
DEFAULT_RT_PRIORITY = 50


@contextlib.contextmanager
def realtime_interpreter() -> Iterator[None]:
    """No automatic GC and a 0.5 ms GIL switch interval inside; restored after."""
    was_enabled = gc.isenabled()
    interval = sys.getswitchinterval()
    gc.collect()
    gc.disable()
    sys.setswitchinterval(5e-4)
    try:
        yield
    finally:
        sys.setswitchinterval(interval)
        if was_enabled:
            gc.enable()


@contextlib.contextmanager
def realtime_scheduling(priority: int) -> Iterator[str]:
    """The calling thread in ``SCHED_FIFO`` at ``priority`` inside, when permitted; yields
    what it got as text (``"SCHED_FIFO 50"``, or ``"normal (...why...)"``) and restores
    the thread's policy after. ``priority`` 0: leave the scheduling alone."""
    if priority <= 0:
        yield "normal (real-time priority not requested)"
        return
    if not hasattr(os, "sched_setscheduler"):
        yield "normal (this system has no SCHED_FIFO)"
        return
    if not 1 <= priority <= os.sched_get_priority_max(os.SCHED_FIFO):
        raise ValueError(f"real-time priority must be 1 to "
                         f"{os.sched_get_priority_max(os.SCHED_FIFO)}, got {priority}")
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        yield (f"normal (SCHED_FIFO {priority} not permitted: {exc.strerror}; grant "
               f"CAP_SYS_NICE or an rtprio limit)")
        return
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        try:
            os.sched_setscheduler(0, before[0], before[1])
        except OSError:
            pass


__all__ = ["DEFAULT_RT_PRIORITY", "realtime_interpreter", "realtime_scheduling"]
