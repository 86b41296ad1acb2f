"""Property-based test of the HAL's drive handling against the eight simulated drives.

A hypothesis ``RuleBasedStateMachine`` interleaves, at random, what a control loop does
(cycles with setpoints, enable, quick stop, a quick stop at speed, fault reset, recover)
with what goes wrong (drive faults, a fault followed by warnings, a drive's heartbeat lost,
the master's own heartbeat stopping, RPDOs lost, a drive off the bus so that its SDO
transfers time out, node resets, the CAN link lost and back, a second master's SDO write
of 0x6040 = 0; and, in :class:`HalTpdoLossMachine`, a drive's TPDOs stopping). The drives
run in this process behind a socketcand hub (firmware_sim.drive_rig.DriveRig), the HAL is
connected through its reconnecting socketcand link, both on the deterministic SYNC clock.

Invariants:

- every call either works or raises the HAL's own errors naming the node or the bus
  (DriveStartupError, DriveConfigError, BusLinkError), never anything else;
- every fault is reported with the right device and code: an injected over-current or
  encoder fault shows as ``drive_fault`` of that node with that code (0x603F confirms it),
  and no drive fault is ever reported with another drive's or a later warning's code;
- no drive receives a new setpoint after a fault (or a lost heartbeat, a stop of its own,
  a reset) until the controller enables it again: no enable-operation controlword goes to
  it, and its target is where it stands;
- no call of the cycle (exchange / receive / transmit) makes an SDO transfer (the only
  blocking I/O of the master);
- after every cycle: a node reported lost (heartbeat lost, boot-up, link lost, drive lost)
  is reported UNKNOWN, never its last live state (a node whose heartbeat is lost is
  UNKNOWN in every cycle until it is back, whatever TPDOs it still sends);
- once the master's heartbeat stopped, every drive leaves Operation Enabled within its
  consumer heartbeat time (0x1016, ``master_heartbeat_timeout_s``), and the HAL says so
  within a cycle more; a drive missing its RPDOs beyond their deadline (0x1400 sub 5)
  leaves Operation Enabled too;
- a quick stop at speed stops every drive no further than v^2 / 2a of the configured
  quick-stop deceleration (winch file, 0x6085) plus two cycles and the lag;
- a drive switched off by a second master is reported in its true state at once, and the
  HAL never enables it again by itself (no enable-operation controlword until enable());
- (:class:`HalTpdoLossMachine`) a drive whose TPDOs stop is ``drive_lost`` with its state
  UNKNOWN within 0.1 s while it is OPERATIONAL; outside OPERATIONAL (e.g. pre-operational
  after its master's heartbeat was lost, 0x1029) it owes no TPDO (CiA 301) and its NMT
  state (``nmt_state``) is the HAL's report, with the state UNKNOWN.

The number of examples follows the hypothesis profile (tests/conftest.py,
tests/prop_support.py): enough in ``make test`` that every rule runs many times
(``test_every_rule_ran_many_times``), many more in ``make test-deep``.
"""

from __future__ import annotations

import struct
import threading
import time

import can
import numpy as np
import pytest
from hypothesis import Phase, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    rule,
    run_state_machine_as_test,
)
from prop_support import RuleCounter, event, machine_settings

from controller.winch import load_winches
from firmware_sim.can_hub import CanHub
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.drive_rig import DriveRig
from hal.bus_watch import TPDO_DEADLINE_CYCLES
from hal.drives import BusLinkError, DriveConfigError, DriveStartupError, DriveState, WinchDrives

W = load_winches()
NODES = st.integers(1, 8)
HAL_ERRORS = (DriveStartupError, DriveConfigError, BusLinkError)
STEP_TIMEOUT = 0.05
_in_cycle = threading.local()
T = W.bus.sync_period_s
LOST = ("heartbeat_lost", "boot_up", "link_lost", "drive_lost")  # state UNKNOWN meanwhile
HB_CYCLES = int(W.bus.heartbeat_period_s * W.bus.heartbeat_misses / T) + 3  # past timeout
LOST_WITHIN_S = 0.1  # a drive whose TPDOs stop is drive_lost within this [s]
#: what the HAL may report for a drive outside OPERATIONAL whose TPDOs stopped (it owes none)
NO_TPDO_OWED = frozenset((*LOST, "nmt_state"))
NMT_OPERATIONAL = 0x05  # CiA 301 heartbeat state
RULES = RuleCounter()
AT_LEAST = 8  # runs of each rule in CI's profile


def goes_wrong(**strategies):
    """Marks one of the things that happen: not a rule of its own, but taken in turn by
    :meth:`HalMachine.something_happens` with arguments drawn from ``strategies``."""
    def mark(fn):
        fn.goes_wrong = strategies
        return fn
    return mark


class HalMachine(RuleBasedStateMachine):
    @initialize(first_wrong=st.integers(0, 20))
    def start(self, first_wrong=0):
        self.first_wrong, self.n_wrong = first_wrong, 0
        self.rig = DriveRig(initial_lengths_m=10.0).start()
        self.port = self.rig.hub.address[1]
        self.hal = WinchDrives.open(self.rig.endpoint()["can"], W, EDS_PATH, clock="sync")
        for node in self.hal.nodes:
            node.sdo.RESPONSE_TIMEOUT = 2.0  # a loaded CI machine: generous, but finite
        self._instrument()
        self.injected: dict[int, int] = {}  # node -> code of the fault it is in (by us)
        self.blocked: set[int] = set()  # nodes that must not be enabled until enable()
        self.silent: set[int] = set()
        self.hb_stopped: set[int] = set()
        self.link_down = False
        self.mhb_stopped_at: float | None = None  # master clock when its heartbeat stopped
        self.mhb_checks = 0  # checks still due after it stopped (drives, then the HAL)
        self.tpdo_stopped: dict[int, float] = {}  # node -> master clock its TPDOs stopped
        self.nmt_left: dict[int, float] = {}  # node -> last master clock seen outside OP
        self.hal.start()
        self.hal.enable_and_wait()

    def teardown(self):
        if hasattr(self, "hal"):
            self.hal.close()
            self.rig.close()

    # ---- instrumentation ----------------------------------------------------------------
    def _instrument(self):
        hal = self.hal
        self.rpdos: list[tuple[int, int, int]] = []  # (node, controlword, target) sent
        bus = hal.network.bus
        send = bus.send
        batch = getattr(bus, "send_batch", None)  # the HAL's cycle sends its frames in one

        def check(msg):
            if 0x201 <= msg.arbitration_id <= 0x27F:
                cw, target = struct.unpack("<Hi", bytes(msg.data))
                nid = msg.arbitration_id - 0x200
                k = hal.node_ids.index(nid)
                self.rpdos.append((nid, cw, target))
                if (cw & 0x0F) == 0x0F and nid in self.blocked:
                    raise AssertionError(f"enable operation sent to node {nid} after a fault "
                                         "before the controller enabled it")
                if (cw & 0x8F) != 0x0F and hal.states()[k] != DriveState.OPERATION_ENABLED:
                    assert target == hal.positions_counts()[k], (nid, target)  # holds

        def spy(msg, timeout=None):
            check(msg)
            return send(msg, timeout)

        def spy_batch(msgs):
            for m in msgs:
                check(m)
            return batch(msgs)

        bus.send = spy
        if batch is not None:
            bus.send_batch = spy_batch
        for node in hal.nodes:
            for name in ("upload", "download"):
                fn = getattr(node.sdo, name)

                def guarded(*a, _fn=fn, **kw):
                    assert not getattr(_in_cycle, "on", False), "SDO inside the cycle"
                    return _fn(*a, **kw)

                setattr(node.sdo, name, guarded)
        for name in ("exchange", "receive", "transmit"):
            fn = getattr(hal, name)

            def in_cycle(_fn=fn):
                _in_cycle.on = True
                try:
                    return _fn()
                finally:
                    _in_cycle.on = False

            setattr(hal, name, in_cycle)

    def _note_faults(self):
        """Drives the HAL reports stopped for a reason: no enable until enable()."""
        for f in self.hal.faults():
            if f.kind in ("drive_fault", "quick_stop", "heartbeat_lost", "boot_up", "link_lost"):
                self.blocked.add(f.node_id)

    def cycles(self, n: int, move: bool = True) -> None:
        hal = self.hal
        for i in range(n):
            if move:
                cmd = hal.lengths_m() + 0.0005 * np.sin(np.arange(8) + 0.3 * i)
                hal.set_lengths(np.clip(cmd, W.min_length_m, W.max_length_m))
            # a silent drive's TPDO never comes: wait less for it
            hal.step(timeout=STEP_TIMEOUT / 5 if self.silent or self.tpdo_stopped
                     else STEP_TIMEOUT)
            self._note_faults()
            self.check_cycle()

    def check_cycle(self) -> None:
        """After every cycle: lost nodes are UNKNOWN, never reported live; the master's
        heartbeat loss and the RPDO deadline stop the drives in time."""
        hal = self.hal
        states = hal.states()
        faults = hal.faults()
        for f in faults:
            k = hal.node_ids.index(f.node_id) if f.node_id in hal.node_ids else None
            if k is None:
                continue
            if f.kind in LOST:
                assert states[k] == DriveState.UNKNOWN, (f, DriveState(states[k]).name)
        now = hal.now()
        if self.mhb_stopped_at is not None and not self.link_down and self.mhb_checks:
            # checked once, when the consumer time passes: a drive that lost its master
            # stops watching it (CiA 301) and may be enabled again by hand
            late = now - self.mhb_stopped_at - W.bus.master_heartbeat_timeout_s
            if late > 0 and self.mhb_checks == 2:
                self.mhb_checks = 1  # the drives' own reaction (0x6007): out of OE
                for node in hal.node_ids:
                    d = self.rig.bank.drive(node)
                    assert d.state != d.state.OPERATION_ENABLED or d.silent, (
                        f"node {node} still Operation Enabled {late:.3f} s after the "
                        "master's heartbeat stopped and its consumer time passed")
            if late > (TPDO_DEADLINE_CYCLES + 1) * T and self.mhb_checks == 1:
                # and the HAL reports it: the TPDO of a later cycle, or, if that TPDO is
                # late, drive_lost (UNKNOWN) once the TPDO deadline passed
                self.mhb_checks = 0
                for k, node in enumerate(hal.node_ids):
                    d = self.rig.bank.drive(node)
                    if not (d.silent or node in self.tpdo_stopped):
                        assert states[k] != DriveState.OPERATION_ENABLED, node
                event("master heartbeat lost: every drive stopped in time")
        if not self.link_down:
            self._check_tpdos_stopped(states, now)

    def _check_tpdos_stopped(self, states: np.ndarray, now: float) -> None:
        """A drive whose TPDOs stopped (master clock ``now`` [s]; link up).

        OPERATIONAL, it owes a TPDO per SYNC (CiA 301: PDOs flow only in OPERATIONAL):
        ``LOST_WITHIN_S`` after they stopped, or after its return to OPERATIONAL (the HAL's
        own NMT start), it is ``drive_lost`` (or, after the link came back without its
        TPDOs, still ``link_lost``). Outside OPERATIONAL (pre-operational after its master's
        heartbeat was lost, 0x1029; a reset) it owes none, and drive_lost would misname a
        node that still beats: the HAL may report its NMT state (``nmt_state``, ``boot_up``,
        from its heartbeat) or, until that heartbeat comes, drive_lost. Either way a fault
        and the state UNKNOWN, never its last live one.
        """
        hal = self.hal
        for node, t0 in self.tpdo_stopped.items():
            d = self.rig.bank.drive(node)
            with self.rig.bank.lock:
                operational = d.nmt_state == NMT_OPERATIONAL
            if not operational:
                self.nmt_left[node] = now  # owes no TPDO until the HAL starts it again
            since = max(t0, self.nmt_left.get(node, t0)) if operational else t0
            if now - since <= LOST_WITHIN_S + 1e-9:
                continue
            k = hal.node_ids.index(node)
            kinds = {f.kind for f in hal.faults() if f.node_id == node}
            said = {"drive_lost", "link_lost"} if operational else NO_TPDO_OWED
            assert kinds & said, (f"node {node}: TPDOs stopped {now - since:.3f} s ago "
                                  f"({'' if operational else 'not '}OPERATIONAL), faults "
                                  f"{sorted(kinds)}")
            assert states[k] == DriveState.UNKNOWN, (
                f"node {node}: TPDOs stopped {now - since:.3f} s ago, state "
                f"{DriveState(states[k]).name}")

    # ---- the control loop ---------------------------------------------------------------
    @goes_wrong(n=st.integers(1, 15), move=st.booleans())
    @RULES.counted
    def run(self, n, move):
        self.cycles(n, move)

    @goes_wrong()
    @RULES.counted
    def enable(self):
        self.blocked.clear()
        try:
            self.hal.enable_and_wait(max_cycles=20)
            event("enable: all enabled")
        except HAL_ERRORS as exc:
            event(f"enable refused: {type(exc).__name__}")
            assert "node" in str(exc) or "--can" in str(exc)
        self._note_faults()

    @goes_wrong()
    @RULES.counted
    def quick_stop(self):
        self.hal.quick_stop()
        self.cycles(5, move=True)

    @goes_wrong()
    @RULES.counted
    def fault_reset(self):
        self.hal.fault_reset()
        self.cycles(5, move=False)

    @goes_wrong()
    @RULES.counted
    def recover(self):
        try:
            restarted = self.hal.recover(timeout=0.3)
            event(f"recovered {len(restarted)}")
        except HAL_ERRORS as exc:
            event(f"recover refused: {type(exc).__name__}")
            assert "node" in str(exc) or "--can" in str(exc)
        self._note_faults()

    @goes_wrong()
    @RULES.counted
    def read_fault_codes(self):
        try:
            codes = self.hal.read_fault_codes()
        except HAL_ERRORS as exc:
            assert "node" in str(exc) or "--can" in str(exc)
            return
        for nid, code in codes.items():
            if nid in self.injected:
                assert code == self.injected[nid]

    # ---- what goes wrong ----------------------------------------------------------------
    @goes_wrong(node=NODES, kind=st.sampled_from(["over_current", "encoder"]))
    @RULES.counted
    def drive_fault(self, node, kind):
        self.fault_until_visible(node, kind)

    def fault_until_visible(self, node: int, kind: str) -> bool:
        """Inject a fault; wait until the HAL reports it with its code when it can see it.
        True if it did."""
        d = self.rig.bank.drive(node)
        code = 0x2310 if kind == "over_current" else 0x7305
        if d.state not in (d.state.FAULT, d.state.FAULT_REACTION_ACTIVE):
            self.injected[node] = code
        (d.inject_over_current if kind == "over_current" else d.inject_encoder_fault)()
        k = node - 1
        # a drive whose TPDOs stopped shows no state (drive_lost, UNKNOWN): its Fault is
        # not seen in its statusword
        visible = not (self.link_down or node in self.silent or self.hal._rebooted[k]
                       or self.hal._relink[k] or self.hal._hb_lost[k]
                       or node in self.tpdo_stopped or d.nmt_state != 0x05)
        for _ in range(30):
            self.cycles(1, move=False)
            if any(f.node_id == node and f.kind == "drive_fault" for f in self.hal.faults()):
                break
        if visible:
            event("fault injected and visible")
            with self.rig.bank.lock:  # ours, or the one it was in already (its cause)
                want = self.injected.setdefault(node, d.error_code)
            deadline = time.monotonic() + 5.0
            while (node, "drive_fault", want) not in {
                    (f.node_id, f.kind, f.code) for f in self.hal.faults()}:
                assert time.monotonic() < deadline, (node, want, self.hal.faults())
                self.cycles(1, move=False)  # the 0x603F read confirms in the background
        return visible

    @goes_wrong(node=NODES)
    @RULES.counted
    def repair(self, node):
        d = self.rig.bank.drive(node)
        d.repair_encoder()
        d.clear_over_current()

    @goes_wrong(node=NODES, stopped=st.booleans())
    @RULES.counted
    def heartbeat(self, node, stopped):
        """A drive's heartbeat producer stops (or starts again); cycles run past the HAL's
        heartbeat timeout."""
        self.rig.bank.drive(node).stop_heartbeat(stopped)
        (self.hb_stopped.add if stopped else self.hb_stopped.discard)(node)
        if stopped:
            self.cycles(HB_CYCLES, move=True)

    @goes_wrong(node=NODES, silent=st.booleans())
    @RULES.counted
    def off_the_bus(self, node, silent):
        """Silent: it sends nothing (TPDOs, heartbeat) and its SDO transfers (recover, fault
        code reads) time out; cycles run past the HAL's heartbeat timeout."""
        self.rig.bank.drive(node).set_silent(silent)
        (self.silent.add if silent else self.silent.discard)(node)
        if silent:
            self.cycles(HB_CYCLES, move=True)


    @goes_wrong(node=NODES)
    @RULES.counted
    def node_reset(self, node):
        self.rig.bank.drive(node).reset_node()
        self.injected.pop(node, None)
        self.cycles(3, move=False)

    @goes_wrong()
    @RULES.counted
    def link_lost_and_back(self):
        self.rig.hub.close()
        self.link_down = True
        deadline = time.monotonic() + 5.0
        while self.hal.link_up():
            assert time.monotonic() < deadline
            time.sleep(0.005)
        self.cycles(3, move=True)
        assert np.all(self.hal.states() == DriveState.UNKNOWN)
        assert {f.kind for f in self.hal.faults()} == {"link_lost"}
        try:
            self.hal.enable_and_wait(max_cycles=5)
            raise AssertionError("enable() on a dead link")
        except BusLinkError as exc:
            assert "--can socketcand" in str(exc)
        self.rig.hub = CanHub("127.0.0.1", self.port, bus=self.rig._hub_bus).start()
        while not self.hal.link_up():
            assert time.monotonic() < deadline + 5.0
            time.sleep(0.005)
        self.link_down = False
        # a drive whose TPDOs stopped before: its deadline counts from the link's return
        now = self.hal.now()
        self.tpdo_stopped = {node: now for node in self.tpdo_stopped}
        self.cycles(2, move=False)

    # ---- the events that matter ----------------------------------------------------------
    @goes_wrong(node=NODES, kind=st.sampled_from(["over_current", "encoder"]),
          warnings=st.lists(st.sampled_from([0x8250, 0x8130, 0x4210, 0x3220]), min_size=1,
                            max_size=4))
    @RULES.counted
    def fault_then_warnings(self, node, kind, warnings):
        """A drive faults, then sends warnings (EMCY): RPDO timeout, heartbeat, temperature,
        under-voltage. The fault's code stays the HAL's and the drive's 0x603F."""
        if not self.fault_until_visible(node, kind):
            return
        d = self.rig.bank.drive(node)
        with self.rig.bank.lock:
            for code in warnings:
                d._emcy(code)
        self.cycles(3, move=False)
        event("warnings after a visible fault")
        want = self.injected[node]
        got = {f.code for f in self.hal.faults() if f.node_id == node and f.kind == "drive_fault"}
        assert got == {want}, (node, hex(want), got)
        try:
            codes = self.hal.read_fault_codes()
        except HAL_ERRORS:
            return
        assert codes.get(node, want) == want, (node, hex(want), codes)

    @goes_wrong(n=st.integers(0, 20))
    @RULES.counted
    def master_heartbeat_stops(self, n):
        """The master's heartbeat stops (its thread and the cycle's): the drives stop on their
        own after their consumer time (0x6007); cycles run on past it."""
        hal = self.hal
        if hal._mhb_thread is None:
            return
        hal._mhb_stop.set()
        hal._mhb_thread.join(2.0)
        hal._mhb_thread = None
        self.mhb_stopped_at = hal.now()
        self.mhb_checks = 2
        self.cycles(int(W.bus.master_heartbeat_timeout_s / T) + 3 + n, move=True)

    @goes_wrong()
    @RULES.counted
    def master_heartbeat_back(self):
        if self.hal._mhb_thread is None:
            self.hal._start_master_heartbeat()
            self.mhb_stopped_at = None
        self.cycles(2, move=False)

    @goes_wrong(node=NODES, n=st.integers(1, 12))
    @RULES.counted
    def rpdos_lost(self, node, n):
        """The next ``n`` RPDOs to a drive are lost (its deadline is 5 cycles)."""
        d = self.rig.bank.drive(node)
        was_enabled = d.state == d.state.OPERATION_ENABLED
        d.drop_rpdos(n)
        self.cycles(n + 1, move=True)
        deadline = int(W.bus.rpdo_timeout_s / T)
        if was_enabled and n > deadline + 1 and not (self.link_down or d.silent):
            assert d.state != d.state.OPERATION_ENABLED, (node, n)
            event("RPDOs lost past the deadline: the drive stopped")
        d.stop_dropping()

    @goes_wrong(v=st.floats(0.2, 0.8), sign=st.sampled_from([-1.0, 1.0]))
    @RULES.counted
    def quick_stop_at_speed(self, v, sign):
        """All drives run at ``v`` [m/s], then the master quick-stops them: each stops within
        v^2 / 2a of the configured deceleration (winch file -> 0x6085, option 6)."""
        hal = self.hal
        self.enable()
        if not np.all(hal.states() == DriveState.OPERATION_ENABLED):
            self.all_back()
        if not np.all(hal.states() == DriveState.OPERATION_ENABLED):
            return
        cmd, speed = hal.lengths_m(), 0.0
        for _ in range(int(v / (3.0 * T)) + 8):  # up to speed at 3 m/s^2 (0x60C5: 4)
            speed = min(v, speed + 3.0 * T)
            cmd = cmd + sign * speed * T
            hal.set_lengths(np.clip(cmd, W.min_length_m, W.max_length_m))
            before = hal.lengths_m()
            self.cycles(1, move=False)
        if not np.all(hal.states() == DriveState.OPERATION_ENABLED):
            return
        at = hal.lengths_m()
        v_meas = np.abs(at - before) / T
        hal.quick_stop()
        self.cycles(int(v / (W.quick_stop_decel_m_s2.min() * T)) + 15, move=False)
        dist = np.abs(hal.lengths_m() - at)
        a = W.quick_stop_decel_m_s2
        bound = v_meas**2 / (2 * a) + v_meas * (3 * T + W.lag_time_constant_s) + 1e-3
        assert np.all(dist <= bound), (dist, bound, v_meas)
        event("quick stop at speed")

    def all_back(self) -> None:
        """Every drive repaired, on the bus, beating, reset, recovered and enabled."""
        if self.link_down:
            return
        for node in self.hal.node_ids:
            d = self.rig.bank.drive(node)
            d.repair_encoder()
            d.clear_over_current()
            d.stop_heartbeat(False)
            d.set_silent(False)
            d.stop_dropping()
        self.silent.clear()
        self.hb_stopped.clear()
        self.tpdo_stopped.clear()
        self.nmt_left.clear()
        self.injected.clear()
        self.master_heartbeat_back()
        self.recover()
        self.fault_reset()
        self.enable()

    @goes_wrong(node=NODES, value=st.sampled_from([0x00, 0x02]))
    @RULES.counted
    def second_master_write(self, node, value):
        """Another client on the bus writes 0x6040 (disable voltage, quick stop) by SDO: the
        HAL reports the drive's true state with the next cycle's TPDO."""
        bus = can.Bus(interface="virtual", channel=self.rig._hub_bus.channel_id)
        try:
            bus.send(can.Message(arbitration_id=0x600 + node, is_extended_id=False,
                                 data=bytes([0x2B, 0x40, 0x60, 0x00, value, 0, 0, 0])))
        finally:
            bus.shutdown()
        d = self.rig.bank.drive(node)
        deadline = time.monotonic() + 2.0
        while d.controlword != value and time.monotonic() < deadline and not (
                d.silent or self.link_down or d.nmt_state not in (0x05, 0x7F)):
            time.sleep(0.001)
        self.cycles(2, move=False)
        k = self.hal.node_ids.index(node)
        with self.rig.bank.lock:
            truth = d.state
        if (truth != d.state.OPERATION_ENABLED and not (d.silent or self.link_down)
                and node not in self.tpdo_stopped):
            assert self.hal.states()[k] != DriveState.OPERATION_ENABLED or self.hal.states()[
                k] == truth, (node, DriveState(self.hal.states()[k]).name, truth)
            event("second master's write seen")
            # switched off (or quick-stopped) by it: the HAL never enables it by itself
            self.blocked.add(node)
            self.cycles(4, move=True)
            if truth in (d.state.SWITCH_ON_DISABLED, d.state.READY_TO_SWITCH_ON):
                event("second master switched it off: it stays off")

    # ---- what goes wrong, in turn ---------------------------------------------------------
    #: what happens (the loop's calls, what goes wrong), taken in turn from one drawn at the
    #: start, skipping at random, so that each comes about as often
    KINDS = ("run", "drive_fault", "enable", "fault_then_warnings", "quick_stop", "heartbeat",
             "fault_reset", "off_the_bus", "recover", "node_reset", "repair",
             "link_lost_and_back", "read_fault_codes", "master_heartbeat_stops",
             "master_heartbeat_back", "rpdos_lost", "quick_stop_at_speed",
             "second_master_write")

    @rule(data=st.data())
    def something_happens(self, data):
        """The next two things that happen, one after the other (the next in turn, or the
        one after it)."""
        for _ in range(2):
            self.n_wrong += 1 + data.draw(st.integers(0, 1), label="skip")
            kind = self.KINDS[(self.first_wrong + self.n_wrong) % len(self.KINDS)]
            fn = getattr(self, kind)
            fn(**{name: data.draw(strategy, label=f"{kind}.{name}")
                  for name, strategy in fn.goes_wrong.items()})

    # ---- invariants ---------------------------------------------------------------------
    @invariant()
    def fault_codes_are_the_causes(self):
        if not hasattr(self, "hal"):
            return
        for f in self.hal.faults():
            if f.kind == "drive_fault" and f.code:
                assert f.code == self.injected.get(f.node_id, f.code), (f, self.injected)
                assert f.code not in (0x8250, 0x8130)  # never a warning's code
                # a fault nobody injected (e.g. a following error) carries the drive's own
                # cause: what 0x603F holds while the drive is still in that fault
                d = self.rig.bank.drive(f.node_id)
                with self.rig.bank.lock:
                    in_fault = d.state in (d.state.FAULT, d.state.FAULT_REACTION_ACTIVE)
                    cause = d.error_code
                if f.node_id not in self.injected and in_fault and cause:
                    assert f.code == cause, (f, hex(cause))

    @invariant()
    def no_drive_runs_on_unknown_state(self):
        if not hasattr(self, "hal"):
            return
        states = self.hal.states()
        for f in self.hal.faults():
            if f.kind in ("link_lost", "boot_up", "heartbeat_lost"):
                assert states[self.hal.node_ids.index(f.node_id)] != DriveState.OPERATION_ENABLED


HalMachine.TestCase.settings = machine_settings(examples=8, steps=30)
TestHalDrives = HalMachine.TestCase
assert can  # python-can is the bus behind both sides
HAL_RULES = list(HalMachine.KINDS)


def test_every_rule_ran_many_times():
    """Each rule ran at least ``AT_LEAST`` times in the machine's run above (run here when
    this test runs alone)."""
    if not any(RULES[r] for r in HAL_RULES):
        run_state_machine_as_test(HalMachine, settings=HalMachine.TestCase.settings)
    assert len(HAL_RULES) >= 18
    print(RULES.report())  # with -s: how often and how long each rule ran
    assert not RULES.missing(HAL_RULES, AT_LEAST), RULES.report()


class HalTpdoLossMachine(HalMachine):
    """The machine above plus a drive whose TPDOs stop (and come back): the HAL must call
    it ``drive_lost`` with its state UNKNOWN within 0.1 s (its last live state never), or,
    while it is outside OPERATIONAL, report its NMT state
    (:meth:`HalMachine._check_tpdos_stopped`)."""

    KINDS = HalMachine.KINDS + ("tpdos_stop",)

    @goes_wrong(node=NODES, n=st.integers(int(LOST_WITHIN_S / T) + 2,
                                          int(LOST_WITHIN_S / T) + 15))
    @RULES.counted
    def tpdos_stop(self, node, n):
        self.rig.bank.drive(node).drop_tpdos(10**9)
        self.tpdo_stopped.setdefault(node, self.hal.now())
        self.cycles(n, move=True)

    @rule(node=NODES)
    def tpdos_back(self, node):
        self.rig.bank.drive(node).stop_dropping()
        self.tpdo_stopped.pop(node, None)
        self.nmt_left.pop(node, None)
        self.cycles(3, move=False)


#: no shrinking: shrinking a run of the HAL takes minutes
HalTpdoLossMachine.TestCase.settings = settings(machine_settings(examples=4, steps=15),
                                                phases=[Phase.generate])


def test_tpdo_loss_is_drive_lost():
    run_state_machine_as_test(HalTpdoLossMachine,
                              settings=HalTpdoLossMachine.TestCase.settings)


def _run_steps(steps: list[tuple[str, dict]], machine: type[HalMachine] = HalMachine,
               first_wrong: int = 0) -> None:
    """The rules ``steps`` ((name, arguments), in order) of a new ``machine``, its invariants
    after each, as hypothesis would run them."""
    m = machine()
    try:
        m.start(first_wrong=first_wrong)
        for name, kw in steps:
            getattr(m, name)(**kw)
            m.fault_codes_are_the_causes()
            m.no_drive_runs_on_unknown_state()
    finally:
        m.teardown()


def test_regression_failed_enable_then_fault_reset_does_not_enable():
    """Found by the machine above: enable() while a drive is in Fault fails for it, and its
    pending enable request used to survive: the next fault reset enabled it by itself."""
    _run_steps([("drive_fault", {"kind": "over_current", "node": 1}), ("enable", {}),
                ("fault_reset", {})])


#: found by HalTpdoLossMachine: the master's heartbeat stops, its drives go pre-operational
#: (0x1029), then a drive's TPDOs "stop" (none flow outside OPERATIONAL anyway); it is
#: recovered with its master's heartbeat back and, its TPDOs still stopped, must be lost
PRE_OP_THEN_TPDOS_STOP = [("master_heartbeat_stops", {"n": 2}),
                          ("tpdos_stop", {"node": 6, "n": 28}),
                          ("master_heartbeat_back", {}), ("recover", {}),
                          ("run", {"n": 30, "move": True})]


def test_regression_tpdos_stop_of_a_preoperational_drive():
    """The HAL reports a pre-operational drive by its NMT state (``nmt_state``, UNKNOWN):
    it owes no TPDO (CiA 301), so not ``drive_lost``; once recovered to OPERATIONAL with
    its TPDOs still stopped it is drive_lost within ``LOST_WITHIN_S``."""
    _run_steps(PRE_OP_THEN_TPDOS_STOP, HalTpdoLossMachine)


def test_tpdo_property_finds_a_hal_that_never_loses_a_drive(monkeypatch):
    """A hand-made bug: the TPDO deadline never passes. The property must fail, for an
    OPERATIONAL drive and for one recovered from pre-operational."""
    monkeypatch.setattr("hal.drives_cycle.feedback_lost",
                        lambda missed, *a, **kw: np.zeros(np.shape(missed), bool))
    with pytest.raises(AssertionError, match=r"node 3: TPDOs stopped .*\(OPERATIONAL\)"):
        _run_steps([("tpdos_stop", {"node": 3, "n": 30})], HalTpdoLossMachine)
    with pytest.raises(AssertionError, match=r"node 6: TPDOs stopped .*\(OPERATIONAL\)"):
        _run_steps(PRE_OP_THEN_TPDOS_STOP, HalTpdoLossMachine)


def test_tpdo_property_finds_a_preoperational_drive_reported_fine(monkeypatch):
    """A hand-made bug: the HAL hears a drive leave OPERATIONAL (its drive_lost ends, its
    state is UNKNOWN) but reports no fault for it (no ``nmt_state``). The property must
    fail."""
    faults = WinchDrives.faults
    monkeypatch.setattr(WinchDrives, "faults",
                        lambda self: [f for f in faults(self) if f.kind != "nmt_state"])
    with pytest.raises(AssertionError, match=r"node 6: TPDOs stopped .*\(not OPERATIONAL\)"):
        _run_steps(PRE_OP_THEN_TPDOS_STOP[:2], HalTpdoLossMachine)
