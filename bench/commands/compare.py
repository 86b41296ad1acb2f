"""``cdpr compare SCENARIO REPORT``: the concealed truth of a scenario beside a diagnosis.

For a demonstration or a check by hand: the scenario (``cdpr-scenario/1``) knows what
the simulated robot really is; the diagnosis report (``cdpr-diagnosis/1``, from
``cdpr diagnose REC --out REPORT`` or ``--json > REPORT``) never saw it. This command
reads both and prints, per effect, what was concealed and what was found (value,
standard error, z-score, within tolerance), the physics outside the vocabulary the
scenario holds, and whether the report declared an unexplained residual.

Exit status: 0 printed, 2 bad scenario or report.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

NAME = "compare"
HELP = "print a scenario's concealed truth beside what a diagnosis report found"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario file (cdpr-scenario/1), or a case.json that "
                                    "cdpr evaluate --keep kept beside a case's recording")
    p.add_argument("report", help="diagnosis report (cdpr-diagnosis/1 JSON)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _fail(args: argparse.Namespace, msg: str) -> int:
    print(f"cdpr compare: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return 2


def compare(sc, report: dict) -> dict:
    """The comparison object of a parsed scenario and a report."""
    from bench.evaluate import _ea_truth, _neutral, _param_ok

    model = sc.model
    neutral = _neutral(model)
    found = {e["name"]: e for e in report.get("effects", [])}
    names = sorted(set(sc.effects) | set(found))
    effects = []
    for name in names:
        truth = {k: v for k, v in sc.effects.get(name, {}).items()}
        f = found.get(name, {})
        keys = sorted(set(truth) | set(f.get("params", {})))
        params = {}
        for k in keys:
            if name == "cable_elasticity":
                t = _ea_truth(truth, k, model) if truth else neutral.get(k)
            else:
                t = truth.get(k, neutral.get(k, 0.0 if name in ("exit_point_offset",
                                                                "cable_length_offset")
                                             else None))
            g = f.get("params", {}).get(k)
            se = f.get("stderr", {}).get(k)
            row: dict = {"truth": t, "found": g, "stderr": se}
            if t is not None and g is not None:
                ok, tol = _param_ok(name, k, t, g)
                row["within_tolerance"] = ok
                row["tolerance"] = tol
                if se and math.isfinite(se) and se > 0:
                    row["z"] = (g - t) / se
            if k in f.get("undetermined", []):
                row["undetermined"] = True
            params[k] = row
        effects.append({"name": name, "concealed": name in sc.effects, "named": name in found,
                        "params": params,
                        "alternatives": [a["name"] for a in f.get("alternatives", [])]})
    oov = {}
    if sc.thermal_strain_per_s:
        oov["thermal_strain_per_h"] = sc.thermal_strain_per_s * 3600.0
    for key, arr in (("backlash_m", sc.backlash_m), ("friction_n", sc.friction_n)):
        vals = {c: float(v) for c, v in zip(model.cable_ids, list(_as_list(arr, model)),
                                            strict=True) if v}
        if vals:
            oov[key] = vals
    missed = [e["name"] for e in effects if e["concealed"] and not e["named"]]
    extra = [e["name"] for e in effects if e["named"] and not e["concealed"]]
    unexplained = report.get("unexplained")
    if not missed and not extra:
        verdict = "every concealed effect named, nothing else"
    else:
        verdict = "; ".join(([f"missed {', '.join(missed)}"] if missed else [])
                            + ([f"named but not concealed: {', '.join(extra)}"] if extra
                               else []))
    if oov:
        verdict += ("; physics outside the vocabulary: " + ", ".join(oov)
                    + (" (declared unexplained)" if unexplained else " (NOT declared)"))
    elif unexplained:
        verdict += "; an unexplained residual was declared"
    return {"scenario": str(sc.path), "report": report.get("recording"),
            "effects": effects, "outside_vocabulary": oov,
            "unexplained": None if not unexplained else unexplained.get("summary"),
            "verdict": verdict}


def _as_list(arr, model) -> list[float]:
    import numpy as np

    a = np.broadcast_to(np.asarray(arr, dtype=float), (model.n_cables,))
    return [float(v) for v in a]


def _fmt(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and (abs(x) >= 1e4 or (abs(x) < 1e-3 and x != 0)):
        return f"{x:.4g}"
    return f"{x:.5g}" if isinstance(x, float) else str(x)


def human(c: dict) -> str:
    from bench.tables import col, render

    lines = [f"scenario {c['scenario']} (concealed truth) beside the diagnosis of "
             f"{c['report']}:"]
    for e in c["effects"]:
        status = ("concealed and named" if e["concealed"] and e["named"] else
                  "concealed, NOT named" if e["concealed"] else "named, NOT concealed")
        lines.append(f"  {e['name']}: {status}"
                     + (f" (alternatives: {', '.join(e['alternatives'])})"
                        if e["alternatives"] else ""))
        rows = []
        for k, p in e["params"].items():
            tol = ("undetermined" if p.get("undetermined") else
                   "-" if "within_tolerance" not in p else
                   f"{'yes' if p['within_tolerance'] else 'NO'} ({p['tolerance']})")
            rows.append([k, _fmt(p["truth"]), _fmt(p["found"]), _fmt(p["stderr"]),
                         f"{p['z']:+.1f}" if "z" in p else "-", tol])
        if rows:  # each parameter in its own unit (the effect's, docs/reference/effects.md)
            lines.append(render([col("parameter", justify="left"), col("truth"),
                                 col("found"), col("± stderr"), col("z"),
                                 col("within tolerance", justify="left")],
                                rows, stream=sys.stdout, indent=4))
    if not c["effects"]:
        lines.append("  no effect concealed, none named")
    for k, v in c["outside_vocabulary"].items():
        lines.append(f"  outside the vocabulary: {k} = {v}")
    if c["unexplained"]:
        lines.append(f"  declared unexplained: {c['unexplained']}")
    lines.append(f"  verdict: {c['verdict']}")
    return "\n".join(lines)


def load_truth(path: str | Path):
    """The scenario of ``path``: a ``cdpr-scenario/1`` TOML file, or a ``.json`` case kept by
    ``cdpr evaluate --keep`` (the scenario mapping with the evaluation's ``case`` and
    ``kept`` sections, which are not the scenario's). Raises ScenarioError naming the file."""
    from firmware_sim.scenario import ScenarioError, load_scenario, parse_scenario

    p = Path(path)
    if p.suffix.lower() != ".json":
        return load_scenario(p)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise ScenarioError(f"{p}: cannot read: {e.strerror or e}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ScenarioError(f"{p}: not a JSON case ({e})") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{p}: not a JSON case (an object expected)")
    try:
        return parse_scenario({k: v for k, v in data.items() if k not in ("case", "kept")}, p)
    except (TypeError, ValueError, KeyError, AttributeError) as e:
        if isinstance(e, ScenarioError):
            raise
        raise ScenarioError(f"{p}: not a valid scenario: {type(e).__name__}: {e}") from None


def run(args: argparse.Namespace) -> int:
    from firmware_sim.scenario import ScenarioError

    try:
        sc = load_truth(args.scenario)
    except ScenarioError as e:
        return _fail(args, str(e))
    p = Path(args.report)
    try:
        report = json.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        return _fail(args, f"{p}: cannot read: {e.strerror or e}")
    except UnicodeDecodeError as e:
        return _fail(args, f"{p}: not UTF-8 text (byte {e.start}: {e.reason})")
    except json.JSONDecodeError as e:
        return _fail(args, f"{p}:{e.lineno}: not JSON ({e.msg})")
    if not isinstance(report, dict) or report.get("format") != "cdpr-diagnosis/1":
        return _fail(args, f"{p}: not a cdpr-diagnosis/1 report")
    try:
        c = compare(sc, report)
    except (KeyError, TypeError, ValueError) as e:
        return _fail(args, f"{p}: malformed report ({type(e).__name__}: {e})")
    print(json.dumps(c) if args.json else human(c))
    return 0
