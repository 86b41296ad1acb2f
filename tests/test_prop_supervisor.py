"""Property-based test of the supervisor's decisions (controller/supervisor.py), pure.

A hypothesis ``RuleBasedStateMachine`` feeds one :class:`Supervisor` a cycle at a time with
observations of four cables whose conditions the rules set and clear at random: tensions
(normal, slack, overload, implausible, NaN, and each threshold exactly), load cells failing
(up to all of them: ``loadcells_blind``), the setpoint infeasible, drive faults of every
kind the HAL reports (a fault, heartbeat lost, boot-up, NMT state, link lost, a quick stop
of its own), the bus refusing frames, a drive leaving Operation Enabled (a second master's
write), following errors at and beyond the window, cycle overruns, an operator's reset, and
a hold then its release. Limits (debounce, persistence, blind time, overruns) and reaction
overrides are drawn per run; the cycle period is 2^-8 s so that times add up exactly.

:class:`SupervisorModel` is the module docstring's specification written again, from the
table and the confirmation rule ("confirmed after ``debounce`` consecutive cycles, a tension
condition once it also lasted ``persist_s``; a device's own report and a load cell to
substitute on the first cycle; the most severe reaction wins; quick stop and disable
latch; hold and substitute end with their condition"). After every cycle:

- ``Decision.reaction``, ``hold``, ``stop``, ``substitute`` and ``conditions`` are the
  model's, exactly (an off-by-one in a threshold, a confirmation count, a persistence or
  ``hold`` itself fails here);
- the events are the model's: each condition starts once when confirmed and ends once.

``test_every_rule_ran_many_times`` asserts that each rule ran many times in CI's profile.
"""

from __future__ import annotations

import math

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

from controller.supervisor import (
    REACTIONS,
    DeviceFault,
    Observation,
    Reaction,
    Supervisor,
    SupervisorLimits,
)

R = Reaction
N = 4
CABLES = ("11", "12", "21", "22")
NODES = (1, 2, 3, 4)
UNITS = (11, 12, 13, 14)
T = 2.0**-8  # cycle period [s] (exact in binary: times and their differences are exact)
SLACK, OVERLOAD, PLAUSIBLE = 10.0, 1000.0, 10_000.0  # [N]
WINDOW = 0.02  # following-error window [m]
NOMINAL = 200.0  # [N]
TENSIONS = {"normal": NOMINAL, "slack": 2.0, "at_slack": SLACK, "overload": 2000.0,
            "at_overload": OVERLOAD, "implausible": 5e4, "at_plausible": PLAUSIBLE,
            "negative_implausible": -5e4, "nan": math.nan}
#: HAL fault kinds of a drive -> the supervisor's condition (module docstring)
DRIVE_KINDS = {"drive_fault": "drive_fault", "heartbeat_lost": "drive_lost",
               "boot_up": "drive_lost", "nmt_state": "drive_lost", "link_lost": "drive_lost",
               "quick_stop": "drive_fault"}
IMMEDIATE = ("drive_fault", "drive_lost", "bus", "loadcell")
PERSIST = ("slack", "overload")
RULES = RuleCounter()
AT_LEAST = 40  # runs of each rule in CI's profile


class SupervisorModel:
    """The supervisor's specification (controller/supervisor.py docstring), cycle by cycle.

    Times are counted in cycles (``persist_cycles``, ``blind_cycles``): a condition that
    first showed in cycle k0 has lasted ``k - k0`` cycles in cycle k."""

    def __init__(self, lim: SupervisorLimits, table: dict[str, Reaction], persist_cycles: int,
                 blind_cycles: int) -> None:
        self.lim, self.table = lim, table
        self.persist_cycles, self.blind_cycles = persist_cycles, blind_cycles
        self.reset()

    def reset(self) -> None:
        self.count: dict[str, int] = {}  # key -> consecutive cycles shown
        self.first: dict[str, int] = {}  # key -> cycle first shown
        self.kind: dict[str, str] = {}
        self.confirmed: set[str] = set()
        self.latched = R.NONE
        self.blind_from: int | None = None
        self.overruns = 0

    def shown(self, k: int, obs: Observation) -> tuple[dict[str, str], set[int]]:
        """{key: kind} of the conditions this observation shows; the cables to substitute."""
        lim = self.lim
        out: dict[str, str] = {}
        invalid = set()
        for j in range(N):
            tau = obs.tensions[j]
            valid = bool(obs.tension_ok[j]) and math.isfinite(tau) and abs(tau) <= lim.plausible_n
            if not valid:
                invalid.add(j)
                out[f"loadcell:loadcell:{UNITS[j]}"] = "loadcell"
            elif tau < lim.slack_n:
                out[f"slack:loadcell:{UNITS[j]}"] = "slack"
            elif tau > lim.overload_n:
                out[f"overload:loadcell:{UNITS[j]}"] = "overload"
        if len(invalid) > lim.max_substituted:
            if self.blind_from is None:
                self.blind_from = k
            if k - self.blind_from >= self.blind_cycles:
                out["loadcells_blind:platform:0"] = "loadcells_blind"
        else:
            self.blind_from = None
        if not obs.feasible:
            out["workspace:controller:0"] = "workspace"
        for j in range(N):
            err = abs(obs.lengths_meas[j] - obs.lengths_cmd[j])
            if obs.enabled[j] and err > lim.following_error_m[j]:
                out[f"following_error:drive:{NODES[j]}"] = "following_error"
        reported = set()
        for f in obs.faults:
            if f.device == "drive":
                reported.add(f.address)
                kind = DRIVE_KINDS[f.kind]
                out[f"{kind}:drive:{f.address}"] = kind
            else:
                out["bus:bus:0"] = "bus"
        if obs.expect_enabled:
            for j in range(N):
                if not obs.enabled[j] and NODES[j] not in reported:
                    out[f"drive_disabled:drive:{NODES[j]}"] = "drive_disabled"
        self.overruns = self.overruns + 1 if obs.overrun else 0
        if self.overruns >= lim.max_overruns:
            out["overruns:controller:0"] = "overruns"
        return out, invalid

    def step(self, k: int, obs: Observation) -> tuple[Reaction, set[int], set[tuple]]:
        """The decision for cycle ``k``: reaction, cables substituted, events (kind,
        address, active)."""
        shown, invalid = self.shown(k, obs)
        events = set()
        for key in list(self.count):
            if key not in shown:
                if key in self.confirmed:
                    events.add((self.kind[key], int(key.rsplit(":", 1)[1]), False))
                    self.confirmed.discard(key)
                del self.count[key], self.first[key]
        for key, kind in shown.items():
            if key not in self.count:
                self.count[key], self.first[key] = 0, k
            self.count[key] += 1
            self.kind[key] = kind
            need = 1 if kind in IMMEDIATE else self.lim.debounce
            lasted = kind not in PERSIST or k - self.first[key] >= self.persist_cycles
            if key not in self.confirmed and self.count[key] >= need and lasted:
                self.confirmed.add(key)
                events.add((kind, int(key.rsplit(":", 1)[1]), True))
        reaction = max((self.table[self.kind[key]] for key in self.confirmed), default=R.NONE)
        if invalid:
            reaction = max(reaction, R.SUBSTITUTE)
        if reaction in (R.QUICK_STOP, R.DISABLE):
            self.latched = max(self.latched, reaction)
        return max(reaction, self.latched), invalid, events


class SupervisorMachine(RuleBasedStateMachine):
    """One supervisor, its model, and the observations the rules shape."""

    @initialize(debounce=st.sampled_from([1, 2, 3]), persist=st.sampled_from([0, 1, 3, 6]),
                max_sub=st.sampled_from([1, 2]), blind=st.sampled_from([0, 2, 5]),
                max_overruns=st.sampled_from([1, 3]),
                overrides=st.sampled_from([{}, {}, {"slack": R.LOG}, {"overload": R.HOLD},
                                           {"workspace": R.QUICK_STOP},
                                           {"drive_disabled": R.HOLD}]))
    def start(self, debounce, persist, max_sub, blind, max_overruns, overrides):
        self.lim = SupervisorLimits(SLACK, OVERLOAD, PLAUSIBLE, np.full(N, WINDOW),
                                    debounce=debounce, persist_s=persist * T,
                                    max_substituted=max_sub, blind_s=blind * T,
                                    max_overruns=max_overruns)
        self.sup = Supervisor(self.lim, dict(overrides))
        self.model = SupervisorModel(self.lim, {**REACTIONS, **overrides}, persist, blind)
        self.k = 0
        self.tensions = np.full(N, NOMINAL)
        self.ok = np.ones(N, bool)
        self.feasible = True
        self.enabled = np.ones(N, bool)
        self.expect_enabled = True
        self.faults: dict[tuple[str, int], DeviceFault] = {}
        self.error = np.zeros(N)
        self.overrun = False
        self.held_cycles = 0  # consecutive cycles of hold (statistics)
        self.longest_hold = 0

    def teardown(self):
        try:
            target(float(self.longest_hold), label="longest hold [cycles]")
        except Exception:
            pass

    # ---- one cycle ----------------------------------------------------------------------
    def observe(self) -> Observation:
        cmd = np.full(N, 10.0)
        return Observation(self.k * T, self.tensions.copy(), self.ok.copy(), cmd + self.error,
                           cmd, self.enabled.copy(), expect_enabled=self.expect_enabled,
                           faults=tuple(self.faults.values()), feasible=self.feasible,
                           reason="" if self.feasible else "tension distribution infeasible",
                           overrun=self.overrun, cables=CABLES, node_ids=NODES,
                           unit_ids=UNITS)

    def cycles(self, n: int) -> None:
        for _ in range(n):
            self.k += 1
            obs = self.observe()
            d = self.sup.step(obs)
            want, invalid, events = self.model.step(self.k, obs)
            assert d.reaction == want, (self.k, d.reaction, want, d.conditions,
                                        sorted(self.model.confirmed))
            assert d.hold == (want in (R.HOLD, R.QUICK_STOP, R.DISABLE)), (self.k, d.hold, want)
            assert d.stop == (want in (R.QUICK_STOP, R.DISABLE)), (self.k, d.stop, want)
            assert set(np.flatnonzero(d.substitute)) == invalid, (self.k, d.substitute, invalid)
            assert d.conditions == tuple(sorted(self.model.confirmed)), (
                self.k, d.conditions, sorted(self.model.confirmed))
            got = {(e.kind, e.address, e.active) for e in d.events}
            assert got == events, (self.k, got, events)
            assert len(got) == len(d.events)  # one event per condition starting or ending
            for e in d.events:
                assert e.reaction == self.model.table[e.kind] and e.t_s == obs.t_s
                event(f"{e.kind} {'confirmed' if e.active else 'ended'} -> {e.reaction.label}")
            if d.hold and not d.stop:
                self.held_cycles += 1
                self.longest_hold = max(self.longest_hold, self.held_cycles)
            else:
                if self.held_cycles:
                    event("hold released" if not d.stop else "hold, then a stop")
                self.held_cycles = 0
            event(f"decision {d.reaction.label}")

    # ---- rules --------------------------------------------------------------------------
    @rule(n=st.integers(1, 30))
    @RULES.counted
    def run(self, n):
        self.cycles(n)

    @rule(cable=st.integers(0, N - 1), kind=st.sampled_from(sorted(TENSIONS)),
          n=st.integers(1, 8))
    @RULES.counted
    def tension(self, cable, kind, n):
        self.tensions[cable] = TENSIONS[kind]
        self.cycles(n)

    @rule(cable=st.integers(0, N - 1), ok=st.booleans(), n=st.integers(1, 8))
    @RULES.counted
    def loadcell_status(self, cable, ok, n):
        """A cell's status (the HAL's verdict): timed out, stale, faulted... or fine."""
        self.ok[cable] = ok
        self.cycles(n)

    @rule(count=st.integers(0, N), n=st.integers(1, 12))
    @RULES.counted
    def loadcells_fail(self, count, n):
        """``count`` cells fail at once (more than ``max_substituted``: blind)."""
        self.ok[:] = np.arange(N) >= count
        self.cycles(n)

    @rule(feasible=st.booleans(), n=st.integers(1, 8))
    @RULES.counted
    def workspace(self, feasible, n):
        self.feasible = feasible
        self.cycles(n)

    @rule(node=st.sampled_from(NODES), kind=st.sampled_from(sorted(DRIVE_KINDS)),
          code=st.sampled_from([0x2310, 0x7305, 0x8130, 0x8250, 0]), n=st.integers(1, 8))
    @RULES.counted
    def drive_reports(self, node, kind, code, n):
        """The HAL reports a drive fault, a lost drive, a stop of its own."""
        self.faults[("drive", node)] = DeviceFault("drive", node, CABLES[NODES.index(node)],
                                                   kind, code, kind)
        self.cycles(n)

    @rule(node=st.sampled_from(NODES), n=st.integers(1, 8))
    @RULES.counted
    def drive_report_ends(self, node, n):
        self.faults.pop(("drive", node), None)
        self.cycles(n)

    @rule(on=st.booleans(), n=st.integers(1, 8))
    @RULES.counted
    def bus(self, on, n):
        if on:
            self.faults[("bus", 0)] = DeviceFault("bus", 0, "-", "bus_error", 0x8100, "refused")
        else:
            self.faults.pop(("bus", 0), None)
        self.cycles(n)

    @rule(node=st.integers(0, N - 1), enabled=st.booleans(), n=st.integers(1, 8))
    @RULES.counted
    def second_master_write(self, node, enabled, n):
        """Another master's 0x6040 = 0: the drive leaves Operation Enabled (or is back)."""
        self.enabled[node] = enabled
        self.cycles(n)

    @rule(expect=st.booleans(), n=st.integers(1, 4))
    @RULES.counted
    def expect_enabled_(self, expect, n):
        self.expect_enabled = expect
        self.cycles(n)

    @rule(node=st.integers(0, N - 1), err=st.sampled_from([0.0, WINDOW, 1.5 * WINDOW,
                                                           -1.5 * WINDOW]),
          n=st.integers(1, 8))
    @RULES.counted
    def following_error(self, node, err, n):
        self.error[node] = err
        self.cycles(n)

    @rule(on=st.booleans(), n=st.integers(1, 6))
    @RULES.counted
    def overruns(self, on, n):
        self.overrun = on
        self.cycles(n)

    @rule(cable=st.integers(0, N - 1), hold=st.integers(1, 12), after=st.integers(1, 6))
    @RULES.counted
    def hold_then_release(self, cable, hold, after):
        """A cable goes slack for ``hold`` cycles, then back: a hold, then its release."""
        before = self.tensions[cable]
        self.tensions[cable] = TENSIONS["slack"]
        self.cycles(hold)
        self.tensions[cable] = before if math.isfinite(before) else NOMINAL
        self.cycles(after)

    @rule()
    @RULES.counted
    def all_clear(self):
        """Every condition ends (the latched reaction stays)."""
        self.tensions[:] = NOMINAL
        self.ok[:] = True
        self.feasible = True
        self.enabled[:] = True
        self.faults.clear()
        self.error[:] = 0.0
        self.overrun = False
        self.cycles(2)

    @rule()
    @RULES.counted
    def operator_reset(self):
        self.sup.reset()
        self.model.reset()
        self.cycles(1)

    @invariant()
    def latched_stays(self):
        if hasattr(self, "sup"):
            assert self.sup.latched == self.model.latched


SupervisorMachine.TestCase.settings = machine_settings(examples=150, steps=30)
TestSupervisorMachine = SupervisorMachine.TestCase
SUPERVISOR_RULES = [name for name in dir(SupervisorMachine)
                    if getattr(getattr(SupervisorMachine, name), "hypothesis_stateful_rule",
                               None)]


def test_every_rule_ran_many_times():
    """Each rule ran at least ``AT_LEAST`` times in the machine's run above (run here when
    this test runs alone)."""
    if not RULES:
        run_state_machine_as_test(SupervisorMachine,
                                  settings=SupervisorMachine.TestCase.settings)
    assert len(SUPERVISOR_RULES) >= 15
    print(RULES.report())  # with -s: how often and how long each rule ran
    assert not RULES.missing(SUPERVISOR_RULES, AT_LEAST), RULES.report()


def test_model_hold_timing_by_hand():
    """The model itself on the docstring's bound: a slack cable, debounce 3, persistence 5
    cycles: confirmed (hold) at the 6th cycle showing it, ``max(debounce - 1, persist)``
    cycles after the first; released on the first cycle it no longer shows."""
    lim = SupervisorLimits(SLACK, OVERLOAD, PLAUSIBLE, np.full(N, WINDOW), debounce=3,
                           persist_s=5 * T)
    m = SupervisorModel(lim, dict(REACTIONS), 5, 0)
    tau = np.full(N, NOMINAL)
    tau[1] = 1.0

    def obs(k, tensions):
        cmd = np.full(N, 10.0)
        return Observation(k * T, tensions, np.ones(N, bool), cmd, cmd, np.ones(N, bool),
                           cables=CABLES, node_ids=NODES, unit_ids=UNITS)

    got = [m.step(k, obs(k, tau))[0] for k in range(1, 8)]
    assert got == [R.NONE] * 5 + [R.HOLD] * 2
    assert m.step(8, obs(8, np.full(N, NOMINAL)))[0] == R.NONE
