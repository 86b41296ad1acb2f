"""Length offsets' intervals without a tracker hold each cable's error by direction of approach.

A winch's hysteresis makes a cable longer after paying out than after reeling in. Where the
platform's pose is estimated from the lengths, that error spreads over every cable's residual
(the error model's direction component reads nothing there), and at the initialisation, where
the encoders are referenced, each cable's sign is unknown and stays in every later sample: a
length offset common to the whole recording, which the fit's standard errors did not hold
(:func:`bench.diagnosis.fit.direction_bias_var`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.diagnosis.fit import (
    ErrorStructure,
    direction_bias_var,
    direction_reference_var,
    fit_effects,
    standard_errors,
)
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.diagnosis.space import ParamSpace
from bench.evaluate import one_blas_thread, record
from bench.recording import read_recording

#: two cables slipped after the initialisation [m]
TRUTH = {"dl_11": 0.005160985043415183, "dl_42": 0.00464403139020601}
#: four poses of an IPAnema-class robot (visited twice, in a continuous recording)
POSES = [[-0.0345, 1.3028, 2.9659, 0.0100, -0.0034, -0.0144],
         [2.3670, -1.4897, 3.5296, 0.0079, 0.0141, -0.0046],
         [0.0206, 1.8923, 3.3153, -0.0057, 0.0158, -0.0115],
         [-0.2084, -2.0538, 2.5333, -0.0069, -0.0045, -0.0016]]


def _case(hysteresis_m: float) -> dict:
    """A continuous recording without a tracker: load cells 0.25 N, 0.1 mm per visit."""
    return {"format": "cdpr-scenario/1", "robot": "ipanema", "seed": 12857,
            "init_pose": [1.1204865656253182, -0.6887376529317846, 3.5246658561851594,
                          0.0, 0.0, 0.0],
            "truth": {"cable_length_offset": dict(TRUTH)},
            "noise": {"tracker_m": 1.5e-05, "tracker_rad": 1e-05, "load_cell_n": 0.25,
                      "encoder_m": 1e-06, "process_m": 0.0001, "exit_m": 2.5e-05},
            "nuisance": {"hysteresis_m": hysteresis_m},
            "poses": {"kind": "list", "list": POSES, "visits": 2, "dwell_s": 2.0,
                      "init_s": 3.0, "speed_m_s": 0.375},
            "recording": {"kind": "continuous", "dwell_at_targets": False,
                          "state_column": True, "tracker": False, "load_cells": True,
                          "rate_hz": 10.0}}


def _offsets(tmp_path: Path, hysteresis_m: float) -> dict[str, tuple[float, float]]:
    """{key: (error, standard error)} [m] of the two slipped cables' offsets, fitted with the
    other cables held; the errors with the reference's error by direction as the report
    adds it (:func:`direction_reference_var`)."""
    one_blas_thread()
    rec_dir = tmp_path / f"rec_{hysteresis_m:g}"
    record(_case(hysteresis_m), rec_dir)
    rec = read_recording(rec_dir)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    space = ParamSpace(rm.model, ("cable_length_offset",))
    hold = np.array([p.key not in TRUTH for p in space.params])
    fit = fit_effects(space, rm, np.arange(s.n), prune=False, hold=hold)
    got = space.values(fit.phi)["cable_length_offset"]
    se = np.sqrt(fit.stderr ** 2 + direction_reference_var(fit, rm, np.arange(s.n)))
    return {p.key: (got[p.key] - TRUTH[p.key], float(se[k]))
            for k, p in enumerate(space.params) if not hold[k]}


@pytest.mark.slow
def test_offset_intervals_hold_the_hysteresis_at_the_reference(tmp_path: Path) -> None:
    """Hysteresis 0.13 mm: the offsets come out 0.09-0.11 mm off (z 2.3 and 2.8 with the
    errors the fit gave before); their 95 % intervals hold the truth. Without hysteresis the
    intervals hold it too, and are narrower (the added variance follows the error)."""
    with_h = _offsets(tmp_path, 1.328e-4)
    without = _offsets(tmp_path, 0.0)
    for key in TRUTH:
        err, se = with_h[key]
        assert abs(err) < 1.96 * se, (key, err, se)
        err0, se0 = without[key]
        assert abs(err0) < 1.96 * se0, (key, err0, se0)
        assert se0 < se, (key, se0, se)


def _structure(m: int) -> ErrorStructure:
    """Independent entries of one kind (no moves, no knots)."""
    return ErrorStructure(np.ones(m), np.zeros(m, dtype=int), np.zeros(m, dtype=int),
                          np.arange(m), np.arange(m), float(m))


def _draw(rng: np.random.Generator, alpha: float, m: int = 400, n: int = 4
          ) -> tuple[np.ndarray, float, float]:
    """A linear fit of two parameters, the first one cable's length offset [DIRECTION m],
    whose entries hold each cable's error by direction of ``alpha`` [m] (and its unknown
    sign from the initialisation on) beside unit white noise: (error of the first
    parameter, its plain standard error, the variance added)."""
    D = rng.normal(size=(m, n)) * 0.3 / DIRECTION
    J = np.column_stack([D[:, 0] * DIRECTION, rng.normal(size=m)])
    s = rng.choice([-1.0, 1.0], size=(m, n))
    X, later = D * s, D
    s0 = rng.choice([-1.0, 1.0], size=n)
    y = rng.normal(size=m) + X @ np.full(n, alpha) - later @ (alpha * s0)
    theta = np.linalg.lstsq(J, y, rcond=None)[0]
    r = y - J @ theta
    e = _structure(m)
    _, se = standard_errors(J, float(r @ r), float(m), np.ones(2), r, None, e)
    added = direction_bias_var(J, r, (X, later), float(m), np.ones(2), e)
    return float(theta[0]), float(se[0]), float(added[0])


#: [m] a direction error's column scale in :func:`_draw` (an error of this size moves a
#: whitened residual by 0.3)
DIRECTION = 1e-4


def test_direction_variance_finds_nothing_without_an_error_by_direction() -> None:
    """Without an error by direction the added variance is a small share of the plain one."""
    rng = np.random.default_rng(3)
    shares = [added / se ** 2 for _, se, added in (_draw(rng, 0.0) for _ in range(40))]
    assert np.median(shares) < 0.05
    assert np.mean(shares) < 0.5


def test_direction_variance_covers_an_error_by_direction() -> None:
    """With an error by direction of twice the offset's plain standard error (its sign at
    the initialisation unknown), the plain intervals miss the truth often; with the added
    variance about 95 % hold it."""
    rng = np.random.default_rng(4)
    draws = [_draw(rng, 0.4 * DIRECTION) for _ in range(60)]
    plain = np.mean([abs(err) < 1.96 * se for err, se, _ in draws])
    held = np.mean([abs(err) < 1.96 * np.sqrt(se ** 2 + add) for err, se, add in draws])
    assert plain < 0.8
    assert held >= 0.88
