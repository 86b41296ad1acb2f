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
    converged: np.ndarray | None = None  # where the catenary's solution converged
    #: sagging cables: what the catenaries were solved for, (h, v, tension, 1/EA, w) broadcast
    #: to ``H``'s shape; given back as a guess, an element whose inputs are the same to the
    #: bit keeps its solution as it is (a finite-difference column moves a few cables only)
    inputs: tuple[np.ndarray, ...] | None = None


def _geometry(st: CableState, C: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Free span from B to the leave point C (``st.C`` unless given): horizontal span h,
    vertical span v and the horizontal unit vector e_h from B towards C."""
    d = (st.C if C is None else C) - st.B
    h = np.hypot(d[..., 0], d[..., 1])
    safe = np.where(h > 0, h, 1.0)
    e_h = np.stack([d[..., 0] / safe, d[..., 1] / safe, np.zeros(h.shape)], axis=-1)
    return h, d[..., 2], e_h


def _leave(st: CableState, t_exit: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Leave point C and wrapped length r*beta: where the chord from B leaves the pulley
    (the catenary's own end tangent differs by the sag angle; this approximation keeps
    force and energy within a fraction of a percent of each other on pulleys)."""
    return st.C, st.radius * st.beta


def _inv_ea(robot: Robot) -> np.ndarray:
    """Compliance 1/EA [1/N] per cable: 0 for an inextensible cable (EA inf), inf for a
    zero EA (a fit's trial value at its bound; no warning)."""
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(robot.ea), 1.0 / robot.ea, 0.0)


def _pulls(H, VB, VA, e_h):
    return H[..., None] * e_h + VB[..., None] * EZ, H[..., None] * e_h + VA[..., None] * EZ


def from_lengths(robot: Robot, st: CableState, l0: np.ndarray,
                 guess: CableForces | None = None) -> CableForces:
    """Forces of cables of unstretched lengths ``l0`` (..., n) [m] hung as ``st`` says."""
    if robot.rho <= 0:
        tau = np.where(st.length > l0, robot.ea * (st.length - l0) / l0, 0.0)
        f = tau[..., None] * st.u
        return CableForces(f, f, tau)
    w = robot.rho * robot.gravity
    inv = _inv_ea(robot)
    pulleys = bool(np.any(st.radius > 0))
    H0 = None if guess is None or guess.H is None else guess.H
    V0 = None if guess is None or guess.VB is None else guess.VB
    T = None if guess is None else guess.tension
    t_exit = None
    for _ in range(4 if pulleys else 1):  # the wrap is stretched by the exit tension
        C, wrap = _leave(st, t_exit)
        h, v, e_h = _geometry(st, C)
        lw = wrap / (1.0 + (0.0 if T is None else T) * inv)
        H, VB, _ = catenary.end_forces(h, v, l0 - lw, inv, w, H0, V0)
        VA = VB + w * (l0 - lw)
        T = np.hypot(H, VA)
        H0, V0 = H, VB
        fB, fA = _pulls(H, VB, VA, e_h)
    return CableForces(fB, fA, T, H, VB, l0 - lw)


def from_tensions(robot: Robot, st: CableState, tension: np.ndarray,
                  guess: CableForces | None = None) -> tuple[CableForces, np.ndarray]:
    """Forces of cables holding ``tension`` (..., n) [N] at their exit ends, and the
    unstretched lengths (..., n) [m] that hang so; ``guess`` the forces of the same cables
    hung nearly so (sagging cables: a warm start of the catenary, same solution)."""
    if robot.rho <= 0:
        f = tension[..., None] * st.u
        return CableForces(f, f, tension), st.length / (1.0 + tension / robot.ea)
    return _inverse(robot, st, tension, "A", guess)


def from_platform_tensions(robot: Robot, st: CableState, tension_b: np.ndarray
                           ) -> tuple[CableForces, np.ndarray]:
    """As :func:`from_tensions` with the tension given at the platform end B (what a tension
    distribution computes): forces, and unstretched lengths [m]."""
    if robot.rho <= 0:
        return from_tensions(robot, st, tension_b)
    return _inverse(robot, st, tension_b, "B")


def _inverse(robot: Robot, st: CableState, tension: np.ndarray, end: str,
             guess: CableForces | None = None) -> tuple[CableForces, np.ndarray]:
    w = robot.rho * robot.gravity
    inv = _inv_ea(robot)
    tension = np.array(tension, dtype=float)  # a copy: kept in the result's inputs
    if end == "A":
        # the top of a hanging cable pulls harder than its bottom by w times the height
        # between them (slack readings below that are noise)
        rise = np.maximum((st.C - st.B)[..., 2], 0.0)
        tension = np.maximum(tension, 1.02 * w * rise + 0.1)
    C, wrap = _leave(st, None)
    h, v, e_h = _geometry(st, C)
    inputs = tuple(np.broadcast_arrays(h, v, tension, inv, w))
    usable = guess is not None and guess.H is not None and guess.free is not None \
        and guess.converged is not None and np.shape(guess.H) == np.shape(h)
    same = None
    if usable and guess.inputs is not None \
            and all(np.shape(a) == np.shape(h) for a in guess.inputs):
        same = np.ones(np.shape(h), dtype=bool)
        for a, b in zip(inputs, guess.inputs, strict=True):
            same &= a == b
    if same is not None and same.all():
        lf, H, VB, ok = guess.free, guess.H, guess.VB, guess.converged
    else:
        todo = Ellipsis if same is None else ~same  # the elements to solve
        sub = tuple(x[todo] for x in inputs[:4])
        g = None
        if usable:
            # only solutions that converged start the next one (the same answer, sooner)
            g = tuple(np.asarray(x)[todo] for x in (
                np.where(guess.converged, guess.free, np.nan), guess.H, guess.VB))
        lf_, H_, VB_, ok_ = catenary.unstretched(*sub, w, end=end, guess=g)
        if g is not None and not ok_.all():
            # where a warm start does not converge, the cold start's answer (it may converge;
            # where it does not either, the same as without a guess: an answer that does not
            # hang on the history of the guesses)
            bad = ~ok_ & np.isfinite(g[0])
            if bad.any():
                l2, H2, V2, ok2 = catenary.unstretched(*(x[bad] for x in sub), w, end=end)
                lf_[bad], H_[bad], VB_[bad], ok_[bad] = l2, H2, V2, ok2
        if same is None:
            lf, H, VB, ok = lf_, H_, VB_, ok_
        else:
            lf, H, VB, ok = (np.array(x, copy=True) for x in (guess.free, guess.H, guess.VB,
                                                             guess.converged))
            lf[todo], H[todo], VB[todo], ok[todo] = lf_, H_, VB_, ok_
    VA = VB + w * lf
    TA = np.hypot(H, VA)
    fB, fA = _pulls(H, VB, VA, e_h)
    return CableForces(fB, fA, TA, H, VB, lf, ok, inputs), lf + wrap / (1.0 + TA * inv)


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
    h, v, e_h = _geometry(st)
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
    T = cf.tension
    lw = l0 - cf.free
    span = catenary.energy(cf.H, cf.VB, cf.free, inv, w, st.B[..., 2])
    return span + 0.5 * T * T * lw * inv
