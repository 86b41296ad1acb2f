"""Pulley kinematics against an independent numerical tangent construction."""

from __future__ import annotations

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.optimize import brentq

from controller.kinematics import cable_state, length_jacobian, unit_vector_derivative
from controller.pose import compose


def standard_formula(A, B, r):
    """Pott 2012 / WireX / cdpyr form: gamma by atan2, l_f and beta by the acos formula."""
    b = B - A
    gamma = np.arctan2(b[1], b[0])
    e_h = np.array([np.cos(gamma), np.sin(gamma), 0.0])
    M = A + r * e_h
    BM = M - B
    D = np.linalg.norm(BM)
    lf = np.sqrt(D**2 - r**2)
    dz = B[2] - M[2]
    beta = np.arccos(lf / D) + np.arccos(dz / D)
    return r * beta + lf, beta


def numerical_tangent(A, B, r):
    """Swivel by root finding (B in the pulley plane), tangent point by root finding
    ((C - B) perpendicular to (C - M)) on the side the cable runs, wrap measured from A."""
    b = B - A
    g = brentq(lambda a: -np.sin(a) * b[0] + np.cos(a) * b[1],
               np.arctan2(b[1], b[0]) - 1.0, np.arctan2(b[1], b[0]) + 1.0, xtol=1e-15)
    e_h = np.array([np.cos(g), np.sin(g), 0.0])
    if e_h @ b < 0:
        e_h = -e_h
    ez = np.array([0.0, 0.0, 1.0])
    M = A + r * e_h

    def C(phi):
        return M + r * (np.cos(phi) * e_h + np.sin(phi) * ez)

    def tangency(phi):
        return (C(phi) - B) @ (C(phi) - M)

    # the cable runs from A (phi = pi) clockwise over the top; scan for the tangency root
    # where the cable continues in the running direction
    phis = np.linspace(np.pi, np.pi - 2 * np.pi + 1e-9, 4001)
    vals = np.array([tangency(p) for p in phis])
    for k in range(len(phis) - 1):
        if vals[k] == 0 or vals[k] * vals[k + 1] < 0:
            p = brentq(tangency, phis[k + 1], phis[k], xtol=1e-15)
            run = np.sin(p) * e_h - np.cos(p) * ez  # direction of travel at C (clockwise)
            if (B - C(p)) @ run > 0:
                beta = np.pi - p
                return r * beta + np.linalg.norm(B - C(p)), beta
    raise AssertionError("no tangent point")


@given(
    bx=st.floats(0.5, 20.0), by=st.floats(-20.0, 20.0), bz=st.floats(-6.0, 1.5),
    r=st.floats(0.01, 0.4),
)
def test_standard_formula_matches_numerical_tangent(bx, by, bz, r):
    assume(np.hypot(np.hypot(bx, by) - r, bz) > 2 * r)  # B well off the pulley
    A = np.array([1.0, 2.0, 3.5])
    B = A + np.array([bx, by, bz])
    length, beta = standard_formula(A, B, r)
    ref_len, ref_beta = numerical_tangent(A, B, r)
    assert abs(length - ref_len) < 1e-9
    assert abs(beta - ref_beta) < 1e-8
    st_ = cable_state(np.array([*B, 0, 0, 0]), np.zeros((1, 3)), A[None], np.array([r]))
    assert abs(st_.length[0] - ref_len) < 1e-9
    assert abs(st_.beta[0] - ref_beta) < 1e-8


def test_wraps_beyond_half_turn():
    """B almost straight below the pulley: the cable wraps more than 180 degrees."""
    A = np.array([0.0, 0.0, 3.5])
    r = 0.2
    for B in (A + [0.35, 0.1, -3.0], A + [0.3, 0.05, -4.0], A + [0.25, 0.0, -2.0]):
        length, beta = standard_formula(A, B, r)
        ref_len, ref_beta = numerical_tangent(A, B, r)
        assert beta > np.pi
        assert abs(length - ref_len) < 1e-9
        st_ = cable_state(np.array([*B, 0, 0, 0]), np.zeros((1, 3)), A[None], np.array([r]))
        assert abs(st_.length[0] - ref_len) < 1e-9


def test_zero_radius_is_straight_line():
    A = np.array([[0.0, 0.0, 3.5]])
    pose = np.array([3.0, 4.0, 1.0, 0.1, 0.2, 0.3])
    st0 = cable_state(pose, np.array([[0.2, 0.1, 0.0]]), A, np.array([0.0]))
    st1 = cable_state(pose, np.array([[0.2, 0.1, 0.0]]), A, np.array([1e-12]))
    assert abs(st0.length[0] - np.linalg.norm(st0.B[0] - A[0])) < 1e-12
    assert abs(st1.length[0] - st0.length[0]) < 1e-9


def test_pulley_derivatives_match_finite_differences():
    rng = np.random.default_rng(3)
    A = rng.uniform(-6, 6, (8, 3))
    A[:, 2] = 3.6
    Bp = rng.uniform(-0.5, 0.5, (8, 3))
    r = rng.uniform(0.05, 0.2, 8)
    pose = np.array([0.3, 0.2, 1.0, 0.1, -0.05, 0.2])
    st_ = cable_state(pose, Bp, A, r)
    J = length_jacobian(st_)
    eps = 1e-6
    for k in range(6):
        dx = np.zeros(6)
        dx[k] = eps
        fd = (cable_state(compose(pose, dx), Bp, A, r).length
              - cable_state(compose(pose, -dx), Bp, A, r).length) / (2 * eps)
        np.testing.assert_allclose(J[:, k], fd, atol=1e-7)
    D = unit_vector_derivative(st_)
    for k in range(3):
        dA = np.zeros((8, 3))
        dA[:, k] = eps
        fd = (cable_state(pose, Bp, A - dA, r).u - cable_state(pose, Bp, A + dA, r).u) / (2 * eps)
        np.testing.assert_allclose(D[:, :, k], fd, atol=1e-7)
