"""Slip times the fit tells: a cable's length offset that starts later than the
initialisation, where no step in time was seen.

The steps in time (:mod:`bench.diagnosis.locate`) need visits of one target on both sides
of a slip, or a jump between two rows of a move. A slip between the first visit of a
target and the next, whose target is not visited again before it, or one that slackens
its cable at the visits after it, shows in neither: the length offset is then fitted
from the initialisation on, the samples before the slip misfit by the whole offset, and
other effects are named to absorb that. Here the selected fit is asked where its offset
should start: the samples are split in time at every gap, those before the split
evaluated without the offset, and the offset's size refitted (to first order) on those
after. A split that lowers the chi-square by more than the bar is the slip's time.

A step of one cable's length reading is no slip where the platform's load changed at its
time (:func:`load_change`: the force balance steps with it): the tensions then change what
they hold up, a slip only shares the same load among the cables otherwise.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import stats

from bench.diagnosis.fit import FitResult
from bench.diagnosis.residuals import Blocks, ResidualModel

#: the effect whose parameters are slips
OFFSET = "cable_length_offset"


def offset_cables(fit: FitResult, ids: tuple[str, ...] | None = None) -> dict[int, int]:
    """``{parameter index: cable index}`` of the length offsets ``fit`` names: free (a
    finite error) and away from zero."""
    space = fit.space
    if OFFSET not in space.effects:
        return {}
    ids = space.model.cable_ids if ids is None else ids
    out = {}
    for k in space.indices(OFFSET):
        if np.isfinite(fit.stderr[k]) and fit.phi[k] != space.neutral[k]:
            out[int(k)] = ids.index(space.params[k].key[len("dl_"):])
    return out


def later_starts(rm: ResidualModel, fit: FitResult, idx: np.ndarray, bar: float,
                 over_drift: float | None = None) -> dict[int, tuple[float, float, float]]:
    """For each cable whose length offset ``fit`` names (free, away from zero) and whose
    slip time is still the end of the initialisation: where a later start of the offset
    lowers the chi-square of the samples ``idx`` by more than ``bar``, ``{cable index: (t
    [s], offset [m], chi-square drop)}`` (the time half-way between the last sample without
    the offset and the first with it).

    With ``over_drift``, only where the step's chi-square is also lower by that much than
    a drift's: the same change growing in proportion to the time since the initialisation
    (a slow creep or a drum slipping slowly is no slip, and a step half-way fits it too)."""
    space = fit.space
    if OFFSET not in space.effects:
        return {}
    s = rm.s
    idx = np.asarray(idx)
    r1 = rm.whitened(space.robot(fit.phi), idx)
    sample = rm.entry_samples(idx)
    ids = rm.model.cable_ids
    out = {}
    for k, c in offset_cables(fit, ids).items():
        if rm.slip_times[c] > rm.init_end:
            continue
        phi0 = fit.phi.copy()
        phi0[k] = space.neutral[k]
        r0 = rm.whitened(space.robot(phi0), idx)
        d = r1 - r0
        n = s.n
        A = np.bincount(sample, weights=r0 * r0, minlength=n)
        B = np.bincount(sample, weights=r0 * d, minlength=n)
        C = np.bincount(sample, weights=d * d, minlength=n)
        moved = np.flatnonzero(C > 0)  # the samples the offset acts on
        if len(moved) < 2:
            continue
        order = moved[np.argsort(s.t[moved], kind="stable")]
        t = s.t[order]
        a, b, cc = A[order], B[order], C[order]
        chi_all = a.sum() - b.sum() ** 2 / cc.sum()
        # split before sample j (j = 1 .. m-1) where its time differs from the one before
        cb, cc_ = np.cumsum(b), np.cumsum(cc)
        j = np.flatnonzero(t[1:] > t[:-1]) + 1
        if not len(j):
            continue
        after_c = cc.sum() - cc_[j - 1]
        after_b = b.sum() - cb[j - 1]
        ok = after_c > 0
        j, after_b, after_c = j[ok], after_b[ok], after_c[ok]
        if not len(j):
            continue
        chi = a.sum() - after_b ** 2 / after_c
        gain = chi_all - chi
        best = int(np.argmax(gain))
        if over_drift is not None:
            w = np.clip((t - rm.init_end) / max(t[-1] - rm.init_end, 1e-9), 0.0, 1.0)
            ww = float(w * w @ cc)
            chi_drift = a.sum() - (float(w @ b) ** 2 / ww if ww > 0 else 0.0)
            if chi[best] > chi_drift - over_drift:
                continue
        if gain[best] > bar:
            jj = j[best]
            size = float(-after_b[best] / after_c[best]) * (fit.phi[k] - space.neutral[k])
            out[c] = (float(0.5 * (t[jj - 1] + t[jj])), float(space.params[k].to_value(
                space.neutral[k] + size)), float(gain[best]))
    return out


#: a step in time is the platform's load, not a slip, where the force balance steps at its time
#: by more than this share of the measured tensions' step (:func:`load_changes`): a slip
#: changes the tensions among themselves (the load is the same; what the force balance sees
#: of it is the cells' calibration, a few percent), a new load changes what they hold up
LOAD_SHARE = 0.3
#: ... and where the force balance's step, the same at every target, stands out of its
#: scatter over the targets beyond this p-value (a t-test per axis, times the three axes)
LOAD_P = 1e-6


def load_change(rm: ResidualModel, b: Blocks, step: dict) -> dict | None:
    """Whether a change of the platform's load explains a step in time of one cable's length
    residual (``step``: :func:`bench.diagnosis.locate.steps_in_time` or a row jump, a
    candidate slip): at its time the force balance ``b.wrench`` (residuals of ``rm``'s
    model, the measured tensions at the measured or estimated poses) steps, the same at every
    target (p < :data:`LOAD_P`), by more than :data:`LOAD_SHARE` of the measured tensions'
    step. Each step compares the visits of a target after its time with those before
    (targets visited on both sides, load cells read). A slip moves one cable's length
    residual and changes the tensions among themselves; a new load moves them all and the
    force they hold up (and, through tension-dependent model errors such as compliant masts,
    some cables' length residuals: 61108, a 10 % lighter platform read as a slip of cable
    42). Returns ``{"load_share": , "load_force_n": (3,) [N]}`` where it does, else None."""
    s = rm.s
    live = ~s.is_init & np.isfinite(s.tau).all(axis=1) & np.isfinite(b.wrench[:, :3]).all(axis=1)
    got = _force_and_tensions(s.t, s.target, s.tau, b.wrench[:, :3], live, step["t_s"])
    if got is None:
        return None
    dF, dT = got
    mean = dF.mean(axis=0)
    share = float(np.linalg.norm(mean) / max(np.sqrt(np.mean(np.sum(dT ** 2, axis=1))), 1e-9))
    if share > LOAD_SHARE and _consistent(dF) < LOAD_P:
        return {"load_share": share, "load_force_n": [float(v) for v in mean]}
    return None


def without_loads(rm: ResidualModel, b: Blocks, steps: list[dict],
                  say: Callable[[str], None] = lambda m: None) -> list[dict]:
    """``steps`` less those a change of the platform's load explains (:func:`load_change`),
    each of those said: the replicate groups are not split at them as at a slip (the change
    is located by the replicate visits' test, :func:`bench.diagnosis.noise.separate`)."""
    out = []
    for st in steps:
        load = load_change(rm, b, st)
        if load is None:
            out.append(st)
            continue
        f = float(np.linalg.norm(load["load_force_n"]))
        say(f"cable {st['cable']}: its length reading steps at t = {st['t_s']:.1f} s as the "
            f"force balance does by {f:.1f} N ({load['load_share']:.0%} of the tensions' "
            f"step): the platform's load changed, no slip")
    return out


def _force_and_tensions(t: np.ndarray, target: np.ndarray, tau: np.ndarray, force: np.ndarray,
                        live: np.ndarray, t0: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Per target visited on both sides of ``t0`` [s] among the ``live`` samples: the mean of
    ``force`` (N,3) after less before, and the same of the tensions ``tau`` (N,n) [N]. None
    with fewer than three such targets."""
    dF, dT = [], []
    for g in np.unique(target[live]):
        i = np.flatnonzero(live & (target == g))
        a, c = i[t[i] < t0], i[t[i] >= t0]
        if len(a) and len(c):
            dF.append(force[c].mean(axis=0) - force[a].mean(axis=0))
            dT.append(tau[c].mean(axis=0) - tau[a].mean(axis=0))
    if len(dF) < 3:
        return None
    return np.array(dF), np.array(dT)


def _consistent(d: np.ndarray) -> float:
    """p-value of the most consistent axis of the per-target steps ``d`` (T,3): the mean over
    the targets against its standard error (two-sided t-test of T - 1 degrees of freedom),
    times the axes."""
    T = len(d)
    se = d.std(axis=0, ddof=1) / np.sqrt(T)
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = np.abs(d.mean(axis=0)) / se
    tt = np.where(se > 0, tt, np.where(np.abs(d.mean(axis=0)) > 0, np.inf, 0.0))
    return float(min(1.0, 2.0 * stats.t.sf(float(tt.max()), T - 1) * d.shape[1]))


#: a candidate alike (:func:`choose_alike`) stays beside the best while its offset leaves a
#: chi-square no more than this much higher (the selection's tie)
ALIKE_TIE = 10.0


def choose_alike(rm: ResidualModel, steps: list[dict]) -> list[dict]:
    """Of the cables a jump is a candidate for (steps with ``alike``: their patterns nearly
    parallel where a row's pose is estimated, :func:`bench.diagnosis.locate.row_jumps`), the
    ones whose offset, from the step on and sized to first order, fits every sample of
    ``rm`` (each at its own pose, where the patterns differ) within :data:`ALIKE_TIE` of the
    best: the others' steps are dropped. Both offsets from one time fitted side by side split
    the slip between them (12939: cable 42's 6.4 mm as 3.4 on 22 and 3.5 on 42, the rest
    taken up by drum scales and E*A)."""
    groups: dict[int, list[dict]] = {}
    for st in steps:
        if st.get("alike"):
            groups.setdefault(st["row"], []).append(st)
    if not groups:
        return steps
    model, ids = rm.model, rm.model.cable_ids
    before = rm.slip_times.copy()
    drop: set[str] = set()
    try:
        r0 = rm.whitened(model)
        for group in groups.values():
            chi = []
            for st in group:
                c = ids.index(st["cable"])
                rm.slip_times = before.copy()
                rm.slip_times[c] = max(st["t_s"], rm.init_end)
                dl = model.length_offset.copy()
                dl[c] += st["step_m"]
                d = rm.whitened(model.replace(length_offset=dl)) - r0
                dd = float(d @ d)
                chi.append(float(r0 @ r0) - (float(r0 @ d) ** 2 / dd if dd > 0 else 0.0))
                st["alike_chi2"] = chi[-1]
            best = min(chi)
            drop |= {st["cable"] for st, x in zip(group, chi, strict=True)
                     if x - best > ALIKE_TIE}
    finally:
        rm.slip_times = before
    out = [st for st in steps if st["cable"] not in drop]
    for st in out:
        if "alike" in st:
            st["alike"] = [c for c in st["alike"] if c not in drop]
            if not st["alike"]:
                del st["alike"]
    return out
