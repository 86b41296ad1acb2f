"""The CAN link dies and comes back (issue 9, defect 3): states unknown, clear errors naming
the bus, the socketcand link reconnecting on its own, then recovery as after a node reset.

The drives (firmware_sim.drive_rig.DriveRig) run in this process behind a socketcand hub
on loopback; "the link dies" is the hub closing (as a socketcand daemon or a CAN adapter's
host going away), "it comes back" a new hub on the same port bridging the same drives.
"""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from controller.winch import load_winches, metres_per_count
from firmware_sim.can_hub import CanHub
from firmware_sim.cia402_drive import EDS_PATH, State
from firmware_sim.drive_rig import DriveRig
from hal.drives import BusLinkError, DriveState, WinchDrives
from hal.socketcand_link import SocketcandLink

W = load_winches()
OE = DriveState.OPERATION_ENABLED
COUNT_M = float(metres_per_count(W)[0])


def wait_for(pred, timeout: float = 10.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, f"{what} not met within {timeout} s"
        time.sleep(0.01)


@pytest.fixture
def setup():
    rig = DriveRig(initial_lengths_m=10.0).start()
    hal = WinchDrives.open(rig.endpoint()["can"], W, EDS_PATH, clock="sync")
    yield rig, hal
    hal.close()
    rig.close()


def kill_link(rig: DriveRig) -> int:
    port = rig.hub.address[1]
    rig.hub.close()
    return port


def revive_link(rig: DriveRig, port: int) -> None:
    rig.hub = CanHub("127.0.0.1", port, bus=rig._hub_bus).start()


def test_link_loss_states_unknown_and_errors_name_the_bus(setup):
    rig, hal = setup
    hal.start()
    hal.enable_and_wait()
    for _ in range(10):
        hal.step()
    assert isinstance(hal.network.bus, SocketcandLink)
    kill_link(rig)
    wait_for(lambda: not hal.link_up(), what="link down seen")
    for _ in range(5):
        hal.exchange()  # the cycle never raises
    assert np.all(hal.states() == DriveState.UNKNOWN)  # not the stale Operation Enabled
    faults = hal.faults()
    assert [(f.node_id, f.kind) for f in faults] == [(n, "link_lost") for n in range(1, 9)]
    assert "--can socketcand:127.0.0.1" in faults[0].text
    ev = [(e.node_id, e.kind) for e in hal.events()]
    assert ev == [(0, "link_lost")]  # one event for the bus, no heartbeat noise
    t0 = time.monotonic()
    with pytest.raises(BusLinkError, match=r"enable: --can socketcand:127\.0\.0\.1:\d+: CAN "
                                           r"link down"):
        hal.enable_and_wait()
    assert time.monotonic() - t0 < 5.0  # at once, not after 50 cycles of timeouts
    with pytest.raises(BusLinkError, match="recover: --can socketcand"):
        hal.recover()
    with pytest.raises(BusLinkError, match="shutdown: --can socketcand"):
        hal.shutdown()
    with pytest.raises(BusLinkError, match="fault_reset: --can socketcand"):
        hal.fault_reset()
    hal.quick_stop()  # a supervisor's reaction: never raises, says it cannot reach them
    ev = hal.events()
    assert [e.kind for e in ev] == ["link_lost"] and "quick stop requested" in ev[0].text
    # behind the dead link the drives lost their master and hold in Quick Stop Active
    wait_for(lambda: all(d.state == State.QUICK_STOP_ACTIVE for d in rig.bank.drives),
             what="drives holding")


def test_link_comes_back_and_drives_are_recovered(setup):
    rig, hal = setup
    hal.start()
    hal.enable_and_wait()
    l0 = hal.lengths_m()
    port = kill_link(rig)
    wait_for(lambda: all(d.state == State.QUICK_STOP_ACTIVE for d in rig.bank.drives),
             what="drives holding")
    revive_link(rig, port)
    wait_for(lambda: hal.link_up(), what="reconnected")  # on its own
    assert hal.network.bus.link_epoch == 2
    hal.exchange()
    kinds = [(e.node_id, e.kind) for e in hal.events()]
    assert kinds[-1] == (0, "link_back")
    assert [f.kind for f in hal.faults()] == ["link_lost"] * 8  # until recovered
    with pytest.raises(Exception, match="recover\\(\\) it first"):
        hal.enable_and_wait()
    assert hal.recover() == list(range(1, 9))
    assert np.all(hal.states() == DriveState.QUICK_STOP_ACTIVE)  # still holding
    assert [f.kind for f in hal.faults()] == ["quick_stop"] * 8  # on their own: until enable
    hal.enable_and_wait()  # 16: Quick Stop Active -> Operation Enabled
    for _ in range(20):
        assert hal.step(timeout=2.0)
    np.testing.assert_allclose(hal.lengths_m(), l0, atol=2 * COUNT_M)
    assert hal.faults() == [] and np.all(hal.states() == OE)


def test_socketcand_link_alone(setup):
    rig, _ = setup
    host, port = rig.hub.address
    bus = SocketcandLink("can0", host, port, retry_s=0.05)
    try:
        assert bus.link_up and bus.link_epoch == 1
        kill_link(rig)
        deadline = time.monotonic() + 5
        while bus.link_up:
            bus.recv(0.05)
            assert time.monotonic() < deadline
        with pytest.raises(can.CanOperationError, match=f"{port}.*link down"):
            bus.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        revive_link(rig, port)
        deadline = time.monotonic() + 5
        while not bus.link_up:
            bus.recv(0.05)
            assert time.monotonic() < deadline
        assert bus.link_epoch == 2 and bus.losses == 1
    finally:
        bus.shutdown()
