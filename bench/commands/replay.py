"""``cdpr replay CAN_LOG``: a CAN log played into the HAL's drive decoders again.

``CAN_LOG``: a candump ``.log``, an ``.asc`` (or ``.blf``, ``.csv``: python-can's readers),
e.g. from ``cdpr commission monitor --candump``, or an MCAP recording with a ``/can``
channel (``cdpr dry-run --record DIR --format mcap``). The drives' frames go, at their
logged pace (or ``--fast``), to a HAL listening as the master did; at each logged SYNC it
runs its cycle. Printed: the drives' CiA 402 state changes, the HAL's drive events (EMCY,
faults, heartbeats, boot-ups, missing TPDOs) and the supervisor's reactions to them, as
the live run derived them (bench/can_replay.py; docs/guide/mcap-and-replay.md).

``--json``: ``{"log", "frames", "syncs", "sync_period_s", "log_s", "wall_s", "events",
"supervisor", "states", "final_states"}``.

Exit status: 0 replayed, 2 bad log (or one without CAN frames) or arguments.
"""

from __future__ import annotations

import argparse
import json
import sys

NAME = "replay"
HELP = "replay a CAN log (candump .log, .asc, MCAP /can) into the HAL: drive states, events"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="CAN_LOG", help="candump .log, .asc, .blf, .csv, or an MCAP "
                                                  "recording with a /can channel")
    p.add_argument("--fast", action="store_true",
                   help="as fast as possible (default: the log's own timing)")
    p.add_argument("--winches", metavar="TOML", default=None,
                   help="winch parameter file (node ids, units, timing) "
                        "[controller/data/rocaspect_winches.toml]")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="the log's SYNC rate [an MCAP recording's rate_hz, else the "
                        "median SYNC interval of the log]")
    p.add_argument("--react", action="append", default=[], metavar="CONDITION=REACTION",
                   help="change a supervisor reaction, as in cdpr dry-run (repeatable)")
    p.add_argument("--quiet", action="store_true", help="no line per event")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")


def _fail(args: argparse.Namespace, msg: str) -> int:
    print(f"cdpr replay: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return 2


def _line(e: dict) -> str:
    if "state" in e:
        return f"t={e['t']:8.3f} s  node {e['node']} (cable {e['cable']}): {e['state']}"
    if "reaction" in e:
        end = "" if e["active"] else "ended: "
        return (f"t={e['t']:8.3f} s  supervisor: {end}{e['kind']} 0x{e['code']:04X} at "
                f"{e['device']} {e['address']} -> {e['reaction']}")
    return (f"t={e['t']:8.3f} s  node {e['node']} (cable {e['cable']}) {e['kind']} "
            f"0x{e['code']:04X}: {e['text']}")


def run(args: argparse.Namespace) -> int:
    from bench.can_replay import ReplayError, read_log, replay, sync_period_of
    from bench.recording import RecordingError
    from controller.supervisor import parse_reactions
    from controller.winch import WinchConfigError, load_winches

    if args.rate is not None and not args.rate > 0:
        return _fail(args, f"--rate {args.rate}: must be a positive number of Hz")
    try:
        reactions = parse_reactions(args.react)
    except ValueError as exc:
        return _fail(args, f"--react {exc}")
    try:
        winches = load_winches(args.winches)
        period = 1.0 / args.rate if args.rate else sync_period_of(args.log)
        show = None if (args.quiet or args.json) else (lambda e: print(_line(e), flush=True))
        res = replay(read_log(args.log), winches, fast=args.fast, on_event=show,
                     reactions=reactions, period_s=period)
    except (ReplayError, RecordingError, WinchConfigError, OSError) as exc:
        return _fail(args, str(exc))
    if res.frames == 0:
        return _fail(args, f"{args.log}: no CAN frames (an MCAP recording has them when "
                           f"written by cdpr dry-run --format mcap)")
    out = {"log": args.log, "frames": res.frames, "syncs": res.syncs,
           "sync_period_s": period, "log_s": res.log_s, "wall_s": res.wall_s,
           "events": res.events, "supervisor": res.supervisor, "states": res.states,
           "final_states": res.final_states}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{args.log}: {res.frames} frames, {res.syncs} SYNCs over {res.log_s:.2f} s "
              f"(replayed in {res.wall_s:.2f} s); {len(res.events)} drive events, "
              f"{len(res.supervisor)} supervisor events; drives now "
              + ", ".join(res.final_states))
    return 0
