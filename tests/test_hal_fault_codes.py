"""Fault codes and EMCY handling of the HAL (issue 9, defects 1 and 4).

A drive in Fault is reported with the EMCY that came with the transition to Fault (then
0x603F, read outside the cycle); warnings after it are events only. EMCYs do not pile up
in memory, and malformed ones are reported naming the node.
"""

from __future__ import annotations

import struct
import time

import can
import pytest
from test_hal_drives import Rig, _codes

from hal.drives import QUEUE_KEPT


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def wait_for(pred, timeout: float = 10.0, progress=None) -> None:
    """Until ``pred()``; fails after ``timeout`` s without it, or, with ``progress`` (a
    function whose value changes while work is being done), after ``timeout`` s in which
    it did not change: a loaded machine delivers slowly, a stuck one not at all."""
    last = progress() if progress else None
    deadline = time.monotonic() + timeout
    while not pred():
        if progress is not None and (now := progress()) != last:
            last, deadline = now, time.monotonic() + timeout
        assert time.monotonic() < deadline
        time.sleep(0.005)


@pytest.mark.parametrize("cause", ["over_current", "following_error"])
def test_a_warning_after_the_fault_does_not_become_its_code(rig, cause):
    d = rig.bank.drives[2]
    if cause == "over_current":
        d.inject_over_current()
        code = 0x2310
    else:
        cmd = rig.hal.lengths_m()
        cmd[2] += 0.05  # 5 cm in one cycle
        rig.hal.set_lengths(cmd)
        code = 0x8611
    rig.steps(15)
    assert _codes(rig.hal.faults()) == [(3, "drive_fault", code)]
    d.drop_rpdos(10)  # 40 ms without RPDO: the drive warns 0x8250 while in Fault
    rig.steps(15)
    ev = [(e.node_id, e.kind, e.code) for e in rig.hal.events()]
    assert (3, "emcy", 0x8250) in ev  # the warning is an event
    assert _codes(rig.hal.faults()) == [(3, "drive_fault", code)]  # not the fault's code
    assert rig.hal.read_fault_codes() == {3: code}


def test_a_fault_without_emcy_gets_its_code_from_0x603f(rig):
    d = rig.bank.drives[5]
    cob = int(d.param(0x1014))  # the drive's EMCY COB-ID made invalid: it sends no EMCY
    rig.hal.nodes[5].sdo[0x1014].raw = cob | 1 << 31
    d.inject_over_current()
    wait_for(lambda: (rig.hal.step() or True) and _codes(rig.hal.faults()) == [
        (6, "drive_fault", 0x2310)])  # 0x603F read in the background
    ev = [(e.node_id, e.kind, e.code) for e in rig.hal.events()]
    assert (6, "fault", 0) in ev and (6, "fault_code", 0x2310) in ev


def test_emcy_flood_keeps_memory_bounded_and_malformed_emcy_is_named(rig):
    spy = can.Bus(interface="virtual", channel=rig.ch)
    try:
        for i in range(3000):  # warnings the master is not asked about
            spy.send(can.Message(arbitration_id=0x84, is_extended_id=False,
                                 data=struct.pack("<HB5s", 0xFF00 + i % 7, 0x80, b"")))
        spy.send(can.Message(arbitration_id=0x84, is_extended_id=False, data=b"\x10\x23"))
        rig.steps(2)
        for node in rig.hal.nodes:
            assert len(node.emcy.log) == 0 and len(node.emcy.active) == 0  # canopen's logs
        ev = rig.hal.events()
        bad = [e for e in ev if e.kind == "emcy_malformed"]
        assert len(bad) == 1 and bad[0].node_id == 4 and "2 bytes" in bad[0].text
        assert 2900 < sum(e.kind == "emcy" for e in ev) <= 3000
        for _ in range(20_000):  # nobody takes the events: the history stays bounded
            spy.send(can.Message(arbitration_id=0x81, is_extended_id=False,
                                 data=struct.pack("<HB5s", 0xFF01, 0x80, b"")))
        rig.steps(2)
        # the notifier may still be delivering when the queue is momentarily empty: cycle until
        # the flood has overflowed the history (over 10,000 events kept) or the queue between
        # two cycles (counted into an emcy_overflow event: which one depends on how fast the
        # notifier delivers against the cycles), then check both stayed bounded
        def overflowed() -> bool:
            rig.hal.step()
            return rig.hal.events_dropped > 0 or any(
                e.kind == "emcy_overflow" for e in rig.hal.events(clear=False))

        wait_for(overflowed, timeout=30.0,
                 progress=lambda: len(rig.hal.events(clear=False)) + rig.hal.events_dropped)
        assert len(rig.hal.events(clear=False)) <= 10_000
        assert len(rig.hal._queue) <= QUEUE_KEPT
    finally:
        spy.shutdown()
