"""The model against the figures of the paper (Zake et al., CableCon 2023)."""

from __future__ import annotations

import numpy as np
from robots import PAPER_K, rocaspect

from controller.masts import settle, tilt_from_rope_elongation
from controller.robot import resolve_robot
from controller.statics import pose_statics

TABLE1_DIST = {"11": 0.0902, "12": 0.1144, "21": 0.0859, "22": 0.0915, "31": 0.0802,
               "32": 0.0912, "41": 0.0663, "42": 0.0567}
TABLE2 = {  # platform position: (|A21 - A21^r|, |A22 - A22^r|) measured [m]
    (4.5, 4.5, 1.0): (0.0204, 0.0322),
    (4.5, 12.5, 1.0): (0.0103, 0.0131),
    (15.5, 12.5, 1.0): (0.0286, 0.0289),
    (15.5, 4.5, 1.0): (0.0167, 0.0232),
}
CENTRE = np.array([10.0, 8.56, 1.0, 0.0, 0.0, 0.0])


def test_planar_example_mast_rotated_1_5_degrees_moves_exit_about_10_cm():
    pivot = np.array([[0.0, 0.0, 0.0]])
    exit_ = np.array([[0.0, 0.0, 4.0]])  # 4 m mast
    moved = settle(exit_, pivot, np.array([0]), np.array([[0.0, np.radians(1.5), 0.0]]))
    d = np.linalg.norm(moved - exit_)
    assert 0.10 < d < 0.11  # 4 m * 2 sin(0.75 deg) = 0.1047 m


def test_rope_elongation_tilts_the_mast_towards_the_workspace():
    # 15 mm of elongation on a 3.8 m rope (0.39 %), as the paper reports
    tilt = tilt_from_rope_elongation(attach_height=3.0, rope_length=3.8, elongation=0.015,
                                     toward=np.array([1.0, 1.0, 0.0]))
    top = settle(np.array([[0.0, 0.0, 3.7]]), np.zeros((1, 3)), np.array([0]), tilt[None])[0]
    assert top[0] > 0 and top[1] > 0 and abs(top[0] - top[1]) < 1e-12
    assert 0.01 < np.linalg.norm(top[:2]) < 0.1  # centimetres, as the paper's A -> A^r
    none = tilt_from_rope_elongation(3.0, 3.8, 0.0, np.array([1.0, 0.0, 0.0]))
    assert np.allclose(none, 0.0)


def test_table1_distances_come_out_of_the_two_descriptions():
    nom = resolve_robot("rocaspect")
    rem = resolve_robot("rocaspect-remeasured")
    d = np.linalg.norm(nom.exits - rem.exits, axis=1)
    for k, cid in enumerate(nom.cable_ids):
        # the paper rounds coordinates to the millimetre before taking distances
        assert abs(d[k] - TABLE1_DIST[cid]) < 2e-3, cid
    assert 0.0567 - 2e-3 < d.min() and d.max() < 0.1144 + 2e-3
    np.testing.assert_array_equal(nom.pivots, rem.pivots)  # the mast bases did not move


def test_table2_compliant_mast_displacements_have_the_papers_magnitude():
    """With the paper's k, exit points A21, A22 move by centimetres with the platform pose."""
    robot = rocaspect(compliant=True)
    assert np.allclose(robot.stiffness, PAPER_K)
    centre = pose_statics(robot, CENTRE)
    assert centre.feasible
    unloaded = robot.exits
    rel, load = [], []
    for pos, (m21, m22) in TABLE2.items():
        ps = pose_statics(robot, np.array([*pos, 0, 0, 0]))
        assert ps.feasible
        for k, _measured in ((2, m21), (3, m22)):
            rel.append(np.linalg.norm(ps.exits[k] - centre.exits[k]))  # like the paper's delta
            load.append(np.linalg.norm(ps.exits[k] - unloaded[k]))  # deflection under load
    rel, load = np.array(rel), np.array(load)
    # centimetre scale, like the paper's 1.0 .. 3.2 cm (see the issue note for the comparison)
    assert 0.001 < rel.max() < 0.04 and rel.max() > 0.01
    assert 0.001 < load.min() and load.max() < 0.04 and load.max() > 0.015
    # the pose nearest mast 2 loads it most; the farthest unloads it
    near = np.array([4.5, 12.5, 1.0, 0, 0, 0])
    far = np.array([15.5, 4.5, 1.0, 0, 0, 0])
    d_near = np.linalg.norm(pose_statics(robot, near).exits[2] - unloaded[2])
    d_far = np.linalg.norm(pose_statics(robot, far).exits[2] - unloaded[2])
    assert d_near > 3 * d_far


def test_infinite_stiffness_gives_the_rigid_model():
    rigid = rocaspect()
    stiff = rocaspect(stiffness=np.full((4, 3), 1e30))
    for pos in TABLE2:
        pose = np.array([*pos, 0, 0, 0])
        a, b = pose_statics(rigid, pose), pose_statics(stiff, pose)
        np.testing.assert_allclose(a.exits, b.exits, atol=1e-12)
        np.testing.assert_allclose(a.tensions, b.tensions, rtol=1e-9)
