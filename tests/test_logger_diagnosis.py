"""``cdpr diagnose`` on a logger's log without the controller's columns (no ``*_des``,
``l_cmd_*``, ``state``) whose tracker is interpolated to slower load cells: the alignment
refuses the pose at the moves' starts and ends (the platform accelerates), and those rows
must not become standing measurements of their own (placed from lengths and tensions they
left residuals 1700 times the noise and nothing was named). A concealed mast stiffness is
named as from the same log with the controller's columns."""

from __future__ import annotations

import numpy as np
import pytest

from bench.chunked import read_conditioned
from bench.diagnosis.report import diagnose
from bench.diagnosis.samples import prepare
from bench.logger_sim import LoggerSpec, simulate_truth, write_log
from firmware_sim.scenario import parse_scenario

pytestmark = pytest.mark.slow

POSES = {"kind": "grid", "n": [2, 2, 1], "x": [8.0, 12.0], "y": [6.0, 11.0], "rpy_deg": 2.0,
         "visits": 2, "dwell_s": 2.0, "init_s": 3.0}
#: the paper's mast stiffness (the model's masts are rigid)
STIFF = {f"k{a}_{m}": k for m in "1234" for a, k in zip("xyz", (2e5, 5e5, 3e5), strict=True)}
#: encoders every 5 ms row, load cells at 25 Hz (the slowest: the rows' instants), tracker 50 Hz
RATES = {"rows_hz": 200.0, "encoders_hz": 200.0, "load_cells_hz": 25.0, "tracker_hz": 50.0,
         "empty": "nan", "controller_columns": False}
PHYSICS_HZ = 10.0


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    sc = parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 31,
                         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
                         "nuisance": {"hysteresis_m": 1e-4, "drift_m_per_h": 5e-5},
                         "poses": POSES, "truth": {"mast_compliance": STIFF}})
    d = tmp_path_factory.mktemp("mast") / "rec"
    return write_log(d, sc, LoggerSpec(physics_hz=PHYSICS_HZ, **RATES),
                     simulate_truth(sc, PHYSICS_HZ))


def test_every_dwell_sample_of_a_tracked_log_has_a_pose(log):
    rec, _, _ = read_conditioned(log)
    assert not np.isfinite(rec.pose_meas).all(axis=1).all()  # some rows without a fix
    s = prepare(rec)
    dwell = s.kind == 0
    assert dwell.sum() >= 9  # 4 poses x 2 visits and the initialisation
    assert np.isfinite(s.pose_meas[dwell]).all()


def test_a_concealed_mast_stiffness_is_named(log):
    rep = diagnose(log).report
    assert [e["name"] for e in rep["effects"]] == ["mast_compliance"]
