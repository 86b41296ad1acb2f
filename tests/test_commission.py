"""``cdpr commission`` against simulated drives on a python-can virtual bus and simulated load
cells on Modbus/TCP, in this process.

The drives run on their deterministic SYNC clock; API-level motion tests run the master in
lock-step (``pace=False``, ``clock="sync"``) so they count cycles, not seconds. CLI tests
go through ``bench.cli.main`` with ``--can virtual:CHANNEL``.
"""

from __future__ import annotations

import dataclasses
import json
import threading
import time

import can
import canopen
import numpy as np
import pytest
from drive_rig import BankRig

from bench.cli import main
from bench.commission.files import edit_length_at_zero
from bench.commission.loadcells import collect_points, fit_gain, measure_raw
from bench.recording import read_recording
from controller.winch import load_winches, m_to_counts
from firmware_sim.cia402_drive import EDS_PATH, SimulatedDrive
from firmware_sim.loadcell_bank import LoadCellBank
from firmware_sim.loadcell_server import LoadCellServer
from hal.drives import WinchDrives
from hal.drives_cia402 import DriveState
from hal.drives_config import Setting, _od_var, drive_settings, sdo_write
from hal.loadcell_calibration import load_calibration
from hal.loadcell_client import LoadCellClient
from hal.motion import AxisMaster, JogInput, MotionError, run_jog
from hal.sdo_config import (
    compare_configuration,
    expected_values,
    export_dcf,
    store_parameters,
)

W = load_winches()
L0 = np.linspace(9.0, 12.5, 8)


class Rig(BankRig):
    """Eight simulated drives on a virtual channel; ``net`` a master-side network on it."""

    def __init__(self, winches=W, before_start=None) -> None:
        super().__init__("commission", winches, L0, before_start)
        self.net = canopen.Network(can.Bus(interface="virtual", channel=self.ch))
        self.net.NOTIFIER_CYCLE = 0.05
        self.net.connect()

    def master(self, k: int, **kw) -> AxisMaster:
        kw.setdefault("clock", "sync")
        kw.setdefault("pace", False)
        return AxisMaster(self.net, W, k, EDS_PATH, **kw)

    def state(self, node_id: int):
        return self.bank.drive(node_id).state.name

    def close(self) -> None:
        self.net.disconnect()
        super().close()


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


class Cells:
    """Simulated load cells served on Modbus/TCP; a thread samples ``true_N`` at 200 Hz."""

    def __init__(self, **bank_kw) -> None:
        self.bank = LoadCellBank(**bank_kw)
        self.true_N = np.full(8, 100.0)
        self.server = LoadCellServer(self.bank, host="127.0.0.1", port=0).start()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.wait(0.005):
            self.bank.update(self.true_N)

    @property
    def spec(self) -> str:
        return self.server.endpoint

    def close(self) -> None:
        self._stop.set()
        self._t.join(2)
        self.server.stop()


@pytest.fixture
def cells():
    c = Cells(gain=np.r_[1.0, 1.0, 1.03, 1.0, 1.0, 1.0, 1.0, 1.0],
              offset_N=np.r_[0.0, 0.0, 12.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    yield c
    c.close()


def cli(capsys, *argv: str) -> tuple[int, dict]:
    """Run ``cdpr commission ARGV --json``; exit status and the JSON object."""
    capsys.readouterr()
    code = main(["commission", *argv, "--json"])
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1]) if out else {}


# ---------------------------------------------------------------------------- scan


def test_scan_finds_all_expected_nodes_and_cells_and_nothing_wrong(rig, cells, capsys, tmp_path):
    code, out = cli(capsys, "scan", "--can", rig.can, "--modbus", cells.spec,
                    "--report", str(tmp_path / "r.md"))
    assert code == 0 and out["ok"]
    assert [d["node_id"] for d in out["drives"]] == list(range(1, 9))
    for d in out["drives"]:
        assert set(d) >= {"node_id", "vendor_id", "product_code", "revision", "serial",
                          "expected"}
        assert d["status"] == "ok" and d["vendor_id"] == 0xCDB and d["product_code"] == 0x402
        assert d["serial"] == 0x1000 + d["node_id"]
        assert d["expected"]["cable"] == W.cables[d["node_id"] - 1]
    assert [c["device_id"] for c in out["load_cells"]] == list(range(1, 9))
    assert all(c["status"] == "ok" for c in out["load_cells"])
    assert out["load_cells"][0]["tension_n"] == pytest.approx(100.0, abs=1e-3)
    assert set(out["load_cells"][0]) >= {"device_id", "cable", "tension_n", "status"}
    report = (tmp_path / "r.md").read_text()
    assert "## " in report and "scan" in report and "| 8 | 42 | ok |" in report


def test_scan_reports_a_missing_and_an_extra_node_and_a_silent_cell(capsys, tmp_path):
    extra = {}

    def setup(r: Rig) -> None:
        d = SimulatedDrive(dataclasses.replace(W.axis(0), node_id=9), lock=r.bank.lock)
        d.attach(r.bank.network)
        extra["drive"] = d

    r = Rig(before_start=setup)
    extra["drive"].power_on()
    r.bank.drive(4).power_off()  # node 4 (cable 22) is not on the bus
    c = Cells()
    c.bank.inject("31", "no_answer")
    try:
        code, out = cli(capsys, "scan", "--can", r.can, "--modbus", c.spec, "--no-report")
    finally:
        c.close()
        r.close()
    assert code == 1 and not out["ok"]
    status = {d["node_id"]: d["status"] for d in out["drives"]}
    assert status == {1: "ok", 2: "ok", 3: "ok", 4: "missing", 5: "ok", 6: "ok", 7: "ok",
                      8: "ok", 9: "extra"}
    row9 = next(d for d in out["drives"] if d["node_id"] == 9)
    assert row9["expected"] is None and row9["serial"] == 0x1009
    row4 = next(d for d in out["drives"] if d["node_id"] == 4)
    assert row4["vendor_id"] is None and row4["expected"]["cable"] == "22"
    cells_status = {x["cable"]: x["status"] for x in out["load_cells"]}
    assert cells_status["31"] == "missing" and cells_status["32"] == "ok"


# ---------------------------------------------------------------------------- check


def test_check_finds_a_wrong_parameter_and_apply_fixes_and_stores_it(rig, capsys, tmp_path):
    rep = str(tmp_path / "report.md")
    code, out = cli(capsys, "check", "--can", rig.can, "--report", rep)
    assert code == 1  # drives out of the box: EDS defaults, not the HAL's table
    # exactly the objects of the HAL's table whose EDS default is not the table's value
    od = canopen.import_od(str(EDS_PATH), 1)
    for d in out["drives"]:
        k = W.index_of_node(d["node_id"])
        want = {(f"0x{st.index:04X}", st.subindex): st.value
                for st in expected_values(drive_settings(W, k, od))
                if _od_var(od, st.index, st.subindex).default != st.value}
        got = {(x["index"], x["subindex"]): x["expected"] for x in d["differences"]}
        assert got == want and len(got) > 5
    code, out = cli(capsys, "check", "--can", rig.can, "--apply", "--yes", "--listen", "0.1",
                    "--report", rep)
    assert code == 0 and out["applied"] == list(range(1, 9))
    code, out = cli(capsys, "check", "--can", rig.can, "--report", rep)
    assert code == 0 and all(d["differences"] == [] for d in out["drives"])  # nothing to find

    # a wrong following-error window, stored in the drive of node 3
    node = canopen.RemoteNode(3, canopen.import_od(str(EDS_PATH), 3))
    rig.net.add_node(node)
    sdo_write(node, Setting(0x6065, 0, 12345, "following error window"), "n3")
    store_parameters(node, "n3")
    code, out = cli(capsys, "check", "--can", rig.can, "--report", rep)
    assert code == 1
    bad = {d["node_id"]: d["differences"] for d in out["drives"] if d["differences"]}
    expected = int(round(W.following_error_m[2] / W.metres_per_count[2]))
    base = ("index", "subindex", "name", "expected", "actual")
    assert {n: [{k: d[k] for k in base} for d in ds] for n, ds in bad.items()} == {
        3: [{"index": "0x6065", "subindex": 0, "name": "following error window",
             "expected": expected, "actual": 12345}]}
    # a distance in metres, the counts kept with the unit in the key
    d = bad[3][0]
    assert d["actual_counts"] == 12345 and d["expected_counts"] == expected
    assert d["actual_m"] == pytest.approx(12345 * W.metres_per_count[2], rel=1e-12)
    assert d["actual_text"] == f"{12345e3 * W.metres_per_count[2]:.2f} mm (12345 counts)"
    code, out = cli(capsys, "check", "3", "--can", rig.can, "--report", rep)
    assert code == 2 and "node:N" in out["error"]  # "3" is no cable id
    code, out = cli(capsys, "check", "21", "--can", rig.can, "--apply", "--yes",
                    "--listen", "0", "--dcf", str(tmp_path / "dcf"), "--report", rep)
    assert code == 0 and out["applied"] == [3] and out["drives"][0]["differences"] == []
    rig.bank.drive(3).reset_node()  # parameters back to the stored ones
    time.sleep(0.05)
    left = compare_configuration(node, drive_settings(W, 2, node.object_dictionary), "n3")
    # everything stored but the mode of operation: process data (rww), written at each start
    assert [(d.index, d.actual) for d in left] == [(0x6060, 0)]
    dcf = canopen.import_od(out["dcf"][0])
    assert dcf.node_id == 3 and dcf[0x6065].value == expected
    assert dcf[0x1A00][2].value == 0x60640020  # TPDO1 maps the position actual value
    text = open(rep).read()
    assert text.count("## ") == 6 and "0x6065:00" in text and "applied" in text


def test_dcf_export_reads_back_with_canopen(rig, tmp_path):
    node = canopen.RemoteNode(5, canopen.import_od(str(EDS_PATH), 5))
    rig.net.add_node(node)
    path, failed = export_dcf(node, tmp_path / "n5.dcf", "n5")
    od = canopen.import_od(str(path))
    assert failed == [] and od.node_id == 5
    assert od[0x1018][4].value == 0x1005 and od[0x6065].value == 100000
    assert od[0x6041].value is None  # process data is no configuration


def _hal_master_running(rig: Rig):
    """The HAL cycling all drives in a thread (another master on the bus)."""
    hal = WinchDrives(rig.net, W, EDS_PATH, clock="sync")
    hal.start()
    stop = threading.Event()

    def cycle() -> None:
        while not stop.is_set():
            hal.step(0.2)
            time.sleep(0.002)

    t = threading.Thread(target=cycle, daemon=True)
    t.start()

    def close() -> None:
        stop.set()
        t.join(2)
        hal.close()

    return close


def test_moving_commands_refuse_while_another_master_is_active(capsys, tmp_path):
    r = Rig()
    other = Rig.__new__(Rig)  # a second master-side network on the same channel
    other.ch, other.bank = r.ch, r.bank
    other.net = canopen.Network(can.Bus(interface="virtual", channel=r.ch))
    other.net.connect()
    close = _hal_master_running(other)
    try:
        before = r.bank.positions_counts()
        code, out = cli(capsys, "jog", "21", "--can", r.can, "--yes", "--listen", "0.3",
                        "--no-report")
        assert code == 1 and "another master" in out["error"] and "SYNC" in out["error"]
        node = canopen.RemoteNode(2, canopen.import_od(str(EDS_PATH), 2))
        r.net.add_node(node)
        sdo_write(node, Setting(0x6065, 0, 777, "following error window"), "n2")
        code, out = cli(capsys, "check", "--can", r.can, "--apply", "--yes", "--listen", "0.3",
                        "--no-report")
        assert code == 1 and "another master" in out["error"]
        assert node.sdo.upload(0x6065, 0) == (777).to_bytes(4, "little")  # not written
        code, out = cli(capsys, "home", "21", "--method", "37", "--can", r.can, "--yes",
                        "--listen", "0.3", "--no-report")
        assert code == 1 and "another master" in out["error"]
        np.testing.assert_array_equal(r.bank.positions_counts(), before)
    finally:
        close()
        other.net.disconnect()
        r.close()


# ---------------------------------------------------------------------------- jog


def _jog(rig: Rig, k: int, inputs, deadman_s=0.2, travel_m=1.0, speed_m_s=0.2, log=None):
    m = rig.master(k)
    ax = W.axis(k)
    m.start(1)
    m.set_profile(int(round(speed_m_s / ax.metres_per_count)))
    start = ax.counts_to_m(m.read_position())
    it = iter(inputs)

    def read():
        x = next(it, JogInput.QUIT)
        if isinstance(x, BaseException):
            raise x
        return x

    try:
        res = run_jog(m, read, int(round(ax.m_to_counts(start + travel_m))),
                      int(round(ax.m_to_counts(start - travel_m))), deadman_s,
                      on_cycle=(lambda fb, ph: log.append((fb.length_m, ph, fb.state)))
                      if log is not None else None)
    finally:
        state, problems = m.finish()
        m.close()
    return res, state, problems


def test_jog_moves_while_input_comes_and_stops_when_the_deadman_input_stops(rig):
    log: list = []
    inputs = [JogInput.OUT] * 150 + [None] * 300 + [JogInput.QUIT]
    res, state, problems = _jog(rig, 2, inputs, deadman_s=0.2, log=log)
    assert state == "SWITCH_ON_DISABLED" and problems == []
    assert res.deadman_stops == 1 and res.reason == "operator quit"
    moving = [x for x in log[:150] if x[1] == "moving"]
    assert moving and moving[-1][0] > L0[2] + 0.05  # paid out while the key was held
    # after the input stopped: halt, then disabled; the cable stands still from then on
    phases = [x[1] for x in log]
    i_idle = phases.index("idle", 150)
    assert "halting" in phases[150:i_idle]
    after = np.array([x[0] for x in log[i_idle:]])
    assert np.ptp(after) == 0.0
    assert all(x[2] == DriveState.READY_TO_SWITCH_ON for x in log[i_idle:])
    assert log[i_idle][0] < L0[2] + 1.0  # stopped before the end of the travel window
    assert rig.state(3) == "SWITCH_ON_DISABLED"


def test_jog_in_reels_in_and_never_leaves_the_travel_window(rig):
    log: list = []
    # the input keeps coming for longer than the window takes at this speed
    res, state, _ = _jog(rig, 1, [JogInput.IN] * 400, travel_m=0.05, speed_m_s=0.5, log=log)
    assert state == "SWITCH_ON_DISABLED"
    assert res.min_m == pytest.approx(L0[1] - 0.05, abs=W.position_window_m[1])
    assert res.max_m <= L0[1] + 1e-6 and res.end_m < L0[1] - 0.04


def test_a_stop_key_halts_and_the_next_key_moves_again(rig):
    log: list = []
    inputs = [JogInput.OUT] * 60 + [JogInput.STOP] + [None] * 60 + [JogInput.IN] * 60
    res, state, _ = _jog(rig, 0, inputs, deadman_s=1.0, log=log)
    assert state == "SWITCH_ON_DISABLED" and res.moves == 2 and res.deadman_stops == 0
    lengths = np.array([x[0] for x in log])
    assert lengths[60:130].max() > L0[0] and lengths[-1] < lengths[120]


@pytest.mark.parametrize("error", ["drive_fault", "input_error", "ctrl_c", "silent_drive"])
def test_an_error_mid_jog_leaves_the_drive_disabled(rig, error):
    m = rig.master(3)
    ax = W.axis(3)
    m.start(1)
    n = [0]

    def read():
        n[0] += 1
        if n[0] == 80:
            if error == "drive_fault":
                rig.bank.drive(4).inject_over_current()
            elif error == "input_error":
                raise OSError("keyboard unplugged")
            elif error == "ctrl_c":
                raise KeyboardInterrupt
            else:
                rig.bank.drive(4).set_silent(True)
        return JogInput.OUT

    with pytest.raises((MotionError, OSError, KeyboardInterrupt)):
        try:
            run_jog(m, read, int(ax.m_to_counts(20.0)), int(ax.m_to_counts(5.0)), 0.5)
        finally:
            if error == "silent_drive":
                # still powered (enabled, or holding in quick stop on its RPDO deadline)
                assert rig.bank.drive(4).state.name in ("OPERATION_ENABLED",
                                                        "QUICK_STOP_ACTIVE")
                rig.bank.drive(4).set_silent(False)  # back: finish() disables it by SDO
            state, problems = m.finish()
            m.close()
    assert n[0] >= 80
    if error == "drive_fault":
        assert state == "FAULT" and any("0x2310" in p for p in problems), (state, problems)
    else:
        assert state == "SWITCH_ON_DISABLED", (state, problems)
    assert rig.bank.drive(4).state.name in ("FAULT", "SWITCH_ON_DISABLED")


def test_jog_cli_refuses_requests_beyond_the_winch_limits(rig, capsys):
    code, out = cli(capsys, "jog", "21", "--can", rig.can, "--speed", "1.5", "--yes",
                    "--no-report")
    assert code == 2 and "max_speed_m_s" in out["error"]
    code, out = cli(capsys, "jog", "21", "--can", rig.can, "--travel", "100", "--yes",
                    "--no-report")
    assert code == 2 and "--travel" in out["error"]
    code, out = cli(capsys, "jog", "77", "--can", rig.can, "--yes", "--no-report")
    assert code == 2 and "not a cable" in out["error"]
    rig.bank.drive_of_cable("21").set_position_counts(
        float(m_to_counts(np.full(8, 40.0), W)[2]))  # beyond max_length_m: unreferenced
    code, out = cli(capsys, "jog", "21", "--can", rig.can, "--yes", "--listen", "0",
                    "--no-report")
    assert code == 1 and "reference the winch first" in out["error"]
    assert rig.state(3) == "SWITCH_ON_DISABLED"  # never enabled


def test_jog_cli_without_yes_and_without_a_terminal_asks_for_yes(rig, capsys, monkeypatch):
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO("+++"))
    code, out = cli(capsys, "jog", "21", "--can", rig.can, "--listen", "0", "--no-report")
    assert code == 2 and "--yes" in out["error"]


# ---------------------------------------------------------------------------- home


def test_homing_sets_the_position_and_referencing_writes_the_winch_file(rig, capsys, tmp_path):
    wfile = tmp_path / "winches.toml"
    wfile.write_text(open(W.source).read())
    code, out = cli(capsys, "home", "21", "--can", rig.can, "--winches", str(wfile),
                    "--method", "37", "--offset", "1000", "--length", "12.0", "--yes",
                    "--listen", "0.1", "--hal-clock", "sync", "--report", str(tmp_path / "r.md"))
    assert code == 0, out
    assert out["position_before_counts"] == int(m_to_counts(L0, W)[2])
    assert out["position_after_counts"] == 1000 and rig.bank.drive(3).position_actual() == 1000
    assert out["state"] == "SWITCH_ON_DISABLED" and rig.state(3) == "SWITCH_ON_DISABLED"
    w2 = load_winches(wfile)
    assert w2.axis(2).counts_to_m(1000) == pytest.approx(12.0, abs=1e-12)
    assert out["length_m"] == pytest.approx(12.0)
    np.testing.assert_array_equal(np.delete(w2.length_at_zero_m, 2), 0.0)  # others untouched
    backups = list(tmp_path.glob("winches.toml.*.bak"))
    assert len(backups) == 1 and backups[0].read_text() == open(W.source).read()
    assert "cable = \"21\"" in wfile.read_text() and "# ROCASPECT winches" in wfile.read_text()
    # the HAL with the new file reads 12 m on cable 21
    hal = WinchDrives(rig.net, w2, EDS_PATH, clock="sync")
    try:
        hal.start()
        assert hal.lengths_m()[2] == pytest.approx(12.0, abs=1e-9)
        assert hal.lengths_m()[3] == pytest.approx(L0[3], abs=1e-6)
    finally:
        hal.close()
    assert "length_at_zero_m" in (tmp_path / "r.md").read_text()


def test_referencing_alone_does_not_move_the_drive(rig, capsys, tmp_path):
    wfile = tmp_path / "w.toml"
    wfile.write_text(open(W.source).read())
    pos = rig.bank.drive(8).position_actual()
    code, out = cli(capsys, "home", "node:8", "--can", rig.can, "--winches", str(wfile),
                    "--length", "10.25", "--yes", "--no-report")
    assert code == 0 and out["method"] is None
    assert rig.bank.drive(8).position_actual() == pos and rig.state(8) == "SWITCH_ON_DISABLED"
    assert load_winches(wfile).axis(7).counts_to_m(pos) == pytest.approx(10.25, abs=1e-12)
    code, out = cli(capsys, "home", "42", "--can", rig.can, "--winches", str(wfile),
                    "--length", "99", "--yes", "--no-report")
    assert code == 2 and "outside" in out["error"]
    code, out = cli(capsys, "home", "42", "--can", rig.can, "--no-report")
    assert code == 2


def test_edit_length_at_zero_replaces_or_inserts_only_that_winch():
    text = open(W.source).read()
    once = edit_length_at_zero(text, "32", 1.5, "w")
    twice = edit_length_at_zero(once, "32", -2.25, "w")
    assert twice.count("length_at_zero_m = -2.25") == 1 and "1.5" not in twice.split(
        "cable = \"32\"")[1].split("[[winch]]")[0]
    assert len(twice.splitlines()) == len(text.splitlines()) + 1
    import tomllib

    from controller.winch import parse_winches

    w = parse_winches(tomllib.loads(twice), "w")
    assert w.length_at_zero_m.tolist() == [0, 0, 0, 0, 0, -2.25, 0, 0]


# ---------------------------------------------------------------------------- load cells


def test_tare_and_calibrate_write_a_file_the_hal_then_applies(cells, capsys, tmp_path,
                                                              monkeypatch):
    cal_file = tmp_path / "cal.toml"
    cells.true_N[:] = 0.0
    code, out = cli(capsys, "tare", "21", "--modbus", cells.spec, "--loadcell-calibration",
                    str(cal_file), "--samples", "5", "--report", str(tmp_path / "r.md"))
    assert code == 0 and out["offset_N"] == pytest.approx(12.0, abs=1e-3)
    assert out["backup"] is None
    assert load_calibration(cal_file).offset_N[2] == pytest.approx(12.0, abs=1e-3)

    # known loads one after another, each put on when the command asks (Enter)
    loads = iter([0.0, 20 * 9.81, 50 * 9.81])

    class Operator:
        def readline(self) -> str:
            cells.true_N[2] = next(loads)
            time.sleep(0.05)  # the load settles
            return "\n"

        def isatty(self) -> bool:
            return False

    monkeypatch.setattr("sys.stdin", Operator())
    code, out = cli(capsys, "calibrate", "unit:3", "--modbus", cells.spec,
                    "--loadcell-calibration", str(cal_file), "--weights", "0,20,50kg",
                    "--samples", "5", "--report", str(tmp_path / "r.md"))
    assert code == 0, out
    assert out["gain"] == pytest.approx(1.03, rel=1e-5)
    assert out["offset_N"] == pytest.approx(12.0, abs=1e-3)
    assert out["residual_rms_N"] < 1e-3 and len(out["points"]) == 3
    assert out["backup"] and (tmp_path / out["backup"]).exists()
    cal = load_calibration(cal_file)
    assert cal.gain[2] == pytest.approx(1.03, rel=1e-5) and cal.gain[0] == 1.0

    # the HAL reads the true tension through the calibration file
    cells.true_N[:] = 300.0
    time.sleep(0.05)
    client = LoadCellClient(cells.spec, calibration=cal)
    try:
        client.poll_once()
        r = client.read()
    finally:
        client.stop()
    assert r.values_N[2] == pytest.approx(300.0, abs=1e-3)
    assert r.values_N[0] == pytest.approx(300.0, abs=1e-3)
    report = (tmp_path / "r.md").read_text()
    assert "tare" in report and "calibrate" in report and "residual" in report


def test_calibration_fit_with_noise_shows_its_residual(cells):
    cells.bank.noise_N = 0.5
    client = LoadCellClient(cells.spec, calibration=None)
    seq = iter([100.0, 400.0, 900.0, 1600.0])

    def ask(prompt: str) -> str:
        cells.true_N[2] = next(seq)
        time.sleep(0.03)
        return "\n"

    from bench.commission.common import Ui

    class A:
        json = True

    try:
        pts = collect_points(lambda: measure_raw(client, 2, 10), [100.0, 400.0, 900.0, 1600.0],
                             Ui(A()), ask, True, 9.81)
    finally:
        client.stop()
    fit = fit_gain(np.array([p[0] for p in pts]), np.array([p[1].mean_N for p in pts]), 0.0)
    assert fit.gain == pytest.approx(1.03, abs=0.002)
    assert fit.offset_N == pytest.approx(12.0, abs=1.5)
    assert 0 < fit.rms_N < 0.5


def test_calibrate_refuses_nonsense(cells, capsys, tmp_path):
    code, out = cli(capsys, "calibrate", "21", "--modbus", cells.spec, "--weights", "0,0",
                    "--no-wait", "--samples", "2", "--loadcell-calibration",
                    str(tmp_path / "c.toml"), "--no-report")
    assert code == 1 and "non-zero" in out["error"]
    assert not (tmp_path / "c.toml").exists()
    code, out = cli(capsys, "calibrate", "21", "--modbus", cells.spec, "--weights", "ten",
                    "--no-report")
    assert code == 2 and "kg" in out["error"]
    cells.bank.inject("21", "sensor_fault")
    code, out = cli(capsys, "tare", "21", "--modbus", cells.spec, "--samples", "2",
                    "--loadcell-calibration", str(tmp_path / "c.toml"), "--no-report")
    assert code == 1 and "unit 3" in out["error"] and not (tmp_path / "c.toml").exists()


# ---------------------------------------------------------------------------- monitor


def test_monitor_records_a_recording_and_logs_every_frame(rig, cells, capsys, tmp_path):
    rec = tmp_path / "rec"
    dump = tmp_path / "bus.asc"
    rig.bank.drive(5).inject_over_current()  # an error the monitor must show
    code, out = cli(capsys, "monitor", "--can", rig.can, "--modbus", cells.spec,
                    "--duration", "0.6", "--rate", "10", "--record", str(rec),
                    "--candump", str(dump), "--init-pose", "10,8.56,1",
                    "--report", str(tmp_path / "r.md"))
    assert code == 0 and out["ended_by"] == "--duration 0.6 s"
    assert out["refreshes"] >= 2 and out["rows"] == out["refreshes"]
    states = {d["node_id"]: d["state"] for d in out["drives"]}
    assert states[5] == "FAULT" and states[1] == "SWITCH_ON_DISABLED"
    assert next(d for d in out["drives"] if d["node_id"] == 5)["error_code"] == 0x2310
    r = read_recording(rec)
    assert r.n_samples == out["rows"]
    np.testing.assert_allclose(r.l_meas[0], L0, atol=1e-6)
    np.testing.assert_allclose(r.tau[0], 100.0 * np.r_[1, 1, 1.03, 1, 1, 1, 1, 1]
                               + np.r_[0, 0, 12, 0, 0, 0, 0, 0], atol=1e-3)
    assert r.extra["drive_state_31"][0] == DriveState.FAULT
    frames = list(can.LogReader(str(dump)))
    ids = {f.arbitration_id for f in frames}
    assert 0x605 in ids and 0x585 in ids  # our SDO requests and the drives' answers
    assert len(frames) >= 2 * 8 * 4 * out["refreshes"]


def test_monitor_first_row_waits_for_a_whole_sweep_of_slow_cells(rig, cells, capsys,
                                                                  tmp_path, monkeypatch):
    """Cells slow to connect: the recording's first row still holds every tension (it
    once began with the cells not yet read as NaN)."""
    from hal.loadcell_client import LoadCellClient

    run = LoadCellClient._run_pipelined

    def slow_start(self):  # a slow first connection
        time.sleep(0.3)
        return run(self)

    monkeypatch.setattr(LoadCellClient, "_run_pipelined", slow_start)
    rec = tmp_path / "rec"
    code, out = cli(capsys, "monitor", "--can", rig.can, "--modbus", cells.spec,
                    "--duration", "0.2", "--rate", "10", "--record", str(rec),
                    "--init-pose", "10,8.56,1", "--no-report")
    assert code == 0
    r = read_recording(rec)
    assert np.isfinite(r.tau[0]).all()
    np.testing.assert_allclose(r.tau[0][:2], 100.0, atol=1e-3)


def test_monitor_shows_a_drive_that_does_not_answer(rig, capsys):
    rig.bank.drive(2).set_silent(True)
    code, out = cli(capsys, "monitor", "--can", rig.can, "--duration", "0.3", "--no-report")
    assert code == 0
    d2 = next(d for d in out["drives"] if d["node_id"] == 2)
    assert d2["answered"] is False and d2["state"] == "UNKNOWN"
    assert any("node 2" in e and "stopped answering" in e for e in out["events"])
    assert all(d["answered"] for d in out["drives"] if d["node_id"] != 2)


def test_disable_resets_a_fault_and_reports_the_state(rig, capsys):
    rig.bank.drive(6).inject_over_current()
    rig.bank.advance(0.5)
    code, out = cli(capsys, "disable", "32", "--can", rig.can, "--no-report")
    assert code == 1 and out["before"] == "FAULT" and out["state"] == "FAULT"
    assert out["error_code"] == 0x2310
    code, out = cli(capsys, "disable", "32", "--can", rig.can, "--fault-reset", "--no-report")
    assert code == 0 and out["state"] == "SWITCH_ON_DISABLED" and out["error_code"] == 0


def test_enable_holds_the_position_and_disables_at_the_end(rig, capsys, monkeypatch):
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # no keys: --duration ends it
    code, out = cli(capsys, "enable", "41", "--can", rig.can, "--yes", "--listen", "0",
                    "--duration", "0.3", "--no-report")
    assert code == 0 and out["ended_by"] == "--duration 0.3 s"
    assert out["state"] == "SWITCH_ON_DISABLED" and rig.state(7) == "SWITCH_ON_DISABLED"
    assert out["length_m"] == pytest.approx(L0[6], abs=1e-6) and out["moved_m"] == 0.0
    monkeypatch.setattr("sys.stdin", io.StringIO("q"))
    code, out = cli(capsys, "enable", "41", "--can", rig.can, "--yes", "--listen", "0",
                    "--no-report")
    assert code == 0 and out["ended_by"] == "operator" and rig.state(7) == "SWITCH_ON_DISABLED"


def test_scan_rows_name_wrong_devices_and_nothing_when_all_match():
    from bench.commission.scan import drive_rows, expected_identity
    from hal.scan import NodeIdentity

    ident = expected_identity(str(EDS_PATH))
    good = dict(device_type=ident["device_type"], vendor_id=0xCDB, product_code=0x402,
                revision=0x10000, answered_sdo=True)
    found = [NodeIdentity(k + 1, serial=k, **good) for k in range(8)]
    rows = drive_rows(found, W, ident)
    assert [r["status"] for r in rows] == ["ok"] * 8 and all(not r["problems"] for r in rows)
    found[1] = NodeIdentity(2, **{**good, "product_code": 0x999})
    found[2] = NodeIdentity(3, **{**good, "revision": 0x20000})
    found[3] = NodeIdentity(4, nmt_state="STOPPED", error="no SDO answer")
    found[4] = NodeIdentity(5, **{**good, "vendor_id": 0x1})
    rows = drive_rows(found, W, ident)
    assert [r["status"] for r in rows] == ["ok", "wrong_product", "wrong_revision", "no_sdo",
                                           "wrong_vendor", "ok", "ok", "ok"]
    assert "0x00000999" in rows[1]["problems"][0] and rows[3]["nmt_state"] == "STOPPED"


def test_monitor_table_refreshes_in_place_on_a_terminal_and_in_blocks_otherwise():
    import io

    from bench.commission.monitor import _Screen

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    t, p = Tty(), io.StringIO()
    for out in (t, p):
        s = _Screen(out)
        s.show(["a", "b"])
        s.show(["c", "d"])
    assert t.getvalue() == "\x1b[J" + "a\nb\n" + "\x1b[2F\x1b[J" + "c\nd\n"
    assert p.getvalue() == "a\nb\n\nc\nd\n\n" and "\x1b" not in p.getvalue()


def test_bad_input_is_a_usage_error_naming_the_file(capsys, tmp_path):
    code, out = cli(capsys, "scan", "--can", "virtual:nobody-x", "--eds", str(tmp_path / "no.eds"),
                    "--no-report")
    assert code == 2 and "no.eds" in out["error"]
    bad = tmp_path / "w.toml"
    bad.write_text("[bus]\nbitrate = 3\n")
    code, out = cli(capsys, "check", "--can", "virtual:nobody-x", "--winches", str(bad),
                    "--no-report")
    assert code == 2 and "w.toml" in out["error"] and "bitrate" in out["error"]
    code, out = cli(capsys, "tare", "21", "--no-report")
    assert code == 2 and "--modbus" in out["error"]
