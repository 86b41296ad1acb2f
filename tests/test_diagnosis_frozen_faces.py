"""The fast path of the internal forces (bench/diagnosis/internal_forces.py ``hint``) and of
the finite-difference Jacobian around one evaluation (ResidualModel.frozen): the same
answers as the full search, at a fraction of its cost."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis import internal_forces
from bench.diagnosis.fit import fd_jacobian
from bench.diagnosis.internal_forces import fit_internal_forces
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.diagnosis.space import ParamSpace
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario


def _problem(seed: int, n: int = 8, M: int = 60, slack_long: float = 5e-3,
             coupled: bool = False):
    """Random balance problems with noisy readings, some cables reading long (slack) and
    some interior minimisers pushing a cable (the convex problem's faces); the first
    quarter of the samples read their true tensions' stretch to within 1 um (interior).
    ``coupled``: a cable's length hangs on the others' tensions too (compliant masts)."""
    rng = np.random.default_rng(seed)
    W = rng.normal(size=(M, 6, n))
    true = rng.uniform(20.0, 300.0, size=(M, n))
    f = np.einsum("mik,mk->mi", W, true)
    tau_k = np.full((M, n), 150.0)
    c = -rng.uniform(1e-6, 1e-5, size=(M, n))
    if coupled:
        c = c[:, :, None] * np.eye(n) + rng.normal(0.0, 1e-6, size=(M, n, n))
    r = rng.normal(0.0, 2e-3, size=(M, n)) - slack_long * rng.uniform(0.0, 1.0, size=(M, n))
    q = M // 4
    r[:q] = np.einsum("...ij,...j->...i" if coupled else "...i,...i->...i", c[:q],
                      tau_k[:q] - true[:q]) + rng.normal(0.0, 1e-6, size=(q, n))
    return W, f, r, c, tau_k, np.full(n, 150.0)


@pytest.mark.parametrize("slack_long", [0.0, 5e-3])
@pytest.mark.parametrize("coupled", [False, True])
def test_the_winning_faces_given_back_give_the_same_answer(monkeypatch, slack_long, coupled):
    W, f, r, c, tau_k, tm = _problem(3, slack_long=slack_long, coupled=coupled)
    full = fit_internal_forces(W, f, r, c, tau_k, tm)
    face, dropped = full.hint()
    # the problems exercise every kind of winner: interior, kept faces (one cable at zero,
    # and as many as the null space has) and slack ones
    kept = face & ~dropped
    assert (~face.any(axis=1)).any() and dropped.any()
    assert (kept.sum(axis=1) == 1).any() and (kept.sum(axis=1) == 2).any()
    searches = []
    search = internal_forces._faces_min
    monkeypatch.setattr(internal_forces, "_faces_min",
                        lambda *a: searches.append(len(a[0])) or search(*a))
    hinted = fit_internal_forces(W, f, r, c, tau_k, tm, hint=full.hint())
    assert not searches  # each sample solved on its face alone
    np.testing.assert_allclose(hinted.tensions, full.tensions, rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(hinted.cost, full.cost, rtol=1e-7, atol=1e-15)
    np.testing.assert_array_equal(hinted.feasible, full.feasible)
    np.testing.assert_array_equal(hinted.face, face)
    np.testing.assert_array_equal(hinted.dropped, dropped)


def test_a_hinted_face_is_kept_while_feasible_and_searched_once_it_is_not():
    W, f, r, c, tau_k, tm = _problem(5)
    full = fit_internal_forces(W, f, r, c, tau_k, tm)
    M, n = r.shape

    def on_its_face(got, keep):
        # the minimiser on the hinted face: pulling, balanced, never cheaper than the search
        assert np.all(got.tensions[keep] >= 0.0) and got.feasible[keep].all()
        np.testing.assert_allclose(np.einsum("mik,mk->mi", W[keep], got.tensions[keep]),
                                   f[keep], atol=1e-6)
        assert np.all(got.cost[keep] >= full.cost[keep] * (1 - 1e-9) - 1e-15)

    # hint: every sample interior (no cable at zero). Where the interior pushes a cable it
    # is infeasible: the search gives the full answer; elsewhere the interior stays, even
    # where the search prefers a slack cable
    none = np.zeros((M, n), dtype=bool)
    got = fit_internal_forces(W, f, r, c, tau_k, tm, hint=(none, none))
    searched = got.face.any(axis=1)
    stayed = ~searched & full.face.any(axis=1)
    assert searched.any() and stayed.any()
    np.testing.assert_allclose(got.tensions[searched], full.tensions[searched], rtol=1e-7,
                               atol=1e-6)
    on_its_face(got, ~searched)
    assert np.all(got.cost[stayed] > full.cost[stayed])
    # hint: cable 0 slack everywhere; where that face balances with pulling cables it is
    # what comes back, elsewhere the search's answer
    face = np.zeros((M, n), dtype=bool)
    face[:, 0] = True
    got = fit_internal_forces(W, f, r, c, tau_k, tm, hint=(face, face.copy()))
    kept = np.all(got.face == face, axis=1) & np.all(got.dropped == face, axis=1)
    assert kept.any() and (~kept).any()
    assert np.all(got.tensions[kept, 0] == 0.0)
    on_its_face(got, kept)
    np.testing.assert_allclose(got.tensions[~kept], full.tensions[~kept], rtol=1e-7,
                               atol=1e-6)


@pytest.fixture(scope="module")
def no_tensions(tmp_path_factory):
    """A recording without load cells on ROCASPECT (settled exit points): its residual
    model, noise estimated."""
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 4,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"exit_point_offset": {"dx_21": 0.03, "dy_32": -0.025}},
        "nuisance": {"hysteresis_m": 5e-5, "drift_m_per_h": 2e-5},
        "poses": copy.deepcopy({"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2}),
        "recording": {"load_cells": False}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("rec") / "rec"))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    assert not rm.has_tau.any()
    return rm


@pytest.mark.parametrize("effects", [("exit_point_offset",), ("drum_scale", "mast_compliance")])
def test_the_frozen_jacobian_equals_the_full_one(no_tensions, effects):
    rm = no_tensions
    space = ParamSpace(rm.model, effects)
    rng = np.random.default_rng(1)
    # around a hypothesis off the model's values (cables at zero tension in places)
    x = np.clip(space.neutral + rng.normal(size=len(space)) * 3.0 * space.scale,
                space.lo, space.hi)

    def fun(phi):
        return rm.whitened(space.robot(phi))

    steps = space.scale * 1e-2
    f0 = fun(x)
    full = fd_jacobian(fun, x, f0, steps, space.lo, space.hi)
    f0 = fun(x)
    frozen = fd_jacobian(fun, x, f0, steps, space.lo, space.hi, rm.frozen)
    assert np.abs(full).max() > 0
    # with compliant masts, one relinearisation leaves the wrench matrix's move with the
    # tensions out: a few entries off by a few per cent
    off = ~np.isclose(frozen, full, rtol=5e-3, atol=1e-4 * np.abs(full).max())
    assert off.mean() < (1e-3 if "mast_compliance" in effects else 1e-9)
    np.testing.assert_allclose(frozen, full, rtol=5e-2, atol=1e-4 * np.abs(full).max())
    # the evaluations after start where they did before the columns
    np.testing.assert_allclose(fun(x), f0, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("effects", [("exit_point_offset",), ("drum_scale", "mast_compliance")])
def test_rounds_on_the_last_faces_end_where_searches_every_round_end(no_tensions, effects,
                                                                   monkeypatch):
    """Outside frozen(), the unmeasured tensions relinearise on the last evaluation's faces
    and search once they settle, each sample until its own search leaves it settled: the
    same residuals as a search of every sample in every round, from the same warm
    start."""
    import bench.diagnosis.residuals as residuals

    rm = no_tensions
    space = ParamSpace(rm.model, effects)
    rng = np.random.default_rng(2)
    x0, x1 = (np.clip(space.neutral + rng.normal(size=len(space)) * k * space.scale,
                      space.lo, space.hi) for k in (1.0, 3.0))
    rm.whitened(space.robot(x0))  # the warm start: its tensions and faces
    warm = (rm._warm_tau.copy(), rm._warm_face.copy(), rm._warm_drop.copy())
    fit = residuals.fit_internal_forces
    hinted, sizes = [], []
    with monkeypatch.context() as mp:
        mp.setattr(residuals, "fit_internal_forces",
                   lambda *a, hint=None, **k: hinted.append(hint is not None)
                   or sizes.append(len(a[0])) or fit(*a, hint=hint, **k))
        held = rm.whitened(space.robot(x1))
    assert any(hinted) and not hinted[-1]  # rounds on held faces, a search last
    # the first round takes every sample; the later ones only those not yet settled
    M = int((rm.has_pose & ~rm.has_tau).sum())
    assert sizes[0] == M and min(sizes) < M
    rm._warm_tau[:], rm._warm_face[:], rm._warm_drop[:] = warm
    with monkeypatch.context() as mp:
        mp.setattr(residuals, "fit_internal_forces",
                   lambda *a, hint=None, **k: fit(*a, **k))  # every round searches
        full = rm.whitened(space.robot(x1))
    assert np.abs(full).max() > 1.0
    np.testing.assert_allclose(held, full, rtol=1e-7, atol=1e-5)


@pytest.fixture(scope="module")
def no_tracker(tmp_path_factory):
    """A recording without tracker poses on ROCASPECT with compliant masts: the poses are
    estimated from the encoders and load cells (ResidualModel._estimate_poses)."""
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"cable_length_offset": {"dl_21": 0.004},
                  "mast_compliance": {"k": [2.0e5, 5.0e5, 3.0e5]}},
        "nuisance": {"hysteresis_m": 5e-5},
        "poses": copy.deepcopy({"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2}),
        "recording": {"tracker": False}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("rec") / "rec"))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    assert rm.est_pose.any()
    return rm


@pytest.mark.parametrize("effects", [("cable_length_offset",),
                                     ("drum_scale", "mast_compliance")])
def test_the_frozen_jacobian_of_estimated_poses_equals_the_full_one(no_tracker, effects):
    """Inside frozen the poses take one Gauss-Newton step from where the evaluation before
    took its last: the columns are those of poses estimated to convergence each time."""
    rm = no_tracker
    space = ParamSpace(rm.model, effects)
    rng = np.random.default_rng(2)
    x = np.clip(space.neutral + rng.normal(size=len(space)) * space.scale,
                space.lo, space.hi)

    def fun(phi):
        return rm.whitened(space.robot(phi))

    steps = space.scale * 1e-2
    fun(x)
    f0 = fun(x)  # from its own estimates: converged within a step or two
    full = fd_jacobian(fun, x, f0, steps, space.lo, space.hi)
    f0 = fun(x)
    frozen = fd_jacobian(fun, x, f0, steps, space.lo, space.hi, rm.frozen)
    assert np.abs(full).max() > 0
    np.testing.assert_allclose(frozen, full, rtol=5e-3, atol=1e-4 * np.abs(full).max())
    np.testing.assert_allclose(fun(x), f0, rtol=1e-6, atol=1e-6)
