"""Output paths checked before the work starts: a command that will write a file or a
directory says at once, naming the path and why, when it could not, instead of failing
(with a traceback) after minutes of work.

:func:`output_file_problem` and :func:`output_dir_problem` return None when the path can
be written, else the message; they create missing parent directories (as the writers
would) and leave nothing else behind.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _parent_problem(parent: Path, what: str) -> str | None:
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        return f"{what}: {parent} exists and is not a directory"
    except OSError as e:
        return f"{what}: cannot create the directory {parent}: {e.strerror or e}"
    if not parent.is_dir():
        return f"{what}: {parent} is not a directory"
    try:  # the only honest test of writability (ACLs, read-only mounts, root)
        fd, probe = tempfile.mkstemp(prefix=".cdpr-write-test-", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        return f"{what}: cannot write in {parent}: {e.strerror or e}"
    return None


def output_file_problem(path: str | Path, what: str = "output") -> str | None:
    """Why the file ``path`` could not be written (None: it can)."""
    p = Path(path)
    if p.is_dir():
        return f"{what}: {p} is a directory, expected a file name"
    if p.exists() and not os.access(p, os.W_OK):
        return f"{what}: {p} exists and is not writable"
    return _parent_problem(p.parent if str(p.parent) else Path("."), f"{what} {p}")


def output_dir_problem(path: str | Path, what: str = "output") -> str | None:
    """Why the directory ``path`` could not be created or written in (None: it can)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        return f"{what}: {p} exists and is not a directory"
    if p.is_dir():
        return _parent_problem(p, f"{what} {p}")
    return _parent_problem(p.parent if str(p.parent) else Path("."), f"{what} {p}")


__all__ = ["output_dir_problem", "output_file_problem"]
