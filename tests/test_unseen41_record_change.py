"""A load-change case is recorded by one run of each campaign: the second's slips after the
change are set in its own clock when its first row's time is known (``run_campaign``'s
``first_row``), the first's plant gives the encoders' reference."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import bench.campaign as campaign
import bench.evaluate as ev
from firmware_sim.plant import Plant


def _first_rows(path) -> float:
    with open(path / "recording.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return float(next(r for r in rows if r["state"] != "init")["t"])


@pytest.mark.parametrize("kind", ["dwell", "continuous"])
def test_first_row_is_the_first_row_after_the_initialisation(kind, tmp_path):
    """``first_row(t, plant)`` is called once, with the time of the recording's first row
    after the initialisation (the same number), before the plant settled there."""
    case = ev.make_case(3, robot="ipanema", kind=kind, effects=(), oov="none",
                        poses={"kind": "grid", "n": [2, 2, 1], "visits": 1})
    case["recording"]["state_column"] = True
    sc = ev.scenario_of(case)
    calls = []

    def first(t: float, plant: Plant) -> None:
        calls.append((t, plant._rests))

    campaign.run_campaign(sc, tmp_path / "r", first_row=first)
    assert len(calls) == 1
    assert calls[0][0] == _first_rows(tmp_path / "r")
    assert calls[0][1] == 1  # the plant has settled for the initialisation only


def test_a_slip_after_the_change_one_run_per_campaign(tmp_path, monkeypatch):
    """A slip 45 s after the change: two campaign runs (not three), and the second's plant
    slips at the slip's time of the whole recording less the shift of the second's rows
    (its first row's time in its own clock to ``t0``); the encoders keep the first's
    reference."""
    case = ev.make_case(61100, kind="load_change")
    runs, firsts, slips, plants, refs = [], [], [], [], []
    run, slip_at, made = campaign.run_campaign, Plant.slip_at, campaign.campaign_plant

    def counted(*a, **k):
        runs.append(k.get("plant"))
        hook = k.get("first_row")
        if hook is not None:
            k["first_row"] = lambda t, plant: (firsts.append(t), hook(t, plant))
        return run(*a, **k)

    def seen(self, times):
        slips.append(np.array(times))
        return slip_at(self, times)

    def plant(*a, **k):
        refs.append(a[1] if len(a) > 1 else k.get("referenced"))
        plants.append(made(*a, **k))
        return plants[-1]

    monkeypatch.setattr(campaign, "run_campaign", counted)
    monkeypatch.setattr(campaign, "campaign_plant", plant)
    monkeypatch.setattr(Plant, "slip_at", seen)
    t0 = 384.7529081904444  # this case's change (its first campaign's end + the gap)
    late = t0 + 45.0
    case["truth"]["cable_length_offset"]["slip_time_41"] = late
    ev.record(case, tmp_path / "rec")
    assert case["case"]["change"]["t_s"] == t0
    assert len(runs) == 2 and refs[0] is None
    assert np.array_equal(refs[1], plants[0].u0)  # the first campaign's own plant
    assert runs == plants[-2:]  # each campaign runs on the plant made for it
    assert len(firsts) == 1 and len(slips) == 1
    sc = ev.scenario_of(case)
    k = sc.model.cable_ids.index("41")
    assert slips[0][k] == late - (t0 - firsts[0])
    assert firsts[0] < slips[0][k] < late
    assert np.all(np.delete(slips[0], k) == sc.poses.init_s)  # no other slip
    with open(tmp_path / "rec" / "recording.csv", newline="") as f:
        t = np.array([float(r["t"]) for r in csv.DictReader(f)])
    assert t[t >= t0][0] == t0  # the second's first row moved to the change
