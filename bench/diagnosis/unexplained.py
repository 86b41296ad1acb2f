"""What the best model leaves: residuals above the noise that the vocabulary does not explain.

After the effects are chosen and fitted, the residuals of the corrected model are
tested against the noise, as a whole and for structure a real robot can have
that the effect vocabulary lacks:

- **level**: reduced chi-square of the fitted model over every sample (held-out
  ones included), against its spread for the residual degrees of freedom and the
  uncertainty of the noise estimate itself;
- **cables / masts**: a cable (or a mast's cables) whose residuals stand out;
- **direction of motion**: a cable whose residual differs with the direction of
  its last length change (backlash, friction): a two-group comparison;
- **time**: residuals that trend with time (thermal drift, creep): a regression on
  time within replicate groups (the model's error at a pose cancels there; on
  independent clusters of samples when few are replicated), per cable and common to
  all;
- **load cells by direction of motion**: a load cell that reads differently while its
  cable pays out and while it reels in (friction between the cell and the platform,
  e.g. on a pulley): the force balance's residuals regressed on each cable's force
  direction signed by its last move (:func:`_cell_direction`);
- **regions** of the workspace where the residual is largest.

:func:`analyse` returns the report's ``unexplained`` object, or None when the
model explains the data within the noise.
"""

from __future__ import annotations

import math

import numpy as np

from bench.diagnosis import locate, probes
from bench.diagnosis.residuals import Blocks, ResidualModel

#: the fitted model leaves clearly more than the noise above this reduced chi-square ...
LEVEL = 1.5
#: ... when it also stands this many standard deviations above 1
LEVEL_Z = 4.0
#: without replicate visits the noise is an assumed repeatability (``residuals.DEFAULTS``),
#: which a winch's may exceed twice: the level alone is a finding above this reduced
#: chi-square only (the residuals twice the assumed noise)
LEVEL_ASSUMED = 4.0
#: a structured residual (direction, time) is declared at this significance ...
STRUCT_Z = 8.0
#: ... when it is also this large against the noise (half the difference, or the drift)
STRUCT_SIZE = 1.0
#: a cable stands out when its residual RMS is this many times the others' median ...
CABLE_RATIO = 2.0


def level_exceeded(ratio: float, dof: float, noise_dof: float, assumed: bool) -> bool:
    """Whether a reduced chi-square ``ratio`` over ``dof`` residual degrees of freedom says
    the model leaves more than the noise: above :data:`LEVEL` (:data:`LEVEL_ASSUMED` when
    the noise is ``assumed``, not measured) and :data:`LEVEL_Z` standard deviations above
    1 (its spread for the residuals' degrees of freedom and the noise estimate's own,
    ``noise_dof``; 0 without one)."""
    sd = math.sqrt(2.0 / max(dof, 1.0) + (2.0 / noise_dof if noise_dof > 0 else 0.0))
    return ratio > (LEVEL_ASSUMED if assumed else LEVEL) and (ratio - 1.0) > LEVEL_Z * sd


def fit_figures(rm: ResidualModel, b: Blocks, n_params: int) -> tuple[dict, float]:
    """How far the fitted model's residual blocks ``b`` (``n_params`` fitted) are from the
    noise: ``{"reduced_chi2", "rms_over_noise", "noise_source"}`` (the ``unexplained``
    object's first fields), and the degrees of freedom of the chi-square (the rows of a
    move count together)."""
    r = rm.whiten(b)
    n_res = float(rm.entry_weights().sum())
    dof = max(n_res - n_params - rm.dof_lost(), 1.0)
    ratio = float(r @ r) / dof
    return {"reduced_chi2": ratio, "rms_over_noise": math.sqrt(max(ratio, 0.0)),
            "noise_source": rm.sigma_source}, dof


def analyse(rm: ResidualModel, b: Blocks, n_params: int, s_regions, init_pose: np.ndarray,
            pivots: np.ndarray, mast_ids: tuple[str, ...], fitted=None,
            probed: tuple[list[probes.ProbeResult], list[probes.Stand]] | None = None
            ) -> dict | None:
    """The ``unexplained`` object for the fitted model's residual blocks ``b`` (``fitted``:
    the corrected robot, for the load cells' direction test; ``probed``: the
    out-of-vocabulary probes tested beside the chosen effects, :func:`probes.screen`)."""
    model = rm.model
    chi = rm.whitened_by_sample(b)
    ok = np.isfinite(chi)
    if not ok.any():
        return None
    out, dof = fit_figures(rm, b, n_params)
    ratio = out["reduced_chi2"]
    # spread of the ratio: chi-square of dof residuals, and a noise estimate of its own dof
    nd = rm.replicate_dof * max(model.n_cables, 1) if rm.sigma_source == "replicate visits" \
        else 0
    assumed = rm.sigma_source != "replicate visits"
    level = level_exceeded(ratio, dof, nd, assumed)
    findings: list[str] = []
    L = _length_over_noise(rm, b)
    if np.isfinite(L).any():
        _by_cable(rm, L, out, findings)
        _by_direction(rm, L, probed, out, findings)
        _by_time(rm, L, probed, out, findings)
    if probed:
        findings.extend(probes.findings(*probed))
        shown = [r.as_dict() for r in probed[0] if r.finding or r.name == "thermal"]
        if shown:
            out["probes"] = shown
        if probed[1]:
            out["effects_in_question"] = [st.as_dict() for st in probed[1]]
    if fitted is not None and rm.any_tau:
        _by_cell_direction(rm, b, fitted, out, findings)
    # where in the workspace
    regions = locate.regions(s_regions, np.sqrt(np.where(ok, chi / np.maximum(
        _entries_per_sample(rm), 1), np.nan)), init_pose, pivots, mast_ids,
        label="rms_over_noise")
    out["regions"] = regions[:4]
    if level:
        findings.insert(0, f"the corrected model leaves residuals {math.sqrt(ratio):.1f} times "
                           f"the noise (reduced chi-square {ratio:.2f})"
                        + (", against an assumed noise" if assumed else ""))
    if not findings:
        return None
    out["findings"] = findings
    out["summary"] = "; ".join(findings)
    return out


def _length_over_noise(rm: ResidualModel, b: Blocks) -> np.ndarray:
    """The length residuals (N, n) in noise units, NaN where a sample has no lengths: a
    residual projected by per-sample unknowns scaled back (:meth:`ResidualModel.
    rank_factor`), a sagging cable's share of its load cell's noise in the noise (as in the
    whitening)."""
    sd = rm.sd["length"][:, None]
    if b.length_extra_sd is not None:
        sd = np.sqrt(sd ** 2 + b.length_extra_sd ** 2)
    L = b.length / sd * rm.rank_factor()[:, None]
    return np.where(rm.has_len[:, None], L, np.nan)


def _by_cable(rm: ResidualModel, L: np.ndarray, out: dict, findings: list[str]) -> None:
    """Per cable and per mast the length residuals' weighted RMS in noise units
    (``by_cable``, ``by_mast``); a finding where one cable stands out from the others'
    median."""
    model, w = rm.model, rm.s.weight
    per = np.array([_wrms(L[:, k], w) for k in range(model.n_cables)])
    out["by_cable"] = {c: _r(v) for c, v in zip(model.cable_ids, per, strict=True)}
    out["by_mast"] = {mid: _r(_wrms(L[:, model.mast_index == i].ravel(),
                                    np.repeat(w, int(np.sum(model.mast_index == i)))))
                      for i, mid in enumerate(model.mast_ids)}
    fin = per[np.isfinite(per)]
    if fin.size >= 3:
        med = float(np.median(fin))
        k = int(np.nanargmax(per))
        if per[k] > CABLE_RATIO * max(med, 1.0) and per[k] > 2.5:
            findings.append(f"cable {model.cable_ids[k]}'s length residual is "
                            f"{per[k]:.1f} times the noise (the others' median "
                            f"{med:.1f})")
            out["cable"] = model.cable_ids[k]


def _by_direction(rm: ResidualModel, L: np.ndarray, probed, out: dict,
                  findings: list[str]) -> None:
    """Per cable its length residual after paying out vs after reeling in (``direction``);
    a finding where one cable's stands out from the others' (every winch's hysteresis is
    part of the noise model) and the probes did not test it."""
    s, w = rm.s, rm.s.weight
    dirs = []
    for k, cid in enumerate(rm.model.cable_ids):
        d = _two_groups(L[:, k], s.direction[:, k], w)
        if d is not None:
            dirs.append((cid, *d))
    if not dirs:
        return
    out["direction"] = {c: {"difference_over_noise": _r(diff), "z": _r(z)}
                        for c, diff, z in dirs}
    strong = [(c, diff, z) for c, diff, z in dirs
              if abs(z) > STRUCT_Z and abs(diff) > STRUCT_SIZE
              and abs(diff) > probes.DIRECTION_RATIO * float(np.median(
                  [abs(o[1]) for o in dirs if o[0] != c] or [0.0]))]
    # (the probes, fitted with the named effects free, judge a cable they tested: this test
    # only one they could not)
    strong = [x for x in strong if not _tested(probed, "direction", x[0])]
    if strong and not _probed(probed, "direction"):
        c, diff, z = max(strong, key=lambda x: abs(x[2]))
        findings.append(f"cable {c}'s length residual depends on the direction of its "
                        f"last move: {abs(diff):.1f} times the noise between paying "
                        f"out and reeling in (z = {abs(z):.0f}; backlash or friction?)")


def _by_time(rm: ResidualModel, L: np.ndarray, probed, out: dict,
             findings: list[str]) -> None:
    """The length residuals' trend with time [noise units over the recording's span], per
    cable and common to the cables (``time``); a finding for a drift the probes did not
    judge. Samples whose errors are independent: each dwell of a dwell campaign (the
    visits of a target are apart in time), stretches of moves otherwise."""
    s, w = rm.s, rm.s.weight
    tt = s.t - np.nanmean(s.t)
    moves = bool((s.kind == 1).any()) and s.cluster is not None and len(s.cluster) == s.n
    clusters = s.cluster if moves else np.arange(s.n)
    span = float(np.ptp(s.t))
    if not span > 0:
        return
    trend = []
    for k, cid in enumerate(rm.model.cable_ids):
        tr = _trend(L[:, k], tt, w, s.target, clusters, span)
        if tr is not None:
            trend.append((cid, *tr))
    seen = np.isfinite(L).sum(axis=1)  # a sample with no cable's length: nan, no warning
    mean = np.where(seen > 0, np.nansum(L, axis=1) / np.maximum(seen, 1), np.nan)
    common = _trend(mean, tt, w, s.target, clusters, span)
    out["time"] = {"span_s": span,
                   "by_cable": {c: {"drift_over_noise": _r(d), "z": _r(z)}
                                for c, d, z in trend}}
    if common is not None:
        out["time"]["common"] = {"drift_over_noise": _r(common[0]), "z": _r(common[1])}
    strong = [(c, d, z) for c, d, z in trend if abs(z) > STRUCT_Z and abs(d) > STRUCT_SIZE]
    strong = [x for x in strong if not _tested(probed, "drift", x[0])]
    if _probed(probed, "thermal", "drift"):
        return  # the probes' findings say it, with the named effects free beside them
    if strong:
        many = len(strong) >= max(3, rm.model.n_cables // 2)
        c, d, z = max(strong, key=lambda x: abs(x[2]))
        if many:
            findings.append(f"the length residuals of {len(strong)} cables drift with "
                            f"time (up to {abs(d):.1f} times the noise over the "
                            f"recording; thermal expansion or creep?)")
        else:
            findings.append(f"cable {c}'s length residual drifts with time "
                            f"({abs(d):.1f} times the noise over the recording)")
    elif common is not None and abs(common[1]) > STRUCT_Z \
            and abs(common[0]) > STRUCT_SIZE and not _tested(probed, "thermal"):
        findings.append(f"the length residuals of the cables drift together with time "
                        f"({abs(common[0]):.1f} times the noise over the recording; "
                        f"thermal expansion or creep?)")


def _by_cell_direction(rm: ResidualModel, b: Blocks, fitted, out: dict,
                       findings: list[str]) -> None:
    """The load cells reading differently by the direction of motion (pulley friction:
    :func:`_cell_direction` on the corrected robot ``fitted``), half-differences in N; a
    finding for the cells :func:`cells_declared` keeps."""
    got = _cell_direction(rm, b, fitted)
    if got is None:
        return
    fr, joint = got
    out["load_cell_direction"] = {c: {"difference_n": _r(2 * f), "z": _r(z)}
                                  for c, f, z in fr}
    out["load_cell_direction_joint_z"] = _r(joint)
    strong = cells_declared(fr, joint, _force_noise(rm), rm.model.n_cables)
    if strong:
        top = max(abs(f) for _, f, _ in strong)
        which = (f"the load cell of cable {strong[0][0]} reads" if len(strong) == 1
                 else f"the load cells of cables {', '.join(c for c, _, _ in strong)} read")
        findings.append(f"{which} differently by the direction of the cable's last "
                        f"move (up to {2 * top:.1f} N between paying out and reeling "
                        f"in; friction between the cell and the platform?)")
        out["load_cell_direction_cables"] = [c for c, _, _ in strong]


def cells_declared(cells: list[tuple[str, float, float]], joint: float, noise: float,
                   n_cables: int) -> list[tuple[str, float, float]]:
    """The load cells declared to read by the direction of motion, of ``cells`` (cable id,
    half difference [N], z; :func:`_cell_direction`) with their joint z ``joint``, against
    the force balance's row-to-row noise ``noise`` [N]: each past :data:`STRUCT_Z` and
    :data:`STRUCT_SIZE` times the noise alone; and where all together stand past
    :data:`STRUCT_Z` and most cells are each as large as one cell's noise (the force
    balance's noise is the cells' summed: sqrt(n / 3) times one's) at a z above 2, those
    too, beside any past the bar alone (a few cells past it alone left the others out,
    their friction found: evaluation case 12993, friction on every pulley). In the cables'
    order."""
    strong = [x for x in cells if abs(x[2]) > STRUCT_Z and abs(x[1]) > STRUCT_SIZE * noise]
    cell = noise * math.sqrt(3.0 / max(n_cables, 3))
    big = [x for x in cells if abs(x[1]) > STRUCT_SIZE * cell and abs(x[2]) > 2.0]
    if joint > STRUCT_Z and len(big) * 2 > len(cells):
        return [x for x in cells if x in strong or x in big]
    return strong


def _tested(probed: tuple[list[probes.ProbeResult], list[probes.Stand]] | None,
            name: str, cable: str | None = None) -> bool:
    """Whether the probes tested ``name`` (on ``cable``)."""
    return any(r.name == name and r.cable == cable for r in (probed[0] if probed else []))


def _probed(probed: tuple[list[probes.ProbeResult], list[probes.Stand]] | None,
            *names: str) -> bool:
    """Whether a probe of one of ``names`` is a finding."""
    return any(r.finding and r.name in names for r in (probed[0] if probed else []))


def _force_noise(rm: ResidualModel) -> float:
    """The load cells' row-to-row noise in the force balance [N] (what a direction-dependent
    reading stands against, and the start of :func:`_direction_fit`'s weights: the replicate
    spread holds the friction itself, and so does the spread after the regression wherever
    the directions the samples tell differ from those the friction followed; 124 N after
    it on an IPAnema-class campaign with 79 N of friction and 1.5 N cells, 2.3 N row to
    row)."""
    return max(min(rm.white_k[0]["force"], rm.white_k[1]["force"]), 0.1)


def _cell_direction(rm: ResidualModel, b: Blocks, robot) -> tuple[list, float] | None:
    """Per cable, half the difference of its load cell's reading between paying out and
    reeling in [N] and its z-value, and the z of all of them together (a Wald test of the k
    differences): the force balance's residuals (N, 6) regressed on ``d_k (u_k; R b_k x
    u_k)`` (d_k the sign of cable k's last move, u_k the direction of its force on the
    platform; :func:`_direction_fit`).

    The z-values are normal deviates of the same tail probability as the statistics' own
    distributions (Student's t and Fisher's F with the degrees of freedom of the variance
    they use): on a campaign of a handful of dwells the residual spread is known from a few
    dozen entries, and a t of 8 is not the normal's 8 there. Standard errors are
    cluster-robust over the recording's error clusters (a target's visits, stretches of
    moves) where there are more than twice as many clusters as differences, never below
    the classical ones. Only cables whose last move had both signs on at least three
    samples each are tested (one sign only: a load-cell offset, fitted already); no other
    least number of samples (the degrees of freedom say what few samples know)."""
    from scipy.stats import f as fisher
    from scipy.stats import norm
    from scipy.stats import t as student

    got = _direction_design(rm, b, robot)
    if got is None:
        return None
    A0, y0, w, groups, ids = got
    k = A0.shape[2]
    fit = _direction_fit(A0, y0, w, _force_noise(rm), _moment_noise(rm))
    if fit is None:
        return None
    coef, A, r, _, nu = fit
    try:
        bread = np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return None
    V = bread * max(float(r @ r) / nu, 1e-12)  # classical
    ug, inv = np.unique(np.repeat(groups, 6), return_inverse=True)
    if len(ug) > 2 * k:  # cluster-robust (sandwich), never below the classical
        sc = np.zeros((len(ug), k))
        np.add.at(sc, inv, A * r[:, None])
        Vs = bread @ (sc.T @ sc) @ bread * len(ug) / (len(ug) - 1)
        if np.trace(Vs) > np.trace(V):
            V, nu = Vs, len(ug) - 1.0
    se = np.sqrt(np.clip(np.diag(V), 1e-300, None))
    t = coef / se
    z = np.sign(t) * norm.isf(student.sf(np.abs(t), nu))
    # all the cells together: friction on every pulley at a few times the cells' noise each
    try:
        wald = float(coef @ np.linalg.solve(V, coef))
    except np.linalg.LinAlgError:
        wald = float(np.sum(t ** 2))
    joint = float(norm.isf(fisher.sf(max(wald, 0.0) / k, k, nu)))
    return [(c, float(f), float(zc)) for c, f, zc in zip(ids, coef, z, strict=True)], joint


def _moment_noise(rm: ResidualModel) -> float:
    """The load cells' row-to-row noise in the moment balance [N m] (the start of
    :func:`_direction_fit`'s weights)."""
    return max(min(rm.white_k[0]["moment"], rm.white_k[1]["moment"]), 0.05)


def _direction_design(rm: ResidualModel, b: Blocks, robot
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list] | None:
    """:func:`_cell_direction`'s regression on the samples with tensions, a pose and a force
    balance: the columns ``d_k (u_k; R b_k x u_k)`` (m, 6, k) of the cables tested, the
    balance's residuals (m, 6) [N, N m], the samples' weights, their error clusters and the
    tested cables' ids (samples where a tested cable's direction is known); None where no
    cable has three samples of each sign."""
    from controller.pose import cross
    from controller.statics import batch_statics, true_tensions

    s = rm.s
    sel = np.flatnonzero(rm.has_tau & np.isfinite(b.wrench).all(axis=1)
                         & np.isfinite(b.poses).all(axis=1))
    d = s.direction[sel]
    both = ((d > 0).sum(axis=0) >= 3) & ((d < 0).sum(axis=0) >= 3)
    if not both.any():
        return None
    # a sample where a tested cable's last move is unknown (the initialisation) holds that
    # cable's friction with either sign: no column of the regression, it would count as noise
    known = np.all(d[:, both] != 0, axis=1)
    sel, d = sel[known], d[known]
    bs = batch_statics(robot, b.poses[sel], true_tensions(robot, s.tau[sel]))
    pf = bs.platform_forces
    size = np.linalg.norm(pf, axis=-1, keepdims=True)
    u = np.where(size > 1.0, pf / np.maximum(size, 1e-9), bs.state.u)
    X = np.concatenate([u, cross(bs.state.Rb, u)], axis=-1) * d[..., None]  # (m, n, 6)
    A0 = np.swapaxes(X, 1, 2)[:, :, both]  # (m, 6, k)
    if not np.isfinite(A0).all():
        return None
    groups = s.cluster if s.cluster is not None and len(s.cluster) == s.n else s.block
    ids = [c for c, kk in zip(rm.model.cable_ids, both, strict=True) if kk]
    return A0, b.wrench[sel], s.weight[sel], groups[sel], ids


def _direction_fit(A0: np.ndarray, y0: np.ndarray, w: np.ndarray, force_sd: float,
                   moment_sd: float) -> tuple | None:
    """Feasible generalised least squares of ``-y0`` (m, 6) on ``A0`` (m, 6, k): forces and
    moments weighted by the spread of their own residuals after the regression, less the
    degrees of freedom it takes from each (the leverages of its entries summed: a spread
    that holds neither the friction nor, on a few samples, shrinks by what the k
    differences fit of the noise); started from the row-to-row spreads ``force_sd`` [N] and
    ``moment_sd`` [N m] (the replicate spread of the noise model holds the friction itself).
    Returns the differences, the whitened design and residuals, the spreads (6,) and the
    residuals' degrees of freedom; None where they leave none."""
    m, _, k = A0.shape
    if 6 * m - k < 1:
        return None
    sw = np.sqrt(w)
    sig = np.array([force_sd] * 3 + [moment_sd] * 3)
    for last in (False, False, False, True):
        wt = sw[:, None] / sig[None, :]
        A = (A0 * wt[:, :, None]).reshape(-1, k)
        y = (y0 * wt).ravel()
        coef, *_ = np.linalg.lstsq(A, -y, rcond=None)
        if last:
            return coef, A, y + A @ coef, sig, float(6 * m - k)
        U, sv, _ = np.linalg.svd(A, full_matrices=False)
        lev = np.sum(U[:, sv > 1e-12 * max(float(sv.max(initial=0.0)), 1e-300)] ** 2,
                     axis=1).reshape(m, 6)
        res = y0 + A0 @ coef  # (m, 6) in N and N m
        sig = np.array([_spread(res[:, :3], w, lev[:, :3])] * 3
                       + [_spread(res[:, 3:], w, lev[:, 3:])] * 3)
    return None


def _spread(res: np.ndarray, w: np.ndarray, lev: np.ndarray) -> float:
    """The spread of the regression's residuals ``res`` (m, 3) of one block (forces or
    moments) by the samples' weights ``w``, over their count less the leverages ``lev``
    (m, 3) the regression took from them; at least 0.05 (N, N m)."""
    num = float(np.sum(w[:, None] * res ** 2))
    den = max(3.0 * float(w.sum()) - float(lev.sum()), 1.0)
    return max(math.sqrt(num / den), 0.05)


def _entries_per_sample(rm: ResidualModel) -> np.ndarray:
    n = rm.model.n_cables
    cnt = np.where(rm.has_len, n, 0).astype(float)
    if rm.any_tau:
        cnt += np.where(rm.has_tau & (rm.has_pose | rm.est_pose), 6, 0)
    if rm.has_exit.any():
        cnt += 3 * rm.has_exit.sum(axis=1)
    return cnt


def _r(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(round(x, 3))


def _wrms(x: np.ndarray, w: np.ndarray) -> float:
    ok = np.isfinite(x)
    if not ok.any():
        return float("nan")
    return float(np.sqrt(np.sum(w[ok] * x[ok] ** 2) / np.sum(w[ok])))


def _two_groups(x: np.ndarray, g: np.ndarray, w: np.ndarray) -> tuple[float, float] | None:
    """Half the difference of the weighted means of ``x`` where g > 0 and g < 0, and its
    z-value (x in noise units; weights are shares of independent samples)."""
    ok = np.isfinite(x)
    a, c = ok & (g > 0), ok & (g < 0)
    na, nc = float(w[a].sum()), float(w[c].sum())
    if na < 3 or nc < 3:
        return None
    ma = float(np.sum(w[a] * x[a]) / na)
    mc = float(np.sum(w[c] * x[c]) / nc)
    va = float(np.sum(w[a] * (x[a] - ma) ** 2) / na)
    vc = float(np.sum(w[c] * (x[c] - mc) ** 2) / nc)
    se = math.sqrt(max(va, 1e-12) / na + max(vc, 1e-12) / nc)
    return 0.5 * (ma - mc), (ma - mc) / se


def _by_cluster(x: np.ndarray, t: np.ndarray, w: np.ndarray, clusters: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted means of ``x`` and ``t`` per error cluster, and the clusters' weights: a trend
    in time is judged on groups of samples whose errors are independent of each other."""
    ok = np.isfinite(x)
    if not ok.any():
        return x[:0], t[:0], w[:0]
    _, inv = np.unique(clusters[ok], return_inverse=True)
    ww = np.bincount(inv, weights=w[ok])
    xm = np.bincount(inv, weights=w[ok] * x[ok]) / np.maximum(ww, 1e-300)
    tm = np.bincount(inv, weights=w[ok] * t[ok]) / np.maximum(ww, 1e-300)
    return xm, tm, np.ones(len(ww))


def _within(x: np.ndarray, t: np.ndarray, w: np.ndarray, groups: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """``x`` and ``t`` less their weighted means over each replicate group of two or more
    finite samples (NaN elsewhere): what repeats at a pose cancels, a drift in time does
    not."""
    ok = np.isfinite(x) & np.isfinite(t)
    xo, to = np.full(len(x), np.nan), np.full(len(t), np.nan)
    if not ok.any():
        return xo, to
    _, inv = np.unique(groups[ok], return_inverse=True)
    ww = np.bincount(inv, weights=w[ok])
    cnt = np.bincount(inv)
    xm = np.bincount(inv, weights=w[ok] * x[ok]) / np.maximum(ww, 1e-300)
    tm = np.bincount(inv, weights=w[ok] * t[ok]) / np.maximum(ww, 1e-300)
    rep = cnt[inv] >= 2
    idx = np.flatnonzero(ok)[rep]
    xo[idx] = x[ok][rep] - xm[inv][rep]
    to[idx] = t[ok][rep] - tm[inv][rep]
    return xo, to


def _trend(x: np.ndarray, t: np.ndarray, w: np.ndarray, groups: np.ndarray,
           clusters: np.ndarray, span: float) -> tuple[float, float] | None:
    """Change of ``x`` over ``span`` of time and its z-value, on the means of independent
    clusters of samples (rows of neighbouring moves share their errors): of the deviations
    from their replicate group's mean when enough samples are replicated (the model's error
    at a pose cancels there), else of ``x`` itself."""
    xw, tw = _within(x, t, w, groups)
    ok = np.isfinite(xw) & np.isfinite(tw)
    if ok.sum() >= 8 and len(np.unique(groups[ok])) >= 3 and np.ptp(tw[ok]) > 0:
        return _slope(*_by_cluster(xw, tw, w, clusters), span)
    return _slope(*_by_cluster(x, t, w, clusters), span)


def _slope(x: np.ndarray, t: np.ndarray, w: np.ndarray, span: float | None = None
           ) -> tuple[float, float] | None:
    """Change of ``x`` over ``span`` (default: the span of ``t``) by weighted least squares,
    and its z-value."""
    ok = np.isfinite(x) & np.isfinite(t)
    if ok.sum() < 6:
        return None
    ww, xx, tt = w[ok], x[ok], t[ok]
    sw = ww.sum()
    tm = np.sum(ww * tt) / sw
    xm = np.sum(ww * xx) / sw
    stt = np.sum(ww * (tt - tm) ** 2)
    if stt <= 0:
        return None
    b = np.sum(ww * (tt - tm) * (xx - xm)) / stt
    res = xx - xm - b * (tt - tm)
    var = np.sum(ww * res ** 2) / max(sw - 2, 1)
    se = math.sqrt(max(var, 1e-12) / stt)
    return float(b * (np.ptp(tt) if span is None else span)), float(b / se)


def with_changes(leftover: dict | None, changes: list, slip_times: dict[str, float],
                 offsets: set[str] | frozenset[str] = frozenset()) -> dict | None:
    """``leftover`` (the ``unexplained`` object or None) with the steps between replicate
    visits (:func:`bench.diagnosis.noise.find_changes`) that no named effect accounts for:
    ``changes`` (each with the time it began) and a finding each. Steps of a cable's length
    at a time a named slip (``slip_times``: cable id -> t [s]) lies in are the slip's, not
    declared, and so are those on a cable whose length offset is named (``offsets``: its
    slip, begun then)."""
    from bench.diagnosis import noise

    noise.name_slips(changes, slip_times, offsets)
    # (a trend or a difference by direction is judged by the time and direction tests
    # above, against the noise the replicate groups give; a step is located in time here)
    left = [c for c in changes if c.named is None and c.kind == "step"]
    if not left:
        return leftover
    out = dict(leftover) if leftover is not None else {}
    out["changes"] = [c.entry() for c in left]
    findings = list(out.get("findings", []))
    for c in left:
        cols = ", ".join(c.columns[:4]) + (" ..." if len(c.columns) > 4 else "")
        what = {"length": "length residuals of cables", "force": "force balance",
                "moment": "moment balance", "exit": "exit points",
                "load": "residuals along a change of the platform's"}.get(c.block, c.block)
        between = f" (between the samples at {c.before_s:.1f} and {c.after_s:.1f} s)" \
            if c.before_s is not None and c.after_s is not None else ""
        findings.append(f"something changed at t = {c.t_s:.1f} s{between}: the replicate visits "
                        f"after it differ from those before in the {what} {cols} by "
                        f"{c.size:.0f} times their noise (z = {c.z:.0f})"
                        + (f"; the platform's load changed by {c.load_kg:+.1f} kg?"
                           if c.load_kg is not None else ""))
    out["findings"] = findings
    out["summary"] = "; ".join(findings)
    return out
