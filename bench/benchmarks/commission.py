"""Commissioning over the socketcand hub: how long an engineer waits for scan, check, monitor.

Against eight simulated drives in another process (``python -m firmware_sim.drive_rig``),
over TCP on 127.0.0.1, as ``cdpr commission`` talks to ``cdpr sim``:

- ``commission_scan_s``: node probe of ids 1..127 (0.1 s listening window) and the identity
  of the eight drives (:func:`hal.scan.scan_nodes`);
- ``commission_check_s``: every object of the HAL's table read and compared, eight drives
  (:func:`hal.sdo_config.compare_configuration`);
- ``commission_monitor_poll_ms``: one refresh of the monitor's drive columns, four SDO
  reads per drive (:meth:`hal.drive_monitor.DriveMonitor.poll`).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import canopen

from bench.benchmarks import median_time, register
from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH
from hal.can_bus import open_bus
from hal.drive_monitor import DriveMonitor
from hal.drives_config import drive_settings
from hal.scan import scan_nodes
from hal.sdo_config import apply_configuration, compare_configuration

ROOT = Path(__file__).resolve().parents[2]


@register("commission")
def bench_commission(quick: bool) -> dict[str, float]:
    """Median seconds of a scan and a check, milliseconds of a monitor refresh (over TCP)."""
    repeat = 3 if quick else 10
    w = load_winches()
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim.drive_rig", "--port", "0", "--stdin-eof-exits"],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        line: list[str] = []
        t = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
        t.start()
        t.join(30.0)
        if not line or not line[0].strip():
            raise RuntimeError("the drive rig did not start")
        net = canopen.Network(open_bus(json.loads(line[0])["can"]))
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
        try:
            scan_s = median_time(lambda: scan_nodes(net, window_s=0.1), repeat, warmup=1)
            nodes = []
            for k, nid in enumerate(int(x) for x in w.node_id):
                node = canopen.RemoteNode(nid, canopen.import_od(str(EDS_PATH), nid))
                net.add_node(node)
                settings = drive_settings(w, k, node.object_dictionary)
                apply_configuration(node, settings, f"node {nid}", store=False)
                nodes.append((node, settings))

            def check() -> None:
                for node, settings in nodes:
                    if compare_configuration(node, settings, f"node {node.id}"):
                        raise RuntimeError("differences right after writing: benchmark invalid")

            check_s = median_time(check, repeat, warmup=1)
            for node, _ in nodes:
                del net[node.id]
            mon = DriveMonitor(net, w, EDS_PATH)
            try:
                poll_s = median_time(mon.poll, repeat * 5, warmup=2)
            finally:
                mon.close()
        finally:
            net.disconnect()
    finally:
        proc.stdin.close()
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)
    return {"commission_scan_s": scan_s, "commission_check_s": check_s,
            "commission_monitor_poll_ms": poll_s * 1e3}
