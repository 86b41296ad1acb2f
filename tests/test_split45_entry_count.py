"""``ResidualModel.entry_kept`` has one share per entry of the whitened vector: the entries are
counted (``_n_entries``), no longer laid out as a per-entry array only for its length. Checked
on stored recordings of every layout the count has terms for (length entries; the wrench's
six where tensions are measured; an exit point's three), for every sample, index subsets
(repeats included) and a mask."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.recording import read_recording

DATA = Path(__file__).parent / "data" / "recordings"
#: a wrench block (tracker, encoders, load cells), exit points measured (no load cells), and
#: neither (no load cells, no exit points)
RECORDINGS = ("oh3_deployable_mast3_tilted", "oh4_rocaspect_tracker_scale",
              "ipanema_no_tensions_exit_11")


@pytest.mark.parametrize("name", RECORDINGS)
def test_entry_kept_one_share_per_entry(name: str) -> None:
    rec = read_recording(DATA / name)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions)
    rng = np.random.default_rng(45)
    for idx in (None, np.arange(s.n), np.sort(rng.choice(s.n, s.n // 2, replace=False)),
                np.array([0, 0, s.n - 1]), rng.random(s.n) < 0.3):
        size = len(rm.entry_weights(idx))
        assert size > 0
        assert rm._n_entries(idx) == size
        assert len(rm.entry_kept(idx)) == size
