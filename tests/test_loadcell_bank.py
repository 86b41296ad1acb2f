"""Simulated load cells without the network: samples, registers, injected faults."""

from __future__ import annotations

import numpy as np
import pytest

from controller.loadcell_map import DEFAULT_MAP
from firmware_sim.loadcell_bank import (
    DEVICE_FAILURE,
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    CellFault,
    LoadCellBank,
    default_register_map,
)

T = np.array([100.1, 200.2, 300.3, 1.5, 0.0, -3.25, 2999.9, 42.0])


def decode(bank: LoadCellBank):
    return DEFAULT_MAP.decode(bank.registers())


def test_shipped_map_is_used_by_default():
    assert default_register_map() == DEFAULT_MAP
    assert LoadCellBank().map == DEFAULT_MAP


def test_update_gives_float32_values_and_advancing_counters():
    bank = LoadCellBank()
    for i in range(1, 4):
        bank.update(T + i)
        v, s, c = decode(bank)
        np.testing.assert_array_equal(v, (T + i).astype(np.float32))
        assert s.tolist() == [0] * 8
        assert c.tolist() == [i] * 8


def test_counter_wraps_at_65536():
    bank = LoadCellBank(counter_start=65534)
    seen = []
    for _ in range(4):
        bank.update(T)
        seen.append(int(decode(bank)[2][0]))
    assert seen == [65535, 0, 1, 2]


def test_gain_and_offset_error_of_the_cells():
    gain = np.linspace(0.95, 1.05, 8)
    offset = np.linspace(-5, 5, 8)
    bank = LoadCellBank(gain=gain, offset_N=offset)
    bank.update(T)
    np.testing.assert_array_equal(decode(bank)[0], (gain * T + offset).astype(np.float32))


def test_wrong_shape_is_refused():
    with pytest.raises(ValueError, match="expected 8 tensions"):
        LoadCellBank().update(T[:7])


def test_overload_bit_follows_the_rated_range():
    bank = LoadCellBank()
    t = T.copy()
    t[1] = 5000.5  # above rated_max_N
    t[2] = -600.0  # below rated_min_N
    bank.update(t)
    v, s, _ = decode(bank)
    assert s.tolist() == [0, 1, 1, 0, 0, 0, 0, 0]
    assert v[1] == np.float32(5000.5)


def test_stale_freezes_value_and_counter_of_that_cell_only():
    bank = LoadCellBank()
    bank.update(T)
    bank.inject("21", "stale")
    bank.update(T + 1)
    bank.update(T + 2)
    v, _, c = decode(bank)
    assert c.tolist() == [3, 3, 1, 3, 3, 3, 3, 3]
    assert v[2] == np.float32(T[2]) and v[0] == np.float32(T[0] + 2)
    bank.clear("21")
    bank.update(T + 3)
    assert decode(bank)[2].tolist() == [4, 4, 2, 4, 4, 4, 4, 4]


def test_value_faults_show_in_the_registers():
    bank = LoadCellBank()
    bank.inject(6, CellFault.OUT_OF_RANGE)  # by unit id: cable 32
    bank.inject("41", "nan")
    bank.inject("42", "sensor_fault")
    bank.inject("11", "out_of_range", value_N=-1000.0)
    bank.update(T)
    v, s, _ = decode(bank)
    assert v[5] == pytest.approx(1.2 * DEFAULT_MAP.rated_max_N) and s[5] == 0b01
    assert v[0] == -1000.0 and s[0] == 0b01
    assert np.isnan(v[6]) and s[6] == 0
    assert v[7] == np.float32(T[7]) and s[7] == 0b10
    assert bank.faults() == {
        "11": ["out_of_range"], "32": ["out_of_range"], "41": ["nan"], "42": ["sensor_fault"],
    }
    bank.clear()
    assert bank.faults() == {}
    assert decode(bank)[1].tolist() == [0] * 8


def test_out_of_range_value_must_be_outside_the_range():
    with pytest.raises(ValueError, match="inside the rated range"):
        LoadCellBank().inject("11", "out_of_range", value_N=100.0)


def test_unknown_fault_and_cell_are_refused():
    bank = LoadCellBank()
    with pytest.raises(ValueError):
        bank.inject("11", "smoke")
    with pytest.raises(KeyError, match="unit 9"):
        bank.inject(9, "stale")
    with pytest.raises(ValueError, match="exception code"):
        bank.inject("11", "exception", exception_code=0x09)


def test_respond_answers_like_a_modbus_device():
    bank = LoadCellBank()
    bank.update(T)
    r = bank.respond(3, 0x04, 0, 4)
    assert r.registers == bank.registers()[2].tolist()
    assert bank.respond(3, 0x04, 2, 2).registers == bank.registers()[2][2:].tolist()
    assert bank.respond(3, 0x03, 0, 4).exception_code == ILLEGAL_FUNCTION
    assert bank.respond(3, 0x04, 3, 2).exception_code == ILLEGAL_ADDRESS
    assert bank.respond(9, 0x04, 0, 4).silent  # nobody with that id
    bank.inject("22", "exception")
    assert bank.respond(4, 0x04, 0, 4).exception_code == DEVICE_FAILURE
    bank.inject("22", "exception", exception_code=0x06)
    assert bank.respond(4, 0x04, 0, 4).exception_code == 0x06
    bank.inject("31", "no_answer")
    assert bank.respond(5, 0x04, 0, 4).silent
    # the others are unaffected
    assert bank.respond(1, 0x04, 0, 4).registers == bank.registers()[0].tolist()
