"""What the sub-commands share: the bus, the winch and sensor names, confirmation, output.

Output: human text on stdout, or with ``--json`` on stderr while one JSON object goes to
stdout at the end. Errors are :class:`CommissionError` (exit status 1, or 2 for bad input),
caught by :func:`dispatch`, which also writes the report section of every sub-command.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import canopen

from bench.commission.report import Section, report_path
from controller.loadcell_map import DEFAULT_MAP, RegisterMap, load_register_map
from controller.winch import WinchSet, load_winches
from hal.can_bus import connected_network

DEFAULT_CALIBRATION = "loadcell_calibration.toml"


class CommissionError(Exception):
    """A sub-command cannot go on; ``code`` is the exit status (1 failure, 2 bad input)."""

    def __init__(self, message: str, code: int = 1) -> None:
        super().__init__(message)
        self.code = code


class Ui:
    """Human output (stdout, or stderr with --json) and the final JSON object."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.json = bool(getattr(args, "json", False))
        # --json-lines (monitor): stdout carries the JSON stream only
        lines = bool(getattr(args, "json_lines", False))
        self.out = sys.stderr if self.json or lines else sys.stdout

    def say(self, text: str = "") -> None:
        print(text, file=self.out, flush=True)

    def progress(self, text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    def emit(self, obj: dict[str, Any]) -> None:
        if self.json:
            print(json.dumps(obj), flush=True)


def winches_of(args: argparse.Namespace) -> WinchSet:
    return load_winches(args.winches)


def winch_file(args: argparse.Namespace) -> Path:
    from controller.winch import DEFAULT_WINCHES

    return Path(args.winches) if args.winches else DEFAULT_WINCHES


def tension_window_of(args: argparse.Namespace):
    """The tension window [N] of ``--tension-window LO,HI``, else the supervisor's for the
    robot of ``--robot`` (slack below a fifth of tension_min, overload above tension_max):
    a :class:`controller.cable_watch.TensionWindow`."""
    from controller.cable_watch import TensionWindow
    from controller.robot import RobotFileError, resolve_robot

    spec = getattr(args, "tension_window", None)
    if spec:
        try:
            lo, hi = (float(x) for x in spec.split(","))
            return TensionWindow(lo, hi)
        except ValueError as exc:
            raise CommissionError(f"--tension-window {spec!r}: expected LO,HI in N with "
                                  f"0 <= LO < HI ({exc})", 2) from None
    try:
        robot = resolve_robot(getattr(args, "robot", None) or "rocaspect")
    except (RobotFileError, OSError, ValueError) as exc:
        raise CommissionError(f"--robot: {exc}", 2) from None
    return TensionWindow.for_robot(robot.tension_min, robot.tension_max)


def register_map_of(args: argparse.Namespace) -> RegisterMap:
    return load_register_map(args.loadcell_map) if args.loadcell_map else DEFAULT_MAP


def polling_cells(args: argparse.Namespace, rmap: RegisterMap):
    """The load cells of ``--modbus`` polled in the background
    (:class:`hal.loadcell_client.LoadCellClient` with the options' calibration, rate and
    timing), started, after one whole sweep: a unit that does not answer shows its
    timeout status instead."""
    from hal.loadcell_calibration import load_calibration
    from hal.loadcell_client import LoadCellClient

    cal = load_calibration(args.loadcell_calibration, rmap.cables) \
        if args.loadcell_calibration else None
    client = LoadCellClient(args.modbus, register_map=rmap, calibration=cal,
                            rate_hz=args.loadcell_rate, timeout_s=args.loadcell_timeout,
                            stale_s=args.loadcell_stale,
                            max_age_s=args.loadcell_max_age).start()
    try:
        client.wait_sweeps(1, timeout_s=args.loadcell_timeout * len(rmap.cables) + 1.0)
    except BaseException:  # Ctrl-C, SIGTERM while waiting: the poller ends too
        client.stop()
        raise
    return client


def resolve_winch(w: WinchSet, text: str) -> int:
    """Array index of a winch given as its cable id (``21``) or node id (``node:3``)."""
    t = str(text).strip()
    if t.lower().startswith("node:"):
        try:
            return w.index_of_node(int(t[5:]))
        except (ValueError, KeyError):
            raise CommissionError(f"{w.source}: no winch with CAN node id {t[5:]!r} "
                                  f"(node ids {[int(x) for x in w.node_id]})", 2) from None
    if t in w.cables:
        return w.cables.index(t)
    raise CommissionError(f"winch {t!r}: not a cable of {w.source} ({', '.join(w.cables)}); "
                          "or give node:N", 2)


def resolve_sensor(rmap: RegisterMap, text: str) -> int:
    """Index of a load cell given as its cable id (``21``) or Modbus unit id (``unit:3``)."""
    t = str(text).strip()
    try:
        if t.lower().startswith("unit:"):
            return rmap.index_of(int(t[5:]))
        return rmap.index_of(t)
    except (ValueError, KeyError):
        raise CommissionError(f"load cell {t!r}: not a cable of the register map {rmap.source} "
                              f"({', '.join(rmap.cables)}) nor unit:N with N in "
                              f"{list(rmap.unit_ids)}", 2) from None


def who(w: WinchSet, k: int) -> str:
    return f"node {int(w.node_id[k])} (cable {w.cables[k]})"


@contextmanager
def network_of(args: argparse.Namespace, candump: Callable | None = None
               ) -> Iterator[canopen.Network]:
    """A connected canopen network on ``--can`` (disconnected at exit)."""
    if args.can is None:
        raise CommissionError("no CAN bus: give --can SPEC (socketcan:can0 on the robot, "
                              "socketcand:HOST:PORT for cdpr sim)", 2)
    with connected_network(args.can) as net:
        yield net


def confirm(args: argparse.Namespace, question: str, ui: Ui) -> None:
    """Ask ``question`` on the terminal unless ``--yes``; CommissionError if not confirmed."""
    if getattr(args, "yes", False):
        return
    if not sys.stdin.isatty():
        raise CommissionError(f"{question} needs confirmation: stdin is not a terminal, "
                              "give --yes", 2)
    print(f"{question} Type 'yes' to go on: ", end="", file=sys.stderr, flush=True)
    answer = sys.stdin.readline().strip().lower()
    if answer not in ("yes", "y"):
        raise CommissionError("not confirmed: nothing done")


def guard_other_master(net: canopen.Network, w: WinchSet, window_s: float, ui: Ui,
                       section: Section, master_ids: tuple[int, ...] = ()) -> None:
    """Refuse (CommissionError) when another master is active on the bus."""
    from hal.scan import other_master_activity

    if window_s <= 0:
        section.fact("other master check", "skipped (--listen 0)")
        return
    master = getattr(w.bus, "master_node_id", None)  # the HAL's heartbeat node id
    ids = tuple(master_ids) + ((int(master),) if master else ())
    seen = other_master_activity(net, window_s, [int(x) for x in w.node_id], ids)
    if seen:
        section.fact("other master", "; ".join(seen))
        raise CommissionError(
            f"another master is active on the bus (heard in {window_s:g} s: {'; '.join(seen)}): "
            "stop the controller or the other tool first")
    section.fact("other master check", f"none heard in {window_s:g} s")


@contextmanager
def sigint_deferred() -> Iterator[None]:
    """While cleaning up: a Ctrl-C is noted, not raised (the cleanup must finish)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hits = []
    old = signal.signal(signal.SIGINT, lambda *_: hits.append(1))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
        if hits:
            print("Ctrl-C during the cleanup: finished it first", file=sys.stderr)


@contextmanager
def sigint_raises() -> Iterator[None]:
    """While a command drives a winch: SIGINT (Ctrl-C, or ``kill -INT`` from a supervisor)
    raises KeyboardInterrupt, whatever the process inherited. A process started in the
    background of a shell without job control inherits SIGINT ignored, and Python then
    leaves it so: a jog would keep moving on the operator's stop."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def command_line(args: argparse.Namespace) -> list[str]:
    """The command as typed (from sys.argv when run as ``cdpr``), else rebuilt from ``args``."""
    if Path(sys.argv[0]).name in ("cdpr", "cli.py") and "commission" in sys.argv:
        return ["cdpr", *sys.argv[1:]]
    out = ["cdpr", "commission", args.sub]
    for key in ("winch", "sensor"):
        if getattr(args, key, None):
            out.append(str(getattr(args, key)))
    if args.can is not None:
        out += ["--can", str(args.can)]
    return out


def dispatch(args: argparse.Namespace, func: Callable[[argparse.Namespace, Ui, Section], int]
             ) -> int:
    """Run one sub-command: errors to exit statuses, the report section written at the end."""
    from can import CanError, CanInitializationError

    from controller.loadcell_map import RegisterMapError
    from controller.winch import WinchConfigError
    from hal.drives_config import DriveConfigError
    from hal.loadcell_calibration import CalibrationError
    from hal.motion import MotionError

    ui = Ui(args)
    name = f"cdpr commission {args.sub}"
    section = Section(report_path(args), args.sub, command_line(args))
    if args.can is not None:
        section.fact("CAN bus", str(args.can))
    if getattr(args, "modbus", None) is not None:
        section.fact("Modbus", str(args.modbus))

    def fail(code: int, msg: str) -> int:
        print(f"{name}: {msg}", file=sys.stderr, flush=True)
        ui.emit({"error": msg, **section.json_extra})
        section.write(f"FAILED: {msg}")
        return code

    eds = getattr(args, "eds", None)
    if eds is not None and not Path(eds).is_file():
        return fail(2, f"--eds {eds}: no such file")
    try:
        with sigint_raises():
            code = func(args, ui, section)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (bench.cli)
        from bench.parallel import interruption

        code, msg = interruption(exc)
        section.write("interrupted (Ctrl-C)" if code == 130 else msg)
        print(f"{name}: {msg}", file=sys.stderr)
        ui.emit({"error": msg, **section.json_extra})
        return code
    except CommissionError as exc:
        return fail(exc.code, str(exc))
    except (WinchConfigError, RegisterMapError, CalibrationError) as exc:
        return fail(2, str(exc))
    except (DriveConfigError, MotionError) as exc:
        return fail(1, str(exc))
    except (CanInitializationError, CanError, OSError) as exc:
        return fail(1, str(exc))
    section.write()
    if section.path is not None:
        print(f"report: {section.path}", file=sys.stderr)
    if code in (130, 143):  # a command that ended on SIGINT / SIGTERM itself: the last line
        from bench.parallel import signal_exit
        print(f"{name}: {signal_exit(code - 128)[1]}", file=sys.stderr, flush=True)
    return code
