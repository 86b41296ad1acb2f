"""The initialisation's samples carry no length error and no information: the error level of
a fit does not count them (issue 32, item 5: pulley_kinematics intervals without load cells).

The encoders are referenced at the initialisation: its readings are the reference, so its
length residuals are the initialisation's unstretched lengths against themselves whatever the
hypothesis (the tracker's noise at most), where every later visit carries its own error of the
lengths. Counted as residuals with their n - 6 degrees of freedom, they lowered the error level
the fit's residuals give: on an IPAnema-class dwell without load cells (13 samples) by 6 of 78
degrees of freedom, the reported standard errors 4 % small
(:meth:`bench.diagnosis.residuals.ResidualModel.dof_lost`). Branch pulley44's tests, landed with
the per-sample projection of the error model (tests/test_pulley45_projected_level.py)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.campaign import campaign_plant, run_campaign
from bench.diagnosis.fit import fit_effects
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.diagnosis.space import ParamSpace
from bench.evaluate import one_blas_thread
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario

R = 0.1157  # [m] every pulley's radius (the model's: 0.01)
#: IPAnema, dwells at 6 poses (a 3 x 2 grid, tilted) visited twice, tracker and encoders, no
#: load cells; the pulleys' radii of the truth, the tensions at referencing 36 N off the
#: distribution's
SCENARIO = {
    "format": "cdpr-scenario/1", "robot": "ipanema", "seed": 4301,
    "init_pose": [2.153, 1.620, 2.298, 0.0, 0.0, 0.0],
    "truth": {"pulley_kinematics": {f"r_{m}{k}": R for m in (1, 2, 3, 4) for k in (1, 2)}},
    "noise": {"tracker_m": 6e-5, "tracker_rad": 4e-5, "encoder_m": 1e-6, "process_m": 4e-4,
              "exit_m": 1e-4},
    "nuisance": {"init_pretension_n": 36.0},
    "poses": {"kind": "list", "visits": 2, "dwell_s": 3.0, "rate_hz": 2.0, "init_s": 4.0,
              "list": [[x, y, 2.9, *rpy] for (x, y), rpy in zip(
                  [(-2.8, -2.1), (0.0, -2.1), (2.8, -2.1), (-2.8, 2.1), (0.0, 2.1), (2.8, 2.1)],
                  [(0.023, -0.011, 0.015), (0.026, 0.016, 0.017), (0.019, 0.010, 0.002),
                   (-0.025, 0.006, -0.023), (-0.014, 0.025, 0.023), (0.004, -0.005, 0.020)],
                  strict=True)]},
    "recording": {"kind": "dwell", "tracker": True, "load_cells": False},
}


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """The recording's residual model (no load cells, the tensions at initialisation a
    fitted nuisance), its samples and the fit of the pulleys."""
    one_blas_thread()
    sc = parse_scenario(SCENARIO)
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("pulley44") / "rec",
                                      plant=campaign_plant(sc, predict=True)))
    assert rec.init_tensions is None
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, None, rows=s.triples)
    rm.estimate_noise(rec.robot)
    k = rm.init_basis.shape[1]
    rm.model = rm.model.replace(init_internal=np.zeros(k))
    space = ParamSpace(rm.model, ("pulley_kinematics",))
    return rm, space


def test_the_initialisation_s_length_residuals_are_nil_and_count_as_lost(case):
    """Whatever the radii, the initialisation's length residuals are far below the visits'
    error (its readings are the reference); :meth:`dof_lost` counts all n of them (old code:
    n - 6, as a visit's)."""
    rm, space = case
    s, n = rm.s, rm.model.n_cables
    init = np.flatnonzero(s.is_init & rm.has_len)
    later = np.flatnonzero(~s.is_init & rm.has_len)
    assert len(init) >= 1 and len(later) >= 12
    sd = rm.sigma["length"]
    for r in (0.01, 0.08, R):
        phi = space.neutral.copy()
        phi[:8] = r
        length = rm.blocks(space.robot(phi)).length
        assert np.nanmax(np.abs(length[init])) < 0.3 * sd, r
        assert np.sqrt(np.nanmean(length[later] ** 2)) > 0.5 * sd, r
    per_visit = n - rm.len_rank[later]
    assert np.all(per_visit == n - 6)
    assert rm.dof_lost(init) == pytest.approx(n * len(init))
    assert rm.dof_lost() == pytest.approx(n * len(init) + per_visit.sum())


def test_the_errors_do_not_change_with_the_initialisation_s_samples_in_the_fit(case):
    """Fitted with or without the initialisation's samples (which hold nothing of the radii),
    the pulleys' values and reported standard errors agree (old code: the errors 4 % smaller
    with them, the level divided by 6 degrees of freedom they do not have)."""
    rm, space = case
    every = np.arange(rm.s.n)
    later = np.flatnonzero(~rm.s.is_init)
    fits = [fit_effects(space, rm, idx, prune=False) for idx in (every, later)]
    for f in fits:
        assert f.success, f.message
    a, b = fits
    free = np.isfinite(a.stderr) & np.isfinite(b.stderr)
    assert free[:8].all()
    np.testing.assert_allclose(a.phi[:8], b.phi[:8], atol=0.05 * a.stderr[:8].min())
    np.testing.assert_allclose(a.stderr[free], b.stderr[free], rtol=0.015)
