"""The elastic catenary and sagging cables in the statics."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from robots import rocaspect
from scipy.integrate import quad

from controller import cables, catenary
from controller.equilibrium import residual_and_jacobian, solve_equilibrium
from controller.kinematics import cable_state
from controller.pose import compose
from controller.statics import pose_statics
from firmware_sim.plant import Plant


@given(H=st.floats(20.0, 2000.0), VB=st.floats(-100.0, 500.0), L0=st.floats(2.0, 30.0),
       ea=st.floats(1e5, 1e7), rho=st.floats(0.005, 0.3))
def test_spans_match_integration_of_the_cable(H, VB, L0, ea, rho):
    w, inv = rho * 9.81, 1.0 / ea
    h, v = catenary.spans(H, VB, L0, inv, w)

    def T(s):
        return np.hypot(H, VB + w * s)

    hx = quad(lambda s: H / T(s) * (1 + T(s) * inv), 0, L0, epsabs=1e-12, epsrel=1e-13)[0]
    vz = quad(lambda s: (VB + w * s) / T(s) * (1 + T(s) * inv), 0, L0, epsabs=1e-12,
              epsrel=1e-13)[0]
    assert abs(h - hx) < 1e-9 * L0 and abs(v - vz) < 1e-9 * L0


@given(H=st.floats(20.0, 2000.0), VB=st.floats(-100.0, 500.0), L0=st.floats(2.0, 30.0),
       rho=st.floats(0.005, 0.3))
def test_inverse_problems_recover_forces_and_lengths(H, VB, L0, rho):
    w, inv = rho * 9.81, 1.0 / 6e5
    h, v = catenary.spans(H, VB, L0, inv, w)
    H2, V2, ok = catenary.end_forces(h, v, L0, inv, w)
    assert ok and H2 == pytest.approx(H, rel=1e-8) and V2 == pytest.approx(VB, abs=1e-6 * H)
    for end, T in (("A", np.hypot(H, VB + w * L0)), ("B", np.hypot(H, VB))):
        L, H3, V3, ok = catenary.unstretched(h, v, T, inv, w, end=end)
        assert ok and L == pytest.approx(L0, rel=1e-9) and H3 == pytest.approx(H, rel=1e-7)


def test_energy_gradient_is_minus_the_end_force():
    w, inv, L0 = 0.5, 1 / 6e5, 15.0
    H, VB = 120.0, -20.0
    h, v = catenary.spans(H, VB, L0, inv, w)

    def U(h_, v_, zB):
        Hh, Vv, _ = catenary.end_forces(h_, v_, L0, inv, w)
        return catenary.energy(Hh, Vv, L0, inv, w, zB)

    e = 1e-6  # B moving towards A shortens h; B moving up shortens v
    fx = -(U(h - e, v, 0.0) - U(h + e, v, 0.0)) / (2 * e)
    fz = -(U(h, v - e, e) - U(h, v + e, -e)) / (2 * e)
    assert fx == pytest.approx(H, rel=1e-6) and fz == pytest.approx(VB, rel=1e-5)


def test_light_cables_tend_to_the_straight_elastic_cable():
    robot = rocaspect()
    pose = np.array([6.0, 5.0, 1.2, 0.0, 0.0, 0.0])
    straight = pose_statics(robot, pose)
    s = cable_state(pose, robot.anchors, robot.exits)
    errs = []
    for rho in (1e-2, 1e-3, 1e-4):
        cf = cables.from_lengths(robot.replace(rho=rho), s, straight.unstretched)
        errs.append(np.abs(cf.tension - straight.tensions).max())
    assert errs[2] < 0.05 and errs[1] < errs[0] and errs[2] < errs[1]


@settings(max_examples=10)
@given(rho=st.floats(0.02, 0.12), x=st.floats(6.0, 14.0), y=st.floats(5.0, 12.0))
def test_sagging_equilibrium_jacobian_and_plant(rho, x, y):
    robot = rocaspect(compliant=True).replace(rho=rho)
    pose = np.array([x, y, 1.2, 0.01, 0.0, -0.02])
    ps = pose_statics(robot, pose)
    assert ps.feasible
    # the statics' unstretched lengths hang the platform exactly at the pose
    res = solve_equilibrium(robot, ps.unstretched, pose + 0.01)
    assert res.success and np.abs(res.pose - pose).max() < 1e-7
    np.testing.assert_allclose(res.tensions, ps.tensions, rtol=1e-5)
    # analytic Jacobian against finite differences
    l0 = ps.unstretched * (1 + 1e-4)
    _, J = residual_and_jacobian(robot, pose, ps.theta, l0)
    eps = 1e-7
    for k in range(J.shape[1]):
        dx = np.zeros(J.shape[1])
        dx[k] = eps
        tp, _ = residual_and_jacobian(robot, compose(pose, dx[:6]),
                                      ps.theta + dx[6:].reshape(-1, 3), l0)
        tm, _ = residual_and_jacobian(robot, compose(pose, -dx[:6]),
                                      ps.theta - dx[6:].reshape(-1, 3), l0)
        np.testing.assert_allclose(J[:, k], (tp.residual - tm.residual) / (2 * eps),
                                   rtol=1e-4, atol=1e-5 * np.abs(J).max())
    # the plant's energy minimum is the same rest position
    plant = Plant(robot, robot, pose)
    rest = plant.rest(l0, guess=pose)
    eq = solve_equilibrium(robot, l0, pose)
    assert np.abs(rest.pose - eq.pose).max() < 1e-6
