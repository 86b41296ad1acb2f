"""The diagnosis of one recording, as the ``cdpr-diagnosis/1`` report object.

:func:`diagnose` prepares the samples, measures the baseline, locates the
mismatch, selects and fits the effects, checks them on held-out samples, and
assembles the report (``docs/formats/diagnosis-report.md``). Figures a
recording cannot give are None (JSON null), never 0.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
from collections.abc import Callable
from concurrent.futures import Executor
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.chunked import read_conditioned
from bench.diagnosis import frame, gauge, locate, noise, probes, slips, unexplained
from bench.diagnosis.fit import (
    FitResult,
    Interval,
    direction_reference_var,
    fit_effects,
    fits_side_by_side,
    referenced_offsets,
    satterthwaite,
    split_columns,
)
from bench.diagnosis.residuals import Forward, ResidualModel
from bench.diagnosis.samples import Samples, pooled_std, prepare
from bench.diagnosis.select import (
    BIC_ENTER,
    BIC_TIE,
    Selection,
    Selector,
    _warm,
    candidate_effects,
    compatible,
    honest_bic,
    untested_effects,
    within,
)
from bench.diagnosis.space import (
    EXPLAINS,
    RIGID_FACTOR,
    ParamSpace,
    report_name,
    undetermined,
)
from bench.recording import Recording, RecordingError
from bench.streams import summary_line
from controller.kinematics import gravity_wrench
from controller.robot import Robot, save_robot
from controller.statics import batch_statics

FORMAT = "cdpr-diagnosis/1"
#: changes too small to matter (fit-space units): not reported as differing from the model
PRACTICAL = {"exit_point_offset": 5e-4, "cable_length_offset": 1e-4, "drum_scale": 1e-4,
             "load_cell_calibration": 2e-3, "platform_mass": 2e-3, "pulley_kinematics": 2e-3,
             "cable_sag": 1e-3}
#: every k-th target pose is held out of the fits
HOLDOUT_EVERY = 5

#: which measurement separates two look-alike effects
SEPARATE = {
    frozenset({"tracker_frame", "exit_point_offset"}):
        "load cells (the frame's rotation tilts gravity) or exit points measured with the "
        "tracker",
    frozenset({"pulley_kinematics", "exit_point_offset"}):
        "poses that swing the cables through different swivel angles and elevations around "
        "each mast, or exit points measured by the tracker at several poses",
    frozenset({"mast_compliance", "cable_elasticity"}):
        "exit points measured by the tracker under different loads (compliance moves them, "
        "elasticity does not)",
    frozenset({"mast_compliance", "exit_point_offset"}):
        "the same poses at two pretension levels or payloads (offsets do not change with "
        "tension)",
    frozenset({"drum_scale", "exit_point_offset"}):
        "long moves that change one cable's length at a constant direction",
    frozenset({"load_cell_calibration", "platform_mass"}):
        "a known extra mass on the platform, or the same poses at two pretension levels",
    # without a tracker a common EA, and a gain common to every load cell with the mass,
    # are one in the statics and in the cables' stretch
    frozenset({"platform_mass", "cable_elasticity"}):
        "tracker poses, or a known extra mass on the platform (without a tracker a common "
        "change of EA and a gain common to every load cell with the mass are the same in the "
        "statics and in the cables' stretch)",
    frozenset({"load_cell_calibration", "cable_elasticity"}):
        "tracker poses, or a known extra mass on the platform",
    frozenset({"cable_elasticity", "drum_scale"}):
        "the same pose at two pretension levels (elasticity follows tension, scale does not)",
    frozenset({"cable_length_offset", "exit_point_offset"}):
        "poses spread further from the initialisation pose",
}

Progress = Callable[[str], None]


@dataclass
class Diagnosis:
    """Everything the report and the plots are made of."""

    report: dict
    recording: Recording
    samples: Samples
    rm: ResidualModel
    selection: Selection
    fitted_robot: Robot
    baseline_forward: Forward
    fitted_forward: Forward
    heldout: np.ndarray
    #: why ``--write-model`` could not be written after the fit (None: written or not asked)
    write_error: str | None = None


def _f(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def pose_figures(fw: Forward, idx: np.ndarray | None = None) -> dict[str, float | None]:
    sl = slice(None) if idx is None else idx
    pe = fw.pose_err[sl]
    d = np.linalg.norm(pe[:, :3], axis=1)
    a = np.linalg.norm(pe[:, 3:], axis=1)
    ok = np.isfinite(d)
    return {
        "pose_rms_m": _f(locate.rms(d)) if ok.any() else None,
        "pose_max_m": _f(float(d[ok].max())) if ok.any() else None,
        "angle_rms_rad": _f(locate.rms(a)) if np.isfinite(a).any() else None,
        "tension_rms_n": _f(locate.rms(fw.tension_err[sl])),
    }


def wrench_rms(H: Robot, s: Samples, raw: bool) -> float | None:
    """RMS of |W tau + w_g| (forces) at the measured poses [N]; ``raw``: tensions as read."""
    ok = np.isfinite(s.pose_meas).all(axis=1) & np.isfinite(s.tau).all(axis=1)
    if not ok.any():
        return None
    tau = s.tau[ok] if raw else (s.tau[ok] - H.load_cell_offset) / H.load_cell_gain
    bs = batch_statics(H, s.pose_meas[ok], tau)
    f = bs.platform_forces.sum(axis=-2) \
        + gravity_wrench(H.mass, H.com, H.gravity, bs.state.R)[..., :3]
    return _f(locate.rms(np.linalg.norm(f[:, :3], axis=1)))


def exit_rms(rm: ResidualModel, H: Robot) -> float | None:
    if not rm.has_exit.any():
        return None
    e = rm.blocks(H).exit
    return _f(locate.rms(np.linalg.norm(e, axis=2)))


#: a parameter is reported when it departs from the model's value by more than this many
#: standard errors (and :data:`PRACTICAL`)
REPORT_SIGMAS = 3.0


def report_threshold(p, se: float, floor_var: float = 0.0) -> tuple[float, float]:
    """(s, c): a parameter ``p`` (fit units, standard error ``se``, ``floor_var`` an
    uncertainty the fit cannot see) is reported as differing from the model when it departs
    from the model's value by more than ``c`` times ``s``: :data:`REPORT_SIGMAS` standard
    errors, or the change too small to matter (:data:`PRACTICAL`; a load cell's offset 0.3
    N; a stiffness 2 % of the model's) where that is more."""
    if p.kind == "inverse":
        s, floor = se, 0.02 * abs(p.neutral)
    else:
        s = math.sqrt(se ** 2 + floor_var)
        floor = PRACTICAL.get(p.effect, 0.0) if not p.key.startswith("offset_") else 0.3
    if not math.isfinite(s):
        return s, REPORT_SIGMAS
    if s <= 0:  # (no error: the floor alone)
        return floor, 1.0
    return s, max(REPORT_SIGMAS, floor / s)


def effect_entries(fit: FitResult, effects: list[str], floor_var: np.ndarray | None = None
                   ) -> tuple[dict, dict, dict]:
    """Per chosen candidate: report params and stderr (only those that differ from the
    model), and the undetermined keys. ``floor_var`` (per fit parameter, fit units squared)
    is an uncertainty the fit cannot see, added to its own before a parameter is judged to
    differ (the encoder reference's, for a length offset from the initialisation on)."""
    params: dict[str, dict] = {e: {} for e in effects}
    errs: dict[str, dict] = {e: {} for e in effects}
    undet: dict[str, list] = {e: [] for e in effects}
    values = fit.space.values(fit.phi)
    fv = np.zeros(len(fit.space.params)) if floor_var is None else floor_var
    for e in effects:
        for k in fit.space.indices(e):
            p = fit.space.params[k]
            se = float(fit.stderr[k])
            phi = p.from_value(values[p.effect][p.key])
            if undetermined(p, phi, se):
                undet[e].append(p.key)
                continue
            scale, c = report_threshold(p, se, float(fv[k]))
            if abs(phi - p.neutral) <= c * scale:
                # the model's value within the uncertainty, or a negligible change (a
                # stiffness: the model's own within the uncertainty)
                continue
            value = values[p.effect][p.key]
            rse = float(fit.reported_stderr[k])  # with what pruning may have moved in
            err = rse / phi**2 if p.kind == "inverse" else rse
            params[e][p.key] = float(value)
            errs[e][p.key] = float(err)
        if not params[e]:
            for k in _jointly_differing(fit, e, undet[e], fv):
                p = fit.space.params[k]
                phi = p.from_value(values[p.effect][p.key])
                se = float(fit.reported_stderr[k])
                params[e][p.key] = float(values[p.effect][p.key])
                errs[e][p.key] = float(se / phi**2 if p.kind == "inverse" else se)
    return params, errs, undet


def effect_intervals(fit: FitResult, rm: ResidualModel, idx: np.ndarray, effects: list[str],
                     params: dict[str, dict], floor_var: np.ndarray, pool: Executor | None,
                     say: Progress, floor_dof: np.ndarray | None = None
                     ) -> dict[str, dict[str, tuple[float | None, float | None, str, float]]]:
    """Per chosen candidate, the 95 % interval of each reported parameter (``params``) in
    the conventions' units, how it was found (:func:`bench.diagnosis.fit.
    confidence_intervals`: linearised, or widened by profile refits where parameters
    correlate or the chi-square is not quadratic) and the Student quantile its standard
    errors were taken at (:func:`bench.diagnosis.fit.interval_quantile`; 1.96 where the
    error model's levels rest on many differences); ``floor_var`` as in
    :func:`effect_entries`, in the interval (at ``floor_dof`` degrees of freedom). An
    unbounded end (a stiffness as rigid as the data allow) is None."""
    from bench.diagnosis.fit import confidence_intervals, value_interval

    where = {(report_name(e), fit.space.params[k].key): int(k)
             for e in effects for k in fit.space.indices(e)}
    which = np.array(sorted({where[(report_name(e), key)] for e in effects
                             for key in params[e] if (report_name(e), key) in where}), dtype=int)
    ivs = confidence_intervals(fit, rm, idx, which, floor_var, pool, say, floor_dof) \
        if len(which) else {}
    for k in ivs:
        ivs[k] = selective(fit, k, ivs[k], float(floor_var[k]))
    out: dict[str, dict[str, tuple[float | None, float | None, str, float]]] = {}
    for e in effects:
        out[e] = {}
        for key in params[e]:
            k = where.get((report_name(e), key))
            if k is not None and k in ivs:
                lo, hi = value_interval(fit.space.params[k], ivs[k])
                out[e][key] = (_f(lo), _f(hi), ivs[k].method, round(ivs[k].quantile, 4))
    return out


def selective(fit: FitResult, k: int, iv: Interval, floor_var: float = 0.0) -> Interval:
    """The interval ``iv`` of parameter ``k`` of ``fit`` widened to the one that allows for
    its having been reported for departing from the model's value
    (:func:`report_threshold`, :func:`bench.diagnosis.fit.selective_interval`): method
    ``selective`` where that reaches further (``profile+selective``, ``jackknife+selective``
    where a refit had widened ``iv`` already). Parameters reported jointly (no threshold of
    their own passed) keep ``iv``."""
    from bench.diagnosis.fit import selective_interval

    p = fit.space.params[k]
    s, c = report_threshold(p, float(fit.stderr[k]), floor_var)
    got = selective_interval(float(fit.phi[k]), p.neutral, s, c)
    if got is None:
        return iv
    lo, hi = max(got[0], p.lo), min(got[1], p.hi)
    if lo < iv.lo or hi > iv.hi:
        method = "selective" if iv.method == "linearised" else f"{iv.method}+selective"
        return Interval(min(lo, iv.lo), max(hi, iv.hi), method, iv.quantile)
    return iv


#: an effect whose parameters jointly differ from the model at this p-value (Wald) ...
JOINT_P = 1e-6
#: ... names the fewest parameters that leave the rest consistent with the model at this one
REST_P = 0.01


def _jointly_differing(fit: FitResult, effect: str, undetermined: list[str],
                       floor_var: np.ndarray | None = None) -> list[int]:
    """Parameters of ``effect`` that must differ from the model, when each one alone stays
    within its uncertainty but together they differ clearly (Wald test, p < JOINT_P).

    Look-alike parameters can share a poorly known common mode (the load cells' common gain
    without a tracker: the marginal errors of all eight gains are that mode's, 2.5 %) while
    their differences are well known: one cell 5 % low is then within three marginal
    standard errors of the model, yet the data's chi-square fell ninety-fold. The fewest
    parameters are freed, one at a time (the one whose freedom explains most of the Wald
    statistic first), until what remains is consistent with the model (p > REST_P); a
    change below the practical size is not named."""
    from scipy.stats import chi2 as chi2_dist

    space = fit.space
    ix = np.array([k for k in space.indices(effect)
                   if space.params[k].key not in undetermined
                   and np.isfinite(fit.stderr[k]) and fit.stderr[k] > 0], dtype=int)
    if len(ix) == 0:
        return []
    d = (fit.phi - space.neutral)[ix]
    cov = fit.cov[np.ix_(ix, ix)]
    if floor_var is not None:
        cov = cov + np.diag(floor_var[ix])
    Ci = np.linalg.pinv(cov, rcond=1e-12, hermitian=True)
    b = Ci @ d
    wald = float(d @ b)
    if not np.isfinite(wald) or chi2_dist.sf(wald, len(ix)) > JOINT_P:
        return []

    def rest(free: list[int]) -> float:
        """Wald statistic left when the parameters ``free`` (positions in ix) are free."""
        if not free:
            return wald
        sub = Ci[np.ix_(free, free)]
        return wald - float(b[free] @ np.linalg.lstsq(sub, b[free], rcond=None)[0])

    free: list[int] = []
    while len(free) < len(ix) and chi2_dist.sf(rest(free), len(ix) - len(free)) <= REST_P:
        free.append(min((j for j in range(len(ix)) if j not in free),
                        key=lambda j: rest(free + [j])))
    out = []
    for j in free:
        p = space.params[ix[j]]
        small = PRACTICAL.get(p.effect, 0.0) if p.kind != "inverse" else 0.02 * abs(p.neutral)
        if p.key.startswith("offset_"):
            small = 0.3
        if abs(d[j]) > small:
            out.append(int(ix[j]))
    return out


def _reference_var(rm: ResidualModel, fit: FitResult, idx: np.ndarray,
                   dof: list[np.ndarray] | None = None) -> np.ndarray:
    """Per fit parameter, the variance of the encoder reference (:meth:`ResidualModel.
    reference_sd` under the fitted robot, and each cable's error by direction of approach
    at the reference where poses are estimated: :func:`direction_reference_var` on the
    fit's samples ``idx``) for a length offset that applies from the initialisation on (no
    step found later): the two are the same signature. With a list ``dof``, the variances'
    degrees of freedom (Welch-Satterthwaite; the reference's taken as known) are appended."""
    out = np.zeros(len(fit.space.params))
    if not any(p.key.startswith("dl_") for p in fit.space.params):
        if dof is not None:
            dof.append(np.full(len(out), np.inf))
        return out
    ref = rm.reference_sd(cleaned_robot(fit))
    ids = rm.model.cable_ids
    for j in np.flatnonzero(referenced_offsets(fit.space, rm)):
        out[j] = ref[ids.index(fit.space.params[j].key[3:])] ** 2
    nu: list[float] = []
    by_dir = direction_reference_var(fit, rm, idx, nu)
    if dof is not None:
        dof.append(satterthwaite([out, by_dir], [math.inf, nu[0] if nu else math.inf]))
    return out + by_dir


def cleaned_robot(fit: FitResult) -> Robot:
    """The fitted robot (every parameter at its fitted value: where the data cannot fix a
    parameter alone, the fit still holds the combination they do fix)."""
    return fit.space.robot(fit.phi)


def posable_robot(fit: FitResult) -> Robot:
    """The fitted robot with every stiffness the fit ran to its rigid bound (a compliance
    or 1/EA ``RIGID_FACTOR`` times past the effect's scale) at the model's value: rigid
    cables over-determine the pose (eight lengths, six coordinates), and a fitted EA of
    1e19 N pulls them against each other with tensions that grow with it (no finite
    equilibrium to pose the platform at). For the poses of a fit whose stiffness the data
    left at that bound (an effect's evidence: the set without it)."""
    sp = fit.space
    rigid = np.array([p.kind == "inverse" and fit.phi[k] * RIGID_FACTOR <= p.scale
                      for k, p in enumerate(sp.params)], dtype=bool)
    return sp.robot(np.where(rigid, sp.neutral, fit.phi)) if rigid.any() else \
        cleaned_robot(fit)


def named_robot(model: Robot, effects: list[dict]) -> Robot:
    """The model with exactly the parameters the report names (what --write-model writes)."""
    from controller.effects import apply_effects

    params: dict[str, dict[str, float]] = {}
    for e in effects:
        params.setdefault(e["name"], {}).update(e["params"])
    return apply_effects(model, params)


def split_samples(s: Samples, init_pose: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Train / validation / test / validation region.

    Samples are split by block (a target with all its visits, or one move), never
    inside one: every k-th block is the **test** set (the figures the report prints
    come from it; selection and fits never see it), another every k-th the
    **validation** set (an effect must improve it to be chosen). The validation
    region (the quarter of the training samples farthest from the initialisation pose
    along the workspace's long axis) is refitted without, as a second check. Small
    recordings (fewer than 2k blocks) have no test set; fewer than 3k, no validation.
    """
    k = HOLDOUT_EVERY
    blocks = np.unique(s.block[~s.is_init])
    test_b = blocks[k // 2::k] if len(blocks) >= 2 * k else blocks[:0]
    rest = np.setdiff1d(blocks, test_b)
    valid_b = rest[k - 1::k] if len(blocks) >= 3 * k else rest[:0]
    test = np.flatnonzero(np.isin(s.block, test_b) & ~s.is_init)
    valid = np.flatnonzero(np.isin(s.block, valid_b) & ~s.is_init)
    train = np.setdiff1d(np.arange(s.n), np.concatenate([test, valid]))
    pos = np.where(np.isfinite(s.pose_meas[:, :3]), s.pose_meas[:, :3], s.pose_des[:, :3])
    region = np.zeros(0, dtype=int)
    if np.isfinite(pos).all(axis=1).sum() >= 12 and len(valid):
        spread = np.nanmax(pos, axis=0) - np.nanmin(pos, axis=0)
        ax = int(np.argmax(spread[:2]))
        side = 1.0 if init_pose[ax] < np.nanmedian(pos[:, ax]) else -1.0
        key = side * (pos[:, ax] - init_pose[ax])
        cut = np.nanquantile(key[train], 0.75)
        region = np.intersect1d(train, np.flatnonzero(key > cut))
        if len(region) > 0.4 * len(train):
            region = np.zeros(0, dtype=int)
    return train, valid, test, region


def split_heldout(s: Samples, init_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Train (with validation) / test / validation region (kept for callers)."""
    train, valid, test, region = split_samples(s, init_pose)
    return np.union1d(train, valid), test, region


def prepare_outputs(write_model: str | Path | None, plots: str | Path | None = None,
                    created: list[Path] | None = None) -> None:
    """Check before the fit that the outputs can be written (raises OSError naming them):
    a real write in their directory (:mod:`bench.outputs`), not the permission bits. The
    directories made for them are appended to ``created`` (to remove them, with
    :func:`bench.outputs.remove_created`, if the diagnosis then fails); on an OSError
    none is left."""
    from bench.outputs import output_dir_problem, output_file_problem, remove_created

    made: list[Path] = []
    problem = None
    if write_model is not None:
        problem = output_file_problem(write_model, "--write-model", made)
    if problem is None and plots is not None:
        problem = output_dir_problem(plots, "--plots", made)
    if problem is not None:
        remove_created(made)
        raise OSError(problem)
    if created is not None:
        created.extend(made)


#: what ``mismatch.encoder_reference`` says of each reading of d_model(p0)
REFERENCES = {
    "description": "the model's geometric lengths to the exit points of the description",
    "deflected": "the model's geometric lengths to the exit points its compliant masts "
                 "take under the tensions at initialisation",
}


def _encoder_reference(rec: Recording, rm: ResidualModel, say: Progress) -> str:
    """Which reading of d_model(p0) the recording's controller referenced its encoders to
    (a key of :data:`REFERENCES`), ``rm`` set to it. For a model with compliant masts the
    conventions' "geometric length" is either to the description's exit points (this
    project's controller) or to those its masts take under the tensions at initialisation
    (a controller that models the deflection everywhere): centimetres apart on a large
    robot, read as length offsets on every cable if taken the wrong way. The model as it
    is decides, without a parameter: the other reading where its chi-square is lower by
    :data:`BIC_TIE`."""
    from controller.cycle import deflected_reference_lengths

    model = rec.robot
    if not model.compliant or not rm.has_len.any():
        return "description"
    try:
        alt = deflected_reference_lengths(model, rec.init_pose, rec.init_tensions)
    except ValueError:
        return "description"
    if not np.isfinite(alt).all() or np.abs(alt - rm.reference).max() < 1e-6:
        return "description"
    idx = np.flatnonzero(rm.has_len)

    def chi2() -> float:
        w = rm.whitened(model, idx)
        return float(np.sum(np.nan_to_num(w) ** 2))

    plain = rm.reference
    c0 = chi2()
    rm.set_reference(alt)
    c1 = chi2()
    if c1 < c0 - BIC_TIE:
        say(f"encoders referenced to the exit points the model's masts take at "
            f"initialisation (chi-square {c1:.4g} against {c0:.4g} to the description's)")
        return "deflected"
    rm.set_reference(plain)
    return "description"


def _cells_at_anchor(rm: ResidualModel, selector: Selector, sel: Selection,
                     candidates: list[str], train: np.ndarray, holdouts: list[np.ndarray],
                     say: Progress, pool: Executor | None) -> tuple[Selector, Selection]:
    """Where a sag is chosen and load cells read the tensions: the selection again with the
    cells at the platform anchors instead of the exit points (the format is silent on
    where a cell sits; along a sagging cable the tension differs by the cable's weight
    between the ends, a few newtons that depend on the pose: read the wrong way, offsets
    on every cell are named beside the sag). Kept where its BIC is lower by
    :data:`BIC_TIE` and it still names the sag; reported in ``mismatch.load_cells``."""
    if "cable_sag" not in sel.effects or not rm.any_tau:
        return selector, sel
    # first the chosen effects (and without the cells' calibration, which may have taken
    # up the weight between the ends) refitted with the cells at the anchors: where neither
    # gains the bar, no selection again (a whole search of sagging cables: 42 -> 159 s)
    rm.cells_at = "anchor"
    sets = [tuple(sel.effects)] + ([tuple(e for e in sel.effects
                                          if e != "load_cell_calibration")]
                                   if "load_cell_calibration" in sel.effects else [])
    pre = [fit_effects(ParamSpace(selector.model, tuple(sorted(k))), rm, train,
                       _warm(tuple(sorted(k)), sel.fit)) for k in sets]
    if not min(f.bic for f in pre) < sel.fit.bic - BIC_TIE:
        say(f"the load cells read at the exit points (the chosen effects with the cells at "
            f"the anchors: BIC {min(f.bic for f in pre):.1f} against {sel.fit.bic:.1f})")
        rm.cells_at = "exit"
        return selector, sel
    say("a sag with load cells: the selection again with the cells at the platform anchors")
    again = Selector(rm, train, holdouts, progress=say, pool=pool)
    sel2 = again.run(candidates, tuple(e for e in sel.effects
                                       if e != "load_cell_calibration"))
    if "cable_sag" in sel2.effects and sel2.fit.bic < sel.fit.bic - BIC_TIE:
        say(f"the load cells read the tensions at the platform anchors (BIC "
            f"{sel2.fit.bic:.1f} against {sel.fit.bic:.1f} at the exit points)")
        return again, sel2
    say(f"the cells read at the exit points (BIC {sel.fit.bic:.1f} against "
        f"{sel2.fit.bic:.1f} at the anchors)")
    rm.cells_at = "exit"
    return selector, sel


def _later_slips(rm: ResidualModel, selector: Selector, sel: Selection,
                 candidates: list[str], train: np.ndarray, holdouts: list[np.ndarray],
                 steps: list[dict], say: Progress, pool: Executor | None
                 ) -> tuple[Selector, Selection]:
    """The selection again where a chosen length offset fits far better from a later time
    on (:func:`bench.diagnosis.slips.later_starts`, asked of the chosen set and of the
    offset alone: the effects chosen beside it may have taken up its early misfit): a slip
    no step in time showed. The search starts from the first selection's effects (its
    backward steps drop those that took up the misfit; half the time of a search from
    the model). Kept where its BIC, charged one parameter per slip time, is
    lower than the first selection's by :data:`BIC_ENTER` (the same noise, so the two
    compare); else the first selection stands and the slip times are as they were."""
    charge = float(np.log(max(sel.fit.n_eff or 2.0, 2.0)))
    later = _later_offsets(rm, selector, sel, train, charge)
    if not later:
        return selector, sel
    before = rm.slip_times.copy()
    times = before.copy()
    for c, (t_s, _, gain) in later.items():
        times[c] = t_s
        say(f"cable {rm.model.cable_ids[c]}: its length offset fits better from t = "
            f"{t_s:.1f} s on (chi-square {gain:.0f} lower) than from the initialisation")
    # first the chosen set (with the offsets) refitted with the slips, one fit: where even
    # it does not gain the bar, no selection again (the later starts are first-order
    # readings of one fit; a selection again costs a whole search: 66 of 207 s on a
    # no-tension case whose three "slips" fit worse, 12480)
    key = tuple(sorted(set(sel.effects) | {"cable_length_offset"}))
    space = ParamSpace(selector.model, key)
    ref = sel.fit if tuple(sorted(sel.effects)) == key else \
        fit_effects(space, rm, train, _warm(key, sel.fit))
    rm.slip_times = times
    pre = fit_effects(space, rm, train, _warm(key, ref))
    if not pre.bic + charge * len(later) < ref.bic - BIC_ENTER:
        say(f"the chosen effects with those slips fit no better (BIC {pre.bic:.1f} against "
            f"{ref.bic:.1f}): the first selection stands")
        rm.slip_times = before
        return selector, sel
    say("the selection again with the slips")
    again = Selector(rm, train, holdouts, progress=say, pool=pool)
    again.restarted = set(selector.restarted)
    sel2 = again.run(candidates, tuple(sel.effects))
    if sel2.fit.bic + charge * len(later) < sel.fit.bic - BIC_ENTER:
        for c, (t_s, size, gain) in later.items():
            steps.append({"cable": rm.model.cable_ids[c], "t_s": t_s, "step_m": size,
                          "z": float(np.sqrt(gain)), "source": "fit"})
        return again, sel2
    say(f"the slips at those times fit no better (BIC {sel2.fit.bic:.1f} against "
        f"{sel.fit.bic:.1f}): the first selection stands")
    rm.slip_times = before
    return selector, sel


def _later_offsets(rm: ResidualModel, selector: Selector, sel: Selection, train: np.ndarray,
                   charge: float) -> dict[int, tuple[float, float, float]]:
    """The cables (index) whose length offset fits better from a later time on by more
    than :data:`BIC_ENTER` plus ``charge`` (one slip time's BIC): (time [s], size [m],
    chi-square gain), from the chosen set and from the offset alone
    (:func:`bench.diagnosis.slips.later_starts`)."""
    later: dict[int, tuple[float, float, float]] = {}
    if "cable_length_offset" in sel.effects:
        fits = (sel.fit, selector.fit(("cable_length_offset",), sel.fit))
        over_drift = None
    else:
        # no offset chosen: one beside the chosen effects, starting later, may be a slip
        # they took up in another form (a drum scale, a softer cable; without a tracker, a
        # drift on the slipped cable) where it beats a drift of that cable too
        # (every cable's offset free: a slip's constant part can be too small to keep)
        key = tuple(sorted((*sel.effects, "cable_length_offset")))
        # (from the search's fit of that set where it has one: the same minimum without the
        # pruning, a few steps away; 12973: 8 of 90 s from the chosen set's values)
        near = selector.cache.get(key)
        phi0 = near.phi if near is not None and near.chi2 <= sel.fit.chi2 \
            else _warm(key, sel.fit)
        fits = (fit_effects(ParamSpace(selector.model, key), rm, train, phi0, prune=False),)
        over_drift = BIC_ENTER
    # the cables whose offsets the set named; and from the offset alone (which moves every
    # cable) the strongest later start at each time, named or not: the chosen set may have
    # held the slipped cable's offset and taken up its misfit in other forms (case 12450,
    # no tracker: a 6 mm slip of cable 41 fitted as offsets on the seven others and two
    # cables' E*A; from the offset alone 41's later start gains 296, cable 31's 62 at the
    # same time, its smear through the estimated poses)
    named = set(slips.offset_cables(fits[0], rm.model.cable_ids).values())
    for n_fit, f in enumerate(fits):
        found = slips.later_starts(rm, f, train, BIC_ENTER + charge, over_drift)
        if n_fit > 0:
            top: dict[float, int] = {}
            for c, got in found.items():
                if got[0] not in top or got[2] > found[top[got[0]]][2]:
                    top[got[0]] = c
            found = {c: found[c] for c in top.values()}
        for c, got in found.items():
            if (c in named or n_fit > 0) and (c not in later or got[2] > later[c][2]):
                later[c] = got
    return later

def _pretension(rm: ResidualModel, selector: Selector, sel: Selection, candidates: list[str],
                train: np.ndarray, holdouts: list[np.ndarray], say: Progress,
                pool: Executor | None) -> tuple[Selector, Selection]:
    """Without load cells at initialisation, the tensions there are the model's tension
    distribution only by assumption: another controller's (or an operator's) pretension
    shortens the cables' unstretched lengths at referencing by their stretch, constant
    offsets in the wrench matrix's null space that length offsets (or other effects) would
    take up. Where one chosen effect, dropped, is replaced by such internal forces
    (:attr:`~controller.robot.Robot.init_internal`, fitted beside the others) at a BIC
    less than :data:`BIC_ENTER` higher (the nuisance comes free, an effect stays by the
    selection's bar over it), or fitted beside all the chosen effects at a lower BIC (off
    the initialisation pose a pretension's stretch reads as scale-like errors of a few
    cables: drum scales beside the true one), or the chosen length offsets are fewer with
    them (:func:`_sparse_offsets`; the chosen effects then start from that gauge), the
    selection runs again with them in every fit (from the other effects) and is kept where
    its BIC, charged BIC_ENTER per effect, is lower; else the first selection stands.

    Every BIC here is taken against the fit of the chosen effects and the tensions
    together, by the evidence the parameters' own errors give (:func:`~.select.honest_bic`):
    a continuous recording's rows between two stops share the visit's error of the lengths,
    and their chi-square's drop counts it several times (IPAnema-class, 0.6 mm per visit:
    six exit-point offsets lowered the plain BIC by 64 below the tensions' alone, by a
    Wald statistic of 34 on 24 parameters beside them)."""
    k = rm.init_basis.shape[1]
    if rm.tau0 is not None or k == 0 or not sel.effects or rm.model.init_internal is not None:
        return selector, sel
    model = rm.model
    flagged = model.replace(init_internal=np.zeros(k))
    best: tuple[float, tuple[str, ...]] | None = None
    rests = [tuple(sorted(c for c in sel.effects if c != e)) for e in sel.effects]
    whole = tuple(sel.fit.space.effects)
    rests.append(whole)  # beside every chosen effect (it pays its parameters' BIC)
    jobs = []
    for rest in rests:
        phi0 = _warm(rest, sel.fit)
        space = ParamSpace(flagged, rest)
        jobs.append((space, None if phi0 is None else np.concatenate([phi0, np.zeros(k)])))
    if pool is not None and len(jobs) > 1:
        say(f"fitting {len(jobs)} sets with the tensions at initialisation on the process pool")
    fits = fits_side_by_side(pool, rm, [(space, train, phi0, {}) for space, phi0 in jobs])
    # each judged against the fit of every chosen effect beside them (``whole``, which
    # holds every other): the chi-square's differences by the evidence the parameters'
    # own errors give (:func:`~.select.honest_bic`; rows of a move share the visit's error)
    top = fits[rests.index(whole)]
    ref = honest_bic(sel.fit, top)
    # (the nuisance enters free in an effect's place, an effect stays only by the
    # selection's bar over it: each set charged BIC_ENTER per effect; beside them all the
    # nuisance must lower the BIC)
    charged = ref + BIC_ENTER * len(sel.effects)
    for rest, f in zip(rests, fits, strict=True):
        h = honest_bic(f, top) if rest != whole else 0.0
        say(f"{' + '.join(rest) or 'the model'} with the tensions at initialisation fitted: "
            f"BIC {f.bic:.1f} against {sel.fit.bic:.1f} (by the parameters' own errors "
            f"{h:.1f} against {ref:.1f})")
        h += BIC_ENTER * len(rest)
        if h < charged and (best is None or h < best[0]):
            best = (h, rest)
    sparse = _sparse_offsets(rm, sel.fit, flagged, train)
    if sparse is not None:
        h = honest_bic(sparse, top)
        say(f"{' + '.join(sel.fit.space.effects)} with the tensions at initialisation fitted "
            f"and fewer length offsets: BIC {sparse.bic:.1f} against {sel.fit.bic:.1f}")
        if h >= ref:
            sparse = None
        elif best is None or h + BIC_ENTER * (len(whole) + 1) < best[0]:
            best = (h + BIC_ENTER * (len(whole) + 1), whole)
    if best is None:
        return selector, sel
    say("the tensions at initialisation are not the distribution's: the selection again "
        "with them fitted")
    rm.model = flagged
    again = Selector(rm, train, holdouts, progress=say, pool=pool)
    again.restarted = set(selector.restarted)
    if sparse is not None and best[1] == whole:
        # (the search starts from the fit in that gauge: the same effects with the tensions
        # fitted, its offsets the fewest)
        again.cache[best[1]] = sparse
    sel2 = again.run(candidates, best[1])
    # (a set the whole fit does not hold: the plain BICs)
    h2, h1 = (honest_bic(sel2.fit, top), ref) if within(sel2.fit, top) \
        else (sel2.fit.bic, sel.fit.bic)
    if h2 + BIC_ENTER * len(sel2.effects) < h1 + BIC_ENTER * len(sel.effects):
        return again, sel2
    say(f"it fits no better (BIC {sel2.fit.bic:.1f} against {sel.fit.bic:.1f}): the first "
        f"selection stands")
    rm.model = model
    return selector, sel


def _sparse_offsets(rm: ResidualModel, fit: FitResult, flagged: Robot, train: np.ndarray
                    ) -> FitResult | None:
    """``fit`` (length offsets among its effects, the tensions at initialisation the
    distribution's) with those tensions fitted too and the offsets in their sparsest
    gauge. A change ``lam`` of the internal forces at initialisation shortens the cables'
    unstretched lengths from then on by ``G lam`` (``G`` (n, k) [m/N], to first order), as
    offsets would: the data fix the offsets only up to ``G``'s columns. Of those readings,
    the one with the fewest offsets that differ from zero (every set of k offsets zeroed in
    turn) is fitted, the others held at zero, where it has fewer than ``fit``. None where
    it has not (or the fit has no length offsets)."""
    space = fit.space
    ix = space.indices("cable_length_offset")
    k = rm.init_basis.shape[1]
    if not len(ix) or not k:
        return None
    H = space.robot(fit.phi)
    h = 10.0  # [N]
    try:
        u0 = rm._init_unstretched(H)
        G = np.column_stack([(rm._init_unstretched(H.replace(init_internal=h * np.eye(k)[j]))
                              - u0) / h for j in range(k)])
    except ValueError:
        return None
    cable = [rm.model.cable_ids.index(space.params[i].key[len("dl_"):]) for i in ix]
    d, se = fit.phi[ix], fit.stderr[ix]
    ok = np.isfinite(se) & (se > 0)
    if ok.sum() <= k:
        return None
    # the reading with the most offsets at zero: each set of k offsets zeroed exactly (the
    # internal forces that do it), the others counted where within two standard errors of
    # zero; ties to the smallest weighted sum of absolute offsets
    Gc, dc, w = G[cable][ok], d[ok], 1.0 / se[ok]
    best: tuple[int, float, np.ndarray] | None = None
    for S in itertools.combinations(range(len(dc)), k):
        A = Gc[list(S)]
        if np.linalg.cond(A) > 1e8:
            continue
        lam_s = np.linalg.solve(A, dc[list(S)])
        left = np.abs(dc - Gc @ lam_s) * w
        got = (int(np.sum(left < 2.0)), -float(left.sum()), lam_s, S)
        if best is None or got[:2] > best[:2]:
            best = got
    if best is None:
        return None
    lam, S = best[2], best[3]
    d2 = d - G[cable] @ lam
    zero_new = ok & (np.abs(d2) < 2.0 * se)
    zero_old = ok & (np.abs(d) < 2.0 * se)
    if zero_new.sum() <= zero_old.sum():
        return None
    fspace = ParamSpace(flagged, space.effects)
    phi0 = np.concatenate([fit.phi, lam])
    phi0[ix] = np.where(zero_new, 0.0, d2)
    # the k offsets zeroed exactly fix the gauge (held: the data cannot tell them from the
    # internal forces); the others are fitted, and pruned where they vanish
    hold = np.concatenate([~np.isfinite(fit.stderr), np.zeros(k, dtype=bool)])
    hold[ix[np.flatnonzero(ok)[list(S)]]] = True
    return fit_effects(fspace, rm, train, phi0, hold=hold)


def stream_slips(rec: Recording, s: Samples, rm: ResidualModel) -> list[dict]:
    """Slips during moves (:func:`bench.diagnosis.locate.row_jumps`) in the raw rows of
    ``s``'s stream, their residuals under ``rm``'s model with its encoder reference, each
    row's pose estimated (no tracker) or tensions fitted (no load cells) as the samples'
    are; after the initialisation."""
    if s.stream is None:
        return []
    model = rm.model
    stream_rm = ResidualModel(s.stream, model, rec.init_pose, rec.init_tensions,
                              reference=rm.reference)
    stream_rm.keep_absorbed = True
    sb = stream_rm.blocks(model)
    return locate.row_jumps(s.stream, np.where(sb.slack, np.nan, sb.length), model.cable_ids,
                            t_after=rm.init_end, absorbed=stream_rm.absorbed)


def diagnose(path: str | Path, progress: Progress | None = None, pool: Executor | None = None,
             write_model: str | Path | None = None) -> Diagnosis:
    """Diagnose the recording directory ``path``. With a process ``pool`` (its workers fit
    candidate sets side by side), this process's own fits split their finite-difference
    columns with a forked child while the pool waits (:func:`.fit.split_columns`)."""
    with split_columns(pool) if pool is not None else nullcontext():
        return _diagnose(path, progress, pool, write_model)


def _diagnose(path: str | Path, progress: Progress | None, pool: Executor | None,
              write_model: str | Path | None) -> Diagnosis:
    """:func:`diagnose` in this process: read, noise, steps, selection, the named effects
    settled, then the report's sections."""
    say = progress or (lambda m: None)
    rec, streams, excluded, s = _read(path, say)
    rm, reference = _noise_model(rec, s, streams, say)
    model = rec.robot
    base_blocks = rm.blocks(model)
    steps = _steps(rec, s, rm, base_blocks, say)
    changes = noise.separate(rm, say)  # systematic differences of replicates: not noise
    high_freq = noise.floor_assumed(rm, say)
    nz = rm.noise_summary()
    say("baseline: equilibrium of every sample under the recording's model")
    base_fw = rm.forward(model)
    pose_noise = _pose_noise(s, base_fw)

    train, valid, test, region = split_samples(s, rec.init_pose)
    candidates = candidate_effects(rm)
    selector, sel = _select(rm, candidates, train, [valid, region], steps, say, pool)
    fit_idx = np.union1d(train, valid)
    got, not_named = _named(rm, selector, sel, candidates, fit_idx, rec, changes, pool, say)
    sel, final, fitted, fit_fw = got.sel, got.final, got.fitted, got.fit_fw
    leftover = probes.with_not_named(got.leftover, not_named, unexplained.fit_figures(
        rm, rm.blocks(fitted), final.n_free)[0] if got.leftover is None and not_named else None)
    if leftover is not None:
        say("unexplained: " + leftover["summary"])

    notes: list[str] = []  # said at the end of the summary
    if len(sel.effects) > 1:  # (each effect's "without" fit below, side by side)
        selector.prefetch([tuple(c for c in sel.effects if c != e) for e in sel.effects],
                          sel.fit, refits=True)
    effects = [_effect_entry(rm, selector, got, e, candidates, fit_idx, test, notes)
               for e in sel.effects]
    if leftover is not None:
        for entry in effects:
            entry["provisional"] = True
    noise.annotate(effects, changes)
    _provisional_by_frame(effects)

    baseline = pose_figures(base_fw)
    baseline["wrench_rms"] = wrench_rms(model, s, raw=True)
    baseline["exit_point_rms_m"] = exit_rms(rm, model)
    mismatch = _mismatch(rec, s, rm, base_blocks, base_fw, steps, sel, leftover, nz,
                         pose_noise, excluded, effects)
    mismatch["encoder_reference"] = {"reading": reference, "means": REFERENCES[reference]}
    mismatch["noise"] |= {"high_frequency": high_freq,
                          "systematic": [c.entry() for c in changes]}
    mismatch["streams"] = streams
    _summary_notes(mismatch, rm, reference, notes)
    model_path, write_error = _write_corrected(model, effects, path, write_model, say)
    report = {
        "format": FORMAT,
        "recording": str(path),
        "samples": int(s.n),
        "baseline": baseline,
        "mismatch": mismatch,
        "effects": effects,
        "unexplained": leftover,
        "fitted": _fitted_figures(rm, final, fitted, fit_fw, fit_idx, test, baseline),
        "model": model_path,
    }
    return Diagnosis(plain(report), rec, s, rm, sel, fitted, base_fw, fit_fw, test,
                     write_error)


def _read(path: str | Path, say: Progress) -> tuple[Recording, dict, list[dict], Samples]:
    """The recording at ``path`` (long logs block by block), its streams, the values
    excluded (the first five said) and its static samples; a RecordingError without any."""
    rec, streams, excluded = read_conditioned(path)
    for e in excluded[:5]:
        if "row" in e:
            say(f"excluded: recording.csv line {e['row']}, column {e['column']}: "
                f"{e['value']:g} ({e['why']})")
    say("streams: " + summary_line(streams))
    s = prepare(rec)
    if s.n == 0:
        raise RecordingError(f"{rec.path / 'recording.csv'}: no static samples (every row "
                             f"accelerates or is in a state where the platform moves)")
    inf = s.info
    say(f"{rec.n_samples} rows -> {s.n} samples ({inf['dwell_samples']} dwells, "
        f"{inf['path_samples']} rows of moves) in {s.n_targets} replicate groups")
    if inf.get("states_unknown"):
        say("state words the format does not define, read from the data: " + ", ".join(
            f"{w} ({k} rows)" for w, k in inf["states_unknown"].items()))
    return rec, streams, excluded, s


def _noise_model(rec: Recording, s: Samples, streams: dict, say: Progress
                 ) -> tuple[ResidualModel, str]:
    """The residual model of ``s`` under the recording's model, its noise estimated, and
    the encoder reference that fits the recording."""
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.stamp_period_s = frame.stamp_period_s(rec.t, streams)
    rm.estimate_noise(rec.robot)
    reference = _encoder_reference(rec, rm, say)
    nz = rm.noise_summary()
    say(f"noise ({rm.sigma_source}): lengths {nz['length'] * 1e3:.3f} mm, forces "
        f"{nz['force']:.2f} N, exit points {nz['exit'] * 1e3:.2f} mm")
    return rm, reference


def _steps(rec: Recording, s: Samples, rm: ResidualModel, base_blocks, say: Progress
           ) -> list[dict]:
    """The steps in time of the cables' length readings (dwells and, with a stream, jumps
    during moves; load changes and look-alikes sorted out): ``rm.slip_times`` set at them
    and the noise estimated again with the slipped cables' replicate groups split."""
    model = rec.robot
    if not rm.has_len.any():
        return []
    one_sided = base_blocks.slack if base_blocks.slack is not None else False
    steps = locate.steps_in_time(s, np.where(one_sided, np.nan, base_blocks.length),
                                 rm.noise_summary()["length"], model.cable_ids,
                                 t_after=rm.init_end)
    if s.stream is not None:
        seen = {st["cable"] for st in steps}
        steps += [j for j in stream_slips(rec, s, rm) if j["cable"] not in seen]
    steps = slips.choose_alike(rm, slips.without_loads(rm, base_blocks, steps, say))
    if not steps:
        return steps
    slip_at = np.full(model.n_cables, rm.init_end)
    for st in steps:
        slip_at[model.cable_ids.index(st["cable"])] = max(st["t_s"], rm.init_end)
        say(f"cable {st['cable']}: its length reading steps at t = {st['t_s']:.1f} s"
            + (f" (or cable {', '.join(st['alike'])}'s: alike through the estimated poses;"
               " the fit tells whose)" if st.get("alike") else ""))
    rm.slip_times = slip_at
    # the visits of a target on both sides of a step differ by the slip: estimate the noise
    # again (the slipped cable's replicate groups split at its step)
    rm.estimate_noise(model)
    nz = rm.noise_summary()
    say(f"noise, the replicate groups split at the steps: lengths "
        f"{nz['length'] * 1e3:.3f} mm, forces {nz['force']:.2f} N")
    return steps


def _select(rm: ResidualModel, candidates: list[str], train: np.ndarray,
            checks: list[np.ndarray], steps: list[dict], say: Progress,
            pool: Executor | None) -> tuple[Selector, Selection]:
    """The selection on ``train`` (judged on ``checks``), then its second looks: the
    slips after the initialisation, the pretension without load cells, the cells read at
    the anchors."""
    selector = Selector(rm, train, checks, progress=say, pool=pool)
    sel = selector.run(candidates)
    selector, sel = _later_slips(rm, selector, sel, candidates, train, checks, steps, say,
                                 pool)
    selector, sel = _pretension(rm, selector, sel, candidates, train, checks, say, pool)
    return _cells_at_anchor(rm, selector, sel, candidates, train, checks, say, pool)


def _named(rm: ResidualModel, selector: Selector, sel: Selection, candidates: list[str],
           fit_idx: np.ndarray, rec: Recording, changes: list, pool: Executor | None,
           say: Progress) -> tuple[_Settled, list[dict]]:
    """The effects settled on ``fit_idx`` (:func:`_settle`), again without those that
    physics outside the vocabulary stands for (:func:`probes.unneeded`) until none is
    left; and the stands of the effects not named so."""
    left_out: list[str] = []  # effects dropped: never selected again
    got = _settle(rm, selector, sel, candidates, fit_idx, left_out, rec, changes, pool, say)
    not_named: list[dict] = []
    while gone := [q for q in probes.unneeded((got.leftover or {}).get(
            "effects_in_question", [])) if q["effect"] in got.sel.effects]:
        got, dropped = _without_unneeded(rm, selector, got, gone, candidates, fit_idx,
                                         left_out, rec, changes, pool, say)
        not_named += dropped
    return got, not_named


def _effect_entry(rm: ResidualModel, selector: Selector, got: _Settled, e: str,
                  candidates: list[str], fit_idx: np.ndarray, test: np.ndarray,
                  notes: list[str]) -> dict:
    """The report's entry of the named effect ``e``: its parameters, errors and intervals,
    the held-out evidence (the corrected model without ``e`` on ``test``), and the
    alternatives declared; a frame motion's sentence goes to ``notes``."""
    sel, params, intervals = got.sel, got.params, got.intervals
    name = report_name(e)
    rest = tuple(c for c in sel.effects if c != e)
    without = posable_robot(selector.fit(rest, sel.fit))
    before = pose_figures(rm.forward(without, test), test)["pose_rms_m"] if len(test) else None
    after = pose_figures(got.fit_fw, test)["pose_rms_m"] if len(test) else None
    ho = sel.heldout.get(e, {})
    entry = {
        "name": name,
        "params": params[e],
        "stderr": got.errs[e],
        "interval95": {k: list(v[:2]) for k, v in intervals[e].items()},
        "interval_method": {k: v[2] for k, v in intervals[e].items()},
        "interval_quantile": {k: v[3] for k, v in intervals[e].items()},
        "explains": EXPLAINS[name],
        "evidence": {"heldout_pose_rms_before_m": before,
                     "heldout_pose_rms_after_m": after,
                     "delta_bic": _f(ho.get("delta_bic"))},
        "undetermined": got.undet[e],
        "alternatives": [{"name": report_name(a), "delta_bic": d}
                         for a, d in sel.alternatives.get(e, [])
                         if report_name(a) != name],
    }
    _declare_alternatives(rm, selector, got, e, entry, candidates, fit_idx, notes)
    if name == "cable_length_offset":
        model = rm.model
        late = [(c, t) for c, t in zip(model.cable_ids, rm.slip_times, strict=True)
                if t > rm.init_end and f"dl_{c}" in params[e]]
        if late:
            entry["explains"] += "; from " + ", ".join(f"t = {t:.1f} s on cable {c}"
                                                     for c, t in late)
    if not got.final.success:
        entry["converged"] = False
    return entry


def _declare_alternatives(rm: ResidualModel, selector: Selector, got: _Settled, e: str,
                          entry: dict, candidates: list[str], fit_idx: np.ndarray,
                          notes: list[str]) -> None:
    """The alternatives of ``entry`` (effect ``e``) the gauge declares beside the
    selection's: the rigid frame motion exit offsets form (said in ``notes``), the
    tracker's frame or a translation, a common gain of the load cells."""
    sel, params, name = got.sel, got.params, entry["name"]
    motion = None
    if name == "exit_point_offset":
        motion = frame.frame_motion(rm.model, params[e], params.get("drum_scale"))
        if motion is not None:
            entry["frame_motion"] = motion
            notes.append(frame.sentence(motion))
    for declared in (frame.gauge_alternative(selector, sel, e, candidates, motion),
                     frame.translation_alternative(selector, sel, e, params[e], candidates)):
        if declared is not None:
            entry["alternatives"] = [a for a in entry["alternatives"]
                                     if a["name"] != declared["name"]] + [declared]
    names = [report_name(c) for c in sel.effects]
    if rm.any_tau and ((name == "platform_mass" and "mass" in params[e]) or (
            name == "load_cell_calibration" and "platform_mass" not in names
            and any(k.startswith("gain_") for k in params[e]))):
        alt = _common_gain_alternative(rm, got.final, fit_idx, name)
        if alt is not None and alt["delta_bic"] < BIC_TIE:
            same = [a for a in entry["alternatives"] if a["name"] == alt["name"]]
            if same:  # the selection's refit of it: what it is, said
                same[0]["note"] = alt["note"]
            else:
                entry["alternatives"].append(alt)


def _provisional_by_frame(effects: list[dict]) -> None:
    """Exit offsets (and drum scales) that a tracker's registration or scale would read
    are provisional: the tracker is checked before exit points or drums are moved."""
    motion = next((e["frame_motion"] for e in effects if "frame_motion" in e), None)
    if motion is None:
        return
    for entry in effects:
        if entry["name"] == "exit_point_offset" or (
                motion.get("scale") and entry["name"] == "drum_scale"):
            entry["provisional"] = True


def _fitted_figures(rm: ResidualModel, final: FitResult, fitted: Robot, fit_fw: Forward,
                    fit_idx: np.ndarray, test: np.ndarray, baseline: dict) -> dict:
    """The report's ``fitted`` section: the corrected model's pose, angle, tension and
    exit-point RMS, on the held-out samples too, and the sample counts."""
    fig = pose_figures(fit_fw)
    out = {
        "pose_rms_m": fig["pose_rms_m"],
        "angle_rms_rad": fig["angle_rms_rad"],
        "tension_rms_n": fig["tension_rms_n"],
        "exit_point_rms_m": exit_rms(rm, fitted),
        "heldout_pose_rms_m": pose_figures(fit_fw, test)["pose_rms_m"] if len(test)
        else None,
        "converged": bool(final.success),
        "samples": {"fit": int(len(fit_idx)), "test": int(len(test))},
    }
    if out["pose_rms_m"] is None and baseline["pose_rms_m"] is None:
        out["heldout_pose_rms_m"] = None
    return out


def _summary_notes(mismatch: dict, rm: ResidualModel, reference: str,
                   notes: list[str]) -> None:
    """The load cells' place and the encoder reference in ``mismatch``; ``notes`` (with
    those) appended to its summary."""
    if rm.any_tau:
        mismatch["load_cells"] = {"at": rm.cells_at}
        if rm.cells_at == "anchor":
            notes.append("the load cells read the tensions at the platform anchors, not at "
                         "the exit points (a sagging cable pulls harder at its top by its "
                         "weight between the ends)")
    if reference != "description":
        notes.insert(0, f"the encoders were referenced to {REFERENCES[reference]} (the "
                        "reading of d_model(p0) that fits the recording)")
    if notes:
        mismatch["summary"] = "; ".join([mismatch["summary"].rstrip(". "), *notes]) + "."


def _write_corrected(model: Robot, effects: list[dict], path: str | Path,
                     write_model: str | Path | None, say: Progress
                     ) -> tuple[str | None, str | None]:
    """The corrected model (the named parameters on ``model``) written to ``write_model``
    when asked: its path, or why it could not be written (said)."""
    if write_model is None:
        return None, None
    named = ", ".join(f"{e['name']} ({', '.join(e['params'])})" for e in effects) or "none"
    header = (f"corrected model written by cdpr diagnose from {path}\n"
              f"effects and parameters named by the report: {named}\n"
              "parameters the report did not name keep the recording's model values")
    try:
        return str(save_robot(named_robot(model, effects).replace(
            name=f"{model.name}-corrected"), write_model, header)), None
    except OSError as e:  # checked before the fit; a disk that filled since: say so
        write_error = f"--write-model {write_model}: cannot write: {e.strerror or e}"
        say(write_error)
        return None, write_error


@dataclass
class _Settled:
    """The named effects settled by :func:`_settle`: the selection, its final fit, the
    effects' entries and intervals, the corrected robot and what it leaves unexplained."""

    sel: Selection
    final: FitResult
    params: dict[str, dict]
    errs: dict[str, dict]
    undet: dict[str, list]
    intervals: dict[str, dict]
    fitted: Robot
    fit_fw: Forward
    leftover: dict | None


def _settle(rm: ResidualModel, selector: Selector, sel: Selection, candidates: list[str],
            fit_idx: np.ndarray, left_out: list[str], rec: Recording, changes: list,
            pool: Executor | None, say: Progress) -> _Settled:
    """The final fit of ``sel`` on ``fit_idx`` with the effects whose parameters all vanish
    dropped (``left_out`` grows with them), the intervals, and what the corrected model
    leaves: the probes beside the named effects and the residual tests."""
    model = rm.model
    s = rm.s
    final = _final_fit(selector, sel, fit_idx, say)
    floor_dof: list[np.ndarray] = []
    floor = _reference_var(rm, final, fit_idx, floor_dof)
    params, errs, undet = effect_entries(final, sel.effects, floor)
    # an effect whose parameters all vanish or cannot be fixed is not reported: the least
    # important such effect goes, the others are refitted without it (what it shared with
    # them may become measurable), and so on. When the data need what it took (the others
    # alone fit far worse), the selection goes on from the others without it: effects it
    # imitated, whose parameters the poses can fix, may take its place
    while True:
        empty = [e for e in sel.effects if not params[e]]
        if not empty:
            break
        e = empty[-1]  # effects are sorted by importance
        say(f"dropping {report_name(e)}: no parameter differs from the model")
        rest = tuple(c for c in sel.effects if c != e)
        # (an offset within the encoder reference's uncertainty is that uncertainty: what
        # the data need there is no effect to look for)
        by_reference = bool(effect_entries(final, [e])[0][e])
        needed = not by_reference and selector.fit(rest, sel.fit).bic - sel.fit.bic > BIC_ENTER
        rejected = dict(sel.rejected)
        rejected[report_name(e)] = "no parameter differs measurably from the model"
        again = e in left_out  # dropped before: never select on from it twice
        left_out.append(e)
        if needed and not again:
            say(f"the others fit far worse without {report_name(e)}: selecting on from them "
                f"without it")
            sel = selector.run([c for c in candidates if c not in left_out], rest)
            sel.rejected = rejected | sel.rejected
        else:
            sel.rejected = rejected
            sel.effects = [c for c in sel.effects if c != e]
        final = _final_fit(selector, sel, fit_idx, say)
        floor_dof = []
        floor = _reference_var(rm, final, fit_idx, floor_dof)
        params, errs, undet = effect_entries(final, sel.effects, floor)
    sel.fit = final
    intervals = effect_intervals(final, rm, fit_idx, sel.effects, params, floor, pool, say,
                                 floor_dof[-1])
    fitted = cleaned_robot(final)
    say("fitted: equilibrium of every sample under the corrected model")
    fit_fw = rm.forward(fitted)
    fit_blocks = rm.blocks(fitted)
    say("probing for physics outside the vocabulary beside the named effects")
    try:
        probed = probes.screen(rm, final.space, final.phi, named=params)
    except (ValueError, np.linalg.LinAlgError) as e:  # a check beside the answer: say so
        say(f"the probes could not be evaluated: {e}")
        probed = None
    probed = _lookalike_stands(rm, selector, sel, params, candidates, probed, say)
    leftover = unexplained.analyse(rm, fit_blocks, final.n_free, s, rec.init_pose,
                                   model.pivots, model.mast_ids, fitted, probed)
    leftover = _friction_in_question(rm, final, leftover, probed, params)
    leftover = unexplained.with_changes(leftover, changes, {
        c: float(t) for c, t in zip(model.cable_ids, rm.slip_times, strict=True)
        if t > rm.init_end}, {k[len("dl_"):] for k in params.get("cable_length_offset", {})})
    return _Settled(sel, final, params, errs, undet, intervals, fitted, fit_fw, leftover)


def _without_unneeded(rm: ResidualModel, selector: Selector, got: _Settled, gone: list[dict],
                      candidates: list[str], fit_idx: np.ndarray, left_out: list[str],
                      rec: Recording, changes: list, pool: Executor | None,
                      say: Progress) -> tuple[_Settled, list[dict]]:
    """:func:`_settle` again without the named effects of ``got`` that physics outside the
    vocabulary stands for and that the data do not need beyond it (``gone``,
    :func:`probes.unneeded`): they go to ``sel.rejected`` and ``left_out``; with them, the
    stands dropped. Where another named effect goes with them (:func:`probes.lost_with`:
    the probe cannot take its parameters, yet the refit without the structure they held
    leaves them below the noise; no probe stands for it), nothing is dropped: ``got`` with
    those stands marked (:func:`probes.needed_by_others`), no stand dropped. Of several
    such effects, the first that goes alone (with all its stands) without the loss goes
    (the loop of the caller judges the others again beside the next settle)."""
    names = list(dict.fromkeys(q["effect"] for q in gone))  # (an effect may have two stands)
    sel = copy.copy(got.sel)  # (got stays as it was, should the drop not be made)
    rejected = dict(sel.rejected)
    for q in gone:
        say(f"not naming {report_name(q['effect'])}: a {q['probe']} probe for physics outside "
            f"the vocabulary fits as well in its place (BIC {q['delta_bic']:+.0f}); beside "
            f"the probe it changes the BIC by {-q['needed_beyond_bic']:+.0f}")
        rejected[report_name(q["effect"])] = (
            f"beside physics outside the vocabulary that explains it as well ({q['probe']} "
            f"probe) it changes the BIC by {-q['needed_beyond_bic']:+.0f} only")
    n_left = len(left_out)
    left_out += names
    sel.effects = [c for c in sel.effects if c not in names]
    sel.fit = selector.fit(tuple(sel.effects), sel.fit)
    sel.rejected = rejected
    again = _settle(rm, selector, sel, candidates, fit_idx, left_out, rec, changes, pool, say)
    stood = {q["effect"] for q in (got.leftover or {}).get("effects_in_question", [])}
    lost = probes.lost_with(got.sel.effects, names, again.sel.effects, stood)
    if not lost:
        return again, gone
    del left_out[n_left:]
    for e in names if len(names) > 1 else []:  # one of them may go without the loss
        alone = _without_unneeded(rm, selector, got, [q for q in gone if q["effect"] == e],
                                  candidates, fit_idx, left_out, rec, changes, pool, say)
        if alone[1]:
            return alone
    say(f"naming {', '.join(report_name(e) for e in names)} after all: without "
        f"{'them' if len(names) > 1 else 'it'} {', '.join(report_name(e) for e in lost)} "
        f"no longer stands out, and the probe cannot take its parameters")
    leftover = dict(got.leftover or {})
    leftover["effects_in_question"] = probes.needed_by_others(
        leftover.get("effects_in_question", []), gone, [report_name(e) for e in lost])
    return dataclasses.replace(got, leftover=leftover), []


def _friction_in_question(rm: ResidualModel, final: FitResult, leftover: dict | None,
                          probed, named: dict[str, dict] | None = None) -> dict | None:
    """``leftover`` with the named effects that the load cells' friction it found
    (``load_cell_direction_cables``) stands for (:func:`probes.friction_stands`) put in
    question: a finding each, and ``effects_in_question``."""
    cables = (leftover or {}).get("load_cell_direction_cables")
    if not cables:
        return leftover
    seen = {st.effect for st in (probed[1] if probed else [])}
    try:
        more = [st for st in probes.friction_stands(rm, final.space, final.phi, cables,
                                                           named)
                if st.effect not in seen]
    except (ValueError, np.linalg.LinAlgError):  # a check beside the answer
        return leftover
    if not more:
        return leftover
    findings = leftover["findings"] + probes.findings([], more)
    asked = leftover.get("effects_in_question", []) + [st.as_dict() for st in more]
    return leftover | {"findings": findings, "summary": "; ".join(findings),
                       "effects_in_question": asked}


def _lookalike_stands(rm: ResidualModel, selector: Selector, sel: Selection,
                      params: dict[str, dict], candidates: list[str],
                      probed: tuple[list, list] | None, say: Progress
                      ) -> tuple[list, list] | None:
    """``probed`` (:func:`probes.screen` at the final fit) with the stands found through a
    named effect's declared look-alikes (:func:`frame.lookalikes`): where the set with the
    look-alike in the effect's place fits within :data:`BIC_ENTER` of the selection's (the
    data prefer the named effect by less than any effect needs to enter), the probes are
    screened at that set's fit too, and a probe that stands for the look-alike there
    (:func:`probes.through_lookalike`) puts the named effect in question. A one-parameter
    tracker frame must not take, as a look-alike with more parameters would not, the
    residual that physics outside the vocabulary left."""
    if probed is None:
        return None
    results, stands = probed
    for e in sel.effects:
        if any(st.effect == e for st in stands):
            continue
        rest = tuple(c for c in sel.effects if c != e)
        for a in frame.lookalikes(e, params.get(e, {}), candidates):
            if a in rest or not compatible(rest, a):
                continue
            f = selector.fit(rest + (a,), sel.fit)
            d = float(f.bic - sel.fit.bic)
            if not d < BIC_ENTER:
                continue
            try:
                st = probes.through_lookalike(rm, e, a, f.space, f.phi, d)
            except (ValueError, np.linalg.LinAlgError) as err:
                say(f"the probes beside {report_name(a)} could not be evaluated: {err}")
                continue
            if st is not None:
                stands = [*stands, st]
                break
    return results, stands


def plain(obj):
    """``obj`` (the report) with numpy scalars and arrays made Python numbers and lists,
    so that ``json.dumps`` takes it as it is (a numpy bool in a probe's finding once cost a
    user the whole report at the last step)."""
    if isinstance(obj, dict):
        return {k: plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _final_fit(selector: Selector, sel: Selection, idx: np.ndarray, say: Progress) -> FitResult:
    """The chosen effects refitted on the training and validation samples (warm start), each
    group of parameters then checked by a refit that holds it
    (:func:`bench.diagnosis.fit.profile_pruning`), the errors the tensions at initialisation
    move in added (:func:`init_tensions_error`), and a tracker latency estimated beside the
    cables' common error by direction (:func:`bench.diagnosis.frame.latency_beside_direction`)."""
    return frame.latency_beside_direction(_refit(selector, sel, idx, say), selector.rm, idx)


def _refit(selector: Selector, sel: Selection, idx: np.ndarray, say: Progress) -> FitResult:
    """:func:`_final_fit` before the latency's step."""
    from bench.diagnosis.fit import fit_effects
    from bench.diagnosis.select import _warm

    key = tuple(sorted(sel.effects))
    start = selector.cache.get(key)
    if start is None:
        start = selector.fit(key)
    if np.array_equal(np.sort(idx), np.sort(selector.train)):
        # nothing held out for validation: the selection's fit is the final one, with
        # the parameters that others stand in for freed (their errors are the report's)
        if len(start.space):
            res = fit_effects(start.space, selector.rm, idx, start.phi,
                              hold=~np.isfinite(start.stderr), free_traded=True)
            if res.success and res.chi2 <= start.chi2 + 1e-6 * max(start.chi2, 1.0) \
                    and res.n_free > start.n_free:
                start = selector.gauge_floor(res, idx)
        return _pruned(selector, start, idx, say)
    space = ParamSpace(selector.model, key)
    say(f"final fit of {' + '.join(report_name(e) for e in key) or 'the model as it is'} on "
        f"{len(idx)} samples")
    # what the selection's fit held (the data cannot fix it) stays held
    held = ~np.isfinite(start.stderr) if len(space) else None
    res = selector.gauge_floor(fit_effects(space, selector.rm, idx, _warm(key, start),
                                           hold=held, free_traded=True), idx)
    if not res.success:
        say(f"the final fit did not converge: {res.message}")
        return res
    return _pruned(selector, res, idx, say)


def _pruned(selector: Selector, fit: FitResult, idx: np.ndarray, say: Progress) -> FitResult:
    """``fit`` pruned by profile refits, with the tensions at initialisation's error."""
    from bench.diagnosis.fit import profile_pruning

    return init_tensions_error(selector.rm, profile_pruning(fit, selector.rm, idx, say,
                                                            free_traded=True), idx, say)


def init_tensions_error(rm: ResidualModel, fit: FitResult, idx: np.ndarray,
                        say: Progress = lambda _m: None) -> FitResult:
    """``fit`` with the error that the tensions at initialisation, taken as the model's
    tension distribution, move into its parameters added to its ``bias_var`` (fit units
    squared), where the recording has no load cells there and the selection did not fit
    those tensions (:func:`_pretension`; :attr:`~controller.robot.Robot.init_internal`).

    The encoders are referenced with the unstretched lengths of the tensions at
    initialisation. Without load cells the diagnosis assumes the distribution's; internal
    forces of another controller's or an operator's pretension (tens of newtons) shorten
    every cable by its stretch, a millimetre on a 10 m cable of 6e5 N, from then on: held at
    zero, they move into exit points and pulley radii (a ROCASPECT case with 77 N, recorded
    ten times: exit offsets at rms z 1.59, 83 % of the intervals holding the truth; 1.08 and
    97 % with this error). As for a parameter the pruning
    held (:func:`~bench.diagnosis.fit.pruning_bias_var`): the fit again with those internal
    forces free beside the same parameters on the samples ``idx``, and the squared error
    holding them moves into each parameter, estimated without bias from their departures
    (at least the kept parameter's error beside them where the data cannot fix them)."""
    from bench.diagnosis.fit import pruning_bias_var, unfixed_parameters

    k = rm.init_basis.shape[1]
    if rm.tau0 is not None or k == 0 or rm.model.init_internal is not None \
            or fit.space.model.init_internal is not None or not len(fit.space) \
            or not fit.success:
        return fit
    p = len(fit.phi)
    space = ParamSpace(fit.space.model.replace(init_internal=np.zeros(k)), fit.space.effects)
    # what the fit held (the data cannot fix it, or the pruning held it) stays held
    free = np.isfinite(fit.stderr)
    if fit.curvature_cov is not None:
        free &= np.diag(fit.curvature_cov) > 0
    hold = np.concatenate([~free, np.zeros(k, dtype=bool)])
    full = fit_effects(space, rm, idx, np.concatenate([fit.phi, np.zeros(k)]), hold=hold,
                       prune=False)
    if not full.success:
        say(f"the fit with the tensions at initialisation free did not converge: "
            f"{full.message}; the errors leave them out")
        return fit
    weak = np.arange(len(full.phi)) >= p
    unfixed = unfixed_parameters(space, full.stderr)
    extra = pruning_bias_var(full, weak, space.neutral, weak & unfixed)[:p]
    out = fit.copy()
    out.bias_var = extra if out.bias_var is None else out.bias_var + extra
    return out


def _pose_noise(s: Samples, fw: Forward) -> float | None:
    """3-D repeatability of the platform position [m]: spread of the forward pose error
    (measured minus predicted, smooth in the pose) within replicate groups."""
    sd = pooled_std(fw.pose_err[:, :3], s.target)
    if sd is None or not np.isfinite(sd).all():
        return None
    return float(np.sqrt(np.sum(sd ** 2)))


def _common_gain_alternative(rm: ResidualModel, fit: FitResult, idx: np.ndarray,
                             named: str = "platform_mass") -> dict | None:
    """The other side of the load cells' gauge: a gain shared by every load cell in place of
    the fitted mass change (``named`` platform_mass), or a mass change in place of the
    fitted gains' common part (their geometric mean; ``named`` load_cell_calibration). In
    statics the two are the same (W tau_meas / g balances m g); only the cables' stretch
    (and with it the likelihood's Jacobian term, :mod:`bench.diagnosis.likelihood`) tells
    them apart. Its chi-square change is evaluated, one parameter for one, not refitted."""
    from bench.diagnosis.likelihood import StretchLikelihood

    robot = fit.space.robot(fit.phi)
    model = rm.model
    if named == "platform_mass":
        alt, ratio = gauge.mass_as_common_gain(robot, model)
        out = {"name": "load_cell_calibration",
               "note": f"a gain of {ratio:.4f} shared by every load cell instead of the mass"}
    else:
        moved = gauge.common_gain_as_mass(robot, model)
        if moved is None:
            return None
        alt, common = moved
        out = {"name": "platform_mass",
               "note": f"a mass of {alt.mass:.4g} kg instead of a gain of {common:.4f} shared "
                       f"by every load cell"}
    lik = StretchLikelihood(rm, idx)
    r_fit = lik.residuals(robot)
    r_alt = lik.residuals(alt)
    d = float(r_alt @ r_alt - r_fit @ r_fit)  # one parameter for one: no penalty change
    if not np.isfinite(d):
        return None
    return out | {"delta_bic": d}


def _mismatch(rec: Recording, s: Samples, rm: ResidualModel, blocks, base_fw: Forward,
              steps: list[dict], sel: Selection, leftover: dict | None, noise: dict,
              pose_noise: float | None, excluded: list[dict],
              effects: list[dict] | None = None) -> dict:
    model = rec.robot
    tension = base_fw.tension_err if np.isfinite(base_fw.tension_err).any() else None
    dist = np.linalg.norm(base_fw.pose_err[:, :3], axis=1)
    if not np.isfinite(dist).any() and rm.has_exit.any():
        dist = np.sqrt(np.nanmean(np.linalg.norm(blocks.exit, axis=2) ** 2, axis=1))
        label = "exit_point_rms_m"
    else:
        label = "pose_rms_m"
    regions = locate.regions(s, dist, rec.init_pose, model.pivots, model.mast_ids, label)
    growth = locate.growth_from_init(s, dist, rec.init_pose)
    untested = untested_effects(rm)
    noise_out = {k: float(v) for k, v in noise.items()} | {"source": rm.sigma_source}
    if pose_noise is not None:
        noise_out["pose_m"] = pose_noise
    out = {
        "summary": _summary(rec, s, rm, blocks, dist, label, growth, steps, sel, leftover,
                            noise, untested, effects),
        "by_cable": locate.by_cable(model.cable_ids, blocks.length, tension),
        "by_mast": locate.by_mast(model.mast_ids, model.mast_index, blocks.length),
        "regions": regions[:6],
        "noise": noise_out,
        "steps": steps,
        "signatures": {report_name(e): float(v) for e, v in _explained(sel).items()},
        "imitation": {report_name(e): {report_name(a): round(v, 3) for a, v in
                                       sorted(d.items(), key=lambda kv: kv[1])}
                      for e, d in sel.imitation.items()},
        "samples": dict(s.info),
        "untested": untested,
        "excluded": excluded,
    }
    if growth:
        out["growth_from_init"] = growth
    pre = _fitted_pretension(rm, sel)
    if pre is not None:
        out["init_tensions"] = pre
    return out


def _fitted_pretension(rm: ResidualModel, sel: Selection) -> dict | None:
    """The tensions at initialisation the fits took (where :func:`_pretension` found them
    other than the distribution's): per cable, fitted and the distribution's [N]."""
    if rm.model.init_internal is None:
        return None
    from controller.statics import init_statics

    H = sel.fit.space.robot(sel.fit.phi)
    try:
        dist = init_statics(H, rm.init_pose).tensions
        tau = rm._init_tensions(H)
    except ValueError:
        return None
    tau = dist if tau is None else tau
    ids = rm.model.cable_ids
    return {"source": "fitted: no load cells at initialisation",
            "tension_n": {c: float(v) for c, v in zip(ids, tau, strict=True)},
            "distribution_n": {c: float(v) for c, v in zip(ids, dist, strict=True)}}


def _explained(sel: Selection) -> dict[str, float]:
    """Fraction of the baseline chi-square each effect explains alone (linearised)."""
    base = sel.baseline.chi2
    n = sel.baseline.n_res
    out = {}
    for e, d in sel.screening.items():
        p = len(ParamSpace(sel.baseline.space.model, (e,)))
        dchi = d - p * math.log(max(n, 2))
        v = float(np.clip(-dchi / base, 0.0, 1.0)) if base > 0 else 0.0
        # (the two forms of the cables' stretch are one effect of the report: the better)
        if v >= max((out[c] for c in out if report_name(c) == report_name(e)), default=0.0):
            out = {c: w for c, w in out.items() if report_name(c) != report_name(e)}
            out[e] = v
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _summary(rec: Recording, s: Samples, rm: ResidualModel, blocks, dist: np.ndarray,
             label: str, growth: dict | None, steps: list[dict], sel: Selection,
             leftover: dict | None, noise: dict, untested: list[str],
             effects: list[dict] | None = None) -> str:
    """The report's one-paragraph summary: the verdict, where the residuals lie, the
    steps in time, the effects' signatures and alternatives, what the data cannot tell."""
    what = "pose error" if label == "pose_rms_m" else "exit-point error"
    r = locate.rms(dist)
    parts = _verdict(rm, sel, leftover, what, r)
    if sel.effects and r is not None:
        assumed = "" if rm.sigma_source == "replicate visits" else \
            ", assumed: no replicate visits to measure it"
        parts.append(f"{what} {r * 1e3:.1f} mm RMS against a noise level of "
                     f"{noise['length' if label == 'pose_rms_m' else 'exit'] * 1e3:.2f} mm"
                     f"{assumed} (reduced chi-square {sel.baseline.reduced_chi2:.3g})")
    parts += _where(rec.robot, blocks, growth, steps, sel)
    sig = _explained(sel)
    if sel.effects and sig:
        top = [f"{report_name(e)} ({v:.0%})" for e, v in list(sig.items())[:3] if v > 0.05]
        if top:
            parts.append("the residuals match the signatures of " + ", ".join(top)
                         + " (share explained alone, linearised)")
    if sel.effects:
        parts.append("left out: " + ", ".join(report_name(e) for e in sel.effects))
    parts += _alternatives_said(sel, effects or [])
    for e, why in sel.rejected.items():
        parts.append(f"{report_name(e)} improved the fit but {why}: not reported")
    parts += _untold(rm, sel, untested)
    return "; ".join(parts) + "."


def _verdict(rm: ResidualModel, sel: Selection, leftover: dict | None, what: str,
             r: float | None) -> list[str]:
    """The summary's first words: what the vocabulary does not explain, or that the model
    explains the data within the noise (with the tensions at initialisation fitted)."""
    red = sel.baseline.reduced_chi2
    names = [report_name(e) for e in sel.effects]
    if leftover is not None:
        return ["the effect vocabulary does not explain the data: " + leftover["summary"]
                + (f"; the effects named ({', '.join(names)}) take what they can and are "
                   f"provisional" if names else "")]
    if not sel.effects and rm.model.init_internal is not None:
        return [f"with the tensions at initialisation fitted (below), the model explains "
                f"the data within the noise (reduced chi-square {red:.2f}; under the "
                f"tension distribution's" + (f": {what} {r * 1e3:.2f} mm RMS" if r else "")
                + ")"]
    if not sel.effects:
        return [f"the model explains the data within the noise (reduced chi-square "
                f"{red:.2f}" + (f", {what} {r * 1e3:.2f} mm RMS" if r else "") + ")"]
    return []


def _where(model: Robot, blocks, growth: dict | None, steps: list[dict],
           sel: Selection) -> list[str]:
    """Where the residuals lie: growing away from the initialisation pose, largest on
    some cables; and the steps in time of the length readings."""
    parts = []
    if growth and sel.effects and growth["near_rms"] and growth["far_rms"]:
        if growth["far_rms"] > 1.5 * growth["near_rms"]:
            parts.append(f"it grows away from the initialisation pose: "
                         f"{growth['near_rms'] * 1e3:.1f} mm within {growth['near_m']:.1f} m of "
                         f"it, {growth['far_rms'] * 1e3:.1f} mm beyond {growth['far_m']:.1f} m")
    if sel.effects and np.isfinite(blocks.length).any():
        per = np.sqrt(np.nanmean(blocks.length ** 2, axis=0))
        worst = np.argsort(-per)[:2]
        if per[worst[0]] > 2 * np.median(per):
            masts = sorted({model.mast_ids[model.mast_index[k]] for k in worst})
            parts.append(f"length residuals are largest on cable{'s' if len(worst) > 1 else ''} "
                         f"{', '.join(model.cable_ids[k] for k in worst)} "
                         f"(mast{'s' if len(masts) > 1 else ''} {', '.join(masts)})")
    for st in steps:
        # step_m is the change of the cable's length offset dl (added to the unstretched
        # length): the reading itself jumped the other way
        parts.append(f"cable {st['cable']}'s length reading jumps by about "
                     f"{-st['step_m'] * 1e3:+.1f} mm at t = {st['t_s']:.0f} s (a slip or an "
                     f"encoder jump: dl_{st['cable']} {st['step_m'] * 1e3:+.1f} mm from then on"
                     + (f"; or cable {', '.join(st['alike'])}'s, alike through the estimated "
                        "poses" if st.get("alike") else "") + ")")
    return parts


def _alternatives_said(sel: Selection, effects: list[dict]) -> list[str]:
    """The alternatives of the named effects (the selection's, the gauge's and look-alikes
    the report declared, a common cell gain) and the imitations above 80 %, each once."""
    parts = []
    for e, alts in sel.alternatives.items():
        for a, d in alts:
            if report_name(a) == report_name(e):
                continue
            how = SEPARATE.get(frozenset({report_name(e), report_name(a)}),
                               "more poses spread over the workspace")
            parts.append(f"{report_name(a)} fits about as well as {report_name(e)} (delta BIC "
                         f"{d:+.1f}); {how} would separate them")
    for entry in effects:
        for alt in entry.get("alternatives", []):
            if alt.get("gauge") == "tracker_frame":
                parts.append(f"{alt['name']} is the other side of the tracker frame's gauge "
                             f"of {entry['name']} (delta BIC {alt['delta_bic']:+.1f}): "
                             f"{alt['note']}")
            elif alt.get("lookalike") == "tracker_frame":
                parts.append(f"{alt['name']} reads as {entry['name']} on these poses (delta "
                             f"BIC {alt['delta_bic']:+.1f}): {alt['note']}")
            elif "note" in alt:
                how = SEPARATE[frozenset({"load_cell_calibration", "platform_mass"})]
                parts.append(f"{alt['name']} fits about as well as {entry['name']} (delta BIC "
                             f"{alt['delta_bic']:+.1f}: {alt['note']}): a gain common to every "
                             f"load cell and the platform's mass are one in the statics, only "
                             f"the cables' stretch tells them apart; {how} would")
    said: set[tuple[str, str]] = set()
    for e, imit in sel.imitation.items():
        close = [a for a, v in sorted(imit.items(), key=lambda kv: -kv[1]) if v > 0.8
                 and a not in [x for x, _ in sel.alternatives.get(e, [])]
                 and report_name(a) != report_name(e)]
        for a in close:
            if (report_name(a), report_name(e)) in said:  # two forms of one effect: once
                continue
            said.add((report_name(a), report_name(e)))
            parts.append(f"on these poses {report_name(a)} can imitate {imit[a]:.0%} of "
                         f"{report_name(e)}'s signature")
    return parts


def _untold(rm: ResidualModel, sel: Selection, untested: list[str]) -> list[str]:
    """What the data cannot tell: effects untested without a tracker or without tensions;
    the tensions at initialisation fitted where no load cells read them."""
    parts = []
    if not rm.has_pose.any() and rm.est_pose.any():
        tested = [report_name(e) for e in dict.fromkeys(candidate_effects(rm))]
        parts.append("without tracker poses the poses were estimated from the encoder lengths "
                     "and measured tensions: " + ", ".join(dict.fromkeys(tested))
                     + " are tested; " + ", ".join(untested) + " cannot be told from such data")
    elif not rm.any_tau:
        parts.append("without tensions the internal forces were fitted to the cables' stretch; "
                     + ", ".join(untested) + " cannot be told from such data")
    pre = _fitted_pretension(rm, sel)
    if pre is not None:
        d = np.array(list(pre["tension_n"].values())) - np.array(list(
            pre["distribution_n"].values()))
        parts.append(f"the tensions at initialisation (no load cells read them) were fitted: "
                     f"{float(np.sqrt(np.mean(d ** 2))):.0f} N RMS off the tension "
                     f"distribution's (another pretension; the encoders were referenced "
                     f"under it); load cells at initialisation would measure them")
    return parts
