"""The simulated robot a dry run runs against: drives, load cells, tracker and plant.

``kind="inprocess"``: a :class:`firmware_sim.rig.SimRig` in this process on python-can's
``virtual`` bus, Modbus/TCP on loopback, the tracker called directly. Without real time
(``clock="sync"``) the world advances in lock-step with the loop: the drives' clock moves
by one SYNC period per SYNC, and :meth:`SimWorld.tick` settles the plant and sweeps the
load cells every ``1/plant_rate_hz`` seconds of simulated time (deterministic, as fast as
the machine allows). In real time the rig's own threads do it on the wall clock.

``kind="process"``: ``cdpr sim`` in another process (socketcand hub, Modbus/TCP, tracker
over TCP) that writes its site (``--write-site``); the loop reaches it through
:class:`bench.dryrun.hardware.HardwareWorld` on that site, exactly as it reaches real
drives. The process ends with this one (stdin closes when we die, whatever the signal).
Its drives follow the master's SYNC (``--clock sync``) in real time too, as a HIL
simulator does: a SYNC the starved simulator handles late delays the simulated world
instead of tripping a drive deadline; in real time its threads run in ``SCHED_FIFO`` one
priority below the loop's when permitted (:mod:`bench.dryrun.realtime`).

The scenario is the truth: the world reads it, the controller never does.
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.dryrun.hardware import (  # noqa: F401  (re-exported for the worlds' users)
    LOCKSTEP_CELL_TIMEOUT_S,
    PROCESS_CELL_MAX_AGE_S,
    HardwareWorld,
    World,
    cell_timing,
    with_rate,
)
from bench.dryrun.lockstep_bus import deliver_in_sender_thread
from bench.dryrun.realtime import DEFAULT_RT_PRIORITY, helper_priority
from controller.winch import WinchSet
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.rig import SimRig
from firmware_sim.scenario import Scenario
from hal.can_bus import open_bus
from hal.interface import CanModbusHardware, open_hardware
from hal.site import load_site, merge_site
from hal.tracker import CallableTracker, Tracker

_cell_timing = cell_timing  # the name the simulated worlds used


class SimWorld(World):
    """The simulated robot: ``hw`` (the hardware interface), ``tracker``, ``tick`` (lock-step
    hook or None), ``rig`` (in-process only), ``close()``."""

    hw: CanModbusHardware
    tracker: Tracker
    rig: SimRig | None = None
    info: dict


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
            # lock-step: the plant's time is the drives' SYNC clock, the HAL's
            self.tracker = CallableTracker(self.rig.measure_pose,
                                           on_hardware_clock=not realtime)
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


class SimProcess:
    """``cdpr sim`` in a child process that wrote its site (``--write-site``) to a private
    temporary folder: :attr:`site` (the file), :attr:`info` (its endpoints line). The
    process ends with :meth:`stop` or with this one (stdin closes when we die, whatever the
    signal). ``args``: extra command-line options for it. The simulator follows the
    master's SYNC (``--clock sync``) in lock-step and in real time, as a HIL simulator does;
    in real time its threads run in SCHED_FIFO one below the loop's ``rt_priority``."""

    def __init__(self, scenario_path: str | Path | None, realtime: bool, plant_rate_hz: float,
                 args: tuple[str, ...] = (), startup_s: float = 60.0,
                 rt_priority: int = DEFAULT_RT_PRIORITY) -> None:
        self._err = tempfile.TemporaryFile(mode="w+")
        self._dir = tempfile.TemporaryDirectory(prefix="cdpr-sim-site-")
        self.site = Path(self._dir.name) / "sim.toml"
        sim_priority = helper_priority(rt_priority) if realtime else 0
        cmd = [sys.executable, "-m", "bench.cli", "sim", "--json", "--exit-on-stdin-eof",
               "--clock", "sync", "--rt-priority", str(sim_priority),
               "--plant-rate", str(plant_rate_hz), "--write-site", str(self.site), *args]
        if scenario_path is not None:
            cmd.insert(4, str(scenario_path))
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._err, text=True, env=env)
        try:
            self.info = self._endpoints(startup_s)
        except BaseException:
            self.stop()
            raise

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

    def stop(self) -> None:
        """End the process (stdin closed, then SIGTERM, then SIGKILL) and remove its site."""
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
        self._dir.cleanup()


class ProcessWorld(SimWorld):
    """``cdpr sim`` in a child process (:class:`SimProcess`), reached exactly as real
    hardware is: a :class:`HardwareWorld` on the site it wrote (``eds`` overrides the
    site's EDS)."""

    def __init__(self, scenario_path: str | Path | None, winches: WinchSet, realtime: bool,
                 plant_rate_hz: float, eds: str | Path | None = None,
                 args: tuple[str, ...] = (), startup_s: float = 60.0,
                 rt_priority: int = DEFAULT_RT_PRIORITY) -> None:
        self.sim = SimProcess(scenario_path, realtime, plant_rate_hz, args, startup_s,
                              rt_priority)
        self.rig = None
        try:
            settings = merge_site(load_site(self.sim.site), eds=eds)
            self._hardware = HardwareWorld(settings, winches, realtime)
        except BaseException:
            self.sim.stop()
            raise
        self.hw, self.tracker = self._hardware.hw, self._hardware.tracker
        self.info = dict(self.sim.info, kind="process")

    @property
    def proc(self) -> subprocess.Popen:
        return self.sim.proc

    def close(self) -> None:
        try:
            self._hardware.close()
        finally:
            self.sim.stop()


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
        return ProcessWorld(path, winches, realtime, plant_rate_hz,
                            None if eds == EDS_PATH else eds, sim_args,
                            rt_priority=rt_priority)
    raise ValueError(f"rig must be 'inprocess' or 'process', got {kind!r}")
