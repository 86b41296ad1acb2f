"""``cdpr iso9283 RECORDING...``: ISO 9283:1998 pose and path figures of recordings.

Each recording (``cdpr-recording/1``: commanded poses ``x_des..yaw_des``, measured poses
``x_meas..yaw_meas``) is analysed on its own, or all together with ``--pool`` (visits of the
same commanded pose and passes over the same commanded path pooled across recordings). How
visits (dwells) and passes (moves) are found: :mod:`bench.iso9283.segments`; the formulas:
:mod:`bench.iso9283.figures`. The rule used is printed with the results.

``--kind pose|path|auto``: pose figures (AP, RP, AP_a..RP_c per commanded pose and the worst
per recording), path figures (AT max and mean, RT, orientation AT/RT per commanded path) or,
by default, auto: path when the recording has moves and at most two dwell poses (the path's
ends), pose otherwise.

``--json`` prints one object (SI units: m, rad; NaN as null)::

    {"format": "cdpr-iso9283/1", "standard": "ISO 9283:1998",
     "analyses": [{
        "label": "<recording dir name, or 'N recordings pooled'>",
        "recordings": ["<dir>", ...], "kind": "pose"|"path", "kind_reason": "...",
        "rule": "<how visits or passes were found>", "warnings": ["<file>:<lines>: ...", ...],
        # kind "pose":
        "poses": [{"pose": 1, "command": [x, y, z, roll, pitch, yaw],
                   "barycentre": [...6], "n": 30,
                   "apx_m", "apy_m", "apz_m", "ap_m", "rp_m", "l_mean_m", "s_l_m",
                   "ap_a_rad", "ap_b_rad", "ap_c_rad", "rp_a_rad", "rp_b_rad", "rp_c_rad",
                   "visits": [{"recording", "lines": [first, last], "t_s": [t0, t1],
                               "attained": [...6]}, ...]}, ...],
        "worst": {"apx_m", ..., "rp_c_rad": largest absolute value over the poses,
                  "pose_of": {"apx_m": <pose number>, ...}},
        # kind "path":
        "main_path": <number of the path with the most passes x length: the test's path>,
        "paths": [{"path": 1, "start": [...6], "end": [...6], "length_m", "passes",
                   "points", "points_complete", "at_max_m", "at_mean_m", "at_max_at_s_m",
                   "rt_m", "at_a_rad", "at_b_rad", "at_c_rad", "rt_a_rad", "rt_b_rad",
                   "rt_c_rad", "pass_lines": [{"recording", "lines": [first, last]}, ...],
                   "along": {"s_m", "command_m", "barycentre_m", "at_x_m", "at_y_m",
                             "at_z_m", "at_m", "rt_m", "count"}}, ...]}, ...]}

``--plots DIR`` writes PNG files: per pose analysis ``NN_<label>_pose_bars.png`` (AP/RP per
pose and the worst) and ``NN_<label>_pose_scatter.png``; per path ``NN_<label>_pathK.png``
(desired vs executed path and AT along it); with several analyses ``pose_worst.png`` (the
worst figures side by side, like the paper's Fig. 6) and ``paths.png`` (each analysis's
main path, like Fig. 7).

Exit status: 0 done, 2 bad arguments or a recording the figures cannot use (the message
names the file, line and column).
"""

from __future__ import annotations

import argparse
import json
import sys

NAME = "iso9283"
HELP = "ISO 9283 pose accuracy/repeatability (AP, RP) and path accuracy/repeatability (AT, RT)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="+", metavar="RECORDING",
                   help="recording directories (cdpr-recording/1)")
    p.add_argument("--kind", choices=("pose", "path", "auto"), default="auto",
                   help="pose figures, path figures, or auto (default): path when the "
                        "recording moves and dwells at 2 poses at most")
    p.add_argument("--pool", action="store_true",
                   help="analyse all recordings together (default: each on its own)")
    p.add_argument("--settle", type=float, default=0.5, metavar="F",
                   help="part of each dwell, from its start, left out while the platform "
                        "settles (default 0.5: the attained pose is the dwell's second half)")
    p.add_argument("--path-points", type=int, default=500, metavar="M",
                   help="commanded points per path, evenly spaced, at which AT/RT are "
                        "computed (default 500)")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots into DIR")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _fail(args: argparse.Namespace, msg: str) -> int:
    print(f"cdpr iso9283: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return 2


def plot_count(analyses) -> int:
    """How many files :func:`write_plots` writes for these analyses."""
    poses = sum(an.kind == "pose" for an in analyses)
    paths = [an for an in analyses if an.kind != "pose"]
    return (2 * poses + sum(len(an.paths) for an in paths) + (poses > 1)
            + (sum(1 for an in paths if an.main_path() is not None) > 1))


def write_plots(analyses, out, on_plot=None) -> list:
    """The ``--plots`` files of analyses (see the module docstring); returns their paths.
    ``on_plot(path)`` is called as each one is written."""
    import numpy as np

    from bench.iso9283.analysis import path_run
    from bench.iso9283.plots import plot_path_cases, plot_pose_bars, plot_pose_scatter, safe_name

    written = []

    def add(path) -> None:
        written.append(path)
        if on_plot is not None:
            on_plot(path)
    worst_runs, path_cases = [], []
    for i, an in enumerate(analyses, start=1):
        stem = f"{i:02d}_{safe_name(an.label)}"
        if an.kind == "pose":
            runs = [dict(r.figures.to_dict(), label=f"P{j}") for j, r in enumerate(an.poses, 1)]
            runs.append(dict(an.worst(), label="worst", color="red"))
            add(plot_pose_bars(runs, f"{out}/{stem}_pose_bars.png",
                               f"{an.label}: ISO 9283 pose figures per commanded "
                               f"pose (bars: absolute values in 'worst')"))
            scat = [{"label": f"P{j}", "command": r.figures.command,
                     "attained": np.array([v.attained for v in r.visits]),
                     "rp_m": r.figures.rp} for j, r in enumerate(an.poses, 1)]
            add(plot_pose_scatter(scat, f"{out}/{stem}_pose_scatter.png",
                                  f"{an.label}: attained positions (x-y deviation "
                                  f"from the commanded pose)"))
            worst_runs.append(dict(an.worst(), label=an.label))
        else:
            for k, r in enumerate(an.paths, start=1):
                f = r.figures
                case = {"title": f"{an.label}, path {k} ({f.n} pass(es))",
                        "desired_m": f.command[:, :3],
                        "runs": {an.label: path_run(f)}}
                span = np.ptp(f.command[:, :3], axis=0)
                plane = "".join(sorted("xyz"[j] for j in np.argsort(span)[-2:]))
                add(plot_path_cases([case], f"{out}/{stem}_path{k}.png",
                                    f"{an.label}: ISO 9283 path accuracy, path {k}: "
                                    f"AT max {f.at * 1e3:.1f} mm, mean "
                                    f"{f.at_mean * 1e3:.1f} mm", plane))
                if r is an.main_path():
                    path_cases.append((case, plane))
    if len(worst_runs) > 1:
        add(plot_pose_bars(worst_runs, f"{out}/pose_worst.png",
                           "ISO 9283 pose figures, worst pose of each recording"))
    if len(path_cases) > 1:
        planes = {p for _, p in path_cases}
        add(plot_path_cases([c for c, _ in path_cases], f"{out}/paths.png",
                            "ISO 9283 path accuracy of each recording",
                            planes.pop() if len(planes) == 1 else "yz"))
    return written


def run(args: argparse.Namespace) -> int:
    from bench.iso9283.analysis import analyse, format_text, to_json
    from bench.recording import RecordingError, read_recording

    if not 0.0 <= args.settle < 1.0:
        return _fail(args, f"--settle {args.settle}: must be in [0, 1)")
    if args.path_points < 2:
        return _fail(args, f"--path-points {args.path_points}: must be >= 2")
    try:
        recs = [read_recording(p) for p in args.recordings]
        groups = [recs] if args.pool else [[r] for r in recs]
        analyses = [analyse(g, args.kind, args.settle, args.path_points) for g in groups]
    except RecordingError as e:
        return _fail(args, str(e))
    if args.plots:
        from bench.progress import Progress

        # a figure of many poses takes seconds: say what is coming, each plot as it is
        # written, and the progress line between them
        prog = Progress("cdpr iso9283 --plots", plot_count(analyses), unit="plots")
        prog.say(f"cdpr iso9283: writing {prog.total} plots into {args.plots}")

        def on_plot(p) -> None:
            prog.done += 1
            prog.say(f"plot {p}")

        try:
            with prog:
                write_plots(analyses, args.plots, on_plot)
        except OSError as e:
            return _fail(args, f"--plots {args.plots}: {e}")
    if args.json:
        print(json.dumps(to_json(analyses)))
    else:
        print(format_text(analyses))
    return 0
