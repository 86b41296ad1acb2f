"""Per-cable load-cell calibration: ``measured = gain * true + offset``.

Same parameter names as the ``load_cell_calibration`` effect of the diagnosis
(cdpr-conventions.md), so a fitted effect's ``params`` can be saved as is::

    # loadcell_calibration.toml
    [load_cell_calibration]
    gain_11 = 1.012        # [-]
    offset_11 = -4.0       # [N]
    gain_21 = 0.995
    # cables not listed: gain 1, offset 0

The top-level table may be omitted (keys at the top level are accepted too).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller.loadcell_map import CABLE_IDS
from controller.ranges import check
from controller.tomlfile import Locator, read_toml

TABLE = "load_cell_calibration"


class CalibrationError(ValueError):
    """Invalid calibration file or values; the message names the file and key."""


@dataclass(frozen=True)
class LoadCellCalibration:
    """Gains [-] and offsets [N] per cable, arrays in ``cables`` order."""

    gain: np.ndarray
    offset_N: np.ndarray
    cables: tuple[str, ...] = CABLE_IDS
    source: str = "<identity>"

    def __post_init__(self) -> None:
        n = len(self.cables)
        gain = np.broadcast_to(np.asarray(self.gain, dtype=float), (n,)).copy()
        offset = np.broadcast_to(np.asarray(self.offset_N, dtype=float), (n,)).copy()
        for k, c in enumerate(self.cables):
            if not np.isfinite(gain[k]) or gain[k] <= 0:
                raise CalibrationError(
                    f"{self.source}: gain_{c} = {gain[k]} must be finite and > 0"
                )
            if not np.isfinite(offset[k]):
                raise CalibrationError(f"{self.source}: offset_{c} = {offset[k]} must be finite")
        gain.setflags(write=False)
        offset.setflags(write=False)
        object.__setattr__(self, "gain", gain)
        object.__setattr__(self, "offset_N", offset)

    @classmethod
    def identity(cls, cables: tuple[str, ...] = CABLE_IDS) -> LoadCellCalibration:
        return cls(np.ones(len(cables)), np.zeros(len(cables)), cables)

    def true_from_measured(self, measured_N: np.ndarray) -> np.ndarray:
        """True tensions [N] from measured ones: ``(measured - offset) / gain``."""
        return (np.asarray(measured_N, dtype=float) - self.offset_N) / self.gain

    def measured_from_true(self, true_N: np.ndarray) -> np.ndarray:
        """What the cells read for true tensions [N]: ``gain * true + offset``."""
        return self.gain * np.asarray(true_N, dtype=float) + self.offset_N

    def as_params(self) -> dict[str, float]:
        """``{"gain_11": ..., "offset_11": ...}`` (the diagnosis' parameter names)."""
        out: dict[str, float] = {}
        for k, c in enumerate(self.cables):
            out[f"gain_{c}"] = float(self.gain[k])
            out[f"offset_{c}"] = float(self.offset_N[k])
        return out


def parse_calibration(
    data: dict[str, Any], source: str = "<memory>", cables: tuple[str, ...] = CABLE_IDS,
    text: str = "",
) -> LoadCellCalibration:
    """Calibration from ``{"gain_11": ..., "offset_11": ...}``.

    The keys may sit under a ``[load_cell_calibration]`` table. Missing cables:
    gain 1, offset 0. Unknown keys raise :class:`CalibrationError`.
    """
    table = data.get(TABLE, data) if isinstance(data, dict) else data
    if not isinstance(table, dict):
        raise CalibrationError(f"{source}: expected a table of gain_ij/offset_ij")
    extra = set(data) - {TABLE} if TABLE in data else set()
    if extra:
        raise CalibrationError(f"{source}: unknown top-level key(s) {sorted(extra)}")
    gain = np.ones(len(cables))
    offset = np.zeros(len(cables))
    loc = Locator(text)  # lines for the range errors (controller.ranges)
    for key, value in table.items():
        name, _, cable = key.partition("_")
        if name not in ("gain", "offset") or cable not in cables:
            raise CalibrationError(
                f"{source}: unknown key {key!r}; expected gain_ij or offset_ij with ij in {cables}"
            )
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CalibrationError(f"{source}: {key} = {value!r} is not a number")
        line = loc.line(TABLE if TABLE in data else None, None, key)
        check("calibration", key, value, f"{source}:{line}: {key}" if line else
              f"{source}: {key}", CalibrationError)
        (gain if name == "gain" else offset)[cables.index(cable)] = float(value)
    return LoadCellCalibration(gain, offset, cables, source)


def load_calibration(path: str | Path, cables: tuple[str, ...] = CABLE_IDS) -> LoadCellCalibration:
    """Read a calibration TOML file (errors name the file and the key or line)."""
    p = Path(path)
    data, text = read_toml(p, CalibrationError)  # errors name the file (line, column)
    return parse_calibration(data, str(p), cables, text)
