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

from controller import cables
from controller.cables import CableForces
from controller.kinematics import CableState, cable_state, gravity_wrench, wrench_matrix
from controller.masts import deflect, lever_arms, mast_rotations
from controller.pose import cross, rotation
from controller.robot import Robot
from controller.tension import TensionResult, closed_form, distribute


@dataclass(frozen=True)
class PoseStatics:
    """Statics at one pose: ``tensions`` (n,) [N] at the exit ends (what the load cells
    read); ``exits`` A# (n,3) [m]; ``theta`` (m,3) mast rotations [rad]; ``state`` the
    cable geometry with A#; ``unstretched`` (n,) [m] the unstretched lengths that hang the
    platform so; ``forces`` the cable forces (sagging cables); ``feasible``/``reason``
    from the tension distribution; ``iterations``."""

    tensions: np.ndarray
    exits: np.ndarray
    theta: np.ndarray
    state: CableState
    feasible: bool
    reason: str
    iterations: int
    unstretched: np.ndarray | None = None
    forces: CableForces | None = None


def settled_exits(robot: Robot) -> np.ndarray:
    """Exit points A* (n,3) [m]: the surveyed exits after the masts' settlement tilt
    (read-only, :attr:`~controller.robot.Robot.exits_settled`)."""
    return robot.exits_settled


def deflected_exits(robot: Robot, tensions: np.ndarray, u: np.ndarray,
                    exits_star: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One mast update: ``(A#, theta)`` for exit tensions (n,) [N] and the directions u (n,3)
    in which the cables leave their exit points."""
    a_star = settled_exits(robot) if exits_star is None else exits_star
    if not robot.compliant:
        return a_star, np.zeros((robot.n_masts, 3))
    r = lever_arms(a_star, robot.pivots, robot.mast_index)
    theta = mast_rotations(robot.compliance, r, tensions, u, robot.mast_index)
    return deflect(a_star, r, theta, robot.mast_index), theta


def pose_statics(robot: Robot, pose: np.ndarray, method: str = "closed_form",
                 tensions: np.ndarray | None = None, tol: float = 1e-10,
                 max_iter: int = 50, forces0: CableForces | None = None,
                 exits0: np.ndarray | None = None) -> PoseStatics:
    """Tensions and exit points at ``pose``, solved together.

    With ``tensions`` given (measured at the exit ends), only the exit points are
    solved for them; otherwise the tension distribution ``method`` computes
    tensions that balance gravity with the current exit points, iterating until
    the exit points move less than ``tol`` [m]. Sagging cables (``rho > 0``) pull
    the platform along their catenary's end tangents, iterated together; the
    tensions stay closest to the distribution the straight cables would have
    (otherwise the internal forces drift from one iteration to the next).
    ``forces0``: with ``tensions`` given, sagging cables hung nearly so (e.g.
    :attr:`PoseStatics.forces` of a nearby robot): the catenaries start there; ``exits0``
    (n,3), with ``tensions`` given, the exit points the masts' iteration starts from (a warm
    start: the same solution to ``tol``).
    """
    pose = np.asarray(pose, dtype=float)
    a_star = settled_exits(robot)
    exits = a_star
    if tensions is not None and robot.compliant and exits0 is not None \
            and np.shape(exits0) == a_star.shape and np.isfinite(exits0).all():
        exits = np.asarray(exits0, dtype=float)
    theta = np.zeros((robot.n_masts, 3))
    sag = robot.rho > 0
    if sag:  # slack-ish heavy cables contract slowly; 1e-9 of direction is 1e-7 of force
        max_iter = max(max_iter, 400)
    turn_tol = 1e-9
    tmin = robot.tension_min
    if sag:  # keep every cable above its own weight, or its end would swing down
        d0 = cable_state(pose, robot.anchors, a_star, robot.pulley_radius).length
        tmin = max(tmin, robot.rho * robot.gravity * float(d0.max()))
    dirs = None
    target = None  # sagging cables: tensions closest to the straight cables' distribution
    result: TensionResult | None = None
    cf: CableForces | None = forces0 if tensions is not None and sag else None
    st = None  # the platform side of the geometry is the same at every iteration
    for it in range(1, max_iter + 1):
        st = cable_state(pose, robot.anchors, exits, robot.pulley_radius, st)
        d = st.u if dirs is None else dirs
        if tensions is None:
            W = wrench_matrix(st) if not sag else np.vstack([d.T, cross(st.Rb, d).T])
            wg = gravity_wrench(robot.mass, robot.com, robot.gravity, st.R)
            if target is None:
                result = distribute(W, wg, tmin, robot.tension_max, method)
                if sag and result.feasible:
                    target = result.tensions
            else:
                # the straight cables' internal forces anchor the iteration of directions
                result = closed_form(W, -wg, tmin, robot.tension_max, target)
                if not result.feasible:
                    result = distribute(W, wg, tmin, robot.tension_max, "qp")
            if not result.feasible:
                return PoseStatics(result.tensions, exits, theta, st, False, result.reason, it)
            tau = result.tensions
            if sag:
                cf, l0 = cables.from_platform_tensions(robot, st, tau)
        else:
            tau = np.asarray(tensions, dtype=float)
            if sag:
                cf, l0 = cables.from_tensions(robot, st, tau, cf)
        if sag:
            new_dirs = cables.platform_directions(robot, st, cf)
            turn = 0.0 if dirs is None else float(np.abs(new_dirs - dirs).max())
            if dirs is not None and it > 8:  # damped: clipping can make it cycle
                new_dirs = 0.5 * (new_dirs + dirs)
                new_dirs /= np.linalg.norm(new_dirs, axis=1, keepdims=True)
            dirs = new_dirs
            tau_exit, u_exit = cf.tension, cf.exit / cf.tension[:, None]
        else:
            turn, tau_exit, u_exit = 0.0, tau, st.u
        if not robot.compliant:
            # given tensions hang the cables the same way whatever the directions: nothing
            # to iterate
            if not sag or tensions is not None or (turn < turn_tol and it > 1):
                # given tensions: the sagging cables were just hung at them from these exits
                return _done(robot, st, exits, theta, tau_exit, cf, it,
                             l0 if sag and tensions is not None else None)
            continue
        new_exits, theta = deflected_exits(robot, tau_exit, u_exit, a_star)
        step = float(np.abs(new_exits - exits).max())
        exits = new_exits
        if step < tol and turn < turn_tol:
            st = cable_state(pose, robot.anchors, exits, robot.pulley_radius, st)
            if sag:  # forces for the final exit points
                cf, _ = (cables.from_tensions(robot, st, tau_exit, cf) if tensions is not None
                         else cables.from_platform_tensions(robot, st, tau))
            return _done(robot, st, exits, theta, tau_exit, cf, it)
    st = cable_state(pose, robot.anchors, exits, robot.pulley_radius, st)
    return PoseStatics(tau, exits, theta, st, False,
                       f"exit points did not settle in {max_iter} iterations", max_iter)


def _done(robot: Robot, st: CableState, exits: np.ndarray, theta: np.ndarray,
          tau_exit: np.ndarray, cf: CableForces | None, it: int,
          l0: np.ndarray | None = None) -> PoseStatics:
    """``l0``: the unstretched lengths of ``cf`` when they were solved at ``st`` already (kept
    where every catenary converged; otherwise solved again at the tensions they reached)."""
    if l0 is not None and cf is not None and cf.converged is not None and cf.converged.all():
        pass
    elif cf is None:
        l0 = unstretched_lengths(st.length, tau_exit, robot.ea)
    else:
        l0 = cables.from_tensions(robot, st, cf.tension, cf)[1]
    return PoseStatics(tau_exit, exits, theta, st, True, "", it, l0, cf)


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


def weight_between_ends(robot: Robot, poses: np.ndarray) -> np.ndarray:
    """(..., n) [N] how much more a sagging cable pulls at its exit point than at its
    platform anchor at ``poses`` (..., 6): along a catenary the tension grows with height by
    the cable's weight per length, ``T_A - T_B = rho g (z_A - z_B)`` exactly (elastic or
    not). Exit heights are the settled ones (a mast's deflection moves them by centimetres:
    a fraction of a newton); zero without sag. For load cells at the platform end."""
    poses = np.asarray(poses, dtype=float)
    if robot.rho <= 0:
        return np.zeros(poses.shape[:-1] + (robot.n_cables,))
    R = rotation(poses[..., 3:])
    zb = poses[..., 2:3] + np.einsum("...j,nj->...n", R[..., 2, :], robot.anchors)
    return robot.rho * robot.gravity * (settled_exits(robot)[:, 2] - zb)


def init_unstretched(robot: Robot, init_pose: np.ndarray,
                     init_tensions: np.ndarray | None = None,
                     method: str = "closed_form") -> tuple[np.ndarray, np.ndarray]:
    """Unstretched lengths at initialisation under ``robot``: ``d(p0, tau0)/(1 + tau0/ea)``.

    ``init_tensions`` are true tensions at p0 (None: the tension distribution).
    Returns ``(u0 (n,) [m], tau0 (n,) [N])``. Raises ValueError if p0 is infeasible.
    """
    ps = init_statics(robot, init_pose, init_tensions, method)
    return ps.unstretched, ps.tensions


def init_statics(robot: Robot, init_pose: np.ndarray, init_tensions: np.ndarray | None = None,
                 method: str = "closed_form", forces0: CableForces | None = None,
                 exits0: np.ndarray | None = None) -> PoseStatics:
    """The statics behind :func:`init_unstretched` (``unstretched`` is ``u0``; ``forces0`` and
    ``exits0`` as in :func:`pose_statics`). Raises ValueError if p0 is infeasible."""
    ps = pose_statics(robot, np.asarray(init_pose, float), method=method, tensions=init_tensions,
                      forces0=forces0, exits0=exits0)
    if not ps.feasible:
        raise ValueError(f"initialisation pose is not feasible under {robot.name}: {ps.reason}")
    return ps


def internal_basis(W: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, n - rank W) of the wrench matrix's null space: the tension
    changes that leave the platform's wrench unchanged (internal forces)."""
    _, sv, vt = np.linalg.svd(W)
    rank = int(np.sum(sv > 1e-10 * sv[0]))
    return vt[rank:].T.copy()


def pretensioned(robot: Robot, init_pose: np.ndarray, internal: np.ndarray,
                 basis: np.ndarray) -> np.ndarray:
    """Tensions [N] at initialisation other than the tension distribution's: ``robot``'s
    distribution at ``init_pose`` plus the internal forces ``basis @ internal`` (``basis``
    (n, k) [-], ``internal`` (k,) [N]) projected on the null space of the wrench matrix
    there (so a basis of a nearby robot's serves, and the forces vary smoothly with the
    robot), at least zero. Raises ValueError if ``init_pose`` is infeasible.

    What the real tensions were when the encoders were referenced is only known where load
    cells read them: a controller's pretension (its own tension distribution, an operator's
    setting) makes them any balanced set."""
    ps = init_statics(robot, init_pose)
    W = wrench_matrix(ps.state)
    extra = basis @ np.asarray(internal, dtype=float)
    extra = extra - np.linalg.pinv(W) @ (W @ extra)
    return np.maximum(ps.tensions + extra, 0.0)


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
                  exits0: np.ndarray | None = None,
                  forces0: CableForces | None = None) -> BatchStatics:
    """:func:`pose_statics` for N poses (N,6) at once.

    With ``tensions`` (N,n) measured at the exit ends, the exit points of all poses
    are iterated together (vectorised), starting from ``exits0`` (N,n,3) when given
    (a warm start); without, each pose gets its tension distribution. ``forces0``: sagging
    cables hung nearly so (e.g. :attr:`BatchStatics.forces` of nearby hypotheses or
    poses): the catenaries' Newton iterations start there (the same solutions, sooner).
    """
    poses = np.asarray(poses, dtype=float)
    N, n = len(poses), robot.n_cables
    if tensions is None:
        tau = np.full((N, n), np.nan)
        exits = np.empty((N, n, 3))
        ok = np.zeros(N, dtype=bool)
        l0 = np.full((N, n), np.nan)
        for i in range(N):
            ps = pose_statics(robot, poses[i], method=method)
            tau[i], exits[i], ok[i] = ps.tensions, ps.exits, ps.feasible
            if ps.feasible:
                l0[i] = ps.unstretched
        st = cable_state(poses, robot.anchors, exits, robot.pulley_radius)
        cf = cables.from_tensions(robot, st, np.nan_to_num(tau, nan=1.0))[0] \
            if robot.rho > 0 else None
        return BatchStatics(tau, exits, st, ok, l0, _platform_forces(st, tau, cf))
    tau = np.asarray(tensions, dtype=float)
    a_star = settled_exits(robot)
    exits = np.broadcast_to(a_star, (N,) + a_star.shape)
    if robot.compliant and exits0 is not None and exits0.shape == (N,) + a_star.shape:
        exits = exits0
    st = cable_state(poses, robot.anchors, exits, robot.pulley_radius)
    cf, l0 = cables.from_tensions(robot, st, tau, forces0)
    if robot.compliant:
        r = lever_arms(a_star, robot.pivots, robot.mast_index)
        last = np.inf
        for _ in range(max_iter):
            u_exit = st.u if robot.rho <= 0 else cf.exit / cf.tension[..., None]
            theta = mast_rotations(robot.compliance, r, tau, u_exit, robot.mast_index)
            new = deflect(a_star, r, theta, robot.mast_index)
            step = float(np.abs(new - exits).max())
            exits = new
            st = cable_state(poses, robot.anchors, exits, robot.pulley_radius, st)
            cf, l0 = cables.from_tensions(robot, st, tau, cf)
            # a contraction (the masts' rotations move the cables' directions by about a
            # thousandth of themselves): what is left after a step is about the step times
            # the ratio of the last two steps; stop when that is within ``tol``
            ratio = step / last if np.isfinite(last) and last > 0 else 1.0
            if step < tol or (ratio < 0.5 and step * ratio / (1.0 - ratio) < tol):
                break
            last = step
    return BatchStatics(tau, np.array(exits), st, np.isfinite(tau).all(axis=1), l0,
                        _platform_forces(st, tau, cf), cf if robot.rho > 0 else None)


def _platform_forces(st: CableState, tau: np.ndarray, cf: CableForces | None) -> np.ndarray:
    return cf.platform if cf is not None else tau[..., None] * st.u


@dataclass(frozen=True)
class BatchStatics:
    """Statics of N poses: ``tensions`` (N,n) at the exit ends [N]; ``exits`` (N,n,3);
    ``state`` (stacked); ``feasible`` (N,); ``unstretched`` (N,n) [m] the lengths that hang
    the platform so; ``platform_forces`` (N,n,3) [N] the cable forces on the platform."""

    tensions: np.ndarray
    exits: np.ndarray
    state: CableState
    feasible: np.ndarray
    unstretched: np.ndarray
    platform_forces: np.ndarray
    #: sagging cables hung at the measured tensions (a warm start for nearby solutions)
    forces: CableForces | None = None
