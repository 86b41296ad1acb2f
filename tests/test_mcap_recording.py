"""MCAP recordings: what a dry run writes opens in the ``mcap`` reader (summary, CRCs) and
reads as its CSV twin; CSV <-> MCAP round trips keep every column; a writer killed mid-way
leaves a file that reads up to its last chunk; ``cdpr diagnose`` gives the same report of
an MCAP recording as of its CSV directory."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bench.cli import main
from bench.mcap import (
    MCAP_NAME,
    McapRecordingWriter,
    csv_to_mcap,
    mcap_to_csv,
    read_mcap,
)
from bench.recording import RecordingError, read_recording, write_recording
from controller.robot import resolve_robot

ROOT = Path(__file__).resolve().parents[1]


def open_with_mcap_reader(path: Path) -> dict[str, int]:
    """Every record through the mcap library's readers: the seeking reader's summary and
    a streaming pass with CRC validation; the message count of each topic."""
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    with path.open("rb") as f:
        n = sum(1 for _ in StreamReader(f, validate_crcs=True).records)
    assert n > 0
    with path.open("rb") as f:
        got = sum(1 for _ in make_reader(f).iter_messages())
    assert got == summary.statistics.message_count
    return {ch.topic: summary.statistics.channel_message_counts.get(i, 0)
            for i, ch in summary.channels.items()}


def test_dry_run_format_both_mcap_equals_csv(tmp_path, capsys):
    rec = tmp_path / "rec"
    assert main(["dry-run", "paper-centre", "--duration", "0.5", "--json", "--quiet",
                 "--record", str(rec), "--format", "both"]) == 0
    json.loads(capsys.readouterr().out)
    counts = open_with_mcap_reader(rec / MCAP_NAME)
    csv_rec = read_recording(rec)
    n = csv_rec.n_samples
    for topic in ("/pose/desired", "/pose/measured", "/cables/lengths", "/cables/tensions",
                  "/loop", "/tf"):
        assert counts[topic] == n, topic
    span = csv_rec.t[-1] - csv_rec.t[0]  # the scene at most every 0.1 s, the first row too
    assert max(2, span / 0.2) <= counts["/scene"] <= 2 + span / 0.1
    assert counts["/supervisor/events"] >= 1
    out = tmp_path / "back"
    mcap_to_csv(rec / MCAP_NAME, out)
    for name in ("recording.csv", "events.csv", "meta.toml", "robot.toml"):
        assert (out / name).read_bytes() == (rec / name).read_bytes(), name


def _mcap_messages(path: Path, topic: str) -> list[dict]:
    """The JSON messages of ``topic`` through the mcap library's reader, in log order."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [json.loads(m.data) for _, _, m in
                make_reader(f).iter_messages(topics=[topic], log_time_order=True)]


def _drive_states(rec, cables) -> np.ndarray:
    """The ``drive_state_{ij}`` columns of a recording, rows by cables."""
    return np.array([rec.extra[f"drive_state_{c}"] for c in cables]).T


def test_dry_run_records_the_drive_states_in_csv_and_mcap(tmp_path, capsys):
    """A drive faults mid-run (lock-step): each row carries the eight CiA 402 states, the
    rows where they change too (enabled, the fault, then the others' quick stop, the final
    states of the run); ``/drives/state`` holds the same numbers as the CSV, and CSV ->
    MCAP -> CSV keeps them."""
    from hal.drives_cia402 import DriveState

    (tmp_path / "f.toml").write_text('[[fault]]\nat_s = 0.4\ndrive = 3\n'
                                     'kind = "over_current"\n', encoding="utf-8")
    rec = tmp_path / "rec"
    assert main(["dry-run", "paper-centre", "--duration", "1.0", "--json", "--quiet",
                 "--faults", str(tmp_path / "f.toml"), "--decimate", "8",
                 "--record", str(rec), "--format", "both"]) == 1
    res = json.loads(capsys.readouterr().out)
    assert res["ended"] == "quick_stop", res
    csv_rec = read_recording(rec)
    cables = csv_rec.robot.cable_ids
    states = _drive_states(csv_rec, cables)
    assert states.shape == (csv_rec.n_samples, 8)
    assert (states[0] == DriveState.OPERATION_ENABLED).all()
    assert states[-1].tolist() == [DriveState[s] for s in res["drive_states"]]  # the end
    faulted = next(e["cable"] for e in res["events"] if e["kind"] == "drive_fault")
    k = cables.index(faulted)
    first_fault = int(np.flatnonzero(states[:, k] == DriveState.FAULT)[0])
    assert (states[first_fault - 1] == DriveState.OPERATION_ENABLED).all()
    assert DriveState.QUICK_STOP_ACTIVE in states[:, k - 1 if k else 1]
    counts = open_with_mcap_reader(rec / MCAP_NAME)
    assert counts["/drives/state"] == csv_rec.n_samples
    msgs = _mcap_messages(rec / MCAP_NAME, "/drives/state")
    from_mcap = np.array([[m["state"][c] for c in cables] for m in msgs], dtype=float)
    np.testing.assert_array_equal(from_mcap, states)
    np.testing.assert_array_equal([m["t"] for m in msgs], csv_rec.t)
    assert main(["recording", "convert", str(rec), str(tmp_path / "r.mcap"), "--json"]) == 0
    assert main(["recording", "convert", str(tmp_path / "r.mcap"), str(tmp_path / "back"),
                 "--json"]) == 0
    capsys.readouterr()
    back = read_recording(tmp_path / "back")
    _same(_drive_states(back, cables), states)
    _same(_drive_states(read_recording(rec / MCAP_NAME), cables), states)
    assert set(back.extra) == set(csv_rec.extra)


def test_dry_run_format_mcap_reads_as_a_recording(tmp_path, capsys):
    rec = tmp_path / "rec"
    assert main(["dry-run", "paper-centre", "--duration", "0.3", "--quiet", "--json",
                 "--record", str(rec), "--format", "mcap"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in rec.iterdir()) == [MCAP_NAME]
    open_with_mcap_reader(rec / MCAP_NAME)
    for path in (rec, rec / MCAP_NAME):  # the directory or the file
        r = read_recording(path)
        assert r.path == path and r.state[0] == "init" and r.n_samples > 10
        have = np.isfinite(r.tau).all(axis=1)  # the load cells' samples, each on its row
        assert have.sum() > 3 and (have | np.isnan(r.tau).all(axis=1)).all()
        assert np.isfinite(r.l_cmd).all()
    c = read_mcap(rec)
    assert not c.truncated
    assert "dry run: completed" in c.meta_text  # the meta updated at the end is the one read


def _robot():
    return resolve_robot("rocaspect")


def _odd_recording(d: Path) -> Path:
    """A hand-made recording: ``t`` not first, ``state`` in the middle, exit points, drive
    feedback, an unknown column, nan and empty cells, a negative time."""
    robot = _robot()
    ids = robot.cable_ids
    header = (["x_meas", "t", "state"] + [f"tau_{k}" for k in ids] + [f"l_meas_{k}" for k in ids]
              + ["ax_meas_11", "ay_meas_11", "az_meas_11", f"vel_{ids[0]}", "humidity"]
              + ["y_meas", "z_meas", "roll_meas", "pitch_meas", "yaw_meas"])
    rng = np.random.default_rng(4)
    lines = [",".join(header)]
    for i in range(12):
        vals = []
        for h in header:
            if h == "t":
                vals.append(repr(-0.5 + 0.25 * i))
            elif h == "state":
                vals.append("dwell" if i % 3 else "move")
            elif h == "humidity" and i == 3:
                vals.append("")
            elif h.startswith("tau_") and i == 5:
                vals.append("nan")
            else:
                vals.append(repr(float(rng.normal(5.0, 3.0))))
        lines.append(",".join(vals))
    d.mkdir()
    (d / "recording.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    from controller.robot import dumps_robot

    (d / "robot.toml").write_text(dumps_robot(robot, "hand made"), encoding="utf-8")
    (d / "meta.toml").write_text('format = "cdpr-recording/1"\nrobot = "robot.toml"\n'
                                 'samples = "recording.csv"\n'
                                 "init_pose = [10.0, 8.56, 1.0, 0.0, 0.0, 0.0]\n"
                                 'notes = "by hand"\n', encoding="utf-8")
    (d / "events.csv").write_text(
        't,device,address,cable,kind,code,reaction,active,text\n'
        '0.5,drive,3,21,emcy,0x2310,event,1,"over-current, \'phase\' A"\n'
        '1.25,controller,0,,slack,0x0000,quick_stop,0,"slack ended"\n', encoding="utf-8")
    return d


def _same(a, b) -> None:
    """Equal arrays, nan where nan (float precision: bit for bit here)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape
    assert np.array_equal(a, b, equal_nan=True)


def test_csv_mcap_csv_round_trip_keeps_every_column(tmp_path, capsys):
    src = _odd_recording(tmp_path / "src")
    assert main(["recording", "convert", str(src), str(tmp_path / "r.mcap"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["to"] == "mcap" and out["rows"] == 12 and out["events"] == 2
    counts = open_with_mcap_reader(tmp_path / "r.mcap")
    assert counts["/cables/exits"] == 12 and counts["/drives/feedback"] == 12
    assert counts["/recording/other"] == 12
    assert main(["recording", "convert", str(tmp_path / "r.mcap"), str(tmp_path / "back"),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["to"] == "csv" and out["rows"] == 12
    a, b = read_recording(src), read_recording(tmp_path / "back")
    for g in ("t", "pose_des", "pose_meas", "l_cmd", "l_meas", "tau", "exit_meas"):
        _same(getattr(a, g), getattr(b, g))
    assert a.state == b.state and set(a.extra) == set(b.extra) == {f"vel_{a.robot.cable_ids[0]}",
                                                                   "humidity"}
    for k in a.extra:
        _same(a.extra[k], b.extra[k])
    # the header order, the events and the text files come back as they were
    assert ((tmp_path / "back" / "recording.csv").read_text().splitlines()[0]
            == (src / "recording.csv").read_text().splitlines()[0])
    assert (tmp_path / "back" / "events.csv").read_text() == (src / "events.csv").read_text()
    assert (tmp_path / "back" / "robot.toml").read_text() == (src / "robot.toml").read_text()
    # the MCAP file reads as the recording too
    _same(read_recording(tmp_path / "r.mcap").tau, a.tau)


def test_convert_refuses_existing_output_and_bad_input(tmp_path, capsys):
    src = _odd_recording(tmp_path / "src")
    (tmp_path / "taken.mcap").write_bytes(b"x")
    assert main(["recording", "convert", str(src), str(tmp_path / "taken.mcap"),
                 "--json"]) == 2
    assert "exists" in json.loads(capsys.readouterr().out)["error"]
    assert main(["recording", "convert", str(src), str(tmp_path / "taken.mcap"), "--force",
                 "--json"]) == 0
    capsys.readouterr()
    (tmp_path / "empty").mkdir()
    assert main(["recording", "convert", str(tmp_path / "empty"), str(tmp_path / "o"),
                 "--json"]) == 2
    err = json.loads(capsys.readouterr().out)["error"]
    assert str(tmp_path / "empty") in err and "meta.toml" in err


def test_an_mcap_file_that_is_no_recording_is_refused_naming_it(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "other.mcap"
    with p.open("wb") as f:
        w = Writer(f)
        w.start()
        w.finish()
    with pytest.raises(RecordingError, match=r"other\.mcap.*cdpr-recording"):
        read_recording(p)


KILLED_WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from bench.mcap import McapRecordingWriter
    from controller.robot import resolve_robot
    robot = resolve_robot("rocaspect")
    cols = ["t", "x_des", "tau_11", "cycle"]
    w = McapRecordingWriter(sys.argv[1], robot, np.zeros(6), cols, flush_s=0.05)
    i = 0
    while True:
        w.append([0.01 * i, 10.0 + i, 100.0 + 0.5 * i, float(i)], "move")
        if i % 7 == 0:
            w.event(0.01 * i, "drive", 3, "21", "emcy", 0x2310, "event", True, f"row {i}")
        i += 1
        time.sleep(0.0005)
""")


def test_a_writer_killed_mid_way_leaves_a_readable_file(tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(path)], env=env)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # a few chunks on disk
            if path.exists() and path.stat().st_size > 3000:
                break
            time.sleep(0.05)
        time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    c = read_mcap(path)
    assert c.truncated and len(c.data) > 5
    i = np.arange(len(c.data))
    _same(c.data, np.column_stack([0.01 * i, 10.0 + i, 100.0 + 0.5 * i, i]))
    assert c.states == ["move"] * len(i)
    assert [e["text"] for e in c.events] == [f"row {k}" for k in range(0, 7 * len(c.events), 7)]
    rec = read_recording(path)  # and as a recording, the rows up to the last chunk
    assert rec.n_samples == len(c.data)
    assert main(["recording", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert not info["whole"] and info["rows"] == len(c.data) and info["chunks"] >= 2
    assert info["compression"] == ["zstd"]


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
cell = st.one_of(finite, st.just(math.nan))


@given(rows=st.lists(st.tuples(finite, cell, cell, cell, cell), min_size=1, max_size=8),
       states=st.lists(st.sampled_from(["init", "move", "dwell", ""]), min_size=8,
                       max_size=8))
def test_property_writer_reader_round_trip_is_exact(tmp_path_factory, rows, states):
    d = tmp_path_factory.mktemp("prop")
    robot = _robot()
    cols = ["t", "z_meas", "tau_21", "l_cmd_42", "oddity"]
    path = d / "p.mcap"
    with McapRecordingWriter(path, robot, np.zeros(6), cols, flush_s=3600.0,
                             scene=False) as w:
        for k, r in enumerate(rows):
            w.append(list(r), states[k])
    c = read_mcap(path)
    _same(c.data, np.array(rows, dtype=float))
    assert c.states == states[:len(rows)] and not c.truncated


@pytest.fixture
def campaign_recording(tmp_path) -> Path:
    poses = [[8.0, 7.0, 1.0, 0, 0, 0], [12.0, 9.0, 1.2, 0, 0, 0], [10.0, 10.0, 0.9, 0, 0, 0],
             [9.0, 9.5, 1.4, 0, 0, 0], [11.0, 7.5, 0.8, 0, 0, 0]]
    sc = tmp_path / "sc.toml"
    sc.write_text(textwrap.dedent(f"""\
        format = "cdpr-scenario/1"
        robot = "rocaspect"
        seed = 3
        init_pose = [10.0, 8.56, 1.0, 0.0, 0.0, 0.0]
        [truth.load_cell_calibration]
        gain_32 = 1.08
        offset_12 = -20.0
        [poses]
        kind = "list"
        list = {json.dumps(poses)}
        visits = 2
        """), encoding="utf-8")
    assert main(["campaign", str(sc), str(tmp_path / "rec"), "--quiet"]) == 0
    return tmp_path / "rec"


def test_diagnose_reads_mcap_as_csv(campaign_recording, tmp_path, capsys):
    capsys.readouterr()
    csv_to_mcap(campaign_recording, tmp_path / "rec.mcap")
    reports = []
    for rec in (campaign_recording, tmp_path / "rec.mcap"):
        assert main(["diagnose", str(rec), "--json", "--quiet", "--jobs", "1"]) == 0
        reports.append(json.loads(capsys.readouterr().out))
    a, b = reports
    assert b["recording"] == str(tmp_path / "rec.mcap")
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]]
    assert "load_cell_calibration" in [e["name"] for e in a["effects"]]
    for ea, eb in zip(a["effects"], b["effects"], strict=True):
        assert ea["params"] == pytest.approx(eb["params"], rel=1e-9, abs=1e-12)
    assert a["samples"] == b["samples"]
    assert a["fitted"]["pose_rms_m"] == pytest.approx(b["fitted"]["pose_rms_m"], rel=1e-9)


def test_write_recording_then_mcap_round_trip(tmp_path):
    robot = _robot()
    n = 5
    cols = {"t": np.arange(n) * 0.1, "x_des": np.linspace(9, 10, n),
            "tau_11": np.array([1.0, math.nan, 3.0, 4.0, 5.0])}
    write_recording(tmp_path / "w", robot, np.zeros(6), cols, states=["init"] * n)
    csv_to_mcap(tmp_path / "w", tmp_path / "w.mcap", scene=False)
    a, b = read_recording(tmp_path / "w"), read_recording(tmp_path / "w.mcap")
    _same(a.tau, b.tau)
    _same(a.pose_des, b.pose_des)


def test_can_frames_round_trip_through_can_log(tmp_path):
    import can

    src = _odd_recording(tmp_path / "src")
    frames = [can.Message(timestamp=100.0 + 0.001 * i, arbitration_id=0x181 + i % 8,
                          data=bytes([i % 256, 1, 2, 3, 4, 5]), is_extended_id=False)
              for i in range(40)]
    with can.Logger(str(src / "can.log")) as log:
        for m in frames:
            log.on_message_received(m)
    csv_to_mcap(src, tmp_path / "r.mcap")
    from bench.mcap import read_can_frames

    got = list(read_can_frames(tmp_path / "r.mcap"))
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [
        (m.arbitration_id, bytes(m.data)) for m in frames]
    assert [m.timestamp for m in got] == pytest.approx([m.timestamp for m in frames], abs=1e-6)
    mcap_to_csv(tmp_path / "r.mcap", tmp_path / "back")
    assert (tmp_path / "back" / "can.log").read_text() == (src / "can.log").read_text()


@given(rpy=st.tuples(*[st.floats(-3.14159, 3.14159)] * 3))
def test_property_quaternion_is_scipys(rpy):
    from scipy.spatial.transform import Rotation

    from bench.mcap.scene import quaternion
    from controller.pose import rotation

    R = rotation(np.array(rpy))
    q = np.array(quaternion(R))
    ref = Rotation.from_matrix(R).as_quat()
    ref = ref if ref[3] >= 0 else -ref
    assert np.allclose(q, ref, atol=1e-9) or (abs(ref[3]) < 1e-9 and np.allclose(q, -ref,
                                                                               atol=1e-9))
