"""Simulated load cells and the HAL client over Modbus (127.0.0.1, OS-assigned ports).

Both framings: Modbus/TCP and RTU framing over TCP; plus the serial RTU client
through a pyserial ``socket://`` URL.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from controller.loadcell_map import DEFAULT_MAP
from firmware_sim.loadcell_bank import LoadCellBank
from firmware_sim.loadcell_server import LoadCellServer
from hal.loadcell_calibration import LoadCellCalibration
from hal.loadcell_client import CableStatus, LoadCellClient

T = np.array([100.1, 200.2, 300.3, 1.5, 0.0, -3.25, 2999.9, 42.0])
F32 = T.astype(np.float32).astype(np.float64)


class FakeClock:
    """Monotonic clock the test advances by hand (ages and staleness without sleeps)."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(params=["tcp", "rtu-tcp"])
def server(request):
    srv = LoadCellServer(rtu=request.param == "rtu-tcp").start()
    yield srv
    srv.stop()


@pytest.fixture
def make_client():
    clients: list[LoadCellClient] = []

    def make(endpoint: str, **kw) -> LoadCellClient:
        # (an answer that takes longer on a loaded machine is no fault of the code tested)
        kw.setdefault("timeout_s", 0.5)
        c = LoadCellClient(endpoint, **kw)
        clients.append(c)
        return c

    yield make
    for c in clients:
        c.stop()


def test_endpoint_names_the_framing(server):
    assert server.port > 0
    prefix = "rtu-tcp:" if server.rtu else ""
    assert server.endpoint == f"{prefix}127.0.0.1:{server.port}"


def test_round_trip_exact_float32_with_ages(server, make_client):
    client = make_client(server.endpoint)
    r0 = client.read()
    assert (r0.status == CableStatus.NO_DATA).all() and np.isnan(r0.values_N).all()
    assert "no data yet" in r0.messages[0]
    server.update(T)
    t_before = client.clock()
    client.poll_once()
    r = client.read()
    t_after = client.clock()
    assert r.all_ok, r.faults()
    np.testing.assert_array_equal(r.values_N, F32)  # exactly the float32 of what was fed
    assert r.counter.tolist() == [1] * 8
    assert np.all(r.age_s >= 0) and np.all(r.age_s <= t_after - t_before)
    assert r.cables == DEFAULT_MAP.cables and r.unit_ids == DEFAULT_MAP.unit_ids


def test_counters_advance_and_ages_restart(server, make_client):
    clock = FakeClock()
    client = make_client(server.endpoint, clock=clock)
    for i in range(1, 6):
        server.update(T + i)
        client.poll_once()
        clock.t += 0.01
        r = client.read()
        assert r.all_ok, r.faults()
        assert r.counter.tolist() == [i] * 8
        np.testing.assert_allclose(r.age_s, 0.01)  # the sample arrived at the poll
        np.testing.assert_array_equal(r.values_N, (T + i).astype(np.float32))


def test_calibration_recovers_true_tensions(make_client):
    gain = np.linspace(0.97, 1.03, 8)
    offset = np.linspace(-6.0, 6.0, 8)
    with LoadCellServer(LoadCellBank(gain=gain, offset_N=offset)) as srv:
        raw = make_client(srv.endpoint)
        cal = make_client(srv.endpoint, calibration=LoadCellCalibration(gain, offset))
        srv.update(T)
        raw.poll_once()
        cal.poll_once()
        np.testing.assert_array_equal(raw.read().values_N, (gain * T + offset).astype(np.float32))
        np.testing.assert_allclose(cal.read().values_N, T, rtol=1e-6, atol=1e-4)


FAULTS = [
    # (fault, params, expected status, words the message must contain)
    ("stale", {}, CableStatus.STALE, ["counter stuck at 1"]),
    ("exception", {}, CableStatus.EXCEPTION, ["exception 0x04", "DEVICE_FAILURE"]),
    ("exception", {"exception_code": 6}, CableStatus.EXCEPTION, ["0x06", "DEVICE_BUSY"]),
    ("no_answer", {}, CableStatus.TIMEOUT, ["no answer within 0.5 s"]),
    ("out_of_range", {}, CableStatus.OUT_OF_RANGE, ["overload bit set", "6000 N outside"]),
    ("nan", {}, CableStatus.NAN, ["NaN"]),
    ("sensor_fault", {}, CableStatus.SENSOR_FAULT, ["sensor fault", "0x0002"]),
]


@pytest.mark.parametrize(("fault", "params", "status", "words"), FAULTS)
@pytest.mark.parametrize("cable", ["21", "42"])
def test_each_fault_is_reported_with_unit_and_cable(
    server, make_client, cable, fault, params, status, words
):
    clock = FakeClock()
    client = make_client(server.endpoint, clock=clock, stale_s=0.25)
    server.update(T)
    client.poll_once()
    assert client.read().all_ok
    server.inject(cable, fault, **params)
    clock.t += 0.3  # longer than stale_s
    server.update(T + 1)
    client.poll_once()
    r = client.read()
    k = DEFAULT_MAP.index_of(cable)
    assert r.status[k] == status, r.messages[k]
    assert np.isnan(r.values_N[k])  # never a number
    msg = r.messages[k]
    assert f"Modbus unit {DEFAULT_MAP.unit_of(cable)} (cable {cable})" in msg
    for w in words:
        assert w in msg
    others = np.arange(8) != k
    assert (r.status[others] == CableStatus.OK).all(), r.faults()
    np.testing.assert_array_equal(r.values_N[others], (T + 1).astype(np.float32)[others])
    assert r.faults() == [msg]
    # the fault clears: values come back
    server.clear(cable)
    server.update(T + 2)
    client.poll_once()
    r = client.read()
    assert r.all_ok, r.faults()
    np.testing.assert_array_equal(r.values_N, (T + 2).astype(np.float32))


def test_several_faults_at_once_are_all_reported(server, make_client):
    client = make_client(server.endpoint)
    server.update(T)
    for cable, fault in [("11", "nan"), ("22", "no_answer"), ("32", "sensor_fault")]:
        server.inject(cable, fault)
    client.poll_once()
    r = client.read()
    assert r.status.tolist() == [
        CableStatus.NAN, 0, 0, CableStatus.TIMEOUT, 0, CableStatus.SENSOR_FAULT, 0, 0,
    ]
    assert len(r.faults()) == 3
    assert client.errors.tolist() == [0, 0, 0, 1, 0, 0, 0, 0]


def test_value_beyond_the_clients_range_without_overload_bit(server, make_client):
    narrow = dataclasses.replace(DEFAULT_MAP, rated_max_N=1000.0)
    client = make_client(server.endpoint, register_map=narrow)
    server.update(T)  # T[6] = 2999.9 N: fine for the cell, beyond the client's 1000 N
    client.poll_once()
    r = client.read()
    assert r.status_of("41") == CableStatus.OUT_OF_RANGE
    assert "overload bit" not in r.messages[6] and "2999.9 N outside" in r.messages[6]
    assert (np.delete(r.status, 6) == CableStatus.OK).all()


def test_no_fault_reported_over_many_polls(server, make_client):
    # patient: a loaded machine may hold a thread for longer than the 0.1 s others test with
    client = make_client(server.endpoint, timeout_s=2.0, stale_s=30.0)
    t = np.arange(300) * 0.02
    tensions = 2500.0 + 2499.0 * np.sin(t[:, None] + np.arange(8))  # 1 .. 4999 N
    tensions[::50, 0] = 0.0
    for i, tau in enumerate(tensions):
        server.update(tau)
        client.poll_once()
        r = client.read()
        assert r.all_ok, f"poll {i}: {r.faults()}"
        np.testing.assert_array_equal(r.values_N, tau.astype(np.float32))
    assert client.errors.sum() == 0 and client.sweeps == len(tensions)


def test_background_poller_and_plant_thread(server, make_client):
    client = make_client(server.endpoint, rate_hz=100.0, stale_s=2.0)
    stop = threading.Event()

    def plant():
        while not stop.wait(0.005):
            server.update(T)

    feeder = threading.Thread(target=plant, daemon=True)
    feeder.start()
    try:
        client.start()
        assert client.wait_sweeps(5)
        r1 = client.read()
        assert client.wait_sweeps(5)
        r2 = client.read()
    finally:
        stop.set()
        feeder.join(5)
    for r in (r1, r2):
        assert r.all_ok, r.faults()
        np.testing.assert_array_equal(r.values_N, F32)
    assert np.all(r2.counter > r1.counter)  # no wrap in this short run
    assert np.all(r2.age_s >= 0)


def test_read_never_waits_for_the_line(server, make_client):
    client = make_client(server.endpoint)
    server.update(T)
    client.poll_once()
    result: list = []
    with client._io_lock:  # the line is busy (a poll in progress)
        th = threading.Thread(target=lambda: result.append(client.read()), daemon=True)
        th.start()
        th.join(5.0)
        assert not th.is_alive(), "read() waited for the Modbus line"
    assert result[0].all_ok


def test_lost_server_is_a_comm_error_for_every_cable(make_client):
    srv = LoadCellServer().start()
    client = make_client(srv.endpoint)
    srv.update(T)
    client.poll_once()
    assert client.read().all_ok
    srv.stop()
    client.poll_once()
    r = client.read()
    assert (r.status == CableStatus.COMM_ERROR).all()
    assert np.isnan(r.values_N).all()
    for k, msg in enumerate(r.messages):
        assert f"Modbus unit {k + 1} (cable {DEFAULT_MAP.cables[k]})" in msg
        assert srv.endpoint in msg


def test_unit_missing_on_the_line_times_out(server, make_client):
    wrong = dataclasses.replace(DEFAULT_MAP, unit_ids=(1, 2, 3, 4, 5, 6, 7, 9))
    client = make_client(server.endpoint, register_map=wrong)
    server.update(T)
    client.poll_once()
    r = client.read()
    assert r.status_of("42") == CableStatus.TIMEOUT
    assert "Modbus unit 9 (cable 42)" in r.messages[7]
    assert (r.status[:7] == CableStatus.OK).all()


def test_serial_rtu_client_through_a_pyserial_url(make_client):
    with LoadCellServer(rtu=True) as srv:
        client = make_client(f"rtu:socket://127.0.0.1:{srv.port}:115200", timeout_s=0.5)
        assert client.endpoint.kind == "rtu"
        srv.update(T)
        client.poll_once()
        r = client.read()
        assert r.all_ok, r.faults()
        np.testing.assert_array_equal(r.values_N, F32)
        srv.inject("31", "exception")
        srv.update(T)
        client.poll_once()
        assert client.read().status_of("31") == CableStatus.EXCEPTION


def test_a_stalled_poller_expires_the_values(server, make_client):
    clock = FakeClock()
    client = make_client(server.endpoint, clock=clock, stale_s=0.1, max_age_s=0.25)
    server.update(T)
    client.poll_once()
    clock.t += 0.2
    r = client.read()
    assert r.all_ok and np.allclose(r.age_s, 0.2)
    clock.t += 0.1  # no answer for 0.3 s > max_age_s
    r = client.read()
    assert (r.status == CableStatus.TIMEOUT).all() and np.isnan(r.values_N).all()
    assert "no fresh answer for 0.300 s (limit 0.25 s" in r.messages[0]
    np.testing.assert_allclose(r.age_s, 0.3)


def test_slow_sweeps_are_not_stale_counters(server, make_client):
    # Staleness is judged between answers: a long gap between two polls (a
    # sweep slowed by a unit that times out) with the counter moving on is fine.
    clock = FakeClock()
    client = make_client(server.endpoint, clock=clock, stale_s=0.1, max_age_s=1.0)
    server.update(T)
    client.poll_once()
    clock.t += 0.4
    server.update(T + 1)
    client.poll_once()
    r = client.read()
    assert r.all_ok, r.faults()
    # ... while the same gap without a new sample is a stuck counter
    clock.t += 0.4
    client.poll_once()
    r = client.read()
    assert (r.status == CableStatus.STALE).all()
    assert "sample counter stuck at 2 for 0.400 s (limit 0.1 s)" in r.messages[3]


def test_connection_refused_names_the_reason(make_client):
    import socket

    with socket.socket() as s:  # a port nobody listens on (bound, then released)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    client = make_client(f"127.0.0.1:{port}")
    client.poll_once()
    r = client.read()
    assert (r.status == CableStatus.COMM_ERROR).all()
    assert "connection failed" in r.messages[0] and "refused" in r.messages[0].lower()
    assert "Modbus unit 8 (cable 42)" in r.messages[7]


def test_missing_serial_device_names_the_reason(make_client):
    client = make_client("rtu:/dev/ttyNO-SUCH-PORT:19200")
    client.poll_once()
    r = client.read()
    assert (r.status == CableStatus.COMM_ERROR).all()
    assert "/dev/ttyNO-SUCH-PORT" in r.messages[0] and "could not open port" in r.messages[0]
