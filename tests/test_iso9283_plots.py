"""Plots like the paper's Fig. 6 and Fig. 7 from plain arrays and dicts."""

from __future__ import annotations

import numpy as np
import pytest

from bench.iso9283.analysis import path_run
from bench.iso9283.figures import path_figures, pose_figures, resample_path
from bench.iso9283.plots import plot_path_cases, plot_pose_bars, plot_pose_scatter, safe_name

PNG = b"\x89PNG\r\n\x1a\n"


def desired_path():
    """A rectangle in the YZ plane at x = 10 m (like the paper's paths)."""
    c = np.array([[10, 6, 1.0], [10, 11, 1.0], [10, 11, 1.8], [10, 6, 1.8], [10, 6, 1.0]])
    pts = np.vstack([a + (b - a) * u[:, None] for a, b in zip(c[:-1], c[1:], strict=True)
                     for u in [np.linspace(0, 1, 40, endpoint=False)]] + [c[-1:]])
    return resample_path(pts, 200)


def test_fig7_like_cases_with_three_models(tmp_path):
    s, cmd = desired_path()
    cases = []
    for name, scale in (("centre path, centre init", 1.0), ("side path, centre init", 3.0)):
        runs = {}
        for model, gain in (("nominal", 1.0), ("compliant", 0.2), ("diagnosed", 0.25)):
            att = cmd[:, :3] + scale * gain * np.c_[0.02 * np.ones(len(s)),
                                                   0.01 * np.sin(s), 0.04 * np.cos(s / 2)]
            f = path_figures(cmd, [att], s=s)
            runs[model] = path_run(f, executed=att)
        cases.append({"title": name, "desired_m": cmd[:, :3], "runs": runs})
    out = plot_path_cases(cases, tmp_path / "fig7.png", "Fig. 7-like")
    assert out.read_bytes()[:8] == PNG and out.stat().st_size > 20_000


def test_fig7_rejects_a_bad_plane_and_nothing(tmp_path):
    with pytest.raises(ValueError, match="plane"):
        plot_path_cases([{"desired_m": np.zeros((2, 3)), "runs": {}}], tmp_path / "x.png",
                        plane="yy")
    with pytest.raises(ValueError):
        plot_path_cases([], tmp_path / "x.png")


def test_fig6_like_bars_from_figures_and_json_dicts(tmp_path):
    rng = np.random.default_rng(3)
    runs = []
    for pose_set, colour in (("V", "purple"), ("P", "deeppink"), ("G", "goldenrod")):
        for model in ("N", "R"):
            for v in (10, 40, 100):
                att = rng.normal(0, 2e-3, (30, 6)) + [0.02, -0.01, 0.03, 0.01, 0, 0.02]
                d = pose_figures(att, np.zeros(6)).to_dict()
                runs.append(dict(d, label=f"{pose_set}{model}{v}", color=colour))
    runs[0]["ap_a_rad"] = None  # a missing value: no bar, no error
    out = plot_pose_bars(runs, tmp_path / "fig6.png")
    assert out.read_bytes()[:8] == PNG
    # positions only: the orientation panels are left out
    out = plot_pose_bars([{"label": "a", "ap_m": 0.01, "rp_m": 0.001}], tmp_path / "p.png")
    assert out.read_bytes()[:8] == PNG
    with pytest.raises(ValueError, match="no figure"):
        plot_pose_bars([{"label": "a"}], tmp_path / "n.png")


def test_pose_scatter(tmp_path):
    att = np.random.default_rng(0).normal(0, 1e-3, (10, 3)) + [10, 8, 1]
    out = plot_pose_scatter([{"label": "P1", "command": [10, 8, 1], "attained": att,
                              "rp_m": 0.003}], tmp_path / "s.png")
    assert out.read_bytes()[:8] == PNG


def test_safe_name():
    assert safe_name("side path / centre init") == "side_path_centre_init"
    assert safe_name("///") == "run"
