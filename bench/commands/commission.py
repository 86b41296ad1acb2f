"""``cdpr commission scan|check|enable|disable|jog|home|tare|calibrate|monitor``.

Commissioning the real winches (CiA 402 drives on CAN, ``--can socketcan:can0`` or any
python-can interface) and load cells (Modbus, ``--modbus HOST:PORT`` or
``rtu:/dev/ttyUSB0:19200``); the same against ``cdpr sim`` (``--can socketcand:...``).
The order on site: scan -> check (--apply) -> reference -> tare / calibrate -> enable -> jog
(one winch with the platform on its stand, or --platform) -> monitor.

The sub-commands live in :mod:`bench.commission`; this module is the argparse front (heavy
imports happen when a sub-command runs). Every sub-command appends a section to the
commissioning report (``commissioning-report.md`` in the current directory, or
``--report PATH``) and takes ``--json`` (one JSON object on stdout at the end).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from bench.commands.argtypes import (
    add_format_and_live,
    nonnegative_float,
    positive_float,
    positive_int,
)

NAME = "commission"
HELP = ("commission the winches and load cells: scan, check, reference, enable, disable, "
        "jog, home, tare, calibrate, monitor")

ORDER = """order on site: scan -> check [--apply] -> reference -> tare / calibrate -> enable ->
jog (one winch, platform on its stand; or --platform) -> monitor.
WINCH is a cable id (21) or node:N; SENSOR a cable id or unit:N. Everything that can move a
winch listens --listen seconds for another master first, asks for confirmation (--yes),
watches every cable's tension (--modbus) and stops when one leaves the tension window, and
leaves the drives disabled on any error, timeout or Ctrl-C. Every sub-command appends a
section to the commissioning report (commissioning-report.md here, or --report PATH)."""


def _default_eds() -> str:
    import firmware_sim

    return str(Path(firmware_sim.__file__).parent / "data" / "winch_drive.eds")


def _common(json_help: str) -> argparse.ArgumentParser:
    from hal.cli_args import add_hardware_arguments

    p = argparse.ArgumentParser(add_help=False)
    add_hardware_arguments(p, eds_default=_default_eds())
    g = p.add_argument_group("tensions")
    g.add_argument("--robot", default=None, metavar="NAME|PATH",
                   help="robot description: tension limits, model [the site's, else "
                        "rocaspect]")
    g.add_argument("--tension-window", metavar="LO,HI",
                   help="tensions a cable may carry [N]: below LO is slack, above HI "
                        "overload [the site's limits, else the supervisor's: tension_min/5, "
                        "tension_max of --robot]")
    g = p.add_argument_group("report and output")
    g.add_argument("--report", metavar="PATH",
                   help="commissioning report to append to [commissioning-report.md]")
    g.add_argument("--no-report", action="store_true", help="write no report section")
    g.add_argument("--json", action="store_true", help=json_help)
    return p


def _state(p: argparse.ArgumentParser) -> None:
    p.add_argument("--state", metavar="FILE",
                   help="commissioning state (the winches' reference, cdpr-commission-state/1 "
                        "TOML) [commissioning-state.toml beside the report]")


def _moving(p: argparse.ArgumentParser) -> None:
    p.add_argument("--yes", action="store_true", help="do not ask for confirmation")
    p.add_argument("--listen", type=nonnegative_float, default=0.5, metavar="S",
                   help="listen S seconds for another master (SYNC, RPDOs, NMT, SDO to the "
                        "drives) and refuse if one is active; 0 skips [0.5]")


#: the load cells' calibration file, said by tare and calibrate
_CAL_DOC = ("The calibration file is --loadcell-calibration (default "
            "loadcell_calibration.toml here); the old one is kept as NAME.DATE.bak. "
            "measured = gain * true + offset.")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = HELP + ".\n\n" + ORDER
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = p.add_subparsers(dest="sub", metavar="SUBCOMMAND")
    sub.required = True

    def add(name: str, help_: str, json_help: str, doc: str = "") -> argparse.ArgumentParser:
        q = sub.add_parser(name, help=help_, description=help_ + (f"\n\n{doc}" if doc else ""),
                           parents=[_common(json_help)],
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        q.set_defaults(sub=name)
        return q

    for declare in (_scan_arguments, _check_arguments, _enable_arguments, _disable_arguments,
                    _jog_arguments, _home_arguments, _reference_arguments, _tare_arguments,
                    _calibrate_arguments, _monitor_arguments):
        declare(add)


def _scan_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission scan``'s options (``add`` makes its parser)."""
    q = add("scan", "the drives on the CAN bus and the load cells on Modbus, against the "
            "configuration",
            'print {"drives": [{"node_id", "vendor_id", "product_code", "revision", "serial", '
            '"expected", "status", ...}], "load_cells": [{"device_id", "cable", "tension_n", '
            '"status"}]}',
            "Statuses: ok, missing, extra, wrong_vendor, wrong_product, wrong_revision, "
            "wrong_device_type, no_sdo. Read-only; exit status 1 when anything is not ok.")
    q.add_argument("--window", type=float, default=0.3, metavar="S",
                   help="how long to listen for answers to the node probe [0.3 s]")
    q.add_argument("--sdo-timeout", type=positive_float, default=0.3, metavar="S",
                   help="SDO answer timeout for the identity reads [0.3 s]")
    q.add_argument("--probe-units", metavar="IDS",
                   help="also probe these Modbus unit ids for devices outside the map "
                        "(e.g. 1-16)")


def _check_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission check``'s options (``add`` makes its parser)."""
    q = add("check", "each drive's parameters by SDO against the HAL's configuration table",
            'print {"drives": [{"node_id", "cable", "differences": [{"index", "subindex", '
            '"name", "expected", "actual"}]}], "applied", "dcf", "ok"}',
            "The table is the one the HAL writes at start (EDS + winch parameter file). "
            "check only reads; --apply writes the differences and stores them (0x1010) after "
            "confirmation. Exit status 1 when a difference remains.")
    q.add_argument("winch", nargs="*", help="winches to check (default all)")
    q.add_argument("--apply", action="store_true",
                   help="write the table to the drives that differ, verify and store it")
    q.add_argument("--no-store", action="store_true",
                   help="with --apply: do not store in the drive's non-volatile memory")
    q.add_argument("--dcf", metavar="DIR", help="export each drive's configuration as a DCF")
    _moving(q)


def _enable_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission enable``'s options (``add`` makes its parser)."""
    q = add("enable", "enable one winch and hold its position until Enter, q or Ctrl-C",
            'print {"winch", "node_id", "length_m", "moved_m", "ended_by", "state"}')
    q.add_argument("winch", help="cable id (21) or node:N")
    q.add_argument("--duration", type=float, metavar="S", help="disable after S seconds")
    _moving(q)


def _disable_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission disable``'s options (``add`` makes its parser)."""
    q = add("disable", "disable one winch (NMT pre-operational, controlword 0 by SDO)",
            'print {"winch", "node_id", "before", "state", "statusword", "error_code"}')
    q.add_argument("winch", help="cable id (21) or node:N")
    q.add_argument("--fault-reset", action="store_true",
                   help="reset a fault first (rising edge of controlword bit 7)")


def _jog_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission jog``'s options (``add`` makes its parser)."""
    q = add("jog", "jog one winch with a dead-man input, or the platform (--platform) through "
            "the model",
            'print {"winch", "node_id", "start_m", "end_m", "min_m", "max_m", "moves", '
            '"deadman_stops", "ended_by", "state", "window_m", "speed_m_s", "travel_m", '
            '"guard_stop", "cable_watch"}; with --platform {"start_pose", "target_pose", '
            '"end_pose", "duration_s", "ended_by", "guard_stop", "cable_watch", "state"}',
            "One winch: hold + to pay cable out, - to reel it in: the terminal's key repeat "
            "keeps the winch moving; release the key and it halts after --deadman seconds, "
            "then is disabled (the next key enables it again). Space stops, q quits. From a "
            "pipe every character is a key and the end of the input quits. A loaded robot's "
            "winch moves at most 5 mm without --platform-supported (the platform resting on "
            "its stand). --platform: all winches move together along a jerk-limited straight "
            "line from the referenced pose (cdpr commission reference) by --step or to --to, "
            "checked before it starts as the dry run checks its path. Every cable's tension is "
            "watched (--modbus): a tension leaving the window, or about to, quick-stops the "
            "motion and the drives are disabled.")
    q.add_argument("winch", nargs="?", help="cable id (21) or node:N (not with --platform)")
    q.add_argument("--speed", type=float, metavar="M/S",
                   help="one winch: jog speed, at most max_speed_m_s of the winch file "
                        "[min(0.05, profile_speed_m_s)]; --platform: the platform's speed "
                        "[0.02 m/s]")
    q.add_argument("--travel", type=float, metavar="M",
                   help="one winch: farthest from the start position, within "
                        "[min_length_m, max_length_m]; more than 0.005 m needs "
                        "--platform-supported [0.01 m; 0.005 m without --platform-supported]")
    q.add_argument("--deadman", type=float, default=0.6, metavar="S",
                   help="one winch: halt after S seconds without a key [0.6]")
    q.add_argument("--platform-supported", action="store_true",
                   help="the platform rests on its stand: a single winch may move more than "
                        "5 mm (the cables are still watched)")
    q.add_argument("--platform", action="store_true",
                   help="Cartesian jog: move the platform (all winches) by --step or to --to")
    q.add_argument("--step", metavar="DX,DY,DZ[,DR,DP,DY]",
                   help="--platform: the step from the referenced pose [m, deg]")
    q.add_argument("--to", metavar="X,Y,Z[,R,P,Y]",
                   help="--platform: the target pose [m, deg]")
    q.add_argument("--max-step", type=positive_float, default=0.10, metavar="M",
                   help="--platform: refuse steps longer than M metres [0.10]")
    _state(q)
    _moving(q)


def _home_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission home``'s options (``add`` makes its parser)."""
    q = add("home", "home a winch (CiA 402 homing) and/or reference it (length_at_zero_m)",
            'print {"winch", "node_id", "method", "position_before_counts", '
            '"position_after_counts", "length_m", "length_at_zero_m", "winch_file", "backup", '
            '"reference_lost"}',
            "--method 35|37: the drive's position becomes --offset counts (homing on the "
            "current position, no motion). --length L: the current position reads L metres: "
            "length_at_zero_m of the winch parameter file (--winches, default the shipped "
            "file) is rewritten, the old file kept as NAME.DATE.bak. A homing changes the "
            "count, never the cable: the platform reference (cdpr commission reference) is "
            "lost and jog --platform refused until it has run again.")
    q.add_argument("winch", help="cable id (21) or node:N")
    q.add_argument("--method", type=int, choices=(35, 37),
                   help="CiA 402 homing method on the current position")
    q.add_argument("--offset", type=int, default=0, metavar="COUNTS",
                   help="home offset 0x607C: the position after homing [0]")
    q.add_argument("--length", type=positive_float, metavar="M",
                   help="the cable length at the current (homed) position [m]")
    _state(q)
    _moving(q)


def _reference_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission reference``'s options (``add`` makes its parser)."""
    from hal.cli_args import add_tracker_argument

    q = add("reference", "reference every winch at a measured platform pose (tracker, or "
            "--pose on the stand)",
            'print {"pose", "pose_source", "robot", "state", "offsets_m", "model_m", '
            '"reading_m"}',
            "Each encoder's reading becomes the model's cable length at the pose "
            "(d_model(p0), the controller's initialisation); the offsets, pose, time and "
            "model go to the state file (--state). Nothing moves, nothing is written to the "
            "drives. A CiA 402 homing (home --method) marks the reference lost.")
    q.add_argument("--pose", metavar="X,Y,Z[,R,P,Y]",
                   help="the platform's known pose on its stand [m, deg]")
    add_tracker_argument(q)
    q.add_argument("--samples", type=positive_int, default=20, metavar="N",
                   help="tracker poses averaged [20]")
    _state(q)


def _tare_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission tare``'s options (``add`` makes its parser)."""
    q = add("tare", "zero a load cell (offset) and write the calibration file",
            'print {"sensor", "device_id", "raw_N", "offset_old_N", "offset_N", "gain", '
            '"file", "backup"}', _CAL_DOC)
    q.add_argument("sensor", help="cable id (21) or unit:N")
    q.add_argument("--load", type=nonnegative_float, default=0.0, metavar="N",
                   help="known load on the cell while taring [0 N: unloaded]")
    q.add_argument("--samples", type=int, default=20, metavar="N",
                   help="fresh samples averaged [20]")


def _calibrate_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission calibrate``'s options (``add`` makes its parser)."""
    q = add("calibrate", "fit a load cell's gain from known loads and write the calibration "
            "file", 'print {"sensor", "points": [...], "gain", "offset_N", "residual_rms_N", '
                    '"file", "backup"}',
            _CAL_DOC + " Loads: asked one after another (kg, or N with the suffix N), or "
            "--weights; two or more distinct loads fit gain and offset, one load fits the "
            "gain with the offset kept.")
    q.add_argument("sensor", help="cable id (21) or unit:N")
    q.add_argument("--weights", metavar="W1,W2,...",
                   help="the loads in order (kg, or N with suffix N); Enter before each")
    q.add_argument("--no-wait", action="store_true",
                   help="with --weights: measure at once, no Enter")
    q.add_argument("--stdin-loads", action="store_true",
                   help="read the loads as lines from stdin even when it is not a terminal")
    q.add_argument("--samples", type=int, default=20, metavar="N",
                   help="fresh samples averaged per load [20]")
    q.add_argument("--g", type=float, default=9.81, metavar="M/S2",
                   help="gravity for masses [9.81]")


def _monitor_arguments(add: Callable[..., argparse.ArgumentParser]) -> None:
    """``cdpr commission monitor``'s options (``add`` makes its parser)."""
    q = add("monitor", "live table of drive states, positions, velocities, torques, tensions, "
            "bus load and the last errors",
            'print {"refreshes", "ended_by", "frames", "drives", "load_cells", "events", '
            '"events_by_severity", "events_dropped", "tension_window_n", "record", "format", '
            '"live", "rows", "candump"} at the end')
    q.add_argument("--rate", type=float, default=5.0, metavar="HZ", help="refreshes per second")
    q.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    q.add_argument("--record", metavar="DIR", help="write a cdpr-recording/1 directory")
    add_format_and_live(q, "with the CAN frames on /can", "the drives and tensions")
    q.add_argument("--init-pose", metavar="X,Y,Z[,R,P,Y]",
                   help="init_pose of --record [forward kinematics of the first sample]")
    q.add_argument("--json-lines", action="store_true",
                   help="one JSON object per refresh on stdout (the table goes to stderr)")
    q.add_argument("--candump", metavar="FILE",
                   help="log every CAN frame (.asc, .blf, .log or .csv: python-can's Logger)")


def _site_defaults(args: argparse.Namespace, site) -> None:
    """The robot, tension window and state file of ``site`` (a :class:`hal.site.Site`, or
    None) where the command line gave none; then the shipped robot."""
    if site is not None:
        if args.robot is None:
            args.robot = site.robot
        if not args.tension_window:
            lim = site.limits
            args.tension_window = f"{lim.tension_min_N!r},{lim.tension_max_N!r}"
        if getattr(args, "state", "absent") is None and site.state_file is not None:
            args.state = str(site.state_file)
    if args.robot is None:
        args.robot = "rocaspect"


def run(args: argparse.Namespace) -> int:
    from bench.commission import check, loadcells, monitor, motion, reference, scan
    from bench.commission.common import dispatch
    from hal.cli_args import apply_site
    from hal.site import SiteError

    try:  # --site: its values where the command line gives none (nothing opened yet)
        _site_defaults(args, apply_site(args).site)
    except (SiteError, ValueError) as exc:
        import sys

        print(f"cdpr commission {args.sub}: {exc}", file=sys.stderr)
        if args.json:
            import json

            print(json.dumps({"error": str(exc)}))
        return 2

    funcs = {"scan": scan.run, "check": check.run, "enable": motion.run_enable,
             "disable": motion.run_disable, "jog": motion.run_jog, "home": motion.run_home,
             "tare": loadcells.run_tare, "calibrate": loadcells.run_calibrate,
             "monitor": monitor.run, "reference": reference.run_reference}
    return dispatch(args, funcs[args.sub])
