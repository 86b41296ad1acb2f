"""Steps in a cable's length residual over time (`bench.diagnosis.locate.steps_in_time`):
measured within targets, so pose-dependent model errors cancel; tested through the
replicated samples even where the rows of moves, unreplicated, are most of a recording."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.diagnosis.locate import steps_in_time

SIGMA = 8e-4  # [m]


def _recording(rng: np.random.Generator, step: float = 0.0, t_step: float = 60.0,
               cable: int = 1):
    """Seven dwell targets visited three times over 180 s with 12 rows of moves between
    visits (unreplicated, 80 % of the samples); pose errors of centimetres per target,
    a ramp along each move; ``step`` [m] on ``cable`` from ``t_step`` on. Two cables."""
    t, tg, r = [], [], []
    clock, nxt = 5.0, 100
    for _visit in range(3):
        for k in range(7):
            for j in range(12):  # a move: its own targets, a ramp of the model's error
                t.append(clock)
                tg.append(nxt)
                nxt += 1
                r.append(np.full(2, 1e-3 * j))
                clock += 0.3
            t.append(clock)
            tg.append(k)
            r.append(np.zeros(2))
            clock += 5.0
    t, tg = np.array(t), np.array(tg)
    pose_err = rng.normal(0, 0.02, (nxt, 2))
    L = pose_err[tg] + np.array(r) + rng.normal(0, SIGMA, (len(t), 2))
    L[t >= t_step, cable] += step
    s = SimpleNamespace(t=t, target=tg, is_init=np.zeros(len(t), dtype=bool))
    return s, L


def test_a_slip_between_the_dwells_of_a_mostly_moving_recording_is_found():
    rng = np.random.default_rng(3)
    s, L = _recording(rng, step=-5 * SIGMA, t_step=60.0)
    found = steps_in_time(s, L, SIGMA, ("11", "21"))
    assert [f["cable"] for f in found] == ["21"]
    assert abs(found[0]["step_m"] + 5 * SIGMA) < 1.5 * SIGMA
    # placed between the last dwell before the slip and the first after it, at the row
    # pair where the reading jumps
    assert abs(found[0]["t_s"] - 60.0) < 1.0


def test_no_slip_no_step_and_none_before_the_initialisation_ends():
    for seed in range(20):
        s, L = _recording(np.random.default_rng(seed))
        assert steps_in_time(s, L, SIGMA, ("11", "21")) == [], seed
    s, L = _recording(np.random.default_rng(0), step=-10 * SIGMA, t_step=60.0)
    assert steps_in_time(s, L, SIGMA, ("11", "21"), t_after=130.0) == []
