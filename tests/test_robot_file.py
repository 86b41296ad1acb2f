"""robot.toml reading, writing and strict validation."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from controller.robot import (
    RobotFileError,
    load_robot,
    save_robot,
    shipped_robot_path,
)

GOOD = shipped_robot_path("rocaspect").read_text()


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "robot.toml"
    p.write_text(text)
    return p


def error_of(tmp_path: Path, text: str) -> str:
    with pytest.raises(RobotFileError) as e:
        load_robot(write(tmp_path, text))
    return str(e.value)


def test_shipped_descriptions_load():
    for name in ("rocaspect", "rocaspect-remeasured"):
        r = load_robot(shipped_robot_path(name))
        assert r.cable_ids == ("11", "12", "21", "22", "31", "32", "41", "42")
        assert r.mast_ids == ("1", "2", "3", "4")
        assert r.mass == 35.0
        assert np.all(r.anchors[:, :2] ** 2 == 0.25)  # corners of the 1 x 1 platform
        assert np.all(np.abs(r.anchors[:, 2]) == 0.25)


def test_round_trip_keeps_everything(tmp_path):
    r = load_robot(shipped_robot_path("rocaspect")).replace(
        stiffness=np.tile([2e5, 5e5, 3e5], (4, 1)), pulley_radius=np.full(8, 0.1),
        tilt=np.array([[0.0, 0.01, 0.0]] * 4), drum_scale=np.linspace(0.99, 1.01, 8),
        load_cell_gain=np.full(8, 1.02), rho=0.02)
    p = save_robot(r, tmp_path / "out.toml", header="written by a test\nsecond line")
    assert p.read_text().startswith("# written by a test\n# second line\n")
    back = load_robot(p)
    for f in ("exits", "anchors", "pivots", "stiffness", "pulley_radius", "tilt", "ea",
              "drum_scale", "load_cell_gain", "load_cell_offset", "length_offset", "com"):
        np.testing.assert_array_equal(getattr(back, f), getattr(r, f), err_msg=f)
    assert back.rho == 0.02 and back.tension_min == r.tension_min


def test_plain_description_has_only_format_keys(tmp_path):
    """A robot with no extension writes a plain cdpr-recording/1 robot.toml."""
    r = load_robot(shipped_robot_path("rocaspect"))
    text = save_robot(r, tmp_path / "plain.toml").read_text()
    for key in ("drum_scale", "length_offset", "load_cell", "tilt", "rho", "stiffness"):
        assert key not in text


@pytest.mark.parametrize(
    "mutate, field, message",
    [
        (lambda t: t.replace("mass = 35.0", "mass = 35.0\ncolour = 'red'"), "colour",
         "unknown key"),
        (lambda t: t.replace("tension_min = 5.0\n", ""), "tension_min", "missing field"),
        (lambda t: t.replace("exit = [0.0, 0.0, 3.565]", "exit = [0.0, 3.565]"), "exit",
         "3 numbers"),
        (lambda t: t.replace("exit = [0.0, 0.0, 3.565]", "exit = [0.0, nan, 3.565]"), "exit",
         "finite"),
        (lambda t: t.replace('id = "12"', 'id = "11"'), "id", "duplicate cable id"),
        (lambda t: t.replace('mast = "3"', 'mast = "7"', 1), "mast", "not defined"),
        (lambda t: t.replace("mass = 35.0", "mass = 'heavy'"), "mass", "number"),
        (lambda t: t.replace("tension_max = 3000.0", "tension_max = 1.0"), "tension_max",
         "exceed"),
    ],
)
def test_invalid_files_name_file_line_and_field(tmp_path, mutate, field, message):
    text = mutate(GOOD)
    assert text != GOOD
    msg = error_of(tmp_path, text)
    assert str(tmp_path / "robot.toml") in msg
    assert field in msg and message in msg
    m = re.search(r"robot\.toml:(\d+):", msg)
    assert m, msg
    line = text.splitlines()[int(m.group(1)) - 1]
    # the line named is the offending key's line (or its table header for a missing key)
    assert field in line or "[" in line or message == "missing field"


def test_too_few_cables(tmp_path):
    text = GOOD
    for cid in ("32", "41", "42"):
        start = text.index(f'id = "{cid}"')
        block_start = text.rfind("[[cable]]", 0, start)
        nxt = text.find("[[cable]]", start)
        text = text[:block_start] + (text[nxt:] if nxt >= 0 else "")
    msg = error_of(tmp_path, text)
    assert "at least 6 cables" in msg
    assert ".toml:" in msg and "[[cable]] #5" in msg  # the line of the last cable's table


def test_not_toml_and_missing_file(tmp_path):
    assert "not valid TOML" in error_of(tmp_path, "name = [")
    with pytest.raises(RobotFileError, match="cannot read"):
        load_robot(tmp_path / "nope.toml")
