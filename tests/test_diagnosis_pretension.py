"""Tensions at initialisation that no load cell read (`report._pretension`).

The encoders are referenced under the tensions of the initialisation; without load cells
there, the diagnosis assumed the model's tension distribution. Another controller's (or an
operator's) pretension shortens every cable's unstretched length by its stretch: constant
offsets in the wrench matrix's null space, which were named as length offsets on every
cable (an independent generator's IPAnema-class recording: 14-15 mm on all eight). The
internal forces at initialisation are now fitted where a chosen effect, dropped for them,
leaves a lower BIC.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis.report import diagnose
from bench.diagnosis.space import PRETENSION, ParamSpace
from bench.evaluate import one_blas_thread
from controller.kinematics import wrench_matrix
from controller.robot import resolve_robot
from controller.statics import init_statics, internal_basis, pretensioned
from firmware_sim.scenario import parse_scenario

SCENARIO = (Path(__file__).parent / "data" / "scenarios"
            / "pretension_ipanema_no_tensions_30008.json")


@pytest.fixture(scope="module")
def ipanema():
    return resolve_robot("ipanema")


def test_pretension_keeps_the_balance(ipanema):
    p0 = np.array([0.0, 0.0, 2.7, 0.0, 0.0, 0.0])
    ps = init_statics(ipanema, p0)
    W = wrench_matrix(ps.state)
    basis = internal_basis(W)
    assert basis.shape == (8, 2) and np.allclose(W @ basis, 0.0, atol=1e-9)
    assert np.allclose(pretensioned(ipanema, p0, np.zeros(2), basis), ps.tensions)
    tau = pretensioned(ipanema, p0, np.array([40.0, -25.0]), basis)
    assert np.linalg.norm(tau - ps.tensions) == pytest.approx(np.hypot(40.0, 25.0), rel=1e-6)
    np.testing.assert_allclose(W @ tau, W @ ps.tensions, atol=1e-6)  # the same balance


def test_the_nuisance_is_fitted_never_reported(ipanema):
    flagged = ipanema.replace(init_internal=np.zeros(2))
    space = ParamSpace(flagged, ("cable_length_offset",))
    assert len(space) == 8 + 2 and len(ParamSpace(ipanema, ("cable_length_offset",))) == 8
    phi = space.neutral.copy()
    phi[0], phi[-2:] = 0.002, (30.0, -10.0)
    assert PRETENSION not in space.values(phi)
    H = space.robot(phi)
    assert np.allclose(H.init_internal, [30.0, -10.0]) and H.length_offset[0] == 0.002
    np.testing.assert_allclose(space.phi_of(H), phi)
    assert ParamSpace(ipanema, ()).robot(np.zeros(0)).init_internal is None


@pytest.mark.parametrize("pretension", [True, False])
def test_a_pretension_is_not_named_as_length_offsets(tmp_path, pretension):
    """IPAnema-class dwell campaign without load cells, nothing concealed, the tensions at
    referencing 153 N (internal forces) off the distribution's (case 30008 of the
    evaluation): length offsets on cables 11, 12, 31 and 32 were named. Must find
    nothing, and without the pretension must fit none."""
    one_blas_thread()
    scenario = json.loads(SCENARIO.read_text())
    if not pretension:
        scenario["nuisance"].pop("init_pretension_n")
    rep = diagnose(run_campaign(parse_scenario(scenario), tmp_path / "rec")).report
    assert rep["effects"] == [], rep["mismatch"]["summary"]
    assert ("init_tensions" in rep["mismatch"]) == pretension, rep["mismatch"]["summary"]
