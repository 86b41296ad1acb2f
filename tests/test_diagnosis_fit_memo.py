"""A fit asked for again with the same inputs is the one made before (a copy), not made again;
any change of what the fit hangs on (start, held parameters, samples, the residual model's
noise) fits anew."""

from __future__ import annotations

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis import fit as fit_module
from bench.diagnosis.fit import fit_effects
from bench.diagnosis.report import split_samples
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import check_values, prepare
from bench.diagnosis.space import ParamSpace
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"drum_scale": {"s_21": 1.004}}, "nuisance": {},
        "poses": {"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2},
        "recording": {}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("memo") / "rec"))
    check_values(rec)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return rm, split_samples(s, rec.init_pose)[0]


@pytest.fixture
def evaluations(problem, monkeypatch):
    rm, _ = problem
    count = []
    real = type(rm).blocks

    def counted(self, *a, **kw):
        count.append(1)
        return real(self, *a, **kw)

    monkeypatch.setattr(type(rm), "blocks", counted)
    return count


def test_the_same_fit_again_is_not_made_again(problem, evaluations):
    rm, train = problem
    space = ParamSpace(rm.model, ("drum_scale",))
    first = fit_effects(space, rm, train)
    assert evaluations
    evaluations.clear()
    again = fit_effects(space, rm, train)
    assert not evaluations  # no residual evaluated
    assert again is not first
    np.testing.assert_array_equal(again.phi, first.phi)
    np.testing.assert_array_equal(again.stderr, first.stderr)
    assert again.chi2 == first.chi2 and again.bic == first.bic
    # a copy: what its user adds (the gauge's floor on the errors) stays its own
    again.bias_var = np.ones(len(space))
    again.phi[0] += 1.0
    third = fit_effects(space, rm, train)
    assert third.bias_var is None or not np.array_equal(third.bias_var, again.bias_var)
    np.testing.assert_array_equal(third.phi, first.phi)


def test_any_change_of_what_a_fit_hangs_on_fits_anew(problem, evaluations):
    rm, train = problem
    space = ParamSpace(rm.model, ("drum_scale",))
    base = fit_effects(space, rm, train)
    changes = [
        lambda: fit_effects(space, rm, train, base.phi),  # another start
        lambda: fit_effects(space, rm, train, hold=np.arange(len(space)) == 0),
        lambda: fit_effects(space, rm, train[:-3]),  # other samples
        lambda: fit_effects(space, rm, train, prune=False),
        lambda: fit_effects(space, rm, train, max_nfev=3),
        lambda: fit_effects(ParamSpace(rm.model, ("cable_length_offset",)), rm, train),
    ]
    for make in changes:
        evaluations.clear()
        make()
        assert evaluations
    # the residual model's noise changed: its whitening, so the fit, is another
    saved = {k: v.copy() for k, v in rm.sd.items()}
    try:
        rm.sd["length"] = rm.sd["length"] * 1.5
        evaluations.clear()
        other = fit_effects(space, rm, train)
        assert evaluations and other.chi2 < base.chi2
    finally:
        rm.sd = saved


def test_a_change_of_the_fit_settings_fits_anew(problem, evaluations, monkeypatch):
    rm, train = problem
    space = ParamSpace(rm.model, ("drum_scale",))
    fit_effects(space, rm, train, prune=False)
    monkeypatch.setattr(fit_module, "SECANT_MIN", 10**6)
    evaluations.clear()
    fit_effects(space, rm, train, prune=False)
    assert evaluations


# ----- pruning: a pruned fit the full fit's curvature says the BIC refuses is not made ------

def _counted_fits(monkeypatch) -> list:
    calls = []
    real = fit_module._fit

    def counted(*a, **kw):
        calls.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(fit_module, "_fit", counted)
    return calls


def test_pruning_cost_is_the_held_departures_distance_under_the_curvature():
    space = type("S", (), {"neutral": np.zeros(3)})()
    curv = np.diag([4.0, 1.0, 9.0])
    res = fit_module.FitResult(space, np.array([2.0, 0.5, 3.0]), 0.0, 10, 0.0, np.ones(3),
                               np.eye(3), True, "", curvature_cov=curv)
    weak = np.array([True, False, True])
    assert fit_module.pruning_cost(res, weak) == pytest.approx(2.0 ** 2 / 4 + 3.0 ** 2 / 9)
    res.curvature_cov = None  # no curvature known: no prediction, the pruned fit is made
    assert fit_module.pruning_cost(res, weak) == 0.0


def test_a_hopeless_pruning_is_not_fitted_and_the_answer_is_the_same(problem, monkeypatch):
    rm, train = problem
    # length offsets on a recording whose error is one drum's scale: the offsets within two
    # (widened) standard errors of zero carry far more chi-square than they would save
    space = ParamSpace(rm.model, ("cable_length_offset",))
    calls = _counted_fits(monkeypatch)
    monkeypatch.setattr(fit_module, "PRUNE_HOPELESS", np.inf)
    made = fit_effects(space, rm, train)
    n_made = len(calls)
    calls.clear()
    monkeypatch.setattr(fit_module, "PRUNE_HOPELESS", 10.0)
    skipped = fit_effects(space, rm, train)
    assert len(calls) < n_made
    assert skipped.chi2 == made.chi2 and skipped.n_free == made.n_free
    np.testing.assert_array_equal(skipped.phi, made.phi)


def test_a_pruning_the_bic_takes_is_still_made(problem, monkeypatch):
    rm, train = problem
    space = ParamSpace(rm.model, ("drum_scale",))  # one drum of eight is off
    calls = _counted_fits(monkeypatch)
    res = fit_effects(space, rm, train, hold=np.zeros(len(space), dtype=bool))
    assert len(calls) >= 2 and res.n_free < len(space)
    assert res.phi[space.params.index(next(p for p in space.params if p.key == "s_21"))] != 0


@pytest.fixture(scope="module")
def no_tensions(tmp_path_factory):
    """A recording without load cells (the fits' evaluations warm-start the unmeasured
    tensions of every sample) on masts that bend (and the deflected exits)."""
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 6,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"exit_point_offset": {"dz_21": 0.02}}, "nuisance": {},
        "poses": {"kind": "grid", "n": [3, 2, 1], "rpy_deg": 1.0, "visits": 2},
        "recording": {"load_cells": False}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("cold") / "rec"))
    check_values(rec)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return rm, split_samples(s, rec.init_pose)[0]


def test_a_fit_is_the_same_whatever_was_evaluated_before_it(no_tensions):
    """Each fit starts cold (:meth:`ResidualModel.cold`): after evaluations of another
    robot (other warm starts left behind) the same fit, made anew, gives the same result
    to the last bit, as a worker given a copy of the model would; the warm starts found
    before the fit are there after it."""
    rm, train = no_tensions
    space = ParamSpace(rm.model, ("exit_point_offset",))
    first = fit_effects(space, rm, train, max_nfev=7)
    other = rm.model.replace(mass=rm.model.mass * 1.3)
    rm.whitened(other, train)
    before = rm._warm_tau.copy()
    assert np.isfinite(before[train]).all()
    fit_module._MEMO.clear()
    again = fit_effects(space, rm, train, max_nfev=7)
    np.testing.assert_array_equal(again.phi, first.phi)
    assert again.chi2 == first.chi2
    np.testing.assert_array_equal(rm._warm_tau, before)
