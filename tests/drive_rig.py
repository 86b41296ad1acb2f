"""Simulated winch drives on a fresh python-can virtual channel, shared by the HAL and
commissioning tests: the bank (firmware_sim.drive_bank) runs on its deterministic SYNC
clock; a master on the same channel (the HAL in "sync" clock) steps in lock-step."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from controller.winch import WinchSet, load_winches
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.drive_bank import SimulatedWinchBank
from hal.drives import WinchDrives

W = load_winches()


class BankRig:
    """The drives of ``winches`` at ``lengths`` [m] on channel ``virtual:<prefix>-<uuid>``;
    ``before_start(rig)`` runs after the bank exists and before its drives boot."""

    def __init__(self, prefix: str, winches: WinchSet = W, lengths: np.ndarray | None = None,
                 before_start: Callable[[Any], None] | None = None) -> None:
        self.hal: WinchDrives | None = None  #: a master's HAL on the channel, closed first
        self.ch = f"{prefix}-{uuid.uuid4().hex}"
        self.can = f"virtual:{self.ch}"
        self.bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=self.ch), winches)
        self.bank.set_positions_m(np.linspace(8.0, 15.0, len(winches))
                                  if lengths is None else lengths)
        if before_start:
            before_start(self)
        self.bank.start()

    def open_hal(self, winches: WinchSet = W, start: bool = True,
                 enable: bool = True) -> WinchDrives:
        """The HAL on this channel ("sync" clock), started and enabled unless told not to."""
        hal = WinchDrives.open(self.can, winches, EDS_PATH, clock="sync")
        if start:
            hal.start()
        if enable:
            hal.enable_and_wait()
        return hal

    def close(self) -> None:
        if self.hal is not None:
            self.hal.close()
        self.bank.close()
