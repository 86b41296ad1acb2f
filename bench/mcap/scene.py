"""The Foxglove messages of a recording's row: the platform's frame (``/tf``) and the 3D
scene (``/scene``: masts, cables coloured by tension, the platform), protobuf encoded by the
foxglove SDK."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bench.mcap.channels import LOG_TOPIC, log_ns
from bench.recording import POSE_AXES
from controller.robot import Robot


def quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of a rotation matrix ``R`` (3, 3) (Shepperd's method, w >= 0); the
    rotation's convention stays :func:`controller.pose.rotation`'s."""
    m = [[float(v) for v in r] for r in R]
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, s / 4)
    elif m[0][0] >= m[1][1] and m[0][0] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = (s / 4, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    elif m[1][1] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = ((m[0][1] + m[1][0]) / s, s / 4, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4, (m[1][0] - m[0][1]) / s)
    return q if q[3] >= 0 else (-q[0], -q[1], -q[2], -q[3])


class Scene:
    """The Foxglove messages of a row: the platform's frame and the 3D scene (protobuf,
    encoded by the foxglove SDK)."""

    def __init__(self, robot: Robot, columns: list[str]) -> None:
        from foxglove import messages as fm

        self.fm, self.robot = fm, robot
        idx = {c: i for i, c in enumerate(columns)}
        self.meas = [idx.get(f"{a}_meas") for a in POSE_AXES]
        self.des = [idx.get(f"{a}_des") for a in POSE_AXES]
        self.tau = [idx.get(f"tau_{c}") for c in robot.cable_ids]
        ext = np.ptp(robot.anchors, axis=0) if robot.n_cables else np.zeros(3)
        self.size = np.maximum(ext, 0.05)

    def schemas(self) -> dict[str, Any]:
        return {"/tf": self.fm.FrameTransform.get_schema(),
                "/scene": self.fm.SceneUpdate.get_schema(),
                LOG_TOPIC: self.fm.Log.get_schema()}

    def log(self, ev: dict[str, Any]) -> bytes:
        """A supervisor or hardware event (the fields of ``events.csv``) as a
        ``foxglove.Log``: level :func:`log_level`, name ``device address (cable)``, message
        ``kind 0xCODE -> reaction: text`` (and ``ended`` when it ends)."""
        fm = self.fm
        ns = log_ns(ev["t"])
        who = f"{ev['device']} {ev['address']}" + (f" (cable {ev['cable']})" if ev["cable"]
                                                  else "")
        code = f" 0x{ev['code']:04X}" if ev["code"] else ""
        text = (f"{ev['kind']}{code} -> {ev['reaction']}: {ev['text']}"
                + ("" if ev["active"] else " (ended)"))
        return fm.Log(timestamp=fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000),
                      level=getattr(fm.LogLevel, log_level(ev["reaction"], ev["active"])),
                      message=text, name=who,
                      file="", line=0).encode()

    def pose(self, row: np.ndarray) -> np.ndarray | None:
        for cols in (self.meas, self.des):
            if all(i is not None for i in cols):
                p = row[cols]
                if np.isfinite(p).all():
                    return p
        return None

    #: the 3D scene at most this often [s of recording time]; the frame every row
    SCENE_PERIOD_S = 0.1

    def messages(self, row: np.ndarray, first: bool) -> list[tuple[str, bytes]]:
        """``(topic, data)`` of the row (none without a pose): ``/tf`` every row, ``/scene``
        in the first row and then at most every :attr:`SCENE_PERIOD_S` of ``t``."""
        from controller.kinematics import cable_state
        from controller.pose import rotation

        p = self.pose(row)
        if p is None:
            return []
        fm, r = self.fm, self.robot
        ns = log_ns(float(row[0]))  # (unsigned, as the log time)
        stamp = fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)
        qx, qy, qz, qw = quaternion(rotation(p[3:6]))
        q = fm.Quaternion(x=qx, y=qy, z=qz, w=qw)
        tf = fm.FrameTransform(timestamp=stamp, parent_frame_id="world",
                               child_frame_id="platform",
                               translation=fm.Vector3(x=p[0], y=p[1], z=p[2]), rotation=q)
        t = float(row[0])
        last = getattr(self, "_scene_t", None)
        if not first and last is not None and last <= t < last + self.SCENE_PERIOD_S:
            return [("/tf", tf.encode())]
        self._scene_t = t
        st = cable_state(p, r.anchors, r.exits, r.pulley_radius)
        entities = [self._cables(stamp, st, row),
                    fm.SceneEntity(timestamp=stamp, frame_id="world", id="platform",
                                   cubes=[fm.CubePrimitive(
                                       pose=fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2]),
                                                    orientation=q),
                                       size=fm.Vector3(x=self.size[0], y=self.size[1],
                                                       z=self.size[2]),
                                       color=fm.Color(r=0.6, g=0.6, b=0.7, a=0.8))])]
        if first:
            entities.append(self._masts(stamp))
        return [("/tf", tf.encode()), ("/scene", fm.SceneUpdate(entities=entities).encode())]

    def _colour(self, tau: float):
        """Blue at the robot's minimum tension to red at its maximum; grey unmeasured."""
        r = self.robot
        if not math.isfinite(tau):
            return self.fm.Color(r=0.5, g=0.5, b=0.5, a=1.0)
        hi = r.tension_max if math.isfinite(r.tension_max) else max(tau, 1.0)
        s = min(1.0, max(0.0, (tau - r.tension_min) / max(hi - r.tension_min, 1e-9)))
        return self.fm.Color(r=s, g=0.2, b=1.0 - s, a=1.0)

    def _cables(self, stamp, st, row: np.ndarray):
        fm = self.fm
        lines = []
        for k in range(self.robot.n_cables):
            i = self.tau[k]
            tau = float(row[i]) if i is not None else math.nan
            a, b = st.A[k], st.B[k]
            lines.append(fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=0.02,
                points=[fm.Point3(x=a[0], y=a[1], z=a[2]), fm.Point3(x=b[0], y=b[1], z=b[2])],
                color=self._colour(tau)))
        return fm.SceneEntity(timestamp=stamp, frame_id="world", id="cables", lines=lines)

    def _masts(self, stamp):
        fm, r = self.fm, self.robot
        lines = []
        for m in range(len(r.mast_ids)):
            tops = r.exits[r.mast_index == m]
            top = tops[np.argmax(tops[:, 2])] if len(tops) else r.pivots[m]
            o = r.pivots[m]
            lines.append(fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=0.1,
                points=[fm.Point3(x=o[0], y=o[1], z=o[2]),
                        fm.Point3(x=top[0], y=top[1], z=top[2])],
                color=fm.Color(r=0.3, g=0.3, b=0.3, a=1.0)))
        return fm.SceneEntity(timestamp=stamp, frame_id="world", id="masts", lines=lines)


def log_level(reaction: str, active: bool) -> str:
    """The ``foxglove.Log`` level of an event: ``Error`` when it starts a quick stop or
    disables the drives, ``Warning`` when it starts a hold or a substitution, else ``Info``
    (a logged event, the end of a condition, the hardware's own events)."""
    if not active:
        return "Info"
    if reaction in ("quick_stop", "disable"):
        return "Error"
    if reaction in ("hold", "substitute"):
        return "Warning"
    return "Info"
