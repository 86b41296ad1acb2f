"""The held-out check's noise (`Selector._heldout_sd`): independent errors give the
chi-square change its ``2 sqrt(d)``; errors a move's rows share, along which the two
fits' predictions differ, make it wider (two moves held out of a continuous recording,
whose shared errors a mast's bending followed, rejected the true mast at 4 deviations)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.diagnosis.select import Selector


def _selector(n_moves: int, rows: int) -> Selector:
    n = n_moves * rows
    moves = np.repeat(np.arange(n_moves), rows)
    cols = np.tile(np.arange(2), n // 2)
    rm = SimpleNamespace(
        entry_weights=lambda idx: np.ones(n), entry_kinds=lambda idx: np.full(n, 4),
        entry_columns=lambda idx: cols, entry_moves=lambda idx: moves,
        entry_blocks=lambda idx: moves, entry_directions=lambda idx: np.zeros(n),
        entry_knots=lambda idx, H=None: None)
    sel = Selector.__new__(Selector)
    sel.rm = rm
    return sel


def test_independent_errors_keep_the_plain_deviation():
    rng = np.random.default_rng(3)
    sel = _selector(40, 10)
    diff = rng.normal(0.0, 0.5, 400)
    d = float(diff @ diff)
    sds = [sel._heldout_sd(np.arange(400), diff, rng.normal(size=400)) for _ in range(20)]
    assert min(sds) >= 2.0 * np.sqrt(d) - 1e-9  # never below the independent errors'
    assert np.median(sds) < 1.3 * 2.0 * np.sqrt(d)


def test_errors_shared_along_the_difference_widen_it():
    rng = np.random.default_rng(4)
    sel = _selector(8, 50)
    diff = np.repeat(rng.normal(0.0, 0.3, 8), 50)  # the fits differ move by move
    d = float(diff @ diff)
    sds = []
    for _ in range(20):
        r = np.repeat(rng.normal(0.0, 1.0, 8), 50) + rng.normal(size=400)
        sds.append(sel._heldout_sd(np.arange(400), diff, r))
    # each move's 50 rows share an error as large as their own: sqrt(51) x the plain one
    assert np.median(sds) > 3.0 * 2.0 * np.sqrt(d)
