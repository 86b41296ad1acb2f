"""A weak true effect beside the tensions at referencing on a continuous recording without
load cells stays named when the pretension's comparisons count the evidence of the
parameters' own errors (`select.honest_bic` in `report._pretension`).

Evaluation case 12876's scenario (IPAnema, continuous at 10 Hz, a tracker, no load cells,
0.6 mm per visit, the tensions at referencing 75 N off the distribution's), with one exit
point 3 mm off along x (half of test_null42_pretension_visits' true offsets): the design
effect of exit-point offsets there is about 4, and the offset must still be named.
"""

from __future__ import annotations

import json
from pathlib import Path

from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "null_ipanema_continuous_no_tensions_12876.json")


def test_a_weak_true_exit_offset_beside_the_pretension_is_named(record_scenario, tmp_path):
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    scenario["truth"] = {"exit_point_offset": {"dx_31": 0.003}}
    rep = diagnose(record_scenario(scenario, tmp_path / "rec")).report
    named = {e["name"]: e["params"] for e in rep["effects"]}
    assert list(named) == ["exit_point_offset"], rep["mismatch"]["summary"]
    assert named["exit_point_offset"].get("dx_31", 0.0) > 0.0  # (the offset itself among them)
