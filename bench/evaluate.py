"""Blind evaluation of the diagnosis on generated cases with concealed effects.

Each case draws a scenario (a random mix of vocabulary effects with random
magnitudes, a pose set and an initialisation pose), records a campaign on the
plant, diagnoses it without telling it the effects, and scores the report
against the truth: which effects were named, how close the key parameters
came (stiffness within 25 %, exit offsets within 5 mm, gains within 1 %, EA
within 10 %, ...), and whether held-out poses came down to the noise.
"""

from __future__ import annotations

import copy
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller.effects import EFFECT_NAMES
from controller.robot import resolve_robot

#: effects a case may conceal
DRAWN = ("exit_point_offset", "mast_compliance", "cable_elasticity", "cable_length_offset",
         "drum_scale", "load_cell_calibration", "platform_mass", "pulley_kinematics",
         "cable_sag")


def draw_effect(effect: str, rng: np.random.Generator, model) -> dict[str, float]:
    """Random parameters of one concealed effect, large enough to matter, physically sound."""
    cids, mids = model.cable_ids, model.mast_ids
    out: dict[str, float] = {}
    if effect == "exit_point_offset":
        for cid in rng.choice(cids, size=rng.integers(1, 5), replace=False):
            for ax in "xyz":
                if rng.random() < 0.7:
                    out[f"d{ax}_{cid}"] = float(rng.choice([-1, 1]) * rng.uniform(0.01, 0.05))
        if not out:
            out[f"dx_{cids[0]}"] = 0.02
    elif effect == "mast_compliance":
        for mid in mids:
            out[f"kx_{mid}"] = float(rng.uniform(1.0e5, 6.0e5))
            out[f"ky_{mid}"] = float(rng.uniform(2.0e5, 9.0e5))
            out[f"kz_{mid}"] = float(rng.uniform(1.0e5, 9.0e5))
    elif effect == "cable_elasticity":
        ea0 = float(np.mean(model.ea[np.isfinite(model.ea)])) if model.elastic else 6.0e5
        out["ea"] = ea0 * float(rng.choice([rng.uniform(0.55, 0.85), rng.uniform(1.2, 1.6)]))
    elif effect == "cable_length_offset":
        for cid in rng.choice(cids, size=rng.integers(1, 3), replace=False):
            out[f"dl_{cid}"] = float(rng.choice([-1, 1]) * rng.uniform(0.002, 0.008))
    elif effect == "drum_scale":
        for cid in rng.choice(cids, size=rng.integers(1, 4), replace=False):
            out[f"s_{cid}"] = 1.0 + float(rng.choice([-1, 1]) * rng.uniform(1e-3, 4e-3))
    elif effect == "load_cell_calibration":
        for cid in rng.choice(cids, size=rng.integers(1, 4), replace=False):
            if rng.random() < 0.7:
                out[f"gain_{cid}"] = 1.0 + float(rng.choice([-1, 1]) * rng.uniform(0.02, 0.06))
            else:
                out[f"offset_{cid}"] = float(rng.choice([-1, 1]) * rng.uniform(3.0, 10.0))
    elif effect == "platform_mass":
        out["mass"] = model.mass + float(rng.choice([-1, 1]) * rng.uniform(2.0, 5.0))
        if rng.random() < 0.5:
            out["com_x"] = float(rng.choice([-1, 1]) * rng.uniform(0.01, 0.04))
    elif effect == "pulley_kinematics":
        r = float(rng.uniform(0.05, 0.12))
        out = {f"r_{c}": r for c in cids}
    elif effect == "cable_sag":
        out["rho"] = float(rng.uniform(0.03, 0.10))
    else:
        raise KeyError(effect)
    return out


#: the pose set of a case unless ``make_case(poses=...)`` overrides some of its keys
CASE_POSES: dict[str, Any] = {"kind": "grid", "n": [5, 4, 2], "rpy_deg": 2.0, "visits": 3}


def make_case(seed: int, robot: str = "rocaspect", n_effects: int | None = None,
              effects: tuple[str, ...] | None = None,
              poses: dict[str, Any] | None = None) -> dict[str, Any]:
    """A scenario mapping (cdpr-scenario/1) with randomly drawn concealed effects.

    ``poses`` overrides keys of the ``[poses]`` table (:data:`CASE_POSES`), e.g.
    ``{"n": [3, 2, 1], "visits": 2}`` for a quick case; the random draws do not change.
    """
    rng = np.random.default_rng(seed)
    model = resolve_robot(robot)
    if effects is None:
        k = int(rng.choice([0, 1, 1, 1, 2, 2])) if n_effects is None else n_effects
        effects = tuple(rng.choice(DRAWN, size=k, replace=False)) if k else ()
    truth = {e: draw_effect(e, rng, model) for e in effects}
    init_choices = [[10.0, 8.56, 1.0], [2.5, 8.5, 1.0], [15.0, 4.0, 1.2], [6.0, 12.0, 1.0]]
    init = init_choices[int(rng.integers(len(init_choices)))]
    return {
        "format": "cdpr-scenario/1", "robot": robot, "seed": int(seed),
        "init_pose": [*init, 0.0, 0.0, 0.0],
        "truth": truth,
        "nuisance": {"hysteresis_m": float(rng.uniform(0, 1.5e-4)),
                     "drift_m_per_h": float(rng.uniform(0, 8e-5))},
        "poses": copy.deepcopy({**CASE_POSES, **(poses or {})}),
    }


# ----- scoring ---------------------------------------------------------------------------

def _param_ok(effect: str, key: str, truth: float, got: float) -> tuple[bool, str]:
    """Whether a recovered parameter meets its tolerance (and the tolerance in words)."""
    if effect == "mast_compliance":
        return abs(got - truth) <= 0.25 * truth, "25 %"
    if effect == "exit_point_offset":
        return abs(got - truth) <= 5e-3, "5 mm"
    if effect == "cable_elasticity":
        return abs(got - truth) <= 0.10 * truth, "10 %"
    if key.startswith("gain_"):
        return abs(got - truth) <= 0.01 * truth, "1 %"
    if key.startswith("offset_"):
        return abs(got - truth) <= 1.0, "1 N"
    if effect == "cable_length_offset":
        return abs(got - truth) <= 5e-4, "0.5 mm"
    if effect == "drum_scale":
        return abs(got - truth) <= 5e-4, "5e-4"
    if key == "mass":
        return abs(got - truth) <= 0.02 * truth, "2 %"
    if key.startswith("com_"):
        return abs(got - truth) <= 5e-3, "5 mm"
    if effect == "pulley_kinematics":
        return abs(got - truth) <= 0.01, "10 mm"
    if effect == "cable_sag":
        return abs(got - truth) <= 0.10 * truth, "10 %"
    return abs(got - truth) <= 1e-3 * max(1.0, abs(truth)), "0.1 %"


@dataclass
class CaseScore:
    """The outcome of one case."""

    seed: int
    truth: list[str]
    named: list[str]
    exact: bool
    params_ok: int
    params_total: int
    failures: list[str]
    z: list[float]
    heldout_ratio: float | None
    seconds: float

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def score(report: dict, truth: dict[str, dict[str, float]], model, seed: int = 0,
          seconds: float = 0.0) -> CaseScore:
    """Score a diagnosis report against the concealed truth."""
    named = [e["name"] for e in report["effects"]]
    truth_names = sorted(truth)
    failures, z = [], []
    ok = total = 0
    by_name = {e["name"]: e for e in report["effects"]}
    neutral = _neutral(model)
    for eff, params in truth.items():
        if eff not in by_name:
            continue
        e = by_name[eff]
        keys = set(params)
        if eff == "exit_point_offset":  # every offset counts, absent ones are zero
            keys |= {f"d{ax}_{c}" for c in model.cable_ids for ax in "xyz"}
        for key in sorted(keys):
            if key in e.get("undetermined", []):
                continue
            t = params.get(key, neutral.get(key, 0.0))
            g = e["params"].get(key, neutral.get(key, t if eff == "mast_compliance" else 0.0))
            if eff == "cable_elasticity" and key == "ea" and "ea" not in e["params"]:
                continue
            if eff == "mast_compliance" and key not in e["params"]:
                continue  # undetermined axis or equal to the model
            total += 1
            good, tol = _param_ok(eff, key, t, g)
            ok += good
            if not good:
                failures.append(f"{key}: {g:.6g} vs truth {t:.6g} (tolerance {tol})")
            se = e["stderr"].get(key)
            if se and math.isfinite(se) and se > 0:
                z.append((g - t) / se)
    ho = report["fitted"].get("heldout_pose_rms_m")
    noise = report["mismatch"].get("noise", {}).get("pose_m")
    ratio = ho / noise if ho is not None and noise else None
    return CaseScore(seed, truth_names, sorted(named), sorted(named) == truth_names, ok, total,
                     failures, z, ratio, seconds)


def _neutral(model) -> dict[str, float]:
    out = {}
    for k, c in enumerate(model.cable_ids):
        out[f"s_{c}"] = 1.0
        out[f"gain_{c}"] = 1.0
        out[f"offset_{c}"] = 0.0
        out[f"r_{c}"] = float(model.pulley_radius[k])
    out["mass"] = model.mass
    for a, ax in enumerate("xyz"):
        out[f"com_{ax}"] = float(model.com[a])
    return out


def run_case(seed: int, workdir: str | None = None, **kw) -> dict:
    """Generate, record and diagnose one case (a plain function for process pools and Dask)."""
    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose
    from firmware_sim.scenario import parse_scenario

    t0 = time.perf_counter()
    case = make_case(seed, **kw)
    sc = parse_scenario(case)
    with tempfile.TemporaryDirectory(dir=workdir) as d:
        rec = Path(d) / "rec"
        run_campaign(sc, rec)
        dg = diagnose(rec)
    s = score(dg.report, {e: dict(p) for e, p in case["truth"].items()}, sc.model, seed,
              time.perf_counter() - t0)
    return s.as_dict()


# ----- aggregate -------------------------------------------------------------------------

def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion k/n (95 % by default)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def summarise(scores: list[dict]) -> dict:
    """Detection matrix, false-positive rate with its 95 % interval, parameter z-scores."""
    names = list(EFFECT_NAMES)
    matrix = {t: {r: 0 for r in names} | {"cases": 0} for t in names + ["none"]}
    fp_cases = fp = 0
    for s in scores:
        truth = s["truth"] or ["none"]
        for t in truth:
            matrix[t]["cases"] += 1
            for r in s["named"]:
                matrix[t][r] += 1
        for r in names:  # false positive: an effect named that was not concealed
            if r not in s["truth"]:
                fp_cases += 1
                fp += r in s["named"]
    z = np.array([v for s in scores for v in s["z"]])
    exact = sum(s["exact"] for s in scores)
    pok = sum(s["params_ok"] for s in scores)
    ptot = sum(s["params_total"] for s in scores)
    lo, hi = wilson(fp, fp_cases)
    ratios = [s["heldout_ratio"] for s in scores if s["heldout_ratio"] is not None]
    return {
        "cases": len(scores),
        "exact_detection": exact / max(len(scores), 1),
        "exact_detection_ci95": list(wilson(exact, len(scores))),
        "false_positive_rate": fp / max(fp_cases, 1),
        "false_positive_ci95": [lo, hi],
        "params_within_tolerance": pok / max(ptot, 1),
        "params_total": ptot,
        "z_scores": {"n": int(z.size), "mean": float(z.mean()) if z.size else None,
                     "std": float(z.std()) if z.size else None,
                     "within_2": float(np.mean(np.abs(z) < 2)) if z.size else None},
        "heldout_over_noise_median": float(np.median(ratios)) if ratios else None,
        "matrix": {t: row for t, row in matrix.items() if row["cases"]},
        "median_case_s": float(np.median([s["seconds"] for s in scores])) if scores else None,
    }
