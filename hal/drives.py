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
own, per 0x6007, when it is gone. Its thread runs in ``SCHED_FIFO`` at ``producer_priority``
where the OS allows it (:mod:`hal.rt_threads`; :meth:`set_producer_priority`), and
:meth:`producer_stats` says its longest gap and how many gaps exceeded the drives'
consumer time. At start-up, drives that left NMT OPERATIONAL before the first enable (a
consumer heartbeat that expired on a busy host) are restarted a bounded number of times by
``enable_and_wait(restart_tries=...)`` (:meth:`restart_for_enable`).

Memory stays bounded whatever the drives send: EMCYs are not logged by canopen
(``node.emcy.log`` stays empty), the event history keeps the last ``EVENTS_KEPT`` events.

Clock: ``clock="wall"`` (time.monotonic) for real drives, ``clock="sync"`` (number of SYNCs
sent x SYNC period) with a rig on the deterministic simulated clock, or any callable.

A CAN log of the bus is replayed through the same code by :class:`hal.drives_replay.ReplayDrives`.

Parts (one object, its state set by ``__init__`` here; the parts by concern):
:mod:`hal.drives_base` (constants, errors, event and fault records),
:mod:`hal.drives_rx` (receive callbacks, event queue and history),
:mod:`hal.drives_nmt` (link, master heartbeat, start-up, recovery, fault-code SDO),
:mod:`hal.drives_cycle` (the cycle: detection, CiA 402 states, RPDOs + SYNC; lock-step,
enabling, shutdown); this module: construction, requests, readings.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path

import canopen
import numpy as np

from controller.winch import WinchSet, counts_to_m, m_to_counts
from hal import drives_base
from hal.bus_watch import (
    DRIVE_LOST,
    FOREIGN_MASTER,
    TPDO_DEADLINE_CYCLES,
    TPDO_DEADLINE_MIN_S,
    ForeignFrameWatch,
)
from hal.can_bus import CanSpec, open_bus
from hal.drives_base import *  # noqa: F403  (its public names, re-exported: __all__ below)
from hal.drives_base import (
    CODE_BUS,
    CODE_HEARTBEAT,
    CODE_PDO_TIMEOUT,
    EVENTS_KEPT,
    NMT_NAMES,
    NMT_OPERATIONAL,
    SDO_TIMEOUT_S,
    DriveEvent,
    DriveFault,
)
from hal.drives_cia402 import (
    RQ,
    ST,
    DriveState,
    emcy_text,
    faulted,
)
from hal.drives_config import (
    RPDO_MAP,
    TPDO_MAP,
    DriveConfigError,
    load_eds,
    pdo_struct,
)
from hal.drives_cycle import CycleMixin
from hal.drives_nmt import NmtMixin
from hal.drives_rx import ReceiveMixin
from hal.rt_threads import check_priority
from hal.sync_count import CountAlignment, SyncHistory, count_window


class WinchDrives(CycleMixin, NmtMixin, ReceiveMixin):
    """All winch drives of one CAN bus, vectorised over winches (see the module docstring).

    ``network`` is a connected :class:`canopen.Network`; ``winches`` the winch parameters
    (node ids, units, limits, bus timing); ``eds`` the drives' EDS file or object dictionary;
    ``bus_name`` how messages name the bus (default: the bus's channel info);
    ``tpdo_deadline_cycles``/``tpdo_deadline_min_s``: a drive is lost after this many SYNCs
    in a row without its TPDO, silent for at least this long [s, master clock];
    ``producer_priority``: the master heartbeat thread's ``SCHED_FIFO`` priority where the
    OS allows it (:func:`hal.rt_threads.raise_thread`; 0: normal scheduling).
    """

    # ------------------------------------------------------ construction

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
        self.producer_priority = check_priority(producer_priority)  # ValueError: range
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
        self._sync_clocked = False  # the clock counts SYNCs (it moves as one is sent)
        if clock == "wall":
            return time.monotonic
        if clock == "sync":
            self._sync_clocked = True
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
        self._sync_t = np.nan  # master clock of the last SYNC sent [s]
        self._rx_sync_t = np.full(n, np.nan)  # ... before each drive's latest TPDO came
        #: the SYNCs sent (number, time.time() as each went: the frames' clock; master
        #: clock), and per drive which SYNC its TPDOs answer (:mod:`hal.sync_count`)
        window = count_window(self.period_s)
        self._sync_sent = SyncHistory(2 * window + self.tpdo_deadline_cycles)
        self._align = [CountAlignment(window) for _ in range(n)]
        #: each drive's last positions and the SYNCs they answer (receive side, under _rx),
        #: for a sample of all the drives at one SYNC (:func:`hal.sync_count.common_sample`):
        #: as many as the TPDO deadline spans (a drive silent longer is lost, not waited for)
        self._deadline_s = max(self.tpdo_deadline_cycles * self.period_s,
                               self.tpdo_deadline_min_s)
        kept = int(np.ceil(self._deadline_s / self.period_s)) + 1
        self._rx_kept_t = np.full((n, kept), np.nan)
        self._rx_kept_pos = np.zeros((n, kept), np.int64)
        self._rx_kept_n = np.zeros(n, np.int64)
        self._sample_pos = np.zeros(n)  # cycle side: the drives' one-SYNC sample
        self._sample_t = np.nan  # ... its SYNC's master clock
        self._pos_t = np.full(n, np.nan)  # ... of each position in use (nan: not a TPDO's)
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

    # ---------------------------------------------------------- requests

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

    # ---------------------------------------------------------- readings

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

    def positions_time(self) -> np.ndarray:
        """Per drive, the master clock [s] of the SYNC its latest position answers (a drive
        samples its position at the SYNC): by the drive's count of TPDOs, never after the
        last SYNC sent before its TPDO came (by the frame's time stamp where the bus gives
        one on this host's clock, else by when the master handled it), see
        :mod:`hal.sync_count`; nan: a position not from a TPDO), shape (n,)."""
        return self._pos_t.copy()

    def positions_sample(self) -> tuple[np.ndarray, float]:
        """The drives' positions [counts] latched at one SYNC, the latest every drive that
        answers had answered at the last :meth:`receive`, and that SYNC's master clock [s]
        (:func:`hal.sync_count.common_sample`: the latest positions where all answer the
        same SYNC; a drive silent beyond the TPDO deadline with its latest position; time
        nan: no position from a TPDO; positions nan: no SYNC in common among those kept)."""
        return self._sample_pos.copy(), self._sample_t

    def lengths_sample_m(self) -> tuple[np.ndarray, float]:
        """:meth:`positions_sample` as cable lengths [m] (nan kept), and its time [s]."""
        pos, t = self.positions_sample()
        return counts_to_m(pos, self.winches), t

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


#: drives_base's public names, and this module's
__all__ = [*drives_base.__all__, "DriveConfigError", "DriveState", "WinchDrives"]
