"""The selection's answer does not hang on the process pool: fits made ahead on the pool
(:meth:`Selector.prefetch`) are only made, never kept by the selection in place of what
:meth:`Selector.fit` keeps, so a selection with a pool holds the fits one without holds
(kept in its cache, the prefetched sets counted in the search's budget and in its pairs of
single effects: the path of the search hung on the pool), and a fit's finite-difference
columns are the same whichever of them a forked child computes."""

from __future__ import annotations

import copy
import dataclasses
import pickle
from concurrent.futures import Future

import numpy as np
import pytest
from residual_models import campaign_residual_model

import bench.diagnosis.fit as fit_module
from bench.campaign import run_campaign
from bench.diagnosis.fit import fd_jacobian
from bench.diagnosis.report import split_samples
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import check_values, prepare
from bench.diagnosis.select import Selector
from bench.diagnosis.space import ParamSpace
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario


class WorkerLike:
    """An executor that runs each job at once on a pickled copy of its arguments and hands
    back a pickled copy of its result, as a process pool's worker does (its own residual
    model, warm starts and memo)."""

    def __init__(self) -> None:
        self.jobs = 0

    def submit(self, fn, *args, **kw) -> Future:
        fn, args, kw = pickle.loads(pickle.dumps((fn, args, kw)))
        self.jobs += 1
        fut: Future = Future()
        fut.set_result(pickle.loads(pickle.dumps(fn(*args, **kw))))
        return fut


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 45,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"drum_scale": {"s_21": 1.004, "s_32": 0.997},
                  "cable_length_offset": {"dl_12": 0.004}}, "nuisance": {},
        "poses": {"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2},
        "recording": {}})
    rec = read_recording(run_campaign(sc, tmp_path_factory.mktemp("pool45") / "rec"))
    check_values(rec)
    return rec


def _selector(rec, pool) -> Selector:
    """A selector of its own (its own residual model: nothing shared with another)."""
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return Selector(rm, split_samples(s, rec.init_pose)[0], [], pool=pool)


def _counting(made: list, real):
    """``real`` (a fit made anew), the effects of each call appended to ``made``."""
    def fit(*a, **k):
        made.append(a[0].effects)
        return real(*a, **k)
    return fit


def test_a_prefetch_leaves_what_the_selection_keeps_and_fit_answers_as_without_a_pool(
        recording, monkeypatch):
    """After a prefetch of two sets (one fitted before, a subset of the start: a refit),
    the selection with a pool keeps the fits and refits it kept before, and :meth:`fit`
    then answers as the selection without a pool does, bit for bit, from the pool's fits
    (none made in this process)."""
    sets = [("drum_scale",), ("cable_length_offset",)]
    both = ("cable_length_offset", "drum_scale")
    answers = {}
    for name, pool in (("alone", None), ("pooled", WorkerLike())):
        sel = _selector(recording, pool)
        first = sel.fit(("drum_scale",))
        start = sel.fit(both, first)
        kept, refits = dict(sel.cache), set(sel._refit_from)
        sel.prefetch(sets, start, refits=True)
        assert sel.cache == kept and sel._refit_from == refits  # (the old code added both)
        made: list[tuple[str, ...]] = []
        with monkeypatch.context() as m:
            m.setattr(fit_module, "_fit_effects", _counting(made, fit_module._fit_effects))
            answers[name] = [sel.fit(k, start) for k in sets]
        if pool is not None:
            assert pool.jobs >= 2 and not made  # the fits were the pool's
        else:
            assert made  # (without a pool, fit makes them here)
    for a, b in zip(answers["alone"], answers["pooled"], strict=True):
        assert a.space.effects == b.space.effects
        assert np.array_equal(a.phi, b.phi) and a.chi2 == b.chi2 and a.bic == b.bic


@pytest.fixture(scope="module")
def sagging(tmp_path_factory) -> ResidualModel:
    """The residual model of a recording of ROCASPECT with sagging cables (load cells, a
    tracker)."""
    return campaign_residual_model(tmp_path_factory.mktemp("sag") / "rec",
                                   {"cable_sag": {"rho": 0.08},
                                    "exit_point_offset": {"dx_21": 0.02}})


def test_a_jacobian_column_is_the_same_after_the_others_or_alone(sagging):
    """Each column of a finite-difference Jacobian (sagging cables: the initialisation's
    catenaries are warm-started) is the same, to the bit, computed after the columns before
    it (in one process) or alone from the evaluation it differs from (the half a forked child
    computes beside a process pool, :func:`bench.diagnosis.fit.fd_jacobian`). The old code
    kept each column's initialisation for the next: 24 of 25 columns differed by 1e-6 of
    their size."""
    space = ParamSpace(sagging.model, ("cable_sag", "exit_point_offset"))
    x = space.neutral.copy()
    x[0] = space.params[0].from_value(0.07)
    steps = space.scale * 1e-2
    rm = copy.deepcopy(sagging)
    f0 = rm.whitened(space.robot(x))
    base = copy.deepcopy(rm)  # the state a forked child starts from
    J = fd_jacobian(lambda phi: rm.whitened(space.robot(phi)), x, f0, steps, space.lo,
                    space.hi, rm.frozen)
    for k in range(len(x)):
        alone = copy.deepcopy(base)
        h = steps[k] if x[k] + steps[k] <= space.hi[k] else -steps[k]
        xp = x.copy()
        xp[k] += h
        with alone.frozen():
            col = (alone.whitened(space.robot(xp)) - f0) / h
        assert np.array_equal(col, J[:, k]), space.params[k].key


def test_a_swap_screen_is_not_handed_to_a_later_fit_at_the_same_address(recording):
    """The swap screen's cache is keyed by the fit's id: a fit it was made for and then let
    go of must not hand its screen to a later fit the allocator puts at the same address
    (which fits are alive there hangs on the pool and on what ran before). The old code kept
    only the id: the later fit, at the model's values, got the screen of the fit at the
    minimum."""
    sel = _selector(recording, None)
    chosen, candidates = ["drum_scale"], ["drum_scale", "cable_length_offset"]
    fitted = sel.fit(("drum_scale",))
    at_model = dataclasses.replace(fitted, phi=fitted.space.neutral.copy())
    want = _selector(recording, None).swap_screen(at_model, chosen, candidates)
    first = dataclasses.replace(fitted)
    address = id(first)
    got_first = sel.swap_screen(first, chosen, candidates)
    assert abs(got_first[("drum_scale", "cable_length_offset")]
               - want[("drum_scale", "cable_length_offset")]) > 1.0  # (two screens apart)
    del first
    held = []
    for _ in range(2000):  # a later fit, at the first one's address where the allocator can
        later = dataclasses.replace(at_model)
        if id(later) == address:
            break
        held.append(later)
    got = sel.swap_screen(later, chosen, candidates)
    assert got.keys() == want.keys()
    for k, v in want.items():
        assert got[k] == pytest.approx(v, rel=1e-6, abs=1e-6), k
