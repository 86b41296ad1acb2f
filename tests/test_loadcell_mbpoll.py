"""The standalone simulated load cells in another process, read by mbpoll and by the HAL."""

from __future__ import annotations

import json
import re
import selectors
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from hal.loadcell_client import CableStatus, LoadCellClient

ROOT = Path(__file__).resolve().parents[1]
# Exactly representable in float32 with few digits, so mbpoll's printout compares exactly.
FED = [101.5, 202.25, 303.125, 44.0, 5.5, 666.75, 2999.5, 0.25]
MBPOLL = shutil.which("mbpoll")


def start_server(*args: str, deadline_s: float = 20.0):
    """Start ``python -m firmware_sim.loadcell_server`` and return (process, its JSON line)."""
    err = tempfile.TemporaryFile(mode="w+")  # a file, not a pipe: it cannot fill up
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim.loadcell_server", "--port", "0", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=err,
        text=True,
    )
    proc.err = err  # type: ignore[attr-defined]
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + deadline_s
    line = ""
    while not line.endswith("\n"):
        left = end - time.monotonic()
        if left <= 0 or not sel.select(left):
            proc.kill()
            raise AssertionError(f"no endpoint line within {deadline_s} s: {stderr_of(proc)}")
        chunk = proc.stdout.readline()
        if not chunk:
            proc.wait(5)
            raise AssertionError(f"server exited {proc.returncode}: {stderr_of(proc)}")
        line += chunk
    return proc, json.loads(line)


def stderr_of(proc: subprocess.Popen) -> str:
    proc.err.seek(0)  # type: ignore[attr-defined]
    return proc.err.read()  # type: ignore[attr-defined]


def stop_server(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


@pytest.fixture
def standalone():
    procs = []

    def start(*args: str):
        proc, info = start_server(*args)
        procs.append(proc)
        return info

    yield start
    for p in procs:
        stop_server(p)
        assert p.returncode == 0, stderr_of(p)


def mbpoll(*args: str) -> str:
    out = subprocess.run(
        [MBPOLL, "-m", "tcp", "-0", "-1", "-o", "2", *args],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def parse_mbpoll(text: str) -> dict[int, list[float]]:
    """``{unit id: [values]}`` from mbpoll's printout."""
    result: dict[int, list[float]] = {}
    unit = None
    for line in text.splitlines():
        if m := re.match(r"-- Polling slave (\d+)", line):
            unit = int(m.group(1))
            result[unit] = []
        elif (m := re.match(r"\[(\d+)\]:\s+(\S+)", line)) and unit is not None:
            result[unit].append(float(m.group(2)))
    return result


def test_standalone_prints_its_endpoint(standalone):
    info = standalone("--tensions", ",".join(map(str, FED)))
    assert info["endpoint"] == f"127.0.0.1:{info['port']}" and info["port"] > 0
    assert info["units"] == {"11": 1, "12": 2, "21": 3, "22": 4, "31": 5, "32": 6, "41": 7, "42": 8}
    assert info["tensions_N"] == FED
    rtu = standalone("--rtu")
    assert rtu["endpoint"] == f"rtu-tcp:127.0.0.1:{rtu['port']}"


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (apt-get install mbpoll)")
def test_mbpoll_reads_the_fed_tensions(standalone):
    info = standalone("--tensions", ",".join(map(str, FED)), "--fault", "21:sensor_fault")
    port = str(info["port"])
    floats = parse_mbpoll(
        mbpoll("-a", "1:8", "-t", "3:float", "-B", "-r", "0", "-c", "1", "-p", port, "127.0.0.1")
    )
    assert floats == {k + 1: [v] for k, v in enumerate(FED)}
    words = parse_mbpoll(
        mbpoll("-a", "1,3", "-t", "3", "-r", "2", "-c", "2", "-p", port, "127.0.0.1")
    )
    assert words[1][0] == 0 and words[3][0] == 2  # status: cable 21 has bit 1 (sensor fault)
    assert words[1][1] >= 1  # sample counter


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (apt-get install mbpoll)")
def test_mbpoll_gets_an_exception_for_holding_registers(standalone):
    info = standalone()
    out = subprocess.run(
        [MBPOLL, "-m", "tcp", "-0", "-1", "-o", "2", "-a", "1", "-t", "4", "-r", "0",
         "-p", str(info["port"]), "127.0.0.1"],
        capture_output=True, text=True, timeout=60,
    )
    assert "Illegal function" in out.stdout + out.stderr


@pytest.mark.parametrize("framing", ["tcp", "rtu-tcp"])
def test_hal_client_reads_the_standalone_process(standalone, framing):
    info = standalone("--source", "sine", "--rate", "100", *(["--rtu"] if framing != "tcp" else []))
    with LoadCellClient(info["endpoint"], rate_hz=50, stale_s=2.0) as client:
        assert client.wait_sweeps(3)
        r1 = r2 = client.read()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # until every counter has moved on
            client.wait_sweeps(1)
            r2 = client.read()
            if np.all(r2.counter != r1.counter):
                break
    for r in (r1, r2):
        assert r.all_ok, r.faults()
        base = np.array(info["tensions_N"])
        assert np.all(np.abs(r.values_N - base) <= 20.0 + 1e-3)  # sine amplitude 20 N
    assert np.all(r2.counter != r1.counter)
    assert (r2.status == CableStatus.OK).all()
