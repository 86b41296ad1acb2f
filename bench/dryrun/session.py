"""One dry run wired, from checked inputs: the robot it runs on (simulated in this process,
a ``cdpr sim`` child process, or given buses), the preflight, the path planned and checked
before anything moves, the recorder, the control loop and the learner.

``cdpr dry-run`` (:mod:`bench.commands.dryrun`) reads and checks the command line into a
:class:`SessionSpec` and :class:`SessionOptions`; :meth:`Session.run` does the rest and
returns the loop's result. Signals, terminal output and the summary stay with the
command.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.dryrun.loop import ControlLoop, LoopOptions, PathRefused
from bench.dryrun.realtime import DEFAULT_RT_PRIORITY
from controller.robot import Robot


class PreflightRefused(Exception):
    """The preflight's first stage (the drives) refused the run before the buses were
    opened: :attr:`preflight` says why."""

    def __init__(self, preflight) -> None:
        super().__init__("; ".join(preflight.problems))
        self.preflight = preflight


class StartFailed(Exception):
    """The robot (``what``: the simulated robot or the buses) could not be started."""

    def __init__(self, what: str, cause: BaseException) -> None:
        super().__init__(f"cannot start {what}: {cause}")


@dataclass
class SessionSpec:
    """What a dry run runs, checked.

    ``settings``: the given buses (:mod:`hal.cli_args`), None where the command starts
    the simulated robot (``scenario`` then holds its truth); ``winches`` at the run's SYNC
    period; ``limits``: the path's limits at the run's speed (None: the path's own);
    ``decimate``: cycles per recorded row."""

    model: Robot
    path: Any  # controller.paths.PathSpec
    path_ref: str
    scenario_path: Path
    scenario: Any | None  # firmware_sim.scenario.Scenario
    settings: Any | None  # hal.cli_args settings
    winches: Any  # controller.winch.WinchSet
    decimate: int
    limits: Any | None  # controller.trajectory.MotionLimits
    reactions: dict = field(default_factory=dict)
    faults: Any | None = None  # firmware_sim.faults.FaultSchedule
    faults_path: str | None = None
    record_dir: str | None = None

    @property
    def rate_hz(self) -> float:
        """The control rate [Hz]: one cycle per SYNC."""
        return 1.0 / self.winches.bus.sync_period_s



@dataclass
class SessionOptions:
    """How a dry run runs. ``rig``: ``inprocess`` or ``process`` (a ``cdpr sim`` child);
    ``on_buses``: given buses; ``ask``: confirm before moving (``confirm`` asks);
    ``cells``: the load cells' timing on the wall clock (used on buses in real time);
    ``say``: a line for the operator (stderr)."""

    rig: str = "inprocess"
    on_buses: bool = False
    realtime: bool = False
    ask: bool = False
    force: bool = False
    fmt: str = "csv"
    live: str | None = None
    plant_rate_hz: float = 20.0
    init_pose_given: bool = False
    duration_s: float | None = None
    rt_priority: int | None = DEFAULT_RT_PRIORITY
    learn: bool = False
    learn_period_s: float = 0.5
    learn_sigma_length_m: float = 5e-4
    cells: dict | None = None
    say: Callable[[str], None] = lambda line: None
    confirm: Callable[[str], bool] = lambda question: False


class Session:
    """A dry run: :meth:`run` starts the robot, runs the loop and closes everything;
    :attr:`preflight` and :attr:`learner` are kept for the summary."""

    def __init__(self, spec: SessionSpec, opts: SessionOptions) -> None:
        self.spec = spec
        self.opts = opts
        self.preflight = None  # on buses: bench.dryrun.preflight.Preflight
        self.learner = None
        self.world = None
        self.child = None
        self.settings = spec.settings  # the given buses', or the cdpr sim child's site

    @property
    def site(self):
        """The site of the buses the run is on (hal.site.Site), or None."""
        return self.settings.site if self.settings is not None else None

    # ----- what the loop calls back ----------------------------------------------------

    def plan(self, p0: np.ndarray):
        """The trajectory from ``p0``, checked whole before anything moves (the
        preflight's readings, the cables, the site's workspace box, the confirmation);
        :class:`PathRefused` otherwise."""
        from controller.paths import build_trajectory, check_trajectory

        sp = self.spec
        if self.preflight is not None:
            self._check_readings(self.preflight)
        traj = build_trajectory(sp.path, p0, sp.limits)
        chk = check_trajectory(sp.model, traj, sp.winches)
        name = sp.path.name or sp.path_ref
        if not chk.ok:
            raise PathRefused(f"path {name} refused before moving: at t = {chk.t_s:.2f} s, "
                              f"pose {np.round(chk.pose, 3).tolist()}: {chk.reason}")
        self._check_box(traj, name)
        speed = sp.limits.speed_pct if sp.limits else sp.path.limits.speed_pct
        if self.opts.ask and not self.opts.confirm(
                f"cdpr dry-run: move the robot on {self.settings.can} along {name} "
                f"({traj.duration_s:.1f} s at {speed:g} % speed) from "
                f"p0 {np.round(p0, 3).tolist()}?"):
            raise PathRefused("not confirmed: nothing moved")
        return traj

    def _check_box(self, traj, name: str) -> None:
        """:class:`PathRefused` where the trajectory leaves the site's workspace box."""
        from controller.paths import check_times

        site = self.site
        if site is None:
            return
        ts = check_times(traj)
        poses = traj.sample(ts).pose
        out = [k for k in range(len(ts)) if site.limits.outside_box(poses[k, :3])]
        if out:
            k = out[0]
            raise PathRefused(
                f"path {name} refused before moving: at t = {ts[k]:.2f} s, position "
                f"{np.round(poses[k, :3], 3).tolist()} m is outside the site's workspace box "
                f"{list(site.limits.workspace_min_m)} .. {list(site.limits.workspace_max_m)} "
                f"({site.path})")

    def _check_readings(self, pf) -> None:
        """The preflight's second stage (load cells, tension window, tracker), said;
        :class:`PathRefused` on a problem."""
        from bench.dryrun.preflight import check_readings, preflight_text

        site = self.site
        window = ((site.limits.tension_min_N, site.limits.tension_max_N)
                  if site is not None else None)
        check_readings(self.world.hw, self.world.tracker, window,
                       require_tracker=site.require_tracker if site is not None else True,
                       out=pf)
        for line in preflight_text(pf):
            self.opts.say(line)
        if pf.problems:
            raise PathRefused("preflight refused the run before anything moved: "
                              + "; ".join(pf.problems))

    def open_recorder(self, p0: np.ndarray):
        """The run's recorder (CSV or MCAP, a live view), or None when nothing is
        recorded; an existing directory replaced with ``force``."""
        from bench.dryrun.record import open_recorder

        sp, o = self.spec, self.opts
        if sp.record_dir is None and o.live is None:
            return None
        rec = Path(sp.record_dir) if sp.record_dir is not None else None
        if rec is not None and rec.exists() and o.force:
            shutil.rmtree(rec)
        info = self.world.info
        if o.on_buses or o.rig == "process":
            src = {"pose_source": "laser tracker " + str(info.get("tracker")),
                   "tension_source": "load cells " + str(info.get("modbus"))}
        else:
            src = {"pose_source": "simulated laser tracker",
                   "tension_source": "simulated load cells"}
        meta = {**src, "notes": "dry run in progress", "scenario": str(sp.scenario_path),
                "path": str(sp.path_ref), "rate_hz": sp.rate_hz, "decimate": sp.decimate}
        return open_recorder(rec, sp.model, p0, meta,
                             robot_header=f"model the controller ran with ({sp.model.name})",
                             fmt=o.fmt, can=info.get("can"), live=o.live, child=self.child)

    # ----- the run -----------------------------------------------------------------------

    def run(self, stop, on_event: Callable[[str], None], progress: Callable[[], Any]):
        """Start the robot, run the loop until the path ends or ``stop`` is set, close
        everything (also on an exception); the loop's result. ``progress()`` makes the
        loop's progress callback once the robot is started (its clock starts then). Raises
        :class:`PreflightRefused` or :class:`StartFailed` before anything moves."""
        o = self.opts
        if o.realtime and (o.live is not None or (self.spec.record_dir is not None
                                                  and o.fmt != "csv")):
            from bench.mcap.child import Spawned

            # real time: the MCAP recording and the live view in a child process, started
            # before the robot (docs/guide/mcap-and-replay.md)
            self.child = Spawned()
        try:
            sim = self._start()
            try:
                return self._loop(stop, on_event, progress())
            finally:
                try:
                    self.world.close()
                finally:
                    if sim is not None:
                        sim.stop()
        finally:
            if self.child is not None:
                self.child.close()

    def _start(self):
        """The world: given buses (after the preflight's first stage), a ``cdpr sim``
        child's site, or the simulated robot in this process; the child (or None)."""
        sp, o = self.spec, self.opts
        sim_args: tuple[str, ...] = ()
        if sp.faults is not None and o.rig == "process":
            sim_args = ("--faults", str(sp.faults_path))
        sim = None
        try:
            if o.rig == "process" and not o.on_buses:
                from bench.dryrun.world import SimProcess
                from hal.site import load_site, merge_site

                # exactly the hardware path, on the site the simulated robot wrote
                sc = sp.scenario
                sim = SimProcess(sc.path if sc.path.name != "<memory>" else None,
                                 o.realtime, o.plant_rate_hz, sim_args,
                                 rt_priority=o.rt_priority)
                self.settings = merge_site(load_site(sim.site))
            if self.settings is not None:
                self.preflight, self.world = self._open_buses()
            else:
                from bench.dryrun.world import start_world

                self.world = start_world(sp.scenario, sp.winches, o.rig, o.realtime,
                                         o.plant_rate_hz, sim_args=sim_args,
                                         rt_priority=o.rt_priority)
        except PreflightRefused:
            if sim is not None:
                sim.stop()
            raise
        except Exception as exc:
            if sim is not None:
                sim.stop()
            what = "the simulated robot" if self.settings is None or sim is not None else \
                "the buses"
            raise StartFailed(what, exc) from exc
        return sim

    def _open_buses(self):
        """The preflight's first stage on the bus, then the :class:`HardwareWorld` (raises
        :class:`PreflightRefused` before opening it when the drives are not as configured)."""
        from bench.dryrun.hardware import HardwareWorld
        from bench.dryrun.preflight import check_drives

        st = self.settings
        site = st.site
        pf = check_drives(st.can, self.spec.winches, st.eds,
                          require_stored_safety=site.require_stored_safety if site else True)
        if pf.problems:
            raise PreflightRefused(pf)
        # lock-step: patient timing (bench.dryrun.hardware.cell_timing)
        cells = self.opts.cells if (self.opts.realtime or st.hal_clock == "wall") else None
        return pf, HardwareWorld(st, self.spec.winches, self.opts.realtime, cells)

    def _tick(self):
        """The lock-step tick of a simulated rig (None in real time or on buses), with the
        fault schedule advanced before each tick; in real time the injector runs by
        itself."""
        world, sp = self.world, self.spec
        tick = world.tick if (world.rig is not None and not self.opts.realtime) else None
        if sp.faults is None or world.rig is None:
            return tick, None
        from firmware_sim.faults import FaultInjector

        injector = FaultInjector(world.rig, sp.faults)
        if tick is None:
            injector.start()
            return None, injector

        def advance_then_tick(_b=tick, _i=injector, _rig=world.rig):
            _i.advance(_rig.time_s())
            _b()

        return advance_then_tick, injector

    def _loop(self, stop, on_event, on_progress):
        """The control loop (and the learner beside it) on the started world."""
        sp, o, world = self.spec, self.opts, self.world
        tick, injector = self._tick()
        try:
            opts = LoopOptions(realtime=o.realtime, decimate=sp.decimate,
                               init_pose=(sp.scenario.init_pose if sp.scenario is not None
                                          and o.init_pose_given else None),
                               max_duration_s=o.duration_s, reactions=sp.reactions,
                               rt_priority=o.rt_priority)
            self.learner = self._learner()
            loop = ControlLoop(world.hw, world.tracker, sp.model, self.plan, opts,
                               self.open_recorder, tick=tick, on_event=on_event,
                               on_progress=on_progress, stop=stop, on_cycle=self.learner)
            if self.learner is not None:  # its identifiability said before the platform moves
                self.learner.trajectory = lambda: loop.trajectory
                rig = getattr(world, "rig", None)
                if rig is not None:  # quasi-static samples at the plant's settles
                    self.learner.state_time = lambda: rig.last.t_s
            try:
                return loop.run()
            finally:
                if self.learner is not None:
                    self.learner.close()
        finally:
            if injector is not None:
                injector.stop()

    def _learner(self):
        """The online estimator (``--learn``), or None: on the wall clock in its own
        process (the cycle never waits for it), lock-step in the cycle (reproducible)."""
        o = self.opts
        if not o.learn:
            return None
        from bench.dryrun.learn import LoopLearner
        from controller.online_ident import IdentOptions

        return LoopLearner(self.world.tracker, o.learn_period_s,
                           IdentOptions(sigma_length=o.learn_sigma_length_m, prior_offset=0.05),
                           threaded=o.realtime, process=True,
                           shared_clock=getattr(self.world, "rig", None) is not None)
