"""The simulated drive driven by an independent CiA 402 master: canopen's BaseNode402.

BaseNode402 uses its own blocking calls (this is commissioning-style use, not the control
cycle): it maps the PDOs itself, reads TPDOs that a background SYNC producer triggers, and
writes the controlword with an event-driven RPDO. It walks the drive through enable, mode
changes, homing, a profile move and a fault reset.
"""

from __future__ import annotations

import time
import uuid

import can
import canopen
import pytest
from canopen.profiles.p402 import BaseNode402

from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH, State
from firmware_sim.drive_bank import SimulatedWinchBank


@pytest.fixture
def master():
    ch = f"bn402-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), load_winches())
    bank.set_positions_counts(2_000_000)
    bank.start()
    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.NOTIFIER_CYCLE = 0.05
    net.connect()
    node = BaseNode402(3, str(EDS_PATH))
    net.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    node.rpdo.read()
    node.tpdo.read()
    node.rpdo[1].clear()
    node.rpdo[1].add_variable(0x6040)
    node.rpdo[1].trans_type = 255  # applied at once
    node.rpdo[1].enabled = True
    node.tpdo[1].clear()
    node.tpdo[1].add_variable(0x6041)
    node.tpdo[1].add_variable(0x6061)
    node.tpdo[1].add_variable(0x6064)
    node.tpdo[1].trans_type = 1  # every SYNC
    node.tpdo[1].enabled = True
    node.rpdo.save()
    node.tpdo.save()
    node.setup_402_state_machine()
    node.nmt.state = "OPERATIONAL"
    net.sync.start(0.004)
    yield node, bank.drive(3)
    net.sync.stop()
    net.disconnect()
    bank.close()


def test_enable_mode_changes_homing_and_profile_move(master):
    node, drive = master
    deadline = time.monotonic() + 2.0
    while node.state != "SWITCH ON DISABLED":  # first TPDOs
        assert time.monotonic() < deadline
        node.check_statusword()
    node.op_mode = "PROFILED POSITION"
    assert node.op_mode == "PROFILED POSITION"
    node.state = "OPERATION ENABLED"
    assert node.state == "OPERATION ENABLED" and drive.state == State.OPERATION_ENABLED

    node.sdo[0x607C].raw = 1_000_000
    assert node.homing(timeout=2.0) is True
    node.check_statusword()
    assert node.tpdo_values[0x6064] == 1_000_000
    assert node.op_mode == "HOMING"

    node.op_mode = "PROFILED POSITION"
    assert node.op_mode == "PROFILED POSITION"
    node.sdo[0x6081].raw = 2_000_000
    node.sdo[0x6083].raw = 8_000_000
    node.sdo[0x6084].raw = 8_000_000
    node.sdo[0x607A].raw = 1_200_000
    node.controlword = 0x0F  # homing left bit 4 high: drop it first
    node.controlword = 0x1F  # new set-point (rising edge of bit 4)
    node.controlword = 0x0F
    deadline = time.monotonic() + 3.0
    while not node.check_statusword() & 0x0400 or node.tpdo_values[0x6064] == 1_000_000:
        assert time.monotonic() < deadline, "profile move did not reach its target"
    assert abs(node.tpdo_values[0x6064] - 1_200_000) <= node.sdo[0x6067].raw

    node.op_mode = "CYCLIC SYNCHRONOUS POSITION"
    assert node.op_mode == "CYCLIC SYNCHRONOUS POSITION"
    assert node.is_op_mode_supported("CYCLIC SYNCHRONOUS VELOCITY")
    assert not node.is_op_mode_supported("PROFILED TORQUE")


def test_fault_reset_back_to_operation_enabled(master):
    node, drive = master
    deadline = time.monotonic() + 2.0
    while node.state != "SWITCH ON DISABLED":
        assert time.monotonic() < deadline
        node.check_statusword()
    node.op_mode = "PROFILED POSITION"
    node.state = "OPERATION ENABLED"
    drive.inject_over_current()
    emcy = node.emcy.wait(0x2310, timeout=2.0)
    assert emcy is not None and emcy.code == 0x2310
    deadline = time.monotonic() + 2.0
    while not node.is_faulted():
        assert time.monotonic() < deadline
        node.check_statusword()
    node.reset_from_fault()
    assert node.state == "OPERATION ENABLED"
    assert node.sdo[0x603F].raw == 0
    assert node.emcy.active == []  # the drive sent the error-reset EMCY
