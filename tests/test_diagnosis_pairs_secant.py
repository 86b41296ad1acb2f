"""The pairs of effects are ranked by a linear fit of their signatures: each effect's
tangent at the model and its secant to its own fit (:meth:`Selector._pairs`). A sag's
lengths grow with the square of the cables' weight, so its tangent at the model sees
only the load it adds: ranked by tangents alone, sag + EA was never fitted on this
continuous ROCASPECT-class recording (case 10923 of `cdpr evaluate --seed 10800`) and the
selection named a platform 3 kg heavier instead. The selection now reaches sag + EA by
other ways too (its later swaps), so the named effects alone no longer tell the ranking
wrong from right: the pairs step is watched as well. Ranked by tangents alone it takes
E*A + the platform's mass here; with the secants, sag + E*A."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.diagnosis.fit import FitResult
from bench.diagnosis.report import diagnose
from bench.diagnosis.select import Selector
from bench.evaluate import one_blas_thread

#: a whole diagnosis of one hard evaluation case (make test-cases; CI runs it after make test)
pytestmark = pytest.mark.cases

SCENARIO = Path(__file__).parent / "data" / "scenarios" / "sag_and_ea_continuous_10923.json"


def test_sag_and_ea_are_named_not_a_heavier_platform(record_scenario, tmp_path, monkeypatch):
    one_blas_thread()
    taken: list[set[str] | None] = []
    pairs = Selector._pairs

    def watched(self: Selector, current: FitResult, candidates: list[str]):
        out = pairs(self, current, candidates)
        taken.append(None if out is None else set(out[0]))
        return out

    monkeypatch.setattr(Selector, "_pairs", watched)
    rep = diagnose(record_scenario(json.loads(SCENARIO.read_text()), tmp_path / "rec")).report
    named = {e["name"]: e for e in rep["effects"]}
    assert set(named) == {"cable_sag", "cable_elasticity"}, rep["mismatch"]["summary"]
    rho = named["cable_sag"]["params"]["rho"]  # the truth's 0.05606 kg/m
    assert abs(rho - 0.05606) < 3 * named["cable_sag"]["stderr"]["rho"] + 1e-3
    # the pairs step itself takes sag + E*A (by tangents alone: E*A + the platform's mass)
    assert {"cable_sag", "cable_elasticity_each"} in taken, taken
