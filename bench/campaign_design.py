"""``cdpr campaign design``: the poses that settle what a diagnosis left open.

From a ``cdpr-diagnosis/1`` report: the **preferred** hypothesis is the recording's model with
the report's effects applied (:func:`bench.diagnosis.report.named_robot`); each effect's
**alternatives** give a rival hypothesis (that effect replaced by the alternative). At N_c
tension-feasible candidate poses in the workspace (:func:`bench.evaluate.feasible_poses`, the
site's box and tension window when given), the data the preferred hypothesis would give are
made (its tension distribution, the lengths that hold it, read through the initialisation
convention), and the diagnosis's own residual model
(:class:`bench.diagnosis.residuals.ResidualModel`, :class:`bench.diagnosis.space.ParamSpace`:
one physics) gives, per candidate:

- the whitened Jacobian of the preferred hypothesis' residuals by its parameters (scaled to
  their typical size): the Fisher information ``J_i^T J_i``;
- for each alternative, fitted to those data over every candidate
  (:func:`bench.diagnosis.fit.fit_effects`), its whitened residuals and Jacobian there.

:func:`controller.design.choose` picks N of them (D-optimal for the parameters, T-optimal for
the alternatives; :func:`match_reference` the poses that come closest to a reference
campaign's standard errors; :func:`identifiability` what they fix with only some cables
measured); :func:`path_document` writes them as a ``cdpr-path/1`` file with a
``visits`` segment, which ``cdpr dry-run --path`` follows and ``cdpr campaign --path`` visits.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.diagnosis.fit import fd_jacobian, fit_effects
from bench.diagnosis.residuals import BLOCKS, ResidualModel
from bench.diagnosis.samples import Samples
from bench.diagnosis.space import PER_CABLE_EA, ParamSpace, report_name, undetermined
from controller import design
from controller.cycle import reference_lengths
from controller.robot import Robot
from controller.statics import init_unstretched, pose_statics, true_tensions

#: the chi-square difference that separates two explanations (the selection's BIC tie is 10;
#: the expected difference must clear it with room for the noise's spread)
TARGET = 25.0
#: candidate poses drawn
CANDIDATES = 150
#: effects a design fixes when the report names none (what commissioning identifies)
DEFAULT_EFFECTS = ("exit_point_offset", "mast_compliance")
#: candidates' roll, pitch and yaw are drawn within +- this [deg]
RPY_DEG = 3.0
#: share of the frame's span in x and y left out of the candidates' box on each side
BOX_MARGIN = 0.03
#: the candidates' heights, as shares of the frame's height (the ground to the highest exit
#: point): the whole height the tension distribution may hold (high poses load the cables
#: most: their stretch is what tells a load cell's gain from the platform's mass)
BOX_HEIGHTS = (0.05, 0.9)
#: rows averaged per dwell sample of the designed campaign (3 s at 2 Hz)
ROWS_PER_DWELL = 6


class DesignError(ValueError):
    """A report or option the design cannot use (the message names the file and field)."""


@dataclass
class Context:
    """What the design needs: ``model`` the controller's model; ``init_pose`` (6,) [m, rad];
    ``init_readings`` (n,) load-cell readings at initialisation [N] (None: the model's
    distribution); ``tracker`` / ``tensions`` whether the campaign measures poses / tensions;
    ``noise`` per block (length [m], force [N], moment [N m], exit [m]) of one visit;
    ``box`` (lo, hi) positions [m] or None; ``tension_window`` [N] or None."""

    model: Robot
    init_pose: np.ndarray
    init_readings: np.ndarray | None
    tracker: bool = True
    tensions: bool = True
    noise: dict[str, float] = field(default_factory=dict)
    box: tuple[np.ndarray, np.ndarray] | None = None
    tension_window: tuple[float, float] | None = None


@dataclass(frozen=True)
class Rival:
    """An alternative explanation: ``label``; ``effects`` its candidate set; ``names`` the
    (preferred, alternative) effect names; ``start`` the robot it starts from (None: fitted
    from the model's values); ``held`` parameter keys kept where ``start`` puts them, and
    ``common_gain``: the load cells' common gain (geometric mean) kept too (the gauge's
    alternatives of :func:`bench.diagnosis.report._common_gain_alternative`: a mass in place
    of a common gain, or the reverse)."""

    label: str
    effects: tuple[str, ...]
    names: tuple[str, str]
    start: Robot | None = None
    held: tuple[str, ...] = ()
    common_gain: bool = False


@dataclass
class Hypotheses:
    """``effects`` the preferred set (selection candidates); ``robot`` the preferred
    hypothesis; ``alternatives`` its rivals; ``undetermined`` parameter keys the report
    could not fix; ``default`` whether the report named no effect (the design fixes
    :data:`DEFAULT_EFFECTS`)."""

    effects: tuple[str, ...]
    robot: Robot
    alternatives: list[Rival]
    undetermined: list[str]
    default: bool = False


def read_report(path: str | Path) -> dict[str, Any]:
    """A ``cdpr-diagnosis/1`` report (a JSON object with that ``format``)."""
    p = Path(path)
    try:
        rep = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise DesignError(f"{p}: not a readable JSON report: {e}") from e
    if not isinstance(rep, dict) or rep.get("format") != "cdpr-diagnosis/1":
        raise DesignError(f"{p}: format: must be \"cdpr-diagnosis/1\"")
    if not isinstance(rep.get("effects"), list):
        raise DesignError(f"{p}: effects: must be a list")
    return rep


def _candidate(entry: dict[str, Any]) -> str:
    """The selection candidate of a report entry (per-cable EA keys: :data:`PER_CABLE_EA`)."""
    if entry["name"] == "cable_elasticity" and any(k.startswith("ea_") for k in
                                                   entry.get("params", {})):
        return PER_CABLE_EA
    return str(entry["name"])


def hypotheses(report: dict[str, Any], model: Robot) -> Hypotheses:
    """The preferred hypothesis and its rivals from ``report`` on ``model``."""
    from bench.diagnosis import gauge
    from bench.diagnosis.report import named_robot

    entries = report["effects"]
    effects = tuple(_candidate(e) for e in entries)
    if not effects:
        return Hypotheses(DEFAULT_EFFECTS, model, [], [], default=True)
    robot = named_robot(model, entries)
    alts: list[Rival] = []
    for e, cand in zip(entries, effects, strict=True):
        for a in e.get("alternatives", []):
            label = f"{a['name']} instead of {e['name']}"
            pair = (e["name"], a["name"])
            if "note" in a:  # the load cells' gauge: one parameter for one
                both = tuple(dict.fromkeys(effects + ("load_cell_calibration",
                                                      "platform_mass")))
                if e["name"] == "platform_mass":
                    start, _ = gauge.mass_as_common_gain(robot, model)
                    alts.append(Rival(label, both, pair, start, ("mass",)))
                else:
                    moved = gauge.common_gain_as_mass(robot, model)
                    if moved is not None:
                        alts.append(Rival(label, both, pair, moved[0], common_gain=True))
                continue
            rival = tuple(c for c in effects if c != cand)
            if a["name"] not in rival:
                rival = rival + (a["name"],)
            alts.append(Rival(label, rival, pair))
    undet = [k for e in entries for k in e.get("undetermined", [])]
    return Hypotheses(effects, robot, alts, undet)


def synthetic_samples(H: Robot, ctx: Context, poses: np.ndarray) -> tuple[Samples, np.ndarray]:
    """The samples a campaign at ``poses`` (K,6) would record if the robot were ``H``: the
    tensions of its distribution read through its load-cell calibration, the encoder readings
    of the unstretched lengths that hold it (the initialisation convention, referenced at
    ``ctx.init_pose`` with ``d_model(p0)`` of ``ctx.model``). Returns the samples (the
    initialisation first) and the indices (into ``poses``) of the feasible ones kept."""
    model = ctx.model
    ref = reference_lengths(model, ctx.init_pose)
    if ctx.init_readings is not None:
        tau_init = true_tensions(H, ctx.init_readings)
    else:
        tau_init = pose_statics(H, ctx.init_pose).tensions
    u0, _ = init_unstretched(H, ctx.init_pose, tau_init)
    rows, kept = [], []
    for k, p in enumerate(np.asarray(poses, float).reshape(-1, 6)):
        ps = pose_statics(H, p)
        if not ps.feasible:
            continue
        length = ref + (ps.unstretched - u0 - H.length_offset) / H.drum_scale
        rows.append((p, length, H.load_cell_gain * ps.tensions + H.load_cell_offset))
        kept.append(k)
    init_read = H.load_cell_gain * tau_init + H.load_cell_offset \
        if ctx.init_readings is None else ctx.init_readings
    rows.insert(0, (ctx.init_pose, ref, init_read))
    K, n = len(rows), model.n_cables
    pose = np.array([r[0] for r in rows])
    tau = np.array([r[2] for r in rows]) if ctx.tensions else np.full((K, n), np.nan)
    s = Samples(t=np.arange(K, dtype=float), pose_des=pose,
                pose_meas=pose if ctx.tracker else np.full((K, 6), np.nan),
                l_meas=np.array([r[1] for r in rows]), tau=tau,
                exit_meas=np.full((K, n, 3), np.nan), count=np.full(K, ROWS_PER_DWELL),
                target=np.arange(K), is_init=np.arange(K) == 0,
                tau_row_sd=ctx.noise.get("force", 0.5) if ctx.tensions else None)
    return s, np.array(kept, dtype=int)


def residual_model(H: Robot, ctx: Context, poses: np.ndarray) -> tuple[ResidualModel,
                                                                        np.ndarray]:
    """The diagnosis's residual model on the synthetic samples of ``H`` at ``poses``, its
    noise the report's (one visit); and the kept candidates."""
    s, kept = synthetic_samples(H, ctx, poses)
    tau0 = s.tau[0] if ctx.tensions else None
    rm = ResidualModel(s, ctx.model, ctx.init_pose, tau0)
    sig = {k: float(ctx.noise.get(k, rm.sigma[k])) for k in BLOCKS}
    rm.sigma = dict(sig)
    rm.sigma_k = {0: dict(sig), 1: dict(sig)}
    rm._update_sd()
    return rm, kept


def _rows(rm: ResidualModel, space: ParamSpace, phi: np.ndarray, K: int
          ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per candidate (samples 1..K): whitened residual rows and scaled Jacobian rows."""
    def fun(x: np.ndarray) -> np.ndarray:
        return rm.whitened(space.robot(x))

    r = fun(phi)
    J = fd_jacobian(fun, phi, r, space.scale * 1e-2, space.lo, space.hi, rm.frozen) \
        * space.scale
    ent = rm.entry_samples()
    return ([r[ent == i + 1] for i in range(K)], [J[ent == i + 1] for i in range(K)])


def _free_directions(space: ParamSpace, rv: Rival) -> np.ndarray:
    """(p,q) an orthonormal basis of the scaled parameter moves a gauge rival may make: its
    held parameters fixed and, with ``common_gain``, the gains' common (log) mean fixed."""
    keys = [p.key for p in space.params]
    rows = [np.eye(len(keys))[keys.index(k)] for k in rv.held if k in keys]
    if rv.common_gain:
        rows.append(np.array([1.0 if k.startswith("gain_") else 0.0 for k in keys]))
    if not rows:
        return np.eye(len(keys))
    C = np.array(rows)
    _, sv, vt = np.linalg.svd(C)
    return vt[int(np.sum(sv > 1e-12)):].T


def _fit_within(rm: ResidualModel, space: ParamSpace, phi0: np.ndarray, Z: np.ndarray,
                steps: int = 4) -> np.ndarray:
    """Gauss-Newton steps from ``phi0`` along the scaled directions ``Z`` only (the gauge
    rival's other parameters refitted; its held combination kept), within the bounds."""
    def fun(x: np.ndarray) -> np.ndarray:
        return rm.whitened(space.robot(x))

    phi = np.clip(phi0, space.lo, space.hi)
    for _ in range(steps):
        r = fun(phi)
        J = fd_jacobian(fun, phi, r, space.scale * 1e-2, space.lo, space.hi, rm.frozen) \
            * space.scale
        step = np.linalg.lstsq(J @ Z, -r, rcond=1e-10)[0]
        trial = np.clip(phi + space.scale * (Z @ step), space.lo, space.hi)
        if float(fun(trial) @ fun(trial)) >= float(r @ r):
            break
        phi = trial
    return phi


#: step of a load-cell reading in the readings' finite differences [N]
READING_STEP = 1.0


def _reading_rows(rm: ResidualModel, H: Robot, K: int) -> tuple[list[np.ndarray],
                                                                list[np.ndarray]]:
    """Per candidate (samples 1..K): its whitened rows by its own load-cell readings (r_i,n)
    and by the initialisation's readings (r_i,n) [per N], forward differences of
    :data:`READING_STEP` (a sample's rows depend on its own readings and the
    initialisation's only)."""
    r0 = rm.whitened(H)
    ent = rm.entry_samples()
    n = rm.s.tau.shape[1]
    own, init = np.zeros((len(r0), n)), np.zeros((len(r0), n))
    tau, tau0 = rm.s.tau.copy(), None if rm.tau0 is None else rm.tau0.copy()
    with rm.frozen():
        for j in range(n):
            rm.s.tau[1:, j] += READING_STEP
            own[:, j] = (rm.whitened(H) - r0) / READING_STEP
            rm.s.tau[:] = tau
            rm.s.tau[0, j] += READING_STEP
            if tau0 is not None:
                rm.tau0[j] += READING_STEP
            init[:, j] = (rm.whitened(H) - r0) / READING_STEP
            rm.s.tau[:] = tau
            if tau0 is not None:
                rm.tau0[:] = tau0
    return ([own[ent == i + 1] for i in range(K)], [init[ent == i + 1] for i in range(K)])


def identifiability(hyp: Hypotheses, ctx: Context, poses: np.ndarray, visits: int,
                    measured: np.ndarray) -> dict[str, Any]:
    """What a campaign at ``poses`` (each visited ``visits`` times) fixes of the preferred
    hypothesis' parameters when only the cables ``measured`` (n,) bool carry load cells
    (:func:`controller.design.measured_information`: the other cables' tensions are
    unknowns of every pose, and of the initialisation), against every cable measured: the
    predicted standard errors (parameter units) and which parameters the diagnosis's rule
    (:func:`bench.diagnosis.space.undetermined`) would leave undetermined."""
    if not ctx.tensions:
        raise DesignError("--load-cells: the campaign records no tensions (its recording or "
                          "scenario has no load cells)")
    measured = np.asarray(measured, bool)
    rm, kept = residual_model(hyp.robot, ctx, poses)
    K = len(kept)
    space = ParamSpace(ctx.model, hyp.effects)
    phi = space.phi_of(hyp.robot)
    _, Jp = _rows(rm, space, phi, K)
    Jr, J0 = _reading_rows(rm, hyp.robot, K)
    S = np.arange(K)
    out: dict[str, Any] = {"load_cells": [c for c, m in zip(ctx.model.cable_ids, measured,
                                                            strict=True) if m],
                           "poses": K, "visits": visits}
    for name, mask in (("all", np.ones_like(measured)), ("measured", measured)):
        G = design.measured_information(Jp, Jr, J0, mask)
        se = design.subset_standard_errors(G, S, int(np.sum(~mask)), visits) * space.scale
        se_u = _to_units([p.key for p in space.params], se, hyp, ctx)
        out[name] = {"stderr": {p.key: float(v) for p, v in zip(space.params, se_u,
                                                                 strict=True)},
                     "undetermined": [p.key for p, v, e in zip(space.params, phi, se,
                                                                strict=True)
                                      if undetermined(p, float(v), float(e))]}
    out["lost"] = [x for x in out["measured"]["undetermined"]
                   if x not in out["all"]["undetermined"]]
    return out


def identifiability_note(ident: dict[str, Any]) -> str:
    """One line: what the design leaves undetermined with only the load cells named."""
    cells = ", ".join(ident["load_cells"])
    lost = ident["lost"]
    left = ident["measured"]["undetermined"]
    return (f"with load cells on {cells} only: "
            + (f"undetermined {', '.join(left)}" if left else "every parameter determined")
            + (f" ({len(lost)} of them fixed when every cable is measured)" if lost else ""))


def measured_mask(model: Robot, cables: list[str] | None) -> np.ndarray:
    """(n,) bool: the cables (ids of ``model``) that carry load cells; None: every one."""
    ids = list(model.cable_ids)
    if cables is None:
        return np.ones(len(ids), bool)
    bad = [c for c in cables if c not in ids]
    if bad or not cables:
        raise DesignError(f"--load-cells: {', '.join(bad) or 'none given'}: cable ids must be "
                          f"among {', '.join(ids)}")
    return np.array([c in cables for c in ids])


@dataclass
class Pieces:
    """Per candidate: ``F`` (C,p,p) the preferred hypothesis' information; ``keys`` its
    parameters; ``scale`` their scales; ``alts`` the alternatives' pieces; ``poses`` (C,6)."""

    F: np.ndarray
    keys: list[str]
    scale: np.ndarray
    alts: list[design.Alternative]
    poses: np.ndarray
    fitted_chi2: dict[str, float]


def pieces(hyp: Hypotheses, ctx: Context, poses: np.ndarray) -> Pieces:
    """Evaluate the preferred hypothesis and its rivals at the candidate ``poses``."""
    rm, kept = residual_model(hyp.robot, ctx, poses)
    poses = np.asarray(poses, float)[kept]
    K = len(kept)
    space = ParamSpace(ctx.model, hyp.effects)
    phi = space.phi_of(hyp.robot)
    _, Jr = _rows(rm, space, phi, K)
    F = np.stack([j.T @ j for j in Jr])
    alts, chi2 = [], {}
    idx = np.arange(rm.s.n)
    for rv in hyp.alternatives:
        sp = ParamSpace(ctx.model, rv.effects)
        if rv.start is None:
            phi_a = fit_effects(sp, rm, idx, prune=False).phi
            Z = None
        else:
            Z = _free_directions(sp, rv)
            phi_a = _fit_within(rm, sp, sp.phi_of(rv.start), Z)
        d, Kr = _rows(rm, sp, phi_a, K)
        if Z is not None:
            Kr = [k @ Z for k in Kr]
        chi2[rv.label] = float(sum(float(x @ x) for x in d))
        alts.append(design.Alternative.from_rows(rv.label, d, Kr,
                                                 np.eye(Kr[0].shape[1]) * 1e-6))
    return Pieces(F, [p.key for p in space.params], space.scale, alts, poses, chi2)


def candidate_poses(robot: Robot, ctx: Context, count: int, rng: np.random.Generator,
                    rpy_deg: float | None = None) -> np.ndarray:
    """Random tension-feasible poses (``count`` drawn, :func:`bench.evaluate.feasible_poses`,
    under ``robot``, the preferred hypothesis) in the site's box (default :func:`design_box`)
    that the controller's model holds too, within the site's tension window."""
    from bench.evaluate import feasible, feasible_poses

    box = ctx.box if ctx.box is not None else design_box(robot)
    rpy = RPY_DEG if rpy_deg is None else rpy_deg
    pts = feasible_poses(robot, rng, count, rpy, box=box)
    pts = pts[[k for k, p in enumerate(pts) if _inside_frame(ctx.model, p)]]
    # the controller runs the campaign with its model: a pose must be feasible for it too
    pts = pts[[k for k, p in enumerate(pts) if feasible(ctx.model, p)]]
    if ctx.tension_window is not None and len(pts):
        lo, hi = ctx.tension_window
        ok = [k for k, p in enumerate(pts) if _within(robot, p, lo, hi)]
        pts = pts[ok]
    return pts


def design_box(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Where candidates are drawn without a site box: the robot's frame
    (:func:`controller.paths.frame_box`) less :data:`BOX_MARGIN` of its span in x and y,
    heights :data:`BOX_HEIGHTS` of the highest exit point above the ground (the feasibility
    check then keeps the poses the tension distribution holds)."""
    from controller.paths import frame_box

    fb = frame_box(robot)
    span = fb[1] - fb[0]
    lo = np.array([*(fb[0, :2] + BOX_MARGIN * span[:2]), fb[0, 2] + BOX_HEIGHTS[0] * span[2]])
    hi = np.array([*(fb[1, :2] - BOX_MARGIN * span[:2]), fb[0, 2] + BOX_HEIGHTS[1] * span[2]])
    return lo, hi


def _inside_frame(robot: Robot, pose: np.ndarray) -> bool:
    """Whether every platform anchor at ``pose`` lies inside the robot's frame
    (:func:`controller.paths.frame_box`, the dry run's check of a path)."""
    from controller.kinematics import cable_state
    from controller.paths import frame_box

    box = frame_box(robot)
    B = cable_state(np.asarray(pose, float), robot.anchors, robot.exits,
                    robot.pulley_radius).B
    return bool(np.all((B >= box[0]) & (B <= box[1])))


def _within(robot: Robot, pose: np.ndarray, lo: float, hi: float) -> bool:
    """Whether ``robot``'s tension distribution holds ``pose`` within [lo, hi] [N]."""
    ps = pose_statics(robot, pose)
    return bool(ps.feasible and ps.tensions.min() >= lo and ps.tensions.max() <= hi)


@dataclass
class Result:
    """A design: the chosen ``poses`` (N,6), the :class:`controller.design.Design`, the
    predicted standard errors of the preferred hypothesis' parameters ``keys`` (``stderr``,
    parameter units); ``notes`` what the design does and does not settle; ``candidates``
    the candidate poses it chose from."""

    poses: np.ndarray
    design: design.Design
    stderr: dict[str, float]
    keys: list[str]
    notes: list[str]
    hyp: Hypotheses
    candidates: int


def run_design(report: dict[str, Any], ctx: Context, n: int, visits: int = 2,
               seed: int = 0, candidates: int = CANDIDATES, target: float = TARGET) -> Result:
    """Choose ``n`` poses (each visited ``visits`` times) from ``candidates`` drawn with
    ``seed`` (module docstring)."""
    from bench.diagnosis.report import SEPARATE

    hyp = hypotheses(report, ctx.model)
    rng = np.random.default_rng(seed)
    pts = candidate_poses(hyp.robot, ctx, candidates, rng)
    if len(pts) < n:
        raise DesignError(f"poses: {n} asked but only {len(pts)} tension-feasible candidate "
                          f"poses were found in the workspace")
    pc = pieces(hyp, ctx, pts)
    if len(pc.poses) < n:
        raise DesignError(f"poses: {n} asked but only {len(pc.poses)} candidates could be "
                          f"evaluated under the preferred hypothesis")
    d = design.choose(pc.F, n, pc.alts, visits, target=target)
    se = design.standard_errors(pc.F, d.indices, visits, np.eye(len(pc.keys)) * 1e-6) \
        * pc.scale
    notes = []
    if hyp.default:
        notes.append("the report names no effect: a design for the parameters of "
                     + ", ".join(DEFAULT_EFFECTS) + " only (nothing to separate)")
    elif not hyp.alternatives:
        notes.append("the report names no alternative: a design for the parameters only "
                     "(D-optimal; nothing to separate)")
    for rv in hyp.alternatives:
        label, names = rv.label, rv.names
        if d.separated[label]:
            notes.append(f"{label}: expected chi-square difference {d.delta[label]:.0f} "
                         f"(>= {target:g}): the designed campaign separates them")
        else:
            how = SEPARATE.get(frozenset(names), "more poses spread over the workspace")
            notes.append(f"{label}: expected chi-square difference only {d.delta[label]:.1f} "
                         f"(< {target:g}) on the best {n} of {len(pc.poses)} tension-feasible "
                         f"poses: poses alone do not tell them apart; {how} would")
    stderr = {k: float(v) for k, v in zip(pc.keys, _to_units(pc.keys, se, hyp, ctx),
                                           strict=True)}
    notes += _undetermined_notes(hyp, stderr)
    return Result(pc.poses[d.indices], d, stderr, pc.keys, notes, hyp, len(pc.poses))


def _undetermined_notes(hyp: Hypotheses, stderr: dict[str, float]) -> list[str]:
    """The design's predicted standard errors (parameter units) of the parameters the report
    left undetermined (it gives them no value: the prediction is at the model's)."""
    got = [f"{k} {stderr[k]:.3g}" for k in hyp.undetermined if k in stderr]
    if not got:
        return []
    return ["undetermined in the report; the design's predicted standard errors: "
            + ", ".join(got)]


def _to_units(keys: list[str], se: np.ndarray, hyp: Hypotheses, ctx: Context) -> np.ndarray:
    """Fit-space standard errors in the parameters' units (stiffness and EA from their
    inverses: se(k) = se(c) k^2)."""
    space = ParamSpace(ctx.model, hyp.effects)
    phi = space.phi_of(hyp.robot)
    out = np.array(se, float)
    for k, p in enumerate(space.params):
        if p.kind == "inverse" and phi[k] > 0:
            out[k] = se[k] / phi[k] ** 2
    return out


def check_path(text: str, ctx: Context) -> str:
    """The dry run's check of the designed path (``cdpr-path/1`` ``text``) from the init
    pose, for the controller's model (:func:`controller.paths.check_trajectory`): ``""``
    when it passes, else where and why it fails."""
    import tomllib

    from controller.paths import build_trajectory, check_trajectory, parse_path

    spec = parse_path(tomllib.loads(text), "<designed path>", text)
    chk = check_trajectory(ctx.model, build_trajectory(spec, ctx.init_pose))
    if chk.ok:
        return ""
    return (f"the path fails the dry run's check at t = {chk.t_s:.1f} s, pose "
            f"{np.round(chk.pose, 3).tolist()}: {chk.reason}")


#: visiting orders (``shuffle`` seeds) tried for a designed path that passes the dry run's check
ORDER_TRIES = 16


def checked_document(res: Result, visits: int, report_path: str, ctx: Context,
                     seed: int = 0) -> tuple[str, str]:
    """The design as a path (:func:`path_document`) whose visiting order passes the dry
    run's check (:func:`check_path`): the ``shuffle`` seeds ``seed``, ``seed + 1``, ... tried
    in turn (at most :data:`ORDER_TRIES`; a straight move between two feasible poses can
    leave the feasible workspace, another order avoids it). Returns the text and ``""``, or
    the text of ``seed`` and why every order tried fails (the poses themselves are
    feasible: a site may still move its init pose)."""
    first = ""
    for k in range(ORDER_TRIES):
        text = path_document(res, visits, report_path, seed=seed + k)
        problem = check_path(text, ctx)
        if not problem:
            return text, ""
        first = first or problem
    return (path_document(res, visits, report_path, seed=seed),
            f"{first} (and with every visiting order of seeds {seed} to "
            f"{seed + ORDER_TRIES - 1})")


def path_document(res: Result, visits: int, report_path: str, dwell_s: float = 3.0,
                  seed: int = 0) -> str:
    """The design as a ``cdpr-path/1`` TOML text: one ``visits`` segment with the poses."""
    lines = ["# Written by cdpr campaign design: poses chosen to settle what a diagnosis left open",
             'format = "cdpr-path/1"', 'name = "designed"',
             'notes = """', f"Designed from {report_path}."]
    lines += [s.replace('"""', "'''") for s in res.notes]
    lines += ['"""', "", "[[segment]]", 'kind = "visits"', 'name = "designed poses"',
              f"visits = {visits}", f"dwell_s = {dwell_s:g}", 'order = "shuffle"',
              f"seed = {seed}", "poses = ["]
    lines += ["  [" + ", ".join(f"{v:.6f}" for v in p) + "]," for p in res.poses]
    lines += ["]", ""]
    return "\n".join(lines)


def as_json(res: Result, path: str | None) -> dict[str, Any]:
    """The design's JSON summary (``--json``)."""
    d = res.design
    return {"poses": [[float(v) for v in p] for p in res.poses], "path": path,
            "candidates": res.candidates, "effects": [report_name(e) for e in res.hyp.effects],
            "alternatives": [{"name": k, "expected_delta_chi2": float(v),
                              "separated": bool(d.separated[k])} for k, v in d.delta.items()],
            "logdet_information": d.logdet, "exchanges": d.exchanges,
            "predicted_stderr": res.stderr, "undetermined_in_report": res.hyp.undetermined,
            "notes": res.notes}


def context(report: dict[str, Any], report_path: str | Path, scenario: str | Path | None = None,
            site: str | Path | None = None) -> Context:
    """The design's :class:`Context`: the model, initialisation and sensors of the recording
    the report names (read when it is there; else the scenario's model and init pose), the
    report's noise, and the site's workspace box and tension window (``--site``) or the
    scenario's sensors (``--scenario``)."""
    from bench.recording import RecordingError, read_recording

    rec = None
    rec_path = Path(str(report.get("recording", "")))
    if not rec_path.is_absolute() and not rec_path.exists():
        rec_path = Path(report_path).parent / rec_path
    try:
        rec = read_recording(rec_path) if str(report.get("recording", "")) else None
    except (RecordingError, OSError):
        rec = None
    noise = {k: float(v) for k, v in report.get("mismatch", {}).get("noise", {}).items()
             if k in BLOCKS and isinstance(v, (int, float))}
    box = window = None
    if scenario is not None:
        from firmware_sim.scenario import ScenarioError, load_scenario

        try:
            sc = load_scenario(scenario)
        except ScenarioError as e:
            raise DesignError(str(e)) from e
        model, init = sc.model, sc.init_pose
        tracker, tensions = sc.recording.tracker, sc.recording.load_cells
        readings = None
    elif rec is None:
        raise DesignError(f"{report_path}: recording: {rec_path} cannot be read (the design "
                          f"needs its model and initialisation: give --scenario)")
    if rec is not None:
        model, init = rec.robot, rec.init_pose
        tracker = bool(np.isfinite(rec.pose_meas).all(axis=1).any())
        tensions = bool(np.isfinite(rec.tau).all(axis=1).any())
        readings = rec.init_tensions
    if site is not None:
        from hal.site import SiteError, load_site

        try:
            st = load_site(site)
        except SiteError as e:
            raise DesignError(str(e)) from e
        lim = st.limits
        window = (lim.tension_min_N, lim.tension_max_N)
        if lim.workspace_min_m is not None and lim.workspace_max_m is not None:
            box = (np.array(lim.workspace_min_m, float), np.array(lim.workspace_max_m, float))
        tracker = tracker and st.tracker is not None
    return Context(model, np.asarray(init, float), readings, tracker, tensions, noise, box,
                   window)


def path_poses(name_or_path: str | Path) -> tuple[np.ndarray, int]:
    """The poses (P,6) of a ``cdpr-path/1`` file's ``visits`` segments and their visits
    (the largest of the segments'); 3-number targets keep a level orientation."""
    from controller.paths import load_path
    from controller.trajectory import Visits

    spec = load_path(name_or_path)
    poses, visits = [], 0
    for seg in spec.segments:
        if isinstance(seg, Visits):
            for t in seg.poses:
                poses.append(list(t) + [0.0] * (6 - len(t)))
            visits = max(visits, int(seg.visits))
    if not poses:
        raise DesignError(f"{spec.source}: no visits segment: no poses to visit")
    return np.array(poses, float), visits


#: parameters the match (goal) compares: mast stiffnesses and exit offsets
MATCH_PREFIXES = ("dx_", "dy_", "dz_", "kx_", "ky_", "kz_")


def match_reference(report: dict[str, Any], ctx: Context, ref_poses: np.ndarray,
                    ref_visits: int, visits: int, seed: int = 0,
                    candidates: int = CANDIDATES, n_max: int = 40,
                    n: int | None = None) -> dict[str, Any]:
    """How many designed poses (``visits`` each) reach the standard errors the reference
    campaign (``ref_poses`` visited ``ref_visits`` times) gives on the preferred
    hypothesis' exit offsets and mast stiffnesses (:data:`MATCH_PREFIXES`), both predicted
    by the same Fisher information (:func:`controller.design.fewest_to_match`); with ``n``
    also the ``n`` poses that come closest (:func:`controller.design.choose_matching`:
    the largest ratio of standard errors to the reference's made small), in ``at_poses``."""
    hyp = hypotheses(report, ctx.model)
    rng = np.random.default_rng(seed)
    cand = candidate_poses(hyp.robot, ctx, candidates, rng)
    allp = np.vstack([np.asarray(ref_poses, float), cand])
    pc = pieces(Hypotheses(hyp.effects, hyp.robot, [], hyp.undetermined, hyp.default), ctx,
                allp)
    # the pieces keep the feasible poses in order: the reference's come first
    n_ref = int(np.sum(_kept_index(hyp.robot, ctx, allp) < len(ref_poses)))
    prior = np.eye(len(pc.keys)) * 1e-6
    ref_se = design.standard_errors(pc.F[:n_ref], np.arange(n_ref), ref_visits, prior) \
        * pc.scale
    space = ParamSpace(ctx.model, hyp.effects)
    phi = space.phi_of(hyp.robot)
    # what the reference leaves undetermined (the diagnosis's rule) is no standard to reach
    open_ = [undetermined(p, float(v), float(e)) for p, v, e in zip(space.params, phi, ref_se,
                                                                    strict=True)]
    keys = np.array([k for k, key in enumerate(pc.keys) if key.startswith(MATCH_PREFIXES)
                     and not open_[k]], dtype=int)
    if not len(keys):
        raise DesignError("the reference determines no exit offset or mast stiffness to match")
    F, ref = pc.F[n_ref:], ref_se[keys] / pc.scale[keys]
    count, idx = design.fewest_to_match(F, ref, keys, visits, prior, n_max, seed)
    got = design.standard_errors(F, idx, visits, prior) * pc.scale
    worst = float(np.max(got[keys] / ref_se[keys]))
    left = [pc.keys[k] for k in range(len(pc.keys))
            if open_[k] and pc.keys[k].startswith(MATCH_PREFIXES)]
    at = None
    if n is not None:
        sel = design.choose_matching(F, min(n, len(F)), keys, ref, visits, prior, seed=seed)
        ratio = (design.standard_errors(F, sel, visits, prior) * pc.scale)[keys] / ref_se[keys]
        se_at = _to_units(pc.keys, design.standard_errors(F, sel, visits, prior) * pc.scale,
                          hyp, ctx)
        at = {"poses": [[float(v) for v in p] for p in pc.poses[n_ref:][sel]],
              "worst_ratio": float(ratio.max()), "median_ratio": float(np.median(ratio)),
              "stderr": {k: float(v) for k, v in zip(pc.keys, se_at, strict=True)}}
    return {"reference_poses": n_ref, "undetermined_by_reference": left, "at_poses": at,
            "reference_visits": ref_visits, "visits": visits,
            "poses_needed": count, "poses": [[float(v) for v in p] for p in
                                             pc.poses[n_ref:][idx]],
            "worst_ratio": worst,
            "stderr_reference": {pc.keys[k]: float(v) for k, v in
                                 zip(keys, _to_units(pc.keys, ref_se, hyp, ctx)[keys],
                                     strict=True)},
            "stderr_designed": {pc.keys[k]: float(v) for k, v in
                                zip(keys, _to_units(pc.keys, got, hyp, ctx)[keys],
                                    strict=True)}}


def _kept_index(H: Robot, ctx: Context, poses: np.ndarray) -> np.ndarray:
    """Indices of ``poses`` whose statics under ``H`` are feasible (those the pieces keep)."""
    return np.array([k for k, p in enumerate(poses) if pose_statics(H, p).feasible], int)
