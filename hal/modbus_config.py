"""Modbus endpoint configuration: the ``--modbus`` spec and the pymodbus client it makes.

Spec forms (one command-line string)::

    HOST:PORT                      Modbus/TCP            e.g. 192.168.1.20:502
    rtu:DEVICE:BAUD[:FRAMING]      serial RTU            e.g. rtu:/dev/ttyUSB0:115200:8E1
    rtu-tcp:HOST:PORT              RTU framing over TCP  e.g. rtu-tcp:10.0.0.7:4001

``DEVICE`` may be any pyserial URL (``socket://host:port``, ``rfc2217://...``)
since pymodbus opens it with ``serial.serial_for_url``. ``FRAMING`` is data
bits, parity (N, E, O) and stop bits, default ``8N1``. IPv6 hosts go in
brackets: ``[::1]:502``.
"""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.framer import FramerType

from hal.cli_args import MODBUS_FORMS as FORMS  # one text of the forms
from hal.cli_args import add_modbus_arguments  # noqa: F401  (re-exported)

DEFAULT_TCP_PORT = 502
_FRAMING = re.compile(r"^([78])([NEO])([12])$")
_BAUD_RANGE = (300, 4_000_000)


class ModbusSpecError(ValueError):
    """A malformed ``--modbus`` spec; the message says which part and the accepted forms."""




@dataclass(frozen=True)
class ModbusEndpoint:
    """Where the load cells are: ``kind`` is ``"tcp"``, ``"rtu"`` or ``"rtu-tcp"``."""

    kind: str
    host: str = ""
    port: int = 0
    device: str = ""
    baudrate: int = 0
    bytesize: int = 8
    parity: str = "N"
    stopbits: int = 1

    def __str__(self) -> str:
        if self.kind == "rtu":
            return (
                f"rtu:{self.device}:{self.baudrate}:{self.bytesize}{self.parity}{self.stopbits}"
            )
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}" if self.kind == "tcp" else f"rtu-tcp:{host}:{self.port}"

    def make_client(self, timeout_s: float) -> ModbusTcpClient | ModbusSerialClient:
        """A synchronous pymodbus client (not connected yet), no retries: the poller retries."""
        if self.kind == "rtu":
            try:
                import serial  # noqa: F401  (pymodbus needs pyserial for serial lines)
            except ImportError as exc:  # pragma: no cover - pyserial is a dependency
                raise RuntimeError(f"{self}: serial RTU needs pyserial") from exc
            return ModbusSerialClient(
                self.device,
                framer=FramerType.RTU,
                baudrate=self.baudrate,
                bytesize=self.bytesize,
                parity=self.parity,
                stopbits=self.stopbits,
                timeout=timeout_s,
                retries=0,
            )
        return ModbusTcpClient(
            self.host,
            port=self.port,
            framer=FramerType.RTU if self.kind == "rtu-tcp" else FramerType.SOCKET,
            timeout=timeout_s,
            retries=0,
        )


def _host_port(spec: str, text: str) -> tuple[str, int]:
    if text.startswith("["):
        host, sep, rest = text[1:].partition("]")
        if not sep or not rest.startswith(":"):
            raise ModbusSpecError(f"--modbus {spec!r}: IPv6 host needs the form [ADDR]:PORT")
        port_text = rest[1:]
    else:
        host, sep, port_text = text.rpartition(":")
        if not sep:
            raise ModbusSpecError(f"--modbus {spec!r}: missing ':PORT' (forms: {FORMS})")
        if ":" in host:
            raise ModbusSpecError(
                f"--modbus {spec!r}: too many ':' in host {host!r} "
                f"(IPv6 in brackets: [::1]:502; forms: {FORMS})"
            )
    if not host:
        raise ModbusSpecError(f"--modbus {spec!r}: empty host (forms: {FORMS})")
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ModbusSpecError(f"--modbus {spec!r}: port {port_text!r} is not in 1..65535")
    return host, int(port_text)


def parse_modbus_spec(spec: str) -> ModbusEndpoint:
    """Endpoint from a ``--modbus`` string; :class:`ModbusSpecError` on a malformed one."""
    if not isinstance(spec, str) or not spec.strip():
        raise ModbusSpecError(f"--modbus: empty spec (forms: {FORMS})")
    spec = spec.strip()
    scheme, sep, rest = spec.partition(":")
    if sep and scheme.lower() == "rtu-tcp":
        host, port = _host_port(spec, rest)
        return ModbusEndpoint("rtu-tcp", host=host, port=port)
    if sep and scheme.lower() == "rtu":
        parts = rest.rsplit(":", 2)
        framing = "8N1"
        if len(parts) == 3 and _FRAMING.match(parts[2].upper()):
            device, baud_text, framing = parts[0], parts[1], parts[2].upper()
        elif len(parts) == 3 and parts[1].isdigit() and not parts[2].isdigit():
            raise ModbusSpecError(
                f"--modbus {spec!r}: framing {parts[2]!r} must be data bits, parity, stop bits "
                "like 8N1, 8E1, 8O2"
            )
        else:
            device, _, baud_text = rest.rpartition(":")
        if not device:
            raise ModbusSpecError(
                f"--modbus {spec!r}: serial RTU needs rtu:DEVICE:BAUD, e.g. rtu:/dev/ttyUSB0:19200"
            )
        lo, hi = _BAUD_RANGE
        if not baud_text.isdigit() or not lo <= int(baud_text) <= hi:
            raise ModbusSpecError(
                f"--modbus {spec!r}: baud rate {baud_text!r} is not an integer in {lo}..{hi} "
                "(form rtu:DEVICE:BAUD[:8N1])"
            )
        m = _FRAMING.match(framing)
        assert m is not None
        return ModbusEndpoint(
            "rtu",
            device=device,
            baudrate=int(baud_text),
            bytesize=int(m.group(1)),
            parity=m.group(2),
            stopbits=int(m.group(3)),
        )
    if sep and scheme.lower() in ("tcp", "modbus", "rtu-over-tcp", "serial"):
        raise ModbusSpecError(f"--modbus {spec!r}: unknown scheme {scheme!r} (forms: {FORMS})")
    host, port = _host_port(spec, spec)
    return ModbusEndpoint("tcp", host=host, port=port)


def modbus_spec_arg(text: str) -> ModbusEndpoint:
    """argparse ``type=`` for ``--modbus`` (turns spec errors into usage errors)."""
    try:
        return parse_modbus_spec(text)
    except ModbusSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


