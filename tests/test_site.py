"""The site file (``cdpr-site/1``, hal/site.py): parsing, errors with file/line/field,
the command line over the site, writing and reading back, the shipped example."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from hal.can_bus import CanSpec
from hal.cli_args import add_hardware_arguments, apply_site
from hal.site import (
    FORMAT,
    SiteError,
    check_site_files,
    dumps_site,
    load_site,
    merge_site,
    write_site,
)

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "site" / "rocaspect-site.toml"
EDS = ROOT / "firmware_sim" / "data" / "winch_drive.eds"

GOOD = f"""format = "{FORMAT}"
name = "test"
clock = "sync"

[robot]
description = "rocaspect"

[drives]
eds = "drive.eds"

[can]
interface = "socketcand:127.0.0.1:29536"

[modbus]
endpoint = "127.0.0.1:1502"

[tracker]
endpoint = "tcp:127.0.0.1:7000"

[limits]
tension_min_N = 5.0
tension_max_N = 3000.0
first_run_speed_pct = 20.0
workspace_min_m = [0.0, 0.0, 0.0]
workspace_max_m = [20.0, 17.0, 4.0]
"""


def _site(tmp_path: Path, text: str = GOOD) -> Path:
    (tmp_path / "drive.eds").write_bytes(EDS.read_bytes())
    p = tmp_path / "site.toml"
    p.write_text(text)
    return p


def test_example_site_loads_and_fits_together():
    s = load_site(EXAMPLE)
    check_site_files(s)
    assert s.can == CanSpec("socketcan", "can0") and s.bitrate == 1_000_000
    assert s.modbus.kind == "rtu" and s.modbus.baudrate == 115200 and s.modbus.parity == "E"
    assert s.tracker.host == "192.168.1.30" and s.tracker.port == 7000
    assert s.limits.first_run_speed_pct == 10.0 and s.require_stored_safety
    assert s.eds == EDS.resolve()  # relative to the site file's folder
    assert s.state_file == (EXAMPLE.parent / "rocaspect-state.toml").resolve()


def test_good_site_parses(tmp_path):
    s = load_site(_site(tmp_path))
    assert s.robot == "rocaspect" and s.clock == "sync"
    assert s.eds == (tmp_path / "drive.eds").resolve()
    assert str(s.can) == "socketcand:127.0.0.1:29536" and str(s.modbus) == "127.0.0.1:1502"
    assert s.limits.tension_min_N == 5.0 and s.limits.first_run_speed_pct == 20.0
    assert s.limits.outside_box([21.0, 5.0, 1.0]) and not s.limits.outside_box([10, 8, 1])


@pytest.mark.parametrize("old,new,line,field,words", [
    ('tension_max_N = 3000.0', 'tension_max_N = 1e300', 22, "[limits].tension_max_N",
     "(0, 100000]"),
    ('tension_max_N = 3000.0', 'tension_max_N = 2.0', 22, "[limits].tension_max_N",
     "above tension_min_N"),
    ('tension_min_N = 5.0', 'tension_min_N = nan', 21, "[limits].tension_min_N", "finite"),
    ('first_run_speed_pct = 20.0', 'first_run_speed_pct = 0', 23,
     "[limits].first_run_speed_pct", "(0, 100]"),
    ('interface = "socketcand:127.0.0.1:29536"', 'interface = "socketcand:127.0.0.1:0"', 12,
     "[can].interface", "1..65535"),
    ('interface = "socketcand:127.0.0.1:29536"', 'interface = "nonsense:x"', 12,
     "[can].interface", "unknown python-can interface"),
    ('endpoint = "127.0.0.1:1502"', 'endpoint = "127.0.0.1"', 15, "[modbus].endpoint",
     "PORT"),
    ('endpoint = "tcp:127.0.0.1:7000"', 'endpoint = "udp:1:2"', 18, "[tracker].endpoint",
     "tcp:HOST:PORT"),
    ('eds = "drive.eds"', 'eds = "missing.eds"', 9, "[drives].eds", "no such file"),
    ('clock = "sync"', 'clock = "fast"', 3, "clock", "wall, sync"),
    ('workspace_max_m = [20.0, 17.0, 4.0]', 'workspace_max_m = [20.0, 17.0, -1.0]', 25,
     "[limits].workspace_max_m", "above workspace_min_m"),
    ('first_run_speed_pct = 20.0', 'first_run_speed_pct = 20.0\nspeed = 3', 24,
     "[limits].speed", "unknown key"),
])
def test_bad_values_name_file_line_field_and_range(tmp_path, old, new, line, field, words):
    p = _site(tmp_path, GOOD.replace(old, new))
    with pytest.raises(SiteError) as e:
        load_site(p)
    msg = str(e.value)
    assert f"{p.resolve()}:{line}: {field}" in msg, msg
    assert words in msg, msg


def test_missing_tables_and_rtu_lines(tmp_path):
    with pytest.raises(SiteError, match=r"missing table \[limits\]"):
        load_site(_site(tmp_path, GOOD[:GOOD.index("[limits]")]))
    rtu = GOOD.replace('endpoint = "127.0.0.1:1502"',
                       'device = "/dev/ttyUSB0"\nbaudrate = 19200\nframing = "8O2"')
    s = load_site(_site(tmp_path, rtu))
    assert str(s.modbus) == "rtu:/dev/ttyUSB0:19200:8O2"
    bad = rtu.replace("baudrate = 19200", "baudrate = 12")
    with pytest.raises(SiteError, match=r"\[modbus\]\.baudrate = 12: .*300\.\.4000000"):
        load_site(_site(tmp_path, bad))
    both = rtu.replace('device = "/dev/ttyUSB0"', 'device = "/dev/ttyUSB0"\nendpoint = "h:1"')
    with pytest.raises(SiteError, match="either endpoint"):
        load_site(_site(tmp_path, both))
    with pytest.raises(SiteError, match="not valid TOML"):
        load_site(_site(tmp_path, GOOD + "\n[limits\n"))


def test_bitrate_must_match_the_winch_file(tmp_path):
    s = load_site(_site(tmp_path, GOOD.replace('29536"', '29536"\nbitrate = 500000')))
    with pytest.raises(SiteError, match=r":13: \[can\]\.bitrate = 500000: .*bitrate = 1000000"):
        check_site_files(s)
    check_site_files(load_site(_site(tmp_path)))  # and without one: fine


def test_command_line_wins_over_the_site(tmp_path):
    site = _site(tmp_path)
    p = argparse.ArgumentParser()
    add_hardware_arguments(p, tracker=True)
    # the site's values where the command line gives none
    st = apply_site(args := p.parse_args(["--site", str(site)]))
    assert str(args.can) == "socketcand:127.0.0.1:29536" and args.hal_clock == "sync"
    assert str(args.modbus) == "127.0.0.1:1502" and str(args.tracker) == "tcp:127.0.0.1:7000"
    assert args.eds == str((tmp_path / "drive.eds").resolve()) and st.site is not None
    # the command line's over the site's, spelled as everywhere
    args = p.parse_args(["--site", str(site), "--can", "virtual:x", "--modbus",
                         "127.0.0.1:9", "--tracker", "none", "--hal-clock", "wall",
                         "--eds", str(EDS)])
    st = apply_site(args)
    assert args.can == CanSpec("virtual", "x") and str(args.modbus) == "127.0.0.1:9"
    assert args.tracker is None and args.hal_clock == "wall" and args.eds == str(EDS)
    # no site: the defaults as before; no EDS known: refused
    with pytest.raises(ValueError, match="no EDS"):
        apply_site(p.parse_args(["--can", "virtual:x"]))
    args = p.parse_args(["--can", "virtual:x", "--eds", str(EDS)])
    assert apply_site(args).site is None and args.hal_clock == "wall" and args.tracker is None
    # a bad site: the error, nothing opened
    with pytest.raises(SiteError, match="format"):
        apply_site(p.parse_args(["--site", str(_site(tmp_path, GOOD.replace(FORMAT, "x")))]))


def test_bitrate_goes_to_interfaces_that_take_it(tmp_path):
    text = GOOD.replace('"socketcand:127.0.0.1:29536"', '"pcan:PCAN_USBBUS1"\nbitrate = 500000')
    st = merge_site(load_site(_site(tmp_path, text)))
    assert st.can.bus_kwargs()["bitrate"] == 500000
    st = merge_site(load_site(_site(tmp_path, GOOD.replace('29536"', '29536"\nbitrate = '
                                                                     '500000'))))
    assert "bitrate" not in st.can.bus_kwargs()  # the hub's bit rate is not ours to set


def test_write_site_round_trip(tmp_path):
    s = load_site(EXAMPLE)
    out = write_site(s, tmp_path / "copy.toml")  # paths outside its folder: absolute
    back = load_site(out)
    for name in ("name", "robot", "eds", "winches", "loadcell_map", "can", "bitrate", "modbus",
                 "tracker", "clock", "limits", "require_stored_safety", "require_tracker",
                 "state_file"):
        assert getattr(back, name) == getattr(s, name), name
    assert "format = \"cdpr-site/1\"" in dumps_site(s)


# ---------------------------------------------------------------------------- preflight


class _Tracker:
    """A tracker that gives one reading (``valid``)."""

    def __init__(self, valid: bool) -> None:
        self.valid = valid

    def wait_fresh(self, timeout_s: float):
        import numpy as np

        from hal.tracker import TrackerReading

        pose = np.array([10.0, 8.5, 1.2, 0, 0, 0]) if self.valid else np.full(6, np.nan)
        return TrackerReading(0.0, pose, self.valid, 0.0)


def _readings(tensions, window=(20.0, 2500.0), tracker=True, require_tracker=True,
              fault=None):
    from bench.dryrun.preflight import check_readings
    from hal.fake import FakeHardware

    hw = FakeHardware(tensions_N=tensions)
    hw.start()
    if fault is not None:
        hw.inject_loadcell_fault(*fault)
    return check_readings(hw, _Tracker(tracker) if tracker is not None else None, window,
                          require_tracker=require_tracker)


def test_preflight_readings_find_nothing_on_a_healthy_robot():
    pf = _readings([200.0, 210, 190, 205, 220, 180, 200, 199])
    assert pf.ok and not pf.problems and not pf.warnings, pf.problems
    assert [c["status"] for c in pf.load_cells] == ["ok"] * 8 and pf.tracker["locked"]
    assert _readings(20.0).ok and _readings(2500.0).ok  # the window's edges are in it


def test_preflight_readings_name_slack_overload_silent_cells_and_the_tracker():
    pf = _readings([200.0, 5.0, 200, 200, 200, 3000.0, 200, 200])
    assert [c["status"] for c in pf.load_cells] == ["ok", "slack", "ok", "ok", "ok",
                                                    "overload", "ok", "ok"]
    assert any("cable 12: tension 5.0 N outside the site's window [20, 2500] N (slack)" in p
               for p in pf.problems) and len(pf.problems) == 2
    pf = _readings(200.0, fault=("31", "timeout"))
    assert pf.problems == ["load cell Modbus unit 5 (cable 31): timeout"]
    assert "no valid fix" in _readings(200.0, tracker=False).problems[0]
    pf = _readings(200.0, tracker=False, require_tracker=False)
    assert pf.ok and "no valid fix" in pf.warnings[0]
    assert "no tracker" in _readings(200.0, tracker=None).problems[0]
