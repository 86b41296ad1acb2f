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
  time, per cable and common to all;
- **regions** of the workspace where the residual is largest.

:func:`analyse` returns the report's ``unexplained`` object, or None when the
model explains the data within the noise.
"""

from __future__ import annotations

import math

import numpy as np

from bench.diagnosis import locate
from bench.diagnosis.residuals import Blocks, ResidualModel

#: the fitted model leaves clearly more than the noise above this reduced chi-square ...
LEVEL = 1.5
#: ... when it also stands this many standard deviations above 1
LEVEL_Z = 4.0
#: a structured residual (direction, time) is declared at this significance ...
STRUCT_Z = 8.0
#: ... when it is also this large against the noise (half the difference, or the drift)
STRUCT_SIZE = 1.0
#: a cable stands out when its residual RMS is this many times the others' median ...
CABLE_RATIO = 2.0


def analyse(rm: ResidualModel, b: Blocks, n_params: int, s_regions, init_pose: np.ndarray,
            pivots: np.ndarray, mast_ids: tuple[str, ...]) -> dict | None:
    """The ``unexplained`` object for the fitted model's residual blocks ``b``."""
    model = rm.model
    s = rm.s
    w = rm.s.weight
    chi = rm.whitened_by_sample(b)
    ok = np.isfinite(chi)
    if not ok.any():
        return None
    r = rm.whiten(b)
    n_res = float(rm.entry_weights().sum())  # rows of a move count together
    dof = max(n_res - n_params - rm.dof_lost(), 1.0)
    chi2 = float(r @ r)
    ratio = chi2 / dof
    # spread of the ratio: chi-square of dof residuals, and a noise estimate of its own dof
    nd = rm.replicate_dof * max(model.n_cables, 1) if rm.sigma_source == "replicate visits" \
        else 0
    sd = math.sqrt(2.0 / dof + (2.0 / nd if nd > 0 else 0.0))
    level = ratio > LEVEL and (ratio - 1.0) > LEVEL_Z * sd
    assumed = rm.sigma_source != "replicate visits"
    findings: list[str] = []
    out: dict = {"reduced_chi2": ratio, "rms_over_noise": math.sqrt(max(ratio, 0.0)),
                 "noise_source": rm.sigma_source}

    # per cable, per mast: whitened length residual RMS
    L = b.length / rm.sd["length"][:, None]
    L = np.where(rm.has_len[:, None], L, np.nan)
    if np.isfinite(L).any():
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
        # direction of motion: residual after paying out vs after reeling in
        dirs = []
        for k, cid in enumerate(model.cable_ids):
            d = _two_groups(L[:, k], s.direction[:, k], w)
            if d is not None:
                dirs.append((cid, *d))
        if dirs:
            out["direction"] = {c: {"difference_over_noise": _r(diff), "z": _r(z)}
                                for c, diff, z in dirs}
            strong = [(c, diff, z) for c, diff, z in dirs
                      if abs(z) > STRUCT_Z and abs(diff) > STRUCT_SIZE]
            if strong:
                c, diff, z = max(strong, key=lambda x: abs(x[2]))
                findings.append(f"cable {c}'s length residual depends on the direction of its "
                                f"last move: {abs(diff):.1f} times the noise between paying "
                                f"out and reeling in (z = {abs(z):.0f}; backlash or friction?)")
        # time: a trend common to the cables, and per cable
        tt = s.t - np.nanmean(s.t)
        # samples whose errors are independent: each dwell of a dwell campaign (the visits
        # of a target are apart in time), stretches of moves otherwise
        moves = bool((s.kind == 1).any()) and s.cluster is not None and len(s.cluster) == s.n
        clusters = s.cluster if moves else np.arange(s.n)
        if np.ptp(s.t) > 0:
            trend = []
            for k, cid in enumerate(model.cable_ids):
                tr = _slope(*_by_cluster(L[:, k], tt, w, clusters))
                if tr is not None:
                    trend.append((cid, *tr))
            common = _slope(*_by_cluster(np.nanmean(L, axis=1), tt, w, clusters))
            out["time"] = {"span_s": float(np.ptp(s.t)),
                           "by_cable": {c: {"drift_over_noise": _r(d), "z": _r(z)}
                                        for c, d, z in trend}}
            strong = [(c, d, z) for c, d, z in trend
                      if abs(z) > STRUCT_Z and abs(d) > STRUCT_SIZE]
            if strong:
                many = len(strong) >= max(3, model.n_cables // 2)
                c, d, z = max(strong, key=lambda x: abs(x[2]))
                if many:
                    findings.append(f"the length residuals of {len(strong)} cables drift with "
                                    f"time (up to {abs(d):.1f} times the noise over the "
                                    f"recording; thermal expansion or creep?)")
                else:
                    findings.append(f"cable {c}'s length residual drifts with time "
                                    f"({abs(d):.1f} times the noise over the recording)")
            if common is not None:
                out["time"]["common"] = {"drift_over_noise": _r(common[0]), "z": _r(common[1])}
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


def _slope(x: np.ndarray, t: np.ndarray, w: np.ndarray) -> tuple[float, float] | None:
    """Change of ``x`` over the span of ``t`` by weighted least squares, and its z-value."""
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
    return float(b * np.ptp(tt)), float(b / se)
