"""Goals (a) and (b) of designed campaigns, measured on generated cases.

**Goal (b): does one designed campaign settle what a diagnosis left open?** Each case (from
its seed, on a shipped robot: ROCASPECT by default, any other from its frame,
:func:`case_geometry`): a concealed effect that a small campaign confuses with another
(:data:`AMBIGUOUS`: pulley radii, which exit-point offsets imitate on poses that swing the
cables little; the cables' E*A and a gain shared by the load cells, which the load cells'
gauge lets a mass or a common E*A imitate), a first campaign of a few poses close together
around the initialisation pose at one height, and its diagnosis. A case counts when that
report names an alternative. Then ``cdpr campaign design`` chooses ``poses`` poses, the
simulator records them on the same truth, and the diagnosis runs again: **settled** when
the new report names the concealed effect with no alternative left; a case whose design or
designed campaign fails (the simulated plant cannot find a rest position) counts as not
settled, its ``stage`` and ``error`` said. ``evaluate(seeds, robot=...)`` runs the cases one
after another in this process; ``summary`` counts them::

    python -c "from bench.design_eval import evaluate, summary; \\
               print(summary(evaluate(range(9400, 9420), robot='rocaspect')))"

**Goal (a): how few designed poses give the paper campaign's standard errors?**
:func:`match_case` per draw (a noise draw of the paper-calibration scenario and a draw of
the candidates), :func:`match_summary` the ratios per parameter group, predicted at one
noise level and diagnosed::

    python -c "from bench.design_eval import match_evaluate, match_summary; \\
               print(match_summary(match_evaluate(range(100, 108))))"
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

#: concealed effects that a small campaign confuses with another: pulley radii (exit-point
#: offsets imitate them), the cables' E*A and a gain shared by every load cell (the load
#: cells' gauge: a platform mass, a common E*A imitate them)
AMBIGUOUS = ("pulley_kinematics", "cable_elasticity", "load_cell_calibration")


#: where a case's first campaign lies, per robot: the centre of its poses in x, y [m], the
#: largest shift of that centre drawn in x and y [m], the heights drawn [m], and the half
#: side of the box its poses are drawn in [m] (pulley radii; the other effects); robots not
#: named here: :func:`case_geometry` from the frame
GEOMETRY = {"rocaspect": ((10.0, 8.56), 2.0, (0.9, 1.6), (1.5, 3.0))}


def case_geometry(robot: str) -> tuple[tuple[float, float], float, tuple[float, float],
                                       tuple[float, float]]:
    """A robot's :data:`GEOMETRY` entry; for another robot from its frame
    (:func:`controller.paths.frame_box`): the frame's centre, a shift of 10 % of its shorter
    side, heights 20-40 % of the frame's height, half sides 8 % and 16 % of the shorter side
    (ROCASPECT's figures in proportion)."""
    from controller.paths import frame_box
    from controller.robot import resolve_robot

    if robot in GEOMETRY:
        return GEOMETRY[robot]
    lo, hi = frame_box(resolve_robot(robot))
    side = float(min(hi[:2] - lo[:2]))
    centre = 0.5 * (lo[:2] + hi[:2])
    h = float(hi[2] - lo[2])
    return ((float(centre[0]), float(centre[1])), 0.1 * side,
            (float(lo[2]) + 0.2 * h, float(lo[2]) + 0.4 * h), (0.08 * side, 0.16 * side))


def make_case(seed: int, robot: str = "rocaspect") -> dict[str, Any]:
    """A scenario mapping (cdpr-scenario/1) of one ambiguous case on the shipped ``robot``."""
    from bench.evaluate import feasible_poses
    from controller.robot import resolve_robot

    rng = np.random.default_rng([seed, 34])
    model = resolve_robot(robot)
    (cx, cy), shift, (z_lo, z_hi), (half_pulley, half_other) = case_geometry(robot)
    effect = str(rng.choice(AMBIGUOUS))
    cids = list(model.cable_ids)
    if effect == "pulley_kinematics":
        truth = {f"r_{c}": float(rng.uniform(0.03, 0.1)) for c in cids}
    elif effect == "load_cell_calibration":
        common = float(rng.choice([-1, 1]) * rng.uniform(0.01, 0.04) + 1)
        truth = {f"gain_{c}": common * float(rng.uniform(0.995, 1.005)) for c in cids}
    else:
        ea = float(np.mean(model.ea)) * float(rng.choice([-1, 1]) * rng.uniform(0.2, 0.5) + 1)
        truth = {"ea": ea}
    centre = np.array([cx, cy]) + rng.uniform(-shift, shift, 2)
    z = float(rng.uniform(z_lo, z_hi))
    # E*A shows where tensions differ: a wider box
    half = half_pulley if effect == "pulley_kinematics" else half_other
    box = (np.array([*(centre - half), z]), np.array([*(centre + half), z]))
    pts = feasible_poses(model, rng, int(rng.integers(4, 7)), 0.0, box=box)
    init = [float(centre[0]), float(centre[1]), z, 0.0, 0.0, 0.0]
    scale = float(rng.choice([0.5, 1.0, 2.0]))
    tracker = effect == "pulley_kinematics" or bool(rng.random() < 0.5)
    return {"format": "cdpr-scenario/1", "robot": robot, "seed": int(seed),
            "init_pose": init, "truth": {effect: truth},
            "noise": {"tracker_m": 3e-5 * scale, "tracker_rad": 2e-5 * scale,
                      "load_cell_n": 0.5 * scale, "encoder_m": 1e-6,
                      "process_m": 2e-4 * scale, "exit_m": 5e-5 * scale},
            "poses": {"kind": "list", "list": [[float(v) for v in p] for p in pts],
                      "visits": 2, "dwell_s": 3.0, "rate_hz": 2.0, "init_s": 4.0},
            "recording": {"tracker": tracker}}


def _alternatives(report: dict[str, Any]) -> list[str]:
    return [f"{a['name']} for {e['name']}" for e in report["effects"]
            for a in e.get("alternatives", [])]


def run_case(seed: int, poses: int = 10, visits: int = 2, robot: str = "rocaspect"
             ) -> dict[str, Any]:
    """One case on ``robot``: first campaign, diagnosis, design, designed campaign, diagnosis
    again."""
    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose
    from bench.evaluate import one_blas_thread
    from firmware_sim.scenario import parse_scenario

    one_blas_thread()
    case = make_case(seed, robot)
    sc = parse_scenario(case)
    concealed = next(iter(case["truth"]))
    out: dict[str, Any] = {"seed": seed, "robot": robot, "concealed": concealed,
                           "tracker": case["recording"]["tracker"]}
    with tempfile.TemporaryDirectory() as d:
        rec = Path(d) / "rec"
        run_campaign(sc, rec)
        first = diagnose(rec).report
        out["first"] = [e["name"] for e in first["effects"]]
        out["alternatives"] = _alternatives(first)
        if not out["alternatives"]:
            return out
        try:
            second = _designed(first, sc, Path(d), poses, visits, seed, out)
        except (ValueError, RuntimeError) as e:  # the design or its campaign failed:
            out.update(error=str(e), settled=False)  # a case with an alternative, unsettled
            return out
    out["second"] = [e["name"] for e in second["effects"]]
    out["left"] = _alternatives(second)
    out["settled"] = out["second"] == [concealed] and not out["left"]
    return out


def _designed(first: dict[str, Any], sc: Any, d: Path, poses: int, visits: int, seed: int,
              out: dict[str, Any]) -> dict[str, Any]:
    """Design from the ``first`` report, record the designed campaign on the scenario ``sc``'s
    truth in ``d``, and return its diagnosis (``out`` gets the predicted differences)."""
    import dataclasses

    from bench import campaign_design as cd
    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose

    out["stage"] = "design"
    rpath = d / "report.json"
    rpath.write_text(json.dumps(first, default=float))
    ctx = cd.context(first, rpath)
    res = cd.run_design(first, ctx, poses, visits=visits, seed=seed)
    out["predicted"] = {k: round(v, 1) for k, v in res.design.delta.items()}
    path = d / "designed.toml"
    text, problem = cd.checked_document(res, visits, str(rpath), ctx, seed=seed)
    path.write_text(text)
    out["path_check"] = problem or "ok"
    poses_, v = cd.path_poses(path)
    sc2 = dataclasses.replace(sc, poses=dataclasses.replace(sc.poses, visits=v))
    out["stage"] = "designed campaign"
    run_campaign(sc2, d / "rec2", poses=poses_)
    out["stage"] = "second diagnosis"
    second = diagnose(d / "rec2").report
    del out["stage"]
    return second


def evaluate(seeds, poses: int = 10, visits: int = 2, robot: str = "rocaspect"
             ) -> list[dict[str, Any]]:
    """:func:`run_case` for every seed on ``robot`` (a case that cannot be made is recorded
    with its error)."""
    results = []
    for s in seeds:
        try:
            results.append(run_case(int(s), poses, visits, robot))
        except (ValueError, RuntimeError) as e:
            results.append({"seed": int(s), "robot": robot, "error": str(e)})
    return results


def summary(results: list[dict[str, Any]]) -> dict[str, Any]:
    """How many cases had an alternative, and how many of those one designed campaign
    settled (a case whose design or designed campaign failed counts as unsettled)."""
    amb = [r for r in results if r.get("alternatives")]
    settled = [r for r in amb if r.get("settled")]
    return {"cases": len(results), "errors": sum("error" in r for r in results),
            "failed_after_first": sum("error" in r for r in amb),
            "with_alternative": len(amb), "settled": len(settled),
            "rate": len(settled) / len(amb) if amb else None, "results": results}


# ----- goal (a): fewer designed poses for the paper campaign's standard errors -------------

#: the scenario of goal (a): ROCASPECT as the paper found it, its 40-pose calibration path
PAPER_SCENARIO = "bench/data/scenarios/paper-calibration.toml"
#: the parameter groups whose standard errors goal (a) compares (report key prefixes)
MATCH_GROUPS = {"exit offsets x, y": ("dx_", "dy_"), "exit offsets z": ("dz_",),
                "mast stiffnesses": ("kx_", "ky_", "kz_")}
#: candidate poses a goal-(a) design chooses from
MATCH_CANDIDATES = 800


def _report_stderr(report: dict[str, Any]) -> dict[str, float]:
    """The standard errors a diagnosis report gives, by parameter key (parameter units)."""
    return {k: float(v) for e in report["effects"] for k, v in e.get("stderr", {}).items()}


def match_case(draw: int, poses: int = 15, visits: int = 3,
               candidates: int = MATCH_CANDIDATES,
               scenario: str | Path = PAPER_SCENARIO) -> dict[str, Any]:
    """One draw of goal (a): the scenario's campaign (its path, the paper's 40 poses x 3
    visits) recorded with the noise of seed ``scenario seed + draw`` and diagnosed; from that
    report ``poses`` designed poses (``visits`` each) chosen from ``candidates`` drawn with
    seed ``draw`` to come closest to its standard errors
    (:func:`bench.campaign_design.match_reference`); recorded on the same simulated robot and
    diagnosed. Per parameter (exit offsets, mast stiffnesses the reference determines): the
    ratio of standard errors designed / reference, **predicted** (both from the Fisher
    information at one noise level: the reference report's) and **diagnosed** (each report's
    own); ``poses_needed`` the fewest designed poses the prediction says reach every ratio
    <= 1; ``missing`` parameters the designed campaign's report gives no standard error
    for."""
    import dataclasses

    from bench import campaign_design as cd
    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose
    from bench.evaluate import one_blas_thread
    from firmware_sim.scenario import load_scenario

    one_blas_thread()
    sc = load_scenario(scenario)
    sc = dataclasses.replace(sc, seed=sc.seed + int(draw))
    ref_poses, ref_visits = cd.path_poses(sc.run_path)
    with tempfile.TemporaryDirectory() as d:
        run_campaign(sc, Path(d) / "ref")
        ref = diagnose(Path(d) / "ref").report
        rpath = Path(d) / "ref.json"
        rpath.write_text(json.dumps(ref, default=float))
        ctx = cd.context(ref, rpath)
        m = cd.match_reference(ref, ctx, ref_poses, ref_visits, visits, seed=int(draw),
                               candidates=candidates, n=poses)
        at = m["at_poses"]
        sc2 = dataclasses.replace(sc, poses=dataclasses.replace(sc.poses, visits=visits))
        run_campaign(sc2, Path(d) / "designed", poses=np.array(at["poses"], float))
        des = diagnose(Path(d) / "designed").report
    se_ref, se_des = _report_stderr(ref), _report_stderr(des)
    keys = list(m["stderr_reference"])
    return {"draw": int(draw), "poses": poses, "visits": visits, "candidates": candidates,
            "poses_needed": m["poses_needed"],
            "predicted": {k: at["stderr"][k] / m["stderr_reference"][k] for k in keys},
            "diagnosed": {k: se_des[k] / se_ref[k] for k in keys if k in se_des and k in se_ref},
            "missing": [k for k in keys if k not in se_des]}


def match_summary(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Per parameter group (:data:`MATCH_GROUPS`), for the predicted and the diagnosed
    ratios: each parameter's median over the draws, then the group's ``median`` and
    ``worst`` (largest) of those, and ``worst_draw`` the largest single ratio of any draw;
    ``poses_needed`` per draw (predicted) and ``smallest_n`` their upper median: the fewest
    designed poses that reach a ratio <= 1 on every parameter on at least half of the draws
    (None: not within 40 poses)."""
    out: dict[str, Any] = {"draws": [r["draw"] for r in results]}
    for kind in ("predicted", "diagnosed"):
        groups = {}
        for name, prefixes in MATCH_GROUPS.items():
            keys = sorted({k for r in results for k in r[kind] if k.startswith(prefixes)})
            if not keys:
                continue
            med = [float(np.median([r[kind][k] for r in results if k in r[kind]]))
                   for k in keys]
            groups[name] = {"parameters": len(keys), "median": round(float(np.median(med)), 3),
                            "worst": round(float(np.max(med)), 3),
                            "worst_draw": round(max(r[kind][k] for r in results
                                                    for k in keys if k in r[kind]), 3)}
        out[kind] = groups
    need = [r["poses_needed"] for r in results]
    out["poses_needed"] = need
    upper = sorted(n if n > 0 else np.inf for n in need)[len(need) // 2]  # upper median
    out["smallest_n"] = int(upper) if np.isfinite(upper) else None
    out["missing"] = {r["draw"]: r["missing"] for r in results if r["missing"]}
    return out


def match_evaluate(draws, poses: int = 15, visits: int = 3,
                   candidates: int = MATCH_CANDIDATES) -> list[dict[str, Any]]:
    """:func:`match_case` for every draw, one after another in this process."""
    return [match_case(int(d), poses, visits, candidates) for d in draws]
