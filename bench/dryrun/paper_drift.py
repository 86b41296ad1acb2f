"""``cdpr dry-run paper-drift``: the robot keeps changing while it works.

The supporting ropes settle a further ``settle_m`` (default 5 mm, :data:`SETTLE_M`) over the
run (``paper-centre`` with the plant's ``rope_settle_m`` nuisance: every exit point moves
horizontally toward the pivots' centroid, linearly in time, :class:`firmware_sim.plant.Nuisances`)
while the platform runs the paper's centre path again and again for ``duration_s``. Two runs,
each lock-step on the in-process rig (:func:`bench.dryrun.paper.run_one`):

- ``learned``: starts from the nominal model, learns during the warm-up and keeps learning
  (tracker fixes, tensions, encoders; :mod:`bench.dryrun.learn`); the estimator's windowed
  innovation test raises a ``learn_drift`` event when the robot changes and learns again
  (:class:`controller.online_ident.IdentOptions`, ``drift_window``);
- ``fixed``: the plant's true model at t = 0 (exit points and mast stiffness, what a perfect
  offline ``cdpr diagnose`` would give before the run), never changed.

Per pass of the path (the recording's ``cycle``), its ISO 9283 path accuracy AT on its own
(:func:`pass_errors`).
``settled``: the largest of the first :data:`SETTLED_PASSES` passes; ``worst``: of all
passes; ``ratio`` = worst / settled. The goal: learned ratio <= 2 while the fixed model's
last passes are worse than its first.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from bench.dryrun import paper

#: [m] the ropes' further settling over the run (exit displacement)
SETTLE_M = 0.005
#: [s] the run's length (from the path's first pass)
DURATION_S = 3600.0
#: control rate [Hz] of the drift runs (the figures do not depend on it)
RATE_HZ = 32.0
#: passes whose worst error is the settled value
SETTLED_PASSES = 3
#: the goal: the learned controller's worst pass within this factor of its settled value
GOAL_RATIO = 2.0


def drift_plan(work: Path, duration_s: float = DURATION_S, settle_m: float = SETTLE_M,
               rate_hz: float = RATE_HZ, models: tuple[str, ...] = ("learned", "fixed"),
               scenario: str = paper.SCENARIO) -> list[paper.RunSpec]:
    """The runs: ``models`` of ``learned`` (nominal start, learning on) and ``fixed`` (the
    truth at t = 0), ``duration_s`` [s] of the centre path repeated, the ropes settling
    ``settle_m`` [m] over it (plant time from the start, warm-up included)."""
    from controller.paths import load_path

    sc = paper.load_named_scenario(scenario)
    sc = dataclasses.replace(sc, rope_settle_m=float(settle_m), rope_settle_s=float(duration_s))
    path = load_path(paper.PATHS["centre"])
    one = paper.with_warmup(path, (), sc.init_pose).duration_s
    path = dataclasses.replace(path, repeat=int(math.ceil(duration_s / one)) + 1)
    stop = str(work / ".stop")
    items = []
    for m in models:
        learn = {"tracker": True} if m == "learned" else None
        robot = sc.model if m == "learned" else sc.truth
        items.append(paper.RunSpec(
            f"drift-{m}", sc, path, str(work / f"drift-{m}"), robot=robot, rate_hz=rate_hz,
            max_duration_s=duration_s, progress=str(work / f".drift-{m}.progress"),
            stop_file=stop, kind="record", learn=learn,
            warmup=paper.warmup_specs if learn is not None else None,
            tags={"model": m, "settle_m": settle_m, "duration_s": duration_s}))
    return items


def pass_errors(recording: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Per pass of the path in a recording (the ISO 9283 analysis's main path, each pass
    on its own): (start time [s], its AT: the largest distance of the pass to the
    commanded path in the normal planes [m]) (K,), (K,)."""
    from bench.iso9283.analysis import PATH_POINTS, analyse
    from bench.iso9283.figures import path_figures, resample_path
    from bench.recording import read_recording

    rec = read_recording(recording)
    main = analyse([rec], kind="path").main_path()
    if main is None:
        return np.zeros(0), np.zeros(0)
    s, cmd, tan = resample_path(main.passes[0].command, PATH_POINTS, with_tangents=True)
    starts = np.array([float(rec.t[p.rows[0]]) for p in main.passes])
    at = np.array([float(path_figures(cmd, [p.attained], s=s, tangents=tan).at)
                   for p in main.passes])
    order = np.argsort(starts)
    return starts[order], at[order]


def drift_summary(result: dict[str, Any]) -> dict[str, Any]:
    """One run's figures: ``passes``, ``settled_m``, ``worst_m``, ``ratio``, ``first_m`` /
    ``last_m`` (the largest of the first / last :data:`SETTLED_PASSES` passes), ``per_pass``
    ([t_s, err_m]), and for the learned run its ``drift_events`` ([t_s, text]), ``learn_events``
    (count per kind) and ``drift`` (the detections' summary,
    :meth:`controller.online_ident.DriftReport.summary`)."""
    t, e = pass_errors(result["recording"])
    k = SETTLED_PASSES
    out: dict[str, Any] = {"model": result["tags"]["model"], "passes": int(len(e))}
    if len(e):
        settled = float(e[:k].max())
        out.update(settled_m=settled, worst_m=float(e.max()),
                   ratio=float(e.max() / settled) if settled > 0 else None,
                   first_m=settled, last_m=float(e[-k:].max()),
                   per_pass=[[round(a, 3), b] for a, b in zip(t.tolist(), e.tolist(),
                                                               strict=True)])
    learn = result.get("learn")
    if learn is not None:
        out["drift_events"] = [[e["t"], e["text"]] for e in learn["events"]
                               if e["kind"] == "drift"]
        out["learn_events"] = {k2: sum(1 for e in learn["events"] if e["kind"] == k2)
                               for k2 in sorted({e["kind"] for e in learn["events"]})}
        out["warmup_s"] = learn.get("warmup_s")
        out["drift"] = learn.get("drift")
    return out


def drift_result(results: list[dict], failures: list[dict], settle_m: float,
                 duration_s: float) -> dict[str, Any]:
    """The ``paper-drift --json`` object: ``{"scenario": "paper-drift", "settle_m",
    "duration_s", "runs": {model: drift_summary}, "goals": {"learned_ratio",
    "learned_within_2x", "fixed_degrades", "drift_detected_at_s"}, "failures"}``."""
    runs = {r["tags"]["model"]: drift_summary(r) for r in results}
    goals: dict[str, Any] = {}
    lr, fx = runs.get("learned"), runs.get("fixed")
    if lr and lr.get("ratio") is not None:
        goals["learned_ratio"] = lr["ratio"]
        goals["learned_within_2x"] = lr["ratio"] <= GOAL_RATIO
        ev = lr.get("drift_events") or []
        goals["drift_detected_at_s"] = ev[0][0] if ev else None
    if fx and fx.get("passes"):
        goals["fixed_ratio"] = fx["ratio"]
        goals["fixed_degrades"] = fx["last_m"] > fx["first_m"]
    return {"scenario": "paper-drift", "settle_m": settle_m, "duration_s": duration_s,
            "runs": runs, "goals": goals, "failures": failures}


def drift_table(res: dict[str, Any]) -> str:
    """The text of ``paper-drift``."""
    lines = [f"paper-drift: ropes settle {1e3 * res['settle_m']:.1f} mm over "
             f"{res['duration_s']:.0f} s of the centre path",
             f"{'model':10s} {'passes':>6s} {'settled':>9s} {'worst':>9s} {'ratio':>6s} "
             f"{'last':>9s}"]
    for m, r in res["runs"].items():
        if not r.get("passes"):
            lines.append(f"{m:10s} no pass")
            continue
        lines.append(f"{m:10s} {r['passes']:6d} {1e3 * r['settled_m']:7.2f}mm "
                     f"{1e3 * r['worst_m']:7.2f}mm {r['ratio']:6.2f} {1e3 * r['last_m']:7.2f}mm")
        for i, (t, text) in enumerate(r.get("drift_events", [])):
            lines.append(f"  drift {'event' if i else 'detected'} at t = {t:.1f} s: {text}")
        d = r.get("drift")
        if d:
            lines.append(f"  {d['detections']} drift detections, {d['events']} events, "
                         f"{d['drifts']} drift(s), the model's lengths changed up to "
                         f"{d['length_change_mm']:.1f} mm"
                         f"{', still drifting at the end' if d['active'] else ''}")
    g = res["goals"]
    if "learned_within_2x" in g:
        lines.append(f"learned worst pass within {GOAL_RATIO:g}x its settled value: "
                     f"{'yes' if g['learned_within_2x'] else 'NO'}")
    if "fixed_degrades" in g:
        lines.append(f"fixed model degrades (last passes worse than first): "
                     f"{'yes' if g['fixed_degrades'] else 'no'}")
    for f in res["failures"]:
        lines.append(f"FAILED {f['label']}: {f['error']}")
    return "\n".join(lines)
