"""Every cable watched while a commissioning command moves anything (thin wiring).

:class:`CableGuard` reads all load cells (``--modbus``, polled in a thread by
:class:`hal.loadcell_client.LoadCellClient`) and hands the readings to
:class:`controller.cable_watch.CableWatch`, which decides; the guard is the ``guard`` of
:mod:`hal.motion` (feedback -> None or the reason to stop) and gives the live view its
tensions (:meth:`CableGuard.line`).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.commission.common import (
    CommissionError,
    Ui,
    polling_cells,
    register_map_of,
    tension_window_of,
)
from bench.commission.report import Section

#: what the horizon adds to the stopping time: cell sampling and the plant/physics lag,
#: the decision and a cycle [s]
LATENCY_S = 0.15


def horizon_s(speed_m_s: float, decel_m_s2: float) -> float:
    """How far ahead [s] a tension is extrapolated: the latency plus the quick-stop time
    from ``speed_m_s`` at ``decel_m_s2``."""
    return LATENCY_S + (abs(speed_m_s) / decel_m_s2 if decel_m_s2 > 0 else 0.0)


class CableGuard:
    """All cables' tensions against the window, each motion cycle (see module docstring).

    ``cables``: the winches' cable ids (the order of the verdict); ``horizon``: see
    :func:`horizon_s`.
    """

    def __init__(self, args: argparse.Namespace, cables: tuple[str, ...] | list[str],
                 horizon: float, reader=None) -> None:
        from controller.cable_watch import CableWatch

        self.window = tension_window_of(args)
        self.cables = tuple(cables)
        self.watch = CableWatch(self.window, self.cables, horizon_s=horizon)
        self.tensions = np.full(len(self.cables), np.nan)
        self.statuses: tuple[str, ...] = ()
        self.stop_reason = ""
        self.low = np.full(len(self.cables), np.inf)  #: lowest tension seen per cable [N]
        self.high = np.full(len(self.cables), -np.inf)  #: highest [N]
        rmap = register_map_of(args)
        self._units = [int(rmap.unit_ids[rmap.index_of(c)]) if c in rmap.cables else 0
                       for c in self.cables]
        self.client = None
        if reader is not None:  # readings from elsewhere (the HAL's own cell poller)
            self.read = reader
            return
        self._open_client(args, rmap)

    def _open_client(self, args: argparse.Namespace, rmap) -> None:
        missing = [c for c in self.cables if c not in rmap.cables]
        if missing:
            raise CommissionError(f"load-cell map {rmap.source}: no cell for cable(s) "
                                  f"{', '.join(missing)}: those cables cannot be watched", 2)
        self._idx = [rmap.index_of(c) for c in self.cables]
        self.client = polling_cells(args, rmap)

    def read(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(tensions (n,) [N] in cable order, valid (n,), sample time [s, monotonic])."""
        now = time.monotonic()
        r = self.client.read()
        tau = np.asarray(r.values_N, float)[self._idx]
        ok = np.array([r.status_of(c).name == "OK" for c in self.cables])
        age = np.asarray(r.age_s, float)[self._idx]
        t = now - float(np.min(age)) if np.isfinite(age).any() else now
        return tau, ok, t

    def check(self):
        """One decision now (:class:`controller.cable_watch.Verdict`)."""
        tau, ok, t = self.read()
        v = self.watch.step(t, tau, ok)
        self.tensions, self.statuses = tau, v.statuses
        fin = np.where(ok, tau, np.nan)
        self.low = np.fmin(self.low, fin)
        self.high = np.fmax(self.high, fin)
        if not v.go and not self.stop_reason:
            k = self.cables.index(v.cable) if v.cable in self.cables else -1
            unit = f" (Modbus unit {self._units[k]})" if k >= 0 else ""
            self.stop_reason = v.reason.replace(f"cable {v.cable}:",
                                                f"cable {v.cable}{unit}:", 1)
        return v

    def __call__(self, fb=None) -> str | None:
        """The :mod:`hal.motion` guard: None to go on, else the reason to stop."""
        v = self.check()
        return None if v.go else self.stop_reason

    def line(self) -> str:
        """All tensions for the live view, flagged where out of the window."""
        parts = []
        for k, c in enumerate(self.cables):
            x = self.tensions[k]
            s = self.statuses[k] if k < len(self.statuses) else "ok"
            flag = "" if s == "ok" else f"!{s}"
            parts.append(f"{c}:{'-' if not np.isfinite(x) else f'{x:.0f}'}{flag}")
        return " ".join(parts) + f" N, stop outside {self.window}"

    def summary(self) -> dict:
        """Lowest and highest tension per cable while watched, the window, the stop."""
        def num(x):
            return None if not np.isfinite(x) else round(float(x), 2)
        return {"window_n": [self.window.low_n, self.window.high_n],
                "min_n": {c: num(self.low[k]) for k, c in enumerate(self.cables)},
                "max_n": {c: num(self.high[k]) for k, c in enumerate(self.cables)},
                "stopped": self.stop_reason}

    def close(self) -> None:
        if self.client is not None:
            self.client.stop()


def open_guard(args: argparse.Namespace, ui: Ui, section: Section, cables, horizon: float,
               required: bool) -> CableGuard | None:
    """A :class:`CableGuard` on ``--modbus``; without it None, refused when ``required``
    (a loaded robot is not moved without watching its cables)."""
    if getattr(args, "modbus", None) is None:
        if required:
            raise CommissionError("no --modbus: the cables' tensions cannot be watched; give "
                                  "the load cells (--modbus HOST:PORT), or --platform-supported "
                                  "when the platform rests on its stand", 2)
        ui.progress("warning: no --modbus: the cables' tensions are not watched")
        section.fact("cable watch", "none (no --modbus)")
        return None
    guard = CableGuard(args, cables, horizon)
    section.fact("cable watch", f"every cable, window {guard.window}, horizon {horizon:.2f} s")
    ui.progress(f"watching every cable: motion stops when a tension leaves {guard.window} "
                f"or would within {horizon:.2f} s")
    return guard


__all__ = ["LATENCY_S", "CableGuard", "horizon_s", "open_guard"]
