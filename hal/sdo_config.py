"""A drive's configuration against the HAL's start-up table: compare, write, store, DCF.

The expected configuration is the one the HAL writes at every start
(:func:`hal.drives_config.drive_settings`: the EDS plus the winch parameter file), so
there is one source of truth: whatever the table holds, :func:`compare_configuration`
checks. Of the CiA 301 write sequence (invalidate a PDO, clear its mapping, map, count,
validate) only the final value of each object is compared, and only the entries the HAL
verifies after writing (``Setting.verify``).

- :func:`compare_configuration` reads every expected object by SDO: the differences;
- :func:`apply_configuration` writes the table with the HAL's own
  :func:`~hal.drives_config.configure_node` (read back and verified), then stores it in
  the drive's non-volatile memory (:func:`store_parameters`, 0x1010 sub 1 "save");
- :func:`export_dcf` reads every readable object of the EDS and writes a DCF (the EDS with
  the drive's values as ``ParameterValue`` and its node id), which canopen and CANopen
  tools import.

Blocking (SDO), outside any control cycle. Errors name the node, the cable and the object.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen import objectdictionary

from hal.drives_config import (
    DriveConfigError,
    Setting,
    configure_node,
    sdo_read,
    sdo_write,
)

SAVE_SIGNATURE = 0x65766173  #: "save" (CiA 301, 0x1010)
STORE_ALL = 1  #: 0x1010 sub-index: all parameters
#: objects not part of a configuration (process data, error history, store/restore commands)
NOT_CONFIGURATION = (0x1003, 0x1010, 0x1011)


@dataclass(frozen=True)
class Difference:
    """One object whose value differs from the table (``actual`` None: could not be read)."""

    index: int
    subindex: int
    name: str
    expected: int | str
    actual: int | str | None
    error: str = ""

    def where(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X} {self.name}"

    def as_dict(self) -> dict:
        d = {"index": f"0x{self.index:04X}", "subindex": self.subindex, "name": self.name,
             "expected": self.expected, "actual": self.actual}
        if self.error:
            d["error"] = self.error
        return d

    def __str__(self) -> str:
        if self.actual is None:
            return f"{self.where()}: expected {_fmt(self.expected)}, {self.error}"
        return f"{self.where()}: expected {_fmt(self.expected)}, drive has {_fmt(self.actual)}"


def _fmt(v: int | str | None) -> str:
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 0x10000:
        return f"{v} (0x{v & 0xFFFFFFFF:08X})"
    return str(v)


def expected_values(settings: list[Setting]) -> list[Setting]:
    """The final value of every verified object of a write sequence, in first-write order."""
    final: dict[tuple[int, int], Setting] = {}
    for st in settings:
        final[(st.index, st.subindex)] = st  # a dict keeps the position of the first write
    return [st for st in final.values() if st.verify]


def compare_configuration(node: canopen.RemoteNode, settings: list[Setting],
                          who: str) -> list[Difference]:
    """Read every expected object of ``settings``: the ones that differ (read-only).

    An object the drive refuses to read (SDO abort) is a difference with ``actual`` None;
    a drive that stops answering raises :class:`~hal.drives_config.DriveConfigError`.
    """
    out = []
    for st in expected_values(settings):
        try:
            got = sdo_read(node, st.index, st.subindex, who)
        except DriveConfigError as exc:
            if "no SDO answer" in str(exc):
                raise
            out.append(Difference(st.index, st.subindex, st.name, st.value, None,
                                  str(exc).removeprefix(f"{who}: ")))
            continue
        if got != st.value:
            out.append(Difference(st.index, st.subindex, st.name, st.value, got))
    return out


def store_parameters(node: canopen.RemoteNode, who: str, subindex: int = STORE_ALL) -> None:
    """Store the drive's parameters in its non-volatile memory (0x1010, "save")."""
    od = node.object_dictionary
    if 0x1010 not in od:
        raise DriveConfigError(f"{who}: the EDS has no 0x1010 store parameters: the drive "
                               "cannot store its configuration by SDO")
    sdo_write(node, Setting(0x1010, subindex, SAVE_SIGNATURE, "store parameters (save)"), who)


def apply_configuration(node: canopen.RemoteNode, settings: list[Setting], who: str,
                        store: bool = True) -> None:
    """Write the table (the HAL's sequence, read back and verified), then store it."""
    configure_node(node, settings, who)
    if store:
        store_parameters(node, who)


def _variables(od: canopen.ObjectDictionary) -> list[objectdictionary.ODVariable]:
    out = []
    for obj in od.values():
        subs = [obj] if isinstance(obj, objectdictionary.ODVariable) else list(obj.values())
        out.extend(subs)
    return out


def read_all(node: canopen.RemoteNode, who: str) -> tuple[dict[tuple[int, int], int | str],
                                                           list[str]]:
    """Every readable configuration object of the EDS by SDO: (values, what failed)."""
    values: dict[tuple[int, int], int | str] = {}
    failed: list[str] = []
    for var in _variables(node.object_dictionary):
        if not var.readable or var.index in NOT_CONFIGURATION:
            continue
        if var.access_type in ("rww", "rwr") or var.index in (0x6040, 0x6041):
            continue  # process data, not configuration
        try:
            values[(var.index, var.subindex)] = sdo_read(node, var.index, var.subindex, who)
        except DriveConfigError as exc:
            if "no SDO answer" in str(exc):
                raise
            failed.append(str(exc).removeprefix(f"{who}: "))
    return values, failed


def export_dcf(node: canopen.RemoteNode, path: str | Path, who: str,
               eds: str | Path | None = None) -> tuple[Path, list[str]]:
    """Write the drive's configuration as a DCF; returns the path and the objects that
    could not be read. ``eds``: the EDS to start from (default: the node's dictionary)."""
    od = canopen.import_od(str(eds), node.id) if eds is not None else node.object_dictionary
    values, failed = read_all(node, who)
    for var in _variables(od):
        key = (var.index, var.subindex)
        if key in values:
            var.value = values[key]
            var.value_raw = None
    od.node_id = node.id
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with p.open("w", encoding="utf-8") as f:
        canopen.export_od(od, f, doc_type="dcf")
    return p, failed


__all__ = ["Difference", "SAVE_SIGNATURE", "apply_configuration", "compare_configuration",
           "expected_values", "export_dcf", "read_all", "store_parameters"]
