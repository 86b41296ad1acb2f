"""The HAL's drive decoders fed from a CAN log instead of a bus: :class:`ReplayDrives`.

A log of the bus (candump, ``.asc``, the ``/can`` channel of an MCAP recording) holds what
the master sent (SYNC, RPDOs, NMT, SDO requests, its heartbeat) and what the drives sent
(TPDOs, EMCYs, heartbeats, SDO answers). :class:`ReplayDrives` is a
:class:`hal.drives.WinchDrives` that takes those frames one by one
(:meth:`ReplayDrives.feed_frame`) and derives the same states, events and faults as the
live master did, with the same code::

    d = ReplayDrives.for_log(winches, eds)
    for msg in frames:                       # in the log's order
        if d.feed_frame(msg) == "sync":      # the master's SYNC: one cycle of the master
            d.receive()                      # what arrived since the last SYNC
            ... d.states(), d.events(), d.faults()
            d.transmit()                     # the clock advances one SYNC period
    d.close()

- It starts in the state :meth:`~hal.drives.WinchDrives.start` leaves (configured, NMT
  OPERATIONAL, heartbeats fresh, nothing sent): a log starts after the drives were started.
- A drive's TPDO, EMCY and heartbeat go to the decoders the bus's notifier calls live; they
  are received at the master clock of the call, which is the number of cycles run times
  the SYNC period (``clock="sync"``, as in a lock-step run; the frames' own time stamps
  are the caller's to keep the pace with).
- The master's RPDOs say what it asked of each drive: an enable-operation controlword is
  an enable request, a quick-stop one a quick stop (not a drive stopping on its own). They
  were sent after the master's cycle had read what came before them, so they take effect
  at the next :meth:`transmit`, as they did live.
- The master's 0x603F read after a fault is not made again: the logged SDO answer (or
  abort) to it confirms the fault's code.
- What the HAL sends (RPDOs, SYNC) goes to a bus of its own that nobody listens to.

Not replayed: frames of another master (a log does not tell them from this master's; live
they are ``foreign_master``), the CAN link's loss (a log has no link), start-up and
recovery (SDO configuration, NMT).
"""

from __future__ import annotations

import struct
import uuid
from pathlib import Path

import can
import canopen
import numpy as np

from controller.winch import WinchSet
from hal.can_bus import open_bus
from hal.drives import NMT_OPERATIONAL, WinchDrives
from hal.drives_cia402 import RQ

#: what :meth:`ReplayDrives.feed_frame` took a frame as
DRIVE_FRAME, MASTER_FRAME, SYNC_FRAME, OTHER_FRAME = "drive", "master", "sync", ""
_SDO_UPLOAD = struct.Struct("<BHB")  # command, index, subindex of an SDO frame


class ReplayDrives(WinchDrives):
    """All winch drives of a logged bus, fed frame by frame (see the module docstring)."""

    @classmethod
    def for_log(cls, winches: WinchSet, eds: str | Path | canopen.ObjectDictionary,
                bus_name: str = "CAN log") -> ReplayDrives:
        """A replay HAL for ``winches`` (node ids, units, SYNC period: that of the log) and
        the drives' EDS; ``bus_name`` names the log in messages. Closed by :meth:`close`."""
        bus = open_bus(f"virtual:replay-{uuid.uuid4().hex}")  # its frames go nowhere
        network = canopen.Network(bus)
        network.NOTIFIER_CYCLE = 0.05
        network.connect()
        d = cls(network, winches, eds, clock="sync", own_network=True, bus_name=bus_name)
        d._as_started()
        return d

    def _as_started(self) -> None:
        now = self.now()
        self._decoders = dict(self._subs)  # COB-ID -> the callback the notifier calls
        self._rpdo_nodes = {0x200 + nid: k for k, nid in enumerate(self.node_ids)}
        self._logged_cw = np.zeros(self.n, np.int64)
        self._logged_rq = np.full(self.n, -1, np.int64)  # requests of the logged RPDOs
        self._started[:] = True
        self._armed[:] = False
        for align in self._align:
            align.restart()
        self._hb_last[:] = now
        self._rx_hb_t[:] = now
        self._nmt[:] = NMT_OPERATIONAL
        self._nmt_wait[:] = now + max(self.hb_timeout_s, self.period_s)
        self._last_tpdo_t[:] = now

    def feed_frame(self, msg: can.Message) -> str:
        """Take one logged frame, as received (see the module docstring). Returns what it
        was taken as: ``"drive"`` (a TPDO, EMCY or heartbeat of one of the drives: decoded),
        ``"master"`` (an RPDO of one of the drives: the master's request; an SDO answer to
        the 0x603F read: the fault's code), ``"sync"`` (the master's SYNC: the caller runs
        :meth:`receive`, then :meth:`transmit`), ``""`` (anything else: not looked at)."""
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return OTHER_FRAME
        cid, data = msg.arbitration_id, bytes(msg.data)
        if cid == 0x80 and not data:
            return SYNC_FRAME
        cb = self._decoders.get(cid)
        if cb is not None:
            cb(cid, bytearray(data), float(msg.timestamp))
            return DRIVE_FRAME
        k = self._rpdo_nodes.get(cid)
        if k is not None and len(data) >= self._rpdo.size:
            self._master_rpdo(k, int(self._rpdo.unpack_from(data)[0]))
            return MASTER_FRAME
        if 0x581 <= cid <= 0x5FF and (cid - 0x580) in self.node_ids and len(data) == 8:
            return MASTER_FRAME if self._sdo_answer(self.node_ids.index(cid - 0x580),
                                                    data) else OTHER_FRAME
        return OTHER_FRAME

    def _master_rpdo(self, k: int, cw: int) -> None:
        self._logged_cw[k] = cw
        if cw & 0x8F == 0x0F:
            self._logged_rq[k] = RQ.ENABLE
        elif cw & 0x87 == 0x02:
            self._logged_rq[k] = RQ.QUICK_STOP

    def _sdo_answer(self, k: int, data: bytes) -> bool:
        cmd, index, sub = _SDO_UPLOAD.unpack_from(data)
        if index != 0x603F or sub != 0:
            return False
        if cmd & 0xE0 == 0x40:  # expedited upload answer
            self._queue.append(("603f", k, struct.unpack_from("<H", data, 4)[0], ""))
        elif cmd == 0x80:  # abort
            abort = struct.unpack_from("<I", data, 4)[0]
            self._queue.append(("603f", k, None, f"SDO abort 0x{abort:08X}"))
        else:
            return False
        return True

    def master_controlwords(self) -> np.ndarray:
        """The controlword of each drive's last logged RPDO (0 before the first), shape (n,)."""
        return self._logged_cw.copy()

    def transmit(self) -> None:
        """The master's requests of the RPDOs logged since the last cycle, then the second
        half of the cycle (:meth:`hal.drives.WinchDrives.transmit`)."""
        asked = self._logged_rq >= 0
        if np.count_nonzero(asked):
            self._request[asked] = self._logged_rq[asked]
            self._logged_rq[:] = -1
        super().transmit()

    def _confirm_fault_code(self, k: int) -> None:
        """The log holds the master's 0x603F read and its answer (fed as a frame)."""


__all__ = ["ReplayDrives"]
