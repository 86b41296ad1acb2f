"""Tables on the terminal, rendered by ``rich``: one helper for every command's tables.

A column is ``(header, unit, justify)``; the unit is shown in the header as
``length [m]`` (``""``: no unit). On a terminal the table is drawn with a header rule and
bold headers; into a pipe or a file it is plain text (no ANSI codes), columns aligned with
spaces, so that scripts and tests can read it.
"""

from __future__ import annotations

import io
import sys
from collections.abc import Iterable, Sequence
from typing import IO, Any

Column = tuple[str, str, str]  # header, unit ("" for none), justify ("left"/"right")


def col(header: str, unit: str = "", justify: str = "right") -> Column:
    """A column: ``header``, its ``unit`` (shown as ``header [unit]``), ``justify``."""
    return (header, unit, justify)


def _is_tty(stream: IO[str] | None) -> bool:
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


def render(columns: Sequence[Column], rows: Iterable[Sequence[Any]], title: str | None = None,
           stream: IO[str] | None = None, indent: int = 2) -> str:
    """The table as text for ``stream`` (default stdout): styled when ``stream`` is a
    terminal, plain otherwise. ``None`` cells are shown as ``-``; each line is indented by
    ``indent`` spaces; no trailing spaces."""
    from rich import box
    from rich.console import Console
    from rich.padding import Padding
    from rich.table import Table

    tty = _is_tty(stream if stream is not None else sys.stdout)
    t = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD if tty else None,
              show_edge=False, pad_edge=False, header_style="bold" if tty else "",
              title_style="", collapse_padding=False)
    for header, unit, justify in columns:
        t.add_column(f"{header} [{unit}]" if unit else header, justify=justify,  # type: ignore[arg-type]
                     no_wrap=True)
    for r in rows:
        t.add_row(*("-" if v is None else str(v) for v in r))
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=tty, no_color=not tty, width=1000,
                      highlight=False, emoji=False, markup=False, color_system="standard"
                      if tty else None)
    console.print(Padding(t, (0, 0, 0, indent)), crop=False)
    return "\n".join(line.rstrip() for line in buf.getvalue().rstrip("\n").split("\n"))


def print_table(columns: Sequence[Column], rows: Iterable[Sequence[Any]],
                title: str | None = None, stream: IO[str] | None = None,
                indent: int = 2) -> None:
    """Print :func:`render`'s text on ``stream`` (default stdout)."""
    out = stream if stream is not None else sys.stdout
    print(render(columns, rows, title, out, indent), file=out, flush=True)
