"""A socketcand client that survives its link: reconnects on its own and says when it is down.

python-can's own ``socketcand`` interface treats the TCP connection as forever: when the
server (the simulated rig's hub, a socketcand daemon on a CAN adapter's host) goes away,
its receive thread spins on an empty socket, sends raise a bare ``BrokenPipeError``, and it
logs a WARNING for every TCP read that ends mid-frame. :class:`SocketcandLink` speaks the
same raw-mode protocol (``< hi >``, ``< open CH >``, ``< rawmode >``, ``< send ... >``,
``< frame ... >``) as a python-can bus, and

- notices the end of the connection (EOF, reset, refused send): :attr:`link_up` turns
  False, :attr:`link_error` says why, sends raise :class:`can.CanOperationError` naming the
  server;
- reconnects by itself every ``retry_s`` from its receive side (the notifier thread) and
  counts it in :attr:`link_epoch` (1 after the first connection, +1 per reconnect), so that
  a user (the HAL) can tell that whatever listened on the other side may have restarted;
- buffers partial TCP reads silently (a frame split over two reads is normal, not news).

It is what :func:`hal.can_bus.open_bus` opens for ``--can socketcand:HOST:PORT``.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time

import can

log = logging.getLogger(__name__)

#: one protocol element may not be longer than this (a frame is ~45 characters)
MAX_ELEMENT = 256


class SocketcandLink(can.BusABC):
    """python-can bus over a socketcand server, reconnecting (see the module docstring).

    :param channel: the CAN interface the server serves (``can0``)
    :param host, port: the server
    :param connect_timeout: seconds for one connection attempt and its handshake
    :param retry_s: seconds between reconnection attempts while the link is down
    :param reconnect: False: stay down once the link is lost
    """

    def __init__(self, channel: str, host: str, port: int, *, connect_timeout: float = 2.0,
                 retry_s: float = 0.5, reconnect: bool = True, tcp_tune: bool = True,
                 can_filters=None, **kwargs) -> None:
        self.host = host
        self.port = int(port)
        self.connect_timeout = float(connect_timeout)
        self.retry_s = float(retry_s)
        self.reconnect = reconnect
        self.tcp_tune = tcp_tune
        self.channel = channel
        self.channel_info = f"socketcand {channel}@{host}:{port}"
        self._lock = threading.Lock()  # guards the socket and the link state
        self._sock: socket.socket | None = None
        self._buf = b""
        self._pending: list[can.Message] = []
        self.link_up = False
        self.link_epoch = 0  #: successful connections so far
        self.link_error = ""  #: why the link went down last (empty while it never did)
        self.losses = 0  #: times the link was lost
        self.bad_elements = 0  #: protocol elements that could not be parsed
        self._next_try = 0.0
        self._closed = False
        try:
            self._connect()
        except OSError as exc:
            raise can.CanInitializationError(f"{self.where}: {exc}") from exc
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    @property
    def where(self) -> str:
        return f"socketcand server {self.host}:{self.port} (channel {self.channel})"

    # ------------------------------------------------------------------ connection

    def _connect(self) -> None:
        """Connect and handshake; OSError (or ConnectionError) when it does not work."""
        sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        try:
            if self.tcp_tune:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            buf = b""
            buf = self._expect(sock, buf, b"< hi >")
            sock.sendall(f"< open {self.channel} >".encode("ascii"))
            buf = self._expect(sock, buf, b"< ok >")
            sock.sendall(b"< rawmode >")
            buf = self._expect(sock, buf, b"< ok >")
            sock.settimeout(1.0)  # bounds sendall(); reads only after select() says ready
        except BaseException:
            sock.close()
            raise
        with self._lock:
            self._sock = sock
            self._buf = buf
            self.link_up = True
            self.link_epoch += 1
        if self.link_epoch > 1:
            log.info("%s: link back (connection %d)", self.where, self.link_epoch)

    @staticmethod
    def _expect(sock: socket.socket, buf: bytes, want: bytes) -> bytes:
        """Read until one element has arrived; it must be ``want``; returns what follows."""
        while b">" not in buf:
            chunk = sock.recv(256)
            if not chunk:
                raise ConnectionError(f"closed during the handshake (waiting for {want!r})")
            buf += chunk
            if len(buf) > MAX_ELEMENT:
                raise ConnectionError(f"not a socketcand server (sent {buf[:40]!r})")
        end = buf.index(b">") + 1
        got = buf[buf.index(b"<") if b"<" in buf[:end] else 0:end].strip()
        if b" ".join(got.split()) != want:
            raise ConnectionError(f"expected {want.decode()}, got {got.decode('ascii', 'replace')}")
        return buf[end:]

    def _drop(self, why: str) -> None:
        with self._lock:
            if self._sock is None:
                return
            try:
                self._sock.close()
            except OSError:
                pass
            self._sock = None
            self._buf = b""
            self.link_up = False
            self.link_error = why
            self.losses += 1
            self._next_try = time.monotonic() + self.retry_s
        log.warning("%s: link lost: %s", self.where, why)

    def _try_reconnect(self) -> None:
        if self._closed or not self.reconnect or time.monotonic() < self._next_try:
            return
        try:
            self._connect()
        except OSError as exc:
            with self._lock:
                self.link_error = f"reconnecting: {exc}"
                self._next_try = time.monotonic() + self.retry_s

    # ------------------------------------------------------------------ python-can bus

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.pop(0), False
        sock = self._sock
        if sock is None:
            self._try_reconnect()
            if self._sock is None:
                wait = 0.05 if timeout is None else min(timeout, 0.05)
                time.sleep(max(0.0, wait))
                return None, False
            sock = self._sock
        try:
            ready, _, _ = select.select([sock], [], [], timeout)
        except (OSError, ValueError) as exc:  # closed under us
            self._drop(f"select failed: {exc}")
            return None, False
        if not ready:
            return None, False
        try:
            chunk = sock.recv(4096)
        except (BlockingIOError, TimeoutError):
            return None, False
        except OSError as exc:
            self._drop(f"receive failed: {exc}")
            return None, False
        if not chunk:
            self._drop("the server closed the connection")
            return None, False
        self._buf += chunk
        self._parse()
        if self._pending:
            return self._pending.pop(0), False
        return None, False

    def _parse(self) -> None:
        buf = self._buf
        while True:
            start = buf.find(b"<")
            if start < 0:
                buf = b""
                break
            end = buf.find(b">", start)
            if end < 0:
                if len(buf) - start > MAX_ELEMENT:
                    self.bad_elements += 1
                    buf = b""
                else:
                    buf = buf[start:]
                break
            element = buf[start + 1:end].split()
            buf = buf[end + 1:]
            if element and element[0] == b"frame":
                msg = self._frame(element)
                if msg is None:
                    self.bad_elements += 1
                else:
                    self._pending.append(msg)
            elif element and element[0] == b"error":
                log.debug("%s: %s", self.where, b" ".join(element).decode("ascii", "replace"))
        self._buf = buf

    def _frame(self, parts: list[bytes]) -> can.Message | None:
        """``frame ID SECONDS.USECONDS [DATA...]`` as a message (None if malformed)."""
        if len(parts) < 3:
            return None
        try:
            can_id = int(parts[1], 16)
            data = bytes.fromhex(b"".join(parts[3:]).decode("ascii"))
        except ValueError:
            return None
        extended = len(parts[1]) > 3
        if len(data) > 8 or can_id > (0x1FFFFFFF if extended else 0x7FF):
            return None
        return can.Message(timestamp=time.time(), arbitration_id=can_id, data=data,
                           dlc=len(data), is_extended_id=extended, is_rx=True,
                           channel=self.channel)

    @staticmethod
    def _element(msg: can.Message) -> str:
        can_id = (f"{msg.arbitration_id & 0x1FFFFFFF:08X}" if msg.is_extended_id
                  else f"{msg.arbitration_id & 0x7FF:03X}")
        data = bytes(msg.data[:msg.dlc])
        return f"< send {can_id} {len(data):X} {' '.join(f'{b:02X}' for b in data)} >"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._send_text(self._element(msg))

    def send_batch(self, msgs: list[can.Message]) -> None:
        """Send frames in order in one TCP write (a cycle's RPDOs and SYNC: one segment, one
        wake-up of the server instead of one per frame; socketcand reads a stream of
        elements, so the frames are the same). All or nothing on this side of the link."""
        if msgs:
            self._send_text("".join(self._element(m) for m in msgs))

    def _send_text(self, text: str) -> None:
        with self._lock:
            sock = self._sock
            if sock is None:
                raise can.CanOperationError(f"{self.where}: link down ({self.link_error})")
            try:
                sock.sendall(text.encode("ascii"))
            except OSError as exc:
                err = exc
            else:
                err = None
        if err is not None:
            self._drop(f"send failed: {err}")
            raise can.CanOperationError(f"{self.where}: send failed: {err}") from err

    def shutdown(self) -> None:
        self._closed = True
        with self._lock:
            if self._sock is not None:
                try:
                    self._sock.close()
                except OSError:
                    pass
                self._sock = None
            self.link_up = False
        super().shutdown()


__all__ = ["SocketcandLink"]
