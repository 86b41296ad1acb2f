"""``cdpr model check|show NAME|PATH``: load a robot description and check it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # heavy imports happen in the functions (cdpr --help stays fast)
    import numpy as np

    from controller.robot import Robot

NAME = "model"
HELP = "check or show a robot description (shipped name such as 'rocaspect', or a robot.toml path)"

#: The paper's hand-tuned mast stiffness [N m/rad] (section 3.4), used to show deflections
#: when a description has rigid masts.
PAPER_STIFFNESS = (2.0e5, 5.0e5, 3.0e5)
#: Workspace grid points at most (a 2 cm step over a 20 x 20 m footprint)
MAX_GRID_POINTS = 1e6
#: Platform positions of the paper's Table 2 and its remeasurement pose [m].
CHECK_POSITIONS = ((10.0, 8.56, 1.0), (4.5, 4.5, 1.0), (4.5, 12.5, 1.0), (15.5, 12.5, 1.0),
                   (15.5, 4.5, 1.0))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=("check", "show"), help="check: validate and analyse; "
                   "show: print the description")
    p.add_argument("robot",
                   help="shipped name (rocaspect, rocaspect-remeasured) or robot.toml path")
    p.add_argument("--height", type=float, default=1.0, help="workspace height z [m] (default 1)")
    p.add_argument("--step", type=float, default=0.5, help="workspace grid step [m] (default 0.5)")
    p.add_argument("--method", default="closed_form", choices=("closed_form", "qp"),
                   help="tension distribution (default closed_form)")
    p.add_argument("--plots", metavar="DIR", default=None,
                   help="write PNG plots into DIR: workspace.png, the map of the "
                        "wrench-feasible workspace")
    p.add_argument("--plot", metavar="PNG", default=None,
                   help="deprecated spelling: the workspace map into this PNG file (use "
                        "--plots DIR)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")


def describe(robot: Robot) -> dict:
    """The description as plain data (ids, geometry, limits)."""
    import numpy as np

    return {
        "name": robot.name,
        "source": robot.source,
        "mass_kg": robot.mass,
        "com_m": robot.com.tolist(),
        "gravity": robot.gravity,
        "tension_min_n": robot.tension_min,
        "tension_max_n": robot.tension_max,
        "ea_n": [None if not np.isfinite(v) else float(v) for v in robot.ea],
        "masts": [{"id": m, "pivot": robot.pivots[i].tolist(),
                   "stiffness": [None if not np.isfinite(k) else float(k)
                                 for k in robot.stiffness[i]]}
                  for i, m in enumerate(robot.mast_ids)],
        "cables": [{"id": c, "mast": robot.mast_ids[robot.mast_index[k]],
                    "exit": robot.exits[k].tolist(), "anchor": robot.anchors[k].tolist(),
                    "pulley_radius": float(robot.pulley_radius[k])}
                   for k, c in enumerate(robot.cable_ids)],
    }


def platform_stiffness_min(robot: Robot, pose: np.ndarray, tensions: np.ndarray,
                           lengths: np.ndarray) -> float | None:
    """Smallest eigenvalue of the symmetric part of the platform stiffness (translational
    block, N/m), or None for inextensible cables."""
    import numpy as np

    from controller.equilibrium import residual_and_jacobian
    from controller.statics import unstretched_lengths

    if not robot.elastic:
        return None
    l0 = unstretched_lengths(lengths, tensions, robot.ea)
    _, J = residual_and_jacobian(robot.replace(stiffness=np.full((robot.n_masts, 3), np.inf)),
                                 pose, np.zeros((robot.n_masts, 3)), l0)
    K = -J[:6, :6]
    # scale rotations by 1 m so the blocks are comparable
    Ks = 0.5 * (K + K.T)
    return float(np.linalg.eigvalsh(Ks).min())


def check(robot: Robot, height: float, step: float, method: str) -> dict:
    """Workspace feasibility, tension range and mast deflections at the check positions."""
    import numpy as np

    from controller.statics import pose_statics, settled_exits
    from controller.workspace import wrench_feasible_grid

    grid = wrench_feasible_grid(robot, z=height, step=step, method=method)
    shown = robot
    stiffness_source = "description"
    if not robot.compliant:
        shown = robot.replace(stiffness=np.tile(PAPER_STIFFNESS, (robot.n_masts, 1)))
        stiffness_source = "paper (description has rigid masts)"
    a_star = settled_exits(shown)
    poses = []
    for pos in CHECK_POSITIONS:
        pose = np.array([*pos, 0.0, 0.0, 0.0])
        ps = pose_statics(shown, pose, method=method)
        entry = {"position_m": list(pos), "feasible": ps.feasible, "reason": ps.reason}
        if ps.feasible:
            disp = np.linalg.norm(ps.exits - a_star, axis=1)
            entry["tensions_n"] = dict(zip(robot.cable_ids, np.round(ps.tensions, 2).tolist(),
                                           strict=True))
            entry["exit_displacement_m"] = dict(zip(robot.cable_ids, disp.round(5).tolist(),
                                                    strict=True))
            entry["mast_displacement_m"] = {
                m: float(disp[robot.mast_index == i].max()) for i, m in enumerate(robot.mast_ids)}
            W_rank = int(np.linalg.matrix_rank(np.vstack([ps.state.u.T,
                                                          np.cross(ps.state.Rb, ps.state.u).T])))
            entry["wrench_rank"] = W_rank
            kmin = platform_stiffness_min(robot, pose, ps.tensions, ps.state.length)
            entry["stiffness_min_eig"] = kmin
        poses.append(entry)
    lo, hi = grid.tension_range
    return {
        "robot": robot.name,
        "valid": True,
        "workspace": {"height_m": height, "step_m": step, "method": method,
                      "feasible_area_m2": grid.area, "points": int(grid.feasible.size),
                      "feasible_points": int(grid.feasible.sum()),
                      "tension_range_n": [lo, hi]},
        # per mast, [kx, ky, kz] [N m/rad]; null for a rigid axis
        "mast_stiffness_used": ({m: [float(k) if np.isfinite(k) else None
                                     for k in shown.stiffness[i]]
                                 for i, m in enumerate(robot.mast_ids)}
                                if shown.compliant else None),
        "mast_stiffness_source": stiffness_source,
        "poses": poses,
        "_grid": grid,
    }


def _print_show(robot: Robot) -> None:
    import numpy as np

    print(f"robot {robot.name} ({robot.source})")
    print(f"  platform {robot.mass} kg, com {robot.com.tolist()} m, g = {robot.gravity}")
    ea = "inextensible" if not robot.elastic else f"EA {robot.ea.min():.4g}..{robot.ea.max():.4g} N"
    print(f"  tensions [{robot.tension_min:g}, {robot.tension_max:g}] N, cables {ea}")
    for i, m in enumerate(robot.mast_ids):
        k = robot.stiffness[i]
        ks = "rigid" if not np.any(np.isfinite(k)) else "k = " + ", ".join(f"{v:.3g}" for v in k)
        print(f"  mast {m}: pivot {robot.pivots[i].tolist()} m, {ks}")
    print("  cable mast  exit A [m]                      anchor B [m]             pulley r [m]")
    for k, c in enumerate(robot.cable_ids):
        a = ", ".join(f"{v:7.3f}" for v in robot.exits[k])
        b = ", ".join(f"{v:6.3f}" for v in robot.anchors[k])
        print(f"  {c:5} {robot.mast_ids[robot.mast_index[k]]:4}  [{a}]  [{b}]  "
              f"{robot.pulley_radius[k]:.3f}")


def _seconds_per_pose(robot: Robot, height: float, method: str, n: int = 16) -> float:
    """Wall time of one pose of the workspace sweep [s]: the median of ``n`` poses drawn
    over the footprint, after a first one (for the sweep's announced duration)."""
    import statistics
    import time

    import numpy as np

    from controller.statics import pose_statics
    from controller.workspace import footprint_bounds

    x0, x1, y0, y1 = footprint_bounds(robot)
    rng = np.random.default_rng(0)
    times = []
    for x, y in zip(rng.uniform(x0, x1, n + 1), rng.uniform(y0, y1, n + 1), strict=True):
        t0 = time.perf_counter()
        pose_statics(robot, np.array([x, y, height, 0.0, 0.0, 0.0]), method=method)
        times.append(time.perf_counter() - t0)
    return statistics.median(times[1:])


def _usage_error(args: argparse.Namespace, msg: str) -> int:
    if args.json:
        print(json.dumps({"robot": args.robot, "valid": False, "error": msg}))
    print(f"cdpr model: {msg}", file=sys.stderr)
    return 2


def _option_problem(args: argparse.Namespace, created: list | None = None) -> str | None:
    import math

    if not (math.isfinite(args.step) and args.step > 0):
        return f"--step {args.step}: the grid step must be a positive number of metres"
    if not math.isfinite(args.height):
        return f"--height {args.height}: must be a finite height [m]"
    if args.plots and args.plot:
        return "--plots DIR and --plot PNG: give one (--plot is the deprecated spelling)"
    if args.plots:
        from bench.outputs import output_dir_problem

        return output_dir_problem(Path(args.plots), "--plots", created)
    if args.plot:
        from bench.outputs import output_file_problem

        print("cdpr model: --plot PNG is deprecated: use --plots DIR (writes "
              "DIR/workspace.png)", file=sys.stderr)
        return output_file_problem(args.plot, "--plot", created)
    return None


def run(args: argparse.Namespace) -> int:
    from bench.outputs import removing_created

    # refused (a grid too fine) or interrupted: no directory made for --plot(s) left
    return removing_created(lambda created: _run(args, created))


def _run(args: argparse.Namespace, created: list) -> int:
    from controller.robot import RobotFileError, resolve_robot
    from controller.workspace import footprint_bounds

    try:
        robot = resolve_robot(args.robot)
    except RobotFileError as e:
        return _usage_error(args, str(e))
    if args.action == "show":
        if args.json:
            print(json.dumps(describe(robot)))
        else:
            _print_show(robot)
        return 0
    if (problem := _option_problem(args, created)) is not None:
        return _usage_error(args, problem)
    x0, x1, y0, y1 = footprint_bounds(robot)
    points = ((x1 - x0) / args.step) * ((y1 - y0) / args.step)
    if points > MAX_GRID_POINTS:
        return _usage_error(args, f"--step {args.step}: {points:.3g} grid points over the "
                            f"{x1 - x0:.1f} x {y1 - y0:.1f} m footprint (at most "
                            f"{MAX_GRID_POINTS:.0e}); take a coarser step")
    from bench.progress import Progress

    # the sweep takes seconds on a fine grid: say how big it is and about how long it takes
    # (from a few poses timed here), then the progress line every second on a terminal
    est = _seconds_per_pose(robot, args.height, args.method) * points
    print(f"cdpr model: workspace sweep of about {points:,.0f} points at z = {args.height:g} m "
          f"({args.step:g} m grid, {args.method}): "
          + (f"about {est:.0f} s" if est >= 1 else "under a second"), file=sys.stderr,
          flush=True)
    with Progress("cdpr model: workspace sweep", None) as prog:
        report = check(robot, args.height, args.step, args.method)
    print(f"cdpr model: workspace sweep done in {prog.elapsed_s():.1f} s", file=sys.stderr,
          flush=True)
    grid = report.pop("_grid")
    png = Path(args.plots) / "workspace.png" if args.plots else args.plot
    if png:
        from bench.workspace_plot import write_workspace_plot

        write_workspace_plot(grid, robot, png)
        report["plots"] = [str(png)]
    if args.json:
        print(json.dumps(report))
        return 0
    lo, hi = report["workspace"]["tension_range_n"]
    print(f"{robot.name}: valid description ({robot.source})")
    print(f"  {robot.n_cables} cables on {robot.n_masts} masts, platform {robot.mass} kg")
    print(f"  wrench-feasible workspace at z = {args.height} m ({args.method}, "
          f"{args.step} m grid): {grid.area:.1f} m² "
          f"({grid.feasible.sum()}/{grid.feasible.size} points)")
    print(f"  tension range over it: {lo:.1f} .. {hi:.1f} N "
          f"(limits {robot.tension_min:g} .. {robot.tension_max:g} N)")
    ks = report["mast_stiffness_used"] or {}
    per_mast = "; ".join(f"{m}: " + ", ".join("rigid" if k is None else f"{k:.3g}" for k in v)
                         for m, v in ks.items())
    print(f"  exit-point displacement under load, mast stiffness kx, ky, kz [N·m/rad] "
          f"({report['mast_stiffness_source']}): {per_mast}")
    print("    platform at [m]          " + "  ".join(f"mast {m:>2}" for m in robot.mast_ids)
          + "   rank  min stiffness")
    for p in report["poses"]:
        pos = ", ".join(f"{v:5.2f}" for v in p["position_m"])
        if not p["feasible"]:
            print(f"    [{pos}]   infeasible: {p['reason']}")
            continue
        d = "  ".join(f"{1000 * p['mast_displacement_m'][m]:5.1f}mm" for m in robot.mast_ids)
        k = p["stiffness_min_eig"]
        ktxt = f"{k:.3g} N/m" if k is not None else "n/a (inextensible)"
        print(f"    [{pos}]  {d}   {p['wrench_rank']}     {ktxt}")
    if png:
        print(f"  workspace map: {png}")
    return 0
