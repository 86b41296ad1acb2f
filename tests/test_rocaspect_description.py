"""The shipped ROCASPECT description: feasible and controllable over the paper's workspace."""

from __future__ import annotations

import numpy as np
from robots import rocaspect

from bench.commands.model import platform_stiffness_min
from controller.statics import pose_statics
from controller.workspace import wrench_feasible_grid


def test_tension_distribution_feasible_over_the_papers_workspace():
    """Paper: workspace footprint 332.5 m^2 at 1 m height (robot footprint 443 m^2)."""
    grid = wrench_feasible_grid(rocaspect(), z=1.0, step=0.5)
    assert 320.0 < grid.area < 345.0
    lo, hi = grid.tension_range
    assert lo >= 5.0 - 1e-9 and hi < 400.0
    # the feasible region is one piece around the centre, not scattered points
    cx, cy = np.searchsorted(grid.xs, 10.0), np.searchsorted(grid.ys, 8.56)
    assert grid.feasible[cx - 8:cx + 8, cy - 8:cy + 8].all()


def test_qp_and_closed_form_agree_on_feasibility():
    a = wrench_feasible_grid(rocaspect(), z=1.0, step=1.5, method="closed_form")
    b = wrench_feasible_grid(rocaspect(), z=1.0, step=1.5, method="qp")
    # the exact QP finds every point the closed form finds, and not many more
    assert np.all(b.feasible[a.feasible])
    assert b.feasible.sum() <= a.feasible.sum() * 1.05 + 2


def test_controllable_in_six_directions_over_the_workspace():
    robot = rocaspect()
    for x in (2.0, 10.0, 18.0):
        for y in (2.0, 8.5, 15.0):
            for rpy in ((0, 0, 0), (0.05, -0.05, 0.1)):
                pose = np.array([x, y, 1.0, *rpy])
                ps = pose_statics(robot, pose)
                assert ps.feasible, (x, y, ps.reason)
                W = np.vstack([ps.state.u.T, np.cross(ps.state.Rb, ps.state.u).T])
                assert np.linalg.matrix_rank(W) == 6
                # positive definite stiffness: the platform resists a push in every direction
                assert platform_stiffness_min(robot, pose, ps.tensions, ps.state.length) > 0


def test_straight_cables_would_shrink_the_workspace():
    """Why the description crosses its cables: the straight layout loses most of it."""
    robot = rocaspect()
    straight = robot.replace(anchors=np.array(
        [[-.5, -.5, .25], [-.5, -.5, -.25], [-.5, .5, .25], [-.5, .5, -.25],
         [.5, .5, .25], [.5, .5, -.25], [.5, -.5, .25], [.5, -.5, -.25]]))
    crossed = wrench_feasible_grid(robot, step=1.0).area
    plain = wrench_feasible_grid(straight, step=1.0).area
    assert plain < 0.6 * crossed
