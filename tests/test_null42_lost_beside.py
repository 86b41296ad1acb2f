"""`select.lost_beside`: effects whose parameters no longer stand out by their own errors in
a fit beside a nuisance (the tensions at initialisation) give way to it; effects that do
stand out, and fits far from the data, keep theirs."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.fit import FitResult
from bench.diagnosis.select import lost_beside
from bench.diagnosis.space import ParamSpace
from controller.robot import resolve_robot


def _fit(z: float, reduced: float = 1.0) -> FitResult:
    """A fit of drum scales and length offsets beside the tensions at initialisation: the
    scales ``z`` standard errors from 1 each, the offsets 20, reduced chi-square
    ``reduced`` on 400 residuals."""
    robot = resolve_robot("ipanema").replace(init_internal=np.zeros(2))
    space = ParamSpace(robot, ("cable_length_offset", "drum_scale"))
    se = np.full(len(space), 1e-4)
    phi = space.neutral.copy()
    ds, dl = space.indices("drum_scale"), space.indices("cable_length_offset")
    phi[ds] += z * se[ds]
    phi[dl] += 20.0 * se[dl]
    n = 400
    return FitResult(space, phi, reduced * (n - len(space)), n, 0.0, se, np.diag(se ** 2),
                     True, "", n_free=len(space), n_eff=float(n))


@pytest.mark.parametrize("z", [0.0, 0.8, 1.5])
def test_scales_within_their_errors_give_way(z):
    assert lost_beside(_fit(z), ["drum_scale", "cable_length_offset"]) == ["drum_scale"]


@pytest.mark.parametrize("z", [4.0, 10.0])
def test_scales_that_stand_out_stay(z):
    assert lost_beside(_fit(z), ["drum_scale", "cable_length_offset"]) == []


def test_a_fit_far_from_the_data_decides_nothing():
    assert lost_beside(_fit(0.5, reduced=20.0), ["drum_scale", "cable_length_offset"]) == []


def test_an_effect_the_fit_lacks_is_not_judged():
    assert lost_beside(_fit(10.0), ["exit_point_offset"]) == []
