"""The load cells' friction through the stretch (bench/diagnosis/probes.py
``friction_column``): a cell reading biased by the direction of its cable's last move
misreads the stretch the residual model computes from it, by ``f L / EA``; the probe column
that lets a found friction put a named effect (a tracker's latency) in question."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.diagnosis import probes
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.recording import Recording
from controller.robot import resolve_robot
from controller.statics import pose_statics

P0 = np.array([0.388, 1.252, 2.663, 0.0, 0.0, 0.0])
ENDS = (np.array([1.5, -0.5, 2.6, 0.0, 0.0, 0.0]), np.array([-1.0, 1.0, 2.7, 0.0, 0.0, 0.0]))


def _rm(ea: float | None = None) -> ResidualModel:
    """20 Hz rows of the IPAnema-class robot (E*A ``ea`` when given) standing at P0, moving
    to two targets and back at 0.3 m/s, with 2 s dwells: encoders and load cells only."""
    robot = resolve_robot("ipanema")
    if ea is not None:
        robot = robot.replace(ea=np.full(robot.n_cables, ea))
    pts = [P0, ENDS[0], P0, ENDS[1], P0]
    poses = [np.tile(P0, (40, 1))]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        k = max(int(np.linalg.norm(b[:3] - a[:3]) / 0.3 * 20), 2)
        poses.append(a + np.linspace(0, 1, k)[1:, None] * (b - a))
        poses.append(np.tile(b, (40, 1)))
    poses = np.vstack(poses)
    t = np.arange(len(poses)) * 0.05
    ps = [pose_statics(robot, p) for p in poses]
    N, n = len(t), robot.n_cables
    nan = np.full((N, 6), np.nan)
    rec = Recording(Path("."), robot, {}, P0, t, nan, nan.copy(), np.full((N, n), np.nan),
                    np.array([q.unstretched for q in ps]), np.array([q.tensions for q in ps]),
                    np.full((N, n, 3), np.nan), init_rows=np.arange(40))
    s = prepare(rec)
    return ResidualModel(s, robot, rec.init_pose, rec.init_tensions, rows=s.triples)


def test_column_is_the_stretch_of_a_reading_biased_by_direction():
    rm = _rm()
    s, model = rm.s, rm.model
    name, cable, x = probes.friction_column(rm, ["11", "22"])
    assert (name, cable) == ("cell_friction", None)
    on = [model.cable_ids.index(c) for c in ("11", "22")]
    off = [k for k in range(model.n_cables) if k not in on]
    assert not np.any(x[:, off])
    assert not np.any(x[s.is_init])
    after = ~s.is_init
    want = 0.5 * np.sign(s.direction[:, on]) * np.abs(s.l_meas[:, on]) / model.ea[on]
    assert np.allclose(x[after][:, on], want[after])
    # both directions are in the column (a friction, not an offset)
    assert (x[:, on] > 0).any() and (x[:, on] < 0).any()


def test_no_column_where_no_stretch_is_computed():
    # inextensible cables: the readings' friction misreads no stretch; no cell found: none
    assert probes.friction_column(_rm(ea=np.inf), ["11"]) is None
    assert probes.friction_column(_rm(), []) is None
