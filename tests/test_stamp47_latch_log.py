"""``cdpr sim --latch-log FILE``: the drives' latches streamed to the file as they come
(bench.commands.sim.LatchLog), the file opened at start (a bad path refused, named)."""

from __future__ import annotations

import subprocess
import sys
import time

from bench.commands.sim import LATCH_FLUSH_S, LatchLog
from tests.test_dryrun_site import ENV


def test_a_latch_log_that_cannot_be_written_is_refused_at_start(tmp_path):
    bad = tmp_path / "no-such-folder" / "latches.csv"
    out = subprocess.run([sys.executable, "-m", "bench.cli", "sim", "paper-centre",
                          "--latch-log", str(bad), "--exit-on-stdin-eof", "--json"],
                         cwd=tmp_path, env=ENV, stdin=subprocess.DEVNULL, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    assert f"--latch-log {bad}" in out.stderr
    assert "--can socketcand" not in out.stdout + out.stderr  # nothing was served


def test_latches_reach_the_file_while_the_sim_runs(tmp_path):
    path = tmp_path / "latches.csv"
    log = LatchLog(str(path))
    try:
        node3, node5 = log.listener(3), log.listener(5)
        now = time.monotonic()
        node3(0.0039, now, 1000)
        node5(0.0039, now, -7)
        node3(0.0078, now + LATCH_FLUSH_S, 1001)  # a second on: flushed with it
        assert path.read_text().splitlines() == [
            "node,drive_t_s,monotonic_s,counts", f"3,0.003900,{now:.6f},1000",
            f"5,0.003900,{now:.6f},-7", f"3,0.007800,{now + LATCH_FLUSH_S:.6f},1001"]
    finally:
        log.close()
    node3(0.0117, now, 1002)  # a drive latching as the sim stops: not written, no error
    assert len(path.read_text().splitlines()) == 4
