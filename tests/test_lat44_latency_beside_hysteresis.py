"""The tracker's latency estimated beside the winches' hysteresis.

While the platform moves at a steady speed, a tracker ``dt`` late changes each cable's length
residual by ``dt`` times its length rate, and hysteresis by half its size with the sign of
that rate: the same sign on every row of a move. Held at zero in the fit, the hysteresis went
into the latency, always toward a shorter one (the coverage test's misses were all low). The
report frees it beside the latency (:func:`bench.diagnosis.frame.latency_beside_direction`).
"""

from __future__ import annotations

import pytest

from bench.campaign import campaign_plant, run_campaign
from bench.diagnosis import frame
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread
from firmware_sim.scenario import parse_scenario
from tests.test_diagnose_kinds import scenario

#: [s] the concealed latency
DT = 0.06
#: one continuous loop around a wide rectangle at 10 Hz (long moves: a latency known to
#: about 0.2 ms, where 0.2 mm of hysteresis held at zero moved it 0.3 ms low)
LOOP = {"kind": "list", "visits": 1, "speed_m_s": 0.4, "init_s": 2.0,
        "list": [[4.0, 4.0, 1.26, 0, 0, 0], [16.0, 4.0, 1.26, 0, 0, 0],
                 [16.0, 13.0, 1.26, 0, 0, 0], [4.0, 13.0, 1.26, 0, 0, 0]]}
CONTINUOUS = {"kind": "continuous", "dwell_at_targets": False, "rate_hz": 10.0}
NOISE = {"tracker_m": 1.5e-5, "tracker_rad": 1e-5, "process_m": 1e-4}


@pytest.fixture(scope="module", autouse=True)
def _one_blas_thread():
    one_blas_thread()


def _recording(tmp_path, hysteresis_m: float, seed: int):
    """A continuous recording of a tracker ``DT`` late with ``hysteresis_m`` on every winch
    (the plant's predicted rests, as the coverage test records)."""
    sc_map = scenario(truth={"tracker_latency": {"dt": DT}}, poses=LOOP, recording=CONTINUOUS,
                      nuisance={"hysteresis_m": hysteresis_m}, seed=seed) | {"noise": NOISE}
    sc = parse_scenario(sc_map)
    return run_campaign(sc, tmp_path / "rec", plant=campaign_plant(sc, predict=True))


def _latency(dg) -> tuple[float, float, list]:
    got = {e["name"]: e for e in dg.report["effects"]}
    assert set(got) == {"tracker_latency"}, dg.report["mismatch"]["summary"]
    e = got["tracker_latency"]
    return e["params"]["dt"], e["stderr"]["dt"], e["interval95"]["dt"]


@pytest.mark.parametrize("seed", [3, 6])
def test_a_lagging_tracker_with_hysteresis_keeps_its_latency_in_the_interval(tmp_path, seed):
    """0.2 mm of hysteresis on every winch beside a tracker 60 ms late: the latency's 95 %
    interval holds the truth and the estimate is within three standard errors of it (held
    at zero, the hysteresis took the estimate 0.3 ms low: 3.4 standard errors, the interval
    0.06 s outside)."""
    dt, se, iv = _latency(diagnose(_recording(tmp_path, 2e-4, seed)))
    assert iv[0] <= DT <= iv[1], (dt, se, iv)
    assert abs(dt - DT) < 3 * se, (dt, se, iv)


def test_without_hysteresis_freeing_it_moves_the_latency_by_little(tmp_path, monkeypatch):
    """No hysteresis: freeing it moves the latency by a fraction of its standard error (the
    column finds nothing to take), and its standard error does not shrink."""
    rec = _recording(tmp_path, 0.0, 4)
    dt, se, iv = _latency(diagnose(rec))
    assert abs(dt - DT) < 3 * se, (dt, se, iv)
    monkeypatch.setattr(frame, "latency_beside_direction", lambda fit, rm, idx: fit)
    dt0, se0, _ = _latency(diagnose(rec))
    assert abs(dt - dt0) < 0.5 * se0, (dt, dt0, se0)
    assert se >= 0.99 * se0, (se, se0)
