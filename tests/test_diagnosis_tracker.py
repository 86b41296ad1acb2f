"""The tracker's own errors as named physics: ``tracker_frame`` and ``tracker_latency``.

A tracker registered to F_b with a small rotation and translation off reads every pose
(and exit point) through that rigid motion; a tracker whose stream lags the drives' reads
a moving platform where it was that long before. The simulated tracker carries both
(``[truth.tracker_frame]``, ``[truth.tracker_latency]``); the diagnosis names them with
their parameters, declares the gauge partner (a rigid motion of every exit point), and
names neither where the tracker is right, nor the frame for one exit point moved.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread
from controller.effects import (
    EFFECT_NAMES,
    apply_effects,
    base_to_tracker,
    tracker_points_to_base,
    tracker_to_base,
)
from firmware_sim.scenario import ScenarioError, parse_scenario
from firmware_sim.tracker_sim import TrackerView
from tests.robots import rocaspect
from tests.test_diagnose_kinds import GRID, scenario

TRACKER = ("tracker_frame", "tracker_latency")
#: a continuous recording along three straight moves, twice, at 10 Hz, no dwells
MOVES = {"kind": "list", "visits": 2, "speed_m_s": 0.4, "init_s": 2.0,
         "list": [[7.0, 6.0, 1.0, 0, 0, 0], [13.0, 7.0, 1.3, 0, 0, 0],
                  [10.0, 11.0, 1.0, 0, 0, 0]]}
CONTINUOUS = {"kind": "continuous", "dwell_at_targets": False, "rate_hz": 10.0}


@pytest.fixture(scope="module", autouse=True)
def _one_blas_thread():
    one_blas_thread()


def _run(tmp_path, sc_map):
    sc = parse_scenario(sc_map)
    return sc, diagnose(run_campaign(sc, tmp_path / "rec"))


def _named(dg) -> dict[str, dict]:
    return {e["name"]: e for e in dg.report["effects"]}


def test_frame_and_latency_round_trip_through_the_tracker():
    """What the simulated tracker reads, taken back to F_b under the same errors, is the
    platform's pose (frame exactly, latency to first order along the motion)."""
    truth = apply_effects(rocaspect(), {
        "tracker_frame": {"rx": 1e-3, "rz": 5e-3, "tx": 0.004, "ty": -0.003},
        "tracker_latency": {"dt": 0.05}})
    p = np.array([[10.0, 8.0, 1.0, 0.01, -0.02, 0.03], [4.0, 5.0, 1.5, 0.0, 0.0, -0.02]])
    seen = base_to_tracker(truth, p)
    assert np.abs(seen - p).max() > 1e-2  # the frame moves them by centimetres
    frame_only = truth.replace(tracker_latency=0.0)
    np.testing.assert_allclose(tracker_to_base(frame_only, seen), p, atol=1e-12)
    pts = np.array([[0.0, 0.0, 5.0], [20.0, 17.0, 5.0]])
    view = TrackerView(frame_only)
    np.testing.assert_allclose(tracker_points_to_base(frame_only, view.points(pts)), pts,
                               atol=1e-12)
    # a platform moving at 0.4 m/s along x, read 50 ms late
    late = TrackerView(truth.replace(tracker_frame=np.zeros(6)))
    v = np.array([0.4, 0, 0, 0, 0, 0])
    reads = [late.read(t, p[0] + v * t) for t in np.arange(0.0, 2.0, 0.1)]
    np.testing.assert_allclose(reads[-1], p[0] + v * (1.9 - 0.05), atol=1e-12)
    back = tracker_to_base(truth.replace(tracker_frame=np.zeros(6)), reads[-1], v)
    np.testing.assert_allclose(back, p[0] + v * 1.9, atol=1e-12)


def test_the_scenario_carries_the_trackers_errors():
    assert set(TRACKER) <= set(EFFECT_NAMES)
    sc = parse_scenario(scenario(truth={"tracker_frame": {"rz": 0.005, "tx": 0.003},
                                        "tracker_latency": {"dt": 0.04}}))
    np.testing.assert_allclose(sc.truth.tracker_frame, [0, 0, 0.005, 0.003, 0, 0])
    assert sc.truth.tracker_latency == 0.04 and sc.model.tracker_latency == 0.0
    with pytest.raises(ScenarioError, match="tracker_frame: unknown parameter 'rw'"):
        parse_scenario(scenario(truth={"tracker_frame": {"rw": 0.1}}))


def test_a_turned_and_shifted_tracker_frame_is_named_with_its_parameters(tmp_path):
    """The issue's case: the tracker's frame turned 0.3 degrees and shifted a few mm. Named
    ``tracker_frame`` (not exit-point offsets), parameters near the truth, the fitted pose
    error at the noise, and the exit points' rigid motion declared as the other side of
    the gauge."""
    truth = {"rz": np.radians(0.3), "rx": 4e-4, "tx": 0.004, "ty": -0.003, "tz": 0.002}
    sc, dg = _run(tmp_path, scenario(truth={"tracker_frame": truth},
                                     poses=GRID | {"n": [3, 3, 2]}))
    got = _named(dg)
    assert set(got) == {"tracker_frame"}, dg.report["mismatch"]["summary"]
    params = got["tracker_frame"]["params"]
    for k, v in truth.items():
        tol = 1e-4 if k.startswith("r") else 5e-4
        assert abs(params.get(k, 0.0) - v) < tol, (k, params)
    assert dg.report["unexplained"] is None
    assert dg.report["fitted"]["pose_rms_m"] < 1e-3
    alts = {a["name"]: a for a in got["tracker_frame"]["alternatives"]}
    assert alts["exit_point_offset"]["gauge"] == "tracker_frame"
    assert "gauge" in dg.report["mismatch"]["summary"]


def test_one_exit_point_moved_is_no_tracker_frame(tmp_path):
    """A genuine offset of one exit point is no rigid motion of the frame: exit-point
    offsets, no tracker frame (nor latency: the recording stands at each pose)."""
    sc, dg = _run(tmp_path, scenario(truth={"exit_point_offset": {"dx_21": 0.02,
                                                                  "dz_21": -0.01}}))
    got = _named(dg)
    assert set(got) == {"exit_point_offset"}, dg.report["mismatch"]["summary"]
    assert "frame_motion" not in got["exit_point_offset"]
    assert not [a for a in got["exit_point_offset"]["alternatives"] if a.get("gauge")]


def test_a_lagging_tracker_is_named_with_its_latency(tmp_path):
    """Continuous recording while moving: the poses 60 ms late are named tracker_latency,
    with its time."""
    sc, dg = _run(tmp_path, scenario(truth={"tracker_latency": {"dt": 0.06}}, poses=MOVES,
                                     recording=CONTINUOUS))
    got = _named(dg)
    assert set(got) == {"tracker_latency"}, dg.report["mismatch"]["summary"]
    assert abs(got["tracker_latency"]["params"]["dt"] - 0.06) < 0.005


@pytest.mark.parametrize("kind", ["dwell", "continuous"])
def test_a_right_tracker_names_neither(tmp_path, kind):
    """Nothing concealed: neither the frame nor the latency (a continuous recording can see
    the latency, a dwell one only the frame)."""
    sc_map = scenario() if kind == "dwell" else scenario(poses=MOVES, recording=CONTINUOUS)
    sc, dg = _run(tmp_path, sc_map)
    assert not set(_named(dg)) & set(TRACKER), dg.report["mismatch"]["summary"]


def test_the_evaluations_tracker_cases_conceal_the_trackers_errors():
    """``bench.evaluate.CASE_HOOKS``: a case with the tracker's frame off, and one whose
    tracker lags on a continuous recording; nothing else concealed."""
    from bench.evaluate import CASE_HOOKS, scenario_of

    frame = CASE_HOOKS["tracker_frame"](12800)
    assert set(frame["truth"]) == {"tracker_frame"} and frame["case"]["oov"] == "none"
    assert np.abs(scenario_of(frame).truth.tracker_frame[:3]).max() <= np.radians(0.5)
    late = CASE_HOOKS["tracker_latency"](12801)
    assert set(late["truth"]) == {"tracker_latency"}
    assert late["recording"]["kind"] == "continuous"
    assert 0.02 <= scenario_of(late).truth.tracker_latency <= 0.1


def test_pose_rates_follow_each_move_not_the_turn_between_them():
    """Two straight moves meeting at a turn, no stop: each row's rate is its own move's
    velocity (a polynomial across the turn would bend it), a short move's from a line."""
    from types import SimpleNamespace

    from bench.diagnosis.frame import pose_rates

    t = np.arange(0.0, 4.0, 0.1)
    v1, v2 = np.array([0.3, 0, 0, 0, 0, 0.01]), np.array([0, -0.2, 0.05, 0, 0, 0])
    p = np.where((t < 2.0)[:, None], t[:, None] * v1, 2.0 * v1 + (t - 2.0)[:, None] * v2)
    rec = SimpleNamespace(n_samples=len(t), t=t, pose_meas=p)
    rows = np.arange(len(t))
    moves = (t >= 2.0).astype(int)
    got = pose_rates(rec, rows, rows, moves)
    np.testing.assert_allclose(got[t < 2.0], np.tile(v1, ((t < 2.0).sum(), 1)), atol=1e-9)
    np.testing.assert_allclose(got[t >= 2.0], np.tile(v2, ((t >= 2.0).sum(), 1)), atol=1e-9)
    short = pose_rates(rec, rows[:3], rows[:3], np.zeros(3, dtype=int))
    np.testing.assert_allclose(short, np.tile(v1, (3, 1)), atol=1e-9)
    assert not pose_rates(rec, rows[:1], rows[:1], np.zeros(1, dtype=int)).any()


def test_exit_points_moved_together_declare_the_tracker_frame(tmp_path):
    """The other side of the gauge: every exit point moved by one rigid motion (the frame
    surveyed off, the tracker right). The encoders' reference at the commanded
    initialisation pose and the tilt of gravity tell it from a tracker frame: exit-point
    offsets are named, with ``frame_motion``, and ``tracker_frame`` declared beside them."""
    m = rocaspect()
    omega, t = np.array([0.0, 0.0, 1.5e-3]), np.array([0.006, -0.004, 0.0])
    d = np.cross(omega, m.exits - m.exits.mean(axis=0)) + t
    truth = {f"d{ax}_{c}": float(d[k, a]) for k, c in enumerate(m.cable_ids)
             for a, ax in enumerate("xyz") if d[k, a] != 0.0}
    sc, dg = _run(tmp_path, scenario(truth={"exit_point_offset": truth},
                                     poses=GRID | {"n": [3, 3, 2]}))
    got = _named(dg)
    assert set(got) == {"exit_point_offset"}, dg.report["mismatch"]["summary"]
    motion = got["exit_point_offset"]["frame_motion"]
    np.testing.assert_allclose(motion["rotation_rad"], omega, atol=1e-4)
    alts = {a["name"]: a for a in got["exit_point_offset"]["alternatives"]}
    assert alts["tracker_frame"]["gauge"] == "tracker_frame"


def test_a_latency_below_what_the_time_stamps_resolve_is_not_named(tmp_path):
    """A tracker 1 ms late on rows stamped at their writer's period (tens of ms): an offset
    the time stamps cannot resolve (the logger's convention of stamping), not named; the
    floor is a tenth of the length readings' period (the encoders' stream's where the
    recording holds streams)."""
    from bench.diagnosis.frame import LATENCY_FLOOR, stamp_period_s

    sc, dg = _run(tmp_path, scenario(truth={"tracker_latency": {"dt": 0.001}}, poses=MOVES,
                                     recording=CONTINUOUS))
    assert "tracker_latency" not in _named(dg), dg.report["mismatch"]["summary"]
    t = np.arange(0.0, 10.0, 0.05)
    assert stamp_period_s(t, None) == pytest.approx(0.05)
    streams = {"streams": {"encoders": {"period_s": 0.004}}}
    assert stamp_period_s(t, streams) == 0.004
    assert LATENCY_FLOOR * 0.05 > 0.001


def test_a_translation_only_frame_has_the_length_offsets_as_its_lookalike():
    """Which effects read as a named tracker error: the exit points' rigid motion always,
    per-cable length offsets only for a frame fixed by translations (a rotation moves
    poses far apart differently), and only among the candidates."""
    from bench.diagnosis.frame import lookalikes

    every = ["exit_point_offset", "cable_length_offset", "tracker_frame"]
    assert lookalikes("tracker_frame", {"tz": -5e-4}, every) == [
        "exit_point_offset", "cable_length_offset"]
    assert lookalikes("tracker_frame", {"tx": 1e-3, "tz": 2e-3}, every)[-1] == \
        "cable_length_offset"
    assert lookalikes("tracker_frame", {"rz": 1e-3, "tz": 2e-3}, every) == ["exit_point_offset"]
    assert lookalikes("tracker_frame", {"tz": 2e-3}, ["tracker_frame"]) == []
    assert lookalikes("cable_length_offset", {"dl_11": 1e-3}, every) == []


def test_a_frame_translation_does_not_hide_friction_on_a_small_dwell_campaign(tmp_path):
    """Evaluation case 12863: CoGiRo, 5 poses visited twice, winch friction (outside the
    vocabulary), nothing concealed. A tracker-frame translation (tz, one parameter) and
    per-cable length offsets read alike there; the offsets' place a thermal probe takes
    within the tie, so the frame's may stand for physics outside the vocabulary too:
    ``unexplained`` is declared through the look-alike, which is listed."""
    import json

    from bench.evaluate import run_case

    run_case(12863, keep=str(tmp_path))
    case = json.loads((tmp_path / "12863" / "case.json").read_text())
    assert case["case"]["oov"] == "friction" and not case["truth"]
    dg = diagnose(tmp_path / "12863" / "rec")
    rep = dg.report
    assert rep["unexplained"] is not None, rep["mismatch"]["summary"]
    got = _named(dg)
    if "tracker_frame" in got:  # named: its look-alike listed, and the probe through it
        alts = {a["name"]: a for a in got["tracker_frame"]["alternatives"]}
        assert alts["cable_length_offset"]["lookalike"] == "tracker_frame"
        q = {e["effect"]: e for e in rep["unexplained"].get("effects_in_question", [])}
        assert q["tracker_frame"]["via"] == "cable_length_offset"


def test_a_tracker_raised_on_a_small_dwell_campaign_stays_explained(tmp_path):
    """The tracker's frame 2 mm low on a small campaign (5 poses, two visits each): named
    ``tracker_frame`` or its look-alike, nothing put in question (no physics outside the
    vocabulary here: the probes through the look-alike must find nothing)."""
    poses = {"kind": "list", "visits": 2, "list": [
        [9.0, 7.5, 1.0, 0, 0, 0], [11.0, 8.0, 1.2, 0, 0, 0], [10.0, 9.5, 0.9, 0, 0, 0],
        [8.5, 9.0, 1.1, 0, 0, 0], [11.5, 9.5, 1.0, 0, 0, 0]]}
    sc, dg = _run(tmp_path, scenario(truth={"tracker_frame": {"tz": -0.002}}, poses=poses))
    got = _named(dg)
    assert set(got) & {"tracker_frame", "cable_length_offset"}, dg.report["mismatch"]["summary"]
    assert dg.report["unexplained"] is None, dg.report["unexplained"]["summary"]
