"""Ready-made outsider recordings on the shipped CoGiRo-class robot (rigid frame, no pulleys)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.outsider.campaign import Campaign, feasible_grid
from tests.outsider.logger import Habits, write_recording
from tests.outsider.physics import load_robot

ROBOT_TOML = Path(__file__).resolve().parents[2] / "controller" / "data" / "cogiro.toml"
PRETENSION_N = 600.0
BOX = ((-3.0, -2.5, 1.2), (3.0, 2.5, 3.0), 0.04)


def make_case(out: Path, habits: Habits, *, seed: int, targets: int = 10, passes: int = 2,
              dwell_s: float = 5.0, length_offset: dict | None = None,
              exit_moved: tuple[str, tuple] | None = None,
              slip_at_s: float | None = None) -> Path:
    """Write one recording. Concealed: `length_offset` {cable: dl [m]} (a slip half-way
    through the first move, or at `slip_at_s` [s of the campaign]), `exit_moved` (cable,
    offset [m] in F_b)."""
    rng = np.random.default_rng(seed)
    model = load_robot(ROBOT_TOML)
    true = model if exit_moved is None else model.with_exit_moved(exit_moved[0],
                                                                 np.array(exit_moved[1]))
    grid = feasible_grid(model, rng, PRETENSION_N, targets, BOX)
    camp = Campaign(init_pose=np.array([0.0, 0.0, 2.0, 0.0, 0.0, 0.0]),
                    targets=np.concatenate([grid] * passes), dwell_s=dwell_s)
    offset = np.zeros(len(model.ids))
    for cable, dl in (length_offset or {}).items():
        offset[model.ids.index(cable)] = dl
    return write_recording(out, ROBOT_TOML, model, true, camp, habits,
                           pretension_n=PRETENSION_N, length_offset_m=offset, seed=seed + 1,
                           slip_at_s=slip_at_s)
