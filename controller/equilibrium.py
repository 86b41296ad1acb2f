"""Elasto-static equilibrium: the pose of a platform hung on elastic cables from compliant masts.

Unknowns: the pose (6) and the mast rotations theta (m,3). For unstretched
lengths L0 (n,) the equations are

    W(x) tau(x) + w_g(x) = 0                (force and moment on the platform)
    theta_i - c_i * M_i(x) = 0              (each mast, c = 1/k, rigid: c = 0)

with ``tau = ea (L - L0)/L0`` (0 when slack), L the geometric length to the
displaced exit points A# (pulleys included) and M_i the cable moments about the
pivots (:mod:`controller.masts`). Newton's method with the analytic Jacobian
(:func:`residual_and_jacobian`), a backtracking line search and a warm start;
non-convergence is reported, never hidden. Cables far stiffer than the platform's weight
(ea above ``STIFF`` times it, as a fit can make them) are solved by continuation: softened
to that ea, then Newton's method on the mixed form, the tensions as unknowns
(:func:`_mixed_newton`).

Pose increments are ``(dt, w)`` with w a small rotation in F_b (see
:func:`controller.pose.compose`).
"""

from __future__ import annotations

import math
import threading
import weakref
from dataclasses import dataclass

import numpy as np

from controller import cables
from controller.cables import CableForces
from controller.energy import potential_energy, state_energy
from controller.kinematics import (
    CableState,
    cable_state,
    gravity_wrench,
    unit_vector_derivative,
    wrench_matrix,
)
from controller.masts import deflect, lever_arms, mast_incidence, mast_moments
from controller.pose import compose, cross, skew
from controller.robot import Robot
from controller.statics import elastic_tensions, settled_exits


class ConvergenceError(RuntimeError):
    """A solver did not converge; the message says how far it got."""


class SolverStats(threading.local):
    """Counts of :func:`solve_equilibrium` outcomes in this thread: ``calls``, ``newton``
    (converged by Newton from the guess), ``fallbacks`` (the energy descent was needed),
    ``failures`` (no stable equilibrium found), ``mixed`` (of the ``newton`` ones, those
    finished on the mixed form: cables stiffer than ``STIFF``). For evaluations."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.calls = self.newton = self.fallbacks = self.failures = self.mixed = 0

    def as_dict(self) -> dict[str, int]:
        return {"calls": self.calls, "newton": self.newton, "fallbacks": self.fallbacks,
                "failures": self.failures, "mixed": self.mixed}


STATS = SolverStats()


@dataclass(frozen=True)
class EquilibriumResult:
    """Result of :func:`solve_equilibrium`.

    ``pose`` (6,); ``theta`` (m,3) [rad]; ``tensions`` (n,) [N]; ``exits`` A#
    (n,3) [m]; ``success``; ``message``; ``nit`` Newton iterations;
    ``residual`` scaled residual norm (force/weight, moment/(weight*1 m), rad).
    The Jacobian at the solution (for sensitivities) comes from
    :func:`residual_and_jacobian`.
    """

    pose: np.ndarray
    theta: np.ndarray
    tensions: np.ndarray
    exits: np.ndarray
    success: bool
    message: str
    nit: int
    residual: float

    def raise_if_failed(self) -> EquilibriumResult:
        if not self.success:
            raise ConvergenceError(self.message)
        return self


@dataclass(frozen=True)
class EquilibriumTerms:
    """Everything evaluated at one iterate (shared by residual, Jacobian and results)."""

    state: CableState
    exits: np.ndarray
    tensions: np.ndarray
    taut: np.ndarray
    forces: np.ndarray  # (n,3) cable forces on the platform, tau*u
    residual: np.ndarray
    cables: CableForces | None = None  # sagging cables' forces (rho > 0)


def _balance(robot: Robot, st: CableState, f: np.ndarray, theta: np.ndarray,
             r: np.ndarray, tau: np.ndarray, u_exit: np.ndarray) -> np.ndarray:
    """Equilibrium residual (6+3m,): net force [N] and moment [N m] on the platform (cable
    forces ``f`` (n,3) on it plus gravity, base frame), then each mast's ``theta - C M``
    [rad] with M the moments of the tensions ``tau`` [N] pulling along ``u_exit`` at the
    exits."""
    wg = gravity_wrench(robot.mass, robot.com, robot.gravity, st.R)
    F = np.empty(6 + 3 * robot.n_masts)
    F[:3] = f.sum(axis=0) + wg[:3]
    F[3:6] = cross(st.Rb, f).sum(axis=0) + wg[3:]
    M = mast_moments(r, tau, u_exit, robot.mast_index, robot.n_masts)
    F[6:] = (theta - robot.compliance * M).ravel()
    return F


def _terms(robot: Robot, pose: np.ndarray, theta: np.ndarray, l0: np.ndarray,
           a_star: np.ndarray, r: np.ndarray, guess: CableForces | None = None
           ) -> EquilibriumTerms:
    exits = deflect(a_star, r, theta, robot.mast_index) if robot.compliant else a_star
    st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
    if robot.rho > 0:
        return _terms_sag(robot, st, exits, theta, l0, r, guess)
    tau = elastic_tensions(st.length, l0, robot.ea)
    f = tau[:, None] * st.u
    F = _balance(robot, st, f, theta, r, tau, st.u)
    return EquilibriumTerms(st, exits, tau, st.length > l0, f, F)


def _terms_sag(robot: Robot, st: CableState, exits: np.ndarray, theta: np.ndarray,
               l0: np.ndarray, r: np.ndarray, guess: CableForces | None) -> EquilibriumTerms:
    """Terms with sagging cables: catenary forces at both ends (:mod:`controller.cables`)."""
    cf = cables.from_lengths(robot, st, l0, guess)
    f = cf.platform
    u_exit = cf.exit / np.maximum(cf.tension, 1e-12)[:, None]
    F = _balance(robot, st, f, theta, r, cf.tension, u_exit)
    return EquilibriumTerms(st, exits, cf.tension, np.ones(robot.n_cables, dtype=bool), f, F,
                            cf)


def energy_gradient(robot: Robot, pose: np.ndarray, theta: np.ndarray, l0: np.ndarray,
                    a_star: np.ndarray, r: np.ndarray, guess: CableForces | None = None
                    ) -> np.ndarray:
    """Gradient of :func:`controller.energy.potential_energy` w.r.t. ``(dt, w, theta)``
    (6+3m,): ``-F`` on the platform and ``K theta - M`` on the masts (0 on rigid axes).
    ``guess``: as for the energy."""
    T = _terms(robot, pose, theta, l0, a_star, r, guess)
    g = -T.residual
    k = np.where(np.isfinite(robot.stiffness), robot.stiffness, 0.0).ravel()
    g[6:] = k * T.residual[6:]
    return g


def residual_and_jacobian(robot: Robot, pose: np.ndarray, theta: np.ndarray, l0: np.ndarray,
                          a_star: np.ndarray | None = None
                          ) -> tuple[EquilibriumTerms, np.ndarray]:
    """Residual terms and the analytic Jacobian d(residual)/d(dt, w, theta) (6+3m square)."""
    a_star = settled_exits(robot) if a_star is None else a_star
    r = lever_arms(a_star, robot.pivots, robot.mast_index)
    T = _terms(robot, pose, theta, l0, a_star, r)
    return T, _jacobian(robot, T, l0, r)


def _jacobian(robot: Robot, T: EquilibriumTerms, l0: np.ndarray, r: np.ndarray,
              K: np.ndarray | None = None) -> np.ndarray:
    """d(residual)/d(dt, w, theta); ``K`` (n,3,3) overrides the cables' stiffnesses
    df_j = K_j (dB_j - dA_j) (the mixed form passes the geometric part alone)."""
    st, tau, f = T.state, T.tensions, T.forces
    n, m = robot.n_cables, robot.n_masts
    u = st.u
    # df_j = K_j (dB_j - dA_j)
    if K is not None:
        pass
    elif T.cables is not None:
        K = cables.stiffness(robot, st, T.cables)
    else:
        kax = np.where(T.taut, robot.ea / l0, 0.0)
        K = -kax[:, None, None] * (u[:, :, None] * u[:, None, :]) \
            + tau[:, None, None] * unit_vector_derivative(st)
    sRb = skew(st.Rb)
    # dB/d(t, w) = [I, -[Rb]x]  ->  K dB = [K, -K [Rb]x]
    dF_pose = np.empty((n, 3, 6))
    dF_pose[:, :, :3] = K
    dF_pose[:, :, 3:] = -(K @ sRb)
    J = np.zeros((6 + 3 * m, 6 + 3 * m))
    J[0:3, 0:6] = dF_pose.sum(axis=0)
    # moment: d(Rb x f) = [f]x [Rb]x w + [Rb]x df
    J[3:6, 0:6] = (sRb @ dF_pose).sum(axis=0)
    J[3:6, 3:6] += (skew(f) @ sRb).sum(axis=0)
    mg = np.array([0.0, 0.0, -robot.mass * robot.gravity])
    J[3:6, 3:6] += skew(mg) @ skew(st.R @ robot.com)
    J[6:, 6:] = np.eye(3 * m)
    if not robot.compliant:
        return J
    # mast rotations: dA_j = -[r_j]x dtheta_i  ->  df_j/dtheta_i = K_j [r_j]x
    sr = skew(r)
    dF_theta = K @ sr
    S = mast_incidence(robot.mast_index, m)  # (m, n)
    J[0:3, 6:] = (S @ dF_theta.reshape(n, 9)).reshape(m, 3, 3).transpose(1, 0, 2).reshape(3, 3 * m)
    J[3:6, 6:] = (S @ (sRb @ dF_theta).reshape(n, 9)).reshape(m, 3, 3) \
        .transpose(1, 0, 2).reshape(3, 3 * m)
    # mast rows: theta_i - c_i * M_i,  M_i = -sum_j [r_j]x f_j
    c = robot.compliance  # (m, 3)
    dM_pose = (S @ (sr @ dF_pose).reshape(n, 18)).reshape(m, 3, 6)  # = -dM/dx
    J[6:, 0:6] = (c[:, :, None] * dM_pose).reshape(3 * m, 6)
    dM_theta = (S @ (sr @ dF_theta).reshape(n, 9)).reshape(m, 3, 3)  # = -dM/dtheta (per mast)
    blocks = c[:, :, None] * dM_theta
    for i in range(m):
        J[6 + 3 * i:9 + 3 * i, 6 + 3 * i:9 + 3 * i] += blocks[i]
    return J


#: a Newton step longer than this [m, rad] must not raise the potential energy
BIG_STEP = 0.01
_FIXED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: per robot: (pose, theta, l0, inverse Jacobian) of the last converged solution, to start
#: the next solve near it with that inverse (a warm start of the quasi-Newton iteration)
_LAST: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _reuse(robot: Robot, pose: np.ndarray, theta: np.ndarray, l0: np.ndarray
           ) -> np.ndarray | None:
    """The last solution's inverse Jacobian when this solve starts near that solution (within
    5 mm, 5 mrad, 5 mm of length and 0.5 mrad of mast rotation), else None."""
    last = _LAST.get(robot)
    if last is None:
        return None
    p, th, lengths, inv = last
    if (len(lengths) == len(l0) and np.abs(pose[:3] - p[:3]).max() < 5e-3
            and np.abs(pose[3:] - p[3:]).max() < 5e-3 and np.abs(l0 - lengths).max() < 5e-3
            and np.abs(theta - th).max() < 5e-4):
        return inv.copy()
    return None


def _fixed(robot: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Settled exit points, lever arms and residual scale of a robot (computed once per robot
    object: a description is immutable)."""
    got = _FIXED.get(robot)
    if got is None:
        a_star = settled_exits(robot)
        got = (a_star, lever_arms(a_star, robot.pivots, robot.mast_index), _scale(robot))
        _FIXED[robot] = got
    return got


def _scale(robot: Robot) -> np.ndarray:
    w = max(robot.weight, 1.0)
    return np.concatenate([np.full(3, 1.0 / w), np.full(3, 1.0 / w), np.full(3 * robot.n_masts,
                                                                             1e3)])


def solve_equilibrium(robot: Robot, l0: np.ndarray, guess: np.ndarray,
                      theta: np.ndarray | None = None, tol: float = 1e-9,
                      max_iter: int = 60) -> EquilibriumResult:
    """Pose and mast rotations where elastic cables of unstretched lengths ``l0`` balance gravity.

    ``guess`` (6,) is the first pose (e.g. the desired one or the last
    solution); ``theta`` (m,3) the mast rotations to start from (warm start).
    Converged when the scaled residual is below ``tol`` (forces relative to the
    weight, moments relative to weight x 1 m, mast rotations in mrad).

    If Newton's method fails from the guess (cables slack or over-tensioned
    there, several cables changing state on the way) or lands far away on an
    unstable equilibrium, a trust-region descent of the potential energy
    (:mod:`controller.energy`) takes over from the guess and Newton polishes.

    Cables stiffer than ``STIFF`` times the platform's weight (ea in N; a fit can drive an ea
    to 1e14 N) are solved by continuation: the equilibrium with those cables softened to
    that ea (the displacement form, as above), then Newton's method on the mixed form
    (:func:`_mixed_newton`, tensions as unknowns) with the true ea from there.
    """
    soft = _softened(robot)
    model = robot if soft is None else soft
    # forces cannot be resolved finer than round-off in ea * (L - L0) / L0 (the mixed form,
    # with tensions as unknowns, resolves them whatever ea)
    tol_d = max(tol, 20 * np.finfo(float).eps * float(np.max(model.ea))
                * np.sqrt(model.n_cables) / max(model.weight, 1.0))
    if soft is None:
        tol = tol_d

    def finish(res: EquilibriumResult) -> EquilibriumResult:
        if soft is None or not res.success:
            return res
        return _mixed_newton(robot, l0, res.pose, res.theta, tol, max_iter, res.tensions)

    STATS.calls += 1
    res = _newton(model, l0, guess, theta, tol_d, max_iter)
    if res.success and (_near(res.pose, guess) or is_stable(model, res, l0)):
        out = finish(res)
        if out.success:
            STATS.newton += 1
            STATS.mixed += soft is not None
            return out
        res = out
    if max_iter < 5:
        STATS.failures += not res.success
        return res
    STATS.fallbacks += 1
    descent = _energy_descent(model, np.asarray(l0, float), np.array(guess, float), theta, tol_d)
    polished = _newton(model, l0, descent.pose, descent.theta, tol_d, max_iter)
    if polished.success and is_stable(model, polished, l0):
        out = finish(polished)
        if out.success:
            return out
    if descent.success:
        out = finish(descent)
        if out.success:
            return out
    STATS.failures += 1
    if res.success:
        return EquilibriumResult(res.pose, res.theta, res.tensions, res.exits, False,
                                 "equilibrium: only an unstable equilibrium found", res.nit,
                                 res.residual)
    return min((res, descent, polished), key=lambda x: x.residual)


#: cables stiffer than this many times the platform's weight [N/N] are solved by continuation
#: from this ea (:func:`solve_equilibrium`); real cables are below 1e4 (ROCASPECT 1.7e3)
STIFF = 1e5
_SOFT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _softened(robot: Robot) -> Robot | None:
    """The robot with every ea capped at ``STIFF`` times its weight, or None when no cable
    is that stiff (or the cables sag: the catenary has its own stiffness)."""
    if robot.rho > 0:
        return None
    got = _SOFT.get(robot)
    if got is None:
        cap = STIFF * max(robot.weight, 1.0)
        got = (robot.replace(ea=np.minimum(robot.ea, cap)) if np.max(robot.ea) > cap
               else False)
        _SOFT[robot] = got
    return got or None


def scaled_residual(robot: Robot, l0: np.ndarray, pose: np.ndarray,
                    theta: np.ndarray | None = None) -> float:
    """Norm of the equilibrium residual at ``pose`` (mast rotations ``theta``, default none),
    scaled as :func:`solve_equilibrium` scales it: how far a candidate start is from
    balancing (to choose among guesses)."""
    a_star, r, S = _fixed(robot)
    th = np.zeros((robot.n_masts, 3)) if theta is None else np.asarray(theta, dtype=float)
    T = _terms(robot, np.asarray(pose, dtype=float), th, np.asarray(l0, dtype=float), a_star, r)
    return float(np.linalg.norm(S * T.residual))


def _energy_descent(robot: Robot, l0: np.ndarray, guess: np.ndarray,
                    theta: np.ndarray | None, tol: float = 1e-10,
                    max_iter: int = 300) -> EquilibriumResult:
    """Trust-region minimisation of the potential energy over (pose, compliant mast axes).

    Gradient and model Hessian (symmetrised) come from the equilibrium equations
    and their Jacobian; steps are accepted on the actual energy decrease, so slack and
    taut cables change state safely and saddle points repel.
    """
    m = robot.n_masts
    pose = guess.copy()
    th = np.zeros((m, 3)) if theta is None else np.array(theta, dtype=float)
    a_star = settled_exits(robot)
    r = lever_arms(a_star, robot.pivots, robot.mast_index)
    free_th = np.isfinite(robot.stiffness).ravel()
    k = np.where(np.isfinite(robot.stiffness), robot.stiffness, 0.0).ravel()[free_th]
    idx = np.concatenate([np.arange(6), 6 + np.flatnonzero(free_th)])
    # variable scales: metres, radians x 1 m of platform, mast radians x mast height
    height = float(np.mean(np.linalg.norm(r, axis=1)))
    D = np.concatenate([np.ones(6), np.full(len(k), height)])
    S = _scale(robot)
    E = potential_energy(robot, pose, th, l0, a_star, r)
    delta = 0.05
    T = _terms(robot, pose, th, l0, a_star, r)
    it = 0
    for it in range(1, max_iter + 1):
        phi = float(np.linalg.norm(S * T.residual))
        if phi < tol:
            return EquilibriumResult(pose, th, T.tensions, T.exits, True, "converged", it - 1,
                                     phi)
        J = _jacobian(robot, T, l0, r)[np.ix_(idx, idx)]
        # dE/d(pose) = -F_pose;  dE/dtheta = K theta - M = K F_theta
        g = -T.residual[idx]
        g[6:] *= -k
        H = -J
        H[6:] *= -k[:, None]
        H = 0.5 * (H + H.T)
        gs = g / D
        Hs = H / D[:, None] / D[None, :]
        lam_all, V = np.linalg.eigh(Hs)
        gv = V.T @ gs
        for _ in range(40):  # trust region: shrink until the energy goes down enough
            p_s = _trust_step(lam_all, V, gv, delta)
            p = p_s / D
            pred = float(g @ p + 0.5 * p @ H @ p)
            new_pose = compose(pose, p[:6])
            new_th = th.copy().ravel()
            new_th[free_th] += p[6:]
            new_th = new_th.reshape(m, 3)
            E_new = potential_energy(robot, new_pose, new_th, l0, a_star, r)
            rho = (E_new - E) / pred if pred < 0 else -1.0
            if rho > 0.1 or (abs(E_new - E) <= 1e-15 * max(1.0, abs(E)) and pred > -1e-14):
                break
            delta *= 0.25
        else:
            break
        if rho > 0.75 and np.linalg.norm(p_s) > 0.8 * delta:
            delta = min(2.0 * delta, 1.0)
        pose, th, E = new_pose, new_th, E_new
        T = _terms(robot, pose, th, l0, a_star, r)
    phi = float(np.linalg.norm(S * T.residual))
    return EquilibriumResult(pose, th, T.tensions, T.exits, phi < tol,
                             "converged" if phi < tol else
                             f"equilibrium: energy descent stopped (scaled residual {phi:.3g})",
                             it, phi)


def _trust_step(lam: np.ndarray, V: np.ndarray, gv: np.ndarray, delta: float) -> np.ndarray:
    """Minimiser of ``g.p + p.H.p/2`` with ``|p| <= delta`` (H = V diag(lam) V^T, gv = V^T g)."""
    lo = max(0.0, -float(lam.min())) + 1e-12 * max(1.0, float(np.abs(lam).max()))
    if lam.min() > 0:
        p = -gv / lam
        if np.linalg.norm(p) <= delta:
            return V @ p
    hi = lo + np.linalg.norm(gv) / delta + 1.0
    while np.linalg.norm(gv / (lam + hi)) > delta:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if np.linalg.norm(gv / (lam + mid)) > delta:
            lo = mid
        else:
            hi = mid
    return V @ (-gv / (lam + hi))


def _near(pose: np.ndarray, guess: np.ndarray) -> bool:
    """Within 5 cm and 0.05 rad of the guess: Newton stayed in the guess's basin."""
    d = np.abs(np.asarray(pose) - np.asarray(guess))
    return bool(d[:3].max() < 0.05 and d[3:].max() < 0.05)


def platform_stiffness(robot: Robot, res: EquilibriumResult, l0: np.ndarray) -> np.ndarray:
    """Stiffness of the platform at an equilibrium, masts condensed out: K (6,6) with
    ``dF = -K dx`` for a pose increment dx = (dt, w) [N/m, N, N m/rad]. Straight cables carry
    the result's tensions (the mixed form's, for cables too stiff for their lengths to give
    them)."""
    T, J = residual_and_jacobian(robot, res.pose, res.theta, l0)
    if T.cables is None:
        tau = np.asarray(res.tensions, dtype=float)
        T = EquilibriumTerms(T.state, T.exits, tau, tau > 0, tau[:, None] * T.state.u,
                             T.residual)
        a_star, r, _ = _fixed(robot)
        J = _jacobian(robot, T, np.asarray(l0, dtype=float), r)
    A, B, C, D = J[:6, :6], J[:6, 6:], J[6:, :6], J[6:, 6:]
    return -(A - B @ np.linalg.solve(D, C))


def is_stable(robot: Robot, res: EquilibriumResult, l0: np.ndarray) -> bool:
    """A stable equilibrium: every eigenvalue of the platform stiffness has a positive real part."""
    return bool(np.linalg.eigvals(platform_stiffness(robot, res, l0)).real.min() > 0)


def _newton(robot: Robot, l0: np.ndarray, guess: np.ndarray, theta: np.ndarray | None,
            tol: float, max_iter: int) -> EquilibriumResult:
    """Newton's method for :func:`solve_equilibrium`. Steps keep their inverse Jacobian while
    it still contracts the residual tenfold per step (chord steps) and refresh it
    otherwise; a solve that starts near the last solution of the same robot starts with
    that solution's inverse Jacobian.

    The line search asks the residual norm to fall. A cable's slack point is a kink of the
    residual: the taut side's Newton step takes the cable past it, the slack side's takes
    the platform far away, and the residual norm falls along neither (or hardly). Where it
    stalls or creeps so (or every cable is slack, or the Jacobian is singular), Newton goes
    on with the potential energy, smooth across slack points, as its merit
    (:func:`_energy_newton`). So it does where a step longer than ``BIG_STEP`` raises the
    energy: the residual also falls towards saddles, and a long step up the energy heads for
    one (or a state of the cables the linearisation ignored), away from the stable
    equilibrium near the guess."""
    if not np.all(np.isfinite(robot.ea)):
        raise ValueError("solve_equilibrium needs elastic cables (ea); use forward_rigid for "
                         "inextensible ones")
    l0 = np.asarray(l0, dtype=float)
    pose = np.array(guess, dtype=float)
    th = np.zeros((robot.n_masts, 3)) if theta is None else np.array(theta, dtype=float)
    a_star, r, S = _fixed(robot)
    T = _terms(robot, pose, th, l0, a_star, r)
    phi = float(np.linalg.norm(S * T.residual))
    lu = _reuse(robot, pose, th, l0)  # inverse Jacobian (chord steps reuse it)
    fresh = False
    crawl = 0  # consecutive exact Newton steps that took off less than 5 % of the residual
    for it in range(1, max_iter + 1):
        if phi < tol:
            if lu is not None:
                _LAST[robot] = (pose, th, l0, lu)
            return EquilibriumResult(pose, th, T.tensions, T.exits, True, "converged", it - 1,
                                     phi)
        if lu is None:
            if not T.taut.any():
                return _energy_newton(robot, l0, pose, th, T, tol, max_iter, it)
            try:
                lu = np.linalg.inv(_jacobian(robot, T, l0, r))
            except np.linalg.LinAlgError:
                lu = np.full((len(T.residual), len(T.residual)), np.nan)
            fresh = True
        dx = lu @ -T.residual
        if not math.isfinite(float(dx @ dx)):
            if not fresh:
                lu = None
                continue
            return _energy_newton(robot, l0, pose, th, T, tol, max_iter, it)
        step = 1.0
        for _ in range(30):
            p_new = compose(pose, step * dx[:6])
            th_new = th + step * dx[6:].reshape(-1, 3)
            T_new = _terms(robot, p_new, th_new, l0, a_star, r)
            sr = S * T_new.residual
            phi_new = math.sqrt(float(sr @ sr))
            if phi_new < (1.0 - 1e-4 * step) * phi or phi_new < tol:
                break
            step *= 0.5
            if not fresh:
                break  # a stale Jacobian that needs damping: refresh it instead
        else:  # stalled at a kink of the residual
            return _energy_newton(robot, l0, pose, th, T, tol, max_iter, it)
        if (np.abs(dx[:6]).max() * step > BIG_STEP and state_energy(
                robot, T_new.state, p_new, th_new, l0, T_new.cables)
                > state_energy(robot, T.state, pose, th, l0, T.cables)):
            if not fresh:
                # a stale Jacobian's long step up the energy: the Jacobian of here decides
                lu = None
                continue
            # a long step up the energy: towards a saddle (the residual falls there too),
            # or across slack points the linearisation ignored; the energy's Newton descends
            return _energy_newton(robot, l0, pose, th, T, tol, max_iter, it)
        if not fresh and step < 1.0:
            lu = None
            continue
        crawl = crawl + 1 if fresh and phi_new > 0.95 * phi else 0
        if crawl >= 3:  # creeping along kinks: the energy takes the iterates through them
            return _energy_newton(robot, l0, p_new, th_new, T_new, tol, max_iter, it)
        if phi_new > 0.1 * phi:
            lu = None  # slow contraction: refresh the Jacobian next step
        fresh = False
        pose, th, T, phi = p_new, th_new, T_new, phi_new
    ok = phi < tol
    msg = "converged" if ok else (f"equilibrium: no convergence in {max_iter} iterations "
                                  f"(scaled residual {phi:.3g})")
    return EquilibriumResult(pose, th, T.tensions, T.exits, ok, msg, max_iter, phi)


def _energy_newton(robot: Robot, l0: np.ndarray, pose: np.ndarray, th: np.ndarray,
                   T: EquilibriumTerms, tol: float, max_iter: int, it0: int
                   ) -> EquilibriumResult:
    """Newton's method on the potential energy from where :func:`_newton` stalled: steps
    solve ``(H + mu D^2) p = -g`` (g, H the energy's gradient and symmetrised Hessian over
    the pose and the compliant mast axes; D the square roots of H's diagonal, at least the
    weight over 1 m, so that a mast axis stiffer than the others by thirty orders of
    magnitude, as a fit can make it, does not drown them; mu = 0 where H is positive
    definite, else enough to make it so) and are halved until the energy falls (Armijo).
    The energy is continuously differentiable across slack points, so the iterates go
    through the kinks that stall the residual's line search; converged when the scaled
    residual is below ``tol``.

    Where H is positive definite (mu = 0: a convex neighbourhood, no saddle ahead), a full
    step that halves the scaled residual is taken whatever the energy does: sagging cables on
    pulleys have an energy that is their forces' potential only to a fraction of a percent
    (the leave point of :func:`controller.cables._leave`), so its minimum lies micrometres
    from the equilibrium, and there the energy changes by its round-off alone: the
    Armijo steps shrank to nothing 1e-4 (scaled) short of the equilibrium (case 9948)."""
    m = robot.n_masts
    a_star, r, S = _fixed(robot)
    free_th = np.isfinite(robot.stiffness).ravel()
    k = np.where(np.isfinite(robot.stiffness), robot.stiffness, 0.0).ravel()[free_th]
    idx = np.concatenate([np.arange(6), 6 + np.flatnonzero(free_th)])
    height = float(np.mean(np.linalg.norm(r, axis=1)))
    D0 = np.concatenate([np.ones(6), np.full(len(k), height)])  # m, rad x 1 m, rad x height
    floor = max(robot.weight, 1.0)  # [N/m]: gravity alone moves the platform by 1 m a step
    E = state_energy(robot, T.state, pose, th, l0, T.cables)
    phi = float(np.linalg.norm(S * T.residual))
    it = it0
    for it in range(it0, it0 + max_iter):
        if phi < tol:
            return EquilibriumResult(pose, th, T.tensions, T.exits, True, "converged", it, phi)
        J = _jacobian(robot, T, l0, r)[np.ix_(idx, idx)]
        g = -T.residual[idx]
        g[6:] *= -k
        H = -J
        H[6:] *= -k[:, None]
        H = 0.5 * (H + H.T)
        D = D0 * np.sqrt(np.maximum(np.abs(np.diag(H)) / (D0 * D0), floor))
        lam, V = np.linalg.eigh(H / D[:, None] / D[None, :])
        mu = max(0.0, -2.0 * float(lam.min()))
        if lam.min() + mu < 1e-9 * max(1.0, float(np.abs(lam).max())):
            mu += 1.0
        p = -(V @ ((V.T @ (g / D)) / (lam + mu))) / D
        slope = float(g @ p)
        step = 1.0
        for _ in range(40):
            dx = np.zeros(6 + 3 * m)
            dx[idx] = step * p
            p_new = compose(pose, dx[:6])
            th_new = th + dx[6:].reshape(-1, 3)
            T_new = _terms(robot, p_new, th_new, l0, a_star, r)
            E_new = state_energy(robot, T_new.state, p_new, th_new, l0, T_new.cables)
            phi_new = float(np.linalg.norm(S * T_new.residual))
            if (E_new <= E + 1e-4 * step * slope or phi_new < tol
                    or (mu == 0.0 and step == 1.0 and phi_new <= 0.5 * phi)):
                break
            step *= 0.5
        else:
            return EquilibriumResult(pose, th, T.tensions, T.exits, False,
                                     f"equilibrium: line search failed at iteration {it} "
                                     f"(scaled residual {phi:.3g})", it, phi)
        pose, th, T, phi, E = p_new, th_new, T_new, phi_new, E_new
    ok = phi < tol
    msg = "converged" if ok else (f"equilibrium: no convergence in {it0 + max_iter} iterations "
                                  f"(scaled residual {phi:.3g})")
    return EquilibriumResult(pose, th, T.tensions, T.exits, ok, msg, it, phi)


#: the mixed form weighs a cable's length error at most as a spring of the platform's weight per
#: this length would: a stiffer cable's geometric nonlinearity is not magnified by its ea
MIXED_LENGTH = 1e-3  # [m]


def _mixed_terms(robot: Robot, pose: np.ndarray, theta: np.ndarray, tau: np.ndarray,
                 l0: np.ndarray, a_star: np.ndarray, r: np.ndarray
                 ) -> tuple[EquilibriumTerms, np.ndarray]:
    """Residual of the mixed form at (pose, theta, tensions ``tau``): the equilibrium rows of
    :func:`_terms` with the tensions given, and each cable's length error
    ``e = L - L0 (1 + tau/ea)`` (n,) [m]."""
    exits = deflect(a_star, r, theta, robot.mast_index) if robot.compliant else a_star
    st = cable_state(pose, robot.anchors, exits, robot.pulley_radius)
    f = tau[:, None] * st.u
    F = _balance(robot, st, f, theta, r, tau, st.u)
    e = st.length - l0 - tau * (l0 / robot.ea)
    return EquilibriumTerms(st, exits, tau, tau > 0, f, F), e


def _mixed_jacobian(robot: Robot, T: EquilibriumTerms, l0: np.ndarray, r: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blocks of the mixed form's Jacobian: d(rows)/d(dt, w, theta) at fixed tensions (the
    cables' geometric stiffness alone), d(rows)/d(tau) (6+3m, n) and dL/d(dt, w, theta)
    (n, 6+3m)."""
    st = T.state
    n, m = robot.n_cables, robot.n_masts
    K = T.tensions[:, None, None] * unit_vector_derivative(st)
    Jx = _jacobian(robot, T, l0, r, K)
    Wm = wrench_matrix(st)
    B = np.zeros((6 + 3 * m, n))
    B[:6] = Wm
    G = np.zeros((n, 6 + 3 * m))
    G[:, :6] = -Wm.T  # dL/d(t, w) (kinematics.length_jacobian)
    if robot.compliant:  # dL_j/dtheta_i = (r_j x u_j)^T; mast rows d/dtau_j = c_i (r_j x u_j)
        ru = cross(r, st.u)
        cols = 6 + 3 * robot.mast_index[:, None] + np.arange(3)
        rows = np.arange(n)[:, None]
        B[cols, rows] = robot.compliance[robot.mast_index] * ru
        G[rows, cols] = ru
    return Jx, B, G


def _mixed_newton(robot: Robot, l0: np.ndarray, guess: np.ndarray, theta: np.ndarray | None,
                  tol: float, max_iter: int, tau0: np.ndarray | None = None
                  ) -> EquilibriumResult:
    """Newton's method on the mixed form: unknowns the pose, the mast rotations and the
    tensions tau; rows the equilibrium (as :func:`_terms`, with tau) and each cable's
    complementarity ``min(tau_j, beta_j s_j) = 0`` with ``s_j = L0_j (1 + tau_j/ea_j) - L_j``
    (>= 0: not stretched beyond its law) and ``beta_j = min(ea_j/L0_j, weight/MIXED_LENGTH)``
    (semi-smooth Newton: a taut cable's row linearises its length, a slack one's sets its
    tension to 0). Residual norm as merit, halving steps.

    Cables much stiffer than the platform's weight (ea of 1e12 N and more, as a fit can make
    them) break the displacement form (:func:`_newton`): a step of s sideways changes such a
    cable's length by s^2/2L, which ea/L turns into an error of kilonewtons that the residual's
    line search rejects, and its tension ea (L - L0)/L0 cannot be resolved from the lengths
    finer than ea * 1e-16. Here that length error stays a length error and the tension an
    unknown of its own."""
    l0 = np.asarray(l0, dtype=float)
    n, m = robot.n_cables, robot.n_masts
    N = 6 + 3 * m
    pose = np.array(guess, dtype=float)
    th = np.zeros((m, 3)) if theta is None else np.array(theta, dtype=float)
    a_star, r, S = _fixed(robot)
    w = max(robot.weight, 1.0)
    beta = np.minimum(robot.ea / l0, w / MIXED_LENGTH)
    cl = l0 / robot.ea  # [m/N]
    if tau0 is None:  # a soft spring's tension to start
        T, e = _mixed_terms(robot, pose, th, np.zeros(n), l0, a_star, r)
        tau0 = np.maximum(beta * (T.state.length - l0), 0.0)
    T, e = _mixed_terms(robot, pose, th, np.asarray(tau0, dtype=float), l0, a_star, r)

    def ncp(tau: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fischer-Burmeister a + b - |(a, b)| of a = tau/weight, b = beta s/weight, and its
        derivatives by a and b."""
        a, b = tau / w, -beta * e / w
        rho = np.hypot(a, b)
        safe = np.where(rho > 0, rho, 1.0)
        da = np.where(rho > 0, 1.0 - a / safe, 1.0 - math.sqrt(0.5))
        db = np.where(rho > 0, 1.0 - b / safe, 1.0 - math.sqrt(0.5))
        return a + b - rho, da, db

    def merit(T: EquilibriumTerms, e: np.ndarray) -> float:
        v = np.concatenate([S * T.residual, ncp(T.tensions, e)[0]])
        return math.sqrt(float(v @ v))

    phi = merit(T, e)
    it = 0
    for it in range(max_iter):
        if phi < tol:  # slack side of the complementarity: tension 0 (it is below tol)
            tau = np.where(-beta * e > T.tensions, 0.0, np.maximum(T.tensions, 0.0))
            return EquilibriumResult(pose, th, tau, T.exits, True, "converged", it, phi)
        fb, da, db = ncp(T.tensions, e)
        Jx, B, G = _mixed_jacobian(robot, T, l0, r)
        # rows scaled: equilibrium by S, complementarity in weights; unknowns dtau / weight
        A = np.empty((N + n, N + n))
        A[:N, :N] = S[:, None] * Jx
        A[:N, N:] = S[:, None] * B * w
        # d(fb) = da dtau/w + db beta (cl dtau - G dx)/w
        A[N:, :N] = -(db * beta / w)[:, None] * G
        A[N:, N:] = np.diag(da + db * beta * cl)
        rhs = np.concatenate([-S * T.residual, -fb])
        try:
            z = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(z)):
            break
        dtau = z[N:] * w
        step = 1.0
        for _ in range(30):
            p_new = compose(pose, step * z[:6])
            th_new = th + step * z[6:N].reshape(-1, 3)
            T_new, e_new = _mixed_terms(robot, p_new, th_new, T.tensions + step * dtau, l0,
                                        a_star, r)
            phi_new = merit(T_new, e_new)
            if phi_new < (1.0 - 1e-4 * step) * phi or phi_new < tol:
                break
            step *= 0.5
        else:
            return EquilibriumResult(pose, th, np.maximum(T.tensions, 0.0), T.exits, False,
                                     f"equilibrium (mixed form): line search failed at "
                                     f"iteration {it} (scaled residual {phi:.3g})", it, phi)
        pose, th, T, e, phi = p_new, th_new, T_new, e_new, phi_new
    ok = phi < tol
    msg = "converged" if ok else (f"equilibrium (mixed form): no convergence in {it + 1} "
                                  f"iterations (scaled residual {phi:.3g})")
    return EquilibriumResult(pose, th, np.maximum(T.tensions, 0.0), T.exits, ok, msg, it + 1,
                             phi)
