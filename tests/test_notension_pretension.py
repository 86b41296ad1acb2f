"""Tensions at initialisation off the distribution's in a recording without load cells but
with a tracker (issue 32: case 71001 of `cdpr evaluate --robot mix_new`).

An IPAnema-class rig with swivel pulleys, dwells, no load cells, noise three times the
usual, one drum scale concealed (cable 11) and the tensions at referencing about 47 N RMS off
the distribution's. The pretension shortens every cable by its stretch at the initialisation
pose; away from it that reads as scale-like errors of a few cables: four more drum scales
were named beside s_11, 4 to 10 standard errors off the truth, and the pretension was tried
only in the place of the drum scale (which it cannot be). Fitted beside the chosen effects,
it takes them up."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.campaign import run_campaign
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread
from firmware_sim.scenario import parse_scenario

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "drum_scale_pretension_ipanema_no_tensions_71001.json")


@pytest.mark.slow
def test_a_pretension_beside_a_drum_scale_is_fitted_not_named_as_scales(tmp_path):
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    truth = scenario["truth"]["drum_scale"]
    rep = diagnose(run_campaign(parse_scenario(scenario), tmp_path / "rec")).report
    assert [e["name"] for e in rep["effects"]] == ["drum_scale"], rep["mismatch"]["summary"]
    e = rep["effects"][0]
    assert "s_11" in e["params"] and len(e["params"]) <= 2, e["params"]
    for k, v in e["params"].items():  # every named scale within 3 standard errors of the truth
        assert abs(v - truth.get(k, 1.0)) < 3.0 * e["stderr"][k], (k, v, e["stderr"][k])
    assert "init_tensions" in rep["mismatch"]
