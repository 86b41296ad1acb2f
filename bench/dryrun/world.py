"""The simulated robot a dry run runs against: drives, load cells, tracker and plant.

``kind="inprocess"``: a :class:`firmware_sim.rig.SimRig` in this process on python-can's
``virtual`` bus, Modbus/TCP on loopback, the tracker called directly. Without real time
(``clock="sync"``) the world advances in lock-step with the loop: the drives' clock moves
by one SYNC period per SYNC, and :meth:`SimWorld.tick` settles the plant and sweeps the
load cells every ``1/plant_rate_hz`` seconds of simulated time (deterministic, as fast as
the machine allows). In real time the rig's own threads do it on the wall clock.

``kind="process"``: ``cdpr sim`` in another process (socketcand hub, Modbus/TCP, tracker
over TCP); the loop reaches it only through the wire protocols, as it would reach real
drives. The process ends with this one (stdin closes when we die, whatever the signal).
Its drives follow the master's SYNC (``--clock sync``) in real time too, as a HIL
simulator does: a SYNC the starved simulator handles late delays the simulated world
instead of tripping a drive deadline; in real time its threads run in ``SCHED_FIFO`` one
priority below the loop's when permitted (:mod:`bench.dryrun.realtime`).

The scenario is the truth: the world reads it, the controller never does.
"""

from __future__ import annotations

import dataclasses
import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.dryrun.lockstep_bus import deliver_in_sender_thread
from bench.dryrun.realtime import DEFAULT_RT_PRIORITY, helper_priority
from controller.winch import WinchSet
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.rig import SimRig
from firmware_sim.scenario import Scenario
from hal.can_bus import open_bus
from hal.interface import CanModbusHardware, open_hardware
from hal.tracker import CallableTracker, Tracker, open_tracker


def with_rate(winches: WinchSet, period_s: float) -> WinchSet:
    """The winch set with its SYNC period (control cycle) set to ``period_s`` [s]; the
    drives' RPDO deadline follows (1.5 periods, as the shipped file has it)."""
    bus = winches.bus
    ratio = bus.rpdo_timeout_s / bus.sync_period_s if bus.sync_period_s else 1.5
    period_s = round(period_s * 1e6) * 1e-6
    rpdo = 0.0 if bus.rpdo_timeout_s == 0 else max(1e-3, round(ratio * period_s, 3))
    return dataclasses.replace(winches, bus=dataclasses.replace(
        bus, sync_period_s=period_s, rpdo_timeout_s=rpdo))


#: the HAL's load-cell answer timeout [s, wall clock] in lock-step: the simulation waits
#: for its answers, so a slow answer means a busy host, not a slow cell
LOCKSTEP_CELL_TIMEOUT_S = 0.5
#: lock-step with ``cdpr sim`` in another process: the HAL polls the cells from a thread on
#: the wall clock while the simulation runs at its own pace; a reading older than this
#: [s, wall] is a timeout
PROCESS_CELL_MAX_AGE_S = 1.0


def _cell_timing(realtime: bool, in_process: bool) -> dict:
    """open_hardware's load-cell timing: the defaults in real time; in lock-step a patient
    answer timeout and, in process (polled by the world, aged on the simulated clock), the
    default age limit; across processes (aged on the wall clock) a patient one."""
    if realtime:
        return {}
    rate = 50.0
    return {"loadcell_rate_hz": rate, "loadcell_timeout_s": LOCKSTEP_CELL_TIMEOUT_S,
            "loadcell_max_age_s": 0.1 + 3.0 / rate if in_process else PROCESS_CELL_MAX_AGE_S}


class SimWorld:
    """The simulated robot: ``hw`` (the hardware interface), ``tracker``, ``tick`` (lock-step
    hook or None), ``rig`` (in-process only), ``close()``."""

    hw: CanModbusHardware
    tracker: Tracker
    rig: SimRig | None = None
    info: dict

    def tick(self) -> None:  # lock-step hook, per kind
        return None

    def close(self) -> None:
        raise NotImplementedError

    def _close_all(self, stop_sim) -> None:
        """Tracker, then the HAL, then the simulation, each even when the one before fails."""
        try:
            try:
                self.tracker.close()
            finally:
                self.hw.close()
        finally:
            stop_sim()

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class InProcessWorld(SimWorld):
    def __init__(self, scenario: Scenario, winches: WinchSet, realtime: bool,
                 plant_rate_hz: float, eds: str | Path = EDS_PATH) -> None:
        clock = "wall" if realtime else "sync"
        # the drives on the HAL's virtual bus (a cheap copy of each frame, python-can's
        # deep-copies it), on a channel of their own
        can_spec = f"virtual:dryrun-{os.getpid()}-{id(self):x}"
        bus = open_bus(can_spec)
        try:
            self.rig = SimRig(scenario, winches=winches, clock=clock, plant_thread=realtime,
                              plant_rate_hz=plant_rate_hz, watch_wall_heartbeats=realtime,
                              bus=bus)
        except BaseException:
            bus.shutdown()
            raise
        try:
            # lock-step: each frame handed to its receiver in the sending thread, no thread
            # hand-off per frame (the same frames and callbacks); switched before any traffic
            lockstep_rx = [] if realtime else [deliver_in_sender_thread(self.rig.bank.network)]
            self.rig.start()
            self.hw = open_hardware(can_spec, self.rig.modbus_spec, eds=eds,
                                    winches=winches, clock=clock,
                                    poll="thread" if realtime else "manual",
                                    **_cell_timing(realtime, True))
            if not realtime:  # before the HAL starts (only boot-ups and heartbeats so far)
                lockstep_rx.append(deliver_in_sender_thread(self.hw.drives.network))
            self.lockstep_rx = tuple(lockstep_rx)  #: frames delivered (direct, deferred)
            self.tracker = CallableTracker(self.rig.measure_pose)
        except BaseException:
            self.rig.close()
            raise
        self.info = dict(self.rig.endpoints(), can=can_spec, virtual=can_spec, kind="inprocess")
        self._plant_period = 1.0 / plant_rate_hz
        self._next_plant = 0.0
        self.lockstep = not realtime

    def tick(self) -> None:
        """Lock-step: settle the plant and sweep the load cells when the plant is due."""
        t_s = self.rig.time_s()
        if not self.lockstep or t_s + 1e-9 < self._next_plant:
            return
        self.rig.settle_now()
        self.hw.sample_tensions()
        self._next_plant += self._plant_period * max(1, int((t_s - self._next_plant)
                                                            / self._plant_period) + 1)

    def close(self) -> None:
        self._close_all(self.rig.close)


class ProcessWorld(SimWorld):
    """``cdpr sim`` in a child process; ``args`` extra command-line options for it;
    ``rt_priority`` the loop's real-time priority (the simulator's threads one below)."""

    def __init__(self, scenario_path: str | Path | None, winches: WinchSet, realtime: bool,
                 plant_rate_hz: float, eds: str | Path = EDS_PATH,
                 args: tuple[str, ...] = (), startup_s: float = 60.0,
                 rt_priority: int = DEFAULT_RT_PRIORITY) -> None:
        self._err = tempfile.TemporaryFile(mode="w+")
        sim_priority = helper_priority(rt_priority) if realtime else 0
        cmd = [sys.executable, "-m", "bench.cli", "sim", "--json", "--exit-on-stdin-eof",
               "--clock", "sync", "--rt-priority", str(sim_priority),
               "--plant-rate", str(plant_rate_hz), *args]
        if scenario_path is not None:
            cmd.insert(4, str(scenario_path))
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._err, text=True, env=env)
        self.rig = None
        try:
            self.info = self._endpoints(startup_s)
            clock = "wall" if realtime else "sync"
            self.hw = open_hardware(self.info["can"], self.info["modbus"], eds=eds,
                                    winches=winches, clock=clock, poll="thread",
                                    **_cell_timing(realtime, False))
            self.tracker = open_tracker(self.info["tracker"])
        except BaseException:
            self._stop()
            raise
        self.info["kind"] = "process"

    def _endpoints(self, timeout_s: float) -> dict:
        lines: queue.Queue[str | None] = queue.Queue()

        def read() -> None:
            assert self.proc.stdout is not None
            for line in self.proc.stdout:
                lines.put(line)
            lines.put(None)

        threading.Thread(target=read, name="sim-stdout", daemon=True).start()
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                line = lines.get(timeout=max(0.05, deadline - time.monotonic()))
            except queue.Empty:
                raise TimeoutError(f"cdpr sim gave no endpoints in {timeout_s} s: "
                                   f"{self._stderr()}") from None
            if line is None:
                raise RuntimeError(f"cdpr sim ended at start-up (exit "
                                   f"{self.proc.wait()}): {self._stderr()}")
            try:
                info = json.loads(line)
            except json.JSONDecodeError:
                continue
            if "error" in info:
                raise RuntimeError(f"cdpr sim: {info['error']}")
            return info

    def _stderr(self) -> str:
        self._err.seek(0)
        text = self._err.read().strip()
        return text[-2000:] if text else "(nothing on stderr)"

    def _stop(self) -> None:
        p = self.proc
        if p.poll() is None:
            try:
                assert p.stdin is not None
                p.stdin.close()  # --exit-on-stdin-eof
            except OSError:
                pass
            try:
                p.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                p.terminate()
                try:
                    p.wait(timeout=5.0)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        self._err.close()

    def close(self) -> None:
        self._close_all(self._stop)


def start_world(scenario: Scenario, winches: WinchSet, kind: str = "inprocess",
                realtime: bool = False, plant_rate_hz: float = 20.0,
                eds: str | Path = EDS_PATH, sim_args: tuple[str, ...] = (),
                rt_priority: int = DEFAULT_RT_PRIORITY) -> SimWorld:
    """The simulated robot for a dry run (see the module docstring); ``rt_priority``: the
    loop's real-time priority (a ``process`` simulator's threads run one below)."""
    if kind == "inprocess":
        return InProcessWorld(scenario, winches, realtime, plant_rate_hz, eds)
    if kind == "process":
        path = scenario.path if scenario.path.name != "<memory>" else None
        return ProcessWorld(path, winches, realtime, plant_rate_hz, eds, sim_args,
                            rt_priority=rt_priority)
    raise ValueError(f"rig must be 'inprocess' or 'process', got {kind!r}")
