"""``cdpr campaign SCENARIO OUT_DIR``: record a campaign on the simulated robot.

``cdpr campaign design REPORT.json (--site FILE | --scenario S) --poses N [--out PATH.toml]``
designs the next campaign from a diagnosis report instead
(:mod:`bench.commands.campaign_design`); ``--path PATH.toml`` then records the visits of that
path's poses.

Runs the scenario's campaign (:func:`bench.campaign.run_campaign`: the controller with
the scenario's model visits the pose set; the plant is the scenario's truth) and writes
the recording directory (``cdpr-recording/1``: ``meta.toml``, ``robot.toml`` = the model,
``recording.csv``). The recording never holds the truth.

The recording is first written into a temporary directory beside OUT_DIR and moved into
place only when complete: an error or an interruption leaves OUT_DIR as it was. A
non-empty OUT_DIR is refused unless ``--force``, which replaces the recording's three
files and leaves any other file there untouched.

Exit status: 0 written, 1 the campaign failed, 2 bad scenario or arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.commands.argtypes import nonnegative_int, positive_int

if TYPE_CHECKING:
    from firmware_sim.scenario import Scenario

NAME = "campaign"
HELP = "record a campaign of a scenario on the simulated robot (cdpr-recording/1 directory)"

#: the files a recording directory consists of (replaced by --force)
RECORDING_FILES = ("meta.toml", "robot.toml", "recording.csv")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario file (cdpr-scenario/1), or the word 'design' "
                   "(then the next argument is a diagnosis report: design a campaign)")
    p.add_argument("out_dir", help="recording directory to write (created if absent); after "
                   "'design': the cdpr-diagnosis/1 report")
    p.add_argument("--poses", type=int, metavar="N",
                   help="visit N of the scenario's poses (random pose sets: draw N; grid and "
                        "list: N of them, chosen with the scenario's seed)")
    p.add_argument("--visits", type=int, metavar="V",
                   help="visits of each pose (default: the scenario's poses.visits)")
    p.add_argument("--seed", type=nonnegative_int, metavar="S",
                   help="random seed of the campaign and its noise (default: the scenario's)")
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty OUT_DIR (replaces the recording's files)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--path", metavar="PATH.toml",
                   help="visit the poses of this cdpr-path/1 file's visits segments (e.g. a "
                        "designed one) instead of the scenario's, with its visits")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: path, samples, rows, visits, poses, seconds")
    g = p.add_argument_group("design (cdpr campaign design REPORT.json ...)")
    g.add_argument("--site", metavar="FILE",
                   help="design: the site file (its workspace box and tension window)")
    g.add_argument("--scenario", dest="design_scenario", metavar="S",
                   help="design: a scenario (its model, init pose and sensors, when the "
                        "report's recording cannot be read)")
    g.add_argument("--out", metavar="PATH.toml",
                   help="design: write the poses as a cdpr-path/1 file")
    g.add_argument("--candidates", type=positive_int, default=150, metavar="C",
                   help="design: tension-feasible candidate poses drawn (default 150)")
    g.add_argument("--match", metavar="PATH",
                   help="design: also the fewest designed poses that reach the standard "
                        "errors this path's poses give (exit offsets, mast stiffnesses); "
                        "with nothing to separate, the poses written aim at them")
    g.add_argument("--load-cells", dest="load_cells", metavar="IDS",
                   type=lambda v: [c.strip() for c in v.split(",") if c.strip()],
                   help="design: the cables that carry load cells (comma-separated ids): "
                        "also say what the design fixes with only those measured")


def _fail(args: argparse.Namespace, code: int, msg: str) -> int:
    print(f"cdpr campaign: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return code


def _adjust(sc: Scenario, args: argparse.Namespace) -> tuple[Scenario, Any]:
    """The scenario with --seed/--visits applied, and the pose subset of --poses (or None)."""
    import numpy as np

    from firmware_sim.scenario import ScenarioError

    if args.seed is not None:
        sc = dataclasses.replace(sc, seed=args.seed)
    if args.path is not None:
        from bench.campaign_design import DesignError, path_poses
        from controller.paths import PathFileError

        try:
            poses, visits = path_poses(args.path)
        except (DesignError, PathFileError) as e:
            raise ScenarioError(str(e)) from e
        if args.visits is None:
            sc = dataclasses.replace(sc, poses=dataclasses.replace(sc.poses, visits=visits))
    if args.visits is not None:
        sc = dataclasses.replace(sc, poses=dataclasses.replace(sc.poses, visits=args.visits))
    if args.path is not None:
        return sc, poses if args.poses is None else poses[:args.poses]
    if args.poses is None:
        return sc, None
    if sc.poses.kind == "random":
        return dataclasses.replace(sc, poses=dataclasses.replace(sc.poses, n=(args.poses,))), None
    # grid/list: the same draw as the campaign's, then N of those poses in their order
    every = sc.poses.generate(np.random.default_rng(sc.seed))
    if args.poses > len(every):
        raise ScenarioError(f"{sc.path}: poses: --poses {args.poses} but the {sc.poses.kind} "
                            f"has {len(every)} poses")
    keep = np.sort(np.random.default_rng([sc.seed, args.poses]).choice(
        len(every), size=args.poses, replace=False))
    return sc, every[keep]


def _occupied(out: Path) -> bool:
    return out.exists() and (not out.is_dir() or any(out.iterdir()))


def _place(tmp: Path, out: Path) -> None:
    """Move the finished recording ``tmp`` to ``out`` (replacing only its own files)."""
    if not out.exists():
        os.replace(tmp, out)
        return
    if not any(out.iterdir()):
        out.rmdir()
        os.replace(tmp, out)
        return
    for name in RECORDING_FILES:
        os.replace(tmp / name, out / name)
    shutil.rmtree(tmp, ignore_errors=True)


def run(args: argparse.Namespace) -> int:
    from bench.outputs import removing_created

    if args.scenario == "design":
        from bench.commands.campaign_design import run as design

        return design(args)
    for opt in ("site", "design_scenario", "out", "match", "load_cells"):
        if getattr(args, opt) is not None:
            flag = "--scenario" if opt == "design_scenario" else \
                f"--{opt.replace('_', '-')}"
            return _fail(args, 2, f"{flag}: only with 'cdpr campaign design REPORT.json'")

    # refused or failed (a bad scenario, Ctrl-C): no directory made for OUT_DIR left
    return removing_created(lambda created: _run(args, created))


def _run(args: argparse.Namespace, created: list[Path]) -> int:
    import numpy as np

    from bench.campaign import run_campaign
    from bench.recording import read_recording
    from firmware_sim.scenario import ScenarioError, load_scenario

    for opt in ("poses", "visits"):
        v = getattr(args, opt)
        if v is not None and v < 1:
            return _fail(args, 2, f"--{opt} {v}: must be >= 1")
    out = Path(args.out_dir)
    if out.exists() and not out.is_dir():
        return _fail(args, 2, f"{out}: exists and is not a directory")
    if _occupied(out) and not args.force:
        return _fail(args, 2, f"{out}: not empty (use --force to replace the recording there)")
    from bench.outputs import output_dir_problem

    if (problem := output_dir_problem(out, "OUT_DIR", created)) is not None:
        return _fail(args, 2, problem)
    try:
        sc, subset = _adjust(load_scenario(args.scenario), args)
    except ScenarioError as e:
        return _fail(args, 2, str(e))

    n_poses = len(subset) if subset is not None else len(sc.poses.generate(
        np.random.default_rng(sc.seed)))
    from bench.progress import Progress

    t0 = time.perf_counter()
    prog = Progress("campaign", None, args.quiet, unit="visits")

    def progress(done: int, total: int) -> None:
        prog.total = total
        prog.update(done=done)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp's 0700 would stay on the recording
    try:
        try:
            run_campaign(sc, tmp, progress=progress, poses=subset)
        except ValueError as e:  # a pose the model cannot reach, ...
            return _fail(args, 1, f"{sc.path}: campaign failed: {e}")
        _place(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    seconds = time.perf_counter() - t0
    rec = read_recording(out)
    visits = n_poses * sc.poses.visits
    kind = sc.recording.kind
    dwells = kind == "dwell" or sc.recording.dwell_at_targets
    result = {"path": str(out), "samples": visits + 1 if dwells else 1, "rows": rec.n_samples,
              "visits": visits, "poses": n_poses, "kind": kind, "seconds": round(seconds, 3)}
    if args.json:
        print(json.dumps(result))
    elif kind == "dwell":
        print(f"recording {out}: {rec.n_samples} rows, {visits + 1} dwell samples "
              f"(initialisation + {n_poses} poses x {sc.poses.visits} visits) "
              f"in {seconds:.1f} s")
    else:
        print(f"recording {out}: {rec.n_samples} rows, continuous at "
              f"{sc.recording.rate_hz or sc.poses.rate_hz:g} Hz along {visits} moves between "
              f"{n_poses} poses{' with dwells' if dwells else ''} in {seconds:.1f} s")
    return 0
