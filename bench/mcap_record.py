"""Recordings as MCAP files (``recording.mcap``): written while a run goes, read back as a
``cdpr-recording/1`` recording, converted to and from the CSV directory.

One file holds what the CSV directory holds:

- attachments ``robot.toml`` (the model the controller ran with, as text) and ``meta.toml``
  (the last one written is the meta; :meth:`McapRecordingWriter.update_meta` adds one);
- a metadata record ``cdpr-recording`` with ``format`` and ``columns`` (the CSV header in
  order, JSON list, ``state`` included where the recording has it);
- one JSON channel per column group (:data:`TOPICS`), every message with ``t`` [s] and the
  group's values (``null`` for not measured); all messages of one row share the MCAP
  ``sequence`` (the row index) and ``log_time`` (``t`` in ns, 0 for a negative ``t``);
- ``/supervisor/events`` (``cdpr.SupervisorEvent``), the rows of ``events.csv``;
- for Foxglove: ``/tf`` (``foxglove.FrameTransform``, ``world`` -> ``platform``, the measured
  pose, else the desired one) and ``/scene`` (``foxglove.SceneUpdate``: masts, cables
  coloured by tension, the platform), protobuf encoded by the foxglove SDK.

Chunks are zstd compressed and closed at least every ``flush_s`` seconds by a background
thread, so a file cut short by a crash, SIGKILL or Ctrl-C reads up to its last whole chunk
(:func:`read_mcap` reads such a file and says so).
"""

from __future__ import annotations

import csv
import json
import math
import re
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from bench.recording import FORMAT, POSE_AXES, BackgroundWriter, RecordingError
from controller.robot import Robot

MCAP_NAME = "recording.mcap"
MAGIC = b"\x89MCAP0\r\n"
META_NAME = "cdpr-recording"
EVENTS_TOPIC = "/supervisor/events"
CAN_TOPIC = "/can"
CAN_LOG = "can.log"  #: the CAN frames beside a CSV recording (candump format)
EVENT_FIELDS = ("device", "address", "cable", "kind", "code", "reaction", "active", "text")

#: topic -> (schema name, column pattern -> field path); the first match wins, in order
_GROUPS: list[tuple[str, str, re.Pattern]] = [
    ("/pose/desired", "cdpr.Pose", re.compile(r"^(x|y|z|roll|pitch|yaw)_des$")),
    ("/pose/measured", "cdpr.Pose", re.compile(r"^(x|y|z|roll|pitch|yaw)_meas$")),
    ("/cables/lengths", "cdpr.CableLengths", re.compile(r"^l_(cmd|meas)_(\w+)$")),
    ("/cables/tensions", "cdpr.CableTensions", re.compile(r"^(tau|plan_tau)_(\w+)$")),
    ("/cables/exits", "cdpr.ExitPoints", re.compile(r"^a(x|y|z)_meas_(\w+)$")),
    ("/drives/feedback", "cdpr.DriveFeedback", re.compile(r"^(vel|current)_(\w+)$")),
    ("/loop", "cdpr.LoopState", re.compile(r"^(cycle|overruns|substituted|state)$")),
    ("/recording/other", "cdpr.Columns", re.compile(r"^(.+)$")),
]
#: the row topics in the order they are written
TOPICS = tuple(g[0] for g in _GROUPS)
_FIELD_NAMES = {"cmd": "commanded", "meas": "measured", "tau": "measured",
                "plan_tau": "planned", "vel": "velocity", "current": "current"}


def _path_of(topic: str, m: re.Match) -> tuple[str, ...]:
    """The JSON field path of a column in its topic's message."""
    if topic.startswith("/pose/") or topic in ("/loop", "/recording/other"):
        return (m.group(1),)
    if topic == "/cables/exits":
        return ("measured", m.group(2), m.group(1))
    return (_FIELD_NAMES[m.group(1)], m.group(2))


def layout(columns: list[str]) -> dict[str, list[tuple[str, tuple[str, ...]]]]:
    """Topic -> [(column name, field path)] for the columns other than ``t``."""
    out: dict[str, list[tuple[str, tuple[str, ...]]]] = {}
    for name in columns:
        if name == "t":
            continue
        for topic, _, pat in _GROUPS:
            m = pat.match(name)
            if m:
                out.setdefault(topic, []).append((name, _path_of(topic, m)))
                break
    return {t: out[t] for t in TOPICS if t in out}


def _json_schema(title: str, paths: list[tuple[str, ...]]) -> bytes:
    """A JSON schema (draft 2020-12) of a row message with the field ``paths``."""
    def node() -> dict:
        return {"type": "object", "properties": {}}

    root = node()
    root["properties"]["t"] = {"type": "number", "description": "time [s]"}
    for p in paths:
        cur = root
        for k in p[:-1]:
            cur = cur["properties"].setdefault(k, node())
        leaf = ({"type": "string"} if p == ("state",)
                else {"type": ["number", "null"], "description": "null: not measured"})
        cur["properties"][p[-1]] = leaf
    root["title"] = title
    return json.dumps(root).encode()


_EVENT_SCHEMA = json.dumps({
    "title": "cdpr.SupervisorEvent", "type": "object", "properties": {
        "t": {"type": "number"}, "device": {"type": "string"},
        "address": {"type": "integer"}, "cable": {"type": "string"},
        "kind": {"type": "string"}, "code": {"type": "integer"},
        "reaction": {"type": "string"}, "active": {"type": "boolean"},
        "text": {"type": "string"}}}).encode()


_CAN_SCHEMA = json.dumps({
    "title": "cdpr.CanFrame", "type": "object", "properties": {
        "t": {"type": "number", "description": "the frame's timestamp [s] (bus clock)"},
        "id": {"type": "integer", "description": "arbitration id"},
        "extended": {"type": "boolean"}, "dlc": {"type": "integer"},
        "data": {"type": "string", "description": "payload, hex"}}}).encode()


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _ns(t: float) -> int:
    """MCAP log time [ns] of a recording time ``t`` [s], clamped to what MCAP's unsigned
    64-bit times hold (0 before 0, the largest after 584 years); the message's own ``t``
    keeps the value."""
    t = float(t)
    if not t > 0:
        return 0
    return min(int(round(t * 1e9)), 2**64 - 1) if t < 1.8e10 else 2**64 - 1


def quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of a rotation matrix ``R`` (3, 3) (Shepperd's method, w >= 0); the
    rotation's convention stays :func:`controller.pose.rotation`'s."""
    m = [[float(v) for v in r] for r in R]
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, s / 4)
    elif m[0][0] >= m[1][1] and m[0][0] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = (s / 4, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    elif m[1][1] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = ((m[0][1] + m[1][0]) / s, s / 4, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4, (m[1][0] - m[0][1]) / s)
    return q if q[3] >= 0 else (-q[0], -q[1], -q[2], -q[3])


class _Scene:
    """The Foxglove messages of a row: the platform's frame and the 3D scene (protobuf,
    encoded by the foxglove SDK)."""

    def __init__(self, robot: Robot, columns: list[str]) -> None:
        from foxglove import messages as fm

        self.fm, self.robot = fm, robot
        idx = {c: i for i, c in enumerate(columns)}
        self.meas = [idx.get(f"{a}_meas") for a in POSE_AXES]
        self.des = [idx.get(f"{a}_des") for a in POSE_AXES]
        self.tau = [idx.get(f"tau_{c}") for c in robot.cable_ids]
        ext = np.ptp(robot.anchors, axis=0) if robot.n_cables else np.zeros(3)
        self.size = np.maximum(ext, 0.05)

    def schemas(self) -> dict[str, Any]:
        return {"/tf": self.fm.FrameTransform.get_schema(),
                "/scene": self.fm.SceneUpdate.get_schema()}

    def pose(self, row: np.ndarray) -> np.ndarray | None:
        for cols in (self.meas, self.des):
            if all(i is not None for i in cols):
                p = row[cols]
                if np.isfinite(p).all():
                    return p
        return None

    #: the 3D scene at most this often [s of recording time]; the frame every row
    SCENE_PERIOD_S = 0.1

    def messages(self, row: np.ndarray, first: bool) -> list[tuple[str, bytes]]:
        """``(topic, data)`` of the row (none without a pose): ``/tf`` every row, ``/scene``
        in the first row and then at most every :attr:`SCENE_PERIOD_S` of ``t``."""
        from controller.kinematics import cable_state
        from controller.pose import rotation

        p = self.pose(row)
        if p is None:
            return []
        fm, r = self.fm, self.robot
        ns = _ns(float(row[0]))  # (unsigned, as the log time)
        stamp = fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)
        qx, qy, qz, qw = quaternion(rotation(p[3:6]))
        q = fm.Quaternion(x=qx, y=qy, z=qz, w=qw)
        tf = fm.FrameTransform(timestamp=stamp, parent_frame_id="world",
                               child_frame_id="platform",
                               translation=fm.Vector3(x=p[0], y=p[1], z=p[2]), rotation=q)
        t = float(row[0])
        last = getattr(self, "_scene_t", None)
        if not first and last is not None and last <= t < last + self.SCENE_PERIOD_S:
            return [("/tf", tf.encode())]
        self._scene_t = t
        st = cable_state(p, r.anchors, r.exits, r.pulley_radius)
        entities = [self._cables(stamp, st, row),
                    fm.SceneEntity(timestamp=stamp, frame_id="world", id="platform",
                                   cubes=[fm.CubePrimitive(
                                       pose=fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2]),
                                                    orientation=q),
                                       size=fm.Vector3(x=self.size[0], y=self.size[1],
                                                       z=self.size[2]),
                                       color=fm.Color(r=0.6, g=0.6, b=0.7, a=0.8))])]
        if first:
            entities.append(self._masts(stamp))
        return [("/tf", tf.encode()), ("/scene", fm.SceneUpdate(entities=entities).encode())]

    def _colour(self, tau: float):
        """Blue at the robot's minimum tension to red at its maximum; grey unmeasured."""
        r = self.robot
        if not math.isfinite(tau):
            return self.fm.Color(r=0.5, g=0.5, b=0.5, a=1.0)
        hi = r.tension_max if math.isfinite(r.tension_max) else max(tau, 1.0)
        s = min(1.0, max(0.0, (tau - r.tension_min) / max(hi - r.tension_min, 1e-9)))
        return self.fm.Color(r=s, g=0.2, b=1.0 - s, a=1.0)

    def _cables(self, stamp, st, row: np.ndarray):
        fm = self.fm
        lines = []
        for k in range(self.robot.n_cables):
            i = self.tau[k]
            tau = float(row[i]) if i is not None else math.nan
            a, b = st.A[k], st.B[k]
            lines.append(fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=0.02,
                points=[fm.Point3(x=a[0], y=a[1], z=a[2]), fm.Point3(x=b[0], y=b[1], z=b[2])],
                color=self._colour(tau)))
        return fm.SceneEntity(timestamp=stamp, frame_id="world", id="cables", lines=lines)

    def _masts(self, stamp):
        fm, r = self.fm, self.robot
        lines = []
        for m in range(len(r.mast_ids)):
            tops = r.exits[r.mast_index == m]
            top = tops[np.argmax(tops[:, 2])] if len(tops) else r.pivots[m]
            o = r.pivots[m]
            lines.append(fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=0.1,
                points=[fm.Point3(x=o[0], y=o[1], z=o[2]),
                        fm.Point3(x=top[0], y=top[1], z=top[2])],
                color=fm.Color(r=0.3, g=0.3, b=0.3, a=1.0)))
        return fm.SceneEntity(timestamp=stamp, frame_id="world", id="masts", lines=lines)


def row_messages(lay: dict, idx: dict[str, int], scene: _Scene | None, row: np.ndarray,
                 state: str, first: bool) -> list[tuple[str, bytes]]:
    """``(topic, data)`` of one row: the JSON messages of :func:`layout` (``idx``: column
    name -> index in ``row``), then the Foxglove ones of ``scene``."""
    t = float(row[0])
    out = []
    for topic, cols in lay.items():
        msg: dict[str, Any] = {"t": t}
        for name, p in cols:
            v: Any = state if name == "state" else _num(row[idx[name]])
            cur = msg
            for k in p[:-1]:
                cur = cur.setdefault(k, {})
            cur[p[-1]] = v
        out.append((topic, json.dumps(msg).encode()))
    if scene is not None:
        out += scene.messages(row, first)
    return out


def row_schemas(lay: dict) -> dict[str, tuple[str, bytes]]:
    """Topic -> (schema name, JSON schema) of the row channels of :func:`layout`."""
    out = {}
    for topic, cols in lay.items():
        title = next(g[1] for g in _GROUPS if g[0] == topic)
        out[topic] = (title, _json_schema(title, [p for _, p in cols]))
    return out


class McapRecordingWriter(BackgroundWriter):
    """A recording written as one MCAP file while the run goes (the interface of
    :class:`bench.recording.RecordingWriter`: :meth:`append`, :meth:`event`,
    :meth:`update_meta`, :meth:`close`, :attr:`rows`).

    ``append`` only queues; a background thread encodes and writes, and closes the chunk
    (zstd) and flushes the file at least every ``flush_s`` seconds. ``scene``: also the
    Foxglove ``/tf`` and ``/scene`` channels. ``header``: the CSV header order to keep
    (``columns`` and ``state``; default: ``columns`` then ``state``)."""

    def __init__(self, path: str | Path, robot: Robot, init_pose: np.ndarray,
                 columns: list[str], meta: dict[str, Any] | None = None,
                 robot_header: str = "", states: bool = True, flush_s: float = 1.0,
                 robot_text: str | None = None, scene: bool = True,
                 header: list[str] | None = None) -> None:
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
        sid = self._w.register_schema("cdpr.SupervisorEvent", "jsonschema", _EVENT_SCHEMA)
        self._ch[EVENTS_TOPIC] = self._w.register_channel(EVENTS_TOPIC, "json", sid)
        sid = self._w.register_schema("cdpr.CanFrame", "jsonschema", _CAN_SCHEMA)
        self._ch[CAN_TOPIC] = self._w.register_channel(CAN_TOPIC, "json", sid)
        self._can_frames = 0
        self._scene = _Scene(robot, self.columns) if scene else None
        if self._scene is not None:
            for topic, sc in self._scene.schemas().items():
                sid = self._w.register_schema(sc.name, sc.encoding, sc.data)
                self._ch[topic] = self._w.register_channel(topic, "protobuf", sid)
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
        item = ("can", (float(msg.timestamp), int(msg.arbitration_id),
                        bool(msg.is_extended_id), int(msg.dlc), bytes(msg.data)), None)
        self._queue_item(item, check=False)  # a bus thread's callback: never raises

    def update_meta(self, **fields: Any) -> None:
        """A new ``meta.toml`` attachment (readers take the last)."""
        self._check()
        self.meta.update(fields)
        self._queue_item(("meta", tomli_w.dumps(self.meta), None))

    def _write_row(self, row: np.ndarray, state: str, seq: int) -> None:
        ns = _ns(float(row[0]))
        for topic, data in row_messages(self._layout, self._idx, self._scene, row, state,
                                        seq == 0):
            self._w.add_message(self._ch[topic], ns, data, ns, seq)

    def _write(self, items: list[tuple]) -> None:
        for kind, a, b in items:
            if kind == "row":
                self._write_row(a, b, self.rows)
                self.rows += 1
            elif kind == "can":
                t, cid, ext, dlc, data = a
                ns = _ns(t)
                self._w.add_message(self._ch[CAN_TOPIC], ns, json.dumps(
                    {"t": t, "id": cid, "extended": ext, "dlc": dlc, "data": data.hex()}
                ).encode(), ns, self._can_frames)
                self._can_frames += 1
                continue  # (many: no pause per frame)
            elif kind == "event":
                ns = _ns(a["t"])
                self._w.add_message(self._ch[EVENTS_TOPIC], ns, json.dumps(a).encode(), ns,
                                    self._events)
                self._events += 1
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


# ---------------------------------------------------------------------------- reading


@dataclass
class McapContent:
    """What an MCAP recording holds: ``header`` the CSV columns in order (``state``
    included), ``data`` (N, columns other than ``state``) float, ``states`` (N,) or None,
    ``events`` dicts of :data:`EVENT_FIELDS` and ``t``, the ``meta.toml`` and
    ``robot.toml`` texts, ``truncated`` when the file ended before its footer (a crash)."""

    path: Path
    header: list[str]
    data: np.ndarray
    states: list[str] | None
    events: list[dict[str, Any]]
    meta_text: str
    robot_text: str
    truncated: bool = False
    topics: dict[str, int] = field(default_factory=dict)


def mcap_file(path: str | Path) -> Path | None:
    """The MCAP file of a recording ``path`` (an MCAP file, or a directory holding
    :data:`MCAP_NAME` and no ``meta.toml``), else None."""
    p = Path(path)
    if p.is_dir():
        f = p / MCAP_NAME
        return f if f.is_file() and not (p / "meta.toml").exists() else None
    try:
        with p.open("rb") as fh:
            return p if fh.read(len(MAGIC)) == MAGIC else None
    except OSError:
        return None


def _records(path: Path):
    """The records of an MCAP file in order; (records, truncated)."""
    from mcap.exceptions import McapError
    from mcap.records import Footer
    from mcap.stream_reader import StreamReader

    out, truncated = [], True
    with path.open("rb") as f:
        try:
            for rec in StreamReader(f, validate_crcs=True).records:
                out.append(rec)
                if isinstance(rec, Footer):
                    truncated = False
        except (McapError, EOFError, ValueError, OSError) as e:
            if not out:
                raise RecordingError(f"{path}: not a readable MCAP file: {e}") from None
        except Exception as e:  # a record cut in the middle (struct, zstd errors)
            if not out:
                raise RecordingError(f"{path}: not a readable MCAP file: {e}") from None
    return out, truncated


def _get(msg: dict, p: tuple[str, ...]) -> Any:
    cur: Any = msg
    for k in p:
        if not isinstance(cur, dict) or k not in cur:
            return None
        cur = cur[k]
    return cur


def read_mcap(path: str | Path) -> McapContent:
    """Read an MCAP recording (complete, or cut short by a crash: the rows whose every
    message was written). Errors name the file and what is missing."""
    from mcap.records import Attachment, Channel, Message, Metadata

    p = mcap_file(path) or Path(path)
    recs, truncated = _records(p)
    header: list[str] | None = None
    texts: dict[str, str] = {}
    channels: dict[int, str] = {}
    msgs: dict[str, dict[int, dict]] = {}
    events = []
    for r in recs:
        if isinstance(r, Metadata) and r.name == META_NAME:
            header = json.loads(r.metadata["columns"])
        elif isinstance(r, Attachment) and r.name in ("robot.toml", "meta.toml"):
            texts[r.name] = r.data.decode("utf-8")
        elif isinstance(r, Channel):
            channels[r.id] = r.topic
        elif isinstance(r, Message):
            topic = channels.get(r.channel_id)
            if topic == EVENTS_TOPIC:
                events.append(json.loads(r.data))
            elif topic in TOPICS:
                msgs.setdefault(topic, {})[r.sequence] = json.loads(r.data)
    for what, ok in (("metadata record 'cdpr-recording'", header is not None),
                     ("attachment robot.toml", "robot.toml" in texts),
                     ("attachment meta.toml", "meta.toml" in texts)):
        if not ok:
            raise RecordingError(f"{p}: {what} missing: not a cdpr recording in MCAP")
    assert header is not None
    lay = layout(header)
    seqs = sorted(set.intersection(*(set(msgs.get(t, {})) for t in lay)) if lay
                  else set(msgs.get("/pose/desired", {})))
    if not lay:
        raise RecordingError(f"{p}: no column besides 't'")
    first = next(iter(lay))
    numeric = [c for c in header if c != "state"]
    ncol = {c: i for i, c in enumerate(numeric)}
    data = np.full((len(seqs), len(numeric)), np.nan)
    states: list[str] | None = [] if "state" in header else None
    for k, s in enumerate(seqs):
        data[k, ncol["t"]] = msgs[first][s]["t"]
        for topic, cols in lay.items():
            m = msgs[topic][s]
            for name, path_ in cols:
                v = _get(m, path_)
                if name == "state":
                    assert states is not None
                    states.append("" if v is None else str(v))
                elif v is not None:
                    data[k, ncol[name]] = float(v)
    return McapContent(p, header, data, states, events, texts["meta.toml"],
                       texts["robot.toml"], truncated,
                       {t: len(v) for t, v in msgs.items()})


def read_can_frames(path: str | Path):
    """The ``/can`` channel of an MCAP recording as ``can.Message`` objects, in order
    (a file cut short: up to its last whole chunk)."""
    import can
    from mcap.records import Channel, Message

    p = mcap_file(path) or Path(path)
    recs, _ = _records(p)
    chan = None
    for r in recs:
        if isinstance(r, Channel) and r.topic == CAN_TOPIC:
            chan = r.id
        elif isinstance(r, Message) and r.channel_id == chan:
            m = json.loads(r.data)
            yield can.Message(timestamp=m["t"], arbitration_id=m["id"],
                              is_extended_id=m["extended"], dlc=m["dlc"],
                              data=bytes.fromhex(m["data"]), check=False)


class CanTap:
    """Every frame of a CAN bus to ``on_frame(msg)``: on a ``virtual:CHANNEL`` in the
    sending thread as it is sent (the order of the bus, lock-step included); another bus
    (e.g. the socketcand hub of ``--rig process``) through a second connection and a
    python-can notifier. :meth:`close` detaches."""

    def __init__(self, spec: str, on_frame) -> None:
        import can

        from hal.can_bus import open_bus, parse_can_spec

        self.spec = spec
        self._notifier = None
        s = parse_can_spec(spec)
        if s.interface == "virtual":
            from can.interfaces import virtual

            from bench.dryrun.lockstep_bus import _DirectQueue

            self.bus = virtual.VirtualBus(channel=s.channel)
            direct = _DirectQueue([on_frame])
            with virtual.channels_lock:  # first of the receivers: a frame is logged
                # before any receiver answers it (a SYNC before its TPDOs, as on a wire)
                self.bus.channel.remove(self.bus.queue)
                self.bus.channel.insert(0, direct)
                self.bus.queue = direct
        else:
            self.bus = open_bus(spec)
            self._notifier = can.Notifier(self.bus, [on_frame], timeout=0.05)

    def close(self) -> None:
        if self._notifier is not None:
            self._notifier.stop()
        self.bus.shutdown()


# ------------------------------------------------------------------------ conversion


def _event_cells(ev: dict) -> tuple[str, ...]:
    from bench.dryrun.record import event_cells

    return event_cells(ev["t"], ev["device"], ev["address"], ev["cable"], ev["kind"],
                       ev["code"], ev["reaction"], ev["active"], ev["text"])


def mcap_to_csv(src: str | Path, out_dir: str | Path, can_log: bool = True) -> McapContent:
    """Write the ``cdpr-recording/1`` directory ``out_dir`` (created) of an MCAP recording:
    ``meta.toml``, ``robot.toml`` (the texts it holds), ``recording.csv`` (the columns in
    their order), ``events.csv`` when it has events, and with ``can_log`` ``can.log``
    (candump) when it has CAN frames. Returns what was read."""
    from bench.dryrun.record import EVENT_COLUMNS
    from bench.recording import _cell, _write_atomic

    c = read_mcap(src)
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    meta = tomllib.loads(c.meta_text)
    meta["samples"], meta["robot"] = "recording.csv", "robot.toml"
    _write_atomic(d / "robot.toml", c.robot_text)
    _write_atomic(d / "meta.toml", tomli_w.dumps(meta))
    numeric = [h for h in c.header if h != "state"]
    pos = [numeric.index(h) if h != "state" else -1 for h in c.header]
    with (d / "recording.csv").open("w", newline="", encoding="utf-8") as f:
        f.write(",".join(c.header) + "\n")
        for k, row in enumerate(c.data):
            f.write(",".join(c.states[k] if j < 0 and c.states is not None else _cell(row[j])
                             for j in pos) + "\n")
    if c.events:
        with (d / "events.csv").open("w", newline="", encoding="utf-8") as f:
            f.write(",".join(EVENT_COLUMNS) + "\n")
            for ev in c.events:
                f.write(",".join(_event_cells(ev)) + "\n")
    if can_log:
        frames = read_can_frames(src)
        first = next(frames, None)
        if first is not None:
            import can

            with can.Logger(str(d / CAN_LOG)) as log:
                log.on_message_received(first)
                for m in frames:
                    log.on_message_received(m)
    return c


def _read_events_csv(p: Path) -> list[dict[str, Any]]:
    out = []
    with p.open(newline="", encoding="utf-8") as f:
        for lineno, row in enumerate(csv.DictReader(f), start=2):
            try:
                out.append({"t": float(row["t"]), "device": row["device"],
                            "address": int(row["address"]), "cable": row["cable"],
                            "kind": row["kind"], "code": int(row["code"], 0),
                            "reaction": row["reaction"], "active": row["active"] == "1",
                            "text": row["text"]})
            except (KeyError, TypeError, ValueError) as e:
                raise RecordingError(f"{p}:{lineno}: not an event row "
                                     f"({', '.join(_event_fields())}): {e}") from None
    return out


def _event_fields() -> tuple[str, ...]:
    return ("t",) + EVENT_FIELDS


def csv_to_mcap(src_dir: str | Path, out: str | Path, scene: bool = True) -> Path:
    """Write the MCAP file ``out`` of a ``cdpr-recording/1`` directory (validated by
    :func:`bench.recording.read_recording` first): every CSV column, the state, the
    events, ``meta.toml`` and ``robot.toml`` as they are."""
    from bench.recording import read_recording

    d = Path(src_dir)
    rec = read_recording(d)  # validates, names file/line/column
    samples = d / str(rec.meta["samples"])
    with samples.open(newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        header = [h.strip() for h in next(reader)]
        rows = [r for r in reader if r and any(x.strip() for x in r)]
    st = header.index("state") if "state" in header else -1
    numeric = ["t"] + [h for h in header if h not in ("t", "state")]  # the writer: t first
    idx = [header.index(h) for h in numeric]
    meta_text = (d / "meta.toml").read_text(encoding="utf-8")
    robot_text = (d / str(rec.meta["robot"])).read_text(encoding="utf-8")
    meta = tomllib.loads(meta_text)
    w = McapRecordingWriter(out, rec.robot, rec.init_pose, numeric, meta, states=st >= 0,
                            flush_s=3600.0, robot_text=robot_text, scene=scene,
                            header=header)
    try:
        for r in rows:
            vals = [math.nan if r[j].strip().lower() in ("", "nan") else float(r[j])
                    for j in idx]
            w.append(vals, r[st].strip() if st >= 0 else None)
        ev = d / "events.csv"
        if ev.is_file():
            for e in _read_events_csv(ev):
                w.event(**e)
        if (d / CAN_LOG).is_file():
            import can

            for m in can.LogReader(str(d / CAN_LOG)):
                w.can_frame(m)
    finally:
        w.close()
    return Path(out)


def read_recording_mcap(path: str | Path):
    """A :class:`bench.recording.Recording` of an MCAP recording, read as its CSV
    directory would be (the same validation, the same arrays); ``rec.path`` is ``path``."""
    from bench.recording import read_recording

    with tempfile.TemporaryDirectory(prefix="cdpr-mcap-") as tmp:
        mcap_to_csv(path, Path(tmp) / "rec", can_log=False)
        rec = read_recording(Path(tmp) / "rec")
    rec.path = Path(path)
    return rec


def convert_target(src: str | Path, out: str | Path) -> tuple[str, Path]:
    """What ``convert`` makes of ``src``: ``("csv", OUT)`` (a CSV directory of an MCAP
    recording) or ``("mcap", file)`` (``OUT`` when it ends in ``.mcap``, else
    ``OUT/recording.mcap``). Raises :class:`RecordingError` when ``src`` is neither."""
    src, out = Path(src), Path(out)
    if mcap_file(src) is not None:
        return "csv", out
    if not (src / "meta.toml").is_file():
        raise RecordingError(f"{src}: neither an MCAP recording nor a recording directory "
                             f"(no meta.toml, no {MCAP_NAME})")
    return "mcap", out if out.suffix == ".mcap" else out / MCAP_NAME


def convert(src: str | Path, out: str | Path) -> dict[str, Any]:
    """``cdpr recording convert``: an MCAP recording to a CSV directory, or a CSV directory
    to an MCAP file (:func:`convert_target`). Returns a summary (``from``, ``to``,
    ``input``, ``output``, ``rows``, ``events``, ``truncated``)."""
    to, target = convert_target(src, out)
    if to == "csv":
        c = mcap_to_csv(src, target)
    else:
        csv_to_mcap(src, target)
        c = read_mcap(target)
    return {"from": "mcap" if to == "csv" else "csv", "to": to, "input": str(src),
            "output": str(target), "rows": len(c.data), "events": len(c.events),
            "truncated": c.truncated}


def info(path: str | Path) -> dict[str, Any]:
    """``cdpr recording info``: an MCAP recording's channels (topic, schema, encoding,
    messages), rows, events, time span, chunks and compression, whether it is whole."""
    from mcap.records import Channel, Chunk, Footer, Message, Schema
    from mcap.stream_reader import StreamReader

    p = mcap_file(path)
    if p is None:
        raise RecordingError(f"{path}: not an MCAP recording")
    schemas: dict[int, Schema] = {}
    chans: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    chunks, compression, whole = 0, set(), False
    with p.open("rb") as f:
        try:
            for r in StreamReader(f, emit_chunks=True, validate_crcs=True).records:
                if isinstance(r, Chunk):
                    chunks += 1
                    compression.add(r.compression or "none")
                    from mcap.stream_reader import breakup_chunk
                    for x in breakup_chunk(r, validate_crc=True):
                        if isinstance(x, Message):
                            counts[x.channel_id] = counts.get(x.channel_id, 0) + 1
                        elif isinstance(x, Schema):
                            schemas[x.id] = x
                        elif isinstance(x, Channel):
                            chans[x.id] = x
                elif isinstance(r, Footer):
                    whole = True
        except Exception:  # cut short: what came before
            pass
    c = read_mcap(p)
    return {"file": str(p), "whole": whole, "chunks": chunks,
            "compression": sorted(compression), "rows": len(c.data),
            "events": len(c.events),
            "t_s": [float(c.data[0, 0]), float(c.data[-1, 0])] if len(c.data) else None,
            "channels": [{"topic": ch.topic, "schema": schemas[ch.schema_id].name
                          if ch.schema_id in schemas else "", "encoding": ch.message_encoding,
                          "messages": counts.get(i, 0)} for i, ch in sorted(chans.items())]}


# ------------------------------------------------------------------- the dry run's recorder


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
