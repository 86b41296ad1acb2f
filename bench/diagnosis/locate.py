"""Where the mismatch is: per cable, per mast, by region of the workspace, over time."""

from __future__ import annotations

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

    Pose-dependent model errors repeat at each visit of a target, so each sample's
    residual is taken relative to the mean of its target; what is left steps when
    the reading jumps. Recordings with few replicates (rows of moves) use the residual
    itself, against its own row-to-row spread.
    """
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
        counts = cnt[inv]
        sig = sigma
        if np.mean(counts > 1) >= 0.5:
            sums = np.bincount(inv, weights=r)
            d = r - sums[inv] / counts
            d = np.where(counts > 1, d, np.nan)
        else:
            continue  # no replicates: see row_jumps
        good = np.isfinite(d)
        d, tt = d[good], t[good]
        n = len(d)
        if n < 8:
            continue
        cs = np.cumsum(d)
        best, at = 0.0, -1
        for i in range(3, n - 3):
            if tt[i - 1] < t_after:
                continue
            m1 = cs[i - 1] / i
            m2 = (cs[-1] - cs[i - 1]) / (n - i)
            z = abs(m2 - m1) / (sig * np.sqrt(1.0 / i + 1.0 / (n - i)))
            if z > best:
                best, at = z, i
        if best > STEP_Z and at > 0:
            # the step in the reading itself: compare raw residuals of the same targets
            before = slice(0, at)
            after = slice(at, n)
            size = float(np.mean(d[after]) - np.mean(d[before]))
            found.append({"cable": cid, "t_s": float(0.5 * (tt[at - 1] + tt[at])),
                          "step_m": size, "z": float(best)})
    return found


#: a jump between consecutive rows stands this many robust standard deviations out ...
JUMP_Z = 12.0
#: ... and is at least this large [m]
JUMP_MIN_M = 5e-4


def row_jumps(stream: Samples, length: np.ndarray, cable_ids: tuple[str, ...],
              t_after: float = -np.inf) -> list[dict]:
    """Slips during moves: a cable's length residual jumping between two consecutive raw rows
    (``stream``, residuals ``length`` (R,n)) far beyond its row-to-row spread, alone (a jump
    of most cables at once is the pose, not a cable). One step per cable, the largest."""
    same = np.concatenate([[False], stream.block[1:] == stream.block[:-1]])
    d = np.full(length.shape, np.nan)
    d[1:] = length[1:] - length[:-1]
    d[~same] = np.nan
    d[stream.t <= t_after] = np.nan
    found = []
    with np.errstate(invalid="ignore"):
        mad = 1.4826 * np.nanmedian(np.abs(d), axis=0)
        z = np.abs(d) / np.maximum(mad, 1e-9)
        big = (z > JUMP_Z) & (np.abs(d) > JUMP_MIN_M)
    many = big.sum(axis=1) > max(1, len(cable_ids) // 2)
    big[many] = False
    for k, cid in enumerate(cable_ids):
        rows = np.flatnonzero(big[:, k])
        if not len(rows):
            continue
        i = rows[np.argmax(np.abs(d[rows, k]))]
        found.append({"cable": cid, "t_s": float(0.5 * (stream.t[i - 1] + stream.t[i])),
                      "step_m": float(d[i, k]), "z": float(z[i, k]), "row": int(stream.row[i])})
    return found
