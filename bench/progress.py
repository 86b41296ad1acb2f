"""The one progress display of every long command (``cdpr dry-run``, ``cdpr campaign``,
the paper's campaigns, ``cdpr evaluate``, ``cdpr iso9283 --plots``, ``cdpr model check``,
the commissioning motions), on stderr.

On a terminal it is one live line redrawn in place (a bar when the fraction done is known);
into a pipe or a file it is a plain line (no ANSI codes) every few seconds
(:data:`PIPE_PERIOD_S`), never one per update. Two ways to drive it:

- pulled: :meth:`Progress.start` (or ``with``) runs a thread that prints the line every
  period (items done out of the total, the items in flight with their fraction done when a
  progress file gives it);
- pushed: :meth:`Progress.update` sets the fraction, the count or a detail text and prints
  the line when it is due: at once the first time, then at most every
  :data:`TTY_PERIOD_S` on a terminal, every ``period_s`` otherwise (``force``: now, e.g. a
  phase change).

:meth:`Progress.say` prints a line of its own (a start, an item done, an event) without
tearing the progress line. Nothing is printed with ``quiet``.
"""

from __future__ import annotations

import shutil
import sys
import threading
import time
from pathlib import Path

#: seconds between progress lines when stderr is not a terminal
PIPE_PERIOD_S = 5.0
#: seconds between redraws of the live line on a terminal
TTY_PERIOD_S = 0.2
_BAR = 24


def _clock(seconds: float) -> str:
    s = int(max(0.0, seconds))
    if s >= 3600:
        return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
    return f"{s // 60}:{s % 60:02d}"


class Progress:
    """The progress line on stderr: ``title: [bar] 42.0%, done/total <unit> done, <detail>,
    M:SS elapsed, ETA M:SS; running a 40%, b`` (the parts that are known). ``running``
    maps an item's label to its progress file (a fraction as the first word) or None (the
    label alone). ``total`` None: no count. ``period_s``: seconds between lines
    [:data:`TTY_PERIOD_S` pushed / 1 pulled on a terminal, :data:`PIPE_PERIOD_S`
    otherwise]."""

    def __init__(self, title: str, total: int | None, quiet: bool = False, unit: str = "runs",
                 period_s: float | None = None) -> None:
        self.title, self.total, self.quiet, self.unit = title, total, quiet, unit
        self.done = 0
        self.fraction: float | None = None
        self.detail = ""
        self.running: dict[str, str | None] = {}  # label -> progress file (or None)
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self._period = period_s
        self.lines_printed = 0
        self._last: float | None = None  # when update() last printed
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._live = False  # a line drawn in place that the next output must clear

    @property
    def period_s(self) -> float:
        if self._period is not None:
            return self._period
        if not self.tty:
            return PIPE_PERIOD_S
        return 1.0 if self._thread is not None else TTY_PERIOD_S

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

    def _done_fraction(self) -> float | None:
        if self.fraction is not None:
            return min(1.0, max(0.0, self.fraction))
        if self.total:
            return min(1.0, self.done / self.total)
        return None

    def line(self) -> str:
        """The progress line as text (no ANSI codes; the bar only on a terminal)."""
        el = self.elapsed_s()
        head = []
        if self.fraction is not None:
            f = min(1.0, max(0.0, self.fraction))
            n = int(_BAR * f)
            bar = f"[{'█' * n}{'░' * (_BAR - n)}] " if self.tty else ""
            head.append(f"{bar}{100 * f:5.1f}%")
        if self.total is not None:
            head.append(f"{self.done}/{self.total} {self.unit} done")
        if self.detail:
            head.append(self.detail)
        tail = f"{_clock(el)} elapsed"
        f = self._done_fraction()
        if f is not None and 0.0 < f < 1.0 and el > 2.0:
            tail += f", ETA {_clock(el * (1.0 - f) / f)}"
        parts = []
        for label, p in list(self.running.items()):
            if p is None:
                parts.append(label)
                continue
            frac = self._fraction(p)
            if frac is not None and 0.0 < frac < 1.0:
                parts.append(f"{label} {100 * frac:.0f}%")
        return (f"{self.title}: " + "".join(h + ", " for h in head) + tail
                + (f"; running {', '.join(parts)}" if parts else ""))

    def _emit(self, text: str) -> None:
        """Print the progress line (the lock held): in place on a terminal."""
        if self.tty:  # cut to the terminal's width: a wrapped line cannot be redrawn
            width = max(20, shutil.get_terminal_size((200, 24)).columns - 1)
            print("\r\033[K" + text[:width], end="", file=sys.stderr, flush=True)
            self._live = True
        else:
            print(text, file=sys.stderr, flush=True)
        self.lines_printed += 1

    def update(self, fraction: float | None = None, detail: str | None = None,
               done: int | None = None, force: bool = False) -> None:
        """Pushed progress: the fraction done [0, 1], a detail text, the count done (None:
        unchanged); the line is printed when due (see the module), with ``force`` now.
        Reaching a fraction of 1 (or the total) prints once more."""
        if fraction is not None:
            self.fraction = fraction
        if detail is not None:
            self.detail = detail
        if done is not None:
            self.done = done
        if self.quiet or self._thread is not None:
            return
        now = time.perf_counter()
        f = self._done_fraction()
        ended = f is not None and f >= 1.0 and not getattr(self, "_ended", False)
        if ended:
            self._ended = True
        if force or ended or self._last is None or now - self._last >= self.period_s:
            with self._lock:
                self._emit(self.line())
            self._last = now

    def say(self, msg: str) -> None:
        if self.quiet:
            return
        with self._lock:
            print(("\r\033[K" if self._live else "") + msg, file=sys.stderr, flush=True)
            self._live = False

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            with self._lock:
                self._emit(self.line())

    def close(self) -> None:
        """End the display: stop the thread; on a terminal, end the live line."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        with self._lock:
            if self._live:
                print(file=sys.stderr, flush=True)
                self._live = False
