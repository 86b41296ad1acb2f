"""Poses of a log without the tracker's and the controller's columns (bench/diagnosis/
residuals.py ``kinematic_starts``): each sample's pose estimate starts from the rigid forward
kinematics of its encoder readings; a target far from the initial pose must not land on a
mirrored branch (the platform turned over)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.recording import Recording
from controller.robot import resolve_robot
from controller.statics import pose_statics

P0 = np.array([0.388, 1.252, 2.663, 0.0, 0.0, 0.0])


def _log(end: np.ndarray) -> tuple[Recording, ResidualModel]:
    """20 Hz rows of the IPAnema-class robot standing at P0 for 3 s, moving at 0.3 m/s to
    ``end``, standing there for 3 s: encoder readings and load cells only (the readings the
    model's unstretched lengths, the cells its tensions)."""
    robot = resolve_robot("ipanema")
    dist = float(np.linalg.norm(end[:3] - P0[:3]))
    t_move = dist / 0.3
    t = np.arange(0.0, 6.0 + t_move, 0.05)
    f = np.clip((t - 3.0) / t_move, 0.0, 1.0)
    poses = P0 + f[:, None] * (end - P0)
    lengths, tau = [], []
    for p in poses:
        ps = pose_statics(robot, p)
        lengths.append(ps.unstretched)
        tau.append(ps.tensions)
    N, n = len(t), robot.n_cables
    nan = np.full((N, 6), np.nan)
    rec = Recording(Path("."), robot, {}, P0, t, nan, nan.copy(), np.full((N, n), np.nan),
                    np.array(lengths), np.array(tau), np.full((N, n, 3), np.nan),
                    init_rows=np.flatnonzero(t < 3.0))
    s = prepare(rec)
    return rec, ResidualModel(s, robot, rec.init_pose, rec.init_tensions, rows=s.triples)


def _starts(end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The start poses of every sample and the sample times."""
    _, rm = _log(end)
    return rm._kinematic_starts(np.arange(rm.s.n)), np.asarray(rm.s.t)


def test_far_corner_is_reached_upright():
    # from P0 alone the rigid solution of this corner's readings is the platform turned over
    # (roll 3 rad, 4 cm RMS misfit accepted); from the samples before it, upright
    end = np.array([-2.75, -2.3, 2.5, 0.0, 0.0, 0.0])
    starts, t = _starts(end)
    last = starts[np.argmax(t)]
    assert np.abs(starts[:, 3:]).max() < 0.05
    assert np.abs(last[:3] - end[:3]).max() < 0.02


def test_near_target_unchanged():
    # nothing to mend: a target the initial pose reaches directly gives that solution
    from controller.forward import forward_rigid

    end = np.array([1.0, 0.5, 2.6, 0.0, 0.0, 0.0])
    _, rm = _log(end)
    starts = rm._kinematic_starts(np.arange(rm.s.n))
    s = rm.s
    for i in range(s.n):
        res = forward_rigid(rm.model, s.l_meas[i], P0, tensions=s.tau[i])
        assert np.abs(starts[i] - res.pose).max() < 1e-6
