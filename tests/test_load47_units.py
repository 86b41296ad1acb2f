"""Error units of a campaign with moves and dwells (issue 32, "What to build" 3; load47).

The replicate visits' tests (:mod:`bench.diagnosis.noise`) compare independent error units:
a dwell, or all rows of a move (they share the move's slow error). In the null
continuous_dwell campaigns 12819 and 12840 of the 200-case evaluation they read steps of
z 7-9: the units were neither independent nor alike. A dwell's deviation follows the move
that leaves it (correlation 0.89; 0.02 with the move arriving): the stop's slow error lasts
until the platform reaches its next target. And a move's unit was its rows' sum, whose
spread grows with their number while a dwell's does not: the F-test pooled both into one
spread that was neither's. Units are now a dwell with the move leaving it, and their means.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.diagnosis import noise


def test_a_dwell_is_one_unit_with_the_move_that_leaves_it():
    """Samples in time: dwell, 3 rows of move 0, dwell, dwell, 2 rows of move 1, dwell (the
    last): the first dwell joins move 0, the third move 1, the others stand alone."""
    kind = np.array([0, 1, 1, 1, 0, 0, 1, 1, 0])
    block = np.array([7, 0, 0, 0, 8, 9, 1, 1, 10])
    t = np.arange(9.0)
    order = np.array([3, 0, 8, 5, 1, 7, 2, 4, 6])  # (any sample order: time decides)
    s = SimpleNamespace(kind=kind[order], block=block[order], t=t[order], n=9)
    unit = np.empty(9, dtype=int)
    unit[order] = noise._units(s)
    assert unit[0] == unit[1] == unit[2] == unit[3]
    assert unit[5] == unit[6] == unit[7]
    assert len({unit[0], unit[4], unit[5], unit[8]}) == 4


def test_a_step_test_over_units_of_many_rows_and_of_one_keeps_its_false_alarm_rate():
    """Ten dwell targets visited three times (a unit of one sample each) and two moves
    visited three times (a unit of twelve rows each, sharing one slow error of the same
    spread as a dwell's, and a white error a tenth of it): no change. The F-test of a step
    after the first visits, at its 1 % level, fires in about 1 % of 400 draws (at most 3 %);
    with the units' sums, the moves' errors twelve times a dwell's in a spread pooled
    mostly from dwells, it fired in most."""
    rng = np.random.default_rng(47)
    n_d, n_m, rows, visits = 10, 2, 12, 3
    # per sample: group, unit, visit
    g_d = np.tile(np.arange(n_d), visits)
    v_d = np.repeat(np.arange(visits), n_d)
    u_d = np.arange(n_d * visits)
    g_m = np.tile(n_d + np.arange(n_m * rows), visits)
    v_m = np.repeat(np.arange(visits), n_m * rows)
    u_m = n_d * visits + np.repeat(np.arange(n_m * visits), rows)
    g, v, unit = np.r_[g_d, g_m], np.r_[v_d, v_m], np.r_[u_d, u_m]
    dof0 = float(n_d * visits + n_m * visits - (n_d + n_m))
    after = (v >= 1).astype(float)[:, None]
    U = noise._centre(after, g)
    fired = 0
    for _ in range(400):
        e = rng.normal(0.0, 1.0, unit.max() + 1)[unit] + np.where(
            unit >= n_d * visits, rng.normal(0.0, 0.1, len(unit)), 0.0)
        got = noise._ftest(noise._centre(e, g), U, unit, dof0, 1e-12)
        fired += got is not None and got[0] < 0.01
    assert fired <= 12, fired  # (this seed: 4; the sums: 153)
