"""Statics of a robot description: exit points, tensions and cable lengths at a pose.

The inverse problem the controller solves every cycle: for a desired pose,
the tensions (tension distribution) and the exit points (compliant masts)
depend on each other; :func:`pose_statics` solves both together by fixed-point
iteration (deflections are millimetres to centimetres against cables of metres,
so it contracts in a few steps). :func:`unstretched_lengths` turns geometric
lengths and tensions into the unstretched lengths the winches must hold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.kinematics import CableState, cable_state, gravity_wrench, wrench_matrix
from controller.masts import deflect, lever_arms, mast_rotations, settle
from controller.robot import Robot
from controller.tension import TensionResult, distribute


@dataclass(frozen=True)
class PoseStatics:
    """Statics at one pose: ``tensions`` (n,) [N]; ``exits`` A# (n,3) [m];
    ``theta`` (m,3) mast rotations [rad]; ``state`` the cable geometry with A#;
    ``feasible``/``reason`` from the tension distribution; ``iterations``."""

    tensions: np.ndarray
    exits: np.ndarray
    theta: np.ndarray
    state: CableState
    feasible: bool
    reason: str
    iterations: int


def settled_exits(robot: Robot) -> np.ndarray:
    """Exit points A* (n,3) [m]: the surveyed exits after the masts' settlement tilt."""
    return settle(robot.exits, robot.pivots, robot.mast_index, robot.tilt)


def deflected_exits(robot: Robot, tensions: np.ndarray, u: np.ndarray,
                    exits_star: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One mast update: ``(A#, theta)`` for tensions (n,) [N] and cable directions u (n,3)."""
    a_star = settled_exits(robot) if exits_star is None else exits_star
    if not robot.compliant:
        return a_star, np.zeros((robot.n_masts, 3))
    r = lever_arms(a_star, robot.pivots, robot.mast_index)
    theta = mast_rotations(robot.compliance, r, tensions, u, robot.mast_index)
    return deflect(a_star, r, theta, robot.mast_index), theta


def pose_statics(robot: Robot, pose: np.ndarray, method: str = "closed_form",
                 tensions: np.ndarray | None = None, tol: float = 1e-10,
                 max_iter: int = 50) -> PoseStatics:
    """Tensions and exit points at ``pose``, solved together.

    With ``tensions`` given (e.g. measured), only the exit points are solved
    for them; otherwise the tension distribution ``method`` computes tensions
    that balance gravity with the current exit points, iterating until the exit
    points move less than ``tol`` [m].
    """
    pose = np.asarray(pose, dtype=float)
    a_star = settled_exits(robot)
    exits = a_star
    theta = np.zeros((robot.n_masts, 3))
    result: TensionResult | None = None
    for it in range(1, max_iter + 1):
        st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
        if tensions is None:
            W = wrench_matrix(st)
            wg = gravity_wrench(robot.mass, robot.com, robot.gravity, st.R)
            result = distribute(W, wg, robot.tension_min, robot.tension_max, method)
            if not result.feasible:
                return PoseStatics(result.tensions, exits, theta, st, False, result.reason, it)
            tau = result.tensions
        else:
            tau = np.asarray(tensions, dtype=float)
        if not robot.compliant:
            return PoseStatics(tau, exits, theta, st, True, "", it)
        new_exits, theta = deflected_exits(robot, tau, st.u, a_star)
        step = float(np.abs(new_exits - exits).max())
        exits = new_exits
        if step < tol:
            st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
            return PoseStatics(tau, exits, theta, st, True, "", it)
    st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
    return PoseStatics(tau, exits, theta, st, False,
                       f"exit points did not settle in {max_iter} iterations", max_iter)


def unstretched_lengths(lengths: np.ndarray, tensions: np.ndarray, ea: np.ndarray) -> np.ndarray:
    """Unstretched lengths ``L0 = L / (1 + tau/ea)`` [m] (L0 = L for inextensible cables)."""
    return lengths / (1.0 + tensions / ea)


def elastic_tensions(lengths: np.ndarray, l0: np.ndarray, ea: np.ndarray) -> np.ndarray:
    """Tensions ``tau = ea (L - L0)/L0`` [N] of elastic cables, 0 where slack."""
    return np.where(lengths > l0, ea * (lengths - l0) / l0, 0.0)


def true_tensions(robot: Robot, measured: np.ndarray) -> np.ndarray:
    """Tensions [N] a load cell reading means under ``robot``'s calibration
    (measured = gain * true + offset)."""
    return (np.asarray(measured, dtype=float) - robot.load_cell_offset) / robot.load_cell_gain


def init_unstretched(robot: Robot, init_pose: np.ndarray,
                     init_tensions: np.ndarray | None = None,
                     method: str = "closed_form") -> tuple[np.ndarray, np.ndarray]:
    """Unstretched lengths at initialisation under ``robot``: ``d(p0, tau0)/(1 + tau0/ea)``.

    ``init_tensions`` are true tensions at p0 (None: the tension distribution).
    Returns ``(u0 (n,) [m], tau0 (n,) [N])``. Raises ValueError if p0 is infeasible.
    """
    ps = pose_statics(robot, np.asarray(init_pose, float), method=method, tensions=init_tensions)
    if not ps.feasible:
        raise ValueError(f"initialisation pose is not feasible under {robot.name}: {ps.reason}")
    return unstretched_lengths(ps.state.length, ps.tensions, robot.ea), ps.tensions


def unstretched_from_readings(robot: Robot, readings: np.ndarray, reference: np.ndarray,
                              u0: np.ndarray, length_offset: np.ndarray | None = None
                              ) -> np.ndarray:
    """Unstretched lengths [m] behind encoder readings, by the initialisation convention:
    ``L0 = s (l_meas - d_model(p0)) + u0 + dl`` (cdpr-conventions.md).

    ``readings`` (..., n) [m]; ``reference`` = d_model(p0) (n,) of the model the
    controller ran with; ``u0`` from :func:`init_unstretched` under ``robot``;
    ``s`` and ``dl`` are ``robot``'s drum scales and length offsets (or
    ``length_offset`` when given, e.g. an offset that starts at a slip).
    """
    dl = robot.length_offset if length_offset is None else length_offset
    return robot.drum_scale * (np.asarray(readings, float) - reference) + u0 + dl


def batch_statics(robot: Robot, poses: np.ndarray, tensions: np.ndarray | None = None,
                  method: str = "closed_form", tol: float = 1e-10, max_iter: int = 20,
                  exits0: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, CableState, np.ndarray]:
    """:func:`pose_statics` for N poses (N,6) at once.

    With ``tensions`` (N,n) the exit points of all poses are iterated together
    (vectorised), starting from ``exits0`` (N,n,3) when given (a warm start);
    without, each pose gets its tension distribution. Returns
    ``(tensions (N,n), exits (N,n,3), state (stacked), feasible (N,))``.
    """
    poses = np.asarray(poses, dtype=float)
    N = len(poses)
    if tensions is None:
        tau = np.full((N, robot.n_cables), np.nan)
        exits = np.empty((N, robot.n_cables, 3))
        ok = np.zeros(N, dtype=bool)
        for i in range(N):
            ps = pose_statics(robot, poses[i], method=method)
            tau[i], exits[i], ok[i] = ps.tensions, ps.exits, ps.feasible
        return tau, exits, cable_state(poses, robot.anchors, exits, robot.pulley_radius), ok
    tau = np.asarray(tensions, dtype=float)
    a_star = settled_exits(robot)
    exits = np.broadcast_to(a_star, (N,) + a_star.shape)
    if robot.compliant and exits0 is not None and exits0.shape == (N,) + a_star.shape:
        exits = exits0
    st = cable_state(poses, robot.anchors, exits, robot.pulley_radius)
    if robot.compliant:
        r = lever_arms(a_star, robot.pivots, robot.mast_index)
        for _ in range(max_iter):
            theta = mast_rotations(robot.compliance, r, tau, st.u, robot.mast_index)
            new = deflect(a_star, r, theta, robot.mast_index)
            step = float(np.abs(new - exits).max())
            exits = new
            st = cable_state(poses, robot.anchors, exits, robot.pulley_radius)
            if step < tol:
                break
    return tau, np.array(exits), st, np.isfinite(tau).all(axis=1)
