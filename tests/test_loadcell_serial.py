"""Modbus RTU on real (pseudo-)serial lines: simulated cells on one tty, the HAL on another.

Two pseudo-terminals joined by a byte relay play a null-modem cable, so both
pymodbus' serial server and its serial client run over termios devices as on
an RS-485 adapter.
"""

from __future__ import annotations

import os
import select
import subprocess
import threading

import numpy as np
import pytest
from test_loadcell_mbpoll import FED, MBPOLL, parse_mbpoll, start_server, stop_server

from firmware_sim.loadcell_server import LoadCellServer
from hal.loadcell_client import CableStatus, LoadCellClient

T = np.array([100.1, 200.2, 300.3, 1.5, 0.0, -3.25, 2999.9, 42.0])


@pytest.fixture
def null_modem():
    """Two tty device names whose bytes are relayed to each other."""
    try:
        m1, s1 = os.openpty()
        m2, s2 = os.openpty()
    except OSError as exc:  # pragma: no cover - no pty support
        pytest.skip(f"no pseudo-terminals: {exc}")
    stop = threading.Event()

    def relay() -> None:
        while not stop.is_set():
            ready, _, _ = select.select([m1, m2], [], [], 0.05)
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                os.write(m2 if fd == m1 else m1, data)

    th = threading.Thread(target=relay, daemon=True)
    th.start()
    yield os.ttyname(s1), os.ttyname(s2)
    stop.set()
    th.join(5)
    for fd in (m1, s1, m2, s2):
        os.close(fd)


def test_rtu_over_a_serial_line(null_modem):
    server_tty, client_tty = null_modem
    srv = LoadCellServer(serial=server_tty, baudrate=115200).start()
    try:
        assert srv.endpoint == f"rtu:{server_tty}:115200"
        client = LoadCellClient(f"rtu:{client_tty}:115200", timeout_s=0.3)
        try:
            srv.update(T)
            client.poll_once()
            r = client.read()
            assert r.all_ok, r.faults()
            np.testing.assert_array_equal(r.values_N, T.astype(np.float32))
            srv.inject("22", "exception")
            srv.inject("41", "no_answer")
            srv.update(T + 1)
            client.poll_once()
            r = client.read()
            assert r.status_of("22") == CableStatus.EXCEPTION
            assert r.status_of("41") == CableStatus.TIMEOUT
            assert f"Modbus unit 7 (cable 41) at rtu:{client_tty}:115200" in r.messages[6]
            ok = np.isin(np.arange(8), [3, 6], invert=True)
            assert (r.status[ok] == CableStatus.OK).all(), r.faults()
            np.testing.assert_array_equal(r.values_N[ok], (T + 1).astype(np.float32)[ok])
        finally:
            client.stop()
    finally:
        srv.stop()


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (apt-get install mbpoll)")
def test_mbpoll_rtu_reads_the_standalone_server_on_a_serial_line(null_modem):
    server_tty, client_tty = null_modem
    proc, info = start_server("--serial", server_tty, "--baud", "115200",
                              "--tensions", ",".join(map(str, FED)))
    try:
        assert info["endpoint"] == f"rtu:{server_tty}:115200" and info["framer"] == "rtu"
        out = subprocess.run(
            [MBPOLL, "-m", "rtu", "-b", "115200", "-P", "none", "-0", "-1", "-o", "1",
             "-a", "1:8", "-t", "3:float", "-B", "-r", "0", client_tty],
            capture_output=True, text=True, timeout=60,
        )
        assert out.returncode == 0, out.stdout + out.stderr
        assert parse_mbpoll(out.stdout) == {k + 1: [v] for k, v in enumerate(FED)}
    finally:
        stop_server(proc)
    assert proc.returncode == 0
