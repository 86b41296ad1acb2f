"""Replicate groups of rows of moves: rows near each other on moves that are not neighbours
(neighbouring moves meet at the target between them and share that visit's errors)."""

import numpy as np

from bench.diagnosis.samples import _near_groups


def test_rows_near_each_other_group_only_across_moves_that_are_not_neighbours():
    p = np.array([[1.0, 2.0, 1.0, 0.0, 0.0, 0.0]])
    pose = np.repeat(p, 4, axis=0) + np.array([[0, 0, 0, 0, 0, 0], [1e-3, 0, 0, 0, 0, 0],
                                               [0, 1e-3, 0, 0, 0, 0], [0, 0, 1e-3, 0, 0, 0]])
    seg = np.array([0, 1, 2, 5])
    g = _near_groups(pose, pose, seg)
    assert g[0] != g[1]  # neighbouring moves: the visit at the target between them
    assert g[0] == g[2] == g[3]
    assert len(set(_near_groups(pose, pose, np.array([3, 3, 4, 4])).tolist())) == 4


def test_far_rows_never_group():
    pose = np.array([[0.0, 0, 1, 0, 0, 0], [5.0, 0, 1, 0, 0, 0]])
    assert len(set(_near_groups(pose, pose, np.array([0, 7])).tolist())) == 2
