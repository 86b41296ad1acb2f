"""One winch drive moved by this process as the CANopen master, for commissioning.

:class:`AxisMaster` drives ONE CiA 402 drive outside the control loop: it configures the
drive with the HAL's own start-up table (:func:`hal.drives_config.drive_settings`), then
switches it to profile position (mode 1) or homing (mode 6) and runs a synchronous cycle
like the HAL's: one RPDO (controlword + target position, the table's mapping) and one SYNC
per period, one TPDO (statusword + position actual) back. On top of the CiA 402 power
state machine (:mod:`hal.drives_cia402`) it sets the operation-mode bits of the
controlword: new set-point (bit 4) with change immediately (bit 5) and its handshake
(statusword bit 12), halt (bit 8), homing start (bit 4).

- :meth:`AxisMaster.start` NMT reset communication, boot-up, identity, table written and
  verified, mode written, NMT start (blocking; SDO);
- :meth:`AxisMaster.step` one cycle (paced on the wall clock with ``pace=True``), raising
  :class:`MotionError` when the drive faults, resets, or its TPDOs or heartbeats stop;
- :meth:`AxisMaster.finish` the safe end, for ``finally:`` blocks: disable voltage by PDO,
  NMT pre-operational, controlword 0 by SDO, the session's changes restored; it never
  raises and reports the state the drive was left in.

:func:`run_jog` is the jog of a commissioning engineer: motion in profile position toward
the end of a travel window at a given speed while the operator's input keeps coming (each
key repeat is one input); when the input stops for ``deadman_s`` (on the master clock),
the drive halts (bit 8), and once stopped it is disabled. :func:`run_homing` is CiA 402
homing on the current position (methods 35 and 37). :func:`hold_enabled` keeps the drive
enabled and still until told to stop.

All three take a ``guard``: called every cycle with the feedback, it returns None to go on
or the reason to stop (the commissioning commands watch every cable's tension with
:class:`controller.cable_watch.CableWatch`). On a reason the drive quick-stops and holds
(:func:`quick_stop_hold`: Quick Stop Active on the quick-stop ramp, 0x605A option 6, then
disabled: the brake holds), the motion ends, and the reason is in the result.

The session widens the drive's RPDO deadline (0x1400 sub 5) to ``session_rpdo_timeout_s``:
a commissioning laptop is no real-time controller. What the session changes beyond the
table (deadline, mode, profile velocity) is written back at :meth:`AxisMaster.finish`.
"""

from __future__ import annotations

import dataclasses
import enum
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import numpy as np

from controller.winch import WinchSet
from hal.bus_watch import FOREIGN_MASTER, ForeignFrameWatch
from hal.drives_cia402 import (
    CW_DISABLE_VOLTAGE,
    DriveState,
    Request,
    controlwords,
    decode_states,
    emcy_text,
    faulted,
)
from hal.drives_config import (
    RPDO_MAP,
    TPDO_MAP,
    DriveConfigError,
    Setting,
    _od_var,
    configure_node,
    drive_settings,
    pdo_struct,
    sdo_read,
    sdo_write,
    verify_identity,
)

MODE_PP = 1
MODE_HOMING = 6
HOMING_CURRENT_POSITION = (35, 37)

CW_NEW_SETPOINT = 1 << 4
CW_CHANGE_IMMEDIATELY = 1 << 5
CW_HALT = 1 << 8
SW_TARGET_REACHED = 1 << 10
SW_OMS12 = 1 << 12  #: PP set-point acknowledge / homing attained
SW_OMS13 = 1 << 13  #: following error (PP) / homing error

NMT_RESET_COMM = 0x82
NMT_START = 0x01
NMT_PRE_OPERATIONAL = 0x80


class MotionError(RuntimeError):
    """The motion could not go on; names the node. ``kind``: "fault" (the drive faulted),
    "silent" (TPDOs or heartbeats stopped), "reset" (the node booted), "bus" (sending
    failed), "foreign_master" (another master sent an SDO request or RPDO to the drive, an
    NMT command or a SYNC: :mod:`hal.bus_watch`; the message names the COB-ID) or
    "other"."""

    def __init__(self, message: str, kind: str = "other") -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class AxisFeedback:
    """What the drive reported in the last cycle."""

    t_s: float  #: master clock [s]
    state: DriveState
    statusword: int
    position_counts: int
    length_m: float

    @property
    def enabled(self) -> bool:
        return self.state == DriveState.OPERATION_ENABLED


def master_heartbeat(settings: list[Setting]) -> tuple[int, float] | None:
    """(node id, period [s]) of the master heartbeat the drive consumes (0x1016 in the table),
    at half the consumer time; None when the table configures no consumer."""
    for st in settings:
        if st.index == 0x1016 and st.subindex >= 1 and st.value:
            nid, ms = (st.value >> 16) & 0x7F, st.value & 0xFFFF
            if nid and ms:
                return nid, ms / 2000.0
    return None


class AxisMaster:
    """One drive (winch ``k`` of ``winches``) with this process as its master; see the module
    docstring. ``clock``: "wall" (time.monotonic) or "sync" (SYNCs sent x period, for a
    simulated rig on its deterministic clock) or a callable. ``pace``: cycles follow the
    wall clock at the SYNC period (else as fast as the drive answers: lock-step tests)."""

    def __init__(self, network: canopen.Network, winches: WinchSet, k: int,
                 eds: str | Path | canopen.ObjectDictionary, clock: str | Callable = "wall",
                 pace: bool = True, session_rpdo_timeout_s: float = 0.1,
                 feedback_timeout_s: float = 0.5) -> None:
        self.network = network
        self.k = int(k)
        bus = winches.bus
        if bus.rpdo_timeout_s and bus.rpdo_timeout_s < session_rpdo_timeout_s:
            bus = dataclasses.replace(bus, rpdo_timeout_s=session_rpdo_timeout_s)
        self.winches = winches
        self.session_winches = dataclasses.replace(winches, bus=bus)
        self.node_id = int(winches.node_id[k])
        self.cable = winches.cables[k]
        self.axis = winches.axis(k)
        od = eds if isinstance(eds, canopen.ObjectDictionary) else canopen.import_od(
            str(eds), self.node_id)
        self.node = canopen.RemoteNode(self.node_id, od)
        network.add_node(self.node)
        self._rpdo = pdo_struct(od, RPDO_MAP)
        self._tpdo = pdo_struct(od, TPDO_MAP)
        self._rpdo_cob = int(_od_var(od, 0x1400, 1).default) & 0x7FF
        self._tpdo_cob = int(_od_var(od, 0x1800, 1).default) & 0x7FF
        self.period_s = winches.bus.sync_period_s
        self.pace = pace
        # paced (a real bus): a TPDO comes within the cycle, do not stall the cycle waiting
        self.feedback_timeout_s = (min(feedback_timeout_s, max(0.02, 3 * self.period_s))
                                   if pace else feedback_timeout_s)
        if clock == "wall":
            self._clock: Callable[[], float] = time.monotonic
        elif clock == "sync":
            self._clock = lambda: self.syncs * self.period_s
        elif callable(clock):
            self._clock = clock
        else:
            raise ValueError(f"clock must be 'wall', 'sync' or a callable, got {clock!r}")
        self.syncs = 0
        self.cycle = 0
        self.log: list[tuple[float, str]] = []  #: (time.time(), what happened)
        self._rx = threading.Condition()
        self._rx_sw = 0
        self._rx_pos = 0
        self._rx_count = 0
        self._boots = 0
        self._hb_last_wall = time.monotonic()
        self._hb_seen = False
        self._emcy: list[tuple[int, int]] = []
        self._seen = 0
        self._expect = 0
        self._missed = 0
        self._sw = 0
        self._pos = 0
        self._have = False
        self.state = DriveState.UNKNOWN
        self.request = Request.DISABLE
        self.halt = False
        self._target = 0
        self._pending: int | None = None
        self._bit4 = False
        self._bit4_sent_at = 0
        self._started = False
        self._identity_ok = False  #: the node is the EDS's device: finish() may write to it
        self._boots_at_start = 0
        self._restore: dict[tuple[int, int], Setting] = {}
        self._settings: list[Setting] = []
        self._master_hb: tuple[int, float] | None = None
        self._next_hb = 0.0
        self._next_hb_clock = 0.0
        self._next_wall = 0.0
        self._last_code = 0
        self._subs = [(self._tpdo_cob, self._on_tpdo), (0x700 + self.node_id, self._on_hb)]
        for cob, cb in self._subs:
            network.subscribe(cob, cb)
        self.node.emcy.add_callback(self._on_emcy)
        #: frames only another master sends (checked every cycle, as the HAL does)
        self.foreign = ForeignFrameWatch(network, [self.node_id], {self._rpdo_cob: self.node_id})

    # ------------------------------------------------------------------ plumbing

    def who(self) -> str:
        return f"node {self.node_id} (cable {self.cable})"

    def now(self) -> float:
        return self._clock()

    def note(self, text: str) -> None:
        self.log.append((time.time(), text))

    def _on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < self._tpdo.size:
            return
        sw, pos = self._tpdo.unpack_from(data)
        with self._rx:
            self._rx_sw, self._rx_pos = int(sw), int(pos)
            self._rx_count += 1
            self._rx.notify_all()

    def _on_hb(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if not data:
            return
        with self._rx:
            if data[0] & 0x7F == 0:
                self._boots += 1
            self._hb_last_wall = time.monotonic()
            self._hb_seen = True
            self._rx.notify_all()

    def _on_emcy(self, err: canopen.emcy.EmcyError) -> None:
        with self._rx:
            self._emcy.append((int(err.code), int(err.register)))

    def close(self) -> None:
        """Unsubscribe and take the node off the network (call after :meth:`finish`)."""
        for cob, cb in self._subs:
            if cb in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, cb)
        self._subs = []
        self.foreign.close()
        if self.node_id in self.network:
            del self.network[self.node_id]

    def _nmt(self, command: int) -> None:
        self.network.send_message(0, bytes([command, self.node_id]))

    def _sdo_write(self, index: int, subindex: int, value: int, name: str,
                   restore: bool = True) -> None:
        """Write by SDO; with ``restore`` the table's value (else the value read now) is
        written back by :meth:`finish`."""
        key = (index, subindex)
        if restore and key not in self._restore:
            table = {(s.index, s.subindex): s for s in self._table_settings()}
            if key in table:
                self._restore[key] = table[key]
            else:
                old = sdo_read(self.node, index, subindex, self.who())
                self._restore[key] = Setting(index, subindex, int(old), name)
        sdo_write(self.node, Setting(index, subindex, int(value), name), self.who())

    def _table_settings(self) -> list[Setting]:
        return drive_settings(self.winches, self.k, self.node.object_dictionary)

    # ------------------------------------------------------------------ start-up

    def start(self, mode: int, timeout_s: float = 3.0) -> AxisFeedback:
        """Reset communication, check identity, write the table, set ``mode``, NMT start.

        Blocking (SDO). Raises :class:`~hal.drives_config.DriveConfigError` or
        :class:`MotionError` naming the node. The drive stays disabled.
        """
        who = self.who()
        with self._rx:
            before = self._boots
        self._nmt(NMT_RESET_COMM)
        deadline = time.monotonic() + timeout_s
        with self._rx:
            while self._boots <= before:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise MotionError(f"{who}: no boot-up within {timeout_s:g} s after NMT "
                                      "reset communication: is the node on the bus?")
                self._rx.wait(left)
        verify_identity(self.node, who)
        self._identity_ok = True
        self._settings = drive_settings(self.session_winches, self.k,
                                        self.node.object_dictionary)
        table = {(s.index, s.subindex): s for s in self._table_settings()}
        for st in self._settings:  # session-only values (the widened RPDO deadline)
            key = (st.index, st.subindex)
            if key in table and table[key].value != st.value and st.verify:
                self._restore[key] = table[key]
        configure_node(self.node, self._settings, who)
        self._sdo_write(0x6060, 0, mode, "modes of operation")
        got = sdo_read(self.node, 0x6061, 0, who)
        if got != mode:
            raise MotionError(f"{who}: 0x6061 modes of operation display is {got} after "
                              f"writing mode {mode} to 0x6060")
        sw = int(sdo_read(self.node, 0x6041, 0, who))
        pos = int(sdo_read(self.node, 0x6064, 0, who))
        self._master_hb = master_heartbeat(self._settings)
        period = getattr(self.winches.bus, "master_heartbeat_period_s", 0.0)
        if self._master_hb is not None and period > 0:  # the HAL's producer time
            self._master_hb = (self._master_hb[0], min(period, self._master_hb[1]))
        with self._rx:
            self._rx_sw, self._rx_pos = sw, pos
            self._seen = self._expect = self._rx_count
            self._boots_at_start = self._boots
            self._emcy.clear()
            self._hb_last_wall = time.monotonic()
        self._sw, self._pos, self._have = sw, pos, True
        self._last_rx_wall = time.monotonic()
        self._target = pos
        self.state = DriveState(int(decode_states(np.array([sw]))[0]))
        if self._master_hb is not None:
            self._send_master_heartbeat()
        self._nmt(NMT_START)
        self._started = True
        self._next_wall = time.monotonic()
        self.note(f"{who}: configured from the HAL table, mode {mode}, NMT started "
                  f"(position {pos} counts, {self.state.name})")
        if faulted(np.array([self.state]))[0]:
            code = int(sdo_read(self.node, 0x603F, 0, who))
            raise MotionError(f"{who}: in {self.state.name} before any motion: error code "
                              f"0x{code:04X} {emcy_text(code)} (reset the fault first: "
                              "cdpr commission disable --fault-reset)")
        return self.feedback()

    def read_position(self) -> int:
        """Position actual value 0x6064 [counts] by SDO (before :meth:`start` too)."""
        return int(sdo_read(self.node, 0x6064, 0, self.who()))

    def set_profile(self, velocity_counts_s: int | None = None) -> None:
        """Profile velocity 0x6081 [counts/s] for the next moves (restored by finish)."""
        if velocity_counts_s is not None:
            self._sdo_write(0x6081, 0, int(velocity_counts_s), "profile velocity")

    def set_homing(self, method: int, offset_counts: int = 0) -> None:
        """Homing method 0x6098 and home offset 0x607C (the position after homing)."""
        if method not in HOMING_CURRENT_POSITION:
            raise MotionError(f"{self.who()}: homing method {method}: only homing on the "
                              f"current position (35, 37) is supported")
        self._sdo_write(0x6098, 0, method, "homing method", restore=False)
        self._sdo_write(0x607C, 0, int(offset_counts), "home offset", restore=False)

    # ------------------------------------------------------------------ the cycle

    def feedback(self) -> AxisFeedback:
        length = self.axis.counts_to_m(self._pos)
        return AxisFeedback(self.now(), self.state, self._sw, self._pos, length)

    def _send_master_heartbeat(self) -> None:
        nid, _ = self._master_hb
        self.network.send_message(0x700 + nid, bytes([0x05]))

    def _controlword(self) -> int:
        st = np.array([self.state])
        cw = int(controlwords(st, np.array([self.request]))[0])
        if self.state == DriveState.OPERATION_ENABLED and self.request == Request.ENABLE:
            if self._bit4:
                if self._sw & SW_OMS12 and self._seen > self._bit4_sent_at:
                    self._bit4 = False  # acknowledged: release bit 4
            elif self._pending is not None and not self._sw & SW_OMS12:
                self._target = self._pending
                self._pending = None
                self._bit4 = True
                self._bit4_sent_at = self._seen
            if self._bit4:
                cw |= CW_NEW_SETPOINT | CW_CHANGE_IMMEDIATELY
            if self.halt:
                cw |= CW_HALT
        else:
            self._bit4 = False
        return cw

    def _receive(self) -> None:
        with self._rx:
            count, sw, pos = self._rx_count, self._rx_sw, self._rx_pos
            boots = self._boots
            emcy, self._emcy = self._emcy, []
            hb_age = time.monotonic() - self._hb_last_wall
            hb_seen = self._hb_seen
        for code, reg in emcy:
            if code:
                self._last_code = code
            self.note(f"{self.who()}: EMCY 0x{code:04X} {emcy_text(code)} "
                      f"(error register 0x{reg:02X})")
        foreign = self.foreign.take()
        if foreign and self._started:
            raise MotionError(f"{self.who()}: {FOREIGN_MASTER}: {foreign[0].text} (another "
                              "master on the bus)", FOREIGN_MASTER)
        if boots > self._boots_at_start:
            self._started = False
            raise MotionError(f"{self.who()}: the node was reset (boot-up) during the motion",
                              "reset")
        if count > self._seen:
            self._missed = 0
            self._last_rx_wall = time.monotonic()
            self._sw, self._pos = sw, pos
        elif self.syncs:
            self._missed += 1
            silent_s = time.monotonic() - self._last_rx_wall
            if self._missed >= 3 and (self._missed * self.period_s >= max(0.1, 10 * self.period_s)
                                      or silent_s >= 1.0):
                raise MotionError(f"{self.who()}: no TPDO for {self._missed} SYNCs: the drive "
                                  "stopped answering", "silent")
        self._seen = count
        hb = self.winches.bus
        if hb_seen and hb.heartbeat_period_s > 0 and self.pace and \
                hb_age > hb.heartbeat_period_s * hb.heartbeat_misses + 0.5:
            raise MotionError(f"{self.who()}: no heartbeat for {hb_age:.2f} s", "silent")
        old = self.state
        self.state = DriveState(int(decode_states(np.array([self._sw]))[0]))
        if self.state == DriveState.OPERATION_ENABLED and old != self.state:
            self._target = self._pos  # hold where it stands
            self._pending = None
        if faulted(np.array([self.state]))[0]:
            code = self._last_code
            text = emcy_text(code) if code else "fault without EMCY (see 0x603F)"
            raise MotionError(f"{self.who()}: drive fault 0x{code:04X}: {text}", "fault")

    def _transmit(self) -> None:
        cw = self._controlword()
        target = self._target if self.state == DriveState.OPERATION_ENABLED else self._pos
        if self.state != DriveState.OPERATION_ENABLED:
            self._target = self._pos
        msgs = [(self._rpdo_cob, self._rpdo.pack(cw, int(target))), (0x80, b"")]
        with self._rx:
            self._expect = self._rx_count
        try:
            for cob, data in msgs:
                self.network.send_message(cob, data)
            if self._master_hb is not None:
                # due on the master clock (a SYNC-driven drive's time) or on the wall clock
                wall, now = time.monotonic(), self.now()
                if wall >= self._next_hb or now >= self._next_hb_clock:
                    self._send_master_heartbeat()
                    self._next_hb = wall + self._master_hb[1]
                    self._next_hb_clock = now + self._master_hb[1]
        except (can.CanError, OSError) as exc:
            raise MotionError(f"{self.who()}: sending RPDO/SYNC failed: {exc}", "bus") from exc
        self.syncs += 1
        self.cycle += 1

    def _wait(self) -> bool:
        deadline = time.monotonic() + self.feedback_timeout_s
        with self._rx:
            while self._rx_count <= self._expect:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._rx.wait(left)
        return True

    def step(self) -> AxisFeedback:
        """One cycle: RPDO + SYNC out, wait for the TPDO, process it. Raises MotionError."""
        if not self._started:
            raise MotionError(f"{self.who()}: not started")
        if self.pace:
            delay = self._next_wall - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self._next_wall = max(self._next_wall + self.period_s,
                                  time.monotonic() - self.period_s)
        self._transmit()
        self._wait()
        self._receive()
        return self.feedback()

    # ------------------------------------------------------------------ requests

    def move_to(self, counts: int) -> None:
        """New profile-position target [counts] (change immediately), sent when enabled."""
        self._pending = int(counts)
        self.halt = False

    def enable(self, max_cycles: int = 100) -> AxisFeedback:
        """Cycle until Operation Enabled (holding the actual position)."""
        self.request = Request.ENABLE
        fb = self.feedback()
        for _ in range(max_cycles):
            fb = self.step()
            if fb.enabled:
                self.note(f"{self.who()}: enabled at {fb.length_m:.4f} m")
                return fb
        raise MotionError(f"{self.who()}: not Operation Enabled after {max_cycles} cycles "
                          f"({self.state.name})")

    def disable(self, max_cycles: int = 100) -> AxisFeedback:
        """Cycle until the power stage is off (Ready To Switch On)."""
        self.request = Request.DISABLE
        self.halt = False
        fb = self.feedback()
        for _ in range(max_cycles):
            fb = self.step()
            if fb.state in (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCH_ON_DISABLED):
                return fb
        raise MotionError(f"{self.who()}: still {self.state.name} after {max_cycles} cycles")

    @property
    def halted(self) -> bool:
        """Halt requested and the drive reports standstill (statusword bit 10)."""
        return (self.halt and self.state == DriveState.OPERATION_ENABLED
                and bool(self._sw & SW_TARGET_REACHED))

    @property
    def target_reached(self) -> bool:
        return (self.state == DriveState.OPERATION_ENABLED and not self._bit4
                and self._pending is None and bool(self._sw & SW_TARGET_REACHED))

    # ------------------------------------------------------------------ the safe end

    def finish(self, pdo_cycles: int = 25) -> tuple[str, list[str]]:
        """Leave the drive disabled and as the table says; never raises.

        Returns the CiA 402 state read back by SDO (or "unknown") and what went wrong.
        """
        problems: list[str] = []
        who = self.who()
        if self._started:
            # disable voltage by PDO; a drive in its fault reaction gets the SYNCs it may
            # need (a simulated drive's clock) until it reaches Fault
            self.request = Request.OFF
            self.halt = False
            for _ in range(pdo_cycles):
                try:
                    self._transmit()
                    self._wait()
                    self._receive()
                except MotionError as exc:
                    if exc.kind != "fault":
                        problems.append(str(exc))
                        break
                if self.state in (DriveState.SWITCH_ON_DISABLED, DriveState.READY_TO_SWITCH_ON,
                                  DriveState.FAULT):
                    break
        self._started = False
        try:
            self._nmt(NMT_PRE_OPERATIONAL)
        except (can.CanError, OSError) as exc:
            problems.append(f"{who}: NMT pre-operational not sent: {exc}")
        state = "unknown"
        if not self._identity_ok:
            self.note(f"{who}: finished before its identity was confirmed: nothing written")
            return state, problems
        try:
            sdo_write(self.node, Setting(0x6040, 0, CW_DISABLE_VOLTAGE, "controlword"), who)
            for st in self._restore.values():
                sdo_write(self.node, st, who)
            sw = int(sdo_read(self.node, 0x6041, 0, who))
            self._sw = sw
            self.state = DriveState(int(decode_states(np.array([sw]))[0]))
            state = self.state.name
            if self.state == DriveState.FAULT:
                code = int(sdo_read(self.node, 0x603F, 0, who))
                problems.append(f"{who}: left in FAULT, error code 0x{code:04X} "
                                f"{emcy_text(code)}")
        except DriveConfigError as exc:
            problems.append(f"{exc}: cannot confirm the drive is disabled")
        self.note(f"{who}: finished, drive {state}")
        return state, problems


# ---------------------------------------------------------------------------- jog


class JogInput(enum.Enum):
    """What the operator's input says in one cycle."""

    OUT = "+"  #: pay cable out (longer)
    IN = "-"  #: reel cable in (shorter)
    STOP = "stop"  #: halt now
    QUIT = "quit"  #: halt, disable, end the session
    EOF = "eof"  #: the input ended: as QUIT


@dataclass
class JogResult:
    start_m: float
    end_m: float
    min_m: float
    max_m: float
    deadman_stops: int = 0
    moves: int = 0
    cycles: int = 0
    reason: str = ""
    guard_stop: str = ""  #: why the guard stopped the motion ("" if it did not)


#: a guard: feedback -> None (go on) or the reason to stop
Guard = Callable[[AxisFeedback], "str | None"]


def quick_stop_hold(master: AxisMaster, reason: str, max_cycles: int = 200,
                    on_cycle: Callable[[AxisFeedback, str], None] | None = None
                    ) -> AxisFeedback:
    """Quick stop (controlword: Quick Stop Active, the drive's ramp 0x6085, holding with
    0x605A option 6), wait for standstill, then disable (the brake holds). Notes
    ``reason``. Returns the last feedback."""
    master.note(f"{master.who()}: stop: {reason}")
    master.halt = False
    fb = master.feedback()
    if fb.state in (DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE):
        master.request = Request.QUICK_STOP
        for _ in range(max_cycles):
            fb = master.step()
            if on_cycle is not None:
                on_cycle(fb, "stopping")
            if fb.state != DriveState.QUICK_STOP_ACTIVE or fb.statusword & SW_TARGET_REACHED:
                break
    master.request = Request.DISABLE
    for _ in range(max_cycles):
        fb = master.step()
        if fb.state in (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCH_ON_DISABLED,
                        DriveState.FAULT):
            break
    master.note(f"{master.who()}: stopped and disabled at {fb.length_m:.4f} m "
                f"({fb.state.name})")
    return fb


def run_jog(master: AxisMaster, read_input: Callable[[], JogInput | None], out_counts: int,
            in_counts: int, deadman_s: float,
            on_cycle: Callable[[AxisFeedback, str], None] | None = None,
            max_cycles: int | None = None, guard: Guard | None = None) -> JogResult:
    """Jog ``master``'s drive while the operator's input keeps coming (see module docstring).

    ``read_input()`` is called once per cycle: the latest input since the last call or
    None. ``out_counts``/``in_counts``: the targets [counts] of the travel window's ends;
    ``deadman_s``: input silence [s, master clock] after which the drive halts, then is
    disabled. Ends on QUIT/EOF (once disabled), after ``max_cycles``, or when ``guard``
    gives a reason to stop (quick stop and hold, :func:`quick_stop_hold`); the drive is
    left disabled (the caller's ``finally`` calls :meth:`AxisMaster.finish`).
    """
    fb = master.feedback()
    res = JogResult(fb.length_m, fb.length_m, fb.length_m, fb.length_m)
    phase = "idle"
    direction: JogInput | None = None
    last_input = master.now()
    quitting = False

    def go(d: JogInput) -> None:
        master.move_to(out_counts if d is JogInput.OUT else in_counts)
        res.moves += 1
        master.note(f"{master.who()}: jog {'out' if d is JogInput.OUT else 'in'} from "
                    f"{master.feedback().length_m:.4f} m")

    while True:
        cmd = read_input()
        now = master.now()
        if cmd in (JogInput.OUT, JogInput.IN) and not quitting:
            last_input = now
            if phase in ("idle", "disabling"):
                master.request = Request.ENABLE
                master.halt = False
                phase, direction = "enabling", cmd
            elif phase == "enabling":
                direction = cmd
            elif phase == "moving" and cmd is not direction or phase == "halting":
                direction = cmd
                go(cmd)
                phase = "moving"
        elif cmd is JogInput.STOP:
            if phase in ("moving", "enabling"):
                master.halt = True
                phase = "halting"
        elif cmd in (JogInput.QUIT, JogInput.EOF):
            quitting = True
            res.reason = "operator quit" if cmd is JogInput.QUIT else "input ended"
            if phase in ("moving", "enabling"):
                master.halt = True
                phase = "halting"
        fb = master.step()
        res.cycles += 1
        res.min_m = min(res.min_m, fb.length_m)
        res.max_m = max(res.max_m, fb.length_m)
        why = guard(fb) if guard is not None else None
        if why:
            res.guard_stop = why
            res.reason = f"stopped: {why}"
            fb = quick_stop_hold(master, why, on_cycle=on_cycle)
            res.min_m = min(res.min_m, fb.length_m)
            res.max_m = max(res.max_m, fb.length_m)
            break
        if phase == "enabling" and fb.enabled:
            go(direction)
            phase = "moving"
        if phase in ("moving", "enabling") and now - last_input > deadman_s:
            master.halt = True
            phase = "halting"
            res.deadman_stops += 1
            master.note(f"{master.who()}: dead-man: no input for {now - last_input:.2f} s, "
                        f"halt at {fb.length_m:.4f} m")
        if phase == "halting" and (master.halted or not fb.enabled):
            master.request = Request.DISABLE
            master.halt = False
            phase = "disabling"
        if phase == "disabling" and fb.state in (DriveState.READY_TO_SWITCH_ON,
                                                 DriveState.SWITCH_ON_DISABLED):
            phase = "idle"
            master.note(f"{master.who()}: stopped and disabled at {fb.length_m:.4f} m")
        if on_cycle is not None:
            on_cycle(fb, phase)
        if quitting and phase == "idle":
            break
        if max_cycles is not None and res.cycles >= max_cycles:
            res.reason = res.reason or f"{max_cycles} cycles"
            break
    res.end_m = master.feedback().length_m
    return res


class GuardStop(MotionError):
    """The guard stopped the motion (the drive quick-stopped and was disabled)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, "guard")


def _guarded(master: AxisMaster, guard: Guard | None, fb: AxisFeedback) -> None:
    why = guard(fb) if guard is not None else None
    if why:
        quick_stop_hold(master, why)
        raise GuardStop(f"{master.who()}: stopped: {why}")


def run_homing(master: AxisMaster, max_cycles: int = 500,
               guard: Guard | None = None) -> AxisFeedback:
    """CiA 402 homing (mode 6, method and offset set with :meth:`AxisMaster.set_homing`):
    enable, start (bit 4), wait for homing attained (statusword bits 12 and 10), disable.
    Returns the feedback after homing; MotionError on a homing error (bit 13),
    :class:`GuardStop` when ``guard`` gives a reason to stop."""
    master.enable()
    master.move_to(master.feedback().position_counts)  # bit 4 rising edge starts homing
    for _ in range(max_cycles):
        fb = master.step()
        _guarded(master, guard, fb)
        if master._sw & SW_OMS13:
            raise MotionError(f"{master.who()}: homing error (statusword 0x{master._sw:04X})")
        if not master._bit4 and master._pending is None and master._sw & SW_OMS12 \
                and master._sw & SW_TARGET_REACHED:
            master.note(f"{master.who()}: homing attained, position {fb.position_counts} counts")
            master.disable()
            return master.feedback()
    raise MotionError(f"{master.who()}: homing not attained after {max_cycles} cycles")


def hold_enabled(master: AxisMaster, keep_going: Callable[[AxisFeedback], bool],
                 on_cycle: Callable[[AxisFeedback, str], None] | None = None,
                 guard: Guard | None = None) -> AxisFeedback:
    """Enable and hold the actual position while ``keep_going(feedback)``; then disable.
    :class:`GuardStop` when ``guard`` gives a reason to stop (quick stop, then disabled)."""
    fb = master.enable()
    while keep_going(fb):
        fb = master.step()
        if on_cycle is not None:
            on_cycle(fb, "enabled")
        _guarded(master, guard, fb)
    return master.disable()


__all__ = ["AxisFeedback", "AxisMaster", "Guard", "GuardStop", "JogInput", "JogResult",
           "MotionError", "hold_enabled", "master_heartbeat", "quick_stop_hold", "run_homing",
           "run_jog"]
