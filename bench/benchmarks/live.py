"""The loop's timing with the live view and an MCAP recording: the README's real-time dry
run against ``cdpr sim`` in another process (``cdpr dry-run paper-centre --realtime --rig
process --duration 5``), with ``--record DIR --format mcap --live 127.0.0.1:0`` and a
Foxglove WebSocket client (in this process) subscribed to every channel, and without them.

- ``realtime_rate_hz_live`` / ``deadline_miss_ratio_live``: the highest rate tried (the
  bus-load limit, then 200, 150, 100, 50 Hz) at which the run with the live view and the
  MCAP recording missed at most 0.1 % of its deadlines (overruns per cycle), and the ratio
  at that rate (one run per rate; a run that ended early missed every deadline);
- ``realtime_rate_hz_plain`` / ``deadline_miss_ratio_plain``: the same without them;
- ``live_messages_received``: the messages the client received in the run at the live
  rate (0: the view showed nothing).

A few seconds of path per run: the figures compare the two, they are no 60 s statistics
(``realtime_rate_hz`` of the ``dryrun`` group is).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.benchmarks import register
from bench.benchmarks.dryrun import FALLBACK_RATES, MISS_GOAL

#: trajectory time of each run [s]
DURATION_S = 5.0
ROOT = Path(__file__).resolve().parents[2]
_ADDRESS = re.compile(r"Foxglove live view: ws://([\d.]+):(\d+)")


def realtime_run(rate_hz: float | None, live: bool, duration_s: float = DURATION_S,
                 timeout_s: float = 300.0) -> tuple[dict, int]:
    """One real-time ``--rig process`` dry run in a child process, with ``live`` also
    ``--record --format mcap --live 127.0.0.1:0`` and a subscribed client: (its JSON object,
    the messages the client received). The JSON has ``ended`` "error" when it printed
    none."""
    with tempfile.TemporaryDirectory(prefix="cdpr-bench-live-") as tmp:
        cmd = [sys.executable, "-m", "bench.cli", "dry-run", "paper-centre", "--realtime",
               "--rig", "process", "--duration", str(duration_s), "--json", "--quiet"]
        cmd += ["--rate", f"{rate_hz:g}"] if rate_hz is not None else []
        cmd += ["--record", str(Path(tmp) / "rec"), "--format", "mcap", "--live",
                "127.0.0.1:0"] if live else []
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        client = _Client() if live else None
        err: list[str] = []
        reader = threading.Thread(target=_read_stderr, args=(proc, err, client), daemon=True)
        reader.start()  # (stderr is the reader's alone: the address line starts the client)
        killer = threading.Timer(timeout_s, proc.kill)
        killer.start()
        try:
            assert proc.stdout is not None
            out = proc.stdout.read()
            proc.wait()
        finally:
            killer.cancel()
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            reader.join(5)
            received = client.stop() if client is not None else 0
    try:
        return json.loads(out), received
    except json.JSONDecodeError:
        return {"ended": "error", "message": "".join(err)[-300:]}, received


def _read_stderr(proc: subprocess.Popen, err: list[str], client) -> None:
    assert proc.stderr is not None
    for line in proc.stderr:
        err.append(line)
        m = _ADDRESS.search(line)
        if m and client is not None:
            client.start(int(m.group(2)))


class _Client:
    """A Foxglove WebSocket client (tornado) subscribed to every channel advertised,
    counting the messages it receives, in a thread of its own."""

    def __init__(self) -> None:
        self.received = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, port: int) -> None:
        self._thread = threading.Thread(target=self._run, args=(port,), daemon=True)
        self._thread.start()

    def stop(self) -> int:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10)
        return self.received

    def _run(self, port: int) -> None:
        try:
            from tornado import ioloop
        except ImportError:  # no client: the view is served, none watches
            return
        try:
            ioloop.IOLoop(make_current=False).run_sync(lambda: self._go(port), timeout=600)
        except Exception as exc:  # the server went away with the run
            print(f"bench live: client: {exc}", file=sys.stderr)

    async def _go(self, port: int) -> None:
        from tornado import websocket

        ws = await websocket.websocket_connect(f"ws://127.0.0.1:{port}",
                                               subprotocols=["foxglove.sdk.v1"])
        subscribed: set[int] = set()
        while not self._stop.is_set():
            msg = await ws.read_message()  # None when the run's server stops
            if msg is None:
                break
            if isinstance(msg, str):
                m = json.loads(msg)
                if m.get("op") == "advertise":
                    subs = [{"id": len(subscribed) + i, "channelId": ch["id"]}
                            for i, ch in enumerate(m["channels"]) if ch["id"] not in subscribed]
                    subscribed.update(ch["id"] for ch in m["channels"])
                    await ws.write_message(json.dumps({"op": "subscribe",
                                                       "subscriptions": subs}))
            else:
                self.received += 1
        ws.close()


def _rate_search(live: bool) -> tuple[float, float, int]:
    """(rate [Hz], miss ratio, messages received) of the highest rate kept (see the module
    docstring); (0, the last ratio, ...) when none was."""
    rates: list[float | None] = [None]  # the bus-load limit, then the lower fallbacks
    miss, received = 1.0, 0
    while rates:
        rate = rates.pop(0)
        out, received = realtime_run(rate, live)
        ended = out.get("ended")
        cycles = max(int(out.get("cycles") or 0), 1)
        miss = float(out.get("overruns", cycles)) / cycles if ended == "completed" else 1.0
        print(f"bench live: {'live+mcap' if live else 'plain'} at "
              f"{out.get('rate_hz', rate)} Hz: {ended}, miss ratio {miss:.4f}"
              + (f" ({out['message']})" if out.get("message") else "")
              + (f", {received} messages received" if live else ""), file=sys.stderr)
        if ended == "completed" and miss <= MISS_GOAL:
            return float(out["rate_hz"]), miss, received
        if rate is None:
            top = float(out.get("rate_hz") or max(FALLBACK_RATES) + 1)
            rates = [r for r in FALLBACK_RATES if r < top]
    return 0.0, miss, received


@register("live")
def bench_live(quick: bool) -> dict[str, float]:
    t0 = time.monotonic()
    rate_p, miss_p, _ = _rate_search(False)
    rate_l, miss_l, received = _rate_search(True)
    print(f"bench live: {time.monotonic() - t0:.0f} s", file=sys.stderr)
    return {"realtime_rate_hz_live": rate_l, "deadline_miss_ratio_live": miss_l,
            "realtime_rate_hz_plain": rate_p, "deadline_miss_ratio_plain": miss_p,
            "live_messages_received": float(received)}
