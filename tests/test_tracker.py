"""The laser tracker: the simulated one (firmware_sim/tracker_sim.py) in process and over
the cdpr-tracker/1 protocol, the HAL's clients (hal/tracker.py), the rig's hook and
``cdpr sim``. Waits have generous deadlines; nothing asserts on elapsed time."""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.rig import SimRig
from firmware_sim.scenario import Noise
from firmware_sim.tracker_sim import PROTOCOL, SimTracker, TrackerServer
from hal.tracker import (
    CallableTracker,
    TcpTracker,
    TrackerError,
    TrackerSpecError,
    add_tracker_argument,
    open_tracker,
    parse_line,
    parse_tracker_spec,
)

ROOT = Path(__file__).resolve().parents[1]
TRUTH = np.array([10.0, 8.56, 1.2, 0.01, -0.02, 0.3])
WAIT = 10.0  # generous deadline for anything that crosses threads or sockets


class Clock:
    """A pose source with its own time: ``(t, TRUTH)``, t advancing by 4 ms per call."""

    def __init__(self) -> None:
        self.t = 0.0
        self.lock = threading.Lock()

    def __call__(self):
        with self.lock:
            self.t += 0.004
            return self.t, TRUTH


def _until(cond, what: str, deadline_s: float = WAIT):
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.01)
    raise AssertionError(f"not within {deadline_s} s: {what}")


# ---------------------------------------------------------------------------- in process


def test_noise_statistics_with_a_fixed_seed():
    n = Noise()
    sim = SimTracker(Clock(), n.tracker_m, n.tracker_rad, seed=42)
    m = np.array([sim.measure()[1] for _ in range(4000)])
    err = m - TRUTH
    sd = err.std(axis=0, ddof=1)
    want = np.array([n.tracker_m] * 3 + [n.tracker_rad] * 3)
    np.testing.assert_allclose(sd, want, rtol=0.06)  # 4000 samples: sd of sd ~ 1.1 %
    assert np.all(np.abs(err.mean(axis=0)) < 4 * want / np.sqrt(len(m)))
    # independent axes and samples
    c = np.corrcoef(err.T)
    assert np.abs(c - np.eye(6)).max() < 0.08
    assert abs(np.corrcoef(err[1:, 0], err[:-1, 0])[0, 1]) < 0.08
    # the same seed repeats the same noise, another seed does not
    again = SimTracker(Clock(), n.tracker_m, n.tracker_rad, seed=42)
    other = SimTracker(Clock(), n.tracker_m, n.tracker_rad, seed=43)
    first = np.array([again.measure()[1] for _ in range(3)])
    np.testing.assert_array_equal(first, m[:3])
    assert not np.allclose(other.measure()[1], m[0])


def test_noise_free_tracker_and_time_stamps():
    sim = SimTracker(Clock())
    t1, p1, v1 = sim.measure()
    t2, p2, v2 = sim()
    assert v1 and v2 and t2 > t1
    np.testing.assert_array_equal(p1, TRUTH)
    with pytest.raises(ValueError):
        SimTracker(Clock(), -1.0)


def test_losing_the_target():
    sim = SimTracker(Clock(), 1e-4, 1e-5)
    tr = CallableTracker(sim.measure)
    r = tr.start().read()
    assert r.valid and r.age_s == 0.0 and np.allclose(r.pose, TRUTH, atol=1e-3)
    sim.lose_target()
    r = tr.wait_fresh(1.0)
    assert not r.valid and np.isnan(r.pose).all() and np.isfinite(r.t_s)
    sim.regain_target()
    assert tr.read().valid
    tr.close()


def test_callable_tracker_treats_a_nan_pose_as_invalid():
    tr = CallableTracker(lambda: (1.0, np.array([1, 2, np.nan, 0, 0, 0]), True))
    r = tr.read()
    assert not r.valid and np.isnan(r.pose).all()


# ---------------------------------------------------------------------------- protocol


def test_protocol_lines_over_a_raw_socket():
    sim = SimTracker(Clock(), 1e-4, 1e-5, seed=1)
    with TrackerServer(sim.measure, rate_hz=100.0) as srv:
        with socket.create_connection(srv.address, timeout=WAIT) as s:
            f = s.makefile("rwb")
            hello = f.readline().decode()
            assert hello.startswith(PROTOCOL) and "rate_hz=100" in hello
            assert "frame=F_b" in hello and "units=m,rad" in hello
            f.write(b"PING\n")
            f.flush()
            assert f.readline() == b"PONG\n"
            f.write(b"HELLO there\n")
            f.flush()
            assert f.readline().startswith(b"ERR unknown command")
            f.write(b"SUBSCRIBE\n")
            f.flush()
            lines = [f.readline().decode() for _ in range(5)]
            parsed = [parse_line(x) for x in lines]
            assert all(p is not None for p in parsed), lines
            seqs = [p[0] for p in parsed]
            assert seqs == list(range(seqs[0], seqs[0] + 5))
            ts = [p[1] for p in parsed]
            assert all(b > a for a, b in zip(ts, ts[1:], strict=False))
            for _, _, pose, valid in parsed:
                assert valid and np.allclose(pose, TRUTH, atol=1e-3)
            sim.lose_target()
            p = _until(lambda: (q := parse_line(f.readline().decode())) and not q[3] and q,
                       "an invalid measurement line")
            assert np.isnan(p[2]).all()
            f.write(b"QUIT\n")
            f.flush()
            _until(lambda: f.readline() == b"", "the server closing the connection")


def test_parse_line_rejects_what_is_not_a_measurement():
    assert parse_line("P 1 0.5 1 2 3 0 0 0 1")[3] is True
    assert parse_line("P 1 0.5 1 2 3 0 0 0 0")[3] is False
    assert parse_line("P 1 0.5 nan 2 3 0 0 0 1")[3] is False  # NaN is never valid
    for bad in ("", "PONG", "P 1 0.5 1 2 3 0 0 0", "P x 0.5 1 2 3 0 0 0 1",
                "P 1 0.5 1 2 3 0 0 0 yes", "Q 1 0.5 1 2 3 0 0 0 1"):
        assert parse_line(bad) is None, bad


# ---------------------------------------------------------------------------- TCP client


def test_tcp_tracker_reads_the_stream_and_reconnects():
    sim = SimTracker(Clock(), 1e-4, 1e-5, seed=3)
    srv = TrackerServer(sim.measure, rate_hz=200.0).start()
    port = srv.address[1]
    tr = open_tracker(srv.spec, stale_s=0.3, retry_s=0.05)
    assert isinstance(tr, TcpTracker)
    try:
        tr.start(timeout_s=WAIT)
        r = tr.wait_fresh(WAIT)
        assert r.valid and r.age_s >= 0 and np.allclose(r.pose, TRUTH, atol=1e-3)
        r2 = tr.wait_fresh(WAIT)
        assert r2.t_s > r.t_s
        # the target lost and found again
        sim.lose_target()
        _until(lambda: not tr.wait_fresh(WAIT).valid, "an invalid reading")
        sim.regain_target()
        _until(lambda: tr.wait_fresh(WAIT).valid, "a valid reading again")
        # the server drops the connection: the client reconnects by itself
        srv.drop_clients()
        _until(lambda: tr.connects >= 2, "a reconnection")
        assert tr.wait_fresh(WAIT).valid
        # the server goes away: readings turn invalid (stale), wait_fresh times out
        srv.close()
        r = _until(lambda: (x := tr.read()).valid is False and x, "a stale reading")
        assert np.isnan(r.pose).all() and r.age_s > 0.3 and np.isfinite(r.t_s)
        with pytest.raises(TrackerError, match="no measurement within"):
            tr.wait_fresh(0.3)
        # ... and comes back on the same port: the client reconnects and reads again
        srv = TrackerServer(sim.measure, port=port, rate_hz=200.0).start()
        _until(lambda: tr.connects >= 3, "a reconnection to the new server")
        assert tr.wait_fresh(WAIT).valid
        assert tr.bad_lines == 0
    finally:
        tr.close()
        srv.close()
    assert not any(t.name == "tracker-rx" and t.is_alive() for t in threading.enumerate())


def test_tcp_tracker_start_fails_clearly_without_a_server():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # a port nobody listens on
    tr = TcpTracker("127.0.0.1", port, retry_s=0.05)
    with pytest.raises(TrackerError, match=f"tcp:127.0.0.1:{port}: no measurement within"):
        tr.start(timeout_s=0.5)
    r = tr.read()
    assert not r.valid and r.age_s == float("inf") and np.isnan(r.t_s)
    assert not any(t.name == "tracker-rx" and t.is_alive() for t in threading.enumerate())


def test_tcp_tracker_refuses_a_server_of_another_protocol():
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]

    def serve():
        try:
            c, _ = srv.accept()
            c.sendall(b"+OK POP3 ready\r\n")
            time.sleep(0.5)
            c.close()
        except OSError:
            pass

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    tr = TcpTracker("127.0.0.1", port, retry_s=5.0)
    with pytest.raises(TrackerError, match="not a CDPR-TRACKER/1 server"):
        tr.start(timeout_s=1.0)
    srv.close()
    th.join(WAIT)


def test_tracker_specs():
    assert parse_tracker_spec("none").kind == "none"
    s = parse_tracker_spec("tcp:127.0.0.1:40125")
    assert (s.kind, s.host, s.port, str(s)) == ("tcp", "127.0.0.1", 40125, "tcp:127.0.0.1:40125")
    assert str(parse_tracker_spec("tcp:[::1]:7")) == "tcp:[::1]:7"
    assert open_tracker("none") is None and open_tracker(None) is None
    for bad in ("", "udp:host:1", "tcp:host", "tcp::5", "tcp:host:0", "tcp:host:x",
                "tcp:[::1:5"):
        with pytest.raises(TrackerSpecError):
            parse_tracker_spec(bad)
    p = argparse.ArgumentParser()
    add_tracker_argument(p)
    assert p.parse_args([]).tracker.kind == "none"
    assert p.parse_args(["--tracker", "tcp:localhost:9"]).tracker.port == 9
    with pytest.raises(SystemExit) as e:
        p.parse_args(["--tracker", "tcp:localhost"])
    assert e.value.code == 2


# ---------------------------------------------------------------------------- the rig


def test_the_rig_measures_its_plant_in_process_and_over_tcp():
    with SimRig(plant_thread=False, tracker_port=0) as rig:
        sc = rig.scenario
        spec = rig.tracker_spec
        assert spec.startswith("tcp:127.0.0.1:") and rig.endpoints()["tracker"] == spec
        truth = rig.last.pose
        np.testing.assert_allclose(truth, sc.init_pose, atol=1e-6)
        t, pose, valid = rig.measure_pose()
        assert valid and t == pytest.approx(rig.time_s())
        m = np.array([rig.measure_pose()[1] for _ in range(500)])
        sd = (m - truth).std(axis=0)
        want = np.array([sc.noise.tracker_m] * 3 + [sc.noise.tracker_rad] * 3)
        np.testing.assert_allclose(sd, want, rtol=0.15)
        tr = CallableTracker(rig.measure_pose)
        assert tr.read().valid
        tcp = TcpTracker(*spec[4:].rsplit(":", 1))
        with tcp:
            r = tcp.wait_fresh(WAIT)
            assert r.valid and np.allclose(r.pose, truth, atol=10 * sc.noise.tracker_m)
            rig.tracker.lose_target()
            _until(lambda: not tcp.wait_fresh(WAIT).valid, "the rig's tracker losing the target")
            assert not tr.read().valid
    # closed with the rig
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", int(spec.rsplit(":", 1)[1])), timeout=2).close()


def test_a_rig_without_a_tracker_port_serves_none():
    with SimRig(plant_thread=False) as rig:
        assert rig.tracker_spec is None and rig.endpoints()["tracker"] is None
        assert rig.measure_pose()[2]


def test_cdpr_sim_serves_the_tracker():
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "sim", "--json",
                             "--exit-on-stdin-eof"], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        info = json.loads(proc.stdout.readline())
        spec = info["tracker"]
        tr = open_tracker(spec)
        with tr:
            r = tr.wait_fresh(WAIT)
            assert r.valid
            np.testing.assert_allclose(r.pose, info["init_pose"], atol=1e-3)
    finally:
        proc.stdin.close()
        proc.wait(timeout=30)
    assert proc.returncode == 0
