"""The error level of a kind the per-sample unknowns do not project (the force and moment
entries at an estimated pose: :meth:`bench.diagnosis.fit.ErrorStructure.kind_stand_in`).

Its stand-in share ``s`` (the one the unknowns leave over the samples after the
initialisation) scales the level the residuals tell after the fit's correction: the errors'
variance is taken as ``rss / ((n - f) s)`` over the kind's ``n`` entries of which the fit's
parameters take ``f``. Taken as a projection inside the expectation instead, ``rss / (s n -
f)``, it has a pole where the fit takes ``s n`` of a kind of few entries: on 12939 (a
ROCASPECT-class continuous campaign with dwells, no tracker) the 21 force entries at the
dwells, ``s`` 0.57, ``f`` 6.7, read their level 1.5 times, the load cells' standard errors
grew 4x and a false cable elasticity was named. Here: a linear problem whose errors have a
known variance, the force entries few and the fit's parameters taking a third of them."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.fit import ErrorStructure, standard_errors

N_CABLES, SAMPLES = 8, 12
#: force entries (seven dwells' three force axes) and the parameters only they fix
FORCES, P_FORCE, P_LENGTH = 21, 7, 4


def _problem(rng: np.random.Generator, rank: int) -> tuple:
    """Lengths of ``SAMPLES`` samples projected to rank ``rank`` by their per-sample unknowns
    (kind 0, ``P_LENGTH`` parameters), ``FORCES`` force entries they do not project (kind 1,
    ``P_FORCE`` parameters of their own); every error of unit variance. Returns J, the
    fitted residuals, the ErrorStructure, the unknowns' lost degrees of freedom and the
    force parameters' (J^T J)^-1 diagonal."""
    n = N_CABLES
    rows_l = []
    e_l = []
    for _ in range(SAMPLES):
        B = np.linalg.qr(rng.normal(size=(n, rank)))[0]
        M = B @ B.T
        rows_l.append(M @ rng.normal(size=(n, P_LENGTH)))
        e_l.append(M @ rng.normal(size=n))
    Jl, el = np.concatenate(rows_l), np.concatenate(e_l)
    Jf, ef = rng.normal(size=(FORCES, P_FORCE)), rng.normal(size=FORCES)
    J = np.zeros((len(el) + FORCES, P_LENGTH + P_FORCE))
    J[:len(el), :P_LENGTH], J[len(el):, P_LENGTH:] = Jl, Jf
    e = np.concatenate([el, ef])
    r = e - J @ np.linalg.lstsq(J, e, rcond=None)[0]
    N = len(r)
    lost = float(SAMPLES * (n - rank))
    kinds = np.r_[np.zeros(len(el), dtype=int), np.ones(FORCES, dtype=int)]
    shares = np.r_[np.full(len(el), rank / n), np.ones(FORCES)]
    es = ErrorStructure(np.ones(N), kinds, np.arange(N), np.r_[np.repeat(
        np.arange(SAMPLES), n), SAMPLES + np.arange(FORCES)], np.zeros(N, dtype=int), N,
        None, None, (N - lost) / N, entry_kept=shares, unknowns_kept=(N - lost) / N)
    inv = np.diag(np.linalg.inv(J.T @ J))[P_LENGTH:]
    return J, r, es, lost, inv


@pytest.mark.parametrize("rank", [4, 2])
def test_a_stand_in_kind_s_level_is_its_errors_over_the_share(rank):
    """Over draws, the force parameters' reported variances average ``(J^T J)^-1 / s`` (the
    errors' unit variance scaled by the stand-in share ``s``), within 6 %. Old code (the
    share inside the expectation, ``rss / (s n - f)``): 1.5 times it beside the pole (rank
    4, ``s`` 0.59, 12939's), 0.65 of it at the pole (rank 2, ``s`` 0.38: the fit takes
    nearly ``s n``, the plain ``rss / (s n)`` stands in)."""
    rng = np.random.default_rng(46)
    ratios = []
    for _ in range(300):
        J, r, es, lost, inv = _problem(rng, rank)
        s = es.stand_in()
        assert es.kind_stand_in(es.kinds == 1) == s < 0.6
        se2 = standard_errors(J, float(r @ r), len(r) - lost, None, r, None, es)[1] ** 2
        ratios.append(np.mean(se2[P_LENGTH:] / (inv / s)))
    assert 0.94 < float(np.mean(ratios)) < 1.06, np.mean(ratios)


def test_a_projected_kind_has_no_stand_in():
    """The lengths the unknowns project keep their own shares (stand-in 1), the forces the
    recording's share."""
    J, r, es, lost, inv = _problem(np.random.default_rng(1), 2)
    assert es.kind_stand_in(es.kinds == 0) == 1.0
    np.testing.assert_allclose(es.kind_shares(es.kinds == 0), 2 / N_CABLES)
    np.testing.assert_allclose(es.kind_shares(es.kinds == 1), 1.0)
    assert es.kind_kept(es.kinds == 1) == es.stand_in()
