"""Which SYNC a synchronous TPDO answers: by count, bounded by the frame's time.

A drive on a synchronous TPDO (transmission type 1) latches its position at each SYNC it
receives and answers it with one TPDO, in order. The master knows two things about the
TPDO numbered ``i`` (the drive's TPDOs received so far):

- an upper bound from time: it answers no SYNC sent after the frame came, so at most the
  SYNC numbered ``b_i``, the last sent before the frame's time stamp (on this host's clock)
  or, without one, before the master handled it (:meth:`SyncHistory.bound`);
- the count: the TPDO after it answers the next SYNC, ``s_{i+1} = s_i + 1``.

So ``s_i = i + c`` with ``c`` the drive's constant count offset, and every bound gives
``c <= b_j - j``: the tightest is the minimum over the TPDOs seen, ``c = min_j (b_j - j)``
(:class:`CountAlignment`), right as soon as one of them came within its own SYNC period.
A starved receiver or a starved answerer (frames in bursts, 5-15 periods late) shifts
``b`` up, never ``c``: the stamps stay on the SYNC the position was latched at.

The count breaks where a TPDO is lost (a bus error, a drive that skipped a SYNC): the
offset grows by one and the minimum, kept over all TPDOs, would stamp every later one a
period early. So the minimum is taken over a sliding window of the last ``window`` TPDOs:
after N TPDOs lost the stamps are N periods early for at most the window, and the window
must hold one on-time answer (see :data:`COUNT_WINDOW_S`). A new stream (the drive armed
anew after a start, a reboot; a drive whose heartbeat says it left OPERATIONAL, or silent
beyond its TPDO deadline, whose gap of unanswered SYNCs would stamp its answers that gap
early; every drive after a SYNC kept that failed to go out) starts a new window
(:meth:`CountAlignment.restart`).
"""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np

#: [s] span of the sliding window of TPDOs the count offset is the minimum over. Longer
#: than the longest run of late answers it must see through (a starved answerer or
#: receiver on a loaded 2-core host: bursts 5-15 SYNC periods late, <= 60 ms at 256 Hz;
#: the window holds several such runs and the on-time answers between them), and as short
#: as that allows, because N lost TPDOs stamp the drive's positions N periods early until
#: the TPDOs before the loss have left the window.
COUNT_WINDOW_S = 0.5


def count_window(period_s: float) -> int:
    """TPDOs in :data:`COUNT_WINDOW_S` at one TPDO per SYNC period ``period_s`` [s]."""
    return max(2, math.ceil(COUNT_WINDOW_S / period_s))


class SyncHistory:
    """The SYNCs the master sent: number, wall time (``time.time()``, the clock of the
    frames' time stamps) and master clock [s]. Written by the cycle (:meth:`note`), read by
    the receive thread: a ring of ``kept`` entries, the count written after its entry
    (one list item or attribute assignment at a time: atomic), and the oldest slot, which
    the next :meth:`note` overwrites, never read."""

    def __init__(self, kept: int) -> None:
        self.kept = max(2, int(kept))
        self._wall = [math.nan] * self.kept
        self._clock = [math.nan] * self.kept
        self.sent = 0  #: SYNCs noted; the last one is number ``sent - 1``

    def note(self, wall: float, clock_s: float) -> None:
        """The SYNC numbered :attr:`sent` goes out at ``wall`` [s, time.time()] with the
        master clock ``clock_s`` [s]."""
        slot = self.sent % self.kept
        self._wall[slot] = wall
        self._clock[slot] = clock_s
        self.sent += 1

    def _oldest(self, sent: int) -> int:
        return max(0, sent - self.kept + 1)

    def last_wall(self) -> float:
        """The wall time [s] of the last SYNC noted (nan: none)."""
        sent = self.sent
        return self._wall[(sent - 1) % self.kept] if sent else math.nan

    def bound(self, timestamp: float | None) -> int:
        """The number of the last SYNC sent before ``timestamp`` [s, time.time()] (a
        frame's own time stamp), or before now where it is none, not within the SYNCs kept
        and now (another clock: a bus's hardware clock) or older; -1: none sent."""
        sent = self.sent
        last = sent - 1
        if sent == 0 or timestamp is None or not timestamp <= time.time():
            return last
        if not timestamp >= self._wall[self._oldest(sent) % self.kept]:
            return last  # another clock, or older than the SYNCs kept
        for number in range(last, self._oldest(sent) - 1, -1):
            if self._wall[number % self.kept] <= timestamp:
                return number
        return last

    def clock_of(self, number: int) -> float:
        """The master clock [s] of SYNC ``number``; nan when it is no longer kept."""
        sent = self.sent
        if not self._oldest(sent) <= number < sent:
            return math.nan
        return self._clock[number % self.kept]


class CountAlignment:
    """One drive's count offset (module docstring): the SYNC number each of its TPDOs
    answers, from the count and the time bounds of the last ``window`` TPDOs. Used by one
    thread (the receive thread); :meth:`restart` from another is taken at the next TPDO."""

    def __init__(self, window: int) -> None:
        self.window = max(1, int(window))
        self._count = 0  # TPDOs taken in this stream
        self._mins: deque[tuple[int, int]] = deque()  # (count, b - count), values rising
        self._epoch = 0
        self._taken_epoch = 0

    def restart(self) -> None:
        """A new stream of TPDOs (the drive armed anew): forget the offset."""
        self._epoch += 1

    def answered(self, bound: int) -> int:
        """The SYNC number the next TPDO answers, given its time ``bound`` (the last SYNC
        sent before it came, :meth:`SyncHistory.bound`); never above the bound."""
        if self._taken_epoch != self._epoch:
            self._taken_epoch = self._epoch
            self._count = 0
            self._mins.clear()
        i = self._count
        self._count += 1
        value = bound - i
        mins = self._mins
        while mins and mins[-1][1] >= value:
            mins.pop()
        mins.append((i, value))
        while mins[0][0] <= i - self.window:
            mins.popleft()
        return i + mins[0][1]




def common_sample(latest_t: np.ndarray, pos: np.ndarray, kept_t: np.ndarray,
                  kept_pos: np.ndarray, window_s: float) -> tuple[np.ndarray, float]:
    """The drives' positions latched at one SYNC, and that SYNC's master clock [s]: the
    latest SYNC every answering drive has answered, so that one sample of all the drives
    has one time (drives whose answers came in bursts, or a slow bus, hold positions of
    different SYNCs at one read).

    ``latest_t`` (n,): the SYNC of each drive's latest position [s] (nan: not from a TPDO);
    ``pos`` (n,): the latest positions; ``kept_t``, ``kept_pos`` (n, H): each drive's last
    positions and their SYNCs (nan: an empty slot). A drive whose latest position is older
    than the newest one's by more than ``window_s`` [s] (silent: lost) is not waited for:
    its latest position is given. Returns (positions, time); time nan when no drive's
    position is from a TPDO, positions nan when the answering drives have no SYNC in
    common among those kept (a TPDO lost at each)."""
    live = np.isfinite(latest_t)
    if not live.any():
        return pos, math.nan
    newest = float(np.max(latest_t[live]))
    live &= latest_t >= newest - window_s
    t = latest_t[live]
    earliest = float(np.min(t))
    if earliest == newest:
        return pos, newest
    rows = np.flatnonzero(live)
    kept = kept_t[rows]
    first = kept[0][kept[0] <= earliest]
    for s in np.sort(first)[::-1]:
        hit = kept == s
        if hit.any(axis=1).all():
            out = pos.copy()
            out[rows] = kept_pos[rows, hit.argmax(axis=1)]
            return out, float(s)
    return np.full(pos.shape, np.nan), earliest


__all__ = ["COUNT_WINDOW_S", "CountAlignment", "SyncHistory", "common_sample", "count_window"]
