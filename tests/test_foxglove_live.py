"""``--live``: a Foxglove WebSocket server (bound to 127.0.0.1, port 0) that a client
connects to and receives the recording's channels from; bad addresses are refused."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from bench.cli import main
from bench.dryrun.record import columns
from bench.mcap.live import LiveWriter, parse_address
from controller.robot import resolve_robot


def _client(port: int, want_topics: set[str], timeout_s: float = 10.0,
            payloads: dict[str, list[bytes]] | None = None, count: int = 1):
    """Connect (subprotocol foxglove.sdk.v1), take the advertised channels, subscribe to all,
    return (advertised topics -> schema name, topics with a message received); with
    ``payloads``, each message's data is added to ``payloads[topic]`` until each wanted
    topic has ``count`` messages."""
    pytest.importorskip("tornado")  # (dev extras: dask[distributed] brings it)
    from tornado import ioloop, websocket

    async def go():
        ws = await websocket.websocket_connect(
            f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"])
        channels: dict[int, dict] = {}
        got: set[str] = set()
        subscribed = False
        deadline = time.monotonic() + timeout_s
        def done() -> bool:
            return want_topics <= got and (payloads is None or all(
                len(payloads.get(t, ())) >= count for t in want_topics))

        while time.monotonic() < deadline and not done():
            msg = await ws.read_message()
            if msg is None:
                break
            if isinstance(msg, str):
                m = json.loads(msg)
                if m.get("op") == "advertise":
                    for ch in m["channels"]:
                        channels[ch["id"]] = ch
                    if not subscribed and want_topics <= {c["topic"] for c in
                                                          channels.values()}:
                        subs = [{"id": i, "channelId": cid} for i, cid in
                                enumerate(channels)]
                        await ws.write_message(json.dumps({"op": "subscribe",
                                                           "subscriptions": subs}))
                        subscribed = True
            elif msg[0] == 1:  # message data: opcode, subscription id (u32), ...
                sub = int.from_bytes(msg[1:5], "little")
                topic = channels[list(channels)[sub]]["topic"]
                got.add(topic)
                if payloads is not None:  # after the log time (u64)
                    payloads.setdefault(topic, []).append(bytes(msg[13:]))
        ws.close()
        return {c["topic"]: c["schemaName"] for c in channels.values()}, got

    return ioloop.IOLoop(make_current=False).run_sync(go, timeout=timeout_s + 5)


def test_a_client_receives_the_channels():
    robot = resolve_robot("rocaspect")
    cols = columns(robot)
    w = LiveWriter("127.0.0.1:0", robot, cols, rate_hz=50.0)
    assert w.port > 0
    import threading

    stop = threading.Event()

    def feed():
        k = 0
        while not stop.is_set():
            row = np.full(len(cols), 100.0)
            row[0] = 0.01 * k
            row[1:7] = [10.0, 8.5, 1.0, 0.0, 0.0, 0.0]
            row[7 + 3 * robot.n_cables:13 + 3 * robot.n_cables] = [10.0, 8.5, 1.0, 0, 0, 0]
            w.append(row, "move")
            if k % 10 == 0:
                w.event(0.01 * k, "drive", 3, "21", "emcy", 0x2310, "event", True, "x")
            k += 1
            time.sleep(0.005)

    t = threading.Thread(target=feed, daemon=True)
    t.start()
    try:
        want = {"/cables/tensions", "/pose/measured", "/tf", "/scene", "/supervisor/events",
                "/loop"}
        advertised, got = _client(w.port, want)
    finally:
        stop.set()
        t.join()
        w.close()
    assert advertised["/tf"] == "foxglove.FrameTransform"
    assert advertised["/scene"] == "foxglove.SceneUpdate"
    assert advertised["/cables/tensions"] == "cdpr.CableTensions"
    assert want <= got, got
    assert w.rows > 0


def _frames(k: int) -> list:
    """Two CAN frames of step ``k``: a SYNC and a TPDO of node 3 with ``k`` in its data."""
    import can

    return [can.Message(arbitration_id=0x80, data=b"", is_extended_id=False),
            can.Message(arbitration_id=0x183, data=bytes([k % 256, 1, 2, 3]),
                        is_extended_id=False)]


def _fed(feed_once, stop) -> None:
    k = 0
    while not stop.is_set():
        feed_once(k)
        k += 1
        time.sleep(0.005)


def _check_can(payloads: dict[str, list[bytes]]) -> None:
    """The ``/can`` messages are the frames fed: the schema's fields, ids and data."""
    msgs = [json.loads(p) for p in payloads["/can"]]
    assert {m["id"] for m in msgs} <= {0x80, 0x183} and 0x183 in {m["id"] for m in msgs}
    for m in msgs:
        assert set(m) == {"t", "id", "extended", "dlc", "data"} and not m["extended"]
        if m["id"] == 0x183:
            assert m["dlc"] == 4 and m["data"][2:] == "010203"
        else:
            assert m["dlc"] == 0 and m["data"] == ""


def test_a_client_receives_the_can_frames():
    """``LiveWriter.can_frame`` (the monitor's frames, any thread): the frames go out on
    ``/can`` as ``cdpr.CanFrame``, not in the caller's thread."""
    import threading

    robot = resolve_robot("rocaspect")
    cols = columns(robot)
    w = LiveWriter("127.0.0.1:0", robot, cols, rate_hz=50.0, can_t0=0.0)
    stop = threading.Event()

    def once(k):
        row = np.full(len(cols), 1.0)
        row[0] = 0.01 * k
        w.append(row, "move")
        for m in _frames(k):
            m.timestamp = 0.01 * k
            w.can_frame(m)

    t = threading.Thread(target=_fed, args=(once, stop), daemon=True)
    t.start()
    payloads: dict[str, list[bytes]] = {}
    try:
        advertised, got = _client(w.port, {"/can", "/loop"}, payloads=payloads, count=6)
    finally:
        stop.set()
        t.join()
        w.close()
    assert advertised["/can"] == "cdpr.CanFrame" and "/can" in got, got
    _check_can(payloads)
    assert w.can_frames > 0


@pytest.mark.parametrize("fmt", [None, "mcap"])
def test_the_dry_run_s_live_view_serves_its_bus_and_the_drive_states(fmt, tmp_path):
    """The dry run's live recorder (``open_recorder(..., live=, can=)``) taps the drives'
    bus (with an MCAP recording, through the recording's tap): frames sent on it reach a
    client on ``/can`` (and the file); the rows' drive states reach it on ``/drives/state``."""
    import threading
    import uuid

    import can

    from bench.dryrun.record import open_recorder

    robot = resolve_robot("rocaspect")
    spec = f"virtual:live-can-{uuid.uuid4().hex}"
    path = None if fmt is None else tmp_path / "rec"
    rec = open_recorder(path, robot, np.array([10.0, 8.5, 1.0, 0, 0, 0]), {},
                        fmt=fmt or "csv", live="127.0.0.1:0", can=spec)
    view = rec if fmt is None else rec.recorders[1]
    bus = can.Bus(interface="virtual", channel=spec.split(":", 1)[1])
    stop = threading.Event()
    n = robot.n_cables
    states = np.array([4, 4, 7, 5, 5, 5, 5, 5])

    def once(k):
        for m in _frames(k):
            bus.send(m)
        rec.row(0.01 * k, np.zeros(6), np.ones(n), np.ones(n), np.ones(n), np.zeros(6),
                np.ones(n), 0, 0, 0, "move", drive_states=states)

    t = threading.Thread(target=_fed, args=(once, stop), daemon=True)
    t.start()
    payloads: dict[str, list[bytes]] = {}
    try:
        advertised, got = _client(view.port, {"/can", "/drives/state"}, payloads=payloads,
                                  count=6)
    finally:
        stop.set()
        t.join()
        rec.close()
        bus.shutdown()
    assert {"/can", "/drives/state"} <= got, got
    assert advertised["/drives/state"] == "cdpr.DriveStates"
    _check_can(payloads)
    last = json.loads(payloads["/drives/state"][-1])["state"]
    assert [last[c] for c in robot.cable_ids] == states.tolist()
    if fmt is not None:
        from bench.mcap import read_can_frames

        assert len(list(read_can_frames(path / "recording.mcap"))) >= len(payloads["/can"])


@pytest.mark.parametrize("address", ["127.0.0.1:http", "host:70000"])
def test_bad_addresses_are_refused(address, capsys):
    with pytest.raises(ValueError, match="--live"):
        parse_address(address)
    assert main(["dry-run", "paper-centre", "--live", address, "--json"]) == 2
    assert "--live" in json.loads(capsys.readouterr().out)["error"]


def test_address_forms():
    assert parse_address("127.0.0.1:0") == ("127.0.0.1", 0)
    assert parse_address(":9000") == ("127.0.0.1", 9000)
    assert parse_address("0.0.0.0") == ("0.0.0.0", 8765)


def test_a_recording_that_cannot_open_closes_the_live_view(tmp_path, capsys):
    """``open_recorder`` with ``--live`` and a recording that fails to open (its directory
    is a file): the error comes out and the view's server is stopped (its port refuses)."""
    import socket

    from bench.dryrun.record import open_recorder

    robot = resolve_robot("rocaspect")
    (tmp_path / "rec").write_text("a file")
    with pytest.raises(OSError):
        open_recorder(tmp_path / "rec", robot, np.array([10.0, 8.5, 1.0, 0, 0, 0]), {},
                      fmt="mcap", live="127.0.0.1:0")
    line = [x for x in capsys.readouterr().err.splitlines() if "Foxglove live view" in x]
    port = int(line[-1].rsplit(":", 1)[1])
    # (the SDK's server stops its listener on its own runtime: refused within moments)
    deadline = time.monotonic() + 5.0
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
        except OSError:
            break
        assert time.monotonic() < deadline, f"port {port} still accepts after the close"
        time.sleep(0.02)
