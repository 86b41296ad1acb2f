"""``cdpr diagnose`` on a logger's log without the controller's columns (no ``*_des``,
``l_cmd_*``, ``state``) whose tracker is interpolated to slower load cells: the alignment
refuses the pose at the moves' starts and ends (the platform accelerates), and those rows
must not become standing measurements of their own (placed from lengths and tensions they
left residuals 1700 times the noise and nothing was named). A concealed mast stiffness is
named as from the same log with the controller's columns."""

from __future__ import annotations

import numpy as np
import pytest
from mast_logs import mast_log

from bench.chunked import read_conditioned
from bench.diagnosis.report import diagnose
from bench.diagnosis.samples import prepare

pytestmark = pytest.mark.slow

#: encoders every 5 ms row, load cells at 25 Hz (the slowest: the rows' instants), tracker 50 Hz
RATES = {"rows_hz": 200.0, "encoders_hz": 200.0, "load_cells_hz": 25.0, "tracker_hz": 50.0,
         "empty": "nan", "controller_columns": False}


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return mast_log(tmp_path_factory.mktemp("mast") / "rec", 31, RATES)


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
