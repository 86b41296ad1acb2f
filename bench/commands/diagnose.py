"""``cdpr diagnose RECORDING_DIR``: locate the mismatch, name the physics left out, fit it."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from bench.recording import RecordingError

NAME = "diagnose"
HELP = "find which physics the model left out of a recording, fit it, show the fit improve"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="recording directory (cdpr-recording/1)")
    p.add_argument("--json", action="store_true",
                   help="print the cdpr-diagnosis/1 report object on stdout")
    p.add_argument("--plots", metavar="DIR", help="write plots (PNG) into DIR")
    p.add_argument("--write-model", metavar="PATH", help="write the corrected robot.toml")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes for candidate fits (default 2; 1 = in-process)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _human(rep: dict) -> str:
    b, f = rep["baseline"], rep["fitted"]

    def mm(x):
        return "n/a" if x is None else f"{x * 1e3:.2f} mm"

    lines = [f"recording {rep['recording']}: {rep['samples']} samples",
             f"  baseline: pose {mm(b['pose_rms_m'])} RMS (max {mm(b['pose_max_m'])}), "
             f"exit points {mm(b['exit_point_rms_m'])}, tensions "
             + ("n/a" if b["tension_rms_n"] is None else f"{b['tension_rms_n']:.2f} N")
             + ", force balance "
             + ("n/a" if b["wrench_rms"] is None else f"{b['wrench_rms']:.2f} N"),
             "  mismatch: " + rep["mismatch"]["summary"]]
    if not rep["effects"]:
        lines.append("  effects: none: the model explains the recording within the noise")
    for e in rep["effects"]:
        ev = e["evidence"]
        lines.append(f"  effect {e['name']}: {e['explains']}")
        lines.append(f"    held-out pose {mm(ev['heldout_pose_rms_before_m'])} -> "
                     f"{mm(ev['heldout_pose_rms_after_m'])}, delta BIC "
                     + ("n/a" if ev["delta_bic"] is None else f"{ev['delta_bic']:.1f}"))
        for k, v in e["params"].items():
            lines.append(f"    {k:12} {v:14.6g} ± {e['stderr'][k]:.3g}")
        if e["undetermined"]:
            lines.append(f"    undetermined by these poses: {', '.join(e['undetermined'])}")
        for a in e["alternatives"]:
            lines.append(f"    alternative: {a['name']} (delta BIC {a['delta_bic']:+.1f})")
    lines.append(f"  fitted: pose {mm(f['pose_rms_m'])} RMS, held-out {mm(f['heldout_pose_rms_m'])}"
                 f", exit points {mm(f['exit_point_rms_m'])}, tensions "
                 + ("n/a" if f["tension_rms_n"] is None else f"{f['tension_rms_n']:.2f} N"))
    if rep["model"]:
        lines.append(f"  corrected model: {rep['model']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from bench.diagnosis.report import diagnose

    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    pool = ProcessPoolExecutor(args.jobs) if args.jobs > 1 else None
    try:
        dg = diagnose(args.recording, progress, pool, args.write_model)
    except RecordingError as e:
        print(f"cdpr diagnose: {e}", file=sys.stderr)
        return 2
    finally:
        if pool is not None:
            pool.shutdown()
    if args.plots:
        from bench.diagnosis.plots import write_plots

        for p in write_plots(dg, args.plots):
            progress(f"plot {p}")
    if args.json:
        print(json.dumps(dg.report))
    else:
        print(_human(dg.report))
    return 0
