"""A sag entered as a lighter platform (`Selector._displaced`, the swap's bar at equal
cost): at the model a sag's tangent is the load it adds, so the screen ranks the mass
first; fitted beside the mass, the sag holds the mass at the model's value.

On this ROCASPECT continuous campaign with dwells and three times the usual noise (case
11931 of `cdpr evaluate --seed 11800`), the mass was named alone (BIC 583.2) while the
sag alone explains the data better (571.2), a swap the entry bar of 25 refused."""

from __future__ import annotations

import json
from pathlib import Path

from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "sag_displaces_mass_rocaspect_11931.json")


def test_the_sag_takes_the_place_of_the_mass(record_scenario, tmp_path):
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    rep = diagnose(record_scenario(scenario, tmp_path / "rec")).report
    named = {e["name"]: e for e in rep["effects"]}
    assert set(named) == {"cable_sag"}, rep["mismatch"]["summary"]
    rho = scenario["truth"]["cable_sag"]["rho"]
    assert abs(named["cable_sag"]["params"]["rho"] - rho) < 4 * named["cable_sag"]["stderr"]["rho"]
