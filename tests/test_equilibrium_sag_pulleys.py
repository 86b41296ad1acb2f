"""Sagging cables on swivel pulleys (IPAnema-class robot with cable_sag and
pulley_kinematics fitted): the equilibrium converges by Newton, without the energy-descent
fallback. Captured problems (tests/data/equilibrium_sag_pulleys.json, evaluation case 9948):
a chord step (the previous step's Jacobian) went 18 mm up the energy and handed over to the
energy's Newton, which stalled micrometres short of the equilibrium: with sag on pulleys the
energy is the forces' potential only to a fraction of a percent, and near its minimum it
changes by its round-off alone."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from controller import equilibrium as eq
from controller.robot import resolve_robot

DATA = Path(__file__).parent / "data" / "equilibrium_sag_pulleys.json"


def _problems():
    doc = json.loads(DATA.read_text())
    fields = {k: (np.where(np.asarray(v) >= 1e300, np.inf, v) if isinstance(v, list) else v)
              for k, v in doc["robot"].items() if k != "base"}
    robot = resolve_robot(doc["robot"]["base"]).replace(**fields)
    assert robot.rho > 0 and np.all(robot.pulley_radius > 0) and robot.compliant
    return robot, [tuple(np.array(p[k]) for k in ("l0", "guess", "theta", "pose"))
                   for p in doc["problems"]]


def _check(robot, res, l0, pose):
    assert res.success, res.message
    assert eq.scaled_residual(robot, l0, res.pose, res.theta) < 1e-8
    assert eq.is_stable(robot, res, l0)
    # the stable equilibrium the energy descent found, sub-millimetre from the guess
    np.testing.assert_allclose(res.pose, pose, rtol=0, atol=1e-8)


def test_captured_sag_pulley_problems_converge_by_newton():
    robot, problems = _problems()
    assert len(problems) == 3
    eq.STATS.reset()
    for l0, guess, theta, pose in problems:
        _check(robot, eq.solve_equilibrium(robot, l0, guess, theta), l0, pose)
    stats = eq.STATS.as_dict()
    assert stats["fallbacks"] == 0 and stats["failures"] == 0, stats
    assert stats["newton"] == stats["calls"] == 3


@pytest.mark.parametrize("i", range(3))
def test_energy_newton_reaches_the_equilibrium_with_sag_on_pulleys(i):
    """The energy's Newton by itself converges to the residual's tolerance (it stalled at a
    scaled residual of 3e-5 to 9e-5 before: the energy's minimum, not the equilibrium)."""
    robot, problems = _problems()
    l0, guess, theta, pose = problems[i]
    a_star, r, _ = eq._fixed(robot)
    T = eq._terms(robot, guess, theta, l0, a_star, r)
    res = eq._energy_newton(robot, l0, guess, theta, T, 1e-9, 60, 1)
    assert res.residual < 1e-9, res.message
    _check(robot, res, l0, pose)


def test_a_stale_jacobians_step_up_the_energy_refreshes_it(monkeypatch):
    """Newton's method alone (no energy Newton) solves the captured problems: a chord step
    that goes up the energy is not taken, the Jacobian is refreshed instead."""
    robot, problems = _problems()
    entered = []
    inner = eq._energy_newton
    monkeypatch.setattr(eq, "_energy_newton", lambda *a: entered.append(1) or inner(*a))
    for l0, guess, theta, pose in problems:
        eq._LAST.pop(robot, None)
        _check(robot, eq._newton(robot, l0, guess, theta, 1e-9, 60), l0, pose)
    assert not entered
