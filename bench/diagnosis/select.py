"""Choosing the effects the data need: screening, refits, held-out checks, look-alikes.

1. Candidates are the vocabulary effects the recording can see (tensions for
   load cells and mass, encoder lengths for scale and offsets, ...).
2. Forward selection: each candidate's linearised signature at the current fit
   predicts its chi-square drop; the most promising are refitted with the full
   nonlinear model; the best enters when its BIC drops by more than
   ``BIC_ENTER``. A backward pass drops effects the others make unnecessary.
   The entry also needs the effect's parameters to stand out from the model's values by
   their own standard errors (:func:`stands_out`): the BIC's chi-square counts every
   residual as independent, the errors (a sandwich of the residuals' own structure)
   do not, and rows of a continuous recording share their errors.
3. Every chosen effect must also improve held-out samples the fits never saw:
   every k-th target pose, and a whole region of the workspace.
4. Look-alikes: each chosen effect is swapped for each other candidate and
   refitted; near-ties become ``alternatives`` (a declared ambiguity beats a
   confident wrong answer), and the imitation of each effect's signature by
   the others is computed on the recording's own poses.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np

from bench.diagnosis import gauge
from bench.diagnosis.fit import (
    MAX_NFEV,
    FitResult,
    error_meat,
    error_structure,
    fd_jacobian,
    fit_effects,
    fits_side_by_side,
    quad_form,
)
from bench.diagnosis.frame import material, tracker_candidates
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.space import PER_CABLE_EA, ParamSpace, report_name
from controller.effects import EFFECT_NAMES

#: BIC drop an effect must bring to enter (very strong evidence: small systematic errors
#: outside the vocabulary must not pull effects in)
BIC_ENTER = 25.0
#: BIC difference under which a swapped effect counts as an alternative
BIC_TIE = 10.0
#: swaps whose linearised BIC change is below this are refitted (linearisation is rough)
SWAP_SCREEN = 50.0
#: look-alikes within this much of a tie (linearised) are refitted to decide
SWAP_SCREEN_MARGIN = 50.0
#: an effect reproducing this share of another's signature is listed as its alternative
IMITATES = 0.98
#: the model explains the data within the noise below this reduced chi-square
EXPLAINED = 1.3
#: fraction of an effect's signal (chi-square) the linearised swap screen may be off by
LINEAR_ERROR = 0.01
#: look-alikes refitted per chosen effect beyond the screen's margin
LOOKALIKE_REFITS = 2
#: ... whose linearised BIC change is within this of a tie, whatever the signal
LOOKALIKE_MARGIN = 250.0
#: above this reduced chi-square the linearised screen is not trusted alone
INADEQUATE = 3.0
#: above this reduced chi-square a fit's errors measure its misfit, not the noise: an
#: effect's parameters need not stand out by them (:func:`stands_out`) to enter or stay
FAR = 10.0
#: the pairs of this many best single effects are fitted when one effect is far from enough
PAIR_TOP = 4
#: ... and the best this many of them by their linearised fit are refitted
PAIR_FITS = 2
#: at most this many effects in a model (more is physics the vocabulary lacks)
MAX_EFFECTS = 5
#: every candidate is refitted (not only the screen's best) while fewer effects are chosen
WIDE_SEARCH = 3
#: validation blocks on which the fits with and without an effect differ by this much
#: (whitened chi-square) decide alone whether the effect holds
CONCLUSIVE = 25.0

Progress = Callable[[str], None]


def candidate_effects(rm: ResidualModel) -> list[str]:
    """Effects this recording can see.

    Without tracker poses (tensions and encoders only) the poses are estimated from the
    lengths, which absorbs what moves exit points: the load cells, the mass, the cables'
    stretch and the length readings' offsets and scales are tested (a reading's error is
    absorbed only in the pose's six directions at each sample; the stretch and the force
    balance see the rest). Without tensions, the cables' sag (it hangs on the tensions) is
    not (:func:`untested_effects` says which are not). The tracker's own frame and latency
    where its poses can show them (:func:`bench.diagnosis.frame.tracker_candidates`)."""
    out = []
    have_len = bool(rm.has_len.any())
    have_exit = bool(rm.has_exit.any())
    measured_pose = bool((rm.has_pose & (rm.has_len | rm.has_exit.any(axis=1))).any())
    geometry = measured_pose and (have_len or have_exit)
    if geometry:
        out += ["exit_point_offset", "mast_compliance"]
    if have_len:
        out += ["cable_elasticity", PER_CABLE_EA]
    if have_len and (measured_pose or (rm.est_pose.any() and rm.any_tau)):
        out += ["cable_length_offset", "drum_scale"]
    if rm.any_tau:
        out += ["load_cell_calibration", "platform_mass"]
    if geometry:
        out += ["pulley_kinematics"]
    if have_len and measured_pose and rm.any_tau:
        out += ["cable_sag"]  # a sagging cable's length depends on its tension: measure it
    out += tracker_candidates(rm)
    return out


def untested_effects(rm: ResidualModel) -> list[str]:
    """Vocabulary effects this recording cannot test (see :func:`candidate_effects`)."""
    seen = {report_name(c) for c in candidate_effects(rm)}
    return [e for e in EFFECT_NAMES if e not in seen]


#: candidates that are two forms of one effect: never both in a set
EXCLUSIVE = {frozenset({"cable_elasticity", PER_CABLE_EA}),
             # a rigid motion of every exit point is the tracker's frame seen from the robot
             # (the gauge: :mod:`bench.diagnosis.frame`): one of the two, the other declared
             frozenset({"exit_point_offset", "tracker_frame"})}


def compatible(effects: tuple[str, ...] | list[str], extra: str) -> bool:
    """Whether ``extra`` may join ``effects`` (not a second form of one of them)."""
    return all(frozenset({extra, e}) not in EXCLUSIVE for e in effects)


@dataclass
class Selection:
    """Outcome of the selection: the chosen set with its fit, and what was learnt on the way."""

    effects: list[str]
    fit: FitResult
    baseline: FitResult
    fits: dict[tuple[str, ...], FitResult] = field(default_factory=dict)
    heldout: dict[str, dict[str, float]] = field(default_factory=dict)
    alternatives: dict[str, list[tuple[str, float]]] = field(default_factory=dict)
    imitation: dict[str, dict[str, float]] = field(default_factory=dict)
    rejected: dict[str, str] = field(default_factory=dict)
    screening: dict[str, float] = field(default_factory=dict)


#: evaluations a fit with the load cells' gauge pinned (:meth:`Selector._pinned`) may take
PINNED_NFEV = MAX_NFEV // 2


class Selector:
    """Runs the selection for one recording (train / held-out sample indices given)."""

    def __init__(self, rm: ResidualModel, train: np.ndarray, holdouts: list[np.ndarray],
                 progress: Progress | None = None, pool: Executor | None = None) -> None:
        self.rm = rm
        self.train = train
        self.holdouts = [h for h in holdouts if len(h)]
        self.progress = progress or (lambda msg: None)
        self.pool = pool
        self.cache: dict[tuple[str, ...], FitResult] = {}
        self.cache_ho: dict[tuple[tuple[str, ...], int], FitResult] = {}
        self._swap_cache: dict[tuple, tuple[FitResult, dict[tuple[str, str], float]]] = {}
        #: chi-square each chosen effect removes (by swap_screen's key and effect)
        self._signal: dict[tuple, float] = {}
        self._refit_from: set[tuple] = set()  # (subset, superset, its chi-square) refitted
        self.model = rm.model
        # with an assumed noise, "far more than the noise" says little: no wider search
        self.measured_noise = rm.sigma_source == "replicate visits"
        self.stalled = False
        #: the search stops once the cache holds this many fitted sets (None: no limit)
        self.budget: int | None = None
        #: at most this many effects in the search's sets
        self.max_effects = MAX_EFFECTS
        self._floored: dict[int, FitResult] = {}
        #: the effects a search ran again without (:meth:`_restart`); given to a selection
        #: again (a nuisance fitted, slip times), its restarts skip them: that second
        #: opinion was taken, and the selection again starts from the set it led to
        self.restarted: set[str] = set()

    # ----- fits -----------------------------------------------------------------------
    def fit(self, effects: tuple[str, ...], start: FitResult | None = None) -> FitResult:
        """The fit of a set of effects on the training samples (cached). A set fitted before
        and now asked for as part of a larger fit ``start`` (dropping an effect, a held-out
        check without it) is refitted from ``start``'s values too, and the better fit kept:
        the first fit may have stopped in a poor local minimum (a pulley radius started at
        0, where the residual is rough), and an effect compared with that stays in for the
        wrong reason. Where the change of effects moves along the load cells' gauge, the
        fits start from ``start`` moved along it too (:func:`bench.diagnosis.gauge.starts`)."""
        key = tuple(sorted(effects))
        if key in self.cache:
            cached = self.cache[key]
            if start is None or not set(key) < set(start.space.effects):
                return cached
            tag = self._tag(key, start)
            if tag in self._refit_from:
                return cached
            self._refit_from.add(tag)
            res = self._best_of(key, self._starts(key, start))
            if res.bic < cached.bic - 1e-6 * max(1.0, abs(cached.bic)):
                self._refitted(key, start, cached, res)
                return res
            return cached
        space = ParamSpace(self.model, key)
        self.progress(f"fitting {' + '.join(key) or 'the model as it is'} "
                      f"({len(space)} parameters)")
        res = self._best_of(key, self._starts(key, start) if start is not None
                            else [space.neutral.copy()])
        self.cache[key] = res
        return res

    def prefetch(self, sets: list[tuple[str, ...]], start: FitResult | None = None,
                 refits: bool = False) -> None:
        """Make ahead, all at once on the process pool, the fits :meth:`fit` of the sets of
        ``sets`` not fitted yet would make (from ``start``: each start, and the fits with
        the load cells' gauge pinned): the search asks for them in turn and may drop some
        after the first answer, but two cores fit two for the time of one. With ``refits``,
        also those of the sets fitted before that :meth:`fit` would refit from ``start``
        (subsets of it). Only the fits are made (kept in :func:`~.fit.fit_effects`' memo,
        where :meth:`fit` finds them when it asks): what the selection keeps and refits
        (:attr:`cache`, the refits made) stays as :meth:`fit` leaves it, so the pool changes
        when a fit is made, never the answer. (Kept in the cache, the sets prefetched and
        never asked for counted in the search's budget and in its pairs of single effects,
        and a refit from an earlier start was kept where :meth:`fit` refits from the current
        one: the selection's path hung on the pool.) Nothing without a pool."""
        if getattr(self, "pool", None) is None:  # (a Selector built bare in a test)
            return
        todo = list(dict.fromkeys(tuple(sorted(s_)) for s_ in sets))
        again = []
        if refits and start is not None:
            again = [k for k in todo if k in self.cache and set(k) < set(start.space.effects)
                     and self._tag(k, start) not in self._refit_from]
        todo = [k for k in todo if k not in self.cache] + again
        if len(todo) < 2:
            return
        jobs = [(k, phi0) for k in todo
                for phi0 in (self._starts(k, start) if start is not None
                             else [ParamSpace(self.model, k).neutral.copy()])]
        self.progress(f"fitting {len(todo)} sets from {len(jobs)} starts on the process pool")
        got = fits_side_by_side(self.pool, self.rm, [
            (ParamSpace(self.model, k), self.train, phi0, {}) for k, phi0 in jobs])
        fits: dict[tuple[str, ...], list[FitResult]] = {}
        for (k, _), res in zip(jobs, got, strict=True):
            fits.setdefault(k, []).append(res)
        self._pinned_many([min(fs, key=lambda f: f.bic) for fs in fits.values()])

    @staticmethod
    def _tag(key: tuple[str, ...], start: FitResult) -> tuple:
        """What :meth:`fit` remembers of a refit of ``key`` from ``start``."""
        return (key, tuple(sorted(start.space.effects)), round(float(start.chi2), 9))

    def _refitted(self, key: tuple[str, ...], start: FitResult, cached: FitResult,
                  res: FitResult) -> None:
        """Keep ``res``, the refit of ``key`` from ``start`` better than ``cached``."""
        self.progress(f"{' + '.join(key) or 'the model as it is'}: refitted from "
                      f"{' + '.join(start.space.effects)} (chi-square {cached.chi2:.4g}"
                      f" -> {res.chi2:.4g})")
        self.cache[key] = res

    def _starts(self, key: tuple[str, ...], start: FitResult | None) -> list[np.ndarray | None]:
        """Starting points of a fit of ``key`` from ``start``: its values (the others at the
        model's), and the same moved along the load cells' gauge when the change of
        effects calls for it."""
        if start is None:
            return [None]
        if gauge.complete(key, self.model):  # the whole gauge free: every start on it is one
            return [_warm(key, start)]  # (and the fit is pinned at its median cell after)
        space = ParamSpace(self.model, key)
        return [_warm(key, start)] + gauge.starts(space, start.space, start.phi)

    def _best_of(self, key: tuple[str, ...], phis: list[np.ndarray | None]) -> FitResult:
        """The best fit of ``key`` from starts ``phis``; for a set with the load cells and
        another effect of their gauge, also that fit with the scale fixed at the median
        cell (:meth:`_pinned`), and the errors of the one chosen floored by
        :meth:`gauge_floor`."""
        space = ParamSpace(self.model, key)
        fits = self.fit_starts(space, phis)
        best = min(fits, key=lambda f: f.bic)
        return self.gauge_floor(min([best] + self._pinned(best), key=lambda f: f.bic))

    def fit_starts(self, space: ParamSpace, phis: list[np.ndarray | None]) -> list[FitResult]:
        """Fits of ``space`` on the training samples from each start of ``phis`` (None: the
        model's values), on the process pool when there is one and more than one start
        (each fit starts cold: the same results in this process or a worker)."""
        return fits_side_by_side(self.pool, self.rm,
                                 [(space, self.train, phi0, {}) for phi0 in phis])

    def _pinned(self, fit: FitResult) -> list[FitResult]:
        """``fit`` refitted with the load cells' gauge fixed at its median cell, for a set
        with the load cells and another effect of the gauge (the mass, the stretch). Where
        the data cannot fix the tensions' scale (the whole gauge free), or fix it only
        weakly through the cables' stretch, the fit holds one of the gauge's parameters at
        the model's value (E*A where it is null; a mass within its error of the model's
        where pruning holds it) and reports the others with errors that take it as known:
        eight gains 7 % high at standard errors of a few thousandths in place of a mass
        change known to 12 %. Which one is held is the data's choice no more than the
        cell's; the fewer parameters decide (BIC)."""
        return self._pinned_many([fit])[0]

    def _pinned_many(self, fits: list[FitResult]) -> list[list[FitResult]]:
        """:meth:`_pinned` of each of ``fits``, on the process pool where there is one and
        more than one such refit."""
        jobs = []
        for i, fit in enumerate(fits):
            space = fit.space
            if not _on_gauge(space.effects):
                continue
            pin = gauge.pinned(space, fit.phi, fit.cov)
            if pin is None:
                continue
            phi0, hold = pin
            other = ~np.isfinite(fit.stderr) & ~gauge.members(space)  # the data cannot fix
            jobs.append((i, space, phi0, hold | other))
        out: list[list[FitResult]] = [[] for _ in fits]
        # (from a minimum moved along the gauge: where the gauge holds, a few steps; half
        # the budget of a fit from afar. 12823: 248 evaluations, 10 of 67 s, not converged,
        # for a reading that lost by its BIC)
        got = fits_side_by_side(getattr(self, "pool", None), self.rm, [
            (space, self.train, phi0, {"hold": hold, "max_nfev": PINNED_NFEV})
            for _, space, phi0, hold in jobs])
        for (i, _, _, _), res in zip(jobs, got, strict=True):
            out[i].append(res)
        return out

    def gauge_floor(self, fit: FitResult, idx: np.ndarray | None = None) -> FitResult:
        """``fit`` (of a set with the load cells and another effect of their gauge, on
        samples ``idx``, the training ones by default) with each parameter of the gauge
        reported with at least the error it has with the tensions' scale free: what the
        fit held to fix the scale (a gain, the mass, E*A) is an assumption, and the data
        know the scale only through the cables' stretch (a mass known to 12 % without a
        tracker is not known to 0.03 kg because every gain was held at one). Where that
        leaves the gauge exact (every member free), the members other than gains that the
        fit held at the model's (the cables' E*A it found right) stay held: their stretch
        fixes the scale, weakly. Directions the data cannot fix at all are left out (an
        exact gauge: the values are those of the scale chosen). In place: the floor is
        added to ``fit.bias_var``."""
        space = fit.space
        if not _on_gauge(space.effects) or id(fit) in self._floored:
            return fit
        idx = self.train if idx is None else idx
        mem = gauge.members(space)
        other = ~np.isfinite(fit.stderr) & ~mem
        free = fit_effects(space, self.rm, idx, fit.phi, hold=other, prune=False, max_nfev=2)
        held = mem & (fit.phi == space.neutral) & ~np.array(
            [p.key.startswith("gain_") for p in space.params], dtype=bool)
        if held.any() and not np.isfinite(free.stderr[mem & ~held]).any():
            # every member free, the gauge is exact; the stretch the fit held at the
            # model's (seven cables of eight) still tells the scale, if weakly
            free = fit_effects(space, self.rm, idx, fit.phi, hold=other | held, prune=False,
                               max_nfev=2)
        kept = mem & np.isfinite(fit.stderr) & np.isfinite(free.stderr)
        extra = np.zeros(len(space))
        extra[kept] = np.clip(free.stderr[kept] ** 2 - fit.reported_stderr[kept] ** 2, 0.0,
                              None)
        fit.bias_var = extra if fit.bias_var is None else fit.bias_var + extra
        self._floored[id(fit)] = fit  # (kept: an id is unique while its object lives)
        return fit

    def fit_many(self, sets: list[tuple[str, ...]], start: FitResult | None = None,
                 multistart: bool = False) -> list[FitResult]:
        """Fits of several sets, warm-started from ``start``. With ``multistart``, each set is
        also fitted from its new effect's own fit alone (the others at the model's values):
        where effects overlap, the warm start can stay in the minimum where the effects
        already chosen imitate the new one; the better of the two is kept."""
        todo = [tuple(sorted(s)) for s in sets if tuple(sorted(s)) not in self.cache]
        jobs: list[tuple[tuple[str, ...], np.ndarray | None]] = []
        for s_ in todo:
            jobs.extend((s_, phi0) for phi0 in self._starts(s_, start))
            if multistart and start is not None:
                new = [e for e in s_ if e not in start.space.effects]
                solo = self.cache.get(tuple(new)) if len(new) == 1 else None
                if solo is not None and len(start.space.effects):
                    jobs.append((s_, _warm(s_, solo)))
        results: dict[tuple[str, ...], FitResult] = {}
        if self.pool is not None and len(jobs) > 1:
            self.progress(f"fitting {len(jobs)} candidate sets on the process pool")
        else:
            for s_, _ in jobs:
                self.progress(f"fitting {' + '.join(s_) or 'the model as it is'}")
        done = list(zip([s_ for s_, _ in jobs], fits_side_by_side(self.pool, self.rm, [
            (ParamSpace(self.model, s_), self.train, phi0, {}) for s_, phi0 in jobs]),
            strict=True))
        for s_, res in done:
            if s_ not in results or res.bic < results[s_].bic:
                results[s_] = res
        pins = self._pinned_many(list(results.values()))
        for (s_, res), pin in zip(list(results.items()), pins, strict=True):
            results[s_] = self.gauge_floor(min([res] + pin, key=lambda f: f.bic))
        self.cache.update(results)
        return [self.fit(s_, start) for s_ in sets]

    # ----- screening ------------------------------------------------------------------
    def screen(self, current: FitResult, candidates: list[str]) -> dict[str, float]:
        """Predicted BIC change of adding each candidate, linearised at the current fit with
        the current parameters free too: a new effect may fit only together with a change of
        those already chosen (a length offset beside pulley radii that took its share), which
        a screen holding them fixed cannot see."""
        sp = current.space
        robot = sp.robot(current.phi)
        r0 = self.rm.whitened(robot, self.train)
        n_res = len(r0)
        Jc = fd_jacobian(lambda phi: self.rm.whitened(sp.robot(phi), self.train),
                         current.phi, r0, sp.scale * 1e-2, sp.lo, sp.hi,
                         self.rm.frozen) if len(sp) \
            else np.zeros((n_res, 0))
        out = {}
        for eff in candidates:
            sub = ParamSpace(robot, (eff,))
            J = fd_jacobian(lambda phi, s=sub: self.rm.whitened(s.robot(phi), self.train),
                            sub.neutral, r0, sub.scale * 1e-2, sub.lo, sub.hi, self.rm.frozen)
            both = np.hstack([Jc, J])
            delta = _bounded_lstsq(both, -r0, np.concatenate([current.phi, sub.neutral]),
                                   np.concatenate([sp.lo, sub.lo]),
                                   np.concatenate([sp.hi, sub.hi]))
            r1 = r0 + both @ delta
            out[eff] = float(r1 @ r1 - r0 @ r0) + len(sub) * np.log(n_res)
        return out

    # ----- held-out -------------------------------------------------------------------
    def fit_on(self, effects: tuple[str, ...], k: int, start: FitResult | None) -> FitResult:
        """Fit on the training samples minus held-out set ``k`` (the first set is already
        outside the training samples)."""
        if k == 0:
            return self.fit(effects, start)
        key = (tuple(sorted(effects)), k)
        if key not in self.cache_ho:
            idx = np.setdiff1d(self.train, self.holdouts[k])
            space = ParamSpace(self.model, key[0])
            self.cache_ho[key] = fit_effects(space, self.rm, idx,
                                             _warm(key[0], start) if start else None)
        return self.cache_ho[key]

    def heldout_chi2(self, fit: FitResult, idx: np.ndarray) -> tuple[float, int]:
        r = self.rm.whitened(fit.space.robot(fit.phi), idx)
        return float(r @ r), len(r)

    def heldout_improves(self, with_: tuple[str, ...], without: tuple[str, ...],
                         start: FitResult) -> tuple[bool, dict]:
        """Whether adding the effect predicts held-out samples better than the fits without it.

        ``d`` is how much the two fits' predictions differ there (whitened, squared): a real
        effect lowers the held-out chi-square by about ``d`` (give or take ``2 sqrt(d)`` for
        independent errors), a spurious one raises it by about ``d``. The effect passes when
        the drop exceeds ``d/2`` less one and a half of its standard deviations
        (:meth:`_heldout_sd`; ``3 sqrt(d)`` for independent errors), so an effect the
        held-out samples cannot see, ``d`` small, only must not make them worse. Set 0:
        every k-th block; set 1: the validation region, refitted without (it decides too
        only when set 0 cannot see the effect)."""
        info: dict[str, float] = {}
        ok = True
        new = [e for e in with_ if e not in without]
        for k, idx in enumerate(self.holdouts):
            fw = self.fit_on(without, k, start)
            fi = self.fit_on(with_, k, start)
            if k > 0 and new:
                # the region may hold all the effect's support (a slip late in the recording,
                # a mast seen only there): without it the effect cannot be fitted, and the
                # region cannot test it
                ix = np.concatenate([fi.space.indices(e) for e in new])
                if len(ix) and not np.isfinite(fi.stderr[ix]).any():
                    info[f"heldout_{k}_skipped"] = 1.0
                    continue
            r_without = self.rm.whitened(fw.space.robot(fw.phi), idx)
            r_with = self.rm.whitened(fi.space.robot(fi.phi), idx)
            a, b = float(r_without @ r_without), float(r_with @ r_with)
            diff = r_with - r_without
            d = float(diff @ diff)
            info[f"heldout_{k}_chi2_without"] = a
            info[f"heldout_{k}_chi2_with"] = b
            info[f"heldout_{k}_predicted"] = d
            info[f"heldout_{k}_n"] = len(idx)
            sd = self._heldout_sd(idx, diff, r_with)
            info[f"heldout_{k}_sd"] = float(sd)
            passed = a - b > 0.5 * d - 1.5 * sd
            if k == 0 and d >= CONCLUSIVE:
                return passed, info  # the validation blocks see the effect: they decide
            if not passed:
                ok = False
        return ok, info

    def _heldout_sd(self, idx: np.ndarray, diff: np.ndarray, r: np.ndarray) -> float:
        """Standard deviation of the noise in the held-out chi-square change between two
        fits whose whitened predictions on samples ``idx`` differ by ``diff`` (``r``: the
        residuals of one of them): ``2 sqrt(diff^T C diff)``, with the errors' covariance
        ``C`` of the standard errors (:func:`bench.diagnosis.fit.error_meat`: a move's rows
        share errors, the lengths blend theirs between stops), estimated from ``r`` beside
        ``diff`` (its part along ``diff`` is the effect, not noise). At least the
        ``2 sqrt(d)`` of independent errors: held out on a continuous recording, two moves'
        rows, whose shared errors a mast's bending followed, made a true effect look
        four deviations worse than predicted."""
        d = float(diff @ diff)
        if d <= 0.0 or len(diff) != len(r):
            return 2.0 * np.sqrt(max(d, 0.0))
        rm = self.rm
        errors = error_structure(rm, idx)
        beside = r - diff * float(diff @ r) / d
        try:
            var = float(error_meat(diff[:, None], beside, errors)[0, 0])
        except (ValueError, np.linalg.LinAlgError):
            var = d
        return 2.0 * np.sqrt(max(var, d) if np.isfinite(var) else d)

    # ----- the whole selection --------------------------------------------------------
    def run(self, candidates: list[str], initial: tuple[str, ...] = ()) -> Selection:
        """Choose effects among ``candidates``, starting from the set ``initial`` (the model
        as it is by default)."""
        self.stalled = False
        base = self.fit(())
        chosen: list[str] = [e for e in initial if e in candidates]
        current = self.fit(tuple(chosen), None) if chosen else base
        sel = Selection([], base, base)
        chosen, current = self._search(chosen, current, candidates, sel)
        restart = self._restart(chosen, current, candidates, base)
        if restart is not None:
            chosen, current = restart
        for attempt in range(2):
            chosen, current = self._heldout_checks(chosen, current, sel)
            if len(chosen) > 1:  # (each effect's importance asks for the set without it)
                self.prefetch([tuple(c for c in chosen if c != e) for e in chosen], current,
                              refits=True)
            sel.effects = sorted(chosen, key=lambda e: -self._importance(e, chosen, current))
            sel.fit = current
            sel.alternatives = {}
            self._lookalikes(sel, candidates)
            missed = self._missed_swap(sel) if attempt == 0 else None
            if missed is None:
                break
            # a look-alike refitted from the final fit beat the chosen effect where the
            # linearised swap screen saw no promise: the swap, and the search from there
            e, a, chosen, current = missed
            self.progress(f"swapping {e} for {a}: it explains the data better")
            chosen, current = self._search(chosen, current, candidates, sel)
        sel.fits = dict(self.cache)
        return sel

    def _heldout_checks(self, chosen: list[str], current: FitResult, sel: Selection
                        ) -> tuple[list[str], FitResult]:
        """Held-out check of each chosen effect against the set without it."""
        order = list(chosen)
        fetched = None
        for i, e in enumerate(order):
            if len(chosen) > 1 and fetched is not current:
                # every check left asks for its set without the effect (refitted from the
                # set with it), and on each held-out set but the first for both: side by
                # side on the pool, again after a rejection (12973: 9 s in a row)
                self._prefetch_checks(chosen, order[i:], current)
                fetched = current
            rest = tuple(c for c in chosen if c != e)
            without = self.fit(rest, current)
            ok, info = self.heldout_improves(tuple(chosen), rest, current)
            info["delta_bic"] = current.bic - without.bic
            sel.heldout[e] = info
            # an effect of the gauge that replaces more parameters of the others predicts
            # what they predict (the same readings): held-out poses cannot choose, the BIC did
            if not ok and not _takes_over(e, chosen, current, without):
                self.progress(f"rejecting {e}: held-out poses do not improve")
                sel.rejected[e] = "held-out poses do not improve"
                chosen.remove(e)
                current = self.fit(tuple(chosen), current)
        return chosen, current

    def _prefetch_checks(self, chosen: list[str], left: list[str], current: FitResult
                         ) -> None:
        """The fits the held-out checks of the effects ``left`` ask for (:meth:`fit` and
        :meth:`fit_on` of ``chosen`` with and without each, from ``current``), made ahead on
        the process pool all at once (:meth:`prefetch`: the fits only, what the checks
        keep stays theirs). Nothing without a pool."""
        if getattr(self, "pool", None) is None:
            return
        rests = [tuple(sorted(c for c in chosen if c != e)) for e in left]
        self.prefetch(rests, current, refits=True)
        if len(self.holdouts) < 2:
            return
        # the other held-out sets only where the first does not decide (its predicted
        # difference below CONCLUSIVE: :meth:`heldout_improves`)
        idx0 = self.holdouts[0]
        open_ = []
        # (a guess of which sets the checks will ask for: what fit would give, the
        # selection's cache untouched; evaluated cold, so that the evaluations after start
        # as they would have without a pool)
        with self.rm.cold():
            r_with = self.rm.whitened(current.space.robot(current.phi), idx0)
            for rest in rests:
                fw = self.cache.get(rest) or self._best_of(rest, self._starts(rest, current))
                diff = r_with - self.rm.whitened(fw.space.robot(fw.phi), idx0)
                if float(diff @ diff) < CONCLUSIVE:
                    open_.append(rest)
        jobs = list(dict.fromkeys((key, k) for k in range(1, len(self.holdouts))
                                  for key in ([tuple(sorted(chosen))] + open_ if open_ else [])
                                  if (key, k) not in self.cache_ho))
        if len(jobs) < 2:
            return
        self.progress(f"fitting {len(jobs)} sets on held-out samples on the process pool")
        fits_side_by_side(self.pool, self.rm, [
            (ParamSpace(self.model, key), np.setdiff1d(self.train, self.holdouts[k]),
             _warm(key, current), {}) for key, k in jobs])  # (fit_on finds them)

    def _missed_swap(self, sel: Selection
                     ) -> tuple[str, str, list[str], FitResult] | None:
        """The look-alike (:meth:`_lookalikes`) that beats the chosen effect it stands for:
        (chosen, other, new set, its fit), or None. At no more free parameters any lower
        BIC: the search's swaps wait for a margin (:data:`BIC_TIE`) so that near ties do
        not cycle, but the effect the report prefers is the one the data favour (at a BIC
        lower by 2.5 the odds are 3.5 to 1; the other stays listed as the alternative). At
        more free parameters the entry bar."""
        best = None
        self.prefetch([tuple([c for c in sel.effects if c != e] + [a])
                       for e, alts in sel.alternatives.items() for a, _ in alts], sel.fit)
        for e, alts in sel.alternatives.items():
            for a, _ in alts:
                others = [c for c in sel.effects if c != e] + [a]
                f = self.fit(tuple(others), sel.fit)
                bar = 0.0 if f.n_free <= sel.fit.n_free else BIC_ENTER
                if f.bic - sel.fit.bic < -bar and (best is None or f.bic < best[3].bic):
                    best = (e, a, others, f)
        return best

    def _search(self, chosen: list[str], current: FitResult, candidates: list[str],
                sel: Selection) -> tuple[list[str], FitResult]:
        """Forward steps, backward drops and swaps from ``chosen`` until none changes it (or
        the sets fitted reach :attr:`budget`, or it comes back to a set it left: a swap the
        backward step undoes, and the forward step brings back, cycles until the cap; case
        12554 swapped the load cells for a cable's E*A and dropped it fourteen times)."""
        seen = {frozenset(chosen)}
        for _ in range(3 * len(candidates) + 3):
            if self.budget is not None and len(self.cache) >= self.budget:
                self.progress("the search's budget of fits is spent: it stops here")
                break
            changed = False
            step = self._forward(current, chosen, candidates, sel)
            if step is not None:
                chosen, current = step
                changed = True
                if len(chosen) == 1:
                    pair = self._pairs(current, candidates)
                    if pair is not None:
                        chosen, current = pair
            if self.budget is not None and len(chosen) >= self.max_effects - 1 \
                    and current.reduced_chi2 > INADEQUATE:
                # a restart (_restart) with as many effects as the first search chose that
                # still leaves far more than the noise: the one effect more it may add must
                # take most of what is left, where the first search's set explained it
                self.progress(f"the search again leaves {current.reduced_chi2:.3g} x the "
                              f"noise with {len(chosen)} effects: it stops here")
                break
            chosen, current, dropped = self._backward(chosen, current)
            swapped = self._swap(chosen, current, candidates)
            if swapped is not None:
                chosen, current = swapped
            if not (changed or dropped or swapped is not None):
                break
            if frozenset(chosen) in seen:
                self.progress("the search comes back to a set it left: it stops there")
                break
            seen.add(frozenset(chosen))
        return chosen, current

    def _restart(self, chosen: list[str], current: FitResult, candidates: list[str],
                 base: FitResult) -> tuple[list[str], FitResult] | None:
        """The search again from the model as it is without the widest chosen effect (the
        most parameters the data fix), when the set explains the data within
        :data:`INADEQUATE` x the noise or the search stalled (:meth:`_forward`): the set it
        leads to when its BIC is lower, else None. After a stall the restart may add one
        effect more than the first search chose (sag, mass and drum scales behind a stall
        of load cells, exit points and drums at 33 x the noise). Alone too: 17 exit-point
        coordinates took, in one step, what pulley radii and two cables' stretch did on an
        IPAnema-class recording without tensions, and no effect was left for a second step.

        Greedy steps favour a wide effect while the model is far from the data: its many
        parameters take a share of several effects at once (exit points moved where pulley
        radii and a length offset, or the masts' bending and a drum's scale, act), and
        once it is in, none of those it imitates lowers the BIC alone, nor does a
        one-for-one swap: the whole path from the first step on is another. One restart
        without it follows that other path; what it cannot beat is kept.

        Only for an effect that the data fix with more parameters than any other candidate
        has (it can carry the shares of two of them; one no wider than another imitates
        what a single effect does, which the swaps test), and not for one of the load
        cells' gauge: what it shares with the others of the gauge, the gauge moves and
        swaps search already (:func:`_gauge_moves`, :func:`_gauge_swaps`).

        Also where the load cells, the only effect of the gauge chosen, carry a gain shared
        by the cells and leave far more than the noise (:meth:`_cells_as_scale`): the search
        runs again without them, and may name three effects in their place (the cables'
        weight, a lighter platform and stiffer cables read as every cell 30 % high, at 9 x
        the noise; without the cells the three explain it). Where both restarts apply, the
        better of the two is kept (exit points and the cells' gain stalled on sag, mass and
        drum scales: the restart without the exit points finds them)."""
        scale = self._cells_as_scale(chosen, current)
        if not chosen:
            return None
        tries = []
        if current.reduced_chi2 <= INADEQUATE or self.stalled:
            free = {e: int(np.isfinite(current.stderr[current.space.indices(e)]).sum())
                    for e in chosen}
            wide = max(chosen, key=lambda e: (free[e], -chosen.index(e)))
            widest_other = max((len(ParamSpace(self.model, (c,))) for c in candidates
                                if c != wide), default=0)
            if wide not in gauge.GAUGE_EFFECTS and free[wide] > widest_other:
                tries.append((wide, free[wide], 1 + int(self.stalled)))
        if scale:
            n_cells = int(np.isfinite(current.stderr[current.space.indices(
                "load_cell_calibration")]).sum())
            tries.append(("load_cell_calibration", n_cells, 3))
        for wide, _, _ in tries:
            if wide in self.restarted:
                self.progress(f"no search again without {wide}: the selection before this "
                              f"one ran it")
        tries = [t for t in tries if t[0] not in self.restarted]
        self.restarted.update(t[0] for t in tries)
        stalled = self.stalled
        best = None
        for wide, n_free, more in tries:
            rest = [c for c in candidates if c != wide]
            self.stalled = False
            self.progress(f"searching again without {wide} ({n_free} free parameters): "
                          f"it may imitate several effects")
            # a second opinion costs at most what the first search did (as many new sets),
            # and looks for the wide effect's place taken by two: one effect more at most
            # (two more where the first search stalled: it named what it could, not what
            # was; three for the cells' shared gain: the mass, the stretch and the cables'
            # weight each scale the tensions)
            self.budget, self.max_effects = 2 * len(self.cache), len(chosen) + more
            try:
                other, fit = self._search([], base, rest, Selection([], base, base))
            finally:
                self.budget, self.max_effects = None, MAX_EFFECTS
            if fit.bic < (current if best is None else best[1]).bic:
                best = (other, fit)
        if best is not None:
            self.progress(f"{' + '.join(sorted(best[0]))} explains the data better than "
                          f"{' + '.join(sorted(chosen))} (BIC {best[1].bic:.1f} against "
                          f"{current.bic:.1f})")
            return best
        self.stalled = stalled
        return None

    def _cells_as_scale(self, chosen: list[str], current: FitResult) -> bool:
        """Whether the load cells, chosen without another effect of their gauge, carry a
        gain shared by the cells (the median cell's off the model's) while the set leaves
        more than :data:`INADEQUATE` x the noise: the common gain scales every tension, as a
        heavier platform, stiffer cables or the cables' own weight do, and may stand in for
        several of them at once, none of which then lowers the BIC alone."""
        if "load_cell_calibration" not in chosen or current.reduced_chi2 <= INADEQUATE \
                or set(chosen) & (gauge.GAUGE_EFFECTS - {"load_cell_calibration"}):
            return False
        robot = current.space.robot(current.phi)
        with np.errstate(divide="ignore", invalid="ignore"):
            lr = np.log(robot.load_cell_gain / self.model.load_cell_gain)
        return bool(np.isfinite(lr).all() and abs(float(np.median(lr))) > gauge.MIN_MOVE)

    def _forward(self, current: FitResult, chosen: list[str], candidates: list[str],
                 sel: Selection) -> tuple[list[str], FitResult] | None:
        """Add the effect whose refit lowers the BIC most (screened by linearised signatures)."""
        rest = [c for c in candidates if c not in chosen and compatible(chosen, c)]
        if not rest or len(chosen) >= min(MAX_EFFECTS, self.max_effects):
            return None
        if self.stalled:
            return None
        self.progress(f"screening {len(rest)} candidate effects (reduced chi-square "
                      f"{current.reduced_chi2:.3g})")
        pred = self.screen(current, rest)
        if not chosen:
            sel.screening = dict(pred)
        promising = sorted((d, e) for e, d in pred.items() if d < -BIC_ENTER)[:3]
        tried = [e for _, e in promising]
        # along the load cells' gauge the screen sees nothing (a common gain, a mass change
        # and a common stretch give the same readings): what each would take over is fitted
        tried += [e for e in _gauge_moves(chosen, rest) if e not in tried]
        fits = self.fit_many([tuple(chosen + [e]) for e in tried], current,
                             multistart=current.reduced_chi2 > INADEQUATE
                             and self.measured_noise) if tried else []
        every = list(zip(fits, tried, strict=True))
        best = min(every, key=lambda x: x[0].bic) if fits else None
        # the linearised screen is myopic where effects overlap (offsets absorb most of a
        # pulley's signature): while the best model leaves far more than the noise, every
        # remaining candidate is refitted
        left = (best[0] if best else current).reduced_chi2
        if left > INADEQUATE and self.measured_noise and len(chosen) < WIDE_SEARCH:
            more = [e for e in rest if e not in tried]
            if more:
                self.progress(f"the best model leaves {left:.3g} x the noise: refitting every "
                              f"candidate")
                extra = self.fit_many([tuple(chosen + [e]) for e in more], current,
                                      multistart=True)
                for f, e in zip(extra, more, strict=True):
                    every.append((f, e))
                    if best is None or f.bic < best[0].bic:
                        best = (f, e)
        if best is not None and best[0].bic - current.bic <= -BIC_ENTER:
            # the BIC's drop must hold by the parameters' own errors too: of the sets that
            # clear the bar, the best whose new effect does. (Not where the set with it
            # still leaves :data:`FAR` x the noise and it took half of the excess: there
            # the errors measure the misfit of
            # the effects still missing, and would keep out every one of them; a CoGiRo
            # dwell without tensions, exit offsets at 286 x the noise, refused a drum scale
            # that lowered the BIC by 19,223, and the truth (BIC 132) was never reached.
            # The backward step checks the errors once the set explains the data.)
            clear = [(f, e) for f, e in every if f.bic - current.bic <= -BIC_ENTER]
            firm = [(f, e) for f, e in clear if _far_step(current, f) or stands_out(f, e, self.rm)]
            if not firm:
                weak = min(clear, key=lambda x: x[0].bic)
                w, k = wald_statistic(*weak)
                self.progress(f"{weak[1]} lowers the BIC by {current.bic - weak[0].bic:.1f}, "
                              f"but its {k} parameters stand out from the model's values "
                              f"by their own errors by a chi-square of {w:.1f} only: it "
                              f"does not enter")
            best = min(firm, key=lambda x: x[0].bic) if firm else (current, "")
        if best is not None and best[0].bic - current.bic > -BIC_ENTER:
            # an effect of the gauge that takes over what the chosen ones carried with more
            # parameters (a mass for every cell's gain) is a simpler account of the same
            # readings, not a new effect: a clear BIC drop is enough
            swaps = [(f, e) for f, e in zip(fits, tried, strict=True)
                     if _takes_over(e, chosen + [e], f, current)]
            best = min(swaps, key=lambda x: x[0].bic) if swaps else None
        if best is None:
            return self._whole_gauge(current, chosen, rest)
        # the vocabulary is not converging on the data (physics it lacks): an effect that
        # leaves far more than the noise and takes less than half of what was left is the
        # last one added
        before, after = current.reduced_chi2, best[0].reduced_chi2
        if chosen and after > INADEQUATE and before - after < 0.5 * (before - 1.0):
            self.progress(f"adding {best[1]} leaves {after:.3g} x the noise (was {before:.3g}): "
                          f"no further effect is tried")
            self.stalled = True
        return chosen + [best[1]], best[0]

    def _whole_gauge(self, current: FitResult, chosen: list[str], rest: list[str]
                     ) -> tuple[list[str], FitResult] | None:
        """With the load cells chosen and no other effect of their gauge: the mass and the
        cables' stretch added together (and the masts' compliance where the model's masts
        bend: the whole gauge, its scale pinned at the median cell), when that accounts for
        the readings with fewer free parameters and a BIC lower by more than
        :data:`BIC_TIE` (:func:`_takes_over`'s rule). Every cell's gain 8.6 % high is a
        platform 8.6 % heavier whose cables stretch as the model says only if they are 8.6 %
        stiffer too: neither the mass alone (the stretch then differs) nor the stretch alone
        takes it over, one step at a time."""
        if "load_cell_calibration" not in chosen or set(chosen) & {
                "platform_mass", "cable_elasticity", PER_CABLE_EA}:
            return None
        # only where at least half the cells share the departure (the median cell's gain is
        # off): else pinning at the median cell frees no gain, and the fit of the whole gauge
        # (with the masts, fifty parameters) is 46 s for nothing
        robot = current.space.robot(current.phi)
        with np.errstate(divide="ignore", invalid="ignore"):
            lr = np.log(robot.load_cell_gain / self.model.load_cell_gain)
        if not np.isfinite(lr).all() or abs(float(np.median(lr))) <= gauge.MIN_MOVE:
            return None
        add = [e for e in ("platform_mass", "cable_elasticity", "mast_compliance")
               if e in rest and e not in chosen]
        target = chosen + add
        if not gauge.complete(target, self.model):
            target = [e for e in target if e != "mast_compliance"]
            if not gauge.complete(target, self.model):
                return None
        if not all(compatible([c for c in target if c != e], e) for e in target):
            return None
        (f,) = self.fit_many([tuple(target)], current)
        if f.n_free < current.n_free and f.bic < current.bic - BIC_TIE:
            self.progress(f"{' + '.join(e for e in target if e not in chosen)} together "
                          f"take over the load cells' common gain (BIC {f.bic:.1f} against "
                          f"{current.bic:.1f}, {f.n_free} free parameters against "
                          f"{current.n_free})")
            return target, f
        return None

    def _pairs(self, current: FitResult, candidates: list[str]
               ) -> tuple[list[str], FitResult] | None:
        """When the best single effect leaves far more than the noise, the best pairs of
        single effects (greedy selection can take first an effect that imitates two others,
        sag for compliance, and never recover): the pairs of every fitted single effect
        ranked by their joint linearised fit at the model, the best :data:`PAIR_FITS` and
        the best of the :data:`PAIR_TOP` best single effects fitted from either member's own
        fit. The pair replaces the single effect when it lowers the BIC."""
        if current.reduced_chi2 <= INADEQUATE or not self.measured_noise:
            return None
        singles = sorted(((f.bic, k[0]) for k, f in self.cache.items()
                          if len(k) == 1 and k[0] in candidates), key=lambda x: x[0])
        best4 = {e for _, e in singles[:PAIR_TOP]}
        # every fitted single takes part: effects on different residual blocks (load cells
        # on the force balance, geometry on the lengths) each do little alone against the
        # other's share, and a pair of them can be what the data hold
        top = [e for _, e in singles]
        pairs = [(a, b) for i, a in enumerate(top) for b in top[i + 1:] if compatible([a], b)]
        # rank the pairs by their linearised fit at the model, refit the best few
        base = self.cache.get(())
        robot0 = self.model
        r0 = self.rm.whitened(robot0, self.train)
        cols = {}
        for e in top:
            sub = ParamSpace(robot0, (e,))
            J = fd_jacobian(lambda phi, s=sub: self.rm.whitened(s.robot(phi), self.train),
                            sub.neutral, r0, sub.scale * 1e-2, sub.lo, sub.hi,
                            self.rm.frozen)
            # and the secant to the effect's own fit: where its residuals start at a kink
            # or bend (a sag's lengths grow with the square of the cables' weight, a
            # pulley radius from zero), the tangent at the model sees only a part of what
            # the effect does, and a pair with it ranked low however well it fits
            own = self.cache[(e,)]
            sec = self.rm.whitened(own.space.robot(own.phi), self.train) - r0
            lo, hi = np.append(sub.lo, -1.0), np.append(sub.hi, 2.0)
            cols[e] = (np.append(sub.neutral, 0.0), lo, hi, np.hstack([J, sec[:, None]]))
        ranked = []
        for a, b in pairs:
            (xa, la, ha, ja), (xb, lb, hb, jb) = cols[a], cols[b]
            J = np.hstack([ja, jb])
            x0 = np.concatenate([xa, xb])
            d = _bounded_lstsq(J, -r0, x0, np.concatenate([la, lb]), np.concatenate([ha, hb]))
            r1 = r0 + J @ d
            ranked.append((float(r1 @ r1), (a, b)))
        del base
        ranked.sort(key=lambda x: x[0])
        # the best pairs by their linearised fit, and the best of the best single effects
        # (the linearisation is rough where a parameter starts at a kink: a pulley radius)
        picked = [p for _, p in ranked[:PAIR_FITS]]
        among = [p for _, p in ranked if set(p) <= best4]
        if among and among[0] not in picked:
            picked.append(among[0])
        todo = [tuple(sorted(p)) for p in picked if tuple(sorted(p)) not in self.cache]
        if not todo:
            return None
        self.progress(f"the best single effect leaves {current.reduced_chi2:.3g} x the noise: "
                      f"fitting the {len(todo)} pairs of the {len(top)} best")
        jobs = []
        for p in todo:
            for member in p:
                jobs.append((p, _warm(p, self.cache[(member,)])))
        results: dict[tuple[str, ...], FitResult] = {}
        done = list(zip([p for p, _ in jobs], fits_side_by_side(self.pool, self.rm, [
            (ParamSpace(self.model, p), self.train, phi0, {}) for p, phi0 in jobs]),
            strict=True))
        for p, res in done:
            if p not in results or res.bic < results[p].bic:
                results[p] = res
        self.cache.update(results)
        best = min(results.items(), key=lambda kv: kv[1].bic)
        if best[1].bic - current.bic > -BIC_ENTER:
            return None
        return list(best[0]), best[1]

    def _backward(self, chosen: list[str], current: FitResult
                  ) -> tuple[list[str], FitResult, bool]:
        """Drop effects the others make unnecessary."""
        dropped = False
        if len(chosen) > 1:
            # every set without one effect, and the refits from ``current`` of those fitted
            # before (:meth:`fit` refits a subset of its start): side by side on the pool.
            # A drop makes the ones after it moot; without one, each is asked for in turn
            # (12883: five refits in a row, 4 s)
            self.prefetch([tuple(c for c in chosen if c != e) for e in chosen], current,
                          refits=True)
        for e in list(chosen):
            if len(chosen) < 2:
                break
            reduced = self.fit(tuple(c for c in chosen if c != e), current)
            weak = not _far_step(reduced, current) and not stands_out(current, e, self.rm)
            if (reduced.bic - current.bic < BIC_ENTER or weak) and not _takes_over(
                    e, chosen, current, reduced):
                self.progress(f"dropping {e}: the other effects explain it" if not weak else
                              f"dropping {e}: its parameters do not stand out from the "
                              f"model's by their errors")
                chosen = [c for c in chosen if c != e]
                current = reduced
                dropped = True
        return chosen, current, dropped

    def swap_screen(self, current: FitResult, chosen: list[str], candidates: list[str]
                    ) -> dict[tuple[str, str], float]:
        """Predicted BIC change of replacing each chosen effect by each other candidate,
        linearised at the current fit with the remaining effects refitted jointly."""
        # (the candidates are part of the key: a selection run again without an effect must
        # not be handed swaps into it from the run before)
        # (the fit is kept with its entry: its id, and those of :attr:`_signal`, cannot be
        # another fit's while the entry lives; a fit the cache let go of could otherwise
        # hand its screen to a later one at the same address, as the pool allocates)
        key = (id(current), tuple(chosen), tuple(candidates))
        if key in self._swap_cache:
            return self._swap_cache[key][1]
        space = current.space
        out: dict[tuple[str, str], float] = {}
        r_cur = self.rm.whitened(space.robot(current.phi), self.train)
        n_res = len(r_cur)
        # the current fit's BIC on the residuals alone, as the linearised swaps have them (a
        # fit's chi-square may hold the likelihood's Jacobian term: bench.diagnosis.likelihood)
        base = float(r_cur @ r_cur) + current.bic - current.chi2
        for e in chosen:
            phi_wo = current.phi.copy()
            ix = space.indices(e)
            phi_wo[ix] = space.neutral[ix]
            keep = np.setdiff1d(np.arange(len(space)), ix)
            robot_wo = space.robot(phi_wo)
            r_wo = self.rm.whitened(robot_wo, self.train)
            self._signal[key + (e,)] = float(r_wo @ r_wo - r_cur @ r_cur)

            def fun_keep(z: np.ndarray, phi_wo=phi_wo, keep=keep) -> np.ndarray:
                full = phi_wo.copy()
                full[keep] = z
                return self.rm.whitened(space.robot(full), self.train)

            J_keep = fd_jacobian(fun_keep, phi_wo[keep], r_wo, space.scale[keep] * 1e-2,
                                 space.lo[keep], space.hi[keep], self.rm.frozen) \
                if len(keep) else \
                np.zeros((n_res, 0))
            p_keep = int(np.isfinite(current.stderr[keep]).sum())
            for a in candidates:
                if a in chosen or not compatible([c for c in chosen if c != e], a):
                    continue
                sub = ParamSpace(robot_wo, (a,))
                J_a = fd_jacobian(lambda phi, s=sub: self.rm.whitened(s.robot(phi), self.train),
                                  sub.neutral, r_wo, sub.scale * 1e-2, sub.lo, sub.hi,
                                  self.rm.frozen)
                J = np.hstack([J_keep, J_a])
                x0 = np.concatenate([phi_wo[keep], sub.neutral])
                lo = np.concatenate([space.lo[keep], sub.lo])
                hi = np.concatenate([space.hi[keep], sub.hi])
                d = _bounded_lstsq(J, -r_wo, x0, lo, hi)
                r1 = r_wo + J @ d
                bic_pred = float(r1 @ r1) + (p_keep + len(sub)) * np.log(n_res)
                out[(e, a)] = bic_pred - base
        self._swap_cache[key] = (current, out)
        return out

    def _swap(self, chosen: list[str], current: FitResult, candidates: list[str]
              ) -> tuple[list[str], FitResult] | None:
        """Replace a chosen effect by another when that lowers the BIC clearly (a look-alike
        that entered first): by :data:`BIC_ENTER`, or by :data:`BIC_TIE` where the other
        needs no more free parameters (two accounts of one signature, the better by a
        likelihood ratio of 150 at equal cost: a sag entered as a lighter platform, whose
        tangent at the model it shares, and lost to it by 12 only). Only swaps the
        linearised screen finds promising are refitted."""
        if not chosen:
            return None
        pred = self.swap_screen(current, chosen, candidates)
        pairs = [p for p, d in sorted(pred.items(), key=lambda kv: kv[1])
                 if d < SWAP_SCREEN][:4]
        # swaps along the load cells' gauge, which the linearised screen cannot see
        pairs += [p for p in _gauge_swaps(chosen, candidates) if p not in pairs]
        pairs += [p for p in self._displaced(chosen, candidates) if p not in pairs]
        if not pairs:
            return None
        sets = [tuple(c for c in chosen if c != e) + (a,) for e, a in pairs]
        fits = self.fit_many(sets, current)
        best = min(range(len(fits)), key=lambda k: fits[k].bic)
        bar = BIC_TIE if fits[best].n_free <= current.n_free else BIC_ENTER
        if fits[best].bic - current.bic > -bar:
            return None
        e, a = pairs[best]
        self.progress(f"swapping {e} for {a}: it explains the data better")
        return [c for c in chosen if c != e] + [a], fits[best]

    def _displaced(self, chosen: list[str], candidates: list[str]) -> list[tuple[str, str]]:
        """(chosen, other) swaps where the fit of the chosen effects with the other added
        (fitted already) holds every parameter of that chosen one at the model's values:
        the other took its place, which a screen linearised at the model may not see (a
        sag's tangent there is the load it adds, a mass's)."""
        out = []
        for a in candidates:
            f = self.cache.get(tuple(sorted(chosen + [a]))) if a not in chosen else None
            if f is None:
                continue
            for e in chosen:
                ix = f.space.indices(e)
                if len(ix) and np.array_equal(f.phi[ix], f.space.neutral[ix]):
                    out.append((e, a))
        return out

    def _importance(self, e: str, chosen: list[str], current: FitResult) -> float:
        without = self.fit(tuple(c for c in chosen if c != e), current)
        return without.chi2 - current.chi2

    def _lookalikes(self, sel: Selection, candidates: list[str]) -> None:
        chosen = sel.effects
        cur = sel.fit
        pred = self.swap_screen(cur, chosen, candidates) if chosen else {}
        for e in chosen:
            others = [c for c in candidates if c not in chosen
                      and compatible([x for x in chosen if x != e], c)]
            near = [a for a in others if pred.get((e, a), np.inf) < BIC_TIE + SWAP_SCREEN_MARGIN
                    or (e, a) in _gauge_swaps(chosen, candidates)]
            # the screen is linear: its error grows with the signal it is asked to replace
            # (pulley radii for exit offsets of 0.1 m: predicted +228, refitted -11; one
            # cable's E*A for the masts beside exit offsets and the mass: +107, refitted
            # -37), so the best predictions within a fraction of that signal, or within a
            # margin, are refitted too
            signal = self._signal.get((id(cur), tuple(chosen), tuple(candidates), e), 0.0)
            wide = sorted((pred[(e, a)], a) for a in others if (e, a) in pred
                          and pred[(e, a)] < BIC_TIE + max(LINEAR_ERROR * signal,
                                                           LOOKALIKE_MARGIN))
            near += [a for _, a in wide[:LOOKALIKE_REFITS] if a not in near]
            sets = [tuple(c for c in chosen if c != e) + (a,) for a in near]
            alt = []
            for a, f in zip(near, self.fit_many(sets, cur), strict=True):
                d = f.bic - cur.bic
                if d < BIC_TIE:
                    alt.append((a, float(d)))
            # a swap the search fitted already (a displaced effect, a pair) is as good a
            # witness as a refit: within the tie it is an alternative, whatever the screen
            # predicted (a sag 2.5 lower in BIC than the mass the greedy order chose was
            # not listed: case 12435)
            for a in others:
                f = self.cache.get(tuple(sorted([c for c in chosen if c != e] + [a])))
                if f is not None and a not in [x for x, _ in alt] \
                        and f.bic - cur.bic < BIC_TIE:
                    alt.append((a, float(f.bic - cur.bic)))
            sel.imitation[e] = self.imitation(cur, e, others)
            # an effect that reproduces this one's signature almost entirely is a declared
            # ambiguity even when its extra parameters cost it BIC (not when its refit fits
            # worse: the linearised imitation saw a likeness the data do not bear out)
            for a, v in sel.imitation[e].items():
                if v >= IMITATES and a not in [x for x, _ in alt]:
                    f = self.fit(tuple(c for c in chosen if c != e) + (a,), cur)
                    if f.chi2 - cur.chi2 < BIC_TIE:
                        alt.append((a, float(f.bic - cur.bic)))
            sel.alternatives[e] = sorted(alt, key=lambda x: x[1])

    def imitation(self, fit: FitResult, effect: str, others: list[str]) -> dict[str, float]:
        """How well each other effect reproduces ``effect``'s signature on these poses
        (fraction of the signature explained, linearised, 0..1)."""
        space = fit.space
        phi_wo = fit.phi.copy()
        ix = space.indices(effect)
        phi_wo[ix] = space.neutral[ix]
        robot_wo = space.robot(phi_wo)
        r_with = self.rm.whitened(space.robot(fit.phi), self.train)
        r_wo = self.rm.whitened(robot_wo, self.train)
        sig = r_wo - r_with
        norm = float(sig @ sig)
        out = {}
        if norm <= 0:
            return out
        for a in others:
            sub = ParamSpace(robot_wo, (a,))
            J = fd_jacobian(lambda phi, s=sub: self.rm.whitened(s.robot(phi), self.train),
                            sub.neutral, r_wo, sub.scale * 1e-2, sub.lo, sub.hi, self.rm.frozen)
            delta = _bounded_lstsq(J, -sig, sub.neutral, sub.lo, sub.hi)
            rem = sig + J @ delta
            out[a] = float(np.clip(1.0 - (rem @ rem) / norm, 0.0, 1.0))
        return out


def wald_statistic(fit: FitResult, effect: str) -> tuple[float, int]:
    """(W, k): the Wald statistic of ``effect``'s parameters' departure from the model's
    values under ``fit``'s covariance (the others free), and k the parameters the data fix
    (0, 0 when none)."""
    ix = _fitted(fit, fit.space.indices(effect))
    if not len(ix):
        return 0.0, 0
    w = quad_form((fit.phi - fit.space.neutral)[ix], fit.cov[np.ix_(ix, ix)])
    return (w if np.isfinite(w) else 0.0), len(ix)


def stands_out(fit: FitResult, effect: str, rm: ResidualModel | None = None) -> bool:
    """Whether ``effect``'s parameters in ``fit`` depart from the model's values, by their
    own errors, at the significance the BIC asks of one parameter to enter (a chi-square
    drop of :data:`BIC_ENTER` + ln n): the Wald statistic's tail probability with as many
    degrees of freedom as parameters the data fix is below that one's.

    The BIC's chi-square counts every residual as independent evidence of the stated
    noise. The fit's covariance is the residuals' own (a sandwich of their structure:
    :func:`bench.diagnosis.fit.standard_errors`): where rows share their errors (a
    continuous recording's rows between two stops, a per-visit change of the lengths)
    or the model misfits, W is smaller than the chi-square's drop. A parameter named 1.7
    standard errors from the model's value is no finding, whatever the chi-square said.
    (The BIC's charge per parameter is the complexity's, which the BIC made; this test
    asks only that the departure be real.) With the residual model ``rm``, a tracker
    latency must also exceed what the recording's time stamps can resolve
    (:func:`bench.diagnosis.frame.material`)."""
    from scipy.stats import chi2 as chi2_dist

    w, k = wald_statistic(fit, effect)
    if k == 0:
        return False
    if rm is not None and not material(rm, effect, fit.space.values(fit.phi).get(effect, {})):
        return False
    bar = BIC_ENTER + float(np.log(max(fit.n_eff or fit.n_res, 2)))
    return bool(chi2_dist.sf(w, k) < chi2_dist.sf(bar, 1))


def design_effect(fit: FitResult, effects: list[str] | tuple[str, ...] | np.ndarray
                  ) -> float:
    """How many times the chi-square's drop for ``effects``' parameters in ``fit`` (a fit
    with them) overstates the evidence their own errors give: the Wald statistic of their
    departure from the model's values by the naive covariance ``(J^T J)^-1`` (every
    residual an independent error of the stated noise: what the chi-square counts, to
    first order) over the same by the fit's covariance (the sandwich of the error model:
    rows of a move or visit share one error, a per-visit change of the lengths blends
    along a move). At least 1 (where the error model finds the rows surer than stated, the
    chi-square stands); 1 where the parameters are fixed by nothing, sit at the model's
    values, or where ``fit`` is far from the data (:data:`FAR`: its errors measure a
    misfit, not the noise). An IPAnema-class continuous recording, 0.6 mm per visit:
    about 4 for exit-point offsets (1064 residuals, ~144 independent errors).
    ``effects``: effect names, or the parameters' indices in ``fit.space``."""
    if fit.curvature_cov is None or not np.isfinite(fit.reduced_chi2) \
            or fit.reduced_chi2 > FAR:
        return 1.0
    space = fit.space
    given = np.asarray(effects).dtype.kind in "iu"
    cols = list(np.asarray(effects, dtype=int)) if given else \
        [k for e in effects if e in space.effects for k in space.indices(e)]
    ix = _fitted(fit, cols)
    if not len(ix):
        return 1.0
    d = (fit.phi - space.neutral)[ix]
    naive = quad_form(d, fit.curvature_cov[np.ix_(ix, ix)])
    robust = quad_form(d, fit.cov[np.ix_(ix, ix)])
    if not (np.isfinite(naive) and np.isfinite(robust)) or robust <= 0.0 or naive <= 0.0:
        return 1.0
    return max(naive / robust, 1.0)


def honest_bic(fit: FitResult, whole: FitResult) -> float:
    """The BIC of ``fit`` relative to ``whole``'s, where ``whole`` (on the same samples)
    holds every parameter of ``fit`` and more (an effect or a nuisance added): the
    chi-square's difference divided by the design effect (:func:`design_effect`) of the
    parameters ``whole`` fits and ``fit`` does not (absent, or held at the model's value),
    in ``whole`` (the evidence of their departure by their own
    errors), plus the BIC's charge of those parameters. With independent errors, ``fit.bic
    - whole.bic``; that plain difference too where ``fit`` is not within ``whole``."""
    plain = float(fit.bic - whole.bic)
    if not within(fit, whole):
        return plain
    mine = {(p.effect, p.key): k for k, p in enumerate(fit.space.params)}
    extra = np.array([k for k, p in enumerate(whole.space.params) if _free(whole, k)
                      and not ((p.effect, p.key) in mine and _free(fit, mine[p.effect, p.key]))],
                     dtype=int)
    if not len(extra):
        return plain
    paid = (fit.bic - fit.chi2) - (whole.bic - whole.chi2)  # (the parameters' charge)
    return float(fit.chi2 - whole.chi2) / design_effect(whole, extra) + float(paid)


def _free(fit: FitResult, k: int) -> bool:
    """Whether ``fit`` fitted its parameter ``k`` (not held at the model's value: a finite,
    positive standard error)."""
    se = float(fit.stderr[k])
    return bool(np.isfinite(se)) and se > 0


def _fitted(fit: FitResult, cols) -> np.ndarray:
    """The indices among ``cols`` of the parameters ``fit`` fitted (:func:`_free`)."""
    return np.array([k for k in cols if _free(fit, k)], dtype=int)


def within(fit: FitResult, whole: FitResult) -> bool:
    """Whether every parameter of ``fit`` is one of ``whole``'s (by effect and name)."""
    return {(p.effect, p.key) for p in fit.space.params} <= {
        (p.effect, p.key) for p in whole.space.params}


def _far_step(without: FitResult, with_: FitResult) -> bool:
    """Whether adding an effect moved a fit still far from the data (``with_`` leaves more
    than :data:`FAR` x the noise) by half of what ``without`` left above the noise or
    more: its errors measure the misfit of the effects still missing, and its own
    parameters need not stand out by them. (An effect that takes a tenth of a misfit
    outside the vocabulary is no such step: the errors decide there.)"""
    before, after = without.reduced_chi2, with_.reduced_chi2
    return bool(after > FAR and before - after >= 0.5 * (before - 1.0))


def _warm(effects: tuple[str, ...], start: FitResult | None) -> np.ndarray | None:
    if start is None:
        return None
    space = ParamSpace(start.space.model, effects)
    phi0 = space.neutral.copy()
    for k, p in enumerate(space.params):
        for j, q in enumerate(start.space.params):
            if p.key == q.key and p.effect == q.effect:
                phi0[k] = start.phi[j]
    return phi0


#: effects of the load cells' gauge the selection moves between (the common form of the
#: stretch: a per-cable stretch and the masts' compliance come in by their own evidence)
GAUGE_MOVES = ("load_cell_calibration", "platform_mass", "cable_elasticity")


def _gauge_moves(chosen: list[str], rest: list[str]) -> list[str]:
    """Candidates to add for what they take over along the load cells' gauge: with the
    load cells and another effect of the group chosen (or the load cells alone), the others
    of :data:`GAUGE_MOVES`; with the group chosen without the load cells, the load cells."""
    held = set(chosen) & gauge.GAUGE_EFFECTS
    if not held:
        return []
    if "load_cell_calibration" in held:
        return [e for e in GAUGE_MOVES if e in rest and compatible(chosen, e)]
    return ["load_cell_calibration"] if "load_cell_calibration" in rest else []


def _on_gauge(effects: tuple[str, ...]) -> bool:
    """Whether a set holds the load cells and another effect of their gauge."""
    e = set(effects)
    return "load_cell_calibration" in e and bool(
        e & {"platform_mass", "cable_elasticity", PER_CABLE_EA})


def _takes_over(e: str, chosen: list[str], with_: FitResult, without: FitResult) -> bool:
    """Whether effect ``e`` of the load cells' gauge, among ``chosen`` (with the load cells),
    accounts more simply for what the others carry without it: fewer free parameters with
    it and a BIC lower by more than :data:`BIC_TIE` (a mass for a gain shared by every cell:
    the same readings, eight parameters for one)."""
    # the mass trades exactly with the cells' common gain in the statics; the stretch only
    # where the mass is free too (else the mass fixes the tensions' scale, and a stretch is
    # an effect of its own that must pay its way like any other)
    on_orbit = e == "platform_mass" or (e == "cable_elasticity" and "platform_mass" in chosen)
    return (on_orbit and "load_cell_calibration" in chosen
            and with_.n_free < without.n_free and with_.bic < without.bic - BIC_TIE)


def _gauge_swaps(chosen: list[str], candidates: list[str]) -> list[tuple[str, str]]:
    """(chosen, other) swaps within :data:`GAUGE_MOVES` where the load cells are among
    the two sets (one effect taking over another's share of the gauge)."""
    out = []
    for e in chosen:
        if e not in gauge.GAUGE_EFFECTS:
            continue
        for a in GAUGE_MOVES:
            if a in chosen or a not in candidates \
                    or not compatible([c for c in chosen if c != e], a):
                continue
            if "load_cell_calibration" in set(chosen) | {a} and \
                    not (a == "load_cell_calibration" and e == "load_cell_calibration"):
                out.append((e, a))
    return out


def _bounded_lstsq(J: np.ndarray, b: np.ndarray, x0: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> np.ndarray:
    """min |J d - b| with x0 + d within bounds (scipy lsq_linear), d returned."""
    from scipy.optimize import lsq_linear

    if J.shape[1] == 0:
        return np.zeros(0)
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    res = lsq_linear(J / scale, b, bounds=((lo - x0) * scale, (hi - x0) * scale),
                     lsmr_tol="auto", method="bvls" if J.shape[1] < 60 else "trf")
    return res.x / scale
