"""The dry run against the simulated robot: in this process (virtual CAN bus, Modbus/TCP on
loopback, lock-step), through the ``cdpr dry-run`` command, and once against ``cdpr sim`` in
another process. Short runs: seconds of the paper's centre path."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.dryrun.loop import ControlLoop, LoopOptions
from bench.dryrun.record import DryRunRecorder
from bench.dryrun.scenarios import max_rate_hz, resolve_scenario, sync_period_us
from bench.dryrun.world import start_world, with_rate
from bench.recording import read_recording
from controller.paths import build_trajectory, load_path
from controller.winch import load_winches
from firmware_sim.scenario import load_scenario
from hal.drives_cia402 import DriveState

ROOT = Path(__file__).resolve().parents[1]
SC = load_scenario(resolve_scenario("paper-centre"))
RATE = max_rate_hz(load_winches())
WINCHES = with_rate(load_winches(), sync_period_us(RATE) * 1e-6)


def _run(model, seconds, tmp_path=None, stop_at=None):
    spec = load_path("paper-centre")
    stop = threading.Event()
    with start_world(SC, WINCHES) as world:
        def progress(res, t_traj):
            if stop_at is not None and t_traj >= stop_at:
                stop.set()

        rec = None
        if tmp_path is not None:
            def rec(p0):
                return DryRunRecorder(tmp_path / "rec", model, p0, {})
        loop = ControlLoop(world.hw, world.tracker, model,
                           lambda p0: build_trajectory(spec, p0),
                           LoopOptions(max_duration_s=seconds, decimate=5), rec,
                           tick=world.tick, on_progress=progress, stop=stop)
        res = loop.run()
        states = world.hw.read().states
    return res, states


def test_true_model_follows_within_the_noise_nominal_does_not():
    res_true, _ = _run(SC.truth, 6.0)
    res_nom, _ = _run(SC.model, 6.0)
    assert res_true.ended == res_nom.ended == "completed"
    # truth in the controller: process noise (0.5 mm per visit) and the tracker's 0.05 mm
    assert res_true.pose_error_rms_m < 2e-3, res_true.pose_error_rms_m
    # the nominal model misses by the settled ropes and the bending masts
    assert res_nom.pose_error_rms_m > 2 * res_true.pose_error_rms_m
    assert res_nom.pose_error_max_m > 5e-3


def test_stop_mid_run_holds_the_drives_and_keeps_the_recording(tmp_path):
    res, states = _run(SC.model, 6.0, tmp_path, stop_at=1.5)
    assert res.ended == "interrupted"
    assert np.all(states == DriveState.QUICK_STOP_ACTIVE) or np.all(
        states == DriveState.SWITCH_ON_DISABLED)  # held (0x605A option of the winch file)
    assert not np.any(states == DriveState.OPERATION_ENABLED)
    rec = read_recording(tmp_path / "rec")
    assert rec.n_samples > 50 and rec.state[-1] == "quick_stop"
    assert rec.state[0] == "init" and "move" in rec.state
    events = (tmp_path / "rec" / "events.csv").read_text()
    assert "interrupted" in events


def test_cli_json_recording_and_plots(tmp_path, capsys):
    code = main(["dry-run", "paper-centre", "--duration", "2", "--json", "--quiet",
                 "--record", str(tmp_path / "rec"), "--plots", str(tmp_path / "plots")])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["ended"] == "completed"
    for key in ("scenario", "robot", "cycles", "rate_hz", "simulated_s", "wall_s", "overruns",
                "events", "pose_error_rms_m", "pose_error_max_m", "recording"):
        assert key in out
    assert out["rate_hz"] == pytest.approx(RATE)
    assert out["cycles"] > 500 and out["overruns"] == 0
    assert out["recording"] == str(tmp_path / "rec")
    rec = read_recording(tmp_path / "rec")
    fix = np.isfinite(rec.pose_meas).all(axis=1)  # the tracker's fixes, each on its row
    assert rec.robot.name == "rocaspect" and rec.t[-1] - rec.t[fix][-1] < 0.1
    assert all(Path(p).stat().st_size > 10_000 for p in out["plots"])


@pytest.mark.parametrize("argv, message", [
    (["dry-run", "paper-centre", "--rate", "1000"], "above the"),
    (["dry-run", "no-such-scenario"], "shipped"),
    (["dry-run", "paper-centre", "--path", "no-such-path"], "no-such-path"),
    (["dry-run", "paper-centre", "--speed-pct", "150"], "speed-pct"),
])
def test_cli_refuses_bad_input_before_starting(argv, message, capsys):
    assert main(argv + ["--json"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert message in out["error"]


def test_cli_refuses_a_non_empty_record_dir(tmp_path, capsys):
    (tmp_path / "rec").mkdir()
    (tmp_path / "rec" / "keep.txt").write_text("data")
    assert main(["dry-run", "paper-centre", "--record", str(tmp_path / "rec"), "--json"]) == 2
    assert "not empty" in json.loads(capsys.readouterr().out)["error"]
    assert (tmp_path / "rec" / "keep.txt").read_text() == "data"


def _cli(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "bench.cli", "dry-run", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def test_against_cdpr_sim_in_another_process():
    p = _cli("paper-centre", "--rig", "process", "--duration", "1.5", "--json", "--quiet")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    res = json.loads(out)
    assert res["ended"] == "completed" and res["rig"] == "process"
    assert res["pose_error_rms_m"] is not None and res["pose_error_rms_m"] < 0.05


def test_sigint_stops_the_platform_and_leaves_a_readable_recording(tmp_path):
    rec = tmp_path / "rec"
    p = _cli("paper-centre", "--json", "--record", str(rec))
    # wait until the platform moves (the recording has move rows), then Ctrl-C
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        csv = rec / "recording.csv"
        if csv.exists() and ",move" in csv.read_text():
            break
        time.sleep(0.2)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, err  # 128 + SIGINT, the last line says so
    assert err.strip().splitlines()[-1] == "cdpr dry-run: interrupted (SIGINT)"
    res = json.loads(out)
    assert res["ended"] == "interrupted"
    assert "OPERATION_ENABLED" not in res["drive_states"]
    r = read_recording(rec)
    assert r.state[-1] == "quick_stop" and r.n_samples > 10


FAULTS = """
[[fault]]
at_s = {cell_at}
cell = 5
kind = "nan"
clear_s = {cell_clear}

[[fault]]
at_s = {drive_at}
drive = 3
kind = "over_current"
"""


@pytest.mark.parametrize("rig", ["inprocess", "process"])
def test_fault_schedule_gets_its_reactions_and_is_recorded(rig, tmp_path):
    """A load cell that reads NaN for a while is substituted (start and end logged), then an
    over-current on node 3 quick-stops every drive; the recording says so."""
    faults = tmp_path / "faults.toml"
    faults.write_text(FAULTS.format(cell_at=0.4, cell_clear=0.8, drive_at=1.2))
    rec = tmp_path / "rec"
    p = _cli("paper-centre", "--rig", rig, "--faults", str(faults), "--duration", "3",
             "--record", str(rec), "--json", "--quiet")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 1, err
    res = json.loads(out)
    ev = res["events"]
    # unit 5's NaN from 0.4 s to 0.8 s (a loaded machine may add stale readings of others):
    # substituted while the fault lasts and released after it clears, before the drive's
    # fault; how soon is a latency, which `cdpr bench` measures (with the separate-process
    # rig a loaded machine took 52 ms where 50 were allowed)
    subs = [(e["t"], e["active"]) for e in ev
            if e["reaction"] == "substitute" and e["address"] == 5]
    assert subs and subs[0][1] and 0.39 <= subs[0][0] < 0.8, ev
    assert any(not a and 0.79 <= t < 1.2 for t, a in subs), ev
    faults_ev = [e for e in ev if e["reaction"] in ("quick_stop", "disable")]
    assert faults_ev and faults_ev[0]["address"] == 3 and faults_ev[0]["code"] == 0x2310, ev
    assert "OPERATION_ENABLED" not in res["drive_states"]
    r = read_recording(rec)
    assert r.state[-1] == "quick_stop"
    events_csv = (rec / "events.csv").read_text()
    assert "0x2310" in events_csv.lower() or "9008" in events_csv  # code as hex or decimal


def test_fault_schedule_errors_name_the_file_line_and_field(tmp_path, capsys):
    faults = tmp_path / "faults.toml"
    faults.write_text('[[fault]]\nat_s = 1.0\ndrive = 42\nkind = "over_current"\n')
    assert main(["dry-run", "paper-centre", "--faults", str(faults), "--json"]) == 2
    err = json.loads(capsys.readouterr().out)["error"]
    assert str(faults) in err and ":3" in err and "drive" in err


@pytest.mark.parametrize("opt", ["--record", "--plots"])
def test_cli_refuses_an_output_it_cannot_write_before_starting(opt, tmp_path, capsys):
    (tmp_path / "blk").write_text("a file")
    assert main(["dry-run", "paper-centre", opt, str(tmp_path / "blk" / "out"), "--json"]) == 2
    err = json.loads(capsys.readouterr().out)["error"]
    assert opt in err and "not a directory" in err


def test_cli_plots_without_a_recording(tmp_path, capsys):
    code = main(["dry-run", "paper-centre", "--duration", "0.5", "--json", "--quiet",
                 "--plots", str(tmp_path / "plots")])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["recording"] is None
    assert out["plots"] and all(Path(p).stat().st_size > 10_000 for p in out["plots"])


@pytest.mark.parametrize("watch_wall", [False, True])
def test_lockstep_in_process_survives_a_starved_heartbeat_thread(watch_wall):
    """In lock-step in one process the master cannot die apart from the drives: a starved
    master-heartbeat thread (a busy host) must not stop them. With the wall-clock watch on
    (the setting for a master in another process) the same starvation does stop them."""
    sc = load_scenario(resolve_scenario("paper-centre"))
    world = start_world(sc, load_winches(), "inprocess", realtime=False)
    try:
        for d in world.rig.bank.drives:
            d.watch_wall = watch_wall
        hw = world.hw
        hw.start()
        hw.enable()
        drives = hw.drives
        drives._mhb_stop.set()  # the heartbeat thread starved for 0.6 s of wall time
        drives._mhb_thread.join(timeout=5.0)
        time.sleep(0.6)
        for _ in range(20):
            r = hw.step()
        if watch_wall:  # stopped, pre-operational (0x1029 = 0): no longer said enabled
            assert not np.any(r.states == DriveState.OPERATION_ENABLED), r.states
            assert all(d.state.name == "QUICK_STOP_ACTIVE" for d in world.rig.bank.drives)
            assert {f.kind for f in hw.faults()} & {"nmt_state", "quick_stop"}
        else:
            assert np.all(r.states == DriveState.OPERATION_ENABLED), r.states
            assert hw.faults() == []
    finally:
        world.close()


def test_a_scenario_changes_the_default_reactions_and_the_command_line_wins(tmp_path, capsys):
    from firmware_sim.scenario import ScenarioError

    assert load_scenario(resolve_scenario("paper-calibration")).react == {"slack": "log"}
    assert SC.react == {}
    text = resolve_scenario("paper-centre").read_text(encoding="utf-8")
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('format = "cdpr-scenario/1"',
                                'format = "cdpr-scenario/1"\nreact = { slack = "ignore" }'),
                   encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"bad\.toml: react\.slack"):
        load_scenario(bad)
    code = main(["dry-run", "paper-calibration", "--duration", "0.3", "--json"])
    err = capsys.readouterr().err
    assert code == 0 and "reactions changed: slack=log (scenario: slack=log)" in err
    code = main(["dry-run", "paper-calibration", "--duration", "0.3", "--json",
                 "--react", "slack=hold"])
    err = capsys.readouterr().err
    assert code == 0 and "reactions changed: slack=hold (scenario: slack=log)" in err
