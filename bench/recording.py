"""Recordings in the ``cdpr-recording/1`` format (``docs/formats/recording.md``).

A recording is a directory with ``meta.toml``, ``robot.toml`` (the model the
controller ran with) and ``recording.csv``. :func:`read_recording` validates it
and returns arrays ordered as the robot's cables; errors name the file, the
line and the column. :func:`write_recording` writes one; :class:`RecordingWriter`
streams one while a run goes.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from bench.streams import loose_columns, signal_noise, time_back_message, time_goes_back
from controller.robot import Robot, RobotFileError, dumps_robot, load_robot
from controller.tomlfile import decode_utf8, read_toml

FORMAT = "cdpr-recording/1"
POSE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")
#: tolerance [m, rad] within which a desired pose still counts as the initialisation pose
INIT_TOL_DES = 1e-6
#: same for a measured pose (tracker noise) when there is no desired pose
INIT_TOL_MEAS = 2e-3
#: a first desired pose within this of init_pose [m, rad] is the pose of the initialisation
#: (the nominal target the platform stood at, init_pose what the tracker measured there)
INIT_NEAR = 0.05


class RecordingError(ValueError):
    """An invalid recording; the message names the file, line and column."""


@dataclass
class Recording:
    """A recording as arrays (N samples, n cables in the robot's order; NaN = not measured).

    ``pose_des``/``pose_meas`` (N,6); ``l_cmd``/``l_meas``/``tau`` (N,n);
    ``exit_meas`` (N,n,3); ``state`` (N,) strings or None; ``extra`` other
    numeric columns by name; ``init_rows`` the rows taken at initialisation.
    """

    path: Path
    robot: Robot
    meta: dict[str, Any]
    init_pose: np.ndarray
    t: np.ndarray
    pose_des: np.ndarray
    pose_meas: np.ndarray
    l_cmd: np.ndarray
    l_meas: np.ndarray
    tau: np.ndarray
    exit_meas: np.ndarray
    state: list[str] | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    init_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    #: rows of the file(s) each row comes from, when the rows were aligned or condensed
    #: (:mod:`bench.streams`); None: row k is the k-th row of the file
    source_rows: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return len(self.t)

    def has(self, group: str) -> bool:
        """Whether a column group (``pose_des``, ``pose_meas``, ``l_cmd``, ``l_meas``, ``tau``,
        ``exit_meas``) holds any measured value."""
        return bool(np.isfinite(getattr(self, group)).any())

    @property
    def init_tensions(self) -> np.ndarray | None:
        """Measured tensions at initialisation [N] (n,): each cable's mean over the init rows
        that hold a reading of it (a logger's load cells sample only some rows), or None
        when some cable has no reading there."""
        if not len(self.init_rows) or not self.has("tau"):
            return None
        tau = self.tau[self.init_rows]
        if not np.isfinite(tau).any(axis=0).all():
            return None
        return np.nanmean(tau, axis=0)


    def table_rows(self) -> np.ndarray:
        """(N,) bool: rows that are standing measurements of their own in a table of poses
        logged one row per pose: without a ``state`` column, the rows on both sides are
        more than :data:`TABLE_GAP_S` away in time and the commanded pose (else the measured
        one, else the encoder lengths) differs on both sides. A move is logged at 10-50 Hz;
        between such rows none was, so they are no rows of one."""
        N = self.n_samples
        out = np.zeros(N, dtype=bool)
        if self.state is not None or N == 0:
            return out
        p = next((a for a in (self.pose_des[:, :3], self.pose_meas[:, :3], self.l_cmd,
                              self.l_meas) if np.isfinite(a).all(axis=1).any()), None)
        if p is None:
            return out
        big = np.full(N + 1, True)  # between row k-1 and row k (the ends: no neighbour)
        with np.errstate(invalid="ignore"):
            moved = np.linalg.norm(np.diff(p, axis=0), axis=1)
            big[1:-1] = (np.diff(self.t) > TABLE_GAP_S) & ~(moved == 0)
        return big[:-1] & big[1:]


#: a table of poses: rows this many seconds apart with no row between (:meth:`table_rows`)
TABLE_GAP_S = 1.0


def _column_groups(robot: Robot) -> dict[str, tuple[str, int, int]]:
    """Known column name -> (group, cable index or axis, component)."""
    cols: dict[str, tuple[str, int, int]] = {}
    for a, ax in enumerate(POSE_AXES):
        cols[f"{ax}_des"] = ("pose_des", a, 0)
        cols[f"{ax}_meas"] = ("pose_meas", a, 0)
    for k, cid in enumerate(robot.cable_ids):
        cols[f"l_cmd_{cid}"] = ("l_cmd", k, 0)
        cols[f"l_meas_{cid}"] = ("l_meas", k, 0)
        cols[f"tau_{cid}"] = ("tau", k, 0)
        for c, ax in enumerate("xyz"):
            cols[f"a{ax}_meas_{cid}"] = ("exit_meas", k, c)
    return cols


_CABLE_COL = re.compile(r"^(l_cmd|l_meas|tau|ax_meas|ay_meas|az_meas|vel|current)_(\w+)$")


def read_recording(path: str | Path) -> Recording:
    """Read and validate a recording directory (or an MCAP recording: :mod:`bench.mcap`)."""
    from bench.mcap.convert import read_recording_mcap
    from bench.mcap.reader import mcap_file
    if mcap_file(path) is not None:
        return read_recording_mcap(path)
    d, meta, robot, init_pose, samples_path = open_recording(path)
    return _read_csv(d, samples_path, robot, meta, init_pose)


def open_recording(path: str | Path) -> tuple[Path, dict, Robot, np.ndarray,
                                                Path | list[Path]]:
    """A recording directory's validated meta.toml and robot.toml: (directory, meta, robot,
    init pose, the samples file or the list of a split recording's files)."""
    d = Path(path)
    meta_path = d / "meta.toml"
    meta, text = read_toml(meta_path, RecordingError)
    if meta.get("format") != FORMAT:
        raise RecordingError(f"{meta_path}: format: expected {FORMAT!r}, got "
                             f"{meta.get('format')!r}")
    for key in ("robot", "samples", "init_pose"):
        if key not in meta:
            raise RecordingError(f"{meta_path}: {key}: missing field")
    ip = meta["init_pose"]
    if (not isinstance(ip, list) or len(ip) != 6
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in ip)):
        raise RecordingError(f"{meta_path}: init_pose: must be 6 finite numbers "
                             f"(x, y, z, roll, pitch, yaw), got {ip!r}")
    check_meta_numbers(meta, meta_path, text)
    try:
        robot = load_robot(inside_recording(d, meta, "robot", meta_path, text))
    except RobotFileError as e:
        raise RecordingError(str(e)) from e
    samples = meta["samples"]  # one file, or the files of a split recording
    if isinstance(samples, list):
        samples_path: Path | list[Path] = [
            inside_recording(d, {"samples": q}, "samples", meta_path, text) for q in samples]
    else:
        samples_path = inside_recording(d, meta, "samples", meta_path, text)
    return d, meta, robot, np.array(ip, dtype=float), samples_path


def inside_recording(d: Path, meta: dict, key: str, meta_path: Path, text: str = "") -> Path:
    """The file that meta.toml's ``key`` names, resolved inside the recording's folder
    ``d``; RecordingError naming the line and the reason when it is not a relative path
    to a regular file there (an absolute path, ``..`` out of the folder, a symbolic link
    leading out of it): a recording never makes the reader open a foreign file."""
    from controller.tomlfile import Locator

    name = meta[key]
    line = Locator(text).line(None, None, key)
    where = f"{meta_path}:{line}: {key}" if line else f"{meta_path}: {key}"
    if not isinstance(name, str) or not name:
        raise RecordingError(f"{where}: must be a file name (string) inside the recording's "
                             f"folder, got {name!r}")
    if Path(name).is_absolute():
        raise RecordingError(f"{where}: {name!r} is an absolute path; a recording names its "
                             "files relative to its own folder")
    base = d.resolve()
    target = (d / name).resolve()
    if not target.is_relative_to(base):
        raise RecordingError(f"{where}: {name!r} leads out of the recording's folder {d} "
                             "(.. or a symbolic link); a recording's files live inside it")
    if target.exists() and not target.is_file():
        raise RecordingError(f"{where}: {name!r} is not a regular file")
    return d / name


def check_meta_numbers(meta: dict, meta_path: Path, text: str = "") -> None:
    """meta.toml's numbers within their physical ranges (:mod:`controller.ranges`,
    ``recording``): the init pose, and ``rate_hz`` / ``decimate`` where written."""
    from controller.ranges import RANGES, check
    from controller.tomlfile import Locator

    loc = Locator(text)
    for key in RANGES["recording"]:
        if key not in meta:
            continue
        line = loc.line(None, None, key)
        where = f"{meta_path}:{line}: {key}" if line else f"{meta_path}: {key}"
        vals = meta[key] if isinstance(meta[key], list) else [meta[key]]
        for i, v in enumerate(vals):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise RecordingError(f"{where}: must be a number, got {v!r}")
            check("recording", key, v, where + (f"[{i}]" if len(vals) > 1 else ""),
                  RecordingError, i)


def _read_csv(d: Path, p: Path | list[Path], robot: Robot, meta: dict,
              init_pose: np.ndarray) -> Recording:
    """The samples file ``p`` (or the files of a split recording, merged in time order)."""
    paths = p if isinstance(p, list) else [p]
    if not paths:
        raise RecordingError(f"{d / 'meta.toml'}: samples: an empty list (one file name, or "
                             f"a list of the files of a split recording)")
    parts = [_read_columns(q, robot) for q in paths]
    if len(parts) == 1:
        header, col, states = parts[0]
    else:
        from bench.streams import merge_parts

        header, col, states = merge_parts(parts)
    return _from_columns(d, paths[0], robot, meta, init_pose, header, col, states)


def _read_columns(p: Path, robot: Robot) -> tuple[list[str], dict[str, np.ndarray],
                                                  list[str] | None]:
    """Header, numeric columns and ``state`` of one samples file: the columnar reader
    (:func:`bench.streams.read_columns`), else row by row (whose errors name the line)."""
    from bench.streams import read_columns

    header = _read_header(p, robot)
    fast = read_columns(p, header)
    if fast is not None:
        return header, *fast
    try:
        return _read_csv_rows(p, header)
    except UnicodeDecodeError:
        decode_utf8(p.read_bytes(), p, RecordingError)  # raises, naming line and column
        raise
    except csv.Error as e:
        raise RecordingError(f"{p}: not readable as CSV: {e}") from None


def _read_header(p: Path, robot: Robot) -> list[str]:
    """The validated header row of ``p`` (names stripped)."""
    try:  # (utf-8-sig: a byte-order mark, as spreadsheet programs write, is no part of 't')
        f = p.open(newline="", encoding="utf-8-sig")
    except OSError as e:
        raise RecordingError(f"{p}: cannot read: {e.strerror or e}") from e
    with f:
        try:
            header = [h.strip() for h in next(csv.reader(f))]
        except StopIteration:
            raise RecordingError(f"{p}:1: empty file (no header)") from None
        except UnicodeDecodeError:
            decode_utf8(p.read_bytes(), p, RecordingError)
            raise
        except csv.Error as e:
            raise RecordingError(f"{p}: not readable as CSV: {e}") from None
    if "t" not in header:
        raise RecordingError(f"{p}:1: {_no_time(header)}")
    seen = set()
    for c, name in enumerate(header):
        if name in seen:
            raise RecordingError(f"{p}:1: column {c + 1} '{name}': duplicate column")
        seen.add(name)
    known = _column_groups(robot)
    for c, name in enumerate(header):
        m = _CABLE_COL.match(name)
        if m and name not in known and m.group(2) not in robot.cable_ids:
            raise RecordingError(
                f"{p}:1: column {c + 1} '{name}': cable {m.group(2)!r} is not in the robot "
                f"(cables: {', '.join(robot.cable_ids)})")
    return header


def _no_time(header: list[str]) -> str:
    """Why a first line without a column ``t`` is no header row (names the line's start)."""
    first = ",".join(header)
    shown = first if len(first) <= 60 else first[:57] + "..."
    if first.lstrip().startswith("#"):
        return (f"the first line must be the header row naming the columns (t, ...), got "
                f"the comment {shown!r}: comment lines are not part of the format")
    sep = next((c for c in (";", "\t", "|") if len(header) == 1 and c in first), None)
    if sep is not None:
        return (f"column 't' (time) is missing from the header row ({shown!r}): its fields "
                f"are separated by {sep!r}; the format separates them by ','")
    return f"column 't' (time) is missing from the header row ({shown!r})"


def _read_csv_rows(p: Path, header: list[str], text: str | None = None, first_line: int = 2
                   ) -> tuple[list[str], dict[str, np.ndarray], list[str] | None]:
    """Row by row (errors name the line and column): header, columns, states. With ``text``
    (a block of data lines of ``p`` whose first is line ``first_line``) that block only."""
    with (p.open(newline="", encoding="utf-8") if text is None
          else io.StringIO(text, newline="")) as f:
        reader = csv.reader(f)
        if text is None:
            next(reader)
        rows: list[list[float]] = []
        lines: list[int] = []
        states: list[str] = []
        state_col = header.index("state") if "state" in header else -1
        numeric = [c for c, name in enumerate(header) if c != state_col]
        loose = {header.index(h) for h in loose_columns(header)}
        for lineno, row in enumerate(reader, start=first_line):
            if not row or all(not x.strip() for x in row):
                continue
            if len(row) != len(header):
                raise RecordingError(f"{p}:{lineno}: {len(row)} fields, the header has "
                                     f"{len(header)}{_torn(p, text, reader.line_num)}")
            vals = []
            for c in numeric:
                s = row[c].strip()
                if s == "" or s.lower() == "nan":
                    vals.append(math.nan)
                    continue
                try:
                    v = float(s)
                except ValueError:
                    if c in loose:  # the lab's own column: kept and ignored
                        vals.append(math.nan)
                        continue
                    raise RecordingError(f"{p}:{lineno}: column {c + 1} '{header[c]}': not a "
                                         f"number: {s!r}") from None
                if math.isinf(v) and c not in loose:
                    raise RecordingError(f"{p}:{lineno}: column {c + 1} '{header[c]}': "
                                         f"infinite value")
                vals.append(v)
            rows.append(vals)
            lines.append(lineno)
            if state_col >= 0:
                states.append(row[state_col].strip())
    names = [header[c] for c in numeric]
    data = np.array(rows, dtype=float).reshape(len(rows), len(names))
    if not len(rows):
        raise RecordingError(f"{p}: no samples")
    t = data[:, names.index("t")]
    if np.isnan(t).any():
        line = int(np.flatnonzero(np.isnan(t))[0]) + first_line
        raise RecordingError(f"{p}:{line}: column {header.index('t') + 1} 't': time missing")
    back = time_goes_back(t)
    if back is not None:
        raise RecordingError(f"{p}:{lines[back]}: "
                             f"{time_back_message(header, t[back - 1], lines[back - 1], t[back])}")
    return header, {name: data[:, k] for k, name in enumerate(names)}, \
        (states if state_col >= 0 else None)


def _torn(p: Path, text: str | None, line_num: int) -> str:
    """A note when the row just read (the ``line_num``-th line of the file, or of ``text``,
    a block of its lines) is the last and has no line end (a logger stopped while writing
    it), else ''. (A block ends at a line end, but for the file's last.)"""
    try:
        data = text.encode() if text is not None else p.read_bytes()
    except OSError:
        return ""
    if data.endswith((b"\n", b"\r")) or data.count(b"\n") + 1 != line_num:
        return ""
    return (": the last line is cut short and has no line end (the logger stopped while "
            "writing it?); delete that line to read the rest")


def _from_columns(d: Path, p: Path, robot: Robot, meta: dict, init_pose: np.ndarray,
                  header: list[str], col: dict[str, np.ndarray],
                  states: list[str] | None) -> Recording:
    """The Recording of parsed columns (name -> (N,) floats, NaN = no value)."""
    N, n = len(col["t"]), robot.n_cables
    if N == 0:
        raise RecordingError(f"{p}: no samples")
    known = _column_groups(robot)
    t = col["t"]
    groups = {
        "pose_des": np.full((N, 6), np.nan), "pose_meas": np.full((N, 6), np.nan),
        "l_cmd": np.full((N, n), np.nan), "l_meas": np.full((N, n), np.nan),
        "tau": np.full((N, n), np.nan), "exit_meas": np.full((N, n, 3), np.nan),
    }
    extra = {}
    for name, values in col.items():
        if name == "t":
            continue
        if name in known:
            g, k, c = known[name]
            if g == "exit_meas":
                groups[g][:, k, c] = values
            else:
                groups[g][:, k] = values
        else:
            extra[name] = values
    rec = Recording(d, robot, meta, init_pose, t, groups["pose_des"], groups["pose_meas"],
                    groups["l_cmd"], groups["l_meas"], groups["tau"], groups["exit_meas"],
                    states, extra)
    rec.init_rows = _init_rows(rec)
    return rec


def _init_rows(rec: Recording) -> np.ndarray:
    """Rows taken at initialisation: those before the first row where the platform leaves
    init_pose (by the desired pose if recorded, else by the encoders or the measured pose,
    whichever shows it first: :func:`_left_by_encoders`, :func:`_left_by_tracker`).

    ``init_pose`` is the *measured* pose; a controller may log as its desired pose at
    initialisation the nominal target it stands at (7.5 m where the tracker read 7.50002):
    where the first row's desired pose is within :data:`INIT_NEAR` of ``init_pose``, the
    platform leaves when the desired pose leaves that first row's."""
    if rec.has("pose_des"):
        first = rec.pose_des[0]
        seen = np.isfinite(first)  # (columns a recording leaves out are nan)
        near = seen.any() and np.all(np.abs(first - rec.init_pose)[seen] <= INIT_NEAR)
        # (a row without a desired pose (NaN) shows no sign of leaving; np.nanmax would
        # warn "All-NaN slice encountered" on such rows)
        off = np.max(np.nan_to_num(np.abs(rec.pose_des - (first if near else rec.init_pose)),
                                   nan=0.0), axis=1) > INIT_TOL_DES
        leave = np.flatnonzero(off)
        return np.flatnonzero(rec.t < rec.t[leave[0]]) if len(leave) \
            else np.arange(rec.n_samples)
    # without a desired pose: the encoders leave first (their noise is micrometres), the
    # tracker's pose where they cannot tell (no encoders); the earlier of the two
    leaves = [t for t in (_left_by_encoders(rec), _left_by_tracker(rec)) if t is not None]
    if not leaves and not (rec.has("pose_meas") or rec.has("l_meas")):
        return np.zeros(0, dtype=int)
    if not leaves:
        return np.arange(rec.n_samples)
    return np.flatnonzero(rec.t < min(leaves))


def _left_by_tracker(rec: Recording) -> float | None:
    """Time [s] of the first row whose measured pose is farther than :data:`INIT_TOL_MEAS`
    from ``init_pose``; None without a tracker or where it never is."""
    if not rec.has("pose_meas"):
        return None
    with np.errstate(invalid="ignore"):  # rows without a fix (NaN): no sign of leaving
        off = np.max(np.nan_to_num(np.abs(rec.pose_meas - rec.init_pose), nan=0.0),
                     axis=1) > INIT_TOL_MEAS
    leave = np.flatnonzero(off)
    return float(rec.t[leave[0]]) if len(leave) else None


#: rows [s] from the first on whose encoder readings are the initialisation's reference ...
INIT_REF_S = 1.0
#: ... and consecutive rows that must all stand off it for the platform to have left
INIT_LEFT_ROWS = 3
#: [m] a reading's change always within its resolution (encoders without noise)
INIT_FLOOR_M = 1e-6


def _left_by_encoders(rec: Recording) -> float | None:
    """Time [s] of the first row from which :data:`INIT_LEFT_ROWS` rows in a row have an
    encoder reading off the initialisation's: off the median of the readings of the first
    :data:`INIT_REF_S` by more than their own white noise reaches over the rows
    (``sqrt(2 ln N) + 3`` standard deviations, :func:`bench.streams.signal_noise` on those
    first rows; at least :data:`INIT_FLOOR_M`). A slip as the platform leaves moves them too,
    and the rows before it are the initialisation's. None without encoders, with fewer than
    five reference rows, or where the readings never leave."""
    cols = np.isfinite(rec.l_meas).any(axis=0)
    if not cols.any():
        return None
    rows = np.flatnonzero(np.isfinite(rec.l_meas[:, cols]).all(axis=1))
    if len(rows) < 5 + INIT_LEFT_ROWS:
        return None
    x, t = rec.l_meas[rows][:, cols], rec.t[rows]
    ref = t <= t[0] + INIT_REF_S
    if ref.sum() < 5:
        return None
    sd = signal_noise(t[ref], x[ref])
    limit = np.maximum((np.sqrt(2.0 * np.log(len(rows))) + 3.0) * sd, INIT_FLOOR_M)
    off = (np.abs(x - np.median(x[ref], axis=0)) > limit).any(axis=1)
    run = np.convolve(off.astype(int), np.ones(INIT_LEFT_ROWS, dtype=int), "valid")
    left = np.flatnonzero(run == INIT_LEFT_ROWS)
    return float(t[left[0]]) if len(left) else None


def write_header_files(d: Path, robot: Robot, init_pose: np.ndarray,
                       meta: dict[str, Any] | None = None, robot_header: str = "") -> dict:
    """Write ``meta.toml`` and ``robot.toml`` of a recording directory ``d``; the meta."""
    d.mkdir(parents=True, exist_ok=True)
    m = {"format": FORMAT, "robot": "robot.toml", "samples": "recording.csv",
         "init_pose": [float(v) for v in init_pose], "pose_source": "laser tracker",
         "tension_source": "load cells"}
    m.update(meta or {})
    _write_atomic(d / "robot.toml", dumps_robot(robot, robot_header))
    _write_atomic(d / "meta.toml", tomli_w.dumps(m))
    return m


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _cell(v: float) -> str:
    return repr(float(v)) if math.isfinite(v) else "nan"


class BackgroundWriter:
    """A file written while a run goes: items are queued by the caller (cheap, never blocks
    on the disk) and written by a background thread at least every ``flush_s`` seconds;
    :meth:`close` writes the rest. A subclass opens ``self._f``, calls :meth:`_start` and
    defines :meth:`_write` (items to the file, flushed: the file reads up to there after a
    crash) and optionally :meth:`_finish` (what :meth:`close` writes after the rest).
    A write error is raised by the next :meth:`_queue_item`, :meth:`flush` or :meth:`close`."""

    path: Path
    _f: Any

    def _start(self, flush_s: float, name: str) -> None:
        self.flush_s = float(flush_s)
        # (a deque, appended here and emptied from the left by the thread, needs no lock: a
        # Ctrl-C's exception raised just after a lock's acquisition could leave it held and
        # the close waiting for the thread for ever)
        self._queue: deque[tuple] = deque()
        self._appended = 0
        self._written = 0
        self._wake = threading.Event()
        self._closed = False  # (the thread is asked to end)
        self._done = False  # (the rest written, the file closed)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _write(self, items: list[tuple]) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        return None

    def _check(self) -> None:
        if self._error is not None:
            raise OSError(f"{self.path}: writing failed: {self._error}") from self._error

    def _queue_item(self, item: tuple, check: bool = True) -> None:
        if check:
            self._check()
        self._queue.append(item)
        self._appended += 1

    def _write_taken(self) -> None:
        items = [self._queue.popleft() for _ in range(len(self._queue))]
        self._write(items)
        self._written += len(items)

    def _run(self) -> None:
        while not self._closed:
            self._wake.wait(self.flush_s)
            self._wake.clear()
            try:
                self._write_taken()
            except BaseException as e:  # disk full, ...: reported by the next call
                self._error = e
                return

    def flush(self) -> None:
        """Write what is queued now (blocks until it is on disk or the writer failed)."""
        target = self._appended
        self._wake.set()
        while self._written < target and self._thread.is_alive():
            time.sleep(0.002)
        self._check()

    def close(self) -> None:
        """Write the rest and close the file (idempotent; a close that a Ctrl-C interrupted
        while it waited for the writer thread is done whole by the next call)."""
        if self._done:
            return
        self._closed = True
        self._wake.set()
        self._thread.join()
        self._done = True
        try:
            if self._error is None:
                self._write_taken()
                self._finish()
        finally:
            self._f.close()
        self._check()


class CsvStream(BackgroundWriter):
    """A CSV file written while a run goes (:class:`BackgroundWriter`): rows are queued by
    :meth:`append` and written in small chunks so that a real-time loop in the same
    process keeps the interpreter. After a crash the file holds every row up to the last
    flush, each row whole."""

    def __init__(self, path: Path, header: list[str], flush_s: float = 1.0) -> None:
        self.path = path
        self.rows = 0  #: rows written to the file so far
        self._f = path.open("w", newline="", encoding="utf-8")
        self._f.write(",".join(header) + "\n")
        self._f.flush()
        self._start(flush_s, f"csv-{path.name}")

    def append(self, row: tuple) -> None:
        """Queue one row (already in column order: numbers, or strings kept as they are)."""
        self._queue_item(row)

    def _write(self, rows: list[tuple], chunk: int = 25) -> None:
        f = self._f
        for i in range(0, len(rows), chunk):
            lines = []
            for row in rows[i:i + chunk]:
                lines.append(",".join(v if isinstance(v, str) else _cell(v) for v in row))
            f.write("\n".join(lines) + "\n")
            time.sleep(0)  # let a real-time loop run between chunks
        f.flush()
        self.rows += len(rows)


class RecordingWriter:
    """A ``cdpr-recording/1`` directory written while the run goes.

    ``meta.toml`` and ``robot.toml`` first, then ``recording.csv`` with the header
    ``columns`` (``t`` first) and, when ``states``, a ``state`` column; rows are appended
    with :meth:`append` and flushed at least every ``flush_s`` seconds (wall clock) by a
    background thread, so that after a crash or Ctrl-C the directory is a valid recording
    up to the last flushed row. Memory stays bounded by one flush interval of rows.
    :meth:`update_meta` rewrites ``meta.toml`` atomically (e.g. notes at the end).
    """

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray,
                 columns: list[str], meta: dict[str, Any] | None = None,
                 robot_header: str = "", states: bool = True, flush_s: float = 1.0) -> None:
        if not columns or columns[0] != "t":
            raise ValueError("the first column must be 't'")
        self.path = Path(path)
        self.columns = list(columns)
        self.states = states
        self.meta = write_header_files(self.path, robot, init_pose, meta, robot_header)
        header = self.columns + (["state"] if states else [])
        self._csv = CsvStream(self.path / "recording.csv", header, flush_s)

    @property
    def rows(self) -> int:
        """Rows written to disk so far."""
        return self._csv.rows

    def append(self, values: np.ndarray | list[float], state: str | None = None) -> None:
        """One row: ``values`` in column order; ``state`` when the recording has the column."""
        row = tuple(float(v) for v in values)
        if len(row) != len(self.columns):
            raise ValueError(f"{len(row)} values for {len(self.columns)} columns")
        self._csv.append(row + ((state or "",) if self.states else ()))

    def update_meta(self, **fields: Any) -> None:
        self.meta.update(fields)
        _write_atomic(self.path / "meta.toml", tomli_w.dumps(self.meta))

    def flush(self) -> None:
        self._csv.flush()

    def close(self) -> None:
        self._csv.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_recording(path: str | Path, robot: Robot, init_pose: np.ndarray,
                    columns: dict[str, np.ndarray], meta: dict[str, Any] | None = None,
                    robot_header: str = "", states: list[str] | None = None) -> Path:
    """Write a recording directory: ``columns`` maps column names (``t`` first) to (N,) arrays."""
    names = list(columns)
    if not names or names[0] != "t":
        raise ValueError("the first column must be 't'")
    arrays = np.column_stack([np.asarray(columns[k], dtype=float) for k in names])
    with RecordingWriter(path, robot, init_pose, names, meta, robot_header,
                         states=states is not None, flush_s=3600.0) as w:
        for i, row in enumerate(arrays):
            w.append(row, states[i] if states is not None else None)
    return Path(path)
