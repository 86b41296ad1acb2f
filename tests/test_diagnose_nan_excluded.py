"""``cdpr diagnose``'s ``excluded``: a NaN length where the row's encoders sampled is
excluded and reported like inf and 1e300; a row without any length (another stream's
sample) and NaN in the tracker's pose columns of a row without a fix are "no sample",
never listed."""

from __future__ import annotations

import numpy as np

from bench.diagnosis.samples import check_values
from bench.recording import read_recording, write_recording
from controller.kinematics import cable_lengths
from controller.robot import resolve_robot

ROBOT = resolve_robot("rocaspect")
POSE = np.array([10.0, 8.5, 1.5, 0.0, 0.0, 0.0])


def _recording(tmp_path, spoil):
    """20 rows at one pose, lengths and tracker poses; ``spoil(lengths, poses)`` edits."""
    n = 20
    lengths = np.tile(cable_lengths(POSE, ROBOT.anchors, ROBOT.exits), (n, 1))
    poses = np.tile(POSE, (n, 1))
    spoil(lengths, poses)
    cols = {"t": np.arange(n) * 0.1}
    for a, ax in enumerate(("x", "y", "z", "roll", "pitch", "yaw")):
        cols[f"{ax}_meas"] = poses[:, a]
    for k, c in enumerate(ROBOT.cable_ids):
        cols[f"l_meas_{c}"] = lengths[:, k]
    return read_recording(write_recording(tmp_path / "rec", ROBOT, POSE, cols))


def test_nan_inf_and_huge_lengths_are_all_reported(tmp_path):
    def spoil(lengths, poses):
        lengths[3, 2] = np.nan
        lengths[5, 4] = np.inf
        lengths[7, 1] = 1e300

    rec = _recording(tmp_path, spoil)
    ex = check_values(rec)
    got = {(e["row"], e["column"]) for e in ex}
    c = ROBOT.cable_ids
    assert got == {(5, f"l_meas_{c[2]}"), (7, f"l_meas_{c[4]}"), (9, f"l_meas_{c[1]}")}
    nan = next(e for e in ex if e["row"] == 5)
    assert np.isnan(nan["value"]) and "NaN" in nan["why"]


def test_rows_without_a_sample_are_not_listed(tmp_path):
    def spoil(lengths, poses):
        lengths[4, :] = np.nan  # a row of another stream: no encoder sample
        poses[6:9, :] = np.nan  # rows without a tracker fix

    rec = _recording(tmp_path, spoil)
    assert check_values(rec) == []


def test_a_column_never_measured_is_not_listed(tmp_path):
    def spoil(lengths, poses):
        lengths[:, 3] = np.nan  # a winch without an encoder column value anywhere

    rec = _recording(tmp_path, spoil)
    assert check_values(rec) == []
