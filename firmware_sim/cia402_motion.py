"""Motion model of one simulated winch drive, in drive units (counts, counts/s, counts/s^2).

Two pieces, both pure and scalar (one drive):

- :func:`profile_step` moves a *demand* position toward a goal with trapezoidal
  velocity limits (profile position moves, halt and stop ramps).
- :class:`Axis` is the motor behind the position loop: it follows the demand as a
  first-order lag (time constant ``lag_s``) whose velocity and acceleration saturate
  at the drive limits, and it never overshoots a standing demand. A held brake
  freezes it.

The drum/gear/encoder relation to metres of cable is in :mod:`controller.winch`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def profile_step(
    dem: float,
    dem_v: float,
    goal: float | None,
    v_max: float,
    acc: float,
    dec: float,
    h: float,
) -> tuple[float, float]:
    """One step ``h`` [s] of a trapezoidal profile: new (demand [counts], velocity [counts/s]).

    ``goal=None`` decelerates to standstill at ``dec``. Otherwise the demand moves toward
    ``goal`` no faster than ``v_max``, speeding up at ``acc`` and braking at ``dec`` so that
    it stops on the goal.
    """
    if goal is None:
        dv = dec * h
        v = 0.0 if abs(dem_v) <= dv else dem_v - math.copysign(dv, dem_v)
        return dem + 0.5 * (dem_v + v) * h, v
    d = goal - dem
    if d == 0.0 and abs(dem_v) <= dec * h:
        return goal, 0.0
    v_stop = math.copysign(math.sqrt(2.0 * dec * abs(d)), d)
    v_des = _clamp(v_stop, -v_max, v_max)
    rate = acc if abs(v_des) > abs(dem_v) and v_des * dem_v >= 0 else dec
    v = _clamp(v_des, dem_v - rate * h, dem_v + rate * h)
    step = 0.5 * (dem_v + v) * h
    if (d > 0 and step >= d) or (d < 0 and step <= d):
        if abs(v) <= dec * h * 2.0:
            return goal, 0.0
    return dem + step, v


@dataclass
class Axis:
    """Actual position [counts] and velocity [counts/s] of the motor, following a demand."""

    pos: float = 0.0
    vel: float = 0.0

    def follow(
        self, dem: float, dem_v: float, h: float, v_max: float, a_max: float, lag_s: float
    ) -> None:
        """Advance ``h`` [s] toward the demand ``dem`` [counts] moving at ``dem_v`` [counts/s].

        First-order lag of time constant ``lag_s`` [s]; the velocity saturates at ``v_max``
        and changes by at most ``a_max`` [counts/s^2]; the motor approaches the demand no
        faster (relative to it) than it can still brake at ``a_max``, so it does not overshoot.
        """
        err = dem - self.pos
        if lag_s > 0.0:
            v_des = err * (1.0 - math.exp(-h / lag_s)) / h
        else:
            v_des = err / h
        v_rel = math.sqrt(2.0 * a_max * abs(err))
        v_des = _clamp(v_des, dem_v - v_rel, dem_v + v_rel) if err else dem_v
        v_des = _clamp(v_des, -v_max, v_max)
        v = _clamp(v_des, self.vel - a_max * h, self.vel + a_max * h)
        self.pos += v * h
        self.vel = v

    def hold(self) -> None:
        """Brake engaged: the motor does not turn."""
        self.vel = 0.0
