"""``cdpr commission reference``: the winches referenced from a measured platform pose, and
the commissioning state file that remembers it.

A CDPR's winches are referenced as the controller initialises (cdpr-conventions): at a
measured pose p0 (the tracker, or ``--pose`` known on the stand) each encoder's reading
becomes the model's length there, ``d_model(p0)``
(:func:`controller.cycle.reference_lengths`); the per-winch offset is model minus reading,
as :meth:`hal.interface.WinchHardware.reference` does for the dry run. Nothing moves and
nothing is written to the drives.

The state file (``--state FILE``, default ``commissioning-state.toml`` beside the
commissioning report), format ``cdpr-commission-state/1``::

    format = "cdpr-commission-state/1"
    referenced = true              # false once a CiA 402 homing changed a count
    time = "2026-12-04T21:05:00Z"  # UTC
    robot = "rocaspect"            # the model the lengths come from
    pose = [10.0, 8.56, 1.0, 0.0, 0.0, 0.0]   # p0: x, y, z [m], roll, pitch, yaw [rad]
    pose_source = "--pose (known pose on the stand)"
    lost = ""                      # why the reference was lost (when referenced = false)

    [[winch]]
    cable = "11"
    node_id = 1
    position_counts = 28455846     # the drive's reading at p0 (0x6064)
    reading_m = 9.5312             # that reading through the winch file [m]
    model_m = 9.5312               # d_model(p0) [m]
    offset_m = 0.0                 # model_m - reading_m: added to every reading

A CiA 402 homing (``cdpr commission home --method``) changes a drive's count: the state's
reference is marked lost (``referenced = false``, ``lost`` says why), and the Cartesian jog
is refused until ``reference`` has run again.
"""

from __future__ import annotations

import argparse
import math
import time
import tomllib
from pathlib import Path

import numpy as np

from bench.commission.common import CommissionError, Ui, network_of, winches_of
from bench.commission.report import Section, report_path

FORMAT = "cdpr-commission-state/1"
DEFAULT_STATE = "commissioning-state.toml"


def state_path(args: argparse.Namespace) -> Path:
    """``--state``, else ``commissioning-state.toml`` beside the commissioning report."""
    if getattr(args, "state", None):
        return Path(args.state)
    rep = report_path(args)
    return (rep.parent if rep is not None else Path(".")) / DEFAULT_STATE


def parse_pose(text: str, what: str = "--pose") -> np.ndarray:
    """``x,y,z[,roll,pitch,yaw]`` [m, deg] -> (6,) [m, rad]; CommissionError naming
    ``what``."""
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) == 3:
        v += [0.0, 0.0, 0.0]
    if len(v) != 6 or not all(math.isfinite(x) for x in v):
        raise CommissionError(f"{what} {text!r}: expected x,y,z[,roll,pitch,yaw] (m, deg), "
                              "finite numbers", 2)
    return np.r_[v[:3], np.radians(v[3:])]


def _num(x: float) -> str:
    return repr(float(x))


def dumps_state(state: dict) -> str:
    """The state as TOML (the layout of the module docstring)."""
    lines = [f'format = "{FORMAT}"', f"referenced = {str(bool(state['referenced'])).lower()}",
             f'time = "{state["time"]}"', f'robot = "{state["robot"]}"',
             "pose = [" + ", ".join(_num(x) for x in state["pose"]) + "]",
             f'pose_source = "{state["pose_source"]}"', f'lost = "{state.get("lost", "")}"']
    for wn in state["winch"]:
        lines += ["", "[[winch]]", f'cable = "{wn["cable"]}"', f"node_id = {int(wn['node_id'])}",
                  f"position_counts = {int(wn['position_counts'])}",
                  f"reading_m = {_num(wn['reading_m'])}", f"model_m = {_num(wn['model_m'])}",
                  f"offset_m = {_num(wn['offset_m'])}"]
    return "\n".join(lines) + "\n"


def read_state(path: Path) -> dict | None:
    """The state file's content, None if there is none; CommissionError naming the file
    and field when it is not a ``cdpr-commission-state/1``."""
    if not path.is_file():
        return None
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CommissionError(f"{path}: not TOML: {exc}", 2) from None
    if data.get("format") != FORMAT:
        raise CommissionError(f"{path}: format: expected {FORMAT!r}, got "
                              f"{data.get('format')!r}", 2)
    for key, typ in (("referenced", bool), ("pose", list), ("winch", list)):
        if not isinstance(data.get(key), typ):
            raise CommissionError(f"{path}: field {key!r} missing or not a {typ.__name__}", 2)
    return data


def write_state(path: Path, state: dict) -> None:
    """Write atomically (a temporary file renamed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(dumps_state(state))
    tmp.replace(path)


def mark_lost(path: Path, why: str) -> bool:
    """Mark the reference lost (``referenced = false``, ``lost = why``); False when there
    was no referenced state."""
    st = read_state(path)
    if st is None or not st["referenced"]:
        return False
    st["referenced"] = False
    st["lost"] = why
    write_state(path, st)
    return True


def require_reference(path: Path, w) -> np.ndarray:
    """The reference offsets [m] (n,) in the winch file's cable order, or CommissionError
    saying why Cartesian motion is refused."""
    st = read_state(path)
    if st is None:
        raise CommissionError(f"no reference ({path} does not exist): run `cdpr commission "
                              "reference` (tracker, or --pose on the stand) first", 1)
    if not st["referenced"]:
        why = st.get("lost") or "referenced = false"
        raise CommissionError(f"the winches are not referenced ({path}: {why}): Cartesian "
                              "motion is refused until `cdpr commission reference` has run "
                              "again", 1)
    by_cable = {str(x["cable"]): float(x["offset_m"]) for x in st["winch"]}
    missing = [c for c in w.cables if c not in by_cable]
    if missing:
        raise CommissionError(f"{path}: no reference for cable(s) {', '.join(missing)}", 1)
    return np.array([by_cable[c] for c in w.cables])


def read_positions(net, w, eds: str) -> np.ndarray:
    """Every drive's position actual 0x6064 [counts] by SDO (nothing moves)."""
    import canopen

    from hal.drives_config import sdo_read

    out = []
    for k, nid in enumerate(int(x) for x in w.node_id):
        node = canopen.RemoteNode(nid, canopen.import_od(str(eds), nid))
        net.add_node(node)
        try:
            out.append(int(sdo_read(node, 0x6064, 0, f"node {nid} (cable {w.cables[k]})")))
        finally:
            del net[nid]
    return np.array(out)


def check_readings(w, reading: np.ndarray, model: np.ndarray | None = None) -> None:
    """CommissionError when a drive's reading [m] is outside its winch range: its count was
    homed (or the winch file's ``length_at_zero_m`` is wrong), so the drive's position
    limits and every setpoint through the winch file would be wrong too. Names the fix."""
    bad = (reading < w.min_length_m) | (reading > w.max_length_m)
    if not bad.any():
        return
    k = int(np.flatnonzero(bad)[0])
    c = w.cables[k]
    fix = (f"cdpr commission home {c} --length {model[k]:.4f}" if model is not None
           else f"cdpr commission home {c} --length L")
    raise CommissionError(
        f"cable {c} (CAN node {int(w.node_id[k])}) reads {reading[k]:.4f} m, outside "
        f"[{w.min_length_m[k]:g}, {w.max_length_m[k]:g}] m of {w.source}: its count was homed "
        f"or length_at_zero_m is wrong; set the winch's length first ({fix}"
        + (", the model's length at this pose)" if model is not None else ")"), 1)


def _measured_pose(args: argparse.Namespace, ui: Ui) -> tuple[np.ndarray, str]:
    if args.pose:
        return parse_pose(args.pose), "--pose (known pose on the stand)"
    from bench.dryrun.loop import measure_init_pose
    from hal.tracker import TrackerError, TrackerSpecError, open_tracker

    try:
        tracker = open_tracker(args.tracker)
    except TrackerSpecError as exc:
        raise CommissionError(f"--tracker {args.tracker!r}: {exc}", 2) from None
    if tracker is None:
        raise CommissionError("no pose: give --tracker SPEC (the laser tracker on the "
                              "platform) or --pose x,y,z[,r,p,y] (a known pose on the stand)", 2)
    ui.progress(f"measuring the pose with the tracker ({args.samples} samples) ...")
    try:
        tracker.start()
        pose = measure_init_pose(tracker, args.samples)
    except (TrackerError, TimeoutError, OSError) as exc:
        raise CommissionError(f"tracker: {exc}", 1) from None
    finally:
        tracker.close()
    return pose, f"tracker, mean of {args.samples} samples"


def run_reference(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from controller.cycle import reference_lengths
    from controller.robot import resolve_robot

    w = winches_of(args)
    robot = resolve_robot(args.robot)
    if tuple(robot.cable_ids) != tuple(w.cables):
        raise CommissionError(f"robot {robot.name} has cables {robot.cable_ids}, the winches "
                              f"{w.source} {w.cables}", 2)
    pose, source = _measured_pose(args, ui)
    model = reference_lengths(robot, pose)
    with network_of(args) as net:
        counts = read_positions(net, w, args.eds)
    reading = np.array([w.axis(k).counts_to_m(int(c)) for k, c in enumerate(counts)])
    check_readings(w, reading, model)
    offset = model - reading
    bad = (model < w.min_length_m) | (model > w.max_length_m)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise CommissionError(f"pose {np.round(pose, 4).tolist()}: cable {w.cables[k]} would "
                              f"be {model[k]:.4f} m, outside [{w.min_length_m[k]:g}, "
                              f"{w.max_length_m[k]:g}] m of {w.source}: is the pose right?", 1)
    path = state_path(args)
    state = {"referenced": True, "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
             "robot": robot.name, "pose": [float(x) for x in pose], "pose_source": source,
             "lost": "", "winch": [
                 {"cable": c, "node_id": int(w.node_id[k]), "position_counts": int(counts[k]),
                  "reading_m": float(reading[k]), "model_m": float(model[k]),
                  "offset_m": float(offset[k])} for k, c in enumerate(w.cables)]}
    write_state(path, state)
    section.fact("pose", f"{np.round(pose, 5).tolist()} ({source})")
    section.table(["cable", "node", "reading [m]", "model [m]", "offset [mm]"],
                  [[c, int(w.node_id[k]), f"{reading[k]:.5f}", f"{model[k]:.5f}",
                    f"{1e3 * offset[k]:+.2f}"] for k, c in enumerate(w.cables)])
    section.fact("state", str(path))
    for k, c in enumerate(w.cables):
        ui.say(f"  cable {c:>3} node {int(w.node_id[k])}: reading {reading[k]:.5f} m, model "
               f"{model[k]:.5f} m, offset {1e3 * offset[k]:+.2f} mm")
    ui.say(f"referenced at pose {np.round(pose, 5).tolist()} ({source}); written to {path}")
    ui.emit({"pose": state["pose"], "pose_source": source, "robot": robot.name,
             "state": str(path), "offsets_m": {c: float(offset[k])
                                               for k, c in enumerate(w.cables)},
             "model_m": [float(x) for x in model], "reading_m": [float(x) for x in reading]})
    return 0


__all__ = ["DEFAULT_STATE", "FORMAT", "check_readings", "dumps_state", "mark_lost",
           "parse_pose", "read_state", "require_reference", "run_reference",
           "state_path", "write_state"]
