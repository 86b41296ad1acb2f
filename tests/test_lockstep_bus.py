"""Lock-step CAN delivery in the sender's thread (bench/dryrun/lockstep_bus.py)."""

from __future__ import annotations

import threading
import time
import uuid

import can
import canopen
import pytest

from bench.dryrun.lockstep_bus import deliver_in_sender_thread
from hal.can_bus import open_bus


@pytest.fixture
def pair():
    channel = f"lockstep-{uuid.uuid4().hex}"
    nets = []
    for _ in range(2):
        net = canopen.Network(open_bus(f"virtual:{channel}"))
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
        nets.append(net)
    yield nets
    for net in nets:
        net.disconnect()


def _wait(cond, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.005)
    return cond()


def test_frames_arrive_before_send_returns_in_the_senders_thread(pair):
    tx, rx = pair
    got = []
    rx.subscribe(0x181, lambda cob, data, ts: got.append(
        (cob, bytes(data), threading.current_thread().name)))
    q = deliver_in_sender_thread(rx)
    for i in range(50):
        tx.send_message(0x181, bytes([i, 0xAA]))
        assert len(got) == i + 1  # delivered within the call
    assert [d for _, d, _ in got] == [bytes([i, 0xAA]) for i in range(50)]
    assert {name for _, _, name in got} == {threading.current_thread().name}
    assert q.direct == 50 and q.deferred == 0


def test_other_networks_keep_their_own_thread(pair):
    tx, rx = pair
    got = []
    tx.subscribe(0x201, lambda cob, data, ts: got.append(threading.current_thread().name))
    deliver_in_sender_thread(rx)  # only rx receives synchronously
    rx.send_message(0x201, b"\x01")
    assert _wait(lambda: got)
    assert got[0] != threading.current_thread().name


def test_frames_waiting_at_the_switch_come_first_and_nothing_is_lost(pair):
    tx, rx = pair
    got = []
    rx.subscribe(0x181, lambda cob, data, ts: got.append(data[0]))
    with rx.notifier._lock:  # the notifier thread cannot deliver: frames wait for it
        for i in range(4):
            tx.send_message(0x181, bytes([i]))
        time.sleep(0.05)
        q = deliver_in_sender_thread(rx)  # delivers the waiting ones (not the one in hand)
    for i in range(4, 8):
        tx.send_message(0x181, bytes([i]))
    assert _wait(lambda: len(got) == 8)
    assert sorted(got) == list(range(8))
    # at most the frame the notifier had taken before the switch comes late
    assert [x for x in got if x != 0] == list(range(1, 8))
    assert q.direct == 4


def test_a_listener_that_sends_to_its_own_network_does_not_deadlock(pair):
    tx, rx = pair
    got = []
    bus2 = open_bus(f"virtual:{tx.bus.channel_id}")  # a third party on the channel

    def echo(cob, data, ts):
        got.append(bytes(data))
        if data[0] < 3:  # sends to rx again from inside rx's delivery
            bus2.send(can.Message(arbitration_id=0x181, data=bytes([data[0] + 1]),
                                  is_extended_id=False))

    rx.subscribe(0x181, echo)
    q = deliver_in_sender_thread(rx)
    try:
        tx.send_message(0x181, b"\x00")
        assert len(got) == 4  # all of them before send returned
        assert got == [b"\x00", b"\x01", b"\x02", b"\x03"]
        assert q.direct == 1 and q.deferred == 3  # each after the delivery that sent it
    finally:
        bus2.shutdown()


def test_only_a_virtual_bus(tmp_path):
    net = canopen.Network()  # not connected
    with pytest.raises(TypeError):
        deliver_in_sender_thread(net)
