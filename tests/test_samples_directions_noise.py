"""A cable's direction into a dwell (backlash, friction by direction) is set by changes beyond
the readings' own noise, and that noise is the readings' while they stand: on a continuous
recording at a low row rate the second differences of moving readings also hold the moves'
accelerations (60 um read for 5 um of noise), which hid a small reversal before a dwell."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.diagnosis.samples import _directions, _standing_noise

RATE_HZ = 15.0


def _profile(rng: np.random.Generator, noise_m: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(t, lengths (N, 1), the row of the last dwell): dwells of 1 s between smooth moves
    of 0.3 m in 4 s (most rows move), then a reversal of 40 um over three rows and a
    dwell."""
    t_move = np.arange(0.0, 4.0, 1.0 / RATE_HZ)
    s = 0.3 * (t_move / 4.0 - np.sin(2 * np.pi * t_move / 4.0) / (2 * np.pi))
    dwell = np.zeros(int(1 * RATE_HZ))
    parts, level = [], 10.0
    for sign in (1, -1, 1, -1, 1):
        parts += [level + dwell, level + sign * s]
        level += sign * s[-1]
    parts.append(level + dwell)
    back = level - np.array([13e-6, 27e-6, 40e-6])
    parts += [back, back[-1] + dwell]
    x = np.concatenate(parts)
    x = x + rng.normal(0.0, noise_m, x.size)
    t = np.arange(x.size) / RATE_HZ
    return t, x[:, None], x.size - 5


def test_a_small_reversal_before_a_dwell_sets_the_direction():
    rng = np.random.default_rng(3)
    t, x, last = _profile(rng, 2e-6)
    rec = SimpleNamespace(t=t, l_meas=x, l_cmd=np.full_like(x, np.nan))
    assert _directions(rec, np.array([last]))[0, 0] == -1.0


def test_the_noise_of_standing_readings_is_theirs():
    rng = np.random.default_rng(4)
    t, x, _ = _profile(rng, 5e-6)
    d = np.zeros_like(x)
    d[1:] = np.diff(x, axis=0)
    got = _standing_noise(t, x, d)[0]
    assert 3.5e-6 < got < 6.5e-6


def test_no_standing_rows_no_noise():
    t = np.arange(100) / RATE_HZ
    x = (0.1 * t ** 2)[:, None]
    d = np.zeros_like(x)
    d[1:] = np.diff(x, axis=0)
    assert _standing_noise(t, x, d)[0] == 0.0
