"""Forward kinematics.

- :func:`forward_rigid`: inextensible cables. The pose whose geometric lengths
  best match the given lengths, in the least-squares sense over all cables
  (the paper's method: desired pose as first guess, Gauss-Newton/Levenberg-
  Marquardt with the analytic Jacobian ``-W^T``). With compliant masts the exit
  points follow the given (measured) tensions, or, without them, the tension
  distribution at the current iterate, as the paper did.
- :func:`forward_pose`: dispatches on the model: elastic cables ->
  elasto-static equilibrium (:mod:`controller.equilibrium`), otherwise rigid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.equilibrium import EquilibriumResult, solve_equilibrium
from controller.kinematics import cable_state, length_jacobian
from controller.pose import compose
from controller.robot import Robot
from controller.statics import deflected_exits, pose_statics, settled_exits


@dataclass(frozen=True)
class ForwardResult:
    """Result of a forward kinematics: ``pose`` (6,); ``tensions`` (n,) [N] (given or
    estimated; NaN if unknown); ``exits`` (n,3) [m]; ``residual`` RMS of the length
    misfit [m]; ``success``; ``message``; ``nit``."""

    pose: np.ndarray
    tensions: np.ndarray
    exits: np.ndarray
    residual: float
    success: bool
    message: str
    nit: int
    theta: np.ndarray | None = None


def forward_rigid(robot: Robot, lengths: np.ndarray, guess: np.ndarray,
                  tensions: np.ndarray | None = None, tol: float = 1e-11,
                  max_iter: int = 100, method: str = "closed_form") -> ForwardResult:
    """Pose of inextensible cables of the given geometric ``lengths`` (n,) [m], least squares."""
    lengths = np.asarray(lengths, dtype=float)
    pose = np.array(guess, dtype=float)
    a_star = settled_exits(robot)
    exits = a_star
    tau = np.full(robot.n_cables, np.nan) if tensions is None else np.asarray(tensions, float)
    lam = 1e-6
    prev_cost = np.inf
    for it in range(1, max_iter + 1):
        if robot.compliant:
            if tensions is None:
                ps = pose_statics(robot, pose, method=method)
                if not ps.feasible:
                    return ForwardResult(pose, ps.tensions, ps.exits, np.nan, False,
                                         f"forward kinematics: {ps.reason}", it)
                exits, tau = ps.exits, ps.tensions
            else:
                st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
                exits, _ = deflected_exits(robot, tau, st.u, a_star)
        st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
        e = st.length - lengths
        cost = float(e @ e)
        J = length_jacobian(st)
        H = J.T @ J
        g = J.T @ e
        dx = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -g)
        trial = compose(pose, dx)
        st_t = cable_state(trial, robot.anchors, exits, robot.pulley_radius)
        e_t = st_t.length - lengths
        if e_t @ e_t <= cost:
            pose = trial
            lam = max(lam / 10, 1e-12)
        else:
            lam *= 10
        if np.abs(dx).max() < tol and abs(prev_cost - cost) <= 1e-20 + 1e-12 * cost:
            rms = float(np.sqrt(cost / len(e)))
            return ForwardResult(pose, tau, exits, rms, True, "converged", it)
        prev_cost = cost
    rms = float(np.sqrt(prev_cost / robot.n_cables))
    return ForwardResult(pose, tau, exits, rms, False,
                         f"forward kinematics: no convergence in {max_iter} iterations "
                         f"(length RMS {rms:.3g} m)", max_iter)


def forward_pose(robot: Robot, l0: np.ndarray, guess: np.ndarray,
                 tensions: np.ndarray | None = None,
                 theta: np.ndarray | None = None) -> ForwardResult:
    """Pose reached with unstretched lengths ``l0``: equilibrium if the cables are
    elastic, least squares on the lengths if they are inextensible."""
    if robot.elastic:
        res: EquilibriumResult = solve_equilibrium(robot, l0, guess, theta)
        st = cable_state(res.pose, robot.anchors, res.exits, robot.pulley_radius)
        rms = float(np.sqrt(np.mean((st.length / (1 + res.tensions / robot.ea) - l0) ** 2)))
        return ForwardResult(res.pose, res.tensions, res.exits, rms, res.success, res.message,
                             res.nit, res.theta)
    return forward_rigid(robot, l0, guess, tensions)
