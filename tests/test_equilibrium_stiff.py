"""Cables far stiffer than the platform's weight: a diagnosis's fit can drive a cable's ea to
1e12-1e19 N. The displacement form's Newton cannot solve those (a sideways step of s changes
such a cable's length by s^2/2L, which ea/L turns into kilonewtons; its tension cannot be
resolved from the lengths finer than ea * 1e-16): the solver continues from softened cables
to the mixed form (tensions as unknowns). The captured problems (tests/data) are the ones
where it fell back to the energy descent or failed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from robots import inner_pose, random_robots

from controller import equilibrium as eq
from controller.kinematics import cable_state, gravity_wrench
from controller.pose import compose
from controller.robot import resolve_robot
from controller.statics import pose_statics, unstretched_lengths

DATA = Path(__file__).parent / "data" / "equilibrium_stiff_cables.json"


def _problems():
    doc = json.loads(DATA.read_text())
    robots = [resolve_robot(m["base"]).replace(ea=np.array(m["ea"])) for m in doc["robots"]]
    return [(robots[p["robot"]], np.array(p["l0"]), np.array(p["guess"]))
            for p in doc["problems"]]


def _check_equilibrium(robot, res, l0):
    """Balanced and every cable on its law, written out from the conventions with the
    result's tensions: taut ones at L = L0 (1 + tau/ea), slack ones at tau = 0, L <= L0."""
    st = cable_state(res.pose, robot.anchors, res.exits, robot.pulley_radius)
    tau = res.tensions
    f = tau[:, None] * st.u
    wg = gravity_wrench(robot.mass, robot.com, robot.gravity, st.R)
    assert np.linalg.norm(f.sum(0) + wg[:3]) < 1e-6 * robot.weight
    assert np.linalg.norm(np.cross(st.Rb, f).sum(0) + wg[3:]) < 1e-6 * robot.weight
    assert np.all(tau >= 0)
    taut = tau > 0
    np.testing.assert_allclose(st.length[taut], (l0 * (1 + tau / robot.ea))[taut], rtol=0,
                               atol=1e-9)
    assert np.all(st.length[~taut] <= l0[~taut] + 1e-9)


def test_captured_stiff_cable_problems_converge_by_newton():
    problems = _problems()
    assert len(problems) >= 10 and max(np.max(r.ea) for r, _, _ in problems) > 1e18
    eq.STATS.reset()
    for robot, l0, guess in problems:
        res = eq.solve_equilibrium(robot, l0, guess)
        assert res.success, res.message
        _check_equilibrium(robot, res, l0)
        assert eq.is_stable(robot, res, l0)
    stats = eq.STATS.as_dict()
    assert stats["fallbacks"] == 0 and stats["failures"] == 0, stats
    assert stats["newton"] == stats["calls"] == stats["mixed"] == len(problems)


def test_stiff_cables_are_the_limit_of_stiffer_and_stiffer_displacement_solutions():
    """Independent of the mixed form: the displacement form's Newton with the stiff cables
    softened to ea = 1e8 and 1e10 N lands nearer and nearer (like 1/ea) the mixed form's
    equilibrium."""
    for robot, l0, guess in _problems()[::3]:
        res = eq.solve_equilibrium(robot, l0, guess).raise_if_failed()
        errors = []
        for cap in (1e8, 1e10):
            soft = robot.replace(ea=np.minimum(robot.ea, cap))
            tol = 20 * np.finfo(float).eps * cap * np.sqrt(8) / soft.weight
            ref = eq._newton(soft, l0, res.pose, res.theta, max(tol, 1e-9), 60)
            assert ref.success, ref.message
            errors.append(np.abs(ref.pose - res.pose).max())
        assert errors[1] < 1e-6 and errors[1] < errors[0] / 30 + 1e-12, errors


def test_no_cable_that_stiff_keeps_the_displacement_form():
    """Real cables (ea a few thousand times the weight) never take the mixed form."""
    for name in ("rocaspect", "cogiro", "ipanema"):
        robot = resolve_robot(name)
        assert eq._softened(robot) is None
        assert eq._softened(robot.replace(ea=robot.ea * 1e3)) is not None


@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_mixed_jacobian_matches_finite_differences(data):
    robot = data.draw(random_robots(elastic=True))
    pose = inner_pose(data.draw, robot)
    ps = pose_statics(robot, pose)
    assume(ps.feasible)
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea) * 0.9995
    theta = ps.theta * 1.3 + 1e-4
    tau = ps.tensions * 1.1 + 3.0
    a_star, r, _ = eq._fixed(robot)
    T, _ = eq._mixed_terms(robot, pose, theta, tau, l0, a_star, r)
    Jx, B, G = eq._mixed_jacobian(robot, T, l0, r)
    N = Jx.shape[1]
    h = 1e-7
    for k in range(N):
        dx = np.zeros(N)
        dx[k] = h
        tp, ep = eq._mixed_terms(robot, compose(pose, dx[:6]), theta + dx[6:].reshape(-1, 3),
                                 tau, l0, a_star, r)
        tm, em = eq._mixed_terms(robot, compose(pose, -dx[:6]), theta - dx[6:].reshape(-1, 3),
                                 tau, l0, a_star, r)
        np.testing.assert_allclose(Jx[:, k], (tp.residual - tm.residual) / (2 * h), rtol=1e-5,
                                   atol=1e-6 * np.abs(Jx).max())
        if robot.compliant or k < 6:  # rigid masts: theta is pinned, its columns unused
            np.testing.assert_allclose(G[:, k], (ep - em) / (2 * h), rtol=1e-5, atol=1e-7)
    for j in range(robot.n_cables):
        dt = np.zeros(robot.n_cables)
        dt[j] = 1.0
        tp, ep = eq._mixed_terms(robot, pose, theta, tau + dt, l0, a_star, r)
        tm, em = eq._mixed_terms(robot, pose, theta, tau - dt, l0, a_star, r)
        np.testing.assert_allclose(B[:, j], (tp.residual - tm.residual) / 2, rtol=1e-6,
                                   atol=1e-9 * np.abs(B).max())
        np.testing.assert_allclose((ep - em)[j] / 2, -l0[j] / robot.ea[j], rtol=1e-6)


@settings(max_examples=20, deadline=None)
@given(data=st.data())
def test_mixed_form_finds_the_displacement_forms_equilibrium_on_ordinary_cables(data):
    """Compliant masts, pulleys, cables millimetres off: started near the displacement form's
    equilibrium (as the solver starts it, from the softened cables' one), the mixed form's
    Newton finds that equilibrium (it is a local method: the continuation gives it its
    start)."""
    robot = data.draw(random_robots(elastic=True))
    pose = inner_pose(data.draw, robot)
    ps = pose_statics(robot, pose)
    assume(ps.feasible)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    l0 = unstretched_lengths(ps.state.length, ps.tensions, robot.ea) \
        + rng.normal(0, 0.003, robot.n_cables)
    ref = eq.solve_equilibrium(robot, l0, pose)
    assume(ref.success and eq.is_stable(robot, ref, l0))
    res = eq._mixed_newton(robot, l0, ref.pose + 1e-4, ref.theta, 1e-9, 60,
                           ref.tensions * 1.001)
    assert res.success, res.message
    np.testing.assert_allclose(res.pose, ref.pose, atol=1e-7)
    np.testing.assert_allclose(res.tensions, ref.tensions, atol=1e-4 * robot.weight)


def test_stiff_cable_non_convergence_is_reported_never_silent():
    robot, l0, guess = _problems()[0]
    eq.STATS.reset()
    res = eq.solve_equilibrium(robot, l0, guess + 0.3, max_iter=1)
    assert not res.success and "no convergence" in res.message
    assert eq.STATS.as_dict()["failures"] == 1
    with pytest.raises(eq.ConvergenceError):
        res.raise_if_failed()
    # the mixed form alone, stopped early: a failure with its residual, never a success
    bad = eq._mixed_newton(robot, l0, guess + 0.05, None, 1e-9, 2)
    assert not bad.success and "mixed form" in bad.message and bad.residual > 1e-9


def test_a_long_newton_step_up_the_energy_is_not_taken():
    """Captured (case 9111, IPAnema-class, a mast axis of 1000 N m/rad): Newton's first step
    from the guess, two cables slack there, went 0.6 rad away down the residual but up the
    energy, to an unstable equilibrium; the energy's Newton finds the stable one near the
    guess, with no energy-descent fallback."""
    doc = json.loads((Path(__file__).parent / "data" /
                      "equilibrium_soft_mast_axis.json").read_text())
    fields = {k: (np.where(np.asarray(v) >= 1e300, np.inf, v) if isinstance(v, list) else v)
              for k, v in doc["robot"].items() if k != "base"}
    robot = resolve_robot(doc["robot"]["base"]).replace(**fields)
    eq.STATS.reset()
    for p in doc["problems"]:
        l0, guess, theta = (np.array(p[k]) for k in ("l0", "guess", "theta"))
        res = eq.solve_equilibrium(robot, l0, guess, theta)
        assert res.success, res.message
        assert eq.is_stable(robot, res, l0)
        _check_equilibrium(robot, res, l0)
        assert np.abs(res.pose - guess).max() < 0.01
    stats = eq.STATS.as_dict()
    assert stats["fallbacks"] == 0 and stats["failures"] == 0, stats
