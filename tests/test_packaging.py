"""Packaging a user expects: a built wheel works outside the repository (shipped data
included), ``cdpr --version`` gives the version and the commit, ``python -m bench`` works,
every package carries ``py.typed``."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from bench.version import git_commit, package_version, version_string

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("controller", "hal", "firmware_sim", "bench")


def _run(args: list[str], cwd: Path, env: dict[str, str] | None = None,
         timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def test_version_names_the_version_and_the_checkouts_commit():
    text = version_string()
    assert text.startswith(f"cdpr {package_version()} (commit ")
    commit = git_commit()
    if commit is not None:  # a git checkout: its commit, not "unknown"
        assert commit in text


def test_python_m_bench_is_the_cdpr_command(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = _run([sys.executable, "-m", "bench", "--version"], cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("cdpr ") and "(commit " in r.stdout
    r = _run([sys.executable, "-m", "bench", "--help"], cwd=tmp_path, env=env)
    assert r.returncode == 0 and "dry-run" in r.stdout


def test_every_package_has_a_py_typed_marker():
    for pkg in PACKAGES:
        assert (ROOT / pkg / "py.typed").is_file(), pkg


def _source_copy(dest: Path) -> Path:
    """The working tree's files (tracked and new, not ignored) copied to ``dest``: the
    build writes nothing into the repository."""
    files = _run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=ROOT)
    if files.returncode != 0:
        pytest.skip("not a git checkout: cannot list the source files")
    for name in files.stdout.splitlines():
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest


@pytest.mark.slow  # a wheel build (5 to 30 s, more on a loaded machine)
def test_built_wheel_runs_outside_the_repository(tmp_path):
    src = _source_copy(tmp_path / "src")
    env = {**os.environ, "CDPR_BUILD_COMMIT": "feedc0ffee"}
    r = _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
              str(tmp_path / "dist"), str(src)], cwd=tmp_path, env=env, timeout=300)
    if r.returncode != 0 and ("Could not find a version" in r.stderr
                              or "NewConnectionError" in r.stderr):
        pytest.skip("the build back-end could not be fetched (offline): " + r.stderr[-200:])
    assert r.returncode == 0, r.stderr
    (wheel,) = (tmp_path / "dist").glob("cdpr_bench-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for pkg in PACKAGES:
        assert f"{pkg}/py.typed" in names
    for data in ("controller/data/rocaspect.toml", "controller/data/rocaspect_winches.toml",
                 "firmware_sim/data/loadcell_registers.toml", "firmware_sim/data/winch_drive.eds",
                 "bench/data/paper_scenario.toml", "bench/data/paths/paper-centre.toml",
                 "bench/data/scenarios/paper-centre.toml"):
        assert data in names, data

    site = tmp_path / "site"
    r = _run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site),
              str(wheel)], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # the wheel's packages first; the dependencies from this interpreter's site-packages
    run_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    run_env["PYTHONPATH"] = str(site)
    where = _run([sys.executable, "-c", "import bench, controller; print(bench.__file__); "
                  "print(controller.__file__)"], cwd=elsewhere, env=run_env)
    assert where.returncode == 0, where.stderr
    assert all(line.startswith(str(site)) for line in where.stdout.split()), where.stdout

    r = _run([sys.executable, "-m", "bench", "model", "check", "rocaspect", "--json"],
             cwd=elsewhere, env=run_env)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert isinstance(out, dict) and "error" not in out
    r = _run([str(site / "bin" / "cdpr"), "--version"], cwd=elsewhere, env=run_env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"cdpr {package_version()} (commit feedc0ffee)"
