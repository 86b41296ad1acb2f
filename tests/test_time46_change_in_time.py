"""A change during a campaign located in time (issue 32, "What to build" 3; time46).

- A dwell is one visit only while the log runs: the rows after a gap in the log at the same
  commanded pose are another visit (`cdpr evaluate --kind load_change` seed 32013: the
  load changed while the platform stood at the first campaign's last pose, the two dwells
  became one sample of 12 rows, and the step's time bracket [417.8, 467.1] s missed the
  change at 482.1 s).
"""

from __future__ import annotations

import numpy as np

from bench.diagnosis import noise, samples
from bench.diagnosis.residuals import ResidualModel
from bench.evaluate import make_case, record
from bench.recording import read_recording


def test_a_gap_in_the_log_ends_a_dwell_and_jitter_does_not():
    """Rows at one commanded pose 0.5 s apart (jittered by 10 %), then 30 s without a row,
    then the same pose again: two runs; the jitter alone splits nothing."""
    rng = np.random.default_rng(1)
    t = np.r_[np.arange(6) * 0.5, 32.5 + np.arange(6) * 0.5] + rng.uniform(-0.05, 0.05, 12)
    keys = np.zeros((12, 6))
    assert samples._runs(keys, ["dwell"] * 12, t) == [(0, 6), (6, 12)]
    assert samples._runs(keys[:6], ["dwell"] * 6, t[:6]) == [(0, 6)]


def test_a_load_change_at_a_standing_pose_is_bracketed_by_its_samples(tmp_path):
    """Seed 32013 of the load_change kind (CoGiRo, 22 poses visited twice): the second
    campaign starts at the pose where the first ended. No sample holds rows from both sides
    of the change, and the force balance's step is placed between the last sample before
    the change and the first after it."""
    case = make_case(32013, kind="load_change")
    record(case, tmp_path / "rec")
    t0 = float(case["case"]["change"]["t_s"])
    rec = read_recording(tmp_path / "rec")
    s = samples.prepare(rec)
    gap_start = t0 - 30.0  # (the first campaign's last row: evaluate.CHANGE_GAP_S before)
    assert not np.any((s.t > gap_start) & (s.t < t0)), "a sample straddles the change"
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    steps = [c for c in noise.find_changes(rm, rm.blocks(rec.robot)) if c.kind == "step"]
    assert steps, "the load change was not found"
    assert steps[0].before_s < t0 <= steps[0].after_s
