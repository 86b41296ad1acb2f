"""Tensions of samples without load cells (bench/diagnosis/internal_forces.py): exact over
which cables are slack, continuous in the data, and honest when nothing balances."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.internal_forces import fit_internal_forces


def _problem(seed: int, n: int = 8, M: int = 40, slack_long: float = 0.0):
    rng = np.random.default_rng(seed)
    W = rng.normal(size=(M, 6, n))
    true = rng.uniform(20.0, 300.0, size=(M, n))
    f = np.einsum("mik,mk->mi", W, true)
    tau_p = true  # a balance (for the tests' own checks)
    tau_k = np.full((M, n), 150.0)
    c = -rng.uniform(1e-6, 1e-5, size=(M, n))
    # readings off by noise, and some cables read longer (slack candidates)
    r = rng.normal(0.0, 2e-3, size=(M, n)) - slack_long * rng.uniform(0.0, 1.0, size=(M, n))
    return W, f, tau_p, r, c, tau_k, np.full(n, 150.0)


def _objective(tau, r, c, tau_k, tm, eps):
    """The module's objective for one sample, by the definition (one-sided at zero)."""
    e = np.where(tau > 1e-9, r + c * (tau - tau_k), np.maximum(r - c * tau_k, 0.0))
    return float(np.sum(e * e) + eps * np.sum((tau - tm) ** 2))


@pytest.mark.parametrize("slack_long", [0.0, 5e-3])
def test_the_minimum_is_the_least_cost_over_a_dense_search_of_the_null_space(slack_long):
    W, f, tau_p, r, c, tau_k, tm = _problem(3, slack_long=slack_long)
    got = fit_internal_forces(W, f, r, c, tau_k, tm)
    assert got.feasible.all()
    assert np.all(got.tensions >= 0.0)
    np.testing.assert_allclose(np.einsum("mik,mk->mi", W, got.tensions), f, atol=1e-6)
    rng = np.random.default_rng(7)
    for i in range(W.shape[0]):
        eps = 1e-9 * np.max(c[i] ** 2)
        best = _objective(got.tensions[i], r[i], c[i], tau_k[i], tm, eps)
        assert best == pytest.approx(got.cost[i], rel=1e-6, abs=1e-12)
        _, _, Vt = np.linalg.svd(W[i])
        N = Vt[6:].T
        # random balanced tensions around the answer, and with cables pushed to zero
        lam = rng.normal(size=(4000, 2)) * rng.choice([1.0, 10.0, 100.0], size=(4000, 1))
        cand = got.tensions[i] + lam @ N.T
        for t in cand[np.all(cand >= 0.0, axis=1)]:
            assert _objective(t, r[i], c[i], tau_k[i], tm, eps) >= best - 1e-12


def test_a_cable_reading_long_goes_slack_at_no_cost_and_a_short_one_never_does():
    W, f, tau_p, r, c, tau_k, tm = _problem(5, M=20)
    # cable 2 reads 5 cm longer than the straight line: slack explains it if a balance
    # without it exists (8 cables, 6 equations: it does for these random problems)
    r[:, 2] = -0.05 + c[:, 2] * tau_k[:, 2]
    got = fit_internal_forces(W, f, r, c, tau_k, tm)
    slack_ok = got.feasible & got.at_zero[:, 2]
    assert slack_ok.sum() >= 10
    # a cable reading shorter than the straight line cannot be slack
    r[:, 2] = 0.05 + c[:, 2] * tau_k[:, 2]
    got2 = fit_internal_forces(W, f, r, c, tau_k, tm)
    assert not np.any(got2.at_zero[:, 2] & (got2.cost < 0.05 ** 2))


def test_the_cost_moves_continuously_with_the_readings():
    W, f, tau_p, r, c, tau_k, tm = _problem(11, M=1, slack_long=5e-3)
    costs = []
    for d in np.linspace(-0.01, 0.01, 401):  # cable 0 from long (slack) to short (taut)
        rr = r.copy()
        rr[:, 0] += d
        costs.append(fit_internal_forces(W, f, rr, c, tau_k, tm).cost[0])
    jumps = np.abs(np.diff(costs))
    assert jumps.max() < 2e-5  # 0.05 mm steps: no jump of a slack decision


def test_rigid_cables_take_the_balance_nearest_mid_range():
    W, f, tau_p, r, c, tau_k, tm = _problem(2, M=10)
    c[:] = 0.0
    r = np.abs(r)
    got = fit_internal_forces(W, f, r, c, tau_k, tm)
    assert got.feasible.all()
    for i in range(10):  # nearest non-negative balance to tm: check against the projection
        _, _, Vt = np.linalg.svd(W[i])
        N = Vt[6:].T
        free = tau_p[i] + N @ (N.T @ (tm - tau_p[i]))
        if np.all(free >= 0):
            np.testing.assert_allclose(got.tensions[i], free, rtol=1e-6, atol=1e-6)


def test_no_balance_with_pulling_cables_is_said_not_hidden():
    W, f, tau_p, r, c, tau_k, tm = _problem(4, M=6)
    W = np.abs(W)  # every cable pushes the wrench the same way...
    f = -np.abs(f) - 10.0  # ...and the wrench asks the opposite
    got = fit_internal_forces(W, f, r, c, tau_k, tm)
    assert not got.feasible.any()
    assert np.all(got.tensions >= 0.0) and np.all(np.isfinite(got.cost))


def test_length_sensitivity_with_compliant_masts_matches_finite_differences():
    from bench.diagnosis.residuals import _length_sensitivity
    from controller.effects import apply_effects
    from controller.robot import resolve_robot
    from controller.statics import batch_statics

    model = resolve_robot("rocaspect")
    ks = {f"k{a}_{m}": k for m in model.mast_ids for a, k in zip("xyz", (2e5, 5e5, 3e5),
                                                               strict=True)}
    H = apply_effects(model, {"mast_compliance": ks})
    assert H.compliant
    poses = np.array([[10.0, 8.56, 1.2, 0, 0, 0], [6.0, 12.0, 2.0, 0.02, -0.01, 0.03]])
    tau = np.tile(np.linspace(300.0, 900.0, H.n_cables), (2, 1))
    C = _length_sensitivity(H, batch_statics(H, poses, tau), tau)
    assert np.abs(C - np.eye(H.n_cables) * np.diagonal(C, axis1=1, axis2=2)[:, :, None]
                  ).max() > 0  # the masts couple cables
    h = 1.0
    for j in range(H.n_cables):
        up, dn = tau.copy(), tau.copy()
        up[:, j] += h
        dn[:, j] -= h
        fd = (batch_statics(H, poses, up, tol=1e-14).unstretched
              - batch_statics(H, poses, dn, tol=1e-14).unstretched) / (2 * h)
        np.testing.assert_allclose(C[:, :, j], fd, rtol=0.05, atol=1e-3 * np.abs(fd).max())


def _degenerate_problem(seed: int, M: int = 60, near: float = 0.0):
    """Balance problems (eight cables) whose null space makes faces degenerate: cables 0 and
    1 have parallel null-space rows (a face holding both at zero cannot be reached but by
    tensions the balance fixes), cable 2 a zero row (its tension is the same in every
    balance: a face holding it alone is reached only where that is zero). ``near`` tilts
    the parallel rows and lifts the zero row by that much (near-degenerate faces)."""
    rng = np.random.default_rng(seed)
    n = 8
    W = np.empty((M, 6, n))
    for i in range(M):
        N0 = rng.normal(size=(n, 2))
        N0[1] = rng.uniform(0.5, 2.0) * N0[0] + near * rng.normal(size=2)
        N0[2] = near * rng.normal(size=2)
        comp = np.linalg.svd(N0.T)[2][2:]  # (6, n): the complement of N0's span
        R = np.linalg.qr(rng.normal(size=(6, 6)))[0] * rng.uniform(0.5, 2.0, size=6)
        W[i] = R @ comp  # well conditioned: only the faces are degenerate
    true = rng.uniform(20.0, 300.0, size=(M, n))
    f = np.einsum("mik,mk->mi", W, true)
    tau_k = np.full((M, n), 150.0)
    c = -rng.uniform(1e-6, 1e-5, size=(M, n))
    r = rng.normal(0.0, 2e-3, size=(M, n)) - 5e-3 * rng.uniform(0.0, 1.0, size=(M, n))
    return W, f, r, c, tau_k, np.full(n, 150.0)


def _both_ways(monkeypatch, W, f, r, c, tau_k, tm):
    """fit_internal_forces with the eight-cable closed form, and with the general solve."""
    from bench.diagnosis import internal_forces

    closed = fit_internal_forces(W, f, r, c, tau_k, tm)
    search = internal_forces._faces_min
    with monkeypatch.context() as mp:
        mp.setattr(internal_forces, "_faces_min",
                   lambda *a: search(*a, closed_form=False))
        general = fit_internal_forces(W, f, r, c, tau_k, tm)
    return closed, general


def _assert_same(closed, general, problem):
    scale = np.abs(general.tensions).max()
    np.testing.assert_allclose(closed.tensions, general.tensions, rtol=1e-8,
                               atol=1e-9 * scale)
    np.testing.assert_allclose(closed.cost, general.cost, rtol=1e-7, atol=1e-15)
    np.testing.assert_array_equal(closed.feasible, general.feasible)
    np.testing.assert_array_equal(closed.face, general.face)
    # the rows left out may differ only where the face's minimiser is the same with its rows
    # kept or not (a face holding two cables: the constraints fix it; one cable whose
    # length does not hang on the others' tensions: its residual is the same all along the
    # face): two equal candidates, which one comes first is round-off
    differ = (closed.dropped != general.dropped).any(axis=1)
    if differ.any():
        W, f, r, c, tau_k, tm = problem
        swapped = fit_internal_forces(W, f, r, c, tau_k, tm, hint=general.hint())
        np.testing.assert_allclose(swapped.tensions, closed.tensions, rtol=1e-8,
                                   atol=1e-9 * scale)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("slack_long", [0.0, 5e-3])
def test_the_closed_form_of_eight_cables_equals_the_general_solve(monkeypatch, seed,
                                                                  slack_long):
    W, f, tau_p, r, c, tau_k, tm = _problem(seed, M=80, slack_long=slack_long)
    coupled = c[:, :, None] * np.eye(8) + np.random.default_rng(seed).normal(
        0.0, 1e-6, size=(80, 8, 8))  # compliant masts: lengths hang on others' tensions
    held = []
    for C in (c, coupled, np.zeros_like(c)):  # stretch, coupled stretch, rigid cables
        closed, general = _both_ways(monkeypatch, W, f, r, C, tau_k, tm)
        _assert_same(closed, general, (W, f, r, C, tau_k, tm))
        held += list(closed.face.sum(axis=1))
    assert {0, 1, 2} <= set(held)  # interior winners, and faces of one and two cables


@pytest.mark.parametrize("near", [0.0, 1e-7, 1e-4, 0.1])
def test_the_closed_form_on_degenerate_faces_equals_the_general_solve(monkeypatch, near):
    from bench.diagnosis import internal_forces

    W, f, r, c, tau_k, tm = _degenerate_problem(1, near=near)
    general_pairs = []
    lams = internal_forces._face_lams
    with monkeypatch.context() as mp:
        mp.setattr(internal_forces, "_face_lams",
                   lambda *a: general_pairs.append(len(a[6])) or lams(*a))
        fit_internal_forces(W, f, r, c, tau_k, tm)
    closed, general = _both_ways(monkeypatch, W, f, r, c, tau_k, tm)
    _assert_same(closed, general, (W, f, r, c, tau_k, tm))
    assert closed.feasible.any()
    if near <= 1e-7:  # the degenerate faces went to the general solve
        assert sum(general_pairs) > 0
    if near >= 0.1:  # nothing degenerate left: all in closed form
        assert sum(general_pairs) == 0
