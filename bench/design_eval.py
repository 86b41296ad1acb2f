"""Does one designed campaign settle what a diagnosis left open? Generated cases, measured.

Each case (from its seed): ROCASPECT with a concealed effect that a small campaign confuses
with another (:data:`AMBIGUOUS`: pulley radii, which exit-point offsets imitate on poses
that swing the cables little; the cables' E*A and a gain shared by the load cells, which
the load cells' gauge lets a mass or a common E*A imitate), a first
campaign of a few poses close together around the initialisation pose at one height, and its
diagnosis. A case counts when that report names an alternative. Then ``cdpr campaign
design`` chooses ``poses`` poses, the simulator records them on the same truth, and the
diagnosis runs again: **settled** when the new report names the concealed effect with no
alternative left; a case whose design or designed campaign fails (the simulated plant
cannot find a rest position) counts as not settled, its ``stage`` and ``error`` said.

``evaluate(seeds)`` runs the cases one after another in this process; the figure in the
docs comes from::

    python -c "from bench.design_eval import evaluate, summary; \\
               print(summary(evaluate(range(9300, 9350))))"
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


def make_case(seed: int) -> dict[str, Any]:
    """A scenario mapping (cdpr-scenario/1) of one ambiguous case."""
    from bench.evaluate import feasible_poses
    from controller.robot import resolve_robot

    rng = np.random.default_rng([seed, 34])
    model = resolve_robot("rocaspect")
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
    centre = np.array([10.0, 8.56]) + rng.uniform(-2.0, 2.0, 2)
    z = float(rng.uniform(0.9, 1.6))
    half = 1.5 if effect == "pulley_kinematics" else 3.0  # E*A shows where tensions differ
    box = (np.array([*(centre - half), z]), np.array([*(centre + half), z]))
    pts = feasible_poses(model, rng, int(rng.integers(4, 7)), 0.0, box=box)
    init = [float(centre[0]), float(centre[1]), z, 0.0, 0.0, 0.0]
    scale = float(rng.choice([0.5, 1.0, 2.0]))
    tracker = effect == "pulley_kinematics" or bool(rng.random() < 0.5)
    return {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": int(seed),
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


def run_case(seed: int, poses: int = 10, visits: int = 2) -> dict[str, Any]:
    """One case: first campaign, diagnosis, design, designed campaign, diagnosis again."""
    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose
    from bench.evaluate import one_blas_thread
    from firmware_sim.scenario import parse_scenario

    one_blas_thread()
    case = make_case(seed)
    sc = parse_scenario(case)
    concealed = next(iter(case["truth"]))
    out: dict[str, Any] = {"seed": seed, "concealed": concealed,
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
    path.write_text(cd.path_document(res, visits, str(rpath), seed=seed))
    out["path_check"] = cd.check_path(path.read_text(), ctx) or "ok"
    poses_, v = cd.path_poses(path)
    sc2 = dataclasses.replace(sc, poses=dataclasses.replace(sc.poses, visits=v))
    out["stage"] = "designed campaign"
    run_campaign(sc2, d / "rec2", poses=poses_)
    out["stage"] = "second diagnosis"
    second = diagnose(d / "rec2").report
    del out["stage"]
    return second


def evaluate(seeds, poses: int = 10, visits: int = 2) -> list[dict[str, Any]]:
    """:func:`run_case` for every seed (a case that cannot be made is recorded with its
    error)."""
    results = []
    for s in seeds:
        try:
            results.append(run_case(int(s), poses, visits))
        except (ValueError, RuntimeError) as e:
            results.append({"seed": int(s), "error": str(e)})
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
