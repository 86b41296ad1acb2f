"""One simulated CiA 402 winch servo drive on a CANopen network.

The object dictionary is a canopen :class:`~canopen.LocalNode` built from the shipped
EDS (``firmware_sim/data/winch_drive.eds``); canopen serves SDO. What a real drive adds,
this class adds:

- NMT slave: boot-up message, heartbeat producer (0x1017), start/stop/pre-operational,
  reset node (all parameters back to saved or EDS values) and reset communication
  (0x1000-0x1FFF only); PDOs only in OPERATIONAL, no SDO in STOPPED.
- PDOs from the mapping objects 0x1400/0x1600 (RPDO) and 0x1800/0x1A00 (TPDO): synchronous
  RPDO data (transmission type 0..240) is applied at the next SYNC, event-driven (254/255)
  at once; synchronous TPDOs go out on every n-th SYNC, event-driven ones on change
  (inhibit time 0x1800 sub 3) and on the event timer. Mapping follows CiA 301 (only while
  the PDO is invalid and sub 0 is 0; objects must exist and be mappable, at most 64 bits).
  RPDO deadline monitoring (0x1400 sub 5) sends EMCY 0x8250.
- Master loss (CiA 301, CiA 402): consumer heartbeat (0x1016, monitoring starts with the
  first heartbeat of the watched node), the RPDO deadline while Operation Enabled, and NMT
  leaving OPERATIONAL are a lost connection: EMCY (0x8130 / 0x8250) and the abort
  connection option 0x6007 (0 no action, 1 fault signal, 2 disable voltage, 3 quick stop
  command); a heartbeat consumer timeout (a communication error) then also takes the
  error behaviour 0x1029 sub 1 (0 pre-operational, 1 no change, 2 stopped). See
  :meth:`SimulatedDrive._connection_lost`.
- The CiA 402 power state machine (controlword 0x6040, statusword 0x6041 with the masks
  of the standard), modes profile position (1), homing (6, methods 35/37), cyclic
  synchronous position (8) and velocity (9); quick stop by 0x605A, fault reaction by 0x605E,
  following error (0x6065/0x6066 -> EMCY 0x8611), software position limits (0x607D:
  demand clamped, statusword bit 11), EMCY with error register 0x1001, error code 0x603F
  and history 0x1003; fault reset on a rising edge of controlword bit 7.
- A motion model (:mod:`firmware_sim.cia402_motion`): demand -> actual through a saturated
  first-order lag; the brake holds the axis whenever the power stage is off.
- Fault injection: encoder fault (EMCY 0x7305), over-current (0x2310), stuck brake (the
  axis cannot move: following error 0x8611 once motion is demanded), heartbeat stop,
  silence (off the bus), node reset, dropped/delayed TPDOs, dropped RPDOs.

Time: the drive keeps its own clock in integer microseconds. With ``clock=None`` it is
deterministic: every SYNC advances it by the communication cycle period (0x1006, else
0x60C2, else ``default_cycle_s``), and :meth:`SimulatedDrive.advance` moves it between
SYNCs. With a clock function (e.g. ``time.monotonic``) it follows that clock; then call
:meth:`SimulatedDrive.tick` periodically for heartbeats (the bank does).

A SYNC-driven drive still lives in real time where a real one must
(:meth:`SimulatedDrive.wall_tick`, called by the bank's ticker): it sends its heartbeat at
least once per heartbeat period of wall time (a tool waiting for it does not wait for
SYNC), it watches its consumer heartbeats on wall time as well, and once it has lost its
master on wall time (no SYNC will come from a dead master) its clock runs on wall time
until the next SYNC, so that the stop it makes is carried out.

Units: positions counts, velocities counts/s, accelerations counts/s^2, torque per mille
of the rated torque 0x6076 [mN*m].
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import canopen
from canopen import LocalNode, objectdictionary
from canopen.sdo import SdoAbortedError

from controller.winch import WinchAxis
from firmware_sim.cia402_motion import Axis, profile_step

#: The shipped EDS of the vendor-neutral winch drive.
EDS_PATH = Path(__file__).parent / "data" / "winch_drive.eds"

# NMT states (heartbeat byte)
NMT_INITIALISING = 0x00
NMT_STOPPED = 0x04
NMT_OPERATIONAL = 0x05
NMT_PRE_OPERATIONAL = 0x7F

# EMCY error codes (CiA 301 / CiA 402)
EMCY_NO_ERROR = 0x0000
EMCY_OVER_CURRENT = 0x2310  # continuous over current (device output side)
EMCY_ENCODER = 0x7305  # incremental sensor 1 fault
EMCY_PDO_LENGTH = 0x8210  # PDO not processed due to length error
EMCY_RPDO_TIMEOUT = 0x8250  # RPDO timeout
EMCY_HEARTBEAT = 0x8130  # life guard / heartbeat error (consumer heartbeat timeout)
EMCY_FOLLOWING_ERROR = 0x8611  # following error

# SDO abort codes (CiA 301)
ABORT_VALUE_RANGE = 0x06090030
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_DEVICE_STATE = 0x08000022
ABORT_NOT_STORED = 0x08000020
ABORT_NO_DATA = 0x08000024
ABORT_PARAM_INCOMPATIBLE = 0x06040043  # e.g. two 0x1016 entries for one node id

# 0x6007 abort connection option codes (CiA 402)
ABORT_CONN_NONE = 0
ABORT_CONN_FAULT = 1
ABORT_CONN_DISABLE_VOLTAGE = 2
ABORT_CONN_QUICK_STOP = 3
# 0x1029 sub 1 error behaviour after a communication error (CiA 301)
ERR_BEHAVIOUR_PRE_OPERATIONAL = 0
ERR_BEHAVIOUR_NO_CHANGE = 1
ERR_BEHAVIOUR_STOPPED = 2

SAVE_SIGNATURE = 0x65766173  # "save"

# Modes of operation (0x6060)
MODE_NONE = 0
MODE_PP = 1
MODE_HOMING = 6
MODE_CSP = 8
MODE_CSV = 9
HOMING_METHODS = (35, 37)  # homing on the current position

PDO_INVALID = 1 << 31
PDO_COMM = {"rpdo": (0x1400, 0x1600), "tpdo": (0x1800, 0x1A00)}


class State(IntEnum):
    """CiA 402 power states."""

    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7


#: Statusword bits 0-6 of each state (bit 4 "voltage enabled" set while powered).
STATE_BITS = {
    State.NOT_READY_TO_SWITCH_ON: 0x0000,
    State.SWITCH_ON_DISABLED: 0x0040,
    State.READY_TO_SWITCH_ON: 0x0031,
    State.SWITCHED_ON: 0x0033,
    State.OPERATION_ENABLED: 0x0037,
    State.QUICK_STOP_ACTIVE: 0x0017,
    State.FAULT_REACTION_ACTIVE: 0x001F,
    State.FAULT: 0x0008,
}
_POWERED = (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)

SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_OMS12 = 1 << 12  # PP set-point acknowledge / homing attained / CSP-CSV drive follows
SW_OMS13 = 1 << 13  # following error / homing error

CW_FAULT_RESET = 1 << 7
CW_NEW_SETPOINT = 1 << 4
CW_CHANGE_IMMEDIATELY = 1 << 5
CW_RELATIVE = 1 << 6
CW_HALT = 1 << 8


def error_register_bits(code: int) -> int:
    """Error register 0x1001 bits for an EMCY code (CiA 301): generic + class bit."""
    if code == EMCY_NO_ERROR:
        return 0
    reg = 0x01
    group = code >> 12
    if group == 0x2:
        reg |= 0x02  # current
    elif group == 0x3:
        reg |= 0x04  # voltage
    elif group == 0x4:
        reg |= 0x08  # temperature
    elif code >> 8 in (0x81, 0x82):
        reg |= 0x10  # communication
    elif code >> 8 in (0x71, 0x73, 0x84, 0x85, 0x86):
        reg |= 0x20  # device profile specific
    return reg


@dataclass
class _PdoConfig:
    cob_id: int
    valid: bool
    trans_type: int
    entries: list[tuple[int, int, int]]  # (index, subindex, bytes)
    inhibit_us: int = 0
    event_us: int = 0

    @property
    def length(self) -> int:
        return sum(e[2] for e in self.entries)


class _DriveNode(LocalNode):
    """LocalNode without canopen's NMT heartbeat timer: the drive does NMT itself."""

    def __init__(self, node_id: int, od: canopen.ObjectDictionary) -> None:
        super().__init__(node_id, od)
        self._write_callbacks = []


class SimulatedDrive:
    """A CiA 402 servo drive for one winch, as a CANopen slave (see the module docstring).

    ``axis`` gives the node id and the mechanics; ``lock`` serialises everything (share
    one among drives of a bank); ``clock`` returns seconds (None = SYNC-driven clock).
    """

    def __init__(
        self,
        axis: WinchAxis,
        eds: str | Path = EDS_PATH,
        lock: threading.RLock | None = None,
        clock: Callable[[], float] | None = None,
        default_cycle_s: float = 0.004,
        serial_number: int | None = None,
    ) -> None:
        self.axis_params = axis
        self.node_id = int(axis.node_id)
        self.od = canopen.import_od(str(eds), self.node_id)
        self.node = _DriveNode(self.node_id, self.od)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.lock = lock if lock is not None else threading.RLock()
        self._clock = clock
        self.default_cycle_us = int(round(default_cycle_s * 1e6))
        self.serial_number = serial_number if serial_number is not None else 0x1000 + self.node_id
        self.network: canopen.Network | None = None
        self.now_us = int(round(clock() * 1e6)) if clock else 0
        self.axis = Axis()
        #: the count minus the drum: homing moves the count (0x6064), never the drum
        #: (:meth:`drum_counts`, the cable's physical position) [counts]
        self.count_offset = 0.0
        self._saved: dict[tuple[int, int], bytes] = {}
        self._params: dict[tuple[int, int], object] = {}
        self._subscribed: dict[str, int | None] = {"sync": None, "rpdo": None}
        self._hb_subscribed: set[int] = set()  # producers watched (0x1016)
        self._wall_prev: float | None = None  # last wall_tick() [s]
        self._hb_wall_sent = -1e18  # wall time of the last heartbeat sent [s]
        self.free_running = False  #: SYNC-driven clock runs on wall time (master lost)
        #: a SYNC-driven drive also watches its consumer heartbeats on wall time (a dead
        #: master sends no SYNC); off where the master cannot die apart from the drive
        #: (lock-step in one process), so that a starved heartbeat thread stops nothing
        self.watch_wall = True
        #: a gap in our own activity longer than this [s] is starvation, not counted
        #: against the master (:meth:`_forgive_starvation`; the bank sets it from its tick)
        self.starved_s = self.STARVED_S if clock is None else self.CLOCK_STARVED_S
        #: (drive time [us], what, lag [s]) of each lost connection: lag from the last
        #: frame heard (master heartbeat, RPDO) to the reaction, for tests
        self.connection_losses: list[tuple[int, str, float | None]] = []
        #: the last loss: time from the last frame heard (master heartbeat, RPDO) [s]
        self.last_loss_lag_s: float | None = None
        # fault injection
        self.encoder_broken = False
        self.over_current = False
        self.brake_stuck = False
        self.heartbeat_stopped = False
        self.silent = False
        self._drop_tpdo = 0
        self._delay_tpdo = 0
        self._drop_rpdo = 0
        self._delayed: list[tuple[int, bytes]] = []
        #: frames this drive sent, for tests: (time_us, cob_id, data)
        self.sent: list[tuple[int, int, bytes]] = []
        self.keep_sent = False
        #: called (under the drive's lock, at once) with each position latched at a SYNC a
        #: synchronous TPDO answers (the truth a master's time stamps are checked against):
        #: (the drive's time of the SYNC [s], ``time.monotonic()`` as it handled it [s],
        #: the position actual 0x6064 it sends [counts]); None: not told
        self.on_latch: Callable[[float, float, int], None] | None = None
        self.load_torque_nm = 0.0
        self._reset_state(application=True)
        self.nmt_state = NMT_INITIALISING
        self.powered = False

    # ------------------------------------------------------------------ wiring

    def attach(self, network: canopen.Network) -> None:
        """Put the drive on ``network`` (not yet powered: call :meth:`power_on`)."""
        self.network = network
        network.add_node(self.node)
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo)
        network.unsubscribe(0, self.node.nmt.on_command)
        network.subscribe(0, self._on_nmt)
        self._update_subscriptions()

    def detach(self) -> None:
        if self.network is None:
            return
        net = self.network
        for kind in ("sync", "rpdo"):
            cob = self._subscribed[kind]
            if cob is not None:
                net.unsubscribe(cob, self._on_sync if kind == "sync" else self._on_rpdo)
                self._subscribed[kind] = None
        net.unsubscribe(self.node.sdo.rx_cobid, self._on_sdo)
        net.unsubscribe(0, self._on_nmt)
        for nid in self._hb_subscribed:
            net.unsubscribe(0x700 + nid, self._on_consumer_heartbeat)
        self._hb_subscribed = set()
        # canopen's own handlers back, so that it can remove them with the node
        net.subscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        net.subscribe(0, self.node.nmt.on_command)
        del net[self.node_id]
        self.network = None

    def power_on(self) -> None:
        """Switch the drive on: initialise, send boot-up, enter PRE-OPERATIONAL."""
        with self.lock:
            self.powered = True
            self._reset_node(application=True)

    def power_off(self) -> None:
        """Switch the drive off: silent until :meth:`power_on`."""
        with self.lock:
            self.powered = False
            self.nmt_state = NMT_INITIALISING

    # ------------------------------------------------------------------ parameters

    def param(self, index: int, subindex: int = 0) -> object:
        """Current value of a parameter object (decoded)."""
        try:
            return self._params[(index, subindex)]
        except KeyError:
            obj = self.node._find_object(index, subindex)
            val = obj.decode_raw(self.node.get_data(index, subindex))
            return val

    def _load_area(self, lo: int, hi: int) -> None:
        """Parameters in [lo, hi] back to their saved values, else the EDS defaults."""
        store = self.node.data_store
        for index in [i for i in store if lo <= i <= hi]:
            del store[index]
        for key in [k for k in self._params if lo <= k[0] <= hi]:
            del self._params[key]
        for obj in self.od.values():
            if not lo <= obj.index <= hi:
                continue
            subs = [obj] if isinstance(obj, objectdictionary.ODVariable) else list(obj.values())
            for var in subs:
                key = (var.index, var.subindex)
                if key in self._saved:
                    store.setdefault(var.index, {})[var.subindex] = self._saved[key]
                    self._params[key] = var.decode_raw(self._saved[key])
                elif var.default is not None:
                    self._params[key] = var.default
        if lo <= 0x1018 <= hi:
            data = struct.pack("<I", self.serial_number)
            store.setdefault(0x1018, {})[4] = data
            self._params[(0x1018, 4)] = self.serial_number
        self._pdo_cache: dict[str, _PdoConfig] = {}

    def _save_all(self) -> None:
        self._saved = {}
        for index, subs in self.node.data_store.items():
            for sub, data in subs.items():
                obj = self.node._find_object(index, sub)
                if obj.writable and obj.access_type != "rww":  # not process outputs
                    self._saved[(index, sub)] = bytes(data)

    # ------------------------------------------------------------------ resets

    def _reset_state(self, application: bool) -> None:
        if application:
            self._load_area(0x1000, 0xFFFF)
            self.state = State.NOT_READY_TO_SWITCH_ON
            self.controlword = 0
            self.mode = MODE_NONE
            self.error_code = 0
            self.error_history: list[int] = []
            self.dem = self.axis.pos
            self.dem_v = 0.0
            self._csp_from = self._csp_to = self.axis.pos
            self._csp_t = self._csp_T = 0
            self._pp_goal: float | None = None
            self._pp_pending: float | None = None
            self._pp_ack = False
            self._homing_done = False
            self._homing_error = False
            self._fe_time_us = 0
            self._following_error = False
            self._internal_limit = False
            self._ramp: tuple[float, str] | None = None  # (decel, then) while stopping
            self._stop_decel = 0.0  # deceleration of the last stop ramp [counts/s^2]
            self._brake_now = False
        else:
            self._load_area(0x1000, 0x1FFF)
        self._rpdo_buffer: bytes | None = None
        self._last_sync_us: int | None = None
        self._cw_pending: int | None = None
        self._in_pdo = False
        self._sync_count = 0
        self._rpdo_seen = False
        self._last_rpdo_us = 0
        self._rpdo_timeout_active = False
        self._hb_timeout_active = False
        self._consumers: dict[int, int] = {}  # producer node id -> consumer time [us]
        self._hb_heard_us: dict[int, int] = {}  # producer -> last heartbeat (drive time)
        self._hb_heard_wall: dict[int, float] = {}  # producer -> last heartbeat (wall) [s]
        self._tpdo_last: bytes | None = None
        self._tpdo_last_us = -(10**12)
        self._delayed = []
        self._next_hb_us: int | None = None
        self._update_subscriptions()

    def _reset_node(self, application: bool) -> None:
        self.nmt_state = NMT_INITIALISING
        self._reset_state(application)
        self._send(0x700 + self.node_id, b"\x00", "bootup")
        self.nmt_state = NMT_PRE_OPERATIONAL
        self._restart_heartbeat()
        if application:
            self.state = State.SWITCH_ON_DISABLED  # transition 1 (automatic)
            if self.encoder_broken:
                self._fault(EMCY_ENCODER)

    # ------------------------------------------------------------------ time

    def _cycle_us(self) -> int:
        period = int(self.param(0x1006))
        if period > 0:
            return period
        value = int(self.param(0x60C2, 1))
        index = int(self.param(0x60C2, 2))
        if value > 0 and -6 <= index <= 0:
            return int(round(value * 10.0 ** (index + 6)))
        return self.default_cycle_us

    def advance(self, dt_s: float) -> None:
        """Let ``dt_s`` seconds pass (deterministic clock): motion, heartbeat, monitoring."""
        with self.lock:
            self._advance_to(self.now_us + int(round(dt_s * 1e6)))

    def tick(self) -> None:
        """Catch up with the clock function (real-time mode): motion and heartbeats."""
        if self._clock is None:
            return
        with self.lock:
            self._catch_up()

    def _catch_up(self) -> None:
        """Clock mode (under the lock): forgive a gap in our own activity (ticks and frames
        handled), then advance to the clock, deadlines included. A frame handled after the
        process was starved was waiting in our socket: its deadline is judged after the
        gap is forgiven, never before."""
        now_s = self._clock()
        self._forgive_starvation(now_s)
        self._advance_to(int(round(now_s * 1e6)))

    #: a tick this much later than the previous one means this process was starved [s]
    #: (the SYNC clock's wall-time duties, ticked every 10 ms)
    STARVED_S = 0.05
    #: the same on a clock function, where the bank ticks every 2 ms and every frame
    #: handled counts as activity too: shorter than the shortest RPDO deadline (20 ms)
    CLOCK_STARVED_S = 0.008

    def _forgive_starvation(self, now_s: float) -> None:
        """After a gap in our own activity longer than :attr:`starved_s` (the simulator's
        process did not run), do not count the gap against the master: its frames may be
        waiting in our socket. A real drive is never starved; a simulated one must not stop
        the robot because it was. A master that is gone still is: our ticks go on."""
        prev, self._wall_prev = self._wall_prev, now_s
        if prev is None or now_s - prev <= self.starved_s:
            return
        gap_s = now_s - prev
        gap_us = int(gap_s * 1e6)
        if self._clock is not None:
            self._last_rpdo_us += gap_us
            for nid in self._hb_heard_us:
                self._hb_heard_us[nid] += gap_us
        for nid in self._hb_heard_wall:
            self._hb_heard_wall[nid] += gap_s

    def wall_tick(self, now_s: float) -> None:
        """Real-time duties of a SYNC-driven drive (``clock=None``), called periodically with
        the wall time [s]: a heartbeat at least once per heartbeat period of wall time, the
        consumer heartbeats watched on wall time, and the clock running on wall time while
        the master is lost (see the module docstring)."""
        if self._clock is not None:
            return
        with self.lock:
            prev = self._wall_prev
            self._forgive_starvation(now_s)
            if not self.powered:
                return
            if self.free_running and prev is not None and now_s > prev:
                self._advance_to(self.now_us + int(round((now_s - prev) * 1e6)))
            period_s = int(self.param(0x1017)) * 1e-3
            if period_s > 0 and now_s - self._hb_wall_sent >= period_s:
                if not self.heartbeat_stopped:
                    self._send(0x700 + self.node_id, bytes([self.nmt_state]), "heartbeat")
                self._hb_wall_sent = now_s
            for nid, time_us in self._consumers.items():
                heard = self._hb_heard_wall.get(nid)
                if not self.watch_wall:
                    continue
                if heard is not None and now_s - heard > time_us * 1e-6:
                    self.last_loss_lag_s = now_s - heard
                    self._consumer_expired(nid, wall=True)

    def _advance_to(self, now_us: int) -> None:
        if now_us <= self.now_us:
            return
        if not self.powered:
            self.now_us = now_us
            return
        if self._clock is not None and now_us - self.now_us > 200_000:
            # a stalled wall clock: do not replay the gap (no axis jump, no heartbeat burst)
            self.now_us = now_us - 200_000
            if self._next_hb_us is not None and self._next_hb_us < self.now_us:
                self._next_hb_us = self.now_us
        while True:
            stop = now_us
            hb_due = self._next_hb_us is not None and self._next_hb_us <= now_us
            if hb_due:
                stop = max(self._next_hb_us, self.now_us)
            deadline = self._next_deadline_us()
            if deadline is not None and self.now_us <= deadline < stop:
                stop, hb_due = deadline, False
            self._integrate(stop - self.now_us)
            self.now_us = stop
            if hb_due:
                self._heartbeat()
            self._rpdo_deadline()
            self._consumer_deadlines()
            if stop >= now_us:
                break
        self._async_tpdos()

    def _next_deadline_us(self) -> int | None:
        """The earliest RPDO or consumer heartbeat deadline [us of drive time] still armed."""
        out = []
        limit_us = int(self.param(0x1400, 5)) * 1000
        if (limit_us > 0 and self.nmt_state == NMT_OPERATIONAL and self._rpdo_seen
                and not self._rpdo_timeout_active):
            out.append(self._last_rpdo_us + limit_us + 1)
        for nid, time_us in self._consumers.items():
            heard = self._hb_heard_us.get(nid)
            if heard is not None:
                out.append(heard + time_us + 1)
        return min(out) if out else None

    def _integrate(self, dt_us: int) -> None:
        """Motion over ``dt_us`` in sub-steps of at most 2 ms."""
        if dt_us <= 0:
            return
        n = max(1, math.ceil(dt_us / 2000))
        for i in range(n):
            self._motion_step((dt_us * (i + 1)) // n - (dt_us * i) // n)

    # ------------------------------------------------------------------ NMT / heartbeat

    def _restart_heartbeat(self) -> None:
        period_ms = int(self.param(0x1017))
        self._next_hb_us = self.now_us + period_ms * 1000 if period_ms > 0 else None

    def _heartbeat(self) -> None:
        """Send the heartbeat due now and schedule the next one."""
        if self._next_hb_us is None or self.now_us < self._next_hb_us:
            return
        period_us = int(self.param(0x1017)) * 1000
        if not self.heartbeat_stopped:
            self._send(0x700 + self.node_id, bytes([self.nmt_state]), "heartbeat")
            self._hb_wall_sent = time.monotonic()
        self._next_hb_us += period_us
        if self._next_hb_us <= self.now_us - period_us:
            self._next_hb_us = self.now_us + period_us

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) < 2:
            return
        cmd, target = data[0], data[1]
        with self.lock:
            if not self.powered or self.silent or target not in (0, self.node_id):
                return
            if (cmd in (0x02, 0x80, 0x82) and self.nmt_state == NMT_OPERATIONAL
                    and self.state == State.OPERATION_ENABLED):
                # leaving OPERATIONAL: no more setpoints (CiA 402 abort connection)
                self._connection_lost(f"NMT command 0x{cmd:02X} while Operation Enabled",
                                      nmt=False)
            if cmd == 0x01:
                if self.nmt_state != NMT_OPERATIONAL:
                    self._rpdo_seen = False
                    self._sync_count = 0
                self.nmt_state = NMT_OPERATIONAL
            elif cmd == 0x02:
                self.nmt_state = NMT_STOPPED
            elif cmd == 0x80:
                self.nmt_state = NMT_PRE_OPERATIONAL
            elif cmd == 0x81:
                self._reset_node(application=True)
            elif cmd == 0x82:
                self._reset_node(application=False)

    def _on_sdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self.lock:
            if not self.powered or self.silent:
                return
            if self.nmt_state not in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL):
                return
            if len(data) != 8:
                return  # not an SDO frame (CiA 301: always 8 bytes): ignored
            ccs = data[0] & 0xE0
            if ccs in (0x00, 0x60) and self.node.sdo._buffer is None:
                # a segment with no transfer in progress: abort, as a drive would (canopen
                # would abort too, but log the exception it trips over)
                self.node.sdo.abort(0x05040001)
                return
            self.node.sdo.on_request(can_id, data, timestamp)
            self._async_tpdos()

    # ------------------------------------------------------------------ OD callbacks

    def _on_read(self, index: int, subindex: int, od: objectdictionary.ODVariable):
        if index == 0x6041:
            return self.statusword()
        if index == 0x6064:
            return self.position_actual()
        if index == 0x606C:
            return int(round(self.axis.vel))
        if index == 0x6061:
            return self.mode
        if index == 0x6077:
            return self.torque_actual()
        if index == 0x603F:
            return self.error_code
        if index == 0x1001:
            return self.error_register()
        if index == 0x1010 and subindex == 1:
            return 1  # capability: saves on command (writing "save" stores everything)
        if index == 0x1003:
            if subindex == 0:
                return len(self.error_history)
            if subindex > len(self.error_history):
                raise SdoAbortedError(ABORT_NO_DATA)
            return self.error_history[subindex - 1]
        return None

    def _on_write(self, index: int, subindex: int, od: objectdictionary.ODVariable, data: bytes):
        value = od.decode_raw(data)
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, value)
        elif index == 0x1003:
            if value != 0:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            self.error_history = []
            return
        elif index == 0x1005:
            if value & (1 << 30) or value & 0x1FFFF800:
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # consumer only, 11-bit id
        elif index == 0x1010:
            if value != SAVE_SIGNATURE:
                raise SdoAbortedError(ABORT_NOT_STORED)
            self._params[(index, subindex)] = 1
            self._save_all()
            return
        elif index == 0x6060:
            if not self._mode_supported(value):
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x6098:
            if value not in HOMING_METHODS:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x605A:
            if not 0 <= value <= 8:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x605E:
            if not 0 <= value <= 4:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x6007:
            if not 0 <= value <= 3:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x1029:
            if not 0 <= value <= 2:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x1016:
            nid = (value >> 16) & 0xFF
            if value & 0xFF000000 or nid > 127:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            if nid and value & 0xFFFF:
                for sub in range(1, 5):
                    other = int(self.param(0x1016, sub))
                    if sub != subindex and (other >> 16) & 0xFF == nid and other & 0xFFFF:
                        raise SdoAbortedError(ABORT_PARAM_INCOMPATIBLE)  # CiA 301
        self._params[(index, subindex)] = value
        if 0x1400 <= index <= 0x1BFF:
            self._pdo_cache = {}
            self._update_subscriptions()
        elif index == 0x1005:
            self._update_subscriptions()
        elif index == 0x1017:
            self._restart_heartbeat()
        elif index == 0x1016:
            self._load_consumers()
        elif index == 0x6040:
            if self._in_pdo:
                self._cw_pending = value
            else:
                self._process_controlword(value)
        elif index == 0x6060:
            self._set_mode(value)

    def _mode_supported(self, mode: int) -> bool:
        if mode == MODE_NONE:
            return True
        if not 1 <= mode <= 10:
            return False
        bit = {1: 0, 2: 1, 3: 2, 4: 3, 6: 5, 7: 6, 8: 7, 9: 8, 10: 9}.get(mode)
        return bit is not None and bool(int(self.param(0x6502)) >> bit & 1)

    # ------------------------------------------------------------------ PDO configuration

    def _check_pdo_write(self, index: int, subindex: int, value: int) -> None:
        kind = "rpdo" if index < 0x1800 else "tpdo"
        comm, mapping = PDO_COMM[kind]
        n = (index - comm) % 0x200
        cfg = self._pdo(kind, n)
        if index - n == comm:  # communication parameter
            if subindex == 1:
                if cfg.valid and not value & PDO_INVALID and (value & 0x7FF) != cfg.cob_id:
                    raise SdoAbortedError(ABORT_VALUE_RANGE)  # COB-ID changes only when invalid
                if value & 0x1FFFF800 and not value & (1 << 29):
                    raise SdoAbortedError(ABORT_VALUE_RANGE)
            elif subindex == 2 and 240 < value < 254:
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # reserved / RTR-only: unsupported
            return
        # mapping parameter: only while the PDO is invalid (CiA 301)
        if cfg.valid:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
            total = 0
            for sub in range(1, value + 1):
                entry = int(self.param(mapping + n, sub))
                total += self._check_mapping_entry(kind, entry)
            if total > 64:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
        else:
            if int(self.param(mapping + n, 0)) != 0:
                raise SdoAbortedError(ABORT_DEVICE_STATE)
            if value:
                self._check_mapping_entry(kind, value)

    def _check_mapping_entry(self, kind: str, entry: int) -> int:
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        try:
            obj = self.node._find_object(index, sub)
        except SdoAbortedError:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE) from None
        if not obj.pdo_mappable or bits != len(obj) or bits % 8:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        if kind == "rpdo" and not obj.writable:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        if kind == "tpdo" and not obj.readable:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        return bits

    def _pdo(self, kind: str, n: int = 0) -> _PdoConfig:
        key = f"{kind}{n}"
        cfg = self._pdo_cache.get(key)
        if cfg is not None:
            return cfg
        comm, mapping = PDO_COMM[kind]
        cob = int(self.param(comm + n, 1))
        entries = []
        for sub in range(1, int(self.param(mapping + n, 0)) + 1):
            e = int(self.param(mapping + n, sub))
            entries.append((e >> 16, (e >> 8) & 0xFF, (e & 0xFF) // 8))
        cfg = _PdoConfig(
            cob_id=cob & 0x7FF,
            valid=not cob & PDO_INVALID,
            trans_type=int(self.param(comm + n, 2)),
            entries=entries,
        )
        if kind == "tpdo":
            cfg.inhibit_us = int(self.param(comm + n, 3)) * 100
            cfg.event_us = int(self.param(comm + n, 5)) * 1000
        self._pdo_cache[key] = cfg
        return cfg

    def _update_subscriptions(self) -> None:
        self._load_consumers()
        if self.network is None:
            return
        sync_cob = int(self.param(0x1005)) & 0x7FF
        rp = self._pdo("rpdo")
        want = {"sync": sync_cob, "rpdo": rp.cob_id if rp.valid else None}
        for kind, handler in (("sync", self._on_sync), ("rpdo", self._on_rpdo)):
            old = self._subscribed[kind]
            if old == want[kind]:
                continue
            if old is not None:
                self.network.unsubscribe(old, handler)
            if want[kind] is not None:
                self.network.subscribe(want[kind], handler)
            self._subscribed[kind] = want[kind]

    # ------------------------------------------------------------------ PDO traffic

    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self.lock:
            if not self.powered or self.silent or self.nmt_state != NMT_OPERATIONAL:
                return
            if self._drop_rpdo > 0:
                self._drop_rpdo -= 1
                return
            cfg = self._pdo("rpdo")
            if not cfg.valid or can_id != cfg.cob_id:
                return
            if len(data) < cfg.length:
                self._emcy(EMCY_PDO_LENGTH)
                return
            if self._clock is not None:  # stamp with the time it arrived, not the last tick
                self._catch_up()
            self._rpdo_seen = True
            self._last_rpdo_us = self.now_us
            if self._rpdo_timeout_active:
                self._rpdo_timeout_active = False
                if self.error_code == 0:
                    self._emcy(EMCY_NO_ERROR)
            if cfg.trans_type <= 240:
                self._rpdo_buffer = bytes(data)
            else:
                self._apply_rpdo(bytes(data))
                self._async_tpdos()

    def _apply_rpdo(self, data: bytes) -> None:
        cfg = self._pdo("rpdo")
        self._in_pdo = True
        self._cw_pending = None
        try:
            offset = 0
            for index, sub, nbytes in cfg.entries:
                self.node.set_data(index, sub, data[offset:offset + nbytes])
                offset += nbytes
        finally:
            self._in_pdo = False
        if self._cw_pending is not None:
            cw, self._cw_pending = self._cw_pending, None
            self._process_controlword(cw)

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self.lock:
            if not self.powered or self.silent:
                return
            self.free_running = False  # a master is there again: time is the SYNCs' again
            if self._clock is None:
                now = self.now_us + self._cycle_us()
            else:
                now_s = self._clock()
                self._forgive_starvation(now_s)  # as _catch_up: a SYNC waiting meanwhile
                now = int(round(now_s * 1e6))
            interval = now - self._last_sync_us if self._last_sync_us is not None else 0
            self._last_sync_us = now
            self._advance_to(now)
            if self.nmt_state != NMT_OPERATIONAL:
                return
            for cob, payload in self._delayed:
                self._send(cob, payload, "tpdo")
            self._delayed = []
            if self._rpdo_buffer is not None:
                buf, self._rpdo_buffer = self._rpdo_buffer, None
                self._apply_rpdo(buf)
            if self.mode in (MODE_CSP,) and self.state == State.OPERATION_ENABLED:
                # interpolate over the configured period; on the wall clock over the measured
                # SYNC interval (a late or early SYNC does not make the demand lag or jump)
                period = self._cycle_us()
                if self._clock is not None and 0 < interval < 4 * period:
                    period = interval
                self._csp_segment(period)
            self._sync_count += 1
            cfg = self._pdo("tpdo")
            if cfg.valid and 1 <= cfg.trans_type <= 240 and self._sync_count % cfg.trans_type == 0:
                if self.on_latch is not None:
                    self.on_latch(self.now_us * 1e-6, time.monotonic(),
                                  int(self.position_actual()))
                self._transmit_tpdo(cfg)
            elif cfg.valid and cfg.trans_type == 0:
                payload = self._tpdo_payload(cfg)
                if payload != self._tpdo_last:
                    self._transmit_tpdo(cfg, payload)
            self._async_tpdos()

    def _tpdo_payload(self, cfg: _PdoConfig) -> bytes:
        out = bytearray()
        for index, sub, nbytes in cfg.entries:
            out += self.node.get_data(index, sub)[:nbytes]
        return bytes(out)

    def _transmit_tpdo(self, cfg: _PdoConfig, payload: bytes | None = None) -> None:
        payload = self._tpdo_payload(cfg) if payload is None else payload
        self._tpdo_last = payload
        self._tpdo_last_us = self.now_us
        if self._drop_tpdo > 0:
            self._drop_tpdo -= 1
            return
        if self._delay_tpdo > 0:
            self._delay_tpdo -= 1
            self._delayed.append((cfg.cob_id, payload))
            return
        self._send(cfg.cob_id, payload, "tpdo")

    def _async_tpdos(self) -> None:
        if self.nmt_state != NMT_OPERATIONAL or self.silent or not self.powered:
            return
        cfg = self._pdo("tpdo")
        if not cfg.valid or cfg.trans_type < 254:
            return
        since = self.now_us - self._tpdo_last_us
        payload = self._tpdo_payload(cfg)
        changed = payload != self._tpdo_last and since >= cfg.inhibit_us
        timer = cfg.event_us > 0 and since >= cfg.event_us
        if changed or timer:
            self._transmit_tpdo(cfg, payload)

    def _rpdo_deadline(self) -> None:
        if self.nmt_state != NMT_OPERATIONAL or not self._rpdo_seen or self._rpdo_timeout_active:
            return
        limit_us = int(self.param(0x1400, 5)) * 1000
        if limit_us > 0 and self.now_us - self._last_rpdo_us > limit_us:
            self.last_loss_lag_s = (self.now_us - self._last_rpdo_us) * 1e-6
            self._rpdo_timeout_active = True
            self._emcy(EMCY_RPDO_TIMEOUT)
            if self.state == State.OPERATION_ENABLED:
                # the setpoints stopped: the drive cannot follow a master it no longer hears
                self._connection_lost("RPDO deadline (0x1400 sub 5) passed", nmt=False)

    # ------------------------------------------------------------------ master loss

    def _load_consumers(self) -> None:
        """0x1016 sub 1..n -> watched producers; (re)subscribe to their heartbeats."""
        consumers: dict[int, int] = {}
        for sub in range(1, 5):
            try:
                value = int(self.param(0x1016, sub))
            except (KeyError, SdoAbortedError):
                break
            nid, time_ms = (value >> 16) & 0xFF, value & 0xFFFF
            if 1 <= nid <= 127 and time_ms > 0:
                consumers[nid] = time_ms * 1000
        self._consumers = consumers
        for nid in list(self._hb_heard_us):
            if nid not in consumers:
                del self._hb_heard_us[nid]
        for nid in list(self._hb_heard_wall):
            if nid not in consumers:
                del self._hb_heard_wall[nid]
        if self.network is None:
            return
        want = set(consumers)
        for nid in self._hb_subscribed - want:
            self.network.unsubscribe(0x700 + nid, self._on_consumer_heartbeat)
        for nid in want - self._hb_subscribed:
            self.network.subscribe(0x700 + nid, self._on_consumer_heartbeat)
        self._hb_subscribed = want

    def _on_consumer_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        nid = can_id - 0x700
        with self.lock:
            if not self.powered or self.silent or nid not in self._consumers or not data:
                return
            if self._clock is not None:  # stamp with the time it arrived, not the last tick
                self._catch_up()
            self._hb_heard_us[nid] = self.now_us
            if self._clock is None:  # for wall_tick(), which the bank calls with this clock
                self._hb_heard_wall[nid] = time.monotonic()
            if self._hb_timeout_active:
                self._hb_timeout_active = False
                if self.error_code == 0 and not self._rpdo_timeout_active:
                    self._emcy(EMCY_NO_ERROR)

    def _consumer_deadlines(self) -> None:
        for nid, time_us in list(self._consumers.items()):
            heard = self._hb_heard_us.get(nid)
            if heard is not None and self.now_us - heard > time_us:
                self.last_loss_lag_s = (self.now_us - heard) * 1e-6
                self._consumer_expired(nid, wall=False)

    def _consumer_expired(self, nid: int, wall: bool) -> None:
        """No heartbeat of ``nid`` within its consumer time: monitoring stops until the next
        heartbeat (CiA 301), EMCY 0x8130, then the connection counts as lost."""
        self._hb_heard_us.pop(nid, None)
        self._hb_heard_wall.pop(nid, None)
        self._hb_timeout_active = True
        self._emcy(EMCY_HEARTBEAT)
        if wall and self._clock is None:
            self.free_running = True  # no SYNC will come: carry the stop out on wall time
        self._connection_lost(f"no heartbeat of node {nid} for "
                              f"{self._consumers.get(nid, 0) / 1000:g} ms (0x1016)")

    def _connection_lost(self, why: str, nmt: bool = True) -> None:
        """The master is lost: 0x6007 on the power state, then (``nmt``: a communication
        error in the sense of CiA 301, i.e. a heartbeat consumer timeout) 0x1029 sub 1 on the
        NMT state. A missed RPDO deadline or NMT leaving OPERATIONAL only act on the power
        state: the setpoints stopped, the node itself is not in question."""
        self.connection_losses.append((self.now_us, why, self.last_loss_lag_s))
        opt = int(self.param(0x6007))
        s = self.state
        if opt == ABORT_CONN_FAULT:
            self._fault(EMCY_HEARTBEAT if "heartbeat" in why else EMCY_RPDO_TIMEOUT)
        elif opt == ABORT_CONN_DISABLE_VOLTAGE:
            if s in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
                self._power_off(State.SWITCH_ON_DISABLED)  # 9 / 12
            elif s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON):
                self.state = State.SWITCH_ON_DISABLED  # 7 / 10
        elif opt == ABORT_CONN_QUICK_STOP:
            if s == State.OPERATION_ENABLED:
                self._quick_stop()  # 11
            elif s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON):
                self.state = State.SWITCH_ON_DISABLED  # 7 / 10
        if not nmt:
            return
        behaviour = int(self.param(0x1029, 1))
        if behaviour == ERR_BEHAVIOUR_PRE_OPERATIONAL and self.nmt_state == NMT_OPERATIONAL:
            self.nmt_state = NMT_PRE_OPERATIONAL
        elif behaviour == ERR_BEHAVIOUR_STOPPED:
            self.nmt_state = NMT_STOPPED

    # ------------------------------------------------------------------ sending

    def _send(self, cob_id: int, data: bytes, kind: str) -> None:
        if self.silent or not self.powered or self.network is None:
            return
        if self.keep_sent:
            self.sent.append((self.now_us, cob_id, bytes(data)))
        self.network.send_message(cob_id, bytes(data))

    def _emcy(self, code: int) -> None:
        if self.nmt_state not in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL):
            return
        reg = self.error_register() if code == EMCY_NO_ERROR else (
            self.error_register() | error_register_bits(code))
        cob = int(self.param(0x1014))
        if cob & PDO_INVALID:
            return
        self._send(cob & 0x7FF, struct.pack("<HB5s", code, reg, b""), "emcy")

    def error_register(self) -> int:
        reg = error_register_bits(self.error_code)
        if self._rpdo_timeout_active or self._hb_timeout_active:
            reg |= error_register_bits(EMCY_RPDO_TIMEOUT)
        return reg

    # ------------------------------------------------------------------ CiA 402 state machine

    def _process_controlword(self, cw: int) -> None:
        prev, self.controlword = self.controlword, cw
        s = self.state
        if s == State.FAULT:
            if cw & CW_FAULT_RESET and not prev & CW_FAULT_RESET:
                self._fault_reset()
            return
        if s in (State.FAULT_REACTION_ACTIVE, State.NOT_READY_TO_SWITCH_ON):
            return
        if cw & CW_FAULT_RESET:
            return  # bit 7 high: no command (a reset edge only matters in Fault)
        disable_voltage = cw & 0x02 == 0
        quick_stop = cw & 0x06 == 0x02
        shutdown = cw & 0x07 == 0x06
        switch_on = cw & 0x0F == 0x07
        enable = cw & 0x0F == 0x0F
        if s == State.SWITCH_ON_DISABLED:
            if shutdown:
                self.state = State.READY_TO_SWITCH_ON  # 2
        elif s == State.READY_TO_SWITCH_ON:
            if disable_voltage or quick_stop:
                self.state = State.SWITCH_ON_DISABLED  # 7
            elif switch_on:
                self.state = State.SWITCHED_ON  # 3
            elif enable:
                self.state = State.SWITCHED_ON  # 3 + 4
                self._enable_operation()
        elif s == State.SWITCHED_ON:
            if disable_voltage or quick_stop:
                self.state = State.SWITCH_ON_DISABLED  # 10
            elif shutdown:
                self.state = State.READY_TO_SWITCH_ON  # 6
            elif enable:
                self._enable_operation()  # 4
        elif s == State.OPERATION_ENABLED:
            if disable_voltage:
                self._power_off(State.SWITCH_ON_DISABLED)  # 9
            elif quick_stop:
                self._quick_stop()  # 11
            elif shutdown:
                self._power_off(State.READY_TO_SWITCH_ON)  # 8
            elif switch_on:
                self._power_off(State.SWITCHED_ON)  # 5
            else:
                self._mode_controlword(prev, cw)
        elif s == State.QUICK_STOP_ACTIVE:
            if disable_voltage:
                self._power_off(State.SWITCH_ON_DISABLED)  # 12
            elif enable and self._ramp is None and self._quick_stop_option() >= 5:
                self._enable_operation()  # 16

    def _enable_operation(self) -> None:
        self.state = State.OPERATION_ENABLED
        self.dem = self.axis.pos
        self.dem_v = 0.0
        self._fe_time_us = 0
        self._following_error = False
        self._ramp = None
        self._pp_goal = self._pp_pending = None
        # CSP: the drive starts from where it stands; the next SYNC brings the target
        self._csp_from = self._csp_to = self.axis.pos
        self._csp_t = self._csp_T = 0

    def _power_off(self, new_state: State) -> None:
        self.state = new_state
        self._ramp = None
        self.dem = self.axis.pos
        self.dem_v = 0.0
        self.axis.hold()

    def _quick_stop_option(self) -> int:
        return int(self.param(0x605A))

    def _quick_stop(self) -> None:
        opt = self._quick_stop_option()
        if opt == 0:
            self._power_off(State.SWITCH_ON_DISABLED)
            return
        self.state = State.QUICK_STOP_ACTIVE
        decel = self._ramp_decel({1: 0x6084, 5: 0x6084, 2: 0x6085, 6: 0x6085}.get(opt, 0x60C5))
        self._start_ramp(decel, "disable" if opt <= 4 else "hold")

    def _ramp_decel(self, index: int) -> float:
        dec = float(self.param(index))
        return dec if dec > 0 else float(self.param(0x60C5))

    def _start_ramp(self, decel: float, then: str) -> None:
        self._ramp = (max(decel, 1.0), then)
        self._stop_decel = max(decel, 1.0)
        self.dem = self.axis.pos
        self.dem_v = self.axis.vel

    def _fault(self, code: int) -> None:
        """A fault occurred: EMCY, then the fault reaction (0x605E), then Fault."""
        if self.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return
        self.error_code = code
        self.error_history = ([code] + self.error_history)[:8]
        self._emcy(code)
        self._pp_goal = self._pp_pending = None
        powered = self.state in _POWERED
        self.state = State.FAULT_REACTION_ACTIVE
        opt = int(self.param(0x605E))
        if not powered or opt == 0 or self.encoder_broken:
            self._power_off(State.FAULT)
            return
        index = {1: 0x6084, 2: 0x6085}.get(opt, 0x60C5)
        self._start_ramp(self._ramp_decel(index), "fault")

    def _fault_reset(self) -> None:
        if self.encoder_broken or (self.over_current and self.error_code == EMCY_OVER_CURRENT):
            return  # the cause persists
        self.state = State.SWITCH_ON_DISABLED  # 15
        self.error_code = 0
        self._following_error = False
        self._fe_time_us = 0
        self._emcy(EMCY_NO_ERROR)

    def _set_mode(self, mode: int) -> None:
        if mode == self.mode:
            return
        self.mode = mode
        self._pp_goal = self._pp_pending = None
        self._pp_ack = False
        self._homing_done = self._homing_error = False
        self.dem = self.axis.pos
        self.dem_v = 0.0 if self.state != State.OPERATION_ENABLED else self.dem_v
        self._csp_from = self._csp_to = self.axis.pos
        self._csp_t = self._csp_T = 0

    def _mode_controlword(self, prev: int, cw: int) -> None:
        """Operation-mode bits of the controlword in Operation Enabled (bits 4, 5, 6, 8)."""
        rising = cw & CW_NEW_SETPOINT and not prev & CW_NEW_SETPOINT
        if self.mode == MODE_PP:
            if not cw & CW_NEW_SETPOINT:
                self._pp_ack = False
            if rising:
                target = float(self.param(0x607A))
                if cw & CW_RELATIVE:
                    base = self._pp_goal if self._pp_goal is not None else self.dem
                    target += base
                target = self._clamp_limits(target)
                if self._pp_goal is None or cw & CW_CHANGE_IMMEDIATELY:
                    self._pp_goal = target
                    self._pp_pending = None
                else:
                    self._pp_pending = target
                self._pp_ack = True
        elif self.mode == MODE_HOMING and rising:
            method = int(self.param(0x6098))
            self._homing_done = False
            self._homing_error = False
            if method in HOMING_METHODS:
                delta = float(self.param(0x607C)) - self.axis.pos
                self.axis.pos += delta
                self.dem += delta
                self._csp_from += delta
                self._csp_to += delta
                self.count_offset += delta  # the reading moves, the drum does not
                self._homing_done = True
            else:
                self._homing_error = True

    def _csp_segment(self, period_us: int) -> None:
        """At SYNC: the demand runs from where it is to the new target over one period."""
        target = self._clamp_limits(float(self.param(0x607A)))
        self._csp_from = self.dem
        self._csp_to = target
        self._csp_t = 0
        self._csp_T = max(period_us, 1)

    def _limits(self) -> tuple[float, float] | None:
        lo, hi = int(self.param(0x607D, 1)), int(self.param(0x607D, 2))
        if lo == 0 and hi == 0 or lo > hi:
            return None
        return float(lo), float(hi)

    def _clamp_limits(self, x: float) -> float:
        lim = self._limits()
        if lim is None:
            self._internal_limit = False
            return x
        lo, hi = lim
        self._internal_limit = not lo <= x <= hi
        # outside the limits already (moved there unpowered): no further outward, no jump
        lo, hi = min(lo, self.dem), max(hi, self.dem)
        return min(max(x, lo), hi)

    # ------------------------------------------------------------------ motion

    def _motion_step(self, h_us: int) -> None:
        h = h_us * 1e-6
        s = self.state
        v_max = float(self.param(0x607F)) or 1e12
        a_max = float(self.param(0x60C5)) or 1e12
        moving = True
        if s in (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE):
            # the stop ramp sets how hard the motor brakes, even beyond 0x60C5
            a_max = max(a_max, self._stop_decel)
        if s == State.OPERATION_ENABLED:
            self._mode_demand(h_us, v_max, a_max)
        elif s in (State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE) and self._ramp:
            decel, then = self._ramp
            self.dem, self.dem_v = profile_step(self.dem, self.dem_v, None, v_max, decel, decel, h)
            if self.dem_v == 0.0:
                self._ramp = None
                if then == "fault":
                    self._power_off(State.FAULT)  # 14
                    moving = False
                elif then == "disable":
                    self._power_off(State.SWITCH_ON_DISABLED)  # 12
                    moving = False
        elif s == State.QUICK_STOP_ACTIVE:
            self.dem_v = 0.0  # stopped and holding (options 5-8)
        else:
            moving = False
        if not moving or self.brake_stuck or self.encoder_broken:
            if not moving:
                self.dem = self.axis.pos
                self.dem_v = 0.0
            self.axis.hold()
        else:
            self.axis.follow(self.dem, self.dem_v, h, v_max, a_max,
                             self.axis_params.lag_time_constant_s)
        self._monitor_following(h_us)

    def _mode_demand(self, h_us: int, v_max: float, a_max: float) -> None:
        h = h_us * 1e-6
        halt = bool(self.controlword & CW_HALT)
        if self.mode == MODE_CSP:
            if self._csp_T > 0:
                running = self._csp_t < self._csp_T  # else: holding the last target
                self._csp_t = min(self._csp_t + h_us, self._csp_T)
                frac = self._csp_t / self._csp_T
                self.dem = self._csp_from + (self._csp_to - self._csp_from) * frac
                slope = (self._csp_to - self._csp_from) / (self._csp_T * 1e-6)
                self.dem_v = slope if running else 0.0
        elif self.mode == MODE_CSV:
            v_t = max(-v_max, min(v_max, float(self.param(0x60FF))))
            if halt:
                v_t = 0.0
            dv = max(-a_max * h, min(a_max * h, v_t - self.dem_v))
            self.dem_v += dv
            nxt = self.dem + self.dem_v * h
            lim = self._limits()
            if lim is not None and not lim[0] <= nxt <= lim[1]:
                nxt = min(max(nxt, lim[0]), lim[1])
                self.dem_v = 0.0
                self._internal_limit = True
            elif lim is not None:
                self._internal_limit = False
            self.dem = nxt
        elif self.mode == MODE_PP:
            acc = float(self.param(0x6083)) or a_max
            dec = float(self.param(0x6084)) or a_max
            vp = min(float(self.param(0x6081)) or v_max, v_max)
            goal = None if halt else self._pp_goal
            if goal is None and self.dem_v == 0.0:
                return
            self.dem, self.dem_v = profile_step(
                self.dem, self.dem_v, goal, vp, min(acc, a_max), min(dec, a_max), h)
            if goal is not None and self.dem == goal and self.dem_v == 0.0:
                if self._pp_pending is not None:
                    self._pp_goal, self._pp_pending = self._pp_pending, None
        else:  # homing, no mode: hold
            self.dem_v = 0.0

    def _monitor_following(self, h_us: int) -> None:
        if self.state != State.OPERATION_ENABLED or self.mode not in (MODE_PP, MODE_CSP, MODE_CSV):
            self._fe_time_us = 0
            return
        window = int(self.param(0x6065))
        if window == 0xFFFFFFFF:
            return
        if abs(self.dem - self.axis.pos) > window:
            self._fe_time_us += h_us
            if self._fe_time_us > int(self.param(0x6066)) * 1000:
                self._following_error = True
                self._fault(EMCY_FOLLOWING_ERROR)
        else:
            self._fe_time_us = 0
            self._following_error = False

    # ------------------------------------------------------------------ process values

    def statusword(self) -> int:
        s = self.state
        sw = STATE_BITS[s] | SW_REMOTE
        if self._rpdo_timeout_active or self._hb_timeout_active:
            sw |= SW_WARNING
        if self._internal_limit and s == State.OPERATION_ENABLED:
            sw |= SW_INTERNAL_LIMIT
        if s == State.OPERATION_ENABLED:
            halt = bool(self.controlword & CW_HALT)
            if self.mode == MODE_PP:
                at_goal = self._pp_goal is None or (
                    self.dem == self._pp_goal and self.dem_v == 0.0
                    and abs(self._pp_goal - self.axis.pos) <= int(self.param(0x6067)))
                if (at_goal and self._pp_pending is None) or (halt and self.dem_v == 0.0):
                    sw |= SW_TARGET_REACHED
                if self._pp_ack:
                    sw |= SW_OMS12
                if self._following_error:
                    sw |= SW_OMS13
            elif self.mode == MODE_HOMING:
                if self._homing_done or halt:
                    sw |= SW_TARGET_REACHED
                if self._homing_done:
                    sw |= SW_OMS12
                if self._homing_error:
                    sw |= SW_OMS13
            elif self.mode in (MODE_CSP, MODE_CSV):
                if not halt:
                    sw |= SW_OMS12
                if self._following_error and self.mode == MODE_CSP:
                    sw |= SW_OMS13
        elif s == State.QUICK_STOP_ACTIVE and self._ramp is None:
            sw |= SW_TARGET_REACHED
        return sw

    def position_actual(self) -> int:
        return int(round(self.axis.pos))

    def drum_counts(self) -> float:
        """The drum's physical position [counts of the power-on reading]: the position
        actual less what homings added to the count (the plant's cable length)."""
        return self.axis.pos - self.count_offset

    def torque_actual(self) -> int:
        rated_mnm = int(self.param(0x6076)) or 1
        tq = self.load_torque_nm * 1e6 / rated_mnm if self.state in _POWERED else 0.0
        return max(-32768, min(32767, int(round(tq))))

    # ------------------------------------------------------------------ physical state

    def set_position_counts(self, counts: float) -> None:
        """Move the axis to ``counts`` (e.g. from a plant model): actual and demand together."""
        with self.lock:
            delta = float(counts) - self.axis.pos
            self.axis.pos += delta
            self.dem += delta
            self._csp_from += delta
            self._csp_to += delta
            if self._pp_goal is not None:
                self._pp_goal += delta

    # ------------------------------------------------------------------ fault injection

    def inject_encoder_fault(self) -> None:
        """Encoder signal lost: EMCY 0x7305, immediate stop (brake), Fault until repaired."""
        with self.lock:
            self.encoder_broken = True
            if self.state == State.FAULT_REACTION_ACTIVE:  # no reaction ramp without it
                self._power_off(State.FAULT)
            self._fault(EMCY_ENCODER)
            self._async_tpdos()

    def repair_encoder(self) -> None:
        with self.lock:
            self.encoder_broken = False

    def inject_over_current(self, persist: bool = False) -> None:
        """Output over-current trip: EMCY 0x2310, fault reaction, Fault. ``persist``: the
        cause stays (a fault reset fails) until :meth:`clear_over_current`."""
        with self.lock:
            self.over_current = self.over_current or persist
            self._fault(EMCY_OVER_CURRENT)
            self._async_tpdos()

    def clear_over_current(self) -> None:
        with self.lock:
            self.over_current = False

    def stick_brake(self, stuck: bool = True) -> None:
        """The holding brake does not release: the axis cannot move (following error)."""
        with self.lock:
            self.brake_stuck = stuck

    def stop_heartbeat(self, stopped: bool = True) -> None:
        """The heartbeat producer stops (everything else keeps running)."""
        with self.lock:
            self.heartbeat_stopped = stopped

    def set_silent(self, silent: bool = True) -> None:
        """The node drops off the bus (sends and answers nothing) or comes back."""
        with self.lock:
            self.silent = silent

    def reset_node(self) -> None:
        """Power cycle / internal reset: boot-up, PRE-OPERATIONAL, Switch On Disabled.

        Parameters return to their saved (0x1010) or EDS values; the position is kept
        (absolute multi-turn encoder).
        """
        with self.lock:
            self._reset_node(application=True)

    def drop_tpdos(self, n: int = 1) -> None:
        """Do not send the next ``n`` TPDOs."""
        with self.lock:
            self._drop_tpdo += n

    def delay_tpdos(self, n: int = 1) -> None:
        """Send each of the next ``n`` TPDOs one SYNC late (before the next one)."""
        with self.lock:
            self._delay_tpdo += n

    def drop_rpdos(self, n: int = 1) -> None:
        """Lose the next ``n`` RPDOs addressed to this drive."""
        with self.lock:
            self._drop_rpdo += n

    def stop_dropping(self) -> None:
        """Send and receive PDOs again (cancels what drop_tpdos / drop_rpdos still owe)."""
        with self.lock:
            self._drop_tpdo = 0
            self._drop_rpdo = 0
