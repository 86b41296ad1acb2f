"""ISO 9283 figures on small point sets worked by hand, and their properties."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.iso9283.figures import (
    normal_plane_points,
    path_figures,
    path_tangents,
    pose_figures,
    repeatability_radius,
    resample_path,
    wrap_angle,
)

D = math.radians


# --------------------------------------------------------------------------------------------
# pose figures


def test_pose_figures_three_points_worked_by_hand():
    # command (0, 0, 0); attained p1 = (1, 0, 0), p2 = (0, 2, 0), p3 = (2, 1, 3)
    # barycentre (3/3, 3/3, 3/3) = (1, 1, 1): APx = APy = APz = 1, AP = sqrt(3) = 1.7320508
    # l1 = |(0,-1,-1)| = sqrt 2 = 1.4142136, l2 = |(-1,1,-1)| = sqrt 3 = 1.7320508,
    # l3 = |(1,0,2)| = sqrt 5 = 2.2360680; l_mean = 5.3823324 / 3 = 1.7941108
    # deviations -0.3798972, -0.0620600, +0.4419572; squares 0.1443219 + 0.0038514
    # + 0.1953262 = 0.3434995; / (n - 1 = 2) = 0.1717498; S_l = 0.4144270
    # RP = 1.7941108 + 3 * 0.4144270 = 3.0373918
    f = pose_figures([[1, 0, 0], [0, 2, 0], [2, 1, 3]], [0, 0, 0])
    assert f.n == 3
    np.testing.assert_allclose(f.ap_xyz, [1, 1, 1])
    assert f.ap == pytest.approx(1.7320508, abs=1e-7)
    np.testing.assert_allclose(f.l_j, [1.4142136, 1.7320508, 2.2360680], atol=1e-7)
    assert f.l_mean == pytest.approx(1.7941108, abs=1e-7)
    assert f.s_l == pytest.approx(0.4144270, abs=1e-7)
    assert f.rp == pytest.approx(3.0373918, abs=1e-7)
    assert np.isnan(f.ap_abc).all() and np.isnan(f.rp_abc).all()  # positions only


def test_pose_figures_four_points_barycentre_on_command():
    # command (10, 20, 30) mm; attained = command + (3,0,0), (-3,0,0), (0,4,0), (0,-4,0) mm
    # barycentre = command: AP = 0; l = 3, 3, 4, 4 mm, l_mean = 3.5 mm,
    # S_l = sqrt(4 * 0.25 / 3) = 0.5773503 mm; RP = 3.5 + 1.7320508 = 5.2320508 mm
    c = np.array([10.0, 20.0, 30.0]) * 1e-3
    att = c + np.array([[3, 0, 0], [-3, 0, 0], [0, 4, 0], [0, -4, 0]]) * 1e-3
    f = pose_figures(att, c)
    assert f.ap == pytest.approx(0.0, abs=1e-15)
    assert f.l_mean == pytest.approx(3.5e-3)
    assert f.s_l == pytest.approx(0.5773503e-3, abs=1e-10)
    assert f.rp == pytest.approx(5.2320508e-3, abs=1e-10)


def test_orientation_figures_worked_by_hand_with_wrap():
    # a (roll):  command 0 deg, attained 1, 2, 3: a_mean = 2 -> AP_a = 2 deg;
    #            S_a = sqrt((1 + 0 + 1) / 2) = 1 -> RP_a = 3 deg
    # b (pitch): command 1 deg, attained 0, 0, 3: b_mean = 1 -> AP_b = 0;
    #            S_b = sqrt((1 + 1 + 4) / 2) = sqrt 3 -> RP_b = 3 sqrt 3 = 5.1961524 deg
    # c (yaw):   command 179 deg, attained -179, 179, 178: wrapped deviations +2, 0, -1:
    #            AP_c = 1/3 deg; deviations from the mean 5/3, -1/3, -4/3: squares sum
    #            (25 + 1 + 16) / 9 = 4.6666667, / 2 = 2.3333333, S_c = 1.5275252 ->
    #            RP_c = 4.5825757 deg
    att = np.array([[0, 0, 0, D(1), D(0), D(-179)], [0, 0, 0, D(2), D(0), D(179)],
                    [0, 0, 0, D(3), D(3), D(178)]])
    f = pose_figures(att, [0, 0, 0, 0, D(1), D(179)])
    np.testing.assert_allclose(np.degrees(f.ap_abc), [2.0, 0.0, 1 / 3], atol=1e-9)
    np.testing.assert_allclose(np.degrees(f.rp_abc), [3.0, 5.1961524, 4.5825757], atol=1e-7)
    assert math.degrees(f.barycentre[5]) == pytest.approx(179 + 1 / 3)
    assert f.ap == 0.0 and f.rp == 0.0  # all at the command's position


def test_pose_rp_translation_invariant_and_ap_follows_the_shift():
    rng = np.random.default_rng(1)
    att = rng.normal(0, 1e-3, (5, 6))
    c = np.zeros(6)
    f0 = pose_figures(att, c)
    v = np.array([3.0, -2.0, 0.5, 0, 0, 0])
    f1 = pose_figures(att + v, c)
    assert f1.rp == pytest.approx(f0.rp, rel=1e-9)
    np.testing.assert_allclose(f1.rp_abc, f0.rp_abc)
    np.testing.assert_allclose(f1.ap_xyz, f0.ap_xyz + v[:3])
    f2 = pose_figures(att + v, c + v)  # command moved with them: nothing changes
    assert f2.ap == pytest.approx(f0.ap, abs=1e-12)


def test_pose_single_visit_has_no_repeatability():
    f = pose_figures([[1.0, 0, 0, 0.1, 0, 0]], [0, 0, 0, 0, 0, 0])
    assert f.ap == 1.0 and f.ap_abc[0] == pytest.approx(0.1)
    assert math.isnan(f.rp) and np.isnan(f.rp_abc).all()


def test_pose_rejects_bad_shapes_and_missing_positions():
    with pytest.raises(ValueError):
        pose_figures(np.zeros((3, 4)), np.zeros(3))
    with pytest.raises(ValueError):
        pose_figures([[np.nan, 0, 0]], [0, 0, 0])
    with pytest.raises(ValueError):
        pose_figures(np.zeros((0, 3)), np.zeros(3))


def test_repeatability_radius_equal_distances():
    # four points on a circle of radius 2 about their barycentre: l = 2, S_l = 0 -> RP = 2
    rp, lm, sl = repeatability_radius([[2, 0, 0], [-2, 0, 0], [0, 2, 0], [0, -2, 0]])
    assert (rp, lm, sl) == (2.0, 2.0, 0.0)


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle([np.pi + 0.1, -np.pi - 0.1, 0.3]),
                               [-np.pi + 0.1, np.pi - 0.1, 0.3])


# --------------------------------------------------------------------------------------------
# path figures


def straight_command():
    """Commanded points on the y axis at y = 0, 1, 2, 3, 4 m (normal planes y = y_i)."""
    return np.c_[np.zeros(5), np.arange(5.0), np.zeros(5)]


def test_path_figures_two_passes_worked_by_hand():
    # pass 1: the line x = 1 (vertices y = -1 and 5): crosses plane y = y_i at (1, y_i, 0)
    # pass 2: x = 3 with a bump to x = 5 at y = 2 (vertices y = -1, 1, 2, 3, 5):
    #         crosses at x = 3, 3, 5, 3, 3
    # barycentres x = 2, 2, 3, 2, 2: AT along the path 2, 2, 3, 2, 2 (all along x)
    # AT = 3 at s = 2; AT_mean by arc length (trapezoid weights 0.5, 1, 1, 1, 0.5 over 4 m):
    # (1 + 2 + 3 + 2 + 1) / 4 = 2.25
    # RT: l = (1, 1) at y != 2 (S = 0 -> 1), (2, 2) at y = 2 (-> 2): RT = 2
    # yaw: pass 1 0.01 rad, pass 2 0.03 rad, command 0: AT_c = 0.02;
    # S_c = sqrt((0.01^2 + 0.01^2) / 1) = 0.0141421 -> RT_c = 0.0424264
    p1 = np.array([[1, -1, 0, 0, 0, 0.01], [1, 5, 0, 0, 0, 0.01]])
    p2 = np.array([[3, -1, 0], [3, 1, 0], [5, 2, 0], [3, 3, 0], [3, 5, 0.0]])
    p2 = np.c_[p2, np.zeros((5, 2)), np.full(5, 0.03)]
    f = path_figures(np.c_[straight_command(), np.zeros((5, 3))], [p1, p2])
    np.testing.assert_allclose(f.dev, [2, 2, 3, 2, 2])
    np.testing.assert_allclose(f.dev_xyz, [[2, 0, 0]] * 2 + [[3, 0, 0]] + [[2, 0, 0]] * 2)
    assert f.at == 3.0 and f.at_s == 2.0
    assert f.at_mean == pytest.approx(2.25)
    np.testing.assert_allclose(f.rt_points, [1, 1, 2, 1, 1])
    assert f.rt == 2.0
    np.testing.assert_allclose(f.at_abc, [0, 0, 0.02], atol=1e-12)
    np.testing.assert_allclose(f.rt_abc, [0, 0, 0.0424264], atol=1e-7)
    assert f.complete.all() and (f.count == 2).all()


def test_path_rt_zero_for_identical_passes():
    th = np.linspace(0, 1.5 * np.pi, 40)
    curve = np.c_[np.full(40, 10.0), 8 + 2 * np.cos(th), 1.5 + np.sin(th)]
    s, cmd = resample_path(curve, 101)
    att = curve + [0.0, 0.01, -0.02]
    f = path_figures(cmd, [att, att.copy(), att.copy()], s=s)
    assert f.complete.sum() >= 99
    assert f.rt == pytest.approx(0.0, abs=1e-12)
    assert f.at > 0.0


def test_path_shifted_normal_to_its_plane_has_at_equal_to_the_shift():
    # a curved path in the YZ plane; the executed path shifted by 37 mm along x (normal to
    # every normal plane's in-plane directions): AT = AT_mean = 37 mm, AT_x = 37 mm everywhere
    th = np.linspace(0, np.pi, 200)
    curve = np.c_[np.full(200, 5.0), 8 + 3 * np.cos(th), 1.2 + 1.5 * np.sin(th)]
    s, cmd = resample_path(curve, 150)
    v = np.array([0.037, 0.0, 0.0])
    f = path_figures(cmd, [curve + v], s=s)
    assert f.complete.all()
    assert f.at == pytest.approx(0.037, abs=1e-12)
    assert f.at_mean == pytest.approx(0.037, abs=1e-12)
    np.testing.assert_allclose(f.dev_xyz, np.tile(v, (150, 1)), atol=1e-12)
    assert math.isnan(f.rt)  # one pass: no repeatability


def test_shift_of_a_straight_path_by_any_vector_leaves_its_normal_component():
    # straight path along y; shifted by (a, b, c): the normal planes y = y_i see (a, 0, c),
    # the shift along the path is no path error
    cmd = straight_command()
    att = np.c_[np.zeros(3), [-1.0, 2.0, 5.0], np.zeros(3)] + [0.02, 0.3, -0.01]
    f = path_figures(cmd, [att])
    assert f.at == pytest.approx(math.hypot(0.02, 0.01))
    np.testing.assert_allclose(f.dev_xyz[:, 1], 0.0, atol=1e-12)


def test_path_that_comes_back_is_matched_to_the_right_leg():
    # commanded: out along y from 0 to 4 at x = 0, back from 4 to 0 at x = 2 mm (a hairpin);
    # executed: 30 mm in +z on the way out, 5 mm in -z on the way back. The plane of an
    # outward point is crossed 5.4 mm from it by the return leg, but against the direction of
    # travel: not counted, the outward leg's crossing (30 mm) is taken.
    out = np.c_[np.zeros(41), np.linspace(0, 4, 41), np.zeros(41)]
    back = np.c_[np.full(41, 0.002), np.linspace(4, 0, 41), np.zeros(41)]
    turn = np.c_[np.linspace(0, 0.002, 6)[1:-1], np.full(4, 4.0), np.zeros(4)]
    cmd = np.vstack([out, turn, back])
    att = cmd.copy()
    att[:41, 2] += 0.030
    att[-41:, 2] -= 0.005
    f = path_figures(cmd[::4], [att])
    n_out = len(range(0, 41, 4))
    np.testing.assert_allclose(f.dev_xyz[1:n_out - 1, 2], 0.030, atol=1e-12)
    np.testing.assert_allclose(f.dev_xyz[-(n_out - 1):-1, 2], -0.005, atol=1e-12)
    assert f.at == pytest.approx(0.030)


def test_closed_path_end_not_matched_to_a_crossing_far_back():
    # a closed rectangle in the YZ plane, travelled y+, z+, y-, z- back to the start; the
    # executed path is off in z by 15 mm * cos(2 pi s / L): it ends 15 mm above the start,
    # short of the last normal plane (z = 1.0, travelled downwards), which its bottom leg
    # crossed downwards 3 m away near s = 2.9 m. That crossing is out of order: the last
    # point stays unmatched, and AT stays at the wave's size (at most sqrt 2 * 15 mm =
    # 21.2 mm, on the bisector plane of a corner where the executed path runs 15 mm off).
    c = np.array([[0, 6, 1.0], [0, 11, 1.0], [0, 11, 1.8], [0, 6, 1.8], [0, 6, 1.0]])
    dense = np.vstack([a + (b - a) * u[:, None] for a, b in zip(c[:-1], c[1:], strict=True)
                       for u in [np.linspace(0, 1, 200, endpoint=False)]] + [c[-1:]])
    s, cmd = resample_path(dense, 117)
    sd, _ = resample_path(dense, len(dense))
    att = dense + np.c_[np.zeros((len(dense), 2)), 0.015 * np.cos(2 * np.pi * sd / sd[-1])]
    pts = normal_plane_points(cmd, att)
    assert np.isnan(pts[-1]).all()
    assert np.isfinite(pts[:-1, :3]).all()
    f = path_figures(cmd, [att], s=s)
    assert 0.015 <= f.at <= 0.0213


def test_normal_plane_points_missing_when_a_pass_stops_short():
    cmd = straight_command()
    short = np.c_[np.zeros(2), [-1.0, 2.5], np.full(2, 0.1)]
    pts = normal_plane_points(cmd, short)
    assert np.isfinite(pts[:3, :3]).all() and np.isnan(pts[3:]).all()
    full = np.c_[np.zeros(2), [-1.0, 5.0], np.zeros(2)]
    f = path_figures(cmd, [full, short])
    np.testing.assert_array_equal(f.count, [2, 2, 2, 1, 1])
    np.testing.assert_array_equal(f.complete, [True, True, True, False, False])
    assert f.at == pytest.approx(0.05)  # over the complete points only
    assert f.dev[4] == pytest.approx(0.0)  # the full pass alone there


def test_max_distance_drops_far_crossings():
    cmd = straight_command()
    far = np.c_[np.full(2, 0.8), [-1.0, 5.0], np.zeros(2)]
    assert np.isnan(normal_plane_points(cmd, far, max_distance=0.5)).all()
    assert np.isfinite(normal_plane_points(cmd, far)[:, :3]).all()
    with pytest.raises(ValueError, match="crossed by every pass"):
        path_figures(cmd, [far], max_distance=0.5)


def test_resample_path_even_spacing_and_angles():
    pts = np.array([[0, 0, 0, 0, 0, D(170)], [0, 0, 0, 0, 0, D(170)], [0, 1, 0, 0, 0, D(-170)],
                    [0, 1, 2, 0, 0, D(-170)]])
    s, out = resample_path(pts, 7)
    np.testing.assert_allclose(s, np.linspace(0, 3, 7))
    np.testing.assert_allclose(out[:, :3], [[0, 0, 0], [0, .5, 0], [0, 1, 0], [0, 1, .5],
                                            [0, 1, 1], [0, 1, 1.5], [0, 1, 2]])
    # yaw goes the short way through 180 deg
    assert math.degrees(out[1, 5]) == pytest.approx(180.0) or \
        math.degrees(out[1, 5]) == pytest.approx(-180.0)
    with pytest.raises(ValueError):
        resample_path([[1, 1, 1], [1, 1, 1]], 5)


def test_corner_takes_a_legs_normal_plane_not_the_bisector():
    # an L: 4 m along +y, then 4 m along +z (rows every 5 cm); executed shifted by
    # (0, -10, +10) mm. On the first leg (planes y = const) the deviation is +10 mm in z, on
    # the second (planes z = const) -10 mm in y: AT = 10 mm. With the polyline's segment
    # tangents the corner point (s = 4 m) takes the outgoing leg's plane z = 0, which the
    # executed path (at z = +10 mm there) never crosses: left out. The central difference's
    # bisector plane there would give sqrt 2 * 10 = 14.1 mm, a corner artefact.
    leg1 = np.c_[np.zeros(81), np.linspace(0, 4, 81), np.zeros(81)]
    leg2 = np.c_[np.zeros(80), np.full(80, 4.0), np.linspace(0, 4, 81)[1:]]
    rows = np.vstack([leg1, leg2])
    att = rows + [0, -0.010, 0.010]
    s, cmd, tan = resample_path(rows, 9, with_tangents=True)
    np.testing.assert_allclose(tan, [[0, 1, 0]] * 4 + [[0, 0, 1]] * 5)
    f = path_figures(cmd, [att], s=s, tangents=tan)
    np.testing.assert_array_equal(f.complete, [True] * 4 + [False] + [True] * 4)
    assert f.at == pytest.approx(0.010)
    assert path_figures(cmd, [att], s=s).at == pytest.approx(0.010 * math.sqrt(2))


def test_tangents_are_unit_and_central():
    t = path_tangents(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]]))
    np.testing.assert_allclose(t, [[1, 0, 0], [np.sqrt(.5), np.sqrt(.5), 0], [0, 1, 0]])
