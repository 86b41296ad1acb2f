"""The operator's keys: stdin read in a thread, one input per key (or key repeat).

On a terminal stdin is switched to cbreak mode (no Enter needed, no echo) and restored at
the end; from a pipe every character counts the same way, so a script or a test feeds
``+++++`` and the stream's end is the end of the input. Keys:

=============  ======================================
``+`` ``=``    jog out (pay cable out: longer)
``-`` ``_``    jog in (reel cable in: shorter)
space ``s``    stop (halt)
``q`` Ctrl-D   quit (halt, disable, end)
Enter          (enable) end the hold
=============  ======================================
"""

from __future__ import annotations

import os
import queue
import sys
import threading
from contextlib import contextmanager
from typing import IO

from hal.motion import JogInput

KEYMAP = {"+": JogInput.OUT, "=": JogInput.OUT, "-": JogInput.IN, "_": JogInput.IN,
          " ": JogInput.STOP, "s": JogInput.STOP, "q": JogInput.QUIT, "Q": JogInput.QUIT,
          "\x04": JogInput.QUIT, "\n": JogInput.QUIT, "\r": JogInput.QUIT}


class KeyReader:
    """Reads ``stream`` in a daemon thread; :meth:`poll` returns the latest input or None.

    ``enter_quits``: Enter ends (enable/hold); else newlines are ignored (piped jog keys).
    """

    def __init__(self, stream: IO[str] | None = None, enter_quits: bool = False) -> None:
        self.stream = stream if stream is not None else sys.stdin
        self.enter_quits = enter_quits
        self._q: queue.Queue[JogInput] = queue.Queue()
        self.keys = 0
        self._thread = threading.Thread(target=self._run, name="keys", daemon=True)

    def start(self) -> KeyReader:
        self._thread.start()
        return self

    def _read_char(self) -> str:
        try:
            fd = self.stream.fileno()
        except (AttributeError, OSError, ValueError):
            return self.stream.read(1)
        data = os.read(fd, 1)  # unbuffered: each key as it comes
        return data.decode("latin-1") if data else ""

    def _run(self) -> None:
        while True:
            try:
                ch = self._read_char()
            except (OSError, ValueError):
                ch = ""
            if not ch:
                self._q.put(JogInput.EOF)
                return
            if ch in "\r\n" and not self.enter_quits:
                continue
            cmd = KEYMAP.get(ch)
            if cmd is not None:
                self.keys += 1
                self._q.put(cmd)

    def poll(self) -> JogInput | None:
        """The latest input since the last call (a stop or quit wins over motion keys)."""
        last = None
        while True:
            try:
                cmd = self._q.get_nowait()
            except queue.Empty:
                return last
            if last in (JogInput.QUIT, JogInput.EOF):
                continue
            if last is JogInput.STOP and cmd in (JogInput.OUT, JogInput.IN):
                last = cmd  # a key pressed after the stop key
                continue
            last = cmd


@contextmanager
def cbreak(stream: IO[str] | None = None):
    """Terminal in cbreak mode while inside (no-op when not a terminal)."""
    s = stream if stream is not None else sys.stdin
    try:
        fd = s.fileno()
        tty_ = os.isatty(fd)
    except (AttributeError, OSError, ValueError):
        tty_ = False
    if not tty_:
        yield
        return
    import termios
    import tty

    old = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)
