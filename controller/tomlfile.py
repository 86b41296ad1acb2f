"""Reading TOML files with errors that name the file (and tomllib's line and column)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any


def read_toml(path: str | Path, error: type[Exception]) -> tuple[dict[str, Any], str]:
    """``(data, text)`` of a TOML file; raises ``error`` naming the file when it cannot be
    read or is not valid TOML (the message then carries the line and column)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise error(f"{p}: cannot read: {e.strerror or e}") from e
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as e:
        raise error(f"{p}: TOML syntax error, not valid TOML: {e}") from e
