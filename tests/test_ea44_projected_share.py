"""Without a tracker, the error model reads each kind of entry at the share of its errors the
estimated poses leave.

A sample's pose is solved from its n cable lengths: its length residual keeps ``r = n - 6`` of
the n directions of the readings' errors (its moments are ``r / n`` of theirs), its force and
moment residuals all six. The error model (:func:`bench.diagnosis.fit.error_meat`) estimates
each kind's error level from the moments of the residuals and scales it back to the errors'.
With one share for every entry (the residuals' degrees of freedom left over all of them), a
recording of eight cables with load cells scaled its lengths' level by 14/8 where their share
is 2/8 (0.44 of their errors' variance): the elasticities, fixed by the lengths, got standard
errors 0.62 to 0.66 of what the curvature tells (their 95 % intervals held the truth 6 times
in 12, z up to 8.6). The lengths now have their own share
(:meth:`bench.diagnosis.residuals.ResidualModel.entry_kept`); the force and moment entries,
which the poses do not project, keep the recording's share.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.diagnosis.fit import ErrorStructure, error_structure, standard_errors
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.evaluate import one_blas_thread, record
from bench.recording import read_recording

N_CABLES = 8


def _projected_problem(rng: np.random.Generator, m: int = 80, wrench_gain: float = 0.05
                       ) -> tuple[np.ndarray, np.ndarray, ErrorStructure, float]:
    """A one-parameter linear fit with per-sample poses profiled out of ``m`` samples: per
    sample, n length entries projected onto the n - 6 directions a pose Jacobian leaves
    (errors of unit variance before the projection) and six wrench entries the pose leaves
    whole (the parameter reaches them by ``wrench_gain``). Returns the Jacobian, the fitted
    residuals, their error structure and the parameter's true variance ``(J^T J)^-1``."""
    n = N_CABLES
    rows_j, rows_r, kinds, cols, kept = [], [], [], [], []
    for _ in range(m):
        A = rng.normal(size=(n, 6))
        P = np.eye(n) - A @ np.linalg.pinv(A)
        rows_j.append(P @ rng.normal(size=n))
        rows_r.append(P @ rng.normal(size=n))
        rows_j.append(wrench_gain * rng.normal(size=6))
        rows_r.append(rng.normal(size=6))
        kinds += [0] * n + [1, 1, 1, 2, 2, 2]
        cols += list(range(n)) + list(range(n, n + 6))
        kept += [(n - 6) / n] * n + [1.0] * 6
    J = np.concatenate(rows_j)[:, None]
    e = np.concatenate(rows_r)
    theta = float(J[:, 0] @ e / (J[:, 0] @ J[:, 0]))
    r = e - J[:, 0] * theta
    size = len(r)
    lost = 6.0 * m
    moves = np.repeat(np.arange(m), n + 6)
    errors = ErrorStructure(np.ones(size), np.array(kinds), np.array(cols), moves,
                            np.zeros(size, dtype=int), float(size), None, None,
                            (size - lost) / size, entry_kept=np.array(kept))
    return J, r, errors, float(1.0 / (J[:, 0] @ J[:, 0]))


def _variance_ratio(rng: np.random.Generator, wrench_gain: float) -> float:
    """Mean over draws of the sandwich variance over the estimate's true variance."""
    ratios = []
    for _ in range(30):
        J, r, errors, true_var = _projected_problem(rng, wrench_gain=wrench_gain)
        _, se = standard_errors(J, float(r @ r), errors.n_eff * errors.kept, None, r, None,
                                errors)
        ratios.append(se[0] ** 2 / true_var)
    return float(np.mean(ratios))


def test_a_parameter_fixed_by_projected_lengths_gets_the_variance_of_its_estimate():
    """Over draws of the errors, the sandwich variance of a parameter the projected lengths
    fix is its estimate's true variance (within 10 %; the recording's one share gave 0.44 of
    it). The wrench entries keep the recording's share (1 / kept of their errors' moments:
    at an estimated pose they also carry the visits' length errors, not modelled on dwells)."""
    rng = np.random.default_rng(44)
    assert 0.9 < _variance_ratio(rng, 0.05) < 1.1
    kept = (N_CABLES - 6 + 6) / (N_CABLES + 6)
    assert 0.9 / kept < _variance_ratio(rng, 20.0) < 1.1 / kept


def test_without_unknowns_per_sample_every_share_is_one():
    """With every entry's errors whole (a tracker pose and tensions: nothing projected), the
    per-kind shares change nothing: the sandwich is the one of a single share of 1."""
    rng = np.random.default_rng(7)
    J = rng.normal(size=(120, 2))
    r = rng.normal(size=120)
    kinds = np.repeat([0, 1], 60)
    base = ErrorStructure(np.ones(120), kinds, kinds * 3 + np.arange(120) % 3,
                          np.arange(120) // 6, np.zeros(120, dtype=int), 120.0)
    with_shares = ErrorStructure(base.weights, kinds, base.columns, base.moves,
                                 base.stretches, 120.0, entry_kept=np.ones(120))
    a = standard_errors(J, float(r @ r), 120.0, None, r, None, base)[0]
    b = standard_errors(J, float(r @ r), 120.0, None, r, None, with_shares)[0]
    np.testing.assert_allclose(a, b, rtol=1e-12)


def test_estimated_poses_leave_r_over_n_of_the_lengths_and_all_of_the_wrench(tmp_path: Path):
    """On a recording without a tracker: each length entry keeps (n - 6) / n, each force and
    moment entry 1, and the shares weighted like the entries sum to their weights less the
    degrees of freedom the poses take (the error structure carries them)."""
    one_blas_thread()
    case = {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 4411,
            "init_pose": [9.6, 4.9, 1.74, 0.0, 0.0, 0.0], "truth": {},
            "noise": {"tracker_m": 1.5e-05, "tracker_rad": 1e-05, "load_cell_n": 0.25,
                      "encoder_m": 1e-06, "process_m": 1e-4, "exit_m": 2.5e-05},
            "nuisance": {},
            "poses": {"kind": "list", "list": [[9.0, 4.0, 2.5, 0, 0, 0],
                                               [10.5, 5.5, 3.0, 0, 0, 0]],
                      "visits": 2, "dwell_s": 2.0, "rate_hz": 2.0, "init_s": 3.0},
            "recording": {"kind": "dwell", "dwell_at_targets": False, "state_column": True,
                          "tracker": False, "load_cells": True}}
    record(case, tmp_path)
    rec = read_recording(tmp_path)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions)
    idx = np.arange(s.n)
    assert rm.est_pose[~s.is_init].all()
    kept = rm.entry_kept(idx)
    q = rm.entry_kinds(idx) % 4
    n = rec.robot.n_cables
    init = rm._per_entry(s.is_init.astype(float), idx) > 0  # the encoders' reference: none
    assert init.any()
    np.testing.assert_allclose(kept[(q == 0) & ~init], (n - 6) / n)
    np.testing.assert_allclose(kept[(q == 0) & init], 0.0)
    np.testing.assert_allclose(kept[q != 0], 1.0)
    w = rm.entry_weights(idx)
    lost = rm.dof_lost(idx)
    assert abs(float(w @ kept) - (w.sum() - lost)) < 1e-9 * w.sum()
    e = error_structure(rm, idx, lost)
    np.testing.assert_array_equal(e.entry_kept, kept)
    assert e.kept == pytest.approx((w @ kept) / w.sum())
    lengths = q == 0
    assert e.kind_kept(lengths) == pytest.approx(float(w[lengths] @ kept[lengths])
                                                 / w[lengths].sum())
    assert e.kind_kept(lengths & ~init) == pytest.approx((n - 6) / n)
    # the kinds the poses do not project, and the initialisation's lengths alone (no level
    # of their own), stand in with the share the poses leave after the initialisation
    later = idx[~s.is_init[idx]]
    own = 1.0 - rm.dof_lost(later) / rm.entry_weights(later).sum()
    assert e.unknowns_kept == pytest.approx(own) and own > e.kept
    assert e.kind_kept(lengths & init) == e.unknowns_kept
    assert e.kind_kept(q == 1) == pytest.approx(e.unknowns_kept)
    assert error_structure(rm, idx).entry_kept is None  # (no unknowns counted: one share)
