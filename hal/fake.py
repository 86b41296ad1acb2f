"""A pure-Python stand-in for the winch hardware: no CAN, no Modbus, no threads.

:class:`FakeHardware` implements :class:`hal.interface.WinchHardware` for fast controller
tests. Each :meth:`~FakeHardware.write_lengths` is one control cycle of ``period_s``
(the SYNC period) on the fake's own clock:

- winches: a first-order lag (time constant ``lag_time_constant_s``) toward the setpoint,
  saturated at ``max_speed_m_s``, only while Operation Enabled; a CiA 402 state per drive
  (start-up -> Switch On Disabled, enable -> Operation Enabled, quick stop -> Quick Stop
  Active, where it holds with 0x605A options 5..8 and from which enable() resumes, or ->
  Switch On Disabled with options 0..4; fault -> Fault, fault reset -> Ready To Switch On;
  a lost heartbeat -> the master quick-stops it, and reports its state UNKNOWN every cycle
  until its heartbeat is back or it is recovered, as the HAL does);
- load cells: every ``tension_period_s`` a new sample of ``plant(lengths_m, t_s)`` (the
  tensions the cells measure [N]; e.g. a simulated plant settling for the cable lengths;
  called again only when the lengths changed) or of the constant ``tensions_N``; the
  calibration turns them into tensions as the Modbus client does.

Fault injection mirrors the simulated drives and cells: :meth:`~FakeHardware.inject_drive_fault`
(EMCY code), :meth:`~FakeHardware.stop_heartbeat` (lost after ``heartbeat_misses``
periods, code 0x8130), :meth:`~FakeHardware.reset_node`,
:meth:`~FakeHardware.inject_loadcell_fault` (a :class:`~hal.loadcell_client.CableStatus`
and, for ``exception``, the Modbus exception code), :meth:`~FakeHardware.lose_link` /
:meth:`~FakeHardware.restore_link` (states unknown, ``link_lost`` faults, blocking calls
raise :class:`~hal.drives.BusLinkError`; back, the drives hold in Quick Stop Active, having
lost their master, until recovered). Faults, events and messages take the forms of the
real interface.

The drives' positions answer the SYNC of the cycle (``Readings.lengths_t_s``: its time);
:meth:`~FakeHardware.hold_feedback` keeps the positions read, and their SYNC, for some
cycles (the drives' TPDOs late: a reading with no new sample).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from controller.loadcell_map import DEFAULT_MAP, RegisterMap
from controller.winch import WinchSet, load_winches
from hal.drives import CODE_BUS, CODE_HEARTBEAT, BusLinkError, DriveStartupError
from hal.drives_cia402 import DriveState, emcy_text
from hal.interface import (
    DRIVE,
    HardwareEvent,
    HardwareFault,
    LoadCellStatusTracker,
    Readings,
    WinchHardware,
    loadcell_faults,
)
from hal.loadcell_calibration import LoadCellCalibration
from hal.loadcell_client import CableStatus, TensionReading

S = DriveState
_FAULTED = (S.FAULT, S.FAULT_REACTION_ACTIVE)
_STATUS_TEXT = {
    CableStatus.TIMEOUT: "no answer within the timeout",
    CableStatus.EXCEPTION: "Modbus exception",
    CableStatus.COMM_ERROR: "connection failed",
    CableStatus.STALE: "sample counter stuck",
    CableStatus.SENSOR_FAULT: "sensor fault (status register)",
    CableStatus.OUT_OF_RANGE: "value outside the rated range",
    CableStatus.NAN: "value is NaN",
}


class FakeHardware(WinchHardware):
    """The winch hardware as a few numpy arrays (see the module docstring).

    :param winches: winch parameters (node ids, limits, speeds, bus timing)
    :param register_map: Modbus unit ids of the cells (only the ids are used)
    :param initial_lengths_m: cable lengths at power-on [m], scalar or (n,)
    :param plant: ``plant(lengths_m, t_s) -> tensions (n,)`` [N] as the cells measure them
    :param tensions_N: constant measured tensions when there is no plant [N]
    :param calibration: load-cell gain/offset (values = (measured - offset) / gain)
    :param tension_period_s: load-cell sample interval [s]
    :param lag_time_constant_s: winch lag (default: the winch parameter file's)
    """

    def __init__(
        self,
        winches: WinchSet | None = None,
        *,
        register_map: RegisterMap = DEFAULT_MAP,
        initial_lengths_m: float | np.ndarray = 10.0,
        plant: Callable[[np.ndarray, float], np.ndarray] | None = None,
        tensions_N: float | np.ndarray = 200.0,
        calibration: LoadCellCalibration | None = None,
        tension_period_s: float = 0.02,
        lag_time_constant_s: float | np.ndarray | None = None,
    ) -> None:
        w = winches if winches is not None else load_winches()
        self.winches = w
        n = len(w)
        if tuple(register_map.cables) != tuple(w.cables):
            raise ValueError(f"register map {register_map.source} lists cables "
                             f"{register_map.cables}, winches {w.source} {w.cables}")
        self.cables = tuple(w.cables)
        self.node_ids = tuple(int(x) for x in w.node_id)
        self.unit_ids = tuple(register_map.unit_ids)
        self.period_s = w.bus.sync_period_s
        self.hb_timeout_s = w.bus.heartbeat_period_s * w.bus.heartbeat_misses
        self.plant = plant
        self.calibration = calibration or LoadCellCalibration.identity(self.cables)
        self.tension_period_s = float(tension_period_s)
        tau = w.lag_time_constant_s if lag_time_constant_s is None else lag_time_constant_s
        self.tau = np.broadcast_to(np.asarray(tau, float), (n,)).copy()
        self.cycle = 0
        self.t = 0.0
        self.pos = np.broadcast_to(np.asarray(initial_lengths_m, float), (n,)).copy()
        self.target = self.pos.copy()
        self._held: tuple[np.ndarray, float] | None = None  # positions read, their SYNC
        self._hold_left = 0  # cycles the positions read stay held
        self.states = np.full(n, S.UNKNOWN, np.int8)
        self.code = np.zeros(n, np.int64)
        self.persistent = np.zeros(n, bool)
        self.started = False
        self.hb_stopped = np.zeros(n, bool)
        self.hb_last = np.zeros(n)
        self.hb_lost = np.zeros(n, bool)
        self.rebooted = np.zeros(n, bool)
        self.link_down = False
        self.relink = np.zeros(n, bool)
        self._events: list[HardwareEvent] = []
        self._const = np.broadcast_to(np.asarray(tensions_N, float), (n,)).copy()
        self._measured = np.full(n, np.nan)
        self._sampled_at = np.full(n, np.nan)
        self._sampled_pos: np.ndarray | None = None
        self._counter = -1
        self._cell_fault: dict[int, tuple[CableStatus, int]] = {}
        self._tracker = LoadCellStatusTracker(n)

    # ---- helpers ----------------------------------------------------------------------
    def who(self, k: int) -> str:
        return f"node {self.node_ids[k]} (cable {self.cables[k]})"

    def _index(self, node_or_cable: int | str) -> int:
        if isinstance(node_or_cable, str):
            return self.cables.index(node_or_cable)
        return self.node_ids.index(int(node_or_cable))

    def _mask(self, nodes: list[int] | None) -> np.ndarray:
        m = np.zeros(self.n, bool)
        if nodes is None:
            m[:] = True
        else:
            for nid in nodes:
                m[self.node_ids.index(int(nid))] = True
        return m

    def _event(self, k: int, kind: str, code: int, text: str) -> None:
        self._events.append(HardwareEvent(DRIVE, self.node_ids[k], self.cables[k], kind, code,
                                          text, self.t, self.cycle))

    def _faulted(self) -> np.ndarray:
        return np.isin(self.states, _FAULTED)

    def _reported(self) -> np.ndarray:
        """The states as the master reports them: UNKNOWN for a node whose heartbeat is lost
        (known only from a node that is not lost), else the drive's own."""
        return np.where(self.hb_lost, S.UNKNOWN, self.states).astype(np.int8)

    # ---- fault injection --------------------------------------------------------------
    def inject_drive_fault(self, node: int | str, code: int = 0x2310,
                           persistent: bool = False) -> None:
        """A drive trips with EMCY ``code`` (node id or cable id); ``persistent``: a fault
        reset fails until :meth:`repair`."""
        k = self._index(node)
        self.code[k] = code
        self.persistent[k] = persistent
        self._event(k, "emcy", code, f"{emcy_text(code)} (error register 0x81)")
        if self.states[k] not in _FAULTED:
            self._event(k, "fault", code, f"FAULT: {emcy_text(code)}")
        self.states[k] = S.FAULT
        self.target[k] = self.pos[k]

    def repair(self, node: int | str) -> None:
        """The cause of a persistent drive fault is gone (a reset now succeeds)."""
        self.persistent[self._index(node)] = False

    def stop_heartbeat(self, node: int | str, stopped: bool = True) -> None:
        """A drive's heartbeat producer stops (or starts again)."""
        self.hb_stopped[self._index(node)] = stopped

    def reset_node(self, node: int | str) -> None:
        """A drive resets (boot-up): disabled until :meth:`recover`."""
        k = self._index(node)
        self.rebooted[k] = True
        self.states[k] = S.UNKNOWN  # as the master sees it until recover()
        self.target[k] = self.pos[k]
        self._event(k, "boot_up", CODE_HEARTBEAT,
                    "unexpected boot-up: the node was reset; recover() it")

    def hold_feedback(self, cycles: int) -> None:
        """The positions read now, and the SYNC they answer, are what :meth:`read` gives
        for the next ``cycles`` cycles (the drives' TPDOs late), then the cycle's again."""
        self._held = (self.pos.copy(), self.t)
        self._hold_left = int(cycles)

    def lose_link(self) -> None:
        """The CAN link dies: drive states unknown; the drives lose their master and hold
        in Quick Stop Active (0x6007, 0x605A) behind it."""
        self.link_down = True
        self.relink[:] = self.started
        self._events.append(HardwareEvent("bus", 0, "-", "link_lost", CODE_BUS,
                                          "fake: CAN link lost: drive states unknown",
                                          self.t, self.cycle))
        held = self.started & (self.states == S.OPERATION_ENABLED)
        self._behind = np.where(held, S.QUICK_STOP_ACTIVE, self.states).astype(np.int8)
        self.target = self.pos.copy()
        self.states[:] = S.UNKNOWN

    def restore_link(self) -> None:
        """The link is back: the drives wait for recover()."""
        self.link_down = False
        self._events.append(HardwareEvent("bus", 0, "-", "link_back", 0, "fake: CAN link back",
                                          self.t, self.cycle))

    def inject_loadcell_fault(self, cable: int | str, status: CableStatus | str,
                              exception_code: int = 0x04) -> None:
        """The load cell of ``cable`` (cable id, or Modbus unit id as int) reports
        ``status`` (a CableStatus or its lower-case name) until cleared."""
        k = self.cables.index(cable) if isinstance(cable, str) else self.unit_ids.index(cable)
        st = CableStatus[status.upper()] if isinstance(status, str) else CableStatus(status)
        if st in (CableStatus.OK, CableStatus.NO_DATA):
            raise ValueError(f"{st.name} is not a fault")
        self._cell_fault[k] = (st, exception_code if st is CableStatus.EXCEPTION else 0)

    def clear_loadcell_fault(self, cable: int | str | None = None) -> None:
        if cable is None:
            self._cell_fault.clear()
            return
        k = self.cables.index(cable) if isinstance(cable, str) else self.unit_ids.index(cable)
        self._cell_fault.pop(k, None)

    # ---- blocking ---------------------------------------------------------------------
    def start(self, timeout_s: float = 3.0) -> None:
        self.started = True
        fresh = ~self._faulted()
        self.states[fresh] = S.SWITCH_ON_DISABLED
        self.hb_last[:] = self.t
        self.hb_lost[:] = False
        self.rebooted[:] = False
        self.target = self.pos.copy()
        self._sample(force=True)

    def enable(self, max_cycles: int = 50, restart_tries: int = 0) -> None:
        if self.link_down:
            raise BusLinkError("enable: fake: CAN link down")
        if not self.started:
            raise DriveStartupError("enable() before start()")
        if restart_tries > 0:
            self.recover()  # start-up: restart what is not ready (the real HAL's tries)
        stale = [f"{self.who(k)}: behind a lost CAN link: recover() it first"
                 for k in np.flatnonzero(self.relink)]
        if stale:
            raise DriveStartupError(f"enable refused: {'; '.join(stale)}")
        bad = [f"{self.who(k)}: {S(int(self.states[k])).name}" for k in range(self.n)
               if self.states[k] in _FAULTED or self.hb_lost[k] or self.rebooted[k]]
        ok = ~(self._faulted() | self.hb_lost | self.rebooted)
        entering = ok & (self.states != S.OPERATION_ENABLED)
        self.target[entering] = self.pos[entering]  # hold where it stands
        self.states[ok] = S.OPERATION_ENABLED
        self.write_lengths(None)
        if bad:
            raise DriveStartupError(
                f"not Operation Enabled after {max_cycles} cycles: {'; '.join(bad)}")

    def recover(self, timeout_s: float = 3.0) -> list[int]:
        if self.link_down:
            raise BusLinkError("recover: fake: CAN link down")
        for k in np.flatnonzero(self.relink):
            self.states[k] = self._behind[k]
        ks = np.flatnonzero(self.rebooted | (self.hb_lost & ~self.hb_stopped) | self.relink)
        self.relink[:] = False
        for k in ks:
            self.rebooted[k] = False
            self.hb_lost[k] = False
            self.hb_last[k] = self.t
            if self.states[k] not in _FAULTED:
                self.states[k] = S.SWITCH_ON_DISABLED
            self._event(int(k), "recovered", 0, "reconfigured and started")
        return [self.node_ids[k] for k in ks]

    def shutdown(self) -> None:
        if self.link_down:
            self.started = False
            raise BusLinkError("shutdown: fake: CAN link down")
        ok = ~self._faulted()
        self.states[ok] = S.SWITCH_ON_DISABLED
        self.target = self.pos.copy()
        self.started = False

    def close(self) -> None:
        self.started = False

    # ---- per cycle --------------------------------------------------------------------
    def write_lengths(self, lengths_m: np.ndarray | None) -> None:
        w = self.winches
        if lengths_m is not None:
            x = self._to_drive(lengths_m)
            if x.shape != (self.n,):
                raise ValueError(f"set_lengths: expected shape ({self.n},), got {x.shape}")
            bad = ~np.isfinite(x) | (x < w.min_length_m) | (x > w.max_length_m)
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"set_lengths: {self.who(k)}: {float(x[k])!r} m is not within "
                    f"[{w.min_length_m[k]}, {w.max_length_m[k]}] m")
            oe = self.states == S.OPERATION_ENABLED
            self.target = np.where(oe, x, self.target)
        self._cycle()

    def _cycle(self) -> None:
        dt = self.period_s
        self.t += dt
        self.cycle += 1
        self._hold_left -= 1
        if self._hold_left < 0:
            self._held = None
        if not self.started:
            return
        w = self.winches
        # quick stop: stopped at once; options 5..8 hold there, 0..4 switch the drive off
        qs = (self.states == S.QUICK_STOP_ACTIVE) & (w.quick_stop_option < 5)
        self.states[qs] = S.SWITCH_ON_DISABLED
        moving = self.states == S.OPERATION_ENABLED
        alpha = 1.0 - np.exp(-dt / np.maximum(self.tau, 1e-9))
        step = np.clip((self.target - self.pos) * alpha, -w.max_speed_m_s * dt,
                       w.max_speed_m_s * dt)
        self.pos = np.where(moving, self.pos + step, self.pos)
        self.target = np.where(moving, self.target, self.pos)
        # heartbeats
        beating = ~self.hb_stopped
        resumed = beating & self.hb_lost
        for k in np.flatnonzero(resumed):
            self.hb_lost[k] = False
            self._event(int(k), "heartbeat_resumed", CODE_HEARTBEAT, "heartbeat back")
        self.hb_last[beating] = self.t
        lost = ~self.hb_lost & ~self.rebooted & (self.t - self.hb_last > self.hb_timeout_s + 1e-9)
        for k in np.flatnonzero(lost):
            self.hb_lost[k] = True
            self._event(int(k), "heartbeat_lost", CODE_HEARTBEAT,
                        f"no heartbeat for {self.t - self.hb_last[k]:.3f} s "
                        f"(> {w.bus.heartbeat_misses} periods)")
            if self.states[k] == S.OPERATION_ENABLED:
                self.states[k] = S.QUICK_STOP_ACTIVE  # the master quick-stops it
        self._sample()

    def _sample(self, force: bool = False) -> None:
        """A new load-cell sample when one is due."""
        due = force or not np.isfinite(self._sampled_at).any() or (
            self.t - np.nanmax(self._sampled_at) >= self.tension_period_s - 1e-12)
        if not due:
            return
        if self.plant is None:
            measured = self._const
        elif self._sampled_pos is not None and np.array_equal(self._sampled_pos, self.pos):
            measured = self._measured
        else:
            measured = np.asarray(self.plant(self.pos.copy(), self.t), float)
            self._sampled_pos = self.pos.copy()
        live = np.ones(self.n, bool)
        for k, (st, _) in self._cell_fault.items():
            if st in (CableStatus.STALE, CableStatus.TIMEOUT, CableStatus.EXCEPTION,
                      CableStatus.COMM_ERROR):
                live[k] = False  # no new sample gets through
        self._measured = np.where(live | np.isnan(self._measured), measured, self._measured)
        self._sampled_at = np.where(live | np.isnan(self._sampled_at), self.t, self._sampled_at)
        self._counter += 1

    def _tension_reading(self) -> TensionReading:
        n = self.n
        status = np.where(np.isnan(self._measured), int(CableStatus.NO_DATA),
                          int(CableStatus.OK)).astype(np.int8)
        exc = np.zeros(n, np.int64)
        messages = [""] * n
        for k, (st, code) in self._cell_fault.items():
            status[k] = st
            exc[k] = code
            what = _STATUS_TEXT.get(st, st.name)
            if st is CableStatus.EXCEPTION:
                what = f"Modbus exception {code:#04x}"
            messages[k] = (f"Modbus unit {self.unit_ids[k]} (cable {self.cables[k]}) at fake: "
                           f"{what} [{st.name}]")
        values = self.calibration.true_from_measured(self._measured)
        values = np.where(status == CableStatus.OK, values, np.nan)
        age = np.where(np.isnan(self._sampled_at), np.inf, self.t - self._sampled_at)
        return TensionReading(values, age, status, tuple(messages),
                              np.full(n, self._counter, np.int64), self.t, self.cables,
                              self.unit_ids, exception_codes=exc)

    def _drive_faults(self) -> list[HardwareFault]:
        out = []
        seen = self._reported()
        for k in range(self.n):
            nid, cable = self.node_ids[k], self.cables[k]
            if self.relink[k]:
                out.append(HardwareFault(DRIVE, nid, cable, "link_lost", CODE_BUS,
                                         "fake: state unknown; recover() it when the link "
                                         "is back"))
                continue
            if seen[k] in _FAULTED:
                code = int(self.code[k])
                out.append(HardwareFault(DRIVE, nid, cable, "drive_fault", code,
                                         emcy_text(code)))
            if self.hb_lost[k]:
                out.append(HardwareFault(DRIVE, nid, cable, "heartbeat_lost", CODE_HEARTBEAT,
                                         "heartbeat lost"))
            if self.rebooted[k]:
                out.append(HardwareFault(DRIVE, nid, cable, "boot_up", CODE_HEARTBEAT,
                                         "node was reset (boot-up); recover() it"))
        return out

    def read(self) -> Readings:
        r = self._tension_reading()
        self._tracker.update(r, self.t, self.cycle)
        faults = self._drive_faults() + loadcell_faults(r)
        pos, sync_t = self._held if self._held is not None else (self.pos.copy(), self.t)
        return Readings(self.t, self.cycle, self.cables, self._to_model(pos),
                        self._reported(), r.values_N, r.age_s, r.status, tuple(faults),
                        sync_t)

    def _raw_lengths(self) -> np.ndarray:
        return self.pos.copy()

    def faults(self) -> list[HardwareFault]:
        return self._drive_faults() + loadcell_faults(self._tension_reading())

    def events(self, clear: bool = True) -> list[HardwareEvent]:
        self._tracker.update(self._tension_reading(), self.t, self.cycle)
        out = self._events + self._tracker.take(clear)
        out.sort(key=lambda e: e.cycle)
        if clear:
            self._events = []
        return out

    def quick_stop(self, nodes: list[int] | None = None) -> None:
        m = self._mask(nodes) & (self.states == S.OPERATION_ENABLED)
        self.states[m] = S.QUICK_STOP_ACTIVE
        self.target[m] = self.pos[m]
        off = self._mask(nodes) & np.isin(self.states, (S.READY_TO_SWITCH_ON, S.SWITCHED_ON))
        self.states[off] = S.SWITCH_ON_DISABLED  # transitions 7, 10

    def fault_reset(self, nodes: list[int] | None = None) -> None:
        m = self._mask(nodes) & self._faulted()
        for k in np.flatnonzero(m):
            if self.persistent[k]:
                self._event(int(k), "fault_reset_failed", int(self.code[k]),
                            "still in Fault after the reset edge (cause persists?)")
                continue
            self.states[k] = S.READY_TO_SWITCH_ON
            self._event(int(k), "emcy", 0, "error reset (no error)")
            self._event(int(k), "fault_cleared", 0, "now SWITCH_ON_DISABLED")
            self.code[k] = 0

    # ---- lock-step --------------------------------------------------------------------
    def wait_feedback(self, timeout_s: float = 0.5) -> bool:
        return self.started

    def sample_tensions(self, timeout_s: float = 2.0) -> bool:
        self._sample(force=True)
        return True


__all__ = ["FakeHardware"]
