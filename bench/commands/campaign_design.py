"""``cdpr campaign design REPORT.json (--site FILE | --scenario S) --poses N``: the wiring.

The options are parsed by :mod:`bench.commands.campaign` (``design`` is its first word);
this module turns them into typed values for :mod:`bench.campaign_design` and prints the
result. Exit status: 0 a design written (or printed), 2 a bad report, file or option.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def _fail(as_json: bool, code: int, msg: str) -> int:
    print(f"cdpr campaign design: {msg}", file=sys.stderr)
    if as_json:
        print(json.dumps({"error": msg}))
    return code


def run(args: argparse.Namespace) -> int:
    """``args.out_dir`` is the report; ``--poses`` N; ``--site`` / ``--scenario``; ``--out``
    the path file; ``--visits`` per pose (default 2); ``--seed`` the candidates' draw;
    ``--candidates``; ``--match PATH`` also the fewest poses that reach that path's
    standard errors; ``--load-cells`` what the design fixes with only those cables
    measured."""
    import numpy as np

    from bench import campaign_design as cd
    from bench.outputs import write_text_file

    report_path = args.out_dir
    if args.poses is None:
        return _fail(args.json, 2, "--poses N is required (the number of poses to choose)")
    if (args.site is None) == (args.design_scenario is None):
        return _fail(args.json, 2, "give exactly one of --site FILE or --scenario S")
    visits = args.visits if args.visits is not None else 2
    seed = args.seed if args.seed is not None else 0
    try:
        report = cd.read_report(report_path)
        ctx = cd.context(report, report_path, scenario=args.design_scenario, site=args.site)
        res = cd.run_design(report, ctx, args.poses, visits=visits, seed=seed,
                            candidates=args.candidates)
        out: dict[str, Any] = cd.as_json(res, args.out)
        if args.match is not None:
            ref, ref_visits = cd.path_poses(args.match)
            out["match"] = cd.match_reference(report, ctx, ref, ref_visits, visits, seed,
                                              args.candidates, n=args.poses)
            out["match"]["path"] = args.match
            at = out["match"]["at_poses"]
            if not res.hyp.alternatives:  # nothing to separate: aim at the path's errors
                res.poses = np.array(at["poses"], float)
                out["poses"], out["predicted_stderr"] = at["poses"], at["stderr"]
                out["notes"].append(
                    f"poses chosen to reach the standard errors of {args.match} on exit "
                    f"offsets and mast stiffnesses: largest ratio {at['worst_ratio']:.2f}, "
                    f"median {at['median_ratio']:.2f} (predicted)")
        if args.load_cells is not None:
            mask = cd.measured_mask(ctx.model, args.load_cells)
            out["identifiability"] = cd.identifiability(res.hyp, ctx, res.poses, visits, mask)
            out["notes"].append(cd.identifiability_note(out["identifiability"]))
    except (cd.DesignError, ValueError) as e:
        return _fail(args.json, 2, str(e))
    text, problem = cd.checked_document(res, visits, report_path, ctx, seed=seed)
    out["path_check"] = problem or "ok"
    if problem:  # said, and the file still written: a site may move the init pose
        out["notes"].append(problem)
    if args.out is not None:
        try:
            write_text_file(args.out, text)
        except OSError as e:
            return _fail(args.json, 2, str(e))
    if args.json:
        print(json.dumps(out))
        return 0
    _print(out, args.out, len(res.poses), visits)
    return 0


def _print(out: dict[str, Any], path: str | None, n: int, visits: int) -> None:
    print(f"designed {n} poses x {visits} visits from {out['candidates']} tension-feasible "
          f"candidates" + (f": {path}" if path else ""))
    for note in out["notes"]:
        print("  " + note)
    m = out.get("match")
    if m is not None:
        got = m["poses_needed"]
        print(f"  to reach the standard errors of {m['path']} ({m['reference_poses']} poses x "
              f"{m['reference_visits']} visits) on exit offsets and mast stiffnesses: "
              + (f"{got} designed poses x {m['visits']} visits" if got > 0 else
                 f"not reached with {len(m['poses'])} poses x {m['visits']} visits"))
    if path is None:
        for p in out["poses"]:
            print("  [" + ", ".join(f"{v:.4f}" for v in p) + "]")
