"""Reading recordings (cdpr-recording/1): strict, with file, line and column in errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from bench.recording import RecordingError, RecordingWriter, read_recording, write_recording
from controller.robot import resolve_robot

EXAMPLE = Path(__file__).parent.parent / "examples" / "paper_tables"


@pytest.fixture()
def rec_dir(tmp_path):
    d = tmp_path / "rec"
    shutil.copytree(EXAMPLE, d)
    return d


def error(d: Path) -> str:
    with pytest.raises(RecordingError) as e:
        read_recording(d)
    return str(e.value)


def test_write_then_read_round_trip(tmp_path):
    robot = resolve_robot("rocaspect")
    t = np.arange(5.0)
    cols = {"t": t, "x_des": np.full(5, 10.0), "l_meas_11": np.linspace(10, 11, 5),
            "tau_21": np.array([1.0, np.nan, 3.0, 4.0, 5.0]), "x_meas": np.full(5, 10.0)}
    d = write_recording(tmp_path / "r", robot, [10.0, 8.0, 1.0, 0, 0, 0], cols,
                        states=["init", "init", "dwell", "dwell", "dwell"])
    rec = read_recording(d)
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.l_meas[:, 0], cols["l_meas_11"])
    assert np.isnan(rec.l_meas[:, 1]).all()
    assert np.isnan(rec.tau[1, 2]) and rec.tau[2, 2] == 3.0
    assert rec.state == ["init", "init", "dwell", "dwell", "dwell"]
    assert rec.has("l_meas") and not rec.has("exit_meas")


def test_missing_time_column(rec_dir):
    p = rec_dir / "recording.csv"
    p.write_text(p.read_text().replace("t,", "time,", 1))
    assert "recording.csv:1" in error(rec_dir) and "'t'" in error(rec_dir)


def test_non_numeric_value_names_line_and_column(rec_dir):
    p = rec_dir / "recording.csv"
    lines = p.read_text().splitlines()
    fields = lines[3].split(",")
    fields[8] = "twelve"
    lines[3] = ",".join(fields)
    p.write_text("\n".join(lines) + "\n")
    msg = error(rec_dir)
    assert "recording.csv:4" in msg and "column 9 'y_meas'" in msg and "twelve" in msg


def test_cable_the_robot_does_not_have(rec_dir):
    p = rec_dir / "recording.csv"
    p.write_text(p.read_text().replace("ax_meas_42", "ax_meas_52", 1))
    msg = error(rec_dir)
    assert "cable '52'" in msg and "recording.csv:1" in msg


def test_robot_with_fewer_than_six_cables_and_bad_geometry(rec_dir):
    robot = rec_dir / "robot.toml"
    text = robot.read_text()
    robot.write_text(text.replace("exit = [0.0, 0.0, 3.565]", "exit = [0.0, inf, 3.565]"))
    msg = error(rec_dir)
    assert "robot.toml" in msg and "exit" in msg and "finite" in msg
    cut = text[:text.index('[[cable]]  # high pulley -> +x face')]
    robot.write_text(cut)
    assert "at least 6 cables" in error(rec_dir)


def test_meta_errors(rec_dir):
    meta = rec_dir / "meta.toml"
    text = meta.read_text()
    meta.write_text(text.replace('format = "cdpr-recording/1"', 'format = "cdpr-recording/9"'))
    assert "meta.toml: format" in error(rec_dir)
    meta.write_text(text.replace("init_pose = [10.0, 8.56, 1.0, 0.0, 0.0, 0.0]",
                                 "init_pose = [10.0, 8.56]"))
    assert "init_pose" in error(rec_dir)


def test_initialisation_rows_and_dwells(tmp_path):
    robot = resolve_robot("rocaspect")
    x = np.array([10, 10, 10, 12, 12, 12, 10.5, 10.5, 12, 12])
    cols = {"t": np.arange(10.0), "x_des": x, "y_des": np.full(10, 8.0),
            "z_des": np.ones(10), "x_meas": x + 1e-5}
    rec = read_recording(write_recording(tmp_path / "r", robot, [10, 8, 1, 0, 0, 0], cols))
    assert list(rec.init_rows) == [0, 1, 2]
    from bench.diagnosis.samples import average_dwells

    s = average_dwells(rec)
    assert s.n == 4 and list(s.count) == [3, 3, 2, 2]
    assert list(s.target) == [0, 1, 2, 1]  # the second visit of x = 12 is a replicate
    assert list(s.is_init) == [True, False, False, False]


def test_initialisation_rows_where_the_desired_pose_is_the_nominal_target(tmp_path):
    """init_pose is what the tracker measured (10.00002); the controller logged its nominal
    target (10.0) as the desired pose at initialisation: the platform leaves when the
    desired pose leaves its first row's, not at row 0 (a recording by other hands lost its
    initialisation tensions so). A first desired pose far from init_pose keeps the rule."""
    robot = resolve_robot("rocaspect")
    x = np.array([10, 10, 10, 12, 12, 12, 10.5, 10.5])
    cols = {"t": 86.4 + np.arange(8.0), "x_des": x, "y_des": np.full(8, 8.0),
            "z_des": np.ones(8), "x_meas": x + 2e-5,
            **{f"tau_{c}": np.full(8, 300.0) for c in robot.cable_ids}}
    rec = read_recording(write_recording(tmp_path / "r", robot,
                                         [10.00002, 7.99997, 1.00001, 0, 0, 1e-5], cols))
    assert list(rec.init_rows) == [0, 1, 2]
    assert rec.init_tensions is not None
    far = read_recording(write_recording(tmp_path / "far", robot, [10.3, 8, 1, 0, 0, 0],
                                         cols))
    assert list(far.init_rows) == []


def test_unknown_state_names_are_read_from_the_data(tmp_path):
    """State names are free: another controller's ``track`` rows along a path are rows of
    moves, its ``measure`` rows standing measurements, a lab's ``feed_hold`` is its own word
    (read from the data too); a reaction the format defines (``hold``) counts only while the
    platform stands."""
    from bench.diagnosis.samples import prepare, reaction_state

    robot = resolve_robot("rocaspect")
    n = 60
    t = np.arange(n) * 0.1
    x = np.concatenate([np.full(5, 10.0), 10.0 + 0.02 * np.arange(1, n - 4)])
    ls = {f"l_meas_{c}": 10.0 + 0.01 * x for c in robot.cable_ids}
    cols = {"t": t, "x_des": x, "y_des": np.full(n, 8.0), "z_des": np.ones(n),
            "x_meas": x, "y_meas": np.full(n, 8.0), "z_meas": np.ones(n), **ls}
    named = {}
    for word in ("move", "track", "feed_hold", "hold"):
        states = ["init"] * 5 + [word] * (n - 5)
        rec = read_recording(write_recording(tmp_path / word, robot, [10, 8, 1, 0, 0, 0],
                                             cols, states=states))
        named[word] = prepare(rec).info
    assert named["track"]["path_samples"] == named["move"]["path_samples"] > 0
    assert named["track"]["rows_in_other_states"] == 0
    assert named["feed_hold"]["path_samples"] == named["move"]["path_samples"]
    assert named["feed_hold"]["states_unknown"] == {"feed_hold": n - 5}
    assert named["hold"]["path_samples"] == 0
    assert named["hold"]["rows_in_other_states"] == n - 5
    assert reaction_state("quick_stop") and reaction_state("HOLD")
    assert not reaction_state("track") and not reaction_state("measure")
    assert not reaction_state("FAULT") and not reaction_state("feed_hold")


def test_streaming_writer_is_readable_while_it_runs(tmp_path):
    """Rows flushed so far form a valid recording before close(); close() writes the rest."""
    robot = resolve_robot("rocaspect")
    cols = ["t", "x_des", "tau_11"]
    w = RecordingWriter(tmp_path / "r", robot, [10, 8.56, 1, 0, 0, 0], cols, flush_s=3600)
    for i in range(5):
        w.append([0.1 * i, 10.0, np.nan if i == 2 else 100.0 + i], "init")
    w.flush()
    rec = read_recording(tmp_path / "r")
    assert rec.n_samples == 5 and rec.state == ["init"] * 5
    assert np.isnan(rec.tau[2, 0]) and rec.tau[4, 0] == 104.0
    w.append([0.5, 10.5, 105.0], "move")
    w.update_meta(notes="ended")
    w.close()
    w.close()  # idempotent
    rec = read_recording(tmp_path / "r")
    assert rec.n_samples == 6 and rec.state[-1] == "move" and rec.meta["notes"] == "ended"
    with RecordingWriter(tmp_path / "s", robot, [10, 8.56, 1, 0, 0, 0], cols) as w2:
        with pytest.raises(ValueError, match="3 columns"):
            w2.append([1.0])


def test_init_tensions_average_each_cable_over_the_init_rows_that_read_it(tmp_path):
    """A logger's load cells sample only some rows: each cable's mean over its own readings;
    None when a cable was not read during the initialisation."""
    robot = resolve_robot("rocaspect")
    nan = np.nan
    cols = {"t": np.arange(6.0), "x_des": np.array([10.0] * 4 + [11.0] * 2)}
    for k, c in enumerate(robot.cable_ids):
        cols[f"tau_{c}"] = np.array([nan, 100.0 + k, nan, 102.0 + k, nan, 500.0])
    states = ["init"] * 4 + ["dwell"] * 2
    rec = read_recording(write_recording(tmp_path / "r", robot, [10.0, 8.0, 1.0, 0, 0, 0],
                                         cols, states=states))
    np.testing.assert_allclose(rec.init_tensions, 101.0 + np.arange(robot.n_cables))
    cols[f"tau_{robot.cable_ids[3]}"][:4] = nan  # one cable never read at initialisation
    rec = read_recording(write_recording(tmp_path / "s", robot, [10.0, 8.0, 1.0, 0, 0, 0],
                                         cols, states=states))
    assert rec.init_tensions is None
