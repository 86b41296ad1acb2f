"""The paper's campaigns on the simulated robot (Zake et al., CableCon 2023, sections 3-4).

``cdpr dry-run paper-paths`` and ``cdpr dry-run paper-poses`` run these through the same
pieces as any dry run (:mod:`bench.dryrun.world`, :class:`bench.dryrun.loop.ControlLoop`,
:class:`bench.dryrun.record.DryRunRecorder`) and compute the ISO 9283 figures of each run's
recording (:func:`bench.iso9283.analysis.analyse`); nothing here moves the robot otherwise.

- :class:`RunSpec` one run: a scenario (the truth, with the init pose the case needs), the
  controller's model, a path, the control rate, where to record; :func:`run_one` runs it
  (lock-step, in-process rig) and returns its figures. A module-level function, so that
  independent runs go to worker processes (:func:`bench.parallel.run_each`).
- Models the controller runs with (:data:`MODELS`): ``nominal`` (the scenario's robot,
  Table 1 nominal), ``remeasured`` (Table 1 remeasured exit points, the paper's second
  model), ``compliant`` (the plant's true model, exit points moved each cycle with the
  tensions the load cells measure), ``diagnosed`` (the corrected robot.toml that
  ``cdpr diagnose`` writes from a dry-run recording of a calibration campaign),
  ``planned`` (the compliant model with the tension distribution's tensions in the mast
  update instead of the load cells').
- :func:`paths_campaign` the four path runs of Table 3 for each model (plus the
  calibration recording and its diagnosis); :func:`poses_campaign` the three pose sets of
  Fig. 6 at several velocities and models.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from controller.robot import Robot
from firmware_sim.scenario import Scenario

#: the paper's init poses (section 3.3): the brown (centre) and cyan (side) spheres of Fig. 2
INIT_POSES: dict[str, tuple[float, ...]] = {"centre": (10.0, 8.56, 1.2, 0.0, 0.0, 0.0),
                                            "side": (1.0, 8.56, 1.2, 0.0, 0.0, 0.0)}
#: the paper's two paths parallel to the ZY plane (shipped path files, bench/data/paths/)
PATHS: dict[str, str] = {"centre": "paper-centre", "side": "paper-side"}
#: Table 3's cases in its order: (path, initialisation)
CASES: tuple[tuple[str, str], ...] = (("centre", "centre"), ("centre", "side"),
                                      ("side", "side"), ("side", "centre"))
#: Table 3 [mm]: nominal AT max, AT mean; the paper's offline compliant estimate max, mean
PAPER_TABLE3: dict[tuple[str, str], tuple[float, float, float, float]] = {
    ("centre", "centre"): (43.1, 24.8, 28.0, 13.6),
    ("centre", "side"): (77.1, 52.0, 46.3, 24.0),
    ("side", "side"): (127.6, 67.8, 69.2, 34.2),
    ("side", "centre"): (206.3, 154.0, 111.4, 95.7),
}
#: the pose sets of Fig. 2 / Fig. 6 (shipped path files), from the centre outwards
POSE_SETS: dict[str, str] = {"violet": "paper-poses-violet", "pink": "paper-poses-pink",
                             "gold": "paper-poses-gold"}
#: what each model is (the controller's robot.toml)
MODELS: dict[str, str] = {
    "nominal": "the scenario's robot (Table 1 nominal exit points)",
    "remeasured": "Table 1 remeasured exit points (rocaspect-remeasured), the paper's second "
                  "model",
    "compliant": "the plant's true model; exit points moved each cycle with the measured "
                 "tensions",
    "diagnosed": "the corrected robot.toml cdpr diagnose wrote from a dry-run calibration "
                 "recording; exit points moved with the measured tensions",
    "planned": "the compliant model with the tension distribution's tensions in the mast "
               "update (not the load cells')",
}


class CampaignError(RuntimeError):
    """A run of a campaign did not complete, or its recording gave no figures."""


@dataclass(frozen=True)
class RunSpec:
    """One dry run of a campaign.

    ``scenario`` the truth (its ``init_pose`` is where the plant starts; the loop measures
    it with the tracker); ``robot`` the controller's model; ``path`` a path file (name or
    file); ``speed_pct`` the velocity as a percentage of the path's maximum (None: the
    path's); ``rate_hz`` the control (SYNC) rate; ``plant_rate_hz`` plant settles per
    simulated second; ``mast_tensions`` "measured" or "planned"; ``record`` the recording
    directory (replaced); ``kind`` "path" or "pose" (the ISO figures computed);
    ``max_duration_s`` stops the trajectory early (tests); ``progress`` a file the run
    writes its fraction done to (for the parent's progress line), or None.
    """

    label: str
    scenario: Scenario
    robot: Robot
    path: str
    record: str
    kind: str = "path"
    speed_pct: float | None = None
    rate_hz: float | None = None
    plant_rate_hz: float = 20.0
    mast_tensions: str = "measured"
    max_duration_s: float | None = None
    progress: str | None = None
    decimate: int | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------- one run

_WATCHDOG = threading.Event()
_STOP = threading.Event()


def _watch_parent(parent: int, grace_s: float = 10.0) -> None:
    """In a worker process: when the parent is gone (whatever killed it), stop the run in
    progress (quick stop, recording closed), then leave; never outlive it by ``grace_s``."""
    if _WATCHDOG.is_set() or os.getpid() == parent:
        return
    _WATCHDOG.set()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        _STOP.set()
        time.sleep(grace_s)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _write_progress(path: str | None, frac: float, text: str) -> None:
    if path is None:
        return
    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(f"{frac:.4f} {text}\n")
        os.replace(tmp, path)
    except OSError:
        pass


def run_one(spec: RunSpec, parent_pid: int | None = None) -> dict[str, Any]:
    """Run ``spec`` (lock-step, in-process rig) and return its figures (plain data).

    The result: ``label``, ``ended``, ``message``, ``wall_s``, ``simulated_s``,
    ``rate_hz``, ``recording``, ``events`` (supervisor reactions other than ``none``), and
    for a path run ``at_max_m``, ``at_mean_m``, ``rt_m``, ``along`` (``s_m``,
    ``at_xyz_m``, ``executed_m``, ``desired_m`` for the Fig. 7 plots); for a pose run
    ``poses`` (per commanded pose, ``PoseFigures.to_dict()``) and ``worst``. Raises
    :class:`CampaignError` when the run did not complete.
    """
    from bench.dryrun.loop import ControlLoop, LoopOptions, PathRefused
    from bench.dryrun.record import DryRunRecorder
    from bench.dryrun.scenarios import max_rate_hz, sync_period_us
    from bench.dryrun.world import start_world, with_rate
    from controller.paths import build_trajectory, check_trajectory, load_path
    from controller.winch import load_winches

    if parent_pid is not None:
        _watch_parent(parent_pid)
    model = spec.robot
    path = load_path(spec.path)
    winches = load_winches()
    rate = spec.rate_hz or max_rate_hz(winches)
    winches = with_rate(winches, sync_period_us(rate) * 1e-6)
    rate = 1.0 / winches.bus.sync_period_s
    decimate = spec.decimate or max(1, int(round(rate / 50.0)))
    limits = None
    if spec.speed_pct is not None:
        limits = dataclasses.replace(path.limits, speed_pct=float(spec.speed_pct))

    def plan(p0):
        traj = build_trajectory(path, p0, limits)
        chk = check_trajectory(model, traj, winches)
        if not chk.ok:
            raise PathRefused(f"path {path.name or spec.path} refused for model {model.name}: "
                              f"at t = {chk.t_s:.2f} s, pose {np.round(chk.pose, 3).tolist()}: "
                              f"{chk.reason}")
        return traj

    rec = Path(spec.record)

    def open_recorder(p0):
        if rec.exists():
            shutil.rmtree(rec)
        meta = {"pose_source": "simulated laser tracker",
                "tension_source": "simulated load cells", "notes": "dry run in progress",
                "scenario": str(spec.scenario.path), "path": str(spec.path),
                "rate_hz": rate, "decimate": decimate, "campaign_run": spec.label,
                "mast_tensions": spec.mast_tensions, **dict(spec.meta)}
        return DryRunRecorder(rec, model, p0, meta,
                              robot_header=f"model the controller ran with ({model.name})")

    def progress(res, t_traj: float) -> None:
        _write_progress(spec.progress, min(1.0, t_traj / (res.path_s or 1.0)),
                        f"{res.simulated_s:.0f}s")

    opts = LoopOptions(decimate=decimate, mast_tensions=spec.mast_tensions,
                       max_duration_s=spec.max_duration_s)
    with start_world(spec.scenario, winches, "inprocess", False, spec.plant_rate_hz) as world:
        loop = ControlLoop(world.hw, world.tracker, model, plan, opts, open_recorder,
                           tick=world.tick, on_progress=progress, stop=_STOP)
        res = loop.run()
    if res.ended != "completed":
        raise CampaignError(f"{spec.label}: the dry run ended {res.ended}: {res.message}")
    out: dict[str, Any] = {
        "label": spec.label, "ended": res.ended, "message": res.message, "wall_s": res.wall_s,
        "simulated_s": res.simulated_s, "rate_hz": res.rate_hz, "recording": str(rec),
        "init_pose": res.init_pose,
        "events": [e for e in res.events if e["reaction"] not in ("none", "event")],
    }
    out.update(figures(rec, spec.kind))
    return out


def figures(recording: str | Path, kind: str) -> dict[str, Any]:
    """ISO 9283 figures of one recording: path (``at_max_m``, ``at_mean_m``, ``rt_m``,
    ``along`` of the main path) or pose (``poses``, ``worst``)."""
    from bench.iso9283.analysis import analyse
    from bench.recording import read_recording

    an = analyse([read_recording(recording)], kind=kind)
    if kind == "path":
        main = an.main_path()
        assert main is not None
        f = main.figures
        return {"at_max_m": float(f.at), "at_mean_m": float(f.at_mean),
                "rt_m": float(f.rt) if np.isfinite(f.rt) else None,
                "warnings": an.warnings,
                "along": {"s_m": f.s, "at_xyz_m": f.dev_xyz,
                          "executed_m": f.barycentre[:, :3], "desired_m": f.command[:, :3]}}
    worst = an.worst()
    return {"poses": [dict(r.figures.to_dict(), command=r.figures.command.tolist())
                      for r in an.poses], "worst": worst, "warnings": an.warnings}
