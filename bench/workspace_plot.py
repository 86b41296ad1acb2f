"""The map of the wrench-feasible workspace (``cdpr model check --plots DIR``: workspace.png)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from controller.robot import Robot
from controller.workspace import WorkspaceGrid


def feasibility_boundary(grid: WorkspaceGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The feasible set as a field whose 0.5 contour is its boundary: ``(xs, ys, f)`` with
    the grid's cell centres [m] grown by one cell on each side and ``f`` (ny+2, nx+2) 1
    where feasible, 0 elsewhere (outside the swept grid too), so the contour closes; it
    runs halfway between a feasible and an infeasible cell centre."""
    s = grid.step
    xs = np.concatenate(([grid.xs[0] - s], grid.xs, [grid.xs[-1] + s]))
    ys = np.concatenate(([grid.ys[0] - s], grid.ys, [grid.ys[-1] + s]))
    f = np.zeros((len(ys), len(xs)))
    f[1:-1, 1:-1] = grid.feasible.T
    return xs, ys, f


def workspace_figure(grid: WorkspaceGrid, robot: Robot, plt):
    """The highest cable tension over the feasible points (infeasible cells grey), the
    feasibility boundary, the swept grid, the exit points; axes around all of them, the
    legend and the colour bar outside the map, the title above it on two lines."""
    from matplotlib.colors import Colormap

    fig, ax = plt.subplots(figsize=(8.5, 8.2), layout="constrained")
    h = grid.step / 2
    extent = (grid.xs[0] - h, grid.xs[-1] + h, grid.ys[0] - h, grid.ys[-1] + h)
    cmap: Colormap = plt.get_cmap("viridis").with_extremes(bad="0.85")
    data = np.where(grid.feasible, grid.tension_max, np.nan).T
    im = ax.imshow(data, origin="lower", extent=extent, cmap=cmap, aspect="equal",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="highest cable tension [N] (grey: infeasible)",
                 shrink=0.8)
    ax.plot([extent[0], extent[1], extent[1], extent[0], extent[0]],
            [extent[2], extent[2], extent[3], extent[3], extent[2]], "k:", lw=1,
            label=f"grid swept ({grid.step:g} m step; the exit points' footprint)",
            gid="swept")
    bx, by, bf = feasibility_boundary(grid)
    ax.contour(bx, by, bf, levels=[0.5], colors="tab:red", linewidths=1.8)
    ax.plot([], [], "-", color="tab:red", lw=1.8, gid="boundary_legend",
            label=f"feasibility boundary (tensions within [{robot.tension_min:g}, "
                  f"{robot.tension_max:g}] N)")
    ax.plot(robot.exits[:, 0], robot.exits[:, 1], "r^", label="exit points", gid="exits")
    for k, c in enumerate(robot.cable_ids):
        ax.annotate(c, robot.exits[k, :2], xytext=(3, 3), textcoords="offset points",
                    fontsize=8)
    pts = np.vstack([robot.exits[:, :2], [[extent[0], extent[2]], [extent[1], extent[3]]]])
    pad = 0.04 * float(np.ptp(pts, axis=0).max())
    ax.set_xlim(pts[:, 0].min() - pad, pts[:, 0].max() + pad)
    ax.set_ylim(pts[:, 1].min() - pad, pts[:, 1].max() + pad)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{robot.name}: wrench-feasible workspace at z = {grid.z:g} m\n"
                 f"{grid.area:.1f} m² feasible of {grid.feasible.size * grid.step ** 2:.1f} "
                 f"m² swept ({grid.method})")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=1, fontsize=8,
              frameon=False)
    return fig


def write_workspace_plot(grid: WorkspaceGrid, robot: Robot, path: str | Path) -> Path:
    """Draw :func:`workspace_figure` into the PNG ``path`` (parents created)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig = workspace_figure(grid, robot, plt)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p
