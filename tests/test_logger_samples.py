"""Static samples of logs without the controller's columns (bench/diagnosis/samples.py):
rows between a tracker's fixes (no pose: the alignment refused to interpolate one where the
platform accelerates) are no standing measurements of their own, whereas a pose that really
jumps to a row and away from it is one."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.diagnosis import samples
from bench.recording import Recording
from controller.robot import resolve_robot


def _bare(t: np.ndarray, pose: np.ndarray) -> Recording:
    """A recording holding only the measured pose (no commanded pose, no state column)."""
    robot = resolve_robot("rocaspect")
    N, n = len(t), robot.n_cables
    nan = np.full((N, n), np.nan)
    return Recording(Path("."), robot, {}, pose[0], t, np.full((N, 6), np.nan), pose,
                     nan, nan.copy(), nan.copy(), np.full((N, n, 3), np.nan))


def _moves(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """50 Hz rows of a platform standing, moving 1 m at 0.25 m/s, standing, moving back."""
    t = np.arange(0.0, 16.0, 0.02)
    x = np.clip(0.25 * (t - 2.0), 0.0, 1.0) - np.clip(0.25 * (t - 10.0), 0.0, 1.0)
    pose = np.zeros((len(t), 6))
    pose[:, 0] = 10.0 + x + rng.normal(0, 5e-5, len(t))
    pose[:, 1:3] = [8.0, 1.0]
    return t, pose


def test_rows_without_a_pose_are_no_jumps():
    # rows around the moves' starts and ends lose their pose (one axis or all): none of them,
    # nor their neighbours, is a standing measurement of its own
    t, pose = _moves(np.random.default_rng(3))
    accel = np.zeros(len(t), dtype=bool)
    for t0 in (2.0, 6.0, 10.0, 14.0):
        accel |= np.abs(t - t0) < 0.1
    pose[accel] = np.nan
    pose[np.flatnonzero(accel)[::3], 0] = 3.0  # some rows keep a wrong axis alone
    pose[np.flatnonzero(accel)[::3], 1:] = np.nan
    rec = _bare(t, pose)
    rows = np.arange(len(t))
    assert not samples._isolated(rec, rows).any()


def test_a_pose_jumping_to_a_row_and_back_is_isolated():
    # the detector still finds what it is for: one row 30 cm away from rows 20 ms on either
    # side, also when the rows beside it have no pose
    t, pose = _moves(np.random.default_rng(4))
    pose[300, :3] += [0.3, 0.0, 0.0]
    pose[[299, 301]] = np.nan
    rec = _bare(t, pose)
    rows = np.arange(len(t))
    assert np.flatnonzero(samples._isolated(rec, rows)).tolist() == [300]


def _encoders_only(t: np.ndarray, lengths: np.ndarray) -> Recording:
    """A recording holding only encoder readings (no tracker, no controller's columns)."""
    robot = resolve_robot("rocaspect")
    N, n = len(t), robot.n_cables
    nan = np.full((N, n), np.nan)
    return Recording(Path("."), robot, {}, np.array([10.0, 8.0, 1.0, 0, 0, 0]), t,
                     np.full((N, 6), np.nan), np.full((N, 6), np.nan), nan, lengths,
                     nan.copy(), np.full((N, n, 3), np.nan))


def _ramp(t: np.ndarray, t0: float, t1: float, accel: float) -> np.ndarray:
    """Distance [m] of a move from t0 to t1 accelerating at ``accel`` [m/s^2] for its first
    and last quarter (a trapezoidal speed profile)."""
    q = 0.25 * (t1 - t0)
    v = accel * q
    s = np.clip(t - t0, 0.0, t1 - t0)
    up = 0.5 * accel * np.minimum(s, q) ** 2
    mid = v * np.clip(s - q, 0.0, 2 * q)
    down_t = np.clip(s - 3 * q, 0.0, q)
    return up + mid + v * down_t - 0.5 * accel * down_t ** 2


def test_without_any_pose_the_encoders_judge_acceleration():
    # 8 cables paid out along a trapezoidal move (1 m/s^2 for 0.5 s at each end), 0.1 um
    # encoders: rows inside the ramps accelerate, rows at constant speed and standing do not
    t = np.arange(0.0, 8.0, 0.004)
    d = _ramp(t, 2.0, 4.0, 1.0) - _ramp(t, 5.0, 7.0, 1.0)
    share = np.linspace(-1.0, 1.0, 8)  # each cable's length moves by share x d
    lengths = np.round((10.0 + d[:, None] * share[None, :]) / 1e-7) * 1e-7
    rec = _encoders_only(t, lengths)
    rows = np.arange(len(t))
    qs = samples._quasi_static(rec, rows)
    ramp = np.zeros(len(t), dtype=bool)
    for t0 in (2.0, 3.5, 5.0, 6.5):
        ramp |= (t > t0 + 0.1) & (t < t0 + 0.4)
    steady = ((t > 2.75) & (t < 3.25)) | ((t > 5.75) & (t < 6.25)) | (t < 1.4) | (t > 7.6)
    assert not qs[ramp].any()
    assert qs[steady].all()


def test_a_steady_move_without_any_pose_is_quasi_static():
    # nothing accelerates: no row is refused, whatever the encoders' quantisation
    t = np.arange(0.0, 6.0, 0.004) + np.random.default_rng(5).normal(0, 2e-4, 1500)
    t.sort()
    lengths = np.round((10.0 + 0.25 * t[:, None] * np.linspace(-1, 1, 8)) / 1e-6) * 1e-6
    rec = _encoders_only(t, lengths)
    assert samples._quasi_static(rec, np.arange(len(t))).all()


def test_visits_without_any_pose_group_by_their_encoder_lengths():
    # no commanded pose, no tracker: three visits of two targets whose readings repeat within
    # a tenth of a millimetre are two replicate groups; a third target 1 cm off on one cable
    # alone is a target of its own (nothing is pooled across targets)
    rng = np.random.default_rng(6)
    a, b = np.full(8, 10.0), np.full(8, 12.0)
    c = a.copy()
    c[3] += 0.01
    lens = np.array([a, b, a, b, a, b, c]) + rng.normal(0, 1e-4, (7, 8))
    nan = np.full((7, 6), np.nan)
    tg = samples._targets(nan, nan, lens)
    assert tg[0] == tg[2] == tg[4] and tg[1] == tg[3] == tg[5]
    assert len({tg[0], tg[1], tg[6]}) == 3
    # without lengths either, every dwell is its own target (as before)
    assert len(set(samples._targets(nan, nan).tolist())) == 7


def test_a_pose_without_a_commanded_one_is_estimated_metres_from_the_start():
    # encoders and load cells only, the platform 3 m from its initial pose: the estimate
    # from the readings and tensions reaches it (5 cm damped steps from the initial pose
    # could not)
    from bench.diagnosis.residuals import ResidualModel
    from controller.cycle import reference_lengths
    from controller.statics import batch_statics, init_unstretched

    robot = resolve_robot("rocaspect")
    p0 = np.array([10.0, 8.56, 1.0, 0.0, 0.0, 0.0])
    far = np.array([12.5, 10.0, 2.5, 0.01, -0.02, 0.015])
    poses = np.array([p0, far])
    bs = batch_statics(robot, poses)
    u0, _ = init_unstretched(robot, p0, bs.tensions[0])
    reading = bs.unstretched - u0 + reference_lengths(robot, p0)
    t = np.arange(0.0, 26.0, 0.1)  # stands 3 s, moves 20 s, stands 3 s
    w = np.clip((t - 3.0) / 20.0, 0.0, 1.0)[:, None]
    N, n = len(t), robot.n_cables
    rec = Recording(Path("."), robot, {}, p0, t, np.full((N, 6), np.nan),
                    np.full((N, 6), np.nan), np.full((N, n), np.nan),
                    (1 - w) * reading[0] + w * reading[1],
                    (1 - w) * bs.tensions[0] + w * bs.tensions[1], np.full((N, n, 3), np.nan))
    rec.init_rows = np.flatnonzero(t < 3.0)
    s = samples.prepare(rec)
    dwell = np.flatnonzero(s.kind == 0)
    assert len(dwell) == 2
    rm = ResidualModel(s, robot, p0, bs.tensions[0])
    est = rm.blocks(robot).poses[dwell]
    assert np.abs(est[:, :3] - poses[:, :3]).max() < 1e-4


def _two_stands(gap_move_m: float) -> Recording:
    """Encoders only: 3 s standing, no rows for 17 s, 3 s standing ``gap_move_m`` [m] longer
    on every cable."""
    t = np.r_[np.arange(0.0, 3.0, 0.1), np.arange(20.0, 23.0, 0.1)]
    lengths = np.full((len(t), 8), 10.0) + np.where(t > 10, gap_move_m, 0.0)[:, None]
    rng = np.random.default_rng(7)
    return _encoders_only(t, np.round((lengths + rng.normal(0, 2e-7, lengths.shape)) / 1e-7)
                          * 1e-7)


def test_standing_on_either_side_of_a_gap_in_the_log_are_two_dwells():
    rec = _two_stands(0.5)
    s = samples.prepare(rec)
    assert s.n == 2 and (s.kind == 0).all()
    assert np.ptp(s.l_meas[:, 0]) > 0.4
    # the same pause in the log without a move between: two dwells too, at one pose (the
    # log saw nothing across it: a load changed there shows as their difference)
    still = samples.prepare(_two_stands(0.0))
    assert still.n == 2 and np.ptp(still.l_meas[:, 0]) < 1e-6


def test_a_gap_in_a_log_whose_instants_repeat_ends_a_dwell_too():
    """A log split by sensor repeats each instant once per stream (steps of 0): the gap is
    judged on the steps between distinct instants, not on a median step of 0."""
    one = _two_stands(0.0)
    t = np.repeat(one.t, 2)
    s = samples.prepare(_encoders_only(t, np.repeat(one.l_meas, 2, axis=0)))
    assert s.n == 2
