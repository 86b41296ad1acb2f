"""A CAN "bus" between processes over TCP: a hub speaking the socketcand raw-mode protocol.

There is no SocketCAN here, so the simulated rig serves its CAN bus on 127.0.0.1 the way
`socketcand <https://github.com/linux-can/socketcand>`_ serves a real one, and python-can's
own ``socketcand`` interface connects to it with no extra dependency::

    can.Bus(interface="socketcand", host="127.0.0.1", port=PORT, channel="can0")

Protocol (ASCII, one ``< ... >`` element per message), as python-can 4.6 expects it:

- server ``< hi >``; client ``< open CHANNEL >``, server ``< ok >`` (``< error ... >`` for
  another channel); client ``< rawmode >``, server ``< ok >``; ``< echo >`` is echoed.
- client -> hub: ``< send ID DLC B0 B1 ... >`` (hex id of 3 digits standard, 8 extended;
  hex bytes). Malformed elements are counted in :attr:`CanHub.bad_messages` and dropped
  (socketcand does not answer errors in raw mode).
- hub -> client: ``< frame ID SECONDS.MICROSECONDS DATA >`` with DATA one hex string
  (possibly empty).

Every frame a client sends goes to all other clients and, when the hub bridges an
in-process python-can bus (``bus=``), onto that bus; frames received on that bus go to
all clients. A client gets frames only after its ``< rawmode >`` answer had time to reach
it (``handshake_grace_s``; frames meanwhile are queued, not lost), because python-can
reads the handshake answers with a plain ``recv``.
"""

from __future__ import annotations

import logging
import socket
import threading
import time

import can

log = logging.getLogger(__name__)

#: frames from the bridged bus sent to the clients in one TCP write at most (the frames
#: waiting when the hub reads: a SYNC's answers from every drive leave together)
MAX_BATCH = 64


def frame_element(msg: can.Message, timestamp: float | None = None) -> bytes:
    """The socketcand ``< frame ... >`` element of a CAN message."""
    ts = msg.timestamp if timestamp is None else timestamp
    secs = int(ts)
    usecs = int(round((ts - secs) * 1e6))
    if usecs >= 1_000_000:
        secs, usecs = secs + 1, usecs - 1_000_000
    can_id = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    data = bytes(msg.data[: msg.dlc]).hex().upper()
    return f"< frame {can_id} {secs}.{usecs:06d} {data} >".encode("ascii")


def parse_send(element: str) -> can.Message:
    """A ``< send ID DLC B0 ... >`` element as a CAN message; ValueError if malformed."""
    parts = element[1:-1].split()
    if len(parts) < 3 or parts[0] != "send":
        raise ValueError(f"not a send element: {element!r}")
    id_text, dlc_text, data_text = parts[1], parts[2], parts[3:]
    if len(id_text) not in (3, 8):
        raise ValueError(f"CAN id {id_text!r} must have 3 (standard) or 8 (extended) hex digits")
    can_id = int(id_text, 16)
    extended = len(id_text) == 8
    if can_id > (0x1FFFFFFF if extended else 0x7FF):
        raise ValueError(f"CAN id {id_text!r} out of range")
    dlc = int(dlc_text, 16)
    if not 0 <= dlc <= 8 or len(data_text) != dlc:
        raise ValueError(f"DLC {dlc_text!r} does not match {len(data_text)} data byte(s)")
    data = bytes(int(b, 16) for b in data_text)
    return can.Message(arbitration_id=can_id, is_extended_id=extended, data=data, dlc=dlc)


class _Client:
    def __init__(self, sock: socket.socket, addr: tuple, grace_s: float) -> None:
        self.sock = sock
        self.addr = addr
        self.lock = threading.Lock()
        self.raw = False
        self.ready_at = 0.0
        self.pending: list[bytes] = []
        self.grace_s = grace_s
        self.alive = True

    def enter_raw(self) -> None:
        with self.lock:
            self.raw = True
            self.ready_at = time.monotonic() + self.grace_s
        timer = threading.Timer(self.grace_s, self.flush)
        timer.daemon = True
        timer.start()

    def flush(self) -> None:
        with self.lock:
            if self.pending and self.alive:
                data, self.pending = b"".join(self.pending), []
                self._sendall(data)

    def send_frame(self, element: bytes) -> None:
        with self.lock:
            if not self.raw or not self.alive:
                return
            if time.monotonic() < self.ready_at:
                self.pending.append(element)
                return
            if self.pending:
                element, self.pending = b"".join(self.pending) + element, []
            self._sendall(element)

    def send_text(self, text: str) -> None:
        with self.lock:
            self._sendall(text.encode("ascii"))

    def _sendall(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError as exc:
            log.info("socketcand hub: client %s gone (%s)", self.addr, exc)
            self.alive = False


class CanHub:
    """socketcand-compatible TCP hub (raw mode) for one CAN channel; see the module docstring.

    ``bus`` is an optional in-process python-can bus bridged to the TCP clients (the hub
    reads it in its own thread; do not attach a notifier to the same bus object).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        channel: str = "can0",
        bus: can.BusABC | None = None,
        handshake_grace_s: float = 0.05,
    ) -> None:
        self.channel = channel
        self.bus = bus
        self.grace_s = handshake_grace_s
        self._server = socket.create_server((host, port))
        self._server.settimeout(0.2)
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        #: the wire: a frame is stamped and sent to every client under it, so that every
        #: client (a CAN logger among them) gets the frames in one order, the order of their
        #: timestamps (a SYNC after the answers to the one before, as on a real bus)
        self._wire = threading.Lock()
        self._running = False
        self._threads: list[threading.Thread] = []
        #: malformed elements received (dropped)
        self.bad_messages = 0
        #: frames forwarded from clients
        self.frames_in = 0

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the hub listens on."""
        host, port = self._server.getsockname()[:2]
        return host, port

    def start(self) -> CanHub:
        self._running = True
        self._spawn(self._accept_loop, "can-hub-accept")
        if self.bus is not None:
            self._spawn(self._bridge_loop, "can-hub-bridge")
        return self

    def _spawn(self, fn, name: str, *args) -> threading.Thread:
        t = threading.Thread(target=fn, args=args, name=name, daemon=True)
        t.start()
        self._threads.append(t)
        return t

    def close(self) -> None:
        """Stop serving: disconnect clients, stop the threads (the bridged bus stays open)."""
        self._running = False
        try:
            self._server.close()
        except OSError:
            pass
        with self._lock:
            clients, self._clients = self._clients, []
        for c in clients:
            c.alive = False
            try:
                c.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.sock.close()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)

    def __enter__(self) -> CanHub:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def n_clients(self) -> int:
        with self._lock:
            return sum(1 for c in self._clients if c.raw and c.alive)

    # ------------------------------------------------------------------ threads

    def _accept_loop(self) -> None:
        while self._running:
            try:
                sock, addr = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, addr, self.grace_s)
            with self._lock:
                self._clients.append(client)
            self._spawn(self._serve, f"can-hub-client-{addr[1]}", client)

    def _bridge_loop(self) -> None:
        assert self.bus is not None
        while self._running:
            try:
                msg = self.bus.recv(timeout=0.1)
            except can.CanError as exc:
                log.warning("socketcand hub: bridged bus failed: %s", exc)
                break
            batch = []
            while msg is not None:  # with whatever else is waiting: one write per client
                if not (msg.is_error_frame or msg.is_remote_frame):
                    batch.append(msg)
                if len(batch) >= MAX_BATCH:
                    break
                try:
                    msg = self.bus.recv(timeout=0.0)
                except can.CanError:
                    msg = None
            if batch:
                with self._wire:
                    now = time.time()
                    self._broadcast(b"".join(frame_element(m, now) for m in batch),
                                    exclude=None)

    def _broadcast(self, element: bytes, exclude: _Client | None) -> None:
        with self._lock:
            targets = [c for c in self._clients if c is not exclude]
        for c in targets:
            c.send_frame(element)

    def _serve(self, client: _Client) -> None:
        sock = client.sock
        client.send_text("< hi >")
        buf = ""
        opened = False
        try:
            while self._running and client.alive:
                try:
                    chunk = sock.recv(4096)
                except OSError:
                    break
                if not chunk:
                    break
                buf += chunk.decode("ascii", errors="replace")
                while True:
                    start = buf.find("<")
                    if start < 0:
                        buf = ""
                        break
                    end = buf.find(">", start)
                    if end < 0:
                        buf = buf[start:]
                        if len(buf) > 1024:
                            self.bad_messages += 1
                            buf = ""
                        break
                    element, buf = buf[start:end + 1], buf[end + 1:]
                    opened = self._handle(client, element, opened)
        finally:
            client.alive = False
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)
            try:
                sock.close()
            except OSError:
                pass

    def _handle(self, client: _Client, element: str, opened: bool) -> bool:
        words = element[1:-1].split()
        if not words:
            self.bad_messages += 1
            return opened
        cmd = words[0]
        if cmd == "send" and client.raw:
            try:
                msg = parse_send(element)
            except ValueError as exc:
                self.bad_messages += 1
                log.info("socketcand hub: dropped %r from %s: %s", element, client.addr, exc)
                return opened
            self.frames_in += 1
            with self._wire:
                msg.timestamp = time.time()
                self._broadcast(frame_element(msg), exclude=client)
            if self.bus is not None:
                try:
                    self.bus.send(msg)
                except can.CanError as exc:
                    log.warning("socketcand hub: bridged bus refused a frame: %s", exc)
        elif cmd == "open" and not opened:
            if len(words) == 2 and words[1] == self.channel:
                client.send_text("< ok >")
                return True
            client.send_text(f"< error could not open bus {' '.join(words[1:])} >")
        elif cmd == "rawmode" and opened and not client.raw:
            client.send_text("< ok >")
            client.enter_raw()
        elif cmd == "echo":
            client.send_text("< echo >")
        else:
            self.bad_messages += 1
            log.info("socketcand hub: unsupported element %r from %s", element, client.addr)
        return opened
