"""Noise that cannot hide a change (:mod:`bench.diagnosis.noise`): replicate visits are tested
for systematic differences before they are pooled as noise.

The load-change case of issue 32: the platform's load changes between the first and the
second visit of each pose. Pooled, the replicate visits read the change as 17 N of
load-cell noise and the report said the model explains the data; tested first, the change
is located in time and declared ``unexplained`` with the time it began. A campaign where
nothing changed names and declares nothing (at several noise levels); a slip is still a
slip, named with its time."""

from __future__ import annotations

import copy
from contextlib import contextmanager

import numpy as np
import pytest

import bench.campaign as campaign
from bench.campaign import run_campaign
from bench.diagnosis import noise, unexplained
from bench.diagnosis.report import diagnose
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.evaluate import one_blas_thread
from bench.recording import read_recording
from firmware_sim.plant import Plant
from firmware_sim.scenario import parse_scenario

POSES = {"kind": "grid", "n": [3, 2, 2], "x": [6.0, 14.0], "y": [5.0, 12.0], "z": [0.8, 1.6],
         "rpy_deg": 0.0, "visits": 3, "dwell_s": 2.0, "init_s": 3.0, "speed_m_s": 0.5}


def _scenario(seed: int = 7, visits: int = 3, tracker_m: float = 5e-5,
              process_m: float = 1e-4, truth: dict | None = None,
              kind: str = "dwell") -> dict:
    return {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": seed,
            "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0], "truth": truth or {},
            "noise": {"process_m": process_m, "tracker_m": tracker_m},
            "nuisance": {"hysteresis_m": 5e-5, "drift_m_per_h": 2e-5},
            "poses": {**copy.deepcopy(POSES), "visits": visits},
            "recording": {"kind": kind, "rate_hz": 4.0, "dwell_at_targets": True}}


@contextmanager
def _load_changes_at(t_change: float, factor: float):
    """Campaigns whose platform mass is multiplied by ``factor`` from ``t_change`` [s] on."""
    class Changed(Plant):
        def settle(self, readings, t=0.0, visit_noise=None, guess=None):
            if t >= t_change and not getattr(self, "_changed", False):
                self.truth = self.truth.replace(mass=self.truth.mass * factor)
                self._changed = True
            return super().settle(readings, t, visit_noise, guess)
    old = campaign.Plant
    campaign.Plant = Changed
    try:
        yield
    finally:
        campaign.Plant = old


@pytest.fixture(scope="module")
def load_change(tmp_path_factory):
    """(recording directory, time of the change [s]): the load 15 % heavier from the end of
    the first round of visits on."""
    d = tmp_path_factory.mktemp("load")
    first = read_recording(run_campaign(parse_scenario(_scenario(visits=1)), d / "first"))
    t_change = float(first.t[-1]) + 0.1
    with _load_changes_at(t_change, 1.15):
        rec = run_campaign(parse_scenario(_scenario()), d / "rec")
    return rec, t_change


def _changes(path) -> tuple[ResidualModel, list[noise.Change]]:
    rec = read_recording(path)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return rm, noise.find_changes(rm, rm.blocks(rec.robot))


def test_a_load_change_is_declared_with_its_time(load_change):
    one_blas_thread()
    path, t_change = load_change
    rep = diagnose(path).report
    left = rep["unexplained"]
    assert left is not None, rep["mismatch"]["summary"]
    steps = [c for c in left["changes"] if c["kind"] == "step"]
    assert steps, left
    lo, hi = steps[0]["between_s"]
    assert lo < t_change < hi  # between the last visit before it and the first after
    assert lo <= steps[0]["t_s"] <= hi
    assert "t = " in left["summary"]
    # the noise is what is random: the load cells' spread, not the load change
    assert rep["mismatch"]["noise"]["force"] < 2.0
    assert rep["mismatch"]["noise"]["systematic"]


def test_pooling_without_the_test_hides_the_change(load_change):
    """What the test guards: the same visits pooled as they are read the load change as
    noise (force noise of tens of newtons)."""
    rm, changes = _changes(load_change[0])
    assert rm.noise_summary()["force"] > 10.0
    before = rm.noise_summary()["force"]
    rm.s.target = noise.split_targets(rm.s.target, rm.s.t, noise.change_times(changes))
    rm.estimate_noise(rm.model)
    assert rm.noise_summary()["force"] < before / 10


@pytest.mark.parametrize("tracker_m,process_m", [(1e-5, 2e-5), (5e-5, 1e-4), (3e-4, 5e-4)])
@pytest.mark.parametrize("seed", [3, 11])
def test_nothing_changed_nothing_found(tmp_path, seed, tracker_m, process_m):
    path = run_campaign(parse_scenario(_scenario(seed=seed, tracker_m=tracker_m,
                                                 process_m=process_m)), tmp_path / "rec")
    _, changes = _changes(path)
    assert changes == []


def test_a_null_campaign_names_and_declares_nothing(tmp_path):
    one_blas_thread()
    path = run_campaign(parse_scenario(_scenario(seed=5)), tmp_path / "rec")
    rep = diagnose(path).report
    assert rep["effects"] == [] and rep["unexplained"] is None, rep["mismatch"]["summary"]
    assert rep["mismatch"]["noise"]["systematic"] == []


def test_a_slip_is_named_with_its_time_not_declared(tmp_path):
    one_blas_thread()
    probe = read_recording(run_campaign(parse_scenario(_scenario(visits=1)), tmp_path / "p"))
    t_slip = float(probe.t[-1]) + 0.1
    truth = {"cable_length_offset": {"dl_21": 3e-3, "slip_time_21": t_slip}}
    rep = diagnose(run_campaign(parse_scenario(_scenario(truth=truth)),
                                tmp_path / "rec")).report
    named = {e["name"]: e for e in rep["effects"]}
    assert set(named) == {"cable_length_offset"}, rep["mismatch"]["summary"]
    assert set(named["cable_length_offset"]["params"]) == {"dl_21"}
    times = [st["t_s"] for st in rep["mismatch"]["steps"] if st["cable"] == "21"]
    assert times and abs(times[0] - t_slip) < 25.0
    assert rep["unexplained"] is None or not rep["unexplained"].get("changes")


def test_split_targets_and_high_frequency_noise():
    target = np.array([0, 1, 0, 1, 0, 1])
    t = np.arange(6.0)
    g = noise.split_targets(target, t, [2.5])
    assert len(np.unique(g)) == 4 and g[0] == g[2] and g[2] != g[4]
    # second differences remove a smooth (quadratic over three samples: linear) trend
    rng = np.random.default_rng(0)
    x = np.linspace(0, 1, 400) * 5e-3 + rng.normal(0, 1e-4, 400)

    class _S:
        block = np.zeros(400, dtype=int)
        t = np.arange(400.0)

    class _RM:
        s = _S()

        def block_values(self, b):
            return {"length": x[:, None]}

    got = noise.high_frequency(_RM(), None)["length"]
    assert 0.8e-4 < got < 1.2e-4


class _FakeSamples:
    def __init__(self, n_targets: int, visits: int, n: int, rng) -> None:
        self.target = np.tile(np.arange(n_targets), visits)
        N = len(self.target)
        self.t = np.arange(N, dtype=float) * 10.0
        self.is_init = np.zeros(N, dtype=bool)
        pos = rng.uniform([3, 3, 0.5], [17, 14, 2], size=(n_targets, 3))
        self.pose_meas = np.concatenate([pos[self.target], np.zeros((N, 3))], axis=1)
        self.pose_des = self.pose_meas
        self.count = np.full(N, 6)
        self.kind = np.zeros(N, dtype=int)
        self.block = self.target.copy()
        self.n = N
        self.direction = rng.choice([-1.0, 1.0], size=(N, n))
        self.tau = np.full((N, n), np.nan)  # (no load cells)


class _FakeModel:
    cable_ids = tuple(f"{m}{k}" for m in "1234" for k in "12")


class _FakeRM:
    """The parts of a ResidualModel that :func:`noise.find_changes` reads: length residuals
    ``x`` (N, 8) of targets visited ``visits`` times."""

    def __init__(self, x: np.ndarray, s: _FakeSamples) -> None:
        self.s, self.x, self.model = s, x, _FakeModel()
        self.white_k = {0: {"length": 1e-6}, 1: {"length": 1e-6}}
        self.len_rank = np.full(len(s.t), float(x.shape[1]))  # independent columns

    def block_values(self, b):
        return {"length": self.x}

    def replicate_groups(self, groups):
        return {"length": np.repeat(self.s.target[:, None], self.x.shape[1], axis=1)}


def _fake(seed: int, kind: str | None, size: float = 8.0) -> list[noise.Change]:
    """Replicate deviations of unit noise, a model error per target, and (``kind``) a step
    at the campaign's middle, a trend, or a difference by direction of ``size`` noise."""
    rng = np.random.default_rng(seed)
    s = _FakeSamples(15, 3, 8, rng)
    x = rng.normal(0, 5.0, (15, 8))[s.target] + rng.normal(0, 1.0, (len(s.t), 8))
    if kind == "step":
        x += size * (s.t > s.t.mean())[:, None]
    elif kind == "trend":
        x += size * (s.t / s.t.max())[:, None]
    elif kind == "direction":
        x += 0.5 * size * s.direction
    return noise.find_changes(_FakeRM(x * 1e-4, s), None)


@pytest.mark.parametrize("seed", range(40))
def test_pure_noise_is_no_systematic_difference(seed):
    assert _fake(seed, None) == []


@pytest.mark.parametrize("kind", ["step", "trend", "direction"])
def test_each_systematic_difference_is_found(kind):
    # (a trend of 16 noise over the campaign: 5 between visits a third of it apart)
    got = _fake(1, kind, 16.0 if kind == "trend" else 8.0)
    assert got and got[0].kind == kind, got
    if kind == "step":
        t_mid = 10.0 * 45 / 2
        assert got[0].before_s < t_mid < got[0].after_s


def test_a_length_step_a_named_offset_accounts_for_is_not_declared():
    step = noise.Change("step", "length", ["21", "22"], 135.6, 7.0, 4.0, 134.0, 137.1)
    load = noise.Change("step", "force", ["z"], 135.6, 9.0, 50.0, 134.0, 137.1)
    # a slip the report places between the step's samples, or an offset on its cable
    assert unexplained.with_changes(None, [copy.copy(step)], {"21": 135.0}) is None
    effects = [{"name": "cable_length_offset", "params": {"dl_21": -3e-3}, "explains": "x"}]
    named = [copy.copy(step)]
    assert unexplained.with_changes(None, named, {}, {"21"}) is None
    noise.annotate(effects, named)
    assert "t = 135.6 s on cable 21" in effects[0]["explains"]
    # an offset on another cable, or a slip at another time, accounts for nothing; nor for
    # a step of the force balance
    for args in (({"21": 100.0}, {"31"}), ({}, set())):
        left = unexplained.with_changes(None, [copy.copy(step), copy.copy(load)], *args)
        assert [c["block"] for c in left["changes"]] == ["length", "force"]
        assert left["changes"][0]["t_s"] == 135.6 and "t = 135.6 s" in left["summary"]
    left = unexplained.with_changes(None, [copy.copy(step), copy.copy(load)], {}, {"21"})
    assert [c["block"] for c in left["changes"]] == ["force"]


def test_rows_of_the_same_two_moves_are_one_difference():
    """A continuous recording's replicate groups of path rows (case 12812 of `cdpr evaluate
    --seed 12800`): twenty-odd groups each pairing a row of one move with a row of the
    same later move. The moves' slow errors (a visit's change blending along the move)
    differ between the two moves by several row noises; counted as twenty-odd independent
    differences that read as a step of z 8 between the moves."""
    rng = np.random.default_rng(4)
    s = _FakeSamples(5, 2, 8, rng)  # five dwell targets visited twice
    rows = 24
    t_a, t_b = 55.0 + np.arange(rows), 120.0 + np.arange(rows)
    n_d = len(s.t)
    s.t = np.concatenate([s.t, t_a, t_b])
    s.target = np.concatenate([s.target, 100 + np.arange(rows), 100 + np.arange(rows)])
    s.kind = np.concatenate([s.kind, np.ones(2 * rows, dtype=int)])
    s.block = np.concatenate([s.block, np.full(rows, 50), np.full(rows, 51)])
    pos = np.concatenate([s.pose_meas, np.tile(s.pose_meas[:1], (2 * rows, 1))])
    s.pose_meas = s.pose_des = pos
    s.count = np.full(len(s.t), 6)
    s.is_init = np.zeros(len(s.t), dtype=bool)
    s.direction = rng.choice([-1.0, 1.0], size=(len(s.t), 8))
    s.tau = np.full((len(s.t), 8), np.nan)
    s.n = len(s.t)
    x = rng.normal(0, 1.0, (len(s.t), 8))
    x[n_d:n_d + rows] = 4.0 + rng.normal(0, 0.2, (rows, 8))  # move A's slow error
    x[n_d + rows:] = -4.0 + rng.normal(0, 0.2, (rows, 8))  # move B's
    assert noise.find_changes(_FakeRM(x * 1e-4, s), None) == []
