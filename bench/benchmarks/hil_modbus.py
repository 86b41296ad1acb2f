"""Load-cell Modbus benchmarks against the in-process simulated cells (127.0.0.1)."""

from __future__ import annotations

import numpy as np

from bench.benchmarks import median_time, register
from firmware_sim.loadcell_server import LoadCellServer
from hal.loadcell_client import LoadCellClient


@register("hil_modbus")
def bench_hil_modbus(quick: bool) -> dict[str, float]:
    """``modbus_read_ms``: one synchronous read of all eight load cells (8 requests of the
    4-register block, Modbus/TCP, in-process server); ``modbus_rtu_tcp_read_ms``: the same
    with RTU framing over TCP; ``loadcell_read_us``: the control cycle's non-blocking
    :meth:`LoadCellClient.read` (status, ages, calibration of the latest values)."""
    tensions = np.linspace(100.0, 2000.0, 8)
    reps = 50 if quick else 500
    out: dict[str, float] = {}
    for key, rtu in (("modbus_read_ms", False), ("modbus_rtu_tcp_read_ms", True)):
        with LoadCellServer(rtu=rtu) as srv:
            srv.update(tensions)
            client = LoadCellClient(srv.endpoint, timeout_s=1.0)
            try:
                out[key] = 1e3 * median_time(client.poll_once, reps, warmup=5)
                if not rtu:
                    srv.update(tensions)  # a fresh sample, as the plant would give
                    client.poll_once()
                    r = client.read()
                    if not r.all_ok:
                        raise RuntimeError(f"load cells not healthy in benchmark: {r.faults()}")
                    out["loadcell_read_us"] = 1e6 * median_time(
                        client.read, reps * 10, warmup=20
                    )
            finally:
                client.stop()
    return out
