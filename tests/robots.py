"""Robots for tests: the shipped ROCASPECT and random robots of the same family."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from controller.robot import Robot, resolve_robot

PAPER_K = (2.0e5, 5.0e5, 3.0e5)


def rocaspect(compliant: bool = False, **changes) -> Robot:
    r = resolve_robot("rocaspect")
    if compliant:
        changes.setdefault("stiffness", np.tile(PAPER_K, (r.n_masts, 1)))
    return r.replace(**changes) if changes else r


@st.composite
def random_robots(draw, elastic: bool = True, compliant: bool | None = None,
                  pulleys: bool | None = None) -> Robot:
    """A 4-mast, 8-cable suspended robot with crossed cables, random sizes and perturbations."""
    Lx = draw(st.floats(8.0, 30.0))
    Ly = draw(st.floats(6.0, 25.0))
    h = draw(st.floats(3.0, 6.0))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    corners = np.array([[0, 0], [0, Ly], [Lx, Ly], [Lx, 0]], dtype=float)
    # side directions of each mast's two pulleys (low j=1, high j=2), as ROCASPECT
    side = {0: ([0, 0.55], [-0.77, 0.0]), 1: ([-0.77, 0], [0, 0.55]),
            2: ([0, -0.55], [0.77, 0]), 3: ([0.77, 0], [0, -0.55])}
    exits, pivots = [], []
    for i, c in enumerate(corners):
        d1, d2 = (np.array(v) for v in side[i])
        a1 = np.array([*(c + 0.0 * d1), h]) + rng.normal(0, 0.05, 3)
        a2 = np.array([*(c + d2 * 1.0 + d1 * 0.7), h + 0.3]) + rng.normal(0, 0.05, 3)
        exits += [a1, a2]
        pivots.append([(a1[0] + a2[0]) / 2, (a1[1] + a2[1]) / 2, 0.0])
    s = np.array(draw(st.tuples(st.floats(0.3, 0.6), st.floats(0.3, 0.6), st.floats(0.15, 0.3))))
    sign = np.array([[1, -1, -1], [-1, 1, 1], [-1, -1, -1], [1, 1, 1],
                     [-1, 1, -1], [1, -1, 1], [1, 1, -1], [-1, -1, 1]], dtype=float)
    anchors = sign * s + rng.normal(0, 0.02, (8, 3))
    if compliant is None:
        compliant = draw(st.booleans())
    if pulleys is None:
        pulleys = draw(st.booleans())
    stiff = rng.uniform(5e4, 1e6, (4, 3)) if compliant else np.full((4, 3), np.inf)
    radius = rng.uniform(0.03, 0.15, 8) if pulleys else np.zeros(8)
    ea = np.full(8, draw(st.floats(1e5, 5e6))) if elastic else np.full(8, np.inf)
    return Robot(
        name="random", cable_ids=("11", "12", "21", "22", "31", "32", "41", "42"),
        mast_ids=("1", "2", "3", "4"), exits=np.array(exits), anchors=anchors,
        mast_index=np.repeat(np.arange(4), 2), pivots=np.array(pivots), stiffness=stiff,
        pulley_radius=radius, ea=ea, mass=draw(st.floats(10.0, 80.0)),
        com=rng.normal(0, 0.03, 3), gravity=9.81, tension_min=5.0, tension_max=5000.0,
    )


def inner_pose(draw, robot: Robot, margin: float = 0.3) -> np.ndarray:
    """A pose in the central part of the footprint, small orientation."""
    a = robot.exits
    x0, x1 = a[:, 0].min(), a[:, 0].max()
    y0, y1 = a[:, 1].min(), a[:, 1].max()
    fx = draw(st.floats(margin, 1 - margin))
    fy = draw(st.floats(margin, 1 - margin))
    z = draw(st.floats(0.6, a[:, 2].min() - 1.5))
    ang = draw(st.tuples(*[st.floats(-0.05, 0.05)] * 3))
    return np.array([x0 + fx * (x1 - x0), y0 + fy * (y1 - y0), z, *ang])
