"""Trajectories (controller/trajectory.py): the S-curve in closed form, limits checked by
finite differences of the samples, continuity at segment joints, every segment kind,
labels and the order of visits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from controller.pose import euler_rate_matrix, rotation
from controller.trajectory import (
    Circle,
    Dwell,
    Line,
    MotionLimits,
    Move,
    SCurve,
    Trajectory,
    TrajectoryError,
    Visits,
    euler_accels,
    euler_rates,
    visit_order,
)

P0 = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.0])
LIM = MotionLimits()
TOL = 1e-6  # relative tolerance on limits


# ---------------------------------------------------------------------------- S-curve


@pytest.mark.parametrize("D, vp, T", [
    # cruise: Tj = a/j = 0.5 s, Ta = v/a + a/j = 1.5 s, Tv = (10 - 0.5*1.5)/0.5 = 18.5 s
    (10.0, 0.5, 2 * 1.5 + 18.5),
    # no cruise, a reached: vp = (-a^2/j + sqrt(a^4/j^2 + 4 a D))/2, T = 2 (vp/a + a/j)
    (0.5, 0.5 * (-0.25 + math.sqrt(0.0625 + 1.0)),
     2 * (0.5 * (-0.25 + math.sqrt(0.0625 + 1.0)) / 0.5 + 0.5)),
    # a not reached: vp = (D sqrt(j)/2)^(2/3), T = 4 sqrt(vp/j)
    (0.2, 0.1 ** (2 / 3), 4 * math.sqrt(0.1 ** (2 / 3))),
])
def test_scurve_closed_form_cases(D, vp, T):
    sc = SCurve(D, 0.5, 0.5, 1.0)
    assert sc.v_peak == pytest.approx(vp, rel=1e-12)
    assert sc.duration == pytest.approx(T, rel=1e-12)
    assert sc.at(T) == (D, 0.0, 0.0)
    s, v, a = sc.at(T * (1 - 1e-9))
    assert s == pytest.approx(D, abs=1e-9) and abs(v) < 1e-6 and abs(a) < 1e-6
    # symmetric: half the distance at half the time, at the peak speed
    s, v, a = sc.at(T / 2)
    assert s == pytest.approx(D / 2, rel=1e-9) and v == pytest.approx(vp, rel=1e-9)
    assert sc.at(-1.0) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("D", [1e-5, 0.01, 0.2, 0.5, 0.75, 1.0, 3.0, 40.0])
def test_scurve_respects_its_bounds_and_integrates(D):
    v, a, j = 0.5, 0.5, 1.0
    sc = SCurve(D, v, a, j)
    t = np.linspace(0, sc.duration, 20001)
    s, sv, sa = sc.batch(t)
    assert np.all(np.diff(s) >= -1e-15) and s[0] == 0 and s[-1] == D
    assert sv.max() <= v * (1 + TOL) and sv.min() >= -1e-12
    assert np.abs(sa).max() <= a * (1 + TOL)
    dt = t[1] - t[0]
    assert np.abs(np.diff(sa) / dt).max() <= j * (1 + 1e-6)
    # velocity is the derivative of position, acceleration of velocity
    np.testing.assert_allclose(np.gradient(s, dt)[1:-1], sv[1:-1], atol=2 * j * dt * dt + 1e-12)
    np.testing.assert_allclose(np.gradient(sv, dt)[1:-1], sa[1:-1], atol=j * dt + 1e-12)


def test_scurve_zero_distance_and_bad_bounds():
    assert SCurve(0.0, 1, 1, 1).duration == 0.0
    with pytest.raises(TrajectoryError):
        SCurve(1.0, 0.0, 1, 1)
    with pytest.raises(TrajectoryError):
        SCurve(-1.0, 1, 1, 1)


# ---------------------------------------------------------------------------- limits


def test_motion_limits_validation_and_speed_pct():
    assert LIM.max_speed_m_s == 0.5 and LIM.speed_pct == 100.0
    lim = MotionLimits(speed_pct=40)
    assert lim.speed_m_s == pytest.approx(0.2)
    assert lim.angular_speed_rad_s == pytest.approx(0.4 * LIM.max_angular_speed_rad_s)
    for bad in ({"speed_pct": 0}, {"speed_pct": 150}, {"max_accel_m_s2": -1},
                {"max_jerk_m_s3": float("nan")}):
        with pytest.raises(TrajectoryError, match=next(iter(bad))):
            MotionLimits(**bad)
    with pytest.raises(TrajectoryError, match="unknown"):
        LIM.replace(speed=3)


def _angular_speed(poses: np.ndarray, dt: float) -> np.ndarray:
    """|omega| from consecutive orientations (finite differences on SO(3))."""
    R = Rotation.from_euler("xyz", poses[:, 3:])
    return np.linalg.norm((R[1:] * R[:-1].inv()).as_rotvec(), axis=1) / dt


def _check_limits(tr: Trajectory, lim: MotionLimits, n: int = 40001) -> None:
    t = np.linspace(0, tr.duration_s, n)
    dt = t[1] - t[0]
    s = tr.sample(t)
    # finite differences of the sampled poses never exceed the limits
    v_fd = np.linalg.norm(np.diff(s.pose[:, :3], axis=0), axis=1) / dt
    assert v_fd.max() <= lim.speed_m_s * (1 + 1e-3)
    a_fd = np.linalg.norm(np.diff(s.velocity[:, :3], axis=0), axis=1) / dt
    assert a_fd.max() <= lim.max_accel_m_s2 * (1 + 1e-3)
    j_fd = np.linalg.norm(np.diff(s.acceleration[:, :3], axis=0), axis=1) / dt
    assert j_fd.max() <= lim.max_jerk_m_s3 * (1 + 1e-3)
    w = _angular_speed(s.pose, dt)
    assert w.max() <= lim.angular_speed_rad_s * (1 + 1e-3)
    # analytic velocities and accelerations are the derivatives of the samples
    v_an = s.velocity
    np.testing.assert_allclose(np.diff(s.pose, axis=0) / dt, 0.5 * (v_an[1:] + v_an[:-1]),
                               atol=1e-4)
    # (exact for piecewise-linear accelerations, but for a kink inside a step: j dt / 2)
    np.testing.assert_allclose(np.diff(v_an, axis=0) / dt,
                               0.5 * (s.acceleration[1:] + s.acceleration[:-1]),
                               atol=max(1e-3, lim.max_jerk_m_s3 * dt / 2))


def _mixed(lim: MotionLimits = LIM) -> Trajectory:
    return Trajectory([
        Move((12.0, 8.56, 1.2, 0.05, -0.03, 0.3)),
        Dwell(1.5),
        Line(((12.0, 10.0, 1.2), (10.0, 10.0, 1.0, 0.0, 0.0, 0.0), (10.0, 10.3, 1.0))),
        Circle((10.0, 9.0, 1.0), (0.0, 0.0, 1.0), 270.0),
        Circle((9.0, 9.0, 1.0), (0.0, 1.0, 0.0), -90.0),
        Visits(((5.0, 5.0, 1.0), (6.0, 6.0, 1.2, 0.02, 0.0, -0.1)), visits=2, dwell_s=1.0),
    ], P0, lim)


@pytest.mark.parametrize("pct", [100.0, 40.0, 10.0])
def test_no_limit_is_exceeded(pct):
    lim = MotionLimits(speed_pct=pct)
    _check_limits(_mixed(lim), lim, n=80001 if pct < 50 else 40001)


def test_tight_angular_limits_synchronise_rotation_and_translation():
    lim = MotionLimits(max_angular_speed_rad_s=0.02, max_angular_accel_rad_s2=0.01,
                       max_angular_jerk_rad_s3=0.01)
    tr = Trajectory([Move((10.5, 8.56, 1.2, 0.0, 0.0, 0.5))], P0, lim)
    _check_limits(tr, lim)
    t = np.linspace(0, tr.duration_s, 2001)
    s = tr.sample(t)
    # both arrive together: the orientation turns about one fixed axis in proportion to
    # the distance travelled
    frac_t = np.linalg.norm(s.pose[:, :3] - P0[:3], axis=1) / 0.5
    frac_r = np.abs(s.pose[:, 5]) / 0.5
    np.testing.assert_allclose(frac_t, frac_r, atol=1e-9)
    # the angular speed, not the translation, sets the duration: a rotation of 0.5 rad at
    # 0.02 rad/s takes at least 25 s where 0.5 m alone takes about 3 s
    assert tr.duration_s > 25.0


def test_euler_rate_helpers_invert_the_rate_matrix():
    rng = np.random.default_rng(3)
    for _ in range(20):
        rpy = rng.uniform(-1.2, 1.2, 3)
        w = rng.normal(size=3)
        d = euler_rates(rpy, w)
        np.testing.assert_allclose(euler_rate_matrix(rpy) @ d, w, atol=1e-12)
    # accelerations: d/dt of the rates along a slerp (finite differences of rates)
    phi = np.array([0.3, -0.2, 0.5])
    R0 = rotation(np.array([0.1, 0.2, -0.3]))

    def rates(t):
        rpy = Rotation.from_matrix(Rotation.from_rotvec(t * t * phi).as_matrix() @ R0)
        rpy = rpy.as_euler("xyz")
        return rpy, euler_rates(rpy, 2 * t * phi)

    t, h = 0.7, 1e-6
    rpy, d = rates(t)
    fd = (rates(t + h)[1] - rates(t - h)[1]) / (2 * h)
    np.testing.assert_allclose(euler_accels(rpy, d, 2 * phi), fd, atol=1e-6)


# ---------------------------------------------------------------------------- joints, kinds


def test_continuity_and_rest_at_every_segment_joint():
    tr = _mixed()
    assert len(tr.segments) > 8
    for a, b in zip(tr.segments[:-1], tr.segments[1:], strict=True):
        assert a.t1 == pytest.approx(b.t0)
        np.testing.assert_allclose(a.target, b.start, atol=1e-12)
        eps = 1e-9
        before, after = tr.sample(a.t1 - eps), tr.sample(a.t1 + eps)
        np.testing.assert_allclose(before.pose, after.pose, atol=1e-8)
        np.testing.assert_allclose(before.velocity, after.velocity, atol=1e-7)
        np.testing.assert_allclose(tr.sample(b.t0).velocity, 0.0, atol=1e-12)
        np.testing.assert_allclose(tr.sample(b.t0).pose, b.start, atol=1e-9)
    end = tr.sample(tr.duration_s + 5.0)
    np.testing.assert_allclose(end.pose, tr.segments[-1].target, atol=1e-12)
    np.testing.assert_allclose(end.velocity, 0.0)
    np.testing.assert_allclose(tr.sample(-3.0).pose, P0)


def test_scalar_and_vector_samples_agree():
    tr = _mixed()
    t = np.random.default_rng(0).uniform(-1, tr.duration_s + 1, 300)
    v = tr.sample(t)
    assert v.pose.shape == (300, 6) and v.label.shape == (300,)
    for i, ti in enumerate(t):
        s = tr.sample(float(ti))
        np.testing.assert_allclose(s.pose, v.pose[i], atol=1e-12)
        np.testing.assert_allclose(s.velocity, v.velocity[i], atol=1e-12)
        np.testing.assert_allclose(s.acceleration, v.acceleration[i], atol=1e-10)
        assert s.label == v.label[i] and s.segment == v.segment[i]


def test_move_is_a_straight_line_with_slerp_to_the_target():
    target = np.array([14.0, 6.0, 2.0, 0.1, -0.05, 0.4])
    tr = Trajectory([Move(tuple(target))], P0)
    t = np.linspace(0, tr.duration_s, 501)
    s = tr.sample(t)
    d = target[:3] - P0[:3]
    rel = s.pose[:, :3] - P0[:3]
    # on the segment: no component off the line
    off = rel - np.outer(rel @ d / (d @ d), d)
    assert np.abs(off).max() < 1e-12
    np.testing.assert_allclose(s.pose[-1], target, atol=1e-12)
    # slerp: one rotation axis from start to end
    R = Rotation.from_euler("xyz", s.pose[1:, 3:]) * Rotation.from_euler("xyz", P0[3:]).inv()
    axes = R.as_rotvec()
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    assert np.abs(axes - axes[-1]).max() < 1e-9
    assert set(s.label) == {"move"}


def test_three_number_targets_keep_the_orientation():
    start = np.array([10.0, 8.0, 1.0, 0.02, 0.01, -0.2])
    tr = Trajectory([Move((11.0, 8.0, 1.0)), Line(((11.0, 9.0, 1.5),))], start)
    np.testing.assert_allclose(tr.end_pose, [11.0, 9.0, 1.5, 0.02, 0.01, -0.2])
    s = tr.sample(np.linspace(0, tr.duration_s, 50))
    np.testing.assert_allclose(s.pose[:, 3:], np.tile(start[3:], (50, 1)), atol=1e-12)


def test_line_rests_at_each_vertex_and_goes_straight_between():
    verts = [(12.0, 8.56, 1.2), (12.0, 10.0, 1.2), (12.0, 10.0, 0.8)]
    tr = Trajectory([Line(tuple(verts))], P0)
    assert [s.kind for s in tr.segments] == ["line"] * 3
    for seg, v in zip(tr.segments, verts, strict=True):
        np.testing.assert_allclose(seg.target[:3], v)
        np.testing.assert_allclose(tr.sample(seg.t1).velocity, 0.0, atol=1e-12)
        mid = tr.sample(0.5 * (seg.t0 + seg.t1)).pose[:3]
        np.testing.assert_allclose(mid, 0.5 * (seg.start[:3] + seg.target[:3]), atol=1e-12)


@pytest.mark.parametrize("lim", [LIM, MotionLimits(max_jerk_m_s3=100.0)],
                         ids=["default", "jerk-free"])
def test_circle_stays_on_its_circle_and_limits_the_centripetal_acceleration(lim):
    r = 0.4
    start = np.array([10.0 + r, 8.56, 1.2, 0.0, 0.0, 0.1])
    tr = Trajectory([Circle((10.0, 8.56, 1.2), (0.0, 0.0, 2.0), 360.0)], start, lim)
    t = np.linspace(0, tr.duration_s, 20001)
    s = tr.sample(t)
    q = s.pose[:, :3] - [10.0, 8.56, 1.2]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), r, atol=1e-12)
    np.testing.assert_allclose(q[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(s.pose[:, 3:], np.tile(start[3:], (len(t), 1)))
    np.testing.assert_allclose(s.pose[-1], start, atol=1e-12)  # full turn: back at the start
    # counter-clockwise about +z: the first step goes towards +y
    assert s.pose[10, 1] > 8.56
    speed = np.linalg.norm(s.velocity[:, :3], axis=1)
    acc = np.linalg.norm(s.acceleration[:, :3], axis=1)
    # a small radius limits the speed by the centripetal acceleration: v^2/r <= 0.6 a
    assert speed.max() <= math.sqrt(0.6 * lim.max_accel_m_s2 * r) * (1 + 1e-9)
    assert speed.max() < lim.speed_m_s
    assert acc.max() <= lim.max_accel_m_s2 * (1 + 1e-9)
    # at cruise the acceleration is centripetal, pointing to the centre
    i = int(np.argmax(speed))
    a_dir = s.acceleration[i, :3] / acc[i]
    np.testing.assert_allclose(a_dir, -q[i] / r, atol=1e-6)
    _check_limits(tr, lim)


def test_circle_angle_and_direction():
    tr = Trajectory([Circle((10.0, 8.0, 1.2), (1.0, 0.0, 0.0), -90.0)], P0)
    # start at (y, z) = (8.56, 1.2), radius 0.56 about +x, -90 deg: to (8.0, 1.2 - 0.56)
    np.testing.assert_allclose(tr.end_pose[:3], [10.0, 8.0, 1.2 - 0.56], atol=1e-12)


def test_circle_start_off_its_plane_is_refused():
    with pytest.raises(TrajectoryError, match="off the circle's plane"):
        Trajectory([Circle((10.0, 8.56, 1.0), (0.0, 0.0, 1.0), 90.0)], P0)
    with pytest.raises(TrajectoryError, match="radius 0"):
        Trajectory([Circle((10.0, 8.56, 1.2), (0.0, 0.0, 1.0), 90.0)], P0)


def test_dwell_stands_still_with_the_dwell_label():
    tr = Trajectory([Move((11.0, 8.56, 1.2)), Dwell(4.0), Move((11.0, 9.0, 1.2))], P0)
    kinds = [(s.kind, s.label) for s in tr.segments]
    assert kinds == [("move", "move"), ("dwell", "dwell"), ("move", "move")]
    d = tr.segments[1]
    assert d.duration_s == pytest.approx(4.0)
    s = tr.sample(np.linspace(d.t0, d.t1 - 1e-9, 30))
    assert set(s.label) == {"dwell"}
    np.testing.assert_allclose(s.pose, np.tile([11.0, 8.56, 1.2, 0, 0, 0], (30, 1)))
    np.testing.assert_allclose(s.velocity, 0.0)
    assert tr.sample(d.t0 - 0.1).label == "move" and tr.sample(d.t1 + 0.1).label == "move"
    assert tr.dwells() == [d]


def test_zero_length_moves_are_dropped():
    tr = Trajectory([Move(tuple(P0)), Dwell(1.0), Move(tuple(P0[:3]))], P0)
    assert [s.kind for s in tr.segments] == ["dwell"]
    empty = Trajectory([Move(tuple(P0))], P0)
    assert empty.duration_s == 0.0 and empty.sample(1.0).label == "dwell"
    np.testing.assert_allclose(empty.sample(np.array([0.0, 1.0])).pose, [P0, P0])


def test_bad_targets_name_the_segment():
    with pytest.raises(TrajectoryError, match=r"segment #2 \(move\)"):
        Trajectory([Dwell(1.0), Move((1.0, 2.0))], P0)
    with pytest.raises(TrajectoryError, match="here.toml:7"):
        Trajectory([Move((1.0, 2.0, float("nan")), where="here.toml:7")], P0)
    with pytest.raises(TrajectoryError, match="start pose"):
        Trajectory([], [0.0, 1.0])


# ---------------------------------------------------------------------------- visits


POSES = ((5.0, 5.0, 1.0), (6.0, 5.0, 1.0), (6.0, 6.0, 1.5), (5.0, 6.0, 1.5))


def test_visits_cycle_in_order_with_a_dwell_each():
    tr = Trajectory([Visits(POSES, visits=3, dwell_s=2.0, order="cycle")], P0)
    dw = tr.dwells()
    assert [s.pose_index for s in dw] == [0, 1, 2, 3] * 3
    assert [s.round for s in dw] == [0] * 4 + [1] * 4 + [2] * 4
    for s in dw:
        assert s.kind == "visits" and s.duration_s == pytest.approx(2.0)
        np.testing.assert_allclose(s.target[:3], POSES[s.pose_index])
    # each dwell follows its move: move, dwell, move, dwell ...
    assert [s.label for s in tr.segments] == ["move", "dwell"] * 12
    t = np.linspace(0, tr.duration_s, 5000)
    lab = tr.sample(t).label
    in_dwell = np.zeros(len(t), bool)
    for s in dw:
        in_dwell |= (t >= s.t0) & (t < s.t1)
    in_dwell |= t >= tr.duration_s  # after the end: the last segment's label
    assert np.array_equal(lab == "dwell", in_dwell)


def test_visits_shuffle_is_a_seeded_permutation_per_round():
    a = visit_order(6, 5, "shuffle", seed=11)
    assert a == visit_order(6, 5, "shuffle", seed=11)
    assert a != visit_order(6, 5, "shuffle", seed=12)
    for k in range(5):
        assert sorted(i for r, i in a if r == k) == list(range(6))
    assert any([i for r, i in a if r == k] != list(range(6)) for k in range(5))
    # never the same pose twice in a row: every visit moves
    for seed in range(30):
        seq = [i for _, i in visit_order(3, 6, "shuffle", seed)]
        assert all(x != y for x, y in zip(seq[:-1], seq[1:], strict=True))
    assert visit_order(3, 2, "cycle") == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]
    with pytest.raises(TrajectoryError, match="order"):
        visit_order(3, 2, "random")
    tr = Trajectory([Visits(POSES, visits=4, dwell_s=1.0, order="shuffle", seed=5)], P0)
    assert [s.pose_index for s in tr.dwells()] == [i for _, i in visit_order(4, 4, "shuffle", 5)]


def test_repeat_and_approach_tag_the_cycles():
    specs = [Move((10.0, 9.0, 1.2)), Line(((10.0, 9.5, 1.2), (10.0, 9.0, 1.2)))]
    tr = Trajectory(specs, P0, repeat=3, approach=1)
    assert [s.cycle for s in tr.segments] == [-1] + [0, 0, 1, 1, 2, 2]
    assert [s.cycle for s in Trajectory(specs, P0).segments] == [0, 0, 0]
    with pytest.raises(TrajectoryError, match="repeat"):
        Trajectory(specs, P0, repeat=0)
