"""The progress line on stderr of a long job (the paper's campaigns, ``cdpr evaluate``,
``cdpr iso9283 --plots``, ``cdpr model check``): items done out of the total, elapsed time,
the items in flight (with their fraction done when a progress file gives it), refreshed
in place every second on a terminal and printed every 15 s otherwise; :meth:`Progress.say`
prints a line of its own (a start, an item done) without tearing the progress line."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path


class Progress:
    """The progress line on stderr: ``title: done/total <unit> done, M:SS elapsed; running
    a 40%, b``. ``running`` maps an item's label to its progress file (a fraction as the
    first word) or None (the label alone). ``total`` None: one job, no count (``title: M:SS
    elapsed``). Nothing is printed with ``quiet``. ``period_s``: seconds between progress
    lines [1 on a terminal, 15 otherwise]."""

    def __init__(self, title: str, total: int | None, quiet: bool = False, unit: str = "runs",
                 period_s: float | None = None) -> None:
        self.title, self.total, self.quiet, self.unit = title, total, quiet, unit
        self.done = 0
        self.running: dict[str, str | None] = {}  # label -> progress file (or None)
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.period_s = period_s if period_s is not None else (1.0 if self.tty else 15.0)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> Progress:
        if not self.quiet:
            self._thread = threading.Thread(target=self._run, name="progress", daemon=True)
            self._thread.start()
        return self

    def __enter__(self) -> Progress:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def elapsed_s(self) -> float:
        return time.perf_counter() - self.t0

    def _fraction(self, path: str) -> float | None:
        try:
            return float(Path(path).read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return None

    def line(self) -> str:
        el = self.elapsed_s()
        parts = []
        for label, p in list(self.running.items()):
            if p is None:
                parts.append(label)
                continue
            f = self._fraction(p)
            if f is not None and 0.0 < f < 1.0:
                parts.append(f"{label} {100 * f:.0f}%")
        count = "" if self.total is None else f"{self.done}/{self.total} {self.unit} done, "
        return (f"{self.title}: {count}{int(el // 60)}:{int(el % 60):02d} elapsed"
                + (f"; running {', '.join(parts)}" if parts else ""))

    def say(self, msg: str) -> None:
        if self.quiet:
            return
        with self._lock:
            print(("\r\033[K" if self.tty else "") + msg, file=sys.stderr, flush=True)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            with self._lock:
                text = self.line()
                if self.tty:
                    print("\r\033[K" + text[:200], end="", file=sys.stderr, flush=True)
                else:
                    print(text, file=sys.stderr, flush=True)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
            if self.tty:
                print("\r\033[K", end="", file=sys.stderr, flush=True)
