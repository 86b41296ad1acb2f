"""Real time on a loaded machine: the README's ``cdpr dry-run paper-centre --realtime --rig
process`` while another process keeps one core busy.

- ``realtime_process_completion``: the fraction of ``realtime_process_runs`` runs (5; 3
  with ``--quick``) that completed 10 s of the path (``--duration 10``) at the default
  control rate against ``cdpr sim`` in another process, while a child process this
  benchmark starts (and always kills) spins on one core. A run that ends otherwise (a
  following error on late feedback, a drive that stopped) counts as not completed; what
  ended each is printed on stderr.
- ``realtime_process_sched_fifo``: 1 when the loop's thread ran under SCHED_FIFO (the
  simulator's threads then ask for it one priority below; see
  :mod:`bench.dryrun.realtime`).
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from bench.benchmarks import register

#: trajectory time of each run [s]
DURATION_S = 10.0
ROOT = Path(__file__).resolve().parents[2]


@contextlib.contextmanager
def busy_core() -> Iterator[subprocess.Popen]:
    """A child process spinning on one core inside; killed on the way out, whatever
    happened."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    try:
        yield proc
    finally:
        proc.kill()
        proc.wait()


def realtime_run(duration_s: float = DURATION_S, timeout_s: float = 300.0) -> dict:
    """One ``cdpr dry-run paper-centre --realtime --rig process --duration D --json`` in a
    child process: its JSON object (``ended`` "error" with the stderr's tail when it
    printed none)."""
    cmd = [sys.executable, "-m", "bench.cli", "dry-run", "paper-centre", "--realtime",
           "--rig", "process", "--duration", str(duration_s), "--json", "--quiet"]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout_s)
    try:
        return json.loads(r.stdout)
    except json.JSONDecodeError:
        return {"ended": "error", "message": r.stderr.strip()[-300:]}


@register("realtime_load")
def bench_realtime_load(quick: bool) -> dict[str, float]:
    n = 3 if quick else 5
    done, fifo = 0, False
    for i in range(n):
        with busy_core():
            out = realtime_run()
        fifo = fifo or str(out.get("scheduling") or "").startswith("SCHED_FIFO")
        done += out["ended"] == "completed"
        print(f"bench realtime_load: run {i + 1}/{n}: {out['ended']}"
              f"{': ' + out['message'] if out.get('message') else ''}", file=sys.stderr)
    return {"realtime_process_completion": done / n, "realtime_process_runs": float(n),
            "realtime_process_sched_fifo": float(fifo)}
