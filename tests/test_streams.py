"""Recordings as sensor streams (bench/streams.py, bench/logger_sim.py): the columnar reader
gives what the row-by-row reader gives, rates/jitter/gaps are found, streams are aligned
without inventing samples, motion is judged from measurements by filters that tracker
noise cannot fool, and condensing keeps the rows where something happens."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import bench.streams as streams
from bench.logger_sim import LoggerSpec, dropout_intervals, simulate_truth, write_log
from bench.recording import RecordingError, read_recording
from firmware_sim.scenario import parse_scenario

SMALL = {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
         "nuisance": {"hysteresis_m": 1e-4, "drift_m_per_h": 5e-5},
         "poses": {"kind": "grid", "n": [2, 2, 1], "x": [8.0, 12.0], "y": [6.0, 11.0],
                   "rpy_deg": 1.0, "visits": 1, "dwell_s": 2.0, "init_s": 3.0}}


@pytest.fixture(scope="module")
def small():
    """A one-minute campaign's truth (4 targets), simulated once for the module."""
    sc = parse_scenario(SMALL)
    return sc, simulate_truth(sc, 10.0)


def _log(tmp: Path, small, name: str, **kw) -> Path:
    sc, truth = small
    return write_log(tmp / name, sc, LoggerSpec(physics_hz=10.0, **kw), truth)


THREE = {"rows_hz": 250.0, "encoders_hz": 250.0, "load_cells_hz": 50.0, "tracker_hz": 25.0,
         "empty": "", "controller_columns": False}


def _same(a, b) -> None:
    for g in ("t", "pose_des", "pose_meas", "l_cmd", "l_meas", "tau", "exit_meas"):
        np.testing.assert_array_equal(getattr(a, g), getattr(b, g), err_msg=g)
    assert a.state == b.state


def test_columnar_reader_reads_what_the_row_reader_reads(tmp_path, small, monkeypatch):
    for kw in ({}, THREE):
        monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)  # the columnar reader, small files
        d = _log(tmp_path, small, f"log{len(kw)}", **kw)
        fast = read_recording(d)
        monkeypatch.setattr(streams, "read_columns", lambda p, h: None)
        slow = read_recording(d)
        monkeypatch.undo()
        _same(fast, slow)
        assert np.isnan(fast.pose_meas).any() and np.isfinite(fast.pose_meas).any()


def test_errors_still_name_the_line_and_column(tmp_path, small):
    d = _log(tmp_path, small, "bad", **THREE)
    lines = (d / "recording.csv").read_text().splitlines()
    for bad, msg in (("x", "not a number: 'x'"), ("inf", "infinite value")):
        row = lines[40].split(",")
        row[3] = bad
        (d / "recording.csv").write_text("\n".join(lines[:40] + [",".join(row)]
                                                   + lines[41:]) + "\n")
        with pytest.raises(RecordingError, match=rf"recording.csv:41: column 4 .*{msg}"):
            read_recording(d)
    # a short row (a columnar reader would fill it with nulls) is refused as before
    (d / "recording.csv").write_text("\n".join(lines[:40] + [lines[40].rsplit(",", 1)[0]]
                                               + lines[41:]) + "\n")
    with pytest.raises(RecordingError, match=r"recording.csv:41: \d+ fields, the header has"):
        read_recording(d)


@pytest.mark.parametrize("split", ["time", "sensor"])
def test_a_recording_split_across_files_reads_as_one(tmp_path, small, split):
    one = read_recording(_log(tmp_path, small, "one", **THREE))
    d = _log(tmp_path, small, "split", **THREE, split=split, files=3)
    assert len(list(d.glob("*.csv"))) == 3
    parts = read_recording(d)
    if split == "time":
        _same(one, parts)
    else:  # one file per sensor: each row's samples are in as many rows as streams
        for g, name in (("l_meas", "encoders"), ("tau", "load_cells"),
                        ("pose_meas", "tracker")):
            a, b = getattr(one, g), getattr(parts, g)
            np.testing.assert_array_equal(a[np.isfinite(a).all(axis=1)],
                                          b[np.isfinite(b).all(axis=1)], err_msg=name)
        sa = streams.describe(one)
        sb = streams.describe(parts)
        for name in ("encoders", "load_cells", "tracker"):
            assert sa[name].rate_hz == pytest.approx(sb[name].rate_hz, rel=1e-9)


def test_files_split_by_sensor_at_one_rate_read_as_one_run(tmp_path, small):
    # every stream at the rows' rate in its own file: the merged rows repeat each instant
    # once per stream (zero intervals); no pause, no gap, the rows' rate
    same = {"rows_hz": 100.0, "encoders_hz": 100.0, "load_cells_hz": 100.0,
            "tracker_hz": 100.0}
    rec = read_recording(_log(tmp_path, small, "split1", **same, split="sensor"))
    assert np.mean(np.diff(rec.t) == 0) > 0.6
    _, report = streams.condition(rec)
    assert report["runs"]["pauses"] == 0 and "runs" not in streams.summary_line(report)
    assert all(s["gaps"] == 0 for s in report["streams"].values())


def test_rates_jitter_and_gaps_are_found(tmp_path, small):
    rec = read_recording(_log(tmp_path, small, "three", **THREE, jitter_s=3e-4))
    found = streams.describe(rec)
    assert set(found) == {"encoders", "load_cells", "tracker"}
    for name, hz in (("encoders", 250.0), ("load_cells", 50.0), ("tracker", 25.0)):
        assert found[name].rate_hz == pytest.approx(hz, rel=0.01)
        assert found[name].gaps == []
    assert found["encoders"].jitter_s == pytest.approx(3e-4 * np.sqrt(2), rel=0.3)
    # the tracker loses the platform for 2 s: one gap, where it is, how long
    cut = (rec.t > 20.0) & (rec.t < 22.0)
    rec.pose_meas[cut] = np.nan
    gaps = streams.describe(rec)["tracker"].gaps
    assert len(gaps) == 1 and gaps[0][0] == pytest.approx(20.0, abs=0.05)
    assert gaps[0][1] == pytest.approx(2.0, abs=0.1)
    assert streams.describe(rec)["encoders"].gaps == []


def test_alignment_takes_the_slow_stream_s_instants_and_invents_nothing(tmp_path, small):
    rec = read_recording(_log(tmp_path, small, "three", **THREE))
    found = streams.describe(rec)
    out, al = streams.align(rec, found)
    assert al.reference == "tracker"
    # the rows are the tracker's fixes; encoders read in the same rows are taken as they are
    np.testing.assert_array_equal(out.t, rec.t[found["tracker"].rows])
    np.testing.assert_array_equal(out.l_meas, rec.l_meas[found["tracker"].rows])
    assert al.same_row["encoders"] == len(out.t)
    # load cells between their own samples: interpolated, each value between its neighbours
    assert al.interpolated["load_cells"] > 0.9 * len(out.t)
    cells = found["load_cells"].rows
    k = np.searchsorted(rec.t[cells], out.t)
    ok = (k > 0) & (k < len(cells)) & np.isfinite(out.tau).all(axis=1)
    lo, hi = rec.tau[cells[k[ok] - 1]], rec.tau[cells[np.minimum(k[ok], len(cells) - 1)]]
    assert np.all(out.tau[ok] >= np.minimum(lo, hi) - 1e-9)
    assert np.all(out.tau[ok] <= np.maximum(lo, hi) + 1e-9)
    # a 1 s hole in the load cells: no value invented across it
    hole = (rec.t > 30.0) & (rec.t < 31.0)
    rec.tau[hole] = np.nan
    out2, al2 = streams.align(rec)
    inside = (out2.t > 30.05) & (out2.t < 30.95)
    assert inside.any() and np.isnan(out2.tau[inside]).all()
    assert al2.refused["load_cells"] >= inside.sum()


def test_single_rate_recordings_are_left_as_they_are(tmp_path, small):
    rec = read_recording(_log(tmp_path, small, "one", rows_hz=25.0, encoders_hz=25.0,
                              load_cells_hz=25.0, tracker_hz=25.0))
    out, report = streams.condition(rec)
    assert out is rec and report["alignment"] is None and report["condensed"] is None


def test_interpolation_refused_where_the_motion_does_not_allow_it():
    # a stream sampled at 10 Hz with a velocity step: between the samples around the step
    # the straight line is off by up to 2.5 mm, refused; in the steady parts it is exact
    t = np.arange(0.0, 2.0, 0.1)
    x = np.where(t < 1.0, 0.0, 0.5 * (t - 1.0))[:, None]
    dst = np.array([0.45, 0.95, 1.55])
    v, err = streams._interp(t, x, dst, 0.25)
    assert err[0, 0] == 0.0 and err[2, 0] < 1e-12 and v[2, 0] == pytest.approx(0.275)
    assert err[1, 0] > 1e-3


def test_a_tracker_fix_is_interpolated_whole_or_refused_whole(tmp_path, small):
    """The load cells set the instants, the tracker's fixes are interpolated to them; where
    one axis moves too fast to interpolate, the whole pose is refused: never a pose with x
    and y missing and z kept (that row would be compared with a platform at x = y = 0)."""
    rec = read_recording(_log(tmp_path, small, "whole", rows_hz=200.0, encoders_hz=200.0,
                              load_cells_hz=25.0, tracker_hz=50.0))
    rows = streams.describe(rec)["tracker"].rows
    rec.pose_meas[rows[len(rows) // 2], 0] += 0.05  # one x reading off: x not interpolable
    out, al = streams.align(rec)
    assert al.reference == "load_cells"
    seen = np.isfinite(out.pose_meas)
    assert seen.any() and al.refused["tracker"] > 0
    assert np.all(seen.all(axis=1) | ~seen.any(axis=1))


@pytest.mark.parametrize("rate", [50.0, 100.0, 250.0])
def test_quasi_static_rows_from_measured_poses_resist_tracker_noise(rate):
    # a platform moving at a steady 0.25 m/s, measured with 0.05 mm / 0.05 mrad noise:
    # every row away from the ends is quasi-static; finite differences call most of them
    # accelerating at these rates
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 8.0, 1.0 / rate) + rng.normal(0, 1e-4, int(8.0 * rate))
    t.sort()
    pose = np.zeros((len(t), 6))
    pose[:, 0] = 5.0 + 0.25 * t
    pose[:, :3] += rng.normal(0, 5e-5, (len(t), 3))
    pose[:, 3:] += rng.normal(0, 5e-5, (len(t), 3))
    rec = _bare(t, pose)
    rows = np.arange(len(t))
    lin, ang = streams.measured_acceleration(rec, rows)
    from bench.diagnosis.samples import ACCEL_MAX, ANG_ACCEL_MAX

    assert np.all(lin <= ACCEL_MAX) and np.all(ang <= ANG_ACCEL_MAX)
    dt = np.diff(t)
    a = np.diff(np.diff(pose[:, 3:], axis=0) / dt[:, None], axis=0) / dt[1:, None]
    assert np.mean(np.abs(a).max(axis=1) > ANG_ACCEL_MAX) > 0.5  # what the filter avoids
    # a real acceleration (a stop within 0.2 s) is seen
    pose2 = pose.copy()
    pose2[:, 0] = 5.0 + np.where(t < 4.0, 0.25 * t, 1.0)
    lin2, _ = streams.measured_acceleration(_bare(t, pose2), rows)
    assert np.any(lin2[np.abs(t - 4.0) < 0.3] > ACCEL_MAX)


def test_standing_and_moving_rows_from_measurements_alone():
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 12.0, 0.04)
    x = np.clip(0.25 * (t - 4.0), 0.0, 1.0)  # stands 4 s, moves 4 s, stands 4 s
    pose = np.zeros((len(t), 6))
    pose[:, 0] = x + rng.normal(0, 5e-5, len(t))
    still, known = streams.still_rows(_bare(t, pose))
    assert known[5:-5].all()
    assert still[(t > 0.6) & (t < 3.4)].all() and still[(t > 8.6) & (t < 11.4)].all()
    assert not still[(t > 4.6) & (t < 7.4)].any()


def _bare(t: np.ndarray, pose: np.ndarray):
    from bench.recording import Recording
    from controller.robot import resolve_robot

    robot = resolve_robot("rocaspect")
    N, n = len(t), robot.n_cables
    nan = np.full((N, n), np.nan)
    return Recording(Path("."), robot, {}, pose[0], t, np.full((N, 6), np.nan), pose,
                     nan, nan.copy(), nan.copy(), np.full((N, n, 3), np.nan))


def test_condensing_keeps_every_row_where_something_happens(tmp_path, small):
    rec = read_recording(_log(tmp_path, small, "one", rows_hz=25.0, encoders_hz=25.0,
                              load_cells_hz=25.0, tracker_hz=25.0))
    ev = streams.events(rec)
    # the moves' starts and stops are events (the encoders start or stop moving)
    moving = np.any(np.abs(np.diff(rec.l_meas, axis=0)) > 1e-6, axis=1)
    starts = np.flatnonzero(moving[1:] & ~moving[:-1]) + 1
    assert len(starts) >= 4 and all(ev[max(s - 1, 0):s + 2].any() for s in starts)
    out, info = streams.condense(rec, budget=len(rec.t) // 5)
    assert info["rows_after"] <= len(rec.t) // 5 + info["event_rows"]
    kept = set(out.source_rows.tolist())
    assert all(s in kept for s in starts)
    assert out.t[0] == rec.t[0] and out.t[-1] == rec.t[-1]


def test_a_jump_is_an_event_and_kept(tmp_path, small):
    rec = read_recording(_log(tmp_path, small, "one", rows_hz=25.0, encoders_hz=25.0,
                              load_cells_hz=25.0, tracker_hz=25.0))
    moving = np.any(np.abs(np.diff(rec.l_meas, axis=0)) > 1e-6, axis=1)
    k = int(np.flatnonzero(~moving[100:])[20]) + 101  # a row within a dwell
    before = streams.events(rec)[k]
    rec.l_meas[k:, 3] += 1e-3  # cable 22 slips 1 mm on its drum
    assert not before and streams.events(rec)[k]
    out, _ = streams.condense(rec, budget=len(rec.t) // 10)
    assert k in set(out.source_rows.tolist()) and k - 1 in set(out.source_rows.tolist())


def test_commanded_motion_under_jittered_time_stamps_is_not_called_accelerating():
    # a controller logging its set point at 200 Hz with 0.3 ms jitter in the time stamps:
    # finite differences scatter by metres per second squared; the filter does not
    rng = np.random.default_rng(3)
    t = np.sort(np.arange(0.0, 6.0, 0.005) + rng.normal(0, 3e-4, 1200))
    x = 5.0 + 0.25 * np.arange(1200) * 0.005  # the set point at its nominal instants
    pose = np.zeros((1200, 6))
    pose[:, 0] = x
    rec = _bare(t, pose + rng.normal(0, 5e-5, pose.shape))
    rec.pose_des = pose
    from bench.diagnosis.samples import _quasi_static, _quasi_static_rows

    rows = np.arange(100, 1100)
    assert streams.jittered(rec.t)
    assert _quasi_static(rec, rows).all()
    assert _quasi_static_rows(rec, rows).mean() < 0.5  # what finite differences say


def test_the_tracker_s_gap_keeps_the_other_streams_at_its_rate(tmp_path, small):
    rec = read_recording(_log(tmp_path, small, "three", **THREE))
    cut = (rec.t > 20.0) & (rec.t < 22.0)
    rec.pose_meas[cut] = np.nan
    out, al = streams.align(rec)
    inside = (out.t > 20.1) & (out.t < 21.9)
    # rows at about the tracker's 25 Hz inside its gap, with encoders, without a pose
    assert 35 <= inside.sum() <= 55
    assert np.isnan(out.pose_meas[inside]).all() and np.isfinite(out.l_meas[inside]).all()
    assert np.isfinite(out.tau[inside]).all(axis=1).mean() > 0.9
    assert al.reference == "tracker"


def test_an_error_in_a_split_recording_names_its_file(tmp_path, small):
    d = _log(tmp_path, small, "split", **THREE, split="sensor")
    lines = (d / "tracker.csv").read_text().splitlines()
    row = lines[5].split(",")
    row[2] = "n/a"
    (d / "tracker.csv").write_text("\n".join(lines[:5] + [",".join(row)] + lines[6:]) + "\n")
    with pytest.raises(RecordingError, match=r"tracker.csv:6: column 3 .*not a number"):
        read_recording(d)
    meta = (d / "meta.toml").read_text()
    (d / "meta.toml").write_text(meta.replace(
        'samples = [\n    "encoders.csv",\n    "load_cells.csv",\n    "tracker.csv",\n]',
        "samples = []"))
    with pytest.raises(RecordingError, match=r"meta.toml: samples: an empty list"):
        read_recording(d)


def _read_in_child(d: str, out) -> None:
    out.put(len(read_recording(Path(d)).t))


def test_a_child_forked_after_polars_ran_reads_without_deadlock(tmp_path, small,
                                                                monkeypatch):
    """The project's process pools fork; a child forked after this process used polars
    must not call polars (its thread pool is not in the child: a deadlock, as seen in a
    paper campaign's workers): it reads row by row, the same rows."""
    import multiprocessing

    monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)
    d = _log(tmp_path, small, "log", **THREE)
    rows = len(read_recording(d).t)  # polars' pool started here
    assert streams._polars_usable()
    ctx = multiprocessing.get_context("fork")
    out = ctx.Queue()
    child = ctx.Process(target=_read_in_child, args=(str(d), out))
    child.start()
    child.join(60)
    if child.is_alive():
        child.kill()
        child.join()
        pytest.fail("the forked child did not finish reading in 60 s (polars deadlock)")
    assert out.get(timeout=5) == rows


DWELLS = {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 5,
          "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
          "poses": {"kind": "grid", "n": [2, 2, 1], "x": [8.0, 12.0], "y": [6.0, 11.0],
                    "rpy_deg": 1.0, "visits": 2, "dwell_s": 2.0, "init_s": 3.0}}


def test_a_dwell_recording_s_line_says_runs_not_gaps(tmp_path):
    # the project's recorder writes rows at dwells only: the pauses between dwells are the
    # recording's runs, no stream lost anything
    from bench.campaign import run_campaign

    run_campaign(parse_scenario(DWELLS), tmp_path / "dwells")
    rec = read_recording(tmp_path / "dwells")
    _, report = streams.condition(rec)
    line = streams.summary_line(report)
    assert report["runs"]["runs"] == 9 and report["runs"]["pauses"] == 8  # 8 visits + init
    assert "rows in 9 runs" in line and "gaps" not in line
    assert all(s["gaps"] == 0 for s in report["streams"].values())
    # the tracker lost inside a dwell (3 of its 5 rows, 1.5 s): named, the other streams not
    dwell = np.flatnonzero(rec.t > 20.0)[:5]
    rec.pose_meas[dwell[1:4]] = np.nan
    _, report = streams.condition(rec)
    assert report["streams"]["tracker"]["gaps"] == 1
    assert report["streams"]["tracker"]["longest_gaps"][0]["duration_s"] == pytest.approx(2.0)
    assert "tracker 2 Hz, 1 gaps (2 s without samples)" in streams.summary_line(report)
    assert report["streams"]["encoders"]["gaps"] == 0


def _union(iv: np.ndarray) -> np.ndarray:
    """Intervals (D, 2) [s] with those that overlap merged, sorted."""
    out: list[list[float]] = []
    for a, b in iv[np.argsort(iv[:, 0])]:
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return np.array(out)


def test_a_logger_s_dropouts_are_named_where_they_are(tmp_path, small):
    # tracker dropouts drawn by the logger (2 to 3 s, about 4 a minute): the report names
    # each at its time; the streams without dropouts lose nothing
    drops = (("tracker", 4.0, 2.0, 3.0),)
    d = _log(tmp_path, small, "drops", **THREE, dropouts=drops)
    rec = read_recording(d)
    sc, _ = small
    spec = LoggerSpec(physics_hz=10.0, **THREE, dropouts=drops)
    iv = dropout_intervals(spec, sc.seed, rec.t[0], rec.t[-1])["tracker"]
    iv = _union(iv[iv[:, 1] < rec.t[-1] - 0.1])  # overlapping dropouts are one gap
    assert len(iv) >= 2
    _, report = streams.condition(rec)
    tr = report["streams"]["tracker"]
    assert tr["gaps"] == len(iv)
    found = sorted((g["t_s"], g["duration_s"]) for g in tr["longest_gaps"])
    for (a, b), (t_s, dur) in zip(iv, found, strict=False):
        assert t_s == pytest.approx(a, abs=0.05) and dur == pytest.approx(b - a, abs=0.1)
    assert "tracker 25 Hz (jitter" in streams.summary_line(report)
    assert f", {len(iv)} gaps (" in streams.summary_line(report)
    assert report["streams"]["encoders"]["gaps"] == 0 and report["runs"]["pauses"] == 0
    assert "runs" not in streams.summary_line(report)


def test_without_dropouts_the_logger_samples_as_before(tmp_path, small):
    # the dropouts draw from a generator of their own: a logger without them writes the
    # same file as before they existed; one with them differs only in the dropped stream
    a = read_recording(_log(tmp_path, small, "a", **THREE))
    b = read_recording(_log(tmp_path, small, "b", **THREE, dropouts=(("load_cells", 3.0, 1.0,
                                                                       2.0),)))
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.l_meas, b.l_meas)
    lost = np.isfinite(a.tau).any(axis=1) & ~np.isfinite(b.tau).any(axis=1)
    assert lost.sum() > 0 and not (np.isfinite(b.tau).any(axis=1)
                                    & ~np.isfinite(a.tau).any(axis=1)).any()
