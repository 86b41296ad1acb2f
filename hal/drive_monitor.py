"""Watch the winch drives without driving them: SDO polls, heartbeats and EMCYs.

:class:`DriveMonitor` is read-only: it never sends NMT, SYNC or PDOs, so it can run beside
the controller (the HAL) or on an idle bus. Per :meth:`DriveMonitor.poll` it reads by SDO
the statusword 0x6041, position 0x6064, velocity 0x606C, torque 0x6077 (and current
0x6078 when the EDS has it) of every drive, and 0x603F when a drive is in Fault; in the
background it notes each drive's heartbeat (NMT state and age) and every EMCY (the last
errors). A drive that does not answer is reported as such, with its node id and cable;
it is skipped for ``skip_s`` seconds so that one dead node does not slow the others down.

Units as the HAL's: lengths [m] through the winch parameters, velocities [m/s] (positive:
paying out), torque and current in per mille of the rated value, as the drive reports.
Blocking (SDO), outside any control cycle.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import canopen

from controller.winch import WinchSet
from hal.drives_cia402 import DriveState, decode_states, emcy_text
from hal.drives_config import DriveConfigError, sdo_read
from hal.event_log import FAULT, NMT, WARNING, SeverityLog, emcy_severity
from hal.scan import NMT_STATE_NAMES


@dataclass(frozen=True)
class DriveSample:
    """One drive as last read (None where unknown)."""

    node_id: int
    cable: str
    t: float  #: time.monotonic() of the read [s]
    answered: bool
    state: str  #: CiA 402 state name, "UNKNOWN" without an answer
    statusword: int | None = None
    position_counts: int | None = None
    length_m: float | None = None
    velocity_m_s: float | None = None
    torque_permille: int | None = None
    current_permille: int | None = None
    error_code: int = 0  #: 0x603F while in Fault
    nmt_state: str | None = None  #: from the last heartbeat
    heartbeat_age_s: float | None = None
    error: str = ""

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class MonitorEvent:
    """An EMCY, a boot-up (node reset) or a drive that stopped answering, with the wall
    time it was seen and its severity (:mod:`hal.event_log`: fault, nmt, warning)."""

    wall_time: float
    node_id: int
    cable: str
    code: int
    text: str
    severity: str = WARNING
    #: ``emcy``, ``boot_up``, ``sdo_lost`` (stopped answering), ``sdo_resumed``
    kind: str = "emcy"

    def __str__(self) -> str:
        stamp = time.strftime("%H:%M:%S", time.localtime(self.wall_time))
        return (f"{stamp} node {self.node_id} (cable {self.cable}) 0x{self.code:04X} "
                f"{self.severity}: {self.text}")

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class DriveMonitor:
    """Read-only view of the drives of ``winches`` (see the module docstring)."""

    def __init__(self, network: canopen.Network, winches: WinchSet, eds: str | Path,
                 sdo_timeout_s: float = 0.2, skip_s: float = 2.0, max_events: int = 50) -> None:
        self.network = network
        self.winches = winches
        self.skip_s = skip_s
        self.nodes: list[canopen.RemoteNode] = []
        self._lock = threading.Lock()
        self._hb: dict[int, tuple[int, float]] = {}
        self._skip_until = [0.0] * len(winches)
        self._answered = [True] * len(winches)
        #: kept by severity, ``max_events`` of each: warnings never evict faults
        self.events = SeverityLog(max_events)
        self._subs = []
        for k, nid in enumerate(int(x) for x in winches.node_id):
            node = canopen.RemoteNode(nid, canopen.import_od(str(eds), nid))
            node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            node.sdo.MAX_RETRIES = 1  # canopen: the number of attempts
            network.add_node(node)
            node.emcy.add_callback(self._emcy_cb(k))
            self.nodes.append(node)
            cb = self._hb_cb(nid)
            network.subscribe(0x700 + nid, cb)
            self._subs.append((0x700 + nid, cb))
        self.has_current = 0x6078 in self.nodes[0].object_dictionary if self.nodes else False

    def _hb_cb(self, nid: int):
        def cb(can_id: int, data: bytearray, timestamp: float) -> None:
            if data:
                with self._lock:
                    self._hb[nid] = (data[0] & 0x7F, time.monotonic())
                if data[0] & 0x7F == 0:
                    k = [int(x) for x in self.winches.node_id].index(nid)
                    self._event(k, 0, "boot-up: the node was reset or powered on (its "
                                "configuration is the stored one)", NMT, "boot_up")
        return cb

    def _emcy_cb(self, k: int):
        def cb(err: canopen.emcy.EmcyError) -> None:
            code = int(err.code)
            text = emcy_text(code) if code else "error reset / no error"
            self._event(k, code, f"EMCY: {text} (error register 0x{int(err.register):02X})",
                        emcy_severity(code))
        return cb

    def _event(self, k: int, code: int, text: str, severity: str = WARNING,
               kind: str = "emcy") -> None:
        self.events.append(MonitorEvent(time.time(), int(self.winches.node_id[k]),
                                        self.winches.cables[k], code, text, severity, kind))

    def close(self) -> None:
        for cob, cb in self._subs:
            self.network.unsubscribe(cob, cb)
        self._subs = []
        for node in self.nodes:
            if node.id in self.network:
                del self.network[node.id]

    def last_events(self, n: int = 5) -> list[MonitorEvent]:
        """The last ``n`` events, faults and boot-ups first kept (a warning flood does not
        hide them): the newest faults/boot-ups, then the newest warnings, in time order."""
        serious = self.events.items(FAULT) + self.events.items(NMT)
        serious.sort(key=lambda e: e.wall_time)
        serious = serious[-n:]
        warn = self.events.items(WARNING)[-(n - len(serious)):] if n > len(serious) else []
        return sorted(serious + warn, key=lambda e: e.wall_time)

    def poll(self) -> list[DriveSample]:
        """One SDO read of every drive (skipping, for a while, those that did not answer)."""
        return [self._poll_one(k) for k in range(len(self.nodes))]

    def _poll_one(self, k: int) -> DriveSample:
        node = self.nodes[k]
        nid, cable = node.id, self.winches.cables[k]
        who = f"node {nid} (cable {cable})"
        now = time.monotonic()
        with self._lock:
            hb = self._hb.get(nid)
        nmt = NMT_STATE_NAMES.get(hb[0], f"0x{hb[0]:02X}") if hb else None
        hb_age = now - hb[1] if hb else None
        base = dict(node_id=nid, cable=cable, nmt_state=nmt, heartbeat_age_s=hb_age)
        if now < self._skip_until[k]:
            return DriveSample(t=now, answered=False, state="UNKNOWN",
                               error="no SDO answer (retrying soon)", **base)
        try:
            sw = int(sdo_read(node, 0x6041, 0, who))
            pos = int(sdo_read(node, 0x6064, 0, who))
            vel = int(sdo_read(node, 0x606C, 0, who))
            torque = int(sdo_read(node, 0x6077, 0, who))
            current = int(sdo_read(node, 0x6078, 0, who)) if self.has_current else None
            state = DriveState(int(decode_states([sw])[0]))
            code = int(sdo_read(node, 0x603F, 0, who)) if state in (
                DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE) else 0
        except DriveConfigError as exc:
            if self._answered[k]:
                self._event(k, 0, f"stopped answering SDO: {exc}", FAULT, "sdo_lost")
            self._answered[k] = False
            self._skip_until[k] = now + self.skip_s
            return DriveSample(t=now, answered=False, state="UNKNOWN",
                               error=str(exc).removeprefix(f"{who}: "), **base)
        if not self._answered[k]:
            self._event(k, 0, "answers SDO again", WARNING, "sdo_resumed")
        self._answered[k] = True
        ax = self.winches.axis(k)
        return DriveSample(
            t=now, answered=True, state=state.name, statusword=sw, position_counts=pos,
            length_m=ax.counts_to_m(pos),
            velocity_m_s=ax.direction * vel * ax.metres_per_count,
            torque_permille=torque, current_permille=current, error_code=code, **base)


__all__ = ["DriveMonitor", "DriveSample", "MonitorEvent"]
