"""Property-based test of the simulated CiA 402 drive against the standard's state machine.

A hypothesis ``RuleBasedStateMachine`` drives one :class:`SimulatedDrive` (through its object
dictionary, as SDO or RPDO writes would) with random controlwords, mode changes, setpoints,
quick-stop options, SYNCs, time, injected faults and repairs, and with the life of its
master: a heartbeat every 50 ms (watched by the drive, 0x1016) and an RPDO with the
controlword every cycle (0x1400 sub 5 deadline), either of which can stop, the master dying
and coming back (NMT start), and a second master's SDO write of 0x6040. Whole sequences
that matter are rules too, so that every run reaches them: a quick stop at speed, the
master's heartbeat or RPDOs lost at speed, a fault followed by warnings, a fault reset.
A model of the CiA 402 power state machine (IEC 61800-7-201 / CiA 402-2, transitions 2-16)
predicts each controlword's transition; after every step:

- the state is the one the transition table allows (the drive may only add what the table
  leaves to it: a ramp still running in Quick Stop Active / Fault Reaction Active);
- the statusword decodes to that state (the masks of the standard);
- the axis never moves unless the drive is Operation Enabled or stopping on a ramp;
- a fault always ends in Fault, with 0x603F set to its code and an EMCY with that code sent;
- a quick stop stops within the configured deceleration (no further than v^2 / 2a plus the
  position loop's lag) and, with options 5-8, then holds in Quick Stop Active;
- Operation Enabled is only ever entered by an enable-operation command: a fault reset
  never re-enables by itself;
- a drive leaves Operation Enabled within its consumer heartbeat time once the master's
  heartbeat stopped, and within the RPDO deadline once the RPDOs stopped (0x6007 1-3);
- the fault code (0x603F, also as an SDO upload reads it) is the one that caused the
  Fault transition: warnings after it (EMCY 0x8250, 0x8130) never overwrite it.

``test_every_rule_ran_many_times`` asserts that each rule ran many times in CI's profile.

``make test`` runs a fixed seed and bounded examples (tests/conftest.py profiles,
tests/prop_support.py); ``make test-deep`` many more. Failures found are kept as
``@example``-style regression steps in :func:`test_regressions`.
"""

from __future__ import annotations

import math
import struct
import uuid

import can
import canopen
import pytest
from hypothesis import strategies as st
from hypothesis import target
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    precondition,
    rule,
    run_state_machine_as_test,
)
from prop_support import RuleCounter, event, machine_settings

from controller.winch import load_winches
from firmware_sim.cia402_drive import NMT_OPERATIONAL, STATE_BITS, SimulatedDrive, State

W = load_winches()
AX = W.axis(0)
S = State
POWERED_OFF = (S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.FAULT,
               S.NOT_READY_TO_SWITCH_ON)

# controlword commands (bits 0-3, 7) and the extra operation-mode bits (4, 5, 6, 8)
SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP, FAULT_RESET = (
    0x06, 0x07, 0x0F, 0x00, 0x02, 0x80)
COMMANDS = st.sampled_from([SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP,
                            FAULT_RESET, 0x04, 0x01, 0x0B, 0x0D, 0x03])
EXTRA = st.sampled_from([0x0000, 0x0010, 0x0020, 0x0040, 0x0100, 0x0070])

MASTER = 127  # the master's node id (its heartbeat: COB-ID 0x77F)
CYCLE_US = 4000  # communication cycle period (0x1006) [us]
MASTER_HB_US = 50_000  # the master's heartbeat period [us]
QS_DECEL = 8_000_000  # quick-stop deceleration 0x6085 [counts/s^2]
RULES = RuleCounter()  # how often each rule ran (test_every_rule_ran_many_times)
AT_LEAST = 12  # runs of each rule in CI's profile


def next_state(s: S, prev_cw: int, cw: int, qs_option: int, cause: bool = False) -> set[S]:
    """States the standard allows after controlword ``cw`` in state ``s`` (before any time
    passes). Quick Stop Active with options 1-4 or Fault Reaction Active may still be
    ramping: the drive leaves them when the ramp ends. ``cause``: the cause of a Fault is
    still there (a reset then leaves the drive in Fault)."""
    if s == S.FAULT:
        if cw & 0x80 and not prev_cw & 0x80 and not cause:
            return {S.SWITCH_ON_DISABLED}  # 15
        return {S.FAULT}
    if s in (S.FAULT_REACTION_ACTIVE, S.NOT_READY_TO_SWITCH_ON):
        return {s}
    if cw & 0x80:
        return {s}  # bit 7 high: a fault reset request outside Fault is no command
    disable_voltage = cw & 0x02 == 0
    quick_stop = cw & 0x06 == 0x02
    shutdown = cw & 0x07 == 0x06
    switch_on = cw & 0x0F == 0x07
    enable = cw & 0x0F == 0x0F
    if s == S.SWITCH_ON_DISABLED:
        return {S.READY_TO_SWITCH_ON} if shutdown else {s}  # 2
    if s == S.READY_TO_SWITCH_ON:
        if disable_voltage or quick_stop:
            return {S.SWITCH_ON_DISABLED}  # 7
        if switch_on:
            return {S.SWITCHED_ON}  # 3
        if enable:
            return {S.OPERATION_ENABLED}  # 3 + 4 (the drive passes Switched On)
        return {s}
    if s == S.SWITCHED_ON:
        if disable_voltage or quick_stop:
            return {S.SWITCH_ON_DISABLED}  # 10
        if shutdown:
            return {S.READY_TO_SWITCH_ON}  # 6
        if enable:
            return {S.OPERATION_ENABLED}  # 4
        return {s}
    if s == S.OPERATION_ENABLED:
        if disable_voltage:
            return {S.SWITCH_ON_DISABLED}  # 9
        if quick_stop:
            return {S.SWITCH_ON_DISABLED} if qs_option == 0 else {S.QUICK_STOP_ACTIVE}  # 11
        if shutdown:
            return {S.READY_TO_SWITCH_ON}  # 8
        if switch_on:
            return {S.SWITCHED_ON}  # 5
        return {s}
    if s == S.QUICK_STOP_ACTIVE:
        if disable_voltage:
            return {S.SWITCH_ON_DISABLED}  # 12
        if enable and qs_option >= 5:
            return {S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE}  # 16 (once stopped)
        return {s}
    raise AssertionError(f"unknown state {s}")


class DriveMachine(RuleBasedStateMachine):
    """One simulated drive, its master (heartbeat, RPDOs, SDO) and a second master, against
    the CiA 402 model (see the module docstring)."""

    @initialize(qs=st.sampled_from([0, 1, 2, 5, 6]), fr=st.sampled_from([0, 1, 2]),
                abort=st.sampled_from([1, 2, 3]), consumer_ms=st.sampled_from([100, 250]),
                rpdo_ms=st.sampled_from([0, 20]), behaviour=st.sampled_from([0, 1]))
    def start(self, qs, fr, abort, consumer_ms, rpdo_ms, behaviour):
        bus = can.Bus(interface="virtual", channel=f"prop402-{uuid.uuid4().hex}")
        self.net = canopen.Network(bus)  # no notifier: frames go out, nothing comes back
        self.d = SimulatedDrive(AX)
        self.d.keep_sent = True
        self.d.attach(self.net)
        self.d.set_position_counts(1_000_000)
        self.d.power_on()
        self.write(0x1006, 0, CYCLE_US)
        self.write(0x605E, 0, fr)
        self.write(0x6085, 0, QS_DECEL)  # quick-stop deceleration [counts/s^2]
        self.write(0x6084, 0, 2_000_000)  # profile deceleration (options 1, 5)
        self.write(0x60C5, 0, 8_000_000)
        self.write(0x6065, 0, 200_000)  # following error window [counts]
        self.write(0x6066, 0, 50)
        self.write(0x1016, 1, (MASTER << 16) | consumer_ms)  # consumer heartbeat (master)
        self.write(0x6007, 0, abort)  # abort connection option
        self.write(0x1029, 1, behaviour)  # communication error: pre-operational / no change
        self.write(0x1400, 5, rpdo_ms)  # RPDO deadline [ms] (0: not watched)
        self.consumer_us, self.rpdo_us, self.abort = consumer_ms * 1000, rpdo_ms * 1000, abort
        self.d.param(0x6060)
        self.set_quick_stop_option(qs)
        self.cw = 0  # the master's controlword (its RPDOs repeat it every cycle)
        self.drive_cw = 0  # the last controlword the drive received, from anyone
        self.stop_from: tuple[float, float, float] | None = None  # (t0, pos0, |v0|) quick stop
        self.fault_code: int | None = None
        self.hb_on = self.rpdos_on = True
        self.next_hb_us = 0
        self.hb_deadline_us: int | None = None  # last master heartbeat + consumer time
        self.rpdo_deadline_us: int | None = None  # last RPDO + 0x1400 sub 5
        self.nmt_start()
        self.master_cycle()

    qs_ratio = 0.0  # the largest quick-stop distance at speed / its bound (hypothesis.target)

    def teardown(self):
        try:
            target(self.qs_ratio, label="quick stop distance at speed / bound")
        except Exception:  # called by hand, outside a hypothesis run
            pass
        if hasattr(self, "net"):
            self.d.detach()
            self.net.bus.shutdown()

    # ---- access -------------------------------------------------------------------------
    def write(self, index: int, sub: int, value: int) -> None:
        var = self.d.node._find_object(index, sub)
        self.d.node.set_data(index, sub, var.encode_raw(value), check_writable=True)

    def read_603f(self) -> int:
        """0x603F as an SDO upload reads it (the OD read callback)."""
        return struct.unpack("<H", self.d.node.get_data(0x603F, 0, check_readable=True))[0]

    def set_quick_stop_option(self, qs: int) -> None:
        self.write(0x605A, 0, qs)
        self.qs = qs

    def decel(self, index: int) -> float:
        return float(self.d.param(index))

    def qs_decel(self) -> float:
        return self.decel({1: 0x6084, 5: 0x6084, 2: 0x6085, 6: 0x6085}.get(self.qs, 0x60C5))

    def nmt_start(self) -> None:
        self.d._on_nmt(0x000, bytes([0x01, 0]), 0.0)

    def emcys(self, since: int) -> list[int]:
        return [struct.unpack_from("<H", data)[0] for _, cob, data in self.d.sent[since:]
                if cob == 0x80 + self.d.node_id]

    # ---- the master: heartbeat and RPDOs every cycle, on the drive's clock ---------------
    def master_cycle(self) -> None:
        d = self.d
        if self.rpdos_on and d.nmt_state == NMT_OPERATIONAL:
            d._on_rpdo(0x200 + d.node_id, struct.pack("<H", self.cw), 0.0)
            self.drive_cw = self.cw
            if self.rpdo_us:
                self.rpdo_deadline_us = d.now_us + self.rpdo_us
        if self.hb_on and d.now_us >= self.next_hb_us:
            d._on_consumer_heartbeat(0x700 + MASTER, bytes([NMT_OPERATIONAL]), 0.0)
            self.hb_deadline_us = d.now_us + self.consumer_us
            self.next_hb_us = d.now_us + MASTER_HB_US

    def pass_time(self, dt_s: float, sync: bool = False) -> None:
        """``dt_s`` [s] in cycles: the master's frames, then SYNC or time, then the checks."""
        d = self.d
        end = d.now_us + int(round(dt_s * 1e6))
        while d.now_us < end:
            before, t0, pos0, vel0 = d.state, d.now_us, d.axis.pos, abs(d.axis.vel)
            n_sent, n_lost = len(d.sent), len(d.connection_losses)
            self.master_cycle()
            if sync:
                d._on_sync(0x80, b"", 0.0)
            else:
                d.advance(min(CYCLE_US, end - d.now_us) * 1e-6)
            self.after_time(before, t0, pos0, vel0, n_sent, n_lost)

    # ---- rules --------------------------------------------------------------------------
    def command(self, cw: int, sdo_frame: bool = False) -> None:
        """A controlword written by SDO (``sdo_frame``: as an expedited download frame on the
        wire, from a second master), checked against the transition table."""
        d = self.d
        before, prev = d.state, self.drive_cw
        pos, vel = d.axis.pos, abs(d.axis.vel)
        allowed = next_state(before, prev, cw, self.qs, cause=d.encoder_broken)
        if sdo_frame:
            d._on_sdo(0x600 + d.node_id, bytes([0x2B, 0x40, 0x60, 0x00])
                      + struct.pack("<H", cw) + b"\x00\x00", 0.0)
        else:
            self.write(0x6040, 0, cw)
        self.drive_cw = cw
        self.track_motion()
        assert d.state in allowed, (S(before).name, hex(cw), S(d.state).name)
        if d.state == S.OPERATION_ENABLED and before != S.OPERATION_ENABLED:
            assert cw & 0x0F == 0x0F  # only an enable-operation command enables
        if before == S.OPERATION_ENABLED and d.state == S.QUICK_STOP_ACTIVE:
            self.stop_from = (d.now_us * 1e-6, pos, vel)
            event("quick stop at speed" if vel > 500_000 else "quick stop standing")
        if before != d.state:
            event(f"transition {S(before).name} -> {S(d.state).name}")
        if d.state != S.QUICK_STOP_ACTIVE:
            self.stop_from = None
        if before == S.FAULT and d.state != S.FAULT:
            self.fault_code = None
            assert d.state == S.SWITCH_ON_DISABLED  # 15, never further by itself
            event("fault reset")

    @rule(cmd=COMMANDS, extra=EXTRA)
    @RULES.counted
    def controlword(self, cmd, extra):
        """The master's controlword (by SDO; its RPDOs repeat it)."""
        self.cw = cmd | extra
        self.command(self.cw)

    @rule(extra=EXTRA)
    @RULES.counted
    def enable_sequence(self, extra):
        """Shutdown then enable operation (transitions 2, 3+4): what a master does."""
        self.controlword(SHUTDOWN, extra)
        self.controlword(ENABLE, extra)

    @rule(value=st.sampled_from([DISABLE_VOLTAGE, QUICK_STOP]))
    @RULES.counted
    def second_master_write(self, value):
        """Another client on the bus writes 0x6040 by SDO (CAN has no authentication)."""
        was = self.d.state
        self.command(value, sdo_frame=True)
        if was == S.OPERATION_ENABLED:
            event("second master stopped an enabled drive")

    @rule(v=st.integers(-2_000_000, 2_000_000), dt=st.sampled_from([0.05, 0.3]))
    @RULES.counted
    def run_at_speed(self, v, dt):
        """Cyclic synchronous velocity at ``v`` [counts/s] for ``dt`` [s]."""
        self.write(0x6060, 0, 9)
        self.write(0x60FF, 0, v)
        self.pass_time(dt)

    @rule(mode=st.sampled_from([1, 8, 9]))
    @RULES.counted
    def mode(self, mode):
        self.write(0x6060, 0, mode)

    @rule(delta=st.integers(-20_000, 20_000))
    @RULES.counted
    def position_target(self, delta):
        self.write(0x607A, 0, int(self.d.axis.pos) + delta)

    @rule(v=st.integers(-2_000_000, 2_000_000))
    @RULES.counted
    def velocity_target(self, v):
        self.write(0x60FF, 0, v)

    @rule(n=st.integers(1, 10))
    @RULES.counted
    def sync(self, n):
        self.pass_time(n * CYCLE_US * 1e-6, sync=True)

    @rule(dt=st.sampled_from([0.002, 0.01, 0.05, 0.2, 0.5]))
    @RULES.counted
    def advance(self, dt):
        self.pass_time(dt)

    @rule(qs=st.sampled_from([0, 1, 2, 5, 6]))
    @precondition(lambda self: self.d.state != S.QUICK_STOP_ACTIVE)
    @RULES.counted
    def quick_stop_option(self, qs):
        self.set_quick_stop_option(qs)

    @rule(kind=st.sampled_from(["over_current", "encoder"]))
    @RULES.counted
    def inject(self, kind):
        d = self.d
        was = d.state
        n_sent = len(d.sent)
        if kind == "over_current":
            d.inject_over_current()
            code = 0x2310
        else:
            d.inject_encoder_fault()
            code = 0x7305
        if was in (S.FAULT, S.FAULT_REACTION_ACTIVE):
            event("fault while faulted: the first cause stays")
            return
        event(f"fault in {S(was).name}")
        self.fault_code = code
        self.stop_from = None
        assert d.state in (S.FAULT_REACTION_ACTIVE, S.FAULT)
        assert self.emcys(n_sent) == [code]  # the EMCY of the fault, sent with the transition
        assert d.error_code == code  # 0x603F

    @rule()
    @RULES.counted
    def repair(self):
        self.d.repair_encoder()

    # ---- the master's life --------------------------------------------------------------
    @rule()
    @RULES.counted
    def heartbeat_stops(self):
        """The master's heartbeat stops (its RPDOs go on)."""
        self.hb_on = False

    @rule()
    @RULES.counted
    def rpdos_stop(self):
        """The master's RPDOs stop (its heartbeat goes on)."""
        self.rpdos_on = False

    @rule()
    @RULES.counted
    def master_dies(self):
        self.hb_on = self.rpdos_on = False

    @rule()
    @RULES.counted
    def master_back(self):
        """The master is back: heartbeat, NMT start, RPDOs."""
        self.hb_on = self.rpdos_on = True
        self.next_hb_us = self.d.now_us
        self.nmt_start()
        d = self.d
        before, pos0, vel0, n_sent, n_lost = (d.state, d.axis.pos, abs(d.axis.vel), len(d.sent),
                                              len(d.connection_losses))
        self.master_cycle()  # its RPDO may carry a reset edge (after another's write)
        self.after_time(before, d.now_us, pos0, vel0, n_sent, n_lost)

    # ---- the events that matter, whole ---------------------------------------------------
    def clear_fault(self) -> None:
        if self.d.state == S.FAULT_REACTION_ACTIVE:
            self.pass_time(0.5)
        if self.d.state == S.FAULT:
            self.repair()
            self.d.clear_over_current()
            self.controlword(DISABLE_VOLTAGE, 0)
            self.controlword(FAULT_RESET, 0)

    def enabled_at_speed(self, v: int, dt: float = 0.3) -> None:
        """From any state to Operation Enabled in velocity mode at ``v`` [counts/s]."""
        self.clear_fault()
        self.controlword(DISABLE_VOLTAGE, 0)
        self.enable_sequence(0)
        self.run_at_speed(v, dt)

    @rule(v=st.sampled_from([-1, 1]).flatmap(
        lambda s: st.integers(800_000, 2_000_000).map(lambda x: s * x)),
        qs=st.sampled_from([1, 2, 5, 6]))
    @RULES.counted
    def quick_stop_at_speed(self, v, qs):
        """Enable, run at speed, quick stop, let it stop: the ramp of 0x605A/0x6085."""
        self.enabled_at_speed(v)
        if self.d.state == S.OPERATION_ENABLED:
            self.controlword(DISABLE_VOLTAGE, 0)
            self.set_quick_stop_option(qs)
            self.enabled_at_speed(v)
        if self.d.state == S.OPERATION_ENABLED:
            self.controlword(QUICK_STOP, 0)
        self.pass_time(0.6)

    @rule(v=st.integers(-2_000_000, 2_000_000), rpdos=st.booleans())
    @RULES.counted
    def heartbeat_loss_at_speed(self, v, rpdos):
        """The master's heartbeat stops while the drive runs (``rpdos``: its RPDOs go on)."""
        self.master_back()
        self.enabled_at_speed(v, 0.05)
        if self.d.state == S.OPERATION_ENABLED:
            event("master heartbeat lost while Operation Enabled")
        self.hb_on, self.rpdos_on = False, rpdos
        self.pass_time(self.consumer_us * 1e-6 + 0.05)

    @rule(v=st.integers(-2_000_000, 2_000_000))
    @RULES.counted
    def rpdo_loss_at_speed(self, v):
        """The master's RPDOs stop while the drive runs (its heartbeat goes on)."""
        self.master_back()
        self.enabled_at_speed(v, 0.05)
        self.rpdos_on = False
        self.pass_time(0.1)

    @rule(kind=st.sampled_from(["over_current", "encoder"]), v=st.integers(-500_000, 500_000))
    @RULES.counted
    def fault_then_warnings(self, kind, v):
        """A fault, then the master goes: warnings (EMCY 0x8250, 0x8130) after the fault."""
        self.master_back()
        self.enabled_at_speed(v, 0.05)
        self.inject(kind)
        code, n_sent = self.d.error_code, len(self.d.sent)
        self.hb_on = self.rpdos_on = False
        self.pass_time(self.consumer_us * 1e-6 + 0.05)
        later = [c for c in self.emcys(n_sent) if c]
        if later and code:
            event("warnings after a fault")
            assert self.d.error_code == code == self.read_603f(), (
                hex(code), hex(self.d.error_code), [hex(c) for c in later])
        self.master_back()
        self.pass_time(0.05)

    @rule(kind=st.sampled_from(["over_current", "encoder"]))
    @RULES.counted
    def fault_reset(self, kind):
        """A fault, its cause repaired, a fault reset: Switch On Disabled, 0x603F cleared."""
        self.inject(kind)
        self.pass_time(0.3)
        if self.d.state == S.FAULT:
            self.repair()
            self.d.clear_over_current()
            self.controlword(DISABLE_VOLTAGE, 0)
            self.controlword(FAULT_RESET, 0)
            assert self.d.state == S.SWITCH_ON_DISABLED
            assert self.read_603f() == 0

    # ---- after time passed --------------------------------------------------------------
    def after_time(self, before: S, t0_us: int, pos0: float, vel0: float, n_sent: int,
                   n_lost: int) -> None:
        d = self.d
        self.track_motion()
        lost = len(d.connection_losses) > n_lost
        if lost:
            event("master lost: " + d.connection_losses[-1][1].split(" (")[0][:30])
        # a fault with time: the master lost (0x6007 = 1) or a following error
        if d.state in (S.FAULT, S.FAULT_REACTION_ACTIVE) and self.fault_code is None:
            assert before not in (S.FAULT, S.FAULT_REACTION_ACTIVE)
            assert d.error_code in (0x8130, 0x8250, 0x8611), hex(d.error_code)
            assert d.error_code in self.emcys(n_sent)  # its EMCY, sent with the transition
            self.fault_code = d.error_code
            self.stop_from = None
            event(f"fault 0x{d.error_code:04X} with time")
        if before == S.FAULT and d.state == S.SWITCH_ON_DISABLED:
            # the master's RPDO carried a rising edge of bit 7 (after another's write of 0)
            assert self.cw & 0x80 and self.rpdos_on
            self.fault_code = None
        # time never enables a drive, except the master's RPDO repeating enable operation in
        # Quick Stop Active once stopped (transition 16, options 5-8)
        if d.state == S.OPERATION_ENABLED and before != S.OPERATION_ENABLED:
            assert (before == S.QUICK_STOP_ACTIVE and self.qs >= 5 and self.rpdos_on
                    and self.cw & 0x0F == 0x0F), S(before).name
            self.stop_from = None
        if before == S.OPERATION_ENABLED and d.state == S.QUICK_STOP_ACTIVE:
            # the drive's own quick stop (master lost, 0x6007 = 3): from where it was when
            # the cycle began, at most one cycle's acceleration faster
            assert lost
            self.stop_from = (t0_us * 1e-6, pos0,
                              vel0 + self.decel(0x60C5) * CYCLE_US * 1e-6)
            event("quick stop at speed by master loss" if vel0 > 500_000
                  else "quick stop standing by master loss")
        if self.stop_from is not None and d.state != S.QUICK_STOP_ACTIVE:
            # options 1, 2: then Switch On Disabled; 5, 6 hold there unless the master is lost
            assert d.state == S.SWITCH_ON_DISABLED and (self.qs < 5 or lost), (
                S(d.state).name, self.qs)
            self.stop_from = None
        if self.stop_from is not None:
            self.check_quick_stop()
        self.check_master_loss()

    def check_quick_stop(self) -> None:
        """A quick stop decelerates at least at its configured ramp: stopped by v0/a (plus
        a cycle), and no further than v0^2 / 2a plus the position loop's lag."""
        d = self.d
        t0, p0, v0 = self.stop_from
        a = self.qs_decel()
        t_stop = v0 / a if a > 0 else 0.0
        if d.now_us * 1e-6 > t0 + t_stop + 0.05:
            assert d._ramp is None, ("still ramping", t_stop)  # stopped
            if self.qs >= 5:
                assert abs(d.axis.vel) < 1.0
        lag = v0 * AX.lag_time_constant_s + 2 * 0.002 * v0  # loop lag, 2 ms steps
        dist = abs(d.axis.pos - p0)
        assert dist <= v0**2 / (2 * a) + lag + 2.0, (dist, v0**2 / (2 * a), v0, a)
        if v0 > 500_000:
            self.qs_ratio = max(self.qs_ratio, dist / (v0**2 / (2 * a) + lag + 2.0))

    def check_master_loss(self) -> None:
        """A drive leaves Operation Enabled within its consumer heartbeat time (0x1016) once
        the master's heartbeat stopped, and within the RPDO deadline (0x1400 sub 5) once its
        RPDOs stopped (0x6007 1-3; checked once, when the deadline passes)."""
        d = self.d
        if not self.hb_on and self.hb_deadline_us is not None and d.now_us > self.hb_deadline_us:
            self.hb_deadline_us = None
            assert d.state != S.OPERATION_ENABLED, (
                f"still Operation Enabled after the consumer heartbeat time "
                f"{self.consumer_us} us")
            event("consumer heartbeat time passed")
        if (not self.rpdos_on and self.rpdo_deadline_us is not None
                and d.now_us > self.rpdo_deadline_us):
            self.rpdo_deadline_us = None
            if d.nmt_state == NMT_OPERATIONAL:
                assert d.state != S.OPERATION_ENABLED, (
                    f"still Operation Enabled after the RPDO deadline {self.rpdo_us} us")
                event("RPDO deadline passed")

    # ---- invariants ---------------------------------------------------------------------
    @invariant()
    def statusword_matches_the_state(self):
        sw = self.d.statusword()
        want = STATE_BITS[self.d.state]
        mask = 0x4F if self.d.state in (S.SWITCH_ON_DISABLED, S.FAULT, S.FAULT_REACTION_ACTIVE,
                                         S.NOT_READY_TO_SWITCH_ON) else 0x6F
        assert sw & mask == want & mask, (hex(sw), S(self.d.state).name)

    @invariant()
    def a_fault_ends_in_fault_with_its_code(self):
        """The code of the fault that caused the transition stays in 0x603F (later EMCYs,
        warnings, do not overwrite it) until a fault reset."""
        d = self.d
        if self.fault_code is None:
            return
        assert d.state in (S.FAULT, S.FAULT_REACTION_ACTIVE)
        assert d.error_code == self.fault_code, (hex(d.error_code), hex(self.fault_code))
        assert self.read_603f() == self.fault_code
        if d._ramp is None:
            assert d.state == S.FAULT

    @invariant()
    def never_moves_unless_enabled_or_stopping(self):
        self.track_motion()

    def track_motion(self) -> None:
        """The axis never moves unless the drive is enabled or stopping (checked after every
        command and every cycle of time)."""
        d = self.d
        if not hasattr(self, "last_pos"):
            self.last_pos = d.axis.pos
        if d.state in POWERED_OFF or d.encoder_broken:
            assert d.axis.vel == 0.0
        if d.state in POWERED_OFF and self.last_state in POWERED_OFF:
            assert d.axis.pos == self.last_pos, (S(d.state).name, d.axis.pos, self.last_pos)
        self.last_pos = d.axis.pos
        self.last_state = d.state

    last_state = S.SWITCH_ON_DISABLED


DriveMachine.TestCase.settings = machine_settings(examples=160, steps=30)
TestDriveStateMachine = DriveMachine.TestCase

#: every rule of the machine
DRIVE_RULES = [name for name in dir(DriveMachine)
               if getattr(getattr(DriveMachine, name), "hypothesis_stateful_rule", None)]


def test_every_rule_ran_many_times():
    """The machine's statistics: each rule (the events that matter among them) ran at least
    ``AT_LEAST`` times in the run above (run here when this test runs alone)."""
    if not RULES:
        run_state_machine_as_test(DriveMachine, settings=DriveMachine.TestCase.settings)
    assert len(DRIVE_RULES) >= 20
    print(RULES.report())  # with -s: how often and how long each rule ran
    assert not RULES.missing(DRIVE_RULES, AT_LEAST), RULES.report()


def test_transition_table_is_the_standards():
    """The model itself, on the transitions the standard names (a test that can fail)."""
    qs6 = 6
    assert next_state(S.SWITCH_ON_DISABLED, 0, SHUTDOWN, qs6) == {S.READY_TO_SWITCH_ON}
    assert next_state(S.OPERATION_ENABLED, 0, QUICK_STOP, qs6) == {S.QUICK_STOP_ACTIVE}
    assert next_state(S.OPERATION_ENABLED, 0, QUICK_STOP, 0) == {S.SWITCH_ON_DISABLED}
    assert next_state(S.FAULT, 0, FAULT_RESET, qs6) == {S.SWITCH_ON_DISABLED}
    assert next_state(S.FAULT, FAULT_RESET, FAULT_RESET, qs6) == {S.FAULT}  # no edge
    assert next_state(S.QUICK_STOP_ACTIVE, 0, ENABLE, 2) == {S.QUICK_STOP_ACTIVE}
    assert S.OPERATION_ENABLED in next_state(S.QUICK_STOP_ACTIVE, 0, ENABLE, 5)
    for s in S:
        for cw in (SHUTDOWN, SWITCH_ON, DISABLE_VOLTAGE, QUICK_STOP):
            assert S.OPERATION_ENABLED not in next_state(s, 0, cw, qs6)
    assert math.isclose(STATE_BITS[S.QUICK_STOP_ACTIVE] & 0x6F, 0x07)


@pytest.mark.parametrize("steps", [
    # kept regressions: sequences hypothesis found (none so far; add as they come)
    [],
])
def test_regressions(steps):
    m = DriveMachine()
    try:
        m.start(qs=6, fr=2, abort=3, consumer_ms=100, rpdo_ms=20, behaviour=1)
        for name, kw in steps:
            getattr(m, name)(**kw)
            m.statusword_matches_the_state()
            m.a_fault_ends_in_fault_with_its_code()
            m.never_moves_unless_enabled_or_stopping()
    finally:
        m.teardown()
