"""Scenario files (``cdpr-scenario/1``): what the simulated robot really is, and how it is run.

Only the simulation reads a scenario: the concealed effects (``[truth.<effect>]``
tables with the parameter keys of the conventions' effect vocabulary), the
nuisances outside the vocabulary, the measurement noise and the poses of a
campaign. A recording made from a scenario carries the model (``robot``) but
never the truth.

```toml
format = "cdpr-scenario/1"
robot = "rocaspect"              # the model the controller runs with: shipped name or path,
                                 # or an inline table holding a robot.toml ([robot] ...)
seed = 1
init_pose = [10.0, 8.56, 1.0, 0.0, 0.0, 0.0]

[truth.mast_compliance]          # effects the robot has and the model leaves out
k = [2.0e5, 5.0e5, 3.0e5]        # shortcut: kx, ky, kz of every mast
[truth.exit_point_offset]
dx_21 = 0.05
[truth.cable_length_offset]
dl_21 = 0.004
slip_time_21 = 120.0             # the offset appears at t = 120 s (a slip); default: right
                                 # after the initialisation dwell

[noise]                          # standard deviations (encoder: quantisation step)
tracker_m = 3.0e-5
tracker_rad = 2.0e-5
load_cell_n = 0.5
encoder_m = 1.0e-6
process_m = 2.0e-4               # per visit, on each unstretched length (repeatability)
exit_m = 5.0e-5                  # tracker on exit points

[nuisance]                       # physics outside the effect vocabulary
hysteresis_m = 1.0e-4            # every cable, by the direction of its last move
drift_m_per_h = 5.0e-5           # every cable, uniform creep
backlash_m = 0.0                 # backlash_cables' winches: direction-dependent length error
backlash_cables = []             # cable ids (default: none)
thermal_strain_per_h = 0.0       # thermal expansion of every cable [1/h]
friction_n = 0.0                 # pulley friction seen by friction_cables' load cells [N]
friction_cables = []             # cable ids (default: every cable when friction_n > 0)
init_pretension_n = 0.0          # tensions at referencing off the distribution's by internal
                                 # forces of this size [N] (random null-space direction)
rope_settle_m = 0.0              # the masts' supporting ropes keep settling: every exit point
rope_settle_h = 1.0              # moves this far [m] toward the pivots' centroid per this time [h]

[recording]                      # what is recorded and how
kind = "dwell"                   # dwell: visits with dwells | continuous: rows along the path
dwell_at_targets = true          # continuous: stop for poses.dwell_s at each target
rate_hz = 2.0                    # rows per second (default: poses.rate_hz)
state_column = true              # write the controller state (init, move, dwell)
tracker = true                   # record the measured pose (x_meas ...)
load_cells = true                # record the tensions (tau_ij)

[poses]
kind = "grid"                    # grid | random | list
x = [3.0, 17.0]
y = [2.5, 14.5]
z = [0.8, 1.6]
n = [5, 4, 2]                    # grid points along x, y, z (grid) / count (random: n = 60)
rpy_deg = 2.0                    # orientation amplitude (random, uniform) [deg]
visits = 3
dwell_s = 3.0
rate_hz = 2.0
init_s = 4.0
speed_m_s = 0.25
exit_points = []                 # cable ids whose exit point the tracker also measures
```

A scenario may also name the path a dry run follows: ``path = "paper-centre"`` (a
shipped ``cdpr-path/1`` file by name, or a file relative to the scenario).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from controller.effects import EFFECT_NAMES, apply_effects
from controller.ranges import check, robot_problems
from controller.robot import Robot, RobotFileError, parse_robot, resolve_robot
from controller.tomlfile import Locator

if TYPE_CHECKING:
    from firmware_sim.plant import Nuisances

FORMAT = "cdpr-scenario/1"


class ScenarioError(ValueError):
    """An invalid scenario; the message names the file and the field."""


@dataclass(frozen=True)
class Noise:
    """Measurement noise (standard deviations) and encoder quantisation step."""

    tracker_m: float = 3.0e-5
    tracker_rad: float = 2.0e-5
    load_cell_n: float = 0.5
    encoder_m: float = 1.0e-6
    process_m: float = 2.0e-4
    exit_m: float = 5.0e-5


@dataclass(frozen=True)
class PoseSet:
    """How a campaign visits the workspace."""

    kind: str = "grid"
    x: tuple[float, float] = (3.0, 17.0)
    y: tuple[float, float] = (2.5, 14.5)
    z: tuple[float, float] = (0.8, 1.6)
    n: tuple[int, ...] = (5, 4, 2)
    rpy_deg: float = 0.0
    poses: tuple[tuple[float, ...], ...] = ()
    visits: int = 3
    dwell_s: float = 3.0
    rate_hz: float = 2.0
    init_s: float = 4.0
    speed_m_s: float = 0.25
    exit_points: tuple[str, ...] = ()

    def generate(self, rng: np.random.Generator) -> np.ndarray:
        """The poses (P, 6) of one round of visits."""
        if self.kind == "list":
            return np.array(self.poses, dtype=float).reshape(-1, 6)
        if self.kind == "grid":
            nx, ny, nz = (list(self.n) + [1, 1, 1])[:3]
            xs = np.linspace(*self.x, nx)
            ys = np.linspace(*self.y, ny)
            zs = np.linspace(*self.z, nz) if nz > 1 else np.array([np.mean(self.z)])
            pts = np.array([[x, y, z] for z in zs for y in ys for x in xs])
        elif self.kind == "random":
            count = int(self.n[0])
            lo = np.array([self.x[0], self.y[0], self.z[0]])
            hi = np.array([self.x[1], self.y[1], self.z[1]])
            pts = rng.uniform(lo, hi, (count, 3))
        else:
            raise ValueError(f"unknown pose set kind {self.kind!r}")
        ang = np.radians(self.rpy_deg) * rng.uniform(-1, 1, (len(pts), 3)) if self.rpy_deg \
            else np.zeros((len(pts), 3))
        return np.hstack([pts, ang])


@dataclass(frozen=True)
class RecordingSpec:
    """What a campaign records: ``kind`` ``dwell`` (dwells at the targets, one row per
    ``1/rate_hz`` while standing) or ``continuous`` (rows at ``rate_hz`` along straight
    lines between targets, with dwells at the targets if ``dwell_at_targets``); which
    column groups (``tracker``, ``load_cells``, ``state_column``)."""

    kind: str = "dwell"
    dwell_at_targets: bool = True
    rate_hz: float | None = None
    state_column: bool = True
    tracker: bool = True
    load_cells: bool = True


@dataclass
class Scenario:
    """A parsed scenario: ``model`` as the controller knows it, ``truth`` the real robot."""

    path: Path
    model: Robot
    truth: Robot
    effects: dict[str, dict[str, float]]
    slip_times: np.ndarray
    init_pose: np.ndarray
    seed: int = 0
    noise: Noise = field(default_factory=Noise)
    hysteresis_m: float = 0.0
    drift_m_per_s: float = 0.0
    poses: PoseSet = field(default_factory=PoseSet)
    notes: str = ""
    #: the path a dry run follows (a ``cdpr-path/1`` file, by name or relative path), or ""
    run_path: str = ""
    backlash_m: np.ndarray | float = 0.0
    thermal_strain_per_s: float = 0.0
    friction_n: np.ndarray | float = 0.0
    recording: RecordingSpec = field(default_factory=RecordingSpec)
    #: the supervisor's reactions a dry run of this scenario changes by default, condition
    #: -> reaction name (``react = { slack = "log" }``; ``cdpr dry-run --react`` overrides)
    react: dict[str, str] = field(default_factory=dict)
    #: internal forces [N] by which the tensions at referencing differ from the distribution's
    init_pretension_n: float = 0.0
    #: the supporting ropes' further settling: exit displacement [m] per ``rope_settle_s``
    rope_settle_m: float = 0.0
    rope_settle_s: float = 3600.0

    def nuisances(self, process: bool = True) -> Nuisances:
        """The plant's nuisances for this scenario (``process``: with the per-visit process
        noise of the cable lengths)."""
        from firmware_sim.plant import Nuisances

        return Nuisances(self.hysteresis_m, self.drift_m_per_s,
                         self.noise.process_m if process else 0.0, self.backlash_m,
                         self.thermal_strain_per_s, self.friction_n,
                         self.init_pretension_n, self.rope_settle_m, self.rope_settle_s)


_TOP = {"format", "robot", "seed", "init_pose", "truth", "noise", "nuisance", "poses", "notes",
        "path", "recording", "react"}
_NUISANCE = ("hysteresis_m", "drift_m_per_h", "backlash_m", "backlash_cables",
             "thermal_strain_per_h", "friction_n", "friction_cables", "init_pretension_n",
             "rope_settle_m", "rope_settle_h")
_RECORDING = {"kind", "dwell_at_targets", "rate_hz", "state_column", "tracker", "load_cells"}


def _num(path: Path, where: str, v: Any, positive: bool = False, nonneg: bool = False,
         loc: Locator | None = None, component: int | None = None) -> float:
    """``v`` as a finite number within the physical range of field ``where``
    (:mod:`controller.ranges`; ``component``: its index in a vector field); the range
    error names the line when ``loc`` has the file's text."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ScenarioError(f"{path}: {where}: must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise ScenarioError(f"{path}: {where}: must be > 0, got {v}")
    if nonneg and v < 0:
        raise ScenarioError(f"{path}: {where}: must be >= 0, got {v}")
    table, _, key = where.rpartition(".")
    line = loc.line(table or None, None, key) if loc is not None else None
    head = f"{path}:{line}: {where}" if line else f"{path}: {where}"
    check("scenario", where, v, head + (f"[{component}]" if component is not None else ""),
          ScenarioError, component)
    return float(v)


def _table(p: Path, name: str, value: Any) -> dict:
    if not isinstance(value, dict):
        raise ScenarioError(f"{p}: {name}: must be a table, got {value!r}")
    return value


def parse_scenario(data: dict[str, Any], path: str | Path = "<memory>",
                   text: str = "") -> Scenario:
    """Validate a parsed scenario mapping (``text``: the file's, for line numbers)."""
    r = _Reader(Path(path), Locator(text))
    p = r.p
    for k in data:
        if k not in _TOP:
            raise ScenarioError(f"{p}: {k}: unknown key (allowed: {', '.join(sorted(_TOP))})")
    if data.get("format") != FORMAT:
        raise ScenarioError(f"{p}: format: expected {FORMAT!r}, got {data.get('format')!r}")
    model = r.model(data.get("robot", "rocaspect"))
    ip = data.get("init_pose", [10.0, 8.56, 1.0, 0.0, 0.0, 0.0])
    if not isinstance(ip, list) or len(ip) != 6:
        raise ScenarioError(f"{p}: init_pose: must be 6 numbers")
    init_pose = np.array([r.num("init_pose", v, component=i) for i, v in enumerate(ip)])
    truth, effects, slips = r.truth(model, data.get("truth", {}))
    noise = r.noise(data.get("noise", {}))
    nz = _table(p, "nuisance", data.get("nuisance", {}))
    for k in nz:
        if k not in _NUISANCE:
            raise ScenarioError(f"{p}: nuisance.{k}: unknown key (allowed: "
                                f"{', '.join(sorted(_NUISANCE))})")
    num = r.num
    hyst = num("nuisance.hysteresis_m", nz.get("hysteresis_m", 0.0), nonneg=True)
    drift = num("nuisance.drift_m_per_h", nz.get("drift_m_per_h", 0.0)) / 3600.0
    thermal = num("nuisance.thermal_strain_per_h", nz.get("thermal_strain_per_h", 0.0)) \
        / 3600.0
    backlash = r.per_cable(model, nz, "backlash_m", "backlash_cables", False)
    friction = r.per_cable(model, nz, "friction_n", "friction_cables", True)
    recording = r.recording(data.get("recording", {}))
    poses = r.poses(model, _table(p, "poses", data.get("poses", {})))
    run_path = data.get("path", "")
    if not isinstance(run_path, str):
        raise ScenarioError(f"{p}: path: must be a path file name or relative path (string)")
    if run_path and p.name != "<memory>" and (p.parent / run_path).exists():
        run_path = str(p.parent / run_path)
    return Scenario(p, model, truth, effects, slips, init_pose,
                    int(num("seed", data.get("seed", 0), nonneg=True)), noise, hyst, drift,
                    poses, str(data.get("notes", "")), run_path, backlash, thermal,
                    friction, recording, _react(p, data.get("react", {})),
                    num("nuisance.init_pretension_n", nz.get("init_pretension_n", 0.0),
                        nonneg=True),
                    num("nuisance.rope_settle_m", nz.get("rope_settle_m", 0.0), nonneg=True),
                    3600.0 * num("nuisance.rope_settle_h", nz.get("rope_settle_h", 1.0),
                                 positive=True))


#: the keys of the ``poses`` table
_POSES = {"kind", "x", "y", "z", "n", "rpy_deg", "list", "visits", "dwell_s", "rate_hz",
          "init_s", "speed_m_s", "exit_points"}


@dataclass
class _Reader:
    """The tables of one scenario file checked: ``p`` names it in errors, ``loc`` finds
    a field's line."""

    p: Path
    loc: Locator

    def num(self, where: str, v: Any, positive: bool = False, nonneg: bool = False,
            component: int | None = None) -> float:
        """:func:`_num` on this file."""
        return _num(self.p, where, v, positive, nonneg, self.loc, component)

    def model(self, robot_ref: Any) -> Robot:
        """The scenario's robot: an inline robot.toml table, a file beside the scenario,
        or a shipped robot's name."""
        p = self.p
        try:
            if isinstance(robot_ref, dict):  # an inline robot.toml
                return parse_robot(robot_ref, f"{p} [robot]")
            robot_ref = str(robot_ref)
            candidate = (p.parent / robot_ref) if p.name != "<memory>" else Path(robot_ref)
            return resolve_robot(candidate if candidate.exists() else robot_ref)
        except RobotFileError as e:
            raise ScenarioError(f"{p}: robot: {e}") from e

    def truth(self, model: Robot, truth_tab: Any
              ) -> tuple[Robot, dict[str, dict[str, float]], np.ndarray]:
        """The ``truth`` table: the robot its effects make (checked physical), the effects'
        parameters, and the cables' slip times [s] (0: none)."""
        p = self.p
        slips = np.zeros(model.n_cables)
        if not isinstance(truth_tab, dict):
            raise ScenarioError(f"{p}: truth: must be a table of effects")
        effects: dict[str, dict[str, float]] = {}
        for eff, params in truth_tab.items():
            if eff not in EFFECT_NAMES:
                raise ScenarioError(f"{p}: truth.{eff}: unknown effect (known: "
                                    f"{', '.join(EFFECT_NAMES)})")
            if not isinstance(params, dict):
                raise ScenarioError(f"{p}: truth.{eff}: must be a table of parameters")
            effects[eff] = self._effect(model, eff, params, slips)
        try:
            truth = apply_effects(model, effects, name=f"{model.name} (truth)")
        except (KeyError, ValueError) as e:
            raise ScenarioError(f"{p}: truth: {e.args[0] if e.args else e}") from e
        bad = robot_problems(truth)
        if bad:
            raise ScenarioError(f"{p}: truth: the robot its effects describe is not physical: "
                                f"{bad[0]}"
                                + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""))
        return truth, effects, slips

    def _effect(self, model: Robot, eff: str, params: dict, slips: np.ndarray
                ) -> dict[str, float]:
        """One effect's parameters (a mast stiffness [kx, ky, kz] for every mast; a
        length offset's ``slip_time_<cable>`` into ``slips``)."""
        vals: dict[str, float] = {}
        for key, v in params.items():
            where = f"truth.{eff}.{key}"
            if eff == "mast_compliance" and key == "k":
                if not isinstance(v, list) or len(v) != 3:
                    raise ScenarioError(f"{self.p}: {where}: must be [kx, ky, kz]")
                for mid in model.mast_ids:
                    for ax, kv in zip("xyz", v, strict=True):
                        vals[f"k{ax}_{mid}"] = self.num(where, kv, positive=True)
            elif eff == "cable_length_offset" and key.startswith("slip_time_"):
                cid = key[len("slip_time_"):]
                if cid not in model.cable_ids:
                    raise ScenarioError(f"{self.p}: {where}: no cable {cid!r}")
                slips[model.cable_ids.index(cid)] = self.num(where, v, nonneg=True)
            else:
                vals[key] = self.num(where, v)
        return vals

    def noise(self, tab: Any) -> Noise:
        """The ``noise`` table."""
        noise_tab = _table(self.p, "noise", tab)
        known = set(Noise.__dataclass_fields__)
        for k in noise_tab:
            if k not in known:
                raise ScenarioError(f"{self.p}: noise.{k}: unknown key "
                                    f"(allowed: {', '.join(sorted(known))})")
        return Noise(**{k: self.num(f"noise.{k}", v, nonneg=True)
                        for k, v in noise_tab.items()})

    def per_cable(self, model: Robot, nz: dict, key: str, cables_key: str,
                  default_all: bool) -> np.ndarray:
        """A nuisance's size on the cables ``cables_key`` lists (without the list: every
        cable or none, by ``default_all``), zero elsewhere."""
        v = self.num(f"nuisance.{key}", nz.get(key, 0.0), nonneg=True)
        ids = nz.get(cables_key)
        if ids is None:
            ids = list(model.cable_ids) if default_all else []
        if not isinstance(ids, list):
            raise ScenarioError(f"{self.p}: nuisance.{cables_key}: must be a list of cable ids")
        out = np.zeros(model.n_cables)
        for c in ids:
            if str(c) not in model.cable_ids:
                raise ScenarioError(f"{self.p}: nuisance.{cables_key}: no cable {c!r}")
            out[model.cable_ids.index(str(c))] = v
        return out

    def recording(self, rt: Any) -> RecordingSpec:
        """The ``recording`` table: kind, rate and the column groups written."""
        p = self.p
        if not isinstance(rt, dict):
            raise ScenarioError(f"{p}: recording: must be a table")
        for k in rt:
            if k not in _RECORDING:
                raise ScenarioError(f"{p}: recording.{k}: unknown key (allowed: "
                                    f"{', '.join(sorted(_RECORDING))})")
        rkw: dict[str, Any] = {}
        if "kind" in rt:
            if rt["kind"] not in ("dwell", "continuous"):
                raise ScenarioError(f"{p}: recording.kind: must be dwell or continuous")
            rkw["kind"] = rt["kind"]
        for k in ("dwell_at_targets", "state_column", "tracker", "load_cells"):
            if k in rt:
                if not isinstance(rt[k], bool):
                    raise ScenarioError(f"{p}: recording.{k}: must be true or false")
                rkw[k] = rt[k]
        if "rate_hz" in rt:
            rkw["rate_hz"] = self.num("recording.rate_hz", rt["rate_hz"], positive=True)
        if not rkw.get("tracker", True) and not rkw.get("load_cells", True):
            raise ScenarioError(f"{p}: recording: a recording needs the tracker or the load "
                                f"cells")
        return RecordingSpec(**rkw)

    def poses(self, model: Robot, ps: dict) -> PoseSet:
        """The ``poses`` table: a grid, random poses or a list, visits and timing."""
        p, num = self.p, self.num
        for k in ps:
            if k not in _POSES:
                raise ScenarioError(f"{p}: poses.{k}: unknown key "
                                    f"(allowed: {', '.join(sorted(_POSES))})")
        kw: dict[str, Any] = {}
        for k in ("x", "y", "z"):
            if k in ps:
                v = ps[k]
                if not isinstance(v, list) or len(v) != 2:
                    raise ScenarioError(f"{p}: poses.{k}: must be [min, max]")
                kw[k] = (num(f"poses.{k}", v[0]), num(f"poses.{k}", v[1]))
        if "n" in ps:
            n = ps["n"] if isinstance(ps["n"], list) else [ps["n"]]
            kw["n"] = tuple(int(num("poses.n", v, positive=True)) for v in n)
        if "list" in ps:
            lst = ps["list"]
            if not isinstance(lst, list) or not all(isinstance(r, list) and len(r) == 6
                                                    for r in lst):
                raise ScenarioError(f"{p}: poses.list: must be a list of [x, y, z, roll, "
                                    f"pitch, yaw]")
            kw["poses"] = tuple(tuple(num("poses.list", v, component=i)
                                      for i, v in enumerate(r)) for r in lst)
            kw["kind"] = "list"
        if "kind" in ps:
            if ps["kind"] not in ("grid", "random", "list"):
                raise ScenarioError(f"{p}: poses.kind: must be grid, random or list")
            kw["kind"] = ps["kind"]
        for k in ("rpy_deg", "dwell_s", "rate_hz", "init_s", "speed_m_s"):
            if k in ps:
                kw[k] = num(f"poses.{k}", ps[k], nonneg=True)
        if "visits" in ps:
            kw["visits"] = int(num("poses.visits", ps["visits"], positive=True))
        if "exit_points" in ps:
            if not isinstance(ps["exit_points"], list):
                raise ScenarioError(f"{p}: poses.exit_points: must be a list of cable ids")
            ep = [str(c) for c in ps["exit_points"]]
            for c in ep:
                if c not in model.cable_ids:
                    raise ScenarioError(f"{p}: poses.exit_points: no cable {c!r}")
            kw["exit_points"] = tuple(ep)
        return PoseSet(**kw)


def _react(p: Path, react: Any) -> dict[str, str]:
    """The ``react`` table: supervisor conditions -> reaction names, checked against the
    supervisor's (controller/supervisor.py)."""
    from controller.supervisor import parse_reactions

    if not isinstance(react, dict):
        raise ScenarioError(f"{p}: react: must be a table of condition = \"reaction\"")
    for k, v in react.items():
        if not isinstance(v, str):
            raise ScenarioError(f"{p}: react.{k}: must be a reaction name (string)")
        try:
            parse_reactions([f"{k}={v}"])
        except ValueError as e:
            raise ScenarioError(f"{p}: react.{k}: {e}") from e
    return {str(k): str(v).lower() for k, v in react.items()}


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file."""
    from controller.tomlfile import read_toml

    p = Path(path)
    data, text = read_toml(p, ScenarioError)  # errors name the file (line, column)
    try:
        return parse_scenario(data, p, text)
    except (TypeError, ValueError, KeyError, AttributeError) as e:
        if isinstance(e, ScenarioError):
            raise
        raise ScenarioError(f"{p}: not a valid scenario: {type(e).__name__}: {e}") from None
