"""The simulated CiA 402 winch drive (firmware_sim/cia402_drive.py) seen from a CANopen master.

One drive on a python-can ``virtual`` bus; the master is a plain canopen network with a
RemoteNode (SDO client) and raw frames. The drive runs on its deterministic clock: time
passes only with SYNC or ``drive.advance``. An SDO round trip is the barrier that makes
sure the drive processed every frame sent before it (one receive thread, FIFO).
"""

from __future__ import annotations

import struct
import time
import uuid

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH, SimulatedDrive, State

W = load_winches()
AX = W.axis(0)  # node 1, direction +1
START_COUNTS = round(AX.m_to_counts(10.0))


class Harness:
    def __init__(self, clock=None) -> None:
        ch = f"simdrive-{uuid.uuid4().hex}"
        self.drive = SimulatedDrive(AX, clock=clock)
        self.drive.keep_sent = True
        self.rig = canopen.Network(can.Bus(interface="virtual", channel=ch))
        self.rig.NOTIFIER_CYCLE = 0.05
        self.drive.attach(self.rig)
        self.rig.connect()
        self.net = canopen.Network(can.Bus(interface="virtual", channel=ch))
        self.net.NOTIFIER_CYCLE = 0.05
        self.net.connect()
        self.node = self.net.add_node(1, str(EDS_PATH))
        self.node.sdo.RESPONSE_TIMEOUT = 0.5
        self.rx: dict[int, list[bytes]] = {}
        for cob in (0x181, 0x701, 0x81):
            self.rx[cob] = []
            self.net.subscribe(cob, lambda c, d, t: self.rx[c].append(bytes(d)))
        self.drive.set_position_counts(START_COUNTS)
        self.drive.power_on()
        self.barrier()

    def close(self) -> None:
        self.net.disconnect()
        self.rig.disconnect()

    # -- helpers
    def barrier(self) -> None:
        self.node.sdo.upload(0x1000, 0)

    def wait_for(self, pred, timeout: float = 2.0) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < deadline, "condition not met in time"
            time.sleep(0.002)

    def sync(self, n: int = 1) -> None:
        for _ in range(n):
            self.net.send_message(0x80, b"")
        self.barrier()

    def nmt(self, cmd: int) -> None:
        self.net.send_message(0, bytes([cmd, 1]))

    def w(self, index: int, sub: int, value: int) -> None:
        if isinstance(self.node.object_dictionary[index], canopen.objectdictionary.ODVariable):
            self.node.sdo[index].raw = value
        else:
            self.node.sdo[index][sub].raw = value

    def r(self, index: int, sub: int = 0):
        if isinstance(self.node.object_dictionary[index], canopen.objectdictionary.ODVariable):
            return self.node.sdo[index].raw
        return self.node.sdo[index][sub].raw

    def cw(self, value: int) -> None:
        self.w(0x6040, 0, value)

    @property
    def sw(self) -> int:
        return self.r(0x6041)

    def emcy_codes(self) -> list[int]:
        return [struct.unpack_from("<H", d)[0] for d in self.rx[0x81]]

    def map_csp(self, rpdo_type: int = 1, tpdo_type: int = 1) -> None:
        """Map RPDO1 = controlword + target, TPDO1 = statusword + position (canopen API)."""
        self.node.rpdo.read()
        self.node.tpdo.read()
        rp, tp = self.node.rpdo[1], self.node.tpdo[1]
        rp.clear()
        rp.add_variable(0x6040)
        rp.add_variable(0x607A)
        rp.trans_type = rpdo_type
        rp.enabled = True
        tp.clear()
        tp.add_variable(0x6041)
        tp.add_variable(0x6064)
        tp.trans_type = tpdo_type
        tp.enabled = True
        self.node.rpdo.save()
        self.node.tpdo.save()

    def rpdo(self, cw: int, target: int) -> None:
        self.net.send_message(0x201, struct.pack("<Hi", cw, target))

    def enable_csp(self) -> None:
        self.w(0x6060, 0, 8)
        self.map_csp()
        self.nmt(0x01)
        for cw in (0x06, 0x07, 0x0F):
            self.rpdo(cw, self.drive.position_actual())
            self.sync()
        assert self.drive.state == State.OPERATION_ENABLED


@pytest.fixture
def h():
    harness = Harness()
    yield harness
    harness.close()


# ---------------------------------------------------------------------------- NMT


def test_boot_up_then_heartbeat_on_the_simulated_clock(h):
    assert h.rx[0x701][0] == b"\x00"  # boot-up
    assert h.drive.nmt_state == 0x7F and h.drive.state == State.SWITCH_ON_DISABLED
    h.w(0x1017, 0, 20)
    h.drive.advance(0.1)
    h.nmt(0x01)
    h.barrier()
    h.drive.advance(0.04)
    h.wait_for(lambda: len(h.rx[0x701]) >= 8)
    assert h.rx[0x701][1:] == [b"\x7f"] * 5 + [b"\x05"] * 2
    times = [t for t, cob, _ in h.drive.sent if cob == 0x701]
    assert [b - a for a, b in zip(times[1:], times[2:], strict=False)] == [20_000] * 6


def test_pdos_only_in_operational_and_no_sdo_when_stopped(h):
    h.map_csp()
    h.rpdo(0x06, 0)
    h.sync(2)
    assert h.rx[0x181] == [] and h.drive.state == State.SWITCH_ON_DISABLED
    h.nmt(0x01)
    h.rpdo(0x06, 0)
    h.sync()
    assert len(h.rx[0x181]) == 1 and h.drive.state == State.READY_TO_SWITCH_ON
    h.w(0x1017, 0, 10)
    h.nmt(0x02)  # stopped: heartbeat yes, SDO and PDO no
    h.wait_for(lambda: h.drive.nmt_state == 0x04)
    h.node.sdo.RESPONSE_TIMEOUT = 0.05
    with pytest.raises(SdoCommunicationError):
        h.r(0x1000)
    h.drive.advance(0.01)
    h.wait_for(lambda: h.rx[0x701][-1:] == [b"\x04"])
    h.nmt(0x80)
    h.node.sdo.RESPONSE_TIMEOUT = 0.5
    h.wait_for(lambda: h.drive.nmt_state == 0x7F)
    assert h.r(0x1000) == 0x00020192


def test_reset_communication_node_and_stored_parameters(h):
    h.w(0x1017, 0, 50)
    h.w(0x6065, 0, 1234)
    h.nmt(0x82)  # reset communication: 0x1000-0x1FFF back, application kept
    h.wait_for(lambda: len(h.rx[0x701]) == 2)
    assert h.rx[0x701][1] == b"\x00"
    assert h.r(0x1017) == 0 and h.r(0x6065) == 1234
    h.nmt(0x81)  # reset node: everything back to the EDS
    h.wait_for(lambda: len(h.rx[0x701]) == 3)
    assert h.r(0x6065) == 100000
    h.w(0x6065, 0, 4321)
    with pytest.raises(SdoAbortedError) as exc:
        h.w(0x1010, 1, 0x12345678)
    assert exc.value.code == 0x08000020
    h.w(0x1010, 1, 0x65766173)  # "save"
    assert h.r(0x1010, 1) == 1  # reads back the capability, not the signature
    h.drive.reset_node()
    h.barrier()
    assert h.r(0x6065) == 4321
    assert h.r(0x1018, 4) == 0x1001  # serial number survives
    assert h.drive.position_actual() == START_COUNTS  # absolute encoder


def test_pdo_mapping_follows_cia301(h):
    def abort(index, sub, value):
        with pytest.raises(SdoAbortedError) as exc:
            h.w(index, sub, value)
        return exc.value.code

    assert abort(0x1600, 1, 0x607A0020) == 0x08000022  # PDO valid: mapping locked
    h.w(0x1400, 1, 0x201 | 1 << 31)  # invalidate
    assert abort(0x1600, 1, 0x607A0020) == 0x08000022  # sub 0 must be 0 first
    h.w(0x1600, 0, 0)
    assert abort(0x1600, 1, 0x60650020) == 0x06040041  # not mappable
    assert abort(0x1600, 1, 0x60410010) == 0x06040041  # read-only in an RPDO
    assert abort(0x1600, 1, 0x607A0010) == 0x06040041  # wrong length
    for sub in range(1, 4):
        h.w(0x1600, sub, 0x607A0020)
    assert abort(0x1600, 0, 3) == 0x06040042  # 96 bits > 64
    assert abort(0x1400, 2, 250) == 0x06090030  # reserved transmission type
    h.w(0x1600, 0, 2)
    h.w(0x1400, 1, 0x201)  # valid again
    assert abort(0x1400, 1, 0x205) == 0x06090030  # no COB-ID change while valid
    assert h.r(0x1600, 0) == 2


def test_sync_rpdo_applies_at_the_next_sync_tpdo_every_nth_sync(h):
    h.map_csp(rpdo_type=1, tpdo_type=3)
    h.nmt(0x01)
    h.rpdo(0x06, 0)
    h.barrier()
    assert h.drive.state == State.SWITCH_ON_DISABLED  # received, not applied yet
    h.sync()
    assert h.drive.state == State.READY_TO_SWITCH_ON
    h.sync(5)
    assert len(h.rx[0x181]) == 2  # SYNC 3 and 6
    sw, pos = struct.unpack("<Hi", h.rx[0x181][-1])
    assert sw & 0x6F == 0x21 and pos == START_COUNTS


def test_event_driven_tpdo_on_change(h):
    h.map_csp(tpdo_type=255)
    h.nmt(0x01)
    h.barrier()
    h.wait_for(lambda: len(h.rx[0x181]) == 1)  # first transmission on start
    h.cw(0x06)
    h.barrier()
    h.cw(0x06)  # same state: no new TPDO
    h.cw(0x07)
    h.barrier()
    h.wait_for(lambda: len(h.rx[0x181]) == 3)
    states = [struct.unpack("<Hi", d)[0] & 0x6F for d in h.rx[0x181]]
    assert states == [0x40 & 0x6F, 0x21, 0x23]


# ---------------------------------------------------------------------------- CiA 402


@pytest.mark.parametrize(
    ("sequence", "expected"),
    [
        ([0x06, 0x07, 0x0F], [0x0231, 0x0233, 0x0237]),  # 2, 3, 4
        ([0x06, 0x0F], [0x0231, 0x0237]),  # 2, 3+4
        ([0x06, 0x07, 0x0F, 0x07, 0x06, 0x00], [0x231, 0x233, 0x237, 0x233, 0x231, 0x240]),
        ([0x06, 0x0F, 0x06], [0x231, 0x237, 0x231]),  # 8
        ([0x06, 0x0F, 0x00], [0x231, 0x237, 0x240]),  # 9
        ([0x06, 0x07, 0x02], [0x231, 0x233, 0x240]),  # 10 (quick stop)
        ([0x06, 0x02], [0x231, 0x240]),  # 7
        ([0x0F, 0x07], [0x240, 0x240]),  # no shutdown first: nothing happens
        ([0x06, 0x86, 0x07], [0x231, 0x231, 0x233]),  # bit 7 high: no command
    ],
)
def test_state_machine_transitions_and_statusword(h, sequence, expected):
    got = []
    for cw in sequence:
        h.cw(cw)
        got.append(h.sw & 0x7FF)
    assert got == [e & 0x7FF for e in expected]


def test_fault_reset_needs_a_rising_edge_of_bit_7(h):
    h.drive.inject_over_current()
    assert h.sw & 0x4F == 0x08
    h.cw(0x80)
    assert h.sw & 0x4F == 0x40  # 15: Switch On Disabled
    h.drive.inject_over_current()
    h.cw(0x80)  # bit 7 was already high: no edge
    assert h.sw & 0x4F == 0x08
    h.cw(0x00)
    h.cw(0x80)
    assert h.sw & 0x4F == 0x40
    h.wait_for(lambda: h.emcy_codes() == [0x2310, 0x0000, 0x2310, 0x0000])


def test_following_error_fault_reaction_emcy_and_error_objects(h):
    h.enable_csp()
    h.rpdo(0x0F, START_COUNTS + 1_000_000)  # 0.48 m in one cycle: cannot follow
    seen = set()
    for _ in range(40):
        h.sync()
        seen.add(h.drive.state)
        if h.drive.state == State.FAULT:
            break
    assert State.FAULT_REACTION_ACTIVE in seen and h.drive.state == State.FAULT
    h.wait_for(lambda: h.emcy_codes() == [0x8611])
    code, reg = struct.unpack_from("<HB", h.rx[0x81][0])
    assert reg == 0x21  # generic + device profile specific
    assert h.r(0x603F) == 0x8611 and h.r(0x1001) == 0x21
    assert h.r(0x1003, 0) == 1 and h.r(0x1003, 1) == 0x8611
    h.w(0x1003, 0, 0)
    assert h.r(0x1003, 0) == 0


def _enable_csv(h, velocity: int) -> None:
    h.w(0x6060, 0, 9)
    h.w(0x60FF, 0, velocity)
    for cw in (0x06, 0x07, 0x0F):
        h.cw(cw)


@pytest.mark.parametrize(("option", "final"), [(2, State.SWITCH_ON_DISABLED),
                                                (6, State.QUICK_STOP_ACTIVE),
                                                (0, State.SWITCH_ON_DISABLED)])
def test_quick_stop_options(h, option, final):
    h.w(0x605A, 0, option)
    h.w(0x6085, 0, 4_000_000)
    _enable_csv(h, 1_000_000)
    h.drive.advance(0.5)
    assert h.drive.axis.vel == pytest.approx(1_000_000, rel=1e-3)
    h.cw(0x02)
    if option == 0:
        assert h.drive.state == State.SWITCH_ON_DISABLED and h.drive.axis.vel == 0
        return
    assert h.drive.state == State.QUICK_STOP_ACTIVE and h.sw & 0x6F == 0x07
    p0 = h.drive.axis.pos
    h.drive.advance(0.2)
    assert h.drive.state == State.QUICK_STOP_ACTIVE  # still ramping (0.25 s to stop)
    h.drive.advance(0.1)
    assert h.drive.state == final and abs(h.drive.axis.vel) < 1.0
    stop_dist = h.drive.axis.pos - p0
    assert stop_dist == pytest.approx(1e6**2 / (2 * 4e6), rel=0.05)  # v^2 / 2a
    if option == 6:
        assert h.sw & 0x0400  # target reached: stopped
        h.cw(0x0F)  # 16
        assert h.drive.state == State.OPERATION_ENABLED


def test_software_limits_clamp_the_demand_and_set_bit_11(h):
    hi = START_COUNTS + 50_000
    h.w(0x607D, 1, START_COUNTS - 50_000)
    h.w(0x607D, 2, hi)
    h.enable_csp()
    for k in range(1, 41):
        h.rpdo(0x0F, START_COUNTS + 4000 * k)  # 160 000 counts, beyond the limit
        h.sync()
    h.sync(10)
    assert h.drive.position_actual() == pytest.approx(hi, abs=2)
    assert h.sw & 0x0800
    h.rpdo(0x0F, hi - 1000)
    h.sync(5)
    assert not h.sw & 0x0800 and h.drive.state == State.OPERATION_ENABLED


def test_profile_position_move(h):
    h.w(0x6060, 0, 1)
    h.w(0x6081, 0, 500_000)
    h.w(0x6083, 0, 2_000_000)
    h.w(0x6084, 0, 2_000_000)
    for cw in (0x06, 0x07, 0x0F):
        h.cw(cw)
    goal = START_COUNTS + 400_000
    h.w(0x607A, 0, goal)
    h.cw(0x1F)  # new set-point
    assert h.sw & 0x1000  # acknowledged
    h.cw(0x0F)
    assert not h.sw & 0x1000 and not h.sw & 0x0400
    peak = 0.0
    for _ in range(150):
        h.drive.advance(0.01)
        peak = max(peak, h.drive.axis.vel)
    assert h.sw & 0x0400  # target reached
    assert abs(h.drive.position_actual() - goal) <= h.r(0x6067)
    assert peak <= 500_000 * 1.01


def test_homing_on_the_current_position(h):
    h.w(0x6060, 0, 6)
    h.w(0x6098, 0, 37)
    h.w(0x607C, 0, 12345)
    for cw in (0x06, 0x07, 0x0F, 0x1F):
        h.cw(cw)
    assert h.r(0x6064) == 12345
    assert h.sw & 0x1400 == 0x1400  # attained + target reached


def test_cyclic_synchronous_velocity(h):
    _enable_csv(h, -300_000)
    h.drive.advance(1.0)
    assert h.drive.axis.vel == pytest.approx(-300_000, rel=1e-3)
    assert h.sw & 0x1000  # drive follows


def test_unsupported_mode_and_homing_method_are_refused(h):
    for index, value in ((0x6060, 3), (0x6060, 10), (0x6098, 17), (0x605A, 9)):
        with pytest.raises(SdoAbortedError) as exc:
            h.w(index, 0, value)
        assert exc.value.code == 0x06090030
    assert h.r(0x6061) == 0
    with pytest.raises(SdoAbortedError):
        h.w(0x6041, 0, 0)  # read-only


# ---------------------------------------------------------------------------- faults


def test_encoder_fault_stops_at_once_and_persists_until_repaired(h):
    _enable_csv(h, 500_000)
    h.drive.advance(0.2)
    h.drive.inject_encoder_fault()
    assert h.drive.state == State.FAULT and h.drive.axis.vel == 0  # brake, no ramp
    h.cw(0x00)
    h.cw(0x80)
    assert h.drive.state == State.FAULT  # cause persists
    h.drive.repair_encoder()
    h.cw(0x00)
    h.cw(0x80)
    assert h.drive.state == State.SWITCH_ON_DISABLED
    h.wait_for(lambda: h.emcy_codes() == [0x7305, 0x0000])
    assert struct.unpack_from("<HB", h.rx[0x81][0])[1] == 0x21


def test_over_current_sends_2310_with_the_current_bit(h):
    _enable_csv(h, 0)
    h.drive.inject_over_current()
    h.drive.advance(0.01)
    assert h.drive.state == State.FAULT
    h.wait_for(lambda: h.emcy_codes() == [0x2310])
    assert struct.unpack_from("<HB", h.rx[0x81][0])[1] == 0x03


def test_stuck_brake_is_a_following_error_only_when_motion_is_demanded(h):
    h.drive.stick_brake()
    h.enable_csp()
    h.sync(20)  # standing still: nothing to detect
    assert h.drive.state == State.OPERATION_ENABLED and h.emcy_codes() == []
    for k in range(1, 40):
        h.rpdo(0x0F, START_COUNTS + 6000 * k)
        h.sync()
    assert h.drive.state == State.FAULT and h.drive.position_actual() == START_COUNTS
    h.wait_for(lambda: h.emcy_codes() == [0x8611])


def test_rpdo_deadline_warning_and_pdo_length_error(h):
    h.w(0x6007, 0, 0)  # abort connection: no action (the deadline alone is a warning)
    h.enable_csp()
    h.w(0x1400, 1, 0x201 | 1 << 31)
    h.w(0x1400, 5, 6)  # 6 ms deadline, SYNC every 4 ms
    h.w(0x1400, 1, 0x201)
    for _ in range(3):
        h.rpdo(0x0F, START_COUNTS)
        h.sync()
    assert h.emcy_codes() == []  # 4 ms between RPDOs: fine
    h.drive.drop_rpdos(1)
    h.rpdo(0x0F, START_COUNTS)
    h.sync()  # 8 ms since the last RPDO arrived > 6 ms
    h.wait_for(lambda: h.emcy_codes() == [0x8250])
    assert h.sw & 0x80 and h.drive.state == State.OPERATION_ENABLED  # warning, not a fault
    h.rpdo(0x0F, START_COUNTS)
    h.sync()
    h.wait_for(lambda: h.emcy_codes() == [0x8250, 0x0000])
    assert not h.sw & 0x80
    h.net.send_message(0x201, b"\x0f\x00")  # 2 bytes, 6 mapped
    h.barrier()
    h.wait_for(lambda: h.emcy_codes()[-1:] == [0x8210])


def test_dropped_and_delayed_tpdos_and_silence(h):
    h.enable_csp()
    n0 = len(h.rx[0x181])
    h.drive.drop_tpdos(1)
    h.sync()
    assert len(h.rx[0x181]) == n0
    h.drive.delay_tpdos(1)
    h.sync()
    assert len(h.rx[0x181]) == n0
    h.sync()
    assert len(h.rx[0x181]) == n0 + 2  # the late one, then the current one
    h.drive.set_silent()
    h.node.sdo.RESPONSE_TIMEOUT = 0.05
    with pytest.raises(SdoCommunicationError):
        h.r(0x1000)
    h.drive.set_silent(False)
    h.node.sdo.RESPONSE_TIMEOUT = 0.5
    assert h.r(0x1000) == 0x00020192


def test_nothing_is_reported_without_injection(h):
    h.w(0x1017, 0, 20)
    h.w(0x1400, 1, 0x201 | 1 << 31)
    h.w(0x1400, 5, 6)
    h.w(0x1400, 1, 0x201)
    h.enable_csp()
    import math

    for k in range(400):  # 1.6 s, 0.4 m/s and 3 m/s^2 peaks
        x = 0.05 * (1 - math.cos(2 * math.pi * k * 0.004 / 1.6 * 2))
        h.rpdo(0x0F, START_COUNTS + round(x / AX.metres_per_count))
        h.sync()
    assert h.drive.state == State.OPERATION_ENABLED
    assert h.emcy_codes() == []
    assert h.sw & 0x2880 == 0  # no following error, no limit, no warning
    assert len(h.rx[0x181]) >= 400
