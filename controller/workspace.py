"""Wrench-feasible workspace on a grid: where gravity can be balanced within the tension limits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.robot import Robot
from controller.statics import pose_statics


@dataclass(frozen=True)
class WorkspaceGrid:
    """Feasibility on a horizontal grid at height ``z`` [m].

    ``xs`` (nx,), ``ys`` (ny,) grid coordinates [m]; ``feasible`` (nx, ny);
    ``tension_min``/``tension_max`` (nx, ny) extreme tensions at each point [N]
    (NaN where infeasible); ``step`` [m]; ``method``.
    """

    xs: np.ndarray
    ys: np.ndarray
    z: float
    feasible: np.ndarray
    tension_min: np.ndarray
    tension_max: np.ndarray
    step: float
    method: str

    @property
    def area(self) -> float:
        """Feasible footprint [m^2] (cells of ``step`` x ``step``)."""
        return float(self.feasible.sum()) * self.step**2

    @property
    def tension_range(self) -> tuple[float, float]:
        """Lowest and highest tension over the feasible points [N]."""
        if not self.feasible.any():
            return (float("nan"), float("nan"))
        return (float(np.nanmin(self.tension_min)), float(np.nanmax(self.tension_max)))


def footprint_bounds(robot: Robot, margin: float = 0.0) -> tuple[float, float, float, float]:
    """Bounding box (xmin, xmax, ymin, ymax) [m] of the exit points, grown by ``margin``."""
    a = robot.exits
    return (a[:, 0].min() - margin, a[:, 0].max() + margin,
            a[:, 1].min() - margin, a[:, 1].max() + margin)


def wrench_feasible_grid(robot: Robot, z: float = 1.0, step: float = 0.5,
                         orientation: np.ndarray | None = None,
                         method: str = "closed_form") -> WorkspaceGrid:
    """Tension feasibility of the platform at height ``z`` over the footprint (cell centres)."""
    x0, x1, y0, y1 = footprint_bounds(robot)
    xs = np.arange(x0 + step / 2, x1, step)
    ys = np.arange(y0 + step / 2, y1, step)
    rpy = np.zeros(3) if orientation is None else np.asarray(orientation, dtype=float)
    feas = np.zeros((len(xs), len(ys)), dtype=bool)
    tmin = np.full(feas.shape, np.nan)
    tmax = np.full(feas.shape, np.nan)
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            ps = pose_statics(robot, np.array([x, y, z, *rpy]), method=method)
            if ps.feasible:
                feas[i, j] = True
                tmin[i, j] = ps.tensions.min()
                tmax[i, j] = ps.tensions.max()
    return WorkspaceGrid(xs, ys, z, feas, tmin, tmax, step, method)
