"""Commissioning motion that watches every cable, Cartesian jog, referencing, homing that
moves the count and never the cable, tensions classified against the window, the monitor's
history by severity.

The robot is the whole simulated rig in this process (:class:`firmware_sim.rig.SimRig`:
drives on a python-can virtual channel, load cells on Modbus/TCP at 127.0.0.1 port 0, the
plant settling in the rig's thread); the commands run through ``bench.cli.main``. The rig's
own record of every plant state it served (:attr:`SimRig.history`) is the truth the tests
hold the motion to.
"""

from __future__ import annotations

import io
import json
import sys
import time

import numpy as np
import pytest

from bench.cli import main
from controller.cable_watch import (
    INVALID,
    OK,
    OVERLOAD,
    SLACK,
    CableWatch,
    TensionWindow,
    classify_tensions,
    decide,
)
from controller.robot import resolve_robot
from controller.supervisor import SupervisorLimits
from firmware_sim.rig import SimRig
from hal.event_log import FAULT, NMT, WARNING, SeverityLog, emcy_severity

ROBOT = resolve_robot("rocaspect")
WINDOW = TensionWindow.for_robot(ROBOT.tension_min, ROBOT.tension_max)
CABLES = tuple(ROBOT.cable_ids)


class Keys:
    """An operator holding one key: a key every 20 ms (a terminal's repeat) for
    ``seconds``, then the end of the input."""

    def __init__(self, key: str = "+", seconds: float = 3.0) -> None:
        self.key, self.end = key, time.monotonic() + seconds

    def read(self, n: int = 1) -> str:
        time.sleep(0.02)
        return self.key if time.monotonic() < self.end else ""


def cli(*argv: str, stdin=None) -> tuple[int, dict]:
    """``cdpr commission ARGV --json --no-report``: exit status and the last JSON line."""
    old_in, old_out = sys.stdin, sys.stdout
    buf = io.StringIO()
    if stdin is not None:
        sys.stdin = stdin
    sys.stdout = buf
    try:
        code = main(["commission", *argv, "--json", "--no-report"])
    finally:
        sys.stdin, sys.stdout = old_in, old_out
    lines = buf.getvalue().strip().splitlines()
    return code, json.loads(lines[-1]) if lines else {}


@pytest.fixture
def rig():
    r = SimRig().start()
    yield r
    r.close()


def _bus(rig) -> list[str]:
    # a shared, loaded test machine may starve the simulated cells' thread for a while:
    # the cells' staleness limits are widened so that the watch stops for the physics only
    return ["--can", rig.can_spec, "--modbus", rig.modbus_spec, "--loadcell-stale", "1.0",
            "--loadcell-timeout", "0.5"]


def _served_since(rig, t0_wall: float, n_before: int) -> np.ndarray:
    """True tensions (m, 8) [N] of every plant state served after ``n_before`` states."""
    hist = list(rig.history)[n_before:] if n_before < len(rig.history) else [rig.last]
    return np.array([h.tensions_N for h in hist])


# ---------------------------------------------------------------------------- pure decisions


def test_window_is_the_supervisors_thresholds():
    lim = SupervisorLimits.for_robot(ROBOT.tension_min, ROBOT.tension_max, 0.0)
    assert (WINDOW.low_n, WINDOW.high_n) == (lim.slack_n, lim.overload_n)
    with pytest.raises(ValueError):
        TensionWindow(5.0, 5.0)


def test_classification_flags_slack_overload_and_invalid_and_nothing_in_the_window():
    inside = np.linspace(WINDOW.low_n, WINDOW.high_n, 8)  # edges included: inside
    assert classify_tensions(inside, WINDOW) == [OK] * 8
    tau = np.array([0.7, 430.0, 3000.5, np.nan, 200.0, 1.0, 0.0, 5000.0])
    assert classify_tensions(tau, WINDOW) == [SLACK, OK, OVERLOAD, INVALID, OK, OK, SLACK,
                                              OVERLOAD]
    valid = np.ones(8, bool)
    valid[4] = False  # a stale cell: not watched
    assert classify_tensions(tau, WINDOW, valid)[4] == INVALID


def test_decide_goes_on_when_all_in_the_window_and_steady():
    v = decide(np.full(8, 200.0), np.zeros(8), WINDOW, 0.25, CABLES)
    assert v.go and v.reason == "" and v.statuses == (OK,) * 8


def test_decide_stops_before_a_falling_tension_leaves_and_names_the_cable():
    tau = np.full(8, 200.0)
    rate = np.zeros(8)
    rate[6] = -900.0  # cable 41 falling fast: 200 - 900 * 0.25 < 1 N
    v = decide(tau, rate, WINDOW, 0.25, CABLES)
    assert not v.go and v.cable == "41" and v.kind == "predicted_slack"
    assert "cable 41" in v.reason and "[1, 3000] N" in v.reason
    rate[6] = -500.0  # would still be 75 N: go on
    assert decide(tau, rate, WINDOW, 0.25, CABLES).go
    tau[2] = 3100.0
    v = decide(tau, np.zeros(8), WINDOW, 0.25, CABLES)
    assert not v.go and v.cable == "21" and v.kind == OVERLOAD
    tau[2] = np.nan
    v = decide(tau, np.zeros(8), WINDOW, 0.25, CABLES)
    assert not v.go and v.kind == INVALID and "not watched" in v.reason


def test_cable_watch_fits_the_rate_over_its_span_and_noise_alone_never_stops_it():
    rng = np.random.default_rng(3)
    w = CableWatch(WINDOW, CABLES, horizon_s=0.25)
    for i in range(200):  # 4 s of 50 Hz samples with 0.5 N noise around 20 N
        v = w.step(i * 0.02, 20.0 + rng.normal(0.0, 0.5, 8))
        assert v.go, v.reason
    w.reset()
    stopped = None
    for i in range(100):  # cable 11 falls at 400 N/s from 200 N
        tau = np.full(8, 200.0)
        tau[0] = 200.0 - 400.0 * i * 0.02
        v = w.step(i * 0.02, tau)
        if not v.go:
            stopped = tau[0]
            break
    assert stopped is not None and stopped > WINDOW.low_n  # before it left the window
    assert stopped == pytest.approx(400.0 * 0.25, abs=10.0)  # at about rate x horizon


# ---------------------------------------------------------------------------- history by severity


def test_severity_log_keeps_faults_and_boot_ups_through_a_warning_flood():
    class E:
        def __init__(self, t, sev, code):
            self.wall_time, self.severity, self.code = t, sev, code

    log = SeverityLog(max_per_class=50)
    log.append(E(0.0, FAULT, 0x2310))
    log.append(E(0.1, NMT, 0))
    log.append(E(0.2, FAULT, 0x7305))
    for i in range(60):
        log.append(E(1.0 + i, WARNING, 0x8250))
    codes = [e.code for e in log.items(FAULT)]
    assert codes == [0x2310, 0x7305] and len(log.items(NMT)) == 1
    assert log.dropped() == {FAULT: 0, NMT: 0, WARNING: 10}
    assert len(log.items(WARNING)) == 50 and log.items()[0].code == 0x2310  # time order
    for i in range(55):
        log.append(E(100.0 + i, FAULT, 0x1000 + i))
    assert log.dropped()[FAULT] == 7 and log.dropped()[WARNING] == 10
    assert emcy_severity(0x2310) == FAULT and emcy_severity(0x8250) == WARNING
    assert emcy_severity(0x8130) == WARNING and emcy_severity(0) == WARNING


def test_monitor_keeps_the_fault_and_counts_the_boot_up_under_a_warning_flood(rig):
    import canopen

    from firmware_sim.cia402_drive import EDS_PATH
    from hal.can_bus import open_bus
    from hal.drive_monitor import DriveMonitor

    net = canopen.Network(open_bus(rig.can_spec))
    net.connect()
    try:
        mon = DriveMonitor(net, rig.winches, EDS_PATH, max_events=50)
        drv = rig.bank.drive(4)
        drv._emcy(0x2310)  # a fault, then 60 warnings
        for _ in range(60):
            drv._emcy(0x8250)
        rig.bank.drive(3).reset_node()  # a node reset is an event
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and (
                len(mon.events.items(WARNING)) < 50 or not mon.events.items(NMT)):
            time.sleep(0.02)
        faults = mon.events.items(FAULT)
        assert [e.code for e in faults] == [0x2310] and faults[0].node_id == 4
        assert [e.node_id for e in mon.events.items(NMT)] == [3]
        assert mon.events.dropped()[WARNING] == 10 + 0  # 60 warnings, 50 kept
        assert any(e.severity == FAULT for e in mon.last_events(4))
        mon.close()
    finally:
        net.disconnect()


# ---------------------------------------------------------------------------- scan and monitor


def test_scan_and_monitor_call_out_of_window_readings_slack_and_overload(rig):
    code, out = cli("scan", *_bus(rig))
    assert code == 0 and [c["status"] for c in out["load_cells"]] == ["ok"] * 8
    # the same readings judged against a window that the rig's ~215 N leave
    code, out = cli("scan", *_bus(rig), "--tension-window", "220,3000")
    st = {c["cable"]: (c["status"], c["tension_n"]) for c in out["load_cells"]}
    assert code == 1
    for s, t in st.values():
        assert s == ("slack" if t < 220 else "ok")
    code, out = cli("monitor", *_bus(rig), "--duration", "0.3", "--rate", "10",
                    "--tension-window", "1,215")
    for c in out["load_cells"]:
        assert c["status"] == ("overload" if c["tension_n"] > 215 else "ok")
    assert out["events_dropped"] == {"fault": 0, "nmt": 0, "warning": 0}


def test_monitor_json_lines_streams_one_object_per_refresh(rig):
    code = 0
    old = sys.stdout
    buf = io.StringIO()
    sys.stdout = buf
    try:
        code = main(["commission", "monitor", *_bus(rig), "--duration", "0.45", "--rate", "10",
                     "--json-lines", "--no-report"])
    finally:
        sys.stdout = old
    rows = [json.loads(x) for x in buf.getvalue().splitlines() if x.strip()]
    assert code == 0 and len(rows) >= 3
    for r in rows:
        assert set(r) >= {"t_s", "drives", "load_cells", "bus_load", "frames", "events_new"}
        assert len(r["drives"]) == 8 and [c["status"] for c in r["load_cells"]] == ["ok"] * 8
    assert [r["t_s"] for r in rows] == sorted(r["t_s"] for r in rows)


# ---------------------------------------------------------------------------- single-winch jog


def test_a_long_single_winch_jog_needs_the_platform_supported_and_stops_in_the_window(rig):
    code, out = cli("jog", "21", *_bus(rig), "--travel", "0.083", "--yes", "--listen", "0")
    assert code == 2 and "--platform-supported" in out["error"]
    assert rig.bank.drive(3).state.name == "SWITCH_ON_DISABLED"  # never enabled
    n0 = len(rig.history)
    code, out = cli("jog", "21", *_bus(rig), "--travel", "0.083", "--platform-supported",
                    "--yes", "--listen", "0", stdin=Keys("+", 4.0))
    assert code == 1 and out["guard_stop"].startswith("cable ")
    assert "window [1, 3000] N" in out["guard_stop"]
    assert out["state"] == "SWITCH_ON_DISABLED"
    assert 0.005 < out["end_m"] - out["start_m"] < 0.083  # moved, and was stopped early
    rig.wait_settled()
    time.sleep(0.2)
    served = _served_since(rig, 0.0, n0)
    assert served.min() > WINDOW.low_n and served.max() < WINDOW.high_n
    assert not rig.plant_errors


def test_the_default_single_winch_jog_is_5_mm_on_a_loaded_robot_and_shows_every_cable(rig):
    code, out = cli("jog", "21", *_bus(rig), "--yes", "--listen", "0", stdin=Keys("-", 1.5))
    assert code == 0 and out["travel_m"] == pytest.approx(0.005)
    assert out["start_m"] - out["min_m"] <= 0.005 + 2e-4  # the motor lags its demand
    assert set(out["cable_watch"]["min_n"]) == set(CABLES)
    code, out = cli("jog", "21", "--can", rig.can_spec, "--yes", "--listen", "0")
    assert code == 2 and "--modbus" in out["error"]  # no cells, no --platform-supported


# ---------------------------------------------------------------------------- Cartesian jog


def test_a_5_cm_cartesian_jog_in_z_keeps_every_cable_in_the_window(rig, tmp_path):
    state = str(tmp_path / "state.toml")
    code, out = cli("jog", "--platform", "--step", "0,0,0.05", *_bus(rig), "--yes",
                    "--listen", "0", "--state", state)
    assert code == 1 and "reference" in out["error"]  # not referenced yet
    p0 = rig.last.pose
    code, out = cli("reference", "--pose", ",".join(f"{x:.9f}" for x in p0[:3]),
                    "--can", rig.can_spec, "--state", state)
    assert code == 0 and max(abs(v) for v in out["offsets_m"].values()) < 1e-5
    n0 = len(rig.history)
    code, out = cli("jog", "--platform", "--step", "0,0,0.05", *_bus(rig), "--yes",
                    "--listen", "0", "--state", state)
    assert code == 0 and out["ended_by"] == "target reached", out["ended_by"]
    rig.wait_settled()
    assert rig.last.pose[2] - p0[2] == pytest.approx(0.05, abs=2e-3)
    np.testing.assert_allclose(rig.last.pose[:2], p0[:2], atol=2e-3)
    served = _served_since(rig, 0.0, n0)
    assert len(served) > 10
    assert served.min() > WINDOW.low_n and served.max() < WINDOW.high_n
    assert out["cable_watch"]["stopped"] == ""


def test_an_infeasible_cartesian_target_is_refused_before_anything_moves(rig, tmp_path):
    state = str(tmp_path / "state.toml")
    p0 = rig.last.pose
    cli("reference", "--pose", ",".join(f"{x:.9f}" for x in p0[:3]), "--can", rig.can_spec,
        "--state", state)
    before = rig.bank.positions_counts()
    code, out = cli("jog", "--platform", "--step", "0,0,-2", *_bus(rig), "--yes", "--listen",
                    "0", "--state", state, "--max-step", "5")
    assert code == 1 and "refused before any motion" in out["error"]
    np.testing.assert_array_equal(rig.bank.positions_counts(), before)


# ---------------------------------------------------------------------------- homing


def test_homing_moves_the_count_not_the_cable_and_loses_the_reference(rig, tmp_path):
    state = str(tmp_path / "state.toml")
    p0 = rig.last.pose
    code, out = cli("reference", "--pose", ",".join(f"{x:.9f}" for x in p0[:3]),
                    "--can", rig.can_spec, "--state", state)
    assert code == 0
    code, scan0 = cli("scan", *_bus(rig))
    tau0 = np.array([c["tension_n"] for c in scan0["load_cells"]])
    code, out = cli("home", "21", "--method", "35", "--yes", "--listen", "0",
                    "--can", rig.can_spec, "--state", state)
    assert code == 0 and out["position_after_counts"] == 0 and out["reference_lost"], out
    assert out["position_before_counts"] != 0
    time.sleep(0.3)
    rig.wait_settled()
    assert not rig.plant_errors, rig.plant_errors[:1]  # the plant still finds its rest pose
    np.testing.assert_allclose(rig.last.pose, p0, atol=1e-6)
    code, scan1 = cli("scan", *_bus(rig))
    tau1 = np.array([c["tension_n"] for c in scan1["load_cells"]])
    assert code == 0 and [c["status"] for c in scan1["load_cells"]] == ["ok"] * 8, scan1
    np.testing.assert_allclose(tau1, tau0, atol=3.0)  # the cells' noise
    text = open(state).read()
    assert "referenced = false" in text and "--method 35" in text
    code, out = cli("jog", "--platform", "--step", "0,0,0.01", *_bus(rig), "--yes",
                    "--listen", "0", "--state", state)
    assert code == 1 and "not referenced" in out["error"] and "reference" in out["error"]
    # the count of 21 reads ~0 m now: reference names the fix (the model's length there)
    pose = ",".join(f"{x:.9f}" for x in p0[:3])
    code, out = cli("reference", "--pose", pose, "--can", rig.can_spec, "--state", state)
    assert code == 1 and "cdpr commission home 21 --length 13.64" in out["error"]
    wfile = tmp_path / "winches.toml"
    wfile.write_text(open(rig.winches.source).read())
    code, out = cli("home", "21", "--length", "13.6409", "--yes", "--listen", "0",
                    "--can", rig.can_spec, "--winches", str(wfile), "--state", state)
    assert code == 0
    code, out = cli("reference", "--pose", pose, "--can", rig.can_spec, "--state", state,
                    "--winches", str(wfile))
    assert code == 0 and max(abs(v) for v in out["offsets_m"].values()) < 1e-4, out
    code, out = cli("jog", "--platform", "--step", "0,0,0.01", *_bus(rig), "--yes",
                    "--listen", "0", "--state", state, "--winches", str(wfile))
    assert code == 0 and out["ended_by"] == "target reached", out
    rig.wait_settled()
    assert rig.last.pose[2] - p0[2] == pytest.approx(0.01, abs=2e-3)


def test_enable_is_stopped_and_disabled_when_any_cable_is_out_of_the_window(rig):
    code, out = cli("enable", "41", *_bus(rig), "--yes", "--listen", "0", "--duration", "2",
                    "--tension-window", "1,215", stdin=io.StringIO(""))
    assert code == 1 and "overload" in out["ended_by"] and "above 215 N" in out["ended_by"]
    assert out["state"] == "SWITCH_ON_DISABLED" and rig.bank.drive(7).state.name == \
        "SWITCH_ON_DISABLED"
    code, out = cli("enable", "41", *_bus(rig), "--yes", "--listen", "0", "--duration", "0.3",
                    stdin=io.StringIO(""))  # all in the window: held to the end
    assert code == 0 and out["ended_by"] == "--duration 0.3 s"
    assert out["cable_watch"]["stopped"] == ""


def test_reference_from_the_tracker_records_the_pose_offsets_and_model(tmp_path):
    from bench.commission.reference import read_state

    with SimRig(tracker_port=0) as rig:
        state = tmp_path / "state.toml"
        code, out = cli("reference", "--can", rig.can_spec, "--tracker", rig.tracker_spec,
                        "--samples", "5", "--state", str(state))
        assert code == 0 and out["pose_source"] == "tracker, mean of 5 samples"
        np.testing.assert_allclose(out["pose"], rig.last.pose, atol=1e-3)  # tracker noise
        st = read_state(state)
        assert st["referenced"] and st["robot"] == "rocaspect" and len(st["winch"]) == 8
        assert [w["cable"] for w in st["winch"]] == list(CABLES)
        for w in st["winch"]:
            assert w["offset_m"] == pytest.approx(w["model_m"] - w["reading_m"])
            assert abs(w["offset_m"]) < 5e-3
    with pytest.raises(SystemExit) as stop:  # a usage error: the shared --tracker's parser
        cli("reference", "--can", "virtual:nobody", "--tracker", "nonsense",
            "--state", str(state))
    assert stop.value.code == 2
    code, out = cli("reference", "--can", "virtual:nobody", "--pose", "1,2",
                    "--state", str(state))
    assert code == 2 and "x,y,z" in out["error"]


def test_a_bad_state_file_is_refused_naming_the_file_and_field(tmp_path):
    from bench.commission.common import CommissionError
    from bench.commission.reference import dumps_state, read_state, require_reference
    from controller.winch import load_winches

    w = load_winches()
    p = tmp_path / "s.toml"
    p.write_text('format = "cdpr-commission-state/9"\n')
    with pytest.raises(CommissionError, match="s.toml: format"):
        read_state(p)
    p.write_text('format = "cdpr-commission-state/1"\nreferenced = "yes"\n')
    with pytest.raises(CommissionError, match="'referenced'"):
        read_state(p)
    good = {"referenced": True, "time": "t", "robot": "rocaspect", "pose": [0.0] * 6,
            "pose_source": "x", "winch": [
                {"cable": c, "node_id": k + 1, "position_counts": 0, "reading_m": 1.0,
                 "model_m": 1.5, "offset_m": 0.5} for k, c in enumerate(w.cables[:7])]}
    p.write_text(dumps_state(good))
    with pytest.raises(CommissionError, match="no reference for cable"):
        require_reference(p, w)  # cable 42 missing
    good["winch"].append({"cable": "42", "node_id": 8, "position_counts": 0,
                          "reading_m": 1.0, "model_m": 1.5, "offset_m": 0.5})
    p.write_text(dumps_state(good))
    np.testing.assert_allclose(require_reference(p, w), 0.5)


def test_a_cartesian_jog_quick_stops_every_drive_when_a_cable_would_leave_the_window(rig,
                                                                                    tmp_path):
    state = str(tmp_path / "state.toml")
    p0 = rig.last.pose
    cli("reference", "--pose", ",".join(f"{x:.9f}" for x in p0[:3]), "--can", rig.can_spec,
        "--state", state)
    top = float(rig.last.tensions_N.max()) + 4.0  # up by 5 cm loads the cables by ~8 N
    code, out = cli("jog", "--platform", "--step", "0,0,0.05", *_bus(rig), "--yes",
                    "--listen", "0", "--state", state, "--tension-window", f"1,{top:.1f}")
    assert code == 1 and "overload" in out["guard_stop"], out
    assert out["end_pose"][2] - p0[2] < 0.045  # stopped on the way
    rig.wait_settled()
    assert all(d.state.name in ("SWITCH_ON_DISABLED", "READY_TO_SWITCH_ON")
               for d in rig.bank.drives)


def test_monitor_output_keeps_the_faults_of_a_warning_flood_and_counts_the_dropped(
        rig, tmp_path, capsys, monkeypatch):
    import threading

    from hal.drive_monitor import DriveMonitor

    polling = threading.Event()
    poll = DriveMonitor.poll

    def poll_and_tell(self):
        polling.set()
        return poll(self)

    monkeypatch.setattr(DriveMonitor, "poll", poll_and_tell)

    def flood():
        polling.wait(30)  # the monitor is up
        drv = rig.bank.drive(5)
        drv._emcy(0x2310)
        drv._emcy(0x7305)
        for _ in range(60):
            drv._emcy(0x8250)

    th = threading.Thread(target=flood)
    th.start()
    rep = tmp_path / "r.md"
    capsys.readouterr()
    code = main(["commission", "monitor", *_bus(rig), "--duration", "2.0", "--rate", "5",
                 "--json", "--report", str(rep)])
    th.join()
    cap = capsys.readouterr()
    out = json.loads(cap.out.strip().splitlines()[-1])
    assert code == 0
    assert [e["code"] for e in out["events_by_severity"]["fault"]] == [0x2310, 0x7305]
    assert out["events_dropped"] == {"fault": 0, "nmt": 0, "warning": 10}
    assert len(out["events_by_severity"]["warning"]) == 50
    assert "events dropped (oldest first, by severity): 0 fault, 0 nmt, 10 warning" in cap.err
    assert "events dropped: 0 fault, 0 nmt, 10 warning" in rep.read_text()


def test_a_cartesian_jog_turns_the_platform_by_a_step_in_degrees(rig, tmp_path):
    state = str(tmp_path / "state.toml")
    p0 = rig.last.pose
    cli("reference", "--pose", ",".join(f"{x:.9f}" for x in p0[:3]), "--can", rig.can_spec,
        "--state", state)
    code, out = cli("jog", "--platform", "--step", "0.02,0,0,0,0,2", *_bus(rig), "--yes",
                    "--listen", "0", "--state", state)
    assert code == 0 and out["ended_by"] == "target reached"
    rig.wait_settled()
    d = rig.last.pose - p0
    assert d[0] == pytest.approx(0.02, abs=1e-3) and np.degrees(d[5]) == pytest.approx(2, abs=0.05)
    np.testing.assert_allclose(d[1:5], 0.0, atol=1e-3)


def test_the_hal_jog_quick_stops_holds_and_disables_when_its_guard_says_so():
    """Lock-step (the drives on the SYNC clock, the master unpaced): the guard's reason
    ends the jog through Quick Stop Active, the drive disabled and still."""
    import can
    import canopen

    from controller.winch import load_winches
    from firmware_sim.cia402_drive import EDS_PATH
    from firmware_sim.drive_bank import SimulatedWinchBank
    from hal.drives_cia402 import DriveState
    from hal.motion import AxisMaster, JogInput, run_jog

    w = load_winches()
    ch = f"motion-guard-{time.monotonic_ns()}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), w)
    bank.set_positions_m(np.full(8, 12.0))
    bank.start()
    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.NOTIFIER_CYCLE = 0.05
    net.connect()
    try:
        m = AxisMaster(net, w, 2, EDS_PATH, clock="sync", pace=False)
        ax = w.axis(2)
        m.start(1)
        m.set_profile(int(round(0.2 / ax.metres_per_count)))
        seen: list = []
        calls = {"n": 0}

        def guard(fb):
            calls["n"] += 1
            return "cable 41: slack, 0.7 N below 1 N" if calls["n"] == 120 else None

        try:
            res = run_jog(m, lambda: JogInput.OUT, int(round(ax.m_to_counts(12.5))),
                          int(round(ax.m_to_counts(11.5))), 0.5, guard=guard,
                          on_cycle=lambda fb, ph: seen.append((fb.length_m, ph, fb.state)),
                          max_cycles=2000)
        finally:
            state, problems = m.finish()
            m.close()
        assert res.guard_stop == "cable 41: slack, 0.7 N below 1 N"
        assert res.reason.startswith("stopped: cable 41")
        assert res.cycles == 120  # ended at the guard's cycle, not by the input
        assert DriveState.QUICK_STOP_ACTIVE in [s for _, ph, s in seen if ph == "stopping"]
        assert state == "SWITCH_ON_DISABLED" and problems == []
        assert res.end_m > 12.0 + 1e-3  # it moved, then stood
        assert any("stop: cable 41" in text for _, text in m.log)
    finally:
        net.disconnect()
        bank.close()
