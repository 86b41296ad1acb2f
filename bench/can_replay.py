"""Replay a CAN log into the HAL's drive decoders: the drive states and events again.

A log (candump ``.log``, ``.asc``, ``.blf``, ``.csv`` through python-can's readers, or the
``/can`` channel of an MCAP recording) holds what the master sent (SYNC, RPDOs, NMT, SDO
requests, its heartbeat) and what the drives sent (TPDOs, EMCYs, heartbeats, SDO answers).
The player sends the drives' frames on a python-can ``virtual`` bus, delivered in its own
thread (:mod:`bench.dryrun.lockstep_bus`), to a :class:`hal.drives.WinchDrives` listening on
that bus as the master did: at every logged SYNC the HAL takes what arrived
(:meth:`~hal.drives.WinchDrives.receive`) and runs its cycle
(:meth:`~hal.drives.WinchDrives.transmit`, whose frames go nowhere). Its clock is the SYNC
count times the period (``clock="sync"``), as in a lock-step dry run; the states and events
it derives (EMCY faults and their codes, Fault/Quick Stop transitions, heartbeats lost and
back, boot-ups, TPDOs missing or late) are those of the live run.

The HAL is put in the state it has after :meth:`~hal.drives.WinchDrives.start` without any
traffic (no NMT, no SDO: the log's drives were started already); the master's requests are
taken from the logged RPDOs (a quick-stop controlword is the master's, not a drive stopping
on its own); the background 0x603F read the HAL makes on a fault is answered by the logged
SDO answer, not asked again. This module reaches into the HAL's private state for that (the
one place that does; its tests fail if the HAL changes under it).
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from controller.winch import WinchSet

#: suffixes python-can reads (can.LogReader)
LOG_SUFFIXES = (".log", ".asc", ".blf", ".csv", ".trc")


class ReplayError(ValueError):
    """A log that cannot be replayed; the message names the file and why."""


def read_log(path: str | Path) -> Iterator[can.Message]:
    """The frames of a CAN log in order: an MCAP recording's ``/can`` channel, else
    python-can's reader of the file's suffix."""
    from bench.mcap_record import mcap_file, read_can_frames

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
    from bench.mcap_record import mcap_file, read_mcap

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
    """The HAL on a virtual bus and the sender of the logged drive frames."""

    def __init__(self, winches: WinchSet, eds: str | Path) -> None:
        import canopen

        from bench.dryrun.lockstep_bus import deliver_in_sender_thread
        from hal.can_bus import open_bus
        from hal.drives import NMT_OPERATIONAL, WinchDrives
        from hal.drives_cia402 import RQ

        channel = f"virtual:replay-{os.getpid()}-{id(self):x}"
        bus = open_bus(channel)
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.05
        self.network.connect()
        deliver_in_sender_thread(self.network)
        self.sender = open_bus(channel)
        d = self.drives = WinchDrives(self.network, winches, eds, clock="sync",
                                      bus_name=f"replay of {channel}")
        d._confirm_fault_code = lambda k: None  # answered from the log (see the docstring)
        now = d.now()
        d._started[:] = True  # as after start(): configured and NMT started
        d._armed[:] = False
        d._hb_last[:] = now
        d._rx_hb_t[:] = now
        d._nmt[:] = NMT_OPERATIONAL
        d._nmt_wait[:] = now + max(d.hb_timeout_s, d.period_s)
        self.rq = RQ
        self.master_enabled = np.zeros(d.n, bool)  #: the master asks Operation Enabled
        self.index = {nid: k for k, nid in enumerate(d.node_ids)}
        self.rpdo = d._rpdo

    def frame(self, msg: can.Message) -> None:
        """Hand one logged frame to the HAL (the drives' frames) or read the master's."""
        cid, d = msg.arbitration_id, self.drives
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return
        fn, node = cid & 0x780, cid & 0x7F
        k = self.index.get(node)
        if cid == 0x80 and not msg.data:  # SYNC: the master's cycle (replay() runs it)
            return
        elif k is None:
            return
        elif fn in (0x180, 0x080, 0x700):  # TPDO, EMCY, heartbeat of a drive
            self.sender.send(msg)
        elif fn == 0x200 and len(msg.data) >= self.rpdo.size:  # the master's RPDO
            cw = self.rpdo.unpack_from(bytes(msg.data))[0]
            self.master_enabled[k] = cw & 0x8F == 0x0F
            if cw & 0x8F == 0x0F:
                d._request[k] = self.rq.ENABLE
            elif cw & 0x87 == 0x02:
                d._request[k] = self.rq.QUICK_STOP
        elif fn == 0x580 and len(msg.data) == 8:  # SDO answer: 0x603F read of a fault
            cmd, index, sub = msg.data[0], *struct.unpack_from("<HB", msg.data, 1)
            if index == 0x603F and sub == 0:
                if cmd & 0xE0 == 0x40:
                    code = struct.unpack_from("<H", msg.data, 4)[0]
                    d._queue.append(("603f", k, code, ""))
                elif cmd == 0x80:
                    abort = struct.unpack_from("<I", msg.data, 4)[0]
                    d._queue.append(("603f", k, None, f"SDO abort 0x{abort:08X}"))

    def transmit(self) -> None:
        """The second half of the HAL's cycle (after :meth:`WinchDrives.receive` and what
        looks at its result): its clock advances one SYNC."""
        self.drives.transmit()
        while self.sender.recv(0) is not None:  # the HAL's own RPDOs and SYNC: dropped
            pass

    def close(self) -> None:
        try:
            self.drives.close()
        finally:
            self.network.disconnect()
            self.sender.shutdown()


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
                     expect_enabled=bool(pl.master_enabled.all()), faults=faults,
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
            pl.frame(msg)
            if msg.arbitration_id == 0x80 and not msg.data and not msg.is_extended_id:
                res.syncs += 1
                _take_cycle(pl, sup, res, on_event)
                pl.transmit()
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
