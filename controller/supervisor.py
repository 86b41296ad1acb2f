"""The supervisor: what the control loop does when something is wrong. Decisions only, no I/O.

Every cycle the loop hands the supervisor what it measured and what the controller
planned (:class:`Observation`); the supervisor answers with a :class:`Decision`: the
reaction to take now, which tensions to replace by the planned ones, and the events
(a condition starting or ending, naming the device) to log and record. The loop
carries the reaction out (bench/dryrun); nothing here touches a bus.

Reactions, by severity (the most severe active condition wins):

==================  =====================================================================
``none``            carry on
``log``             carry on; the condition is logged and recorded when it starts and
                    ends (only by an explicit override of the table below)
``substitute``      carry on; the planned tension (tension distribution) replaces a
                    load cell's reading in the mast update
``hold``            feed hold: the trajectory slows down to a stand still (time scaling,
                    within the motion limits) and the platform holds there; the loop
                    never sends a setpoint the controller found infeasible (it repeats
                    the last feasible one). Released when the condition ends.
``quick_stop``      every drive quick-stops (0x605A: quick-stop ramp, then Quick Stop
                    Active, holding position); latched until the loop is restarted
``disable``         the drives are disabled (brakes hold); latched
==================  =====================================================================

The conditions and their reactions (:data:`REACTIONS`):

====================  ==================================================  ============
condition             detected when                                       reaction
====================  ==================================================  ============
``slack``             a valid tension < ``slack_n`` for ``persist_s``        hold
                      (cable going slack)
``overload``          a valid tension > ``overload_n`` for ``persist_s``     quick_stop
``workspace``         the setpoint is infeasible (tension distribution,    hold
                      winch length limits)
``following_error``   |commanded - measured| length > the winch window    quick_stop
``drive_fault``       a drive is in Fault / Fault Reaction Active          quick_stop
``drive_lost``        heartbeat lost, TPDOs lost (no TPDO for the HAL's     quick_stop
                      deadline of SYNCs), node reset (boot-up), NMT state
                      other than OPERATIONAL, CAN link lost
``foreign_master``    a frame only a master sends, not sent by this one     quick_stop
                      (SDO request or RPDO to a drive, NMT, SYNC)
``drive_disabled``    a drive left Operation Enabled without being told    quick_stop
``bus``               the CAN bus refuses frames                           quick_stop
``loadcell``          a load cell is stale, timed out, faulted, NaN,       substitute
                      out of range or implausible
``loadcells_blind``   more than ``max_substituted`` cells substituted for   hold
                      longer than ``blind_s``
``overruns``          ``max_overruns`` consecutive cycle overruns           hold
====================  ==================================================  ============

A measured condition (slack, overload, workspace, following error, a drive that left
Operation Enabled) is confirmed after ``debounce`` consecutive cycles, and a tension
condition (slack, overload) only once it also lasted ``persist_s`` (load cells sample
slower than the loop and are noisy: a single low sample of a cable held near its minimum
tension is no slack cable); what a device reports itself (drive fault, lost drive, bus)
and a load cell to substitute are confirmed on the first cycle. So a reaction is decided
at most ``max(debounce - 1, ceil(persist_s / T))`` cycles after the first cycle that shows
its condition (T the cycle period), and the loop applies it in that cycle.
Latched reactions stay after their condition ends; ``hold`` and ``substitute`` end with
their conditions. An operator may change a condition's reaction (``Supervisor(limits,
reactions={"slack": Reaction.LOG})``, ``cdpr dry-run --react slack=log``), e.g. to record
a campaign with a model so wrong that cables go slack; the change is logged at start.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


class Reaction(enum.IntEnum):
    """What the loop does, by increasing severity."""

    NONE = 0
    LOG = 1
    SUBSTITUTE = 2
    HOLD = 3
    QUICK_STOP = 4
    DISABLE = 5

    @property
    def label(self) -> str:
        return self.name.lower()


#: condition kind -> reaction (the table of the module docstring)
REACTIONS: dict[str, Reaction] = {
    "slack": Reaction.HOLD,
    "overload": Reaction.QUICK_STOP,
    "workspace": Reaction.HOLD,
    "following_error": Reaction.QUICK_STOP,
    "drive_fault": Reaction.QUICK_STOP,
    "drive_lost": Reaction.QUICK_STOP,
    "foreign_master": Reaction.QUICK_STOP,
    "drive_disabled": Reaction.QUICK_STOP,
    "bus": Reaction.QUICK_STOP,
    "loadcell": Reaction.SUBSTITUTE,
    "loadcells_blind": Reaction.HOLD,
    "overruns": Reaction.HOLD,
}

#: slack: a valid tension below this fraction of the robot's minimum tension
SLACK_FRACTION = 0.2

#: reactions that stay after their condition ended
LATCHED = (Reaction.QUICK_STOP, Reaction.DISABLE)

#: tension conditions: confirmed only once they lasted ``persist_s``
_PERSIST = ("slack", "overload")

#: conditions confirmed on the first cycle that shows them
_IMMEDIATE = ("drive_fault", "drive_lost", "foreign_master", "bus", "loadcell")

#: HAL fault kinds of a drive that mean the drive is lost to the master
_LOST_KINDS = ("heartbeat_lost", "drive_lost", "boot_up", "nmt_state", "link_lost")


def _all(mask: np.ndarray) -> bool:
    """``mask.all()`` for a boolean array, without the reduction's overhead (every cycle)."""
    return np.count_nonzero(mask) == mask.size


@dataclass(frozen=True)
class SupervisorLimits:
    """Thresholds of the supervisor (arrays (n,) over the cables where per cable).

    ``slack_n``/``overload_n`` [N]: valid measured tensions below/above trip ``slack`` /
    ``overload``; ``plausible_n`` [N]: a reading beyond it (or negative beyond
    ``-plausible_n``) is a sensor error, never a tension (substituted, not an overload);
    ``following_error_m`` (n,) [m]: the winch's following-error window; ``debounce``
    [cycles]; ``persist_s`` [s] a tension condition must last; ``max_substituted`` cells
    at once before ``loadcells_blind`` after ``blind_s`` [s]; ``max_overruns`` consecutive
    overruns.
    """

    slack_n: float
    overload_n: float
    plausible_n: float
    following_error_m: np.ndarray
    debounce: int = 2
    persist_s: float = 0.1
    max_substituted: int = 2
    blind_s: float = 0.5
    max_overruns: int = 10

    @classmethod
    def for_robot(cls, tension_min: float, tension_max: float,
                  following_error_m: np.ndarray | float, **kw) -> SupervisorLimits:
        """Defaults from a robot's tension limits and the winches' following-error window:
        slack below a fifth of the minimum tension (a cable held at its minimum reads
        around it, within the cells' noise), overload above the maximum, implausible beyond
        ten times the maximum (or 1e5 N without one)."""
        tmax = float(tension_max)
        plausible = 10.0 * tmax if np.isfinite(tmax) else 1e5
        overload = tmax if np.isfinite(tmax) else plausible
        return cls(slack_n=SLACK_FRACTION * float(tension_min), overload_n=overload,
                   plausible_n=plausible,
                   following_error_m=np.asarray(following_error_m, float), **kw)


@dataclass(frozen=True)
class DeviceFault:
    """A fault the hardware reports (the HAL's HardwareFault as plain data)."""

    device: str  #: "drive", "loadcell" or "bus"
    address: int  #: CAN node id / Modbus unit id / 0
    cable: str
    kind: str
    code: int
    text: str


@dataclass(slots=True)
class Observation:
    """What one cycle saw. Arrays (n,) in cable order.

    ``tensions`` [N] as read (HAL-calibrated; NaN where not valid) and ``tension_ok``
    the HAL's verdict; ``lengths_meas`` [m] the drives' lengths; ``lengths_cmd`` [m] the
    setpoints the drives were following (last sent; None before the first);
    ``enabled`` drives in Operation Enabled; ``expect_enabled`` whether the loop has them
    enabled; ``faults`` active device faults; ``feasible``/``reason`` the controller's
    verdict on this cycle's setpoint; ``overrun`` whether the last cycle missed its
    deadline.
    """

    t_s: float
    tensions: np.ndarray
    tension_ok: np.ndarray
    lengths_meas: np.ndarray
    lengths_cmd: np.ndarray | None
    enabled: np.ndarray
    expect_enabled: bool = True
    faults: tuple[DeviceFault, ...] = ()
    feasible: bool = True
    reason: str = ""
    overrun: bool = False
    cables: tuple[str, ...] = ()
    node_ids: tuple[int, ...] = ()
    unit_ids: tuple[int, ...] = ()


@dataclass(frozen=True)
class SupervisorEvent:
    """A condition starting (``active``) or ending, with the reaction it calls for."""

    t_s: float
    device: str  #: "drive", "loadcell", "bus", "controller" or "platform"
    address: int  #: CAN node id, Modbus unit id, or 0
    cable: str  #: cable id or ""
    kind: str  #: condition kind (a key of :data:`REACTIONS`)
    code: int  #: device error code (EMCY, Modbus exception) or 0
    reaction: Reaction
    active: bool
    text: str

    def __str__(self) -> str:
        who = {"drive": f"CAN node {self.address}", "loadcell": f"Modbus unit {self.address}",
               "bus": "CAN bus"}.get(self.device, self.device)
        cab = f" (cable {self.cable})" if self.cable else ""
        state = "" if self.active else "ended: "
        code = f" 0x{self.code:04X}" if self.code else ""
        return (f"t={self.t_s:.3f} s {state}{self.kind}{code} at {who}{cab}: {self.text} "
                f"-> {self.reaction.label}")


@dataclass(frozen=True)
class Decision:
    """The supervisor's answer for one cycle."""

    reaction: Reaction  #: the most severe active reaction (latched ones included)
    substitute: np.ndarray  #: (n,) bool: use the planned tension for these cables
    events: tuple[SupervisorEvent, ...] = ()
    conditions: tuple[str, ...] = ()  #: active condition keys "kind:device:address"

    @property
    def hold(self) -> bool:
        return self.reaction >= Reaction.HOLD

    @property
    def stop(self) -> bool:
        return self.reaction >= Reaction.QUICK_STOP


@dataclass
class _Cond:
    kind: str
    device: str
    address: int
    cable: str
    code: int
    text: str
    count: int = 0  #: consecutive cycles seen
    since: float = 0.0  #: time first seen [s]
    confirmed: bool = False


@dataclass
class Supervisor:
    """Stateful (counters, latches) but deterministic: ``step(observation) -> Decision``."""

    limits: SupervisorLimits
    #: condition kind -> reaction, overriding :data:`REACTIONS` for these kinds
    reactions: dict[str, Reaction] = field(default_factory=dict)
    latched: Reaction = Reaction.NONE
    _conds: dict[str, _Cond] = field(default_factory=dict)
    _overruns: int = 0
    _blind_since: float | None = None
    _none: Decision | None = None  #: the "nothing wrong" decision, reused

    def __post_init__(self) -> None:
        self._tau_hi = min(self.limits.overload_n, self.limits.plausible_n)
        unknown = set(self.reactions) - set(REACTIONS)
        if unknown:
            raise ValueError(f"no supervisor condition {', '.join(sorted(unknown))} "
                             f"(known: {', '.join(REACTIONS)})")
        self._table = {**REACTIONS, **{k: Reaction(v) for k, v in self.reactions.items()}}

    def _cond_list(self, obs: Observation) -> list[_Cond]:
        """Every condition this observation shows (unconfirmed)."""
        lim = self.limits
        n = len(obs.tensions)
        cables = obs.cables or tuple(str(k) for k in range(n))
        nodes = obs.node_ids or tuple(range(1, n + 1))
        units = obs.unit_ids or tuple(range(1, n + 1))
        out: list[_Cond] = []
        tau = np.asarray(obs.tensions, float)
        finite = np.isfinite(tau)
        plausible = finite & (np.abs(np.where(finite, tau, 0.0)) <= lim.plausible_n)
        valid = np.asarray(obs.tension_ok, bool) & plausible
        # load cells: every invalid reading, named by its unit (the HAL's fault text if any)
        cell_text = {f.address: f for f in obs.faults if f.device == "loadcell"}
        for k in np.flatnonzero(~valid):
            f = cell_text.get(units[k])
            if f is not None:
                kind_text, code = f"{f.kind}: {f.text}", f.code
            elif not finite[k]:
                kind_text, code = "no valid value", 0
            else:
                kind_text, code = f"implausible value {tau[k]:.6g} N", 0
            out.append(_Cond("loadcell", "loadcell", int(units[k]), cables[k], code,
                             f"{kind_text}; planned tension used"))
        for k in np.flatnonzero(valid & (tau < lim.slack_n)):
            out.append(_Cond("slack", "loadcell", int(units[k]), cables[k], 0,
                             f"tension {tau[k]:.1f} N below {lim.slack_n:.1f} N"))
        for k in np.flatnonzero(valid & (tau > lim.overload_n)):
            out.append(_Cond("overload", "loadcell", int(units[k]), cables[k], 0,
                             f"tension {tau[k]:.1f} N above {lim.overload_n:.1f} N"))
        n_sub = int((~valid).sum())
        if n_sub > lim.max_substituted:
            if self._blind_since is None:
                self._blind_since = obs.t_s
            if obs.t_s - self._blind_since >= lim.blind_s:
                out.append(_Cond("loadcells_blind", "platform", 0, "", 0,
                                 f"{n_sub} of {n} load cells without a valid value for "
                                 f"{obs.t_s - self._blind_since:.2f} s"))
        else:
            self._blind_since = None
        if not obs.feasible:
            out.append(_Cond("workspace", "controller", 0, "", 0,
                             obs.reason or "setpoint infeasible"))
        if obs.lengths_cmd is not None:
            err = np.abs(np.asarray(obs.lengths_meas, float) - np.asarray(obs.lengths_cmd))
            en = np.asarray(obs.enabled, bool)
            window = np.broadcast_to(lim.following_error_m, (n,))
            bad = en & np.isfinite(err) & (err > window)
            for k in np.flatnonzero(bad):
                out.append(_Cond("following_error", "drive", int(nodes[k]), cables[k], 0x8611,
                                 f"length {obs.lengths_meas[k]:.4f} m, commanded "
                                 f"{obs.lengths_cmd[k]:.4f} m (error {1e3 * err[k]:.1f} mm > "
                                 f"{1e3 * window[k]:.1f} mm)"))
        faulted_nodes = set()
        for f in obs.faults:
            if f.kind == "foreign_master" and f.device in ("drive", "bus"):
                out.append(_Cond("foreign_master", f.device, f.address,
                                 f.cable if f.device == "drive" else "", f.code, f.text))
            elif f.device == "drive":
                kind = "drive_fault" if f.kind == "drive_fault" else (
                    "drive_lost" if f.kind in _LOST_KINDS else "drive_fault")
                faulted_nodes.add(f.address)
                out.append(_Cond(kind, "drive", f.address, f.cable, f.code, f.text))
            elif f.device == "bus":
                out.append(_Cond("bus", "bus", 0, "", f.code, f.text))
        if obs.expect_enabled:
            for k in np.flatnonzero(~np.asarray(obs.enabled, bool)):
                if int(nodes[k]) not in faulted_nodes:
                    out.append(_Cond("drive_disabled", "drive", int(nodes[k]), cables[k], 0,
                                     "left Operation Enabled"))
        self._overruns = self._overruns + 1 if obs.overrun else 0
        if self._overruns >= lim.max_overruns:
            out.append(_Cond("overruns", "controller", 0, "", 0,
                             f"{self._overruns} consecutive cycles missed their deadline"))
        return out

    def _healthy(self, obs: Observation) -> bool:
        """Nothing to look at this cycle and nothing pending (the common case, vectorised)."""
        if (self._conds or self.latched or obs.faults or obs.overrun or not obs.feasible):
            return False
        lim = self.limits
        tau = obs.tensions
        # NaN fails the comparisons: a missing value is not healthy
        if not (_all(obs.tension_ok) and _all((tau >= lim.slack_n) & (tau <= self._tau_hi))):
            return False
        if obs.expect_enabled and not _all(obs.enabled):
            return False
        if obs.lengths_cmd is not None and not _all(
                np.abs(obs.lengths_meas - obs.lengths_cmd) <= lim.following_error_m):
            return False
        return True

    def step(self, obs: Observation) -> Decision:
        """Decide for this cycle (see the module docstring)."""
        if self._healthy(obs):
            self._overruns = 0
            self._blind_since = None
            if self._none is None or len(self._none.substitute) != len(obs.tensions):
                none = np.zeros(len(obs.tensions), bool)
                none.setflags(write=False)
                self._none = Decision(Reaction.NONE, none)
            return self._none
        lim = self.limits
        seen = {f"{c.kind}:{c.device}:{c.address}": c for c in self._cond_list(obs)}
        events: list[SupervisorEvent] = []
        for key, old in list(self._conds.items()):
            if key not in seen:
                if old.confirmed:
                    events.append(SupervisorEvent(obs.t_s, old.device, old.address, old.cable,
                                                  old.kind, old.code, self._table[old.kind],
                                                  False, "condition ended"))
                del self._conds[key]
        for key, c in seen.items():
            cur = self._conds.get(key)
            if cur is None:
                cur = c
                self._conds[key] = cur
            else:
                cur.text, cur.code = c.text, c.code
            cur.count += 1
            # a device's own fault report is a fact, and a substitution acts at once:
            # no debounce for them
            need = 1 if c.kind in _IMMEDIATE else lim.debounce
            if cur.count == 1:
                cur.since = obs.t_s
            lasted = c.kind not in _PERSIST or obs.t_s - cur.since >= lim.persist_s - 1e-9
            if not cur.confirmed and cur.count >= need and lasted:
                cur.confirmed = True
                events.append(SupervisorEvent(obs.t_s, cur.device, cur.address, cur.cable,
                                              cur.kind, cur.code, self._table[cur.kind], True,
                                              cur.text))
        active = [c for c in self._conds.values() if c.confirmed]
        # load cells substitute at once (a bad value never reaches the statics)
        n = len(obs.tensions)
        cables = obs.cables or tuple(str(k) for k in range(n))
        sub_cables = {c.cable for c in seen.values() if c.kind == "loadcell"}
        substitute = np.array([cab in sub_cables for cab in cables], bool)
        reaction = max([self._table[c.kind] for c in active], default=Reaction.NONE)
        if substitute.any():
            reaction = max(reaction, Reaction.SUBSTITUTE)
        if reaction in LATCHED:
            self.latched = max(self.latched, reaction)
        reaction = max(reaction, self.latched)
        return Decision(reaction, substitute, tuple(events),
                        tuple(sorted(f"{c.kind}:{c.device}:{c.address}" for c in active)))

    def reset(self) -> None:
        """Forget latched reactions and conditions (after the operator cleared them)."""
        self.latched = Reaction.NONE
        self._conds.clear()
        self._overruns = 0
        self._blind_since = None


def parse_reactions(specs: list[str] | tuple[str, ...]) -> dict[str, Reaction]:
    """``["slack=log", ...]`` -> overrides; ValueError naming the bad item."""
    out: dict[str, Reaction] = {}
    for item in specs:
        kind, sep, name = item.partition("=")
        kind, name = kind.strip(), name.strip().upper()
        if not sep or kind not in REACTIONS or name not in Reaction.__members__:
            raise ValueError(f"{item!r}: expected CONDITION=REACTION with a condition among "
                             f"{', '.join(REACTIONS)} and a reaction among "
                             f"{', '.join(r.label for r in Reaction)}")
        out[kind] = Reaction[name]
    return out


__all__ = ["REACTIONS", "Decision", "DeviceFault", "Observation", "Reaction", "Supervisor",
           "SupervisorEvent", "SupervisorLimits", "parse_reactions"]
