"""Dry-run benchmarks: the controller in the loop with the simulated robot.

- ``dryrun_speedup``: simulated time over wall time of a lock-step dry run of the paper's
  centre path (in this process, the real protocol stack in the loop: CiA 402 over the
  virtual CAN bus, Modbus/TCP load cells, the plant), at the default control rate.
- ``realtime_rate_hz``: the highest rate at which a real-time dry run against ``cdpr sim``
  in another process (socketcand hub, Modbus/TCP, tracker over TCP) keeps
  ``deadline_miss_ratio`` (overruns per cycle) at or below 0.1 % over 60 s (10 s with
  ``--quick``), trying the bus-load limit first and then lower rates; with it
  ``deadline_miss_ratio`` and ``jitter_p99_ms`` (99th percentile of the lateness of the
  cycles' SYNC after their deadline) at that rate.
"""

from __future__ import annotations

import numpy as np

from bench.benchmarks import register
from bench.dryrun.loop import ControlLoop, LoopOptions
from bench.dryrun.scenarios import max_rate_hz, resolve_scenario, sync_period_us
from bench.dryrun.world import start_world, with_rate
from controller.paths import build_trajectory, load_path
from controller.winch import load_winches
from firmware_sim.scenario import load_scenario

MISS_GOAL = 1e-3
#: rates tried below the bus-load limit [Hz]
FALLBACK_RATES = (200.0, 150.0, 100.0, 50.0)


def _run(kind: str, realtime: bool, rate_hz: float, seconds: float):
    sc = load_scenario(resolve_scenario("paper-centre"))
    spec = load_path(sc.run_path)
    winches = with_rate(load_winches(), sync_period_us(rate_hz) * 1e-6)
    with start_world(sc, winches, kind, realtime) as world:
        tick = world.tick if (world.rig is not None and not realtime) else None
        loop = ControlLoop(world.hw, world.tracker, sc.model,
                           lambda p0: build_trajectory(spec, p0),
                           LoopOptions(realtime=realtime, max_duration_s=seconds,
                                       init_dwell_s=0.5, decimate=5), tick=tick)
        res = loop.run()
    if res.ended != "completed":
        raise RuntimeError(f"dry run ended {res.ended}: {res.message}")
    return res


@register("dryrun")
def bench_dryrun(quick: bool) -> dict[str, float]:
    top = max_rate_hz(load_winches())
    speed = [r.simulated_s / r.wall_s for r in
             (_run("inprocess", False, top, 5.0 if quick else 20.0) for _ in range(1 if quick
                                                                            else 3))]
    out: dict[str, float] = {"dryrun_speedup": float(np.median(speed))}
    seconds = 10.0 if quick else 60.0
    for rate in (top,) + tuple(r for r in FALLBACK_RATES if r < top):
        res = _run("process", True, rate, seconds)
        miss = res.overruns / max(res.cycles, 1)
        out.update({"realtime_rate_hz": res.rate_hz, "deadline_miss_ratio": miss,
                    "jitter_p99_ms": res.jitter_ms(99.0) or 0.0})
        if miss <= MISS_GOAL:
            break
    else:
        out["realtime_rate_hz"] = 0.0  # no rate kept the deadlines
    return out
