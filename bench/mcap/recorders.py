"""The recorders of a run in MCAP (``--format mcap|both``), the tee of several recorders
(a recording and the live view), and the writer of ``cdpr commission monitor``'s rows in
any format (:func:`open_writer`)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bench.dryrun.record import (
    CsvRecording,
    DryRunRecorder,
    TimeOrder,
    columns,
    held_columns,
    sample_groups,
)
from bench.mcap.can_tap import CanTap
from bench.mcap.channels import MCAP_NAME
from bench.mcap.writer import McapRecordingWriter
from controller.robot import Robot


def dry_run_recorder(path: str | Path, robot: Robot, init_pose: np.ndarray, meta: dict,
                     robot_header: str = "", flush_s: float = 1.0, fmt: str = "mcap",
                     can: str | None = None, also: tuple = ()):
    """A :class:`bench.dryrun.record.DryRunRecorder` whose rows and events go to
    ``path/recording.mcap`` (the same columns and events as the CSV directory); with
    ``fmt`` ``both`` also the CSV directory (the MCAP file beside its files). ``can``: the
    ``--can`` spec of the drives' bus, whose every frame from now on goes to ``/can`` (and
    to each callable of ``also``, e.g. the live view's ``can_frame``: one tap of the bus)."""
    def mcap() -> SinkRecorder:
        writer = McapRecordingWriter(Path(path) / MCAP_NAME, robot, init_pose, columns(robot),
                                     meta, robot_header, states=True, flush_s=flush_s,
                                     can_t0="rows")
        rec = SinkRecorder(writer, robot.n_cables, can, _fan_out(writer.can_frame, *also))
        rec.path = Path(path)
        return rec

    if fmt == "both":
        csv_rec = DryRunRecorder(path, robot, init_pose, meta, robot_header, flush_s)
        return TeeRecorder(csv_rec, mcap())
    return mcap()


def process_recorder(path: str | Path | None, robot: Robot, init_pose: np.ndarray,
                     meta: dict, robot_header: str = "", flush_s: float = 1.0,
                     can: str | None = None, live: str | None = None,
                     spawned=None) -> SinkRecorder:
    """A :class:`SinkRecorder` whose MCAP recording ``path/recording.mcap`` (none when
    ``path`` is None) and live view (``live``, ``HOST:PORT``; none when None) are written
    and served by a child process (:class:`bench.mcap.child.RecordingProcess`: a real-time
    loop's process only queues its rows; ``spawned``, a :class:`bench.mcap.child.Spawned`,
    or one started now). ``can``: the ``--can`` spec of the drives' bus
    for ``/can``, tapped by the child on its own connection (a ``virtual`` bus, which
    lives in this process, here, its frames handed over)."""
    from bench.mcap.child import Factory, RecordingProcess
    from bench.mcap.live import LiveWriter
    from hal.can_bus import parse_can_spec

    cols = columns(robot)
    factories = []
    if path is not None:
        factories.append(Factory(McapRecordingWriter, (Path(path) / MCAP_NAME, robot,
                                                       init_pose, cols, meta, robot_header),
                                 {"states": True, "flush_s": flush_s, "can_t0": "rows"}))
    if live is not None:
        factories.append(Factory(LiveWriter, (live, robot, cols), {"can_t0": "rows"}))
    here = can is not None and parse_can_spec(can).interface == "virtual"
    proc = RecordingProcess(factories, cols, None if here else can,
                            name=str(path) if path is not None else "live view",
                            spawned=spawned)
    rec = SinkRecorder(proc, robot.n_cables, can if here else None)
    rec.path = Path(path) if path is not None else None
    if live is not None:
        rec.port = proc.port
        print(f"Foxglove live view: ws://{proc.host}:{proc.port}", file=sys.stderr,
              flush=True)
    return rec


class SinkRecorder(DryRunRecorder):
    """A :class:`bench.dryrun.record.DryRunRecorder` (its packing of the loop's row) whose
    rows and events go to ``writer`` (an MCAP writer, the live view: ``append``, ``event``,
    ``update_meta``, ``close``, ``columns``, ``rows``), ``n_cables`` cables; with ``can``
    (the ``--can`` spec of the drives' bus) every frame of that bus to ``on_frame``
    (:class:`CanTap`). The writer is closed when the tap cannot open."""

    def __init__(self, writer, n_cables: int, can: str | None, on_frame=None) -> None:
        self.n = n_cables
        self.writer = writer
        self.order = TimeOrder(writer.append, held_columns(n_cables))
        self._groups, self._all = sample_groups(n_cables), np.arange(len(writer.columns))
        try:
            self.tap = CanTap(can, on_frame or writer.can_frame) if can else None
        except BaseException:
            writer.close()
            raise

    def event(self, t, device, address, cable, kind, code, reaction, active, text) -> None:
        self.writer.event(t, device, address, cable, kind, code, reaction, active, text)

    def close(self) -> None:
        try:
            self.order.flush()
            if self.tap is not None:
                self.tap.close()
        finally:
            self.writer.close()


def _fan_out(*targets):
    """One callable calling each of ``targets`` (the first alone when only one)."""
    if len(targets) == 1:
        return targets[0]

    def each(msg) -> None:
        for f in targets:
            f(msg)

    return each


class TeeRecorder:
    """Rows, events and meta to several recorders (``--format both``, ``--live``); as well
    several writers (:meth:`append`; CAN frames to those that keep them)."""

    def __init__(self, *recorders) -> None:
        self.recorders = recorders

    @property
    def rows(self) -> int:
        """The rows of the first (the recording's: a live view skips rows)."""
        return self.recorders[0].rows

    def row(self, *args, **kw) -> None:
        for r in self.recorders:
            r.row(*args, **kw)

    def append(self, *args, **kw) -> None:
        for r in self.recorders:
            r.append(*args, **kw)

    def event(self, *args, **kw) -> None:
        for r in self.recorders:
            r.event(*args, **kw)

    def can_frame(self, msg) -> None:
        for r in self.recorders:
            if hasattr(r, "can_frame"):
                r.can_frame(msg)

    def update_meta(self, **fields) -> None:
        for r in self.recorders:
            r.update_meta(**fields)

    def close(self) -> None:
        errors = []
        for r in self.recorders:
            try:
                r.close()
            except OSError as e:
                errors.append(e)
        if errors:
            raise errors[0]


class CsvWriter(CsvRecording):
    """A ``cdpr-recording/1`` directory written while a run goes, with its ``events.csv``,
    rows given whole (the CSV format keeps no CAN frames: ``--candump``)."""

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray,
                 columns: list[str], meta: dict, states: bool, flush_s: float = 1.0) -> None:
        super().__init__(path, robot, init_pose, columns, meta, states, flush_s)

    def append(self, values, state: str | None = None) -> None:
        self.writer.append(values, state)


def open_writer(path: str | Path | None, robot: Robot, init_pose: np.ndarray,
                columns: list[str], meta: dict, fmt: str = "csv", states: bool = False,
                live: str | None = None, can_t0: float | None = None,
                flush_s: float = 1.0):
    """One writer (``append(values, state)``, ``event(...)``, ``can_frame(msg)``,
    ``update_meta``, ``close``, ``rows``) of a recording ``path`` in ``fmt`` (``csv``: the
    directory with ``events.csv``; ``mcap``: ``path/recording.mcap`` with ``/can``;
    ``both``) and, with ``live`` (``HOST:PORT``), the Foxglove live view (``/can`` too).
    ``can_t0``: the CAN frames' clock [s] at ``t`` = 0 (their MCAP log time then on the
    rows' clock). None when there is neither."""
    from bench.dryrun.record import FORMATS

    if fmt not in FORMATS:
        raise ValueError(f"record format {fmt!r}: one of {', '.join(FORMATS)}")
    out: list = []
    if path is not None and fmt in ("csv", "both"):
        out.append(CsvWriter(path, robot, init_pose, columns, meta, states, flush_s))
    if path is not None and fmt in ("mcap", "both"):
        out.append(McapRecordingWriter(Path(path) / MCAP_NAME, robot, init_pose, columns, meta,
                                       states=states, flush_s=flush_s, can_t0=can_t0))
    if live is not None:
        from bench.mcap.live import LiveWriter

        view = LiveWriter(live, robot, columns, states=states, can_t0=can_t0)
        print(f"Foxglove live view: ws://{view.host}:{view.port}", file=sys.stderr, flush=True)
        out.append(view)
    if not out:
        return None
    return out[0] if len(out) == 1 else TeeRecorder(*out)
