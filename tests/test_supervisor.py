"""The supervisor (controller/supervisor.py): each condition leads to its reaction within the
debounce bound, named by device, and nothing is found when nothing is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from controller.feedrate import FeedRate, ramp_time
from controller.supervisor import (
    REACTIONS,
    DeviceFault,
    Observation,
    Reaction,
    Supervisor,
    SupervisorLimits,
)

N = 8
CABLES = ("11", "12", "21", "22", "31", "32", "41", "42")
NODES = tuple(range(1, 9))
UNITS = tuple(range(11, 19))
LIM = SupervisorLimits.for_robot(5.0, 3000.0, np.full(N, 0.02))


def obs(t=0.0, tau=None, ok=None, meas=None, cmd=None, enabled=None, **kw) -> Observation:
    tau = np.full(N, 200.0) if tau is None else np.asarray(tau, float)
    meas = np.full(N, 10.0) if meas is None else meas
    return Observation(t, tau, np.ones(N, bool) if ok is None else ok, meas,
                       meas if cmd is None else cmd,
                       np.ones(N, bool) if enabled is None else enabled,
                       cables=CABLES, node_ids=NODES, unit_ids=UNITS, **kw)


def run(sup: Supervisor, observations):
    return [sup.step(o) for o in observations]


def test_nothing_wrong_nothing_found():
    sup = Supervisor(LIM)
    rng = np.random.default_rng(0)
    for k in range(200):  # noisy but healthy tensions, small following errors
        d = sup.step(obs(k * 0.004, tau=200 + rng.normal(0, 5, N),
                         cmd=10.0 + rng.normal(0, 1e-3, N)))
        assert d.reaction == Reaction.NONE and d.events == () and not d.substitute.any()


def test_reaction_table_is_complete():
    assert set(REACTIONS.values()) <= set(Reaction)
    for kind in ("slack", "overload", "workspace", "following_error", "drive_fault",
                 "drive_lost", "drive_disabled", "bus", "loadcell", "loadcells_blind",
                 "overruns"):
        assert kind in REACTIONS


def _first(decisions, reaction):
    return next(i for i, d in enumerate(decisions) if d.reaction >= reaction)


def test_slack_holds_after_it_lasted_and_releases():
    sup = Supervisor(LIM)
    tau = np.full(N, 200.0)
    tau[2] = 0.5
    dt = 0.004
    ds = run(sup, [obs(dt * k, tau=tau) for k in range(40)])
    k = _first(ds, Reaction.HOLD)
    assert k == int(np.ceil(LIM.persist_s / dt - 1e-9))  # bounded: persist_s / T cycles
    ev = [e for d in ds for e in d.events]
    assert [(e.kind, e.device, e.address, e.cable, e.active) for e in ev] == [
        ("slack", "loadcell", 13, "21", True)]
    d = sup.step(obs(0.2))
    assert d.reaction == Reaction.NONE
    assert [(e.kind, e.active) for e in d.events] == [("slack", False)]


def test_a_noisy_cable_near_its_minimum_is_no_slack_cable():
    """A cable held at its 5 N minimum reads 5 +- 1 N: short dips are no slack."""
    sup = Supervisor(LIM)
    rng = np.random.default_rng(3)
    for k in range(5000):
        tau = np.full(N, 200.0)
        tau[4] = 5.0 + rng.normal(0, 1.0)
        d = sup.step(obs(0.004 * k, tau=tau))
        assert d.reaction == Reaction.NONE and not d.events


def test_overload_quick_stops_and_latches():
    sup = Supervisor(LIM)
    tau = np.full(N, 200.0)
    tau[7] = 3500.0
    ds = run(sup, [obs(0.004 * k, tau=tau) for k in range(30)] + [obs(0.2)])
    k = _first(ds, Reaction.QUICK_STOP)
    assert k == int(np.ceil(LIM.persist_s / 0.004 - 1e-9)) and ds[k].stop
    assert ds[-1].reaction == Reaction.QUICK_STOP  # latched after the condition ended
    sup.reset()
    assert sup.step(obs(0.3)).reaction == Reaction.NONE


@pytest.mark.parametrize("bad", [np.nan, 1e300, -1e6])
def test_bad_reading_is_substituted_at_once_never_an_overload(bad):
    sup = Supervisor(LIM)
    tau = np.full(N, 200.0)
    tau[4] = bad
    d = sup.step(obs(0.0, tau=tau))
    assert d.reaction == Reaction.SUBSTITUTE
    np.testing.assert_array_equal(d.substitute, np.arange(N) == 4)
    assert [(e.kind, e.address, e.active) for e in d.events] == [("loadcell", 15, True)]
    d = sup.step(obs(0.004))
    assert d.reaction == Reaction.NONE and [(e.kind, e.active) for e in d.events] == [
        ("loadcell", False)]


def test_loadcell_fault_named_with_the_hal_text():
    sup = Supervisor(LIM)
    ok = np.ones(N, bool)
    ok[0] = False
    f = DeviceFault("loadcell", 11, "11", "timeout", 0, "no answer within 0.1 s")
    d = sup.step(obs(0.0, ok=ok, faults=(f,)))
    assert d.substitute[0] and "timeout: no answer" in d.events[0].text


def test_too_many_substitutions_hold_after_blind_time():
    sup = Supervisor(LIM)
    ok = np.ones(N, bool)
    ok[:3] = False
    dt = 0.004
    ds = run(sup, [obs(k * dt, ok=ok) for k in range(200)])
    k = _first(ds, Reaction.HOLD)
    assert abs(k * dt - LIM.blind_s) <= (LIM.debounce + 1) * dt
    assert any(e.kind == "loadcells_blind" for e in ds[k].events)


def test_following_error_quick_stops():
    sup = Supervisor(LIM)
    cmd = np.full(N, 10.0)
    cmd[1] += 0.05
    ds = run(sup, [obs(0.0, cmd=cmd), obs(0.004, cmd=cmd)])
    assert ds[1].reaction == Reaction.QUICK_STOP
    e = ds[1].events[0]
    assert (e.kind, e.device, e.address, e.code) == ("following_error", "drive", 2, 0x8611)
    # not while the drive is not enabled (quick stop ramps are not following errors)
    sup2 = Supervisor(LIM)
    en = np.ones(N, bool)
    en[1] = False
    ds = run(sup2, [obs(0.0, cmd=cmd, enabled=en, expect_enabled=False)] * 3)
    assert all(d.reaction == Reaction.NONE for d in ds)


def test_drive_fault_and_lost_drive_quick_stop_on_the_first_cycle():
    for kind, cond in (("drive_fault", "drive_fault"), ("heartbeat_lost", "drive_lost"),
                       ("boot_up", "drive_lost")):
        sup = Supervisor(LIM)
        en = np.ones(N, bool)
        en[5] = False
        f = DeviceFault("drive", 6, "32", kind, 0x2310, "over current")
        d = sup.step(obs(0.0, enabled=en, faults=(f,)))
        assert d.reaction == Reaction.QUICK_STOP
        # one event, for the drive that faulted (not also "drive_disabled" for it)
        assert [(e.kind, e.address, e.code) for e in d.events] == [(cond, 6, 0x2310)]


def test_unexpectedly_disabled_drive_quick_stops():
    sup = Supervisor(LIM)
    en = np.ones(N, bool)
    en[0] = False
    ds = run(sup, [obs(0.0, enabled=en), obs(0.004, enabled=en)])
    assert ds[1].reaction == Reaction.QUICK_STOP
    assert ds[1].events[0].kind == "drive_disabled"


def test_bus_error_quick_stops():
    sup = Supervisor(LIM)
    d = sup.step(obs(0.0, faults=(DeviceFault("bus", 0, "", "bus_error", 0x8100, "down"),)))
    assert d.reaction == Reaction.QUICK_STOP


def test_infeasible_setpoint_holds():
    sup = Supervisor(LIM)
    ds = run(sup, [obs(0.0, feasible=False, reason="closed_form: no tensions"),
                   obs(0.004, feasible=False, reason="closed_form: no tensions")])
    assert ds[1].reaction == Reaction.HOLD and ds[1].events[0].kind == "workspace"


def test_overruns_hold_after_the_limit_and_reset_on_a_good_cycle():
    sup = Supervisor(LIM)
    ds = run(sup, [obs(k * 0.004, overrun=True) for k in range(LIM.max_overruns - 1)]
             + [obs(1.0, overrun=False)] + [obs(1 + k * 0.004, overrun=True)
                                            for k in range(LIM.max_overruns + LIM.debounce)])
    assert all(d.reaction == Reaction.NONE for d in ds[:LIM.max_overruns + 1])
    assert ds[-1].reaction == Reaction.HOLD


def test_feed_rate_ramps_down_and_up_within_limits():
    ramp = ramp_time(0.5, 0.5)
    f = FeedRate(ramp)
    dt = 0.004
    rates, advanced = [], 0.0
    for _ in range(int(ramp / dt) + 5):
        advanced += f.advance(dt, hold=True)
        rates.append(f.rate)
    assert f.stopped and rates[-1] == 0.0
    assert np.all(np.diff(rates) <= 0)
    # the trajectory advanced about half the ramp time while slowing down
    assert 0.4 * ramp < advanced < 0.6 * ramp
    slope = np.abs(np.diff(rates)) / dt
    assert slope.max() <= 1.5 / ramp + 1e-9  # extra acceleration <= 1.5 v / ramp = a_max
    for _ in range(int(ramp / dt) + 5):
        f.advance(dt, hold=False)
    assert f.rate == 1.0


def test_reaction_override_logs_instead_of_holding():
    from controller.supervisor import parse_reactions

    sup = Supervisor(LIM, parse_reactions(["slack=log"]))
    tau = np.full(N, 200.0)
    tau[2] = 0.2
    ds = run(sup, [obs(0.004 * k, tau=tau) for k in range(60)] + [obs(1.0)])
    assert all(d.reaction <= Reaction.LOG for d in ds)
    ev = [(e.kind, e.reaction, e.active) for d in ds for e in d.events]
    assert ev == [("slack", Reaction.LOG, True), ("slack", Reaction.LOG, False)]
    with pytest.raises(ValueError, match="no supervisor condition"):
        Supervisor(LIM, {"slak": Reaction.LOG})
    for bad in (["slack"], ["slack=maybe"], ["nothing=log"]):
        with pytest.raises(ValueError, match="CONDITION=REACTION"):
            parse_reactions(bad)
