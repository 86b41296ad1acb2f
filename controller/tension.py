"""Tension distribution: tensions tau in [tau_min, tau_max] with ``W tau = f``.

For static equilibrium ``W tau + w_g = 0`` call with ``f = -w_g``. Two methods:

- :func:`closed_form`: the improved closed-form method (Pott 2014): start at the
  middle of the tension range, ``tau = tau_m + W^+ (f - W tau_m)``; while a
  tension leaves the range, fix the worst one at its bound and redistribute
  over the others. Fast (the control cycle uses it); may refuse a pose where a
  feasible distribution exists close to the border of the workspace.
- :func:`min_norm_qp`: the minimal-norm distribution ``min |tau|^2`` subject to
  balance and bounds, exact (primal active set, phase 1 by linear programming).

Both return a :class:`TensionResult`; when infeasible, ``tensions`` is all NaN
and ``reason`` says why. A feasible result always balances ``f`` (residual
checked) and stays within bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dposv
from scipy.optimize import linprog


@dataclass(slots=True)
class TensionResult:
    """Result of a tension distribution.

    ``tensions`` (n,) [N] (NaN when infeasible); ``feasible``; ``reason`` (empty
    when feasible); ``residual``: ``|W tau - f|`` [N, N m]; ``iterations``.
    """

    tensions: np.ndarray
    feasible: bool
    reason: str = ""
    residual: float = 0.0
    iterations: int = 0


# the reductions of ndarray.sum/min/max without their Python wrappers (the same results;
# a control cycle makes a dozen of them on arrays of a few values)
_sum, _min, _max = np.add.reduce, np.minimum.reduce, np.maximum.reduce


def _tolerance(f: np.ndarray, tmax: float) -> float:
    """Absolute tolerance on balance and bounds [N]: 1e-9 of the largest force in play."""
    return 1e-9 * max(1.0, float(_max(np.abs(f))), tmax if tmax < np.inf else 1.0)


def _fail(n: int, reason: str, it: int = 0) -> TensionResult:
    return TensionResult(np.full(n, np.nan), False, reason, np.inf, it)


def _check(W: np.ndarray, f: np.ndarray, tau: np.ndarray, tmin: float, tmax: float,
           it: int, method: str, tol: float) -> TensionResult:
    e = W @ tau - f
    res = math.sqrt(float(e @ e))
    if res > 3e3 * tol:
        return _fail(len(tau), f"{method}: the wrench cannot be balanced at this pose "
                     f"(residual {res:.3g}; wrench matrix rank-deficient)", it)
    if tau.min() < tmin or tau.max() > tmax:
        np.clip(tau, tmin, tmax, out=tau)  # round-off only; violations were handled above
    return TensionResult(tau, True, "", res, it)


def closed_form(W: np.ndarray, f: np.ndarray, tmin: float, tmax: float,
                target: np.ndarray | None = None) -> TensionResult:
    """Improved closed-form tension distribution (Pott 2014), ``W tau = f``: the tensions
    closest to the middle of the range, or to ``target`` (n,) when given."""
    m, n = W.shape
    f = np.asarray(f, dtype=float)
    if not math.isfinite(float(_sum(W, axis=None)) + float(_sum(f, axis=None))):
        return _fail(n, "closed-form: non-finite wrench matrix or wrench")
    tol = _tolerance(f, tmax)
    # the common case in a control cycle: one solve around the middle of the range (or the
    # target), every tension within bounds
    tm0 = 0.5 * (tmin + tmax) if target is None else np.asarray(target, float)
    _, y, info = dposv(W @ W.T, f - (tm0 * _sum(W, axis=1) if target is None else W @ tm0))
    if info == 0:
        sol = y @ W
        sol += tm0
        lo, hi = _min(sol), _max(sol)
        if lo >= tmin - tol and hi <= tmax + tol:
            e = W @ sol - f
            res = math.sqrt(float(e @ e))
            if res <= 3e3 * tol:
                if lo < tmin or hi > tmax:
                    np.clip(sol, tmin, tmax, out=sol)  # round-off only
                return TensionResult(sol, True, "", res, 1)
    tau = np.empty(n)
    free = np.ones(n, dtype=bool)
    idx_free = np.arange(n)
    rhs = f
    tm = np.full(n, 0.5 * (tmin + tmax)) if target is None else np.asarray(target, float)
    Wf = W
    for it in range(1, n + 1):
        k = len(idx_free)
        if k < m:
            return _fail(n, f"closed-form: {n - k} cables at their limits leave {k} < {m} "
                         f"to balance the wrench (outside the wrench-feasible workspace)", it)
        # minimal-norm correction around the middle tension, Cholesky on W W^T (SPD if rank m)
        tf = tm[idx_free]
        _, y, info = dposv(Wf @ Wf.T, rhs - Wf @ tf)
        if info != 0:
            return _fail(n, "closed-form: the remaining cables cannot balance the wrench "
                         "(wrench matrix rank-deficient)", it)
        sol = y @ Wf
        sol += tf
        lo_v = sol.min()
        hi_v = sol.max()
        if lo_v >= tmin - tol and hi_v <= tmax + tol:
            tau[idx_free] = sol
            return _check(W, f, tau, tmin, tmax, it, "closed-form", tol)
        if tmin - lo_v >= hi_v - tmax:
            worst, bound = int(sol.argmin()), tmin
        else:
            worst, bound = int(sol.argmax()), tmax
        idx = idx_free[worst]
        tau[idx] = bound
        free[idx] = False
        idx_free = np.delete(idx_free, worst)
        rhs = rhs - W[:, idx] * bound
        Wf = W[:, idx_free]
    return _fail(n, "closed-form: no feasible distribution", n)


def _phase1(W: np.ndarray, f: np.ndarray, tmin: float, tmax: float) -> np.ndarray | None:
    n = W.shape[1]
    res = linprog(np.ones(n), A_eq=W, b_eq=f, bounds=[(tmin, tmax)] * n, method="highs")
    return res.x if res.status == 0 else None


def min_norm_qp(W: np.ndarray, f: np.ndarray, tmin: float, tmax: float,
                start: np.ndarray | None = None, max_iter: int = 200) -> TensionResult:
    """Minimal 2-norm tension distribution within bounds, ``W tau = f`` (primal active set)."""
    m, n = W.shape
    if not np.all(np.isfinite(W)) or not np.all(np.isfinite(f)):
        return _fail(n, "qp: non-finite wrench matrix or wrench")
    tol = _tolerance(f, tmax)
    tau = None
    if start is not None and np.all(np.isfinite(start)):
        s = np.clip(start, tmin, tmax)
        if np.linalg.norm(W @ s - f) <= 1e3 * tol:
            tau = s
    if tau is None:
        cf = closed_form(W, f, tmin, tmax)
        tau = cf.tensions if cf.feasible else _phase1(W, f, tmin, tmax)
    if tau is None:
        return _fail(n, f"qp: no tensions within [{tmin:g}, {tmax:g}] N balance the wrench "
                     f"(outside the wrench-feasible workspace)")
    tau = np.array(tau, dtype=float)
    # working set: cables held at a bound (-1 lower, +1 upper, 0 free)
    bound = np.zeros(n, dtype=int)
    btol = 1e-9 * max(1.0, tmax if np.isfinite(tmax) else 1.0)
    bound[np.abs(tau - tmin) <= btol] = -1
    bound[np.abs(tau - tmax) <= btol] = 1
    for it in range(1, max_iter + 1):
        free = bound == 0
        fixed_val = np.where(bound < 0, tmin, tmax)
        rhs = f - W[:, ~free] @ fixed_val[~free]
        Wf = W[:, free]
        # minimal-norm solution on the free set (rhs is reachable: tau is feasible)
        target = np.where(free, 0.0, fixed_val)
        if free.any():
            target[free] = np.linalg.pinv(Wf) @ rhs
        p = target - tau
        if np.linalg.norm(p) <= 1e-12 * max(1.0, np.linalg.norm(tau)):
            y = np.linalg.lstsq(Wf.T, tau[free], rcond=None)[0] if free.any() else np.zeros(m)
            lam = tau - W.T @ y  # multipliers of the held bounds
            wrong = np.where(bound < 0, -lam, np.where(bound > 0, lam, -np.inf))
            j = int(np.argmax(wrong))
            if wrong[j] <= 1e-9 * max(1.0, np.abs(tau).max()):
                return _check(W, f, tau, tmin, tmax, it, "qp", tol)
            bound[j] = 0
            continue
        # longest step towards target within bounds
        alpha, block = 1.0, -1
        for k in np.flatnonzero(free):
            if p[k] < 0 and tau[k] + p[k] < tmin:
                a = (tmin - tau[k]) / p[k]
                if a < alpha:
                    alpha, block = a, k
            elif p[k] > 0 and tau[k] + p[k] > tmax:
                a = (tmax - tau[k]) / p[k]
                if a < alpha:
                    alpha, block = a, k
        tau = tau + alpha * p
        if block >= 0:
            bound[block] = -1 if p[block] < 0 else 1
            tau[block] = tmin if p[block] < 0 else tmax
    return _fail(n, f"qp: no convergence in {max_iter} iterations", max_iter)


METHODS = {"closed_form": closed_form, "qp": min_norm_qp}


def distribute(W: np.ndarray, w_g: np.ndarray, tmin: float, tmax: float,
               method: str = "closed_form") -> TensionResult:
    """Tensions that balance the gravity wrench: ``W tau + w_g = 0``."""
    try:
        fn = METHODS[method]
    except KeyError:
        raise ValueError(f"unknown tension distribution {method!r} "
                         f"(known: {', '.join(METHODS)})") from None
    return fn(W, -np.asarray(w_g, dtype=float), tmin, tmax)
