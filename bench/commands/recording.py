"""``cdpr recording convert IN OUT`` and ``cdpr recording info FILE``: recordings between
the CSV directory (``cdpr-recording/1``) and MCAP (docs/guide/mcap-and-replay.md).

``convert`` reads ``IN`` by what it is: an MCAP recording (a ``.mcap`` file, or a directory
holding ``recording.mcap`` and no ``meta.toml``) becomes the CSV directory ``OUT``; a CSV
directory becomes the MCAP file ``OUT`` (when it ends in ``.mcap``, else
``OUT/recording.mcap``). ``--json``: ``{"from", "to", "input", "output", "rows", "events",
"truncated"}``. ``info`` prints an MCAP recording's channels, chunks and rows
(``--json``: the object). ``layout OUT`` writes the Foxglove layout
(:mod:`bench.mcap.foxglove_layout`) for ``--robot``'s cables (``--json``: ``{"output",
"robot", "topics"}``).

Exit status: 0 done, 2 bad input or an output that exists (without ``--force``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys

NAME = "recording"
HELP = ("convert recordings between the CSV directory and MCAP; describe an MCAP recording; "
        "write the Foxglove layout")


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    c = sub.add_parser("convert", help="CSV directory -> MCAP, or MCAP -> CSV directory")
    c.add_argument("input", help="recording directory (cdpr-recording/1) or MCAP recording")
    c.add_argument("output", help="MCAP file (*.mcap) or directory; a directory for CSV")
    c.add_argument("--force", action="store_true", help="overwrite an existing OUTPUT")
    c.add_argument("--json", action="store_true", help="one JSON object on stdout")
    i = sub.add_parser("info", help="channels, chunks and rows of an MCAP recording")
    i.add_argument("input", help="MCAP recording (file, or directory with recording.mcap)")
    i.add_argument("--json", action="store_true", help="one JSON object on stdout")
    lo = sub.add_parser("layout", help="write the Foxglove layout for a robot's cables")
    lo.add_argument("output", help="layout file to write (*.json)")
    lo.add_argument("--robot", default="rocaspect",
                    help="robot name or robot.toml whose cables the plots show [rocaspect]")
    lo.add_argument("--force", action="store_true", help="overwrite an existing OUTPUT")
    lo.add_argument("--json", action="store_true", help="one JSON object on stdout")


def _fail(args: argparse.Namespace, msg: str) -> int:
    print(f"cdpr recording {args.action}: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return 2


def run(args: argparse.Namespace) -> int:
    from bench.mcap import convert, convert_target, info
    from bench.recording import RecordingError

    try:
        if args.action == "layout":
            return _layout(args)
        if args.action == "info":
            out = info(args.input)
            if args.json:
                print(json.dumps(out))
            else:
                print(f"{out['file']}: {out['rows']} rows, {out['events']} events, "
                      f"{out['chunks']} chunks ({', '.join(out['compression'])})"
                      + ("" if out["whole"] else ", CUT SHORT (no footer)"))
                for ch in out["channels"]:
                    print(f"  {ch['topic']:20} {ch['schema']:24} {ch['encoding']:9} "
                          f"{ch['messages']} messages")
            return 0
        to, target = convert_target(args.input, args.output)
        taken = target.exists() and (target.is_file() or any(target.iterdir()))
        if taken and not args.force:
            return _fail(args, f"{target}: exists (use --force to overwrite)")
        if taken:
            shutil.rmtree(target) if target.is_dir() else target.unlink()
        out = convert(args.input, args.output)
    except (RecordingError, OSError) as exc:
        return _fail(args, str(exc))
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{out['input']} ({out['from']}) -> {out['output']} ({out['to']}): "
              f"{out['rows']} rows, {out['events']} events"
              + (" (the input was cut short: rows up to its last whole chunk)"
                 if out["truncated"] else ""))
    return 0


def _layout(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bench.mcap import foxglove_layout as fl
    from controller.robot import RobotFileError, resolve_robot

    out = Path(args.output)
    if out.exists() and not args.force:
        return _fail(args, f"{out}: exists (use --force to overwrite)")
    try:
        robot = resolve_robot(args.robot)
    except (RobotFileError, ValueError, OSError) as exc:
        return _fail(args, f"--robot {args.robot}: {exc}")
    lay = fl.robot_layout(robot)
    fl.write(out, lay)
    res = {"output": str(out), "robot": robot.name, "topics": sorted(fl.topics(lay))}
    print(json.dumps(res) if args.json else f"{out}: Foxglove layout for {robot.name} "
          f"({len(robot.cable_ids)} cables)")
    return 0
