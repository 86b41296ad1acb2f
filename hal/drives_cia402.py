"""CiA 402 master logic, vectorised over the drives: statusword decoding, controlwords.

Pure functions on numpy arrays (one entry per drive), used by :mod:`hal.drives` once per
control cycle. No I/O, no waiting: each call looks at the latest statuswords and returns
the controlword that moves every drive one transition toward what is requested.

Statusword masks (CiA 402, bits 0-3, 5, 6)::

    Not ready to switch on   xxxx xxxx x0xx 0000     mask 0x4F value 0x00
    Switch on disabled       xxxx xxxx x1xx 0000     mask 0x4F value 0x40
    Ready to switch on       xxxx xxxx x01x 0001     mask 0x6F value 0x21
    Switched on              xxxx xxxx x01x 0011     mask 0x6F value 0x23
    Operation enabled        xxxx xxxx x01x 0111     mask 0x6F value 0x27
    Quick stop active        xxxx xxxx x00x 0111     mask 0x6F value 0x07
    Fault reaction active    xxxx xxxx x0xx 1111     mask 0x4F value 0x0F
    Fault                    xxxx xxxx x0xx 1000     mask 0x4F value 0x08

Controlword commands (bits 0 switch on, 1 enable voltage, 2 quick stop (low active),
3 enable operation, 7 fault reset on a rising edge): shutdown 0x06, switch on 0x07,
enable operation 0x0F, disable voltage 0x00, quick stop 0x02, fault reset 0x80.
"""

from __future__ import annotations

from enum import IntEnum
from types import SimpleNamespace

import numpy as np


class DriveState(IntEnum):
    """CiA 402 power state of a drive as the master sees it (UNKNOWN: no statusword yet)."""

    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7
    UNKNOWN = 8


STATE_NAMES: tuple[str, ...] = tuple(s.name for s in DriveState)

#: (mask, value, state) of the statusword, in CiA 402 order.
SW_MASKS: tuple[tuple[int, int, DriveState], ...] = (
    (0x4F, 0x00, DriveState.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, DriveState.SWITCH_ON_DISABLED),
    (0x6F, 0x21, DriveState.READY_TO_SWITCH_ON),
    (0x6F, 0x23, DriveState.SWITCHED_ON),
    (0x6F, 0x27, DriveState.OPERATION_ENABLED),
    (0x6F, 0x07, DriveState.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, DriveState.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, DriveState.FAULT),
)

SW_WARNING = 1 << 7
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_DRIVE_FOLLOWS = 1 << 12  # CSP/CSV: the drive follows the command value
SW_FOLLOWING_ERROR = 1 << 13

CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080


class Request(IntEnum):
    """What the master wants of a drive."""

    OFF = 0  #: disable voltage -> Switch On Disabled (brake)
    DISABLE = 1  #: shutdown -> Ready To Switch On (power stage off, brake)
    ENABLE = 2  #: -> Operation Enabled
    QUICK_STOP = 3  #: -> Quick Stop Active (then per 0x605A)


_S = DriveState
#: the states and requests as plain ints, for array work: numpy compares with an IntEnum
#: member about seven times slower than with an int (it inspects the object first)
ST = SimpleNamespace(**{m.name: int(m) for m in DriveState})
RQ = SimpleNamespace(**{m.name: int(m) for m in Request})
# Controlword per request (row) and state (column, DriveState order incl. UNKNOWN).
_CW_TABLE = np.zeros((len(Request), len(DriveState)), dtype=np.uint16)
_CW_TABLE[Request.OFF, :] = CW_DISABLE_VOLTAGE
_CW_TABLE[Request.DISABLE, [_S.SWITCH_ON_DISABLED, _S.READY_TO_SWITCH_ON, _S.SWITCHED_ON,
                            _S.OPERATION_ENABLED]] = CW_SHUTDOWN
_CW_TABLE[Request.ENABLE, _S.SWITCH_ON_DISABLED] = CW_SHUTDOWN  # 2
_CW_TABLE[Request.ENABLE, _S.READY_TO_SWITCH_ON] = CW_SWITCH_ON  # 3
_CW_TABLE[Request.ENABLE, _S.SWITCHED_ON] = CW_ENABLE_OPERATION  # 4
_CW_TABLE[Request.ENABLE, _S.OPERATION_ENABLED] = CW_ENABLE_OPERATION
_CW_TABLE[Request.ENABLE, _S.QUICK_STOP_ACTIVE] = CW_ENABLE_OPERATION  # 16 (options 5-8)
_CW_TABLE[Request.QUICK_STOP, :] = CW_QUICK_STOP
_CW_TABLE[Request.QUICK_STOP, [_S.FAULT, _S.FAULT_REACTION_ACTIVE]] = CW_DISABLE_VOLTAGE


def _state_table() -> np.ndarray:
    """The state of every value of the statusword bits the masks look at (0x6F), by
    :data:`SW_MASKS` in order (a later match wins), UNKNOWN where none matches."""
    bits = np.arange(0x70, dtype=np.int64)
    out = np.full(bits.shape, ST.UNKNOWN, dtype=np.int8)
    for mask, value, state in SW_MASKS:
        out[(bits & mask) == value] = state
    return out


_SW_BITS = 0x6F  # every mask of SW_MASKS lies within these bits
assert all(mask & ~_SW_BITS == 0 for mask, _, _ in SW_MASKS)
_STATE_OF_BITS = _state_table()


def decode_states(statuswords: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """CiA 402 states (:class:`DriveState` values, int8) of statuswords, shape (n,)."""
    sw = np.asarray(statuswords, dtype=np.int64)
    out = _STATE_OF_BITS[sw & _SW_BITS]  # one look-up per drive (a table of SW_MASKS)
    if valid is not None:
        out[~np.asarray(valid, dtype=bool)] = ST.UNKNOWN
    return out


def controlwords(states: np.ndarray, requests: np.ndarray) -> np.ndarray:
    """Controlwords (uint16) moving each drive one transition toward its request."""
    return _CW_TABLE[np.asarray(requests, dtype=np.int64), np.asarray(states, dtype=np.int64)]


def enabling(states: np.ndarray, controlwords_: np.ndarray) -> np.ndarray:
    """Drives this controlword takes into Operation Enabled (transitions 3+4, 4, 16)."""
    s = np.asarray(states)
    cw = np.asarray(controlwords_)
    going = (cw & 0x8F) == CW_ENABLE_OPERATION
    return going & ((s == ST.READY_TO_SWITCH_ON) | (s == ST.SWITCHED_ON)
                    | (s == ST.QUICK_STOP_ACTIVE))


def faulted(states: np.ndarray) -> np.ndarray:
    """Drives in Fault or Fault Reaction Active."""
    s = np.asarray(states)
    return (s == ST.FAULT) | (s == ST.FAULT_REACTION_ACTIVE)


# ---------------------------------------------------------------------------- EMCY codes

#: Text of the EMCY / error codes a winch drive or the master reports (CiA 301, CiA 402).
EMCY_TEXT: dict[int, str] = {
    0x0000: "error reset / no error",
    0x1000: "generic error",
    0x2310: "continuous over current (motor side)",
    0x2320: "short circuit / earth leakage (motor side)",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x4210: "excess temperature of the device",
    0x5530: "EEPROM / parameter memory",
    0x6010: "software reset (watchdog)",
    0x6320: "parameter error",
    0x7121: "motor blocked",
    0x7305: "incremental sensor 1 (motor encoder) fault",
    0x7320: "position sensor fault",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8250: "RPDO timeout",
    0x8611: "following error",
    0x8612: "reference limit",
}

_EMCY_CLASSES = (
    (0xF000, 0x2000, "current"),
    (0xF000, 0x3000, "voltage"),
    (0xF000, 0x4000, "temperature"),
    (0xFF00, 0x5000, "device hardware"),
    (0xF000, 0x6000, "device software"),
    (0xFF00, 0x7000, "additional modules"),
    (0xF000, 0x7000, "drive / sensor"),
    (0xFF00, 0x8100, "communication"),
    (0xFF00, 0x8200, "protocol error"),
    (0xF000, 0x8000, "monitoring"),
    (0xFF00, 0x9000, "external error"),
    (0xFF00, 0xF000, "additional functions"),
    (0xFF00, 0xFF00, "device specific"),
)


def emcy_text(code: int) -> str:
    """Human-readable meaning of an EMCY error code."""
    if code in EMCY_TEXT:
        return EMCY_TEXT[code]
    for mask, value, text in _EMCY_CLASSES:
        if code & mask == value:
            return f"{text} (0x{code:04X})"
    return f"unknown error 0x{code:04X}"
