"""Reading an MCAP recording (whole, or cut short by a crash) back into the columns of its
CSV twin; its ``/can`` frames; ``cdpr recording info``."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.mcap.channels import CAN_TOPIC, EVENTS_TOPIC, MAGIC, MCAP_NAME, META_NAME, TOPICS, layout
from bench.recording import RecordingError


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
