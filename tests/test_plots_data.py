"""Each plot draws the data it says it draws (not only that a PNG was written).

The dry run's ``path.png`` draws the pose errors the summary is made of (per tracker fix,
to the commanded path) and axes around the data; its ``cables.png`` the following-error
window and the supervisor's events; the diagnosis's ``cables.png`` linear bars with the
noise level; ``exit_points.png`` the values fixed by construction apart from the checked
ones; ``lengths_over_time.png`` a noise band one can see; ``workspace.png`` the
feasibility boundary, its title and legend clear of the map.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bench.dryrun import report as dry  # noqa: E402
from bench.dryrun.loop import ControlLoop, LoopOptions  # noqa: E402
from bench.dryrun.record import DryRunRecorder  # noqa: E402
from bench.recording import read_recording  # noqa: E402
from controller.effects import apply_effects  # noqa: E402
from controller.trajectory import Dwell, Move, Trajectory  # noqa: E402
from controller.winch import load_winches  # noqa: E402
from firmware_sim.plant import Plant  # noqa: E402
from hal.fake import FakeHardware  # noqa: E402
from hal.tracker import CallableTracker  # noqa: E402
from tests.robots import rocaspect  # noqa: E402

EXAMPLE = Path(__file__).parent.parent / "examples" / "paper_tables"
P0 = np.array([10.0, 8.56, 1.2, 0, 0, 0])
W = dataclasses.replace(load_winches(), quick_stop_option=np.full(8, 6),
                        following_error_m=np.full(8, 0.015))
TRUTH = {"mast_compliance": {f"k{a}_{m}": k for m in "1234"
                             for a, k in zip("xyz", (2e5, 5e5, 3e5), strict=True)},
         "exit_point_offset": {"dx_11": 0.02, "dy_21": -0.02}}


def _lines(ax, prefix: str) -> list:
    return [ln for ln in ax.get_lines() if (ln.get_gid() or "").startswith(prefix)]


# ---------------------------------------------------------------- dry run: path, cables
@pytest.fixture(scope="module")
def dry_run(tmp_path_factory):
    """A short dry run on the fake hardware: the nominal model against a compliant truth
    (errors of millimetres), a tracker giving a fix every 50 ms (held between fixes) with
    its own time stamps, recorded every 3rd cycle, a drive fault at 2.2 s (quick stop)."""
    model = rocaspect()
    plant = Plant(model, apply_effects(model, TRUTH), P0)
    fired: dict = {}
    hw: FakeHardware

    def tensions(lm, t):
        if t >= 2.2 and not fired:
            fired["t"] = t
            hw.inject_drive_fault(3, 0x2310)
        return plant.measured_tensions(plant.settle(lm, t).tensions)

    hw = FakeHardware(W, initial_lengths_m=plant.reference, plant=tensions,
                      tension_period_s=0.02)
    fix = {"t": -1.0, "pose": None}

    def tracker():
        t_fix = math.floor(hw.t / 0.05) * 0.05
        if t_fix > fix["t"]:
            fix["t"], fix["pose"] = t_fix, plant.state.pose.copy()
        return fix["t"], fix["pose"], True

    d = tmp_path_factory.mktemp("dry") / "rec"

    def plan(p0):
        return Trajectory([Move([10.1, 9.8, 1.21, 0, 0, 0]), Dwell(0.3)], p0)

    opt = LoopOptions(init_dwell_s=0.2, end_dwell_s=0.2, decimate=3)
    loop = ControlLoop(hw, CallableTracker(tracker), model, plan, opt,
                       lambda p0: DryRunRecorder(d, model, p0, {"notes": "test"}))
    res = loop.run()
    assert res.ended == "quick_stop", res.message
    return res, d, read_recording(d)


def test_path_error_is_the_summarys_per_tracker_fix(dry_run):
    """The plotted errors are the summary's numbers: RMS and largest equal to 1e-9, one
    point per counted fix (a fix held over rows counts once), none in init/quick stop."""
    res, d, rec = dry_run
    t, err, st = dry.path_errors(rec)
    assert len(err) == res.pose_errors > 10
    rms, big = dry.error_figures(err)
    assert abs(rms - res.pose_error_rms_m) < 1e-9 and abs(big - res.pose_error_max_m) < 1e-9
    assert res.pose_error_max_m > 3e-4  # a real error (the nominal model misses)
    assert not {"init", "quick_stop"} & set(st)
    # fixes every 50 ms, rows every 3 cycles: fewer counted errors than moving rows
    assert len(err) < 0.5 * sum(s not in ("init", "quick_stop") for s in rec.state)
    fig = dry.path_figure(rec, plt)
    e = fig.axes[2]
    drawn = np.sort(np.concatenate([ln.get_ydata() for ln in _lines(e, "error_")
                                    if ln.get_gid() not in ("error_rms", "error_max")]))
    assert np.allclose(drawn, np.sort(1e3 * err), rtol=0, atol=1e-9)
    assert abs(_lines(e, "error_rms")[0].get_ydata()[0] - 1e3 * res.pose_error_rms_m) < 1e-9
    assert abs(_lines(e, "error_max")[0].get_ydata()[0] - 1e3 * res.pose_error_max_m) < 1e-9
    assert e.get_ylim()[1] >= 1e3 * res.pose_error_max_m
    plt.close(fig)


def test_path_views_are_around_the_data_not_the_floor(dry_run):
    """Axis limits contain the commanded path and the fixes and stay near them: the side
    view's z axis spans centimetres around the path's 1.2 m (a path mostly along y), not
    the y range nor metres of floor; every panel has a legend."""
    _, _, rec = dry_run
    fig = dry.path_figure(rec, plt)
    top, side, err = fig.axes[:3]
    z = np.concatenate([rec.pose_des[:, 2], rec.pose_meas[:, 2]])
    z = z[np.isfinite(z)]
    lo, hi = side.get_ylim()
    assert lo <= z.min() and hi >= z.max()
    assert lo > z.min() - 0.05 and hi < z.max() + 0.05
    y_span = np.nanmax(rec.pose_des[:, 1]) - np.nanmin(rec.pose_des[:, 1])
    assert y_span > 0.3 and hi - lo < 0.5 * y_span  # z is not drawn to the y axis's scale
    for ax, (i, j) in ((top, (0, 1)), (side, (1, 2))):
        for k, lim in ((i, ax.get_xlim()), (j, ax.get_ylim())):
            v = rec.pose_des[:, k]
            assert lim[0] <= np.nanmin(v) and lim[1] >= np.nanmax(v)
            assert lim[1] - lim[0] < (np.nanmax(v) - np.nanmin(v)) + 1.5  # no floor-to-roof
    assert all(ax.get_legend() is not None for ax in (top, side, err))
    plt.close(fig)


def test_cables_draw_the_window_and_mark_the_quick_stop(dry_run):
    """The lower panel: a legend naming every cable and the window, the 0x6065 window at
    ±15 mm (the winch set's value, not the shipped 20 mm), the quick stop's event at its
    time from events.csv, the quick-stop rows shaded."""
    res, d, rec = dry_run
    events = dry.supervisor_events(d)
    stops = [e for e in events if e["reaction"] == "quick_stop" and e["active"]]
    assert stops and all(e["kind"] not in ("initialised",) for e in events)
    t_fault = [e["t"] for e in res.events if e["kind"] == "drive_fault"][0]
    assert abs(stops[0]["t"] - t_fault) < 1e-5
    window, src = dry.following_error_window(rec, W)
    assert np.allclose(window, 0.015)
    fig = dry.cables_figure(rec, events, window, src, plt)
    lower = fig.axes[1]
    ys = sorted(ln.get_ydata()[0] for ln in _lines(lower, "following_error_window"))
    assert np.allclose(ys, [-15.0, 15.0])
    marks = _lines(lower, "event_quick_stop_start")
    assert [ln.get_xdata()[0] for ln in marks] == [e["t"] for e in stops]
    assert any(c.get_gid() == "quick_stop_rows" for c in lower.collections)
    labels = [t.get_text() for t in lower.get_legend().get_texts()]
    assert all(f"cable {c}" in labels for c in rec.robot.cable_ids)
    assert any("0x6065" in lab and "15 mm" in lab for lab in labels)
    assert any("quick_stop" in lab for lab in labels)
    plt.close(fig)
    # the shipped winch file's window when none is given
    assert np.allclose(dry.following_error_window(rec)[0], load_winches().following_error_m)


def test_supervisor_events_are_none_on_a_quiet_run(tmp_path):
    (tmp_path / "events.csv").write_text(
        "t,device,address,cable,kind,code,reaction,active,text\n"
        '0,controller,0,,initialised,0x0000,none,1,"p0"\n'
        '0,controller,0,,reaction_override,0x0000,log,1,"slack -> log"\n'
        '1.5,drive,3,21,emcy,0x2310,event,1,"over current"\n')
    assert dry.supervisor_events(tmp_path) == []


# ------------------------------------------------------------------------ diagnosis
def _campaign(tmp_path: Path):
    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose
    from firmware_sim.scenario import parse_scenario

    sc = {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 3,
          "init_pose": [10.0, 8.56, 1.0, 0, 0, 0],
          "truth": {"exit_point_offset": {"dx_21": 0.03, "dy_32": -0.025}},
          "nuisance": {"hysteresis_m": 5e-5, "drift_m_per_h": 2e-5},
          "poses": copy.deepcopy({"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0,
                                  "visits": 2}), "recording": {}}
    return diagnose(run_campaign(parse_scenario(sc), tmp_path / "rec"))


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    from bench.evaluate import one_blas_thread

    one_blas_thread()
    return _campaign(tmp_path_factory.mktemp("diag"))


def test_diagnosis_cable_bars_are_linear_with_the_noise_level(campaign):
    from bench.diagnosis.plots import cable_bars_data, cable_bars_figure

    data = cable_bars_data(campaign)
    assert data["before_mm"][2] > 10 * data["noise_mm"]  # cable 21's offset
    fig = cable_bars_figure(data, plt)
    ax = fig.axes[0]
    assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0.0
    for key in ("before_mm", "after_mm"):
        bars = [p for p in ax.patches if p.get_gid() == f"bars_{key}"]
        assert np.allclose([b.get_height() for b in bars], data[key])
        assert all(b.get_y() == 0.0 for b in bars)
    line = _lines(ax, "noise_line")[0]
    assert abs(line.get_ydata()[0] - data["noise_mm"]) < 1e-12
    band = [p for p in ax.patches if p.get_gid() == "noise_band"][0]
    y = band.get_path().transformed(band.get_patch_transform()).vertices[:, 1]
    assert np.isclose(min(y), 0) and np.isclose(max(y), data["noise_mm"])
    assert ax.get_ylim()[1] >= max(data["before_mm"].max(), data["noise_mm"])
    plt.close(fig)


def test_lengths_over_time_noise_band_is_visible(campaign):
    """The band is ±noise on every panel; on the corrected model's panels (residuals near
    the noise) it spans a good part of the axis, not a hairline under 20 mm of scale."""
    from bench.diagnosis.plots import lengths_over_time_data, lengths_over_time_figure

    data = lengths_over_time_data(campaign)
    fig = lengths_over_time_figure(data, plt)
    n = len(data["cables"])
    axes = np.array(fig.axes[:2 * n]).reshape(n, 2)
    noise = data["noise_mm"]
    for k in range(n):
        for col, key in enumerate(("before_mm", "after_mm")):
            ax = axes[k, col]
            band = [p for p in ax.patches if p.get_gid() == "noise_band"]
            assert len(band) == 1
            lo, hi = ax.get_ylim()
            v = data[key][:, k]
            assert lo <= np.nanmin(v) and hi >= np.nanmax(v)
            pts = _lines(ax, f"residual_{key}")[0].get_ydata()
            assert np.allclose(pts, v, equal_nan=True)
        lo, hi = axes[k, 1].get_ylim()
        assert 2 * noise / (hi - lo) > 0.2, data["cables"][k]
    # the recording's model misses cable 21 by centimetres: there the band is thin
    lo, hi = axes[2, 0].get_ylim()
    assert 2 * noise / (hi - lo) < 0.1
    plt.close(fig)


def test_exit_points_constructed_values_drawn_apart():
    """The paper's tables: 6 of 8 exit points measured at one pose only, each moved by its
    own fitted offset onto that measurement: zero by construction, hatched, not solid
    bars; 21 and 22 (five poses) are checked and drawn solid."""
    from bench.diagnosis.plots import exit_points_data, exit_points_figure
    from bench.diagnosis.report import diagnose

    data = exit_points_data(diagnose(EXAMPLE))
    cables = data["cables"]
    built = [c for c, b in zip(cables, data["constructed"], strict=True) if b]
    assert built == ["11", "12", "31", "32", "41", "42"]
    assert all(data["after_mm"][cables.index(c)] < 0.1 for c in built)
    fig = exit_points_figure(data, plt)
    ax = fig.axes[0]
    solid = [p for p in ax.patches if p.get_gid() == "bars_fitted"]
    hatched = [p for p in ax.patches if p.get_gid() == "bars_constructed"]
    assert len(solid) == 2 and len(hatched) == 6
    assert np.allclose([p.get_height() for p in solid],
                       data["after_mm"][[cables.index("21"), cables.index("22")]])
    assert all(p.get_hatch() == "///" for p in hatched)
    assert all(not p.get_hatch() for p in solid)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("by construction" in lab for lab in labels)
    plt.close(fig)


# ------------------------------------------------------------------------ workspace
def test_workspace_boundary_title_and_legend(tmp_path):
    """On a robot whose tension limit leaves part of the footprint infeasible: the
    boundary contour has every feasible cell centre inside and every infeasible one
    outside; the title is inside the figure; the legend is outside the map."""
    from matplotlib.path import Path as MPath

    from bench.workspace_plot import workspace_figure
    from controller.workspace import wrench_feasible_grid

    robot = rocaspect(tension_max=290.0)
    grid = wrench_feasible_grid(robot, z=1.0, step=1.0)
    assert grid.feasible.any() and not grid.feasible.all()
    fig = workspace_figure(grid, robot, plt)
    ax = fig.axes[0]
    fig.canvas.draw()
    X, Y = np.meshgrid(grid.xs, grid.ys, indexing="ij")
    centres = np.column_stack([X.ravel(), Y.ravel()])
    contours = [c for c in ax.collections if type(c).__name__ in ("QuadContourSet",
                                                                  "ContourSet")]
    paths = [p for c in contours for p in c.get_paths()]
    assert paths
    inside = np.zeros(len(centres), dtype=int)
    for p in paths:
        for poly in p.to_polygons():
            inside += MPath(poly).contains_points(centres)
    inside = inside % 2 == 1  # holes: even-odd
    assert np.array_equal(inside, grid.feasible.ravel())
    fb = fig.bbox
    tb = ax.title.get_window_extent()
    assert tb.x0 >= fb.x0 and tb.x1 <= fb.x1 and tb.y1 <= fb.y1
    lb = ax.get_legend().get_window_extent()
    assert not lb.overlaps(ax.get_window_extent())
    xl, yl = ax.get_xlim(), ax.get_ylim()
    assert xl[0] < robot.exits[:, 0].min() and xl[1] > robot.exits[:, 0].max()
    assert yl[0] < robot.exits[:, 1].min() and yl[1] > robot.exits[:, 1].max()
    plt.close(fig)


def test_model_check_plots_dir_and_the_deprecated_plot(tmp_path, capsys):
    import json

    from bench.cli import main

    assert main(["model", "check", "rocaspect", "--step", "1.5", "--json",
                 "--plots", str(tmp_path / "p")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["plots"] == [str(tmp_path / "p" / "workspace.png")]
    assert (tmp_path / "p" / "workspace.png").stat().st_size > 10_000
    assert main(["model", "check", "rocaspect", "--step", "1.5", "--plot",
                 str(tmp_path / "old.png")]) == 0
    assert "deprecated" in capsys.readouterr().err
    assert (tmp_path / "old.png").stat().st_size > 10_000
    assert main(["model", "check", "rocaspect", "--plot", str(tmp_path / "a.png"),
                 "--plots", str(tmp_path / "q")]) == 2
