"""Residuals of a hypothesis about the real robot against the samples of a recording.

Inverse residuals, evaluated at the samples' poses (cheap, vectorised over
samples, no equilibrium solve), are what the fits minimise:

- ``length`` (n per sample) [m]: unstretched length the hypothesis needs to hold
  the platform at the pose with the tensions, minus the unstretched length it
  reads behind the encoders by the initialisation convention.
- ``wrench`` (6) [N, N m]: ``W tau + w_g`` at the pose, measured tensions through
  the hypothesis' load-cell calibration. Independent of lengths: isolates load
  cells, mass and exit-point directions.
- ``exit`` (3 per measured exit point) [m]: predicted minus measured exit point.

What a recording lacks is solved for, per sample and per hypothesis:

- **no tracker pose** (tensions and encoders): the pose is the one whose needed
  unstretched lengths best match the readings (Gauss-Newton over the cables, the
  paper's forward kinematics with the measured tensions); the length residual
  keeps n - 6 degrees of freedom per sample, the wrench balance all six.
- **no tensions** (tracker and encoders): tensions balance gravity at the pose and
  their internal forces (the null space of the wrench matrix) are whatever makes
  the cables' stretch match the readings (as the real cables settle them); the
  length residual keeps 6 degrees of freedom per sample (the forward pose error,
  linearised). Without tensions nothing fixes the load cells or the mass.

Noise: each sample's residual has the variance ``sigma_p^2 + sigma_w^2 / count``:
``sigma_w`` the row-to-row (white) noise, from second differences of raw rows;
``sigma_p`` what changes between visits of one pose (repeatability), from
replicate groups. Rows of a move count with their weight (they share slow
errors); where a recording stops between moves, a cable's visit-to-visit error
changes at each stop and the rows of a move carry a blend of the errors of its two
stops (:meth:`ResidualModel.entry_knots`, for the standard errors). Where per-sample
unknowns are solved for (an estimated pose, internal forces), a sample's length
residual is the noise projected onto the ``r`` of ``n`` directions the unknowns leave
(``r = n - 6`` without a tracker pose, ``r = 6`` without tensions): its spread
measured on replicates is ``r / n`` of the readings' noise, which is what whitens it
(each such residual counts ``r / n`` of a degree of freedom,
:meth:`ResidualModel.dof_lost`), so that a parameter fitted to noise lowers the
chi-square by one, not by ``n / r``. Forward figures (:meth:`ResidualModel.forward`)
solve the equilibrium of each sample under the hypothesis and compare poses and
tensions: the headline.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from bench.diagnosis.internal_forces import fit_internal_forces
from bench.diagnosis.samples import Samples
from controller import cables
from controller.cycle import reference_lengths
from controller.effects import tracker_error, tracker_points_to_base, tracker_to_base
from controller.equilibrium import scaled_residual
from controller.forward import forward_pose, forward_rigid
from controller.kinematics import gravity_wrench, wrench_matrix
from controller.masts import lever_arms
from controller.pose import cross, euler_rate_matrix
from controller.robot import Robot
from controller.statics import (
    BatchStatics,
    batch_statics,
    init_statics,
    init_unstretched,
    internal_basis,
    pretensioned,
    settled_exits,
    true_tensions,
    unstretched_from_readings,
    weight_between_ends,
)

#: per-sample noise floors [m, N, N m, m]
FLOORS = {"length": 2e-5, "force": 0.05, "moment": 0.05, "exit": 2e-5}
#: repeatability assumed when the recording has no replicates (declared in the report)
DEFAULTS = {"length": 3e-4, "force": 2.0, "moment": 2.0, "exit": 1e-3}
#: degrees of freedom given the declared visit-to-visit level where nothing measured it: a
#: level known within a factor of about two either way (0.2-0.6 mm of process noise against
#: the 0.3 mm default; a chi-square of 6 dof puts 95 % of s^2 / sigma^2 in 0.21-2.4)
VISIT_DEFAULT_DOF = 6.0
#: white noise assumed when no raw rows tell it
WHITE_DEFAULTS = {"length": 5e-5, "force": 0.5, "moment": 0.5, "exit": 1e-4}
BLOCKS = ("length", "force", "moment", "exit")


def _finite(a: np.ndarray) -> np.ndarray:
    """``a`` with its non-finite entries zero (``np.nan_to_num`` without its checks and
    copy where all are finite: it was a tenth of a no-tracker diagnosis's time)."""
    bad = ~np.isfinite(a)
    return np.where(bad, 0.0, a) if bad.any() else a


#: Gauss-Newton steps of the estimated poses inside :meth:`ResidualModel.frozen` at most
FROZEN_STEPS = 3


@dataclass
class Blocks:
    """Raw inverse residuals of all samples: ``length`` (N,n), ``wrench`` (N,6), ``exit``
    (N,n,3); NaN where the data do not allow them. ``ok`` (N,) samples evaluated;
    ``poses`` (N,6) the poses used (measured, or estimated from the lengths)."""

    length: np.ndarray
    wrench: np.ndarray
    exit: np.ndarray
    ok: np.ndarray
    length_extra_sd: np.ndarray | None = None  # (N,n) load-cell noise carried into lengths
    poses: np.ndarray | None = None
    slack: np.ndarray | None = None  # (N,n) cables read as slack (one-sided length residual)


@dataclass
class Forward:
    """Forward figures per sample: ``pose_err`` (N,6) measured minus predicted; ``tension_err``
    (N,n) measured minus predicted load-cell readings; ``exit_err`` (N,n,3); ``ok`` (N,)."""

    pose_err: np.ndarray
    tension_err: np.ndarray
    exit_err: np.ndarray
    ok: np.ndarray


@dataclass
class _Settling:
    """The rounds of :meth:`ResidualModel._unmeasured` over M samples of n cables, per
    sample: ``tau`` (M,n) linearisation tensions [N] (fitted, at least the floor);
    ``fitted`` (M,n) the last fitted tensions before the floor [N]; ``face``, ``drop`` (M,n)
    the internal-force faces (:mod:`bench.diagnosis.internal_forces`); ``at_zero`` (M,n)
    cables at zero; ``ok`` (M,) fitted and feasible; ``W`` (M,6,n) the last wrench matrices
    (base frame: force rows unitless, moment rows [m]); ``C`` (M,n,n) the last length
    sensitivities [m/N] (None unless the absorbed directions are kept); ``search`` (M,) the
    next round searches every face; ``held``, ``searches`` (M,) rounds on held faces since
    the last search, searches; ``live`` (M,) not yet ended; ``exits`` (M,n,3) the last
    deflected exits [m, base frame] (None with rigid masts; with compliant ones, until the
    first round where no warm start had them); ``bs`` the last statics of every sample
    (rigid masts)."""

    tau: np.ndarray
    fitted: np.ndarray
    face: np.ndarray
    drop: np.ndarray
    at_zero: np.ndarray
    ok: np.ndarray
    W: np.ndarray
    C: np.ndarray | None
    search: np.ndarray
    held: np.ndarray
    searches: np.ndarray
    live: np.ndarray
    exits: np.ndarray | None
    bs: BatchStatics | None = None

    @classmethod
    def start(cls, tau: np.ndarray, hint: tuple[np.ndarray, np.ndarray] | None,
              exits: np.ndarray | None, keep_absorbed: bool) -> _Settling:
        """Rounds from the tensions ``tau`` (M,n) [N] and deflected ``exits`` (M,n,3) [m]
        (or None), on the faces ``hint`` (face, drop), each (M,n), where given (else the
        first round searches every face); ``keep_absorbed``: keep the length
        sensitivities."""
        M, n = tau.shape
        face = np.zeros((M, n), dtype=bool) if hint is None else hint[0].copy()
        drop = np.zeros((M, n), dtype=bool) if hint is None else hint[1].copy()
        return cls(tau=tau, fitted=np.zeros((M, n)), face=face, drop=drop,
                   at_zero=np.zeros((M, n), dtype=bool), ok=np.ones(M, dtype=bool),
                   W=np.full((M, 6, n), np.nan),
                   C=np.zeros((M, n, n)) if keep_absorbed else None,
                   search=np.full(M, hint is None), held=np.zeros(M, dtype=np.int64),
                   searches=np.zeros(M, dtype=np.int64), live=np.ones(M, dtype=bool),
                   exits=exits)

    def linearise(self, H: Robot, a: np.ndarray, poses: np.ndarray, read: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The statics of the samples ``a`` (indices into the M) at ``poses`` (M,6) holding
        their tensions: wrench matrices (A,6,n) and gravity wrenches (A,6) [N, N m] in the
        base frame, length residuals against ``read`` (M,n) (A,n) [m] and length sensitivities
        (A,n,n) [m/N] (non-finite entries zero, :func:`_finite`). With compliant masts the
        geometry hangs on the tensions: the samples ``a`` only, their exits kept; with
        rigid ones only the cables' forces are evaluated again, of every sample."""
        if H.compliant:  # the geometry hangs on the tensions: the live samples only
            ba = _statics(H, poses[a], self.tau[a],
                          None if self.exits is None else self.exits[a], None)
            if self.exits is None:
                self.exits = np.repeat(ba.exits[:1], len(poses), axis=0)
            self.exits[a] = ba.exits
            W = wrench_matrix(ba.state)
            wg = gravity_wrench(H.mass, H.com, H.gravity, ba.state.R)
            r = _finite(ba.unstretched - read[a])
            C = _finite(_length_sensitivity(H, ba, self.tau[a]))
        else:  # the same geometry: only the cables' forces again (of every sample)
            self.bs = bs = _statics(H, poses, self.tau, None, self.bs)
            W = wrench_matrix(bs.state)[a]
            wg = gravity_wrench(H.mass, H.com, H.gravity, bs.state.R)[a]
            r = _finite(bs.unstretched - read)[a]
            C = _finite(_length_sensitivity(H, bs, self.tau))[a]
        self.W[a] = W
        if self.C is not None:
            self.C[a] = C
        return W, wg, r, C

    def fit_faces(self, a: np.ndarray, W: np.ndarray, wg: np.ndarray, r: np.ndarray,
                  C: np.ndarray, tm: np.ndarray, floor: np.ndarray) -> np.ndarray:
        """The fitted tensions (A,n) [N] of the samples ``a`` from their statics (``W``,
        ``wg``, ``r``, ``C`` of :meth:`linearise`): on their held faces, or searching every
        face where :attr:`search` says so (:func:`fit_internal_forces`, toward the mid-range
        ``tm`` (n,) [N]), at least ``floor`` (n,) [N]; their last tensions where the fit is
        not finite. Their faces, cables at zero, fitted tensions and success kept."""
        new = self.tau[a].copy()
        for group in (~self.search[a], self.search[a]):
            g = np.flatnonzero(group)
            if not len(g):
                continue
            k = a[g]
            fit = fit_internal_forces(_finite(W[g]), -wg[g], r[g], C[g], self.tau[k], tm,
                                      hint=None if self.search[k[0]]
                                      else (self.face[k], self.drop[k]))
            good = np.isfinite(W[g]).all(axis=(1, 2)) & \
                np.isfinite(fit.tensions).all(axis=1)
            self.ok[k] = good & fit.feasible
            self.at_zero[k] = fit.at_zero
            self.fitted[k] = fit.tensions
            self.face[k], self.drop[k] = fit.hint()
            new[g] = np.where(good[:, None], np.maximum(fit.tensions, floor), self.tau[k])
        return new

    def advance(self, a: np.ndarray, settled: np.ndarray, rounds: int) -> None:
        """After a round of the samples ``a`` (``settled`` (A,): their tensions moved less
        than the tolerance): a search that left the tensions settled ends the sample (so
        does the cap of ``rounds`` searches); a face that changed settles on the new face
        (at most ``rounds`` rounds) before the next search."""
        was = self.search[a]
        self.searches[a] += was
        self.held[a] += ~was
        self.live[a] = ~(was & (settled | (self.searches[a] >= rounds)))
        self.search[a] = ~was & (settled | (self.held[a] >= rounds))
        self.held[a] = np.where(was, 0, self.held[a])


class ResidualModel:
    """Residuals of hypotheses against the samples of one recording.

    ``model`` is the robot the controller ran with (defines the encoder reference
    ``d_model(p0)``); ``tau0`` the load-cell readings at initialisation (None if
    the recording has no tensions); ``slip_times`` (n,) the times from which a
    cable length offset applies (default: the end of the initialisation: a slip
    happens after it); ``rows`` raw rows in triples (white noise).
    """

    def __init__(self, samples: Samples, model: Robot, init_pose: np.ndarray,
                 tau0: np.ndarray | None, slip_times: np.ndarray | None = None,
                 rows: Samples | None = None, reference: np.ndarray | None = None) -> None:
        self.s = samples
        self.model = model
        self.init_pose = np.asarray(init_pose, dtype=float)
        self.tau0 = tau0
        #: (n,) [m] the encoders' reference d_model(p0) (default: :func:`reference_lengths`;
        #: see :meth:`set_reference`)
        self.reference = reference_lengths(model, self.init_pose) if reference is None \
            else np.asarray(reference, dtype=float)
        #: where the load cells sit along a sagging cable: "exit" (at the winch side, the
        #: tension at the exit point) or "anchor" (at the platform)
        self.cells_at = "exit"
        n = model.n_cables
        s = samples
        init_t = s.t[s.is_init] if s.is_init.any() else s.t[:0]
        self.init_end = float(init_t.max()) if len(init_t) else -np.inf
        self.slip_times = np.full(n, self.init_end) if slip_times is None \
            else np.maximum(np.asarray(slip_times, float), self.init_end)
        self.has_pose = np.isfinite(s.pose_meas).all(axis=1)
        self.has_tau = np.isfinite(s.tau).all(axis=1)
        have_l = np.isfinite(s.l_meas).all(axis=1)
        self.est_pose = have_l & self.has_tau & ~self.has_pose  # pose from the lengths
        self.has_len = have_l & (self.has_pose | self.est_pose)
        self.has_exit = np.isfinite(s.exit_meas).all(axis=2) & self.has_pose[:, None]
        self.any_tau = bool(self.has_tau.any())
        # directions of a sample's length residual left by its per-sample unknowns (of n)
        rank = np.full(s.n, float(n))
        rank[self.est_pose] = max(n - 6, 1)
        rank[self.has_pose & ~self.has_tau] = min(6, n)
        self.len_rank = np.where(self.has_len, rank, float(n))
        self.sigma = {k: DEFAULTS[k] for k in BLOCKS}
        self.white = dict(WHITE_DEFAULTS)
        # by sample kind: 0 dwell samples, 1 rows of moves
        self.sigma_k = {0: dict(self.sigma), 1: dict(self.sigma)}
        self.white_k = {0: dict(self.white), 1: dict(self.white)}
        self.sigma_source = "defaults (no replicate visits)"
        #: [s] period of the recording's length readings (set by the diagnosis; None
        #: unknown): what its time stamps resolve (:func:`bench.diagnosis.frame.material`)
        self.stamp_period_s: float | None = None
        self.replicate_dof = 0.0
        #: visit-to-visit length error of dwells [m] measured on replicates (None unmeasured)
        self.visit_sd: float | None = None
        #: the visit level was measured on rows of moves (no dwell replicates): the lengths'
        #: error changes at the turns (:meth:`entry_knots`)
        self.visit_rows = False
        #: degrees of freedom of ``visit_sd`` (independent replicate differences over every
        #: cable; :data:`VISIT_DEFAULT_DOF` for the declared default)
        self.visit_dof = VISIT_DEFAULT_DOF
        # per sample (NaN before the first): the last deflected exits and estimated poses
        # (warm starts)
        self._warm_exits = np.full((s.n, n, 3), np.nan)
        self._pose_est = np.full((s.n, 6), np.nan)
        # ... the point each estimate took its last Gauss-Newton step from, and the poses
        # its load cells' tensions were taken at (:meth:`_estimate_poses` inside frozen)
        self._pose_lin = np.full((s.n, 6), np.nan)
        self._pose_t0 = np.full((s.n, 6), np.nan)
        # per sample without a commanded pose: where its pose estimate starts (NaN until
        # needed; :meth:`_kinematic_starts`)
        self._kin_start = np.full((s.n, 6), np.nan)
        # per sample: the last fitted unmeasured tensions (warm start, NaN before the first)
        # and their faces (cables at zero, rows left out: a hint inside :meth:`frozen`)
        self._warm_tau = np.full((s.n, n), np.nan)
        #: per sample without measured tensions or without a tracker pose (NaN elsewhere,
        #: and until an evaluation with :attr:`keep_absorbed` set): the directions (n, k) of
        #: its length residual that what is fitted per sample takes up, to first order: the
        #: internal forces (n - 6 directions: the stretch and the masts' deflection of a
        #: tension change in the wrench matrix's null space) [m/N], or the estimated pose (6:
        #: the lengths' Jacobian) [m]; padded with zero columns to k = max(n - 6, 6)
        self.keep_absorbed = False
        self.absorbed = np.full((s.n, n, max(n - 6, 6)), np.nan)
        # sagging cables: the catenaries of the last evaluation outside :meth:`frozen` (of
        # the samples with measured tensions, and at those tensions plus the step that carries
        # their noise into the lengths) and of the last initialisation: the next ones start
        # there, and a cable whose spans and tension are the same keeps its solution
        self._cat_memo: dict[str, tuple[bytes, cables.CableForces]] = {}
        self._warm_face = np.zeros((s.n, n), dtype=bool)
        self._warm_drop = np.zeros((s.n, n), dtype=bool)
        self._frozen = False
        #: (N,n) [m] a length change added to every evaluation's unstretched lengths (the
        #: out-of-vocabulary probes of :mod:`bench.diagnosis.probes`); None: none
        self.extra_length: np.ndarray | None = None
        self._at_zero: np.ndarray | None = None  # cables the last unmeasured fit left at zero
        self._init_cache: dict[bytes, np.ndarray | ValueError] = {}
        # slack cables: measured tension within the load-cell noise of zero (the noise of
        # one row, from the spread within dwells; 0.5 N if the recording cannot tell)
        tau_noise = s.tau_row_sd if s.tau_row_sd else 0.5
        self.slack_threshold = max(1.0, 4.0 * tau_noise)
        self.tau_noise = tau_noise / np.sqrt(np.maximum(s.count, 1))  # per sample [N]
        self.rows = None
        if rows is not None and rows.n >= 3:
            self.rows = ResidualModel(rows, model, init_pose, tau0, self.slip_times,
                                      reference=self.reference)
        self._update_sd()

    def cell_tensions(self, H: Robot, readings: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """True tensions at the exit ends [N] under ``H`` for load-cell ``readings`` taken
        at ``poses``: through ``H``'s calibration, and, with the cells at the platform
        anchors (:attr:`cells_at`), the cable's weight between the ends added."""
        tau = true_tensions(H, readings)
        if self.cells_at == "anchor" and H.rho > 0:
            tau = tau + weight_between_ends(H, poses)
        return tau

    def measured_poses(self, H: Robot) -> np.ndarray:
        """(N,6) the samples' measured poses in F_b under ``H``: through its tracker frame
        and latency (:func:`controller.effects.tracker_to_base`, the latency along each
        sample's pose rate), as read where ``H`` has no tracker error."""
        if not tracker_error(H):
            return self.s.pose_meas
        return tracker_to_base(H, self.s.pose_meas, self.s.pose_rate)

    def measured_exits(self, H: Robot) -> np.ndarray:
        """(N,n,3) the samples' measured exit points in F_b under ``H``'s tracker frame."""
        return tracker_points_to_base(H, self.s.exit_meas)

    def set_reference(self, reference: np.ndarray) -> None:
        """Read the encoders against another reference ``reference`` (n,) [m] (here and in
        the raw rows' model)."""
        self.reference = np.asarray(reference, dtype=float)
        if self.rows is not None:
            self.rows.reference = self.reference

    def _slipped(self) -> np.ndarray:
        """(N,n) where a cable's length offset applies: from its slip time on, never to a
        sample or row of the initialisation (the encoders are referenced there)."""
        return (self.s.t[:, None] >= self.slip_times) & ~self.s.is_init[:, None]

    def reference_sd(self, H: Robot) -> np.ndarray:
        """(n,) [m] uncertainty of each cable's encoder reference under ``H``, carried from the
        load cells' noise at initialisation (``u0`` hangs on the mean of the init rows'
        tensions: a slack, sagging cable's length by millimetres per newton). A length offset
        from the initialisation on looks like it: smaller than this, it is no finding."""
        n = self.model.n_cables
        init = self.s.is_init
        if self.tau0 is None or not init.any():
            return np.zeros(n)
        rows = float(np.sum(np.maximum(self.s.count[init], 1)))
        sig = (self.s.tau_row_sd if self.s.tau_row_sd else 0.5) / np.sqrt(rows)
        dT = max(10.0 * sig, 0.1)
        try:
            tau0 = self.cell_tensions(H, self.tau0, self.init_pose)
            u_a = init_unstretched(H, self.init_pose, tau0)[0]
            u_b = init_unstretched(H, self.init_pose, tau0 + dT)[0]
        except ValueError:
            return np.zeros(n)
        return np.abs(u_b - u_a) / dT * sig

    # ----- degrees of freedom -------------------------------------------------------
    def dof_lost(self, idx: np.ndarray | None = None) -> float:
        """Residual degrees of freedom taken by per-sample unknowns (an estimated pose: 6 of
        a sample's n length residuals; internal forces without tensions: n - 6), weighted
        like the entries (:meth:`entry_weights`).

        The initialisation's samples lose all n: their readings are the encoders'
        reference, so their length residuals are the initialisation's own unstretched
        lengths against themselves (no visit's error, the tracker's noise at most), whatever
        the hypothesis. Counted as residuals they lowered the error level of a fit (by 6 of
        78 degrees of freedom on a 13-sample IPAnema-class dwell without load cells:
        standard errors 4 % small)."""
        sl = slice(None) if idx is None else idx
        n = self.model.n_cables
        lost = np.where(self.s.is_init[sl], n, n - self.len_rank[sl]) * self.has_len[sl]
        return float(np.sum(self.s.weight[sl] * lost))

    def entry_kept(self, idx: np.ndarray | None = None) -> np.ndarray:
        """Per entry of :meth:`whiten`'s vector, the share of its error's variance the
        per-sample unknowns leave in it: ``r / n`` for a length entry they project
        (:attr:`len_rank`: an estimated pose leaves n - 6 of a sample's n directions, fitted
        internal forces 6), none for the initialisation's length entries (their readings are
        the encoders' reference: :meth:`dof_lost`), 1 for the others (the wrench at an
        estimated pose keeps its six, an exit point its three). Weighted like the entries,
        they sum to the entries' weights less :meth:`dof_lost`."""
        sl = slice(None) if idx is None else idx
        n = self.model.n_cables
        rank = np.where(self.s.is_init[sl], 0.0, self.len_rank[sl])
        share = np.zeros((len(self.s.t[sl]), n)) + (rank / n)[:, None]
        lengths = self._mask(share, self.has_len[sl][:, None])
        out = np.ones(self._n_entries(idx))
        out[:len(lengths)] = lengths  # (the length entries come first)
        return out

    def rank_factor(self) -> np.ndarray:
        """sqrt(n / r) per sample (N,): a length residual projected onto r of n directions,
        divided by this, has the variance of the readings' noise."""
        return np.sqrt(self.model.n_cables / self.len_rank)

    # ----- inverse residuals --------------------------------------------------------
    def blocks(self, H: Robot, idx: np.ndarray | None = None) -> Blocks:
        """Inverse residuals of hypothesis ``H`` on every sample, or on the samples ``idx``
        (indices) only when given (NaN elsewhere)."""
        s, n, N = self.s, self.model.n_cables, self.s.n
        length = np.full((N, n), np.nan)
        wrench = np.full((N, 6), np.nan)
        exits_err = np.full((N, n, 3), np.nan)
        ok = np.zeros(N, dtype=bool)
        poses = np.where(self.has_pose[:, None], self.measured_poses(H), np.nan)
        exit_meas = self.measured_exits(H)
        try:
            u0 = self._init_unstretched(H)
        except ValueError:
            return Blocks(length, wrench, exits_err, ok, None, poses)
        dl = np.where(self._slipped(), H.length_offset, 0.0)
        if self.extra_length is not None:
            dl = dl + self.extra_length
        read = unstretched_from_readings(H, s.l_meas, self.reference, u0, dl)
        sel = np.ones(N, dtype=bool)
        if idx is not None:
            sel = np.zeros(N, dtype=bool)
            sel[idx] = True
        e = np.flatnonzero(self.est_pose & sel)
        if len(e):
            poses[e] = self._estimate_poses(H, read, e)
        extra = np.zeros((N, n)) if H.rho > 0 else None
        slack_all = np.zeros((N, n), dtype=bool)
        # samples with measured tensions
        m = np.flatnonzero(np.isfinite(poses).all(axis=1) & self.has_tau & sel)
        if len(m):
            tau = self.cell_tensions(H, s.tau[m], poses[m])
            warm = self._warm_exits[m]
            warm = warm if np.isfinite(warm).all() else None
            key = m.tobytes()
            bs = batch_statics(H, poses[m], tau, exits0=warm,
                               forces0=self._memo("tau", key) if H.rho > 0 else None)
            if H.compliant and not self._frozen:
                self._warm_exits[m] = bs.exits
            self._keep("tau", key, bs.forces)
            ok[m] = bs.feasible
            lres = bs.unstretched - read[m]
            if H.rho > 0:
                # a sagging cable's length hangs on its tension (more so the slacker it is):
                # the load cells' noise carries into its length residual
                dT = 0.5
                cf_up, l_up = cables.from_tensions(H, bs.state, tau + dT,
                                                   self._memo("tau_up", key) or bs.forces)
                self._keep("tau_up", key, cf_up)
                extra[m] = np.abs(l_up - bs.unstretched) / dT * self.tau_noise[m][:, None]
            # a slack cable only says it is at least as long as the straight line (its
            # reading is noise about zero: a sagging model would hang it at that tension
            # from its exit point, metres long)
            slack = tau < self.slack_threshold
            if H.rho > 0 and bs.forces is not None and bs.forces.converged is not None:
                # a reading below what any catenary of the cable's span pulls at its top (no
                # solution: the cable cannot hang there at that tension) says no more than a
                # slack one: Newton's last iterate is no length (metres off, either sign)
                slack = slack | ~bs.forces.converged
            slack_all[m] = slack
            if slack.any():
                chord = bs.state.length / (1.0 + np.maximum(tau, 0.0) / H.ea)
                lres = np.where(slack, np.maximum(chord - read[m], 0.0), lres)
                if extra is not None:
                    extra[m] = np.where(slack, 0.0, extra[m])
            length[m] = lres
            f = bs.platform_forces
            st = bs.state
            if H.rho > 0 and slack.any():
                # a slack cable's reading (noise about zero, negative too) pulls along the
                # chord, as under a straight model: no catenary at a made-up tension
                f = np.where(slack[..., None], tau[..., None] * st.u, f)
            wg = gravity_wrench(H.mass, H.com, H.gravity, st.R)
            wr = np.concatenate([f.sum(axis=-2), cross(st.Rb, f).sum(axis=-2)], axis=-1) + wg
            # in load-cell units: a hypothesis must not shrink the sensor noise by its gains
            wr *= float(np.exp(np.mean(np.log(H.load_cell_gain))))
            wrench[m] = wr
            if self.has_exit[m].any():
                e = bs.exits - exit_meas[m]
                e[~self.has_exit[m]] = np.nan
                exits_err[m] = e
        # samples without tensions: internal forces from the stretch
        u = np.flatnonzero(self.has_pose & ~self.has_tau & sel)
        if len(u):
            lres, ex, good = self._unmeasured(H, u, poses[u], read[u])
            ok[u] = good
            length[u] = lres
            # a cable left at zero tension: a one-sided residual, like a slack one's
            slack_all[u] = self._at_zero
            if self.has_exit[u].any():
                e = ex - exit_meas[u]
                e[~self.has_exit[u]] = np.nan
                exits_err[u] = e
        length[~self.has_len] = np.nan
        return Blocks(length, wrench, exits_err, ok, extra, poses, slack_all)

    def _memo(self, name: str, key: bytes) -> cables.CableForces | None:
        """The catenaries kept as ``name`` for the samples ``key`` (None: none kept)."""
        got = self._cat_memo.get(name)
        return got[1] if got is not None and got[0] == key else None

    def _keep(self, name: str, key: bytes, cf: cables.CableForces | None) -> None:
        """Keep ``cf`` as ``name`` (outside :meth:`frozen` only: the columns of a
        finite-difference Jacobian start from the evaluation they differ from, not from the
        column before)."""
        if cf is not None and cf.H is not None and not self._frozen:
            self._cat_memo[name] = (key, cf)

    #: robot fields the unstretched lengths at initialisation hang on (not the readings' scale
    #: and offsets; the load cells' calibration through the tensions)
    _INIT_FIELDS = ("exits", "anchors", "mast_index", "pivots", "stiffness", "tilt",
                    "pulley_radius", "ea", "mass", "com", "gravity", "tension_min",
                    "tension_max", "rho", "init_internal")

    def _init_tensions(self, H: Robot) -> np.ndarray | None:
        """True tensions [N] at initialisation under ``H``: the load cells' readings there;
        without them, ``H``'s tension distribution (None), or that with ``H``'s
        :attr:`~controller.robot.Robot.init_internal` forces in :attr:`init_basis`.
        Raises ValueError if the initialisation pose is infeasible under ``H``."""
        if self.tau0 is not None:
            return self.cell_tensions(H, self.tau0, self.init_pose)
        if H.init_internal is None or not np.any(H.init_internal):
            return None
        return pretensioned(H, self.init_pose, H.init_internal, self.init_basis)

    @functools.cached_property
    def init_basis(self) -> np.ndarray:
        """(n, n - 6) a basis of the internal forces at initialisation (the null space of the
        recording model's wrench matrix at the initialisation pose) [-]."""
        try:
            ps = init_statics(self.model, self.init_pose)
        except ValueError:
            return np.zeros((self.model.n_cables, 0))
        return internal_basis(wrench_matrix(ps.state))

    def _init_unstretched(self, H: Robot) -> np.ndarray:
        """:func:`init_unstretched` (n,) [m] of ``H`` at the initialisation pose with the
        recording's initial tensions; the last few kept (the columns of a finite-difference
        Jacobian change it for some parameters only). Raises ValueError as it does."""
        tau0 = self._init_tensions(H)
        key = b"".join(np.asarray(getattr(H, f), dtype=float).tobytes()
                       for f in self._INIT_FIELDS) + (b"" if tau0 is None else tau0.tobytes())
        got = self._init_cache.get(key)
        if got is None:
            try:
                # (the masts' iteration starts from the settled exits every time: a warm start
                # moves u0 within the iteration's tolerance, and the finite-difference columns
                # of a stiffness the data hardly fix are of that size)
                ps = init_statics(H, self.init_pose, tau0,
                                  forces0=self._memo("init", b"") if H.rho > 0 else None)
                got = ps.unstretched
                self._keep("init", b"", ps.forces)
            except ValueError as e:
                got = e
            # inside frozen nothing is kept: each column of a finite-difference Jacobian
            # starts from the evaluation it differs from, whichever columns came before it
            # (in this process or in a forked child: :func:`~.fit.fd_jacobian`)
            if not self._frozen:
                if len(self._init_cache) >= 8:
                    self._init_cache.pop(next(iter(self._init_cache)))
                self._init_cache[key] = got
        if isinstance(got, ValueError):
            raise got
        return got

    def _kinematic_starts(self, idx: np.ndarray) -> np.ndarray:
        """(M,6) start poses of the samples ``idx`` for :meth:`_estimate_poses` without a
        commanded pose (:func:`kinematic_starts`; the damped steps of the estimate, 5 cm
        each, could not reach a target metres away from the initial pose). Depends on the
        recording only: computed for every sample at the first call."""
        if not np.isfinite(self._kin_start).all():
            self._kin_start = kinematic_starts(self.model, self.s, self.init_pose)
        return self._kin_start[idx]

    def _estimate_poses(self, H: Robot, read: np.ndarray, idx: np.ndarray,
                        iterations: int = 15) -> np.ndarray:
        """Poses (M,6) of the samples ``idx`` (M,) without a tracker pose: the needed
        unstretched lengths (measured tensions) match the readings ``read`` (N,n) in the
        least-squares sense (damped Gauss-Newton, steps of at most 5 cm and 0.05 rad; from
        the last estimates when they are near the commanded poses, else from the commanded
        poses). Inside :meth:`frozen` (the columns of a finite-difference Jacobian), from the
        point the evaluation before took its last step from, at most :data:`FROZEN_STEPS`
        steps: the Jacobian of the steps leaves the masts' deflection and the catenaries
        out, so one step has the poses' derivative within a few per cent, each further one
        a factor of about 50 closer (12730's columns had taken the 15 iterations of the cap
        from their own start in a third of the calls: 80 % of its time)."""
        s = self.s
        ea = np.where(np.isfinite(H.ea), H.ea, np.inf)
        # a slack cable only says it is at least as long as the straight line: it does not
        # place the platform
        taut = (s.tau[idx] >= self.slack_threshold).astype(float)
        limit = np.array([0.05, 0.05, 0.05, 0.05, 0.05, 0.05])
        lin, t0 = self._pose_lin[idx], self._pose_t0[idx]
        if self._frozen and np.isfinite(lin).all() and np.isfinite(t0).all():
            tau = self.cell_tensions(H, s.tau[idx], t0)
            p, forces = lin, None
            for _ in range(FROZEN_STEPS):
                dp, forces, _ = self._gauss_newton_step(H, p, tau, read[idx], taut, ea,
                                                        limit, forces)
                p = p + dp
                if np.abs(dp).max() < 1e-10:
                    break
            return p
        start = s.pose_des[idx].copy()
        none = ~np.isfinite(start).all(axis=1)
        if none.any():
            start[none] = self._kinematic_starts(idx[none])
        p = start.copy()
        last = self._pose_est[idx]
        near = np.isfinite(last).all(axis=1) & \
            (np.abs(last[:, :3] - start[:, :3]).max(axis=1) < 0.2)
        p[near] = last[near]
        at = p  # where the load cells' tensions are taken (at the platform's anchors)
        tau = self.cell_tensions(H, s.tau[idx], at)
        p0, forces = p, None
        for _ in range(iterations):
            # sagging cables: the catenaries of the last iteration start the next one's
            dp, forces, J = self._gauss_newton_step(H, p, tau, read[idx], taut, ea, limit,
                                                    forces)
            p0, p = p, p + dp
            if np.abs(dp).max() < 1e-10:
                break
        if self.keep_absorbed and not self._frozen:
            self.absorbed[idx] = 0.0
            self.absorbed[idx, :, :6] = J  # (at the last step's start: first order)
        if not self._frozen:
            self._pose_est[idx] = p
            self._pose_lin[idx] = p0
            self._pose_t0[idx] = at
        return p

    @staticmethod
    def _gauss_newton_step(H: Robot, p: np.ndarray, tau: np.ndarray, read: np.ndarray,
                           taut: np.ndarray, ea: np.ndarray, limit: np.ndarray,
                           forces: cables.CableForces | None = None
                           ) -> tuple[np.ndarray, cables.CableForces | None, np.ndarray]:
        """One damped Gauss-Newton step (M,6) of :meth:`_estimate_poses` from the poses ``p``
        (M,6) holding ``tau`` (M,n) [N] toward the unstretched ``read`` (M,n) [m] of the
        ``taut`` (M,n) cables, clipped to ``limit`` (6,); the cables' forces there and the
        lengths' Jacobian (M,n,6) [m per m or rad of the Euler angles]."""
        bs = batch_statics(H, p, tau, forces0=forces)
        r = _finite((bs.unstretched - read) * taut)
        J = -np.swapaxes(wrench_matrix(bs.state), -1, -2) / (1.0 + tau / ea)[..., None]
        J = _finite(J * taut[..., None])
        J[..., 3:] = J[..., 3:] @ euler_rate_matrix(p[:, 3:])
        JtJ = np.swapaxes(J, -1, -2) @ J
        damp = 1e-9 * np.trace(JtJ, axis1=-2, axis2=-1)[:, None, None] + 1e-12
        g = np.einsum("nki,nk->ni", J, r)
        dp = -np.linalg.solve(JtJ + damp * np.eye(6), g[..., None])[..., 0]
        dp = _finite(dp)
        big = np.max(np.abs(dp) / limit, axis=1, keepdims=True)
        return dp / np.maximum(big, 1.0), bs.forces, J

    #: the evaluations' warm starts (:meth:`cold`)
    _WARM = ("_warm_exits", "_pose_est", "_pose_lin", "_pose_t0", "_warm_tau", "_warm_face",
             "_warm_drop")

    @contextmanager
    def cold(self) -> Iterator[None]:
        """Evaluations inside start as the first one did (no warm starts: unmeasured
        tensions, estimated poses, deflected exits, catenaries), and those after find the
        warm starts as they were before. A fit made inside is then the same whatever was
        evaluated before it, in this process or in a worker that got a copy of this model
        (the selection's fits on a process pool): ``cdpr diagnose --jobs 1`` and
        ``--jobs 2`` gave two answers to one recording of nine samples, the fits' paths
        apart by the warm starts' tolerance."""
        saved = {k: getattr(self, k) for k in self._WARM}
        memo, at_zero, init = self._cat_memo, self._at_zero, self._init_cache
        for k, v in saved.items():
            setattr(self, k, np.full_like(v, np.nan) if v.dtype.kind == "f"
                    else np.zeros_like(v))
        # (the initialisation's lengths too: with sagging cables, one kept from before was
        # solved from another warm start than the one this evaluation would take)
        self._cat_memo, self._at_zero, self._init_cache = {}, None, {}
        try:
            if self.rows is not None:
                with self.rows.cold():
                    yield
            else:
                yield
        finally:
            for k, v in saved.items():
                setattr(self, k, v)
            self._cat_memo, self._at_zero, self._init_cache = memo, at_zero, init

    @contextmanager
    def frozen(self) -> Iterator[None]:
        """Evaluations inside start each sample from the last evaluation before (its
        unmeasured tensions, estimated pose, deflected exits) and keep its internal-force
        face (which cables sit at zero, which read as slack:
        :mod:`bench.diagnosis.internal_forces`), searching the faces only for the samples
        where it no longer pulls or balances, and relinearise once: for the columns of a
        finite-difference Jacobian around that evaluation (the derivative on its piece of
        the objective to about 1e-3, a few per cent in rare entries with compliant masts,
        at a sixth of a full evaluation's cost). They leave the warm starts of the
        evaluations after unchanged."""
        self._frozen = True
        try:
            yield
        finally:
            self._frozen = False

    def _unmeasured(self, H: Robot, u: np.ndarray, poses: np.ndarray, read: np.ndarray,
                    rounds: int = 4, rtol: float = 1e-7
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Length residuals (M,n) [m], exits (M,n,3) [m, base frame] and success (M,) of the
        samples ``u`` (M,) at ``poses`` (M,6) without measured tensions (``read`` (M,n) the
        unstretched lengths read [m]): tensions that balance gravity, pull, and fit the
        readings' stretch (:mod:`bench.diagnosis.internal_forces`: exact over which cables
        are slack, so the residuals do not jump with the parameters); a cable left at zero
        tension only says it is at least as long as the straight line. Relinearisations of
        the statics (exits and stretch move with the tensions) until a round that searches
        every face moves the tensions by less than ``rtol`` of mid-range (at most ``rounds``
        such searches; the rounds before them keep each sample's last faces, see below);
        each sample warm-started from its last tensions and deflected exits (inside
        :meth:`frozen`: from those of the last evaluation before, on its faces, one
        relinearisation)."""
        tm = np.full(H.n_cables, 0.5 * (H.tension_min + H.tension_max))  # as the controller plans
        floor = 1e-3 * tm  # linearisation tension of a cable at zero
        tau_k, known = self._start_tensions(H, u, poses, tm, floor)
        hint = (self._warm_face[u], self._warm_drop[u]) if known.all() else None
        # on held faces from the last evaluation's tensions, one relinearisation gives the
        # tensions to first order in a finite-difference step (a column within 1e-3). With
        # compliant masts the wrench matrix moves with the tensions too, which the
        # relinearisation leaves out (the length sensitivity has the masts' tilt): a few
        # entries of a column off by up to 3 %; a second round cost a tenth of a
        # diagnosis without load cells (12973: 138 -> 115 CPU-s with one, same answer)
        held_only = self._frozen and hint is not None
        if held_only:
            rounds = 1
        # outside frozen, the rounds relinearise on the faces of the last evaluation (one
        # KKT solve per sample) until the tensions settle, then search the faces in full:
        # where a face changes, they settle on the new faces and search again. A sample
        # ends with a search that moves its tensions less than ``rtol``: the fixed point of
        # full searches every round, with one search (two where a face changed) instead of
        # three or four; ``rounds`` caps the searches, and the rounds on held faces between
        # two searches. Each sample's statics and tensions are its own: the rounds after
        # the first take only the samples not yet ended (12973: a third of the rounds'
        # samples, most of them settled after two)
        st = _Settling.start(tau_k, hint, self._start_exits(H, u),
                             self.keep_absorbed and not self._frozen)
        tol = rtol * float(tm.max())
        while st.live.any():
            a = np.flatnonzero(st.live)
            W, wg, r, C = st.linearise(H, a, poses, read)
            new = st.fit_faces(a, W, wg, r, C, tm, floor)
            settled = np.abs(new - st.tau[a]).max(axis=1) <= tol
            st.tau[a] = new
            if held_only:
                break
            st.advance(a, settled, rounds)
        return self._settled_residuals(H, u, st, poses, read)

    def _start_tensions(self, H: Robot, u: np.ndarray, poses: np.ndarray, tm: np.ndarray,
                        floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_unmeasured`'s first linearisation tensions (M,n) [N] of the samples ``u``
        at ``poses`` (M,6), each at least ``floor`` (n,) [N], and which samples had warm
        ones (M,): their last tensions where they have them, else the tensions closest to
        the mid-range ``tm`` (n,) [N] that balance gravity on straight cables (``tm`` where
        that fails)."""
        n = H.n_cables
        warm = self._warm_tau[u]
        known = np.isfinite(warm).all(axis=1)
        tau_k = np.maximum(np.where(known[:, None], warm, tm), floor)
        if not known.all():
            c = np.flatnonzero(~known)
            straight = H.replace(rho=0.0) if H.rho > 0 else H
            bs0 = batch_statics(straight, poses[c], np.full((len(c), n), 1.0))  # geometry only
            wg = gravity_wrench(H.mass, H.com, H.gravity, bs0.state.R)
            tau = _balance(wrench_matrix(bs0.state), -wg, tm)
            tau_k[c] = np.maximum(np.where(np.isfinite(tau), tau, tm), floor)
        return tau_k, known

    def _start_exits(self, H: Robot, u: np.ndarray) -> np.ndarray | None:
        """The deflected exits (M,n,3) [m, base frame] :meth:`_unmeasured`'s first round of
        the samples ``u`` starts from: those of the last evaluation outside :meth:`frozen`,
        where every sample has them (the masts' iteration converges to its tolerance from
        there in fewer steps); None with rigid masts or where one is missing."""
        exits = self._warm_exits[u] if H.compliant else None
        if exits is not None and not np.isfinite(exits).all():
            exits = None
        return exits

    def _settled_residuals(self, H: Robot, u: np.ndarray, st: _Settling, poses: np.ndarray,
                           read: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_unmeasured`'s answer from its settled rounds ``st`` of the samples ``u`` at
        ``poses`` (M,6) with the unstretched lengths ``read`` (M,n) [m]: the length residuals
        (M,n) [m] (one-sided for cables at zero tension), exits (M,n,3) [m, base frame] and
        success (M,); the warm starts (outside :meth:`frozen`), the absorbed directions
        (:attr:`keep_absorbed`) and the cables at zero (``_at_zero``) kept."""
        if not self._frozen:
            self._warm_tau[u], self._warm_face[u], self._warm_drop[u] = st.tau, st.face, st.drop
        if st.C is not None:
            null = np.swapaxes(np.linalg.svd(np.nan_to_num(st.W))[2][:, 6:, :], -1, -2)
            self.absorbed[u] = 0.0
            self.absorbed[u, :, :null.shape[-1]] = st.C @ null
        bs = _statics(H, poses, np.where(st.at_zero, 0.0, st.tau), st.exits, st.bs)
        if H.compliant and not self._frozen:
            self._warm_exits[u] = bs.exits
        # the balance holds at most n - 6 cables at zero; where the platform hangs on fewer
        # cables (more of them slack), the fitted tension of another slack one comes out
        # within round-off of zero: a cable whose fitted tension is below what a load cell
        # would tell from slack and whose reading is longer than its straight line is slack,
        # one-sided like a measured slack cable (two-sided, it would count millimetres)
        faint = ~st.at_zero & (st.fitted < self.slack_threshold) & \
            (bs.state.length - read < 0.0)
        at_zero = st.at_zero | faint
        self._at_zero = at_zero
        lres = np.where(at_zero, np.maximum(bs.state.length - read, 0.0),
                        bs.unstretched - read)
        return lres, bs.exits, st.ok & np.isfinite(lres).all(axis=1)

    # ----- noise ----------------------------------------------------------------------
    def estimate_noise(self, H: Robot, groups: np.ndarray | None = None) -> dict[str, float]:
        """Noise of each residual block, for dwell samples and rows of moves apart (a moving
        platform adds what a dwell does not: channels read at slightly different instants,
        dynamics): white noise from raw rows (second differences), repeatability from the
        spread over replicate groups (model errors repeat at a pose, noise does not); a kind
        without replicates takes the other kind's, declared defaults without any.

        Replicate groups are the samples' targets, split per cable where that cable's
        length offset starts (``slip_times`` after the initialisation: a slip is no noise).
        A slip moves only its own cable's residual where the pose and the tensions are
        measured, so the other cables keep their replicates; where per-sample unknowns are
        solved for (an estimated pose, fitted internal forces) it moves every cable's, and
        such samples split for every cable. The wrench splits at every slip. A visit whose
        pose was estimated (no tracker fix) or whose internal forces were fitted is no
        replicate of one measured whole (:attr:`len_rank` splits them). ``groups`` (N,) or
        (N,n) replaces the targets (split the same way).

        ``replicate_dof`` counts the independent replicate differences, per cable (mean over
        cables): a sample counts with its weight (rows of one move share its slow errors, so
        twelve pairs of rows from two moves are a few differences, not twelve)."""
        b = self.blocks(H)
        self._white_from_rows(H)
        G = self.replicate_groups(groups)
        # every call starts from the declared defaults: replicate groups of an earlier call
        # (e.g. visits on both sides of a slip, before the groups were split) must not leave
        # their spread behind where this call finds none
        self.sigma_k = {0: dict(DEFAULTS), 1: dict(DEFAULTS)}
        self.sigma_source = "defaults (no replicate visits)"
        self.replicate_dof = 0.0
        found, rep_rows, dof_len, dof_kind = self._replicate_spread(b, G)
        if found[0] and found[1]:
            # rows of moves carry at least the visit-to-visit error of the dwells (the lengths
            # change between visits whether the platform stands or moves); their own replicate
            # groups, rows near each other on few moves, can miss it
            found[1] = {k: max(v, found[0].get(k, 0.0)) for k, v in found[1].items()}
        self._visit_level(found, dof_kind, rep_rows)
        self._adopt_repeatability(found, dof_len)
        self.sigma = dict(self.sigma_k[int(np.bincount(self.s.kind, minlength=2).argmax())])
        self._update_sd()
        return self.noise_summary()

    def _white_from_rows(self, H: Robot) -> None:
        """:meth:`estimate_noise`'s white noise per kind (``white_k``, each block's units)
        from the raw rows where the recording has them (a kind without enough rows takes
        the other's), and ``white`` that of the samples' commoner kind."""
        if self.rows is not None:
            rw = self.rows.white_noise_by_kind(H)
            for kind in (0, 1):
                own = rw.get(kind) or rw.get(1 - kind) or {}
                self.white_k[kind].update(own)
        self.white = dict(self.white_k[int(np.bincount(self.s.kind, minlength=2).argmax())])

    def _replicate_spread(self, b: Blocks, G: dict[str, np.ndarray]
                          ) -> tuple[dict[int, dict[str, float]], np.ndarray, np.ndarray,
                                     dict[int, float]]:
        """:meth:`estimate_noise`'s repeatability measured on the replicate groups ``G``
        (:meth:`replicate_groups`) of the residual blocks ``b``, per kind (0 dwells, 1 rows
        of moves): each block's spread less the white noise the samples' counts leave in it
        [m, N, N m, m] (blocks without replicates absent); the rows of moves in a length
        replicate group (N,); the length level's replicate dof per cable (n,), summed over
        the kinds; and that dof summed over the cables, per kind."""
        count = np.maximum(self.s.count, 1)
        w = np.clip(self.s.weight, 0.0, 1.0)
        found: dict[int, dict[str, float]] = {0: {}, 1: {}}
        rep_rows = np.zeros(self.s.n, dtype=bool)
        dof_len = np.zeros(self.model.n_cables)
        dof_kind = {0: 0.0, 1: 0.0}  # the length level's dof over every cable, per kind
        for kind in (0, 1):
            of_kind = self.s.kind == kind
            if not of_kind.any():
                continue
            for name, vals in self.block_values(b).items():
                v = np.where(of_kind[:, None], vals, np.nan)
                g = G[name]
                if not np.isfinite(v).any():
                    continue
                sd, rep, dof = _pooled_columns(v, g, w)
                if sd is None:
                    continue
                if name == "length" and kind == 1:
                    rep_rows = rep
                white = self.white_k[kind][name] ** 2 * float(np.mean(1.0 / count[rep]))
                var = float(np.nanmean(sd ** 2)) - white
                found[kind][name] = float(np.sqrt(max(var, 0.0)))
                if name == "length":
                    dof_len += dof
                    dof_kind[kind] = float(np.sum(dof))
        return found, rep_rows, dof_len, dof_kind

    def _visit_level(self, found: dict[int, dict[str, float]], dof_kind: dict[int, float],
                     rep_rows: np.ndarray) -> None:
        """:meth:`estimate_noise`'s visit-to-visit level of the lengths (``visit_sd`` [m],
        ``visit_dof``, ``visit_rows``: told by rows of moves) from the repeatability
        ``found`` per kind, the length level's dof per kind ``dof_kind`` and the rows of
        moves in a replicate group ``rep_rows`` (N,)."""
        self.visit_sd = found[0].get("length")
        self.visit_dof = dof_kind[0]
        self.visit_rows = False
        if self.visit_sd is None and "length" in found[1] and self.s.turns is not None \
                and len(self.s.turns):
            # no dwell replicates (no dwells, or a stray one where the platform stood a
            # moment): the spread of rows near each other on different moves tells the level
            # (the lengths change from turn to turn; between turns, rows blend it)
            self.visit_sd = found[1]["length"] / math.sqrt(self._blend_share(rep_rows))
            self.visit_dof = dof_kind[1]
            self.visit_rows = True
        elif self.visit_sd is None and not (self.s.kind == 0)[~self.s.is_init].any():
            self.visit_sd = found[1].get("length")
            self.visit_dof = dof_kind[1]
        if self.visit_sd is None and "length" not in found[1]:
            # nothing measured the level: the declared repeatability changes from stop to
            # stop as the diagonal's default says it does (a continuous recording without
            # replicates named per-cable stretch from the moves' shared errors, W 108 on 8;
            # with the stops' blend at this level, 9.8). Estimating the level from the
            # residuals' moments instead told it from a move's shared error no better
            # than the default (a third of the truth there) and named the stretch again
            self.visit_sd = DEFAULTS["length"]
            self.visit_dof = VISIT_DEFAULT_DOF
        if self.visit_sd is None:  # (no level, no knots: nothing leans on its dof)
            self.visit_dof = math.inf

    def _adopt_repeatability(self, found: dict[int, dict[str, float]],
                             dof_len: np.ndarray) -> None:
        """:meth:`estimate_noise`'s repeatability per kind (``sigma_k``, each block's units)
        from what the replicates ``found`` per kind, over the declared defaults, and its
        source and ``replicate_dof`` (the mean over cables of ``dof_len`` (n,))."""
        for kind in (0, 1):
            if found[kind]:
                self.sigma_k[kind].update(found[kind])
            elif found[1 - kind]:
                # no replicates of its own: the other kind's measured repeatability (the
                # lengths change from visit to visit whether the platform stands or moves; a
                # kind's own row-to-row noise is measured apart, in ``white_k``). A declared
                # default above a measurement would hide effects of a low-noise recording
                self.sigma_k[kind].update(found[1 - kind])
        if found[0] or found[1]:
            self.sigma_source = "replicate visits"
            self.replicate_dof = float(np.mean(dof_len))

    def _blend_share(self, rows: np.ndarray) -> float:
        """Mean over the rows ``rows`` (mask, N) of the sum of their squared weights on the
        turns (:meth:`_turn_knots`): the share of the stops' visit-to-visit variance a row of
        a move carries (1 at a turn, 1/2 midway between two). The spread of replicate rows
        on different moves measures the visit level times this share (2/3 for rows spread
        evenly along the moves); 1 where the recording has no turns or no such rows."""
        s = self.s
        sl = np.flatnonzero(rows & (s.kind == 1))
        if s.turns is None or not len(s.turns) or not len(sl):
            return 1.0
        hat = self._turn_knots(sl)
        return float(np.clip(np.mean(np.sum(hat ** 2, axis=1)), 0.5, 1.0))

    def replicate_groups(self, groups: np.ndarray | None) -> dict[str, np.ndarray]:
        """Replicate group ids per block column (see :meth:`estimate_noise`): ``length`` (N,n),
        ``exit`` (N,3n), ``force`` and ``moment`` (N,3)."""
        s, n = self.s, self.model.n_cables
        tg = s.target if groups is None else np.asarray(groups)
        tg = np.broadcast_to(tg[:, None] if tg.ndim == 1 else tg, (s.n, n)).astype(np.int64)
        # epochs: a cable's slip located after the initialisation starts a new one
        late = self.slip_times > self.init_end
        ep = (s.t[:, None] >= self.slip_times) & late & ~s.is_init[:, None]
        # slips happen in time order: how many have happened numbers the epochs of every cable
        every = ep.sum(axis=1).astype(np.int64)
        projected = self.len_rank < n  # per-sample unknowns spread a slip over every cable
        per_cable = np.where(projected[:, None], every[:, None], np.where(ep, -1, 0))
        # a sample whose per-sample unknowns were solved for (its pose estimated where the
        # tracker gave none, or its internal forces fitted) leaves another residual than a
        # visit of the same target measured whole: the difference is the model's error, no
        # noise (a tracker lost over one dwell read as 25 times the lengths' noise)
        how = np.broadcast_to(self.len_rank.astype(np.int64)[:, None], (s.n, n))
        length = _renumber(np.stack([tg, per_cable, how], axis=-1))
        common = _renumber(np.stack([tg[:, :1], every[:, None], how[:, :1]], axis=-1))[:, 0]
        return {"length": length, "exit": np.repeat(length, 3, axis=1),
                "force": np.repeat(common[:, None], 3, axis=1),
                "moment": np.repeat(common[:, None], 3, axis=1)}

    def white_noise_by_kind(self, H: Robot) -> dict[int, dict[str, float]]:
        """:meth:`white_noise` of the raw-row triples of dwells (kind 0) and of moves (1)."""
        b = self.blocks(H)
        out = {}
        kinds = self.s.kind[::3] if len(self.s.kind) >= 3 else self.s.kind
        for kind in (0, 1):
            sel = np.repeat(kinds == kind, 3)[: self.s.n]
            if sel.sum() >= 6:
                out[kind] = self._white(b, sel)
        return out

    def white_noise(self, H: Robot) -> dict[str, float]:
        """White noise of each block from raw rows in consecutive triples: the second difference
        ``r_a - 2 r_b + r_c`` cancels what is smooth (pose, slow errors); variance / 6."""
        return self._white(self.blocks(H), np.ones(self.s.n, dtype=bool))

    def _white(self, b: Blocks, sel: np.ndarray) -> dict[str, float]:
        out = {}
        for name, vals in self.block_values(b).items():
            v = vals[sel].reshape(int(sel.sum()), -1)
            T = len(v) // 3
            if T < 2:
                continue
            v = v[: 3 * T].reshape(T, 3, -1)
            d2 = v[:, 0] - 2 * v[:, 1] + v[:, 2]
            d2 = d2[np.isfinite(d2)]
            if d2.size < 6:
                continue
            mad = 1.4826 * float(np.median(np.abs(d2)))
            keep = np.abs(d2) <= max(5 * mad, 1e-15)
            out[name] = max(float(np.sqrt(np.mean(d2[keep] ** 2) / 6.0)), FLOORS[name])
        return out

    def block_values(self, b: Blocks) -> dict[str, np.ndarray]:
        """Residual blocks for noise estimates (slack cables' one-sided residuals left out;
        length residuals projected by per-sample unknowns scaled back to the readings'
        noise)."""
        length = b.length if b.slack is None else np.where(b.slack, np.nan, b.length)
        length = length * self.rank_factor()[:, None]
        return {"length": length, "force": b.wrench[:, :3], "moment": b.wrench[:, 3:],
                "exit": b.exit.reshape(len(b.exit), -1)}

    def _update_sd(self) -> None:
        """Per-sample noise of each block (by the sample's kind) and the whitening weights."""
        count = np.maximum(self.s.count, 1)
        kind = np.clip(self.s.kind, 0, 1)
        self.sd = {}
        for name in BLOCKS:
            sig = np.array([self.sigma_k[0][name], self.sigma_k[1][name]])[kind]
            wht = np.array([self.white_k[0][name], self.white_k[1][name]])[kind]
            var = sig ** 2 + wht ** 2 / count
            self.sd[name] = np.maximum(np.sqrt(var), FLOORS[name])
        self.sqrt_w = np.sqrt(np.clip(self.s.weight, 1e-6, 1.0))

    def noise_summary(self) -> dict[str, float]:
        """Typical noise of one sample per block (median over samples)."""
        return {k: float(np.median(self.sd[k])) if len(self.sd[k]) else float(FLOORS[k])
                for k in BLOCKS}

    # ----- whitened vector --------------------------------------------------------------
    def whitened(self, H: Robot, idx: np.ndarray | None = None) -> np.ndarray:
        """Residuals of ``idx`` samples (all by default), divided by their noise, as one vector
        (NaN entries dropped; their positions depend only on the data)."""
        return self.whiten(self.blocks(H, idx), idx)

    def whiten(self, b: Blocks, idx: np.ndarray | None = None) -> np.ndarray:
        sl = slice(None) if idx is None else idx
        w = self.sqrt_w[sl]
        present = self.has_len[sl][:, None]
        sd = self.sd["length"][sl][:, None]
        if b.length_extra_sd is not None:
            sd = np.sqrt(sd ** 2 + b.length_extra_sd[sl] ** 2)
        parts = [self._mask(b.length[sl] / sd * w[:, None], present)]
        if self.any_tau:
            m = (self.has_tau[sl] & (self.has_pose[sl] | self.est_pose[sl]))[:, None]
            parts.append(self._mask(b.wrench[sl][:, :3] / self.sd["force"][sl][:, None]
                                    * w[:, None], m))
            parts.append(self._mask(b.wrench[sl][:, 3:] / self.sd["moment"][sl][:, None]
                                    * w[:, None], m))
        if self.has_exit.any():
            parts.append(self._mask(b.exit[sl] / self.sd["exit"][sl][:, None, None]
                                    * w[:, None, None], self.has_exit[sl][..., None]))
        parts = [p for p in parts if p.size]
        return np.concatenate(parts) if parts else np.zeros(0)

    def entry_weights(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The sample weight (``Samples.weight``) of each entry of :meth:`whiten`'s vector: their
        sum is the effective number of residuals (rows of a move count together)."""
        return self._per_entry(self.s.weight.astype(float), idx)

    def entry_blocks(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The error cluster (``Samples.cluster``, else ``block``) of each entry of
        :meth:`whiten`'s vector."""
        groups = self.s.cluster if self.s.cluster is not None and \
            len(self.s.cluster) == self.s.n else self.s.block
        return self._per_entry(groups.astype(float), idx).astype(int)

    def entry_samples(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The sample (index into the samples) of each entry of :meth:`whiten`'s vector."""
        return self._per_entry(np.arange(self.s.n, dtype=float), idx).astype(int)

    def entry_moves(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The move (rows of a move) or target (dwells) of each entry of :meth:`whiten`'s
        vector (``Samples.block``)."""
        return self._per_entry(self.s.block.astype(float), idx).astype(int)

    def entry_knots(self, idx: np.ndarray | None = None,
                    H: Robot | None = None) -> np.ndarray | None:
        """The visit-to-visit error of the lengths where the recording stops between moves
        (dwells and rows of moves both fitted): (entries of :meth:`whiten`'s vector, stops x
        cables), whitened. A cable's error changes from stop to stop (what replicate dwells
        measure, ``visit_sd``) and rows of the move between two stops carry a blend of theirs
        (linear in time), so a move's rows share their error with the dwells at both ends
        and with the rows of the moves before and after: its covariance is ``K K^T``. None
        when there is nothing to blend (no rows of moves, or no dwell replicates told the
        level). The initialisation's stops carry none: the encoders are referenced there.
        A recording that never stops (or whose dwells have no replicates) has its knots where
        the moves meet (``Samples.turns``), its level from rows near each other on different
        moves (their spread over their mean share of the turns' variance, ``visit_rows``).

        With the hypothesis ``H`` and poses estimated from the lengths, the force and moment
        entries carry the same errors too: a cable's error moves the estimated pose, and the
        balance of the measured tensions there (:meth:`_wrench_knots`). Without them, the
        wrench entries' share of a visit's error is left out of the errors and out of their
        correlation with the lengths' (drum scales' errors 0.7 of their spread over replicate
        recordings, IPAnema-class, continuous with dwells, no tracker)."""
        s, n = self.s, self.model.n_cables
        sl = np.arange(s.n) if idx is None else np.asarray(idx)
        if not self.visit_sd or not (s.kind[sl] == 1).any():
            return None
        if (s.kind == 0)[~s.is_init].any() and not self.visit_rows:
            hat = self._dwell_knots(sl)
        elif s.turns is not None and len(s.turns):
            hat = self._turn_knots(sl)
        else:
            return None
        if hat is None or not hat.any():
            return None
        # per sample and cable: the stops' weights on that cable's column, over its noise
        amp = self.visit_sd / self.sd["length"][sl]
        S = hat.shape[1]
        K = (hat * amp[:, None])[:, None, :, None] * np.eye(n)[None, :, None, :]  # (M,n,S,n)
        out = [K[self.has_len[sl]].reshape(-1, S * n)]
        if self.any_tau:
            mm = self.has_tau[sl] & (self.has_pose[sl] | self.est_pose[sl])
            W = None if H is None else self._wrench_knots(H, sl, hat)
            if W is None:
                out.append(np.zeros((int(mm.sum()) * 6, S * n)))
            else:  # whiten's layout: every sample's force axes, then every moment axes
                out += [W[mm, :3].reshape(-1, S * n), W[mm, 3:].reshape(-1, S * n)]
        if self.has_exit.any():
            out.append(np.zeros((int(self.has_exit[sl].sum()) * 3, S * n)))
        return np.concatenate(out)

    def _wrench_knots(self, H: Robot, sl: np.ndarray, hat: np.ndarray) -> np.ndarray | None:
        """(samples ``sl``, 6, stops x cables): the whitened force and moment residuals' share
        of the stops' length errors (``hat`` each sample's weights on the stops, at
        ``visit_sd``) where poses are estimated from the lengths: each cable's error moves the
        estimated pose and with it the balance of the measured tensions
        (:meth:`length_steps`, per metre). None where no pose is estimated."""
        est = self.est_pose[sl] & self.has_len[sl]
        if not est.any() or not self.visit_sd:
            return None
        b0, steps = self.length_steps(H, sl)
        sd = np.concatenate([np.repeat(self.sd["force"][sl][:, None], 3, axis=1),
                             np.repeat(self.sd["moment"][sl][:, None], 3, axis=1)], axis=1)
        dw = np.stack([(st.wrench[sl] - b0.wrench[sl]) for st in steps], axis=-1) \
            / self.LOADING_STEP_M / sd[..., None]  # (M, 6, n) per metre of each cable
        dw = np.where(est[:, None, None] & np.isfinite(dw), dw, 0.0)
        W = hat[:, None, :, None] * dw[:, :, None, :] * self.visit_sd  # (M, 6, S, n)
        return W.reshape(len(sl), 6, -1)

    #: [m] length step of :meth:`length_steps`' finite differences
    LOADING_STEP_M = 1e-5

    def length_steps(self, H: Robot, sl: np.ndarray) -> tuple[Blocks, list[Blocks]]:
        """The blocks of ``H`` on the samples ``sl``, and with each cable's unstretched length
        longer by :attr:`LOADING_STEP_M` on every sample at once (each sample's residuals
        depend on its own lengths only: one evaluation per cable), inside :meth:`frozen`."""
        n = self.model.n_cables
        base = self.extra_length
        zero = np.zeros((self.s.n, n)) if base is None else base
        b0 = self.blocks(H, sl)
        steps = []
        try:
            with self.frozen():
                for j in range(n):
                    self.extra_length = zero.copy()
                    self.extra_length[:, j] += self.LOADING_STEP_M
                    steps.append(self.blocks(H, sl))
        finally:
            self.extra_length = base
        return b0, steps

    def projects(self, idx: np.ndarray | None = None) -> bool:
        """Whether per-sample unknowns project the length residual of some sample of ``idx``
        (an estimated pose, fitted internal forces)."""
        sl = slice(None) if idx is None else idx
        return bool(((self.len_rank < self.model.n_cables) & self.has_len)[sl].any())

    def direction_columns(self, H: Robot, idx: np.ndarray | None = None,
                          steps: tuple[Blocks, list[Blocks]] | None = None,
                          every: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
        """Two (entries of :meth:`whiten`'s vector, n) [1/m] column sets, on the samples whose
        length residual per-sample unknowns project (an estimated pose, fitted internal
        forces: :attr:`len_rank` below n; zero elsewhere): how the whitened residuals move per
        metre of a cable's length error

        - by the direction of the cable's last move (+ after paying out, - after reeling in:
          hysteresis, a winch's backlash), and
        - the same on every sample after the initialisation (the encoders' reference: where
          the cable's last move before it was is unknown, its error by direction there is
          one sign or the other, the same for every later sample).

        Projected, a cable's error spreads over every cable's residual, where the error
        model's direction component (:func:`bench.diagnosis.fit.error_meat`) reads nothing
        (:func:`bench.diagnosis.fit.direction_bias_var`). With ``every``, on every sample
        with lengths (projected or not: :func:`bench.diagnosis.frame.latency_beside_direction`).
        None where no such sample with a known direction is among ``idx``."""
        sl = np.arange(self.s.n) if idx is None else np.asarray(idx)
        n = self.model.n_cables
        proj = ((self.len_rank[sl] < n) | every) & self.has_len[sl]
        sign = np.where(proj[:, None], np.sign(np.nan_to_num(self.s.direction[sl])), 0.0)
        if not sign.any():
            return None
        b0, bs = self.length_steps(H, sl) if steps is None else steps
        r0 = self.whiten(b0, sl)
        signed, later = np.zeros((len(r0), n)), np.zeros((len(r0), n))
        after = np.zeros(self.s.n)
        after[sl] = proj & ~self.s.is_init[sl]
        after = self._per_entry(after, sl)
        for j, b in enumerate(bs):
            d = (self.whiten(b, sl) - r0) / self.LOADING_STEP_M
            d = np.where(np.abs(d) < 1e8, d, 0.0)  # (failed evaluations read 1e6)
            along = np.zeros(self.s.n)
            along[sl] = sign[:, j]
            signed[:, j] = d * self._per_entry(along, sl)
            later[:, j] = d * after
        return (signed, later) if signed.any() else None

    def _dwell_knots(self, sl: np.ndarray) -> np.ndarray | None:
        """(samples ``sl``, stops): each sample's weights on the dwells' errors (its own for a
        dwell; the two stops around it, linear in time, for a row of a move); none on the
        initialisation's."""
        s = self.s
        if not (s.kind[sl] == 0).any():
            return None
        stops = np.flatnonzero(s.kind == 0)
        stops = stops[np.argsort(s.t[stops], kind="stable")]
        hat = _blend(s.t[stops], s.t[sl])
        own = np.flatnonzero(s.kind[sl] == 0)
        hat[own] = 0.0
        by_index = np.argsort(stops)
        hat[own, by_index[np.searchsorted(stops[by_index], sl[own])]] = 1.0
        hat[:, s.is_init[stops]] = 0.0
        return hat

    def _turn_knots(self, sl: np.ndarray) -> np.ndarray:
        """(samples ``sl``, turns): where the recording never stops, the lengths' error
        changes where moves meet (``Samples.turns``) and blends along each move; the
        initialisation's dwell carries none (the encoders are referenced there)."""
        s = self.s
        hat = _blend(np.asarray(s.turns, dtype=float), s.t[sl])
        hat[s.kind[sl] == 0] = 0.0
        return hat

    def entry_directions(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The sign (+1 paid out, -1 reeled in, 0 unknown) of the last move of each length
        entry's cable of :meth:`whiten`'s vector (``Samples.direction``); 0 for the other
        entries."""
        n = self.model.n_cables
        sl = slice(None) if idx is None else idx
        d = np.sign(np.asarray(self.s.direction, dtype=float)[sl])
        if d.shape != (len(self.s.t[sl]), n):
            d = np.zeros((len(self.s.t[sl]), n))
        parts = [self._mask(d, self.has_len[sl][:, None])]
        m = len(d)
        if self.any_tau:
            mm = (self.has_tau[sl] & (self.has_pose[sl] | self.est_pose[sl]))[:, None]
            parts += [self._mask(np.zeros((m, 3)), mm)] * 2
        if self.has_exit.any():
            parts.append(self._mask(np.zeros((m, n, 3)), self.has_exit[sl][..., None]))
        parts = [q for q in parts if q.size]
        return np.concatenate(parts) if parts else np.zeros(0)

    def entry_kinds(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The kind of each entry of :meth:`whiten`'s vector, by quantity (0 a cable length,
        1 a force axis, 2 a moment axis, 3 an exit point's axis) and by sample (a dwell's
        average, or a row of a move: + 4): each kind has its own error level."""
        n = self.model.n_cables
        quantity = np.searchsorted(np.array([n, n + 3, n + 6]), self.entry_columns(idx),
                                   side="right")
        moving = self._per_entry(np.clip(self.s.kind, 0, 1).astype(float), idx)
        return quantity + 4 * moving.astype(int)

    def entry_columns(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The column of each entry of :meth:`whiten`'s vector (a cable's length, a force or
        moment axis, an exit point's axis): the same quantity over the samples."""
        n = self.model.n_cables
        sl = slice(None) if idx is None else idx
        m = len(self.s.t[sl])
        parts = [self._mask(np.zeros((m, n)) + np.arange(n), self.has_len[sl][:, None])]
        if self.any_tau:
            mm = (self.has_tau[sl] & (self.has_pose[sl] | self.est_pose[sl]))[:, None]
            parts += [self._mask(np.zeros((m, 3)) + n + np.arange(3), mm),
                      self._mask(np.zeros((m, 3)) + n + 3 + np.arange(3), mm)]
        if self.has_exit.any():
            parts.append(self._mask(np.zeros((m, n, 3)) + n + 6 + np.arange(3 * n).reshape(n, 3),
                                    self.has_exit[sl][..., None]))
        parts = [p for p in parts if p.size]
        return np.concatenate(parts).astype(int) if parts else np.zeros(0, dtype=int)

    def _per_entry(self, values: np.ndarray, idx: np.ndarray | None) -> np.ndarray:
        n = self.model.n_cables
        sl = slice(None) if idx is None else idx
        blk = values[sl]
        parts = [self._mask(np.zeros((len(blk), n)) + blk[:, None],
                            self.has_len[sl][:, None])]
        if self.any_tau:
            m = (self.has_tau[sl] & (self.has_pose[sl] | self.est_pose[sl]))[:, None]
            parts += [self._mask(np.zeros((len(blk), 3)) + blk[:, None], m)] * 2
        if self.has_exit.any():
            parts.append(self._mask(np.zeros((len(blk), n, 3)) + blk[:, None, None],
                                    self.has_exit[sl][..., None]))
        parts = [p for p in parts if p.size]
        return np.concatenate(parts) if parts else np.zeros(0)

    def _n_entries(self, idx: np.ndarray | None) -> int:
        """The length of :meth:`whiten`'s vector of the samples ``idx`` (every sample where
        None): what :meth:`_per_entry` lays out, counted."""
        sl = slice(None) if idx is None else idx
        count = self.model.n_cables * int(np.count_nonzero(self.has_len[sl]))
        if self.any_tau:
            count += 6 * int(np.count_nonzero(self.has_tau[sl] & (self.has_pose[sl]
                                                                  | self.est_pose[sl])))
        if self.has_exit.any():
            count += 3 * int(np.count_nonzero(self.has_exit[sl]))
        return count

    def whitened_by_sample(self, b: Blocks) -> np.ndarray:
        """Sum of squared whitened residuals of each sample (N,) (NaN where none)."""
        N = self.s.n
        out = np.zeros(N)
        cnt = np.zeros(N)
        w2 = self.sqrt_w ** 2
        sd = self.sd["length"][:, None]
        if b.length_extra_sd is not None:
            sd = np.sqrt(sd ** 2 + b.length_extra_sd ** 2)
        parts = [(b.length / sd, self.has_len[:, None])]
        if self.any_tau:
            m = (self.has_tau & (self.has_pose | self.est_pose))[:, None]
            parts += [(b.wrench[:, :3] / self.sd["force"][:, None], m),
                      (b.wrench[:, 3:] / self.sd["moment"][:, None], m)]
        if self.has_exit.any():
            parts.append((b.exit.reshape(N, -1) / self.sd["exit"][:, None],
                          np.repeat(self.has_exit, 3, axis=1)))
        for v, m in parts:
            v = np.where(np.broadcast_to(m, v.shape) & np.isfinite(v), v, np.nan)
            out += np.nansum(v ** 2, axis=1) * w2
            cnt += np.isfinite(v).sum(axis=1)
        return np.where(cnt > 0, out, np.nan)

    @staticmethod
    def _mask(values: np.ndarray, present: np.ndarray) -> np.ndarray:
        """Entries where data exist (fixed layout); a failed evaluation counts as a huge
        residual rather than a missing one, so a fit cannot gain by breaking samples."""
        present = np.broadcast_to(present, values.shape)
        v = values[present]
        return np.where(np.isfinite(v), v, 1e6)

    # ----- forward figures -------------------------------------------------------------
    def forward(self, H: Robot, idx: np.ndarray | None = None) -> Forward:
        """Equilibrium of each sample under ``H`` from its encoder readings, vs measurements."""
        s, n = self.s, self.model.n_cables
        N = s.n
        pose_err = np.full((N, 6), np.nan)
        tension_err = np.full((N, n), np.nan)
        exit_err = np.full((N, n, 3), np.nan)
        ok = np.zeros(N, dtype=bool)
        have_l = np.isfinite(s.l_meas).all(axis=1)
        if not have_l.any():
            return Forward(pose_err, tension_err, exit_err, ok)
        try:
            u0, _ = init_unstretched(H, self.init_pose, self._init_tensions(H))
        except ValueError:
            return Forward(pose_err, tension_err, exit_err, ok)
        todo = np.flatnonzero(have_l) if idx is None else np.intersect1d(idx,
                                                                         np.flatnonzero(have_l))
        pose_meas, exit_meas = self.measured_poses(H), self.measured_exits(H)
        theta = None
        for i in todo:
            dl = np.where(self._slipped()[i], H.length_offset, 0.0)
            l0 = unstretched_from_readings(H, s.l_meas[i], self.reference, u0, dl)
            # start where the hypothesis is nearest to balancing: the measured pose (near
            # the equilibrium of a good hypothesis) or the commanded one (the recording's
            # model balances there: the controller computed the lengths for it)
            cands = [g for g in (pose_meas[i], s.pose_des[i]) if np.isfinite(g).all()]
            if not cands:
                guess = self.init_pose
            elif len(cands) == 1 or not H.elastic:
                guess = cands[0]
            else:
                guess = min(cands, key=lambda g: scaled_residual(H, l0, g, theta))
            tau_meas = self.cell_tensions(H, s.tau[i], guess) if self.has_tau[i] else None
            res = forward_pose(H, l0, guess, tensions=tau_meas, theta=theta)
            if not res.success:
                continue
            theta = res.theta if H.elastic else None
            ok[i] = True
            if self.has_pose[i]:
                pose_err[i] = pose_meas[i] - res.pose
            if self.has_tau[i] and np.all(np.isfinite(res.tensions)) and H.elastic:
                at_cells = res.tensions - (weight_between_ends(H, res.pose)
                                           if self.cells_at == "anchor" else 0.0)
                tension_err[i] = s.tau[i] - (H.load_cell_gain * at_cells + H.load_cell_offset)
            if self.has_exit[i].any():
                e = exit_meas[i] - res.exits
                e[~self.has_exit[i]] = np.nan
                exit_err[i] = e
        return Forward(pose_err, tension_err, exit_err, ok)


#: [m] RMS of the rigid forward kinematics' length misfit above which no start is kept
KIN_RESIDUAL_M = 0.05


def kinematic_starts(model: Robot, s: Samples, init_pose: np.ndarray) -> np.ndarray:
    """(N,6) least-squares poses of rigid cables as long as each sample's encoder readings
    (the readings are ``model``'s lengths at the initialisation), the initial pose where
    that fails (misfit above :data:`KIN_RESIDUAL_M` RMS). Each sample is solved in time
    order from two starts, ``init_pose`` and the solution of the sample before it (the
    platform moves continuously: the branch the recording is on), and the solution of
    the smaller misfit kept: from the initial pose alone, a target metres away can land
    on a mirrored branch (the platform turned over, its slack cables read long: 16 mm RMS
    where the platform's own pose fits to 1.2 mm)."""
    out = np.tile(np.asarray(init_pose, float), (s.n, 1))
    prev: np.ndarray | None = None
    for i in np.argsort(np.asarray(s.t, float), kind="stable"):
        tau = s.tau[i] if np.isfinite(s.tau[i]).all() else None
        best = None
        for start in (init_pose,) if prev is None else (init_pose, prev):
            res = forward_rigid(model, s.l_meas[i], start, tensions=tau)
            if np.isfinite(res.pose).all() and res.residual < KIN_RESIDUAL_M and (
                    best is None or res.residual < best.residual):
                best = res
        if best is not None:
            out[i] = prev = best.pose
    return out


def _blend(ts: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(len(t), len(ts)) weights of times ``t`` [s] on knots at sorted times ``ts`` [s]:
    linear between the two around each time (the end knot's alone outside them)."""
    hat = np.zeros((len(t), len(ts)))
    if len(ts) == 1:
        hat[:, 0] = 1.0
        return hat
    b = np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)
    f = np.clip((t - ts[b - 1]) / np.maximum(ts[b] - ts[b - 1], 1e-9), 0.0, 1.0)
    rows = np.arange(len(t))
    hat[rows, b - 1] = 1.0 - f
    hat[rows, b] += f
    return hat


def _replicated(target: np.ndarray) -> np.ndarray:
    """Samples that belong to a replicate group of two or more."""
    _, inv, cnt = np.unique(target, return_inverse=True, return_counts=True)
    return cnt[inv] >= 2


def _renumber(keys: np.ndarray) -> np.ndarray:
    """(N,d) group ids from keys (N,d,k): equal keys within a column, equal ids."""
    N, d = keys.shape[:2]
    out = np.zeros((N, d), dtype=np.int64)
    for j in range(d):
        out[:, j] = np.unique(keys[:, j], axis=0, return_inverse=True)[1].ravel()
    return out


def _pooled_columns(values: np.ndarray, groups: np.ndarray, weight: np.ndarray
                    ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """Pooled within-group standard deviation of ``values`` (N,d), column j grouped by
    ``groups[:, j]`` (NaN values left out), the samples that took part (N,) and the
    independent differences per column (d,): each sample counts with its ``weight``, a
    group of weights w_i gives sum(w_i) - max(w_i) (n - 1 for n samples of weight one).
    None when no column has replicates."""
    N, d = values.shape
    sd = np.full(d, np.nan)
    dof = np.zeros(d)
    rep = np.zeros(N, dtype=bool)
    for j in range(d):
        ok = np.isfinite(values[:, j])
        if ok.sum() < 2:
            continue
        g = groups[ok, j]
        _, inv, cnt = np.unique(g, return_inverse=True, return_counts=True)
        inv = inv.ravel()
        multi = cnt[inv] >= 2
        if not multi.any():
            continue
        x = values[ok, j]
        m = np.bincount(inv, weights=x) / cnt
        ss = float(np.sum(((x - m[inv]) ** 2)[multi]))
        k = int(np.sum(cnt[cnt >= 2] - 1))
        sd[j] = np.sqrt(ss / k)
        ww = weight[ok]
        wsum = np.bincount(inv, weights=ww)
        wmax = np.zeros(len(cnt))
        np.maximum.at(wmax, inv, ww)
        dof[j] = float(np.sum((wsum - wmax)[cnt >= 2]))
        rep[np.flatnonzero(ok)[multi]] = True
    if not np.isfinite(sd).any():
        return None, rep, dof
    return sd, rep, dof


def _statics(H: Robot, poses: np.ndarray, tau: np.ndarray, exits: np.ndarray | None,
             last: BatchStatics | None) -> BatchStatics:
    """:func:`batch_statics` of ``poses`` holding ``tau``, from ``exits`` (a warm start of
    compliant masts); without compliant masts the geometry does not hang on the tensions:
    that of ``last`` (the same poses) is kept and only the cables' forces and unstretched
    lengths are evaluated again (what :func:`batch_statics` computes, without the cable
    states)."""
    if last is None or H.compliant:
        return batch_statics(H, poses, tau, exits0=exits)
    cf, l0 = cables.from_tensions(H, last.state, tau)
    return BatchStatics(tau, last.exits, last.state, np.isfinite(tau).all(axis=1), l0,
                        cf.platform)


def _balance(W: np.ndarray, f: np.ndarray, tm: np.ndarray) -> np.ndarray:
    """Tensions (M,n) closest to ``tm`` with ``W tau = f`` (batched minimal-norm correction)."""
    WWt = W @ np.swapaxes(W, -1, -2)
    rhs = f - np.einsum("mik,...k->mi", W, tm) if tm.ndim == 1 else \
        f - np.einsum("mik,mk->mi", W, tm)
    try:
        y = np.linalg.solve(WWt, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        y = np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(WWt, rhs,
                                                                            strict=True)])
    return tm + np.einsum("nik,ni->nk", W, y)


def _length_sensitivity(H: Robot, bs, tau: np.ndarray) -> np.ndarray:
    """d(needed unstretched length i)/d(tension j) (M,n,n) [m/N] at the statics ``bs``: each
    cable's stretch on the diagonal and, on a compliant mast, how the tension of a cable
    on the same mast tilts it and moves the exit point (first order: the mast's rotation
    ``c * (r_j x u_j)`` per newton, the exit ``theta x r_i``, the length along ``u_i``)."""
    C = _stretch_sensitivity(H, bs, tau)[:, :, None] * np.eye(H.n_cables)
    if not H.compliant:
        return C
    u = bs.state.u  # (M, n, 3) from the platform toward the exit
    r = lever_arms(settled_exits(H), H.pivots, H.mast_index)  # (n, 3)
    mi = H.mast_index
    ru = cross(r, u)  # (M, n, 3)
    dtheta = -H.compliance[mi] * ru  # (M, n_j, 3): mast rotation per newton on j
    # the length along u_i of the exit's move dtheta_j x r_i: u_i . (dtheta_j x r_i) =
    # dtheta_j . (r_i x u_i)
    same = (mi[:, None] == mi[None, :]).astype(float)  # (n_i, n_j)
    ea = np.where(np.isfinite(H.ea), H.ea, np.inf)
    stretch = 1.0 / (1.0 + tau / ea)  # dL0/dL
    return C + (ru @ np.swapaxes(dtheta, -1, -2)) * same * stretch[:, :, None]


def _stretch_sensitivity(H: Robot, bs, tau: np.ndarray) -> np.ndarray:
    """d(needed unstretched length)/d(tension) (M,n) [m/N] at the statics ``bs``."""
    if H.rho > 0:
        dT = 0.5
        l_up = cables.from_tensions(H, bs.state, tau + dT)[1]
        return (l_up - bs.unstretched) / dT
    ea = H.ea
    L = bs.state.length
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(np.isfinite(ea), -L / ea / (1.0 + tau / ea) ** 2, 0.0)
    return np.nan_to_num(c)
