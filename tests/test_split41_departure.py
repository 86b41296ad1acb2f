"""Without the controller's columns (no desired pose, no commanded lengths) the
initialisation ends where the encoders leave their first readings: they move first and
their noise is micrometres (the tracker's pose needed 2 mm and took the first move's first
rows, and a slip at that moment, into the initialisation). With and without a tracker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.chunked import read_conditioned
from bench.diagnosis.report import diagnose
from tests.outsider.cases import make_case
from tests.outsider.logger import Habits

SMALL = {"targets": 4, "passes": 2, "dwell_s": 3.0, "seed": 2}
INIT_S = 6.0  # the outsider campaign's initialisation [s]
SLIP = {"21": 0.004}


def _init_end(rec) -> float:
    """The last initialisation row's time from the campaign's start [s]."""
    return float(rec.t[rec.init_rows[-1]] - rec.t[0])


@pytest.mark.parametrize("drop", [(), ("tracker",)], ids=["tracker", "no-tracker"])
def test_a_clean_recording_is_initialised_until_the_first_move(tmp_path, drop):
    rec, _, _ = read_conditioned(make_case(tmp_path / "r", Habits(drop=drop), **SMALL))
    assert len(rec.init_rows) and INIT_S - 0.3 < _init_end(rec) < INIT_S + 0.3
    assert not np.isfinite(rec.pose_des).any() and not np.isfinite(rec.l_cmd).any()


@pytest.mark.parametrize("drop", [(), ("tracker",)], ids=["tracker", "no-tracker"])
def test_a_slip_as_the_platform_leaves_is_named_alone(tmp_path, drop):
    """Cable 21 slips 4 mm at the moment the platform leaves the initialisation: the slip is
    named exactly (its interval holds the truth) and nothing is left unexplained."""
    path: Path = make_case(tmp_path / "r", Habits(drop=drop), length_offset=SLIP,
                           slip_at_s=INIT_S, **SMALL)
    rec, _, _ = read_conditioned(path)
    assert _init_end(rec) < INIT_S  # the slipped rows are no initialisation's
    rep = diagnose(path).report
    assert [e["name"] for e in rep["effects"]] == ["cable_length_offset"], rep["effects"]
    eff = rep["effects"][0]
    assert set(eff["params"]) == {"dl_21"}
    lo, hi = eff["interval95"]["dl_21"]
    assert lo <= SLIP["21"] <= hi
    # the Student quantile each interval's standard errors were taken at: 1.96 or more
    assert set(eff["interval_quantile"]) == set(eff["interval95"])
    assert all(1.9599 < q < 15.0 for q in eff["interval_quantile"].values())
    assert rep["unexplained"] is None, rep["unexplained"]
