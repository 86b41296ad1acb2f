"""The repeatability estimated from replicate visits (``ResidualModel.estimate_noise``): a slip
on one cable splits that cable's replicate groups only (the other cables' visits stay
replicates), and the replicate degrees of freedom count rows of a move by their weight (they
share the move's slow errors)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis.residuals import ResidualModel, _pooled_columns
from bench.diagnosis.samples import prepare
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario

POSES = {"kind": "grid", "n": [3, 2, 1], "x": [7.0, 13.0], "y": [6.0, 11.0], "z": [1.0, 1.5],
         "rpy_deg": 0.0, "visits": 3, "dwell_s": 2.0, "init_s": 3.0, "speed_m_s": 0.5}
SLIP_M = 3e-3


def _model(tmp_path, truth: dict) -> tuple[ResidualModel, float]:
    sc = parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 7,
                         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0], "truth": truth,
                         "noise": {"process_m": 1e-4},
                         "poses": copy.deepcopy(POSES), "recording": {"kind": "dwell"}})
    rec = read_recording(run_campaign(sc, tmp_path / "rec"))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    return rm, float(np.max(sc.slip_times))


@pytest.fixture(scope="module")
def slipped(tmp_path_factory):
    # the slip half-way through the campaign: visits of a target on both sides of it
    d = tmp_path_factory.mktemp("slip")
    rm, _ = _model(d / "probe", {})
    t_slip = float(np.median(rm.s.t[~rm.s.is_init]))
    rm, _ = _model(d / "rec", {"cable_length_offset": {"dl_21": SLIP_M,
                                                         "slip_time_21": t_slip}})
    return rm, t_slip


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    rm, _ = _model(tmp_path_factory.mktemp("plain"), {})
    rm.estimate_noise(rm.model)
    return rm


def test_a_slip_splits_only_its_own_cables_replicates(slipped, plain):
    rm, t_slip = slipped
    k = rm.model.cable_ids.index("21")
    slips = np.full(rm.model.n_cables, rm.init_end)
    slips[k] = t_slip
    rm.slip_times = slips
    rm.estimate_noise(rm.model)
    # the step is no noise: the repeatability is what the recording without the slip shows
    assert rm.sigma["length"] < 3.0 * plain.sigma["length"] + 2e-5
    assert rm.sigma["length"] < SLIP_M / 10
    # the other seven cables keep every replicate difference; cable 21 loses some
    n = rm.model.n_cables
    assert rm.replicate_dof > plain.replicate_dof * (n - 1) / n
    assert rm.replicate_dof < plain.replicate_dof
    # without the slip time, the step counts as noise (what must not happen once it is
    # located)
    rm.slip_times = np.full(n, rm.init_end)
    rm.estimate_noise(rm.model)
    assert rm.sigma["length"] > SLIP_M / 10


def test_no_slip_no_split(plain):
    # a dwell campaign: every visit a replicate, each difference counts one
    s = plain.s
    _, cnt = np.unique(s.target, return_counts=True)
    pairs = float(np.sum(cnt[cnt >= 2] - 1))
    assert plain.sigma_source == "replicate visits"
    assert plain.replicate_dof == pytest.approx(pairs, rel=0.05)


def test_replicate_differences_count_rows_of_a_move_by_their_weight():
    rng = np.random.default_rng(1)
    # twelve pairs of rows from two moves (weight 1/3 each: a move counts as four samples),
    # and three dwells visited twice
    groups = np.concatenate([np.repeat(np.arange(12), 2), np.repeat(np.arange(12, 15), 2)])
    w = np.concatenate([np.full(24, 1 / 3), np.ones(6)])
    v = rng.normal(size=(30, 2))
    sd, rep, dof = _pooled_columns(v, np.stack([groups, groups], axis=1), w)
    assert rep.all()
    assert dof == pytest.approx([12 / 3 + 3, 12 / 3 + 3])
    # the spread itself is the plain pooled one
    m = np.array([v[groups == g].mean(axis=0) for g in range(15)])
    ss = ((v - m[groups]) ** 2).sum(axis=0)
    assert sd == pytest.approx(np.sqrt(ss / 15))
    # a value left out leaves its group without a difference
    v[0, 0] = np.nan
    _, _, dof = _pooled_columns(v, np.stack([groups, groups], axis=1), w)
    assert dof[0] == pytest.approx(dof[1] - 1 / 3)


def test_rows_of_moves_without_replicates_take_the_dwells_visit_to_visit_error(tmp_path):
    """Rows of moves with no replicates of their own carry the dwells' measured visit-to-visit
    error (plus their own row-to-row noise), not a declared default far above it."""
    sc = parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
                         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0], "truth": {},
                         "nuisance": {"hysteresis_m": 5e-5, "drift_m_per_h": 2e-5},
                         "noise": {"process_m": 1e-4},
                         "poses": {**copy.deepcopy(POSES), "visits": 2},
                         "recording": {"kind": "continuous", "dwell_at_targets": True,
                                       "rate_hz": 10.0}})
    rec = read_recording(run_campaign(sc, tmp_path / "rec"))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    # every row of a move its own group: only the dwells have replicates
    groups = np.where(s.kind == 1, s.target.max() + 1 + np.arange(s.n), s.target)
    rm.estimate_noise(rm.model, groups=groups)
    visit = rm.sigma_k[0]["length"]
    assert rm.sigma_source == "replicate visits" and 0 < visit < 2e-4
    assert rm.sigma_k[1]["length"] == pytest.approx(visit)


def test_a_dwell_without_a_whole_pose_fix_is_no_replicate_of_anything():
    """Without commanded poses, dwells group by measured pose; a dwell whose pose is missing
    (nan: no tracker fix) or partial is its own group, never the replicate of every other."""
    from bench.diagnosis.samples import _targets

    nan = np.nan
    meas = np.array([[1.0, 2.0, 3.0, 0, 0, 0], [nan] * 6, [1.001, 2.0, 3.0, 0, 0, 0],
                     [5.0, 2.0, 3.0, 0, 0, 0], [nan, nan, 3.0, nan, nan, nan],
                     [5.0, 2.0, 3.001, 0, 0, 0], [9.0, 9.0, 3.0, 0, 0, 0]])
    ids = _targets(np.full((7, 6), nan), meas)
    assert ids[0] == ids[2] and ids[3] == ids[5]
    assert len({ids[0], ids[1], ids[3], ids[4], ids[6]}) == 5
