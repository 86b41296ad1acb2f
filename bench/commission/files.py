"""Parameter files rewritten by commissioning, each time with a timestamped backup.

- :func:`set_length_at_zero` writes a winch's ``length_at_zero_m`` (referencing) into the
  winch parameter file, editing only that line of the winch's ``[[winch]]`` table (the
  comments and the other winches stay as they are), and reads the result back;
- :func:`write_calibration` writes the load-cell calibration file the HAL reads
  (:mod:`hal.loadcell_calibration`), all cables, with a comment saying what changed.

The file replaced is first copied to ``NAME.YYYYmmdd-HHMMSS.bak`` beside it; the new file
appears complete or not at all (written to a temporary file, then renamed).
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from pathlib import Path

from controller.tomlfile import read_toml
from controller.winch import WinchConfigError, WinchSet, parse_winches
from hal.loadcell_calibration import TABLE, LoadCellCalibration, parse_calibration


def backup(path: Path) -> Path | None:
    """Copy ``path`` to a timestamped ``.bak`` beside it (None when it does not exist)."""
    if not path.exists():
        return None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    dest = path.with_name(f"{path.name}.{stamp}.bak")
    n = 1
    while dest.exists():
        dest = path.with_name(f"{path.name}.{stamp}-{n}.bak")
        n += 1
    shutil.copy2(path, dest)
    return dest


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


_TABLE = re.compile(r"^\s*\[")
_KEY = re.compile(r"^(\s*)length_at_zero_m\s*=\s*([^#\n]*?)(\s*#.*)?$")
_CABLE = re.compile(r"""^\s*cable\s*=\s*["']([^"']*)["']""")
_NODE = re.compile(r"^\s*node_id\s*=")


def edit_length_at_zero(text: str, cable: str, value: float, source: str) -> str:
    """``text`` of a winch file with ``length_at_zero_m = value`` in the table of ``cable``."""
    lines = text.splitlines(keepends=True)
    starts = [i for i, ln in enumerate(lines) if ln.strip().startswith("[[winch]]")]
    for s in starts:
        end = next((j for j in range(s + 1, len(lines)) if _TABLE.match(lines[j])), len(lines))
        block = range(s + 1, end)
        if not any((m := _CABLE.match(lines[j])) and m.group(1) == cable for j in block):
            continue
        new = f"length_at_zero_m = {value!r}"
        for j in block:
            m = _KEY.match(lines[j].rstrip("\n"))
            if m:
                comment = m.group(3) or "  # set by cdpr commission home"
                nl = "\n" if lines[j].endswith("\n") else ""
                lines[j] = f"{m.group(1)}{new}{comment}{nl}"
                return "".join(lines)
        after = next((j for j in block if _NODE.match(lines[j])), s)
        if not lines[after].endswith("\n"):
            lines[after] += "\n"
        lines.insert(after + 1, f"{new}  # set by cdpr commission home\n")
        return "".join(lines)
    raise WinchConfigError(f"{source}: no [[winch]] table with cable = {cable!r}")


def set_length_at_zero(path: Path, cable: str, value: float) -> tuple[WinchSet, Path | None]:
    """Write ``length_at_zero_m`` of ``cable`` into the winch file ``path`` (backup first);
    returns the winches as read back and the backup's path."""
    text = path.read_text(encoding="utf-8")
    new_text = edit_length_at_zero(text, cable, value, str(path))
    import tomllib

    try:
        doc = tomllib.loads(new_text)
    except tomllib.TOMLDecodeError as exc:
        raise WinchConfigError(f"{path}: the edited file does not parse: {exc}") from None
    w = parse_winches(doc, str(path))
    k = w.cables.index(cable)
    if float(w.length_at_zero_m[k]) != float(value):
        raise WinchConfigError(f"{path}: cable {cable}: length_at_zero_m reads back "
                               f"{w.length_at_zero_m[k]!r}, wrote {value!r}")
    saved = backup(path)
    write_atomic(path, new_text)
    doc2, _ = read_toml(path, WinchConfigError)
    return parse_winches(doc2, str(path)), saved


def calibration_text(cal: LoadCellCalibration, note: str) -> str:
    """A calibration file: comment lines, then ``[load_cell_calibration]`` with every cable."""
    head = ["# Load-cell calibration: measured = gain * true + offset [N] (read by the HAL,",
            "# --loadcell-calibration; hal/loadcell_calibration.py).",
            f"# Written by cdpr commission on {time.strftime('%Y-%m-%d %H:%M:%S')}: {note}"]
    body = [f"[{TABLE}]"]
    for k, c in enumerate(cal.cables):
        body.append(f"gain_{c} = {float(cal.gain[k])!r}")
        body.append(f"offset_{c} = {float(cal.offset_N[k])!r}")
    return "\n".join(head) + "\n\n" + "\n".join(body) + "\n"


def write_calibration(path: Path, cal: LoadCellCalibration, note: str) -> Path | None:
    """Write the calibration file (backup of the old one first); returns the backup."""
    import tomllib

    text = calibration_text(cal, note)
    parse_calibration(tomllib.loads(text), str(path), cal.cables)  # what the HAL will read
    saved = backup(path)
    write_atomic(path, text)
    return saved
