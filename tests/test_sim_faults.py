"""Fault schedules (firmware_sim/faults.py): the file format and its errors, the injector on
the rig's clock against the HAL, and the control channel of ``cdpr sim`` (issue 9, defect 6).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import canopen
import numpy as np
import pytest

from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.faults import (
    FaultControlServer,
    FaultInjector,
    FaultSchedule,
    FaultScheduleError,
    send_request,
)
from firmware_sim.rig import SimRig
from hal.drives_cia402 import DriveState
from hal.interface import open_hardware
from hal.loadcell_client import CableStatus

ROOT = Path(__file__).resolve().parents[1]
W = load_winches()

EXAMPLE = """\
# a fault schedule
[[fault]]
at_s = 0.1
drive = 3
kind = "over_current"
clear_s = 0.3

[[fault]]
at_s = 0.05
cell = 5
kind = "stale"
clear_s = 0.5

[[fault]]
at_s = 0.2
cell = 2
kind = "exception"
code = 0x06

[[fault]]
at_s = 0.0
drive = 7
kind = "drop_rpdo"
count = 2
"""


def write(tmp_path: Path, text: str | bytes, name: str = "faults.toml") -> Path:
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def test_the_example_loads(tmp_path):
    s = FaultSchedule.load(write(tmp_path, EXAMPLE))
    assert [(f.device, f.address, f.kind, f.at_s, f.clear_s) for f in s.faults] == [
        ("drive", 3, "over_current", 0.1, 0.3), ("cell", 5, "stale", 0.05, 0.5),
        ("cell", 2, "exception", 0.2, None), ("drive", 7, "drop_rpdo", 0.0, None)]
    assert s.faults[2].code == 6 and s.faults[3].count == 2
    assert s.faults[0].where.endswith("faults.toml:2")


@pytest.mark.parametrize(("change", "needle"), [
    (('kind = "over_current"', 'kind = "overcurrent"'), ":5: kind: unknown kind 'overcurrent'"),
    (("drive = 3", "drive = 9"), ":4: drive: no drive with CAN node id 9"),
    (("cell = 5", "cell = 12"), ":10: cell: no cell with Modbus unit id 12"),
    (('kind = "stale"', 'kind = "silent"'), ":11: kind: unknown kind 'silent' of a cell (a kind "
                                            "of a drive)"),
    (("clear_s = 0.3", "clear_s = 0.05"), ":6: clear_s: 0.05 s must be after at_s 0.1 s"),
    (("clear_s = 0.3", "colour = 3"), ":6: colour: unknown key"),
    (("at_s = 0.1\n", ""), ":2: at_s is missing"),
    (("code = 0x06", "code = 9"), ":18: code: 0x09 is not a Modbus exception code"),
    (("count = 2", "count = 0"), ":24: count: must be >= 1"),
    (("at_s = 0.05", 'at_s = "soon"'), ":9: at_s: value must be a number"),
    (("drive = 3", "drive = 3\ncell = 2"), ":2: give drive = CAN node id or cell"),
])
def test_errors_name_file_line_and_field(tmp_path, change, needle):
    p = write(tmp_path, EXAMPLE.replace(*change, 1))
    with pytest.raises(FaultScheduleError) as exc:
        FaultSchedule.load(p)
    assert str(exc.value).startswith(str(p)) and needle in str(exc.value), str(exc.value)


def test_unreadable_files_are_named(tmp_path):
    with pytest.raises(FaultScheduleError, match="line 3, column 9: not UTF-8"):
        FaultSchedule.load(write(tmp_path, b"[[fault]]\nat_s = 1\nkind = \"\xe9\"\n"))
    with pytest.raises(FaultScheduleError, match="TOML syntax error.*line 2"):
        FaultSchedule.load(write(tmp_path, "[[fault]]\nat_s = = 1\n"))
    with pytest.raises(FaultScheduleError, match="cannot read"):
        FaultSchedule.load(tmp_path / "missing.toml")


def test_injector_on_the_rig_clock_against_the_hal(tmp_path):
    """In-process: the dry run's way. Faults come at their time on the SYNC clock; the HAL
    reports them naming node and unit; a persistent over-current blocks a reset until its
    clear_s."""
    rig = SimRig(plant_thread=False).start()
    hw = open_hardware(rig.can_spec, rig.modbus_spec, eds=EDS_PATH, clock="sync", poll="manual")
    inj = FaultInjector(rig, FaultSchedule.load(write(tmp_path, EXAMPLE)))
    try:
        hw.start()
        hw.enable()
        seen: dict[str, float] = {}
        for _ in range(150):  # 0.6 s of SYNC clock
            r = hw.step()
            inj.advance()
            hw.sample_tensions()
            r = hw.read()
            for f in r.faults:
                seen.setdefault(f"{f.device} {f.address} {f.kind} 0x{f.code:04X}", r.t_s)
            if (0.15 < r.t_s < 0.2 or r.t_s > 0.32) and r.states[2] == DriveState.FAULT:
                hw.fault_reset([3])
        assert 0.1 <= seen["drive 3 drive_fault 0x2310"] <= 0.1 + 3 * W.bus.sync_period_s
        assert seen["loadcell 5 stale 0x0000"] >= 0.05  # + stale_s of wall time
        assert seen["loadcell 2 exception 0x0006"] >= 0.2
        assert [(x.action, x.fault.kind) for x in inj.log] == [
            ("apply", "drop_rpdo"), ("apply", "stale"), ("apply", "over_current"),
            ("apply", "exception"), ("clear", "over_current"), ("clear", "stale")]
        r = hw.read()
        assert r.states[2] != DriveState.FAULT  # reset once the cause went away
        assert r.tension_status[4] == CableStatus.OK and r.tension_status[1] == (
            CableStatus.EXCEPTION)
        ev = [(e.address, e.kind) for e in hw.events() if e.device == "drive"]
        assert (3, "fault_reset_failed") in ev  # tried before 0.3 s: the cause was there
        assert not any(a == 7 for a, _ in ev)  # two RPDOs lost: within the deadline
    finally:
        hw.close()
        rig.close()


def test_control_channel_in_process():
    rig = SimRig(plant_thread=False).start()
    inj = FaultInjector(rig)
    ctl = FaultControlServer(inj).start()
    try:
        ep = ctl.endpoint
        assert send_request(ep, "time").startswith("ok 0.0")
        assert send_request(ep, "fault drive=4 kind=heartbeat_stop") == (
            "ok fault 1 drive 4 heartbeat_stop at 0 s")
        assert rig.bank.drive(4).heartbeat_stopped
        assert send_request(ep, "fault cell=3 kind=exception code=0x02 clear_s=9").startswith(
            "ok fault 2 cell 3 exception")
        assert rig.cells.faults() == {"21": ["exception"]}
        assert send_request(ep, "fault drive=12 kind=silent").startswith(
            "error request: drive: no drive with CAN node id 12")
        assert send_request(ep, "fault drive=4 kind=nan").startswith("error request: kind:")
        assert send_request(ep, "bogus").startswith("error unknown request 'bogus'")
        entries = json.loads(send_request(ep, "list")[3:])
        assert [(e["id"], e["kind"], e["applied"]) for e in entries] == [
            (1, "heartbeat_stop", True), (2, "exception", True)]
        assert send_request(ep, "clear drive=4") == "ok cleared 1"
        assert not rig.bank.drive(4).heartbeat_stopped
        assert send_request(ep, "clear all") == "ok cleared 1"
        assert rig.cells.faults() == {}
    finally:
        ctl.close()
        rig.close()


def _start_sim(*args: str) -> tuple[subprocess.Popen, dict]:
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "sim", "--json",
                             "--exit-on-stdin-eof", *args], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line: list[str] = []
    th = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
    th.start()
    th.join(60)
    if not line or not line[0].strip():
        proc.kill()
        raise AssertionError(f"cdpr sim printed nothing: {proc.communicate(timeout=10)[1]}")
    return proc, json.loads(line[0])


def _stop(proc: subprocess.Popen) -> str:
    try:  # closes stdin: the sim stops (--exit-on-stdin-eof)
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate(timeout=10)
    return err


def test_cdpr_sim_faults_and_control_channel(tmp_path):
    """A separate process: a schedule, then a fault from the control channel, seen by the
    HAL over the socketcand hub; third-party style: heartbeats without any SYNC."""
    sched = write(tmp_path, '[[fault]]\nat_s = 0.0\ncell = 6\nkind = "nan"\n')
    proc, info = _start_sim("--faults", str(sched))
    try:
        assert info["faults"] == str(sched) and ":" in info["control"]
        # a tool waiting for a heartbeat gets one on the SYNC clock with nobody sending SYNC
        net = canopen.Network()
        net.connect(interface="socketcand", channel="can0",
                    host=info["can"].split(":")[1], port=int(info["can"].split(":")[2]))
        try:
            node = net.add_node(5, str(EDS_PATH))
            node.sdo[0x1017].raw = 50  # heartbeat every 50 ms, please
            node.nmt.wait_for_heartbeat(timeout=5.0)
        finally:
            net.disconnect()
        hw = open_hardware(info["can"], info["modbus"], eds=EDS_PATH, clock="sync")
        try:
            hw.start()
            hw.enable()
            assert send_request(info["control"], "fault drive=2 kind=over_current").startswith(
                "ok fault 2 drive 2 over_current")  # 1: the schedule's
            deadline = time.monotonic() + 20
            while True:
                r = hw.step(timeout_s=1.0)
                kinds = {(f.device, f.address, f.kind, f.code) for f in r.faults}
                if ("drive", 2, "drive_fault", 0x2310) in kinds and (
                        "loadcell", 6, "nan", 0) in kinds:
                    break
                assert time.monotonic() < deadline, kinds
            assert np.sum(r.states == DriveState.OPERATION_ENABLED) == 7
        finally:
            hw.close()
    finally:
        err = _stop(proc)
    assert "2 fault(s) injected" in err


def test_cdpr_sim_refuses_a_bad_schedule(tmp_path):
    sched = write(tmp_path, '[[fault]]\nat_s = 1.0\ndrive = 3\nkind = "meltdown"\n')
    out = subprocess.run([sys.executable, "-m", "bench.cli", "sim", "--faults", str(sched)],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert f"{sched}:4: kind: unknown kind 'meltdown'" in out.stderr
    assert "Traceback" not in out.stderr
