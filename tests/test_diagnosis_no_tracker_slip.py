"""A slip during a move without a tracker (`report.stream_slips`): each raw row's pose is
estimated from its readings and takes up six of the eight directions of the slip's jump;
the slip is found through its cable's pattern in the two left and its tension's jump.

ROCASPECT, continuous recording without a tracker (case 12935 of `cdpr evaluate --seed
12800`, its first three targets): cable 41 slips 6.1 mm at 158.5 s. Before the estimated
poses' directions were accounted for, no row's jump was any one cable's own (the pose
spread it over all eight), the slip was fitted from the initialisation on, and a drum
scale, E*A and the load cells were named beside offsets on five cables."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.diagnosis.report import stream_slips
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.diagnosis.slips import choose_alike
from bench.evaluate import one_blas_thread
from bench.recording import read_recording

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "slip_no_tracker_continuous_rocaspect_12935.json")


def _slips(folder: Path, choose: bool = False) -> list[dict]:
    """The slips the raw rows show in the recording ``folder`` (with ``choose``: those the
    candidates' offsets over every sample keep)."""
    one_blas_thread()
    rec = read_recording(folder)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    found = stream_slips(rec, s, rm)
    if choose:
        rm.estimate_noise(rec.robot)
        found = choose_alike(rm, found)
    return found


@pytest.fixture(scope="module")
def scenario() -> dict:
    return json.loads(SCENARIO.read_text())


@pytest.fixture(scope="module")
def slipped(scenario, record_scenario, tmp_path_factory) -> Path:
    """The scenario's recording (the slip included), shared by the tests that read it."""
    return record_scenario(scenario, tmp_path_factory.mktemp("slip") / "rec")


def test_the_slip_is_found_at_its_row(scenario, slipped):
    """Found at its row, at its size. ROCASPECT's odd cables' patterns are nearly parallel
    in the two directions an estimated pose leaves: 31's accounts for the jump within the
    noise too, and is a candidate alike (the selection's fit of the offsets tells whose)."""
    truth = scenario["truth"]["cable_length_offset"]
    found = {f["cable"]: f for f in _slips(slipped)}
    assert "41" in found and set(found) <= {"11", "21", "31", "41"}
    for f in found.values():
        assert abs(f["t_s"] - truth["slip_time_41"]) < 0.2
        assert set(f.get("alike", [])) == set(found) - {f["cable"]}
    assert abs(found["41"]["step_m"] - truth["dl_41"]) < 5e-4


def test_the_candidates_offsets_over_every_sample_choose_the_slipped_cable(slipped):
    """Each candidate's offset from the step on, sized to first order, over every sample
    (each at its own pose, where the patterns differ): cable 41's fits best by far; the
    others' steps are dropped."""
    found = _slips(slipped, choose=True)
    assert [f["cable"] for f in found] == ["41"] and "alike" not in found[0]


def test_no_slip_no_jump(scenario, record_scenario, tmp_path):
    """Must find nothing: the same campaign without the slip (the reversals between the
    targets, the readings' hysteresis, the estimated poses' noise)."""
    plain = dict(scenario, truth={})
    assert _slips(record_scenario(plain, tmp_path / "rec")) == []
