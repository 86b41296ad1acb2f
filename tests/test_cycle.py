"""The control cycle (controller/cycle.py): setpoints in the encoder reference, everything a
corrected robot.toml holds applied, bad tensions never reaching the statics."""

from __future__ import annotations

import numpy as np
import pytest

from controller.cycle import LengthController, reference_lengths
from controller.statics import pose_statics, unstretched_lengths
from tests.robots import rocaspect

P0 = np.array([10.0, 8.56, 1.2, 0, 0, 0])
P1 = np.array([14.0, 5.0, 1.5, 0, 0, 0.02])


def _ctl(robot, tau0=None):
    return LengthController(robot, P0, init_tensions=tau0)


def test_first_setpoint_is_the_reference_for_any_model():
    """At p0 the setpoints equal d_model(p0) (inextensible) or differ by the stretch of the
    planned minus the measured tensions (elastic), for nominal and corrected models."""
    for robot in (rocaspect(), rocaspect(compliant=True),
                  rocaspect(exits=rocaspect().exits + 0.05)):
        ctl = _ctl(robot)
        out = ctl.step(P0)
        assert out.feasible
        np.testing.assert_allclose(out.lengths, reference_lengths(robot, P0), atol=2e-3)
    inext = rocaspect(ea=np.inf)
    np.testing.assert_allclose(_ctl(inext).step(P0).lengths, reference_lengths(inext, P0),
                               atol=1e-12)


def test_setpoint_is_reference_plus_change_of_unstretched_length():
    robot = rocaspect()
    ctl = _ctl(robot)
    out = ctl.step(P1)
    ps = pose_statics(robot, P1)
    expect = reference_lengths(robot, P0) + ps.unstretched - ctl.u0
    np.testing.assert_allclose(out.lengths, expect, atol=1e-9)


def test_drum_scale_divides_the_change():
    s = np.linspace(0.98, 1.02, 8)
    base, scaled = _ctl(rocaspect()), _ctl(rocaspect(drum_scale=s))
    ref = reference_lengths(rocaspect(), P0)
    d0 = base.step(P1).lengths - ref
    d1 = scaled.step(P1).lengths - ref
    np.testing.assert_allclose(d1, d0 / s, atol=1e-9)
    assert np.abs(d1 - d0).max() > 1e-3  # it changes the setpoints measurably


def test_length_offset_is_subtracted():
    dl = np.array([0.004, 0, 0, -0.002, 0, 0, 0, 0.001])
    base, off = _ctl(rocaspect()), _ctl(rocaspect(length_offset=dl))
    np.testing.assert_allclose(off.step(P1).lengths, base.step(P1).lengths - dl, atol=1e-9)


def test_per_cable_ea_sets_the_stretch():
    ea = np.full(8, 6e5)
    ea[2] = 3e5  # cable 21 softer
    base, soft = _ctl(rocaspect()), _ctl(rocaspect(ea=ea))
    a, b = base.step(P1), soft.step(P1)
    # the unstretched length follows each cable's own EA
    ps = pose_statics(rocaspect(ea=ea), P1)
    np.testing.assert_allclose(b.lengths - soft.reference, ps.unstretched - soft.u0, atol=1e-9)
    assert abs((b.lengths - a.lengths)[2]) > 1e-4
    np.testing.assert_allclose(np.delete(b.lengths - a.lengths, 2), 0, atol=2e-4)
    np.testing.assert_allclose(unstretched_lengths(ps.state.length, ps.tensions, ea),
                               ps.unstretched)


def test_load_cell_calibration_corrects_the_tensions_read():
    gain = np.array([1.04, 1.04, 1.04, 1.04, 1, 1, 1, 1])
    off = np.array([0, 0, 5.0, 0, 0, 0, 0, -3.0])
    robot = rocaspect(compliant=True)
    cal = robot.replace(load_cell_gain=gain, load_cell_offset=off)
    true = pose_statics(robot, P1).tensions
    read = gain * true + off  # what the miscalibrated cells show
    ref_ctl, cal_ctl = _ctl(robot), _ctl(cal)
    a = ref_ctl.step(P1, true)
    b = cal_ctl.step(P1, read)
    np.testing.assert_allclose(b.exits, a.exits, atol=1e-12)
    np.testing.assert_allclose(cal_ctl.true_tensions(read), true, atol=1e-9)
    # the uncorrected reading moves the exit points: the correction matters
    c = _ctl(robot).step(P1, read)
    assert np.abs(c.exits - a.exits).max() > 1e-5


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e300, -1e6])
def test_bad_tension_is_replaced_by_the_planned_one(bad):
    robot = rocaspect(compliant=True)
    ctl = _ctl(robot)
    planned = ctl.step(P1).tensions  # the previous cycle's plan
    meas = planned.copy()
    meas[3] = bad
    out = ctl.step(P1, meas)
    assert out.feasible and np.all(np.isfinite(out.lengths))
    np.testing.assert_array_equal(out.substituted, np.arange(8) == 3)
    ref = _ctl(robot)
    ref.step(P1)
    np.testing.assert_allclose(out.lengths, ref.step(P1, planned).lengths, atol=1e-12)


def test_every_cycle_after_a_bad_tension_still_works():
    """One timeout must not make the controller refuse the following cycles."""
    robot = rocaspect(compliant=True)
    ctl = _ctl(robot)
    tau = ctl.step(P0).tensions
    meas = tau.copy()
    meas[0] = np.nan
    for k in range(5):
        out = ctl.step(P0 + np.array([0.01 * k, 0, 0, 0, 0, 0]), meas if k == 1 else tau)
        assert out.feasible, out.reason


def test_invalid_mask_substitutes_good_looking_values():
    robot = rocaspect(compliant=True)
    ctl = _ctl(robot)
    tau = ctl.step(P1).tensions
    valid = np.ones(8, bool)
    valid[5] = False
    out = ctl.step(P1, tau * 1.5, valid)
    np.testing.assert_array_equal(out.substituted, ~valid)


def test_init_tensions_must_be_finite():
    with pytest.raises(ValueError, match="finite"):
        _ctl(rocaspect(), np.full(8, np.nan))
