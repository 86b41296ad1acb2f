"""The site description (``cdpr-site/1``, TOML): which robot, which files, which buses.

One file says everything a hardware command needs to reach the robot: the robot
description, the winch file, the drives' EDS, the load-cell register map and
calibration, the endpoints (CAN as python-can takes it, Modbus/TCP or RTU, the
``cdpr-tracker/1`` tracker or none), the master's clock and the site's limits (tension
window [N], the speed allowed on a first run [%], the workspace box [m] in F_b).
docs/formats/site.md documents the format.

- :func:`load_site` reads and validates a file: :class:`SiteError` names the file, the
  line, the field, the value and the allowed range; nothing is opened.
- :func:`merge_site` merges a site with the command line's values (``--can``,
  ``--modbus``, ``--tracker``, ... given on the command line win) into
  :class:`HardwareSettings`, the typed values a command opens the hardware with.
- :func:`dumps_site` / :func:`write_site` write one (``cdpr sim --write-site``).

Relative paths in a site file resolve against the folder of the site file. Light: no bus
library is imported until an endpoint is parsed.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controller.tomlfile import Locator, read_toml

if TYPE_CHECKING:
    from hal.can_bus import CanSpec
    from hal.modbus_config import ModbusEndpoint
    from hal.tracker import TrackerSpec

FORMAT = "cdpr-site/1"
CLOCKS = ("wall", "sync")
#: interfaces whose bit rate python-can sets when opening (others: set by the OS or a hub)
BITRATE_INTERFACES_SKIP = ("virtual", "socketcand", "socketcan")
TENSION_MAX_N = 1.0e5  #: the largest tension a site may allow [N]
WORKSPACE_MAX_M = 1.0e3  #: the largest workspace coordinate [m]

_TABLES: dict[str | None, set[str]] = {
    None: {"format", "name", "clock", "robot", "drives", "loadcells", "can", "modbus",
           "tracker", "limits", "preflight", "state", "sim"},
    "robot": {"description", "winches"},
    "drives": {"eds"},
    "loadcells": {"map", "calibration"},
    "can": {"interface", "bitrate"},
    "modbus": {"endpoint", "device", "baudrate", "framing"},
    "tracker": {"endpoint"},
    "limits": {"tension_min_N", "tension_max_N", "first_run_speed_pct", "workspace_min_m",
               "workspace_max_m"},
    "preflight": {"require_stored_safety", "require_tracker"},
    "state": {"file"},
    "sim": {"pid", "control", "scenario", "clock"},
}


class SiteError(ValueError):
    """An invalid site file; the message names file, line, field, value and allowed range."""


@dataclass(frozen=True)
class SiteLimits:
    """What the site allows: tension window [N], first-run speed [% of the path's], and
    the workspace box in F_b [m] (None: no box)."""

    tension_min_N: float
    tension_max_N: float
    first_run_speed_pct: float = 10.0
    workspace_min_m: tuple[float, float, float] | None = None
    workspace_max_m: tuple[float, float, float] | None = None

    def outside_box(self, xyz: Any) -> bool:
        """Whether the point ``xyz`` (3,) [m] lies outside the workspace box."""
        if self.workspace_min_m is None or self.workspace_max_m is None:
            return False
        return any(not lo <= float(v) <= hi for v, lo, hi in
                   zip(xyz, self.workspace_min_m, self.workspace_max_m, strict=True))


@dataclass(frozen=True)
class Site:
    """A parsed site file (paths absolute; None where the site leaves the default)."""

    path: Path
    name: str
    robot: str  #: shipped robot name or absolute robot.toml path
    eds: Path
    limits: SiteLimits
    winches: Path | None = None
    loadcell_map: Path | None = None
    loadcell_calibration: Path | None = None
    can: CanSpec | None = None
    bitrate: int | None = None
    modbus: ModbusEndpoint | None = None
    tracker: TrackerSpec | None = None  #: None: no tracker (``endpoint = "none"``)
    clock: str = "wall"  #: the master's clock: wall, or sync (drives follow the SYNC)
    require_stored_safety: bool = True
    require_tracker: bool = True
    state_file: Path | None = None  #: referencing state (commission reference)
    sim: dict[str, Any] = field(default_factory=dict)  #: written by ``cdpr sim``


@dataclass(frozen=True)
class HardwareSettings:
    """The values a hardware command opens the hardware with: the command line's where
    given, else the site's, else the defaults."""

    can: CanSpec | None
    modbus: ModbusEndpoint | None
    tracker: TrackerSpec | None
    eds: str | None
    winches: str | None
    loadcell_map: str | None
    loadcell_calibration: str | None
    hal_clock: str
    site: Site | None = None


# ---------------------------------------------------------------------------- reading


class _Reader:
    """Field access with file, line and field in every error."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.loc = Locator(text)

    def fail(self, table: str | None, key: str | None, value: Any, why: str) -> SiteError:
        where = self.loc.where(str(self.path), table, None, key)
        shown = "" if value is _MISSING else f" = {value!r}"
        return SiteError(f"{where}{shown}: {why}")

    def table(self, data: dict, name: str, required: bool) -> dict | None:
        v = data.get(name)
        if v is None:
            if required:
                raise self.fail(None, None, _MISSING, f"missing table [{name}]")
            return None
        if not isinstance(v, dict):
            raise self.fail(None, name, v, f"must be a table [{name}]")
        unknown = sorted(set(v) - _TABLES[name])
        if unknown:
            raise self.fail(name, unknown[0], v[unknown[0]],
                            f"unknown key (allowed: {', '.join(sorted(_TABLES[name]))})")
        return v

    def text(self, t: dict, table: str | None, key: str, required: bool = False) -> str | None:
        v = t.get(key)
        if v is None:
            if required:
                raise self.fail(table, key, _MISSING, "missing (a string)")
            return None
        if not isinstance(v, str) or not v.strip():
            raise self.fail(table, key, v, "must be a non-empty string")
        return v.strip()

    def file(self, t: dict, table: str | None, key: str, required: bool = False) -> Path | None:
        v = self.text(t, table, key, required)
        if v is None:
            return None
        p = Path(v).expanduser()
        p = p if p.is_absolute() else (self.path.parent / p)
        if not p.is_file():
            raise self.fail(table, key, v, f"no such file ({p.resolve()}; relative paths "
                                           f"resolve against the site file's folder)")
        return p.resolve()

    def number(self, t: dict, table: str, key: str, lo: float, hi: float,
               default: float | None = None, lo_open: bool = False) -> float:
        v = t.get(key)
        if v is None:
            if default is None:
                raise self.fail(table, key, _MISSING, f"missing (a number in "
                                                      f"{'(' if lo_open else '['}{lo:g}, {hi:g}])")
            return default
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                or v < lo or v > hi or (lo_open and v == lo):
            raise self.fail(table, key, v, f"must be a finite number in "
                                           f"{'(' if lo_open else '['}{lo:g}, {hi:g}]")
        return float(v)

    def flag(self, t: dict, table: str, key: str, default: bool) -> bool:
        v = t.get(key, default)
        if not isinstance(v, bool):
            raise self.fail(table, key, v, "must be true or false")
        return v

    def point(self, t: dict, table: str, key: str) -> tuple[float, float, float] | None:
        v = t.get(key)
        if v is None:
            return None
        if (not isinstance(v, list) or len(v) != 3 or any(
                isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x)
                or abs(x) > WORKSPACE_MAX_M for x in v)):
            raise self.fail(table, key, v, f"must be [x, y, z] in metres, each finite and "
                                           f"within +-{WORKSPACE_MAX_M:g} m")
        return (float(v[0]), float(v[1]), float(v[2]))


_MISSING = object()


def _endpoint(r: _Reader, table: str, key: str, text: str, parse, error) -> Any:
    try:
        return parse(text)
    except error as exc:  # the parser's "--can 'SPEC': why" without the option's name
        why = re.sub(r"^--\w+:? ('[^']*': )?", "", str(exc))
        raise r.fail(table, key, text, why) from None


def _can(r: _Reader, t: dict | None) -> tuple[CanSpec | None, int | None]:
    if t is None:
        return None, None
    from hal.can_bus import CanSpecError, parse_can_spec

    text = r.text(t, "can", "interface", required=True)
    spec = _endpoint(r, "can", "interface", text, parse_can_spec, CanSpecError)
    bitrate = None
    if "bitrate" in t:
        from controller.winch import STANDARD_BITRATES

        b = t["bitrate"]
        if isinstance(b, bool) or not isinstance(b, int) or b not in STANDARD_BITRATES:
            raise r.fail("can", "bitrate", b, f"must be a CiA bit rate {STANDARD_BITRATES}")
        bitrate = int(b)
    return spec, bitrate


def _modbus(r: _Reader, t: dict | None) -> ModbusEndpoint | None:
    if t is None:
        return None
    from hal.modbus_config import ModbusSpecError, parse_modbus_spec

    endpoint = r.text(t, "modbus", "endpoint")
    device = r.text(t, "modbus", "device")
    if (endpoint is None) == (device is None):
        raise r.fail("modbus", None, _MISSING, "give either endpoint = \"HOST:PORT\" (or "
                                               "\"rtu-tcp:HOST:PORT\") or device = ... with "
                                               "baudrate (serial RTU)")
    if endpoint is not None:
        for key in ("baudrate", "framing"):
            if key in t:
                raise r.fail("modbus", key, t[key], "only with device = ... (serial RTU)")
        return _endpoint(r, "modbus", "endpoint", endpoint, parse_modbus_spec, ModbusSpecError)
    baud = t.get("baudrate")
    if isinstance(baud, bool) or not isinstance(baud, int):
        raise r.fail("modbus", "baudrate", baud if baud is not None else _MISSING,
                     "serial RTU needs an integer baud rate in 300..4000000")
    framing = r.text(t, "modbus", "framing") or "8N1"
    spec = f"rtu:{device}:{baud}:{framing}"
    try:
        return parse_modbus_spec(spec)
    except ModbusSpecError as exc:
        key = "framing" if "framing" in str(exc) else "baudrate"
        raise r.fail("modbus", key, t.get(key, framing),
                     re.sub(r"^--\w+:? ('[^']*': )?", "", str(exc))) from None


def _tracker(r: _Reader, t: dict | None) -> TrackerSpec | None:
    if t is None:
        return None
    from hal.tracker import TrackerSpecError, parse_tracker_spec

    text = r.text(t, "tracker", "endpoint", required=True)
    spec = _endpoint(r, "tracker", "endpoint", text, parse_tracker_spec, TrackerSpecError)
    return None if spec.kind == "none" else spec


def _limits(r: _Reader, t: dict) -> SiteLimits:
    lo = r.number(t, "limits", "tension_min_N", 0.0, TENSION_MAX_N)
    hi = r.number(t, "limits", "tension_max_N", 0.0, TENSION_MAX_N, lo_open=True)
    if hi <= lo:
        raise r.fail("limits", "tension_max_N", t["tension_max_N"],
                     f"must be above tension_min_N = {lo:g} N")
    pct = r.number(t, "limits", "first_run_speed_pct", 0.0, 100.0, default=10.0,
                   lo_open=True)
    wmin = r.point(t, "limits", "workspace_min_m")
    wmax = r.point(t, "limits", "workspace_max_m")
    if (wmin is None) != (wmax is None):
        key = "workspace_max_m" if wmin is not None else "workspace_min_m"
        raise r.fail("limits", key, _MISSING, "missing: the workspace box needs both "
                                              "workspace_min_m and workspace_max_m")
    if wmin is not None and wmax is not None and not all(a < b for a, b in zip(wmin, wmax,
                                                                              strict=True)):
        raise r.fail("limits", "workspace_max_m", list(wmax),
                     f"must be above workspace_min_m = {list(wmin)} in x, y and z")
    return SiteLimits(lo, hi, pct, wmin, wmax)


def _robot(r: _Reader, t: dict) -> str:
    from controller.robot import SHIPPED

    ref = r.text(t, "robot", "description", required=True)
    assert ref is not None
    if ref in SHIPPED:
        return ref
    p = r.file(t, "robot", "description", required=True)
    return str(p)


def parse_site(data: dict[str, Any], path: str | Path, text: str = "") -> Site:
    """A :class:`Site` from a parsed TOML mapping (``text`` for the line numbers)."""
    p = Path(path).resolve() if str(path) != "<memory>" else Path.cwd() / "<memory>"
    r = _Reader(p, text)
    unknown = sorted(set(data) - _TABLES[None])
    if unknown:
        raise r.fail(None, unknown[0], _MISSING, f"unknown key (allowed: "
                                                 f"{', '.join(sorted(_TABLES[None]))})")
    fmt = data.get("format")
    if fmt != FORMAT:
        raise r.fail(None, "format", fmt if fmt is not None else _MISSING,
                     f"must be {FORMAT!r}")
    name = r.text(data, None, "name") or p.stem
    clock = data.get("clock", "wall")
    if clock not in CLOCKS:
        raise r.fail(None, "clock", clock, f"must be one of {', '.join(CLOCKS)}")
    robot_t = r.table(data, "robot", required=True)
    drives_t = r.table(data, "drives", required=True)
    cells_t = r.table(data, "loadcells", required=False) or {}
    pre_t = r.table(data, "preflight", required=False) or {}
    state_t = r.table(data, "state", required=False) or {}
    sim_t = r.table(data, "sim", required=False) or {}
    limits_t = r.table(data, "limits", required=True)
    assert robot_t is not None and drives_t is not None and limits_t is not None
    can, bitrate = _can(r, r.table(data, "can", required=False))
    state = r.text(state_t, "state", "file")
    return Site(
        path=p, name=name, robot=_robot(r, robot_t),
        eds=r.file(drives_t, "drives", "eds", required=True),  # type: ignore[arg-type]
        limits=_limits(r, limits_t),
        winches=r.file(robot_t, "robot", "winches"),
        loadcell_map=r.file(cells_t, "loadcells", "map"),
        loadcell_calibration=r.file(cells_t, "loadcells", "calibration"),
        can=can, bitrate=bitrate,
        modbus=_modbus(r, r.table(data, "modbus", required=False)),
        tracker=_tracker(r, r.table(data, "tracker", required=False)),
        clock=clock,
        require_stored_safety=r.flag(pre_t, "preflight", "require_stored_safety", True),
        require_tracker=r.flag(pre_t, "preflight", "require_tracker", True),
        state_file=None if state is None else (p.parent / Path(state).expanduser()).resolve(),
        sim=dict(sim_t),
    )


def load_site(path: str | Path) -> Site:
    """Read and validate a site file (:class:`SiteError` naming file, line and field)."""
    data, text = read_toml(path, SiteError)
    return parse_site(data, path, text)


# ---------------------------------------------------------------------------- merging


def merge_site(site: Site | None, *, can: CanSpec | str | None = None,
               modbus: ModbusEndpoint | str | None = None,
               tracker: TrackerSpec | str | None = None, eds: str | Path | None = None,
               winches: str | Path | None = None, loadcell_map: str | Path | None = None,
               loadcell_calibration: str | Path | None = None, hal_clock: str | None = None,
               eds_default: str | Path | None = None,
               can_default: CanSpec | str | None = None) -> HardwareSettings:
    """The command line's values (not None) over the site's over the defaults.

    Strings are parsed with the HAL's own parsers (``--can``, ``--modbus``, ``--tracker``
    forms); a tracker ``"none"`` means no tracker. Raises ValueError (CanSpecError, ...)
    on a malformed string. The site's CAN bit rate goes to python-can for interfaces that
    set it when opening (pcan, kvaser, ...)."""
    from hal.can_bus import parse_can_spec
    from hal.modbus_config import parse_modbus_spec
    from hal.tracker import parse_tracker_spec

    if isinstance(can, str):
        can = parse_can_spec(can)
    if isinstance(modbus, str):
        modbus = parse_modbus_spec(modbus)
    if isinstance(tracker, str):
        tracker = parse_tracker_spec(tracker)
    if tracker is not None and tracker.kind == "none":
        tracker_out = None
    elif tracker is not None:
        tracker_out = tracker
    else:
        tracker_out = site.tracker if site is not None else None
    s = site
    if can is None and s is not None and s.can is not None:
        can = _with_bitrate(s.can, s.bitrate)
    if can is None and can_default is not None:
        can = parse_can_spec(can_default) if isinstance(can_default, str) else can_default

    def pick(given, from_site, default=None):
        if given is not None:
            return str(given)
        if from_site is not None:
            return str(from_site)
        return None if default is None else str(default)

    return HardwareSettings(
        can=can,
        modbus=modbus if modbus is not None else (s.modbus if s is not None else None),
        tracker=tracker_out,
        eds=pick(eds, s.eds if s else None, eds_default),
        winches=pick(winches, s.winches if s else None),
        loadcell_map=pick(loadcell_map, s.loadcell_map if s else None),
        loadcell_calibration=pick(loadcell_calibration, s.loadcell_calibration if s else None),
        hal_clock=hal_clock or (s.clock if s is not None else "wall"),
        site=s,
    )


def _with_bitrate(spec: CanSpec, bitrate: int | None) -> CanSpec:
    if bitrate is None or spec.interface in BITRATE_INTERFACES_SKIP:
        return spec
    from dataclasses import replace

    return replace(spec, options={**spec.options, "bitrate": bitrate})


def check_site_files(site: Site) -> None:
    """Load the files the site names (robot, winches, map, calibration) and check that they
    fit together and with the site's bit rate; SiteError naming the site and the file."""
    from controller.loadcell_map import DEFAULT_MAP, load_register_map
    from controller.robot import resolve_robot
    from controller.winch import load_winches
    from hal.loadcell_calibration import load_calibration

    try:
        robot = resolve_robot(site.robot)
        w = load_winches(site.winches)
        rmap = load_register_map(site.loadcell_map) if site.loadcell_map else DEFAULT_MAP
        if site.loadcell_calibration is not None:
            load_calibration(site.loadcell_calibration, rmap.cables)
    except ValueError as exc:  # RobotFileError, WinchConfigError, RegisterMapError, ...
        raise SiteError(f"{site.path}: {exc}") from None
    if tuple(robot.cable_ids) != tuple(w.cables) or tuple(rmap.cables) != tuple(w.cables):
        raise SiteError(f"{site.path}: the robot {robot.name} has cables {robot.cable_ids}, "
                        f"the winch file {w.source} {w.cables}, the register map "
                        f"{rmap.source} {rmap.cables}: they must be the same")
    if site.bitrate is not None and site.bitrate != w.bus.bitrate:
        r = _Reader(site.path, site.path.read_text(encoding="utf-8"))
        raise r.fail("can", "bitrate", site.bitrate, f"the winch file {w.source} says "
                                                     f"[bus] bitrate = {w.bus.bitrate}")


# ---------------------------------------------------------------------------- writing


def _rel(p: str | Path | None, folder: Path) -> str | None:
    if p is None:
        return None
    q = Path(p).resolve()
    try:
        return str(q.relative_to(folder))
    except ValueError:
        return str(q)


def site_dict(site: Site, folder: Path | None = None) -> dict[str, Any]:
    """The site as a TOML mapping; paths relative to ``folder`` where inside it."""
    folder = (folder or site.path.parent).resolve()
    robot = site.robot if "/" not in site.robot else _rel(site.robot, folder)
    d: dict[str, Any] = {"format": FORMAT, "name": site.name, "clock": site.clock,
                         "robot": {"description": robot}, "drives": {"eds": _rel(site.eds,
                                                                                 folder)}}
    if site.winches is not None:
        d["robot"]["winches"] = _rel(site.winches, folder)
    cells = {k: _rel(v, folder) for k, v in (("map", site.loadcell_map),
                                              ("calibration", site.loadcell_calibration))
             if v is not None}
    if cells:
        d["loadcells"] = cells
    if site.can is not None:
        d["can"] = {"interface": str(site.can)}
        if site.bitrate is not None:
            d["can"]["bitrate"] = site.bitrate
    if site.modbus is not None:
        d["modbus"] = {"endpoint": str(site.modbus)}
    d["tracker"] = {"endpoint": str(site.tracker) if site.tracker is not None else "none"}
    lim = site.limits
    d["limits"] = {"tension_min_N": lim.tension_min_N, "tension_max_N": lim.tension_max_N,
                   "first_run_speed_pct": lim.first_run_speed_pct}
    if lim.workspace_min_m is not None and lim.workspace_max_m is not None:
        d["limits"]["workspace_min_m"] = list(lim.workspace_min_m)
        d["limits"]["workspace_max_m"] = list(lim.workspace_max_m)
    d["preflight"] = {"require_stored_safety": site.require_stored_safety,
                      "require_tracker": site.require_tracker}
    if site.state_file is not None:
        d["state"] = {"file": _rel(site.state_file, folder)}
    if site.sim:
        d["sim"] = dict(site.sim)
    return d


def dumps_site(site: Site, header: str = "", folder: Path | None = None) -> str:
    """``cdpr-site/1`` text; ``header`` lines as comments on top."""
    import tomli_w

    head = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    return head + tomli_w.dumps(site_dict(site, folder))


def write_site(site: Site, path: str | Path, header: str = "") -> Path:
    """Write ``site`` to ``path`` (relative paths against its folder), validated by reading
    it back; written to a temporary name first, so a reader never sees half a file."""
    import tomllib

    p = Path(path).resolve()
    text = dumps_site(site, header, p.parent)
    parse_site(tomllib.loads(text), p, text)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(p)
    return p


__all__ = ["FORMAT", "HardwareSettings", "Site", "SiteError", "SiteLimits",
           "check_site_files", "dumps_site", "load_site", "merge_site", "parse_site",
           "site_dict", "write_site"]
