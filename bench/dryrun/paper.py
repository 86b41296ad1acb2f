"""The paper's campaigns on the simulated robot (Zake et al., CableCon 2023, sections 3-4).

``cdpr dry-run paper-paths`` and ``cdpr dry-run paper-poses`` run these through the same
pieces as any dry run (:func:`bench.dryrun.world.start_world`,
:class:`bench.dryrun.loop.ControlLoop`, :class:`bench.dryrun.record.DryRunRecorder`) and
compute the ISO 9283 figures of each run's recording (:func:`bench.iso9283.analysis.analyse`);
nothing here moves the robot otherwise.

- :class:`RunSpec` one run: a scenario (the truth, with the init pose the case needs), the
  controller's model, a path, the control rate, where to record; :func:`run_one` runs it
  (lock-step, in-process rig) and returns its figures. Module-level functions, so that
  independent runs go to worker processes (:func:`bench.parallel.run_each`).
- The models the controller runs with (:data:`MODELS`): ``nominal`` (the scenario's robot,
  Table 1 nominal), ``remeasured`` (Table 1 remeasured exit points, the paper's second
  model), ``compliant`` (the plant's true model; the exit points move each cycle with the
  tensions the load cells measure), ``diagnosed`` (the corrected robot.toml that ``cdpr
  diagnose`` writes from a dry-run recording of a calibration campaign in the same
  scenario: record -> diagnose -> corrected robot.toml -> run).
- The measured tensions matter (:func:`paths_plan`, ``planned``): in a scenario whose
  platform is heavier than every model says (``paper-heavy``), the compliant controller
  with the load cells' tensions in the mast update against the same controller with the
  tension distribution's tensions (``LoopOptions.mast_tensions = "planned"``).
- :func:`run_campaign` runs a plan's items on a process pool with a progress line;
  :func:`paths_result` / :func:`poses_result` turn the runs into the ``--json`` objects,
  :func:`paths_table` / :func:`poses_table` into text, :func:`paths_plots` /
  :func:`poses_plots` into the Fig. 7- and Fig. 6-like PNGs (:mod:`bench.iso9283.plots`).

The plant settles at least every :data:`PLANT_STEP_M` of motion (:func:`plant_rate`); a run
the simulated drives stopped on a lost master heartbeat (a machine loaded beyond what the
lock-step rig tolerates) runs again once (:func:`run_item`, reported as ``retried``).

Slack cables are logged, not held (:data:`REACTIONS`; ``--react`` changes it): the paper's
runs went through, and on the side of the workspace the far cables run at the model's minimum
tension, where the plant's per-visit length noise (0.5 mm, +-15 N on a 20 m cable) lets
a nominal model's cable go slack; each run's slack events are counted in the results.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.progress import Progress
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
#: Table 3 [m]: nominal AT max, AT mean; the paper's offline compliant estimate max, mean
PAPER_TABLE3: dict[tuple[str, str], tuple[float, float, float, float]] = {
    ("centre", "centre"): (0.0431, 0.0248, 0.0280, 0.0136),
    ("centre", "side"): (0.0771, 0.0520, 0.0463, 0.0240),
    ("side", "side"): (0.1276, 0.0678, 0.0692, 0.0342),
    ("side", "centre"): (0.2063, 0.1540, 0.1114, 0.0957),
}
#: the pose sets of Fig. 2 / Fig. 6 (shipped path files), from the centre outwards
POSE_SETS: dict[str, str] = {"violet": "paper-poses-violet", "pink": "paper-poses-pink",
                             "gold": "paper-poses-gold"}
#: what each model is (the controller's robot.toml)
MODELS: dict[str, str] = {
    "nominal": "the scenario's robot (Table 1 nominal exit points, rigid masts)",
    "remeasured": "Table 1 remeasured exit points (rocaspect-remeasured), the paper's second "
                  "model, rigid masts",
    "compliant": "the plant's true model; exit points moved each cycle with the tensions the "
                 "load cells measure",
    "diagnosed": "the corrected robot.toml cdpr diagnose wrote from a dry-run calibration "
                 "recording; exit points moved with the measured tensions",
    "learned": "starts from the nominal model and identifies exit points and mast "
               "compliance online (tracker fixes, tensions, encoders) during a warm-up of "
               "at most 60 s, then runs the path with the model handed over (learning on)",
    "learned_untracked": "as learned during the warm-up (tracker fixes, tensions, encoders), "
                         "then tensions and encoders only: the tracker off for the path "
                         "(it still gives the figures); the estimate moves only along the "
                         "directions these determine",
    "learned_warmup": "as learned during the warm-up, then fixed: no learning on the path "
                      "(what learned_untracked starts from)",
    "learned_notracker": "starts from the nominal model and learns from tensions and "
                         "encoders only, warm-up and path (no tracker fix ever used; the "
                         "tracker still gives the figures): only the directions these "
                         "determine move",
}
#: the order models appear in tables and plots
MODEL_ORDER = ("nominal", "remeasured", "compliant", "diagnosed", "learned",
               "learned_warmup", "learned_untracked", "learned_notracker")
#: the models paper-paths runs when none are named
DEFAULT_MODELS = ("nominal", "remeasured", "compliant", "diagnosed")
#: the learning models: whether the estimator uses the tracker's fixes (True: all the run;
#: "warmup": during the warm-up only, then tensions and encoders; "warmup_only": during the
#: warm-up only, then no learning; False: never, tensions and encoders all the run)
LEARNED: dict[str, bool | str] = {"learned": True, "learned_untracked": "warmup",
                                  "learned_warmup": "warmup_only", "learned_notracker": False}
#: the warm-up of the learning models: dwell poses offset from the init pose [m] (x, y, z
#: from the init pose, clipped into :data:`WARMUP_BOX`), each visited once: toward each
#: mast in turn, high and low alternately (large tension changes on every mast: its
#: cables taut near it, slack-ish far from it; the height changes every tension)
WARMUP_OFFSETS: tuple[tuple[float, float, float], ...] = (
    (-2.5, -2.5, 0.6), (-2.5, 2.5, -0.5), (2.5, 2.5, 0.6), (2.5, -2.5, -0.5))
#: the box the warm-up's poses are kept in [m] (x, y, z lower; x, y, z upper): the extent
#: of the calibration grid (bench/data/paths/calibration-quick.toml)
WARMUP_BOX: tuple[tuple[float, float, float], tuple[float, float, float]] = (
    (1.0, 2.0, 0.6), (19.0, 15.12, 2.0))
#: [s] dwell at each warm-up pose (the learner keeps samples after ``still_s`` at rest)
WARMUP_DWELL_S = 0.5
#: the warm-up's segment name
WARMUP_NAME = "learning warm-up"
#: [m/s] the learning models' hand-over rate per exit coordinate: the setpoints move by
#: at most about this much per second more than the path asks (2 % of its 0.5 m/s)
LEARN_RATE_OFFSET = 0.01
#: the hand-over's correlation limit for the learning model with the tracker
#: (:meth:`controller.online_ident.ModelHandover.target`; above 1: off: the warm-up's samples
#: fix the parameters together). Without the tracker (2 equations a sample) the warm-up leaves
#: them correlated: the default 0.5 applies, a part of a correction can be worse than none
LEARN_CORRELATED = 1.01
#: the scenarios and paths the campaigns use (shipped names)
SCENARIO = "paper-centre"
CALIBRATION_SCENARIO = "paper-calibration"
CALIBRATION_PATH = "calibration-quick"
HEAVY_SCENARIO = "paper-heavy"
#: control rate of the campaigns [Hz] (the figures do not depend on it:
#: docs/explanation/paper.md; ``--rate`` changes it)
PATHS_RATE_HZ = 64.0
POSES_RATE_HZ = 32.0
CALIBRATION_RATE_HZ = 32.0
#: plant settles per simulated second, at least: path runs 20 (the dry run's default); pose and
#: calibration campaigns 5 (they measure at dwells of 3 s, long after the plant settled)
PATHS_PLANT_HZ = 20.0
DWELL_PLANT_HZ = 5.0
#: and at most this far between two plant settles at the path's top speed [m] (0.5 m/s at
#: 20 Hz): the plant's rest search starts from the last rest, and a long jump lets it land on
#: another local minimum of the energy than the one the platform moves along (seen: a
#: platform turned over after a 10 cm jump as a cable went slack, gold set at 100 %, 5 Hz)
PLANT_STEP_M = 0.025
#: the supervisor's reactions the campaigns change (``--react`` adds to them): slack cables
#: logged, not held (see the module docstring)
REACTIONS: dict[str, str] = {"slack": "log"}
#: the goal of the compliant and diagnosed controllers: AT max cut by at least this
GOAL_CUT = 0.8


class CampaignError(RuntimeError):
    """A run of a campaign did not complete, or its recording gave no figures."""


class DriveLostError(CampaignError):
    """A run stopped because the simulated drives lost their master (heartbeat, NMT): on a
    machine loaded beyond what the lock-step rig tolerates, not something the robot did.
    :func:`run_item` runs such a run again, :data:`RETRIES` times at most, and says so."""


#: how many times :func:`run_item` runs a run again after a :class:`DriveLostError`
RETRIES = 1


@dataclass(frozen=True)
class RunSpec:
    """One dry run of a campaign.

    ``scenario`` the truth (its ``init_pose`` is where the plant starts; the loop measures
    it with the tracker); ``robot`` the controller's model, or ``robot_file`` a robot.toml
    to read when the run starts (a model another item writes, e.g. the diagnosis);
    ``path`` a path file (name or file) or a parsed :class:`controller.paths.PathSpec`;
    ``speed_pct`` the velocity as a percentage of the path's maximum (None: the path's);
    ``rate_hz`` the control (SYNC) rate; ``plant_rate_hz`` plant settles per simulated
    second, at least (more when the path's top speed would move the platform more than
    :data:`PLANT_STEP_M` between two); ``mast_tensions`` "measured" or "planned";
    ``record`` the recording directory (replaced); ``kind`` "path", "pose" (the ISO figures
    computed) or "record" (none);
    ``max_duration_s`` stops the trajectory this long after the approach to the path ended
    (shortened campaigns, tests); ``progress`` a file the run writes its fraction done to;
    ``stop_file`` a file whose appearance stops the run (quick stop, recording kept);
    ``reactions`` the supervisor's reactions changed for the run, condition -> reaction
    name (default :data:`REACTIONS`: slack logged);
    ``tags`` free data copied into the result (case, model, ...);
    ``learn``: None, or the online identification's options (``tracker``: the estimator
    uses the tracker's fixes, True all the run, False never, "warmup" during the warm-up
    only (then tensions and encoders), "warmup_only" during the warm-up only (then the
    learning stops); ``period_s``; ``sigma_length``): the run learns
    (:class:`bench.dryrun.learn.LoopLearner`) from its first cycle to its last;
    ``warmup``: the segment specs (:mod:`controller.trajectory`) run from the init pose
    before the path, as part of its approach (``cycle`` -1: no part of the ISO figures),
    or a callable of the init pose that returns them.
    """

    label: str
    scenario: Scenario
    path: str | Any  #: a path file (name or file), or a controller.paths.PathSpec
    record: str
    robot: Robot | None = None
    robot_file: str | None = None
    kind: str = "path"
    speed_pct: float | None = None
    rate_hz: float | None = None
    plant_rate_hz: float = PATHS_PLANT_HZ
    mast_tensions: str = "measured"
    max_duration_s: float | None = None
    progress: str | None = None
    stop_file: str | None = None
    reactions: Mapping[str, str] = field(default_factory=lambda: dict(REACTIONS))
    tags: Mapping[str, Any] = field(default_factory=dict)
    learn: Mapping[str, Any] | None = None
    warmup: Any = None


@dataclass(frozen=True)
class DiagnoseSpec:
    """Record a calibration campaign (``run``, kind "record") and diagnose it: the corrected
    robot.toml goes to ``model_file``, the report's summary into the result."""

    label: str
    run: RunSpec
    model_file: str


# --------------------------------------------------------------------------- models


def table1_exit_offsets(nominal: Robot, remeasured: Robot, stiffness: Sequence[float],
                        pose: Sequence[float] = (10.0, 8.56, 1.0, 0.0, 0.0, 0.0),
                        iterations: int = 8) -> np.ndarray:
    """Exit-point offsets (n,3) [m] of a truth with compliant masts (``stiffness`` kx, ky,
    kz [N m/rad] on every mast) whose exit points A#, deflected by the tension
    distribution's tensions with the platform at ``pose``, are ``remeasured``'s exits (the
    paper's Table 1: A^r measured with the platform at [10.0, 8.56, 1.0])."""
    from controller.effects import apply_effects
    from controller.statics import pose_statics

    p = np.asarray(pose, float)
    off = remeasured.exits - nominal.exits
    k = {f"k{a}_{m}": float(v) for m in nominal.mast_ids for a, v in zip("xyz", stiffness,
                                                                         strict=True)}
    for _ in range(iterations):
        eff = {"mast_compliance": k, "exit_point_offset": {
            f"d{a}_{c}": float(off[j, i]) for j, c in enumerate(nominal.cable_ids)
            for i, a in enumerate("xyz")}}
        ps = pose_statics(apply_effects(nominal, eff), p)
        off = off + (remeasured.exits - ps.exits)
    return off


def warmup_specs(init_pose: Sequence[float]) -> list:
    """The learning models' warm-up from ``init_pose`` (6,): one visit of each pose of
    :data:`WARMUP_OFFSETS` (level, kept in :data:`WARMUP_BOX`) with a dwell of
    :data:`WARMUP_DWELL_S`, then back to the init pose's position."""
    from controller.trajectory import Move, Visits

    p0 = np.asarray(init_pose, float)
    lo, hi = np.array(WARMUP_BOX[0]), np.array(WARMUP_BOX[1])
    poses = tuple(tuple(np.r_[np.clip(p0[:3] + np.array(o), lo, hi), p0[3:]].tolist())
                  for o in WARMUP_OFFSETS)
    return [Visits(poses, 1, WARMUP_DWELL_S, name=WARMUP_NAME),
            Move(tuple(p0.tolist()), name=f"{WARMUP_NAME}: back to the init pose")]


def with_warmup(path: Any, warmup: Sequence, start_pose: Sequence[float],
                limits: Any = None) -> Any:
    """The trajectory of ``path`` (:class:`controller.paths.PathSpec`) from ``start_pose``
    with the segment specs ``warmup`` run first, as part of the approach (``cycle`` -1)."""
    from controller.paths import build_trajectory
    from controller.trajectory import Move, Trajectory

    if not warmup:
        return build_trajectory(path, start_pose, limits)
    specs = list(warmup)
    if path.start is not None:
        specs.append(Move(path.start, "approach", f"{path.source}: start"))
    return Trajectory(specs + list(path.segments), start_pose, limits or path.limits,
                      repeat=path.repeat, approach=len(specs))


def known_truth(scenario: Scenario, unknown: Sequence[str] = ()) -> Robot:
    """The scenario's truth without the effects in ``unknown`` (what a controller that knows
    the robot but not, e.g., a payload runs with); the truth itself when none is left out."""
    from controller.effects import apply_effects

    if not any(e in scenario.effects for e in unknown):
        return scenario.truth
    eff = {k: v for k, v in scenario.effects.items() if k not in unknown}
    return apply_effects(scenario.model, eff, name=f"{scenario.model.name} (truth without "
                                                   f"{', '.join(unknown)})")


def load_named_scenario(name: str) -> Scenario:
    from bench.dryrun.scenarios import resolve_scenario
    from firmware_sim.scenario import load_scenario

    return load_scenario(resolve_scenario(name))


def at_init(scenario: Scenario, init: str | Sequence[float]) -> Scenario:
    """The scenario with the plant starting at ``init`` (a name of :data:`INIT_POSES` or a
    pose)."""
    pose = INIT_POSES[init] if isinstance(init, str) else tuple(init)
    return dataclasses.replace(scenario, init_pose=np.array(pose, float))


# --------------------------------------------------------------------------- one run

_WATCHDOG = threading.Event()
_STOP = threading.Event()
_STOP_FILE: list[str | None] = [None]


def _watch(parent: int | None, grace_s: float = 10.0) -> None:
    """In a worker process: when the parent is gone (whatever killed it) or the current
    run's stop file appears, stop the run in progress (quick stop, recording closed); when
    the parent is gone, leave within ``grace_s``. Started once per process."""
    if _WATCHDOG.is_set():
        return
    _WATCHDOG.set()

    def watch() -> None:
        while True:
            if parent is not None and os.getppid() != parent:
                _STOP.set()
                time.sleep(grace_s)
                os._exit(1)
            sf = _STOP_FILE[0]
            if sf is not None and os.path.exists(sf):
                _STOP.set()
            time.sleep(0.5)

    threading.Thread(target=watch, name="campaign-watchdog", daemon=True).start()


def _write_progress(path: str | None, frac: float) -> None:
    if path is None:
        return
    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(f"{frac:.4f}\n")
        os.replace(tmp, path)
    except OSError:
        pass


def plant_rate(minimum_hz: float, limits: Any) -> float:
    """Plant settles per simulated second [Hz]: ``minimum_hz``, or more so that the platform
    moves at most :data:`PLANT_STEP_M` between two at the top speed of ``limits``
    (:class:`controller.trajectory.MotionLimits`)."""
    return max(float(minimum_hz), limits.max_speed_m_s * limits.speed_pct / 100.0 / PLANT_STEP_M)


def run_one(spec: RunSpec, parent_pid: int | None = None) -> dict[str, Any]:
    """Run ``spec`` (lock-step, in-process rig) and return its figures (plain data).

    The result: ``label``, ``tags``, ``ended``, ``wall_s``, ``simulated_s``, ``rate_hz``,
    ``recording``, ``slack_events`` (slack conditions logged), ``events`` (other supervisor
    reactions), and for a path run ``at_max_m``, ``at_mean_m``, ``rt_m``, ``along``
    (``s_m``, ``at_xyz_m``, ``executed_m``, ``desired_m`` for the Fig. 7 plots); for a pose
    run ``poses`` (per commanded pose, the ISO figures) and ``worst``. Raises
    :class:`CampaignError` when the run did not complete.
    """
    from bench.dryrun.loop import ControlLoop, LoopOptions, PathRefused
    from bench.dryrun.record import DryRunRecorder
    from bench.dryrun.scenarios import max_rate_hz, sync_period_us
    from bench.dryrun.world import start_world, with_rate
    from controller.paths import PathSpec, check_trajectory, load_path
    from controller.robot import load_robot
    from controller.supervisor import Reaction
    from controller.winch import load_winches

    in_process = parent_pid is None or parent_pid == os.getpid()
    _STOP_FILE[0] = spec.stop_file
    if spec.stop_file and os.path.exists(spec.stop_file):
        raise CampaignError(f"{spec.label}: not started (the campaign was stopped)")
    _STOP.clear()
    _watch(None if in_process else parent_pid)
    model = spec.robot if spec.robot is not None else load_robot(spec.robot_file)
    path = spec.path if isinstance(spec.path, PathSpec) else load_path(spec.path)
    winches = load_winches()
    rate = spec.rate_hz or max_rate_hz(winches)
    winches = with_rate(winches, sync_period_us(rate) * 1e-6)
    rate = 1.0 / winches.bus.sync_period_s
    decimate = max(1, int(round(rate / 50.0)))
    limits = None
    if spec.speed_pct is not None:
        limits = path.limits.replace(speed_pct=float(spec.speed_pct))
    plant_hz = plant_rate(spec.plant_rate_hz, limits or path.limits)

    def warm(p0) -> list:
        return list(spec.warmup(p0) if callable(spec.warmup) else spec.warmup or ())

    def plan(p0):
        traj = with_warmup(path, warm(p0), p0, limits)
        chk = check_trajectory(model, traj, winches)
        if not chk.ok:
            raise PathRefused(f"path {path.name or path.source} refused for model {model.name}: "
                              f"at t = {chk.t_s:.2f} s, pose {np.round(chk.pose, 3).tolist()}: "
                              f"{chk.reason}")
        return traj

    rec = Path(spec.record)

    def open_recorder(p0):
        if rec.exists():
            shutil.rmtree(rec)
        meta = {"pose_source": "simulated laser tracker",
                "tension_source": "simulated load cells", "notes": "dry run in progress",
                "scenario": str(spec.scenario.path), "path": path.name or path.source,
                "rate_hz": rate, "decimate": decimate, "campaign_run": spec.label,
                "mast_tensions": spec.mast_tensions}
        return DryRunRecorder(rec, model, p0, meta,
                              robot_header=f"model the controller ran with ({model.name})")

    def progress(res, t_traj: float) -> None:
        _write_progress(spec.progress, min(1.0, t_traj / (res.path_s or 1.0)))

    max_s = spec.max_duration_s
    if max_s is not None:  # counted from the end of the approach to the path
        approach = with_warmup(path, warm(spec.scenario.init_pose), spec.scenario.init_pose,
                               limits).segments
        max_s += max((s.t1 for s in approach if s.cycle < 0), default=0.0)
    opts = LoopOptions(decimate=decimate, mast_tensions=spec.mast_tensions,
                       max_duration_s=max_s,
                       reactions={k: Reaction[v.upper()] for k, v in spec.reactions.items()})
    with start_world(spec.scenario, winches, "inprocess", False, plant_hz) as world:
        learner = _learner(spec.learn, world)
        loop = ControlLoop(world.hw, world.tracker, model, plan, opts, open_recorder,
                           tick=world.tick, on_progress=progress, stop=_STOP,
                           on_cycle=learner)
        if learner is not None:
            learner.trajectory = lambda: loop.trajectory
        res = loop.run()
    _write_progress(spec.progress, 1.0)
    _check_ended(spec, res, in_process)
    return _figures_of(spec, res, rec, model, learner, loop)


def _check_ended(spec: RunSpec, res, in_process: bool) -> None:
    """KeyboardInterrupt after a Ctrl-C in this process (the campaign ends, not this run);
    :class:`DriveLostError` or :class:`CampaignError` when the run did not complete."""
    if res.ended == "interrupted" and in_process and not _STOP.is_set():
        raise KeyboardInterrupt
    if res.ended != "completed":
        msg = f"{spec.label}: the dry run ended {res.ended}: {res.message}"
        lost = [e for e in res.events if e["kind"] == "drive_lost" and e["active"]]
        if lost:
            raise DriveLostError(f"{msg} ({lost[0]['device']} {lost[0]['address']}: "
                                 f"{lost[0]['text']})")
        raise CampaignError(msg)


def _figures_of(spec: RunSpec, res, rec: Path, model, learner, loop) -> dict[str, Any]:
    """The completed run's figures (:func:`run_one`'s result)."""
    slack = [e for e in res.events if e["kind"] == "slack" and e["active"]]
    out: dict[str, Any] = {
        "label": spec.label, "tags": dict(spec.tags), "ended": res.ended,
        "wall_s": res.wall_s, "simulated_s": res.simulated_s, "rate_hz": res.rate_hz,
        "recording": str(rec), "model": model.name, "mast_tensions": spec.mast_tensions,
        "slack_events": len(slack),
        "events": [e for e in res.events
                   if e["reaction"] not in ("none", "event", "log") and e["active"]],
    }
    if learner is not None:
        out["learn"] = learner.report()
        out["learn"]["warmup_s"] = _warmup_s(loop.trajectory)
    if spec.kind != "record":
        out.update(figures(rec, spec.kind))
    return out


def _learner(learn: Mapping[str, Any] | None, world: Any) -> Any:
    """The run's online identification (None: the run does not learn); in the in-process
    world, the time of the plant state the readings are of is the rig's last settle."""
    if learn is None:
        return None
    from bench.dryrun.learn import LoopLearner
    from controller.online_ident import IdentOptions

    rig = getattr(world, "rig", None)
    tracker = learn.get("tracker", True)
    learner = LoopLearner(world.tracker, float(learn.get("period_s", 0.5)),
                          IdentOptions(sigma_length=float(learn.get("sigma_length", 5e-4))),
                          rate_offset=float(learn.get("rate_offset", LEARN_RATE_OFFSET)),
                          correlated=float(learn.get("correlated", LEARN_CORRELATED if
                                                     tracker is not False else 0.5)),
                          use_tracker=tracker is not False,
                          state_time=None if rig is None else (lambda: rig.last.t_s))
    if tracker in ("warmup", "warmup_only"):  # the tracker's fixes during the warm-up only
        learner.untracked = tracker == "warmup"
        learner.tracked_s = lambda: _warmup_s(learner.trajectory()
                                              if learner.trajectory is not None else None)
    return learner


def _warmup_s(traj: Any) -> float | None:
    """[s] trajectory time of the learning warm-up (:func:`warmup_specs`; not the approach
    to the path's start, which every model's run has)."""
    if traj is None:
        return None
    return float(sum(s.duration_s for s in traj.segments if s.name.startswith(WARMUP_NAME)))


def figures(recording: str | Path, kind: str) -> dict[str, Any]:
    """ISO 9283 figures of one recording: path (``at_max_m``, ``at_mean_m``, ``rt_m``,
    ``along`` of the main path) or pose (``poses``, ``worst``)."""
    from bench.iso9283.analysis import analyse
    from bench.recording import read_recording

    an = analyse([read_recording(recording)], kind=kind)
    if kind == "path":
        main = an.main_path()
        if main is None:
            raise CampaignError(f"{recording}: no path in the recording")
        f = main.figures
        return {"at_max_m": float(f.at), "at_mean_m": float(f.at_mean),
                "rt_m": float(f.rt) if np.isfinite(f.rt) else None,
                "warnings": list(an.warnings),
                "along": {"s_m": f.s, "at_xyz_m": f.dev_xyz,
                          "executed_m": f.barycentre[:, :3], "desired_m": f.command[:, :3]}}
    return {"poses": [dict(r.figures.to_dict(), command=r.figures.command.tolist())
                      for r in an.poses], "worst": an.worst(), "warnings": list(an.warnings)}


def diagnose_one(spec: DiagnoseSpec, parent_pid: int | None = None) -> dict[str, Any]:
    """Record the calibration campaign, diagnose it, write the corrected robot.toml.

    Returns the calibration run's result plus ``model_file``, ``diagnose_s`` and
    ``diagnosis`` (the report's effects, their parameters and the held-out figures)."""
    from bench.diagnosis.report import diagnose

    out = run_one(spec.run, parent_pid)
    t0 = time.perf_counter()
    dg = diagnose(spec.run.record, None, None, spec.model_file)
    rep = dg.report
    out.update(model_file=spec.model_file, diagnose_s=time.perf_counter() - t0,
               diagnosis={"effects": [{"name": e["name"], "params": e["params"],
                                       "undetermined": e["undetermined"]}
                                      for e in rep.get("effects", [])],
                          "samples": rep.get("samples"), "baseline": rep.get("baseline"),
                          "fitted": rep.get("fitted")})
    return out


def run_item(item: RunSpec | DiagnoseSpec, parent_pid: int | None = None) -> dict[str, Any]:
    """A campaign item in a worker process (see :func:`run_campaign`); a run the drives
    stopped on a lost master (:class:`DriveLostError`) runs again, :data:`RETRIES` times at
    most; the result's ``retried`` lists why (empty: first time through)."""
    why: list[str] = []
    while True:
        try:
            out = (diagnose_one(item, parent_pid) if isinstance(item, DiagnoseSpec)
                   else run_one(item, parent_pid))
        except DriveLostError as exc:
            if len(why) >= RETRIES:
                raise
            why.append(str(exc))
            continue
        out["retried"] = why
        return out


# --------------------------------------------------------------------------- plans


@dataclass
class PathsOptions:
    """What ``paper-paths`` runs (the defaults are the command's)."""

    work: Path
    models: tuple[str, ...] = DEFAULT_MODELS
    planned: bool = True  #: the measured-vs-planned comparison in the heavy scenario
    rate_hz: float = PATHS_RATE_HZ
    plant_rate_hz: float = PATHS_PLANT_HZ
    max_duration_s: float | None = None  #: trajectory time per path run (tests)
    cases: tuple[tuple[str, str], ...] = CASES
    scenario: str = SCENARIO
    calibration_scenario: str = CALIBRATION_SCENARIO
    calibration_path: str = CALIBRATION_PATH
    calibration_rate_hz: float = CALIBRATION_RATE_HZ
    calibration_plant_hz: float = DWELL_PLANT_HZ
    calibration_duration_s: float | None = None
    diagnosed_model: str | None = None  #: a corrected robot.toml instead of calibrating
    heavy_scenario: str = HEAVY_SCENARIO
    reactions: dict[str, str] = field(default_factory=lambda: dict(REACTIONS))


def _case_name(case: tuple[str, str]) -> str:
    return f"{case[0]}-path_{case[1]}-init"


def paths_plan(opt: PathsOptions) -> tuple[list[DiagnoseSpec | RunSpec], list[RunSpec]]:
    """The items of ``paper-paths``: first phase (calibration and its diagnosis first, then
    every run that needs no diagnosis), second phase (the diagnosed runs)."""
    from controller.robot import resolve_robot

    work = opt.work
    sc = load_named_scenario(opt.scenario)
    robots: dict[str, Robot | None] = {"nominal": sc.model, "compliant": sc.truth}
    if "remeasured" in opt.models:
        robots["remeasured"] = resolve_robot("rocaspect-remeasured")
    stop = str(work / ".stop")

    def spec(label, scen, robot, path, tags, robot_file=None, mast="measured",
             learn=None) -> RunSpec:
        return RunSpec(label, scen, PATHS[path], str(work / label), robot=robot,
                       robot_file=robot_file, rate_hz=opt.rate_hz,
                       plant_rate_hz=opt.plant_rate_hz, mast_tensions=mast,
                       max_duration_s=opt.max_duration_s,
                       progress=str(work / f".{label}.progress"), stop_file=stop,
                       reactions=opt.reactions, tags=tags, learn=learn,
                       warmup=warmup_specs if learn is not None else None)

    first: list[DiagnoseSpec | RunSpec] = []
    second: list[RunSpec] = []
    model_file = opt.diagnosed_model
    if "diagnosed" in opt.models and model_file is None:
        cal = load_named_scenario(opt.calibration_scenario)
        model_file = str(work / "diagnosed_robot.toml")
        run = RunSpec("calibration", cal, opt.calibration_path, str(work / "calibration"),
                      robot=cal.model, kind="record", rate_hz=opt.calibration_rate_hz,
                      plant_rate_hz=opt.calibration_plant_hz,
                      max_duration_s=opt.calibration_duration_s,
                      progress=str(work / ".calibration.progress"), stop_file=stop,
                      reactions=opt.reactions, tags={"role": "calibration"})
        first.append(DiagnoseSpec("calibration", run, model_file))
    for case in opt.cases:
        scen = at_init(sc, case[1])
        for m in opt.models:
            tags = {"path": case[0], "init": case[1], "model": m}
            label = f"{m}_{_case_name(case)}"
            if m == "diagnosed":
                second.append(spec(label, scen, None, case[0], tags, robot_file=model_file))
            elif m in LEARNED:
                first.append(spec(label, scen, sc.model, case[0], tags,
                                  learn={"tracker": LEARNED[m]}))
            else:
                first.append(spec(label, scen, robots[m], case[0], tags))
    if opt.planned:
        heavy = load_named_scenario(opt.heavy_scenario)
        rob = known_truth(heavy, ("platform_mass",))
        for case in opt.cases:
            scen = at_init(heavy, case[1])
            for mast in ("measured", "planned"):
                tags = {"path": case[0], "init": case[1], "model": "compliant",
                        "mast_tensions": mast, "scenario": opt.heavy_scenario}
                first.append(spec(f"heavy-{mast}_{_case_name(case)}", scen, rob, case[0],
                                  tags, mast=mast))
    if "diagnosed" in opt.models and opt.diagnosed_model is not None:
        first.extend(second)
        second = []
    return first, second


@dataclass
class PosesOptions:
    """What ``paper-poses`` runs."""

    work: Path
    cycles: int = 30
    speeds: tuple[float, ...] = (10.0, 40.0, 100.0)
    models: tuple[str, ...] = ("nominal", "remeasured")
    sets: tuple[str, ...] = tuple(POSE_SETS)
    rate_hz: float = POSES_RATE_HZ
    plant_rate_hz: float = DWELL_PLANT_HZ
    scenario: str = SCENARIO
    diagnosed_model: str | None = None
    reactions: dict[str, str] = field(default_factory=lambda: dict(REACTIONS))


def pose_path(set_name: str, cycles: int):
    """A pose set's path (:class:`controller.paths.PathSpec`) with ``cycles`` visits of its
    poses."""
    from controller.paths import load_path

    spec = load_path(POSE_SETS[set_name])
    seg = spec.segments[0]
    if seg.visits == cycles:
        return spec
    return dataclasses.replace(spec, segments=(dataclasses.replace(seg, visits=int(cycles)),)
                               + tuple(spec.segments[1:]))


def poses_plan(opt: PosesOptions) -> list[RunSpec]:
    """The runs of ``paper-poses``: every set x speed x model (the longest first)."""
    from controller.robot import resolve_robot

    sc = load_named_scenario(opt.scenario)
    robots: dict[str, Robot | None] = {"nominal": sc.model, "compliant": sc.truth,
                                       "remeasured": resolve_robot("rocaspect-remeasured")}
    stop = str(opt.work / ".stop")
    items = []
    for set_name in reversed(opt.sets):  # gold is the longest
        path = pose_path(set_name, opt.cycles)
        for v in sorted(opt.speeds):
            for m in opt.models:
                label = f"{set_name}_{m}_{v:g}pct"
                items.append(RunSpec(
                    label, sc, path, str(opt.work / label), kind="pose",
                    robot=robots.get(m) if m != "diagnosed" else None,
                    robot_file=opt.diagnosed_model if m == "diagnosed" else None,
                    speed_pct=v, rate_hz=opt.rate_hz, plant_rate_hz=opt.plant_rate_hz,
                    progress=str(opt.work / f".{label}.progress"), stop_file=stop,
                    reactions=opt.reactions, tags={"set": set_name, "speed_pct": v, "model": m}))
    return items


# --------------------------------------------------------------------------- running


def run_campaign(phases: Sequence[Sequence[RunSpec | DiagnoseSpec]], jobs: int,
                 progress: Progress, on_result: Callable[[dict], None] | None = None
                 ) -> tuple[list[dict], list[dict]]:
    """Run the phases one after the other, each phase's items on ``jobs`` processes
    (:func:`bench.parallel.run_each`); returns (results, failures). A failure is
    ``{"label", "error"}``; a phase's items all run even when some fail. Ctrl-C or SIGTERM
    stops the runs in flight (quick stop, recordings kept; the stop file) and re-raises.
    When a calibration (:class:`DiagnoseSpec`) fails, the later phases (the diagnosed runs)
    are reported as failures without running."""
    from bench.parallel import run_each

    results: list[dict] = []
    failures: list[dict] = []
    failed_diagnosis = False
    stop_files = {it.run.stop_file if isinstance(it, DiagnoseSpec) else it.stop_file
                  for ph in phases for it in ph}
    try:
        for items in phases:
            if not items:
                continue
            if failed_diagnosis:  # later phases run the diagnosed model: nothing to run
                for it in items:
                    failures.append({"label": it.label, "error": "not run: the calibration "
                                     "run or its diagnosis failed (see calibration)"})
                    progress.done += 1
                continue
            for it in items:
                spec = it.run if isinstance(it, DiagnoseSpec) else it
                if spec.progress:
                    progress.running[it.label] = spec.progress
            for o in run_each(run_item, items, jobs=jobs, parent_pid=os.getpid()):
                progress.running.pop(o.item.label, None)
                progress.done += 1
                if o.ok:
                    results.append(o.value)
                    progress.say(f"  {o.item.label}: {_done_text(o.value)}")
                    if on_result is not None:
                        on_result(o.value)
                else:
                    failures.append({"label": o.item.label, "error": o.error})
                    progress.say(f"  {o.item.label}: FAILED: {o.error}")
                    failed_diagnosis |= isinstance(o.item, DiagnoseSpec)
    except BaseException:
        for sf in stop_files:
            if sf:
                try:
                    Path(sf).touch()
                except OSError:
                    pass
        raise
    return results, failures


def _done_text(v: dict) -> str:
    speed = v["simulated_s"] / max(v["wall_s"], 1e-9)
    txt = f"{v['simulated_s']:.0f} s simulated in {v['wall_s']:.0f} s (x{speed:.1f})"
    if "at_max_m" in v:
        txt += f", AT max {1e3 * v['at_max_m']:.1f} mm, mean {1e3 * v['at_mean_m']:.1f} mm"
    if "worst" in v:
        txt += (f", AP {1e3 * v['worst']['ap_m']:.1f} mm, RP {1e3 * v['worst']['rp_m']:.2f} "
                f"mm")
    if "diagnosis" in v:
        names = [e["name"] for e in v["diagnosis"]["effects"]]
        txt += f"; diagnosed in {v['diagnose_s']:.0f} s: {', '.join(names) or 'no effect'}"
    if v.get("slack_events"):
        txt += f" ({v['slack_events']} slack events logged)"
    if v.get("retried"):
        txt += f"; run again after: {v['retried'][0]}"
    return txt
