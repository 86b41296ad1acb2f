"""``cdpr bench``: under ``--json`` stdout carries one JSON object, the listing and errors too
(the benchmarks themselves are not run here: they take minutes)."""

from __future__ import annotations

import json

from bench.benchmarks import registry
from bench.cli import main


def test_list_json_is_one_object(capsys):
    assert main(["bench", "--list", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == {"groups": list(registry())}


def test_list_text_is_one_group_a_line(capsys):
    assert main(["bench", "--list"]) == 0
    assert capsys.readouterr().out.splitlines() == list(registry())


def test_unknown_group_under_json_is_an_error_object(capsys):
    assert main(["bench", "--json", "--only", "nosuch"]) == 2
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert "nosuch" in out["error"] and out["unknown"] == ["nosuch"]
    assert "physics" in out["groups"]
    assert "unknown group(s) nosuch" in cap.err
