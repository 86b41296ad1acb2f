"""The tracker's own frame and latency beside the exit points.

The platform's pose is measured in the tracker's frame. A tracker registered to the base
frame with a small rotation and translation off (a misregistered frame, a moved tracker
between the survey and the campaign) reads every pose through that motion: the robot, seen
from the tracker, has every exit point moved by it. The vocabulary names that error
``tracker_frame`` (:mod:`controller.effects`); fitted as exit-point offsets instead, they
form a rigid motion ``d_ij = omega x a_ij + t`` (small angles). The two are one between
poses (the gauge), not quite over a recording: the encoders are referenced at the
initialisation pose, which the controller commands in F_b (the tracker does not place
it), and the frame's rotation tilts gravity in the load cells' force balance; exit points
measured with the tracker tell them apart too. The selection never fits both in one set;
the report names the one the data prefer and declares the other
(:func:`gauge_alternative`). Where named exit-point offsets are such a motion
(:func:`frame_motion`), the report says so: the exit points may be where the description
puts them and the tracker's registration off.

The tracker's latency (``tracker_latency``) is seen only while the platform moves: each
moving sample carries the rate of its measured pose (:func:`pose_rates`), and the
recording can test the latency where some do (:func:`tracker_candidates`).
"""

from __future__ import annotations

import numpy as np

#: the rigid motion must take at least this share of the offsets' sum of squares ...
SHARE = 0.9
#: ... on at least this many cables (over at least three masts)
MIN_CABLES = 4


def rigid_part(exits: np.ndarray, offsets: np.ndarray, scale: bool = False
               ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The rigid motion (with ``scale``: the similarity) closest to exit-point offsets
    (small angles and scale change, least squares).

    ``exits`` (n, 3) [m] exit points in F_b, ``offsets`` (n, 3) [m]. Returns the rotation
    vector ``omega`` (3,) [rad] about the exits' centroid, the translation ``t`` (3,) [m] of
    the centroid, the scale change ``sigma`` [-] about it (0 without ``scale``), and the
    share (0..1) of the offsets' sum of squares the motion takes."""
    a = np.asarray(exits, float)
    d = np.asarray(offsets, float)
    c = a.mean(axis=0)
    r = a - c
    # d_k = omega x r_k + sigma r_k + t = -[r_k]x omega + sigma r_k + t
    rows = []
    for rk in r:
        rx = np.array([[0.0, -rk[2], rk[1]], [rk[2], 0.0, -rk[0]], [-rk[1], rk[0], 0.0]])
        rows.append(np.hstack([-rx, np.eye(3)] + ([rk[:, None]] if scale else [])))
    A = np.vstack(rows)
    x, *_ = np.linalg.lstsq(A, d.ravel(), rcond=None)
    total = float(d.ravel() @ d.ravel())
    left = d.ravel() - A @ x
    share = 1.0 - float(left @ left) / total if total > 0 else 0.0
    return x[:3], x[3:6], float(x[6]) if scale else 0.0, share


def frame_motion(model, params: dict[str, float],
                 drums: dict[str, float] | None = None) -> dict | None:
    """Where the named exit-point offsets ``params`` (``dx_ij`` ... [m]) of ``model`` are one
    rigid motion of the frame (:data:`SHARE` of them, on :data:`MIN_CABLES` cables or more of
    three masts or more), what it is: ``rotation_rad`` (3,) about the exits' centroid,
    ``translation_m`` (3,), ``scale`` 0, ``share``; else None. Offsets the report did not
    name are zero.

    A tracker whose length scale is off by ``sigma`` reads the robot scaled by 1 + sigma
    about its station: every exit point moved by the similarity and every cable's length
    change read 1 + sigma times too short. Where the named drum scales ``drums``
    (``s_ij``) are all within a third of sigma of 1 + sigma and the similarity takes
    :data:`SHARE` of the offsets, that is said instead (``scale`` sigma)."""
    n = model.n_cables
    d = np.zeros((n, 3))
    moved = np.zeros(n, dtype=bool)
    for key, v in params.items():
        axis, cid = key[1], key[3:]
        if key[0] != "d" or axis not in "xyz" or cid not in model.cable_ids:
            continue
        k = model.cable_ids.index(cid)
        d[k, "xyz".index(axis)] = v
        moved[k] = True
    masts = {model.mast_index[k] for k in np.flatnonzero(moved)}
    if moved.sum() < MIN_CABLES or len(masts) < 3:
        return None
    omega, t, sigma, share = rigid_part(model.exits, d)
    if share < SHARE and drums and len(drums) == n:
        omega, t, sigma, share = rigid_part(model.exits, d, scale=True)
        s = np.array(list(drums.values())) - 1.0
        if not (share >= SHARE and np.all(np.abs(s - sigma) <= abs(sigma) / 3)):
            return None
    elif share < SHARE:
        return None
    return {"rotation_rad": [float(v) for v in omega], "translation_m": [float(v) for v in t],
            "scale": float(sigma), "share": round(share, 4)}


def sentence(motion: dict) -> str:
    """The summary's words for a frame motion."""
    rot = float(np.linalg.norm(motion["rotation_rad"])) * 1e3
    tr = float(np.linalg.norm(motion["translation_m"])) * 1e3
    if motion.get("scale"):
        return (f"the exit-point offsets and the drum scales are what a laser tracker whose "
                f"length scale is off by {motion['scale']:+.1e} reads (the offsets a "
                f"similarity of the exit points, {100 * motion['share']:.0f} % of them; every "
                f"drum scale near 1 {motion['scale']:+.1e}): check the tracker's scale (its "
                f"weather station, a reference length) before moving exit points or drums")
    return (f"the exit-point offsets move the exit points together as one rigid body "
            f"(a rotation of {rot:.2f} mrad and a translation of {tr:.1f} mm take "
            f"{100 * motion['share']:.0f} % of them): a laser tracker whose frame is "
            f"registered that far off would read nearly the same (its fit, tracker_frame, is "
            f"the declared alternative); measuring exit points or fixed targets on the base "
            f"with the tracker would tell them apart")


#: [s] the window of the polynomial whose slope is a moving row's pose rate
RATE_WINDOW_S = 1.0


def pose_rates(rec, rows: np.ndarray, fresh: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """(len(rows), 6) time derivatives [m/s, rad/s] of the measured pose at the path
    ``rows`` of recording ``rec``, from the ``fresh`` rows (tracker values of their own,
    sorted) of the same move (``moves``: the move id of each fresh row): the slope of a
    least-squares polynomial over :data:`RATE_WINDOW_S` within the move
    (:func:`bench.streams.local_derivative`; a line through a move of fewer than five
    rows), so that a turn between moves does not bend it. Zero where none is known (a
    row without a tracker pose, a move of one row): the latency cannot be seen there."""
    from bench.streams import local_derivative

    out = np.zeros((len(rows), 6))
    if not len(rows) or not len(fresh):
        return out
    rate = np.zeros((rec.n_samples, 6))
    pose = rec.pose_meas
    for g in np.unique(moves):
        r = fresh[moves == g]
        r = r[np.isfinite(pose[r]).all(axis=1)]
        if len(r) >= 5:
            d, _ = local_derivative(rec.t[r], pose[r], 1, RATE_WINDOW_S)
            rate[r] = np.nan_to_num(d)
        elif len(r) >= 2 and np.ptp(rec.t[r]) > 0:
            rate[r] = np.polyfit(rec.t[r] - rec.t[r].mean(), pose[r], 1)[0]
    return rate[rows]


def tracker_candidates(rm) -> list[str]:
    """The tracker's own errors a recording can see (:class:`ResidualModel` ``rm``): its
    frame where measured poses meet encoder lengths (or measured exit points), its latency
    where some of those poses were taken while the platform moved (a pose rate)."""
    pose = rm.has_pose & (rm.has_len | rm.has_exit.any(axis=1))
    if not pose.any():
        return []
    out = ["tracker_frame"]
    if (pose & rm.has_len & np.any(rm.s.pose_rate[:, :3] != 0.0, axis=1)).any():
        out.append("tracker_latency")
    return out


#: a latency below this share of the moving samples' spacing in time is no finding
LATENCY_FLOOR = 0.1


def latency_floor_s(rm) -> float:
    """[s] the smallest tracker latency the recording of ``rm`` can name:
    :data:`LATENCY_FLOOR` times the period of its length readings (``rm.stamp_period_s``:
    the encoders' stream, or the rows'). A row's time stamp says when it was written, not
    when within its period each sensor sampled; an offset between the streams well below
    that period is the logger's (or the drives') convention of stamping, not a tracker
    that lags. 0 where the period is unknown."""
    period = getattr(rm, "stamp_period_s", None)
    return float(LATENCY_FLOOR * period) if period and np.isfinite(period) else 0.0


def stamp_period_s(t: np.ndarray, streams: dict | None) -> float | None:
    """[s] the period of a recording's length readings: the encoders' stream's where the
    recording holds streams at their own rates (``streams``, :func:`bench.streams.condition`'s
    report), else the median spacing of the rows' time stamps ``t`` [s]."""
    enc = ((streams or {}).get("streams") or {}).get("encoders") or {}
    if enc.get("period_s"):
        return float(enc["period_s"])
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(np.median(dt)) if dt.size else None


def material(rm, effect: str, values: dict[str, float]) -> bool:
    """Whether the tracker's error ``effect`` (fitted ``values``) is one the recording of
    ``rm`` can name: a ``tracker_latency`` of at least :func:`latency_floor_s`. True for
    every other effect."""
    if effect != "tracker_latency":
        return True
    return abs(values.get("dt", 0.0)) >= latency_floor_s(rm)


#: the two sides of the tracker frame's gauge (a rigid motion of every exit point)
GAUGE_PAIR = {"tracker_frame": "exit_point_offset", "exit_point_offset": "tracker_frame"}


def gauge_alternative(selector, sel, effect: str, candidates: list[str],
                      motion: dict | None) -> dict | None:
    """The other side of the tracker frame's gauge for the named ``effect`` of the selection
    ``sel`` (:class:`bench.diagnosis.select.Selection`): ``exit_point_offset`` for a named
    ``tracker_frame``, ``tracker_frame`` for exit-point offsets that form one rigid motion
    (``motion``, :func:`frame_motion`). A rigid motion of every exit point reads as the
    tracker's frame moved the other way: the two differ only by the gravity the frame's
    rotation tilts (the load cells' force balance) and by exit points measured with the
    tracker. The swapped set is fitted (``selector.fit``, from the selection's fit) and
    its BIC change returned as an alternative entry ``{"name", "delta_bic", "gauge",
    "note"}``, whatever its size (declared, not a near tie). None where the pair does not
    apply or the other is no candidate."""
    other = GAUGE_PAIR.get(effect)
    if other is None or other not in candidates or (effect == "exit_point_offset"
                                                    and motion is None):
        return None
    swapped = tuple(c for c in sel.effects if c != effect) + (other,)
    fit = selector.fit(swapped, sel.fit)
    how = ("the same lengths between poses; the encoders' reference at the initialisation "
           "pose (commanded in F_b, not measured), the gravity the frame's rotation tilts and "
           "exit points measured with the tracker tell them apart")
    note = (f"every exit point moved by one rigid motion instead of the tracker's frame "
            f"({how})") if other == "exit_point_offset" else \
        (f"the tracker's frame registered off by that rigid motion instead of the exit "
         f"points ({how})")
    return {"name": other, "delta_bic": float(fit.bic - sel.fit.bic), "gauge": "tracker_frame",
            "note": note}


#: the tracker frame's translations (a frame fixed by these alone moves every pose alike)
TRANSLATION_KEYS = frozenset({"tx", "ty", "tz"})


def lookalikes(effect: str, reported: dict[str, float], candidates: list[str]) -> list[str]:
    """The effects that read as the named tracker error ``effect`` (its ``reported``
    parameters): the other side of the frame's gauge (:data:`GAUGE_PAIR`), and, for a
    ``tracker_frame`` that the data fix by translations only, ``cable_length_offset``: a
    translation ``t`` of every measured pose changes cable i's length by ``u_i . t``
    (``u_i`` its unit vector), nearly the same at poses close together, so per-cable
    length offsets read the same on a small campaign. Only candidates are listed."""
    if effect != "tracker_frame":
        return []
    out = [GAUGE_PAIR[effect]]
    if reported and set(reported) <= TRANSLATION_KEYS:
        out.append("cable_length_offset")
    return [a for a in out if a in candidates]


def translation_alternative(selector, sel, effect: str, reported: dict[str, float],
                            candidates: list[str]) -> dict | None:
    """``cable_length_offset`` as the declared alternative of a ``tracker_frame`` fixed by
    translations only (:func:`lookalikes`): the set with it in the frame's place fitted
    from the selection's fit, its BIC change returned (whatever its size) as an entry
    ``{"name", "delta_bic", "lookalike": "tracker_frame", "note"}``. None where it does not
    apply."""
    if "cable_length_offset" not in lookalikes(effect, reported, candidates):
        return None
    swapped = tuple(c for c in sel.effects if c != effect) + ("cable_length_offset",)
    fit = selector.fit(swapped, sel.fit)
    return {"name": "cable_length_offset", "delta_bic": float(fit.bic - sel.fit.bic),
            "lookalike": "tracker_frame",
            "note": "the tracker's frame fixed by a translation only: on poses close together "
                    "a translation of every measured pose changes each cable's length by "
                    "nearly the same amount at every pose, as per-cable length offsets do "
                    "(poses spread over the workspace, or a rotation the data fix, tell them "
                    "apart)"}


def latency_beside_direction(fit, rm, idx: np.ndarray):
    """``fit`` (:class:`bench.diagnosis.fit.FitResult` on the samples ``idx`` of ``rm``) with
    its ``tracker_latency`` estimated beside the cables' length error by the direction of
    their last move (hysteresis, a winch's backlash: a cable reads ``-h/2`` short while it
    pays out, ``+h/2`` while it reels in).

    While the platform moves at a steady speed, a latency ``dt`` changes cable i's length
    residual by ``dt * dl_i/dt``, and a direction error by ``h/2 * sign(dl_i/dt)``: the same
    sign on every row, told apart only by the speeds. Held at zero, the direction error
    goes into the latency (always toward a shorter one: ``-h/2 sum|v| / sum v^2``; the
    intervals of generated continuous campaigns with 0.02 to 0.1 mm of hysteresis held the
    truth 74 % of the time, every miss low). Freed as a linear column (one level for every
    cable: a winch's hysteresis acts with one sign on every winch, and one level keeps the
    latency's speeds across the cables; :meth:`ResidualModel.direction_columns` on every
    sample with lengths, summed), the Gauss-Newton step moves the fit's free parameters to the
    joint minimum and the covariance is the joint one (:func:`bench.diagnosis.fit.
    standard_errors`, the same error model), the curvature too; the latency is marked
    ``beside_nuisance`` (its linearised interval is the joint fit's: profile refits of the
    set, which hold the direction error at zero, would measure the biased valley). The fit
    is returned unchanged where it holds no free latency or no sample with a known
    direction.

    ``chi2``, ``bic`` and ``n_free`` stay those of ``fit`` (the set without the direction
    level) on purpose: the selection compares them with fits of other sets that hold no
    direction level (``report._lookalike_stands``, the gauge and translation alternatives'
    ``delta_bic``), and those comparisons stay like for like. Only ``phi`` and the errors
    are the joint model's."""
    from dataclasses import replace

    space = fit.space
    free = np.flatnonzero(np.isfinite(fit.stderr))
    lat = [k for k in free if space.params[k].effect == "tracker_latency"]
    if not lat:
        return fit
    H = space.robot(fit.phi)
    steps = rm.length_steps(H, idx)
    cols = rm.direction_columns(H, idx, steps, every=True)
    if cols is None:
        return fit
    X = cols[0].sum(axis=1, keepdims=True)  # one level for every cable
    if not np.linalg.norm(X) > 0:
        return fit
    phi, S, se, nu, curv = _joint_step(fit, rm, idx, free, X, rm.whiten(steps[0], idx), H)
    p = len(free)
    stderr, cov = fit.stderr.copy(), fit.cov.copy()
    stderr[free] = se[:p]
    cov[np.ix_(free, free)] = S[:p, :p]
    dof = None if fit.stderr_dof is None else fit.stderr_dof.copy()
    if dof is not None and nu:
        dof[free] = nu[0][:p]
    curv_all = None
    if fit.curvature_cov is not None:
        curv_all = fit.curvature_cov.copy()
        curv_all[np.ix_(free, free)] = curv
    beside = np.zeros(len(phi), dtype=bool)
    beside[lat] = True
    return replace(fit, phi=phi, stderr=stderr, cov=cov, stderr_dof=dof,
                   curvature_cov=curv_all, beside_nuisance=beside)


def _joint_step(fit, rm, idx: np.ndarray, free: np.ndarray, X: np.ndarray, r: np.ndarray,
                H) -> tuple[np.ndarray, np.ndarray, np.ndarray, list, np.ndarray]:
    """:func:`latency_beside_direction`'s Gauss-Newton step of ``fit``'s ``free``
    parameters with the whitened columns ``X`` (per metre) freed beside them, from the
    whitened residuals ``r`` of ``H`` (the fitted robot) on ``idx``: the new fit-space
    values (within the bounds), the joint covariance and standard errors (free parameters
    then ``X``'s; the error model of :func:`bench.diagnosis.fit.standard_errors`), their
    degrees of freedom
    (a list as that function appends them) and the free parameters' joint curvature."""
    from bench.diagnosis import fit as F

    space = fit.space

    def fun(z: np.ndarray) -> np.ndarray:
        phi = fit.phi.copy()
        phi[free] = z
        return rm.whitened(space.robot(phi), idx)

    J = F.fd_jacobian(fun, fit.phi[free], r, space.scale[free] * 1e-2, space.lo[free],
                      space.hi[free], rm.frozen)
    Ja = np.hstack([J, X])
    sc = np.concatenate([space.scale[free], np.full(X.shape[1], F.DIRECTION_SCALE_M)])
    step = -np.linalg.lstsq(Ja * sc, r, rcond=None)[0] * sc
    r_new = r + Ja @ step
    lost = rm.dof_lost(idx)
    errors = F.error_structure(rm, idx, lost, H)
    nu: list[np.ndarray] = []
    S, se = F.standard_errors(Ja, float(r_new @ r_new), errors.n_eff - lost, sc, r_new,
                             errors.stretches, errors, nu)
    p = len(free)
    phi = fit.phi.copy()
    phi[free] = np.clip(phi[free] + step[:p], space.lo[free], space.hi[free])
    curv = F.curvature(Ja, sc)[:p, :p]
    return phi, S, se, nu, curv
