"""Masts: supporting-rope settlement (A -> A*) and compliant masts (eq. 4-8).

Mast i pivots about its base O_i on three elastic joints along x_b, y_b, z_b
with compliance ``c_i = 1/k_i`` [rad/(N m)] (0 = rigid). Cable ij pulls its
pulley with ``f_ij = -tau_ij (u_ij + v_ij)``; ``v_ij`` is parallel to the lever
arm ``r_ij = A*_ij - O_i`` and so adds no moment about the pivot, leaving

    M_i = sum_j r_ij x f_ij = -sum_j tau_ij r_ij x u_ij,
    dtheta_i = c_i * M_i,          A#_ij = A*_ij + dtheta_i x r_ij,

which is the paper's ``delta a = J K^-1 J^T w`` written per mast. Lever arms
are taken at A* (small deflections); u_ij is the direction of the cable as it
leaves the displaced pulley.
"""

from __future__ import annotations

import numpy as np

from controller.pose import cross, rotvec_matrix


def settle(exits: np.ndarray, pivots: np.ndarray, mast_index: np.ndarray,
           tilt: np.ndarray) -> np.ndarray:
    """Exit points A* (n,3) after each mast tilted rigidly by ``tilt`` (m,3) [rad] about its
    pivot."""
    out = np.array(exits, dtype=float, copy=True)
    for i in range(len(pivots)):
        if np.any(tilt[i] != 0):
            sel = mast_index == i
            out[sel] = pivots[i] + (exits[sel] - pivots[i]) @ rotvec_matrix(tilt[i]).T
    return out


def tilt_from_rope_elongation(attach_height: float, rope_length: float, elongation: float,
                              toward: np.ndarray) -> np.ndarray:
    """Tilt vector [rad] of a mast whose back supporting rope grew by ``elongation`` [m].

    The rope runs from the mast at ``attach_height`` [m] above the pivot down to a
    ground anchor behind the mast; ``rope_length`` [m] is its nominal length. The
    mast leans by the angle that lets the rope reach its new length, towards the
    horizontal direction ``toward`` (the centre of the workspace).
    """
    h, L = attach_height, rope_length
    e = np.sqrt(L * L - h * h)  # horizontal distance from the pivot back to the rope anchor
    # leaning by a towards d, the attachment is at (h sin a, h cos a) in the (d, z) plane and
    # the anchor at (-e, 0): |.|^2 = h^2 + e^2 + 2 h e sin a = (L + elongation)^2
    a = np.arcsin(np.clip(((L + elongation) ** 2 - L * L) / (2 * h * e), -1.0, 1.0))
    d = np.array([toward[0], toward[1], 0.0], dtype=float)
    d /= np.linalg.norm(d)
    return a * np.cross(np.array([0.0, 0.0, 1.0]), d)  # rotates +z towards d


def lever_arms(exits_star: np.ndarray, pivots: np.ndarray, mast_index: np.ndarray) -> np.ndarray:
    """Lever arms ``r_ij = A*_ij - O_i`` (n,3) [m]."""
    return exits_star - pivots[mast_index]


def mast_moments(r: np.ndarray, tensions: np.ndarray, u: np.ndarray, mast_index: np.ndarray,
                 n_masts: int) -> np.ndarray:
    """Moments ``M_i`` (m,3) [N m] of the cable forces about the mast pivots."""
    per_cable = -tensions[..., None] * cross(r, u)
    return mast_incidence(mast_index, n_masts) @ per_cable


def mast_incidence(mast_index: np.ndarray, n_masts: int) -> np.ndarray:
    """(m, n) 0/1 matrix summing per-cable rows into per-mast rows."""
    key = (mast_index.tobytes(), n_masts)
    S = _INCIDENCE.get(key)
    if S is None:
        S = np.zeros((n_masts, len(mast_index)))
        S[mast_index, np.arange(len(mast_index))] = 1.0
        _INCIDENCE[key] = S
    return S


_INCIDENCE: dict[tuple[bytes, int], np.ndarray] = {}


def deflect(exits_star: np.ndarray, r: np.ndarray, theta: np.ndarray,
            mast_index: np.ndarray) -> np.ndarray:
    """Displaced exit points ``A# = A* + dtheta_i x r_ij`` (n,3) [m] ((..., n, 3) for stacked
    rotations (..., m, 3))."""
    return exits_star + cross(theta[..., mast_index, :], r)


def mast_rotations(compliance: np.ndarray, r: np.ndarray, tensions: np.ndarray, u: np.ndarray,
                   mast_index: np.ndarray) -> np.ndarray:
    """Joint rotations ``dtheta_i = c_i * M_i`` (m,3) [rad] for tensions (n,) and cable
    directions u (n,3)."""
    return compliance * mast_moments(r, tensions, u, mast_index, len(compliance))
