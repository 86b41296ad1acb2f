"""One full hardware-in-the-loop cycle through the one hardware interface (hal/interface.py).

A cycle is what the controller's loop does with the simulated robot in lock-step:
``write_lengths`` (8 RPDOs + SYNC), wait for the 8 TPDOs, a synchronous read of all eight
load cells through the Modbus client (8 requests), and ``read()``.

``hil_cycle_ms``: the simulated robot (:class:`firmware_sim.rig.SimRig`) in this process,
CAN on python-can's ``virtual`` bus, load cells on Modbus/TCP over 127.0.0.1.
``hil_cycle_tcp_ms``: ``cdpr sim`` in another process, CAN through its socketcand hub and
Modbus/TCP, both over 127.0.0.1.
"""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from bench.benchmarks import median_time, register
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.rig import SimRig
from hal.interface import WinchHardware, open_hardware

ROOT = Path(__file__).resolve().parents[2]


def _cycle_s(hw: WinchHardware, repeat: int) -> float:
    hw.start()
    hw.enable()
    l0 = hw.read().lengths_m
    k = [0]

    def cycle() -> None:
        k[0] += 1
        hw.write_lengths(l0 + 0.002 * (1 - np.cos(2 * np.pi * k[0] * 0.004)))
        if not hw.wait_feedback(2.0):
            raise RuntimeError("a drive did not answer the SYNC: benchmark invalid")
        hw.sample_tensions()
        hw.read()

    t = median_time(cycle, repeat, warmup=20)
    r = hw.read()
    if r.faults or not r.ok:
        raise RuntimeError(f"faults during the benchmark: {[str(f) for f in r.faults]}")
    return t


def _in_process(repeat: int) -> float:
    with SimRig() as rig:
        hw = open_hardware(rig.can_spec, rig.modbus_spec, eds=EDS_PATH, clock="sync",
                           poll="manual")
        try:
            return _cycle_s(hw, repeat)
        finally:
            hw.close()


def _across_processes(repeat: int) -> float:
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", "sim", "--json", "--exit-on-stdin-eof"],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
        try:
            line = lines.get(timeout=30.0)
        except queue.Empty:
            line = ""
        if not line.strip():
            raise RuntimeError("cdpr sim did not print its endpoints")
        ep = json.loads(line)
        hw = open_hardware(ep["can"], ep["modbus"], eds=EDS_PATH, clock="sync", poll="manual")
        try:
            return _cycle_s(hw, repeat)
        finally:
            hw.close()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@register("hil")
def bench_hil(quick: bool) -> dict[str, float]:
    """Median of one full HIL cycle [ms] (8 RPDO + SYNC + 8 TPDO + 8 Modbus reads + read())."""
    repeat = 100 if quick else 1000
    return {
        "hil_cycle_ms": _in_process(repeat) * 1e3,
        "hil_cycle_tcp_ms": _across_processes(repeat) * 1e3,
    }
