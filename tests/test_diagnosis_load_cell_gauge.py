"""The load cells' gauge: tensions scaled by a factor with the mass, the cables' E*A and the
masts' stiffness, and the cells' gains divided by it, read the same; the selection's starts
move along it; the report's alternatives are points of it."""

from __future__ import annotations

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis import gauge
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import check_values, prepare
from bench.diagnosis.space import ParamSpace
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario


@pytest.fixture(scope="module")
def rm(tmp_path_factory):
    """A small dwell campaign on ROCASPECT with every sensor."""
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 11,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"load_cell_calibration": {"gain_21": 1.03}}, "nuisance": {},
        "poses": {"kind": "grid", "n": [3, 2, 1], "rpy_deg": 1.0, "visits": 1},
        "recording": {}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("gauge") / "rec"))
    check_values(rec)
    s = prepare(rec)
    out = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    out.estimate_noise(rec.robot)
    return out


def _hypothesis(model):
    """A robot away from the model in every quantity of the gauge, without sag."""
    n = len(model.cable_ids)
    return model.replace(rho=0.0, mass=model.mass * 1.1, ea=np.full(n, 2.5e5),
                         stiffness=np.full_like(model.stiffness, 4e6),
                         load_cell_gain=np.linspace(0.97, 1.05, n),
                         load_cell_offset=np.linspace(-5.0, 5.0, n))


def test_scaled_tensions_read_the_same(rm):
    robot = _hypothesis(rm.model)
    r0 = rm.whitened(robot)
    r1 = rm.whitened(gauge.scale_tensions(robot, 1.3))
    assert np.max(np.abs(r1 - r0)) < 1e-3
    # each quantity alone is not a symmetry: the test can tell
    for change in ({"mass": robot.mass * 1.3}, {"ea": robot.ea * 1.3},
                   {"load_cell_gain": robot.load_cell_gain / 1.3}):
        assert np.max(np.abs(rm.whitened(robot.replace(**change)) - r0)) > 1.0


def test_common_gain_and_mass_read_the_same_in_statics(rm):
    """With inextensible cables and rigid masts, a gain shared by every cell is a mass
    change (the offsets stay: measured = gain tension + offset)."""
    stiff = rm.model.replace(rho=0.0, ea=np.full(len(rm.model.cable_ids), np.inf),
                             load_cell_offset=np.linspace(-5.0, 5.0, len(rm.model.cable_ids)))
    gains = stiff.replace(load_cell_gain=stiff.load_cell_gain * 1.2)
    r0 = rm.whitened(gains)
    alt, common = gauge.common_gain_as_mass(gains, rm.model)
    assert common == pytest.approx(1.2)
    assert alt.mass == pytest.approx(rm.model.mass * 1.2)
    assert np.max(np.abs(rm.whitened(alt) - r0)) < 1e-3
    back, ratio = gauge.mass_as_common_gain(alt, rm.model)
    assert ratio == pytest.approx(1.2)
    assert np.max(np.abs(rm.whitened(back) - r0)) < 1e-3
    assert gauge.common_gain_as_mass(stiff, rm.model) is None  # no common gain: no move


def test_starts_move_a_mass_change_into_the_stretch():
    """From the load cells carrying a mass change (every gain 1.25 x one cell's own error,
    the mass 1.25 x), the fit with the stretch in place of the mass starts where the mass is
    the model's, the gains are back to one cell off, and the cables 1.25 x softer."""
    from controller.robot import resolve_robot

    model = resolve_robot("rocaspect")
    src = ParamSpace(model, ("load_cell_calibration", "platform_mass"))
    truth = model.replace(ea=model.ea / 1.25, load_cell_gain=np.where(
        np.array(model.cable_ids) == "11", 1.04, 1.0))
    seen = gauge.scale_tensions(truth, 1.25)  # the mass 1.25 x, every gain over 1.25
    phi = src.phi_of(seen)
    dst = ParamSpace(model, ("cable_elasticity", "load_cell_calibration"))
    got = [dst.values(p) for p in gauge.starts(dst, src, phi)]
    match = [v for v in got if abs(v["cable_elasticity"]["ea"] - model.ea[0] / 1.25) < 1.0]
    assert match
    gains = match[0]["load_cell_calibration"]
    assert gains["gain_11"] == pytest.approx(1.04)
    assert all(v == pytest.approx(1.0) for k, v in gains.items()
               if k.startswith("gain_") and k != "gain_11")


def test_no_starts_where_the_gauge_does_not_move():
    from controller.robot import resolve_robot

    model = resolve_robot("rocaspect")
    src = ParamSpace(model, ("load_cell_calibration", "platform_mass"))
    phi = src.phi_of(model.replace(mass=model.mass * 1.2,
                                   load_cell_gain=model.load_cell_gain / 1.2))
    # adding an effect outside the group, or no load cells on either side: nothing to move
    assert gauge.starts(ParamSpace(model, ("exit_point_offset", "load_cell_calibration",
                                           "platform_mass")), src, phi) == []
    no_cells = ParamSpace(model, ("platform_mass",))
    assert gauge.starts(ParamSpace(model, ("cable_elasticity", "platform_mass")), no_cells,
                        no_cells.phi_of(model.replace(mass=model.mass * 1.2))) == []
    # at the model's values there is nothing to move either
    assert gauge.starts(ParamSpace(model, ("cable_elasticity", "load_cell_calibration")),
                        src, src.neutral) == []


@pytest.fixture(scope="module")
def heavier_platform(tmp_path_factory):
    """A CoGiRo-class dwell campaign without a tracker: the platform 7 % heavier than the
    model says and one load cell with an offset. The cables are stiff (the stretch barely
    tells the mass from a gain shared by every cell)."""
    from bench.evaluate import make_case, scenario_of

    case = make_case(4343, robot="cogiro", effects=("platform_mass",), kind="dwell",
                     sensors="no_tracker", oov="none", poses={"visits": 2})
    model = scenario_of(case).model
    case["truth"] = {"platform_mass": {"mass": model.mass * 1.07},
                     "load_cell_calibration": {"offset_42": 15.0}}
    case["nuisance"] = {"hysteresis_m": 0.0, "drift_m_per_h": 0.0}
    out = tmp_path_factory.mktemp("heavier") / "rec"
    run_campaign(scenario_of(case), out)
    return out, model.mass * 1.07


def test_a_heavier_platform_is_not_read_as_every_cell_reading_high(heavier_platform):
    """Where the statics cannot tell a mass change from a gain shared by every cell, the
    fit holds one of them at the model's value; the choice is the fewest parameters' (the
    mass, with the cells right), not the gains carrying the mass at standard errors that
    hold the mass fixed (8 gains 7 % high at a few thousandths before)."""
    from bench.diagnosis.report import diagnose

    path, mass = heavier_platform
    rep = diagnose(path).report
    by = {e["name"]: e for e in rep["effects"]}
    assert set(by) == {"load_cell_calibration", "platform_mass"}
    assert by["platform_mass"]["params"]["mass"] == pytest.approx(mass, rel=0.01)
    gains = [k for k in by["load_cell_calibration"]["params"] if k.startswith("gain_")]
    assert not gains
    assert by["load_cell_calibration"]["params"]["offset_42"] == pytest.approx(15.0, abs=3.0)


def test_only_a_move_along_the_gauge_takes_over_on_a_small_bic_drop():
    """A mass for the cells' common gain, or a stretch where the mass is free too, may
    replace more parameters on a BIC drop under the entry threshold; a stretch beside the
    cells alone (the mass fixes the tensions' scale there) is an effect of its own."""
    from types import SimpleNamespace

    from bench.diagnosis.select import BIC_ENTER, BIC_TIE, _takes_over

    with_ = SimpleNamespace(n_free=3, bic=100.0)
    without = SimpleNamespace(n_free=9, bic=100.0 + 0.5 * (BIC_TIE + BIC_ENTER))
    lc, mass, ea = "load_cell_calibration", "platform_mass", "cable_elasticity"
    assert _takes_over(mass, [lc, mass], with_, without)
    assert _takes_over(ea, [lc, mass, ea], with_, without)
    assert not _takes_over(ea, [lc, ea], with_, without)
    assert not _takes_over(mass, [mass], with_, without)  # no load cells: nothing to trade
    assert not _takes_over(mass, [lc, mass], SimpleNamespace(n_free=10, bic=100.0), without)
    assert not _takes_over(mass, [lc, mass], with_,
                           SimpleNamespace(n_free=9, bic=100.0 + 0.5 * BIC_TIE))


def _cogiro_gains_seen(scale: float):
    """CoGiRo with three cells right, two 2 % low and three off each its own way (as in
    case 11693; here the median falls on a low cell), seen along the gauge: every gain
    ``scale`` x its own."""
    from controller.robot import resolve_robot

    model = resolve_robot("cogiro")
    true_gain = np.array([1.0, 0.980, 0.979, 1.0, 0.975, 0.959, 0.953, 1.0])
    truth = model.replace(load_cell_gain=true_gain)
    space = ParamSpace(model, ("load_cell_calibration", "platform_mass", "cable_elasticity"))
    return model, space, space.phi_of(gauge.scale_tensions(truth, 1.0 / scale)), true_gain


def _gain_cov(space, phi, own: float, common: float) -> np.ndarray:
    """Covariance of the fit's parameters: each gain its own error and a common mode (the
    scale the data know poorly) shared by all."""
    ix = [k for k, p in enumerate(space.params) if p.key.startswith("gain_")]
    g = phi[ix]
    cov = np.zeros((len(space), len(space)))
    cov[np.ix_(ix, ix)] = np.outer(g, g) * (common ** 2 + own ** 2 * np.eye(len(ix)))
    return cov


def test_the_gauge_is_pinned_where_most_cells_agree():
    """Three cells right, two 2 % low: the median of the eight falls on a low cell (case
    11693 pinned one: every other gain and the mass then 2 % off at errors of 0.02 %,
    z 126). Pinned at a cell of the larger group, the three right cells read 1 and the
    others their own gains, whatever the common mode's error."""
    model, space, phi, true_gain = _cogiro_gains_seen(1.0207)
    for common in (0.0, 0.04):
        pin = gauge.pinned(space, phi, _gain_cov(space, phi, 4e-4, common))
        assert pin is not None
        moved, hold = pin
        held = [space.params[k].key for k in np.flatnonzero(hold)]
        assert held[0] in ("gain_11", "gain_22", "gain_42")
        got = space.robot(moved).load_cell_gain
        np.testing.assert_allclose(got, true_gain, rtol=1e-9)


def test_without_agreement_the_gauge_is_pinned_at_the_median_cell():
    """Without a covariance, or gains that each differ beyond their errors, the cell
    nearest the gains' median is held."""
    lr = np.log([1.0, 0.980, 0.979, 1.0, 0.975, 0.959, 0.953, 1.0]) + 0.0207
    median_cell = int(np.argmin(np.abs(lr - np.median(lr))))
    assert gauge.agreeing_cell(lr) == median_cell
    spread = np.log(np.linspace(0.95, 1.05, 8))
    assert gauge.agreeing_cell(spread, np.eye(8) * 1e-8) == int(
        np.argmin(np.abs(spread - np.median(spread))))
    # with errors wide enough that every gain agrees with every other, the median decides
    assert gauge.agreeing_cell(lr, np.eye(8) * 1.0) == median_cell


def test_the_scale_is_reported_as_known_to_what_the_stretch_tells(tmp_path):
    """A heavier CoGiRo platform, two cells 2 % low, no tracker: the fit of the cells, the
    mass and a stiffness per cable holds every E*A at the model's (right) and a gain to
    fix the tensions' scale. Freeing everything to measure the scale's error leaves the
    gauge exact (no error at all: the mass was reported to 0.09 %); with the E*A the fit
    found right held, the stiff cables' stretch tells the scale to a few per cent, and the
    mass is reported so."""
    from bench.diagnosis.select import Selector
    from bench.diagnosis.space import PER_CABLE_EA
    from bench.evaluate import make_case, scenario_of

    case = make_case(4343, robot="cogiro", effects=("platform_mass",), kind="dwell",
                     sensors="no_tracker", oov="none", poses={"visits": 2})
    model = scenario_of(case).model
    mass = model.mass * 1.07
    case["truth"] = {"platform_mass": {"mass": mass}, "load_cell_calibration": {
        "offset_42": 15.0, "gain_11": 0.98, "gain_21": 0.98}}
    case["nuisance"] = {"hysteresis_m": 0.0, "drift_m_per_h": 0.0}
    rec = read_recording(run_campaign(scenario_of(case), tmp_path / "rec"))
    check_values(rec)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    fit = Selector(rm, np.arange(s.n), []).fit(
        tuple(sorted(("load_cell_calibration", "platform_mass", PER_CABLE_EA))))
    keys = [p.key for p in fit.space.params]
    ea = [k for k, key in enumerate(keys) if key.startswith("ea_")]
    assert np.array_equal(fit.phi[ea], fit.space.neutral[ea])  # the case tested: E*A held
    k = keys.index("mass")
    assert fit.reported_stderr[k] > 0.01 * mass
    assert abs(fit.phi[k] - mass) < 3 * fit.reported_stderr[k]
