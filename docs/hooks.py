"""MkDocs hooks: the command reference is written at build time from the ``cdpr``
argument parser (``bench.cli.build_parser``), so it cannot go stale.

``mkdocs.yml`` names this file under ``hooks``; it is excluded from the site.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import re
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = "reference/commands.md"


def _cell(text: str) -> str:
    """Text for one Markdown table cell."""
    return " ".join(text.split()).replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _metavar(action: argparse.Action, default: str) -> str:
    if action.metavar is not None:
        m = action.metavar
        return " ".join(m) if isinstance(m, tuple) else str(m)
    if action.choices:
        return "{" + ",".join(str(c) for c in action.choices) + "}"
    return default


def _option(action: argparse.Action) -> str:
    if action.option_strings:
        flags = ", ".join(action.option_strings)
        if action.nargs != 0:
            flags += " " + _metavar(action, action.dest.upper())
        return f"`{flags}`"
    return f"`{_metavar(action, action.dest)}`"


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    text = parser._get_formatter()._expand_help(action) if action.help else ""
    if (action.option_strings and action.default not in (None, False, argparse.SUPPRESS)
            and "default" not in text and "[" not in text and action.nargs != 0):
        text += f" (default: {action.default})"
    return _cell(text)


_ROLE = re.compile(r":(?:mod|func|class|meth|attr|data|exc):`~?([^`]+)`")


def _inline(line: str) -> str:
    """RST inline markup of a docstring line as Markdown: ``code`` and roles to `code`; a
    ``<`` outside code escaped."""
    line = _ROLE.sub(r"``\1``", line).replace("``", "`")
    parts = line.split("`")
    for k in range(0, len(parts), 2):  # outside code spans
        parts[k] = parts[k].replace("<", "&lt;")
    return "`".join(parts)


def docstring_markdown(doc: str) -> list[str]:
    """A command module's docstring (RST-ish) as Markdown lines: inline code, and a
    paragraph ending in ``::`` followed by an indented block as a code block."""
    lines = inspect.cleandoc(doc).splitlines()
    out: list[str] = []
    k = 0
    while k < len(lines):
        line = lines[k]
        if line.rstrip().endswith("::"):
            out.append(_inline(line.rstrip()[:-1]))
            k += 1
            while k < len(lines) and not lines[k].strip():
                k += 1
            block = []
            while k < len(lines) and (not lines[k].strip() or lines[k].startswith(" ")):
                block.append(lines[k])
                k += 1
            while block and not block[-1].strip():
                block.pop()
            out += ["", "```text", *textwrap.dedent("\n".join(block)).splitlines(), "```", ""]
            continue
        out.append(_inline(line))
        k += 1
    return out


def _section(parser: argparse.ArgumentParser, words: list[str], out: list[str],
             doc: str | None = None) -> None:
    """One command's section, then its sub-commands' (depth first)."""
    name = " ".join(words)
    level = "#" * min(len(words), 4)
    out += [f"{level} `{name}`", ""]
    if parser.description:
        out += [parser.description.strip(), ""]
    if doc:
        out += docstring_markdown(doc) + [""]
    usage = " ".join(parser.format_usage().split())
    out += ["```text", usage, "```", ""]
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    rows = [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]
    if rows:
        out += ["| argument | meaning |", "| --- | --- |"]
        out += [f"| {_option(a)} | {_help(parser, a)} |" for a in rows]
        out.append("")
    for sub in subs:
        for child, p in sub.choices.items():
            _section(p, words + [child], out)


def commands_page() -> str:
    """The whole reference page, Markdown."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from bench.cli import COMMANDS, build_parser

    parser = build_parser("")
    out = ["# Commands", "",
           "Generated from the argument parser (`bench/cli.py`, `bench/commands/`) each "
           "time the site is built. Every command takes `--json` (one JSON object on "
           "stdout); progress, warnings and errors in words go to stderr. Exit statuses: "
           "[exit status](exit-status.md).", ""]
    top = " ".join(parser.format_usage().split())
    out += ["```text", top, "```", "", "| argument | meaning |", "| --- | --- |",
            "| `--version` | the version and the git commit it was built from |", ""]
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    docs = {}
    for modname in COMMANDS:
        mod = importlib.import_module(modname)
        docs[mod.NAME] = mod.__doc__
    for name, p in sub.choices.items():
        _section(p, ["cdpr", name], out, docs.get(name))
    # the machine's checkout path in a default is the repository's relative path
    return "\n".join(out).replace(str(ROOT) + "/", "") + "\n"


def on_files(files, config):
    """Add the generated command reference to the site's files."""
    from mkdocs.structure.files import File

    files.append(File.generated(config, PAGE, content=commands_page()))
    return files
