"""The long continuous recording of ``cdpr bench --only diagnose_hour`` (bench/benchmarks/
diagnose.py): made here at a minute's length over 3 of its targets, it is a continuous log that
lasts at least that long (the benchmark's hour is the same function with ``HOUR_S``)."""

from __future__ import annotations

import numpy as np

from bench.benchmarks import diagnose as bd
from bench.recording import read_recording


def test_the_long_recording_is_continuous_and_lasts_as_asked(tmp_path, monkeypatch):
    monkeypatch.setattr(bd, "HOUR_S", 60.0)
    rec = read_recording(bd.hour_campaign(tmp_path / "rec", rate_hz=2.0, targets=3))
    t = np.asarray(rec.t, dtype=float)
    assert t[-1] - t[0] >= 60.0
    dt = np.diff(t)
    assert np.all(dt > 0) and abs(float(np.median(dt)) - 0.5) < 1e-6  # no stops: rows at 2 Hz
