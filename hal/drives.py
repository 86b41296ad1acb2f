"""The eight CiA 402 winch drives as the controller sees them: one object, arrays in, arrays out.

:class:`WinchDrives` runs all drives of one CAN bus through canopen ``RemoteNode`` objects
(SDO, EMCY) and its own per-cycle CiA 402 master (:mod:`hal.drives_cia402`).

Life cycle (blocking calls, outside the control cycle)::

    drives = WinchDrives.open("socketcand:127.0.0.1:PORT", winches, eds=EDS)
    drives.start()            # NMT reset comm, boot-up, identity check, SDO config + verify,
                              # PDO mapping, NMT start (all drives)
    drives.enable_and_wait()  # cycles until all drives are Operation Enabled in CSP
    ...
    drives.shutdown(); drives.close()

Control cycle (never blocks, no SDO, no sleep)::

    drives.exchange()               # latest TPDOs in, state machine, RPDOs + SYNC out
                                    # (= drives.receive(); drives.transmit())
    l = drives.lengths_m()          # cable lengths [m] from the drives' positions
    drives.set_lengths(cmd_m)       # setpoints [m] sent with the next exchange()

``exchange()`` reads what arrived since the previous call: with the drives answering each
SYNC within the cycle, positions are one cycle old. :meth:`WinchDrives.wait_feedback`
waits (with a deadline) for the TPDOs of the last SYNC, for lock-step operation with a
simulated rig, in tests and benchmarks; :meth:`WinchDrives.step` is both.

Per cycle the master sends every operational drive one RPDO (controlword + target position
[counts]) and then one SYNC; drives answer with one TPDO (statusword + position actual).
A drive about to enter Operation Enabled gets its actual position as target, and the
setpoints of a drive are its actual position until it is enabled, so nothing jumps.

Detection (reported by :meth:`faults` while active and as :class:`DriveEvent` history by
:meth:`events`; ``source`` "drive" for EMCY, "hal" for what the master detects):

- EMCY from a drive (code, text): faults, warnings (e.g. 0x8250 RPDO timeout), reset 0x0000;
- drive in Fault / Fault Reaction Active (statusword), with the code of its last EMCY
  (or of 0x603F after :meth:`read_fault_codes`);
- heartbeat lost: no heartbeat for ``heartbeat_misses`` periods (code 0x8130);
- unexpected boot-up (node reset; code 0x8130) or NMT state other than OPERATIONAL;
- TPDO missing for a SYNC or arriving late (code 0x8250 from the master's side);
- internal limit active (software position limit reached, statusword bit 11);
- the bus refusing frames (node id 0, code 0x8100), without raising out of the cycle.

Clock: ``clock="wall"`` (time.monotonic) for real drives, ``clock="sync"`` (number of SYNCs
sent x SYNC period) with a rig on the deterministic simulated clock, or any callable.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import numpy as np

from controller.winch import WinchSet, counts_to_m, m_to_counts
from hal.can_bus import CanSpec, open_bus
from hal.drives_cia402 import (
    CW_FAULT_RESET,
    SW_INTERNAL_LIMIT,
    DriveState,
    Request,
    controlwords,
    decode_states,
    emcy_text,
    enabling,
    faulted,
)
from hal.drives_config import (
    RPDO_MAP,
    TPDO_MAP,
    DriveConfigError,
    configure_node,
    drive_settings,
    pdo_struct,
    sdo_read,
    verify_identity,
)

CODE_HEARTBEAT = 0x8130  # life guard / heartbeat error (CiA 301)
CODE_PDO_TIMEOUT = 0x8250  # RPDO timeout, here: the master's receive PDO = drive's TPDO
CODE_BUS = 0x8100  # communication, generic: the bus refused our frames

NMT_NAMES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
NMT_OPERATIONAL = 0x05


class DriveStartupError(RuntimeError):
    """Drives did not come up (missing boot-up, no answer); the message names the nodes."""


@dataclass(frozen=True)
class DriveEvent:
    """Something that happened on a drive, in order of detection."""

    node_id: int
    cable: str
    kind: str  #: emcy, fault, fault_cleared, heartbeat_lost, heartbeat_resumed, boot_up,
    #: nmt_state, tpdo_missing, tpdo_late, tpdo_short, internal_limit, fault_reset_failed,
    #: recovered, bus_error (node_id 0)
    code: int  #: EMCY / error code (0 when none applies)
    text: str
    source: str  #: "drive" (EMCY it sent) or "hal" (detected by the master)
    cycle: int  #: exchange() count when processed
    time_s: float  #: master clock [s]

    def __str__(self) -> str:
        return (f"node {self.node_id} (cable {self.cable}) {self.kind} 0x{self.code:04X}: "
                f"{self.text} [{self.source}, cycle {self.cycle}]")


@dataclass(frozen=True)
class DriveFault:
    """An active fault of one drive."""

    node_id: int
    cable: str
    kind: str  #: drive_fault, heartbeat_lost, boot_up, nmt_state
    code: int
    text: str

    def __str__(self) -> str:
        return (f"node {self.node_id} (cable {self.cable}) {self.kind} 0x{self.code:04X}: "
                f"{self.text}")


class WinchDrives:
    """All winch drives of one CAN bus, vectorised over winches (see the module docstring).

    ``network`` is a connected :class:`canopen.Network`; ``winches`` the winch parameters
    (node ids, units, limits, bus timing); ``eds`` the drives' EDS file or object dictionary.
    """

    def __init__(
        self,
        network: canopen.Network,
        winches: WinchSet,
        eds: str | Path | canopen.ObjectDictionary,
        clock: str | Callable[[], float] = "wall",
        own_network: bool = False,
    ) -> None:
        self.network = network
        self.winches = winches
        self.n = len(winches)
        self._own_network = own_network
        self.node_ids = [int(x) for x in winches.node_id]
        self.nodes: list[canopen.RemoteNode] = []
        for nid in self.node_ids:
            od = eds if isinstance(eds, canopen.ObjectDictionary) else canopen.import_od(
                str(eds), nid)
            node = canopen.RemoteNode(nid, od)
            network.add_node(node)
            self.nodes.append(node)
        od0 = self.nodes[0].object_dictionary
        self._rpdo = pdo_struct(od0, RPDO_MAP)
        self._tpdo = pdo_struct(od0, TPDO_MAP)
        self.period_s = winches.bus.sync_period_s
        self.hb_timeout_s = winches.bus.heartbeat_period_s * winches.bus.heartbeat_misses
        if clock == "wall":
            self._clock: Callable[[], float] = time.monotonic
        elif clock == "sync":
            self._clock = self._sync_clock
        elif callable(clock):
            self._clock = clock
        else:
            raise ValueError(f"clock must be 'wall', 'sync' or a callable, got {clock!r}")
        n = self.n
        # receive side (written by the notifier thread under _rx)
        self._rx = threading.Condition()
        self._rx_sw = np.zeros(n, np.int64)
        self._rx_pos = np.zeros(n, np.int64)
        self._rx_count = np.zeros(n, np.int64)
        self._boot_count = np.zeros(n, np.int64)
        self._queue: deque[tuple] = deque()
        # cycle side
        self.cycle = 0
        self._syncs = 0
        self._seen = np.zeros(n, np.int64)
        self._expect = np.zeros(n, np.int64)
        self._sw = np.zeros(n, np.int64)
        self._pos = np.zeros(n, np.int64)
        self._have = np.zeros(n, bool)
        self._states = np.full(n, DriveState.UNKNOWN, np.int8)
        self._request = np.full(n, Request.DISABLE, np.int8)
        self._target = np.zeros(n, np.int64)
        self._setpoint_ok = np.zeros(n, bool)  # user setpoints apply (drive enabled)
        self._last_cw = np.zeros(n, np.int64)
        self._reset_left = np.zeros(n, np.int64)  # cycles left holding fault reset
        self._started = np.zeros(n, bool)  # configured and NMT started by us
        self._armed = np.zeros(n, bool)  # got a SYNC since it was started: owes TPDOs
        self._rebooted = np.zeros(n, bool)
        self._hb_last = np.zeros(n)
        self._hb_lost = np.zeros(n, bool)
        self._nmt = np.full(n, -1, np.int64)
        self._miss_streak = np.zeros(n, np.int64)
        self._limit = np.zeros(n, bool)
        self._code = np.zeros(n, np.int64)  # last active EMCY code (0 = none)
        self._events: list[DriveEvent] = []
        self._bus_failing = False
        self._send_lock = network.send_lock
        self._subs: list[tuple[int, Callable]] = []
        for k, node in enumerate(self.nodes):
            self._subs.append((0x180 + node.id, self._tpdo_cb(k)))
            self._subs.append((0x700 + node.id, self._heartbeat_cb(k)))
            node.emcy.add_callback(self._emcy_cb(k))
        for cob, cb in self._subs:
            network.subscribe(cob, cb)

    # ------------------------------------------------------------------ construction

    @classmethod
    def open(
        cls,
        can: str | CanSpec,
        winches: WinchSet,
        eds: str | Path | canopen.ObjectDictionary,
        clock: str | Callable[[], float] = "wall",
    ) -> WinchDrives:
        """Open the bus of a ``--can`` spec and a network on it (closed by :meth:`close`)."""
        bus = open_bus(can)
        network = canopen.Network(bus)
        network.NOTIFIER_CYCLE = 0.05  # quick shutdown
        network.connect()
        return cls(network, winches, eds, clock=clock, own_network=True)

    def close(self) -> None:
        """Unsubscribe; disconnect the network if :meth:`open` created it."""
        for cob, cb in self._subs:
            if cb in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, cb)
        self._subs = []
        for node in self.nodes:
            if node.id in self.network:
                del self.network[node.id]
        if self._own_network:
            self.network.disconnect()

    def __enter__(self) -> WinchDrives:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def who(self, k: int) -> str:
        """'node N (cable C)' of winch index ``k``."""
        return f"node {self.node_ids[k]} (cable {self.winches.cables[k]})"

    def _sync_clock(self) -> float:
        return self._syncs * self.period_s

    def now(self) -> float:
        """The master clock [s]."""
        return self._clock()

    # ------------------------------------------------------------------ receive callbacks

    def _tpdo_cb(self, k: int):
        size = self._tpdo.size

        def cb(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                self._queue.append(("short", k, len(data)))
                return
            sw, pos = self._tpdo.unpack_from(data)
            with self._rx:
                self._rx_sw[k] = sw
                self._rx_pos[k] = pos
                self._rx_count[k] += 1
                self._rx.notify_all()

        return cb

    def _heartbeat_cb(self, k: int):
        def cb(can_id: int, data: bytearray, timestamp: float) -> None:
            if not data:
                return
            state = data[0] & 0x7F
            if state == 0:
                with self._rx:
                    self._boot_count[k] += 1
                    self._rx.notify_all()
            self._queue.append(("hb", k, state, self._clock()))

        return cb

    def _emcy_cb(self, k: int):
        def cb(err: canopen.emcy.EmcyError) -> None:
            self._queue.append(("emcy", k, err.code, err.register, bytes(err.data)))

        return cb

    # ------------------------------------------------------------------ events

    def _event(self, k: int, kind: str, code: int, text: str, source: str = "hal") -> None:
        self._events.append(DriveEvent(self.node_ids[k], self.winches.cables[k], kind, code,
                                       text, source, self.cycle, self._clock()))

    def _bus_event(self, text: str) -> None:
        self._events.append(DriveEvent(0, "-", "bus_error", CODE_BUS, text, "hal", self.cycle,
                                       self._clock()))

    def events(self, clear: bool = True) -> list[DriveEvent]:
        """Events since the last call (all of them with ``clear=False``: kept)."""
        out = list(self._events)
        if clear:
            self._events.clear()
        return out

    def _drain(self) -> None:
        while self._queue:
            item = self._queue.popleft()
            kind, k = item[0], item[1]
            if kind == "hb":
                state, t = item[2], item[3]
                self._hb_last[k] = t
                if state == 0:
                    if self._started[k] and not self._rebooted[k]:
                        self._rebooted[k] = True
                        self._request[k] = Request.DISABLE
                        self._setpoint_ok[k] = False
                        self._have[k] = False  # state UNKNOWN until recover() reads it
                        self._event(k, "boot_up", CODE_HEARTBEAT,
                                    "unexpected boot-up: the node was reset; recover() it")
                    self._nmt[k] = 0x7F
                    continue
                if self._hb_lost[k]:
                    self._hb_lost[k] = False
                    self._event(k, "heartbeat_resumed", CODE_HEARTBEAT, "heartbeat back")
                if state != self._nmt[k] and self._started[k] and not self._rebooted[k]:
                    if state != NMT_OPERATIONAL:
                        self._event(k, "nmt_state", CODE_HEARTBEAT,
                                    f"NMT state {NMT_NAMES.get(state, hex(state))}, "
                                    "expected OPERATIONAL")
                self._nmt[k] = state
            elif kind == "emcy":
                code, register = item[2], item[3]
                if code == 0:
                    self._code[k] = 0
                    self._event(k, "emcy", 0, "error reset (no error)", "drive")
                else:
                    self._code[k] = code
                    self._event(k, "emcy", code, f"{emcy_text(code)} (error register "
                                f"0x{register:02X})", "drive")
            elif kind == "short":
                self._event(k, "tpdo_short", CODE_PDO_TIMEOUT,
                            f"TPDO of {item[2]} bytes, expected {self._tpdo.size}")

    # ------------------------------------------------------------------ start-up (blocking)

    def _wait_bootups(self, ks: list[int], before: np.ndarray, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        with self._rx:
            while True:
                missing = [k for k in ks if self._boot_count[k] <= before[k]]
                left = deadline - time.monotonic()
                if not missing:
                    return
                if left <= 0:
                    who = ", ".join(self.who(k) for k in missing)
                    raise DriveStartupError(
                        f"no boot-up within {timeout:.1f} s after NMT reset from {who}")
                self._rx.wait(left)

    def _send_nmt(self, k: int, command: int) -> None:
        self.network.send_message(0, bytes([command, self.node_ids[k]]))

    def start(self, timeout: float = 3.0, nodes: Iterable[int] | None = None) -> None:
        """Bring drives to NMT OPERATIONAL with the CSP configuration (blocking; SDO).

        NMT reset communication, wait for each boot-up, check identity against the EDS,
        write and verify the configuration, read statusword and position, NMT start.
        ``nodes`` are array indices (default: all). Raises DriveStartupError or
        DriveConfigError naming the node.
        """
        ks = list(range(self.n)) if nodes is None else list(nodes)
        before = self._boot_count.copy()
        for k in ks:
            self._send_nmt(k, 0x82)  # reset communication
        self._wait_bootups(ks, before, timeout)
        for k in ks:
            node = self.nodes[k]
            who = self.who(k)
            verify_identity(node, who)
            configure_node(node, drive_settings(self.winches, k, node.object_dictionary), who)
            sw = int(sdo_read(node, 0x6041, 0, who))
            pos = int(sdo_read(node, 0x6064, 0, who))
            with self._rx:
                self._rx_sw[k] = sw
                self._rx_pos[k] = pos
                self._seen[k] = self._rx_count[k]
            self._sw[k], self._pos[k], self._have[k] = sw, pos, True
            self._target[k] = pos
        self._drain_startup(ks)
        now = self._clock()
        for k in ks:
            self._send_nmt(k, 0x01)  # start remote node
            self._started[k] = True
            self._armed[k] = False
            self._rebooted[k] = False
            self._hb_lost[k] = False
            self._hb_last[k] = now
            self._nmt[k] = NMT_OPERATIONAL
            self._miss_streak[k] = 0
            self._request[k] = Request.DISABLE
            self._setpoint_ok[k] = False
        self._states = decode_states(self._sw, self._have)
        for k in ks:
            if faulted(self._states[k:k + 1])[0]:
                if not self._code[k]:  # its EMCY may have gone out before we listened
                    self._code[k] = int(sdo_read(self.nodes[k], 0x603F, 0, self.who(k)))
                code = int(self._code[k])
                text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
                self._event(k, "fault", code, f"in {DriveState(self._states[k]).name} at "
                            f"start-up: {text}")

    def _drain_startup(self, ks: list[int]) -> None:
        """Consume events of the start-up (boot-ups we caused); keep EMCYs."""
        keep = []
        while self._queue:
            item = self._queue.popleft()
            if item[0] == "hb" and item[1] in ks:
                continue
            keep.append(item)
        self._queue.extend(keep)
        self._drain()

    def recover(self, timeout: float = 3.0) -> list[int]:
        """Restart drives that rebooted or went silent and are back (blocking; SDO).

        Returns the node ids restarted. They come back disabled: call :meth:`enable`.
        """
        self._drain()
        ks = [k for k in range(self.n) if self._rebooted[k] or self._hb_lost[k]
              or (self._started[k] and self._nmt[k] not in (NMT_OPERATIONAL, -1))]
        if not ks:
            return []
        self.start(timeout=timeout, nodes=ks)
        for k in ks:
            self._event(k, "recovered", 0, "reconfigured and started")
        return [self.node_ids[k] for k in ks]

    def read_fault_codes(self) -> dict[int, int]:
        """Read 0x603F error code of drives in Fault by SDO (blocking). {node id: code}."""
        out = {}
        for k in np.flatnonzero(faulted(self._states)):
            code = int(sdo_read(self.nodes[k], 0x603F, 0, self.who(k)))
            self._code[k] = code
            out[self.node_ids[k]] = code
        return out

    # ------------------------------------------------------------------ requests

    def _mask(self, nodes: Iterable[int] | None) -> np.ndarray:
        m = np.zeros(self.n, bool)
        if nodes is None:
            m[:] = True
        else:
            for nid in nodes:
                m[self.node_ids.index(int(nid))] = True
        return m

    def enable(self, nodes: Iterable[int] | None = None) -> None:
        """Request Operation Enabled (CSP) for drives (node ids; default all)."""
        self._request[self._mask(nodes)] = Request.ENABLE

    def disable(self, nodes: Iterable[int] | None = None) -> None:
        """Request Ready To Switch On: power stage off, brakes hold."""
        self._request[self._mask(nodes)] = Request.DISABLE

    def off(self, nodes: Iterable[int] | None = None) -> None:
        """Request Switch On Disabled (disable voltage)."""
        self._request[self._mask(nodes)] = Request.OFF

    def quick_stop(self, nodes: Iterable[int] | None = None) -> None:
        """Request a quick stop (each drive stops on its 0x605A ramp)."""
        self._request[self._mask(nodes)] = Request.QUICK_STOP

    def fault_reset(self, nodes: Iterable[int] | None = None, hold_cycles: int = 20) -> None:
        """Reset faulted drives with a rising edge of controlword bit 7 (over the next cycles)."""
        m = self._mask(nodes) & faulted(self._states)
        self._reset_left[m] = hold_cycles

    def set_lengths(self, lengths_m: np.ndarray) -> None:
        """Cable length setpoints [m], shape (n,), sent with the next :meth:`exchange`.

        Raises ValueError (nothing is changed) for a non-finite value or one outside the
        winch's [min_length_m, max_length_m]. Drives not enabled keep their position.
        """
        x = np.asarray(lengths_m, dtype=float)
        if x.shape != (self.n,):
            raise ValueError(f"set_lengths: expected shape ({self.n},), got {x.shape}")
        bad = ~np.isfinite(x) | (x < self.winches.min_length_m) | (x > self.winches.max_length_m)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"set_lengths: {self.who(k)}: {float(x[k])!r} m is not within "
                f"[{self.winches.min_length_m[k]}, {self.winches.max_length_m[k]}] m")
        self.set_positions_counts(m_to_counts(x, self.winches))

    def set_positions_counts(self, counts: np.ndarray) -> None:
        """Position setpoints [counts] (no limit check: the drives clamp to 0x607D)."""
        c = np.asarray(counts, dtype=np.int64)
        if c.shape != (self.n,):
            raise ValueError(f"set_positions_counts: expected shape ({self.n},), got {c.shape}")
        self._target = np.where(self._setpoint_ok, c, self._target)

    # ------------------------------------------------------------------ the cycle

    def _expected(self) -> np.ndarray:
        return self._started & self._armed & ~self._rebooted & ~self._hb_lost

    def exchange(self) -> None:
        """One control cycle: process what arrived, run the state machine, send RPDOs + SYNC.

        Never blocks (no SDO, no sleep). Same as :meth:`receive` then :meth:`transmit`.
        """
        self.receive()
        self.transmit()

    def receive(self) -> None:
        """First half of a cycle: process the TPDOs, heartbeats and EMCYs that arrived since
        the last call (positions, states, detection). Never blocks. Call once per cycle,
        before :meth:`transmit` (a TPDO is expected per SYNC sent)."""
        self._drain()
        with self._rx:
            counts = self._rx_count.copy()
            sw = self._rx_sw.copy()
            pos = self._rx_pos.copy()
        fresh = counts > self._seen
        n_new = counts - self._seen
        self._seen = counts
        expected = self._expected()
        self._check_pdos(fresh, n_new, expected)
        self._sw = np.where(fresh, sw, self._sw)
        self._pos = np.where(fresh, pos, self._pos)
        self._have |= fresh
        self._update_states(expected)
        self._check_heartbeats()

    def transmit(self) -> None:
        """Second half of a cycle: state machine requests, RPDOs (setpoints) + SYNC out.
        Never blocks."""
        self._send_outputs()
        self.cycle += 1

    def _check_pdos(self, fresh: np.ndarray, n_new: np.ndarray, expected: np.ndarray) -> None:
        for k in np.flatnonzero(expected & ~fresh):
            if self._miss_streak[k] == 0:
                self._event(k, "tpdo_missing", CODE_PDO_TIMEOUT,
                            f"no TPDO for SYNC {self._syncs}")
            self._miss_streak[k] += 1
        for k in np.flatnonzero(fresh & (self._miss_streak > 0)):
            if self._miss_streak[k] > 1:
                self._event(k, "tpdo_missing", CODE_PDO_TIMEOUT,
                            f"TPDOs back after {self._miss_streak[k]} missed SYNCs")
            self._miss_streak[k] = 0
        for k in np.flatnonzero(expected & (n_new > 1)):
            self._event(k, "tpdo_late", CODE_PDO_TIMEOUT,
                        f"{n_new[k]} TPDOs in one cycle: one arrived late")

    def _update_states(self, expected: np.ndarray) -> None:
        old = self._states
        new = decode_states(self._sw, self._have)
        was_fault = faulted(old)
        now_fault = faulted(new)
        for k in np.flatnonzero(now_fault & ~was_fault):
            code = int(self._code[k])
            text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
            self._event(k, "fault", code, f"{DriveState(new[k]).name}: {text}")
            self._request[k] = Request.DISABLE
        for k in np.flatnonzero(~now_fault & was_fault & (new != DriveState.UNKNOWN)):
            self._event(k, "fault_cleared", 0, f"now {DriveState(new[k]).name}")
            self._code[k] = 0
        oe = new == DriveState.OPERATION_ENABLED
        entering = oe & ~self._setpoint_ok
        self._target[entering] = self._pos[entering]  # hold where it stands
        self._setpoint_ok = oe
        limit = oe & ((self._sw & SW_INTERNAL_LIMIT) != 0)
        for k in np.flatnonzero(limit & ~self._limit):
            self._event(k, "internal_limit", 0, "software position limit reached (bit 11)")
        self._limit = limit
        self._states = new

    def _check_heartbeats(self) -> None:
        if self.hb_timeout_s <= 0:
            return
        now = self._clock()
        lost = self._started & ~self._rebooted & ~self._hb_lost & (
            now - self._hb_last > self.hb_timeout_s + 1e-9)
        for k in np.flatnonzero(lost):
            self._hb_lost[k] = True
            self._request[k] = Request.DISABLE
            self._event(k, "heartbeat_lost", CODE_HEARTBEAT,
                        f"no heartbeat for {now - self._hb_last[k]:.3f} s "
                        f"(> {self.winches.bus.heartbeat_misses} periods)")

    def _send_outputs(self) -> None:
        states = self._states
        cw = controlwords(states, self._request).astype(np.int64)
        # fault reset: bit 7 low for one cycle, then high while the drive is in Fault
        resetting = self._reset_left > 0
        cw = np.where(resetting & ((self._last_cw & CW_FAULT_RESET) == 0) & faulted(states),
                      CW_FAULT_RESET, cw)
        hold = resetting & ((self._last_cw & CW_FAULT_RESET) != 0) & faulted(states)
        cw = np.where(hold, CW_FAULT_RESET, cw)
        done = resetting & ~faulted(states)
        self._reset_left[done] = 0
        self._reset_left[resetting & ~done] -= 1
        for k in np.flatnonzero(resetting & ~done & (self._reset_left == 0)):
            self._event(k, "fault_reset_failed", int(self._code[k]),
                        "still in Fault after the reset edge (cause persists?)")
        # a drive not enabled, or being enabled now, gets its actual position as target
        going = enabling(states, cw)
        target = np.where(self._setpoint_ok & ~going, self._target, self._pos)
        self._target = target
        self._last_cw = cw
        send = self._started & ~self._rebooted
        bus_send = self.network.bus.send
        pack = self._rpdo.pack
        try:
            with self._send_lock:
                for k in np.flatnonzero(send):
                    bus_send(can.Message(arbitration_id=0x200 + self.node_ids[k],
                                         data=pack(int(cw[k]), int(target[k])),
                                         is_extended_id=False))
                with self._rx:
                    self._expect = self._rx_count.copy()
                bus_send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
        except (can.CanError, OSError) as exc:
            # the bus refused the frames (bus off, link down): report once per streak and
            # keep cycling; the drives' heartbeats and TPDOs tell what happened to them
            if not self._bus_failing:
                self._bus_event(f"sending RPDOs/SYNC failed: {exc}")
            self._bus_failing = True
        else:
            if self._bus_failing:
                self._bus_event("sending works again")
            self._bus_failing = False
        self._syncs += 1
        self._armed |= send

    def wait_feedback(self, timeout: float = 0.5) -> bool:
        """Wait until every expected drive answered the last SYNC (lock-step; blocks)."""
        mask = self._expected()
        deadline = time.monotonic() + timeout
        with self._rx:
            while True:
                if np.all(self._rx_count[mask] > self._expect[mask]):
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._rx.wait(left)

    def step(self, timeout: float = 0.5) -> bool:
        """exchange() then wait_feedback(): one lock-step cycle (blocks)."""
        self.exchange()
        return self.wait_feedback(timeout)

    def run_until(self, done: Callable[[WinchDrives], bool], max_cycles: int,
                  timeout: float = 0.5) -> bool:
        """Lock-step cycles until ``done(self)`` or ``max_cycles`` (blocks)."""
        for _ in range(max_cycles):
            self.step(timeout)
            if done(self):
                return True
        return False

    def enable_and_wait(self, max_cycles: int = 50) -> None:
        """Enable all drives and cycle until they are Operation Enabled (blocks)."""
        self.enable()
        ok = self.run_until(lambda d: bool(np.all(d.states() == DriveState.OPERATION_ENABLED)),
                            max_cycles)
        if not ok:
            bad = [f"{self.who(k)}: {DriveState(s).name}" for k, s in enumerate(self._states)
                   if s != DriveState.OPERATION_ENABLED]
            raise DriveStartupError(
                f"not Operation Enabled after {max_cycles} cycles: {'; '.join(bad)}")

    def shutdown(self, max_cycles: int = 20) -> None:
        """Disable voltage on all drives (cycling until Switch On Disabled), then NMT pre-op."""
        self.off()
        self.run_until(lambda d: bool(np.all(d.states() != DriveState.OPERATION_ENABLED)),
                       max_cycles)
        for k in range(self.n):
            if self._started[k]:
                self._send_nmt(k, 0x80)
        self._started[:] = False

    # ------------------------------------------------------------------ readings

    def states(self) -> np.ndarray:
        """CiA 402 state of each drive (:class:`DriveState` values), shape (n,)."""
        return self._states.copy()

    def state_names(self) -> list[str]:
        return [DriveState(s).name for s in self._states]

    def statuswords(self) -> np.ndarray:
        return self._sw.copy()

    def positions_counts(self) -> np.ndarray:
        """Latest actual positions [counts] (0x6064), shape (n,)."""
        return self._pos.copy()

    def lengths_m(self) -> np.ndarray:
        """Cable lengths [m] of the latest actual positions, shape (n,)."""
        return counts_to_m(self._pos, self.winches)

    def targets_counts(self) -> np.ndarray:
        """Targets [counts] sent with the last RPDOs."""
        return self._target.copy()

    def limits_active(self) -> np.ndarray:
        """Drives whose software position limit is active (statusword bit 11)."""
        return self._limit.copy()

    def faults(self) -> list[DriveFault]:
        """Active faults (drive Fault, heartbeat lost, node reset, wrong NMT state)."""
        out = []
        for k in range(self.n):
            nid, cable = self.node_ids[k], self.winches.cables[k]
            if faulted(self._states[k:k + 1])[0]:
                code = int(self._code[k])
                text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
                out.append(DriveFault(nid, cable, "drive_fault", code, text))
            if self._hb_lost[k]:
                out.append(DriveFault(nid, cable, "heartbeat_lost", CODE_HEARTBEAT,
                                      "heartbeat lost"))
            if self._rebooted[k]:
                out.append(DriveFault(nid, cable, "boot_up", CODE_HEARTBEAT,
                                      "node was reset (boot-up); recover() it"))
            elif self._started[k] and self._nmt[k] not in (NMT_OPERATIONAL, -1) \
                    and not self._hb_lost[k]:
                out.append(DriveFault(nid, cable, "nmt_state", CODE_HEARTBEAT,
                                      f"NMT {NMT_NAMES.get(int(self._nmt[k]), '?')}"))
        return out


__all__ = [
    "DriveConfigError",
    "DriveEvent",
    "DriveFault",
    "DriveStartupError",
    "DriveState",
    "WinchDrives",
]
