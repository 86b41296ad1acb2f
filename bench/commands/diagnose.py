"""``cdpr diagnose RECORDING_DIR``: locate the mismatch, name the physics left out, fit it.

Outputs (``--plots DIR``, ``--write-model PATH``, ``--out FILE``) are checked before the
fit starts; the directories made for them are removed again (when still empty) if the
command then fails. Under ``--json`` stdout carries one JSON object: the report, or
``{"error": ...}`` when the diagnosis fails. Worker processes (``--jobs``) end with the
command, whatever ends it (Ctrl-C, SIGTERM, SIGKILL).

Exit status: 0 diagnosed, 1 the diagnosis failed, 2 bad recording or arguments,
130 interrupted (Ctrl-C), 143 terminated (SIGTERM).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from pathlib import Path

NAME = "diagnose"
HELP = "find which physics the model left out of a recording, fit it, show the fit improve"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="recording directory (cdpr-recording/1) or MCAP "
                                     "recording (.mcap, docs/guide/mcap-and-replay.md)")
    p.add_argument("--json", action="store_true",
                   help="print the cdpr-diagnosis/1 report object on stdout")
    p.add_argument("--out", metavar="FILE", help="also write the report (JSON) to FILE")
    p.add_argument("--plots", metavar="DIR", help="write plots (PNG) into DIR")
    p.add_argument("--write-model", metavar="PATH", help="write the corrected robot.toml")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes for candidate fits (default 2; 1 = in-process)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _interval_note(effect: dict, key: str) -> str:
    """The 95 % interval of parameter ``key`` of a report's ``effect`` (in the parameter's
    units), for the line beside its standard error, where it is not the value ± q standard
    errors (``interval_method`` not ``"linearised"``: a profile refit, the jackknife or the
    selective interval made it wider); ``""`` otherwise. An open end (``null``: as rigid as
    the data allow) reads ``inf``."""
    method = effect.get("interval_method", {}).get(key)
    iv = effect.get("interval95", {}).get(key)
    if not iv or method in (None, "linearised"):
        return ""
    lo, hi = ("-inf" if iv[0] is None else f"{iv[0]:.6g}",
              "inf" if iv[1] is None else f"{iv[1]:.6g}")
    return f"   95 % [{lo}, {hi}] ({method})"


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
    if rep["mismatch"].get("streams"):
        from bench.streams import summary_line

        lines.insert(1, "  streams: " + summary_line(rep["mismatch"]["streams"]))
    un = rep.get("unexplained")
    if un:
        lines.append("  UNEXPLAINED: " + un["summary"])
    if not rep["effects"] and not un:
        lines.append("  effects: none: the model explains the recording within the noise")
    for e in rep["effects"]:
        ev = e["evidence"]
        lines.append(f"  effect {e['name']}" + (" (provisional)" if e.get("provisional") else "")
                     + f": {e['explains']}")
        lines.append(f"    held-out pose {mm(ev['heldout_pose_rms_before_m'])} -> "
                     f"{mm(ev['heldout_pose_rms_after_m'])}, delta BIC "
                     + ("n/a" if ev["delta_bic"] is None else f"{ev['delta_bic']:.1f}"))
        for k, v in e["params"].items():
            lines.append(f"    {k:12} {v:14.6g} ± {e['stderr'][k]:.3g}" + _interval_note(e, k))
        if e["undetermined"]:
            lines.append(f"    undetermined by these poses: {', '.join(e['undetermined'])}")
        for a in e["alternatives"]:
            lines.append(f"    alternative: {a['name']} (delta BIC {a['delta_bic']:+.1f})")
    lines.append(f"  fitted: pose {mm(f['pose_rms_m'])} RMS, held-out {mm(f['heldout_pose_rms_m'])}"
                 f", exit points {mm(f['exit_point_rms_m'])}, tensions "
                 + ("n/a" if f["tension_rms_n"] is None else f"{f['tension_rms_n']:.2f} N")
                 + ("" if f.get("converged", True) else " (the fit did not converge)"))
    for x in rep["mismatch"].get("excluded", []):
        if "row" in x:
            lines.append(f"  excluded: recording.csv line {x['row']}, {x['column']} = "
                         f"{x['value']:g} ({x['why']})")
        else:
            lines.append(f"  excluded: {x['more']} more values")
    if rep["model"]:
        lines.append(f"  corrected model: {rep['model']}")
    return "\n".join(lines)


def _fail(args: argparse.Namespace, code: int, msg: str) -> int:
    print(f"cdpr diagnose: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg, "recording": args.recording}))
    return code


def _write_json(path: Path, obj: dict) -> None:
    from bench.outputs import write_text_file

    write_text_file(path, json.dumps(obj, indent=1))


def run(args: argparse.Namespace) -> int:
    from bench.outputs import removing_created

    # failed before writing there (a bad recording, Ctrl-C): no directory made for it left
    return removing_created(lambda created: _run(args, created))


def _run(args: argparse.Namespace, created: list[Path]) -> int:
    from bench.diagnosis.report import diagnose, prepare_outputs
    from bench.parallel import (
        ending_workers,
        interrupt_on_term,
        interruption,
        single_blas_thread,
        worker_pool,
    )
    from bench.recording import RecordingError

    single_blas_thread()
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    if args.jobs < 1:
        return _fail(args, 2, f"--jobs {args.jobs}: must be >= 1")
    try:
        prepare_outputs(args.write_model, args.plots, created)
        if args.out:
            from bench.outputs import output_file_problem

            problem = output_file_problem(args.out, "--out", created)
            if problem:
                raise OSError(problem)
    except OSError as e:
        return _fail(args, 2, str(e))
    try:
        with interrupt_on_term():
            pool = worker_pool(args.jobs, share_cores=True) if args.jobs > 1 else None
            with ending_workers(pool):
                dg = diagnose(args.recording, progress, pool, args.write_model)
    except RecordingError as e:
        return _fail(args, 2, str(e))
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM: one line, the workers are ended
        code, msg = interruption(e)
        print(f"cdpr diagnose: {msg}", file=sys.stderr)
        if args.json:
            print(json.dumps({"error": msg, "recording": args.recording}))
        return code
    except Exception as e:  # noqa: BLE001 - reported, with the trace on stderr
        traceback.print_exc(file=sys.stderr)
        return _fail(args, 1, f"the diagnosis failed: {type(e).__name__}: {e}")
    if args.plots:
        # seconds of drawing (matplotlib's start-up, the residual maps): said first
        progress(f"drawing the plots (residual maps, per-cable bars) into {args.plots}")
        try:
            from bench.diagnosis.plots import write_plots

            for p in write_plots(dg, args.plots):
                progress(f"plot {p}")
        except Exception as e:  # noqa: BLE001 - the report is not lost for a plot
            print(f"cdpr diagnose: --plots {args.plots}: {type(e).__name__}: {e}",
                  file=sys.stderr)
    code = 0
    if dg.write_error:
        print(f"cdpr diagnose: {dg.write_error}", file=sys.stderr)
        code = 1
    if args.out:
        try:
            _write_json(Path(args.out), dg.report)
        except OSError as e:  # the report still goes to stdout below: nothing lost
            print(f"cdpr diagnose: --out {e}", file=sys.stderr)
            code = 1
    if args.json:
        print(json.dumps(dg.report))
    else:
        print(_human(dg.report))
    return code
