"""Online identification: the masts' settled exit points and stiffnesses, while the robot works.

A recursive estimator (an extended Kalman filter on constant parameters with a small random
walk) on the diagnosis's inverse **length residual** (``bench/diagnosis/residuals.py``): at a
pose ``p`` with load-cell readings ``tau_m`` and encoder readings ``l``,

    r(theta) = L0_H(p, tau) - [ s (l - d_model(p0)) + u0_H + dl ]        (n,) [m]

where ``H`` is the controller's model with the parameters ``theta`` applied
(:func:`controller.effects.apply_effects`), ``L0_H(p, tau)`` the unstretched lengths that hold
the platform at ``p`` with the true tensions ``tau`` (masts deflected under them,
:func:`controller.statics.batch_statics`), and the bracket the unstretched lengths behind the
encoders by the initialisation convention (:func:`controller.statics.unstretched_from_readings`,
``u0_H`` from the readings at initialisation, :func:`controller.statics.init_unstretched`).
The same functions the diagnosis calls: one physics.

Parameters ``theta`` (:attr:`OnlineIdentifier.names`), in F_b:

- ``dx_<cable>``, ``dy_<cable>``, ``dz_<cable>`` [m]: the ``exit_point_offset`` effect, added to
  the model's surveyed exit points;
- ``cx_<mast>``, ``cy_<mast>``, ``cz_<mast>`` [rad/(N m)]: the compliance ``1/k`` of each mast's
  joint axes (the ``mast_compliance`` effect's ``k`` = 1/c; 0 = rigid). Compliance, not
  stiffness, is estimated: the deflection is linear in it.

A measurement's pose is a tracker fix (``tracked``: its noise is carried into the residual),
or, without one, the commanded pose: then the residual is projected on the ``n - 6``
directions a pose error cannot produce (first order), as the diagnosis does without a tracker.

Safety: estimates are clipped to physical bounds (the effects' bounds); a step larger than
``max_step`` is clipped; an innovation beyond its chi-square threshold (a sudden change), a
clipped step, an estimate at a bound, a covariance that grows: each is an :class:`Event`.
The controller never takes the estimate directly: :class:`ModelHandover` moves the model it
uses toward the estimate at a bounded rate.

Pure: no I/O, no clock (times are arguments).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from controller.cycle import reference_lengths
from controller.effects import effect_params
from controller.robot import Robot
from controller.statics import (
    batch_statics,
    init_unstretched,
    pose_statics,
    true_tensions,
    unstretched_from_readings,
)

#: finite-difference steps: exit offsets [m], compliance [rad/(N m)], pose [m, rad], tension [N]
FD_OFFSET = 1e-4
FD_COMPLIANCE = 1e-8
FD_POSE = 1e-5
FD_TENSION = 1.0


@dataclass(frozen=True)
class Measurement:
    """One sample: ``pose`` (6,) in F_b [m, rad] (a tracker fix when ``tracked``, else the
    commanded pose); ``tensions`` (n,) load-cell readings [N]; ``lengths`` (n,) encoder
    readings [m]; ``t`` [s]."""

    pose: np.ndarray
    tensions: np.ndarray
    lengths: np.ndarray
    tracked: bool = True
    t: float = 0.0


@dataclass(frozen=True)
class Event:
    """Something the operator must see: ``kind`` one of ``sudden_change``,
    ``large_correction``, ``bound``, ``covariance_growing``, ``unusable``, ``drift``,
    ``drift_end`` (:class:`DriftReport`); ``t`` [s];
    ``detail``."""

    kind: str
    t: float
    detail: str


@dataclass
class IdentOptions:
    """Noise and safety limits. ``sigma_length`` encoder noise [m]; ``sigma_tension`` load-cell
    noise [N]; ``sigma_pose`` tracker noise (position [m], orientation [rad]);
    ``prior_offset`` [m] / ``prior_compliance`` [rad/(N m)] prior standard deviations;
    ``walk_offset`` [m/sqrt(s)] / ``walk_compliance`` / ``walk_length`` [m/sqrt(s)] random
    walk of the parameters (the length offsets' too: the encoders keep the reference of the
    initialisation, so an exit that moves afterwards moves them with it);
    ``max_step_offset`` [m] / ``max_step_compliance`` largest correction per update;
    ``prior_length`` [m]: a cable length offset expected beyond the encoder reference's
    uncertainty (0: none); ``stiffness_min`` [N m/rad]: the stiffest bound on a joint's
    compliance (1/it; the masts' fixed-point iteration diverges near 1e3 for ROCASPECT);
    ``alarm_p`` false-alarm probability of the innovation test per update;
    ``grow_updates``: covariance growing over this many updates in a row is an event;
    ``iterations``: linearisations per update (iterated EKF; 1 = plain EKF); ``gate``: a
    batch that fails the innovation test is not learnt from (only its event is kept);
    ``drift_window`` updates: the sum of their normalised innovations squared is tested
    against the chi-square quantile of ``drift_p`` (a slow change no single batch shows,
    e.g. ropes that keep settling): beyond it, a ``drift`` event and the covariance is
    multiplied by ``drift_inflate`` (the filter learns again; the test restarts on the next
    ``drift_window`` updates); and the estimate's move from its reference (that of the
    ``drift_window``-th update, or of the last such event) is tested at ``drift_p`` in the
    metric of the reference's covariance: a filter that follows a slow change by its random
    walk, with no innovation beyond its noise, says so too (a ``drift`` event, no
    inflation);
    ``persist``: that many batches in a row failing the innovation test are a change that
    persists, not outliers: when the correction they call for (with the covariance inflated
    as above) is within ``max_step_*``, a ``drift`` event and the batch learnt from (junk
    that persists asks for more: still not learnt);
    ``report_move`` [m], ``report_hold_s`` [s], ``report_quiet_s`` [s]: what of the drift
    detections above becomes an event (:class:`DriftReport`: the first detection, then a
    change of the model's lengths by ``report_move`` since the last event, none in the
    ``report_hold_s`` after an event, the drift's end after ``report_quiet_s`` without
    detection); ``drift_walk``: while a drift goes on (from
    its first detection to its end, :attr:`DriftReport.active`), the random walk's variances
    are multiplied by this (the estimate follows a change that goes on faster; 1: no);
    ``untracked_ratio``: without the tracker's fixes (batches of untracked samples only),
    the estimate moves only along the directions the untracked samples since the tracker
    stopped determine: those whose standard deviation, from the covariance when the
    tracker stopped (the prior when there never was one), their information alone brings
    below this ratio of it (:meth:`OnlineIdentifier.untracked_directions`); the others keep
    the estimate of the tracker's time (0: off, every direction learnt);
    ``untracked_visible``: of those, only the combinations that would move the platform by
    at most this ratio of the change the untracked samples see (what moves the platform is
    what they cannot check; 0: no such restriction)."""

    sigma_length: float = 5e-5
    sigma_tension: float = 0.5
    sigma_pose: tuple[float, float] = (3e-5, 2e-5)
    prior_offset: float = 0.02
    prior_compliance: float = 2e-5
    walk_offset: float = 1e-6
    walk_compliance: float = 1e-10
    walk_length: float = 1e-6
    max_step_offset: float = 0.05
    max_step_compliance: float = 1e-4
    prior_length: float = 0.0
    stiffness_min: float = 1e4
    alarm_p: float = 1e-6
    grow_updates: int = 20
    iterations: int = 1
    gate: bool = True
    drift_window: int = 20
    drift_p: float = 1e-6
    drift_inflate: float = 4.0
    persist: int = 3
    report_move: float = 1e-3
    report_hold_s: float = 120.0
    report_quiet_s: float = 600.0
    drift_walk: float = 9.0
    untracked_ratio: float = 0.3
    untracked_visible: float = 0.1


@dataclass
class UpdateResult:
    """One update: ``nis`` normalised innovation squared, ``dof`` its degrees of freedom,
    ``events`` raised by it, ``used`` the number of samples used, ``rejected`` whether the
    batch failed the innovation test and was not learnt from."""

    nis: float
    dof: int
    events: list[Event] = field(default_factory=list)
    used: int = 0
    rejected: bool = False


class DriftReport:
    """What of the estimator's drift detections the operator sees as events: the first
    detection (``drift``: the robot started changing, and when); then, while the drift goes
    on, a ``drift`` event only when the model changed materially since the last event (its
    length residual at the update's samples, what the setpoints follow, by ``move`` [m] or
    more: a step, or a slow drift's accumulated change); the estimate's change during the
    ``hold_s`` [s] after an event is that event's (the filter converging on the change it
    reported: no event); a ``drift_end`` event when no detection came for ``quiet_s`` [s]
    (the next detection starts a new drift: hysteresis).
    Every detection is counted (:meth:`summary`). The exit points alone are no measure of
    the change: along a cable, an exit's move and a length offset are the same to the data,
    and each of them wanders by millimetres while their sum is known to micrometres."""

    def __init__(self, move: float = 1e-3, hold_s: float = 120.0,
                 quiet_s: float = 600.0) -> None:
        self.move, self.hold_s, self.quiet_s = float(move), float(hold_s), float(quiet_s)
        self.active = False  #: a drift is going on
        self.first_s: float | None = None  #: [s] the run's first detection
        self.detections = 0  #: detections of the run
        self.said = 0  #: ``drift`` events of the run
        self.drifts = 0  #: drifts (first detection to ``drift_end``) of the run
        self.moved = 0.0  #: [m] the largest length change from a drift's start, of the run
        self._start: np.ndarray | None = None  #: the estimate at the drift's start
        self._ref: np.ndarray | None = None  #: the estimate the next event's change is from
        self._ref_s = self._last_event = self._last_detect = -np.inf
        self._since = 0  #: detections since the last event

    def observe(self, t: float, theta: np.ndarray, found: list[Event],
                residual: Callable[[np.ndarray], np.ndarray]) -> list[Event]:
        """The events to say at update time ``t`` [s] with the estimate ``theta`` (p,), the
        update's detections ``found`` (kind ``drift``, or ``drift_step``: a change that
        persisted over batches beyond the innovation test) and
        ``residual``: the length residuals [m] of an estimate at the update's samples."""
        self.detections += len(found)
        self._since += len(found)
        if found:
            self._last_detect = t
        if found and not self.active:
            self.active, self.drifts = True, self.drifts + 1
            self.first_s = t if self.first_s is None else self.first_s
            self._start = theta.copy()
            return self._say(t, theta, f"drift detected: {found[0].detail}")
        if not self.active:
            return []
        if t - self._last_event <= self.hold_s:  # the last event's change, converging
            self._ref, self._ref_s = theta.copy(), t
            return []
        now, ref, start = _each_once(residual, [theta, self._ref, self._start])
        move = _largest_change(now, ref)
        self.moved = max(self.moved, _largest_change(now, start))
        if move >= self.move:
            return self._say(t, theta, f"the robot goes on changing: the model's lengths "
                             f"changed by up to {1e3 * move:.1f} mm since t = "
                             f"{self._ref_s:.1f} s ({self._since} detections since the last "
                             f"event; the last: {found[-1].detail if found else 'none'})")
        if t - self._last_detect >= self.quiet_s:
            self.active = False
            return [Event("drift_end", t, f"no drift detected for {self.quiet_s:.0f} s: the "
                          f"model's lengths changed by up to {1e3 * self.moved:.1f} mm since "
                          f"the first detection")]
        return []

    def _say(self, t: float, theta: np.ndarray, text: str) -> list[Event]:
        self.said += 1
        self._ref, self._ref_s, self._last_event, self._since = theta.copy(), t, t, 0
        return [Event("drift", t, text)]

    def summary(self) -> dict[str, float | int | bool | None]:
        """``detected_at_s`` (the first detection, None: none), ``detections``, ``events``
        (``drift`` events said), ``drifts``, ``active`` (a drift going on at the end),
        ``length_change_mm`` (the model's largest length change from a drift's start, at the
        samples of the updates after the hold of an event)."""
        return {"detected_at_s": self.first_s, "detections": self.detections,
                "events": self.said, "drifts": self.drifts, "active": self.active,
                "length_change_mm": round(1e3 * self.moved, 3)}


def _each_once(residual: Callable[[np.ndarray], np.ndarray], thetas: list[np.ndarray]
               ) -> list[np.ndarray]:
    """``residual(th)`` of each estimate in ``thetas``, an estimate equal to an earlier one
    not evaluated again (its statics at the batch's samples are the same): the estimates at
    a drift's start, at the last event and now coincide where the estimate stood still (a
    rejected update) or no update fell in an event's hold."""
    out: list[np.ndarray] = []
    for k, th in enumerate(thetas):
        same = next((i for i in range(k) if np.array_equal(thetas[i], th)), None)
        out.append(residual(th) if same is None else out[same])
    return out


def _largest_change(a: np.ndarray, b: np.ndarray) -> float:
    """[m] the largest difference of two residual arrays (0 where either is NaN)."""
    d = np.abs(np.asarray(a) - np.asarray(b))
    return float(np.max(np.where(np.isfinite(d), d, 0.0), initial=0.0))


class OnlineIdentifier:
    """Recursive estimate of exit-point offsets and mast compliances of ``model``.

    ``init_pose`` (6,) and ``init_readings`` (n,) [N]: the pose and load-cell readings when the
    encoders were referenced (``reference``: d_model(p0) of the model the controller ran with;
    default that of ``model``). ``theta0``: a starting estimate (default: the model's own
    compliance, no offsets).
    """

    def __init__(self, model: Robot, init_pose: np.ndarray, init_readings: np.ndarray,
                 reference: np.ndarray | None = None, options: IdentOptions | None = None,
                 theta0: np.ndarray | None = None) -> None:
        self.model = model
        self.opt = options or IdentOptions()
        self.init_pose = np.asarray(init_pose, float)
        self.init_readings = np.asarray(init_readings, float)
        self.reference = reference_lengths(model, self.init_pose) if reference is None \
            else np.asarray(reference, float)
        n, m = model.n_cables, model.n_masts
        self.n_offsets = 3 * n
        self.n_compliance = 3 * m
        self.names = [s.key for s in effect_params("exit_point_offset", model)] + \
            [f"c{ax}_{mid}" for mid in model.mast_ids for ax in "xyz"] + \
            [s.key for s in effect_params("cable_length_offset", model)]
        lo_l, hi_l = effect_params("cable_length_offset", model)[0].bounds
        lo_o, hi_o = effect_params("exit_point_offset", model)[0].bounds
        k_lo = max(effect_params("mast_compliance", model)[0].bounds[0] if m else 0.0,
                   self.opt.stiffness_min)
        #: physical bounds of each parameter (lower, upper) (p,)
        self.lower = np.r_[np.full(3 * n, lo_o), np.zeros(3 * m), np.full(n, lo_l)]
        self.upper = np.r_[np.full(3 * n, hi_o), np.full(3 * m, 1.0 / k_lo), np.full(n, hi_l)]
        c0 = model.compliance.ravel()
        self.theta = np.r_[np.zeros(3 * n), c0, np.zeros(n)] if theta0 is None \
            else np.array(theta0, float)
        ref_cov = self._reference_cov()
        #: (p,) prior variances: the scale the covariance is compared in
        self.prior = np.r_[np.full(3 * n, self.opt.prior_offset ** 2),
                           np.full(3 * m, self.opt.prior_compliance ** 2), np.diag(ref_cov)]
        self.P = np.diag(self.prior)
        self.P[-n:, -n:] = ref_cov
        self.P0 = self.P.copy()  #: the prior covariance
        #: the covariance an inflation never opens beyond (:meth:`_inflate`)
        self._cap = np.diag(np.r_[self.prior[:3 * n + 3 * m],
                                  np.full(n, self.opt.prior_offset ** 2)])
        self._walk = np.r_[np.full(3 * n, self.opt.walk_offset ** 2),
                           np.full(3 * m, self.opt.walk_compliance ** 2),
                           np.full(n, self.opt.walk_length ** 2)]
        self._max_step = np.r_[np.full(3 * n, self.opt.max_step_offset),
                               np.full(3 * m, self.opt.max_step_compliance),
                               np.full(n, self.opt.max_step_offset)]
        self._fd = np.r_[np.full(3 * n, FD_OFFSET), np.full(3 * m, FD_COMPLIANCE),
                         np.full(n, FD_OFFSET)]
        self._groups = self._column_groups()
        #: [N] a cable read below this is slack (the diagnosis's threshold: four times the
        #: load cells' noise, at least 1 N)
        self.slack_threshold = max(1.0, 4.0 * self.opt.sigma_tension)
        self._t_last: float | None = None
        self._grow = 0
        self._trace_last = float(np.trace(self.P))
        self.events: list[Event] = []
        #: every drift detection (kinds ``drift`` and ``drift_step``); the events said of
        #: them: :attr:`drift_report`
        self.detections: list[Event] = []
        self.drift_report = DriftReport(self.opt.report_move, self.opt.report_hold_s,
                                        self.opt.report_quiet_s)
        self.updates = 0
        self._window: list[tuple[float, int]] = []  #: (nis, dof) of the last updates
        self._rejects = 0  #: batches in a row that failed the innovation test
        #: the estimate and covariance the move test compares with (None: not yet)
        self._moved_ref: tuple[np.ndarray, np.ndarray] | None = None
        #: untracked learning: the covariance when the tracker stopped (None: tracked)
        self._anchor: np.ndarray | None = None
        self._info = np.zeros_like(self.P)  #: untracked information since then
        #: the same of the residuals' parts a pose error can produce (the pose-visible part:
        #: what moves the platform, which untracked samples cannot see)
        self._seen = np.zeros_like(self.P)
        self._visible = np.zeros((0, len(self.theta)))  #: the last :meth:`_rows`' of those

    # ----- the model ------------------------------------------------------------------
    def robot_at(self, theta: np.ndarray | None = None, name: str | None = None) -> Robot:
        """The model with parameters ``theta`` (default the estimate) applied."""
        th = self.theta if theta is None else np.asarray(theta, float)
        n, nc = self.n_offsets, self.n_compliance
        exits = self.model.exits + th[:n].reshape(-1, 3)
        c = th[n:n + nc].reshape(-1, 3)
        stiffness = np.where(c > 0, 1.0 / np.where(c > 0, c, 1.0), np.inf)
        return self.model.replace(exits=exits, stiffness=stiffness,
                                  length_offset=self.model.length_offset + th[n + nc:],
                                  name=name or self.model.name)

    def effects(self, theta: np.ndarray | None = None) -> dict[str, dict[str, float]]:
        """The parameters as effects of :mod:`controller.effects` (what
        :meth:`robot_at` applies: ``apply_effects(model, effects(theta))`` is the same robot)."""
        th = self.theta if theta is None else np.asarray(theta, float)
        n, nc = self.n_offsets, self.n_compliance
        off = {k: float(v) for k, v in zip(self.names[:n], th[:n], strict=True)}
        stiff = {f"k{k[1:]}": (1.0 / float(c) if c > 0 else float("inf"))
                 for k, c in zip(self.names[n:n + nc], th[n:n + nc], strict=True)}
        dl = {k: float(v) for k, v in zip(self.names[n + nc:], th[n + nc:], strict=True)}
        return {"exit_point_offset": off, "mast_compliance": stiff, "cable_length_offset": dl}

    def _reference_cov(self) -> np.ndarray:
        """(n,n) [m^2] how uncertain the cables' encoder references are: the load cells' noise
        at initialisation carried into ``u0`` (stretch, and the masts' deflection: correlated
        between the cables of a mast) and the encoders' noise; the prior of the length offsets
        ``dl`` (a constant length error from the initialisation on looks like an exit point's
        move along the cable)."""
        H, o = self.model, self.opt
        n = H.n_cables
        tau0 = true_tensions(H, self.init_readings)
        u_a = init_unstretched(H, self.init_pose, tau0)[0]
        J = np.empty((n, n))
        for j in range(n):
            d = np.zeros(n)
            d[j] = FD_TENSION
            J[:, j] = (init_unstretched(H, self.init_pose, tau0 + d)[0] - u_a) / FD_TENSION
        return o.sigma_tension ** 2 * J @ J.T + \
            np.eye(n) * (o.sigma_length ** 2 + o.prior_length ** 2)

    def to_robot(self, name: str | None = None) -> Robot:
        """The identified robot description (write it with
        :func:`controller.robot.save_robot`)."""
        return self.robot_at(self.theta, name or f"{self.model.name}_identified")

    @property
    def sd(self) -> np.ndarray:
        """Standard deviations of the estimate (p,) in the parameters' units."""
        return np.sqrt(np.maximum(np.diag(self.P), 0.0))

    def residuals(self, theta: np.ndarray, poses: np.ndarray, readings: np.ndarray,
                  lengths: np.ndarray) -> np.ndarray:
        """Length residuals (K,n) [m] of the model with ``theta`` at ``poses`` (K,6) with
        load-cell ``readings`` (K,n) [N] and encoder ``lengths`` (K,n) [m] (NaN where the
        statics fail, all NaN if the initialisation pose is infeasible under ``theta``)."""
        H = self.robot_at(theta)
        try:
            u0, _ = init_unstretched(H, self.init_pose, true_tensions(H, self.init_readings))
        except ValueError:
            return np.full(np.shape(lengths), np.nan)
        read = unstretched_from_readings(H, lengths, self.reference, u0)
        bs = batch_statics(H, poses, true_tensions(H, readings))
        return np.where(bs.feasible[:, None], bs.unstretched - read, np.nan)

    def _residual_at(self, theta: np.ndarray, batch: list[Measurement]) -> np.ndarray:
        """:meth:`residuals` (K,n) [m] of ``theta`` at the samples of ``batch``."""
        return self.residuals(theta, np.array([b.pose for b in batch], float),
                              np.array([b.tensions for b in batch], float),
                              np.array([b.lengths for b in batch], float))

    # ----- Jacobians -------------------------------------------------------------------
    def _column_groups(self) -> list[np.ndarray]:
        """Parameters perturbed together in one evaluation: with the tensions measured, a
        mast's exit points hang only on its own cables' parameters, so one parameter per mast
        (the same slot: cable j, axis a, or joint axis a) shares an evaluation."""
        mi = self.model.mast_index
        n, m = self.model.n_cables, self.model.n_masts
        slot = np.array([int(np.sum(mi[:c] == mi[c])) for c in range(n)])
        groups: dict[tuple, list[int]] = {}
        for c in range(n):
            for a in range(3):
                groups.setdefault(("o", slot[c], a), []).append(3 * c + a)
        for i in range(m):
            for a in range(3):
                groups.setdefault(("c", a), []).append(3 * n + 3 * i + a)
        groups[("l",)] = list(range(3 * n + 3 * m, 4 * n + 3 * m))
        return [np.array(g) for g in groups.values()]

    def _support(self, j: int) -> np.ndarray:
        """The cables (n,) bool whose residual parameter ``j`` can move (its mast's)."""
        mi = self.model.mast_index
        n, nc = self.n_offsets, self.n_compliance
        if j >= n + nc:  # a length offset: its own cable
            return np.arange(len(mi)) == j - n - nc
        mast = mi[j // 3] if j < n else (j - n) // 3
        return mi == mast

    def jacobian(self, theta: np.ndarray, poses: np.ndarray, readings: np.ndarray,
                 lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(r (K,n), J (K,n,p))``: residuals and their derivatives by the parameters (forward
        differences, one evaluation per column group)."""
        r = self.residuals(theta, poses, readings, lengths)
        J = np.zeros(r.shape + (len(theta),))
        for g in self._groups:
            step = self._fd[g]
            th = theta.copy()
            up = theta[g] + step <= self.upper[g]
            th[g] = np.where(up, theta[g] + step, theta[g] - step)  # backward at a bound
            h = th[g] - theta[g]
            dr = self.residuals(th, poses, readings, lengths) - r
            for j, hj in zip(g, h, strict=True):
                J[:, self._support(j), j] = dr[:, self._support(j)] / hj
        return r, J

    def nuisance(self, theta: np.ndarray, poses: np.ndarray, readings: np.ndarray,
                 lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(Jp (K,n,6), Jt (K,n))`` at the estimate: the residuals' derivatives by the pose
        [m/m, m/rad] and by each cable's own tension [m/N], at ``theta``."""
        K = len(poses)
        eye = np.eye(6) * FD_POSE
        stacked = (poses[:, None, :] + eye[None]).reshape(-1, 6)
        rep = lambda a: np.repeat(a, 6, axis=0)  # noqa: E731
        r0 = self.residuals(theta, poses, readings, lengths)
        rp = self.residuals(theta, stacked, rep(readings), rep(lengths)).reshape(K, 6, -1)
        Jp = np.swapaxes((rp - r0[:, None, :]) / FD_POSE, 1, 2)
        rt = self.residuals(theta, poses, readings + FD_TENSION, lengths)
        return Jp, (rt - r0) / FD_TENSION

    # ----- the update ------------------------------------------------------------------
    def _rows(self, batch: list[Measurement], theta: np.ndarray,
              nuis: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
        """Whitened innovation rows at ``theta``: ``(nu (q,), Jw (q,p), ok samples, nuis)`` for
        a batch: each sample's residual, noise-whitened; without a tracker fix, projected on
        the directions a pose error cannot produce (``nuis``: :meth:`nuisance` of the batch,
        computed when None)."""
        o = self.opt
        visible = []
        poses = np.array([b.pose for b in batch], float)
        readings = np.array([b.tensions for b in batch], float)
        lengths = np.array([b.lengths for b in batch], float)
        r, J = self.jacobian(theta, poses, readings, lengths)
        Jp, Jt = self.nuisance(theta, poses, readings, lengths) if nuis is None else nuis
        sp = np.r_[np.full(3, o.sigma_pose[0]), np.full(3, o.sigma_pose[1])]
        nus, Js = [], []
        for k, b in enumerate(batch):
            if not (np.isfinite(r[k]).all() and np.isfinite(J[k]).all()
                    and np.isfinite(Jp[k]).all()):
                continue
            # a slack cable's reading says only that it is at least as long as its chord (the
            # diagnosis's one-sided residual): no equation
            taut = true_tensions(self.model, readings[k]) >= self.slack_threshold
            if not b.tracked and np.count_nonzero(taut) <= 6:
                continue
            R = np.diag(o.sigma_length ** 2 + (Jt[k][taut] * o.sigma_tension) ** 2)
            rk, Jk, Jpk = r[k][taut], J[k][taut], Jp[k][taut]
            if b.tracked:
                R = R + (Jpk * sp) @ (Jpk * sp).T
            else:  # the directions orthogonal to the pose's
                q, _ = np.linalg.qr(Jpk, mode="complete")
                Q2 = q[:, 6:]
                visible.append(q[:, :6].T @ Jk / o.sigma_length)
                rk, Jk, R = Q2.T @ rk, Q2.T @ Jk, Q2.T @ R @ Q2
            L = np.linalg.cholesky(R)
            nus.append(-np.linalg.solve(L, rk))
            Js.append(np.linalg.solve(L, Jk))
        self._visible = np.vstack(visible) if visible else np.zeros((0, len(theta)))
        if not nus:
            return np.zeros(0), np.zeros((0, len(theta))), np.zeros(0), (Jp, Jt)
        return np.concatenate(nus), np.vstack(Js), np.ones(len(nus)), (Jp, Jt)

    def update(self, batch: list[Measurement]) -> UpdateResult:
        """One recursive update with the samples ``batch`` (taken since the last update);
        returns the innovation test and the events raised (also kept in :attr:`events`)."""
        if not batch:
            return UpdateResult(0.0, 0)
        t = float(batch[-1].t)
        if self._t_last is not None:  # random walk since the last update
            walk = self._walk * (self.opt.drift_walk if self.drift_report.active else 1.0)
            self.P = self.P + np.diag(walk * max(t - self._t_last, 0.0))
        self._t_last = t
        prior = self.theta
        nu, Jw, ok, nuis = self._rows(batch, prior)
        events: list[Event] = []
        if len(nu) == 0:  # no sample gives an equation: nothing learnt, and said
            events.append(Event("unusable", t, self._unusable(batch)))
            return UpdateResult(0.0, 0, self._said(events, t, batch), 0, rejected=True)
        nis = self._innovation_test(nu, Jw, t, events)
        Pi = None
        if any(b.tracked for b in batch):
            self._anchor = None
        elif self.opt.untracked_ratio > 0:  # only the directions the untracked data fix
            self._add_untracked(Jw)
            Pi = self._projector()
        raw, Jw = Jw, (Jw if Pi is None else Jw @ Pi)
        self._rejects = self._rejects + 1 if events else 0
        if events and self.opt.gate and self._rejects < self.opt.persist:
            # not the model's noise: not learnt from, unless it persists
            self._check_drift(nis, len(nu), t, events)
            return UpdateResult(nis, len(nu), self._said(events, t, batch), 0, rejected=True)
        persistent = bool(events) and self.opt.gate
        saved = self.P.copy()
        if persistent:  # a change that persists: learnt again, if physically plausible
            self._inflate()
            if Pi is not None:  # the projector is in the metric of the covariance: anew
                Pi = self._projector()
                Jw = raw @ Pi
        th, K, q = prior, None, len(nu)
        for it in range(self.opt.iterations):  # iterated EKF: relinearised at the update
            if it:
                nu_i, Jw_i, _, _ = self._rows(batch, th, nuis)
                if len(nu_i) != q:  # the statics fail there: keep the last linearisation
                    break
                nu, Jw = nu_i, (Jw_i if Pi is None else Jw_i @ Pi)
            y = nu + Jw @ (th - prior)  # the innovation of the prior, linearised at th
            Sc = np.linalg.cholesky(Jw @ self.P @ Jw.T + np.eye(q))
            K = np.linalg.solve(Sc.T, np.linalg.solve(Sc, Jw @ self.P)).T
            th = prior + K @ y
        step = th - prior
        ratio = float(np.max(np.abs(step) / self._max_step))
        if persistent and ratio > 1.0:  # no change the robot can make: not learnt
            self.P = saved
            self._check_drift(nis, len(nu), t, events)
            return UpdateResult(nis, len(nu), self._said(events, t, batch), 0, rejected=True)
        if persistent:
            self._window = []
            events.append(Event("drift_step", t, f"{self._rejects} batches in a row beyond the "
                                "innovation test: the robot changed; the model is "
                                "learnt again"))
            self._rejects = 0
        if ratio > 1.0:  # the same direction, shorter: the gain scaled, the covariance with it
            worst = int(np.argmax(np.abs(step) / self._max_step))
            events.append(Event("large_correction", t, f"{self.names[worst]}: correction "
                                f"{step[worst]:.3g} beyond {self._max_step[worst]:.3g} "
                                f"(taken {1.0 / ratio:.2f} of it)"))
            K, step = K / ratio, step / ratio
        if Pi is not None:  # untracked: shortened to the bounds, within the span
            K, step = self._within_bounds(K, step, t, events)
        IKH = np.eye(len(prior)) - K @ Jw
        self.P = IKH @ self.P @ IKH.T + K @ K.T  # Joseph form: consistent for any gain
        self.theta = self._bounded(self.theta + step, t, events)
        self._check_growth(t, events)
        self._check_drift(nis, q, t, events)
        self._check_moved(t, events)
        self.updates += 1
        return UpdateResult(nis, q, self._said(events, t, batch), int(ok.sum()))

    def _said(self, events: list[Event], t: float, batch: list[Measurement]) -> list[Event]:
        """An update's events as the operator sees them (kept in :attr:`events`): its drift
        detections (kept in :attr:`detections`) through :attr:`drift_report` (the model's
        change measured at the samples of ``batch``), the others as they are."""
        drift = ("drift", "drift_step")
        found = [e for e in events if e.kind in drift]
        self.detections.extend(found)
        out = [e for e in events if e.kind not in drift] + \
            self.drift_report.observe(t, self.theta, found, lambda th: self._residual_at(th, batch))
        self.events.extend(out)
        return out

    def _unusable(self, batch: list[Measurement]) -> str:
        """Why no sample of ``batch`` gave an equation."""
        few = sum(not b.tracked and np.count_nonzero(true_tensions(self.model, b.tensions)
                                                     >= self.slack_threshold) <= 6
                  for b in batch)
        return (f"no sample of {len(batch)} could be used: {few} untracked with 6 taut cables "
                f"or fewer (nothing left once the pose's 6 directions are projected out), "
                f"{len(batch) - few} with statics infeasible under the estimate")

    def _add_untracked(self, Jw: np.ndarray) -> None:
        """The information of an untracked batch's whitened rows ``Jw`` (q,p) (and of its
        pose-visible rows, :meth:`_rows`) added to that since the tracker stopped."""
        if self._anchor is None:  # the tracker just stopped (or never ran)
            self._anchor = self.P.copy()
            self._info = np.zeros_like(self.P)
            self._seen = np.zeros_like(self.P)
        self._info = self._info + Jw.T @ Jw
        self._seen = self._seen + self._visible.T @ self._visible

    def _projector(self) -> np.ndarray:
        """(p,p) the projector ``Pi`` (in the metric of the covariance ``P``: computed anew
        when ``P`` changes) on the directions :meth:`untracked_directions` finds. An untracked
        update sees the rows ``Jw @ Pi``: its gain ``P Pi^T Jw^T S^-1`` lies in their span,
        the other directions keep their estimate and their covariance (the Joseph form stays
        exact for this gain). With a projector of another ``P`` (the covariance inflated after
        it), the gain left the span: the undetermined directions moved."""
        D = self.untracked_directions()
        if D.shape[1] == 0:
            return np.zeros_like(self.P)
        Pinv_D = np.linalg.solve(self.P, D)
        return D @ np.linalg.solve(D.T @ Pinv_D, Pinv_D.T)

    def untracked_directions(self) -> np.ndarray:
        """(p,k) the directions of the parameters the untracked samples since the tracker
        stopped determine: the eigenvectors of their information scaled by the covariance
        of that time, ``L^T F L`` (``P = L L^T``), whose eigenvalue ``lambda`` shrinks the
        standard deviation below :attr:`IdentOptions.untracked_ratio` of its value then
        (``1 / sqrt(1 + lambda)`` below it), mapped back by ``L``; of these, with
        :attr:`IdentOptions.untracked_visible` > 0, only the combinations whose change of the
        lengths a pose error could produce (what would move the platform, the part of the
        residual the untracked samples project out and cannot check: ``G``, the same sum
        over those rows) is at most ``untracked_visible`` of the change they see
        (``d^T G d <= untracked_visible^2 d^T F d``)."""
        if self._anchor is None:
            return np.zeros((len(self.theta), 0))
        L = np.linalg.cholesky(self._anchor)
        lam, V = np.linalg.eigh(L.T @ self._info @ L)
        keep = lam > 1.0 / self.opt.untracked_ratio ** 2 - 1.0
        D = L @ V[:, keep]
        v = self.opt.untracked_visible
        if v <= 0 or not D.shape[1]:
            return D
        # within span D: the generalised eigenvectors of (D^T G D, D^T F D)
        Fd = D.T @ self._info @ D
        Gd = D.T @ self._seen @ D
        Lf = np.linalg.cholesky(0.5 * (Fd + Fd.T))
        Li = np.linalg.inv(Lf)
        mu, W = np.linalg.eigh(Li @ Gd @ Li.T)
        return D @ Li.T @ W[:, mu <= v ** 2]

    def _innovation_test(self, nu: np.ndarray, Jw: np.ndarray, t: float,
                         events: list[Event]) -> float:
        """The normalised innovation squared of whitened innovations ``nu`` (rows ``Jw``); beyond
        the chi-square quantile of :attr:`IdentOptions.alarm_p`, a ``sudden_change`` event."""
        Sc = np.linalg.cholesky(Jw @ self.P @ Jw.T + np.eye(len(nu)))
        w = np.linalg.solve(Sc, nu)
        nis = float(w @ w)
        limit = float(chi2.isf(self.opt.alarm_p, len(nu)))
        if nis > limit:
            events.append(Event("sudden_change", t, f"innovation chi-square {nis:.1f} > "
                                f"{limit:.1f} ({len(nu)} dof)"))
        return nis

    def _within_bounds(self, K: np.ndarray, step: np.ndarray, t: float,
                       events: list[Event]) -> tuple[np.ndarray, np.ndarray]:
        """An untracked update's gain ``K`` and ``step`` (p,) shortened so that the estimate
        stays within the physical bounds: the step keeps its direction (in the span the
        untracked samples determine; projecting the estimate on the bounds by its covariance
        moved the others outside it); a ``bound`` event when shortened, unless a parameter
        already on its bound stops the step (then nothing moves)."""
        th = self.theta + step
        over = (th > self.upper) | (th < self.lower)
        if not np.any(over):
            return K, step
        room = np.where(step > 0, self.upper - self.theta, self.lower - self.theta)
        frac = np.clip(room[over] / step[over], 0.0, 1.0)
        a = float(frac.min())
        j = int(np.flatnonzero(over)[np.argmin(frac)])
        if a > 0:  # (a parameter already on its bound, the step stopped: said before)
            events.append(Event("bound", t, f"{self.names[j]}: {th[j]:.3g} outside "
                                f"[{self.lower[j]:.3g}, {self.upper[j]:.3g}] (untracked step "
                                f"shortened to {a:.2f} of it)"))
        return K * a, step * a

    def _bounded(self, theta: np.ndarray, t: float, events: list[Event]) -> np.ndarray:
        """``theta`` within the physical bounds: the parameters beyond them set on them and the
        others moved with them by their covariance (the projection of the estimate on the
        bounds: a parameter the data hardly fix, clipped alone, would bias those it is
        correlated with). A violation beyond three standard deviations is an event."""
        for _ in range(3):
            target = np.clip(theta, self.lower, self.upper)
            out = np.flatnonzero(target != theta)
            if not len(out):
                break
            sd = np.sqrt(np.diag(self.P)[out])
            far = np.abs(theta[out] - target[out]) > 3.0 * sd
            for j in out[far]:
                events.append(Event("bound", t, f"{self.names[j]}: {theta[j]:.3g} outside "
                                    f"[{self.lower[j]:.3g}, {self.upper[j]:.3g}]"))
            gain = np.linalg.solve(self.P[np.ix_(out, out)], theta[out] - target[out])
            theta = theta - self.P[:, out] @ gain
            theta[out] = target[out]
        return np.clip(theta, self.lower, self.upper)

    def _inflate(self) -> None:
        """The covariance multiplied by :attr:`IdentOptions.drift_inflate` (fading memory: the
        correlations the data built are kept, so the update corrects along the combinations
        they fixed rather than opening each parameter alone), but never beyond the priors
        (:attr:`_cap`: the exits' and compliances' prior, and for the length offsets that of
        an exit, ``prior_offset``: an exit that moves after the initialisation moves them by
        as much; in each direction of ``P`` relative to it: the generalised eigenvalues are
        multiplied, capped at 1, or kept when already beyond): a robot that keeps changing
        opens the estimate back to what nothing was known of it, no further (repeated
        inflations made the covariance, then the corrections, grow without bound).
        The length offsets too: a change after the initialisation (an exit point that moved)
        is, for the encoders referenced before it, a change of the exit points and of the
        length offsets that hold the old reference."""
        L0 = np.linalg.cholesky(self._cap)
        A = np.linalg.solve(L0, np.linalg.solve(L0, self.P).T)
        lam, V = np.linalg.eigh(0.5 * (A + A.T))
        lam = np.minimum(lam * self.opt.drift_inflate, np.maximum(lam, 1.0))
        LV = L0 @ V
        self.P = (LV * lam) @ LV.T

    def _check_drift(self, nis: float, dof: int, t: float, events: list[Event]) -> None:
        """The windowed innovation test (:attr:`IdentOptions.drift_window`): a ``drift``
        event and the covariance inflated when the last updates' innovations together are
        beyond the model's noise."""
        o = self.opt
        if o.drift_window < 1:
            return
        self._window.append((nis, dof))
        if len(self._window) < o.drift_window:
            return
        total = sum(v for v, _ in self._window)
        dof_sum = sum(d for _, d in self._window)
        self._window = self._window[1:]
        limit = float(chi2.isf(o.drift_p, dof_sum))
        if total <= limit:
            return
        self._inflate()
        self._window = []
        events.append(Event("drift", t, f"innovations of the last {o.drift_window} updates: "
                            f"chi-square {total:.1f} > {limit:.1f} ({dof_sum} dof): the robot "
                            f"is changing; the model is learnt again"))

    def _check_moved(self, t: float, events: list[Event]) -> None:
        """A ``drift`` event when the estimate moved from its reference (that of the
        ``drift_window``-th update, or of the last such event) beyond the chi-square quantile
        of ``drift_p`` in the metric of the reference's covariance (a consistent filter's
        estimate moves by less: its change has the covariance ``P_ref - P``)."""
        if self._moved_ref is None:
            if self.updates + 1 >= self.opt.drift_window:
                self._moved_ref = (self.theta.copy(), self.P.copy())
            return
        th0, P0 = self._moved_ref
        d = self.theta - th0
        d2 = float(d @ np.linalg.solve(P0, d))
        limit = float(chi2.isf(self.opt.drift_p, len(d)))
        if d2 <= limit:
            return
        self._moved_ref = (self.theta.copy(), self.P.copy())
        events.append(Event("drift", t, f"the estimate moved by chi-square {d2:.1f} > "
                            f"{limit:.1f} ({len(d)} dof) from its reference: the robot is "
                            f"changing"))

    def _check_growth(self, t: float, events: list[Event]) -> None:
        tr = float(np.sum(np.diag(self.P) / self.prior))
        self._grow = self._grow + 1 if tr > self._trace_last else 0
        self._trace_last = tr
        if self._grow == self.opt.grow_updates:
            events.append(Event("covariance_growing", t, f"covariance grew over "
                                f"{self._grow} updates in a row (nothing observes it)"))

    # ----- identifiability -------------------------------------------------------------
    def fisher(self, batch: list[Measurement], ratio: float = 0.3) -> Identifiability:
        """What a path can fix, before running it: the Fisher information of the samples
        ``batch`` (e.g. the path's poses with planned tensions and lengths) at the estimate;
        a parameter is determined when the path alone brings its standard deviation below
        ``ratio`` of the prior's."""
        _, Jw, _, _ = self._rows(batch, self.theta)
        F = Jw.T @ Jw
        prior = self.prior
        post = np.linalg.inv(F + np.linalg.inv(self.P0))
        sd = np.sqrt(np.diag(post))
        det = sd < ratio * np.sqrt(prior)
        ev = np.linalg.eigvalsh(F * np.sqrt(np.outer(prior, prior)))
        return Identifiability(self.names, sd, det, int(np.sum(ev > 1.0 / ratio ** 2 - 1.0)))


def planned_samples(ident: OnlineIdentifier, poses: np.ndarray,
                    tracked: bool = True) -> list[Measurement]:
    """The samples a path's ``poses`` (P,6) would give if the robot were the current estimate
    (its tension distribution, the lengths that hold it): what :meth:`OnlineIdentifier.fisher`
    needs to say, before the path runs, which parameters it can fix. Infeasible poses are
    left out."""
    H = ident.robot_at()
    u0, _ = init_unstretched(H, ident.init_pose, true_tensions(H, ident.init_readings))
    out = []
    for p in np.asarray(poses, float).reshape(-1, 6):
        ps = pose_statics(H, p)
        if not ps.feasible:
            continue
        lengths = ident.reference + (ps.unstretched - u0 - H.length_offset) / H.drum_scale
        readings = H.load_cell_gain * ps.tensions + H.load_cell_offset
        out.append(Measurement(p, readings, lengths, tracked, 0.0))
    return out


@dataclass(frozen=True)
class Identifiability:
    """Per parameter: ``sd`` the standard deviation the path alone (plus the prior) leaves,
    ``determined`` whether the path fixes it; ``rank`` how many independent combinations
    (of the prior-scaled parameters) it fixes."""

    names: list[str]
    sd: np.ndarray
    determined: np.ndarray
    rank: int

    def undetermined(self) -> list[str]:
        """Names of the parameters the path cannot fix."""
        return [k for k, d in zip(self.names, self.determined, strict=True) if not d]


class ModelHandover:
    """The model the controller uses, moved toward the estimate at a bounded rate: at most
    ``rate_offset`` [m/s] per exit coordinate and ``rate_compliance`` [rad/(N m)/s] per joint
    axis, so the setpoints never jump; only the parameters the data determine move
    (:meth:`target`). ``advance(dt)`` returns the new model's parameters and whether they
    changed."""

    def __init__(self, ident: OnlineIdentifier, rate_offset: float = 2e-3,
                 rate_compliance: float = 2e-6, determined: float = 0.3,
                 correlated: float = 0.5) -> None:
        self.ident = ident
        self.theta = ident.theta.copy()
        self._start = ident.theta.copy()
        self.determined = float(determined)
        self.correlated = float(correlated)
        n, nc = ident.n_offsets, ident.n_compliance
        self._rate = np.r_[np.full(n, rate_offset), np.full(nc, rate_compliance),
                           np.full(len(self.theta) - n - nc, rate_offset)]

    def advance(self, dt: float) -> tuple[np.ndarray, bool]:
        """Move toward the current estimate for ``dt`` [s]."""
        lim = self._rate * max(dt, 0.0)
        delta = np.clip(self.target() - self.theta, -lim, lim)
        changed = bool(np.any(delta != 0))
        self.theta = self.theta + delta
        return self.theta, changed

    def target(self) -> np.ndarray:
        """Where the hand-over heads: the estimate of each parameter the data determine (its
        standard deviation below ``determined`` of its prior's) and all those correlated with it
        beyond ``correlated`` are determined too; the starting value of the others (what
        nothing fixes stays as the model had it, however the estimate wanders)."""
        ident = self.ident
        sd = ident.sd
        fixed = sd < self.determined * np.sqrt(ident.prior)
        # a parameter moves with those it is correlated with, or not at all (a part of a
        # correction can be worse than none)
        corr = np.abs(ident.P) / np.maximum(np.outer(sd, sd), 1e-300) > self.correlated
        for _ in range(len(fixed)):
            keep = fixed & ~np.any(corr & ~fixed[None, :], axis=1)
            if np.array_equal(keep, fixed):
                break
            fixed = keep
        return np.where(fixed, ident.theta, self._start)

    def robot(self) -> Robot:
        """The model the controller uses now."""
        return self.ident.robot_at(self.theta)
