"""One silent load cell must not hold up the others; old values do not pass as OK
(issue 9, defect 5). Counts of answers, not wall-clock deadlines: a silent unit's lane
and the others' run in the same wall time."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from firmware_sim.loadcell_server import LoadCellServer
from hal.loadcell_client import CableStatus, LoadCellClient

T = np.linspace(100.0, 800.0, 8)


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(params=["tcp", "rtu-tcp"])
def server(request):
    srv = LoadCellServer(rtu=request.param == "rtu-tcp").start()
    srv.update(T)
    yield srv
    srv.stop()


def test_a_silent_unit_does_not_slow_the_others(server):
    client = LoadCellClient(server.endpoint, rate_hz=50.0, timeout_s=0.2)
    server.inject("21", "no_answer")
    stop = threading.Event()

    def cells_sample() -> None:  # the cells keep sampling (50 Hz)
        while not stop.wait(0.02):
            server.update(T)

    feeder = threading.Thread(target=cells_sample, daemon=True)
    feeder.start()
    try:
        client.start()
        pollers = [t.name for t in threading.enumerate() if t.name.startswith("loadcell-poll")]
        time.sleep(1.2)
        a0, e0 = client.answers.copy(), client.errors.copy()
        time.sleep(1.0)
        answers = client.answers - a0
        tries = client.errors[2] - e0[2]
        r = client.read()
    finally:
        client.stop()
        stop.set()
        feeder.join(5)
    others = np.delete(answers, 2)
    assert answers[2] == 0 and r.status[2] == CableStatus.TIMEOUT
    assert "Modbus unit 3 (cable 21)" in r.messages[2]
    # a sweep with the silent unit in it would take 0.2 s: as many answers as it has tries
    assert np.all(others >= 4 * (tries + 1)), (others, tries)
    assert np.all(np.delete(r.status, 2) == CableStatus.OK), r.faults()
    # on one line, and polled together over per-unit connections, the silent unit is
    # asked only every retry_s
    assert tries <= 1.0 / client.retry_s + 1, tries
    assert len(pollers) == 1, pollers  # one thread, whatever the connections


def test_per_unit_connections_on_tcp_only():
    assert LoadCellClient("127.0.0.1:5020").connections == "per_unit"
    assert LoadCellClient("rtu-tcp:127.0.0.1:5020").connections == "shared"
    with pytest.raises(ValueError, match="shared line"):
        LoadCellClient("rtu-tcp:127.0.0.1:5020", connections="per_unit")


def test_values_turn_stale_by_age_without_waiting_for_their_turn(server):
    """A hung server: nothing answers any more; the values already read must not stay OK
    for long, whether or not the poller got round to them."""
    clock = FakeClock()
    client = LoadCellClient(server.endpoint, clock=clock, rate_hz=50.0, timeout_s=0.1)
    try:
        client.poll_once()
        assert client.read().all_ok
        clock.t += 0.15  # < one timeout plus three poll periods
        assert client.read().all_ok
        clock.t += 0.02  # no poll happened (a hung server): 0.17 s old
        r = client.read()
        assert np.all(r.status == CableStatus.TIMEOUT) and np.all(np.isnan(r.values_N))
        assert "no fresh answer for 0.170 s (limit 0.16 s" in r.messages[4]
    finally:
        client.stop()
