"""Long recordings read block by block (bench/chunked.py): the blocks hold what the whole
file holds, a bad row names its line in the file, a forked child reads row by row, the
conditioned rows are those of the whole file, a recording split in time reads as one, and
decimating while reading gives the answer of the full (uncondensed) fit."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

import bench.chunked as ch
import bench.streams as streams
from bench.diagnosis.report import diagnose
from bench.logger_sim import LoggerSpec, simulate_truth, write_log
from bench.recording import RecordingError, _read_columns, _read_header, open_recording
from firmware_sim.scenario import parse_scenario

pytestmark = pytest.mark.slow

#: a 3-minute campaign: 4 targets visited twice, 2 s dwells (about 45,000 rows at 250 Hz)
POSES = {"kind": "grid", "n": [2, 2, 1], "x": [8.0, 12.0], "y": [6.0, 11.0], "rpy_deg": 2.0,
         "visits": 2, "dwell_s": 2.0, "init_s": 3.0}
PHYSICS_HZ = 10.0
#: encoders 250 Hz in every row, load cells 50 Hz, tracker 25 Hz, empty fields, no controller
THREE = LoggerSpec(rows_hz=250.0, encoders_hz=250.0, load_cells_hz=50.0, tracker_hz=25.0,
                   empty="", controller_columns=False, physics_hz=PHYSICS_HZ)
#: blocks of this many bytes: some tens of blocks in the 3-minute log
BLOCK = 300_000


@pytest.fixture(scope="module")
def slipped(tmp_path_factory):
    """A cable paid out 4 mm after initialisation, logged at three rates: the scenario, its
    truth, the recording and a scratch folder."""
    sc = parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 21,
                         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
                         "nuisance": {"hysteresis_m": 1e-4, "drift_m_per_h": 5e-5},
                         "poses": POSES,
                         "truth": {"cable_length_offset": {"dl_21": 0.004}}})
    truth = simulate_truth(sc, PHYSICS_HZ)
    d = tmp_path_factory.mktemp("chunked")
    return sc, truth, write_log(d / "three", sc, THREE, truth), d


@pytest.fixture
def in_blocks(monkeypatch):
    """Every recording read block by block, in blocks of :data:`BLOCK` bytes, the columnar
    parse used whatever the file's size."""
    monkeypatch.setattr(ch, "CHUNKED_MIN_BYTES", 0)
    monkeypatch.setattr(ch, "BLOCK_BYTES", BLOCK)
    monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)


def _samples(rec):
    _, _, robot, _, p = open_recording(rec)
    return p, _read_header(p, robot), robot


def _blocks(p, header) -> dict[str, np.ndarray]:
    parts = list(ch.iter_blocks(p, header, BLOCK))
    assert len(parts) > 10
    return {k: np.concatenate([c[k] for c, _, _ in parts]) for k in parts[0][0]}


def test_blocks_hold_what_the_whole_file_holds(slipped, monkeypatch):
    monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)
    p, header, robot = _samples(slipped[2])
    _, whole, _ = _read_columns(p, robot)
    got = _blocks(p, header)
    assert got.keys() == whole.keys()
    for k, v in whole.items():
        np.testing.assert_array_equal(got[k], v)  # NaN where NaN, every value the same


@pytest.mark.parametrize("block", [1, 50, 4096])
def test_blocks_of_any_size_cut_at_line_ends(tmp_path, block):
    """Blocks shorter than a line, a last line without its line end, a blank last line: the
    rows are the file's, and a bad row's error names its line in the file."""
    from bench.recording import RecordingError

    header = ["t", "x_meas"]  # (a documented column: the lab's own may hold text)
    p = tmp_path / "s.csv"
    p.write_bytes(b"t,x_meas\n" + b"".join(b"%d,%d.5\n" % (i, i) for i in range(40)) + b"40,1")
    t = np.concatenate([c["t"] for c, _, _ in ch.iter_blocks(p, header, block)])
    np.testing.assert_array_equal(t, np.arange(41.0))
    p.write_bytes(b"t,x_meas\n0,1\n1,2\n\n")
    assert [len(c["t"]) for c, _, _ in ch.iter_blocks(p, header, block)] in ([2], [1, 1])
    p.write_bytes(b"t,x_meas\n")
    assert list(ch.iter_blocks(p, header, block)) == []
    p.write_bytes(b"t,x_meas\n0,1\n1,2\n2,oops\n3,4\n")
    with pytest.raises(RecordingError, match=r"s\.csv:4: column 2"):
        list(ch.iter_blocks(p, header, block))


def test_a_forked_child_reads_blocks_row_by_row(slipped, monkeypatch):
    # in a process forked after its parent used polars, polars is never called: the blocks
    # are read row by row, and hold the same
    monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)
    p, header, robot = _samples(slipped[2])
    _, whole, _ = _read_columns(p, robot)
    monkeypatch.setattr(streams, "_POLARS_PID", -1)  # as in a forked child

    def forbidden(*a):
        raise AssertionError("polars called in a forked child")

    monkeypatch.setattr(streams, "parse_block", forbidden)
    got = _blocks(p, header)
    for k, v in whole.items():
        np.testing.assert_array_equal(got[k], v)


@pytest.mark.parametrize("bad, why", [("abc", "not a number"), ("inf", "infinite value")])
def test_a_bad_row_in_a_block_names_its_line_in_the_file(slipped, tmp_path, in_blocks,
                                                         bad, why):
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(slipped[2], rec)
    csv = rec / "recording.csv"
    lines = csv.read_bytes().split(b"\n")
    k = 30_001  # line 30,001 of the file: far beyond the first block
    fields = lines[k - 1].split(b",")
    fields[3] = bad.encode()
    lines[k - 1] = b",".join(fields)
    csv.write_bytes(b"\n".join(lines))
    with pytest.raises(RecordingError, match=rf"recording.csv:{k}: column 4 'l_meas_21': "
                                             rf"{why}"):
        ch.read_conditioned(rec)


def _conditioned_pair(rec, monkeypatch):
    whole = ch.read_conditioned(rec)
    monkeypatch.setattr(ch, "CHUNKED_MIN_BYTES", 0)
    monkeypatch.setattr(ch, "BLOCK_BYTES", BLOCK)
    monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)
    return whole, ch.read_conditioned(rec)


def _same_rows(a, b) -> None:
    """Conditioned recordings ``a`` (whole file) and ``b`` (blocks): the same rows of the
    file at the same instants, the same values, tensions in the same rows; an
    interpolated tension refused in a column by one and not the other in at most 0.5 % of
    the rows (each block judges the interpolation against its own stream noise)."""
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.source_rows, b.source_rows)
    for g in ("l_meas", "pose_meas", "exit_meas"):
        np.testing.assert_array_equal(getattr(a, g), getattr(b, g))
    both = np.isfinite(a.tau) & np.isfinite(b.tau)
    np.testing.assert_allclose(a.tau[both], b.tau[both], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.isfinite(a.tau).any(axis=1),
                                  np.isfinite(b.tau).any(axis=1))
    assert (np.isfinite(a.tau) != np.isfinite(b.tau)).any(axis=1).mean() < 0.005


def test_conditioned_in_blocks_as_the_whole_file(slipped, monkeypatch):
    (a, ra, ea), (b, rb, eb) = _conditioned_pair(slipped[2], monkeypatch)
    assert rb["read"]["blocks"] > 10 and "read" not in ra
    _same_rows(a, b)
    assert rb["streams"] == ra["streams"]  # rates, jitter, gaps of all rows
    for k in ("reference", "rows_before", "rows_after", "same_row"):
        assert rb["alignment"][k] == ra["alignment"][k]
    assert rb["alignment"]["interpolated"]["load_cells"] == pytest.approx(
        ra["alignment"]["interpolated"]["load_cells"], rel=0.01)
    assert ea == eb == []


def test_a_recording_split_in_time_reads_as_one(slipped, monkeypatch):
    sc, truth, _, d = slipped
    rec = write_log(d / "split", sc, replace(THREE, split="time", files=3), truth)
    assert len(list(rec.glob("recording-*.csv"))) == 3
    (a, ra, _), (b, rb, _) = _conditioned_pair(rec, monkeypatch)
    assert rb["read"]["rows"] == ra["alignment"]["rows_before"]
    _same_rows(a, b)


def test_decimating_while_reading_keeps_the_answer_of_the_full_fit(slipped, monkeypatch):
    # the full fit: every aligned row (no condensing at this length); then read in blocks,
    # decimated while reading to a third and condensed to a sixth of the aligned rows
    full = diagnose(slipped[2]).report
    rows = full["mismatch"]["samples"]["rows"]
    assert full["mismatch"]["streams"]["condensed"] is None
    monkeypatch.setattr(ch, "CHUNKED_MIN_BYTES", 0)
    monkeypatch.setattr(ch, "BLOCK_BYTES", BLOCK)
    monkeypatch.setattr(ch, "PRE_BUDGET", rows // 3)
    monkeypatch.setattr(streams, "ROW_BUDGET", rows // 6)
    monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)
    small = diagnose(slipped[2]).report
    cd = small["mismatch"]["streams"]["condensed"]
    assert cd["rows_before"] == rows and cd["rows_after"] < rows // 4
    assert [e["name"] for e in full["effects"]] == ["cable_length_offset"]
    assert [e["name"] for e in small["effects"]] == ["cable_length_offset"]
    assert bool(small["unexplained"]) == bool(full["unexplained"]) is False
    for a, b in zip(small["effects"], full["effects"], strict=True):
        for k, v in b["params"].items():
            assert a["params"][k] == pytest.approx(v, abs=2 * np.hypot(a["stderr"][k],
                                                                       b["stderr"][k]))


def test_the_long_log_writer_writes_streams_window_by_window(slipped):
    # write_long_log (the 8-hour benchmark's writer) in windows of 7,000 rows, split in
    # time: one time column rising through the windows and files, the streams at their
    # rates, empty fields, no controller columns
    from bench.logger_sim import write_long_log
    from bench.recording import read_recording

    sc, truth, _, d = slipped
    rec = write_long_log(d / "long", sc, replace(THREE, split="time", files=2), truth,
                         window_rows=7_000)
    assert sorted(p.name for p in rec.glob("*.csv")) == ["recording-001.csv",
                                                         "recording-002.csv"]
    text = (rec / "recording-001.csv").read_text().splitlines()
    assert ",," in text[2] and not any(h.endswith("_des") for h in text[0].split(","))
    r = read_recording(rec)
    assert np.all(np.diff(r.t) > 0)
    assert r.n_samples == pytest.approx((truth.t[-1] - truth.t[0]) * 250.0, abs=2)
    st = streams.describe(r)
    for name, hz in (("encoders", 250.0), ("load_cells", 50.0), ("tracker", 25.0)):
        assert st[name].rate_hz == pytest.approx(hz, rel=0.02)
    assert "controller" not in st
    # the truth of a dwell is kept as its two ends: the same readings between them
    assert len(truth.t) < 0.95 * (truth.t[-1] - truth.t[0]) * PHYSICS_HZ


def test_the_long_log_writer_drops_what_the_logger_s_dropouts_say(slipped):
    # encoders (every row) and tracker dropouts: no sample inside them, samples all around
    from bench.logger_sim import dropout_intervals, write_long_log
    from bench.recording import read_recording

    sc, truth, _, d = slipped
    spec = replace(THREE, dropouts=(("encoders", 2.0, 0.3, 0.6), ("tracker", 2.0, 1.0, 2.0)))
    r = read_recording(write_long_log(d / "drops", sc, spec, truth, window_rows=7_000))
    iv = dropout_intervals(spec, sc.seed, r.t[0], r.t[-1])
    found = streams.describe(r)
    for name, g in (("encoders", r.l_meas), ("tracker", r.pose_meas)):
        assert len(iv[name]) >= 2
        has = np.isfinite(g).any(axis=1)
        inside = np.zeros(r.n_samples, dtype=bool)
        for a, b in iv[name]:
            inside |= (r.t >= a) & (r.t <= b)
        assert inside.any() and not has[inside].any()
        assert has[~inside].mean() > (0.99 if name == "encoders" else 0.09)
        assert len(found[name].gaps) >= 1
    assert found["load_cells"].gaps == []


def test_a_logger_that_pauses_reads_as_runs_whole_or_in_blocks(slipped, monkeypatch):
    # the logger wrote no row for 5 s, 2 s and 0.5 s: three pauses, four runs, the same whole
    # or in blocks (a pause across a block's edge too); no stream lost samples of its own
    _, _, rec, d = slipped
    paused = d / "paused"
    shutil.copytree(rec, paused)
    lines = (paused / "recording.csv").read_text().splitlines()
    t = np.array([float(ln.split(",", 1)[0]) for ln in lines[1:]])
    cut = ((t > 40) & (t < 45)) | ((t > 90) & (t < 92)) | ((t > 150) & (t < 150.5))
    keep = [ln for ln, c in zip(lines[1:], cut, strict=True) if not c]
    (paused / "recording.csv").write_text("\n".join([lines[0], *keep]) + "\n")
    (_, ra, _), (_, rb, _) = _conditioned_pair(paused, monkeypatch)
    assert rb["read"]["blocks"] > 10
    assert ra["runs"] == rb["runs"] and ra["runs"]["runs"] == 4
    assert ra["runs"]["pause_total_s"] == pytest.approx(7.5, abs=0.05)
    assert rb["streams"] == ra["streams"]
    assert all(s["gaps"] == 0 for s in ra["streams"].values())
