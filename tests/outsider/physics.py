"""Straight-cable statics of a robot.toml, read with tomllib (docs/formats/robot.md).

Frames: F_b (base, z up) and F_p (platform); a pose is (x, y, z, roll, pitch, yaw) [m, rad],
R = Rz(yaw) Ry(pitch) Rx(roll) (docs/explanation/conventions.md).
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Robot:
    """What the outsider's physics needs of a robot.toml (SI units)."""

    ids: tuple[str, ...]
    exits: np.ndarray        # (n, 3) A_ij in F_b [m]
    anchors: np.ndarray      # (n, 3) B_ij in F_p [m]
    mass: float              # [kg]
    com: np.ndarray          # (3,) in F_p [m]
    gravity: float           # [m/s^2]
    ea: float | None         # E*A [N], None: inextensible
    tension_min: float       # [N]
    tension_max: float       # [N]

    def with_exit_moved(self, cable: str, delta_m: np.ndarray) -> Robot:
        """The same robot with one exit point moved by `delta_m` [m] in F_b."""
        exits = self.exits.copy()
        exits[self.ids.index(cable)] += delta_m
        return replace(self, exits=exits)


def load_robot(path: Path) -> Robot:
    """Read the fields of a robot.toml this physics uses; refuse what it cannot model."""
    doc = tomllib.loads(Path(path).read_text())
    cables = doc["cable"]
    for c in cables:
        if c.get("pulley_radius", 0.0) or "ea" in c:
            raise ValueError(f"{path}: cable {c['id']}: pulleys / per-cable ea not modelled")
    if any("stiffness" in m for m in doc["mast"]):
        raise ValueError(f"{path}: compliant masts not modelled")
    return Robot(
        ids=tuple(str(c["id"]) for c in cables),
        exits=np.array([c["exit"] for c in cables], float),
        anchors=np.array([c["anchor"] for c in cables], float),
        mass=float(doc["platform"]["mass"]),
        com=np.array(doc["platform"].get("com", [0.0, 0.0, 0.0]), float),
        gravity=float(doc.get("gravity", 9.81)),
        ea=doc["cables"].get("ea"),
        tension_min=float(doc["cables"]["tension_min"]),
        tension_max=float(doc["cables"]["tension_max"]),
    )


def rotations(poses: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for each pose row (k, 6) -> (k, 3, 3)."""
    r, p, y = poses[:, 3], poses[:, 4], poses[:, 5]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out = np.empty((len(poses), 3, 3))
    out[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], 1)
    out[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], 1)
    out[:, 2] = np.stack([-sp, cp * sr, cp * cr], 1)
    return out


def cable_vectors(robot: Robot, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cable vectors a - t - R b (k, n, 3) [m] and the rotated anchors R b (k, n, 3)."""
    rb = np.einsum("kij,nj->kni", rotations(poses), robot.anchors)
    return robot.exits[None] - poses[:, None, :3] - rb, rb


def lengths(robot: Robot, poses: np.ndarray) -> np.ndarray:
    """Straight-line lengths |a - t - R b| (k, n) [m]."""
    return np.linalg.norm(cable_vectors(robot, poses)[0], axis=2)


def tensions(robot: Robot, poses: np.ndarray, pretension_n: float) -> np.ndarray:
    """Tensions (k, n) [N] balancing the platform's weight, closest to `pretension_n` each.

    The solution of W tau = -w_g nearest (least norm) to a uniform pretension: tau =
    tau_ref + W^+ (-w_g - W tau_ref).
    """
    vec, rb = cable_vectors(robot, poses)
    u = vec / np.linalg.norm(vec, axis=2, keepdims=True)
    w = np.concatenate([u, np.cross(rb, u)], axis=2).transpose(0, 2, 1)  # (k, 6, n)
    mg = np.array([0.0, 0.0, -robot.mass * robot.gravity])
    rc = np.einsum("kij,j->ki", rotations(poses), robot.com)
    wg = np.concatenate([np.broadcast_to(mg, rc.shape), np.cross(rc, mg)], axis=1)
    ref = np.full(len(robot.ids), pretension_n)
    rhs = -wg - w @ ref
    return ref + np.einsum("kij,kj->ki", np.linalg.pinv(w), rhs)


def unstretched(robot: Robot, d: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Unstretched lengths L0 = d / (1 + tau/ea) [m] (d itself for inextensible cables)."""
    return d if robot.ea is None else d / (1.0 + tau / robot.ea)
