"""Logging a user can read (issue 9, defect 7): a TCP read that ends in the middle of a
socketcand frame is normal on a stream and is not logged as a warning, neither by our
socketcand link nor by python-can's own client (filtered once hal.can_bus is imported)."""

from __future__ import annotations

import logging
import socket
import threading
import time

import can

import hal.can_bus  # noqa: F401  (installs the filter)
from hal.socketcand_link import SocketcandLink


class SplittingServer:
    """A socketcand server that sends every frame in two TCP segments, 20 ms apart."""

    def __init__(self, frames: int = 5) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.frames = frames
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.sock.accept()
        with conn:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.sendall(b"< hi >")
            conn.recv(100)  # < open can0 >
            conn.sendall(b"< ok >")
            conn.recv(100)  # < rawmode >
            conn.sendall(b"< ok >")
            time.sleep(0.05)
            for i in range(self.frames):
                conn.sendall(f"< frame 12{i} 1.000000 01".encode())
                time.sleep(0.02)
                conn.sendall(b"02 >")
                time.sleep(0.02)
            time.sleep(0.5)

    def close(self) -> None:
        self.sock.close()
        self.thread.join(2)


def _receive(bus: can.BusABC, n: int) -> list[can.Message]:
    got, deadline = [], time.monotonic() + 5
    while len(got) < n and time.monotonic() < deadline:
        m = bus.recv(0.1)
        if m is not None:
            got.append(m)
    return got


def test_our_link_reads_split_frames_quietly(caplog):
    srv = SplittingServer()
    caplog.set_level(logging.DEBUG)
    bus = SocketcandLink("can0", "127.0.0.1", srv.port)
    try:
        got = _receive(bus, 5)
    finally:
        bus.shutdown()
        srv.close()
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [
        (0x120 + i, b"\x01\x02") for i in range(5)]
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_python_can_client_partial_read_warnings_are_dropped(caplog):
    srv = SplittingServer()
    caplog.set_level(logging.DEBUG, logger="can")
    bus = can.Bus(interface="socketcand", channel="can0", host="127.0.0.1", port=srv.port)
    try:
        got = _receive(bus, 5)
        logging.getLogger("can.interfaces.socketcand.socketcand").warning("something else")
    finally:
        bus.shutdown()
        srv.close()
    assert len(got) == 5
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings == ["something else"]  # what matters still shows
