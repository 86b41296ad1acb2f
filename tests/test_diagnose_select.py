"""The selection's fits: a set fitted before and asked for again inside a larger fit (dropping
an effect, a held-out check without it) is refitted from the larger fit's values when the
first fit stopped short; a first fit already at its minimum is kept."""

from __future__ import annotations

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis.fit import fit_effects
from bench.diagnosis.report import split_samples
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import check_values, prepare
from bench.diagnosis.select import Selector
from bench.diagnosis.space import ParamSpace
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario

SCALES = {"s_21": 1.004, "s_32": 0.997}


@pytest.fixture(scope="module")
def selector(tmp_path_factory):
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 4,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"drum_scale": SCALES}, "nuisance": {},
        "poses": {"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2},
        "recording": {}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("sel") / "rec"))
    check_values(rec)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    train = split_samples(s, rec.init_pose)[0]
    return Selector(rm, train, [])


def _scales(fit) -> dict[str, float]:
    return fit.space.values(fit.phi)["drum_scale"]


def test_a_subset_fit_that_stopped_short_is_refitted_from_the_larger_fit(selector):
    both = selector.fit(("cable_length_offset", "drum_scale"))
    space = ParamSpace(selector.model, ("drum_scale",))
    short = fit_effects(space, selector.rm, selector.train, max_nfev=1, prune=False)
    proper = fit_effects(space, selector.rm, selector.train)
    assert short.chi2 > 2.0 * proper.chi2  # the first fit stopped far from the minimum
    selector.cache[("drum_scale",)] = short
    got = selector.fit(("drum_scale",), both)
    assert got is not short and got.chi2 < 1.01 * proper.chi2
    for key, v in SCALES.items():
        assert abs(_scales(got)[key] - v) < 5e-4
    assert selector.fit(("drum_scale",)) is got  # cached for the next asker


def test_a_subset_fit_at_its_minimum_is_kept(selector):
    both = selector.fit(("cable_length_offset", "drum_scale"))
    space = ParamSpace(selector.model, ("drum_scale",))
    selector.cache[("drum_scale",)] = first = fit_effects(space, selector.rm, selector.train)
    selector._refit_from.clear()
    assert selector.fit(("drum_scale",), both) is first
    # not a subset of the start: never refitted
    assert selector.fit(("drum_scale",), selector.fit(("cable_length_offset",))) is first


def test_a_fit_out_of_budget_runs_again_only_while_it_progresses(selector, monkeypatch):
    import bench.diagnosis.fit as fit_module

    space = ParamSpace(selector.model, ("drum_scale",))
    runs = []
    real = fit_module.least_squares
    # the finite-difference runs alone (the secant path before them: its own test)
    monkeypatch.setattr(fit_module, "SECANT_MIN", 10**6)

    def counted(*a, **kw):
        runs.append(kw.get("max_nfev"))
        return real(*a, **kw)

    monkeypatch.setattr(fit_module, "least_squares", counted)
    res = fit_module.fit_effects(space, selector.rm, selector.train, max_nfev=2, prune=False)
    assert len(runs) == fit_module.RETRIES + 1  # each short run lowered the chi-square
    runs.clear()

    def stalled(fun, x0, **kw):  # a run that spends its budget where it started
        out = real(fun, x0, **kw | {"max_nfev": 1})
        out.x, out.fun, out.status = np.array(x0, float), fun(np.array(x0, float)), 0
        out.cost = 0.5 * float(out.fun @ out.fun)
        runs.append(1)
        return out

    monkeypatch.setattr(fit_module, "least_squares", stalled)
    res = fit_module.fit_effects(space, selector.rm, selector.train, prune=False)
    assert len(runs) == 1 and not res.success and "did not converge" in res.message


def test_the_secant_path_ends_at_the_finite_difference_minimum(selector, monkeypatch):
    import bench.diagnosis.fit as fit_module

    space = ParamSpace(selector.model, ("drum_scale", "cable_length_offset"))
    assert len(space) >= fit_module.SECANT_MIN
    jacobians = []
    real = fit_module.fd_jacobian

    def counted(*a, **kw):
        jacobians.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(fit_module, "fd_jacobian", counted)
    secant = fit_module.fit_effects(space, selector.rm, selector.train, prune=False)
    n_secant = len(jacobians)
    jacobians.clear()
    monkeypatch.setattr(fit_module, "SECANT_MIN", 10**6)
    exact = fit_module.fit_effects(space, selector.rm, selector.train, prune=False)
    assert secant.success and exact.success
    # the same minimum: parameters within a small fraction of their standard errors
    se = exact.stderr[np.isfinite(exact.stderr)]
    assert len(se)
    d = np.abs(secant.phi - exact.phi)[np.isfinite(exact.stderr)] / se
    assert d.max() < 0.1
    assert abs(secant.chi2 - exact.chi2) < 0.05 + 1e-6 * exact.chi2
    # the standard errors come from finite differences at the minimum either way
    np.testing.assert_allclose(secant.stderr, exact.stderr, rtol=0.05)
    assert n_secant <= len(jacobians)


def test_swap_predictions_hold_only_the_candidates_asked_for(selector):
    """A selection run again without an effect (the report drops an effect without a
    parameter and selects on from the others) must not be handed swaps into that effect
    from the run before: the swap screen's memo is keyed on the candidates too (the report
    looped forever on a dropped drum scale swapped back in)."""
    current = selector.fit(("cable_length_offset",))
    every = selector.swap_screen(current, ["cable_length_offset"],
                                 ["drum_scale", "exit_point_offset"])
    assert ("cable_length_offset", "drum_scale") in every
    fewer = selector.swap_screen(current, ["cable_length_offset"], ["exit_point_offset"])
    assert set(fewer) == {("cable_length_offset", "exit_point_offset")}
