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
  a malformed one (wrong length) as ``emcy_malformed`` naming the node;
- drive in Fault / Fault Reaction Active (statusword), with the code of the EMCY that came
  with the transition to Fault (warnings after it are events, never the fault's code),
  then confirmed by reading 0x603F outside the cycle (a background SDO read; an event
  ``fault_code`` when 0x603F says something else, which then becomes the code);
- drive in Quick Stop Active without the master asking (``quick_stop``: it lost its master,
  0x6007): the master holds it there (never re-enables it by itself) until :meth:`enable`;
- heartbeat lost: no heartbeat for ``heartbeat_misses`` periods (code 0x8130): the drive's
  state is UNKNOWN in every cycle until its heartbeat is back (``heartbeat_resumed``) or
  :meth:`recover`, whatever TPDOs it still sends; the master asks it to quick stop (in case
  it still listens);
- unexpected boot-up (node reset; code 0x8130) or NMT state other than OPERATIONAL;
- TPDO missing for a SYNC or arriving late (code 0x8250 from the master's side);
- TPDOs lost: no TPDO for ``tpdo_deadline_cycles`` SYNCs in a row (and at least
  ``tpdo_deadline_min_s`` of the master clock; :func:`hal.bus_watch.feedback_lost`): the
  drive is lost (``drive_lost``, code 0x8250), its state UNKNOWN (never its last live
  state) until its TPDOs come back (``tpdo_resumed``); the master asks it to quick stop
  (in case it still listens). :meth:`enable_and_wait` raises :class:`DriveLostError` when a
  drive is lost while it enables;
- another master on the bus (``foreign_master``, :class:`hal.bus_watch.ForeignFrameWatch`):
  an SDO request to one of our drives, an NMT command, an RPDO of one of our drives or a
  SYNC that this master did not send; the event names the COB-ID and what the frame does
  (node id 0 for NMT to all nodes and SYNC); active as a fault for ``FOREIGN_HOLD_S`` of
  the master clock after the last such frame;
- a drive the master asks to be enabled that goes back towards Switch On Disabled without
  being asked (``switched_off``: another master's 0x6040 write, or the drive itself): the
  master stops asking, leaves it where it is and never enables it again by itself (until
  :meth:`enable`);
- internal limit active (software position limit reached, statusword bit 11);
- the bus refusing frames (node id 0, code 0x8100), without raising out of the cycle;
- the link lost (node id 0, ``link_lost``; a :class:`~hal.socketcand_link.SocketcandLink`
  whose server went away): every drive's state is unknown and each has a ``link_lost``
  fault; when the link is back (``link_back``) the drives are recovered like reset nodes
  (:meth:`recover`). Blocking calls on a dead link raise :class:`BusLinkError` naming the
  bus.

Master heartbeat: from :meth:`start` on, the master produces its heartbeat (COB-ID
0x700 + ``[bus] master_node_id``, state OPERATIONAL) every ``master_heartbeat_period_s``
from its own thread (on the wall clock, whatever the cycle does), and on a non-wall clock
also from the cycle, once per period of that clock. The drives watch it (0x1016, written at
:meth:`start` with the rest of :func:`~hal.drives_config.drive_settings`) and stop on their
own, per 0x6007, when it is gone.

Memory stays bounded whatever the drives send: EMCYs are not logged by canopen
(``node.emcy.log`` stays empty), the event history keeps the last ``EVENTS_KEPT`` events.

Clock: ``clock="wall"`` (time.monotonic) for real drives, ``clock="sync"`` (number of SYNCs
sent x SYNC period) with a rig on the deterministic simulated clock, or any callable.

A CAN log of the bus is replayed through the same code by :class:`hal.drives_replay.ReplayDrives`.
"""

from __future__ import annotations

import logging
import queue
import struct
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
from hal.bus_watch import (
    DRIVE_LOST,
    FOREIGN_MASTER,
    TPDO_DEADLINE_CYCLES,
    TPDO_DEADLINE_MIN_S,
    ForeignFrameWatch,
    feedback_lost,
)
from hal.can_bus import CanSpec, open_bus, send_frames
from hal.drives_cia402 import (
    CW_FAULT_RESET,
    RQ,
    ST,
    SW_INTERNAL_LIMIT,
    DriveState,
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
    holding_problems,
    load_eds,
    pdo_struct,
    sdo_read,
    verify_identity,
)
from hal.rt_threads import raise_thread

#: SDO answer timeout of the HAL's nodes [s] (start-up, recovery, fault-code reads)
SDO_TIMEOUT_S = 1.0
#: a foreign master's frame is an active fault for this long after the last one [s, master
#: clock] (the supervisor latches its quick stop)
FOREIGN_HOLD_S = 0.5
#: lock-step: wall time [s] waited for the TPDOs of drives that missed the SYNC before
MISSING_WAIT_S = 0.05

log = logging.getLogger(__name__)

CODE_HEARTBEAT = 0x8130  # life guard / heartbeat error (CiA 301)
CODE_PDO_TIMEOUT = 0x8250  # RPDO timeout, here: the master's receive PDO = drive's TPDO
CODE_BUS = 0x8100  # communication, generic: the bus refused our frames

NMT_NAMES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
NMT_OPERATIONAL = 0x05
#: NMT restarts of a drive that is not OPERATIONAL before the first enable (start-up)
NMT_START_TRIES = 3
EMCY_STRUCT = struct.Struct("<HB5s")
#: a drive's place on the way to Operation Enabled (by DriveState value; -1: off that way)
_ENABLE_RANK = np.full(len(DriveState), -1, np.int8)
_ENABLE_RANK[[ST.NOT_READY_TO_SWITCH_ON, ST.SWITCH_ON_DISABLED, ST.READY_TO_SWITCH_ON,
              ST.SWITCHED_ON, ST.OPERATION_ENABLED]] = [0, 0, 1, 2, 3]
#: events kept by :meth:`WinchDrives.events` when nobody takes them (oldest dropped)
EVENTS_KEPT = 10_000
#: EMCYs waiting for the next cycle at most (a flood beyond is counted, not kept)
QUEUE_KEPT = 10_000


class DriveStartupError(RuntimeError):
    """Drives did not come up (missing boot-up, no answer); the message names the nodes."""


class DriveLostError(DriveStartupError):
    """Drives lost while they were being enabled (their TPDOs stopped: ``drive_lost``);
    ``node_ids`` names them. Their faults stay in :meth:`WinchDrives.faults`."""

    def __init__(self, message: str, node_ids: tuple[int, ...]) -> None:
        super().__init__(message)
        self.node_ids = node_ids


class BusLinkError(DriveStartupError):
    """The CAN link is down (the socketcand server or the adapter went away, the bus refuses
    frames): raised by the blocking calls, the message names the bus."""


@dataclass(frozen=True)
class DriveEvent:
    """Something that happened on a drive, in order of detection."""

    node_id: int
    cable: str
    kind: str  #: emcy, emcy_malformed, emcy_overflow, fault, fault_code, fault_cleared,
    #: quick_stop, switched_off, heartbeat_lost, heartbeat_resumed, heartbeat_malformed,
    #: boot_up, nmt_state, tpdo_missing, tpdo_late, tpdo_short, drive_lost, tpdo_resumed,
    #: foreign_master, internal_limit, fault_reset_failed, recovered, sdo_error; node_id 0
    #: (the bus): bus_error, link_lost, link_back, foreign_master (NMT to all nodes, SYNC)
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
    kind: str  #: drive_fault, quick_stop, heartbeat_lost, drive_lost, boot_up, nmt_state,
    #: link_lost, foreign_master (node_id 0: a frame to the whole bus)
    code: int
    text: str

    def __str__(self) -> str:
        return (f"node {self.node_id} (cable {self.cable}) {self.kind} 0x{self.code:04X}: "
                f"{self.text}")


class WinchDrives:
    """All winch drives of one CAN bus, vectorised over winches (see the module docstring).

    ``network`` is a connected :class:`canopen.Network`; ``winches`` the winch parameters
    (node ids, units, limits, bus timing); ``eds`` the drives' EDS file or object dictionary;
    ``bus_name`` how messages name the bus (default: the bus's channel info);
    ``tpdo_deadline_cycles``/``tpdo_deadline_min_s``: a drive is lost after this many SYNCs
    in a row without its TPDO, silent for at least this long [s, master clock];
    ``producer_priority``: the master heartbeat thread's ``SCHED_FIFO`` priority where the
    OS allows it (:func:`hal.rt_threads.raise_thread`; 0: normal scheduling).
    """

    def __init__(
        self,
        network: canopen.Network,
        winches: WinchSet,
        eds: str | Path | canopen.ObjectDictionary,
        clock: str | Callable[[], float] = "wall",
        own_network: bool = False,
        bus_name: str | None = None,
        tpdo_deadline_cycles: int = TPDO_DEADLINE_CYCLES,
        tpdo_deadline_min_s: float = TPDO_DEADLINE_MIN_S,
        producer_priority: int = 0,
    ) -> None:
        if tpdo_deadline_cycles < 1 or not tpdo_deadline_min_s >= 0:
            raise ValueError(f"tpdo_deadline_cycles {tpdo_deadline_cycles} must be >= 1 and "
                             f"tpdo_deadline_min_s {tpdo_deadline_min_s} >= 0")
        self.tpdo_deadline_cycles = int(tpdo_deadline_cycles)
        self.tpdo_deadline_min_s = float(tpdo_deadline_min_s)
        self.network = network
        self.winches = winches
        self.n = len(winches)
        self._own_network = own_network
        self.bus_name = bus_name or str(getattr(network.bus, "channel_info", None)
                                        or getattr(network.bus, "channel", "CAN bus"))
        self._add_nodes(network, winches, eds)
        self.period_s = winches.bus.sync_period_s
        self.hb_timeout_s = winches.bus.heartbeat_period_s * winches.bus.heartbeat_misses
        self._clock = self._pick_clock(clock)
        self.producer_priority = int(producer_priority)
        #: what the master heartbeat thread got (:func:`hal.rt_threads.raise_thread`)
        self.producer_scheduling = "not started"
        self._init_state(network)
        self._subscribe(network)

    def _add_nodes(self, network: canopen.Network, winches: WinchSet,
                   eds: str | Path | canopen.ObjectDictionary) -> None:
        """One canopen RemoteNode per winch, added to ``network``; the PDO layouts."""
        self.node_ids = [int(x) for x in winches.node_id]
        self.nodes: list[canopen.RemoteNode] = []
        for nid in self.node_ids:
            od = eds if isinstance(eds, canopen.ObjectDictionary) else load_eds(eds, nid)
            node = canopen.RemoteNode(nid, od)
            # SDOs run at start-up and in recovery only, never in the cycle: a patient
            # answer timeout costs nothing there and survives a busy host (canopen: 0.3 s)
            node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
            network.add_node(node)
            self.nodes.append(node)
        od0 = self.nodes[0].object_dictionary
        self._rpdo = pdo_struct(od0, RPDO_MAP)
        self._tpdo = pdo_struct(od0, TPDO_MAP)

    def _pick_clock(self, clock: str | Callable[[], float]) -> Callable[[], float]:
        """The master clock [s]: 'wall' (monotonic), 'sync' (SYNCs sent x period) or a callable."""
        self._wall_clock = clock == "wall"
        if clock == "wall":
            return time.monotonic
        if clock == "sync":
            return self._sync_clock
        if callable(clock):
            return clock
        raise ValueError(f"clock must be 'wall', 'sync' or a callable, got {clock!r}")

    def _init_state(self, network: canopen.Network) -> None:
        """The receive-side (notifier thread, under ``_rx``) and cycle-side state arrays."""
        n = self.n
        # receive side (written by the notifier thread under _rx)
        self._rx = threading.Condition()
        self._rx_sw = np.zeros(n, np.int64)
        self._rx_pos = np.zeros(n, np.int64)
        self._rx_count = np.zeros(n, np.int64)
        self._boot_count = np.zeros(n, np.int64)
        self._rx_hb_t = np.full(n, -np.inf)  # master clock of each drive's last heartbeat
        self._rx_hb_state = np.full(n, -1, np.int64)  # NMT state of the last one
        self._queue: deque[tuple] = deque()
        self._queue_overflow = np.zeros(n, np.int64)  # EMCYs not queued (flood)
        # cycle side
        self.cycle = 0
        self._syncs = 0
        self._seen = np.zeros(n, np.int64)
        self._expect = np.zeros(n, np.int64)
        self._sw = np.zeros(n, np.int64)
        self._pos = np.zeros(n, np.int64)
        self._have = np.zeros(n, bool)
        self._states = np.full(n, ST.UNKNOWN, np.int8)
        self._request = np.full(n, RQ.DISABLE, np.int8)
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
        self._syncs_seen = 0  # SYNCs sent at the last receive()
        self._no_one = np.zeros(n, bool)
        self._lost = np.zeros(n, bool)  # TPDOs overdue: drive_lost
        self._last_tpdo_t = np.zeros(n)  # master clock of the last TPDO (or of arming)
        self._foreign_until = np.full(n, -np.inf)  # foreign_master active until (clock)
        self._foreign_text = [""] * n
        self._foreign_bus_until = -np.inf
        self._foreign_bus_text = ""
        self._limit = np.zeros(n, bool)
        self._code = np.zeros(n, np.int64)  # last EMCY code (0 = none or reset)
        self._fault_code = np.zeros(n, np.int64)  # cause of the present Fault
        self._window: list[list[int]] = [[] for _ in range(n)]  # EMCYs since last not faulted
        # length of each window before this cycle's EMCYs: a drive's TPDO (sampled at the
        # last SYNC) may predate an EMCY of this cycle, so a statusword that still says "not
        # faulted" clears only the EMCYs that came before it
        self._window_mark = [0] * n
        self._self_stopped = np.zeros(n, bool)  # in Quick Stop Active, not by our request
        self._nmt_wait = np.full(n, -np.inf)  # ignore stale pre-op heartbeats until (clock)
        self._relink = np.zeros(n, bool)  # the link was lost since it was started
        self._events: deque[DriveEvent] = deque(maxlen=EVENTS_KEPT)
        self.events_dropped = 0  #: events that fell out of the history untaken
        self._bus_failing = False
        self._link_down = False
        self._link_epoch = getattr(network.bus, "link_epoch", 1)
        self._send_lock = network.send_lock
        self._sdo_lock = threading.Lock()  # one SDO transfer at a time (cycle never waits)
        self._jobs: queue.Queue[int | None] = queue.Queue()
        self._worker: threading.Thread | None = None
        self._mhb_stop = threading.Event()
        self._mhb_thread: threading.Thread | None = None
        self._mhb_wall = -np.inf  # wall time of the last master heartbeat sent
        self._mhb_clock = -np.inf  # master clock of the last one sent by the cycle
        self._mhb_gap_max = 0.0  # longest wall time between two master heartbeats [s]
        self._mhb_late = 0  # gaps longer than the drives' consumer time
        self._closed = False

    def _subscribe(self, network: canopen.Network) -> None:
        """Take each node's TPDO, heartbeat and EMCY from canopen; watch for another master."""
        self._subs: list[tuple[int, Callable]] = []
        for k, node in enumerate(self.nodes):
            # the master's own EMCY and heartbeat handling: bounded, and a malformed frame
            # is reported naming the node (canopen's would log every EMCY for ever)
            network.unsubscribe(0x80 + node.id, node.emcy.on_emcy)
            network.unsubscribe(0x700 + node.id, node.nmt.on_heartbeat)
            network.unsubscribe(0, node.nmt.on_command)  # the master sends NMT, not follows
            self._subs.append((0x180 + node.id, self._tpdo_cb(k)))
            self._subs.append((0x700 + node.id, self._heartbeat_cb(k)))
            self._subs.append((0x80 + node.id, self._emcy_cb(k)))
        for cob, cb in self._subs:
            network.subscribe(cob, cb)
        rpdo_cobs = {}
        for node in self.nodes:
            try:
                cob = int(node.object_dictionary[0x1400][1].default) & 0x7FF
            except (KeyError, TypeError, ValueError):
                cob = 0x200 + node.id
            rpdo_cobs[cob or 0x200 + node.id] = node.id
        #: frames only another master sends (see :mod:`hal.bus_watch`)
        self.foreign = ForeignFrameWatch(network, self.node_ids, rpdo_cobs)

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
        return cls(network, winches, eds, clock=clock, own_network=True, bus_name=f"--can {can}")

    def close(self) -> None:
        """Stop the master heartbeat and the SDO worker; unsubscribe; disconnect the network
        if :meth:`open` created it."""
        self._closed = True
        self._mhb_stop.set()
        if self._mhb_thread is not None:
            self._mhb_thread.join(timeout=2.0)
            self._mhb_thread = None
        if self._worker is not None:
            self._jobs.put(None)
            self._worker.join(timeout=2.0)
            self._worker = None
        for cob, cb in self._subs:
            if cb in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, cb)
        self._subs = []
        self.foreign.close()
        for node in self.nodes:
            if node.id in self.network:
                # canopen's own handlers back, so that it can remove them with the node
                self.network.subscribe(0x80 + node.id, node.emcy.on_emcy)
                self.network.subscribe(0x700 + node.id, node.nmt.on_heartbeat)
                self.network.subscribe(0, node.nmt.on_command)
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

    # ------------------------------------------------------------------ events

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

    def _send_nmt(self, k: int, command: int) -> None:
        self.network.send_message(0, bytes([command, self.node_ids[k]]))

    # ------------------------------------------------------------------ the link

    def link_up(self) -> bool:
        """The bus is usable (a socketcand link that is connected; other buses: always)."""
        return bool(getattr(self.network.bus, "link_up", True))

    def _link_why(self) -> str:
        why = getattr(self.network.bus, "link_error", "") or "link down"
        return f"{self.bus_name}: CAN link down ({why})"

    def _require_link(self, what: str) -> None:
        if not self.link_up():
            raise BusLinkError(f"{what}: {self._link_why()}")

    def _blocking(self, what: str, fn: Callable[[], object]) -> object:
        """Run a blocking operation; a bus that fails under it raises BusLinkError naming the
        bus (never a raw OSError / CanError)."""
        self._require_link(what)
        try:
            return fn()
        except (can.CanError, OSError) as exc:
            raise BusLinkError(f"{what}: {self.bus_name}: {type(exc).__name__}: {exc}") from exc
        except DriveConfigError as exc:
            if not self.link_up():
                raise BusLinkError(f"{what}: {self._link_why()}: {exc}") from exc
            raise

    def _check_link(self) -> None:
        """Per cycle: notice a lost or restored link (a reconnect counts as both)."""
        up = self.link_up()
        epoch = getattr(self.network.bus, "link_epoch", self._link_epoch)
        if (not up or epoch != self._link_epoch) and not self._link_down:
            self._link_down = True
            why = getattr(self.network.bus, "link_error", "") or "reconnected"
            self._bus_event(f"CAN link lost ({why}): drive states unknown", "link_lost")
            lost = self._started.copy()
            self._relink |= lost
            self._have[:] = False
            self._setpoint_ok[:] = False
            self._request[lost] = RQ.QUICK_STOP  # hold, should anything still listen
        if up and self._link_down:
            self._link_down = False
            self._bus_event("CAN link back: the drives stopped on their own (master lost); "
                            "recover() them, then enable()", "link_back", 0)
        self._link_epoch = epoch

    # ------------------------------------------------------------------ master heartbeat

    def _master_heartbeat(self) -> None:
        mid = self.winches.bus.master_node_id
        try:
            with self._send_lock:
                self.network.bus.send(can.Message(arbitration_id=0x700 + mid,
                                                  data=bytes([NMT_OPERATIONAL]),
                                                  is_extended_id=False))
        except (can.CanError, OSError):
            pass  # a dead link: the cycle reports it
        now = time.monotonic()
        gap = now - self._mhb_wall
        if gap < np.inf:
            self._mhb_gap_max = max(self._mhb_gap_max, gap)
            if gap > self.winches.bus.master_heartbeat_timeout_s > 0:
                self._mhb_late += 1
        self._mhb_wall = now

    def producer_stats(self) -> dict:
        """The master heartbeat producer so far: ``scheduling`` (what its thread got),
        ``gap_max_s`` (longest wall time between two heartbeats sent [s]), ``late`` (gaps
        longer than the drives' consumer time, ``master_heartbeat_timeout_s``: each one
        let the drives conclude that their master is gone)."""
        return {"scheduling": self.producer_scheduling,
                "gap_max_s": float(self._mhb_gap_max), "late": int(self._mhb_late)}

    def _producer_text(self) -> str:
        st = self.producer_stats()
        return (f"master heartbeat: longest gap {st['gap_max_s']:.3f} s, {st['late']} longer "
                f"than the drives' consumer time {self.winches.bus.master_heartbeat_timeout_s:g}"
                f" s; producer thread {st['scheduling']}")

    def set_producer_priority(self, priority: int) -> str:
        """The master heartbeat thread's SCHED_FIFO priority (0: normal scheduling, as it
        is); applied at once when it runs, else when :meth:`start` starts it. Returns
        :attr:`producer_scheduling`."""
        self.producer_priority = int(priority)
        t = self._mhb_thread
        if t is not None and t.native_id is not None and priority > 0:
            self.producer_scheduling = raise_thread(self.producer_priority, t.native_id)
        return self.producer_scheduling

    def _mhb_loop(self) -> None:
        self.producer_scheduling = raise_thread(self.producer_priority)
        period = self.winches.bus.master_heartbeat_period_s
        while not self._mhb_stop.wait(max(0.001, period - (time.monotonic() - self._mhb_wall))):
            if time.monotonic() - self._mhb_wall >= period - 1e-4:
                self._master_heartbeat()

    def _start_master_heartbeat(self) -> None:
        if self.winches.bus.master_heartbeat_period_s <= 0 or self._mhb_thread is not None:
            return
        self._mhb_stop.clear()
        self._master_heartbeat()
        self._mhb_thread = threading.Thread(target=self._mhb_loop, name="master-heartbeat",
                                            daemon=True)
        self._mhb_thread.start()

    def _cycle_heartbeat(self) -> None:
        """On a non-wall clock, also one heartbeat per period of that clock (the drives on
        the same clock then hear it at the period, however fast the cycles run)."""
        period = self.winches.bus.master_heartbeat_period_s
        if self._wall_clock or period <= 0 or self._mhb_thread is None:
            return
        now = self._clock()
        if now - self._mhb_clock >= period - 1e-9:
            self._mhb_clock = now
            self._master_heartbeat()

    # ------------------------------------------------------------------ fault codes (SDO)

    def _confirm_fault_code(self, k: int) -> None:
        """Read 0x603F of drive ``k`` in the background (the cycle never waits for SDO)."""
        if self._worker is None:
            self._worker = threading.Thread(target=self._work, name="drive-sdo", daemon=True)
            self._worker.start()
        self._jobs.put(k)

    def _work(self) -> None:
        while True:
            k = self._jobs.get()
            if k is None or self._closed:
                return
            try:
                with self._sdo_lock:
                    code = int(sdo_read(self.nodes[k], 0x603F, 0, self.who(k)))
                self._queue.append(("603f", k, code, ""))
            except (DriveConfigError, can.CanError, OSError) as exc:
                self._queue.append(("603f", k, None, str(exc)))

    def _fault_code_read(self, k: int, code: int | None, err: str) -> None:
        if not faulted(self._states[k:k + 1])[0]:
            return  # reset meanwhile
        if code is None:
            self._event(k, "sdo_error", 0, f"reading 0x603F error code: {err}")
            return
        if code != self._fault_code[k]:
            old = int(self._fault_code[k])
            self._fault_code[k] = code
            said = f"0x{old:04X}" if old else "no EMCY"
            self._event(k, "fault_code", code, f"0x603F error code 0x{code:04X} "
                        f"({emcy_text(code)}); the fault came with {said}")

    # ------------------------------------------------------------------ start-up (blocking)

    def start(self, timeout: float = 3.0, nodes: Iterable[int] | None = None) -> None:
        """Bring drives to NMT OPERATIONAL with the CSP configuration (blocking; SDO).

        NMT reset communication, wait for each boot-up, check identity against the EDS,
        write and verify the configuration (master-loss monitoring included), read
        statusword and position, NMT start; the master heartbeat runs from here on.
        ``nodes`` are array indices (default: all). Raises DriveStartupError or
        DriveConfigError naming the node, BusLinkError naming the bus.
        """
        if nodes is None:
            for problem in holding_problems(self.winches):
                log.warning("%s", problem)
        self._blocking("start", lambda: self._start(timeout, nodes))

    def _start(self, timeout: float, nodes: Iterable[int] | None) -> None:
        ks = list(range(self.n)) if nodes is None else list(nodes)
        self._start_master_heartbeat()
        before = self._boot_count.copy()
        for k in ks:
            self._send_nmt(k, 0x82)  # reset communication
        self._wait_bootups(ks, before, timeout)
        with self._sdo_lock:
            for k in ks:
                node = self.nodes[k]
                who = self.who(k)
                verify_identity(node, who)
                configure_node(node, drive_settings(self.winches, k, node.object_dictionary),
                               who)
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
        self._link_down = False
        self._link_epoch = getattr(self.network.bus, "link_epoch", self._link_epoch)
        states = decode_states(self._sw, self._have)
        for k in ks:
            self._send_nmt(k, 0x01)  # start remote node
            self._started[k] = True
            self._armed[k] = False
            self._rebooted[k] = False
            self._relink[k] = False
            self._hb_lost[k] = False
            self._hb_last[k] = now
            self._rx_hb_t[k] = max(self._rx_hb_t[k], now)
            self._rx_hb_state[k] = -1  # the next heartbeat tells the state
            self._nmt[k] = NMT_OPERATIONAL
            self._nmt_wait[k] = now + max(self.hb_timeout_s, self.period_s)
            self._miss_streak[k] = 0
            self._lost[k] = False
            self._last_tpdo_t[k] = now
            # a drive holding in Quick Stop Active (it lost its master) keeps holding
            held = states[k] == ST.QUICK_STOP_ACTIVE
            self._request[k] = RQ.QUICK_STOP if held else RQ.DISABLE
            self._self_stopped[k] = held
            self._setpoint_ok[k] = False
        self._states = states
        for k in ks:
            if faulted(self._states[k:k + 1])[0]:
                if not self._window[k]:  # its EMCY may have gone out before we listened
                    with self._sdo_lock:
                        self._fault_code[k] = int(sdo_read(self.nodes[k], 0x603F, 0,
                                                           self.who(k)))
                else:
                    self._fault_code[k] = self._cause(k)
                code = int(self._fault_code[k])
                text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
                self._event(k, "fault", code, f"in {DriveState(self._states[k]).name} at "
                            f"start-up: {text}")

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

    def _needs_recovery(self) -> np.ndarray:
        return self._rebooted | self._relink | self._hb_lost | (
            self._started & ~np.isin(self._nmt, (NMT_OPERATIONAL, -1)))

    def recover(self, timeout: float = 3.0) -> list[int]:
        """Restart drives that rebooted, went silent and are back, or were behind a lost
        link (blocking; SDO). Returns the node ids restarted. They come back disabled, or
        holding in Quick Stop Active if they stopped on their own: call :meth:`enable`.
        BusLinkError while the link is down.
        """
        self._require_link("recover")
        self._check_link()
        self._drain()
        ks = [int(k) for k in np.flatnonzero(self._needs_recovery())]
        if not ks:
            return []
        self._blocking("recover", lambda: self._start(timeout, ks))
        for k in ks:
            self._event(k, "recovered", 0, "reconfigured and started")
        return [self.node_ids[k] for k in ks]

    def read_fault_codes(self) -> dict[int, int]:
        """Read 0x603F error code of drives in Fault by SDO (blocking). {node id: code}."""

        def read() -> dict[int, int]:
            out = {}
            for k in np.flatnonzero(faulted(self._states)):
                with self._sdo_lock:
                    code = int(sdo_read(self.nodes[k], 0x603F, 0, self.who(k)))
                self._fault_code[k] = code
                out[self.node_ids[k]] = code
            return out

        return self._blocking("read_fault_codes", read)

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
        self._request[self._mask(nodes)] = RQ.ENABLE

    def disable(self, nodes: Iterable[int] | None = None) -> None:
        """Request Ready To Switch On: power stage off, brakes hold."""
        self._request[self._mask(nodes)] = RQ.DISABLE

    def off(self, nodes: Iterable[int] | None = None) -> None:
        """Request Switch On Disabled (disable voltage)."""
        self._request[self._mask(nodes)] = RQ.OFF

    def quick_stop(self, nodes: Iterable[int] | None = None) -> None:
        """Request a quick stop (each drive stops on its 0x605A ramp). Never raises (a
        supervisor's reaction): on a dead link an event says it cannot reach the drives,
        which stop on their own (consumer heartbeat, 0x6007)."""
        self._request[self._mask(nodes)] = RQ.QUICK_STOP
        if not self.link_up():
            self._bus_event(f"quick stop requested but {self._link_why()}: the drives stop "
                            "on their own when they miss the master's heartbeat", "link_lost")

    def fault_reset(self, nodes: Iterable[int] | None = None, hold_cycles: int = 20) -> None:
        """Reset faulted drives with a rising edge of controlword bit 7 (over the next cycles).
        They come back disabled, never enabled: that takes :meth:`enable`. Raises
        BusLinkError on a dead link (an operator's action: it cannot be done)."""
        self._require_link("fault_reset")
        m = self._mask(nodes) & faulted(self._states)
        self._reset_left[m] = hold_cycles
        self._request[m] = RQ.DISABLE

    def set_lengths(self, lengths_m: np.ndarray) -> None:
        """Cable length setpoints [m], shape (n,), sent with the next :meth:`exchange`.

        Raises ValueError (nothing is changed) for a non-finite value or one outside the
        winch's [min_length_m, max_length_m]. Drives not enabled keep their position.
        """
        x = np.asarray(lengths_m, dtype=float)
        if x.shape != (self.n,):
            raise ValueError(f"set_lengths: expected shape ({self.n},), got {x.shape}")
        bad = ~np.isfinite(x) | (x < self.winches.min_length_m) | (x > self.winches.max_length_m)
        if np.count_nonzero(bad):
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
        """Drives that owe a TPDO per SYNC (started by us, operational as far as we know,
        not lost)."""
        op = (self._nmt == NMT_OPERATIONAL) | (self._nmt == -1)
        return (self._started & self._armed & ~self._rebooted & ~self._hb_lost & ~self._relink
                & ~self._lost & op)

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
        self._window_mark = [len(w) for w in self._window]
        self._drain()
        self._check_link()
        with self._rx:
            counts = self._rx_count.copy()
            sw = self._rx_sw.copy()
            pos = self._rx_pos.copy()
        fresh = counts > self._seen
        n_new = counts - self._seen
        self._seen = counts
        # an answer is owed per SYNC sent since the last receive (none: nothing is missing)
        expected = self._expected() if self._syncs != self._syncs_seen else self._no_one
        self._syncs_seen = self._syncs
        self._check_pdos(fresh, n_new, expected)
        self._sw = np.where(fresh, sw, self._sw)
        self._pos = np.where(fresh, pos, self._pos)
        # a node its heartbeat says is outside OPERATIONAL sends no PDO: a TPDO counted now
        # was sent before it left (its statusword is old news)
        out_of_op = (self._nmt != NMT_OPERATIONAL) & (self._nmt != -1)
        self._heartbeats_back()
        # the state is known only from fresh feedback of a node that is not lost: while its
        # heartbeat is lost it is UNKNOWN every cycle, whatever TPDOs still come (the node
        # needs recover() or its heartbeat back); a drive_lost node has no fresh TPDO
        self._have |= fresh & ~self._relink & ~out_of_op & ~self._hb_lost
        self._nmt_wait[fresh] = -np.inf  # PDOs only flow in OPERATIONAL
        self._check_feedback(fresh, expected)
        self._update_states(expected)
        self._check_heartbeats()
        self._check_foreign()

    def _check_feedback(self, fresh: np.ndarray, expected: np.ndarray) -> None:
        """TPDO deadline: a drive silent for the deadline is lost (state unknown, asked to
        quick stop); its TPDOs back end it."""
        now = self._clock()
        if np.count_nonzero(fresh):
            self._last_tpdo_t[fresh] = now
        back = self._lost & fresh
        for k in np.flatnonzero(back) if np.count_nonzero(back) else ():
            self._lost[k] = False
            self._event(k, "tpdo_resumed", CODE_PDO_TIMEOUT, "TPDOs back: state known again")
        if not np.count_nonzero(self._miss_streak):
            return
        lost = feedback_lost(np.where(expected, self._miss_streak, 0), now - self._last_tpdo_t,
                             self.tpdo_deadline_cycles, self.tpdo_deadline_min_s)
        for k in np.flatnonzero(lost) if np.count_nonzero(lost) else ():
            self._lost[k] = True
            self._have[k] = False  # its state is unknown now, never its last live one
            self._setpoint_ok[k] = False
            self._request[k] = RQ.QUICK_STOP  # hold, if it still hears us
            self._event(k, DRIVE_LOST, CODE_PDO_TIMEOUT, self._lost_text(k, now))

    def _lost_text(self, k: int, now: float) -> str:
        return (f"no TPDO for {self._miss_streak[k]} SYNCs ({now - self._last_tpdo_t[k]:.3f} "
                f"s; deadline {self.tpdo_deadline_cycles} SYNCs and "
                f"{self.tpdo_deadline_min_s:.3f} s): state unknown")

    def _check_foreign(self) -> None:
        """Frames another master sent (queued by :attr:`foreign`): an event when the
        condition starts, a fault while it lasts."""
        frames = self.foreign.take()
        if not frames:
            return
        now = self._clock()
        for f in frames:
            if f.node_id in self.node_ids:
                k = self.node_ids.index(f.node_id)
                if now > self._foreign_until[k]:
                    self._event(k, FOREIGN_MASTER, 0, f"{f.text} (another master on the bus)")
                self._foreign_until[k] = now + FOREIGN_HOLD_S
                self._foreign_text[k] = f.text
            else:
                if now > self._foreign_bus_until:
                    self._bus_event(f"{f.text} (another master on the bus)", FOREIGN_MASTER, 0)
                self._foreign_bus_until = now + FOREIGN_HOLD_S
                self._foreign_bus_text = f.text

    def transmit(self) -> None:
        """Second half of a cycle: state machine requests, RPDOs (setpoints) + SYNC out.
        Never blocks."""
        self._send_outputs()
        self._cycle_heartbeat()
        self.cycle += 1

    def _check_pdos(self, fresh: np.ndarray, n_new: np.ndarray, expected: np.ndarray) -> None:
        if (np.count_nonzero(fresh) == fresh.size and not np.count_nonzero(self._miss_streak)
                and not np.count_nonzero(n_new > 1)):
            return  # every drive answered once, none was missing: nothing to report
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

    def _cause(self, k: int) -> int:
        """The EMCY that came with drive ``k``'s transition to Fault: of the EMCYs since it
        was last seen not faulted, the first that is not a communication warning (0x81xx,
        0x82xx), else the first; 0 if none came."""
        codes = self._window[k]
        for code in codes:
            if code >> 8 not in (0x81, 0x82):
                return code
        return codes[0] if codes else 0

    def _update_states(self, expected: np.ndarray) -> None:
        old = self._states
        new = decode_states(self._sw, self._have)
        was_fault = faulted(old)
        now_fault = faulted(new)
        any_fault = bool(np.count_nonzero(was_fault) or np.count_nonzero(now_fault))
        for k in np.flatnonzero(now_fault & ~was_fault) if any_fault else ():
            code = self._cause(k)
            self._fault_code[k] = code
            text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
            self._event(k, "fault", code, f"{DriveState(new[k]).name}: {text}")
            self._request[k] = RQ.DISABLE
            self._confirm_fault_code(int(k))
        cleared = ~now_fault & was_fault & (new != ST.UNKNOWN) if any_fault else ()
        for k in np.flatnonzero(cleared) if any_fault else ():
            self._event(k, "fault_cleared", 0, f"now {DriveState(new[k]).name}")
            self._fault_code[k] = 0
        known_ok = ~now_fault & (new != ST.UNKNOWN)
        for k in np.flatnonzero(known_ok) if any(self._window_mark) else ():
            del self._window[k][:self._window_mark[k]]
        # a drive that quick-stopped on its own (master lost, 0x6007) holds there until the
        # controller enables it again: the master never re-enables it by itself
        qs = new == ST.QUICK_STOP_ACTIVE
        for k in np.flatnonzero(qs & (old != ST.QUICK_STOP_ACTIVE)
                                & (self._request != RQ.QUICK_STOP)) if np.count_nonzero(qs) else ():
            self._self_stopped[k] = True
            self._request[k] = RQ.QUICK_STOP
            code = next((c for c in reversed(self._window[k]) if c), int(self._code[k]))
            why = emcy_text(code) if code else "no EMCY"
            self._event(k, "quick_stop", code, f"the drive stopped on its own ({why}): held in "
                        "Quick Stop Active until enable()")
        self._self_stopped &= qs | (new == ST.UNKNOWN)
        self._drop_enable(old, new)
        oe = new == ST.OPERATION_ENABLED
        entering = oe & ~self._setpoint_ok
        self._target[entering] = self._pos[entering]  # hold where it stands
        self._setpoint_ok = oe
        limit = oe & ((self._sw & SW_INTERNAL_LIMIT) != 0)
        for k in np.flatnonzero(limit & ~self._limit) if np.count_nonzero(limit) else ():
            self._event(k, "internal_limit", 0, "software position limit reached (bit 11)")
        self._limit = limit
        self._states = new

    def _drop_enable(self, old: np.ndarray, new: np.ndarray) -> None:
        """A drive asked to be enabled that went back along the enable path (Operation
        Enabled -> Switched On -> Ready To Switch On -> Switch On Disabled) without the master
        asking: switched off by another master (an SDO write of 0x6040) or by itself. The
        master stops asking (never enables it again by itself, until :meth:`enable`) and
        leaves it where it is: an event ``switched_off``."""
        back = (self._request == RQ.ENABLE) & (_ENABLE_RANK[new] >= 0) & (
            _ENABLE_RANK[new] < _ENABLE_RANK[old])
        for k in np.flatnonzero(back) if np.count_nonzero(back) else ():
            off = new[k] in (ST.SWITCH_ON_DISABLED, ST.NOT_READY_TO_SWITCH_ON)
            self._request[k] = RQ.OFF if off else RQ.DISABLE
            self._event(k, "switched_off", 0, f"{DriveState(old[k]).name} -> "
                        f"{DriveState(new[k]).name} without the master asking (another master? "
                        "the drive itself?): not enabled again until enable()")

    def _heartbeats_back(self) -> None:
        """Heartbeats of lost nodes that came again (``heartbeat_resumed``): their TPDOs of
        this cycle give their state again."""
        if self.hb_timeout_s <= 0 or self._link_down:
            return
        now = self._clock()
        self._hb_last = np.maximum(self._hb_last, self._rx_hb_t)
        back = self._hb_lost & (now - self._hb_last <= self.hb_timeout_s + 1e-9)
        for k in np.flatnonzero(back) if np.count_nonzero(back) else ():
            self._hb_lost[k] = False
            self._event(k, "heartbeat_resumed", CODE_HEARTBEAT, "heartbeat back")

    def _check_heartbeats(self) -> None:
        """Nodes silent beyond the heartbeat timeout: ``heartbeat_lost``, state UNKNOWN from
        this cycle on until the heartbeat is back (or :meth:`recover`)."""
        if self.hb_timeout_s <= 0 or self._link_down:
            return
        now = self._clock()
        self._hb_last = np.maximum(self._hb_last, self._rx_hb_t)
        watched = self._started & ~self._rebooted & ~self._relink
        lost = watched & ~self._hb_lost & (now - self._hb_last > self.hb_timeout_s + 1e-9)
        for k in np.flatnonzero(lost) if np.count_nonzero(lost) else ():
            self._hb_lost[k] = True
            self._have[k] = False  # its state is unknown now
            self._states[k] = ST.UNKNOWN
            self._setpoint_ok[k] = False
            self._request[k] = RQ.QUICK_STOP  # hold, if it still hears us
            self._event(k, "heartbeat_lost", CODE_HEARTBEAT,
                        f"no heartbeat for {now - self._hb_last[k]:.3f} s "
                        f"(> {self.winches.bus.heartbeat_misses} periods)")

    def _send_outputs(self) -> None:
        states = self._states
        cw = controlwords(states, self._request).astype(np.int64)
        # fault reset: bit 7 low for one cycle, then high while the drive is in Fault
        resetting = self._reset_left > 0
        if np.count_nonzero(resetting):
            cw = np.where(resetting & ((self._last_cw & CW_FAULT_RESET) == 0) & faulted(states),
                          CW_FAULT_RESET, cw)
            hold = resetting & ((self._last_cw & CW_FAULT_RESET) != 0) & faulted(states)
            cw = np.where(hold, CW_FAULT_RESET, cw)
            done = resetting & ~faulted(states)
            self._reset_left[done] = 0
            self._reset_left[resetting & ~done] -= 1
            for k in np.flatnonzero(resetting & ~done & (self._reset_left == 0)):
                self._event(k, "fault_reset_failed", int(self._fault_code[k]),
                            "still in Fault after the reset edge (cause persists?)")
        # a drive not enabled, or being enabled now, gets its actual position as target
        going = enabling(states, cw)
        target = np.where(self._setpoint_ok & ~going, self._target, self._pos)
        self._target = target
        self._last_cw = cw
        send = self._started & ~self._rebooted & ~self._relink
        if self._link_down or not self.link_up():
            self._syncs += 1  # the cycle happened; nothing can go out (see _check_link)
            return
        pack = self._rpdo.pack
        cws, targets, ids = cw.tolist(), target.tolist(), self.node_ids  # plain ints
        rpdos = [can.Message(arbitration_id=0x200 + ids[k], data=pack(cws[k], targets[k]),
                             is_extended_id=False) for k in np.flatnonzero(send).tolist()]
        sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        bus = self.network.bus
        try:
            with self._send_lock:
                if hasattr(bus, "send_batch"):  # one write: nothing can answer in between
                    with self._rx:
                        self._expect = self._rx_count.copy()
                    send_frames(bus, rpdos + [sync])
                else:  # answers to the RPDOs (delivered at once in lock-step) come first
                    send_frames(bus, rpdos)
                    with self._rx:
                        self._expect = self._rx_count.copy()
                    bus.send(sync)
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

    def wait_feedback(self, timeout: float = 0.5, missing_timeout: float | None = None
                      ) -> bool:
        """Wait until every expected drive answered the last SYNC (lock-step; blocks at most
        ``timeout`` [s, wall], or ``missing_timeout`` when every drive not yet answered
        missed the SYNC before too: default :data:`MISSING_WAIT_S`, one SYNC period on the
        wall clock). A miss counts towards the TPDO deadline, after which the drive is lost
        and no longer waited for: the cycles go on at the master's pace."""
        if missing_timeout is None:
            missing_timeout = self.period_s if self._wall_clock else MISSING_WAIT_S
        mask = self._expected()
        if not np.count_nonzero(mask):
            return True
        missed_before = self._miss_streak != 0
        deadline = time.monotonic() + timeout
        short = False  # the short bound is set
        with self._rx:
            while True:
                pending = mask & (self._rx_count <= self._expect)
                if not np.count_nonzero(pending):
                    return True
                if not short and not np.count_nonzero(pending & ~missed_before):
                    # only drives that missed the SYNC before: a short wait more
                    deadline = min(deadline, time.monotonic() + missing_timeout)
                    short = True
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

    def enable_and_wait(self, max_cycles: int = 50, restart_tries: int = 0) -> None:
        """Enable all drives and cycle until they are Operation Enabled (blocks).

        Fails at once (nothing is sent) with BusLinkError when the link is down, and with
        DriveStartupError naming the drives that need :meth:`recover` first (reset, silent,
        behind a lost link) or whose state is unknown. ``restart_tries`` > 0 (start-up,
        before anything moved): such drives are restarted first, as a CANopen master
        restarts a slave after an error control event (:meth:`restart_for_enable`)."""
        self._require_link("enable")
        self._drain()
        self._check_link()
        if self._link_down:
            raise BusLinkError(f"enable: {self._link_why()}")
        if restart_tries > 0:
            self.restart_for_enable(restart_tries)
        bad = [f"{self.who(k)}: {self._why_not_ready(k)}" for k in range(self.n)
               if self._why_not_ready(k)]
        if bad:
            raise DriveStartupError(f"enable refused: {'; '.join(bad)} ({self._producer_text()})")
        self.enable()
        ok = self._blocking("enable", lambda: self.run_until(
            lambda d: bool(np.all(d.states() == ST.OPERATION_ENABLED) or d._lost.any()),
            max_cycles))
        if self._lost.any():
            ks = np.flatnonzero(self._lost)
            # the others: no pending enable; those already enabled quick-stop
            oe = self._states == ST.OPERATION_ENABLED
            self._request[~self._lost & ~oe & (self._request == RQ.ENABLE)] = RQ.DISABLE
            self._request[~self._lost & oe] = RQ.QUICK_STOP
            raise DriveLostError(
                f"{DRIVE_LOST} while enabling: " + "; ".join(
                    f"{self.who(k)}: {self._lost_text(k, self._clock())}" for k in ks),
                tuple(self.node_ids[k] for k in ks))
        if not ok:
            bad = [f"{self.who(k)}: {DriveState(s).name}" for k, s in enumerate(self._states)
                   if s != ST.OPERATION_ENABLED]
            # the drives that did not come keep no pending enable: a later fault reset or
            # recovery must not enable them behind the controller's back
            late = self._states != ST.OPERATION_ENABLED
            held = late & (self._states == ST.QUICK_STOP_ACTIVE)
            self._request[late & ~held] = RQ.DISABLE
            self._request[held] = RQ.QUICK_STOP
            if not self.link_up():
                raise BusLinkError(f"enable: {self._link_why()}")
            raise DriveStartupError(
                f"not Operation Enabled after {max_cycles} cycles: {'; '.join(bad)}")

    def restart_for_enable(self, tries: int = NMT_START_TRIES, timeout: float = 3.0
                           ) -> list[int]:
        """Restart the drives that are not ready to be enabled because they left NMT
        OPERATIONAL, were reset or lost their heartbeat (e.g. their consumer heartbeat
        expired while the host starved the master's producer) - at start-up, before
        anything moved (blocking; SDO). Each try is :meth:`recover` (NMT reset, boot-up,
        configuration, NMT start) and then waits up to :meth:`confirm_window_s` for their
        heartbeats to say OPERATIONAL; at most ``tries`` tries. An event ``nmt_restart``
        per drive and try. Returns the node ids restarted; raises DriveStartupError naming
        each node, its NMT state and the master heartbeat's record when the last try
        leaves some not OPERATIONAL."""
        t0 = time.monotonic()
        done: list[int] = []
        left: list[int] = []
        for attempt in range(1, tries + 1):
            self._drain()
            left = [int(k) for k in np.flatnonzero(self._needs_recovery() & self._started)]
            if not left:
                return done
            for k in left:
                why = self._why_not_ready(k).split(": recover()")[0] or "not OPERATIONAL"
                self._event(k, "nmt_restart", CODE_HEARTBEAT, f"{why} before enabling: "
                            f"restart {attempt} of {tries} ({self._producer_text()})")
            done += [self.node_ids[k] for k in left if self.node_ids[k] not in done]
            self.recover(timeout)
            left = self._confirm_operational(left)
            if not left:
                return done
        raise DriveStartupError("not NMT OPERATIONAL after " f"{tries} restarts in "
                                f"{time.monotonic() - t0:.1f} s: " + "; ".join(
                                    f"{self.who(k)}: NMT {self._nmt_name(k)}" for k in left)
                                + f" ({self._producer_text()})")

    def confirm_window_s(self) -> float:
        """How long [s, wall] :meth:`restart_for_enable` waits for a restarted drive's
        heartbeat: two of its heartbeat periods and the master's consumer time."""
        bus = self.winches.bus
        return 2.0 * bus.heartbeat_period_s + bus.master_heartbeat_timeout_s

    def _confirm_operational(self, ks: list[int]) -> list[int]:
        """Of drives ``ks`` just NMT-started, those whose heartbeat did not say OPERATIONAL
        within :meth:`confirm_window_s` (none when the drives send no heartbeat)."""
        if self.winches.bus.heartbeat_period_s <= 0:
            return []
        deadline = time.monotonic() + self.confirm_window_s()
        while True:
            left = [k for k in ks if self._rx_hb_state[k] != NMT_OPERATIONAL]
            if not left or time.monotonic() >= deadline:
                break
            time.sleep(min(0.01, max(0.0, deadline - time.monotonic())))
        for k in left:  # what it said last (-1: nothing since the NMT start)
            state = int(self._rx_hb_state[k])
            if state >= 0:
                self._nmt[k] = state
        return left

    def _nmt_name(self, k: int) -> str:
        state = int(self._nmt[k]) if self._rx_hb_state[k] < 0 else int(self._rx_hb_state[k])
        return NMT_NAMES.get(state, f"unknown (no heartbeat within "
                             f"{self.confirm_window_s():.2f} s)" if state < 0 else hex(state))

    def _why_not_ready(self, k: int) -> str:
        if not self._started[k]:
            return "not started (start() first)"
        if self._relink[k]:
            return "behind a lost CAN link: recover() it first"
        if self._rebooted[k]:
            return "was reset (boot-up): recover() it first"
        if self._hb_lost[k]:
            return "heartbeat lost: recover() it once it is back"
        if self._lost[k]:
            return "TPDOs lost (drive_lost): its state is unknown"
        if self._nmt[k] not in (NMT_OPERATIONAL, -1):
            return f"NMT {NMT_NAMES.get(int(self._nmt[k]), '?')}: recover() it first"
        return ""

    def shutdown(self, max_cycles: int = 20) -> None:
        """Disable voltage on all drives (cycling until Switch On Disabled), then NMT pre-op.
        BusLinkError (after marking the drives stopped) when the link is down."""
        try:
            self._require_link("shutdown")

            def off() -> None:
                self.off()
                self.run_until(lambda d: bool(np.all(d.states() != ST.OPERATION_ENABLED)),
                               max_cycles)
                for k in range(self.n):
                    if self._started[k]:
                        self._send_nmt(k, 0x80)

            self._blocking("shutdown", off)
        finally:
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

    def feedback_age(self) -> np.ndarray:
        """Per drive, the SYNCs in a row without its TPDO at the last :meth:`receive` (0: its
        position answers the latest SYNC it could), shape (n,)."""
        return self._miss_streak.copy()

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
        """Active faults (drive Fault, quick stop of its own, heartbeat lost, node reset,
        wrong NMT state, link lost)."""
        out: list[DriveFault] = []
        nmt_bad = self._started & (self._nmt != NMT_OPERATIONAL) & (self._nmt != -1)
        now = self._clock()
        foreign = self._foreign_until >= now
        anything = (self._relink | faulted(self._states) | self._self_stopped | self._hb_lost
                    | self._rebooted | nmt_bad | self._lost | foreign)
        if self._foreign_bus_until >= now:
            out.append(DriveFault(0, "-", FOREIGN_MASTER, 0, f"{self.bus_name}: "
                                  f"{self._foreign_bus_text} (another master on the bus)"))
        if not np.count_nonzero(anything):
            return out  # none of the conditions below holds for any drive
        for k in range(self.n):
            nid, cable = self.node_ids[k], self.winches.cables[k]
            if self._relink[k]:
                out.append(DriveFault(nid, cable, "link_lost", CODE_BUS,
                                      f"{self._link_why() if self._link_down else self.bus_name}"
                                      ": state unknown; recover() it when the link is back"))
                continue
            if faulted(self._states[k:k + 1])[0]:
                code = int(self._fault_code[k])
                text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
                out.append(DriveFault(nid, cable, "drive_fault", code, text))
            if self._self_stopped[k]:
                code = int(self._code[k]) if self._code[k] else 0
                out.append(DriveFault(nid, cable, "quick_stop", code, "stopped on its own "
                                      "(master lost?), holding in Quick Stop Active"))
            if self._hb_lost[k]:
                out.append(DriveFault(nid, cable, "heartbeat_lost", CODE_HEARTBEAT,
                                      "heartbeat lost"))
            if self._lost[k]:
                out.append(DriveFault(nid, cable, DRIVE_LOST, CODE_PDO_TIMEOUT,
                                      f"TPDOs lost: {self._lost_text(k, now)}"))
            if foreign[k]:
                out.append(DriveFault(nid, cable, FOREIGN_MASTER, 0, f"{self._foreign_text[k]} "
                                      "(another master on the bus)"))
            if self._rebooted[k]:
                out.append(DriveFault(nid, cable, "boot_up", CODE_HEARTBEAT,
                                      "node was reset (boot-up); recover() it"))
            elif self._started[k] and self._nmt[k] not in (NMT_OPERATIONAL, -1) \
                    and not self._hb_lost[k]:
                out.append(DriveFault(nid, cable, "nmt_state", CODE_HEARTBEAT,
                                      f"NMT {NMT_NAMES.get(int(self._nmt[k]), '?')}"))
        return out


__all__ = [
    "BusLinkError",
    "DriveConfigError",
    "DriveEvent",
    "DriveFault",
    "DriveLostError",
    "DriveStartupError",
    "NMT_START_TRIES",
    "DriveState",
    "WinchDrives",
]
