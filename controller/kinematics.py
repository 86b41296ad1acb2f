"""Inverse kinematics (eq. 1), pulley kinematics, wrench matrix (eq. 3), derivatives.

All functions are vectorised over the n cables. Frames: exit points ``exits``
(A_ij, or the displaced A#_ij) in F_b; anchors (B_ij) in F_p; pose as in
:mod:`controller.pose`.

Pulleys (Pott 2012): with radius r > 0 the exit point A is the fixed entry
point on the vertical swivel axis where the cable arrives from below (+z_b).
The pulley swivels to the vertical plane that holds A and B (swivel angle
``gamma = atan2(b_y, b_x)`` of ``b = B - A``); its centre is ``M = A + r e_h``
with ``e_h`` the horizontal unit vector towards B. The cable wraps over the
pulley by the angle beta and leaves tangentially at C towards B:
``l_f = sqrt(|BM|^2 - r^2)``, ``beta = acos(l_f/|BM|) + acos(d_z/|BM|)`` with
``d_z = B_z - M_z`` (written below with atan2, which is the same where
``b_h >= r`` and stays right where B is closer than r to the axis), and the
geometric length is ``r beta + l_f``. ``u`` then points from B to C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.pose import cross, rotation

EZ = np.array([0.0, 0.0, 1.0])
_NO_PLANE = np.zeros((0, 3))  # e_h placeholder when no cable has a pulley


_add_reduce = np.add.reduce


def _sum_last(x: np.ndarray) -> np.ndarray:
    """``x.sum(axis=-1)`` (the same reduction: three components are added in the order numpy
    adds them, component by component, which is three times faster than a reduction over an
    axis of three)."""
    if x.shape[-1] == 3:
        return x[..., 0] + x[..., 1] + x[..., 2]
    return _add_reduce(x, axis=-1)


@dataclass(slots=True)
class CableState:
    """Geometry of all cables at one pose (arrays over the n cables).

    ``Rb`` (n,3): anchors rotated into F_b, relative to the platform origin [m];
    ``B`` (n,3): anchors in F_b; ``A`` (n,3): exit points used; ``C`` (n,3):
    points where the cables leave their pulleys (= A without pulley);
    ``u`` (n,3): unit vectors from B to C; ``free`` (n,): free length |BC| [m];
    ``beta`` (n,): wrap angle [rad]; ``length`` (n,): r*beta + free [m];
    ``e_h`` (n,3) and ``b_h`` (n,): pulley plane direction and horizontal
    distance from the swivel axis to B (used by derivatives; ``e_h`` is empty
    when no cable has a pulley). A plain record (not frozen: made every control cycle);
    treat it as read-only.
    """

    R: np.ndarray
    Rb: np.ndarray
    B: np.ndarray
    A: np.ndarray
    C: np.ndarray
    u: np.ndarray
    free: np.ndarray
    beta: np.ndarray
    length: np.ndarray
    radius: np.ndarray
    e_h: np.ndarray
    b_h: np.ndarray


def cable_state(
    pose: np.ndarray,
    anchors: np.ndarray,
    exits: np.ndarray,
    radius: np.ndarray | None = None,
    frame: CableState | None = None,
) -> CableState:
    """Inverse kinematics: cable geometry at ``pose`` (6,) for exit points ``exits`` (n,3).

    Stacked poses (..., 6) with exits (n,3) or (..., n,3) give stacked states
    (leading dimensions first, e.g. ``u`` (..., n, 3)). ``frame``: a state of the same
    ``pose`` and ``anchors`` (other exits), whose platform side (``R``, ``Rb``, ``B``) is
    taken as it is (iterations over the exit points at a fixed pose; the same result).
    """
    if frame is not None:
        R, Rb, B = frame.R, frame.Rb, frame.B
    else:
        R = rotation(pose[..., 3:6])
        if pose.ndim == 1:
            Rb = anchors @ R.T
            B = pose[:3] + Rb
        else:
            Rb = anchors @ np.swapaxes(R, -1, -2)
            B = pose[..., None, :3] + Rb
    b = B - exits  # from A to B
    # (np.count_nonzero and np.add.reduce: any() and sum() without their Python wrappers,
    # the same results; this runs every control cycle)
    if radius is None or not np.count_nonzero(radius > 0):
        d = np.sqrt(_sum_last(b * b))
        u = b / -d[..., None]
        zeros = np.zeros(d.shape)
        return CableState(R, Rb, B, exits, exits, u, d, zeros, d, zeros, _NO_PLANE, zeros)
    r = np.asarray(radius, dtype=float)
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    b_h = np.sqrt(bx * bx + by * by)
    e_h = np.zeros(b.shape)
    on_axis = b_h == 0  # B on the swivel axis (degenerate): any plane, take +x
    if np.count_nonzero(on_axis):
        safe = np.where(on_axis, 1.0, b_h)
        e_h[..., 0] = np.where(on_axis, 1.0, bx / safe)
        e_h[..., 1] = np.where(on_axis, 0.0, by / safe)
    else:
        e_h[..., 0] = bx / b_h
        e_h[..., 1] = by / b_h
    h = b_h - r  # horizontal distance from the pulley centre M to B
    D2 = h * h + bz * bz  # bz: vertical distance from M (at A's height) to B
    free = np.sqrt(np.maximum(D2 - r * r, 0.0))
    # phi_c = atan2(bz, h) + acos(r / D): its cosine and sine by the angle-sum formulas
    inv_d2 = 1.0 / np.where(D2 > 0, D2, 1.0)
    cos_c = (h * r - bz * free) * inv_d2
    sin_c = (bz * r + h * free) * inv_d2
    beta = np.pi - np.arctan2(sin_c, cos_c)
    no_pulley = r == 0
    if np.count_nonzero(no_pulley):
        beta[..., no_pulley] = 0.0
    # C = M + r (cos phi_c e_h + sin phi_c ez), M = A + r e_h
    C = exits + (r * (1.0 + cos_c))[..., None] * e_h
    C[..., 2] += r * sin_c
    u = (C - B) / free[..., None]
    length = r * beta + free
    return CableState(R, Rb, B, exits, C, u, free, beta, length, r, e_h, b_h)


def cable_lengths(pose: np.ndarray, anchors: np.ndarray, exits: np.ndarray,
                  radius: np.ndarray | None = None) -> np.ndarray:
    """Geometric cable lengths (n,) [m] at ``pose`` (straight, or over the pulleys)."""
    return cable_state(pose, anchors, exits, radius).length


def wrench_matrix(st: CableState) -> np.ndarray:
    """Wrench matrix W (6, n): column ij is ``[u_ij ; (R b_ij) x u_ij]`` (eq. 3).
    (..., 6, n) for stacked states."""
    if st.u.ndim == 2:
        W = np.empty((6, len(st.u)))
        W[:3] = st.u.T
        W[3:] = cross(st.Rb, st.u).T
        return W
    W = np.empty(st.u.shape[:-2] + (6, st.u.shape[-2]))
    W[..., :3, :] = np.swapaxes(st.u, -1, -2)
    W[..., 3:, :] = np.swapaxes(cross(st.Rb, st.u), -1, -2)
    return W


def gravity_wrench(mass: float, com: np.ndarray, gravity: float, R: np.ndarray) -> np.ndarray:
    """Gravity wrench ``w_g = [m g ; (R c) x m g]`` (6,) [N, N m] with g = [0, 0, -gravity];
    (..., 6) for stacked rotations (..., 3, 3)."""
    mg = mass * gravity
    c = R @ com
    if c.ndim == 1:
        return np.array([0.0, 0.0, -mg, -c[1] * mg, c[0] * mg, 0.0])
    w = np.zeros(c.shape[:-1] + (6,))
    w[..., 2] = -mg
    w[..., 3] = -c[..., 1] * mg
    w[..., 4] = c[..., 0] * mg
    return w


def length_jacobian(st: CableState) -> np.ndarray:
    """dL/d(t, w) (n, 6): ``-W^T`` (w: small rotation in F_b). Holds with pulleys too."""
    return -wrench_matrix(st).T


def unit_vector_derivative(st: CableState) -> np.ndarray:
    """D (n,3,3) with ``du = D (dB - dA)``: derivative of u w.r.t. the anchor point B
    (in F_b) minus the exit point A, pulley swivel included.

    The tangent point slides along u (removed by the projector), and the swivel
    moves C perpendicular to the pulley plane by ``dgamma * ez x (C - A)``.
    """
    u = st.u
    P = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    G = np.zeros((len(u), 3, 3))
    has = (st.radius > 0) & (st.b_h > 0)
    if np.any(has):
        perp = cross(EZ, st.C - st.A)  # motion of C per unit swivel angle
        n_plane = cross(EZ, st.e_h)  # dgamma = n_plane . db / b_h
        G[has] = perp[has][:, :, None] * n_plane[has][:, None, :] / st.b_h[has][:, None, None]
    return P @ (G - np.eye(3)[None]) / st.free[:, None, None]
