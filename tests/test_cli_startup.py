"""``cdpr --help`` and a command's parser load no heavy library (startup stays short)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from bench.cli import COMMANDS, build_parser

HEAVY = ("numpy", "scipy", "can", "canopen", "pymodbus", "matplotlib", "hal.interface")


@pytest.mark.parametrize("only", [None, "dry-run", "commission", "diagnose", "sim"])
def test_parser_imports_nothing_heavy(only):
    code = (f"import sys; from bench.cli import build_parser; build_parser({only!r}); "
            f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "", f"build_parser({only!r}) imported {out}"


def test_full_parser_has_every_command_and_their_options():
    parser = build_parser("")
    for argv in (["dry-run", "paper-centre", "--rate", "100"], ["model", "check", "rocaspect"],
                 ["commission", "scan"]):
        args = parser.parse_args(argv)
        assert callable(args._run)
    assert len(COMMANDS) >= 10
