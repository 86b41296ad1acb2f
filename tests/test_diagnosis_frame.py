"""Exit-point offsets that are one rigid motion of the frame (a misregistered tracker)."""

from __future__ import annotations

import numpy as np

from bench.diagnosis.frame import frame_motion, rigid_part, sentence
from tests.robots import rocaspect


def _params(model, d: np.ndarray, cables=None) -> dict[str, float]:
    out = {}
    for k, c in enumerate(model.cable_ids):
        if cables is None or c in cables:
            for a, ax in enumerate("xyz"):
                out[f"d{ax}_{c}"] = float(d[k, a])
    return out


def test_a_rigid_motion_of_every_exit_is_told_with_its_rotation():
    model = rocaspect()
    omega, t = np.array([3e-4, -2e-4, 8e-4]), np.array([2e-3, -1.5e-3, 1e-3])
    a = model.exits
    d = np.cross(omega, a) + t + np.random.default_rng(1).normal(0, 2e-4, a.shape)
    got = frame_motion(model, _params(model, d))
    assert got is not None and got["share"] > 0.95
    np.testing.assert_allclose(got["rotation_rad"], omega, atol=5e-5)
    # the translation is the centroid's: omega x c + t
    np.testing.assert_allclose(got["translation_m"], np.cross(omega, a.mean(axis=0)) + t,
                               atol=3e-4)
    assert "registered" in sentence(got)


def test_masts_tilted_each_their_own_way_are_no_frame_motion():
    """The paper's settled ropes: each mast leans towards the workspace, about its own
    pivot: the offsets are no rigid motion of the whole frame."""
    model = rocaspect()
    centre = model.exits[:, :2].mean(axis=0)
    d = np.zeros((model.n_cables, 3))
    for k in range(model.n_cables):
        inward = centre - model.exits[k, :2]
        d[k, :2] = 0.015 * inward / np.linalg.norm(inward)
    assert frame_motion(model, _params(model, d)) is None
    _, _, _, share = rigid_part(model.exits, d)
    assert share < 0.5


def test_few_cables_or_random_offsets_say_nothing():
    model = rocaspect()
    rng = np.random.default_rng(2)
    d = rng.normal(0, 0.01, (model.n_cables, 3))
    assert frame_motion(model, _params(model, d)) is None
    omega = np.array([0.0, 0.0, 1e-3])
    d = np.cross(omega, model.exits)
    assert frame_motion(model, _params(model, d, cables={"11", "12", "21"})) is None
    assert frame_motion(model, {}) is None


def test_a_tracker_scale_is_told_by_a_similarity_and_the_drum_scales():
    """A tracker whose length scale is 2e-4 off about its station reads the exit points
    moved by that similarity and every length change 1 + 2e-4 times short: exit offsets
    and drum scales near 1.0002 on every cable (an independent recording gave them back so).
    Drum scales on a few cables only, or far from the similarity's scale, are no tracker."""
    model = rocaspect()
    sigma, station = 2e-4, np.array([-4.0, -3.0, 1.2])
    d = sigma * (model.exits - station)
    drums = {f"s_{c}": 1.0 + sigma + 1e-5 * (-1) ** k for k, c in enumerate(model.cable_ids)}
    got = frame_motion(model, _params(model, d), drums)
    assert got is not None and abs(got["scale"] - sigma) < 2e-5
    assert "length scale" in sentence(got)
    assert frame_motion(model, _params(model, d)) is None  # no drums: a scale is no motion
    few = dict(list(drums.items())[:3])
    assert frame_motion(model, _params(model, d), few) is None
    far = {k: 1.0 + 3 * sigma for k in drums}
    assert frame_motion(model, _params(model, d), far) is None
