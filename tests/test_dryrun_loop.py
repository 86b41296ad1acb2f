"""The dry run's control loop (bench/dryrun/loop.py) on the pure-Python fake hardware: the
platform follows a path, the model equal to the truth gives errors within the noise, every
supervisor trigger gets its reaction within the bound, a stop leaves the drives held and the
recording readable, an infeasible path is refused before anything moves."""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest

from bench.dryrun.loop import ControlLoop, LoopOptions, PathRefused, reference_command
from bench.dryrun.record import DryRunRecorder
from bench.recording import read_recording
from controller.effects import apply_effects
from controller.paths import check_trajectory
from controller.trajectory import Dwell, Move, Trajectory
from controller.winch import load_winches
from firmware_sim.plant import Plant
from hal.drives_cia402 import DriveState
from hal.fake import FakeHardware
from hal.tracker import CallableTracker
from tests.robots import rocaspect

P0 = np.array([10.0, 8.56, 1.2, 0, 0, 0])
TARGET = np.array([11.0, 9.06, 1.4, 0, 0, 0])
# quick stop ends holding in Quick Stop Active (0x605A option 6), as the shipped file says
W = dataclasses.replace(load_winches(), quick_stop_option=np.full(8, 6))
TRUTH_EFFECTS = {"mast_compliance": {f"k{a}_{m}": k for m in "1234"
                                     for a, k in zip("xyz", (2e5, 5e5, 3e5), strict=True)},
                 "exit_point_offset": {"dx_11": 0.03, "dy_21": -0.03, "dx_32": -0.03}}


class World:
    """FakeHardware over a plant, a noise-free tracker of the plant's pose."""

    def __init__(self, model, truth, p0=P0, tension_hook=None, winches=W):
        self.plant = Plant(model, truth, p0)
        hook = tension_hook or (lambda t, tau: tau)
        self.hw = FakeHardware(winches, initial_lengths_m=self.plant.reference,
                               plant=lambda lm, t: hook(t, self.plant.measured_tensions(
                                   self.plant.settle(lm, t).tensions)),
                               tension_period_s=0.02)
        self.tracker = CallableTracker(lambda: (self.hw.t, self.plant.state.pose.copy(), True))


def _plan(model, specs):
    def plan(p0):
        traj = Trajectory(specs, p0)
        chk = check_trajectory(model, traj)
        if not chk.ok:
            raise PathRefused(f"t={chk.t_s}: {chk.reason}")
        return traj
    return plan


def _run(world, model, specs, tmp_path=None, stop=None, **opts):
    rec = None
    if tmp_path is not None:
        def rec(p0):
            return DryRunRecorder(tmp_path / "rec", model, p0, {"notes": "test"})
    opt = LoopOptions(init_dwell_s=0.2, end_dwell_s=0.2, **opts)
    loop = ControlLoop(world.hw, world.tracker, model, _plan(model, specs), opt, rec,
                       stop=stop)
    return loop, loop.run()


SPECS = [Move(TARGET.tolist()), Dwell(0.5)]


def test_model_equal_to_truth_follows_the_path_within_the_noise(tmp_path):
    truth = apply_effects(rocaspect(), TRUTH_EFFECTS)
    w = World(truth, truth)
    loop, res = _run(w, truth, SPECS, tmp_path)
    assert res.ended == "completed", res.message
    assert res.overruns == 0 and res.cycles > 100
    # the plant ends where the path ends; the tracker saw the path all along
    np.testing.assert_allclose(w.plant.state.pose[:3], TARGET[:3], atol=2e-4)
    assert res.pose_error_max_m < 5e-3 and res.pose_error_rms_m < 2e-3
    assert not [e for e in res.events if e["reaction"] not in ("none", "event")]
    rec = read_recording(tmp_path / "rec")
    assert rec.state[0] == "init" and "move" in rec.state and rec.state[-1] == "end"
    np.testing.assert_allclose(rec.init_pose, P0, atol=1e-9)
    # each sensor's sample once, on the row of its time: a group is whole or no sample
    for group in (rec.tau, rec.pose_meas):
        have = np.isfinite(group).all(axis=1)
        assert have.sum() > 50 and (have | np.isnan(group).all(axis=1)).all()
    # drives disabled at the end (brakes), nothing moving
    assert not np.any(w.hw.read().states == DriveState.OPERATION_ENABLED)


def test_nominal_model_misses_and_compliant_truth_is_what_it_misses():
    truth = apply_effects(rocaspect(), TRUTH_EFFECTS)
    nominal = rocaspect()
    w = World(nominal, truth)
    _, res = _run(w, nominal, SPECS)
    assert res.ended == "completed"
    err = np.linalg.norm(w.plant.state.pose[:3] - TARGET[:3])
    assert err > 3e-3  # the model error shows away from p0


def test_any_model_starts_at_the_drives_positions():
    """Referencing: a model whose exits are 5 cm off starts without a jump (no following
    error), the first setpoints within the stretch difference of the drives' positions."""
    truth = rocaspect()
    off = rocaspect(exits=rocaspect().exits + np.array([0.05, -0.04, 0.01]))
    w = World(truth, truth)
    loop, res = _run(w, off, [Dwell(0.3)])
    assert res.ended == "completed", res.message
    assert not [e for e in res.events if e["kind"] == "following_error"]
    assert max(abs(v) for v in res.reference_offset_m) > 0.01


def test_infeasible_path_is_refused_before_anything_moves(tmp_path):
    model = rocaspect()
    w = World(model, model)
    far = [Move([20.5, 8.56, 0.5, 0, 0, 0])]  # to the side, out of the feasible workspace
    _, res = _run(w, model, far, tmp_path)
    assert res.ended == "refused" and "t=" in res.message
    assert not np.any(w.hw.read().states == DriveState.OPERATION_ENABLED)
    assert not (tmp_path / "rec").exists()
    assert w.hw.cycle < 5  # no cycles beyond start-up


def _kinds(res, reaction=None):
    return [(e["kind"], e["reaction"]) for e in res.events
            if reaction is None or e["reaction"] == reaction]


def _first_time(res, kind):
    return min(e["t"] for e in res.events if e["kind"] == kind and e["active"])


def test_drive_fault_quick_stops_every_drive_within_the_bound(tmp_path):
    model = rocaspect()
    w = World(model, model)
    fired = {}

    def hook(t, tau):
        if t >= 0.6 and not fired:
            fired["t"] = t
            w.hw.inject_drive_fault(3, 0x2310)
        return tau

    w2 = World(model, model, tension_hook=hook)
    w = w2
    _, res = _run(w, model, SPECS, tmp_path)
    assert res.ended == "quick_stop", res.message
    t_detect = _first_time(res, "drive_fault")
    assert t_detect - fired["t"] <= 3 * w.hw.period_s + 1e-9
    st = w.hw.read().states
    assert st[2] == DriveState.FAULT
    assert np.all(np.delete(st, 2) == DriveState.QUICK_STOP_ACTIVE)  # held, not released
    ev = [e for e in res.events if e["kind"] == "drive_fault"][0]
    assert (ev["device"], ev["address"], ev["code"], ev["reaction"]) == (
        "drive", 3, 0x2310, "quick_stop")
    rec = read_recording(tmp_path / "rec")
    assert rec.state[-1] == "quick_stop"
    events = (tmp_path / "rec" / "events.csv").read_text()
    assert "drive_fault" in events and "quick_stop" in events


def test_loadcell_fault_is_substituted_and_logged_start_and_end(tmp_path):
    model = rocaspect(compliant=True)
    w = World(model, model)
    calls = {"n": 0}

    def tick_fault(t, tau):
        calls["n"] += 1
        if 0.5 <= t < 0.9:
            w.hw.inject_loadcell_fault("21", "timeout")
        else:
            w.hw.clear_loadcell_fault("21")
        return tau

    w = World(model, model, tension_hook=tick_fault)
    _, res = _run(w, model, SPECS, tmp_path)
    assert res.ended == "completed", res.message
    cell = [e for e in res.events if e["kind"] == "loadcell"]
    assert [(e["address"], e["active"], e["reaction"]) for e in cell] == [
        (3, True, "substitute"), (3, False, "substitute")]
    assert res.substituted_cycles > 0
    rec = read_recording(tmp_path / "rec")
    sub = rec.extra["substituted"]
    assert sub.max() == 1 and np.isnan(rec.tau[sub == 1, 2]).all()


def test_nan_tension_never_stops_the_controller():
    model = rocaspect(compliant=True)

    def nan_hook(t, tau):
        tau = tau.copy()
        if 0.4 < t < 0.45:
            tau[0] = np.nan
        return tau

    w = World(model, model, tension_hook=nan_hook)
    _, res = _run(w, model, SPECS)
    assert res.ended == "completed", res.message
    assert ("loadcell", "substitute") in _kinds(res)


def test_slack_cable_holds_the_platform(tmp_path):
    model = rocaspect()

    def slack(t, tau):
        tau = tau.copy()
        if t > 0.6:
            tau[4] = 0.5
        return tau

    w = World(model, model, tension_hook=slack)
    _, res = _run(w, model, SPECS, tmp_path, hold_timeout_s=0.5)
    assert res.ended == "hold_timeout"
    assert ("slack", "hold") in _kinds(res)
    assert res.trajectory_s < res.path_s
    rec = read_recording(tmp_path / "rec")
    assert rec.state[-1] == "hold"
    # the platform came to a stand-still along the path (no jump): last rows equal
    np.testing.assert_allclose(rec.pose_des[-1], rec.pose_des[-5], atol=1e-6)


def test_slack_can_be_logged_instead(tmp_path):
    from controller.supervisor import Reaction

    model = rocaspect()

    def slack(t, tau):
        tau = tau.copy()
        if t > 0.6:
            tau[4] = 0.5
        return tau

    w = World(model, model, tension_hook=slack)
    _, res = _run(w, model, SPECS, tmp_path, reactions={"slack": Reaction.LOG})
    assert res.ended == "completed"
    assert ("slack", "log") in _kinds(res) and ("reaction_override", "log") in _kinds(res)


def test_overload_quick_stops():
    model = rocaspect()

    def over(t, tau):
        tau = tau.copy()
        if t > 0.5:
            tau[7] = 5000.0
        return tau

    w = World(model, model, tension_hook=over)
    _, res = _run(w, model, SPECS)
    assert res.ended == "quick_stop" and ("overload", "quick_stop") in _kinds(res)


def test_following_error_quick_stops():
    model = rocaspect()
    slow = dataclasses.replace(W, max_speed_m_s=np.full(8, 0.01))  # winches cannot follow
    w = World(model, model, winches=slow)
    _, res = _run(w, model, SPECS)
    assert res.ended == "quick_stop"
    assert ("following_error", "quick_stop") in _kinds(res)


def test_stop_request_quick_stops_holds_and_leaves_a_readable_recording(tmp_path):
    model = rocaspect()
    stop = threading.Event()

    def ask(t, tau):
        if t > 0.7:
            stop.set()
        return tau

    w = World(model, model, tension_hook=ask)
    _, res = _run(w, model, SPECS, tmp_path, stop=stop)
    assert res.ended == "interrupted"
    assert np.all(w.hw.read().states == DriveState.QUICK_STOP_ACTIVE)
    rec = read_recording(tmp_path / "rec")
    assert rec.n_samples > 10 and rec.state[-1] == "quick_stop"
    assert "dry run: interrupted" in (Path(tmp_path) / "rec" / "meta.toml").read_text()


def test_decimation_records_every_nth_cycle(tmp_path):
    model = rocaspect()
    w = World(model, model)
    _, res = _run(w, model, [Dwell(0.4)], tmp_path, decimate=5)
    rec = read_recording(tmp_path / "rec")
    # every 5th cycle, plus the first cycle of each state (init, dwell, end); the cycle
    # rows hold the encoders, the load cells' samples have rows of their own
    changes = sum(1 for a, b in zip(rec.state, rec.state[1:], strict=False) if a != b) + 1
    cycle_rows = int(np.isfinite(rec.l_meas).all(axis=1).sum())
    assert res.cycles // 5 <= cycle_rows <= res.cycles // 5 + changes
    assert rec.state[0] == "init" and rec.state[-1] == "end"


@pytest.mark.parametrize("given", [True, False])
def test_init_pose_given_or_measured(given):
    model = rocaspect()
    w = World(model, model)
    _, res = _run(w, model, [Dwell(0.2)], init_pose=P0 if given else None)
    np.testing.assert_allclose(res.init_pose, P0, atol=1e-9)


class FakeClock:
    """A monotonic clock that only moves when slept on or told to (work)."""

    def __init__(self):
        self.t = 100.0

    def now(self):
        return self.t

    def sleep(self, dt):
        self.t += dt


def test_cycle_clock_keeps_absolute_deadlines_without_drift():
    from bench.dryrun.loop import CycleClock

    c = FakeClock()
    clock = CycleClock(0.004, now=c.now, sleep=lambda dt: c.sleep(dt + 1e-4), spin_s=0.0)
    start = c.t
    for _ in range(1000):
        late = clock.wait()
        assert late < 2e-4  # woke within the sleep's own error, never accumulating
        c.t += 0.001  # the cycle's work
        assert not clock.done()
    # 1000 cycles of 4 ms: the deadlines stayed on the grid (no drift from the work or
    # from sleeping too long)
    assert clock.deadline == pytest.approx(start + 1000 * 0.004, abs=1e-9)
    assert clock.overruns == 0


def test_cycle_clock_counts_overruns_and_skips_missed_deadlines():
    from bench.dryrun.loop import CycleClock

    c = FakeClock()
    clock = CycleClock(0.004, now=c.now, sleep=c.sleep, spin_s=0.0)
    start = c.t
    clock.wait()
    c.t += 0.0105  # work of 10.5 ms: two deadlines missed
    assert clock.done()
    assert clock.overruns == 1 and clock.skipped == 2
    assert clock.deadline == pytest.approx(start + 3 * 0.004)  # back on the grid
    clock.wait()
    c.t += 0.001
    assert not clock.done()


def test_real_time_collects_garbage_before_the_drives_are_fed(monkeypatch):
    """A full collection takes tens of milliseconds: after the drives have seen their first
    setpoint that is a lost master (their RPDO deadline), so it comes before, not between
    the initialisation and the first cycle."""
    import gc

    truth = rocaspect()
    w = World(truth, truth)
    seen = {}
    enable = w.hw.enable

    def spy_enable(*a, **k):
        seen["gc_enabled_at_enable"] = gc.isenabled()
        return enable(*a, **k)

    monkeypatch.setattr(w.hw, "enable", spy_enable)
    collections = []
    monkeypatch.setattr(gc, "collect", lambda *a: collections.append(
        (a, "enable" in seen)) or 0)
    was = gc.isenabled()
    _, res = _run(w, truth, [Dwell(0.05)], realtime=True, rt_priority=0)
    assert res.ended == "completed", res.message
    assert seen["gc_enabled_at_enable"] is False
    full = [after for a, after in collections if not a or a[0] == 2]
    assert full and not any(full)  # every full collection before the drives were enabled
    assert gc.isenabled() == was


def test_a_late_answer_is_judged_against_the_commands_of_its_sync():
    """Real time: a position answers the SYNC before the latest (or the one before); a
    drive that missed k SYNCs answers k earlier. A move of 10 mm per cycle: judged against
    the latest commands, the late drive would seem 30 mm behind."""
    sent = [np.full(3, 10.0 + 0.01 * i) for i in range(6)]  # 10.00 .. 10.05, newest last
    lengths = np.array([10.04, 10.02, 10.0])  # on time; 2 SYNCs late; beyond the history
    ref = reference_command(lengths, sent, np.array([0, 2, 9]))
    np.testing.assert_allclose(ref, [10.04, 10.02, 10.0])
    # a drive that answers on time but stands still is judged against its own SYNC's
    # commands, never an older one: the error is still seen
    ref = reference_command(np.array([10.0, 10.0, 10.0]), sent, np.zeros(3, int))
    np.testing.assert_allclose(ref, [10.04] * 3)
    assert reference_command(lengths, sent[:1], np.array([0, 2, 9])).tolist() == [10.0] * 3
