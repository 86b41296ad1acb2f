"""CAN bus cycle of the winch drives: 8 RPDOs + SYNC + 8 TPDOs, HAL against simulated drives.

``hil_can_cycle_ms``: one lock-step cycle (``WinchDrives.step``: exchange, then wait for the
eight TPDOs) with the drives in the same process on python-can's ``virtual`` bus.
``hil_can_cycle_tcp_ms``: the same with the rig in another process behind the socketcand
hub (``python -m firmware_sim.drive_rig``), over TCP on 127.0.0.1.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import can
import numpy as np

from bench.benchmarks import median_time, register
from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.drive_bank import SimulatedWinchBank
from hal.drives import WinchDrives

ROOT = Path(__file__).resolve().parents[2]


def _cycle_s(hal: WinchDrives, repeat: int) -> float:
    l0 = hal.lengths_m()
    k = [0]

    def cycle() -> None:
        k[0] += 1
        hal.set_lengths(l0 + 0.01 * (1 - np.cos(2 * np.pi * k[0] * 0.004)))
        if not hal.step(timeout=2.0):
            raise RuntimeError("a drive did not answer the SYNC: benchmark invalid")

    t = median_time(cycle, repeat, warmup=20)
    if hal.faults():
        raise RuntimeError(f"drive faults during the benchmark: {hal.faults()}")
    return t


def _in_process(repeat: int) -> float:
    w = load_winches()
    ch = f"bench-hil-can-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), w)
    bank.set_positions_m(np.full(len(w), 10.0))
    bank.start()
    hal = WinchDrives.open(f"virtual:{ch}", w, EDS_PATH, clock="sync")
    try:
        hal.start()
        hal.enable_and_wait()
        return _cycle_s(hal, repeat)
    finally:
        hal.close()
        bank.close()


def _across_hub(repeat: int) -> float:
    w = load_winches()
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim.drive_rig", "--port", "0", "--stdin-eof-exits"],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        line: list[str] = []
        t = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
        t.start()
        t.join(30.0)
        if not line or not line[0].strip():
            raise RuntimeError("the drive rig did not start")
        endpoint = json.loads(line[0])
        hal = WinchDrives.open(endpoint["can"], w, EDS_PATH, clock="sync")
        try:
            hal.start()
            hal.enable_and_wait()
            return _cycle_s(hal, repeat)
        finally:
            hal.close()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@register("hil_can")
def bench_hil_can(quick: bool) -> dict[str, float]:
    """Median time of one CAN bus cycle (8 RPDO + SYNC + 8 TPDO) [ms], in-process and over TCP."""
    repeat = 100 if quick else 1000
    return {
        "hil_can_cycle_ms": _in_process(repeat) * 1e3,
        "hil_can_cycle_tcp_ms": _across_hub(repeat) * 1e3,
    }
