"""The socketcand-compatible hub (firmware_sim/can_hub.py) with python-can's own client."""

from __future__ import annotations

import socket
import time
import uuid

import can
import pytest

from firmware_sim.can_hub import CanHub, frame_element, parse_send


def _client(hub: CanHub, channel: str = "can0") -> can.BusABC:
    host, port = hub.address
    return can.Bus(interface="socketcand", host=host, port=port, channel=channel, tcp_tune=True)


def _recv(bus: can.BusABC, timeout: float = 3.0) -> can.Message | None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = bus.recv(timeout=0.1)
        if msg is not None:
            return msg
    return None


def _wait_clients(hub: CanHub, n: int, timeout: float = 3.0) -> None:
    deadline = time.monotonic() + timeout
    while hub.n_clients < n:
        assert time.monotonic() < deadline, f"hub has {hub.n_clients} raw clients, wanted {n}"
        time.sleep(0.005)


def test_frame_element_matches_socketcand_format():
    m = can.Message(arbitration_id=0x181, data=b"\x37\x12\x00\x10\x00\x00", is_extended_id=False)
    assert frame_element(m, 12.5) == b"< frame 181 12.500000 371200100000 >"
    sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
    assert frame_element(sync, 1.0) == b"< frame 080 1.000000  >"
    ext = can.Message(arbitration_id=0x18FF50E5, data=b"\x01", is_extended_id=True)
    assert frame_element(ext, 0.0).startswith(b"< frame 18FF50E5 0.000000 01")


def test_parse_send_as_python_can_writes_it():
    from can.interfaces.socketcand.socketcand import convert_can_message_to_ascii_message

    for data, ext, cid in ((b"", False, 0x80), (bytes(range(8)), False, 0x7FF),
                           (b"\xff", True, 0x1ABCDEF)):
        msg = can.Message(arbitration_id=cid, data=data, is_extended_id=ext)
        back = parse_send(convert_can_message_to_ascii_message(msg))
        assert (back.arbitration_id, bytes(back.data), back.is_extended_id) == (cid, data, ext)


@pytest.mark.parametrize("bad", ["< send 1234 1 ff >", "< send 123 2 ff >", "< send 800 0 >",
                                 "< send 123 1 fff >", "< send >"])
def test_parse_send_rejects_malformed(bad):
    with pytest.raises(ValueError):
        parse_send(bad)


def test_frames_reach_every_other_client_and_not_the_sender():
    with CanHub() as hub:
        a, b, c = _client(hub), _client(hub), _client(hub)
        try:
            _wait_clients(hub, 3)
            time.sleep(hub.grace_s * 2)
            sent = [can.Message(arbitration_id=0x80, data=b"", is_extended_id=False),
                    can.Message(arbitration_id=0x201, data=b"\x0f\x00\x10\x27\x00\x00",
                                is_extended_id=False),
                    can.Message(arbitration_id=0x1FFFFFF0, data=bytes(range(8)),
                                is_extended_id=True)]
            for m in sent:
                a.send(m)
            for rx in (b, c):
                for m in sent:
                    got = _recv(rx)
                    assert got is not None
                    assert got.arbitration_id == m.arbitration_id
                    assert bytes(got.data) == bytes(m.data)
                    assert got.is_extended_id == m.is_extended_id
            assert a.recv(timeout=0.05) is None
            assert hub.bad_messages == 0 and hub.frames_in == 3
        finally:
            for bus in (a, b, c):
                bus.shutdown()


def test_bridges_an_in_process_bus_both_ways():
    ch = f"hub-bridge-{uuid.uuid4().hex}"
    hub_side = can.Bus(interface="virtual", channel=ch)
    rig_side = can.Bus(interface="virtual", channel=ch)
    try:
        with CanHub(bus=hub_side) as hub:
            tcp = _client(hub)
            try:
                _wait_clients(hub, 1)
                # sent by the rig right away: queued during the handshake grace, not lost
                rig_side.send(can.Message(arbitration_id=0x701, data=b"\x00",
                                          is_extended_id=False))
                got = _recv(tcp)
                assert got is not None and got.arbitration_id == 0x701 and got.data == b"\x00"
                tcp.send(can.Message(arbitration_id=0x601, data=b"\x40\x00\x10\x00\0\0\0\0",
                                     is_extended_id=False))
                got = _recv(rig_side)
                assert got is not None and got.arbitration_id == 0x601
                assert bytes(got.data) == b"\x40\x00\x10\x00\0\0\0\0"
            finally:
                tcp.shutdown()
    finally:
        hub_side.shutdown()
        rig_side.shutdown()


def test_wrong_channel_is_refused_by_the_handshake():
    with CanHub(channel="can0") as hub, pytest.raises(can.CanError, match="could not open bus"):
        _client(hub, channel="can7")


def test_malformed_input_is_counted_and_dropped_without_breaking_the_hub():
    with CanHub() as hub:
        good = _client(hub)
        try:
            raw = socket.create_connection(hub.address, timeout=2.0)
            assert raw.recv(64) == b"< hi >"
            raw.sendall(b"< open can0 >")
            assert raw.recv(64) == b"< ok >"
            raw.sendall(b"< rawmode >")
            assert raw.recv(64) == b"< ok >"
            raw.sendall(b"< echo >")
            assert raw.recv(64) == b"< echo >"
            raw.sendall(b"< send 12345 1 00 >< bogus >< send 123 1 aa >")
            _wait_clients(hub, 2)
            got = _recv(good)
            assert got is not None and got.arbitration_id == 0x123 and got.data == b"\xaa"
            assert hub.bad_messages == 2
            raw.close()
        finally:
            good.shutdown()


def test_a_batch_of_frames_goes_out_in_one_write_and_arrives_in_order_both_ways():
    """The HAL's link sends a cycle's RPDOs and SYNC in one TCP write (send_batch); the hub
    bridges them in order, and frames waiting on the bridged bus come back in order in
    one write too."""
    from hal.can_bus import send_frames
    from hal.socketcand_link import SocketcandLink

    ch = f"hub-batch-{uuid.uuid4().hex}"
    hub_side = can.Bus(interface="virtual", channel=ch)
    rig_side = can.Bus(interface="virtual", channel=ch)
    try:
        with CanHub(bus=hub_side) as hub:
            host, port = hub.address
            link = SocketcandLink("can0", host, port)
            try:
                _wait_clients(hub, 1)
                time.sleep(0.1)  # past the handshake grace
                out = [can.Message(arbitration_id=0x201 + k, data=bytes([k, 1, 2, 3]),
                                   is_extended_id=False) for k in range(8)]
                out.append(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
                send_frames(link, out)
                got = [_recv(rig_side) for _ in out]
                assert [(m.arbitration_id, bytes(m.data)) for m in got] == \
                    [(m.arbitration_id, bytes(m.data)) for m in out]
                back = [can.Message(arbitration_id=0x181 + k, data=bytes([k] * 6),
                                    is_extended_id=False) for k in range(8)]
                for m in back:
                    rig_side.send(m)
                got = [_recv(link) for _ in back]
                assert [(m.arbitration_id, bytes(m.data)) for m in got] == \
                    [(m.arbitration_id, bytes(m.data)) for m in back]
                assert hub.frames_in == len(out) and hub.bad_messages == 0
            finally:
                link.shutdown()
    finally:
        hub_side.shutdown()
        rig_side.shutdown()


def test_send_frames_falls_back_to_one_send_each():
    from hal.can_bus import send_frames

    sent = []

    class Plain:
        def send(self, msg):
            sent.append(msg.arbitration_id)

    send_frames(Plain(), [can.Message(arbitration_id=i, is_extended_id=False)
                          for i in (3, 1, 2)])
    assert sent == [3, 1, 2]
