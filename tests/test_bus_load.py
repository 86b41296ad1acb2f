"""CAN bus time of the winch cycle and the SYNC rate it allows (hal/bus_load.py)."""

from __future__ import annotations

import pytest

from hal.bus_load import CycleConfig, frame_bits


def test_frame_bits_worst_case_stuffing_standard_id():
    # 8n + 47 + floor((34 + 8n - 1) / 4)
    assert frame_bits(0) == 55  # SYNC
    assert frame_bits(1) == 65  # heartbeat
    assert frame_bits(6) == 115  # 6-byte PDO
    assert frame_bits(8) == 135


def test_frame_bits_without_stuffing_and_extended():
    assert frame_bits(8, stuffing=False) == 64 + 47
    assert frame_bits(0, extended=True) == 54 + 13 + 13
    with pytest.raises(ValueError, match="0..8"):
        frame_bits(9)


def test_eight_drives_six_byte_pdos_at_1_mbit_take_1_9_ms():
    cfg = CycleConfig()
    assert cfg.cycle_bits() == 16 * 115 + 55
    assert cfg.cycle_time_s() == pytest.approx(1.9e-3, abs=0.01e-3)


def test_fifty_percent_load_allows_about_250_hz():
    cfg = CycleConfig()
    f = cfg.max_sync_rate_hz(0.5)
    assert 240.0 < f < 270.0
    assert cfg.load(f) == pytest.approx(0.5)
    assert cfg.load(250.0) < 0.5 < cfg.load(300.0)


def test_heartbeats_and_slower_bus_lower_the_rate():
    base = CycleConfig().max_sync_rate_hz(0.5)
    with_hb = CycleConfig(heartbeat_period_s=0.01).max_sync_rate_hz(0.5)
    assert with_hb < base
    assert CycleConfig(bitrate=500_000).max_sync_rate_hz(0.5) == pytest.approx(base / 2)
    with pytest.raises(ValueError):
        CycleConfig().max_sync_rate_hz(0.0)
