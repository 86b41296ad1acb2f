"""The commissioning report: one Markdown file, one section appended per sub-command.

Every ``cdpr commission`` sub-command appends what it did (scanned, checked, changed,
measured) with its start and end times, the command line, the bus and files it used, and
how it ended, to ``commissioning-report.md`` in the current directory, or to the file of
``--report PATH`` (``--no-report``: none). The file is created with a title when new; a
section is appended even when the command fails or is interrupted, so the report is the
site's log of the commissioning.
"""

from __future__ import annotations

import os
import shlex
import time
from dataclasses import dataclass, field
from pathlib import Path

DEFAULT_REPORT = "commissioning-report.md"
TITLE = ("# Commissioning report\n\n"
         "Written by `cdpr commission` (cdpr-bench): one section per command, in the order "
         "they ran. Times are local.\n")


def _stamp(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def md_cell(v: object) -> str:
    """A value as a Markdown table cell (pipes escaped)."""
    return str(v).replace("|", "\\|").replace("\n", " ")


@dataclass
class Section:
    """One command's section; :meth:`write` appends it to the report."""

    path: Path | None
    command: str
    argv: list[str]
    started: float = field(default_factory=time.time)
    facts: list[tuple[str, str]] = field(default_factory=list)
    blocks: list[str] = field(default_factory=list)
    outcome: str = ""
    written: bool = False
    #: fields added to the JSON error object when the command fails (e.g. the drive's state)
    json_extra: dict = field(default_factory=dict)

    def fact(self, key: str, value: object) -> None:
        """A ``- key: value`` line under the heading."""
        self.facts.append((key, str(value)))

    def text(self, paragraph: str) -> None:
        self.blocks.append(paragraph.rstrip() + "\n")

    def bullets(self, items: list[str]) -> None:
        if items:
            self.blocks.append("".join(f"- {md_cell(i)}\n" for i in items))

    def table(self, headers: list[str], rows: list[list[object]]) -> None:
        if not rows:
            return
        lines = ["| " + " | ".join(md_cell(h) for h in headers) + " |",
                 "|" + "|".join(" --- " for _ in headers) + "|"]
        lines += ["| " + " | ".join(md_cell(c) for c in row) + " |" for row in rows]
        self.blocks.append("\n".join(lines) + "\n")

    def markdown(self, ended: float) -> str:
        out = [f"\n## {_stamp(self.started)} {self.command}\n"]
        out.append(f"- command: `{shlex.join(self.argv)}`")
        out.append(f"- directory: `{os.getcwd()}`")
        for k, v in self.facts:
            out.append(f"- {k}: {md_cell(v)}")
        out.append(f"- ended: {_stamp(ended)} ({ended - self.started:.1f} s): "
                   f"{self.outcome or 'done'}")
        text = "\n".join(out) + "\n"
        for b in self.blocks:
            text += "\n" + b
        return text

    def write(self, outcome: str | None = None) -> Path | None:
        """Append the section (once); returns the report's path (None: no report)."""
        if outcome is not None:
            self.outcome = outcome
        if self.written or self.path is None:
            return self.path
        self.written = True
        p = self.path
        p.parent.mkdir(parents=True, exist_ok=True)
        new = not p.exists() or p.stat().st_size == 0
        with p.open("a", encoding="utf-8") as f:
            if new:
                f.write(TITLE)
            f.write(self.markdown(time.time()))
        return p


def report_path(args) -> Path | None:
    """The report file of a command's options (None with ``--no-report``)."""
    if getattr(args, "no_report", False):
        return None
    return Path(getattr(args, "report", None) or DEFAULT_REPORT)
