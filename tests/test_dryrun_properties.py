"""Property-based safety tests of the controller and its supervisor in the dry-run loop
(bench/dryrun/loop.py on hal/fake.py over the plant): random paths, speeds, payload masses,
sensor faults (stale, stuck, NaN, spikes, out of range, timeouts) and drive faults.

Invariants, whatever hypothesis draws:
- a path is either refused before anything moves, or run;
- the tensions the controller plans stay within [tension_min, tension_max];
- no setpoint leaves the winches' length range, none is sent for an infeasible pose;
- the commanded motion keeps the speed limit, and the acceleration limit except during a
  feed hold (where time scaling may add up to the limit again: 2 a_max);
- every drive fault gets its quick stop within the bound, named and recorded; every load
  cell that fails is substituted at once and its start is recorded;
- the recording holds every cycle (decimation 1), readable, with the events file; each
  encoder sample once, at its own time (drives' answers late for some cycles: the sample
  already recorded is not written again).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from bench.dryrun.loop import ControlLoop, LoopOptions, PathRefused
from bench.dryrun.record import DryRunRecorder
from bench.recording import read_recording
from controller.effects import apply_effects
from controller.paths import check_trajectory
from controller.statics import pose_statics
from controller.trajectory import Dwell, MotionLimits, Move, Trajectory
from controller.winch import load_winches
from firmware_sim.plant import Plant
from hal.drives_cia402 import DriveState
from hal.fake import FakeHardware
from hal.tracker import CallableTracker
from tests.robots import rocaspect

W = dataclasses.replace(load_winches(), quick_stop_option=np.full(8, 6))
MODEL = rocaspect(compliant=True)
P0 = np.array([10.0, 8.56, 1.2, 0, 0, 0])
#: the profile's example count, scaled down (5 in the ci profile): each example is a dry run
EXAMPLES = max(3, settings().max_examples // 8)
CELL_PERIOD_S = 0.05  #: the fake load cells' sample period [s]
SENSOR_KINDS = ("stale", "nan", "spike", "stuck", "out_of_range", "timeout")


@st.composite
def scenarios(draw):
    target = [draw(st.floats(3.0, 17.0)), draw(st.floats(3.0, 14.0)),
              draw(st.floats(0.4, 2.5)), draw(st.floats(-0.05, 0.05)),
              draw(st.floats(-0.05, 0.05)), draw(st.floats(-0.1, 0.1))]
    speed = draw(st.sampled_from([10.0, 40.0, 100.0]))
    mass = draw(st.floats(25.0, 50.0))
    sensor = draw(st.lists(st.tuples(st.floats(0.3, 3.0), st.integers(0, 7),
                                     st.sampled_from(SENSOR_KINDS), st.floats(0.05, 0.6)),
                           max_size=3))
    drive = draw(st.one_of(st.none(), st.tuples(st.floats(0.3, 3.0), st.integers(1, 8),
                                                st.sampled_from([0x2310, 0x7305, 0x8611]))))
    late = draw(st.one_of(st.none(), st.tuples(st.floats(0.3, 3.0), st.integers(1, 5))))
    return target, speed, mass, sensor, drive, late


class Faulty:
    """The fake hardware over a plant whose truth has another payload mass, with sensor
    faults applied to what the cells measure, drive faults at given times and the drives'
    answers late (``late``: from when, for how many cycles)."""

    def __init__(self, mass, sensor, drive, late=None):
        truth = apply_effects(MODEL, {"platform_mass": {"mass": mass}})
        self.plant = Plant(MODEL, truth, P0)
        self.sensor, self.drive, self.late = sensor, drive, late
        self.held_cycles = 0  #: cycles the drives' answers were late
        self.drive_fired: float | None = None
        self.cell_fired: dict[int, float] = {}
        self._stuck: dict[int, float] = {}
        self.hw = FakeHardware(W, initial_lengths_m=self.plant.reference, plant=self._measure,
                               tension_period_s=CELL_PERIOD_S)
        self.tracker = CallableTracker(lambda: (self.hw.t, self.plant.state.pose.copy(), True))

    def _measure(self, lengths, t):
        tau = self.plant.measured_tensions(self.plant.settle(lengths, t).tensions).copy()
        hw = self.hw
        if self.drive is not None and self.drive_fired is None and t >= self.drive[0]:
            self.drive_fired = t
            hw.inject_drive_fault(self.drive[1], self.drive[2])
        if self.late is not None and not self.held_cycles and t >= self.late[0]:
            self.held_cycles = self.late[1]
            hw.hold_feedback(self.late[1])
        for t0, k, kind, dur in self.sensor:
            active = t0 <= t < t0 + dur
            # a stuck cell reads a plausible value (only a model can tell): the reaction is
            # timed from the cell's first fault the supervisor can see
            if active and k not in self.cell_fired and kind != "stuck":
                self.cell_fired[k] = t
            if kind in ("stale", "out_of_range", "timeout"):
                if active:
                    hw.inject_loadcell_fault(hw.cables[k], kind)
                elif t >= t0 + dur:
                    hw.clear_loadcell_fault(hw.cables[k])
            elif active and kind == "nan":
                tau[k] = np.nan
            elif active and kind == "spike":
                tau[k] = 1e6
            elif active and kind == "stuck":
                tau[k] = self._stuck.setdefault(k, tau[k])
        return tau


@settings(max_examples=EXAMPLES, deadline=None)
@given(scenarios())
# found by hypothesis: a drive fault freezes the commanded pose (no command after it)
@example(([3.0, 3.0, 1.0, 0.0, 0.0, 0.0], 10.0, 25.0, [], (1.0, 1, 0x2310), None))
@example(([5.0, 6.0, 1.0, 0.0, 0.0, 0.0], 40.0, 30.0, [], None, (0.5, 3)))
def test_dry_run_safety_properties(tmp_path_factory, sc):
    target, speed, mass, sensor, drive, late = sc
    tmp = tmp_path_factory.mktemp("run")
    world = Faulty(mass, sensor, drive, late)
    limits = MotionLimits(speed_pct=speed)

    def plan(p0):
        traj = Trajectory([Move(target), Dwell(0.5)], p0, limits)
        chk = check_trajectory(MODEL, traj, W)
        if not chk.ok:
            raise PathRefused(chk.reason)
        return traj

    loop = ControlLoop(world.hw, world.tracker, MODEL, plan,
                       LoopOptions(init_dwell_s=0.2, end_dwell_s=0.2, max_duration_s=3.0,
                                   hold_timeout_s=0.5),
                       lambda p0: DryRunRecorder(tmp / "rec", MODEL, p0, {}))
    res = loop.run()
    hw = world.hw
    if res.ended == "refused":
        # nothing moved: no drive was enabled, no recording was made
        assert not np.any(hw.read().states == DriveState.OPERATION_ENABLED)
        assert not (tmp / "rec").exists()
        return
    assert res.ended in ("completed", "quick_stop", "hold_timeout"), res.message
    assert not np.any(hw.read().states == DriveState.OPERATION_ENABLED)  # nothing moving
    rec = read_recording(tmp / "rec")
    # every cycle, nothing lost or truncated, each encoder sample once: the cycles' rows
    # hold the encoders (lock-step: the SYNC of the cycle) but where the drives' answers
    # were late (the sample already recorded, not written again), at increasing times; the
    # load cells' and tracker's samples have rows of their own
    cyc = np.isfinite(rec.l_meas).all(axis=1)
    assert res.cycles - world.held_cycles <= cyc.sum() <= res.cycles
    assert np.all(np.diff(rec.t[cyc]) > 0), "an encoder sample written twice at its time"
    states, pose_des, t_cyc = np.asarray(rec.state)[cyc], rec.pose_des[cyc], rec.t[cyc]
    plan_tau = np.column_stack([rec.extra[f"plan_tau_{c}"] for c in MODEL.cable_ids])
    tol = 1e-6 * MODEL.tension_max
    assert np.all(plan_tau >= MODEL.tension_min - tol) and np.all(
        plan_tau <= MODEL.tension_max + tol)
    off = np.asarray(res.reference_offset_m)
    drive_l = rec.l_cmd - off
    assert np.all(drive_l >= W.min_length_m) and np.all(drive_l <= W.max_length_m)
    # commanded motion within the limits (finite differences of the setpoint poses of
    # consecutive cycles, not across the cycles of late answers; after a quick stop the
    # drives follow their own ramp and no pose is commanded)
    T = hw.period_s
    commanded = np.array([s != "quick_stop" for s in states])
    n_cmd = int(np.argmin(commanded)) if not commanded.all() else len(commanded)
    one = np.abs(np.diff(t_cyc[:n_cmd]) - T) < 1e-6  # [s] the file's times: to 1 ns
    v = np.diff(pose_des[:n_cmd, :3], axis=0) / T
    speed_max = np.linalg.norm(v[one], axis=1).max(initial=0)
    assert speed_max <= limits.speed_m_s * 1.02 + 1e-9
    acc = np.linalg.norm(np.diff(v, axis=0) / T, axis=1)[one[1:] & one[:-1]]
    held = np.array([s == "hold" for s in states[1:n_cmd - 1]])[one[1:] & one[:-1]]
    assert acc[~held].max(initial=0) <= limits.max_accel_m_s2 * 1.05 + 1e-6
    assert acc.max(initial=0) <= 2 * limits.max_accel_m_s2 * 1.05 + 1e-6
    # every commanded pose is in the wrench-feasible workspace of the controller's model
    # (tensions within limits with the masts deflected by them), a subset of the rows
    for row in range(0, n_cmd, 16):
        st_ = pose_statics(MODEL, pose_des[row])
        assert st_.feasible, f"row {row}: commanded pose {pose_des[row]} infeasible"
    events = res.events
    if world.drive_fired is not None and world.drive_fired < res.simulated_s - 2 * T:
        ev = [e for e in events if e["kind"] == "drive_fault" and e["active"]]
        assert ev and ev[0]["address"] == drive[1] and ev[0]["reaction"] == "quick_stop"
        assert ev[0]["t"] - (world.drive_fired - T) <= 3 * T + 1e-9  # fired before the read
        assert res.ended == "quick_stop"
        assert np.all(np.delete(hw.read().states, drive[1] - 1)
                      == DriveState.QUICK_STOP_ACTIVE)
    for k, t_fired in world.cell_fired.items():
        if t_fired >= res.simulated_s - 0.1:
            continue
        ev = [e for e in events if e["kind"] in ("loadcell", "overload", "slack")
              and e["cable"] == MODEL.cable_ids[k] and e["active"]]
        assert ev, f"cell {MODEL.cable_ids[k]} failed at {t_fired} s: no event"
        # substituted at once: within the cells' sample period (a failure shows at the next
        # sample) and the supervisor's bound (a cell: immediate; a tension: 0.1 s + 2 cycles)
        late = ev[0]["t"] - t_fired
        bound = CELL_PERIOD_S + (0.1 if ev[0]["kind"] != "loadcell" else 0.0) + 3 * T
        assert late <= bound + 1e-9, (
            f"cell {MODEL.cable_ids[k]} failed at {t_fired:.4f} s, reaction at "
            f"{ev[0]['t']:.4f} s (bound {bound:.3f} s)")
    text = (tmp / "rec" / "events.csv").read_text()
    for e in events:
        if e["reaction"] in ("quick_stop", "hold", "substitute"):
            assert e["kind"] in text
