"""Sagging cables' catenaries kept between evaluations (controller/cables.py ``inputs``,
ResidualModel's memos) and the warm starts of the statics: the same answers as solving
every evaluation from scratch, with the Newton iterations only where something moved."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from robots import rocaspect

from bench.campaign import run_campaign
from bench.diagnosis.fit import fd_jacobian
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.diagnosis.space import ParamSpace
from bench.recording import read_recording
from controller import cables, catenary
from controller.kinematics import cable_state
from controller.statics import batch_statics, pose_statics
from firmware_sim.scenario import parse_scenario

POSES = np.array([[10.0, 8.56, 1.0, 0.0, 0.0, 0.0], [6.0, 5.0, 1.5, 0.02, -0.01, 0.1],
                  [15.0, 12.0, 0.8, 0.0, 0.03, -0.05]])


def _hung(rho: float = 0.08):
    r = rocaspect(rho=rho)
    st = cable_state(POSES, r.anchors, np.broadcast_to(r.exits, (len(POSES),) + r.exits.shape),
                     r.pulley_radius)
    tau = np.linspace(150.0, 900.0, len(POSES) * r.n_cables).reshape(len(POSES), r.n_cables)
    return r, st, tau


def test_the_platform_side_of_a_state_given_back_gives_the_same_state():
    r = rocaspect()
    st = cable_state(POSES, r.anchors, np.broadcast_to(r.exits, (3,) + r.exits.shape))
    moved = r.exits + 0.01
    again = cable_state(POSES, r.anchors, moved, frame=st)
    fresh = cable_state(POSES, r.anchors, moved)
    for f in ("R", "Rb", "B", "u", "length", "C"):
        assert np.array_equal(getattr(again, f), getattr(fresh, f)), f


def test_a_guess_solved_for_the_same_inputs_is_given_back_and_others_are_solved():
    r, st, tau = _hung()
    cf, l0 = cables.from_tensions(r, st, tau)
    assert cf.converged.all()
    same, l_same = cables.from_tensions(r, st, tau, cf)
    assert np.array_equal(l_same, l0) and np.array_equal(same.H, cf.H)
    # one cable's tension moved: only it is solved again, to the cold solution
    t2 = tau.copy()
    t2[1, 3] += 40.0
    sizes = []
    solve = catenary.unstretched

    def counted(h, *a, **k):
        sizes.append(np.size(h))
        return solve(h, *a, **k)

    cold = cables.from_tensions(r, st, t2)[1]
    catenary.unstretched = counted
    try:
        warm = cables.from_tensions(r, st, t2, cf)[1]
    finally:
        catenary.unstretched = solve
    assert sizes == [1]
    np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-10)
    assert np.array_equal(warm[0], l0[0]) and np.array_equal(warm[2], l0[2])


def test_the_cables_weight_is_part_of_what_a_kept_solution_was_solved_for():
    r, st, tau = _hung(0.08)
    cf = cables.from_tensions(r, st, tau)[0]
    heavier = r.replace(rho=0.12)
    np.testing.assert_allclose(cables.from_tensions(heavier, st, tau, cf)[1],
                               cables.from_tensions(heavier, st, tau)[1], rtol=0, atol=1e-10)
    assert np.abs(cables.from_tensions(heavier, st, tau)[1]
                  - cables.from_tensions(r, st, tau)[1]).max() > 1e-4


def test_warm_started_statics_end_where_cold_ones_do():
    r, _, tau = _hung()
    r = r.replace(stiffness=np.tile((2e5, 5e5, 3e5), (r.n_masts, 1)))
    cold = batch_statics(r, POSES, tau)
    near = r.replace(rho=0.081)
    warm = batch_statics(near, POSES, tau, exits0=cold.exits, forces0=cold.forces)
    ref = batch_statics(near, POSES, tau)
    np.testing.assert_allclose(warm.unstretched, ref.unstretched, rtol=0, atol=1e-9)
    np.testing.assert_allclose(warm.exits, ref.exits, rtol=0, atol=1e-9)
    p0 = pose_statics(r, POSES[0], tensions=tau[0])
    p1 = pose_statics(near, POSES[0], tensions=tau[0], exits0=p0.exits, forces0=p0.forces)
    p2 = pose_statics(near, POSES[0], tensions=tau[0])
    assert p1.feasible and p1.iterations < p2.iterations
    np.testing.assert_allclose(p1.unstretched, p2.unstretched, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def sagging(tmp_path_factory):
    """A recording of ROCASPECT with sagging cables, load cells and a tracker."""
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"cable_sag": {"rho": 0.08}, "exit_point_offset": {"dx_21": 0.02}},
        "poses": copy.deepcopy({"kind": "grid", "n": [3, 2, 1], "rpy_deg": 1.0, "visits": 2})})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("rec") / "rec"))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    assert rm.has_tau.any()
    return rm


def test_the_jacobian_with_kept_catenaries_equals_one_solved_from_scratch(sagging):
    space = ParamSpace(sagging.model, ("cable_sag", "exit_point_offset"))
    x = space.neutral.copy()
    assert space.params[0].key == "rho"
    x[0] = space.params[0].from_value(0.08)
    fresh = copy.deepcopy(sagging)  # no evaluation made yet: nothing kept
    rm = copy.deepcopy(sagging)

    def fun(phi):
        return rm.whitened(space.robot(phi))

    steps = space.scale * 1e-2
    f0 = fun(x)
    J = fd_jacobian(fun, x, f0, steps, space.lo, space.hi, rm.frozen)
    for k in (0, 1, 7):  # the weight of the cables, an exit offset of one cable and another's
        xp = x.copy()
        xp[k] += steps[k]
        ref = (copy.deepcopy(fresh).whitened(space.robot(xp))
               - copy.deepcopy(fresh).whitened(space.robot(x))) / steps[k]
        assert np.abs(ref).max() > 0
        np.testing.assert_allclose(J[:, k], ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_a_cable_too_slack_to_hang_gets_the_same_answer_whatever_the_guess():
    """A reading below what any catenary of its span pulls at the top has no solution; the
    answer it gets must not hang on what was solved before (the cold start's)."""
    r, st, tau = _hung(0.3)
    cf = cables.from_tensions(r, st, tau)[0]
    low = tau.copy()
    low[0, 2] = 4.0  # newtons: less than the weight of the span
    cold_cf, cold = cables.from_tensions(r, st, low)
    assert not cold_cf.converged[0, 2] and cold_cf.converged.sum() == cold_cf.converged.size - 1
    for guess in (cf, cables.from_tensions(r, st, tau * 1.3)[0]):
        warm_cf, warm = cables.from_tensions(r, st, low, guess)
        assert not warm_cf.converged[0, 2]
        assert np.array_equal(warm[0, 2], cold[0, 2])
        np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-9)
