"""The error model's level where per-sample unknowns and the fit's parameters both project
the residuals (issue 32, item 5: pulley_kinematics intervals without load cells).

Per-sample unknowns (internal forces without load cells, an estimated pose without a
tracker) project each sample's n length residuals onto ``r`` of n directions; the fit's p
parameters, whose columns those projections leave whole, take p more. The residuals' sum of
squares then holds ``N - lost - p`` of the errors' variance, not ``(N - p)(N - lost) / N``
(the per-sample share applied after the parameters' correction: the variance 0.8 of right in
the problem below, 0.95 on an IPAnema-class dwell without load cells)
(:func:`bench.diagnosis.fit._unbiased_components`). The initialisation's samples, whose
length readings are the encoders' reference (residual and columns nil, all n degrees of
freedom lost: :meth:`bench.diagnosis.residuals.ResidualModel.dof_lost`), change nothing, not
the level of the kinds the unknowns do not project either (:attr:`ErrorStructure.unknowns_kept`:
with the recording's share counting them, a CoGiRo-class campaign with load cells and a
tracker read its cells' errors large and named nothing, test_unneeded43)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.fit import ErrorStructure, standard_errors

N_CABLES, RANK, SAMPLES, P = 8, 2, 20, 10


def _projection(rng: np.random.Generator, n: int, r: int) -> np.ndarray:
    """(n, n) orthogonal projection onto ``r`` random directions."""
    B = np.linalg.qr(rng.normal(size=(n, r)))[0]
    return B @ B.T


def _problem(rng: np.random.Generator, init: int = 0, forces: int = 0,
             cables_as_columns: bool = False) -> tuple:
    """A linear fit of ``P`` parameters to ``SAMPLES`` samples whose n length entries a
    per-sample projection of rank ``RANK`` leaves (the parameters' columns in its range, the
    errors of unit variance before it), ``init`` samples of the initialisation first (their
    lengths nil, columns and residuals), ``forces`` unprojected entries per sample (a kind of
    its own). Returns J, the fitted residuals r, the entries' kinds, columns, moves, shares,
    the degrees of freedom the unknowns take, the share they leave of the entries after the
    initialisation and the truth's variance (J^T J)^-1."""
    n = N_CABLES
    Js, es, kinds, cols, moves, shares = [], [], [], [], [], []
    for i in range(init + SAMPLES):
        M = np.zeros((n, n)) if i < init else _projection(rng, n, RANK)
        Js.append(M @ rng.normal(size=(n, P)))
        es.append(M @ rng.normal(size=n))
        kinds += [0] * n
        cols += list(range(n)) if cables_as_columns else list(range(n * i, n * (i + 1)))
        moves += [i] * n
        shares += [0.0 if i < init else RANK / n] * n
    for i in range(forces and SAMPLES):
        Js.append(rng.normal(size=(forces, P)))
        es.append(rng.normal(size=forces))
        kinds += [1] * forces
        cols += list(range(10_000 + forces * i, 10_000 + forces * (i + 1)))
        moves += [init + i] * forces
        shares += [1.0] * forces
    J, e = np.concatenate(Js), np.concatenate(es)
    beta = np.linalg.lstsq(J, e, rcond=None)[0]
    lost = SAMPLES * (n - RANK) + init * n
    later = SAMPLES * (n + forces)  # (the entries after the initialisation)
    return (J, e - J @ beta, np.array(kinds), np.array(cols), np.array(moves),
            np.array(shares), float(lost), 1.0 - SAMPLES * (n - RANK) / later,
            np.linalg.inv(J.T @ J))


def _se2(J, r, kinds, cols, moves, shares, lost, own, _inv=None) -> np.ndarray:
    """The reported variances (standard errors squared) of the error model (``own`` the
    share the unknowns leave after the initialisation)."""
    N = float(len(r))
    e = ErrorStructure(np.ones(len(r)), kinds, cols, moves, np.zeros(len(r), dtype=int), N,
                       None, None, (N - lost) / N, entry_kept=shares, unknowns_kept=own)
    return standard_errors(J, float(r @ r), N - lost, None, r, None, e)[1] ** 2


def test_the_level_is_the_sum_of_squares_over_what_both_projections_leave():
    """One level (every entry its own column): the variances are ``rss / (N - lost - p)``
    times ``(J^T J)^-1``, exactly (old code: ``rss N / ((N - p)(N - lost))``, 0.8 of it)."""
    rng = np.random.default_rng(45)
    J, r, kinds, cols, moves, shares, lost, own, inv = _problem(rng)
    N = len(r)
    assert N == SAMPLES * N_CABLES and lost == SAMPLES * (N_CABLES - RANK)
    want = float(r @ r) / (N - lost - P) * np.diag(inv)
    np.testing.assert_allclose(_se2(J, r, kinds, cols, moves, shares, lost, own), want,
                               rtol=1e-9)


def test_over_draws_the_variance_is_the_estimates():
    """Over draws of the errors, the reported variance averages the estimates' true one
    (within 5 %; old code 0.8 of it)."""
    rng = np.random.default_rng(7)
    ratios = []
    for _ in range(150):
        J, r, kinds, cols, moves, shares, lost, own, inv = _problem(rng)
        ratios.append(np.mean(_se2(J, r, kinds, cols, moves, shares, lost, own)
                              / np.diag(inv)))
    assert 0.95 < float(np.mean(ratios)) < 1.05, np.mean(ratios)


@pytest.mark.parametrize("columns", [False, True])
def test_the_initialisation_s_samples_change_no_error(columns):
    """The same draws with two samples of the initialisation before them (nil residuals and
    columns, all n degrees of freedom lost) give the same variances, with the shared
    components the cables' columns pair (``columns``) and beside a kind the unknowns do not
    project (old code: every kind's level scaled by a recording share that counted the
    initialisation's entries; the lengths' shared components paired with them)."""
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    with_init = _problem(rng_a, init=2, forces=6, cables_as_columns=columns)
    rng_b.normal(size=(2 * (N_CABLES * P + N_CABLES)))  # (the same draws for the rest)
    without = _problem(rng_b, init=0, forces=6, cables_as_columns=columns)
    np.testing.assert_allclose(with_init[0][2 * N_CABLES:], without[0])  # (the same problem)
    a, b = _se2(*with_init), _se2(*without)
    np.testing.assert_allclose(a, b, rtol=1e-9)
