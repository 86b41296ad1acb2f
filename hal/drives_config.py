"""Start-up configuration of the winch drives: the SDO table, written and verified.

:func:`drive_settings` turns the winch parameters (``controller/data/rocaspect_winches.toml``)
into the list of object writes one drive needs for cyclic synchronous position (CSP):
communication (SYNC 0x1005/0x1006, heartbeat 0x1017), master-loss monitoring (consumer
heartbeat 0x1016, error behaviour 0x1029, abort connection option 0x6007), the PDO mapping (RPDO1 =
controlword + target position, TPDO1 = statusword + position actual value, transmission
type 1 = every SYNC, RPDO deadline 0x1400 sub 5) following the CiA 301 procedure
(invalidate, clear, map, count, validate), and the drive parameters (mode 8, following
error, software limits, velocity/acceleration limits, ramps, quick stop and fault
reaction options). This table is the one place that says what a drive is configured with:
the HAL writes and verifies it at start-up and ``cdpr commission check`` compares a drive
against it. Every entry is checked against the EDS first (object exists, is
writable, the value fits its type, mapped objects are mappable), then written by SDO and
read back (:func:`configure_node`). Blocking: run it at start-up, never in the cycle.
Errors name the node, the cable, the object and the value.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen import objectdictionary
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from controller.winch import WinchSet, limits_counts, m_to_counts_rate, metres_per_count

PDO_INVALID = 1 << 31
MODE_CSP = 8
RPDO_MAP: tuple[tuple[int, int], ...] = ((0x6040, 0), (0x607A, 0))  # controlword, target
TPDO_MAP: tuple[tuple[int, int], ...] = ((0x6041, 0), (0x6064, 0))  # statusword, position
SUPPORTED_MODE_CSP_BIT = 1 << 7  # 0x6502

SDO_ABORT_TEXT = {
    0x05040000: "SDO protocol timed out",
    0x06010000: "unsupported access to an object",
    0x06010002: "attempt to write a read only object",
    0x06020000: "object does not exist",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "the number and length of the mapped objects would exceed the PDO length",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06090011: "sub-index does not exist",
    0x06090030: "value range of parameter exceeded",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000022: "data cannot be transferred or stored because of the present device state",
    0x08000024: "no data available",
}


class DriveConfigError(RuntimeError):
    """A drive could not be configured or does not match; the message names node and object."""


def load_eds(path: str | Path, node_id: int) -> canopen.ObjectDictionary:
    """The object dictionary of an EDS file for ``node_id``; DriveConfigError naming the file
    (and the line of a byte that is not UTF-8) when it cannot be read or is not an EDS."""
    import contextlib
    import io

    from controller.tomlfile import decode_utf8

    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise DriveConfigError(f"EDS {p}: cannot read: {e.strerror or e}") from None
    decode_utf8(data, f"EDS {p}", DriveConfigError)
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):  # canopen prints some complaints
            od = canopen.import_od(str(p), node_id)
    except Exception as e:  # configparser, KeyError, ValueError...: any way of not being one
        extra = said.getvalue().strip()
        raise DriveConfigError(f"EDS {p}: not a valid EDS: {type(e).__name__}: {e}"
                               + (f" ({extra})" if extra else "")) from None
    if not len(od) or 0x1000 not in od:
        raise DriveConfigError(f"EDS {p}: no object 0x1000 (device type): not a device EDS")
    return od


@dataclass(frozen=True)
class Setting:
    """One object write of the start-up configuration."""

    index: int
    subindex: int
    value: int
    name: str
    verify: bool = True  #: read back and compare after writing

    def where(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X} {self.name}"


def _od_var(od: canopen.ObjectDictionary, index: int, subindex: int) -> objectdictionary.ODVariable:
    obj = od[index]
    if not isinstance(obj, objectdictionary.ODVariable):
        obj = obj[subindex]
    return obj


def interpolation_period(period_us: int) -> tuple[int, int]:
    """0x60C2 (value, index) with value * 10**index s = ``period_us``, value 1..255."""
    for index in (-3, -4, -5, -6, -2, -1):
        scale = 10 ** (index + 6)  # microseconds per unit
        if period_us % scale == 0 and 1 <= period_us // scale <= 255:
            return period_us // scale, index
    raise DriveConfigError(f"SYNC period {period_us} us cannot be written as 0x60C2 value*10^index")


def pdo_settings(
    od: canopen.ObjectDictionary,
    kind: str,
    entries: tuple[tuple[int, int], ...],
    trans_type: int,
    event_timer_ms: int | None = None,
) -> list[Setting]:
    """CiA 301 sequence mapping ``entries`` (index, subindex) to PDO 1 of ``kind`` rpdo/tpdo."""
    comm, mapping = (0x1400, 0x1600) if kind == "rpdo" else (0x1800, 0x1A00)
    name = kind.upper() + "1"
    cob = int(_od_var(od, comm, 1).default) & 0x7FF
    out = [
        Setting(comm, 1, cob | PDO_INVALID, f"{name} COB-ID (invalid)", verify=False),
        Setting(comm, 2, trans_type, f"{name} transmission type"),
    ]
    if event_timer_ms is not None:
        out.append(Setting(comm, 5, event_timer_ms, f"{name} event timer [ms]"))
    out.append(Setting(mapping, 0, 0, f"{name} mapping count (clear)", verify=False))
    for i, (index, sub) in enumerate(entries, start=1):
        var = _od_var(od, index, sub)
        out.append(Setting(mapping, i, index << 16 | sub << 8 | len(var), f"{name} map {var.name}"))
    out.append(Setting(mapping, 0, len(entries), f"{name} mapping count"))
    out.append(Setting(comm, 1, cob, f"{name} COB-ID (valid)"))
    return out


def consumer_heartbeat(node_id: int, time_ms: int) -> int:
    """0x1016 sub-index value watching ``node_id``'s heartbeat for ``time_ms`` (CiA 301 7.5.2.
    19: bits 16-23 node id, bits 0-15 consumer heartbeat time [ms]; 0 = not watched)."""
    if time_ms <= 0:
        return 0
    return (int(node_id) & 0x7F) << 16 | (int(time_ms) & 0xFFFF)


#: (object, option, what it does) of the stop options that leave a hanging load to the brake
#: alone or let it coast (CiA 402 0x605A, 0x605E, 0x6007); see ``rocaspect_winches.toml``.
NOT_HOLDING: tuple[tuple[str, int, str], ...] = (
    ("quick_stop_option", 0, "0x605A = 0: a quick stop disables the drive function (coasts)"),
    ("quick_stop_option", 1, "0x605A = 1: a quick stop ends in Switch On Disabled (no torque)"),
    ("quick_stop_option", 2, "0x605A = 2: a quick stop ends in Switch On Disabled (no torque)"),
    ("fault_reaction_option", 0, "0x605E = 0: a fault switches the power off at once (coasts)"),
    ("abort_connection_option", 0, "0x6007 = 0: a drive keeps moving when the master is lost"),
    ("abort_connection_option", 2,
     "0x6007 = 2: master loss disables voltage at once (coasts)"),
)


#: Objects that decide whether a drive stops when its master dies (CiA 301 / CiA 402):
#: (index, subindex) -> what a value other than the table's does. A drive that differs on
#: one of them is a *safety failure* of ``cdpr commission check``: with the power-on values
#: of many drives (0x1016 = 0, 0x1400:5 = 0, 0x6007 = 1, 0x605A = 2) a drive whose master
#: was killed keeps following its last setpoint for seconds.
SAFETY_OBJECTS: dict[tuple[int, int], str] = {
    (0x1016, 1): "the drive must watch the master's heartbeat (node, time): otherwise it "
                 "keeps moving after the master died",
    (0x1017, 0): "the drive's own heartbeat: without it the master cannot see a drive die",
    (0x1029, 1): "error behaviour on a communication error (master heartbeat lost)",
    (0x1400, 5): "RPDO deadline: without it a drive keeps its last setpoint when the "
                 "master's setpoints stop",
    (0x6007, 0): "abort connection option: what the drive does when the master is lost "
                 "(3 = quick stop; 0 = nothing, 1 = fault signal only, 2 = coasts)",
    (0x605A, 0): "quick stop option: 6 stops on the quick-stop ramp and holds the load in "
                 "Quick Stop Active; 0-2 drop the holding torque under a hanging load",
    (0x605E, 0): "fault reaction option: 0 switches the power off at once (the load coasts)",
}


def safety_failure(index: int, subindex: int, expected: int | str,
                   actual: int | str | None) -> str | None:
    """Why ``actual`` (the drive's value; None: unreadable) of a safety object is a safety
    failure against the table's safe value ``expected``, or None (not a safety object, or
    no difference)."""
    why = SAFETY_OBJECTS.get((index, subindex))
    if why is None or actual == expected:
        return None
    if actual is None:
        return f"cannot be read: {why}"
    if index == 0x1016 and isinstance(actual, int):
        node, ms = (actual >> 16) & 0x7F, actual & 0xFFFF
        have = "not watched" if ms == 0 else f"node {node}, {ms} ms"
        return f"master heartbeat {have}: {why}"
    if (index, subindex) == (0x1400, 5) and actual == 0:
        return f"no RPDO deadline (0): {why}"
    return why


def format_object_value(index: int, subindex: int, value: int | str | None) -> str:
    """A value as CANopen people read it: 0x1016 as ``0x007F00FA (node 127, 250 ms)``, a
    PDO mapping or COB-ID in hex, times in ms, small numbers in decimal."""
    if value is None or not isinstance(value, int) or isinstance(value, bool):
        return str(value)
    if index == 0x1016:
        return (f"0x{value:08X} (node {(value >> 16) & 0x7F}, {value & 0xFFFF} ms)"
                if value & 0xFFFF else f"{value} (not watched)")
    if index in (0x1017,) or (0x1400 <= index <= 0x15FF and subindex == 5):
        return f"{value} ms"
    if abs(value) >= 0x10000:
        return f"0x{value & 0xFFFFFFFF:08X}"
    return str(value)


def holding_problems(w: WinchSet) -> list[str]:
    """Stop options of the winch parameters that do not end holding the load (empty: every
    stop ends in Quick Stop Active or on the quick-stop ramp), naming winch and object."""
    out = []
    for key, value, what in NOT_HOLDING:
        for k in range(len(w)):
            if int(getattr(w, key)[k]) == value:
                out.append(f"{w.source}: winch {w.cables[k]!r} (node {int(w.node_id[k])}) "
                           f"{key}: {what}")
    if w.bus.master_heartbeat_timeout_s <= 0:
        out.append(f"{w.source}: [bus] master_heartbeat_timeout_s = 0: the drives do not watch "
                   "the master's heartbeat")
    return out


def drive_settings(w: WinchSet, k: int, od: canopen.ObjectDictionary) -> list[Setting]:
    """The start-up writes of winch ``k`` (array index) for CSP, in order."""
    bus = w.bus
    mpc = metres_per_count(w)[k]
    lo, hi = (int(x[k]) for x in limits_counts(w))

    def rate(x: float) -> int:
        return int(round(float(m_to_counts_rate(x, w)[k])))

    period_us = bus.sync_period_us
    ip_value, ip_index = interpolation_period(period_us)
    s: list[Setting] = [
        Setting(0x1005, 0, 0x80, "COB-ID SYNC"),
        Setting(0x1006, 0, period_us, "communication cycle period [us]"),
        Setting(0x1017, 0, bus.heartbeat_ms, "producer heartbeat time [ms]"),
        Setting(0x1016, 1, consumer_heartbeat(bus.master_node_id, bus.master_heartbeat_timeout_ms),
                "consumer heartbeat time (master)"),
        Setting(0x1029, 1, int(w.comm_error_behaviour[k]), "error behaviour: communication error"),
    ]
    s += pdo_settings(od, "rpdo", RPDO_MAP, 1, bus.rpdo_timeout_ms)
    s += pdo_settings(od, "tpdo", TPDO_MAP, 1)
    s += [
        Setting(0x6060, 0, MODE_CSP, "modes of operation (CSP)"),
        Setting(0x60C2, 1, ip_value, "interpolation time period value"),
        Setting(0x60C2, 2, ip_index, "interpolation time index"),
        Setting(0x6065, 0, int(round(w.following_error_m[k] / mpc)), "following error window"),
        Setting(0x6066, 0, int(round(w.following_error_time_s[k] * 1e3)),
                "following error time out [ms]"),
        Setting(0x6067, 0, int(round(w.position_window_m[k] / mpc)), "position window"),
        Setting(0x607D, 1, lo, "software position limit min"),
        Setting(0x607D, 2, hi, "software position limit max"),
        Setting(0x607F, 0, rate(w.max_speed_m_s[k]), "max profile velocity"),
        Setting(0x60C5, 0, rate(w.max_accel_m_s2[k]), "max acceleration"),
        Setting(0x6081, 0, rate(w.profile_speed_m_s[k]), "profile velocity"),
        Setting(0x6083, 0, rate(w.profile_accel_m_s2[k]), "profile acceleration"),
        Setting(0x6084, 0, rate(w.profile_accel_m_s2[k]), "profile deceleration"),
        Setting(0x6085, 0, rate(w.quick_stop_decel_m_s2[k]), "quick stop deceleration"),
        Setting(0x605A, 0, int(w.quick_stop_option[k]), "quick stop option code"),
        Setting(0x605E, 0, int(w.fault_reaction_option[k]), "fault reaction option code"),
        Setting(0x6007, 0, int(w.abort_connection_option[k]), "abort connection option code"),
        Setting(0x6076, 0, int(round(w.rated_torque_nm[k] * 1e3)), "motor rated torque [mN*m]"),
    ]
    return s


def check_against_eds(settings: list[Setting], od: canopen.ObjectDictionary, who: str) -> None:
    """Every setting names a writable object of the EDS and fits its type; PDO maps mappable."""
    for st in settings:
        try:
            var = _od_var(od, st.index, st.subindex)
        except KeyError:
            raise DriveConfigError(f"{who}: {st.where()}: not in the EDS") from None
        if not var.writable:
            raise DriveConfigError(f"{who}: {st.where()}: read-only in the EDS ({var.access_type})")
        try:
            var.encode_raw(st.value)
        except (ValueError, struct.error) as exc:
            raise DriveConfigError(
                f"{who}: {st.where()} = {st.value}: does not fit the EDS data type "
                f"0x{var.data_type:04X}: {exc}") from None
        if 0x1600 <= st.index <= 0x17FF or 0x1A00 <= st.index <= 0x1BFF:
            if st.subindex and st.value:
                index, sub = st.value >> 16, (st.value >> 8) & 0xFF
                mapped = _od_var(od, index, sub)
                if not mapped.pdo_mappable:
                    raise DriveConfigError(f"{who}: {st.where()}: 0x{index:04X} {mapped.name} "
                                           "is not PDO-mappable in the EDS")


def _abort_text(exc: SdoAbortedError) -> str:
    return f"SDO abort 0x{exc.code:08X} ({SDO_ABORT_TEXT.get(exc.code, 'see CiA 301')})"


def sdo_read(node: canopen.RemoteNode, index: int, subindex: int, who: str) -> int | str:
    """Read one object by SDO, decoded with the EDS type; DriveConfigError on failure."""
    var = _od_var(node.object_dictionary, index, subindex)
    try:
        data = node.sdo.upload(index, subindex)
    except SdoAbortedError as exc:
        raise DriveConfigError(f"{who}: reading 0x{index:04X}:{subindex:02X} {var.name}: "
                               f"{_abort_text(exc)}") from exc
    except SdoCommunicationError as exc:
        raise DriveConfigError(f"{who}: reading 0x{index:04X}:{subindex:02X} {var.name}: "
                               f"no SDO answer ({exc})") from exc
    except (struct.error, ValueError, IndexError, TypeError) as exc:  # a malformed answer
        raise DriveConfigError(f"{who}: reading 0x{index:04X}:{subindex:02X} {var.name}: "
                               f"malformed SDO answer ({type(exc).__name__}: {exc})") from exc
    try:
        return var.decode_raw(data)
    except (struct.error, ValueError, objectdictionary.ObjectDictionaryError) as exc:
        raise DriveConfigError(f"{who}: reading 0x{index:04X}:{subindex:02X} {var.name}: "
                               f"{len(data)} bytes ({bytes(data).hex()}) do not decode as "
                               f"type 0x{var.data_type:04X}: {exc}") from exc


def sdo_write(node: canopen.RemoteNode, st: Setting, who: str) -> None:
    """Write one setting by SDO; DriveConfigError naming the object on failure."""
    var = _od_var(node.object_dictionary, st.index, st.subindex)
    try:
        node.sdo.download(st.index, st.subindex, var.encode_raw(st.value))
    except SdoAbortedError as exc:
        raise DriveConfigError(f"{who}: writing {st.where()} = {st.value}: {_abort_text(exc)}"
                               ) from exc
    except SdoCommunicationError as exc:
        raise DriveConfigError(f"{who}: writing {st.where()} = {st.value}: no SDO answer ({exc})"
                               ) from exc
    except (struct.error, ValueError, IndexError, TypeError) as exc:  # a malformed answer
        raise DriveConfigError(f"{who}: writing {st.where()} = {st.value}: malformed SDO "
                               f"answer ({type(exc).__name__}: {exc})") from exc


def verify_identity(node: canopen.RemoteNode, who: str) -> None:
    """Device type (0x1000), vendor id and product code (0x1018) and CSP support match the EDS."""
    od = node.object_dictionary
    checks = [
        (0x1000, 0, _od_var(od, 0x1000, 0).default, "device type"),
        (0x1018, 1, od.device_information.vendor_number or _od_var(od, 0x1018, 1).default,
         "vendor id"),
        (0x1018, 2, od.device_information.product_number or _od_var(od, 0x1018, 2).default,
         "product code"),
    ]
    for index, sub, want, what in checks:
        got = sdo_read(node, index, sub, who)
        if got != want:
            raise DriveConfigError(f"{who}: 0x{index:04X}:{sub:02X} {what} is 0x{got:08X}, "
                                   f"the EDS says 0x{want:08X}: wrong device on this node id?")
    modes = sdo_read(node, 0x6502, 0, who)
    if not int(modes) & SUPPORTED_MODE_CSP_BIT:
        raise DriveConfigError(f"{who}: 0x6502 supported drive modes 0x{modes:08X} lacks "
                               "cyclic synchronous position (bit 7)")


def configure_node(node: canopen.RemoteNode, settings: list[Setting], who: str) -> None:
    """Write ``settings`` in order, then read back and compare every verified one."""
    check_against_eds(settings, node.object_dictionary, who)
    for st in settings:
        sdo_write(node, st, who)
    final: dict[tuple[int, int], Setting] = {}
    for st in settings:
        if st.verify:
            final[(st.index, st.subindex)] = st
    for st in final.values():
        got = sdo_read(node, st.index, st.subindex, who)
        if got != st.value:
            raise DriveConfigError(f"{who}: {st.where()} reads back {got}, wrote {st.value}")
    mode = sdo_read(node, 0x6061, 0, who)
    if mode != MODE_CSP:
        raise DriveConfigError(f"{who}: 0x6061 modes of operation display is {mode}, expected "
                               f"{MODE_CSP} (CSP) after writing 0x6060")


def pdo_struct(od: canopen.ObjectDictionary, entries: tuple[tuple[int, int], ...]) -> struct.Struct:
    """Little-endian struct packing the mapped objects of a PDO, from their EDS types."""
    fmt = "<"
    for index, sub in entries:
        var = _od_var(od, index, sub)
        st = var.STRUCT_TYPES.get(var.data_type)
        if st is None:
            raise DriveConfigError(f"0x{index:04X} {var.name}: type 0x{var.data_type:04X} "
                                   "cannot be packed in a PDO")
        fmt += st.format.lstrip("<>=!@")
    return struct.Struct(fmt)
