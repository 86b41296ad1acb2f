"""Physics benchmarks: one control cycle and one warm-started elasto-static equilibrium."""

from __future__ import annotations

import numpy as np

from bench.benchmarks import median_time, register
from controller.cycle import LengthController
from controller.equilibrium import solve_equilibrium
from controller.robot import resolve_robot
from controller.statics import pose_statics

PAPER_STIFFNESS = (2.0e5, 5.0e5, 3.0e5)


def _robot():
    r = resolve_robot("rocaspect")
    return r.replace(stiffness=np.tile(PAPER_STIFFNESS, (r.n_masts, 1)))


@register("physics")
def bench_physics(quick: bool) -> dict[str, float]:
    """``control_cycle_us``: inverse kinematics + wrench matrix + tension distribution + mast
    update for 8 cables (median over poses along a path); ``equilibrium_ms``: one warm-started
    elasto-static equilibrium with compliant masts after a 1 mm/1 mrad step."""
    robot = _robot()
    p0 = np.array([10.0, 8.56, 1.0, 0.0, 0.0, 0.0])
    ctl = LengthController(robot, p0)
    rng = np.random.default_rng(1)
    path = [p0 + np.array([0.01 * k, -0.005 * k, 0.002 * k, 0, 0, 0]) for k in range(200)]
    meas = [ctl.step(p).tensions * (1 + 0.01 * rng.standard_normal(8)) for p in path]
    k = [0]

    def cycle():
        i = k[0] % len(path)
        ctl.step(path[i], meas[i])
        k[0] += 1

    reps = 300 if quick else 5000
    cyc = median_time(cycle, reps, warmup=50)

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
    return {"control_cycle_us": cyc * 1e6, "equilibrium_ms": eq * 1e3}
