"""What a dry run writes while it goes: a ``cdpr-recording/1`` directory plus an events file.

``recording.csv`` columns (the recording format's names; extra columns are allowed):

- ``t`` [s] the hardware clock of the cycle;
- ``x_des`` .. ``yaw_des`` the trajectory's setpoint pose of the cycle;
- ``l_cmd_{ij}`` [m] the lengths sent; ``l_meas_{ij}`` [m] the drives' lengths read (both in
  the encoder reference of the initialisation);
- ``tau_{ij}`` [N] the load cells' tensions as read (``nan`` when not valid);
- ``x_meas`` .. ``yaw_meas`` the tracker's pose (``nan`` when it has none);
- extra: ``plan_tau_{ij}`` [N] the tensions the controller planned, ``substituted`` the
  number of load cells replaced by planned tensions in the mast update, ``cycle`` the
  repetition of the path (0, 1, ...; -1 before the path starts), ``overruns`` the cycles
  that missed their deadline so far (real time), ``pose_err`` [m] the distance from the
  tracker's fix to the commanded path on the rows where the loop counted a new fix (the
  numbers the summary's ``pose_error_rms_m``/``pose_error_max_m`` are made of; ``nan`` on
  the other rows: a fix held from an earlier row, no fix, or not counted: initialisation,
  quick stop), ``drive_state_{ij}`` the CiA 402 state of each drive as the master read it
  on the row (:class:`hal.drives_cia402.DriveState` number: 4 Operation Enabled, 5 Quick
  Stop Active, 7 Fault, 8 unknown, ...; ``nan`` when not given);
- ``state``: ``init`` (initialisation dwell), ``approach`` (the move from the init pose to
  the path's start), ``move``/``dwell`` (the trajectory's labels: a dwell stands at a
  target; replicate visits have equal ``*_des``), ``hold`` (feed hold), ``quick_stop``
  (drives stopped), ``end`` (final stand-still).

``events.csv``: ``t, device, address, cable, kind, code, reaction, active, text``: every
supervisor condition when it starts (``active`` 1) and ends (0), the hardware's own events
(EMCY, heartbeat, load-cell status changes; reaction ``event``) and the loop's (start, end,
interruption). Both files are flushed at least every second; after a crash or Ctrl-C the
directory is a valid recording up to the last flushed row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.recording import POSE_AXES, CsvStream, RecordingWriter
from controller.robot import Robot

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


class DryRunRecorder(CsvRecording):
    """Rows and events of a run into ``path`` (created; must be empty or absent)."""

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray, meta: dict,
                 robot_header: str = "", flush_s: float = 1.0) -> None:
        super().__init__(path, robot, init_pose, columns(robot), meta, True, flush_s,
                         robot_header)
        self.n = robot.n_cables
        self._row = np.empty(len(self.writer.columns))

    def row(self, t: float, pose_des: np.ndarray, l_cmd: np.ndarray, l_meas: np.ndarray,
            tau: np.ndarray, pose_meas: np.ndarray, tau_plan: np.ndarray, substituted: int,
            cycle: int, overruns: int, state: str, pose_err: float = float("nan"),
            drive_states: np.ndarray | None = None) -> None:
        """One row (:func:`columns`); ``drive_states``: the CiA 402 state numbers of the
        drives in cable order (None: ``nan``)."""
        n, r = self.n, self._row
        r[0] = t
        r[1:7] = pose_des
        r[7:7 + n] = l_cmd
        r[7 + n:7 + 2 * n] = l_meas
        r[7 + 2 * n:7 + 3 * n] = tau
        r[7 + 3 * n:13 + 3 * n] = pose_meas
        r[13 + 3 * n:13 + 4 * n] = tau_plan
        r[13 + 4 * n] = substituted
        r[14 + 4 * n] = cycle
        r[15 + 4 * n] = overruns
        r[16 + 4 * n] = pose_err
        r[17 + 4 * n:17 + 5 * n] = np.nan if drive_states is None else drive_states
        self.writer.append(r, state)
