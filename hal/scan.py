"""Who is on the CAN bus: node scan, identities, other masters, bus load.

Read-only helpers for commissioning, outside any control cycle (they block):

- :func:`probe_nodes` finds the CANopen nodes that answer an SDO upload of the device type
  (0x1000) or send a heartbeat / boot-up within a listening window (a node in NMT STOPPED
  answers no SDO but still sends its heartbeat);
- :func:`read_identity` reads device type 0x1000 and the identity object 0x1018 (vendor id,
  product code, revision, serial number) of one node by SDO;
- :func:`scan_nodes` does both for every node id;
- :class:`BusActivity` listens to every frame for a window and tells which of them only a
  master sends (SYNC, NMT commands, TIME, RPDOs or SDO requests to given nodes, heartbeats
  of given master node ids): :func:`other_master_activity` is the "is another master
  active?" check of the commands that can move a winch;
- :class:`FrameCounter` counts frames and their bits (:func:`hal.bus_load.frame_bits`) for
  the bus load of a monitor.

Frames this process sends itself are never received back on python-can buses, so whatever
:class:`BusActivity` hears comes from someone else.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import can
import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hal.bus_load import frame_bits

NMT_STATE_NAMES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL",
                   0x7F: "PRE-OPERATIONAL"}
SYNC_COB = 0x080
TIME_COB = 0x100
#: default COB-IDs of RPDO 1..4 of a node: 0x200/0x300/0x400/0x500 + node id
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)


class ScanError(RuntimeError):
    """The bus could not be scanned (the message says why)."""


@dataclass(frozen=True)
class NodeIdentity:
    """What one node says about itself (None: not read / not answered)."""

    node_id: int
    device_type: int | None = None
    vendor_id: int | None = None
    product_code: int | None = None
    revision: int | None = None
    serial: int | None = None
    nmt_state: str | None = None  #: from a heartbeat seen while listening
    answered_sdo: bool = False
    error: str = ""  #: why an object could not be read

    def as_dict(self) -> dict:
        return {"node_id": self.node_id, "device_type": self.device_type,
                "vendor_id": self.vendor_id, "product_code": self.product_code,
                "revision": self.revision, "serial": self.serial, "nmt_state": self.nmt_state,
                "answered_sdo": self.answered_sdo, "error": self.error}


def probe_nodes(network: canopen.Network, node_ids: Iterable[int] = range(1, 128),
                window_s: float = 0.3) -> dict[int, tuple[bool, str | None]]:
    """Node ids heard within ``window_s``: {node id: (answered the SDO probe, NMT state)}.

    Sends one SDO upload request of 0x1000:00 to every id (as canopen's NodeScanner does)
    and listens to SDO responses (0x580 + id) and heartbeats / boot-ups (0x700 + id).
    """
    ids = [int(i) for i in node_ids]
    for nid in ids:
        if not 1 <= nid <= 127:
            raise ValueError(f"node id {nid} is not in 1..127")
    heard: dict[int, list] = {}
    lock = threading.Lock()

    def sdo_cb(can_id: int, data: bytearray, timestamp: float) -> None:
        nid = can_id - 0x580
        with lock:
            heard.setdefault(nid, [False, None])[0] = True

    def hb_cb(can_id: int, data: bytearray, timestamp: float) -> None:
        if not data:
            return
        nid = can_id - 0x700
        with lock:
            heard.setdefault(nid, [False, None])[1] = NMT_STATE_NAMES.get(
                data[0] & 0x7F, f"0x{data[0] & 0x7F:02X}")

    subs = [(0x580 + nid, sdo_cb) for nid in ids] + [(0x700 + nid, hb_cb) for nid in ids]
    for cob, cb in subs:
        network.subscribe(cob, cb)
    try:
        request = b"\x40\x00\x10\x00\x00\x00\x00\x00"  # SDO initiate upload 0x1000:00
        for nid in ids:
            try:
                network.send_message(0x600 + nid, request)
            except (can.CanError, OSError) as exc:
                raise ScanError(f"cannot send on the bus: {exc}") from exc
        time.sleep(window_s)
    finally:
        for cob, cb in subs:
            network.unsubscribe(cob, cb)
    with lock:
        return {nid: (bool(v[0]), v[1]) for nid, v in sorted(heard.items())}


def _upload_u32(node: canopen.RemoteNode, index: int, sub: int) -> int:
    data = node.sdo.upload(index, sub)
    return int.from_bytes(bytes(data[:4]).ljust(4, b"\0"), "little")


def read_identity(network: canopen.Network, node_id: int, nmt_state: str | None = None,
                  timeout_s: float = 0.3) -> NodeIdentity:
    """Device type and identity object (0x1018 sub 1..4) of ``node_id`` by SDO.

    Objects the node does not have (an SDO abort) stay None with the reason in ``error``;
    a node that does not answer gives ``answered_sdo=False``.
    """
    node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = timeout_s
    node.sdo.MAX_RETRIES = 1  # canopen: the number of attempts
    network.add_node(node)
    values: dict[str, int | None] = {}
    errors: list[str] = []
    answered = False
    try:
        for key, index, sub in (("device_type", 0x1000, 0), ("vendor_id", 0x1018, 1),
                                ("product_code", 0x1018, 2), ("revision", 0x1018, 3),
                                ("serial", 0x1018, 4)):
            try:
                values[key] = _upload_u32(node, index, sub)
                answered = True
            except SdoAbortedError as exc:
                answered = True
                values[key] = None
                errors.append(f"0x{index:04X}:{sub:02X}: SDO abort 0x{exc.code:08X}")
            except SdoCommunicationError as exc:
                values[key] = None
                errors.append(f"0x{index:04X}:{sub:02X}: no SDO answer ({exc})")
                if not answered:
                    break  # silent node: do not wait for every object
    finally:
        del network[node_id]
    return NodeIdentity(node_id, nmt_state=nmt_state, answered_sdo=answered,
                        error="; ".join(errors), **values)


def scan_nodes(network: canopen.Network, node_ids: Iterable[int] = range(1, 128),
               window_s: float = 0.3, timeout_s: float = 0.3) -> list[NodeIdentity]:
    """Every node heard by :func:`probe_nodes`, with its identity, in node id order."""
    found = probe_nodes(network, node_ids, window_s)
    out = []
    for nid, (sdo, state) in found.items():
        if sdo:
            out.append(read_identity(network, nid, state, timeout_s))
        else:
            out.append(NodeIdentity(nid, nmt_state=state,
                                    error="no SDO answer (heartbeat only: NMT STOPPED?)"))
    return out


# ---------------------------------------------------------------------------- other masters


@dataclass
class BusActivity(can.Listener):
    """Classifies the frames heard: what only a master sends (see the module docstring).

    ``drive_ids``: nodes whose RPDOs and SDO requests count as another master's;
    ``master_ids``: node ids whose heartbeat is a master's; ``sync_cob``: the SYNC COB-ID.
    """

    drive_ids: tuple[int, ...] = ()
    master_ids: tuple[int, ...] = ()
    sync_cob: int = SYNC_COB
    counts: Counter = field(default_factory=Counter)
    frames: int = 0

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._kinds: dict[int, str] = {0x000: "NMT command (0x000)",
                                       self.sync_cob: f"SYNC (0x{self.sync_cob:03X})",
                                       TIME_COB: "TIME (0x100)"}
        for nid in self.drive_ids:
            for i, base in enumerate(RPDO_BASES):
                self._kinds[base + nid] = f"RPDO{i + 1} to node {nid} (0x{base + nid:03X})"
            self._kinds[0x600 + nid] = f"SDO request to node {nid} (0x{0x600 + nid:03X})"
        for nid in self.master_ids:
            self._kinds[0x700 + nid] = f"heartbeat of master node {nid} (0x{0x700 + nid:03X})"

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_extended_id:
            return
        kind = self._kinds.get(msg.arbitration_id)
        with self._lock:
            self.frames += 1
            if kind is not None:
                self.counts[kind] += 1

    def master_frames(self) -> list[str]:
        """"KIND x COUNT" of the master-only frames heard, most frequent first."""
        with self._lock:
            return [f"{kind} x{n}" for kind, n in self.counts.most_common()]


def other_master_activity(network: canopen.Network, window_s: float,
                          drive_ids: Iterable[int] = (), master_ids: Iterable[int] = (),
                          sync_cob: int = SYNC_COB) -> list[str]:
    """Listen ``window_s`` seconds; the master-only frames someone else sent (empty: none).

    ``network`` must be connected (its notifier delivers the frames).
    """
    act = BusActivity(tuple(int(i) for i in drive_ids), tuple(int(i) for i in master_ids),
                      sync_cob)
    notifier = network.notifier
    if notifier is None:
        raise ScanError("the CANopen network is not connected")
    notifier.add_listener(act)
    try:
        time.sleep(window_s)
    finally:
        notifier.remove_listener(act)
    return act.master_frames()


# ---------------------------------------------------------------------------- bus load


class FrameCounter(can.Listener):
    """Counts frames and their worst-case bits, for the bus load over a sliding window.

    Frames this process sends are not received back: pass them to :meth:`count` yourself
    (e.g. from a wrapped ``bus.send``).
    """

    def __init__(self, window_s: float = 1.0) -> None:
        self.window_s = float(window_s)
        self._lock = threading.Lock()
        self._events: deque[tuple[float, int]] = deque()
        self.frames = 0
        self.error_frames = 0

    def count(self, msg: can.Message, t: float | None = None) -> None:
        if msg.is_error_frame:
            with self._lock:
                self.error_frames += 1
            return
        bits = frame_bits(min(msg.dlc, 8), msg.is_extended_id)
        now = time.monotonic() if t is None else t
        with self._lock:
            self.frames += 1
            self._events.append((now, bits))

    def on_message_received(self, msg: can.Message) -> None:
        self.count(msg)

    def load(self, bitrate: int, now: float | None = None) -> float:
        """Bus load (0..1) over the last ``window_s`` seconds at ``bitrate`` [bit/s]."""
        t = time.monotonic() if now is None else now
        with self._lock:
            while self._events and self._events[0][0] < t - self.window_s:
                self._events.popleft()
            bits = sum(b for _, b in self._events)
        return bits / (bitrate * self.window_s)


__all__ = ["BusActivity", "FrameCounter", "NodeIdentity", "ScanError", "other_master_activity",
           "probe_nodes", "read_identity", "scan_nodes"]
