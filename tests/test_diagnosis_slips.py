"""Slip times the fit tells (``slips.later_starts``): a length offset that fits far better
from a later time on than from the initialisation, where no step in time was seen; none
where the offset was there from the start."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.diagnosis.slips import later_starts


class _Param:
    def __init__(self, key: str) -> None:
        self.key = key

    def to_value(self, phi: float) -> float:
        return phi


def _case(y: np.ndarray, t: np.ndarray, init: int = 1):
    """One whitened entry per sample: the reading's offset ``y`` against a model that applies
    a length offset ``dl_22`` to every sample after the initialisation's ``init``."""
    after = np.arange(len(y)) >= init
    space = SimpleNamespace(effects=("cable_length_offset",), neutral=np.zeros(1),
                            params=[_Param("dl_22")],
                            indices=lambda e: np.array([0]), robot=lambda phi: phi)
    rm = SimpleNamespace(
        s=SimpleNamespace(t=t, n=len(y)), model=SimpleNamespace(cable_ids=("11", "22")),
        slip_times=np.array([t[init - 1], t[init - 1]]), init_end=float(t[init - 1]),
        whitened=lambda phi, idx: (y - phi[0] * after)[idx],
        entry_samples=lambda idx: np.asarray(idx))
    dl = float(y[after].mean())  # the offset's fit from the initialisation on
    fit = SimpleNamespace(space=space, phi=np.array([dl]), stderr=np.array([0.1]))
    return rm, fit


def test_an_offset_that_starts_after_the_first_visits_is_a_later_slip():
    rng = np.random.default_rng(3)
    t = np.arange(20) * 30.0
    y = rng.normal(0.0, 1.0, 20)
    y[5:] += 22.0  # slipped between the fifth sample and the sixth
    rm, fit = _case(y, t)
    got = later_starts(rm, fit, np.arange(20), 31.0)
    assert list(got) == [1]
    t_s, size, gain = got[1]
    assert t_s == 0.5 * (t[4] + t[5])
    assert abs(size - y[5:].mean()) < 1e-9 and gain > 400.0


def test_an_offset_there_from_the_start_is_no_later_slip():
    """Must find nothing: the offset from the initialisation on, plus noise; and a cable
    whose slip time a step in time already set."""
    rng = np.random.default_rng(4)
    t = np.arange(20) * 30.0
    y = rng.normal(0.0, 1.0, 20)
    y[1:] += 22.0
    rm, fit = _case(y, t)
    assert later_starts(rm, fit, np.arange(20), 31.0) == {}
    y[1:6] -= 22.0  # slipped after the sixth sample: found where no step was seen
    rm, fit = _case(y, t)
    assert later_starts(rm, fit, np.arange(20), 31.0) != {}
    rm.slip_times[1] = t[5] + 1.0  # seen as a step already: not asked again
    assert later_starts(rm, fit, np.arange(20), 31.0) == {}


def test_a_step_beats_a_drift_but_a_drift_is_no_step():
    """With ``over_drift`` (a length offset asked for beside effects that chose none), a
    step is a later slip only where it fits better than the same change growing with time
    since the initialisation. A slow drift (no slip, out of the vocabulary) must give
    nothing, though a step half-way fits it far better than an offset from the start."""
    rng = np.random.default_rng(5)
    t = np.arange(40) * 10.0
    step = rng.normal(0.0, 1.0, 40)
    step[25:] += 15.0
    rm, fit = _case(step, t)
    got = later_starts(rm, fit, np.arange(40), 31.0, over_drift=25.0)
    assert list(got) == [1] and got[1][0] == 0.5 * (t[24] + t[25])
    drift = rng.normal(0.0, 1.0, 40) + 30.0 * (t - t[0]) / (t[-1] - t[0])
    rm, fit = _case(drift, t)
    assert later_starts(rm, fit, np.arange(40), 31.0) != {}  # the step alone: "a slip"
    assert later_starts(rm, fit, np.arange(40), 31.0, over_drift=25.0) == {}
