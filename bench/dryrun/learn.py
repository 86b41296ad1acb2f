"""``cdpr dry-run --learn``: online identification in the loop (controller/online_ident.py).

The loop hands every cycle to :class:`LoopLearner` (``ControlLoop(on_cycle=...)``). It keeps
the samples that come with a fresh tracker fix (tensions valid), updates the estimator every
``period_s`` of loop time with them (the estimator runs at that lower rate, not in the
cycle's budget), moves the model the controller uses toward the estimate at a bounded rate
(:class:`~controller.online_ident.ModelHandover`) and hands it over
(:meth:`~controller.cycle.LengthController.set_model`). The estimator's events come back to
the loop as events of the run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from controller.cycle import LengthController
from controller.online_ident import (
    IdentOptions,
    Measurement,
    ModelHandover,
    OnlineIdentifier,
    planned_samples,
)
from controller.robot import Robot

#: [s] between two poses of a trajectory in :func:`path_identifiability`
IDENT_STEP_S = 1.0
#: the estimator's process runs this much nicer than the loop (:class:`_EstimatorProcess`)
ESTIMATOR_NICE = 19


def path_identifiability(ident: OnlineIdentifier, trajectory, step_s: float = IDENT_STEP_S
                         ) -> dict[str, dict]:
    """What a trajectory can fix, before it runs: the Fisher information
    (:meth:`~controller.online_ident.OnlineIdentifier.fisher`) of its poses every ``step_s``
    [s] with the tensions and lengths of the current estimate
    (:func:`~controller.online_ident.planned_samples`), with the tracker's fixes and
    without (tensions and encoders only). ``{"tracker"|"no_tracker": {"determined" (count),
    "parameters" (count), "rank", "undetermined" [names]}}``."""
    return poses_identifiability(ident, trajectory_poses(trajectory, step_s))


def trajectory_poses(trajectory, step_s: float = IDENT_STEP_S) -> np.ndarray:
    """(P,6) the trajectory's poses every ``step_s`` [s]."""
    t = np.arange(0.0, trajectory.duration_s + 1e-9, step_s)
    return np.asarray(trajectory.sample(t).pose, float).reshape(-1, 6)


def poses_identifiability(ident: OnlineIdentifier, poses: np.ndarray) -> dict[str, dict]:
    """:func:`path_identifiability` of the poses (P,6)."""
    out = {}
    for key, tracked in (("tracker", True), ("no_tracker", False)):
        fi = ident.fisher(planned_samples(ident, poses, tracked))
        out[key] = {"determined": int(np.sum(fi.determined)), "parameters": len(fi.names),
                    "rank": fi.rank, "undetermined": fi.undetermined()}
    return out


def identifiability_text(idf: dict[str, dict]) -> str:
    """One line per case of :func:`path_identifiability`."""
    lines = []
    for key, what in (("tracker", "with the tracker"), ("no_tracker", "without it")):
        d = idf[key]
        und = d["undetermined"]
        names = ", ".join(und[:12]) + (f" and {len(und) - 12} more" if len(und) > 12 else "")
        lines.append(f"{what}: {d['determined']} of {d['parameters']} parameters determined "
                     f"(rank {d['rank']}){'; not: ' + names if und else ''}")
    return "; ".join(lines)


@dataclass
class LearnSummary:
    """What the learner did (plain data for ``--json``)."""

    updates: int = 0
    samples: int = 0
    rejected: int = 0
    handovers: int = 0
    events: list[dict] = field(default_factory=list)
    offsets_mm: dict[str, float] = field(default_factory=dict)
    sd_mm_max: float | None = None


class LoopLearner:
    """Online identification for one run: ``tracker`` (``read()`` -> ``.valid``, ``.pose``,
    ``.t_s``); ``period_s`` [s] between estimator updates and hand-overs; ``options`` the
    estimator's noise and limits; ``rate_offset`` [m/s] the hand-over's rate; ``per_update``:
    samples kept per update, spread over the period (the errors of one visit of the winches
    are shared by its samples: more of them would count the same error as independent);
    ``sync_s`` [s]: a fix is paired with the cycle's readings only when its time is within
    this of theirs (moving at 0.1 m/s, 0.1 s between them is a centimetre of error);
    ``still_s`` [s]: samples are kept only once the commanded pose has stood still this long
    (the simulated plant settles at its own rate: while moving, the fix, the lengths and the
    tensions are of different instants; measured on paper-centre, 10 to 20 mm of length
    residual at 0.1 m/s even under the true robot); ``correlated``: the hand-over's
    correlation limit (:meth:`~controller.online_ident.ModelHandover.target`);
    ``use_tracker``: False learns from tensions and encoders only (the commanded pose stands
    for the pose, :class:`~controller.online_ident.Measurement` ``tracked=False``: the
    residual's ``n - 6`` directions a pose error cannot produce), whatever the tracker
    gives (it may still serve the loop's initialisation and the recording);
    ``state_time``: the time [s, the readings' clock] of the platform state the readings
    are of (the simulated plant's last settle, :attr:`firmware_sim.rig.SimRig.last`): when
    given, samples are kept while moving too, at the cycles whose readings are of a settled
    state (quasi-static samples of the moving platform: their length residual under the
    true robot is that at rest, 0.6 mm RMS on paper-centre at 0.5 m/s, against 7 mm for
    the cycles between two settles); without it, only at rest (``still_s``);
    ``threaded``: the estimator's updates (and the identifiability of the trajectory, said
    at the first hand-over after the thread computed it) run on a thread of their own
    (:class:`_EstimatorThread`), not in the cycle: the cycle hands the period's samples
    over and, at the same period, moves the hand-over toward the estimate of the last
    update the thread finished (under its lock; while an update is in progress the
    hand-over waits for the next period: the cycle never waits for the estimator).
    :meth:`close` ends the thread; ``process``: with ``threaded``, the estimator in a
    process of its own instead (:class:`_EstimatorProcess`: a thread of the loop's process
    shares its interpreter lock, so a busy estimator delays the cycles by up to the
    interpreter's switch interval, 5 ms, each time); ``handover_s`` [s] between two
    hand-overs of the model (default a tenth of ``period_s``): the model moves toward the
    estimate by the rate times this each time, so that a setpoint moves by a fraction of a
    millimetre more than the path asks at each hand-over, never by the period's worth at
    once;
    ``tracked_s`` [s]: with ``use_tracker``, the tracker's fixes are used this long after the
    first cycle (a number, or a callable that returns it, asked at the first cycle, e.g. the
    warm-up's duration), then tensions and encoders only (a ``learn_untracked`` event); the
    estimator then moves only the directions these determine
    (:attr:`~controller.online_ident.IdentOptions.untracked_ratio`); with ``untracked``
    False, the learning stops then instead (the hand-over still reaches the estimate).
    None: the tracker all the run;
    ``shared_clock``: the tracker's fix times are on the readings' clock (the in-process
    rig): a fix pairs with a cycle within ``sync_s``; False (a tracker on its own clock, e.g.
    over TCP): a fix pairs with a cycle at rest (``still_s``, whatever ``state_time``) when
    it was received after the platform had stood still ``still_s`` (its ``age_s``)."""

    def __init__(self, tracker, period_s: float = 0.5, options: IdentOptions | None = None,
                 rate_offset: float = 2e-3, per_update: int = 4, sync_s: float = 1e-3,
                 still_s: float = 0.3, correlated: float = 0.5,
                 rate_compliance: float = 2e-6,
                 use_tracker: bool = True,
                 state_time: Callable[[], float] | None = None,
                 threaded: bool = False, handover_s: float | None = None,
                 tracked_s: float | Callable[[], float | None] | None = None,
                 untracked: bool = True, process: bool = False,
                 shared_clock: bool = True) -> None:
        self.tracker = tracker
        self.shared_clock = bool(shared_clock)
        self.untracked = bool(untracked)
        self._learning = True
        self.tracked_s = tracked_s
        self._untracked_at = np.inf  #: [s] loop time the tracker's fixes stop being used
        self.state_time = state_time
        self.use_tracker = bool(use_tracker)
        self.period_s = float(period_s)
        self.handover_s = self.period_s / 10.0 if handover_s is None else float(handover_s)
        self._next_hand = self._last_hand = 0.0
        self.options = options
        self.rate_offset = rate_offset
        self.rate_compliance = rate_compliance
        self.correlated = float(correlated)
        self.sync_s = float(sync_s)
        self.still_s = float(still_s)
        self._last_des: np.ndarray | None = None
        self._still_since = -np.inf
        self._spacing = self.period_s / max(int(per_update), 1)
        self._last_kept = -np.inf
        self.ident: OnlineIdentifier | None = None
        self.hand: ModelHandover | None = None
        self.summary = LearnSummary()
        self._batch: list[Measurement] = []
        self._last_fix = -np.inf
        self._next = None
        self._new_events: list[dict] = []
        self._worker: _EstimatorThread | _EstimatorProcess | None = None
        self.process = bool(process)
        #: the estimator's class (a test slows it down)
        self.ident_class: type[OnlineIdentifier] = OnlineIdentifier
        self.threaded = bool(threaded)
        if self.threaded and self.process:  # started now: its start-up before the motion
            self._worker = _EstimatorProcess()
        #: the run's trajectory (a callable returning it, set by the loop's owner): its
        #: identifiability is said at the first cycle, before the platform moves
        self.trajectory: Callable[[], object] | None = None
        self.identifiable: dict | None = None

    def _start(self, ctl: LengthController) -> None:
        readings = ctl.init_readings if ctl.init_readings is not None else ctl.init_tensions
        self.ident = self.ident_class(ctl.robot, ctl.init_pose, readings,
                                      reference=ctl.reference, options=self.options)
        self.hand = ModelHandover(self.ident, rate_offset=self.rate_offset,
                                  rate_compliance=self.rate_compliance,
                                  correlated=self.correlated)
        if self.threaded and self.process:
            self._worker.begin(self.ident)
        elif self.threaded:
            self._worker = _EstimatorThread(self.ident)

    def __call__(self, t: float, r, pose_des: np.ndarray,
                 ctl: LengthController) -> list[tuple[str, str]]:
        """One cycle at loop time ``t`` [s] with the hardware's readings ``r`` (``tensions_N``,
        ``tensions_ok``, ``lengths_m``): the events (kind, text) to log."""
        first: list[tuple[str, str]] = []
        if self.ident is None:
            self._start(ctl)
            self._next = t + self.period_s
            self._next_hand = t + self.handover_s
            self._last_hand = t
            traj = self.trajectory() if self.trajectory is not None else None
            if traj is not None and self._worker is not None:  # said when the thread has it
                self._worker.call_identifiability(trajectory_poses(traj))
            elif traj is not None:
                self.identifiable = path_identifiability(self.ident, traj)
                first.append(("learn_identifiable", identifiability_text(self.identifiable)))
            ts = self.tracked_s() if callable(self.tracked_s) else self.tracked_s
            if ts is not None and self.use_tracker:
                self._untracked_at = t + float(ts)
        if t >= self._untracked_at:
            self._untracked_at = np.inf
            self._update()  # the tracked samples in a batch of their own
            self.use_tracker = False
            self._learning = self.untracked
            first.append(("learn_untracked", "the tracker's fixes are no longer used: tensions "
                          "and encoders only, along the directions they determine"
                          if self.untracked else "the tracker's fixes are no longer used: "
                          "learning stops, the model is kept"))
        moved = self._last_des is not None and np.abs(pose_des - self._last_des).max() > 1e-9
        self._last_des = np.array(pose_des, float)
        if moved:
            self._still_since = t
        if self.state_time is not None and self.shared_clock:
            still = abs(self.state_time() - r.t_s) <= self.sync_s
        else:
            still = t - self._still_since >= self.still_s
        due = t - self._last_kept >= self._spacing * 0.999
        if self._learning and still and np.all(r.tensions_ok) and due:
            m = self._sample(t, r, pose_des)
            if m is not None:
                self._last_kept = t
                self._batch.append(m)
        if t >= self._next:
            self._next = t + self.period_s
            self._update()
        if t < self._next_hand:
            return first
        self._next_hand = t + self.handover_s
        return first + self._handover(t, ctl)

    def _sample(self, t: float, r, pose_des: np.ndarray) -> Measurement | None:
        """This cycle's sample: with the tracker, its fix when it is of the plant as of this
        cycle's readings (the tracker measures the pose the plant settled in for these
        lengths and tensions: an older fix is of other lengths), else none; without, the
        commanded pose."""
        if not self.use_tracker:
            return Measurement(np.array(pose_des, float), np.array(r.tensions_N),
                               np.array(r.lengths_m), False, t)
        tr = self.tracker.read()
        if self.shared_clock:
            now = abs(tr.t_s - r.t_s) <= self.sync_s
        else:  # received after the platform stood still long enough
            now = t - tr.age_s >= self._still_since + self.still_s
        if not (tr.valid and now and tr.t_s > self._last_fix and np.all(np.isfinite(tr.pose))):
            return None
        self._last_fix = tr.t_s
        return Measurement(np.array(tr.pose, float), np.array(r.tensions_N),
                           np.array(r.lengths_m), True, t)

    def _update(self) -> None:
        """The period's batch to the estimator (its thread, or now)."""
        if not self._batch:
            return
        batch, self._batch = self._batch, []
        if self._worker is not None:
            self._worker.submit(batch)
        else:
            self._record(self.ident.update(batch), len(batch))

    def _handover(self, t: float, ctl: LengthController) -> list[tuple[str, str]]:
        """Move the model toward the estimate for the time since the last hand-over and give it
        to the controller; the events of the updates finished since."""
        robot, results, moved = None, [], False
        if self._worker is None or self._worker.lock.acquire(blocking=False):
            # threaded: the estimate as of the last update the thread finished; while it
            # updates, the hand-over waits for the next one (the cycle never waits)
            try:
                if self._worker is not None:
                    results = self._worker.take()
                _, changed = self.hand.advance(t - self._last_hand)
                robot = self.hand.robot() if changed else None
                moved = True
            finally:
                if self._worker is not None:
                    self._worker.lock.release()
        if moved:
            self._last_hand = t
        out = self._results(results)
        out += [(f"learn_{e['kind']}", e["text"]) for e in self._new_events]
        self._new_events = []
        if robot is not None:
            try:
                ctl.set_model(robot)
                self.summary.handovers += 1
            except ValueError as exc:
                out.append(("learn_handover_refused", str(exc)))
        return out

    def _results(self, results: list) -> list[tuple[str, str]]:
        """Record what the thread finished (updates; the identifiability, said as an
        event)."""
        out = []
        for res, k in results:
            if k is None:
                self.identifiable = res
                out.append(("learn_identifiable", identifiability_text(res)))
            else:
                self._record(res, k)
        return out

    def _record(self, res, k: int) -> None:
        s = self.summary
        s.updates += 1
        s.samples += k
        s.rejected += bool(res.rejected)
        for e in res.events:
            ev = {"t": e.t, "kind": e.kind, "text": e.detail}
            s.events.append(ev)
            self._new_events.append(ev)

    def close(self) -> None:
        """End the estimator's thread (threaded mode; waits for the update in progress)."""
        if self._worker is not None:
            self._worker.close()
            with self._worker.lock:
                self._results(self._worker.take())

    def identified(self) -> Robot | None:
        """The identified robot: the estimate of the parameters the run determined, the
        model's values of the others (the hand-over's target; None before the first cycle)."""
        if self.ident is None:
            return None
        return self.ident.robot_at(self.hand.target(), f"{self.ident.model.name}_identified")

    def report(self) -> dict:
        """The summary with the estimate: exit offsets [mm] and their largest sd [mm]; the
        drift detections' summary (:meth:`controller.online_ident.DriftReport.summary`)."""
        s = self.summary
        if self.ident is not None:
            n = self.ident.n_offsets
            s.offsets_mm = {k: round(1e3 * float(v), 3)
                            for k, v in zip(self.ident.names[:n], self.ident.theta[:n],
                                            strict=True)}
            s.sd_mm_max = round(1e3 * float(self.ident.sd[:n].max()), 3)
        return {"updates": s.updates, "samples": s.samples, "rejected": s.rejected,
                "handovers": s.handovers, "events": s.events, "offsets_mm": s.offsets_mm,
                "offset_sd_mm_max": s.sd_mm_max, "identifiable": self.identifiable,
                "untracked_directions": self._untracked_count(),
                "drift": None if self.ident is None else self.ident.drift_report.summary()}

    def _untracked_count(self) -> int | None:
        """How many directions the untracked samples determined (None: no untracked
        learning in this run)."""
        if self.ident is None or self.use_tracker:
            return None
        return int(self.ident.untracked_directions().shape[1])


class _EstimatorThread:
    """The estimator's updates on a daemon thread: :meth:`submit` a batch or :meth:`call` a
    function of the estimator (both return at once; they queue up), :meth:`take` the results
    finished since the last call, ``(UpdateResult, samples)`` or ``(value, None)`` (hold
    :attr:`lock`: the estimate does not change under it), :meth:`close`."""

    def __init__(self, ident: OnlineIdentifier) -> None:
        import queue
        import threading

        self.ident = ident
        self.lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue()
        self._done: list = []
        self._thread = threading.Thread(target=self._run, name="cdpr-estimator", daemon=True)
        self._thread.start()

    def submit(self, batch: list[Measurement]) -> None:
        self._queue.put(batch)

    def call_identifiability(self, poses: np.ndarray) -> None:
        """:func:`poses_identifiability` of ``poses`` (P,6), as a result ``(value, None)``."""
        self._queue.put(lambda: poses_identifiability(self.ident, poses))

    def take(self) -> list:
        done, self._done = self._done, []
        return done

    def _run(self) -> None:
        while True:
            batch = self._queue.get()
            if batch is None:
                return
            with self.lock:
                if callable(batch):
                    self._done.append((batch(), None))
                else:
                    self._done.append((self.ident.update(batch), len(batch)))

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join()


class _EstimatorProcess:
    """The estimator in a process of its own (``spawn``): no interpreter lock shared with the
    loop, so the estimator's work never delays a cycle (a loop thread in SCHED_FIFO preempts
    it; without, it runs :data:`ESTIMATOR_NICE` nicer). The same interface as
    :class:`_EstimatorThread`: :meth:`submit` and :meth:`call_identifiability` send to the
    process (a few hundred bytes, at once); :meth:`take` receives what it finished, without
    waiting, and sets the estimate and its covariance of each update on :attr:`ident`, the
    loop's copy (what the hand-over reads); :meth:`close` ends the process and takes its
    whole final state. :attr:`lock` is the loop's own (never held by the process)."""

    def __init__(self) -> None:
        import multiprocessing
        import threading

        self.ident: OnlineIdentifier | None = None
        self.lock = threading.Lock()
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_estimator_main, args=(child,),
                                 name="cdpr-estimator", daemon=True)
        self._proc.start()
        child.close()
        self._pending: list = []

    def begin(self, ident: OnlineIdentifier) -> None:
        """The estimator to run (its state at the first cycle); :attr:`ident` the loop's
        copy."""
        self.ident = ident
        self._conn.send(("begin", ident))

    def submit(self, batch: list[Measurement]) -> None:
        self._conn.send(("update", batch))

    def call_identifiability(self, poses: np.ndarray) -> None:
        self._conn.send(("identifiable", poses))

    def take(self) -> list:
        done, self._pending = self._pending, []
        while not self._conn.closed and self._conn.poll():
            done += self._receive(self._conn.recv())
        return done

    def _receive(self, msg: tuple) -> list:
        kind = msg[0]
        if kind == "update":
            _, res, k, theta, P = msg
            self.ident.theta, self.ident.P = theta, P
            return [(res, k)]
        if kind == "identifiable":
            return [(msg[1], None)]
        if kind == "final" and msg[1] is not None and self.ident is not None:
            self.ident.__dict__.update(msg[1].__dict__)
        return []

    def close(self, timeout_s: float = 60.0) -> None:
        """The updates sent are finished, then the process ends (at most ``timeout_s``)."""
        try:
            self._conn.send(("close",))
            while self._conn.poll(timeout_s):
                msg = self._conn.recv()
                self._pending += self._receive(msg)
                if msg[0] == "final":
                    break
        except (EOFError, OSError):
            pass
        finally:
            self._proc.join(timeout_s)
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join()
            self._conn.close()


def _estimator_main(conn) -> None:
    """:class:`_EstimatorProcess`'s process: the estimator (``begin``), then its updates and
    identifiability until ``close``, then the whole estimator back. It runs
    :data:`ESTIMATOR_NICE` nicer than the loop: on a busy machine the loop and the drives'
    process get the processor first."""
    import os

    try:
        os.nice(ESTIMATOR_NICE)
    except OSError:  # not permitted: normal priority
        pass
    ident: OnlineIdentifier | None = None
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the loop's process ended
            return
        if msg[0] == "begin":
            ident = msg[1]
        elif msg[0] == "update":
            res = ident.update(msg[1])
            conn.send(("update", res, len(msg[1]), ident.theta.copy(), ident.P.copy()))
        elif msg[0] == "identifiable":
            conn.send(("identifiable", poses_identifiability(ident, msg[1])))
        else:
            conn.send(("final", ident))
            return
