"""HAL drives and a simulated rig in another process, across the socketcand hub (TCP).

The rig is ``python -m firmware_sim.drive_rig --port 0``; it prints its endpoint as one JSON
line. The controller side connects with python-can's own ``socketcand`` interface through
``--can socketcand:HOST:PORT``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from controller.winch import load_winches, metres_per_count
from firmware_sim.cia402_drive import EDS_PATH
from hal.can_bus import parse_can_spec
from hal.drives import BusLinkError, DriveState, WinchDrives

ROOT = Path(__file__).resolve().parents[1]
W = load_winches()


def start_rig(*args: str, timeout: float = 30.0) -> tuple[subprocess.Popen, dict]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim.drive_rig", "--port", "0", "--stdin-eof-exits",
         *args],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
    )
    line: list[str] = []
    reader = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    if not line or not line[0].strip():
        proc.kill()
        _, err = proc.communicate(timeout=5)
        raise AssertionError(f"rig did not print its endpoint: {err}")
    return proc, json.loads(line[0])


def stop_rig(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(timeout=5)


@pytest.fixture
def rig_process():
    proc, endpoint = start_rig("--lengths", "9.0", "10.0", "11.0", "12.0", "9.5", "10.5",
                               "11.5", "12.5")
    yield proc, endpoint
    stop_rig(proc)


def test_endpoint_line(rig_process):
    _, ep = rig_process
    assert ep["interface"] == "socketcand" and ep["host"] == "127.0.0.1" and ep["port"] > 0
    spec = parse_can_spec(ep["can"])
    assert (spec.host, spec.port, spec.channel) == ("127.0.0.1", ep["port"], "can0")
    assert ep["node_ids"] == list(range(1, 9)) and ep["clock"] == "sync"


def test_startup_and_setpoints_across_the_hub(rig_process):
    proc, ep = rig_process
    hal = WinchDrives.open(ep["can"], W, EDS_PATH, clock="sync")
    try:
        hal.start()
        np.testing.assert_allclose(hal.lengths_m(), [9, 10, 11, 12, 9.5, 10.5, 11.5, 12.5],
                                   atol=metres_per_count(W)[0])
        hal.enable_and_wait()
        assert np.all(hal.states() == DriveState.OPERATION_ENABLED)
        l0 = hal.lengths_m()
        amp = np.linspace(-0.05, 0.05, 8)
        ok = []
        for i in range(1, 201):
            cmd = l0 + amp * (1 - np.cos(2 * np.pi * i * 0.004 / 0.8))
            hal.set_lengths(cmd)
            ok.append(hal.step(timeout=2.0))
        for _ in range(10):
            ok.append(hal.step(timeout=2.0))
        assert all(ok)
        np.testing.assert_allclose(hal.lengths_m(), cmd, atol=2e-4)
        assert hal.faults() == [] and hal.events() == []
        hal.shutdown()
        assert np.all(hal.states() == DriveState.SWITCH_ON_DISABLED)
    finally:
        hal.close()
    assert stop_rig(proc) == 0


def test_rig_gone_is_reported_not_raised(rig_process):
    proc, ep = rig_process
    hal = WinchDrives.open(ep["can"], W, EDS_PATH, clock="sync")
    try:
        hal.start()
        hal.enable_and_wait()
        stop_rig(proc)
        for _ in range(80):  # 320 ms of SYNC clock > 3 heartbeat periods
            hal.exchange()
            time.sleep(0.001)
        kinds = [(e.node_id, e.kind) for e in hal.events()]
        assert kinds == [(0, "link_lost")]
        assert np.all(hal.states() == DriveState.UNKNOWN)
        assert sorted({f.node_id for f in hal.faults() if f.kind == "link_lost"}) == list(
            range(1, 9))
        with pytest.raises(BusLinkError, match=ep["can"]):
            hal.recover()
    finally:
        hal.close()
