"""A length residual by the direction of approach that the cables share
(:func:`bench.diagnosis.unexplained.common_direction`): the winches' hysteresis is part of the
noise model (an error every cable shares, a fraction of the noise) and is not declared; a
common error by direction several times the residuals' random spread is (friction behind the
load cells read into the stretch, a hysteresis far beyond the noise)."""

from __future__ import annotations

import numpy as np

from bench.diagnosis.unexplained import common_direction, common_direction_found

CABLES = 8


def _residuals(n: int, half: np.ndarray | float, seed: int, pose_sd: float = 0.0,
               offset: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Length residuals (n, 8) in noise units: an offset per cable (``offset`` plus a
    spread of 0.5), ``half`` times each cable's direction of approach (+-1: most cables of a
    sample move alike, two thirds of the samples one way; a few zeros), unit noise per
    entry and an error of the pose every cable of a sample shares (``pose_sd``)."""
    rng = np.random.default_rng(seed)
    way = np.where(rng.random(n) < 2 / 3, 1.0, -1.0)
    d = way[:, None] * np.where(rng.random((n, CABLES)) < 0.2, -1.0, 1.0)
    d[rng.random((n, CABLES)) < 0.05] = 0.0
    L = offset + rng.normal(0.0, 0.5, CABLES)[None, :] + np.asarray(half) * d \
        + rng.normal(0.0, 1.0, (n, CABLES)) + rng.normal(0.0, pose_sd, (n, 1))
    return L, d, np.ones(n)


def test_a_common_direction_well_beyond_the_noise_is_found():
    """Every cable 2 noise units apart by direction (half 1): found, at its size."""
    half, z, over = common_direction(*_residuals(40, 1.0, 1))
    assert abs(half - 1.0) < 0.25 and abs(over - 1.0) < 0.3
    assert z > 8.0
    half, z, over = common_direction(*_residuals(40, 2.0, 2))
    assert common_direction_found(half, z, over), (half, z, over)


def test_the_winches_hysteresis_a_fraction_of_the_noise_is_not_declared():
    """The same hysteresis on every winch at 0.7 of the noise (the simulator draws at most
    about that): significant over many samples, not a finding."""
    for seed in range(5):
        half, z, over = common_direction(*_residuals(2000, 0.7, seed))
        assert z > 8.0  # it is there ...
        assert not common_direction_found(half, z, over), (half, z, over)  # ... but noise


def test_each_cable_s_own_direction_error_is_not_common():
    """Half the cables +2, half -2 by direction: nothing the cables share."""
    halves = np.array([2.0, -2.0] * (CABLES // 2))
    half, z, over = common_direction(*_residuals(60, halves, 3))
    assert abs(half) < 0.3
    assert not common_direction_found(half, z, over)


def test_an_error_of_the_pose_every_cable_shares_does_not_make_a_direction():
    """No error by direction, a large error of the pose shared by a sample's cables: the
    z-value stays a normal deviate's (the error counted once per sample, not per entry)."""
    zs = [common_direction(*_residuals(30, 0.0, seed, pose_sd=3.0))[1] for seed in range(40)]
    assert float(np.std(zs)) < 1.6, zs
    assert max(abs(z) for z in zs) < 5.0


def test_an_offset_of_every_cable_is_not_a_direction():
    """Every cable 3 noise units off, no error by direction, most samples approached one
    way: each cable's mean is its own, nothing by direction."""
    half, z, over = common_direction(*_residuals(60, 0.0, 6, offset=3.0))
    assert abs(half) < 0.3 and abs(z) < 4.0, (half, z)


def test_too_few_cables_with_both_directions_give_nothing():
    """Fewer than three cables moved both ways: no common figure."""
    L, d, w = _residuals(30, 1.0, 4)
    d[:, 2:] = 1.0
    assert common_direction(L, d, w) is None
