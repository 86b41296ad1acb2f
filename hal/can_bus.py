"""Open the CAN bus from one command-line form shared by every command.

``--can SPEC`` where SPEC is

- ``virtual:NAME``             python-can's in-process virtual bus (tests, one process)
- ``socketcand:HOST:PORT``     a socketcand server, e.g. the simulated rig's hub
  (``socketcand:HOST:PORT:CHANNEL`` to open another channel than ``can0``; IPv6 hosts in
  brackets: ``socketcand:[::1]:29536``)
- ``socketcan:CHANNEL``        Linux SocketCAN, e.g. ``socketcan:can0`` on the robot
- ``INTERFACE:CHANNEL``        any other python-can interface (``pcan:PCAN_USBBUS1``,
  ``kvaser:0``, ...), passed to :func:`can.Bus` as is

:func:`parse_can_spec` checks the form and raises :class:`CanSpecError` naming what is
wrong; :func:`open_bus` opens it. A socketcand link is a
:class:`hal.socketcand_link.SocketcandLink`: it reconnects on its own when the server comes
back and tells its users (``link_up``, ``link_epoch``).

Logging: python-can's own socketcand client (used by third-party tools in this process)
logs a WARNING for every TCP read that ends in the middle of a frame, over a thousand lines
a minute under load, for something that is normal on a stream; importing this module
drops exactly those records (:class:`QuietPartialReads`; ``dropped`` counts them).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import socket
import time
from dataclasses import dataclass, field
from typing import Any

import can
from can.interfaces import VALID_INTERFACES
from can.interfaces.virtual import VirtualBus

from hal.cli_args import CAN_FORMS as _FORMS  # one text of the forms
from hal.cli_args import add_can_argument  # noqa: F401  (re-exported)

DEFAULT_SOCKETCAND_CHANNEL = "can0"


class QuietPartialReads(logging.Filter):
    """Drops python-can's socketcand "incomplete message" warnings (see the module docstring);
    every other record passes."""

    NOISE = ("Got incomplete message", "Incomplete message exceeds")

    def __init__(self) -> None:
        super().__init__()
        self.dropped = 0

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.msg if isinstance(record.msg, str) else ""
        if msg.startswith(self.NOISE):
            self.dropped += 1
            return False
        return True


_PYCAN_SOCKETCAND = logging.getLogger("can.interfaces.socketcand.socketcand")
if not any(isinstance(f, QuietPartialReads) for f in _PYCAN_SOCKETCAND.filters):
    _PYCAN_SOCKETCAND.addFilter(QuietPartialReads())


class CanSpecError(ValueError):
    """A ``--can`` specification is malformed; the message says which part and why."""


@dataclass(frozen=True)
class CanSpec:
    """A parsed ``--can`` specification."""

    interface: str
    channel: str
    host: str | None = None
    port: int | None = None
    options: dict[str, Any] = field(default_factory=dict)

    def bus_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for :func:`can.Bus`."""
        kw: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.interface == "socketcand":
            kw.update(host=self.host, port=self.port, tcp_tune=True)
        kw.update(self.options)
        return kw

    def __str__(self) -> str:
        if self.interface == "socketcand":
            host = f"[{self.host}]" if self.host and ":" in self.host else self.host
            tail = "" if self.channel == DEFAULT_SOCKETCAND_CHANNEL else f":{self.channel}"
            return f"socketcand:{host}:{self.port}{tail}"
        return f"{self.interface}:{self.channel}"




def _port(text: str, spec: str) -> int:
    try:
        port = int(text, 10)
    except ValueError:
        raise CanSpecError(f"--can {spec!r}: port {text!r} is not a number") from None
    if not 1 <= port <= 65535:
        raise CanSpecError(f"--can {spec!r}: port {port} is not in 1..65535")
    return port


def parse_can_spec(spec: str) -> CanSpec:
    """Parse a ``--can`` specification (see the module docstring)."""
    if not isinstance(spec, str) or not spec.strip():
        raise CanSpecError(f"--can: empty specification; expected {_FORMS}")
    spec = spec.strip()
    interface, sep, rest = spec.partition(":")
    if not sep:
        raise CanSpecError(f"--can {spec!r}: missing ':'; expected {_FORMS}")
    if interface not in VALID_INTERFACES:
        raise CanSpecError(
            f"--can {spec!r}: unknown python-can interface {interface!r}; "
            f"known: {', '.join(sorted(VALID_INTERFACES))}"
        )
    if interface == "socketcand":
        if rest.startswith("["):
            close = rest.find("]")
            if close < 0:
                raise CanSpecError(f"--can {spec!r}: '[' of an IPv6 host without ']'")
            host, after = rest[1:close], rest[close + 1:]
            if not after.startswith(":"):
                raise CanSpecError(f"--can {spec!r}: expected ':PORT' after the host")
            parts = after[1:].split(":")
        else:
            host, *parts = rest.split(":")
        if not host:
            raise CanSpecError(f"--can {spec!r}: missing host; expected socketcand:HOST:PORT")
        if not parts or not parts[0]:
            raise CanSpecError(f"--can {spec!r}: missing port; expected socketcand:HOST:PORT")
        if len(parts) > 2:
            raise CanSpecError(f"--can {spec!r}: too many ':' fields; "
                               "expected socketcand:HOST:PORT[:CHANNEL]")
        port = _port(parts[0], spec)
        channel = parts[1] if len(parts) == 2 else DEFAULT_SOCKETCAND_CHANNEL
        if not channel:
            raise CanSpecError(f"--can {spec!r}: empty channel after the port")
        return CanSpec("socketcand", channel, host=host, port=port)
    if not rest:
        raise CanSpecError(f"--can {spec!r}: missing channel after '{interface}:'")
    if interface in ("virtual", "socketcan") and ":" in rest:
        raise CanSpecError(f"--can {spec!r}: channel {rest!r} must not contain ':'")
    return CanSpec(interface, rest)


class LightVirtualBus(VirtualBus):
    """python-can's in-process virtual bus with a cheap copy of each frame sent.

    The stock bus deep-copies every message for every receiver (~25 us each, a third of a
    lock-step dry run's bus time); a frame's fields are plain values and its data a byte
    array, so a field-by-field copy is the same message. Interoperates with
    ``can.Bus(interface="virtual")`` on the same channel (the channels are shared)."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            copy = can.Message(
                timestamp=timestamp, arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame, channel=self.channel_id, dlc=msg.dlc,
                data=bytearray(msg.data), is_fd=msg.is_fd, is_rx=bus_queue is not self.queue,
                bitrate_switch=msg.bitrate_switch,
                error_state_indicator=msg.error_state_indicator, check=False)
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def send_frames(bus: can.BusABC, msgs: list[can.Message]) -> None:
    """Send ``msgs`` in order: in one write where the bus can (``send_batch``, e.g.
    :class:`hal.socketcand_link.SocketcandLink`), else one ``send`` each."""
    batch = getattr(bus, "send_batch", None)
    if batch is not None:
        batch(msgs)
        return
    for m in msgs:
        bus.send(m)


@contextlib.contextmanager
def connected_network(spec, notifier_cycle_s: float = 0.05):
    """A connected ``canopen.Network`` on the bus of ``spec`` (a :class:`CanSpec` or its
    text), disconnected (and the bus shut down) at exit; the bus is shut down when the
    connection fails."""
    import canopen

    bus = open_bus(spec)
    net = canopen.Network(bus)
    net.NOTIFIER_CYCLE = notifier_cycle_s
    try:
        net.connect()
    except Exception:
        bus.shutdown()
        raise
    try:
        yield net
    finally:
        net.disconnect()


def open_bus(spec: str | CanSpec, **options: Any) -> can.BusABC:
    """Open the bus of a ``--can`` specification (extra ``options`` go to :func:`can.Bus`)."""
    s = parse_can_spec(spec) if isinstance(spec, str) else spec
    if s.interface == "socketcand":
        # python-can retries a refused connection for 10 s; fail fast with a clear message
        try:
            socket.create_connection((s.host, s.port), timeout=2.0).close()
        except OSError as exc:
            raise can.CanInitializationError(
                f"--can {s}: no socketcand server at {s.host}:{s.port}: {exc}") from exc
    kw = s.bus_kwargs()
    kw.update(options)
    try:
        if s.interface == "socketcand":
            from hal.socketcand_link import SocketcandLink

            kw.pop("interface")
            return SocketcandLink(**kw)
        if s.interface == "virtual":
            kw.pop("interface")
            return LightVirtualBus(**kw)
        return can.Bus(**kw)
    except (can.CanError, OSError, TimeoutError, ValueError) as exc:
        raise can.CanInitializationError(f"--can {s}: cannot open the bus: {exc}") from exc


