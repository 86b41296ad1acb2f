"""Cable forces, straight or sagging: one place for what a cable does at both ends.

Without sag (``robot.rho == 0``) a cable is a straight elastic segment: it pulls
the platform at B with ``tau u`` and its exit point with ``-tau u``. With sag
(``rho > 0``, weight w = rho g per unstretched metre) the free span from B to C
(the exit point, or where the cable leaves its pulley) is an elastic catenary
(:mod:`controller.catenary`): it pulls the platform with ``H e_h + V_B e_z`` and
the exit with ``-(H e_h + V_A e_z)``; the load cells read the tension at the
exit end. The wrap on a pulley is a straight segment in series (same tension).

Functions take a :class:`controller.kinematics.CableState` (stacked or not) and
work on its arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller import catenary
from controller.kinematics import CableState
from controller.robot import Robot

EZ = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class CableForces:
    """``platform`` (..., n, 3): force of each cable on the platform at B [N];
    ``exit`` (..., n, 3): the cable's pull direction times tension at the exit end
    (the exit point feels minus this) [N]; ``tension`` (..., n): tension at the exit
    end [N]; ``H``, ``VB`` catenary end forces (None without sag)."""

    platform: np.ndarray
    exit: np.ndarray
    tension: np.ndarray
    H: np.ndarray | None = None
    VB: np.ndarray | None = None
    free: np.ndarray | None = None  # unstretched length of the sagging span [m]


def _geometry(st: CableState) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Free span from B to C: horizontal span h, vertical span v, horizontal unit e_h and
    the wrapped length r*beta."""
    d = st.C - st.B
    h = np.hypot(d[..., 0], d[..., 1])
    safe = np.where(h > 0, h, 1.0)
    e_h = np.stack([d[..., 0] / safe, d[..., 1] / safe, np.zeros(h.shape)], axis=-1)
    return h, d[..., 2], e_h, st.radius * st.beta


def _inv_ea(robot: Robot) -> np.ndarray:
    return np.where(np.isfinite(robot.ea), 1.0 / robot.ea, 0.0)


def from_lengths(robot: Robot, st: CableState, l0: np.ndarray,
                 guess: CableForces | None = None) -> CableForces:
    """Forces of cables of unstretched lengths ``l0`` (..., n) [m] hung as ``st`` says."""
    if robot.rho <= 0:
        tau = np.where(st.length > l0, robot.ea * (st.length - l0) / l0, 0.0)
        f = tau[..., None] * st.u
        return CableForces(f, f, tau)
    w = robot.rho * robot.gravity
    inv = _inv_ea(robot)
    h, v, e_h, wrap = _geometry(st)
    H0 = None if guess is None or guess.H is None else guess.H
    V0 = None if guess is None or guess.VB is None else guess.VB
    T = None if guess is None else guess.tension
    for _ in range(3 if np.any(wrap > 0) else 1):  # wrap stretched by the exit tension
        lw = wrap / (1.0 + (0.0 if T is None else T) * inv)
        H, VB, _ = catenary.end_forces(h, v, l0 - lw, inv, w, H0, V0)
        T = np.hypot(H, VB + w * (l0 - lw))
        H0, V0 = H, VB
    VA = VB + w * (l0 - lw)
    fB = H[..., None] * e_h + VB[..., None] * EZ
    fA = H[..., None] * e_h + VA[..., None] * EZ
    return CableForces(fB, fA, T, H, VB, l0 - lw)


def from_tensions(robot: Robot, st: CableState, tension: np.ndarray
                  ) -> tuple[CableForces, np.ndarray]:
    """Forces of cables holding ``tension`` (..., n) [N] at their exit ends, and the
    unstretched lengths (..., n) [m] that hang so."""
    if robot.rho <= 0:
        f = tension[..., None] * st.u
        return CableForces(f, f, tension), st.length / (1.0 + tension / robot.ea)
    w = robot.rho * robot.gravity
    inv = _inv_ea(robot)
    h, v, e_h, wrap = _geometry(st)
    # a hanging cable holds at least its own weight at the top (slack readings are noise)
    tension = np.maximum(np.asarray(tension, dtype=float), 1.05 * w * np.hypot(h, v) + 0.1)
    lf, H, VB, _ = catenary.unstretched(h, v, tension, inv, w, end="A")
    VA = VB + w * lf
    fB = H[..., None] * e_h + VB[..., None] * EZ
    fA = H[..., None] * e_h + VA[..., None] * EZ
    return CableForces(fB, fA, np.asarray(tension, float), H, VB, lf), \
        lf + wrap / (1.0 + tension * inv)


def from_platform_tensions(robot: Robot, st: CableState, tension_b: np.ndarray
                           ) -> tuple[CableForces, np.ndarray]:
    """As :func:`from_tensions` with the tension given at the platform end B (what a tension
    distribution computes): forces, and unstretched lengths [m]."""
    if robot.rho <= 0:
        return from_tensions(robot, st, tension_b)
    w = robot.rho * robot.gravity
    inv = _inv_ea(robot)
    h, v, e_h, wrap = _geometry(st)
    lf, H, VB, _ = catenary.unstretched(h, v, tension_b, inv, w, end="B")
    VA = VB + w * lf
    TA = np.hypot(H, VA)
    fB = H[..., None] * e_h + VB[..., None] * EZ
    fA = H[..., None] * e_h + VA[..., None] * EZ
    return CableForces(fB, fA, TA, H, VB, lf), lf + wrap / (1.0 + TA * inv)


def platform_directions(robot: Robot, st: CableState, cf: CableForces | None) -> np.ndarray:
    """Unit directions (..., n, 3) of the cable forces on the platform (u without sag)."""
    if robot.rho <= 0 or cf is None:
        return st.u
    norm = np.linalg.norm(cf.platform, axis=-1, keepdims=True)
    return cf.platform / np.where(norm > 0, norm, 1.0)


def stiffness(robot: Robot, st: CableState, cf: CableForces) -> np.ndarray:
    """K (..., n, 3, 3) with ``dF = K (dB - dA)`` for the force F of a sagging cable on the
    platform (the exit pull changes alike, the weight of the span being constant); the
    leave point moves with the exit point."""
    w = robot.rho * robot.gravity
    inv = _inv_ea(robot)
    h, v, e_h, wrap = _geometry(st)
    H, VB = cf.H, cf.VB
    f11, f12, f21, f22, _, _ = catenary.flexibility(H, VB, cf.free, inv, w)
    det = f11 * f22 - f12 * f21
    k11, k12, k21, k22 = f22 / det, -f12 / det, -f21 / det, f11 / det  # d(H,VB)/d(h,v)
    e_perp = np.stack([-e_h[..., 1], e_h[..., 0], np.zeros(h.shape)], axis=-1)
    E = np.stack([e_h, np.broadcast_to(EZ, e_h.shape)], axis=-1)  # (..., 3, 2)
    Kloc = np.stack([np.stack([k11, k12], -1), np.stack([k21, k22], -1)], -2)  # (..., 2, 2)
    Kc = E @ Kloc @ np.swapaxes(E, -1, -2)
    safe = np.where(h > 0, h, 1.0)
    Kc = Kc + (H / safe)[..., None, None] * (e_perp[..., :, None] * e_perp[..., None, :])
    return -Kc


def energy(robot: Robot, st: CableState, l0: np.ndarray, cf: CableForces) -> np.ndarray:
    """Potential energy (..., n) [J] of each cable: strain energy, plus the weight of the
    sagging span when ``rho > 0``."""
    inv = _inv_ea(robot)
    if robot.rho <= 0:
        stretch = np.maximum(st.length - l0, 0.0)
        return np.where(np.isfinite(robot.ea), robot.ea * stretch * stretch / (2.0 * l0), 0.0)
    w = robot.rho * robot.gravity
    h, v, e_h, wrap = _geometry(st)
    T = cf.tension
    lw = l0 - cf.free
    span = catenary.energy(cf.H, cf.VB, cf.free, inv, w, st.B[..., 2])
    return span + 0.5 * T * T * lw * inv
