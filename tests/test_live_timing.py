"""The live view and the MCAP recording do not touch the loop's timing: a dry run with
``--format mcap --live`` runs the same cycles with the same overruns as without; the loop's
thread only hands rows over (the encoding and the publishing run in the view's thread);
a client that connects, subscribes and never reads blocks neither the loop nor the end of
the run."""

from __future__ import annotations

import base64
import json
import os
import socket
import struct
import threading
import time

import numpy as np
import pytest

from bench.cli import main
from bench.dryrun.record import columns
from bench.mcap import MCAP_NAME, read_mcap
from bench.mcap.live import LiveWriter
from controller.robot import resolve_robot
from tests.test_mcap_recording import open_with_mcap_reader

ROBOT = resolve_robot("rocaspect")
SUMMARY = ("cycles", "overruns", "ended", "simulated_s")  # (the tracker: wall-clock noise)


def _dry_run(capsys, *extra: str) -> dict:
    capsys.readouterr()
    assert main(["dry-run", "paper-centre", "--duration", "0.4", "--json", "--quiet",
                 *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_dry_run_with_mcap_and_live_runs_as_without(tmp_path, capsys):
    plain = _dry_run(capsys)
    live = _dry_run(capsys, "--record", str(tmp_path / "rec"), "--format", "mcap",
                    "--live", "127.0.0.1:0")
    assert {k: live[k] for k in SUMMARY} == {k: plain[k] for k in SUMMARY}
    assert live["ended"] == "completed" and live["overruns"] == plain["overruns"]
    counts = open_with_mcap_reader(tmp_path / "rec" / MCAP_NAME)
    assert counts["/can"] > 0 and counts["/supervisor/log"] == counts["/supervisor/events"]
    assert not read_mcap(tmp_path / "rec").truncated


def _row(k: int) -> np.ndarray:
    n = ROBOT.n_cables
    row = np.full(len(columns(ROBOT)), 100.0)
    row[0] = 0.002 * k
    row[1:7] = [10.0, 8.5, 1.0, 0.0, 0.0, 0.0]
    row[7 + 3 * n:13 + 3 * n] = [10.0, 8.5, 1.0, 0.0, 0.0, 0.0]
    return row


def test_a_slow_publisher_never_delays_the_caller(monkeypatch):
    """Each publication takes 0.2 s: appending rows and events still takes microseconds,
    and nothing is encoded nor sent in the caller's thread while the view runs."""
    from bench.mcap import live

    threads: set[str] = set()
    real = live.row_messages

    def slow(*a, **kw):
        threads.add(threading.current_thread().name)
        time.sleep(0.2)
        return real(*a, **kw)

    monkeypatch.setattr(live, "row_messages", slow)
    w = LiveWriter("127.0.0.1:0", ROBOT, columns(ROBOT), rate_hz=100.0)
    try:
        worst = 0.0
        for k in range(300):
            t0 = time.perf_counter()
            w.append(_row(k), "move")
            w.event(0.002 * k, "drive", 3, "21", "emcy", 0x2310, "event", True, "x")
            worst = max(worst, time.perf_counter() - t0)
            time.sleep(0.002)
        assert threads == {"foxglove-live"}
        assert worst < 0.05, worst  # (the publisher holds no lock while it works)
    finally:
        w.close()


class _StuckClient:
    """A WebSocket client (by hand, a small receive buffer) that subscribes to every
    channel and then never reads."""

    def __init__(self, port: int) -> None:
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.settimeout(10)
        s.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                   f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                   "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1"
                   "\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            head += s.recv(1)
        assert b" 101 " in head.split(b"\r\n")[0], head
        self.sock, self.channels = s, []
        while not self.channels:  # the server's advertisement
            op, data = self._frame()
            if op == 1:
                m = json.loads(data)
                if m.get("op") == "advertise":
                    self.channels = [c["id"] for c in m["channels"]]
        self._send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": c} for i, c in enumerate(self.channels)]}).encode())

    def _recv(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            out += self.sock.recv(n - len(out))
        return out

    def _frame(self) -> tuple[int, bytes]:
        b0, b1 = self._recv(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack(">H", self._recv(2))[0]
        elif n == 127:
            n = struct.unpack(">Q", self._recv(8))[0]
        return b0 & 0x0F, self._recv(n)

    def _send(self, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126
                                else bytes([0x80 | 126]) + struct.pack(">H", n))
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def close(self) -> None:
        self.sock.close()


def test_a_client_that_never_reads_blocks_neither_the_loop_nor_the_end():
    pytest.importorskip("foxglove")
    w = LiveWriter("127.0.0.1:0", ROBOT, columns(ROBOT), rate_hz=500.0)
    client = None
    try:
        client = _StuckClient(w.port)
        assert len(client.channels) >= 8
        worst, k = 0.0, 0
        t_end = time.monotonic() + 2.5  # at 500 publications/s: megabytes unread
        while time.monotonic() < t_end:
            t0 = time.perf_counter()
            w.append(_row(k), "move")
            worst = max(worst, time.perf_counter() - t0)
            k += 1
            time.sleep(0.001)
        rows_then = w.rows
        time.sleep(0.3)
        w.append(_row(k), "move")
        time.sleep(0.3)
        assert w.rows > rows_then  # the publisher still publishes (it drops for the client)
        assert worst < 0.05, worst
    finally:
        t0 = time.monotonic()
        w.close()
        closed_s = time.monotonic() - t0
        if client is not None:
            client.close()
    assert closed_s < 5.0, closed_s
