"""Command-line options of the hardware (``--site``, ``--can``, ``--modbus``, the load cells,
the drives' EDS and winch file), shared by every command that opens it.

``--site FILE`` (``cdpr-site/1``, :mod:`hal.site`) gives them all at once; an option given
on the command line wins over the site's value, the site's over the option's default
(:func:`apply_site`, called by the commands before they open anything).

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


#: the options a site can give; the attribute lists those given on the command line
SITE_OPTIONS = ("can", "modbus", "tracker", "eds", "winches", "loadcell_map",
                "loadcell_calibration", "hal_clock")
GIVEN = "given_hardware_options"


class _Given(argparse.Action):
    """``store`` that also notes the option as given on the command line."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, values)
        given = set(getattr(namespace, GIVEN, None) or ())
        given.add(self.dest)
        setattr(namespace, GIVEN, given)


def add_site_argument(parser: argparse.ArgumentParser) -> None:
    """Add the shared ``--site FILE`` option."""
    parser.add_argument("--site", metavar="FILE", default=None,
                        help="site file (cdpr-site/1): robot, files, endpoints, limits; "
                             "--can, --modbus, --tracker, ... given here win over it")


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
        type=_type, action=_Given,
        default=_type(default) if default else None,
        metavar="SPEC",
        help=f"CAN bus: {CAN_FORMS}" + (f" (default {default})" if default else ""),
    )


def add_modbus_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the load-cell Modbus options to a command's parser."""
    g = parser.add_argument_group("load cells (Modbus)")
    g.add_argument(
        "--modbus", type=_modbus_spec, metavar="SPEC", action=_Given,
        help=f"load cell endpoint: {MODBUS_FORMS}",
    )
    g.add_argument("--loadcell-map", metavar="TOML", action=_Given,
                   help="register map [the site's, else the built-in default map]")
    g.add_argument(
        "--loadcell-calibration", metavar="TOML", action=_Given,
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


def add_tracker_argument(parser: argparse.ArgumentParser) -> None:
    """Add the shared ``--tracker SPEC`` option (parsed into a TrackerSpec; default: the
    site's, else none)."""

    def _type(text: str):
        from hal.tracker import TrackerSpecError, parse_tracker_spec

        try:
            return parse_tracker_spec(text)
        except TrackerSpecError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parser.add_argument("--tracker", type=_type, default=None, metavar="SPEC", action=_Given,
                        help="laser tracker (cdpr-tracker/1): tcp:HOST:PORT or none "
                             "[the site's, else none]")


def add_hardware_arguments(parser: argparse.ArgumentParser, eds_default: str | None = None,
                           can_default: str | None = None, tracker: bool = False) -> None:
    """Add ``--site``, ``--can``, ``--winches``, ``--eds``, ``--hal-clock`` and the load-cell
    options (and ``--tracker`` if ``tracker``) to a parser. ``--eds`` is required unless
    there is a default or a ``--site`` gives it (checked by :func:`apply_site`)."""
    add_site_argument(parser)
    add_can_argument(parser, default=can_default)
    if tracker:
        add_tracker_argument(parser)
    parser.add_argument("--winches", metavar="TOML", default=None, action=_Given,
                        help="winch parameter file [the site's, else "
                             "controller/data/rocaspect_winches.toml]")
    parser.add_argument("--eds", metavar="EDS", default=eds_default, action=_Given,
                        help="EDS file of the winch drives [the site's" +
                        (f", else {eds_default}]" if eds_default else "]"))
    parser.add_argument("--hal-clock", choices=("wall", "sync"), default="wall",
                        action=_Given,
                        help="wall: real drives; sync: lock-step with a simulated rig "
                             "[the site's clock, else wall]")
    add_modbus_arguments(parser)


def apply_site(args: argparse.Namespace):
    """Fill the hardware options of ``args`` from ``args.site`` (where the command line did
    not give them), with :func:`hal.site.merge_site`; returns the
    :class:`hal.site.HardwareSettings` (``.site`` the :class:`hal.site.Site`, or None).

    Raises :class:`hal.site.SiteError` for a bad site file (file, line, field) and
    ValueError when no EDS is known; nothing is opened."""
    from hal.site import load_site, merge_site

    path = getattr(args, "site", None)
    site = load_site(path) if path else None
    given = set(getattr(args, GIVEN, None) or ())

    def cli(name: str):
        return getattr(args, name, None) if name in given else None

    default_can = getattr(args, "can", None) if "can" not in given else None
    settings = merge_site(
        site, can=cli("can"), modbus=cli("modbus"), tracker=cli("tracker"), eds=cli("eds"),
        winches=cli("winches"), loadcell_map=cli("loadcell_map"),
        loadcell_calibration=cli("loadcell_calibration"), hal_clock=cli("hal_clock"),
        eds_default=getattr(args, "eds", None), can_default=default_can)
    for name in SITE_OPTIONS:
        if hasattr(args, name):
            setattr(args, name, getattr(settings, name))
    if hasattr(args, "eds") and not args.eds:
        raise ValueError("no EDS of the winch drives: give --eds FILE or a --site with "
                         "[drives] eds")
    return settings


__all__ = ["CAN_FORMS", "MODBUS_FORMS", "SITE_OPTIONS", "add_can_argument",
           "add_hardware_arguments", "add_modbus_arguments", "add_site_argument",
           "add_tracker_argument", "apply_site"]
