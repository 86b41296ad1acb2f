"""``cdpr dry-run --learn``'s learner (bench/dryrun/learn.py) on readings made by the controller's
model functions: samples only at rest and with a fix of this cycle, updates at its period,
the model handed over at a bounded rate."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from bench.cli import main
from bench.dryrun.learn import LoopLearner
from controller.cycle import LengthController
from controller.effects import apply_effects
from controller.online_ident import OnlineIdentifier
from controller.statics import pose_statics
from tests.robots import rocaspect
from tests.test_online_ident import P0, Plant


class FakeTracker:
    def __init__(self) -> None:
        self.reading = SimpleNamespace(valid=False, pose=np.full(6, np.nan), t_s=np.nan)

    def read(self):
        return self.reading


def test_learner_learns_at_rest_and_hands_over():
    model = rocaspect(compliant=True)
    truth = apply_effects(model, {"exit_point_offset": {"dx_11": 0.004, "dy_21": -0.004}})
    plant = Plant(model, truth, seed=1)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    # (correlation limit off: four poses leave every parameter correlated with others)
    learner = LoopLearner(tracker, period_s=0.5, per_update=2, still_s=0.2, correlated=1.01)
    targets = [P0 + np.r_[dx, dy, dz, 0, 0, 0]
               for dx, dy, dz in ((2, 1, 0.3), (-3, 2, 0), (1, -2, 0.6), (-2, -1, 0.2))]
    T, t, events, moving_samples = 0.01, 0.0, [], 0
    before = ctl.robot
    for target in targets:
        for phase in ("move", "rest"):
            for _ in range(60 if phase == "move" else 120):
                t += T
                pose = target + (0.01 * np.sin(t) if phase == "move" else 0.0)
                m = plant.measure(pose, t)
                tracker.reading = SimpleNamespace(valid=True, pose=m.pose, t_s=t)
                r = SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                                    tensions_ok=np.ones(8, bool))
                n0, seen = len(learner._batch), learner._last_des is not None
                events += learner(t, r, pose, ctl)
                moving_samples += phase == "move" and seen and len(learner._batch) > n0
    rep = learner.report()
    assert moving_samples == 0  # never while the commanded pose moves
    assert rep["updates"] >= 4 and rep["samples"] >= 8 and rep["rejected"] == 0, rep
    assert rep["handovers"] > 0 and ctl.robot is not before
    assert not [e for e in events if e[0] == "learn_sudden_change"], events
    # the hand-over moves at most rate * time: here 2 mm/s over ~10 s, the estimate ~4 mm
    moved = np.abs(ctl.robot.exits - model.exits).max()
    assert 0 < moved <= 2e-3 * t + 1e-12
    assert abs(rep["offsets_mm"]["dx_11"] - 4.0) < 3.0, rep["offsets_mm"]
    ps = pose_statics(truth, P0)
    assert np.all(np.isfinite(ctl.step(P0, ps.tensions).lengths))


def test_learn_runs_in_real_time(capsys):
    """``--learn --realtime``: the estimator in its own process, ended with the run (none
    left); the run completes with the learner's report."""
    import multiprocessing

    rc = main(["dry-run", "paper-centre", "--learn", "--realtime", "--duration", "1.5",
               "--json", "--quiet", "--learn-period", "0.25"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0, out
    assert out["realtime"] and out["cycles"] > 0 and "learn" in out, out
    assert not [p for p in multiprocessing.active_children() if p.name == "cdpr-estimator"]


class SlowIdent(OnlineIdentifier):
    """The estimator with each update made 0.3 s slower (a sleep, then a busy loop: the
    interpreter's lock held, as a slow update in Python holds it)."""

    def update(self, batch):
        import time

        time.sleep(0.15)
        t_end = time.perf_counter() + 0.15
        while time.perf_counter() < t_end:
            pass
        return super().update(batch)


def _slow_cycles(threaded: bool, process: bool = False):
    """Wall time [s] of each learner call (the cycle's share) over 1.2 s of cycles, with the
    estimator's update made 0.3 s slower (:class:`SlowIdent`); and the learner."""
    import time

    model = rocaspect(compliant=True)
    plant = Plant(model, model, seed=3)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    learner = LoopLearner(tracker, period_s=0.1, per_update=2, threaded=threaded,
                          process=process)
    learner.ident_class = SlowIdent
    learner(0.0, _reading(plant, tracker, P0, 0.0), P0, ctl)  # the start: not timed
    walls = []
    for k in range(1, 121):
        t = 0.01 * k
        pose = P0 + np.r_[0.1 * t, 0, 0, 0, 0, 0]
        r = _reading(plant, tracker, pose, t)
        t0 = time.perf_counter()
        learner(t, r, pose, ctl)
        walls.append(time.perf_counter() - t0)
    learner.close()
    return np.array(walls), learner


def _reading(plant, tracker, pose, t):
    m = plant.measure(pose, t)
    tracker.reading = SimpleNamespace(valid=True, pose=m.pose, t_s=t)
    return SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                           tensions_ok=np.ones(8, bool))


@pytest.mark.parametrize("process", [False, True])
def test_threaded_learner_never_blocks_the_cycle(process):
    """An estimator update made 0.3 s slower: on its thread or in its process, no cycle's
    learner call waits for it (each well below the delay; the updates still happen,
    behind, and the same as in the cycle); in the cycle (not threaded), the calls that
    update take the delay (what the thread is for)."""
    walls, learner = _slow_cycles(threaded=True, process=process)
    assert walls.max() < 0.1, walls.max()
    assert learner.summary.updates >= 1  # they ran aside (close waited for them)
    walls_in, inline = _slow_cycles(threaded=False)
    assert walls_in.max() >= 0.3
    k = learner.summary.updates  # the same estimate after the same updates
    assert k <= inline.summary.updates
    if k == inline.summary.updates:
        np.testing.assert_allclose(learner.ident.theta, inline.ident.theta, atol=1e-12)


def _drive(learner, plant, ctl, tracker, settle_every: int, cycles: int, moving: bool,
           tracked: bool = True):
    """Cycles of 0.01 s along a line (``moving``) or at rest; the plant's state is fresh every
    ``settle_every`` cycles (``learner.state_time``). Returns (kept samples, cycles at which
    the state was fresh)."""
    T, fresh_t = 0.01, [0.0]
    learner.state_time = lambda: fresh_t[0]
    kept, fresh = [], []
    for k in range(1, cycles + 1):
        t = k * T
        pose = P0 + (np.r_[0.2 * t, 0.1 * t, 0, 0, 0, 0] if moving else 0.0)
        if k % settle_every == 0:
            fresh_t[0] = t
            fresh.append(k)
        m = plant.measure(pose, t)
        tracker.reading = SimpleNamespace(valid=tracked, pose=m.pose if tracked else
                                          np.full(6, np.nan), t_s=t)
        r = SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                            tensions_ok=np.ones(8, bool))
        learner(t, r, pose, ctl)
        if learner._last_kept == t:
            kept.append(k)
    return kept, fresh


def test_learner_keeps_quasi_static_samples_while_moving():
    """With ``state_time``, samples while moving, only at cycles whose readings are of a
    settled plant state; without it, none while moving."""
    model = rocaspect(compliant=True)
    plant = Plant(model, model, seed=2)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    learner = LoopLearner(tracker, period_s=0.5, per_update=10)
    kept, fresh = _drive(learner, plant, ctl, tracker, 3, 120, moving=True)
    assert kept and set(kept) <= set(fresh), (kept, fresh)
    assert learner.summary.samples + len(learner._batch) >= 10
    still = LoopLearner(tracker, period_s=0.5, per_update=10)
    _drive(still, plant, LengthController(model, P0, plant.init_readings), tracker, 3, 120,
           moving=True)
    still.state_time = None
    n0 = still.summary.samples + len(still._batch)
    for k in range(20):  # without state_time: moving cycles give nothing
        t = 1.3 + 0.01 * k
        pose = P0 + np.r_[0.2 * t, 0, 0, 0, 0, 0]
        m = plant.measure(pose, t)
        tracker.reading = SimpleNamespace(valid=True, pose=m.pose, t_s=t)
        still(t, SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                                 tensions_ok=np.ones(8, bool)), pose, ctl)
    assert still.summary.samples + len(still._batch) == n0


def test_untracked_learner_uses_the_commanded_pose():
    model = rocaspect(compliant=True)
    plant = Plant(model, model, seed=2)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    learner = LoopLearner(tracker, period_s=0.5, per_update=4, use_tracker=False)
    _drive(learner, plant, ctl, tracker, 2, 40, moving=True, tracked=False)
    assert learner._batch or learner.summary.samples
    assert all(not m.tracked for m in learner._batch)
    tracked = LoopLearner(tracker, period_s=0.5, per_update=4)
    _drive(tracked, plant, ctl, tracker, 2, 40, moving=True, tracked=False)
    assert not tracked._batch and tracked.summary.samples == 0  # no fix: nothing


def test_threaded_learner_learns_the_same():
    """The estimator on its own thread: the same batches, the same estimate; the hand-over
    follows."""
    model = rocaspect(compliant=True)
    truth = apply_effects(model, {"exit_point_offset": {"dx_11": 0.004, "dy_21": -0.004}})
    out = []
    for threaded in (False, True):
        plant = Plant(model, truth, seed=1)
        ctl = LengthController(model, P0, plant.init_readings)
        tracker = FakeTracker()
        learner = LoopLearner(tracker, period_s=0.2, per_update=2, threaded=threaded,
                              correlated=1.01)
        _drive(learner, plant, ctl, tracker, 2, 150, moving=True)
        learner.close()
        out.append((learner.summary.updates, learner.ident.theta.copy()))
    assert out[0][0] == out[1][0] > 3
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=0, atol=1e-12)


def test_identifiability_said_at_the_first_cycle():
    from controller.trajectory import Line, Trajectory

    model = rocaspect(compliant=True)
    plant = Plant(model, model, seed=2)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    learner = LoopLearner(tracker)
    corners = [[12.0, 10.0, 1.6], [8.0, 10.0, 0.8], [8.0, 7.0, 1.6], [12.0, 7.0, 0.8]]
    learner.trajectory = lambda: Trajectory([Line(corners)], P0)
    m = plant.measure(P0, 0.01)
    ev = learner(0.01, SimpleNamespace(t_s=0.01, tensions_N=m.tensions, lengths_m=m.lengths,
                                       tensions_ok=np.ones(8, bool)), P0, ctl)
    kinds = [k for k, _ in ev]
    assert kinds[0] == "learn_identifiable", ev
    idf = learner.identifiable
    assert idf["tracker"]["determined"] > idf["no_tracker"]["determined"]
    assert "cz_1" in idf["tracker"]["undetermined"]  # torsion: a path hardly loads it
    assert "with the tracker" in ev[0][1] and "without it" in ev[0][1]
    assert learner.report()["identifiable"] == idf


def test_handover_moves_the_model_in_small_steps():
    """The model changes every ``handover_s``, each time by at most the rate times it (not
    the period's worth at once: that was a setpoint step of ~10 mm)."""
    model = rocaspect(compliant=True)
    truth = apply_effects(model, {"exit_point_offset": {"dx_11": 0.01, "dy_21": -0.01}})
    plant = Plant(model, truth, seed=1)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    learner = LoopLearner(tracker, period_s=0.2, per_update=2, correlated=1.01,
                          rate_offset=0.01, handover_s=0.02)
    steps, last = [], None
    T, fresh = 0.01, [0.0]
    learner.state_time = lambda: fresh[0]
    for k in range(1, 201):
        t = k * T
        pose = P0 + np.r_[2.0 * np.sin(t), 1.5 * np.sin(2 * t), 0.3 * np.sin(3 * t), 0, 0, 0]
        fresh[0] = t if k % 2 == 0 else fresh[0]
        m = plant.measure(pose, t)
        tracker.reading = SimpleNamespace(valid=True, pose=m.pose, t_s=t)
        learner(t, SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                                   tensions_ok=np.ones(8, bool)), pose, ctl)
        if learner.hand is not None:
            if last is not None:
                steps.append(np.abs(learner.hand.theta - last))
            last = learner.hand.theta.copy()
    steps = np.array(steps)
    bound = learner.hand._rate * (0.02 + T) * (1 + 1e-9) + 1e-15  # rate x time since the last
    assert learner.summary.handovers > 3 * learner.summary.updates > 0
    assert np.all(steps <= bound), (steps / bound).max()
    assert steps.sum() > 0  # it did move


def test_set_model_keeps_the_running_state():
    """Handing over the same model changes no setpoint: the mast update keeps the last
    cycle's cable directions (those at p0 moved the exit points by centimetres for a cycle,
    a setpoint jump at each hand-over far from p0)."""
    model = rocaspect(compliant=True)
    far = P0 + np.r_[-7.0, 3.0, 0.4, 0, 0, 0]
    tau = pose_statics(model, far).tensions
    a = LengthController(model, P0, pose_statics(model, P0).tensions)
    b = LengthController(model, P0, pose_statics(model, P0).tensions)
    for ctl in (a, b):
        ctl.step(far, tau)
    b.set_model(model.replace(name="handed over"))
    np.testing.assert_allclose(b.step(far, tau).lengths, a.step(far, tau).lengths,
                               rtol=0, atol=1e-12)


def test_tracker_on_its_own_clock_pairs_fixes_at_rest():
    """A tracker whose fix times are on its own clock (over TCP: 1000 s apart from the
    readings'): fixes pair with the cycles at rest once the platform stood still
    ``still_s``, and only with fixes received since; with the shared-clock rule, none."""
    model = rocaspect(compliant=True)
    plant = Plant(model, model, seed=4)
    kept = {}
    for shared in (True, False):
        ctl = LengthController(model, P0, plant.init_readings)
        tracker = FakeTracker()
        learner = LoopLearner(tracker, period_s=10.0, per_update=1000, still_s=0.2,
                              shared_clock=shared)
        moving_kept = 0
        for k in range(1, 101):
            t = 0.01 * k
            moving = 2 <= k <= 50  # (the first cycle: at rest before it)
            pose = P0 + np.r_[0.1 * min(t, 0.5), 0, 0, 0, 0, 0]
            m = plant.measure(pose, t)
            age = 0.0 if moving or k % 5 else 0.15  # some fixes arrive late (received before)
            tracker.reading = SimpleNamespace(valid=True, pose=m.pose, t_s=1000.0 + t,
                                              age_s=age)
            n0 = len(learner._batch)
            learner(t, SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                                       tensions_ok=np.ones(8, bool)), pose, ctl)
            if len(learner._batch) > n0:
                moving_kept += moving
                assert t - tracker.reading.age_s >= learner._still_since + 0.2 - 1e-9
        kept[shared] = (len(learner._batch), moving_kept)
    assert kept[True] == (0, 0)
    assert kept[False][0] > 10 and kept[False][1] == 0, kept


@pytest.mark.parametrize("untracked", [True, False])
def test_tracker_for_the_first_seconds_then_untracked_or_stop(untracked):
    """``tracked_s``: the tracker's fixes for that long after the first cycle, then a
    ``learn_untracked`` event and tensions and encoders only (``untracked``), or no more
    samples (not ``untracked``)."""
    model = rocaspect(compliant=True)
    plant = Plant(model, model, seed=6)
    ctl = LengthController(model, P0, plant.init_readings)
    tracker = FakeTracker()
    learner = LoopLearner(tracker, period_s=10.0, per_update=200, tracked_s=lambda: 0.5,
                          untracked=untracked)
    events = []
    for k in range(1, 101):
        t = 0.01 * k
        events += learner(t, _reading(plant, tracker, P0, t), P0, ctl)
    kinds = [e[0] for e in events]
    assert kinds.count("learn_untracked") == 1
    # the tracked samples went to the estimator at the switch, in a batch of their own
    assert learner.summary.updates == 1 and learner.summary.samples > 0
    after = learner._batch
    assert all(m.t >= 0.51 - 1e-9 for m in after)
    if untracked:
        assert after and not any(m.tracked for m in after)
    else:
        assert not after
