"""What every part of the winch drives' master (:mod:`hal.drives`) shares: constants,
errors and the event and fault records."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from hal.drives_cia402 import (
    ST,
    DriveState,
)

#: SDO answer timeout of the HAL's nodes [s] (start-up, recovery, fault-code reads)
SDO_TIMEOUT_S = 1.0
#: a foreign master's frame is an active fault for this long after the last one [s, master
#: clock] (the supervisor latches its quick stop)
FOREIGN_HOLD_S = 0.5
#: lock-step: wall time [s] waited for the TPDOs of drives that missed the SYNC before
MISSING_WAIT_S = 0.05


CODE_HEARTBEAT = 0x8130  # life guard / heartbeat error (CiA 301)
CODE_PDO_TIMEOUT = 0x8250  # RPDO timeout, here: the master's receive PDO = drive's TPDO
CODE_BUS = 0x8100  # communication, generic: the bus refused our frames

NMT_NAMES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
NMT_OPERATIONAL = 0x05
#: NMT restarts of a drive that is not OPERATIONAL before the first enable (start-up)
NMT_START_TRIES = 3
EMCY_STRUCT = struct.Struct("<HB5s")
#: a drive's place on the way to Operation Enabled (by DriveState value; -1: off that way)
_ENABLE_RANK = np.full(len(DriveState), -1, np.int8)
_ENABLE_RANK[[ST.NOT_READY_TO_SWITCH_ON, ST.SWITCH_ON_DISABLED, ST.READY_TO_SWITCH_ON,
              ST.SWITCHED_ON, ST.OPERATION_ENABLED]] = [0, 0, 1, 2, 3]
#: events kept by :meth:`WinchDrives.events` when nobody takes them (oldest dropped)
EVENTS_KEPT = 10_000
#: EMCYs waiting for the next cycle at most (a flood beyond is counted, not kept)
QUEUE_KEPT = 10_000


class DriveStartupError(RuntimeError):
    """Drives did not come up (missing boot-up, no answer); the message names the nodes."""


class DriveLostError(DriveStartupError):
    """Drives lost while they were being enabled (their TPDOs stopped: ``drive_lost``);
    ``node_ids`` names them. Their faults stay in :meth:`WinchDrives.faults`."""

    def __init__(self, message: str, node_ids: tuple[int, ...]) -> None:
        super().__init__(message)
        self.node_ids = node_ids


class BusLinkError(DriveStartupError):
    """The CAN link is down (the socketcand server or the adapter went away, the bus refuses
    frames): raised by the blocking calls, the message names the bus."""


@dataclass(frozen=True)
class DriveEvent:
    """Something that happened on a drive, in order of detection."""

    node_id: int
    cable: str
    kind: str  #: emcy, emcy_malformed, emcy_overflow, fault, fault_code, fault_cleared,
    #: quick_stop, switched_off, heartbeat_lost, heartbeat_resumed, heartbeat_malformed,
    #: boot_up, nmt_state, tpdo_missing, tpdo_late, tpdo_short, drive_lost, tpdo_resumed,
    #: foreign_master, internal_limit, fault_reset_failed, recovered, sdo_error; node_id 0
    #: (the bus): bus_error, link_lost, link_back, foreign_master (NMT to all nodes, SYNC)
    code: int  #: EMCY / error code (0 when none applies)
    text: str
    source: str  #: "drive" (EMCY it sent) or "hal" (detected by the master)
    cycle: int  #: exchange() count when processed
    time_s: float  #: master clock [s]

    def __str__(self) -> str:
        return (f"node {self.node_id} (cable {self.cable}) {self.kind} 0x{self.code:04X}: "
                f"{self.text} [{self.source}, cycle {self.cycle}]")


@dataclass(frozen=True)
class DriveFault:
    """An active fault of one drive."""

    node_id: int
    cable: str
    kind: str  #: drive_fault, quick_stop, heartbeat_lost, drive_lost, boot_up, nmt_state,
    #: link_lost, foreign_master (node_id 0: a frame to the whole bus)
    code: int
    text: str

    def __str__(self) -> str:
        return (f"node {self.node_id} (cable {self.cable}) {self.kind} 0x{self.code:04X}: "
                f"{self.text}")


__all__ = [
    "BusLinkError",
    "CODE_BUS",
    "CODE_HEARTBEAT",
    "CODE_PDO_TIMEOUT",
    "DriveEvent",
    "DriveFault",
    "DriveLostError",
    "DriveStartupError",
    "EMCY_STRUCT",
    "EVENTS_KEPT",
    "FOREIGN_HOLD_S",
    "MISSING_WAIT_S",
    "NMT_NAMES",
    "NMT_OPERATIONAL",
    "NMT_START_TRIES",
    "QUEUE_KEPT",
    "SDO_TIMEOUT_S",
]
