"""A continuous recording without a tracker and without replicate rows: the lengths'
visit-to-visit error changes where the path turns and blends along each move
(`ResidualModel.entry_knots` with `Samples.turns`), at the declared repeatability when
nothing measures it.

On this CoGiRo-class recording (case 11486 of `cdpr evaluate --seed 11400`: a platform
25 % lighter, three load cells' gains and one offset off, noise three times the usual), the
rows of the moves share errors that per-cable stretch took up: the eight EAs stood out by a
Wald statistic of 108 on 8 beside the true cells and mass, and one cable's EA was named.
With the turns' blend in the standard errors, 9.8: the cells and the mass only."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread

#: a whole diagnosis of one hard evaluation case (make test-cases; CI runs it after make test)
pytestmark = pytest.mark.cases

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "continuous_no_tracker_cells_mass_cogiro_11486.json")


def test_shared_errors_of_the_moves_are_no_per_cable_stretch(record_scenario, tmp_path):
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    rep = diagnose(record_scenario(scenario, tmp_path / "rec")).report
    named = {e["name"]: e for e in rep["effects"]}
    assert set(named) == {"load_cell_calibration", "platform_mass"}, rep["mismatch"]["summary"]
    truth = scenario["truth"]
    mass = named["platform_mass"]
    assert abs(mass["params"]["mass"] - truth["platform_mass"]["mass"]) \
        < 3 * mass["stderr"]["mass"]
    cells = named["load_cell_calibration"]
    for k, v in truth["load_cell_calibration"].items():
        assert abs(cells["params"][k] - v) < 3 * cells["stderr"][k], k
