"""The measured pose of the platform: a laser tracker as the controller sees it.

A :class:`Tracker` gives :class:`TrackerReading` s: the pose of F_p in F_b (``x, y, z,
roll, pitch, yaw`` [m, rad], cdpr-conventions.md) with the measurement's time stamp on
the source's clock and a validity flag. The control loop uses it to initialise (the
measured init pose p0, the paper's Fig. 4d: ``wait_fresh``) and to record the attained
pose each cycle (``read``, which never blocks)::

    tracker = open_tracker("tcp:127.0.0.1:40125")   # or CallableTracker(rig.measure_pose)
    tracker.start(timeout_s=3.0)                     # TrackerError if nothing arrives
    p0 = tracker.wait_fresh(1.0)                     # a measurement newer than the call
    r = tracker.read()                               # the latest; r.valid, r.age_s
    tracker.close()

Implementations:

- :class:`CallableTracker`: in-process, ``fn() -> (t_s, pose, valid)`` (the simulated
  tracker of the in-process rig, ``SimRig.measure_pose``); every read is fresh.
- :class:`TcpTracker`: the ``cdpr-tracker/1`` line protocol over TCP (served by ``cdpr sim``;
  a bridge to a real tracker can serve it too). A background thread receives the stream
  and reconnects when the server comes back; :meth:`TcpTracker.read` says ``valid=False``
  (NaN pose) when the latest measurement is older than ``stale_s`` or nothing arrived.

The protocol (the contract with ``firmware_sim/tracker_sim.py``; hal does not import
firmware_sim, nor firmware_sim hal): ASCII lines over TCP. The server greets with
``CDPR-TRACKER/1 rate_hz=R frame=F_b units=m,rad`` (version 1.1:
``CDPR-TRACKER/1.1 rate_hz=R frame=F_b units=m,rad clock=C``, :func:`parse_greeting`); the
client sends ``SUBSCRIBE``; the server then sends
``P <seq> <t_s> <x> <y> <z> <roll> <pitch> <yaw> <valid>`` per measurement (``valid`` 1/0,
``nan`` pose when invalid). ``UNSUBSCRIBE``, ``PING`` (-> ``PONG``), ``QUIT`` are the other
commands. Whose clock ``t_s`` is on (the greeting's ``clock``, :data:`CLOCKS`): ``drives``,
the clock of the drives the controller commands (:attr:`Tracker.on_hardware_clock`);
``own``, the tracker's own, whose offset to the receiver's clock the client estimates
(:class:`ClockOffset`, :attr:`TrackerReading.taken_age_s`); not said (version 1): a fix is
timed by its arrival.

A real tracker plugs in behind :class:`Tracker`. A driver for a Leica AT960-class
tracker (6-DoF with a T-Mac or T-Frame probe on the platform, through Leica's LMF/emScon
SDK or its TCP interface) would implement:

- ``start``: connect to the tracker controller, check the probe is locked on, select a
  continuous 6-DoF measurement profile at the wanted rate (the AT960 streams up to
  1000 Hz), load the alignment of the tracker's frame to F_b (from the commissioning
  survey of the exit points) and the probe's offset to F_p's origin;
- a receive thread that, per measurement, converts the probe pose (position in mm,
  orientation as a quaternion or rotation matrix in the tracker frame) into F_b and
  F_p's origin and into ``(x, y, z, roll, pitch, yaw)`` with ``R = Rz Ry Rx``; time stamps
  it (the tracker's own time stamp mapped to the controller's clock, or the receive
  time); sets ``valid`` from the measurement status (beam broken, probe out of range or
  turned away, accuracy flags);
- ``read`` / ``wait_fresh`` / ``close`` as :class:`TcpTracker` does (latest value under a
  lock, a condition for fresh ones, stop the stream and disconnect).
Alternatively a small bridge process serves the ``cdpr-tracker/1`` protocol and the
controller keeps using :class:`TcpTracker`.
"""

from __future__ import annotations

import abc
import argparse
import logging
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

PROTOCOL = "CDPR-TRACKER/1"  #: the protocol's name and major version (the greeting's start)
#: the greeting's ``clock`` (version 1.1): ``t_s`` on the drives' clock, or the tracker's own
CLOCKS = ("drives", "own")
_FORMS = "tcp:HOST:PORT or none"


class TrackerError(RuntimeError):
    """The tracker cannot be reached or gives no measurement (the message names it)."""


class TrackerSpecError(ValueError):
    """A ``--tracker`` specification that cannot be parsed."""


@dataclass(frozen=True)
class TrackerReading:
    """One measurement: ``t_s`` its time on the source's clock [s] (NaN if none);
    ``pose`` (6,) F_p in F_b [m, rad] (NaN when not valid); ``valid``; ``age_s`` [s] since
    it was received (first received, when sent again with its time stamp; 0 for an
    in-process tracker, inf if nothing arrived); ``taken_age_s`` [s] since it was taken, on
    the receiver's clock, where the source's clock is its own and the offset is estimated
    (``clock=own``, :class:`ClockOffset`; NaN otherwise)."""

    t_s: float
    pose: np.ndarray
    valid: bool
    age_s: float
    taken_age_s: float = math.nan


def _nothing(age: float = math.inf, t: float = math.nan) -> TrackerReading:
    return TrackerReading(t, np.full(6, np.nan), False, age)


class Tracker(abc.ABC):
    """A source of measured platform poses (see the module docstring)."""

    name = "tracker"
    #: whether ``t_s`` is on the hardware interface's clock (``Readings.t_s``): a
    #: recorder then stamps a fix with it; else (a tracker's own clock) with the time it
    #: was taken where the offset is estimated (``TrackerReading.taken_age_s``), else
    #: with the time it arrived
    on_hardware_clock: bool = False

    def start(self, timeout_s: float = 3.0) -> Tracker:
        """Connect and wait for a first measurement (TrackerError if none within
        ``timeout_s``)."""
        return self

    @abc.abstractmethod
    def read(self) -> TrackerReading:
        """The latest measurement; never blocks."""

    @abc.abstractmethod
    def wait_fresh(self, timeout_s: float) -> TrackerReading:
        """Block until a measurement newer than this call arrives; TrackerError after
        ``timeout_s``."""

    def close(self) -> None:  # noqa: B027 (nothing to release by default)
        """Release the tracker (idempotent)."""

    def __enter__(self) -> Tracker:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


class CallableTracker(Tracker):
    """In-process tracker: ``fn() -> (t_s, pose (6,), valid)`` is called at each read;
    ``on_hardware_clock``: ``fn``'s ``t_s`` is the hardware interface's clock."""

    def __init__(self, fn: Callable[[], tuple[float, np.ndarray, bool]],
                 name: str = "in-process tracker", on_hardware_clock: bool = False) -> None:
        self.fn = fn
        self.name = name
        self.on_hardware_clock = bool(on_hardware_clock)

    def read(self) -> TrackerReading:
        t, pose, valid = self.fn()
        pose = np.asarray(pose, dtype=float).reshape(6)
        valid = bool(valid) and bool(np.isfinite(pose).all())
        return TrackerReading(float(t), pose.copy() if valid else np.full(6, np.nan), valid,
                              0.0)

    def wait_fresh(self, timeout_s: float) -> TrackerReading:
        return self.read()


@dataclass(frozen=True)
class Greeting:
    """A server's greeting: ``version`` (major, minor), its ``key=value`` ``fields``
    (unknown keys kept: a later minor version may add some) and ``clock`` (one of
    :data:`CLOCKS`; None: not said, or a value this client does not know)."""

    version: tuple[int, int]
    fields: dict[str, str]

    @property
    def clock(self) -> str | None:
        c = self.fields.get("clock")
        return c if c in CLOCKS else None


def parse_greeting(line: str) -> Greeting | None:
    """The greeting ``CDPR-TRACKER/1[.N] key=value ...``, or None when it is not one of
    this protocol (another name or major version)."""
    head, *rest = line.split() or [""]
    name, sep, ver = head.partition("/")
    major, _, minor = ver.partition(".")
    if f"{name}{sep}{major}" != PROTOCOL or not (minor.isdigit() or minor == ""):
        return None
    fields = dict(kv.split("=", 1) for kv in rest if "=" in kv)
    return Greeting((int(major), int(minor or 0)), fields)


class ClockOffset:
    """The offset [s] of a source's own clock to the receiver's, from the fixes' time stamps
    ``t_s`` and their arrival times ``rx`` [s]: ``rx - t_s`` is the offset plus the fix's
    delay (>= 0), so its minimum over the last :attr:`WINDOW_S` is the offset plus the
    shortest delay seen (the minimum-delay filter of clock synchronisation): fixes placed
    with it are late by no more than their own delay, early never but by the clocks' drift
    over the window (a source clock slower than the receiver's: <= 1 ms, :attr:`WINDOW_S`)."""

    #: [s] a quartz clock drifts up to ~100 ppm: over 10 s the offset moves by <= 1 ms, a
    #: quarter of a 256 Hz control period
    WINDOW_S = 10.0

    def __init__(self) -> None:
        self._seen: deque[tuple[float, float]] = deque()  # (rx, rx - t_s), rising in the 2nd

    def add(self, t_s: float, rx: float) -> None:
        """A fix taken at ``t_s`` (source's clock) received at ``rx`` (receiver's) [s]."""
        d = rx - t_s
        while self._seen and self._seen[-1][1] >= d:
            self._seen.pop()
        self._seen.append((rx, d))
        while self._seen[0][0] < rx - self.WINDOW_S:
            self._seen.popleft()

    @property
    def offset_s(self) -> float:
        """The receiver's clock less the source's [s] (NaN before a fix)."""
        return self._seen[0][1] if self._seen else math.nan


def parse_line(line: str) -> tuple[int, float, np.ndarray, bool] | None:
    """``(seq, t_s, pose, valid)`` of a protocol ``P`` line, or None if it is not one."""
    parts = line.split()
    if len(parts) != 10 or parts[0] != "P":
        return None
    try:
        seq = int(parts[1])
        t = float(parts[2])
        pose = np.array([float(x) for x in parts[3:9]])
        valid = parts[9] == "1"
    except ValueError:
        return None
    if parts[9] not in ("0", "1"):
        return None
    if valid and not np.isfinite(pose).all():
        valid = False
    return seq, t, pose, valid


class TcpTracker(Tracker):
    """``cdpr-tracker/1`` client (module docstring). A background thread connects,
    subscribes, keeps the latest measurement and reconnects (every ``retry_s`` [s]) when
    the connection drops. :meth:`read` returns ``valid=False`` with a NaN pose when
    nothing arrived yet or the latest measurement was received more than ``stale_s`` [s]
    ago (``t_s`` and ``age_s`` still say which and how old). The server's greeting says
    whose clock ``t_s`` is on (:attr:`clock`): ``drives`` sets :attr:`on_hardware_clock`;
    ``own`` makes :meth:`read` give ``taken_age_s`` (:class:`ClockOffset`, estimated anew
    on each connection)."""

    def __init__(self, host: str, port: int, stale_s: float = 0.5, retry_s: float = 0.2,
                 connect_timeout_s: float = 2.0) -> None:
        self.host, self.port = host, int(port)
        self.name = f"tracker tcp:{host}:{port}"
        self.stale_s = float(stale_s)
        self.retry_s = float(retry_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self._cond = threading.Condition()
        self._latest: tuple[float, np.ndarray, bool, float] | None = None  # t, pose, ok, rx
        self._received = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self.connected = False
        self.connects = 0  #: connections made so far (1 + reconnects)
        self.bad_lines = 0  #: lines that were not understood
        self.last_error = ""  #: why the last connection failed or ended
        self.clock: str | None = None  #: the server's clock (:data:`CLOCKS`; None: not said)
        self._offset = ClockOffset()

    # ------------------------------------------------------------------ life cycle

    def start(self, timeout_s: float = 3.0) -> TcpTracker:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="tracker-rx", daemon=True)
            self._thread.start()
        try:
            self.wait_fresh(timeout_s)
        except TrackerError:
            self.close()
            raise
        return self

    def close(self) -> None:
        self._stop.set()
        sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        with self._cond:
            self._cond.notify_all()

    # ------------------------------------------------------------------ reading

    @property
    def received(self) -> int:
        """Measurements received so far."""
        with self._cond:
            return self._received

    def read(self) -> TrackerReading:
        with self._cond:  # (the receive thread changes the offset and, on connecting, clock)
            latest = self._latest
            offset = self._offset.offset_s if self.clock == "own" else math.nan
        if latest is None:
            return _nothing()
        t, pose, valid, rx = latest
        now = time.monotonic()
        age = now - rx
        if not valid or age > self.stale_s:
            return _nothing(age, t)
        return TrackerReading(t, pose.copy(), True, age, now - (t + offset))

    def wait_fresh(self, timeout_s: float) -> TrackerReading:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            n0 = self._received
            while self._received == n0:
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set():
                    why = f" ({self.last_error})" if self.last_error else ""
                    raise TrackerError(f"{self.name}: no measurement within {timeout_s:g} s"
                                       f"{why}")
                self._cond.wait(min(left, 0.1))
        return self.read()

    # ------------------------------------------------------------------ thread

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._session()
            except OSError as exc:
                self.last_error = f"{type(exc).__name__}: {exc}"
            except TrackerError as exc:
                self.last_error = str(exc)
            finally:
                self.connected = False
                sock, self._sock = self._sock, None
                if sock is not None:
                    sock.close()
            self._stop.wait(self.retry_s)

    def _session(self) -> None:
        sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        self._sock = sock
        if self._stop.is_set():
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(0.5)
        lines = self._lines(sock)
        greeting = next(lines, None)
        if greeting is None:
            raise TrackerError("connection closed before the greeting")
        hello = parse_greeting(greeting)
        if hello is None:
            raise TrackerError(f"not a {PROTOCOL} server: {greeting[:60]!r}")
        with self._cond:
            self.clock = hello.clock
            self.on_hardware_clock = hello.clock == "drives"
            self._offset = ClockOffset()
        sock.sendall(b"SUBSCRIBE\n")
        self.connected = True
        self.connects += 1
        for line in lines:
            m = parse_line(line)
            if m is None:
                if not line.startswith(("PONG", "ERR")):
                    self.bad_lines += 1
                    if self.bad_lines == 1:
                        log.warning("%s: ignoring a line not in %s: %r", self.name, PROTOCOL,
                                    line[:80])
                continue
            _, t, pose, valid = m
            with self._cond:
                # a measurement sent again (a source that holds its time stamp) keeps the
                # time it first arrived: its age is the measurement's
                again = self._latest is not None and self._latest[0] == t
                rx = self._latest[3] if again else time.monotonic()
                if not again and self.clock == "own" and math.isfinite(t):
                    self._offset.add(t, rx)
                self._latest = (t, pose, valid, rx)
                self._received += 1
                self._cond.notify_all()
        if not self._stop.is_set():
            self.last_error = "connection closed by the server"

    def _lines(self, sock: socket.socket):
        """Non-empty lines received, until the stream ends or the tracker is closed."""
        buf = b""
        while not self._stop.is_set():
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            if not data:
                return
            buf += data
            if b"\n" not in buf:
                if len(buf) > 65536:
                    raise TrackerError("a line longer than 64 kB: not the tracker protocol")
                continue
            *done, buf = buf.split(b"\n")
            for raw in done:
                line = raw.decode("ascii", "replace").strip()
                if line:
                    yield line


# ---------------------------------------------------------------------------- --tracker


@dataclass(frozen=True)
class TrackerSpec:
    """A parsed ``--tracker``: ``kind`` "tcp" or "none", ``host``, ``port``."""

    kind: str
    host: str = ""
    port: int = 0

    def __str__(self) -> str:
        if self.kind == "none":
            return "none"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp:{host}:{self.port}"


def parse_tracker_spec(spec: str) -> TrackerSpec:
    """Parse ``tcp:HOST:PORT`` (IPv6 hosts in brackets) or ``none``."""
    if not isinstance(spec, str) or not spec.strip():
        raise TrackerSpecError(f"--tracker: empty specification; expected {_FORMS}")
    s = spec.strip()
    if s.lower() == "none":
        return TrackerSpec("none")
    kind, sep, rest = s.partition(":")
    if kind != "tcp" or not sep:
        raise TrackerSpecError(f"--tracker {s!r}: expected {_FORMS}")
    if rest.startswith("["):
        close = rest.find("]")
        if close < 0 or not rest[close + 1:].startswith(":"):
            raise TrackerSpecError(f"--tracker {s!r}: expected tcp:[IPv6]:PORT")
        host, port_s = rest[1:close], rest[close + 2:]
    else:
        host, sep, port_s = rest.rpartition(":")
        if not sep:
            raise TrackerSpecError(f"--tracker {s!r}: missing port; expected tcp:HOST:PORT")
    if not host:
        raise TrackerSpecError(f"--tracker {s!r}: missing host; expected tcp:HOST:PORT")
    try:
        port = int(port_s, 10)
    except ValueError:
        raise TrackerSpecError(f"--tracker {s!r}: port {port_s!r} is not a number") from None
    if not 1 <= port <= 65535:
        raise TrackerSpecError(f"--tracker {s!r}: port {port} is not in 1..65535")
    return TrackerSpec("tcp", host, port)


def open_tracker(spec: str | TrackerSpec | None, **options) -> Tracker | None:
    """The tracker of a ``--tracker`` specification (not started), None for ``none``.
    ``options`` go to :class:`TcpTracker` (``stale_s``, ``retry_s``)."""
    if spec is None:
        return None
    s = parse_tracker_spec(spec) if isinstance(spec, str) else spec
    if s.kind == "none":
        return None
    return TcpTracker(s.host, s.port, **options)


def add_tracker_argument(parser: argparse.ArgumentParser, default: str = "none") -> None:
    """Add the shared ``--tracker SPEC`` option (parsed into a :class:`TrackerSpec`)."""

    def _type(text: str) -> TrackerSpec:
        try:
            return parse_tracker_spec(text)
        except TrackerSpecError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parser.add_argument("--tracker", type=_type, default=parse_tracker_spec(default),
                        metavar="SPEC",
                        help=f"laser tracker for the measured pose: {_FORMS} "
                             f"(cdpr sim prints its own) [{default}]")


__all__ = [
    "CLOCKS", "CallableTracker", "ClockOffset", "Greeting", "TcpTracker", "Tracker",
    "TrackerError", "TrackerReading",
    "TrackerSpec", "TrackerSpecError", "add_tracker_argument", "open_tracker",
    "parse_greeting", "parse_line", "parse_tracker_spec",
]
