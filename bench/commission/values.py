"""Object values as CANopen people read them, for ``cdpr commission`` output.

- PDO mapping entries (0x1600-0x17FF, 0x1A00-0x1BFF, sub-index >= 1) in hex with what they
  map: ``0x607A0020 (0x607A:00, 32 bit)``;
- consumer heartbeat entries (0x1016:01..7F, ``node << 16 | time_ms``) as
  ``node 127, 250 ms`` (``not watched (0)`` when the time is 0);
- COB-IDs (0x1005, 0x1012, 0x1014, PDO communication sub-index 1) in hex, with
  ``disabled`` when bit 31 is set; times in ms or us;
- positions, speeds and accelerations of a winch in metres (cable length, m/s, m/s^2)
  with the counts beside them, converted with the winch file's counts per metre.

:func:`describe` gives the text and the JSON keys that carry the unit in their name
(``_counts``, ``_m``, ``_counts_s``, ``_m_s``, ``_counts_s2``, ``_m_s2``).
"""

from __future__ import annotations

from typing import Any

#: absolute positions [counts]: shown as the cable length [m]
POSITIONS = {(0x607A, 0), (0x6064, 0), (0x6062, 0), (0x607D, 1), (0x607D, 2)}
#: position differences [counts]: shown in m
DISTANCES = {(0x6065, 0), (0x6067, 0), (0x607C, 0), (0x60F4, 0)}
#: speeds [counts/s] and accelerations [counts/s^2]
SPEEDS = {(0x607F, 0), (0x6081, 0), (0x60FF, 0), (0x606C, 0)}
ACCELERATIONS = {(0x60C5, 0), (0x60C6, 0), (0x6083, 0), (0x6084, 0), (0x6085, 0)}
MS = {(0x1017, 0), (0x6066, 0)}
COB_IDS = {(0x1005, 0), (0x1012, 0), (0x1014, 0)}


def is_mapping(index: int, subindex: int) -> bool:
    return (0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF) and subindex >= 1


def mapping_text(value: int) -> str:
    """A PDO mapping entry: ``0x607A0020 (0x607A:00, 32 bit)``; 0: ``0 (empty)``."""
    if value == 0:
        return "0 (empty)"
    v = value & 0xFFFFFFFF
    return f"0x{v:08X} (0x{v >> 16:04X}:{(v >> 8) & 0xFF:02X}, {v & 0xFF} bit)"


def heartbeat_text(value: int) -> str:
    """A consumer heartbeat entry (0x1016:xx, ``node << 16 | time_ms``):
    ``node 127, 250 ms``, or ``not watched (0)`` when the time is 0."""
    node, ms = (value >> 16) & 0x7F, value & 0xFFFF
    return f"node {node}, {ms} ms" if ms else f"not watched ({value})"


def cob_id_text(value: int) -> str:
    """A COB-ID entry in hex: ``0x00000201``, with ``(disabled)`` when bit 31 is set."""
    v = value & 0xFFFFFFFF
    return f"0x{v:08X}" + (" (disabled)" if v & 0x80000000 else "")


def describe(index: int, subindex: int, value: Any, winches=None,
             k: int | None = None) -> tuple[str, dict[str, Any]]:
    """``value`` of object ``index:subindex`` as text, and JSON entries with the unit in
    their key (without a prefix: ``counts``, ``m``...; the caller prefixes ``expected_``
    / ``actual_``). ``winches`` (a :class:`controller.winch.WinchSet`) and ``k`` (the
    winch's array index) convert counts to metres; without them counts stay counts."""
    if value is None or not isinstance(value, int) or isinstance(value, bool):
        return str(value), {}
    key = (index, subindex)
    if is_mapping(index, subindex):
        return mapping_text(value), {}
    if index == 0x1016 and subindex >= 1:
        return heartbeat_text(value), {}
    if key in COB_IDS or ((0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF)
                          and subindex == 1):
        return cob_id_text(value), {}
    if key in MS or ((0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF)
                     and subindex == 5):
        return f"{value} ms", {}
    if key == (0x1006, 0):
        return f"{value} us", {}
    if winches is not None and k is not None:
        from controller.winch import counts_to_m_rate

        ax = winches.axis(k)
        if key in POSITIONS:
            m = float(ax.counts_to_m(value))
            return f"{m:.4f} m ({value} counts)", {"counts": value, "m": m}
        if key in DISTANCES:
            m = abs(value) * float(ax.metres_per_count)
            return f"{1e3 * m:.2f} mm ({value} counts)", {"counts": value, "m": m}
        if key in SPEEDS or key in ACCELERATIONS:
            rate = abs(float(counts_to_m_rate(value, winches)[k]))
            unit, tag = ("m/s", "s") if key in SPEEDS else ("m/s²", "s2")
            return (f"{rate:.4g} {unit} ({value} counts/{tag.replace('2', '²')})",
                    {f"counts_{tag}": value, f"m_{tag}": rate})
    if abs(value) >= 0x10000:
        return f"0x{value & 0xFFFFFFFF:08X}", {}
    return str(value), {}


def annotate(diff: dict, index: int, winches=None, k: int | None = None) -> dict:
    """A difference dict (``expected``, ``actual``) with ``expected_text``/``actual_text``
    and the unit-keyed values of :func:`describe` (``expected_m``, ``actual_counts``...)."""
    for side in ("expected", "actual"):
        text, extra = describe(index, int(diff["subindex"]), diff.get(side), winches, k)
        diff[f"{side}_text"] = text if diff.get(side) is not None else diff.get(
            "error", "unreadable")
        diff.update({f"{side}_{u}": v for u, v in extra.items()})
    return diff
