"""``cdpr compare`` takes the ``case.json`` that ``cdpr evaluate --keep`` keeps beside a
case's recording (the scenario with the evaluation's ``case`` and ``kept`` sections), so that
a case diagnosed again by hand is compared with its truth as a scenario file is. Before,
the kept case was read as TOML and refused ("TOML syntax error")."""

from __future__ import annotations

import json

from bench.cli import main

#: a kept case as `cdpr evaluate --keep` writes it: a cdpr-scenario/1 mapping with one
#: concealed effect, and the evaluation's own sections
CASE = {"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": 7,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
        "truth": {"cable_length_offset": {"dl_21": -0.004}},
        "case": {"robot": "rocaspect", "kind": "logger", "sensors": "all",
                 "logger": {"rows_hz": 250.0, "split": "sensor"}},
        "kept": {"config": {"kind": "logger"}, "made": {"attempt": 0}}}

#: its diagnosis: the offset named (z -1)
REPORT = {"format": "cdpr-diagnosis/1", "recording": "k/7/rec", "unexplained": None,
          "effects": [{"name": "cable_length_offset", "params": {"dl_21": -0.0041},
                       "stderr": {"dl_21": 1e-4}, "undetermined": [], "alternatives": []}]}


def _files(tmp_path, case: dict) -> tuple[str, str]:
    (tmp_path / "case.json").write_text(json.dumps(case))
    (tmp_path / "report.json").write_text(json.dumps(REPORT))
    return str(tmp_path / "case.json"), str(tmp_path / "report.json")


def test_a_kept_case_is_compared_with_its_diagnosis(tmp_path, capsys):
    assert main(["compare", *_files(tmp_path, CASE), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict"] == "every concealed effect named, nothing else"
    (row,) = out["effects"][0]["params"].values()
    assert row["truth"] == -0.004 and round(row["z"], 6) == -1.0


def test_a_kept_case_that_is_no_scenario_names_the_file(tmp_path, capsys):
    bad = CASE | {"format": "cdpr-scenario/9"}
    assert main(["compare", *_files(tmp_path, bad), "--json"]) == 2
    err = json.loads(capsys.readouterr().out)["error"]
    assert "case.json" in err and "format" in err
    (tmp_path / "broken.json").write_text("{\"format\": ")
    assert main(["compare", str(tmp_path / "broken.json"), str(tmp_path / "report.json")]) == 2
    assert "broken.json: not a JSON case" in capsys.readouterr().err
