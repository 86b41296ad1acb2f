"""``cdpr campaign SCENARIO OUT_DIR``: a recording that the reader takes and that hides the truth,
the options, overwrite refusal, and errors naming the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.recording import read_recording
from firmware_sim.scenario import load_scenario

POSES = [[8.0, 7.0, 1.0, 0.0, 0.0, 0.0], [12.0, 9.0, 1.2, 0.0, 0.0, 0.0],
         [10.0, 10.0, 0.9, 0.0, 0.0, 0.0]]
# concealed values with digit strings unlikely to appear by chance in the text files
SCENARIO = f"""format = "cdpr-scenario/1"
robot = "rocaspect"
seed = 3
init_pose = [10.0, 8.56, 1.0, 0.0, 0.0, 0.0]

[truth.exit_point_offset]
dx_21 = 0.0437913
dz_42 = -0.0291357
[truth.load_cell_calibration]
gain_32 = 1.0537913
offset_12 = -7.3917

[poses]
kind = "list"
list = {json.dumps(POSES)}
visits = 2
"""
INIT_ROWS = 8  # init_s 4 s at 2 Hz
DWELL_ROWS = 6  # dwell_s 3 s at 2 Hz


@pytest.fixture
def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "scenario.toml"
    p.write_text(SCENARIO, encoding="utf-8")
    return p


def run_json(capsys, *argv: str) -> tuple[int, dict, str]:
    rc = main(["campaign", *argv, "--json"])
    cap = capsys.readouterr()
    return rc, json.loads(cap.out), cap.err


def target_poses(rec) -> np.ndarray:
    """The distinct desired poses of the dwells after initialisation."""
    des = rec.pose_des[np.array(rec.state) == "dwell"]
    return np.unique(np.round(des, 9), axis=0)


def test_campaign_writes_a_recording_the_reader_takes(scenario, tmp_path, capsys):
    out = tmp_path / "rec"
    rc, info, err = run_json(capsys, str(scenario), str(out))
    assert rc == 0
    assert info["path"] == str(out)
    assert info["visits"] == 6 and info["poses"] == 3 and info["samples"] == 7
    assert info["rows"] == INIT_ROWS + 6 * DWELL_ROWS
    assert info["seconds"] >= 0
    assert "campaign: 1/6 visits done" in err and "campaign: 6/6 visits done" in err
    rec = read_recording(out)
    assert rec.n_samples == info["rows"]
    assert sorted(p.name for p in out.iterdir()) == ["meta.toml", "recording.csv", "robot.toml"]
    np.testing.assert_allclose(target_poses(rec), np.unique(np.array(POSES), axis=0))
    assert np.isfinite(rec.tau).all() and np.isfinite(rec.pose_meas).all()
    np.testing.assert_allclose(rec.init_pose, [10.0, 8.56, 1.0, 0, 0, 0])
    # only the scenario's visits: no temporary directory left beside the recording
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec", "scenario.toml"]


def test_the_recording_never_holds_the_truth(scenario, tmp_path, capsys):
    out = tmp_path / "rec"
    rc, _, _ = run_json(capsys, str(scenario), str(out))
    assert rc == 0
    sc = load_scenario(scenario)
    text = {p.name: p.read_text(encoding="utf-8") for p in out.iterdir()}
    for name, body in text.items():
        for word in ("truth", "exit_point_offset", "load_cell_calibration", "gain", "scenario"):
            assert word not in body.lower(), (name, word)
        for value in ("0437913", "0291357", "0537913", "7.3917"):
            assert value not in body, (name, value)
    # the robot written is the model the controller ran with, not the plant's truth
    robot = read_recording(out).robot
    np.testing.assert_array_equal(robot.exits, sc.model.exits)
    k21 = robot.cable_ids.index("21")
    assert abs(sc.truth.exits[k21, 0] - robot.exits[k21, 0]) > 0.04
    assert repr(float(sc.truth.exits[k21, 0])) not in text["robot.toml"]


def test_options_poses_visits_seed(scenario, tmp_path, capsys):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    rc, info, _ = run_json(capsys, str(scenario), str(a), "--poses", "2", "--visits", "3",
                           "--seed", "11")
    assert rc == 0
    assert (info["poses"], info["visits"], info["samples"]) == (2, 6, 7)
    assert info["rows"] == INIT_ROWS + 6 * DWELL_ROWS
    got = target_poses(read_recording(a))
    assert len(got) == 2
    assert all(any(np.allclose(g, p) for p in POSES) for g in got)
    # same seed, same recording; another seed, other noise
    assert run_json(capsys, str(scenario), str(b), "--poses", "2", "--visits", "3",
                    "--seed", "11")[0] == 0
    assert (a / "recording.csv").read_bytes() == (b / "recording.csv").read_bytes()
    assert run_json(capsys, str(scenario), str(c), "--poses", "2", "--visits", "3",
                    "--seed", "12")[0] == 0
    assert not np.array_equal(read_recording(a).tau, read_recording(c).tau)


def test_refuses_a_non_empty_out_dir_unless_forced(scenario, tmp_path, capsys):
    out = tmp_path / "rec"
    out.mkdir()
    (out / "notes.txt").write_text("mine", encoding="utf-8")
    rc, info, err = run_json(capsys, str(scenario), str(out))
    assert rc == 2
    assert "not empty" in info["error"] and str(out) in err and "--force" in err
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    # an empty directory is fine
    empty = tmp_path / "empty"
    empty.mkdir()
    assert run_json(capsys, str(scenario), str(empty))[0] == 0
    read_recording(empty)
    # --force replaces the recording, keeps the other files
    rc, info, _ = run_json(capsys, str(scenario), str(out), "--force")
    assert rc == 0
    assert (out / "notes.txt").read_text(encoding="utf-8") == "mine"
    first = (out / "recording.csv").read_bytes()
    rc, info, _ = run_json(capsys, str(scenario), str(out), "--force", "--seed", "99")
    assert rc == 0 and (out / "recording.csv").read_bytes() != first
    read_recording(out)
    assert run_json(capsys, str(scenario), str(out / "notes.txt"))[0] == 2


@pytest.mark.parametrize("edit, field", [
    (("dx_21 = 0.0437913", 'dx_21 = "a lot"'), "truth.exit_point_offset.dx_21"),
    (("[truth.load_cell_calibration]", "[truth.cable_stretch]"), "truth.cable_stretch"),
    (("visits = 2", "visits = 0"), "poses.visits"),
    (('format = "cdpr-scenario/1"', 'format = "cdpr-scenario/9"'), "format"),
    (("kind = \"list\"", "kind = \"spiral\""), "poses.kind"),
    (("visits = 2", "visits = 2\n[noise]\ntracker = 1e-5"), "noise.tracker"),
])
def test_bad_scenario_exit_2_naming_file_and_field(scenario, tmp_path, capsys, edit, field):
    scenario.write_text(SCENARIO.replace(*edit), encoding="utf-8")
    out = tmp_path / "rec"
    rc, info, err = run_json(capsys, str(scenario), str(out))
    assert rc == 2
    assert str(scenario) in info["error"] and field in info["error"]
    assert field in err
    assert not out.exists()


def test_argument_and_campaign_errors(scenario, tmp_path, capsys):
    out = tmp_path / "rec"
    rc, info, _ = run_json(capsys, str(scenario), str(out), "--poses", "4")
    assert rc == 2 and str(scenario) in info["error"] and "poses" in info["error"]
    for opt in ("--poses", "--visits"):
        rc, info, _ = run_json(capsys, str(scenario), str(out), opt, "0")
        assert rc == 2 and opt in info["error"]
    rc, info, _ = run_json(capsys, str(tmp_path / "missing.toml"), str(out))
    assert rc == 2 and "missing.toml" in info["error"]
    # a pose the model cannot reach: exit 1, the pose named, nothing written
    scenario.write_text(SCENARIO.replace("[12.0, 9.0, 1.2,", "[10.0, 8.5, 3.55,"),
                        encoding="utf-8")
    rc, info, _ = run_json(capsys, str(scenario), str(out))
    assert rc == 1 and "not feasible" in info["error"] and "3.55" in info["error"]
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenario.toml"]


def test_human_output(scenario, tmp_path, capsys):
    assert main(["campaign", str(scenario), str(tmp_path / "rec"), "--quiet"]) == 0
    cap = capsys.readouterr()
    assert cap.err == ""
    assert "44 rows" in cap.out and "3 poses x 2 visits" in cap.out
