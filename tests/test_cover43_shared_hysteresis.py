"""The error by the direction of approach shared by the cables (``bench.diagnosis.fit``'s
direction components): hysteresis is one mechanism with one sign convention on every
winch, so a parameter every cable's column carries alike (one E·A, one sag density) sees
the cables' shares of it add up, not average out. Checked against the spread of the
estimates over many simulated data sets (a linear model fitted the way the diagnosis
whitens its residuals), with the hysteresis common to the cables and, where the shared
component must find nothing, drawn independently per cable around zero."""

from __future__ import annotations

import numpy as np

from bench.diagnosis.fit import ErrorStructure, standard_errors

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
