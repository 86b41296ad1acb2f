"""The diagnosis's residual map reads right at a glance (``bench.diagnosis.plots``)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.quiver import Quiver, QuiverKey  # noqa: E402

from bench.diagnosis.plots import _key_length, residual_map  # noqa: E402


def _map(before_mm: float, after_mm: float):
    rng = np.random.default_rng(3)
    pos = np.column_stack([rng.uniform(3, 17, 40), rng.uniform(2, 15, 40), np.ones(40)])
    exits = np.array([[0, 0, 4], [21, 0, 4], [21, 17, 4], [0, 17, 4.0]])
    before = rng.normal(0, before_mm, (40, 3))
    after = rng.normal(0, after_mm, (40, 3))
    fig = residual_map([before, after], pos, exits, np.array([2.0, 8.5, 1.0]), plt)
    quivers = [[c for c in ax.collections if isinstance(c, Quiver)] for ax in fig.axes[:2]]
    keys = [{id(a) for a in ax.get_children() if isinstance(a, QuiverKey)}
            for ax in fig.axes[:2]]
    return fig, before, after, pos, exits, [q[0] for q in quivers], keys


def test_both_panels_share_one_arrow_scale_and_one_colour_scale():
    fig, before, after, pos, exits, (q0, q1), keys = _map(40.0, 0.3)
    assert q0.scale == q1.scale and q0.scale_units == q1.scale_units == "xy"
    assert q0.get_clim() == q1.get_clim()
    assert all(len(k) == 1 for k in keys), "one key arrow per panel"
    plt.close(fig)


def test_the_largest_error_is_drawn_visibly_and_the_small_one_at_the_same_scale():
    """The largest xy error is an eighth of the plotted extent (workspace and exit points),
    not a dot; the corrected panel's arrows are shorter by the errors' ratio."""
    fig, before, after, pos, exits, (q0, q1), _ = _map(40.0, 0.3)
    extent = np.ptp(np.vstack([pos[:, :2], exits[:, :2]]), axis=0).max()
    longest = np.linalg.norm(before[:, :2], axis=1).max() / q0.scale  # metres of plot
    assert 0.1 * extent < longest < 0.2 * extent
    ratio = np.linalg.norm(after[:, :2], axis=1).max() / np.linalg.norm(before[:, :2],
                                                                         axis=1).max()
    assert ratio < 0.05  # and drawn as such: the same scale, not rescaled per panel
    plt.close(fig)


def test_key_length_is_a_round_number_below_the_largest_error():
    for top, want in ((80.0, 20.0), (38.0, 10.0), (0.9, 0.2), (12.0, 5.0), (3.0, 1.0)):
        assert _key_length(top) == want, top
    assert _key_length(0.0) == 1.0 and _key_length(float("nan")) == 1.0
