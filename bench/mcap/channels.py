"""The channels of a cdpr recording in MCAP: names, the row topics and their JSON schemas,
the messages of a row (bench/mcap/__init__.py describes the file)."""

from __future__ import annotations

import json
import math
import re
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from bench.mcap.scene import Scene

MCAP_NAME = "recording.mcap"
MAGIC = b"\x89MCAP0\r\n"
META_NAME = "cdpr-recording"
EVENTS_TOPIC = "/supervisor/events"
LOG_TOPIC = "/supervisor/log"  #: the events as ``foxglove.Log`` (Foxglove's Log panel)
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
    ("/drives/feedback", "cdpr.DriveFeedback", re.compile(r"^(vel|current|torque)_(\w+)$")),
    ("/drives/state", "cdpr.DriveStates", re.compile(r"^(drive_state)_(\w+)$")),
    ("/loop", "cdpr.LoopState", re.compile(r"^(cycle|overruns|substituted|state)$")),
    ("/recording/other", "cdpr.Columns", re.compile(r"^(.+)$")),
]
#: the row topics in the order they are written
TOPICS = tuple(g[0] for g in _GROUPS)
_FIELD_NAMES = {"cmd": "commanded", "meas": "measured", "tau": "measured",
                "plan_tau": "planned", "vel": "velocity", "current": "current",
                "torque": "torque", "drive_state": "state"}


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


EVENT_SCHEMA = json.dumps({
    "title": "cdpr.SupervisorEvent", "type": "object", "properties": {
        "t": {"type": "number"}, "device": {"type": "string"},
        "address": {"type": "integer"}, "cable": {"type": "string"},
        "kind": {"type": "string"}, "code": {"type": "integer"},
        "reaction": {"type": "string"}, "active": {"type": "boolean"},
        "text": {"type": "string"}}}).encode()


CAN_SCHEMA = json.dumps({
    "title": "cdpr.CanFrame", "type": "object", "properties": {
        "t": {"type": "number", "description": "the frame's timestamp [s] (bus clock)"},
        "id": {"type": "integer", "description": "arbitration id"},
        "extended": {"type": "boolean"}, "dlc": {"type": "integer"},
        "data": {"type": "string", "description": "payload, hex"}}}).encode()


def can_message(t: float, cid: int, extended: bool, dlc: int, data: bytes) -> bytes:
    """A ``/can`` message (:data:`CAN_SCHEMA`): ``t`` [s] the frame's timestamp."""
    return json.dumps({"t": t, "id": cid, "extended": extended, "dlc": dlc,
                       "data": data.hex()}).encode()


def can_fields(msg) -> tuple[float, int, bool, int, bytes]:
    """(t [s], id, extended, dlc, data) of a ``can.Message``."""
    return (float(msg.timestamp), int(msg.arbitration_id), bool(msg.is_extended_id),
            int(msg.dlc), bytes(msg.data))


def num_or_none(v: float) -> float | None:
    """``v`` as a JSON number, None (``null``: not measured) when not finite."""
    return float(v) if math.isfinite(v) else None


def log_ns(t: float) -> int:
    """MCAP log time [ns] of a recording time ``t`` [s], clamped to what MCAP's unsigned
    64-bit times hold (0 before 0, the largest after 584 years); the message's own ``t``
    keeps the value."""
    t = float(t)
    if not t > 0:
        return 0
    return min(int(round(t * 1e9)), 2**64 - 1) if t < 1.8e10 else 2**64 - 1


def row_messages(lay: dict, idx: dict[str, int], scene: Scene | None, row: np.ndarray,
                 state: str, first: bool) -> list[tuple[str, bytes]]:
    """``(topic, data)`` of one row: the JSON messages of :func:`layout` (``idx``: column
    name -> index in ``row``), then the Foxglove ones of ``scene``."""
    t = float(row[0])
    out = []
    for topic, cols in lay.items():
        msg: dict[str, Any] = {"t": t}
        for name, p in cols:
            v: Any = state if name == "state" else num_or_none(row[idx[name]])
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

