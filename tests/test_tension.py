"""Tension distribution: balance, bounds, optimality, and honest infeasibility."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from robots import inner_pose, random_robots, rocaspect
from scipy.optimize import minimize

from controller.kinematics import cable_state, gravity_wrench, wrench_matrix
from controller.tension import closed_form, distribute, min_norm_qp


def wrench_problem(robot, pose):
    s = cable_state(pose, robot.anchors, robot.exits, robot.pulley_radius)
    return wrench_matrix(s), gravity_wrench(robot.mass, robot.com, robot.gravity, s.R)


@given(data=st.data())
def test_feasible_results_balance_and_stay_in_bounds(data):
    robot = data.draw(random_robots())
    pose = inner_pose(data.draw, robot)
    W, wg = wrench_problem(robot, pose)
    for method in ("closed_form", "qp"):
        res = distribute(W, wg, robot.tension_min, robot.tension_max, method)
        if res.feasible:
            assert np.all(res.tensions >= robot.tension_min)
            assert np.all(res.tensions <= robot.tension_max)
            assert np.linalg.norm(W @ res.tensions + wg) < 1e-6
        else:
            assert np.all(np.isnan(res.tensions)) and res.reason


def kkt_certificate(W, f, tau, tmin, tmax, tol=1e-6):
    """Optimality of min |tau|^2 s.t. W tau = f, tmin <= tau <= tmax (convex: KKT suffices):
    tau = W^T y + lam with lam >= 0 on lower-active, <= 0 on upper-active, 0 on free."""
    scale = max(1.0, np.abs(tau).max())
    low = np.isclose(tau, tmin, atol=1e-7 * scale)
    up = np.isclose(tau, tmax, atol=1e-7 * scale)
    free = ~(low | up)
    y = np.linalg.lstsq(W[:, free].T, tau[free], rcond=None)[0]
    lam = tau - W.T @ y
    assert np.abs(lam[free]).max(initial=0) < tol * scale
    assert np.all(lam[low] >= -tol * scale)
    assert np.all(lam[up] <= tol * scale)
    assert np.linalg.norm(W @ tau - f) < 1e-6


@given(data=st.data())
def test_qp_is_the_minimal_norm_distribution(data):
    robot = data.draw(random_robots())
    pose = inner_pose(data.draw, robot)
    W, wg = wrench_problem(robot, pose)
    tmin = data.draw(st.floats(1.0, 60.0))
    res = min_norm_qp(W, -wg, tmin, robot.tension_max)
    assume(res.feasible)
    kkt_certificate(W, -wg, res.tensions, tmin, robot.tension_max)
    ref = minimize(lambda t: t @ t, res.tensions + 1.0, jac=lambda t: 2 * t, method="SLSQP",
                   bounds=[(tmin, robot.tension_max)] * 8,
                   constraints=[{"type": "eq", "fun": lambda t: W @ t + wg, "jac": lambda t: W}],
                   options={"ftol": 1e-14, "maxiter": 500})
    if ref.success and np.linalg.norm(W @ ref.x + wg) < 1e-6:
        assert res.tensions @ res.tensions <= ref.fun * (1 + 1e-7) + 1e-9


def test_qp_kkt_detects_a_suboptimal_distribution():
    """The certificate used above must reject a feasible but non-minimal distribution."""
    robot = rocaspect()
    W, wg = wrench_problem(robot, np.array([10.0, 8.5, 1.0, 0, 0, 0]))
    qp = min_norm_qp(W, -wg, 5.0, 3000.0)
    kkt_certificate(W, -wg, qp.tensions, 5.0, 3000.0)
    null = np.linalg.svd(W)[2][-1]  # a null-space direction: balance is kept
    worse = qp.tensions + 5.0 * null
    assert np.all(worse > 5.0) and np.linalg.norm(W @ worse + wg) < 1e-6
    assert worse @ worse > qp.tensions @ qp.tensions
    with pytest.raises(AssertionError):
        kkt_certificate(W, -wg, worse, 5.0, 3000.0)


def test_closed_form_fixes_cables_at_their_bounds_near_the_border():
    robot = rocaspect()
    clipped = 0
    for x in np.arange(0.0, 21.0, 0.7):
        for y in np.arange(0.0, 17.0, 0.7):
            W, wg = wrench_problem(robot, np.array([x, y, 1.0, 0, 0, 0]))
            res = closed_form(W, -wg, 20.0, 3000.0)
            if res.feasible and res.iterations > 1:
                clipped += 1
                assert np.isclose(res.tensions, 20.0).any()
                assert np.all(res.tensions >= 20.0)
                assert np.linalg.norm(W @ res.tensions + wg) < 1e-6
    assert clipped > 5


@pytest.mark.parametrize("method", ["closed_form", "qp"])
def test_infeasible_says_why_and_returns_no_number(method):
    robot = rocaspect()
    # outside the footprint: gravity cannot be balanced with positive tensions
    W, wg = wrench_problem(robot, np.array([30.0, 8.0, 1.0, 0, 0, 0]))
    res = distribute(W, wg, robot.tension_min, robot.tension_max, method)
    assert not res.feasible
    assert np.all(np.isnan(res.tensions))
    assert "wrench" in res.reason
    # tension_max too low for the weight
    W, wg = wrench_problem(robot, np.array([10.0, 8.5, 1.0, 0, 0, 0]))
    res = distribute(W, wg, 1.0, 20.0, method)
    assert not res.feasible and np.all(np.isnan(res.tensions))


def test_rank_deficient_wrench_matrix_is_infeasible():
    W = np.zeros((6, 8))
    W[2] = 1.0  # only vertical forces
    res = closed_form(W, np.array([0, 0, 300.0, 0, 0, 1.0]), 1.0, 1000.0)
    assert not res.feasible and "rank" in res.reason or "balance" in res.reason
    res = min_norm_qp(W, np.array([0, 0, 300.0, 0, 0, 1.0]), 1.0, 1000.0)
    assert not res.feasible


def test_unknown_method():
    with pytest.raises(ValueError, match="unknown tension distribution"):
        distribute(np.eye(6, 8), np.zeros(6), 0, 1, "magic")
