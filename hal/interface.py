"""The winch hardware as the controller sees it: ONE interface, vectorised over the winches.

In the spirit of ros2_control, the hardware interface is kept apart from the controllers:
a controller only ever talks to a :class:`WinchHardware`, whether behind it are the
CiA 402 drives on CAN and the Modbus load cells (:class:`CanModbusHardware`, built by
:func:`open_hardware` from the ``--can`` and ``--modbus`` specs), or the pure-Python
:class:`hal.fake.FakeHardware` of fast controller tests.

Life cycle (blocking calls, outside the control cycle)::

    hw = open_hardware("socketcand:127.0.0.1:PORT", "127.0.0.1:PORT2", eds=EDS)
    hw.start()        # drives configured and NMT started, load-cell poller running
    hw.enable()       # all drives Operation Enabled in cyclic synchronous position
    ...
    hw.shutdown(); hw.close()

Control cycle (never blocks, no SDO, no socket I/O on the caller's thread)::

    r = hw.read()             # Readings: lengths [m], states, tensions [N] + age + status, faults
    hw.write_lengths(l_cmd)   # (n,) setpoints [m]: out with the RPDOs and the SYNC

``read()`` processes what arrived since the last ``write_lengths`` (drive positions answer
the SYNC that went out with it, so they are one cycle old on a real bus); calling it again
before the next write only refreshes the tensions. ``write_lengths(None)`` runs a cycle
with the setpoints unchanged (drives not enabled hold their actual position anyway).

Arrays run over the winches in cable id order ``11, 12, 21, ... 42``. Faults are
:class:`HardwareFault` values naming the device (CAN node id or Modbus unit id), the cable
and a code: the CiA 301/402 error code for a drive (EMCY / 0x603F, 0x8130 heartbeat,
0x8250 PDO), the Modbus exception code for a load cell that answered one (else 0, the
``kind`` then says what is wrong: ``timeout``, ``stale``, ``sensor_fault``, ...).

Lock-step helpers (block; for a simulated rig in tests and benchmarks, never in the real
cycle): :meth:`WinchHardware.wait_feedback`, :meth:`WinchHardware.sample_tensions`,
:meth:`WinchHardware.step`.
"""

from __future__ import annotations

import argparse
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import canopen
import numpy as np

from controller.loadcell_map import DEFAULT_MAP, RegisterMap, load_register_map
from controller.winch import WinchSet, load_winches
from hal.can_bus import CanSpec
from hal.cli_args import add_hardware_arguments
from hal.drives import DriveEvent, DriveFault, DriveStartupError, WinchDrives
from hal.drives_cia402 import ST, DriveState
from hal.loadcell_calibration import LoadCellCalibration, load_calibration
from hal.loadcell_client import CableStatus, LoadCellClient, TensionReading
from hal.modbus_config import ModbusEndpoint

DRIVE = "drive"
LOADCELL = "loadcell"
BUS = "bus"


class HardwareConfigError(ValueError):
    """Parameter files that do not fit together (the message names them)."""


@dataclass(frozen=True)
class HardwareFault:
    """An active fault: ``device`` is "drive" (``address`` = CAN node id), "loadcell"
    (``address`` = Modbus unit id) or "bus" (address 0); ``kind`` what is wrong
    (drive: drive_fault, quick_stop (stopped on its own), heartbeat_lost, drive_lost (its
    TPDOs stopped: state unknown), boot_up, nmt_state, link_lost, foreign_master (a frame
    another master sent to it; device "bus" for NMT to all nodes and SYNC); load cell: the
    :class:`~hal.loadcell_client.CableStatus` name in lower case); ``code`` see the module
    docstring."""

    device: str
    address: int
    cable: str
    kind: str
    code: int
    text: str

    def who(self) -> str:
        if self.device == DRIVE:
            return f"node {self.address} (cable {self.cable})"
        if self.device == LOADCELL:
            return f"Modbus unit {self.address} (cable {self.cable})"
        return "CAN bus"

    def __str__(self) -> str:
        return f"{self.device} {self.who()} {self.kind} 0x{self.code:04X}: {self.text}"


@dataclass(frozen=True)
class HardwareEvent:
    """Something that happened, in order of detection (the history behind the faults):
    drive events of :class:`hal.drives.DriveEvent` kinds, load-cell status changes
    (``kind`` the new status, ``ok`` when it recovered)."""

    device: str
    address: int
    cable: str
    kind: str
    code: int
    text: str
    time_s: float  #: hardware clock [s]
    cycle: int

    def __str__(self) -> str:
        return (f"{self.device} {self.address} (cable {self.cable}) {self.kind} "
                f"0x{self.code:04X}: {self.text} [cycle {self.cycle}]")


@dataclass(frozen=True)
class Readings:
    """What the hardware measured, arrays (n,) in cable id order."""

    t_s: float  #: hardware clock of this read [s]
    cycle: int  #: cycles written so far
    cables: tuple[str, ...]
    lengths_m: np.ndarray  #: cable lengths from the drives' actual positions [m]
    states: np.ndarray  #: CiA 402 states (:class:`~hal.drives_cia402.DriveState` values)
    tensions_N: np.ndarray  #: calibrated tensions [N], NaN where the status is not OK
    tension_age_s: np.ndarray  #: age of each tension sample [s] (inf: none yet)
    tension_status: np.ndarray  #: :class:`~hal.loadcell_client.CableStatus` codes
    faults: tuple[HardwareFault, ...] = field(default=())
    #: hardware clock [s] of the SYNC the lengths sample (``sample_lengths_m``, else
    #: ``lengths_m``) answers (nan: unknown)
    lengths_t_s: float = float("nan")
    #: the drives' lengths [m] latched at one SYNC (the latest every answering drive had
    #: answered: :meth:`hal.drives.WinchDrives.positions_sample`; nan: none in common):
    #: the encoders' sample; None: ``lengths_m`` (drives that do not say)
    sample_lengths_m: np.ndarray | None = None

    @property
    def enabled(self) -> np.ndarray:
        """(n,) bool: the drive is Operation Enabled."""
        return self.states == ST.OPERATION_ENABLED

    @property
    def all_enabled(self) -> bool:
        return bool(np.all(self.enabled))

    @property
    def tensions_ok(self) -> np.ndarray:
        """(n,) bool: the tension is a valid number."""
        return self.tension_status == CableStatus.OK

    @property
    def ok(self) -> bool:
        """All drives enabled, all tensions valid, no fault."""
        return self.all_enabled and bool(np.all(self.tensions_ok)) and not self.faults

    def state_names(self) -> list[str]:
        return [DriveState(int(s)).name for s in self.states]


def _sync_time(drives) -> float:
    """The hardware clock [s] of the SYNC the drives' positions answer: the median over the
    drives that have one (:meth:`hal.drives.WinchDrives.positions_time`); nan when none
    (or drives that do not say)."""
    times = getattr(drives, "positions_time", None)
    t = np.asarray(times(), float) if times is not None else np.zeros(0)
    t = t[np.isfinite(t)]
    return float(np.median(t)) if t.size else float("nan")


def loadcell_faults(r: TensionReading) -> list[HardwareFault]:
    """The cables whose tension is not OK, as faults naming the Modbus unit."""
    bad = r.status != CableStatus.OK
    if not np.count_nonzero(bad):
        return []
    codes = r.exception_codes if r.exception_codes is not None else np.zeros(len(r.cables))
    out = []
    for k in np.flatnonzero(bad):
        st = CableStatus(int(r.status[k]))
        out.append(HardwareFault(LOADCELL, int(r.unit_ids[k]), r.cables[k], st.name.lower(),
                                 int(codes[k]), r.messages[k] or st.name))
    return out


class LoadCellStatusTracker:
    """Turns changes of the load cells' statuses between reads into :class:`HardwareEvent`
    (a status that is not OK, and OK again after one)."""

    def __init__(self, n: int) -> None:
        self.status = np.full(n, int(CableStatus.NO_DATA), np.int8)
        self.events: list[HardwareEvent] = []

    def update(self, r: TensionReading, t_s: float, cycle: int) -> None:
        changed = r.status != self.status
        if not np.count_nonzero(changed):
            return  # the same statuses (kept as they are)
        for k in np.flatnonzero(changed):
            st = CableStatus(int(r.status[k]))
            if st is CableStatus.NO_DATA or (
                    st is CableStatus.OK and self.status[k] == CableStatus.NO_DATA):
                continue  # the first valid value is no event
            code = int(r.exception_codes[k]) if r.exception_codes is not None else 0
            if st is CableStatus.OK:
                kind, text = "ok", "tension valid again"
            else:
                kind, text = st.name.lower(), r.messages[k] or st.name
            self.events.append(HardwareEvent(LOADCELL, int(r.unit_ids[k]), r.cables[k], kind,
                                             code, text, t_s, cycle))
        self.status = r.status.copy()

    def take(self, clear: bool = True) -> list[HardwareEvent]:
        out = list(self.events)
        if clear:
            self.events.clear()
        return out


def drive_fault(f: DriveFault) -> HardwareFault:
    device = BUS if f.node_id == 0 else DRIVE  # foreign_master: a frame to the whole bus
    return HardwareFault(device, f.node_id, f.cable, f.kind, f.code, f.text)


def drive_event(e: DriveEvent) -> HardwareEvent:
    device = BUS if e.node_id == 0 else DRIVE  # bus_error, link_lost, link_back
    return HardwareEvent(device, e.node_id, e.cable, e.kind, e.code, e.text, e.time_s, e.cycle)


class WinchHardware(ABC):
    """The one hardware interface of the controller (see the module docstring)."""

    cables: tuple[str, ...]
    winches: WinchSet  #: the winch parameters (limits, windows, bus timing)
    node_ids: tuple[int, ...]  #: CAN node id per winch
    unit_ids: tuple[int, ...]  #: Modbus unit id of the load cell per cable
    period_s: float  #: control cycle = SYNC period [s]

    @property
    def n(self) -> int:
        return len(self.cables)

    # ---- referencing (the paper's initialisation, Fig. 4d) ------------------------------
    _ref_offset: np.ndarray | None = None

    @property
    def reference_offset_m(self) -> np.ndarray:
        """Per-winch offset [m] added to every length read and subtracted from every
        setpoint (zeros until :meth:`reference`)."""
        return np.zeros(self.n) if self._ref_offset is None else self._ref_offset.copy()

    def reference(self, lengths_m: np.ndarray) -> np.ndarray:
        """Referencing: from now on the drives' latest positions (the last :meth:`read`)
        read as the cable lengths ``lengths_m`` (n,) [m], e.g. the model's lengths at the
        measured initialisation pose. A per-winch offset in the HAL, added to the lengths
        read and subtracted from the setpoints; the drives are not changed (commissioning
        homes them by setting their position instead). Returns the offsets [m]."""
        target = np.asarray(lengths_m, dtype=float)
        if target.shape != (self.n,) or not np.all(np.isfinite(target)):
            raise ValueError(f"reference: expected {self.n} finite lengths [m], got "
                             f"{np.asarray(lengths_m).tolist()}")
        raw = self._raw_lengths()
        if not np.all(np.isfinite(raw)):
            bad = [self.cables[k] for k in np.flatnonzero(~np.isfinite(raw))]
            raise ValueError(f"reference: no position read yet from the winches of cables "
                             f"{', '.join(bad)}")
        self._ref_offset = target - raw
        return self._ref_offset.copy()

    def _to_model(self, raw_m: np.ndarray) -> np.ndarray:
        return raw_m if self._ref_offset is None else raw_m + self._ref_offset

    def _to_drive(self, lengths_m: np.ndarray) -> np.ndarray:
        x = np.asarray(lengths_m, dtype=float)
        return x if self._ref_offset is None else x - self._ref_offset

    @abstractmethod
    def _raw_lengths(self) -> np.ndarray:
        """The drives' latest lengths [m] without the referencing offset."""

    # ---- blocking, outside the cycle ------------------------------------------------
    @abstractmethod
    def start(self, timeout_s: float = 3.0) -> None:
        """Bring the drives up (configured, NMT operational, disabled), start reading the
        load cells and wait for a first read of all of them. Raises naming the node that
        failed; load cells that do not answer show in the readings' statuses."""

    @abstractmethod
    def enable(self, max_cycles: int = 50, restart_tries: int = 0) -> None:
        """Enable every drive (Operation Enabled, CSP), cycling until done; raises
        :class:`~hal.drives.DriveStartupError` naming the drives that did not come.
        ``restart_tries`` > 0 (start-up, nothing moved yet): drives that left NMT
        OPERATIONAL, were reset or lost their heartbeat are restarted first, at most that
        many times (:meth:`hal.drives.WinchDrives.restart_for_enable`)."""

    def set_thread_priority(self, priority: int) -> dict[str, str]:
        """The HAL's time-critical producer threads (the master heartbeat) in SCHED_FIFO at
        ``priority`` where the OS allows it (:func:`hal.rt_threads.raise_thread`; 0:
        normal); returns what each got as text, by thread (none here)."""
        return {}

    @abstractmethod
    def recover(self, timeout_s: float = 3.0) -> list[int]:
        """Restart drives that were reset or went silent and are back; node ids restarted
        (they come back disabled: :meth:`enable` them)."""

    @abstractmethod
    def shutdown(self) -> None:
        """Disable the drives (Switch On Disabled, brakes hold), then NMT pre-operational;
        stop polling the load cells."""

    @abstractmethod
    def close(self) -> None:
        """Release the bus and the connections."""

    # ---- per cycle, non-blocking ----------------------------------------------------
    @abstractmethod
    def read(self) -> Readings:
        """The latest measurements and the active faults (never blocks)."""

    @abstractmethod
    def write_lengths(self, lengths_m: np.ndarray | None) -> None:
        """Length setpoints (n,) [m] (None: unchanged) and one bus cycle out. Raises
        ValueError naming the node for a non-finite setpoint or one outside the winch's
        limits (then nothing is sent). Never blocks."""

    @abstractmethod
    def faults(self) -> list[HardwareFault]:
        """Active faults (drives, load cells)."""

    @abstractmethod
    def events(self, clear: bool = True) -> list[HardwareEvent]:
        """Events since the last call (all with ``clear=False``)."""

    @abstractmethod
    def quick_stop(self, nodes: list[int] | None = None) -> None:
        """Quick stop of drives (node ids; default all), from the next write."""

    @abstractmethod
    def fault_reset(self, nodes: list[int] | None = None) -> None:
        """Reset faulted drives over the next cycles (they come back disabled)."""

    def feedback_age(self) -> np.ndarray:
        """Per drive, how many SYNCs in a row went unanswered before the position of the
        last :meth:`read` (0: it answers the latest SYNC it could; k: it is k SYNCs older,
        a late or missing TPDO), shape (n,). Here: none."""
        return np.zeros(self.n, np.int64)

    # ---- lock-step helpers (block) --------------------------------------------------
    @abstractmethod
    def wait_feedback(self, timeout_s: float = 0.5) -> bool:
        """Wait until every drive answered the last SYNC (lock-step with a simulator), at
        most ``timeout_s`` [s, wall] (a short wait for a drive that missed the SYNC before,
        none for a lost one): a miss counts towards the drives' TPDO deadline
        (``drive_lost``), the cycles never wait longer."""

    @abstractmethod
    def sample_tensions(self, timeout_s: float = 2.0) -> bool:
        """Make sure the tensions come from a read of all cells that began after this call
        (a synchronous sweep, or waiting for the poller); False on timeout."""

    def step(self, lengths_m: np.ndarray | None = None, timeout_s: float = 0.5) -> Readings:
        """One lock-step cycle: write, wait for the drives' answers, read (a drive that did
        not answer in time shows as a missing TPDO in the next read's events)."""
        self.write_lengths(lengths_m)
        self.wait_feedback(timeout_s)
        return self.read()

    def run_until(self, done: Callable[[Readings], bool], max_cycles: int,
                  lengths_m: np.ndarray | None = None, timeout_s: float = 0.5) -> Readings:
        """Lock-step cycles until ``done(readings)`` or ``max_cycles``; the last readings."""
        r = self.read()
        for _ in range(max_cycles):
            if done(r):
                break
            r = self.step(lengths_m, timeout_s)
        return r

    def __enter__(self) -> WinchHardware:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class CanModbusHardware(WinchHardware):
    """CiA 402 drives over CANopen (:class:`~hal.drives.WinchDrives`) and load cells over
    Modbus (:class:`~hal.loadcell_client.LoadCellClient`; None: no load cells, tensions
    NaN with status NO_DATA and no load-cell faults).

    ``poll``: "thread" reads the cells in the background at the client's rate (the control
    loop); "manual" only in :meth:`sample_tensions` (lock-step benchmarks).
    """

    def __init__(self, drives: WinchDrives, cells: LoadCellClient | None,
                 poll: str = "thread") -> None:
        if poll not in ("thread", "manual"):
            raise ValueError(f"poll must be 'thread' or 'manual', got {poll!r}")
        self.drives = drives
        self.cells = cells
        self.poll = poll
        w = drives.winches
        self.winches = w
        self.cables = tuple(w.cables)
        self.node_ids = tuple(drives.node_ids)
        if cells is not None:
            if tuple(cells.map.cables) != self.cables:
                raise HardwareConfigError(
                    f"load-cell register map {cells.map.source} lists cables {cells.map.cables}, "
                    f"winch parameters {w.source} {self.cables}")
            self.unit_ids = tuple(cells.map.unit_ids)
        else:
            self.unit_ids = tuple(0 for _ in self.cables)
        self.period_s = drives.period_s
        self._owes_receive = False
        self._poller_started = False
        self._tracker = LoadCellStatusTracker(self.n)
        self._reading: TensionReading | None = None

    # ---- blocking ---------------------------------------------------------------------
    def start(self, timeout_s: float = 3.0) -> None:
        self.drives.start(timeout=timeout_s)
        self._owes_receive = False
        if self.cells is not None and self.poll == "thread" and not self._poller_started:
            self.cells.start()
            self._poller_started = True
        if self.cells is not None:
            # one sweep done before the first cycle: values, or statuses naming the units
            self.sample_tensions(timeout_s=max(timeout_s, 2 * self.cells.timeout_s * self.n))

    def enable(self, max_cycles: int = 50, restart_tries: int = 0) -> None:
        if self._owes_receive:
            self.drives.receive()
            self._owes_receive = False
        try:
            # lock-step cycles, ends after a SYNC
            self.drives.enable_and_wait(max_cycles, restart_tries=restart_tries)
        finally:
            # also after a failure (e.g. a drive lost while enabling): the last SYNC's
            # answers are read by the next read() (a receive without a SYNC counts nothing)
            self._owes_receive = True

    def set_thread_priority(self, priority: int) -> dict[str, str]:
        return {"master_heartbeat": self.drives.set_producer_priority(priority)}

    def recover(self, timeout_s: float = 3.0) -> list[int]:
        if self._owes_receive:
            self.drives.receive()
            self._owes_receive = False
        return self.drives.recover(timeout=timeout_s)

    def shutdown(self) -> None:
        if self._owes_receive:
            self.drives.receive()
            self._owes_receive = False
        try:
            self.drives.shutdown()  # BusLinkError on a dead link: the cells stop anyway
        finally:
            self._stop_cells()

    def _stop_cells(self) -> None:
        if self.cells is not None:
            self.cells.stop()  # joins the poller (if any) and closes the connection
            self._poller_started = False

    def close(self) -> None:
        self._stop_cells()
        self.drives.close()

    # ---- per cycle --------------------------------------------------------------------
    def _tensions(self) -> TensionReading | None:
        if self.cells is None:
            return None
        r = self.cells.read()
        self._tracker.update(r, self.drives.now(), self.drives.cycle)
        self._reading = r
        return r

    def read(self) -> Readings:
        d = self.drives
        if self._owes_receive:
            d.receive()
            self._owes_receive = False
        r = self._tensions()
        faults = [drive_fault(f) for f in d.faults()]
        if r is not None:
            faults += loadcell_faults(r)
            tensions, age, status = r.values_N, r.age_s, r.status
        else:
            tensions = np.full(self.n, np.nan)
            age = np.full(self.n, np.inf)
            status = np.full(self.n, int(CableStatus.NO_DATA), np.int8)
        sample, sample_t = self._lengths_sample()
        return Readings(d.now(), d.cycle, self.cables, self._to_model(d.lengths_m()),
                        d.states(), tensions, age, status, tuple(faults), sample_t, sample)

    def _lengths_sample(self) -> tuple[np.ndarray | None, float]:
        """The drives' lengths [m] at one SYNC and its hardware clock [s]
        (:meth:`hal.drives.WinchDrives.lengths_sample_m`); drives that do not say: None and
        the median of their positions' SYNCs (nan: unknown)."""
        take = getattr(self.drives, "lengths_sample_m", None)
        if take is None:
            return None, _sync_time(self.drives)
        lengths, t = take()
        return self._to_model(lengths), t

    def _raw_lengths(self) -> np.ndarray:
        return self.drives.lengths_m()

    def write_lengths(self, lengths_m: np.ndarray | None) -> None:
        d = self.drives
        if lengths_m is not None:
            d.set_lengths(self._to_drive(lengths_m))  # validates first: raises, nothing changed
        if self._owes_receive:
            d.receive()  # the state machine acts on the latest states
        d.transmit()
        self._owes_receive = True

    def faults(self) -> list[HardwareFault]:
        out = [drive_fault(f) for f in self.drives.faults()]
        r = self._reading if self._reading is not None else (
            self.cells.read() if self.cells is not None else None)
        if r is not None:
            out += loadcell_faults(r)
        return out

    def events(self, clear: bool = True) -> list[HardwareEvent]:
        self._tensions()
        out = [drive_event(e) for e in self.drives.events(clear)]
        out += self._tracker.take(clear)
        out.sort(key=lambda e: e.cycle)
        return out

    def quick_stop(self, nodes: list[int] | None = None) -> None:
        self.drives.quick_stop(nodes)

    def fault_reset(self, nodes: list[int] | None = None) -> None:
        self.drives.fault_reset(nodes)

    def feedback_age(self) -> np.ndarray:
        return self.drives.feedback_age()

    # ---- lock-step --------------------------------------------------------------------
    def wait_feedback(self, timeout_s: float = 0.5) -> bool:
        return self.drives.wait_feedback(timeout_s)

    def sample_tensions(self, timeout_s: float = 2.0) -> bool:
        if self.cells is None:
            return False
        if self._poller_started:
            # the sweep running now may have begun before the call: wait for the next one too
            return self.cells.wait_sweeps(2, timeout_s)
        self.cells.poll_once()
        return True


# ---------------------------------------------------------------------------- factory


def _winches(w: WinchSet | str | Path | None) -> WinchSet:
    return w if isinstance(w, WinchSet) else load_winches(w)


def open_hardware(
    can: str | CanSpec,
    modbus: str | ModbusEndpoint | None,
    *,
    eds: str | Path | canopen.ObjectDictionary,
    winches: WinchSet | str | Path | None = None,
    register_map: RegisterMap | str | Path | None = None,
    calibration: LoadCellCalibration | str | Path | None = None,
    clock: str | Callable[[], float] = "wall",
    poll: str = "thread",
    loadcell_rate_hz: float = 50.0,
    loadcell_timeout_s: float = 0.1,
    loadcell_stale_s: float = 0.25,
    loadcell_max_age_s: float | None = None,
) -> CanModbusHardware:
    """The hardware behind a ``--can`` spec and a ``--modbus`` spec (None: no load cells).

    ``eds``: the drives' EDS file; ``winches``: winch parameter file or set (default the
    shipped ROCASPECT winches); ``register_map``/``calibration``: load-cell map and gains
    (files or objects; default the built-in map, identity); ``clock``: "wall" for real
    drives, "sync" in lock-step with a simulated rig on its deterministic clock.
    Opens the bus and the Modbus client (not connected until :meth:`start`).
    """
    w = _winches(winches)
    if register_map is None:
        rmap = DEFAULT_MAP
    elif isinstance(register_map, RegisterMap):
        rmap = register_map
    else:
        rmap = load_register_map(register_map)
    if isinstance(calibration, str | Path):
        calibration = load_calibration(calibration, rmap.cables)
    if tuple(rmap.cables) != tuple(w.cables):
        raise HardwareConfigError(f"load-cell register map {rmap.source} lists cables "
                                  f"{rmap.cables}, winch parameters {w.source} {w.cables}")
    drives = WinchDrives.open(can, w, eds, clock=clock)
    cells = None
    if modbus is not None:
        # polled by the caller in lock-step (``sync``, ``manual``): a reading's age on the
        # master clock, the simulated time since it came, however fast the simulation runs;
        # a polling thread runs on the wall clock, and so do its ages
        kw = {"clock": drives.now} if (clock == "sync" and poll == "manual") else {}
        try:
            cells = LoadCellClient(modbus, register_map=rmap, calibration=calibration,
                                   rate_hz=loadcell_rate_hz, timeout_s=loadcell_timeout_s,
                                   stale_s=loadcell_stale_s, max_age_s=loadcell_max_age_s,
                                   **kw)
        except BaseException:
            drives.close()
            raise
    return CanModbusHardware(drives, cells, poll=poll)


def hardware_from_args(args: argparse.Namespace, poll: str = "thread") -> CanModbusHardware:
    """:func:`open_hardware` from the options of :func:`add_hardware_arguments` (``--site``
    filled in first with :func:`hal.cli_args.apply_site`)."""
    from hal.cli_args import apply_site

    apply_site(args)
    if args.can is None:
        raise ValueError("no CAN bus: give --can SPEC (e.g. socketcand:127.0.0.1:PORT)")
    return open_hardware(
        args.can, args.modbus, eds=args.eds, winches=args.winches,
        register_map=args.loadcell_map, calibration=args.loadcell_calibration,
        clock=args.hal_clock, poll=poll, loadcell_rate_hz=args.loadcell_rate,
        loadcell_timeout_s=args.loadcell_timeout, loadcell_stale_s=args.loadcell_stale,
        loadcell_max_age_s=args.loadcell_max_age,
    )


__all__ = [
    "CanModbusHardware",
    "DriveStartupError",
    "DriveState",
    "CableStatus",
    "HardwareConfigError",
    "HardwareEvent",
    "HardwareFault",
    "Readings",
    "WinchHardware",
    "add_hardware_arguments",
    "hardware_from_args",
    "loadcell_faults",
    "open_hardware",
]
