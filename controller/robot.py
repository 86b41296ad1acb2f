"""Robot description: the ``robot.toml`` of ``cdpr-recording/1`` as arrays.

Frames and units follow ``cdpr-conventions.md``: exit points ``exit`` (A_ij) and
mast pivots (O_i) in F_b [m]; anchors (B_ij) and centre of mass in F_p [m];
stiffness [N m/rad]; ``ea`` [N]; tensions [N]; mass [kg].

Beyond the keys of the recording format, this reader knows a few optional keys
(written only when they differ from their neutral value, so that a file with
none of them is a plain ``cdpr-recording/1`` robot):

- ``[cables] rho`` [kg/m]: linear mass of the cables (sag, Irvine); 0 = no sag.
- ``[[mast]] tilt`` [rad]: settlement of the supporting ropes as a rotation
  vector about the pivot (A -> A*); default no tilt.
- ``[[cable]] ea`` [N]: a cable's own E*A, overriding ``[cables] ea``.
- ``[[cable]] drum_scale`` [-], ``length_offset`` [m]: calibration of the length
  reading (true change = drum_scale * read change; ``length_offset`` added).
- ``[[cable]] load_cell_gain`` [-], ``load_cell_offset`` [N]: the load cell reads
  ``gain * true + offset``.

- ``gravity_unusual = true``: a gravity away from the Earth's surface (9.76 to
  9.84 m/s^2 otherwise).

Unknown keys, missing fields, wrong vector lengths, non-finite numbers, numbers
outside their physical range (:mod:`controller.ranges`: a 1e300 kg platform, an exit
point beyond 1 km), duplicate ids and cables naming a missing mast are errors that
name the file, the line where it can be found, the field, the value and the range.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from controller.masts import settle
from controller.ranges import GRAVITY_EARTH, check
from controller.tomlfile import Locator as _Locator
from controller.tomlfile import read_toml


class RobotFileError(ValueError):
    """An invalid robot description; the message names file, line and field."""


@dataclass(frozen=True, eq=False)
class Robot:
    """A cable robot, arrays ordered as ``cable_ids`` / ``mast_ids``.

    Shapes: n cables, m masts. ``stiffness`` is ``inf`` for a rigid axis, ``ea``
    is ``inf`` for an inextensible cable.
    """

    name: str
    cable_ids: tuple[str, ...]
    mast_ids: tuple[str, ...]
    exits: np.ndarray  # (n, 3) A_ij in F_b [m] as surveyed (before settlement)
    anchors: np.ndarray  # (n, 3) B_ij in F_p [m]
    mast_index: np.ndarray  # (n,) index into mast_ids
    pivots: np.ndarray  # (m, 3) O_i in F_b [m]
    stiffness: np.ndarray = field(default=None)  # (m, 3) [N m/rad], inf = rigid
    tilt: np.ndarray = field(default=None)  # (m, 3) settlement rotation vector [rad]
    pulley_radius: np.ndarray = field(default=None)  # (n,) [m], 0 = fixed exit point
    ea: np.ndarray = field(default=None)  # (n,) [N], inf = inextensible
    mass: float = 35.0  # [kg]
    com: np.ndarray = field(default=None)  # (3,) in F_p [m]
    gravity: float = 9.81  # [m/s^2]
    tension_min: float = 0.0  # [N]
    tension_max: float = math.inf  # [N]
    rho: float = 0.0  # [kg/m] cable linear mass (sag)
    drum_scale: np.ndarray = field(default=None)  # (n,) [-]
    length_offset: np.ndarray = field(default=None)  # (n,) [m]
    load_cell_gain: np.ndarray = field(default=None)  # (n,) [-]
    load_cell_offset: np.ndarray = field(default=None)  # (n,) [N]
    source: str = "<memory>"
    #: (k,) [N] a hypothesis about a recording without load cells at initialisation: the
    #: tensions when the encoders were referenced differ from the tension distribution's by
    #: these internal forces (coordinates in a basis of the wrench matrix's null space at the
    #: initialisation pose, :func:`controller.statics.pretensioned`); None: the distribution's
    init_internal: np.ndarray | None = None
    #: (6,) the laser tracker's frame F_t in F_b (effect ``tracker_frame``): rotation vector
    #: ``rx, ry, rz`` [rad] about F_b's origin and translation ``tx, ty, tz`` [m]; a point
    #: read ``x_t`` by the tracker is at ``R x_t + t`` in F_b. Zero: the tracker reads F_b
    tracker_frame: np.ndarray = field(default=None)
    #: [s] the tracker's stream lags the drives' by this (effect ``tracker_latency``): the
    #: pose stamped ``t`` is the platform's at ``t - tracker_latency``
    tracker_latency: float = 0.0

    def __post_init__(self) -> None:
        n, m = len(self.cable_ids), len(self.mast_ids)
        defaults = {
            "stiffness": np.full((m, 3), np.inf),
            "tilt": np.zeros((m, 3)),
            "pulley_radius": np.zeros(n),
            "ea": np.full(n, np.inf),
            "com": np.zeros(3),
            "drum_scale": np.ones(n),
            "length_offset": np.zeros(n),
            "load_cell_gain": np.ones(n),
            "load_cell_offset": np.zeros(n),
            "tracker_frame": np.zeros(6),
        }
        for name, default in defaults.items():
            val = getattr(self, name)
            arr = default if val is None else np.array(val, dtype=float)
            if np.ndim(default) == 1 and np.ndim(arr) == 0:
                arr = np.full(default.shape, float(arr))
            if arr.shape != default.shape:
                raise ValueError(f"{name}: shape {arr.shape}, expected {default.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        for name in ("exits", "anchors", "pivots"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        mi = np.array(self.mast_index, dtype=int)
        mi.setflags(write=False)
        object.__setattr__(self, "mast_index", mi)
        if self.exits.shape != (n, 3) or self.anchors.shape != (n, 3) or mi.shape != (n,):
            raise ValueError("exits/anchors/mast_index do not match the cable count")
        if self.pivots.shape != (m, 3):
            raise ValueError("pivots do not match the mast count")

    # ----- derived quantities -------------------------------------------------
    @property
    def n_cables(self) -> int:
        return len(self.cable_ids)

    @property
    def n_masts(self) -> int:
        return len(self.mast_ids)

    @functools.cached_property
    def compliance(self) -> np.ndarray:
        """(m, 3) joint compliance 1/k [rad/(N m)], 0 for a rigid axis."""
        return 1.0 / self.stiffness

    @functools.cached_property
    def exits_settled(self) -> np.ndarray:
        """Exit points A* (n,3) in F_b [m] after the masts' settlement tilt (read-only; once
        per robot: the statics ask for them at every iteration)."""
        a = settle(self.exits, self.pivots, self.mast_index, self.tilt)
        a.setflags(write=False)
        return a

    @functools.cached_property
    def compliant(self) -> bool:
        return bool(np.any(np.isfinite(self.stiffness)))

    @functools.cached_property
    def elastic(self) -> bool:
        return bool(np.any(np.isfinite(self.ea)))

    @functools.cached_property
    def has_pulleys(self) -> bool:
        return bool(np.any(self.pulley_radius > 0))

    @property
    def weight(self) -> float:
        """Platform weight m*g [N]."""
        return self.mass * self.gravity

    def replace(self, **changes: Any) -> Robot:
        """A copy with fields changed (arrays copied)."""
        return dataclasses.replace(self, **changes)

    def cable(self, cable_id: str) -> int:
        """Index of a cable id."""
        return self.cable_ids.index(cable_id)


# ----- TOML reading -----------------------------------------------------------

_TOP_KEYS = {"name", "gravity", "gravity_unusual", "platform", "cables", "mast", "cable"}
_PLATFORM_KEYS = {"mass", "com"}
_CABLES_KEYS = {"tension_min", "tension_max", "ea", "rho"}
_MAST_KEYS = {"id", "pivot", "stiffness", "tilt"}
_CABLE_KEYS = {
    "id", "mast", "exit", "anchor", "pulley_radius", "ea", "drum_scale", "length_offset",
    "load_cell_gain", "load_cell_offset",
}


class _Reader:
    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.loc = _Locator(text)

    def fail(self, msg: str, table: str | None = None, index: int | None = None,
             key: str | None = None) -> RobotFileError:
        return RobotFileError(f"{self.loc.where(self.path, table, index, key)}: {msg}")

    def number(self, d: dict, key: str, table: str | None, index: int | None,
               required: bool = True, default: float | None = None,
               positive: bool = False, nonneg: bool = False,
               fld: str | None = None) -> float | None:
        """A finite number within the physical range of its field (:mod:`controller.ranges`,
        ``fld`` or ``table.key``)."""
        if key not in d:
            if required:
                raise self.fail("missing field", table, index, key)
            return default
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(f"must be a number, got {v!r}", table, index, key)
        v = float(v)
        if not math.isfinite(v):
            raise self.fail(f"must be finite, got {v!r}", table, index, key)
        if positive and v <= 0:
            raise self.fail(f"must be > 0, got {v}", table, index, key)
        if nonneg and v < 0:
            raise self.fail(f"must be >= 0, got {v}", table, index, key)
        check("robot", fld or (f"{table}.{key}" if table else key), d[key],
              self.loc.where(self.path, table, index, key), RobotFileError)
        return v

    def vector(self, d: dict, key: str, table: str | None, index: int | None,
               required: bool = True, default: Any = None, positive: bool = False,
               rigid_inf: bool = False) -> Any:
        """A list of 3 finite numbers; ``rigid_inf``: ``inf`` is also allowed (a stiffness
        axis that is rigid)."""
        if key not in d:
            if required:
                raise self.fail("missing field", table, index, key)
            return default
        v = d[key]
        if not isinstance(v, list):
            raise self.fail(f"must be a list of 3 numbers, got {v!r}", table, index, key)
        if len(v) != 3:
            raise self.fail(f"must have 3 numbers, got {len(v)}", table, index, key)
        out = []
        for x in v:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise self.fail(f"must hold numbers, got {x!r}", table, index, key)
            if not math.isfinite(float(x)) and not (rigid_inf and float(x) == math.inf):
                raise self.fail(f"must be finite{' (or inf: rigid)' if rigid_inf else ''}, "
                                f"got {x!r}", table, index, key)
            if positive and float(x) <= 0:
                raise self.fail(f"must be > 0, got {x!r}", table, index, key)
            check("robot", f"{table}.{key}" if table else key, x,
                  f"{self.loc.where(self.path, table, index, key)}[{len(out)}]",
                  RobotFileError, len(out))
            out.append(float(x))
        return out

    def string(self, d: dict, key: str, table: str | None, index: int | None) -> str:
        if key not in d:
            raise self.fail("missing field", table, index, key)
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (str, int)):
            raise self.fail(f"must be a string, got {v!r}", table, index, key)
        return str(v)

    def unknown(self, d: dict, allowed: set[str], table: str | None, index: int | None) -> None:
        if not isinstance(d, dict):
            raise self.fail(f"must be a table, got {d!r}", table, index, None)
        for k in d:
            if k not in allowed:
                raise self.fail(f"unknown key (allowed: {', '.join(sorted(allowed))})",
                                table, index, k)


def parse_robot(data: dict[str, Any], path: str = "<memory>", text: str = "") -> Robot:
    """Validate a parsed robot.toml mapping and build a :class:`Robot`."""
    r = _Reader(path, text)
    r.unknown(data, _TOP_KEYS, None, None)
    name = str(data.get("name", Path(path).stem))
    unusual = data.get("gravity_unusual", False)
    if not isinstance(unusual, bool):
        raise r.fail(f"must be true or false, got {unusual!r}", None, None, "gravity_unusual")
    gravity = r.number(data, "gravity", None, None, required=False, default=9.81, positive=True,
                       fld="gravity (gravity_unusual = true)" if unusual else "gravity")

    plat = data.get("platform")
    if not isinstance(plat, dict):
        raise r.fail("missing table [platform]")
    r.unknown(plat, _PLATFORM_KEYS, "platform", None)
    mass = r.number(plat, "mass", "platform", None, positive=True)
    com = r.vector(plat, "com", "platform", None, required=False, default=[0.0, 0.0, 0.0])

    cab = data.get("cables")
    if not isinstance(cab, dict):
        raise r.fail("missing table [cables]")
    r.unknown(cab, _CABLES_KEYS, "cables", None)
    tmin = r.number(cab, "tension_min", "cables", None, nonneg=True)
    tmax = r.number(cab, "tension_max", "cables", None, positive=True)
    if tmax <= tmin:
        raise r.fail(f"must exceed tension_min ({tmin})", "cables", None, "tension_max")
    ea_all = r.number(cab, "ea", "cables", None, required=False, default=math.inf, positive=True)
    rho = r.number(cab, "rho", "cables", None, required=False, default=0.0, nonneg=True)

    masts = data.get("mast", [])
    if not isinstance(masts, list) or not masts:
        raise r.fail("no [[mast]] table")
    mast_ids: list[str] = []
    pivots, stiff, tilt = [], [], []
    for k, mt in enumerate(masts):
        r.unknown(mt, _MAST_KEYS, "mast", k)
        mid = r.string(mt, "id", "mast", k)
        if mid in mast_ids:
            raise r.fail(f"duplicate mast id {mid!r}", "mast", k, "id")
        mast_ids.append(mid)
        pivots.append(r.vector(mt, "pivot", "mast", k))
        stiff.append(r.vector(mt, "stiffness", "mast", k, required=False,
                              default=[math.inf] * 3, positive=True, rigid_inf=True))
        tilt.append(r.vector(mt, "tilt", "mast", k, required=False, default=[0.0] * 3))

    cables = data.get("cable", [])
    if not isinstance(cables, list) or not cables:
        raise r.fail("no [[cable]] table")
    ids: list[str] = []
    cols: dict[str, list] = {k: [] for k in (
        "mast", "exit", "anchor", "pulley_radius", "ea", "drum_scale", "length_offset",
        "load_cell_gain", "load_cell_offset")}
    for k, ct in enumerate(cables):
        r.unknown(ct, _CABLE_KEYS, "cable", k)
        cid = r.string(ct, "id", "cable", k)
        if cid in ids:
            raise r.fail(f"duplicate cable id {cid!r}", "cable", k, "id")
        ids.append(cid)
        mast = r.string(ct, "mast", "cable", k)
        if mast not in mast_ids:
            raise r.fail(f"names mast {mast!r}, which is not defined (masts: "
                         f"{', '.join(mast_ids)})", "cable", k, "mast")
        cols["mast"].append(mast_ids.index(mast))
        cols["exit"].append(r.vector(ct, "exit", "cable", k))
        cols["anchor"].append(r.vector(ct, "anchor", "cable", k))
        cols["pulley_radius"].append(r.number(ct, "pulley_radius", "cable", k, required=False,
                                              default=0.0, nonneg=True))
        cols["ea"].append(r.number(ct, "ea", "cable", k, required=False, default=ea_all,
                                   positive=True))
        cols["drum_scale"].append(r.number(ct, "drum_scale", "cable", k, required=False,
                                           default=1.0, positive=True))
        cols["length_offset"].append(r.number(ct, "length_offset", "cable", k, required=False,
                                              default=0.0))
        cols["load_cell_gain"].append(r.number(ct, "load_cell_gain", "cable", k,
                                               required=False, default=1.0, positive=True))
        cols["load_cell_offset"].append(r.number(ct, "load_cell_offset", "cable", k,
                                                 required=False, default=0.0))
    if len(ids) < 6:
        raise r.fail(f"a robot needs at least 6 cables for a 6-DoF platform, got {len(ids)}",
                     "cable", len(ids) - 1 if ids else None, None)
    for k, mid in enumerate(mast_ids):
        if k not in cols["mast"]:
            raise r.fail(f"no cable uses mast {mid!r} (each [[mast]] carries at least one "
                         "cable's exit point; remove it or name it in a cable's mast)",
                         "mast", k, "id")
    return Robot(
        name=name, cable_ids=tuple(ids), mast_ids=tuple(mast_ids),
        exits=np.array(cols["exit"]), anchors=np.array(cols["anchor"]),
        mast_index=np.array(cols["mast"]), pivots=np.array(pivots),
        stiffness=np.array(stiff), tilt=np.array(tilt),
        pulley_radius=np.array(cols["pulley_radius"]), ea=np.array(cols["ea"]),
        mass=mass, com=np.array(com), gravity=gravity, tension_min=tmin, tension_max=tmax,
        rho=rho, drum_scale=np.array(cols["drum_scale"]),
        length_offset=np.array(cols["length_offset"]),
        load_cell_gain=np.array(cols["load_cell_gain"]),
        load_cell_offset=np.array(cols["load_cell_offset"]), source=path,
    )


def load_robot(path: str | Path) -> Robot:
    """Read and validate a robot.toml file."""
    data, text = read_toml(path, RobotFileError)
    return parse_robot(data, str(Path(path)), text)


SHIPPED = {
    "rocaspect": "rocaspect.toml",
    "rocaspect-remeasured": "rocaspect_remeasured.toml",
    "cogiro": "cogiro.toml",
    "ipanema": "ipanema.toml",
    "hexa6": "hexa6.toml",
}


def shipped_robot_path(name: str) -> Path:
    """Path of a description shipped with the package (``rocaspect``, ``rocaspect-remeasured``,
    ``cogiro``, ``ipanema``, ``hexa6``)."""
    fname = SHIPPED.get(name)
    if fname is None:
        raise RobotFileError(f"{name}: no such shipped robot (known: {', '.join(SHIPPED)})")
    return Path(str(resources.files("controller") / "data" / fname))


def resolve_robot(name_or_path: str | Path) -> Robot:
    """Load a shipped description by name, or a robot.toml by path."""
    s = str(name_or_path)
    if s in SHIPPED:
        return load_robot(shipped_robot_path(s))
    return load_robot(s)


# ----- TOML writing -----------------------------------------------------------

def _num(x: float) -> float:
    return float(x)


def robot_to_dict(robot: Robot) -> dict[str, Any]:
    """The robot as a robot.toml mapping; optional keys only where not neutral."""
    d: dict[str, Any] = {"name": robot.name, "gravity": _num(robot.gravity)}
    if not GRAVITY_EARTH.contains(robot.gravity):
        d["gravity_unusual"] = True  # said explicitly: not the Earth's surface
    d["platform"] = {"mass": _num(robot.mass), "com": [_num(v) for v in robot.com]}
    cab: dict[str, Any] = {"tension_min": _num(robot.tension_min),
                           "tension_max": _num(robot.tension_max)}
    ea = robot.ea
    common_ea = bool(np.all(ea == ea[0]))
    if common_ea and np.isfinite(ea[0]):
        cab["ea"] = _num(ea[0])
    if robot.rho > 0:
        cab["rho"] = _num(robot.rho)
    d["cables"] = cab
    masts = []
    for i, mid in enumerate(robot.mast_ids):
        mt: dict[str, Any] = {"id": mid, "pivot": [_num(v) for v in robot.pivots[i]]}
        if np.any(np.isfinite(robot.stiffness[i])):
            # an axis without a stiffness is rigid: TOML's inf (never a large stand-in number)
            mt["stiffness"] = [_num(v) for v in robot.stiffness[i]]
        if np.any(robot.tilt[i] != 0):
            mt["tilt"] = [_num(v) for v in robot.tilt[i]]
        masts.append(mt)
    d["mast"] = masts
    cables = []
    for k, cid in enumerate(robot.cable_ids):
        ct: dict[str, Any] = {
            "id": cid, "mast": robot.mast_ids[robot.mast_index[k]],
            "exit": [_num(v) for v in robot.exits[k]],
            "anchor": [_num(v) for v in robot.anchors[k]],
        }
        if robot.pulley_radius[k] > 0:
            ct["pulley_radius"] = _num(robot.pulley_radius[k])
        if not common_ea and np.isfinite(ea[k]):
            ct["ea"] = _num(ea[k])
        for key, neutral in (("drum_scale", 1.0), ("length_offset", 0.0),
                             ("load_cell_gain", 1.0), ("load_cell_offset", 0.0)):
            v = getattr(robot, key)[k]
            if v != neutral:
                ct[key] = _num(v)
        cables.append(ct)
    d["cable"] = cables
    return d


def dumps_robot(robot: Robot, header: str = "") -> str:
    """robot.toml text; ``header`` lines are written as comments on top."""
    body = tomli_w.dumps(robot_to_dict(robot))
    head = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    return head + body


def save_robot(robot: Robot, path: str | Path, header: str = "") -> Path:
    """Write a robot.toml (validated by reading it back)."""
    p = Path(path)
    text = dumps_robot(robot, header)
    parse_robot(tomllib.loads(text), str(p), text)
    p.write_text(text, encoding="utf-8")
    return p
