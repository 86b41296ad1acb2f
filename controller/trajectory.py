"""Trajectories: rest-to-rest, jerk-limited motions of the platform, sampled in time.

A :class:`Trajectory` is built from a start pose and a sequence of segment specifications
(:class:`Move`, :class:`Line`, :class:`Circle`, :class:`Dwell`, :class:`Visits`) under one
set of :class:`MotionLimits`. Each motion is a 7-phase S-curve (jerk +j, 0, -j, 0, -j, 0,
+j; the constant-acceleration or the cruise phases vanish on short moves) on a path
parameter, computed in closed form per phase: position, velocity and acceleration are
exact polynomials of time, continuous across phases and segments (every motion starts and
ends at rest).

- ``move``: a straight translation from the current pose to ``to`` while the orientation
  turns on SO(3) about one fixed axis (slerp); both follow the same normalised parameter
  ``s`` in [0, 1], whose speed, acceleration and jerk bounds are the tightest of the
  translational ones divided by the distance and the angular ones divided by the angle,
  so neither limit is exceeded and both arrive together.
- ``line``: a polyline through waypoints; the platform comes to rest at each vertex (a
  move per leg). Rest at the vertices keeps every corner free of jerk spikes and makes
  each leg's straightness exact, at the cost of a stop per vertex.
- ``circle``: an arc about ``center`` in the plane normal to ``normal``, by ``angle``
  (right-hand rule about ``normal``), starting where the platform is (which must lie in
  that plane); orientation held. The S-curve runs on the arc length; its cruise speed,
  tangential acceleration and jerk are reduced so that the full acceleration
  ``sqrt(a_t^2 + (v^2/r)^2)`` and jerk ``|(j_t - v^3/r^2) T + (3 v a_t / r) N|`` stay
  within the limits.
- ``dwell``: stand still for a duration.
- ``visits``: target poses visited ``visits`` times, each visit a move then a dwell of
  ``dwell_s``; order ``cycle`` (P1..Pn each round, as ISO 9283 pose tests do) or
  ``shuffle`` (a new permutation per round from ``seed``, as a calibration campaign does;
  a round never starts with the pose the previous one ended on, so that every visit
  moves).

Conventions (cdpr-conventions.md): poses ``(x, y, z, roll, pitch, yaw)`` in F_b [m, rad]
with ``R = Rz(yaw) Ry(pitch) Rx(roll)``. Velocities and accelerations returned by
:meth:`Trajectory.sample` are ``(dx, dy, dz, droll, dpitch, dyaw)`` [m/s, rad/s] and their
time derivatives [m/s^2, rad/s^2]: Euler-angle rates, not the angular velocity (the
limits bound the angular velocity ``omega`` in F_b; ``omega = E(rpy) d(rpy)/dt``, see
:func:`controller.pose.euler_rate_matrix`). Orientations near pitch = +-90 deg (gimbal
lock of these angles) are not supported.

A target given with 3 numbers is a position: the orientation is kept.

Labels: each sample is ``"move"`` while the platform is commanded to move and
``"dwell"`` while it stands at a target (``dwell`` segments and the dwells of
``visits``); a recording's ``state`` column takes them.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from controller.pose import euler_from_rotation, rotation, rotvec_matrix

MOVE = "move"
DWELL = "dwell"
ORDERS = ("cycle", "shuffle")


class TrajectoryError(ValueError):
    """A trajectory that cannot be built (bad limits, a circle whose start is off its
    plane, ...); the message says where (the segment, and the file when known)."""


# ---------------------------------------------------------------------------- limits


@dataclass(frozen=True)
class MotionLimits:
    """Bounds on the platform's motion (magnitudes of vectors, in F_b).

    ``max_speed_m_s`` [m/s]: the platform's maximum speed (the paper: 0.5 m/s);
    ``speed_pct`` [%]: the paper's v%, in (0, 100], scales the translational and angular
    speed bounds (not accelerations and jerks);
    ``max_accel_m_s2`` [m/s^2], ``max_jerk_m_s3`` [m/s^3]: translational;
    ``max_angular_speed_rad_s`` [rad/s], ``max_angular_accel_rad_s2`` [rad/s^2],
    ``max_angular_jerk_rad_s3`` [rad/s^3]: of the angular velocity in F_b.

    Defaults for a 35 kg platform hanging on ~20 m cables (ROCASPECT): 0.5 m/s^2 is an
    inertial force of 17.5 N, 5 % of the platform's weight, small against the tensions
    (~50-300 N) that the quasi-static controller plans from gravity alone; a jerk of
    1 m/s^3 ramps the acceleration over 0.5 s, slow against the cable-platform modes of
    a robot of this size (around 1-5 Hz), so the motion excites little swing. 0.2 rad/s
    moves an anchor 0.75 m from the centre at 0.15 m/s; 0.5 rad/s^2 and 1 rad/s^3 keep
    the same 0.5 s ramps. Cable speeds then stay below about 0.65 m/s, within the
    winches' 1 m/s (controller/data/rocaspect_winches.toml).
    """

    max_speed_m_s: float = 0.5
    speed_pct: float = 100.0
    max_accel_m_s2: float = 0.5
    max_jerk_m_s3: float = 1.0
    max_angular_speed_rad_s: float = 0.2
    max_angular_accel_rad_s2: float = 0.5
    max_angular_jerk_rad_s3: float = 1.0

    def __post_init__(self) -> None:
        for f in self.__dataclass_fields__:
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise TrajectoryError(f"limits: {f}: must be a finite number, got {v!r}")
            if v <= 0:
                raise TrajectoryError(f"limits: {f}: must be > 0, got {v}")
            object.__setattr__(self, f, float(v))
        if self.speed_pct > 100.0:
            raise TrajectoryError(f"limits: speed_pct: must be in (0, 100] % of "
                                  f"max_speed_m_s, got {self.speed_pct}")

    @property
    def speed_m_s(self) -> float:
        """Translational speed bound [m/s]: ``max_speed_m_s * speed_pct / 100``."""
        return self.max_speed_m_s * self.speed_pct / 100.0

    @property
    def angular_speed_rad_s(self) -> float:
        """Angular speed bound [rad/s]: ``max_angular_speed_rad_s * speed_pct / 100``."""
        return self.max_angular_speed_rad_s * self.speed_pct / 100.0

    def replace(self, **changes: float) -> MotionLimits:
        """A copy with some limits changed (validated)."""
        unknown = set(changes) - set(self.__dataclass_fields__)
        if unknown:
            raise TrajectoryError(f"limits: unknown key(s) {', '.join(sorted(unknown))} "
                                  f"(known: {', '.join(self.__dataclass_fields__)})")
        return replace(self, **changes)


# ---------------------------------------------------------------------------- S-curve


class SCurve:
    """Rest-to-rest jerk-limited profile of a scalar over ``distance`` >= 0 with bounds
    ``v`` (speed), ``a`` (acceleration), ``j`` (jerk) > 0, in closed form.

    Seven phases with jerks (+j, 0, -j, 0, -j, 0, +j) and durations
    (Tj, Ta - 2 Tj, Tj, Tv, Tj, Ta - 2 Tj, Tj): ``Tj = a_p / j`` is the jerk time,
    ``Ta`` the whole acceleration phase, ``Tv`` the cruise. With ``v_p`` the peak speed:
    ``a_p = a`` and ``Ta = v_p/a + a/j`` when ``v_p j >= a^2``, else ``a_p = sqrt(v_p j)``
    and ``Ta = 2 sqrt(v_p/j)``; the acceleration phase covers ``v_p Ta / 2``. If
    ``distance >= v Ta(v)``, ``v_p = v`` and ``Tv = (distance - v Ta)/v``; otherwise there
    is no cruise and ``v_p`` solves ``v_p Ta(v_p) = distance``:
    ``v_p = (-a^2/j + sqrt(a^4/j^2 + 4 a distance)) / 2`` (``a`` reached) or
    ``v_p = (distance sqrt(j) / 2)^(2/3)`` (``a`` not reached).
    """

    __slots__ = ("distance", "v_peak", "a_peak", "jerk", "tb", "s0", "v0", "a0", "jk",
                 "duration", "_tb_list", "_phases")

    def __init__(self, distance: float, v: float, a: float, j: float) -> None:
        D = float(distance)
        if not (D >= 0 and math.isfinite(D)):
            raise TrajectoryError(f"S-curve: distance must be finite and >= 0, got {D}")
        if not (v > 0 and a > 0 and j > 0):
            raise TrajectoryError(f"S-curve: bounds must be > 0, got v={v} a={a} j={j}")
        self.distance = D
        self.jerk = float(j)
        if D == 0.0:
            vp, Tj, Ta, ap, Tv = 0.0, 0.0, 0.0, 0.0, 0.0
        else:
            Tj, Ta, ap = self._accel_phase(v, a, j)
            if D >= v * Ta:
                vp, Tv = v, (D - v * Ta) / v
            else:
                Tv = 0.0
                vp = 0.5 * (-a * a / j + math.sqrt((a * a / j) ** 2 + 4.0 * a * D))
                if vp * j < a * a:
                    vp = (D * math.sqrt(j) / 2.0) ** (2.0 / 3.0)
                Tj, Ta, ap = self._accel_phase(vp, a, j)
        self.v_peak, self.a_peak = vp, ap
        Tc = max(0.0, Ta - 2.0 * Tj)
        durs = (Tj, Tc, Tj, Tv, Tj, Tc, Tj)
        jerks = (j, 0.0, -j, 0.0, -j, 0.0, j)
        tb = [0.0]
        s0, v0, a0 = [0.0], [0.0], [0.0]
        for d, jk in zip(durs, jerks, strict=True):
            s, vv, aa = s0[-1], v0[-1], a0[-1]
            s0.append(s + vv * d + aa * d * d / 2.0 + jk * d ** 3 / 6.0)
            v0.append(vv + aa * d + jk * d * d / 2.0)
            a0.append(aa + jk * d)
            tb.append(tb[-1] + d)
        self.duration = tb[-1]
        # phase starts (7) and the state there; the end state is exact rest at D
        self.tb = np.array(tb[:7])
        self._tb_list = tb[:7]
        self.s0 = np.array(s0[:7])
        self.v0 = np.array(v0[:7])
        self.a0 = np.array(a0[:7])
        self.jk = np.array(jerks)
        self._phases = list(zip(tb[:7], s0[:7], v0[:7], a0[:7], jerks, strict=True))

    @staticmethod
    def _accel_phase(vp: float, a: float, j: float) -> tuple[float, float, float]:
        """``(Tj, Ta, a_peak)`` of an acceleration phase from rest to ``vp``."""
        if vp * j >= a * a:
            Tj = a / j
            return Tj, vp / a + Tj, a
        Tj = math.sqrt(vp / j)
        return Tj, 2.0 * Tj, j * Tj

    def at(self, t: float) -> tuple[float, float, float]:
        """``(s, ds/dt, d2s/dt2)`` at time ``t`` [s] from the start (clamped to the motion)."""
        if t <= 0.0:
            return 0.0, 0.0, 0.0
        if t >= self.duration:
            return self.distance, 0.0, 0.0
        t0, s0, v0, a0, jk = self._phases[bisect.bisect_right(self._tb_list, t) - 1]
        dt = t - t0
        s = s0 + v0 * dt + a0 * dt * dt / 2.0 + jk * dt * dt * dt / 6.0
        return (min(s, self.distance), v0 + a0 * dt + jk * dt * dt / 2.0, a0 + jk * dt)

    def batch(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`at` for an array of times."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.tb, t, side="right") - 1, 0, 6)
        dt = t - self.tb[k]
        jk, a0, v0 = self.jk[k], self.a0[k], self.v0[k]
        s = self.s0[k] + v0 * dt + a0 * dt * dt / 2.0 + jk * dt ** 3 / 6.0
        v = v0 + a0 * dt + jk * dt * dt / 2.0
        a = a0 + jk * dt
        end = t >= self.duration
        s = np.where(end, self.distance, np.minimum(s, self.distance))
        v = np.where(end, 0.0, v)
        a = np.where(end, 0.0, a)
        return s, v, a


# ---------------------------------------------------------------------------- Euler rates


def euler_rates(rpy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Euler-angle rates (..., 3) [rad/s] of the angular velocity ``w`` (..., 3) in F_b:
    the inverse of ``w = E(rpy) d(rpy)`` (:func:`controller.pose.euler_rate_matrix`)."""
    p, y = rpy[..., 1], rpy[..., 2]
    cp, sp, cy, sy = np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    dr = (cy * w[..., 0] + sy * w[..., 1]) / cp
    dp = -sy * w[..., 0] + cy * w[..., 1]
    dy = w[..., 2] + sp * dr
    return np.stack([dr, dp, dy], axis=-1)


def euler_accels(rpy: np.ndarray, drpy: np.ndarray, dw: np.ndarray) -> np.ndarray:
    """Second derivatives (..., 3) [rad/s^2] of the Euler angles for the angular
    acceleration ``dw`` (..., 3) in F_b: ``E^-1 (dw - dE/dt d(rpy))``."""
    p, y = rpy[..., 1], rpy[..., 2]
    cp, sp, cy, sy = np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    dr, dp, dy = drpy[..., 0], drpy[..., 1], drpy[..., 2]
    ed = np.stack([(-sy * cp * dy - cy * sp * dp) * dr - cy * dy * dp,
                   (cy * cp * dy - sy * sp * dp) * dr - sy * dy * dp,
                   -cp * dp * dr], axis=-1)
    return euler_rates(rpy, dw - ed)


def _euler_rates1(rpy: list[float], w: list[float]) -> list[float]:
    """Scalar :func:`euler_rates` in plain floats (the per-cycle path)."""
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    dr = (cy * w[0] + sy * w[1]) / cp
    return [dr, -sy * w[0] + cy * w[1], w[2] + sp * dr]


def _euler_accels1(rpy: list[float], d: list[float], dw: list[float]) -> list[float]:
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    dr, dp, dy = d
    return _euler_rates1(rpy, [dw[0] - ((-sy * cp * dy - cy * sp * dp) * dr - cy * dy * dp),
                               dw[1] - ((cy * cp * dy - sy * sp * dp) * dr - sy * dy * dp),
                               dw[2] + cp * dp * dr])


def _wrap(x: np.ndarray | float) -> np.ndarray | float:
    """Angle difference wrapped into [-pi, pi)."""
    return (x + math.pi) % (2.0 * math.pi) - math.pi


# ---------------------------------------------------------------------------- motions


class _Motion:
    """A motion primitive over ``duration`` [s]; ``at`` (scalar) and ``batch`` (arrays)
    give pose, velocity and acceleration (6,) / (N,6) at local time."""

    duration: float = 0.0
    label: str = MOVE
    peak_speed: float = 0.0  #: the largest translational speed reached [m/s]
    peak_angular_speed: float = 0.0  #: the largest angular speed reached [rad/s]

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def batch(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError


class _Hold(_Motion):
    def __init__(self, pose: np.ndarray, duration: float, label: str) -> None:
        self.pose = np.array(pose, dtype=float)
        self.duration = float(duration)
        self.label = label
        self._zero = np.zeros(6)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.pose.copy(), self._zero.copy(), self._zero.copy()

    def batch(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(t)
        return np.tile(self.pose, (n, 1)), np.zeros((n, 6)), np.zeros((n, 6))


class _Linear(_Motion):
    """Straight translation with slerp: ``q(s) = q0 + s dq``, ``R(s) = exp(s [phi]x) R0``
    (phi in F_b), s in [0, 1] on an S-curve."""

    def __init__(self, start: np.ndarray, end: np.ndarray, lim: MotionLimits) -> None:
        self.start = np.array(start, dtype=float)
        self.end = np.array(end, dtype=float)
        self.dq = self.end[:3] - self.start[:3]
        self.R0 = rotation(self.start[3:])
        self.phi = Rotation.from_matrix(rotation(self.end[3:]) @ self.R0.T).as_rotvec()
        D = float(np.linalg.norm(self.dq))
        th = float(np.linalg.norm(self.phi))
        if th < 1e-12:
            th = 0.0
            self.phi = np.zeros(3)
        self.rotates = th > 0.0
        inf = math.inf
        v = min(lim.speed_m_s / D if D > 0 else inf, lim.angular_speed_rad_s / th if th else inf)
        a = min(lim.max_accel_m_s2 / D if D > 0 else inf,
                lim.max_angular_accel_rad_s2 / th if th else inf)
        j = min(lim.max_jerk_m_s3 / D if D > 0 else inf,
                lim.max_angular_jerk_rad_s3 / th if th else inf)
        self.profile = SCurve(1.0, v, a, j) if (D > 0 or th > 0) else None
        self.duration = self.profile.duration if self.profile else 0.0
        if self.profile:
            self.peak_speed = D * self.profile.v_peak
            self.peak_angular_speed = th * self.profile.v_peak
        self._q0 = [float(x) for x in self.start[:3]]
        self._dq = [float(x) for x in self.dq]
        self._rpy0 = [float(x) for x in self.start[3:]]
        self._drpy = [float(x) for x in self.end[3:] - self.start[3:]]
        self._phi = [float(x) for x in self.phi]

    def _orientation1(self, s: float) -> list[float]:
        rpy = euler_from_rotation(rotvec_matrix([p * s for p in self._phi]) @ self.R0)
        out = []
        for k in range(3):
            lin = self._rpy0[k] + s * self._drpy[k]
            out.append(lin + _wrap(float(rpy[k]) - lin))
        return out

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.profile is None:
            return self.end.copy(), np.zeros(6), np.zeros(6)
        s, ds, dds = self.profile.at(t)
        q0, dq = self._q0, self._dq
        if not self.rotates:
            return (np.array([q0[0] + s * dq[0], q0[1] + s * dq[1], q0[2] + s * dq[2],
                              *self._rpy0]),
                    np.array([ds * dq[0], ds * dq[1], ds * dq[2], 0.0, 0.0, 0.0]),
                    np.array([dds * dq[0], dds * dq[1], dds * dq[2], 0.0, 0.0, 0.0]))
        rpy = self._orientation1(s)
        phi = self._phi
        d = _euler_rates1(rpy, [ds * phi[0], ds * phi[1], ds * phi[2]])
        dd = _euler_accels1(rpy, d, [dds * phi[0], dds * phi[1], dds * phi[2]])
        return (np.array([q0[0] + s * dq[0], q0[1] + s * dq[1], q0[2] + s * dq[2], *rpy]),
                np.array([ds * dq[0], ds * dq[1], ds * dq[2], *d]),
                np.array([dds * dq[0], dds * dq[1], dds * dq[2], *dd]))

    def batch(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(t)
        pose, vel, acc = np.empty((n, 6)), np.zeros((n, 6)), np.zeros((n, 6))
        if self.profile is None:
            pose[:] = self.end
            return pose, vel, acc
        s, ds, dds = self.profile.batch(t)
        pose[:, :3] = self.start[:3] + s[:, None] * self.dq
        vel[:, :3] = ds[:, None] * self.dq
        acc[:, :3] = dds[:, None] * self.dq
        if not self.rotates:
            pose[:, 3:] = self.start[3:]
            return pose, vel, acc
        R = Rotation.from_rotvec(s[:, None] * self.phi) * Rotation.from_matrix(self.R0)
        lin = self.start[3:] + s[:, None] * (self.end[3:] - self.start[3:])
        pose[:, 3:] = lin + _wrap(R.as_euler("xyz") - lin)
        rpy = pose[:, 3:]
        vel[:, 3:] = euler_rates(rpy, ds[:, None] * self.phi)
        acc[:, 3:] = euler_accels(rpy, vel[:, 3:], dds[:, None] * self.phi)
        return pose, vel, acc


class _Arc(_Motion):
    """Arc about ``center`` in the plane normal to ``normal`` by ``angle`` [rad] (right hand
    about ``normal``), orientation held; S-curve on the arc length."""

    PLANE_TOL_M = 1e-3

    def __init__(self, start: np.ndarray, center: np.ndarray, normal: np.ndarray,
                 angle: float, lim: MotionLimits) -> None:
        self.start = np.array(start, dtype=float)
        c = np.asarray(center, dtype=float)
        nrm = np.asarray(normal, dtype=float)
        nn = float(np.linalg.norm(nrm))
        if not nn > 0:
            raise TrajectoryError("circle: normal must not be the zero vector")
        nrm = nrm / nn
        r0 = self.start[:3] - c
        off = float(r0 @ nrm)
        if abs(off) > self.PLANE_TOL_M:
            raise TrajectoryError(
                f"circle: the start point {np.round(self.start[:3], 4).tolist()} is "
                f"{off:+.4f} m off the circle's plane (through center "
                f"{np.round(c, 4).tolist()}, normal {np.round(nrm, 4).tolist()}); "
                f"the arc starts where the platform is")
        r0 = r0 - off * nrm
        r = float(np.linalg.norm(r0))
        if not r > 1e-6:
            raise TrajectoryError("circle: the start point is at the centre (radius 0)")
        self.center, self.normal, self.radius = c + off * nrm, nrm, r
        self.e1, self.e2 = r0, np.cross(nrm, r0)  # both of length r
        self.sign = 1.0 if angle >= 0 else -1.0
        self.angle = float(angle)
        L = r * abs(float(angle))
        v, at, jt = self._limits(r, lim)
        self.profile = SCurve(L, v, at, jt) if L > 0 else None
        self.duration = self.profile.duration if self.profile else 0.0
        self.peak_speed = self.profile.v_peak if self.profile else 0.0
        end_phi = self.sign * L / r
        self.end = self.start.copy()
        self.end[:3] = self.center + self.e1 * math.cos(end_phi) + self.e2 * math.sin(end_phi)

    @staticmethod
    def _limits(r: float, lim: MotionLimits) -> tuple[float, float, float]:
        """Cruise speed, tangential acceleration and jerk such that the full acceleration
        and jerk of the circular motion stay within the limits."""
        amax, jmax = lim.max_accel_m_s2, lim.max_jerk_m_s3
        v = min(lim.speed_m_s, math.sqrt(0.6 * amax * r))  # v^2/r <= 0.6 amax
        at = 0.8 * amax  # sqrt(0.8^2 + 0.6^2) = 1
        jt = 0.5 * jmax
        for _ in range(200):
            jn = math.hypot(jt + v ** 3 / r ** 2, 3.0 * v * at / r)
            if jn <= jmax:
                break
            v *= 0.9
            at *= 0.9
        return v, at, jt

    def _state(self, s, ds, dds):
        phi = self.sign * s / self.radius
        w = self.sign * ds / self.radius
        dw = self.sign * dds / self.radius
        return phi, w, dw

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.profile is None:
            return self.start.copy(), np.zeros(6), np.zeros(6)
        phi, w, dw = self._state(*self.profile.at(t))
        c, s = math.cos(phi), math.sin(phi)
        q = self.e1 * c + self.e2 * s
        tq = self.e2 * c - self.e1 * s  # dq/dphi
        pose = self.start.copy()
        pose[:3] = self.center + q
        vel = np.zeros(6)
        vel[:3] = w * tq
        acc = np.zeros(6)
        acc[:3] = dw * tq - w * w * q
        return pose, vel, acc

    def batch(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(t)
        pose = np.tile(self.start, (n, 1))
        vel, acc = np.zeros((n, 6)), np.zeros((n, 6))
        if self.profile is None:
            return pose, vel, acc
        phi, w, dw = self._state(*self.profile.batch(t))
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        q = self.e1 * c + self.e2 * s
        tq = self.e2 * c - self.e1 * s
        pose[:, :3] = self.center + q
        vel[:, :3] = w[:, None] * tq
        acc[:, :3] = dw[:, None] * tq - (w * w)[:, None] * q
        return pose, vel, acc


# ---------------------------------------------------------------------------- specs


def _target(current: np.ndarray, to: Sequence[float], where: str) -> np.ndarray:
    t = np.asarray(to, dtype=float).ravel()
    if t.shape not in ((3,), (6,)) or not np.isfinite(t).all():
        raise TrajectoryError(f"{where}: a target is 3 (position) or 6 (pose) finite numbers, "
                              f"got {list(np.ravel(to))}")
    out = np.array(current, dtype=float)
    out[: len(t)] = t
    return out


@dataclass(frozen=True)
class Move:
    """Point to point: a straight line, rest to rest, to ``to`` (3 or 6 numbers)."""

    to: tuple[float, ...]
    name: str = ""
    where: str = ""  #: where the spec comes from (file:line), for error messages


@dataclass(frozen=True)
class Line:
    """A polyline through ``through`` (each 3 or 6 numbers), at rest at each vertex."""

    through: tuple[tuple[float, ...], ...]
    name: str = ""
    where: str = ""


@dataclass(frozen=True)
class Circle:
    """An arc about ``center`` (3,) [m] in the plane normal to ``normal`` (3,) by
    ``angle_deg`` [deg] (right hand about ``normal``; 360 = full circle), from the current
    position, which must lie in that plane; orientation held."""

    center: tuple[float, float, float]
    normal: tuple[float, float, float]
    angle_deg: float
    name: str = ""
    where: str = ""


@dataclass(frozen=True)
class Dwell:
    """Stand still for ``duration_s`` [s]."""

    duration_s: float
    name: str = ""
    where: str = ""


@dataclass(frozen=True)
class Visits:
    """Visit ``poses`` (each 3 or 6 numbers) ``visits`` times: per visit a move, then a
    dwell of ``dwell_s`` [s]. ``order``: ``cycle`` (P1..Pn each round) or ``shuffle``
    (a permutation per round drawn from ``seed``)."""

    poses: tuple[tuple[float, ...], ...]
    visits: int = 1
    dwell_s: float = 3.0
    order: str = "cycle"
    seed: int = 0
    name: str = ""
    where: str = ""


SegmentSpec = Move | Line | Circle | Dwell | Visits


def visit_order(n: int, visits: int, order: str, seed: int = 0) -> list[tuple[int, int]]:
    """The visits as ``(round, pose index)`` in the order they happen.

    ``cycle``: 0..n-1 each round. ``shuffle``: a permutation per round from
    ``numpy.random.default_rng(seed)``; when a round would start with the pose the
    previous round ended on, its first two visits are swapped (n > 1)."""
    if order not in ORDERS:
        raise TrajectoryError(f"visits: order must be one of {', '.join(ORDERS)}, got {order!r}")
    rng = np.random.default_rng(seed)
    out: list[tuple[int, int]] = []
    for k in range(visits):
        perm = list(range(n)) if order == "cycle" else [int(i) for i in rng.permutation(n)]
        if order == "shuffle" and out and n > 1 and perm[0] == out[-1][1]:
            perm[0], perm[1] = perm[1], perm[0]
        out.extend((k, i) for i in perm)
    return out


# ---------------------------------------------------------------------------- trajectory


@dataclass(frozen=True)
class Segment:
    """One timed piece of a trajectory: from ``t0`` to ``t1`` [s] (trajectory time),
    ``kind`` of the spec it comes from (move, line, circle, dwell, visits), ``label``
    (``move`` or ``dwell``), ``start`` and ``target`` poses (6,), the spec's ``name``;
    for visits, ``pose_index`` (index of the target in the spec's list) and ``round``
    (0-based visit round), else -1; ``cycle``: which repetition of the whole segment list
    (0-based, see ``repeat`` of :class:`Trajectory`; -1 for the approach)."""

    t0: float
    t1: float
    kind: str
    label: str
    start: np.ndarray
    target: np.ndarray
    name: str = ""
    pose_index: int = -1
    round: int = -1
    cycle: int = 0
    motion: _Motion = field(default=None, repr=False, compare=False)

    @property
    def duration_s(self) -> float:
        return self.t1 - self.t0


class TrajectorySample(NamedTuple):
    """Samples of a trajectory: ``pose`` (6,)/(N,6) [m, rad]; ``velocity`` and
    ``acceleration`` (6,)/(N,6) (translational [m/s, m/s^2], Euler-angle rates [rad/s,
    rad/s^2]); ``label`` ``"move"``/``"dwell"`` (str, or an (N,) array); ``segment`` the
    index into :attr:`Trajectory.segments` (int or (N,) array)."""

    pose: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    label: str | np.ndarray
    segment: int | np.ndarray


class Trajectory:
    """A timed sequence of segments from ``start_pose`` (6,) under ``limits``.

    ``repeat``: run the specs that many times (ISO 9283 path tests repeat a path), after
    the first ``approach`` specs (not repeated: e.g. the move from the init pose to the
    path's start).
    ``segments``: the :class:`Segment` list (zero-length moves are dropped);
    ``duration_s``; :meth:`sample` for a time or an array of times [s]; before 0 the
    platform is at the start, after the end at the last target (with the last segment's
    label).
    """

    def __init__(self, specs: Sequence[SegmentSpec], start_pose: Sequence[float],
                 limits: MotionLimits | None = None, repeat: int = 1,
                 approach: int = 0) -> None:
        if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
            raise TrajectoryError(f"repeat must be an integer >= 1, got {repeat!r}")
        self.limits = limits if limits is not None else MotionLimits()
        p = np.asarray(start_pose, dtype=float).ravel()
        if p.shape != (6,) or not np.isfinite(p).all():
            raise TrajectoryError(f"start pose must be 6 finite numbers, got {p.tolist()}")
        self.start_pose = p.copy()
        segs: list[Segment] = []
        t = 0.0
        cur = p.copy()

        cycle = -1

        def add(motion: _Motion, kind: str, target: np.ndarray, name: str,
                pose_index: int = -1, rnd: int = -1) -> None:
            nonlocal t, cur
            if motion.duration <= 0.0:
                return
            segs.append(Segment(t, t + motion.duration, kind, motion.label, cur.copy(),
                                np.array(target, float), name, pose_index, rnd, cycle,
                                motion))
            t += motion.duration
            cur = np.array(target, dtype=float)

        specs = list(specs)
        plan = [(-1, k) for k in range(min(approach, len(specs)))]
        plan += [(c, k) for c in range(repeat) for k in range(min(approach, len(specs)),
                                                               len(specs))]
        for cyc, k in plan:
            cycle = cyc  # read by add()
            spec = specs[k]
            where = spec.where or f"segment #{k + 1} ({type(spec).__name__.lower()})"
            try:
                if isinstance(spec, Move):
                    tgt = _target(cur, spec.to, where)
                    add(_Linear(cur, tgt, self.limits), "move", tgt, spec.name)
                elif isinstance(spec, Line):
                    if len(spec.through) < 1:
                        raise TrajectoryError("line: needs at least one waypoint")
                    for w in spec.through:
                        tgt = _target(cur, w, where)
                        add(_Linear(cur, tgt, self.limits), "line", tgt, spec.name)
                elif isinstance(spec, Circle):
                    arc = _Arc(cur, spec.center, spec.normal, math.radians(spec.angle_deg),
                               self.limits)
                    add(arc, "circle", arc.end, spec.name)
                elif isinstance(spec, Dwell):
                    if not (spec.duration_s >= 0 and math.isfinite(spec.duration_s)):
                        raise TrajectoryError(f"dwell: duration_s must be >= 0, got "
                                              f"{spec.duration_s}")
                    add(_Hold(cur, spec.duration_s, DWELL), "dwell", cur, spec.name)
                elif isinstance(spec, Visits):
                    if not (spec.dwell_s >= 0 and math.isfinite(spec.dwell_s)):
                        raise TrajectoryError(f"visits: dwell_s must be >= 0, got "
                                              f"{spec.dwell_s}")
                    if spec.visits < 1 or not spec.poses:
                        raise TrajectoryError("visits: needs poses and visits >= 1")
                    for rnd, i in visit_order(len(spec.poses), spec.visits, spec.order,
                                              spec.seed):
                        tgt = _target(cur, spec.poses[i], where)
                        add(_Linear(cur, tgt, self.limits), "visits", tgt, spec.name, i, rnd)
                        add(_Hold(tgt, spec.dwell_s, DWELL), "visits", tgt, spec.name, i, rnd)
                else:
                    raise TrajectoryError(f"unknown segment spec {spec!r}")
            except TrajectoryError as exc:
                msg = str(exc)
                raise TrajectoryError(msg if msg.startswith(where) else f"{where}: {msg}") \
                    from None
        self.segments: tuple[Segment, ...] = tuple(segs)
        self.duration_s = t
        self.end_pose = cur
        self._t0 = [s.t0 for s in segs]
        self._t0_arr = np.array(self._t0)
        self._labels = np.array([s.label for s in segs] or [DWELL])

    def segment_index(self, t: float) -> int:
        """Index of the segment that holds time ``t`` [s] (the last one after the end;
        -1 for an empty trajectory)."""
        if not self.segments:
            return -1
        return max(0, bisect.bisect_right(self._t0, t) - 1)

    def sample(self, t: float | np.ndarray) -> TrajectorySample:
        """Pose, velocity, acceleration, label and segment at ``t`` [s] (a number), or at
        each of an array of times (then (N,6) arrays and (N,) labels)."""
        if np.ndim(t) == 0:
            t = float(t)
            if not self.segments:
                return TrajectorySample(self.start_pose.copy(), np.zeros(6), np.zeros(6),
                                        DWELL, -1)
            k = bisect.bisect_right(self._t0, t) - 1
            if k < 0:
                k, t = 0, self._t0[0]
            seg = self.segments[k]
            pose, vel, acc = seg.motion.at(t - seg.t0)
            return TrajectorySample(pose, vel, acc, seg.label, k)
        ts = np.asarray(t, dtype=float).ravel()
        n = len(ts)
        if not self.segments:
            return TrajectorySample(np.tile(self.start_pose, (n, 1)), np.zeros((n, 6)),
                                    np.zeros((n, 6)), np.full(n, DWELL), np.full(n, -1))
        idx = np.clip(np.searchsorted(self._t0_arr, ts, side="right") - 1, 0, None)
        pose, vel, acc = np.empty((n, 6)), np.empty((n, 6)), np.empty((n, 6))
        order = np.argsort(idx, kind="stable")
        bounds = np.searchsorted(idx[order], np.arange(len(self.segments) + 1))
        for k in range(len(self.segments)):
            sel = order[bounds[k]:bounds[k + 1]]
            if len(sel) == 0:
                continue
            seg = self.segments[k]
            p, v, a = seg.motion.batch(np.maximum(ts[sel] - seg.t0, 0.0))
            pose[sel], vel[sel], acc[sel] = p, v, a
        return TrajectorySample(pose, vel, acc, self._labels[idx], idx)

    def dwells(self) -> list[Segment]:
        """The segments where the platform stands at a target (label ``dwell``)."""
        return [s for s in self.segments if s.label == DWELL]

    def __repr__(self) -> str:
        return (f"Trajectory({len(self.segments)} segments, {self.duration_s:.3f} s, "
                f"limits {self.limits})")


__all__ = [
    "Circle", "Dwell", "Line", "MotionLimits", "Move", "SCurve", "Segment", "SegmentSpec",
    "Trajectory", "TrajectoryError", "TrajectorySample", "Visits", "euler_accels",
    "euler_rates", "visit_order",
]
