"""A continuous recording without load cells: the tensions at referencing and the per-visit
change of the lengths (`select.honest_bic`, `report._pretension`).

Evaluation case 12876 (IPAnema, continuous at 10 Hz, a tracker, no load cells, noise x3:
0.6 mm per visit; nothing concealed; the tensions at referencing 75 N off the
distribution's). The first selection took length offsets, then six exit-point offsets
(1.3-4.6 mm, up to 3.7 standard errors): their BIC was 64 below the pretension's alone,
because the BIC counts the rows of a move, which share the visit's error, as independent.
Beside the pretension fitted, the offsets' Wald statistic is 34 on 24 parameters (their
chi-square's drop 4.4 times that): by their own errors they are no finding, and the
pretension takes their place. A true exit-point offset of a few
millimetres beside the same pretension and noise stays named.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "null_ipanema_continuous_no_tensions_12876.json")


def _report(record, tmp_path: Path, truth: dict) -> dict:
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    scenario["truth"] = truth
    return diagnose(record(scenario, tmp_path / "rec")).report


@pytest.mark.cases  # one whole case recorded and diagnosed (make test-cases)
def test_nothing_concealed_names_nothing(record_scenario, tmp_path):
    rep = _report(record_scenario, tmp_path, {})
    assert [e["name"] for e in rep["effects"]] == [], rep["mismatch"]["summary"]


@pytest.mark.cases  # one whole case recorded and diagnosed (make test-cases)
@pytest.mark.parametrize("offsets", [{"dx_31": 0.006, "dz_12": -0.005}])
def test_a_true_exit_offset_beside_the_pretension_stays(record_scenario, tmp_path, offsets):
    rep = _report(record_scenario, tmp_path, {"exit_point_offset": offsets})
    named = {e["name"]: e["params"] for e in rep["effects"]}
    assert "exit_point_offset" in named, rep["mismatch"]["summary"]
