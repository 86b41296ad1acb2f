"""Benchmarks of online identification (controller/online_ident.py): the control cycle with the
identified model handed over, the hand-over itself, and one estimator update."""

from __future__ import annotations

import numpy as np

from bench.benchmarks import median_time, register
from bench.benchmarks.physics import PAPER_STIFFNESS, cycle_time
from controller.cycle import LengthController
from controller.effects import apply_effects
from controller.online_ident import Measurement, ModelHandover, OnlineIdentifier
from controller.robot import resolve_robot
from controller.statics import pose_statics

P0 = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.0])
#: cycles between two hand-overs of the model (the estimator's rate: 0.5 s at 256 Hz)
HANDOVER_EVERY = 128


def _setup():
    r = resolve_robot("rocaspect")
    model = r.replace(stiffness=np.tile(PAPER_STIFFNESS, (r.n_masts, 1)))
    rng = np.random.default_rng(1)
    truth = apply_effects(model, {"exit_point_offset": {
        f"d{a}_{c}": float(rng.normal(0, 0.005)) for c in model.cable_ids for a in "xyz"}})
    tau0 = pose_statics(truth, P0).tensions
    return model, truth, tau0, rng


class _Fix:
    """A tracker stand-in: ``read()`` returns the current sample's pose, now."""

    def __init__(self) -> None:
        from types import SimpleNamespace

        self.reading = SimpleNamespace(valid=True, pose=P0, t_s=0.0)

    def read(self):
        return self.reading


@register("learn")
def bench_learn(quick: bool) -> dict[str, float]:
    """``control_cycle_learn_us``: the control cycle of ``control_cycle_us`` with online
    identification as the dry run runs it on the wall clock, the estimator in a process of
    its own (:class:`bench.dryrun.learn.LoopLearner`, ``threaded``, ``process``): each
    cycle the learner keeps its sample (a tracked pose with tensions and lengths of the
    truth, 4 per period), every :data:`HANDOVER_EVERY` cycles (0.5 s at 256 Hz) it sends the
    batch to the estimator's process, and every tenth of that it takes the finished updates
    and hands the model over (rate-limited, :class:`~controller.online_ident.ModelHandover`)
    while the process runs its updates concurrently (the median is of cycles without a
    hand-over: ``learn_handover_us`` is the cost of those with one); ``learn_handover_us``:
    one hand-over (:meth:`~controller.cycle.LengthController.set_model`);
    ``ident_update_ms``: one estimator update with a batch of 4 tracked samples (what the
    process does per period)."""
    from types import SimpleNamespace

    from bench.dryrun.learn import LoopLearner

    model, truth, tau0, rng = _setup()
    poses = [P0 + np.r_[rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(-0.4, 0.6),
                        np.zeros(3)] for _ in range(64)]
    samples = []
    for p in poses:
        ps = pose_statics(truth, p)
        samples.append(Measurement(p, ps.tensions, ps.unstretched, True, 0.0))
    T = 0.0039
    ctl = LengthController(model, P0, tau0)
    fix = _Fix()
    clock = {"t": 0.0}
    learner = LoopLearner(fix, period_s=HANDOVER_EVERY * T, correlated=1.01, rate_offset=0.01,
                          state_time=lambda: clock["t"], threaded=True, process=True)
    k = [0]

    def learn():
        k[0] += 1
        t = clock["t"] = k[0] * T
        m = samples[(k[0] // 8) % len(samples)]
        fix.reading = SimpleNamespace(valid=True, pose=m.pose, t_s=t)
        r = SimpleNamespace(t_s=t, tensions_N=m.tensions, lengths_m=m.lengths,
                            tensions_ok=np.ones(len(m.tensions), bool))
        learner(t, r, m.pose, ctl)

    reps = 300 if quick else 5000
    try:
        cyc = cycle_time(model, reps, hook=learn, ctl=ctl)
    finally:
        learner.close()
    est = OnlineIdentifier(model, P0, tau0)
    hand = ModelHandover(est)
    est.theta = est.theta + np.r_[rng.normal(0, 0.003, est.n_offsets),
                                  np.zeros(len(est.theta) - est.n_offsets)]

    def one_handover():
        hand.advance(0.5)
        ctl.set_model(hand.robot())

    ho = median_time(one_handover, 20 if quick else 200, warmup=2)
    j = [0]

    def update():
        est.update(samples[4 * (j[0] % 16):4 * (j[0] % 16) + 4])
        j[0] += 1

    up = median_time(update, 5 if quick else 40, warmup=1)
    if learner.summary.updates == 0:
        raise RuntimeError("the estimator's process ran no update during the cycle benchmark")
    return {"control_cycle_learn_us": cyc * 1e6, "learn_handover_us": ho * 1e6,
            "ident_update_ms": up * 1e3}
