"""The shipped Foxglove layout (docs/foxglove/cdpr-layout.json) is the generated one, and
every topic and field it names is a channel (a field) that the recorders write: a dry run's
MCAP file, the monitor's, and the live view's channels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.commission.monitor import _columns
from bench.mcap import MCAP_NAME
from bench.mcap import foxglove_layout as fl
from bench.mcap.writer import McapRecordingWriter
from controller.robot import resolve_robot

ROOT = Path(__file__).resolve().parents[1]
ROBOT = resolve_robot("rocaspect")


def _first_messages(path: Path) -> dict[str, object]:
    """Topic -> its first message (JSON decoded; the protobuf ones as bytes)."""
    from mcap.reader import make_reader

    out: dict[str, object] = {}
    with path.open("rb") as f:
        for _, ch, m in make_reader(f).iter_messages():
            if ch.topic not in out:
                out[ch.topic] = json.loads(m.data) if ch.message_encoding == "json" else m.data
    return out


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> dict[str, object]:
    """The first message of every channel of a dry run's MCAP file and of a monitor-like
    recording (the monitor's columns through the same writer)."""
    tmp = tmp_path_factory.mktemp("layout")
    assert main(["dry-run", "paper-centre", "--duration", "0.3", "--quiet", "--json",
                 "--record", str(tmp / "dry"), "--format", "mcap"]) == 0
    msgs = _first_messages(tmp / "dry" / MCAP_NAME)
    cols = _columns(ROBOT.cable_ids, has_current=True)
    import can

    w = McapRecordingWriter(tmp / "mon.mcap", ROBOT, np.array([10, 8.5, 1, 0, 0, 0.0]), cols,
                            states=False)
    w.append(np.arange(len(cols), dtype=float))
    w.event(0.1, "drive", 3, "21", "emcy", 0x2310, "event", True, "over-current")
    w.can_frame(can.Message(timestamp=0.05, arbitration_id=0x183, data=b"\x01\x02"))
    w.close()
    for topic, m in _first_messages(tmp / "mon.mcap").items():
        msgs.setdefault(topic, m)
    return msgs


def test_the_shipped_layout_is_the_generated_one():
    shipped = (ROOT / fl.SHIPPED).read_text(encoding="utf-8")
    assert shipped == fl.dumps(fl.robot_layout(ROBOT)), \
        "regenerate: cdpr recording layout docs/foxglove/cdpr-layout.json --force"


def test_every_topic_and_field_of_the_layout_is_written(written):
    lay = json.loads((ROOT / fl.SHIPPED).read_text(encoding="utf-8"))
    named = fl.topics(lay)
    assert {"/scene", "/tf", "/cables/tensions", "/cables/lengths", "/drives/state",
            "/loop", "/supervisor/log", "/can"} <= named
    assert named <= set(written), named - set(written)
    for path in _paths(lay):  # the fields of every message path
        topic, *fields = path.split(".")
        msg = written[topic]
        for f in fields:
            assert isinstance(msg, dict) and f in msg, f"{path}: no field {f!r}"
            msg = msg[f]


def test_a_layout_naming_what_is_not_written_is_caught(written):
    """The check finds a drifted topic or field (and nothing in the shipped layout)."""
    lay = fl.robot_layout(ROBOT)
    lay["configById"]["Plot!tensions"]["paths"][0]["value"] = "/cable/tensions.measured.11"
    assert fl.topics(lay) - set(written) == {"/cable/tensions"}
    lay = fl.robot_layout(ROBOT)
    lay["configById"]["RawMessages!can"]["topicPath"] = "/can_frames"
    assert fl.topics(lay) - set(written) == {"/can_frames"}
    assert fl.topics(fl.robot_layout(ROBOT)) - set(written) == set()


def test_the_live_view_serves_every_topic_of_the_layout():
    from bench.dryrun.record import columns
    from bench.mcap.live import LiveWriter

    w = LiveWriter("127.0.0.1:0", ROBOT, columns(ROBOT) + [f"drive_state_{c}" for c in
                                                            ROBOT.cable_ids])
    try:
        served = set(w._ch)
    finally:
        w.close()
    assert fl.topics(fl.robot_layout(ROBOT)) - served == set()
    assert "/can" in served


def test_cdpr_recording_layout_writes_it(tmp_path, capsys):
    out = tmp_path / "l.json"
    assert main(["recording", "layout", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert out.read_text() == (ROOT / fl.SHIPPED).read_text()
    assert "/scene" in res["topics"] and res["robot"] == ROBOT.name
    assert main(["recording", "layout", str(out), "--json"]) == 2  # exists
    assert "exists" in json.loads(capsys.readouterr().out)["error"]


def _paths(lay: dict) -> list[str]:
    out = []
    for cfg in lay["configById"].values():
        out += [p["value"] for p in cfg.get("paths", [])]
    return out
