"""``controller.pose.cross``: the components gathered (small arrays) or taken as views (large
ones, :data:`controller.pose.CROSS_VIEWS_MIN`) give the same numbers to the last bit, and
the cross product they are."""

from __future__ import annotations

import numpy as np
import pytest

from controller.pose import CROSS_VIEWS_MIN, cross

_I1 = np.array([1, 2, 0])
_I2 = np.array([2, 0, 1])


def _gathered(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The cross product as the gathered components give it (the small arrays' way)."""
    return a.take(_I1, axis=-1) * b.take(_I2, axis=-1) - a.take(_I2, axis=-1) * b.take(_I1, axis=-1)


@pytest.mark.parametrize("shapes", [((8, 3), (8, 3)), ((8, 3), (1, 8, 3)),
                                    ((300, 8, 3), (300, 8, 3)), ((8, 3), (300, 8, 3)),
                                    ((300, 8, 3), (3,)), ((40, 1, 3), (40, 8, 3))])
def test_both_ways_give_the_same_bits_and_the_cross_product(shapes):
    rng = np.random.default_rng(len(shapes[0]) * 1000 + shapes[-1][0])
    a = rng.normal(size=shapes[0]) * 10.0 ** rng.integers(-6, 6, size=shapes[0])
    b = rng.normal(size=shapes[1]) * 10.0 ** rng.integers(-6, 6, size=shapes[1])
    got = cross(a, b)
    assert got.shape == np.broadcast_shapes(a.shape, b.shape)
    assert np.array_equal(got, _gathered(a, b))  # bit for bit: no answer moves
    ref = np.cross(a, b)
    scale = np.linalg.norm(a, axis=-1, keepdims=True) * np.linalg.norm(b, axis=-1, keepdims=True)
    assert np.all(np.abs(got - ref) <= 1e-15 * scale)


def test_the_large_arrays_take_the_views():
    # the cases above cover both sides of the switch
    assert 2 * 8 * 3 < CROSS_VIEWS_MIN <= 2 * 300 * 8 * 3
