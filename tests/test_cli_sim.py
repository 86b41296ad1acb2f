"""``cdpr sim`` in ANOTHER PROCESS: the HAL over the socketcand hub (TCP) and Modbus/TCP,
mbpoll against its load cells, signals, RTU framing, scenario errors.

The endpoints come from the command's ``--json`` line; nothing is hard-coded but the
loopback address. The rig runs on the deterministic SYNC clock, the HAL on the matching
"sync" clock, lock-step: cycles are counted, not seconds.
"""

from __future__ import annotations

import json
import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from controller.winch import load_winches, metres_per_count
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.plant import Plant
from firmware_sim.rig import default_scenario
from firmware_sim.scenario import load_scenario
from hal.can_bus import parse_can_spec
from hal.interface import open_hardware
from hal.loadcell_client import LoadCellClient
from hal.modbus_config import parse_modbus_spec

ROOT = Path(__file__).resolve().parents[1]
W = load_winches()
COUNT_M = float(metres_per_count(W)[0])
MBPOLL = shutil.which("mbpoll")
SCENARIO = """format = "cdpr-scenario/1"
robot = "rocaspect"
seed = 7
init_pose = [11.0, 9.0, 1.1, 0.0, 0.0, 0.0]

[truth.load_cell_calibration]
gain_32 = 1.05
offset_12 = -3.0

[truth.mast_compliance]
k = [2.0e5, 5.0e5, 3.0e5]

[noise]
load_cell_n = 0.25
"""


class Sim:
    """A ``cdpr sim`` process; ``info`` its JSON line (or ``lines``: its human output)."""

    def __init__(self, *args: str, json_line: bool = True, deadline_s: float = 30.0) -> None:
        self.err = tempfile.TemporaryFile(mode="w+")  # a file cannot fill up like a pipe
        cmd = [sys.executable, "-m", "bench.cli", "sim", "--exit-on-stdin-eof", *args]
        if json_line:
            cmd.append("--json")
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.err, text=True)
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        want = 1 if json_line else 4
        self.lines = [self._line(deadline_s) for _ in range(want)]
        self.info = json.loads(self.lines[0]) if json_line else None

    def _line(self, deadline_s: float) -> str:
        try:
            line = self._lines.get(timeout=deadline_s)
        except queue.Empty:
            self.proc.kill()
            raise AssertionError(f"cdpr sim printed nothing in {deadline_s} s: "
                                 f"{self.stderr()}") from None
        if line is None:
            self.proc.wait(5)
            raise AssertionError(f"cdpr sim exited {self.proc.returncode}: {self.stderr()}")
        return line

    def _read(self) -> None:
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def stderr(self) -> str:
        self.err.seek(0)
        return self.err.read()

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
            raise AssertionError(f"cdpr sim ignored signal {sig}: {self.stderr()}") from None

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        self.proc.stdin.close()
        self.err.close()


@pytest.fixture
def sims():
    started: list[Sim] = []

    def start(*args: str, **kw) -> Sim:
        s = Sim(*args, **kw)
        started.append(s)
        return s

    yield start
    for s in started:
        s.close()


def _local_plant(scenario=None) -> Plant:
    sc = scenario or default_scenario()
    return Plant(sc.model, sc.truth, sc.init_pose)


# ---------------------------------------------------------------------------- HAL across


def test_hal_against_cdpr_sim_in_another_process(sims):
    sim = sims()
    ep = sim.info
    spec = parse_can_spec(ep["can"])
    assert (spec.interface, spec.host, spec.channel) == ("socketcand", "127.0.0.1", "can0")
    mb = parse_modbus_spec(ep["modbus"])
    assert (mb.kind, mb.host) == ("tcp", "127.0.0.1") and mb.port != spec.port
    assert ep["node_ids"] == list(range(1, 9)) and ep["unit_ids"] == list(range(1, 9))
    plant = _local_plant()
    np.testing.assert_allclose(ep["reference_m"], plant.reference)

    hw = open_hardware(ep["can"], ep["modbus"], eds=EDS_PATH, clock="sync")
    try:
        hw.start()
        hw.enable()
        r = hw.read()
        assert r.all_enabled and r.faults == ()
        np.testing.assert_allclose(r.lengths_m, plant.reference, atol=COUNT_M)
        # tensions: the plant at the init pose, through Modbus/TCP, within the cells' noise
        tol = 5 * default_scenario().noise.load_cell_n + 0.05
        assert hw.sample_tensions()
        r = hw.read()
        assert r.ok, r.faults
        expect = plant.measured_tensions(plant.settle(r.lengths_m).tensions)
        np.testing.assert_allclose(r.tensions_N, expect, atol=tol)
        # setpoints followed across the hub
        l0 = r.lengths_m
        amp = np.array([0.004, 0.0, -0.004, 0.0, 0.0, 0.0, 0.0, 0.0])
        for i in range(1, 101):
            cmd = l0 + amp * 0.5 * (1 - np.cos(np.pi * i / 100))
            hw.step(cmd, timeout_s=2.0)
        for _ in range(15):
            r = hw.step(timeout_s=2.0)
        np.testing.assert_allclose(r.lengths_m, cmd, atol=2e-5)
        assert r.faults == () and hw.events() == []
        # the plant in the other process responds: its tensions reach what the plant says
        expect = plant.measured_tensions(plant.settle(r.lengths_m).tensions)
        deadline = time.monotonic() + 15.0
        while True:  # the other process settles at its own rate: poll with a deadline
            assert hw.sample_tensions()
            got = hw.read()
            if np.all(np.abs(got.tensions_N - expect) <= tol) or time.monotonic() > deadline:
                break
        np.testing.assert_allclose(got.tensions_N, expect, atol=tol)
        assert got.tensions_N[2] - l0_tension(plant, l0)[2] > 30  # cable 21 pulled in
        hw.shutdown()
        assert not np.any(hw.read().enabled)
    finally:
        hw.close()
    assert sim.stop(signal.SIGTERM) == 143, sim.stderr()
    assert "stopped" in sim.stderr()
    assert sim.stderr().strip().splitlines()[-1] == "cdpr sim: terminated (SIGTERM)"


def l0_tension(plant: Plant, lengths: np.ndarray) -> np.ndarray:
    """Measured tensions for ``lengths`` on a fresh plant of the same robot."""
    fresh = Plant(plant.model, plant.truth, plant.init_pose)
    return fresh.measured_tensions(fresh.settle(lengths).tensions)


# ---------------------------------------------------------------------------- mbpoll


def _mbpoll_floats(port: int) -> dict[int, float]:
    out = subprocess.run(
        [MBPOLL, "-m", "tcp", "-0", "-1", "-o", "2", "-a", "1:8", "-t", "3:float", "-B",
         "-r", "0", "-c", "1", "-p", str(port), "127.0.0.1"],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    values: dict[int, float] = {}
    unit = None
    for line in out.stdout.splitlines():
        if m := re.match(r"-- Polling slave (\d+)", line):
            unit = int(m.group(1))
        elif (m := re.match(r"\[(\d+)\]:\s+(\S+)", line)) and unit is not None:
            values[unit] = float(m.group(2))
    return values


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (.ci/run installs it)")
def test_mbpoll_reads_the_tensions_the_plant_computed(sims, tmp_path):
    path = tmp_path / "truth.toml"
    path.write_text(SCENARIO)
    sim = sims(str(path))
    ep = sim.info
    assert ep["scenario"] == str(path) and ep["init_pose"] == [11.0, 9.0, 1.1, 0.0, 0.0, 0.0]
    sc = load_scenario(path)
    plant = _local_plant(sc)
    true_n = plant.settle(np.array(ep["reference_m"])).tensions
    expect = plant.measured_tensions(true_n)  # gain 1.05 on 32, offset -3 N on 12
    values = _mbpoll_floats(parse_modbus_spec(ep["modbus"]).port)
    assert sorted(values) == list(range(1, 9))
    got = np.array([values[u] for u in range(1, 9)])
    tol = 5 * sc.noise.load_cell_n + 0.05
    np.testing.assert_allclose(got, expect, atol=tol)
    # the calibration errors of the truth are in what mbpoll reads
    assert got[5] - true_n[5] > 0.04 * true_n[5] - tol
    assert true_n[1] - got[1] > 3.0 - tol
    # a second read through the HAL's client agrees within the noise
    client = LoadCellClient(ep["modbus"])
    try:
        client.poll_once()
        r = client.read()
    finally:
        client.stop()
    assert r.all_ok, r.faults()
    np.testing.assert_allclose(r.values_N, got, atol=2 * tol)
    assert sim.stop(signal.SIGINT) == 130, sim.stderr()


# ---------------------------------------------------------------------------- CLI


def test_human_output_rtu_and_sigint(sims):
    sim = sims("--can", "socketcand:127.0.0.1:0", "--modbus", "rtu-tcp:127.0.0.1:0",
               json_line=False)
    text = "".join(sim.lines)
    can = re.search(r"^  --can (socketcand:127\.0\.0\.1:\d+)$", text, re.M)
    mb = re.search(r"^  --modbus (rtu-tcp:127\.0\.0\.1:\d+)$", text, re.M)
    assert can and mb, text
    assert parse_can_spec(can.group(1)).port > 0
    client = LoadCellClient(mb.group(1))
    try:
        client.poll_once()
        r = client.read()
    finally:
        client.stop()
    assert r.all_ok, r.faults()
    np.testing.assert_allclose(r.values_N, _local_plant().init_tensions, atol=5 * 0.5 + 0.1)
    assert sim.stop(signal.SIGINT) == 130, sim.stderr()


def test_scenario_errors_name_file_and_field_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "cdpr-scenario/1"\n[noise]\nload_cell_n = -1.0\n')
    assert main(["sim", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "noise.load_cell_n" in err
    bad.write_text('format = "cdpr-scenario/1"\n[truth.exit_point_offset]\ndx_99 = 0.1\n')
    assert main(["sim", str(bad), "--json"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert str(bad) in out["error"] and "dx_99" in out["error"]
    assert main(["sim", str(tmp_path / "missing.toml")]) == 2
    assert "missing.toml" in capsys.readouterr().err
    assert main(["sim", "--can", "socketcand:127.0.0.1:70000"]) == 2
    assert "--can 'socketcand:127.0.0.1:70000'" in capsys.readouterr().err
    assert main(["sim", "--modbus", "127.0.0.1"]) == 2
    assert "--modbus '127.0.0.1'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:  # the deprecated alias: still a port, 0..65535
        main(["sim", "--can-port", "70000"])
    assert e.value.code == 2 and "70000" in capsys.readouterr().err
    assert main(["sim", "--can", "nonsense"]) == 2
    assert "--can 'nonsense'" in capsys.readouterr().err


def test_ports_in_use_exit_1(capsys):
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = str(busy.getsockname()[1])
        assert main(["sim", "--can", f"socketcand:127.0.0.1:{port}"]) == 1
        assert f"127.0.0.1:{port}" in capsys.readouterr().err
        assert main(["sim", "--modbus", f"127.0.0.1:{port}", "--json"]) == 1
        out = json.loads(capsys.readouterr().out)
        assert port in out["error"]
        # the deprecated spellings still work, and say so
        assert main(["sim", "--can-port", port]) == 1
        err = capsys.readouterr().err
        assert f"127.0.0.1:{port}" in err and "--can-port is deprecated" in err
        assert main(["sim", "--modbus-port", port, "--json"]) == 1
        out = json.loads(capsys.readouterr().out)
        assert port in out["error"]
