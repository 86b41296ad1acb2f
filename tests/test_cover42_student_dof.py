"""95 % intervals whose variance leans on a level estimated from few differences
(``bench.diagnosis.fit``: :func:`effective_dof`, :func:`interval_quantile`).

The lengths' visit-to-visit level of a recording (``ResidualModel.visit_sd``) enters the
standard errors whole (``ErrorStructure.knots``), measured on a handful of replicate
differences (``visit_dof``; the declared default where nothing measured it). An interval of
the estimate +- 1.96 such standard errors covers the truth less often than 95 % (a
Student's t of few degrees of freedom has heavier tails than the normal): the quantile is
Student's at the Welch-Satterthwaite degrees of freedom of the variance's components."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy.stats import t as student

from bench.diagnosis.fit import (
    Z95,
    ErrorStructure,
    FitResult,
    Interval,
    effective_dof,
    interval_quantile,
    linearised_interval,
    standard_errors,
    stretched,
)
from bench.diagnosis.space import ParamSpace
from controller.robot import resolve_robot

#: stops, entries per stop, the stops' error over the entries' own (whitened units)
STOPS, PER_STOP, LEVEL = 6, 10, 3.0


def _structure(level_est: float, dof: float) -> ErrorStructure:
    """Entries that share their stop's error (known at ``level_est``, measured with ``dof``
    degrees of freedom) and nothing else: each entry its own quantity, move and stretch."""
    n = STOPS * PER_STOP
    hat = np.repeat(np.eye(STOPS), PER_STOP, axis=0)
    return ErrorStructure(np.ones(n), np.zeros(n, dtype=int), np.arange(n), np.arange(n),
                          np.arange(n), float(n), None, hat * level_est, 1.0, dof)


@functools.cache
def _space() -> ParamSpace:
    return ParamSpace(resolve_robot("ipanema"), ("cable_length_offset",))


def _fit(phi: float, se: float, nu: float) -> FitResult:
    """A fit of one free parameter at ``phi`` with error ``se`` of ``nu`` degrees of freedom
    (the others held)."""
    space = _space()
    n = len(space)
    p = space.neutral.copy()
    p[0] = phi
    stderr, dof = np.full(n, np.inf), np.full(n, np.inf)
    stderr[0], dof[0] = se, nu
    cov = np.zeros((n, n))
    cov[0, 0] = se ** 2
    return FitResult(space, p, 100.0, 200, 100.0, stderr, cov, True, "", n_free=1,
                     stderr_dof=dof)


def _coverage(dof: float, draws: int, rng: np.random.Generator,
              use_dof: bool = True) -> tuple[float, float]:
    """Share of ``draws`` simulated recordings whose 95 % interval of a common offset holds
    its truth (0), the stops' level measured on ``dof`` differences (``inf``: known), and
    the median quantile used. ``use_dof`` False: the intervals at the normal's quantile."""
    n = STOPS * PER_STOP
    J = np.ones((n, 1))
    hits, qs = 0, []
    for _ in range(draws):
        y = LEVEL * np.repeat(rng.standard_normal(STOPS), PER_STOP) + rng.standard_normal(n)
        est = LEVEL * (math.sqrt(rng.chisquare(dof) / dof) if math.isfinite(dof) else 1.0)
        theta = float(np.mean(y))
        r = y - theta
        nu: list[np.ndarray] = []
        _, se = standard_errors(J, float(r @ r), float(n), None, r, None,
                                _structure(est, dof), nu)
        fit = _fit(0.1 + theta * 1e-4, float(se[0]) * 1e-4, float(nu[0][0]) if use_dof
                   else math.inf)
        iv = linearised_interval(fit, 0)
        hits += iv.lo <= 0.1 <= iv.hi
        qs.append(interval_quantile(fit, 0))
    return hits / draws, float(np.median(qs))


def test_intervals_leaning_on_a_level_of_few_dof_cover_95_percent():
    """The stops' level measured on 4 differences: the normal quantile covers about 88 %,
    Student's at the Satterthwaite dof 95 % (within the binomial spread of 1500 draws).
    Fails with the knots' dof left out of :func:`effective_dof` (coverage 0.88)."""
    rng = np.random.default_rng(42)
    got, q = _coverage(4.0, 1500, rng)
    assert 0.935 <= got <= 0.965, (got, q)
    assert q > 2.4
    plain, q0 = _coverage(4.0, 1500, rng, use_dof=False)
    assert plain < 0.92 and q0 == Z95


def test_a_level_known_or_measured_on_many_differences_keeps_the_normal_interval():
    """Nothing to widen where the level is known (the quantile is the normal's exactly) or
    measured on 400 differences (within 0.5 % of it), and the intervals still cover."""
    rng = np.random.default_rng(7)
    got, q = _coverage(math.inf, 600, rng)
    assert q == Z95 and 0.93 <= got <= 0.97, got
    got, q = _coverage(400.0, 600, rng)
    assert Z95 < q < Z95 * 1.005 and 0.93 <= got <= 0.97, (got, q)


def test_effective_dof_is_welch_satterthwaite_over_the_components():
    """Two components of one parameter's variance, 3 : 1, at 5 and infinite dof: (4)^2 /
    (3^2 / 5) = 8.9; a component without dof weight leaves inf; a second parameter that only
    the known component reaches keeps inf."""
    cov_s = np.eye(2)
    parts = [(np.diag([3.0, 0.0]), 5.0), (np.diag([1.0, 2.0]), math.inf)]
    nu = effective_dof(cov_s, parts)
    assert nu[0] == pytest.approx(16.0 / (9.0 / 5.0))
    assert nu[1] == math.inf
    assert effective_dof(cov_s, [(np.eye(2), math.inf)]).tolist() == [math.inf, math.inf]


def test_the_quantile_counts_an_extra_variance_of_few_dof():
    """An uncertainty beside the fit's own (the encoders' reference by direction of approach,
    its level over the cables: 8 dof) widens the quantile by its share: equal variances, the
    fit's of 100 dof, the extra of 8: (2)^2 / (1/100 + 1/8) = 29.6 dof."""
    fit = _fit(0.1, 1e-4, 100.0)
    q = interval_quantile(fit, 0, 1e-8, 8.0)
    assert q == pytest.approx(float(student.ppf(0.975, 4.0 / (1 / 100 + 1 / 8))))
    assert interval_quantile(fit, 0, 1e-8) == pytest.approx(
        float(student.ppf(0.975, 4.0 / (1 / 100))))
    iv = linearised_interval(fit, 0, 1e-8, 8.0)
    assert iv.hi - 0.1 == pytest.approx(q * math.sqrt(2e-8))


def test_a_stretched_interval_is_the_linearised_one_at_the_student_quantile():
    """Stretching the normal-quantile interval by q / 1.96 is the interval at q (both ends,
    within the bounds, the method kept): what a profile-widened interval gets on top of its
    refits, so that the Student quantile never narrows what they found."""
    fit = _fit(0.1, 1e-4, 5.0)
    q = interval_quantile(fit, 0)
    plain = linearised_interval(fit, 0, quantile=Z95)
    got = stretched(fit, 0, plain, q / Z95)
    want = linearised_interval(fit, 0)
    assert (got.lo, got.hi) == pytest.approx((want.lo, want.hi))
    assert got.method == "linearised" and q > 2.5
    profile = Interval(0.1 - 5e-4, 0.1 + 2e-4, "profile")
    wide = stretched(fit, 0, profile, 1.5)
    assert (wide.lo, wide.hi) == pytest.approx((0.1 - 7.5e-4, 0.1 + 3e-4))
    assert wide.method == "profile"
    assert stretched(fit, 0, Interval(-0.5, 0.2, "linearised"), 2.0).lo == fit.space.lo[0] == -1.0


def _move_shared_dof(column: np.ndarray, rng: np.random.Generator) -> float:
    """The Satterthwaite dof of one parameter fitted with ``column`` to 12 moves x 10 rows
    of one quantity, each move's rows sharing an error of the rows' own size."""
    moves = np.repeat(np.arange(12), 10)
    n = len(moves)
    e = ErrorStructure(np.ones(n), np.zeros(n, dtype=int), np.zeros(n, dtype=int), moves,
                       moves, float(n))
    y = np.repeat(rng.standard_normal(12), 10) + rng.standard_normal(n)
    J = column[:, None]
    r = y - J[:, 0] * float(column @ y / (column @ column))
    nu: list[np.ndarray] = []
    standard_errors(J, float(r @ r), float(n), None, r, None, e, nu)
    return float(nu[0][0])


def test_a_column_that_changes_sign_within_a_move_keeps_its_rows_dof():
    """A parameter whose column alternates within each move hardly sees the moves' shared
    error: its variance leans on the rows' level, measured on about a hundred entries. The
    terms pairing different entries of a move cancel its level for such a column: taken
    alone in the Satterthwaite sum they gave 1 dof (a quantile of 12.7) in most draws; as
    nested positive increments (``_nested_parts``) the dof stay those of the level. A common
    offset, which the shared error reaches whole, has about the moves' number."""
    rng = np.random.default_rng(3)
    alternating = np.tile([1.0, -1.0], 60)
    got = [_move_shared_dof(alternating, rng) for _ in range(40)]
    assert min(got) > 20, sorted(got)[:5]
    common = [_move_shared_dof(np.ones(120), rng) for _ in range(40)]
    assert 5 < float(np.median(common)) < 40, np.median(common)
