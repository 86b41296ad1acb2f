"""The results of the paper's campaigns (:mod:`bench.dryrun.paper`): the ``--json`` objects,
the text tables (Table 3, Fig. 6's figures) and the plots (Fig. 7- and Fig. 6-like, drawn by
:mod:`bench.iso9283.plots`).

- :func:`paths_result` the ``paper-paths --json`` object: ``{"scenario": "paper-paths",
  "cases": [{"path", "init", "at_max_<model>_m", "at_mean_<model>_m", "at_max_cut_<model>",
  "paper_at_max_nominal_m", ...}], "goals", "planned_vs_measured", "diagnosis", "runs",
  "failures", ...}`` (documented in :mod:`bench.dryrun.paper_command`);
- :func:`poses_result` the ``paper-poses --json`` object;
- :func:`paths_table`, :func:`poses_table` the text; :func:`paths_plots`,
  :func:`poses_plots` the PNGs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.dryrun.paper import (
    GOAL_CUT,
    LEARNED,
    MODEL_ORDER,
    MODELS,
    PAPER_TABLE3,
    PathsOptions,
    PosesOptions,
    load_named_scenario,
)
from controller.robot import Robot


def _by(results: Sequence[dict], **tags) -> dict | None:
    for r in results:
        t = r.get("tags", {})
        if all(t.get(k) == v for k, v in tags.items()):
            return r
    return None


def _cut(nominal: float | None, other: float | None) -> float | None:
    if nominal is None or other is None or not nominal > 0:
        return None
    return 1.0 - other / nominal


def _f(x: Any) -> Any:
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def diagnosis_vs_truth(model_file: str, truth: Robot,
                       undetermined: Sequence[str] = ()) -> dict[str, Any]:
    """How far the diagnosed robot.toml is from the plant's truth: exit points A* (RMS and
    max [m]), mast stiffness (per mast, relative error of kx, ky, kz; None for a stiffness
    the diagnosis left ``undetermined``, e.g. ``kz_1``: the calibration did not load it)."""
    from controller.robot import load_robot
    from controller.statics import settled_exits

    m = load_robot(model_file)
    d = np.linalg.norm(settled_exits(m) - settled_exits(truth), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = m.stiffness / truth.stiffness - 1.0
    for i, mid in enumerate(m.mast_ids):
        for a, ax in enumerate("xyz"):
            if f"k{ax}_{mid}" in undetermined:
                rel[i, a] = np.nan
    return {"exit_rms_m": float(np.sqrt(np.mean(d ** 2))), "exit_max_m": float(d.max()),
            "stiffness_fitted": [[_f(v) for v in row] for row in m.stiffness],
            "stiffness_truth": [[_f(v) for v in row] for row in truth.stiffness],
            "stiffness_rel_error": [[_f(v) for v in row] for row in rel]}


#: the models whose AT max cut against nominal is a goal
CUT_MODELS = ("compliant", "diagnosed") + tuple(LEARNED)


def _learning(r: dict) -> dict[str, Any]:
    """A learning run's summary: its label, warm-up [s], updates, samples, rejected batches,
    hand-overs, its events counted by kind, what it could identify (said before moving)."""
    lr = r["learn"]
    counts: dict[str, int] = {}
    for e in lr["events"]:
        counts[e["kind"]] = counts.get(e["kind"], 0) + 1
    return {"label": r["label"], "warmup_s": lr.get("warmup_s"), "updates": lr["updates"],
            "samples": lr["samples"], "rejected": lr["rejected"], "handovers": lr["handovers"],
            "event_counts": counts, "identifiable": lr.get("identifiable"),
            "offset_sd_mm_max": lr.get("offset_sd_mm_max"),
            "untracked_directions": lr.get("untracked_directions"),
            "drift": lr.get("drift")}


def paths_result(results: Sequence[dict], failures: Sequence[dict], opt: PathsOptions,
                 wall_s: float) -> dict[str, Any]:
    """The ``paper-paths --json`` object (see :mod:`bench.dryrun.paper_command`)."""
    cases = []
    for case in opt.cases:
        c: dict[str, Any] = {"path": case[0], "init": case[1]}
        nominal = _by(results, path=case[0], init=case[1], model="nominal")
        for m in opt.models:
            r = _by(results, path=case[0], init=case[1], model=m, **(
                {} if m != "compliant" else {}))
            if r is not None and r.get("tags", {}).get("scenario"):
                r = None
            c[f"at_max_{m}_m"] = None if r is None else r["at_max_m"]
            c[f"at_mean_{m}_m"] = None if r is None else r["at_mean_m"]
            if m != "nominal":
                c[f"at_max_cut_{m}"] = _cut(None if nominal is None else nominal["at_max_m"],
                                            c[f"at_max_{m}_m"])
        for m in ("nominal", "compliant", "diagnosed"):
            c.setdefault(f"at_max_{m}_m", None)
            c.setdefault(f"at_mean_{m}_m", None)
        p = PAPER_TABLE3.get(case)
        if p:
            c.update(paper_at_max_nominal_m=p[0], paper_at_mean_nominal_m=p[1],
                     paper_at_max_compliant_estimate_m=p[2],
                     paper_at_mean_compliant_estimate_m=p[3])
        c["slack_events"] = {m: (r or {}).get("slack_events") for m in opt.models
                             if (r := _by(results, path=case[0], init=case[1], model=m))}
        cases.append(c)
    out: dict[str, Any] = {"scenario": "paper-paths", "cases": cases,
                           "models": {m: MODELS[m] for m in opt.models},
                           "rate_hz": opt.rate_hz, "reactions": dict(opt.reactions),
                           "wall_s": wall_s}
    # goals: the paper's ordering of the nominal cases, and the cut of the AT max
    nom = {(c["path"], c["init"]): c["at_max_nominal_m"] for c in cases}
    goals: dict[str, Any] = {}
    if all(v is not None for v in nom.values()) and len(nom) == 4:
        order = sorted(nom, key=lambda k: nom[k])
        goals["nominal_order"] = [f"{p} path, {i} init" for p, i in order]
        goals["worst_is_side_path_centre_init"] = order[-1] == ("side", "centre")
        goals["best_is_centre_path_centre_init"] = order[0] == ("centre", "centre")
        goals["paper_order"] = ["centre path, centre init", "centre path, side init",
                                "side path, side init", "side path, centre init"]
    for m in CUT_MODELS:
        cuts = [c.get(f"at_max_cut_{m}") for c in cases]
        if m in opt.models and cuts and all(v is not None for v in cuts):
            goals[f"min_at_max_cut_{m}"] = min(cuts)
            goals[f"{m}_cuts_at_max_by_80pct_everywhere"] = min(cuts) >= GOAL_CUT
    out["goals"] = goals
    out["learning"] = [_learning(r) for r in results if r.get("learn") is not None]
    if opt.planned:
        pv = []
        for case in opt.cases:
            rm = _by(results, path=case[0], init=case[1], mast_tensions="measured",
                     scenario=opt.heavy_scenario)
            rp = _by(results, path=case[0], init=case[1], mast_tensions="planned",
                     scenario=opt.heavy_scenario)
            pv.append({"path": case[0], "init": case[1],
                       "at_max_measured_m": None if rm is None else rm["at_max_m"],
                       "at_mean_measured_m": None if rm is None else rm["at_mean_m"],
                       "at_max_planned_m": None if rp is None else rp["at_max_m"],
                       "at_mean_planned_m": None if rp is None else rp["at_mean_m"]})
        heavy = load_named_scenario(opt.heavy_scenario)
        out["planned_vs_measured"] = {
            "scenario": opt.heavy_scenario,
            "platform_mass_kg": {"truth": heavy.truth.mass, "model": heavy.model.mass},
            "model": "the scenario's truth without its platform mass (the payload the "
                     "controller does not know)",
            "cases": pv,
            "measured_better_everywhere": all(
                c["at_max_measured_m"] is not None and c["at_max_planned_m"] is not None
                and c["at_max_measured_m"] < c["at_max_planned_m"] for c in pv)}
    cal = next((r for r in results if r.get("tags", {}).get("role") == "calibration"), None)
    if cal is not None:
        sc = load_named_scenario(opt.calibration_scenario)
        out["diagnosis"] = dict(cal["diagnosis"], model_file=cal["model_file"],
                                diagnose_s=cal["diagnose_s"],
                                calibration={"path": opt.calibration_path,
                                             "simulated_s": cal["simulated_s"],
                                             "wall_s": cal["wall_s"],
                                             "rate_hz": cal["rate_hz"],
                                             "recording": cal["recording"]},
                                vs_truth=diagnosis_vs_truth(cal["model_file"], sc.truth, [
                                    k for e in cal["diagnosis"]["effects"]
                                    for k in e["undetermined"]]))
    elif opt.diagnosed_model is not None:
        out["diagnosis"] = {"model_file": opt.diagnosed_model}
    out["runs"] = [{"label": r["label"], "model": r["model"],
                    "mast_tensions": r["mast_tensions"], "simulated_s": r["simulated_s"],
                    "wall_s": r["wall_s"], "slack_events": r["slack_events"],
                    "events": len(r["events"]), "retried": r.get("retried", []),
                    "recording": r["recording"]} for r in results]
    out["failures"] = list(failures)
    return _clean(out)


def _clean(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.integer,)):
        return int(x)
    return _f(x)


def _mm(x: float | None, w: int = 6) -> str:
    return f"{'-':>{w}}" if x is None else f"{1e3 * x:{w}.1f}"


def _pct(x: float | None) -> str:
    return "    -" if x is None else f"{100 * x:4.0f}%"


def paths_table(res: dict[str, Any]) -> str:
    """Table 3 as text (mm), the paper's values beside, then the planned-vs-measured
    comparison and the diagnosis."""
    models = [m for m in MODEL_ORDER if m in res["models"]]
    lines = ["Table 3: path accuracy AT (ISO 9283), max / mean [mm]; cut = reduction of AT "
             "max from the nominal model",
             f"  {'path':6} {'init':6} | {'paper N':>13} {'paper C est.':>13} | "
             + " | ".join(f"{m:>13}" + ("" if m == "nominal" else "  cut ")
                          for m in models)]
    for c in res["cases"]:
        row = (f"  {c['path']:6} {c['init']:6} | {_mm(c.get('paper_at_max_nominal_m'))} "
               f"{_mm(c.get('paper_at_mean_nominal_m'))} | "
               f"{_mm(c.get('paper_at_max_compliant_estimate_m'))} "
               f"{_mm(c.get('paper_at_mean_compliant_estimate_m'))} | ")
        cols = []
        for m in models:
            s = f"{_mm(c.get(f'at_max_{m}_m'))} {_mm(c.get(f'at_mean_{m}_m'))}"
            if m != "nominal":
                s += " " + _pct(c.get(f"at_max_cut_{m}"))
            cols.append(s)
        lines.append(row + " | ".join(cols))
    g = res.get("goals", {})
    if "nominal_order" in g:
        lines.append(f"  nominal, best to worst: {'; '.join(g['nominal_order'])} (paper: "
                     f"{'; '.join(g['paper_order'])})")
    for m in CUT_MODELS:
        if f"min_at_max_cut_{m}" in g:
            ok = g[f"{m}_cuts_at_max_by_80pct_everywhere"]
            lines.append(f"  {m}: AT max cut by {100 * g[f'min_at_max_cut_{m}']:.0f} % at "
                         f"least ({'meets' if ok else 'misses'} the 80 % goal)")
    for lr in res.get("learning", []):
        lines.append(f"  {lr['label']}: warm-up {lr['warmup_s']:.0f} s; {lr['updates']} "
                     f"updates, {lr['samples']} samples, {lr['rejected']} rejected, "
                     f"{lr['handovers']} hand-overs; events {lr['event_counts'] or 'none'}")
        if lr.get("identifiable"):
            from bench.dryrun.learn import identifiability_text
            lines.append(f"    said before moving: {identifiability_text(lr['identifiable'])}")
    pv = res.get("planned_vs_measured")
    if pv:
        mass = pv["platform_mass_kg"]
        lines.append(f"measured vs planned tensions in the mast update ({pv['scenario']}: "
                     f"platform {mass['truth']:g} kg, the model's {mass['model']:g} kg), AT "
                     f"max / mean [mm]")
        for c in pv["cases"]:
            lines.append(f"  {c['path']:6} {c['init']:6} | measured "
                         f"{_mm(c['at_max_measured_m'])} {_mm(c['at_mean_measured_m'])} | "
                         f"planned {_mm(c['at_max_planned_m'])} {_mm(c['at_mean_planned_m'])}")
        lines.append("  the load cells' tensions do better in every case" if
                     pv["measured_better_everywhere"] else
                     "  the load cells' tensions do NOT do better in every case")
    dg = res.get("diagnosis")
    if dg and "effects" in dg:
        vt = dg["vs_truth"]
        cal = dg["calibration"]
        lines.append(f"diagnosis of the calibration recording ({cal['path']}, "
                     f"{cal['simulated_s']:.0f} s simulated in {cal['wall_s']:.0f} s; "
                     f"diagnosed in {dg['diagnose_s']:.0f} s): "
                     f"{', '.join(e['name'] for e in dg['effects']) or 'no effect'}; exit "
                     f"points {1e3 * vt['exit_rms_m']:.1f} mm RMS from the truth (max "
                     f"{1e3 * vt['exit_max_m']:.1f} mm); corrected model {dg['model_file']}")
        rel = [abs(v) for row in vt["stiffness_rel_error"] for v in row if v is not None]
        nund = sum(v is None for row in vt["stiffness_rel_error"] for v in row)
        if rel:
            lines.append(f"  mast stiffness within {100 * max(rel):.1f} % of the truth"
                         + (f" ({nund} stiffness undetermined by the calibration: not "
                            f"loaded by it, kept rigid)" if nund else ""))
    for r in res.get("runs", []):
        if r.get("retried"):
            label = r.get("label") or f"{r['set']} {r['model']} {r['speed_pct']:g} %"
            lines.append(f"  {label} ran again after: {r['retried'][0]}")
    for f in res.get("failures", []):
        lines.append(f"  FAILED {f['label']}: {f['error']}")
    return "\n".join(lines)


def _plot_rank(label: str) -> tuple[int, str]:
    order = MODEL_ORDER + ("measured tensions", "planned tensions")
    return (order.index(label) if label in order else len(order), label)


#: the Fig. 7-like path plots magnify the executed path's deviation from the desired one
PATH_EXAGGERATION = 10.0


def paths_plots(results: Sequence[dict], opt: PathsOptions, out_dir: str | Path) -> list[Path]:
    """Fig. 7-like PNGs: ``paths.png`` (per case, desired vs executed path in the YZ plane,
    the deviation magnified :data:`PATH_EXAGGERATION` times, and AT, AT_x, AT_y, AT_z along
    the path, one line per model) and ``planned_vs_measured.png``."""
    from bench.iso9283.plots import plot_path_cases

    out = Path(out_dir)
    written = []
    k = PATH_EXAGGERATION

    def case_plot(filter_tags: Callable[[dict], str | None], name: str, title: str) -> None:
        cases = []
        for case in opt.cases:
            runs: dict[str, Any] = {}
            desired = None
            for r in results:
                t = r.get("tags", {})
                if t.get("path") != case[0] or t.get("init") != case[1] or "along" not in r:
                    continue
                lab = filter_tags(t)
                if lab is None:
                    continue
                a = r["along"]
                desired = np.asarray(a["desired_m"], float)
                # the executed path shown with its deviation magnified k times: centimetres
                # on a 10 m path are invisible at scale
                shown = desired + k * (np.asarray(a["executed_m"], float) - desired)
                runs[lab] = {"s_m": a["s_m"], "at_xyz_m": a["at_xyz_m"], "executed_m": shown}
            # the same colour for a model in every case and every campaign (the order of
            # MODEL_ORDER, measured before planned), whatever order the runs ended in
            runs = dict(sorted(runs.items(), key=lambda kv: _plot_rank(kv[0])))
            if runs:
                cases.append({"title": f"{case[0]} path, {case[1]} initialisation "
                                       f"(deviation x{k:g})",
                              "desired_m": desired, "runs": runs})
        if cases:
            written.append(plot_path_cases(cases, out / name, title=title))

    case_plot(lambda t: t["model"] if "scenario" not in t else None, "paths.png",
              "paper-paths: desired vs executed path and AT along it (Fig. 7), per model")
    if opt.planned:
        case_plot(lambda t: f"{t['mast_tensions']} tensions" if "scenario" in t else None,
                  "planned_vs_measured.png",
                  f"{opt.heavy_scenario}: mast update from the measured vs the planned "
                  f"tensions")
    return written


# --------------------------------------------------------------------------- poses results

_POSE_KEYS = ("apx_m", "apy_m", "apz_m", "ap_m", "rp_m", "ap_a_rad", "ap_b_rad", "ap_c_rad",
              "rp_a_rad", "rp_b_rad", "rp_c_rad")


def poses_result(results: Sequence[dict], failures: Sequence[dict], opt: PosesOptions,
                 wall_s: float) -> dict[str, Any]:
    """The ``paper-poses --json`` object."""
    runs = []
    for set_name in opt.sets:
        for v in sorted(opt.speeds):
            for m in opt.models:
                r = _by(results, set=set_name, speed_pct=v, model=m)
                e: dict[str, Any] = {"set": set_name, "speed_pct": v, "model": m}
                if r is not None:
                    e.update({k: r["worst"][k] for k in _POSE_KEYS})
                    e["poses"] = [{k: p[k] for k in ("command", "n", "ap_m", "rp_m")}
                                  for p in r["poses"]]
                    e.update(simulated_s=r["simulated_s"], wall_s=r["wall_s"],
                             recording=r["recording"], retried=r.get("retried", []))
                else:
                    e.update({k: None for k in _POSE_KEYS})
                runs.append(e)
    out = {"scenario": "paper-poses", "cycles": opt.cycles, "speeds_pct": list(opt.speeds),
           "models": {m: MODELS[m] for m in opt.models}, "rate_hz": opt.rate_hz,
           "reactions": dict(opt.reactions), "runs": runs, "wall_s": wall_s,
           "failures": list(failures)}
    # the paper's finding: accuracy worse away from the centre (violet < pink < gold)
    trend = {}
    for m in opt.models:
        for v in opt.speeds:
            ap = [next((r["ap_m"] for r in runs if r["set"] == s and r["speed_pct"] == v
                        and r["model"] == m), None) for s in ("violet", "pink", "gold")]
            if all(a is not None for a in ap):
                trend[f"{m}_{v:g}pct"] = bool(ap[0] <= ap[1] <= ap[2])
    out["ap_grows_away_from_centre"] = trend
    return _clean(out)


def poses_table(res: dict[str, Any]) -> str:
    lines = [f"ISO 9283 pose accuracy AP and repeatability RP per set, velocity and model (worst "
             f"pose of each set; {res['cycles']} cycles) [mm, deg]",
             f"  {'set':7} {'v%':>4} {'model':11} {'APx':>7} {'APy':>7} {'APz':>7} {'AP':>7} "
             f"{'RP':>7} {'AP_a':>6} {'AP_b':>6} {'AP_c':>6} {'RP_a':>6} {'RP_b':>6} "
             f"{'RP_c':>6}"]
    for r in res["runs"]:
        degs = [f"{'-':>6}" if r.get(k) is None else f"{math.degrees(r[k]):6.3f}"
                for k in _POSE_KEYS[5:]]
        lines.append(f"  {r['set']:7} {r['speed_pct']:4g} {r['model']:11} "
                     + " ".join(_mm(r.get(k), 7) for k in _POSE_KEYS[:5]) + " "
                     + " ".join(degs))
    tr = res.get("ap_grows_away_from_centre", {})
    if tr:
        lines.append("  AP grows from violet to pink to gold: " + ", ".join(
            f"{k} {'yes' if v else 'no'}" for k, v in tr.items()))
    for r in res.get("runs", []):
        if r.get("retried"):
            label = r.get("label") or f"{r['set']} {r['model']} {r['speed_pct']:g} %"
            lines.append(f"  {label} ran again after: {r['retried'][0]}")
    for f in res.get("failures", []):
        lines.append(f"  FAILED {f['label']}: {f['error']}")
    return "\n".join(lines)


def poses_plots(res: dict[str, Any], out_dir: str | Path) -> list[Path]:
    """Fig. 6-like bars (``poses.png``): AP/RP per set, model and velocity."""
    from bench.iso9283.plots import plot_pose_bars

    colours = {"violet": "tab:purple", "pink": "tab:pink", "gold": "goldenrod"}
    bars = []
    for r in res["runs"]:
        if r.get("ap_m") is None:
            continue
        bars.append(dict({k: r[k] for k in _POSE_KEYS},
                         label=f"{r['set'][0].upper()} {r['model'][0].upper()} "
                               f"{r['speed_pct']:g}", color=colours.get(r["set"])))
    if not bars:
        return []
    return [plot_pose_bars(bars, Path(out_dir) / "poses.png",
                           title="paper-poses: AP and RP per set (V/P/G), model "
                                 "(N nominal, R remeasured, C compliant, D diagnosed) and "
                                 "velocity [% of 0.5 m/s] (Fig. 6)")]
