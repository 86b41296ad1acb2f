"""Command-line options of the hardware (``--can``, ``--modbus``, the load cells, the drives'
EDS and winch file), shared by every command that opens it.

Light on purpose: building a command's parser imports no bus library (python-can,
canopen, pymodbus); the option values are parsed by the HAL's own parsers when given.
"""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hal.can_bus import CanSpec
    from hal.modbus_config import ModbusEndpoint

#: the forms of ``--can`` and ``--modbus`` (the parsers in hal.can_bus / hal.modbus_config)
CAN_FORMS = "virtual:NAME, socketcan:CHANNEL, socketcand:HOST:PORT[:CHANNEL] or INTERFACE:CHANNEL"
MODBUS_FORMS = "HOST:PORT, rtu:DEVICE:BAUD[:8N1] or rtu-tcp:HOST:PORT"


def _modbus_spec(text: str) -> ModbusEndpoint:
    from hal.modbus_config import modbus_spec_arg

    return modbus_spec_arg(text)


def add_can_argument(parser: argparse.ArgumentParser, default: str | None = None) -> None:
    """Add the shared ``--can SPEC`` option (parsed into a :class:`CanSpec`)."""

    def _type(text: str) -> CanSpec:
        from hal.can_bus import CanSpecError, parse_can_spec

        try:
            return parse_can_spec(text)
        except CanSpecError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parser.add_argument(
        "--can",
        type=_type,
        default=_type(default) if default else None,
        metavar="SPEC",
        help=f"CAN bus: {CAN_FORMS}" + (f" (default {default})" if default else ""),
    )


def add_modbus_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the load-cell Modbus options to a command's parser."""
    g = parser.add_argument_group("load cells (Modbus)")
    g.add_argument(
        "--modbus", type=_modbus_spec, metavar="SPEC",
        help=f"load cell endpoint: {MODBUS_FORMS}",
    )
    g.add_argument("--loadcell-map", metavar="TOML", help="register map [built-in default map]")
    g.add_argument(
        "--loadcell-calibration", metavar="TOML",
        help="per-cable gain_ij/offset_ij [N] (measured = gain*true + offset)",
    )
    g.add_argument("--loadcell-rate", type=float, default=50.0, metavar="HZ",
                   help="polls of all eight cells per second [50]")
    g.add_argument("--loadcell-timeout", type=float, default=0.1, metavar="S",
                   help="answer timeout per request [0.1 s]")
    g.add_argument("--loadcell-stale", type=float, default=0.25, metavar="S",
                   help="a counter not advancing for longer is stale [0.25 s]")
    g.add_argument("--loadcell-max-age", type=float, default=None, metavar="S",
                   help="no fresh answer for longer is a timeout [timeout + 3 poll periods]")


def add_hardware_arguments(parser: argparse.ArgumentParser, eds_default: str | None = None,
                           can_default: str | None = None) -> None:
    """Add ``--can``, ``--winches``, ``--eds`` and the load-cell options to a parser."""
    add_can_argument(parser, default=can_default)
    parser.add_argument("--winches", metavar="TOML", default=None,
                        help="winch parameter file [controller/data/rocaspect_winches.toml]")
    parser.add_argument("--eds", metavar="EDS", default=eds_default, required=eds_default is None,
                        help="EDS file of the winch drives" +
                        (f" [{eds_default}]" if eds_default else ""))
    parser.add_argument("--hal-clock", choices=("wall", "sync"), default="wall",
                        help="wall: real drives; sync: lock-step with a simulated rig [wall]")
    add_modbus_arguments(parser)


__all__ = ["CAN_FORMS", "MODBUS_FORMS", "add_can_argument", "add_hardware_arguments",
           "add_modbus_arguments"]
