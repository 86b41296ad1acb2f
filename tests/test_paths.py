"""Path files (controller/paths.py): the strict reader (errors with file, line and field),
the shipped paths, and the whole-path check (first infeasible point and why; nothing
found on feasible paths)."""

from __future__ import annotations

import dataclasses
import re
import textwrap

import numpy as np
import pytest

from controller.paths import (
    PathFileError,
    build_trajectory,
    check_times,
    check_trajectory,
    frame_box,
    load_path,
    parse_path,
    shipped_paths,
)
from controller.robot import resolve_robot
from controller.statics import pose_statics
from controller.trajectory import Line, Move, Trajectory, Visits
from controller.winch import load_winches

ROBOT = resolve_robot("rocaspect")
WINCHES = load_winches()
CENTRE = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.0])
SIDE = np.array([1.0, 8.56, 1.2, 0.0, 0.0, 0.0])
SHIPPED = ("paper-centre", "paper-side", "calibration", "paper-poses-gold",
           "paper-poses-pink", "paper-poses-violet")


def _write(tmp_path, text: str, name: str = "p.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text).lstrip())
    return p


GOOD = """
format = "cdpr-path/1"
name = "demo"
notes = "a test path"
start = [10.0, 8.56, 1.2, 0.0, 0.0, 0.0]

[limits]
speed_pct = 40.0

[[segment]]
kind = "move"
to = [11.0, 8.56, 1.2]

[[segment]]
kind = "dwell"
duration_s = 2.0

[[segment]]
kind = "line"
name = "two legs"
through = [
  [11.0, 9.56, 1.2],
  [11.0, 9.56, 1.0, 0.0, 0.0, 0.05],
]

[[segment]]
kind = "circle"
center = [11.0, 9.06, 1.0]
normal = [0.0, 0.0, 1.0]
angle_deg = 180.0

[[segment]]
kind = "visits"
poses = [[9.0, 8.0, 1.0], [10.0, 8.0, 1.4]]
visits = 2
dwell_s = 1.5
order = "shuffle"
seed = 4

[[segment]]
kind = "visits"
x = [8.0, 12.0]
y = [7.0, 9.0]
z = [1.0, 1.0]
n = [3, 2]
rpy_deg = 1.0
seed = 2
"""


def test_a_good_file_reads_and_builds(tmp_path):
    spec = load_path(_write(tmp_path, GOOD))
    assert spec.name == "demo" and spec.limits.speed_pct == 40.0
    assert [type(s).__name__ for s in spec.segments] == ["Move", "Dwell", "Line", "Circle",
                                                          "Visits", "Visits"]
    grid = spec.segments[5]
    assert len(grid.poses) == 6  # 3 x 2 x 1, z in the middle of its range
    xy = np.array(grid.poses)[:, :2]
    np.testing.assert_allclose(xy[:3, 0], [8.0, 10.0, 12.0])  # x fastest
    np.testing.assert_allclose(xy[::3, 1], [7.0, 9.0])
    ang = np.degrees(np.array(grid.poses)[:, 3:])
    assert np.abs(ang).max() <= 1.0 and np.abs(ang).max() > 0.1
    # the same seed gives the same grid
    assert load_path(_write(tmp_path, GOOD, "q.toml")).segments[5].poses == grid.poses
    tr = build_trajectory(spec, [9.0, 8.0, 1.2, 0.0, 0.0, 0.0])
    kinds = [s.kind for s in tr.segments]
    assert kinds[:6] == ["move", "move", "dwell", "line", "line", "circle"]
    assert tr.segments[0].name == "approach" and tr.segments[0].cycle == -1
    np.testing.assert_allclose(tr.segments[0].target, CENTRE)
    assert sum(s.label == "dwell" for s in tr.segments) == 1 + 4 + 6
    assert tr.limits.speed_pct == 40.0
    fast = build_trajectory(spec, CENTRE, {"speed_pct": 100.0})
    assert fast.limits.speed_pct == 100.0 and fast.duration_s < tr.duration_s


def test_a_path_without_start_begins_at_the_given_pose(tmp_path):
    p = _write(tmp_path, """
        format = "cdpr-path/1"
        repeat = 2
        [[segment]]
        kind = "line"
        through = [[10.0, 9.0, 1.2], [10.0, 8.56, 1.2]]
        """)
    tr = build_trajectory(load_path(p), CENTRE)
    np.testing.assert_allclose(tr.segments[0].start, CENTRE)
    assert [s.cycle for s in tr.segments] == [0, 0, 1, 1]
    assert load_path(p).name == "p"


def _error(tmp_path, text: str) -> str:
    p = _write(tmp_path, text)
    with pytest.raises(PathFileError) as e:
        spec = load_path(p)
        build_trajectory(spec, CENTRE)
    msg = str(e.value)
    assert msg.startswith(str(p)), msg
    return msg


def _line_of(text: str, needle: str) -> int:
    lines = textwrap.dedent(text).lstrip().splitlines()
    return next(i + 1 for i, line in enumerate(lines) if needle in line)


@pytest.mark.parametrize("change, needle, field", [
    (('to = [11.0, 8.56, 1.2]', 'to = [11.0, 8.56]'), "to = [11.0, 8.56]",
     "[[segment]] #1.to"),
    (('duration_s = 2.0', 'duration_s = -2.0'), "duration_s = -2.0",
     "[[segment]] #2.duration_s"),
    (('duration_s = 2.0', 'duration = 2.0'), "duration = 2.0", "[[segment]] #2.duration"),
    (('kind = "circle"', 'kind = "spiral"'), 'kind = "spiral"', "[[segment]] #4.kind"),
    (('angle_deg = 180.0', 'angle_deg = "half"'), 'angle_deg = "half"',
     "[[segment]] #4.angle_deg"),
    (('normal = [0.0, 0.0, 1.0]', 'normal = [0.0, 0.0, 0.0]'), "normal = [0.0, 0.0, 0.0]",
     "[[segment]] #4.normal"),
    (('order = "shuffle"', 'order = "random"'), 'order = "random"', "[[segment]] #5.order"),
    (('visits = 2', 'visits = 0'), "visits = 0", "[[segment]] #5.visits"),
    (('n = [3, 2]', 'n = [3, 0]'), "n = [3, 0]", "[[segment]] #6.n"),
    (('x = [8.0, 12.0]', 'x = [12.0, 8.0]'), "x = [12.0, 8.0]", "[[segment]] #6.x"),
    (('speed_pct = 40.0', 'speed_pct = 400.0'), "speed_pct = 400.0", "[limits].speed_pct"),
    (('speed_pct = 40.0', 'top_speed = 1.0'), "top_speed = 1.0", "[limits].top_speed"),
    (('start = [10.0, 8.56, 1.2, 0.0, 0.0, 0.0]', 'start = [10.0, 8.56, 1.2, 0.0]'),
     "start = [", "start"),
    (('notes = "a test path"', 'colour = "red"'), 'colour = "red"', "colour"),
    (('  [11.0, 9.56, 1.2],', '  [11.0, 9.56, "x"],'), "through = [",
     "[[segment]] #3.through"),
])
def test_errors_name_file_line_and_field(tmp_path, change, needle, field):
    text = GOOD.replace(*change)
    assert text != GOOD
    msg = _error(tmp_path, text)
    line = _line_of(text, needle)
    assert f"p.toml:{line}: {field}" in msg, msg


def test_structural_errors(tmp_path):
    assert "format" in _error(tmp_path, 'format = "cdpr-path/2"\n[[segment]]\nkind = "dwell"\n'
                                        "duration_s = 1.0\n")
    assert "no [[segment]]" in _error(tmp_path, 'format = "cdpr-path/1"\n')
    msg = _error(tmp_path, 'format = "cdpr-path/1"\n[[segment]]\nduration_s = 1.0\n')
    assert re.search(r"p\.toml:2: \[\[segment\]\] #1\.kind: missing field", msg), msg
    both = GOOD.replace('poses = [[9.0, 8.0, 1.0], [10.0, 8.0, 1.4]]',
                        'poses = [[9.0, 8.0, 1.0]]\nx = [1.0, 2.0]')
    assert "either poses or a grid" in _error(tmp_path, both)
    assert "TOML syntax" in _error(tmp_path, 'format = "cdpr-path/1"\n[[segment]\n')
    with pytest.raises(PathFileError, match="no such path file, nor a shipped path"):
        load_path("no-such-path")
    with pytest.raises(PathFileError, match="cannot read"):
        load_path(tmp_path / "missing.toml")


def test_a_circle_off_its_plane_names_the_file_and_segment(tmp_path):
    text = GOOD.replace("center = [11.0, 9.06, 1.0]", "center = [11.0, 9.06, 1.3]")
    msg = _error(tmp_path, text)
    line = _line_of(text, 'kind = "circle"') - 1  # the [[segment]] header
    assert f"p.toml:{line}: [[segment]] #4: circle: the start point" in msg, msg


def test_parse_path_in_memory():
    spec = parse_path({"format": "cdpr-path/1", "segment": [{"kind": "dwell",
                                                             "duration_s": 1}]})
    assert spec.source == "<memory>" and spec.start is None


# ---------------------------------------------------------------------------- shipped


def test_the_shipped_paths_load_by_name():
    assert set(SHIPPED) <= set(shipped_paths())
    for name in SHIPPED:
        spec = load_path(name)
        assert spec.name == name and len(spec.notes) > 200  # the choices are written down


def test_the_paper_paths_run_in_the_zy_plane_through_their_init_pose():
    for name, x in (("paper-centre", 10.0), ("paper-side", 1.0)):
        spec = load_path(name)
        np.testing.assert_allclose(spec.start, [x, 8.56, 1.2, 0, 0, 0])
        for init in (CENTRE, SIDE):
            tr = build_trajectory(spec, init)
            path = [s for s in tr.segments if s.cycle >= 0]
            pts = np.array([s.target for s in path] + [path[0].start])
            np.testing.assert_allclose(pts[:, 0], x)  # parallel to ZY
            np.testing.assert_allclose(pts[-2], spec.start)  # a closed loop
            assert (init[0] == x) == (len(path) == len(tr.segments))


def test_the_iso_pose_sets_follow_iso_9283():
    d = 26.238
    gold = np.array(load_path("paper-poses-gold").segments[0].poses)
    centre = gold[0, :3]
    # P2..P5 on the test plane's diagonals at 0.1 d from its corners: centre + 0.8 (C - c)
    half = np.abs(gold[1:, :3] - centre) / 0.8
    np.testing.assert_allclose(half, np.tile(half[0], (4, 1)), atol=2e-3)
    assert np.linalg.norm(2 * half[0]) == pytest.approx(d, abs=2e-3)
    assert np.linalg.norm(gold[1, :3] - gold[3, :3]) == pytest.approx(0.8 * d, abs=5e-3)
    for name, f in (("paper-poses-pink", 0.5), ("paper-poses-violet", 0.25)):
        spec = load_path(name)
        v = spec.segments[0]
        assert isinstance(v, Visits) and v.visits == 30 and v.order == "cycle"
        inner = np.array(v.poses)
        np.testing.assert_allclose(inner[:, :3] - centre, f * (gold[:, :3] - centre), atol=2e-3)


@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_paths_are_feasible_with_margin(name):
    spec = load_path(name)
    remeasured = resolve_robot("rocaspect-remeasured")
    compliant = dataclasses.replace(remeasured, stiffness=np.tile([2e5, 5e5, 3e5], (4, 1)))
    heavier = dataclasses.replace(ROBOT, mass=1.2 * ROBOT.mass)
    robots = [ROBOT, remeasured, heavier]
    if "calibration" not in name and "gold" not in name:  # the long ones once, nominal
        robots.append(compliant)
    for init in ((CENTRE, SIDE) if name.startswith("paper-") and "poses" not in name
                 else (CENTRE,)):
        tr = build_trajectory(spec, init)
        for rob in robots:
            c = check_trajectory(rob, tr, WINCHES)
            assert c.ok, (name, rob.name, c.reason)
            assert c.min_length_margin_m > 1.0
            assert c.tension_max_n < 0.5 * rob.tension_max


def test_the_side_path_keeps_half_a_metre_from_the_infeasible_region():
    spec = load_path("paper-side")
    legs = [np.array(w) for w in spec.segments[0].through]
    for dx, dy, dz in ((-0.5, 0, 0), (0, -1.0, 0), (0, 1.0, 0), (-0.5, 0, -0.3)):
        shifted = [tuple(w + [dx, dy, dz]) for w in legs]
        start = SIDE + [dx, dy, dz, 0, 0, 0]
        c = check_trajectory(ROBOT, Trajectory([Line(tuple(shifted))], start))
        assert c.ok, (dx, dy, dz, c.reason)


# ---------------------------------------------------------------------------- checking


def test_the_check_refuses_a_path_through_an_infeasible_region_at_its_first_bad_point():
    corner = (0.5, 0.5, 1.2)
    tr = Trajectory([Move((12.0, 8.56, 1.2)), Move(corner), Move((10.0, 8.56, 1.2))], CENTRE)
    c = check_trajectory(ROBOT, tr, WINCHES)
    assert not c.ok and c.segment == 1
    assert "no feasible tensions" in c.reason and "closed-form" in c.reason
    assert f"t = {c.t_s:.3f} s" in c.reason and "segment #2" in c.reason
    assert not pose_statics(ROBOT, c.pose).feasible
    np.testing.assert_allclose(tr.sample(c.t_s).pose, c.pose)
    # every pose sampled before it is feasible: it is the first
    times = check_times(tr)
    before = times[times < c.t_s]
    assert len(before) == c.checked - 1
    for t in before[-40:]:
        assert pose_statics(ROBOT, tr.sample(t).pose).feasible
    # on the way in, not at the corner
    assert np.linalg.norm(c.pose[:3] - corner) > 0.05


def test_the_check_refuses_poses_outside_the_frame():
    tr = Trajectory([Move((10.0, 8.56, 0.6)), Move((10.0, 8.56, 0.1))], CENTRE)
    c = check_trajectory(ROBOT, tr)
    assert not c.ok and c.segment == 1 and "outside the robot's frame" in c.reason
    # the first pose whose lowest anchor (0.25 m below the centre) is below the ground
    assert c.pose[2] < 0.25 and c.pose[2] > 0.25 - 0.1
    assert frame_box(ROBOT)[0, 2] == 0.0


def test_the_check_refuses_lengths_outside_the_winch_range():
    short = WINCHES.replace(max_length_m=np.full(8, 15.0))
    tr = Trajectory([Move((6.0, 8.56, 1.2))], CENTRE)
    assert check_trajectory(ROBOT, tr, WINCHES).ok
    c = check_trajectory(ROBOT, tr, short)
    assert not c.ok and "outside the winch range [0.5, 15] m" in c.reason
    assert re.search(r"cable (31|32|41|42) \(CAN node \d\)", c.reason), c.reason
    assert c.min_length_margin_m < 0


def test_the_check_finds_nothing_on_a_feasible_path_and_reports_tensions():
    tr = build_trajectory(load_path("paper-centre"), CENTRE)
    c = check_trajectory(ROBOT, tr, WINCHES)
    assert c.ok and c.t_s is None and c.pose is None and c.reason == ""
    assert ROBOT.tension_min <= c.tension_min_n < c.tension_max_n <= ROBOT.tension_max
    assert c.checked == len(c.times) > 100


def test_check_times_are_dense_enough():
    tr = build_trajectory(load_path("paper-centre"), SIDE)
    t = check_times(tr, step_m=0.05)
    p = tr.sample(t).pose
    assert np.linalg.norm(np.diff(p[:, :3], axis=0), axis=1).max() <= 0.05 + 1e-9
    assert t[0] == 0.0 and t[-1] == tr.duration_s
    for s in tr.segments:
        assert np.any(np.isclose(t, s.t1))
