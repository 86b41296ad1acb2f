"""Trajectory benchmarks: one setpoint from a trajectory (called once per control cycle) and
the whole-path check of the shipped calibration path (run before anything moves)."""

from __future__ import annotations

import time

import numpy as np

from bench.benchmarks import median_time, register
from controller.paths import build_trajectory, check_trajectory, load_path
from controller.robot import resolve_robot
from controller.winch import load_winches

INIT = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.0])


@register("trajectory")
def bench_trajectory(quick: bool) -> dict[str, float]:
    """``trajectory_sample_us``: ``Trajectory.sample(t)`` for one time (pose, velocity,
    acceleration, label), median over times spread along the calibration path (moves with
    small rotations, and dwells); ``trajectory_sample_rot_us``: the same on a move that
    turns (slerp and Euler rates); ``path_check_calibration_s``: ``check_trajectory`` of
    the shipped calibration path (about 50 min, 13k poses) for the nominal rocaspect with
    its winches."""
    robot = resolve_robot("rocaspect")
    traj = build_trajectory(load_path("calibration"), INIT)
    times = np.random.default_rng(0).uniform(0.0, traj.duration_s, 997).tolist()
    k = [0]

    def one() -> None:
        traj.sample(times[k[0] % len(times)])
        k[0] += 1

    reps = 2000 if quick else 20000
    sample = median_time(one, reps, warmup=100)
    moving = [t for t in times if traj.sample(t).label == "move"]
    k[0] = 0

    def one_move() -> None:
        traj.sample(moving[k[0] % len(moving)])
        k[0] += 1

    sample_rot = median_time(one_move, reps, warmup=100)
    winches = load_winches()
    checks = []
    for _ in range(1 if quick else 3):
        t0 = time.perf_counter()
        res = check_trajectory(robot, traj, winches)
        checks.append(time.perf_counter() - t0)
        if not res.ok:
            raise RuntimeError(f"the shipped calibration path fails its check: {res.reason}")
    return {"trajectory_sample_us": sample * 1e6, "trajectory_sample_rot_us": sample_rot * 1e6,
            "path_check_calibration_s": float(np.median(checks))}
