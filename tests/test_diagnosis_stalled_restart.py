"""A search that stalls searches again (`Selector._restart` after `_forward`'s stall rule).

On this CoGiRo-class dwell campaign (case 11554 of `cdpr evaluate --seed 11400`: cables
sagging, a platform 9 % heavier than the model's, two drums' scales 0.3 and 0.5 % off),
the first steps took the load cells (every gain 11 % high: the mass's share) and 24 exit
coordinates (a share of the sag's and the drums'); the drums then left 33 x the noise where
60 was left, and the stall rule ended the search with a mismatch declared unexplained. A
second search without the exit points, allowed one effect more than the first, finds the
sag, the mass and the drums and leaves the noise."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.campaign import run_campaign
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread
from firmware_sim.scenario import parse_scenario

#: a whole diagnosis of one hard evaluation case (make test-cases; CI runs it after make test)
pytestmark = pytest.mark.cases

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "stalled_sag_mass_drum_cogiro_11554.json")


def test_a_stalled_search_searches_again_without_its_widest_effect(tmp_path):
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    rep = diagnose(run_campaign(parse_scenario(scenario), tmp_path / "rec")).report
    named = {e["name"]: e for e in rep["effects"]}
    truth = scenario["truth"]
    assert set(named) == set(truth), rep["mismatch"]["summary"]
    assert rep["unexplained"] is None
    assert set(named["drum_scale"]["params"]) == set(truth["drum_scale"])
    for effect, params in truth.items():
        for k, v in params.items():
            got, se = named[effect]["params"][k], named[effect]["stderr"][k]
            assert abs(got - v) < 4 * se + 1e-4 * abs(v), (effect, k, got, se, v)
