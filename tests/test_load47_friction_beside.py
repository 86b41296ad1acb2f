"""A load change beside friction located in time (issue 32, "What to build" 3; load47).

Friction at the pulleys or winches (outside the vocabulary) makes each visit's residuals
depend on the direction every cable came from: visits of one pose differ by far more than
their noise. Pooled as noise, that spread hid the force balance's step at a load change
(`cdpr evaluate --kind load_change` seeds 46103, 46108: the step 1.4 times the spread, below
``MIN_SIZE``; the recordings answered `unexplained` without the change's time). The step is
now also tried with the direction of travel fitted beside it, and the refinement of its
time scans around the best coarse time's better neighbour too (46108: the best coarse time
was 62 s after the change, beyond the best's neighbours).
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis import noise
from tests.residual_models import load_change_residual_model


@pytest.mark.parametrize("seed", [46103, 46108])
@pytest.mark.parametrize("factor", [None, 1.0])
def test_a_load_change_beside_friction_is_bracketed_and_friction_alone_is_no_step(
        tmp_path, seed, factor):
    """ROCASPECT dwell campaigns with friction, the load changed after the first visit of
    every pose: a step of the force balance placed between the last sample before the
    change and the first after it. The same campaigns without the change (mass factor 1),
    friction left: no step (a difference by direction may be said, no time)."""
    rm, case = load_change_residual_model(seed, factor, tmp_path)
    assert "friction" in case["case"]["oov"]
    t0 = float(case["case"]["change"]["t_s"])
    changes = noise.find_changes(rm, rm.blocks(rm.model))
    steps = [c for c in changes if c.kind == "step"]
    if factor is not None:
        assert steps == [], [c.entry() for c in steps]
        return
    assert steps, "the load change was not found"
    assert steps[0].block == "force"
    assert steps[0].before_s < t0 <= steps[0].after_s


def test_the_direction_regressors_hold_no_step_and_need_degrees_of_freedom():
    """`_beside_direction`: the sign of each cable's last move times its tension at the
    pose, the group's mean: a tension that steps with a load change (every sample of the
    group after the step 10 % higher) leaves the regressors as they were; too few degrees
    of freedom: none."""
    rng = np.random.default_rng(3)
    inv = np.repeat(np.arange(10), 4)
    d = rng.choice([-1.0, 1.0], size=(40, 4))
    tau = 100.0 + 50.0 * rng.random((10, 4))[inv]
    stepped = tau * np.where(np.arange(40) % 4 >= 1, 1.1, 1.0)[:, None]
    V0 = noise._beside_direction(d, tau, inv, 30.0)
    V1 = noise._beside_direction(d, stepped, inv, 30.0)
    assert V0 is not None and V0.shape == (40, 4)
    # (each group's mean tension 1.075 times: the same regressors, scaled; no step in them)
    np.testing.assert_allclose(V1, 1.075 * V0, rtol=1e-12)
    assert noise._beside_direction(d, tau, inv, 15.0) is None


def test_the_refinement_scans_beside_the_better_neighbour():
    """`_refined`: the candidates between the best coarse time's neighbours, and with the
    coarse p-values those around its better neighbour too."""
    coarse = np.arange(0.0, 100.0, 10.0)
    every = np.arange(0.5, 100.0, 1.0)
    p = np.full(len(coarse), 0.5)
    p[5], p[4], p[6] = 1e-9, 1e-8, 1e-3
    old = noise._refined(50.0, coarse, every)
    new = noise._refined(50.0, coarse, every, p)
    assert old.min() > 40.0 and old.max() < 60.0
    assert new.min() == pytest.approx(30.5) and new.max() == pytest.approx(59.5)
