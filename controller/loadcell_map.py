"""Modbus register map of the cable-tension load cells, and its encoding.

Pure description shared by the simulated load cells (``firmware_sim``) and the
Modbus client (``hal``): which Modbus unit id measures which cable, where the
tension, status and sample counter sit among the input registers (function
code 0x04, 0-based PDU addresses) and how they are encoded. No I/O besides
reading a map file; no pymodbus.

Default map (``firmware_sim/data/loadcell_registers.toml`` documents the same
table): unit id k = 1..8 is the k-th cable in id order ``11, 12, 21, ... 42``;

=========  ==========================================================
register   content
=========  ==========================================================
0, 1       tension [N], IEEE-754 float32, high word first
2          status bits: bit 0 overload, bit 1 sensor fault (0 = ok)
3          sample counter, +1 per new sample, wraps at 65536
=========  ==========================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from controller.ranges import check
from controller.tomlfile import Locator, read_toml

#: Cable ids in array order (cdpr-conventions.md).
CABLE_IDS: tuple[str, ...] = ("11", "12", "21", "22", "31", "32", "41", "42")

_REG_KEYS = ("tension", "status", "counter")
_TOP_KEYS = {"format", "word_order", "device", "registers", "status_bits", "sensor"}
MAP_FORMAT = "cdpr-loadcell-map/1"


class RegisterMapError(ValueError):
    """A register map file or table is invalid; the message names the file and field."""


@dataclass(frozen=True)
class RegisterMap:
    """Where one load cell keeps its reading, and which unit measures which cable.

    ``unit_ids[k]`` is the Modbus unit (device) id of cable ``cables[k]``.
    Addresses are 0-based input-register (FC 0x04) addresses.
    """

    unit_ids: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)
    cables: tuple[str, ...] = CABLE_IDS
    tension_address: int = 0  #: first of two registers, float32 [N]
    status_address: int = 2
    counter_address: int = 3
    word_order: str = "big"  #: "big": high word first; "little": low word first
    overload_bit: int = 0
    sensor_fault_bit: int = 1
    counter_modulo: int = 65536
    rated_min_N: float = -500.0  #: below this the cell is out of its range [N]
    rated_max_N: float = 5000.0  #: above this the cell is overloaded [N]
    source: str = field(default="<default>", compare=False)

    # ---- derived layout -------------------------------------------------
    @property
    def block_start(self) -> int:
        """First register of the contiguous block read in one request."""
        return min(self.tension_address, self.status_address, self.counter_address)

    @property
    def block_count(self) -> int:
        """Number of registers in that block."""
        end = max(self.tension_address + 2, self.status_address + 1, self.counter_address + 1)
        return end - self.block_start

    @property
    def n(self) -> int:
        return len(self.unit_ids)

    def unit_of(self, cable: str) -> int:
        """Modbus unit id of ``cable`` (e.g. ``"21"`` -> 3 in the default map)."""
        try:
            return self.unit_ids[self.cables.index(cable)]
        except ValueError:
            raise KeyError(f"cable {cable!r} not in register map {self.source}") from None

    def cable_of(self, unit_id: int) -> str:
        """Cable id measured by Modbus unit ``unit_id``."""
        try:
            return self.cables[self.unit_ids.index(unit_id)]
        except ValueError:
            raise KeyError(f"Modbus unit {unit_id} not in register map {self.source}") from None

    def index_of(self, unit_or_cable: int | str) -> int:
        """Array index of a cable given its id string or its Modbus unit id (int)."""
        if isinstance(unit_or_cable, str):
            self.unit_of(unit_or_cable)  # raises a KeyError naming the map
            return self.cables.index(unit_or_cable)
        self.cable_of(int(unit_or_cable))
        return self.unit_ids.index(int(unit_or_cable))

    def describe(self, k: int) -> str:
        """Human name of array slot ``k``: ``'Modbus unit 3 (cable 21)'``."""
        return f"Modbus unit {self.unit_ids[k]} (cable {self.cables[k]})"

    # ---- encoding -------------------------------------------------------
    def encode(
        self, tension_N: np.ndarray, status: np.ndarray, counter: np.ndarray
    ) -> np.ndarray:
        """Register blocks ``(..., block_count)`` uint16 for tensions [N] (float32-rounded).

        Broadcasts over leading dimensions (e.g. the 8 cells at once).
        """
        t = np.asarray(tension_N, dtype=np.float32)
        shape = np.broadcast_shapes(t.shape, np.shape(status), np.shape(counter))
        out = np.zeros(shape + (self.block_count,), dtype=np.uint16)
        f = np.ascontiguousarray(np.broadcast_to(t, shape), dtype=">f4").reshape(-1)
        words = f.view(">u2").reshape(shape + (2,))
        if self.word_order == "little":
            words = words[..., ::-1]
        a = self.tension_address - self.block_start
        out[..., a : a + 2] = words
        out[..., self.status_address - self.block_start] = np.broadcast_to(status, shape)
        out[..., self.counter_address - self.block_start] = (
            np.broadcast_to(counter, shape) % self.counter_modulo
        )
        return out

    def decode(self, registers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(tension_N float64, status int, counter int)`` from register blocks ``(..., count)``.

        The float32 is widened to float64 exactly (NaN and inf pass through).
        """
        r = np.asarray(registers)
        if r.shape[-1] != self.block_count:
            raise ValueError(
                f"expected {self.block_count} registers per load cell, got {r.shape[-1]}"
            )
        if np.any((r < 0) | (r > 0xFFFF)):
            raise ValueError("register values must be 16-bit unsigned")
        a = self.tension_address - self.block_start
        words = r[..., a : a + 2].astype(">u2")
        if self.word_order == "little":
            words = words[..., ::-1]
        tension = np.ascontiguousarray(words).view(">f4")[..., 0].astype(np.float64)
        status = r[..., self.status_address - self.block_start].astype(np.int64)
        counter = r[..., self.counter_address - self.block_start].astype(np.int64)
        return tension, status, counter

    def status_word(self, overload: bool = False, sensor_fault: bool = False) -> int:
        """Status register value with the given bits set."""
        return (int(overload) << self.overload_bit) | (int(sensor_fault) << self.sensor_fault_bit)


DEFAULT_MAP = RegisterMap()


# ---- parsing -------------------------------------------------------------
def _err(source: str, where: str, msg: str) -> RegisterMapError:
    return RegisterMapError(f"{source}: {where}: {msg}")


def _int(source: str, where: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise _err(source, where, f"expected an integer, got {v!r}")
    if not lo <= v <= hi:
        raise _err(source, where, f"{v} outside [{lo}, {hi}]")
    return v


def _float(source: str, where: str, v: Any, loc: Locator | None = None) -> float:
    """``v`` as a finite number within the physical range of field ``where``
    (:mod:`controller.ranges`; the line from ``loc``, the file's text)."""
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
        raise _err(source, where, f"expected a finite number, got {v!r}")
    table, _, key = where.rpartition(".")
    line = loc.line(table or None, None, key) if loc is not None else None
    check("loadcell_map", where, v, f"{source}:{line}: {where}" if line else
          f"{source}: {where}", RegisterMapError)
    return float(v)


def _table(source: str, where: str, v: Any, keys: set[str]) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise _err(source, where, f"expected a table, got {v!r}")
    unknown = sorted(set(v) - keys)
    if unknown:
        raise _err(source, where, f"unknown key(s) {unknown}; known: {sorted(keys)}")
    return v


def parse_register_map(data: dict[str, Any], source: str = "<memory>",
                       text: str = "") -> RegisterMap:
    """Register map from a TOML table (the layout of ``loadcell_registers.toml``).

    Errors raise :class:`RegisterMapError` naming ``source`` and the field (and the line,
    given the file's ``text``).
    """
    loc = Locator(text)
    _table(source, "top level", data, _TOP_KEYS)
    if data.get("format", MAP_FORMAT) != MAP_FORMAT:
        raise _err(source, "format", f"expected {MAP_FORMAT!r}, got {data['format']!r}")
    word_order = data.get("word_order", "big")
    if word_order not in ("big", "little"):
        raise _err(source, "word_order", f"expected 'big' or 'little', got {word_order!r}")

    devices = data.get("device")
    if not isinstance(devices, list) or not devices:
        raise _err(source, "device", "expected an array of [[device]] tables")
    units: list[int] = []
    cables: list[str] = []
    for i, dev in enumerate(devices):
        where = f"device[{i}]"
        _table(source, where, dev, {"unit_id", "cable"})
        if "unit_id" not in dev or "cable" not in dev:
            raise _err(source, where, "needs both 'unit_id' and 'cable'")
        uid = _int(source, where + ".unit_id", dev["unit_id"], 1, 247)
        cab = dev["cable"]
        if not isinstance(cab, str) or not cab:
            raise _err(source, where + ".cable", f"expected a cable id string, got {cab!r}")
        if uid in units:
            raise _err(source, where + ".unit_id", f"unit id {uid} used twice")
        if cab in cables:
            raise _err(source, where + ".cable", f"cable {cab} mapped twice")
        units.append(uid)
        cables.append(cab)
    if sorted(cables) != cables:
        raise _err(source, "device", f"devices must be listed in cable id order, got {cables}")

    regs = _table(source, "registers", data.get("registers", {}), set(_REG_KEYS))
    addr: dict[str, int] = {}
    want = {
        "tension": ("float32", 2),
        "status": ("uint16", 1),
        "counter": ("uint16", 1),
    }
    for key in _REG_KEYS:
        where = f"registers.{key}"
        if key not in regs:
            raise _err(source, where, "missing")
        r = _table(source, where, regs[key], {"address", "count", "type", "unit", "note"})
        addr[key] = _int(source, where + ".address", r.get("address"), 0, 65534)
        typ, count = want[key]
        if r.get("type", typ) != typ:
            raise _err(source, where + ".type", f"only {typ!r} is supported, got {r['type']!r}")
        if r.get("count", count) != count:
            raise _err(source, where + ".count", f"must be {count}, got {r['count']!r}")
    spans = sorted(
        (addr[k], addr[k] + want[k][1], k) for k in _REG_KEYS
    )
    for (_a0, e0, k0), (a1, _e1, k1) in zip(spans, spans[1:], strict=False):
        if a1 < e0:
            raise _err(source, f"registers.{k1}.address", f"overlaps registers.{k0}")
    if spans[-1][1] - spans[0][0] > 125:
        raise _err(source, "registers", "block longer than 125 registers (one Modbus read)")

    bits = _table(source, "status_bits", data.get("status_bits", {}), {"overload", "sensor_fault"})
    ovl = _int(source, "status_bits.overload", bits.get("overload", 0), 0, 15)
    flt = _int(source, "status_bits.sensor_fault", bits.get("sensor_fault", 1), 0, 15)
    if ovl == flt:
        raise _err(source, "status_bits", "overload and sensor_fault use the same bit")

    sensor = _table(
        source, "sensor", data.get("sensor", {}), {"rated_min_N", "rated_max_N", "counter_modulo"}
    )
    lo = _float(source, "sensor.rated_min_N", sensor.get("rated_min_N", -500.0), loc)
    hi = _float(source, "sensor.rated_max_N", sensor.get("rated_max_N", 5000.0), loc)
    if not lo < hi:
        raise _err(source, "sensor", f"rated_min_N {lo} must be < rated_max_N {hi}")
    modulo = _int(source, "sensor.counter_modulo", sensor.get("counter_modulo", 65536), 2, 65536)

    return RegisterMap(
        unit_ids=tuple(units),
        cables=tuple(cables),
        tension_address=addr["tension"],
        status_address=addr["status"],
        counter_address=addr["counter"],
        word_order=word_order,
        overload_bit=ovl,
        sensor_fault_bit=flt,
        counter_modulo=modulo,
        rated_min_N=lo,
        rated_max_N=hi,
        source=source,
    )


def load_register_map(path: str | Path) -> RegisterMap:
    """Read a register map TOML file (errors name the file, line or field)."""
    p = Path(path)
    data, text = read_toml(p, RegisterMapError)
    return parse_register_map(data, str(p), text)
