"""The ``cdpr`` command: one entry point, one sub-command per module in ``bench.commands``.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. Every command accepts ``--json`` (machine-readable output
on stdout; human output, progress and warnings go to stderr).
"""

from __future__ import annotations

import argparse
import importlib
import sys

# Command modules, in the order `cdpr --help` lists them. Add one line per command.
COMMANDS: tuple[str, ...] = (
    "bench.commands.model",
    "bench.commands.bench",
    "bench.commands.diagnose",
    "bench.commands.sim",
    "bench.commands.campaign",
    "bench.commands.evaluate",
    "bench.commands.dryrun",
    "bench.commands.iso9283",
    "bench.commands.commission",
    "bench.commands.compare",
)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"{version('cdpr-bench')} (cdpr-bench)"
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown (cdpr-bench, not installed)"


def build_parser(only: str | None = "") -> argparse.ArgumentParser:
    """The ``cdpr`` parser. ``only``: build the options of that command alone (the others
    are listed with their help; a command's options may import heavy modules); ``""`` all of
    them; ``None`` none (``cdpr --help``)."""
    parser = argparse.ArgumentParser(
        prog="cdpr",
        description="Commission, run and check a large cable-driven parallel robot (ROCASPECT).",
    )
    parser.add_argument("--version", action="version", version=f"cdpr {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for modname in COMMANDS:
        mod = importlib.import_module(modname)
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        if only == "" or only == mod.NAME:
            mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _command(argv: list[str]) -> str | None:
    """The command named on the command line (the first word that is not an option)."""
    return next((a for a in argv if not a.startswith("-")), None)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_command(argv))
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
