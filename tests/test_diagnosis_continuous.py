"""What a continuous (dry-run) recording without load cells holds that dwell campaigns rarely
do, and what the diagnosis must make of it: the platform hanging on fewer cables than the
balance leaves free (more than ``n - 6`` slack), and replicate groups that a slip splits
apart (the noise estimated again without them)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnosis.residuals import DEFAULTS, ResidualModel
from bench.diagnosis.samples import Samples
from controller.cycle import LengthController
from controller.robot import resolve_robot
from firmware_sim.plant import Plant


def _samples(poses: np.ndarray, lengths: np.ndarray, t: np.ndarray,
             target: np.ndarray | None = None) -> Samples:
    N, n = lengths.shape
    return Samples(t, poses.copy(), poses.copy(), lengths, np.full((N, n), np.nan),
                   np.full((N, n, 3), np.nan), np.ones(N, dtype=int),
                   np.arange(N) if target is None else target, t <= 0.0)


@pytest.fixture(scope="module")
def three_slack():
    """CoGiRo at rest with cables 22, 41 and 42 paid out by 10 cm: it hangs on five cables
    (three slack, one more than the balance of eight cables can hold at zero)."""
    model = resolve_robot("cogiro")
    p0 = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    l0 = LengthController(model, p0, init_tensions=None).step(p0, None).lengths
    slack = [model.cable_ids.index(c) for c in ("22", "41", "42")]
    l1 = l0.copy()
    l1[slack] += 0.1
    st = Plant(model, model, p0).settle(l1, t=10.0, guess=p0)
    assert np.sum(st.tensions < 1e-6) == 3 and np.all(np.delete(st.tensions, slack) > 1.0)
    s = _samples(np.array([p0, st.pose]), np.array([l0, l1]), np.array([0.0, 10.0]))
    return model, p0, s, slack


def test_a_platform_hanging_on_five_of_eight_cables_is_explained_by_its_model(three_slack):
    model, p0, s, slack = three_slack
    b = ResidualModel(s, model, p0, None).blocks(model)
    assert b.ok.all()
    # every cable within micrometres: the three slack ones one-sided (read longer than
    # their line: no cost), none of them a taut cable with a tension of round-off
    assert np.abs(b.length[1]).max() < 2e-5
    assert b.slack[1, slack].all() and not np.delete(b.slack[1], slack).any()


def test_a_taut_cable_s_error_shows_beside_three_slack_ones(three_slack):
    # the one-sided reading of the slack cables hides nothing of the taut ones: a hypothesis
    # with a 2 mm length offset on a taut cable leaves it (as least squares spread it over
    # the six directions the balance leaves: most of it)
    model, p0, s, slack = three_slack
    k = model.cable_ids.index("11")
    dl = np.zeros(model.n_cables)
    dl[k] = 2e-3
    H = model.replace(length_offset=dl)
    b = ResidualModel(s, model, p0, None).blocks(H)
    taut = np.delete(np.arange(model.n_cables), slack)
    assert np.abs(b.length[1, taut]).max() > 5e-4


def test_noise_estimated_again_without_replicates_falls_back_to_the_defaults():
    # two visits of each pose, the second one after a 5 mm slip of cable 11: the first
    # estimate (visits of a pose together) takes the slip for noise; split at the slip there
    # are no replicates left, and the noise is the declared default, not the slip's spread
    model = resolve_robot("cogiro")
    p0 = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    ctl = LengthController(model, p0, init_tensions=None)
    poses = np.array([p0] + [p0 + [dx, dy, 0.0, 0.0, 0.0, 0.0]
                             for dx, dy in ((0.5, 0.0), (0.0, 0.5), (-0.5, 0.3))] * 2)
    lengths = np.array([ctl.step(p, None).lengths for p in poses])
    t = np.arange(len(poses), dtype=float) * 10.0
    late = t > 35.0
    lengths[late, 0] += 5e-3
    target = np.array([0, 1, 2, 3, 1, 2, 3])
    s = _samples(poses, lengths, t, target)
    rm = ResidualModel(s, model, p0, None)
    rm.estimate_noise(model)
    assert rm.sigma_source == "replicate visits" and rm.sigma["length"] > 1e-3
    rm.estimate_noise(model, groups=target * 2 + late)
    assert rm.sigma_source.startswith("defaults")
    assert rm.sigma["length"] == pytest.approx(DEFAULTS["length"])
    assert rm.replicate_dof == 0
