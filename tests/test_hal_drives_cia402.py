"""Pure CiA 402 master logic (hal/drives_cia402.py) and the start-up table (drives_config)."""

from __future__ import annotations

import canopen
import numpy as np
import pytest

from controller.winch import limits_counts, load_winches
from firmware_sim.cia402_drive import EDS_PATH
from hal.drives_cia402 import (
    DriveState,
    Request,
    controlwords,
    decode_states,
    emcy_text,
    enabling,
    faulted,
)
from hal.drives_config import (
    DriveConfigError,
    Setting,
    check_against_eds,
    drive_settings,
    interpolation_period,
    pdo_struct,
)

S = DriveState


@pytest.mark.parametrize(
    ("sw", "state"),
    [
        (0x0000, S.NOT_READY_TO_SWITCH_ON),
        (0x0250, S.SWITCH_ON_DISABLED),  # other bits do not matter
        (0x0231, S.READY_TO_SWITCH_ON),
        (0x0233, S.SWITCHED_ON),
        (0x1237, S.OPERATION_ENABLED),
        (0x0217, S.QUICK_STOP_ACTIVE),
        (0x021F, S.FAULT_REACTION_ACTIVE),
        (0x0208, S.FAULT),
        (0x0228, S.FAULT),  # bit 5 is "x" in Fault
        (0x0001, S.UNKNOWN),  # no CiA 402 pattern
    ],
)
def test_statusword_masks(sw, state):
    assert decode_states(np.array([sw]))[0] == state


def test_decode_is_vectorised_and_honours_validity():
    sw = np.array([0x40, 0x21, 0x23, 0x27, 0x07, 0x0F, 0x08, 0x27])
    got = decode_states(sw, valid=np.array([1, 1, 1, 1, 1, 1, 1, 0], bool))
    assert got.tolist() == [1, 2, 3, 4, 5, 6, 7, S.UNKNOWN]


def test_enable_walks_one_transition_per_cycle():
    states = np.array([S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON,
                       S.OPERATION_ENABLED, S.FAULT, S.UNKNOWN, S.NOT_READY_TO_SWITCH_ON,
                       S.FAULT_REACTION_ACTIVE])
    cw = controlwords(states, np.full(8, Request.ENABLE))
    assert cw.tolist() == [0x06, 0x07, 0x0F, 0x0F, 0x00, 0x00, 0x00, 0x00]
    assert enabling(states, cw).tolist() == [False, False, True, False, False, False, False,
                                             False]


def test_other_requests():
    states = np.arange(9)
    assert set(controlwords(states, np.full(9, Request.OFF)).tolist()) == {0}
    qs = controlwords(states, np.full(9, Request.QUICK_STOP))
    assert qs[S.OPERATION_ENABLED] == 0x02 and qs[S.FAULT] == 0x00
    dis = controlwords(states, np.full(9, Request.DISABLE))
    assert dis[S.OPERATION_ENABLED] == 0x06 and dis[S.QUICK_STOP_ACTIVE] == 0x00
    assert faulted(states).tolist() == [s in (6, 7) for s in range(9)]


def test_emcy_texts():
    assert emcy_text(0x8611) == "following error"
    assert "heartbeat" in emcy_text(0x8130)
    assert emcy_text(0x2399).startswith("current")
    assert emcy_text(0xFF42).startswith("device specific")


def test_interpolation_period_encoding():
    assert interpolation_period(4000) == (4, -3)
    assert interpolation_period(2500) == (25, -4)
    assert interpolation_period(250) == (25, -5)
    with pytest.raises(DriveConfigError):
        interpolation_period(1234567)


def test_startup_table_matches_the_winch_file_and_the_eds():
    w = load_winches()
    od = canopen.import_od(str(EDS_PATH), 4)
    table = drive_settings(w, 3, od)
    check_against_eds(table, od, "node 4")
    final = {(s.index, s.subindex): s.value for s in table}
    lo, hi = limits_counts(w)
    assert final[(0x607D, 1)] == lo[3] and final[(0x607D, 2)] == hi[3]
    assert final[(0x6060, 0)] == 8
    assert final[(0x1600, 1)] == 0x60400010 and final[(0x1600, 2)] == 0x607A0020
    assert final[(0x1A00, 1)] == 0x60410010 and final[(0x1A00, 2)] == 0x60640020
    assert final[(0x1400, 1)] == 0x204 and final[(0x1800, 1)] == 0x184
    assert final[(0x1400, 2)] == 1 and final[(0x1800, 2)] == 1
    assert final[(0x1006, 0)] == 4000 and final[(0x1017, 0)] == 100
    # CiA 301 order: PDO invalid before its mapping is touched, valid again at the end
    idx = [(s.index, s.subindex, s.value) for s in table]
    first_map = next(i for i, s in enumerate(idx) if s[0] == 0x1600)
    assert idx[first_map - 3] == (0x1400, 1, 0x204 | 1 << 31)
    assert pdo_struct(od, ((0x6041, 0), (0x6064, 0))).size == 6


def test_eds_check_rejects_unknown_readonly_and_unmappable():
    od = canopen.import_od(str(EDS_PATH), 1)
    with pytest.raises(DriveConfigError, match="0x6999:00 x: not in the EDS"):
        check_against_eds([Setting(0x6999, 0, 1, "x")], od, "node 1")
    with pytest.raises(DriveConfigError, match="read-only"):
        check_against_eds([Setting(0x6041, 0, 1, "statusword")], od, "node 1")
    with pytest.raises(DriveConfigError, match="not PDO-mappable"):
        check_against_eds([Setting(0x1600, 1, 0x60650020, "map")], od, "node 1")
    with pytest.raises(DriveConfigError, match="does not fit"):
        check_against_eds([Setting(0x6066, 0, 70000, "timeout")], od, "node 1")
