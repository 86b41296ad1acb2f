"""The shared ``--can`` specification (hal/can_bus.py)."""

from __future__ import annotations

import argparse
import socket

import can
import pytest

from hal.can_bus import CanSpec, CanSpecError, add_can_argument, open_bus, parse_can_spec


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("virtual:rig", CanSpec("virtual", "rig")),
        ("socketcan:can0", CanSpec("socketcan", "can0")),
        ("socketcand:127.0.0.1:29536", CanSpec("socketcand", "can0", "127.0.0.1", 29536)),
        ("socketcand:localhost:1:vcan1", CanSpec("socketcand", "vcan1", "localhost", 1)),
        ("socketcand:[::1]:29536", CanSpec("socketcand", "can0", "::1", 29536)),
        ("pcan:PCAN_USBBUS1", CanSpec("pcan", "PCAN_USBBUS1")),
        ("  kvaser:0 ", CanSpec("kvaser", "0")),
    ],
)
def test_valid_specs(text, expected):
    spec = parse_can_spec(text)
    assert spec == expected
    assert parse_can_spec(str(spec)) == spec  # printable and round-trips


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("", "empty"),
        ("virtual", "missing ':'"),
        ("vcan:can0", "unknown python-can interface 'vcan'"),
        ("virtual:", "missing channel"),
        ("socketcand:127.0.0.1", "missing port"),
        ("socketcand::29536", "missing host"),
        ("socketcand:host:http", "port 'http' is not a number"),
        ("socketcand:host:70000", "not in 1..65535"),
        ("socketcand:host:1:can0:x", "too many"),
        ("socketcand:[::1:5", "without ']'"),
        ("socketcan:can0:1", "must not contain ':'"),
    ],
)
def test_malformed_specs_say_what_is_wrong(text, needle):
    with pytest.raises(CanSpecError) as exc:
        parse_can_spec(text)
    assert needle in str(exc.value)
    assert "--can" in str(exc.value)


def test_bus_kwargs_for_socketcand_tune_tcp():
    kw = parse_can_spec("socketcand:127.0.0.1:5000").bus_kwargs()
    assert kw == {"interface": "socketcand", "channel": "can0", "host": "127.0.0.1",
                  "port": 5000, "tcp_tune": True}


def test_open_virtual_bus_carries_frames():
    a = open_bus("virtual:test-can-bus-open")
    b = open_bus(parse_can_spec("virtual:test-can-bus-open"))
    try:
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        msg = b.recv(timeout=2.0)
        assert msg is not None and msg.arbitration_id == 0x123 and bytes(msg.data) == b"\x01\x02"
    finally:
        a.shutdown()
        b.shutdown()


def test_socketcand_without_server_fails_fast_and_clearly():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    with pytest.raises(can.CanInitializationError,
                       match=f"no socketcand server at 127.0.0.1:{port}"):
        open_bus(f"socketcand:127.0.0.1:{port}")


def test_argparse_option():
    p = argparse.ArgumentParser()
    add_can_argument(p, default="virtual:default")
    assert p.parse_args([]).can == CanSpec("virtual", "default")
    assert p.parse_args(["--can", "socketcan:can1"]).can == CanSpec("socketcan", "can1")
    with pytest.raises(SystemExit):
        p.parse_args(["--can", "nonsense"])
