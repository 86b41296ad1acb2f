"""What a dry run writes while it goes: a ``cdpr-recording/1`` directory plus an events file.

``recording.csv`` columns (the recording format's names; extra columns are allowed):

- ``t`` [s] the loop's clock (the hardware's, from the run's start): of the cycle on a
  cycle's row, of the sample on a sample's row (below);
- ``x_des`` .. ``yaw_des`` the trajectory's setpoint pose of the cycle;
- ``l_cmd_{ij}`` [m] the lengths sent; ``l_meas_{ij}`` [m] the drives' lengths read (both in
  the encoder reference of the initialisation);
- ``tau_{ij}`` [N] the load cells' tensions as read (``nan`` when not valid);
- ``x_meas`` .. ``yaw_meas`` the tracker's pose;
- extra: ``plan_tau_{ij}`` [N] the tensions the controller planned, ``substituted`` the
  number of load cells replaced by planned tensions in the mast update, ``cycle`` the
  repetition of the path (0, 1, ...; -1 before the path starts), ``overruns`` the cycles
  that missed their deadline so far (real time), ``pose_err`` [m] the distance from the
  tracker's fix to the commanded path on the fix's row where the loop counted it (the
  numbers the summary's ``pose_error_rms_m``/``pose_error_max_m`` are made of; ``nan`` on
  the other rows and for fixes not counted: initialisation, quick stop),
  ``drive_state_{ij}`` the CiA 402 state of each drive as the master read it on the row
  (:class:`hal.drives_cia402.DriveState` number: 4 Operation Enabled, 5 Quick Stop Active,
  7 Fault, 8 unknown, ...; ``nan`` when not given);
- ``state``: ``init`` (initialisation dwell), ``approach`` (the move from the init pose to
  the path's start), ``move``/``dwell`` (the trajectory's labels: a dwell stands at a
  target; replicate visits have equal ``*_des``), ``hold`` (feed hold), ``quick_stop``
  (drives stopped), ``end`` (final stand-still).

Each sensor's sample is recorded once, at the time it was taken on the loop's clock (the
recording format's sensor streams: a row whose group is ``nan`` holds no sample of it):

- encoders: a new sample only (a cycle on which no TPDO came since the last row holds the
  sample already recorded: not written again), at the SYNC their positions answer
  (``Readings.lengths_t_s``: the SYNC each drive's count of TPDOs gives, never after the
  last SYNC sent before its TPDO came, see :mod:`hal.sync_count`; the drives' positions
  at one SYNC, ``Readings.sample_lengths_m``, the latest all of them answered, where
  their latest answer different SYNCs; in lock-step the cycle's own, on its row; in real
  time usually the SYNC before, on a row of its own);
- the tracker: a new fix only (a fix read again on a later row is not written again), at
  its own time stamp where the tracker says that is the hardware's clock
  (``Tracker.on_hardware_clock``: the in-process simulated tracker in lock-step, a
  ``cdpr-tracker/1.1`` tracker greeting with ``clock=drives``), else at the time it was
  taken where the tracker's clock is its own with an estimated offset
  (``TrackerReading.taken_age_s``, ``clock=own``), else at the time it arrived (the loop's
  time less ``TrackerReading.age_s``);
- the load cells: a new sample only, at the loop's time less its age
  (``Readings.tension_age_s``, the mean over the cables).

(:class:`SampleTimes` applies these rules to a cycle's readings.)

A sample taken before its cycle is a row of its own at its time (or joins a row of that
time) holding the controller's columns (setpoints, planned tensions, ``substituted``,
``cycle``, ``overruns``, drive states) and the ``state`` of the row before it; rows wait
:data:`HOLD_S` to be written in time order.

``events.csv``: ``t, device, address, cable, kind, code, reaction, active, text``: every
supervisor condition when it starts (``active`` 1) and ends (0), the hardware's own events
(EMCY, heartbeat, load-cell status changes; reaction ``event``) and the loop's (start, end,
interruption). Both files are flushed at least every second; after a crash or Ctrl-C the
directory is a valid recording up to the last flushed row.
"""

from __future__ import annotations

import bisect
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench.recording import POSE_AXES, CsvStream, RecordingWriter
from controller.robot import Robot

if TYPE_CHECKING:
    from hal.interface import Readings
    from hal.tracker import Tracker, TrackerReading

EVENT_COLUMNS = ["t", "device", "address", "cable", "kind", "code", "reaction", "active",
                 "text"]


def columns(robot: Robot) -> list[str]:
    """The recording's numeric columns in order (``t`` first)."""
    c = robot.cable_ids
    return (["t"] + [f"{a}_des" for a in POSE_AXES] + [f"l_cmd_{k}" for k in c]
            + [f"l_meas_{k}" for k in c] + [f"tau_{k}" for k in c]
            + [f"{a}_meas" for a in POSE_AXES] + [f"plan_tau_{k}" for k in c]
            + ["substituted", "cycle", "overruns", "pose_err"]
            + [f"drive_state_{k}" for k in c])


def held_columns(n: int) -> np.ndarray:
    """The indices of :func:`columns` (``n`` cables) that hold their value from one cycle
    to the next: the setpoints, planned tensions, ``substituted``, ``cycle``,
    ``overruns`` and the drives' states (not the sensors' samples, not ``pose_err``)."""
    return np.r_[1:7 + n, 13 + 3 * n:16 + 4 * n, 17 + 4 * n:17 + 5 * n]


def sample_groups(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The indices of :func:`columns` (``n`` cables) of each sensor's sample: the encoders'
    lengths, the load cells' tensions, the tracker's pose and its ``pose_err``."""
    return (np.r_[7 + n:7 + 2 * n], np.r_[7 + 2 * n:7 + 3 * n],
            np.r_[7 + 3 * n:13 + 3 * n, 16 + 4 * n])


def event_cells(t: float, device: str, address: int, cable: str, kind: str, code: int,
                reaction: str, active: bool, text: str) -> tuple[str, ...]:
    """The fields of an ``events.csv`` row, as written."""
    t_txt = f"{float(t):.6f}".rstrip("0").rstrip(".")  # microseconds, no float noise
    return (t_txt, device, str(int(address)), cable, kind, f"0x{int(code):04X}",
            reaction, "1" if active else "0", '"' + text.replace('"', "'") + '"')


#: what ``--record DIR`` writes: the CSV directory, ``DIR/recording.mcap``, or both
FORMATS = ("csv", "mcap", "both")


def open_recorder(path: str | Path | None, robot: Robot, init_pose: np.ndarray, meta: dict,
                  robot_header: str = "", fmt: str = "csv", flush_s: float = 1.0,
                  can: str | None = None, live: str | None = None, child=None):
    """The recorder of a run in ``fmt`` (:data:`FORMATS`; MCAP: :mod:`bench.mcap`, which
    also records every frame of the ``can`` bus, a ``--can`` spec, when given); with
    ``live`` (``HOST:PORT``) also shown live in Foxglove (:mod:`bench.mcap.live`; with the
    ``can`` bus's frames on ``/can``), and only that when ``path`` is None. ``child`` (a
    real-time run: a :class:`bench.mcap.child.Spawned` process): the MCAP recording and
    the live view are written and served by that child process (the CSV directory stays
    in this one); None: here (lock-step: in the order of the simulated bus)."""
    if fmt not in FORMATS:
        raise ValueError(f"record format {fmt!r}: one of {', '.join(FORMATS)}")
    mcap = path is not None and fmt != "csv"
    if child is not None and (mcap or live is not None):
        return _in_child(child, path, robot, init_pose, meta, robot_header, fmt, flush_s,
                         can, live)
    view = None
    if live is not None:  # one tap of the bus: the MCAP recording's when there is one
        from bench.mcap.live import live_recorder

        view = live_recorder(live, robot, init_pose, can=None if mcap else can)
    try:
        rec = None
        if path is not None and not mcap:
            rec = DryRunRecorder(path, robot, init_pose, meta, robot_header, flush_s)
        elif mcap:
            from bench.mcap.recorders import dry_run_recorder

            also = (view.writer.can_frame,) if view is not None else ()
            rec = dry_run_recorder(path, robot, init_pose, meta, robot_header, flush_s, fmt,
                                   can, also)
    except BaseException:
        if view is not None:
            view.close()
        raise
    if view is None or rec is None:
        return view if rec is None else rec
    from bench.mcap.recorders import TeeRecorder

    return TeeRecorder(rec, view)


def _in_child(child, path: str | Path | None, robot: Robot, init_pose: np.ndarray,
              meta: dict, robot_header: str, fmt: str, flush_s: float, can: str | None,
              live: str | None):
    """:func:`open_recorder` with ``child``: the CSV directory (``fmt`` csv or both) here,
    first (its directory must be empty), the MCAP recording and the live view in the
    child process (:func:`bench.mcap.recorders.process_recorder`)."""
    from bench.mcap.recorders import TeeRecorder, process_recorder

    csv_rec = (DryRunRecorder(path, robot, init_pose, meta, robot_header, flush_s)
               if path is not None and fmt in ("csv", "both") else None)
    try:
        rec = process_recorder(path if fmt != "csv" else None, robot, init_pose, meta,
                               robot_header, flush_s, can, live, child)
    except BaseException:
        if csv_rec is not None:
            csv_rec.close()
        raise
    return rec if csv_rec is None else TeeRecorder(csv_rec, rec)


class CsvRecording:
    """A ``cdpr-recording/1`` directory ``path`` written while a run goes (created; must be
    empty or absent): the rows' :class:`~bench.recording.RecordingWriter` and ``events.csv``
    (:data:`EVENT_COLUMNS`)."""

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray,
                 cols: list[str], meta: dict, states: bool, flush_s: float = 1.0,
                 robot_header: str = "") -> None:
        self.path = Path(path)
        self.writer = RecordingWriter(self.path, robot, init_pose, cols, meta, robot_header,
                                      states=states, flush_s=flush_s)
        self.events = CsvStream(self.path / "events.csv", EVENT_COLUMNS, flush_s)

    @property
    def rows(self) -> int:
        return self.writer.rows

    def event(self, t: float, device: str, address: int, cable: str, kind: str, code: int,
              reaction: str, active: bool, text: str) -> None:
        self.events.append(event_cells(t, device, address, cable, kind, code, reaction, active,
                                       text))

    def update_meta(self, **fields) -> None:
        self.writer.update_meta(**fields)

    def close(self) -> None:
        try:
            self.writer.close()
        finally:
            self.events.close()


#: [s] how long a row waits for the samples taken before it (a sample arrives after its
#: time: a TPDO a cycle later, a tracker fix or a load cell's answer up to their staleness
#: limits, 0.5 s for :class:`hal.tracker.TcpTracker`); a sample older than the rows
#: already written goes into the oldest row it still can (counted: ``late_samples``)
HOLD_S = 0.5


class TimeOrder:
    """Rows waiting :data:`HOLD_S` to be written in time order: the loop's cycle rows and
    the samples stamped with their own (earlier) times. A sample at a time already held
    joins that row where its columns are empty; a sample's own row takes the state and the
    ``held`` columns (indices: the controller's, which hold until the next cycle) of the
    row before it (before the first cycle row: the held columns of that one, state
    ``init``)."""

    def __init__(self, append, held: np.ndarray | None = None) -> None:
        self.append = append  # (values, state) -> None: the writer's
        self.held = np.zeros(0, int) if held is None else held
        self._last: np.ndarray | None = None  # the last row written
        self._t: list[float] = []
        self._rows: list[tuple[np.ndarray, str | None]] = []
        self.written_t = -np.inf  #: [s] the time of the last row written
        self._state = "init"
        self.late = 0  #: samples older than the rows written (moved to the oldest)

    def place(self, t: float, values: np.ndarray, state: str | None,
              cols: np.ndarray) -> None:
        """Hold ``values`` (a whole row: nan outside the indices ``cols``) at ``t`` [s]."""
        if t < self.written_t:
            t, self.late = self.written_t, self.late + 1
            values = values.copy()
            values[0] = t
        i = bisect.bisect_left(self._t, t)
        while i < len(self._t) and self._t[i] == t:
            row, st = self._rows[i]
            if np.all(np.isnan(row[cols])):
                row[cols] = values[cols]
                if st is None:
                    self._rows[i] = (row, state)
                return
            i += 1
        self._t.insert(i, t)
        self._rows.insert(i, (values.copy(), state))

    def flush(self, until: float = np.inf) -> None:
        """Write the rows held up to ``until`` [s] (all by default)."""
        k = bisect.bisect_right(self._t, until)
        for t, (row, state) in zip(self._t[:k], self._rows[:k], strict=True):
            if state is None:  # a sample's own row (before the first cycle: the first's)
                like = self._last if self._last is not None else next(
                    (r for r, st in self._rows if st is not None), None)
                if like is not None:
                    row[self.held] = like[self.held]
            self._state = state if state is not None else self._state
            self.append(row, self._state)
            self.written_t, self._last = t, row
        del self._t[:k], self._rows[:k]


class SampleTimes:
    """When each sensor's sample read on a cycle was taken, on the recording's clock (the
    hardware interface's less ``t0`` [s]), and whether it is new (a sample is recorded
    once): the module docstring's rules. ``tracker``: its ``on_hardware_clock`` says
    whether its fixes' time stamps are on the hardware's clock. Per run (it remembers the
    last fix, encoder and load-cell sample)."""

    def __init__(self, t0: float, tracker: Tracker) -> None:
        self.t0 = float(t0)
        self.tracker = tracker
        self._fix_t = -np.inf  # the last new fix's key [s] (:meth:`_fix_key`)
        self._tau_t = -np.inf  # the load cells' sample recorded last [s]
        self._len_t = math.nan  # the SYNC of the encoders' sample recorded last [s]

    def lengths(self, r: Readings, t: float) -> tuple[np.ndarray, float | None]:
        """The encoders' sample: the drives' lengths [m] at one SYNC
        (``Readings.sample_lengths_m``, else ``lengths_m``) and that SYNC's time [s]
        (``Readings.lengths_t_s``; None: not known, the row's ``t``; never after ``t``), or
        ``nan`` lengths when they answer the SYNC already recorded (no TPDO came since: the
        sample already recorded, not written again at its time). A sample is new when its
        SYNC differs from the last one recorded (drives whose time is not known: every
        reading)."""
        lengths = r.lengths_m if r.sample_lengths_m is None else r.sample_lengths_m
        ts = r.lengths_t_s - self.t0
        if not math.isfinite(ts):
            return lengths, None
        if ts == self._len_t:
            return np.full(len(lengths), np.nan), None
        self._len_t = ts
        return lengths, min(ts, t)

    def fix(self, tr: TrackerReading, t: float) -> float | None:
        """The time [s] of the tracker's fix ``tr`` read at ``t``, None when it is not a
        new valid one: its own time stamp where the tracker says it is on the hardware's
        clock (``Tracker.on_hardware_clock``) and that stamp is not after ``t`` (a stamp
        ahead of the read is on another clock: drives that counted another master's
        SYNCs), else ``t`` less the time since it was taken (``taken_age_s``: a tracker
        on its own clock with an estimated offset) or, where that is not known, since it
        arrived (``age_s``); never after ``t``."""
        if not (tr.valid and np.all(np.isfinite(tr.pose))):
            return None
        key = self._fix_key(tr, t)
        if key == self._fix_t:
            return None
        self._fix_t = key
        if getattr(self.tracker, "on_hardware_clock", False):
            ts = tr.t_s - self.t0
            if ts <= t + 1e-9:  # [s] the times' rounding
                return min(t, ts)
        age = tr.taken_age_s if math.isfinite(tr.taken_age_s) else tr.age_s
        return t - max(0.0, age) if math.isfinite(age) else t

    @staticmethod
    def _fix_key(tr: TrackerReading, t: float) -> float:
        """What tells one fix from the next [s]: its own time stamp, or, a tracker that gives
        none, its arrival (``t`` less ``age_s``, to the microsecond). A fix is new when its
        key differs from the last one's, not only when it is later: a tracker restarted (its
        own clock from zero again) goes on being recorded."""
        if math.isfinite(tr.t_s):
            return float(tr.t_s)
        return round(t - tr.age_s, 6) if math.isfinite(tr.age_s) else t

    def tensions(self, r: Readings, t: float) -> tuple[np.ndarray, float]:
        """The load cells' tensions [N] and the time [s] they were sampled (``t`` less the
        mean age of the valid ones, on the hardware's clock), or ``nan`` when they are the
        sample already recorded (no new sample)."""
        age = r.tension_age_s[np.isfinite(r.tension_age_s)]
        if not age.size:
            return r.tensions_N, t
        ts = t - float(np.mean(age))
        if ts <= self._tau_t + 1e-6:  # the same sample (its age grew with t)
            return np.full(len(r.tensions_N), np.nan), t
        self._tau_t = ts
        return r.tensions_N, min(ts, t)


class DryRunRecorder(CsvRecording):
    """Rows and events of a run into ``path`` (created; must be empty or absent)."""

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray, meta: dict,
                 robot_header: str = "", flush_s: float = 1.0) -> None:
        super().__init__(path, robot, init_pose, columns(robot), meta, True, flush_s,
                         robot_header)
        self.n = robot.n_cables
        self.order = TimeOrder(self.writer.append, held_columns(self.n))
        self._groups, self._all = sample_groups(self.n), np.arange(len(self.writer.columns))

    def row(self, t: float, pose_des: np.ndarray, l_cmd: np.ndarray, l_meas: np.ndarray,
            tau: np.ndarray, pose_meas: np.ndarray, tau_plan: np.ndarray, substituted: int,
            cycle: int, overruns: int, state: str, pose_err: float = float("nan"),
            drive_states: np.ndarray | None = None, lengths_t: float | None = None,
            tensions_t: float | None = None, pose_t: float | None = None) -> None:
        """The cycle's row at ``t`` [s] (:func:`columns`) and each sensor's sample at the
        time it was taken on the loop's clock (``lengths_t``: the SYNC the encoders
        answer, ``tensions_t`` the load cells' sample, ``pose_t`` the tracker's fix;
        None: ``t``): a sample taken before ``t`` is a row of its own (the other columns
        ``nan``), or joins a row of its time. All-``nan`` ``tau`` or ``pose_meas``: no
        sample. ``drive_states``: the CiA 402 state numbers of the drives in cable order
        (None: ``nan``)."""
        n = self.n
        t = round(t, 9)  # [s] to the nanosecond: no float noise in the file's times
        r = np.full(len(self.writer.columns), np.nan)
        r[0] = t
        r[1:7] = pose_des
        r[7:7 + n] = l_cmd
        r[13 + 3 * n:13 + 4 * n] = tau_plan
        r[13 + 4 * n:16 + 4 * n] = (substituted, cycle, overruns)
        r[17 + 4 * n:17 + 5 * n] = np.nan if drive_states is None else drive_states
        own = []
        enc, cells, fix = self._groups
        for cols, vals, ts in ((enc, l_meas, lengths_t), (cells, tau, tensions_t),
                               (fix, (*pose_meas, pose_err), pose_t)):
            ts = None if ts is None else round(ts, 9)
            if ts is None or not ts < t:
                r[cols] = vals
            elif not np.all(np.isnan(vals)):
                own.append((ts, cols, vals))
        self.order.place(t, r, state, self._all)
        for ts, cols, vals in own:
            s = np.full(len(r), np.nan)
            s[0], s[cols] = ts, vals
            self.order.place(ts, s, None, cols)
        self.order.flush(t - HOLD_S)

    def close(self) -> None:
        try:
            self.order.flush()
            if self.order.late:
                self.writer.update_meta(late_samples=self.order.late)
        finally:
            super().close()
