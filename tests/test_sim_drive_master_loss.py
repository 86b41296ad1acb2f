"""The simulated drive loses its master: consumer heartbeat (0x1016), RPDO deadline, abort
connection option (0x6007), error behaviour (0x1029), and the quick stop that holds (0x605A 6).

One drive on a virtual bus on its deterministic clock (see tests/test_sim_drive.py); the
master's heartbeat is a raw frame 0x700 + 127 sent by the test.
"""

from __future__ import annotations

import time
import uuid

import can
import pytest
from canopen.sdo import SdoAbortedError
from test_sim_drive import AX, START_COUNTS, Harness

from firmware_sim.cia402_drive import State
from firmware_sim.drive_bank import SimulatedWinchBank

MASTER = 127
QS_DECEL = 4_000_000  # counts/s^2
V = 1_000_000  # counts/s


@pytest.fixture
def h():
    harness = Harness()
    yield harness
    harness.close()


def master_heartbeat(h: Harness) -> None:
    h.net.send_message(0x700 + MASTER, b"\x05")
    h.barrier()


def watch_master(h: Harness, timeout_ms: int = 250, option: int = 3, behaviour: int = 0) -> None:
    h.w(0x1016, 1, MASTER << 16 | timeout_ms)
    h.w(0x6007, 0, option)
    h.w(0x1029, 1, behaviour)
    h.w(0x605A, 0, 6)
    h.w(0x6085, 0, QS_DECEL)


def run_csv(h: Harness) -> None:
    """Operation Enabled in cyclic synchronous velocity at V, NMT operational."""
    h.w(0x6060, 0, 9)
    h.w(0x60FF, 0, V)
    h.nmt(0x01)
    for cw in (0x06, 0x07, 0x0F):
        h.cw(cw)
    h.drive.advance(0.3)
    assert h.drive.state == State.OPERATION_ENABLED
    assert h.drive.axis.vel == pytest.approx(V, rel=1e-3)


def test_master_heartbeat_loss_quick_stops_and_holds_in_quick_stop_active(h):
    watch_master(h)
    run_csv(h)
    master_heartbeat(h)
    t_heard = h.drive.now_us
    h.drive.advance(0.2)
    master_heartbeat(h)  # still there
    t_heard = h.drive.now_us
    h.drive.advance(0.24)
    assert h.drive.state == State.OPERATION_ENABLED and h.emcy_codes() == []
    p0 = h.drive.axis.pos
    h.drive.advance(0.02)  # 260 ms of silence > 250 ms
    h.wait_for(lambda: h.emcy_codes() == [0x8130])
    assert h.drive.state == State.QUICK_STOP_ACTIVE
    t_lost, why, lag = h.drive.connection_losses[-1]
    assert lag == pytest.approx(0.250001)
    assert t_lost - t_heard == 250_001 and "node 127" in why  # 1 us after the consumer time
    assert h.drive.nmt_state == 0x7F  # 0x1029:1 = 0: pre-operational
    h.drive.advance(0.3)  # V / a = 0.25 s on the quick-stop ramp
    assert h.drive.state == State.QUICK_STOP_ACTIVE  # option 6: stays
    stop = h.drive.axis.pos - p0  # 10 ms at V, then the ramp
    assert stop == pytest.approx(V * 0.010 + V**2 / (2 * QS_DECEL), rel=0.05)
    p1 = h.drive.axis.pos
    h.drive.advance(1.0)
    assert abs(h.drive.axis.pos - p1) < 0.01 and abs(h.drive.axis.vel) < 1e-3  # holds
    assert h.sw & 0x6F == 0x07 and h.sw & 0x0410 == 0x0410  # QSA, voltage on, stopped
    # the master comes back: heartbeat, NMT start, enable operation (transition 16)
    master_heartbeat(h)
    h.wait_for(lambda: h.emcy_codes() == [0x8130, 0x0000])
    h.nmt(0x01)
    h.cw(0x0F)
    assert h.drive.state == State.OPERATION_ENABLED


def test_monitoring_starts_with_the_first_heartbeat(h):
    watch_master(h)
    run_csv(h)
    h.drive.advance(2.0)  # no master heartbeat ever: not watched yet (CiA 301)
    assert h.drive.state == State.OPERATION_ENABLED and h.emcy_codes() == []


@pytest.mark.parametrize(("option", "final", "nmt"), [
    (0, State.OPERATION_ENABLED, 0x7F),  # no action: keeps running (never on a cable robot)
    (1, State.FAULT, 0x7F),  # fault signal: fault reaction (0x605E 2: ramp), then Fault
    (2, State.SWITCH_ON_DISABLED, 0x7F),  # disable voltage at once
    (3, State.QUICK_STOP_ACTIVE, 0x7F),
])
def test_abort_connection_options(h, option, final, nmt):
    watch_master(h, option=option)
    run_csv(h)
    master_heartbeat(h)
    h.drive.advance(0.6)
    assert h.drive.state == final and h.drive.nmt_state == nmt
    if final == State.FAULT:
        assert h.r(0x603F) == 0x8130


@pytest.mark.parametrize(("behaviour", "nmt"), [(0, 0x7F), (1, 0x05), (2, 0x04)])
def test_error_behaviour_after_a_heartbeat_loss(h, behaviour, nmt):
    watch_master(h, behaviour=behaviour)
    run_csv(h)
    master_heartbeat(h)
    h.drive.advance(0.3)
    assert h.drive.nmt_state == nmt and h.drive.state == State.QUICK_STOP_ACTIVE


def test_rpdo_deadline_acts_while_operation_enabled(h):
    watch_master(h)
    h.w(0x1400, 1, 0x201 | 1 << 31)
    h.w(0x1400, 5, 20)  # 20 ms deadline, SYNC every 4 ms
    h.w(0x1400, 1, 0x201)
    h.enable_csp()
    for _ in range(10):
        h.rpdo(0x0F, START_COUNTS)
        h.sync()
    h.drive.drop_rpdos(4)
    for _ in range(4):  # 4 lost: 20 ms since the last one arrived, not more
        h.rpdo(0x0F, START_COUNTS)
        h.sync()
    assert h.drive.state == State.OPERATION_ENABLED and h.emcy_codes() == []
    h.drive.drop_rpdos(1)
    h.rpdo(0x0F, START_COUNTS)
    h.sync()  # 24 ms
    h.wait_for(lambda: h.emcy_codes() == [0x8250])
    assert h.drive.state == State.QUICK_STOP_ACTIVE
    assert h.drive.nmt_state == 0x05  # the node is fine: no 0x1029 reaction
    h.rpdo(0x0F, START_COUNTS)  # setpoints again: EMCY reset; re-enable as the standard allows
    h.sync()
    h.wait_for(lambda: h.emcy_codes() == [0x8250, 0x0000])
    assert h.drive.state == State.OPERATION_ENABLED  # the RPDO's controlword 0x0F: 16


def test_nmt_stop_while_enabled_is_an_abort(h):
    watch_master(h)
    run_csv(h)
    h.nmt(0x02)
    h.wait_for(lambda: h.drive.nmt_state == 0x04)
    assert h.drive.state == State.QUICK_STOP_ACTIVE


def test_consumer_entries_are_checked(h):
    h.w(0x1016, 1, MASTER << 16 | 100)
    with pytest.raises(SdoAbortedError) as exc:
        h.w(0x1016, 2, MASTER << 16 | 200)  # a second time for the same node
    assert exc.value.code == 0x06040043
    h.w(0x1016, 2, 5 << 16 | 200)  # another node: fine
    with pytest.raises(SdoAbortedError):
        h.w(0x6007, 0, 4)
    with pytest.raises(SdoAbortedError):
        h.w(0x1029, 1, 3)


def test_sync_clock_drive_lives_in_real_time_without_sync(h):
    """No SYNC at all: heartbeats per period of wall time; the master lost on wall time
    starts the stop and the drive's clock runs on wall time to carry it out."""
    watch_master(h)
    h.w(0x1017, 0, 100)
    run_csv(h)
    n0 = len(h.rx[0x701])
    t = time.monotonic()
    h.drive.wall_tick(t)
    for i in range(1, 6):
        h.drive.wall_tick(t + 0.1 * i)
    h.barrier()
    assert len(h.rx[0x701]) - n0 >= 5  # one per 100 ms of wall time
    master_heartbeat(h)
    t = time.monotonic()
    h.drive.wall_tick(t)
    h.drive.wall_tick(t + 0.04)
    assert h.drive.state == State.OPERATION_ENABLED and not h.drive.free_running
    for i in range(1, 70):  # 10 ms ticks, as the bank does: 690 ms of wall time
        h.drive.wall_tick(t + 0.04 + 0.01 * i)
    assert h.drive.free_running and h.drive.state == State.QUICK_STOP_ACTIVE
    assert abs(h.drive.axis.vel) < 1.0  # the ramp was carried out on wall time
    h.wait_for(lambda: 0x8130 in h.emcy_codes())
    h.sync()  # a master again: SYNC-driven again
    assert not h.drive.free_running


def test_a_starved_simulator_does_not_stop_the_robot(h):
    watch_master(h)
    run_csv(h)
    master_heartbeat(h)
    t = time.monotonic()
    h.drive.wall_tick(t)
    h.drive.wall_tick(t + 1.0)  # our own process did not run for 1 s
    assert h.drive.state == State.OPERATION_ENABLED
    assert AX.node_id == 1


class FakeClock:
    """The wall clock of a drive on a clock function, moved by the test [s]."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _wall_clock_drive_enabled(clock: FakeClock) -> Harness:
    """A drive on a clock function in CSP, Operation Enabled, RPDO deadline 20 ms, fed an
    RPDO + SYNC every 4 ms with the bank's tick every 2 ms between."""
    h = Harness(clock=clock)
    h.w(0x1400, 1, 0x201 | 1 << 31)
    h.w(0x1400, 5, 20)
    h.w(0x1400, 1, 0x201)
    h.enable_csp()
    for _ in range(10):
        _cycle(h, clock)
    assert h.drive.state == State.OPERATION_ENABLED
    return h


def _cycle(h: Harness, clock: FakeClock, rpdo: bool = True) -> None:
    for _ in range(2):
        clock.t += 0.002
        h.drive.tick()
    if rpdo:
        h.rpdo(0x0F, h.drive.position_actual())
    h.sync()


def test_a_starved_wall_clock_simulator_judges_waiting_frames_after_the_gap():
    """The simulator's process did not run for 30 ms (> the 20 ms RPDO deadline): the RPDO
    waiting in its socket is handled first, and the gap is not the master's."""
    clock = FakeClock()
    h = _wall_clock_drive_enabled(clock)
    try:
        clock.t += 0.030  # no tick, no frame handled: starved
        _cycle(h, clock)
        assert h.drive.state == State.OPERATION_ENABLED
        assert 0x8250 not in h.emcy_codes()
    finally:
        h.close()


def test_a_wall_clock_drive_still_stops_when_the_setpoints_stop():
    """Its own ticks go on (it runs), the RPDOs stop for 24 ms: RPDO timeout, stopped."""
    clock = FakeClock()
    h = _wall_clock_drive_enabled(clock)
    try:
        for _ in range(6):
            _cycle(h, clock, rpdo=False)
        h.wait_for(lambda: 0x8250 in h.emcy_codes())
        assert h.drive.state != State.OPERATION_ENABLED  # 0x6007 as configured (fault)
    finally:
        h.close()


def test_the_bank_sees_frames_waiting_for_its_drives():
    """The bank's ticker leaves the deadlines to frames waiting in its bus's queue (their
    handling judges them after the gap): it must see them, and see none when none wait."""
    clock = FakeClock()
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=f"bank-{uuid.uuid4().hex}"),
                              clock=clock)  # not started: no ticker
    try:
        bank.network.notifier.stop()  # nothing takes the frames from the queue now
        assert not bank._frames_waiting()
        bank.network.bus.queue.put(can.Message(arbitration_id=0x80, data=b""))
        assert bank._frames_waiting()
        bank.network.bus.queue.get_nowait()
        assert not bank._frames_waiting()
    finally:
        bank.close()
