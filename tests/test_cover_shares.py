"""Standard errors where per-sample unknowns project some entries and not others.

Without a tracker, each sample's pose is solved from its n cable lengths: the length residual
keeps ``n - 6`` of its ``n`` directions (a quarter of the readings' variance on an eight-cable
robot), while the force and moment residuals at the solved pose keep all of theirs. The error
model estimates each kind's level from the residuals; taking the unknowns out as one share of
every entry (``(n_eff - lost) / n_eff``) under-stated the lengths' level by ``(8/14) / (2/8)``
and over-stated the forces': a length-driven parameter's standard error came out 0.66 of the
truth, a force-driven one's 1.32 (:attr:`bench.diagnosis.fit.ErrorStructure.shares`,
:meth:`bench.diagnosis.residuals.ResidualModel.entry_shares`).
"""

from __future__ import annotations

import numpy as np

from bench.diagnosis.fit import ErrorStructure, standard_errors

#: cables, pose unknowns and force axes of one sample
N_CABLES, N_POSE, N_FORCE = 8, 6, 6


def _draw(rng: np.random.Generator, samples: int, projected: bool
          ) -> tuple[np.ndarray, np.ndarray, ErrorStructure, float, np.ndarray]:
    """A linear fit of two parameters, the first seen by the lengths, the second by the forces,
    with unit white errors; each sample's length residual projected off its own random pose
    Jacobian when ``projected``. Returns (Jacobian, residuals, structure, residual dof, the
    true standard errors)."""
    rows_j, rows_r, kinds, cols, moves = [], [], [], [], []
    share = (N_CABLES - N_POSE) / N_CABLES if projected else 1.0
    for i in range(samples):
        xl = np.column_stack([rng.normal(size=N_CABLES) * 0.3, np.zeros(N_CABLES)])
        xf = np.column_stack([np.zeros(N_FORCE), rng.normal(size=N_FORCE) * 0.3])
        el, ef = rng.normal(size=N_CABLES), rng.normal(size=N_FORCE)
        if projected:
            A = rng.normal(size=(N_CABLES, N_POSE))
            P = np.eye(N_CABLES) - A @ np.linalg.pinv(A)
            xl, el = P @ xl, P @ el
        rows_j += [xl, xf]
        rows_r += [el, ef]
        kinds += [0] * N_CABLES + [1] * N_FORCE
        cols += list(range(N_CABLES + N_FORCE))
        moves += [i] * (N_CABLES + N_FORCE)
    J, e = np.vstack(rows_j), np.concatenate(rows_r)
    theta = np.linalg.lstsq(J, e, rcond=None)[0]
    r = e - J @ theta
    m = len(r)
    kinds_a = np.array(kinds)
    shares = np.where(kinds_a == 0, share, 1.0)
    moves_a = np.array(moves)
    n_eff = float(m)
    lost = float(samples * N_POSE) if projected else 0.0
    es = ErrorStructure(np.ones(m), kinds_a, np.array(cols), moves_a, moves_a // 25, n_eff,
                        None, None, 1.0, shares)
    # the errors the projected residuals hold are the raw ones projected: the score J^T e
    # has covariance J^T J (J lies in the projection's range)
    true_se = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    return J, r, es, n_eff - lost, true_se


def _ratio(seed: int, projected: bool, entry_by_entry: bool = True) -> np.ndarray:
    rng = np.random.default_rng(seed)
    J, r, es, n_res, true_se = _draw(rng, 240, projected)
    if not entry_by_entry:  # every entry keeps the same share of its error
        es.kept = n_res / es.n_eff
        es.shares = None
    _, se = standard_errors(J, float(r @ r), n_res, np.ones(2), r, None, es)
    return se / true_se


def test_estimated_poses_standard_errors_match_the_spread() -> None:
    """Lengths projected onto 2 of 8 directions per sample, forces whole: both parameters'
    standard errors within 12 % of the truth (0.66 and 1.32 with one share for all)."""
    for seed in (1, 2, 3):
        ratio = _ratio(seed, projected=True)
        assert np.all(np.abs(ratio - 1.0) < 0.12), (seed, ratio)


def test_one_share_for_every_entry_misstates_both() -> None:
    """The old rule, one share of every entry: the length-driven error too small, the
    force-driven one too large (what the entry-by-entry shares mend)."""
    ratio = _ratio(1, projected=True, entry_by_entry=False)
    assert ratio[0] < 0.8 and ratio[1] > 1.2, ratio


def test_nothing_projected_nothing_changes() -> None:
    """With every entry whole (a tracker: no per-sample unknowns) the shares change nothing:
    the standard errors are the ones of the structure without them, and right."""
    rng = np.random.default_rng(5)
    J, r, es, n_res, true_se = _draw(rng, 240, projected=False)
    _, se = standard_errors(J, float(r @ r), n_res, np.ones(2), r, None, es)
    es.shares = None
    _, se0 = standard_errors(J, float(r @ r), n_res, np.ones(2), r, None, es)
    np.testing.assert_allclose(se, se0, rtol=1e-12)
    assert np.all(np.abs(se / true_se - 1.0) < 0.12), se / true_se
