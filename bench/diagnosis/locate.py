"""Where the mismatch is: per cable, per mast, by region of the workspace, over time."""

from __future__ import annotations

import warnings

import numpy as np

from bench.diagnosis.samples import Samples

#: a step in a cable's length residual must stand this many standard errors above noise
STEP_Z = 8.0


def rms(x: np.ndarray) -> float | None:
    """RMS of the finite entries, None if there are none."""
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else None


def by_cable(cable_ids: tuple[str, ...], length: np.ndarray,
             tension: np.ndarray | None) -> dict[str, dict[str, float | None]]:
    out = {}
    for k, cid in enumerate(cable_ids):
        out[cid] = {"length_rms_m": rms(length[:, k]),
                    "tension_rms_n": rms(tension[:, k]) if tension is not None else None}
    return out


def by_mast(mast_ids: tuple[str, ...], mast_index: np.ndarray,
            length: np.ndarray) -> dict[str, dict[str, float | None]]:
    return {mid: {"length_rms_m": rms(length[:, mast_index == i])}
            for i, mid in enumerate(mast_ids)}


def regions(s: Samples, err: np.ndarray, init_pose: np.ndarray, pivots: np.ndarray,
            mast_ids: tuple[str, ...], label: str = "pose_rms_m") -> list[dict]:
    """RMS of per-sample errors ``err`` (N,) [m] in regions of the workspace, worst first."""
    pos = np.where(np.isfinite(s.pose_meas[:, :3]), s.pose_meas[:, :3], s.pose_des[:, :3])
    ok = np.isfinite(err) & np.isfinite(pos).all(axis=1)
    if ok.sum() < 4:
        return []
    pos, e = pos[ok], err[ok]
    out = []

    def add(where: str, sel: np.ndarray) -> None:
        if sel.sum() >= 2:
            out.append({"where": where, label: rms(e[sel]), "samples": int(sel.sum())})

    dist = np.linalg.norm(pos[:, :2] - init_pose[:2], axis=1)
    q = float(np.median(dist))
    add(f"within {q:.1f} m of the initialisation pose", dist <= q)
    add(f"farther than {q:.1f} m from the initialisation pose", dist > q)
    for a, ax in enumerate("xyz"):
        m = float(np.median(pos[:, a]))
        if np.ptp(pos[:, a]) > 0.2:
            add(f"{ax} > {m:.1f} m", pos[:, a] > m)
            add(f"{ax} <= {m:.1f} m", pos[:, a] <= m)
    dm = np.linalg.norm(pos[:, None, :2] - pivots[None, :, :2], axis=2)
    near = dm.min(axis=1)
    which = dm.argmin(axis=1)
    r = float(np.median(near))
    for i, mid in enumerate(mast_ids):
        add(f"within {r:.1f} m of mast {mid}", (which == i) & (near <= r))
    return sorted(out, key=lambda d: -(d[label] or 0.0))


def growth_from_init(s: Samples, err: np.ndarray, init_pose: np.ndarray) -> dict | None:
    """Error near and far from the initialisation pose, and their correlation."""
    pos = np.where(np.isfinite(s.pose_meas[:, :3]), s.pose_meas[:, :3], s.pose_des[:, :3])
    ok = np.isfinite(err) & np.isfinite(pos).all(axis=1)
    if ok.sum() < 6:
        return None
    d = np.linalg.norm(pos[ok] - init_pose[:3], axis=1)
    e = err[ok]
    lo, hi = np.quantile(d, [0.25, 0.75])
    corr = float(np.corrcoef(d, e)[0, 1]) if np.std(d) > 0 and np.std(e) > 0 else 0.0
    return {"near_m": float(lo), "near_rms": rms(e[d <= lo]), "far_m": float(hi),
            "far_rms": rms(e[d >= hi]), "correlation": corr}


def steps_in_time(s: Samples, length: np.ndarray, sigma: float,
                  cable_ids: tuple[str, ...], t_after: float = -np.inf) -> list[dict]:
    """Steps in a cable's length residual over time (a slip on the drum, an encoder jump),
    later than ``t_after`` (the end of the initialisation: a slip cannot happen before).

    Pose-dependent model errors repeat at each visit of a target, so a step is measured
    within targets: for each time ``t0`` the least-squares step of the residual at
    ``t >= t0`` with a free mean per target (both the residual and the step's indicator
    taken relative to their target's mean), against the length noise ``sigma``: ``z =
    |beta| sqrt(sum u~^2) / sigma``. Only targets visited on both sides of ``t0`` carry
    it; a recording whose replicates are its dwells (a continuous one with a few stops
    visited again) is tested through them, the rows of its moves through
    :func:`row_jumps`. (A target's deviations from its own mean were compared with the
    noise of one reading before, a third too small for a pair, and only where half the
    samples were replicated: a 2.5 mm slip between the dwells of a CoGiRo-class recording
    without tensions, 0.84 mm noise, went unseen.)"""
    order = np.argsort(s.t)
    found = []
    for k, cid in enumerate(cable_ids):
        r = length[order, k]
        tg = s.target[order]
        ok = np.isfinite(r) & ~s.is_init[order]
        if ok.sum() < 8:
            continue
        r, tg, t = r[ok], tg[ok], s.t[order][ok]
        _, inv, cnt = np.unique(tg, return_inverse=True, return_counts=True)
        rep = cnt[inv] > 1
        if rep.sum() < 8:
            continue  # no replicates: see row_jumps
        r_all, t_all = r, t
        r, inv, t = r[rep], np.unique(inv[rep], return_inverse=True)[1], t[rep]
        n = len(r)
        counts = np.bincount(inv).astype(float)
        d = r - (np.bincount(inv, weights=r) / counts)[inv]
        # every split at once: u (n splits, n samples) is 1 from the split on
        cand = np.arange(3, n - 2)
        cand = cand[t[cand - 1] >= t_after]
        if not len(cand):
            continue
        u = (np.arange(n)[None, :] >= cand[:, None]).astype(float)
        um = np.stack([np.bincount(inv, weights=row) for row in u]) / counts
        ut = u - um[:, inv]
        uu = np.einsum("ij,ij->i", ut, ut)
        with np.errstate(divide="ignore", invalid="ignore"):
            beta = (ut @ d) / uu
            z = np.abs(beta) * np.sqrt(uu) / sigma
        z = np.where(uu > 1e-9, z, 0.0)
        j = int(np.argmax(z))
        if z[j] > STEP_Z:
            at = int(cand[j])
            found.append({"cable": cid, "t_s": _when(t_all, r_all, t[at - 1], t[at], beta[j]),
                          "step_m": float(beta[j]), "z": float(z[j])})
    return found


def _when(t: np.ndarray, r: np.ndarray, lo: float, hi: float, step: float) -> float:
    """The time of a step of size ``step`` found between replicated samples at ``lo`` and
    ``hi`` [s], from every sample between them (times ``t``, residuals ``r``): the middle of
    the consecutive pair whose change, less the median change of the pairs there (the
    residual's drift along a move), goes furthest the step's way; the middle of ``lo`` and
    ``hi`` without samples between them."""
    k = np.flatnonzero((t >= lo) & (t <= hi))
    if len(k) < 3:
        return float(0.5 * (lo + hi))
    dr = np.diff(r[k])
    j = int(np.argmax(np.sign(step) * (dr - np.median(dr))))
    return float(0.5 * (t[k[j]] + t[k[j + 1]]))


#: a jump between consecutive rows stands this many robust standard deviations out ...
JUMP_Z = 12.0
#: ... and is at least this large [m]
JUMP_MIN_M = 5e-4
#: one cable's jump is its own when this many times the next largest
DOMINANT = 2.5
#: rows on each side of a jump over which the new level must hold
JUMP_HOLD = 4
#: ... and stand this many standard errors out of their scatter
HOLD_Z = 5.0
#: rows on each side whose jumps give the local spread
JUMP_LOCAL = 15
#: a cable's account of a jump where the tensions or the pose are fitted leaves no more
#: than this many standard deviations of noise (beside the directions' own count)
FIT_Z = 5.0


def row_jumps(stream: Samples, length: np.ndarray, cable_ids: tuple[str, ...],
              t_after: float = -np.inf, absorbed: np.ndarray | None = None) -> list[dict]:
    """Slips during moves: a cable's length residual stepping between two consecutive raw rows
    (``stream``, residuals ``length`` (R,n)) far beyond its row-to-row spread and far above
    the other cables' at that row (a jump of several cables at once is the pose, not a
    cable). One step per cable, the largest.

    A step is told from what a model error does along a move: the jump is taken against the
    local slope (the median of the neighbouring rows' changes: a residual that ramps as the
    platform moves away from where the model holds does not step), and the new level must
    hold over the next :data:`JUMP_HOLD` rows against the line through the previous ones, out
    of their scatter (a single wild row, a transient that returns, a noisy reading is no
    slip).

    Rows without measured tensions (``stream.tau`` not finite) have them fitted to the
    stretch: there, residuals left out (NaN: a cable at zero tension, one-sided) mark the
    balance the row was evaluated on, and where a cable goes to or from zero between two
    such rows every cable's residual changes with the balance (under a model centimetres
    off, two sets of cables at zero can fit almost equally and the fit switches between
    them), not with the readings: such a pair of rows tells no step. (With measured
    tensions a slip itself may slacken a cable: those pairs count.)

    ``absorbed`` (R, n, k): where finite, the directions of a row's length residual that its
    fitted tensions take up (:attr:`bench.diagnosis.residuals.ResidualModel.absorbed`). There
    a slip of one cable is no jump of that cable alone: the refitted tensions stretch the
    others to share it (a 2.9 mm slip read as 0.95 mm on its cable and 1.2 mm on another).
    Each cable's slip is fitted to the whole row's jump through its pattern (the unit
    change of its reading less what the tensions take up, :func:`cable_accounts`), and a
    jump is one cable's own where that cable's account leaves far less of it than any
    other cable's."""
    R = len(length)
    tau = getattr(stream, "tau", None)
    same = _comparable_rows(stream, length, tau)
    raw = _row_changes(length, same)
    raw[stream.t <= t_after] = np.nan
    j, own, alike, fitted_rows = raw, None, None, None
    if absorbed is not None:
        # each cable's slip that accounts for the jump best, where the tensions are fitted
        beta, own, fitted_rows, alike = cable_accounts(raw, absorbed)
        j = np.where(fitted_rows[:, None], beta, raw)
    with np.errstate(invalid="ignore"):
        mad = 1.4826 * np.nanmedian(np.abs(j), axis=0)
        z = np.abs(j) / np.maximum(mad, 1e-9)
        big = (z > JUMP_Z) & (np.abs(j) > JUMP_MIN_M)
    # one cable's own: its jump dominates the other cables' at that row (a jump of several
    # cables at once is the pose, or all the cables' lengths changing at a new visit)
    if len(cable_ids) > 1:
        alone = _dominant(raw)
        big &= alone if own is None else np.where(fitted_rows[:, None], own, alone)
    if own is not None and tau is not None:
        big = _with_posed_candidates(np.asarray(tau, float).reshape(R, -1), same, j, z, big,
                                     fitted_rows, alike)
    else:
        alike = None
    found = [f for k, cid in enumerate(cable_ids)
             if (f := _cable_step(stream, length, raw, j, z, big, alike, k, cid, cable_ids))]
    at = {f["cable"]: f["row"] for f in found}
    for f in found:  # (the candidates found at that row)
        if "alike" in f:
            f["alike"] = [c for c in f["alike"] if at.get(c) == f["row"]]
            if not f["alike"]:
                del f["alike"]
    return found


def _comparable_rows(stream: Samples, length: np.ndarray, tau) -> np.ndarray:
    """(R,) whether a row's change from the row before tells a step: both in one block, and,
    where both rows' tensions were fitted, no cable going to or from zero tension between
    them (:func:`row_jumps`)."""
    R = len(length)
    same = np.concatenate([[False], stream.block[1:] == stream.block[:-1]])
    if tau is not None and R > 1:
        fitted = ~np.isfinite(np.asarray(tau, float).reshape(R, -1)).all(axis=1)
        gone = ~np.isfinite(length)
        switch = np.any(gone[1:] != gone[:-1], axis=1) & fitted[1:] & fitted[:-1]
        same[1:] &= ~switch
    return same


def _dominant(raw: np.ndarray) -> np.ndarray:
    """(R, n) whether a cable's change ``raw`` is more than :data:`DOMINANT` times the
    largest of the other cables' at that row."""
    mag = np.nan_to_num(np.abs(raw))
    top2 = np.sort(mag, axis=1)[:, -2:]
    second = np.where(mag >= top2[:, 1:2], top2[:, :1], top2[:, 1:2])
    return mag > DOMINANT * second


def _with_posed_candidates(tm: np.ndarray, same: np.ndarray, j: np.ndarray, z: np.ndarray,
                           big: np.ndarray, fitted_rows: np.ndarray,
                           alike: np.ndarray) -> np.ndarray:
    """``big`` for rows whose pose was estimated from measured tensions ``tm`` (R, n) [N]:
    the pose takes up six of eight directions, and several cables' patterns are nearly
    parallel in the two left (ROCASPECT's even cables): a jump of several cables' readings
    at once (hysteresis at a reversal) is accounted for by one of them within the noise. A
    slip moves the platform: its cable's tension jumps with it (a 6 mm slip of a 15 m
    cable at E*A 700 kN, by a hundred newtons); a reading's error does not. Where no
    cable's account is its own but several account for the jump within the noise
    (ROCASPECT's odd cables), each is a candidate: the time is known, whose slip it is the
    fit tells (its offset)."""
    posed = fitted_rows & np.isfinite(tm).all(axis=1)
    if not posed.any():
        return big
    dtau = _row_changes(tm, same)
    with np.errstate(invalid="ignore"):
        zt = np.abs(dtau) / np.maximum(1.4826 * np.nanmedian(np.abs(dtau), axis=0), 1e-9)
        cand = (z > JUMP_Z) & (np.abs(j) > JUMP_MIN_M) & alike & posed[:, None]
    cand &= (cand.sum(axis=1) > 1)[:, None] & ~big
    return (big | cand) & (~posed[:, None] | (zt > JUMP_Z))


def _cable_step(stream: Samples, length: np.ndarray, raw: np.ndarray, j: np.ndarray,
                z: np.ndarray, big: np.ndarray, alike: np.ndarray | None, k: int, cid: str,
                cable_ids: tuple[str, ...]) -> dict | None:
    """Cable ``k``'s step (the largest of its rows that step locally and hold, a jump its
    own before one it is only a candidate for), or None."""
    rows = [i for i in np.flatnonzero(big[:, k])
            if _local_z(j[:, k], int(i)) > JUMP_Z
            and _holds(stream, length[:, k], int(i), float(raw[i, k]))]
    if alike is not None and any(not alike[i, k] for i in rows):
        # a jump that is the cable's own before one it is only a candidate for (a larger
        # slip of a cable alike, whose fit will tell)
        rows = [i for i in rows if not alike[i, k]]
    if not rows:
        return None
    i = rows[int(np.argmax(np.abs(j[rows, k])))]
    f = {"cable": cid, "t_s": float(0.5 * (stream.t[i - 1] + stream.t[i])),
         "step_m": float(j[i, k]), "z": float(z[i, k]), "row": int(stream.row[i])}
    if alike is not None and alike[i, k]:
        f["alike"] = [c for c, a in zip(cable_ids, big[i] & alike[i], strict=True)
                      if a and c != cid]
    return f


def _row_changes(x: np.ndarray, same: np.ndarray) -> np.ndarray:
    """Changes (R, n) of ``x`` (R, n) between consecutive rows of one block (``same``: a row
    in the block of the one before), less the local slope (the median of the changes of
    the two rows on each side); NaN at a block's first row."""
    R = len(x)
    d = np.full(x.shape, np.nan)
    d[1:] = x[1:] - x[:-1]
    d[~same] = np.nan
    nb = []
    for off in (-2, -1, 1, 2):
        sh = np.full(x.shape, np.nan)
        lo, hi = max(off, 0), R + min(off, 0)
        sh[lo - off:hi - off] = d[lo:hi]
        nb.append(sh)
    with warnings.catch_warnings():  # rows without neighbours: no slope
        warnings.simplefilter("ignore", RuntimeWarning)
        slope = np.nanmedian(np.stack(nb), axis=0) if R else d
    return d - np.where(np.isfinite(slope), slope, 0.0)


def cable_accounts(jump: np.ndarray, absorbed: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each cable's slip (R, n) [m] that best accounts for the rows' jumps ``jump`` (R, n)
    where the tensions or the pose are fitted; whether it is that cable's own (R, n): its
    account leaves :data:`DOMINANT` squared times less of the jump than the next best
    cable's, and no more than noise (:data:`FIT_Z`); the rows that have such accounts (R,):
    ``absorbed`` (R, n, k) finite and every cable's jump measured; and, in rows with no
    cable's own, the cables whose accounts leave noise only, within :data:`FIT_Z` of the
    best (R, n): candidates alike.

    A slip ``s`` of cable ``c`` changes a row's residual by ``s P e_c`` with ``P`` the
    projection off the absorbed directions: the least-squares slip is ``(P j)_c / P_cc``
    and it explains ``(P j)_c^2 / P_cc`` of the jump's ``|j|^2``."""
    R, n = jump.shape
    rows = np.isfinite(absorbed).all(axis=(1, 2)) & np.isfinite(jump).all(axis=1)
    beta = np.full((R, n), np.nan)
    own = np.zeros((R, n), dtype=bool)
    alike = np.zeros((R, n), dtype=bool)
    if not rows.any():
        return beta, own, rows, alike
    A = absorbed[rows]
    P = np.eye(n) - A @ np.linalg.pinv(A, rcond=1e-10)
    jr = jump[rows]
    pj = np.einsum("rij,rj->ri", P, jr)
    pcc = np.diagonal(P, axis1=-2, axis2=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.where(pcc > 1e-9, pj / pcc, 0.0)
        explained = np.where(pcc > 1e-9, pj * pj / pcc, 0.0)
    left = np.einsum("ri,ri->r", jr, jr)[:, None] - explained  # (rows, n)
    top2 = np.sort(left, axis=1)[:, :2]
    second = np.where(left <= top2[:, :1], top2[:, 1:2], top2[:, :1])
    beta[rows] = b
    # and what it leaves is noise: the rows' jumps (most without a slip) are noise in the
    # dof directions the fit leaves, their squared size about sigma^2 chi2(dof); one
    # cable's slip leaves sigma^2 chi2(dof - 1)
    dof = max(int(round(float(np.median(np.trace(P, axis1=-2, axis2=-1))))), 1)
    med = float(np.median(np.einsum("ri,ri->r", pj, pj)))
    sigma2 = med / max(dof * (1.0 - 2.0 / (9.0 * dof)) ** 3, 1e-300)
    fits = left <= sigma2 * (dof - 1 + FIT_Z ** 2)
    own[rows] = (DOMINANT ** 2 * np.maximum(left, 0.0) < second) & fits
    # no cable's own, but several account for the jump within the noise of the best
    near = left - left.min(axis=1, keepdims=True) < sigma2 * FIT_Z ** 2
    alike[rows] = fits & near & ~own[rows].any(axis=1, keepdims=True)
    return beta, own, rows, alike


def _local_z(j: np.ndarray, i: int) -> float:
    """Jump ``j[i]`` against the robust spread of the jumps of the :data:`JUMP_LOCAL` rows on
    each side (a slack, sagging cable's reading swings with its tension's noise there)."""
    w = np.concatenate([j[max(i - JUMP_LOCAL, 0):i], j[i + 1:i + 1 + JUMP_LOCAL]])
    w = w[np.isfinite(w)]
    if len(w) < 4:
        return 0.0
    return float(abs(j[i]) / max(1.4826 * float(np.median(np.abs(w))), 1e-9))


def _holds(stream: Samples, r: np.ndarray, i: int, jump: float) -> bool:
    """Whether residual ``r`` keeps the level it jumped to at row ``i``: a line with one slope
    and a step at ``i`` through :data:`JUMP_HOLD` rows on each side (same block) has a step
    of the jump's sign and at least half its size."""
    lo, hi = max(i - JUMP_HOLD, 0), min(i + JUMP_HOLD, len(r))
    idx = np.arange(lo, hi)
    idx = idx[(stream.block[idx] == stream.block[i]) & np.isfinite(r[idx])]
    after = idx >= i
    if after.sum() < 2 or (~after).sum() < 2:
        return False
    t = stream.t[idx] - stream.t[i]
    A = np.column_stack([np.ones(len(idx)), t, after.astype(float)])
    coef, *_ = np.linalg.lstsq(A, r[idx], rcond=None)
    step = float(coef[2])
    if step * jump <= 0 or abs(step) < 0.5 * abs(jump):
        return False
    # and stands out of the rows' own scatter there (a slack, sagging cable's reading
    # swings with its tension's noise)
    dof = len(idx) - 3
    if dof < 1:
        return True
    res = r[idx] - A @ coef
    try:
        var = float(res @ res) / dof * np.linalg.inv(A.T @ A)[2, 2]
    except np.linalg.LinAlgError:
        return False
    return abs(step) > HOLD_Z * np.sqrt(max(var, 0.0))
