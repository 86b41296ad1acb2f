"""The load cells' gauge: what the readings cannot tell apart.

Every cable's tension scaled by a factor ``c``, with the platform's mass, every cable's
E*A and every mast's stiffness scaled by ``c`` and the load cells' gains by ``1/c``,
leaves every reading the same: the force balance holds ``c tau`` against ``c m g``; a
cable stretches by ``(c tau) L / (c EA)``; a mast bends by ``(c M) / (c k)``; a cell reads
``(g / c)(c tau) + offset``. Only the cables' own weight (their sag and its share of the
force balance), which the factor does not scale, breaks the symmetry, and weakly. So the
load cells' common gain, the mass, the cables' stretch and the masts' compliance trade
along one direction (:func:`scale_tensions`), and a fit that holds some of them at the
model's values picks one point of it: which one the data cannot say, only the number of
parameters each needs.

The selection uses it to start fits where one effect of the group is back at the model's
values and another carries its share (:func:`starts`): from a fit with the gains carrying
a mass change, the fit with the mass at the model's value and the cables' stretch in its
place, where a fit started at the old values would have to walk the whole way along a
direction its residuals barely see.
"""

from __future__ import annotations

import numpy as np

from bench.diagnosis.space import PER_CABLE_EA, ParamSpace
from controller.robot import Robot

#: candidates whose parameters move along the gauge (the load cells' gains pin it)
GAUGE_EFFECTS = frozenset({"load_cell_calibration", "platform_mass", "cable_elasticity",
                           PER_CABLE_EA, "mast_compliance"})
#: factors closer to 1 than this are no move
MIN_MOVE = 1e-3


def scale_tensions(robot: Robot, c: float) -> Robot:
    """The robot whose cables carry ``c`` times the tensions of ``robot`` behind the same
    readings (mass, E*A and mast stiffness times ``c``, load-cell gains over ``c``)."""
    return robot.replace(mass=robot.mass * c, ea=robot.ea * c, stiffness=robot.stiffness * c,
                         load_cell_gain=robot.load_cell_gain / c)


def factors(robot: Robot, model: Robot) -> dict[str, float]:
    """The factor :func:`scale_tensions` needs to bring each quantity of the gauge group in
    ``robot`` back to ``model``'s: the mass, the cables' E*A (geometric mean over the
    cables) and the load cells' common gain (geometric mean). Absent where the quantity is
    already the model's (within :data:`MIN_MOVE`) or not finite."""
    out = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        ea = np.log(model.ea / robot.ea)
        gain = np.log(robot.load_cell_gain / model.load_cell_gain)
    cands = {"platform_mass": model.mass / robot.mass,
             "cable_elasticity": float(np.exp(np.mean(ea[np.isfinite(ea)])))
             if np.isfinite(ea).any() else 1.0,
             "load_cell_calibration": float(np.exp(np.mean(gain[np.isfinite(gain)])))
             if np.isfinite(gain).any() else 1.0}
    for name, c in cands.items():
        if np.isfinite(c) and c > 0 and abs(np.log(c)) > MIN_MOVE:
            out[name] = float(c)
    return out


def common_gain_as_mass(robot: Robot, model: Robot) -> tuple[Robot, float] | None:
    """``robot`` with the load cells' common gain (geometric mean against ``model``'s)
    moved into the mass, the cables' E*A kept: (that robot, the common gain). In statics
    it reads the same (the cells read ``common`` x the tensions: the platform is
    ``common`` x heavier instead; measured = gain tension + offset, so the offsets stay);
    only the cables' stretch tells the two apart. None when the gains share no change."""
    common = factors(robot, model).get("load_cell_calibration")
    if common is None:
        return None
    return robot.replace(mass=robot.mass * common,
                         load_cell_gain=robot.load_cell_gain / common), common


def mass_as_common_gain(robot: Robot, model: Robot) -> tuple[Robot, float]:
    """``robot`` with its mass change moved into a gain shared by every load cell, the
    cables' E*A kept: (that robot, the shared gain); see :func:`common_gain_as_mass`."""
    ratio = robot.mass / model.mass
    return robot.replace(mass=model.mass, load_cell_gain=robot.load_cell_gain * ratio), ratio


def complete(effects: tuple[str, ...] | list[str], model: Robot) -> bool:
    """Whether a set of effects holds the whole gauge (the load cells, the mass, the cables'
    stretch, and the masts' compliance where the model's masts bend): then its fit cannot
    fix the tensions' scale, only the cables' weight can, and weakly."""
    e = set(effects)
    masts = "mast_compliance" in e or not np.isfinite(model.stiffness).any()
    return {"load_cell_calibration", "platform_mass"} <= e and masts and \
        bool(e & {"cable_elasticity", PER_CABLE_EA})


def pinned(space: ParamSpace, phi: np.ndarray, cov: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray] | None:
    """For a fit of a set that holds the whole gauge (:func:`complete`): ``phi`` moved
    along it until one load cell reads with the model's gain, and the mask that holds that
    gain there. The scale the data cannot fix is then fixed where most cells are right
    (fewest gains to report): at the cell with the most others whose gains agree with its
    own (:func:`agreeing_cell`, under the fit's covariance ``cov``), ties to the one that
    departs least from the cells' median (in ratio to the model's). The other ends of the
    gauge (the mass, or the stretch, at the model's) are sets without that effect, which
    the selection fits too. None without gains."""
    ix = [k for k, p in enumerate(space.params) if p.key.startswith("gain_")]
    if not ix:
        return None
    robot = space.robot(phi)
    with np.errstate(divide="ignore", invalid="ignore"):
        lr = np.log(robot.load_cell_gain / space.model.load_cell_gain)
    if not np.isfinite(lr).all():
        return None
    ratio_cov = None
    if cov is not None and len(ix) == len(lr):
        g = phi[ix]  # (a gain's parameter is its value: d log g = d g / g)
        ratio_cov = cov[np.ix_(ix, ix)] / np.outer(g, g)
    k = agreeing_cell(lr, ratio_cov)
    moved = space.phi_of(scale_tensions(robot, float(np.exp(lr[k]))))
    key = f"gain_{space.model.cable_ids[k]}"
    hold = np.array([p.key == key for p in space.params])
    moved[hold] = space.neutral[hold]
    return moved, hold


#: two cells' gains agree when their log-ratio differs by less than this many standard errors
AGREE_SIGMAS = 2.0


def agreeing_cell(log_gain: np.ndarray, cov: np.ndarray | None = None) -> int:
    """Index of the load cell whose gain (``log_gain``: log of the ratio to the model's)
    the most other cells share: the cells calibrated right all read with one gain along
    the gauge, which the data place wherever the scale falls; held at the model's, every
    one of them is then at the model's too. Two gains agree when their difference is within
    :data:`AGREE_SIGMAS` of its standard error under ``cov`` (the log-gains' covariance:
    the scale the data know poorly is common to every gain and cancels in the difference).
    Ties, and no finite covariance, to the cell nearest the gains' median (three cells
    right of eight, five off each its own way: their median may fall on a wrong one)."""
    lr = np.asarray(log_gain, dtype=float)
    med = np.abs(lr - np.median(lr))
    count = np.zeros(len(lr))
    if cov is not None and np.isfinite(cov).all():
        v = np.diag(cov)
        var = v[:, None] + v[None, :] - 2.0 * cov
        diff = np.abs(lr[:, None] - lr[None, :])
        count = np.sum(diff ** 2 <= AGREE_SIGMAS ** 2 * np.clip(var, 0.0, None), axis=1)
    best = np.flatnonzero(count == count.max())
    return int(best[np.argmin(med[best])])


def members(space: ParamSpace) -> np.ndarray:
    """Mask of the parameters of ``space`` that move along the gauge with the tensions'
    scale (gains, the mass, E*A)."""
    return np.array([p.key.startswith(("gain_", "ea")) or p.key == "mass"
                     for p in space.params], dtype=bool)


def moves(target: tuple[str, ...], start_effects: tuple[str, ...]) -> bool:
    """Whether going from a fit of ``start_effects`` to one of ``target`` changes which
    effects of the gauge group hold it, with the load cells among them (their gains pin
    the gauge: without them the tensions' scale is fixed by the readings)."""
    s, t = set(start_effects), set(target)
    if "load_cell_calibration" not in s | t:
        return False
    return bool((s ^ t) & GAUGE_EFFECTS) and bool(t & GAUGE_EFFECTS)


def starts(space: ParamSpace, start_space: ParamSpace, start_phi: np.ndarray
           ) -> list[np.ndarray]:
    """Starts for a fit of ``space`` from a fit of ``start_space`` at ``start_phi`` moved
    along the gauge: one per quantity of the group the start holds away from the model (a
    mass change, a common gain, a common stretch), moved back to the model's value with the
    others of ``space`` carrying it. Empty when the change of effects does not touch the
    group (:func:`moves`)."""
    if not moves(space.effects, start_space.effects):
        return []
    robot = start_space.robot(start_phi)
    out: list[np.ndarray] = []
    seen: list[float] = []
    for c in factors(robot, start_space.model).values():
        if any(abs(np.log(c / c0)) < MIN_MOVE for c0 in seen):
            continue
        seen.append(c)
        out.append(space.phi_of(scale_tensions(robot, c)))
    return out
