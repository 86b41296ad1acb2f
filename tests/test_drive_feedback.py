"""Lost drive feedback is a fault (``drive_lost``) and another master on the bus is noticed
(``foreign_master``): the pure checks of hal/bus_watch.py, the HAL on a virtual bus, the
dry run in lock-step and in real time, the socketcand hub."""

from __future__ import annotations

import json
import threading
import time
import uuid

import can
import canopen
import numpy as np
import pytest
from drive_rig import BankRig

from bench.cli import main
from bench.dryrun.loop import ControlLoop, LoopOptions
from bench.dryrun.scenarios import max_rate_hz, resolve_scenario, sync_period_us
from bench.dryrun.world import start_world, with_rate
from controller.paths import build_trajectory, load_path
from controller.supervisor import Reaction
from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.drive_bank import SimulatedWinchBank
from firmware_sim.scenario import load_scenario
from hal.bus_watch import (
    DRIVE_LOST,
    FOREIGN_MASTER,
    TPDO_DEADLINE_MIN_S,
    OwnFrames,
    feedback_lost,
    master_frame,
)
from hal.can_bus import open_bus
from hal.drives import DriveLostError, DriveState, WinchDrives

W = load_winches()
OE = DriveState.OPERATION_ENABLED
RPDOS = {0x200 + n: n for n in range(1, 9)}
#: SDO expedited write of 0x6040:0 (controlword) = 0 to node 4: "switch it off"
SDO_OFF_4 = (0x604, bytes([0x2B, 0x40, 0x60, 0x00, 0x00, 0x00, 0x00, 0x00]))


# ---------------------------------------------------------------------------- pure checks


def test_feedback_lost_needs_both_the_cycles_and_the_time():
    missed = np.array([0, 4, 5, 5, 9])
    silent = np.array([1.0, 1.0, 0.04, 0.05, 0.2])
    assert feedback_lost(missed, silent, 5, 0.05).tolist() == [False, False, False, True, True]
    # nobody missed anything: nothing is lost, however long since the last TPDO
    assert not feedback_lost(np.zeros(8), np.full(8, 10.0), 5, 0.05).any()
    with pytest.raises(ValueError, match="deadline_cycles"):
        feedback_lost(missed, silent, 0)


@pytest.mark.parametrize("cob, data, node, words", [
    (0x604, SDO_OFF_4[1], 4, ["0x604", "SDO", "write", "0x6040:0", "= 0"]),
    (0x603, bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]), 3, ["0x603", "read", "0x6041:0"]),
    (0x000, bytes([0x02, 0x00]), 0, ["0x000", "NMT stop", "all nodes"]),
    (0x000, bytes([0x81, 0x05]), 5, ["0x000", "reset node", "node 5"]),
    (0x080, b"", 0, ["0x080", "SYNC"]),
    (0x207, bytes(6), 7, ["0x207", "RPDO"]),
])
def test_master_frames_are_named_by_their_cob_id(cob, data, node, words):
    hit = master_frame(cob, data, range(1, 9), RPDOS)
    assert hit is not None and hit[0] == node
    for w in words:
        assert w in hit[1], hit[1]


@pytest.mark.parametrize("cob", [0x183, 0x703, 0x083, 0x583, 0x77F, 0x609, 0x209, 0x280])
def test_frames_a_master_does_not_send_are_not_flagged(cob):
    """TPDOs, heartbeats, EMCYs, SDO answers, the master's heartbeat, another bus's nodes."""
    assert master_frame(cob, bytes(8), range(1, 9), RPDOS) is None


def test_own_frames_are_recognised_once_and_only_within_the_window():
    t = [0.0]
    own = OwnFrames(window_s=1.0, clock=lambda: t[0])
    own.sent(0x080, b"")
    own.sent(0x604, b"\x40\x41\x60\x00\x00\x00\x00\x00")
    assert own.is_own(0x080, b"")
    assert not own.is_own(0x080, b"")  # one echo per frame sent: a second SYNC is foreign
    assert not own.is_own(0x604, b"\x2b\x40\x60\x00\x00\x00\x00\x00")  # other data
    t[0] = 2.0
    assert not own.is_own(0x604, b"\x40\x41\x60\x00\x00\x00\x00\x00")  # too old


# ---------------------------------------------------------------------------- the HAL


class Rig(BankRig):
    """Eight simulated drives on a virtual bus and the HAL, lock-step on the SYNC clock;
    ``echo``: the HAL's bus receives its own frames (as a bus with receive_own_messages)."""

    def __init__(self, echo: bool = False) -> None:
        super().__init__("feedback")
        if echo:
            net = canopen.Network(open_bus(self.can, receive_own_messages=True))
            net.connect()
            self.hal = WinchDrives(net, W, EDS_PATH, clock="sync", own_network=True)
            self.hal.start()
            self.hal.enable_and_wait()
        else:
            self.hal = self.open_hal()

    def other_master_sends(self, cob: int, data: bytes) -> None:
        """A second python-can client on the channel sends one frame (delivered to the HAL
        by its notifier thread: given 0.1 s)."""
        other = can.Bus(interface="virtual", channel=self.ch)
        try:
            other.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))
        finally:
            other.shutdown()
        time.sleep(0.1)


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_tpdos_that_stop_make_the_drive_lost_with_its_state_unknown(rig):
    hal = rig.hal
    for _ in range(20):
        hal.step()
    assert hal.events() == [] and hal.faults() == []
    rig.bank.drives[2].drop_tpdos(10**9)
    t0 = time.monotonic()
    n = 0
    while not hal.faults():
        hal.step()
        n += 1
        assert n < 30
    # the deadline: 5 SYNCs and 0.08 s (20 cycles at 250 Hz), then the next receive
    assert n <= int(np.ceil(TPDO_DEADLINE_MIN_S / W.bus.sync_period_s)) + 2
    assert [(f.node_id, f.kind) for f in hal.faults()] == [(3, DRIVE_LOST)]
    assert hal.state_names()[2] == "UNKNOWN"  # never its last live state
    assert np.all(np.delete(hal.states(), 2) == OE)
    kinds = [(e.node_id, e.kind) for e in hal.events()]
    assert kinds == [(3, "tpdo_missing"), (3, DRIVE_LOST)]
    # the cycles go on at the master's pace: one bounded wait per miss, none once lost
    for _ in range(50):
        hal.step()
    assert time.monotonic() - t0 < 0.5 + 22 * 0.05 + 2.0
    assert hal.state_names()[2] == "UNKNOWN"
    with pytest.raises(Exception, match="drive_lost"):
        hal.enable_and_wait(max_cycles=3)


def test_a_lost_drive_whose_tpdos_come_back_is_known_again(rig):
    hal = rig.hal
    rig.bank.drives[5].drop_tpdos(20)
    for _ in range(40):
        hal.step()
    kinds = [(e.node_id, e.kind) for e in hal.events()]
    assert (6, DRIVE_LOST) in kinds and (6, "tpdo_resumed") in kinds
    assert hal.faults() == [] and hal.state_names()[5] != "UNKNOWN"


def test_a_drive_lost_while_enabling_raises_naming_it():
    r = Rig()
    try:
        r.hal.disable()
        r.hal.run_until(lambda d: not np.any(d.states() == OE), 20)
        r.bank.drives[2].drop_tpdos(10**9)
        with pytest.raises(DriveLostError, match=r"node 3 \(cable 21\)") as exc:
            r.hal.enable_and_wait()
        assert exc.value.node_ids == (3,)
        assert [(f.node_id, f.kind) for f in r.hal.faults()] == [(3, DRIVE_LOST)]
    finally:
        r.close()


@pytest.mark.parametrize("echo", [False, True])
def test_nothing_is_reported_without_a_fault_nor_another_master(echo):
    """The HAL's own SDOs (start-up), NMT, SYNC and RPDOs are never foreign, on a bus that
    echoes them too."""
    r = Rig(echo=echo)
    try:
        assert r.hal.foreign.echoes is echo
        for _ in range(200):
            r.hal.set_lengths(r.hal.lengths_m())
            r.hal.step()
        r.hal.read_fault_codes()  # (none in Fault: nothing read)
        assert r.hal.events() == [] and r.hal.faults() == []
        # and another master is still noticed
        r.other_master_sends(*SDO_OFF_4)
        r.hal.step()
        found = [(f.node_id, f.kind) for f in r.hal.faults()]
        assert (4, FOREIGN_MASTER) in found
    finally:
        r.close()


def test_a_drive_another_master_switched_off_is_not_enabled_again(rig):
    """0x6040 = 0 from another master switches node 4 off: the HAL reports it, drops its
    own enable request (it used to drive it back to Operation Enabled within 3 cycles) and
    leaves it off until enable(); the other drives go on."""
    hal = rig.hal
    for _ in range(5):
        hal.step()
    hal.events()
    rig.other_master_sends(*SDO_OFF_4)
    for _ in range(30):
        hal.set_lengths(hal.lengths_m())
        hal.step()
    assert hal.state_names()[3] == "SWITCH_ON_DISABLED"
    assert rig.bank.drive(4).state.name == "SWITCH_ON_DISABLED"
    assert np.all(np.delete(hal.states(), 3) == OE)
    ev = [(e.node_id, e.kind) for e in hal.events()]
    assert ev.count((4, "switched_off")) == 1 and (4, FOREIGN_MASTER) in ev, ev
    hal.enable_and_wait()  # the controller's own enable brings it back
    assert np.all(hal.states() == OE)


def test_the_bus_log_of_a_switch_off_replays_to_the_same_events(rig):
    """The frames of the bus while another master switches node 4 off, replayed into the
    replay HAL: the same drive events (``switched_off`` included) and final states; the
    other master's SDO frame is not told from this master's in a log (not replayed)."""
    from bench.can_replay import replay

    log = can.Bus(interface="virtual", channel=rig.ch)  # hears every frame on the bus
    hal = rig.hal
    try:
        for _ in range(5):
            hal.step()
        hal.events()
        rig.other_master_sends(*SDO_OFF_4)
        for _ in range(20):
            hal.step()
        time.sleep(0.05)
        frames = []
        while (m := log.recv(0)) is not None:
            frames.append(m)
    finally:
        log.shutdown()
    live = [(e.node_id, e.kind, e.code) for e in hal.events() if e.kind != FOREIGN_MASTER]
    assert (4, "switched_off", 0) in live
    got = replay(frames, W)
    assert [(e["node"], e["kind"], e["code"]) for e in got.events] == live
    assert got.final_states == hal.state_names()


@pytest.mark.parametrize("cob, data, node", [
    SDO_OFF_4 + (4,),
    (0x000, bytes([0x80, 0x00]), 0),  # NMT pre-operational to all nodes
    (0x080, b"", 0),  # a second SYNC producer
    (0x202, bytes(6), 2),  # an RPDO of node 2
])
def test_another_master_is_an_event_naming_the_cob_id(rig, cob, data, node):
    rig.other_master_sends(cob, data)
    rig.hal.step()
    ev = [e for e in rig.hal.events() if e.kind == FOREIGN_MASTER]
    assert [(e.node_id, e.kind) for e in ev] == [(node, FOREIGN_MASTER)]
    assert f"COB-ID 0x{cob:03X}" in ev[0].text
    assert any(f.kind == FOREIGN_MASTER and f.node_id == node for f in rig.hal.faults())


def test_another_master_through_the_socketcand_hub():
    from firmware_sim.rig import SimRig
    from hal.interface import open_hardware

    sim = SimRig(winches=W).start()
    try:
        hw = open_hardware(sim.can_spec, None, eds=EDS_PATH, winches=W, clock="sync")
        try:
            hw.start()
            hw.enable()
            for _ in range(50):
                hw.step()
            assert hw.events() == [] and hw.faults() == []
            other = open_bus(sim.can_spec)
            try:
                other.send(can.Message(arbitration_id=SDO_OFF_4[0], data=SDO_OFF_4[1],
                                       is_extended_id=False))
                time.sleep(0.2)  # over TCP: let it arrive (lock-step cycles take no time)
            finally:
                other.shutdown()
            r = hw.step()
            assert [(f.device, f.address, f.kind) for f in r.faults
                    if f.kind == FOREIGN_MASTER] == [("drive", 4, FOREIGN_MASTER)]
            assert "COB-ID 0x604" in str(r.faults)
        finally:
            hw.close()
    finally:
        sim.close()


# ---------------------------------------------------------------------------- dry runs

TP = '[[fault]]\nat_s = {at}\ndrive = 3\nkind = "drop_tpdo"\nclear_s = 1000.0\n'


def _dry_run(tmp_path, capsys, at: float, *extra: str) -> tuple[int, dict]:
    faults = tmp_path / "tp.toml"
    faults.write_text(TP.format(at=at))
    code = main(["dry-run", "paper-centre", "--faults", str(faults), "--duration", "4",
                 "--json", "--quiet", *extra])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, json.loads(out)


def _lost_3(res: dict, at: float) -> None:
    lost = [e for e in res["events"] if e["kind"] == DRIVE_LOST and e["active"]]
    assert lost and lost[0]["address"] == 3 and lost[0]["reaction"] == "quick_stop", \
        res["events"]
    assert 0.0 <= lost[0]["t"] - at <= 0.1, lost[0]
    assert res["ended"] == "quick_stop", res["message"]
    assert "drive_lost" in res["message"] or "TPDOs lost" in res["message"], res["message"]
    assert res["drive_states"][2] == "UNKNOWN"
    assert "OPERATION_ENABLED" not in res["drive_states"]


@pytest.mark.parametrize("at", [1.5, 0.1])
def test_dry_run_lock_step_tpdo_loss_is_drive_lost_quickly(tmp_path, capsys, at):
    t0 = time.monotonic()
    code, res = _dry_run(tmp_path, capsys, at)
    assert code == 1
    _lost_3(res, at)
    assert time.monotonic() - t0 < 60  # it crawled for ~240 s before


def test_dry_run_real_time_tpdo_loss_while_enabling_is_a_clean_stop(tmp_path, capsys):
    code, res = _dry_run(tmp_path, capsys, 0.1, "--realtime")
    assert code == 1
    lost = [e for e in res["events"] if e["kind"] == DRIVE_LOST and e["active"]]
    assert lost and lost[0]["address"] == 3, res["events"]
    assert res["ended"] == "quick_stop" and "node 3 (cable 21)" in res["message"]
    assert res["drive_states"][2] == "UNKNOWN"


SC = load_scenario(resolve_scenario("paper-centre"))
WINCHES = with_rate(load_winches(), sync_period_us(max_rate_hz(load_winches())) * 1e-6)


def _loop_with(world, tick, seconds: float) -> ControlLoop:
    model = SC.model
    spec = load_path("paper-centre")
    return ControlLoop(world.hw, world.tracker, model, lambda p0: build_trajectory(spec, p0),
                       LoopOptions(max_duration_s=seconds, decimate=5, init_dwell_s=0.2),
                       tick=tick, stop=threading.Event())


def test_dry_run_second_client_sdo_write_quick_stops_within_3_cycles():
    with start_world(SC, WINCHES) as world:
        channel = world.info["virtual"].removeprefix("virtual:")
        sent: list[float] = []
        holder: list[ControlLoop] = []

        def tick():
            world.tick()
            loop = holder[0]
            if not sent and loop.result.cycles == 150:
                other = can.Bus(interface="virtual", channel=channel)
                try:
                    other.send(can.Message(arbitration_id=SDO_OFF_4[0], data=SDO_OFF_4[1],
                                           is_extended_id=False))
                finally:
                    other.shutdown()
                sent.append(world.hw.drives.now() - loop._t0)

        loop = _loop_with(world, tick, 2.0)
        holder.append(loop)
        res = loop.run()
    assert sent
    ev = [e for e in res.events if e["kind"] == FOREIGN_MASTER and e["active"]]
    assert ev and ev[0]["reaction"] == Reaction.QUICK_STOP.label, res.events
    assert ev[0]["address"] == 4 and "COB-ID 0x604" in ev[0]["text"]
    assert ev[0]["t"] - sent[0] <= 3 * WINCHES.bus.sync_period_s + 1e-6
    assert res.ended == "quick_stop"


def test_dry_run_without_faults_reports_neither():
    with start_world(SC, WINCHES) as world:
        res = _loop_with(world, world.tick, 1.0).run()
    assert res.ended == "completed", res.message
    kinds = {e["kind"] for e in res.events}
    assert not kinds & {DRIVE_LOST, FOREIGN_MASTER, "tpdo_missing", "heartbeat_lost"}, kinds


# ---------------------------------------------------------------------------- commissioning


@pytest.mark.parametrize("foreign", [True, False])
def test_commission_jog_stops_on_another_masters_frame(foreign):
    """The commissioning master (hal.motion.AxisMaster) watches the same frames: an SDO
    write from a second client ends the jog (MotionError naming the COB-ID) and the drive
    is left disabled; without it the jog runs to its end."""
    from hal.motion import AxisMaster, JogInput, MotionError, run_jog

    ch = f"feedback-jog-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), W)
    bank.set_positions_m(np.linspace(9.0, 12.5, 8))
    bank.start()
    net = canopen.Network(can.Bus(interface="virtual", channel=ch))
    net.connect()
    try:
        m = AxisMaster(net, W, 3, EDS_PATH, clock="sync", pace=False)
        ax = W.axis(3)
        m.start(1)
        n = [0]

        def read():
            n[0] += 1
            if n[0] == 40 and foreign:
                other = can.Bus(interface="virtual", channel=ch)
                try:
                    other.send(can.Message(arbitration_id=SDO_OFF_4[0], data=SDO_OFF_4[1],
                                           is_extended_id=False))
                finally:
                    other.shutdown()
                time.sleep(0.1)  # the notifier thread delivers it
            return JogInput.OUT if n[0] < 120 else JogInput.QUIT

        try:
            if foreign:
                with pytest.raises(MotionError, match="COB-ID 0x604 SDO request") as exc:
                    run_jog(m, read, int(ax.m_to_counts(20.0)), int(ax.m_to_counts(5.0)), 0.5)
                assert exc.value.kind == FOREIGN_MASTER
                assert n[0] <= 41
            else:
                res = run_jog(m, read, int(ax.m_to_counts(20.0)), int(ax.m_to_counts(5.0)),
                              0.5)
                assert res.reason == "operator quit" and n[0] >= 120
        finally:
            state, problems = m.finish()
            m.close()
        assert state == "SWITCH_ON_DISABLED", (state, problems)
    finally:
        net.disconnect()
        bank.close()


def test_dry_run_against_cdpr_sim_second_client_on_the_hub_quick_stops():
    """`cdpr sim` in another process, lock-step; a second socketcand client on its hub
    writes 0x6040 = 0 to node 4: foreign_master naming COB-ID 0x604, a quick stop."""
    with start_world(SC, WINCHES, "process") as world:
        other = open_bus(world.info["can"])
        sent: list[tuple[float, int]] = []
        holder: list[ControlLoop] = []

        def tick():
            loop = holder[0]
            if not sent and loop.result.cycles == 150:
                other.send(can.Message(arbitration_id=SDO_OFF_4[0], data=SDO_OFF_4[1],
                                       is_extended_id=False))
                sent.append((world.hw.drives.now() - loop._t0, loop.result.cycles))

        try:
            loop = _loop_with(world, tick, 2.0)
            holder.append(loop)
            res = loop.run()
        finally:
            other.shutdown()
    assert sent
    ev = [e for e in res.events if e["kind"] == FOREIGN_MASTER and e["active"]]
    assert ev and ev[0]["reaction"] == "quick_stop" and ev[0]["address"] == 4, res.events
    assert "COB-ID 0x604" in ev[0]["text"]
    assert ev[0]["t"] - sent[0][0] <= 3 * WINCHES.bus.sync_period_s + 1e-6, (ev[0], sent)
    assert res.ended == "quick_stop"
