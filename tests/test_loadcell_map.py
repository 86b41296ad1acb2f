"""Register map of the load cells: encoding, the shipped table, parse errors."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.loadcell_map import (
    CABLE_IDS,
    DEFAULT_MAP,
    RegisterMap,
    RegisterMapError,
    load_register_map,
    parse_register_map,
)

SHIPPED = Path(__file__).resolve().parents[1] / "firmware_sim" / "data" / "loadcell_registers.toml"


def test_shipped_table_is_the_default_map():
    m = load_register_map(SHIPPED)
    assert m == DEFAULT_MAP
    assert m.unit_ids == (1, 2, 3, 4, 5, 6, 7, 8)
    assert m.cables == CABLE_IDS
    assert (m.block_start, m.block_count) == (0, 4)


def test_unit_and_cable_lookup():
    m = DEFAULT_MAP
    assert [m.unit_of(c) for c in CABLE_IDS] == list(range(1, 9))
    assert m.cable_of(3) == "21"
    assert m.index_of("42") == 7 and m.index_of(8) == 7
    assert m.describe(2) == "Modbus unit 3 (cable 21)"
    with pytest.raises(KeyError, match="unit 9"):
        m.cable_of(9)
    with pytest.raises(KeyError, match="'51'"):
        m.index_of("51")


def test_encoding_matches_the_documented_layout():
    # 100.5 N = 0x42C90000 as float32: high word first in register 0
    regs = DEFAULT_MAP.encode(100.5, 3, 70000)
    assert regs.tolist() == [0x42C9, 0x0000, 3, 70000 % 65536]
    little = RegisterMap(word_order="little").encode(100.5, 0, 1)
    assert little.tolist() == [0x0000, 0x42C9, 0, 1]


@given(
    st.lists(st.floats(width=32, allow_nan=True, allow_infinity=True), min_size=8, max_size=8),
    st.lists(st.integers(0, 0xFFFF), min_size=8, max_size=8),
    st.lists(st.integers(0, 10**6), min_size=8, max_size=8),
    st.sampled_from(["big", "little"]),
)
def test_encode_decode_round_trip(values, status, counter, order):
    m = RegisterMap(word_order=order)
    regs = m.encode(np.array(values), np.array(status), np.array(counter))
    assert regs.shape == (8, 4) and regs.dtype == np.uint16
    v, s, c = m.decode(regs)
    expect = np.array(values, dtype=np.float32).astype(np.float64)
    np.testing.assert_array_equal(v, expect)  # NaN == NaN here
    assert s.tolist() == status
    assert c.tolist() == [x % 65536 for x in counter]
    # and it is the IEEE-754 big-endian float32 of the Modbus convention
    for k in range(8):
        hi, lo = (regs[k, 0], regs[k, 1]) if order == "big" else (regs[k, 1], regs[k, 0])
        raw = struct.unpack(">f", struct.pack(">HH", hi, lo))[0]
        assert raw == expect[k] or (np.isnan(raw) and np.isnan(expect[k]))


def test_decode_rejects_wrong_block_length():
    with pytest.raises(ValueError, match="expected 4 registers"):
        DEFAULT_MAP.decode(np.zeros(3, dtype=int))


def _table() -> dict:
    return {
        "format": "cdpr-loadcell-map/1",
        "registers": {
            "tension": {"address": 10, "count": 2, "type": "float32"},
            "status": {"address": 12},
            "counter": {"address": 13},
        },
        "device": [{"unit_id": 20 + k, "cable": c} for k, c in enumerate(CABLE_IDS)],
    }


def test_parse_custom_map():
    m = parse_register_map(_table(), "custom.toml")
    assert m.unit_ids == tuple(range(20, 28))
    assert (m.block_start, m.block_count) == (10, 4)
    assert m.unit_of("21") == 22


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (
            lambda d: d["device"][2].update(unit_id=20),
            r"device\[2\]\.unit_id: unit id 20 used twice",
        ),
        (
            lambda d: d["device"][3].update(cable="11"),
            r"device\[3\]\.cable: cable 11 mapped twice",
        ),
        (lambda d: d["device"][1].update(unit_id=300), r"device\[1\]\.unit_id: 300 outside"),
        (lambda d: d["device"].reverse(), r"device: devices must be listed in cable id order"),
        (
            lambda d: d["registers"]["status"].update(address=11),
            r"registers\.status\.address: overlaps",
        ),
        (lambda d: d["registers"]["tension"].update(type="int32"), r"registers\.tension\.type"),
        (lambda d: d["registers"].pop("counter"), r"registers\.counter: missing"),
        (lambda d: d.update(word_order="middle"), r"word_order"),
        (lambda d: d.update(colour="red"), r"top level: unknown key\(s\) \['colour'\]"),
        (
            lambda d: d.update(sensor={"rated_min_N": 10.0, "rated_max_N": 5.0}),
            r"sensor: rated_min_N",
        ),
        (
            lambda d: d.update(status_bits={"overload": 1, "sensor_fault": 1}),
            r"status_bits: .*same bit",
        ),
    ],
)
def test_parse_errors_name_the_file_and_field(mutate, match):
    d = _table()
    mutate(d)
    with pytest.raises(RegisterMapError, match=r"^bad\.toml: " + match):
        parse_register_map(d, "bad.toml")


def test_toml_syntax_error_names_file_and_line(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text('format = "cdpr-loadcell-map/1"\nword_order = \n')
    with pytest.raises(RegisterMapError, match=r"broken\.toml: .*line 2"):
        load_register_map(p)
