"""cdpr-tracker/1.1: the tracker says whose clock its time stamps are on.

The greeting's ``clock`` (docs/formats/tracker.md): ``drives`` (the controller's drives'
clock: a fix is recorded at its own time stamp), ``own`` (the tracker's clock: the client
estimates the offset, :class:`hal.tracker.ClockOffset`), not said (version 1: a fix is timed
by its arrival). Both ways: the simulated server greets as the rig's clock says and the HAL
reads it; a version 1 server's greeting and lines still read; a version 1 client's check
(the greeting starts with ``CDPR-TRACKER/1``) still passes a 1.1 greeting.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from bench.dryrun.record import SampleTimes
from firmware_sim.rig import SimRig
from firmware_sim.tracker_sim import TrackerServer
from hal.tracker import (
    PROTOCOL,
    ClockOffset,
    TcpTracker,
    TrackerReading,
    parse_greeting,
)

POSE = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.1])
WAIT = 10.0  # generous deadline for anything that crosses threads or sockets
OLD_GREETING = "CDPR-TRACKER/1 rate_hz=200 frame=F_b units=m,rad"


def test_greetings_of_both_versions_and_what_is_refused():
    old = parse_greeting(OLD_GREETING)
    assert old is not None and old.version == (1, 0) and old.clock is None
    new = parse_greeting(OLD_GREETING.replace("/1 ", "/1.1 ") + " clock=drives")
    assert new is not None and new.version == (1, 1) and new.clock == "drives"
    assert parse_greeting("CDPR-TRACKER/1.1 clock=own").clock == "own"
    # a later minor version with fields this client does not know; a clock it does not know
    later = parse_greeting("CDPR-TRACKER/1.7 rate_hz=50 clock=own sync=ptp")
    assert later.version == (1, 7) and later.clock == "own" and later.fields["sync"] == "ptp"
    assert parse_greeting("CDPR-TRACKER/1.1 clock=gps").clock is None
    for bad in ("CDPR-TRACKER/2 rate_hz=200", "CDPR-TRACKER/10 rate_hz=200",
                "CDPR-TRACKER/1.x", "CDPR-TRACKERS/1", "+OK POP3 ready", ""):
        assert parse_greeting(bad) is None, bad


def _greeted(server: TrackerServer) -> str:
    with socket.create_connection(server.address, timeout=WAIT) as s:
        return s.makefile("rb").readline().decode().strip()


def test_the_simulated_server_says_its_clock_and_an_old_client_still_reads_it():
    for clock in ("drives", "own", None):
        with TrackerServer(lambda: (1.0, POSE, True), clock=clock) as srv:
            hello = _greeted(srv)
        assert hello.startswith(PROTOCOL)  # a version 1 client's whole check
        assert parse_greeting(hello).clock == clock
        assert (hello.split()[0] == "CDPR-TRACKER/1") == (clock is None)
    with pytest.raises(ValueError, match="clock"):
        TrackerServer(lambda: (1.0, POSE, True), clock="gps")


def test_the_rig_greets_with_the_drives_clock_on_the_sync_clock_and_its_own_on_the_wall():
    for rig_clock, said in (("sync", "drives"), ("wall", "own")):
        rig = SimRig(clock=rig_clock, tracker_port=0)
        try:
            rig.start()
            assert parse_greeting(_greeted(rig.tracker_server)).clock == said
        finally:
            rig.close()


def _serve_lines(lines_of) -> tuple[socket.socket, threading.Event]:
    """A raw server: greets with ``lines_of()``'s first line, then after SUBSCRIBE sends the
    rest, every 5 ms, until stopped (one client)."""
    srv = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve():
        try:
            c, _ = srv.accept()
            with c:
                lines = lines_of()
                c.sendall((next(lines) + "\n").encode())
                c.recv(64)  # SUBSCRIBE
                while not stop.is_set():
                    c.sendall((next(lines) + "\n").encode())
                    time.sleep(0.005)
        except OSError:
            pass

    threading.Thread(target=serve, daemon=True).start()
    return srv, stop


def test_an_old_servers_lines_still_read_and_are_timed_by_arrival():
    def lines():
        yield OLD_GREETING
        k = 0
        while True:
            k += 1
            yield f"P {k} {100 + 0.005 * k:.6f} 10 8.56 1.2 0 0 0.1 1"

    srv, stop = _serve_lines(lines)
    tr = TcpTracker("127.0.0.1", srv.getsockname()[1])
    try:
        tr.start(timeout_s=WAIT)
        r = tr.wait_fresh(WAIT)
        assert r.valid and np.allclose(r.pose, POSE) and r.t_s > 100
        assert tr.clock is None and not tr.on_hardware_clock and math.isnan(r.taken_age_s)
    finally:
        stop.set()
        tr.close()
        srv.close()


def test_drives_clock_time_stamps_are_the_hardwares():
    with TrackerServer(lambda: (2.5, POSE, True), clock="drives") as srv:
        tr = TcpTracker(*srv.address)
        try:
            tr.start(timeout_s=WAIT)
            r = tr.wait_fresh(WAIT)
            assert tr.clock == "drives" and tr.on_hardware_clock and math.isnan(r.taken_age_s)
        finally:
            tr.close()
    # the recording places such a fix at its time stamp, unless that is ahead of its clock
    fix = TrackerReading(2.5, POSE, True, 0.01)
    on_drives = SimpleNamespace(on_hardware_clock=True)
    assert SampleTimes(1.0, on_drives).fix(fix, 1.6) == pytest.approx(1.5)
    assert SampleTimes(1.0, on_drives).fix(fix, 1.2) == pytest.approx(1.19)  # another clock


def test_own_clock_fixes_are_timed_by_the_estimated_offset_never_early():
    """A tracker whose clock is the receiver's + 1000 s sends every other fix 30 ms after
    it was taken: timed by arrival those are 30 ms late; with the offset estimated from the
    others, by no more than their delivery."""
    lag_s, offset_s = 0.030, 1000.0

    def lines():
        yield "CDPR-TRACKER/1.1 rate_hz=200 frame=F_b units=m,rad clock=own"
        k = 0
        while True:
            k += 1
            t = time.monotonic() + offset_s - (lag_s if k % 2 else 0.0)
            yield f"P {k} {t:.6f} 10 8.56 1.2 0 0 0.1 1"

    srv, stop = _serve_lines(lines)
    tr = TcpTracker("127.0.0.1", srv.getsockname()[1])
    late_by_arrival, late = [], []
    try:
        tr.start(timeout_s=WAIT)
        for _ in range(40):
            r = tr.wait_fresh(WAIT)
            true_age = time.monotonic() - (r.t_s - offset_s)
            late.append(true_age - r.taken_age_s)  # > 0: placed after it was taken
            late_by_arrival.append(true_age - r.age_s)
        assert tr.clock == "own" and not tr.on_hardware_clock
    finally:
        stop.set()
        tr.close()
        srv.close()
    late, late_by_arrival = np.array(late), np.array(late_by_arrival)
    assert np.all(late >= -1e-5), late  # never early (the time stamps' microseconds)
    assert np.max(late_by_arrival) > lag_s * 0.9  # the stale fixes, by arrival
    assert np.median(late) < np.median(late_by_arrival)
    assert np.mean(late < lag_s / 2) > 0.9, late  # the stale ones are placed right


def test_the_offset_is_the_smallest_delay_over_its_window():
    est = ClockOffset()
    assert math.isnan(est.offset_s)
    for rx, d in ((0.0, 100.01), (1.0, 100.03), (2.0, 100.02)):  # offset 100 s + delay
        est.add(rx - d, rx)
    assert est.offset_s == pytest.approx(100.01)  # the least delay
    est.add(12.0 - 100.05, 12.0)  # 10 s on: the fixes before 2 s left the window
    assert est.offset_s == pytest.approx(100.02)


def test_a_read_takes_the_offset_under_the_lock_the_receive_thread_changes_it_under():
    """:meth:`TcpTracker.read` reads the clock offset while holding the lock the receive
    thread holds as it adds a fix to it (its window emptied and refilled) or replaces it on
    a new connection: read outside, the deque could empty between its check and its index."""
    tr = TcpTracker("127.0.0.1", 1)  # never started: the state set by hand
    held = []

    class Watched(ClockOffset):
        @property
        def offset_s(self) -> float:
            held.append(tr._cond._is_owned())  # (threading.Condition's own test)
            return 1000.0

    with tr._cond:
        tr.clock, tr._offset = "own", Watched()
        # taken 0.2 s ago on the receiver's clock (its own + 1000 s), just received
        tr._latest = (time.monotonic() - 0.2 - 1000.0, POSE, True, time.monotonic())
    r = tr.read()
    assert held == [True]
    assert r.valid and r.taken_age_s == pytest.approx(0.2, abs=0.1)


def test_a_restarted_tracker_and_one_without_stamps_are_still_recorded():
    """A fix is new when it is another fix, not only a later one: a tracker restarted (its
    own clock from zero again) goes on being recorded, and a tracker that stamps nothing
    has each fix told by its arrival; the same fix read again is not recorded twice."""
    own = SimpleNamespace(on_hardware_clock=False)
    times = SampleTimes(0.0, own)
    assert times.fix(TrackerReading(500.0, POSE, True, 0.0), 10.0) == pytest.approx(10.0)
    assert times.fix(TrackerReading(500.0, POSE, True, 0.004), 10.004) is None  # read again
    assert times.fix(TrackerReading(0.2, POSE, True, 0.0), 10.5) == pytest.approx(10.5)
    unstamped = SampleTimes(0.0, own)
    assert unstamped.fix(TrackerReading(float("nan"), POSE, True, 0.001), 1.0) is not None
    assert unstamped.fix(TrackerReading(float("nan"), POSE, True, 0.005), 1.004) is None
    assert unstamped.fix(TrackerReading(float("nan"), POSE, True, 0.0), 1.02) is not None
