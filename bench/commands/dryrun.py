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

On given buses (``--site FILE``, or ``--can``/``--modbus``/``--tracker`` over a site's or
alone) the same loop runs against whatever is behind them, the real winches or a ``cdpr
sim`` started apart, and starts nothing (:class:`bench.dryrun.hardware.HardwareWorld`).
The positional argument is then a path file or a scenario whose ``path`` is run (its
truth is not used: nothing is simulated); the controller's model is ``--robot`` or the
site's robot. Before anything moves: the read-only preflight (:mod:`bench.dryrun.preflight`:
identities, stored safety parameters, another master, load cells, tension window,
tracker), the referencing, the check of the whole path (and of the site's workspace box),
and a confirmation (``--yes`` skips it; without a terminal on stdin the run is refused,
nothing opened). The speed is capped at the site's ``first_run_speed_pct`` unless
``--speed-pct`` is given; drives on the wall clock (the site's ``clock``, ``--hal-clock``)
always get a real-time run. ``--rig process`` is exactly this path on the site a ``cdpr sim``
child process wrote (no confirmation: the robot is simulated and started by the command).
The ``--json`` object then also has ``site`` and ``preflight``; a refusal by the preflight
ends the run like a refused path.

Exit status: 0 when the path was completed, 1 when the run ended otherwise (quick stop,
hold timeout, refused path), 2 for bad input, 130 on SIGINT and 143 on SIGTERM (the last
line on stderr says which; the recording is kept).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.commands.argtypes import add_format_and_live, positive_float
from bench.dryrun.realtime import DEFAULT_RT_PRIORITY

if TYPE_CHECKING:
    from bench.dryrun.session import SessionSpec

NAME = "dry-run"
HELP = "run the controller in the loop with the simulated robot along a path"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="PATH_OR_SCENARIO",
                   help="scenario file (cdpr-scenario/1) or shipped name "
                        "(paper-centre, paper-calibration, paper-heavy); or a "
                        "campaign of the paper: paper-paths (Table 3, Fig. 7), "
                        "paper-poses (Fig. 6); with --site or --can: a path file "
                        "(cdpr-path/1, name or file) or a scenario whose path is run")
    p.add_argument("--robot", metavar="PATH", default=None,
                   help="robot.toml the controller runs with (name or file) [the scenario's "
                        "robot]")
    p.add_argument("--path", metavar="FILE", default=None,
                   help="path file (cdpr-path/1, name or file) [the scenario's path]")
    p.add_argument("--rig", choices=("inprocess", "process"), default="inprocess",
                   help="simulated robot in this process (virtual bus) or as a `cdpr sim` "
                        "process reached through the site it writes, as real hardware is "
                        "(socketcand hub, Modbus/TCP) [inprocess]; not with --site/--can")
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
    add_format_and_live(p, "docs/guide/mcap-and-replay.md", "the run")
    p.add_argument("--decimate", type=int, default=None, metavar="N",
                   help="record every N-th cycle [about 50 rows per second]")
    p.add_argument("--force", action="store_true", help="overwrite a non-empty --record DIR")
    p.add_argument("--plots", metavar="DIR", default=None, help="write PNG plots of the run")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
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
                   "model, handed over at a bounded rate (with --realtime or on given buses "
                   "the estimator runs in a process of its own; "
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
    p.add_argument("--yes", action="store_true",
                   help="on given buses (--site, --can): do not ask for confirmation before "
                        "the drives are enabled")
    from hal.cli_args import add_hardware_arguments

    add_hardware_arguments(p, tracker=True)
    g = p.add_argument_group("the paper's campaigns (paper-paths, paper-poses)")
    g.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="runs in parallel processes [2]")
    g.add_argument("--models", metavar="LIST", default=None,
                   help="controller models, of nominal, remeasured, compliant, diagnosed, "
                        "learned, learned_warmup, learned_untracked, learned_notracker, and "
                        "for paper-paths "
                        "planned (the measured-vs-planned tensions comparison) [paper-paths: "
                        "nominal, "
                        "remeasured, compliant, diagnosed, planned; paper-poses: "
                        "nominal,remeasured]")
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
    """The run's progress (:class:`bench.progress.Progress`): the fraction is trajectory
    time against where the run ends (the path's end, or --duration when that comes first);
    the initialisation before the path starts reads 0 %."""
    from bench.progress import Progress

    prog = Progress("dry-run", None, quiet)

    def show(res, t_traj: float) -> None:
        total = res.path_s or 1.0
        end = min(total, duration_s) if duration_s else total
        wall = prog.elapsed_s()
        speed = res.simulated_s / wall if wall > 0 else 0.0
        err = res.pose_error_rms_m
        of = f" (--duration, path {total:.1f} s)" if end < total else ""
        prog.update(min(1.0, max(0.0, t_traj / end)), (
            f"t {t_traj:.1f}/{end:.1f} s{of}, {res.cycles / wall if wall > 0 else 0.0:.0f} "
            f"cycles/s (x{speed:.1f}), overruns {res.overruns}, "
            f"events {sum(1 for e in res.events if e['reaction'] != 'event')}, pose error "
            f"{'-' if err is None else f'{1e3 * err:.1f} mm rms'}"))

    return show


def run(args: argparse.Namespace) -> int:
    if args.scenario in ("paper-paths", "paper-poses", "paper-drift"):
        from bench.dryrun import paper_command

        return paper_command.run(args)
    from bench.outputs import removing_created

    # refused or failed before recording (a bad fault file, Ctrl-C): no directory made
    # for --record or --plots left
    return removing_created(lambda created: _run(args, created))


def _on_buses(args: argparse.Namespace) -> bool:
    """Whether the run goes to given buses (``--site`` or ``--can`` on the command line)."""
    from hal.cli_args import GIVEN

    return bool(args.site) or "can" in (getattr(args, GIVEN, None) or ())


def _bus_inputs(args: argparse.Namespace):
    """On given buses: ``(settings, label, path_ref, model, scenario_react)`` from the site
    and the command line, read without the simulation (a scenario only names the path).
    Raises ValueError (SiteError, RobotFileError, ...) for bad input; nothing opened."""
    from bench.dryrun.scenarios import resolve_scenario
    from controller.robot import resolve_robot
    from controller.tomlfile import read_toml
    from hal.cli_args import GIVEN, apply_site
    from hal.site import check_site_files

    given = set(getattr(args, GIVEN, None) or ())
    settings = apply_site(args)
    if settings.site is not None:
        check_site_files(settings.site)
    if settings.can is None:
        raise ValueError("no CAN bus: give --can SPEC or a --site with [can] interface")
    if "hal_clock" not in given and settings.site is None:
        settings = dataclasses.replace(settings, hal_clock="wall")
    if settings.tracker is None:
        raise ValueError("no tracker: the dry run measures the initial pose and the pose "
                         "error with one: give --tracker tcp:HOST:PORT or a --site with "
                         "[tracker] endpoint")
    robot_ref = args.robot or (settings.site.robot if settings.site else None)
    if robot_ref is None:
        raise ValueError("no robot description: give --robot or a --site with [robot]")
    model = resolve_robot(robot_ref)
    label, path_ref, react = str(args.scenario), args.scenario, {}
    try:
        sc_path = resolve_scenario(args.scenario)
    except FileNotFoundError:
        sc_path = None  # a path file or a shipped path's name
    if sc_path is not None:
        data, _ = read_toml(sc_path, ValueError)
        if str(data.get("format", "")).startswith("cdpr-scenario/"):
            label, react = sc_path.name, dict(data.get("react", {}) or {})
            run = data.get("path", "")
            if not run:
                raise ValueError(f"{sc_path}: the scenario names no path (path = ...): "
                                 "give --path FILE")
            path_ref = str(sc_path.parent / run) if (sc_path.parent / run).exists() else run
    return settings, label, args.path or path_ref, model, react


def _confirm(question: str) -> bool:
    """Ask on the terminal; True for 'yes'."""
    print(f"{question} Type 'yes' to go on: ", end="", file=sys.stderr, flush=True)
    answer = sys.stdin.readline()
    return answer.strip().lower() == "yes"


def _run(args: argparse.Namespace, created: list) -> int:
    from hal.cli_args import GIVEN

    on_buses = _on_buses(args)
    given = set(getattr(args, GIVEN, None) or ()) - {"can"}
    if on_buses and args.rig != "inprocess":
        return _fail(args, 2, "--rig process starts its own simulated robot; --site/--can "
                              "reach one that runs already: give one or the other")
    if not on_buses and given:
        return _fail(args, 2, f"--{sorted(given)[0].replace('_', '-')} is for given buses: "
                              "give --site FILE or --can SPEC")
    if on_buses and args.faults:
        return _fail(args, 2, "--faults acts on a simulated robot this command starts; on "
                              "given buses use `cdpr sim --faults` (or its control channel)")
    if on_buses and not args.yes and not sys.stdin.isatty():
        return _fail(args, 2, "a dry run on given buses needs confirmation before the drives "
                              "are enabled: stdin is not a terminal, give --yes "
                              "(nothing was opened)")
    return _run_checked(args, created, on_buses)


class _BadInput(Exception):
    """A command-line value or input file refused before anything runs (exit 2)."""


@dataclass
class _Inputs:
    """The checked inputs: the session's spec, the bus's top rate [Hz], the speed [% of
    the path's] asked or the site's first-run limit (None: the path's own), the scenario's
    own reactions (said), and the scratch directory of ``--plots`` without ``--record``."""

    spec: SessionSpec
    top_hz: float
    speed_pct: float | None
    scenario_react: dict
    scratch: Any | None


def _run_checked(args: argparse.Namespace, created: list, on_buses: bool) -> int:
    from bench.dryrun.session import PreflightRefused, Session, StartFailed
    from bench.parallel import stopping_on_signals

    try:
        inp = _inputs(args, created, on_buses)
    except _BadInput as exc:
        return _fail(args, 2, str(exc))
    _announce(args, inp, on_buses)
    tty = sys.stderr.isatty()
    events_out: list[str] = []

    def on_event(line: str) -> None:
        events_out.append(line)
        if not args.quiet:
            print(("\r\033[K" if tty else "") + line, file=sys.stderr, flush=True)

    session = Session(inp.spec, _options(args, on_buses))
    with stopping_on_signals() as (stop, caught):
        try:
            res = session.run(stop, on_event,
                              lambda: _progress_printer(args.quiet, args.duration))
        except PreflightRefused as exc:
            return _refused(args, exc.preflight)
        except StartFailed as exc:
            return _fail(args, 1, str(exc))
    if tty and not args.quiet:
        print(file=sys.stderr)
    out = _result(args, inp, session, res, on_buses)
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


def _scenario_inputs(args: argparse.Namespace, on_buses: bool):
    """(settings, scenario, its path, the path's reference, the model, the scenario's
    reactions): from the given buses' site and the positional argument, or from the
    scenario the simulated robot plays. On buses with drives on the wall clock the run
    is made real time (said)."""
    from controller.robot import RobotFileError

    if on_buses:
        try:
            settings, sc_label, path_ref, model, sc_react = _bus_inputs(args)
        except (ValueError, FileNotFoundError) as exc:
            raise _BadInput(str(exc)) from exc
        if settings.hal_clock == "wall" and not args.realtime:
            # drives on the wall clock take each SYNC as one period: a loop as fast as
            # possible would move them faster than planned
            args.realtime = True
            if not args.quiet:
                print("cdpr dry-run: the drives run on the wall clock (the site's clock, or "
                      "--hal-clock wall): the dry run runs in real time", file=sys.stderr)
        return settings, None, Path(sc_label), path_ref, model, sc_react
    from bench.dryrun.scenarios import resolve_scenario
    from controller.robot import resolve_robot
    from firmware_sim.scenario import ScenarioError, load_scenario

    try:
        sc_path = resolve_scenario(args.scenario)
        sc = load_scenario(sc_path)
        model = resolve_robot(args.robot) if args.robot else sc.model
    except (FileNotFoundError, ScenarioError, RobotFileError) as exc:
        raise _BadInput(str(exc)) from exc
    path_ref = args.path or sc.run_path
    if not path_ref:
        raise _BadInput(f"{sc_path}: the scenario names no path (path = ...): give --path FILE")
    return None, sc, sc_path, path_ref, model, dict(sc.react)


def _inputs(args: argparse.Namespace, created: list, on_buses: bool) -> _Inputs:
    """Every input read and checked before anything runs; :class:`_BadInput` naming the
    option or file and the allowed range otherwise."""
    from bench.dryrun.hardware import with_rate
    from bench.dryrun.scenarios import max_rate_hz, sync_period_us
    from bench.dryrun.session import SessionSpec
    from controller.paths import PathFileError, load_path
    from controller.winch import load_winches

    settings, sc, sc_path, path_ref, model, sc_react = _scenario_inputs(args, on_buses)
    try:
        spec = load_path(path_ref)
        winches = load_winches(settings.winches if settings is not None else None)
    except (FileNotFoundError, PathFileError, ValueError) as exc:
        raise _BadInput(str(exc)) from exc
    top = max_rate_hz(winches)
    rate = top if args.rate is None else float(args.rate)
    if not (rate > 0 and math.isfinite(rate)):
        raise _BadInput(f"--rate {args.rate}: must be a positive number of Hz")
    if rate > top * (1 + 1e-9):
        raise _BadInput(f"--rate {rate:g} Hz: above the {top:.1f} Hz the CAN bus allows for "
                        f"{len(winches)} drives at {winches.bus.bitrate} bit/s (bus load 50 %, "
                        f"hal/bus_load.py)")
    reactions = _check_options(args, sc_react)
    record_dir, scratch = _output_dirs(args, created)
    winches = with_rate(winches, sync_period_us(rate) * 1e-6)
    speed_pct = args.speed_pct
    if speed_pct is None and settings is not None and settings.site is not None:
        # a first run on a site: at most the site's speed (unless --speed-pct says)
        speed_pct = min(spec.limits.speed_pct, settings.site.limits.first_run_speed_pct)
    limits = None if speed_pct is None else \
        dataclasses.replace(spec.limits, speed_pct=float(speed_pct))
    decimate = args.decimate or max(1, int(round(1.0 / winches.bus.sync_period_s / 50.0)))
    faults = _faults(args, winches)
    return _Inputs(SessionSpec(model, spec, path_ref, sc_path, sc, settings, winches, decimate,
                               limits, reactions, faults, args.faults, record_dir),
                   top, speed_pct, sc_react, scratch)


def _check_options(args: argparse.Namespace, sc_react: dict) -> dict:
    """The numeric options checked; the supervisor's reactions (the scenario's ``react``
    table, then the command line's)."""
    from controller.supervisor import parse_reactions

    if args.speed_pct is not None and not 0 < args.speed_pct <= 100:
        raise _BadInput(f"--speed-pct {args.speed_pct}: must be in (0, 100]")
    try:
        reactions = parse_reactions([f"{k}={v}" for k, v in sc_react.items()])
        reactions.update(parse_reactions(args.react))
    except ValueError as exc:
        raise _BadInput(f"--react {exc}") from exc
    if args.live is not None:
        from bench.mcap.live import parse_address
        try:
            parse_address(args.live)
        except ValueError as exc:
            raise _BadInput(str(exc)) from exc
    if not args.learn_period > 0:
        raise _BadInput(f"--learn-period: {args.learn_period} s, must be > 0")
    if args.decimate is not None and args.decimate < 1:
        raise _BadInput(f"--decimate {args.decimate}: must be >= 1")
    if not args.plant_rate > 0:
        raise _BadInput(f"--plant-rate {args.plant_rate}: must be > 0")
    return reactions


def _output_dirs(args: argparse.Namespace, created: list) -> tuple[str | None, Any | None]:
    """The recording's directory, checked (with ``--plots`` alone: a scratch directory,
    returned to be cleaned up)."""
    for d, what in ((args.record, "--record"), (args.plots, "--plots")):
        if d is not None and (msg := _check_dir(d, args.force or what == "--plots", what,
                                                created)):
            raise _BadInput(msg)
    if not (args.plots and args.record is None):
        return args.record, None
    import tempfile

    scratch = tempfile.TemporaryDirectory(prefix="cdpr-dryrun-")
    return str(Path(scratch.name) / "rec"), scratch


def _faults(args: argparse.Namespace, winches):
    """The fault schedule of ``--faults`` (its CAN nodes and Modbus units checked against
    the drives and the load cells), or None."""
    if not args.faults:
        return None
    from controller.loadcell_map import DEFAULT_MAP
    from firmware_sim.faults import FaultSchedule, FaultScheduleError
    try:
        return FaultSchedule.load(args.faults, node_ids=tuple(int(x) for x in winches.node_id),
                                  unit_ids=tuple(DEFAULT_MAP.unit_ids))
    except (OSError, FaultScheduleError) as exc:
        raise _BadInput(str(exc)) from exc


def _options(args: argparse.Namespace, on_buses: bool):
    """The session's options from the command line."""
    from bench.dryrun.session import SessionOptions

    def say(line: str) -> None:
        if not args.quiet:
            print(line, file=sys.stderr)

    return SessionOptions(
        rig=args.rig, on_buses=on_buses, realtime=args.realtime,
        ask=on_buses and not args.yes, force=args.force, fmt=args.format, live=args.live,
        plant_rate_hz=args.plant_rate, init_pose_given=args.init_pose == "given",
        duration_s=args.duration, rt_priority=args.rt_priority, learn=args.learn,
        learn_period_s=args.learn_period, learn_sigma_length_m=args.learn_sigma_length,
        cells={"loadcell_rate_hz": args.loadcell_rate,
               "loadcell_timeout_s": args.loadcell_timeout,
               "loadcell_stale_s": args.loadcell_stale,
               "loadcell_max_age_s": args.loadcell_max_age},
        say=say, confirm=_confirm)


def _announce(args: argparse.Namespace, inp: _Inputs, on_buses: bool) -> None:
    """The run's first lines on stderr: what runs where, at what rate and speed, and the
    supervisor's reactions changed."""
    if args.quiet:
        return
    sp = inp.spec
    site = sp.settings.site if sp.settings is not None else None
    where = (f"site {site.path}" if on_buses and site is not None
             else f"--can {sp.settings.can}" if on_buses else f"rig {args.rig}")
    speed = inp.speed_pct
    print(f"cdpr dry-run: {sp.scenario_path.name} with model {sp.model.name}, path "
          f"{sp.path.name or sp.path_ref}, {sp.rate_hz:.1f} Hz (bus limit {inp.top_hz:.1f} Hz), "
          f"{'real time' if args.realtime else 'lock-step, as fast as possible'}, "
          f"{where}" + (f", speed {speed:g} % (the site's first-run limit; "
                        f"--speed-pct to change)" if args.speed_pct is None
                        and speed is not None else ""), file=sys.stderr)
    if sp.reactions:
        react = inp.scenario_react
        print("cdpr dry-run: supervisor reactions changed: " + ", ".join(
            f"{k}={r.label}" for k, r in sp.reactions.items())
            + (f" (scenario: {', '.join(f'{k}={v}' for k, v in react.items())})"
               if react else ""), file=sys.stderr)


def _result(args: argparse.Namespace, inp: _Inputs, session, res, on_buses: bool) -> dict:
    """The ``--json`` object (and the summary's source): the loop's figures, the plots
    drawn, the preflight, the learner's report (its model written with --learn-out)."""
    sp = inp.spec
    plots = None
    if args.plots and sp.record_dir and res.ended != "refused":
        from bench.dryrun.report import plot_run
        plots = [str(p) for p in plot_run(sp.record_dir, args.plots)]
    if inp.scratch is not None:
        inp.scratch.cleanup()
    settings = session.settings
    out = {
        "scenario": str(args.scenario), "robot": sp.model.name, "cycles": res.cycles,
        "rate_hz": res.rate_hz, "simulated_s": res.simulated_s, "wall_s": res.wall_s,
        "overruns": res.overruns,
        "events": [e for e in res.events if e["reaction"] != "event" or e["kind"] in
                   ("fault", "emcy", "heartbeat_lost", "boot_up")],
        "pose_error_rms_m": res.pose_error_rms_m, "pose_error_max_m": res.pose_error_max_m,
        "recording": str(args.record) if args.record and res.ended != "refused" else None,
        "ended": res.ended, "message": res.message, "trajectory_s": res.trajectory_s,
        "path_s": res.path_s, "init_pose": res.init_pose,
        "reference_offset_m": res.reference_offset_m, "drive_states": res.drive_states,
        "plots": plots, "rig": "site" if on_buses else args.rig, "realtime": args.realtime,
        "scheduling": res.scheduling,
        "site": (str(settings.site.path) if on_buses and settings is not None
                 and settings.site is not None else None),
        "speed_pct": inp.speed_pct,
        "preflight": session.preflight.as_dict() if session.preflight is not None else None,
    }
    learner = session.learner
    if learner is not None:
        out["learn"] = learner.report()
        if args.learn_out and learner.identified() is not None:
            from controller.robot import save_robot
            out["learn"]["robot"] = str(save_robot(
                learner.identified(), args.learn_out,
                header=f"identified online by cdpr dry-run --learn from {sp.model.name}"))
    return out


def _refused(args: argparse.Namespace, pf) -> int:
    from bench.dryrun.preflight import preflight_text

    for line in preflight_text(pf):
        print(f"cdpr dry-run: {line}", file=sys.stderr)
    msg = "preflight refused the run before anything moved: " + "; ".join(pf.problems)
    print(f"cdpr dry-run: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg, "ended": "refused", "preflight": pf.as_dict()}))
    return 1
