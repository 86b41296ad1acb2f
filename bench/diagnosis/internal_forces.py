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
robots' count) by the number of cables at zero.
"""

from __future__ import annotations

from dataclasses import dataclass
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


def _faces(n: int, k: int) -> np.ndarray:
    """(F, n) masks of the faces with 1..jmax cables at zero (under :data:`MAX_FACES`)."""
    out, total = [], 1
    for j in range(1, k + 1):
        c = comb(n, j)
        if total + c > MAX_FACES:
            break
        for S in combinations(range(n), j):
            m = np.zeros(n, dtype=bool)
            m[list(S)] = True
            out.append(m)
        total += c
    return np.array(out, dtype=bool).reshape(-1, n)


def fit_internal_forces(W: np.ndarray, f: np.ndarray, r: np.ndarray, C: np.ndarray,
                        tau_k: np.ndarray, tm: np.ndarray,
                        eps_rel: float = 1e-9) -> InternalForces:
    """The tensions of the module's objective for M samples.

    ``W`` (M,6,n) wrench matrices, ``f`` (M,6) the wrench to balance, ``r`` (M,n) length
    residuals [m] at ``tau_k`` (M,n) [N], ``C`` their sensitivity to the tensions [m/N]:
    (M,n,n), or (M,n) for its diagonal; ``tm`` (n,) or (M,n) the tensions the ``eps``
    term pulls toward [N]."""
    M, m, n = W.shape
    C = np.asarray(C, float)
    if C.ndim == 2:
        C = C[:, :, None] * np.eye(n)
    tm = np.broadcast_to(np.asarray(tm, float), (M, n))
    out_t = np.zeros((M, n))
    out_cost = np.full(M, np.inf)
    out_ok = np.zeros(M, dtype=bool)
    for a in range(0, M, BLOCK):
        sl = slice(a, min(a + BLOCK, M))
        t, cost, ok = _block(W[sl], f[sl], r[sl], C[sl], tau_k[sl], tm[sl], eps_rel)
        out_t[sl], out_cost[sl], out_ok[sl] = t, cost, ok
    scale = np.maximum(np.abs(out_t).max(axis=1, keepdims=True), 1.0)
    return InternalForces(out_t, out_t <= 1e-9 * scale, out_cost, out_ok)


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


def _block(W, f, r, C, tau_k, tm, eps_rel):
    M, m, n = W.shape
    CtC = np.swapaxes(C, -1, -2) @ C
    top = np.max(np.diagonal(CtC, axis1=-2, axis2=-1), axis=-1)
    eps = np.where(top > 0, eps_rel * top, 1.0)  # rigid cables: only the pull to tm
    b = r - np.einsum("mij,mj->mi", C, tau_k)  # residuals at zero tensions
    eyeM = eps[:, None, None] * np.eye(n)
    H = CtC + eyeM
    g = -np.einsum("mji,mj->mi", C, b) + eps[:, None] * tm
    none = np.zeros((M, n), dtype=bool)
    tau0 = _kkt(H, g, W, f, none)
    scale = np.maximum(np.abs(tau0).max(axis=1), np.abs(tm).max(axis=1))
    tol = 1e-9 * scale
    t = np.maximum(tau0, 0.0)
    cost = _cost(t, b, C, eps, tm, none)
    balanced = np.linalg.norm(np.einsum("mik,mk->mi", W, tau0) - f, axis=1) <= \
        1e-6 * (np.abs(f).sum(axis=1) + 1.0)
    ok = np.all(tau0 >= -tol[:, None], axis=1) & balanced
    # a cable that would read longer than its line with its own tension at zero may be
    # slack: those samples, and those pushing a cable, try the faces
    e_own0 = b + np.einsum("mij,mj->mi", C, tau0) - np.diagonal(C, axis1=-2, axis2=-1) * tau0
    hard = ~ok | np.any(e_own0 < 0.0, axis=1)
    if n > m and hard.any():
        h = np.flatnonzero(hard)
        viol0 = np.maximum(-tau0[h], 0.0).max(axis=1)
        th, ch, okh = _faces_min(H[h], g[h], W[h], f[h], C[h], b[h], eps[h], tm[h], tol[h],
                                 t[h], cost[h], ok[h], viol0)
        t[h], cost[h], ok[h] = th, ch, okh
    return t, cost, ok


def _faces_min(H, g, W, f, C, b, eps, tm, tol, t0, cost0, ok0, viol0):
    """The least-objective feasible candidate over the faces (module docstring), the
    interior one (``t0``, ``cost0``, ``ok0``, its bound violation ``viol0``) included."""
    M, n = g.shape
    faces = _faces(n, n - W.shape[-2])  # (F, n)
    F = len(faces)
    if F == 0:
        return t0, cost0, ok0
    fz = np.broadcast_to(faces, (M, F, n))
    # kept in the least squares: the convex problem's face
    Hk = np.broadcast_to(H[:, None], (M, F, n, n))
    gk = np.broadcast_to(g[:, None], (M, F, n))
    # left out of it (slack): rows of the face's cables dropped from C^T C and C^T b
    Cs = np.where(fz[..., :, None], 0.0, C[:, None])  # (M, F, n, n): rows i in S zeroed
    Hd = np.swapaxes(Cs, -1, -2) @ Cs + eps[:, None, None, None] * np.eye(n)
    gd = -np.einsum("mfji,mfj->mfi", Cs, np.where(fz, 0.0, b[:, None])) \
        + eps[:, None, None] * tm[:, None]
    HH = np.concatenate([Hk, Hd], axis=1)
    gg = np.concatenate([gk, gd], axis=1)
    zz = np.concatenate([fz, fz], axis=1)
    Wb = np.broadcast_to(W[:, None], (M, 2 * F) + W.shape[1:])
    fb = np.broadcast_to(f[:, None], (M, 2 * F, f.shape[-1]))
    taus = _kkt(HH, gg, Wb, fb, zz)  # (M, 2F, n)
    taus = np.where(zz, 0.0, taus)
    bal = np.linalg.norm(np.einsum("mfik,mfk->mfi", Wb, taus) - fb, axis=-1) <= \
        1e-6 * (np.abs(f).sum(axis=-1)[:, None] + 1.0)
    viol = np.maximum(-taus, 0.0).max(axis=-1)  # (M, 2F)
    feasible = (viol <= tol[:, None]) & bal
    tc = np.maximum(taus, 0.0)
    cost = _cost(tc, b[:, None], C[:, None], eps[:, None], tm[:, None], zz)
    # with the interior candidate
    all_t = np.concatenate([t0[:, None], tc], axis=1)
    all_cost = np.concatenate([cost0[:, None], cost], axis=1)
    all_ok = np.concatenate([ok0[:, None], feasible], axis=1)
    all_viol = np.concatenate([viol0[:, None],
                               np.where(bal, viol, np.inf)], axis=1)
    pick = np.where(all_ok, all_cost, np.inf)
    best = np.argmin(pick, axis=1)
    rows = np.arange(M)
    ok = np.isfinite(pick[rows, best])
    # no feasible candidate: the one that violates the bound least
    best = np.where(ok, best, np.argmin(all_viol, axis=1))
    return all_t[rows, best], all_cost[rows, best], ok
