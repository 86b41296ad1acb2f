"""Potential energy of the platform on elastic cables hung from compliant masts.

    E = sum_j ea_j (L_j - L0_j)_+^2 / (2 L0_j)  +  m g z_G  +  sum_i theta_i^T K_i theta_i / 2

(cable strain energy, slack cables store none; gravity of the platform's
centre of mass G; mast joint springs). Sagging cables (rho > 0) store the
strain and gravity energy of their catenary instead (:mod:`controller.cables`).
Its stationary points are the elasto-static equilibria of
:mod:`controller.equilibrium` (the mast model of the conventions is
conservative: dL/dA = u, and A# is linear in theta), its minima the stable ones.
[J] for lengths in m, forces in N.
"""

from __future__ import annotations

import numpy as np

from controller import cables as cable_forces
from controller.cables import CableForces
from controller.kinematics import CableState, cable_state
from controller.masts import deflect
from controller.robot import Robot


def potential_energy(robot: Robot, pose: np.ndarray, theta: np.ndarray, l0: np.ndarray,
                     a_star: np.ndarray, r: np.ndarray, guess: CableForces | None = None
                     ) -> float:
    """E [J] at ``pose`` (6,) with mast rotations ``theta`` (m,3) [rad] and unstretched lengths
    ``l0`` (n,) [m]; ``a_star`` settled exits (n,3) and ``r`` lever arms (n,3) [m]. ``guess``:
    sagging cables hung nearly so (their catenaries' Newton starts there: the same
    solutions, sooner)."""
    exits = deflect(a_star, r, theta, robot.mast_index) if robot.compliant else a_star
    st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
    cf = cable_forces.from_lengths(robot, st, l0, guess) if robot.rho > 0 else None
    return state_energy(robot, st, pose, theta, l0, cf)


def state_energy(robot: Robot, st: CableState, pose: np.ndarray, theta: np.ndarray,
                 l0: np.ndarray, cf: CableForces | None = None) -> float:
    """E [J] from an evaluated cable state ``st`` at ``pose`` with mast rotations ``theta``
    (``cf`` the sagging cables' forces when ``rho > 0``): what :func:`potential_energy`
    returns, without evaluating the cables again."""
    cables = float(np.sum(cable_forces.energy(robot, st, l0, cf)))
    z_g = float(pose[2] + (st.R @ robot.com)[2])
    k = np.where(np.isfinite(robot.stiffness), robot.stiffness, 0.0)
    masts = 0.5 * float(np.sum(k * theta * theta))
    return cables + robot.mass * robot.gravity * z_g + masts
