"""The socketcand hub gives every client the frames in one order: a logger connected beside
the master sees each SYNC after the drives' answers to the one before, as on a wire (a CAN
log taken through the hub, e.g. the ``/can`` channel of a ``--rig process`` dry run, once
had a SYNC before the answers to the previous one, and its replay reported TPDOs missing
and late that the live run never saw)."""

from __future__ import annotations

import threading
import time
import uuid

import can

from firmware_sim.can_hub import CanHub
from tests.test_can_hub import _client, _wait_clients

SYNC, N_DRIVES, CYCLES = 0x080, 8, 300


def _drives(bus: can.BusABC, stop: threading.Event) -> None:
    """Eight drives answering every SYNC with a TPDO each."""
    while not stop.is_set():
        m = bus.recv(timeout=0.05)
        if m is not None and m.arbitration_id == SYNC:
            for k in range(N_DRIVES):
                bus.send(can.Message(arbitration_id=0x181 + k, data=b"\x37\x12",
                                     is_extended_id=False))


def test_a_logger_sees_every_sync_after_the_answers_to_the_previous_one():
    ch = f"hub-order-{uuid.uuid4().hex}"
    bridged = can.Bus(interface="virtual", channel=ch)
    drives_bus = can.Bus(interface="virtual", channel=ch)
    stop = threading.Event()
    drives = threading.Thread(target=_drives, args=(drives_bus, stop), daemon=True)
    drives.start()
    log: list[int] = []
    with CanHub(bus=bridged, handshake_grace_s=0.02) as hub:
        master = _client(hub)  # first: the hub writes the drives' answers to it first
        logger = _client(hub)
        _wait_clients(hub, 2)
        time.sleep(0.05)

        def listen() -> None:
            while not stop.is_set():
                m = logger.recv(timeout=0.05)
                if m is not None:
                    log.append(m.arbitration_id)

        listener = threading.Thread(target=listen, daemon=True)
        listener.start()
        try:
            for _ in range(CYCLES):  # the master: RPDO, SYNC, then wait for every answer
                master.send(can.Message(arbitration_id=0x201, data=b"\x0f\x00",
                                        is_extended_id=False))
                master.send(can.Message(arbitration_id=SYNC, data=b"", is_extended_id=False))
                got, deadline = 0, time.monotonic() + 2.0
                while got < N_DRIVES and time.monotonic() < deadline:
                    m = master.recv(timeout=0.1)
                    got += m is not None and 0x181 <= m.arbitration_id < 0x181 + N_DRIVES
                assert got == N_DRIVES
            time.sleep(0.2)
        finally:
            stop.set()
            listener.join(2)
            drives.join(2)
            master.shutdown()
            logger.shutdown()
    drives_bus.shutdown()
    bridged.shutdown()
    syncs = [i for i, cid in enumerate(log) if cid == SYNC]
    assert len(syncs) == CYCLES
    for a, b in zip(syncs, syncs[1:] + [len(log)], strict=True):  # RPDO, 8 TPDOs
        between = sorted(log[a + 1:b])
        want = [0x181 + k for k in range(N_DRIVES)] + ([0x201] if b < len(log) else [])
        assert between == want, (a, [hex(x) for x in log[a:b + 1]])
