"""ISO 9283 figures of recordings: visits and passes, with and without a state column, the
``cdpr iso9283`` command (table, --json, --plots, errors)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench.cli import main
from bench.iso9283.analysis import analyse
from bench.iso9283.figures import pose_figures
from bench.iso9283.segments import Iso9283Error, segment
from bench.recording import POSE_AXES, read_recording, write_recording
from controller.robot import resolve_robot

ROBOT = resolve_robot("rocaspect")
RATE = 10.0  # rows per second


class Rows:
    """Rows of a synthetic recording: commanded and measured poses and a state."""

    def __init__(self):
        self.des: list[np.ndarray] = []
        self.meas: list[np.ndarray] = []
        self.state: list[str] = []

    def add(self, des, meas, state, count=1):
        for _ in range(count):
            self.des.append(np.asarray(des, float))
            self.meas.append(np.asarray(meas, float))
            self.state.append(state)

    def write(self, path, states=True, drop=(), extra=None):
        des, meas = np.array(self.des), np.array(self.meas)
        cols = {"t": np.arange(len(des)) / RATE}
        cols.update(extra or {})
        for a, ax in enumerate(POSE_AXES):
            cols[f"{ax}_des"] = des[:, a]
        for a, ax in enumerate(POSE_AXES):
            cols[f"{ax}_meas"] = meas[:, a]
        for k in drop:
            cols.pop(k)
        return write_recording(path, ROBOT, self.des[0], cols,
                               states=self.state if states else None)


# --------------------------------------------------------------------------------------------
# pose campaigns

POSES = np.array([[10.0, 8.56, 1.0, 0, 0, 0], [4.0, 4.0, 1.5, 0, 0, 0.02],
                  [16.0, 13.0, 0.8, 0.01, 0, 0]])
BIAS = np.array([[0.012, -0.004, 0.020, 0.001, 0, 0], [-0.030, 0.010, -0.015, 0, 0.002, 0],
                 [0.005, 0.025, 0.040, 0, 0, -0.003]])
# per-visit scatter [m, rad], cycle j, pose k
SCATTER = np.array([[[0.4, -0.2, 0.1], [-0.3, 0.5, 0.2], [0.1, 0.1, -0.6]],
                    [[-0.1, 0.3, -0.2], [0.2, -0.4, 0.1], [-0.5, 0.2, 0.3]],
                    [[0.2, 0.0, 0.3], [0.4, 0.1, -0.3], [0.3, -0.3, 0.2]],
                    [[-0.5, -0.1, -0.1], [-0.3, -0.2, 0.0], [0.1, 0.0, 0.1]]]) * 1e-3
CYCLES = len(SCATTER)
INIT = np.array([10.0, 8.56, 1.2, 0, 0, 0])  # the initialisation pose, not a target


def attained(j, k):
    return POSES[k] + BIAS[k] + np.r_[SCATTER[j, k], SCATTER[j, k] * 0.01]


def pose_rows(dwell=10, transient=0.05, moves=True):
    """init at INIT, then CYCLES cycles over POSES (P1 P2 P3): a move of 8 rows, then a dwell whose
    first half overshoots by ``transient`` m in z (not settled) and whose second half is at
    the attained pose."""
    r = Rows()
    r.add(INIT, INIT, "init", 6)
    prev = INIT
    for j in range(CYCLES):
        for k in range(len(POSES)):
            if moves:
                for u in np.linspace(0, 1, 10)[1:-1]:
                    p = prev + u * (POSES[k] - prev)
                    r.add(p, p + 0.01, "move")
            a = attained(j, k)
            r.add(POSES[k], a + [0, 0, transient, 0, 0, 0], "dwell", dwell // 2)
            r.add(POSES[k], a, "dwell", dwell - dwell // 2)
            prev = POSES[k]
    return r


def expected_pose(k):
    return pose_figures(np.array([attained(j, k) for j in range(CYCLES)]), POSES[k])


@pytest.mark.parametrize("states", [True, False])
def test_pose_figures_of_a_recording_leave_out_the_settling(tmp_path, states):
    d = pose_rows().write(tmp_path / "r", states=states)
    an = analyse([read_recording(d)])
    assert an.kind == "pose" and len(an.poses) == 3
    for k, res in enumerate(an.poses):
        exp = expected_pose(k)
        assert res.figures.n == CYCLES
        np.testing.assert_allclose(res.figures.command, POSES[k])
        np.testing.assert_allclose(res.figures.ap_xyz, exp.ap_xyz, atol=1e-12)
        assert res.figures.rp == pytest.approx(exp.rp, abs=1e-12)
        np.testing.assert_allclose(res.figures.ap_abc, exp.ap_abc, atol=1e-12)
        np.testing.assert_allclose(res.figures.rp_abc, exp.rp_abc, atol=1e-12)
        # the 50 mm overshoot of the dwells' first halves is not in the figures
        assert abs(res.figures.ap_xyz[2] - BIAS[k, 2]) < 1e-3
    worst = an.worst()
    aps = [expected_pose(k).ap for k in range(3)]
    assert worst["ap_m"] == pytest.approx(max(aps))
    assert worst["pose_of"]["ap_m"] == int(np.argmax(aps)) + 1
    assert "second" not in an.rule and "last 50 %" in an.rule
    assert ("state 'dwell'" in an.rule) == states


def test_settle_fraction_changes_the_rows_averaged(tmp_path):
    d = pose_rows().write(tmp_path / "r")
    rec = read_recording(d)
    all_rows = analyse([rec], settle=0.0)
    # with the whole dwell, half of the rows carry the 50 mm overshoot: AP_z moves 25 mm
    for k, res in enumerate(all_rows.poses):
        assert res.figures.ap_xyz[2] - BIAS[k, 2] == pytest.approx(0.025, abs=1e-3)
    seg = segment(rec, settle=0.8)
    v = seg.visits[0]
    assert v.used[1] == v.rows[1] and v.used[1] - v.used[0] == 2


def test_back_to_back_visits_of_one_pose_are_split(tmp_path):
    r = Rows()
    r.add(POSES[0], POSES[0], "init", 5)
    plan = [0, 1, 1, 2, 0, 2]  # pose 1 twice in a row: one dwell twice as long
    for j, k in enumerate(plan):
        r.add(POSES[k], attained(j % CYCLES, k), "dwell", 6)
    d = r.write(tmp_path / "r")
    seg = segment(read_recording(d))
    assert len(seg.visits) == 6
    assert any("2 back-to-back visits" in w and "recording.csv:" in w for w in seg.warnings)
    an = analyse([read_recording(d)])
    assert [res.figures.n for res in an.poses] == [2, 2, 2]


def test_a_dwell_of_ordinary_length_is_not_split(tmp_path):
    r = Rows()
    r.add(POSES[0], POSES[0], "init", 5)
    for j, k in enumerate([0, 1, 2, 0, 1, 2]):
        r.add(POSES[k], attained(j % CYCLES, k), "dwell", 6 if j != 3 else 8)
    seg = segment(read_recording(r.write(tmp_path / "r")))
    assert len(seg.visits) == 6 and not seg.warnings


# --------------------------------------------------------------------------------------------
# paths

#: a closed rectangle in the YZ plane at x = 10 m, corners in order of travel
CORNERS = np.array([[10.0, 6.0, 1.0], [10.0, 11.0, 1.0], [10.0, 11.0, 1.8], [10.0, 6.0, 1.8],
                    [10.0, 6.0, 1.0]])
PASS_DX = (0.010, 0.020, 0.030)  # each pass runs this far off in x (normal to the plane)


def rectangle(step=0.05):
    pts = [CORNERS[0]]
    for a, b in zip(CORNERS[:-1], CORNERS[1:], strict=True):
        n = int(round(np.linalg.norm(b - a) / step))
        pts += [a + (b - a) * u for u in np.linspace(0, 1, n + 1)[1:]]
    return np.array(pts)


def path_rows(dxs=PASS_DX, dz_wave=0.0):
    """init at the rectangle's start, then one pass per dx: the platform runs dx off in x
    (normal to the rectangle's plane), and dwells at the start between passes (first half
    where the last pass ended, second half where the next starts)."""
    r = Rows()
    start = np.r_[CORNERS[0], 0, 0, 0]
    r.add(start, start, "init", 5)
    path = rectangle()
    last = 0.0
    for dx in dxs:
        r.add(start, start + [last, 0, 0, 0, 0, 0], "dwell", 2)
        r.add(start, start + [dx, 0, 0, 0, 0, 0], "dwell", 2)
        for p in path[1:-1]:
            des = np.r_[p, 0, 0, 0]
            r.add(des, des + [dx, 0, dz_wave * math.sin(p[1]), 0, 0, 0], "move")
        last = dx
    r.add(start, start + [last, 0, 0, 0, 0, 0], "dwell", 4)
    return r


@pytest.mark.parametrize("states", [True, False])
def test_path_figures_of_a_recording(tmp_path, states):
    # three passes 10, 20, 30 mm off in x, normal to the rectangle's plane: barycentre 20 mm
    # off everywhere -> AT = AT_mean = 20 mm; l = 10, 0, 10 mm: l_mean = 20/3 mm,
    # S_l = sqrt(((10/3)^2 + (20/3)^2 + (10/3)^2) / 2) = 10/sqrt(3) mm ->
    # RT = 20/3 + 30/sqrt(3) = 23.987 mm
    d = path_rows().write(tmp_path / "r", states=states)
    an = analyse([read_recording(d)], path_points=200)
    assert an.kind == "path" and len(an.paths) == 1
    f = an.paths[0].figures
    assert f.n == 3 and f.complete.all()
    assert f.length == pytest.approx(2 * 5.0 + 2 * 0.8)
    assert f.at == pytest.approx(0.020, abs=1e-9)
    assert f.at_mean == pytest.approx(0.020, abs=1e-9)
    assert f.rt == pytest.approx((20 / 3 + 30 / math.sqrt(3)) * 1e-3, abs=1e-9)
    np.testing.assert_allclose(f.dev_xyz[:, 0], 0.020, atol=1e-9)


def test_path_at_follows_a_deviation_in_the_plane(tmp_path):
    # one pass with a z deviation of 10 mm * sin(y): on the horizontal legs the normal planes
    # (y = const) see dz = 10 mm * sin(y) -> AT_z = 10 mm sin(y) there (but at the start and
    # end, y = 6, where the platform rests without the wave)
    d = path_rows(dxs=(0.0,), dz_wave=0.010).write(tmp_path / "r")
    f = analyse([read_recording(d)], path_points=233).paths[0].figures
    bottom = (f.command[:, 2] == 1.0) & (f.command[:, 1] > 6.0)
    assert bottom.sum() == 99
    np.testing.assert_allclose(f.dev_xyz[bottom, 2], 0.010 * np.sin(f.command[bottom, 1]),
                               atol=2e-5)
    assert math.isnan(f.rt)


def looped_rows(approach=True):
    """A dry run's path test: init (off the path, with an approach move to its start, or at
    the start), then the closed rectangle three times with no dwell between the
    repetitions, then 'end' rows. Each repetition starts and ends at rest at the start
    pose; it runs PASS_DX off in x, and stands where the last ended until it moves. Returns
    the rows and the cycle of each row (-1 init and approach)."""
    r, cyc = Rows(), []
    start = np.r_[CORNERS[0], 0, 0, 0]
    init = start + ([0, -3.0, 0.2, 0, 0, 0] if approach else 0)
    r.add(init, init, "init", 5)
    cyc += [-1] * 5
    if approach:
        for u in np.linspace(0, 1, 40)[1:]:
            p = init + u * (start - init)
            r.add(p, p + [0, 0, 0.05 * (1 - u), 0, 0, 0], "move")
            cyc.append(-1)
    path = rectangle()
    last = 0.0
    for k, dx in enumerate(PASS_DX):
        r.add(start, start + [last, 0, 0, 0, 0, 0], "move")
        cyc.append(k)
        for p in path[1:]:
            des = np.r_[p, 0, 0, 0]
            r.add(des, des + [dx, 0, 0, 0, 0, 0], "move")
            cyc.append(k)
        last = dx
    r.add(start, start + [last, 0, 0, 0, 0, 0], "end", 4)
    cyc += [len(PASS_DX) - 1] * 4
    return r, np.array(cyc, dtype=float)


@pytest.mark.parametrize("approach", [True, False])
@pytest.mark.parametrize("with_cycle", [True, False])
def test_repetitions_without_dwells_are_cut_into_passes(tmp_path, approach, with_cycle):
    r, cyc = looped_rows(approach)
    d = r.write(tmp_path / "r", extra={"cycle": cyc} if with_cycle else None)
    an = analyse([read_recording(d)], path_points=150)
    assert an.kind == "path"
    main = an.main_path()
    f = main.figures
    assert f.n == 3 and f.length == pytest.approx(11.6)
    # along the path (not at its start, where each pass stands where the last ended) the
    # passes are 10, 20, 30 mm off in x: deviation 20 mm, l_mean + 3 S_l = 23.987 mm
    inner = slice(2, -1)
    np.testing.assert_allclose(f.dev[inner], 0.020, atol=1e-9)
    np.testing.assert_allclose(f.rt_points[inner], (20 / 3 + 30 / math.sqrt(3)) * 1e-3,
                               atol=1e-9)
    assert f.complete[inner].all()
    others = [p for p in an.paths if p is not main]
    if approach and not with_cycle:  # the approach ends at the path's end pose: a pass
        assert len(others) == 1 and others[0].figures.n == 1
        assert others[0].figures.length == pytest.approx(math.hypot(3.0, 0.2))
    else:  # no approach, or the cycle column leaves it out
        assert others == []
    assert ("'cycle' column" in an.rule) == with_cycle


def test_passes_in_several_recordings_pool(tmp_path):
    dirs = [path_rows(dxs=(dx,)).write(tmp_path / f"r{i}") for i, dx in enumerate(PASS_DX)]
    recs = [read_recording(d) for d in dirs]
    pooled = analyse(recs, path_points=100)
    assert pooled.paths[0].figures.n == 3
    assert pooled.paths[0].figures.at == pytest.approx(0.020, abs=1e-9)
    alone = analyse(recs[:1], path_points=100)
    assert alone.paths[0].figures.at == pytest.approx(0.010, abs=1e-9)


def test_different_paths_are_not_pooled(tmp_path):
    r = path_rows(dxs=(0.01,))
    start = np.r_[CORNERS[0], 0, 0, 0]
    for y in np.linspace(6.0, 9.0, 31)[1:]:  # another path: straight out along y
        p = np.r_[10.0, y, 1.0, 0, 0, 0]
        r.add(p, p + [0, 0, 0.005, 0, 0, 0], "move")
    r.add(np.r_[10.0, 9.0, 1.0, 0, 0, 0], np.r_[10.0, 9.0, 1.0, 0, 0, 0], "dwell", 4)
    assert start is not None
    an = analyse([read_recording(r.write(tmp_path / "r"))], kind="path", path_points=100)
    assert len(an.paths) == 2
    assert [p.figures.n for p in an.paths] == [1, 1]


def test_auto_picks_pose_for_a_pose_campaign_with_moves(tmp_path):
    an = analyse([read_recording(pose_rows().write(tmp_path / "r"))])
    assert an.kind == "pose" and "3 dwell pose(s)" in an.kind_reason
    an = analyse([read_recording(pose_rows().write(tmp_path / "r2"))], kind="path",
                 path_points=20)
    assert an.kind == "path" and len(an.paths) >= 1


# --------------------------------------------------------------------------------------------
# errors


def test_missing_measured_pose_names_file_and_column(tmp_path):
    d = pose_rows().write(tmp_path / "r", drop=("x_meas",))
    with pytest.raises(Iso9283Error, match=r"recording\.csv:1: column 'x_meas' is missing"):
        analyse([read_recording(d)])


def test_all_nan_measured_pose_names_the_column_number(tmp_path):
    r = pose_rows()
    r.meas = [np.r_[m[:2], np.nan, m[3:]] for m in r.meas]
    d = r.write(tmp_path / "r")
    with pytest.raises(Iso9283Error, match=r"column 10 'z_meas': no value in any row"):
        analyse([read_recording(d)])


def test_no_dwell_names_the_states_found(tmp_path):
    d = path_rows().write(tmp_path / "r")
    rec = read_recording(d)
    rec.state = ["move" if s == "dwell" else s for s in rec.state]
    with pytest.raises(Iso9283Error, match=r"no dwell: no row in state 'dwell' \(states found: "
                                           r"init, move\)"):
        analyse([rec], kind="pose")


def test_visit_without_measured_position_is_skipped_with_its_lines(tmp_path):
    r = pose_rows(moves=False)
    for i in range(6, 16):  # the first visit's rows (after 6 init rows)
        r.meas[i] = np.full(6, np.nan)
    seg = segment(read_recording(r.write(tmp_path / "r")))
    assert len(seg.visits) == 3 * CYCLES - 1
    assert any("recording.csv:8-17: dwell without a measured position" in w
               for w in seg.warnings)


# --------------------------------------------------------------------------------------------
# the command


def test_cli_pose_table_and_json(tmp_path, capsys):
    d = pose_rows().write(tmp_path / "r")
    assert main(["iso9283", str(d)]) == 0
    out = capsys.readouterr().out
    assert "ISO 9283 pose figures, 3 commanded poses, 12 visits" in out
    assert "worst" in out and "P3" in out
    assert main(["iso9283", str(d), "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["format"] == "cdpr-iso9283/1"
    a = js["analyses"][0]
    assert a["kind"] == "pose" and len(a["poses"]) == 3
    p1 = a["poses"][0]
    exp = expected_pose(0)
    assert p1["ap_m"] == pytest.approx(exp.ap) and p1["rp_m"] == pytest.approx(exp.rp)
    assert p1["n"] == CYCLES and len(p1["visits"]) == CYCLES
    assert p1["visits"][0]["lines"][0] >= 2
    assert set(a["worst"]) >= {"ap_m", "rp_m", "rp_c_rad", "pose_of"}


def test_cli_path_json_and_plots(tmp_path, capsys):
    d = path_rows().write(tmp_path / "r")
    plots = tmp_path / "plots"
    assert main(["iso9283", str(d), "--json", "--plots", str(plots), "--path-points", "120"]) == 0
    js = json.loads(capsys.readouterr().out)
    p = js["analyses"][0]["paths"][0]
    assert p["passes"] == 3 and p["points"] == 120
    assert p["at_max_m"] == pytest.approx(0.020, abs=1e-7)
    assert p["rt_m"] == pytest.approx((20 / 3 + 30 / math.sqrt(3)) * 1e-3, abs=1e-7)
    assert len(p["along"]["at_x_m"]) == 120 and p["at_a_rad"] == pytest.approx(0.0)
    pngs = sorted(plots.glob("*.png"))
    assert [x.name for x in pngs] == ["01_r_path1.png"]
    assert pngs[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_several_recordings_each_and_pooled(tmp_path, capsys):
    dirs = [str(path_rows(dxs=(dx,)).write(tmp_path / f"r{i}")) for i, dx in enumerate(PASS_DX)]
    assert main(["iso9283", *dirs, "--json", "--path-points", "50"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert [a["paths"][0]["at_max_m"] for a in js["analyses"]] == pytest.approx(PASS_DX)
    plots = tmp_path / "p"
    assert main(["iso9283", *dirs[:2], "--path-points", "50", "--plots", str(plots)]) == 0
    assert sorted(p.name for p in plots.iterdir()) == ["01_r0_path1.png", "02_r1_path1.png",
                                                       "paths.png"]
    assert "ISO 9283 path figures" in capsys.readouterr().out
    assert main(["iso9283", *dirs, "--json", "--pool", "--path-points", "50"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert len(js["analyses"]) == 1 and js["analyses"][0]["paths"][0]["passes"] == 3


def test_cli_errors_exit_2_with_the_file(tmp_path, capsys):
    d = pose_rows().write(tmp_path / "r", drop=("y_meas",))
    assert main(["iso9283", str(d), "--json"]) == 2
    cap = capsys.readouterr()
    assert "column 'y_meas' is missing" in cap.err and "recording.csv" in cap.err
    assert "error" in json.loads(cap.out)
    assert main(["iso9283", str(tmp_path / "absent")]) == 2
    assert "absent" in capsys.readouterr().err
    assert main(["iso9283", str(d), "--settle", "1.5"]) == 2


def test_cli_on_a_campaign_recording(tmp_path, capsys):
    assert main(["campaign", "tests/data/scenarios/paper.toml", str(tmp_path / "c"),
                 "--poses", "3", "--visits", "3", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["iso9283", str(tmp_path / "c"), "--json"]) == 0
    a = json.loads(capsys.readouterr().out)["analyses"][0]
    assert a["kind"] == "pose"
    # merged back-to-back visits are split again: 3 visits of each pose
    assert sorted(p["n"] for p in a["poses"]) == [3, 3, 3]
    assert all(p["rp_m"] is not None and p["rp_m"] < 0.01 for p in a["poses"])


def test_cli_plots_say_what_comes_then_each_plot_as_it_is_written(tmp_path, capsys,
                                                                   monkeypatch):
    from bench.iso9283 import plots as iso_plots

    dirs = [str(path_rows(dxs=(dx,)).write(tmp_path / f"r{i}")) for i, dx in enumerate(PASS_DX)]
    plots = tmp_path / "p"
    seen = []  # stderr so far, each time a figure is about to be drawn
    real = iso_plots.plot_path_cases

    def said() -> str:
        """stderr so far without the progress lines a slow host adds (over 2 s)"""
        return "".join(ln for ln in capsys.readouterr().err.splitlines(keepends=True)
                       if " plots done, " not in ln)

    def spy(*a, **kw):
        seen.append(said())
        return real(*a, **kw)

    monkeypatch.setattr(iso_plots, "plot_path_cases", spy)
    assert main(["iso9283", *dirs[:2], "--path-points", "50", "--plots", str(plots)]) == 0
    assert seen == [f"cdpr iso9283: writing 3 plots into {plots}\n",
                    f"plot {plots}/01_r0_path1.png\n", f"plot {plots}/02_r1_path1.png\n"]
    assert said() == f"plot {plots}/paths.png\n"
    # a pose analysis: bars and scatter
    monkeypatch.undo()
    d = pose_rows().write(tmp_path / "pose")
    assert main(["iso9283", str(d), "--plots", str(tmp_path / "pp")]) == 0
    err = said().splitlines()
    assert err[0] == f"cdpr iso9283: writing 2 plots into {tmp_path / 'pp'}"
    assert len(err) == 3 and all(ln.startswith("plot ") for ln in err[1:])
