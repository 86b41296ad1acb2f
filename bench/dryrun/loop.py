"""The control loop of a dry run, on the hardware interface only.

The same code drives :class:`hal.fake.FakeHardware`, the simulated rig in this process,
``cdpr sim`` in another process and real drives: it only calls
:class:`hal.interface.WinchHardware` and :class:`hal.tracker.Tracker`. Decisions are the
controller's (:class:`controller.cycle.LengthController`, :class:`controller.supervisor
.Supervisor`, :class:`controller.feedrate.FeedRate`); this module only wires them.

Initialisation (the conventions' Fig. 4d): the platform's pose p0 is given or measured
by the tracker (mean of fresh samples), the tensions tau0 are read at p0, the controller
is built for p0 and tau0, and the HAL references the drives' length readings to the
model's lengths ``d_model(p0)``: whatever robot.toml the controller runs with (nominal,
remeasured, corrected by ``cdpr diagnose``), its first setpoints are the drives'
positions. Then the whole trajectory is planned and checked before any drive is enabled.

Each cycle (period T, absolute deadlines ``t0 + k T``, so no drift): the setpoints
computed in the previous cycle go out with the SYNC at the deadline, the drives'
answers and the tensions are read, the trajectory advances by ``rate * T`` (feed hold),
the controller computes the next setpoints from the measured tensions (a load cell that
is not valid is replaced by the planned tension), the supervisor decides, and the loop
acts: hold (feed rate to 0, never an infeasible setpoint sent), quick stop (every drive,
then wait until they stand in Quick Stop Active), or carry on. Without ``realtime`` the
loop runs in lock-step with a simulated world (``tick``) as fast as it can.

A cycle that ends after the next deadline is an overrun (counted, recorded; the loop
then skips the deadlines it missed instead of bursting).
"""

from __future__ import annotations

import array
import contextlib
import gc
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.dryrun.realtime import (
    DEFAULT_RT_PRIORITY,
    helper_priority,
    helper_threads,
    realtime_interpreter,
    realtime_scheduling,
)
from bench.dryrun.record import DryRunRecorder, SampleTimes
from controller.cycle import LengthController
from controller.feedrate import FeedRate, ramp_time
from controller.robot import Robot
from controller.supervisor import (
    REACTIONS,
    DeviceFault,
    Observation,
    Reaction,
    Supervisor,
    SupervisorLimits,
)
from controller.trajectory import Trajectory
from hal.drives import NMT_START_TRIES, DriveStartupError
from hal.drives_cia402 import ST
from hal.interface import Readings, WinchHardware
from hal.tracker import Tracker

#: states of the ``state`` column
INIT, APPROACH, HOLD, QUICK_STOP, END = "init", "approach", "hold", "quick_stop", "end"


class PathRefused(ValueError):
    """The trajectory was refused before anything moved (the message says where, why)."""


@dataclass
class LoopOptions:
    """How the loop runs.

    ``realtime``: on the wall clock with absolute deadlines (else lock-step, as fast as the
    world allows); ``decimate``: record every n-th cycle (and every cycle whose state
    differs from the last recorded one); ``init_pose``: given p0 (None:
    measure it with the tracker, mean of ``init_samples`` fresh samples);
    ``init_dwell_s``/``end_dwell_s`` [s] standing still before and after the trajectory;
    ``stop_timeout_s`` [s]: a quick stop must reach stand-still within it;
    ``hold_timeout_s`` [s]: a hold whose condition does not clear within this time after
    the platform came to a stand-still ends the run (drives disabled, brakes hold);
    ``max_duration_s``: stop after this much trajectory time (None: the whole path).
    """

    realtime: bool = False
    decimate: int = 1
    init_pose: np.ndarray | None = None
    init_samples: int = 20
    init_dwell_s: float = 1.0
    end_dwell_s: float = 0.5
    stop_timeout_s: float = 2.0
    hold_timeout_s: float = 5.0
    max_duration_s: float | None = None
    method: str = "closed_form"
    supervisor: dict[str, Any] = field(default_factory=dict)  #: SupervisorLimits overrides
    #: condition kind -> reaction, overriding the supervisor's table (e.g. slack: log)
    reactions: dict[str, Reaction] = field(default_factory=dict)
    #: tensions of the mast update: "measured" (the load cells, the paper's future work) or
    #: "planned" (the tension distribution's, as the paper's offline estimate did)
    mast_tensions: str = "measured"
    #: real time: SCHED_FIFO priority of the loop's thread when permitted (0: normal)
    rt_priority: int = DEFAULT_RT_PRIORITY


@dataclass
class LoopResult:
    """What a run did (plain data; :meth:`summary` is the ``--json`` object's core)."""

    ended: str = "not started"  #: completed, quick_stop (also: the drives could not all be
    #: enabled, e.g. one lost while enabling: an ``enable_failed`` event), interrupted,
    #: hold_timeout, refused, error
    message: str = ""
    cycles: int = 0
    period_s: float = 0.0
    simulated_s: float = 0.0
    wall_s: float = 0.0
    trajectory_s: float = 0.0  #: trajectory time reached [s]
    path_s: float = 0.0  #: the trajectory's duration [s]
    overruns: int = 0
    events: list[dict] = field(default_factory=list)
    pose_errors: int = 0
    pose_error_sq: float = 0.0
    pose_error_max_m: float | None = None
    init_pose: list[float] | None = None
    init_tensions: list[float] | None = None
    reference_offset_m: list[float] | None = None
    substituted_cycles: int = 0
    drive_states: list[str] | None = None  #: CiA 402 states when the run ended
    lateness_s: array.array = field(default_factory=lambda: array.array("f"))
    #: real time: the loop thread's scheduling ("SCHED_FIFO 50", "normal (...)")
    scheduling: str | None = None

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period_s if self.period_s else 0.0

    @property
    def pose_error_rms_m(self) -> float | None:
        return math.sqrt(self.pose_error_sq / self.pose_errors) if self.pose_errors else None

    def jitter_ms(self, q: float = 99.0) -> float | None:
        """Percentile of the lateness of the cycles' start after their deadline [ms]."""
        if not len(self.lateness_s):
            return None
        return float(np.percentile(np.frombuffer(self.lateness_s, np.float32), q) * 1e3)

    def summary(self) -> dict:
        return {"ended": self.ended, "message": self.message, "cycles": self.cycles,
                "rate_hz": self.rate_hz, "simulated_s": self.simulated_s,
                "wall_s": self.wall_s, "trajectory_s": self.trajectory_s,
                "path_s": self.path_s, "overruns": self.overruns, "events": self.events,
                "pose_error_rms_m": self.pose_error_rms_m,
                "pose_error_max_m": self.pose_error_max_m, "init_pose": self.init_pose,
                "reference_offset_m": self.reference_offset_m,
                "drive_states": self.drive_states, "scheduling": self.scheduling}


class CycleClock:
    """Absolute deadlines ``t0 + k T`` on a monotonic clock (no drift): :meth:`wait` sleeps
    until the next deadline (the last millisecond spinning) and returns how late it woke
    [s]; :meth:`done` ends a cycle: an overrun when the work ran past the next deadline,
    which is then skipped with any others already missed (no burst of catch-up cycles).
    ``now``/``sleep`` are injectable for tests."""

    def __init__(self, period_s: float, now=time.perf_counter, sleep=time.sleep,
                 spin_s: float = 1e-3) -> None:
        self.T = float(period_s)
        self.now, self.sleep, self.spin_s = now, sleep, spin_s
        self.deadline = now()
        self.overruns = 0  #: cycles whose work ran past the next deadline
        self.skipped = 0  #: deadlines skipped after overruns

    def wait(self) -> float:
        """Sleep until the current deadline; the lateness [s] (>= 0)."""
        left = self.deadline - self.now()
        if left > self.spin_s * 1.5:
            self.sleep(left - self.spin_s)
        while self.now() < self.deadline:
            self.sleep(0.0)  # spins, yet lets the HAL's threads have the interpreter
        return self.now() - self.deadline

    def done(self) -> bool:
        """End of a cycle's work: move to the next deadline; True for an overrun."""
        self.deadline += self.T
        now = self.now()
        if now <= self.deadline:
            return False
        self.overruns += 1
        missed = int((now - self.deadline) / self.T) + 1  # up to the first one ahead
        self.skipped += missed
        self.deadline += missed * self.T
        return True

    def slack(self) -> float:
        """Time left before the next deadline [s]."""
        return self.deadline - self.now()


#: commands kept for the following-error reference of a late drive answer (cycles)
FEEDBACK_HISTORY = 8


def reference_command(lengths_m: np.ndarray, sent: deque[np.ndarray] | list[np.ndarray],
                      age: np.ndarray) -> np.ndarray:
    """The command [m] each drive's position ``lengths_m`` [m] is judged against in real
    time: it answers the SYNC before the latest (or the one before that), and a drive that
    missed ``age`` SYNCs in a row answers that many SYNCs earlier still. Of the two
    commands sent then (``sent``: the commands sent, newest last), the nearer. An age
    beyond the history takes the oldest two kept. Shape (n,)."""
    h = np.asarray(sent)
    m, n = h.shape
    if m < 2:
        return h[-1].copy()
    a = m - 1 - np.clip(np.asarray(age, np.int64), 0, m - 2)
    cols = np.arange(n)
    newer, older = h[a, cols], h[a - 1, cols]
    return np.where(np.abs(lengths_m - newer) < np.abs(lengths_m - older), newer, older)


class CrossTrack:
    """Distance from measured positions to the commanded path (the positions commanded over
    the last ``window_s`` seconds, as a polyline): the pose error without the lag along the
    path of a quasi-static plant or a tracker."""

    def __init__(self, period_s: float, window_s: float = 1.0) -> None:
        # the last ``cap`` distinct commanded positions, in a ring (oldest first from _next)
        self._cap = max(2, int(window_s / period_s) + 1)
        self._buf = np.empty((self._cap, 3))
        self._n = 0  # positions held
        self._next = 0  # where the next one goes
        self._last = np.full(3, np.nan)  # the newest one

    def command(self, pos: np.ndarray) -> None:
        p = pos[:3]
        if self._n == 0 or np.count_nonzero(self._last != p):
            self._buf[self._next] = p
            self._last = self._buf[self._next].copy()
            self._next = (self._next + 1) % self._cap
            self._n = min(self._n + 1, self._cap)

    def _points(self) -> np.ndarray:
        if self._n < self._cap:
            return self._buf[:self._n]
        return np.concatenate((self._buf[self._next:], self._buf[:self._next]))

    def error(self, pos: np.ndarray) -> float:
        p = np.asarray(pos[:3], float)
        if self._n == 1:
            return float(np.linalg.norm(p - self._buf[0]))
        pts = self._points()
        a, b = pts[:-1], pts[1:]
        ab = b - a
        den = (ab * ab).sum(1)
        s = np.clip(np.where(den > 0, ((p - a) * ab).sum(1) / np.where(den > 0, den, 1), 0),
                    0, 1)
        d = a + s[:, None] * ab - p
        return float(np.sqrt((d * d).sum(1).min()))


def _faults(r: Readings) -> tuple[DeviceFault, ...]:
    return tuple(DeviceFault(f.device, f.address, f.cable, f.kind, f.code, f.text)
                 for f in r.faults)


def measure_init_pose(tracker: Tracker, samples: int, timeout_s: float = 5.0) -> np.ndarray:
    """Mean of ``samples`` fresh valid tracker poses (the platform stands still)."""
    got = []
    deadline = time.monotonic() + timeout_s
    while len(got) < samples:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"the tracker gave {len(got)} valid poses of the {samples} "
                               f"wanted within {timeout_s} s: is it locked on the platform?")
        rd = tracker.wait_fresh(min(left, 1.0))
        if rd.valid and np.all(np.isfinite(rd.pose)):
            got.append(np.asarray(rd.pose, float))
    return np.mean(got, axis=0)


def mean_tensions(hw: WinchHardware, sweeps: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the valid tensions over ``sweeps`` fresh reads of all cells; (n,) [N] (NaN
    where a cell never gave a valid value) and the valid mask."""
    acc, cnt = np.zeros(hw.n), np.zeros(hw.n)
    for _ in range(sweeps):
        hw.sample_tensions()
        r = hw.read()
        ok = r.tensions_ok & np.isfinite(r.tensions_N)
        acc[ok] += r.tensions_N[ok]
        cnt[ok] += 1
    with np.errstate(invalid="ignore"):
        return np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan), cnt > 0


_NAN6 = np.full(6, np.nan)


@dataclass
class _CycleState:
    """What the control loop carries from cycle to cycle. Lengths [m] are the
    controller's (the drives' plus the reference offset); times [s] from the loop's start
    (``t_traj``: along the trajectory, slowed by holds)."""

    cmd: np.ndarray  # the setpoints sent with the next SYNC
    last_sent: np.ndarray
    sent: deque  # the setpoints sent, newest last (real time: a late TPDO's reference)
    pose_des: np.ndarray
    out_tensions: np.ndarray  # the controller's last feasible tensions [N]
    prev_sent: np.ndarray | None = None
    k: int = 0  # cycles run
    t_traj: float = 0.0
    stopping: int = 0  # cycles since a quick stop was sent
    held_since: float | None = None  # a hold began (the feed ramps down)
    state: str = INIT
    path_cycle: int = -1
    substituted: int = 0  # load cells whose planned tension stood in this cycle
    last_state: str = ""
    last_drives: bytes = b""
    overrun: bool = False
    init_cycles: int = 0  # cycles of the initial dwell (the trajectory waits)
    measured_masts: bool = True  # the masts moved by the measured tensions (else planned)
    outside: int | None = None  # a winch whose setpoint is outside its limits (held)

    @classmethod
    def held_at(cls, lengths_m: np.ndarray, p0: np.ndarray, tensions_N: np.ndarray,
                init_cycles: int, measured_masts: bool) -> _CycleState:
        """The state before the first cycle: hold where the cables stand (the referenced
        lengths), the desired pose ``p0``."""
        cmd = lengths_m.copy()
        return cls(cmd=cmd, last_sent=cmd.copy(), sent=deque([cmd], maxlen=FEEDBACK_HISTORY),
                   pose_des=p0.copy(), out_tensions=tensions_N, init_cycles=init_cycles,
                   measured_masts=measured_masts)


class ControlLoop:
    """One dry run (see the module docstring).

    ``plan(p0) -> Trajectory`` builds and checks the trajectory from the measured init pose
    (raises :class:`PathRefused`); ``open_recorder(p0)`` the recording (or None);
    ``tick()`` advances a simulated world in lock-step after each SYNC's answers arrived
    (None for real hardware); ``on_event(line)`` logs; ``on_progress(result, t_traj)`` is
    called about four times a second; ``stop`` (set by SIGINT) ends the run with a quick stop.
    """

    #: the samples' times, made at start-up (on the hardware's clock from there)
    _times: SampleTimes

    def __init__(self, hw: WinchHardware, tracker: Tracker, model: Robot,
                 plan: Callable[[np.ndarray], Trajectory], options: LoopOptions,
                 open_recorder: Callable[[np.ndarray], DryRunRecorder | None] | None = None,
                 tick: Callable[[], None] | None = None,
                 on_event: Callable[[str], None] | None = None,
                 on_progress: Callable[[LoopResult, float], None] | None = None,
                 stop: threading.Event | None = None,
                 on_cycle: Callable[..., list[tuple[str, str]]] | None = None) -> None:
        self.hw, self.tracker, self.model = hw, tracker, model
        #: called every cycle but the initialisation's and a stop's with (t, readings, desired
        #: pose, controller); returns events (kind, text) to log (bench/dryrun/learn.py)
        self.on_cycle = on_cycle
        self.plan, self.opt = plan, options
        self.open_recorder = open_recorder
        self.tick = tick
        self.on_event = on_event or (lambda s: None)
        self.on_progress = on_progress
        self.stop = stop or threading.Event()
        self.result = LoopResult(period_s=hw.period_s)
        self.recorder: DryRunRecorder | None = None
        self.controller: LengthController | None = None
        self.trajectory: Trajectory | None = None
        self._finished = False
        self._enable_failed_seen = False  #: enabling the drives failed (see _enable_failed)
        self._t0 = 0.0  #: hardware time at start-up [s]

    # ------------------------------------------------------------------ events
    def _event(self, t: float, device: str, address: int, cable: str, kind: str, code: int,
               reaction: str, active: bool, text: str) -> None:
        self.result.events.append({"t": round(float(t), 6), "device": device,
                                   "address": int(address), "cable": cable, "kind": kind,
                                   "code": int(code), "reaction": reaction,
                                   "active": bool(active), "text": text})
        if self.recorder is not None:
            self.recorder.event(t, device, address, cable, kind, code, reaction, active, text)
        who = {"drive": f"CAN node {address}", "loadcell": f"Modbus unit {address}",
               "bus": "CAN bus"}.get(device, device)
        cab = f" (cable {cable})" if cable else ""
        state = "" if active else "ended: "
        self.on_event(f"t={t:8.3f} s  {state}{kind}{f' 0x{code:04X}' if code else ''} at "
                      f"{who}{cab}: {text} -> {reaction}")

    def _hw_events(self) -> None:
        for e in self.hw.events():
            self._event(e.time_s - self._t0, e.device, e.address, e.cable, e.kind, e.code, "event",
                        True, e.text)

    # ------------------------------------------------------------------ initialisation
    def _initialise(self) -> tuple[np.ndarray, Trajectory]:
        hw, opt = self.hw, self.opt
        hw.start()
        self._t0 = hw.read().t_s  # the recording's time starts here
        self._times = SampleTimes(self._t0, self.tracker)  # each sample's time, once
        self.tracker.start()
        p0 = (np.asarray(opt.init_pose, float) if opt.init_pose is not None
              else measure_init_pose(self.tracker, opt.init_samples))
        tau0, ok = mean_tensions(hw)
        init_tensions = tau0 if ok.all() else None
        self.controller = LengthController(self.model, p0, init_tensions, method=opt.method)
        traj = self.plan(p0)  # raises PathRefused before anything moves
        self.trajectory = traj
        if self.open_recorder is not None:
            self.recorder = self.open_recorder(p0)
        if self.recorder is not None:
            # where t = 0 is on the hardware's clock: the recording aligned with other logs
            self.recorder.update_meta(clock_origin_s=round(self._t0, 9))
        t = hw.read().t_s - self._t0
        if not ok.all():
            bad = [hw.cables[k] for k in np.flatnonzero(~ok)]
            self._event(t, "controller", 0, "", "init_tensions", 0, "substitute", True,
                        f"no valid tension from cables {', '.join(bad)} at initialisation: "
                        f"the tension distribution stands for tau0")
        off = hw.reference(self.controller.reference)
        res = self.result
        res.init_pose = [float(v) for v in p0]
        res.init_tensions = [float(v) for v in self.controller.init_tensions]
        res.reference_offset_m = [float(v) for v in off]
        res.path_s = traj.duration_s
        how = "given" if opt.init_pose is not None else "tracker"
        self._event(t, "controller", 0, "", "initialised", 0, "none", True,
                    f"p0 {np.round(p0, 4).tolist()} ({how}); referenced: offsets "
                    f"{np.round(1e3 * off, 2).tolist()} mm")
        try:
            # nothing moved yet: a drive that left NMT OPERATIONAL meanwhile (its consumer
            # heartbeat expired on a busy host) is restarted, a bounded number of times
            hw.enable(restart_tries=NMT_START_TRIES)
        except DriveStartupError as exc:
            self._enable_failed(exc)
            raise
        return p0, traj

    def _supervisor(self) -> Supervisor:
        """The supervisor of this run (the robot's tension limits, the winches' windows,
        the options' overrides)."""
        lim = SupervisorLimits.for_robot(self.model.tension_min, self.model.tension_max,
                                         self.hw.winches.following_error_m,
                                         **self.opt.supervisor)
        return Supervisor(lim, dict(self.opt.reactions))

    def _enable_failed(self, exc: DriveStartupError) -> None:
        """The drives did not all come to Operation Enabled (e.g. one lost while it
        enabled): what the HAL reports goes through the supervisor as in the cycle (the
        same events, e.g. ``drive_lost`` naming the node), then the HAL's events."""
        self._enable_failed_seen = True
        r = self.hw.read()
        ob = Observation(r.t_s - self._t0, r.tensions_N, r.tensions_ok, r.lengths_m, None,
                         r.enabled, expect_enabled=False, faults=_faults(r),
                         cables=self.hw.cables, node_ids=self.hw.node_ids,
                         unit_ids=self.hw.unit_ids)
        for e in self._supervisor().step(ob).events:
            if e.kind != "loadcell":
                self._event(e.t_s, e.device, e.address, e.cable, e.kind, e.code,
                            e.reaction.label, e.active, e.text)
        self._event(r.t_s - self._t0, "controller", 0, "", "enable_failed", 0, "quick_stop",
                    True, str(exc))
        self._hw_events()

    # ------------------------------------------------------------------ the run
    def run(self) -> LoopResult:
        res = self.result
        wall0 = time.perf_counter()
        try:
            with contextlib.ExitStack() as rt:
                if self.opt.realtime:
                    # the full collection comes before the drives are fed: once they have
                    # seen a setpoint, a pause of tens of milliseconds is a lost master
                    rt.enter_context(realtime_interpreter())
                    # real time from start-up on: the drives watch the master's heartbeat
                    # from their configuration, and a producer thread waiting for the
                    # interpreter behind a preempted main thread is late all the same
                    self._raise_producers()
                    res.scheduling = rt.enter_context(
                        realtime_scheduling(self.opt.rt_priority))
                try:
                    p0, traj = self._initialise()
                except PathRefused as exc:
                    res.ended, res.message = "refused", str(exc)
                    return res
                except DriveStartupError as exc:
                    if not self._enable_failed_seen:
                        raise  # start-up: not one of the supervisor's conditions
                    res.ended, res.message = "quick_stop", str(exc)  # events: _enable_failed
                    self._emergency_stop()
                    return res
                if self.opt.realtime:
                    self._raise_producers(say=True)
                    # the threads started since (tracker reader, SDO worker, ...)
                    rt.enter_context(helper_threads(self.opt.rt_priority)
                                     if res.scheduling.startswith("SCHED_FIFO")
                                     else contextlib.nullcontext())
                    self.on_event(f"real time: the loop's thread runs {res.scheduling}")
                self._cycle_loop(p0, traj)
        except KeyboardInterrupt:
            res.ended, res.message = "interrupted", "KeyboardInterrupt"
            self._emergency_stop()
        except Exception as exc:
            res.ended, res.message = "error", f"{type(exc).__name__}: {exc}"
            self._emergency_stop()
            raise
        finally:
            res.wall_s = time.perf_counter() - wall0
            try:
                res.drive_states = self.hw.read().state_names()
            except Exception:  # the bus may be gone
                res.drive_states = None
            if self.recorder is not None:
                try:
                    self.recorder.update_meta(notes=f"dry run: {res.ended}"
                                              + (f" ({res.message})" if res.message else ""))
                finally:
                    self.recorder.close()
        return res

    def _raise_producers(self, say: bool = False) -> None:
        """The HAL's producer threads (master heartbeat) one priority below the loop's from
        start-up on, where the OS allows it: the drives' consumer heartbeat runs from
        their configuration, long before the loop's own thread goes real time. ``say``:
        tell what they got (after start-up, when they run)."""
        if self.opt.rt_priority <= 0:
            return
        got = self.hw.set_thread_priority(helper_priority(self.opt.rt_priority))
        for name, text in got.items() if say else ():
            self.on_event(f"real time: the HAL's {name.replace('_', ' ')} thread runs {text}")

    def _emergency_stop(self) -> None:
        """Quick-stop every drive (best effort, after an error or interruption)."""
        try:
            self.hw.quick_stop()
            for _ in range(int(self.opt.stop_timeout_s / self.hw.period_s) + 1):
                self.hw.write_lengths(None)
                if self.tick is not None:
                    self.hw.wait_feedback()
                else:
                    time.sleep(self.hw.period_s)
                if not np.any(self.hw.read().states == ST.OPERATION_ENABLED):
                    break
        except Exception:  # the bus may be gone: the drives' own master-loss reaction acts
            pass

    def _stood_too_long(self, feed: FeedRate, t: float) -> bool:
        """Whether a held platform has stood still for longer than the hold timeout."""
        if not feed.stopped:
            return False
        if self._stood_since is None:
            self._stood_since = t
        return t - self._stood_since > self.opt.hold_timeout_s

    def _cycle_loop(self, p0: np.ndarray, traj: Trajectory) -> None:
        """The cycles from the referenced lengths along ``traj`` until it ends, a hold
        times out or a quick stop (or ``stop``) stands the drives still: each cycle sends
        the last setpoints with the SYNC, reads, advances the trajectory, asks the
        controller and the supervisor, acts, measures and records."""
        hw, opt, res = self.hw, self.opt, self.result
        T = hw.period_s
        sup = self._supervisor()
        for kind, reaction in opt.reactions.items():
            self._event(0.0, "controller", 0, "", "reaction_override", 0, reaction.label, True,
                        f"supervisor: {kind} -> {reaction.label} (default "
                        f"{REACTIONS[kind].label})")
        if opt.mast_tensions not in ("measured", "planned"):
            raise ValueError(f"mast_tensions must be 'measured' or 'planned', got "
                             f"{opt.mast_tensions!r}")
        feed = FeedRate(ramp_time(traj.limits.speed_m_s, traj.limits.max_accel_m_s2))
        xt = CrossTrack(T)
        c = _CycleState.held_at(hw.read().lengths_m, p0, self.controller.init_tensions,
                                int(round(opt.init_dwell_s / T)),
                                opt.mast_tensions == "measured")
        end_at = traj.duration_s + opt.end_dwell_s
        if opt.max_duration_s is not None:
            end_at = min(end_at, opt.max_duration_s)
        self._stood_since: float | None = None  # the held platform stands still
        next_progress = time.perf_counter()
        # a real-time thread wakes on time (no timer slack) and must not hold a core
        # spinning; under the normal scheduler the last millisecond is spun
        fifo = (self.result.scheduling or "").startswith("SCHED_FIFO")
        clock = CycleClock(T, spin_s=1e-4 if fifo else 1e-3) if opt.realtime else None
        while True:
            # ---- output: the setpoints of the last cycle go out with the SYNC
            if clock is not None:
                res.lateness_s.append(clock.wait())
            hw.write_lengths(None if c.stopping else c.cmd)
            if not opt.realtime:  # lock-step: the drives' answers to this SYNC, then the world
                hw.wait_feedback()
                if self.tick is not None:
                    self.tick()
            r = hw.read()
            c.k += 1
            res.cycles = c.k
            t = r.t_s - self._t0
            self._advance(c, traj, feed)
            out, d = self._decide(c, r, sup, t)
            self._act(c, d, out, t)
            self._measure(c, r, xt, t)
            if self.on_cycle is not None and c.state not in (INIT, QUICK_STOP) \
                    and not c.stopping:
                for kind, text in self.on_cycle(t, r, c.pose_des, self.controller):
                    self._event(t, "controller", 0, "", kind, 0, "event", True, text)
            res.simulated_s = c.k * T
            res.trajectory_s = c.t_traj
            if self._ended(c, d, r, feed, t, end_at):
                break
            # ---- timing
            if clock is not None:
                c.overrun = clock.done()
                res.overruns = clock.overruns
                if not c.overrun and c.k % 64 == 0 and clock.slack() > 0.5 * T:
                    gc.collect(0)  # the young generation, in the slack of a cycle
            if self.on_progress is not None and time.perf_counter() >= next_progress:
                self.on_progress(res, c.t_traj)
                next_progress = time.perf_counter() + 0.25
        if not self._finished:
            self._hw_events()
        if self.on_progress is not None:
            self.on_progress(res, c.t_traj)

    def _advance(self, c: _CycleState, traj: Trajectory, feed: FeedRate) -> None:
        """The trajectory advances after the initial dwell (a feed hold slows it down):
        the desired pose, the path's cycle and the state label."""
        if c.stopping:
            c.state = QUICK_STOP
            return
        if c.k <= c.init_cycles:
            return
        hold = c.held_since is not None
        c.t_traj += feed.advance(self.hw.period_s, hold)
        smp = traj.sample(c.t_traj)
        c.pose_des = smp.pose
        label = smp.label
        c.path_cycle = traj.segments[smp.segment].cycle if smp.segment >= 0 else 0
        if c.path_cycle < 0 and label == "move":
            label = APPROACH  # the move from p0 to the path's start
        c.state = HOLD if (hold or feed.rate < 1.0) else (
            END if c.t_traj >= traj.duration_s else label)

    def _decide(self, c: _CycleState, r: Readings, sup: Supervisor, t: float):
        """The controller's lengths for the desired pose (the masts moved by the measured
        tensions, or the planned ones), then the supervisor's decision on what was read;
        its events logged."""
        hw, res = self.hw, self.result
        valid = r.tensions_ok
        out = self.controller.step(c.pose_des, r.tensions_N if c.measured_masts else None,
                                   valid)
        if out.feasible:
            c.out_tensions = out.tensions
        c.substituted = int(out.substituted.sum()) if out.substituted.size else 0
        res.substituted_cycles += c.substituted > 0
        enabled = r.states == ST.OPERATION_ENABLED
        # positions answer the SYNC just sent (lock-step) or the one before (real time):
        # a following error exceeds the window against both
        # (a late or missing TPDO: the SYNCs before, as many as it missed)
        ref_cmd = c.last_sent if c.prev_sent is None else reference_command(
            r.lengths_m, c.sent, hw.feedback_age())
        ob = Observation(t, r.tensions_N, valid, r.lengths_m, ref_cmd, enabled,
                         expect_enabled=not c.stopping, faults=_faults(r),
                         feasible=out.feasible, reason=out.reason, overrun=c.overrun,
                         cables=hw.cables, node_ids=hw.node_ids, unit_ids=hw.unit_ids)
        d = sup.step(ob)
        for e in d.events:
            self._event(e.t_s, e.device, e.address, e.cable, e.kind, e.code,
                        e.reaction.label, e.active, e.text)
        if c.k % 5 == 0 or r.faults:
            self._hw_events()
        return out, d

    def _act(self, c: _CycleState, d, out, t: float) -> None:
        """The supervisor's decision acted on: a quick stop (or ``stop``), a hold (never a
        setpoint the controller refused), or the controller's lengths; then the winch
        limits checked again before sending."""
        hw = self.hw
        if (d.stop or self.stop.is_set()) and not c.stopping:
            hw.quick_stop()
            c.stopping = 1
            if self.stop.is_set() and not d.stop:
                self._event(t, "controller", 0, "", "interrupted", 0, "quick_stop", True,
                            "stop requested (SIGINT/SIGTERM)")
            c.state = QUICK_STOP
        elif c.stopping:
            c.stopping += 1
        elif d.hold:
            if c.held_since is None:
                c.held_since = t
            c.cmd = out.lengths if out.feasible else c.last_sent
        else:
            c.cmd = out.lengths if out.feasible else c.last_sent
        if c.stopping:
            return
        if self._outside_limits(c, t):
            c.cmd = c.last_sent
            c.held_since = c.held_since if c.held_since is not None else t
        elif not d.hold:
            c.held_since = self._stood_since = None
        c.prev_sent = c.last_sent if self.opt.realtime else None
        c.last_sent = c.cmd
        if self.opt.realtime:
            c.sent.append(c.cmd)

    def _outside_limits(self, c: _CycleState, t: float) -> bool:
        """The winch limits checked again before sending (whatever planned ``c.cmd``):
        whether a setpoint is outside a winch's length range (or not finite). The first
        such cycle is a ``workspace`` event (a hold), the first cycle back within the
        limits ends it; while outside, the loop holds, so a setpoint that stays outside
        ends the run as a hold timeout."""
        hw = self.hw
        w = hw.winches
        raw = c.cmd - hw.reference_offset_m  # the drives' lengths
        bad = ~np.isfinite(c.cmd) | (raw < w.min_length_m) | (raw > w.max_length_m)
        was = c.outside
        c.outside = int(np.flatnonzero(bad)[0]) if np.count_nonzero(bad) else None
        if c.outside is not None and was is None:
            j = c.outside
            self._event(t, "drive", hw.node_ids[j], hw.cables[j], "workspace", 0, "hold", True,
                        f"setpoint {c.cmd[j]:.4f} m outside the winch's length limits "
                        f"[{w.min_length_m[j]:.4f}, {w.max_length_m[j]:.4f}] m: not sent")
        elif c.outside is None and was is not None:
            self._event(t, "drive", hw.node_ids[was], hw.cables[was], "workspace", 0, "hold",
                        False, "setpoints within the winch's length limits again")
        return c.outside is not None

    def _measure(self, c: _CycleState, r: Readings, xt: CrossTrack, t: float) -> None:
        """At the recording's rate (and whenever the state or the drives' CiA 402 states
        change): the tracker read, the error to the path counted, the row recorded."""
        res = self.result
        xt.command(c.pose_des)
        drives = r.states.tobytes()
        if not (c.k % self.opt.decimate == 0 or c.state != c.last_state
                or drives != c.last_drives):
            return
        c.last_state, c.last_drives = c.state, drives
        tr = self.tracker.read()
        pose_t = self._times.fix(tr, t)  # None: not a new fix (a fix is recorded once)
        pose_meas = _NAN6 if pose_t is None else tr.pose
        err = math.nan  # the error counted on this row (recorded: the plots')
        if pose_t is not None and c.state not in (INIT, QUICK_STOP):
            err = xt.error(tr.pose)
            res.pose_errors += 1
            res.pose_error_sq += err * err
            res.pose_error_max_m = max(res.pose_error_max_m or 0.0, err)
        if self.recorder is not None:
            tau, tau_t = self._times.tensions(r, t)
            lengths, lengths_t = self._times.lengths(r, t)  # nan: the sample recorded
            self.recorder.row(t, c.pose_des, c.last_sent, lengths, tau,
                              pose_meas, c.out_tensions, c.substituted, c.path_cycle,
                              res.overruns, c.state, err, drive_states=r.states,
                              lengths_t=lengths_t, tensions_t=tau_t, pose_t=pose_t)

    def _ended(self, c: _CycleState, d, r: Readings, feed: FeedRate, t: float,
               end_at: float) -> bool:
        """Whether the run ends this cycle (``result.ended`` and its message set): the
        drives stand after a quick stop (or it timed out), a hold did not clear in time,
        or the trajectory (with its end dwell, or ``max_duration_s``) is done."""
        opt, res = self.opt, self.result
        if c.stopping:
            standing = not np.any(r.states == ST.OPERATION_ENABLED)
            if not (standing or c.stopping * self.hw.period_s > opt.stop_timeout_s):
                return False
            res.ended = "interrupted" if self.stop.is_set() and not d.stop else "quick_stop"
            if not standing:
                res.message = (f"drives still Operation Enabled {opt.stop_timeout_s} s "
                               f"after the quick stop")
            elif not res.message:
                res.message = next((e["text"] for e in reversed(res.events)
                                    if e["reaction"] in ("quick_stop",) and e["active"]), "")
            return True
        if c.held_since is not None and self._stood_too_long(feed, t):
            res.ended = "hold_timeout"
            held = list(d.conditions)
            if c.outside is not None:
                held.append(f"workspace: cable {self.hw.cables[c.outside]}'s setpoint "
                            f"outside its winch's length limits")
            res.message = (f"held for {opt.hold_timeout_s} s: "
                           f"{', '.join(held) or 'condition'} did not clear")
            if any(cond.startswith("slack:") for cond in d.conditions):
                res.message += (" (a cable stays slack there with this model; "
                                "--react slack=log records it and goes on)")
            self._finish()
            return True
        if c.t_traj >= end_at:
            res.ended = "completed"
            self._finish()
            return True
        return False

    def _finish(self) -> None:
        """Normal end: the last events, then the drives disabled (brakes hold)."""
        self._hw_events()
        self._finished = True
        self.hw.shutdown()
