"""The version of cdpr-bench and the git commit it was built from (``cdpr --version``).

The commit is baked into a built wheel (``bench/_build_commit.py``, written by ``setup.py``'s
build step, never kept in the source tree); a source checkout looks it up with git at run
time; anything else says ``unknown``.
"""

from __future__ import annotations

import subprocess
import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent


def package_version() -> str:
    """The installed distribution's version, else the source tree's pyproject.toml's."""
    try:
        return version("cdpr-bench")
    except PackageNotFoundError:
        try:
            with open(_ROOT / "pyproject.toml", "rb") as f:
                return str(tomllib.load(f)["project"]["version"])
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "unknown"


def git_commit(where: Path = _ROOT) -> str | None:
    """The short commit of the git checkout holding ``where`` (``-dirty`` with local
    changes), or None outside a checkout or without git."""
    try:
        run = dict(cwd=where, capture_output=True, text=True, timeout=5, check=True)
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], **run).stdout.strip()
        if Path(top).resolve() != where.resolve():
            return None  # installed inside someone else's checkout: not our commit
        sha = subprocess.run(["git", "rev-parse", "--short=10", "HEAD"], **run).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               **run).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return sha + ("-dirty" if dirty else "") if sha else None


def build_commit() -> str:
    """The commit: baked in at build time, else git's, else ``unknown``."""
    try:
        from bench._build_commit import COMMIT  # type: ignore[import-not-found]

        return str(COMMIT)
    except ImportError:
        return git_commit() or "unknown"


def version_string() -> str:
    """``cdpr 0.1.0 (commit 1a2b3c4d5e)``."""
    return f"cdpr {package_version()} (commit {build_commit()})"
