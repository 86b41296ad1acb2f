"""Feed hold: slowing a trajectory down to a stand-still and back, by time scaling.

The loop advances the trajectory's time by ``rate * dt`` instead of ``dt``. A hold
brings ``rate`` from 1 to 0, a release from 0 back to 1, along a smoothstep
``rate = 3 phi^2 - 2 phi^3`` of a phase ``phi`` that moves by ``dt / ramp_s`` per
cycle. Along the path the speed is ``rate * v(s)`` and the acceleration
``rate^2 a(s) + rate' v(s)``, with ``|rate'| <= 1.5 / ramp_s``: with
``ramp_s = 1.5 v_max / a_max`` (:func:`ramp_time`) the extra acceleration stays
within ``a_max`` and the jerk stays finite (the rate's derivative is continuous).
Pure, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass


def ramp_time(max_speed_m_s: float, max_accel_m_s2: float) -> float:
    """Ramp duration [s] that keeps the extra acceleration of a hold within ``max_accel``."""
    return 1.5 * max_speed_m_s / max_accel_m_s2


@dataclass
class FeedRate:
    """Time scaling state: ``rate`` in [0, 1]; ``ramp_s`` [s] from 1 to 0 or back."""

    ramp_s: float
    phase: float = 1.0

    @property
    def rate(self) -> float:
        p = self.phase
        return p * p * (3.0 - 2.0 * p)

    @property
    def stopped(self) -> bool:
        return self.phase <= 0.0

    def advance(self, dt_s: float, hold: bool) -> float:
        """Move the ramp by one cycle of ``dt_s`` [s] toward stand-still (``hold``) or full
        speed; the trajectory time increment [s] for this cycle (trapezoidal rule)."""
        before = self.rate
        step = dt_s / self.ramp_s if self.ramp_s > 0 else 1.0
        self.phase = max(0.0, self.phase - step) if hold else min(1.0, self.phase + step)
        return 0.5 * (before + self.rate) * dt_s
