"""``cdpr diagnose``: the report object on stdout, plots, corrected model, errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from bench.cli import main

EXAMPLE = Path(__file__).parent.parent / "examples" / "paper_tables"

TOP = {"format", "recording", "samples", "baseline", "mismatch", "effects", "fitted", "model",
       "unexplained"}
BASELINE = {"pose_rms_m", "pose_max_m", "angle_rms_rad", "tension_rms_n", "wrench_rms",
            "exit_point_rms_m"}
FITTED = {"pose_rms_m", "angle_rms_rad", "tension_rms_n", "exit_point_rms_m",
          "heldout_pose_rms_m"}
EFFECT = {"name", "params", "stderr", "explains", "evidence", "undetermined", "alternatives"}


def test_json_report_follows_the_spec(capsys, tmp_path):
    model = tmp_path / "corrected.toml"
    plots = tmp_path / "plots"
    assert main(["diagnose", str(EXAMPLE), "--json", "--jobs", "1", "--quiet",
                 "--write-model", str(model), "--plots", str(plots)]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep) == TOP and rep["format"] == "cdpr-diagnosis/1"
    assert rep["recording"] == str(EXAMPLE) and rep["samples"] == 5
    assert set(rep["baseline"]) == BASELINE and FITTED <= set(rep["fitted"])
    assert {"summary", "by_cable", "by_mast", "regions"} <= set(rep["mismatch"])
    assert isinstance(rep["mismatch"]["summary"], str) and rep["mismatch"]["summary"]
    for e in rep["effects"]:
        assert EFFECT <= set(e)
        assert set(e["params"]) == set(e["stderr"])
        assert {"heldout_pose_rms_before_m", "heldout_pose_rms_after_m",
                "delta_bic"} <= set(e["evidence"])
    assert rep["model"] == str(model) and model.exists()
    from controller.robot import load_robot

    assert load_robot(model).n_cables == 8
    assert any(p.suffix == ".png" for p in plots.iterdir())


def test_human_output_and_progress(capsys):
    assert main(["diagnose", str(EXAMPLE), "--jobs", "1"]) == 0
    out, err = capsys.readouterr()
    assert "effect exit_point_offset" in out and "mismatch:" in out
    assert "samples (" in err and "dwells" in err  # progress on stderr


def test_bad_recording_exits_2_naming_the_file(capsys, tmp_path):
    d = tmp_path / "rec"
    shutil.copytree(EXAMPLE, d)
    (d / "recording.csv").write_text("time,x\n1,2\n")
    assert main(["diagnose", str(d), "--json", "--quiet"]) == 2
    captured = capsys.readouterr()
    # under --json stdout carries one JSON object even when the diagnosis fails
    assert "recording.csv:1" in json.loads(captured.out)["error"]
    assert "recording.csv:1" in captured.err
    assert main(["diagnose", str(tmp_path / "missing"), "--quiet"]) == 2


def test_progress_says_the_plots_are_being_drawn_before_they_are(capsys, monkeypatch,
                                                                  tmp_path):
    from bench.diagnosis import plots

    real, seen = plots.write_plots, []

    def spy(*a, **kw):
        seen.append(capsys.readouterr().err)  # stderr before the drawing starts
        return real(*a, **kw)

    monkeypatch.setattr(plots, "write_plots", spy)
    assert main(["diagnose", str(EXAMPLE), "--jobs", "1", "--plots", str(tmp_path / "p")]) == 0
    assert len(seen) == 1
    last = seen[0].strip().splitlines()[-1]
    assert last.endswith(f"drawing the plots (residual maps, per-cable bars) into "
                         f"{tmp_path / 'p'}")
    assert "plot " in capsys.readouterr().err
    # --quiet: no progress at all
    assert main(["diagnose", str(EXAMPLE), "--jobs", "1", "--quiet", "--plots",
                 str(tmp_path / "q")]) == 0
    assert seen[1] == "" and capsys.readouterr().err == ""
