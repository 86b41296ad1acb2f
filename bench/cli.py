"""The ``cdpr`` command: one entry point, one sub-command per module in ``bench.commands``.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. Every command accepts ``--json`` (machine-readable output
on stdout; human output, progress and warnings go to stderr).

Under ``--json`` stdout carries one JSON object whatever happens: a usage error (an
unknown command or option, a missing argument) prints ``{"error", "usage"}`` there (the
usual message on stderr, exit status 2).

Signals: SIGTERM and SIGHUP raise :class:`bench.parallel.Terminated` (a KeyboardInterrupt)
in every command, so that its ``finally`` blocks run and its worker processes end. An
interruption ends every command with a last line on stderr, ``cdpr COMMAND: interrupted
(SIGINT)`` (Ctrl-C, exit status 130) or ``terminated (SIGTERM)`` (143: 128 + the signal),
and under ``--json`` ``{"error": "interrupted (SIGINT)"}`` (or the SIGTERM message) on
stdout unless the command printed its own object (commands that stop themselves on a
signal, ``dry-run``, ``sim``, ``commission monitor``, return the same statuses).
"""

from __future__ import annotations

import argparse
import importlib
import json
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
    "bench.commands.recording",
    "bench.commands.replay",
)


class _VersionAction(argparse.Action):
    """``--version``: the version and the git commit (looked up only when asked)."""

    def __init__(self, option_strings, dest, **kwargs) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="print the version and the git commit, then exit")

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from bench.version import version_string

        print(version_string(), flush=True)
        parser.exit()


class JsonErrorParser(argparse.ArgumentParser):
    """A parser whose usage errors also print ``{"error": message, "usage": usage}`` on
    stdout (for ``--json``); the sub-command parsers are of the same class."""

    def error(self, message: str):
        usage = " ".join(self.format_usage().split())  # one line, not wrapped
        print(json.dumps({"error": message, "usage": usage}), flush=True)
        super().error(message)  # the usual usage and message on stderr, exit status 2


def json_requested(argv: list[str]) -> bool:
    """Whether ``--json`` (or an abbreviation argparse would take) is on the command line
    (before ``--``)."""
    for a in argv:
        if a == "--":
            return False
        if a == "--json" or (len(a) >= 4 and "--json".startswith(a)):
            return True
    return False


def build_parser(only: str | None = "", json_errors: bool = False) -> argparse.ArgumentParser:
    """The ``cdpr`` parser. ``only``: build the options of that command alone (the others
    are listed with their help; a command's options may import heavy modules); ``""`` all of
    them; ``None`` none (``cdpr --help``). ``json_errors``: usage errors also print a JSON
    object on stdout (:class:`JsonErrorParser`)."""
    cls = JsonErrorParser if json_errors else argparse.ArgumentParser
    parser = cls(
        prog="cdpr",
        description="Commission, run and check a large cable-driven parallel robot (ROCASPECT).",
    )
    parser.add_argument("--version", action=_VersionAction)
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


class _Watched:
    """A text stream that notes whether anything was written through it."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self.written = False

    def write(self, text: str) -> int:
        if text:
            self.written = True
        return self._stream.write(text)

    def writelines(self, lines) -> None:
        for line in lines:
            self.write(line)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    as_json = json_requested(argv)
    parser = build_parser(_command(argv), json_errors=as_json)
    args = parser.parse_args(argv)
    from bench.parallel import interrupt_on_term, interruption

    stdout = sys.stdout
    out = sys.stdout = _Watched(stdout)
    try:
        with interrupt_on_term():
            return int(args._run(args) or 0)
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM, SIGHUP the command did not handle
        code, msg = interruption(e)
        print(f"cdpr {args.command}: {msg}", file=sys.stderr, flush=True)
        if as_json and not out.written:
            print(json.dumps({"error": msg}), file=stdout, flush=True)
        return code
    except BrokenPipeError:
        return 0
    finally:
        if sys.stdout is out:
            sys.stdout = stdout


if __name__ == "__main__":
    sys.exit(main())
