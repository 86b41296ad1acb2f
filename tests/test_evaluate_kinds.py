"""The evaluation's case kinds drawn only when asked for (``bench.evaluate``: logger, hour,
load_change, ``mix_new`` robots, the six-cable ``hexa6``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.evaluate import DROPOUTS, NEW_KINDS, _duration, make_case, record, scenario_of
from bench.logger_sim import LoggerSpec
from controller.robot import resolve_robot


def _case(seed: int, **kw) -> dict:
    """The case of ``seed`` as :func:`bench.evaluate.run_case` draws it (another draw where
    one cannot be made)."""
    for attempt in range(5):
        try:
            return make_case(seed, attempt=attempt, **kw)
        except RuntimeError:
            continue
    raise RuntimeError(f"seed {seed}: no case")


def test_new_kinds_are_drawn_only_when_asked_for():
    for seed in range(12800, 12806):
        case = _case(seed)
        assert case["case"]["kind"] not in NEW_KINDS
        assert "logger" not in case["case"] and "change" not in case["case"]
        assert case["case"]["robot"] in ("rocaspect", "cogiro", "ipanema")
    kinds = {_case(seed, kind="new")["case"]["kind"] for seed in range(40, 52)}
    assert kinds == set(NEW_KINDS)


def test_a_logger_case_says_how_its_logger_writes():
    case = _case(5, kind="logger")
    spec = LoggerSpec(**case["case"]["logger"])
    assert spec.rows_hz in (100.0, 200.0, 250.0) and spec.encoders_hz == spec.rows_hz
    assert spec.tracker_hz <= 50.0 and spec.empty in ("nan", "")
    assert case["recording"]["kind"] == "continuous" and case["recording"]["dwell_at_targets"]
    assert {f.name for f in dataclasses.fields(LoggerSpec)} >= set(case["case"]["logger"])


def test_logger_cases_draw_sensor_dropouts_per_stream():
    # each stream in some cases and not in others, rates and durations in their ranges, as
    # LoggerSpec data; the other draws of a case do not depend on them
    seen: dict[str, int] = {s: 0 for s in DROPOUTS}
    cases = [_case(seed, kind="logger") for seed in range(46000, 46012)]
    for case in cases:
        spec = LoggerSpec(**case["case"]["logger"])
        for stream, rate, short, long_ in spec.dropouts:
            (r0, r1), (s0, s1), (l0, l1) = DROPOUTS[stream]
            assert r0 <= rate <= r1 and s0 <= short <= s1 and l0 <= long_ <= l1
            seen[stream] += 1
    assert all(0 < k < len(cases) for k in seen.values()), seen
    assert any(not c["case"]["logger"]["dropouts"] for c in cases)


def test_an_hour_case_lasts_an_hour():
    case = _case(6, kind="hour", robot="rocaspect", effects=())
    assert case["case"]["logger"]["rows_hz"] == 50.0
    assert _duration(scenario_of(case)) >= 3000.0


def test_mix_new_draws_rigid_frames_with_pulleys_and_six_cables():
    robots = {_case(seed, robot="mix_new")["case"]["robot"] for seed in range(60, 72)}
    assert robots == {"ipanema", "hexa6"}
    r = resolve_robot("hexa6")
    assert r.n_cables == 6 and r.n_masts == 3 and np.all(r.pulley_radius > 0)
    # a concealed pulley radius differs cable by cable in the new cases, not in the others
    new = _case(3, robot="mix_new", effects=("pulley_kinematics",))
    old = _case(3, effects=("pulley_kinematics",))
    assert len(set(new["truth"]["pulley_kinematics"].values())) > 1
    assert len(set(old["truth"]["pulley_kinematics"].values())) == 1


def test_a_load_change_case_records_two_campaigns_one_after_the_other(tmp_path):
    case = _case(8, robot="ipanema", kind="load_change", effects=(),
                     poses={"n": [2, 2, 1], "visits": 2}, oov="none")
    assert case["case"]["oov"] == "load_change"
    record(case, tmp_path / "rec")
    from bench.recording import read_recording

    rec = read_recording(tmp_path / "rec")
    t = rec.t
    assert np.all(np.diff(t) > 0)
    t_change = case["case"]["change"]["t_s"]
    before, after = t < t_change, t >= t_change
    assert before.any() and after.any()
    # the gap before the second campaign; no second initialisation
    assert t[after][0] == t_change and t_change - t[before][-1] >= 30.0 - 1e-9
    assert len(t[after]) < len(t[before]) + 4 * 2 * 10
