"""CAN bus time of a CANopen cycle, and the highest SYNC rate a bus load allows.

Classical CAN (ISO 11898-1) data frame with ``n`` data bytes, standard 11-bit id:
SOF 1 + id 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8n + CRC 15 = 34 + 8n bits are
subject to bit stuffing, then CRC delimiter 1 + ACK 2 + EOF 7 + intermission 3 = 13
fixed bits. With worst-case stuffing (one stuff bit after every 4 bits after the
first, Davis et al. 2007) a frame occupies

    8n + 47 + floor((34 + 8n - 1) / 4)   bits   (extended 29-bit id: g = 54, 67 fixed)

A synchronous cycle of the winch bus is one RPDO per drive, one SYNC (0 bytes) and
one TPDO per drive. Eight drives with 6-byte PDOs at 1 Mbit/s: 16 x 115 + 55 = 1895
bits = 1.9 ms, so at 50 % bus load the SYNC rate is at most about 260 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass


def frame_bits(n_bytes: int, extended: bool = False, stuffing: bool = True) -> int:
    """Bits one classical CAN data frame occupies on the bus, intermission included."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"a classical CAN frame carries 0..8 data bytes, got {n_bytes}")
    g = 54 if extended else 34  # bits from SOF to the end of the CRC, without data
    stuffed = g + 8 * n_bytes
    fixed = 13
    stuff = (stuffed - 1) // 4 if stuffing else 0
    return stuffed + fixed + stuff


@dataclass(frozen=True)
class CycleConfig:
    """The frames of one synchronous cycle, and the background traffic."""

    bitrate: int = 1_000_000  #: bit/s
    n_drives: int = 8
    rpdo_bytes: int = 6  #: controlword + target position
    tpdo_bytes: int = 6  #: statusword + position actual value
    sync_bytes: int = 0  #: 1 with a SYNC counter
    heartbeat_period_s: float = 0.0  #: per drive, 0 = not counted
    extended: bool = False

    def cycle_bits(self) -> int:
        """Worst-case bits of one cycle: n RPDOs + SYNC + n TPDOs."""
        return (
            self.n_drives * frame_bits(self.rpdo_bytes, self.extended)
            + frame_bits(self.sync_bytes, self.extended)
            + self.n_drives * frame_bits(self.tpdo_bytes, self.extended)
        )

    def cycle_time_s(self) -> float:
        """Bus time of one cycle [s]."""
        return self.cycle_bits() / self.bitrate

    def background_bits_per_s(self) -> float:
        """Heartbeat traffic [bit/s] (1-byte frames from every drive)."""
        if self.heartbeat_period_s <= 0:
            return 0.0
        return self.n_drives * frame_bits(1, self.extended) / self.heartbeat_period_s

    def load(self, sync_rate_hz: float) -> float:
        """Bus load (0..1) at a SYNC rate [Hz]."""
        return (sync_rate_hz * self.cycle_bits() + self.background_bits_per_s()) / self.bitrate

    def max_sync_rate_hz(self, load: float = 0.5) -> float:
        """Highest SYNC rate [Hz] that keeps the bus load at or below ``load`` (0..1]."""
        if not 0 < load <= 1:
            raise ValueError(f"bus load must be in (0, 1], got {load}")
        spare = load * self.bitrate - self.background_bits_per_s()
        if spare <= 0:
            return 0.0
        return spare / self.cycle_bits()
