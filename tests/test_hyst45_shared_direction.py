"""The error by the direction of approach shared by the cables (``bench.diagnosis.fit``'s
direction components): hysteresis is one mechanism with one sign convention on every
winch, so a parameter every cable's column carries alike (one E·A, one sag density) sees
the cables' shares of it add up, not average out. Checked against the spread of the
estimates over many simulated data sets (a linear model fitted the way the diagnosis
whitens its residuals), with the hysteresis common to the cables and, where the shared
component must find nothing, drawn independently per cable around zero."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.fit import (
    ErrorStructure,
    _KindGroups,
    error_structure,
    fd_jacobian,
    standard_errors,
)
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.diagnosis.space import ParamSpace
from bench.evaluate import one_blas_thread, record
from bench.recording import read_recording

CABLES, PER = 8, 40


def _design() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-cable offsets and one slope every cable carries (like 1/E·A: a tension-like
    column that follows the direction of approach a little), directions two thirds one
    way; (X, directions, cable of each entry)."""
    n = CABLES * PER
    col = np.repeat(np.arange(CABLES), PER)
    rng = np.random.default_rng(5)
    s = np.where(rng.random(n) < 2 / 3, 1.0, -1.0)
    x = rng.uniform(0.0, 2.0, n) + 0.2 * s
    X = np.column_stack([(col[:, None] == np.arange(CABLES)).astype(float), x])
    return X, s, col


def _spread_and_se(shared: float, own: float, reps: int = 300) -> tuple[float, float]:
    """Spread of the slope's estimate over ``reps`` data sets and its rms standard error;
    each cable's hysteresis ``h_a = shared * g + own * g_a`` (g, g_a standard normal, new
    per data set) times its directions, plus independent noise 0.3."""
    X, s, col = _design()
    n = len(col)
    rng = np.random.default_rng(11)
    est, ses = [], []
    for _ in range(reps):
        h = shared * rng.normal() + own * rng.normal(0.0, 1.0, CABLES)
        y = X @ np.r_[np.zeros(CABLES), 0.5] + h[col] * s + rng.normal(0.0, 0.3, n)
        beta = np.linalg.lstsq(X, y, rcond=None)[0]
        r = y - X @ beta
        e = ErrorStructure(np.ones(n), np.zeros(n, int), col, np.arange(n), np.zeros(n, int),
                           float(n), s)
        _, se = standard_errors(X, float(r @ r), float(n), r=r, errors=e)
        est.append(beta[-1])
        ses.append(se[-1])
    return float(np.std(est)), float(np.sqrt(np.mean(np.square(ses))))


def test_a_hysteresis_every_cable_shares_widens_a_parameter_every_cable_carries():
    """The same hysteresis on every cable: the slope's error is the eight cables' shares
    added (paired within a cable only, its standard error was about a third of the
    spread)."""
    spread, se = _spread_and_se(shared=1.0, own=0.0)
    assert abs(se / spread - 1.0) < 0.25, (se, spread)


def test_a_hysteresis_of_each_cable_its_own_is_not_counted_as_shared():
    """Each cable's hysteresis its own, around zero: nothing shared to find, the slope's
    standard error stays its spread (the shared component does not widen it)."""
    spread, se = _spread_and_se(shared=0.0, own=1.0)
    assert abs(se / spread - 1.0) < 0.2, (se, spread)


def test_a_shared_part_beside_each_cable_s_own():
    """A shared part and each cable's own beside it: both counted."""
    spread, se = _spread_and_se(shared=0.7, own=0.7)
    assert abs(se / spread - 1.0) < 0.25, (se, spread)


# ----- on a generated recording's own design --------------------------------------------

#: [m] half the winches' hysteresis drawn in :func:`_generated_spread` (0.15 mm between the
#: two directions of approach, the evaluation's upper range)
HALF_HYSTERESIS = 7.5e-5


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> tuple:
    """An IPAnema-class dwell campaign with a tracker and load cells (a 3 x 3 grid visited
    twice, nothing concealed): its whitened residual vector's Jacobian of the one E·A at the
    model's value, its error structure, and how the whitened residuals move per metre of each
    cable's length error by the direction of approach
    (:meth:`~bench.diagnosis.residuals.ResidualModel.direction_columns`)."""
    one_blas_thread()
    rec_dir = tmp_path_factory.mktemp("hyst45") / "rec"
    record({"format": "cdpr-scenario/1", "robot": "ipanema", "seed": 5,
            "init_pose": [0.0, 0.0, 2.7, 0.0, 0.0, 0.0], "truth": {}, "nuisance": {},
            "poses": {"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2,
                      "x": [-2.2, 2.2], "y": [-1.5, 1.5], "z": [2.3, 3.2],
                      "dwell_s": 3.0, "rate_hz": 2.0, "init_s": 4.0},
            "recording": {"kind": "dwell", "tracker": True, "load_cells": True,
                          "state_column": True}}, rec_dir)
    rec = read_recording(rec_dir)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    idx = np.arange(s.n)
    space = ParamSpace(rm.model, ("cable_elasticity",))
    H = space.robot(space.neutral)
    r0 = rm.whitened(H, idx)
    J = fd_jacobian(lambda z: rm.whitened(space.robot(z), idx), space.neutral, r0,
                    space.scale * 1e-2, space.lo, space.hi, rm.frozen)
    lost = rm.dof_lost(idx)
    X = rm.direction_columns(H, idx, every=True)[0]
    return J * space.scale, error_structure(rm, idx, lost, H), lost, X


def _generated_spread(generated: tuple, shared: float, own: float, reps: int = 300
                      ) -> tuple[float, float]:
    """Over ``reps`` draws of the generated recording's errors (unit white noise and each
    cable's hysteresis ``HALF_HYSTERESIS * (shared g + own g_a)`` by its directions, g and
    g_a standard normal, new each draw), fitted linearly as the diagnosis fits: the spread
    of the E·A estimate and its rms standard error (in the fit's units)."""
    J, e, lost, X = generated
    rng = np.random.default_rng(45)
    est, ses = [], []
    for _ in range(reps):
        h = HALF_HYSTERESIS * (shared * rng.normal() + own * rng.normal(size=X.shape[1]))
        y = rng.normal(size=len(J)) + X @ h
        b = np.linalg.lstsq(J, y, rcond=None)[0]
        r = y - J @ b
        _, se = standard_errors(J, float(r @ r), e.n_eff - lost, None, r, e.stretches, e)
        est.append(b[0])
        ses.append(se[0])
    return float(np.std(est)), float(np.sqrt(np.mean(np.square(ses))))


def test_a_generated_campaigns_shared_hysteresis_is_in_its_elasticitys_error(generated):
    """The winches' hysteresis the same on every cable (75 um each way, of either sign), on
    a generated IPAnema-class dwell campaign's own directions, targets and weights: the one
    E·A's standard error is its spread over the draws (paired within a cable only, 0.73 of
    it)."""
    spread, se = _generated_spread(generated, shared=1.0, own=0.0)
    assert 0.85 < se / spread < 1.25, (se, spread)


@pytest.mark.parametrize("own", [1.0, 0.0], ids=["own_hysteresis", "none"])
def test_without_a_shared_hysteresis_the_generated_errors_do_not_move(generated, own,
                                                                      monkeypatch):
    """Each cable's hysteresis its own, or none: the shared component finds nothing; the
    E·A's standard error is the one without it (within 5 %) and still its spread."""
    spread, se = _generated_spread(generated, shared=0.0, own=own)
    monkeypatch.setattr(_KindGroups, "shared_direction", lambda self, cs, cd: 0.0)
    _, se_without = _generated_spread(generated, shared=0.0, own=own)
    assert abs(se / se_without - 1.0) < 0.05, (se, se_without)
    assert 0.85 < se / spread < 1.25, (se, spread)
