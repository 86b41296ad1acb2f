"""The Foxglove layout shipped for the recordings and the live view
(``docs/foxglove/cdpr-layout.json``, the ROCASPECT's cables; ``cdpr recording layout``
writes it for another robot's).

The layout is Foxglove's exported layout JSON (``configById``, ``layout``: the tree of
splits), which Foxglove's *Layouts -> Import from file* reads. Its panels:

- ``3D!scene``: the 3D scene (``/scene``, ``/tf``; fixed frame ``world``);
- ``Plot!tensions``: the measured tensions [N] (``/cables/tensions.measured.<cable>``);
- ``Plot!lengths``: the measured lengths [m] (``/cables/lengths.measured.<cable>``);
- ``StateTransitions!states``: the loop's state (``/loop.state``, a dry run) and the drives'
  CiA 402 state numbers (``/drives/state.state.<cable>``, ``cdpr commission monitor``);
- ``Log!events``: the supervisor's and the hardware's events (``/supervisor/log``);
- ``RawMessages!can``: the last raw CAN frame (``/can``).

:func:`topics` lists every topic the layout names (what a test checks against the channels
the recorders write).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.mcap.channels import CAN_TOPIC, LOG_TOPIC

#: where the layout of the ROCASPECT's cables is shipped (relative to the repository)
SHIPPED = Path("docs") / "foxglove" / "cdpr-layout.json"


def _series(path: str, label: str) -> dict[str, Any]:
    return {"value": path, "enabled": True, "timestampMethod": "receiveTime", "label": label}


def _plot(title: str, paths: list[dict[str, Any]]) -> dict[str, Any]:
    return {"title": title, "paths": paths, "showXAxisLabels": True, "showYAxisLabels": True,
            "showLegend": True, "legendDisplay": "floating", "showPlotValuesInLegend": True,
            "isSynced": True, "xAxisVal": "timestamp"}


def _split(first: Any, second: Any, direction: str, percent: float) -> dict[str, Any]:
    return {"first": first, "second": second, "direction": direction,
            "splitPercentage": percent}


def layout(cable_ids: Sequence[str], centre: Sequence[float] = (0.0, 0.0, 0.0)
           ) -> dict[str, Any]:
    """The layout for a robot with ``cable_ids`` whose workspace centre is ``centre`` [m,
    world frame] (the 3D view looks at it)."""
    cx, cy, cz = (float(v) for v in centre)
    config: dict[str, Any] = {
        "3D!scene": {
            "followTf": "world",
            "scene": {"transforms": {"showLabel": False}},
            "cameraState": {"distance": 35.0, "perspective": True, "phi": 55.0,
                            "thetaOffset": 35.0, "targetOffset": [cx, cy, cz],
                            "target": [0.0, 0.0, 0.0], "targetOrientation": [0, 0, 0, 1],
                            "fovy": 45.0, "near": 0.5, "far": 5000.0},
            "topics": {"/scene": {"visible": True}, "/tf": {"visible": True}},
            "layers": {"grid": {"visible": True, "layerId": "foxglove.Grid",
                                "frameId": "world", "size": 30, "divisions": 30,
                                "position": [cx, cy, 0.0], "rotation": [0, 0, 0],
                                "lineWidth": 1, "color": "#248eff80"}},
        },
        "Plot!tensions": _plot("Cable tensions [N]", [
            _series(f"/cables/tensions.measured.{c}", c) for c in cable_ids]),
        "Plot!lengths": _plot("Cable lengths [m]", [
            _series(f"/cables/lengths.measured.{c}", c) for c in cable_ids]),
        "StateTransitions!states": {
            "title": "Loop and drive states",
            "paths": [_series("/loop.state", "loop")] + [
                _series(f"/drives/state.state.{c}", f"drive {c}") for c in cable_ids],
            "isSynced": True},
        "Log!events": {"title": "Events", "topicToRender": LOG_TOPIC, "minLogLevel": 1,
                       "searchTerms": [], "nameFilter": {}},
        "RawMessages!can": {"title": "Raw CAN", "topicPath": CAN_TOPIC, "diffEnabled": False,
                            "diffMethod": "custom", "diffTopicPath": "",
                            "showFullMessageForDiff": False, "expansion": "all"},
    }
    tree = _split(
        "3D!scene",
        _split(_split("Plot!tensions", "Plot!lengths", "column", 50),
               _split("StateTransitions!states",
                      _split("Log!events", "RawMessages!can", "column", 60), "column", 40),
               "row", 55),
        "row", 40)
    return {"configById": config, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": tree}


def robot_layout(robot) -> dict[str, Any]:
    """:func:`layout` of a :class:`controller.robot.Robot`, looking at the middle of its
    cables' exit points (half their mean height)."""
    import numpy as np

    e = np.asarray(robot.exits, float).reshape(-1, 3)
    c = np.r_[e[:, :2].mean(axis=0), e[:, 2].mean() / 2] if len(e) else np.zeros(3)
    return layout(list(robot.cable_ids), [round(float(v), 2) for v in c])


def dumps(lay: dict[str, Any]) -> str:
    """The layout file's text (sorted keys, indented, newline-terminated)."""
    return json.dumps(lay, indent=2, sort_keys=True) + "\n"


_TOPIC = re.compile(r"^(/[A-Za-z0-9_/-]*?)(?:\.|$)")


def topics(lay: dict[str, Any]) -> set[str]:
    """Every topic the layout names: the 3D panel's topics, the topic of every message path
    (``/topic.field...``), the Log panel's and the raw-message panel's topics."""
    out: set[str] = set()

    def walk(node: Any, key: str = "") -> None:
        if isinstance(node, dict):
            if key == "topics":
                out.update(node)
            for k, v in node.items():
                walk(v, k)
        elif isinstance(node, list):
            for v in node:
                walk(v, key)
        elif isinstance(node, str) and key in ("value", "topicPath", "topicToRender"):
            m = _TOPIC.match(node)
            if m:
                out.add(m.group(1))

    walk(lay["configById"])
    return out


def write(path: str | Path, lay: dict[str, Any]) -> Path:
    """Write the layout file ``path`` (its folder created)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(dumps(lay), encoding="utf-8")
    return p
