"""Newton's method converges by itself (no energy-descent fallback) on the CoGiRo- and
IPAnema-class robots of the evaluation, at random feasible poses, with unstretched lengths
centimetres off the ones that balance there (some cables go slack: the residual's kinks)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.evaluate import feasible_poses, perturb_robot
from controller import equilibrium as eq
from controller.kinematics import cable_state, gravity_wrench
from controller.robot import resolve_robot
from controller.statics import pose_statics


def _cases(name: str, count: int, seed: int):
    rng = np.random.default_rng(seed)
    base = resolve_robot(name)
    out = []
    while len(out) < count:
        robot = base if len(out) % 2 == 0 else perturb_robot(base, rng)
        if len(out) % 4 >= 2:  # compliant masts on half of them
            robot = robot.replace(stiffness=np.tile(rng.uniform(5e4, 1e6, 3),
                                                    (robot.n_masts, 1)))
        poses = feasible_poses(robot, rng, 1, 3.0)
        if len(poses) == 0:
            continue
        ps = pose_statics(robot, poses[0])
        l0 = ps.unstretched + rng.normal(0.0, 0.01, robot.n_cables)
        guess = poses[0] + np.concatenate([rng.normal(0, 0.03, 3), rng.normal(0, 0.006, 3)])
        out.append((robot, l0, guess))
    return out


@pytest.mark.parametrize("name", ["cogiro", "ipanema", "rocaspect"])
def test_newton_converges_without_fallback_at_random_feasible_poses(name, monkeypatch):
    entered = []
    inner = eq._energy_newton
    monkeypatch.setattr(eq, "_energy_newton", lambda *a: entered.append(1) or inner(*a))
    eq.STATS.reset()
    slack = 0
    for robot, l0, guess in _cases(name, 16, seed=11):
        res = eq.solve_equilibrium(robot, l0, guess)
        assert res.success, res.message
        assert eq.is_stable(robot, res, l0)
        # balanced, written out from the conventions
        st = cable_state(res.pose, robot.anchors, res.exits, robot.pulley_radius)
        tau = np.where(st.length > l0, robot.ea * (st.length - l0) / l0, 0.0)
        f = tau[:, None] * st.u
        wg = gravity_wrench(robot.mass, robot.com, robot.gravity, st.R)
        assert np.linalg.norm(f.sum(0) + wg[:3]) < 1e-6 * robot.weight
        assert np.linalg.norm(np.cross(st.Rb, f).sum(0) + wg[3:]) < 1e-6 * robot.weight
        slack += int((tau == 0).any())
    assert eq.STATS.fallbacks == 0 and eq.STATS.failures == 0, eq.STATS.as_dict()
    assert eq.STATS.newton == eq.STATS.calls == 16
    if name == "cogiro":  # centimetres of length on stiff cables: slack cables, kinks
        assert slack >= 3 and entered


def test_energy_newton_finds_the_descents_stable_equilibrium():
    """From the guess, the energy Newton finds the stable equilibrium the trust-region
    descent finds."""
    for robot, l0, guess in _cases("cogiro", 12, seed=5):
        a_star, r, _ = eq._fixed(robot)
        th = np.zeros((robot.n_masts, 3))
        T = eq._terms(robot, guess, th, l0, a_star, r)
        en = eq._energy_newton(robot, l0, guess, th, T, 1e-9, 60, 1)
        ref = eq._energy_descent(robot, l0, guess, None, 1e-9)
        assert en.success and ref.success, (en.message, ref.message)
        np.testing.assert_allclose(en.pose, ref.pose, atol=1e-6)


def test_newton_converges_with_a_mast_axis_stiffer_than_the_others_by_decades():
    """A fit can make a mast axis all but rigid (k = 1e41 N m/rad, finite): the energy's
    curvature on that axis must not drown the others' (the energy Newton stalled there)."""
    eq.STATS.reset()
    for robot, l0, guess in _cases("cogiro", 16, seed=11):
        stiffness = np.tile([3e5, 8e5, 1e5], (robot.n_masts, 1))
        stiffness[1, 2] = 5.6e41
        robot = robot.replace(stiffness=stiffness)
        res = eq.solve_equilibrium(robot, l0, guess)
        assert res.success and eq.is_stable(robot, res, l0), res.message
    assert eq.STATS.fallbacks == 0 and eq.STATS.failures == 0, eq.STATS.as_dict()
