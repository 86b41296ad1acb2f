"""Dwell averaging: one static sample per dwell, replicate visits grouped by target pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.recording import Recording


@dataclass
class Samples:
    """N dwell-averaged samples of a recording (NaN = not measured).

    ``target`` (N,) numbers the distinct target poses (replicate visits share
    one); ``is_init`` marks the initialisation dwell; ``count`` rows averaged.
    """

    t: np.ndarray
    pose_des: np.ndarray
    pose_meas: np.ndarray
    l_meas: np.ndarray
    tau: np.ndarray
    exit_meas: np.ndarray
    count: np.ndarray
    target: np.ndarray
    is_init: np.ndarray
    tau_row_sd: float | None = None  # load-cell noise of one row [N] (within dwells)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def n_targets(self) -> int:
        return int(self.target.max()) + 1 if self.n else 0

    @property
    def replicated(self) -> bool:
        """Whether some target pose was visited more than once."""
        return bool(self.n > self.n_targets)

    def take(self, idx: np.ndarray) -> Samples:
        return Samples(self.t[idx], self.pose_des[idx], self.pose_meas[idx], self.l_meas[idx],
                       self.tau[idx], self.exit_meas[idx], self.count[idx], self.target[idx],
                       self.is_init[idx], self.tau_row_sd)


def _keys(rec: Recording) -> np.ndarray:
    """A per-row key that stays constant during a dwell (what the controller aimed at)."""
    for arr, scale in ((rec.pose_des, 1e6), (rec.l_cmd, 1e6)):
        cols = np.isfinite(arr).any(axis=0)  # the columns the recording has
        if cols.any():
            k = np.round(np.nan_to_num(arr[:, cols], nan=1e9) * scale)
            return k.reshape(len(k), -1)
    cols = np.isfinite(rec.pose_meas).any(axis=0)
    if cols.any():
        # no commanded values: rows whose measured pose stays within 2 mm / 2 mrad
        return np.round(np.nan_to_num(rec.pose_meas[:, cols], nan=1e9) / 2e-3)
    return np.arange(rec.n_samples)[:, None].astype(float)


def average_dwells(rec: Recording) -> Samples:
    """Average each dwell (consecutive rows with one target) into one sample."""
    keys = _keys(rec)
    N = rec.n_samples
    change = np.ones(N, dtype=bool)
    change[1:] = np.any(keys[1:] != keys[:-1], axis=1)
    starts = np.flatnonzero(change)
    bounds = list(zip(starts, list(starts[1:]) + [N], strict=True))
    counts = np.array([b - a for a, b in bounds])
    # recordings with dwells: drop the single rows of moves in between
    if counts.size and (counts[counts >= 3].sum() >= 0.5 * N):
        bounds = [(a, b) for a, b in bounds if b - a >= 2]
    init = np.zeros(N, dtype=bool)
    init[rec.init_rows] = True

    def mean(arr: np.ndarray, a: int, b: int) -> np.ndarray:
        chunk = arr[a:b]
        ok = np.isfinite(chunk)
        with np.errstate(invalid="ignore"):
            return np.where(ok.any(axis=0), np.nansum(chunk, axis=0) / np.maximum(ok.sum(0), 1),
                            np.nan)

    fields = {k: [] for k in ("t", "pose_des", "pose_meas", "l_meas", "tau", "exit_meas")}
    is_init = []
    for a, b in bounds:
        for k in fields:
            fields[k].append(mean(getattr(rec, k), a, b))
        is_init.append(bool(init[a:b].any()))
    arr = {k: np.array(v) for k, v in fields.items()}
    count = np.array([b - a for a, b in bounds])
    # load-cell noise: spread of the rows of a dwell around their mean (the state is static)
    ss, dof = 0.0, 0
    for a, b in bounds:
        chunk = rec.tau[a:b]
        if b - a >= 2 and np.isfinite(chunk).all():
            ss += float(((chunk - chunk.mean(axis=0)) ** 2).sum())
            dof += (b - a - 1) * chunk.shape[1]
    tau_sd = float(np.sqrt(ss / dof)) if dof else None
    return Samples(arr["t"], arr["pose_des"], arr["pose_meas"], arr["l_meas"], arr["tau"],
                   arr["exit_meas"], count, _targets(arr["pose_des"], arr["pose_meas"]),
                   np.array(is_init), tau_sd)


def _targets(pose_des: np.ndarray, pose_meas: np.ndarray) -> np.ndarray:
    """Number target poses: equal desired poses (0.1 mm) or, without them, measured poses
    within 5 mm / 5 mrad of each other."""
    N = len(pose_des)
    cols = np.isfinite(pose_des).any(axis=0)
    have_des = np.isfinite(pose_des[:, cols]).all(axis=1) & cols.any()
    pose_des = np.where(cols, pose_des, 0.0)
    key = np.where(have_des[:, None], np.round(pose_des / 1e-4), np.nan)
    ids = np.full(N, -1)
    reps: list[tuple[np.ndarray, bool]] = []
    for i in range(N):
        for j, (rep, is_des) in enumerate(reps):
            if have_des[i] and is_des and np.array_equal(key[i], rep):
                ids[i] = j
                break
            if (not have_des[i] and not is_des and np.isfinite(pose_meas[i, :3]).all()
                    and np.all(np.nan_to_num(np.abs(pose_meas[i] - rep)) < 5e-3)):
                ids[i] = j
                break
        if ids[i] < 0:
            ids[i] = len(reps)
            reps.append((key[i] if have_des[i] else pose_meas[i], bool(have_des[i])))
    return ids


def pooled_std(values: np.ndarray, target: np.ndarray) -> np.ndarray | None:
    """Pooled within-target standard deviation of ``values`` (N, d) per column, over targets
    visited more than once (model errors repeat at a target; noise does not). None if no
    target has replicates."""
    values = np.asarray(values, dtype=float)
    v2 = values.reshape(len(values), -1)
    ss = np.zeros(v2.shape[1])
    dof = np.zeros(v2.shape[1])
    for g in np.unique(target):
        sel = target == g
        if sel.sum() < 2:
            continue
        x = v2[sel]
        ok = np.isfinite(x)
        cnt = ok.sum(axis=0)
        m = np.where(cnt > 0, np.nansum(x, axis=0) / np.maximum(cnt, 1), 0.0)
        ss += np.nansum((x - m) ** 2, axis=0)
        dof += np.maximum(cnt - 1, 0)
    if not np.any(dof > 0):
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(dof > 0, np.sqrt(ss / np.maximum(dof, 1)), np.nan)
