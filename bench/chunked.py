"""Long recordings read block by block and conditioned as they are read.

A recording whose samples files together hold at least :data:`CHUNKED_MIN_BYTES` is never
held whole. Its data lines are read :data:`BLOCK_BYTES` at a time (a columnar parse of each
block, :func:`bench.streams.parse_block`; a block it cannot take is read row by row, and the
error names the file's line). Each block in turn

1. has its impossible values excluded (:func:`bench.diagnosis.samples.check_values`);
2. gives its streams' time stamps (kept for the whole file: 8 bytes a sample, so that the
   rates, jitter and gaps in the report are those of all rows);
3. is brought to the instants of the slowest measuring stream (:func:`bench.streams.align`;
   the stream and its period are decided on the first block, gap instants counted from the
   first row's time). Blocks overlap by a margin of :data:`MARGIN_S` (at least 8 periods
   of that stream), and a block gives only the aligned rows up to a margin before its end,
   so that every interpolation sees the neighbours it would see in the whole file;
4. when the aligned rows of the whole file would exceed :data:`PRE_BUDGET` (projected from
   the bytes read so far), is decimated to every m-th aligned row plus every row within
   :data:`bench.streams.EVENT_ROWS` of an event (:func:`bench.streams.events`).

The rows kept are then condensed as a whole recording's (:func:`bench.streams.condense`), so
the diagnosis sees at most about :data:`bench.streams.ROW_BUDGET` rows whatever the length
of the log, and the memory held is a block plus the rows kept. A recording split in time
(files whose times follow each other) is read the same way, file after file; one split by
sensor (files whose times interleave) is merged whole (:func:`bench.streams.merge_parts`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bench import streams as st
from bench.recording import (
    Recording,
    RecordingError,
    _from_columns,
    _read_csv_rows,
    _read_header,
    open_recording,
    read_recording,
)
from controller.tomlfile import decode_utf8

#: samples files of at least this many bytes (together) are read block by block
CHUNKED_MIN_BYTES = 128 * 1024 * 1024
#: bytes of data lines parsed at a time
BLOCK_BYTES = 32 * 1024 * 1024
#: overlap [s] of consecutive blocks (at least 8 periods of the slowest stream)
MARGIN_S = 5.0
#: aligned rows beyond which blocks are decimated as they are read
PRE_BUDGET = 3 * st.ROW_BUDGET


def read_conditioned(path: str | Path) -> tuple[Recording, dict, list[dict]]:
    """The recording at ``path`` as the diagnosis takes it: (recording aligned and condensed,
    the streams report of :func:`bench.streams.condition`, the impossible values excluded
    as :func:`bench.diagnosis.samples.check_values` lists them). Long recordings are read
    block by block (module docstring); others whole."""
    from bench.diagnosis.samples import check_values
    from bench.mcap.reader import mcap_file

    if mcap_file(path) is None:
        d, meta, robot, init_pose, samples = open_recording(path)
        paths = samples if isinstance(samples, list) else [samples]
        try:
            size = sum(p.stat().st_size for p in paths)
        except OSError:
            size = -1  # the whole-file reader names the missing file
        if size >= CHUNKED_MIN_BYTES and _in_time_order(paths, robot):
            return _read_chunked(d, paths, robot, meta, init_pose, size)
    rec = read_recording(path)
    excluded = check_values(rec)
    rec, report = st.condition(rec)
    return rec, report, excluded


def _time_span(p: Path, header: list[str]) -> tuple[float, float] | None:
    """The times of the first and last data lines of ``p`` (None when not plain numbers)."""
    k = header.index("t")
    with p.open("rb") as f:
        f.readline()
        first = f.readline()
        size = f.seek(0, 2)
        f.seek(max(0, size - 65536))
        lines = [ln for ln in f.read().splitlines() if ln.strip()]
    try:
        return float(first.split(b",")[k]), float(lines[-1].split(b",")[k])
    except (ValueError, IndexError):
        return None


def _in_time_order(paths: list[Path], robot) -> bool:
    """Whether the files' times follow each other (one file, or a recording split in time)."""
    if len(paths) == 1:
        return True
    spans = [_time_span(p, _read_header(p, robot)) for p in paths]
    if any(s is None for s in spans):
        return False
    return all(b[0] >= a[1] for a, b in zip(spans, spans[1:], strict=False))


def iter_blocks(p: Path, header: list[str], block_bytes: int | None = None):
    """Consecutive blocks of the data rows of ``p`` (whose header is ``header``): yields
    (columns, states, bytes) as :func:`bench.streams.read_columns` gives them; a block the
    columnar parse does not take (or in a forked child: :func:`bench.streams._polars_usable`)
    is read row by row, its errors naming the file's line. The file is mapped, not read:
    each block is one copy of its bytes, cut at the last line end within ``block_bytes``
    (a line longer than that extends its block). The mapped pages of a block are released
    once copied (they would otherwise count in the process's resident memory: the whole
    file by the end)."""
    import mmap

    size = block_bytes or BLOCK_BYTES
    last_t, last_line = None, 0
    with p.open("rb") as f:
        if os.fstat(f.fileno()).st_size == 0:
            return
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            start, end, line = mm.find(b"\n") + 1, len(mm), 2
            while 0 < start < end:
                stop = min(start + size, end)
                cut = end if stop == end else mm.rfind(b"\n", start, stop) + 1
                if cut <= start:  # a line longer than the block: up to its end
                    nl = mm.find(b"\n", stop)
                    cut = end if nl < 0 else nl + 1
                data = mm[start:cut]
                _release(mm, start, cut)
                start = cut
                if not data.isspace():  # (a copy-free test: strip() would copy the block)
                    cols, states = _parse(p, header, data, line)
                    t = cols["t"]
                    if last_t is not None and len(t) and t[0] < last_t:
                        raise RecordingError(
                            f"{p}:{_first_row_line(data, line)}: "
                            f"{st.time_back_message(header, last_t, last_line, t[0])}")
                    if len(t):
                        last_t, last_line = float(t[-1]), _last_row_line(data, line)
                    yield cols, states, len(data)
                line += data.count(b"\n")


def _first_row_line(data: bytes, line: int) -> int:
    """The file's line number of the first non-blank line of a block starting at ``line``."""
    parts = data.split(b"\n", 64)  # (blank lines before it: a few at most)
    return line + next((k for k, ln in enumerate(parts) if ln.strip()), 0)


def _last_row_line(data: bytes, line: int) -> int:
    """The file's line number of the last non-blank line of a block starting at ``line``."""
    body = data.rstrip()
    return line + body.count(b"\n")


def _release(mm, start: int, stop: int) -> None:
    """Drop the mapped pages of bytes ``[start, stop)`` of ``mm`` from the process (where
    the system allows: they stay in the page cache)."""
    import mmap

    lo = start - start % mmap.PAGESIZE
    if stop > lo and hasattr(mm, "madvise") and hasattr(mmap, "MADV_DONTNEED"):
        mm.madvise(mmap.MADV_DONTNEED, lo, stop - lo)


def _parse(p: Path, header: list[str], data: bytes, line: int):
    """One block's columns: columnar where it can, else row by row (naming the line)."""
    fast = st.parse_block(data, header) if st._polars_usable() else None
    if fast is not None:
        return fast
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        decode_utf8(p.read_bytes(), p, RecordingError)  # raises, naming line and column
        raise
    _, cols, states = _read_csv_rows(p, header, text=text, first_line=line)
    return cols, states


class Conditioner:
    """Blocks of consecutive rows in, the conditioned recording out (module docstring)."""

    def __init__(self, total_bytes: int) -> None:
        self.total_bytes = total_bytes
        self.bytes = 0
        self.rows = 0
        self.blocks = 0
        self.times: dict[str, list[np.ndarray]] = {}
        self.reference: st.Stream | None = None
        self.t0 = 0.0
        self.margin = MARGIN_S
        self.carry: Recording | None = None
        self.until = -np.inf
        self.kept: list[Recording] = []
        self.aligned = 0
        self.every = 1
        self.event_rows = 0
        self.al = st.Alignment("", 0, 0)
        self.sumsq: dict[str, list[float]] = {}
        self.excluded: list[dict] = []
        self.more = 0
        self.row_period = 0.0  # the rows' median interval [s], from the first block
        self.paused: list[np.ndarray] = []  # the recording's pauses (streams.pauses)
        self.last_t: float | None = None

    def feed(self, block: Recording, nbytes: int) -> None:
        """Take the next block (``source_rows`` its rows in the whole file)."""
        self._check(block)
        if self.blocks == 0:
            self._decide(block)
        self.blocks += 1
        self.rows += block.n_samples
        t = block.t if self.last_t is None else np.concatenate([[self.last_t], block.t])
        self.paused.append(st.pauses(t, self.row_period))
        self.last_t = float(block.t[-1])
        self.bytes += nbytes
        w = block if self.carry is None else st.concat_rows([self.carry, block], init=False)
        sw = st.describe(w)
        new = w.n_samples - block.n_samples  # the block's first row in w
        for name, s in sw.items():
            rows = s.rows[s.rows >= new]
            if len(rows):
                self.times.setdefault(name, []).append(w.t[rows])
        cut = float(w.t[-1]) - self.margin
        self._emit(w, sw, cut)
        self.carry = st.take_rows(w, np.flatnonzero(w.t >= cut - self.margin), init=False)

    def _check(self, block: Recording) -> None:
        from bench.diagnosis.samples import check_values

        off = int(block.source_rows[0]) if block.source_rows is not None else 0
        for e in check_values(block):
            if "more" in e:
                self.more += e["more"]
            elif len(self.excluded) < 20:
                self.excluded.append({**e, "row": e["row"] + off})
            else:
                self.more += 1

    def _decide(self, block: Recording) -> None:
        """The reference stream and the overlap, from the first block."""
        self.t0 = float(block.t[0])
        self.row_period = st.row_period(block.t)
        s = st.describe(block)
        if st.multi_rate(block, s):
            self.reference = st._slowest(s)
            self.margin = max(MARGIN_S, 8 * self.reference.period_s)

    def _emit(self, w: Recording, sw: dict[str, st.Stream], cut: float) -> None:
        """Keep the aligned rows of ``w`` (whose streams are ``sw``) from the last cut up to
        ``cut`` [s]."""
        if self.reference is not None:
            a, al = st.align(w, sw, reference=self.reference, t0=self.t0)
        else:
            a, al = w, None
        sel = np.flatnonzero((a.t >= self.until) & (a.t < cut))
        self.until = cut
        if not len(sel):
            return
        if al is not None:
            self._count(w, a, sel, al)
        before = self.aligned
        self.aligned += len(sel)
        projected = self.aligned / max(self.bytes, 1) * self.total_bytes
        if projected > PRE_BUDGET:
            self.every = int(np.ceil(projected / PRE_BUDGET))
            near = np.convolve(st.events(a).astype(float), np.ones(2 * st.EVENT_ROWS + 1),
                               mode="same") > 0
            self.event_rows += int(near[sel].sum())
            sel = sel[near[sel] | ((before + np.arange(len(sel))) % self.every == 0)]
        self.kept.append(st.take_rows(a, sel, init=False))

    def _count(self, w: Recording, a: Recording, sel: np.ndarray, al: st.Alignment) -> None:
        """The alignment's counts over the rows ``sel`` of ``a`` (those this block gives)."""
        at = np.searchsorted(w.source_rows, a.source_rows[sel])
        for name in set(al.same_row) | set(al.refused):
            had = np.zeros(len(sel), dtype=bool)
            has = np.zeros(len(sel), dtype=bool)
            for g in st.GROUPS[name]:
                had |= np.isfinite(getattr(w, g)[at].reshape(len(sel), -1)).any(axis=1)
                has |= np.isfinite(getattr(a, g)[sel].reshape(len(sel), -1)).any(axis=1)
                if g in al.interp_rms:
                    acc = self.sumsq.setdefault(g, [0.0, 0.0])
                    acc[0] += al.interp_rms[g] ** 2 * int((has & ~had).sum())
                    acc[1] += int((has & ~had).sum())
            self.al.same_row[name] = self.al.same_row.get(name, 0) + int(had.sum())
            if name in al.interpolated:  # align tried to interpolate it in this block
                for d, v in ((self.al.interpolated, has & ~had), (self.al.refused, ~has & ~had)):
                    d[name] = d.get(name, 0) + int(v.sum())

    def finish(self) -> tuple[Recording, dict, list[dict]]:
        """The conditioned recording, the streams report and the excluded values."""
        if self.carry is not None:
            self._emit(self.carry, st.describe(self.carry), np.inf)
        rec = st.concat_rows(self.kept)
        report: dict = {"streams": {}}
        paused = np.concatenate(self.paused) if self.paused else np.zeros((0, 2))
        for name, parts in self.times.items():
            t = np.concatenate(parts)
            report["streams"][name] = st._stream(name, t, np.arange(len(t))).report(self.rows,
                                                                                   paused)
        report["runs"] = st.runs_report(paused)
        report["alignment"] = None
        if self.reference is not None:
            al = self.al
            al.reference, al.rows_before, al.rows_after = (self.reference.name, self.rows,
                                                          self.aligned)
            al.interp_rms = {g: float(np.sqrt(s / n)) for g, (s, n) in self.sumsq.items() if n}
            report["alignment"] = al.report()
        out, info = st.condense(rec, st.ROW_BUDGET)
        report["condensed"] = None
        if info is not None or self.every > 1:
            report["condensed"] = {
                "rows_before": self.aligned, "rows_after": out.n_samples,
                "every": self.every * (info["every"] if info else 1),
                "event_rows": info["event_rows"] if info else self.event_rows}
        report["read"] = {"blocks": self.blocks, "bytes": self.bytes, "rows": self.rows}
        excluded = self.excluded + ([{"more": self.more}] if self.more else [])
        return out, report, excluded


def _read_chunked(d: Path, paths: list[Path], robot, meta: dict, init_pose: np.ndarray,
                  size: int) -> tuple[Recording, dict, list[dict]]:
    """:func:`read_conditioned` of a long recording, block by block."""
    cond = Conditioner(size)
    row = 0
    for p in paths:
        header = _read_header(p, robot)
        for cols, states, nbytes in iter_blocks(p, header):
            block = _from_columns(d, p, robot, meta, init_pose, header, cols, states)
            block.source_rows = row + np.arange(block.n_samples)
            row += block.n_samples
            cond.feed(block, nbytes)
    if row == 0:
        raise RecordingError(f"{paths[0]}: no samples")
    return cond.finish()
