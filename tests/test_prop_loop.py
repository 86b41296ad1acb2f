"""Property-based test of the dry run's control loop (bench/dryrun/loop.py) reacting to the
supervisor, on the pure-Python fake hardware (hal/fake.py).

The loop runs in a thread of its own and is stepped one control cycle at a time: its
lock-step ``tick`` (called once per cycle, after the setpoints went out) waits for the
machine. A hypothesis ``RuleBasedStateMachine`` interleaves cycles with what goes wrong on
the fake: a cable going slack for a while and back (a hold, then its release), load cells
failing (substituted; more than two for long: ``loadcells_blind``, a hold), an overload, a
drive fault, a drive's heartbeat stopping (``drive_lost`` after the heartbeat timeout), a
node reset, the CAN link lost, a second master switching a drive off (0x6040 = 0), a stop
request (SIGINT); after a run ended, a new one. The loop's supervisor is the real one,
recorded (observation, decision) cycle by cycle.

After every cycle:

- the trajectory time advances exactly as the feed rate (controller/feedrate.py) says for
  the supervisor's decisions of the cycles before: full speed, a ramp down from the cycle
  after a hold is decided, back up after its release, nothing after a stop;
- no setpoint advances while the supervisor holds: once a hold lasted longer than the
  feed's ramp, the trajectory time and the setpoints sent stay where they are;
- a stop decided (or requested) in a cycle quick-stops the drives in that very cycle, and
  no setpoint is sent after it; a device's own fault report (drive fault, lost drive)
  stops in the cycle it is first read; a drive switched off by someone else stops within
  the debounce;
- the run ends without an exception, as ``quick_stop``/``interrupted`` after a stop.

``test_every_rule_ran_many_times`` asserts that each rule ran many times in CI's profile.
"""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
from hypothesis import strategies as st
from hypothesis import target
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    rule,
    run_state_machine_as_test,
)
from prop_support import RuleCounter, event, machine_settings

import bench.dryrun.loop as loop_module
from bench.dryrun.loop import ControlLoop, LoopOptions
from controller.cycle import LengthController
from controller.feedrate import FeedRate, ramp_time
from controller.supervisor import Supervisor
from controller.trajectory import MotionLimits, Move, Trajectory
from controller.winch import load_winches
from hal.drives_cia402 import DriveState
from hal.fake import FakeHardware
from hal.tracker import CallableTracker
from tests.robots import rocaspect

S = DriveState
P0 = np.array([10.0, 8.56, 1.2, 0, 0, 0])
TARGET = np.array([11.0, 9.06, 1.4, 0, 0, 0])
W = dataclasses.replace(load_winches(), quick_stop_option=np.full(8, 6))
MODEL = rocaspect()
TAU0 = LengthController(MODEL, P0, None).init_tensions  # tensions at P0 [N]
REFERENCE = LengthController(MODEL, P0, None).reference  # lengths at P0 [m]
#: a path, and limits under which the feed ramps in 0.15 s (37.5 cycles)
TRAJ = Trajectory([Move(TARGET.tolist()), Move(P0.tolist()), Move(TARGET.tolist())], P0,
                  MotionLimits(max_speed_m_s=0.5, max_accel_m_s2=5.0, max_jerk_m_s3=50.0))
T = W.bus.sync_period_s
INIT_CYCLES = 10
DEBOUNCE = 2
LOST_KINDS = ("drive_fault", "heartbeat_lost", "boot_up", "link_lost", "nmt_state")
STOPS = ("overload", "drive_fault", "heartbeat_stops", "node_reset", "link_lost",
         "second_master_write", "stop_request")
RULES = RuleCounter()
AT_LEAST = 8  # runs of each rule in CI's profile
STEP_TIMEOUT_S = 20.0  # a cycle of the loop thread takes well under a millisecond


class SpyHardware(FakeHardware):
    """The fake hardware, recording the setpoints written (None: none) and quick stops."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.written: list[np.ndarray | None] = []
        self.quick_stops: list[int] = []  # number of writes before each quick stop

    def write_lengths(self, lengths_m):
        self.written.append(None if lengths_m is None else np.array(lengths_m, float))
        super().write_lengths(lengths_m)

    def quick_stop(self, nodes=None):
        self.quick_stops.append(len(self.written))
        super().quick_stop(nodes)


class RecordingSupervisor(Supervisor):
    """The real supervisor; each (observation, decision) goes to ``sink``."""

    sink: list | None = None  #: where the next supervisor made records

    def __post_init__(self) -> None:
        super().__post_init__()
        self.records = RecordingSupervisor.sink

    def step(self, obs):
        d = super().step(obs)
        if self.records is not None:
            self.records.append((obs, d))
        return d


class LoopMachine(RuleBasedStateMachine):
    """The control loop on the fake, stepped cycle by cycle (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        self.thread: threading.Thread | None = None
        self.runs = 0
        self.n_stops = 0

    @initialize(first_stop=st.integers(0, len(STOPS) - 1))
    def start(self, first_stop=0):
        self.first_stop = first_stop
        self.new_run_()

    # ---- the loop in its thread ---------------------------------------------------------
    def new_run_(self) -> None:
        self.hw = SpyHardware(W, initial_lengths_m=REFERENCE, tensions_N=TAU0)
        self.tracker = CallableTracker(lambda: (self.hw.t, P0.copy(), True))
        opt = LoopOptions(init_pose=P0, init_dwell_s=INIT_CYCLES * T, end_dwell_s=0.2,
                          hold_timeout_s=0.4,
                          supervisor={"debounce": DEBOUNCE, "blind_s": 0.25 + T / 2})
        self.sink: list = []
        self.go = threading.Semaphore(0)
        self.paused = threading.Semaphore(0)
        self.finished = False
        self.abort = False
        self.error: BaseException | None = None
        self.loop = ControlLoop(self.hw, self.tracker, MODEL, lambda p0: TRAJ, opt,
                                tick=self._tick)
        # the model of the loop's reaction
        self.feed = FeedRate(ramp_time(TRAJ.limits.speed_m_s, TRAJ.limits.max_accel_m_s2))
        self.m_t = 0.0
        self.m_hold = False
        self.m_stop_at: int | None = None  # cycle of the quick stop
        self.stop_requested_at: int | None = None
        self.held_for = 0  # consecutive cycles whose decision was a hold (no stop)
        self.checked = 0  # cycles checked
        self.off_since: dict[int, int] = {}  # drive index -> first cycle seen off, no fault
        self.runs += 1
        original = loop_module.Supervisor
        RecordingSupervisor.sink = self.sink
        loop_module.Supervisor = RecordingSupervisor
        try:
            self.thread = threading.Thread(target=self._body, name="loop-under-test",
                                           daemon=True)
            self.thread.start()
            assert self.paused.acquire(timeout=STEP_TIMEOUT_S), "the loop never ticked"
            self.base = len(self.hw.written) - 1  # writes before the first cycle's
        finally:
            loop_module.Supervisor = original
            RecordingSupervisor.sink = None
        assert self.error is None, repr(self.error)

    def _tick(self) -> None:
        self.paused.release()
        self.go.acquire()
        if self.abort:
            raise KeyboardInterrupt  # teardown: the loop stops the drives and ends

    def _body(self) -> None:
        try:
            self.result = self.loop.run()
        except BaseException as exc:  # reported by the machine
            self.error = exc
        finally:
            self.finished = True
            self.paused.release()

    def teardown(self):
        try:
            target(float(self.runs), label="runs in one example")
        except Exception:
            pass
        if self.thread is not None and not self.finished:
            self.abort = True
            self.go.release()
            self.thread.join(STEP_TIMEOUT_S)

    def cycles(self, n: int) -> None:
        """Let the loop run ``n`` cycles (fewer if it ends); check each one."""
        for _ in range(n):
            if self.finished:
                return
            self.go.release()
            assert self.paused.acquire(timeout=STEP_TIMEOUT_S), "the loop hangs"
            assert self.error is None, repr(self.error)
            self.check_cycles()
        if self.finished:
            self.check_end()

    # ---- checks -------------------------------------------------------------------------
    def check_cycles(self) -> None:
        while self.checked < len(self.sink):
            self.checked += 1
            self.check_cycle(self.checked)

    def check_cycle(self, c: int) -> None:
        """Cycle ``c`` (1-based) was decided; the trajectory time is the loop's after it."""
        obs, d = self.sink[c - 1]
        hw = self.hw
        # the feed: the trajectory advances by the rate of the decisions before
        t_before = self.m_t
        if c > INIT_CYCLES and self.m_stop_at is None:
            self.m_t += self.feed.advance(T, self.m_hold)
        if self.checked == len(self.sink) and not self.finished:
            assert math.isclose(self.loop.result.trajectory_s, self.m_t, rel_tol=0,
                                abs_tol=1e-12), (c, self.loop.result.trajectory_s, self.m_t,
                                                 self.m_hold, d.reaction)
        # reactions: a stop in this very cycle, nothing sent after it
        stopping = self.m_stop_at is not None
        asked = self.stop_requested_at is not None and c >= self.stop_requested_at
        if not stopping and (d.stop or asked):
            self.m_stop_at = c
            assert self.base + c in hw.quick_stops, (c, self.base, hw.quick_stops, d.reaction)
            event("quick stop" if d.stop else "stop requested")
        if stopping:
            assert all(w is None for w in hw.written[self.base + self.m_stop_at:]), (
                "a setpoint sent after the stop")
        own = [f for f in obs.faults if f.device == "drive" and f.kind in LOST_KINDS]
        if own and not stopping:
            assert self.m_stop_at == c, ("a drive's own fault did not stop the loop at once",
                                         own)
            event(f"stop on {own[0].kind}")
        for k in range(len(obs.enabled)):
            faulted = any(f.device == "drive" and f.address == hw.node_ids[k]
                          for f in obs.faults)
            if obs.expect_enabled and not obs.enabled[k] and not faulted:
                self.off_since.setdefault(k, c)
                if c - self.off_since[k] >= DEBOUNCE - 1:
                    assert self.m_stop_at is not None and self.m_stop_at <= c, (
                        "a drive switched off by another master did not stop the loop", k)
            else:
                self.off_since.pop(k, None)
        # holds: the feed ramps down, then nothing advances
        was_held = self.m_hold
        if self.m_stop_at is None:
            self.m_hold = bool(d.hold)
        self.held_for = self.held_for + 1 if (self.m_hold and was_held) else int(self.m_hold)
        if self.held_for > self.feed.ramp_s / T + 2 and c > INIT_CYCLES + 1:
            assert self.m_t == t_before, ("the trajectory advances during a hold", c)
            sent = hw.written[self.base + c - 1:self.base + c + 1]  # in cycles c and c + 1
            if len(sent) == 2 and sent[0] is not None and sent[1] is not None:
                old, new = sent
                assert np.max(np.abs(new - old)) < 1e-9, (
                    "a setpoint advanced during a hold", c, np.max(np.abs(new - old)))
                event("held and standing still")
        if was_held and not self.m_hold and self.m_stop_at is None:
            event("hold released")

    def check_end(self) -> None:
        assert self.error is None, repr(self.error)
        self.check_cycles()
        res = self.result
        event(f"run ended: {res.ended}")
        if self.m_stop_at is not None:
            assert res.ended in ("quick_stop", "interrupted"), (res.ended, res.message)
            assert not np.any(self.hw.read().states == S.OPERATION_ENABLED)
        else:
            assert res.ended in ("completed", "hold_timeout"), (res.ended, res.message)

    # ---- rules --------------------------------------------------------------------------
    def running(self) -> None:
        """After a run ended, the next rule starts a new one."""
        if self.finished:
            RULES["new_run"] += 1
            event("new run")
            self.new_run_()

    @rule(n=st.integers(1, 30))
    @RULES.counted
    def run(self, n):
        self.running()
        self.cycles(n)

    @rule(cable=st.integers(0, 7), hold=st.integers(10, 100), after=st.integers(1, 40))
    @RULES.counted
    def slack_then_back(self, cable, hold, after):
        """A cable goes slack for ``hold`` cycles (a hold once it lasted), then back: the
        hold's release."""
        self.running()
        self.hw._const[cable] = 0.5
        self.cycles(hold)
        self.hw._const[cable] = TAU0[cable]
        self.cycles(after)

    @rule(count=st.integers(1, 4), n=st.integers(5, 90))
    @RULES.counted
    def loadcells_fail(self, count, n):
        """``count`` load cells time out for ``n`` cycles (substituted; three or more for
        long: blind, a hold), then answer again."""
        self.running()
        for k in range(count):
            self.hw.inject_loadcell_fault(self.hw.cables[k], "timeout")
        self.cycles(n)
        self.hw.clear_loadcell_fault()
        self.cycles(3)

    @rule(k=st.integers(0, 7), code=st.sampled_from([0x2310, 0x7305, 0x8611]),
          n=st.integers(1, 10))
    @RULES.counted
    def stopping_event(self, k, code, n):
        """What stops a run: an overload, a drive fault, a drive's heartbeat stopping (lost
        after the heartbeat timeout, 0.3 s), a node reset, the CAN link lost, a second
        master switching a drive off (0x6040 = 0), a stop request (SIGINT). The kinds take
        turns from the one drawn at the start, so that each comes as often."""
        self.running()
        kind = STOPS[(self.first_stop + self.n_stops) % len(STOPS)]
        self.n_stops += 1
        RULES[f"stop:{kind}"] += 1
        event(f"stopping event {kind}")
        hw, node = self.hw, self.hw.node_ids[k]
        if kind == "overload":
            hw._const[k] = 5000.0
            n += 30  # confirmed once it lasted persist_s (0.1 s)
        elif kind == "drive_fault":
            hw.inject_drive_fault(node, code)
        elif kind == "heartbeat_stops":
            hw.stop_heartbeat(node)
            n += 80
        elif kind == "node_reset":
            hw.reset_node(node)
        elif kind == "link_lost":
            hw.lose_link()
        elif kind == "second_master_write":
            if hw.states[k] == S.OPERATION_ENABLED:
                hw.states[k] = S.SWITCH_ON_DISABLED
                event("second master switched an enabled drive off")
        elif kind == "stop_request":
            self.stop_requested_at = len(self.sink) + 1  # seen by the cycle now running
            self.loop.stop.set()
        self.cycles(n)

    @invariant()
    def no_error(self):
        if hasattr(self, "loop"):
            assert self.error is None, repr(self.error)


LoopMachine.TestCase.settings = machine_settings(examples=24, steps=20)
TestLoopMachine = LoopMachine.TestCase
LOOP_RULES = [name for name in dir(LoopMachine)
              if getattr(getattr(LoopMachine, name), "hypothesis_stateful_rule", None)]
LOOP_RULES += ["new_run"] + [f"stop:{kind}" for kind in STOPS]


def test_every_rule_ran_many_times():
    """Each rule ran at least ``AT_LEAST`` times in the machine's run above (run here when
    this test runs alone)."""
    if not RULES:
        run_state_machine_as_test(LoopMachine, settings=LoopMachine.TestCase.settings)
    assert len(LOOP_RULES) >= 12
    print(RULES.report())  # with -s: how often and how long each rule ran
    assert not RULES.missing(LOOP_RULES, AT_LEAST), RULES.report()


def test_hold_by_hand_stands_still(hold=150):
    """One hold, by hand: a slack cable for ``hold`` cycles holds the platform where it is
    (the machine's checks run on every cycle), then the run goes on."""
    m = LoopMachine()
    try:
        m.start()
        m.cycles(60)
        m.slack_then_back(cable=2, hold=hold, after=40)
        assert m.held_for == 0 and m.m_stop_at is None
        assert any(d.hold for _, d in m.sink)
    finally:
        m.teardown()
