"""The dry-run loop's last guard (bench/dryrun/loop.py ``ControlLoop._act``): a setpoint
outside a winch's length limits is never sent, whatever planned it.

``cdpr dry-run`` refuses such a path before anything moves (``check_trajectory``), so the
guard is only reached by a plan that was not checked (a learner's correction, a trajectory
factory of a caller's own); these tests give the loop one on the fake hardware, with the
limits of one winch narrowed so that the path crosses them half-way.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.dryrun.loop import ControlLoop, LoopOptions
from controller.cycle import LengthController, reference_lengths
from controller.trajectory import MotionLimits, Move, Trajectory
from controller.winch import load_winches
from hal.fake import FakeHardware
from hal.tracker import CallableTracker
from tests.robots import rocaspect

MODEL = rocaspect()
P0 = np.array([10.0, 8.56, 1.2, 0, 0, 0])
TARGET = np.array([11.0, 9.06, 1.4, 0, 0, 0])
MAX_CYCLES = 5000  # ~20 s at 256 Hz: the path takes ~3 s
LIMITS = MotionLimits(max_speed_m_s=0.5, max_accel_m_s2=5.0, max_jerk_m_s3=50.0)


class SpyHardware(FakeHardware):
    """The fake hardware, recording every setpoint written (drive coordinates) [m]."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.written: list[np.ndarray] = []

    def write_lengths(self, lengths_m):
        if lengths_m is not None:
            self.written.append(np.asarray(lengths_m, float) - self.reference_offset_m)
        super().write_lengths(lengths_m)


def _run(narrow: int | None, shrink: float = 0.5):
    """Run P0 -> TARGET on the fake (lock-step, no tick); with ``narrow`` the cable whose
    length grows most may only reach ``shrink`` of the way [m]. Returns (hw, result, the
    winches, the cable narrowed)."""
    lc = LengthController(MODEL, P0, None)
    l0, l1 = lc.reference, reference_lengths(MODEL, TARGET)
    w = load_winches()
    j = int(np.argmax(l1 - l0))
    if narrow is not None:
        hi = w.max_length_m.copy()
        hi[j] = l0[j] + shrink * (l1[j] - l0[j])
        w = dataclasses.replace(w, max_length_m=hi)
    hw = SpyHardware(w, initial_lengths_m=l0, tensions_N=lc.init_tensions)
    tracker = CallableTracker(lambda: (hw.t, P0.copy(), True))
    traj = Trajectory([Move(TARGET.tolist())], P0, LIMITS)
    opt = LoopOptions(init_pose=P0, init_dwell_s=0.05, end_dwell_s=0.1, hold_timeout_s=0.3)
    cycles = [0]

    def tick() -> None:  # a loop that never ends is stopped (and fails), not hung
        cycles[0] += 1
        if cycles[0] == MAX_CYCLES:
            loop.stop.set()

    loop = ControlLoop(hw, tracker, MODEL, lambda p0: traj, opt, tick=tick)
    result = loop.run()
    return hw, result, w, j


def test_a_setpoint_past_a_winch_limit_is_never_sent_and_is_said():
    hw, result, w, j = _run(narrow=0)
    sent = np.array(hw.written)
    assert len(sent) > 20
    over = sent > w.max_length_m + 1e-9
    assert not over.any(), f"sent past the limit on cable {np.flatnonzero(over.any(0))}"
    hits = [e for e in result.events if e["kind"] == "workspace"]
    assert hits and hits[0]["cable"] == hw.cables[j], result.events
    # the winch went to its limit's neighbourhood and stood there (a hold, not a jump)
    assert sent[-1, j] <= w.max_length_m[j] and sent[-1, j] > sent[0, j]
    assert result.ended == "hold_timeout", (result.ended, result.message)
    assert "workspace: cable" in result.message, result.message
    ends = [e for e in result.events if e["kind"] == "workspace" and not e["active"]]
    assert not ends  # the setpoint never came back within the limits


def test_within_the_limits_the_guard_says_nothing():
    hw, result, w, _ = _run(narrow=None)
    assert result.ended == "completed", (result.ended, result.message)
    assert not [e for e in result.events if e["kind"] == "workspace"]
    np.testing.assert_allclose(hw.written[-1], reference_lengths(MODEL, TARGET), atol=2e-3)
