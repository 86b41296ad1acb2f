"""``cdpr sim [SCENARIO]``: run the simulated robot until interrupted.

Eight simulated CiA 402 drives, eight Modbus load cells and the plant
(:class:`firmware_sim.rig.SimRig`). The CAN bus is served on TCP by a socketcand hub
(``--can socketcand:HOST:PORT``, PORT 0 = any free port) bridged to the rig's in-process
bus, or the drives sit on another bus given with ``--can`` (e.g. ``socketcan:can0``; then no
hub); the load cells listen at ``--modbus [rtu-tcp:]HOST:PORT``. ``--can-port`` and
``--modbus-port`` are deprecated aliases (still taken, with a warning). The command
prints where it listens, in the forms the HAL takes::

    --can socketcand:127.0.0.1:40123
    --modbus 127.0.0.1:40124
    --tracker tcp:127.0.0.1:40125

(one JSON object on one line with ``--json``) and runs until SIGINT (exit 130) or SIGTERM
(143; the last line on stderr says which), or until stdin closes with
``--exit-on-stdin-eof`` (exit 0).
A scenario file that is not valid is reported with file and field (exit 2).

``--write-site FILE`` also writes the site of the robot it serves (``cdpr-site/1``: its
endpoints, its clock, the robot, winch, EDS and register-map files it uses; the robot
description beside it, ``FILE`` with the suffix ``.robot.toml``) before it prints the
endpoints, so that ``cdpr dry-run ... --site FILE`` reaches it like a real robot.

Faults: ``--faults FILE`` applies a fault schedule on the sim's clock, and a control
channel on loopback (``--control-port``, 0 = any free port; printed as
``--control 127.0.0.1:R``) takes faults from tests and tools, one line per request
(:mod:`firmware_sim.faults` documents both). A schedule that is not valid is reported
with file, line and field (exit 2).

``--latch-log FILE`` (for checking a master's time stamps): every position the drives
latch at a SYNC they answer with a synchronous TPDO, with the drive's time of that SYNC and
the monotonic time it was handled, written as they come (:class:`LatchLog`; 8 drives at
256 Hz: ~60 MB an hour); a path that cannot be written is refused at start (exit 2).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time

from bench.commands.argtypes import tcp_port

NAME = "sim"
HELP = "run the simulated robot (drives on CAN, load cells on Modbus, plant) until interrupted"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", default=None,
                   help="scenario file (cdpr-scenario/1) or shipped name (paper-centre); "
                        "default: the rocaspect model as the truth, init pose "
                        "[10, 8.56, 1, 0, 0, 0]")
    p.add_argument("--host", default="127.0.0.1",
                   help="address the tracker, the control channel and (without --can / "
                        "--modbus) the hub and the load cells bind [127.0.0.1]")
    p.add_argument("--can-port", type=tcp_port, default=None, metavar="P",
                   help="deprecated: --can socketcand:HOST:P")
    p.add_argument("--modbus-port", type=tcp_port, default=None, metavar="Q",
                   help="deprecated: --modbus HOST:Q")
    p.add_argument("--modbus", metavar="[rtu-tcp:]HOST:PORT", default=None,
                   help="where the load cells listen (PORT 0: any free one; rtu-tcp: RTU "
                        "framing) [HOST of --host, any free port]")
    p.add_argument("--tracker-port", type=int, default=0, metavar="T",
                   help="TCP port of the simulated laser tracker, cdpr-tracker/1 protocol "
                        "(0: any free one) [0]")
    p.add_argument("--rtu", action="store_true",
                   help="load cells with RTU framing over TCP (--modbus rtu-tcp:HOST:PORT)")
    p.add_argument("--can", metavar="SPEC", default=None,
                   help="socketcand:HOST:PORT: serve the drives on a socketcand hub there "
                        "(PORT 0: any free one); any other bus (e.g. socketcan:can0): put the "
                        "drives on it, no hub [socketcand:HOST of --host:0]")
    p.add_argument("--clock", choices=("sync", "wall"), default="sync",
                   help="sync: drive and plant time advance by the SYNC period per SYNC, as "
                        "a HIL simulator follows its master, in lock-step or real time "
                        "(deadlines in SYNC periods; master loss still watched on wall "
                        "time); wall: the drives' own wall clock [sync]")
    p.add_argument("--rt-priority", type=int, default=0, metavar="P",
                   help="the simulator's threads in SCHED_FIFO at this priority when the "
                        "system permits it, else normal scheduling, said at start (0: "
                        "normal) [0]")
    p.add_argument("--plant-rate", type=float, default=20.0, metavar="HZ",
                   help="plant settles per second at most [20]")
    p.add_argument("--faults", metavar="FILE", default=None,
                   help="fault schedule (TOML [[fault]] tables, see firmware_sim/faults.py)")
    p.add_argument("--control-port", type=int, default=0, metavar="R",
                   help="TCP port of the fault control channel on the host (0: any free one) "
                        "[0]")
    p.add_argument("--exit-on-stdin-eof", action="store_true",
                   help="also stop when stdin closes (the parent process went away)")
    p.add_argument("--write-site", metavar="FILE", default=None,
                   help="write the site file (cdpr-site/1) of the robot served, and its robot "
                        "description beside it (FILE with suffix .robot.toml)")
    p.add_argument("--json", action="store_true", help="print the endpoints as one JSON line")
    p.add_argument("--latch-log", metavar="FILE", default=None,
                   help="write every position the drives latch at a SYNC they answer, as "
                        "they come (CSV: node, drive_t_s, monotonic_s, counts): the truth a "
                        "master's encoder time stamps are checked against")


def write_sim_site(path: str, rig, can_spec: str, clock: str, scenario: str | None,
                   control: str) -> str:
    """Write the site of the simulated robot ``rig`` serves to ``path``; returns its path.

    The tension window is the controller's (the supervisor's slack threshold to the robot's
    tension_max), the workspace box the exit points' bounding box; the simulated drives
    ship with their EDS values, so the stored safety parameters are not required."""
    from pathlib import Path

    import numpy as np

    from controller.paths import frame_box
    from controller.robot import save_robot
    from controller.supervisor import SLACK_FRACTION
    from firmware_sim.cia402_drive import EDS_PATH
    from hal.can_bus import parse_can_spec
    from hal.modbus_config import parse_modbus_spec
    from hal.site import Site, SiteLimits, write_site
    from hal.tracker import parse_tracker_spec

    p = Path(path).resolve()
    model = rig.scenario.model
    robot_file = save_robot(model, p.with_suffix(".robot.toml"),
                            header=f"the model of the robot cdpr sim serves ({model.name})")
    box_min, box_max = frame_box(model)  # the check of the path's own frame box
    tmax = float(model.tension_max) if np.isfinite(model.tension_max) else 1e4
    src = getattr(rig.cells.map, "source", "")
    sim = {"pid": os.getpid(), "control": control, "clock": clock}
    if scenario:
        sim["scenario"] = str(Path(scenario).resolve())
    site = Site(
        path=p, name=f"cdpr sim ({model.name})", robot=str(robot_file), eds=Path(EDS_PATH),
        limits=SiteLimits(SLACK_FRACTION * float(model.tension_min), tmax, 100.0,
                          tuple(float(v) for v in box_min), tuple(float(v) for v in box_max)),
        winches=Path(rig.winches.source) if Path(rig.winches.source).is_file() else None,
        loadcell_map=Path(src) if src and Path(src).is_file() else None,
        can=parse_can_spec(can_spec), modbus=parse_modbus_spec(rig.modbus_spec),
        tracker=parse_tracker_spec(rig.tracker_spec) if rig.tracker_spec else None,
        clock=clock, require_stored_safety=False, require_tracker=rig.tracker_spec is not None,
        sim=sim)
    return str(write_site(site, p, header="written by cdpr sim --write-site: the simulated "
                                          "robot's endpoints live as long as that process"))


class LatchLog:
    """``--latch-log FILE``: the positions the drives
    (:class:`firmware_sim.cia402_drive.SimulatedDrive`) latch at the SYNCs their synchronous
    TPDOs answer, written as they come (``SimulatedDrive.on_latch``): CSV ``node,
    drive_t_s`` (the drive's time of the SYNC: the SYNC clock's or the wall clock's)
    ``, monotonic_s`` (``time.monotonic()`` as the drive handled the SYNC) ``, counts``
    (the position actual 0x6064 sent), the nodes' rows interleaved in the order they
    latched. Opened (created or emptied) at once: OSError naming the path; flushed at least
    every :data:`LATCH_FLUSH_S` and at :meth:`close`."""

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self._file = open(path, "w", encoding="ascii")  # noqa: SIM115 (closed by close)
        except OSError as exc:
            raise OSError(f"--latch-log {path}: {exc.strerror or exc}") from exc
        self._file.write("node,drive_t_s,monotonic_s,counts\n")
        self._lock = threading.Lock()  # the drives latch in their own threads
        self._flushed = time.monotonic()

    def listener(self, node: int):
        """The ``on_latch`` of the drive with node id ``node``."""
        def on_latch(drive_t_s: float, monotonic_s: float, counts: int) -> None:
            with self._lock:
                if self._file.closed:
                    return
                self._file.write(f"{node},{drive_t_s:.6f},{monotonic_s:.6f},{counts}\n")
                if monotonic_s - self._flushed >= LATCH_FLUSH_S:
                    self._file.flush()
                    self._flushed = monotonic_s
        return on_latch

    def attach(self, drives) -> None:
        for d in drives:
            d.on_latch = self.listener(int(d.node_id))

    def close(self) -> None:
        with self._lock:
            self._file.close()


#: [s] the latch log is flushed at least this often (a sim killed loses at most this much)
LATCH_FLUSH_S = 1.0


def _fail(args: argparse.Namespace, code: int, msg: str) -> int:
    print(f"cdpr sim: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}), flush=True)
    return code


def _port(args: argparse.Namespace, name: str) -> str | None:
    value = getattr(args, name.replace("-", "_"))
    if not 0 <= value <= 65535:
        return f"--{name} {value}: not a TCP port (0..65535)"
    return None


def _endpoints(args: argparse.Namespace) -> str | None:
    """Resolve ``--can``/``--modbus`` (and the deprecated ``--can-port``/``--modbus-port``)
    into ``args.hub_host``, ``args.hub_port``, ``args.modbus_host``, ``args.modbus_port``,
    ``args.rtu``; ``args.can`` stays set only for a bus that is not a hub. The problem as
    text, or None."""
    from bench.commands.argtypes import listen_endpoint

    args.hub_host = args.modbus_host = args.host
    args.hub_port = 0 if args.can_port is None else args.can_port
    for old, new in (("can-port", "--can socketcand:HOST:P"), ("modbus-port",
                                                               "--modbus HOST:Q")):
        if getattr(args, old.replace("-", "_")) is not None:
            print(f"cdpr sim: --{old} is deprecated and will go; use {new}", file=sys.stderr)
    try:
        if args.can and args.can.startswith("socketcand:"):
            _, args.hub_host, args.hub_port = listen_endpoint("--can", args.can,
                                                              ("socketcand",))
            args.can = None
        args.modbus_port = 0 if args.modbus_port is None else args.modbus_port
        if args.modbus:
            scheme, args.modbus_host, args.modbus_port = listen_endpoint(
                "--modbus", args.modbus, ("tcp", "rtu-tcp"))
            args.rtu = args.rtu or scheme == "rtu-tcp"
    except ValueError as exc:
        return str(exc)
    return None


def run(args: argparse.Namespace) -> int:
    from bench.dryrun.realtime import simulator_scheduling
    from hal.rt_threads import check_priority

    try:
        check_priority(args.rt_priority)
    except ValueError as exc:
        return _fail(args, 2, f"--rt-priority {args.rt_priority}: {exc}")
    with simulator_scheduling(args.rt_priority) as scheduling:
        return _serve(args, scheduling)


class _Refused(Exception):
    """An input or a listening socket refused: the exit status and the message."""

    def __init__(self, code: int, msg: str) -> None:
        super().__init__(msg)
        self.code = code


def _serve(args: argparse.Namespace, scheduling: str) -> int:
    """Check the options, open the simulated robot, its fault injector and control
    channel, say where they listen, and serve until a signal (or stdin's end)."""
    from bench.parallel import stopping_on_signals

    try:
        _check(args)
        rig, bus, schedule, injector, control, latches = _open(args)
    except _Refused as exc:
        return _fail(args, exc.code, str(exc))
    with stopping_on_signals(second_raises=False) as (stop, caught):
        try:
            try:
                rig.start()
            except (RuntimeError, TimeoutError, OSError) as exc:
                return _fail(args, 1, str(exc))
            injector.start()
            control.start()
            try:
                info = _info(args, rig, bus, control, scheduling)
            except _Refused as exc:
                return _fail(args, exc.code, str(exc))
            _announce(args, info, rig, schedule, scheduling)
            _wait(args, stop)
        finally:
            control.close()
            injector.stop()
            rig.close()
            if latches is not None:
                latches.close()
    print(f"cdpr sim: stopped ({rig.settles} plant settles, {len(rig.plant_errors)} without "
          f"a rest position, {sum(r.action == 'apply' for r in injector.log)} fault(s) "
          "injected)", file=sys.stderr)
    if caught:  # stopped by SIGINT (130) or SIGTERM (143): the last line says which
        from bench.parallel import signal_exit
        code, msg = signal_exit(caught[0])
        print(f"cdpr sim: {msg}", file=sys.stderr, flush=True)
        return code
    return 0


def _check(args: argparse.Namespace) -> None:
    """The ports, the endpoints and the plant rate checked (:class:`_Refused`, exit 2)."""
    for name in ("tracker-port", "control-port"):
        if (msg := _port(args, name)) is not None:
            raise _Refused(2, msg)
    if (msg := _endpoints(args)) is not None:
        raise _Refused(2, msg)
    if not args.plant_rate > 0:
        raise _Refused(2, f"--plant-rate {args.plant_rate}: must be > 0")


def _open(args: argparse.Namespace):
    """The simulated robot (on ``--can``'s bus or a socketcand hub), its fault schedule,
    injector and control server, not started, and the latch log (``--latch-log``, open):
    (rig, bus or None, schedule or None, injector, control, latch log or None). What was
    opened is closed again on a refusal."""
    from bench.dryrun.scenarios import resolve_scenario
    from firmware_sim.faults import (
        FaultControlServer,
        FaultInjector,
        FaultSchedule,
        FaultScheduleError,
    )
    from firmware_sim.scenario import ScenarioError, load_scenario
    from hal.can_bus import CanSpecError, open_bus, parse_can_spec

    try:  # a file, or a shipped scenario's name (paper-centre)
        scenario = load_scenario(resolve_scenario(args.scenario)) if args.scenario else None
    except (ScenarioError, FileNotFoundError) as exc:
        raise _Refused(2, str(exc)) from exc
    bus = None
    if args.can:
        try:
            bus = open_bus(parse_can_spec(args.can))
        except CanSpecError as exc:
            raise _Refused(2, str(exc)) from exc
        except Exception as exc:  # CanInitializationError, OSError
            raise _Refused(1, str(exc)) from exc
    try:
        latches = LatchLog(args.latch_log) if args.latch_log else None
    except OSError as exc:
        if bus is not None:
            bus.shutdown()
        raise _Refused(2, str(exc)) from exc
    rig = _rig(args, scenario, bus)
    if latches is not None:
        latches.attach(rig.bank.drives)
    try:
        schedule = FaultSchedule.load(
            args.faults, node_ids=tuple(int(x) for x in rig.winches.node_id),
            unit_ids=tuple(rig.cells.map.unit_ids)) if args.faults else None
    except FaultScheduleError as exc:
        _close_opened(rig, latches)
        raise _Refused(2, str(exc)) from exc
    injector = FaultInjector(rig, schedule)
    try:
        control = FaultControlServer(injector, host=args.host, port=args.control_port)
    except OSError as exc:
        _close_opened(rig, latches)
        raise _Refused(1, f"cannot listen on {args.host}:{args.control_port}: {exc}") from exc
    return rig, bus, schedule, injector, control, latches


def _close_opened(rig, latches: LatchLog | None) -> None:
    rig.close()
    if latches is not None:
        latches.close()


def _rig(args: argparse.Namespace, scenario, bus):
    """The :class:`firmware_sim.rig.SimRig` listening where the options say (the bus shut
    down again when it cannot)."""
    from firmware_sim.rig import SimRig

    try:
        return SimRig(scenario, clock=args.clock, bus=bus,
                      hub_port=None if bus is not None else args.hub_port,
                      hub_host=args.hub_host, modbus_host=args.modbus_host,
                      modbus_port=args.modbus_port, rtu=args.rtu,
                      plant_rate_hz=args.plant_rate, tracker_port=args.tracker_port,
                      tracker_host=args.host)
    except OSError as exc:
        if bus is not None:
            bus.shutdown()
        raise _Refused(1, f"cannot listen on {args.hub_host}:{args.hub_port} or "
                          f"{args.modbus_host}:{args.modbus_port}: {exc}") from exc
    except ValueError as exc:
        if bus is not None:
            bus.shutdown()
        raise _Refused(2, str(exc)) from exc


def _info(args: argparse.Namespace, rig, bus, control, scheduling: str) -> dict:
    """Where the started robot listens and what it is (the ``--json`` object); the site
    file written with ``--write-site``."""
    from hal.can_bus import parse_can_spec

    can_spec = rig.can_spec if bus is None else str(parse_can_spec(args.can))
    sc = rig.scenario
    site_file = None
    if args.write_site:
        try:
            site_file = write_sim_site(args.write_site, rig, can_spec, args.clock,
                                       args.scenario, control.endpoint)
        except (OSError, ValueError) as exc:
            raise _Refused(2, f"--write-site {args.write_site}: {exc}") from exc
    return {
        "can": can_spec,
        "modbus": rig.modbus_spec,
        "tracker": rig.tracker_spec,
        "node_ids": [int(x) for x in rig.winches.node_id],
        "unit_ids": list(rig.cells.map.unit_ids),
        "cables": list(rig.winches.cables),
        "clock": args.clock,
        "scheduling": scheduling,
        "scenario": str(args.scenario) if args.scenario else None,
        "robot": sc.model.name,
        "init_pose": [float(v) for v in sc.init_pose],
        "reference_m": [float(v) for v in rig.reference_m],
        "pid": os.getpid(),
        "control": control.endpoint,
        "faults": str(args.faults) if args.faults else None,
        "site": site_file,
    }


def _announce(args: argparse.Namespace, info: dict, rig, schedule, scheduling: str) -> None:
    """``info`` as one JSON line (``--json``) or as the options a client gives."""
    import numpy as np

    if args.json:
        print(json.dumps(info), flush=True)
        return
    sc = rig.scenario
    where = args.scenario or "default: rocaspect as the truth"
    print(f"simulated robot {sc.model.name} (scenario {where}), {args.clock} clock, "
          f"init pose {np.round(sc.init_pose, 4).tolist()}; threads {scheduling}")
    print(f"  --can {info['can']}")
    print(f"  --modbus {rig.modbus_spec}")
    print(f"  --tracker {rig.tracker_spec}")
    print(f"  --control {info['control']}   (faults: one request per line; 'help')")
    if info["site"]:
        print(f"  --site {info['site']}")
    if args.clock == "wall" and not scheduling.startswith("SCHED_FIFO"):
        from bench.dryrun.realtime import DEFAULT_RT_PRIORITY

        print("  note: wall clock at normal priority: on a busy host the simulated "
              "drives miss their deadlines before the loop does; --rt-priority "
              f"{DEFAULT_RT_PRIORITY - 1} runs them just below a real-time dry run's "
              "loop (docs/guide/real-time.md)", file=sys.stderr)
    if schedule is not None:
        print(f"  {len(schedule.faults)} scheduled fault(s) from {args.faults}")
    print("running; SIGINT (Ctrl-C) or SIGTERM stops it", flush=True)


def _wait(args: argparse.Namespace, stop: threading.Event) -> None:
    """Until ``stop`` is set (a signal), or stdin ends with ``--exit-on-stdin-eof``."""
    if args.exit_on_stdin_eof:
        def _watch() -> None:
            try:
                sys.stdin.read()
            except (OSError, ValueError):
                pass
            stop.set()
        threading.Thread(target=_watch, name="stdin-eof", daemon=True).start()
    while not stop.wait(0.5):
        pass
