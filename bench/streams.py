"""A recording as the sensor streams it holds: a columnar reader, rates and gaps, alignment.

- :func:`read_columns` reads a ``recording.csv`` with polars' columnar CSV reader (millions
  of rows per second); on anything it cannot take as is it returns None and the caller's
  row-by-row reader gives the message that names the line and column.
- :func:`describe` finds the streams of a :class:`~bench.recording.Recording`: for each
  sensor group (encoders ``l_meas``, load cells ``tau``, tracker ``pose_meas`` and
  ``exit_meas``, controller ``pose_des``/``l_cmd``) the rows where it has a value (a row
  where the group is NaN/empty is "no sample" of that stream), its rate [Hz], time-stamp
  jitter [s] and gaps; the report names a stream's gaps only where it lost samples while
  rows were written (:meth:`Stream.lost`), the recording's pauses without rows (a
  recording taken at dwells) being its runs (:func:`pauses`).
- :func:`align` brings streams at different rates to common instants without inventing
  samples: the instants of the slowest measuring stream; a faster stream is taken from the
  same row when it has a sample there, else interpolated linearly between its two
  neighbouring samples where the motion allows it (the interpolation error, estimated from
  the stream's second difference, below the stream's own noise or a floor); otherwise the
  value stays "no sample". Rows of a single-rate recording are returned unchanged.
- :func:`condense` keeps the cost growing with the information: continuous rows beyond a
  budget are decimated, every row kept around events (reversals, jumps, starts and stops).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

#: sensor streams -> the Recording's column groups that hold them
GROUPS: dict[str, tuple[str, ...]] = {
    "encoders": ("l_meas",),
    "load_cells": ("tau",),
    "tracker": ("pose_meas", "exit_meas"),
    "controller": ("pose_des", "l_cmd"),
}
#: streams that measure (the controller's columns say what was aimed at)
MEASURED = ("encoders", "load_cells", "tracker")
#: an interval longer than this many median periods is a gap of the stream
GAP_PERIODS = 3.0
#: a stream is slower than the rows when its median period exceeds the rows' by this factor
SLOWER = 1.5
#: column groups that are one measurement per row (the tracker's pose fix): interpolated
#: whole or refused whole, never some axes of a fix without the others
WHOLE_GROUPS = frozenset({"pose_meas"})
#: an interpolated value is kept only while its estimated error stays below the stream's
#: noise or this floor (lengths and positions [m], tensions [N], angles [rad])
INTERP_FLOOR = {"l_meas": 5e-6, "tau": 0.2, "pose_meas": 5e-6, "exit_meas": 5e-6,
                "pose_des": np.inf, "l_cmd": np.inf}
#: at most this many gaps are listed per stream in the report
GAPS_LISTED = 5
#: :func:`condense` keeps at most about this many rows of continuous data
ROW_BUDGET = 100_000
#: rows kept on each side of an event by :func:`condense`
EVENT_ROWS = 3

NULLS = ["", "nan", "NaN", "NAN", "Nan"]
#: the documented numeric columns (docs/formats/recording.md): any other column but
#: ``state`` is the lab's own, kept and ignored, and may hold text
DOCUMENTED = re.compile(r"^(t|(x|y|z|roll|pitch|yaw)_(des|meas)"
                        r"|(l_cmd|l_meas|tau|ax_meas|ay_meas|az_meas|drive_state)_\w+)$")


def loose_columns(header: list[str]) -> set[str]:
    """The columns of ``header`` the format does not define (other than ``state``): read as
    numbers where they are, a field that is not one is no value (NaN), never an error."""
    return {h for h in header if h != "state" and not DOCUMENTED.match(h)}


def time_goes_back(t: np.ndarray) -> int | None:
    """Index of the first row whose time is earlier than the row before it, or None (equal
    times are in order)."""
    back = np.flatnonzero(np.diff(t) < 0)
    return int(back[0]) + 1 if len(back) else None


def time_back_message(header: list[str], t_from: float, line_from: int, t_to: float) -> str:
    """What is wrong with a row whose time ``t_to`` [s] is earlier than ``t_from`` [s] of the
    row at line ``line_from`` (the caller puts the file and the row's line before it)."""
    return (f"column {header.index('t') + 1} 't': time goes back from {t_from:.6g} s (line "
            f"{line_from}) to {t_to:.6g} s: the rows of a file must be in time order (equal "
            f"times allowed)")


#: the process that first used polars: its thread pool lives there only, and a process
#: forked from it (the project's process pools fork) deadlocks in polars, so such a child
#: reads row by row (polars' own warning on fork says the same)
_POLARS_PID: int | None = None
#: files smaller than this [bytes] are read row by row: the columnar reader pays off on
#: long logs, and a process that never starts polars' thread pool forks safely
FAST_MIN_BYTES = 8 * 1024 * 1024


def _polars_usable() -> bool:
    """Whether polars may run in this process: not in a child forked after the parent
    started polars' thread pool."""
    global _POLARS_PID
    import os

    if _POLARS_PID is None:
        _POLARS_PID = os.getpid()
    return _POLARS_PID == os.getpid()


# ----- reading ---------------------------------------------------------------------------

def read_columns(p: Path, header: list[str]) -> tuple[dict[str, np.ndarray],
                                                     list[str] | None] | None:
    """The columns of the CSV file ``p`` whose (stripped, validated) header is ``header``:
    name -> (N,) float64 (NaN = no value) and the ``state`` column as strings (or None).
    None when the file holds anything this fast path does not take exactly as the
    row-by-row reader would (a field that is not a plain number, an infinite value, a
    missing time, ...), or in a process forked after this one's parent used polars: the
    caller then reads it row by row, naming the line."""
    try:
        if p.stat().st_size < FAST_MIN_BYTES:
            return None
    except OSError:
        return None
    if not _polars_usable():
        return None
    import polars as pl

    loose = loose_columns(header)
    schema = {h: (pl.String if h == "state" or h in loose else pl.Float64)
              for h in header}
    try:
        df = pl.read_csv(p, has_header=False, skip_rows=1, new_columns=header, schema=schema,
                         null_values=NULLS,
                         raise_if_empty=False)
    except (pl.exceptions.PolarsError, OSError, ValueError):
        return None
    if df.height == 0 or not _whole_rows(p, df.height, len(header)):
        return None
    return _frame_columns(df, header)


def parse_block(data: bytes, header: list[str]) -> tuple[dict[str, np.ndarray],
                                                         list[str] | None] | None:
    """The columns (as :func:`read_columns`) of ``data``, whole data lines of a samples file
    whose header is ``header``; None where :func:`read_columns` gives None (the caller then
    reads the block row by row, naming the line). Called only where polars may run."""
    import io

    import polars as pl

    loose = loose_columns(header)
    schema = {h: (pl.String if h == "state" or h in loose else pl.Float64)
              for h in header}
    try:
        df = pl.read_csv(io.BytesIO(data), has_header=False, new_columns=header,
                         schema=schema, null_values=NULLS, raise_if_empty=False)
    except (pl.exceptions.PolarsError, OSError, ValueError):
        return None
    if df.height == 0 or data.count(b",") != df.height * (len(header) - 1):
        return None
    return _frame_columns(df, header)


def _frame_columns(df, header: list[str]) -> tuple[dict[str, np.ndarray],
                                                   list[str] | None] | None:
    """A polars frame's columns as float64 arrays and the states as strings; None on an
    infinite value, a missing time or a time going back (the row-by-row reader names them).
    The lab's own columns (:func:`loose_columns`) are numbers where they are, else NaN."""
    import polars as pl

    cols: dict[str, np.ndarray] = {}
    states = None
    loose = loose_columns(header)
    for name in header:
        c = df.get_column(name)
        if name == "state":
            states = c.fill_null("").str.strip_chars().to_list()
            continue
        if name in loose:
            cols[name] = c.str.strip_chars().cast(pl.Float64, strict=False).fill_null(
                np.nan).to_numpy().astype(np.float64, copy=False)
            continue
        v = c.to_numpy().astype(np.float64, copy=False)
        if np.isinf(v).any():
            return None
        cols[name] = v
    if np.isnan(cols["t"]).any() or time_goes_back(cols["t"]) is not None:
        return None
    return cols, states


def _whole_rows(p: Path, rows: int, ncols: int) -> bool:
    """Whether every one of the ``rows`` data rows of ``p`` has ``ncols`` fields: the file
    holds exactly rows x (ncols - 1) commas after its header (a short row, which a
    columnar reader fills with nulls, or a quoted comma fails this and the file is read
    row by row)."""
    with p.open("rb") as f:
        f.readline()  # the header
        commas = 0
        while chunk := f.read(1 << 26):  # 64 MB at a time
            commas += chunk.count(b",")
    return commas == rows * (ncols - 1)


# ----- streams ---------------------------------------------------------------------------

@dataclass
class Stream:
    """One sensor stream of a recording: ``rows`` where it has a sample; median ``period_s``,
    ``rate_hz``; ``jitter_s`` the robust spread of its intervals about the median (time-stamp
    jitter); ``gaps`` [(t_start, duration_s)] intervals beyond GAP_PERIODS periods."""

    name: str
    rows: np.ndarray
    period_s: float
    jitter_s: float
    gaps: list[tuple[float, float]] = field(default_factory=list)

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period_s if self.period_s > 0 else 0.0

    def report(self, rows_total: int, paused: np.ndarray | None = None) -> dict:
        """The stream as the report lists it. ``paused``: the recording's pauses
        (:func:`pauses`, (P, 2) [s]); the gaps listed are the stream's :meth:`lost` ones."""
        gaps = sorted(self.lost(paused), key=lambda g: -g[1])
        return {"samples": int(len(self.rows)), "rows_share": len(self.rows) / max(rows_total, 1),
                "rate_hz": _r(self.rate_hz), "period_s": _r(self.period_s),
                "jitter_s": _r(self.jitter_s), "gaps": len(gaps),
                "gap_total_s": _r(sum(g[1] for g in gaps)),
                "longest_gaps": [{"t_s": _r(a), "duration_s": _r(b)}
                                 for a, b in gaps[:GAPS_LISTED]]}

    def lost(self, paused: np.ndarray | None = None) -> list[tuple[float, float]]:
        """The gaps where samples were lost: [(t_start [s], duration [s])] of the stream's
        silence while the logger wrote rows: each of the recording's pauses inside the gap
        (``paused``, (P, 2) [start, end] [s], each between two rows: inside a gap or outside
        it) counts as one period of the stream, as if its run had gone on; a gap is lost
        when that is longer than GAP_PERIODS of the stream's periods, as in a recording
        without pauses (a dwell recording's stream, silent from one dwell to the next with
        the rows, loses nothing)."""
        if paused is None or not len(paused) or not self.gaps:
            return list(self.gaps)
        cum = np.concatenate([[0.0], np.cumsum(paused[:, 1] - paused[:, 0])])
        out = []
        for a, d in self.gaps:
            i = np.searchsorted(paused[:, 0], a - 1e-9)
            j = np.searchsorted(paused[:, 1], a + d + 1e-9, side="right")
            left = d - (cum[j] - cum[i]) + (j - i) * self.period_s if j > i else d
            if left > GAP_PERIODS * self.period_s:
                out.append((a, float(left)))
        return out


def pauses(t: np.ndarray, period_s: float | None = None) -> np.ndarray:
    """(P, 2) [start, end] [s]: the intervals between consecutive rows of times ``t`` [s]
    longer than GAP_PERIODS row periods (``period_s``, by default :func:`row_period`): the
    logger wrote no row at all (between the dwells of a recording taken at dwells, or a
    logger that stopped). The stretches between them are the recording's runs."""
    if len(t) < 2:
        return np.zeros((0, 2))
    k = np.flatnonzero(long_steps(np.diff(t), period_s))
    return np.column_stack([t[k], t[k + 1]])


def long_steps(dt: np.ndarray, period_s: float | None = None) -> np.ndarray:
    """Which steps ``dt`` [s] between consecutive rows are longer than GAP_PERIODS periods
    (``period_s``, by default :func:`median_step` of ``dt``: none where no step is
    positive)."""
    period = median_step(dt) if period_s is None else period_s
    return dt > GAP_PERIODS * max(period, 1e-12)


def row_period(t: np.ndarray) -> float:
    """The rows' median interval [s] between distinct instants ``t`` [s]: files split by
    sensor merge into rows of equal times (one per stream), whose zero intervals are not
    the logger's period."""
    return median_step(np.diff(t))


def median_step(dt: np.ndarray) -> float:
    """The median of the positive steps ``dt`` [s] (0 when there are none)."""
    dt = dt[dt > 0]
    return float(np.median(dt)) if len(dt) else 0.0


def runs_report(paused: np.ndarray) -> dict:
    """The recording's runs as the report lists them: how many, and the pauses between."""
    return {"runs": int(len(paused) + 1), "pauses": int(len(paused)),
            "pause_total_s": _r(float(np.sum(paused[:, 1] - paused[:, 0])))}


def _r(x: float) -> float:
    return float(f"{x:.6g}")


def _group_rows(rec, name: str) -> np.ndarray:
    """(N,) bool: rows where the stream ``name`` has a value in any of its columns."""
    has = np.zeros(rec.n_samples, dtype=bool)
    for g in GROUPS[name]:
        a = getattr(rec, g)
        has |= np.isfinite(a.reshape(len(a), -1)).any(axis=1)
    return has


def _stream(name: str, t: np.ndarray, rows: np.ndarray) -> Stream:
    ts = t[rows]
    dt = np.diff(ts)
    if not len(dt):
        return Stream(name, rows, 0.0, 0.0)
    med = float(np.median(dt))
    jit = float(1.4826 * np.median(np.abs(dt - med))) if len(dt) > 2 else 0.0
    big = np.flatnonzero(dt > GAP_PERIODS * max(med, 1e-12))
    gaps = [(float(ts[k]), float(dt[k])) for k in big]
    return Stream(name, rows, med, jit, gaps)


def describe(rec) -> dict[str, Stream]:
    """The streams a recording holds (those with at least one sample), by name."""
    out = {}
    for name in GROUPS:
        rows = np.flatnonzero(_group_rows(rec, name))
        if len(rows):
            out[name] = _stream(name, rec.t, rows)
    return out


def multi_rate(rec, streams: dict[str, Stream]) -> bool:
    """Whether some measuring stream is slower than the rows (samples in some rows only, at
    a longer period): rows are then no common instants of the sensors."""
    rows_period = float(np.median(np.diff(rec.t))) if rec.n_samples > 1 else 0.0
    for name in MEASURED:
        s = streams.get(name)
        if s is not None and len(s.rows) < rec.n_samples \
                and s.period_s > SLOWER * max(rows_period, 1e-12):
            return True
    return False


# ----- alignment ---------------------------------------------------------------------------

@dataclass
class Alignment:
    """What :func:`align` did: ``reference`` the stream whose instants the rows are now;
    per other stream the samples taken from the same row, interpolated, and refused (the
    motion too fast for the interpolation, or a gap); ``interp_rms`` the estimated RMS
    interpolation error per column group (counted in the noise: the diagnosis estimates
    the noise from the aligned rows)."""

    reference: str
    rows_before: int
    rows_after: int
    same_row: dict[str, int] = field(default_factory=dict)
    interpolated: dict[str, int] = field(default_factory=dict)
    refused: dict[str, int] = field(default_factory=dict)
    interp_rms: dict[str, float] = field(default_factory=dict)

    def report(self) -> dict:
        return {"reference": self.reference, "rows_before": self.rows_before,
                "rows_after": self.rows_after, "same_row": self.same_row,
                "interpolated": self.interpolated, "refused": self.refused,
                "interpolation_rms": {k: _r(v) for k, v in self.interp_rms.items()}}


def _slowest(streams: dict[str, Stream]) -> Stream:
    """The measuring stream with the longest period (the instants the others come to)."""
    return max((streams[n] for n in MEASURED if n in streams), key=lambda s: s.period_s)


def _fill_gaps(t: np.ndarray, slow: Stream, others: np.ndarray, t0: float | None = None
               ) -> np.ndarray:
    """Rows of ``others`` inside the slow stream's gaps (and before its first or after its
    last sample), one per slow period counted from ``t0`` [s] (default the first row's
    time): the instants where only faster streams measured."""
    if not len(others):
        return others
    ts = t[slow.rows]
    to = t[others]
    k = np.searchsorted(ts, to)
    prev = np.where(k > 0, ts[np.maximum(k - 1, 0)], -np.inf)
    nxt = np.where(k < len(ts), ts[np.minimum(k, len(ts) - 1)], np.inf)
    inside = np.minimum(to - prev, nxt - to) > 1.5 * slow.period_s
    cand = others[inside]
    if not len(cand):
        return cand
    bins = np.floor((t[cand] - (t[0] if t0 is None else t0)) / slow.period_s).astype(np.int64)
    _, first = np.unique(bins, return_index=True)
    return cand[first]


def _interp(t_src: np.ndarray, v_src: np.ndarray, t_dst: np.ndarray, max_dt: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Values (M, d) of samples ``v_src`` (K, d) at times ``t_src`` interpolated linearly to
    ``t_dst`` (M,), NaN where the neighbouring samples are farther apart than ``max_dt``;
    and the estimated interpolation error (M, d): (t-t_a)(t_b-t)/2 times the larger second
    derivative of the samples on either side."""
    K = len(t_src)
    M = len(t_dst)
    d = v_src.shape[1]
    out = np.full((M, d), np.nan)
    err = np.full((M, d), np.nan)
    if K < 2:
        return out, err
    b = np.clip(np.searchsorted(t_src, t_dst), 1, K - 1)
    a = b - 1
    ta, tb = t_src[a], t_src[b]
    h = tb - ta
    ok = (h > 0) & (h <= max_dt) & (t_dst >= ta) & (t_dst <= tb)
    w = np.where(ok, (t_dst - ta) / np.where(h > 0, h, 1.0), 0.0)[:, None]
    out = np.where(ok[:, None], (1 - w) * v_src[a] + w * v_src[b], np.nan)
    # second derivative from the samples around: (a-1, a, b) and (a, b, b+1)
    acc = np.zeros((M, d))
    for lo, mid, hi in ((a - 1, a, b), (a, b, b + 1)):
        good = (lo >= 0) & (hi < K)
        lo_, hi_ = np.clip(lo, 0, K - 1), np.clip(hi, 0, K - 1)
        h1 = t_src[mid] - t_src[lo_]
        h2 = t_src[hi_] - t_src[mid]
        with np.errstate(divide="ignore", invalid="ignore"):
            dd = 2 * ((v_src[hi_] - v_src[mid]) / h2[:, None]
                      - (v_src[mid] - v_src[lo_]) / h1[:, None]) / (h1 + h2)[:, None]
        dd = np.where(good[:, None] & np.isfinite(dd), np.abs(dd), 0.0)
        acc = np.maximum(acc, dd)
    err = np.where(ok[:, None], 0.5 * (t_dst - ta)[:, None] * (tb - t_dst)[:, None] * acc,
                   np.nan)
    return out, err


def _noise(v: np.ndarray) -> np.ndarray:
    """Per column white noise of samples (K, d): robust second differences / sqrt(6)."""
    if len(v) < 5:
        return np.zeros(v.shape[1])
    d2 = np.abs(v[2:] - 2 * v[1:-1] + v[:-2])
    out = np.zeros(v.shape[1])
    seen = np.isfinite(d2).any(axis=0)  # (a column without three samples in a row: 0;
    if seen.any():                      # np.nanmedian would warn "All-NaN slice")
        out[seen] = 1.4826 * np.nanmedian(d2[:, seen], axis=0) / np.sqrt(6.0)
    return out


def _align_group(rec, g: str, stream: Stream, ref: np.ndarray, al: Alignment) -> np.ndarray:
    """The column group ``g`` of stream ``stream`` at the reference rows ``ref``."""
    arr = getattr(rec, g)
    shape = arr.shape[1:]
    flat = arr.reshape(len(arr), -1)
    out = flat[ref].copy()
    have = np.isfinite(out).any(axis=1)
    al.same_row[stream.name] = al.same_row.get(stream.name, 0) + int(have.sum())
    need = np.flatnonzero(~have)
    if len(need) and len(stream.rows) >= 2:
        src = stream.rows
        vals, err = _interp(rec.t[src], flat[src], rec.t[ref[need]],
                            (GAP_PERIODS - 0.5) * stream.period_s)
        limit = np.maximum(_noise(flat[src]), INTERP_FLOOR[g])
        bad = ~(err <= limit)  # NaN errors (no neighbours) refused as well
        if g in WHOLE_GROUPS:  # one fix: all its axes or none
            bad[:] = bad.any(axis=1, keepdims=True)
        vals[bad] = np.nan
        taken = np.isfinite(vals).any(axis=1)
        out[need] = vals
        al.interpolated[stream.name] = al.interpolated.get(stream.name, 0) + int(taken.sum())
        al.refused[stream.name] = al.refused.get(stream.name, 0) + int((~taken).sum())
        e = err[np.isfinite(vals)]
        if e.size and np.isfinite(INTERP_FLOOR[g]):
            al.interp_rms[g] = float(np.sqrt(np.mean(e ** 2)))
    return out.reshape((len(ref),) + shape)


def align(rec, streams: dict[str, Stream] | None = None, reference: Stream | None = None,
          t0: float | None = None):
    """``rec`` brought to the instants of its slowest measuring stream (see the module
    docstring): a new Recording and the :class:`Alignment`, or ``rec`` and None when its
    streams share the rows already. A part of a long recording read block by block
    (:mod:`bench.chunked`) is brought to the whole recording's ``reference`` stream (its
    name and period; the rows are this part's), gap instants counted from ``t0`` [s]."""
    streams = describe(rec) if streams is None else streams
    if reference is None:
        if not multi_rate(rec, streams):
            return rec, None
        slow = _slowest(streams)
    else:
        rows = streams[reference.name].rows if reference.name in streams \
            else np.zeros(0, dtype=int)
        slow = replace(reference, rows=rows)
    name = slow.name
    others = [streams[n].rows for n in MEASURED if n in streams and n != name]
    others_rows = np.unique(np.concatenate(others)) if others else np.zeros(0, dtype=int)
    ref = np.unique(np.concatenate([slow.rows, _fill_gaps(rec.t, slow, others_rows, t0)]))
    al = Alignment(name, rec.n_samples, len(ref))
    new = {}
    for sname, s in streams.items():
        for g in GROUPS[sname]:
            if sname == name:
                new[g] = getattr(rec, g)[ref]
            elif sname == "controller":
                new[g] = _held(rec, g, s, ref)
            else:
                new[g] = _align_group(rec, g, s, ref, al)
    for g in ("pose_des", "pose_meas", "l_cmd", "l_meas", "tau", "exit_meas"):
        if g not in new:
            new[g] = getattr(rec, g)[ref]
    state = None
    if rec.state is not None:
        st = np.asarray(rec.state, dtype=object)
        filled = _carry(np.array([bool(x) for x in st]))
        state = [str(x) for x in st[filled[ref]]]
    out = replace(rec, t=rec.t[ref], state=state,
                  extra={k: v[ref] for k, v in rec.extra.items()}, **new)
    out.source_rows = ref if getattr(rec, "source_rows", None) is None else rec.source_rows[ref]
    from bench.recording import _init_rows

    out.init_rows = _init_rows(out)
    return out, al


def _carry(has: np.ndarray) -> np.ndarray:
    """(N,) index of the last row at or before each row where ``has`` (0 before any)."""
    idx = np.where(has, np.arange(len(has)), 0)
    return np.maximum.accumulate(idx)


def _held(rec, g: str, s: Stream, ref: np.ndarray) -> np.ndarray:
    """The controller's last set point at each reference row (a controller holds it)."""
    arr = getattr(rec, g)
    has = np.zeros(rec.n_samples, dtype=bool)
    has[s.rows] = True
    return arr[_carry(has)[ref]]


# ----- scale -------------------------------------------------------------------------------

def events(rec, still_m: float = 2e-5) -> np.ndarray:
    """(N,) bool: rows where something happens: a cable's reading reverses direction, starts
    or stops moving; a cable's reading or the measured position jumps (a step beyond 10
    times both neighbouring steps and 10 times the noise); the state changes; the first
    and last rows."""
    N = rec.n_samples
    ev = np.zeros(N, dtype=bool)
    ev[[0, -1]] = True
    src = rec.l_meas if np.isfinite(rec.l_meas).any() else rec.l_cmd
    if np.isfinite(src).any() and N > 3:
        d = np.nan_to_num(np.diff(src, axis=0))
        step = np.abs(d) > still_m
        moving = step.any(axis=1)  # between row k and k+1
        ev[1:-1] |= moving[1:] != moving[:-1]  # starts and stops
        # reversals: the sign of each cable's last real step flips
        sgn = np.where(step, np.sign(d), 0.0)
        last = np.take_along_axis(sgn, np.maximum.accumulate(
            np.where(step, np.arange(N - 1)[:, None], 0), axis=0), axis=0)
        ev[1:-1] |= np.any((last[1:] * last[:-1]) < 0, axis=1)
    for arr in (src, rec.pose_meas[:, :3]):  # a step 10 times both neighbouring steps
        ok = np.isfinite(arr).all(axis=1)
        idx = np.flatnonzero(ok)
        if len(idx) < 4:
            continue
        ad = np.abs(np.diff(arr[idx], axis=0))
        nb = np.maximum(np.r_[ad[:1], ad[:-1]], np.r_[ad[1:], ad[-1:]])
        floor = np.maximum(10 * _noise(arr[idx]), still_m)
        ev[idx[1:]] |= np.any(ad > 10 * nb + floor, axis=1)
    if rec.state is not None:
        st = np.asarray(rec.state, dtype=object)
        ev[1:] |= st[1:] != st[:-1]
    return ev


def condense(rec, budget: int = ROW_BUDGET):
    """``rec`` with at most about ``budget`` rows: every k-th row, and every row within
    EVENT_ROWS of an event (:func:`events`); the rows of a stretch where nothing happens
    carry the same information at a lower rate (the diagnosis keeps a few hundred samples).
    Returns (rec, info) with info None when nothing was left out."""
    N = rec.n_samples
    if N <= budget:
        return rec, None
    ev = events(rec)
    near = np.convolve(ev.astype(float), np.ones(2 * EVENT_ROWS + 1), mode="same") > 0
    n_ev = int(near.sum())
    k = max(2, int(np.ceil(N / max(budget - min(n_ev, budget // 2), 1))))
    keep = near.copy()
    keep[::k] = True
    if n_ev > budget // 2:  # too many events: keep them decimated as well
        keep = np.zeros(N, dtype=bool)
        keep[::k] = True
        keep[np.flatnonzero(near)[:: max(1, n_ev // (budget // 2))]] = True
    idx = np.flatnonzero(keep)
    out = take_rows(rec, idx)
    info = {"rows_before": N, "rows_after": len(idx), "every": k, "event_rows": n_ev}
    return out, info


def take_rows(rec, idx: np.ndarray, init: bool = True):
    """The recording's rows ``idx`` (in order) as a recording of their own (its ``init_rows``
    found again when ``init``, else none: a part that is no recording of its own)."""
    out = replace(rec, t=rec.t[idx], pose_des=rec.pose_des[idx], pose_meas=rec.pose_meas[idx],
                  l_cmd=rec.l_cmd[idx], l_meas=rec.l_meas[idx], tau=rec.tau[idx],
                  exit_meas=rec.exit_meas[idx],
                  state=[rec.state[i] for i in idx] if rec.state is not None else None,
                  extra={k: v[idx] for k, v in rec.extra.items()})
    src = getattr(rec, "source_rows", None)
    out.source_rows = idx if src is None else src[idx]
    from bench.recording import _init_rows

    out.init_rows = _init_rows(out) if init else np.zeros(0, dtype=int)
    return out


def concat_rows(recs: list, init: bool = True):
    """Recordings of consecutive rows of one recording (:func:`take_rows` of its parts) as
    one; ``init_rows`` found again on the whole (when ``init``)."""
    first = recs[0]

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(r, name) for r in recs])

    keys = list(dict.fromkeys(k for r in recs for k in r.extra))
    extra = {k: np.concatenate([r.extra.get(k, np.full(r.n_samples, np.nan)) for r in recs])
             for k in keys}
    state = None
    if any(r.state is not None for r in recs):
        state = [x for r in recs for x in (r.state or [""] * r.n_samples)]
    out = replace(first, t=cat("t"), pose_des=cat("pose_des"), pose_meas=cat("pose_meas"),
                  l_cmd=cat("l_cmd"), l_meas=cat("l_meas"), tau=cat("tau"),
                  exit_meas=cat("exit_meas"), state=state, extra=extra)
    out.source_rows = np.concatenate([
        r.source_rows if r.source_rows is not None else np.arange(r.n_samples) for r in recs])
    from bench.recording import _init_rows

    out.init_rows = _init_rows(out) if init else np.zeros(0, dtype=int)
    return out


def merge_parts(parts: list[tuple[list[str], dict[str, np.ndarray], list[str] | None]]
                ) -> tuple[list[str], dict[str, np.ndarray], list[str] | None]:
    """The files of a split recording as one table: the union of their columns (a column a
    file lacks is "no sample" in its rows), rows in time order (a stable sort: rows of
    equal time keep the order of the files)."""
    header: list[str] = []
    for h, _, _ in parts:
        header += [c for c in h if c not in header]
    sizes = [len(c["t"]) for _, c, _ in parts]
    N = sum(sizes)
    cols = {name: np.full(N, np.nan) for name in header if name != "state"}
    states = [""] * N if any(s is not None for _, _, s in parts) else None
    at = 0
    for (_, c, st), size in zip(parts, sizes, strict=True):
        for name, v in c.items():
            cols[name][at:at + size] = v
        if states is not None and st is not None:
            states[at:at + size] = st
        at += size
    order = np.argsort(cols["t"], kind="stable")
    cols = {k: v[order] for k, v in cols.items()}
    if states is not None:
        states = [states[i] for i in order]
    return header, cols, states


def condition(rec):
    """The recording as the diagnosis takes it: its streams described, brought to common
    instants (:func:`align`) and condensed (:func:`condense`). Returns (rec, report) where
    report is ``{"streams": {name: ...}, "alignment": ... or None, "condensed": ... or
    None}`` (docs/formats/recording-streams.md)."""
    streams = describe(rec)
    paused = pauses(rec.t)
    report = {"streams": {k: v.report(rec.n_samples, paused) for k, v in streams.items()},
              "runs": runs_report(paused)}
    rec, al = align(rec, streams)
    report["alignment"] = al.report() if al is not None else None
    rec, info = condense(rec, ROW_BUDGET)
    report["condensed"] = info
    return rec, report


def summary_line(report: dict) -> str:
    """One line for a person: the recording's runs (when it pauses), each stream's rate
    (within runs), jitter and lost samples; alignment; condensing."""
    parts = []
    runs = report.get("runs")
    if runs and runs["pauses"]:
        parts.append(f"rows in {runs['runs']} runs ({runs['pauses']} pauses without rows, "
                     f"{runs['pause_total_s']:.3g} s; rates within runs)")
    for name, s in report["streams"].items():
        txt = f"{name} {s['rate_hz']:.4g} Hz"
        if s["jitter_s"] > 1e-6:
            txt += f" (jitter {s['jitter_s'] * 1e3:.2g} ms)"
        if s["gaps"]:
            txt += f", {s['gaps']} gaps ({s['gap_total_s']:.3g} s without samples)"
        parts.append(txt)
    line = "; ".join(parts)
    al = report.get("alignment")
    if al:
        line += (f"; aligned to the {al['reference']}'s instants ({al['rows_before']} rows -> "
                 f"{al['rows_after']})")
    cd = report.get("condensed")
    if cd:
        line += f"; condensed to {cd['rows_after']} rows (every {cd['every']}th and events)"
    return line


# ----- motion from measurements -------------------------------------------------------------

#: window [s] of the local polynomial fits that judge motion from measured signals
MOTION_WINDOW_S = 1.0
#: a measured signal stands still where its fitted speed stays below this many standard
#: deviations of the fitted speed's noise (and below STILL_SPEED)
STILL_SIGMAS = 6.0
#: speed [m/s] below which a measured signal counts as standing (beside its noise)
STILL_SPEED = 1e-3


def _segments_of(t: np.ndarray, ok: np.ndarray, window_s: float) -> list[np.ndarray]:
    """Runs of rows with ``ok`` values whose time steps stay below half the window."""
    idx = np.flatnonzero(ok)
    if not len(idx):
        return []
    cut = np.flatnonzero(np.diff(t[idx]) > 0.5 * window_s) + 1
    return np.split(idx, cut)


def local_derivative(t: np.ndarray, x: np.ndarray, order: int,
                     window_s: float = MOTION_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """The ``order``-th time derivative (1 speed, 2 acceleration) of the measured signal
    ``x`` (N, d) at every row, from a least-squares polynomial of degree 2 over the rows
    within ``window_s`` [s] (a Savitzky-Golay filter on each stretch of rows without
    gaps, spaced as their median step; the first and last rows of a stretch from its
    first and last window). Returns (N, d) derivatives (NaN where a row has no value or
    its stretch is shorter than 5 rows) and (d,) the standard deviation of the
    derivative's noise per unit white noise of ``x`` (to compare with the signal's noise)."""
    N, d = x.shape
    out = np.full((N, d), np.nan)
    gain = np.full(d, np.inf)
    ok = np.isfinite(x).all(axis=1)
    for seg in _segments_of(t, ok, window_s):
        if len(seg) < 5:
            continue
        h = float(np.median(np.diff(t[seg])))
        w = int(round(window_s / max(h, 1e-9))) | 1
        w = max(5, min(w, len(seg) - (1 - len(seg) % 2)))
        xs = x[seg]
        m = w // 2
        win = np.lib.stride_tricks.sliding_window_view(xs, w, axis=0)  # (K-w+1, d, w)
        c = _poly_coeffs(w, m, order, h)
        res = np.empty_like(xs)
        res[m:len(seg) - m] = win @ c
        for i in range(m):  # the ends: the first and last windows' polynomials
            res[i] = xs[:w].T @ _poly_coeffs(w, i, order, h)
            res[len(seg) - 1 - i] = xs[-w:].T @ _poly_coeffs(w, w - 1 - i, order, h)
        out[seg] = res
        gain = np.minimum(gain, float(np.sqrt(np.sum(c ** 2))))
    return out, gain


def _poly_coeffs(w: int, pos: int, order: int, h: float) -> np.ndarray:
    """(w,) weights giving the ``order``-th derivative, at sample ``pos`` of a window of
    ``w`` samples ``h`` [s] apart, of the least-squares polynomial of degree 2."""
    z = (np.arange(w) - pos) * h
    pinv = np.linalg.pinv(np.vander(z, 3, increasing=True))
    return pinv[order] * (1.0 if order < 2 else 2.0)


def signal_noise(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(d,) white noise of a measured signal (N, d): robust second differences of
    consecutive samples / sqrt(6) (a steady motion cancels)."""
    ok = np.isfinite(x).all(axis=1)
    return _noise(x[ok]) if ok.sum() >= 5 else np.zeros(x.shape[1])


def still_rows(rec) -> tuple[np.ndarray, np.ndarray] | None:
    """(N,) bool twice: rows where the platform stands, judged from measurements only
    (encoders, else the measured pose: the fitted speed of every signal within STILL_SIGMAS
    of its noise and below STILL_SPEED), and rows where that could be judged (in a
    stretch of at least 5 rows without gaps). None without such signals."""
    for arr in (rec.l_meas, rec.pose_meas[:, :3]):
        cols = np.isfinite(arr).any(axis=0)
        if not cols.any():
            continue
        x = arr[:, cols]
        v, gain = local_derivative(rec.t, x, 1)
        lim = np.minimum(np.maximum(STILL_SIGMAS * gain * signal_noise(rec.t, x), 1e-5),
                         STILL_SPEED)
        known = np.isfinite(v).all(axis=1)
        with np.errstate(invalid="ignore"):
            return np.all(np.abs(v) <= lim, axis=1) & known, known
    return None


def jittered(t: np.ndarray) -> bool:
    """Whether time stamps ``t`` jitter (their intervals spread by more than 1 % of the
    median interval): finite differences of even a noise-free signal then scatter by
    (speed x jitter / interval^2)."""
    dt = np.diff(t)
    if len(dt) < 3:
        return False
    med = float(np.median(dt))
    return bool(1.4826 * np.median(np.abs(dt - med)) > 0.01 * med)


def measured_acceleration(rec, rows: np.ndarray, pose: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray] | None:
    """Linear [m/s^2] and angular [rad/s^2] acceleration magnitudes of the measured pose
    (or of ``pose`` (N,6), e.g. the commanded one under jittered time stamps) at ``rows``,
    filtered (:func:`local_derivative`) so that tracker noise and time-stamp jitter at any
    rate stay far below the limits it is compared with; None without such a pose."""
    p = rec.pose_meas if pose is None else pose
    cols = np.isfinite(p).any(axis=0)
    if not cols[:3].all():
        return None
    a = np.zeros((len(p), 6))
    a[:, cols], _ = local_derivative(rec.t, p[:, cols], 2)
    a = a[rows]
    lin = np.linalg.norm(a[:, :3], axis=1)
    ang = np.abs(a[:, 3:]).max(axis=1)
    return lin, ang  # NaN where the filter has no value (too few rows around)


def length_acceleration(rec, rows: np.ndarray) -> np.ndarray | None:
    """The largest acceleration [m/s^2] of any cable's encoder reading at ``rows``, filtered
    as :func:`measured_acceleration` (NaN where the filter has no value); None without
    encoder readings. A cable's length accelerates by the platform's acceleration along
    the cable (plus the lever arm's share of the angular one): where no pose is measured
    this judges the platform's motion from below."""
    cols = np.isfinite(rec.l_meas).any(axis=0)
    if not cols.any():
        return None
    a, _ = local_derivative(rec.t, rec.l_meas[:, cols], 2)
    return np.abs(a[rows]).max(axis=1)
