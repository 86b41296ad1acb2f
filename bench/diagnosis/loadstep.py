"""A change of the platform's load found along its own direction in the residuals.

Where load cells measure the tensions, a new load shows in the force balance: a step of its
columns (:func:`bench.diagnosis.noise.find_changes`). Without them it shows only through
the lengths at the measured poses (the cables' stretch, their sag, the masts' bending under
the new tensions), by a fraction of the noise in each column, and only along one direction
per sample: the residuals' change under a change of the platform's mass, with the
per-sample unknowns (internal forces, an estimated pose) solved again as they are for the
data. The residual model itself gives that direction (one physics:
:meth:`ResidualModel.blocks` of the model with another mass, the initialisation held), and
each sample's residuals projected on it, weighted by their noise, are one number of known
scale: a matched filter. Its replicate visits are tested for a step as a column's are
(:mod:`bench.diagnosis.noise`: F-test over independent error units, Bonferroni over the
times, the small-sample tail on a dwell campaign), its regressor the direction's own size
at each sample. ``cdpr evaluate --kind load_change`` seed 47110 (ROCASPECT without load
cells, 35 kg, 4.3 kg lighter after the first visits): F 828 at the change's time (z 12
after the corrections), the size -4.8 kg; no column alone found it, the columns together
(:func:`~bench.diagnosis.noise._joint_step`, which runs first) only once its time was
refined beside the better neighbour. Seeds 46105, 47104 and audit case 32011 (IPAnema,
0.5-1.2 kg changes of 7-10 kg, stiff cables): F 1.5-3.5 at the change's time, below what
any test can tell from noise (46105's estimate -1.17 kg for a true -1.13 kg, at 1.9 of its
standard errors).
"""

from __future__ import annotations

import numpy as np

from bench.diagnosis import noise
from bench.diagnosis.residuals import Blocks, ResidualModel
from controller.effects import apply_effects

#: the platform's mass is changed by this fraction of itself for the load's direction (the
#: residuals are evaluated frozen about the model's: a finite-difference column)
MASS_STEP = 0.01


def signature(rm: ResidualModel, b: Blocks) -> dict[str, np.ndarray] | None:
    """Per block (as :meth:`ResidualModel.block_values`), the residuals' change per kg of
    the platform's mass [block unit / kg] from ``b`` (``rm``'s model's), the
    initialisation's unstretched lengths held (the encoders keep their reference: a load
    changed later does not move it). None where the initialisation cannot be solved."""
    H0 = rm.model
    dm = MASS_STEP * float(H0.mass)
    H1 = apply_effects(H0, {"platform_mass": {"mass": float(H0.mass) + dm}})
    kept = rm.extra_length
    try:
        held = rm._init_unstretched(H0) - rm._init_unstretched(H1)
    except ValueError:
        return None
    rm.extra_length = held if kept is None else kept + held
    try:
        with rm.frozen():
            v1 = rm.block_values(rm.blocks(H1))
    finally:
        rm.extra_length = kept
    v0 = rm.block_values(b)
    return {k: (v1[k] - v0[k]) / dm for k in v0 if k in v1}


def projected(rm: ResidualModel, b: Blocks, sig: dict[str, np.ndarray],
              groups: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Each sample's residuals ``b`` projected on the load's direction ``sig``, both
    whitened by the samples' noise (``rm.sd``): (N,) the projection ``J'r / |J|`` (noise 1
    per sample), (N,) ``|J|`` [1/kg], (N,) the white noise's share of the projection's
    variance, (N,) whether the sample's entries are the same under both masses (a cable
    that turns slack under one changes what is projected), (N,) the replicate group of
    the sample's entries together (``groups`` per block column)."""
    values = rm.block_values(b)
    s = rm.s
    N = s.n
    jr, jj, jw = np.zeros(N), np.zeros(N), np.zeros(N)
    same = np.ones(N, dtype=bool)
    labels = []
    count = np.maximum(s.count, 1).astype(float)
    kind = np.clip(s.kind, 0, 1)
    for name in noise.TESTED:
        v, J = values.get(name), sig.get(name)
        if v is None or J is None or not np.isfinite(J).any():
            continue
        sd = rm.sd[name][:, None]
        white2 = np.array([rm.white_k[0][name], rm.white_k[1][name]])[kind] ** 2 / count
        ok = np.isfinite(v) & np.isfinite(J)
        same &= (np.isfinite(v) == ok).all(axis=1)
        Jw = np.where(ok, J / sd, 0.0)
        jr += np.sum(Jw * np.where(ok, v / sd, 0.0), axis=1)
        jj += np.sum(Jw ** 2, axis=1)
        jw += np.sum(Jw ** 2 * white2[:, None] / sd ** 2, axis=1)
        labels.append(groups[name])
    size = np.sqrt(jj)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(size > 0, jr / size, np.nan)
        white = np.where(size > 0, jw / np.maximum(jj, 1e-300), 0.0)
    if not labels:
        return z, size, white, same & False, np.zeros(N, dtype=np.int64)
    g = np.unique(np.concatenate(labels, axis=1), axis=0, return_inverse=True)[1].ravel()
    return z, size, white, same, g


def find(rm: ResidualModel, b: Blocks, groups: dict[str, np.ndarray] | None = None
         ) -> noise.Change | None:
    """A step of the platform's load during ``rm``'s campaign, from the residuals ``b`` of
    its model, in the replicate groups ``groups`` (per block column; default ``rm``'s): the
    matched filter (:func:`projected`) of the dwells tested for a step of the mass
    (regressor ``|J|`` from the step's time on, centred within the groups) over the times
    :func:`~bench.diagnosis.noise._scanned` tries; a ``step`` of block ``load`` where its
    p-value, Bonferroni-corrected over the times and doubled (one more test beside the
    columns', as the joint step's), is below ``P_SYSTEMATIC`` and its size at least
    ``MIN_JOINT_SIZE`` (the load moves each entry by less than its noise, as it does the
    columns of a joint step); ``load_kg`` the change's size [kg] (the data's: the
    hypothesis' mass that would follow it, with the opposite sign). Dwells only (rows of
    moves share slow errors: as the joint step). None otherwise, and None on a recording
    with load cells (their force columns are tested for the load's step)."""
    if rm.any_tau:
        # load cells measure the tensions: a new load steps the force balance's columns,
        # which find_changes tests with far more power than one projection per sample; run
        # beside them on an hour-long all-sensor log (14003 of --kind new) this test read a
        # step of z 17 where nothing changed
        return None
    s = rm.s
    dwells, unit = ~s.is_init & (s.kind == 0), noise._units(s)
    if noise._column(np.zeros(s.n), s.target, unit, dwells) is None:
        return None  # (no dwells visited twice: the model's evaluation spared)
    sig = signature(rm, b)
    if sig is None:
        return None
    G = rm.replicate_groups(None) if groups is None else groups
    z, size, white, same, g = projected(rm, b, sig, G)
    col = noise._column(z, g, unit, dwells & same & (size > 0))
    if col is None:
        return None
    idx, inv, uinv, x, dof0 = col
    t, u = s.t[idx], size[idx]
    independent = not bool((s.kind == 1).any())
    every, coarse = noise._splits(t, inv)
    if not len(coarse):
        return None

    def scan(times: np.ndarray, best: tuple | None) -> tuple | None:
        for tm in times:
            got = noise._ftest(x, _regressor(u, inv, t >= tm), uinv, dof0,
                               float(np.mean(white[idx])), independent)
            if got is not None and (best is None or got[0] < best[0]):
                best = (got[0], got[1], float(tm))
        return best

    best, n_times = noise._scanned(scan, coarse, every)
    if best is None:
        return None
    p = min(2.0 * best[0] * n_times, 1.0)
    if p >= noise.P_SYSTEMATIC or best[1] < noise.MIN_JOINT_SIZE:
        return None
    U = _regressor(u, inv, t >= best[2])[:, 0]
    size_u = np.bincount(uinv)
    A = np.bincount(uinv, weights=U) / size_u  # (units' means, as the test's)
    kg = -float(A @ (np.bincount(uinv, weights=x) / size_u) / (A @ A))
    t_live = s.t[~s.is_init]
    before, after = t_live[t_live < best[2]], t_live[t_live > best[2]]
    return noise.Change("step", "load", ["mass"], best[2], noise._z_of(p), best[1],
                        before_s=float(before.max()) if len(before) else None,
                        after_s=float(after.min()) if len(after) else None, joint=True,
                        load_kg=kg)


def _regressor(u: np.ndarray, inv: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(m, 1): the load direction's size ``u`` (m,) on the samples ``after`` (m,) a step,
    centred within the replicate groups ``inv``."""
    return noise._centre((u * after)[:, None], inv)
