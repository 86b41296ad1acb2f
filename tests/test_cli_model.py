"""``cdpr model``: check, show, JSON output and exit codes."""

from __future__ import annotations

import json

from bench.cli import main


def test_model_check_json(capsys, tmp_path):
    png = tmp_path / "ws.png"
    assert main(["model", "check", "rocaspect", "--json", "--step", "1.0",
                 "--plot", str(png)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["valid"] and out["robot"] == "rocaspect"
    assert out["workspace"]["feasible_area_m2"] > 300
    assert len(out["poses"]) == 5
    first = out["poses"][0]
    assert set(first["mast_displacement_m"]) == {"1", "2", "3", "4"}
    assert all(0.0 < v < 0.05 for v in first["mast_displacement_m"].values())
    assert png.stat().st_size > 10_000


def test_model_check_human(capsys):
    assert main(["model", "check", "rocaspect-remeasured", "--step", "1.5"]) == 0
    out = capsys.readouterr().out
    assert "wrench-feasible workspace" in out and "mast  1" in out


def test_model_check_invalid_file_exits_non_zero(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[platform]\nmass = 35.0\nwings = 2\n')
    assert main(["model", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml:4" in err and "wings" in err
    assert main(["model", "check", str(bad), "--json"]) == 2
    assert json.loads(capsys.readouterr().out)["valid"] is False


def test_model_show(capsys):
    assert main(["model", "show", "rocaspect", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert [c["id"] for c in d["cables"]] == ["11", "12", "21", "22", "31", "32", "41", "42"]
    assert main(["model", "show", "rocaspect"]) == 0
    assert "pivot" in capsys.readouterr().out


def test_model_check_says_how_big_the_sweep_is_before_it(capsys, monkeypatch):
    from bench.commands import model

    real, seen = model.check, []

    def spy(*a, **kw):
        seen.append(capsys.readouterr().err)  # stderr before the sweep
        return real(*a, **kw)

    monkeypatch.setattr(model, "check", spy)
    assert main(["model", "check", "rocaspect", "--step", "1.5", "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["valid"]
    assert len(seen) == 1 and seen[0].startswith("cdpr model: workspace sweep of about ")
    assert "points at z = 1 m (1.5 m grid, closed_form): " in seen[0]
    assert cap.err.startswith("cdpr model: workspace sweep done in ")
