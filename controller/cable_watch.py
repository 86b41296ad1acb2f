"""Every cable watched while anything moves outside the control loop (commissioning).

Pure decisions, no I/O. A cable robot hanging from its cables is never moved one axis
at a time without looking at all the others: paying out one winch slackens the opposite
cable and loads its neighbours. While a commissioning command moves a winch (or all of
them), every load cell is read each cycle and :class:`CableWatch` decides whether the
motion may go on.

The tension window is the supervisor's: a valid reading below ``slack_n`` is ``slack``,
above ``overload_n`` is ``overload`` (:class:`controller.supervisor.SupervisorLimits`,
``for_robot``: a fifth of the robot's minimum tension, its maximum tension). The same
thresholds classify readings in ``cdpr commission scan`` and ``monitor``
(:func:`classify_tensions`); they are written once, in the supervisor.

The decision (:func:`decide`) stops the motion when

- any reading is not valid (a load cell that does not answer leaves the cable unwatched);
- any cable is outside the window (``slack`` or ``overload``);
- any cable's tension, extrapolated over ``horizon_s`` at its current rate of change,
  would leave the window: the motion stops *before* the cable leaves it (the horizon
  covers the cells' sampling, the decision and the stopping ramp).

:class:`CableWatch` keeps the few past readings the rate needs (least squares over the
last ``rate_span_s``); it is deterministic.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from controller.supervisor import SupervisorLimits

OK = "ok"
SLACK = "slack"
OVERLOAD = "overload"
INVALID = "invalid"


@dataclass(frozen=True)
class TensionWindow:
    """Tensions a cable may carry [N]: ``low_n`` (slack below) to ``high_n`` (overload
    above)."""

    low_n: float
    high_n: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.low_n) and np.isfinite(self.high_n)
                and 0.0 <= self.low_n < self.high_n):
            raise ValueError(f"tension window [{self.low_n}, {self.high_n}] N: needs "
                             "0 <= low < high, both finite")

    @classmethod
    def from_limits(cls, limits: SupervisorLimits) -> TensionWindow:
        """The supervisor's slack and overload thresholds."""
        return cls(float(limits.slack_n), float(limits.overload_n))

    @classmethod
    def for_robot(cls, tension_min: float, tension_max: float) -> TensionWindow:
        """The window the supervisor uses for a robot's tension limits [N]."""
        return cls.from_limits(SupervisorLimits.for_robot(tension_min, tension_max, 0.0))

    def __str__(self) -> str:
        return f"[{self.low_n:g}, {self.high_n:g}] N"


def classify_tensions(tensions: np.ndarray, window: TensionWindow,
                      valid: np.ndarray | None = None) -> list[str]:
    """Per cable: ``ok``, ``slack`` (below the window), ``overload`` (above it) or
    ``invalid`` (NaN, or marked not valid by ``valid``). ``tensions`` (n,) [N]."""
    tau = np.asarray(tensions, float)
    ok = np.isfinite(tau) if valid is None else np.isfinite(tau) & np.asarray(valid, bool)
    out = []
    for k, x in enumerate(tau):
        if not ok[k]:
            out.append(INVALID)
        elif x < window.low_n:
            out.append(SLACK)
        elif x > window.high_n:
            out.append(OVERLOAD)
        else:
            out.append(OK)
    return out


@dataclass(frozen=True)
class Verdict:
    """The decision for one cycle: ``go`` or not, and why (naming the cable)."""

    go: bool
    reason: str  #: "" when go
    statuses: tuple[str, ...]  #: per cable, :func:`classify_tensions`
    predicted_n: np.ndarray  #: (n,) tensions extrapolated over the horizon [N]
    cable: str = ""  #: the cable that stopped it ("" when go)
    kind: str = ""  #: slack, overload, invalid, or predicted_slack / predicted_overload


def decide(tensions: np.ndarray, rates_n_s: np.ndarray, window: TensionWindow,
           horizon_s: float, cables: tuple[str, ...] | list[str],
           valid: np.ndarray | None = None) -> Verdict:
    """Continue or stop (see the module docstring). ``tensions`` (n,) [N], ``rates_n_s``
    (n,) [N/s] (NaN or 0 where unknown), ``horizon_s`` [s] >= 0."""
    tau = np.asarray(tensions, float)
    rate = np.nan_to_num(np.asarray(rates_n_s, float), nan=0.0, posinf=0.0, neginf=0.0)
    status = classify_tensions(tau, window, valid)
    pred = tau + rate * max(0.0, float(horizon_s))
    for k, s in enumerate(status):  # what is out now comes first
        if s == INVALID:
            return Verdict(False, f"cable {cables[k]}: no valid tension reading: the cable "
                           "is not watched", tuple(status), pred, cables[k], INVALID)
        if s != OK:
            edge = window.low_n if s == SLACK else window.high_n
            return Verdict(False, f"cable {cables[k]}: {s}, {tau[k]:.1f} N "
                           f"{'below' if s == SLACK else 'above'} {edge:g} N "
                           f"(window {window})", tuple(status), pred, cables[k], s)
    for k in range(len(tau)):
        if pred[k] < window.low_n or pred[k] > window.high_n:
            s = SLACK if pred[k] < window.low_n else OVERLOAD
            return Verdict(False, f"cable {cables[k]}: {tau[k]:.1f} N changing at "
                           f"{rate[k]:+.1f} N/s would be {s} within {horizon_s:.2f} s "
                           f"(window {window})", tuple(status), pred, cables[k],
                           "predicted_" + s)
    return Verdict(True, "", tuple(status), pred)


def tension_rates(t_s: np.ndarray, tensions: np.ndarray) -> np.ndarray:
    """Least-squares slope [N/s] per cable of ``tensions`` (m, n) over times ``t_s`` (m,);
    zeros with fewer than two distinct times."""
    t = np.asarray(t_s, float)
    tau = np.asarray(tensions, float)
    if len(t) < 2 or np.ptp(t) <= 0:
        return np.zeros(tau.shape[1] if tau.ndim == 2 else 0)
    dt = t - t.mean()
    return (dt @ (tau - tau.mean(axis=0))) / float(dt @ dt)


@dataclass
class CableWatch:
    """Watches every cable; ``step(t_s, tensions, valid) -> Verdict`` each cycle.

    ``horizon_s`` [s]: how far ahead a tension is extrapolated (reading age + decision +
    stopping time); ``rate_span_s`` [s]: the readings the rate is fitted over.
    """

    window: TensionWindow
    cables: tuple[str, ...]
    horizon_s: float = 0.25
    rate_span_s: float = 0.2
    _hist: deque = field(default_factory=deque)

    def step(self, t_s: float, tensions: np.ndarray,
             valid: np.ndarray | None = None) -> Verdict:
        """Decide for the readings at time ``t_s`` [s] (tensions (n,) [N])."""
        tau = np.asarray(tensions, float)
        if not self._hist or self._hist[-1][0] < t_s:
            self._hist.append((float(t_s), tau.copy()))
        while self._hist and self._hist[0][0] < t_s - self.rate_span_s:
            self._hist.popleft()
        ts = np.array([h[0] for h in self._hist])
        taus = np.array([h[1] for h in self._hist])
        good = np.all(np.isfinite(taus), axis=0) if len(taus) else np.zeros(len(tau), bool)
        rates = np.where(good, tension_rates(ts, np.nan_to_num(taus)), 0.0) if len(ts) > 1 \
            else np.zeros(len(tau))
        return decide(tau, rates, self.window, self.horizon_s, self.cables, valid)

    def reset(self) -> None:
        """Forget the past readings (after a stand-still)."""
        self._hist.clear()


__all__ = ["INVALID", "OK", "OVERLOAD", "SLACK", "CableWatch", "TensionWindow", "Verdict",
           "classify_tensions", "decide", "tension_rates"]
