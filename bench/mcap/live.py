"""A run shown live in Foxglove: the recording's channels on a Foxglove WebSocket server.

``cdpr dry-run ... --live [HOST:PORT]`` starts a server (foxglove-sdk) with the channels of
an MCAP recording (bench/mcap: the JSON row channels, ``/supervisor/events``,
``/tf``, ``/scene``, the raw CAN frames on ``/can``); Foxglove connects to
``ws://HOST:PORT``. The control loop only queues its rows, events and frames
(:meth:`LiveWriter.append`, :meth:`LiveWriter.can_frame`: cheap, no encoding); a thread of
its own publishes, at most ``rate_hz`` times a second, the newest row (a view, not a record:
rows in between are not sent; ``--record`` keeps them), every event and the CAN frames
queued since the last publication (at most ``can_queue``, the newest; encoded only while a
client subscribes to ``/can``). Port 0 takes a free port (:attr:`LiveWriter.port`).
"""

from __future__ import annotations

import json
import sys
import threading
from collections import deque
from typing import Any

import numpy as np

from bench.mcap.channels import (
    CAN_SCHEMA,
    CAN_TOPIC,
    EVENT_SCHEMA,
    EVENTS_TOPIC,
    LOG_TOPIC,
    can_fields,
    can_message,
    layout,
    log_ns,
    row_messages,
    row_schemas,
)
from bench.mcap.scene import Scene
from controller.robot import Robot

CAN_QUEUE = 4096  #: CAN frames kept between two publications (the newest)


def parse_address(address: str) -> tuple[str, int]:
    """``HOST:PORT`` (or ``:PORT``, ``HOST``) -> (host, port); ValueError naming it."""
    host, sep, port = address.rpartition(":")
    if not sep:
        host, port = address, "8765"
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"--live {address}: the port must be a number 0..65535") from None
    if not 0 <= p <= 65535:
        raise ValueError(f"--live {address}: the port must be in 0..65535")
    return host or "127.0.0.1", p


class LiveWriter:
    """The recording writer's interface (:meth:`append`, :meth:`event`, :meth:`update_meta`,
    :meth:`close`, :attr:`rows`; :meth:`can_frame`) publishing on a Foxglove WebSocket
    server. ``can_t0``: the log time of the ``/can`` messages (each message's ``t`` keeps
    the frame's own time [s]): None the frames' clock; a number, the frames' clock [s] at
    ``t`` = 0; ``"rows"``, the ``t`` of the newest row published with them."""

    def __init__(self, address: str, robot: Robot, columns: list[str], states: bool = True,
                 rate_hz: float = 30.0, can_t0: float | str | None = None,
                 can_queue: int = CAN_QUEUE) -> None:
        import foxglove

        host, port = parse_address(address)
        self.columns = list(columns)
        self.rows = 0  #: rows published so far
        self._ctx = foxglove.Context()
        self.server = foxglove.start_server(name="cdpr-bench", host=host, port=port,
                                            context=self._ctx)
        self.host, self.port = host, int(self.server.port)
        header = self.columns + (["state"] if states else [])
        self._layout = layout(header)
        self._idx = {name: i for i, name in enumerate(self.columns)}
        self._scene = Scene(robot, self.columns)
        self._ch: dict[str, Any] = {}
        for topic, (title, schema) in row_schemas(self._layout).items():
            self._ch[topic] = foxglove.Channel(
                topic, message_encoding="json", context=self._ctx,
                schema=foxglove.Schema(name=title, encoding="jsonschema", data=schema))
        self._ch[EVENTS_TOPIC] = foxglove.Channel(
            EVENTS_TOPIC, message_encoding="json", context=self._ctx,
            schema=foxglove.Schema(name="cdpr.SupervisorEvent", encoding="jsonschema",
                                   data=EVENT_SCHEMA))
        self._ch[CAN_TOPIC] = foxglove.Channel(
            CAN_TOPIC, message_encoding="json", context=self._ctx,
            schema=foxglove.Schema(name="cdpr.CanFrame", encoding="jsonschema",
                                   data=CAN_SCHEMA))
        self._can: deque = deque(maxlen=int(can_queue))  # appended from any thread
        self._can_t0 = can_t0 if can_t0 is None or can_t0 == "rows" else float(can_t0)
        self._row_t = 0.0
        self.can_frames = 0  #: CAN frames published so far
        for topic, sc in self._scene.schemas().items():
            self._ch[topic] = foxglove.Channel(
                topic, message_encoding="protobuf", context=self._ctx,
                schema=foxglove.Schema(name=sc.name, encoding=sc.encoding, data=sc.data))
        self._period = 1.0 / float(rate_hz)
        self._lock = threading.Lock()
        self._latest: tuple[np.ndarray, str] | None = None
        self._events: list[dict] = []
        self._first = True
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="foxglove-live", daemon=True)
        self._thread.start()

    def append(self, values, state: str | None = None) -> None:
        with self._lock:
            self._latest = (np.array(values, dtype=float), state or "")

    def event(self, t: float, device: str, address: int, cable: str, kind: str, code: int,
              reaction: str, active: bool, text: str) -> None:
        ev = {"t": float(t), "device": str(device), "address": int(address),
              "cable": str(cable), "kind": str(kind), "code": int(code),
              "reaction": str(reaction), "active": bool(active), "text": str(text)}
        with self._lock:
            self._events.append(ev)

    def can_frame(self, msg) -> None:
        """One CAN frame (a ``can.Message``) for ``/can``; any thread (a bus's callback:
        only queued, the oldest dropped beyond ``can_queue``)."""
        self._can.append(msg)

    def update_meta(self, **fields: Any) -> None:
        """(The live view has no meta.)"""

    def publish(self) -> None:
        """Publish the events, the CAN frames and the newest row queued (the thread does it;
        also at close)."""
        with self._lock:
            latest, self._latest = self._latest, None
            events, self._events = self._events, []
        for ev in events:
            self._ch[EVENTS_TOPIC].log(json.dumps(ev).encode(), log_time=log_ns(ev["t"]))
            self._ch[LOG_TOPIC].log(self._scene.log(ev), log_time=log_ns(ev["t"]))
        if latest is not None:
            self._row_t = float(latest[0][0])
        self._publish_can()
        if latest is not None:
            row, state = latest
            ns = log_ns(float(row[0]))
            for topic, data in row_messages(self._layout, self._idx, self._scene, row, state,
                                            self._first):
                self._ch[topic].log(data, log_time=ns)
            self._first = False
            self.rows += 1

    def _publish_can(self) -> None:
        """The CAN frames queued (encoded only when a client subscribes to ``/can``)."""
        ch, q = self._ch[CAN_TOPIC], self._can
        frames = [q.popleft() for _ in range(len(q))]
        if not frames or not ch.has_sinks():
            return
        for msg in frames:
            f = can_fields(msg)
            ns = log_ns(f[0] if self._can_t0 is None else self._row_t
                        if self._can_t0 == "rows" else f[0] - self._can_t0)
            ch.log(can_message(*f), log_time=ns)
        self.can_frames += len(frames)

    def _run(self) -> None:
        while not self._closed.wait(self._period):
            self.publish()

    def close(self) -> None:
        """Publish the rest, stop the server (idempotent)."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._thread.join()
        try:
            self.publish()
        finally:
            self.server.stop()


def live_recorder(address: str, robot: Robot, init_pose: np.ndarray, rate_hz: float = 30.0,
                  can: str | None = None):
    """A :class:`bench.dryrun.record.DryRunRecorder` whose rows and events go live to
    Foxglove (its packing of the loop's row, a :class:`LiveWriter` sink); with ``can`` (the
    ``--can`` spec of the drives' bus) also every frame of that bus on ``/can``."""
    from bench.dryrun.record import columns
    from bench.mcap.recorders import SinkRecorder

    writer = LiveWriter(address, robot, columns(robot), rate_hz=rate_hz, can_t0="rows")
    rec = SinkRecorder(writer, robot.n_cables, can)
    rec.port = writer.port
    print(f"Foxglove live view: ws://{rec.writer.host}:{rec.port}", file=sys.stderr,
          flush=True)
    return rec
