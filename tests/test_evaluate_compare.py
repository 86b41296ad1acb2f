"""``cdpr evaluate --compare A B``: the cases whose answers differ between two evaluations
(records written by hand in the --out and --json formats; no case is run)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.cli import main
from bench.commands.evaluate import OUT_FORMAT
from bench.evaluate import compare


def rec(seed: int, named: list[str], truth: list[str] | None = None, unexplained: bool = False,
        params: dict[str, tuple[float, float]] | None = None) -> dict:
    """A case record as ``cdpr evaluate`` writes it (the fields the comparison reads)."""
    truth = named if truth is None else truth
    ivs = [{"effect": k.split(".")[0], "key": k.split(".")[1], "truth": v, "value": v,
            "stderr": se} for k, (v, se) in (params or {}).items()]
    return {"seed": seed, "truth": truth, "named": named, "exact": sorted(named) == sorted(truth),
            "unexplained": unexplained, "intervals": ivs,
            "info": {"robot": "cogiro", "kind": "dwell", "sensors": "all", "oov": "none"}}


def write_out(path: Path, records: list[dict]) -> Path:
    lines = [{"format": OUT_FORMAT, "config": {}}, *records]
    path.write_text("".join(json.dumps(r) + "\n" for r in lines), encoding="utf-8")
    return path


BEFORE = [rec(1, ["drum_scale"], params={"drum_scale.s_11": (1.0010, 1e-5)}),
          rec(2, []),
          rec(3, ["platform_mass"], params={"platform_mass.mass": (35.00, 0.02)}),
          rec(4, ["cable_length_offset"], truth=[], unexplained=True)]


def test_the_same_answers_differ_nowhere_even_with_parameters_moved_within_their_errors():
    after = [dict(r) for r in BEFORE]
    after[0] = rec(1, ["drum_scale"], params={"drum_scale.s_11": (1.0010 + 4e-6, 1e-5)})
    got = compare({r["seed"]: r for r in BEFORE}, {r["seed"]: r for r in after})
    assert (got["common"], got["same"], got["differ"]) == (4, 4, [])
    assert got["exact"] == {"a": 3, "b": 3}


def test_named_effects_unexplained_and_moved_parameters_are_each_reported():
    after = [rec(1, ["drum_scale"], params={"drum_scale.s_11": (1.0010 + 2e-5, 1e-5)}),
             rec(2, ["tracker_latency"], truth=[]),
             rec(3, ["platform_mass"], params={"platform_mass.mass": (35.00, 0.02)}),
             rec(4, ["tracker_frame"], truth=[]),
             rec(5, [])]
    got = compare({r["seed"]: r for r in BEFORE}, {r["seed"]: r for r in after})
    what = {d["seed"]: d["differences"] for d in got["differ"]}
    assert set(what) == {1, 2, 4}
    assert what[1] == ["moved drum_scale.s_11 1.001 -> 1.00102"]
    assert what[2] == ["named +tracker_latency", "no longer exact"]
    assert what[4] == ["named -cable_length_offset +tracker_frame", "unexplained gone"]
    assert got["only_b"] == [5] and got["only_a"] == []


def test_compare_reads_out_files_and_json_outputs_and_exits_1_on_a_difference(tmp_path, capsys):
    a = write_out(tmp_path / "a.jsonl", BEFORE)
    b = tmp_path / "b.json"
    cases = [dict(r) for r in BEFORE[1:]] + [rec(1, [])]
    b.write_text(json.dumps({"summary": {}, "cases": cases[:-1],
                             "errors": [{"seed": 1, "error": "plant: no rest"}]}),
                 encoding="utf-8")
    assert main(["evaluate", "--compare", str(a), str(a)]) == 0
    assert "4 same answers, 0 differ" in capsys.readouterr().out
    assert main(["evaluate", "--compare", str(a), str(b), "--json"]) == 1
    got = json.loads(capsys.readouterr().out)
    assert [d["seed"] for d in got["differ"]] == [1]
    assert got["differ"][0]["b"] == {"error": "plant: no rest"}


def test_compare_refuses_what_cdpr_evaluate_did_not_write(tmp_path, capsys):
    other = tmp_path / "x.json"
    other.write_text(json.dumps({"effects": []}), encoding="utf-8")
    assert main(["evaluate", "--compare", str(other), str(other)]) == 2
    assert f"{other}: a JSON object without 'cases'" in capsys.readouterr().err
    assert main(["evaluate", "--compare", str(tmp_path / "none.jsonl"), str(other)]) == 2
    assert "cannot read" in capsys.readouterr().err
    for argv in (["evaluate"], ["evaluate", "--cases", "1", "--compare", "a", "b"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2 and "--cases" in capsys.readouterr().err
