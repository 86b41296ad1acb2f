"""``cdpr dry-run paper-paths`` and ``cdpr dry-run paper-poses``: the paper's campaigns.

Called by :mod:`bench.commands.dryrun` for these two names (the options are the dry run's,
plus ``--jobs``, ``--cycles``, ``--speeds``, ``--models``, ``--diagnosed-model``). The
campaigns themselves: :mod:`bench.dryrun.paper`; the results: :mod:`bench.dryrun.paper_report`.

``paper-paths [--json] [--plots DIR] [--record DIR] [--jobs N] [--rate HZ] [--duration S]
[--models nominal,remeasured,compliant,diagnosed,learned,learned_warmup,learned_untracked,
learned_notracker]
[--diagnosed-model ROBOT.toml]``: the
four path runs of Table 3 per model, the calibration campaign (``paper-calibration``
scenario, ``calibration-quick`` path) recorded by a dry run and diagnosed by ``cdpr
diagnose`` for the ``diagnosed`` model (``--diagnosed-model`` runs a corrected robot.toml
you have instead), and the measured-vs-planned comparison in ``paper-heavy``.

``paper-poses [--cycles N] [--speeds 10,40,100] [--models nominal,remeasured] [--sets
violet,pink,gold] [--json] [--plots DIR] [--record DIR] [--jobs N] [--rate HZ]``: the three
pose sets of Fig. 6.

Both log slack cables instead of holding (``--react`` changes that or any other reaction,
e.g. ``--react slack=hold``; docs/explanation/paper.md says why).

``paper-paths --json``: ``{"scenario": "paper-paths", "cases": [{"path": "centre"|"side",
"init": "centre"|"side", "at_max_<model>_m", "at_mean_<model>_m" (every model run; nominal,
compliant and diagnosed always present, null when not run), "at_max_cut_<model>" (1 - AT
max / nominal AT max), "paper_at_max_nominal_m", "paper_at_mean_nominal_m",
"paper_at_max_compliant_estimate_m", "paper_at_mean_compliant_estimate_m" (Table 3),
"slack_events": {model: count}}], "models": {name: what it is}, "goals": {"nominal_order",
"paper_order", "worst_is_side_path_centre_init", "best_is_centre_path_centre_init",
"min_at_max_cut_<model>", "<model>_cuts_at_max_by_80pct_everywhere"},
"planned_vs_measured": {"scenario", "platform_mass_kg": {"truth", "model"}, "cases": [{"path",
"init", "at_max_measured_m", "at_mean_measured_m", "at_max_planned_m", "at_mean_planned_m"}],
"measured_better_everywhere"}, "diagnosis": {"effects", "samples", "baseline", "fitted",
"model_file", "diagnose_s", "calibration", "vs_truth": {"exit_rms_m", "exit_max_m",
"stiffness_fitted", "stiffness_truth", "stiffness_rel_error"}}, "runs": [{"label", "model",
"mast_tensions", "simulated_s", "wall_s", "slack_events", "events", "recording"}],
"failures": [{"label", "error"}], "learning": [{"label", "warmup_s", "updates", "samples",
"rejected", "handovers", "event_counts", "identifiable", "offset_sd_mm_max",
"untracked_directions", "drift"}] (the learning models' runs), "rate_hz", "reactions",
"wall_s", "plots"}`` (m, s).

``paper-poses --json``: ``{"scenario": "paper-poses", "cycles", "speeds_pct", "models",
"rate_hz", "reactions", "runs": [{"set", "speed_pct", "model", "apx_m", "apy_m", "apz_m",
"ap_m", "rp_m", "ap_a_rad", ..., "rp_c_rad" (the worst pose of the set, ISO 9283), "poses":
[{"command", "n", "ap_m", "rp_m"}], "simulated_s", "wall_s", "recording"}],
"ap_grows_away_from_centre": {"<model>_<v>pct": bool}, "wall_s", "failures", "plots"}``.

``paper-drift [--duration S] [--json] [--record DIR] [--jobs N]``: the supporting ropes
settle a further 5 mm over ``--duration`` (default 3600 s) while the centre path runs again
and again, learned controller against the fixed true model of t = 0
(:mod:`bench.dryrun.paper_drift`); ``--json``: ``{"scenario": "paper-drift", "settle_m",
"duration_s", "runs": {"learned"|"fixed": {"passes", "settled_m", "worst_m", "ratio",
"first_m", "last_m", "per_pass": [[t_s, at_m]], "drift_events": [[t_s, text]] (learned),
"learn_events", "warmup_s", "drift": {"detected_at_s", "detections", "events", "drifts",
"active", "length_change_mm"}}}, "goals": {"learned_ratio", "learned_within_2x",
"drift_detected_at_s", "fixed_ratio", "fixed_degrades"}, "failures", "wall_s"}``.

Exit status: 0 every run completed, 1 a run failed (the others are reported), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

CAMPAIGNS = ("paper-paths", "paper-poses", "paper-drift")


def _fail(args: argparse.Namespace, code: int, msg: str) -> int:
    print(f"cdpr dry-run {args.scenario}: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return code


def _list(text: str | None, what: str, allowed: tuple[str, ...] | None = None,
          number: bool = False) -> list:
    if text is None:
        return []
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise ValueError(f"{what} {text!r}: empty list")
    if number:
        out = []
        for t in items:
            try:
                v = float(t)
            except ValueError:
                raise ValueError(f"{what} {text!r}: {t!r} is not a number") from None
            if not 0 < v <= 100:
                raise ValueError(f"{what} {text!r}: {t} must be in (0, 100]")
            out.append(v)
        return out
    bad = [t for t in items if allowed is not None and t not in allowed]
    if bad:
        raise ValueError(f"{what} {text!r}: unknown {', '.join(bad)} (known: "
                         f"{', '.join(allowed or ())})")
    return items


def _react_text(reactions: dict[str, str]) -> str:
    return "supervisor reactions changed: " + ", ".join(f"{k}={v}" for k, v in
                                                        reactions.items())


def run(args: argparse.Namespace) -> int:
    """Run the campaign ``args.scenario`` names (see the module docstring)."""
    from bench.dryrun import paper
    from bench.dryrun.scenarios import max_rate_hz
    from controller.winch import load_winches

    name = args.scenario
    from controller.supervisor import parse_reactions

    try:  # the campaigns log slack cables (paper.REACTIONS); --react changes any reaction
        reactions = dict(paper.REACTIONS)
        reactions.update({k: r.label for k, r in parse_reactions(args.react or []).items()})
    except ValueError as exc:
        return _fail(args, 2, f"--react {exc}")
    for opt in ("robot", "path", "speed_pct", "faults", "decimate"):
        if getattr(args, opt, None) is not None:
            return _fail(args, 2, f"--{opt.replace('_', '-')} does not apply to the {name} "
                                  f"campaign")
    if getattr(args, "rig", "inprocess") != "inprocess" or getattr(args, "realtime", False):
        return _fail(args, 2, "campaigns run lock-step on the in-process rig (no --rig "
                              "process, no --realtime)")
    if args.jobs < 1:
        return _fail(args, 2, f"--jobs {args.jobs}: must be >= 1")
    top = max_rate_hz(load_winches())
    if args.rate is not None and not 0 < args.rate <= top * (1 + 1e-9):
        return _fail(args, 2, f"--rate {args.rate:g}: must be in (0, {top:.1f}] Hz (the CAN "
                              f"bus limit)")
    if args.duration is not None and not args.duration > 0:
        return _fail(args, 2, f"--duration {args.duration}: must be > 0")
    try:
        models = _list(args.models, "--models", tuple(paper.MODELS) + ("planned",))
        speeds = _list(args.speeds, "--speeds", number=True)
        cases = [tuple(c.split("/")) for c in _list(
            args.cases, "--cases", tuple(f"{p}/{i}" for p, i in paper.CASES))]
        sets = _list(args.sets, "--sets", tuple(paper.POSE_SETS))
    except ValueError as exc:
        return _fail(args, 2, str(exc))
    if args.diagnosed_model is not None:
        from controller.robot import RobotFileError, load_robot
        try:
            load_robot(args.diagnosed_model)
        except (FileNotFoundError, RobotFileError) as exc:
            return _fail(args, 2, f"--diagnosed-model: {exc}")
    if name == "paper-poses" and args.cycles < 1:
        return _fail(args, 2, f"--cycles {args.cycles}: must be >= 1")
    for d, what in ((args.record, "--record"), (args.plots, "--plots")):
        if d is not None:
            p = Path(d)
            if p.exists() and not p.is_dir():
                return _fail(args, 2, f"{what} {p}: exists and is not a directory")
            if what == "--record" and p.is_dir() and any(p.iterdir()) and not args.force:
                return _fail(args, 2, f"--record {p}: not empty (use --force to overwrite)")
    keep = args.record is not None
    work = Path(args.record) if keep else Path(tempfile.mkdtemp(prefix=f"cdpr-{name}-"))
    if keep and work.exists() and args.force:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    stop_file = work / ".stop"
    stop_file.unlink(missing_ok=True)

    previous = {}

    def on_term(signum, frame):  # SIGTERM: bench.cli's line and exit status 143
        from bench.parallel import Terminated
        raise Terminated(signum)

    if threading.current_thread() is threading.main_thread():
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, on_term)
    t0 = time.perf_counter()
    try:
        if name == "paper-drift":
            if sets or cases or models:
                return _fail(args, 2, "--sets, --cases and --models do not apply to "
                                      "paper-drift")
            return _drift(args, work, t0)
        if name == "paper-paths":
            if sets:
                return _fail(args, 2, "--sets applies to paper-poses")
            return _paths(args, paper, work, models, cases, t0, reactions)
        if cases:
            return _fail(args, 2, "--cases applies to paper-paths")
        return _poses(args, paper, work, models, speeds, sets, t0, reactions)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if not keep:
            shutil.rmtree(work, ignore_errors=True)


def _paths(args, paper, work: Path, models: list[str], cases: list, t0: float,
           reactions: dict[str, str]) -> int:
    from bench.dryrun import paper_report as rep

    opt = paper.PathsOptions(work=work, max_duration_s=args.duration,
                             diagnosed_model=args.diagnosed_model, reactions=reactions)
    if models:
        opt.models = tuple(m for m in paper.MODEL_ORDER if m in models)
        opt.planned = "planned" in models
    if cases:
        opt.cases = tuple(c for c in paper.CASES if c in cases)
    if args.rate is not None:
        opt.rate_hz = float(args.rate)
    first, second = paper.paths_plan(opt)
    prog = paper.Progress("paper-paths", len(first) + len(second), args.quiet)
    if not args.quiet:
        extra = (f", measured vs planned tensions in {opt.heavy_scenario}" if opt.planned
                 else "")
        print(f"cdpr dry-run paper-paths: {len(first) + len(second)} runs ("
              f"{', '.join(opt.models)}; {len(opt.cases)} cases{extra}), {opt.rate_hz:g} Hz, "
              f"{args.jobs} processes; {_react_text(reactions)}; recordings in {work}",
              file=sys.stderr)
    prog.start()
    try:
        results, failures = paper.run_campaign([first, second], args.jobs, prog)
    finally:
        prog.close()
    res = rep.paths_result(results, failures, opt, time.perf_counter() - t0)
    if args.plots:
        res["plots"] = [str(p) for p in rep.paths_plots(results, opt, args.plots)]
    if not args.record:
        res["recordings_kept"] = False
    if args.json:
        print(json.dumps(res))
    else:
        print(rep.paths_table(res))
    return 1 if failures else 0


def _poses(args, paper, work: Path, models: list[str], speeds: list[float], sets: list[str],
           t0: float, reactions: dict[str, str]) -> int:
    from bench.dryrun import paper_report as rep

    opt = paper.PosesOptions(work=work, cycles=args.cycles,
                             diagnosed_model=args.diagnosed_model, reactions=reactions)
    if "planned" in models:
        return _fail(args, 2, "--models planned: the measured-vs-planned comparison is part of "
                              "paper-paths")
    if models:
        learned = [m for m in models if m in paper.LEARNED]
        if learned:
            return _fail(args, 2, f"--models {', '.join(learned)}: the learning models run in "
                                  f"paper-paths")
        if "diagnosed" in models and args.diagnosed_model is None:
            return _fail(args, 2, "--models diagnosed needs --diagnosed-model ROBOT.toml (the "
                                  "corrected robot.toml of cdpr diagnose, e.g. the one "
                                  "paper-paths --record DIR leaves in DIR)")
        opt.models = tuple(m for m in paper.MODEL_ORDER if m in models)
    if speeds:
        opt.speeds = tuple(speeds)
    if sets:
        opt.sets = tuple(s for s in paper.POSE_SETS if s in sets)
    if args.rate is not None:
        opt.rate_hz = float(args.rate)
    items = paper.poses_plan(opt)
    prog = paper.Progress("paper-poses", len(items), args.quiet)
    if not args.quiet:
        print(f"cdpr dry-run paper-poses: {len(items)} runs (sets {', '.join(opt.sets)}; "
              f"speeds {', '.join(f'{v:g}' for v in opt.speeds)} %; models "
              f"{', '.join(opt.models)}; {opt.cycles} cycles), {opt.rate_hz:g} Hz, "
              f"{args.jobs} processes; {_react_text(reactions)}; recordings in {work}",
              file=sys.stderr)
    prog.start()
    try:
        results, failures = paper.run_campaign([items], args.jobs, prog)
    finally:
        prog.close()
    res = rep.poses_result(results, failures, opt, time.perf_counter() - t0)
    if args.plots:
        res["plots"] = [str(p) for p in rep.poses_plots(res, args.plots)]
    if args.json:
        print(json.dumps(res))
    else:
        print(rep.poses_table(res))
    return 1 if failures else 0


def _drift(args, work: Path, t0: float) -> int:
    from bench.dryrun import paper
    from bench.dryrun import paper_drift as pd

    duration = float(args.duration) if args.duration is not None else pd.DURATION_S
    rate = float(args.rate) if args.rate is not None else pd.RATE_HZ
    items = pd.drift_plan(work, duration, pd.SETTLE_M, rate)
    prog = paper.Progress("paper-drift", len(items), args.quiet)
    if not args.quiet:
        print(f"cdpr dry-run paper-drift: ropes settling {1e3 * pd.SETTLE_M:g} mm over "
              f"{duration:g} s, {len(items)} runs (learned, fixed), {rate:g} Hz, {args.jobs} "
              f"processes; recordings in {work}", file=sys.stderr)
    prog.start()
    try:
        results, failures = paper.run_campaign([items], args.jobs, prog)
    finally:
        prog.close()
    res = pd.drift_result(results, failures, pd.SETTLE_M, duration)
    res["wall_s"] = time.perf_counter() - t0
    if args.json:
        print(json.dumps(res))
    else:
        print(pd.drift_table(res))
    return 1 if failures else 0
