"""Forward kinematics and the elasto-static equilibrium: properties over random robots."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from robots import inner_pose, random_robots, rocaspect

from controller.cycle import LengthController, reference_lengths
from controller.equilibrium import ConvergenceError, residual_and_jacobian, solve_equilibrium
from controller.forward import forward_pose, forward_rigid
from controller.kinematics import cable_state, gravity_wrench
from controller.masts import lever_arms, mast_moments
from controller.pose import compose
from controller.statics import pose_statics, settled_exits, unstretched_lengths


def perturb(draw, pose, size=1.0):
    d = np.array(draw(st.tuples(*[st.floats(-0.05, 0.05)] * 3, *[st.floats(-0.01, 0.01)] * 3)))
    return pose + size * d


@given(data=st.data())
def test_forward_of_inverse_is_identity_rigid_cables(data):
    robot = data.draw(random_robots(elastic=False))
    pose = inner_pose(data.draw, robot)
    ps = pose_statics(robot, pose)
    assume(ps.feasible)
    res = forward_rigid(robot, ps.state.length, perturb(data.draw, pose))
    assert res.success, res.message
    np.testing.assert_allclose(res.pose, pose, atol=1e-8)
    assert res.residual < 1e-9


@given(data=st.data())
def test_forward_of_inverse_is_identity_elastic_cables(data):
    robot = data.draw(random_robots(elastic=True))
    pose = inner_pose(data.draw, robot)
    ps = pose_statics(robot, pose)
    assume(ps.feasible)
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea)
    res = solve_equilibrium(robot, l0, perturb(data.draw, pose))
    assert res.success, res.message
    np.testing.assert_allclose(res.pose, pose, atol=1e-8)
    np.testing.assert_allclose(res.tensions, ps.tensions, atol=1e-5 * robot.weight)
    np.testing.assert_allclose(res.exits, ps.exits, atol=1e-9)


@given(data=st.data())
def test_equilibrium_balances_forces_and_mast_moments(data):
    robot = data.draw(random_robots(elastic=True, compliant=True))
    pose = inner_pose(data.draw, robot)
    ps = pose_statics(robot, pose)
    assume(ps.feasible)
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea)
    l0 = l0 * (1 + np.array(data.draw(st.tuples(*[st.floats(-2e-4, 2e-4)] * 8))))
    res = solve_equilibrium(robot, l0, pose)
    assert res.success, res.message
    # independent check, written out from the conventions
    st_ = cable_state(res.pose, robot.anchors, res.exits, robot.pulley_radius)
    tau = robot.ea * (st_.length - l0) / l0
    tau[st_.length <= l0] = 0.0
    np.testing.assert_allclose(tau, res.tensions, atol=1e-6)
    f = tau[:, None] * st_.u
    wg = gravity_wrench(robot.mass, robot.com, robot.gravity, st_.R)
    assert np.linalg.norm(f.sum(0) + wg[:3]) < 1e-6 * robot.weight
    assert np.linalg.norm(np.cross(st_.Rb, f).sum(0) + wg[3:]) < 1e-6 * robot.weight
    a_star = settled_exits(robot)
    r = lever_arms(a_star, robot.pivots, robot.mast_index)
    M = mast_moments(r, tau, st_.u, robot.mast_index, robot.n_masts)
    np.testing.assert_allclose(robot.stiffness * res.theta, M, atol=1e-6 * np.abs(M).max())
    np.testing.assert_allclose(res.exits, a_star + np.cross(res.theta[robot.mast_index], r),
                               atol=1e-12)


@given(data=st.data())
def test_analytic_equilibrium_jacobian_matches_finite_differences(data):
    robot = data.draw(random_robots(elastic=True))
    pose = inner_pose(data.draw, robot)
    ps = pose_statics(robot, pose)
    assume(ps.feasible)
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea) * 0.9995
    theta = ps.theta * 1.3 + 1e-4
    _, J = residual_and_jacobian(robot, pose, theta, l0)
    eps = 1e-7
    for k in range(J.shape[1]):
        dx = np.zeros(J.shape[1])
        dx[k] = eps
        tp, _ = residual_and_jacobian(robot, compose(pose, dx[:6]), theta + dx[6:].reshape(-1, 3),
                                      l0)
        tm, _ = residual_and_jacobian(robot, compose(pose, -dx[:6]),
                                      theta - dx[6:].reshape(-1, 3), l0)
        fd = (tp.residual - tm.residual) / (2 * eps)
        np.testing.assert_allclose(J[:, k], fd, rtol=1e-5, atol=1e-6 * np.abs(J).max())


@given(data=st.data())
def test_infinite_stiffness_and_stiff_cables_give_the_rigid_model(data):
    robot = data.draw(random_robots(elastic=True, compliant=True, pulleys=False))
    pose = inner_pose(data.draw, robot)
    stiff_masts = robot.replace(stiffness=np.full((4, 3), 1e30))
    rigid_masts = robot.replace(stiffness=np.full((4, 3), np.inf))
    a, b = pose_statics(stiff_masts, pose), pose_statics(rigid_masts, pose)
    assume(a.feasible)
    l0 = unstretched_lengths(b.state.length, b.tensions, robot.ea)
    ra = solve_equilibrium(stiff_masts, l0, pose)
    rb = solve_equilibrium(rigid_masts, l0, pose)
    assert ra.success and rb.success
    np.testing.assert_allclose(ra.pose, rb.pose, atol=1e-9)
    # stiffer and stiffer cables of the geometric lengths: the equilibrium tends to the rigid
    # pose, the error shrinking like 1/ea
    lengths = b.state.length
    errors = []
    for ea in (1e6, 1e8, 1e10):
        eq = solve_equilibrium(rigid_masts.replace(ea=np.full(8, ea)), lengths, pose)
        assert eq.success, eq.message
        errors.append(np.linalg.norm(eq.pose[:3] - pose[:3]))
    # (the error's size depends on the geometry: flat cables amplify the stretch into a drop
    # of centimetres at ea = 1e6; what must hold is the 1/ea shrinking)
    assert errors[2] < 1e-3 * errors[0] + 1e-11
    assert errors[1] < errors[0] / 30 + 1e-11 and errors[2] < errors[1] / 30 + 1e-11
    fk = forward_rigid(rigid_masts.replace(ea=np.full(8, np.inf)), lengths, pose + 0.01)
    assert fk.success and np.linalg.norm(fk.pose - pose) < 1e-8


def test_non_convergence_is_reported_never_silent():
    robot = rocaspect()
    pose = np.array([10.0, 8.5, 1.0, 0, 0, 0])
    ps = pose_statics(robot, pose)
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea)
    res = solve_equilibrium(robot, l0, pose + 0.3, max_iter=1)
    assert not res.success and "no convergence" in res.message
    with pytest.raises(ConvergenceError):
        res.raise_if_failed()
    bad = forward_rigid(robot.replace(ea=np.full(8, np.inf)), l0 * 0.5, pose, max_iter=3)
    assert not bad.success and bad.message


def test_forward_pose_dispatches_on_elasticity():
    robot = rocaspect(compliant=True)
    pose = np.array([6.0, 5.0, 1.2, 0.01, 0.0, -0.02])
    ps = pose_statics(robot, pose)
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea)
    el = forward_pose(robot, l0, pose + 0.02)
    assert el.success and np.allclose(el.pose, pose, atol=1e-8)
    rig = robot.replace(ea=np.full(8, np.inf))
    ps = pose_statics(rig, pose)
    fk = forward_pose(rig, ps.state.length, pose + 0.02)
    assert fk.success and np.allclose(fk.pose, pose, atol=1e-8)


@pytest.mark.parametrize("compliant", [False, True])
def test_control_cycle_lengths_reach_the_desired_pose(compliant):
    """Setpoints in the encoder reference, read back with the initialisation convention,
    put a plant that equals the model exactly at the desired pose."""
    robot = rocaspect(compliant=compliant)
    p0 = np.array([10.0, 8.56, 1.0, 0, 0, 0])
    ctl = LengthController(robot, p0)
    d_ref = reference_lengths(robot, p0)
    ps0 = pose_statics(robot, p0)
    u0 = unstretched_lengths(ps0.state.length, ps0.tensions, robot.ea)
    for target in ([4.5, 4.5, 1.0, 0, 0, 0], [15.5, 12.5, 1.5, 0.02, -0.01, 0.05]):
        target = np.array(target)
        out = None
        for _ in range(3):  # mast update from the "measured" (planned) tensions converges
            out = ctl.step(target, None if out is None else out.tensions)
        assert out.feasible
        l0 = out.lengths - d_ref + u0  # conventions: L0 = l_meas - d_model(p0) + d(p0)/(1+t0/ea)
        res = solve_equilibrium(robot, l0, p0)
        assert res.success
        assert np.linalg.norm(res.pose[:3] - target[:3]) < 2e-4
