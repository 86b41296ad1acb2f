"""The robot a dry run runs against when it is given buses: :class:`HardwareWorld`.

It opens the buses of a site (``--site``, ``--can``, ``--modbus``, ``--tracker``;
:class:`hal.site.HardwareSettings`) and starts nothing: no simulator, no hub. Behind the
buses may be the real winches or a ``cdpr sim`` process (``--rig process`` is exactly
that: ``cdpr sim --write-site``, then this world on its site). Nothing here imports
``firmware_sim`` (a test says so).

Also the parts every world shares: :func:`with_rate` (the winch set at the dry run's
control rate) and the load-cell timing in lock-step (:func:`cell_timing`).
"""

from __future__ import annotations

import dataclasses

from controller.winch import WinchSet
from hal.interface import CanModbusHardware, open_hardware
from hal.site import HardwareSettings
from hal.tracker import Tracker, open_tracker


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


def cell_timing(realtime: bool, in_process: bool) -> dict:
    """open_hardware's load-cell timing: the defaults in real time; in lock-step a patient
    answer timeout and, in process (polled by the world, aged on the simulated clock), the
    default age limit; across processes (aged on the wall clock) a patient one."""
    if realtime:
        return {}
    rate = 50.0
    return {"loadcell_rate_hz": rate, "loadcell_timeout_s": LOCKSTEP_CELL_TIMEOUT_S,
            "loadcell_max_age_s": 0.1 + 3.0 / rate if in_process else PROCESS_CELL_MAX_AGE_S}


class World:
    """What a dry run runs against: ``hw`` (the hardware interface), ``tracker``, ``tick``
    (lock-step hook, None-like for hardware), ``rig`` (a simulated rig in this process, or
    None), ``info`` (endpoints, plain data), ``close()``."""

    hw: CanModbusHardware
    tracker: Tracker
    rig = None
    info: dict

    def tick(self) -> None:  # lock-step hook, per kind
        return None

    def close(self) -> None:
        raise NotImplementedError

    def _close_all(self, stop_sim) -> None:
        """Tracker, then the HAL, then the simulation, each even when the one before fails."""
        try:
            try:
                if self.tracker is not None:
                    self.tracker.close()
            finally:
                self.hw.close()
        finally:
            stop_sim()

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class HardwareWorld(World):
    """The buses of ``settings`` opened, nothing started (see the module docstring).

    ``winches``: the winch set at the dry run's rate; ``realtime``: the loop runs on the
    wall clock; the master's clock is ``settings.hal_clock`` ("sync": lock-step with drives
    that follow the master's SYNC, e.g. ``cdpr sim --clock sync``). ``cells``: load-cell
    timing (:func:`open_hardware`'s keywords) where the defaults do not fit.
    """

    def __init__(self, settings: HardwareSettings, winches: WinchSet, realtime: bool,
                 cells: dict | None = None) -> None:
        if settings.can is None:
            raise ValueError("no CAN bus: give --can SPEC or a --site with [can] interface")
        if not settings.eds:
            raise ValueError("no EDS of the winch drives: give --eds or a --site with "
                             "[drives] eds")
        timing = cells if cells is not None else cell_timing(
            realtime or settings.hal_clock == "wall", False)
        self.hw = open_hardware(settings.can, settings.modbus, eds=settings.eds,
                                winches=winches, register_map=settings.loadcell_map,
                                calibration=settings.loadcell_calibration,
                                clock=settings.hal_clock, poll="thread", **timing)
        try:
            self.tracker = open_tracker(settings.tracker)
        except BaseException:
            self.hw.close()
            raise
        self.info = {"can": str(settings.can),
                     "modbus": None if settings.modbus is None else str(settings.modbus),
                     "tracker": None if settings.tracker is None else str(settings.tracker),
                     "clock": settings.hal_clock, "kind": "hardware",
                     "site": None if settings.site is None else str(settings.site.path)}

    def close(self) -> None:
        self._close_all(lambda: None)


__all__ = ["HardwareWorld", "LOCKSTEP_CELL_TIMEOUT_S", "PROCESS_CELL_MAX_AGE_S", "World",
           "cell_timing", "with_rate"]
