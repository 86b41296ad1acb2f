"""Shipped dry-run scenarios, by name, and the choice of the control rate.

A dry-run scenario is a ``cdpr-scenario/1`` file (firmware_sim/scenario.py) that names
the path the controller follows (``path = "paper-centre"``). Shipped ones live in
``bench/data/scenarios/``: ``paper-centre`` (ROCASPECT as the paper found it, nominal
model, the paper's centre path initialised in the centre) and ``paper-calibration`` (the
same robot and model, a calibration campaign of dwells whose recording ``cdpr diagnose``
turns into a corrected robot.toml).
"""

from __future__ import annotations

import math
from pathlib import Path

from controller.winch import WinchSet
from hal.bus_load import CycleConfig
from hal.drives_config import DriveConfigError, interpolation_period

SCENARIO_DIR = Path(__file__).resolve().parents[1] / "data" / "scenarios"

#: the bus load the default rate keeps (CiA 301 practice: leave half the bus for the rest)
DEFAULT_BUS_LOAD = 0.5


def shipped_scenarios() -> dict[str, Path]:
    """Shipped scenario names -> files."""
    return {p.stem: p for p in sorted(SCENARIO_DIR.glob("*.toml"))}


def resolve_scenario(name_or_path: str | Path) -> Path:
    """A scenario file: an existing path, or a shipped scenario's name. FileNotFoundError
    naming the shipped ones otherwise."""
    p = Path(name_or_path)
    if p.exists():
        return p
    shipped = shipped_scenarios()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    raise FileNotFoundError(f"{name_or_path}: no such scenario file, nor a shipped scenario "
                            f"(shipped: {', '.join(shipped) or 'none'})")


def bus_config(winches: WinchSet) -> CycleConfig:
    """The synchronous cycle of the winch bus: one RPDO and one TPDO per drive, a SYNC,
    and the drives' heartbeats as background traffic."""
    return CycleConfig(bitrate=winches.bus.bitrate, n_drives=len(winches),
                       heartbeat_period_s=winches.bus.heartbeat_period_s)


def max_rate_hz(winches: WinchSet, load: float = DEFAULT_BUS_LOAD) -> float:
    """Highest control rate [Hz] the CAN bus load allows: the shortest SYNC period the
    drives can be given (whole microseconds in 0x1006, and ``value * 10^index`` s with
    value 1..255 in 0x60C2) that keeps the load within ``load``."""
    hz = bus_config(winches).max_sync_rate_hz(load)
    if hz <= 0:
        return 0.0
    return 1e6 / sync_period_us(hz)


def sync_period_us(rate_hz: float) -> int:
    """The shortest SYNC period [us] at or above ``1/rate_hz`` that a CiA 402 drive can be
    given (0x1006 in whole microseconds, 0x60C2 as ``value * 10^index`` s, value 1..255)."""
    period_us = math.ceil(1e6 / rate_hz - 1e-6)
    while True:
        try:
            interpolation_period(period_us)
        except DriveConfigError:
            period_us += 1
            continue
        return period_us
