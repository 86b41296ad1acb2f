"""The control cycle: length setpoints for a desired pose, exit points from measured tensions.

Every cycle (Fig. 3 of the paper): the mast update moves the exit points with
the tensions measured by the load cells (or, without them, the tensions the
controller planned), then inverse kinematics, wrench matrix and the
tension distribution give the planned tensions, and the unstretched lengths
that hold the platform at the desired pose with those tensions become the
winch setpoints, expressed in the encoder reference set at initialisation
(cdpr-conventions.md): ``l_cmd = L0(p) - L0(p0) + d_model(p0)``.

No I/O here; the HAL brings the measurements and takes the setpoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.kinematics import cable_lengths, cable_state, gravity_wrench, wrench_matrix
from controller.masts import deflect, lever_arms, mast_rotations
from controller.robot import Robot
from controller.statics import pose_statics, settled_exits, unstretched_lengths
from controller.tension import distribute


@dataclass(frozen=True)
class CycleOutput:
    """One cycle's result: ``lengths`` setpoints (n,) [m] in the encoder reference;
    ``tensions`` planned (n,) [N]; ``exits`` A# used (n,3) [m]; ``feasible``;
    ``reason`` why not (then ``lengths`` holds the previous setpoints)."""

    lengths: np.ndarray
    tensions: np.ndarray
    exits: np.ndarray
    feasible: bool
    reason: str = ""


def reference_lengths(robot: Robot, init_pose: np.ndarray) -> np.ndarray:
    """Encoder reference: the model's geometric lengths ``d_model(p0)`` (n,) [m] with the
    description's exit points (no deflection, no stretch), as the conventions define."""
    return cable_lengths(np.asarray(init_pose, float), robot.anchors, robot.exits,
                         robot.pulley_radius)


class LengthController:
    """Cable length setpoints for desired poses, for one robot model.

    ``init_pose``: the measured pose p0 at initialisation; ``init_tensions``: the
    tensions measured there (τ0), or None to use the tension distribution.
    """

    def __init__(self, robot: Robot, init_pose: np.ndarray, init_tensions: np.ndarray | None = None,
                 method: str = "closed_form") -> None:
        self.robot = robot
        self.method = method
        self._a_star = settled_exits(robot)
        self._r = lever_arms(self._a_star, robot.pivots, robot.mast_index)
        p0 = np.asarray(init_pose, dtype=float)
        ps0 = pose_statics(robot, p0, method=method, tensions=init_tensions)
        if not ps0.feasible:
            raise ValueError(f"initialisation pose {p0.tolist()} is not feasible: {ps0.reason}")
        self._u = ps0.state.u  # cable directions of the last cycle, for the mast update
        self._exits = ps0.exits
        u0 = ps0.unstretched
        self._offset = reference_lengths(robot, p0) - u0
        self._last = u0 + self._offset
        self.init_tensions = ps0.tensions

    def step(self, pose: np.ndarray, measured_tensions: np.ndarray | None = None) -> CycleOutput:
        """Setpoints for the desired ``pose`` (6,), exit points from ``measured_tensions`` (n,)."""
        rob = self.robot
        pose = np.asarray(pose, dtype=float)
        if rob.rho > 0:  # sagging cables: catenaries and exit points solved together
            ps = pose_statics(rob, pose, self.method)
            if not ps.feasible:
                return CycleOutput(self._last.copy(), ps.tensions, ps.exits, False, ps.reason)
            self._last = ps.unstretched + self._offset
            return CycleOutput(self._last.copy(), ps.tensions, ps.exits, True)
        if rob.compliant and measured_tensions is not None:
            theta = mast_rotations(rob.compliance, self._r, measured_tensions, self._u,
                                   rob.mast_index)
            exits = deflect(self._a_star, self._r, theta, rob.mast_index)
        else:
            exits = self._exits
        st = cable_state(pose, rob.anchors, exits, rob.pulley_radius)
        W = wrench_matrix(st)
        res = distribute(W, gravity_wrench(rob.mass, rob.com, rob.gravity, st.R),
                         rob.tension_min, rob.tension_max, self.method)
        if not res.feasible:
            return CycleOutput(self._last.copy(), res.tensions, exits, False, res.reason)
        if rob.compliant and measured_tensions is None:
            # no load cells: move the exit points with the planned tensions (next cycle)
            theta = mast_rotations(rob.compliance, self._r, res.tensions, st.u, rob.mast_index)
            self._exits = deflect(self._a_star, self._r, theta, rob.mast_index)
        self._u = st.u
        lengths = unstretched_lengths(st.length, res.tensions, rob.ea) + self._offset
        self._last = lengths
        return CycleOutput(lengths, res.tensions, exits, True)
