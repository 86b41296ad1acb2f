"""The evaluation page (``python -m bench.evaluation_page``): the figures of a ``cdpr
evaluate --out`` file with the commit, dates and machine its records name."""

from __future__ import annotations

import json
from pathlib import Path

from bench.commands.evaluate import OUT_FORMAT
from bench.evaluation_page import command, main

CONFIG = {"robot": "ipanema", "effects": ["drum_scale"], "poses": {"n": [3, 2, 1], "visits": 2},
          "kind": "dwell", "sensors": "no_tracker", "oov": "none"}


def _case(seed: int, exact: bool, covered: bool, commit: str = "abc1234567") -> dict:
    value = 1.001 if covered else 1.01
    return {"seed": seed, "truth": ["drum_scale"], "named": ["drum_scale"] if exact else [],
            "exact": exact, "params_ok": 1, "params_total": 1, "failures": [], "z": [0.5],
            "heldout_ratio": 1.0, "seconds": 1.5, "unexplained": False,
            "info": {"robot": "ipanema", "kind": "dwell", "sensors": "no_tracker",
                     "oov": "none"},
            "intervals": [{"effect": "drum_scale", "key": "s_11", "truth": 1.0, "value": value,
                           "stderr": 0.001, "interval": [value - 0.002, value + 0.002],
                           "method": "linearised"}],
            "run": {"commit": commit, "date": f"2026-12-05 10:0{seed % 10} UTC",
                    "cpu": "AMD EPYC, 2 logical CPUs"}}


def _write(path: Path, cases: list[dict]) -> Path:
    lines = [{"format": OUT_FORMAT, "config": CONFIG}, *cases]
    path.write_text("".join(json.dumps(x) + "\n" for x in lines), encoding="utf-8")
    return path


def test_command_makes_the_same_cases_again():
    assert command(CONFIG, [40, 41, 42]) == (
        "cdpr evaluate --cases 3 --seed 40 --robot ipanema --kind dwell --sensors no_tracker "
        "--oov none --effects drum_scale --grid 3,2,1 --visits 2")
    mix = {"robot": "mix", "effects": None, "poses": {}, "kind": "mix", "sensors": "mix",
           "oov": None, "tracker": "tracker_latency"}
    assert command(mix, [7]) == "cdpr evaluate --cases 1 --seed 7 --tracker-error tracker_latency"


def test_page_gives_the_figures_and_where_they_were_measured(tmp_path, capsys):
    f = _write(tmp_path / "eval.jsonl", [_case(1, True, True), _case(2, True, False),
                                         _case(3, False, True)]
               + [{"seed": 4, "error": "boom", "trace": ""}])
    out = tmp_path / "page.md"
    assert main([str(f), "--out", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    assert "`cdpr evaluate --cases 3 --seed 1 --robot ipanema" in text
    assert "| diagnosis commit | `abc1234567` |" in text
    assert "| evaluation run started | 2026-12-05 10:01 UTC to 2026-12-05 10:03 UTC |" in text
    assert "| cases that raised | 1 |" in text
    assert "| exact detection | 66.7 % " in text
    # coverage: two exact cases, one interval holds the truth
    row = next(ln for ln in text.splitlines() if ln.startswith("| drum_scale | 2 | 2 |"))
    assert "| 50.0 % |" in row
    assert "do not edit by hand" in text


def test_records_of_several_commits_are_all_named(tmp_path, capsys):
    f = _write(tmp_path / "eval.jsonl", [_case(1, True, True, "aaa"), _case(2, True, True, "bbb")])
    assert main([str(f)]) == 0
    assert "| diagnosis commit | `aaa`, `bbb` |" in capsys.readouterr().out


def test_a_file_that_is_not_an_evaluation_is_refused(tmp_path, capsys):
    bad = tmp_path / "x.jsonl"
    bad.write_text('{"seed": 1, "truth": []}\n', encoding="utf-8")
    assert main([str(bad)]) == 1
    assert "no cdpr-evaluation/1 header" in capsys.readouterr().err
    empty = _write(tmp_path / "e.jsonl", [])
    assert main([str(empty)]) == 1
    assert "no cases" in capsys.readouterr().err
    assert main([]) == 2


def test_a_second_file_adds_the_new_kinds_section_with_its_own_provenance(tmp_path):
    first = _write(tmp_path / "eval.jsonl", [_case(1, True, True, "aaa")])
    logger = _case(14005, True, True, "bbb") | {"truth": ["drum_scale"]}
    logger["info"] = {"robot": "cogiro", "kind": "logger", "sensors": "all", "oov": "none",
                      "logger": {"rows_hz": 200.0, "dropouts": [["tracker", 1.5, 1.0, 4.0]]}}
    change = _case(14006, False, False, "bbb") | {"named": [], "unexplained": True}
    change["info"] = {"robot": "ipanema", "kind": "load_change", "sensors": "all",
                      "oov": "load_change"}
    lines = [{"format": OUT_FORMAT, "config": {"kind": "new"}}, logger, change]
    second = tmp_path / "new.jsonl"
    second.write_text("".join(json.dumps(x) + "\n" for x in lines), encoding="utf-8")
    out = tmp_path / "page.md"
    assert main([str(first), str(second), "--out", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    head, sec = text.split("## The new kinds")
    assert "| diagnosis commit | `aaa` |" in head and "`bbb`" not in head
    assert "| diagnosis commit | `bbb` |" in sec and "`aaa`" not in sec
    assert "`cdpr evaluate --cases 2 --seed 14005 --kind new`" in sec
    assert f"| records | `{second}` |" in sec
    assert ("| 14005 | logger | cogiro | all | rows 200 Hz; dropouts: tracker 1.5/min 1-4 s | "
            "drum_scale | drum_scale | no | yes |") in sec
    assert "| 14006 | load_change | ipanema | all | - | drum_scale, *load_change* | none | yes " \
           "| no |" in sec
    assert "| load_change | 1 | 0 |" in sec  # by kind: outside the vocabulary
    # a dropout drawn for a stream the case does not record is not said
    logger["info"] |= {"sensors": "no_tracker"}
    second.write_text("".join(json.dumps(x) + "\n" for x in lines), encoding="utf-8")
    assert main([str(first), str(second), "--out", str(out)]) == 0
    assert "| no_tracker | rows 200 Hz; dropouts: none |" in out.read_text(encoding="utf-8")
    # one file: no such section
    assert main([str(first), "--out", str(out)]) == 0
    assert "## The new kinds" not in out.read_text(encoding="utf-8")
