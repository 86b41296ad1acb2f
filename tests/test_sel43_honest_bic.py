"""`select.design_effect` and `select.honest_bic`: a set's BIC against a fit that holds it and
more, the chi-square's difference counted by the evidence the parameters' own errors give.

Rows of a continuous recording share the visit's error of the lengths: the chi-square's drop
of an effect is then several times its (sandwich) Wald statistic, and the plain BIC names
effects the errors do not bear out. These fits are built by hand: eight drum scales ``z``
standard errors from 1 beside length offsets 20 standard errors off and the tensions at
initialisation (a recording without load cells), the naive covariance ``(J^T J)^-1`` a
``share`` of the sandwich's (rows sharing errors), the chi-square without the scales higher by
their naive Wald statistic (a linear fit).
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.fit import FitResult, bic
from bench.diagnosis.select import BIC_ENTER, design_effect, honest_bic, wald_statistic
from bench.diagnosis.space import ParamSpace
from controller.robot import resolve_robot

N = 1000
EFFECTS = ("cable_length_offset", "drum_scale")


def _robot():
    return resolve_robot("ipanema").replace(init_internal=np.zeros(2))


def _fit(space: ParamSpace, phi: np.ndarray, chi2: float, se: np.ndarray, share: float
         ) -> FitResult:
    return FitResult(space, phi, chi2, N, bic(chi2, len(space), N), se, np.diag(se ** 2), True,
                     "", n_free=len(space), n_eff=float(N),
                     curvature_cov=np.diag(se ** 2) / share)


def _whole(z: float, share: float = 4.0, reduced: float = 1.0) -> FitResult:
    space = ParamSpace(_robot(), EFFECTS)
    se = np.full(len(space), 1e-4)
    phi = space.neutral.copy()
    phi[space.indices("drum_scale")] += z * se[space.indices("drum_scale")]
    phi[space.indices("cable_length_offset")] += 20.0 * se[space.indices("cable_length_offset")]
    return _fit(space, phi, reduced * (N - len(space)), se, share)


def _without_scales(whole: FitResult, share: float = 4.0) -> FitResult:
    """The fit without the drum scales: chi-square higher by their naive Wald statistic."""
    space = ParamSpace(_robot(), ("cable_length_offset",))
    ix = whole.space.indices("drum_scale")
    d = (whole.phi - whole.space.neutral)[ix]
    rise = float(np.sum(d ** 2 / np.diag(whole.curvature_cov)[ix]))
    keep = np.setdiff1d(np.arange(len(whole.space)), ix)
    return _fit(space, whole.phi[keep], whole.chi2 + rise, whole.stderr[keep], share)


def test_design_effect_is_the_naive_over_the_robust_wald():
    assert design_effect(_whole(3.0, share=4.0), ["drum_scale"]) == pytest.approx(4.0)
    # by indices too (the tensions at initialisation are no effect of the space)
    whole = _whole(3.0)
    ix = whole.space.indices("drum_scale")
    assert design_effect(whole, ix) == pytest.approx(4.0)


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_independent_errors_give_the_plain_bic(share):
    """Errors as stated (or the sandwich surer than them): the plain BIC's difference."""
    whole = _whole(2.2, share=share)
    small = _without_scales(whole, share)
    assert design_effect(whole, ["drum_scale"]) == 1.0
    assert honest_bic(small, whole) == pytest.approx(small.bic - whole.bic)


@pytest.mark.parametrize("z", [1.8, 2.2, 2.5])
def test_scales_within_their_errors_give_way(z):
    """Eight scales at 1.8 to 2.5 standard errors each: the plain BIC keeps them by more
    than BIC_ENTER (at 2.2 chi-square 155 for 8 parameters), the honest one does not (Wald
    39)."""
    whole = _whole(z)
    small = _without_scales(whole)
    assert honest_bic(small, whole) < BIC_ENTER
    if z == 2.2:
        assert small.bic - whole.bic > BIC_ENTER  # the bug: the plain BIC names them
        assert wald_statistic(whole, "drum_scale")[0] == pytest.approx(8 * z ** 2)


@pytest.mark.parametrize("z", [4.0, 10.0])
def test_scales_that_stand_out_stay(z):
    """A true weak effect (eight scales at 4 standard errors: Wald 128 against a charge of
    55) is still worth more than BIC_ENTER by its own errors."""
    whole = _whole(z)
    assert honest_bic(_without_scales(whole), whole) > BIC_ENTER


def test_a_fit_far_from_the_data_keeps_the_plain_bic():
    """Where the fit leaves far more than the noise, its errors measure a misfit."""
    whole = _whole(2.2, reduced=20.0)
    small = _without_scales(whole)
    assert design_effect(whole, ["drum_scale"]) == 1.0
    assert honest_bic(small, whole) == pytest.approx(small.bic - whole.bic)


def test_a_set_the_fit_does_not_hold_keeps_the_plain_bic():
    whole = _whole(2.2)
    other = ParamSpace(_robot(), ("exit_point_offset",))
    f = _fit(other, other.neutral.copy(), whole.chi2 + 300.0, np.full(len(other), 1e-4), 4.0)
    assert honest_bic(f, whole) == pytest.approx(f.bic - whole.bic)


def test_an_effect_the_fit_lacks_or_at_the_model_is_not_judged():
    whole = _whole(0.0)
    assert design_effect(whole, ["exit_point_offset"]) == 1.0
    assert design_effect(whole, ["drum_scale"]) == 1.0  # (every scale at the model's)


def test_parameters_held_at_the_model_count_as_lacking():
    """A fit on the whole's space with the scales held at the model's values (standard
    error inf, as pruning or a gauge leaves them) is judged as the fit without them."""
    whole = _whole(2.2)
    small = _without_scales(whole)
    ix = whole.space.indices("drum_scale")
    phi = whole.phi.copy()
    phi[ix] = whole.space.neutral[ix]
    se = whole.stderr.copy()
    se[ix] = np.inf
    held = FitResult(whole.space, phi, small.chi2, N, small.bic, se, np.diag(np.where(
        np.isfinite(se), se, 0.0) ** 2), True, "", n_free=len(small.space), n_eff=float(N),
        curvature_cov=np.diag(np.where(np.isfinite(se), se, 0.0) ** 2) / 4.0)
    assert honest_bic(held, whole) == pytest.approx(honest_bic(small, whole))
    assert honest_bic(held, whole) < BIC_ENTER < held.bic - whole.bic
