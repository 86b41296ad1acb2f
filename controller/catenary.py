"""The elastic catenary (Irvine): a cable sagging under its own weight.

A cable of unstretched length L0 [m], axial stiffness EA [N] and weight per
unstretched length w = rho g [N/m] hangs from its lower end B (on the platform)
to its upper end A (the exit point, or the point where it leaves its pulley).
Along the cable, s in [0, L0] from B, the horizontal tension component H [N] is
constant and the vertical one is V(s) = V_B + w s, so the cable pulls the
platform at B with ``H e_h + V_B e_z`` (e_h: horizontal unit vector from B towards
A) and pulls A with ``-(H e_h + V_A e_z)``, V_A = V_B + w L0. The spans are

    h = H L0/EA + (H/w) [asinh(b) - asinh(a)]
    v = (V_B L0 + w L0^2/2)/EA + (H/w) [sqrt(1+b^2) - sqrt(1+a^2)]

with a = V_B/H, b = V_A/H. Functions work elementwise on arrays (any shape);
``inv_ea`` = 1/EA (0 for an inextensible cable). Newton solutions report
convergence per element.
"""

from __future__ import annotations

import numpy as np


def _differences(a: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, ...]:
    """For ``b = a + d`` (d >= 0): ``ra = sqrt(1+a^2)``, ``rb``, and ``asinh(b) - asinh(a)``
    and ``b/rb - a/ra`` each divided by ``d``, without the cancellation of the plain
    differences when the cable's weight is small against its tension (``d = w L0/H``
    tiny: a light or very taut cable, the straight limit). Where a and b share a sign,
    ``asinh(b) - asinh(a) = asinh(d (a+b) / (b ra + a rb))`` and
    ``b/rb - a/ra = d (a+b) / ((b ra + a rb) ra rb)``; elsewhere the plain differences
    (no cancellation there)."""
    b = a + d
    ra, rb = np.hypot(1.0, a), np.hypot(1.0, b)
    same = a * b > 0
    den = np.where(same, b * ra + a * rb, 1.0)
    pos = d > 0
    dd = np.where(pos, d, 1.0)
    q = d * (a + b) / den
    asd = np.where(same, np.arcsinh(q), np.arcsinh(b) - np.arcsinh(a)) / dd
    gd = np.where(same, q / (ra * rb), b / rb - a / ra) / dd
    # d = 0 (no cable): the limits, the derivatives at a
    asd = np.where(pos, asd, 1.0 / ra)
    gd = np.where(pos, gd, 1.0 / ra ** 3)
    return b, ra, rb, asd, gd


def _terms(H: np.ndarray, VB: np.ndarray, L0: np.ndarray, w: float) -> tuple[np.ndarray, ...]:
    """``a = V_B/H`` and :func:`_differences` of it: what :func:`spans` and
    :func:`flexibility` share (one Newton iteration computes them once)."""
    a = VB / H
    return (a, *_differences(a, w * L0 / H))


def spans(H: np.ndarray, VB: np.ndarray, L0: np.ndarray, inv_ea: np.ndarray,
          w: float, terms: tuple[np.ndarray, ...] | None = None
          ) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical spans (h, v) [m] of the cable for end forces (H, V_B)
    (``terms``: :func:`_terms` of the same, when already at hand)."""
    a, b, ra, rb, asd, _ = _terms(H, VB, L0, w) if terms is None else terms
    # (H/w) [asinh(b) - asinh(a)] = L0 asd; (H/w) [rb - ra] = L0 (a + b)/(ra + rb)
    h = H * L0 * inv_ea + L0 * asd
    v = (VB * L0 + 0.5 * w * L0 * L0) * inv_ea + L0 * (a + b) / (ra + rb)
    return h, v


def flexibility(H: np.ndarray, VB: np.ndarray, L0: np.ndarray, inv_ea: np.ndarray,
                w: float, terms: tuple[np.ndarray, ...] | None = None
                ) -> tuple[np.ndarray, ...]:
    """Partial derivatives of the spans: (dh/dH, dh/dVB, dv/dH, dv/dVB, dh/dL0, dv/dL0)
    (``terms``: :func:`_terms` of the same, when already at hand)."""
    a, b, ra, rb, asd, gd = _terms(H, VB, L0, w) if terms is None else terms
    k = L0 / H  # d / w
    dh_dH = L0 * inv_ea + k * (asd - gd)
    dh_dV = -k * (a + b) / ((ra + rb) * ra * rb)  # (1/rb - 1/ra) / w
    dv_dV = L0 * inv_ea + k * gd
    dh_dL = H * inv_ea + 1.0 / rb
    dv_dL = (VB + w * L0) * inv_ea + b / rb
    return dh_dH, dh_dV, dh_dV, dv_dV, dh_dL, dv_dL


def _straight_guess(h, v, L0, inv_ea, w):
    d = np.hypot(h, v)
    strain = np.maximum(d / np.maximum(L0, 1e-9) - 1.0, 0.0)
    T = np.where(inv_ea > 0, strain / np.where(inv_ea > 0, inv_ea, 1.0), 0.0)
    T = np.maximum(T, w * L0)  # at least the weight of the cable
    H = np.maximum(T * h / d, 1e-3 * (w * L0 + 1.0))
    VB = T * v / d - 0.5 * w * L0
    return H, VB


def end_forces(h: np.ndarray, v: np.ndarray, L0: np.ndarray, inv_ea: np.ndarray, w: float,
               H0: np.ndarray | None = None, VB0: np.ndarray | None = None,
               tol: float = 1e-12, max_iter: int = 60
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """End forces (H, V_B) [N] of a cable of unstretched length L0 spanning (h, v); the
    third array says where Newton's method converged (relative span error < tol)."""
    h, v, L0 = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (h, v, L0)))
    inv_ea = np.broadcast_to(np.asarray(inv_ea, dtype=float), h.shape)
    if H0 is None or VB0 is None:
        H, VB = _straight_guess(h, v, L0, inv_ea, w)
    else:
        H, VB = np.array(H0, dtype=float, copy=True), np.array(VB0, dtype=float, copy=True)
    scale = np.maximum(np.hypot(h, v), 1e-9)
    ok = np.zeros(h.shape, dtype=bool)
    for _ in range(max_iter):
        terms = _terms(H, VB, L0, w)
        hh, vv = spans(H, VB, L0, inv_ea, w, terms)
        eh, ev = hh - h, vv - v
        ok = np.hypot(eh, ev) < tol * scale
        if ok.all():
            break
        f11, f12, f21, f22, _, _ = flexibility(H, VB, L0, inv_ea, w, terms)
        det = f11 * f22 - f12 * f21
        dH = (f22 * eh - f12 * ev) / det
        dV = (-f21 * eh + f11 * ev) / det
        # keep H positive: at most halve it per step
        step = np.where(dH > 0.5 * H, 0.5 * H / np.where(dH != 0, dH, 1.0), 1.0)
        H = H - step * dH
        VB = VB - step * dV
    return H, VB, ok


def unstretched(h: np.ndarray, v: np.ndarray, T: np.ndarray, inv_ea: np.ndarray, w: float,
                end: str = "A", tol: float = 1e-12, max_iter: int = 60,
                guess: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unstretched length L0 [m] and end forces (H, V_B) of the cable spanning (h, v) with
    tension T [N] at end ``A`` (upper) or ``B`` (lower); the fourth array says where it
    converged. ``guess`` (L0, H, V_B), shaped as the result, starts Newton's method where
    it is finite with H > 0 (a solution for nearby spans: a warm start)."""
    h, v, T = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (h, v, T)))
    shape = h.shape
    inv_ea = np.broadcast_to(np.asarray(inv_ea, dtype=float), shape).ravel()
    h, v, T = h.ravel(), v.ravel(), T.ravel()
    d = np.hypot(h, v)
    L0 = d / (1.0 + T * inv_ea)
    H = np.maximum(T * h / d, 1e-6)
    VB = T * v / d - 0.5 * w * L0
    if guess is not None:
        gL, gH, gV = (np.broadcast_to(np.asarray(g, dtype=float), shape).ravel() for g in guess)
        use = np.isfinite(gL) & np.isfinite(gH) & np.isfinite(gV) & (gH > 0) & (gL > 0)
        L0, H, VB = np.where(use, gL, L0), np.where(use, gH, H), np.where(use, gV, VB)
    scale = np.maximum(d, 1e-9)
    ok = np.zeros(h.shape, dtype=bool)
    act = np.arange(h.size)  # elements still iterating (the converged ones stop)
    best = np.full(h.size, np.inf)
    stall = np.zeros(h.size, dtype=int)
    for _ in range(max_iter):
        Ha, Va, La, ia = H[act], VB[act], L0[act], inv_ea[act]
        Ta, sa = T[act], scale[act]
        terms = _terms(Ha, Va, La, w)
        hh, vv = spans(Ha, Va, La, ia, w, terms)
        V_end = Va + w * La if end == "A" else Va
        r = np.stack([hh - h[act], vv - v[act],
                      (np.hypot(Ha, V_end) - Ta) / np.maximum(Ta, 1e-9) * sa])
        err = np.abs(r).max(axis=0)
        done = err < tol * sa
        ok[act[done]] = True
        # an element whose error has not halved in 6 iterations will not converge: it stops
        better = err < 0.5 * best[act]
        best[act] = np.where(better, err, best[act])
        stall[act] = np.where(better, 0, stall[act] + 1)
        keep = ~done & (stall[act] < 6)
        if not keep.any():
            break
        act, r = act[keep], r[:, keep]
        Ha, Va, La, ia, Ta, sa, V_end = (x[keep] for x in (Ha, Va, La, ia, Ta, sa, V_end))
        f11, f12, f21, f22, f1L, f2L = flexibility(Ha, Va, La, ia, w,
                                                   tuple(x[keep] for x in terms))
        Tn = np.maximum(np.hypot(Ha, V_end), 1e-12)
        g = sa / np.maximum(Ta, 1e-9)
        dT_dH, dT_dV = Ha / Tn * g, V_end / Tn * g
        dT_dL = (w * V_end / Tn * g) if end == "A" else np.zeros_like(Ha)
        dH, dV, dL = _solve3((f11, f12, f1L), (f21, f22, f2L), (dT_dH, dT_dV, dT_dL), r)
        step = np.where(dH > 0.5 * Ha, 0.5 * Ha / np.where(dH != 0, dH, 1.0), 1.0)
        H[act], VB[act], L0[act] = Ha - step * dH, Va - step * dV, La - step * dL
    return L0.reshape(shape), H.reshape(shape), VB.reshape(shape), ok.reshape(shape)


def _solve3(row0, row1, row2, r):
    """Solutions (x0, x1, x2) of the 3x3 systems with rows ``row0..2`` (each three arrays of
    shape (K,)) and right-hand sides ``r`` (3,K), elementwise by Cramer's rule (one LAPACK
    call per system costs more than the arithmetic)."""
    (a, b, c), (d, e, f), (g, h, i) = row0, row1, row2
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g  # cofactors of the first row
    det = a * A + b * B + c * C
    r0, r1, r2 = r
    x0 = (r0 * A + r1 * (c * h - b * i) + r2 * (b * f - c * e)) / det
    x1 = (r0 * B + r1 * (a * i - c * g) + r2 * (c * d - a * f)) / det
    x2 = (r0 * C + r1 * (b * g - a * h) + r2 * (a * e - b * d)) / det
    return x0, x1, x2


def energy(H: np.ndarray, VB: np.ndarray, L0: np.ndarray, inv_ea: np.ndarray, w: float,
           zB: np.ndarray) -> np.ndarray:
    """Potential energy [J] of the hanging cable: strain energy plus the gravity of its own
    weight (the lower end at height zB [m]); its derivative with respect to an end is
    minus the force the cable exerts there."""
    a = VB / H
    b = (VB + w * L0) / H
    VA = VB + w * L0
    strain = 0.5 * inv_ea * (H * H * L0 + (VA**3 - VB**3) / (3.0 * w))

    def G(u):
        return 0.5 * (u * np.hypot(1.0, u) + np.arcsinh(u))

    int_z = (VB * L0 * L0 / 2.0 + w * L0**3 / 6.0) * inv_ea \
        + (H / w) * ((H / w) * (G(b) - G(a)) - L0 * np.hypot(1.0, a))
    return strain + w * (zB * L0 + int_z)
