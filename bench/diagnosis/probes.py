"""Out-of-vocabulary probes: forms of length error a real robot can have that the effect
vocabulary lacks, tested jointly with the effects the selection chose.

The residual tests of :mod:`bench.diagnosis.unexplained` look at what the fitted model
leaves. An effect the selection chose may have taken a share of a drift or a
direction-dependent error (a cable's stretch follows the path, and the path follows the
clock), so what is left of it can stand below the noise. A probe is tested the way the
selection screens a candidate effect: its columns beside the chosen effects' parameters,
all free, linearised at the final fit (:func:`screen`). A probe that lowers the BIC by more
than an effect needs to enter, and whose size stands above the noise, is physics the
vocabulary does not hold: the report says so instead of trusting the named effects.

The probes, each a length change (N samples, n cables) [m] per unit parameter added to the
unstretched lengths behind the encoder readings (``ResidualModel.extra_length``), zero at
the initialisation (the encoders are referenced there):

- ``thermal``: every cable's length changes in proportion to its length and to time
  (thermal expansion, creep of all cables): one parameter, the strain over the recording;
- ``drift``: one cable's length changes in proportion to time (creep, a slipping drum):
  one parameter per cable, the change over the recording [m];
- ``direction``: one cable's length differs by the direction of its last move (backlash,
  friction in its winch): one parameter per cable, the difference between paying out and
  reeling in [m]; a finding only when it stands out from the other cables' (what all the
  winches share is their hysteresis, part of the noise model);
- ``stretch``: one cable's stretch is not proportional to its tension (a fibre rope that
  stiffens or softens with load, a replaced rope): one parameter per cable with measured
  tensions, the length change at the largest tension read of a term in the square of
  the tension's change since the initialisation [m] (the proportional part is the
  cable's E*A, an effect of the vocabulary, and stays to the effects).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse, stats

from bench.diagnosis.fit import fd_jacobian
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.space import ParamSpace

#: a probe is a finding when it lowers the BIC by more than this (what an effect needs to
#: enter the selection: bench.diagnosis.select.BIC_ENTER) ...
PROBE_BIC = 25.0
#: ... and its largest length change stands this many times above the length noise
PROBE_SIZE = 1.0
#: a cable's direction probe needs this many samples after each sign of its last move
MIN_PER_SIGN = 3
#: a cable's direction-dependent error is a finding only this many times the others' median
DIRECTION_RATIO = 2.0
#: the probes whose columns are smooth in time (a stretch of rows, an error cluster, shares
#: its slow error): their reading allows for slow errors the noise model lacks
#: (:func:`slow_scale`)
IN_TIME = ("thermal", "drift")
#: length change [m] of a probe column's finite difference (the probes are linear in it)
STEP_M = 1e-4

#: what each probe stands for, in the report's words
WHAT = {
    "thermal": "every cable's length drifts in proportion to its length with time "
               "(thermal expansion or creep of the cables?)",
    "drift": "the length drifts with time (creep, or a drum slipping slowly?)",
    "direction": "the length depends on the direction of the cable's last move "
                 "(backlash or friction in the winch?)",
    "stretch": "the stretch is not proportional to the tension (a rope that stiffens or "
               "softens with load?)",
    "cell_friction": "friction at the load cells (their readings, and the stretch computed "
                     "from them, differ by the direction of each cable's last move)",
}


@dataclass
class ProbeResult:
    """One probe column tested beside the chosen effects: ``name`` (``thermal``, ``drift``,
    ``direction``), ``cable`` (None for ``thermal``), ``value`` the fitted parameter (strain
    over the recording, or metres), ``delta_bic`` (negative: the probe fits better; its
    chi-square drop is the value's squared z, with the larger of the classical variance
    times the fit's reduced chi-square when above 1 and the cluster-robust one; for a probe
    in time, at most the z read with the slow errors' scale on Student's t,
    :func:`slow_scale`),
    ``size_over_noise`` the largest length change it makes over the length noise."""

    name: str
    cable: str | None
    value: float
    delta_bic: float
    size_over_noise: float
    finding: bool = field(default=False)

    def as_dict(self) -> dict:
        return {"probe": self.name, "cable": self.cable, "value": _r(self.value),
                "delta_bic": _r(self.delta_bic), "size_over_noise": _r(self.size_over_noise),
                "finding": bool(self.finding)}


def columns(rm: ResidualModel) -> list[tuple[str, str | None, np.ndarray]]:
    """The probes' columns (name, cable or None, (N,n) length change [m] per unit)."""
    s, model = rm.s, rm.model
    n = model.n_cables
    t = np.asarray(s.t, float)
    after = ~s.is_init
    if not after.any() or not np.isfinite(t).any():
        return []
    t_ref = rm.init_end if np.isfinite(rm.init_end) else float(np.nanmin(t))
    span = float(np.nanmax(t[after]) - t_ref)
    out: list[tuple[str, str | None, np.ndarray]] = []
    if span > 0:
        tau = np.where(after, np.clip((t - t_ref) / span, 0.0, 1.0), 0.0)
        lengths = np.where(np.isfinite(s.l_meas), np.abs(s.l_meas), 0.0)
        out.append(("thermal", None, tau[:, None] * lengths))
        for k, cid in enumerate(model.cable_ids):
            x = np.zeros((s.n, n))
            x[:, k] = tau
            out.append(("drift", cid, x))
    d = np.where(after[:, None], np.sign(s.direction), 0.0) if s.direction.shape == (s.n, n) \
        else np.zeros((s.n, n))
    use = rm.has_len & after
    for k, cid in enumerate(model.cable_ids):
        if (np.sum(use & (d[:, k] > 0)) >= MIN_PER_SIGN
                and np.sum(use & (d[:, k] < 0)) >= MIN_PER_SIGN):
            x = np.zeros((s.n, n))
            x[:, k] = 0.5 * d[:, k]
            out.append(("direction", cid, x))
    tau = np.asarray(s.tau, dtype=float)
    if rm.tau0 is not None and tau.shape == (s.n, n):
        read = np.isfinite(tau) & after[:, None]
        for k, cid in enumerate(model.cable_ids):
            if read[:, k].sum() < 8:
                continue
            dt = np.where(read[:, k], tau[:, k] - rm.tau0[k], 0.0)
            top = float(np.max(np.abs(dt)))
            if top <= 0:
                continue
            x = np.zeros((s.n, n))
            x[:, k] = (dt / top) ** 2
            out.append(("stretch", cid, x))
    # a column that changes no length residual tests nothing (no encoder readings there)
    return [c for c in out if np.any(c[2][rm.has_len] != 0.0)]


def companions(rm: ResidualModel, name: str, x: np.ndarray) -> list[np.ndarray]:
    """Length changes (N, n) [m per unit] that go with probe ``name`` (its column ``x``)
    when it stands as the structure an effect must be needed beyond. An error that depends
    on the direction of each cable's last move is referenced at the initialisation, whose
    direction the recording need not say: relative to the reference it is the probe's
    column plus a constant of each cable it touches, times what the error changes there (a
    ``direction`` error: the cable's length after the initialisation; ``cell_friction``:
    the stretch computed from the cell's readings, ``L / EA`` per newton). The other probes
    are zero at the reference by their form: none."""
    if name not in ("direction", "cell_friction"):
        return []
    after = ~rm.s.is_init
    out = []
    for k in np.flatnonzero(np.any(x != 0.0, axis=0)):
        c = np.zeros_like(x)
        c[:, k] = np.where(after, 1.0, 0.0) if name == "direction" else 2.0 * np.abs(x[:, k])
        out.append(c)
    return out


@dataclass
class Stand:
    """A named effect that a probe replaces about as well (``delta_bic`` of the probe in
    its place, below :data:`select.BIC_TIE`): the data cannot tell the effect from physics
    the vocabulary lacks."""

    effect: str
    probe: ProbeResult
    delta_bic: float
    #: the look-alike of ``effect`` the probe replaced (:func:`through_lookalike`), and the
    #: look-alike's BIC change in ``effect``'s place; None where it replaced ``effect``
    via: str | None = None
    via_delta_bic: float | None = None
    #: the BIC ``effect`` gains beside the probe (the probe free in both fits; positive: the
    #: data need the effect beyond it); None where not measured (a look-alike's stand)
    beyond: float | None = None
    #: whether the probe is itself a finding (the structure it stands for is declared)
    found: bool = False

    def as_dict(self) -> dict:
        via = {} if self.via is None else {"via": self.via,
                                           "via_delta_bic": _r(self.via_delta_bic)}
        more = ({} if self.beyond is None else {"needed_beyond_bic": _r(self.beyond)}) \
            | {"probe_finding": bool(self.found)}
        return {"effect": self.effect, "delta_bic": _r(self.delta_bic)} | via | more | {
            k: v for k, v in self.probe.as_dict().items() if k != "finding"}


def unneeded(in_question: list[dict]) -> list[dict]:
    """The stands (:meth:`Stand.as_dict`, the ``unexplained`` object's
    ``effects_in_question``) whose effect is not needed beyond the probe: a direct stand (not
    through a look-alike) of a probe that is a finding itself, beside which (with its
    companions) the effect lowers the BIC by less than an effect
    needs to enter the selection (``select.BIC_ENTER``), and that no other named effect
    needs (not marked ``others_need_it``, :func:`needed_by_others`). Such an effect holds
    only what physics outside the vocabulary left: it is not named."""
    from bench.diagnosis.select import BIC_ENTER

    return [q for q in in_question if "via" not in q and q.get("probe_finding")
            and q.get("needed_beyond_bic") is not None and q["needed_beyond_bic"] < BIC_ENTER
            and not q.get("others_need_it")]


def lost_with(before: list[str], gone: list[str], after: list[str],
              stood: set[str] | frozenset[str] = frozenset()) -> list[str]:
    """The effects named ``before`` that are no longer named ``after`` the effects ``gone``
    were left out (:func:`unneeded`) and the rest settled again, and that no probe stands
    for (``stood``: the effects of the stands, ``effects_in_question``). A refit without
    ``gone`` holds nothing of the structure outside the vocabulary they took, so what they
    leave can take another effect's parameters below the noise: where the probe cannot
    take that effect's place, the drop loses what the data need beyond the probe, and it is
    not made. An effect the probe can replace that goes too went with what it soaked."""
    return [e for e in before if e not in gone and e not in after and e not in stood]


def needed_by_others(in_question: list[dict], gone: list[dict], lost: list[str]) -> list[dict]:
    """``in_question`` with the stands ``gone`` marked ``others_need_it``: the effects
    ``lost`` (:func:`lost_with`) went without them, so :func:`unneeded` keeps them named."""
    ids = {id(q) for q in gone}
    return [q | {"others_need_it": list(lost)} if id(q) in ids else q for q in in_question]


def _length_column(rm: ResidualModel, robot, idx: np.ndarray, r0: np.ndarray,
                   x: np.ndarray) -> np.ndarray | float:
    """The derivative of the whitened residuals ``r0`` of ``robot`` on samples ``idx`` along
    an extra length ``x`` [m per sample and cable], by a forward difference of
    :data:`STEP_M` at the largest entry (``rm.extra_length`` is left set: the caller
    clears it); nan where a sample is lost."""
    unit = STEP_M / max(float(np.max(np.abs(x))), 1e-12)
    rm.extra_length = x * unit
    r = rm.whitened(robot, idx)
    return (r - r0) / unit if r.shape == r0.shape else np.nan


def _valid(r: np.ndarray, like: np.ndarray) -> np.ndarray | None:
    """``r`` where it has ``like``'s shape and is finite (every sample solved), else None."""
    return r if r.shape == like.shape and np.isfinite(r).all() else None


def _beyond(solve: Callable, j: int, without: tuple[np.ndarray, np.ndarray | None],
            full: tuple[np.ndarray, np.ndarray]) -> float:
    """The chi-square the probe ``j`` with its companions leaves from ``without`` (the
    columns kept free, the residuals there) less the one from ``full``; nan where the
    residuals without could not be evaluated (a sample lost)."""
    if without[1] is None:
        return math.nan
    return solve(without[0], j, without[1], True)[0] - solve(full[0], j, full[1], True)[0]


@dataclass
class _Linear:
    """The fit linearised at ``phi`` on the samples ``idx`` for :func:`screen`: the whitened
    residuals ``r0``, the columns of the free parameters ``act`` (``Jc``), of the probes
    (``Jp``, one each) and of each probe's companions (``Jq[j]``), the parameters' bounds,
    and the chi-square ``chi0`` of the refit without a probe with its ``inflation`` (the
    reduced chi-square, at least 1)."""

    r0: np.ndarray
    act: np.ndarray
    x_act: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    Jc: np.ndarray
    Jp: np.ndarray
    Jq: list[np.ndarray]
    sizes: np.ndarray  #: each probe column's largest entry [m]
    log_n: float
    chi0: float = 0.0
    inflation: float = 1.0

    @property
    def every(self) -> np.ndarray:
        return np.ones(len(self.act), dtype=bool)

    def solve(self, keep: np.ndarray, j: int | None, r_at: np.ndarray | None = None,
              with_companions: bool = False) -> tuple[float, float, np.ndarray]:
        """chi-square of the linearised fit from the residuals ``r_at`` (``r0``) with the
        ``keep`` columns of the effects (and probe column ``j``, with its companions when
        asked) free; the probe's value; the residuals."""
        from bench.diagnosis.select import _bounded_lstsq

        r_at = self.r0 if r_at is None else r_at
        n_res = len(self.r0)
        extra = np.zeros((n_res, 0)) if j is None else np.hstack(
            [self.Jq[j] if with_companions else np.zeros((n_res, 0)), self.Jp[:, j:j + 1]])
        m = extra.shape[1]
        A = np.hstack([self.Jc[:, keep], extra])
        x0 = np.concatenate([self.x_act[keep], np.zeros(m)])
        a = np.concatenate([self.lo[keep], np.full(m, -np.inf)])
        b = np.concatenate([self.hi[keep], np.full(m, np.inf)])
        d = _bounded_lstsq(A, -r_at, x0, a, b) if A.shape[1] else np.zeros(0)
        r = r_at + A @ d
        return float(r @ r), float(d[-1]) if j is not None else 0.0, r


def _linearise(rm: ResidualModel, space: ParamSpace, phi: np.ndarray, idx: np.ndarray | None,
               cols: list[tuple[str, str | None, np.ndarray]]) -> _Linear | None:
    """:class:`_Linear` at ``phi`` (None without residuals): the free parameters' columns by
    finite differences within their bounds, the probes' and companions' by an extra length
    (:func:`_length_column`, the robot frozen)."""
    robot = space.robot(phi)
    rm.extra_length = None
    r0 = rm.whitened(robot, idx)
    n_res = len(r0)
    if n_res == 0:
        return None
    act = np.flatnonzero(phi != space.neutral)  # the parameters the fit left free

    def fun(z: np.ndarray) -> np.ndarray:
        p = phi.copy()
        p[act] = z
        return rm.whitened(space.robot(p), idx)

    lo, hi = space.lo[act], space.hi[act]
    Jc = fd_jacobian(fun, phi[act], r0, space.scale[act] * 1e-2, lo, hi, rm.frozen) \
        if len(act) else np.zeros((n_res, 0))
    Jp = np.empty((n_res, len(cols)))
    sizes = np.empty(len(cols))
    Jq: list[np.ndarray] = []
    try:
        with rm.frozen():
            for j, (_, _, x) in enumerate(cols):
                sizes[j] = float(np.max(np.abs(x)))
                Jp[:, j] = _length_column(rm, robot, idx, r0, x)
        # each probe's companions (:func:`companions`), for the test of what an effect adds
        # beside the probe
        with rm.frozen():
            for name, _, col in cols:
                comp = companions(rm, name, col)
                Jq.append(np.empty((n_res, len(comp))))
                for i, x in enumerate(comp):
                    Jq[-1][:, i] = _length_column(rm, robot, idx, r0, x)
    finally:
        rm.extra_length = None
    lin = _Linear(r0, act, phi[act], lo, hi, Jc, Jp, Jq, sizes, math.log(n_res))
    # the chosen effects refitted on these samples, linearised, without a probe: what a
    # probe adds is measured from there (the final fit saw fewer samples)
    lin.chi0 = lin.solve(lin.every, None)[0]
    dof = max(float(rm.entry_weights(idx).sum()) - len(act) - rm.dof_lost(idx), 1.0)
    lin.inflation = max(lin.chi0 / dof, 1.0)
    return lin


def screen(rm: ResidualModel, space: ParamSpace, phi: np.ndarray,
           idx: np.ndarray | None = None,
           cols: list[tuple[str, str | None, np.ndarray]] | None = None,
           named: dict[str, dict] | None = None, declared: bool = False
           ) -> tuple[list[ProbeResult], list[Stand]]:
    """Each probe column fitted beside the fitted parameters of ``space`` (at ``phi``; the
    ones the fit held at the model's values stay held), linearised there, on the samples
    ``idx`` (all by default): its fitted value, BIC change and size, the findings marked
    (:data:`PROBE_BIC`, :data:`PROBE_SIZE`). Then each effect of ``space`` with a probe in
    its place: the effects a probe of size above the noise replaces within
    ``select.BIC_TIE``, and what the effect's parameters the report names (``named``:
    effect -> {key: value}; all its free parameters without it) lower the BIC by beside
    the probe (:attr:`Stand.beyond`). ``cols`` replaces the probes' columns
    (:func:`columns`); ``declared``: another test found what they stand for (each counts as
    a finding). A probe that is a finding stands with its companions too
    (:func:`companions`)."""
    cols = columns(rm) if cols is None else cols
    if not cols:
        return [], []
    lin = _linearise(rm, space, phi, idx, cols)
    if lin is None:
        return [], []
    ok = np.isfinite(lin.Jp).all(axis=0) & np.isfinite(lin.Jc).all()
    noise = _length_noise(rm)
    out, used = _probe_results(rm, idx, lin, cols, ok, noise)
    found = {j: r.finding or declared for j, r in zip(used, out, strict=True)}
    stands = [st for e in space.effects
              if (st := _stand(rm, space, phi, idx, lin, cols, ok, noise, found, e,
                               set((named or {}).get(e, {})))) is not None]
    return out, stands


def _probe_results(rm: ResidualModel, idx: np.ndarray | None, lin: _Linear,
                   cols: list[tuple[str, str | None, np.ndarray]], ok: np.ndarray,
                   noise: float) -> tuple[list[ProbeResult], list[int]]:
    """Each probe fitted beside the effects: its value, BIC change (from the variance of its
    coefficient: classical, or cluster-robust over the error clusters where there are 3
    or more, never below the classical; a probe in time, :data:`IN_TIME`, also read with
    the slow error the drift columns' cluster scores show, :func:`slow_scale`, on
    Student's t of their effective degrees of freedom, whichever reads less) and size over
    the ``noise``, a finding marked; and the columns that gave a result. A
    direction-dependent error common to the cables is the winches' hysteresis, which the
    noise model holds (its direction component): one cable's is a finding only where it
    also stands out from the others'."""
    Jc, Jp = lin.Jc, lin.Jp
    # each probe column less what the effects' columns hold of it (its coefficient's
    # information), and the error clusters (rows of neighbouring moves, a target's visits
    # share their errors: a drift judged row by row would count each error many times)
    U = np.zeros((len(lin.r0), 0))
    if Jc.shape[1] and np.isfinite(Jc).all():
        U, sv, _ = np.linalg.svd(Jc, full_matrices=False)
        U = U[:, sv > sv[0] * 1e-10]
        Pp = Jp - U @ (U.T @ np.where(np.isfinite(Jp), Jp, 0.0))
    else:
        Pp = Jp
    _, cluster = np.unique(rm.entry_blocks(idx), return_inverse=True)
    n_groups = int(cluster.max()) + 1 if cluster.size else 0
    fits: list[_ProbeFit] = []
    for j, (name, _, _) in enumerate(cols):
        info = float(Pp[:, j] @ Pp[:, j]) if ok[j] else 0.0
        if info <= 0:
            continue
        _, value, r = lin.solve(lin.every, j)
        fit = _ProbeFit(j, name, value, lin.inflation / info)
        if n_groups >= 3:  # cluster-robust (sandwich), never below the classical
            score = np.bincount(cluster, weights=Pp[:, j] * r, minlength=n_groups)
            fit.sandwich = float(score @ score) / info ** 2 * n_groups / (n_groups - 1)
        fits.append(fit)
    scale, dof = slow_scale(lin, Pp, U, [cols[f.j][0] for f in fits], [f.j for f in fits],
                            cluster, n_groups)
    out: list[ProbeResult] = []
    for f in fits:
        z2 = f.value ** 2 / max(f.classical, f.sandwich)
        if f.name in IN_TIME and math.isfinite(dof):
            z2 = min(z2, t_as_normal(f.value ** 2 / (max(scale, 1.0) * f.classical), dof))
        name, cid, _ = cols[f.j]
        # (a direction column is half the difference: its size is the half, as the
        # residuals' two-group test reports it)
        res = ProbeResult(name, cid, f.value, -z2 + lin.log_n,
                          abs(f.value) * lin.sizes[f.j] / noise)
        res.finding = bool(res.delta_bic < -PROBE_BIC and res.size_over_noise > PROBE_SIZE)
        out.append(res)
    dirs = [r for r in out if r.name == "direction"]
    for r in dirs:
        others = [abs(o.value) for o in dirs if o is not r]
        if others and abs(r.value) <= DIRECTION_RATIO * float(np.median(others)):
            r.finding = False
    return out, [f.j for f in fits]


@dataclass
class _ProbeFit:
    """One probe column's fit for :func:`_probe_results`: column ``j``, probe ``name``, its
    ``value``, the classical variance of the value (times the reduced chi-square when above
    1) and the cluster-robust one (``sandwich``, 0 without 3 clusters)."""

    j: int
    name: str
    value: float
    classical: float
    sandwich: float = 0.0


def cluster_dof(a: np.ndarray, V: np.ndarray, cluster: np.ndarray,
                n_groups: int) -> tuple[float, float]:
    """What the noise model expects of the sum of squared cluster scores of weights ``a``
    on a fit's residuals, and that sum's effective degrees of freedom (Satterthwaite; Bell
    and McCaffrey 2002, Imbens and Kolesar 2016, independent errors the working model).

    ``a`` (m,) weighs the whitened entries, ``V`` (m, k) is an orthonormal basis of the
    fitted columns, ``cluster`` (m,) each entry's cluster in ``0..n_groups-1``. The
    residuals are ``r = M e`` with ``M = I - V V'``; cluster g's score ``a_g @ r`` (``a_g``:
    ``a`` on the cluster's entries, 0 elsewhere) is ``(M a_g) @ e``, and the sum of squares
    is ``e' C C' e`` with ``C = [M a_1 ... M a_G]``. For errors of unit variance its mean is
    ``tr(C'C)`` and, normal, its variance ``2 tr((C'C)^2)``: it is the mean times a
    chi-square of ``nu = tr(C'C)^2 / tr((C'C)^2)`` degrees of freedom over ``nu``. ``C'C`` is
    ``diag(|a_g|^2) - L L'`` with ``L``'s row g ``V' a_g`` (G x k), so both traces come
    without a G x G matrix. Where ``a`` lies in the fitted columns (a coefficient's own
    sandwich) the columns of C sum to ``M a = 0`` and ``nu`` <= G - 1; it is less where a
    few clusters carry the weights (a drift's first and last stretches of time): 2 to 3.5
    on recordings of 4 to 6 clusters."""
    S = sparse.csr_matrix((np.ones(len(cluster)), (cluster, np.arange(len(cluster)))),
                          shape=(n_groups, len(cluster)))
    aa = S @ (a * a)
    L = S @ (V * a[:, None])
    row2 = np.einsum("gi,gi->g", L, L)
    trace = float(aa.sum() - row2.sum())
    frob2 = float(aa @ aa - 2.0 * aa @ row2 + np.sum((L.T @ L) ** 2))
    if trace <= 0 or frob2 <= 0:
        return math.nan, math.nan
    return trace, trace ** 2 / frob2


def slow_scale(lin: _Linear, Pp: np.ndarray, U: np.ndarray, names: list[str],
               js: list[int], cluster: np.ndarray, n_groups: int) -> tuple[float, float]:
    """The variance of slow errors over what the noise model holds (lambda), from the
    cables' drift columns' cluster scores, and its degrees of freedom (nan, nan without 3
    clusters or a drift column).

    The residuals are those of the effects with every probe in time (:data:`IN_TIME`,
    columns ``js`` of ``Pp``, the probe columns less the effects' ``U``) fitted too: a
    drift or thermal expansion that is real leaves them, the slow errors no line in time
    holds stay. Each cable's drift column weighs a stretch-of-time contrast of that cable's
    length entries; its sum of squared cluster scores on those residuals over what the
    noise model (unit whitened errors times the fit's reduced chi-square) expects of it is,
    where the model holds but for a scale lambda of its errors, lambda times a chi-square of
    ``nu`` (:func:`cluster_dof`) over ``nu``. The cables' scores are of different entries:
    their ``nu``-weighted mean is lambda times a chi-square of ``sum nu`` over ``sum nu``.

    Why pooled: one coefficient's own sandwich has ``nu`` <= G - 1, and read on its t no
    probe on 4 to 6 clusters could pass :data:`PROBE_BIC` (a BIC change of -33 asks a t of
    2.2 degrees of freedom for ~1e4); pooled over n cables the degrees of freedom are about
    n times as many. A time probe is then also read with ``max(lambda, 1)`` times its
    classical variance on Student's t of ``sum nu`` (:func:`t_as_normal`). Measured: on
    tracker_frame 32010/32011 and the 200-case evaluation's 12861/12935 (4 to 5 clusters,
    lambda 1.8 to 4.6, sum nu 18 to 22) the false drifts of z^2 35 to 60 read below 20; the
    thermal expansions of 12890/12896 (6 and 4 clusters, lambda 1.7 and 1.3) stay
    declared; 12923's thermal and 12962's drift (z^2 44 and 37 on the classical variance,
    lambda 1.8 and 3.4) no longer are."""
    time = [j for j, name in zip(js, names, strict=True) if name in IN_TIME]
    drifts = [j for j, name in zip(js, names, strict=True) if name == "drift"]
    if n_groups < 3 or not drifts:
        return math.nan, math.nan
    Q, sv, _ = np.linalg.svd(Pp[:, time], full_matrices=False)
    Q = Q[:, sv > sv[0] * 1e-10]
    r = lin.solve(lin.every, None)[2]
    r = r - Q @ (Q.T @ r)
    V = np.hstack([U, Q])
    nus, sums = [], []
    for j in drifts:
        score = np.bincount(cluster, weights=Pp[:, j] * r, minlength=n_groups)
        expected, nu = cluster_dof(Pp[:, j], V, cluster, n_groups)
        if math.isfinite(nu):
            nus.append(nu)
            sums.append(float(score @ score) / (lin.inflation * expected))
    if not nus:
        return math.nan, math.nan
    nu_all = np.array(nus)
    return float(nu_all @ np.array(sums) / nu_all.sum()), float(nu_all.sum())


def t_as_normal(z2: float, dof: float) -> float:
    """The squared normal deviate with the tail probability of Student's t of ``dof``
    degrees of freedom at ``sqrt(z2)``: the chi-square of one degree of freedom a
    coefficient test on an estimated variance stands for, to compare with a BIC threshold.
    Never above ``z2`` (many degrees of freedom: the normal)."""
    if z2 <= 0 or not math.isfinite(z2):
        return z2
    p = float(stats.t.sf(math.sqrt(z2), dof))
    return min(float(stats.norm.isf(p)) ** 2, z2) if p > 0 else z2


def _stand(rm: ResidualModel, space: ParamSpace, phi: np.ndarray, idx: np.ndarray | None,
           lin: _Linear, cols: list[tuple[str, str | None, np.ndarray]], ok: np.ndarray,
           noise: float, found: dict[int, bool], e: str, keys: set[str]) -> Stand | None:
    """The probe that best takes effect ``e``'s place (its parameters back at the model's
    values; a finding also with its companions): of size above the ``noise`` and within
    ``select.BIC_TIE`` of the fit with ``e``; and what the parameters of ``e`` the report
    names (``keys``; all its free ones without) add beside it. None where no probe does."""
    from bench.diagnosis.select import BIC_TIE

    pos = {k: i for i, k in enumerate(lin.act)}
    mine = [pos[k] for k in space.indices(e) if k in pos]
    if not mine:
        return None
    act, every = lin.act, lin.every
    said = [pos[k] for k in space.indices(e) if k in pos and space.params[k].key in keys] \
        or mine
    keep = every.copy()
    keep[mine] = False
    # without the effect: its parameters back at the model's values
    p = phi.copy()
    p[act[mine]] = space.neutral[act[mine]]
    r_wo = rm.whitened(space.robot(p), idx)
    if r_wo.shape != lin.r0.shape or not np.isfinite(r_wo).all():
        return None
    without = (keep, r_wo)  # what the named parameters add is measured from here
    best: Stand | None = None
    for j, (name, cid, _) in enumerate(cols):
        if not ok[j]:
            continue
        # the probe in the effect's place, alone and, a finding, with its companions
        with_comp = lin.Jq[j].shape[1] and found.get(j) and np.isfinite(lin.Jq[j]).all()
        for comp in (False, True) if with_comp else (False,):
            chi, value, _ = lin.solve(keep, j, r_wo, comp)
            size = abs(value) * lin.sizes[j] / noise
            d_bic = (chi - lin.chi0) / lin.inflation \
                + (1 + (lin.Jq[j].shape[1] if comp else 0) - len(mine)) * lin.log_n
            if not (size > PROBE_SIZE and d_bic < BIC_TIE
                    and (best is None or d_bic < best.delta_bic)):
                continue
            if said != mine and without[0] is keep:  # (evaluated once, where a probe stands)
                held = every.copy()
                held[said] = False
                p_said = phi.copy()
                p_said[act[said]] = space.neutral[act[said]]
                without = (held, _valid(rm.whitened(space.robot(p_said), idx), lin.r0))
            # what the effect's named parameters add beside the probe (both fits with the
            # probe and its companions free)
            beyond = _beyond(lin.solve, j, without, (every, lin.r0)) / lin.inflation \
                - len(said) * lin.log_n
            best = Stand(e, ProbeResult(name, cid, value, d_bic, size), d_bic,
                         beyond=None if math.isnan(beyond) else float(beyond),
                         found=found.get(j, False))
    return best


def findings(results: list[ProbeResult], stands: list[Stand] | None = None) -> list[str]:
    """Sentences for the report: the thermal probe, then cables by probe kind, then the named
    effects a probe stands in for."""
    out = []
    hit = [r for r in results if r.finding]
    th = [r for r in hit if r.name == "thermal"]
    if th:
        r = th[0]
        out.append(f"{WHAT['thermal']}: a strain of {r.value:+.1e} over the recording "
                   f"({r.size_over_noise:.1f} times the noise on the longest cable) lowers "
                   f"the BIC by {-r.delta_bic:.0f} beside the named effects")
    # a cable found by both a drift and a direction is said by the stronger (a backlash's
    # error follows the moves, and the moves the clock)
    best: dict[str, ProbeResult] = {}
    for r in hit:
        if r.cable is not None and (r.cable not in best or r.delta_bic < best[r.cable].delta_bic):
            best[r.cable] = r
    for name in ("drift", "direction", "stretch"):
        got = sorted((r for r in hit if r.name == name and best.get(r.cable) is r),
                     key=lambda r: r.delta_bic)
        if th and name == "drift":
            # a common drift's share of each cable is the thermal probe's
            got = [r for r in got if r.delta_bic < th[0].delta_bic - PROBE_BIC]
        if not got:
            continue
        which = ", ".join(str(r.cable) for r in got)
        top = got[0]
        what = {"drift": f"{top.value * 1e3:+.2f} mm over the recording",
                "direction": f"{abs(top.value) * 1e3:.2f} mm between paying out and reeling in",
                "stretch": f"{top.value * 1e3:+.2f} mm beside a proportional stretch at its "
                           f"largest tension change"}[name]
        out.append(f"cable{'s' if len(got) > 1 else ''} {which}: {WHAT[name]}: "
                   f"{what} on cable {top.cable} ({top.size_over_noise:.1f} times the "
                   f"noise), lowering the BIC by {-top.delta_bic:.0f} beside the named effects")
    from bench.diagnosis.space import report_name

    for st in stands or []:
        p = st.probe
        where = "" if p.cable is None else f" on cable {p.cable}"
        place = "in its place" if st.via is None else \
            (f"in the place of its look-alike {report_name(st.via)} (which fits within BIC "
             f"{st.via_delta_bic:+.0f} of it)")
        out.append(f"{report_name(st.effect)} may stand for physics outside the vocabulary: "
                   f"{WHAT[p.name]}{where} explains the data as well or better {place} (BIC "
                   f"{st.delta_bic:+.0f}, {p.size_over_noise:.1f} times the noise)")
    return out


def friction_column(rm: ResidualModel, cables: list[str]
                    ) -> tuple[str, str | None, np.ndarray] | None:
    """The ``cell_friction`` probe's column: the load cells of ``cables`` read one friction
    force [N] lower or higher by the direction of each cable's last move, and the stretch
    the residual model computes from their readings (``tau L / EA``) with them: a length
    change (N, n) [m per N of the difference between paying out and reeling in] of
    ``0.5 sign(direction) L / EA`` on those cables' samples with a reading. None where it
    changes no length (inextensible cables, no readings or directions)."""
    s, model = rm.s, rm.model
    n = model.n_cables
    if s.direction.shape != (s.n, n) or np.asarray(s.tau).shape != (s.n, n):
        return None
    on = np.zeros(n, dtype=bool)
    on[[model.cable_ids.index(c) for c in cables if c in model.cable_ids]] = True
    ea = np.asarray(model.ea, float)
    on &= np.isfinite(ea) & (ea > 0)
    read = np.isfinite(np.asarray(s.tau, float)) & ~s.is_init[:, None] & on[None, :]
    lengths = np.where(np.isfinite(s.l_meas), np.abs(s.l_meas), 0.0)
    x = np.where(read, 0.5 * np.sign(s.direction) * lengths / np.where(on, ea, 1.0), 0.0)
    x = np.nan_to_num(x)
    if not np.any(x[rm.has_len] != 0.0):
        return None
    return ("cell_friction", None, x)


def friction_stands(rm: ResidualModel, space: ParamSpace, phi: np.ndarray,
                    cables: list[str], named: dict[str, dict] | None = None) -> list[Stand]:
    """The named effects (``space`` at ``phi``) that the load cells' friction, found on
    ``cables`` (the residual tests' direction-dependent readings), replaces about as well
    through the stretch computed from the readings (:func:`friction_column`,
    :func:`screen`'s test): a stretch misread by direction follows the moves, as a
    tracker's latency or a length offset of each cable can (``named``: :func:`screen`'s)."""
    col = friction_column(rm, cables)
    if col is None:
        return []
    # (the cells' direction test found the friction)
    return screen(rm, space, phi, cols=[col], named=named, declared=True)[1]


def through_lookalike(rm: ResidualModel, effect: str, lookalike: str, fit_space: ParamSpace,
                      phi: np.ndarray, delta_bic: float) -> Stand | None:
    """The probe that stands for ``lookalike`` in the fit (``fit_space`` at ``phi``) of the
    named effects with ``lookalike`` in ``effect``'s place (:func:`screen`'s test there), as
    a :class:`Stand` of ``effect``: the data tell the two apart by ``delta_bic`` only (the
    look-alike's BIC change), so what the look-alike may stand for the named effect may
    too. None where no probe stands for it."""
    _, stands = screen(rm, fit_space, phi)
    got = [st for st in stands if st.effect == lookalike]
    if not got:
        return None
    st = min(got, key=lambda x: x.delta_bic)
    return Stand(effect, st.probe, st.delta_bic, lookalike, float(delta_bic))


def _length_noise(rm: ResidualModel) -> float:
    """The median length noise of a sample [m] (what a probe's size stands against)."""
    sd = rm.sd["length"][rm.has_len] if rm.has_len.any() else rm.sd["length"]
    sd = sd[np.isfinite(sd)]
    return float(np.median(sd)) if sd.size else 1e-4


def _r(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(f"{x:.4g}")


def with_not_named(leftover: dict | None, gone: list[dict],
                   figures: dict | None = None) -> dict | None:
    """``leftover`` (the ``unexplained`` object or None) with the effects not named because
    physics outside the vocabulary stands for them (``gone``, :func:`unneeded`): a finding
    each and ``effects_not_named`` (the structure stays declared where the refit without
    them no longer shows it; the object then starts from ``figures``, the fit's
    :func:`bench.diagnosis.unexplained.fit_figures`)."""
    if not gone:
        return leftover
    from bench.diagnosis.select import BIC_ENTER
    from bench.diagnosis.space import report_name

    out = dict(leftover) if leftover is not None else dict(figures or {})
    found = [f"{report_name(q['effect'])} is not named: {WHAT[q['probe']]}"
             + ("" if q.get("cable") is None else f" on cable {q['cable']}")
             + f" explains the data as well in its place (BIC {q['delta_bic']:+.0f}); beside "
             f"it the effect changes the BIC by {-q['needed_beyond_bic']:+.0f} (to enter, an "
             f"effect lowers it by more than {BIC_ENTER:.0f})"
             for q in gone]
    out["findings"] = list(out.get("findings", [])) + found
    out["summary"] = "; ".join(out["findings"])
    out["effects_not_named"] = gone
    return out
