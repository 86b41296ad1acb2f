"""Physics benchmarks: one control cycle and one warm-started elasto-static equilibrium."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bench.benchmarks import median_time, register
from controller.cycle import LengthController
from controller.equilibrium import solve_equilibrium
from controller.feedrate import FeedRate, ramp_time
from controller.robot import Robot, resolve_robot
from controller.statics import pose_statics
from controller.supervisor import Observation, Supervisor, SupervisorLimits
from controller.trajectory import Line, Trajectory

PAPER_STIFFNESS = (2.0e5, 5.0e5, 3.0e5)
#: the swivel pulleys of ``control_cycle_pulley_us`` [m] (ROCASPECT has large pulleys)
PULLEY_RADIUS_M = 0.1


def _robot():
    r = resolve_robot("rocaspect")
    return r.replace(stiffness=np.tile(PAPER_STIFFNESS, (r.n_masts, 1)))


def cycle_time(robot: Robot, reps: int, hook: Callable[[], None] | None = None,
               ctl: LengthController | None = None) -> float:
    """Median time [s] of everything a dry-run cycle computes: the feed rate, the
    trajectory's setpoint, the controller's step with measured tensions (mast update, IK,
    wrench matrix, tension distribution, setpoints) and the supervisor's decision; along the
    paper's centre path, with noisy measured tensions. ``hook``: called once per cycle (e.g. a
    model hand-over, ``bench/benchmarks/learn.py``); ``ctl``: the controller (default one of
    ``robot`` referenced at the path's start)."""
    p0 = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.0])
    ctl = LengthController(robot, p0) if ctl is None else ctl
    traj = Trajectory([Line([[10.0, 13.56, 1.2], [10.0, 13.56, 0.6], [10.0, 3.56, 0.6]])], p0)
    n = robot.n_cables
    sup = Supervisor(SupervisorLimits.for_robot(robot.tension_min, robot.tension_max,
                                                np.full(n, 0.02)))
    feed = FeedRate(ramp_time(0.5, 0.5))
    rng = np.random.default_rng(1)
    T = 0.0039
    ok, enabled = np.ones(n, bool), np.ones(n, bool)
    state = {"t": 0.0, "tau": ctl.init_tensions, "l": ctl.step(p0).lengths}
    noise = [1 + 0.01 * rng.standard_normal(n) for _ in range(64)]
    k = [0]

    def cycle():
        state["t"] = (state["t"] + feed.advance(T, False)) % traj.duration_s
        pose = traj.sample(state["t"]).pose
        out = ctl.step(pose, state["tau"], ok)
        sup.step(Observation(state["t"], state["tau"], ok, state["l"], state["l"], enabled,
                             cables=robot.cable_ids))
        state["tau"] = out.tensions * noise[k[0] % 64]
        state["l"] = out.lengths
        k[0] += 1
        if hook is not None:
            hook()

    return median_time(cycle, reps, warmup=50)


@register("physics")
def bench_physics(quick: bool) -> dict[str, float]:
    """``control_cycle_us`` / ``control_cycle_pulley_us``: one control cycle (trajectory,
    controller with mast update, supervisor; see :func:`cycle_time`) for 8 cables, without
    and with 0.1 m swivel pulleys; ``equilibrium_ms``: one warm-started elasto-static
    equilibrium with compliant masts after a 1 mm/1 mrad step."""
    robot = _robot()
    reps = 300 if quick else 5000
    cyc = cycle_time(robot, reps)
    cyc_pulley = cycle_time(robot.replace(pulley_radius=np.full(robot.n_cables,
                                                                PULLEY_RADIUS_M)), reps)
    rng = np.random.default_rng(1)
    pose = np.array([15.5, 4.5, 1.0, 0.0, 0.0, 0.0])
    ps = pose_statics(robot, pose)
    l0 = ps.unstretched
    base = solve_equilibrium(robot, l0, pose).raise_if_failed()
    steps = [l0 + 1e-3 * rng.standard_normal(8) for _ in range(50)]
    j = [0]

    def equil():
        res = solve_equilibrium(robot, steps[j[0] % len(steps)], base.pose, base.theta)
        if not res.success:
            raise RuntimeError(res.message)
        j[0] += 1

    eq = median_time(equil, 50 if quick else 500, warmup=5)
    return {"control_cycle_us": cyc * 1e6, "control_cycle_pulley_us": cyc_pulley * 1e6,
            "equilibrium_ms": eq * 1e3}
