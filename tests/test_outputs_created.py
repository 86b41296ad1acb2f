"""A command that refuses to run, or fails, before writing its outputs leaves no directory
it made for them (bench/outputs.py ``created``, ``remove_created``); one that wrote there
keeps them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from bench.cli import main
from bench.outputs import make_dirs, output_dir_problem, output_file_problem, remove_created

EXAMPLE = Path(__file__).parent.parent / "examples" / "paper_tables"


def test_checks_report_the_directories_they_made(tmp_path):
    created: list[Path] = []
    assert output_file_problem(tmp_path / "a" / "b" / "m.toml", "--x", created) is None
    assert output_dir_problem(tmp_path / "c" / "plots", "--y", created) is None
    assert output_file_problem(tmp_path / "a" / "n.toml", "--z", created) is None  # exists
    assert created == [tmp_path / "a", tmp_path / "a" / "b", tmp_path / "c"]
    (tmp_path / "c" / "kept.png").write_bytes(b"x")  # written: not removed
    remove_created(created)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c"]


def test_a_failed_check_leaves_nothing(tmp_path):
    (tmp_path / "file").write_text("x")
    created: list[Path] = []
    assert output_file_problem(tmp_path / "file" / "m.toml", "--x", created) is not None
    assert created == [] and sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    made: list[Path] = []
    make_dirs(tmp_path / "d" / "e", made)
    assert made == [tmp_path / "d", tmp_path / "d" / "e"]


def test_diagnose_of_a_bad_recording_leaves_no_output_directory(tmp_path, capsys):
    bad = tmp_path / "rec"
    shutil.copytree(EXAMPLE, bad)
    (bad / "recording.csv").write_text("time,x\n1,2\n")
    new = tmp_path / "newdir"
    assert main(["diagnose", str(bad), "--json", "--quiet", "--write-model",
                 str(new / "x.toml"), "--plots", str(tmp_path / "p" / "q" / "plots"),
                 "--out", str(tmp_path / "o" / "r.json")]) == 2
    assert "recording.csv:1" in json.loads(capsys.readouterr().out)["error"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_diagnose_refusing_one_output_removes_the_directories_made_for_the_others(
        tmp_path, capsys):
    assert main(["diagnose", str(EXAMPLE), "--quiet", "--write-model",
                 str(tmp_path / "m" / "x.toml"), "--out", "/proc/r.json"]) == 2
    assert "--out" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_diagnose_keeps_the_directories_it_wrote_into(tmp_path, capsys):
    assert main(["diagnose", str(EXAMPLE), "--quiet", "--jobs", "1", "--write-model",
                 str(tmp_path / "m" / "x.toml")]) == 0
    assert (tmp_path / "m" / "x.toml").is_file()


def _left(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir())


def test_campaign_refused_or_failed_leaves_no_directory(tmp_path, capsys, monkeypatch):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "cdpr-scenario/1"\nrobot = "no-such-robot"\n')
    assert main(["campaign", str(bad), str(tmp_path / "new" / "rec"), "--quiet"]) == 2
    assert _left(tmp_path) == ["bad.toml"]
    import bench.campaign

    def fails(*a, **kw):
        raise ValueError("a pose the model cannot reach")

    monkeypatch.setattr(bench.campaign, "run_campaign", fails)
    scenario = Path(__file__).parent / "data" / "scenarios" / "paper.toml"
    assert main(["campaign", str(scenario), str(tmp_path / "new" / "rec"), "--quiet"]) == 1
    assert "cannot reach" in capsys.readouterr().err
    assert _left(tmp_path) == ["bad.toml"]


def test_model_check_refused_leaves_no_directory(tmp_path, capsys):
    assert main(["model", "check", "rocaspect", "--step", "0.001", "--plot",
                 str(tmp_path / "new" / "ws.png")]) == 2
    assert "grid points" in capsys.readouterr().err
    assert _left(tmp_path) == []


def test_dry_run_refused_leaves_no_directory(tmp_path, capsys):
    assert main(["dry-run", "paper-centre", "--quiet", "--faults",
                 str(tmp_path / "absent.toml"), "--record", str(tmp_path / "new" / "rec"),
                 "--plots", str(tmp_path / "p" / "plots")]) == 2
    assert "absent.toml" in capsys.readouterr().err
    assert _left(tmp_path) == []


def test_evaluate_refused_leaves_no_directory(tmp_path, capsys):
    from bench.commands.evaluate import OUT_FORMAT

    out_file = tmp_path / "cases.jsonl"
    out_file.write_text(json.dumps({"format": OUT_FORMAT, "config": {"robot": "other"}})
                        + "\n", encoding="utf-8")
    assert main(["evaluate", "--cases", "1", "--keep", str(tmp_path / "new" / "kept"),
                 "--out", str(out_file)]) == 2
    assert "another case configuration" in capsys.readouterr().err
    assert _left(tmp_path) == ["cases.jsonl"]
