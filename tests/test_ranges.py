"""controller/ranges.py: the physical ranges as data and the one checker every loader uses;
every shipped file is within them (the checker finds nothing there)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from controller.ranges import RANGES, Range, check, lookup, problem, robot_problems

ROOT = Path(__file__).resolve().parents[1]


def test_range_bounds_sign_infinity_and_integers():
    r = Range(0.0, 10.0, "kg", lo_open=True)
    assert r.contains(10.0) and r.contains(1e-9)
    assert not r.contains(0.0) and not r.contains(10.000001) and not r.contains(math.nan)
    assert not r.contains(math.inf) and not r.contains(-math.inf)
    assert Range(0.0, 1.0, inf_ok=True).contains(math.inf)
    assert not Range(0.0, 1.0, inf_ok=True).contains(-math.inf)
    n = Range(1, 100, integer=True)
    assert n.contains(3) and not n.contains(2.5) and not n.contains(0)
    assert r.text("mass") == "0 < mass <= 10 kg"


def test_problem_names_value_range_and_meaning():
    msg = problem("robot", "platform.mass", 1e300)
    assert msg == ("1e+300 is outside the physical range 0 < mass <= 10000 kg "
                   "(a platform up to 10 t)")
    assert problem("robot", "platform.mass", 35.0) is None
    assert problem("robot", "no.such.field", 1e300) is None  # not a ranged field
    # a pose: positions [m] then angles [rad]
    assert problem("path", "start", 7.0, 3) is not None and problem("path", "start", 7.0, 0) is None
    assert problem("fault", "count", 10**30) is not None
    assert problem("fault", "count", "many").startswith("'many' is not a number")
    with pytest.raises(ValueError, match=r"^f.toml:3: at_s: -1.0 is outside"):
        check("fault", "at_s", -1.0, "f.toml:3: at_s", ValueError)


def test_patterns_and_every_range_is_well_formed():
    assert lookup("calibration", "gain_21") is lookup("calibration", "gain_*")
    assert lookup("calibration", "gain") is None
    for kind, table in RANGES.items():
        for fld, rng in table.items():
            for r in rng if isinstance(rng, tuple) else (rng,):
                assert r.lo < r.hi and math.isfinite(r.lo) and math.isfinite(r.hi), (kind, fld)


def test_every_shipped_file_is_within_the_ranges():
    """The checker finds nothing in what the project ships (robots, paths, scenarios, the
    winch file, the register map, the example recording)."""
    from bench.recording import read_recording
    from controller.loadcell_map import load_register_map
    from controller.paths import load_path, shipped_paths
    from controller.robot import SHIPPED, resolve_robot
    from controller.winch import load_winches
    from firmware_sim.loadcell_bank import REGISTER_MAP_FILE
    from firmware_sim.scenario import load_scenario

    for name in SHIPPED:
        assert robot_problems(resolve_robot(name)) == [], name
    for p in shipped_paths().values():
        load_path(p)
    scenarios = sorted((ROOT / "tests" / "data" / "scenarios").glob("*.toml"))
    scenarios += sorted((ROOT / "bench" / "data").glob("*scenario*.toml"))
    scenarios += sorted((ROOT / "bench" / "data" / "scenarios").glob("*.toml"))
    scenarios = [p for p in scenarios if 'format = "cdpr-scenario/1"' in p.read_text()]
    assert len(scenarios) > 10
    for p in scenarios:
        assert robot_problems(load_scenario(p).truth) == [], p
    for p in sorted((ROOT / "tests" / "data" / "scenarios").glob("*.toml")):
        if "[platform]" in p.read_text():  # a robot beside the scenarios
            assert robot_problems(resolve_robot(p)) == [], p
    load_winches()
    load_register_map(REGISTER_MAP_FILE)
    read_recording(ROOT / "examples" / "paper_tables")


def test_robot_problems_name_cable_mast_and_component():
    from controller.robot import resolve_robot

    r = resolve_robot("rocaspect")
    exits = r.exits.copy()
    exits[2, 1] = 5e3
    stiff = r.stiffness.copy()
    stiff[1, 0] = -1.0
    bad = robot_problems(r.replace(exits=exits, stiffness=stiff, mass=1e300))
    assert bad[0].startswith("mass: 1e+300")
    assert any(b.startswith(f"cable {r.cable_ids[2]} exit[1]: 5000.0") for b in bad)
    assert any(b.startswith(f"mast {r.mast_ids[1]} stiffness[0]: -1.0") for b in bad)
    assert len(bad) == 3
