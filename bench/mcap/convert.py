"""MCAP recording <-> ``cdpr-recording/1`` CSV directory (``cdpr recording convert``), and
an MCAP recording read as a :class:`bench.recording.Recording`."""

from __future__ import annotations

import csv
import math
import tempfile
import tomllib
from pathlib import Path
from typing import Any

import tomli_w

from bench.mcap.channels import CAN_LOG, EVENT_FIELDS, MCAP_NAME
from bench.mcap.reader import McapContent, mcap_file, read_can_frames, read_mcap
from bench.mcap.writer import McapRecordingWriter
from bench.recording import RecordingError


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
