"""Effect parameters as a vector for fitting.

Each vocabulary effect becomes a group of fit parameters with physical bounds
and a scale. Compliance is fitted as c = 1/k and elasticity as e = 1/EA, so
that "no effect" (rigid mast, inextensible cable) is c = 0, e = 0 and the
neutral point is the model's own value. :meth:`ParamSpace.robot` builds the
hypothesis robot through :func:`controller.effects.apply_effects`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.effects import TRACKER_FRAME_KEYS, apply_effects
from controller.robot import Robot

#: fit-parameter scale per effect (typical size of a meaningful change), for steps and scaling
SCALES = {
    "exit_point_offset": 1e-3, "mast_compliance": 1e-6, "cable_elasticity": 1e-7,
    "cable_length_offset": 1e-4, "drum_scale": 1e-4, "load_cell_gain": 1e-3,
    "load_cell_offset": 0.1, "mass": 0.1, "com": 1e-3, "pulley_kinematics": 1e-3,
    "cable_sag": 1e-3, "tracker_frame": 1e-3, "tracker_rotation": 1e-4, "tracker_latency": 1e-3,
}

#: the nuisance of a recording without load cells at initialisation: the internal forces
#: [N] by which the tensions there differ from the distribution's (``Robot.init_internal``;
#: in the fits of every set once the report finds them needed, never reported as an effect)
PRETENSION = "init_pretension"
#: [N] (its finite-difference step, 0.3 N, stretches a cable about as a length offset's does)
SCALES[PRETENSION] = 30.0

#: a stiffness or EA known only to this relative standard error is called undetermined
UNDETERMINED_REL = 0.4
#: ... and so is one fitted this many times stiffer than its effect's typical scale (the
#: fit ran to the rigid bound: 1e9 N m/rad for a mast, 1e10 N for a cable's EA)
RIGID_FACTOR = 1e3
#: a candidate of the selection that the report names ``cable_elasticity``: each cable's
#: own E*A (``ea_{ij}``) instead of one for all
PER_CABLE_EA = "cable_elasticity_each"


def report_name(candidate: str) -> str:
    """The vocabulary's name of a selection candidate."""
    return "cable_elasticity" if candidate == PER_CABLE_EA else candidate


#: what each effect explains, for the report
EXPLAINS = {
    "exit_point_offset": "exit points sit elsewhere than the model says (supporting ropes "
                         "settled, masts tilted or a survey error): constant offsets",
    "mast_compliance": "exit points move with the tension on their mast: the masts bend "
                       "about their bases (eq. 4-8)",
    "cable_elasticity": "cables stretch in proportion to tension times length",
    "cable_length_offset": "a cable's length reading is off by a constant (slip on the drum, "
                           "encoder jump)",
    "drum_scale": "length changes are read with a wrong scale (drum radius, winding)",
    "load_cell_calibration": "tension sensors read with a gain or offset error",
    "platform_mass": "the platform's mass or centre of mass differs from the model",
    "pulley_kinematics": "cables wrap on pulleys of finite radius that swivel towards the "
                         "platform",
    "cable_sag": "cables sag under their own weight",
    "tracker_frame": "the laser tracker's frame is registered to F_b with a small rotation and "
                     "translation off: every measured pose (and exit point) is seen through "
                     "that rigid motion",
    "tracker_latency": "the tracker's poses lag the drives' readings by a constant time: "
                       "while the platform moves, each pose is where it was that long before",
}


@dataclass(frozen=True)
class Param:
    """One fit parameter: report ``key``, ``effect``, ``kind`` (value, inverse), fit-space
    ``neutral``, ``scale``, bounds ``lo``/``hi``."""

    key: str
    effect: str
    kind: str
    neutral: float
    scale: float
    lo: float
    hi: float

    def to_value(self, phi: float) -> float:
        """Fit-space value -> the conventions' parameter value (k = 1/c, ea = 1/e)."""
        if self.kind == "inverse":
            return float("inf") if phi <= 0 else 1.0 / phi
        return phi

    def from_value(self, v: float) -> float:
        if self.kind == "inverse":
            return 0.0 if not np.isfinite(v) or v <= 0 else 1.0 / v
        return v


def param_value(robot: Robot, model: Robot, p: Param) -> float:
    """The value of fit parameter ``p`` in ``robot``, in the conventions' units (exit
    offsets relative to ``model``; a common ``ea`` is the cables' mean)."""
    k = p.key
    if p.effect == "tracker_frame":
        return float(robot.tracker_frame[TRACKER_FRAME_KEYS.index(k)])
    if p.effect == "tracker_latency":
        return float(robot.tracker_latency)
    c = lambda pre: robot.cable_ids.index(k[len(pre):])  # noqa: E731
    if k.startswith(("dx_", "dy_", "dz_")):
        i = c(k[:3])
        return float(robot.exits[i, "xyz".index(k[1])] - model.exits[i, "xyz".index(k[1])])
    if k.startswith("k") and k[2:3] == "_":
        return float(robot.stiffness[robot.mast_ids.index(k[3:]), "xyz".index(k[1])])
    if k == "ea":
        return float(np.mean(robot.ea))
    per_cable = {"ea_": robot.ea, "dl_": robot.length_offset, "s_": robot.drum_scale,
                 "gain_": robot.load_cell_gain, "offset_": robot.load_cell_offset,
                 "r_": robot.pulley_radius}
    for pre, arr in per_cable.items():
        if k.startswith(pre):
            return float(arr[c(pre)])
    if k == "mass":
        return float(robot.mass)
    if k.startswith("com_"):
        return float(robot.com["xyz".index(k[-1])])
    if k == "rho":
        return float(robot.rho)
    if p.effect == PRETENSION and robot.init_internal is not None:
        return float(robot.init_internal[int(k.rsplit("_", 1)[1]) - 1])
    return float(p.to_value(p.neutral))


def undetermined(p: Param, phi: float, se: float) -> bool:
    """Whether the data cannot fix parameter ``p`` at fit-space value ``phi`` with standard
    error ``se`` (the report lists it as undetermined, gives no value)."""
    if not math.isfinite(se):
        return True
    # at or near a bound of the fit (within 1 % of its range; a compliance within a factor
    # two of the softest allowed) the fit was stopped by the bound and its standard error
    # says nothing; a lower bound of zero is physical (no pulley, no sag; a compliance of
    # zero is the rigid bound below)
    margin = 0.5 * p.hi if p.kind == "inverse" else 0.01 * (p.hi - p.lo)
    if phi >= p.hi - margin or (p.lo != 0.0 and phi <= p.lo + margin):
        return True
    if p.kind == "inverse":  # compliance or 1/EA: cannot tell it from rigid, or too wide
        # at the rigid bound (a stiffness RIGID_FACTOR times past the effect's scale) the
        # standard error of a clipped fit says nothing: a number there would be a guess
        return (phi - 2.0 * se <= 0.0 or se > UNDETERMINED_REL * phi
                or phi * RIGID_FACTOR <= p.scale)
    if p.effect == "tracker_frame":  # 1 mrad of rotation, 5 mm of translation
        return se > max(1e-3 if p.key.startswith("r") else 5e-3, 0.5 * abs(phi - p.neutral))
    limits = {"exit_point_offset": 5e-3, "cable_length_offset": 1e-3, "drum_scale": 5e-3,
              "pulley_kinematics": 0.03, "cable_sag": 0.05, "tracker_latency": 0.01}
    if p.effect in limits:
        return se > max(limits[p.effect], 0.5 * abs(phi - p.neutral))
    if p.key.startswith("gain_"):
        return se > 0.05
    if p.key.startswith("offset_"):
        return se > 5.0
    if p.key == "mass":
        return se > max(2.0, 0.05 * p.neutral)  # 5 % of the platform (a 91 kg one: 4.5 kg)
    if p.key.startswith("com_"):
        return se > 0.05
    return se > 100 * SCALES.get(p.effect, 1.0)


def effect_fit_params(effect: str, model: Robot) -> list[Param]:
    """The fit parameters of one effect for ``model``."""
    cids, mids = model.cable_ids, model.mast_ids
    out: list[Param] = []
    if effect == "exit_point_offset":
        for cid in cids:
            for ax in "xyz":
                out.append(Param(f"d{ax}_{cid}", effect, "offset", 0.0,
                                 SCALES[effect], -0.5, 0.5))
    elif effect == "mast_compliance":
        for i, mid in enumerate(mids):
            for a, ax in enumerate("xyz"):
                k = model.stiffness[i, a]
                out.append(Param(f"k{ax}_{mid}", effect, "inverse",
                                 0.0 if not np.isfinite(k) else 1.0 / k, SCALES[effect],
                                 0.0, 1e-3))
    elif effect == "cable_elasticity":
        ea = model.ea[np.isfinite(model.ea)]
        e0 = 0.0 if not len(ea) else 1.0 / float(np.mean(ea))
        out.append(Param("ea", effect, "inverse", e0, SCALES[effect], 0.0, 1e-3))
    elif effect == PER_CABLE_EA:  # cable_elasticity with a stiffness per cable
        for k, cid in enumerate(cids):
            e0 = 0.0 if not np.isfinite(model.ea[k]) else 1.0 / float(model.ea[k])
            out.append(Param(f"ea_{cid}", "cable_elasticity", "inverse", e0,
                             SCALES["cable_elasticity"], 0.0, 1e-3))
    elif effect == "cable_length_offset":
        out = [Param(f"dl_{c}", effect, "offset", 0.0, SCALES[effect], -1.0, 1.0) for c in cids]
    elif effect == "drum_scale":
        out = [Param(f"s_{c}", effect, "value", float(model.drum_scale[k]), SCALES[effect],
                     0.8, 1.25) for k, c in enumerate(cids)]
    elif effect == "load_cell_calibration":
        for k, c in enumerate(cids):
            out.append(Param(f"gain_{c}", effect, "value", float(model.load_cell_gain[k]),
                             SCALES["load_cell_gain"], 0.5, 2.0))
            out.append(Param(f"offset_{c}", effect, "value", float(model.load_cell_offset[k]),
                             SCALES["load_cell_offset"], -500.0, 500.0))
    elif effect == "platform_mass":
        out.append(Param("mass", effect, "value", model.mass, SCALES["mass"], 0.1,
                         10 * model.mass + 100))
        for a, ax in enumerate("xyz"):
            out.append(Param(f"com_{ax}", effect, "value", float(model.com[a]), SCALES["com"],
                             -2.0, 2.0))
    elif effect == "pulley_kinematics":
        out = [Param(f"r_{c}", effect, "value", float(model.pulley_radius[k]),
                     SCALES[effect], 0.0, 1.0) for k, c in enumerate(cids)]
    elif effect == "cable_sag":
        out = [Param("rho", effect, "value", model.rho, SCALES[effect], 0.0, 5.0)]
    elif effect == "tracker_frame":
        out = [Param(k, effect, "value", float(model.tracker_frame[i]),
                     SCALES["tracker_rotation"] if i < 3 else SCALES[effect],
                     -0.1 if i < 3 else -1.0, 0.1 if i < 3 else 1.0)
               for i, k in enumerate(TRACKER_FRAME_KEYS)]
    elif effect == "tracker_latency":
        out = [Param("dt", effect, "value", float(model.tracker_latency), SCALES[effect],
                     -1.0, 1.0)]
    else:
        raise KeyError(f"unknown effect {effect!r}")
    return out


class ParamSpace:
    """Fit parameters of a set of effects on a model robot."""

    def __init__(self, model: Robot, effects: list[str] | tuple[str, ...]) -> None:
        self.model = model
        self.effects = tuple(effects)
        self.params: list[Param] = []
        for e in self.effects:
            self.params += effect_fit_params(e, model)
        if model.init_internal is not None:  # a nuisance of every fit, never reported
            self.params += [Param(f"{PRETENSION}_{k + 1}", PRETENSION, "value", float(v),
                                  SCALES[PRETENSION], -1e6, 1e6)
                            for k, v in enumerate(model.init_internal)]
        self.neutral = np.array([p.neutral for p in self.params])
        self.scale = np.array([p.scale for p in self.params])
        self.lo = np.array([p.lo for p in self.params])
        self.hi = np.array([p.hi for p in self.params])

    def __len__(self) -> int:
        return len(self.params)

    def values(self, phi: np.ndarray) -> dict[str, dict[str, float]]:
        """{effect: {key: value in the conventions' units}} (the vocabulary's effect names).

        Load-cell gains are not normalised: with the model's mass the force balance fixes
        their common mode (any number of cells may be off). Only when the mass is fitted
        too are a common gain and the mass confounded in the statics; then the cables'
        stretch alone separates them, and the fit holds what it cannot fix."""
        out: dict[str, dict[str, float]] = {}
        vals = np.array([p.to_value(float(v)) for p, v in zip(self.params, phi, strict=True)])
        for p, v in zip(self.params, vals, strict=True):
            if p.effect != PRETENSION:
                out.setdefault(p.effect, {})[p.key] = float(v)
        return out

    def canonical(self, phi: np.ndarray) -> np.ndarray:
        """Fit-space values as reported (no gauge: the identity)."""
        return np.array(phi, dtype=float, copy=True)

    def robot(self, phi: np.ndarray) -> Robot:
        """The hypothesis robot for fit-space values ``phi``."""
        robot = apply_effects(self.model, self.values(phi))
        nuisance = [k for k, p in enumerate(self.params) if p.effect == PRETENSION]
        return robot.replace(init_internal=np.asarray(phi, float)[nuisance]) if nuisance \
            else robot

    def phi_of(self, robot: Robot) -> np.ndarray:
        """Fit-space values that describe ``robot`` (the inverse of :meth:`robot` for what
        the space's effects hold), within the bounds."""
        phi = np.array([p.from_value(param_value(robot, self.model, p)) for p in self.params])
        return np.clip(phi, self.lo, self.hi)

    def indices(self, effect: str) -> np.ndarray:
        """Parameters of a candidate (``effect`` as in :attr:`effects`)."""
        name = report_name(effect)
        own = [k for k, p in enumerate(self.params) if p.effect == name]
        if name != effect or effect == "cable_elasticity":
            # the two elasticity candidates share the report name: tell them by their keys
            each = effect == PER_CABLE_EA
            own = [k for k in own if self.params[k].key.startswith("ea_") == each]
        return np.array(own, dtype=int)
