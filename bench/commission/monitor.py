"""``cdpr commission monitor``: a live table of the drives, the load cells and the bus.

Read-only (:class:`hal.drive_monitor.DriveMonitor`: SDO reads, heartbeats, EMCYs; the load
cells polled by :class:`hal.loadcell_client.LoadCellClient`), so it runs beside the
controller as well as on an idle bus. Every ``1/--rate`` seconds: per winch the NMT state,
CiA 402 state, cable length, speed, torque (and current when the EDS has 0x6078) and
tension with its status and age; the bus load over the last second (frames heard plus ours,
worst-case bit stuffing, at the winch file's bit rate) and the last errors (EMCY, drives or
cells that stop answering). On a terminal the table refreshes in place (ANSI); otherwise a
block of plain lines per refresh.

``--record DIR`` writes a ``cdpr-recording/1`` as it goes (``t``, ``l_meas_*``, ``tau_*``,
``vel_*`` [m/s], ``torque_*`` [N m], ``drive_state_*`` (CiA 402 state number), and
``current_*`` [per mille] when read; ``events.csv``: the events below, device ``drive``,
reaction ``event``); its ``init_pose`` is ``--init-pose`` or the forward kinematics of the
first sample (said in its notes). ``--format mcap`` writes it as ``DIR/recording.mcap``
instead (``both``: the two), with every CAN frame heard and sent on ``/can``
(:mod:`bench.mcap`); ``--live [HOST:PORT]`` serves the same channels to Foxglove
(``/can`` included). ``--candump FILE`` logs every CAN frame, heard and sent, with
python-can's Logger (.asc, .blf, .log, .csv by the suffix).
``--duration S`` ends it; else Ctrl-C or ``q`` (exit status 0, files closed).

A valid tension outside the window (``--tension-window``, else the supervisor's) shows as
``slack`` or ``overload``, never ``ok`` (:func:`controller.cable_watch.classify_tensions`).
``--json-lines`` writes one JSON object per refresh on stdout (the table then goes to
stderr): ``t_s``, ``drives``, ``load_cells``, ``bus_load``, ``frames``, ``events_new``.
The events (EMCYs, boot-ups, drives that stop answering) are kept by severity
(:class:`hal.event_log.SeverityLog`): a flood of warnings never evicts a fault or a
boot-up; what was dropped is counted.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

import numpy as np

from bench.commission.common import (
    CommissionError,
    Ui,
    network_of,
    polling_cells,
    register_map_of,
    tension_window_of,
    winches_of,
)
from bench.commission.report import Section
from bench.parallel import raise_pending
from hal.event_log import SEVERITIES

STATE_SHORT = {"NOT_READY_TO_SWITCH_ON": "not ready", "SWITCH_ON_DISABLED": "disabled",
               "READY_TO_SWITCH_ON": "ready", "SWITCHED_ON": "switched on",
               "OPERATION_ENABLED": "ENABLED", "QUICK_STOP_ACTIVE": "QUICK STOP",
               "FAULT_REACTION_ACTIVE": "FAULT REACT", "FAULT": "FAULT", "UNKNOWN": "?"}


class _FrameSink:
    """CAN frames (heard and sent) for ``/can`` (the recording's, the live view's): those
    before the recording opens (it opens with the first sample) are kept, at most ``limit``,
    and handed over when it does (:meth:`attach`); after :meth:`detach` none."""

    def __init__(self, limit: int = 100_000) -> None:
        self.lock = threading.Lock()
        self.pending: list | None = []
        self.limit = limit
        self.target = None

    def __call__(self, msg) -> None:
        with self.lock:
            if self.target is not None:
                self.target(msg)
            elif self.pending is not None and len(self.pending) < self.limit:
                self.pending.append(msg)

    def attach(self, target) -> None:
        with self.lock:
            for m in self.pending or []:
                target(m)
            self.pending, self.target = None, target

    def detach(self) -> None:
        with self.lock:
            self.pending, self.target = None, None


def record_event(writer, e, wall_t0: float) -> None:
    """A :class:`hal.drive_monitor.MonitorEvent` as a recording's event (``t`` [s] since
    ``wall_t0``, the wall time of the first refresh; reaction ``event``: the monitor does
    not react)."""
    writer.event(e.wall_time - wall_t0, "drive", e.node_id, e.cable, e.kind, e.code, "event",
                 e.kind != "sdo_resumed", e.text)


class _LockedLogger:
    """python-can's Logger fed from two threads: the notifier (frames heard) and ours
    (frames sent, which the bus does not hand back)."""

    def __init__(self, logger) -> None:
        self.logger = logger
        self.lock = threading.Lock()

    def on_message_received(self, msg) -> None:
        with self.lock:
            self.logger.on_message_received(msg)

    __call__ = on_message_received

    def on_error(self, exc: Exception) -> None:
        pass

    def stop(self) -> None:
        with self.lock:
            self.logger.stop()


def _fmt(v, spec: str, none: str = "-") -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return none
    return format(v, spec)


def cell_status(reading, j: int, cable: str, window) -> str:
    """A load cell's status: the client's (timeout, stale, ...) or, for a valid reading,
    ``ok`` / ``slack`` / ``overload`` against the tension window."""
    from controller.cable_watch import classify_tensions

    st = reading.status_of(cable).name.lower()
    if st != "ok":
        return st
    return classify_tensions([reading.values_N[j]], window)[0]


def cells_json(reading, window) -> list[dict]:
    """The load cells as JSON rows."""
    if reading is None:
        return []
    return [{"device_id": int(reading.unit_ids[j]), "cable": c,
             "tension_n": None if not np.isfinite(reading.values_N[j])
             else float(reading.values_N[j]),
             "status": cell_status(reading, j, c, window),
             "age_s": float(reading.age_s[j]) if np.isfinite(reading.age_s[j]) else None}
            for j, c in enumerate(reading.cables)]


def render(samples, reading, rmap, load: float, frames: int, events, header: str,
           has_current: bool, window=None, stream=None) -> list[str]:
    """The table's lines (``window``: the tension window the cells' status is judged by;
    None: the client's status only; ``stream``: where they go, styled if a terminal)."""
    from bench.tables import col
    from bench.tables import render as table

    lines = [header + f"  bus load {load * 100:5.1f} %  frames {frames}"]
    cols = [col("cable"), col("node"), col("NMT", justify="left"), col("state", justify="left"),
            col("length", "m"), col("v", "m/s"), col("torque", "‰")]
    cols += [col("current", "‰")] if has_current else []
    cols += [col("tension", "N"), col("status", justify="left"), col("age", "s")]
    rows = []
    for s in samples:
        state = STATE_SHORT.get(s.state, s.state)
        if s.error_code:
            state += f" {s.error_code:04X}"
        tension, status, age = "-", "-", "-"
        if reading is not None:
            j = rmap.index_of(s.cable) if s.cable in rmap.cables else None
            if j is not None:
                tension = _fmt(float(reading.values_N[j]), ".1f")
                status = (reading.status_of(s.cable).name.lower() if window is None
                          else cell_status(reading, j, s.cable, window))
                age = _fmt(float(reading.age_s[j]), ".2f")
        rows.append([s.cable, s.node_id, (s.nmt_state or "-")[:8], state,
                     _fmt(s.length_m, ".4f"), _fmt(s.velocity_m_s, ".4f"),
                     _fmt(s.torque_permille, "d")]
                    + ([_fmt(s.current_permille, "d")] if has_current else [])
                    + [tension, status, age])
    lines += table(cols, rows, stream=stream, indent=0).split("\n")
    notes = [str(e) for e in events]
    if reading is not None:
        notes += reading.faults()[:3]
    lines.append("last errors: " + ("none" if not notes else ""))
    lines += [f"  {n}" for n in notes[-6:]]
    return lines


class _Screen:
    """Redraws in place on a terminal, else prints each block."""

    def __init__(self, out) -> None:
        self.out = out
        self.tty = hasattr(out, "isatty") and out.isatty()
        self.n = 0

    def show(self, lines: list[str]) -> None:
        if self.tty:
            up = f"\x1b[{self.n}F" if self.n else ""
            self.out.write(up + "\x1b[J" + "\n".join(lines) + "\n")
        else:
            self.out.write("\n".join(lines) + "\n\n")
        self.out.flush()
        self.n = len(lines)


def _init_pose(args, robot, lengths: np.ndarray) -> tuple[np.ndarray, str]:
    if args.init_pose:
        try:
            v = [float(x) for x in args.init_pose.split(",")]
        except ValueError:
            v = []
        if len(v) == 3:
            v += [0.0, 0.0, 0.0]
        if len(v) != 6 or not np.all(np.isfinite(v)):
            raise CommissionError(f"--init-pose {args.init_pose!r}: expected x,y,z[,roll,pitch,"
                                  "yaw]", 2)
        return np.array(v), "init_pose given with --init-pose"
    from controller.forward import forward_rigid

    exits = np.asarray(robot.exits, float)
    guess = np.array([*exits[:, :2].mean(axis=0), exits[:, 2].mean() / 3, 0, 0, 0])
    if np.all(np.isfinite(lengths)):
        res = forward_rigid(robot, lengths, guess)
        if res.success and np.all(np.isfinite(res.pose)):
            return res.pose, (f"init_pose not measured: forward kinematics of the first "
                              f"sample (length residual {res.residual:.2e} m)")
    return guess, "init_pose not measured and forward kinematics failed: a guess"


def run(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    """``cdpr commission monitor``: the table refreshed every ``1/--rate`` s until
    ``--duration``, ``q`` or a signal; the section's facts and the ``--json`` object."""
    _check(args)
    m = _Monitor(args, section)
    with network_of(args) as net:
        m.attach(net)
        try:
            m.start_cells()
            m.loop(_Screen(sys.stderr if args.json_lines else ui.out))
        finally:
            m.detach(net)
    return m.report(ui)


def _check(args: argparse.Namespace) -> None:
    """The rate and duration checked before anything is read (:class:`CommissionError`,
    exit 2)."""
    if not 0 < args.rate <= 50:
        raise CommissionError(f"--rate {args.rate}: must be in (0, 50] Hz", 2)
    if args.duration is not None and not args.duration > 0:
        raise CommissionError(f"--duration {args.duration}: must be > 0", 2)


def _check_outputs(args: argparse.Namespace) -> None:
    """The ``--live`` address checked (:class:`CommissionError`, exit 2)."""
    if args.live is not None:
        from bench.mcap.live import parse_address

        try:
            parse_address(args.live)
        except ValueError as exc:
            raise CommissionError(str(exc), 2) from None


class _Monitor:
    """One monitor run: the bus's frames counted (and logged, recorded), the drives and
    the load cells polled, the recording written, the last table kept for the report."""

    def __init__(self, args: argparse.Namespace, section: Section) -> None:
        from controller.robot import resolve_robot
        from controller.winch import WinchConfigError
        from hal.scan import FrameCounter

        self.args, self.section = args, section
        self.w = w = winches_of(args)
        self.rmap = register_map_of(args)
        _check_outputs(args)
        self.robot = None
        if args.record or args.live is not None:
            self.robot = resolve_robot(args.robot)
            if tuple(self.robot.cable_ids) != tuple(w.cables):
                raise WinchConfigError(f"robot {self.robot.name} has cables "
                                       f"{self.robot.cable_ids}, the winches {w.source} "
                                       f"{w.cables}")
        if args.record:
            rec_dir = Path(args.record)
            if rec_dir.exists() and any(rec_dir.iterdir()):
                raise CommissionError(f"--record {rec_dir}: not empty; choose a new directory",
                                      2)
        section.fact("winch file", w.source)
        self.window = tension_window_of(args)
        section.fact("tension window", str(self.window))
        self.counter = FrameCounter(window_s=1.0)
        self.frames = (_FrameSink() if (args.record and args.format != "csv")
                       or args.live is not None else None)
        self.writer = self.logger = self.cells = self.mon = self.reading = None
        self.polls = 0
        self.why = ""
        self.stopped: tuple[int, str] | None = None  # (exit status, message) of a signal
        self.last_lines: list[str] = []
        self.samples: list = []
        self._send = None

    # ----- the bus ----------------------------------------------------------------------

    def attach(self, net) -> None:
        """Count (log, record) every frame heard and sent on ``net``; the drive monitor."""
        import can

        from hal.drive_monitor import DriveMonitor

        args, bus = self.args, net.bus
        if args.candump:
            try:
                self.logger = _LockedLogger(can.Logger(args.candump))
            except (ValueError, OSError) as exc:
                raise CommissionError(f"--candump {args.candump}: {exc}", 2) from None
        self._send = send = bus.send
        counter, logger, frames = self.counter, self.logger, self.frames

        def send_and_count(msg, timeout=None):
            send(msg, timeout)
            msg.timestamp = time.time()
            counter.count(msg)
            if logger is not None:
                logger(msg)
            if frames is not None:
                frames(msg)

        bus.send = send_and_count
        for listener in (counter, logger, frames):
            if listener is not None:
                net.notifier.add_listener(listener)
        self.mon = DriveMonitor(net, self.w, args.eds)

    def detach(self, net) -> None:
        """Everything closed and the bus as it was (also after an error)."""
        net.bus.send = self._send
        if self.cells is not None:
            self.cells.stop()
        if self.mon is not None:
            self.mon.close()
        if self.frames is not None:
            net.notifier.remove_listener(self.frames)
            self.frames.detach()
        if self.writer is not None:
            self.writer.close()
        net.notifier.remove_listener(self.counter)
        if self.logger is not None:
            net.notifier.remove_listener(self.logger)
            self.logger.stop()

    def start_cells(self) -> None:
        """The load cells' poller (``--modbus``), after one whole sweep."""
        if self.args.modbus is not None:
            self.cells = polling_cells(self.args, self.rmap)

    # ----- the refreshes ----------------------------------------------------------------

    def loop(self, screen: _Screen) -> None:
        """Refresh every period until ``--duration``, the operator's key or a signal
        (Ctrl-C, SIGTERM: ``stopped``)."""
        args = self.args
        self.t0, self.wall_t0 = time.monotonic(), time.time()
        t_end = None if args.duration is None else self.t0 + args.duration
        keys = None
        if sys.stdin.isatty() and not args.json:
            from bench.commission.keys import KeyReader, cbreak
            keys = KeyReader(enter_quits=True)
        self.n_seen = self.n_recorded = 0
        period = 1.0 / args.rate
        try:
            with cbreak() if keys is not None else _Null():
                if keys is not None:
                    keys.start()
                next_t = self.t0
                while True:
                    now = self._refresh(screen)
                    raise_pending()  # a signal whose exception a gc callback lost
                    if t_end is not None and now >= t_end:
                        self.why = f"--duration {args.duration:g} s"
                        break
                    if keys is not None and keys.poll() is not None:
                        self.why = "operator"
                        break
                    next_t += period
                    delay = next_t - time.monotonic()
                    if delay > 0:
                        time.sleep(delay if t_end is None else min(delay,
                                   max(0.0, t_end - time.monotonic())))
                    else:
                        next_t = time.monotonic()
        except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: reported, then 130 / 143
            from bench.parallel import interruption
            self.stopped = interruption(exc)
            self.why = "Ctrl-C" if self.stopped[0] == 130 else self.stopped[1]

    def _refresh(self, screen: _Screen) -> float:
        """One refresh: poll, record, draw the table, a JSON line; the monotonic time."""
        args, mon, w = self.args, self.mon, self.w
        self.samples = mon.poll()
        self.reading = self.cells.read() if self.cells is not None else None
        now = time.monotonic()
        self.polls += 1
        if self.robot is not None and self.writer is None:
            self._open_writer()
        if self.writer is not None:
            self.writer.append(_row(now - self.t0, self.samples, self.reading, w, self.rmap,
                                    mon.has_current))
            new, self.n_recorded = _new_events(mon, self.n_recorded)
            for e in new:
                record_event(self.writer, e, self.wall_t0)
        load = self.counter.load(w.bus.bitrate, now)
        header = f"cdpr commission monitor {time.strftime('%H:%M:%S')} {args.can}"
        self.last_lines = render(self.samples, self.reading, self.rmap, load,
                                 self.counter.frames, mon.last_events(4), header,
                                 mon.has_current, self.window, screen.out)
        screen.show(self.last_lines)
        if args.json_lines:
            new, self.n_seen = _new_events(mon, self.n_seen)
            print(json.dumps({
                "t_s": round(now - self.t0, 4), "drives": [x.as_dict() for x in self.samples],
                "load_cells": cells_json(self.reading, self.window), "bus_load": load,
                "frames": self.counter.frames, "events_new": [e.as_dict() for e in new]}),
                flush=True)
        return now

    def _open_writer(self) -> None:
        """The recording, at the first sample (its init pose from it or ``--init-pose``)."""
        from bench.mcap.recorders import open_writer

        args, w = self.args, self.w
        lengths = np.array([np.nan if s.length_m is None else s.length_m
                            for s in self.samples])
        pose, note = _init_pose(args, self.robot, lengths)
        self.writer = open_writer(
            args.record, self.robot, pose, _columns(w.cables, self.mon.has_current),
            {"pose_source": "none (cdpr commission monitor)",
             "tension_source": "load cells" if self.cells else "none",
             "notes": f"cdpr commission monitor on {args.can}; {note}; winches {w.source}"},
            fmt=args.format, live=args.live, can_t0=self.wall_t0)
        if self.frames is not None:
            self.frames.attach(self.writer.can_frame)
        self.section.fact("init pose", f"{np.round(pose, 4).tolist()} ({note})")

    # ----- the report -------------------------------------------------------------------

    def report(self, ui: Ui) -> int:
        """The section's facts, the line said and the ``--json`` object; the exit status
        (130 / 143 after a signal: dispatch's last line on stderr says which)."""
        args, section, mon, writer = self.args, self.section, self.mon, self.writer
        events = [str(e) for e in mon.events]
        dropped = mon.events.dropped()
        frames = self.counter.frames
        section.fact("result", f"{self.polls} refreshes, ended by {self.why}, {frames} "
                     f"frames, {len(events)} event(s)")
        lost = ", ".join(f"{v} {k}" for k, v in dropped.items())
        if any(dropped.values()):
            section.fact("events dropped", lost)
        if args.record:
            section.fact("recording", f"{args.record} ({writer.rows if writer else 0} rows, "
                         f"{args.format})")
        if args.candump:
            section.fact("CAN log", args.candump)
        section.bullets(events)
        if self.last_lines:
            section.text("Last table:\n\n```\n" + "\n".join(self.last_lines) + "\n```")
        ui.say(f"monitor: {self.polls} refreshes, ended by {self.why}"
               + (f"; recording {args.record} ({writer.rows} rows)" if args.record and writer
                  else "")
               + (f"; CAN log {args.candump}" if args.candump else ""))
        if any(dropped.values()):
            ui.say("events dropped (oldest first, by severity): " + lost)
        window = self.window
        ui.emit({"refreshes": self.polls, "ended_by": self.why, "frames": frames,
                 "drives": [s.as_dict() for s in self.samples],
                 "load_cells": cells_json(self.reading, window),
                 "events": events,
                 "events_by_severity": {sev: [e.as_dict() for e in mon.events.items(sev)]
                                        for sev in SEVERITIES},
                 "events_dropped": dropped, "tension_window_n": [window.low_n, window.high_n],
                 "record": args.record, "format": args.format, "live": args.live,
                 "rows": writer.rows if args.record and writer else 0,
                 "candump": args.candump})
        return self.stopped[0] if self.stopped is not None else 0


def _new_events(mon, n_seen: int) -> tuple[list, int]:
    """The events that came since ``n_seen`` events had come (those still kept) and the
    running count now."""
    total = len(mon.events) + sum(mon.events.dropped().values())
    fresh = total - n_seen
    return (mon.events.items()[-fresh:] if fresh > 0 else []), total


class _Null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _columns(cables, has_current: bool) -> list[str]:
    cols = ["t"] + [f"l_meas_{c}" for c in cables] + [f"tau_{c}" for c in cables]
    cols += [f"vel_{c}" for c in cables] + [f"torque_{c}" for c in cables]
    cols += [f"drive_state_{c}" for c in cables]
    if has_current:
        cols += [f"current_{c}" for c in cables]
    return cols


def _row(t: float, samples, reading, w, rmap, has_current: bool) -> list[float]:
    nan = float("nan")

    def v(x):
        return nan if x is None else float(x)

    row = [t] + [v(s.length_m) for s in samples]
    if reading is not None:
        row += [float(reading.values_N[rmap.index_of(c)]) if c in rmap.cables else nan
                for c in w.cables]
    else:
        row += [nan] * len(samples)
    row += [v(s.velocity_m_s) for s in samples]
    row += [nan if s.torque_permille is None else s.torque_permille * 1e-3 * w.rated_torque_nm[k]
            for k, s in enumerate(samples)]
    from hal.drives_cia402 import DriveState

    row += [float(DriveState[s.state]) for s in samples]
    if has_current:
        row += [v(s.current_permille) for s in samples]
    return row
