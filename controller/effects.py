"""The effect vocabulary of ``cdpr-conventions.md``: what a model can leave out.

Each effect is a parametrised extension of a robot description with physical
parameters (keys exactly as the conventions name them). :func:`apply_effects`
turns a description plus effect parameters into the description of the robot
those effects describe; the simulated plant (the truth), the diagnosis (its
hypotheses) and corrected models all go through it.

Parameter values are absolute, in the units of the conventions, except the
offsets ``dx/dy/dz`` and ``dl``, which are added to the model's values.
``cable_elasticity`` takes ``ea`` (all cables) or ``ea_{ij}``.

Two effects are errors of the measurement itself, not of the robot: ``tracker_frame``
(``rx, ry, rz`` [rad], ``tx, ty, tz`` [m]: the laser tracker's frame registered to F_b
off by a rigid motion, absolute values) and ``tracker_latency`` (``dt`` [s]: the
tracker's stream lags the drives'). :func:`tracker_to_base` and
:func:`tracker_points_to_base` take what the tracker reads to F_b through them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from controller.pose import euler_from_rotation, rotation, rotvec_matrix
from controller.robot import Robot

EFFECT_NAMES: tuple[str, ...] = (
    "exit_point_offset", "mast_compliance", "cable_elasticity", "cable_length_offset",
    "drum_scale", "load_cell_calibration", "platform_mass", "pulley_kinematics", "cable_sag",
    "tracker_frame", "tracker_latency",
)
#: the keys of ``tracker_frame`` in the order of :attr:`Robot.tracker_frame`
TRACKER_FRAME_KEYS = ("rx", "ry", "rz", "tx", "ty", "tz")


@dataclass(frozen=True)
class ParamSpec:
    """One effect parameter: ``key`` as in the conventions, ``neutral`` its no-effect value
    for this robot, ``bounds`` physical limits, ``unit``."""

    key: str
    neutral: float
    bounds: tuple[float, float]
    unit: str


def effect_params(name: str, robot: Robot) -> list[ParamSpec]:
    """Parameters of effect ``name`` for ``robot`` (neutral values from the robot)."""
    c, m = robot.cable_ids, robot.mast_ids
    if name == "exit_point_offset":
        return [ParamSpec(f"{ax}_{cid}", 0.0, (-0.5, 0.5), "m") for cid in c
                for ax in ("dx", "dy", "dz")]
    if name == "mast_compliance":
        return [ParamSpec(f"k{ax}_{mid}", float(robot.stiffness[i, a]), (1e3, 1e12), "N m/rad")
                for i, mid in enumerate(m) for a, ax in enumerate("xyz")]
    if name == "cable_elasticity":
        return [ParamSpec(f"ea_{cid}", float(robot.ea[k]), (1e3, 1e12), "N")
                for k, cid in enumerate(c)]
    if name == "cable_length_offset":
        return [ParamSpec(f"dl_{cid}", 0.0, (-1.0, 1.0), "m") for cid in c]
    if name == "drum_scale":
        return [ParamSpec(f"s_{cid}", float(robot.drum_scale[k]), (0.8, 1.25), "-")
                for k, cid in enumerate(c)]
    if name == "load_cell_calibration":
        out = []
        for k, cid in enumerate(c):
            out.append(ParamSpec(f"gain_{cid}", float(robot.load_cell_gain[k]), (0.5, 2.0), "-"))
            out.append(ParamSpec(f"offset_{cid}", float(robot.load_cell_offset[k]),
                                 (-500.0, 500.0), "N"))
        return out
    if name == "platform_mass":
        return [ParamSpec("mass", robot.mass, (0.1, 10 * robot.mass + 100), "kg")] + [
            ParamSpec(f"com_{ax}", float(robot.com[a]), (-2.0, 2.0), "m")
            for a, ax in enumerate("xyz")]
    if name == "pulley_kinematics":
        return [ParamSpec(f"r_{cid}", float(robot.pulley_radius[k]), (0.0, 1.0), "m")
                for k, cid in enumerate(c)]
    if name == "cable_sag":
        return [ParamSpec("rho", robot.rho, (0.0, 5.0), "kg/m")]
    if name == "tracker_frame":
        return [ParamSpec(k, float(robot.tracker_frame[i]), (-0.1, 0.1) if i < 3 else (-1.0, 1.0),
                          "rad" if i < 3 else "m") for i, k in enumerate(TRACKER_FRAME_KEYS)]
    if name == "tracker_latency":
        return [ParamSpec("dt", robot.tracker_latency, (-1.0, 1.0), "s")]
    raise KeyError(f"unknown effect {name!r} (known: {', '.join(EFFECT_NAMES)})")


def _cable_index(robot: Robot, key: str, prefix: str) -> int:
    cid = key[len(prefix):]
    if cid not in robot.cable_ids:
        raise KeyError(f"{key}: no cable {cid!r} (cables: {', '.join(robot.cable_ids)})")
    return robot.cable_ids.index(cid)


def apply_effects(robot: Robot, effects: Mapping[str, Mapping[str, float]],
                  name: str | None = None) -> Robot:
    """The robot that ``effects`` ({effect name: {parameter key: value}}) describe.

    Raises KeyError naming an unknown effect or parameter key.
    """
    exits = np.array(robot.exits)
    stiffness = np.array(robot.stiffness)
    ea = np.array(robot.ea)
    length_offset = np.array(robot.length_offset)
    drum = np.array(robot.drum_scale)
    gain = np.array(robot.load_cell_gain)
    offset = np.array(robot.load_cell_offset)
    radius = np.array(robot.pulley_radius)
    mass, com, rho = robot.mass, np.array(robot.com), robot.rho
    frame, latency = np.array(robot.tracker_frame), robot.tracker_latency
    for eff, params in effects.items():
        if eff not in EFFECT_NAMES:
            raise KeyError(f"unknown effect {eff!r} (known: {', '.join(EFFECT_NAMES)})")
        for key, value in params.items():
            v = float(value)
            if eff == "exit_point_offset" and key[:3] in ("dx_", "dy_", "dz_"):
                exits[_cable_index(robot, key, key[:3]), "xyz".index(key[1])] += v
            elif eff == "mast_compliance" and key[:1] == "k" and key[2:3] == "_":
                mid = key[3:]
                if mid not in robot.mast_ids or key[1] not in "xyz":
                    raise KeyError(f"{key}: not a mast stiffness key (masts: "
                                   f"{', '.join(robot.mast_ids)})")
                stiffness[robot.mast_ids.index(mid), "xyz".index(key[1])] = v
            elif eff == "cable_elasticity" and key == "ea":
                ea[:] = v
            elif eff == "cable_elasticity" and key.startswith("ea_"):
                ea[_cable_index(robot, key, "ea_")] = v
            elif eff == "cable_length_offset" and key.startswith("dl_"):
                length_offset[_cable_index(robot, key, "dl_")] += v
            elif eff == "drum_scale" and key.startswith("s_"):
                drum[_cable_index(robot, key, "s_")] = v
            elif eff == "load_cell_calibration" and key.startswith("gain_"):
                gain[_cable_index(robot, key, "gain_")] = v
            elif eff == "load_cell_calibration" and key.startswith("offset_"):
                offset[_cable_index(robot, key, "offset_")] = v
            elif eff == "platform_mass" and key == "mass":
                mass = v
            elif eff == "platform_mass" and key in ("com_x", "com_y", "com_z"):
                com["xyz".index(key[-1])] = v
            elif eff == "pulley_kinematics" and key == "r":
                radius[:] = v
            elif eff == "pulley_kinematics" and key.startswith("r_"):
                radius[_cable_index(robot, key, "r_")] = v
            elif eff == "cable_sag" and key == "rho":
                rho = v
            elif eff == "tracker_frame" and key in TRACKER_FRAME_KEYS:
                frame[TRACKER_FRAME_KEYS.index(key)] = v
            elif eff == "tracker_latency" and key == "dt":
                latency = v
            else:
                raise KeyError(f"{eff}: unknown parameter {key!r}")
    return robot.replace(
        name=name or robot.name, exits=exits, stiffness=stiffness, ea=ea,
        length_offset=length_offset, drum_scale=drum, load_cell_gain=gain,
        load_cell_offset=offset, pulley_radius=radius, mass=mass, com=com, rho=rho,
        tracker_frame=frame, tracker_latency=latency,
    )


def tracker_error(robot: Robot) -> bool:
    """Whether ``robot`` holds a tracker frame or latency error (else the tracker reads F_b
    at the drives' times, and :func:`tracker_to_base` is the identity)."""
    return bool(np.any(robot.tracker_frame != 0.0) or robot.tracker_latency != 0.0)


def tracker_to_base(robot: Robot, poses: np.ndarray, rates: np.ndarray | None = None
                    ) -> np.ndarray:
    """Platform poses (N, 6) in F_b at their time stamps from the poses the tracker read
    ``poses`` (N, 6) [m, rad] and their time derivatives ``rates`` (N, 6) [m/s, rad/s] (None:
    standing): first the latency (the pose read at ``t + dt`` is the platform's at ``t``: to
    first order ``pose + dt * rate``), then the tracker's frame (position ``R p + t``,
    orientation ``R R(rpy)``; the angles kept continuous with the read ones)."""
    p = np.array(poses, dtype=float)
    if robot.tracker_latency != 0.0 and rates is not None:
        p = p + robot.tracker_latency * np.nan_to_num(np.asarray(rates, dtype=float))
    if not np.any(robot.tracker_frame != 0.0):
        return p
    Rf = rotvec_matrix(robot.tracker_frame[:3])
    out = np.empty_like(p)
    out[..., :3] = p[..., :3] @ Rf.T + robot.tracker_frame[3:]
    rpy = euler_from_rotation(Rf @ rotation(np.atleast_2d(p[..., 3:]).reshape(-1, 3))
                              ).reshape(p[..., 3:].shape)
    out[..., 3:] = p[..., 3:] + (rpy - p[..., 3:] + np.pi) % (2 * np.pi) - np.pi
    return out


def tracker_points_to_base(robot: Robot, points: np.ndarray) -> np.ndarray:
    """Points (..., 3) in F_b from the points the tracker read (exit points): ``R x + t``."""
    x = np.asarray(points, dtype=float)
    if not np.any(robot.tracker_frame != 0.0):
        return x
    return x @ rotvec_matrix(robot.tracker_frame[:3]).T + robot.tracker_frame[3:]


def base_to_tracker(robot: Robot, poses: np.ndarray) -> np.ndarray:
    """The inverse of :func:`tracker_to_base`'s frame part: what a tracker registered as
    ``robot.tracker_frame`` reads for platform poses (N, 6) in F_b (the simulated tracker)."""
    p = np.array(poses, dtype=float)
    if not np.any(robot.tracker_frame != 0.0):
        return p
    Rt = rotvec_matrix(robot.tracker_frame[:3]).T
    out = np.empty_like(p)
    out[..., :3] = (p[..., :3] - robot.tracker_frame[3:]) @ Rt.T
    rpy = euler_from_rotation(Rt @ rotation(np.atleast_2d(p[..., 3:]).reshape(-1, 3))
                              ).reshape(p[..., 3:].shape)
    out[..., 3:] = p[..., 3:] + (rpy - p[..., 3:] + np.pi) % (2 * np.pi) - np.pi
    return out
