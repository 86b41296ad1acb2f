"""Fault schedules for the simulated robot: a TOML file, its loader, an injector, a control
channel.

Format (``cdpr sim --faults FILE``; one table per fault)::

    [[fault]]
    at_s = 1.0              # seconds on the sim's clock
    drive = 3               # CAN node id; or cell = 5 (Modbus unit id)
    kind = "over_current"
    clear_s = 3.0           # optional: when the cause goes away

Kinds of a drive (CAN node id ``drive``):

==================  ======================================================  ==============
kind                what happens at ``at_s``                                at ``clear_s``
==================  ======================================================  ==============
``over_current``    EMCY 0x2310, fault reaction, Fault                      cause gone:
                    (with ``clear_s``: a fault reset fails until then)      reset works
``encoder``         EMCY 0x7305, Fault at once (brake); reset fails         repaired
``stuck_brake``     the brake does not release: following error 0x8611      released
                    once motion is demanded
``heartbeat_stop``  the heartbeat producer stops                            beats again
``silent``          off the bus: sends and answers nothing                  back on it
``node_reset``      power cycle: boot-up, pre-operational (no ``clear_s``)  -
``drop_tpdo``       TPDOs lost: ``count`` of them (default 1), or all       sent again
                    until ``clear_s``
``drop_rpdo``       RPDOs lost, the same way                                received again
==================  ======================================================  ==============

Kinds of a load cell (Modbus unit id ``cell``), until ``clear_s`` or for good: ``stale``
(the counter stops, the value freezes), ``nan``, ``timeout`` (no answer), ``exception``
(Modbus exception ``code``, default 0x04), ``out_of_range`` (``value_N``, default 1.2 x
the rated maximum, overload bit), ``sensor_fault`` (status bit).

Optional keys: ``count`` (drop_tpdo, drop_rpdo), ``code`` (exception), ``value_N``
(out_of_range). Any other key, an unknown kind, node or unit, a kind of the wrong device,
``clear_s`` not after ``at_s``, a number outside its physical range
(:mod:`controller.ranges`: times within 1e6 s, ``count`` 1..1e6, ``value_N`` within 1 MN)
is a :class:`FaultScheduleError` naming the file, the line, the field and the range.

Time is the rig's (:meth:`firmware_sim.rig.SimRig.time_s`): the drives' SYNC clock with
``--clock sync``, the wall clock since the start with ``--clock wall``.

:class:`FaultInjector` applies a schedule to a rig: :meth:`~FaultInjector.advance` with the
rig's time (in-process, e.g. a dry run stepping the rig), or :meth:`~FaultInjector.start`
(after every SYNC the rig processes, and from a thread every few milliseconds of wall
time). :class:`FaultControlServer` is the control channel of ``cdpr sim``: a TCP server on
loopback speaking one line per request, one line per answer::

    fault drive=3 kind=over_current [at_s=T] [clear_s=T] [count=N] [code=N] [value_N=X]
        -> ok fault 1 drive 3 over_current at 12.345 s
    clear drive=3 [kind=over_current]    (or cell=5 ..., or: clear all)
        -> ok cleared 1
    time            -> ok 12.345        (the rig's clock [s])
    list            -> ok [{"id": 1, "drive": 3, "kind": "over_current", ...}, ...]
    help            -> ok <the commands>
    anything else   -> error <why>

Values are TOML-like: integers (``0x04`` too), decimals, bare words. Without ``at_s`` a
fault starts now; ``at_s`` and ``clear_s`` are on the rig's clock (absolute).
"""

from __future__ import annotations

import json
import logging
import math
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.ranges import check
from controller.tomlfile import Locator, read_toml

log = logging.getLogger(__name__)

DRIVE_KINDS = ("over_current", "encoder", "stuck_brake", "heartbeat_stop", "silent",
               "node_reset", "drop_tpdo", "drop_rpdo")
CELL_KINDS = ("stale", "nan", "timeout", "exception", "out_of_range", "sensor_fault")
_KEYS = {"at_s", "drive", "cell", "kind", "clear_s", "count", "code", "value_N"}
_CELL_FAULT = {"stale": "stale", "nan": "nan", "timeout": "no_answer", "exception": "exception",
               "out_of_range": "out_of_range", "sensor_fault": "sensor_fault"}
#: Modbus exception codes a simulated cell may answer
EXCEPTION_CODES = (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x0A, 0x0B)


class FaultScheduleError(ValueError):
    """A fault schedule (or control-channel request) that is not valid: names file, line,
    field."""


@dataclass(frozen=True)
class Fault:
    """One scheduled fault. ``device`` "drive" (``address`` = CAN node id) or "cell"
    (Modbus unit id); times on the rig's clock [s]."""

    at_s: float
    device: str
    address: int
    kind: str
    clear_s: float | None = None
    count: int | None = None
    code: int | None = None
    value_N: float | None = None
    where: str = ""  #: "FILE:LINE" it came from

    def describe(self) -> str:
        tail = "" if self.clear_s is None else f" until {self.clear_s:g} s"
        return f"{self.device} {self.address} {self.kind} at {self.at_s:g} s{tail}"

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"at_s": self.at_s, self.device: self.address, "kind": self.kind}
        for key in ("clear_s", "count", "code", "value_N"):
            if getattr(self, key) is not None:
                d[key] = getattr(self, key)
        return d


def _default_ids() -> tuple[tuple[int, ...], tuple[int, ...]]:
    from controller.loadcell_map import DEFAULT_MAP
    from controller.winch import load_winches

    return tuple(int(x) for x in load_winches().node_id), tuple(DEFAULT_MAP.unit_ids)


def _number(value: Any, where: str, key: str, integer: bool = False) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FaultScheduleError(f"{where}: {key} must be a number, got {value!r}")
    if integer and isinstance(value, float) and not value.is_integer():
        raise FaultScheduleError(f"{where}: {key} must be an integer, got {value!r}")
    try:
        finite = math.isfinite(value)
    except OverflowError:  # an integer beyond any float (the control channel reads any size)
        finite = False
    if not finite:
        text = str(value) if len(str(value)) <= 24 else f"a {len(str(value))}-digit integer"
        raise FaultScheduleError(f"{where}: {key} must be finite, got {text}")
    return int(value) if integer else float(value)


def parse_fault(entry: Any, where: str, node_ids: tuple[int, ...],
                unit_ids: tuple[int, ...], line_of=None) -> Fault:
    """One fault from a table (a ``[[fault]]`` of a file or a control-channel request).
    ``where`` names it; ``line_of(key)`` gives a "file:line" for a field (or None)."""

    def at(key: str | None) -> str:
        w = line_of(key) if line_of is not None else None
        return f"{w or where}" + (f": {key}" if key else "")

    if not isinstance(entry, dict):
        raise FaultScheduleError(f"{at(None)}: a fault must be a table")
    for key in entry:
        if key not in _KEYS:
            raise FaultScheduleError(f"{at(key)}: unknown key; known: {', '.join(sorted(_KEYS))}")
    if "at_s" not in entry:
        raise FaultScheduleError(f"{at(None)}: at_s is missing (seconds on the sim's clock)")
    at_s = _number(entry["at_s"], at("at_s"), "value")
    check("fault", "at_s", at_s, at("at_s"), FaultScheduleError)
    if at_s < 0:
        raise FaultScheduleError(f"{at('at_s')}: must be >= 0, got {at_s!r}")
    if ("drive" in entry) == ("cell" in entry):
        raise FaultScheduleError(f"{at(None)}: give drive = CAN node id or cell = Modbus unit "
                                 "id (one of them)")
    device = "drive" if "drive" in entry else "cell"
    address = _number(entry[device], at(device), "value", integer=True)
    known = node_ids if device == "drive" else unit_ids
    if address not in known:
        what = "CAN node id" if device == "drive" else "Modbus unit id"
        raise FaultScheduleError(f"{at(device)}: no {device} with {what} {address} "
                                 f"(known: {', '.join(map(str, known))})")
    kind = entry.get("kind")
    kinds = DRIVE_KINDS if device == "drive" else CELL_KINDS
    if not isinstance(kind, str) or kind not in kinds:
        other = CELL_KINDS if device == "drive" else DRIVE_KINDS
        hint = f" (a kind of a {'cell' if device == 'drive' else 'drive'})" if kind in other else ""
        raise FaultScheduleError(f"{at('kind')}: unknown kind {kind!r} of a {device}{hint}; "
                                 f"known: {', '.join(kinds)}")
    clear_s = None
    if "clear_s" in entry:
        clear_s = _number(entry["clear_s"], at("clear_s"), "value")
        check("fault", "clear_s", clear_s, at("clear_s"), FaultScheduleError)
        if clear_s <= at_s:
            raise FaultScheduleError(f"{at('clear_s')}: {clear_s:g} s must be after at_s "
                                     f"{at_s:g} s")
        if kind == "node_reset":
            raise FaultScheduleError(f"{at('clear_s')}: a node reset is over at once; no clear_s")
    count = code = value_N = None
    if "count" in entry:
        if kind not in ("drop_tpdo", "drop_rpdo"):
            raise FaultScheduleError(f"{at('count')}: only for drop_tpdo, drop_rpdo")
        count = _number(entry["count"], at("count"), "value", integer=True)
        if count < 1:
            raise FaultScheduleError(f"{at('count')}: must be >= 1, got {count}")
        check("fault", "count", count, at("count"), FaultScheduleError)
    if "code" in entry:
        if kind != "exception":
            raise FaultScheduleError(f"{at('code')}: only for exception")
        code = _number(entry["code"], at("code"), "value", integer=True)
        if code not in EXCEPTION_CODES:
            raise FaultScheduleError(f"{at('code')}: {code:#04x} is not a Modbus exception "
                                     f"code ({', '.join(f'{c:#04x}' for c in EXCEPTION_CODES)})")
    if "value_N" in entry:
        if kind != "out_of_range":
            raise FaultScheduleError(f"{at('value_N')}: only for out_of_range")
        value_N = _number(entry["value_N"], at("value_N"), "value")
        check("fault", "value_N", value_N, at("value_N"), FaultScheduleError)
    return Fault(at_s, device, address, kind, clear_s, count, code, value_N,
                 where=line_of(None) if line_of is not None else where)


@dataclass(frozen=True)
class FaultSchedule:
    """The faults of a schedule file, in file order."""

    faults: tuple[Fault, ...]
    source: str = "<memory>"

    @classmethod
    def load(cls, path: str | Path, node_ids: tuple[int, ...] | None = None,
             unit_ids: tuple[int, ...] | None = None) -> FaultSchedule:
        """Read a schedule file; the drives' node ids and the cells' unit ids it may name
        (default: the shipped winch file and register map). FaultScheduleError naming the
        file, line and field."""
        p = Path(path)
        doc, text = read_toml(p, FaultScheduleError)
        return cls.parse(doc, str(p), text, node_ids, unit_ids)

    @classmethod
    def parse(cls, doc: dict[str, Any], source: str = "<memory>", text: str = "",
              node_ids: tuple[int, ...] | None = None,
              unit_ids: tuple[int, ...] | None = None) -> FaultSchedule:
        if node_ids is None or unit_ids is None:
            dn, du = _default_ids()
            node_ids = dn if node_ids is None else tuple(node_ids)
            unit_ids = du if unit_ids is None else tuple(unit_ids)
        unknown = set(doc) - {"fault"}
        if unknown:
            raise FaultScheduleError(f"{source}: unknown top-level key(s) {sorted(unknown)}; "
                                     "a schedule is [[fault]] tables")
        entries = doc.get("fault", [])
        if not isinstance(entries, list):
            raise FaultScheduleError(f"{source}: fault must be [[fault]] tables")
        loc = Locator(text)
        faults = []
        for i, entry in enumerate(entries):

            def line_of(key: str | None, i=i) -> str | None:
                line = loc.line("fault", i, key)
                return f"{source}:{line}" if line else None

            faults.append(parse_fault(entry, f"{source}: [[fault]] #{i + 1}", node_ids,
                                      unit_ids, line_of))
        return cls(tuple(faults), source)


# ---------------------------------------------------------------------------- injector


@dataclass
class _Entry:
    fault: Fault
    id: int
    applied: bool = False
    cleared: bool = False


@dataclass
class InjectionRecord:
    """What the injector did: ``action`` "apply" or "clear", at the rig's ``t_s``."""

    t_s: float
    action: str
    fault: Fault
    id: int


class FaultInjector:
    """Applies faults to a simulated rig on the rig's clock (see the module docstring).

    ``rig`` is a :class:`~firmware_sim.rig.SimRig` (drives in ``rig.bank``, cells behind
    ``rig.server``), or anything with ``bank`` (and ``server`` for cells) and ``time_s()``.
    """

    def __init__(self, rig: Any, schedule: FaultSchedule | None = None) -> None:
        self.rig = rig
        self._lock = threading.RLock()
        self._entries: list[_Entry] = []
        self.log: list[InjectionRecord] = []  #: everything applied and cleared, in order
        self._next_id = 1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._hooked = False
        for f in (schedule.faults if schedule is not None else ()):
            self.add(f)

    # ---- the rig ------------------------------------------------------------------------
    def time_s(self) -> float:
        """The rig's clock [s]."""
        fn = getattr(self.rig, "time_s", None)
        if fn is not None:
            return float(fn())
        with self.rig.bank.lock:
            return self.rig.bank.drives[0].now_us * 1e-6

    def node_ids(self) -> tuple[int, ...]:
        return tuple(d.node_id for d in self.rig.bank.drives)

    def unit_ids(self) -> tuple[int, ...]:
        server = getattr(self.rig, "server", None)
        return tuple(server.register_map.unit_ids) if server is not None else ()

    # ---- schedule -----------------------------------------------------------------------
    def add(self, fault: Fault) -> int:
        """Schedule one more fault; its id."""
        with self._lock:
            e = _Entry(fault, self._next_id)
            self._next_id += 1
            self._entries.append(e)
            return e.id

    def entries(self) -> list[dict[str, Any]]:
        with self._lock:
            return [{"id": e.id, **e.fault.as_dict(), "applied": e.applied,
                     "cleared": e.cleared} for e in self._entries]

    def advance(self, t_s: float | None = None) -> list[InjectionRecord]:
        """Apply what is due at ``t_s`` (default: the rig's clock now); what was done."""
        t = self.time_s() if t_s is None else float(t_s)
        done = []
        with self._lock:
            for e in self._entries:
                f = e.fault
                if not e.applied and f.at_s <= t:
                    self._apply(f)
                    e.applied = True
                    done.append(InjectionRecord(t, "apply", f, e.id))
                    if f.clear_s is None and f.kind == "node_reset":
                        e.cleared = True
                if e.applied and not e.cleared and f.clear_s is not None and f.clear_s <= t:
                    self._clear(f)
                    e.cleared = True
                    done.append(InjectionRecord(t, "clear", f, e.id))
            self.log.extend(done)
        for r in done:
            log.info("fault injector: %s %s (t = %.3f s)", r.action, r.fault.describe(), r.t_s)
        return done

    def clear(self, device: str | None = None, address: int | None = None,
              kind: str | None = None) -> int:
        """Clear applied faults now (all, or of a device/address/kind); how many."""
        n = 0
        t = self.time_s()
        with self._lock:
            for e in self._entries:
                f = e.fault
                if e.cleared or (device and f.device != device) or (
                        address is not None and f.address != address) or (kind and f.kind != kind):
                    continue
                if e.applied:
                    self._clear(f)
                    self.log.append(InjectionRecord(t, "clear", f, e.id))
                e.cleared = e.applied = True
                n += 1
        return n

    def _apply(self, f: Fault) -> None:
        if f.device == "cell":
            params: dict[str, Any] = {}
            if f.kind == "exception":
                params["exception_code"] = f.code if f.code is not None else 0x04
            if f.kind == "out_of_range" and f.value_N is not None:
                params["value_N"] = f.value_N
            self.rig.server.inject(f.address, _CELL_FAULT[f.kind], **params)
            return
        d = self.rig.bank.drive(f.address)
        k = f.kind
        if k == "over_current":
            d.inject_over_current(persist=f.clear_s is not None)
        elif k == "encoder":
            d.inject_encoder_fault()
        elif k == "stuck_brake":
            d.stick_brake(True)
        elif k == "heartbeat_stop":
            d.stop_heartbeat(True)
        elif k == "silent":
            d.set_silent(True)
        elif k == "node_reset":
            d.reset_node()
        elif k in ("drop_tpdo", "drop_rpdo"):
            n = f.count if f.count is not None else (10**12 if f.clear_s is not None else 1)
            (d.drop_tpdos if k == "drop_tpdo" else d.drop_rpdos)(n)

    def _clear(self, f: Fault) -> None:
        if f.device == "cell":
            self.rig.server.clear(f.address, _CELL_FAULT[f.kind])
            return
        d = self.rig.bank.drive(f.address)
        k = f.kind
        if k == "over_current":
            d.clear_over_current()
        elif k == "encoder":
            d.repair_encoder()
        elif k == "stuck_brake":
            d.stick_brake(False)
        elif k == "heartbeat_stop":
            d.stop_heartbeat(False)
        elif k == "silent":
            d.set_silent(False)
        elif k in ("drop_tpdo", "drop_rpdo"):
            d.stop_dropping()

    # ---- running with the rig -----------------------------------------------------------
    def start(self, poll_s: float = 0.005) -> FaultInjector:
        """Advance after every SYNC the drives process and every ``poll_s`` of wall time."""
        if not self._hooked:
            self.rig.bank.add_sync_callback(lambda bank: self.advance())
            self._hooked = True
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, args=(poll_s,), daemon=True,
                                            name="fault-injector")
            self._thread.start()
        return self

    def _run(self, poll_s: float) -> None:
        while not self._stop.wait(poll_s):
            try:
                self.advance()
            except Exception:  # keep injecting the others; the error is logged
                log.exception("fault injector")

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None


# ---------------------------------------------------------------------------- control channel


def _value(text: str) -> Any:
    t = text.strip()
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "\"'":
        return t[1:-1]
    try:
        return int(t, 0)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def parse_request(line: str) -> tuple[str, dict[str, Any]]:
    """``verb key=value ...`` -> (verb, {key: value}); FaultScheduleError if malformed."""
    parts = line.strip().split()
    if not parts:
        raise FaultScheduleError("empty request; try: help")
    verb, args = parts[0].lower(), {}
    for p in parts[1:]:
        key, sep, value = p.partition("=")
        if not sep or not key:
            if verb == "clear" and p == "all":
                continue
            raise FaultScheduleError(f"{p!r}: expected key=value")
        args[key] = _value(value)
    return verb, args


HELP = ("fault drive=N|cell=N kind=K [at_s=T] [clear_s=T] [count=N] [code=N] [value_N=X]; "
        "clear [all|drive=N|cell=N] [kind=K]; time; list; help")


class FaultControlServer:
    """The control channel (see the module docstring): one line per request on loopback."""

    def __init__(self, injector: FaultInjector, host: str = "127.0.0.1", port: int = 0) -> None:
        self.injector = injector
        self._server = socket.create_server((host, port))
        self._server.settimeout(0.2)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._server.getsockname()[:2]
        return host, port

    @property
    def endpoint(self) -> str:
        host, port = self.address
        return f"{host}:{port}"

    def start(self) -> FaultControlServer:
        th = threading.Thread(target=self._accept, name="fault-control", daemon=True)
        th.start()
        self._threads.append(th)
        return self

    def close(self) -> None:
        self._stop.set()
        try:
            self._server.close()
        except OSError:
            pass
        with self._lock:
            for c in self._clients:
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                c.close()
        for th in self._threads:
            th.join(timeout=2.0)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.settimeout(None)
            with self._lock:
                self._clients.append(conn)
            th = threading.Thread(target=self._serve, args=(conn,), daemon=True,
                                  name="fault-control-client")
            th.start()
            self._threads.append(th)

    def _serve(self, conn: socket.socket) -> None:
        buf = b""
        try:
            while not self._stop.is_set():
                chunk = conn.recv(4096)
                if not chunk:
                    return
                buf += chunk
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    answer = self.handle(line.decode("utf-8", "replace"))
                    conn.sendall((answer + "\n").encode())
                if len(buf) > 65536:
                    conn.sendall(b"error request line too long\n")
                    return
        except OSError:
            return
        finally:
            conn.close()

    def handle(self, line: str) -> str:
        """The answer line to one request line."""
        inj = self.injector
        try:
            verb, args = parse_request(line)
            if verb == "help":
                return f"ok {HELP}"
            if verb == "time":
                return f"ok {inj.time_s():.6f}"
            if verb == "list":
                return "ok " + json.dumps(inj.entries())
            if verb == "fault":
                now = inj.time_s()
                args.setdefault("at_s", now)
                f = parse_fault(args, "request", inj.node_ids(), inj.unit_ids())
                fid = inj.add(f)
                inj.advance(now)
                return f"ok fault {fid} {f.describe()}"
            if verb == "clear":
                unknown = set(args) - {"drive", "cell", "kind"}
                if unknown:
                    raise FaultScheduleError(f"clear: unknown key(s) {sorted(unknown)}")
                device = "drive" if "drive" in args else "cell" if "cell" in args else None
                n = inj.clear(device, args.get(device) if device else None, args.get("kind"))
                return f"ok cleared {n}"
            raise FaultScheduleError(f"unknown request {verb!r}; {HELP}")
        except FaultScheduleError as exc:
            return f"error {exc}"
        except Exception as exc:  # never kill the channel; say what went wrong
            log.exception("fault control: %r", line)
            return f"error {type(exc).__name__}: {exc}"


def send_request(endpoint: str, line: str, timeout_s: float = 5.0) -> str:
    """Send one request line to a control channel ``HOST:PORT``; the answer line."""
    host, _, port = endpoint.rpartition(":")
    with socket.create_connection((host, int(port)), timeout=timeout_s) as s:
        s.sendall((line.strip() + "\n").encode())
        buf = b""
        deadline = time.monotonic() + timeout_s
        while b"\n" not in buf:
            chunk = s.recv(4096)
            if not chunk or time.monotonic() > deadline:
                break
            buf += chunk
    return buf.decode("utf-8", "replace").strip()


__all__ = [
    "CELL_KINDS",
    "DRIVE_KINDS",
    "Fault",
    "FaultControlServer",
    "FaultInjector",
    "FaultSchedule",
    "FaultScheduleError",
    "InjectionRecord",
    "parse_fault",
    "send_request",
]
