"""The visit-to-visit length error of a continuous recording with dwells
(``ResidualModel.entry_knots``): each stop has its own error, and the rows of the move
between two stops carry a blend of their two errors. The standard errors count it whole
(``tests/test_diagnosis_standard_errors.py`` checks them against the spread of estimates)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bench.campaign import campaign_plant, run_campaign
from bench.diagnosis.residuals import DEFAULTS, ResidualModel
from bench.diagnosis.samples import prepare
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario

POSES = {"kind": "grid", "n": [3, 2, 1], "x": [7.0, 13.0], "y": [6.0, 11.0], "z": [1.0, 1.5],
         "rpy_deg": 0.0, "visits": 2, "dwell_s": 2.0, "init_s": 3.0, "speed_m_s": 0.5}


def _model(tmp_path, recording: dict, poses: dict | None = None) -> ResidualModel:
    sc = parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
                         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0], "truth": {},
                         "nuisance": {"hysteresis_m": 5e-5, "drift_m_per_h": 2e-5},
                         "poses": copy.deepcopy(poses or POSES), "recording": recording})
    # rest searches along a move from the extrapolated rest: the same rows within 1e-8 m
    rec = read_recording(run_campaign(sc, tmp_path / "rec", plant=campaign_plant(sc, predict=True)))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return rm


@pytest.fixture(scope="module")
def dwells_and_moves(tmp_path_factory):
    return _model(tmp_path_factory.mktemp("blend"),
                  {"kind": "continuous", "dwell_at_targets": True, "rate_hz": 10.0})


def test_rows_of_a_move_blend_the_errors_of_the_stops_at_its_ends(dwells_and_moves):
    rm = dwells_and_moves
    s, n = rm.s, rm.model.n_cables
    K = rm.entry_knots()
    assert K is not None and rm.visit_sd and rm.visit_sd > 0
    assert K.shape[0] == len(rm.whitened(rm.model))
    stops = np.flatnonzero(s.kind == 0)
    assert K.shape[1] == len(stops) * n
    # length entries come first, sample by sample, cable by cable; the rest carry none
    m = int(rm.has_len.sum())
    L = K[: m * n].reshape(m, n, len(stops), n)
    assert not K[m * n:].any()
    amp = rm.visit_sd / rm.sd["length"][rm.has_len]
    hat = L.sum(axis=3) / amp[:, None, None]  # (samples, cables, stops)
    # each entry loads its own cable only
    off = L * (1.0 - np.eye(n))[None, :, None, :]
    assert not off.any()
    kinds = s.kind[rm.has_len]
    init = s.is_init[stops]
    for i in range(m):
        h = hat[i, 0]
        assert np.allclose(hat[i], h)  # the same weights for every cable of a sample
        if kinds[i] == 0:
            own = np.flatnonzero(stops == np.flatnonzero(rm.has_len)[i])[0]
            # a dwell: its own stop's error whole; the initialisation's: none (the reference)
            assert np.isclose(h[own], 0.0 if init[own] else 1.0)
            assert np.isclose(h.sum(), h[own])
        else:
            # a row of a move: weights on at most two stops next to each other, summing to
            # one (less the initialisation's share on the first move)
            nz = np.flatnonzero(h > 1e-12)
            assert 1 <= len(nz) <= 2 and (len(nz) == 1 or nz[1] == nz[0] + 1)
            assert h.sum() <= 1.0 + 1e-9
            if s.t[rm.has_len][i] > s.t[stops[~init]].min():
                assert np.isclose(h.sum(), 1.0)
    # the rows blend: some rows of moves share two stops' errors
    moving = hat[kinds == 1, 0]
    assert np.any(np.sum(moving > 0.2, axis=1) == 2)


def test_nothing_to_blend_without_rows_of_moves(tmp_path):
    dwell = _model(tmp_path / "d", {"kind": "dwell"},
                   POSES | {"rate_hz": 2.0, "dwell_s": 3.0, "init_s": 4.0})
    assert dwell.visit_sd and dwell.entry_knots() is None


def test_without_dwells_the_error_changes_where_moves_meet(tmp_path):
    """A continuous recording that never stops: the knots are the times where the commanded
    path turns (the targets), the level the spread of rows near each other on different
    moves; a row blends the knots before and after it."""
    rm = _model(tmp_path / "m", {"kind": "continuous", "dwell_at_targets": False,
                                 "rate_hz": 10.0})
    s, n = rm.s, rm.model.n_cables
    assert not (s.kind[~s.is_init] == 0).any()
    turns = s.turns
    assert turns is not None and len(turns) >= 2 and np.all(np.diff(turns) > 0)
    # every knot between the first and the last is where the commanded path reaches a
    # target of the grid (rows at 10 Hz, 0.5 m/s: within 5 cm)
    rec = read_recording(tmp_path / "m" / "rec")
    grid = np.array([[x, y] for x in np.linspace(7.0, 13.0, 3) for y in (6.0, 11.0)])
    for tk in turns[1:-1]:
        p = rec.pose_des[int(np.argmin(np.abs(rec.t - tk))), :2]
        assert np.min(np.linalg.norm(grid - p, axis=1)) < 0.05, (tk, p)
    K = rm.entry_knots()
    assert K is not None and rm.visit_sd and rm.visit_sd > 0
    m = int(rm.has_len.sum())
    assert K.shape == (len(rm.whitened(rm.model)), len(turns) * n)
    L = K[: m * n].reshape(m, n, len(turns), n)
    amp = rm.visit_sd / rm.sd["length"][rm.has_len]
    hat = L.sum(axis=3)[:, 0] / amp[:, None]  # (samples, turns)
    kinds = s.kind[rm.has_len]
    assert not hat[kinds == 0].any()  # the initialisation carries none
    for h in hat[kinds == 1]:
        nz = np.flatnonzero(h > 1e-12)
        assert 1 <= len(nz) <= 2 and (len(nz) == 1 or nz[1] == nz[0] + 1)
        assert np.isclose(h.sum(), 1.0)
    # the knots' errors are independent of each other
    assert np.any(np.sum(hat[kinds == 1] > 0.2, axis=1) == 2)


def test_without_replicates_the_declared_repeatability_changes_at_each_turn(tmp_path):
    """Nothing measures the level (one pass through each target): the repeatability the
    diagonal assumes (``DEFAULTS``) is the level of the turns' errors too."""
    rm = _model(tmp_path / "one", {"kind": "continuous", "dwell_at_targets": False,
                                   "rate_hz": 10.0}, POSES | {"visits": 1})
    assert rm.sigma_source.startswith("defaults")
    assert rm.visit_sd == DEFAULTS["length"]
    K = rm.entry_knots()
    assert K is not None and K.shape[1] == len(rm.s.turns) * rm.model.n_cables
