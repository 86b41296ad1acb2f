"""A bounded history of device events kept by severity: a flood of one kind never evicts
another.

Three classes, each with its own bound and its own count of what was dropped:

- ``fault``: an EMCY that is a fault (any code but 0x0000 and the communication warnings
  0x81xx / 0x82xx), a drive that stops answering;
- ``nmt``: a boot-up (the node was reset or powered on: its configuration is gone);
- ``warning``: communication warnings (0x81xx RPDO / heartbeat, 0x82xx PDO), error resets
  (0x0000), a drive answering again.

A warning flood drops the oldest warnings, never a fault or a boot-up. The events come
back in time order (:meth:`SeverityLog.items`), and :meth:`SeverityLog.dropped` says how
many of each class were dropped.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterator
from typing import Any

FAULT = "fault"
NMT = "nmt"
WARNING = "warning"
SEVERITIES = (FAULT, NMT, WARNING)


def emcy_severity(code: int) -> str:
    """``fault`` or ``warning`` for an EMCY error code (0x0000: error reset, a warning)."""
    if code == 0 or code >> 8 in (0x81, 0x82):
        return WARNING
    return FAULT


class SeverityLog:
    """Events by severity, ``max_per_class`` kept of each (the newest). Thread-safe.

    Each event is any object with a ``wall_time`` [s] (the time order) and an optional
    ``severity`` attribute (else ``append(event, severity)`` says it).
    """

    def __init__(self, max_per_class: int = 50) -> None:
        if max_per_class < 1:
            raise ValueError(f"max_per_class must be >= 1, got {max_per_class}")
        self.maxlen = int(max_per_class)
        self._lock = threading.Lock()
        self._seq = 0
        self._q: dict[str, deque] = {s: deque(maxlen=self.maxlen) for s in SEVERITIES}
        self._dropped = dict.fromkeys(SEVERITIES, 0)

    def append(self, event: Any, severity: str | None = None) -> None:
        sev = severity or getattr(event, "severity", WARNING)
        if sev not in self._q:
            raise ValueError(f"severity {sev!r}: expected one of {', '.join(SEVERITIES)}")
        with self._lock:
            q = self._q[sev]
            if len(q) == q.maxlen:
                self._dropped[sev] += 1
            q.append((self._seq, event))
            self._seq += 1

    def items(self, severity: str | None = None) -> list[Any]:
        """The kept events in the order they came (of one class, or all)."""
        with self._lock:
            pairs = [p for s in SEVERITIES if severity in (None, s) for p in self._q[s]]
        return [e for _, e in sorted(pairs, key=lambda p: p[0])]

    def dropped(self) -> dict[str, int]:
        """How many of each class were dropped for the bound."""
        with self._lock:
            return dict(self._dropped)

    def __iter__(self) -> Iterator[Any]:
        return iter(self.items())

    def __len__(self) -> int:
        with self._lock:
            return sum(len(q) for q in self._q.values())


__all__ = ["FAULT", "NMT", "SEVERITIES", "WARNING", "SeverityLog", "emcy_severity"]
