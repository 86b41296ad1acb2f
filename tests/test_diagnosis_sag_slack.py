"""A sagging cable whose load cell reads less than any catenary of its span pulls at its top
(no solution: the reading is noise about a slack cable, or the hypothesis is far off) says
only that the cable is at least as long as the straight line, like a slack reading: its
length residual is one-sided, never Newton's last iterate (metres off, either sign)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from residual_models import campaign_residual_model


@pytest.fixture(scope="module")
def sagging(tmp_path_factory):
    return campaign_residual_model(tmp_path_factory.mktemp("rec") / "rec",
                                   {"cable_sag": {"rho": 0.08}})


def test_a_reading_no_catenary_can_hang_at_is_one_sided(sagging):
    rm = copy.deepcopy(sagging)
    H = rm.model.replace(rho=0.08)
    k = int(np.flatnonzero(rm.has_tau & rm.has_len & ~rm.s.is_init)[0])
    before = rm.blocks(H)
    assert np.abs(before.length[k]).max() < 0.05  # the hypothesis holds: millimetres
    low = 3.0  # N: less than the weight of any of its spans (>= 8 m of 0.08 kg/m)
    assert low > rm.slack_threshold
    rm.s.tau[k, 2] = low
    b = rm.blocks(H)
    assert b.slack[k, 2]
    assert 0.0 <= b.length[k, 2] < 0.05
    others = np.ones(rm.model.n_cables, dtype=bool)
    others[2] = False
    np.testing.assert_allclose(b.length[k, others], before.length[k, others], atol=1e-9)
    # nothing changes where every cable hangs
    assert not before.slack[k].any()
