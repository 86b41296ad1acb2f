"""Which parameters a chosen effect reports: each one beyond its own uncertainty, or, when
none is alone but together they differ clearly, the fewest that must differ given the
others (a poorly known common mode must not hide one load cell 5 % low)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.fit import FitResult
from bench.diagnosis.report import effect_entries
from bench.diagnosis.space import ParamSpace
from controller.robot import resolve_robot

EFFECT = "load_cell_calibration"


def _fit(gain_dev: np.ndarray, rng: np.random.Generator) -> FitResult:
    """A load-cell fit whose gains share a common mode known to 2.5 % while their differences
    are known to 0.3 % (a recording without tracker poses); offsets at the model's values."""
    space = ParamSpace(resolve_robot("rocaspect"), (EFFECT,))
    gains = np.array([k for k, p in enumerate(space.params) if p.key.startswith("gain_")])
    n = len(gains)
    common = np.full((n, n), 0.025 ** 2)
    cov_g = common + np.eye(n) * 0.003 ** 2
    cov = np.diag(np.where([p.key.startswith("offset_") for p in space.params], 4.0, 0.0))
    cov[np.ix_(gains, gains)] = cov_g
    phi = space.neutral.copy()
    phi[gains] += gain_dev
    offsets = np.setdiff1d(np.arange(len(space)), gains)
    phi[offsets] += rng.normal(0.0, 0.1, len(offsets))
    se = np.sqrt(np.diag(cov))
    return FitResult(space, phi, 100.0, 1000, 150.0, se, cov, True, "test", n_free=len(space))


def test_one_cell_off_under_a_poorly_known_common_gain_is_named():
    rng = np.random.default_rng(1)
    dev = np.full(8, 0.007) + rng.normal(0, 0.002, 8)
    dev[7] = -0.047  # cable 42, 5 % below the others: 1.9 marginal standard errors
    params, errs, _ = effect_entries(_fit(dev, rng), [EFFECT])
    assert set(params[EFFECT]) == {"gain_42"}
    assert errs[EFFECT]["gain_42"] == pytest.approx(np.hypot(0.025, 0.003))


@pytest.mark.parametrize("seed", range(5))
def test_a_common_gain_within_its_uncertainty_or_noise_names_nothing(seed):
    rng = np.random.default_rng(seed)
    for dev in (np.full(8, 0.03) + rng.normal(0, 0.003, 8),  # the common mode, 1.2 se
                rng.normal(0, 0.003, 8)):  # the differences' noise
        params, _, _ = effect_entries(_fit(dev, rng), [EFFECT])
        assert params[EFFECT] == {}


@pytest.mark.parametrize("k_fit, se_rel, undetermined", [
    (4e4, 0.05, False),     # a soft mast, well known: reported
    (1e7, 0.05, False),     # stiff yet measurable: reported
    (6e12, 1e-3, True),     # run to the rigid bound with a tiny clipped error: not a number
    (4e4, 0.6, True),       # known only to 60 %: undetermined
    (1e3, 1e-4, True),      # run to the soft bound of the fit: not a number either
    (1.07e3, 1e-9, True),   # stopped near it with an absurdly small error: the same
    (2.5e3, 0.05, False),   # soft, yet clear of the bound: reported
])
def test_a_stiffness_at_the_rigid_bound_is_undetermined_not_reported(k_fit, se_rel,
                                                                      undetermined):
    space = ParamSpace(resolve_robot("rocaspect"), ("mast_compliance",))
    phi = space.neutral.copy()
    j = next(k for k, p in enumerate(space.params) if p.key.startswith("kx_"))
    phi[j] = 1.0 / k_fit
    se = np.full(len(space), 1e-9)
    se[j] = se_rel * phi[j]
    fit = FitResult(space, phi, 100.0, 1000, 150.0, se, np.diag(se ** 2), True, "test",
                    n_free=len(space))
    params, _, undet = effect_entries(fit, ["mast_compliance"])
    key = space.params[j].key
    assert (key in undet["mast_compliance"]) == undetermined
    assert (key in params["mast_compliance"]) == (not undetermined)


def _offset_fit(dl: np.ndarray, se: float) -> FitResult:
    space = ParamSpace(resolve_robot("rocaspect"), ("cable_length_offset",))
    phi = space.neutral + dl
    cov = np.eye(len(space)) * se ** 2
    return FitResult(space, phi, 100.0, 1000, 150.0, np.sqrt(np.diag(cov)), cov, True, "test",
                     n_free=len(space))


def test_a_length_offset_within_the_encoder_references_uncertainty_is_no_finding():
    """A slack, sagging cable's reference length hangs on its load cell's mean reading at
    initialisation: an offset from then on, within that uncertainty, is not named; beyond
    it, or with a reference known exactly, it is."""
    dl = np.zeros(8)
    dl[3] = 4.7e-4  # ten of its own standard errors, one of the reference's
    fit = _offset_fit(dl, 4.4e-5)
    floor = np.zeros(8)
    floor[3] = 4.6e-4 ** 2
    assert effect_entries(fit, ["cable_length_offset"])[0]["cable_length_offset"] \
        == {"dl_22": pytest.approx(4.7e-4)}
    assert effect_entries(fit, ["cable_length_offset"], floor)[0]["cable_length_offset"] == {}
    dl[3] = 3e-3  # a slip of 3 mm stands out of both
    params = effect_entries(_offset_fit(dl, 4.4e-5), ["cable_length_offset"], floor)[0]
    assert set(params["cable_length_offset"]) == {"dl_22"}
