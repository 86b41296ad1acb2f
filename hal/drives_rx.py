"""The receive side of the winch drives' master (:class:`hal.drives.WinchDrives`): the
canopen callbacks (TPDO, heartbeat, EMCY; notifier thread), the queue they fill, and
the event history the cycle drains it into.
"""

from __future__ import annotations

import numpy as np

from hal.drives_base import (
    CODE_BUS,
    CODE_HEARTBEAT,
    CODE_PDO_TIMEOUT,
    EMCY_STRUCT,
    NMT_NAMES,
    NMT_OPERATIONAL,
    QUEUE_KEPT,
    DriveEvent,
)
from hal.drives_cia402 import (
    RQ,
    emcy_text,
)


class ReceiveMixin:
    """TPDO, heartbeat and EMCY callbacks, the event queue and history (a part of
    :class:`hal.drives.WinchDrives`, whose ``__init__`` sets the state)."""

    # ------------------------------------------------- receive callbacks

    def _tpdo_cb(self, k: int):
        size = self._tpdo.size

        def cb(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                self._queue.append(("short", k, len(data)))
                return
            sw, pos = self._tpdo.unpack_from(data)
            sync_t = self._sync_answered(k, timestamp)
            with self._rx:
                self._rx_sw[k] = sw
                self._rx_pos[k] = pos
                self._rx_sync_t[k] = sync_t
                self._rx_count[k] += 1
                slot = self._rx_kept_n[k] % self._rx_kept_t.shape[1]
                self._rx_kept_t[k, slot] = sync_t
                self._rx_kept_pos[k, slot] = pos
                self._rx_kept_n[k] += 1
                self._rx.notify_all()

        return cb

    def _sync_answered(self, k: int, timestamp: float | None) -> float:
        """The master clock [s] of the SYNC the TPDO of drive index ``k`` received at
        ``timestamp`` answers: by the drive's count of TPDOs, never after the last SYNC
        sent before the frame came (its time stamp, the sender's or the kernel's, on
        ``time.time()``'s clock; a time stamp on another clock, or none: when the master
        handles it), see :mod:`hal.sync_count`. A frame handled after the next SYNC went
        out, or one of a burst of late answers, keeps its own SYNC."""
        history = self._sync_sent
        bound = history.bound(timestamp)
        if bound < 0:
            return self._sync_t
        t = history.clock_of(self._align[k].answered(bound))
        if t != t:  # older than the SYNCs kept: the bound's
            t = history.clock_of(bound)
        return t if t == t else self._sync_t

    def _heartbeat_cb(self, k: int):
        def cb(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != 1:
                self._post(("hb_bad", k, len(data)))
                if not data:
                    return
            state = data[0] & 0x7F
            t = self._clock()
            self._rx_hb_t[k] = t
            if state == 0:
                with self._rx:
                    self._boot_count[k] += 1
                    self._rx.notify_all()
            changed = state != self._rx_hb_state[k]
            self._rx_hb_state[k] = state
            if changed or state == 0:  # changes only: a bounded queue
                self._queue.append(("hb", k, state, t))

        return cb

    def _emcy_cb(self, k: int):
        def cb(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) != EMCY_STRUCT.size:
                self._post(("emcy_bad", k, bytes(data)))
                return
            code, register, extra = EMCY_STRUCT.unpack(data)
            self._post(("emcy", k, code, register, extra))

        return cb

    def _post(self, item: tuple) -> None:
        """Queue an item for the next cycle; beyond QUEUE_KEPT (nobody cycles, a flood) it is
        counted instead (reported as ``emcy_overflow`` by the next cycle)."""
        if len(self._queue) >= QUEUE_KEPT:
            self._queue_overflow[item[1]] += 1
            return
        self._queue.append(item)

    # ------------------------------------------------------------ events

    def _keep(self, e: DriveEvent) -> None:
        if len(self._events) == self._events.maxlen:
            self.events_dropped += 1
        self._events.append(e)

    def _event(self, k: int, kind: str, code: int, text: str, source: str = "hal") -> None:
        self._keep(DriveEvent(self.node_ids[k], self.winches.cables[k], kind, code, text,
                              source, self.cycle, self._clock()))

    def _bus_event(self, text: str, kind: str = "bus_error", code: int = CODE_BUS) -> None:
        self._keep(DriveEvent(0, "-", kind, code, f"{self.bus_name}: {text}", "hal", self.cycle,
                              self._clock()))

    def events(self, clear: bool = True) -> list[DriveEvent]:
        """Events since the last call (all of them with ``clear=False``: kept)."""
        out = list(self._events)
        if clear:
            self._events.clear()
        return out

    def _drain(self) -> None:
        over = self._queue_overflow
        for k in np.flatnonzero(over) if np.count_nonzero(over) else ():
            self._event(int(k), "emcy_overflow", 0, f"{self._queue_overflow[k]} EMCYs not kept "
                        "(more than the master could take between two cycles)")
            self._queue_overflow[k] = 0
        while self._queue:
            item = self._queue.popleft()
            kind, k = item[0], item[1]
            if kind == "hb":
                self._heartbeat_in(k, item[2])
            elif kind == "emcy":
                code, register = item[2], item[3]
                self._code[k] = code
                if code == 0:
                    self._event(k, "emcy", 0, "error reset (no error)", "drive")
                else:
                    if len(self._window[k]) < 16:
                        self._window[k].append(code)
                    self._event(k, "emcy", code, f"{emcy_text(code)} (error register "
                                f"0x{register:02X})", "drive")
            elif kind == "emcy_bad":
                self._event(k, "emcy_malformed", 0, f"EMCY of {len(item[2])} bytes "
                            f"({item[2].hex() or 'empty'}), expected {EMCY_STRUCT.size}: ignored")
            elif kind == "hb_bad":
                self._event(k, "heartbeat_malformed", CODE_HEARTBEAT,
                            f"heartbeat of {item[2]} bytes, expected 1")
            elif kind == "short":
                self._event(k, "tpdo_short", CODE_PDO_TIMEOUT,
                            f"TPDO of {item[2]} bytes, expected {self._tpdo.size}")
            elif kind == "603f":
                self._fault_code_read(k, item[2], item[3])

    def _heartbeat_in(self, k: int, state: int) -> None:
        if state == 0:
            if self._started[k] and not self._rebooted[k]:
                self._rebooted[k] = True
                self._request[k] = RQ.DISABLE
                self._setpoint_ok[k] = False
                self._have[k] = False  # state UNKNOWN until recover() reads it
                self._event(k, "boot_up", CODE_HEARTBEAT,
                            "unexpected boot-up: the node was reset; recover() it")
            self._nmt[k] = 0x7F
            return
        if state != NMT_OPERATIONAL and self._clock() <= self._nmt_wait[k]:
            self._rx_hb_state[k] = -1  # the next one counts again
            return  # sent before our NMT start reached it: not news
        if state == NMT_OPERATIONAL:
            self._nmt_wait[k] = -np.inf
        else:  # no TPDO leaves it: its next ones are a new stream (the SYNCs between unanswered)
            self._align[k].restart()
        if state != self._nmt[k] and self._started[k] and not self._rebooted[k]:
            if state != NMT_OPERATIONAL:
                # no PDO leaves a node outside OPERATIONAL: the statusword we hold is old,
                # its power state unknown until a TPDO comes again (or recover()); the NMT
                # state is the fault (no TPDO is owed: not drive_lost)
                self._lost[k] = False
                self._have[k] = False
                self._setpoint_ok[k] = False
                self._event(k, "nmt_state", CODE_HEARTBEAT,
                            f"NMT state {NMT_NAMES.get(state, hex(state))}, "
                            "expected OPERATIONAL: its power state is unknown")
        self._nmt[k] = state


__all__ = ["ReceiveMixin"]
