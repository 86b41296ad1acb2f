"""``cdpr dry-run SCENARIO``: the controller in the loop with the simulated robot.

Starts the simulated drives, load cells and tracker (in this process on the virtual bus,
or as a ``cdpr sim`` process over the socketcand hub and Modbus/TCP), runs the controller
over the scenario's path (or ``--path``), shows progress, and prints a summary: pose
errors along the path (tracker against the commanded path), supervisor events. The
scenario is the truth the simulation plays; the controller runs with the scenario's model
(``robot``) or ``--robot``, and never reads the scenario. Ctrl-C stops the platform (quick
stop, drives held), closes everything and leaves the recording readable.

``--json`` prints one object: ``{"scenario", "robot", "cycles", "rate_hz",
"simulated_s", "wall_s", "overruns", "events": [{"t", "device", "address", "kind", "code",
"reaction"}], "pose_error_rms_m", "pose_error_max_m", "recording"}`` plus ``ended``,
``message``, ``trajectory_s``, ``path_s``, ``init_pose``, ``reference_offset_m``,
``drive_states`` (CiA 402 states when the run ended), ``plots`` and ``rig``.

Exit status: 0 when the path was completed, 1 when the run ended otherwise (quick stop,
hold timeout, refused path), 2 for bad input, 130 on SIGINT and 143 on SIGTERM (the last
line on stderr says which; the recording is kept).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from bench.dryrun.realtime import DEFAULT_RT_PRIORITY

NAME = "dry-run"
HELP = "run the controller in the loop with the simulated robot along a path"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario file (cdpr-scenario/1) or shipped name "
                                    "(paper-centre, paper-calibration, paper-heavy); or a "
                                    "campaign of the paper: paper-paths (Table 3, Fig. 7), "
                                    "paper-poses (Fig. 6)")
    p.add_argument("--robot", metavar="PATH", default=None,
                   help="robot.toml the controller runs with (name or file) [the scenario's "
                        "robot]")
    p.add_argument("--path", metavar="FILE", default=None,
                   help="path file (cdpr-path/1, name or file) [the scenario's path]")
    p.add_argument("--rig", choices=("inprocess", "process"), default="inprocess",
                   help="simulated robot in this process (virtual bus) or as a `cdpr sim` "
                        "process (socketcand hub, Modbus/TCP) [inprocess]")
    p.add_argument("--realtime", action="store_true",
                   help="run on the wall clock (default: lock-step, as fast as possible)")
    p.add_argument("--rt-priority", type=int, default=DEFAULT_RT_PRIORITY, metavar="P",
                   help="with --realtime: the loop's thread in SCHED_FIFO at this priority "
                        "when the system permits it, else normal scheduling, said at start "
                        f"(0: normal) [{DEFAULT_RT_PRIORITY}]")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="control rate (SYNC) [the highest the CAN bus load allows]")
    p.add_argument("--speed-pct", type=float, default=None, metavar="P",
                   help="velocity as a percentage of the path's maximum speed [the path's]")
    p.add_argument("--init-pose", choices=("tracker", "given"), default="tracker",
                   help="initialisation pose: measured by the tracker, or the scenario's "
                        "init_pose as given [tracker]")
    p.add_argument("--plant-rate", type=float, default=20.0, metavar="HZ",
                   help="plant settles per second of simulated time [20]")
    p.add_argument("--record", metavar="DIR", default=None,
                   help="write the run as a cdpr-recording/1 directory (with events.csv)")
    p.add_argument("--decimate", type=int, default=None, metavar="N",
                   help="record every N-th cycle [about 50 rows per second]")
    p.add_argument("--force", action="store_true", help="overwrite a non-empty --record DIR")
    p.add_argument("--plots", metavar="DIR", default=None, help="write PNG plots of the run")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds of trajectory time")
    p.add_argument("--faults", metavar="FILE", default=None,
                   help="fault schedule (TOML, [[fault]] tables) applied to the simulated "
                        "drives and load cells")
    p.add_argument("--react", action="append", default=[], metavar="CONDITION=REACTION",
                   help="change a supervisor reaction, e.g. slack=log (repeatable; "
                        "conditions and defaults: docs/guide/safety-reactions.md)")
    p.add_argument("--learn", action="store_true",
                   help="identify the exit points and mast stiffnesses online from the tracker's "
                   "fixes, tensions and encoders, and run the controller with the identified "
                   "model, handed over at a bounded rate (lock-step only; "
                   "docs/explanation/online-identification.md)")
    p.add_argument("--learn-period", type=float, default=0.5, metavar="S",
                   help="seconds of loop time between two estimator updates (default 0.5)")
    p.add_argument("--learn-sigma-length", type=float, default=5e-4, metavar="M",
                   help="the estimator's length noise per sample [m] (default 5e-4: the "
                   "winding repeatability of a visit, not the encoders' resolution)")
    p.add_argument("--learn-out", metavar="ROBOT.toml", default=None,
                   help="write the identified model as a robot.toml at the end of the run")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    g = p.add_argument_group("the paper's campaigns (paper-paths, paper-poses)")
    g.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="runs in parallel processes [2]")
    g.add_argument("--models", metavar="LIST", default=None,
                   help="controller models, of nominal, remeasured, compliant, diagnosed, and "
                        "for paper-paths planned (the measured-vs-planned tensions comparison) "
                        "[paper-paths: all; paper-poses: nominal,remeasured]")
    g.add_argument("--diagnosed-model", metavar="ROBOT.toml", default=None,
                   help="the diagnosed model: this corrected robot.toml (no calibration run)")
    g.add_argument("--cases", metavar="LIST", default=None,
                   help="paper-paths: cases as PATH/INIT, e.g. side/centre [the four of "
                        "Table 3]")
    g.add_argument("--sets", metavar="LIST", default=None,
                   help="paper-poses: pose sets, of violet, pink, gold [all three]")
    g.add_argument("--cycles", type=int, default=30, metavar="N",
                   help="paper-poses: visits of each pose [30]")
    g.add_argument("--speeds", metavar="LIST", default=None,
                   help="paper-poses: velocities in %% of 0.5 m/s [10,40,100]")


def _fail(args: argparse.Namespace, code: int, msg: str) -> int:
    print(f"cdpr dry-run: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return code


def _check_dir(path: str, force: bool, what: str, created: list | None = None) -> str | None:
    """Why ``path`` cannot take the output, or None (checked before anything runs, by
    creating the missing parents and writing a probe file)."""
    from bench.outputs import output_dir_problem

    p = Path(path)
    if p.is_dir() and any(p.iterdir()) and not force:
        return f"{what} {p}: not empty (use --force to overwrite)"
    return output_dir_problem(p, what, created)


def _progress_printer(quiet: bool, duration_s: float | None = None):
    t0 = time.perf_counter()
    tty = sys.stderr.isatty()

    def show(res, t_traj: float) -> None:
        if quiet:
            return
        # the bar, the percentage and the time are all trajectory time against where the
        # run ends: the path's end, or --duration when that comes first (the loop's end);
        # the initialisation before the path starts reads 0 %
        total = res.path_s or 1.0
        end = min(total, duration_s) if duration_s else total
        frac = min(1.0, max(0.0, t_traj / end))
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        wall = time.perf_counter() - t0
        speed = res.simulated_s / wall if wall > 0 else 0.0
        rate = res.cycles / wall if wall > 0 else 0.0
        err = res.pose_error_rms_m
        of = f" (--duration, path {total:.1f} s)" if end < total else ""
        line = (f"[{bar}] {100 * frac:5.1f}%  t {t_traj:7.1f}/{end:.1f} s{of}  "
                f"{rate:6.0f} cycles/s (x{speed:4.1f})  overruns {res.overruns}  "
                f"events {sum(1 for e in res.events if e['reaction'] != 'event')}  "
                f"pose error {'-' if err is None else f'{1e3 * err:.1f} mm rms'}")
        print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr,
              flush=True)

    return show


def run(args: argparse.Namespace) -> int:
    if args.scenario in ("paper-paths", "paper-poses"):
        from bench.dryrun import paper_command

        return paper_command.run(args)
    from bench.outputs import removing_created

    # refused or failed before recording (a bad fault file, Ctrl-C): no directory made
    # for --record or --plots left
    return removing_created(lambda created: _run(args, created))


def _run(args: argparse.Namespace, created: list) -> int:
    import dataclasses

    import numpy as np

    from bench.dryrun.scenarios import max_rate_hz, resolve_scenario, sync_period_us
    from controller.robot import RobotFileError, resolve_robot
    from controller.winch import load_winches
    from firmware_sim.scenario import ScenarioError, load_scenario

    if args.learn and args.realtime:
        return _fail(args, 2, "--learn runs the estimator inside the loop's thread: lock-step "
                              "only (drop --realtime)")
    if not args.learn_period > 0:
        return _fail(args, 2, f"--learn-period: {args.learn_period} s, must be > 0")
    try:
        sc_path = resolve_scenario(args.scenario)
        sc = load_scenario(sc_path)
        model = resolve_robot(args.robot) if args.robot else sc.model
    except (FileNotFoundError, ScenarioError, RobotFileError) as exc:
        return _fail(args, 2, str(exc))
    path_ref = args.path or sc.run_path
    if not path_ref:
        return _fail(args, 2, f"{sc_path}: the scenario names no path (path = ...): give "
                              f"--path FILE")
    from controller.paths import PathFileError, build_trajectory, check_trajectory, load_path
    try:
        spec = load_path(path_ref)
    except (FileNotFoundError, PathFileError) as exc:
        return _fail(args, 2, str(exc))
    winches = load_winches()
    top = max_rate_hz(winches)
    rate = top if args.rate is None else float(args.rate)
    if not (rate > 0 and np.isfinite(rate)):
        return _fail(args, 2, f"--rate {args.rate}: must be a positive number of Hz")
    if rate > top * (1 + 1e-9):
        return _fail(args, 2, f"--rate {rate:g} Hz: above the {top:.1f} Hz the CAN bus allows "
                              f"for {len(winches)} drives at {winches.bus.bitrate} bit/s "
                              f"(bus load 50 %, hal/bus_load.py)")
    if args.speed_pct is not None and not 0 < args.speed_pct <= 100:
        return _fail(args, 2, f"--speed-pct {args.speed_pct}: must be in (0, 100]")
    from controller.supervisor import parse_reactions
    try:  # the scenario's own (its ``react`` table), then the command line's
        reactions = parse_reactions([f"{k}={v}" for k, v in sc.react.items()])
        reactions.update(parse_reactions(args.react))
    except ValueError as exc:
        return _fail(args, 2, f"--react {exc}")
    if args.decimate is not None and args.decimate < 1:
        return _fail(args, 2, f"--decimate {args.decimate}: must be >= 1")
    if not args.plant_rate > 0:
        return _fail(args, 2, f"--plant-rate {args.plant_rate}: must be > 0")
    for d, what in ((args.record, "--record"), (args.plots, "--plots")):
        if d is not None and (msg := _check_dir(d, args.force or what == "--plots", what,
                                                created)):
            return _fail(args, 2, msg)
    # --plots without --record: the plots are drawn from a recording in a scratch directory
    scratch = None
    record_dir = args.record
    if args.plots and record_dir is None:
        import tempfile

        scratch = tempfile.TemporaryDirectory(prefix="cdpr-dryrun-")
        record_dir = str(Path(scratch.name) / "rec")
    faults = None
    if args.faults:
        from controller.loadcell_map import DEFAULT_MAP
        from firmware_sim.faults import FaultSchedule, FaultScheduleError
        try:
            faults = FaultSchedule.load(args.faults,
                                        node_ids=tuple(int(x) for x in winches.node_id),
                                        unit_ids=tuple(DEFAULT_MAP.unit_ids))
        except (OSError, FaultScheduleError) as exc:
            return _fail(args, 2, str(exc))

    from bench.dryrun.loop import ControlLoop, LoopOptions, PathRefused
    from bench.dryrun.record import DryRunRecorder
    from bench.dryrun.world import start_world, with_rate

    winches = with_rate(winches, sync_period_us(rate) * 1e-6)
    period = winches.bus.sync_period_s
    rate = 1.0 / period
    decimate = args.decimate or max(1, int(round(rate / 50.0)))
    limits = None
    if args.speed_pct is not None:
        limits = dataclasses.replace(spec.limits, speed_pct=float(args.speed_pct))

    def plan(p0):
        traj = build_trajectory(spec, p0, limits)
        chk = check_trajectory(model, traj, winches)
        if not chk.ok:
            raise PathRefused(f"path {spec.name or path_ref} refused before moving: at "
                              f"t = {chk.t_s:.2f} s, pose {np.round(chk.pose, 3).tolist()}: "
                              f"{chk.reason}")
        return traj

    def open_recorder(p0):
        if record_dir is None:
            return None
        import shutil

        rec = Path(record_dir)
        if rec.exists() and args.force:
            shutil.rmtree(rec)
        meta = {"pose_source": "simulated laser tracker", "tension_source": "simulated load "
                "cells", "notes": "dry run in progress", "scenario": str(sc_path),
                "path": str(path_ref), "rate_hz": rate, "decimate": decimate}
        return DryRunRecorder(rec, model, p0, meta,
                              robot_header=f"model the controller ran with ({model.name})")

    if not args.quiet:
        print(f"cdpr dry-run: {sc_path.name} with model {model.name}, path "
              f"{spec.name or path_ref}, {rate:.1f} Hz (bus limit {top:.1f} Hz), "
              f"{'real time' if args.realtime else 'lock-step, as fast as possible'}, "
              f"rig {args.rig}", file=sys.stderr)
        if reactions:
            print("cdpr dry-run: supervisor reactions changed: " + ", ".join(
                f"{k}={r.label}" for k, r in reactions.items())
                + (f" (scenario: {', '.join(f'{k}={v}' for k, v in sc.react.items())})"
                   if sc.react else ""), file=sys.stderr)
    stop = threading.Event()
    previous = {}
    caught: list[int] = []  # the signals that stopped the run (exit status 130 / 143)

    def on_signal(signum, frame):
        if stop.is_set():  # a second Ctrl-C: give up waiting
            from bench.parallel import Terminated
            raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)
        caught.append(signum)
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            previous[s] = signal.signal(s, on_signal)
    tty = sys.stderr.isatty()
    events_out: list[str] = []

    def on_event(line: str) -> None:
        events_out.append(line)
        if not args.quiet:
            print(("\r\033[K" if tty else "") + line, file=sys.stderr, flush=True)

    sim_args: tuple[str, ...] = ()
    if faults is not None and args.rig == "process":
        sim_args = ("--faults", str(args.faults))
    try:
        try:
            world = start_world(sc, winches, args.rig, args.realtime, args.plant_rate,
                                sim_args=sim_args)
        except Exception as exc:
            return _fail(args, 1, f"cannot start the simulated robot: {exc}")
        injector = None
        try:
            tick = world.tick if (world.rig is not None and not args.realtime) else None
            if faults is not None and world.rig is not None:
                from firmware_sim.faults import FaultInjector
                injector = FaultInjector(world.rig, faults)
                if tick is not None:
                    base_tick = tick

                    def tick(_b=base_tick, _i=injector, _rig=world.rig):
                        _i.advance(_rig.time_s())
                        _b()
                else:
                    injector.start()
            opts = LoopOptions(realtime=args.realtime, decimate=decimate,
                               init_pose=sc.init_pose if args.init_pose == "given" else None,
                               max_duration_s=args.duration, reactions=reactions,
                               rt_priority=args.rt_priority)
            learner = None
            if args.learn:
                from bench.dryrun.learn import LoopLearner
                from controller.online_ident import IdentOptions
                learner = LoopLearner(world.tracker, args.learn_period,
                                      IdentOptions(sigma_length=args.learn_sigma_length,
                                                   prior_offset=0.05))
            loop = ControlLoop(world.hw, world.tracker, model, plan, opts, open_recorder,
                               tick=tick, on_event=on_event,
                               on_progress=_progress_printer(args.quiet, args.duration), stop=stop,
                               on_cycle=learner)
            res = loop.run()
        finally:
            if injector is not None:
                injector.stop()
            world.close()
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    if tty and not args.quiet:
        print(file=sys.stderr)
    plots = None
    if args.plots and record_dir and res.ended != "refused":
        from bench.dryrun.report import plot_run
        plots = [str(p) for p in plot_run(record_dir, args.plots)]
    if scratch is not None:
        scratch.cleanup()
    out = {
        "scenario": str(args.scenario), "robot": model.name, "cycles": res.cycles,
        "rate_hz": res.rate_hz, "simulated_s": res.simulated_s, "wall_s": res.wall_s,
        "overruns": res.overruns,
        "events": [e for e in res.events if e["reaction"] != "event" or e["kind"] in
                   ("fault", "emcy", "heartbeat_lost", "boot_up")],
        "pose_error_rms_m": res.pose_error_rms_m, "pose_error_max_m": res.pose_error_max_m,
        "recording": str(args.record) if args.record and res.ended != "refused" else None,
        "ended": res.ended, "message": res.message, "trajectory_s": res.trajectory_s,
        "path_s": res.path_s, "init_pose": res.init_pose,
        "reference_offset_m": res.reference_offset_m, "drive_states": res.drive_states,
        "plots": plots, "rig": args.rig, "scheduling": res.scheduling,
    }
    if learner is not None:
        out["learn"] = learner.report()
        if args.learn_out and learner.identified() is not None:
            from controller.robot import save_robot
            out["learn"]["robot"] = str(save_robot(
                learner.identified(), args.learn_out,
                header=f"identified online by cdpr dry-run --learn from {model.name}"))
    if args.json:
        print(json.dumps(out))
    else:
        from bench.dryrun.report import summary_text
        print(summary_text(out))
    if res.ended == "refused":
        print(f"cdpr dry-run: {res.message}", file=sys.stderr)
    if caught:  # SIGINT 130, SIGTERM 143, the last line on stderr says which (recording kept)
        from bench.parallel import signal_exit
        code, msg = signal_exit(caught[0])
        print(f"cdpr dry-run: {msg}", file=sys.stderr, flush=True)
        return code
    return 0 if res.ended == "completed" else 1
