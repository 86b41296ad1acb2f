"""Poses and rotations.

A pose is ``(x, y, z, roll, pitch, yaw)``: the position of the platform frame F_p
in the base frame F_b [m] and ``R = Rz(yaw) Ry(pitch) Rx(roll)`` [rad], i.e.
scipy ``Rotation.from_euler("xyz", [roll, pitch, yaw])``.

Solvers update orientations with a small rotation ``w`` expressed in F_b
(``R <- exp([w]x) R``); :func:`compose` applies such an increment and
:func:`euler_rate_matrix` maps Euler-angle rates to it.
"""

from __future__ import annotations

import math

import numpy as np


def rotation(rpy: np.ndarray) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) Ry(pitch) Rx(roll)`` (3, 3) from ``rpy`` [rad]; (..., 3, 3)
    for stacked angles (..., 3)."""
    if np.ndim(rpy) > 1:
        return _rotation_batch(np.asarray(rpy, dtype=float))
    r, p, y = (float(a) for a in rpy)
    cr, sr = math.cos(r), math.sin(r)
    cp, sp = math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _rotation_batch(rpy: np.ndarray) -> np.ndarray:
    cr, sr = np.cos(rpy[..., 0]), np.sin(rpy[..., 0])
    cp, sp = np.cos(rpy[..., 1]), np.sin(rpy[..., 1])
    cy, sy = np.cos(rpy[..., 2]), np.sin(rpy[..., 2])
    R = np.empty(rpy.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def euler_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation`: ``[roll, pitch, yaw]`` [rad], pitch in [-pi/2, pi/2];
    (..., 3) for stacked matrices (..., 3, 3)."""
    if np.ndim(R) > 2:
        R = np.asarray(R, dtype=float)
        return np.stack([np.arctan2(R[..., 2, 1], R[..., 2, 2]),
                         np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0)),
                         np.arctan2(R[..., 1, 0], R[..., 0, 0])], axis=-1)
    pitch = math.asin(min(1.0, max(-1.0, -float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return np.array([roll, pitch, yaw])


_I1 = np.array([1, 2, 0])
_I2 = np.array([2, 0, 1])


#: elements of ``a`` and ``b`` together from which :func:`cross` takes the components as
#: views: gathering them (``take`` on the last axis) costs about 15 ns an element, the views'
#: six products and ``stack`` about 8 us more at any size; the two cost the same near 1,600
#: (measured: 8 cables, 50 samples, both (50, 8, 3): 19 us gathered, 13 us as views; 300
#: samples: 111 against 28 us; one sample: 2.6 against 10 us)
CROSS_VIEWS_MIN = 1600


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product ``a x b`` along the last axis of (..., 3) arrays (np.cross is slower).
    The same products and differences either way (the same numbers to the last bit): the
    components gathered for small arrays, taken as views for large ones
    (:data:`CROSS_VIEWS_MIN`)."""
    if a.size + b.size < CROSS_VIEWS_MIN:
        return a.take(_I1, axis=-1) * b.take(_I2, axis=-1) - \
            a.take(_I2, axis=-1) * b.take(_I1, axis=-1)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` (..., 3, 3) with ``[v]x a = v x a``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape + (3,))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1] = -z
    out[..., 0, 2] = y
    out[..., 1, 0] = z
    out[..., 1, 2] = -x
    out[..., 2, 0] = -y
    out[..., 2, 1] = x
    return out


def rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` [rad] (Rodrigues)."""
    x, y, z = (float(a) for a in w)
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-12:
        s, c1 = 1.0, 0.5
    else:
        s, c1 = math.sin(th) / th, (1.0 - math.cos(th)) / (th * th)
    return np.array([
        [1.0 - c1 * (y * y + z * z), c1 * x * y - s * z, c1 * x * z + s * y],
        [c1 * x * y + s * z, 1.0 - c1 * (x * x + z * z), c1 * y * z - s * x],
        [c1 * x * z - s * y, c1 * y * z + s * x, 1.0 - c1 * (x * x + y * y)],
    ])


def compose(pose: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """Pose after the increment ``dx = (dt, w)``: ``t + dt`` and ``exp([w]x) R``, w in F_b [rad]."""
    R = rotvec_matrix(dx[3:6]) @ rotation(pose[3:6])
    out = np.empty(6)
    out[:3] = pose[:3] + dx[:3]
    # keep angles continuous with the previous pose (yaw/roll wrap at +-pi)
    d = euler_from_rotation(R) - pose[3:6]
    out[3:] = pose[3:6] + (d + math.pi) % (2 * math.pi) - math.pi
    return out


def euler_rate_matrix(rpy: np.ndarray) -> np.ndarray:
    """Matrix E with ``w = E(rpy) d(rpy)``: angular velocity in F_b from Euler-angle rates;
    (..., 3, 3) for stacked angles (..., 3)."""
    rpy = np.asarray(rpy, dtype=float)
    p, y = rpy[..., 1], rpy[..., 2]
    cp, sp = np.cos(p), np.sin(p)
    cy, sy = np.cos(y), np.sin(y)
    E = np.zeros(rpy.shape[:-1] + (3, 3))
    E[..., 0, 0] = cy * cp
    E[..., 0, 1] = -sy
    E[..., 1, 0] = sy * cp
    E[..., 1, 1] = cy
    E[..., 2, 0] = -sp
    E[..., 2, 2] = 1.0
    return E
