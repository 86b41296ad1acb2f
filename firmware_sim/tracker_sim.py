"""The simulated laser tracker: the plant's pose plus the scenario's tracker noise.

:class:`SimTracker` measures a pose source (``source() -> (t_s, pose)``, e.g. the rig's
plant time and rest pose) and adds independent Gaussian noise per sample: ``noise_m`` [m]
on x, y, z and ``noise_rad`` [rad] on roll, pitch, yaw (``Noise.tracker_m`` and
``Noise.tracker_rad`` of the scenario), from ``numpy.random.default_rng(seed)``. Given the
scenario's ``truth``, it also carries the tracker's own errors (``[truth.tracker_frame]``,
``[truth.tracker_latency]``: :class:`TrackerView`), as the campaigns' tracker does. It is a
plain callable for in-process use (``measure()`` -> ``(t_s, pose, valid)``), and
:class:`TrackerServer` serves it over TCP. A test hook makes it lose the target:
``lose_target()`` / ``regain_target()`` (or ``valid = False``); then measurements carry
``valid = False`` and a NaN pose, as a real tracker's do while the beam is broken.

Wire protocol ``cdpr-tracker/1`` (the contract with :mod:`hal.tracker`: firmware_sim does
not import hal, nor hal firmware_sim). ASCII lines ending in ``\\n`` over TCP:

- on connect the server sends one greeting line::

      CDPR-TRACKER/1.1 rate_hz=200 frame=F_b units=m,rad clock=drives

  (version 1.1; ``clock``: whose clock ``t_s`` is on, ``drives`` (the drives' clock: the
  rig's plant time on the SYNC clock) or ``own`` (the tracker's own; a client estimates
  the offset); a server not told its clock greets as version 1,
  ``CDPR-TRACKER/1 rate_hz=200 frame=F_b units=m,rad``, and fixes are timed by arrival)

- the client subscribes by sending ``SUBSCRIBE``; from then on the server sends one
  measurement line per period (``rate_hz`` on the wall clock, the same measurement to
  every subscriber)::

      P <seq> <t_s> <x> <y> <z> <roll> <pitch> <yaw> <valid>

  ``seq``: measurement counter (int, from 1, shared by all clients, so a client sees gaps
  if it subscribes late); ``t_s``: the measurement's time on the source's clock (the
  plant's time: drive time with the sync clock) [s]; the pose in F_b [m, rad] as in
  cdpr-conventions.md (``nan`` when not valid); ``valid``: ``1`` or ``0``.
- other commands: ``UNSUBSCRIBE`` (stop the stream), ``PING`` (answer ``PONG``),
  ``QUIT`` (the server closes the connection); anything else is answered
  ``ERR unknown command: ...``. Lines longer than 1 kB close the connection.
- A client that does not keep up (its socket blocks for more than 1 s) is dropped.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from collections.abc import Callable

import numpy as np

from controller.effects import base_to_tracker, tracker_error
from controller.pose import rotvec_matrix
from controller.robot import Robot

log = logging.getLogger(__name__)

PROTOCOL = "CDPR-TRACKER/1"
#: the version a server that says its clock greets with (1.1: the greeting's ``clock``)
PROTOCOL_CLOCK = "CDPR-TRACKER/1.1"
#: the greeting's ``clock`` values (1.1): ``t_s`` on the drives' clock, or on the tracker's
CLOCKS = ("drives", "own")
DEFAULT_RATE_HZ = 200.0
_MAX_LINE = 1024


class TrackerView:
    """What a tracker with the errors of ``truth`` (its ``tracker_frame`` and
    ``tracker_latency``, :mod:`controller.effects`) reads of the platform: the pose the
    platform had ``tracker_latency`` [s] before the time stamp (linear between the poses
    it was shown, :meth:`read`), through the tracker's frame
    (:func:`controller.effects.base_to_tracker`). Without errors it reads the pose as it is.
    Times must not go back."""

    #: [s] poses older than this beyond the latency are forgotten
    KEEP_S = 5.0

    def __init__(self, truth: Robot) -> None:
        self.truth = truth
        self.latency = float(truth.tracker_latency)
        self._t: list[float] = []
        self._p: list[np.ndarray] = []

    def read(self, t: float, pose: np.ndarray) -> np.ndarray:
        """The pose (6,) [m, rad] the tracker reads at time ``t`` [s] when the platform is at
        ``pose`` (6,) in F_b then."""
        pose = np.asarray(pose, dtype=float)
        if self.latency != 0.0:
            self._t.append(float(t))
            self._p.append(pose.copy())
            while len(self._t) > 2 and self._t[1] < t - abs(self.latency) - self.KEEP_S:
                del self._t[0], self._p[0]
            ts = np.array(self._t)
            ps = np.array(self._p)
            at = float(t) - self.latency
            pose = np.array([np.interp(at, ts, ps[:, k]) for k in range(6)])
        return base_to_tracker(self.truth, pose)

    def points(self, points: np.ndarray) -> np.ndarray:
        """Fixed points (..., 3) in F_b (exit points) as the tracker reads them."""
        f = self.truth.tracker_frame
        return (np.asarray(points, dtype=float) - f[3:]) @ rotvec_matrix(f[:3])

    @property
    def exact(self) -> bool:
        """Whether the tracker reads F_b at the drives' times (no frame, no latency)."""
        return not tracker_error(self.truth)


class SimTracker:
    """Measures ``source() -> (t_s, pose (6,))`` with Gaussian noise (see the module
    docstring). Thread-safe; ``measure()`` (also ``tracker()``) returns
    ``(t_s, pose (6,), valid)``."""

    def __init__(self, source: Callable[[], tuple[float, np.ndarray]], noise_m: float = 0.0,
                 noise_rad: float = 0.0, seed: int = 0, truth: Robot | None = None) -> None:
        if not (noise_m >= 0 and noise_rad >= 0):
            raise ValueError(f"tracker noise must be >= 0, got {noise_m} m, {noise_rad} rad")
        self.source = source
        #: the tracker's own errors (frame, latency) of the scenario's truth; None: none
        self.view = TrackerView(truth) if truth is not None and tracker_error(truth) else None
        self.noise_m = float(noise_m)
        self.noise_rad = float(noise_rad)
        self._sigma = np.array([noise_m] * 3 + [noise_rad] * 3, dtype=float)
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self.valid = True  #: False: the target is lost (test hook)
        self.count = 0  #: measurements taken

    def lose_target(self) -> None:
        """From now on, measurements are invalid (the beam lost the reflector)."""
        self.valid = False

    def regain_target(self) -> None:
        """Measurements are valid again."""
        self.valid = True

    def measure(self) -> tuple[float, np.ndarray, bool]:
        """One measurement: ``(t_s, pose (6,) [m, rad] in F_b, valid)``; NaN pose if not
        valid."""
        t, pose = self.source()
        with self._lock:
            self.count += 1
            noise = self._rng.standard_normal(6) * self._sigma
            valid = bool(self.valid)
        if not valid:
            return float(t), np.full(6, np.nan), False
        if self.view is not None:
            pose = self.view.read(float(t), pose)
        return float(t), np.asarray(pose, dtype=float) + noise, True

    __call__ = measure


def format_measurement(seq: int, t_s: float, pose: np.ndarray, valid: bool) -> bytes:
    """One ``P`` line of the protocol."""
    vals = " ".join("nan" if not math.isfinite(v) else f"{v:.10g}" for v in map(float, pose))
    return f"P {seq} {t_s:.6f} {vals} {1 if valid else 0}\n".encode("ascii")


class _Client:
    def __init__(self, sock: socket.socket, addr: tuple) -> None:
        self.sock = sock
        self.addr = addr
        self.subscribed = False
        self.lock = threading.Lock()  # one writer at a time (stream vs answers)
        self.alive = True

    def send(self, data: bytes) -> bool:
        with self.lock:
            if not self.alive:
                return False
            try:
                self.sock.sendall(data)
                return True
            except OSError:
                self.alive = False
                return False

    def close(self) -> None:
        self.alive = False
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


class TrackerServer:
    """Serves a :class:`SimTracker` (or any ``() -> (t_s, pose, valid)``) over TCP with
    the ``cdpr-tracker/1`` protocol (module docstring) at ``rate_hz`` measurements per
    second. ``port`` 0 takes any free port; :attr:`address`, :attr:`spec`
    (``tcp:HOST:PORT``, the HAL's ``--tracker`` form). ``clock`` (:data:`CLOCKS`): whose
    clock the time stamps are on, said in a version 1.1 greeting; None: a version 1
    greeting, which does not say."""

    def __init__(self, tracker: Callable[[], tuple[float, np.ndarray, bool]],
                 host: str = "127.0.0.1", port: int = 0,
                 rate_hz: float = DEFAULT_RATE_HZ, clock: str | None = None) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        if clock is not None and clock not in CLOCKS:
            raise ValueError(f"clock must be one of {', '.join(CLOCKS)} or None, got {clock!r}")
        self.clock = clock
        self.tracker = tracker
        self.rate_hz = float(rate_hz)
        self._sock = socket.create_server((host, port), reuse_port=False)
        self._sock.settimeout(0.2)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._clients: list[_Client] = []
        self._clients_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.seq = 0  #: measurements sent so far
        self._started = False

    @property
    def spec(self) -> str:
        host, port = self.address
        return f"tcp:[{host}]:{port}" if ":" in host else f"tcp:{host}:{port}"

    def start(self) -> TrackerServer:
        if self._started:
            return self
        self._started = True
        for target, name in ((self._accept, "tracker-accept"), (self._stream, "tracker-stream")):
            th = threading.Thread(target=target, name=name, daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def close(self) -> None:
        """Stop serving (idempotent): the threads end, every connection is closed."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._sock.close()
        with self._clients_lock:
            clients = list(self._clients)
        for c in clients:
            c.close()
        for th in self._threads:
            th.join(timeout=5.0)

    def __enter__(self) -> TrackerServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def greeting(self) -> str:
        """The greeting line (version 1.1 with ``clock``, else version 1)."""
        head = (f"{PROTOCOL} rate_hz={self.rate_hz:g} frame=F_b units=m,rad" if self.clock is None
                else f"{PROTOCOL_CLOCK} rate_hz={self.rate_hz:g} frame=F_b units=m,rad "
                     f"clock={self.clock}")
        return head + "\n"

    @property
    def n_clients(self) -> int:
        with self._clients_lock:
            return sum(c.alive for c in self._clients)

    def drop_clients(self) -> None:
        """Close every connection (test hook: the clients must reconnect)."""
        with self._clients_lock:
            clients, self._clients = list(self._clients), []
        for c in clients:
            c.close()

    # ------------------------------------------------------------------ threads

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                sock, addr = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            sock.settimeout(1.0)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, addr)
            greeting = self.greeting()
            if not client.send(greeting.encode("ascii")):
                client.close()
                continue
            with self._clients_lock:
                self._clients.append(client)
            th = threading.Thread(target=self._serve, args=(client,), name="tracker-client",
                                  daemon=True)
            th.start()
            self._threads.append(th)

    def _serve(self, c: _Client) -> None:
        buf = b""
        try:
            while c.alive and not self._stop.is_set():
                try:
                    data = c.sock.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    break
                if not data:
                    break
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    if not self._command(c, line.decode("ascii", "replace").strip()):
                        return
                if len(buf) > _MAX_LINE:
                    c.send(b"ERR line too long\n")
                    break
        finally:
            c.close()
            with self._clients_lock:
                if c in self._clients:
                    self._clients.remove(c)

    def _command(self, c: _Client, cmd: str) -> bool:
        word = cmd.split()[0].upper() if cmd.split() else ""
        if word == "SUBSCRIBE":
            c.subscribed = True
        elif word == "UNSUBSCRIBE":
            c.subscribed = False
        elif word == "PING":
            c.send(b"PONG\n")
        elif word == "QUIT":
            return False
        elif word:
            c.send(f"ERR unknown command: {cmd[:60]}\n".encode("ascii", "replace"))
        return True

    def _stream(self) -> None:
        period = 1.0 / self.rate_hz
        nxt = time.monotonic()
        while not self._stop.is_set():
            with self._clients_lock:
                subs = [c for c in self._clients if c.subscribed and c.alive]
            if subs:
                try:
                    t, pose, valid = self.tracker()
                except Exception:  # keep serving; a source error is logged once per burst
                    log.exception("simulated tracker: measurement failed")
                    t, pose, valid = math.nan, np.full(6, np.nan), False
                self.seq += 1
                line = format_measurement(self.seq, t, pose, valid)
                for c in subs:
                    if not c.send(line):
                        c.close()
            nxt += period
            now = time.monotonic()
            if nxt < now - period:  # fell behind (loaded machine): no burst to catch up
                nxt = now
            self._stop.wait(max(0.0, nxt - now))


__all__ = ["CLOCKS", "DEFAULT_RATE_HZ", "PROTOCOL", "PROTOCOL_CLOCK", "SimTracker",
           "TrackerServer", "format_measurement"]
