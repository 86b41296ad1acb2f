"""Noise that cannot hide a change: replicate visits tested before they are pooled.

The repeatability of a campaign is the spread of its replicate visits (a model error
repeats at a pose, noise does not). A change during the campaign (a new load on the
platform, a slipped cable, a moved mast) repeats too, but only from its time on: pooled
with the visits before it, it becomes "noise" and hides itself (a load change between
the first and the second visit of each pose read as 17 N of load-cell noise, and the
model as explaining the data). So the replicate deviations (each sample's residual less
its replicate group's mean) are first tested for what noise cannot do:

- **by time and by pose**: a step at one time, the same at every pose or changing
  smoothly with the pose (a regression on ``[1, x, y, z]`` from the step on), scanned
  over the campaign's times;
- **by time, slowly**: a trend over the campaign (creep, a drift);
- **by direction of travel**: a length residual that differs with the sign of its
  cable's last move (hysteresis, backlash);
- **by time, every cable together**: where no length column alone shows a step or a trend,
  the columns' gains summed (a new load moves every cable by less than its noise).

Each test is an F-test against the deviations' own spread after it (scale-free: the
contaminated noise estimate is never the yardstick), Bonferroni-corrected over the
times scanned and the columns, floored by the row-to-row (white) noise, on independent
error units averaged (all rows of one move, and the dwell it leaves: they share the stop's
and the move's slow errors; a dwell alone otherwise). A step is also tried with the
direction of travel fitted beside it (friction's spread is no noise). Without load cells,
where no block shows a step, the residuals are tested along a change of the platform's load
(:mod:`bench.diagnosis.loadstep`). A systematic step splits the
replicate groups at its time (:func:`split_targets`), so the noise comes
from what is random; the step is then named (a slip's time) or declared ``unexplained``
with the time it began (:func:`declare`).

Recordings without replicates take their noise from the high-frequency part of the
residuals (:func:`high_frequency`): second differences of successive samples of one
move, which remove the motion's smooth part of the model error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse, stats
from scipy.sparse.csgraph import connected_components

from bench.diagnosis.residuals import Blocks, ResidualModel
from bench.diagnosis.samples import Samples

#: a systematic difference is declared below this p-value, after the correction for the
#: times scanned and the columns tested (a z of about 7)
P_SYSTEMATIC = 1e-12
#: ... and where the F-test's own p-value is below this, after the same correction: with few
#: replicate groups the F's tail is heavy and ``P_SYSTEMATIC`` alone would ask a step of
#: thousands of standard errors (:func:`systematic_p`); about 1e-3 false alarms per recording
#: from noise over its ~10 tests (4 blocks x step, trend, direction; the joint step)
P_FALSE = 1e-4
#: ... and where it is at least this large against the deviations' spread after it
MIN_SIZE = 3.0
#: ... for a step of all the length columns together (:func:`_joint_step`): each column moves
#: by less than its noise alone, significance comes from their number
MIN_JOINT_SIZE = 1.0
#: at most this many split times are scanned (evenly over the candidates)
MAX_SPLITS = 64
#: a split time is scanned where at least this many replicate groups span it
MIN_SPANNING = 3
#: the blocks tested (their values per :meth:`ResidualModel.block_values`)
TESTED = ("length", "force", "moment", "exit")


@dataclass
class Change:
    """A systematic difference between replicate visits.

    ``kind`` "step" (from ``t_s`` on), "trend" (over the campaign, from ``t_s``) or
    "direction" (by the sign of the cable's last move; ``t_s`` None); ``block`` and
    ``columns`` where it shows (column names: cable ids, ``x y z`` of the force or
    moment); ``z`` the significance as a normal deviate (corrected); ``size`` its RMS
    over the samples it moves, in units of the deviations' spread; ``before_s`` /
    ``after_s`` the last sample time before and the first after a step [s]."""

    kind: str
    block: str
    columns: list[str]
    t_s: float | None
    z: float
    size: float
    before_s: float | None = None
    after_s: float | None = None
    named: dict | None = field(default=None)
    #: found by the columns together (:func:`_joint_step`), none alone: a change of every
    #: cable (the platform's load), no one cable's slip
    joint: bool = False
    #: a step of block ``load`` (:func:`bench.diagnosis.loadstep.find`): the platform's
    #: load changed by this much [kg]
    load_kg: float | None = None

    def entry(self) -> dict:
        """The report's object (``unexplained.changes[]``; ``mismatch.noise.systematic``)."""
        out = {"kind": self.kind, "block": self.block, "columns": list(self.columns),
               "t_s": _round(self.t_s), "z": _round(self.z, 1),
               "size_over_noise": _round(self.size, 1)}
        if self.kind == "step":
            out["between_s"] = [_round(self.before_s), _round(self.after_s)]
        if self.joint:
            out["joint"] = True
        if self.load_kg is not None:
            out["load_change_kg"] = _round(self.load_kg, 2)
        if self.named is not None:
            out["named"] = dict(self.named)
        return out


def _round(x: float | None, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else float(round(x, nd))


def column_names(rm: ResidualModel, block: str, width: int) -> list[str]:
    """Names of a block's columns: cable ids (length), axes (force, moment), ``a<ax>_<id>``
    (exit)."""
    ids = list(rm.model.cable_ids)
    if block == "length":
        return ids[:width]
    if block in ("force", "moment"):
        return list("xyz")[:width]
    return [f"a{ax}_{c}" for c in ids for ax in "xyz"][:width]


def systematic_p(F: float, d1: float, d2: float, independent: bool = False) -> float:
    """The p-value a systematic difference is judged by, of an F statistic ``F`` of ``d1``
    and ``d2`` degrees of freedom: the larger of its normal-theory tail (chi-square of
    ``d1``, as if the spread were known: the statistic's size in standard errors, what
    :data:`P_SYSTEMATIC` asks, about z 7, beyond what misread errors can make) and its exact
    F tail scaled so that :data:`P_SYSTEMATIC` stands for :data:`P_FALSE` (the chance that
    noise alone makes it, with the spread estimated from ``d2`` degrees of freedom).
    Below ``P_SYSTEMATIC`` (after the correction) means both. With many degrees of freedom
    the two tails agree and the first decides; with a few (four poses visited three times:
    F(1, 7)) the exact tail cannot reach 1e-12 however large the step (load_change seed
    32010: the force balance's step 47 times its spread, p 6e-13 before the correction for
    three columns), and the second decides at its false-alarm rate. Only where the error
    units are ``independent`` (a dwell campaign's visits: each visit's rows averaged, the
    moves between them not recorded); with rows of moves a stop's slow error spans the
    moves and the dwell around it, the units' degrees of freedom are not the F's, and the
    exact tail alone decides (read with the normal tail, 2 of the 200-case evaluation's
    continuous_dwell null cases showed steps of z 7-8)."""
    if not F > 0:
        return 1.0
    if not independent:
        return float(stats.f.sf(F, d1, d2))
    p_normal = float(stats.chi2.sf(d1 * F, d1))
    return max(p_normal, float(stats.f.sf(F, d1, d2)) * P_SYSTEMATIC / P_FALSE)


def _z_of(p: float) -> float:
    """The normal deviate of a one-sided p-value (large for tiny p)."""
    return float(stats.norm.isf(max(p, 1e-300)))


def _centre(x: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``x`` (m,) or (m, q) less its mean over each group ``g`` (m,) (labels 0..k-1)."""
    cnt = np.bincount(g).astype(float)
    if x.ndim == 1:
        return x - (np.bincount(g, weights=x) / cnt)[g]
    means = np.stack([np.bincount(g, weights=x[:, j], minlength=len(cnt))
                      for j in range(x.shape[1])], axis=1) / cnt[:, None]
    return x - means[g]


def _unit_sums(U: np.ndarray, unit: np.ndarray, n_u: int) -> np.ndarray:
    """Columns of ``U`` (m, q) summed over each error unit ``unit`` (m,): (n_u, q)."""
    return np.stack([np.bincount(unit, weights=U[:, k], minlength=n_u)
                     for k in range(U.shape[1])], axis=1)


def _unit_fit(x: np.ndarray, U: np.ndarray, unit: np.ndarray, dof0: float, floor2: float,
              beside: np.ndarray | None = None
              ) -> tuple[float, float, float, np.ndarray] | None:
    """Least squares of deviations ``x`` (m,) on regressors ``U`` (m, q), both centred within
    their replicate groups, averaged over each error unit ``unit`` (m,) (labels 0..): units
    are independent, the samples of one are not. Averaged, not summed: a unit's samples
    share its slow error, their mean's spread is about one sample's whatever their number,
    their sum's grows with it (summed, a move of a dozen rows weighed twelve times a dwell,
    and the spread pooled over both was neither's: the null continuous_dwell campaigns
    12819 and 12840 read steps of z 7-9). ``dof0`` the units' degrees of freedom before;
    the residual variance floored at ``floor2`` per sample (white: over a unit's mean, its
    share of the samples). ``beside`` (m, k): regressors
    fitted with ``U`` whose part is no finding (:func:`_beside_direction`): ``x`` and ``U``
    are taken orthogonal to them, their degrees of freedom (their rank) spent. Returns (the
    sum of squares the regressors take, the residual variance per unit, its degrees of
    freedom, the fitted part per unit); None where nothing is fitted or fewer than two
    degrees of freedom are left."""
    q = U.shape[1]
    dof = dof0 - q
    if dof < 2 or not np.any(U):
        return None
    n_u = int(unit.max()) + 1
    size_u = np.bincount(unit, minlength=n_u).astype(float)
    xs = np.bincount(unit, weights=x, minlength=n_u) / size_u
    A = _unit_sums(U, unit, n_u) / size_u[:, None]
    if beside is not None:
        Q, rank = _basis(_unit_sums(beside, unit, n_u) / size_u[:, None])
        dof -= rank
        if dof < 2:
            return None
        xs = xs - Q @ (Q.T @ xs)
        A = A - Q @ (Q.T @ A)
        if not np.any(np.abs(A) > 1e-12 * max(1.0, float(np.abs(U).max()))):
            return None
    coef, *_ = np.linalg.lstsq(A, xs, rcond=None)
    fitted = A @ coef
    rss1 = float(np.sum((xs - fitted) ** 2))
    gain = float(np.sum(xs * xs)) - rss1
    if gain <= 0:
        return None
    return gain, max(rss1 / dof, floor2 * float(np.mean(1.0 / size_u))), dof, fitted


def _basis(B: np.ndarray) -> tuple[np.ndarray, int]:
    """An orthonormal basis (n_u, r) of the columns of ``B`` (n_u, k) and its rank ``r``
    (singular values above 1e-9 of the largest)."""
    if not B.size:
        return B[:, :0], 0
    u, sv, _ = np.linalg.svd(B, full_matrices=False)
    r = int(np.sum(sv > 1e-9 * max(float(sv[0]), 1e-300)))
    return u[:, :r], r


def _size(fitted: np.ndarray, s2: float) -> float:
    """RMS of a fitted part over the units it moves, in units of the spread ``sqrt(s2)``."""
    moved = np.abs(fitted) > 0
    return math.sqrt(float(np.mean(fitted[moved] ** 2)) / s2) if moved.any() else 0.0


def _ftest(x: np.ndarray, U: np.ndarray, unit: np.ndarray, dof0: float, floor2: float,
           independent: bool = False, beside: np.ndarray | None = None
           ) -> tuple[float, float] | None:
    """F-test of regressors ``U`` (m, q) on deviations ``x`` (m,) (:func:`_unit_fit`, with
    ``beside``). Returns (p-value, RMS of the fitted part over its residual spread)."""
    got = _unit_fit(x, U, unit, dof0, floor2, beside)
    if got is None:
        return None
    gain, s2, dof, fitted = got
    q = U.shape[1]
    return systematic_p(gain / q / s2, q, dof, independent), _size(fitted, s2)


def _column(x: np.ndarray, g: np.ndarray, unit: np.ndarray, ok: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] | None:
    """The samples of a column that compare error units within a replicate group: their
    indices, group labels 0..k-1, unit labels 0..u-1, deviations from the group means, and
    the units' degrees of freedom (units less the groups' connected components: twenty
    groups each holding a row of the same two moves are one difference, not twenty)."""
    idx = np.flatnonzero(ok & np.isfinite(x))
    if len(idx) < 6:
        return None
    for _ in range(2):  # (groups whose samples lie in two units or more)
        _, inv = np.unique(g[idx], return_inverse=True)
        inv = inv.ravel()
        _, uinv = np.unique(unit[idx], return_inverse=True)
        uinv = uinv.ravel()
        umin = np.full(inv.max() + 1, np.iinfo(np.int64).max)
        umax = np.full(inv.max() + 1, -1)
        np.minimum.at(umin, inv, uinv)
        np.maximum.at(umax, inv, uinv)
        keep = (umax > umin)[inv]
        if keep.all():
            break
        idx = idx[keep]
        if len(idx) < 6:
            return None
    k, n_u = int(inv.max()) + 1, int(uinv.max()) + 1
    graph = sparse.coo_matrix((np.ones(len(idx)), (inv, k + uinv)), shape=(k + n_u,) * 2)
    n_comp = connected_components(graph, directed=False)[0]
    return idx, inv, uinv, _centre(x[idx], inv), float(n_u - n_comp)


def _splits(t: np.ndarray, inv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Candidate step times: every midpoint between consecutive distinct times where at
    least :data:`MIN_SPANNING` groups have samples on both sides, and the coarse scan's, at
    most :data:`MAX_SPLITS` of them evenly (:func:`_refined` adds the others near the best
    coarse time)."""
    ut = np.unique(t)
    if len(ut) < 2:
        return ut[:0], ut[:0]
    mids = 0.5 * (ut[1:] + ut[:-1])
    k = int(inv.max()) + 1
    first = np.full(k, np.inf)
    last = np.full(k, -np.inf)
    np.minimum.at(first, inv, t)
    np.maximum.at(last, inv, t)
    spanning = ((first[None, :] < mids[:, None]) & (last[None, :] > mids[:, None])).sum(axis=1)
    mids = mids[spanning >= MIN_SPANNING]
    if len(mids) > MAX_SPLITS:
        return mids, mids[np.unique(np.linspace(0, len(mids) - 1, MAX_SPLITS).round()
                                    .astype(int))]
    return mids, mids


def _refined(best_t: float, coarse: np.ndarray, every: np.ndarray,
             p_coarse: np.ndarray | None = None) -> np.ndarray:
    """The candidate times of ``every`` between the coarse scan's (``coarse``) neighbours of
    its best time ``best_t`` [s], not scanned yet: a step lies between two samples, and a
    coarse time a few samples off splits some visits on the wrong side (load_change seed
    46102: a step of z 15 placed after the first sample of the new load; at its own time
    z 24). With the coarse times' p-values ``p_coarse``, also between the neighbours of the
    better of the best's two neighbours: the step lies on that side, and where the p-values
    beside a step are not monotone (visits of poses near the time on either side) the best
    coarse time can be the second one from it (load_change seed 46108: the coarse times'
    best 62 s after the change, its own time beyond the best's neighbour). Counted in the
    Bonferroni correction with the coarse times."""
    k = int(np.searchsorted(coarse, best_t))
    centres = [k]
    if p_coarse is not None and len(coarse) > 2:
        sides = [i for i in (k - 1, k + 1) if 0 <= i < len(coarse)]
        centres.append(min(sides, key=lambda i: p_coarse[i]))
    keep = np.zeros(len(every), dtype=bool)
    for c in centres:
        lo = coarse[c - 1] if c > 0 else -np.inf
        hi = coarse[c + 1] if c + 1 < len(coarse) else np.inf
        keep |= (every > lo) & (every < hi)
    return np.setdiff1d(every[keep], coarse)


def _scanned(scan: Callable[[np.ndarray, tuple | None], tuple | None], coarse: np.ndarray,
             every: np.ndarray) -> tuple[tuple | None, int]:
    """The best of ``scan`` (candidate times, the best so far -> the best, its p-value first
    and its time [s] third; None: no test) over the coarse times ``coarse``, then over
    :func:`_refined`'s near the best of them (``every``: all the candidates); and the number
    of times scanned, for the Bonferroni correction."""
    each = [scan(coarse[i:i + 1], None) for i in range(len(coarse))]
    p_coarse = np.array([1.0 if b is None else b[0] for b in each])
    tried = [b for b in each if b is not None]
    if not tried:
        return None, len(coarse)
    best = min(tried, key=lambda b: b[0])
    extra = _refined(best[2], coarse, every, p_coarse)
    return scan(extra, best), len(coarse) + len(extra)


def _step(x: np.ndarray, inv: np.ndarray, unit: np.ndarray, t: np.ndarray, pos: np.ndarray,
          dof0: float, floor2: float, independent: bool = False,
          beside: np.ndarray | None = None) -> tuple[float, float, float] | None:
    """The most significant step of deviations ``x`` over the candidate times (the coarse
    scan, then :func:`_refined`): (p-value Bonferroni-corrected over the times and the
    forms tried, size, time [s]). The step is the same at every pose, or a smooth function
    of it (``[1, x, y, z]`` from the step on, where the degrees of freedom allow it): both
    are tried (a uniform step, a new load in the force balance, is tested by one
    parameter, not spread over four that a few replicate groups would nearly saturate).
    ``independent``: as :func:`systematic_p`. ``beside`` (m, k) (:func:`_beside_direction`):
    each form is tried alone and with these regressors fitted beside it (:func:`_unit_fit`),
    both counted in the correction."""
    every, coarse = _splits(t, inv)
    if not len(coarse):
        return None
    forms = _forms(_pose_features(pos), dof0)
    besides = [None] if beside is None else [None, beside]

    def scan(times: np.ndarray, best: tuple | None) -> tuple | None:
        for tm in times:
            after = t >= tm
            for f in forms:
                for v in besides:
                    got = _ftest(x, _step_regressors(f, inv, after), unit, dof0, floor2,
                                 independent, v)
                    if got is not None and (best is None or got[0] < best[0]):
                        best = (got[0], got[1], float(tm))
        return best

    best, n_times = _scanned(scan, coarse, every)
    if best is None:
        return None
    return min(best[0] * n_times * len(forms) * len(besides), 1.0), best[1], best[2]


def _direction(x: np.ndarray, g: np.ndarray, d: np.ndarray, unit: np.ndarray,
               ok: np.ndarray, floor2: float, independent: bool = False
               ) -> tuple[float, float] | None:
    """F-test of the sign of the last move ``d`` on the deviations of ``x`` within groups
    ``g`` (error units split by that sign)."""
    sign = np.sign(d).astype(np.int64)
    col = _column(x, g, unit * 3 + sign + 1, ok & (sign != 0))
    if col is None:
        return None
    idx, inv, uinv, xc, dof0 = col
    if (sign[idx] > 0).sum() < 3 or (sign[idx] < 0).sum() < 3:
        return None
    return _ftest(xc, _centre(sign[idx][:, None].astype(float), inv), uinv, dof0, floor2,
                  independent)


def _beside_direction(d: np.ndarray, tau: np.ndarray, inv: np.ndarray, dof0: float
                      ) -> np.ndarray | None:
    """Regressors of the direction of travel, to fit beside a step (:func:`_step` tries it
    with and without them): per cable, the sign of its last move ``d`` (m, n) times its
    tension at the pose (the mean of ``tau`` (m, n) [N] over the replicate group ``inv``
    (m,); 1 where a sample's tension is not measured), centred within the groups. Friction at
    the pulleys or in the winches (outside the vocabulary) pulls against the motion in
    proportion to the tension: a visit's load-cell and length residuals depend on the
    direction each cable came from, visits of one pose differ by far more than their noise,
    and that spread pooled as noise hides a step beside it (load_change seeds 46103, 46108:
    the force balance's step at the change's time 1.4 times that spread, 3.1 beside these
    regressors). The group's mean tension, not the sample's own: a change of load changes
    the tensions from its time on, the regressors must not hold the step. None where they
    would leave fewer than 8 degrees of freedom beside a step's richest form (as
    :func:`_forms`)."""
    sign = np.sign(np.nan_to_num(d)).astype(float)
    mag = np.ones_like(sign)
    seen = np.isfinite(tau).all(axis=0)
    if seen.any():
        mag[:, seen] = tau[:, seen] - _centre(tau[:, seen], inv)
    V = _centre(sign * mag, inv)
    V = V[:, np.abs(V).max(axis=0) > 0]
    if V.shape[1] == 0 or dof0 - V.shape[1] - 4 < 8:
        return None
    return V


def _pose_features(pos: np.ndarray) -> np.ndarray:
    """``[1, x, y, z]`` of positions (m, 3), centred and scaled (constant axes dropped)."""
    cols = [np.ones(len(pos))]
    for a in range(pos.shape[1]):
        v = pos[:, a]
        sd = float(np.std(v))
        if sd > 1e-3 and np.isfinite(sd):
            cols.append((v - v.mean()) / sd)
    return np.stack(cols, axis=1)


def _forms(feats: np.ndarray, dof0: float) -> list[np.ndarray]:
    """The forms a step takes at samples of pose features ``feats`` (m, f)
    (:func:`_pose_features`), simplest first: the same at every pose (``[1]``), and a smooth
    function of the pose (``[1, x, y, z]``) only where the units' degrees of freedom ``dof0``
    leave at least 8 beside it and some axis varies."""
    if dof0 - feats.shape[1] < 8 or feats.shape[1] == 1:
        return [feats[:, :1]]
    return [feats[:, :1], feats]


def _step_regressors(form: np.ndarray, inv: np.ndarray, after: np.ndarray) -> np.ndarray:
    """A step's regressors: the form (m, q) (:func:`_forms`) on the samples at or after the
    step (``after`` (m,) bool), centred within the replicate groups ``inv`` (m,)."""
    return _centre(form * after[:, None], inv)


def _independent(resid: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """How many independent columns the residuals per error unit ``resid`` (per column: the
    units' sorted labels and residuals) hold: the participation ratio ``(sum l)^2 / sum l^2``
    of the eigenvalues ``l`` (negative ones as zero) of their correlation matrix, each pair
    over the units both have (m for independent columns, 1 for one error common to all; a
    pair with fewer than three units in common counts as independent)."""
    m = len(resid)
    C = np.eye(m)
    for a in range(m):
        for b in range(a + 1, m):
            common, ia, ib = np.intersect1d(resid[a][0], resid[b][0], return_indices=True)
            if len(common) < 3:
                continue
            xa, xb = resid[a][1][ia], resid[b][1][ib]
            if np.std(xa) > 0 and np.std(xb) > 0:
                C[a, b] = C[b, a] = float(np.corrcoef(xa, xb)[0, 1])
    lam = np.clip(np.linalg.eigvalsh(C), 0.0, None)
    return float(lam.sum() ** 2 / np.sum(lam ** 2))


def _unit_spanned(col: tuple, unit: np.ndarray, t: np.ndarray, mids: np.ndarray
                  ) -> np.ndarray:
    """(len(mids),) bool: whether the replicate groups of column ``col`` (:func:`_column`'s
    indices and groups) that have samples on both sides of each time in ``mids`` [s] hold at
    least :data:`MIN_SPANNING` distinct error units ``unit`` (N,) on each side of it."""
    idx, inv = col[0], col[1]
    tt, uu = t[idx], unit[idx]
    k = int(inv.max()) + 1
    ok = np.zeros(len(mids), dtype=bool)
    for i, tm in enumerate(mids):
        before = tt < tm
        spans = np.zeros(k, dtype=bool)
        spans[np.intersect1d(inv[before], inv[~before])] = True
        sel = spans[inv]
        ok[i] = (len(np.unique(uu[sel & before])) >= MIN_SPANNING
                 and len(np.unique(uu[sel & ~before])) >= MIN_SPANNING)
    return ok


def _joint_column(col: tuple, form: np.ndarray, units: np.ndarray, xs: np.ndarray,
                  after: np.ndarray
                  ) -> tuple[float, float, float | None, tuple[np.ndarray, np.ndarray]]:
    """One column's part of a joint step (:func:`_joint_step`) at one time: its whitened
    gain ``gain / s2``, its degrees of freedom left, the squared size of its fitted part
    (None where nothing is fitted) and its residuals per error unit (the units' sorted
    labels ``units`` and the means). ``col`` as in :func:`_joint_step`, ``form`` the step's
    form at its samples (:func:`_forms`), ``xs`` its deviations averaged per error unit,
    ``after`` (m,) its samples at or after the step."""
    idx, inv, uinv, x, dof0, floor2 = col
    got = _unit_fit(x, _step_regressors(form, inv, after), uinv, dof0, floor2)
    if got is None:
        return 0.0, dof0 - form.shape[1], None, (units, xs)
    gain, s2, dof, fitted = got
    return gain / s2, dof, _size(fitted, s2) ** 2, (units, xs - fitted)


def _joint_step(cols: list[tuple], unit: np.ndarray, t: np.ndarray, pos: np.ndarray,
                rank: float, independent: bool = False
                ) -> tuple[float, float, float, list[int]] | None:
    """The most significant step of a block's columns together, the same time in each:
    (p-value Bonferroni-corrected over the times, size, time [s], the columns in the order of
    their share, those above what noise gives). A change of the platform (its load) moves
    every cable's length residual by a fraction of the noise, each column alone short of
    significance; summed, the columns' whitened gains ``sum_j gain_j / s2_j`` are a
    chi-square of ``q r`` degrees of freedom under noise, ``r`` the independent columns:
    at most ``rank`` (the directions a sample's length residual keeps: 6 of n without
    tensions), at most what the residuals after the step show (:func:`_independent`: an
    error common to the cables counts once), tested as F(q r, dof r); only at times where
    the groups that span them do so with :data:`MIN_SPANNING` error units on each side
    (:func:`_unit_spanned`: the rows of two moves are one difference, whichever the cable).
    ``cols``:
    per column :func:`_column`'s indices, group and unit labels, deviations and units'
    degrees of freedom, and the floor of its variance; ``unit`` (N,) the error units'
    labels, ``t`` (N,) [s] and ``pos`` (N, 3) [m] of every sample."""
    if len(cols) < 2 or rank < 1:
        return None
    widest = max(cols, key=lambda c: len(c[0]))  # (its groups say which times are spanned)
    every, coarse = _splits(t[widest[0]], widest[1])
    if not len(coarse):
        return None
    dof_min = min(c[4] for c in cols)
    # (the richest form the fewest degrees of freedom allow; the test counts the last
    # column's parameters)
    forms = [_forms(_pose_features(pos[c[0]]), dof_min)[-1] for c in cols]
    units = [np.unique(unit[c[0]]) for c in cols]
    sums = [np.bincount(c[2], weights=c[3]) / np.bincount(c[2])  # (units' means: the
            for c in cols]                                       # same at every time)

    def scan(times: np.ndarray, best: tuple | None) -> tuple | None:
        for tm in times[_unit_spanned(widest, unit, t, times)]:
            got = _joint_at(cols, forms, units, sums, t >= tm, rank, independent)
            if got is not None and (best is None or got[0] < best[0]):
                best = (got[0], got[1], float(tm), got[2])
        return best

    best, n_times = _scanned(scan, coarse, every)
    if best is None:
        return None
    return min(best[0] * n_times, 1.0), best[1], best[2], best[3]


def _joint_at(cols: list[tuple], forms: list[np.ndarray], units: list[np.ndarray],
              sums: list[np.ndarray], after: np.ndarray, rank: float,
              independent: bool) -> tuple[float, float, list[int]] | None:
    """:func:`_joint_step` at one time: its p-value (uncorrected), size, and the columns in
    the order of their share, those above what noise gives; None where the degrees of
    freedom do not allow the test. ``after`` (N,) the samples at or after the step;
    ``forms``, ``units`` and ``sums`` per column as :func:`_joint_column` takes them."""
    q = forms[-1].shape[1]
    parts = [_joint_column(c, f, u, xs, after[c[0]])
             for c, f, u, xs in zip(cols, forms, units, sums, strict=True)]
    shares = [pt[0] for pt in parts]
    sizes = [pt[2] for pt in parts if pt[2] is not None]
    r = min(float(rank), _independent([pt[3] for pt in parts]))
    d2 = sum(pt[1] for pt in parts) / len(cols) * r
    if not sizes or r < 1 or d2 < 2:
        return None
    p = systematic_p(sum(shares) / (q * r), q * r, d2, independent)
    order = [int(k) for k in np.argsort(shares)[::-1] if shares[k] > q]
    return p, math.sqrt(float(np.mean(sizes))), order


def find_changes(rm: ResidualModel, b: Blocks, groups: dict[str, np.ndarray] | None = None
                 ) -> list[Change]:
    """Systematic differences between the replicate visits of ``rm``'s samples under the
    residual blocks ``b`` (of the recording's model), after the initialisation, in the
    replicate groups ``groups`` (per block, (N, d); default: ``rm``'s, split at the slips
    it knows). One finding per block and kind, the most significant column's, with every
    column significant beside it."""
    s = rm.s
    values = rm.block_values(b)
    G = rm.replicate_groups(None) if groups is None else groups
    live = ~s.is_init
    pos = np.where(np.isfinite(s.pose_meas[:, :3]), s.pose_meas[:, :3], s.pose_des[:, :3])
    live &= np.isfinite(pos).all(axis=1)
    count = np.maximum(s.count, 1).astype(float)
    unit = _units(s)
    # (a dwell campaign's visits are independent units: the small-sample tail may decide)
    independent = not bool((s.kind == 1).any())
    found: list[Change] = []
    for name in TESTED:
        v = values.get(name)
        if v is None or not np.isfinite(v).any():
            continue
        names = column_names(rm, name, v.shape[1])
        kind_white = np.array([rm.white_k[0][name], rm.white_k[1][name]])
        white2 = (kind_white[np.clip(s.kind, 0, 1)] ** 2 / count)
        hits: dict[str, list[tuple[float, float, float | None, str]]] = {}
        m = v.shape[1]
        for j in range(m):
            col = _column(v[:, j], G[name][:, j], unit, live)
            if col is None:
                continue
            idx, inv, uinv, x, dof0 = col
            floor2 = float(np.mean(white2[idx]))
            t = s.t[idx]
            beside = _beside_direction(s.direction[idx], s.tau[idx], inv, dof0)
            got = _step(x, inv, uinv, t, pos[idx], dof0, floor2, independent, beside)
            if got is not None:
                hits.setdefault("step", []).append((got[0] * m, got[1], got[2], names[j]))
            tr = _ftest(x, _centre((t - t.mean())[:, None], inv), uinv, dof0, floor2,
                        independent)
            if tr is not None:
                hits.setdefault("trend", []).append((tr[0] * m, tr[1], float(t.min()),
                                                     names[j]))
            if name == "length":
                dr = _direction(v[:, j], G[name][:, j], s.direction[:, j], unit, live,
                                floor2, independent)
                if dr is not None:
                    hits.setdefault("direction", []).append((dr[0] * m, dr[1], None,
                                                             names[j]))
        found += _declared(hits, name)
        if name == "length" and not any(c.block == name and c.kind != "direction"
                                        for c in found):
            joint = _joint(rm, v, G[name], names, unit, live & (s.kind == 0), white2, pos,
                           independent)
            if joint is not None:
                found.append(joint)
    return _prefer_steps(found, s.t[live])


def _declared(hits: dict[str, list[tuple[float, float, float | None, str]]], block: str
              ) -> list[Change]:
    """The changes of ``block`` declared from its columns' tests ``hits`` (per kind: per
    column (p-value corrected for the columns, size, time [s] or None, column name)): per
    kind, where a column is below :data:`P_SYSTEMATIC` and at least :data:`MIN_SIZE`, one
    change at the most significant column's time, naming every such column, the most
    significant first."""
    found = []
    for kind, rows in hits.items():
        sig = sorted((r for r in rows if r[0] < P_SYSTEMATIC and r[1] >= MIN_SIZE),
                     key=lambda r: r[0])
        if sig:
            found.append(Change(kind, block, [r[3] for r in sig], sig[0][2], _z_of(sig[0][0]),
                                sig[0][1]))
    return found


def _units(s: Samples) -> np.ndarray:
    """(N,) the error units of samples ``s``: rows of one move are one unit (their slow
    errors shared), and a dwell is one with the move that leaves it (the next sample in
    time a row of a move: the stop's slow error lasts until the platform reaches its next
    target; null continuous_dwell 12819: a dwell's deviation correlates 0.89 with the move
    leaving it, 0.02 with the move arriving); other dwells each their own."""
    unit = np.where(s.kind == 1, s.block, -1 - np.arange(s.n))
    order = np.argsort(s.t, kind="stable")
    a, b = order[:-1], order[1:]
    leaves = (s.kind[a] == 0) & (s.kind[b] == 1)
    unit[a[leaves]] = unit[b[leaves]]
    return unit


def _joint(rm: ResidualModel, v: np.ndarray, groups: np.ndarray, names: list[str],
           unit: np.ndarray, ok: np.ndarray, white2: np.ndarray, pos: np.ndarray,
           independent: bool = False) -> Change | None:
    """The length block's columns ``v`` (N, m) in their replicate ``groups`` (N, m) tested
    together for a step (:func:`_joint_step`) where no column alone shows a step or a
    trend, on the samples ``ok`` (N,) (dwells: rows of moves share slow errors along the
    move and blend those of its two stops, which the columns' sum would count as
    independent: continuous recordings read as steps of z 7): a ``joint`` step where
    significant (the Bonferroni factor 2: one more test beside the columns') and at least
    :data:`MIN_JOINT_SIZE` of the noise. ``white2`` (N,) the row noise's floor per sample."""
    cols = []
    for j in range(v.shape[1]):
        col = _column(v[:, j], groups[:, j], unit, ok)
        if col is not None:
            cols.append((j, (*col, float(np.mean(white2[col[0]])))))
    if len(cols) < 2:
        return None
    idx = np.unique(np.concatenate([c[1][0] for c in cols]))
    got = _joint_step([c[1] for c in cols], unit, rm.s.t, pos,
                      float(np.mean(rm.len_rank[idx])), independent)
    if got is None or 2.0 * got[0] >= P_SYSTEMATIC or got[1] < MIN_JOINT_SIZE:
        return None
    return Change("step", "length", [names[cols[k][0]] for k in got[3]], got[2],
                  _z_of(2.0 * got[0]), got[1], joint=True)


def _prefer_steps(found: list[Change], t: np.ndarray) -> list[Change]:
    """A step explains a trend of the same block (a step half-way is a trend too): the
    trend is dropped where the block's step is more significant. Steps get the times of
    the samples on each side."""
    steps = {c.block: c for c in found if c.kind == "step"}
    out = []
    for c in found:
        if c.kind == "trend" and c.block in steps and steps[c.block].z >= c.z:
            continue
        if c.kind == "step" and c.t_s is not None:
            before, after = t[t < c.t_s], t[t > c.t_s]
            c.before_s = float(before.max()) if len(before) else None
            c.after_s = float(after.min()) if len(after) else None
        out.append(c)
    return sorted(out, key=lambda c: -c.z)


def change_times(changes: list[Change]) -> list[float]:
    """The distinct times [s] of the steps among ``changes``, in order."""
    return sorted({c.t_s for c in changes if c.kind == "step" and c.t_s is not None})


def split_targets(target: np.ndarray, t: np.ndarray, times: list[float]) -> np.ndarray:
    """Replicate groups ``target`` (N,) split at ``times`` [s]: visits on different sides of
    a change are no replicates of each other (labels renumbered 0..)."""
    epoch = np.searchsorted(np.asarray(sorted(times), float), t, side="right")
    _, out = np.unique(np.stack([np.asarray(target), epoch], axis=1), axis=0,
                       return_inverse=True)
    return out.ravel().astype(np.asarray(target).dtype)


def name_slips(changes: list[Change], slip_times: dict[str, float],
               offsets: set[str] | frozenset[str] = frozenset()) -> None:
    """Mark the steps of length residuals that a named slip accounts for: a slip of one of
    the step's cables at a time between its samples (``slip_times``: cable id -> t [s] of
    the slips the report names), or a length offset the report names (``offsets``: cable
    ids) on one of the step's cables: that offset began at the step's time. A joint step
    (:func:`_joint_step`: every cable's, no column alone showing it) is none of one cable's
    slip or offset (seed 47110: a load change without cells, the fit's false slip of one
    cable inside its bracket had taken it)."""
    for c in changes:
        # (a joint step is every cable's, none alone showing it: no one cable's slip)
        if c.kind != "step" or c.block != "length" or c.joint:
            continue
        lo = c.before_s if c.before_s is not None else -np.inf
        hi = c.after_s if c.after_s is not None else np.inf
        for cid in c.columns:
            ts = slip_times.get(cid)
            if ts is not None and lo - 1e-6 <= ts <= hi + 1e-6:
                c.named = {"effect": "cable_length_offset", "cable": cid, "t_s": _round(ts)}
                break
        # (where a sample's pose or tensions are estimated, one cable's slip moves every
        # cable's residual: the slipped cable need not show most)
        mine = [cid for cid in c.columns if cid in offsets]
        if c.named is None and mine:
            c.named = {"effect": "cable_length_offset", "cable": mine[0], "t_s": _round(c.t_s)}


def annotate(effects: list[dict], changes: list[Change]) -> None:
    """Say in a named length offset's ``explains`` when the replicate visits show it began,
    where the fit did not place it in time (its slip time the initialisation)."""
    for e in effects:
        if e["name"] != "cable_length_offset" or "; from t = " in e["explains"]:
            continue
        got = [c.named for c in changes if c.named is not None and c.named.get("t_s")
               is not None and f"dl_{c.named['cable']}" in e["params"]]
        if got:
            e["explains"] += "; begun at " + ", ".join(
                f"t = {g['t_s']:.1f} s on cable {g['cable']}" for g in got) \
                + " (the replicate visits differ from then on)"


def high_frequency(rm: ResidualModel, b: Blocks) -> dict[str, float]:
    """Noise of one sample per block from the high-frequency part of the residuals ``b``:
    second differences of successive samples of one move or dwell stretch (``s.block``), in
    time order, ``sd = sqrt(mean(d2^2) / 6)`` (white noise: Var(x0 - 2 x1 + x2) = 6 var),
    robustly (1.4826 MAD); a smooth model error along the motion (linear over three
    samples) cancels. Blocks without three successive samples are left out."""
    s = rm.s
    values = rm.block_values(b)
    order = np.lexsort((s.t, s.block))
    out = {}
    for name, v in values.items():
        x = v[order]
        blk = s.block[order]
        same = (blk[2:] == blk[1:-1]) & (blk[1:-1] == blk[:-2])
        d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
        d2 = d2[same]
        d2 = d2[np.isfinite(d2)]
        if d2.size < 6:
            continue
        out[name] = float(1.4826 * np.median(np.abs(d2)) / math.sqrt(6.0))
    return out


def separate(rm: ResidualModel, say=lambda m: None) -> list[Change]:
    """Test ``rm``'s replicate visits under its model (:func:`find_changes`) and, where a step
    is found, split the replicate groups (``rm.s.target``) at its time and estimate the
    noise again: the noise comes from what is random. Where no block shows a step, the
    residuals are tested along a change of the platform's load (:func:`bench.diagnosis.
    loadstep.find`: without load cells, a new load moves every entry by a fraction of its
    noise). Returns every change found."""
    from bench.diagnosis import loadstep

    model = rm.model
    b = rm.blocks(model)
    changes = find_changes(rm, b)
    if not any(c.kind == "step" for c in changes):
        load = loadstep.find(rm, b)
        changes += [load] if load is not None else []
    for c in changes:
        where = f" from t = {c.t_s:.1f} s" if c.t_s is not None and c.kind == "step" else ""
        say(f"replicate visits differ systematically ({c.kind}{where}, {c.block} "
            f"{', '.join(c.columns[:4])}; z = {c.z:.0f}): not pooled as noise")
    times = change_times(changes)
    if times:
        rm.s.target = split_targets(rm.s.target, rm.s.t, times)
        rm.estimate_noise(model)
        nz = rm.noise_summary()
        say(f"noise, the replicate groups split at t = "
            f"{', '.join(f'{t:.1f}' for t in times)} s: lengths {nz['length'] * 1e3:.3f} mm, "
            f"forces {nz['force']:.2f} N")
    return changes


def floor_assumed(rm: ResidualModel, say=lambda m: None) -> dict[str, float]:
    """Without replicate visits (``rm``'s noise assumed): the high-frequency noise of the
    residuals under the model (:func:`high_frequency`) measured, and the assumed
    repeatability raised to it where it is below (the noise of one sample cannot be less
    than its successive samples show; a fit's own chi-square is never the yardstick).
    Returns the high-frequency estimate per block (reported with the noise)."""
    hf = high_frequency(rm, rm.blocks(rm.model))
    if rm.sigma_source == "replicate visits" or not hf:
        return hf
    raised = []
    for kind in (0, 1):
        for name, v in hf.items():
            have = math.hypot(rm.sigma_k[kind][name], rm.white_k[kind][name])
            if v > have:
                rm.sigma_k[kind][name] = math.sqrt(v * v - rm.white_k[kind][name] ** 2)
                raised.append(name)
    if raised:
        rm.sigma = dict(rm.sigma_k[int(np.bincount(rm.s.kind, minlength=2).argmax())])
        rm._update_sd()
        rm.sigma_source += ", raised to the high-frequency residuals"
        say(f"no replicate visits: the assumed noise raised to the high-frequency residuals "
            f"({', '.join(sorted(set(raised)))})")
    return hf
