"""Weighted least squares of effect parameters (scipy.optimize.least_squares, bounded).

Plain functions, arrays in and out: :func:`fit_effects` returns a
:class:`FitResult` with the parameters, chi-square, BIC, and standard errors
from the whitened Jacobian at the solution.
"""

from __future__ import annotations

import copy
import hashlib
import math
import weakref
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from bench.diagnosis.likelihood import StretchLikelihood
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.space import ParamSpace, undetermined
from bench.parallel import (
    claim_core,
    fork_array,
    join_array,
    kill_forked,
    release_core,
    sharing_cores,
)

#: evaluations of one least-squares run, and runs more from where it stopped if it did not
#: converge but lowered the chi-square (a run that spent its budget without progress is not
#: repeated; a fit that still has not converged is reported as such)
MAX_NFEV = 80
RETRIES = 2
#: relative tolerances on chi-square and parameters (chi-square differences that decide
#: matter from about 1: far coarser than this)
FIT_TOL = 1e-7
#: fits of at least this many free parameters take the path to their minimum with secant
#: (Broyden) updates of the Jacobian between finite-difference ones (one evaluation a step
#: instead of one per parameter), and are then checked and finished with finite differences
SECANT_MIN = 6
#: a secant step whose chi-square drop is below this share of the drop its Jacobian
#: predicted gets finite differences again; so does every this-many-th step
SECANT_RATIO = 0.5
SECANT_STEPS = 6
#: a fit is at its minimum when the Gauss-Newton step with finite-difference Jacobian (within
#: the bounds) predicts a chi-square drop below this (parameters within about a tenth of a
#: standard error of the minimum) or below FIT_TOL of the chi-square
SETTLED = 1e-2

@dataclass
class FitResult:
    """``phi`` fit-space values; ``chi2`` sum of squared whitened residuals of the fitted
    samples; ``n_res`` their count; ``bic`` = chi2 + p ln(n_res); ``stderr`` fit-space
    standard errors (inflated by sqrt(chi2/dof) when above 1); ``cov``; ``success``."""

    space: ParamSpace
    phi: np.ndarray
    chi2: float
    n_res: int
    bic: float
    stderr: np.ndarray
    cov: np.ndarray
    success: bool
    message: str
    nfev: int = 0
    dof_lost: float = 0.0  # residual degrees of freedom taken by per-sample unknowns
    n_free: int = 0
    n_eff: float | None = None  # effective number of residuals (weights summed)
    #: fit-space variance of the error that holding pruned parameters at the model's values
    #: may have moved into the others (:func:`pruning_bias_var`); zero without pruning
    bias_var: np.ndarray | None = None
    #: fit-space covariance of the free parameters from the whitened Jacobian alone
    #: ``(J^T J)^-1`` (zero elsewhere): how the chi-square rises away from the minimum
    #: (:func:`pruning_cost`), where ``cov`` is how far the data may put it
    curvature_cov: np.ndarray | None = None
    #: per parameter, the degrees of freedom of ``stderr`` (Welch-Satterthwaite over the
    #: error model's components, :func:`effective_dof`); None: as many as a normal's
    stderr_dof: np.ndarray | None = None
    #: per parameter, whether it was estimated beside linear nuisance columns that refits do
    #: not carry (:func:`bench.diagnosis.frame.latency_beside_direction`): its linearised
    #: interval is the joint fit's, and no profile refit or jackknife of this fit's model
    #: checks it; None: none was
    beside_nuisance: np.ndarray | None = None

    def copy(self) -> FitResult:
        """A copy whose arrays its user may change (``bias_var`` is added to in place;
        ``space`` and ``beside_nuisance`` are shared)."""
        return replace(self, phi=self.phi.copy(), stderr=self.stderr.copy(),
                       cov=self.cov.copy(),
                       bias_var=None if self.bias_var is None else self.bias_var.copy(),
                       curvature_cov=None if self.curvature_cov is None
                       else self.curvature_cov.copy(),
                       stderr_dof=None if self.stderr_dof is None else self.stderr_dof.copy())

    @property
    def reported_stderr(self) -> np.ndarray:
        """Standard errors as reported: the fit's, with the error pruning may have moved in."""
        if self.bias_var is None:
            return self.stderr
        return np.sqrt(self.stderr ** 2 + self.bias_var)

    @property
    def dof(self) -> float:
        n = self.n_res if self.n_eff is None else self.n_eff
        return max(n - self.n_free - self.dof_lost, 1.0)

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof


def bic(chi2: float, n_params: int, n_res: int) -> float:
    """Bayesian information criterion for Gaussian residuals of known noise."""
    return chi2 + n_params * np.log(max(n_res, 2))


def fd_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
                steps: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                frozen: Callable[[], AbstractContextManager] | None = None) -> np.ndarray:
    """Forward differences with absolute steps, turned inward at the bounds. ``frozen``
    (e.g. :meth:`ResidualModel.frozen`) is entered around the columns when ``f0`` is the
    last evaluation ``fun`` made: the columns keep its per-sample solutions' pieces."""
    J = np.empty((len(f0), len(x)))
    h = np.where(x + steps <= hi, steps, -steps)
    h = np.where(x + h < lo, steps, h)

    def columns(ks: range) -> np.ndarray:
        out = np.empty((len(f0), len(ks)))
        for i, k in enumerate(ks):
            xp = x.copy()
            xp[k] += h[k]
            out[:, i] = (fun(xp) - f0) / h[k]
        return out

    with frozen() if frozen is not None else nullcontext():
        mine, child = range(len(x)), None
        claimed = len(x) >= SPLIT_MIN and claim_core()
        try:
            if claimed:
                half = (len(x) + 1) // 2
                theirs = range(half, len(x))
                child = fork_array(lambda: columns(theirs), (len(f0), len(theirs)))
                if child is not None:
                    mine = range(half)
            try:
                J[:, mine] = columns(mine)
            except BaseException:
                if child is not None:
                    kill_forked(child)
                raise
            if child is not None:
                got = join_array(child)
                J[:, theirs] = got if got is not None else columns(theirs)
        finally:
            if claimed:
                release_core()
    return J


#: Jacobians with at least this many columns split them (:func:`split_columns`)
SPLIT_MIN = 4


@contextmanager
def split_columns(pool: object = None) -> Iterator[None]:
    """Inside, :func:`fd_jacobian` in this process computes half of its columns in a
    forked child where a core is idle (:func:`bench.parallel.claim_core`): for a diagnosis
    whose process pool sits idle while this process fits (the columns of a recording
    without load cells or a tracker are four fifths of its time). With ``pool`` a
    core-sharing :func:`bench.parallel.worker_pool`, its workers do the same when the
    other workers wait (the last fit of a batch). The columns are the same (each starts
    from the state the evaluation before them left, which the child has as it is)."""
    with sharing_cores(pool):
        yield


#: fits kept per residual model (:func:`fit_effects`' memo)
MEMO_SIZE = 512
_MEMO: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _memo_key(space: ParamSpace, rm: ResidualModel, idx: np.ndarray,
              phi0: np.ndarray | None, max_nfev: int, hold: np.ndarray | None,
              prune: bool) -> tuple:
    """What a fit's result hangs on: the space (its effects on its model), the samples, the
    start, what is held, the budget, the residual model's noise (its whitening) and this
    module's settings. Not the residual model's warm starts: they only shorten the path."""
    h = hashlib.blake2b(digest_size=20)
    for a in (idx, phi0, hold, space.neutral, rm.slip_times, rm.sqrt_w, rm.len_rank, rm.reference,
              *(rm.sd[k] for k in sorted(rm.sd))):
        if a is None:
            h.update(b"-")
        else:
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype, a.shape)).encode())
            h.update(a.tobytes())
    h.update(repr((rm.visit_sd, rm.visit_rows, getattr(rm, "visit_dof", None),
                   rm.slack_threshold, rm.cells_at)).encode())
    settings = (MAX_NFEV, RETRIES, FIT_TOL, SECANT_MIN, SECANT_RATIO, SECANT_STEPS, SETTLED,
                PRUNE_HOPELESS,
                id(least_squares), id(fd_jacobian))
    return (id(space.model), id(rm.s), space.effects, int(max_nfev), bool(prune), settings,
            h.digest())


def fit_effects(space: ParamSpace, rm: ResidualModel, idx: np.ndarray,
                phi0: np.ndarray | None = None, max_nfev: int = MAX_NFEV,
                hold: np.ndarray | None = None, prune: bool = True,
                free_traded: bool = False) -> FitResult:
    """Fit the parameters of ``space`` to the samples ``idx`` (whitened inverse residuals).

    ``hold`` marks parameters kept at the model's values. With ``prune``, parameters
    that come out within two standard errors of the model's value are then held there
    and the rest refitted, when that lowers the BIC: an effect counts only the
    parameters the data need (three offset cables, not twenty-four). With ``free_traded``
    (the report's final fit, not the selection's: a parameter freed charges the BIC of
    every set it is in), a weak parameter that a kept one of another effect stands in for
    (:func:`traded_parameters`) is not held.

    A fit asked for again with the same inputs (the selection reaches one set from one
    start on several paths: a backward step and a held-out check, a gauge start equal to
    the warm one) is the one made before (a copy), not made again: run again, it would
    only move within the fit's tolerance with the residual model's warm starts.
    """
    key = _memo_key(space, rm, idx, phi0, max_nfev, hold, prune) + (free_traded,)
    memo = _MEMO.setdefault(rm, {})
    got = memo.get(key)
    if got is not None:
        return got[-1].copy()
    with rm.cold():  # the same fit whatever was evaluated before it
        res = _fit_effects(space, rm, idx, phi0, max_nfev, hold, prune, free_traded)
    _remember(memo, key, space, rm, res)
    return res


#: one call of :func:`fit_effects` (:func:`fits_side_by_side`): the space, the samples, the
#: start, and its keyword arguments (``hold``, ``max_nfev``, ``prune``, ``free_traded``)
FitJob = tuple[ParamSpace, np.ndarray, "np.ndarray | None", dict]


def _job_key(rm: ResidualModel, job: FitJob) -> tuple:
    """:func:`fit_effects`' memo key of ``job`` on ``rm``."""
    space, idx, phi0, kw = job
    return _memo_key(space, rm, idx, phi0, kw.get("max_nfev", MAX_NFEV), kw.get("hold"),
                     kw.get("prune", True)) + (bool(kw.get("free_traded", False)),)


def _pool_job(rm: ResidualModel, job: FitJob) -> FitResult:
    """:func:`fit_effects` of ``job`` in a worker of the process pool (a plain function)."""
    from bench.parallel import job_running

    space, idx, phi0, kw = job
    with job_running():
        return fit_effects(space, rm, idx, phi0, **kw)


def fits_side_by_side(pool: object, rm: ResidualModel, jobs: list[FitJob]) -> list[FitResult]:
    """:func:`fit_effects` of every job on ``rm``: the fits made or kept in this process
    before from its memo, the others on the process ``pool`` side by side (in this process
    without one, or for a single job), and each kept in this process's memo as if it had
    been made here. A fit is a function of its inputs alone (:meth:`ResidualModel.cold`),
    so a worker's is the one this process would have made: a fit made ahead on the pool
    (a prefetch) is found by whoever asks for it here later, and the process pool changes
    when fits are made, never what they are or which are asked for."""
    memo = _MEMO.setdefault(rm, {})
    keys = [_job_key(rm, job) for job in jobs]
    out: list[FitResult | None] = [memo[k][-1].copy() if k in memo else None for k in keys]
    todo = [i for i, f in enumerate(out) if f is None and keys.index(keys[i]) == i]
    if pool is not None and len(todo) > 1:
        futs = [(i, pool.submit(_pool_job, rm, jobs[i])) for i in todo]  # type: ignore[attr-defined]
        for i, fu in futs:
            res = fu.result()
            _remember(memo, keys[i], jobs[i][0], rm, res)
            out[i] = res
    for i, job in enumerate(jobs):
        if out[i] is None:
            space, idx, phi0, kw = job
            out[i] = fit_effects(space, rm, idx, phi0, **kw)  # (or the memo's: a repeated job)
    return out  # type: ignore[return-value]


def _remember(memo: dict, key: tuple, space: ParamSpace, rm: ResidualModel,
              res: FitResult) -> None:
    """Keep a copy of ``res`` as :func:`fit_effects`' answer to ``key`` on ``rm``."""
    if len(memo) >= MEMO_SIZE:
        memo.pop(next(iter(memo)))
    # (the model, the samples and the functions named by id in the key are kept alive with
    # the entry: their ids cannot be reused while it lives)
    memo[key] = (space.model, rm.s, least_squares, fd_jacobian, res.copy())


def _fit_effects(space: ParamSpace, rm: ResidualModel, idx: np.ndarray,
                 phi0: np.ndarray | None, max_nfev: int, hold: np.ndarray | None,
                 prune: bool, free_traded: bool = False) -> FitResult:
    """:func:`fit_effects` made anew."""
    full = _fit(space, rm, idx, phi0, max_nfev, hold)
    if len(space) == 0 or not prune:
        return full
    weak = np.isfinite(full.stderr) & (np.abs(full.phi - space.neutral) < 2.0 * full.stderr)
    if hold is not None:
        weak &= ~hold
    if not weak.any():
        return full
    # all the weak parameters held at once; when the BIC refuses that (they share a
    # direction the data fix, and holding them all pins it), those that can be held
    # together (:func:`pruning_set`)
    tried = np.zeros_like(weak)
    for attempt in range(2):
        if attempt:
            weak = pruning_set(full, weak, space.neutral)
            if not weak.any() or np.array_equal(weak, tried):
                break
        if free_traded:  # (the report's fit: its errors are the ones printed)
            weak = weak & ~traded_parameters(full, weak)
            if not weak.any():
                break
        tried = weak
        held = weak | ~np.isfinite(full.stderr)
        if hold is not None:
            held |= hold
        # a pruned fit pays for the parameters it saves with the chi-square its held ones
        # carried; where the full fit's curvature says that is many times what they save,
        # the BIC refuses it and it is not made (on a continuous recording with masts, the
        # pruned fits the BIC took rose by 1.0 to 1.6 times what the curvature said, at most
        # 0.6 times what they saved; the ones it refused by 0.09 to 80 times)
        saved = (full.n_free - int(np.count_nonzero(~held))) * np.log(max(full.n_eff
                                                                          or full.n_res, 2))
        if pruning_cost(full, weak) > PRUNE_HOPELESS * max(saved, 0.0):
            continue
        pruned = _fit(space, rm, idx, full.phi, max_nfev, held)
        if pruned.bic < full.bic and pruned.success:
            # the held parameters keep the uncertainty the full fit gave them; the others
            # have the pruned fit's. The full fit's would be the errors of a model that lets
            # every weak parameter trade against them (a load cell's gain against its offset
            # when its tension varies little): fifty times the spread of the values over the
            # evaluation
            pruned.stderr = np.where(weak, full.stderr, pruned.stderr)
            pruned.stderr_dof = _held_dof(weak, full, pruned)
            unfixed = unfixed_parameters(space, full.stderr) | shared_mode(full, weak)
            pruned.bias_var = pruning_bias_var(full, weak, space.neutral, weak & unfixed)
            return pruned
    return full


def _held_dof(held: np.ndarray, full: FitResult, refit: FitResult) -> np.ndarray | None:
    """The degrees of freedom of ``refit``'s errors where its ``held`` parameters keep the
    errors of ``full`` (theirs with them); ``refit``'s own where either fit has none."""
    if full.stderr_dof is None or refit.stderr_dof is None:
        return refit.stderr_dof
    return np.where(held, full.stderr_dof, refit.stderr_dof)


def shared_mode(full: FitResult, weak: np.ndarray) -> np.ndarray:
    """Of the ``weak`` parameters, those that a kept parameter of the same effect follows by
    a correlation of at least ``TRADE_CORRELATION`` in the full fit: they share a direction
    the data fix poorly (the load cells' common gain where the platform's weight is small
    against the cells' noise), and holding one at the model's value puts that direction
    where the held one is in truth. Its departure is then invisible in the full fit, so the
    kept ones keep the error they have beside it (:func:`pruning_bias_var`, as unfixed):
    IPAnema without a tracker, gain_11 0.968 held at one, put the seven other gains 3.5 %
    high at errors of a few thousandths (z 28 to 82)."""
    out = np.zeros(len(full.phi), dtype=bool)
    S = full.cov
    sd = np.sqrt(np.clip(np.diag(S), 0.0, None))
    kept = np.isfinite(full.stderr) & ~weak & (sd > 0)
    if not weak.any() or not kept.any():
        return out
    effect = np.array([p.effect for p in full.space.params])
    for h in np.flatnonzero(weak & (sd > 0)):
        k = kept & (effect == effect[h])
        if k.any() and np.any(np.abs(S[h, k]) >= TRADE_CORRELATION * sd[h] * sd[k]):
            out[h] = True
    return out


#: a pruned fit whose chi-square, linearised at the full fit (:func:`pruning_cost`), rises by
#: more than this many times the BIC's charge for the parameters it holds is not made
PRUNE_HOPELESS = 10.0


def pruning_cost(full: FitResult, weak: np.ndarray) -> float:
    """Linearised chi-square increase of holding the ``weak`` parameters at the model's
    values, the others refitted: their departures' Mahalanobis distance under the full
    fit's curvature covariance ``(J^T J)^-1`` (:attr:`FitResult.curvature_cov`; not the
    reported one, which the residuals' error model widens where the model misfits: a
    length scale whose chi-square rises by 55 000 held at one looked 14 away). Zero
    without the curvature."""
    if full.curvature_cov is None:
        return 0.0
    w = weak & np.isfinite(full.stderr)
    if not w.any():
        return 0.0
    d = (full.phi - full.space.neutral)[w]
    return quad_form(d, full.curvature_cov[np.ix_(w, w)])


def quad_form(d: np.ndarray, cov: np.ndarray) -> float:
    """``d^T cov^+ d``: a Wald statistic of the departure ``d`` under ``cov``
    (pseudo-inverse: directions the data do not fix count nothing)."""
    return float(d @ np.linalg.pinv(cov, rcond=1e-12, hermitian=True) @ d)


#: a parameter to be held at the model's value whose part a kept parameter of another
#: effect can play, the linearised chi-square rising by less than this when that one is held
#: instead, is not held (2 ln of a likelihood ratio of 20: strong evidence) ...
TRADE_TIE = 6.0
#: ... when the two are this correlated with each other in the fit that frees it beside the
#: kept ones (one stands in for the other; a gain among eight that share a common mode with
#: the mass is not one: -1.0 marginally, far less on its own)
TRADE_CORRELATION = 0.9


def traded_parameters(full: FitResult, weak: np.ndarray) -> np.ndarray:
    """Of the ``weak`` parameters (to be held at the model's values), those that a kept
    parameter of another effect stands in for: the two correlated by at least
    ``TRADE_CORRELATION`` in the fit that frees the weak one beside the kept ones (the
    full fit's curvature, linearised), and holding the kept one instead (it at the model's
    value, the weak one free) raising :func:`pruning_cost` by less than ``TRADE_TIE``.

    Which of two physics moved is then the data's to say, not the pruning's. Held, the weak
    one hands its part to the kept one, with the kept one's error conditional on the
    holding: a swivel pulley's radius 40 mm off (0.036 +/- 0.011 m against a model of 0.05
    in the full fit) held at the model's, and its cable's exit point moved 22 mm down at
    +/- 0.4 mm in its place (z -49; the full fit: -14 +/- 6 mm, correlation -0.98). The
    holding stands (the selection's BIC is the pruned fit's: freed, such a parameter
    charged every set it is in; a softer cable lost its tie with length offsets), and the
    kept one's error is widened by all the held one moved into it
    (:func:`pruning_bias_var` with the held one as unfixed)."""
    out = np.zeros(len(full.phi), dtype=bool)
    if full.curvature_cov is None or not weak.any():
        return out
    C = full.curvature_cov
    movable = np.diag(C) > 0
    kept = np.isfinite(full.stderr) & ~weak & movable
    if not kept.any():
        return out
    info = np.zeros_like(C)
    info[np.ix_(movable, movable)] = np.linalg.pinv(C[np.ix_(movable, movable)],
                                                    rcond=1e-12, hermitian=True)
    base = pruning_cost(full, weak)
    effect = [p.effect for p in full.space.params]
    ks = np.flatnonzero(kept)
    for h in np.flatnonzero(weak & movable):
        others = [i for i, k in enumerate(ks) if effect[k] != effect[h]]
        if not others:
            continue
        F = np.append(ks, h)
        cov = np.linalg.pinv(info[np.ix_(F, F)], rcond=1e-12, hermitian=True)
        sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
        for i in others:
            if abs(cov[i, -1]) < TRADE_CORRELATION * sd[i] * sd[-1]:
                continue
            swap = weak.copy()
            swap[h], swap[ks[i]] = False, True
            if pruning_cost(full, swap) - base < TRADE_TIE:
                out[h] = True
                break
    return out


def pruning_set(full: FitResult, weak: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """Of the ``weak`` parameters (each within two standard errors of ``neutral``, the
    model's value, in the full fit), those that can be held there together (when the BIC
    refused holding them all).

    Weak parameters can share a poorly known direction (a load cell's gain and offset
    where its tension varies little; the cells' common gain beside their offsets, or
    beside the mass): each one alone is within its marginal error of the model, yet
    holding one fixes the direction, and the others then sit where it puts them. They
    are tested jointly: from a first one, in order of their distance to the model (in
    standard errors), a parameter is held when, with those already held at the model's
    values, it is still within two standard errors of its own (the full fit's covariance,
    linearised: the value and error it would have in the fit holding the others). A cell
    2 % off among gains whose common mode is known to 2.5 % is kept once another cell's
    gain fixes that mode; held all at once, such a set raised the chi-square past what
    pruning saves, and nothing was pruned (every gain and offset kept: a model the BIC
    then rejects for the parameters a look-alike does without).

    Which one fixes the shared direction is the BIC's choice, not the order's: every weak
    parameter is tried as the first, and the set kept is the one whose linearised BIC
    (:func:`pruning_cost` less the BIC's charge for each parameter held) is lowest. The
    nearest one first held the one cell 2 % off among five right ones (its gain 0.9
    standard errors from one, theirs 1.9 along the common mode they share) and put the
    five 2 % off, at errors of 0.02 % (z 190): holding the five instead saves four
    parameters more for a chi-square 3 higher."""
    cand = np.flatnonzero(weak)
    if not len(cand):
        return np.zeros(len(full.phi), dtype=bool)
    d = full.phi - neutral
    order = sorted(cand, key=lambda j: abs(d[j]) / full.stderr[j])
    charge = np.log(max(full.n_eff or full.n_res, 2))
    best, best_bic = np.zeros(len(full.phi), dtype=bool), np.inf
    seen: set[tuple[int, ...]] = set()
    for first in order:
        held = _held_from(full, d, [first] + [k for k in order if k != first])
        if tuple(held) in seen:
            continue
        seen.add(tuple(held))
        mask = np.zeros(len(full.phi), dtype=bool)
        mask[held] = True
        if full.curvature_cov is not None:
            rise = pruning_cost(full, mask)
        else:  # (no curvature kept: the reported covariance's distance)
            h = np.array(held)
            rise = float(d[h] @ np.linalg.pinv(full.cov[np.ix_(h, h)], rcond=1e-12,
                                                hermitian=True) @ d[h])
        bic = rise - charge * len(held)
        if bic < best_bic:
            best, best_bic = mask, bic
    return best


def _held_from(full: FitResult, d: np.ndarray, order: list[int]) -> list[int]:
    """:func:`pruning_set`'s greedy pass: the parameters of ``order`` (departures ``d`` from
    the model's values) held in turn while each, given those already held, is within two
    standard errors of the model's value. Sorted indices."""
    S = full.cov
    held: list[int] = []
    for k in order:
        if held:
            h = np.array(held)
            b = np.linalg.lstsq(S[np.ix_(h, h)], S[h, k], rcond=1e-12)[0]
            m = d[k] - float(b @ d[h])
            v = float(S[k, k] - b @ S[h, k])
        else:
            m, v = d[k], float(S[k, k])
        if m * m < 4.0 * max(v, 1e-12 * float(S[k, k])):
            held.append(int(k))
    return sorted(held)


def unfixed_parameters(space: ParamSpace, stderr: np.ndarray) -> np.ndarray:
    """Parameters that the data cannot fix at the model's values with these standard errors:
    those the report would call undetermined there (``bench.diagnosis.report``: an exit
    point known to worse than 5 mm, a gain to 5 %, a load cell's offset to 5 N, the mass to
    5 %, ...). Holding one of them is an assumption, not a measurement."""
    return np.array([undetermined(p, float(p.neutral), float(se))
                     for p, se in zip(space.params, stderr, strict=True)], dtype=bool)


def held_error(Skh: np.ndarray, Shh: np.ndarray, d: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """How kept parameters follow held ones (``B = S_kh S_hh^-1``, from the covariance blocks
    of a fit that frees both) and the squared error holding them moves into each kept one,
    estimated without bias from their departures ``d``: ``(B d)^2 - diag(B S_hh B^T)``,
    clipped at 0."""
    B = Skh @ np.linalg.pinv(Shh, rcond=1e-12, hermitian=True)
    return B, np.clip((B @ d) ** 2 - np.einsum("ij,jk,ik->i", B, Shh, B), 0.0, None)


def pruning_bias_var(full: FitResult, weak: np.ndarray, neutral: np.ndarray,
                     unfixed: np.ndarray | None = None) -> np.ndarray:
    """Per parameter, the squared error that holding the ``weak`` parameters at ``neutral``
    moves into a kept one, estimated without bias from the full fit: ``(B d)^2 - diag(B
    S_hh B^T)``, clipped at 0, with ``d`` the held parameters' full-fit departures, ``S``
    the full fit's covariance and ``B = S_kh S_hh^-1`` how a kept parameter follows them.

    A held parameter that is in truth zero adds nothing on average (its departure is its
    noise); one the data could not tell from zero but that is not (a mass change that only
    the cables' stretch separates from the load cells' common gain) adds what it moved into
    the others, which the pruned fit's own errors cannot show.

    Where that departure cannot be told from the data at all (``unfixed``: held parameters
    the full fit leaves undetermined, :func:`unfixed_parameters`), its estimate is zero
    whatever it is: a platform 8 % heavier than the model, its mass known to 12 % without a
    tracker, moved whole into the load cells' common gain, reported to 0.05 % (z 170). There
    the squared error is at least ``diag(B_u S_uu B_u^T)`` over those parameters: the kept
    parameter's error in the full fit beside them, which holding them only assumes away."""
    out = np.zeros(len(full.phi))
    kept = np.isfinite(full.stderr) & ~weak & (np.diag(full.cov) > 0)
    if not weak.any() or not kept.any():
        return out
    S = full.cov
    Shh = S[np.ix_(weak, weak)]
    B, out[kept] = held_error(S[np.ix_(kept, weak)], Shh, (full.phi - neutral)[weak])
    if unfixed is not None and (unfixed & weak).any():
        u = unfixed[weak]
        Bu = B[:, u]
        spread = np.einsum("ij,jk,ik->i", Bu, Shh[np.ix_(u, u)], Bu)
        out[kept] = np.maximum(out[kept], spread)
    return out


def parameter_groups(fit: FitResult) -> list[np.ndarray]:
    """The free parameters of ``fit`` (away from the model's values) grouped by effect and
    by what they belong to: one cable's exit point, one load cell's gain and offset, one
    mast's stiffnesses, the mass alone. Indices into the fit's space."""
    space = fit.space
    groups: dict[tuple[str, str], list[int]] = {}
    for k, p in enumerate(space.params):
        if np.isfinite(fit.stderr[k]) and fit.phi[k] != space.neutral[k]:
            owner = p.key.rsplit("_", 1)[-1] if "_" in p.key else p.key
            groups.setdefault((p.effect, owner), []).append(k)
    return [np.array(v) for v in groups.values()]


def profile_pruning(fit: FitResult, rm: ResidualModel, idx: np.ndarray,
                    say: Callable[[str], None] | None = None,
                    free_traded: bool = False) -> FitResult:
    """``fit`` checked against the fits that hold each group of its free parameters
    (:func:`parameter_groups`) at the model's values, the others refitted: the likelihood
    ratio, where pruning (:func:`fit_effects`) judged by the curvature at the minimum.

    Where the chi-square is curved (a cable's exit point trading with its drum scale over
    few poses), the curvature can put a group tens of standard errors from the model while
    the refit holding it there rises by less than its BIC charge: an exit point 41 / 10 /
    -45 mm off at errors of 1 to 2 mm, whose refit at zero rose by 1.8 where the curvature
    said 2200. Such groups are held (those the BIC prefers held, together when that fit is
    better still; each effect keeps one group), and a group kept whose refit rose by less
    than the curvature said has its errors widened to the likelihood ratio's:
    ``|d| / sqrt(rise)`` in place of ``|d| / sqrt(predicted)``, added to ``bias_var``.
    One refit per group, warm from ``fit``, where one evaluation at the group held and the
    others moved as the curvature says (the exit point above: a rise of 26 where the
    curvature said 2300) does not already rise past both the group's BIC charge and half
    the curvature's prediction."""
    say = say or (lambda m: None)
    space = fit.space
    groups = parameter_groups(fit)
    if not groups or fit.curvature_cov is None:
        return fit
    free = np.zeros(len(space), dtype=bool)
    for g in groups:
        free[g] = True
    base_hold = ~free

    def held_fit(mask: np.ndarray) -> FitResult:
        phi0 = np.where(mask, space.neutral, fit.phi)
        return fit_effects(space, rm, idx, phi0, hold=base_hold | mask, prune=False)

    lik = StretchLikelihood(rm, idx)

    def chi2_at(phi: np.ndarray) -> float:
        r = lik.residuals(space.robot(phi))
        return float(r @ r)

    say(f"checking {len(groups)} groups of parameters by holding each")
    rises, deltas = _group_refits(fit, groups, held_fit, chi2_at)
    drop = _groups_to_hold(fit, groups, deltas, free_traded)
    out = _hold_groups(fit, groups, drop, deltas, held_fit, base_hold, say)
    return _widen_kept(fit, out, groups, drop, rises)


def _group_mask(n: int, g: np.ndarray) -> np.ndarray:
    """The mask (n,) of the parameter indices ``g``."""
    mask = np.zeros(n, dtype=bool)
    mask[g] = True
    return mask


def _group_refits(fit: FitResult, groups: list[np.ndarray],
                  held_fit: Callable[[np.ndarray], FitResult],
                  chi2_at: Callable[[np.ndarray], float]) -> tuple[list[float], np.ndarray]:
    """:func:`profile_pruning`'s refits of ``fit`` holding each of its ``groups`` at the
    model's values (``held_fit`` of the group's mask; ``chi2_at`` the chi-square of
    fit-space values): per group, the chi-square rise and the BIC change (inf where the
    refit failed, or where none was made: both inf)."""
    # one evaluation per group first: the group at the model's values, the others moved as
    # the curvature says they follow it. Where that point already rises by more than the
    # group's BIC charge and by more than half the curvature's prediction, the valley is
    # not curved there and holding the group is no better: no refit (a refit costs a
    # Jacobian of every free parameter; without tensions, 20 s for 13 groups)
    c0 = chi2_at(fit.phi)
    charge = np.log(max(fit.n_eff or fit.n_res, 2))
    rises, deltas = [], []
    for g in groups:
        mask = _group_mask(len(fit.space), g)
        predicted = pruning_cost(fit, mask)
        moved = chi2_at(_moved_along(fit, mask)) - c0
        if np.isfinite(moved) and moved > charge * len(g) and moved > 0.5 * predicted:
            rises.append(np.inf)  # no refit: neither held nor widened
            deltas.append(np.inf)
            continue
        r = held_fit(mask)
        rises.append(r.chi2 - fit.chi2)
        deltas.append(r.bic - fit.bic if r.success else np.inf)
    return rises, np.asarray(deltas)


def _moved_along(fit: FitResult, mask: np.ndarray) -> np.ndarray:
    """Fit-space values of ``fit`` with the parameters ``mask`` at the model's values and the
    others moved as its curvature covariance says they follow them, within the bounds."""
    space, C = fit.space, fit.curvature_cov
    k = (np.diag(C) > 0) & ~mask
    phi = np.where(mask, space.neutral, fit.phi)
    phi[k] -= C[np.ix_(k, mask)] @ np.linalg.pinv(C[np.ix_(mask, mask)], rcond=1e-12) \
        @ (fit.phi - space.neutral)[mask]
    return np.clip(phi, space.lo, space.hi)


def _groups_to_hold(fit: FitResult, groups: list[np.ndarray], deltas: np.ndarray,
                    free_traded: bool) -> np.ndarray:
    """:func:`profile_pruning`'s groups (mask over ``groups``) whose refit held lowered the
    BIC (``deltas``), each effect keeping its most needed group; with ``free_traded``, a
    group a kept parameter of another effect stands in for stays free (its BIC change set
    to inf in ``deltas``, in place)."""
    space = fit.space
    if free_traded:  # a group a kept parameter of another effect stands in for stays free
        for i, g in enumerate(groups):
            mask = _group_mask(len(space), g)
            if deltas[i] < 0.0 and traded_parameters(fit, mask)[g].any():
                deltas[i] = np.inf
    # each effect keeps its most needed group
    effect_of = [space.params[int(g[0])].effect for g in groups]
    drop = deltas < 0.0
    for e in set(effect_of):
        mine = [i for i, x in enumerate(effect_of) if x == e]
        if all(drop[i] for i in mine):
            drop[max(mine, key=lambda i: deltas[i])] = False
    return drop


def _hold_groups(fit: FitResult, groups: list[np.ndarray], drop: np.ndarray,
                 deltas: np.ndarray, held_fit: Callable[[np.ndarray], FitResult],
                 base_hold: np.ndarray, say: Callable[[str], None]) -> FitResult:
    """:func:`profile_pruning`'s fit with the groups ``drop`` held together (or the one
    whose refit lowered the BIC most, ``deltas``, where together they do no better than
    it), where that lowers ``fit``'s BIC; ``fit`` itself otherwise. ``drop`` is left
    marking the groups held (in place). The held parameters, and those ``base_hold``,
    keep ``fit``'s errors."""
    space = fit.space
    if not drop.any():
        return fit
    mask = np.zeros(len(space), dtype=bool)
    for i in np.flatnonzero(drop):
        mask[groups[i]] = True
    tried = held_fit(mask)
    if not (tried.success and tried.bic < fit.bic + deltas[drop].min()):
        best = int(np.flatnonzero(drop)[np.argmin(deltas[drop])])
        mask[:] = False
        mask[groups[best]] = True
        drop[:] = False
        drop[best] = True
        tried = held_fit(mask)
    if not (tried.success and tried.bic < fit.bic):
        drop[:] = False
        return fit
    names = ", ".join(space.params[int(k)].key for k in np.flatnonzero(mask))
    say(f"held at the model's values (the refits' likelihood ratio): {names}")
    tried.stderr = np.where(mask | base_hold, fit.stderr, tried.stderr)
    tried.stderr_dof = _held_dof(mask | base_hold, fit, tried)
    tried.bias_var = None if fit.bias_var is None else fit.bias_var.copy()
    return tried


def _widen_kept(fit: FitResult, out: FitResult, groups: list[np.ndarray],
                drop: np.ndarray, rises: list[float]) -> FitResult:
    """``out`` (:func:`profile_pruning`'s fit after holding the groups ``drop``) with the
    errors of each group kept and refitted no smaller than the likelihood ratio says: where
    its refit rose by less (``rises``) than ``fit``'s curvature predicted, ``bias_var``
    (fit units squared) grows by ``se^2 (predicted / rise - 1)``. A copy where ``out`` is
    ``fit``."""
    extra = np.zeros(len(fit.space))
    for i, g in enumerate(groups):
        if drop[i] or not np.isfinite(rises[i]):
            continue
        predicted = pruning_cost(fit, _group_mask(len(fit.space), g))
        if rises[i] > 0 and predicted > rises[i]:
            se = out.stderr[g]
            extra[g] = se ** 2 * (predicted / rises[i] - 1.0)
    if extra.any():
        if out is fit:
            out = fit.copy()
        out.bias_var = extra if out.bias_var is None else out.bias_var + extra
    return out


def _fit(space: ParamSpace, rm: ResidualModel, idx: np.ndarray, phi0: np.ndarray | None,
         max_nfev: int, hold: np.ndarray | None) -> FitResult:
    """One least-squares fit of ``space``'s parameters to the samples ``idx`` of ``rm``
    (whitened residuals, dimensionless), from the fit-space values ``phi0`` (the model's
    where None), at most ``max_nfev`` evaluations a run; ``hold`` marks the parameters kept
    at the model's values (where None, those the data cannot fix at the start:
    :func:`null_parameters`). No pruning (:func:`_fit_effects`)."""
    # the residuals, with the likelihood's Jacobian term where tensions move with the
    # length errors (estimated poses: bench.diagnosis.likelihood) as one entry more
    lik = StretchLikelihood(rm, idx)

    def fun(phi: np.ndarray) -> np.ndarray:
        return lik.residuals(space.robot(phi))

    x0 = space.neutral.copy() if phi0 is None else np.clip(phi0, space.lo, space.hi)
    steps = space.scale * 1e-2
    lost = rm.dof_lost(idx)
    n_eff = float(rm.entry_weights(idx).sum())
    if len(space) == 0:
        r = fun(x0)
        chi2 = float(r @ r) - lik.K
        return FitResult(space, x0, chi2, len(r) - lik.n_extra, bic(chi2, 0, n_eff), np.zeros(0),
                         np.zeros((0, 0)), True, "no parameters", 1, lost, 0, n_eff)
    # parameters the data cannot fix at all (seen at the start, before the fit can wander
    # along them) stay at the model's values; compliance-like ones are held first
    if hold is None:
        J0 = fd_jacobian(fun, x0, fun(x0), steps, space.lo, space.hi, rm.frozen)
        fixed = null_parameters(J0, space)
    else:
        fixed = hold.copy()
    free = ~fixed
    x = np.where(fixed, space.neutral, x0)
    # start inside the bounds: the trust region of 'trf' cannot leave a bound it starts on
    x = np.where(free, np.clip(x, space.lo + 0.1 * space.scale, space.hi - 0.1 * space.scale), x)
    if free.any():
        prob = _FreeResiduals(fun, x, free, steps[free], space.lo[free], space.hi[free],
                              rm.frozen)
        z, r, Jf, nfev, ok, msg = _minimise(prob, x[free], space.scale[free], max_nfev)
        x[free] = z
    else:
        r, Jf, nfev, ok, msg = fun(x), np.zeros((0, 0)), 1, True, "nothing to fit"
    chi2 = float(r @ r) - lik.K
    if lik.n_extra:  # the errors' model holds the residuals proper
        r = r[:-lik.n_extra]
        Jf = Jf[:-lik.n_extra] if len(Jf) else Jf
    se_all, cov_all, dof_all, curv = _fit_errors(space, rm, idx, x, free, r, Jf, lost, n_eff)
    return FitResult(space, x, chi2, len(r), bic(chi2, int(free.sum()), n_eff), se_all,
                     cov_all, ok, msg, nfev, lost, int(free.sum()), n_eff, None, curv, dof_all)


class _FreeResiduals:
    """The residuals ``fun`` of fit-space values as a function of the ``free`` ones (the
    others as in ``x``, read when called), keeping the last evaluation outside the
    Jacobian's columns; their finite-difference Jacobian (``steps``, within ``lo``, ``hi``,
    fit units of the free parameters; ``frozen`` the residual model's context for the
    columns, :func:`fd_jacobian`)."""

    def __init__(self, fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                 free: np.ndarray, steps: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 frozen: Callable[[], AbstractContextManager] | None) -> None:
        self.fun, self.x, self.free = fun, x, free
        self.steps, self.lo, self.hi, self.frozen = steps, lo, hi, frozen
        self.last: dict[str, np.ndarray] = {}

    def at(self, z: np.ndarray) -> np.ndarray:
        """The residuals at the free values ``z``."""
        full = self.x.copy()
        full[self.free] = z
        return self.fun(full)

    def evaluate(self, z: np.ndarray) -> np.ndarray:
        """:meth:`at`, kept as the last evaluation (what ``least_squares`` evaluates)."""
        self.last["z"], self.last["r"] = z.copy(), self.at(z)
        return self.last["r"]

    def f_at(self, z: np.ndarray) -> np.ndarray:
        """The residuals at ``z``, the last evaluation's where it was there."""
        # least_squares asks for the Jacobian where it last evaluated the residuals
        if "z" in self.last and np.array_equal(self.last["z"], z):
            return self.last["r"]
        return self.evaluate(z)

    def jac(self, z: np.ndarray, *_: object) -> np.ndarray:
        """The finite-difference Jacobian at ``z`` (rows: residuals; columns: free values)."""
        return fd_jacobian(self.at, z, self.f_at(z), self.steps, self.lo, self.hi,
                           self.frozen)


def _minimise(prob: _FreeResiduals, z: np.ndarray, sc: np.ndarray, max_nfev: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool, str]:
    """The minimum of ``prob``'s residuals from the free values ``z`` (scales ``sc``, fit
    units): a secant path first for many parameters (module docstring), checked with finite
    differences, then bounded 'trf' runs (at most ``RETRIES`` more, while they lower the
    cost). The free values, the residuals and Jacobian there, the evaluations, whether it
    converged and the message."""
    lo, hi = prob.lo, prob.hi
    nfev, first = 0, None
    r0 = prob.evaluate(z)
    cost = 0.5 * float(r0 @ r0)
    if len(z) >= SECANT_MIN:
        # the path to the minimum with secant Jacobians (module docstring), then the
        # minimum checked (and the fit finished) with finite differences
        res = least_squares(prob.evaluate, z, bounds=(lo, hi),
                            jac=_SecantJacobian(prob.jac, prob.f_at, sc), x_scale=sc,
                            method="trf", max_nfev=2 * max_nfev,
                            xtol=FIT_TOL, ftol=FIT_TOL, gtol=1e-8)
        z = res.x
        nfev += int(res.nfev)
        cost = min(cost, float(res.cost))
        rz = prob.f_at(z)
        Jz = prob.jac(z)
        if _settled(Jz, rz, z, lo, hi, sc):
            return z, rz, Jz, nfev, True, "converged (secant path, checked)"
        first = _First(Jz, z, prob.jac)
    z, r, Jf, n, ok, msg = _trf_runs(prob, z, sc, max_nfev, cost, first)
    nfev += n
    if not ok:
        msg = f"did not converge in {nfev} evaluations: {msg}"
    return z, r, Jf, nfev, ok, msg


def _trf_runs(prob: _FreeResiduals, z: np.ndarray, sc: np.ndarray, max_nfev: int,
              cost: float, first: _First | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool, str]:
    """:func:`_minimise`'s bounded 'trf' runs from ``z`` (``cost`` half the chi-square
    there; the first run's Jacobian ``first`` where given, else finite differences): again
    from where one stopped while it spent its budget lowering the cost, at most
    ``RETRIES`` more. The free values, the residuals and Jacobian there, the evaluations,
    whether the last run converged and its message."""
    nfev = 0
    for _attempt in range(RETRIES + 1):
        res = least_squares(prob.evaluate, z, bounds=(prob.lo, prob.hi),
                            jac=first if first is not None else prob.jac,
                            x_scale=sc, method="trf", max_nfev=max_nfev,
                            xtol=FIT_TOL, ftol=FIT_TOL, gtol=1e-8)
        first = None
        z = res.x
        nfev += int(res.nfev)
        # status 0: the evaluation budget ran out before a convergence test passed
        ok = bool(res.status > 0)
        msg = str(res.message)
        if ok:
            break
        if not cost - float(res.cost) > 1e-6 * cost:
            break  # the budget went without progress: another one would go the same
        cost = float(res.cost)
    return z, res.fun, res.jac, nfev, ok, msg


def _fit_errors(space: ParamSpace, rm: ResidualModel, idx: np.ndarray, x: np.ndarray,
                free: np.ndarray, r: np.ndarray, Jf: np.ndarray, lost: float, n_eff: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_fit`'s errors at the fit-space values ``x`` from the whitened residuals ``r``
    and their Jacobian ``Jf`` in the ``free`` parameters (``lost`` degrees of freedom of
    ``n_eff``): standard errors (inf where held), covariance (zero where held), the
    standard errors' degrees of freedom (inf where held or where the error model gives
    none) and the curvature covariance (:func:`curvature`), all fit units over every
    parameter."""
    if free.any():
        errors = error_structure(rm, idx, lost, space.robot(x))
        nu: list[np.ndarray] = []
        cov, se = standard_errors(Jf, float(r @ r), n_eff - lost, space.scale[free], r,
                                  errors.stretches, errors, nu)
    else:
        cov, se, nu = np.zeros((0, 0)), np.zeros(0), []
    dof_all = np.full(len(x), np.inf)
    if nu:
        dof_all[free] = nu[0]
    se_all = np.full(len(x), np.inf)
    se_all[free] = se
    cov_all = np.zeros((len(x), len(x)))
    cov_all[np.ix_(free, free)] = cov
    curv = np.zeros((len(x), len(x)))
    if free.any() and np.isfinite(Jf).all():
        curv[np.ix_(free, free)] = curvature(Jf, space.scale[free])
    return se_all, cov_all, dof_all, curv


def curvature(J: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The curvature (Gauss-Newton) covariance ``(J^T J)^+`` of whitened residuals' Jacobian
    ``J`` (rows, parameters), computed on the columns scaled by ``scale`` (the parameters'
    units) and returned in the parameters' units."""
    Js = J * scale
    return np.linalg.pinv(Js.T @ Js, rcond=1e-12, hermitian=True) * np.outer(scale, scale)


class _SecantJacobian:
    """Jacobians for ``least_squares`` at its accepted points (``residuals`` there):
    finite differences (``exact``) at the first, then Broyden's update along each step (in
    the parameters' ``scale``), until a step falls short of what its Jacobian predicted
    (:data:`SECANT_RATIO`) or :data:`SECANT_STEPS` updates were made; then finite
    differences again."""

    def __init__(self, exact: Callable[[np.ndarray], np.ndarray],
                 residuals: Callable[[np.ndarray], np.ndarray], scale: np.ndarray) -> None:
        self.exact, self.residuals = exact, residuals
        self.scale = np.asarray(scale, dtype=float)
        self.J: np.ndarray | None = None
        self.z = self.f = None
        self.updates = 0

    def __call__(self, z: np.ndarray, *_: object) -> np.ndarray:
        f = self.residuals(z)
        if self.J is not None and self.updates < SECANT_STEPS:
            dz = z - self.z
            pred = self.f + self.J @ dz
            old = float(self.f @ self.f)
            drop_pred = old - float(pred @ pred)
            drop = old - float(f @ f)
            dzs = dz / self.scale
            nz = float(dzs @ dzs)
            if drop_pred > 0 and drop >= SECANT_RATIO * drop_pred and nz > 0:
                self.J = self.J + np.outer(f - pred, dzs / self.scale / nz)
                self.z, self.f = z.copy(), f.copy()
                self.updates += 1
                return self.J
        self.J = self.exact(z)
        self.z, self.f = z.copy(), f.copy()
        self.updates = 0
        return self.J


class _First:
    """A Jacobian function that answers ``J`` (computed at ``z``) when first asked there."""

    def __init__(self, J: np.ndarray, z: np.ndarray,
                 exact: Callable[[np.ndarray], np.ndarray]) -> None:
        self.J, self.z, self.exact = J, z.copy(), exact

    def __call__(self, z: np.ndarray, *_: object) -> np.ndarray:
        if self.J is not None and np.array_equal(z, self.z):
            J, self.J = self.J, None
            return J
        self.J = None
        return self.exact(z)


def _settled(J: np.ndarray, r: np.ndarray, z: np.ndarray, lo: np.ndarray, hi: np.ndarray,
             scale: np.ndarray) -> bool:
    """Whether the Gauss-Newton step of the whitened residuals ``r`` (finite-difference
    Jacobian ``J``) within the bounds predicts a chi-square drop below :data:`SETTLED` (or
    :data:`FIT_TOL` of the chi-square)."""
    from scipy.optimize import lsq_linear

    if not (np.isfinite(J).all() and np.isfinite(r).all()):
        return False
    Js = J * scale
    norm = np.linalg.norm(Js, axis=0)
    norm[norm == 0] = 1.0
    A = Js / norm
    d = lsq_linear(A, -r, bounds=((lo - z) / scale * norm, (hi - z) / scale * norm),
                   method="bvls" if J.shape[1] < 60 else "trf", lsmr_tol="auto").x
    chi2 = float(r @ r)
    r1 = r + A @ d
    return chi2 - float(r1 @ r1) < max(SETTLED, FIT_TOL * chi2)


#: a parameter whose Jacobian column is within this fraction of the span of the columns
#: before it adds no information
NULL_RATIO = 1e-4
#: ... and one whose norm in the parameters' scales is within this fraction of the largest
#: column's is rounding noise (the square root of standard_errors' eigenvalue cut)
NULL_SCALED = 1e-6


def null_parameters(J: np.ndarray, space: ParamSpace) -> np.ndarray:
    """Parameters to hold at the model's values because the data cannot tell them from the
    others (their Jacobian column lies in the span of the columns before them).

    Columns are taken simplest explanation first: constant offsets, scales and values
    before compliance-like (inverse) parameters, so that a mast seen at a single pose keeps
    exit-point offsets and leaves its compliance undetermined.
    """
    order = sorted(range(J.shape[1]), key=lambda k: space.params[k].kind == "inverse")
    fixed = np.ones(J.shape[1], dtype=bool)
    basis: list[np.ndarray] = []
    # a column that in the parameters' scales is a vanishing share of the largest is the
    # rounding of a finite difference, not a direction (standard_errors' cut, 1e-12 of the
    # largest eigenvalue of J^T J): the Gram-Schmidt test alone, blind to scale, takes such
    # noise for a new direction and lets the fit wander along it
    with np.errstate(invalid="ignore", over="ignore"):
        scaled = np.linalg.norm(J, axis=0) * np.abs(space.scale)
    ok = np.isfinite(scaled)
    top = float(scaled[ok].max(initial=0.0))
    for k in order:
        c = J[:, k].astype(float)
        norm = float(np.linalg.norm(c))
        if norm == 0.0 or not np.isfinite(norm) or scaled[k] <= NULL_SCALED * top:
            continue
        v = c / norm
        for b in basis:  # modified Gram-Schmidt, twice for stability
            v = v - (b @ v) * b
        for b in basis:
            v = v - (b @ v) * b
        left = float(np.linalg.norm(v))
        if left > NULL_RATIO:
            basis.append(v / left)
            fixed[k] = False
    return fixed


#: a parameter whose unit vector has more than this share of its squared length in
#: directions without information (eigenvalues of J^T J below 1e-12 of the largest) is
#: undetermined: exact look-alikes share such a direction by a share of order one,
#: rounding gives a well-determined parameter one of order 1e-30
NULL_LOADING = 1e-6


def standard_errors(J: np.ndarray, chi2: float, n_res: float,
                    scale: np.ndarray | None = None, r: np.ndarray | None = None,
                    groups: np.ndarray | None = None,
                    errors: ErrorStructure | None = None,
                    dof: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Covariance and standard errors from the whitened Jacobian ``J`` (computed in parameter
    units of ``scale``) at the whitened residuals ``r``; ``n_res`` the residuals' degrees of
    freedom before the fit's own parameters.

    With the ``errors`` structure of the entries (:class:`ErrorStructure`), the covariance
    is the sandwich ``A^-1 J^T C J A^-1`` (``A = J^T J``), the residuals' covariance ``C``
    estimated from ``r`` itself (:func:`error_meat`): each kind of quantity its own level,
    and its correlation within a move and within a stretch of time. This holds parameter
    by parameter: an error shared by a move's rows inflates a length offset, which those
    rows see together, and leaves a load-cell gain fitted through the tension noise,
    independent from row to row, as sure as that noise makes it. Without ``errors``, the
    covariance is ``A^-1`` inflated by the reduced chi-square when above 1.

    With the entries' ``groups`` (stretches that may share errors), each standard error is
    at least the cluster-robust (sandwich) one when there are groups enough: residuals
    that depart from the model of their errors in places do not make the fit look surer
    than it is.

    With a list ``dof``, the standard errors' degrees of freedom (:func:`effective_dof`, with
    ``errors``) are appended to it."""
    p = J.shape[1]
    if p == 0:
        return np.zeros((0, 0)), np.zeros(0)
    D = np.ones(p) if scale is None else np.asarray(scale, dtype=float)
    Js = J * D
    JtJ = Js.T @ Js
    w, V = np.linalg.eigh(JtJ)
    top = max(float(w.max()), 1e-300)
    weak = w < 1e-12 * top
    inv_w = np.where(weak, 0.0, 1.0 / np.where(weak, 1.0, w))
    cov_s = (V * inv_w) @ V.T
    widen_dof = False  # (the dof of this call's sandwich in dof[-1])
    if r is not None and errors is not None and len(errors.weights) == len(r):
        parts: list[tuple[np.ndarray, float]] | None = [] if dof is not None else None
        share = errors.n_eff / max(n_res, 1.0)
        cov = cov_s @ error_meat(Js, r, errors, parts) @ cov_s * share * np.outer(D, D)
        if dof is not None and parts is not None:
            dof.append(effective_dof(cov_s, parts))
            widen_dof = True
    else:
        red = chi2 / max(n_res - p, 1)
        cov = cov_s * np.outer(D, D) * max(red, 1.0)
    if r is not None and groups is not None and len(groups) == len(r):
        ug, inv = np.unique(groups, return_inverse=True)
        G = len(ug)
        if G > 2 * p:
            sc = np.zeros((G, p))
            np.add.at(sc, inv, Js * r[:, None])
            meat = sc.T @ sc * G / (G - 1)
            cov_r = cov_s @ meat @ cov_s * np.outer(D, D)
            d = np.sqrt(np.clip(np.diag(cov_r) / np.maximum(np.diag(cov), 1e-300), 1.0, None))
            cov = cov * np.outer(d, d)
            if widen_dof:  # (a variance widened to the groups' own: their G - 1 dof)
                dof[-1] = np.where(d > 1.0, np.minimum(dof[-1], G - 1.0), dof[-1])
    # directions without information are left out of the covariance, whose inverse they
    # would make infinite; a parameter that moves along one (its finite-difference column
    # only rounding noise, or a combination of parameters the residuals do not see at
    # all) is not fixed by the data: its error is infinite, not the zero the truncated
    # inverse gives it (a mast stiffness reported to 1e-15 of itself, 40 times off)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    if weak.any():
        se[np.sum(V[:, weak] ** 2, axis=1) > NULL_LOADING] = np.inf
    return cov, se


#: [m] scale of a cable's length error by direction in :func:`direction_bias_var`
DIRECTION_SCALE_M = 1e-4


def direction_bias_var(J: np.ndarray, r: np.ndarray, cols: tuple[np.ndarray, np.ndarray],
                       n_res: float, scale: np.ndarray, errors: ErrorStructure,
                       dof: list[float] | None = None) -> np.ndarray:
    """Per free parameter, the variance that each cable's length error by its direction of
    approach (hysteresis, backlash; ``cols`` its whitened columns by direction and after the
    initialisation, :meth:`ResidualModel.direction_columns`) adds where per-sample unknowns
    project the lengths:

    - held at zero by the fit, what it moves into the parameters: :func:`pruning_bias_var`'s
      estimate with the errors freed beside the parameters as the full fit
      (``(B d)^2 - diag(B S_hh B^T)``, clipped at 0; covariances by :func:`standard_errors`
      with the ``errors`` structure);
    - at the initialisation, where the encoders are referenced, each cable's error is
      ``+-a`` (its last move before is unknown) and stays in every later sample: the
      parameters follow it as the fit's linear response to those columns says.

    Projected by an estimated pose, a cable's error spreads over every cable's residual,
    where the error model's direction component reads nothing, and the initialisation's
    sign reads as a length offset common to every block of the recording, beyond its
    standard error and out of reach of a jackknife (an IPAnema-class continuous recording
    without a tracker, hysteresis 0.13 mm: offsets 0.15 mm off at z 4 to 6, the same with the
    true offset 0.1, 5 or 10 mm; z about 1 with the hysteresis, but none at the reference).
    The level ``a^2`` is one for every cable: the mean over the cables of their unbiased
    estimates (at least 0). With a list ``dof``, the degrees of freedom of the result (the
    number of cables behind the level) are appended to it."""
    p = J.shape[1]
    X, later = cols
    use = np.linalg.norm(X, axis=0) > 0
    if p == 0 or not use.any():
        return np.zeros(p)
    X, later = X[:, use], later[:, use]
    if dof is not None:
        dof.append(float(X.shape[1]))
    Ja = np.hstack([J, X])
    sc = np.concatenate([np.asarray(scale, dtype=float), np.full(X.shape[1], DIRECTION_SCALE_M)])
    S, _ = standard_errors(Ja, float(r @ r), n_res, sc, r, None, errors)
    d = np.linalg.lstsq(Ja * sc, r, rcond=None)[0][p:] * sc[p:]
    Shh = S[p:, p:]
    _, held = held_error(S[:p, p:], Shh, d)
    # the fit's response to the initialisation's error of each cable (per metre)
    Js = J * sc[:p]
    G = -(np.linalg.pinv(Js.T @ Js, rcond=1e-12, hermitian=True) @ (Js.T @ later)) \
        * sc[:p, None]
    # one level for every cable (a cable's own estimate, a few visits of each direction, is
    # noisier than the level it estimates)
    a2 = max(float(np.mean(d ** 2 - np.diag(Shh))), 0.0)
    out = held + a2 * np.sum(G ** 2, axis=1)
    return np.where(np.isfinite(out), out, 0.0)


@dataclass
class ErrorStructure:
    """What the entries of a whitened residual vector may share, entry by entry:
    ``weights`` the sample weights whose square roots the whitening multiplied in,
    ``kinds`` the kind of entry (a quantity by sample kind: each its own error level),
    ``columns`` the quantity (a cable's length, a force axis), ``moves`` the move (rows of a
    move) or target (dwells) of the sample, ``stretches`` the stretch of time it lies in
    (moves nest in it); ``n_eff`` the effective number of residuals (weights summed: the
    degrees of freedom before per-sample unknowns and the fit's parameters)."""

    weights: np.ndarray
    kinds: np.ndarray
    columns: np.ndarray
    moves: np.ndarray
    stretches: np.ndarray
    n_eff: float
    #: the sign of the last move of each length entry's cable (+1, -1; 0 for other entries
    #: or unknown): an error by the direction of approach (hysteresis) pairs by it
    directions: np.ndarray | None = None
    #: (entries, stops x quantities) the visit-to-visit error of the lengths where moves blend
    #: it between stops (:meth:`ResidualModel.entry_knots`): a known covariance ``K K^T`` of
    #: the unweighted whitened residuals, which the other components are estimated beside
    knots: np.ndarray | None = None
    #: share of the residuals' degrees of freedom per-sample unknowns leave (their moments
    #: are that share of the errors'; the caller scales the meat back by its inverse)
    kept: float = 1.0
    #: degrees of freedom of the level behind ``knots`` (``ResidualModel.visit_dof``)
    knots_dof: float = math.inf
    #: per entry, the share of its error's variance per-sample unknowns leave in it
    #: (:meth:`ResidualModel.entry_kept`: ``r / n`` of an estimated pose's length entries, 1
    #: for its wrench entries, 0 for the initialisation's length entries); None: ``kept``
    #: for every entry
    entry_kept: np.ndarray | None = None
    #: the share the per-sample unknowns leave over the samples after the initialisation
    #: (whose length entries, the encoders' reference, lose everything): what a kind they do
    #: not project stands in with (:meth:`kind_shares`); None: ``kept``
    unknowns_kept: float | None = None

    def projects(self, mask: np.ndarray) -> bool:
        """Whether per-sample unknowns project the kind ``mask``: :attr:`entry_kept`'s
        weighted mean over it below 1."""
        if self.entry_kept is None or len(self.entry_kept) != len(self.weights):
            return False
        w = np.clip(self.weights[mask], 1e-12, None)
        return float(w @ self.entry_kept[mask] / w.sum()) < 1.0

    def kind_share(self, mask: np.ndarray) -> KindShare:
        """What per-sample unknowns leave of the kind ``mask`` (:class:`KindShare`: its
        :meth:`kind_shares`, :meth:`kind_kept` and :meth:`kind_stand_in`), whether they
        project it (:meth:`projects`) asked once."""
        if not self.projects(mask):
            stand = self.stand_in()
            return KindShare(np.ones(int(np.sum(mask))), stand, stand)
        shares = self.entry_kept[mask]
        w = np.clip(self.weights[mask], 1e-12, None)
        k = float(np.clip(w @ shares / w.sum(), 0.0, 1.0))
        return KindShare(shares, k if k >= MIN_KEPT_LEVEL else self.stand_in(), 1.0)

    def kind_shares(self, mask: np.ndarray) -> np.ndarray:
        """Per entry of the kind ``mask``, the share of its error's variance per-sample
        unknowns leave in its residual (the diagonal of their projection, as
        :func:`_unbiased_components` takes it): :attr:`entry_kept` where they project the
        kind (one with almost none left, the initialisation's dwell alone, tells no level:
        :func:`error_meat`), 1 on every entry of a kind they do not project (whose level
        :meth:`kind_stand_in` scales)."""
        return self.kind_share(mask).shares

    def kind_stand_in(self, mask: np.ndarray) -> float:
        """The share a kind the per-sample unknowns do not project stands in with (1 for one
        they project): at an estimated pose, the force and moment residuals also carry each
        visit's length errors through the pose, which :meth:`ResidualModel.entry_knots`
        models on rows of moves only; on dwells the recording's share (:meth:`stand_in`)
        stands for it (with 1, a CoGiRo-class dwell campaign without a tracker kept three
        load-cell offsets of zero at z 3 and read a heavier platform as every cell's gain 7 %
        high).

        It scales the kind's level after the fit's correction, ``rss / ((n - f) s)`` over
        ``n`` entries of which the fit's parameters take ``f``; it is no projection of the
        entries (their columns are not in its range), so it does not enter the expectation
        as one: ``rss / (s n - f)`` has a pole where the fit takes ``s n`` of a kind of few
        entries (a ROCASPECT-class continuous campaign without a tracker, 12939: 21 force
        entries at the dwells, ``s`` 0.57, ``f`` 6.7: their level 1.5 times, the cells'
        standard errors with it, and a false cable elasticity named)."""
        return self.kind_share(mask).stand_in

    def stand_in(self) -> float:
        """The recording's share for a kind the per-sample unknowns do not project: the one
        they leave over the samples after the initialisation (:attr:`unknowns_kept`; the
        initialisation's reference, counted in ``kept``, is no unknown of the samples: with
        it, a CoGiRo-class campaign with load cells and a tracker, where nothing projects
        the force entries, read its cells' errors 0.9 % large and named nothing, 13302 of
        test_unneeded43)."""
        return self.kept if self.unknowns_kept is None else self.unknowns_kept

    def kind_kept(self, mask: np.ndarray) -> float:
        """The share per-sample unknowns leave of the errors of the entries ``mask`` (one kind
        of entry; weighted like the entries; :meth:`kind_shares`). A kind left with under
        :data:`MIN_KEPT_LEVEL` of them (the initialisation's dwell alone: its readings are
        the encoders' reference) keeps the recording's share: its moments tell no level, it
        takes its quantity's (:func:`error_meat`). A kind they do not project keeps its
        :meth:`kind_stand_in`."""
        return self.kind_share(mask).kept


@dataclass(frozen=True)
class KindShare:
    """What per-sample unknowns leave of one kind of entry (:meth:`ErrorStructure.kind_share`).
    """

    #: per entry, the share of its error's variance left (:meth:`ErrorStructure.kind_shares`)
    shares: np.ndarray
    #: the kind's share, weighted like its entries (:meth:`ErrorStructure.kind_kept`)
    kept: float
    #: the share its level is scaled by after the fit's correction
    #: (:meth:`ErrorStructure.kind_stand_in`; 1 for a kind they project)
    stand_in: float


#: pseudo-entries of a kind's error level at its quantity's level over every kind
PRIOR_ENTRIES = 30
#: share of a component's moment statistic the fit must leave in its residuals for the
#: component to be estimated from them (an error level; a covariance shared by samples)
MIN_KEPT_LEVEL = 0.1
#: the same for a shared component (a hard floor: :func:`_unbiased_components` solves for
#: those at or above it, keeps the plain moment below). Known to bite on both sides: 12954
#: (IPAnema dwell, 8 cables) leaves 0.497 of its cables' error over the recording (solved
#: 0.05 of the level, plain 0.002: four false length offsets); test_unneeded43's campaign
#: (13302, CoGiRo dwell, cells' friction unmodelled) loses its named cell calibration where
#: the lengths' same component is solved from 0.30 of it (a floor of 0.35 keeps it, 0.30
#: does not) or the cells' from 0.08. By its standard error from the moment system 13302's
#: lengths' component is the better told (independent errors: 0.4-0.65 v at se 0.05-0.08 v,
#: against 12954's 0.05 v at 0.02 v); as chi-squares over the 8 cables both are poorly told
#: (0.9 and 0.7 of themselves): no rule from these statistics found so far (floor47) keeps
#: 13302's answer and mends 12954's.
MIN_KEPT_SHARED = 0.5
#: components of each kind's errors: a level, three shared ones nested in time, one by the
#: direction of approach
NCOMP = 5


def error_structure(rm, idx: np.ndarray, lost: float | None = None,
                    H=None) -> ErrorStructure:
    """The :class:`ErrorStructure` of the entries of ``rm``'s (a ResidualModel) whitened
    residuals on the samples ``idx``: ``n_eff`` their weights summed; ``lost`` the degrees of
    freedom per-sample unknowns take (``kept`` their complement's share; None: 1). With the
    hypothesis ``H`` (a Robot), the stops' length errors are followed into the force and
    moment entries where poses are estimated (:meth:`ResidualModel.entry_knots`)."""
    w = rm.entry_weights(idx)
    n_eff = float(w.sum())
    kept = 1.0 if lost is None else (n_eff - lost) / max(n_eff, 1e-12)
    own = None
    if lost is not None:  # (the recording's share over the samples after the initialisation)
        later = np.arange(rm.s.n) if idx is None else np.arange(rm.s.n)[idx]
        later = later[~rm.s.is_init[later]]
        w_later = float(rm.entry_weights(later).sum())
        own = (w_later - rm.dof_lost(later)) / w_later if w_later > 0 else kept
    return ErrorStructure(w, rm.entry_kinds(idx), rm.entry_columns(idx), rm.entry_moves(idx),
                          rm.entry_blocks(idx), n_eff, rm.entry_directions(idx),
                          rm.entry_knots(idx, H), kept, float(getattr(rm, "visit_dof", math.inf)),
                          None if lost is None else rm.entry_kept(idx), own)


def error_meat(Js: np.ndarray, r: np.ndarray, e: ErrorStructure,
               parts: list[tuple[np.ndarray, float]] | None = None) -> np.ndarray:
    """``J^T C J`` for the whitened residuals ``r`` (Jacobian ``Js``), with ``C`` from a
    variance-components model of the unweighted whitened residuals ``u = r / sqrt(weight)``.

    Per kind of entry: a variance ``v``; a covariance ``c1`` between two samples of one
    quantity in one move (or at one target) within a stretch; ``c2`` between two in one
    stretch but different moves; ``c3`` between two in different stretches (an error a
    quantity keeps over the whole recording: hysteresis by the direction of approach,
    averaged over the moves, a drift). Each is a moment estimate over every such pair of the
    recording (averages of cross-products; covariances clipped to ``[0, v]``), steady where
    a cluster-robust sandwich over a handful of stretches would not be. The variance leans
    on its quantity's over every kind by ``PRIOR_ENTRIES`` pseudo-entries (a kind of a
    handful of entries says little).

    No error of the encoder reference is added: the initialisation defines it (a winding's
    visit-to-visit change is a change from there).

    Where the recording stops between moves, the lengths' visit-to-visit error is known
    from the replicate dwells and blends along each move between the errors of its two
    stops (``e.knots``, :meth:`ResidualModel.entry_knots`): no grouping by move, target or
    stretch holds it (a move's rows share two stops' errors in proportions that change
    along it, and with the dwells at its ends, another kind). It enters whole, ``kept K K^T``
    in these units, and the components are estimated from what the residuals hold beside
    it (standard errors a third to a half too small without it, on IPAnema-class
    recordings with dwells, against the spread over replicate recordings).

    Entry ``i`` of ``r`` is ``sqrt(w_i) u_i``: a pair adds ``sqrt(w_i w_j) cov(u_i, u_j) J_i
    J_j^T`` (rows a move weighs down but whose errors are independent count as such).

    With a list ``parts``, each term of the sum is appended to it with the degrees of freedom
    of its level (:func:`component_dof`; the knots' from ``e.knots_dof``)."""
    p = Js.shape[1]
    sw = np.sqrt(np.clip(e.weights, 1e-12, None))
    b = Js * sw[:, None]
    ncol = int(e.columns.max()) + 1 if len(e.columns) else 1
    nmove = int(e.moves.max()) + 1 if len(e.moves) else 1
    kinds = [_KindGroups(e.kinds == k, e, ncol, nmove) for k in np.unique(e.kinds)]
    knots = e.knots if e.knots is not None and len(e.knots) == len(r) and e.knots.any() \
        else None
    share = [e.kind_share(kg.mask) for kg in kinds]
    theta = _kind_components(Js, sw, r / sw, kinds, knots, share, e.kept)
    meat = np.zeros((p, p)) if knots is None else _knots_meat(knots, b, e, parts)
    level = _pooled_levels(kinds, e, theta[:, 0], [s.shares for s in share])
    for j, kg in enumerate(kinds):
        v = level[j]
        c = np.clip(theta[j, 1:], 0.0, v)
        grams = kg.grams(b[kg.mask])
        meat += v * grams[0] + sum(ci * g for ci, g in zip(c, grams[1:], strict=True))
        if parts is not None:
            parts += _nested_parts(v, c, grams,
                                   component_dof(kg, e, p, len(r), share[j].kept))
    return meat


def _kind_components(Js: np.ndarray, sw: np.ndarray, u: np.ndarray, kinds: list[_KindGroups],
                     knots: np.ndarray | None, share: list[KindShare], kept: float
                     ) -> np.ndarray:
    """(kinds, :data:`NCOMP`) the components of :func:`error_meat` of the unweighted whitened
    residuals ``u`` (``sw`` the weights' square roots, ``Js`` the whitened Jacobian), in the
    units the caller's ``1 / kept`` scales back.

    Each kind's residuals keep the share of its entries' errors that per-sample unknowns
    leave (``share``: an estimated pose r / n of a length entry's; none of the
    initialisation's: :meth:`ErrorStructure.kind_shares`), the fit's parameters take theirs
    from what is left: both projections are in the expectations (:func:`_unbiased_components`:
    a level rss / (N - lost - p), where a share applied after the parameters' correction gave
    rss N / ((N - p)(N - lost)), 0.95 of it on an IPAnema-class dwell without load cells); a
    kind they do not project, its stand-in share after the fit's correction
    (:meth:`ErrorStructure.kind_stand_in`); ``kept`` undoes the caller's ``1 / kept``."""
    stats = np.array([kg.statistics(u) for kg in kinds]).ravel()
    theta = _unbiased_components(Js, sw, kinds, stats, knots, [s.shares for s in share])
    stand = np.array([s.stand_in for s in share])
    return theta.reshape(len(kinds), NCOMP) * (kept / stand)[:, None]


def _knots_meat(knots: np.ndarray, b: np.ndarray, e: ErrorStructure,
                parts: list[tuple[np.ndarray, float]] | None) -> np.ndarray:
    """The term of :func:`error_meat` of the blended visit-to-visit error ``K K^T``
    (``knots``; ``b`` the Jacobian's rows by the weights' square roots): known from the
    replicate dwells, in the readings' units (the caller's scaling by ``1 / kept`` undone:
    the score sees it whole). Appended to ``parts`` with its level's degrees of freedom
    (``e.knots_dof``)."""
    kb = knots.T @ b
    term = e.kept * (kb.T @ kb)
    if parts is not None:
        parts.append((term, e.knots_dof))
    return term.copy()


def _pooled_levels(kinds: list[_KindGroups], e: ErrorStructure, level: np.ndarray,
                   shares: list[np.ndarray]) -> np.ndarray:
    """Each kind's error level leaning on its quantity's over every kind by
    :data:`PRIOR_ENTRIES` pseudo-entries (a kind of few entries, the initialisation's dwell in
    a continuous recording, says little). A kind whose entries the per-sample unknowns leave
    under :data:`MIN_KEPT_LEVEL` of their errors (``shares``; the initialisation's dwell
    alone: the encoders' reference) tells no level: it takes its quantity's and weighs
    nothing in it."""
    quantity = np.array([int(e.kinds[kg.mask][0]) % 4 for kg in kinds])
    size = np.array([kg.n for kg in kinds], dtype=float)
    told = np.array([float(np.mean(m)) >= MIN_KEPT_LEVEL if len(m) else False
                     for m in shares])
    out = level.copy()
    for j, kg in enumerate(kinds):
        same = quantity == quantity[j]
        pool = same & told if (same & told).any() else same
        pooled = float(size[pool] @ level[pool] / size[pool].sum())
        out[j] = pooled if not told[j] and told[pool].any() else \
            (level[j] * kg.n + PRIOR_ENTRIES * pooled) / (kg.n + PRIOR_ENTRIES)
    return out


def _nested_parts(v: float, c: np.ndarray, grams: list[np.ndarray], nu: list[float]
                  ) -> list[tuple[np.ndarray, float]]:
    """The terms of one kind's meat ``v G_0 + c_1 G_1 + c_2 G_2 + c_3 G_3 + c_d G_4`` as
    positive semi-definite increments for :func:`effective_dof`: ``(v - c_1) S_0 + (c_1 -
    c_2) S_1 + (c_2 - c_3) S_2 + c_3 S_3`` with ``S_l = G_0 + ... + G_l`` (the squared sums
    over level-``l`` groups; the same meat). ``G_1..G_3`` alone pair different entries and
    can be negative: a parameter whose column changes sign within a move would see its
    well-measured level cancelled by them and its dof fall to 1. Increments below zero
    (components not nested in size) count as nothing here; ``nu`` each term's dof."""
    cum = list(np.cumsum(np.array(grams[:4]), axis=0))
    coef = [v, *c[:3]]
    inc = [max(coef[lv] - (coef[lv + 1] if lv < 3 else 0.0), 0.0) for lv in range(4)]
    out = [(a * S, d) for a, S, d in zip(inc, cum, nu[:4], strict=True)]
    return out + [(c[3] * grams[4], nu[4])]


def component_dof(kg: _KindGroups, e: ErrorStructure, p: int, n: int,
                  kept: float | None = None) -> list[float]:
    """Degrees of freedom of the components of :func:`error_meat` of one kind ``kg`` (of
    ``n`` entries, ``p`` fitted parameters): the level's its entries' weights summed (rows of
    a move count together) with the :data:`PRIOR_ENTRIES` it leans on, less the parameters'
    share; a shared covariance's the number of its groups (a cable's move, a cable's
    stretch, a cable over the recording; the direction's: the cables). Each times the share
    of the residuals per-sample unknowns leave (``kept``: the kind's, default ``e.kept``); at
    least 1."""
    share = e.kept if kept is None else kept
    w = float(np.sum(np.clip(e.weights[kg.mask], 0.0, 1.0)))
    groups = [float(m.shape[0]) for m in kg.ind]
    raw = [w + PRIOR_ENTRIES - p * kg.n / max(n, 1)] + groups + [groups[-1]]
    return [max(share * d, 1.0) for d in raw]


def effective_dof(cov_s: np.ndarray, parts: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Per parameter, the Welch-Satterthwaite degrees of freedom of the sandwich variance
    ``diag(cov_s M cov_s)`` with ``M`` the sum of the ``parts`` (each a term of the meat and
    the degrees of freedom of its level): ``(sum_c t_c)^2 / sum_c t_c^2 / nu_c``, ``t_c`` a
    term's share of the variance. A variance that leans on a level estimated from few
    differences (the visit level of a recording with few replicate visits, the lengths'
    level where estimated poses take most of their degrees of freedom) has few; inf where
    nothing contributes."""
    terms = [np.clip(np.einsum("ij,jk,ki->i", cov_s, M, cov_s), 0.0, None) for M, _ in parts]
    return satterthwaite(terms, [nu for _, nu in parts]) if parts \
        else np.full(cov_s.shape[0], np.inf)


def satterthwaite(terms: list, dofs: list[float]) -> np.ndarray:
    """Welch-Satterthwaite degrees of freedom of a sum of variance ``terms`` (arrays or
    numbers, each >= 0, at ``dofs``; inf: known): ``(sum t)^2 / sum t^2 / nu``, at least 1;
    inf where no term of finite dof contributes."""
    tot = sum(np.asarray(t, dtype=float) for t in terms)
    den = sum(np.asarray(t, dtype=float) ** 2 / max(nu, 1.0)
              for t, nu in zip(terms, dofs, strict=True) if math.isfinite(nu))
    den = np.zeros_like(tot) + den
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, tot ** 2 / np.where(den > 0, den, 1.0), np.inf)
    return np.where(np.isfinite(out), np.maximum(out, 1.0), np.inf)


class _KindGroups:
    """The groups of one kind of entry (``mask``) that the components of :func:`error_meat`
    pair: level 1 one quantity in one move of a stretch, 2 in one stretch, 3 over the
    recording. ``P_0`` is the identity, ``P_l`` (l = 1..3) pairs entries in one group of
    level ``l`` but not of level ``l - 1`` (no entry with itself); ``P_4 = S (G - I) S``
    pairs two entries of one quantity by the product of their directions ``s`` (an error of
    +-h by the direction of approach: hysteresis, which a length offset cannot take up
    where both directions occur)."""

    def __init__(self, mask: np.ndarray, e: ErrorStructure, ncol: int, nmove: int) -> None:
        self.mask = mask
        self.n = int(mask.sum())
        key2 = e.stretches[mask].astype(np.int64) * ncol + e.columns[mask]
        key1 = key2 * nmove + e.moves[mask]
        self.index = [np.unique(k, return_inverse=True)[1]
                      for k in (key1, key2, e.columns[mask])]
        # group-by-entry indicator matrices: sums over each group are one sparse product
        self.ind = [sparse.csr_matrix((np.ones(self.n), (i, np.arange(self.n))),
                                      shape=(int(i.max()) + 1 if self.n else 0, self.n))
                    for i in self.index]
        sq = [float(self.n)] + [float(np.sum(np.bincount(i).astype(float) ** 2))
                                for i in self.index]
        self.s = (np.zeros(self.n) if e.directions is None
                  else np.sign(np.asarray(e.directions, dtype=float)[mask]))
        # tr(P_a P_b): the pair sets of levels 0..3 are disjoint; the direction's overlaps
        T = np.zeros((NCOMP, NCOMP))
        T[[0, 1, 2, 3], [0, 1, 2, 3]] = [sq[0]] + [sq[lv] - sq[lv - 1] for lv in (1, 2, 3)]
        if np.any(self.s):
            ss = [float(self.s @ self.s)] + [float(np.sum(self._sums(self.s, lv) ** 2))
                                             for lv in (1, 2, 3)]
            cross = [0.0] + [ss[lv] - ss[lv - 1] for lv in (1, 2, 3)]
            T[4, :4] = T[:4, 4] = cross
            s2 = self._sums(self.s ** 2, 3)
            T[4, 4] = float(s2 @ s2 - np.sum(self.s ** 4))
        self.trace = T
        self.pairs = np.diag(T).copy()

    def kept_trace(self, m: np.ndarray) -> np.ndarray:
        """``tr(P_a M P_b M)`` (NCOMP, NCOMP) with ``M`` the per-sample unknowns' projection,
        known by its diagonal ``m`` per entry of this kind (the share of its error's
        variance they leave: :meth:`ErrorStructure.kind_shares`); with ``m`` 1,
        :attr:`trace`. The level's is ``tr(M) = sum(m)`` (a projection: exact). The shared
        components pair entries of different samples, whose projections ``M_i, M_j`` share
        ``tr(M_i M_j)`` of their directions: between ``n m`` (the same directions: a
        revisited pose) and ``n m_i m_j`` (unrelated ones); taken as ``n sqrt(m_i m_j)``,
        the first where the shares are equal, none beside an entry that keeps nothing (the
        initialisation's, the encoders' reference)."""
        q = np.sqrt(np.clip(np.asarray(m, dtype=float), 0.0, None))
        T = np.zeros((NCOMP, NCOMP))
        T[0, 0] = float(q @ q)
        for lv in (1, 2, 3):
            T[lv, lv] = float(q @ self.apply(q, lv))
        if np.any(self.s):
            sq = self.s * q
            for lv in (1, 2, 3):
                T[4, lv] = T[lv, 4] = float(sq @ self.apply(sq, lv))
            y = self.s * sq  # (P_4 pairs e, e' of one quantity by s_e s_e')
            T[4, 4] = float(np.sum(self._sums(y, 3) ** 2) - y @ y)
        return T

    def _sums(self, x: np.ndarray, level: int) -> np.ndarray:
        return self.ind[level - 1] @ x

    def apply(self, x: np.ndarray, level: int) -> np.ndarray:
        """``P_level x`` for ``x`` (n_kind, ...) of this kind's entries."""
        if level == 0:
            return x
        if level == 4:
            sx = self._s(x)
            return self._s(self._sums(sx, 3)[self.index[2]] - sx)
        g = self._sums(x, level)[self.index[level - 1]]
        if level == 1:
            return g - x
        return g - self._sums(x, level - 1)[self.index[level - 2]]

    def _s(self, x: np.ndarray) -> np.ndarray:
        return x * (self.s[:, None] if x.ndim > 1 else self.s)

    def statistics(self, u: np.ndarray) -> list[float]:
        """``u^T P_l u`` for l = 0..4 (this kind's entries of ``u``)."""
        uk = u[self.mask]
        sq = [float(uk @ uk)] + [float(np.sum(self._sums(uk, lv) ** 2)) for lv in (1, 2, 3)]
        su = self._s(uk)
        sd = float(np.sum(self._sums(su, 3) ** 2) - su @ su)
        return [sq[0]] + [sq[lv] - sq[lv - 1] for lv in (1, 2, 3)] + [sd]

    def grams(self, x: np.ndarray) -> list[np.ndarray]:
        """``x^T P_l x`` for l = 0..4 (x: this kind's rows)."""
        g = [x.T @ x]
        for lv in (1, 2, 3):
            sl = self._sums(x, lv)
            g.append(sl.T @ sl)
        sx = self._s(x)
        ssum = self._sums(sx, 3)
        return [g[0]] + [g[lv] - g[lv - 1] for lv in (1, 2, 3)] + [ssum.T @ ssum - sx.T @ sx]


def _unbiased_components(Js: np.ndarray, sw: np.ndarray, kinds: list[_KindGroups],
                         stats: np.ndarray, knots: np.ndarray | None = None,
                         shares: list[np.ndarray] | None = None) -> np.ndarray:
    """Variance components ``theta`` (kind by kind: v, c1, c2, c3, cd) of the errors whose
    expected moment statistics, over residuals per-sample unknowns and then the fit have
    projected, equal ``stats``.

    The per-sample unknowns (an estimated pose, internal forces) project each sample's
    length residual with ``M`` (block-diagonal, sample by sample), the fit the result onto
    the complement of the span ``Q`` of the Jacobian (whose columns ``M`` leaves whole):
    ``r_fit = (I - Q Q^T) M e = (M - Q Q^T) e``. An error shared by the few rows of a visit
    loses much more than ``p / N`` of its variance to the fit (a dozen visits of a cable
    against a dozen parameters): moments of the fitted residuals then under-state it, and
    the standard errors with it (by half, on continuous recordings with few targets). With
    ``u = D^-1 r`` (``D = diag(sqrt(w))``, one value per sample: it commutes with ``M``),
    ``Y = D^-1 Q``, ``Z = D Q`` and the pair matrices ``P`` of :class:`_KindGroups`:
    ``E[u_fit^T P' u_fit] = sum_l theta_l (tr(P' M P M) - 2 tr(Y^T P' P Z) + tr(Y^T P' Y Z^T
    P Z))``, a linear system solved for ``theta`` (the plain moments where it is singular).
    For the level (``P = P' = I``) this is exact: ``tr(M) - p``, the errors' share
    ``N - lost - p`` (a share of ``M`` applied after the parameters' correction gave the
    level ``rss N / ((N - p)(N - lost))``); for the shared components, ``M`` is taken to
    leave ``P Z`` whole (exact where the paired samples share their projected directions)
    and ``tr(P' M P M)`` from its diagonal, per entry of each kind in ``shares``
    (:meth:`_KindGroups.kept_trace`, :meth:`ErrorStructure.kind_shares`; None: 1). The
    level ``v`` and ``c1..c3`` have disjoint pair sets; the direction's ``cd`` overlaps them
    (``tr(P_4 P_l)`` of :class:`_KindGroups`).

    A known covariance ``K K^T`` of the errors (``knots``: the blended visit-to-visit error
    of :class:`ErrorStructure`) is taken out of the statistics first, by the same
    expectation: the components are what the residuals hold beside it."""
    if shares is None:
        shares = [np.ones(kg.n) for kg in kinds]
    w, V = np.linalg.eigh(Js.T @ Js)
    keep = w > 1e-10 * max(float(w.max(initial=0.0)), 1e-300)
    Q = (Js @ V[:, keep]) / np.sqrt(w[keep])  # an orthonormal basis of the Jacobian's span
    Y, Z = Q / sw[:, None], Q * sw[:, None]
    L = NCOMP
    PY, PZ, GY, GZ = [], [], [], []
    for kg in kinds:
        yk, zk = Y[kg.mask], Z[kg.mask]
        PY.append([kg.apply(yk, lv) for lv in range(L)])
        PZ.append([kg.apply(zk, lv) for lv in range(L)])
        GY.append([yk.T @ py for py in PY[-1]])
        GZ.append([zk.T @ pz for pz in PZ[-1]])
    if knots is not None:
        stats = stats - _known_moments(knots, Z, kinds, shares, PY, GY)
    traces = [kg.kept_trace(m) for kg, m in zip(kinds, shares, strict=True)]
    pairs = np.concatenate([kg.pairs for kg in kinds])
    # the plain moments over the pairs' kept share (all the pairs where almost none is kept:
    # the initialisation's dwell alone, whose level is its quantity's, :func:`error_meat`)
    told = np.concatenate([np.diag(T) for T in traces])
    told = np.where(told >= MIN_KEPT_LEVEL * pairs, told, pairs)
    plain = stats / np.where(told > 0, told, 1.0)
    if knots is not None:
        # what the known part leaves of a level is at least a little of it (never negative)
        lv0 = np.arange(0, len(plain), L)
        plain[lv0] = np.maximum(plain[lv0], 1e-3)
    if Q.shape[1] == 0:
        return plain
    A = _expectation_matrix(kinds, traces, PY, PZ, GY, GZ)
    kept = np.diag(A) / np.where(pairs > 0, pairs, 1.0)
    # a component the fit absorbs for the most part (an error common to every row, against
    # a fitted offset) is not told by the residuals: it stays at its plain moment estimate
    floor = np.tile([MIN_KEPT_LEVEL] + [MIN_KEPT_SHARED] * (L - 1), len(kinds))
    used = (pairs > 0) & (kept >= floor)
    theta = plain.copy()
    theta[pairs <= 0] = 0.0
    fixed = ~used
    try:
        sol = np.linalg.solve(A[np.ix_(used, used)],
                              stats[used] - A[np.ix_(used, fixed)] @ theta[fixed])
    except np.linalg.LinAlgError:
        return plain
    if np.all(np.isfinite(sol)):
        theta[used] = sol
    level = theta.reshape(-1, L)[:, 0]
    if np.any(level[used[::L]] <= 0):
        return plain
    return theta


def _known_moments(knots: np.ndarray, Z: np.ndarray, kinds: list[_KindGroups],
                   shares: list[np.ndarray], PY: list, GY: list) -> np.ndarray:
    """The expected moment statistics (kind by kind, component by component) of the known
    covariance ``C = K K^T`` of the errors after both projections of
    :func:`_unbiased_components`: ``tr(P' M C M) - 2 tr(Y^T P' C Z) + tr(Y^T P' Y Z^T C Z)``
    (``M`` the per-sample unknowns' projection, taken as ``diag(sqrt(shares))`` beside
    ``C`` as in :meth:`_KindGroups.kept_trace`)."""
    L = NCOMP
    kz = knots.T @ Z
    zcz = kz.T @ kz
    known = np.zeros(L * len(kinds))
    for j, kg in enumerate(kinds):
        kk = knots[kg.mask]
        if not kk.any():
            continue
        ckz = kk @ kz
        qk = kk * np.sqrt(np.clip(np.asarray(shares[j], dtype=float), 0.0, None))[:, None]
        for lp in range(L):
            known[L * j + lp] = (float(np.sum(kg.apply(qk, lp) * qk))
                                 - 2.0 * float(np.sum(PY[j][lp] * ckz))
                                 + float(np.sum(GY[j][lp] * zcz)))
    return known


def _expectation_matrix(kinds: list[_KindGroups], traces: list[np.ndarray], PY: list,
                        PZ: list, GY: list, GZ: list) -> np.ndarray:
    """The matrix ``A`` of :func:`_unbiased_components`: row (kind, component ``P'``),
    column (kind, component ``P``): ``tr(P' M P M) - 2 tr(Y^T P' P Z) + tr(Y^T P' Y Z^T P Z)``
    (``traces`` each kind's ``tr(P' M P M)``)."""
    L = NCOMP
    K = L * len(kinds)
    A = np.zeros((K, K))
    for j in range(len(kinds)):
        for lp in range(L):
            row = L * j + lp
            A[row, L * j: L * (j + 1)] += traces[j][lp]
            for lv in range(L):
                # tr(Y^T P' P Z) = sum of (P' Y) * (P Z): P' symmetric
                A[row, L * j + lv] -= 2.0 * float(np.sum(PY[j][lp] * PZ[j][lv]))
            for i in range(len(kinds)):
                for lv in range(L):
                    A[row, L * i + lv] += float(np.sum(GY[j][lp] * GZ[i][lv].T))
    return A


def referenced_offsets(space: ParamSpace, rm: ResidualModel) -> np.ndarray:
    """Per parameter of ``space``: whether it is a length offset that applies from the
    initialisation on (its cable's slip time at the encoders' reference: what an error of
    that reference looks like)."""
    ids = rm.model.cable_ids
    return np.array([p.key.startswith("dl_") and rm.slip_times[ids.index(p.key[3:])]
                     <= rm.init_end for p in space.params], dtype=bool)


def direction_reference_var(fit: FitResult, rm: ResidualModel, idx: np.ndarray,
                            dof: list[float] | None = None) -> np.ndarray:
    """Per fit parameter (fit units squared): :func:`direction_bias_var` of ``fit`` on the
    samples ``idx`` for the length offsets that apply from the initialisation on (those a
    reference error of the encoders looks like: ``bench.diagnosis.report``'s floor of their
    errors); zero for the other parameters, and where per-sample unknowns project no
    sample's length residual (:meth:`ResidualModel.projects`). With a list ``dof``, the
    degrees of freedom of the variances (:func:`direction_bias_var`) are appended to it."""
    out = np.zeros(len(fit.phi))
    space = fit.space
    free = np.flatnonzero(np.isfinite(fit.stderr))
    dl = referenced_offsets(space, rm)
    if not dl[free].any() or not rm.projects(idx):
        return out
    H = space.robot(fit.phi)
    steps = rm.length_steps(H, idx)
    cols = rm.direction_columns(H, idx, steps)
    if cols is None:
        return out
    r = rm.whiten(steps[0], idx)

    def fun(z: np.ndarray) -> np.ndarray:
        phi = fit.phi.copy()
        phi[free] = z
        return rm.whitened(space.robot(phi), idx)

    J = fd_jacobian(fun, fit.phi[free], r, space.scale[free] * 1e-2, space.lo[free],
                    space.hi[free], rm.frozen)
    lost = rm.dof_lost(idx)
    errors = error_structure(rm, idx, lost)
    v = direction_bias_var(J, r, cols, errors.n_eff - lost, space.scale[free], errors, dof)
    out[free] = np.where(dl[free], v, 0.0)
    return out


# ----- 95 % intervals -----------------------------------------------------------------------

#: two-sided 95 % quantile of the normal distribution
Z95 = 1.959963984540054
#: a free parameter that another one follows by at least this correlation (the fit's
#: curvature) nearly trades with it: its interval is checked by the jackknife
#: (:func:`jackknife`) ...
JACKKNIFE_CORRELATION = 0.99
#: ... and one whose chi-square at an end of its linearised interval (the others moved as
#: the curvature says they follow it) rises by more than this factor above or below the rise
#: the curvature predicts there is checked by profile refits (the valley is not quadratic)
PROFILE_NONLINEAR = 1.25
#: profile refits of one diagnosis at most (one per end of a parameter: the least linear
#: parameters first; the others keep the linearised interval)
PROFILE_REFITS = 8


@dataclass(frozen=True)
class Interval:
    """A 95 % interval ``[lo, hi]`` of one fit parameter in fit space (c = 1/k, e = 1/EA)
    and how it was found: ``linearised`` (the estimate +- 1.96 reported standard errors),
    ``profile`` (an end moved out to where the refit holding the parameter there rises by
    the chi-square of a 95 % interval) or ``jackknife`` (the estimate +- a Student quantile
    of jackknife standard errors); widened only. ``quantile``: the Student quantile its
    standard errors were taken at (:func:`interval_quantile`)."""

    lo: float
    hi: float
    method: str
    quantile: float = Z95


def linearised_interval(fit: FitResult, k: int, extra_var: float = 0.0,
                        extra_dof: float = math.inf, quantile: float | None = None) -> Interval:
    """The estimate +- a 95 % quantile times the reported standard error (with
    ``extra_var``, fit units squared: an uncertainty the fit cannot see, estimated with
    ``extra_dof`` degrees of freedom), within the parameter's bounds: the ``quantile``
    given, else :func:`interval_quantile`'s."""
    se = math.sqrt(float(fit.reported_stderr[k]) ** 2 + extra_var)
    q = interval_quantile(fit, k, extra_var, extra_dof) if quantile is None else quantile
    p = fit.space.params[k]
    return Interval(max(float(fit.phi[k]) - q * se, p.lo),
                    min(float(fit.phi[k]) + q * se, p.hi), "linearised")


def interval_quantile(fit: FitResult, k: int, extra_var: float = 0.0,
                      extra_dof: float = math.inf) -> float:
    """The two-sided 95 % quantile for parameter ``k`` of ``fit`` with ``extra_var`` (fit
    units squared, at ``extra_dof`` degrees of freedom) added to its reported variance:
    Student's with the Welch-Satterthwaite degrees of freedom of the sum, the fit's own error
    at its ``stderr_dof``, what pruning may have moved in known; :data:`Z95` where they are
    many (or unknown)."""
    from scipy.stats import t as student

    se2 = float(fit.stderr[k]) ** 2
    var = float(fit.reported_stderr[k]) ** 2 + extra_var
    nu = math.inf if fit.stderr_dof is None else float(fit.stderr_dof[k])
    if not (se2 > 0 and math.isfinite(var) and var > 0):
        return Z95
    nu_all = float(satterthwaite([se2, var - se2 - extra_var, extra_var],
                                 [nu, math.inf, extra_dof]))
    return float(student.ppf(0.975, nu_all)) if nu_all < 1e6 else Z95


@dataclass(frozen=True)
class IntervalCheck:
    """What :func:`interval_checks` found of one parameter: ``nonlinear`` how far (in
    factors of :data:`PROFILE_NONLINEAR`, above 1: too far) its chi-square at the
    linearised ends departs from the curvature's prediction; ``correlation`` the largest
    with another free parameter."""

    index: int
    nonlinear: float
    correlation: float


def interval_checks(fit: FitResult, rm: ResidualModel, idx: np.ndarray,
                    which: np.ndarray) -> list[IntervalCheck]:
    """For the parameters of ``which`` with a finite error: the largest correlation with
    another free parameter under the fit's curvature (a swivel pulley's radius and its
    cable's exit point: -0.997), and how far the chi-square at each end of the linearised
    interval, the others moved as the curvature says, departs from the curvature's
    prediction (one evaluation per end, no refit)."""
    C = fit.curvature_cov
    if C is None or not len(which):
        return []
    space = fit.space
    lik = StretchLikelihood(rm, idx)

    def chi2_at(phi: np.ndarray) -> float:
        r = lik.residuals(space.robot(phi))
        return float(r @ r)

    with rm.cold():  # (the warm starts of what follows left as they were)
        return _checks(fit, which, C, chi2_at)


def _checks(fit: FitResult, which: np.ndarray, C: np.ndarray,
            chi2_at: Callable[[np.ndarray], float]) -> list[IntervalCheck]:
    """:func:`interval_checks` with the chi-square function ``chi2_at``."""
    space = fit.space
    movable = np.diag(C) > 0
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    c0 = chi2_at(fit.phi)
    out = []
    for k in which:
        se = float(fit.reported_stderr[k])
        if not movable[k] or not (np.isfinite(se) and se > 0):
            continue
        others = movable.copy()
        others[k] = False
        corr = float(np.max(np.abs(C[k, others]) / (sd[k] * sd[others]), initial=0.0))
        pred = (Z95 * se) ** 2 / C[k, k]
        off = 0.0
        for sign in (-1.0, 1.0):
            phi = np.clip(fit.phi + C[:, k] / C[k, k] * sign * Z95 * se, space.lo, space.hi)
            ratio = (chi2_at(phi) - c0) / pred
            off = max(off, abs(math.log(ratio)) / math.log(PROFILE_NONLINEAR) if ratio > 0
                      else np.inf)
        out.append(IntervalCheck(int(k), off, corr))
    return out


def held_at(space: ParamSpace, values: np.ndarray) -> ParamSpace:
    """``space`` whose held parameters are held at ``values`` (fit space) in place of the
    model's values: a fit's ``hold`` keeps a parameter at its space's ``neutral``."""
    out = copy.copy(space)
    out.neutral = np.asarray(values, dtype=float).copy()
    return out


def confidence_intervals(fit: FitResult, rm: ResidualModel, idx: np.ndarray,
                         which: np.ndarray, extra_var: np.ndarray | None = None,
                         pool: object = None,
                         say: Callable[[str], None] | None = None,
                         extra_dof: np.ndarray | None = None) -> dict[int, Interval]:
    """95 % intervals of the parameters ``which`` of ``fit`` (on the samples ``idx``), with
    ``extra_var`` (per parameter, fit units squared) at ``extra_dof`` degrees of freedom
    added to the reported variances.

    Each starts linearised (:func:`linearised_interval`), and is widened (never narrowed)
    where that is in doubt (:func:`interval_checks`):

    - a chi-square that is not quadratic: each end is checked by a profile refit, the
      parameter held at the end, the others refitted from where the curvature moves them.
      The chi-square of a 95 % interval there is the rise the curvature predicts at the
      linearised end, ``(1.96 se)^2 / C_kk`` (``C`` the curvature covariance: 3.84 times
      the variance the reported error adds to the curvature's); a refit that rises by less
      (a flat or curved valley) moves the end out to where a quadratic through its rise
      reaches it (within the bounds). At most :data:`PROFILE_REFITS` refits;
    - a variance that leans on levels estimated from few differences: both ends' distances
      from the estimate times the Student quantile of its degrees of freedom over 1.96
      (:func:`interval_quantile`, :func:`stretched`; exact where the valley is quadratic).
      Stretched after the profile refits, which look where the normal quantile puts the
      ends: a refit further out, past a valley that steepens, would move an end out less
      than the quadratic through a nearer one says;
    - a parameter that nearly trades with another (correlation of at least
      :data:`JACKKNIFE_CORRELATION`): the estimate +- a Student quantile of its jackknife
      standard error (:func:`jackknife`, one refit per group of blocks), where that reaches
      further. Along the shared direction of the two, a small error of the model of the
      residuals' errors is a large one of the parameters, and the curvature's valley is
      quadratic there all the same (the profile of a swivel pulley's radius beside its
      cable's exit point rose within 0.3 % of the curvature's prediction at 1.96 and at
      4.3 standard errors).

    The refits run on ``pool`` (an executor) where there is one."""
    say = say or (lambda m: None)
    ev = np.zeros(len(fit.phi)) if extra_var is None else extra_var
    ed = np.full(len(fit.phi), np.inf) if extra_dof is None else extra_dof
    q = {int(k): interval_quantile(fit, int(k), float(ev[k]), float(ed[k])) for k in which}
    out = {k: linearised_interval(fit, k, float(ev[k]), quantile=Z95) for k in q}
    own = np.asarray(which, dtype=int)
    if fit.beside_nuisance is not None:  # (the refits would drop the nuisance columns)
        own = own[~fit.beside_nuisance[own]]
    checks = interval_checks(fit, rm, idx, own)
    curved = [c.index for c in sorted(checks, key=lambda c: -c.nonlinear) if c.nonlinear > 1.0]
    curved = curved[:PROFILE_REFITS // 2]
    if curved:
        _widen_by_profiles(fit, rm, idx, curved, out, pool, say)
    out = {k: stretched(fit, k, iv, q[k] / Z95) for k, iv in out.items()}
    trading = [c.index for c in checks if c.correlation >= JACKKNIFE_CORRELATION]
    if trading:
        jk = jackknife(fit, rm, idx, pool, say)
        if jk is not None:
            se_jk, t = jk
            for k in trading:
                p, iv = fit.space.params[k], out[k]
                lo = max(float(fit.phi[k]) - t * se_jk[k], p.lo)
                hi = min(float(fit.phi[k]) + t * se_jk[k], p.hi)
                if lo < iv.lo or hi > iv.hi:
                    out[k] = Interval(min(lo, iv.lo), max(hi, iv.hi), "jackknife")
    return {k: replace(iv, quantile=q[k]) for k, iv in out.items()}


def stretched(fit: FitResult, k: int, iv: Interval, factor: float) -> Interval:
    """``iv`` of parameter ``k`` with each end's distance from the estimate times
    ``factor`` (within the parameter's bounds; its method kept)."""
    x, p = float(fit.phi[k]), fit.space.params[k]
    return Interval(max(x - (x - iv.lo) * factor, p.lo), min(x + (iv.hi - x) * factor, p.hi),
                    iv.method)


def _widen_by_profiles(fit: FitResult, rm: ResidualModel, idx: np.ndarray, ks: list[int],
                       out: dict[int, Interval], pool: object,
                       say: Callable[[str], None]) -> None:
    """The profile refits of :func:`confidence_intervals` for the parameters ``ks``: their
    intervals in ``out`` widened in place."""
    space, C = fit.space, fit.curvature_cov
    assert C is not None
    movable = np.diag(C) > 0
    jobs = []
    for k in ks:
        iv = out[k]
        for end in (iv.lo, iv.hi):
            phi0 = np.clip(fit.phi + C[:, k] / C[k, k] * (end - fit.phi[k]), space.lo, space.hi)
            phi0[k] = end
            hold = ~movable
            hold[k] = True
            jobs.append((k, end, held_at(space, np.where(hold, phi0, space.neutral)), phi0,
                         hold))
    say(f"checking the intervals of {len(ks)} parameters by {len(jobs)} profile refits")
    fits = fits_side_by_side(pool, rm, [(sp, idx, phi0, {"hold": hold, "prune": False})
                                        for _, _, sp, phi0, hold in jobs])
    ends: dict[int, list[float]] = {}
    for (k, end, _, _, _), res in zip(jobs, fits, strict=True):
        ends.setdefault(k, []).append(_profile_end(fit, k, end, res))
    for k, (lo, hi) in ends.items():
        iv = out[k]
        out[k] = Interval(min(lo, iv.lo), max(hi, iv.hi),
                          "profile" if lo < iv.lo or hi > iv.hi else "linearised")


#: groups of blocks (a target with its visits, or one move) the jackknife leaves out in turn
JACKKNIFE_GROUPS = 8


def jackknife(fit: FitResult, rm: ResidualModel, idx: np.ndarray, pool: object = None,
              say: Callable[[str], None] | None = None) -> tuple[np.ndarray, float] | None:
    """Delete-a-group jackknife standard errors of ``fit``'s free parameters and the
    Student quantile of its 95 % interval: the blocks of the samples ``idx`` (a target with
    its visits, or one move; the initialisation always kept) dealt into
    :data:`JACKKNIFE_GROUPS` groups, each left out by one refit from ``fit`` (what ``fit``
    holds held where it is). The spread of the refits is what the data's own errors do to
    the estimate, whatever their model: where parameters nearly trade (a swivel pulley's
    radius and its cable's exit point, correlation -0.997), a small error of the model of
    the residuals' errors is a large one along their shared direction. None with fewer than
    4 blocks or refits."""
    from scipy.stats import t as student

    s = rm.s
    blocks, init = s.block[idx], s.is_init[idx]
    ub = np.unique(blocks[~init])
    G = min(JACKKNIFE_GROUPS, len(ub))
    if G < 4 or fit.curvature_cov is None:
        return None
    hold = ~(np.diag(fit.curvature_cov) > 0)
    space = held_at(fit.space, np.where(hold, fit.phi, fit.space.neutral))
    subsets = [idx[~(np.isin(blocks, ub[g::G]) & ~init)] for g in range(G)]
    (say or (lambda m: None))(f"jackknife: {G} refits, each without a group of blocks")
    fits = fits_side_by_side(pool, rm, [(space, sub, fit.phi, {"hold": hold, "prune": False})
                                        for sub in subsets])
    th = np.array([f.phi for f in fits if f.success])
    n = len(th)
    if n < 4:
        return None
    var = (n - 1) / n * np.sum((th - th.mean(axis=0)) ** 2, axis=0)
    return np.sqrt(var), float(student.ppf(0.975, n - 1))


def _profile_end(fit: FitResult, k: int, end: float, res: FitResult) -> float:
    """Where the 95 % chi-square of parameter ``k`` is reached on the side of ``end``, from
    the profile refit ``res`` holding it at ``end``: ``end`` itself where the refit rises by
    at least the curvature's prediction (or did not converge), else further out along a
    quadratic through the minimum and the refit's rise, within the parameter's bounds."""
    p = fit.space.params[k]
    C = fit.curvature_cov
    d = end - float(fit.phi[k])
    if C is None or d == 0 or not res.success:
        return end
    target = d * d / C[k, k]
    rise = res.chi2 - fit.chi2
    if rise >= target:
        return end
    far = float(fit.phi[k]) + d * (math.sqrt(target / rise) if rise > 0 else np.inf)
    return float(np.clip(far, p.lo, p.hi))


def selective_interval(x: float, neutral: float, se: float, c: float,
                       level: float = 0.95) -> tuple[float, float] | None:
    """The ``level`` confidence interval (fit units) of a parameter estimated at ``x`` with
    standard error ``se`` that is reported only because it departs from the model's value
    ``neutral`` by more than ``c`` standard errors (|x - neutral| > c se): the interval of
    the normal mean given that selection (the truncated normal's quantiles inverted in its
    mean). A parameter named for passing a threshold sits, by that choice, where the noise
    pushed it past the threshold: of eight length offsets at the model's value, the one
    that noise moved 3.1 standard errors out is reported, and its value +- 1.96 standard
    errors never holds the model's value. Far past the threshold the interval is the plain
    one. None where ``x`` did not pass or ``se`` is no error."""
    from scipy.optimize import brentq
    from scipy.stats import norm

    if not (se > 0 and math.isfinite(se) and c >= 0):
        return None
    z = (x - neutral) / se
    if abs(z) <= c:
        return None
    sign = 1.0 if z > 0 else -1.0
    z = abs(z)  # the selection is symmetric: work on the side the estimate fell

    def below(theta: float) -> float:
        """P(Z <= z | |Z| > c) for Z ~ N(theta, 1), falling in theta (log-space tails)."""
        left = norm.logcdf(-c - theta)          # Z < -c
        mid = _log_diff(norm.logcdf(z - theta), norm.logcdf(c - theta))  # c < Z <= z
        right = norm.logsf(c - theta)           # Z > c
        num = np.logaddexp(left, mid)
        return float(np.exp(num - np.logaddexp(left, right)))

    alpha = 1.0 - level
    ends = []
    for target in (1.0 - alpha / 2.0, alpha / 2.0):
        lo, hi = z - 40.0, z + 40.0
        try:
            ends.append(brentq(lambda t, q=target: below(t) - q, lo, hi, xtol=1e-6))
        except ValueError:  # no crossing within 40 errors: the plain end
            ends.append(z - Z95 if target > 0.5 else z + Z95)
    a, b = neutral + sign * ends[0] * se, neutral + sign * ends[1] * se
    return (min(a, b), max(a, b))


def _log_diff(la: float, lb: float) -> float:
    """log(exp(la) - exp(lb)) for la >= lb (-inf where they are equal)."""
    if not la > lb:
        return -math.inf
    with np.errstate(divide="ignore"):
        return float(la + np.log1p(-np.exp(lb - la)))


def value_interval(p, iv: Interval) -> tuple[float, float]:
    """An interval of fit space as the parameter's values ``(lo, hi)`` in the conventions'
    units (a stiffness k = 1/c: the ends swap; an end at c <= 0 is an infinite stiffness)."""
    a, b = p.to_value(iv.lo), p.to_value(iv.hi)
    return (min(a, b), max(a, b))
