"""From a recording to the inputs of the ISO 9283 figures: visits (pose) and passes (path).

A recording (``cdpr-recording/1``) holds commanded poses ``x_des..yaw_des`` and measured
poses ``x_meas..yaw_meas`` per row. The rules, also printed by ``cdpr iso9283``:

Visits (pose figures), recordings with a ``state`` column: a visit is a run of consecutive
rows in state ``dwell`` with one commanded pose. Without ``state`` (a real robot's log): a
run of at least :data:`MIN_DWELL_ROWS` consecutive rows with one commanded pose, except the
initialisation rows, or a single row of a table of poses logged one row per pose
(:meth:`bench.recording.Recording.table_rows`: rows seconds apart). The attained pose of a
visit is the mean measured pose over the rows of
the dwell's last ``1 − settle`` part by time (default: its second half), so that the
platform has come to rest as ISO 9283 requires. A dwell that lasts k times (k ≥ 2, within a
quarter) the recording's median dwell is taken as k back-to-back visits of the same pose
(a campaign that draws the same pose twice in a row) and split into k equal parts, with a
warning. Visits are grouped by commanded pose (equal within :data:`POSE_TOL`).

Passes (path figures), with ``state``: a run of rows in state ``move`` (rows in ``hold``
between them belong to it: the platform paused on the path), extended by the rest row just
before and after it when that row is in ``dwell``, ``init`` or ``end`` (the path's end
points). Without ``state``: the runs of rows between dwells (rows whose commanded pose
changes), extended the same way. A run holds several passes when a path is repeated without
a dwell between repetitions: with a ``cycle`` column (the trajectory's repetition: −1 for an
approach, 0, 1, ... for the repetitions), the run is cut where ``cycle`` changes and rows
with ``cycle`` < 0 are left out; without it, the run is cut where its commanded pose comes
back to the pose the run ends at (each repetition ends there; an approach that ends there
becomes a pass of its own). Passes are grouped by commanded path (equal within
:data:`PATH_TOL` at 64 points evenly spaced along them); :meth:`Analysis.main_path` is the
group with the most commanded length in all (passes × length).

Rows in other states (``quick_stop``, ``fault``, or any other name) are no part of a visit
or a pass. Errors (:class:`Iso9283Error`) name the file, line and column.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.iso9283.figures import resample_path, wrap_angle
from bench.recording import POSE_AXES, TABLE_GAP_S, Recording, RecordingError

#: no state column: a dwell is a run of at least this many rows with one commanded pose
MIN_DWELL_ROWS = 3
#: commanded poses equal within [m, rad]
POSE_TOL = 1e-6
#: commanded paths equal within [m, rad]
PATH_TOL = 1e-3
#: default part of each dwell, by time from its start, left out while the platform settles
SETTLE = 0.5
#: a dwell this close (relative) to k times the median dwell is k back-to-back visits
_SPLIT_TOL = 0.25


class Iso9283Error(RecordingError):
    """A recording the ISO 9283 figures cannot use; the message names file, line, column."""


@dataclass
class Visit:
    """One visit of a commanded pose: ``command``/``attained`` (6,) [m, rad]; ``rows`` the
    dwell's row indices [a, b); ``used`` the rows averaged; ``lines`` the CSV lines of the
    dwell (first, last); ``source`` the recording directory."""

    command: np.ndarray
    attained: np.ndarray
    rows: tuple[int, int]
    used: tuple[int, int]
    lines: tuple[int, int]
    t: tuple[float, float]
    source: Path


@dataclass
class Pass:
    """One pass over a commanded path: ``command``/``attained`` (k, 6) rows in time order;
    ``rows`` [a, b); ``lines`` CSV lines (first, last)."""

    command: np.ndarray
    attained: np.ndarray
    rows: tuple[int, int]
    lines: tuple[int, int]
    source: Path

    @property
    def length(self) -> float:
        p = self.command[:, :3]
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


@dataclass
class Segments:
    """Visits and passes of one recording, the rules used, and warnings (with lines)."""

    visits: list[Visit]
    passes: list[Pass]
    visit_rule: str
    pass_rule: str
    warnings: list[str] = field(default_factory=list)
    no_visit_reason: str = ""
    no_pass_reason: str = ""


class _Csv:
    """The CSV's path, header and the file line of each data row (as read_recording reads)."""

    def __init__(self, rec: Recording):
        self.path = rec.path / str(rec.meta.get("samples", "recording.csv"))
        lines, header = [], []
        try:
            with self.path.open(newline="", encoding="utf-8") as f:
                reader = csv.reader(f)
                header = [h.strip() for h in next(reader, [])]
                for lineno, row in enumerate(reader, start=2):
                    if row and any(x.strip() for x in row):
                        lines.append(lineno)
        except OSError:
            pass
        self.header = header
        self.lines = np.array(lines if len(lines) == rec.n_samples
                              else np.arange(rec.n_samples) + 2, dtype=int)

    def col(self, name: str) -> str:
        return (f"column {self.header.index(name) + 1} '{name}'" if name in self.header
                else f"column '{name}'")

    def span(self, a: int, b: int) -> tuple[int, int]:
        return int(self.lines[a]), int(self.lines[b - 1])


def _check_columns(rec: Recording, f: _Csv) -> None:
    for group, suffix, what in (("pose_des", "des", "commanded"), ("pose_meas", "meas",
                                                                    "measured")):
        arr = getattr(rec, group)
        for a, ax in enumerate(POSE_AXES[:3]):
            name = f"{ax}_{suffix}"
            if name not in f.header:
                raise Iso9283Error(f"{f.path}:1: column '{name}' is missing: no {what} pose "
                                   f"(the ISO 9283 figures need x_des..z_des and x_meas..z_meas)")
            if not np.isfinite(arr[:, a]).any():
                raise Iso9283Error(f"{f.path}: {f.col(name)}: no value in any row: no {what} "
                                   f"pose")


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) runs of True in a boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


def _split_on_change(a: int, b: int, key: np.ndarray) -> list[tuple[int, int]]:
    """Split [a, b) where the row key changes."""
    cuts = [a] + [k for k in range(a + 1, b) if not np.array_equal(key[k], key[k - 1])] + [b]
    return list(zip(cuts[:-1], cuts[1:], strict=True))


def _pose_key(pose_des: np.ndarray) -> np.ndarray:
    return np.round(np.nan_to_num(pose_des, nan=1e12) / POSE_TOL)


def _mean_pose(rows: np.ndarray) -> np.ndarray:
    """Mean pose of rows (k, 6), ignoring NaN; angles averaged on their wrapped deviation
    from their first finite value."""
    out = np.full(6, np.nan)
    for c in range(6):
        v = rows[:, c][np.isfinite(rows[:, c])]
        if not len(v):
            continue
        out[c] = v.mean() if c < 3 else wrap_angle(v[0] + wrap_angle(v - v[0]).mean())
    return out


def segment(rec: Recording, settle: float = SETTLE) -> Segments:
    """Visits and passes of a recording by the rules of the module docstring."""
    if not 0.0 <= settle < 1.0:
        raise ValueError(f"settle: {settle}: must be in [0, 1)")
    f = _Csv(rec)
    _check_columns(rec, f)
    N = rec.n_samples
    key = _pose_key(rec.pose_des)
    has_des = np.isfinite(rec.pose_des[:, :3]).all(axis=1)
    warnings: list[str] = []
    init = np.zeros(N, dtype=bool)
    if rec.state is not None:
        st = np.array(rec.state, dtype=object)
        init = st == "init"
        dwell_runs = [r for a, b in _runs((st == "dwell") & has_des)
                      for r in _split_on_change(a, b, key)]
        moving = (st == "move") | (st == "hold")
        move_runs = []
        for a, b in _runs(moving):
            inner = np.flatnonzero(st[a:b] == "move")
            if len(inner):
                move_runs.append((a + int(inner[0]), a + int(inner[-1]) + 1))
        rest = (st == "dwell") | init | (st == "end")
        other = sorted(set(st.tolist()) - {"init", "move", "dwell", "hold", "end"})
        if other:
            warnings.append(f"{f.path}: rows in state {', '.join(repr(s) for s in other)} are "
                            f"no part of a visit or a pass")
        visit_rule = ("visits: runs of rows in state 'dwell' with one commanded pose")
        pass_rule = ("passes: runs of rows in state 'move' (with any 'hold' between them), plus "
                     "the rest row before and after")
        states = ", ".join(sorted(set(st.tolist())))
        no_visit = f"no row in state 'dwell' (states found: {states})"
        no_pass = f"no row in state 'move' (states found: {states})"
    else:
        init[rec.init_rows] = True
        runs = [r for a, b in _runs(has_des) for r in _split_on_change(a, b, key)]
        table = rec.table_rows() & has_des
        dwell_runs = sorted([(a, b) for a, b in runs if b - a >= MIN_DWELL_ROWS
                             and not init[a:b].any()]
                            + [(int(i), int(i) + 1) for i in np.flatnonzero(table & ~init)])
        rest = table.copy()
        for a, b in runs:
            if b - a >= MIN_DWELL_ROWS:
                rest[a:b] = True
        rest |= init
        move_runs = _runs(~rest & has_des)
        visit_rule = (f"visits (no 'state' column): runs of at least {MIN_DWELL_ROWS} rows with "
                      f"one commanded pose, after the initialisation rows, and rows of a table "
                      f"of poses (more than {TABLE_GAP_S:g} s from both neighbours, the "
                      f"commanded pose changing on both sides)")
        pass_rule = ("passes (no 'state' column): runs of rows whose commanded pose changes from "
                     "row to row, plus the rest row before and after")
        no_visit = (f"no run of {MIN_DWELL_ROWS} or more rows with one commanded pose after the "
                    f"initialisation, and no row of a table of poses")
        no_pass = "no rows where the commanded pose changes from row to row"
    visit_rule += (f"; attained pose = mean measured pose over the last {100 * (1 - settle):.0f} "
                   f"% of each dwell (by time)")

    dwell_runs = _split_repeats(dwell_runs, f, warnings)
    visits = []
    for a, b in dwell_runs:
        t0, t1 = rec.t[a], rec.t[b - 1]
        cut = t0 + settle * (t1 - t0)
        used = np.flatnonzero(rec.t[a:b] >= cut - 1e-12) + a
        ua, ub = int(used[0]), int(used[-1]) + 1
        att = _mean_pose(rec.pose_meas[ua:ub])
        la, lb = f.span(a, b)
        if not np.isfinite(att[:3]).all():
            warnings.append(f"{f.path}:{la}-{lb}: dwell without a measured position in its last "
                            f"rows (x_meas..z_meas): visit skipped")
            continue
        visits.append(Visit(rec.pose_des[a].copy(), att, (a, b), (ua, ub), (la, lb),
                            (float(t0), float(t1)), rec.path))

    cycle = rec.extra.get("cycle")
    pass_rule += ("; repetitions cut where the 'cycle' column changes (cycle < 0, an approach, "
                  "left out)" if cycle is not None else
                  "; repetitions cut where the commanded pose comes back to the pose the run "
                  "ends at")
    passes = []
    for a, b in move_runs:
        a2 = a - 1 if a > 0 and rest[a - 1] and has_des[a - 1] else a
        b2 = b + 1 if b < N and rest[b] and has_des[b] else b
        for pa, pb in (_cut_by_cycle(a2, b2, cycle) if cycle is not None
                       else _cut_at_end_pose(a2, b2, key)):
            p = Pass(rec.pose_des[pa:pb].copy(), rec.pose_meas[pa:pb].copy(), (pa, pb),
                     f.span(pa, pb), rec.path)
            if pb - pa >= 2 and p.length > PATH_TOL:
                passes.append(p)
    return Segments(visits, passes, visit_rule, pass_rule, warnings, no_visit, no_pass)


def _cut_by_cycle(a: int, b: int, cycle: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) cut where ``cycle`` changes; each part also takes the row before and after it
    (its ends, between recorded rows); parts with cycle < 0 or NaN (approach) left out. The
    rest rows at a and b - 1 count with their neighbours."""
    c = cycle[a:b].copy()
    if len(c) > 2:
        c[0], c[-1] = c[1], c[-2]  # the rest rows belong to the first / last part
    out = []
    for pa, pb in _split_on_change(0, len(c), np.nan_to_num(c, nan=-1.0)[:, None]):
        if c[pa] >= 0:
            out.append((a + max(pa - 1, 0), a + min(pb + 1, len(c))))
    return out


def _cut_at_end_pose(a: int, b: int, key: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) cut at the last row of each earlier stay at the run's final commanded pose
    (the rows on both sides of a cut share that row)."""
    at_end = np.all(key[a:b] == key[b - 1], axis=1)
    cuts = [a]
    for ra, rb in _runs(at_end[:-1]):
        if ra == 0 or a + rb - 1 <= cuts[-1] or a + rb >= b - 1:
            continue  # the run starts or ends there: no pass before or after it
        cuts.append(a + rb - 1)
    if len(cuts) == 1:
        return [(a, b)]
    cuts.append(b - 1)
    return [(x, y + 1) for x, y in zip(cuts[:-1], cuts[1:], strict=True) if y > x]


def _split_repeats(runs: list[tuple[int, int]], f: _Csv, warnings: list[str]
                   ) -> list[tuple[int, int]]:
    """Split dwells that last k ≥ 2 times the median dwell into k visits."""
    if len(runs) < 3:
        return runs
    med = float(np.median([b - a for a, b in runs]))
    out = []
    for a, b in runs:
        r = (b - a) / med if med > 0 else 1.0
        k = int(round(r))
        if k >= 2 and abs(r - k) <= _SPLIT_TOL and (b - a) >= 2 * k:
            la, lb = f.span(a, b)
            warnings.append(f"{f.path}:{la}-{lb}: dwell {r:.2f} times the median dwell "
                            f"({med:.0f} rows): taken as {k} back-to-back visits of one pose")
            cuts = np.linspace(a, b, k + 1).round().astype(int)
            out += list(zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True))
        else:
            out.append((a, b))
    return out


def group_visits(visits: list[Visit]) -> list[list[Visit]]:
    """Visits grouped by commanded pose (equal within :data:`POSE_TOL`), in order of first
    visit."""
    groups: list[list[Visit]] = []
    for v in visits:
        for g in groups:
            d = np.abs(v.command - g[0].command)
            d[3:] = np.abs(wrap_angle(d[3:]))
            if np.all(np.nan_to_num(d, nan=0.0) <= POSE_TOL) and np.array_equal(
                    np.isnan(v.command), np.isnan(g[0].command)):
                g.append(v)
                break
        else:
            groups.append([v])
    return groups


def group_passes(passes: list[Pass], tol: float = PATH_TOL) -> list[list[Pass]]:
    """Passes grouped by commanded path (equal within ``tol`` [m, rad] at 64 points evenly
    spaced along each), in order of first pass."""
    groups: list[tuple[np.ndarray, list[Pass]]] = []
    for p in passes:
        _, q = resample_path(p.command, 64)
        for ref, g in groups:
            d = np.abs(q - ref)
            d[:, 3:] = np.abs(wrap_angle(d[:, 3:]))
            if np.nanmax(d) <= tol:
                g.append(p)
                break
        else:
            groups.append((q, [p]))
    return [g for _, g in groups]
