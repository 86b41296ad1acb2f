"""Replay a CAN log into the HAL's drive decoders: the drive states and events again.

A log (candump ``.log``, ``.asc``, ``.blf``, ``.csv`` through python-can's readers, or the
``/can`` channel of an MCAP recording) holds what the master sent and what the drives
sent. Its frames go, in order, to a :class:`hal.drives_replay.ReplayDrives` (the HAL's
:class:`~hal.drives.WinchDrives` fed frame by frame through its public
:meth:`~hal.drives_replay.ReplayDrives.feed_frame`): at every logged SYNC the HAL takes
what arrived (:meth:`~hal.drives.WinchDrives.receive`), the supervisor looks at it, and
the HAL runs the second half of its cycle (:meth:`~hal.drives.WinchDrives.transmit`,
whose frames go nowhere). Its clock is the SYNC count times the period, as in a lock-step
dry run; the states and events it derives (EMCY faults and their codes, Fault/Quick Stop
transitions, heartbeats lost and back, boot-ups, TPDOs missing or late, drives switched
off) are those of the live run. What the HAL takes from the master's own frames (its
requests in the RPDOs, the answer to its 0x603F read) is described in
:mod:`hal.drives_replay`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from controller.winch import WinchSet
from hal.drives_replay import SYNC_FRAME

#: suffixes python-can reads (can.LogReader)
LOG_SUFFIXES = (".log", ".asc", ".blf", ".csv", ".trc")


class ReplayError(ValueError):
    """A log that cannot be replayed; the message names the file and why."""


def read_log(path: str | Path) -> Iterator[can.Message]:
    """The frames of a CAN log in order: an MCAP recording's ``/can`` channel, else
    python-can's reader of the file's suffix."""
    from bench.mcap import mcap_file, read_can_frames

    p = Path(path)
    if not p.exists():
        raise ReplayError(f"{p}: no such file")
    if mcap_file(p) is not None:
        yield from read_can_frames(p)
        return
    if p.suffix.lower() not in LOG_SUFFIXES:
        raise ReplayError(f"{p}: not a CAN log python-can reads ({', '.join(LOG_SUFFIXES)}) "
                          f"nor an MCAP recording")
    try:
        yield from can.LogReader(str(p))
    except (ValueError, OSError) as exc:
        raise ReplayError(f"{p}: {exc}") from None


def sync_period_of(path: str | Path, syncs: int = 200) -> float | None:
    """The SYNC period [s] of a log: the ``rate_hz`` of an MCAP recording's meta (a dry run
    writes it; its frames carry wall-clock stamps of a lock-step run), else the median
    interval of the first ``syncs`` SYNC frames; None when it has fewer than two."""
    from bench.mcap import mcap_file, read_mcap

    p = Path(path)
    if mcap_file(p) is not None:
        import tomllib

        try:
            rate = tomllib.loads(read_mcap(p).meta_text).get("rate_hz")
        except Exception:  # a /can channel without the recording's rows: by the stamps
            rate = None
        if isinstance(rate, (int, float)) and rate > 0:
            return 1.0 / float(rate)
    stamps = []
    for m in read_log(p):
        if m.arbitration_id == 0x80 and not m.data and not m.is_extended_id:
            stamps.append(float(m.timestamp))
            if len(stamps) > syncs:
                break
    if len(stamps) < 2:
        return None
    return float(np.median(np.diff(stamps)))


@dataclass
class ReplayResult:
    """``events``: the HAL's drive events (dicts: ``t`` [s, SYNC clock from the log's first
    SYNC], ``node``, ``cable``, ``kind``, ``code``, ``text``, ``source``, ``cycle``);
    ``states``: each drive's CiA 402 state changes (``t``, ``node``, ``cable``, ``state``);
    ``final_states`` the states at the end; counts of ``frames`` and ``syncs``; ``log_s``
    the log's span [s, its timestamps], ``wall_s`` the replay's. ``supervisor``: the
    supervisor's events on the drive conditions (``drive_fault``, ``drive_lost``,
    ``drive_disabled``, ``bus``: ``t``, ``device``, ``address``, ``cable``, ``kind``,
    ``code``, ``reaction``, ``active``, ``text``); the log has no tensions nor poses, so
    the load-cell, slack/overload and following-error conditions are not looked at."""

    frames: int = 0
    syncs: int = 0
    events: list[dict[str, Any]] = field(default_factory=list)
    supervisor: list[dict[str, Any]] = field(default_factory=list)
    states: list[dict[str, Any]] = field(default_factory=list)
    final_states: list[str] = field(default_factory=list)
    log_s: float = 0.0
    wall_s: float = 0.0


class _Player:
    """The replay HAL (:class:`hal.drives_replay.ReplayDrives`) and what the replay reads of
    the master's frames: whether the loop expected its drives enabled."""

    def __init__(self, winches: WinchSet, eds: str | Path) -> None:
        from hal.drives_replay import ReplayDrives

        self.drives = ReplayDrives.for_log(winches, eds)
        #: the loop expects its drives enabled (decided at the end of the previous cycle)
        self.expect_enabled = False

    def cycle_done(self) -> None:
        """The second half of the master's cycle; what the loop then expects of the drives
        next cycle: the master's RPDOs so far ask some drive to be enabled and none to
        quick stop (a loop that stops quick-stops them all; one drive switched off by
        someone else keeps the others asked enabled)."""
        d = self.drives
        cw = d.master_controlwords()
        self.expect_enabled = bool(np.any(cw & 0x8F == 0x0F)) and not bool(
            np.any(cw & 0x87 == 0x02))
        d.transmit()

    def close(self) -> None:
        self.drives.close()


def _supervise(sup, pl: _Player, res: ReplayResult,
               on_event: Callable[[dict], None] | None) -> None:
    """One supervisor step on what the drives say (no tensions, no setpoints)."""
    from controller.supervisor import DeviceFault, Observation
    from hal.drives_cia402 import ST

    d = pl.drives
    faults = tuple(DeviceFault("drive", f.node_id, f.cable, f.kind, f.code, f.text)
                   for f in d.faults())
    n = d.n
    ob = Observation(d.now(), np.zeros(n), np.ones(n, bool), np.zeros(n), None,
                     d.states() == ST.OPERATION_ENABLED,
                     expect_enabled=pl.expect_enabled, faults=faults,
                     cables=tuple(d.winches.cables), node_ids=tuple(d.node_ids))
    for e in sup.step(ob).events:
        ev = {"t": round(e.t_s, 6), "device": e.device, "address": e.address,
              "cable": e.cable, "kind": e.kind, "code": e.code, "reaction": e.reaction.label,
              "active": e.active, "text": e.text}
        res.supervisor.append(ev)
        if on_event is not None:
            on_event(ev)


def replay(frames: Iterable[can.Message], winches: WinchSet, eds: str | Path | None = None,
           fast: bool = True, on_event: Callable[[dict], None] | None = None,
           stop: Callable[[], bool] | None = None,
           reactions: dict | None = None, period_s: float | None = None) -> ReplayResult:
    """Play ``frames`` into the HAL (see the module docstring): as fast as possible, or
    with ``fast=False`` at the pace of their timestamps. ``on_event`` gets each drive event,
    state change and supervisor event as it is derived; ``stop()`` true ends the replay
    early; ``reactions`` the supervisor's overrides (``--react``); ``period_s`` the SYNC
    period of the log (:func:`sync_period_of`; default the winch file's)."""
    from controller.supervisor import Supervisor, SupervisorLimits
    from firmware_sim.cia402_drive import EDS_PATH  # the drives' object dictionary

    if period_s is not None:
        from bench.dryrun.world import with_rate

        winches = with_rate(winches, period_s)
    pl = _Player(winches, eds or EDS_PATH)
    sup = Supervisor(SupervisorLimits.for_robot(0.0, np.inf, np.inf), dict(reactions or {}))
    res = ReplayResult()
    res.final_states = pl.drives.state_names()
    wall0 = time.perf_counter()
    t_first = t_last = None
    try:
        for msg in frames:
            if stop is not None and stop():
                break
            ts = float(msg.timestamp)
            if t_first is None:
                t_first = ts
            t_last = ts
            if not fast:
                lag = (ts - t_first) - (time.perf_counter() - wall0)
                if lag > 0:
                    time.sleep(lag)
            res.frames += 1
            if pl.drives.feed_frame(msg) == SYNC_FRAME:
                res.syncs += 1
                _take_cycle(pl, sup, res, on_event)
                pl.cycle_done()
        if res.syncs:  # what answered the last SYNC
            _take_cycle(pl, sup, res, on_event)
    finally:
        pl.close()
    res.wall_s = time.perf_counter() - wall0
    res.log_s = (t_last - t_first) if t_first is not None else 0.0
    return res


def _take_cycle(pl: _Player, sup, res: ReplayResult,
                on_event: Callable[[dict], None] | None) -> None:
    """The first half of the HAL's cycle: what arrived, the events and state changes it
    gives, the supervisor's step on them (into ``res``)."""
    d = pl.drives
    d.receive()
    t = d.now()
    for e in d.events():
        ev = {"t": round(e.time_s, 6), "node": e.node_id, "cable": e.cable, "kind": e.kind,
              "code": e.code, "text": e.text, "source": e.source, "cycle": e.cycle}
        res.events.append(ev)
        if on_event is not None:
            on_event(ev)
    _supervise(sup, pl, res, on_event)
    names = d.state_names()
    for k, (a, b) in enumerate(zip(res.final_states, names, strict=True)):
        if a != b:
            st = {"t": round(t, 6), "node": d.node_ids[k], "cable": d.winches.cables[k],
                  "state": b}
            res.states.append(st)
            if on_event is not None:
                on_event(st)
    res.final_states = names


def drive_events_of_recording(events: Iterable[dict]) -> list[tuple[int, str, int]]:
    """(node, kind, code) of the drives' events of a run's events (``device`` "drive"),
    in order: what a replay of its CAN log must derive again."""
    return [(int(e["address"]), str(e["kind"]), int(e["code"])) for e in events
            if e["device"] == "drive" and e["reaction"] == "event"]


def replay_keys(result: ReplayResult) -> list[tuple[int, str, int]]:
    """(node, kind, code) of a replay's events, in order."""
    return [(int(e["node"]), str(e["kind"]), int(e["code"])) for e in result.events]


def supervisor_keys(events: Iterable[dict]) -> list[tuple[int, str, int, str, bool]]:
    """(address, kind, code, reaction, active) of the supervisor's drive events (a run's
    or a replay's), in order."""
    return [(int(e["address"]), str(e["kind"]), int(e["code"]), str(e["reaction"]),
             bool(e["active"])) for e in events
            if e["device"] in ("drive", "bus") and e["reaction"] != "event"]
