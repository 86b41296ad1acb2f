"""A real-time dry run against ``cdpr sim`` in another process on a loaded machine.

The simulator follows the master's SYNC (a HIL simulator: its drives' deadlines are in SYNC
periods, so its own starvation delays the simulated world instead of tripping them) and
runs its threads in SCHED_FIFO below the loop when permitted; the loop's HAL threads run
one priority below the loop. ``bench.benchmarks.realtime_load`` measures the completion
rate; here one short run must complete while another process keeps a core busy.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_sim_drive import START_COUNTS, Harness
from test_sim_drive_master_loss import watch_master

from bench.benchmarks.realtime_load import busy_core
from bench.cli import main
from firmware_sim.cia402_drive import State

ROOT = Path(__file__).resolve().parents[1]


def test_a_sync_driven_drive_counts_its_rpdo_deadline_in_sync_periods():
    """A SYNC and its RPDO handled 60 ms of wall time late (a starved simulator; the
    deadline is 20 ms) are one period of drive time: nothing trips. A missing RPDO between
    SYNCs still does (tests/test_sim_drive_master_loss.py)."""
    h = Harness()
    try:
        watch_master(h)
        h.w(0x1400, 1, 0x201 | 1 << 31)
        h.w(0x1400, 5, 20)  # 20 ms deadline, SYNC every 4 ms
        h.w(0x1400, 1, 0x201)
        h.enable_csp()
        for _ in range(5):
            h.net.send_message(0x700 + 127, b"\x05")  # the master lives (0x1016, 250 ms)
            h.rpdo(0x0F, START_COUNTS)
            h.sync()
            t_end = time.monotonic() + 0.06
            while time.monotonic() < t_end:  # the bank's ticker runs meanwhile
                h.drive.wall_tick(time.monotonic())
                time.sleep(0.01)
        h.barrier()
        assert h.drive.state == State.OPERATION_ENABLED
        assert 0x8250 not in h.emcy_codes()
    finally:
        h.close()


def test_sim_rt_priority_out_of_range_exit_2(capsys):
    assert main(["sim", "--rt-priority", "1000"]) == 2
    assert "--rt-priority 1000: thread priority must be 0 (normal) to" in capsys.readouterr().err
    assert main(["sim", "--rt-priority", "-1", "--json"]) == 2
    assert "--rt-priority -1" in json.loads(capsys.readouterr().out)["error"]


def test_busy_core_is_killed_on_the_way_out():
    with busy_core() as proc:
        assert proc.poll() is None
    assert proc.poll() is not None
    with pytest.raises(RuntimeError), busy_core() as proc:
        raise RuntimeError("the run failed")
    assert proc.poll() is not None


@pytest.mark.slow
def test_realtime_process_dry_run_completes_with_a_core_busy():
    cmd = [sys.executable, "-m", "bench.cli", "dry-run", "paper-centre", "--realtime",
           "--rig", "process", "--duration", "3", "--json", "--quiet"]
    with busy_core():
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=180)
    out = json.loads(r.stdout)
    assert r.returncode == 0 and out["ended"] == "completed", (out["message"], r.stderr[-2000:])
    assert out["trajectory_s"] >= 3.0
    rpdo = [e for e in out["events"] if e["code"] == 0x8250 and e["device"] == "drive"]
    assert not rpdo, rpdo  # no drive missed its RPDO deadline
