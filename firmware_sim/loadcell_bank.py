"""State of the eight simulated load cells: samples, registers and injected faults.

No network here (see :mod:`firmware_sim.loadcell_server` for the Modbus side).
The plant calls :meth:`LoadCellBank.update` once per simulation step with the
true cable tensions [N] in cable id order; each call is one new sample of every
cell (counter +1). A cell measures ``gain * true + offset`` [N] (the
``load_cell_calibration`` effect of cdpr-conventions.md; ideal by default).

Faults are injected per cell (by cable id ``"21"`` or Modbus unit id ``3``) and
stay until cleared; several can be active on one cell:

=================  ==========================================================
``stale``          counter stops, value frozen (the cell stopped sampling)
``exception``      every read answers a Modbus exception (default 0x04)
``no_answer``      the cell does not answer at all (client times out)
``out_of_range``   value beyond the rated range (default 1.2 x rated max) and
                   the overload bit set
``nan``            the float32 reads NaN, status 0 (a firmware bug)
``sensor_fault``   status bit 1 set, value kept
=================  ==========================================================

Thread-safe: ``update``/``inject`` from the plant's thread while the server's
event loop calls :meth:`respond`.
"""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.loadcell_map import RegisterMap, load_register_map

#: The documented register map shipped with the simulator.
REGISTER_MAP_FILE = Path(__file__).with_name("data") / "loadcell_registers.toml"

# Modbus exception codes used here (Modbus Application Protocol v1.1b3, §7).
ILLEGAL_FUNCTION = 0x01
ILLEGAL_ADDRESS = 0x02
DEVICE_FAILURE = 0x04
#: Exception codes a cell may be told to answer (0x09 is not defined by the standard).
EXCEPTION_CODES = (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x0A, 0x0B)
READ_INPUT_REGISTERS = 0x04


class CellFault(enum.StrEnum):
    """A fault that can be injected into one simulated load cell."""

    STALE = "stale"
    EXCEPTION = "exception"
    NO_ANSWER = "no_answer"
    OUT_OF_RANGE = "out_of_range"
    NAN = "nan"
    SENSOR_FAULT = "sensor_fault"


@dataclass(frozen=True)
class Reply:
    """What a cell answers to one request: registers, an exception code, or nothing."""

    registers: list[int] | None = None
    exception_code: int | None = None

    @property
    def silent(self) -> bool:
        return self.registers is None and self.exception_code is None


NO_REPLY = Reply()


def default_register_map() -> RegisterMap:
    """The register map in ``firmware_sim/data/loadcell_registers.toml``."""
    return load_register_map(REGISTER_MAP_FILE)


class LoadCellBank:
    """Eight (``register_map.n``) simulated load cells.

    :param register_map: layout and unit ids (default: the shipped TOML table)
    :param gain: per-cell gain error [-], measured = gain*true + offset
    :param offset_N: per-cell offset [N]
    :param noise_N: standard deviation of white measurement noise [N] (0: none)
    :param seed: seed of the noise generator
    :param initial_N: tensions before the first :meth:`update` [N]
    :param counter_start: sample counter before the first :meth:`update`
    """

    def __init__(
        self,
        register_map: RegisterMap | None = None,
        *,
        gain: np.ndarray | float = 1.0,
        offset_N: np.ndarray | float = 0.0,
        noise_N: float = 0.0,
        seed: int | None = None,
        initial_N: np.ndarray | float = 0.0,
        counter_start: int = 0,
    ) -> None:
        self.map = register_map if register_map is not None else default_register_map()
        n = self.map.n
        self.gain = np.broadcast_to(np.asarray(gain, dtype=float), (n,)).copy()
        self.offset_N = np.broadcast_to(np.asarray(offset_N, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(self.gain)) or np.any(self.gain == 0):
            raise ValueError(f"load cell gains must be finite and non-zero, got {self.gain}")
        self.noise_N = float(noise_N)
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._measured = np.broadcast_to(np.asarray(initial_N, dtype=float), (n,)).copy()
        self._counter = np.full(n, int(counter_start) % self.map.counter_modulo, dtype=np.int64)
        self._faults: list[dict[CellFault, dict]] = [{} for _ in range(n)]
        self.samples = 0  #: number of update() calls

    # ---- plant side -----------------------------------------------------
    def update(self, tensions_N: np.ndarray) -> None:
        """One new sample of every cell from the true tensions ``(n,)`` [N]."""
        t = np.asarray(tensions_N, dtype=float)
        if t.shape != (self.map.n,):
            raise ValueError(f"expected {self.map.n} tensions in cable order, got shape {t.shape}")
        measured = self.gain * t + self.offset_N
        if self.noise_N > 0:
            measured = measured + self._rng.normal(0.0, self.noise_N, self.map.n)
        with self._lock:
            live = np.array([CellFault.STALE not in f for f in self._faults])
            self._measured[live] = measured[live]
            self._counter[live] = (self._counter[live] + 1) % self.map.counter_modulo
            self.samples += 1

    # ---- fault injection --------------------------------------------------
    def inject(
        self,
        which: int | str,
        fault: CellFault | str,
        *,
        exception_code: int = DEVICE_FAILURE,
        value_N: float | None = None,
    ) -> None:
        """Inject ``fault`` into the cell of cable ``which`` (str) or unit id ``which`` (int).

        ``exception_code`` is used by ``exception``; ``value_N`` by ``out_of_range``.
        """
        k = self.map.index_of(which)
        f = CellFault(fault)
        params: dict = {}
        if f is CellFault.EXCEPTION:
            if exception_code not in EXCEPTION_CODES:
                raise ValueError(
                    f"exception code {exception_code:#04x} is not one of "
                    f"{[hex(c) for c in EXCEPTION_CODES]}"
                )
            params["exception_code"] = int(exception_code)
        if f is CellFault.OUT_OF_RANGE:
            v = 1.2 * self.map.rated_max_N if value_N is None else float(value_N)
            if self.map.rated_min_N <= v <= self.map.rated_max_N:
                raise ValueError(
                    f"out_of_range value {v} N lies inside the rated range "
                    f"[{self.map.rated_min_N}, {self.map.rated_max_N}] N"
                )
            params["value_N"] = v
        with self._lock:
            self._faults[k][f] = params

    def clear(self, which: int | str | None = None, fault: CellFault | str | None = None) -> None:
        """Remove ``fault`` (all faults if None) from one cell (all cells if ``which`` is None)."""
        cells = range(self.map.n) if which is None else [self.map.index_of(which)]
        with self._lock:
            for k in cells:
                if fault is None:
                    self._faults[k].clear()
                else:
                    self._faults[k].pop(CellFault(fault), None)

    def faults(self) -> dict[str, list[str]]:
        """Active faults by cable id (cells without faults omitted)."""
        with self._lock:
            return {
                self.map.cables[k]: sorted(str(f) for f in fs)
                for k, fs in enumerate(self._faults)
                if fs
            }

    # ---- register side ----------------------------------------------------
    def registers(self) -> np.ndarray:
        """Current register blocks ``(n, block_count)`` as the cells would send them."""
        with self._lock:
            value = self._measured.copy()
            counter = self._counter.copy()
            faults = [dict(f) for f in self._faults]
        m = self.map
        overload = (value < m.rated_min_N) | (value > m.rated_max_N)
        sensor_fault = np.zeros(m.n, dtype=bool)
        for k, fs in enumerate(faults):
            if CellFault.OUT_OF_RANGE in fs:
                value[k] = fs[CellFault.OUT_OF_RANGE]["value_N"]
                overload[k] = True
            if CellFault.NAN in fs:
                value[k] = np.nan
                overload[k] = False
            if CellFault.SENSOR_FAULT in fs:
                sensor_fault[k] = True
        status = (overload.astype(np.int64) << m.overload_bit) | (
            sensor_fault.astype(np.int64) << m.sensor_fault_bit
        )
        return m.encode(value, status, counter)

    def respond(self, unit_id: int, function_code: int, address: int, count: int) -> Reply:
        """The answer of unit ``unit_id`` to a read request (what goes on the wire)."""
        if unit_id not in self.map.unit_ids:
            return NO_REPLY  # nobody with that address on the line
        k = self.map.unit_ids.index(unit_id)
        with self._lock:
            faults = dict(self._faults[k])
        if CellFault.NO_ANSWER in faults:
            return NO_REPLY
        if CellFault.EXCEPTION in faults:
            return Reply(exception_code=faults[CellFault.EXCEPTION]["exception_code"])
        if function_code != READ_INPUT_REGISTERS:
            return Reply(exception_code=ILLEGAL_FUNCTION)
        start, n = self.map.block_start, self.map.block_count
        if address < start or count < 1 or address + count > start + n:
            return Reply(exception_code=ILLEGAL_ADDRESS)
        block = self.registers()[k]
        return Reply(registers=[int(v) for v in block[address - start : address - start + count]])
