"""Winch parameters and units: drive encoder counts <-> metres of cable, per winch.

Pure description shared by the HAL (``hal/drives*.py``) and the simulated drives
(``firmware_sim/cia402_drive.py``). Arrays run over the winches in cable-id order
``11, 12, 21, ... 42`` (cdpr-conventions.md); every function is vectorised over them.

Units: a CiA 402 drive counts motor encoder increments ("counts"); velocities are
counts/s and accelerations counts/s^2. A cable length [m] follows from a position
[counts] through the drum and the gear:

    metres_per_count = 2 pi drum_radius_m / (gear_ratio encoder_counts_per_rev)
    length_m         = length_at_zero_m + direction * counts * metres_per_count

``direction`` is +1 when increasing counts pay cable out, -1 when they reel it in.
``length_at_zero_m`` is what referencing sets (the paper's initialisation, Fig. 4d).

The default parameter file is ``controller/data/rocaspect_winches.toml``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller.ranges import check as check_range
from controller.tomlfile import Locator, read_toml

#: Cable ids in array order (cdpr-conventions.md).
CABLE_IDS: tuple[str, ...] = ("11", "12", "21", "22", "31", "32", "41", "42")

#: Default parameter file.
DEFAULT_WINCHES = Path(__file__).parent / "data" / "rocaspect_winches.toml"

INT32_MAX = 2**31 - 1
UINT32_MAX = 2**32 - 1
UINT16_MAX = 2**16 - 1
STANDARD_BITRATES = (10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)


class WinchConfigError(ValueError):
    """A winch parameter file or value is invalid; the message names the file and field."""


# Per-winch fields: name -> (kind, check, what the check means). Order = file documentation.
_POS = (lambda v: v > 0, "must be > 0")
_NONNEG = (lambda v: v >= 0, "must be >= 0")
_FIELDS: dict[str, tuple[type, tuple[Any, str]]] = {
    "gear_ratio": (float, _POS),
    "drum_radius_m": (float, _POS),
    "encoder_counts_per_rev": (int, _POS),
    "direction": (int, (lambda v: v in (1, -1), "must be 1 or -1")),
    "length_at_zero_m": (float, (lambda v: True, "")),
    "min_length_m": (float, _NONNEG),
    "max_length_m": (float, _POS),
    "max_speed_m_s": (float, _POS),
    "max_accel_m_s2": (float, _POS),
    "profile_speed_m_s": (float, _POS),
    "profile_accel_m_s2": (float, _POS),
    "quick_stop_decel_m_s2": (float, _POS),
    "following_error_m": (float, _POS),
    "following_error_time_s": (float, _NONNEG),
    "position_window_m": (float, _NONNEG),
    "quick_stop_option": (int, (lambda v: 0 <= v <= 8, "must be a 0x605A option 0..8")),
    "fault_reaction_option": (int, (lambda v: 0 <= v <= 4, "must be a 0x605E option 0..4")),
    "abort_connection_option": (int, (lambda v: 0 <= v <= 3, "must be a 0x6007 option 0..3")),
    "comm_error_behaviour": (int, (lambda v: 0 <= v <= 2, "must be a 0x1029:01 value 0..2")),
    "lag_time_constant_s": (float, _NONNEG),
    "rated_torque_nm": (float, _POS),
}
_INT_FIELDS = tuple(k for k, (t, _) in _FIELDS.items() if t is int)
#: Fields a file may leave out (added after the first files were written): the safe value.
_OPTIONAL: dict[str, Any] = {
    "abort_connection_option": 3,  # 0x6007: quick stop command when the master is lost
    "comm_error_behaviour": 0,  # 0x1029:01: NMT pre-operational on a communication error
}


@dataclass(frozen=True)
class BusParams:
    """CAN bus timing shared by the eight drives."""

    bitrate: int = 1_000_000  #: bit/s
    sync_period_s: float = 0.004  #: SYNC period = control cycle [s]
    heartbeat_period_s: float = 0.1  #: drive heartbeat producer time [s], 0 = off
    heartbeat_misses: int = 3  #: a drive is lost after this many silent heartbeat periods
    rpdo_timeout_s: float = 0.02  #: drive-side RPDO deadline [s], 0 = not monitored
    master_node_id: int = 127  #: CANopen node id of the master's heartbeat (0x700 + id)
    master_heartbeat_period_s: float = 0.05  #: master heartbeat producer time [s], 0 = off
    #: consumer heartbeat time the drives watch the master with (0x1016) [s], 0 = not watched
    master_heartbeat_timeout_s: float = 0.25

    @property
    def sync_period_us(self) -> int:
        return int(round(self.sync_period_s * 1e6))

    @property
    def heartbeat_ms(self) -> int:
        return int(round(self.heartbeat_period_s * 1e3))

    @property
    def rpdo_timeout_ms(self) -> int:
        return int(round(self.rpdo_timeout_s * 1e3))

    @property
    def master_heartbeat_ms(self) -> int:
        return int(round(self.master_heartbeat_period_s * 1e3))

    @property
    def master_heartbeat_timeout_ms(self) -> int:
        return int(round(self.master_heartbeat_timeout_s * 1e3))


@dataclass(frozen=True)
class WinchAxis:
    """The parameters of one winch (scalars), see :class:`WinchSet` for the meaning."""

    cable: str
    node_id: int
    gear_ratio: float
    drum_radius_m: float
    encoder_counts_per_rev: int
    direction: int
    length_at_zero_m: float
    min_length_m: float
    max_length_m: float
    max_speed_m_s: float
    max_accel_m_s2: float
    profile_speed_m_s: float
    profile_accel_m_s2: float
    quick_stop_decel_m_s2: float
    following_error_m: float
    following_error_time_s: float
    position_window_m: float
    quick_stop_option: int
    fault_reaction_option: int
    lag_time_constant_s: float
    rated_torque_nm: float
    abort_connection_option: int = 3
    comm_error_behaviour: int = 0

    @property
    def metres_per_count(self) -> float:
        return 2.0 * math.pi * self.drum_radius_m / (self.gear_ratio * self.encoder_counts_per_rev)

    def counts_to_m(self, counts: float) -> float:
        return self.length_at_zero_m + self.direction * counts * self.metres_per_count

    def m_to_counts(self, length_m: float) -> float:
        """Position [counts] (not rounded) of a cable length [m]."""
        return (length_m - self.length_at_zero_m) / (self.direction * self.metres_per_count)


@dataclass(frozen=True)
class WinchSet:
    """Parameters of all winches, one array entry per winch in cable-id order.

    Float arrays have shape (n,), ``node_id``, ``direction``, ``encoder_counts_per_rev``
    and the option codes are integer arrays. ``source`` names where they came from.
    """

    cables: tuple[str, ...]
    node_id: np.ndarray
    gear_ratio: np.ndarray
    drum_radius_m: np.ndarray
    encoder_counts_per_rev: np.ndarray
    direction: np.ndarray
    length_at_zero_m: np.ndarray
    min_length_m: np.ndarray
    max_length_m: np.ndarray
    max_speed_m_s: np.ndarray
    max_accel_m_s2: np.ndarray
    profile_speed_m_s: np.ndarray
    profile_accel_m_s2: np.ndarray
    quick_stop_decel_m_s2: np.ndarray
    following_error_m: np.ndarray
    following_error_time_s: np.ndarray
    position_window_m: np.ndarray
    quick_stop_option: np.ndarray
    fault_reaction_option: np.ndarray
    lag_time_constant_s: np.ndarray
    rated_torque_nm: np.ndarray
    abort_connection_option: np.ndarray
    comm_error_behaviour: np.ndarray
    bus: BusParams = BusParams()
    source: str = "<memory>"

    def __len__(self) -> int:
        return len(self.cables)

    @property
    def metres_per_count(self) -> np.ndarray:
        """Cable length per encoder count [m], shape (n,)."""
        return metres_per_count(self)

    def axis(self, k: int) -> WinchAxis:
        """Scalar parameters of winch ``k`` (array index, not node id)."""
        vals: dict[str, Any] = {"cable": self.cables[k], "node_id": int(self.node_id[k])}
        for name in _FIELDS:
            v = getattr(self, name)[k]
            vals[name] = int(v) if name in _INT_FIELDS else float(v)
        return WinchAxis(**vals)

    def index_of_node(self, node_id: int) -> int:
        """Array index of the winch driven by CAN node ``node_id``."""
        hits = np.flatnonzero(self.node_id == node_id)
        if len(hits) != 1:
            raise KeyError(f"{self.source}: no winch with CAN node id {node_id}")
        return int(hits[0])

    def replace(self, **changes: Any) -> WinchSet:
        """A copy with some fields replaced (arrays are broadcast to (n,)) and re-validated."""
        n = len(self)
        fixed: dict[str, Any] = {}
        for key, val in changes.items():
            if key in _FIELDS:
                dtype = np.int64 if key in _INT_FIELDS else float
                fixed[key] = np.broadcast_to(np.asarray(val, dtype=dtype), (n,)).copy()
            else:
                fixed[key] = val
        out = dataclasses.replace(self, **fixed)
        validate(out)
        return out


# ---------------------------------------------------------------------------- units


def metres_per_count(w: WinchSet) -> np.ndarray:
    """Cable length per encoder count [m], shape (n,)."""
    return 2.0 * np.pi * w.drum_radius_m / (w.gear_ratio * w.encoder_counts_per_rev)


def counts_to_m(counts: np.ndarray, w: WinchSet) -> np.ndarray:
    """Cable lengths [m] of drive positions ``counts`` (shape (..., n))."""
    c = np.asarray(counts, dtype=float)
    return w.length_at_zero_m + w.direction * c * metres_per_count(w)


def m_to_counts(lengths_m: np.ndarray, w: WinchSet) -> np.ndarray:
    """Drive positions [counts] (int64, rounded) of cable lengths ``lengths_m`` [m]."""
    x = (np.asarray(lengths_m, dtype=float) - w.length_at_zero_m) / (
        w.direction * metres_per_count(w)
    )
    return np.rint(x).astype(np.int64)


def m_to_counts_rate(rate_m: np.ndarray, w: WinchSet) -> np.ndarray:
    """Magnitude of a cable speed [m/s] or acceleration [m/s^2] in counts/s (counts/s^2)."""
    return np.abs(np.asarray(rate_m, dtype=float)) / metres_per_count(w)


def counts_to_m_rate(rate_counts: np.ndarray, w: WinchSet) -> np.ndarray:
    """Signed cable speed [m/s] of a drive velocity [counts/s] (sign follows ``direction``)."""
    return w.direction * np.asarray(rate_counts, dtype=float) * metres_per_count(w)


def limits_counts(w: WinchSet) -> tuple[np.ndarray, np.ndarray]:
    """Software position limits (min, max) [counts] of the cable length limits, shape (n,)."""
    a = m_to_counts(w.min_length_m, w)
    b = m_to_counts(w.max_length_m, w)
    return np.minimum(a, b), np.maximum(a, b)


def reference_lengths(w: WinchSet, counts: np.ndarray, lengths_m: np.ndarray) -> WinchSet:
    """Winch parameters referenced so that positions ``counts`` read as ``lengths_m`` [m]."""
    c = np.asarray(counts, float)
    l0 = np.asarray(lengths_m, float) - w.direction * c * metres_per_count(w)
    return w.replace(length_at_zero_m=l0)


# ---------------------------------------------------------------------------- loading


def _fail(source: str, where: str, msg: str) -> WinchConfigError:
    return WinchConfigError(f"{source}: {where}: {msg}")


def _parse_bus(table: Any, source: str, loc: Locator | None = None) -> BusParams:
    if not isinstance(table, dict):
        raise _fail(source, "[bus]", "must be a table")
    defaults = dataclasses.asdict(BusParams())
    unknown = set(table) - set(defaults)
    if unknown:
        raise _fail(source, "[bus]", f"unknown key(s) {sorted(unknown)}; known: {sorted(defaults)}")
    vals = dict(defaults)
    for key, val in table.items():
        want = type(defaults[key])
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            raise _fail(source, f"[bus] {key}", f"must be a number, got {val!r}")
        if not math.isfinite(float(val)):
            raise _fail(source, f"[bus] {key}", f"must be finite, got {val!r}")
        if want is int and not float(val).is_integer():
            raise _fail(source, f"[bus] {key}", f"must be an integer, got {val!r}")
        line = loc.line("bus", None, key) if loc is not None else None
        check_range("winch", f"bus.{key}", val, f"{source}{f':{line}' if line else ''}: "
                    f"[bus] {key}", WinchConfigError)
        vals[key] = want(val)
    bus = BusParams(**vals)
    _validate_bus(bus, source)
    return bus


def _validate_bus(bus: BusParams, source: str) -> None:
    if bus.bitrate not in STANDARD_BITRATES:
        raise _fail(source, "[bus] bitrate",
                    f"{bus.bitrate} is not a CiA bit rate {STANDARD_BITRATES}")
    if not (0 < bus.sync_period_s <= 1.0) or bus.sync_period_us < 100:
        raise _fail(source, "[bus] sync_period_s", f"{bus.sync_period_s} must be in [0.0001, 1] s")
    if abs(bus.sync_period_us - bus.sync_period_s * 1e6) > 1e-6:
        raise _fail(source, "[bus] sync_period_s", "must be a whole number of microseconds")
    if not (0 <= bus.heartbeat_ms <= UINT16_MAX):
        raise _fail(source, "[bus] heartbeat_period_s",
                    f"{bus.heartbeat_period_s} out of 0..65.535 s")
    if bus.heartbeat_misses < 1:
        raise _fail(source, "[bus] heartbeat_misses", "must be >= 1")
    if not (0 <= bus.rpdo_timeout_ms <= UINT16_MAX):
        raise _fail(source, "[bus] rpdo_timeout_s", f"{bus.rpdo_timeout_s} out of 0..65.535 s")
    if 0 < bus.rpdo_timeout_s <= bus.sync_period_s:
        raise _fail(source, "[bus] rpdo_timeout_s", f"{bus.rpdo_timeout_s} s must be longer than "
                    f"the SYNC period {bus.sync_period_s} s (one RPDO per SYNC)")
    if not 1 <= bus.master_node_id <= 127:
        raise _fail(source, "[bus] master_node_id", f"{bus.master_node_id} is not a node id 1..127")
    for key in ("master_heartbeat_period_s", "master_heartbeat_timeout_s"):
        ms = int(round(getattr(bus, key) * 1e3))
        if not (0 <= ms <= UINT16_MAX) or not math.isfinite(getattr(bus, key)):
            raise _fail(source, f"[bus] {key}", f"{getattr(bus, key)} out of 0..65.535 s")
    if bus.master_heartbeat_timeout_s > 0:
        if bus.master_heartbeat_period_s <= 0:
            raise _fail(source, "[bus] master_heartbeat_timeout_s", "the drives watch a master "
                        "heartbeat (timeout > 0) but master_heartbeat_period_s is 0")
        if bus.master_heartbeat_timeout_s < 2 * bus.master_heartbeat_period_s:
            raise _fail(source, "[bus] master_heartbeat_timeout_s",
                        f"{bus.master_heartbeat_timeout_s} s must be at least two master "
                        f"heartbeat periods ({2 * bus.master_heartbeat_period_s:g} s)")


def _check_value(source: str, where: str, key: str, val: Any, line: int | None = None) -> Any:
    """``val`` of per-winch field ``key``: its type, its drive-object meaning and its
    physical range (:mod:`controller.ranges`; ``line`` of the file, when known)."""
    kind, (check, meaning) = _FIELDS[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise _fail(source, f"{where} {key}", f"must be a number, got {val!r}")
    if kind is int and not float(val).is_integer():
        raise _fail(source, f"{where} {key}", f"must be an integer, got {val!r}")
    if not math.isfinite(float(val)):
        raise _fail(source, f"{where} {key}", f"must be finite, got {val!r}")
    val = kind(val)
    if not check(val):
        raise _fail(source, f"{where} {key}", f"{meaning}, got {val!r}")
    check_range("winch", key, val, f"{source}{f':{line}' if line else ''}: {where} {key}",
                WinchConfigError)
    return val


def parse_winches(doc: dict[str, Any], source: str = "<memory>", text: str = "") -> WinchSet:
    """Winch parameters from a parsed TOML document (see the default file for the format;
    ``text``: the file's, for the lines of range errors)."""
    loc = Locator(text)
    unknown = set(doc) - {"bus", "defaults", "winch"}
    if unknown:
        raise _fail(source, "top level",
                    f"unknown key(s) {sorted(unknown)}; known: bus, defaults, winch")
    bus = _parse_bus(doc.get("bus", {}), source, loc)
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        raise _fail(source, "[defaults]", "must be a table")
    for key, val in defaults.items():
        if key not in _FIELDS:
            raise _fail(source, f"[defaults] {key}", f"unknown key; known: {sorted(_FIELDS)}")
        _check_value(source, "[defaults]", key, val, loc.line("defaults", None, key))
    entries = doc.get("winch")
    if not isinstance(entries, list) or not entries:
        raise _fail(source, "[[winch]]", "at least one [[winch]] table is required")
    if len(entries) != len(CABLE_IDS):
        raise _fail(source, "[[winch]]", f"{len(entries)} entries, expected {len(CABLE_IDS)} "
                    f"(cables {', '.join(CABLE_IDS)})")
    rows: list[dict[str, Any]] = []
    for i, entry in enumerate(entries):
        where = f"[[winch]] #{i + 1}"
        if not isinstance(entry, dict):
            raise _fail(source, where, "must be a table")
        cable = entry.get("cable")
        if cable != CABLE_IDS[i]:
            raise _fail(source, f"{where} cable", f"is {cable!r}, expected {CABLE_IDS[i]!r} "
                        f"(winches are listed in cable-id order {', '.join(CABLE_IDS)})")
        where = f"[[winch]] #{i + 1} (cable {cable!r})"
        node_id = entry.get("node_id")
        if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
            raise _fail(source, f"{where} node_id",
                        f"must be a CANopen node id 1..127, got {node_id!r}")
        row: dict[str, Any] = {"cable": cable, "node_id": node_id}
        for key in entry:
            if key not in _FIELDS and key not in ("cable", "node_id"):
                raise _fail(source, f"{where} {key}", f"unknown key; known: {sorted(_FIELDS)}")
        for key in _FIELDS:
            if key in entry:
                row[key] = _check_value(source, where, key, entry[key],
                                        loc.line("winch", i, key))
            elif key in defaults:
                row[key] = _check_value(source, "[defaults]", key, defaults[key],
                                        loc.line("defaults", None, key))
            elif key in _OPTIONAL:
                row[key] = _OPTIONAL[key]
            else:
                raise _fail(source, f"{where} {key}", "missing (and no [defaults] value)")
        rows.append(row)
    arrays: dict[str, Any] = {}
    for key in _FIELDS:
        dtype = np.int64 if key in _INT_FIELDS else float
        arrays[key] = np.array([r[key] for r in rows], dtype=dtype)
    w = WinchSet(
        cables=tuple(r["cable"] for r in rows),
        node_id=np.array([r["node_id"] for r in rows], dtype=np.int64),
        bus=bus,
        source=source,
        **arrays,
    )
    validate(w)
    return w


def load_winches(path: str | Path | None = None) -> WinchSet:
    """Load winch parameters from a TOML file (default: the ROCASPECT file)."""
    p = Path(path) if path is not None else DEFAULT_WINCHES
    doc, text = read_toml(p, WinchConfigError)
    return parse_winches(doc, source=str(p), text=text)


def validate(w: WinchSet) -> None:
    """Check cross-field consistency and the ranges of the drive objects they become."""
    src = w.source
    _validate_bus(w.bus, src)
    n = len(w.cables)
    ids = [int(x) for x in w.node_id]
    if len(set(ids)) != len(ids):
        dup = sorted({x for x in ids if ids.count(x) > 1})
        raise _fail(src, "node_id", f"CAN node id(s) {dup} used by more than one winch")
    if w.bus.master_node_id in ids:
        raise _fail(src, "[bus] master_node_id", f"{w.bus.master_node_id} is also the node id of "
                    f"winch {w.cables[ids.index(w.bus.master_node_id)]!r}")
    for key in _FIELDS:
        arr = getattr(w, key)
        if np.shape(arr) != (n,):
            raise _fail(src, key, f"has shape {np.shape(arr)}, expected ({n},)")
        for k in range(n):
            _check_value(src, f"winch {w.cables[k]!r}", key, arr[k].item())
    mpc = metres_per_count(w)
    for k in range(n):
        where = f"winch {w.cables[k]!r} (node {ids[k]})"
        if not w.min_length_m[k] < w.max_length_m[k]:
            raise _fail(src, f"{where} min_length_m", f"{w.min_length_m[k]} must be < max_length_m "
                        f"{w.max_length_m[k]}")
        for key in ("min_length_m", "max_length_m"):
            c = (getattr(w, key)[k] - w.length_at_zero_m[k]) / mpc[k]
            if abs(c) > INT32_MAX:
                raise _fail(src, f"{where} {key}", f"{abs(c):.3g} counts exceed the INTEGER32 "
                            "range of 0x607D (check drum_radius_m, gear_ratio, "
                            "encoder_counts_per_rev)")
        for key in ("max_speed_m_s", "max_accel_m_s2", "profile_speed_m_s", "profile_accel_m_s2",
                    "quick_stop_decel_m_s2", "following_error_m", "position_window_m"):
            c = getattr(w, key)[k] / mpc[k]
            if c > UINT32_MAX:
                raise _fail(src, f"{where} {key}", f"{c:.3g} counts exceed UNSIGNED32")
        if round(w.following_error_time_s[k] * 1e3) > UINT16_MAX:
            raise _fail(src, f"{where} following_error_time_s", "exceeds 65.535 s (0x6066)")
        if w.profile_speed_m_s[k] > w.max_speed_m_s[k]:
            raise _fail(src, f"{where} profile_speed_m_s", "must not exceed max_speed_m_s")
