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


@register("learn")
def bench_learn(quick: bool) -> dict[str, float]:
    """``control_cycle_learn_us``: the control cycle of ``control_cycle_us`` with the identified
    model handed over every :data:`HANDOVER_EVERY` cycles (rate-limited,
    :class:`~controller.online_ident.ModelHandover`; the estimator itself runs outside the
    cycle, at the tracker's rate); ``learn_handover_us``: one hand-over
    (:meth:`~controller.cycle.LengthController.set_model`); ``ident_update_ms``: one estimator
    update with a batch of 4 tracked samples."""
    model, truth, tau0, rng = _setup()
    est = OnlineIdentifier(model, P0, tau0)
    hand = ModelHandover(est)
    est.theta = est.theta + np.r_[rng.normal(0, 0.003, est.n_offsets),
                                  np.zeros(len(est.theta) - est.n_offsets)]
    ctl = LengthController(model, P0, tau0)
    k = [0]

    def handover():
        k[0] += 1
        if k[0] % HANDOVER_EVERY == 0:
            hand.advance(HANDOVER_EVERY * 0.0039)
            ctl.set_model(hand.robot())

    reps = 300 if quick else 5000
    cyc = cycle_time(model, reps, hook=handover, ctl=ctl)

    def one_handover():
        hand.advance(0.5)
        ctl.set_model(hand.robot())

    ho = median_time(one_handover, 20 if quick else 200, warmup=2)
    poses = [P0 + np.r_[rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(-0.4, 0.6),
                        np.zeros(3)] for _ in range(64)]
    samples = []
    for p in poses:
        ps = pose_statics(truth, p)
        samples.append(Measurement(p, ps.tensions, ps.unstretched, True, 0.0))
    j = [0]

    def update():
        est.update(samples[4 * (j[0] % 16):4 * (j[0] % 16) + 4])
        j[0] += 1

    up = median_time(update, 5 if quick else 40, warmup=1)
    return {"control_cycle_learn_us": cyc * 1e6, "learn_handover_us": ho * 1e6,
            "ident_update_ms": up * 1e3}
