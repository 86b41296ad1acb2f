"""The recorders of a run in MCAP (``--format mcap|both``) and the tee of several
recorders (a recording and the live view)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.mcap.can_tap import CanTap
from bench.mcap.channels import MCAP_NAME
from bench.mcap.writer import McapRecordingWriter
from controller.robot import Robot


def dry_run_recorder(path: str | Path, robot: Robot, init_pose: np.ndarray, meta: dict,
                     robot_header: str = "", flush_s: float = 1.0, fmt: str = "mcap",
                     can: str | None = None):
    """A :class:`bench.dryrun.record.DryRunRecorder` whose rows and events go to
    ``path/recording.mcap`` (the same columns and events as the CSV directory); with
    ``fmt`` ``both`` also the CSV directory (the MCAP file beside its files). ``can``: the
    ``--can`` spec of the drives' bus, whose every frame from now on goes to ``/can``."""
    from bench.dryrun.record import DryRunRecorder, columns

    class McapDryRunRecorder(DryRunRecorder):
        def __init__(self) -> None:  # the CSV recorder's row packing, an MCAP sink
            self.path = Path(path)
            self.n = robot.n_cables
            self.writer = McapRecordingWriter(self.path / MCAP_NAME, robot, init_pose,
                                              columns(robot), meta, robot_header,
                                              states=True, flush_s=flush_s)
            self._row = np.empty(len(self.writer.columns))
            self.tap = CanTap(can, self.writer.can_frame) if can else None

        def event(self, t, device, address, cable, kind, code, reaction, active, text):
            self.writer.event(t, device, address, cable, kind, code, reaction, active, text)

        def close(self) -> None:
            try:
                if self.tap is not None:
                    self.tap.close()
            finally:
                self.writer.close()

    if fmt == "both":
        csv_rec = DryRunRecorder(path, robot, init_pose, meta, robot_header, flush_s)
        return TeeRecorder(csv_rec, McapDryRunRecorder())
    return McapDryRunRecorder()


class TeeRecorder:
    """Rows, events and meta to several recorders (``--format both``)."""

    def __init__(self, *recorders) -> None:
        self.recorders = recorders

    @property
    def rows(self) -> int:
        return min(r.rows for r in self.recorders)

    def row(self, *args, **kw) -> None:
        for r in self.recorders:
            r.row(*args, **kw)

    def event(self, *args, **kw) -> None:
        for r in self.recorders:
            r.event(*args, **kw)

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
