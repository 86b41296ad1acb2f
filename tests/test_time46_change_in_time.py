"""A change during a campaign located in time (issue 32, "What to build" 3; time46).

- A dwell is one visit only while the log runs: the rows after a gap in the log at the same
  commanded pose are another visit (`cdpr evaluate --kind load_change` seed 32013: the
  load changed while the platform stood at the first campaign's last pose, the two dwells
  became one sample of 12 rows, and the step's time bracket [417.8, 467.1] s missed the
  change at 482.1 s).
- With few replicate groups (a dwell campaign of four poses), a step is judged by its
  small-sample F tail at a stated false-alarm rate beside the normal tail's z 7: a load
  change 47 times the force balance's spread is found, no change is not.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from bench.diagnosis import noise, samples
from bench.diagnosis.residuals import ResidualModel
from bench.evaluate import CHANGE_GAP_S, make_case, record
from bench.recording import read_recording
from tests.residual_models import load_change_residual_model


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
    rm, case = load_change_residual_model(32013, None, tmp_path)
    t0 = float(case["case"]["change"]["t_s"])
    s = rm.s
    gap_start = t0 - CHANGE_GAP_S  # (the first campaign's last row)
    assert not np.any((s.t > gap_start) & (s.t < t0)), "a sample straddles the change"
    steps = [c for c in noise.find_changes(rm, rm.blocks(rm.model)) if c.kind == "step"]
    assert steps, "the load change was not found"
    assert steps[0].before_s < t0 <= steps[0].after_s


@pytest.mark.parametrize("factor", [None, 1.0])
def test_a_load_change_on_four_poses_is_found_and_no_change_is_not(tmp_path, factor):
    """Seed 32010 of the load_change kind: CoGiRo, four poses visited three times, the load
    9 % lighter after the first round. The force balance steps by 47 times its spread, but
    F(1, 7) cannot reach the 1e-12 that the normal reads as z 7 (p 6e-13 before the
    correction for three columns: missed); its small-sample tail decides at P_FALSE. The step
    is placed between the last sample before the change and the first after. The same
    campaign without the change (mass factor 1): nothing."""
    rm, case = load_change_residual_model(32010, factor, tmp_path)
    t0 = float(case["case"]["change"]["t_s"])
    assert not (rm.s.kind == 1).any()  # a dwell campaign: independent visits
    changes = noise.find_changes(rm, rm.blocks(rm.model))
    if factor is not None:
        assert changes == [], [c.entry() for c in changes]
        return
    steps = [c for c in changes if c.kind == "step" and c.block == "force"]
    assert steps, "the load change was not found"
    assert steps[0].before_s < t0 <= steps[0].after_s
    assert "z" in steps[0].columns


def test_the_small_sample_tail_decides_only_with_independent_units():
    """`systematic_p`: with many degrees of freedom it is the F's tail as before (within a
    factor of the t's tail at z 7); with 7 a step of t 100 passes where the plain F tail
    cannot, and a t of 5 does not (noise: P(|t7| > 5) = 2e-3 > P_FALSE); with units that
    are not independent (rows of moves) the plain F tail alone."""
    big = noise.systematic_p(100.0 ** 2, 1, 7, independent=True)
    assert big < noise.P_SYSTEMATIC / 100
    assert stats.f.sf(100.0 ** 2, 1, 7) > noise.P_SYSTEMATIC  # (the plain tail: missed)
    assert noise.systematic_p(5.0 ** 2, 1, 7, independent=True) > noise.P_SYSTEMATIC
    assert noise.systematic_p(100.0 ** 2, 1, 7) == pytest.approx(stats.f.sf(1e4, 1, 7))
    many = noise.systematic_p(8.0 ** 2, 1, 1e6, independent=True)
    assert many == pytest.approx(stats.f.sf(64.0, 1, 1e6), rel=0.05)


@pytest.mark.cases  # one evaluation case recorded whole (make test-cases)
def test_a_continuous_campaign_without_a_change_shows_none(tmp_path):
    """Seed 12819 of the 200-case evaluation: a continuous_dwell campaign of IPAnema-class
    with nothing concealed. Its dwells share a stop's slow error with the moves around them,
    so the F's degrees of freedom overstate what the units hold: read with the small-sample
    tail (independent units), its length residuals showed a step of z 9 at 82 s; with the
    plain F tail nothing is found."""
    case = make_case(12819)
    assert case["case"]["kind"] == "continuous_dwell" and not case["truth"]
    record(case, tmp_path / "rec")
    rec = read_recording(tmp_path / "rec")
    s = samples.prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    changes = noise.find_changes(rm, rm.blocks(rec.robot))
    assert not [c for c in changes if c.kind == "step"], [c.entry() for c in changes]
