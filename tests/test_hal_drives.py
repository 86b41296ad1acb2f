"""HAL winch drives (hal/drives.py) against eight simulated drives on a python-can virtual bus.

The rig (firmware_sim.drive_bank) runs on its deterministic SYNC clock and the HAL on the
matching "sync" clock, in lock-step (``step()`` = exchange + wait for the TPDOs), so the
tests count cycles, not seconds.
"""

from __future__ import annotations

import dataclasses
import struct
import time
import uuid

import can
import canopen
import numpy as np
import pytest
from drive_rig import BankRig

from controller.winch import limits_counts, load_winches, m_to_counts, metres_per_count
from firmware_sim.cia402_drive import EDS_PATH, State
from firmware_sim.drive_bank import SimulatedWinchBank
from hal.drives import (
    DriveConfigError,
    DriveStartupError,
    DriveState,
    WinchDrives,
)

W = load_winches()
L0 = np.linspace(8.0, 15.0, 8)  # initial cable lengths [m]
OE = DriveState.OPERATION_ENABLED


class Rig(BankRig):
    def __init__(self, winches=W, lengths=L0, start=True, enable=True, before_start=None):
        super().__init__("haldrives", winches, lengths,
                         before_start and (lambda r: before_start(r.bank)))
        self.hal = self.open_hal(winches, start, enable)
        if enable:
            assert self.hal.events() == []

    def steps(self, n: int, timeout: float = 0.5) -> list[bool]:
        return [self.hal.step(timeout) for _ in range(n)]

    def move(self, amplitude_m: np.ndarray, cycles: int, period_s: float = 1.0) -> np.ndarray:
        """Smooth excursion l0 + a (1 - cos) from the current lengths; returns the last command."""
        l0 = self.hal.lengths_m()
        cmd = l0
        for i in range(1, cycles + 1):
            cmd = l0 + amplitude_m * (1 - np.cos(2 * np.pi * i * W.bus.sync_period_s / period_s))
            self.hal.set_lengths(cmd)
            assert self.hal.step()
        return cmd


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def _codes(faults):
    return sorted((f.node_id, f.kind, f.code) for f in faults)


# ---------------------------------------------------------------------------- start-up


def test_startup_brings_eight_drives_to_operation_enabled_in_csp():
    spy_bus = None
    r = Rig(enable=False)
    try:
        spy_bus = can.Bus(interface="virtual", channel=r.ch)
        assert r.hal.state_names() == ["SWITCH_ON_DISABLED"] * 8
        np.testing.assert_allclose(r.hal.lengths_m(), L0, atol=metres_per_count(W)[0])
        for node in r.hal.nodes:  # configuration as the drives report it
            assert node.sdo[0x6061].raw == 8
            assert node.sdo[0x1600][2].raw == 0x607A0020 and node.sdo[0x1A00][2].raw == 0x60640020
            assert node.sdo[0x1006].raw == 4000 and node.sdo[0x1017].raw == 100
        lo, hi = limits_counts(W)
        assert r.hal.nodes[3].sdo[0x607D][2].raw == hi[3]
        r.hal.enable_and_wait()
        assert np.all(r.hal.states() == OE)
        assert r.hal.cycle <= 5
        # the RPDO that enabled each drive carried its actual position as target
        frames = []
        while (m := spy_bus.recv(timeout=0.01)) is not None:
            if 0x201 <= m.arbitration_id <= 0x208:
                frames.append((m.arbitration_id - 0x200, *struct.unpack("<Hi", m.data)))
        actual = m_to_counts(L0, W)
        for nid in range(1, 9):
            first_enable = next(f for f in frames if f[0] == nid and f[1] == 0x0F)
            assert first_enable[2] == actual[nid - 1]
        assert all(d.nmt_state == 0x05 for d in r.bank.drives)
    finally:
        if spy_bus is not None:
            spy_bus.shutdown()
        r.close()


def test_enable_copies_the_actual_position_so_nothing_jumps():
    r = Rig(enable=False)
    try:
        moved = L0 + np.linspace(-0.3, 0.3, 8)
        r.bank.set_positions_m(moved)  # the plant moved the cables while braked
        r.steps(2)
        r.hal.set_lengths(L0)  # stale setpoints: ignored while disabled
        r.hal.enable_and_wait()
        r.steps(20)
        np.testing.assert_allclose(r.hal.lengths_m(), moved, atol=2 * metres_per_count(W)[0])
        assert r.hal.faults() == [] and r.hal.events() == []
    finally:
        r.close()


def test_setpoints_are_followed(rig):
    amp = np.array([0.05, -0.04, 0.03, -0.02, 0.05, 0.04, -0.05, 0.01])
    cmd = rig.move(amp, 250)  # one full period of 1 s: back to the start
    for _ in range(10):
        rig.hal.set_lengths(cmd)
        rig.hal.step()
    np.testing.assert_allclose(rig.hal.lengths_m(), cmd, atol=1e-4)
    np.testing.assert_allclose(rig.bank.positions_m(), rig.hal.lengths_m(),
                               atol=metres_per_count(W)[0])
    assert rig.hal.faults() == [] and rig.hal.events() == []


def test_tracking_error_while_moving_stays_small(rig):
    l0 = rig.hal.lengths_m()
    amp = np.full(8, 0.05)
    worst = 0.0
    for i in range(1, 200):
        cmd = l0 + amp * (1 - np.cos(2 * np.pi * i * 0.004))
        rig.hal.set_lengths(cmd)
        rig.hal.step()
        prev = l0 + amp * (1 - np.cos(2 * np.pi * (i - 2) * 0.004))  # two cycles of transport
        worst = max(worst, float(np.max(np.abs(rig.hal.lengths_m() - prev))))
    assert worst < 0.003  # [m] at 0.31 m/s: lag of the drive's position loop


def test_nothing_is_detected_when_nothing_is_injected(rig):
    amp = np.linspace(-0.08, 0.08, 8)
    ok = []
    l0 = rig.hal.lengths_m()
    for i in range(1, 301):
        rig.hal.set_lengths(l0 + amp * (1 - np.cos(2 * np.pi * i * 0.004 / 1.2)))
        ok.append(rig.hal.step())
    assert all(ok)
    assert rig.hal.faults() == [] and rig.hal.events() == []
    assert np.all(rig.hal.states() == OE) and not rig.hal.limits_active().any()


def test_bad_setpoints_are_refused_whole(rig):
    before = rig.hal.targets_counts()
    bad = rig.hal.lengths_m()
    bad[1] = np.nan
    with pytest.raises(ValueError, match=r"node 2 \(cable 12\)"):
        rig.hal.set_lengths(bad)
    bad[1] = 31.0
    with pytest.raises(ValueError, match=r"node 2 \(cable 12\).*31.0 m"):
        rig.hal.set_lengths(bad)
    with pytest.raises(ValueError, match="shape"):
        rig.hal.set_lengths(bad[:7])
    np.testing.assert_array_equal(rig.hal.targets_counts(), before)


# ---------------------------------------------------------------------------- faults


@pytest.mark.parametrize(
    ("inject", "code"),
    [("inject_encoder_fault", 0x7305), ("inject_over_current", 0x2310)],
)
def test_injected_drive_faults_are_reported_with_node_and_code(rig, inject, code):
    getattr(rig.bank.drives[2], inject)()
    rig.steps(5)
    assert _codes(rig.hal.faults()) == [(3, "drive_fault", code)]
    events = rig.hal.events()
    assert any(e.kind == "emcy" and e.code == code and e.node_id == 3 and e.source == "drive"
               for e in events)
    assert any(e.kind == "fault" and e.code == code and e.node_id == 3 and e.cable == "21"
               for e in events)
    states = rig.hal.states()
    assert states[2] == DriveState.FAULT and np.all(np.delete(states, 2) == OE)
    assert rig.hal.read_fault_codes() == {3: code}


def test_following_error_is_reported(rig):
    cmd = rig.hal.lengths_m()
    cmd[5] += 0.05  # 5 cm in one cycle: 12.5 m/s demanded
    rig.hal.set_lengths(cmd)
    rig.steps(15)
    assert _codes(rig.hal.faults()) == [(6, "drive_fault", 0x8611)]
    assert any(e.kind == "fault" and e.node_id == 6 and "following error" in e.text
               for e in rig.hal.events())


def test_stuck_brake_shows_as_following_error_once_moving(rig):
    rig.bank.drives[6].stick_brake()
    rig.steps(30)
    assert rig.hal.faults() == []  # standing still: undetectable, and not detected
    l0 = rig.hal.lengths_m()
    for i in range(1, 120):
        rig.hal.set_lengths(l0 + 0.1 * (1 - np.cos(2 * np.pi * i * 0.004 / 2)))
        rig.hal.step()
    assert _codes(rig.hal.faults()) == [(7, "drive_fault", 0x8611)]


def test_fault_reset(rig):
    rig.bank.drives[2].inject_over_current()
    rig.steps(5)
    rig.hal.fault_reset()
    rig.steps(3)
    assert rig.hal.faults() == []
    assert rig.hal.state_names()[2] == "READY_TO_SWITCH_ON"  # reset, then kept disabled
    kinds = [e.kind for e in rig.hal.events() if e.node_id == 3]
    assert "fault_cleared" in kinds and kinds.count("emcy") == 2  # 0x2310, then 0x0000
    rig.hal.enable_and_wait()


def test_fault_reset_fails_while_the_cause_persists(rig):
    d = rig.bank.drives[4]
    d.inject_encoder_fault()
    rig.steps(3)
    rig.hal.fault_reset(hold_cycles=5)
    rig.steps(8)
    assert _codes(rig.hal.faults()) == [(5, "drive_fault", 0x7305)]
    assert any(e.kind == "fault_reset_failed" and e.node_id == 5 for e in rig.hal.events())
    d.repair_encoder()
    rig.hal.fault_reset()
    rig.steps(4)
    assert rig.hal.faults() == []


def test_heartbeat_loss_is_detected_within_three_periods():
    w = W.replace(bus=dataclasses.replace(W.bus, heartbeat_period_s=0.02))  # 5 cycles
    r = Rig(winches=w)
    try:
        r.steps(30)
        assert r.hal.faults() == [] and r.hal.events() == []
        r.bank.drives[4].stop_heartbeat()
        n = 0
        while not r.hal.faults():
            r.hal.step()
            n += 1
            assert n < 40
        assert 10 <= n <= 3 * 5 + 6  # > 3 periods of silence since the last one, < 3 + 1
        assert _codes(r.hal.faults()) == [(5, "heartbeat_lost", 0x8130)]
        assert [e.kind for e in r.hal.events()] == ["heartbeat_lost"]
        r.bank.drives[4].stop_heartbeat(False)
        r.steps(6)
        assert r.hal.faults() == []
        assert [e.kind for e in r.hal.events()] == ["heartbeat_resumed"]
    finally:
        r.close()


def test_node_off_the_bus_then_back():
    w = W.replace(bus=dataclasses.replace(W.bus, heartbeat_period_s=0.02))
    r = Rig(winches=w)
    try:
        r.bank.drives[1].set_silent()
        for _ in range(20):
            r.hal.step(timeout=0.02)
        kinds = [(e.node_id, e.kind, e.code) for e in r.hal.events()]
        assert kinds[0] == (2, "tpdo_missing", 0x8250)
        assert (2, "heartbeat_lost", 0x8130) in kinds
        assert {k[0] for k in kinds} == {2}
        d = r.bank.drives[1]
        deadline = time.monotonic() + 10.0
        while not d.connection_losses:  # off the bus for longer than its consumer time
            assert time.monotonic() < deadline
            time.sleep(0.01)
        d.set_silent(False)
        r.steps(8)
        # off the bus for longer than its consumer heartbeat time: it lost its master, went
        # pre-operational (0x1029) and holds in Quick Stop Active (0x6007, 0x605A)
        assert _codes(r.hal.faults()) == [(2, "nmt_state", 0x8130)]
        assert r.bank.drives[1].state == State.QUICK_STOP_ACTIVE
        with pytest.raises(DriveStartupError, match=r"node 2 \(cable 12\): NMT PRE-OP"):
            r.hal.enable_and_wait()
        assert r.hal.recover() == [2]
        assert r.hal.state_names()[1] == "QUICK_STOP_ACTIVE"
        r.hal.enable_and_wait()
    finally:
        r.close()


def test_node_reset_is_detected_and_recovered(rig):
    before = rig.hal.lengths_m()
    rig.bank.drives[4].reset_node()
    rig.steps(3)
    assert _codes(rig.hal.faults()) == [(5, "boot_up", 0x8130)]
    assert [e.kind for e in rig.hal.events()] == ["boot_up"]
    assert np.all(np.delete(rig.hal.states(), 4) == OE)  # the others carry on
    assert rig.hal.recover() == [5]
    assert rig.hal.faults() == []
    rig.hal.enable_and_wait()
    rig.steps(5)
    np.testing.assert_allclose(rig.hal.lengths_m(), before, atol=metres_per_count(W)[0])
    assert [e.kind for e in rig.hal.events()] == ["recovered"]
    rig.move(np.full(8, 0.02), 50)
    assert rig.hal.faults() == []


def _quick_stop_at_speed(r: Rig, v: float = 0.3, cycles: int = 40):
    """Pay out at ``v`` [m/s] (reached smoothly), quick stop, cycle; states and lengths."""
    l0 = r.hal.lengths_m()
    for i in range(1, 101):
        t = i * 0.004
        ramp = min(t, 0.2)
        x = v * (ramp**2 / 0.4 + max(t - 0.2, 0.0))
        r.hal.set_lengths(l0 + x)
        r.hal.step()
    r.hal.quick_stop()
    seen, p = [], []
    for _ in range(cycles):
        r.hal.step()
        seen.append(r.hal.states()[0])
        p.append(r.hal.lengths_m())
    return seen, p


def test_quick_stop_stops_on_the_ramp_and_holds_in_quick_stop_active(rig):
    """0x605A = 6 (the winch file): stop on the quick-stop ramp, stay powered and hold."""
    assert int(rig.bank.drives[0].param(0x605A)) == 6
    seen, p = _quick_stop_at_speed(rig)
    assert seen[1] == DriveState.QUICK_STOP_ACTIVE  # states are one cycle old
    assert np.all(rig.hal.states() == DriveState.QUICK_STOP_ACTIVE)  # and stays there
    np.testing.assert_array_equal(p[-1], p[-10])  # stopped, held by the position loop
    stop = p[-1] - p[0]
    assert np.all(stop > 0) and np.all(stop < 0.3**2 / (2 * 6.0) + 0.01)  # quick-stop ramp
    assert all(d.state == State.QUICK_STOP_ACTIVE and d.powered for d in rig.bank.drives)
    assert rig.hal.faults() == []  # asked for by the master: not a fault
    rig.steps(50)  # holds as long as it takes
    np.testing.assert_allclose(rig.hal.lengths_m(), p[-1], atol=metres_per_count(W)[0])
    rig.hal.enable_and_wait(max_cycles=3)  # transition 16: one cycle
    rig.move(np.full(8, 0.02), 50)  # and it follows setpoints again
    assert rig.hal.faults() == [] and np.all(rig.hal.states() == OE)


def test_quick_stop_option_2_ends_in_switch_on_disabled():
    r = Rig(winches=W.replace(quick_stop_option=2))
    try:
        seen, p = _quick_stop_at_speed(r)
        assert DriveState.QUICK_STOP_ACTIVE in seen
        assert np.all(r.hal.states() == DriveState.SWITCH_ON_DISABLED)  # torque off: brake
        np.testing.assert_array_equal(p[-1], p[-10])
        r.hal.enable_and_wait()
        r.steps(10)
        np.testing.assert_allclose(r.hal.lengths_m(), p[-1], atol=metres_per_count(W)[0])
    finally:
        r.close()


def test_software_limits_are_enforced_by_the_drives():
    lengths = L0.copy()
    lengths[0] = 29.99  # 1 cm below the 30 m limit
    r = Rig(lengths=lengths)
    try:
        lo, hi = limits_counts(W)
        start = r.hal.positions_counts()
        for i in range(1, 40):  # creep 1 mm per cycle to 30.029 m
            c = start.copy()
            c[0] += int(round(i * 0.001 / metres_per_count(W)[0]))
            r.hal.set_positions_counts(c)
            r.hal.step()
        r.steps(10)
        assert abs(r.hal.positions_counts()[0] - hi[0]) <= 2
        assert r.hal.limits_active().tolist() == [True] + [False] * 7
        assert [(e.node_id, e.kind) for e in r.hal.events()] == [(1, "internal_limit")]
        assert r.hal.faults() == []
        with pytest.raises(ValueError, match=r"cable 11"):
            r.hal.set_lengths(np.r_[30.01, L0[1:]])
    finally:
        r.close()


def test_dropped_and_delayed_frames(rig):
    rig.bank.drives[1].drop_tpdos(1)
    assert rig.hal.step(timeout=0.05) is False
    rig.steps(2)
    assert [(e.node_id, e.kind, e.code, e.source) for e in rig.hal.events()] == [
        (2, "tpdo_missing", 0x8250, "hal")]
    rig.bank.drives[2].delay_tpdos(1)
    rig.hal.step(timeout=0.05)
    rig.steps(2)
    assert [(e.node_id, e.kind) for e in rig.hal.events()] == [(3, "tpdo_missing"),
                                                               (3, "tpdo_late")]
    rig.bank.drives[3].drop_rpdos(1)  # within the RPDO deadline (0x1400 sub 5, 20 ms)
    rig.steps(3)
    assert rig.hal.events() == []
    assert rig.hal.faults() == [] and np.all(rig.hal.states() == OE)


def test_rpdo_deadline_stops_the_drive_and_the_master_holds_it(rig):
    """Setpoints lost for longer than the RPDO deadline: the drive stops on its own (0x6007 =
    quick stop, 0x605A = 6) and the master keeps it there until the controller enables it."""
    rig.bank.drives[3].drop_rpdos(6)  # 24 ms without a setpoint
    rig.steps(12)
    ev = [(e.node_id, e.kind, e.code) for e in rig.hal.events()]
    assert ev[:2] == [(4, "emcy", 0x8250), (4, "quick_stop", 0x8250)]
    assert _codes(rig.hal.faults()) == [(4, "quick_stop", 0x0000)]  # EMCY reset since
    states = rig.hal.states()
    assert states[3] == DriveState.QUICK_STOP_ACTIVE and np.all(np.delete(states, 3) == OE)
    target = rig.hal.targets_counts()[3]
    rig.hal.set_lengths(rig.hal.lengths_m() + 0.01)  # not for node 4: it is not enabled
    rig.steps(20)
    assert rig.hal.states()[3] == DriveState.QUICK_STOP_ACTIVE  # never re-enabled by itself
    assert rig.hal.targets_counts()[3] == target
    rig.hal.enable_and_wait(max_cycles=3)
    assert rig.hal.faults() == [] and np.all(rig.hal.states() == OE)


def test_shutdown_disables_and_leaves_operational():
    r = Rig()
    try:
        r.hal.shutdown()
        assert np.all(r.hal.states() == DriveState.SWITCH_ON_DISABLED)
        deadline = time.monotonic() + 2.0
        while not all(d.nmt_state == 0x7F for d in r.bank.drives):  # NMT pre-operational
            assert time.monotonic() < deadline
            time.sleep(0.002)
        assert r.hal.faults() == [] and r.hal.events() == []
    finally:
        r.close()


# ---------------------------------------------------------------------------- start-up errors


def test_missing_drive_is_named():
    r = Rig(start=False, enable=False, before_start=lambda b: b.drives[5].set_silent())
    try:
        with pytest.raises(DriveStartupError, match=r"node 6 \(cable 32\)") as exc:
            r.hal.start(timeout=0.3)
        assert "node 5" not in str(exc.value)
    finally:
        r.close()


def test_wrong_device_or_missing_csp_is_refused():
    r = Rig(start=False, enable=False)
    try:
        od = canopen.import_od(str(EDS_PATH), 1)
        od.device_information.product_number = 0x0999
        r.hal.close()
        r.hal = WinchDrives.open(f"virtual:{r.ch}", W, od, clock="sync")
        with pytest.raises(DriveConfigError, match=r"node 1 \(cable 11\): 0x1018:02 product code"):
            r.hal.start()
    finally:
        r.close()

    def no_csp(bank):
        bank.drives[3].od[0x6502].default = 0x21
    r = Rig(start=False, enable=False, before_start=no_csp)
    try:
        with pytest.raises(DriveConfigError, match=r"node 4 \(cable 22\).*cyclic synchronous"):
            r.hal.start()
    finally:
        r.close()


def test_drive_faulted_at_start_up_is_reported_and_blocks_enable():
    r = Rig(start=False, enable=False, before_start=lambda b: b.drives[7].inject_encoder_fault())
    try:
        r.hal.start()
        assert _codes(r.hal.faults()) == [(8, "drive_fault", 0x7305)]
        assert [(e.node_id, e.kind, e.code) for e in r.hal.events() if e.kind == "fault"] == [
            (8, "fault", 0x7305)]
        with pytest.raises(DriveStartupError, match=r"node 8 \(cable 42\): FAULT"):
            r.hal.enable_and_wait(max_cycles=10)
        assert np.all(np.delete(r.hal.states(), 7) == OE)
    finally:
        r.close()


def test_wall_clock_rig_and_master():
    """Real-time mode: drives follow time.monotonic (heartbeats from the bank's ticker thread),
    the master checks heartbeats on the wall clock."""
    w = W.replace(bus=dataclasses.replace(W.bus, heartbeat_period_s=0.05))
    ch = f"haldrives-wall-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), w, clock=time.monotonic)
    bank.set_positions_m(L0)
    bank.start()
    hal = WinchDrives.open(f"virtual:{ch}", w, EDS_PATH, clock="wall")
    try:
        hal.start()
        hal.enable_and_wait()
        l0 = hal.lengths_m()
        tick = time.monotonic()
        for i in range(1, 101):  # paced at the SYNC period: 0.4 s, 2.5 m/s^2 peak
            hal.set_lengths(l0 + 0.01 * (1 - np.cos(2 * np.pi * i / 100)))
            hal.step()
            tick += w.bus.sync_period_s
            time.sleep(max(0.0, tick - time.monotonic()))
        # tracking on the wall clock depends on this machine keeping the pace: checked on
        # the deterministic clock; here the drives just have to be up and answering
        assert all(hal.step() for _ in range(5))
        assert np.all(np.isfinite(hal.lengths_m()))
        bank.drives[0].stop_heartbeat()
        deadline = time.monotonic() + 5.0
        while not any(f.kind == "heartbeat_lost" for f in hal.faults()):
            assert time.monotonic() < deadline, "heartbeat loss not detected on the wall clock"
            hal.step()
            time.sleep(0.004)
        # (on a starved machine other drives' heartbeats may be late too: not asserted here;
        # that nothing is detected without a cause is tested on the deterministic clock)
        assert (1, "heartbeat_lost") in {(f.node_id, f.kind) for f in hal.faults()}
    finally:
        hal.close()
        bank.close()


# ------------------------------------------------------------------ start-up on a busy host


def _starve_producer(r: Rig) -> None:
    """What a master heartbeat producer kept off the processor for longer than the drives'
    consumer time does (as a busy host can): every drive's consumer heartbeat expires (its
    own reaction, 0x6007 and 0x1029: pre-operational); then cycles (not enabled) until the
    HAL has read the drives' heartbeats saying where they went."""
    deadline = time.monotonic() + 10.0
    while not all(d.nmt_state == 0x05 for d in r.bank.drives):  # the NMT start arrived
        assert time.monotonic() < deadline
        time.sleep(0.005)
    for d in r.bank.drives:  # expired now (the wall-time watch forgives a starved simulator)
        with d.lock:
            d._consumer_expired(W.bus.master_node_id, wall=False)
    for _ in range(500):  # cycles (not time) until their heartbeats said so
        r.hal.step(timeout=0.05)
        if all(f.kind == "nmt_state" for f in r.hal.faults()) and len(r.hal.faults()) == 8:
            return
    raise AssertionError(f"the HAL never saw the drives pre-operational: {r.hal.faults()}")


def test_drives_that_left_operational_before_the_first_enable_are_restarted():
    r = Rig(enable=False)
    try:
        _starve_producer(r)
        assert {f.kind for f in r.hal.faults()} == {"nmt_state"}
        with pytest.raises(DriveStartupError, match=r"NMT PRE-OP.*master heartbeat: longest "
                           r"gap"):
            r.hal.enable_and_wait()  # without restarts: refused, naming the nodes
        r.hal.enable_and_wait(restart_tries=3)
        assert r.hal.state_names() == ["OPERATION_ENABLED"] * 8
        restarts = [e for e in r.hal.events() if e.kind == "nmt_restart"]
        assert sorted(e.node_id for e in restarts) == list(range(1, 9))
        assert all("restart 1 of 3" in e.text for e in restarts)
        assert r.hal.faults() == []
    finally:
        r.close()


def test_nothing_is_restarted_when_every_drive_is_operational(rig):
    rig.hal.disable()
    rig.steps(5)
    assert rig.hal.restart_for_enable() == []
    rig.hal.enable_and_wait(restart_tries=3)
    assert [e.kind for e in rig.hal.events()] == []


def test_a_drive_that_stays_pre_operational_fails_naming_node_and_state():
    r = Rig(enable=False)
    try:
        _starve_producer(r)
        send = r.hal._send_nmt

        def no_start_for_node_3(k: int, command: int) -> None:
            if not (k == 2 and command == 0x01):  # node 3 never gets NMT start
                send(k, command)

        r.hal._send_nmt = no_start_for_node_3
        with pytest.raises(DriveStartupError, match=r"not NMT OPERATIONAL after 2 restarts .*"
                           r"node 3 \(cable 21\): NMT PRE-OPERATIONAL \(master heartbeat"):
            r.hal.enable_and_wait(restart_tries=2)
        tries = [e.text for e in r.hal.events() if e.kind == "nmt_restart" and e.node_id == 3]
        assert len(tries) == 2
        assert r.bank.drives[2].nmt_state == 0x7F
    finally:
        r.close()


def test_the_producer_records_its_gaps_and_lateness(rig):
    st = rig.hal.producer_stats()
    assert st["late"] == 0 and 0 < st["gap_max_s"] < W.bus.master_heartbeat_timeout_s
    assert st["scheduling"].startswith("normal (raised priority not requested")
    rig.hal._master_heartbeat = lambda: None
    time.sleep(W.bus.master_heartbeat_timeout_s * 1.5)  # the gap to record, not a timing
    del rig.hal._master_heartbeat
    deadline = time.monotonic() + 5.0
    while rig.hal.producer_stats()["late"] == 0:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert rig.hal.producer_stats()["gap_max_s"] > W.bus.master_heartbeat_timeout_s
    with pytest.raises(ValueError, match=r"must be 0 \(normal\) to"):
        rig.hal.set_producer_priority(1000)  # refused before the thread is touched
    assert rig.hal.producer_priority == 0


def test_a_syncs_wall_time_is_taken_after_the_rpdos_went_out(rig):
    """The wall time kept for a SYNC (``_sync_sent``, against which TPDOs' time stamps are
    matched) is taken after the cycle's RPDOs were written, just before the SYNC: a TPDO
    that answers the previous SYNC while the RPDOs go out keeps that SYNC."""
    bus = rig.hal.network.bus
    sent: list[tuple[float, int]] = []
    real = bus.send

    def send(msg, *a, **k):
        sent.append((time.time(), msg.arbitration_id))
        return real(msg, *a, **k)

    bus.send = send
    try:
        rig.steps(3)
    finally:
        bus.send = real
    rpdo_t = [t for t, cob in sent if 0x200 <= cob < 0x280]
    sync_t = [t for t, cob in sent if cob == 0x80]
    assert rpdo_t and sync_t
    noted = rig.hal._sync_sent.last_wall()
    assert max(rpdo_t) <= noted <= sync_t[-1]
