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
tension), yet its minimum is exact and continuous in the data. The balanced minimiser without the
bounds comes from a 6 x 6 Schur complement; where it pulls on every cable and no cable
reads longer than its line it is the answer (the problem is convex there). Elsewhere every
face of the polytope ``tau >= 0`` with ``j <= n - 6`` cables at zero is tried (the
minimiser of the quadratic on its affine hull: a ``j x j`` solve from one ``n x n`` matrix
per sample) and the feasible face of least cost wins. Vectorised over samples and faces
(no Python loop over samples); the faces tried are capped at :data:`MAX_FACES` (about the
``n = 10`` robots' count) by the number of cables at zero.
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


def fit_internal_forces(W: np.ndarray, f: np.ndarray, r: np.ndarray,
                        c: np.ndarray, tau_k: np.ndarray, tm: np.ndarray,
                        eps_rel: float = 1e-9) -> InternalForces:
    """The tensions of the module's objective for M samples.

    ``W`` (M,6,n) wrench matrices, ``f`` (M,6) the wrench to balance, ``r`` (M,n) length
    residuals [m] at
    ``tau_k`` (M,n) [N], ``c`` (M,n) their sensitivity to tension [m/N], ``tm`` (n,) or
    (M,n) the tensions the ``eps`` term pulls toward [N]."""
    M, m, n = W.shape
    tm = np.broadcast_to(np.asarray(tm, float), (M, n))
    out_t = np.zeros((M, n))
    out_cost = np.full(M, np.inf)
    out_ok = np.zeros(M, dtype=bool)
    for a in range(0, M, BLOCK):
        sl = slice(a, min(a + BLOCK, M))
        t, cost, ok = _block(W[sl], f[sl], r[sl], c[sl], tau_k[sl], tm[sl], eps_rel)
        out_t[sl], out_cost[sl], out_ok[sl] = t, cost, ok
    scale = np.maximum(np.abs(out_t).max(axis=1, keepdims=True), 1.0)
    return InternalForces(out_t, out_t <= 1e-9 * scale, out_cost, out_ok)


def _block(W, f, r, c, tau_k, tm, eps_rel):
    M, m, n = W.shape
    c2 = c * c
    top = c2.max(axis=1, keepdims=True)
    eps = np.where(top > 0, eps_rel * top, 1.0)  # rigid cables: only the pull to tm
    w = c2 + eps  # per-cable curvature of the objective
    g = c * (c * tau_k - r) + eps * tm  # objective = sum(w tau^2 - 2 g tau) + const
    const = (r - c * tau_k) ** 2 + eps * tm * tm
    e0 = r - c * tau_k  # (M, n) the residual at zero tension
    # a cable at zero costs its one-sided residual (a reading longer than the line is
    # slack): this replaces its e_i(0)^2
    cz = np.maximum(e0, 0.0) ** 2 - e0 ** 2
    # the balanced minimiser without the bounds: tau = (g + W^T y) / w, W tau = f (the
    # Schur complement A = W diag(1/w) W^T, on columns scaled by 1/sqrt(w))
    sw = 1.0 / np.sqrt(w)
    Ws = W * sw[:, None, :]
    A = Ws @ np.swapaxes(Ws, -1, -2)
    A += (1e-13 * np.trace(A, axis1=-2, axis2=-1) + 1e-300)[:, None, None] * np.eye(m)
    y = np.linalg.solve(A, (f - np.einsum("mik,mk->mi", W, g / w))[..., None])[..., 0]
    tau0 = (g + np.einsum("mik,mi->mk", W, y)) / w
    scale = np.maximum(np.abs(tau0).max(axis=1), np.abs(tm).max(axis=1))
    # where it pulls on every cable and no cable reads longer than its line, the problem
    # is convex with its minimum inside: that is the answer
    t = np.maximum(tau0, 0.0)
    cost = (w * t * t - 2.0 * g * t + const).sum(axis=-1)
    ok = np.all(tau0 >= -1e-9 * scale[:, None], axis=1)
    hard = ~ok | np.any(e0 < 0.0, axis=1)
    if n > m and hard.any():
        h = np.flatnonzero(hard)
        # how the balanced minimiser moves with a force on each cable: the inverse of the
        # objective on the balanced subspace, diag(1/w) - diag(1/w) W^T A^-1 W diag(1/w)
        P = np.eye(n) - np.swapaxes(Ws[h], -1, -2) @ np.linalg.solve(A[h], Ws[h])
        G = sw[h][:, :, None] * P * sw[h][:, None, :]
        th, ch, okh = _faces_min(G, tau0[h], w[h], g[h], const[h], cz[h], scale[h])
        t[h], cost[h], ok[h] = th, ch, okh
    return t, cost, ok


def _faces_min(G, tau0, w, g, const, cz, scale):
    """The least-cost feasible face for each sample (module docstring), from ``G = N Q^-1
    N^T`` (M,n,n) and the unconstrained minimiser ``tau0`` (M,n)."""
    M, n = tau0.shape
    taus_l = [tau0[:, None, :]]
    masks = [np.zeros((1, n), dtype=bool)]
    for S in _faces(n, n - 6):
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
    viol = np.maximum(-np.where(zero, 0.0, taus), 0.0).max(axis=-1)  # (M, F)
    feasible = viol <= 1e-9 * scale[:, None]
    t = np.where(zero, 0.0, np.maximum(taus, 0.0))
    cost = (w[:, None] * t * t - 2.0 * g[:, None] * t + const[:, None]).sum(axis=-1)
    cost = cost + (zero[None] * cz[:, None, :]).sum(axis=-1)
    pick_cost = np.where(feasible, cost, np.inf)
    best = np.argmin(pick_cost, axis=1)
    ok = np.isfinite(pick_cost[np.arange(M), best])
    # no feasible face: the one that violates the bound least
    best = np.where(ok, best, np.argmin(viol, axis=1))
    rows = np.arange(M)
    return t[rows, best], cost[rows, best], ok
