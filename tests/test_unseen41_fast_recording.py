"""The logger's truth by the plant's predicted rest searches (``Plant.predict``) is the old
path's truth: the same rests, the same rows, in fewer evaluations of the energy gradient."""

from __future__ import annotations

import numpy as np
import pytest

import bench.campaign as campaign
import bench.logger_sim as logger_sim
from bench.evaluate import make_case, scenario_of
from bench.logger_sim import LoggerSpec, sample_log, simulate_truth
from firmware_sim.plant import Plant

#: a ROCASPECT logger case (compliant masts, a soft one among them; slip, two E*A)
SEED = 61041
#: [s] of its campaign simulated: the initialisation and the first moves
UNTIL_S = 14.0


@pytest.fixture(scope="module")
def case():
    c = make_case(SEED, kind="logger")
    c["truth"]["cable_length_offset"]["slip_time_11"] = 6.0
    return c


def _truths(monkeypatch, sc, tol: float | None):
    """Truth of the old path and of the fast one (plant tolerance ``tol``), and the
    number of energy-gradient evaluations each took."""
    made = campaign.campaign_plant
    calls = {"n": 0}
    gradient = Plant._gradient

    def counted(self, *a):
        calls["n"] += 1
        return gradient(self, *a)

    def plant(*a, **k):
        p = made(*a, **k)
        if tol is not None:
            p.tol = tol
        return p

    monkeypatch.setattr(logger_sim, "campaign_plant", plant)  # the logger's truth makes it
    monkeypatch.setattr(Plant, "_gradient", counted)
    out = []
    for predict in (False, True):
        calls["n"] = 0
        out.append((simulate_truth(sc, 25.0, until_s=UNTIL_S, predict=predict), calls["n"]))
    return out


def test_fast_path_gives_the_old_rows_to_1e9(case, monkeypatch):
    """With both searches converged tightly (1e-10 of the weight), every column of the
    logger's rows agrees to 1e-9 (m, rad; tensions relative): the same physics."""
    sc = scenario_of(case)
    (old, n_old), (new, n_new) = _truths(monkeypatch, sc, 1e-10)
    assert len(old.t) == len(new.t) > 200
    assert {"init", "move", "dwell"} <= set(old.label)  # moves on both sides of a dwell
    spec = LoggerSpec(**case["case"]["logger"])
    a, b = sample_log(sc, old, spec), sample_log(sc, new, spec)
    assert list(a) == list(b)
    for name in a:
        if a[name].dtype.kind in "USO":
            assert (a[name] == b[name]).all(), name
            continue
        assert (np.isnan(a[name]) == np.isnan(b[name])).all(), name
        scale = 1.0 if not name.startswith("tau_") else float(np.nanmax(np.abs(a[name])))
        np.testing.assert_allclose(b[name], a[name], rtol=0, atol=1e-9 * scale,
                                   equal_nan=True, err_msg=name)
    assert n_new < 0.5 * n_old  # the point of the fast path


def test_fast_path_at_the_plants_tolerance(case, monkeypatch):
    """At the default tolerance the rests differ by the searches' stopping points only
    (below 1e-7 m and 1e-3 N); commands, encoders and times are the same numbers."""
    sc = scenario_of(case)
    (old, _), (new, _) = _truths(monkeypatch, sc, None)
    for f in ("t", "pose_des", "l_cmd", "l_meas"):
        assert np.array_equal(getattr(old, f), getattr(new, f)), f
    assert np.abs(new.pose - old.pose).max() < 1e-7
    assert np.abs(new.exits - old.exits).max() < 1e-7
    assert np.abs(new.tau - old.tau).max() < 1e-3
    assert (new.label == old.label).all()


def test_prediction_only_continues_a_steady_motion(case):
    """The extrapolated start is offered only when a settle's time continues the spacing of
    the last two (not after a dwell, a pause or a turn at a target), and only with
    ``predict``."""
    sc = scenario_of(case)
    plant = campaign.campaign_plant(sc, predict=True)
    assert plant._predicted(0.0) is None  # nothing to extrapolate from
    l_ref = plant.reference
    plant.settle(l_ref, t=1.0)
    assert plant._predicted(1.04) is None  # one settle only
    plant.settle(l_ref - 1e-3, t=1.04)
    p = plant._predicted(1.08)
    assert p is not None
    a, b = plant._trail
    assert np.allclose(p.pose, 2 * b[1].pose - a[1].pose)
    assert not np.allclose(p.pose, b[1].pose)  # it moved
    assert plant._predicted(1.12) is None  # a step skipped
    assert plant._predicted(3.04) is None  # after a dwell
    off = campaign.campaign_plant(sc)
    off.settle(l_ref, t=1.0)
    off.settle(l_ref - 1e-3, t=1.04)
    assert off._predicted(1.08) is None
