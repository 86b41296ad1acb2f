"""The paper's own data (Tables 1 and 2) as a recording: examples/paper_tables."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.diagnosis.report import diagnose
from bench.recording import read_recording

EXAMPLE = Path(__file__).parent.parent / "examples" / "paper_tables"


@pytest.fixture(scope="module")
def report():
    return diagnose(EXAMPLE).report


def test_the_example_is_a_valid_recording():
    rec = read_recording(EXAMPLE)
    assert rec.n_samples == 5 and list(rec.init_rows) == [0]
    assert not rec.has("tau") and not rec.has("l_meas") and rec.has("exit_meas")


def test_names_the_papers_two_effects(report):
    assert [e["name"] for e in report["effects"]] == ["exit_point_offset", "mast_compliance"] \
        or sorted(e["name"] for e in report["effects"]) == ["exit_point_offset",
                                                            "mast_compliance"]


def test_exit_point_residual_from_centimetres_to_a_centimetre(report):
    assert report["baseline"]["exit_point_rms_m"] > 0.05  # nominal model: several cm
    assert report["fitted"]["exit_point_rms_m"] <= 0.01
    # nothing the recording cannot give
    for k in ("pose_rms_m", "tension_rms_n", "wrench_rms"):
        assert report["baseline"][k] is None
    assert report["fitted"]["heldout_pose_rms_m"] is None


def test_gives_mast_2_stiffness_to_set_beside_the_papers(report):
    comp = next(e for e in report["effects"] if e["name"] == "mast_compliance")
    # only mast 2 was measured at several poses (Table 2): the others cannot be fixed
    assert {"kx_2", "ky_2"} <= set(comp["params"])
    for k in ("kx_2", "ky_2"):
        assert 2e4 < comp["params"][k] < 2e6
        assert comp["stderr"][k] > 0
    assert {"kx_1", "ky_1", "kx_3", "kx_4"} <= set(comp["undetermined"])
    offsets = next(e for e in report["effects"] if e["name"] == "exit_point_offset")
    # Table 1: A12 moved by (73, 88) mm; the offsets of singly-seen masts carry it
    assert offsets["params"]["dx_12"] == pytest.approx(0.073, abs=0.002)
    assert offsets["params"]["dy_12"] == pytest.approx(0.088, abs=0.002)
