"""The physical plant: the real robot as the simulation knows it.

The truth is a robot description (the model the controller runs with, plus the
effects a scenario conceals: :func:`controller.effects.apply_effects`) and
nuisances outside the effect vocabulary (:class:`Nuisances`: hysteresis by
approach direction, slow drift, per-visit process noise of the cable lengths,
and physics a real robot has that the vocabulary lacks: backlash of one winch,
thermal expansion of the cables, pulley friction seen by the load cells). For
the encoder readings of the winches the plant finds where the platform comes to
rest.

It solves the statics its own way, not with the controller's and the
diagnosis's Newton solver: it minimises the potential energy
(:func:`controller.energy.potential_energy`) over the pose (Euler angles) and
the mast joint rotations by preconditioned descent and BFGS (Hessian by finite
differences, never the analytic Jacobian), and checks each rest position by
finite differences of the energy alone, so an error in the force model cannot
pass unnoticed into the truth. A search that loses its way after a long move (no rest
position, or one turned over) is not the answer: the plant then follows the move through
the rest positions in between (a homotopy of the unstretched lengths, halved while a step
still loses its way). Cables that the truth leaves inextensible get a
very stiff stand-in (``RIGID_EA``) so that their tensions are defined.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize

from controller import cables
from controller.cycle import reference_lengths
from controller.energy import potential_energy
from controller.equilibrium import energy_gradient
from controller.kinematics import cable_state, wrench_matrix
from controller.masts import deflect, lever_arms
from controller.pose import euler_from_rotation, euler_rate_matrix, rotation
from controller.robot import Robot
from controller.statics import (
    init_statics,
    init_unstretched,
    internal_basis,
    pretensioned,
    settled_exits,
    unstretched_from_readings,
)

#: E*A [N] standing in for an inextensible cable (tens of micrometres of stretch at working
#: tensions, below a laser tracker's noise; stiffer stand-ins only trade that for round-off).
RIGID_EA = 1.0e8


class PlantError(RuntimeError):
    """The plant found no rest position (the message says why)."""


class _Lost(PlantError):
    """One rest search lost its way (no rest position, or a spurious one turned over)."""


@dataclass(frozen=True)
class Nuisances:
    """Effects outside the vocabulary.

    Small by design (always present in generated campaigns): ``hysteresis_m``: each
    cable is longer by this much after paying out than after reeling in [m];
    ``drift_m_per_s`` (scalar or (n,)): slow creep of the unstretched lengths [m/s];
    ``process_noise_m``: standard deviation of a random change of each unstretched
    length per visit (repeatability) [m].

    Physics the vocabulary lacks (zero unless a scenario sets them, for testing the
    diagnosis on what it cannot name): ``backlash_m`` (n,): direction-dependent length
    error of a winch, the cable is longer by this much after paying out than after
    reeling in [m] (e.g. one cable's gearbox); ``thermal_strain_per_s``: thermal
    expansion of every cable, its unstretched length grows by this strain per second
    [1/s] (a slow temperature change: lengths drift in proportion to each cable's
    length); ``friction_n`` (n,): pulley friction between a load cell and the platform,
    the cell reads this much less while its cable pays out and more while it reels in
    [N]; ``init_pretension_n``: the tensions when the encoders were referenced differ from
    the tension distribution's by internal forces of this size [N] (in a random direction
    of the wrench matrix's null space, within the tension limits: a controller's or an
    operator's pretension; recordings with load cells measure it, others cannot);
    ``settle_m``, ``settle_s``: the supporting ropes keep settling, every mast leaning toward
    the workspace: its exit points move horizontally toward the centroid of the pivots by
    ``settle_m`` [m] per ``settle_s`` [s] of plant time (linear creep from t = 0).
    """

    hysteresis_m: float = 0.0
    drift_m_per_s: float | np.ndarray = 0.0
    process_noise_m: float = 0.0
    backlash_m: float | np.ndarray = 0.0
    thermal_strain_per_s: float = 0.0
    friction_n: float | np.ndarray = 0.0
    init_pretension_n: float = 0.0
    settle_m: float = 0.0
    settle_s: float = 3600.0


@dataclass(frozen=True)
class PlantState:
    """Where the platform rests: ``pose`` (6,); ``tensions`` true (n,) [N] at the exit
    points; ``exits`` A# (n,3) [m]; ``theta`` mast rotations (m,3) [rad];
    ``unstretched`` true L0 (n,) [m]."""

    pose: np.ndarray
    tensions: np.ndarray
    exits: np.ndarray
    theta: np.ndarray
    unstretched: np.ndarray


@dataclass
class Plant:
    """The real robot: ``model`` is what the controller runs with, ``truth`` what the robot is.

    ``init_pose`` is where the platform stood when the controller referenced its
    encoders; the tensions then are the truth's tension distribution at that pose
    (the operator pretensioned the cables). ``slip_times`` (n,) [s]: a truth
    ``length_offset`` of a cable takes effect at this time (a slip), 0 = from the
    start. ``rng`` draws the per-visit process noise. ``check_every``: every k-th rest
    position is checked against finite differences of the energy (1: all of them; rows
    of a continuous recording, close to each other, are checked one in ``k``).
    ``predict``: a settle that continues a steady motion (its time one step after the last
    two settles', equally spaced) starts its rest search from the rest extrapolated
    linearly from those two (pose and mast rotations), not from the last: a few steps of
    the search instead of many for the same rest position (within the search's force
    tolerance); a search from there that loses its way starts again from the last rest.
    ``referenced`` (n,) [m]: the truth's unstretched lengths when the encoders were
    referenced, where that was before this plant's initialisation (a campaign continuing
    another after a change on the robot keeps its encoders' reference); default: at its
    initialisation (:attr:`u0`).
    """

    model: Robot
    truth: Robot
    init_pose: np.ndarray
    nuisances: Nuisances = field(default_factory=Nuisances)
    slip_times: np.ndarray | None = None
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    #: check the rest position against finite differences of the energy on every n-th rest
    #: (1: every one; a long simulation may thin the check out, the first is always checked)
    check_every: int = 1
    #: start the searches of a steady motion from the extrapolated rest (see above)
    predict: bool = False
    #: force tolerance of a rest search as a fraction of the platform's weight (scaled
    #: gradient of the energy; rests agree to about 1e-8 m and 1e-3 N at the default)
    tol: float = 1e-7
    #: truth's unstretched lengths [m] at the encoders' reference, if before this plant's
    #: initialisation (see above; None: at it)
    referenced: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = self.truth
        if not np.all(np.isfinite(t.ea)):
            t = t.replace(ea=np.where(np.isfinite(t.ea), t.ea, RIGID_EA))
        self.truth = t
        self.init_pose = np.asarray(self.init_pose, dtype=float)
        self.reference = reference_lengths(self.model, self.init_pose)  # d_model(p0)
        u_init, self.init_tensions = init_unstretched(t, self.init_pose)
        if self.nuisances.init_pretension_n:
            u_init, self.init_tensions = init_unstretched(
                t, self.init_pose, self._pretension(self.nuisances.init_pretension_n))
        #: truth's unstretched lengths (n,) [m] when the encoders were referenced
        self.u0 = u_init.copy() if self.referenced is None \
            else np.asarray(self.referenced, dtype=float).copy()
        self._a_star0 = self._a_star = settled_exits(t)
        self._r = lever_arms(self._a_star, t.pivots, t.mast_index)
        inward = t.pivots.mean(axis=0) - t.pivots
        inward[:, 2] = 0.0
        #: (n,3) horizontal unit vector of each exit's settling (toward the pivots' centroid)
        self._settle_dir = (inward / np.linalg.norm(inward, axis=1, keepdims=True))[
            t.mast_index]
        self._free = np.isfinite(t.stiffness).ravel()
        height = float(np.mean(np.linalg.norm(self._r, axis=1)))
        self._scale = np.concatenate([np.ones(6), np.full(int(self._free.sum()), height)])
        self._hess_inv: np.ndarray | None = None
        #: sagging cables at the last rest position: the catenaries of every evaluation of
        #: the next rest search start there (the same solutions, in a few Newton steps)
        self._hung: cables.CableForces | None = None
        self._rests = 0
        # sagging cables on pulleys leave them where the chord would (an approximation of
        # the tangent point): their forces and energy agree to a few tenths of a newton,
        # which the tolerances allow (micrometres of position)
        self._approx_n = 0.5 if (t.rho > 0 and t.has_pulleys) else 0.0
        # what the energy cannot tell apart [J]: 1e-9 of the platform's weight over the frame
        self._energy_roundoff = 1e-9 * t.weight * max(float(np.ptp(t.anchors, axis=0).max()),
                                                       1.0)
        self._last_readings = self.reference.copy()
        self._direction = np.zeros(t.n_cables)
        self._set_slips(np.zeros(t.n_cables) if self.slip_times is None else self.slip_times)
        ps_exits = self._exits(np.zeros((t.n_masts, 3)))
        self.state = PlantState(self.init_pose.copy(), self.init_tensions.copy(), ps_exits,
                                np.zeros((t.n_masts, 3)), u_init)
        #: the last two settles (time [s], rest) for :meth:`_predicted`
        self._trail: list[tuple[float, PlantState]] = []

    def slip_at(self, times: np.ndarray) -> None:
        """Set the times (n,) [s] at which the truth's length offsets take effect (see
        ``slip_times``; a campaign that continues another learns them once it started)."""
        self._set_slips(times)

    def _set_slips(self, times: np.ndarray) -> None:
        """``slip_times`` and the copy the plant reads, from ``times`` (n,) [s]."""
        self.slip_times = np.asarray(times, dtype=float).copy()
        self._slip = self.slip_times.copy()

    def _pretension(self, size: float) -> np.ndarray:
        """Tensions [N] at initialisation: the distribution's plus internal forces of
        ``size`` [N] in a random null-space direction, shortened to keep every tension
        above the robot's minimum (:attr:`Nuisances.init_pretension_n`)."""
        t = self.truth
        ps = init_statics(t, self.init_pose)
        basis = internal_basis(wrench_matrix(ps.state))
        if not basis.shape[1]:
            return ps.tensions
        d = self.rng.normal(size=basis.shape[1])
        e = pretensioned(t, self.init_pose, d / np.linalg.norm(d), basis) - ps.tensions
        room = np.where(e < 0, (ps.tensions - t.tension_min) / np.maximum(-e, 1e-12), np.inf)
        a = min(float(size), 0.9 * max(float(room.min()), 0.0))
        return ps.tensions + a * e

    # ----- the truth's unstretched lengths ------------------------------------------
    def unstretched(self, readings: np.ndarray, t: float = 0.0,
                    visit_noise: np.ndarray | None = None) -> np.ndarray:
        """True unstretched lengths [m] behind encoder ``readings`` (n,) [m] at time ``t`` [s]."""
        readings = np.asarray(readings, dtype=float)
        dl = np.where(t >= self._slip, self.truth.length_offset, 0.0)
        l0 = unstretched_from_readings(self.truth, readings, self.reference, self.u0, dl)
        nz = self.nuisances
        move = np.sign(readings - self._last_readings)
        self._direction = np.where(move != 0, move, self._direction)
        if nz.hysteresis_m:
            l0 = l0 + nz.hysteresis_m * 0.5 * self._direction
        if np.any(np.asarray(nz.backlash_m) != 0):
            l0 = l0 + np.asarray(nz.backlash_m) * 0.5 * self._direction
        if nz.thermal_strain_per_s:
            l0 = l0 * (1.0 + nz.thermal_strain_per_s * t)
        l0 = l0 + np.asarray(nz.drift_m_per_s) * t
        if visit_noise is not None:
            l0 = l0 + visit_noise
        self._last_readings = readings
        return l0

    def visit_noise(self) -> np.ndarray:
        """A fresh per-visit random change of the unstretched lengths [m]."""
        return self.rng.normal(0.0, self.nuisances.process_noise_m, self.truth.n_cables)

    def measured_tensions(self, tensions: np.ndarray) -> np.ndarray:
        """What the load cells read for true tensions [N] (gain and offset of the truth; pulley
        friction by the direction in which each cable last moved)."""
        out = self.truth.load_cell_gain * tensions + self.truth.load_cell_offset
        if np.any(np.asarray(self.nuisances.friction_n) != 0):
            out = out - np.asarray(self.nuisances.friction_n) * self._direction
        return out

    # ----- statics by energy minimisation -------------------------------------------
    def _exits(self, theta: np.ndarray) -> np.ndarray:
        t = self.truth
        return deflect(self._a_star, self._r, theta, t.mast_index) if t.compliant \
            else self._a_star

    def _unpack(self, y: np.ndarray, pose0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = y / self._scale
        pose = pose0 + x[:6]
        theta = np.zeros(self.truth.n_masts * 3)
        theta[self._free] = x[6:]
        return pose, theta.reshape(-1, 3)

    def _energy(self, y: np.ndarray, pose0: np.ndarray, l0: np.ndarray, e0: float) -> float:
        pose, theta = self._unpack(y, pose0)
        return potential_energy(self.truth, pose, theta, l0, self._a_star, self._r,
                                self._hung) - e0

    def _gradient(self, y: np.ndarray, pose0: np.ndarray, l0: np.ndarray, e0: float
                  ) -> np.ndarray:
        pose, theta = self._unpack(y, pose0)
        g = energy_gradient(self.truth, pose, theta, l0, self._a_star, self._r, self._hung)
        out = np.empty_like(y)
        out[:3] = g[:3]
        out[3:6] = g[3:6] @ euler_rate_matrix(pose[3:6])  # w = E(rpy) d(rpy)
        out[6:] = g[6:][self._free]
        return out / self._scale

    def _fd_gradient(self, y: np.ndarray, *args) -> np.ndarray:
        """Central finite differences of the energy (checks the force model); the step stays
        well below the stretch of the stiffest cable, so no cable turns slack within it."""
        h = 1e-6 * min(1.0, 1e6 / float(np.max(self.truth.ea)))
        if self.truth.rho > 0:
            h *= 10.0  # the catenary's energy carries more round-off than a straight cable's
        g = np.empty_like(y)
        for i in range(len(y)):
            yp = y.copy()
            ym = y.copy()
            yp[i] += h
            ym[i] -= h
            g[i] = (self._energy(yp, *args) - self._energy(ym, *args)) / (2 * h)
        return g

    def _hessian(self, y: np.ndarray, *args) -> np.ndarray:
        h = 1e-6
        g0 = self._gradient(y, *args)
        H = np.empty((len(y), len(y)))
        for i in range(len(y)):
            yp = y.copy()
            yp[i] += h
            H[:, i] = (self._gradient(yp, *args) - g0) / h
        return 0.5 * (H + H.T)

    def rest(self, l0: np.ndarray, guess: np.ndarray | None = None,
             predicted: PlantState | None = None) -> PlantState:
        """Where the platform rests with true unstretched lengths ``l0`` (n,) [m].

        The search starts from the last rest position, or from the pose ``guess``
        (6,) when the platform moved far since (e.g. the pose the controller aimed at).
        When that search loses its way after a long move (it finds no rest position, or
        one turned over: :data:`MAX_TURN_RAD`), the plant follows the move through the
        rest positions in between instead (:meth:`_follow_move`). ``predicted``: a rest
        expected near the answer (:meth:`_predicted`), tried first.
        """
        hess_inv = self._hess_inv
        if predicted is not None:
            try:
                return self._search(predicted, l0, None)
            except _Lost:
                self._hess_inv = hess_inv
        try:
            return self._search(self.state, l0, guess)
        except _Lost as lost:
            self._hess_inv = hess_inv  # the failed search's preconditioner is of nowhere
            return self._follow_move(np.asarray(l0, dtype=float), guess, str(lost))

    def _follow_move(self, l0: np.ndarray, guess: np.ndarray | None, lost: str
                     ) -> PlantState:
        """Rest for ``l0`` (n,) [m] reached from the last rest along each of :meth:`_paths`
        in turn (:meth:`_follow`); raises :class:`PlantError` (saying ``lost``, why the
        direct search failed) when every path loses its way, or when the rest reached is
        turned by more than :data:`MAX_TURN_RAD` from ``guess`` (else from the last rest):
        the platform turned over, no rest position the robot reaches."""
        start, hess_inv, hung = self.state, self._hess_inv, self._hung
        ref, whence = ((start.pose, "its last rest") if guess is None
                       else (np.asarray(guess, dtype=float), "the pose aimed at"))
        why = []
        for name, path in self._paths(start, l0, guess):
            try:
                end = self._follow(start, path, 0.0, 1.0, MAX_HALVINGS, first=False)
            except _Lost as again:
                why.append(f"{name} in up to {2 ** MAX_HALVINGS} steps: {again}")
                self._hess_inv, self._hung = hess_inv, hung
                continue
            turn = _turn_angle(ref[3:6], end.pose[3:6])
            if turn <= MAX_TURN_RAD:
                return end
            why.append(f"{name}, the platform ends turned by {turn:.2f} rad from {whence} "
                       f"(it turns over: no rest position the robot reaches)")
            self._hess_inv, self._hung = hess_inv, hung
        raise PlantError(f"{lost}; following the move {'; '.join(why)}")

    def _paths(self, start: PlantState, l0: np.ndarray, guess: np.ndarray | None
               ) -> list[tuple[str, Callable[[float], np.ndarray]]]:
        """Paths of the unstretched lengths [m] from the rest ``start`` to ``l0`` (n,), each a
        function of the fraction ``f`` in [0, 1] (``start.unstretched`` at 0, ``l0`` at 1):
        the lengths blended linearly (as winches moving together pay out); with a ``guess``
        (the pose aimed at) also as the controller moves the platform: along the straight
        line of poses from the start's to the guess, the cables' lengths there less their
        stretch, blended from the start's to the guess's (the truth's geometry at the
        start's mast rotations)."""
        u = start.unstretched
        paths = [("with the lengths blended", lambda f: u + f * (l0 - u))]
        if guess is None:
            return paths
        t, exits = self.truth, self._exits(start.theta)
        guess = np.asarray(guess, dtype=float)

        def length(pose: np.ndarray) -> np.ndarray:
            return cable_state(pose, t.anchors, exits, t.pulley_radius).length

        s0, s1 = length(start.pose) - u, length(guess) - l0
        paths.append(("along the poses to the pose aimed at", lambda f: (
            l0 if f >= 1.0 else length(start.pose + f * (guess - start.pose)) - s0
            - f * (s1 - s0))))
        return paths

    def _follow(self, start: PlantState, path: Callable[[float], np.ndarray], f0: float,
                f1: float, halvings: int, first: bool = True) -> PlantState:
        """Rest position at ``path(f1)`` reached from the rest ``start`` (at ``path(f0)``) as
        the platform goes (a homotopy): the search starts at ``start`` (with ``first``);
        when it loses its way (or without ``first``), the rest at the midpoint of the
        fractions is found first, each half split again down to ``halvings`` times (raises
        :class:`_Lost` beyond)."""
        if first:
            hess_inv = self._hess_inv
            try:
                return self._search(start, path(f1), None)
            except _Lost:
                if halvings <= 0:
                    raise
                self._hess_inv = hess_inv
        fm = 0.5 * (f0 + f1)
        mid = self._follow(start, path, f0, fm, halvings - 1)
        return self._follow(mid, path, fm, f1, halvings - 1)

    def _search(self, start: PlantState, l0: np.ndarray, guess: np.ndarray | None
                ) -> PlantState:
        """One rest search from the rest ``start`` (its mast rotations) and the pose ``guess``
        (or ``start``'s pose): raises :class:`_Lost` when it finds no rest position or one
        turned over, :class:`PlantError` when the force model and the energy disagree."""
        pose0 = start.pose.copy() if guess is None else np.asarray(guess, dtype=float).copy()
        y0 = np.concatenate([np.zeros(6), start.theta.ravel()[self._free] * self._scale[6:]])
        e0 = potential_energy(self.truth, pose0, start.theta, l0, self._a_star, self._r,
                              self._hung)
        args = (pose0, l0, e0)
        if self._hess_inv is None:
            self._hess_inv = _safe_inverse(self._hessian(y0, *args))
        # force tolerance: ``tol`` of the weight, relaxed for very stiff cables so that the
        # position it allows (force / stiffness) stays far below a micrometre
        gtol = self.tol * self.truth.weight * max(1.0, float(np.max(self.truth.ea)) / 1e6)
        accept = max(100 * gtol, self._approx_n)
        y, ok = self._chord(y0, args, gtol, max_iter=8)
        if not ok:  # slow contraction: refresh the finite-difference Hessian where we are
            self._hess_inv = _safe_inverse(self._hessian(y, *args))
            y, ok = self._chord(y, args, gtol)
        if not ok:
            res = minimize(self._energy, y, args=args, jac=self._gradient, method="BFGS",
                           options={"gtol": gtol, "maxiter": 400, "hess_inv0": self._hess_inv})
            if np.linalg.norm(res.jac, np.inf) > accept:
                # far from the last rest position: precondition afresh and go on
                self._hess_inv = _safe_inverse(self._hessian(res.x, *args))
                res = minimize(self._energy, res.x, args=args, jac=self._gradient,
                               method="BFGS", options={"gtol": gtol, "maxiter": 800,
                                                       "hess_inv0": self._hess_inv})
            if np.linalg.norm(res.jac, np.inf) > accept:
                raise _Lost(f"plant: no rest position found ({res.message}; energy "
                            f"gradient {np.linalg.norm(res.jac, np.inf):.3g})")
            y = res.x
        y = self._unwound(y, pose0)
        turn = _turn_angle(pose0[3:6], self._unpack(y, pose0)[0][3:6])
        if turn > MAX_TURN_RAD:
            raise _Lost(f"plant: the rest position found is turned by {turn:.2f} rad from "
                        f"where the search started (a spurious stationary point, not "
                        f"where the platform goes)")
        self._rests += 1
        check = self.check_every <= 1 or self._rests % self.check_every == 1
        fd = self._fd_gradient(y, *args) if check else None
        if fd is not None and np.linalg.norm(fd, np.inf) > max(1e3 * gtol, 2 * self._approx_n):
            raise PlantError(f"plant: the rest position is not an energy minimum (energy "
                             f"gradient {np.linalg.norm(fd, np.inf):.3g}): force model and "
                             f"energy disagree")
        pose, theta = self._unpack(y, pose0)
        exits = self._exits(theta)
        st = cable_state(pose, self.truth.anchors, exits, self.truth.pulley_radius)
        hung = cables.from_lengths(self.truth, st, l0, self._hung)
        if self.truth.rho > 0:
            self._hung = hung
        tau = hung.tension  # at the exit ends
        return PlantState(pose, tau, exits, theta, np.asarray(l0, float).copy())

    def _unwound(self, y: np.ndarray, pose0: np.ndarray) -> np.ndarray:
        """``y`` whose Euler angles went round (one changed by more than pi [rad] in a long
        search) written as the same orientation's principal angles, wound by whole turns to
        lie nearest ``pose0``'s; any other ``y`` as it is."""
        x = y[3:6] / self._scale[3:6]
        if np.abs(x).max() <= np.pi:
            return y
        rpy0 = pose0[3:6]
        rpy = euler_from_rotation(rotation(rpy0 + x))
        rpy = rpy + 2 * np.pi * np.round((rpy0 - rpy) / (2 * np.pi))
        y = y.copy()
        y[3:6] = (rpy - rpy0) * self._scale[3:6]
        return y

    def _chord(self, y: np.ndarray, args: tuple, gtol: float,
               max_iter: int = 30) -> tuple[np.ndarray, bool]:
        """Preconditioned descent ``y -= H0^-1 g`` with the stored inverse Hessian, steps
        halved until the energy decreases; True when the gradient is below ``gtol``.

        Near the minimum the energy changes less than its round-off, so a step is also
        taken when it halves the gradient (the energy cannot tell, the forces can)."""
        e = self._energy(y, *args)
        g = self._gradient(y, *args)
        for _ in range(max_iter):
            gn = np.linalg.norm(g, np.inf)
            if gn < gtol:
                return y, True
            step = -self._hess_inv @ g
            for _ in range(8):
                e_new = self._energy(y + step, *args)
                g_new = self._gradient(y + step, *args)
                # (within round-off of the energy only: far off, a halved gradient may be
                # another stationary point, the platform turned over)
                if e_new <= e or (np.linalg.norm(g_new, np.inf) < 0.5 * gn
                                  and e_new <= e + self._energy_roundoff):
                    break
                step *= 0.5
            else:
                return y, False
            y, e, g = y + step, e_new, g_new
        return y, bool(np.linalg.norm(g, np.inf) < gtol)

    def settle(self, readings: np.ndarray, t: float = 0.0,
               visit_noise: np.ndarray | None = None,
               guess: np.ndarray | None = None) -> PlantState:
        """Rest position for encoder ``readings`` (n,) [m] at time ``t`` [s]; becomes the state.
        ``guess``: a pose near the answer after a long move (see :meth:`rest`)."""
        nz = self.nuisances
        if nz.settle_m:  # the ropes' creep: the settled exits at time t
            self._a_star = self._a_star0 + self._settle_dir * (nz.settle_m * t / nz.settle_s)
            self._r = lever_arms(self._a_star, self.truth.pivots, self.truth.mast_index)
        predicted = self._predicted(t) if guess is None else None
        self.state = self.rest(self.unstretched(readings, t, visit_noise), guess, predicted)
        self._trail = [*self._trail[-1:], (float(t), self.state)]
        return self.state

    def _predicted(self, t: float) -> PlantState | None:
        """With :attr:`predict`, the rest at time ``t`` [s] extrapolated linearly (pose and
        mast rotations) from the last two settles when ``t`` continues their spacing (a
        steady motion, settled at equal steps); else None."""
        if not self.predict or len(self._trail) < 2:
            return None
        (t0, a), (t1, b) = self._trail
        if not t1 > t0 or abs((t - t1) - (t1 - t0)) > 1e-9 * max(1.0, abs(t)):
            return None
        return replace(b, pose=2.0 * b.pose - a.pose, theta=2.0 * b.theta - a.theta)

    def platform_point(self, state: PlantState, point: np.ndarray) -> np.ndarray:
        """A platform point (F_p) in F_b for ``state`` [m]."""
        return state.pose[:3] + rotation(state.pose[3:6]) @ point


#: a rest position turned this much [rad] from where its search started is spurious: the
#: platform rests near its last position or the commanded pose
MAX_TURN_RAD = 0.5

#: a rest search that loses its way follows the move in halves, each halved again while its
#: search loses its way, at most this many times (steps of 1/64 of the move)
MAX_HALVINGS = 6


def _turn_angle(rpy_a: np.ndarray, rpy_b: np.ndarray) -> float:
    """Angle [rad] of the rotation between two orientations (roll, pitch, yaw)."""
    R = rotation(rpy_a).T @ rotation(rpy_b)
    return float(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)))


def _safe_inverse(H: np.ndarray) -> np.ndarray:
    """Inverse of a (nearly) positive definite Hessian, eigenvalues floored."""
    w, V = np.linalg.eigh(H)
    floor = max(1e-6 * float(np.abs(w).max()), 1e-9)
    inv = (V / np.maximum(w, floor)) @ V.T
    return 0.5 * (inv + inv.T)
