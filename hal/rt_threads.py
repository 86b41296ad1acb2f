"""Raised scheduling priority for the HAL's time-critical threads, where the OS allows it.

A CANopen master's producers (the master heartbeat the drives consume, 0x1016) must not
wait behind other work on a busy host: a producer thread under the normal scheduler can be
kept off the processor for longer than the drives' consumer time, and the drives then stop
on their own (0x6007, 0x1029). The consumer time is the site's data; the producer is what
this module raises:

1. ``SCHED_FIFO`` at the given priority (Linux; root, ``CAP_SYS_NICE`` or an ``rtprio``
   limit), with ``SCHED_RESET_ON_FORK`` so that no thread or process started from it
   inherits the real-time policy (an estimator or recorder process started later must not
   compete with the loop);
2. else a lower nice value (:data:`FALLBACK_NICE`; needs the same permission on Linux);
3. else the normal scheduler, said plainly.

:func:`raise_thread` returns what it got as text (``"SCHED_FIFO 49"``, ``"nice -10"``,
``"normal (...why...)"``), which the HAL keeps for its callers to report.
"""

from __future__ import annotations

import os
import threading

#: nice value asked for when SCHED_FIFO is refused (Linux: per thread)
FALLBACK_NICE = -10


def fifo_policy(reset_on_fork: bool = True) -> int:
    """SCHED_FIFO, with SCHED_RESET_ON_FORK (where the platform has it) unless
    ``reset_on_fork`` is False: a thread or process started from a real-time thread then
    runs under the normal scheduler unless it is raised on purpose."""
    return os.SCHED_FIFO | (getattr(os, "SCHED_RESET_ON_FORK", 0) if reset_on_fork else 0)


def max_priority() -> int:
    """The highest SCHED_FIFO priority (99 on Linux); 0 without SCHED_FIFO."""
    if not hasattr(os, "sched_get_priority_max"):
        return 0
    return os.sched_get_priority_max(os.SCHED_FIFO)


def check_priority(priority: int) -> int:
    """``priority`` if it is 0 (normal) to :func:`max_priority`, else ValueError naming the
    range."""
    top = max_priority()
    if priority < 0 or (top and priority > top):
        raise ValueError(f"thread priority must be 0 (normal) to {top}, got {priority}")
    return int(priority)


def raise_thread(priority: int, tid: int | None = None) -> str:
    """Thread ``tid`` (kernel thread id; default the calling one) in ``SCHED_FIFO`` at
    ``priority`` (1..:func:`max_priority`) where permitted, else :data:`FALLBACK_NICE`, else
    unchanged; returns what it got as text. ``priority`` 0: unchanged (not asked).
    ValueError for a priority out of range."""
    if priority <= 0:
        return "normal (raised priority not requested)"
    check_priority(priority)
    top = max_priority()
    tid = threading.get_native_id() if tid is None else tid
    why = "this system has no SCHED_FIFO"
    if top:
        try:
            os.sched_setscheduler(tid, fifo_policy(), os.sched_param(priority))
            return f"SCHED_FIFO {priority}"
        except OSError as exc:
            why = f"SCHED_FIFO {priority} not permitted: {exc.strerror}"
    try:
        os.setpriority(os.PRIO_PROCESS, tid, FALLBACK_NICE)  # Linux: this thread only
        return f"nice {FALLBACK_NICE} ({why})"
    except (OSError, AttributeError) as exc:
        reason = getattr(exc, "strerror", None) or "no setpriority"
        return (f"normal ({why}; nice {FALLBACK_NICE} not permitted: {reason}; grant "
                "CAP_SYS_NICE or an rtprio limit)")


__all__ = ["FALLBACK_NICE", "check_priority", "fifo_policy", "max_priority", "raise_thread"]
