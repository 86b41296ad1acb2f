"""``cdpr diagnose`` on logs written the way a bench's logger writes them (bench/logger_sim.py):
three streams at their own rates with jittered time stamps and nan/empty fields, with and
without the controller's columns, split across files. The same campaign written the
project's usual way (bench/campaign.py) is the reference: the same effects are named; with
nothing concealed, nothing is named. Condensing a long log does not change the answer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import bench.streams as streams
from bench.campaign import run_campaign
from bench.diagnosis.report import diagnose
from bench.logger_sim import LoggerSpec, simulate_truth, write_log
from firmware_sim.scenario import RecordingSpec, parse_scenario

pytestmark = pytest.mark.slow

#: a 3-minute campaign: 4 targets visited twice, 2 s dwells
POSES = {"kind": "grid", "n": [2, 2, 1], "x": [8.0, 12.0], "y": [6.0, 11.0], "rpy_deg": 2.0,
         "visits": 2, "dwell_s": 2.0, "init_s": 3.0}
PHYSICS_HZ = 10.0

#: the issue's two logs: 200 Hz cycle rows, tracker fixes at 10 Hz, nan elsewhere; and
#: 250 / 50 / 25 Hz, empty fields, no controller columns
CYCLE = {"rows_hz": 200.0, "encoders_hz": 200.0, "load_cells_hz": 200.0, "tracker_hz": 10.0,
         "empty": "nan"}
THREE = {"rows_hz": 250.0, "encoders_hz": 250.0, "load_cells_hz": 50.0, "tracker_hz": 25.0,
         "empty": "", "controller_columns": False}


def _scenario(truth: dict, seed: int):
    return parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": seed,
                           "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
                           "nuisance": {"hysteresis_m": 1e-4, "drift_m_per_h": 5e-5},
                           "poses": POSES, "truth": truth})


def _named(path) -> tuple[list[str], bool]:
    rep = diagnose(path).report
    return sorted(e["name"] for e in rep["effects"]), bool(rep["unexplained"])


@pytest.fixture(scope="module")
def slipped(tmp_path_factory):
    """A cable paid out 4 mm on its drum after initialisation: the usual recording (rows at
    10 Hz, every column in every row) and the truth for the logger."""
    sc = _scenario({"cable_length_offset": {"dl_21": 0.004}}, seed=21)
    d = tmp_path_factory.mktemp("slipped")
    usual = run_campaign(replace(sc, recording=RecordingSpec(
        kind="continuous", dwell_at_targets=True, rate_hz=PHYSICS_HZ)), d / "usual")
    return sc, simulate_truth(sc, PHYSICS_HZ), usual, d


def test_the_usual_recording_names_the_slip(slipped):
    # the reference the logger's recordings are held to
    _, _, usual, _ = slipped
    assert _named(usual) == (["cable_length_offset"], False)


@pytest.mark.parametrize("kind", ["cycle", "three", "three_split"])
def test_logger_recordings_name_what_the_usual_one_names(slipped, kind):
    sc, truth, usual, d = slipped
    spec = {"cycle": CYCLE, "three": THREE,
            "three_split": {**THREE, "split": "sensor"}}[kind]
    rec = write_log(d / kind, sc, LoggerSpec(physics_hz=PHYSICS_HZ, **spec), truth)
    dg = diagnose(rec)
    rep = dg.report
    assert sorted(e["name"] for e in rep["effects"]) == ["cable_length_offset"]
    assert not rep["unexplained"]
    (eff,) = rep["effects"]
    assert eff["params"]["dl_21"] == pytest.approx(0.004, abs=max(3 * eff["stderr"]["dl_21"],
                                                                 3e-4))
    st = rep["mismatch"]["streams"]
    rates = {k: v["rate_hz"] for k, v in st["streams"].items()}
    assert rates["tracker"] == pytest.approx(spec["tracker_hz"], rel=0.02)
    assert rates["encoders"] == pytest.approx(spec["encoders_hz"], rel=0.02)
    assert st["alignment"]["reference"] == "tracker"


def test_nothing_concealed_names_nothing(tmp_path):
    sc = _scenario({}, seed=22)
    rec = write_log(tmp_path / "none", sc, LoggerSpec(physics_hz=PHYSICS_HZ, **THREE))
    assert _named(rec) == ([], False)


def test_condensing_does_not_change_the_answer(slipped, monkeypatch):
    # the usual recording diagnosed whole and condensed to a fifth of its rows (every k-th
    # row and every row around an event): the same effect, its parameter within errors
    _, _, usual, _ = slipped
    full = diagnose(usual).report
    rows = full["mismatch"]["samples"]["rows"]
    monkeypatch.setattr(streams, "ROW_BUDGET", rows // 5)
    small = diagnose(usual).report
    assert small["mismatch"]["streams"]["condensed"]["rows_after"] < rows // 3
    assert [e["name"] for e in small["effects"]] == [e["name"] for e in full["effects"]]
    for a, b in zip(small["effects"], full["effects"], strict=True):
        for k, v in b["params"].items():
            assert a["params"][k] == pytest.approx(v, abs=2 * np.hypot(a["stderr"][k],
                                                                       b["stderr"][k]) + 1e-9)
