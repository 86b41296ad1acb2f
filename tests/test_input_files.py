"""Input from outside (issue 9): files that are not UTF-8, options out of range, output paths
that cannot be written, a mast no cable uses; then fuzzing from valid examples. Each gives a
clear error naming the file (line, field), never a traceback.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.cli import main
from bench.recording import RecordingError, read_recording
from controller.loadcell_map import RegisterMapError, load_register_map
from controller.robot import RobotFileError, load_robot
from controller.winch import DEFAULT_WINCHES, WinchConfigError, load_winches
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.faults import FaultSchedule, FaultScheduleError
from firmware_sim.loadcell_bank import REGISTER_MAP_FILE
from firmware_sim.scenario import ScenarioError, load_scenario
from hal.drives_config import DriveConfigError, load_eds
from hal.loadcell_calibration import CalibrationError, load_calibration

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "controller" / "data" / "rocaspect.toml"
SCENARIO = ROOT / "tests" / "data" / "scenarios" / "paper.toml"
RECORDING = ROOT / "examples" / "paper_tables"
CALIBRATION = b"[load_cell_calibration]\ngain_11 = 1.02\noffset_11 = -4.0\n"
SCHEDULE = b'[[fault]]\nat_s = 1.0\ndrive = 3\nkind = "encoder"\n'

LOADERS = {
    "robot.toml": (ROBOT.read_bytes(), load_robot, RobotFileError),
    "scenario.toml": (SCENARIO.read_bytes(), load_scenario, ScenarioError),
    "registers.toml": (REGISTER_MAP_FILE.read_bytes(), load_register_map, RegisterMapError),
    "calibration.toml": (CALIBRATION, load_calibration, CalibrationError),
    "winches.toml": (DEFAULT_WINCHES.read_bytes(), load_winches, WinchConfigError),
    "faults.toml": (SCHEDULE, FaultSchedule.load, FaultScheduleError),
    "drive.eds": (EDS_PATH.read_bytes(), lambda p: load_eds(p, 1), DriveConfigError),
}


def latin1(data: bytes) -> tuple[bytes, int]:
    """``data`` with a Latin-1 'é' in a comment on its third line; (bytes, that line)."""
    lines = data.split(b"\n")
    comment = b";" if lines[0].startswith(b";") or b"[FileInfo]" in data else b"#"
    lines.insert(2, comment + b" r\xe9glage")
    return b"\n".join(lines), 3


@pytest.mark.parametrize("name", sorted(LOADERS))
def test_loaders_read_their_example(tmp_path, name):
    data, load, _ = LOADERS[name]
    p = tmp_path / name
    p.write_bytes(data)
    load(p)  # the valid example loads: the cases below differ only by what they break


@pytest.mark.parametrize("name", sorted(LOADERS))
def test_a_file_that_is_not_utf8_is_named_with_its_line(tmp_path, name):
    data, load, error = LOADERS[name]
    bad, line = latin1(data)
    p = tmp_path / name
    p.write_bytes(bad)
    with pytest.raises(error) as exc:
        load(p)
    msg = str(exc.value)
    assert str(p) in msg and f"line {line}, column 4: not UTF-8" in msg, msg


def test_a_recording_that_is_not_utf8(tmp_path):
    for name, line in (("meta.toml", 3), ("recording.csv", 3), ("robot.toml", 3)):
        d = tmp_path / name.replace(".", "_")
        shutil.copytree(RECORDING, d)
        data = (d / name).read_bytes().split(b"\n")
        data[2] = data[2] + b"\xe9" if name == "recording.csv" else b"# \xe9t\xe9"
        (d / name).write_bytes(b"\n".join(data))
        with pytest.raises(RecordingError) as exc:
            read_recording(d)
        assert f"{name}: line {line}" in str(exc.value), str(exc.value)


def _cli(*args: str) -> tuple[int, str, str]:
    out = subprocess.run([sys.executable, "-m", "bench.cli", *args], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    return out.returncode, out.stdout, out.stderr


def test_commands_name_a_non_utf8_file_without_traceback(tmp_path):
    robot, _ = latin1(ROBOT.read_bytes())
    (tmp_path / "robot.toml").write_bytes(robot)
    rc, _, err = _cli("model", "check", str(tmp_path / "robot.toml"))
    assert rc == 2 and "robot.toml: line 3, column 4: not UTF-8" in err
    assert "Traceback" not in err
    scenario, _ = latin1(SCENARIO.read_bytes())
    (tmp_path / "sc.toml").write_bytes(scenario)
    rc, _, err = _cli("sim", str(tmp_path / "sc.toml"))
    assert rc == 2 and "sc.toml: line 3, column 4: not UTF-8" in err and "Traceback" not in err


def test_a_mast_no_cable_uses_is_named(tmp_path, capsys):
    text = ROBOT.read_text().replace("[[cable]]", '[[mast]]\nid = "5"\npivot = [12.0, 9.0, 0.0]'
                                     "\n\n[[cable]]", 1)
    p = tmp_path / "five.toml"
    p.write_text(text)
    line = text.split("\n").index('id = "5"') + 1
    assert main(["model", "check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"five.toml:{line}" in err and "no cable uses mast '5'" in err


@pytest.mark.parametrize(("option", "needle"), [
    (["--step", "0"], "--step 0.0: the grid step must be a positive number"),
    (["--step", "-1"], "--step -1.0: the grid step must be a positive number"),
    (["--step", "nan"], "--step nan"),
    (["--height", "nan"], "--height nan: must be a finite height"),
    (["--height", "inf"], "--height inf: must be a finite height"),
    (["--step", "1e-5"], "take a coarser step"),
])
def test_model_check_refuses_options_out_of_range(capsys, option, needle):
    assert main(["model", "check", "rocaspect", *option]) == 2
    err = capsys.readouterr().err
    assert needle in err
    assert main(["model", "check", "rocaspect", "--json", *option]) == 2
    assert json.loads(capsys.readouterr().out)["valid"] is False


def test_output_paths_are_checked_before_the_work(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    assert main(["model", "check", "rocaspect", "--plot", str(blocker / "ws.png")]) == 2
    assert "--plot" in capsys.readouterr().err
    assert main(["model", "check", "rocaspect", "--plot", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    rc, _, err = _cli("campaign", str(SCENARIO), str(blocker / "rec"))
    assert rc == 2 and "OUT_DIR" in err and "a_file" in err and "Traceback" not in err


def test_diagnose_outputs_are_probed_by_a_real_write(tmp_path, capsys):
    """Permission bits lie (/proc, read-only mounts, root): the outputs are probed by a real
    write before the fit, and the refusal names the option and the path."""
    from bench.diagnosis.report import prepare_outputs

    with pytest.raises(OSError, match="--write-model /proc/m.toml"):
        prepare_outputs("/proc/m.toml")
    with pytest.raises(OSError, match="--plots"):
        prepare_outputs(None, "/proc/plots")
    prepare_outputs(tmp_path / "new" / "m.toml", tmp_path / "plots")  # creatable: fine
    rc = main(["diagnose", str(tmp_path), "--json", "--out", "/proc/r.json"])
    assert rc == 2 and "--out" in json.loads(capsys.readouterr().out)["error"]


def test_report_files_are_written_whole_and_special_files_kept(tmp_path):
    from bench.outputs import write_text_file

    f = tmp_path / "r.json"
    write_text_file(f, "one")
    write_text_file(f, "two")
    assert f.read_text() == "two" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
    # a special file is written in place, never renamed over; a failed write says so
    with pytest.raises(OSError, match="/dev/full: cannot write"):
        write_text_file("/dev/full", "x" * 100_000)
    assert Path("/dev/full").is_char_device()
    write_text_file("/dev/null", "fine")
    assert Path("/dev/null").is_char_device()


def test_compare_names_a_report_that_is_not_utf8(tmp_path, capsys):
    bad = tmp_path / "report.json"
    bad.write_bytes(b'{"format": "cdpr-diagnosis/1", "x": "\xff\xfe"}'.replace(b"\\x", b"\\x")
                    + b"\xff")
    rc = main(["compare", str(SCENARIO), str(bad), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 2 and "not UTF-8" in out["error"] and "report.json" in out["error"]


# ---------------------------------------------------------------------------- fuzzing

FUZZ = settings(settings.default, max_examples=max(20, settings.default.max_examples),
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow], deadline=None)

_values = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.lists(st.floats(allow_nan=True), max_size=4),
                    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))


def _paths(doc, prefix=()):
    """Every (path) to a value of a parsed TOML document."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield (*prefix, k)
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield (*prefix, i)
            yield from _paths(v, (*prefix, i))


def _mutate(doc, path, how, value):
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    key = path[-1]
    if how == "delete":
        del parent[key]
    elif how == "replace":
        parent[key] = value
    else:  # "add": a sibling key nobody knows
        if isinstance(parent, dict):
            parent[f"zz_{key}"] = value
        else:
            parent.append(value)


def _toml_safe(v):
    if v is None:
        return "null"
    if isinstance(v, list):
        return [_toml_safe(x) for x in v if x is not None]
    if isinstance(v, dict):
        return {k: _toml_safe(x) for k, x in v.items() if x is not None}
    return v


TOML_EXAMPLES = {k: LOADERS[k] for k in ("robot.toml", "scenario.toml", "registers.toml",
                                         "calibration.toml", "winches.toml", "faults.toml")}


@pytest.mark.parametrize("name", sorted(TOML_EXAMPLES))
@FUZZ
@given(data=st.data())
def test_fuzzed_toml_files_give_clear_errors(tmp_path, name, data):
    """Structure-aware mutations of the valid example: a key deleted, a value replaced by
    anything TOML can hold, an unknown key added. It loads, or raises its error class
    naming the file; never anything else."""
    raw, load, error = TOML_EXAMPLES[name]
    doc = tomllib.loads(raw.decode())
    paths = list(_paths(doc))
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        if not paths:
            break
        path = data.draw(st.sampled_from(paths), label="path")
        how = data.draw(st.sampled_from(["delete", "replace", "add"]), label="how")
        _mutate(doc, path, how, _toml_safe(data.draw(_values, label="value")))
        paths = list(_paths(doc))
    p = tmp_path / name
    p.write_text(tomli_w.dumps(doc))
    try:
        load(p)
    except error as exc:
        assert str(p) in str(exc), str(exc)


@pytest.mark.parametrize("name", sorted(LOADERS))
@FUZZ
@given(data=st.data())
def test_fuzzed_bytes_give_clear_errors(tmp_path, name, data):
    """Byte-level damage (a byte changed, a slice cut out or repeated): loads or raises the
    loader's error naming the file."""
    raw, load, error = LOADERS[name]
    buf = bytearray(raw)
    for _ in range(data.draw(st.integers(1, 4), label="damages")):
        i = data.draw(st.integers(0, len(buf) - 1), label="at")
        how = data.draw(st.sampled_from(["byte", "cut", "repeat"]), label="how")
        if how == "byte":
            buf[i] = data.draw(st.integers(0, 255), label="byte")
        elif how == "cut":
            del buf[i:i + data.draw(st.integers(1, 40), label="n")]
        else:
            buf[i:i] = buf[i:i + data.draw(st.integers(1, 40), label="n")]
        if not buf:
            buf = bytearray(b"x")
    p = tmp_path / name
    p.write_bytes(bytes(buf))
    try:
        load(p)
    except error as exc:
        assert str(p) in str(exc), str(exc)


@FUZZ
@given(data=st.data())
def test_fuzzed_recordings_give_clear_errors(tmp_path_factory, data):
    """A recording's CSV damaged cell by cell, row by row: it reads, or RecordingError
    names the file (and the line); nothing else."""
    d = tmp_path_factory.mktemp("rec")
    shutil.copytree(RECORDING, d, dirs_exist_ok=True)
    csv_path = d / "recording.csv"
    lines = csv_path.read_text().split("\n")
    for _ in range(data.draw(st.integers(1, 4), label="damages")):
        i = data.draw(st.integers(0, len(lines) - 1), label="line")
        cells = lines[i].split(",")
        how = data.draw(st.sampled_from(["cell", "drop", "extra", "line", "header"]),
                        label="how")
        if how == "cell":
            j = data.draw(st.integers(0, len(cells) - 1), label="cell")
            cells[j] = data.draw(st.sampled_from(["", "nan", "inf", "-inf", "x", "1e999",
                                                  "0x10", '"1,2"', "1.5.2", " 3 "]),
                                 label="value")
        elif how == "drop":
            cells = cells[:-1]
        elif how == "extra":
            cells.append("1")
        elif how == "line":
            lines.insert(i, data.draw(st.text(max_size=20), label="text"))
        else:
            lines[0] = lines[0].replace(",", ",tau_99,", 1)
        if how != "line":
            lines[i] = ",".join(cells)
    csv_path.write_text("\n".join(lines))
    try:
        read_recording(d)
    except RecordingError as exc:
        assert "recording.csv" in str(exc) or "meta.toml" in str(exc), str(exc)


def test_fuzz_helpers_mutate():
    doc = {"a": [1, {"b": 2}]}
    _mutate(doc, ("a", 1, "b"), "delete", None)
    assert doc == {"a": [1, {}]}
    assert math.isnan(_toml_safe(float("nan")))


# ------------------------------------------------- non-physical numbers (issue 31, item 5)

PATH_EXAMPLE = b'''format = "cdpr-path/1"
name = "every-kind"
start = [10.0, 8.56, 1.2, 0.0, 0.0, 0.0]
repeat = 2

[limits]
max_speed_m_s = 0.5
speed_pct = 40.0
max_accel_m_s2 = 0.5

[[segment]]
kind = "move"
to = [10.0, 8.56, 1.0, 0.0, 0.0, 0.05]

[[segment]]
kind = "line"
through = [[10.0, 9.56, 1.0], [10.0, 9.56, 0.8]]

[[segment]]
kind = "circle"
center = [10.0, 8.56, 0.8]
normal = [0.0, 0.0, 1.0]
angle_deg = 90.0

[[segment]]
kind = "dwell"
duration_s = 1.5

[[segment]]
kind = "visits"
x = [9.0, 11.0]
y = [8.0, 9.0]
z = [0.9, 1.1]
n = [2, 2, 1]
rpy_deg = 1.0
visits = 2
dwell_s = 0.5
order = "shuffle"
seed = 3

[[segment]]
kind = "visits"
poses = [[10.0, 8.56, 1.0, 0.0, 0.0, 0.0]]
'''
FAULTS_EXAMPLE = b'''[[fault]]
at_s = 1.0
drive = 3
kind = "drop_tpdo"
count = 5
clear_s = 4.0

[[fault]]
at_s = 2.0
cell = 5
kind = "out_of_range"
value_N = 6000.0
clear_s = 3.0
'''


def _load_path(p):
    from controller.paths import load_path

    return load_path(p)


def _path_error():
    from controller.paths import PathFileError

    return PathFileError


def _recording_with(name: str):
    """A loader of a recording whose file ``name`` (meta.toml, robot.toml) is the one given:
    the recording's other files are copied beside it, then the folder is read."""

    def load(p: Path):
        for f in ("meta.toml", "robot.toml", "recording.csv"):
            if f != name:
                shutil.copy(RECORDING / f, p.parent / f)
        return read_recording(p.parent)

    return load


#: file kind -> (a valid example with every numeric field of the kind, loader, error class)
PHYSICAL = {
    "meta.toml": ((RECORDING / "meta.toml").read_bytes(), _recording_with("meta.toml"),
                  RecordingError),
    "recorded robot.toml": ((RECORDING / "robot.toml").read_bytes(),
                            _recording_with("robot.toml"), RecordingError),
    "robot.toml": LOADERS["robot.toml"],
    "scenario.toml": LOADERS["scenario.toml"],
    "path.toml": (PATH_EXAMPLE, _load_path, _path_error()),
    "faults.toml": (FAULTS_EXAMPLE, FaultSchedule.load, FaultScheduleError),
    "registers.toml": LOADERS["registers.toml"],
    "calibration.toml": LOADERS["calibration.toml"],
    "winches.toml": LOADERS["winches.toml"],
}

#: no physical number of any field is any of these (+inf is a rigid mast axis: allowed there)
NON_PHYSICAL = (math.nan, math.inf, -math.inf, 1e300, -1e300, 1e30, -1e30, 10**30, -(10**30))

#: fields whose sign is physics: a negative value is not a robot, a noise, a time, a count
SIGNED = {"mass", "tension_max", "ea", "rho", "pulley_radius", "drum_scale", "load_cell_gain",
          "tracker_m", "tracker_rad", "load_cell_n", "encoder_m", "process_m", "exit_m",
          "hysteresis_m", "at_s", "clear_s", "count", "duration_s", "dwell_s", "visits",
          "gear_ratio", "drum_radius_m", "max_speed_m_s", "max_accel_m_s2", "speed_pct",
          "quick_stop_decel_m_s2", "following_error_m", "rated_torque_nm", "rated_max_N",
          "repeat", "n", "rpy_deg"}


def _numbers(doc, prefix=()):
    """Every path to a number (not a bool) of a parsed TOML document, with its leaf key
    (the table key of a vector component)."""
    for path in _paths(doc):
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        v = parent[path[-1]]
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            leaf = next(k for k in reversed(path) if isinstance(k, str))
            yield path, leaf


def _non_physical(leaf: str, value) -> bool:
    """Whether ``value`` may be refused for a field ``leaf`` (+inf of a stiffness is a
    rigid axis, a physical value)."""
    return not (leaf in ("stiffness", "k") and value == math.inf)


def _write_doc(p: Path, doc) -> None:
    p.write_text(tomli_w.dumps(doc))


def _refused(load, error, p: Path, what: str) -> str:
    """``load(p)`` must raise ``error`` naming the file (no traceback, no acceptance)."""
    try:
        load(p)
    except error as exc:
        msg = str(exc)
        assert str(p) in msg, msg
        return msg
    raise AssertionError(f"{what}: accepted")


@pytest.mark.parametrize("name", sorted(PHYSICAL))
@FUZZ
@given(data=st.data())
def test_non_physical_numbers_are_refused_in_every_file_kind(tmp_path, name, data):
    """A number of the valid example (any field, any vector component) replaced by a value
    no robot, bench or schedule can mean (nan, inf, 1e300, 1e30, a 31-digit integer, a
    negative value where the sign is physics): the loader refuses it with its own error
    class naming the file; never a traceback, never acceptance."""
    raw, load, error = PHYSICAL[name]
    doc = tomllib.loads(raw.decode())
    path, leaf = data.draw(st.sampled_from(list(_numbers(doc))), label="field")
    values = list(NON_PHYSICAL) + ([-35.0, -1e-3] if leaf in SIGNED else [])
    huge = st.floats(1e19, 1e308) | st.floats(-1e308, -1e19)  # beyond every field's range
    value = data.draw((st.sampled_from(values) | huge).filter(lambda v: _non_physical(leaf, v)),
                      label="value")
    _mutate(doc, path, "replace", value)
    p = tmp_path / name.split()[-1]
    _write_doc(p, doc)
    _refused(load, error, p, f"{name}: {'.'.join(map(str, path))} = {value!r}")


@pytest.mark.parametrize("name", sorted(PHYSICAL))
def test_every_numeric_field_refuses_1e300_nan_and_huge_integers(tmp_path, name):
    """The exhaustive sweep of the property above for three values: every numeric field of
    every file kind, one at a time."""
    raw, load, error = PHYSICAL[name]
    fields = list(_numbers(tomllib.loads(raw.decode())))
    assert fields
    for value in (1e300, math.nan, 10**30):
        for path, _leaf in fields:
            doc = tomllib.loads(raw.decode())
            _mutate(doc, path, "replace", value)
            p = tmp_path / name.split()[-1]
            _write_doc(p, doc)
            _refused(load, error, p, f"{name}: {'.'.join(map(str, path))} = {value!r}")


def test_a_range_error_names_file_line_field_value_and_range(tmp_path, capsys):
    text = ROBOT.read_text()
    p = tmp_path / "heavy.toml"
    p.write_text(text.replace("mass = 35.0", "mass = 1e300", 1))
    line = p.read_text().split("\n").index("mass = 1e300") + 1
    assert main(["model", "check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"heavy.toml:{line}: [platform].mass: 1e+300" in err
    assert "0 < mass <= 10000 kg" in err
    # an exit point 1 Mm away: named, not a 300-digit grid count
    p.write_text(text.replace("exit = [0.0, 0.0, 3.565]", "exit = [1e300, 0.0, 3.565]", 1))
    assert main(["model", "check", str(p)]) == 2
    err = capsys.readouterr().err
    assert "[[cable]] #1.exit[0]: 1e+300 is outside the physical range" in err
    assert len(err) < 400


def test_gravity_off_the_earth_must_be_said(tmp_path):
    text = ROBOT.read_text()
    p = tmp_path / "moon.toml"
    p.write_text(text.replace("gravity = 9.81", "gravity = 1.62", 1))
    assert "9.76 <= gravity <= 9.84" in _refused(load_robot, RobotFileError, p, "moon")
    p.write_text(text.replace("gravity = 9.81", "gravity = 1.62\ngravity_unusual = true", 1))
    robot = load_robot(p)
    assert robot.gravity == 1.62
    from controller.robot import dumps_robot

    assert "gravity_unusual = true" in dumps_robot(robot)  # written back, so it reads again


@pytest.mark.parametrize("value", [1e300, -1e300, math.nan, 10**30])
def test_recording_meta_and_robot_numbers_are_refused(tmp_path, value):
    d = tmp_path / "rec"
    shutil.copytree(RECORDING, d)
    meta = tomllib.loads((d / "meta.toml").read_text())
    meta["init_pose"][0] = value
    (d / "meta.toml").write_text(tomli_w.dumps(meta))
    assert "meta.toml" in _refused(read_recording, RecordingError, d, "init_pose")
    shutil.copy(RECORDING / "meta.toml", d / "meta.toml")
    robot = tomllib.loads((d / "robot.toml").read_text())
    robot["platform"]["mass"] = value
    (d / "robot.toml").write_text(tomli_w.dumps(robot))
    assert "robot.toml" in _refused(read_recording, RecordingError, d, "robot mass")


@pytest.mark.parametrize(("key", "name", "why"), [
    ("robot", "/etc/passwd", "absolute path"),
    ("robot", "../../../../../../etc/passwd", "leads out of the recording's folder"),
    ("samples", "/etc/passwd", "absolute path"),
    ("samples", "../outside.csv", "leads out of the recording's folder"),
    ("robot", "link.toml", "leads out of the recording's folder"),
    ("robot", 3, "must be a file name"),
])
def test_files_named_by_a_recording_stay_inside_its_folder(tmp_path, key, name, why):
    d = tmp_path / "rec"
    shutil.copytree(RECORDING, d)
    (tmp_path / "outside.csv").write_text("secret,content\n1,2\n")
    (d / "link.toml").symlink_to("/etc/passwd")
    meta = tomllib.loads((d / "meta.toml").read_text())
    meta[key] = name
    (d / "meta.toml").write_text(tomli_w.dumps(meta))
    msg = _refused(read_recording, RecordingError, d, f"{key} = {name!r}")
    assert why in msg and "meta.toml:" in msg and key in msg
    assert "root:" not in msg and "secret" not in msg  # nothing of the foreign file quoted


def test_ranges_documentation_is_generated_from_the_table():
    from controller.ranges import markdown

    doc = (ROOT / "docs" / "reference" / "validation.md").read_text()
    assert markdown() in doc, "docs/reference/validation.md: regenerate the ranges table " \
        "(python -m controller.ranges > ...; see the page)"
