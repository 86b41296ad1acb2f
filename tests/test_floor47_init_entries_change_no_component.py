"""The initialisation's entries (residuals and columns nil, nothing kept: the encoders'
reference) change no error component (:func:`bench.diagnosis.fit._unbiased_components`).

The per-sample unknowns' projection ``M`` is nil there, so the expectation's cross term
``tr(Y^T P' M P Z)`` has nothing on those rows; taken as ``P' Y`` whole it paired a cable's
entries of later samples through the initialisation's (the posterior-mean rule without it:
the components 19 % apart with two samples of the initialisation before the others; the
old floor rule counted the initialisation's pairs in the share it compared with
``MIN_KEPT_SHARED``: the per-cable component solved without them, at its plain moment with
them)."""

from __future__ import annotations

import numpy as np

from bench.diagnosis.fit import ErrorStructure, _KindGroups, _unbiased_components

CABLES, SAMPLES, OFFSET_SAMPLES = 8, 12, 3


def _components(init: int, r_later: np.ndarray) -> np.ndarray:
    """The components of the residuals ``r_later`` of ``SAMPLES`` samples of ``CABLES``
    lengths (each sample its own stretch; the Jacobian an offset per cable on the first
    ``OFFSET_SAMPLES`` of them: 0.56 of a per-cable component's pairs left) after ``init``
    samples of the initialisation."""
    n0, n = CABLES * init, CABLES * (init + SAMPLES)
    cable = np.tile(np.arange(CABLES), init + SAMPLES)
    sample = np.repeat(np.arange(init + SAMPLES), CABLES)
    e = ErrorStructure(np.ones(n), np.zeros(n, dtype=int), cable, sample, sample, float(n))
    kg = _KindGroups(np.ones(n, dtype=bool), e, CABLES, init + SAMPLES)
    J = np.zeros((n, CABLES))
    rows = np.arange(n0, n)
    J[rows, cable[n0:]] = (sample[n0:] - init < OFFSET_SAMPLES).astype(float)
    r = np.concatenate([np.zeros(n0), r_later])
    shares = np.where(sample < init, 0.0, 1.0)
    return _unbiased_components(J, np.ones(n), [kg], np.array(kg.statistics(r)), None,
                                [shares])


def test_the_initialisation_s_entries_change_no_component():
    rng = np.random.default_rng(47)
    n = CABLES * SAMPLES
    cable = np.tile(np.arange(CABLES), SAMPLES)
    J = np.zeros((n, CABLES))
    J[np.arange(n), cable] = (np.repeat(np.arange(SAMPLES), CABLES) < OFFSET_SAMPLES)
    Q = np.linalg.qr(J)[0]
    err = rng.normal(size=n) + 0.5 * rng.normal(size=CABLES)[cable]
    r = err - Q @ (Q.T @ err)
    np.testing.assert_allclose(_components(2, r), _components(0, r), rtol=1e-9, atol=1e-12)
