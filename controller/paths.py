"""Path files (``cdpr-path/1``) and the feasibility check of a whole trajectory.

A path file is TOML, data as data::

    format = "cdpr-path/1"
    name = "demo"
    notes = "what the path is for, where its coordinates come from"
    start = [10.0, 8.56, 1.2, 0.0, 0.0, 0.0]   # optional: the first move goes from the
                                              # measured init pose to it
    repeat = 1            # optional: run the segments this many times (after the start)
    [limits]              # optional, MotionLimits keys (controller/trajectory.py)
    speed_pct = 40.0
    max_accel_m_s2 = 0.5

    [[segment]]
    kind = "line"         # move | line | circle | dwell | visits
    through = [[10.0, 13.56, 1.2], [10.0, 13.56, 0.6]]

Segment keys by ``kind`` (all may have ``name``, a free label for humans):

- ``move``: ``to`` (3 numbers: a position, orientation kept; 6: a pose [m, rad]);
- ``line``: ``through`` (a list of targets; rest at each vertex);
- ``circle``: ``center`` [m], ``normal``, ``angle_deg`` [deg] (right hand about
  ``normal``), from where the platform is (it must lie in the circle's plane);
- ``dwell``: ``duration_s`` [s];
- ``visits``: the targets as ``poses`` (a list of targets) or as a grid: ``x``, ``y``,
  ``z`` ranges ``[lo, hi]`` [m] and ``n = [nx, ny, nz]`` points per axis (an axis with one
  point takes the middle of its range; the grid runs x fastest, then y, then z), with
  ``rpy_deg`` [deg] >= 0 optional: each grid pose gets roll, pitch, yaw drawn uniformly in
  +-rpy_deg (``numpy.random.default_rng((seed, 1))``); ``visits`` (rounds, >= 1),
  ``dwell_s`` [s], ``order`` (``cycle`` or ``shuffle``), ``seed`` (int, for ``shuffle``
  and ``rpy_deg``).

Every error names the file, the line and the field (``PathFileError``); unknown keys are
errors. Shipped paths (``bench/data/paths/*.toml``, package data) load by name:
``load_path("paper-centre")``.

:func:`check_trajectory` checks a whole trajectory before anything moves: the
controller's own statics (:func:`controller.statics.pose_statics`: tension distribution
at the model's exit points, deflected masts included) at every sampled pose, the platform
inside the robot's frame, and the cable length setpoints within the winches' range.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from controller.kinematics import cable_lengths, cable_state
from controller.ranges import check
from controller.robot import Robot
from controller.statics import pose_statics
from controller.tomlfile import Locator, read_toml
from controller.trajectory import (
    DWELL,
    ORDERS,
    Circle,
    Dwell,
    Line,
    MotionLimits,
    Move,
    SegmentSpec,
    Trajectory,
    TrajectoryError,
    Visits,
)
from controller.winch import WinchSet

FORMAT = "cdpr-path/1"
KINDS = ("move", "line", "circle", "dwell", "visits")

_TOP = {"format", "name", "notes", "start", "repeat", "limits", "segment"}
_LIMIT_KEYS = set(MotionLimits.__dataclass_fields__)
_SEGMENT_KEYS = {
    "move": {"kind", "name", "to"},
    "line": {"kind", "name", "through"},
    "circle": {"kind", "name", "center", "normal", "angle_deg"},
    "dwell": {"kind", "name", "duration_s"},
    "visits": {"kind", "name", "poses", "x", "y", "z", "n", "rpy_deg", "visits", "dwell_s",
               "order", "seed"},
}


class PathFileError(ValueError):
    """An invalid path file; the message names the file, the line and the field."""


@dataclass(frozen=True)
class PathSpec:
    """A parsed path file: ``name``, ``notes``, ``start`` (3 or 6 numbers, or None),
    ``limits``, ``segments`` (the specs of :mod:`controller.trajectory`), ``repeat``,
    ``source``."""

    name: str
    notes: str
    start: tuple[float, ...] | None
    limits: MotionLimits
    segments: tuple[SegmentSpec, ...]
    source: str = "<memory>"
    repeat: int = 1


# ---------------------------------------------------------------------------- reading


class _Reader:
    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.loc = Locator(text)

    def where(self, table: str | None = None, index: int | None = None,
              key: str | None = None) -> str:
        return self.loc.where(self.path, table, index, key)

    def fail(self, msg: str, table: str | None = None, index: int | None = None,
             key: str | None = None) -> PathFileError:
        return PathFileError(f"{self.where(table, index, key)}: {msg}")

    def number(self, d: Mapping, key: str, table: str | None, index: int | None, *,
               default: float | None = None, positive: bool = False,
               nonneg: bool = False) -> float:
        if key not in d:
            if default is None:
                raise self.fail("missing field", table, index, key)
            return default
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(f"must be a finite number, got {v!r}", table, index, key)
        if positive and v <= 0:
            raise self.fail(f"must be > 0, got {v}", table, index, key)
        if nonneg and v < 0:
            raise self.fail(f"must be >= 0, got {v}", table, index, key)
        self.ranged(v, table, index, key)
        return float(v)

    def ranged(self, v: Any, table: str | None, index: int | None, key: str,
               component: int | None = None) -> None:
        """``v`` within the physical range of its field (:mod:`controller.ranges`)."""
        where = self.where(table, index, key) + (f"[{component}]" if component is not None
                                                 else "")
        check("path", f"{table}.{key}" if table else key, v, where, PathFileError, component)

    def integer(self, d: Mapping, key: str, table: str | None, index: int | None, *,
                default: int | None = None, minimum: int | None = None) -> int:
        if key not in d:
            if default is None:
                raise self.fail("missing field", table, index, key)
            return default
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(f"must be an integer, got {v!r}", table, index, key)
        if minimum is not None and v < minimum:
            raise self.fail(f"must be >= {minimum}, got {v}", table, index, key)
        self.ranged(v, table, index, key)
        return int(v)

    def vector(self, v: Any, sizes: tuple[int, ...], what: str, table: str | None,
               index: int | None, key: str) -> tuple[float, ...]:
        want = " or ".join(str(s) for s in sizes)
        if not isinstance(v, list) or len(v) not in sizes:
            raise self.fail(f"{what} must be a list of {want} numbers, got {v!r}",
                            table, index, key)
        for i, x in enumerate(v):
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise self.fail(f"{what} must hold finite numbers, got {x!r}", table, index, key)
            self.ranged(x, table, index, key, i)
        return tuple(float(x) for x in v)

    def targets(self, d: Mapping, key: str, table: str, index: int) -> tuple[tuple, ...]:
        if key not in d:
            raise self.fail("missing field", table, index, key)
        v = d[key]
        if not isinstance(v, list) or not v:
            raise self.fail("must be a non-empty list of targets (each 3 or 6 numbers)",
                            table, index, key)
        return tuple(self.vector(x, (3, 6), f"target {i + 1}", table, index, key)
                     for i, x in enumerate(v))

    def unknown(self, d: Mapping, allowed: set[str], table: str | None,
                index: int | None, what: str = "") -> None:
        for k in d:
            if k not in allowed:
                raise self.fail(f"unknown key{what} (allowed: {', '.join(sorted(allowed))})",
                                table, index, k)


def _grid(r: _Reader, seg: Mapping, k: int) -> tuple[tuple[float, ...], ...]:
    T = "segment"
    for key in ("x", "y", "z", "n"):
        if key not in seg:
            raise r.fail("missing field (a visits grid needs x, y, z and n; or give poses)",
                         T, k, key)
    ranges = [r.vector(seg[a], (2,), "a range [lo, hi]", T, k, a) for a in ("x", "y", "z")]
    for a, (lo, hi) in zip("xyz", ranges, strict=True):
        if hi < lo:
            raise r.fail(f"range [{lo}, {hi}] runs backwards", T, k, a)
    n = seg["n"]
    if (not isinstance(n, list) or not 1 <= len(n) <= 3
            or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in n)):
        raise r.fail(f"must be a list of 1 to 3 integers >= 1 (points along x, y, z), got {n!r}",
                     T, k, "n")
    for i, v in enumerate(n):
        r.ranged(v, T, k, "n", i)
    nx, ny, nz = (list(n) + [1, 1, 1])[:3]
    axes = [np.linspace(lo, hi, m) if m > 1 else np.array([0.5 * (lo + hi)])
            for (lo, hi), m in zip(ranges, (nx, ny, nz), strict=True)]
    pts = np.array([[x, y, z] for z in axes[2] for y in axes[1] for x in axes[0]])
    rpy_deg = r.number(seg, "rpy_deg", T, k, default=0.0, nonneg=True)
    seed = r.integer(seg, "seed", T, k, default=0)
    if rpy_deg > 0:
        rng = np.random.default_rng((seed, 1))
        ang = np.radians(rpy_deg) * rng.uniform(-1.0, 1.0, (len(pts), 3))
    else:
        ang = np.zeros((len(pts), 3))
    return tuple(tuple(float(v) for v in row) for row in np.hstack([pts, ang]))


def _segment(r: _Reader, seg: Any, k: int) -> SegmentSpec:
    T = "segment"
    if not isinstance(seg, dict):
        raise r.fail("must be a table", T, k)
    if "kind" not in seg:
        raise r.fail(f"missing field (one of {', '.join(KINDS)})", T, k, "kind")
    kind = seg["kind"]
    if kind not in KINDS:
        raise r.fail(f"unknown kind {kind!r} (known: {', '.join(KINDS)})", T, k, "kind")
    r.unknown(seg, _SEGMENT_KEYS[kind], T, k, f" for kind {kind!r}")
    name = seg.get("name", "")
    if not isinstance(name, str):
        raise r.fail(f"must be a string, got {name!r}", T, k, "name")
    where = r.where(T, k)
    if kind == "move":
        if "to" not in seg:
            raise r.fail("missing field", T, k, "to")
        return Move(r.vector(seg["to"], (3, 6), "a target", T, k, "to"), name, where)
    if kind == "line":
        return Line(r.targets(seg, "through", T, k), name, where)
    if kind == "circle":
        for key in ("center", "normal"):
            if key not in seg:
                raise r.fail("missing field", T, k, key)
        center = r.vector(seg["center"], (3,), "a point", T, k, "center")
        normal = r.vector(seg["normal"], (3,), "a direction", T, k, "normal")
        if not any(normal):
            raise r.fail("must not be the zero vector", T, k, "normal")
        angle = r.number(seg, "angle_deg", T, k)
        return Circle(center, normal, angle, name, where)  # type: ignore[arg-type]
    if kind == "dwell":
        return Dwell(r.number(seg, "duration_s", T, k, nonneg=True), name, where)
    # visits
    has_grid = any(key in seg for key in ("x", "y", "z", "n"))
    if "poses" in seg and has_grid:
        raise r.fail("give either poses or a grid (x, y, z, n), not both", T, k, "poses")
    if "poses" in seg:
        if "rpy_deg" in seg:
            raise r.fail("applies to a grid only (write the orientations into poses)",
                         T, k, "rpy_deg")
        poses = r.targets(seg, "poses", T, k)
    elif has_grid:
        poses = _grid(r, seg, k)
    else:
        raise r.fail("missing field (a list of targets, or a grid x, y, z, n)", T, k, "poses")
    order = seg.get("order", "cycle")
    if order not in ORDERS:
        raise r.fail(f"must be one of {', '.join(ORDERS)}, got {order!r}", T, k, "order")
    return Visits(poses, r.integer(seg, "visits", T, k, default=1, minimum=1),
                  r.number(seg, "dwell_s", T, k, default=3.0, nonneg=True), order,
                  r.integer(seg, "seed", T, k, default=0), name, where)


def parse_path(data: Mapping[str, Any], path: str = "<memory>", text: str = "") -> PathSpec:
    """Validate a parsed path mapping (``text``: the file's text, for line numbers)."""
    r = _Reader(path, text)
    r.unknown(data, _TOP, None, None)
    if data.get("format") != FORMAT:
        raise r.fail(f"expected {FORMAT!r}, got {data.get('format')!r}", None, None, "format")
    name = data.get("name", Path(path).stem)
    notes = data.get("notes", "")
    for key, v in (("name", name), ("notes", notes)):
        if not isinstance(v, str):
            raise r.fail(f"must be a string, got {v!r}", None, None, key)
    start = None
    if "start" in data:
        start = r.vector(data["start"], (3, 6), "the start", None, None, "start")
    repeat = r.integer(data, "repeat", None, None, default=1, minimum=1)
    lim = data.get("limits", {})
    if not isinstance(lim, dict):
        raise r.fail("must be a table", None, None, "limits")
    r.unknown(lim, _LIMIT_KEYS, "limits", None)
    values = {key: r.number(lim, key, "limits", None, positive=True) for key in lim}
    try:
        limits = MotionLimits(**values)
    except TrajectoryError as exc:
        bad = next((k for k in values if f" {k}:" in str(exc)), None)
        raise r.fail(str(exc).split(": ", 2)[-1], "limits", None, bad) from None
    segs = data.get("segment", [])
    if not isinstance(segs, list) or not segs:
        raise r.fail("no [[segment]] table: a path needs at least one segment")
    specs = tuple(_segment(r, s, k) for k, s in enumerate(segs))
    return PathSpec(name, notes, start, limits, specs, path, repeat)


def shipped_dir() -> Path | None:
    """The folder of the shipped path files (``bench/data/paths``), found without importing
    ``bench`` (controller imports none of the other packages)."""
    spec = importlib.util.find_spec("bench")
    if spec is None or not spec.submodule_search_locations:
        return None
    for loc in spec.submodule_search_locations:
        d = Path(loc) / "data" / "paths"
        if d.is_dir():
            return d
    return None


def shipped_paths() -> dict[str, Path]:
    """Shipped path files by name (file stem)."""
    d = shipped_dir()
    return {} if d is None else {p.stem: p for p in sorted(d.glob("*.toml"))}


def resolve_path_file(name_or_path: str | Path) -> Path:
    """A shipped path's file by name, or the file given."""
    s = str(name_or_path)
    p = Path(s)
    if p.suffix != ".toml" and not p.exists():
        shipped = shipped_paths()
        if s in shipped:
            return shipped[s]
        raise PathFileError(f"{s}: no such path file, nor a shipped path (shipped: "
                            f"{', '.join(shipped) or 'none'})")
    return p


def load_path(name_or_path: str | Path) -> PathSpec:
    """Read and validate a path file, or a shipped path by name (``paper-centre``)."""
    p = resolve_path_file(name_or_path)
    data, text = read_toml(p, PathFileError)
    return parse_path(data, str(p), text)


def build_trajectory(spec: PathSpec, start_pose: Any,
                     limits_override: MotionLimits | Mapping[str, float] | None = None
                     ) -> Trajectory:
    """The trajectory of a path from the measured ``start_pose`` (6,) (the init pose): a
    move to the file's ``start`` first (named ``approach``, segment ``cycle`` -1) when it
    has one, then the segments, ``repeat`` times. ``limits_override``: a
    :class:`MotionLimits`, or changes to the file's limits (e.g. ``{"speed_pct": 40}``).
    Raises :class:`PathFileError` naming the file."""
    limits = spec.limits
    try:
        if isinstance(limits_override, MotionLimits):
            limits = limits_override
        elif limits_override:
            limits = limits.replace(**dict(limits_override))
        segs: list[SegmentSpec] = []
        if spec.start is not None:
            segs.append(Move(spec.start, "approach", f"{spec.source}: start"))
        segs.extend(spec.segments)
        return Trajectory(segs, start_pose, limits, repeat=spec.repeat,
                          approach=1 if spec.start is not None else 0)
    except TrajectoryError as exc:
        raise PathFileError(str(exc) if str(exc).startswith(spec.source)
                            else f"{spec.source}: {exc}") from None


# ---------------------------------------------------------------------------- checking


@dataclass(frozen=True)
class PathCheck:
    """Result of :func:`check_trajectory`. ``ok``; for the first infeasible point (in
    time), ``t_s`` [s], ``pose`` (6,), ``segment`` (index) and ``reason`` (None/""
    when ok); ``checked``: poses checked; ``tension_min_n``/``tension_max_n``: the
    extreme planned tensions over the poses checked up to the first failure [N];
    ``min_length_margin_m``: the smallest distance of a length setpoint to the winches'
    range (NaN without winches)."""

    ok: bool
    t_s: float | None
    pose: np.ndarray | None
    reason: str
    checked: int
    segment: int = -1
    tension_min_n: float = math.nan
    tension_max_n: float = math.nan
    min_length_margin_m: float = math.nan
    times: np.ndarray = field(default=None, repr=False)


def check_times(traj: Trajectory, step_m: float = 0.1, step_s: float = 1.0,
                step_rad: float = 0.02) -> np.ndarray:
    """Sample times [s] of a trajectory for :func:`check_trajectory`: along every motion
    no more than ``step_m`` [m], ``step_rad`` [rad] or ``step_s`` [s] apart (each segment's
    ends included), one time per dwell."""
    if not (step_m > 0 and step_s > 0 and step_rad > 0):
        raise ValueError("check steps must be > 0")
    out = [np.array([0.0])]
    for seg in traj.segments:
        m = seg.motion
        if seg.label == DWELL:
            out.append(np.array([seg.t0]))
            continue
        dt = step_s
        if m.peak_speed > 0:
            dt = min(dt, step_m / m.peak_speed)
        if m.peak_angular_speed > 0:
            dt = min(dt, step_rad / m.peak_angular_speed)
        n = max(1, math.ceil(seg.duration_s / dt))
        out.append(seg.t0 + np.linspace(0.0, seg.duration_s, n + 1))
    out.append(np.array([traj.duration_s]))
    t = np.concatenate(out)
    return np.unique(t)


def frame_box(robot: Robot) -> np.ndarray:
    """The robot's frame as a box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` [m] in F_b:
    x, y within the exit points, z from the ground (the lowest mast pivot, the masts stand
    on it) to the highest exit point."""
    a, piv = robot.exits, robot.pivots
    return np.array([[a[:, 0].min(), a[:, 1].min(), piv[:, 2].min()],
                     [a[:, 0].max(), a[:, 1].max(), a[:, 2].max()]])


def check_trajectory(robot: Robot, traj: Trajectory, winches: WinchSet | None = None,
                     step_m: float = 0.1, step_s: float = 1.0, step_rad: float = 0.02,
                     method: str = "closed_form", tol: float = 1e-6,
                     progress: Callable[[int, int], None] | None = None) -> PathCheck:
    """Check a whole trajectory before anything moves, for the controller's model
    ``robot``; the first infeasible point (in time) and why, or ok.

    At poses sampled by :func:`check_times`:

    - frame: every anchor point B_ij of the platform inside :func:`frame_box`
      (vectorised);
    - tensions: the controller's statics (:func:`controller.statics.pose_statics` with
      ``method``: tension distribution within [tension_min, tension_max], deflected exit
      points for compliant masts) feasible;
    - winches (when ``winches`` is given): the length setpoints the controller would send,
      ``L0(p) - L0(p0) + d_model(p0)`` with p0 the trajectory's start (the init pose,
      cdpr-conventions.md), within ``[min_length_m, max_length_m]``.

    ``tol`` [m]: how far the exit points of compliant masts may still move when their
    iteration stops (the statics' default is 1e-10; a micrometre is plenty here and
    faster). ``progress(done, total)`` is called every few hundred poses.
    """
    times = check_times(traj, step_m, step_s, step_rad)
    smp = traj.sample(times)
    poses = smp.pose
    n_pts = len(times)
    first_frame, frame_why = _first_outside_frame(robot, poses)
    # tensions, in time order up to the first failure; identical poses solved once
    first_tension, tension_reason, tau, l0 = _first_without_tensions(
        robot, poses[:first_frame], method, tol, progress)
    n_ok = min(first_frame, first_tension)
    tau, l0 = tau[:n_ok], l0[:n_ok]
    first_len, len_reason, margin = n_pts, "", math.nan
    if winches is not None and n_ok > 0:
        first_len, len_reason, margin = _first_outside_winch_range(
            robot, traj.start_pose, l0, winches, method, tol)
        first_len = n_pts if first_len is None else first_len
    first = min(first_frame, first_tension, first_len)
    tmin = float(np.nanmin(tau)) if n_ok and np.isfinite(tau).any() else math.nan
    tmax = float(np.nanmax(tau)) if n_ok and np.isfinite(tau).any() else math.nan
    if first >= n_pts:
        return PathCheck(True, None, None, "", n_pts, -1, tmin, tmax, margin, times)
    why = (frame_why if first == first_frame else
           f"no feasible tensions: {tension_reason}" if first == first_tension else len_reason)
    k = int(smp.segment[first])
    seg = traj.segments[k]
    t = float(times[first])
    pose = poses[first].copy()
    label = f"{seg.kind} {seg.name!r}" if seg.name else seg.kind
    reason = (f"t = {t:.3f} s (segment #{k + 1}, {label}), pose "
              f"{np.round(pose[:3], 3).tolist()} m, rpy "
              f"{np.round(np.degrees(pose[3:]), 2).tolist()} deg: {why}")
    return PathCheck(False, t, pose, reason, first + 1, k, tmin, tmax, margin, times)


def _first_outside_frame(robot: Robot, poses: np.ndarray) -> tuple[int, str]:
    """The index of the first of ``poses`` (n, 6) with a platform anchor B_ij outside
    :func:`frame_box` (vectorised) and why; ``len(poses)`` and "" when none is."""
    box = frame_box(robot)
    st = cable_state(poses, robot.anchors, robot.exits, robot.pulley_radius)
    outside = (st.B < box[0] - 1e-9) | (st.B > box[1] + 1e-9)
    bad = outside.any(axis=(1, 2))
    if not bad.any():
        return len(poses), ""
    i = int(np.argmax(bad))
    c = int(np.argmax(outside[i].any(axis=1)))
    return i, (f"anchor B_{robot.cable_ids[c]} at {np.round(st.B[i, c], 3).tolist()} m is "
               f"outside the robot's frame (x {box[0, 0]:g}..{box[1, 0]:g}, y {box[0, 1]:g}.."
               f"{box[1, 1]:g}, z {box[0, 2]:g}..{box[1, 2]:g} m)")


def _first_without_tensions(robot: Robot, poses: np.ndarray, method: str, tol: float,
                            progress: Callable[[int, int], None] | None
                            ) -> tuple[int, str, np.ndarray, np.ndarray]:
    """The controller's statics at ``poses`` (n, 6) in time order up to the first without
    feasible tensions (identical poses solved once): its index (``n`` when none) and
    reason, the tensions [N] and unstretched lengths [m] (n, m) (nan from it on)."""
    n_pts = len(poses)
    uniq, inv = np.unique(poses, axis=0, return_inverse=True)
    inv = np.asarray(inv).ravel()
    first_use = np.full(len(uniq), n_pts)
    np.minimum.at(first_use, inv, np.arange(len(inv)))
    tau_u = np.full((len(uniq), robot.n_cables), np.nan)
    l0_u = np.full((len(uniq), robot.n_cables), np.nan)
    first, reason = n_pts, ""
    for done, u in enumerate(np.argsort(first_use, kind="stable")):
        if first_use[u] >= first:
            break
        ps = pose_statics(robot, uniq[u], method=method, tol=tol)
        if not ps.feasible:
            first, reason = int(first_use[u]), ps.reason
            break
        tau_u[u] = ps.tensions
        l0_u[u] = ps.unstretched
        if progress is not None and done % 500 == 0:
            progress(done, len(uniq))
    if progress is not None:
        progress(len(uniq), len(uniq))
    return first, reason, tau_u[inv], l0_u[inv]


def _first_outside_winch_range(robot: Robot, p0: np.ndarray, l0: np.ndarray,
                               winches: WinchSet, method: str, tol: float
                               ) -> tuple[int | None, str, float]:
    """The first of the unstretched lengths ``l0`` (n, m) [m] whose length setpoint
    ``L0(p) - L0(p0) + d_model(p0)`` leaves a winch's range (None when none does) and why,
    and the smallest margin to the range [m] (nan when p0's statics fail)."""
    if tuple(winches.cables) != tuple(robot.cable_ids):
        raise ValueError(f"winches {winches.source} are for cables {winches.cables}, the "
                         f"robot {robot.name} has {robot.cable_ids}")
    ps0 = pose_statics(robot, p0, method=method, tol=tol)
    if not ps0.feasible:
        return None, "", math.nan
    offset = cable_lengths(p0, robot.anchors, robot.exits, robot.pulley_radius) \
        - ps0.unstretched
    lengths = l0 + offset
    lo, hi = winches.min_length_m, winches.max_length_m
    margin = float(np.min(np.minimum(lengths - lo, hi - lengths)))
    bad = (lengths < lo) | (lengths > hi)
    if not bad.any():
        return None, "", margin
    i = int(np.argmax(bad.any(axis=1)))
    c = int(np.argmax(bad[i]))
    return i, (f"cable {robot.cable_ids[c]} (CAN node {int(winches.node_id[c])}): length "
               f"setpoint {lengths[i, c]:.3f} m outside the winch range [{lo[c]:g}, {hi[c]:g}] "
               f"m ({winches.source})"), margin


__all__ = [
    "FORMAT", "PathCheck", "PathFileError", "PathSpec", "build_trajectory", "check_times",
    "check_trajectory", "frame_box", "load_path", "parse_path", "resolve_path_file",
    "shipped_dir", "shipped_paths",
]
