"""The eight simulated winch drives of a rig, on one CAN bus, with their physical state.

:class:`SimulatedWinchBank` puts one :class:`~firmware_sim.cia402_drive.SimulatedDrive`
per winch (node ids and mechanics from the winch parameter file) on a python-can bus and
exposes the physical state a plant model couples to: positions in counts, cable lengths
in metres (through :mod:`controller.winch`), and the cable tensions the motors feel.

Clock: ``clock=None`` (default) is deterministic: the drives advance on every SYNC by the
SYNC period they were configured with (0x1006), and :meth:`SimulatedWinchBank.advance`
lets time pass without SYNC. With ``clock=time.monotonic`` the drives follow wall time and
a ticker thread keeps heartbeats and motion going between SYNCs. On the SYNC clock the
ticker does the drives' real-time duties (:meth:`SimulatedDrive.wall_tick`): heartbeats at
least once per period of wall time, consumer heartbeats watched on wall time, and the stop
after a master loss carried out on wall time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import canopen
import numpy as np

from controller.winch import WinchSet, counts_to_m, load_winches, m_to_counts, metres_per_count
from firmware_sim.cia402_drive import EDS_PATH, SimulatedDrive


class SimulatedWinchBank:
    """Simulated CiA 402 drives of all winches on ``bus`` (the bank owns and closes the bus)."""

    def __init__(
        self,
        bus: can.BusABC,
        winches: WinchSet | None = None,
        eds: str | Path = EDS_PATH,
        clock: Callable[[], float] | None = None,
        tick_period_s: float = 0.002,
        wall_tick_period_s: float = 0.01,
    ) -> None:
        self.winches = winches if winches is not None else load_winches()
        self.lock = threading.RLock()
        self.clock = clock
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.05  # quick shutdown
        self.drives: list[SimulatedDrive] = [
            SimulatedDrive(
                self.winches.axis(k),
                eds=eds,
                lock=self.lock,
                clock=clock,
                default_cycle_s=self.winches.bus.sync_period_s,
            )
            for k in range(len(self.winches))
        ]
        for d in self.drives:
            d.attach(self.network)
            if clock is not None:  # starvation: a few of our ticks missed (see the drive)
                d.starved_s = max(SimulatedDrive.CLOCK_STARVED_S, 4.0 * tick_period_s)
        self._sync_callbacks: list[Callable[[SimulatedWinchBank], None]] = []
        self.network.subscribe(0x80, self._after_sync)
        self.network.connect()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None
        self._tick_period = tick_period_s if clock is not None else wall_tick_period_s

    # ------------------------------------------------------------------ life cycle

    def start(self) -> SimulatedWinchBank:
        """Power all drives on (each sends its boot-up message)."""
        for d in self.drives:
            d.power_on()
        if self._ticker is None:
            self._ticker = threading.Thread(target=self._tick_loop, name="drive-bank-tick",
                                            daemon=True)
            self._ticker.start()
        return self

    def close(self) -> None:
        """Stop the ticker and the network (shuts the bus down)."""
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join(timeout=2.0)
        self.network.disconnect()

    def __enter__(self) -> SimulatedWinchBank:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _frames_waiting(self) -> bool:
        """Frames received on the bus and not yet handed to the drives (a python-can
        virtual bus's queue; other buses: unknown, False)."""
        q = getattr(self.network.bus, "queue", None)
        return bool(q is not None and hasattr(q, "qsize") and q.qsize())

    def _tick_loop(self) -> None:
        while not self._stop.wait(self._tick_period):
            if self.clock is not None:
                if self._frames_waiting():
                    # the master's frames are waiting for this process: their handling
                    # judges the deadlines (after them), not this tick (before them)
                    continue
                for d in self.drives:
                    d.tick()
            else:
                now = time.monotonic()
                for d in self.drives:
                    d.wall_tick(now)

    def _after_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        for fn in list(self._sync_callbacks):
            fn(self)

    def add_sync_callback(self, fn: Callable[[SimulatedWinchBank], None]) -> None:
        """Call ``fn(bank)`` after the drives processed each SYNC (e.g. to step a plant)."""
        self._sync_callbacks.append(fn)

    # ------------------------------------------------------------------ access

    def drive(self, node_id: int) -> SimulatedDrive:
        """The drive with CAN node id ``node_id``."""
        for d in self.drives:
            if d.node_id == node_id:
                return d
        raise KeyError(f"no simulated drive with node id {node_id}")

    def drive_of_cable(self, cable: str) -> SimulatedDrive:
        """The drive of cable ``cable`` (e.g. ``"21"``)."""
        return self.drives[self.winches.cables.index(cable)]

    def advance(self, dt_s: float) -> None:
        """Let ``dt_s`` seconds pass without SYNC (deterministic clock only)."""
        with self.lock:
            for d in self.drives:
                d.advance(dt_s)

    # ------------------------------------------------------------------ physical state

    def positions_counts(self) -> np.ndarray:
        """Actual positions [counts] (0x6064), shape (n,)."""
        with self.lock:
            return np.array([d.axis.pos for d in self.drives])

    def drum_counts(self) -> np.ndarray:
        """The drums' physical positions [counts], shape (n,): the actual positions less
        what a homing changed in the count (:meth:`SimulatedDrive.drum_counts`)."""
        with self.lock:
            return np.array([d.drum_counts() for d in self.drives])

    def drum_lengths_m(self) -> np.ndarray:
        """The physical cable lengths [m] of the drums (what the plant sees), through the
        winch parameters; equal to :meth:`positions_m` until a homing moves a count."""
        return counts_to_m(self.drum_counts(), self.winches)

    def velocities_counts(self) -> np.ndarray:
        """Actual velocities [counts/s], shape (n,)."""
        with self.lock:
            return np.array([d.axis.vel for d in self.drives])

    def positions_m(self) -> np.ndarray:
        """Cable lengths [m] of the actual positions, through the winch parameters."""
        return counts_to_m(self.positions_counts(), self.winches)

    def velocities_m_s(self) -> np.ndarray:
        """Cable speeds [m/s] (positive: paying out)."""
        return self.winches.direction * self.velocities_counts() * metres_per_count(self.winches)

    def set_positions_counts(self, counts: np.ndarray) -> None:
        """Move the axes to ``counts`` (actual and demand together, nothing is commanded)."""
        c = np.broadcast_to(np.asarray(counts, dtype=float), (len(self.drives),))
        with self.lock:
            for d, x in zip(self.drives, c, strict=True):
                d.set_position_counts(float(x))

    def set_positions_m(self, lengths_m: np.ndarray) -> None:
        """Move the axes so that the cables read ``lengths_m`` [m]."""
        self.set_positions_counts(m_to_counts(lengths_m, self.winches))

    def set_cable_tensions(self, tensions_n: np.ndarray) -> None:
        """Cable tensions [N] the motors hold (torque actual 0x6077 = T r / gear)."""
        t = np.broadcast_to(np.asarray(tensions_n, dtype=float), (len(self.drives),))
        torque = t * self.winches.drum_radius_m / self.winches.gear_ratio
        with self.lock:
            for d, tq in zip(self.drives, torque, strict=True):
                d.load_torque_nm = float(tq)
