"""The documentation: the site builds with warnings as errors, the command reference covers
every option, every format page's example loads with the project's own reader, the README
stays short and points where a new user looks, nothing refers to files outside the
repository, and the benchmarks page is the generator's output."""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SNIPPET = re.compile(r'^--8<-- "([^"]+)"\s*$', re.M)


def _hooks():
    spec = importlib.util.spec_from_file_location("cdpr_docs_hooks", DOCS / "hooks.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _mkdocs_missing() -> str | None:
    for name in ("mkdocs", "material"):
        if importlib.util.find_spec(name) is None:
            return f"{name} is not installed (pip install -e '.[dev]' or '.[docs]')"
    return None


# ------------------------------------------------------------------------------ the site


def test_site_builds_with_warnings_as_errors(tmp_path):
    missing = _mkdocs_missing()
    if missing:
        pytest.skip(missing)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"}
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f",
                        str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    page = (tmp_path / "site" / "reference" / "commands" / "index.html").read_text()
    from bench.cli import COMMANDS

    for modname in COMMANDS:
        name = importlib.import_module(modname).NAME
        assert f"cdpr {name}" in page, name
    assert not (tmp_path / "site" / "hooks.py").exists()


def test_every_nav_page_exists():
    """The nav names each page the other branches write too (placeholders here)."""
    text = (ROOT / "mkdocs.yml").read_text()
    pages = re.findall(r":\s+([\w/.-]+\.md)\s*$", text, re.M)
    assert len(pages) >= 25
    for page in pages:
        if page == "reference/commands.md":  # written by the hook at build time
            assert not (DOCS / page).exists(), "the command reference must stay generated"
            continue
        assert (DOCS / page).is_file(), page


def _options(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for p in action.choices.values():
                yield from _options(p)
        elif not isinstance(action, argparse._HelpAction):  # -h: said once, not per command
            yield from action.option_strings


def test_command_reference_covers_every_option_of_the_parser():
    from bench.cli import build_parser

    page = _hooks().commands_page()
    opts = set(_options(build_parser("")))
    assert {"--json", "--record", "--faults", "--write-model"} <= opts
    for opt in opts:
        assert f"`{opt}" in page or f", {opt}" in page, opt
    assert str(ROOT) not in page  # defaults shown relative to the repository


def test_command_reference_follows_the_parser(monkeypatch):
    """A new option appears on the page without anyone editing it."""
    import bench.commands.model as model

    add = model.add_arguments

    def more(p):
        add(p)
        p.add_argument("--brand-new-flag", help="a flag the page never heard of")

    monkeypatch.setattr(model, "add_arguments", more)
    assert "| `--brand-new-flag BRAND_NEW_FLAG` | a flag the page never heard of |" in (
        _hooks().commands_page())


# --------------------------------------------------------------------- format examples


def _load_example(rel: str) -> None:
    """Load one example with the reader the project uses for that format (raises if
    invalid)."""
    path = ROOT / rel
    name = path.name
    if rel.endswith("recording/robot.toml") or name == "robot.toml":
        from controller.robot import load_robot

        assert load_robot(path).n_cables >= 6
    elif name in ("meta.toml", "recording.csv"):
        from bench.recording import read_recording

        rec = read_recording(path.parent)
        assert len(rec.t) > 3 and rec.state is not None
        for group in (rec.l_meas, rec.tau, rec.pose_meas):  # a sample whole, or none
            have = np.isfinite(group).all(axis=1)
            assert have.sum() > 3 and (have | np.isnan(group).all(axis=1)).all()
    elif name == "events.csv":
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        assert rows and {"t", "device", "kind", "reaction"} <= set(rows[0])
    elif name == "scenario.toml":
        from firmware_sim.scenario import load_scenario

        sc = load_scenario(path)
        assert set(sc.effects) == {"mast_compliance", "exit_point_offset", "cable_length_offset"}
        assert sc.react == {"slack": "log"} and sc.run_path == "paper-centre"
    elif name == "path.toml":
        from controller.paths import build_trajectory, check_trajectory, load_path
        from controller.robot import resolve_robot

        spec = load_path(path)
        traj = build_trajectory(spec, np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.0]))
        check = check_trajectory(resolve_robot("rocaspect"), traj)
        assert check.ok, check.reason  # the example is a path one can run
    elif name == "faults.toml":
        from firmware_sim.faults import FaultSchedule

        kinds = {f.kind for f in FaultSchedule.load(path).faults}
        assert {"over_current", "out_of_range"} <= kinds
    elif name == "winches.toml":
        from controller.winch import DEFAULT_WINCHES, load_winches

        assert len(load_winches(path).cables) == 8
        assert path.read_bytes() == DEFAULT_WINCHES.read_bytes(), "copy of the shipped file"
    elif name == "register-map.toml":
        from controller.loadcell_map import load_register_map
        from firmware_sim.loadcell_bank import REGISTER_MAP_FILE

        load_register_map(path)
        assert path.read_bytes() == REGISTER_MAP_FILE.read_bytes(), "copy of the shipped file"
    elif name == "diagnosis-report.json":
        _check_report(json.loads(path.read_text()))
    elif name == "tracker.txt":
        _check_tracker_session(path.read_text().splitlines())
    elif name.endswith(".toml") and "site" in name:  # docs/formats/site.md's example
        from hal.site import load_site  # type: ignore[import-not-found]

        load_site(path)
    else:
        raise AssertionError(f"{rel}: no reader known for this example")


def _check_report(report: dict) -> None:
    from bench.commands.compare import compare
    from controller.effects import EFFECT_NAMES
    from firmware_sim.scenario import load_scenario

    assert report["format"] == "cdpr-diagnosis/1"
    for key in ("recording", "samples", "baseline", "mismatch", "effects", "fitted", "model"):
        assert key in report, key
    for e in report["effects"]:
        assert e["name"] in EFFECT_NAMES and set(e["params"]) <= set(e["stderr"])
    # the project's reader of reports: cdpr compare, against any scenario
    c = compare(load_scenario(ROOT / "bench" / "data" / "paper_scenario.toml"), report)
    assert isinstance(c, dict)


def _check_tracker_session(lines: list[str]) -> None:
    from hal.tracker import parse_greeting, parse_line

    server = [s[2:] for s in lines if s.startswith("< ")]
    client = [s[2:] for s in lines if s.startswith("> ")]
    assert len(server) + len(client) == len(lines)
    hello = parse_greeting(server[0])
    assert hello is not None and hello.fields["frame"] == "F_b"
    measurements = [parse_line(s) for s in server if s.startswith("P ")]
    assert measurements and all(m is not None for m in measurements)
    assert any(m[3] for m in measurements) and any(not m[3] for m in measurements)
    assert client[0] == "SUBSCRIBE"


def _format_pages() -> dict[str, list[str]]:
    pages = {}
    for page in sorted((DOCS / "formats").glob("*.md")):
        pages[page.name] = SNIPPET.findall(page.read_text())
    return pages


def test_every_format_page_has_an_example_in_a_file():
    pages = _format_pages()
    for name in ("robot.md", "recording.md", "diagnosis-report.md", "scenario.md", "path.md",
                 "faults.md", "winches.md", "register-map.md", "tracker.md"):
        assert pages.get(name), f"docs/formats/{name} includes no example file"


@pytest.mark.parametrize("rel", sorted({r for refs in _format_pages().values() for r in refs}))
def test_format_example_loads_with_the_projects_reader(rel):
    _load_example(rel)


def test_a_broken_example_is_refused(tmp_path):
    """The example check can fail: a robot with a cable on a mast that does not exist."""
    from controller.robot import RobotFileError

    text = (DOCS / "formats" / "examples" / "robot.toml").read_text()
    bad = tmp_path / "robot.toml"
    bad.write_text(text.replace('mast = "4"', 'mast = "9"', 1))
    with pytest.raises(RobotFileError, match="mast"):
        _load_example(str(bad))  # an absolute path: ROOT / it is itself


def test_effect_vocabulary_page_names_every_effect():
    from controller.effects import EFFECT_NAMES

    text = (DOCS / "reference" / "effects.md").read_text()
    for name in EFFECT_NAMES:
        assert f"| `{name}` |" in text, name


# ------------------------------------------------------------------------------ README


def test_readme_is_short_and_points_where_a_new_user_looks():
    readme = ROOT / "README.md"
    text = readme.read_text()
    assert readme.stat().st_size <= 12 * 1024
    assert "make demo" in text and "make test" in text
    assert "cdpr dry-run PATH --site FILE" in text
    assert "(docs/guide/real-robot.md)" in text and "(docs/guide/commissioning.md)" in text
    assert "Zake" in text and "hal-04045089" in text
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", text):
        assert (ROOT / target).exists(), f"README links to a missing {target}"
    # no history: no dates, no narrated stops
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text)
    assert "stop of" not in text and "day's" not in text


# --------------------------------------------------------------- self-contained repository


def _tracked_files() -> list[Path]:
    r = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                       cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip("not a git checkout")
    return [ROOT / name for name in r.stdout.splitlines() if (ROOT / name).is_file()]


def test_no_file_refers_to_the_shared_folder_outside_the_repository():
    this = Path(__file__).resolve()
    needles = ("../" + "shared", "shared" + "/spec")
    offenders = []
    for path in _tracked_files():
        if path.resolve() == this:
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue
        if any(n in text for n in needles):
            offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


# ----------------------------------------------------------------------------- benchmarks


def test_benchmarks_page_names_date_commit_cpu_and_load():
    from bench.benchmarks.page import machine, page

    where = machine()
    text = page({"control_cycle_us": 64.0, "equilibrium_ms": 0.39, "machine": "x"}, where)
    for label in ("| date |", "| commit |", "| CPU |", "| load average"):
        assert label in text
    assert "| `control_cycle_us` | 64 |" in text and "`machine`" not in text
    assert where["commit"] and where["cpu"] and re.match(r"\d{4}-\d\d-\d\d", where["date"])


def test_benchmarks_page_is_the_generators_output():
    """docs/benchmarks.md regenerates byte for byte from its own figures and machine
    table: it was not edited by hand."""
    from bench.benchmarks.page import page

    text = (DOCS / "benchmarks.md").read_text()
    where = dict(re.findall(r"^\| (date|commit|CPU|load average \(1 / 5 / 15 min\)|Python) "
                            r"\| (.+) \|$", text, re.M))
    where = {"date": where["date"], "commit": where["commit"].strip("`"), "cpu": where["CPU"],
             "load": where["load average (1 / 5 / 15 min)"], "python": where["Python"]}
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \|", text, re.M)
    assert rows, "no benchmark figures on the page"
    results = {}
    for key, value in rows:
        try:
            results[key] = float(value)
        except ValueError:
            results[key] = value.strip()
    assert page(results, where) == text


def test_evaluation_page_is_the_generators_output_of_its_records():
    """docs/evaluation.md regenerates from the records it names (docs/data/evaluation.jsonl,
    and the new kinds' file when it has their section), but for the time the page was made:
    its figures were not edited by hand."""
    from bench.evaluation_page import load, page

    text = (DOCS / "evaluation.md").read_text()
    sources = re.findall(r"^\| records \| `(.+)` \|$", text, re.M)
    made = re.search(r"^\| page made \| (.+) \|$", text, re.M).group(1)
    new = (*load(str(ROOT / sources[1])), sources[1]) if len(sources) > 1 else None
    assert page(*load(str(ROOT / sources[0])), made, sources[0], new=new) == text
