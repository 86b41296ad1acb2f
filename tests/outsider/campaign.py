"""A campaign's truth: dwells at poses joined by minimum-jerk moves, and what sensors read.

Readings follow docs/explanation/conventions.md (cable lengths and initialisation): the
encoder reading is the unstretched length's change since initialisation plus the model's
geometric length at init_pose; a concealed `cable_length_offset` dl (a slip after
initialisation) makes the true L0 = reading-derived L0 + dl.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tests.outsider.physics import Robot, lengths, tensions, unstretched

MAX_ACC_M_S2 = 0.08    # peak acceleration of a move (quasi-static)
MAX_VEL_M_S = 0.3      # peak speed of a move


@dataclass(frozen=True)
class Campaign:
    """Targets visited in order; the platform stands `dwell_s` at each [m, rad, s]."""

    init_pose: np.ndarray
    targets: np.ndarray            # (m, 6)
    init_s: float = 6.0
    dwell_s: float = 5.0
    segments: list = field(default_factory=list, compare=False)

    def __post_init__(self) -> None:
        t, here = 0.0, self.init_pose
        self.segments.append((t, t + self.init_s, here, here))
        t += self.init_s
        for target in self.targets:
            dist = float(np.linalg.norm(target[:3] - here[:3]))
            move = max(np.sqrt(5.77 * dist / MAX_ACC_M_S2), 1.875 * dist / MAX_VEL_M_S, 3.0)
            self.segments.append((t, t + move, here, target))
            self.segments.append((t + move, t + move + self.dwell_s, target, target))
            t, here = t + move + self.dwell_s, target

    @property
    def duration_s(self) -> float:
        return self.segments[-1][1]

    def poses(self, t: np.ndarray) -> np.ndarray:
        """True poses (k, 6) at times t [s from the campaign's start]."""
        t = np.clip(t, 0.0, self.duration_s)  # (a jittered clock may tick before 0)
        out = np.empty((len(t), 6))
        for t0, t1, a, b in self.segments:
            sel = (t >= t0) & (t <= t1)
            s = np.clip((t[sel] - t0) / (t1 - t0), 0.0, 1.0)
            s = 10 * s**3 - 15 * s**4 + 6 * s**5
            out[sel] = a + s[:, None] * (b - a)
        return out


def feasible_grid(robot: Robot, rng: np.random.Generator, pretension_n: float,
                  count: int, box: tuple) -> np.ndarray:
    """`count` random poses in `box` ((lo xyz), (hi xyz), max angle rad) with tensions in range."""
    lo, hi, ang = box
    out: list[np.ndarray] = []
    while len(out) < count:
        p = np.concatenate([rng.uniform(lo, hi), rng.uniform(-ang, ang, 3)])
        tau = tensions(robot, p[None], pretension_n)[0]
        if tau.min() > robot.tension_min * 1.5 and tau.max() < robot.tension_max * 0.8:
            out.append(p)
    return np.array(out)


@dataclass(frozen=True)
class Truth:
    """What the sensors see, noise-free, at given times."""

    lengths_read: np.ndarray   # encoder readings (k, n) [m]
    tensions: np.ndarray       # true tensions (k, n) [N]
    poses: np.ndarray          # true poses (k, 6)


def readings(model: Robot, true: Robot, campaign: Campaign, t: np.ndarray,
             pretension_n: float, length_offset_m: np.ndarray,
             slip_at_s: float | None = None) -> Truth:
    """Noise-free readings at times t [s]; `true` is the real robot, `model` the toml's.

    The length offset appears at `slip_at_s` (default: half-way through the first move)."""
    poses = campaign.poses(t)
    tau = tensions(true, poses, pretension_n)
    l0 = unstretched(true, lengths(true, poses), tau)
    p0 = campaign.init_pose[None]
    l0_init = unstretched(true, lengths(true, p0), tensions(true, p0, pretension_n))[0]
    read = l0 - l0_init + lengths(model, p0)[0]
    if slip_at_s is None:
        slip_at_s = 0.5 * (campaign.segments[1][0] + campaign.segments[1][1])
    slipped = t > slip_at_s
    read[slipped] -= length_offset_m
    return Truth(lengths_read=read, tensions=tau, poses=poses)
