"""DriftReport.observe evaluates the batch's statics (its ``residual``) once per distinct
estimate: none during an event's hold, two where the estimates at the drift's start and at
the last event are one, three where all differ; the events and the change it reports are
those of evaluating each one."""

import numpy as np
import pytest

import controller.online_ident as oi
from controller.online_ident import DriftReport, Event

DET = [Event("drift", 0.0, "x")]


class Counted:
    """A made-up model whose residual at the batch's one sample is its one parameter [m]."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, th: np.ndarray) -> np.ndarray:
        self.calls += 1
        return np.array([[th[0]]])


def test_statics_evaluated_once_per_distinct_estimate():
    rep = DriftReport(move=1e-3, hold_s=10.0, quiet_s=50.0)
    steps = [  # t [s], estimate [m], detections, residual evaluations, events said
        (2.0, 0.0, DET, 0, ["drift"]),     # the first detection: start = ref
        (15.0, 0.5e-3, DET, 2, []),        # after the hold: now; ref and start are one
        (20.0, 2.0e-3, DET, 2, ["drift"]),  # moved by 2 mm: an event (ref = now)
        (25.0, 2.1e-3, DET, 0, []),        # its hold: the ref follows the estimate
        (31.0, 2.2e-3, DET, 3, []),        # now, ref (2.1 mm) and start (0) all differ
        (32.0, 2.1e-3, [], 2, []),         # the estimate back on the ref: now = ref
    ]
    for t, x, found, calls, kinds in steps:
        res = Counted()
        said = rep.observe(t, np.array([x]), found, res)
        assert res.calls == calls, t
        assert [e.kind for e in said] == kinds, t
    assert abs(rep.summary()["length_change_mm"] - 2.2) < 1e-9
    assert rep.summary()["events"] == 2


def test_the_same_answers_as_evaluating_each_estimate():
    """Random walks of a two-parameter estimate, some updates leaving it where it stood: the
    report's events and change equal those of a report evaluating every estimate."""
    every = lambda residual, thetas: [residual(th) for th in thetas]  # noqa: E731
    rng = np.random.default_rng(5)
    for _ in range(20):
        a = DriftReport(move=1e-3, hold_s=10.0, quiet_s=40.0)
        b = DriftReport(move=1e-3, hold_s=10.0, quiet_s=40.0)
        x = np.zeros(2)
        for k in range(60):
            if rng.uniform() < 0.7:  # some updates leave the estimate where it stood
                x = x + rng.normal(scale=4e-4, size=2)
            found = DET if rng.uniform() < 0.4 else []
            ea = a.observe(3.0 * k, x.copy(), found, lambda th: np.array([th, 2 * th]))
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(oi, "_each_once", every)
                eb = b.observe(3.0 * k, x.copy(), found, lambda th: np.array([th, 2 * th]))
            assert [(e.kind, e.detail) for e in ea] == [(e.kind, e.detail) for e in eb]
        assert a.summary() == b.summary()
