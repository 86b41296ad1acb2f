"""Physical ranges of every number in the project's input files, as data, and one checker.

A file may be valid TOML with every number finite and still describe no robot that can
exist: a 1e300 kg platform, an exit point 1e300 m away, a gravity of 1e-9 m/s^2, a fault
repeated 1e18 times. Every loader (robot.toml, the winch file, scenarios, paths, fault
schedules, the load-cell register map and calibration, a recording's meta.toml) checks
each number against the range of its field here, through :func:`check`, so that the
message always names the file, the line, the field, the value and the allowed range.

:data:`RANGES` holds one table per file kind: field -> :class:`Range` (or a tuple of
ranges, one per component of a vector: a pose is 3 positions [m] then 3 angles [rad]).
Field names are the ones the loaders use in their messages: ``table.key`` (``[platform]
mass`` is ``platform.mass``, ``[[cable]] exit`` is ``cable.exit``), the key alone at the
top level. The ranges are generous bounds of what is physical for a large cable robot
(the reference: ROCASPECT, 35 kg, 20 m frame), not tolerances of one machine: they refuse
what no real robot, file or bench can mean, and never a plausible design.

``docs/reference/validation.md`` is generated from this table (:func:`markdown`); a test
keeps it in sync. Pure: no I/O.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Range:
    """``lo <= value <= hi`` (``lo_open``: ``lo < value``) in ``unit``; ``inf_ok``: +inf is
    also allowed (a rigid axis); ``integer``: a whole number; ``why``: what the bound
    means, for the message."""

    lo: float
    hi: float
    unit: str = ""
    why: str = ""
    lo_open: bool = False
    inf_ok: bool = False
    integer: bool = False

    def contains(self, v: float) -> bool:
        if math.isnan(v):
            return False
        if v == math.inf and self.inf_ok:
            return True
        if self.integer and not float(v).is_integer():
            return False
        return (v > self.lo if self.lo_open else v >= self.lo) and v <= self.hi

    def text(self, name: str = "x") -> str:
        """``0 < mass <= 10000 kg`` (``name`` stands for the value)."""
        lo = f"{_g(self.lo)} {'<' if self.lo_open else '<='} "
        s = f"{lo}{name} <= {_g(self.hi)}" + (f" {self.unit}" if self.unit else "")
        if self.inf_ok:
            s += " or inf"
        if self.integer:
            s += ", a whole number"
        return s


def _g(v: float) -> str:
    if v == int(v) and abs(v) < 1e7:
        return f"{int(v)}"
    return f"{v:g}"


# ----- shared ranges ---------------------------------------------------------------------

#: a coordinate of a point in F_b (exit points, pivots, poses): within a kilometre
POSITION = Range(-1000.0, 1000.0, "m", "within 1 km of F_b's origin")
#: an orientation angle of a pose (roll, pitch, yaw)
ANGLE = Range(-2 * math.pi, 2 * math.pi, "rad", "an angle within one turn")
#: a pose [x, y, z, roll, pitch, yaw]
POSE: tuple[Range, ...] = (POSITION,) * 3 + (ANGLE,) * 3
#: a time on a simulated or recorded clock: up to about 11.6 days
TIME = Range(0.0, 1e6, "s", "within 11.6 days of the start")
#: a duration of one dwell or phase
DURATION = Range(0.0, 86400.0, "s", "at most a day")
#: a random seed
SEED = Range(0, 2**63 - 1, "", "a 63-bit seed", integer=True)
#: the platform's speed / acceleration / jerk
SPEED = Range(0.0, 20.0, "m/s", "a winch or platform speed", lo_open=True)
ACCEL = Range(0.0, 100.0, "m/s^2", "about 10 g", lo_open=True)
#: a tension [N]: a cable robot's cables carry at most a few MN
TENSION = Range(0.0, 1e7, "N", "at most 10 MN")
#: Earth's surface gravity (9.78 at the equator to 9.83 at the poles, mines and mountains)
GRAVITY_EARTH = Range(9.76, 9.84, "m/s^2", "the Earth's surface; write gravity_unusual = "
                      "true for another gravity")
GRAVITY_ANY = Range(0.0, 100.0, "m/s^2", "gravity_unusual = true", lo_open=True)

RANGES: dict[str, dict[str, Range | tuple[Range, ...]]] = {
    "robot": {
        "gravity": GRAVITY_EARTH,
        "gravity (gravity_unusual = true)": GRAVITY_ANY,
        "platform.mass": Range(0.0, 10000.0, "kg", "a platform up to 10 t", lo_open=True),
        "platform.com": Range(-10.0, 10.0, "m", "within 10 m of the platform's origin"),
        "cables.tension_min": TENSION,
        "cables.tension_max": Range(0.0, 1e7, "N", "at most 10 MN", lo_open=True),
        "cables.ea": Range(0.0, 1e12, "N", "E*A of a cable up to 1e12 N", lo_open=True),
        "cables.rho": Range(0.0, 100.0, "kg/m", "a cable's linear mass"),
        "mast.pivot": POSITION,
        "mast.stiffness": Range(0.0, 1e12, "N m/rad", "a mast's joint stiffness; inf: rigid",
                                lo_open=True, inf_ok=True),
        "mast.tilt": Range(-0.5, 0.5, "rad", "a settlement tilt below 29 degrees"),
        "cable.exit": POSITION,
        "cable.anchor": Range(-100.0, 100.0, "m", "a platform within 100 m"),
        "cable.pulley_radius": Range(0.0, 5.0, "m", "a pulley up to 5 m"),
        "cable.ea": Range(0.0, 1e12, "N", "E*A of a cable up to 1e12 N", lo_open=True),
        "cable.drum_scale": Range(0.5, 2.0, "", "a length reading off by at most 2x"),
        "cable.length_offset": Range(-100.0, 100.0, "m", "an offset of the length reading"),
        "cable.load_cell_gain": Range(0.1, 10.0, "", "a load cell off by at most 10x"),
        "cable.load_cell_offset": Range(-1e6, 1e6, "N", "a load cell offset up to 1 MN"),
    },
    "winch": {
        "gear_ratio": Range(0.0, 1e4, "", "motor turns per drum turn", lo_open=True),
        "drum_radius_m": Range(0.0, 5.0, "m", "a drum up to 5 m", lo_open=True),
        "encoder_counts_per_rev": Range(1, 2**31 - 1, "", "a 32-bit encoder", integer=True),
        "length_at_zero_m": Range(-1e4, 1e4, "m", "a reference within 10 km"),
        "min_length_m": Range(0.0, 1e4, "m", "a cable up to 10 km"),
        "max_length_m": Range(0.0, 1e4, "m", "a cable up to 10 km", lo_open=True),
        "max_speed_m_s": SPEED,
        "max_accel_m_s2": ACCEL,
        "profile_speed_m_s": SPEED,
        "profile_accel_m_s2": ACCEL,
        "quick_stop_decel_m_s2": ACCEL,
        "following_error_m": Range(0.0, 10.0, "m", "a following error window", lo_open=True),
        "following_error_time_s": Range(0.0, 65.535, "s", "0x6066 (16 bit, ms)"),
        "position_window_m": Range(0.0, 1.0, "m", "a target window"),
        "lag_time_constant_s": Range(0.0, 10.0, "s", "a position loop's lag"),
        "rated_torque_nm": Range(0.0, 1e5, "N m", "a motor's rated torque", lo_open=True),
        "bus.bitrate": Range(10_000, 1_000_000, "bit/s", "a CAN bit rate", integer=True),
        "bus.sync_period_s": Range(1e-4, 1.0, "s", "a control cycle"),
        "bus.heartbeat_period_s": Range(0.0, 65.535, "s", "0x1017 (16 bit, ms)"),
        "bus.heartbeat_misses": Range(1, 1000, "", "heartbeat periods of silence",
                                      integer=True),
        "bus.rpdo_timeout_s": Range(0.0, 65.535, "s", "0x1400:05 (16 bit, ms)"),
        "bus.master_node_id": Range(1, 127, "", "a CANopen node id", integer=True),
        "bus.master_heartbeat_period_s": Range(0.0, 65.535, "s", "16 bit, ms"),
        "bus.master_heartbeat_timeout_s": Range(0.0, 65.535, "s", "0x1016 (16 bit, ms)"),
    },
    "scenario": {
        "init_pose": POSE,
        "seed": SEED,
        "truth.cable_length_offset.slip_time_*": TIME,
        "truth.tracker_frame.r*": Range(-0.1, 0.1, "rad", "a tracker's registration turned "
                                        "up to 6 degrees"),
        "truth.tracker_frame.t*": Range(-1.0, 1.0, "m", "a tracker's registration shifted"),
        "truth.tracker_latency.dt": Range(-1.0, 1.0, "s", "a tracker's stream late or early"),
        "truth.mast_compliance.k": Range(0.0, 1e12, "N m/rad", "a mast's joint stiffness",
                                         lo_open=True),
        "noise.tracker_m": Range(0.0, 0.1, "m", "a tracker's noise"),
        "noise.tracker_rad": Range(0.0, 0.1, "rad", "a tracker's angular noise"),
        "noise.load_cell_n": Range(0.0, 1000.0, "N", "a load cell's noise"),
        "noise.encoder_m": Range(0.0, 0.01, "m", "an encoder's noise"),
        "noise.process_m": Range(0.0, 0.1, "m", "the platform's process noise"),
        "noise.exit_m": Range(0.0, 0.1, "m", "a measured exit point's noise"),
        "nuisance.hysteresis_m": Range(0.0, 0.1, "m", "a winch's hysteresis"),
        "nuisance.drift_m_per_h": Range(-1.0, 1.0, "m/h", "an encoder drift"),
        "nuisance.thermal_strain_per_h": Range(-0.01, 0.01, "1/h", "a thermal strain rate"),
        "nuisance.backlash_m": Range(0.0, 0.1, "m", "a winch's backlash"),
        "nuisance.friction_n": Range(0.0, 1e4, "N", "a pulley's friction"),
        "nuisance.init_pretension_n": Range(0.0, 1e5, "N", "an internal force"),
        "recording.rate_hz": Range(0.0, 1e5, "Hz", "a logging rate", lo_open=True),
        "poses.x": POSITION,
        "poses.y": POSITION,
        "poses.z": POSITION,
        "poses.n": Range(1, 1000, "", "grid points per axis", integer=True),
        "poses.list": POSE,
        "poses.rpy_deg": Range(0.0, 180.0, "deg", "an orientation spread"),
        "poses.visits": Range(1, 10000, "", "visits of each pose", integer=True),
        "poses.dwell_s": DURATION,
        "poses.rate_hz": Range(0.0, 1e5, "Hz", "a logging rate"),
        "poses.init_s": DURATION,
        "poses.speed_m_s": Range(0.0, 20.0, "m/s", "a platform speed"),
    },
    "path": {
        "start": POSE,
        "repeat": Range(1, 10000, "", "repetitions of the segments", integer=True),
        "limits.max_speed_m_s": SPEED,
        "limits.speed_pct": Range(0.0, 100.0, "%", "of the path's speed", lo_open=True),
        "limits.max_accel_m_s2": ACCEL,
        "limits.max_jerk_m_s3": Range(0.0, 1e4, "m/s^3", "a jerk", lo_open=True),
        "limits.max_angular_speed_rad_s": Range(0.0, 100.0, "rad/s", "", lo_open=True),
        "limits.max_angular_accel_rad_s2": Range(0.0, 1e4, "rad/s^2", "", lo_open=True),
        "limits.max_angular_jerk_rad_s3": Range(0.0, 1e6, "rad/s^3", "", lo_open=True),
        "segment.to": POSE,
        "segment.through": POSE,
        "segment.poses": POSE,
        "segment.center": POSITION,
        "segment.normal": Range(-1e6, 1e6, "", "a direction"),
        "segment.angle_deg": Range(-36000.0, 36000.0, "deg", "at most 100 turns"),
        "segment.duration_s": DURATION,
        "segment.x": POSITION,
        "segment.y": POSITION,
        "segment.z": POSITION,
        "segment.n": Range(1, 1000, "", "grid points per axis", integer=True),
        "segment.rpy_deg": Range(0.0, 180.0, "deg", "an orientation spread"),
        "segment.visits": Range(1, 10000, "", "rounds of visits", integer=True),
        "segment.dwell_s": DURATION,
        "segment.seed": SEED,
    },
    "fault": {
        "at_s": TIME,
        "clear_s": TIME,
        "count": Range(1, 1_000_000, "", "frames, over an hour of cycles", integer=True),
        "value_N": Range(-1e6, 1e6, "N", "a load cell reading within 1 MN"),
    },
    "loadcell_map": {
        "sensor.rated_min_N": Range(-1e6, 1e6, "N", "a load cell's range"),
        "sensor.rated_max_N": Range(0.0, 1e6, "N", "a load cell's range", lo_open=True),
    },
    "calibration": {
        "gain_*": Range(0.1, 10.0, "", "a load cell off by at most 10x"),
        "offset_*": Range(-1e5, 1e5, "N", "a load cell offset up to 100 kN"),
    },
    "recording": {
        "init_pose": POSE,
        "rate_hz": Range(0.0, 1e6, "Hz", "a logging rate", lo_open=True),
        "decimate": Range(1, 1e6, "", "rows kept one in N", integer=True),
    },
}

#: what each file kind is, for the documentation
KINDS: dict[str, str] = {
    "robot": "robot description (`robot.toml`, also inside a recording and a scenario)",
    "winch": "winch parameter file (`[defaults]` and `[[winch]]`, `[bus]`)",
    "scenario": "scenario (`cdpr-scenario/1`); the truth's robot is checked as a robot",
    "path": "path file (`cdpr-path/1`)",
    "fault": "fault schedule (`[[fault]]`)",
    "loadcell_map": "load-cell register map",
    "calibration": "load-cell calibration (`gain_ij`, `offset_ij`)",
    "recording": "a recording's `meta.toml`",
}


def lookup(kind: str, fld: str) -> Range | tuple[Range, ...] | None:
    """The range of field ``fld`` of file kind ``kind`` (None: not a ranged field); a
    table key with ``*`` matches as a shell pattern (``offset_*``)."""
    table = RANGES[kind]
    if fld in table:
        return table[fld]
    return next((r for k, r in table.items() if "*" in k and fnmatch.fnmatchcase(fld, k)),
                None)


def problem(kind: str, fld: str, value: Any, component: int | None = None) -> str | None:
    """Why ``value`` is not physical for ``fld`` (None: it is, or the field has no range).

    ``component``: the index of ``value`` in a vector field (a pose's angle has another
    range than its position)."""
    rng = lookup(kind, fld)
    if rng is None:
        return None
    if isinstance(rng, tuple):
        rng = rng[component if component is not None and component < len(rng) else 0]
    name = fld.split(" ")[0].split(".")[-1]
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        return f"{value!r} is not a number (allowed: {rng.text(name)})"
    if rng.contains(v):
        return None
    why = f" ({rng.why})" if rng.why else ""
    shown = repr(value) if type(value) in (int, float) else repr(v)  # numpy scalars as floats
    return f"{shown} is outside the physical range {rng.text(name)}{why}"


def check(kind: str, fld: str, value: Any, where: str, error: type[Exception],
          component: int | None = None) -> None:
    """Raise ``error(f"{where}: {why}")`` when ``value`` is outside the range of ``fld``.

    ``where`` names the file, the line and the field (``robot.toml:12: [platform].mass``)."""
    why = problem(kind, fld, value, component)
    if why is not None:
        raise error(f"{where}: {why}")


def robot_problems(robot: Any) -> list[str]:
    """The numbers of a built robot (arrays, e.g. a scenario's truth after its effects)
    outside the robot's ranges: ``["cable 21 exit[0]: 1e+300 is outside ..."]``."""
    out: list[str] = []
    g_key = "gravity" if GRAVITY_EARTH.contains(robot.gravity) else \
        "gravity (gravity_unusual = true)"
    scalars = (("gravity", g_key, robot.gravity), ("mass", "platform.mass", robot.mass),
               ("tension_min", "cables.tension_min", robot.tension_min),
               ("tension_max", "cables.tension_max", robot.tension_max),
               ("rho", "cables.rho", robot.rho))
    for name, fld, v in scalars:
        if (why := problem("robot", fld, v)) is not None:
            out.append(f"{name}: {why}")
    for a in range(3):
        if (why := problem("robot", "platform.com", robot.com[a])) is not None:
            out.append(f"com[{a}]: {why}")
    per_cable = (("exit", robot.exits), ("anchor", robot.anchors),
                 ("pulley_radius", robot.pulley_radius), ("ea", robot.ea),
                 ("drum_scale", robot.drum_scale), ("length_offset", robot.length_offset),
                 ("load_cell_gain", robot.load_cell_gain),
                 ("load_cell_offset", robot.load_cell_offset))
    for key, arr in per_cable:
        for k, cid in enumerate(robot.cable_ids):
            vals = arr[k] if arr.ndim > 1 else [arr[k]]
            for i, v in enumerate(vals):
                if key == "ea" and v == math.inf:
                    continue  # inextensible: no ea written
                if (why := problem("robot", f"cable.{key}", v, i)) is not None:
                    comp = f"[{i}]" if arr.ndim > 1 else ""
                    out.append(f"cable {cid} {key}{comp}: {why}")
    per_mast = (("pivot", robot.pivots), ("stiffness", robot.stiffness), ("tilt", robot.tilt))
    for key, arr in per_mast:
        for m, mid in enumerate(robot.mast_ids):
            for i, v in enumerate(arr[m]):
                if (why := problem("robot", f"mast.{key}", v, i)) is not None:
                    out.append(f"mast {mid} {key}[{i}]: {why}")
    return out


def markdown() -> str:
    """The ranges as Markdown tables, one per file kind (docs/reference/validation.md)."""
    lines: list[str] = []
    for kind, table in RANGES.items():
        lines += [f"### {kind}", "", KINDS[kind], "", "| field | allowed | meaning |",
                  "| --- | --- | --- |"]
        for fld, rng in table.items():
            if isinstance(rng, tuple):
                parts = _components(rng)
                lines.append(f"| `{fld}` | {parts} | {rng[0].why} |")
            else:
                lines.append(f"| `{fld}` | {rng.text()} | {rng.why} |")
        lines.append("")
    return "\n".join(lines)


def _components(rngs: tuple[Range, ...]) -> str:
    if len(rngs) == 6 and rngs[:3] == (POSITION,) * 3 and rngs[3:] == (ANGLE,) * 3:
        return f"x, y, z: {POSITION.text()}; roll, pitch, yaw: {ANGLE.text()}"
    return "; ".join(f"[{i}] {r.text()}" for i, r in enumerate(rngs))


if __name__ == "__main__":  # regenerate the tables of docs/reference/validation.md
    print(markdown())
