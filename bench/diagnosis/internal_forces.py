"""Cable tensions of samples recorded without load cells, fitted to the cables' stretch.

At a pose the tensions must balance gravity (``W tau = f``, 6 equations) and pull
(``tau >= 0``); the ``n - 6`` internal forces left free are what the readings of the
winches can tell: a taut cable's unstretched length hangs on the tensions (its own
stretch, and through a compliant mast the tensions of its neighbours), a slack one (no
tension) only says it is at least as long as the straight line. Per sample the estimate
minimises

    sum_i e_i^2 + eps * sum_i (tau_i - tm_i)^2,    e = b + C tau,  b = r - C tau_k

with ``r`` the length residuals [m] at the linearisation tensions ``tau_k`` and ``C`` the
sensitivity ``dL0_i/dtau_j`` [m/N] (diagonal without compliant masts); a cable at zero
tension counts the one-sided ``max(e_i, 0)`` (a reading longer than the line costs
nothing). ``eps`` is a small pull toward ``tm`` (mid-range, as a controller plans) that
only decides what the stretch leaves open (rigid cables).

The one-sided term makes the problem non-convex, yet its minimum is found and moves
continuously with the data. The balanced minimiser without the bounds comes from one KKT
solve; where it pulls on every cable and no cable would read longer than its line at zero
tension, it is the answer (the problem is convex there). Elsewhere every face of the
polytope ``tau >= 0`` with ``j <= n - 6`` cables at zero is tried twice, the face's cables
kept in the least squares (the convex problem's faces) and left out of it (slack), and the
feasible candidate of least objective wins. Vectorised over samples and faces (no Python
loop over samples); the faces tried are capped at :data:`MAX_FACES` (about the ``n = 10``
robots' count) by the number of cables at zero. With eight cables (a two-dimensional null
space) each face's minimiser is solved in closed form (:func:`_faces_min_k2`), degenerate
faces by the general KKT solve.

The winning candidate's face (the cables held at zero, and whether they were left out of
the least squares) is returned; given back as a ``hint``, each sample is solved on that
face alone (one KKT solve, no search) and searched only where the hinted candidate no
longer pulls or balances: the minimiser on the same piece of the objective, which is what
a finite-difference derivative around the hinted solution needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations
from math import comb

import numpy as np

#: faces tried per sample at most (cables at zero: as many as fit under the cap)
MAX_FACES = 400
#: samples per block (bounds the (samples, faces, n + 6, n + 6) arrays)
BLOCK = 256


@dataclass
class InternalForces:
    """Result of :func:`fit_internal_forces` for M samples: ``tensions`` (M,n) [N] >= 0,
    balancing the wrench; ``at_zero`` (M,n) cables at zero tension; ``cost`` (M,) the
    minimised objective [m^2]; ``feasible`` (M,) a balance with non-negative tensions was
    found (else the candidate that violates the bound least, its tensions clipped at
    zero)."""

    tensions: np.ndarray
    at_zero: np.ndarray
    cost: np.ndarray
    feasible: np.ndarray
    face: np.ndarray | None = None  # (M,n) cables the winning candidate holds at zero
    dropped: np.ndarray | None = None  # (M,n) of those, the ones left out (read as slack)

    def hint(self) -> tuple[np.ndarray, np.ndarray]:
        """The winning faces, as :func:`fit_internal_forces` takes them back."""
        return self.face, self.dropped


@lru_cache(maxsize=16)
def _faces(n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The faces with 1..jmax cables at zero (under :data:`MAX_FACES`): masks (F, n) and
    the cables' indices (F, k), padded with -1."""
    masks, idx, total = [], [], 1
    for j in range(1, k + 1):
        c = comb(n, j)
        if total + c > MAX_FACES:
            break
        for S in combinations(range(n), j):
            m = np.zeros(n, dtype=bool)
            m[list(S)] = True
            masks.append(m)
            idx.append(list(S) + [-1] * (k - j))
        total += c
    return (np.array(masks, dtype=bool).reshape(-1, n),
            np.array(idx, dtype=np.intp).reshape(-1, k))


def fit_internal_forces(W: np.ndarray, f: np.ndarray, r: np.ndarray, C: np.ndarray,
                        tau_k: np.ndarray, tm: np.ndarray,
                        eps_rel: float = 1e-9,
                        hint: tuple[np.ndarray, np.ndarray] | None = None) -> InternalForces:
    """The tensions of the module's objective for M samples.

    ``W`` (M,6,n) wrench matrices, ``f`` (M,6) the wrench to balance, ``r`` (M,n) length
    residuals [m] at ``tau_k`` (M,n) [N], ``C`` their sensitivity to the tensions [m/N]:
    (M,n,n), or (M,n) for its diagonal; ``tm`` (n,) or (M,n) the tensions the ``eps``
    term pulls toward [N]. ``hint`` (face, dropped), both (M,n) bool, from an earlier
    result's :meth:`InternalForces.hint`: each sample solved on that face (module
    docstring), searched only where its candidate there is not feasible."""
    M, m, n = W.shape
    C = np.asarray(C, float)
    if C.ndim == 2:
        C = C[:, :, None] * np.eye(n)
    tm = np.broadcast_to(np.asarray(tm, float), (M, n))
    out_t = np.zeros((M, n))
    out_cost = np.full(M, np.inf)
    out_ok = np.zeros(M, dtype=bool)
    out_face = np.zeros((M, n), dtype=bool)
    out_drop = np.zeros((M, n), dtype=bool)
    for a in range(0, M, BLOCK):
        sl = slice(a, min(a + BLOCK, M))
        hs = None if hint is None else (hint[0][sl], hint[1][sl])
        out = _block(W[sl], f[sl], r[sl], C[sl], tau_k[sl], tm[sl], eps_rel, hs)
        out_t[sl], out_cost[sl], out_ok[sl], out_face[sl], out_drop[sl] = out
    scale = np.maximum(np.abs(out_t).max(axis=1, keepdims=True), 1.0)
    return InternalForces(out_t, out_t <= 1e-9 * scale, out_cost, out_ok, out_face, out_drop)


def _cost(t, b, C, eps, tm, zero):
    """The objective at tensions ``t`` (..., n), one-sided for the cables ``zero``
    (``eps`` shaped as the result)."""
    e = b + np.einsum("...ij,...j->...i", C, t)
    e = np.where(zero, np.maximum(e, 0.0), e)
    return np.sum(e * e, axis=-1) + eps * np.sum((t - tm) ** 2, axis=-1)


def _kkt(H, g, W, f, fixed):
    """Minimisers of ``t^T H t - 2 g^T t`` with ``W t = f`` and ``t_i = 0`` where ``fixed``
    (..., n), batched (scaled so that the system is well conditioned)."""
    n = H.shape[-1]
    m = W.shape[-2]
    h0 = np.trace(H, axis1=-2, axis2=-1)[..., None, None] / n + 1e-300
    free = ~fixed
    Hs = np.where(free[..., :, None] & free[..., None, :], H / h0, 0.0)
    Hs = Hs + np.where(fixed, 1.0, 0.0)[..., None] * np.eye(n)
    gs = np.where(free, g / h0[..., 0], 0.0)
    Ws = np.where(free[..., None, :], W, 0.0)
    K = np.zeros(Hs.shape[:-2] + (n + m, n + m))
    K[..., :n, :n] = Hs
    K[..., :n, n:] = np.swapaxes(Ws, -1, -2)
    K[..., n:, :n] = Ws
    # a tiny dual regularisation keeps faces whose free cables cannot balance the wrench
    # solvable (they come out infeasible or with a balance residual, never NaN)
    K[..., n:, n:] = -1e-12 * np.eye(m)
    rhs = np.concatenate([gs, np.broadcast_to(f, gs.shape[:-1] + (m,))], axis=-1)
    return np.linalg.solve(K, rhs[..., None])[..., :n, 0]


def _solve_face(W, f, C, b, eps, tm, face, dropped):
    """The balanced minimisers (M,n) with the cables ``face`` (M,n) held at zero and the rows
    ``dropped`` (M,n) left out of the least squares (one KKT solve per sample), and whether
    each balances the wrench."""
    n = W.shape[-1]
    Cr = np.where(dropped[..., None], 0.0, C)
    H = np.swapaxes(Cr, -1, -2) @ Cr + eps[:, None, None] * np.eye(n)
    g = -np.einsum("mji,mj->mi", Cr, b) + eps[:, None] * tm
    t = _kkt(H, g, W, f, face)
    return t, _balanced(W, t, f)


def _balanced(W, t, f):
    """Whether tensions ``t`` (...,n) balance the wrench ``f`` (...,6) to round-off."""
    return np.linalg.norm(np.einsum("...ik,...k->...i", W, t) - f, axis=-1) <= \
        1e-6 * (np.abs(f).sum(axis=-1) + 1.0)


def _block(W, f, r, C, tau_k, tm, eps_rel, hint=None):
    M, m, n = W.shape
    CtC = np.swapaxes(C, -1, -2) @ C
    top = np.max(np.diagonal(CtC, axis1=-2, axis2=-1), axis=-1)
    eps = np.where(top > 0, eps_rel * top, 1.0)  # rigid cables: only the pull to tm
    b = r - np.einsum("mij,mj->mi", C, tau_k)  # residuals at zero tensions
    none = np.zeros((M, n), dtype=bool)
    if hint is not None:
        face, dropped = hint
        th, bal = _solve_face(W, f, C, b, eps, tm, face, dropped)
        tol = 1e-9 * np.maximum(np.abs(th).max(axis=1), np.abs(tm).max(axis=1))
        good = np.all(th >= -tol[:, None], axis=1) & bal
        t = np.maximum(th, 0.0)
        cost = _cost(t, b, C, eps, tm, face)
        face, dropped = face.copy(), dropped.copy()
        if not good.all():  # the hinted face no longer pulls or balances: search
            h = np.flatnonzero(~good)
            out = _block(W[h], f[h], r[h], C[h], tau_k[h], tm[h], eps_rel)
            t[h], cost[h], good[h], face[h], dropped[h] = out
        return t, cost, good, face, dropped
    tau0, balanced = _solve_face(W, f, C, b, eps, tm, none, none)
    scale = np.maximum(np.abs(tau0).max(axis=1), np.abs(tm).max(axis=1))
    tol = 1e-9 * scale
    t = np.maximum(tau0, 0.0)
    cost = _cost(t, b, C, eps, tm, none)
    ok = np.all(tau0 >= -tol[:, None], axis=1) & balanced
    face, dropped = none.copy(), none.copy()
    # a cable that would read longer than its line with its own tension at zero may be
    # slack: those samples, and those pushing a cable, try the faces
    e_own0 = b + np.einsum("mij,mj->mi", C, tau0) - np.diagonal(C, axis1=-2, axis2=-1) * tau0
    hard = ~ok | np.any(e_own0 < 0.0, axis=1)
    if n > m and hard.any():
        h = np.flatnonzero(hard)
        viol0 = np.maximum(-tau0[h], 0.0).max(axis=1)
        out = _faces_min(W[h], f[h], C[h], b[h], eps[h], tm[h], tol[h], t[h], cost[h], ok[h],
                         viol0, e_own0[h] < 0.0)
        t[h], cost[h], ok[h], face[h], dropped[h] = out
    return t, cost, ok, face, dropped


def _null_space(W, f):
    """The null space (M,n,k) of each sample's W (M,m,n) and a particular balance (M,n) of
    ``W tau = f``."""
    m = W.shape[1]
    U, sv, Vt = np.linalg.svd(W)
    N = np.swapaxes(Vt[:, m:, :], -1, -2)  # (M, n, k)
    sv = np.where(sv > 1e-12 * sv[:, :1], sv, np.inf)
    tp = np.einsum("mjn,mj->mn", Vt[:, :m, :], np.einsum("mij,mi->mj", U, f) / sv)
    return N, tp


def _face_lams(N, tp, CN, ep, eps, d, pm, pf, slack, faces, fidx):
    """The null-space coordinates (P,k) of each pair's minimiser: sample ``pm``, face
    ``pf`` (``faces[pf]``, its cables' indices ``fidx[pf]`` padded with -1) held at zero,
    its rows left out of the least squares where ``slack``. Each is a ``k + j`` KKT
    system, solved as one batched ``2k`` system (general ``k``; a tiny regularisation keeps
    degenerate faces solvable)."""
    k = N.shape[-1]
    idx = fidx[pf]  # (P, k) padded with -1
    real = idx >= 0
    z = faces[pf]
    # the least squares over the kept rows, the face's cables held at zero
    rho = ~(z & slack[:, None])  # rows kept
    CNp = CN[pm] * rho[:, :, None]
    Np, epair = eps[pm], ep[pm]
    Q = np.swapaxes(CNp, -1, -2) @ CNp + Np[:, None, None] * np.eye(k)
    q = np.einsum("pnk,pn->pk", CNp, epair * rho) - Np[:, None] * d[pm]
    h0 = (np.trace(Q, axis1=-2, axis2=-1) / k)[:, None, None] + 1e-300
    A = np.where(real[:, :, None], N[pm[:, None], np.maximum(idx, 0)], 0.0)  # (P, k, k)
    K = np.zeros((len(pm), 2 * k, 2 * k))
    K[:, :k, :k] = Q / h0
    K[:, :k, k:] = np.swapaxes(A, -1, -2)
    K[:, k:, :k] = A
    # padded constraint rows pin their multiplier to zero; a tiny regularisation keeps a
    # face whose cables the null space cannot all release solvable (it comes out infeasible)
    K[:, k:, k:] = np.where(real, -1e-12, 1.0)[:, :, None] * np.eye(k)
    rhs = np.concatenate([-q / h0[:, :, 0],
                          np.where(real, -tp[pm[:, None], np.maximum(idx, 0)], 0.0)], axis=1)
    return np.linalg.solve(K, rhs[..., None])[:, :k, 0]


def _faces_min(W, f, C, b, eps, tm, tol, t0, cost0, ok0, viol0, maybe_slack,
               closed_form: bool = True):
    """The least-objective feasible candidate over the faces (module docstring), the
    interior one (``t0``, ``cost0``, ``ok0``, its bound violation ``viol0``) included.
    Only the faces that can win are solved: the convex problem's faces where the interior
    minimiser pushes a cable, the slack ones whose cables all may be slack
    (``maybe_slack`` (M,n): they would read longer than their line). Each face is a
    ``k + j`` system in the null space of W (``tau = tau_p + N lam``, ``k = n - 6``);
    with ``k = 2`` (eight cables) in closed form (:func:`_faces_min_k2`) unless
    ``closed_form`` is False."""
    M, m, n = W.shape
    k = n - m
    faces, fidx = _faces(n, k)
    F = len(faces)
    none = np.zeros((M, n), dtype=bool)
    if F == 0:
        return t0, cost0, ok0, none, none
    if k == 2 and closed_form:
        return _faces_min_k2(W, f, C, b, eps, tm, tol, t0, cost0, ok0, viol0, maybe_slack)
    # (sample, face) pairs of each kind
    kept_m, kept_f = np.nonzero(np.broadcast_to(~ok0[:, None], (M, F)))
    inside = ~np.any(faces[None, :, :] & ~maybe_slack[:, None, :], axis=-1)  # S within P
    drop_m, drop_f = np.nonzero(inside)
    pm = np.concatenate([kept_m, drop_m])
    pf = np.concatenate([kept_f, drop_f])
    slack = np.concatenate([np.zeros(len(kept_m), bool), np.ones(len(drop_m), bool)])
    z = faces[pf]  # (P, n) cables at zero
    # the null space and a particular balance of each sample's W
    N, tp = _null_space(W, f)
    ep = b + np.einsum("mij,mj->mi", C, tp)  # residuals at the particular balance
    CN = C @ N  # (M, n, k)
    d = np.einsum("mnk,mn->mk", N, tm - tp)
    lam = _face_lams(N, tp, CN, ep, eps, d, pm, pf, slack, faces, fidx)
    taus = np.where(z, 0.0, tp[pm] + np.einsum("pnk,pk->pn", N[pm], lam))  # (P, n)
    bal = _balanced(W[pm], taus, f[pm])
    viol = np.maximum(-taus, 0.0).max(axis=-1)
    feasible = (viol <= tol[pm]) & bal
    tc = np.maximum(taus, 0.0)
    cost = _cost(tc, b[pm], C[pm], eps[pm], tm[pm], z)
    # candidates: the interior ones, then the pairs; the least cost of each sample (the
    # least violation where none is feasible)
    rows = np.arange(M)
    sample = np.concatenate([rows, pm])
    c_all = np.concatenate([cost0, cost])
    t_all = np.concatenate([t0, tc], axis=0)
    pick_cost = np.where(np.concatenate([ok0, feasible]), c_all, np.inf)
    v_all = np.concatenate([viol0, np.where(bal, viol, np.inf)])
    first = _first_per_sample(sample, pick_cost, M)
    ok = np.isfinite(pick_cost[first])
    least_viol = _first_per_sample(sample, v_all, M)
    pick = np.where(ok, first, least_viol)
    z_all = np.concatenate([none, z])
    d_all = np.concatenate([none, z & slack[:, None]])
    return t_all[pick], c_all[pick], ok, z_all[pick], d_all[pick]


def _first_per_sample(sample: np.ndarray, key: np.ndarray, M: int) -> np.ndarray:
    """Index of the candidate of least ``key`` for each sample 0..M-1 (each has one)."""
    order = np.lexsort((key, sample))
    starts = np.searchsorted(sample[order], np.arange(M))
    return order[starts]


#: below this, a face's constraints are degenerate for the closed form (|det| of the two
#: cables' null-space rows against their norms; a single cable's squared row norm): the
#: general regularised solve decides those (they come out infeasible or near a kink)
DEGENERATE = 1e-6


def _faces_min_k2(W, f, C, b, eps, tm, tol, t0, cost0, ok0, viol0, maybe_slack):
    """:func:`_faces_min` for a two-dimensional null space (``n = m + 2``), dense over
    (sample, face) and in closed form, the same candidates in the same order.

    A face with both null-space coordinates fixed by its two cables at zero has
    ``lam = A^-1 c`` (``A`` their rows of N, ``c = -tau_p`` there), the same whether their
    rows are kept or left out (the one candidate stands for both); a face with one cable
    (row ``a``) minimises the quadratic along the line ``a . lam = c``:
    ``lam = c a / |a|^2 + s v`` with ``v`` normal to ``a``. Degenerate constraints
    (:data:`DEGENERATE`) are solved by :func:`_face_lams` instead."""
    M, m, n = W.shape
    faces, fidx = _faces(n, 2)
    F = len(faces)
    single = fidx[:, 1] < 0  # (F,) faces with one cable at zero
    sing, pairs = np.flatnonzero(single), np.flatnonzero(~single)
    i1, i2 = fidx[:, 0], np.maximum(fidx[:, 1], 0)
    N, tp = _null_space(W, f)
    ep = b + np.einsum("mij,mj->mi", C, tp)  # residuals at the particular balance
    CN = C @ N  # (M, n, 2)
    d = np.einsum("mnk,mn->mk", N, tm - tp)
    inside = ~np.any(faces[None, :, :] & ~maybe_slack[:, None, :], axis=-1)  # (M, F)
    # the quadratics of the single faces: every row kept, and the face's row left out
    outer = (CN[:, :, :, None] * CN[:, :, None, :]).reshape(M, n, 4)
    keep = np.vstack([np.ones((1, n)), ~faces[sing]]).astype(float)  # (1 + Fs, n)
    Q = (keep @ outer).reshape(M, -1, 2, 2) + eps[:, None, None, None] * np.eye(2)
    q = np.einsum("sn,mnk->msk", keep, CN * ep[:, :, None]) - eps[:, None, None] * d[:, None]
    Q = np.concatenate([np.broadcast_to(Q[:, :1], (M, len(sing), 2, 2)), Q[:, 1:]], axis=1)
    q = np.concatenate([np.broadcast_to(q[:, :1], (M, len(sing), 2)), q[:, 1:]], axis=1)
    # single faces (kept, then slack): lam = c a / |a|^2 + s v, s minimising along v
    a = np.concatenate([N[:, i1[sing]]] * 2, axis=1)  # (M, 2 Fs, 2)
    c = np.concatenate([-tp[:, i1[sing]]] * 2, axis=1)
    a2 = np.sum(a * a, axis=-1)
    ok_a = a2 > DEGENERATE
    lam_a = a * (c / np.where(ok_a, a2, 1.0))[..., None]
    v = np.stack([-a[..., 1], a[..., 0]], axis=-1)
    Qv = np.einsum("msij,msj->msi", Q, v)
    s = -np.sum(v * (q + np.einsum("msij,msj->msi", Q, lam_a)), axis=-1) / \
        np.sum(v * Qv, axis=-1)
    lam_s = lam_a + s[..., None] * v
    # two-cable faces: lam = A^-1 c
    p1, p2 = N[:, i1[~single]], N[:, i2[~single]]  # (M, Fp, 2) rows of A
    det = p1[..., 0] * p2[..., 1] - p1[..., 1] * p2[..., 0]
    ok_p = np.abs(det) > DEGENERATE * np.sum(p1 * p1 + p2 * p2, axis=-1)
    c1, c2 = -tp[:, i1[~single]], -tp[:, i2[~single]]
    dd = np.where(ok_p, det, 1.0)
    lam_p = np.stack([(p2[..., 1] * c1 - p1[..., 1] * c2) / dd,
                      (p1[..., 0] * c2 - p2[..., 0] * c1) / dd], axis=-1)
    # candidates (columns): every face with its rows kept (face order), then the single
    # faces with their row left out
    Fs = len(sing)
    lam = np.zeros((M, F + Fs, 2))
    lam[:, sing] = lam_s[:, :Fs]
    lam[:, F:] = lam_s[:, Fs:]
    lam[:, pairs] = lam_p
    cols_face = np.concatenate([np.arange(F), sing])
    slack = np.concatenate([np.zeros(F, bool), np.ones(Fs, bool)])
    good = np.ones((M, F + Fs), dtype=bool)
    good[:, sing] = ok_a[:, :Fs]
    good[:, F:] = ok_a[:, Fs:]
    good[:, pairs] = ok_p
    # which candidates the general search has: the kept faces where the interior pushes a
    # cable, the slack faces whose cables all may be slack (a two-cable face's slack
    # candidate is its kept one)
    present = np.zeros((M, F + Fs), dtype=bool)
    present[:, :F] = ~ok0[:, None] | (inside & ~single[None, :])
    present[:, F:] = inside[:, sing]
    # degenerate constraints: the general solve
    bad_m, bad_c = np.nonzero(present & ~good)
    if len(bad_m):
        lam[bad_m, bad_c] = _face_lams(N, tp, CN, ep, eps, d, bad_m, cols_face[bad_c],
                                       slack[bad_c], faces, fidx)
    z = faces[cols_face]  # (F + Fs, n) cables at zero
    taus = np.where(z, 0.0, tp[:, None, :] + lam @ np.swapaxes(N, -1, -2))  # (M, F+Fs, n)
    bal = np.linalg.norm(taus @ np.swapaxes(W, -1, -2) - f[:, None, :], axis=-1) <= \
        1e-6 * (np.abs(f).sum(axis=-1) + 1.0)[:, None]
    viol = np.maximum(-taus, 0.0).max(axis=-1)
    feasible = (viol <= tol[:, None]) & bal & present
    tc = np.maximum(taus, 0.0)
    e = b[:, None, :] + tc @ np.swapaxes(C, -1, -2)
    e = np.where(z, np.maximum(e, 0.0), e)
    cost = np.sum(e * e, axis=-1) + eps[:, None] * np.sum((tc - tm[:, None, :]) ** 2, axis=-1)
    # the interior candidate, then the columns: the least cost of each sample (the least
    # violation where none is feasible), the first of equals
    pick_cost = np.concatenate([np.where(ok0, cost0, np.inf)[:, None],
                                np.where(feasible, cost, np.inf)], axis=1)
    first = np.argmin(pick_cost, axis=1)
    rows = np.arange(M)
    ok = np.isfinite(pick_cost[rows, first])
    v_all = np.concatenate([viol0[:, None], np.where(bal & present, viol, np.inf)], axis=1)
    pick = np.where(ok, first, np.argmin(v_all, axis=1))
    col = np.maximum(pick - 1, 0)
    inner = (pick == 0)[:, None]
    t = np.where(inner, t0, tc[rows, col])
    face = np.where(inner, False, z[col])
    # rows left out: the slack candidates', and a two-cable face's where its kept candidate
    # stands for the slack one alone (the interior balanced: kept faces were not searched)
    pair = np.concatenate([~single, np.zeros(Fs, bool)])
    dropped = face & (slack[col] | (pair[col] & ok0))[:, None]
    return t, np.where(pick == 0, cost0, cost[rows, col]), ok, face, dropped
