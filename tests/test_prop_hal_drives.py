"""Property-based test of the HAL's drive handling against the eight simulated drives.

A hypothesis ``RuleBasedStateMachine`` interleaves, at random, what a control loop does
(cycles with setpoints, enable, quick stop, fault reset, recover) with what goes wrong
(drive faults, heartbeat loss, a drive off the bus so that its SDO transfers time out,
node resets, the CAN link lost and back). The drives run in this process behind a
socketcand hub (firmware_sim.drive_rig.DriveRig), the HAL is connected through its
reconnecting socketcand link, both on the deterministic SYNC clock.

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
  blocking I/O of the master).

The number of examples follows the hypothesis profile (tests/conftest.py): a few in
``make test``, many in ``make test-deep``.
"""

from __future__ import annotations

import struct
import threading
import time

import can
import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import event as _event
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from controller.winch import load_winches
from firmware_sim.can_hub import CanHub
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.drive_rig import DriveRig
from hal.drives import BusLinkError, DriveConfigError, DriveStartupError, DriveState, WinchDrives

W = load_winches()
NODES = st.integers(1, 8)
HAL_ERRORS = (DriveStartupError, DriveConfigError, BusLinkError)
STEP_TIMEOUT = 0.05
_in_cycle = threading.local()


def event(text: str) -> None:
    """hypothesis.event inside a hypothesis run; nothing in the replayed regressions."""
    try:
        _event(text)
    except Exception:
        pass


class HalMachine(RuleBasedStateMachine):
    @initialize()
    def start(self):
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

        def spy(msg, timeout=None):
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
            return send(msg, timeout)

        bus.send = spy
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
            hal.step(timeout=STEP_TIMEOUT)
            self._note_faults()

    # ---- the control loop ---------------------------------------------------------------
    @rule(n=st.integers(1, 15), move=st.booleans())
    def run(self, n, move):
        self.cycles(n, move)

    @rule()
    def enable(self):
        self.blocked.clear()
        try:
            self.hal.enable_and_wait(max_cycles=20)
            event("enable: all enabled")
        except HAL_ERRORS as exc:
            event(f"enable refused: {type(exc).__name__}")
            assert "node" in str(exc) or "--can" in str(exc)
        self._note_faults()

    @rule()
    def quick_stop(self):
        self.hal.quick_stop()
        self.cycles(5, move=True)

    @rule()
    def fault_reset(self):
        self.hal.fault_reset()
        self.cycles(5, move=False)

    @rule()
    def recover(self):
        try:
            restarted = self.hal.recover(timeout=0.3)
            event(f"recovered {len(restarted)}")
        except HAL_ERRORS as exc:
            event(f"recover refused: {type(exc).__name__}")
            assert "node" in str(exc) or "--can" in str(exc)
        self._note_faults()

    @rule()
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
    @rule(node=NODES, kind=st.sampled_from(["over_current", "encoder"]))
    def drive_fault(self, node, kind):
        d = self.rig.bank.drive(node)
        code = 0x2310 if kind == "over_current" else 0x7305
        if d.state not in (d.state.FAULT, d.state.FAULT_REACTION_ACTIVE):
            self.injected[node] = code
        (d.inject_over_current if kind == "over_current" else d.inject_encoder_fault)()
        k = node - 1
        visible = not (self.link_down or node in self.silent or self.hal._rebooted[k]
                       or self.hal._relink[k] or self.hal._hb_lost[k]
                       or d.nmt_state != 0x05)
        for _ in range(30):
            self.cycles(1, move=False)
            if any(f.node_id == node and f.kind == "drive_fault" for f in self.hal.faults()):
                break
        if visible:
            event("fault injected and visible")
            want = self.injected[node]
            deadline = time.monotonic() + 5.0
            while (node, "drive_fault", want) not in {
                    (f.node_id, f.kind, f.code) for f in self.hal.faults()}:
                assert time.monotonic() < deadline, (node, want, self.hal.faults())
                self.cycles(1, move=False)  # the 0x603F read confirms in the background

    @rule(node=NODES)
    def repair(self, node):
        d = self.rig.bank.drive(node)
        d.repair_encoder()
        d.clear_over_current()

    @rule(node=NODES, stopped=st.booleans())
    def heartbeat(self, node, stopped):
        self.rig.bank.drive(node).stop_heartbeat(stopped)
        (self.hb_stopped.add if stopped else self.hb_stopped.discard)(node)

    @rule(node=NODES, silent=st.booleans())
    def off_the_bus(self, node, silent):
        """Silent: its SDO transfers (recover, fault code reads) time out."""
        self.rig.bank.drive(node).set_silent(silent)
        (self.silent.add if silent else self.silent.discard)(node)

    @rule(node=NODES)
    def node_reset(self, node):
        self.rig.bank.drive(node).reset_node()
        self.injected.pop(node, None)
        self.cycles(3, move=False)

    @rule()
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
        self.cycles(2, move=False)

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


HalMachine.TestCase.settings = settings(
    settings.default,
    max_examples=max(3, settings.default.max_examples // 8),
    stateful_step_count=min(settings.default.stateful_step_count, 25),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    deadline=None,
)
TestHalDrives = HalMachine.TestCase
assert can  # python-can is the bus behind both sides


def _run_steps(steps: list[tuple[str, dict]]) -> None:
    m = HalMachine()
    try:
        m.start()
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
