"""``cdpr dry-run --learn``'s learner (bench/dryrun/learn.py) on readings made by the controller's
model functions: samples only at rest and with a fix of this cycle, updates at its period,
the model handed over at a bounded rate."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np

from bench.cli import main
from bench.dryrun.learn import LoopLearner
from controller.cycle import LengthController
from controller.effects import apply_effects
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


def test_learn_refuses_realtime(capsys):
    assert main(["dry-run", "paper-centre", "--learn", "--realtime", "--json", "--quiet"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert "lock-step only" in out["error"]
