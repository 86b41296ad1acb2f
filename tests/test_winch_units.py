"""Winch parameters and counts <-> metres units (controller/winch.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.winch import (
    CABLE_IDS,
    DEFAULT_WINCHES,
    WinchConfigError,
    counts_to_m,
    counts_to_m_rate,
    limits_counts,
    load_winches,
    m_to_counts,
    m_to_counts_rate,
    metres_per_count,
    reference_lengths,
)

W = load_winches()


def test_default_file_describes_eight_winches_in_cable_order():
    assert W.cables == CABLE_IDS
    assert list(W.node_id) == [1, 2, 3, 4, 5, 6, 7, 8]
    assert W.source == str(DEFAULT_WINCHES)
    assert set(W.direction.tolist()) == {1, -1}
    assert W.bus.sync_period_us == 4000 and W.bus.heartbeat_ms == 100


def test_metres_per_count_from_drum_gear_and_encoder():
    expected = 2 * math.pi * 0.06 / (12.0 * 65536)
    np.testing.assert_allclose(metres_per_count(W), expected, rtol=1e-15)
    assert W.axis(3).metres_per_count == pytest.approx(expected, rel=1e-15)


def test_direction_sets_the_sign_of_counts():
    c = m_to_counts(np.full(8, 10.0), W)
    assert np.all(np.sign(c) == W.direction)
    assert abs(int(c[0])) == round(10.0 / metres_per_count(W)[0])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.5, 30.0), min_size=8, max_size=8))
def test_round_trip_metres_counts_metres_within_half_a_count(lengths):
    x = np.array(lengths)
    back = counts_to_m(m_to_counts(x, W), W)
    assert np.all(np.abs(back - x) <= 0.5 * metres_per_count(W) + 1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(-60_000_000, 60_000_000), min_size=8, max_size=8))
def test_round_trip_counts_metres_counts_exact(counts):
    c = np.array(counts, dtype=np.int64)
    np.testing.assert_array_equal(m_to_counts(counts_to_m(c, W), W), c)


def test_vectorised_over_leading_axes():
    c = np.arange(24).reshape(3, 8) * 1000
    out = counts_to_m(c, W)
    assert out.shape == (3, 8)
    np.testing.assert_allclose(out[2], counts_to_m(c[2], W))


def test_rates_are_magnitudes_and_signed_back():
    r = m_to_counts_rate(np.full(8, -1.0), W)
    assert np.all(r > 0)
    np.testing.assert_allclose(r, 1.0 / metres_per_count(W))
    np.testing.assert_allclose(counts_to_m_rate(r, W), W.direction * 1.0)


def test_limits_are_ordered_for_both_directions():
    lo, hi = limits_counts(W)
    assert np.all(lo < hi)
    np.testing.assert_allclose(np.sort(counts_to_m(np.stack([lo, hi]), W), axis=0),
                               np.stack([W.min_length_m, W.max_length_m]),
                               atol=metres_per_count(W)[0])


def test_reference_lengths_makes_counts_read_the_given_lengths():
    counts = np.array([100, -200, 300, -400, 500, -600, 700, -800]) * 10_000
    lengths = np.linspace(8.0, 15.0, 8)
    w2 = reference_lengths(W, counts, lengths)
    np.testing.assert_allclose(counts_to_m(counts, w2), lengths, atol=1e-12)
    assert W.length_at_zero_m[0] == 0.0  # the original is unchanged


def _doc(**winch_overrides):
    doc = {
        "bus": {"sync_period_s": 0.004},
        "defaults": {
            "gear_ratio": 10.0, "drum_radius_m": 0.05, "encoder_counts_per_rev": 4096,
            "direction": 1, "length_at_zero_m": 0.0, "min_length_m": 0.5, "max_length_m": 20.0,
            "max_speed_m_s": 1.0, "max_accel_m_s2": 2.0, "profile_speed_m_s": 0.5,
            "profile_accel_m_s2": 1.0, "quick_stop_decel_m_s2": 3.0, "following_error_m": 0.01,
            "following_error_time_s": 0.01, "position_window_m": 0.001,
            "quick_stop_option": 2, "fault_reaction_option": 0, "lag_time_constant_s": 0.0,
            "rated_torque_nm": 1.0,
        },
        "winch": [{"cable": c, "node_id": k + 1} for k, c in enumerate(CABLE_IDS)],
    }
    doc["winch"][2].update(winch_overrides)
    return doc


def test_parse_minimal_document():
    from controller.winch import parse_winches

    w = parse_winches(_doc(), "mem.toml")
    assert len(w) == 8 and w.encoder_counts_per_rev.dtype == np.int64


@pytest.mark.parametrize(
    ("override", "needle"),
    [
        ({"gear_ratio": -1.0}, "gear_ratio"),
        ({"direction": 0}, "must be 1 or -1"),
        ({"node_id": 0}, "node_id"),
        ({"node_id": 2}, "used by more than one winch"),
        ({"drum_radius_m": "big"}, "must be a number"),
        ({"encoder_counts_per_rev": 4096.5}, "integer"),
        ({"min_length_m": 25.0}, "must be < max_length_m"),
        ({"colour": "red"}, "unknown key"),
        ({"cable": "99"}, "expected '21'"),
        ({"quick_stop_option": 9}, "0x605A"),
        ({"drum_radius_m": 1e-6}, "INTEGER32"),
        ({"profile_speed_m_s": 2.0}, "must not exceed max_speed_m_s"),
    ],
)
def test_errors_name_the_file_and_the_field(override, needle):
    from controller.winch import parse_winches

    with pytest.raises(WinchConfigError) as exc:
        parse_winches(_doc(**override), "mem.toml")
    msg = str(exc.value)
    assert msg.startswith("mem.toml: ")
    assert needle in msg
    if override.get("cable") is None and "node_id" not in override:
        assert "'21'" in msg or "node 3" in msg or "#3" in msg


def test_bus_errors_name_the_key():
    from controller.winch import parse_winches

    doc = _doc()
    doc["bus"] = {"bitrate": 333_000}
    with pytest.raises(WinchConfigError, match=r"mem.toml: \[bus\] bitrate"):
        parse_winches(doc, "mem.toml")
    doc["bus"] = {"sync_period_s": 0.0040005}
    with pytest.raises(WinchConfigError, match="whole number of microseconds"):
        parse_winches(doc, "mem.toml")


def test_toml_syntax_error_names_file_and_line(tmp_path):
    p = tmp_path / "w.toml"
    p.write_text("[bus]\nbitrate = = 5\n")
    with pytest.raises(WinchConfigError, match=r"w.toml: TOML syntax error.*line 2"):
        load_winches(p)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(WinchConfigError, match="cannot read"):
        load_winches(tmp_path / "nope.toml")


def test_replace_broadcasts_and_revalidates():
    w2 = W.replace(following_error_m=0.05)
    assert np.all(w2.following_error_m == 0.05)
    with pytest.raises(WinchConfigError):
        W.replace(gear_ratio=np.array([1, 1, 1, -1, 1, 1, 1, 1.0]))
