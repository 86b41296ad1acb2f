"""Simulated load cells on the wire: one pymodbus server answering unit ids 1..8.

The server runs its own asyncio loop in a background thread, so a plant or a
test drives it with plain calls::

    with LoadCellServer(port=0) as srv:          # 127.0.0.1, OS-assigned port
        srv.update(tensions_N)                   # each simulation step
        srv.inject("21", "stale")                # fault injection
        hal_spec = srv.endpoint                  # "127.0.0.1:PORT" (HAL --modbus form)

``rtu=True`` serves RTU framing (CRC, no MBAP header) over TCP, as a serial
line behind a transparent TCP gateway; ``endpoint`` is then
``"rtu-tcp:127.0.0.1:PORT"``. ``serial="/dev/ttyUSB1"`` serves RTU on a real
serial line (pyserial; any ``serial_for_url`` name), ``endpoint``
``"rtu:/dev/ttyUSB1:BAUD"`` as seen from the other end of a null-modem pair.

Standalone (for tests in another process and for mbpoll)::

    python -m firmware_sim.loadcell_server --port 0 [--rtu] [--source sine]
    python -m firmware_sim.loadcell_server --serial /dev/ttyUSB1 --baud 115200

prints one JSON line with the endpoint on stdout, then feeds the cells from a
built-in tension source (constant or slow sine per cable) until SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import json
import signal
import sys
import threading
import time
from collections.abc import Sequence

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from controller.loadcell_map import RegisterMap, load_register_map

from .loadcell_bank import CellFault, LoadCellBank


async def _cell_action(
    bank: LoadCellBank,
    unit_id: int,
    function_code: int,
    start_address: int,
    address: int,
    count: int,
    current_registers: list[int],
    set_values: list[int] | list[bool] | None,
) -> ExcCodes | None:
    """pymodbus SimDevice action: fill the registers from the bank, or fail as injected."""
    reply = bank.respond(unit_id, function_code, address, count)
    if reply.silent:
        # With ignore_missing_devices=True the request handler sends nothing.
        raise NoSuchIdException(f"simulated load cell unit {unit_id} does not answer")
    if reply.exception_code is not None:
        return ExcCodes(reply.exception_code)
    assert reply.registers is not None
    i = address - start_address
    current_registers[i : i + count] = reply.registers
    return None


async def _silent_action(*_args) -> ExcCodes | None:
    raise NoSuchIdException("no device with that unit id on the simulated line")


class LoadCellServer:
    """Modbus TCP (or RTU-over-TCP) server for a :class:`LoadCellBank`.

    :param bank: the cells (default: ideal cells with the shipped register map)
    :param host: interface to bind [default 127.0.0.1]
    :param port: TCP port, 0 = OS-assigned (read :attr:`port` after :meth:`start`)
    :param rtu: RTU framing instead of Modbus/TCP (MBAP) framing
    :param serial: serve RTU on this serial device instead of TCP (``host``/``port`` unused)
    :param baudrate: serial line speed [bit/s], 8N1
    """

    def __init__(
        self,
        bank: LoadCellBank | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        rtu: bool = False,
        serial: str | None = None,
        baudrate: int = 19200,
    ) -> None:
        self.bank = bank if bank is not None else LoadCellBank()
        self.host = host
        self._requested_port = int(port)
        self.serial = serial
        self.baudrate = int(baudrate)
        self.rtu = bool(rtu) or serial is not None
        self._port: int | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | ModbusSerialServer | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    # ---- plant / test API -------------------------------------------------
    @property
    def register_map(self) -> RegisterMap:
        return self.bank.map

    def update(self, tensions_N: np.ndarray) -> None:
        """New sample of every cell from the true tensions ``(8,)`` [N], cable id order."""
        self.bank.update(tensions_N)

    def inject(self, which: int | str, fault: CellFault | str, **params) -> None:
        """Inject a fault into one cell (see :meth:`LoadCellBank.inject`)."""
        self.bank.inject(which, fault, **params)

    def clear(self, which: int | str | None = None, fault: CellFault | str | None = None) -> None:
        self.bank.clear(which, fault)

    # ---- endpoint -----------------------------------------------------------
    @property
    def port(self) -> int:
        """The bound TCP port (after :meth:`start`)."""
        if self._port is None:
            raise RuntimeError("load cell server not started (or on a serial line)")
        return self._port

    @property
    def endpoint(self) -> str:
        """The endpoint in the HAL's ``--modbus`` form."""
        if self.serial is not None:
            return f"rtu:{self.serial}:{self.baudrate}"
        base = f"{self.host}:{self.port}"
        return f"rtu-tcp:{base}" if self.rtu else base

    # ---- life cycle ---------------------------------------------------------
    def _devices(self) -> list[SimDevice]:
        m = self.bank.map

        def block() -> list[SimData]:
            return [
                SimData(m.block_start, count=m.block_count, values=0, datatype=DataType.REGISTERS)
            ]

        devices = [
            SimDevice(
                id=uid, simdata=block(), action=functools.partial(_cell_action, self.bank, uid)
            )
            for uid in m.unit_ids
        ]
        # id 0 = "every other id": stay silent like an absent device on a bus.
        devices.append(SimDevice(id=0, simdata=block(), action=_silent_action))
        return devices

    async def serve(self) -> None:
        """Run the server in the current event loop until :meth:`stop` (or cancellation)."""
        self._loop = asyncio.get_running_loop()
        try:
            if self.serial is not None:
                self._server = ModbusSerialServer(
                    self._devices(),
                    framer=FramerType.RTU,
                    port=self.serial,
                    baudrate=self.baudrate,
                    ignore_missing_devices=True,
                )
                await self._server.serve_forever(background=True)
            else:
                self._server = ModbusTcpServer(
                    self._devices(),
                    framer=FramerType.RTU if self.rtu else FramerType.SOCKET,
                    address=(self.host, self._requested_port),
                    ignore_missing_devices=True,
                )
                await self._server.serve_forever(background=True)
                sockets = self._server.transport.sockets  # type: ignore[attr-defined]
                self._port = int(sockets[0].getsockname()[1])
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            raise
        self._ready.set()
        try:
            await self._server.serving
        finally:
            await self._server.shutdown()

    def start(self, timeout_s: float = 5.0) -> LoadCellServer:
        """Start serving in a background thread; returns once the port is bound."""
        if self._thread is not None:
            raise RuntimeError("load cell server already started")

        def run() -> None:
            try:
                asyncio.run(self.serve())
            except BaseException as exc:  # reported to start() through _error
                if self._error is None:
                    self._error = exc
                self._ready.set()

        self._thread = threading.Thread(target=run, name="loadcell-modbus-server", daemon=True)
        self._thread.start()
        where = self.serial or f"{self.host}:{self._requested_port}"
        if not self._ready.wait(timeout_s):
            raise TimeoutError(f"load cell server on {where} not ready")
        if self._error is not None:
            raise RuntimeError(
                f"load cell server cannot listen on {where}: {self._error}"
            ) from self._error
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop serving and close every client connection."""
        if self._thread is None:
            return
        if self._loop is not None and self._server is not None and self._loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            try:
                fut.result(timeout_s)
            except Exception:  # the loop may have ended meanwhile
                pass
        self._thread.join(timeout_s)
        self._thread = None

    def __enter__(self) -> LoadCellServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# ---- built-in tension source for the standalone server ----------------------
def default_tensions(n: int = 8) -> np.ndarray:
    """Distinct constant tensions [N] per cable: 100, 112.5, ... (easy to tell apart)."""
    return 100.0 + 12.5 * np.arange(n)


def source_tensions(
    kind: str, t: float, base_N: np.ndarray, amplitude_N: float, period_s: float
) -> np.ndarray:
    """Built-in source: ``constant`` base tensions or a slow ``sine`` per cable [N]."""
    if kind == "constant":
        return base_N
    phase = 2 * np.pi * np.arange(base_N.size) / base_N.size
    return base_N + amplitude_N * np.sin(2 * np.pi * t / period_s + phase)


def _parse_tensions(text: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(f"--tensions: not a list of numbers: {text!r}") from None
    if values.size != 8 or not np.all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"--tensions needs 8 finite values [N], got {text!r}")
    return values


def _parse_fault(text: str) -> tuple[str, str]:
    cable, _, kind = text.partition(":")
    try:
        CellFault(kind)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--fault {text!r}: kind must be one of {[f.value for f in CellFault]}"
        ) from None
    return cable, kind


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m firmware_sim.loadcell_server",
        description="Simulated cable-tension load cells (Modbus units 1..8) on TCP.",
    )
    p.add_argument("--host", default="127.0.0.1", help="interface to bind [127.0.0.1]")
    p.add_argument("--port", type=int, default=5020, help="TCP port, 0 = any free port [5020]")
    p.add_argument("--rtu", action="store_true", help="RTU framing over TCP instead of Modbus/TCP")
    p.add_argument("--serial", metavar="DEVICE", help="serve RTU on a serial line instead of TCP")
    p.add_argument("--baud", type=int, default=19200, help="serial baud rate, 8N1 [19200]")
    p.add_argument("--map", help="register map TOML [firmware_sim/data/loadcell_registers.toml]")
    p.add_argument("--source", choices=("constant", "sine"), default="constant")
    p.add_argument(
        "--tensions", type=_parse_tensions, help="8 comma-separated base tensions [N] (cable order)"
    )
    p.add_argument("--amplitude", type=float, default=20.0, help="sine amplitude [N] [20]")
    p.add_argument("--period", type=float, default=10.0, help="sine period [s] [10]")
    p.add_argument("--rate", type=float, default=50.0, help="samples per second [50]")
    p.add_argument(
        "--fault", type=_parse_fault, action="append", default=[], metavar="CABLE:KIND",
        help="inject a fault at start, e.g. 21:stale (repeatable)",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    rmap = load_register_map(args.map) if args.map else None
    base = args.tensions if args.tensions is not None else default_tensions()
    bank = LoadCellBank(rmap, initial_N=base)
    server = LoadCellServer(
        bank, host=args.host, port=args.port, rtu=args.rtu, serial=args.serial, baudrate=args.baud
    )
    for cable, kind in args.fault:
        try:
            bank.inject(cable, kind)
        except KeyError as exc:
            print(f"--fault: {exc.args[0]}", file=sys.stderr)
            return 2
    bank.update(base)  # first sample before anyone can read
    try:
        server.start()
    except (RuntimeError, TimeoutError) as exc:
        print(str(exc), file=sys.stderr)
        return 1
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    info = {
        "endpoint": server.endpoint,
        "host": None if args.serial else server.host,
        "port": None if args.serial else server.port,
        "serial": args.serial,
        "framer": "rtu" if server.rtu else "socket",
        "units": dict(zip(bank.map.cables, bank.map.unit_ids, strict=True)),
        "source": args.source,
        "tensions_N": [float(v) for v in base],
        "rate_hz": args.rate,
    }
    print(json.dumps(info), flush=True)
    t0 = time.monotonic()
    period = 1.0 / args.rate
    next_t = t0 + period
    try:
        while not stop.wait(max(0.0, next_t - time.monotonic())):
            bank.update(source_tensions(args.source, time.monotonic() - t0, base,
                                        args.amplitude, args.period))
            next_t += period
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
