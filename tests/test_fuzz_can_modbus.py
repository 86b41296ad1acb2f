"""Fuzzing the wire (issue 9): CAN frames of any length and COB-ID, spoofed EMCYs, TPDOs,
heartbeats and SDO traffic against the HAL and the simulated drives; SDO aborts and
malformed SDO answers against the HAL's configuration; Modbus exceptions, wrong register
counts and garbage values against the load-cell client. Each ends in a report or an error
naming the node or the unit, never in an exception escaping a thread or a traceback.
"""

from __future__ import annotations

import logging
import struct
import uuid

import can
import numpy as np
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymodbus.exceptions import ConnectionException, ModbusIOException

from controller.loadcell_map import DEFAULT_MAP
from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.drive_bank import SimulatedWinchBank
from hal.drives import WinchDrives
from hal.drives_config import DriveConfigError, Setting, load_eds, sdo_read, sdo_write
from hal.loadcell_client import CableStatus, LoadCellClient

W = load_winches()
FEW = settings(settings.default, max_examples=max(4, settings.default.max_examples // 8),
               deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                     HealthCheck.function_scoped_fixture])
MANY = settings(settings.default, deadline=None,
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture])

# COB-IDs worth hitting: NMT, SYNC, EMCY, TPDO, RPDO, SDO both ways, heartbeats, the
# master's heartbeat, and anything else
COBS = st.one_of(
    st.sampled_from([0x000, 0x080, 0x77F]),
    st.integers(0x081, 0x088), st.integers(0x181, 0x188), st.integers(0x201, 0x208),
    st.integers(0x581, 0x588), st.integers(0x601, 0x608), st.integers(0x701, 0x708),
    st.integers(0, 0x7FF),
)
FRAMES = st.lists(st.tuples(COBS, st.binary(min_size=0, max_size=8)), min_size=1, max_size=40)


def _no_callback_errors(caplog) -> None:
    """canopen logs (at ERROR) every exception a frame callback raised: there must be none."""
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR
              and r.name in ("canopen.network", "canopen.sdo.server")]
    assert errors == []


@FEW
@given(frames=FRAMES)
def test_random_frames_against_the_hal_and_the_drives(caplog, frames):
    caplog.set_level(logging.WARNING)
    ch = f"fuzz-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), W)
    bank.set_positions_m(np.full(8, 10.0))
    bank.start()
    hal = WinchDrives.open(f"virtual:{ch}", W, EDS_PATH, clock="sync")
    noise = can.Bus(interface="virtual", channel=ch)
    try:
        hal.start()
        hal.enable_and_wait()
        for cob, data in frames:
            noise.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))
            hal.step(timeout=0.05)
        for _ in range(10):
            hal.step(timeout=0.05)  # the cycle never raises, whatever came in
        for f in hal.faults():  # node 0: another master's NMT to all nodes or SYNC
            assert (f.node_id in hal.node_ids or (f.node_id == 0 and f.kind == "foreign_master")
                    ) and 0 <= f.code <= 0xFFFF, f
        for e in hal.events():
            assert e.node_id in (0, *hal.node_ids) and 0 <= e.code <= 0xFFFF, e
            assert f"node {e.node_id}" in str(e)
        try:  # and it can be brought back, or says clearly why not
            hal.recover(timeout=1.0)
            hal.fault_reset()
            hal.enable_and_wait(max_cycles=30)
        except (DriveConfigError, RuntimeError) as exc:
            assert "node" in str(exc), exc
        with bank.lock:  # the drives still answer SDO (none is wedged)
            pass
        for node in hal.nodes:
            if bank.drive(node.id).nmt_state in (0x05, 0x7F) and not bank.drive(node.id).silent:
                assert int(sdo_read(node, 0x1000, 0, hal.who(node.id - 1))) == 0x00020192
        _no_callback_errors(caplog)
    finally:
        noise.shutdown()
        hal.close()
        bank.close()


class _FakeSdo:
    def __init__(self, outcome):
        self.outcome = outcome

    def _do(self):
        if isinstance(self.outcome, Exception):
            raise self.outcome
        return self.outcome

    def upload(self, index, sub):
        return self._do()

    def download(self, index, sub, data):
        self._do()


class _FakeNode:
    def __init__(self, outcome):
        self.object_dictionary = load_eds(EDS_PATH, 3)
        self.sdo = _FakeSdo(outcome)


OUTCOMES = st.one_of(
    st.integers(0, 2**32 - 1).map(SdoAbortedError),
    st.just(SdoCommunicationError("No SDO response received")),
    st.sampled_from([struct.error("unpack requires a buffer of 4 bytes"),
                     ValueError("bad"), IndexError("index out of range")]),
    st.binary(max_size=9),  # an answer of any length
)


@MANY
@given(outcome=OUTCOMES, index=st.sampled_from([(0x6041, 0), (0x1018, 1), (0x6064, 0),
                                                  (0x1008, 0), (0x6060, 0)]))
def test_sdo_aborts_and_malformed_answers_name_the_node(outcome, index):
    node = _FakeNode(outcome)
    who = "node 3 (cable 21)"
    try:
        value = sdo_read(node, *index, who)
    except DriveConfigError as exc:
        assert who in str(exc) and f"0x{index[0]:04X}" in str(exc)
        if isinstance(outcome, SdoAbortedError):
            assert f"SDO abort 0x{outcome.code:08X}" in str(exc)
    else:
        assert isinstance(outcome, bytes)  # only a real answer gives a value
        assert value is not None
    try:
        sdo_write(node, Setting(0x6060, 0, 8, "modes of operation"), who)
    except DriveConfigError as exc:
        assert who in str(exc) and "0x6060" in str(exc)


def test_an_sdo_abort_at_start_up_names_node_object_and_code():
    ch = f"fuzz-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), W)
    drive = bank.drive(6)
    original = drive._on_write

    def refuse(index, subindex, od, data):
        if index == 0x6007:
            raise SdoAbortedError(0x06090030)
        return original(index, subindex, od, data)

    drive._on_write = refuse
    drive.node._write_callbacks = [refuse]
    bank.start()
    hal = WinchDrives.open(f"virtual:{ch}", W, EDS_PATH, clock="sync")
    try:
        with pytest.raises(DriveConfigError, match=r"node 6 \(cable 32\): writing 0x6007:00 "
                           r"abort connection option code = 3: SDO abort 0x06090030 "
                           r"\(value range of parameter exceeded\)"):
            hal.start()
    finally:
        hal.close()
        bank.close()


# ---------------------------------------------------------------------------- Modbus


class _Answer:
    def __init__(self, registers=None, exception_code=None):
        self.registers = registers
        self.exception_code = exception_code

    def isError(self):  # noqa: N802 (pymodbus' name)
        return self.exception_code is not None


class _FakeModbus:
    def __init__(self, answers):
        self.answers = answers  # per unit id

    def read_input_registers(self, start, count, device_id):
        a = self.answers[device_id]
        if isinstance(a, Exception):
            raise a
        return a

    def close(self):
        pass


ANSWERS = st.one_of(
    st.integers(0, 255).map(lambda c: _Answer(exception_code=c)),
    st.lists(st.integers(0, 0xFFFF), min_size=0, max_size=8).map(_Answer),  # any count
    st.lists(st.integers(0, 0xFFFF), min_size=4, max_size=4).map(_Answer),  # garbage values
    st.lists(st.one_of(st.integers(-70000, 70000), st.none()), min_size=4,
             max_size=4).map(_Answer),
    st.just(_Answer(registers=None)),
    st.sampled_from([ModbusIOException("No response received"),
                     ConnectionException("refused"), OSError("reset"), ValueError("bad frame"),
                     struct.error("unpack")]),
)


@MANY
@given(answers=st.lists(ANSWERS, min_size=8, max_size=8))
def test_modbus_garbage_gives_statuses_naming_the_unit(answers):
    client = LoadCellClient("127.0.0.1:1", connections="shared")
    client._lanes[0].client = _FakeModbus(dict(zip(DEFAULT_MAP.unit_ids, answers, strict=True)))
    client.poll_once()
    r = client.read()
    m = DEFAULT_MAP
    for k in range(8):
        st_k = CableStatus(int(r.status[k]))
        if st_k is CableStatus.OK:
            assert np.isfinite(r.values_N[k])
            assert m.rated_min_N <= r.values_N[k] <= m.rated_max_N
            assert r.messages[k] == ""
        else:
            assert np.isnan(r.values_N[k])
            assert f"Modbus unit {m.unit_ids[k]} (cable {m.cables[k]})" in r.messages[k]
    client.stop()
