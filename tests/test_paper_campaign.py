"""The paper's campaigns (cdpr dry-run paper-paths / paper-poses), shortened.

The full campaigns take minutes (bench/benchmarks/paper.py times paper-paths); here every run is
cut a few seconds after the platform reached the path, on one case or one pose set.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.cli import main
from bench.dryrun import paper
from controller.paths import build_trajectory, check_trajectory, load_path
from controller.robot import resolve_robot, save_robot
from controller.statics import pose_statics

REMEASURED = resolve_robot("rocaspect-remeasured")
NOMINAL = resolve_robot("rocaspect")


@pytest.mark.parametrize("name", ["paper-centre", "paper-calibration", "paper-heavy"])
def test_the_truth_has_table_1_remeasured_exit_points_where_the_paper_measured_them(name):
    sc = paper.load_named_scenario(name)
    truth = paper.known_truth(sc, ("platform_mass",))  # paper-heavy: without its payload
    ps = pose_statics(truth, np.array([10.0, 8.56, 1.0, 0.0, 0.0, 0.0]))
    assert np.abs(ps.exits - REMEASURED.exits).max() < 1e-4
    # and the nominal model is 38 to 94 mm off there, as Table 1's last column (57-114 mm
    # with the deflection)
    d = np.linalg.norm(ps.exits - NOMINAL.exits, axis=1)
    np.testing.assert_allclose(d, np.linalg.norm(REMEASURED.exits - NOMINAL.exits, axis=1),
                               atol=1e-4)


def test_table1_exit_offsets_reproduces_the_scenario_offsets():
    sc = paper.load_named_scenario("paper-centre")
    off = paper.table1_exit_offsets(NOMINAL, REMEASURED, (2e5, 5e5, 3e5))
    written = np.array([[sc.effects["exit_point_offset"][f"d{a}_{c}"] for a in "xyz"]
                        for c in NOMINAL.cable_ids])
    assert np.abs(off - written).max() < 6e-5  # rounded to 0.1 mm in the file
    # stiffer masts deflect less at that pose: the settled exits come nearer Table 1's
    stiff = paper.table1_exit_offsets(NOMINAL, REMEASURED, (2e7, 5e7, 3e7))
    table1 = REMEASURED.exits - NOMINAL.exits
    assert np.abs(stiff - table1).max() < 0.1 * np.abs(off - table1).max()
    assert np.abs(off - table1).max() > 0.01  # 17-19 mm of deflection in y


def test_known_truth_leaves_out_the_payload_only():
    heavy = paper.load_named_scenario("paper-heavy")
    rob = paper.known_truth(heavy, ("platform_mass",))
    assert heavy.truth.mass == 50.0 and rob.mass == heavy.model.mass == 35.0
    np.testing.assert_allclose(rob.exits, heavy.truth.exits)
    np.testing.assert_allclose(rob.stiffness, heavy.truth.stiffness)
    centre = paper.load_named_scenario("paper-centre")
    assert paper.known_truth(centre, ("platform_mass",)) is centre.truth


def test_the_quick_calibration_is_feasible_and_reaches_the_paths():
    spec = load_path(paper.CALIBRATION_PATH)
    tr = build_trajectory(spec, np.array(paper.INIT_POSES["centre"]))
    for rob in (NOMINAL, REMEASURED):
        assert check_trajectory(rob, tr).ok
    poses = np.array(spec.segments[0].poses)
    assert poses[:, 0].min() <= 1.0 and poses[:, 0].max() >= 19.0  # the side path's x
    assert tr.duration_s < 20 * 60


def test_pose_path_changes_the_cycles_only():
    spec = paper.pose_path("violet", 2)
    shipped = load_path("paper-poses-violet")
    assert spec.segments[0].visits == 2 and shipped.segments[0].visits == 30
    assert spec.segments[0].poses == shipped.segments[0].poses
    assert paper.pose_path("violet", 30) == shipped


def _json(capsys, argv):
    code = main(argv)
    out = capsys.readouterr().out
    return code, json.loads(out)


def test_paper_paths_shortened(tmp_path, capsys):
    """One case (centre path, centre initialisation), cut 13 s into the path, past its first
    corner (the nominal model's error grows as the platform goes down): the JSON's shape,
    nominal against compliant and diagnosed (a corrected robot.toml given), measured against
    planned tensions."""
    truth_file = tmp_path / "truth.toml"
    save_robot(paper.load_named_scenario("paper-centre").truth, truth_file)
    code, res = _json(capsys, [
        "dry-run", "paper-paths", "--json", "--quiet", "--duration", "13", "--cases",
        "centre/centre", "--models", "nominal,compliant,diagnosed,planned",
        "--diagnosed-model", str(truth_file), "--record", str(tmp_path / "rec"),
        "--plots", str(tmp_path / "plots")])
    assert code == 0, res.get("failures")
    assert res["scenario"] == "paper-paths"
    assert [(c["path"], c["init"]) for c in res["cases"]] == [("centre", "centre")]
    c = res["cases"][0]
    for m in ("nominal", "compliant", "diagnosed"):
        assert c[f"at_max_{m}_m"] > 0 and 0 < c[f"at_mean_{m}_m"] <= c[f"at_max_{m}_m"]
    assert c["paper_at_max_nominal_m"] == pytest.approx(0.0431)
    # the compliant controller (the true model, measured tensions) beats the nominal one
    assert c["at_max_compliant_m"] < 0.2 * c["at_max_nominal_m"]
    assert c["at_max_cut_compliant"] > 0.8
    assert c["at_max_diagnosed_m"] < 0.2 * c["at_max_nominal_m"]
    # a heavier platform than the model: the load cells' tensions beat the planned ones
    pv = res["planned_vs_measured"]
    assert pv["scenario"] == "paper-heavy"
    (p,) = pv["cases"]
    assert p["at_max_measured_m"] < 0.5 * p["at_max_planned_m"]
    assert pv["measured_better_everywhere"] is True
    assert res["failures"] == []
    assert res["reactions"] == {"slack": "log"}  # the campaigns' default (README)
    assert {r["label"] for r in res["runs"]} == {
        "nominal_centre-path_centre-init", "compliant_centre-path_centre-init",
        "diagnosed_centre-path_centre-init", "heavy-measured_centre-path_centre-init",
        "heavy-planned_centre-path_centre-init"}
    assert all((tmp_path / "rec" / r["label"] / "recording.csv").exists() for r in res["runs"])
    assert sorted(p.rsplit("/", 1)[1] for p in res["plots"]) == ["paths.png",
                                                                  "planned_vs_measured.png"]


def test_paper_poses_shortened(tmp_path, capsys):
    code, res = _json(capsys, [
        "dry-run", "paper-poses", "--json", "--quiet", "--cycles", "2", "--sets", "violet",
        "--speeds", "100", "--models", "nominal,compliant", "--plots", str(tmp_path),
        "--react", "overload=hold"])
    assert code == 0, res.get("failures")
    assert res["scenario"] == "paper-poses" and res["cycles"] == 2
    assert res["reactions"] == {"slack": "log", "overload": "hold"}
    runs = {r["model"]: r for r in res["runs"]}
    assert set(runs) == {"nominal", "compliant"}
    for r in runs.values():
        assert r["set"] == "violet" and r["speed_pct"] == 100
        assert len(r["poses"]) == 5 and all(p["n"] == 2 for p in r["poses"])
        assert r["rp_m"] > 0 and r["ap_m"] > 0
    assert runs["compliant"]["ap_m"] < 0.5 * runs["nominal"]["ap_m"]
    assert (tmp_path / "poses.png").exists()


@pytest.mark.parametrize("argv, msg", [
    (["--models", "nominal,best"], "unknown best"),
    (["--cases", "centre/middle"], "unknown centre/middle"),
    (["--jobs", "0"], "--jobs"),
    (["--rate", "1000"], "--rate"),
    (["--robot", "rocaspect"], "--robot does not apply"),
    (["--sets", "gold"], "--sets applies to paper-poses"),
    (["--react", "slack=ignore"], "--react"),
])
def test_paper_paths_refuses_bad_options(argv, msg, capsys):
    assert main(["dry-run", "paper-paths", *argv]) == 2
    assert msg in capsys.readouterr().err


def test_paper_poses_refuses_bad_options(capsys):
    assert main(["dry-run", "paper-poses", "--speeds", "0,40"]) == 2
    assert "(0, 100]" in capsys.readouterr().err
    assert main(["dry-run", "paper-poses", "--models", "diagnosed"]) == 2
    assert "--diagnosed-model" in capsys.readouterr().err


def test_the_plant_settles_at_least_every_25_mm_of_motion():
    limits = load_path("paper-poses-gold").limits  # 0.5 m/s
    assert paper.plant_rate(5.0, limits.replace(speed_pct=100.0)) == pytest.approx(20.0)
    assert paper.plant_rate(5.0, limits.replace(speed_pct=40.0)) == pytest.approx(8.0)
    assert paper.plant_rate(5.0, limits.replace(speed_pct=10.0)) == 5.0  # 1 cm at 5 Hz
    assert paper.plant_rate(64.0, limits) == 64.0


def _spec(tmp_path):
    sc = paper.load_named_scenario("paper-centre")
    return paper.RunSpec("r", sc, "paper-centre", str(tmp_path / "r"), robot=sc.model)


def test_a_run_stopped_by_a_lost_master_runs_again_once(tmp_path, monkeypatch):
    calls = []

    def lost_once(spec, parent_pid=None):
        calls.append(spec.label)
        if len(calls) == 1:
            raise paper.DriveLostError("r: the dry run ended quick_stop (drive 1: NMT)")
        return {"label": spec.label}

    monkeypatch.setattr(paper, "run_one", lost_once)
    out = paper.run_item(_spec(tmp_path))
    assert calls == ["r", "r"] and out["retried"] == [
        "r: the dry run ended quick_stop (drive 1: NMT)"]


def test_a_run_that_fails_otherwise_or_twice_is_not_run_again(tmp_path, monkeypatch):
    calls = []

    def fails(exc):
        def run(spec, parent_pid=None):
            calls.append(spec.label)
            raise exc
        return run

    monkeypatch.setattr(paper, "run_one", fails(paper.CampaignError("r: following error")))
    with pytest.raises(paper.CampaignError, match="following error"):
        paper.run_item(_spec(tmp_path))
    assert calls == ["r"]
    calls.clear()
    monkeypatch.setattr(paper, "run_one", fails(paper.DriveLostError("r: NMT")))
    with pytest.raises(paper.DriveLostError):
        paper.run_item(_spec(tmp_path))
    assert calls == ["r", "r"]  # once again, not more
    out = {"label": "r"}
    monkeypatch.setattr(paper, "run_one", lambda spec, parent_pid=None: dict(out))
    assert paper.run_item(_spec(tmp_path))["retried"] == []
