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


def _client(port: int, want_topics: set[str], timeout_s: float = 10.0):
    """Connect (subprotocol foxglove.sdk.v1), take the advertised channels, subscribe to all,
    return (advertised topics -> schema name, topics with a message received)."""
    pytest.importorskip("tornado")  # (dev extras: dask[distributed] brings it)
    from tornado import ioloop, websocket

    async def go():
        ws = await websocket.websocket_connect(
            f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"])
        channels: dict[int, dict] = {}
        got: set[str] = set()
        subscribed = False
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not (want_topics <= got):
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
                got.add(channels[list(channels)[sub]]["topic"])
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
