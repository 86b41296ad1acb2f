"""Cable tensions from the Modbus load cells, for a control loop.

Background threads poll the eight cells at the sensors' own rate (tens of
hertz, one read of the register block per unit id); the control cycle calls
:meth:`LoadCellClient.read`, which does no I/O and returns at once the latest
tensions with their age and a status per cable::

    with LoadCellClient("127.0.0.1:5020", calibration=cal) as cells:
        r = cells.read()            # TensionReading
        if not r.all_ok:
            log(r.faults())         # e.g. "Modbus unit 3 (cable 21): stale: ..."
        tau = r.values_N            # (8,) [N], NaN where the status is not OK

A value is only ever a number when its status is ``OK``; every problem
(no answer, Modbus exception, stale counter, overload or out-of-range value,
NaN, sensor fault) is reported as such, with a message naming the Modbus
unit id and the cable. Calibration: ``measured = gain*true + offset``, so
``values_N = (measured - offset) / gain``.

One silent cell must not hold up the others:

- Modbus/TCP: one connection per unit id (``connections="per_unit"``, the default for
  TCP) and one poller thread that sends every unit its request at once and takes the
  answers as they come (a sweep is one round trip; one thread wakes the interpreter once
  per sweep, not eight times, which a control loop in the same process feels); a unit
  that has not answered within ``timeout_s`` is TIMEOUT, and it and a unit whose
  connection failed are asked again only every ``retry_s``, so a silent unit costs the
  others at most one timeout per ``retry_s``;
- a shared line (serial RTU, RTU over a TCP gateway: one request at a time): one lane;
  a unit that timed out is asked again only every ``retry_s`` and last in its sweep, so
  it costs the others at most one timeout per ``retry_s``.

A value's status follows its age, whether or not its turn to be polled came: no valid
answer for ``max_age_s`` (default: one timeout plus three poll periods) is TIMEOUT at the
next :meth:`LoadCellClient.read`, so a hung server cannot pass old values as OK.
"""

from __future__ import annotations

import enum
import logging
import select
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu.register_message import ReadInputRegistersRequest
from pymodbus.transport import CommType

from controller.loadcell_map import DEFAULT_MAP, RegisterMap, load_register_map

from .loadcell_calibration import LoadCellCalibration, load_calibration
from .modbus_config import ModbusEndpoint, parse_modbus_spec


class CableStatus(enum.IntEnum):
    """Status of one cable's tension in a :class:`TensionReading`."""

    OK = 0
    NO_DATA = 1  #: nothing received yet
    STALE = 2  #: the sample counter has not advanced for longer than ``stale_s``
    TIMEOUT = 3  #: no answer within ``timeout_s``, or no fresh answer for ``max_age_s``
    EXCEPTION = 4  #: the unit answered a Modbus exception
    COMM_ERROR = 5  #: cannot connect, connection lost or malformed answer
    SENSOR_FAULT = 6  #: the cell reports a sensor fault (status bit)
    OUT_OF_RANGE = 7  #: overload bit set or value outside the rated range
    NAN = 8  #: the value is not a number


@dataclass(frozen=True)
class TensionReading:
    """Latest cable tensions, arrays in cable id order (``cables``)."""

    values_N: np.ndarray  #: (n,) calibrated tensions [N]; NaN where status != OK
    age_s: np.ndarray  #: (n,) time since the current sample arrived [s]; inf if none
    status: np.ndarray  #: (n,) CableStatus codes
    messages: tuple[str, ...]  #: (n,) "" where OK, else what is wrong (unit id and cable)
    counter: np.ndarray  #: (n,) last sample counter read, -1 if none
    t: float  #: monotonic clock time of this read [s]
    cables: tuple[str, ...]
    unit_ids: tuple[int, ...]
    #: (n,) Modbus exception code of the last answer where the status is EXCEPTION, else 0
    exception_codes: np.ndarray | None = None

    @property
    def ok(self) -> np.ndarray:
        """(n,) bool: the value is valid."""
        return self.status == CableStatus.OK

    @property
    def all_ok(self) -> bool:
        return bool(np.all(self.status == CableStatus.OK))

    def faults(self) -> list[str]:
        """Messages of the cables that are not OK."""
        return [m for m in self.messages if m]

    def status_of(self, cable: str) -> CableStatus:
        return CableStatus(int(self.status[self.cables.index(cable)]))


# pymodbus logs an error for every unanswered request; our statuses report
# them already, so records emitted during our own requests are not printed
# but kept, and the last one goes into the status message of a failed connect
# (it holds the reason, e.g. "[Errno 111] Connection refused").
_quiet = threading.local()


class _QuietDuringPolls(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if not getattr(_quiet, "active", False) or record.levelno >= logging.CRITICAL:
            return True
        if record.levelno >= logging.WARNING:
            _quiet.last = record.getMessage().strip().splitlines()[0][:300]
        return False


def _last_pymodbus_error() -> str:
    msg = getattr(_quiet, "last", "")
    _quiet.last = ""
    return msg


_PYMODBUS_LOGGER = logging.getLogger("pymodbus.logging")
if not any(isinstance(f, _QuietDuringPolls) for f in _PYMODBUS_LOGGER.filters):
    _PYMODBUS_LOGGER.addFilter(_QuietDuringPolls())


@dataclass
class _Lane:
    """Units polled one after the other on one connection, by one thread."""

    units: list[int]
    client: object
    lock: threading.Lock = field(default_factory=threading.Lock)
    passes: int = 0


class LoadCellClient:
    """Polls the load cells in the background; :meth:`read` hands out the latest values.

    :param endpoint: a ``--modbus`` spec string or a :class:`ModbusEndpoint`
    :param register_map: layout and unit ids (default: the built-in map)
    :param calibration: gain/offset per cable (default: identity)
    :param rate_hz: sweeps (reads of all cells) per second
    :param timeout_s: answer timeout per request (also the connect timeout)
    :param stale_s: a counter not advancing for longer (between answers) makes the value STALE
    :param max_age_s: no valid answer for longer makes the value TIMEOUT (poller stopped,
        server hung, unit silent), judged at each read; default ``timeout_s + 3 / rate_hz``
    :param clock: monotonic time source [s]
    :param connections: "per_unit" (one connection per unit id, polled together; default for
        Modbus/TCP) or "shared" (one line for all; default for serial and RTU over TCP)
    :param retry_s: a unit that timed out (or, polled together, whose connection failed)
        is asked again after this long [s] (default ``max(0.5, 5 * timeout_s)``)
    """

    def __init__(
        self,
        endpoint: str | ModbusEndpoint,
        *,
        register_map: RegisterMap = DEFAULT_MAP,
        calibration: LoadCellCalibration | None = None,
        rate_hz: float = 50.0,
        timeout_s: float = 0.1,
        stale_s: float = 0.25,
        max_age_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        connections: str | None = None,
        retry_s: float | None = None,
    ) -> None:
        self.endpoint = (
            endpoint if isinstance(endpoint, ModbusEndpoint) else parse_modbus_spec(endpoint)
        )
        self.map = register_map
        n = register_map.n
        if calibration is None:
            calibration = LoadCellCalibration.identity(register_map.cables)
        if calibration.cables != register_map.cables:
            raise ValueError(
                f"calibration {calibration.source} is for cables {calibration.cables}, "
                f"register map {register_map.source} for {register_map.cables}"
            )
        if not (rate_hz > 0 and timeout_s > 0 and stale_s > 0):
            raise ValueError("rate_hz, timeout_s and stale_s must be > 0")
        if max_age_s is None:
            max_age_s = timeout_s + 3.0 / rate_hz
        if retry_s is None:
            retry_s = max(0.5, 5.0 * timeout_s)
        if not (max_age_s > 0 and retry_s > 0):
            raise ValueError("max_age_s and retry_s must be > 0")
        if connections is None:
            connections = "per_unit" if self.endpoint.kind == "tcp" else "shared"
        if connections not in ("per_unit", "shared"):
            raise ValueError(f"connections must be 'per_unit' or 'shared', got {connections!r}")
        if connections == "per_unit" and self.endpoint.kind != "tcp":
            raise ValueError(f"{self.endpoint}: a shared line cannot have one connection per "
                             "unit (connections='shared')")
        self.calibration = calibration
        self.rate_hz = float(rate_hz)
        self.timeout_s = float(timeout_s)
        self.stale_s = float(stale_s)
        self.max_age_s = float(max_age_s)
        self.retry_s = float(retry_s)
        self.connections = connections
        self.clock = clock

        if connections == "per_unit":
            groups = [[k] for k in range(n)]
        else:
            groups = [list(range(n))]
        self._lanes = [_Lane(units, self.endpoint.make_client(self.timeout_s)) for units in groups]
        self._io_lock = threading.Lock()  # one synchronous sweep (poll_once) at a time
        self._next_try = np.full(n, -np.inf)  # shared line: when a silent unit is due again
        self._lock = threading.Lock()  # guards the state arrays below
        self._swept = threading.Condition(self._lock)
        self._raw = np.full(n, np.nan)  # measured tension as read [N]
        self._bits = np.zeros(n, dtype=np.int64)  # status register
        self._counter = np.full(n, -1, dtype=np.int64)
        self._t_sample = np.full(n, np.nan)  # when the current counter value arrived
        self._t_answer = np.full(n, np.nan)  # last valid answer
        self._comm = np.full(n, int(CableStatus.NO_DATA), dtype=np.int8)
        self._exc = np.zeros(n, dtype=np.int64)  # Modbus exception code of the last answer
        self._comm_msg = [f"{register_map.describe(k)}: no data yet" for k in range(n)]
        self.sweeps = 0  #: completed sweeps (every unit asked once, or skipped while due later)
        self._lane_sweeps = 0
        self.errors = np.zeros(n, dtype=np.int64)  #: failed requests per cable
        self.answers = np.zeros(n, dtype=np.int64)  #: valid answers per cable
        self.last_sweep_s = float("nan")  #: duration of the last sweep (or lane pass) [s]

        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()

    def __repr__(self) -> str:
        return f"LoadCellClient({str(self.endpoint)!r}, units={self.map.unit_ids})"

    # ---- polling (I/O) ----------------------------------------------------
    def _fail(self, k: int, status: CableStatus, why: str, exception_code: int = 0) -> None:
        with self._lock:
            self._comm[k] = status
            self._exc[k] = exception_code
            self._comm_msg[k] = f"{self.map.describe(k)} at {self.endpoint}: {why}"
            self.errors[k] += 1

    def _poll_unit(self, k: int, client) -> bool:
        """Read one cell; False when the connection is unusable (skip the rest of the lane)."""
        uid = self.map.unit_ids[k]
        start, count = self.map.block_start, self.map.block_count
        try:
            rr = client.read_input_registers(start, count=count, device_id=uid)
        except Exception as exc:
            return self._request_failed(k, client, exc)
        return self._answer(k, rr)

    def _request_failed(self, k: int, client, exc: Exception) -> bool:
        """A request that raised ``exc``: the cable's status says why; False when the
        connection is unusable (skip the rest of the lane). Other exceptions go on."""
        if isinstance(exc, ConnectionException):
            client.close()
            reason = _last_pymodbus_error() or str(exc)
            self._fail(k, CableStatus.COMM_ERROR, f"connection failed: {reason}")
            return False
        if isinstance(exc, ModbusIOException):
            why = f"no answer within {self.timeout_s:g} s"
            if "No response received" not in str(exc):  # e.g. an answer from another unit
                why += f" ({exc})"
            self._fail(k, CableStatus.TIMEOUT, why)
            return True
        if isinstance(exc, (ModbusException, OSError, ValueError, struct.error, IndexError)):
            client.close()
            self._fail(k, CableStatus.COMM_ERROR, f"{type(exc).__name__}: {exc}")
            return True
        raise exc

    def _answer(self, k: int, rr) -> bool:
        """Take the answer ``rr`` of cell ``k`` (an exception, registers that do not fit, or
        the value with its status bits and counter)."""
        count = self.map.block_count
        t = self.clock()
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0) or 0)
            try:
                name = ExcCodes(code).name
            except ValueError:
                name = "unknown"
            self._fail(k, CableStatus.EXCEPTION, f"Modbus exception {code:#04x} ({name})", code)
            return True
        regs = list(getattr(rr, "registers", None) or [])
        if len(regs) != count:
            self._fail(
                k, CableStatus.COMM_ERROR, f"answered {len(regs)} registers, expected {count}"
            )
            return True
        try:
            value, bits, counter = self.map.decode(np.asarray(regs, dtype=np.int64))
        except (ValueError, OverflowError, TypeError) as exc:
            self._fail(k, CableStatus.COMM_ERROR, f"malformed answer: registers {regs[:8]} "
                       f"do not decode: {exc}")
            return True
        with self._lock:
            if int(counter) != self._counter[k] or not np.isfinite(self._t_sample[k]):
                self._t_sample[k] = t
            self._counter[k] = int(counter)
            self._raw[k] = float(value)
            self._bits[k] = int(bits)
            self._t_answer[k] = t
            self.answers[k] += 1
            self._comm[k] = CableStatus.OK
            self._exc[k] = 0
            self._comm_msg[k] = ""
        return True

    def _poll_lane(self, lane: _Lane, backoff: bool) -> None:
        """Ask each unit of a lane once (``backoff``: units that timed out only when due)."""
        now = self.clock()
        units = lane.units
        if backoff:
            due = [k for k in units if now >= self._next_try[k]]
            units = [k for k in due if np.isinf(self._next_try[k])] + [
                k for k in due if not np.isinf(self._next_try[k])]  # silent ones last
        with lane.lock:
            _quiet.active = True
            _quiet.last = ""
            try:
                for i, k in enumerate(units):
                    if not self._poll_unit(k, lane.client):
                        for j in units[i + 1:]:
                            self._fail(j, CableStatus.COMM_ERROR, "connection failed (see unit "
                                       f"{self.map.unit_ids[k]}), not polled")
                        break
                    if backoff and self._comm[k] == CableStatus.TIMEOUT:
                        self._next_try[k] = self.clock() + self.retry_s
                        with self._lock:
                            self._comm_msg[k] += f"; asked again every {self.retry_s:g} s"
                    elif backoff:
                        self._next_try[k] = -np.inf
            finally:
                _quiet.active = False

    def _pipelined(self) -> bool:
        """Whether a sweep can send every request before it reads the answers: one unit per
        connection (Modbus/TCP, one lane per unit), pymodbus with no retries."""
        return self.connections == "per_unit" and len(self._lanes) > 1 and all(
            len(ln.units) == 1 and getattr(getattr(ln.client, "transaction", None),
                                           "retries", None) == 0 for ln in self._lanes)

    def _sweep_pipelined(self, lanes: list[_Lane] | None = None) -> None:
        """One sweep over per-unit connections (``lanes``: those due, default all): every
        request out, then the answers taken as they arrive (the same requests and answers
        as one unit after the other; the cells answer in parallel, so the sweep takes one
        round trip instead of one per unit). A unit that has not answered ``timeout_s``
        after its request is TIMEOUT and its connection closed (a late answer must not be
        taken for the next request's)."""
        start, count = self.map.block_start, self.map.block_count
        lanes = self._lanes if lanes is None else lanes
        for lane in lanes:
            lane.lock.acquire()
        _quiet.active = True
        _quiet.last = ""
        try:
            waiting: dict[object, tuple[int, object, object]] = {}
            for lane in lanes:
                k, client = lane.units[0], lane.client
                try:
                    request = _send_read(client, start, count, self.map.unit_ids[k])
                except Exception as exc:
                    self._request_failed(k, client, exc)
                    continue
                sock = getattr(client, "socket", None)
                if sock is None:  # no socket to watch: wait for this answer alone
                    self._take_answer(k, client, request)
                else:
                    waiting[sock] = (k, client, request)
            deadline = time.monotonic() + self.timeout_s
            while waiting:
                left = deadline - time.monotonic()
                ready = select.select(list(waiting), [], [], max(left, 0.0))[0] \
                    if left > 0 else []
                if not ready:
                    for k, client, _ in waiting.values():
                        client.close()
                        self._fail(k, CableStatus.TIMEOUT, f"no answer within "
                                   f"{self.timeout_s:g} s")
                    break
                for sock in ready:
                    k, client, request = waiting.pop(sock)
                    self._take_answer(k, client, request)
        finally:
            _quiet.active = False
            for lane in lanes:
                lane.lock.release()

    def _take_answer(self, k: int, client, request) -> None:
        try:
            rr = _await_answer(client, request)
        except Exception as exc:
            self._request_failed(k, client, exc)
        else:
            self._answer(k, rr)

    def poll_once(self) -> None:
        """One synchronous sweep: read every cell once (blocking I/O, up to n x timeout; with
        one connection per unit the requests go out together, see
        :meth:`_sweep_pipelined`)."""
        t0 = self.clock()
        with self._io_lock:
            if self._pipelined():
                self._sweep_pipelined()
            else:
                for lane in self._lanes:
                    self._poll_lane(lane, backoff=False)
        with self._swept:
            self.sweeps += 1
            self.last_sweep_s = self.clock() - t0
            self._swept.notify_all()

    def wait_sweeps(self, count: int = 1, timeout_s: float = 5.0) -> bool:
        """Block until ``count`` more sweeps have completed (False on timeout).

        For start-up and tests, not for the control loop.
        """
        deadline = time.monotonic() + timeout_s
        with self._swept:
            target = self.sweeps + count
            while self.sweeps < target:
                left = deadline - time.monotonic()
                if left <= 0 or not self._swept.wait(left):
                    return self.sweeps >= target
        return True

    def _run(self, lane: _Lane) -> None:
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        backoff = len(lane.units) > 1
        while not self._stop.is_set():
            t0 = self.clock()
            self._poll_lane(lane, backoff)
            with self._swept:
                lane.passes += 1
                self.last_sweep_s = self.clock() - t0
                done = min(ln.passes for ln in self._lanes)
                if done > self._lane_sweeps:
                    self.sweeps += done - self._lane_sweeps
                    self._lane_sweeps = done
                    self._swept.notify_all()
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:  # fell behind (slow line, timeouts): do not try to catch up
                next_t = time.monotonic()
                delay = 0.0
            self._stop.wait(delay)

    def _run_pipelined(self) -> None:
        """One poller for all per-unit connections: pipelined sweeps at ``rate_hz``; a unit
        that timed out or whose connection failed is asked again only every ``retry_s``."""
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            t0 = self.clock()
            due = [ln for ln in self._lanes if t0 >= self._next_try[ln.units[0]]]
            if due:
                with self._io_lock:
                    self._sweep_pipelined(due)
                for ln in due:
                    k = ln.units[0]
                    if self._comm[k] in (CableStatus.TIMEOUT, CableStatus.COMM_ERROR):
                        self._next_try[k] = self.clock() + self.retry_s
                        with self._lock:
                            self._comm_msg[k] += f"; asked again every {self.retry_s:g} s"
                    else:
                        self._next_try[k] = -np.inf
            with self._swept:
                self.sweeps += 1
                self.last_sweep_s = self.clock() - t0
                self._swept.notify_all()
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:  # fell behind: do not try to catch up
                next_t = time.monotonic()
                delay = 0.0
            self._stop.wait(delay)

    def start(self) -> LoadCellClient:
        """Start the background poller(s) (returns at once): one thread for pipelined
        sweeps over per-unit connections, else one per lane."""
        if self._threads:
            raise RuntimeError("load cell poller already running")
        self._stop.clear()
        with self._swept:
            for lane in self._lanes:
                lane.passes = 0
            self._lane_sweeps = 0
        if self._pipelined():
            th = threading.Thread(target=self._run_pipelined, daemon=True,
                                  name="loadcell-poller")
            th.start()
            self._threads.append(th)
            return self
        for i, lane in enumerate(self._lanes):
            th = threading.Thread(target=self._run, args=(lane,), daemon=True,
                                  name=f"loadcell-poller-{i}")
            th.start()
            self._threads.append(th)
        return self

    def stop(self) -> None:
        """Stop the pollers and close the connections."""
        self._stop.set()
        for th in self._threads:
            th.join(self.timeout_s * self.map.n + 2.0)
        self._threads = []
        for lane in self._lanes:
            with lane.lock:
                lane.client.close()

    def __enter__(self) -> LoadCellClient:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ---- control-cycle side (no I/O) -------------------------------------
    def read(self, now: float | None = None) -> TensionReading:
        """Latest tensions with age and status; never blocks on I/O."""
        t = self.clock() if now is None else now
        with self._lock:
            raw = self._raw.copy()
            bits = self._bits.copy()
            counter = self._counter.copy()
            t_sample = self._t_sample.copy()
            t_answer = self._t_answer.copy()
            status = self._comm.copy()
            exc = self._exc.copy()
            comm_msg = list(self._comm_msg)
        m = self.map
        # NaN times (nothing received yet) give infinite ages
        age = t - t_sample
        age[np.isnan(t_sample)] = np.inf
        since_answer = t - t_answer
        since_answer[np.isnan(t_answer)] = np.inf
        stuck_for = t_answer - t_sample  # times are finite or NaN: NaN (none yet) counts as 0
        stuck_for[np.isnan(stuck_for)] = 0.0
        live = status == CableStatus.OK
        sensor = live & ((bits >> m.sensor_fault_bit) & 1).astype(bool)
        beyond = (raw < m.rated_min_N) | (raw > m.rated_max_N)  # NaN: neither (no warning)
        overload = live & (((bits >> m.overload_bit) & 1).astype(bool) | beyond)
        nan = live & np.isnan(raw)
        stale = live & (stuck_for > self.stale_s)
        expired = live & (since_answer > self.max_age_s)
        # priority (last wins): no fresh answer at all, then what the cell says
        # about itself, then what we infer from its answers
        status[stale] = CableStatus.STALE
        status[nan] = CableStatus.NAN
        status[overload] = CableStatus.OUT_OF_RANGE
        status[sensor] = CableStatus.SENSOR_FAULT
        status[expired] = CableStatus.TIMEOUT
        ok = status == CableStatus.OK
        values = self.calibration.true_from_measured(raw)
        messages = [""] * m.n
        if np.count_nonzero(ok) != ok.size:
            values[~ok] = np.nan
            for k in np.flatnonzero(~ok):
                messages[k] = self._message(
                    k, CableStatus(int(status[k])), comm_msg[k], raw[k], bits[k],
                    counter[k], stuck_for[k], since_answer[k], bool(live[k]),
                )
        exc[status != CableStatus.EXCEPTION] = 0
        return TensionReading(
            values_N=values,
            age_s=age,
            status=status,
            messages=tuple(messages),
            counter=counter,
            t=t,
            cables=m.cables,
            unit_ids=m.unit_ids,
            exception_codes=exc,
        )

    def _message(
        self, k: int, st: CableStatus, comm_msg: str, raw: float, bits: int,
        counter: int, stuck_for: float, since_answer: float, live: bool,
    ) -> str:
        m = self.map
        who = f"{m.describe(k)} at {self.endpoint}"
        if not live:  # the last request failed: NO_DATA, TIMEOUT, EXCEPTION, COMM_ERROR
            return f"{comm_msg} [{st.name}]"
        if st is CableStatus.TIMEOUT:
            return (
                f"{who}: no fresh answer for {since_answer:.3f} s (limit {self.max_age_s:g} s; "
                f"server hung, unit silent or poller stopped), last counter {counter} "
                f"[{st.name}]"
            )
        if st is CableStatus.SENSOR_FAULT:
            return f"{who}: sensor fault (status register {bits:#06x}) [{st.name}]"
        if st is CableStatus.OUT_OF_RANGE:
            parts = []
            if (bits >> m.overload_bit) & 1:
                parts.append(f"overload bit set (status register {bits:#06x})")
            if not m.rated_min_N <= raw <= m.rated_max_N:
                parts.append(
                    f"value {raw:.6g} N outside the rated range "
                    f"[{m.rated_min_N:g}, {m.rated_max_N:g}] N"
                )
            else:
                parts.append(f"value {raw:.6g} N")
            return f"{who}: {', '.join(parts)} [{st.name}]"
        if st is CableStatus.NAN:
            return f"{who}: value is NaN (status register {bits:#06x}) [{st.name}]"
        return (  # STALE
            f"{who}: sample counter stuck at {counter} for {stuck_for:.3f} s "
            f"(limit {self.stale_s:g} s) [{st.name}]"
        )


def _send_read(client, start: int, count: int, unit_id: int):
    """Send "read input registers" on a synchronous pymodbus client without waiting for the
    answer (what ``client.read_input_registers`` sends first); the request."""
    if not client.connect():
        raise ConnectionException(f"Failed to connect[{client!s}]")
    request = ReadInputRegistersRequest(address=start, count=count, dev_id=unit_id)
    tm = client.transaction
    request.transaction_id = tm.getNextTID()
    tm.pdu_send(request)
    return request


def _await_answer(client, request):
    """The answer to ``request`` sent by :func:`_send_read`: what ``read_input_registers``
    returns or raises after sending, with no retries (pymodbus 3.16
    ``TransactionManager.sync_execute``)."""
    tm = client.transaction
    try:
        response = tm.sync_get_response(request.dev_id, request.transaction_id)
    except TimeoutError:  # (asyncio's)
        if tm.count_until_disconnect < 0:
            if tm.comm_params.comm_type != CommType.SERIAL:
                tm.connection_lost(TimeoutError("Server not responding"))
            raise _io_error("ERROR: No response received of the last requests (default: "
                            "retries+3), CLOSING CONNECTION.", request) from None
        tm.count_until_disconnect -= 1
        raise _io_error(f"No response received after {tm.retries} retries, continue with "
                        "next request", request) from None
    tm.count_until_disconnect = tm.max_until_disconnect
    if response.dev_id != request.dev_id:
        raise _io_error(f"ERROR: request uses device id={request.dev_id} but received "
                        f"{response.dev_id}.", request)
    if response.transaction_id != request.transaction_id:
        raise _io_error(f"ERROR: request uses transaction id={request.transaction_id} but "
                        f"received {response.transaction_id}.", request)
    response.retries = 0
    return response


def _io_error(message: str, request) -> ModbusIOException:
    return ModbusIOException(message, function_code=request.function_code,
                             transaction_id=request.transaction_id, dev_id=request.dev_id)


def client_from_args(args) -> LoadCellClient:
    """A (not started) client from the options of :func:`hal.modbus_config.add_modbus_arguments`."""
    if getattr(args, "modbus", None) is None:
        raise ValueError("no load cell endpoint: give --modbus HOST:PORT, rtu:DEVICE:BAUD "
                         "or rtu-tcp:HOST:PORT")
    rmap = load_register_map(args.loadcell_map) if args.loadcell_map else DEFAULT_MAP
    cal = (
        load_calibration(args.loadcell_calibration, rmap.cables)
        if args.loadcell_calibration
        else None
    )
    return LoadCellClient(
        args.modbus,
        register_map=rmap,
        calibration=cal,
        rate_hz=args.loadcell_rate,
        timeout_s=args.loadcell_timeout,
        stale_s=args.loadcell_stale,
        max_age_s=getattr(args, "loadcell_max_age", None),
    )
