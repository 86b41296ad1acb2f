"""Recordings written by another hand, from docs/formats/recording*.md alone
(:mod:`tests.outsider`: own statics on the shipped CoGiRo-class robot, own logger habits),
read and diagnosed by the product: every habit the docs allow is accepted and read as the
plain file is; bad files are refused naming file, line and column; a concealed cable length
offset or a moved exit point is named with the truth inside its interval; a clean recording
names nothing."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from bench import chunked, streams
from bench.chunked import read_conditioned
from bench.diagnosis.report import diagnose
from bench.recording import RecordingError, _read_header, read_recording
from tests.outsider.cases import make_case
from tests.outsider.logger import Habits

SMALL = {"targets": 4, "passes": 2, "dwell_s": 3.0}
OFFSET = {"42": -0.003}


def _case(tmp_path_factory, name: str, habits: Habits, **kw) -> Path:
    return make_case(tmp_path_factory.mktemp(name) / "rec", habits, seed=11, **(SMALL | kw))


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    return _case(tmp_path_factory, "plain", Habits())


@pytest.fixture(scope="module")
def slipped(tmp_path_factory) -> Path:
    return _case(tmp_path_factory, "slip", Habits(), length_offset=OFFSET)


def _lines(p: Path) -> list[str]:
    return p.read_text().split("\n")


def _edit(src: Path, dst: Path, edit) -> Path:
    """A copy of the recording ``src`` whose samples file's lines went through ``edit``."""
    shutil.copytree(src, dst)
    f = dst / "samples.csv"
    f.write_bytes("\n".join(edit(_lines(f))).encode())
    return dst


def _set(lines: list[str], i: int, column: str, value: str) -> list[str]:
    fields = lines[i].split(",")
    fields[lines[0].split(",").index(column)] = value
    lines[i] = ",".join(fields)
    return lines


@pytest.fixture(params=["rows", "columnar"])
def reader(request, monkeypatch):
    """Both whole-file readers: row by row (small files) and the columnar one."""
    if request.param == "columnar":
        monkeypatch.setattr(streams, "FAST_MIN_BYTES", 0)
    return request.param


def _same(a, b) -> None:
    for g in ("t", "pose_meas", "l_meas", "tau"):
        np.testing.assert_array_equal(getattr(a, g), getattr(b, g), err_msg=g)


# ----- habits the docs allow: read as the plain file -------------------------------------

@pytest.mark.parametrize("habit", ["bom", "text_column", "crlf", "nan_tokens", "spaces"])
def test_an_allowed_habit_reads_as_the_plain_file(plain, tmp_path, reader, habit):
    edits = {
        "bom": lambda ls: ["\ufeff" + ls[0], *ls[1:]],
        "text_column": lambda ls: [ls[0] + ",operator"] + [x + ",anna b." if x else x
                                                           for x in ls[1:]],
        "crlf": lambda ls: ["\r\n".join(ls)],
        "nan_tokens": lambda ls: [ls[0]] + [",".join(f or ("NaN" if k % 2 else "nan")
                                                     for f in x.split(",")) if x else x
                                            for k, x in enumerate(ls[1:])],
        "spaces": lambda ls: [x.replace(",", ", ") for x in ls],
    }
    _same(read_recording(_edit(plain, tmp_path / "r", edits[habit])), read_recording(plain))


def test_split_in_time_with_its_own_column_orders_reads_as_one_file(tmp_path):
    one = make_case(tmp_path / "one", Habits(), seed=12, targets=2, passes=1)
    parts = make_case(tmp_path / "parts", Habits(split="time", parts=3, shuffle=True), seed=12,
                      targets=2, passes=1)
    _same(read_recording(parts), read_recording(one))


def test_sparse_commanded_poses_give_no_numpy_warning(tmp_path):
    """Controller columns on every 4th row only (empty elsewhere): the initialisation rows
    are found without numpy's "All-NaN slice encountered"."""
    rec_dir = make_case(tmp_path / "r", Habits(controller_hz=50.0), seed=13, targets=2, passes=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(rec_dir)
    assert 0 < len(rec.init_rows) < rec.n_samples
    assert rec.t[rec.init_rows[-1]] - rec.t[0] < 6.1  # the 6 s initialisation dwell


# ----- bad files: refused, naming file, line and column ----------------------------------

BAD = {
    "not a number": (lambda ls: _set(ls, 1000, "tau_11", "12.3.4"),
                     r"samples\.csv:1001: column \d+ 'tau_11': not a number: '12\.3\.4'"),
    "time going back": (lambda ls: _set(ls, 2000, "t", "1000.0"),
                        r"samples\.csv:2001: column \d+ 't': time goes back from 12\d\d\.\d+ s "
                        r"\(line 2000\) to 1000 s"),
    "no time column": (lambda ls: [ls[0].replace("t,", "time,", 1), *ls[1:]],
                       r"samples\.csv:1: column 't' \(time\) is missing from the header row "
                       r"\('time,l_meas_11"),
    "semicolons": (lambda ls: [x.replace(",", ";") for x in ls],
                   r"samples\.csv:1: column 't' \(time\) is missing from the header row "
                   r"\('t;l_meas_11;.*separated by ';'; the format separates them by ','"),
    "comment line": (lambda ls: ["# logger v2.1", *ls],
                     r"samples\.csv:1: the first line must be the header row .* comment"),
    "torn last line": (lambda ls: [*ls[:-2], ls[-2][:40]],
                       r"samples\.csv:\d+: \d+ fields, the header has 23: the last line is cut "
                       r"short and has no line end"),
    "lengths in mm": (lambda ls: [ls[0]] + [",".join(
        f"{float(f) * 1000:.3f}" if k in range(1, 9) and f else f
        for k, f in enumerate(x.split(","))) if x else x for x in ls[1:]],
        r"samples\.csv: lengths: \d+ of \d+ values are impossible \(length outside 0 \.\. "
        r"\d+ m; e\.g\. line 2\)"),
}


@pytest.mark.parametrize("bad", list(BAD))
def test_a_bad_file_is_refused_naming_its_line(plain, tmp_path, reader, bad):
    edit, message = BAD[bad]
    with pytest.raises(RecordingError, match=message):
        read_conditioned(_edit(plain, tmp_path / "r", edit))


def test_a_torn_last_line_is_named_in_blocks(plain, tmp_path, monkeypatch):
    monkeypatch.setattr(chunked, "CHUNKED_MIN_BYTES", 0)
    monkeypatch.setattr(chunked, "BLOCK_BYTES", 1 << 16)
    rec = _edit(plain, tmp_path / "r", lambda ls: [*ls[:-2], ls[-2][:40]])
    last = len(_lines(rec / "samples.csv"))
    with pytest.raises(RecordingError, match=rf"samples\.csv:{last}: \d+ fields, the header has "
                                             rf"23: the last line is cut short"):
        read_conditioned(rec)


def test_time_going_back_across_blocks_names_the_line(plain, tmp_path, monkeypatch):
    """A long file read in blocks: the time going back at a block's first row."""
    monkeypatch.setattr(chunked, "CHUNKED_MIN_BYTES", 0)
    monkeypatch.setattr(chunked, "BLOCK_BYTES", 1 << 16)
    rec = _edit(plain, tmp_path / "r", lambda ls: ls)
    size = len((rec / "samples.csv").read_bytes().split(b"\n")[0]) + 1
    lines = _lines(rec / "samples.csv")
    at = next(k for k in range(1, len(lines))  # the first line of the second block
              if size + sum(len(x) + 1 for x in lines[1:k + 1]) > 1 << 16)
    (rec / "samples.csv").write_text("\n".join(_set(lines, at, "t", "1000.0")))
    with pytest.raises(RecordingError, match=rf"samples\.csv:{at + 1}: column 1 't': time goes "
                                             rf"back from .* \(line {at}\) to 1000 s"):
        read_conditioned(rec)


# ----- the diagnosis ----------------------------------------------------------------------

def test_noisy_encoders_keep_their_dwells_and_a_clean_recording_names_nothing(plain):
    """Encoder noise of 5 um (a 20 um spread over a dwell) must not make dwells moves."""
    rep = diagnose(plain).report
    assert rep["mismatch"]["samples"]["dwells_available"] == 1 + 4 * 2
    assert rep["mismatch"]["noise"]["source"] == "replicate visits"
    assert rep["effects"] == [] and rep["unexplained"] is None


def _named_offset(rep: dict) -> None:
    assert [e["name"] for e in rep["effects"]] == ["cable_length_offset"], rep["effects"]
    eff = rep["effects"][0]
    assert set(eff["params"]) == {"dl_42"}
    lo, hi = eff["interval95"]["dl_42"]
    assert lo <= OFFSET["42"] <= hi and hi - lo < 1e-3


def test_a_slip_is_named_with_the_truth_in_its_interval(slipped):
    _named_offset(diagnose(slipped).report)


@pytest.mark.slow
@pytest.mark.parametrize("habits", [
    Habits(layout="sample", encoders_hz=250, load_cells_hz=50, tracker_hz=25),
    Habits(shuffle=True, extra=True, empty=("nan", "NaN", ""), crlf=True, t0_s=86400.25),
    Habits(split="sensor", layout="sample", crlf=True, empty=("nan",)),
    Habits(split="time", parts=3, shuffle=True, controller_hz=50.0),
], ids=["one-row-per-sample", "mixed-habits", "split-by-sensor", "split-in-time"])
def test_a_slip_is_named_whatever_the_loggers_habits(tmp_path, habits):
    _named_offset(diagnose(make_case(tmp_path / "r", habits, seed=21, length_offset=OFFSET,
                                     **SMALL)).report)


@pytest.mark.slow
def test_a_moved_exit_point_is_named_with_the_truth_in_its_intervals(tmp_path):
    moved = (0.03, -0.02, 0.015)
    rep = diagnose(make_case(tmp_path / "r", Habits(extra=True, shuffle=True), seed=3,
                             exit_moved=("32", moved), **SMALL)).report
    assert [e["name"] for e in rep["effects"]] == ["exit_point_offset"], rep["effects"]
    eff = rep["effects"][0]
    for ax, v in zip("xyz", moved, strict=True):
        lo, hi = eff["interval95"][f"d{ax}_32"]
        assert lo <= v <= hi
    assert rep["unexplained"] is None


@pytest.mark.slow
@pytest.mark.cases  # one whole case recorded and diagnosed (make test-cases)
def test_a_three_rate_log_of_300000_rows_names_the_slip(tmp_path):
    """20 minutes at 250 Hz (encoders), 50 Hz (load cells), 25 Hz (tracker), one file."""
    rec = make_case(tmp_path / "r", Habits(encoders_hz=250.0, load_cells_hz=50.0,
                                           tracker_hz=25.0, empty=("", "nan")),
                    seed=31, targets=30, passes=2, dwell_s=8.0, length_offset=OFFSET)
    rows = sum(len(_lines(rec / "samples.csv")) for _ in [0]) - 2
    assert rows >= 300_000
    _named_offset(diagnose(rec).report)


def test_load_cells_slower_than_the_tracker_give_no_numpy_warning(tmp_path):
    """One row per sample, load cells (10 Hz) the slowest stream: aligning the others to
    them estimates each column's noise without numpy's "All-NaN slice encountered"."""
    rec_dir = make_case(tmp_path / "r", Habits(layout="sample", encoders_hz=100.0,
                                               load_cells_hz=10.0, tracker_hz=50.0),
                        seed=5, targets=2, passes=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec, report, _ = read_conditioned(rec_dir)
    assert report["alignment"]["reference"] == "load_cells"
    assert np.isfinite(rec.pose_meas).all(axis=1).mean() > 0.9


@pytest.mark.parametrize("habit", ["bom", "text_column", "crlf", "nan_tokens"])
def test_an_allowed_habit_reads_as_the_plain_file_in_blocks(plain, tmp_path, habit):
    """The block reader of long files (blocks of 64 kB here) takes the habits as the
    whole-file readers do."""
    edits = {
        "bom": lambda ls: ["\ufeff" + ls[0], *ls[1:]],
        "text_column": lambda ls: [ls[0] + ",operator"] + [x + ",anna b." if x else x
                                                           for x in ls[1:]],
        "crlf": lambda ls: ["\r\n".join(ls)],
        "nan_tokens": lambda ls: [ls[0]] + [",".join(f or "NaN" for f in x.split(","))
                                            if x else x for x in ls[1:]],
    }
    rec = _edit(plain, tmp_path / "r", edits[habit])
    whole = read_recording(plain)

    def blocks(d: Path) -> dict:
        p = d / "samples.csv"
        header = _read_header(p, whole.robot)
        got = [cols for cols, _, _ in chunked.iter_blocks(p, header, block_bytes=1 << 16)]
        return {k: np.concatenate([g[k] for g in got]) for k in ("t", "l_meas_11", "tau_11",
                                                                  "x_meas")}

    a, b = blocks(rec), blocks(plain)
    assert len(a["t"]) == whole.n_samples
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_a_cables_direction_into_a_dwell_is_its_move_not_its_noise(plain):
    """The direction of each cable's last move before a dwell (hysteresis is tested by it):
    5 um encoder noise in the dwell's first rows must not set it."""
    from bench.diagnosis.samples import prepare

    rec, _, _ = read_conditioned(plain)
    s = prepare(rec)
    dwell = np.flatnonzero((s.kind == 0) & ~s.is_init)
    dwell = dwell[np.argsort(s.t[dwell])]
    before = np.concatenate([s.l_meas[s.is_init & (s.kind == 0)][:1], s.l_meas[dwell[:-1]]])
    moved = s.l_meas[dwell] - before
    big = np.abs(moved) > 1e-3
    assert big.sum() > 40
    assert np.mean(s.direction[dwell][big] == np.sign(moved[big])) > 0.95
