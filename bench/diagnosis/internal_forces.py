"""Cable tensions of samples recorded without load cells, fitted to the cables' stretch.

At a pose the tensions must balance gravity (``W tau = f``, 6 equations) and pull
(``tau >= 0``); the ``n - 6`` internal forces left free are what the readings of the
winches can tell: a taut cable's unstretched length hangs on its tension, a slack one
(no tension) only says it is at least as long as the straight line. Per sample the
estimate minimises

    sum_i e_i^2 + eps * sum_i (tau_i - tm_i)^2

with ``e_i = r_i + c_i (tau_i - tau_k,i)`` for a taut cable (``r_i`` the length residual at
the linearisation tensions ``tau_k``, ``c_i = dL0_i/dtau_i`` [m/N]) and the one-sided
``e_i = max(r_i - c_i tau_k,i, 0)`` for a cable at zero tension (a reading longer than the
line costs nothing); ``eps`` is a small pull toward ``tm`` (mid-range, as a controller
plans) that only decides what the stretch leaves open (rigid cables).

The problem is not convex (a slack cable's cost drops to the one-sided value at zero
tension), yet its minimum is exact and continuous in the data: in the null space
(``tau = tau_p + N lam``, ``lam`` of dimension ``k = n - 6``) every face of the polytope
``tau >= 0`` with ``j <= k`` cables at zero is tried (the minimiser of the quadratic on its
affine hull: a ``j x j`` solve from one ``n x n`` matrix per sample), the feasible face of
least cost wins. Vectorised over samples and faces (no Python loop over samples); the faces
tried are capped at :data:`MAX_FACES` (about the ``n = 10`` robots' count) by the number of
cables at zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from math import comb

import numpy as np

#: faces tried per sample at most (cables at zero: as many as fit under the cap)
MAX_FACES = 400
#: samples per block (bounds the (samples, faces, cables) arrays)
BLOCK = 1024


@dataclass
class InternalForces:
    """Result of :func:`fit_internal_forces` for M samples: ``tensions`` (M,n) [N] >= 0,
    balancing the wrench; ``at_zero`` (M,n) cables at zero tension; ``cost`` (M,) the
    minimised objective [m^2]; ``feasible`` (M,) a balance with non-negative tensions was
    found (else the face that violates the bound least, its tensions clipped at zero)."""

    tensions: np.ndarray
    at_zero: np.ndarray
    cost: np.ndarray
    feasible: np.ndarray


def _faces(n: int, k: int) -> list[np.ndarray]:
    """Index arrays (C_j, j) of the faces with j = 1..jmax cables at zero."""
    out, total = [], 1
    for j in range(1, k + 1):
        c = comb(n, j)
        if total + c > MAX_FACES:
            break
        out.append(np.array(list(combinations(range(n), j)), dtype=np.intp))
        total += c
    return out


def fit_internal_forces(W: np.ndarray, f: np.ndarray, tau_p: np.ndarray, r: np.ndarray,
                        c: np.ndarray, tau_k: np.ndarray, tm: np.ndarray,
                        eps_rel: float = 1e-9) -> InternalForces:
    """The tensions of the module's objective for M samples.

    ``W`` (M,6,n) wrench matrices, ``f`` (M,6) the wrench to balance, ``tau_p`` (M,n) a
    particular balance (``W tau_p = f``, any sign), ``r`` (M,n) length residuals [m] at
    ``tau_k`` (M,n) [N], ``c`` (M,n) their sensitivity to tension [m/N], ``tm`` (n,) or
    (M,n) the tensions the ``eps`` term pulls toward [N]."""
    M, m, n = W.shape
    tm = np.broadcast_to(np.asarray(tm, float), (M, n))
    out_t = np.zeros((M, n))
    out_cost = np.full(M, np.inf)
    out_ok = np.zeros(M, dtype=bool)
    for a in range(0, M, BLOCK):
        sl = slice(a, min(a + BLOCK, M))
        t, cost, ok = _block(W[sl], f[sl], tau_p[sl], r[sl], c[sl], tau_k[sl], tm[sl],
                             eps_rel)
        out_t[sl], out_cost[sl], out_ok[sl] = t, cost, ok
    scale = np.maximum(np.abs(out_t).max(axis=1, keepdims=True), 1.0)
    return InternalForces(out_t, out_t <= 1e-9 * scale, out_cost, out_ok)


def _block(W, f, tau_p, r, c, tau_k, tm, eps_rel):
    M, m, n = W.shape
    # the null space of each W (rank 6 assumed; a rank-deficient pose has a larger one,
    # of which the first n - 6 directions are used)
    k = max(n - m, 0)
    c2 = c * c
    top = c2.max(axis=1, keepdims=True)
    eps = np.where(top > 0, eps_rel * top, 1.0)  # rigid cables: only the pull to tm
    w = c2 + eps  # per-cable curvature of the objective
    g = c * (c * tau_k - r) + eps * tm  # objective = sum(w tau^2 - 2 g tau) + const
    const = (r - c * tau_k) ** 2 + eps * tm * tm
    if k == 0:
        taus = tau_p[:, None, :]
        masks = [np.zeros((1, n), dtype=bool)]
    else:
        _, _, Vt = np.linalg.svd(W)
        N = np.swapaxes(Vt[:, m:m + k, :], -1, -2)  # (M, n, k)
        Q = np.einsum("mik,mi,mil->mkl", N, w, N)
        q = np.einsum("mik,mi->mk", N, w * tau_p - g)
        Q += (1e-14 * np.trace(Q, axis1=-2, axis2=-1) + 1e-300)[:, None, None] * np.eye(k)
        lam0 = -np.linalg.solve(Q, q[..., None])[..., 0]
        tau0 = tau_p + np.einsum("mik,mk->mi", N, lam0)  # unconstrained minimiser
        G = N @ np.linalg.solve(Q, np.swapaxes(N, -1, -2))  # (M, n, n)
        taus_l = [tau0[:, None, :]]
        masks = [np.zeros((1, n), dtype=bool)]
        for S in _faces(n, k):
            C, j = S.shape
            GSS = G[:, S[:, :, None], S[:, None, :]]  # (M, C, j, j)
            GSS = GSS + (1e-12 * np.abs(GSS).max(axis=(-2, -1), keepdims=True)
                         + 1e-300) * np.eye(j)
            vS = -tau0[:, S]  # (M, C, j): the move that brings the face's cables to zero
            mu = np.linalg.solve(GSS, vS[..., None])[..., 0]
            GnS = np.moveaxis(G[:, :, S], 1, -1)  # (M, C, j, n)
            taus_l.append(tau0[:, None, :] + np.einsum("mcjn,mcj->mcn", GnS, mu))
            mk = np.zeros((C, n), dtype=bool)
            mk[np.arange(C)[:, None], S] = True
            masks.append(mk)
        taus = np.concatenate(taus_l, axis=1)  # (M, F, n)
    zero = np.concatenate(masks, axis=0)  # (F, n)
    scale = np.maximum(np.abs(tau_p).max(axis=1), np.abs(tm).max(axis=1))[:, None]
    viol = np.maximum(-np.where(zero, 0.0, taus), 0.0).max(axis=-1)  # (M, F)
    feasible = viol <= 1e-9 * scale
    t = np.where(zero, 0.0, np.maximum(taus, 0.0))
    w3, g3 = w[:, None, :], g[:, None, :]
    cost = (w3 * t * t - 2.0 * g3 * t + const[:, None, :]).sum(axis=-1)
    # a cable at zero costs its one-sided residual: a reading longer than the line is slack
    e0 = r - c * tau_k  # (M, n) the residual at zero tension
    cz = np.maximum(e0, 0.0) ** 2 - e0 ** 2  # replaces e_i(0)^2
    cost = cost + (zero[None] * cz[:, None, :]).sum(axis=-1)
    pick_cost = np.where(feasible, cost, np.inf)
    best = np.argmin(pick_cost, axis=1)
    ok = np.isfinite(pick_cost[np.arange(M), best])
    # no feasible face: the one that violates the bound least
    best = np.where(ok, best, np.argmin(viol, axis=1))
    rows = np.arange(M)
    return t[rows, best], cost[rows, best], ok
