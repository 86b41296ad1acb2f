"""Reading TOML files with errors that name the file (and tomllib's line and column)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any


def decode_utf8(data: bytes, path: str | Path, error: type[Exception]) -> str:
    """``data`` as UTF-8 text; ``error`` naming the file, line and column of the first byte
    that is not UTF-8 (e.g. a file saved as Latin-1)."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        col = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        raise error(f"{path}: line {line}, column {col}: not UTF-8 text (byte "
                    f"0x{data[e.start]:02X}); save the file as UTF-8") from None


def read_toml(path: str | Path, error: type[Exception]) -> tuple[dict[str, Any], str]:
    """``(data, text)`` of a TOML file; raises ``error`` naming the file when it cannot be
    read or is not valid TOML (the message then carries the line and column)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise error(f"{p}: cannot read: {e.strerror or e}") from e
    text = decode_utf8(data, p, error)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{p}: TOML syntax error, not valid TOML: {e}") from e
    big = _big_integer(data)
    if big is not None:  # TOML 1.0: integers are 64-bit; tomllib reads any size
        key, v = big
        leaf = key.rsplit(".", 1)[-1].split("[")[0]
        line = next((i + 1 for i, ln in enumerate(text.splitlines())
                     if re.match(r"^\s*" + re.escape(leaf) + r"\s*=", ln)), None)
        raise error(f"{p}" + (f":{line}" if line else "") + f": {key}: integer "
                    f"{str(v)[:20]}{'...' if len(str(v)) > 20 else ''} ({len(str(abs(v)))} "
                    "digits) is outside TOML's 64-bit range")
    return data, text


_INT64 = 2**63


def _big_integer(obj: Any, key: str = "") -> tuple[str, int] | None:
    """The first integer of a parsed TOML document outside the signed 64-bit range that
    TOML 1.0 allows, as ``(dotted key, value)``, or None."""
    if isinstance(obj, bool):
        return None
    if isinstance(obj, int):
        return (key, obj) if not -_INT64 <= obj < _INT64 else None
    if isinstance(obj, dict):
        items = ((f"{key}.{k}" if key else str(k), v) for k, v in obj.items())
    elif isinstance(obj, list):
        items = ((f"{key}[{i}]", v) for i, v in enumerate(obj))
    else:
        return None
    for k, v in items:
        hit = _big_integer(v, k)
        if hit is not None:
            return hit
    return None


#: a table header line ([name], [[name]], ["quoted"]), not a line of a multi-line array
_HEADER = re.compile(r"^\s*\[\[?\s*[A-Za-z_\"']")


class Locator:
    """Finds the line of a key in TOML text, for error messages: ``line(table, index, key)``
    for key ``key`` of ``[table]`` (``index`` None) or of the ``index``-th ``[[table]]``
    (0-based), or of the top level (``table`` None); the table's own line when the key is
    not written there, None when the table is not found."""

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()

    def _table_start(self, table: str | None, index: int | None) -> int:
        if table is None:
            return 0
        pat = re.compile(r"^\s*\[\[\s*" + re.escape(table) + r"\s*\]\]" if index is not None
                         else r"^\s*\[\s*" + re.escape(table) + r"\s*\]")
        count = -1
        for i, line in enumerate(self.lines):
            if pat.match(line):
                count += 1
                if index is None or count == index:
                    return i
        return -1

    def where(self, path: str, table: str | None = None, index: int | None = None,
              key: str | None = None) -> str:
        """``path:line: field`` of an error message (the field as ``key``, ``[table].key``
        or ``[[table]] #n.key``; the line left out when it is not found)."""
        line = self.line(table, index, key)
        head = f"{path}:{line}" if line else path
        if table is None:
            fld = key or ""
        elif index is None:
            fld = f"[{table}]" + (f".{key}" if key else "")
        else:
            fld = f"[[{table}]] #{index + 1}" + (f".{key}" if key else "")
        return f"{head}: {fld}" if fld else head

    def line(self, table: str | None, index: int | None, key: str | None) -> int | None:
        start = self._table_start(table, index)
        if start < 0:
            return None
        if key is None:
            return start + 1
        pat = re.compile(r"^\s*" + re.escape(key) + r"\s*=")
        for i in range(start + (1 if table else 0), len(self.lines)):
            line = self.lines[i]
            if (i > start or table is None) and _HEADER.match(line):
                break
            if pat.match(line):
                return i + 1
        return start + 1
