"""Designed experiments: which poses to measure next, from what a diagnosis left open.

Pure linear algebra on per-candidate pieces (no robot, no I/O): the caller evaluates, at
each candidate pose ``i`` of a feasible set, the whitened residual Jacobian of the
diagnosis's residual model (one physics: ``bench.campaign_design`` builds it with
``bench.diagnosis.residuals.ResidualModel``), and this module chooses ``N`` of them.

Two things a campaign of poses ``S`` (each visited ``v`` times) should do:

**Fix the parameters** (D-optimality). The preferred model's Fisher information is
``M(S) = M0 + v sum_{i in S} J_i^T J_i`` (``J_i`` the whitened Jacobian rows of candidate
``i``, parameters scaled to their typical size; ``M0`` a weak prior that keeps ``log det``
finite while ``S`` is small). The criterion is ``log det M(S)``: the volume of the
confidence ellipsoid, whatever units the parameters have.

**Separate the alternatives** (T-optimality). Data made by the preferred model, fitted by an
alternative ``a`` (linearised at its best fit over every candidate: residuals ``d_i``,
Jacobian ``K_i``), leave the alternative the chi-square

    Delta_a(S) = v * min_delta sum_{i in S} |d_i - K_i delta|^2
               = v * (c - b^T (A + R_a / v)^-1 b),   A = sum K_i^T K_i, b = sum K_i^T d_i,
                                                       c = sum |d_i|^2

(``R_a`` the alternative's weak prior): the expected chi-square difference between the two
explanations on that campaign (noise adds the same to both). An alternative is
**separated** when ``Delta_a`` reaches ``target``.

The chosen set maximises the compound criterion

    Phi(S) = log det M(S) + w sum_a log(min(Delta_a(S), target) + eps target)

(``w`` the number of parameters: an alternative brought from nothing to the target is worth
as much as the parameters' information multiplied by ``1/eps``; once every alternative reached
``target``, only the parameters' information counts). Without alternatives ``Phi`` is the
D-criterion alone. Greedy forward selection builds ``S`` one pose at a time, then Fedorov
exchange passes swap a chosen pose for a candidate while ``Phi`` grows (each accepted swap
raises ``Phi``: it ends).

**Match a reference's standard errors** (:func:`choose_matching`, :func:`fewest_to_match`):
the poses whose standard errors of chosen parameters come closest to (below) those of a
reference campaign, by the 8-norm of the ratios (a smooth largest ratio): exchange passes
from several starts, one of them the heaviest candidates of the approximate design
(:func:`relaxed_weights`: iterated towards the best weighting of the candidates, whose
cost bounds from below what any set of poses reaches; a few hundred iterations get its
support, not its bound).

**Only some cables measured** (:func:`measured_information`): an unmeasured cable's tension
is a nuisance of every pose (and of the initialisation); its columns are fitted away from
the information (Schur complement, :func:`marginal_information`, :func:`eliminate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: share of the target an alternative counts with before it is separated at all
EPS = 1e-3
#: Fedorov exchange passes at most
EXCHANGE_PASSES = 4


@dataclass(frozen=True)
class Alternative:
    """An alternative explanation's pieces per candidate: ``A`` (C,q,q) ``K_i^T K_i``,
    ``b`` (C,q) ``K_i^T d_i``, ``c`` (C,) ``|d_i|^2`` (whitened, dimensionless), and
    ``prior`` (q,q) its weak prior information; ``name`` for the report."""

    name: str
    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    prior: np.ndarray

    @staticmethod
    def from_rows(name: str, d: list[np.ndarray], K: list[np.ndarray],
                  prior: np.ndarray) -> Alternative:
        """From per-candidate residual rows ``d[i]`` (r_i,) and Jacobian rows ``K[i]`` (r_i,q)."""
        A = np.stack([k.T @ k for k in K])
        b = np.stack([k.T @ di for k, di in zip(K, d, strict=True)])
        c = np.array([float(di @ di) for di in d])
        return Alternative(name, A, b, c, np.asarray(prior, float))


@dataclass(frozen=True)
class Design:
    """The chosen candidates ``indices`` (in the order chosen); ``logdet`` of the parameters'
    information; ``delta`` the expected chi-square difference per alternative (by name);
    ``separated`` per alternative (``delta >= target``); ``criterion`` Phi; ``exchanges``
    accepted swaps."""

    indices: np.ndarray
    logdet: float
    delta: dict[str, float]
    separated: dict[str, bool]
    criterion: float
    exchanges: int


def information(F: np.ndarray, S: np.ndarray | list[int], visits: int = 1,
                prior: np.ndarray | None = None) -> np.ndarray:
    """``M(S)`` (p,p): the prior plus ``visits`` times the candidates' information ``F``
    (C,p,p) summed over ``S``."""
    S = np.asarray(S, dtype=int)
    M = visits * F[S].sum(axis=0) if len(S) else np.zeros(F.shape[1:])
    return M if prior is None else M + prior


def logdet(M: np.ndarray) -> float:
    """``log det M`` of a symmetric matrix (-inf when it is not positive definite)."""
    sign, val = np.linalg.slogdet(M)
    return float(val) if sign > 0 else -np.inf


def discrimination(alt: Alternative, S: np.ndarray | list[int], visits: int = 1) -> float:
    """``Delta_a(S)``: the chi-square the alternative is left with, refitted to the preferred
    model's data on ``S`` visited ``visits`` times (module docstring)."""
    S = np.asarray(S, dtype=int)
    if not len(S):
        return 0.0
    A, b, c = alt.A[S].sum(axis=0), alt.b[S].sum(axis=0), float(alt.c[S].sum())
    return _delta(A, b, c, alt.prior, visits)


def _delta(A: np.ndarray, b: np.ndarray, c: float, prior: np.ndarray, visits: int) -> float:
    x = np.linalg.solve(A + prior / visits, b)
    return max(visits * (c - float(b @ x)), 0.0)


def criterion(F: np.ndarray, alts: list[Alternative], S: np.ndarray | list[int], visits: int,
              prior: np.ndarray, target: float) -> float:
    """``Phi(S)`` (module docstring)."""
    phi = logdet(information(F, S, visits, prior))
    w = float(F.shape[1])
    for a in alts:
        phi += w * np.log(min(discrimination(a, S, visits), target) + EPS * target)
    return phi


def choose(F: np.ndarray, n: int, alts: list[Alternative] | None = None, visits: int = 1,
           prior: np.ndarray | None = None, target: float = 25.0,
           start: np.ndarray | None = None) -> Design:
    """Choose ``n`` of the C candidates: greedy forward selection on ``Phi`` (from ``start``
    when given), then exchange passes.

    ``F`` (C,p,p) each candidate's information (``J_i^T J_i``, scaled parameters); ``alts``
    the alternatives to separate (none: a D-optimal design); ``visits`` per pose; ``prior``
    (p,p) the weak prior information (default ``1e-6 I``); ``target`` the chi-square
    difference that separates an alternative."""
    F = np.asarray(F, float)
    C, p = F.shape[0], F.shape[1]
    if not 1 <= n <= C:
        raise ValueError(f"poses: {n} asked, {C} candidates (must be 1..{C})")
    alts = list(alts or [])
    prior = np.eye(p) * 1e-6 if prior is None else np.asarray(prior, float)

    def phi(S: list[int]) -> float:
        return criterion(F, alts, S, visits, prior, target)

    S = [int(i) for i in (start if start is not None else [])][:n]
    while len(S) < n:
        rest = [i for i in range(C) if i not in S]
        S.append(max(rest, key=lambda i: phi(S + [i])))
    best, swaps = phi(S), 0
    for _ in range(EXCHANGE_PASSES):
        improved = False
        for k in range(n):
            for j in range(C):
                if j in S:
                    continue
                trial = S[:k] + [j] + S[k + 1:]
                val = phi(trial)
                if val > best + 1e-9 * max(1.0, abs(best)):
                    S, best, improved, swaps = trial, val, True, swaps + 1
        if not improved:
            break
    idx = np.array(S, dtype=int)
    delta = {a.name: discrimination(a, idx, visits) for a in alts}
    return Design(idx, logdet(information(F, idx, visits, prior)), delta,
                  {k: v >= target for k, v in delta.items()}, best, swaps)


def standard_errors(F: np.ndarray, S: np.ndarray | list[int], visits: int = 1,
                    prior: np.ndarray | None = None) -> np.ndarray:
    """(p,) the standard errors ``sqrt(diag(M(S)^-1))`` the design gives (in the units of
    the scaled parameters ``F`` is in)."""
    M = information(F, S, visits, prior)
    return np.sqrt(np.maximum(np.diag(np.linalg.pinv(M, hermitian=True)), 0.0))


def poses_to_match(F: np.ndarray, reference: np.ndarray, keys: np.ndarray, visits: int,
                   prior: np.ndarray | None = None, n_max: int | None = None
                   ) -> tuple[int, np.ndarray]:
    """The fewest poses (``visits`` each) whose standard errors of the parameters ``keys``
    (indices) are all at most ``reference`` (len(keys),): greedy on the weighted
    A-criterion ``sum_k (se_k / reference_k)^2`` (each step adds the candidate that lowers it
    most), stopped as soon as every ratio is at most 1. Returns ``(count, indices)`` (count
    -1 when ``n_max`` poses do not reach it)."""
    C, p = F.shape[0], F.shape[1]
    n_max = C if n_max is None else min(n_max, C)
    prior = np.eye(p) * 1e-6 if prior is None else prior
    keys = np.asarray(keys, dtype=int)
    ref2 = np.asarray(reference, float) ** 2
    S: list[int] = []
    M = prior.copy()

    def cost(Mi: np.ndarray) -> float:
        return float(np.sum(np.diag(np.linalg.pinv(Mi, hermitian=True))[keys] / ref2))

    for _ in range(n_max):
        rest = [i for i in range(C) if i not in S]
        best = min(rest, key=lambda i: cost(M + visits * F[i]))
        S.append(best)
        M = M + visits * F[best]
        if np.all(standard_errors(F, S, visits, prior)[keys] <= reference):
            return len(S), np.array(S, dtype=int)
    return -1, np.array(S, dtype=int)


def marginal_information(Jt: np.ndarray, Je: np.ndarray) -> np.ndarray:
    """(p,p) the information on the parameters of the whitened Jacobian ``Jt`` (r,p) once the
    nuisance parameters of ``Je`` (r,k) are fitted away (the Schur complement
    ``Jt^T Jt - Jt^T Je (Je^T Je)^+ Je^T Jt``): what a direction of the parameters the
    nuisance can imitate leaves is lost."""
    A = Jt.T @ Jt
    if Je.shape[1] == 0:
        return A
    B = Jt.T @ Je
    M = A - B @ np.linalg.pinv(Je.T @ Je, hermitian=True) @ B.T
    return 0.5 * (M + M.T)


def measured_information(Jp: list[np.ndarray], Jr: list[np.ndarray], J0: list[np.ndarray],
                         measured: np.ndarray) -> np.ndarray:
    """Per candidate the information when only the cables ``measured`` (n,) bool carry load
    cells: each candidate's unmeasured tensions are its own nuisance parameters, the
    unmeasured readings at initialisation a nuisance shared by every candidate.

    ``Jp[i]`` (r_i,p) candidate ``i``'s whitened rows by the parameters (scaled); ``Jr[i]``
    (r_i,n) by its own readings [per N]; ``J0[i]`` (r_i,n) by the initialisation's readings.
    Returns (C, p+k, p+k) (``k`` unmeasured cables): the parameters then the shared
    nuisance, to sum over a design and reduce with :func:`eliminate` (``k``). With every
    cable measured it is ``Jp[i]^T Jp[i]``: nothing lost."""
    off = ~np.asarray(measured, bool)
    out = []
    for jp, jr, j0 in zip(Jp, Jr, J0, strict=True):
        out.append(marginal_information(np.hstack([jp, j0[:, off]]), jr[:, off]))
    return np.stack(out)


def eliminate(M: np.ndarray, k: int) -> np.ndarray:
    """(p,p) the information on the first ``p`` parameters of ``M`` (p+k,p+k) once its last
    ``k`` (nuisance) are fitted away (Schur complement)."""
    if k == 0:
        return M
    p = M.shape[0] - k
    A, B, C = M[:p, :p], M[:p, p:], M[p:, p:]
    out = A - B @ np.linalg.pinv(C, hermitian=True) @ B.T
    return 0.5 * (out + out.T)


def subset_standard_errors(G: np.ndarray, S: np.ndarray | list[int], k: int, visits: int = 1,
                           prior: np.ndarray | None = None) -> np.ndarray:
    """(p,) the standard errors (scaled parameters) a design ``S`` (``visits`` each) gives
    with only some cables measured: ``G`` from :func:`measured_information`, ``k`` its
    shared nuisance; ``prior`` (p,p) on the parameters (default ``1e-6 I``: a parameter the
    data cannot fix gets a standard error near 1e3, i.e. 1000 typical sizes)."""
    M = eliminate(information(G, S, visits), k)
    M = M + (np.eye(M.shape[0]) * 1e-6 if prior is None else prior)
    return np.sqrt(np.maximum(np.diag(np.linalg.pinv(M, hermitian=True)), 0.0))


#: the ratios' norm a matching design minimises (a smooth stand-in for the largest ratio)
MATCH_NORM = 8
#: starts of a matching design: the greedy one, the approximate design's, then random ones
MATCH_STARTS = 4
#: exchange passes of a matching design at most
MATCH_PASSES = 10
#: iterations of the approximate (weights) design's multiplicative algorithm
RELAX_ITERS = 200


def ratio_cost(M: np.ndarray, keys: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(sum_k (se_k / reference_k)^(2q))^(1/q)`` with ``q`` :data:`MATCH_NORM`: the
    standard errors ``se`` of the parameters ``keys`` that the information ``M`` (p,p), or a
    stack of them (..., p,p), gives as ratios to ``reference`` (same units); close to the
    largest squared ratio. ``M`` must be positive definite (a prior keeps it so)."""
    var = np.diagonal(np.linalg.inv(M), axis1=-2, axis2=-1)[..., keys]
    r2 = np.maximum(var, 0.0) / np.asarray(reference, float) ** 2
    top = np.maximum(r2.max(axis=-1), 1e-300)
    return top * np.sum((r2 / top[..., None]) ** MATCH_NORM, axis=-1) ** (1.0 / MATCH_NORM)


def relaxed_weights(F: np.ndarray, keys: np.ndarray, reference: np.ndarray, total: float,
                    prior: np.ndarray, iters: int = RELAX_ITERS) -> np.ndarray:
    """(C,) the approximate design: weights ``w`` (summing to 1) over the C candidates that
    minimise :func:`ratio_cost` of ``M(w) = prior + total sum_i w_i F_i`` (``total`` the
    visits of the whole campaign), by the multiplicative algorithm ``w_i <- w_i (g_i /
    sum_j w_j g_j)^(1/2)`` with ``g_i = -d cost / d w_i >= 0`` (at the optimum no candidate
    has ``g_i`` above the weighted mean: the equivalence theorem). Its heaviest candidates
    start an exchange (:func:`choose_matching`)."""
    F = np.asarray(F, float)
    C = F.shape[0]
    keys = np.asarray(keys, dtype=int)
    inv_ref2 = 1.0 / np.asarray(reference, float) ** 2
    w = np.full(C, 1.0 / C)
    for _ in range(iters):
        Minv = np.linalg.inv(prior + total * np.einsum("c,cij->ij", w, F))
        G = Minv[keys]  # (m,p): d var_k = -G_k dM G_k^T
        r2 = np.maximum(np.diag(Minv)[keys], 0.0) * inv_ref2
        top = max(float(r2.max()), 1e-300)
        u = (r2 / top) ** (MATCH_NORM - 1) * inv_ref2  # d cost / d var_k, up to a factor
        g = np.einsum("k,kp,cpq,kq->c", u, G, F, G, optimize=True)
        mean = float(w @ g)
        if mean <= 0:
            break
        w = w * np.sqrt(np.maximum(g, 0.0) / mean)
        w /= w.sum()
    return w


def choose_matching(F: np.ndarray, n: int, keys: np.ndarray, reference: np.ndarray,
                    visits: int = 1, prior: np.ndarray | None = None,
                    starts: int = MATCH_STARTS, seed: int = 0) -> np.ndarray:
    """``n`` of the C candidates (``visits`` each) whose standard errors of the parameters
    ``keys`` come closest to (below) ``reference``: :func:`ratio_cost` minimised by exchange
    passes (Fedorov: swap a chosen candidate for another while the cost falls) from the
    greedy forward selection, from the ``n`` heaviest candidates of the approximate design
    (:func:`relaxed_weights`) and from ``starts - 2`` random sets. Returns the indices of
    the best."""
    F = np.asarray(F, float)
    C, p = F.shape[0], F.shape[1]
    if not 1 <= n <= C:
        raise ValueError(f"poses: {n} asked, {C} candidates (must be 1..{C})")
    prior = np.eye(p) * 1e-6 if prior is None else np.asarray(prior, float)
    keys = np.asarray(keys, dtype=int)
    vF = visits * F

    def costs(base: np.ndarray, S: list[int]) -> np.ndarray:
        """The cost of ``base`` plus each candidate (inf for those in ``S``)."""
        c = ratio_cost(base[None] + vF, keys, reference)
        c[S] = np.inf
        return c

    S: list[int] = []
    M = prior.copy()
    while len(S) < n:
        j = int(np.argmin(costs(M, S)))
        S.append(j)
        M = M + vF[j]
    w = relaxed_weights(F, keys, reference, float(n * visits), prior)
    rng = np.random.default_rng(seed)
    tries = [S, np.argsort(-w)[:n].tolist()] \
        + [rng.choice(C, n, replace=False).tolist() for _ in range(starts - 2)]
    best_S, best = S, np.inf
    for T in tries:
        T, val = _exchange(costs, vF, prior, T, keys, reference)
        if val < best:
            best_S, best = T, val
    return np.array(best_S, dtype=int)


def _exchange(costs, vF: np.ndarray, prior: np.ndarray, S: list[int], keys: np.ndarray,
              reference: np.ndarray) -> tuple[list[int], float]:
    """Exchange passes on ``S`` (at most :data:`MATCH_PASSES`): each chosen candidate in
    turn is swapped for the candidate that lowers the cost most, while the cost falls."""
    S = [int(i) for i in S]
    M = prior + vF[S].sum(axis=0)
    val = float(ratio_cost(M, keys, reference))
    for _ in range(MATCH_PASSES):
        improved = False
        for k in range(len(S)):
            base = M - vF[S[k]]
            c = costs(base, S)
            j = int(np.argmin(c))
            if c[j] < val * (1.0 - 1e-9):
                S[k], M, val, improved = j, base + vF[j], float(c[j]), True
        if not improved:
            break
    return S, val


def fewest_to_match(F: np.ndarray, reference: np.ndarray, keys: np.ndarray, visits: int,
                    prior: np.ndarray | None = None, n_max: int | None = None,
                    seed: int = 0) -> tuple[int, np.ndarray]:
    """The fewest poses (``visits`` each) whose standard errors of ``keys`` are all at most
    ``reference``: :func:`poses_to_match` (greedy) gives a count, then
    :func:`choose_matching` (exchange, several starts) looks for fewer by bisection (a count
    it reaches becomes the new upper end). Returns ``(count, indices)`` (count -1 when
    ``n_max`` poses do not reach)."""
    C, p = F.shape[0], F.shape[1]
    n_max = C if n_max is None else min(n_max, C)
    prior = np.eye(p) * 1e-6 if prior is None else prior
    keys = np.asarray(keys, dtype=int)

    def reaches(S: np.ndarray) -> bool:
        return bool(np.all(standard_errors(F, S, visits, prior)[keys] <= reference))

    count, S = poses_to_match(F, reference, keys, visits, prior, n_max)
    if count < 0:
        S = choose_matching(F, n_max, keys, reference, visits, prior, seed=seed)
        if not reaches(S):
            return -1, S
        count = n_max
    lo = 0  # bisection: fewer poses than lo do not reach (as far as the search finds)
    while count - lo > 1:
        mid = (lo + count) // 2
        T = choose_matching(F, mid, keys, reference, visits, prior, seed=seed)
        if reaches(T):
            count, S = mid, T
        else:
            lo = mid
    return count, np.asarray(S, dtype=int)
