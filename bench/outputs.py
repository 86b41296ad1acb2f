"""Output paths checked before the work starts: a command that will write a file or a
directory says at once, naming the path and why, when it could not, instead of failing
(with a traceback) after minutes of work.

:func:`output_file_problem` and :func:`output_dir_problem` return None when the path can
be written, else the message; they create missing parent directories (as the writers
would) and leave nothing else behind.

The directories they create are appended to ``created`` when the caller passes a list: a
command that then fails before writing into them calls :func:`remove_created` (or runs in
:func:`removing_created`) and leaves no trace of them (only empty directories are removed,
deepest first).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def make_dirs(path: str | Path, created: list[Path] | None = None) -> None:
    """``mkdir -p path``, appending the directories it made (outermost first) to
    ``created``; raises OSError (what it made before failing is removed)."""
    p = Path(path)
    missing = []
    q = p
    while not q.exists() and q != q.parent:
        missing.append(q)
        q = q.parent
    missing.reverse()
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError:
        remove_created(missing)
        raise
    if created is not None:
        created.extend(missing)


def remove_created(created: list[Path]) -> None:
    """Remove the directories in ``created`` that are still empty, deepest first (a command
    that failed before writing into the directories it made for its outputs)."""
    for d in sorted({Path(c) for c in created}, key=lambda c: len(c.parts), reverse=True):
        try:
            d.rmdir()  # only an empty directory
        except OSError:
            pass


def removing_created(run: Callable[[list[Path]], int]) -> int:
    """``run(created)`` (a command that appends the directories it makes for its outputs to
    ``created``), then, unless it returned 0, :func:`remove_created` (also when it raised,
    Ctrl-C included); returns its exit status."""
    created: list[Path] = []
    code = 1
    try:
        code = run(created)
    finally:
        if code != 0:
            remove_created(created)
    return code


def _parent_problem(parent: Path, what: str, created: list[Path] | None = None) -> str | None:
    made: list[Path] = []
    try:
        make_dirs(parent, made)
    except FileExistsError:
        return f"{what}: {parent} exists and is not a directory"
    except OSError as e:
        return f"{what}: cannot create the directory {parent}: {e.strerror or e}"
    problem = None
    if not parent.is_dir():
        problem = f"{what}: {parent} is not a directory"
    else:
        try:  # the only honest test of writability (ACLs, read-only mounts, root)
            fd, probe = tempfile.mkstemp(prefix=".cdpr-write-test-", dir=parent)
            os.close(fd)
            os.unlink(probe)
        except OSError as e:
            problem = f"{what}: cannot write in {parent}: {e.strerror or e}"
    if problem is not None:
        remove_created(made)
    elif created is not None:
        created.extend(made)
    return problem


def output_file_problem(path: str | Path, what: str = "output",
                        created: list[Path] | None = None) -> str | None:
    """Why the file ``path`` could not be written (None: it can). The missing parent
    directories are created (and appended to ``created``)."""
    p = Path(path)
    if p.is_dir():
        return f"{what}: {p} is a directory, expected a file name"
    if p.exists() and not os.access(p, os.W_OK):
        return f"{what}: {p} exists and is not writable"
    if p.exists() and not p.is_file():  # /dev/stdout, a pipe: written in place
        return None
    return _parent_problem(p.parent if str(p.parent) else Path("."), f"{what} {p}", created)


def output_dir_problem(path: str | Path, what: str = "output",
                       created: list[Path] | None = None) -> str | None:
    """Why the directory ``path`` could not be created or written in (None: it can). Its
    missing parent directories are created (and appended to ``created``)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        return f"{what}: {p} exists and is not a directory"
    if p.is_dir():
        return _parent_problem(p, f"{what} {p}", created)
    return _parent_problem(p.parent if str(p.parent) else Path("."), f"{what} {p}", created)


def write_text_file(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` so that a reader never sees half a file: a regular
    file (or a new one) is written beside and renamed over it; a path that exists and is
    not a regular file (``/dev/stdout``, a named pipe) is written in place, never replaced.
    Raises OSError naming the path."""
    p = Path(path)
    try:
        if p.exists() and not p.is_file():
            with open(p, "w", encoding="utf-8") as f:
                f.write(text)
            return
        tmp = p.with_name(f".{p.name}.tmp")
        try:
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, p)
        finally:
            tmp.unlink(missing_ok=True)
    except OSError as e:
        raise OSError(f"{p}: cannot write: {e.strerror or e}") from e


__all__ = ["make_dirs", "output_dir_problem", "output_file_problem", "remove_created",
           "removing_created", "write_text_file"]
