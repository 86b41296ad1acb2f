"""What the CANopen master watches on its own bus: late feedback and other masters.

Two checks, kept apart from the I/O so that they are tested without a bus:

- :func:`feedback_lost`: a drive owes one TPDO per SYNC; when it stays silent for
  ``deadline_cycles`` SYNCs in a row (and at least ``min_s`` of the master clock), it is
  lost: its state is unknown from then on (never its last live state). The deadline is
  counted in SYNCs sent, so the master's pace never depends on a frame arriving: in
  lock-step a missed answer costs one bounded wait, then counts like any other miss.
- :func:`master_frame`: CAN has no authentication, so a frame only a master sends and
  that this master did not send means another master on the bus (a second tool on the
  socketcand hub, a forgotten PLC): an SDO request to one of our drives (COB-ID
  0x600 + node), an NMT command (0x000), an RPDO of one of our drives (its COB-ID, e.g.
  0x200 + node), a SYNC (0x080). :class:`OwnFrames` tells this master's own frames apart
  on a bus that echoes them (``receive_own_messages``); on one that does not (python-can's
  ``virtual`` bus, the project's socketcand hub), every such frame received is foreign.

:class:`ForeignFrameWatch` subscribes a :class:`canopen.Network` to those COB-IDs and
queues :class:`ForeignFrame` records for the caller's cycle (the callbacks run in the
bus's notifier thread and never block).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

#: a drive is lost after this many consecutive SYNCs without its TPDO
TPDO_DEADLINE_CYCLES = 5
#: ... and at least this long [s, master clock] without one (a host's scheduling hiccup
#: at a high cycle rate is no lost drive)
TPDO_DEADLINE_MIN_S = 0.08
#: the event / fault kind of a drive whose feedback stopped (also the supervisor's condition)
DRIVE_LOST = "drive_lost"
#: the event / fault kind of a frame another master sent (also the supervisor's condition)
FOREIGN_MASTER = "foreign_master"

COB_NMT = 0x000
COB_SYNC = 0x080
COB_SDO_RX = 0x600  #: + node id: SDO request (client -> server)

NMT_COMMANDS = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational",
                0x81: "reset node", 0x82: "reset communication"}
_SDO_CCS = {0: "download segment", 1: "write (download)", 2: "read (upload)",
            3: "upload segment", 4: "abort", 5: "block upload", 6: "block download"}


def feedback_lost(missed_syncs: np.ndarray, silent_s: np.ndarray,
                  deadline_cycles: int = TPDO_DEADLINE_CYCLES,
                  min_s: float = TPDO_DEADLINE_MIN_S) -> np.ndarray:
    """(n,) bool: drives whose TPDOs are overdue.

    ``missed_syncs`` (n,): consecutive SYNCs each drive did not answer; ``silent_s`` (n,)
    [s]: master-clock time since its last TPDO (or since it owed the first one). Lost when
    ``missed_syncs >= deadline_cycles`` and ``silent_s >= min_s``.
    """
    if deadline_cycles < 1:
        raise ValueError(f"deadline_cycles {deadline_cycles}: must be >= 1")
    missed = np.asarray(missed_syncs)
    return (missed >= deadline_cycles) & (np.asarray(silent_s, float) >= min_s - 1e-12)


def _sdo_text(data: bytes) -> str:
    if len(data) < 4:
        return f"SDO request of {len(data)} bytes"
    ccs = data[0] >> 5
    what = _SDO_CCS.get(ccs, f"command 0x{data[0]:02X}")
    if ccs not in (1, 2, 4, 5, 6):
        return f"SDO {what}"
    index, sub = data[1] | data[2] << 8, data[3]
    text = f"SDO {what} of 0x{index:04X}:{sub}"
    expedited = ccs == 1 and data[0] & 0x02 and len(data) == 8
    if expedited:
        size = 4 - ((data[0] >> 2) & 3) if data[0] & 0x01 else 4
        value = int.from_bytes(data[4:4 + size], "little")
        text += f" = {value} (0x{value:X})"
    return text


def master_frame(cob_id: int, data: bytes, node_ids: Iterable[int],
                 rpdo_cobs: dict[int, int]) -> tuple[int, str] | None:
    """Whether a received frame is one only a CANopen master sends.

    ``node_ids``: our drives; ``rpdo_cobs``: {RPDO COB-ID: node id} of our drives. Returns
    (the node id it addresses, 0 for the whole bus; a text naming the COB-ID and what the
    frame does) or None for any other frame (TPDOs, heartbeats, EMCYs, SDO answers, ...).
    """
    nodes = set(node_ids)
    data = bytes(data)
    if cob_id == COB_NMT:
        if len(data) != 2:
            return 0, f"COB-ID 0x000 NMT frame of {len(data)} bytes not ours"
        cmd, target = data[0], data[1]
        what = NMT_COMMANDS.get(cmd, f"command 0x{cmd:02X}")
        to = "all nodes" if target == 0 else f"node {target}"
        return (target if target in nodes else 0,
                f"COB-ID 0x000 NMT {what} to {to} not ours")
    if cob_id == COB_SYNC:
        return 0, "COB-ID 0x080 SYNC not ours (a second SYNC producer)"
    if cob_id - COB_SDO_RX in nodes:
        return (cob_id - COB_SDO_RX,
                f"COB-ID 0x{cob_id:03X} SDO request not ours: {_sdo_text(data)}")
    if cob_id in rpdo_cobs:
        return rpdo_cobs[cob_id], f"COB-ID 0x{cob_id:03X} RPDO not ours ({data.hex() or 'empty'})"
    return None


def watched_cob_ids(node_ids: Iterable[int], rpdo_cobs: dict[int, int]) -> list[int]:
    """The COB-IDs :func:`master_frame` can flag."""
    return sorted({COB_NMT, COB_SYNC, *(COB_SDO_RX + n for n in node_ids), *rpdo_cobs})


class OwnFrames:
    """The frames this master sent recently, for a bus that echoes them: an echo is taken
    off the list (FIFO per COB-ID, same data, within ``window_s`` [s, wall]); a frame not on
    the list is not ours. Bounded (``per_cob`` frames kept per COB-ID)."""

    def __init__(self, window_s: float = 1.0, per_cob: int = 256,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.window_s = window_s
        self.per_cob = per_cob
        self.clock = clock
        self._sent: dict[int, deque[tuple[bytes, float]]] = {}
        self._lock = threading.Lock()

    def sent(self, cob_id: int, data: bytes) -> None:
        with self._lock:
            q = self._sent.setdefault(cob_id, deque(maxlen=self.per_cob))
            q.append((bytes(data), self.clock()))

    def is_own(self, cob_id: int, data: bytes) -> bool:
        """True (and forgotten) when ``data`` on ``cob_id`` is the echo of a frame we sent."""
        data = bytes(data)
        now = self.clock()
        with self._lock:
            q = self._sent.get(cob_id)
            while q and now - q[0][1] > self.window_s:
                q.popleft()
            if not q:
                return False
            for i, (d, _t) in enumerate(q):
                if d == data:
                    del q[i]
                    return True
        return False


@dataclass(frozen=True)
class ForeignFrame:
    """A frame another master sent: the node it addresses (0: the bus), its COB-ID, what it
    does (text), the wall time it was seen [s, time.monotonic]."""

    node_id: int
    cob_id: int
    text: str
    wall_s: float


class ForeignFrameWatch:
    """Watch ``network`` for frames only a master sends and that this one did not send
    (see the module docstring). ``node_ids`` our drives, ``rpdo_cobs`` {COB-ID: node id}.
    Frames wait in a bounded queue for :meth:`take` (beyond ``kept``, they are counted in
    :attr:`dropped`). Our own frames: on a bus whose ``receive_own_messages`` is true, the
    bus's ``send``/``send_batch`` are wrapped to note the watched frames it sends."""

    def __init__(self, network, node_ids: Iterable[int], rpdo_cobs: dict[int, int],
                 kept: int = 256) -> None:
        self.network = network
        self.node_ids = tuple(int(n) for n in node_ids)
        self.rpdo_cobs = dict(rpdo_cobs)
        self.cob_ids = watched_cob_ids(self.node_ids, self.rpdo_cobs)
        self._queue: deque[ForeignFrame] = deque()
        self.kept = kept
        self.dropped = 0  #: foreign frames not kept (a flood)
        bus = network.bus
        self.echoes = bool(getattr(bus, "receive_own_messages", False))
        self.own: OwnFrames | None = OwnFrames() if self.echoes else None
        self._wrapped: list[tuple[str, Callable]] = []
        if self.own is not None:
            self._wrap_sends(bus)
        self._subs = [(cob, self._cb) for cob in self.cob_ids]
        for cob, cb in self._subs:
            network.subscribe(cob, cb)

    def _wrap_sends(self, bus) -> None:
        own, watched = self.own, set(self.cob_ids)
        assert own is not None

        def note(msg) -> None:
            if msg.arbitration_id in watched:
                own.sent(msg.arbitration_id, bytes(msg.data))

        send = bus.send

        def send_noted(msg, timeout=None):
            note(msg)
            return send(msg, timeout)

        self._wrapped.append(("send", send))
        bus.send = send_noted
        batch = getattr(bus, "send_batch", None)
        if batch is not None:
            def batch_noted(msgs):
                for m in msgs:
                    note(m)
                return batch(msgs)

            self._wrapped.append(("send_batch", batch))
            bus.send_batch = batch_noted

    def _cb(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.own is not None and self.own.is_own(can_id, data):
            return
        hit = master_frame(can_id, data, self.node_ids, self.rpdo_cobs)
        if hit is None:
            return
        if len(self._queue) >= self.kept:
            self.dropped += 1
            return
        self._queue.append(ForeignFrame(hit[0], can_id, hit[1], time.monotonic()))

    def take(self) -> list[ForeignFrame]:
        """The foreign frames seen since the last call, oldest first."""
        out = []
        while self._queue:
            out.append(self._queue.popleft())
        return out

    def close(self) -> None:
        for cob, cb in self._subs:
            if cb in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, cb)
        self._subs = []
        bus = self.network.bus
        for name, fn in self._wrapped:
            if name in vars(bus):
                delattr(bus, name)  # the class's method again
            else:
                setattr(bus, name, fn)
        self._wrapped = []


__all__ = ["DRIVE_LOST", "FOREIGN_MASTER", "TPDO_DEADLINE_CYCLES", "TPDO_DEADLINE_MIN_S",
           "ForeignFrame", "ForeignFrameWatch", "OwnFrames", "feedback_lost", "master_frame",
           "watched_cob_ids"]
