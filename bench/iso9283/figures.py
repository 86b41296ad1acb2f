"""ISO 9283:1998 pose and path figures: pure functions on numpy arrays, SI units (m, rad).

Pose characteristics (one command pose c, n attained poses j = 1..n, "cycles"):

- barycentre of the attained positions ``x̄ = (1/n) Σ_j x_j`` (same for y, z);
- pose accuracy ``AP_x = x̄ − x_c``, ``AP_y = ȳ − y_c``, ``AP_z = z̄ − z_c`` and
  ``AP = AP_P = sqrt((x̄ − x_c)² + (ȳ − y_c)² + (z̄ − z_c)²)``;
- orientation accuracy ``AP_a = ā − a_c``, ``AP_b = b̄ − b_c``, ``AP_c = c̄ − c_c`` with
  ``ā = (1/n) Σ_j a_j``;
- pose repeatability ``RP = RP_l = l̄ + 3 S_l`` with ``l_j = |p_j − p̄|`` (distance of attained
  position j to the barycentre), ``l̄ = (1/n) Σ_j l_j`` and
  ``S_l = sqrt(Σ_j (l_j − l̄)² / (n − 1))``;
- orientation repeatability ``RP_a = ±3 S_a = ±3 sqrt(Σ_j (a_j − ā)² / (n − 1))`` (same for
  b, c); the figures hold the half-width 3 S_a.

Path characteristics (a commanded path sampled at m points C_i, n attained passes):

- the normal plane at C_i is the plane through C_i normal to the commanded path's tangent
  there; the attained point x_ij is where pass j crosses that plane (see
  :func:`normal_plane_points`). The standard leaves corners (cornering is a figure of its
  own); here a point at a corner takes the normal plane of the leg that leaves it
  (:func:`resample_path` with ``with_tangents``), never the bisector;
- barycentre ``x̄_i = (1/n) Σ_j x_ij`` (and y, z, a, b, c);
- path accuracy ``AT = AT_P = max_i sqrt((x̄_i − x_ci)² + (ȳ_i − y_ci)² + (z̄_i − z_ci)²)``
  and ``AT_a = max_i |ā_i − a_ci|`` (b, c alike);
- path repeatability ``RT = RT_l = max_i (l̄_i + 3 S_li)`` with ``l_ij = |x_ij − x̄_i|``,
  ``l̄_i = (1/n) Σ_j l_ij``, ``S_li = sqrt(Σ_j (l_ij − l̄_i)² / (n − 1))``, and
  ``RT_a = max_i 3 S_ai``, ``S_ai = sqrt(Σ_j (a_ij − ā_i)² / (n − 1))``;
- beyond the standard (the paper's Table 3 and Fig. 7): the mean deviation ``AT_mean`` (the
  barycentre deviation averaged along the path, weighted by arc length) and the deviation's
  components ``AT_x,i = x̄_i − x_ci`` (y, z) along the path.

Orientation: the standard's a, b, c are rotations about the base axes x_b, y_b, z_b. The
project's pose is ``R = Rz(yaw)·Ry(pitch)·Rx(roll)`` (fixed axes, cdpr-conventions.md), so
a, b, c are roll, pitch, yaw. Angle differences are wrapped into [−π, π) (so that a yaw of
179° against a command of −179° counts as 2°); the mean angle is the command plus the mean
wrapped deviation. Away from ±π this is the standard's arithmetic mean.

With n = 1 the repeatabilities (n − 1 in S) are NaN. Positions must be finite; an
orientation angle with a NaN (a tracker that measures positions only) gives NaN for that
angle's figures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: plane side below which a point counts as lying on a normal plane [m]
_ON_PLANE = 1e-12


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angle(s) wrapped into [−π, π) [rad]."""
    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def _as_poses(a: np.ndarray | Sequence, name: str, ndim: int) -> np.ndarray:
    """``a`` as float array of ndim dims whose last axis has 3 or 6 columns, padded to 6 with
    NaN (positions only: orientation not measured)."""
    arr = np.asarray(a, dtype=float)
    if arr.ndim != ndim or arr.shape[-1] not in (3, 6):
        raise ValueError(f"{name}: expected shape {'(n, 3|6)' if ndim == 2 else '(3|6,)'}, "
                         f"got {arr.shape}")
    if arr.shape[-1] == 3:
        arr = np.concatenate([arr, np.full(arr.shape[:-1] + (3,), np.nan)], axis=-1)
    return arr


def _sample_std(v: np.ndarray, axis: int = 0) -> np.ndarray:
    """Sample standard deviation with n − 1 (NaN for fewer than two values)."""
    n = v.shape[axis]
    if n < 2:
        return np.full(np.delete(v.shape, axis), np.nan) if v.ndim > 1 else np.array(np.nan)
    return np.std(v, axis=axis, ddof=1)


def repeatability_radius(points: np.ndarray) -> tuple[float, float, float]:
    """``(l̄ + 3 S_l, l̄, S_l)`` of positions (n, 3) about their barycentre [m].

    ``l_j = |p_j − p̄|``, ``l̄ = (1/n) Σ l_j``, ``S_l = sqrt(Σ (l_j − l̄)² / (n − 1))``;
    NaN figures for n < 2. This is RP (pose) and, per normal plane, RT (path).
    """
    p = np.asarray(points, dtype=float)
    if len(p) == 0:
        return np.nan, np.nan, np.nan
    l_j = np.linalg.norm(p - p.mean(axis=0), axis=1)
    l_mean = float(l_j.mean())
    s_l = float(_sample_std(l_j))
    return l_mean + 3.0 * s_l, l_mean, s_l


@dataclass(frozen=True)
class PoseFigures:
    """ISO 9283 figures of one command pose (SI: m, rad).

    ``command``/``barycentre`` (6,) x, y, z, a, b, c; ``ap_xyz`` (APx, APy, APz); ``ap`` AP;
    ``l_j`` (n,) distances of the attained positions to their barycentre; ``rp`` RP =
    ``l_mean + 3 s_l``; ``ap_abc`` (AP_a, AP_b, AP_c); ``s_abc`` (S_a, S_b, S_c);
    ``rp_abc`` (RP_a, RP_b, RP_c) = 3 S (the ± half-width).
    """

    n: int
    command: np.ndarray
    barycentre: np.ndarray
    ap_xyz: np.ndarray
    ap: float
    l_j: np.ndarray
    l_mean: float
    s_l: float
    rp: float
    ap_abc: np.ndarray
    s_abc: np.ndarray
    rp_abc: np.ndarray

    def to_dict(self) -> dict[str, float | int]:
        """The scalar figures under the keys of ``cdpr iso9283 --json`` (m, rad)."""
        d: dict[str, float | int] = {"n": self.n}
        for k, v in zip(("apx_m", "apy_m", "apz_m"), self.ap_xyz, strict=True):
            d[k] = float(v)
        d.update(ap_m=self.ap, rp_m=self.rp, l_mean_m=self.l_mean, s_l_m=self.s_l)
        for ax, a, r in zip("abc", self.ap_abc, self.rp_abc, strict=True):
            d[f"ap_{ax}_rad"] = float(a)
            d[f"rp_{ax}_rad"] = float(r)
        return d


def pose_figures(attained: np.ndarray | Sequence, command: np.ndarray | Sequence) -> PoseFigures:
    """ISO 9283 pose accuracy and repeatability of n attained poses of one command pose.

    ``attained`` (n, 3) positions or (n, 6) poses x, y, z, roll, pitch, yaw [m, rad];
    ``command`` (3,) or (6,). See the module docstring for the formulas.
    """
    att = _as_poses(attained, "attained", 2)
    cmd = _as_poses(command, "command", 1)
    n = len(att)
    if n == 0:
        raise ValueError("attained: no pose")
    if not (np.isfinite(att[:, :3]).all() and np.isfinite(cmd[:3]).all()):
        raise ValueError("positions must be finite")
    bary_p = att[:, :3].mean(axis=0)
    ap_xyz = bary_p - cmd[:3]
    rp, l_mean, s_l = repeatability_radius(att[:, :3])
    l_j = np.linalg.norm(att[:, :3] - bary_p, axis=1)
    dev = wrap_angle(att[:, 3:] - cmd[3:])  # a_j − a_c, wrapped
    ap_abc = dev.mean(axis=0)  # ā − a_c (NaN where an angle is missing)
    s_abc = _sample_std(dev, axis=0) if n >= 2 else np.full(3, np.nan)
    bary = np.concatenate([bary_p, wrap_angle(cmd[3:] + ap_abc)])
    return PoseFigures(n, cmd, bary, ap_xyz, float(np.linalg.norm(ap_xyz)), l_j, l_mean, s_l, rp,
                       ap_abc, np.asarray(s_abc, dtype=float), 3.0 * np.asarray(s_abc, float))


# ---------------------------------------------------------------------------------------------
# paths


def resample_path(points: np.ndarray | Sequence, count: int, with_tangents: bool = False
                  ) -> tuple[np.ndarray, ...]:
    """``(s, pts)``: ``count`` points evenly spaced by arc length along a polyline.

    ``points`` (N, 3|6) in order of travel; repeated positions are dropped; positions are
    interpolated linearly in arc length s [m] (of the positions), angles likewise after
    unwrapping. ``with_tangents``: also the unit tangents (count, 3), the direction of the
    polyline's segment each point lies on (at a vertex, the segment that leaves it; at the
    end, the last one): at a corner of the polyline the normal plane is then the incoming
    or the outgoing leg's, never the bisector a central difference would give. Raises
    ValueError for a path of zero length or count < 2.
    """
    p = _as_poses(points, "points", 2)
    if count < 2:
        raise ValueError(f"count: {count}: need at least 2 points")
    p = p[np.isfinite(p[:, :3]).all(axis=1)]
    if len(p) >= 2:
        step = np.linalg.norm(np.diff(p[:, :3], axis=0), axis=1)
        p = p[np.concatenate([[True], step > 0])]
    if len(p) < 2:
        raise ValueError("the path has zero length")
    seg = np.diff(p[:, :3], axis=0)
    s_in = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    s = np.linspace(0.0, s_in[-1], count)
    out = np.empty((count, 6))
    for c in range(3):
        out[:, c] = np.interp(s, s_in, p[:, c])
    for c in range(3, 6):
        col = p[:, c]
        if np.isfinite(col).all():
            out[:, c] = wrap_angle(np.interp(s, s_in, np.unwrap(col)))
        else:
            out[:, c] = np.nan
    if not with_tangents:
        return s, out
    # (within a rounding error of a vertex counts as at it)
    k = np.clip(np.searchsorted(s_in, s + 1e-9 * s_in[-1], side="right") - 1, 0, len(seg) - 1)
    t = seg[k] / np.linalg.norm(seg[k], axis=1)[:, None]
    return s, out, t


def path_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents (m, 3) of a polyline of m ≥ 2 distinct positions: central differences
    inside, one-sided at the ends (the normal planes of ISO 9283 path figures)."""
    p = np.asarray(points, dtype=float)[:, :3]
    if len(p) < 2:
        raise ValueError("a path needs at least 2 points")
    t = np.empty_like(p)
    t[1:-1] = p[2:] - p[:-2]
    t[0] = p[1] - p[0]
    t[-1] = p[-1] - p[-2]
    norm = np.linalg.norm(t, axis=1)
    if np.any(norm == 0):
        raise ValueError("the path has repeated or back-tracking points (no tangent)")
    return t / norm[:, None]


def normal_plane_points(command: np.ndarray | Sequence, attained: np.ndarray | Sequence,
                        max_distance: float | None = None, tangents: np.ndarray | None = None,
                        block: int = 2_000_000) -> np.ndarray:
    """Where one attained pass crosses the normal planes of the commanded path.

    ``command`` (m, 3|6) commanded points in order of travel (distinct positions);
    ``attained`` (N, 3|6) the measured poses of one pass in time order (rows with a NaN
    position are skipped). Returns (m, 6): for each commanded point C_i, the attained pose
    interpolated linearly (angles on their wrapped difference) at the crossing of the pass's
    polyline with the plane through C_i normal to the path's tangent t_i (``tangents`` (m, 3)
    unit vectors, default :func:`path_tangents` of the points); NaN where the pass does not
    cross.

    Rule for a plane crossed several times (a path that comes back near itself, a corner cut
    short, noise at rest):

    - only crossings in the direction of travel count (the signed distance ``(P − C_i)·t_i``
      goes from ≤ 0 to > 0, or from < 0 to ≥ 0), none farther than ``max_distance`` [m] from
      C_i if given, and of each plane the :data:`_KEEP` nearest;
    - the crossings taken must follow the pass in order: as i increases, the crossing's
      position along the attained polyline never goes back. Of the chains of crossings that
      do, the one that matches the most commanded points is taken, and of those the one
      with the smallest sum of distances to the C_i (dynamic programming). A plane whose
      only crossings are out of order (e.g. the last plane of a closed path that the pass
      ends short of, but that it crossed near its start) stays unmatched (NaN).
    """
    cmd = _as_poses(command, "command", 2)
    att = _as_poses(attained, "attained", 2)
    att = att[np.isfinite(att[:, :3]).all(axis=1)]
    m = len(cmd)
    out = np.full((m, 6), np.nan)
    if len(att) < 2:
        return out
    C = cmd[:, :3]
    T = path_tangents(cmd) if tangents is None else np.asarray(tangents, dtype=float)
    if T.shape != C.shape:
        raise ValueError(f"tangents: expected shape {C.shape}, got {T.shape}")
    P = att[:, :3]
    dP = np.diff(P, axis=0)
    dA = wrap_angle(np.diff(att[:, 3:], axis=0))
    cand_i, cand_q, cand_d, cand_x = [], [], [], []
    chunk = max(1, block // len(P))
    for i0 in range(0, m, chunk):
        i1 = min(m, i0 + chunk)
        sd = np.einsum("ik,nk->in", T[i0:i1], P) - np.einsum("ik,ik->i", T[i0:i1],
                                                             C[i0:i1])[:, None]
        sd[np.abs(sd) < _ON_PLANE] = 0.0
        a, b = sd[:, :-1], sd[:, 1:]
        ii, kk = np.nonzero(((a <= 0) & (b > 0)) | ((a < 0) & (b >= 0)))
        if not len(ii):
            continue
        f = -a[ii, kk] / (b[ii, kk] - a[ii, kk])
        X = P[kk] + f[:, None] * dP[kk]
        d = np.linalg.norm(X - C[i0 + ii], axis=1)
        keep = np.ones(len(ii), dtype=bool) if max_distance is None else d <= max_distance
        ii, kk, f, X, d = ii[keep], kk[keep], f[keep], X[keep], d[keep]
        order = np.lexsort((d, ii))
        ii, kk, f, X, d = ii[order], kk[order], f[order], X[order], d[order]
        start = np.searchsorted(ii, ii, side="left")
        near = np.arange(len(ii)) - start < _KEEP  # the _KEEP nearest of each plane
        cand_i.append(i0 + ii[near])
        cand_q.append(kk[near] + f[near])
        cand_d.append(d[near])
        cand_x.append(np.c_[X[near], wrap_angle(att[kk[near], 3:]
                                                + f[near, None] * dA[kk[near]])])
    if not sum(len(c) for c in cand_i):
        return out
    ci, cq, cd = np.concatenate(cand_i), np.concatenate(cand_q), np.concatenate(cand_d)
    cx = np.concatenate(cand_x)
    for k in _ordered_chain(ci, cq, cd):
        out[ci[k]] = cx[k]
    return out


#: crossings of one normal plane kept (nearest first) for the ordered chain
_KEEP = 8


def _ordered_chain(ci: np.ndarray, cq: np.ndarray, cd: np.ndarray) -> list[int]:
    """Indices of the candidates (plane ``ci``, position along the pass ``cq``, distance
    ``cd``; sorted by ci) forming the chain with increasing ci, non-decreasing cq, at most
    one per plane, the most candidates and then the smallest sum of cd."""
    n = len(ci)
    big = float(cd.sum()) + 1.0  # one more match outweighs any sum of distances
    ranks = np.searchsorted(np.unique(cq), cq) + 1  # 1-based for the Fenwick tree
    size = int(ranks.max())
    tree_v = np.full(size + 1, -np.inf)
    tree_k = np.full(size + 1, -1)
    value = np.empty(n)
    prev = np.full(n, -1)

    def query(r: int) -> tuple[float, int]:  # best (value, index) with rank <= r
        best, arg = -np.inf, -1
        while r > 0:
            if tree_v[r] > best:
                best, arg = tree_v[r], tree_k[r]
            r -= r & -r
        return best, arg

    def update(r: int, v: float, k: int) -> None:
        while r <= size:
            if v > tree_v[r]:
                tree_v[r], tree_k[r] = v, k
            r += r & -r

    bounds = np.flatnonzero(np.diff(np.concatenate([[-1], ci, [ci[-1] + 1]])) != 0)
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        for k in range(a, b):  # all of one plane first: no chain holds two of a plane
            best, arg = query(int(ranks[k]))
            base = best if arg >= 0 else 0.0
            value[k] = base + big - cd[k]
            prev[k] = arg
        for k in range(a, b):
            update(int(ranks[k]), value[k], k)
    k = int(np.argmax(value))
    chain = []
    while k >= 0:
        chain.append(k)
        k = int(prev[k])
    return chain[::-1]


@dataclass(frozen=True)
class PathFigures:
    """ISO 9283 path figures of n passes over one commanded path (SI: m, rad).

    Along the path (m points): ``s`` arc length; ``command`` (m, 6); ``points`` (n, m, 6)
    the passes' normal-plane points; ``count`` passes that cross each plane; ``complete``
    the points all n passes cross; ``barycentre`` (m, 6); ``dev_xyz`` (m, 3) the components
    AT_x, AT_y, AT_z (barycentre minus command); ``dev`` (m,) their norm; ``dev_abc`` (m, 3)
    ā_i − a_ci; ``rt_points`` (m,) l̄_i + 3 S_li; ``s_abc`` (m, 3) S_ai.

    Summaries over the complete points: ``at`` AT (max of ``dev``), ``at_mean`` (mean of
    ``dev`` weighted by arc length), ``at_s`` where AT occurs [m along the path], ``at_abc``
    (AT_a, AT_b, AT_c) max |ā_i − a_ci|, ``rt`` RT (max of ``rt_points``, NaN for n < 2),
    ``rt_abc`` max 3 S_ai.
    """

    n: int
    s: np.ndarray
    command: np.ndarray
    points: np.ndarray
    count: np.ndarray
    complete: np.ndarray
    barycentre: np.ndarray
    dev_xyz: np.ndarray
    dev: np.ndarray
    dev_abc: np.ndarray
    rt_points: np.ndarray
    s_abc: np.ndarray
    at: float
    at_mean: float
    at_s: float
    at_abc: np.ndarray
    rt: float
    rt_abc: np.ndarray

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def to_dict(self) -> dict[str, float | int]:
        """The scalar figures under the keys of ``cdpr iso9283 --json`` (m, rad)."""
        d: dict[str, float | int] = {
            "passes": self.n, "points": len(self.s),
            "points_complete": int(self.complete.sum()), "length_m": self.length,
            "at_max_m": self.at, "at_mean_m": self.at_mean, "at_max_at_s_m": self.at_s,
            "rt_m": self.rt}
        for ax, a, r in zip("abc", self.at_abc, self.rt_abc, strict=True):
            d[f"at_{ax}_rad"] = float(a)
            d[f"rt_{ax}_rad"] = float(r)
        return d


def _arc_weights(s: np.ndarray) -> np.ndarray:
    """Trapezoid weights of points at arc lengths s (half segments on each side)."""
    if len(s) < 2:
        return np.ones(len(s))
    w = np.zeros(len(s))
    ds = np.diff(s)
    w[:-1] += ds / 2
    w[1:] += ds / 2
    return w


def _nanmax(v: np.ndarray) -> float:
    v = v[np.isfinite(v)]
    return float(v.max()) if len(v) else float("nan")


def path_figures(command: np.ndarray | Sequence, passes: Sequence[np.ndarray],
                 s: np.ndarray | None = None, max_distance: float | None = None,
                 tangents: np.ndarray | None = None) -> PathFigures:
    """ISO 9283 path accuracy and repeatability of attained passes over a commanded path.

    ``command`` (m, 3|6) commanded points in order of travel (for a fair ``at_mean``, evenly
    spaced: :func:`resample_path`); ``passes`` a list of (N_j, 3|6) measured poses in time
    order; ``s`` (m,) arc length of the commanded points (default: along the polyline);
    ``tangents`` (m, 3) the path's unit tangents there (default: central differences; give
    those of :func:`resample_path` for a path with corners). Each pass is matched to the
    commanded points by :func:`normal_plane_points`. Raises
    ValueError if there is no pass or no commanded point that every pass crosses.
    """
    cmd = _as_poses(command, "command", 2)
    n = len(passes)
    if n == 0:
        raise ValueError("passes: no attained pass")
    if s is None:
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(cmd[:, :3], axis=0),
                                                            axis=1))])
    s = np.asarray(s, dtype=float)
    pts = np.stack([normal_plane_points(cmd, p, max_distance, tangents)
                    for p in passes])  # (n, m, 6)
    crossed = np.isfinite(pts[:, :, :3]).all(axis=2)
    count = crossed.sum(axis=0)
    complete = count == n
    if not complete.any():
        raise ValueError("no point of the commanded path is crossed by every pass (do the "
                         "passes follow the commanded path?)")
    m = len(cmd)
    bary = np.full((m, 6), np.nan)
    dev_abc = np.full((m, 3), np.nan)
    rt_pts = np.full(m, np.nan)
    s_abc = np.full((m, 3), np.nan)
    for i in np.flatnonzero(count > 0):
        att = pts[crossed[:, i], i]
        bary[i, :3] = att[:, :3].mean(axis=0)
        d = wrap_angle(att[:, 3:] - cmd[i, 3:])
        dev_abc[i] = d.mean(axis=0)
        bary[i, 3:] = wrap_angle(cmd[i, 3:] + dev_abc[i])
        rt_pts[i] = repeatability_radius(att[:, :3])[0]
        if len(att) >= 2:
            s_abc[i] = np.std(d, axis=0, ddof=1)
    dev_xyz = bary[:, :3] - cmd[:, :3]
    dev = np.linalg.norm(dev_xyz, axis=1)
    dc = np.where(complete, dev, np.nan)
    k = int(np.nanargmax(dc))
    w = _arc_weights(s) * complete
    at_mean = float(np.sum(w * np.nan_to_num(dc)) / w.sum()) if w.sum() > 0 else float(dc[k])
    at_abc = np.array([_nanmax(np.abs(dev_abc[complete, c])) for c in range(3)])
    rt = _nanmax(rt_pts[complete]) if n >= 2 else float("nan")
    rt_abc = (np.array([_nanmax(3.0 * s_abc[complete, c]) for c in range(3)]) if n >= 2
              else np.full(3, np.nan))
    return PathFigures(n, s, cmd, pts, count, complete, bary, dev_xyz, dev, dev_abc, rt_pts,
                       s_abc, float(dc[k]), at_mean, float(s[k]), at_abc, rt, rt_abc)
