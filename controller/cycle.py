"""The control cycle: length setpoints for a desired pose, exit points from measured tensions.

Every cycle (Fig. 3 of the paper): the mast update moves the exit points with
the tensions measured by the load cells (or, without them, the tensions the
controller planned), then inverse kinematics, wrench matrix and the
tension distribution give the planned tensions, and the unstretched lengths
that hold the platform at the desired pose with those tensions become the
winch setpoints, expressed in the encoder reference set at initialisation
(cdpr-conventions.md).

Everything a robot description can hold is applied (controller/robot.py):

- load-cell calibration: a reading ``m`` means the true tension
  ``(m - load_cell_offset) / load_cell_gain`` (:func:`controller.statics.true_tensions`);
- per-cable ``ea``: the unstretched lengths ``L0 = d / (1 + tau/ea)``;
- the initialisation convention with ``drum_scale`` s and ``length_offset`` dl: the
  true unstretched length behind a reading ``l`` is
  ``L0 = s (l - d_model(p0)) + u0 + dl``, so the setpoint for a wanted ``L0(p)`` is
  ``l_cmd = d_model(p0) + (L0(p) - u0 - dl) / s``, with ``u0 = d(p0, tau0)/(1 + tau0/ea)``
  from the tensions tau0 measured at p0.

A measured tension that is missing, not finite, negative beyond the noise or
implausibly large (``plausible_n``), or that the caller marks invalid (a stale or
faulted load cell), never reaches the statics: the tension the controller planned in
the previous cycle replaces it (``CycleOutput.substituted`` says which).

No I/O here; the HAL brings the measurements and takes the setpoints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from controller.kinematics import cable_lengths, cable_state, gravity_wrench, wrench_matrix
from controller.masts import deflect, lever_arms, mast_rotations
from controller.robot import Robot
from controller.statics import pose_statics, settled_exits, true_tensions, unstretched_lengths
from controller.tension import distribute

_NONE = np.zeros(0, bool)


@dataclass(slots=True)
class CycleOutput:
    """One cycle's result: ``lengths`` setpoints (n,) [m] in the encoder reference;
    ``tensions`` planned (n,) [N]; ``exits`` A# used (n,3) [m]; ``feasible``;
    ``reason`` why not (then ``lengths`` holds the previous setpoints);
    ``substituted`` (n,) bool: measured tensions replaced by planned ones in the mast
    update (empty when no tensions were given)."""

    lengths: np.ndarray
    tensions: np.ndarray
    exits: np.ndarray
    feasible: bool
    reason: str = ""
    substituted: np.ndarray = field(default_factory=lambda: _NONE)


def reference_lengths(robot: Robot, init_pose: np.ndarray) -> np.ndarray:
    """Encoder reference: the model's geometric lengths ``d_model(p0)`` (n,) [m] with the
    description's exit points (no deflection, no stretch), as the conventions define."""
    return cable_lengths(np.asarray(init_pose, float), robot.anchors, robot.exits,
                         robot.pulley_radius)


def deflected_reference_lengths(robot: Robot, init_pose: np.ndarray,
                                tensions: np.ndarray | None = None) -> np.ndarray:
    """The other reading of ``d_model(p0)`` for a model with compliant masts (n,) [m]: the
    geometric lengths to the exit points the model's masts take under the tensions at
    initialisation (the load cells' readings ``tensions`` through the model's calibration,
    or its tension distribution's without them), still without stretch. The conventions
    say "the model's geometric length" and are silent on the deflection: a controller that
    models its masts' compliance may reference its encoders so. Equal to
    :func:`reference_lengths` for rigid masts and no settled tilt."""
    p0 = np.asarray(init_pose, float)
    tau = None if tensions is None else true_tensions(robot, np.asarray(tensions, float))
    ps = pose_statics(robot, p0, tensions=tau)
    return cable_lengths(p0, robot.anchors, ps.exits, robot.pulley_radius)


class LengthController:
    """Cable length setpoints for desired poses, for one robot model.

    ``init_pose``: the measured pose p0 at initialisation; ``init_tensions``: the
    tensions the load cells read there (τ0, before the model's load-cell correction),
    or None to use the tension distribution. ``plausible_n`` [N]: readings beyond it
    are sensor errors (default ten times the maximum tension, 1e5 N without one).
    """

    def __init__(self, robot: Robot, init_pose: np.ndarray, init_tensions: np.ndarray | None = None,
                 method: str = "closed_form", plausible_n: float | None = None) -> None:
        self.method = method
        if plausible_n is None:
            plausible_n = 10.0 * robot.tension_max if np.isfinite(robot.tension_max) else 1e5
        self.plausible_n = float(plausible_n)
        self._p0 = np.asarray(init_pose, dtype=float)
        self._init_readings = None if init_tensions is None else np.asarray(init_tensions, float)
        self.reference = reference_lengths(robot, self._p0)  #: d_model(p0) [m]
        self._use(robot)
        self._last = self.reference.copy()

    def _use(self, robot: Robot) -> None:
        """Take ``robot`` as the model: its constants, and ``u0`` at p0 with the readings at
        initialisation (the encoder reference :attr:`reference` is kept). Raises ValueError
        (the model in use unchanged) if the readings are not finite or p0 is infeasible."""
        p0, tau0 = self._p0, None
        if self._init_readings is not None:
            tau0 = true_tensions(robot, self._init_readings)
            if not np.all(np.isfinite(tau0)):
                raise ValueError("initialisation tensions must all be finite (got "
                                 f"{np.round(self._init_readings, 3).tolist()})")
        ps0 = pose_statics(robot, p0, method=self.method, tensions=tau0)
        if not ps0.feasible:
            raise ValueError(f"initialisation pose {p0.tolist()} is not feasible: {ps0.reason}")
        self.robot = robot
        self._a_star = settled_exits(robot)
        self._r = lever_arms(self._a_star, robot.pivots, robot.mast_index)
        # the model's constants, looked up once (the cycle runs hundreds of times a second)
        self._compliance = robot.compliance
        self._radius = robot.pulley_radius if robot.has_pulleys else None
        self._gain, self._loff = robot.load_cell_gain, robot.load_cell_offset
        self._plain_cells = bool(np.all(self._gain == 1) and np.all(self._loff == 0))
        self._compliant = robot.compliant
        self._u = ps0.state.u  # cable directions of the last cycle, for the mast update
        self._exits = ps0.exits
        self.u0 = ps0.unstretched  #: unstretched lengths at p0 [m]
        self._scale = robot.drum_scale
        self.init_tensions = ps0.tensions  #: true tensions at p0 [N]
        self._planned = ps0.tensions.copy()  # substitutes for invalid readings

    @property
    def init_pose(self) -> np.ndarray:
        """The pose p0 the encoders were referenced at (6,) [m, rad]."""
        return self._p0.copy()

    @property
    def init_readings(self) -> np.ndarray | None:
        """The load cells' readings at initialisation (n,) [N] (None: none were given)."""
        return None if self._init_readings is None else self._init_readings.copy()

    def set_model(self, robot: Robot) -> None:
        """Run with another model of the same robot from the next cycle on (an identified one,
        handed over at a bounded rate: :class:`controller.online_ident.ModelHandover`): its
        exit points, masts, cables and calibration, and its ``u0`` at p0 with the readings at
        initialisation; the encoder reference ``d_model(p0)`` stays the one the encoders were
        referenced by; the running state (the last cycle's cable directions, the planned
        tensions) is kept. Raises ValueError (the model in use unchanged) if p0 is
        infeasible."""
        if robot.cable_ids != self.robot.cable_ids or robot.mast_ids != self.robot.mast_ids:
            raise ValueError(f"model {robot.name!r}: cables/masts differ from "
                             f"{self.robot.name!r}'s")
        u, planned = self._u, self._planned
        self._use(robot)
        # the running state stays: the last cycle's cable directions (the mast update's; those
        # at p0 would move the exit points by centimetres for one cycle away from p0) and the
        # planned tensions that stand for invalid readings
        self._u, self._planned = u, planned

    def true_tensions(self, measured: np.ndarray) -> np.ndarray:
        """The model's true tensions [N] for load-cell readings (its gain and offset)."""
        return true_tensions(self.robot, measured)

    def setpoints(self, unstretched: np.ndarray) -> np.ndarray:
        """Encoder setpoints [m] that hold the unstretched lengths ``unstretched`` [m]."""
        return self.reference + (unstretched - self.u0 - self.robot.length_offset) / self._scale

    def mast_tensions(self, measured: np.ndarray,
                      valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Tensions for the mast update and the substituted mask: the readings corrected by
        the model's load-cell calibration, where valid; the last planned tensions where not
        (marked invalid, not finite, below ``-0.05·plausible_n`` or above ``plausible_n``)."""
        tau = np.asarray(measured, float) if self._plain_cells else \
            (np.asarray(measured, float) - self._loff) / self._gain
        # NaN fails both comparisons: not finite is not plausible
        ok = (tau <= self.plausible_n) & (tau >= -0.05 * self.plausible_n)
        if valid is not None:
            ok &= valid
        if np.count_nonzero(ok) == ok.size:  # ok.all(), without the reduction's overhead
            return tau, ~ok
        return np.where(ok, tau, self._planned), ~ok

    def step(self, pose: np.ndarray, measured_tensions: np.ndarray | None = None,
             valid: np.ndarray | None = None) -> CycleOutput:
        """Setpoints for the desired ``pose`` (6,), exit points from ``measured_tensions``
        (n,) [N] as the load cells read them; ``valid`` (n,) bool marks readings to use
        (None: all that are plausible)."""
        rob = self.robot
        pose = np.asarray(pose, dtype=float)
        substituted = _NONE
        if rob.rho > 0:  # sagging cables: catenaries and exit points solved together
            ps = pose_statics(rob, pose, self.method)
            if not ps.feasible:
                return CycleOutput(self._last.copy(), ps.tensions, ps.exits, False, ps.reason)
            self._planned = ps.tensions
            self._last = self.setpoints(ps.unstretched)
            return CycleOutput(self._last.copy(), ps.tensions, ps.exits, True)
        compliant = self._compliant
        if compliant and measured_tensions is not None:
            tau_m, substituted = self.mast_tensions(measured_tensions, valid)
            theta = mast_rotations(self._compliance, self._r, tau_m, self._u, rob.mast_index)
            exits = deflect(self._a_star, self._r, theta, rob.mast_index)
        else:
            exits = self._exits
        st = cable_state(pose, rob.anchors, exits, self._radius)
        W = wrench_matrix(st)
        res = distribute(W, gravity_wrench(rob.mass, rob.com, rob.gravity, st.R),
                         rob.tension_min, rob.tension_max, self.method)
        if not res.feasible:
            return CycleOutput(self._last.copy(), res.tensions, exits, False, res.reason,
                               substituted)
        if compliant and measured_tensions is None:
            # no load cells: move the exit points with the planned tensions (next cycle)
            theta = mast_rotations(self._compliance, self._r, res.tensions, st.u,
                                   rob.mast_index)
            self._exits = deflect(self._a_star, self._r, theta, rob.mast_index)
        self._u = st.u
        self._planned = res.tensions
        lengths = self.setpoints(unstretched_lengths(st.length, res.tensions, rob.ea))
        self._last = lengths
        return CycleOutput(lengths, res.tensions, exits, True, "", substituted)
