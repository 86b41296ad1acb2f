"""The MCAP recording writer: rows, events, CAN frames and meta written while a run goes
(zstd chunks closed by a background thread at least every ``flush_s`` seconds)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from bench.mcap.channels import (
    CAN_SCHEMA,
    CAN_TOPIC,
    EVENT_SCHEMA,
    EVENTS_TOPIC,
    LOG_TOPIC,
    META_NAME,
    can_fields,
    can_message,
    layout,
    log_ns,
    row_messages,
    row_schemas,
)
from bench.mcap.scene import Scene
from bench.recording import FORMAT, BackgroundWriter
from controller.robot import Robot


class McapRecordingWriter(BackgroundWriter):
    """A recording written as one MCAP file while the run goes (the interface of
    :class:`bench.recording.RecordingWriter`: :meth:`append`, :meth:`event`,
    :meth:`update_meta`, :meth:`close`, :attr:`rows`).

    ``append`` only queues; a background thread encodes and writes, and closes the chunk
    (zstd) and flushes the file at least every ``flush_s`` seconds. ``scene``: also the
    Foxglove channels (``/tf``, ``/scene``, ``/supervisor/log``). ``header``: the CSV
    header order to keep (``columns`` and ``state``; default: ``columns`` then ``state``).
    ``can_t0``: the MCAP log time of the ``/can`` messages (each message's ``t`` keeps the
    frame's own time): None the frames' clock; a number, the frames' clock [s] at ``t`` =
    0 (log times on the rows' clock); ``"rows"``, the ``t`` of the newest row appended
    before the frame (0 before the first: on the rows' clock within a row's period, also
    when the rows' clock is simulated, lock-step)."""

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray,
                 columns: list[str], meta: dict[str, Any] | None = None,
                 robot_header: str = "", states: bool = True, flush_s: float = 1.0,
                 robot_text: str | None = None, scene: bool = True,
                 header: list[str] | None = None,
                 can_t0: float | str | None = None) -> None:
        from mcap.writer import CompressionType, Writer

        from controller.robot import dumps_robot

        if not columns or columns[0] != "t":
            raise ValueError("the first column must be 't'")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = list(columns)
        self.states = states
        self.rows = 0  #: rows written to the file so far
        self.meta = {"format": FORMAT, "robot": "robot.toml", "samples": "recording.csv",
                     "init_pose": [float(v) for v in init_pose],
                     "pose_source": "laser tracker", "tension_source": "load cells"}
        self.meta.update(meta or {})
        self._f = self.path.open("wb")
        self._w = Writer(self._f, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        self._w.start(profile="", library="cdpr-bench")
        header = header or self.columns + (["state"] if states else [])
        if sorted(header) != sorted(self.columns + (["state"] if states else [])):
            raise ValueError(f"header {header} does not hold the columns {self.columns}")
        self._idx = {name: i for i, name in enumerate(self.columns)}
        self._w.add_metadata(META_NAME, {"format": FORMAT, "columns": json.dumps(header)})
        text = robot_text if robot_text is not None else dumps_robot(robot, robot_header)
        self._attach("robot.toml", text)
        self._attach("meta.toml", tomli_w.dumps(self.meta))
        self._layout = layout(header)
        self._ch: dict[str, int] = {}
        sids: dict[tuple[str, bytes], int] = {}
        for topic, (title, schema) in row_schemas(self._layout).items():
            if (title, schema) not in sids:  # /pose/desired and /pose/measured: one
                sids[title, schema] = self._w.register_schema(title, "jsonschema", schema)
            self._ch[topic] = self._w.register_channel(topic, "json", sids[title, schema])
        sid = self._w.register_schema("cdpr.SupervisorEvent", "jsonschema", EVENT_SCHEMA)
        self._ch[EVENTS_TOPIC] = self._w.register_channel(EVENTS_TOPIC, "json", sid)
        sid = self._w.register_schema("cdpr.CanFrame", "jsonschema", CAN_SCHEMA)
        self._ch[CAN_TOPIC] = self._w.register_channel(CAN_TOPIC, "json", sid)
        self._can_frames = 0
        if can_t0 is not None and can_t0 != "rows":
            can_t0 = float(can_t0)
        self._can_t0 = can_t0
        self._row_t = 0.0  #: the newest row's t [s] (``can_t0="rows"``)
        self._scene = Scene(robot, self.columns) if scene else None
        if self._scene is not None:
            for topic, sc in self._scene.schemas().items():
                sid = self._w.register_schema(sc.name, sc.encoding, sc.data)
                self._ch[topic] = self._w.register_channel(topic, "protobuf", sid)
            self._log = 0
        self._w.flush()
        self._events = 0
        self._start(flush_s, f"mcap-{self.path.name}")

    def _attach(self, name: str, text: str) -> None:
        now = time.time_ns()
        self._w.add_attachment(now, now, name, "application/toml", text.encode())

    def append(self, values: np.ndarray | list[float], state: str | None = None) -> None:
        """One row: ``values`` in column order; ``state`` when the recording has the column."""
        self._check()
        row = np.array(values, dtype=float)
        if len(row) != len(self.columns):
            raise ValueError(f"{len(row)} values for {len(self.columns)} columns")
        self._queue_item(("row", row, state or ""))

    def event(self, t: float, device: str, address: int, cable: str, kind: str, code: int,
              reaction: str, active: bool, text: str) -> None:
        """One supervisor or hardware event (the columns of ``events.csv``)."""
        ev = {"t": float(t), "device": str(device), "address": int(address),
              "cable": str(cable), "kind": str(kind), "code": int(code),
              "reaction": str(reaction), "active": bool(active), "text": str(text)}
        self._queue_item(("event", ev, None))

    def can_frame(self, msg) -> None:
        """One CAN frame (a ``can.Message``) for the ``/can`` channel; cheap, any thread."""
        # a bus thread's callback: never raises
        self._queue_item(("can", can_fields(msg), None), check=False)

    def update_meta(self, **fields: Any) -> None:
        """A new ``meta.toml`` attachment (readers take the last)."""
        self._check()
        self.meta.update(fields)
        self._queue_item(("meta", tomli_w.dumps(self.meta), None))

    def _write_row(self, row: np.ndarray, state: str, seq: int) -> None:
        self._row_t = float(row[0])
        ns = log_ns(self._row_t)
        for topic, data in row_messages(self._layout, self._idx, self._scene, row, state,
                                        seq == 0):
            self._w.add_message(self._ch[topic], ns, data, ns, seq)

    def _write(self, items: list[tuple]) -> None:
        for kind, a, b in items:
            if kind == "row":
                self._write_row(a, b, self.rows)
                self.rows += 1
            elif kind == "can":
                t = a[0]
                ns = log_ns(t if self._can_t0 is None else self._row_t
                            if self._can_t0 == "rows" else t - self._can_t0)
                self._w.add_message(self._ch[CAN_TOPIC], ns, can_message(*a), ns,
                                    self._can_frames)
                self._can_frames += 1
                continue  # (many: no pause per frame)
            elif kind == "event":
                ns = log_ns(a["t"])
                self._w.add_message(self._ch[EVENTS_TOPIC], ns, json.dumps(a).encode(), ns,
                                    self._events)
                self._events += 1
                if self._scene is not None:
                    self._w.add_message(self._ch[LOG_TOPIC], ns, self._scene.log(a), ns,
                                        self._log)
                    self._log += 1
            else:
                self._attach("meta.toml", a)
            time.sleep(0)  # let a real-time loop in this process run
        self._w.flush()  # closes the chunk: the file reads up to here after a crash

    def _finish(self) -> None:
        """The summary and the footer, after the rest (:meth:`close`)."""
        self._w.finish()

    def __enter__(self) -> McapRecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
