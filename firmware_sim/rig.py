"""The whole simulated robot: eight CiA 402 drives, eight Modbus load cells and the plant.

:class:`SimRig` couples

- :class:`~firmware_sim.drive_bank.SimulatedWinchBank` on a python-can bus (an in-process
  ``virtual`` channel, optionally served over TCP by the socketcand
  :class:`~firmware_sim.can_hub.CanHub`, or any bus handed in, e.g. SocketCAN);
- a :class:`~firmware_sim.loadcell_bank.LoadCellBank` behind a
  :class:`~firmware_sim.loadcell_server.LoadCellServer` (Modbus/TCP, or RTU framing over TCP);
- :class:`~firmware_sim.plant.Plant`, the robot as the scenario says it really is;
- a :class:`~firmware_sim.tracker_sim.SimTracker` (the plant's pose plus the scenario's
  tracker noise, time stamped with the plant's time): in process with
  :meth:`SimRig.measure_pose`, and over TCP (``tracker_port``) with the ``cdpr-tracker/1``
  protocol (:attr:`SimRig.tracker_spec`, the HAL's ``--tracker`` form).

The drums' positions are the cable lengths (:meth:`SimulatedWinchBank.drum_lengths_m`): a
CiA 402 homing moves a drive's count (0x6064), never its drum, so the plant keeps the
physical cable apart from the encoder reading, as a real winch does. They start at the
plant's encoder reference ``d_model(p0)``, so the platform stands at the scenario's init
pose. The plant settles for the current readings at ``plant_rate_hz`` at most (only when
they changed, or when the scenario has time-dependent effects: drift, a slip due), in the
rig's thread; the true tensions go to the drives (torque actual), the tensions the cells
measure (truth's gain/offset, :meth:`Plant.measured_tensions`) to the load-cell bank, which
adds the scenario's load-cell noise at each sample (``cell_rate_hz``, always running: real
cells sample on their own).

Of the scenario's noise the rig uses ``load_cell_n``, the tracker's and ``process_m``: a
new random change of the unstretched lengths is drawn each time the winches start to move
after standing still (a new visit: winding repeatability); lengths are quantised by the
drives' encoder counts (not ``encoder_m``). Drift and slips act on the plant's time. On
the wall clock, a settle that takes longer than the plant period is counted
(:attr:`SimRig.late_settles`) and logged: the plant falls behind.

Clocks: ``clock="sync"`` (deterministic): the drives advance by the SYNC period on each
SYNC, and the plant's time [s] is the drives' time; ``clock="wall"``: both follow
``time.monotonic``. ``plant_thread=False`` settles only in :meth:`SimRig.settle_now`
(deterministic tests); the load cells keep sampling the last state.

The states the plant reached are in :attr:`SimRig.history` (:class:`RigRecord`, the last
``HISTORY`` of them), the rig's own record of what it served.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from dataclasses import dataclass

import can
import numpy as np

from controller.winch import WinchSet, load_winches
from firmware_sim.can_hub import CanHub
from firmware_sim.drive_bank import SimulatedWinchBank
from firmware_sim.loadcell_bank import LoadCellBank
from firmware_sim.loadcell_server import LoadCellServer
from firmware_sim.plant import Plant, PlantError, PlantState
from firmware_sim.scenario import FORMAT, Scenario, parse_scenario
from firmware_sim.tracker_sim import DEFAULT_RATE_HZ, SimTracker, TrackerServer

log = logging.getLogger(__name__)

#: readings that moved less than this since the last settle are "unchanged" [m]
SETTLE_TOL_M = 1e-9
#: plant states kept in :attr:`SimRig.history` (8 min at 20 settles per second)
HISTORY = 10_000
#: the plant checks its rest position against finite differences of the energy on every
#: n-th settle (the first always): the check costs as much as the settle itself
ENERGY_CHECK_EVERY = 20


def default_scenario() -> Scenario:
    """The shipped ``rocaspect`` model as model and truth, default init pose and noise, no
    per-visit process noise (a rig that comes back to the same readings stands at the same
    pose)."""
    return parse_scenario({"format": FORMAT, "noise": {"process_m": 0.0}},
                          "<default scenario>")


@dataclass(frozen=True)
class RigRecord:
    """One plant state the rig served: at time ``t_s`` [s] for length ``readings_m`` (n,)
    [m], the platform rests at ``pose`` (6,) with true ``tensions_N`` (n,), and the cells
    measure ``measured_N`` (n,) before noise."""

    t_s: float
    readings_m: np.ndarray
    pose: np.ndarray
    tensions_N: np.ndarray
    measured_N: np.ndarray


class SimRig:
    """The simulated robot (see the module docstring).

    :param scenario: what the robot really is (default :func:`default_scenario`)
    :param winches: winch parameters (default the shipped ROCASPECT winches)
    :param clock: "sync" (deterministic drive time) or "wall"
    :param bus: run the drives on this bus (owned and closed by the rig; no hub)
    :param channel: name of the in-process virtual channel (default a unique one)
    :param hub_port: serve the virtual channel over TCP on this port (0: any free one;
        None: no hub); ``hub_host`` the address it binds
    :param modbus_host, modbus_port: where the load cells listen (port 0: any free one)
    :param rtu: RTU framing over TCP instead of Modbus/TCP
    :param plant_thread: settle in the rig's thread (else only in :meth:`settle_now`)
    :param plant_rate_hz: settles per second at most
    :param cell_rate_hz: load-cell samples per second
    :param tracker_port: serve the simulated tracker over TCP on this port (0: any free
        one; None: in process only); ``tracker_host`` the address it binds,
        ``tracker_rate_hz`` measurements per second; ``watch_wall_heartbeats``: with the
        SYNC clock, the drives also watch the master's heartbeat on wall time (False where
        the master runs in lock-step in this process and cannot die apart from the rig)
    """

    def __init__(
        self,
        scenario: Scenario | None = None,
        *,
        winches: WinchSet | None = None,
        clock: str = "sync",
        bus: can.BusABC | None = None,
        channel: str | None = None,
        hub_port: int | None = None,
        hub_host: str = "127.0.0.1",
        modbus_host: str = "127.0.0.1",
        modbus_port: int = 0,
        rtu: bool = False,
        plant_thread: bool = True,
        plant_rate_hz: float = 20.0,
        cell_rate_hz: float = 50.0,
        tracker_port: int | None = None,
        tracker_host: str = "127.0.0.1",
        tracker_rate_hz: float = DEFAULT_RATE_HZ,
        watch_wall_heartbeats: bool = True,
    ) -> None:
        if clock not in ("sync", "wall"):
            raise ValueError(f"clock must be 'sync' or 'wall', got {clock!r}")
        if bus is not None and hub_port is not None:
            raise ValueError("a hub serves the rig's own virtual channel, not a bus handed in")
        if not (plant_rate_hz > 0 and cell_rate_hz > 0):
            raise ValueError("plant_rate_hz and cell_rate_hz must be > 0")
        self.scenario = scenario if scenario is not None else default_scenario()
        self.winches = winches if winches is not None else load_winches()
        self.clock = clock
        self.plant_thread = plant_thread
        self.plant_period_s = 1.0 / plant_rate_hz
        self.cell_period_s = 1.0 / cell_rate_hz
        self._make_plant()
        self._make_can(bus, channel, hub_port, hub_host, watch_wall_heartbeats)
        self._make_cells(modbus_host, modbus_port, rtu)
        self._make_tracker(tracker_port, tracker_host, tracker_rate_hz)
        self._first_rest()

    def _make_plant(self) -> None:
        """The plant of the scenario, at the init pose, and the winches' reference lengths
        there (checked against the winches' cables and length limits)."""
        sc = self.scenario
        if tuple(self.winches.cables) != tuple(sc.model.cable_ids):
            raise ValueError(f"winches {self.winches.source} are for cables "
                             f"{self.winches.cables}, the robot {sc.model.name} has "
                             f"{sc.model.cable_ids}")
        self.plant = Plant(sc.model, sc.truth, sc.init_pose,
                           sc.nuisances(),
                           slip_times=sc.slip_times, rng=np.random.default_rng(sc.seed + 1),
                           check_every=ENERGY_CHECK_EVERY)
        self._visit = np.zeros(sc.model.n_cables)  # this visit's change of the lengths [m]
        self._moving = False
        self.reference_m = self.plant.reference.copy()
        bad = (self.reference_m < self.winches.min_length_m) | (
            self.reference_m > self.winches.max_length_m)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"cable {self.winches.cables[k]}: reference length "
                             f"{self.reference_m[k]:.3f} m at the init pose is outside the "
                             f"winch limits of {self.winches.source}")

    def _make_can(self, bus: can.BusABC | None, channel: str | None, hub_port: int | None,
                  hub_host: str, watch_wall_heartbeats: bool) -> None:
        """The simulated drives on ``bus`` (else on a virtual channel of the rig's own,
        served by a socketcand hub on ``hub_port`` when given), at the reference lengths."""
        self.channel: str | None = None
        self._hub_bus: can.BusABC | None = None
        self.hub: CanHub | None = None
        if bus is None:
            self.channel = channel or f"sim-rig-{os.getpid()}-{id(self):x}"
            bus = can.Bus(interface="virtual", channel=self.channel)
            if hub_port is not None:
                self._hub_bus = can.Bus(interface="virtual", channel=self.channel)
                self.hub = CanHub(hub_host, hub_port, bus=self._hub_bus)
        self._bus_spec = None if self.channel is None else f"virtual:{self.channel}"
        self.bank = SimulatedWinchBank(bus, self.winches,
                                       clock=time.monotonic if self.clock == "wall" else None)
        self.bank.set_positions_m(self.reference_m)
        if not watch_wall_heartbeats:
            for d in self.bank.drives:
                d.watch_wall = False

    def _make_cells(self, host: str, port: int, rtu: bool) -> None:
        """The load cells (the scenario's noise) and their Modbus server (not yet started)."""
        sc = self.scenario
        self.cells = LoadCellBank(noise_N=sc.noise.load_cell_n, seed=sc.seed + 2)
        if tuple(self.cells.map.cables) != tuple(self.winches.cables):
            raise ValueError(f"load-cell map {self.cells.map.source} is for cables "
                             f"{self.cells.map.cables}, winches for {self.winches.cables}")
        self.server = LoadCellServer(self.cells, host=host, port=port, rtu=rtu)

    def _make_tracker(self, port: int | None, host: str, rate_hz: float) -> None:
        """The laser tracker: the plant's pose with the scenario's noise (and its own
        errors), served on ``port`` when given; its time stamps are the plant's time, which
        is the drives' clock on the SYNC clock (the greeting says ``clock=drives``) and the
        rig's own on the wall clock (``clock=own``: since the rig was made)."""
        sc = self.scenario
        self.tracker = SimTracker(self._pose_now,
                                  sc.noise.tracker_m, sc.noise.tracker_rad, seed=sc.seed + 3,
                                  truth=sc.truth)
        self.tracker_server = None if port is None else TrackerServer(
            self.tracker.measure, host=host, port=port, rate_hz=rate_hz,
            clock="drives" if self.clock == "sync" else "own")

    def _first_rest(self) -> None:
        """The plant's state and history, settled once at the drives' quantised readings."""
        self._lock = threading.Condition()
        self._t0 = time.monotonic()
        st = self.plant.state
        self.history: deque[RigRecord] = deque(maxlen=HISTORY)
        self._settle_lock = threading.Lock()  # the plant is not thread-safe
        self._held: tuple[RigRecord | None, float] = (None, -np.inf)  # last rest read
        # the drives' quantised readings, so that the first settle is not a move (no visit)
        self._publish(0.0, self.bank.drum_lengths_m(), st)
        self.settles = 0  #: plant settles so far
        self.plant_errors: list[str] = []  #: why the plant found no rest position
        self.late_settles = 0  #: wall clock: settles that took longer than the plant period
        self.settle_s = 0.0  #: wall time spent settling [s]
        self._settle(force=True)  # for the readings as the drives quantise them
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False
        self._closed = False

    # ------------------------------------------------------------------ life cycle

    def start(self) -> SimRig:
        """Power the drives on, serve the cells (and the hub), start the rig's thread."""
        self.cells.update(self.history[-1].measured_N)  # a first sample before any read
        self.server.start()
        if self.tracker_server is not None:
            self.tracker_server.start()
        if self.hub is not None:
            self.hub.start()
        self.bank.start()
        self._thread = threading.Thread(target=self._run, name="sim-rig", daemon=True)
        self._thread.start()
        self._started = True
        return self

    def close(self) -> None:
        """Stop everything (idempotent): thread, load-cell server, hub, drives, buses."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.server.stop()
        if self.tracker_server is not None:
            self.tracker_server.close()
        if self.hub is not None:
            self.hub.close()
        self.bank.close()
        if self._hub_bus is not None:
            self._hub_bus.shutdown()

    def __enter__(self) -> SimRig:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ endpoints

    @property
    def can_spec(self) -> str | None:
        """The bus in the HAL's ``--can`` form: the hub's socketcand address if it serves,
        else the virtual channel (None for a bus handed in)."""
        if self.hub is not None:
            host, port = self.hub.address
            return f"socketcand:{host}:{port}"
        return self._bus_spec

    @property
    def modbus_spec(self) -> str:
        """The load cells in the HAL's ``--modbus`` form."""
        return self.server.endpoint

    @property
    def tracker_spec(self) -> str | None:
        """The simulated tracker in the HAL's ``--tracker`` form (None: in process only)."""
        return None if self.tracker_server is None else self.tracker_server.spec

    def _pose_now(self) -> tuple[float, np.ndarray]:
        """The platform's pose (6,) [m, rad] the plant holds and its time [s]: now while the
        drums stand at the lengths it was settled for; once they moved on, the last time
        they stood there (the settle's, or the last read at rest: the pose answers those
        lengths, not the drums' now)."""
        t, rec = self.time_s(), self.last
        if float(np.max(np.abs(self.bank.drum_lengths_m() - rec.readings_m))) <= SETTLE_TOL_M:
            self._held = (rec, t)
            return t, rec.pose
        held, since = self._held
        return (max(rec.t_s, since) if held is rec else rec.t_s), rec.pose

    def measure_pose(self) -> tuple[float, np.ndarray, bool]:
        """A tracker measurement now: ``(t_s, pose (6,), valid)``, the plant's time and
        pose plus the scenario's tracker noise (``hal.tracker.CallableTracker`` takes it)."""
        return self.tracker.measure()

    def endpoints(self) -> dict:
        """Where the rig serves, as plain data (``can``, ``modbus``, ``tracker``, ids)."""
        return {
            "can": self.can_spec,
            "virtual": self._bus_spec,
            "modbus": self.modbus_spec,
            "tracker": self.tracker_spec,
            "node_ids": [int(x) for x in self.winches.node_id],
            "unit_ids": list(self.cells.map.unit_ids),
            "cables": list(self.winches.cables),
            "clock": self.clock,
        }

    # ------------------------------------------------------------------ the coupling

    def time_s(self) -> float:
        """Plant time [s]: the drives' time (sync clock) or since the rig was made (wall)."""
        if self.clock == "sync":
            with self.bank.lock:
                return self.bank.drives[0].now_us * 1e-6
        return time.monotonic() - self._t0

    def _publish(self, t: float, readings: np.ndarray, st: PlantState) -> RigRecord:
        rec = RigRecord(t, readings, st.pose.copy(), st.tensions.copy(),
                        np.asarray(self.plant.measured_tensions(st.tensions), float))
        with self._lock:
            self.history.append(rec)
            self._lock.notify_all()
        return rec

    @property
    def last(self) -> RigRecord:
        """The plant state served now."""
        with self._lock:
            return self.history[-1]

    def _time_dependent(self, t_prev: float, t: float) -> bool:
        sc = self.scenario
        if (np.any(np.asarray(sc.drift_m_per_s) != 0.0) or sc.rope_settle_m) and t > t_prev:
            return True
        slips = sc.slip_times[(sc.slip_times > 0) & (sc.truth.length_offset != 0)]
        return bool(np.any((slips > t_prev) & (slips <= t)))

    def settle_now(self, force: bool = False) -> RigRecord:
        """Settle the plant for the drives' positions now (if they changed, a time-dependent
        effect is due, or ``force``); publish the tensions. Blocks ~ms."""
        with self._settle_lock:
            return self._settle(force)

    def _settle(self, force: bool) -> RigRecord:
        readings = self.bank.drum_lengths_m()
        t = self.time_s()
        last = self.last
        moved = float(np.max(np.abs(readings - last.readings_m))) > SETTLE_TOL_M
        if moved and not self._moving and self.plant.nuisances.process_noise_m > 0:
            # a new visit: the winding repeats to within the process noise
            self._visit = self.plant.visit_noise()
        self._moving = moved
        if not (force or moved or self._time_dependent(last.t_s, t)):
            return last
        try:
            st = self.plant.settle(readings, t=t, visit_noise=self._visit)
        except PlantError as exc:
            msg = f"t = {t:.3f} s, readings {np.round(readings, 6).tolist()}: {exc}"
            if not self.plant_errors or self.plant_errors[-1] != msg:
                log.warning("sim rig: %s (keeping the last rest position)", msg)
            self.plant_errors.append(msg)
            return last
        self.settles += 1
        self.bank.set_cable_tensions(st.tensions)
        rec = self._publish(t, readings, st)
        self.cells.update(rec.measured_N)
        return rec

    def wait_settled(self, timeout_s: float = 5.0) -> RigRecord:
        """Block until the served state is for the drives' current positions (polls with a
        deadline; settles itself without the rig's thread). TimeoutError if not."""
        if not self.plant_thread:
            return self.settle_now()
        deadline = time.monotonic() + timeout_s
        while True:
            readings = self.bank.drum_lengths_m()
            rec = self.last
            if float(np.max(np.abs(readings - rec.readings_m))) <= SETTLE_TOL_M:
                return rec
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"plant not settled within {timeout_s} s for readings "
                                   f"{np.round(readings, 6).tolist()}")
            with self._lock:
                self._lock.wait(min(left, 0.05))

    def _run(self) -> None:
        next_cell = time.monotonic()
        next_plant = next_cell
        while not self._stop.is_set():
            now = time.monotonic()
            if self.plant_thread and now >= next_plant:
                try:
                    self.settle_now()
                except Exception:  # keep the rig serving; the error is logged
                    log.exception("sim rig: plant step failed")
                took = time.monotonic() - now
                self.settle_s += took
                if took > self.plant_period_s:
                    self.late_settles += 1
                    if self.late_settles in (1, 10, 100) or self.late_settles % 1000 == 0:
                        log.warning("sim rig: the plant falls behind: a settle took %.1f ms, "
                                    "more than its %.1f ms period (%d times so far); lower "
                                    "the plant rate", 1e3 * took, 1e3 * self.plant_period_s,
                                    self.late_settles)
                next_plant = max(next_plant + self.plant_period_s, now)
            if now >= next_cell:
                self.cells.update(self.last.measured_N)
                next_cell = max(next_cell + self.cell_period_s, now)
            wake = min(next_cell, next_plant) if self.plant_thread else next_cell
            self._stop.wait(max(0.0, wake - time.monotonic()))


__all__ = ["RigRecord", "SimRig", "default_scenario"]
