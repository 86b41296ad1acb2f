"""A logger's log whose tracker gave no fix over one whole dwell (the line of sight lost for a
few seconds, issue 32 item 1: a stream's gaps are "no sample"). That visit's pose is
estimated from its lengths and tensions; its residual is another than that of the visit of
the same target the tracker measured, and the difference is the model's error, not noise.
Pooled as replicates, the two read the paper's 200 Hz log (its exit offsets and masts) as
lengths' noise of 4.9 mm instead of 0.19 mm, and the fit left 4.2 mm of pose error where the
whole log leaves 0.18 mm. Here: the same campaign with the tracker whole and with the
tracker lost over one dwell measure the same noise level; that they name the same effect
is not yet so (strict xfail: an exit offset is named beside the masts' stiffness)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from mast_logs import mast_log

from bench.chunked import read_conditioned
from bench.diagnosis.report import diagnose
from bench.diagnosis.samples import prepare
from bench.recording import POSE_AXES

pytestmark = pytest.mark.slow

#: every stream every 5 ms row but the tracker's 50 Hz, the controller's columns written
RATES = {"rows_hz": 200.0, "encoders_hz": 200.0, "load_cells_hz": 200.0, "tracker_hz": 50.0,
         "empty": "nan", "controller_columns": True}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The campaign's log, and a copy whose tracker columns are empty from 1 s before to 1 s
    after the last dwell sample's time (its visit is the second of its target)."""
    base = tmp_path_factory.mktemp("lost")
    whole = mast_log(base / "whole", 45, RATES)
    s = prepare(read_conditioned(whole)[0])
    last = float(s.t[(s.kind == 0) & ~s.is_init].max())
    lost = base / "lost"
    shutil.copytree(whole, lost)
    _blank_tracker(lost / "recording.csv", last - 1.0, last + 1.0)
    return whole, lost, (last - 1.0, last + 1.0)


def _blank_tracker(path, t0: float, t1: float) -> None:
    """Empty the tracker's pose fields of the rows with ``t0 < t < t1`` (``nan``)."""
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    cols = [head.index(f"{a}_meas") for a in POSE_AXES]
    for i in range(1, len(lines)):
        f = lines[i].split(",")
        if t0 < float(f[0]) < t1:
            for c in cols:
                f[c] = "nan"
            lines[i] = ",".join(f)
    path.write_text("\n".join(lines) + "\n")


def test_the_dwell_without_a_fix_has_its_pose_estimated(logs):
    _, lost, (t0, t1) = logs
    s = prepare(read_conditioned(lost)[0])
    inside = (s.kind == 0) & (s.t > t0) & (s.t < t1)
    assert inside.any() and not np.isfinite(s.pose_meas[inside]).any()


@pytest.fixture(scope="module")
def reports(logs):
    """The diagnoses (in this process) of the whole log and of the one with the fix lost."""
    whole, lost, _ = logs
    return diagnose(whole).report, diagnose(lost).report


def test_a_dwell_without_a_fix_is_no_replicate_of_one_measured(reports):
    a, b = reports
    la, lb = a["mismatch"]["noise"]["length"], b["mismatch"]["noise"]["length"]
    assert lb < 1.5 * la, (la, lb)
    assert b["fitted"]["pose_rms_m"] < 2.0 * a["fitted"]["pose_rms_m"]


@pytest.mark.xfail(strict=True, reason=(
    "measured on 869d6bc and with the replicate split: the log with the fix lost names "
    "exit_point_offset beside mast_compliance (the whole log: mast_compliance alone); "
    "through `cdpr diagnose` (2 processes) the old code also declares it unexplained"))
def test_a_dwell_without_a_fix_names_what_the_whole_log_names(reports):
    a, b = reports
    assert [e["name"] for e in a["effects"]] == ["mast_compliance"]
    assert [e["name"] for e in b["effects"]] == ["mast_compliance"]
