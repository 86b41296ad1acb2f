"""The catenary near its straight limit: a cable whose weight is small against its tension."""

from __future__ import annotations

import numpy as np

from controller import catenary


def test_a_light_cable_converges_to_the_straight_cable():
    rng = np.random.default_rng(3)
    h = rng.uniform(1.0, 20.0, 200)
    v = rng.uniform(-5.0, 10.0, 200)
    T = rng.uniform(50.0, 3000.0, 200)
    inv_ea = np.full(200, 1.0 / 1.2e6)
    for w in (5.6e-6, 1e-9):
        L0, H, VB, ok = catenary.unstretched(h, v, T, inv_ea, w)
        assert ok.all()  # Newton reaches its tolerance (no cancellation floor)
        d = np.hypot(h, v)
        np.testing.assert_allclose(L0, d / (1.0 + T * inv_ea), rtol=1e-6)
        hh, vv = catenary.spans(H, VB, L0, inv_ea, w)
        np.testing.assert_allclose(hh, h, rtol=0, atol=1e-10 * d.max())
        np.testing.assert_allclose(vv, v, rtol=0, atol=1e-10 * d.max())


def test_the_span_derivatives_match_differences_for_light_and_heavy_cables():
    rng = np.random.default_rng(4)
    H = rng.uniform(10.0, 1000.0, 100)
    VB = rng.uniform(-300.0, 300.0, 100)
    L0 = rng.uniform(1.0, 20.0, 100)
    inv_ea = np.full(100, 1e-6)
    for w in (3.0, 1e-6):
        f = catenary.flexibility(H, VB, L0, inv_ea, w)
        for k, (dH, dV, dL) in enumerate([(1e-3 * H, 0, 0), (0, 1e-3 * H, 0), (0, 0, 1e-6 * L0)]):
            hp, vp = catenary.spans(H + dH, VB + dV, L0 + dL, inv_ea, w)
            hm, vm = catenary.spans(H - dH, VB - dV, L0 - dL, inv_ea, w)
            step = dH + dV + dL
            an = [(f[0], f[2]), (f[1], f[3]), (f[4], f[5])][k]
            np.testing.assert_allclose((hp - hm) / (2 * step), an[0], rtol=1e-4,
                                       atol=1e-9 * np.abs(an[0]).max())
            np.testing.assert_allclose((vp - vm) / (2 * step), an[1], rtol=1e-4,
                                       atol=1e-9 * np.abs(an[1]).max())
