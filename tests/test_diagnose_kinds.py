"""The diagnosis on other robots and other recordings, blind: small fast cases.

CoGiRo- and IPAnema-class robots, continuous recordings (with and without a state
column), recordings without tensions or without tracker poses, impossible values,
physics outside the vocabulary (it must be declared, not named as the nearest
effect), per-cable EA, and the corrected model writing only what the report names.
The big evaluation is ``cdpr evaluate``; these are its smallest witnesses.
"""

from __future__ import annotations

import copy
import csv
import json
from pathlib import Path

import numpy as np
import pytest

from bench.campaign import campaign_plant, run_campaign
from bench.cli import main
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread, score
from bench.recording import RecordingError, read_recording
from firmware_sim.scenario import parse_scenario


@pytest.fixture(scope="module", autouse=True)
def _one_blas_thread():
    """The diagnosis's small matrices run fastest on one BLAS thread (threads spin against
    each other and other jobs on a loaded machine), as in ``cdpr diagnose``."""
    one_blas_thread()

GRID = {"kind": "grid", "n": [3, 3, 1], "rpy_deg": 1.0, "visits": 2}


def scenario(robot: str = "rocaspect", truth: dict | None = None, poses: dict | None = None,
             recording: dict | None = None, nuisance: dict | None = None, seed: int = 3,
             init=(10.0, 8.56, 1.0)) -> dict:
    return {"format": "cdpr-scenario/1", "robot": robot, "seed": seed,
            "init_pose": [*init, 0.0, 0.0, 0.0], "truth": truth or {},
            "nuisance": {"hysteresis_m": 5e-5, "drift_m_per_h": 2e-5} | (nuisance or {}),
            "poses": copy.deepcopy(poses or GRID), "recording": recording or {}}


def run(tmp_path: Path, sc_map: dict, name: str = "rec"):
    sc = parse_scenario(sc_map)
    rec = run_campaign(sc, tmp_path / name)
    return sc, rec, diagnose(rec)


def named(dg) -> set[str]:
    return {e["name"] for e in dg.report["effects"]}


def test_cogiro_recording_the_model_explains(tmp_path):
    sc, _, dg = run(tmp_path, scenario("cogiro", poses=GRID | {"x": [-4.0, 4.0], "y": [-3.0, 3.0],
                                                                "z": [1.5, 2.5]},
                                       init=(0.0, 0.0, 2.0)))
    rep = dg.report
    assert rep["effects"] == [] and rep["unexplained"] is None, rep["mismatch"]["summary"]
    assert rep["fitted"]["pose_rms_m"] is not None and rep["fitted"]["tension_rms_n"] is not None


def test_ipanema_with_pulleys_exit_offset(tmp_path):
    truth = {"exit_point_offset": {"dx_21": 0.03, "dz_32": -0.02}}
    sc, _, dg = run(tmp_path, scenario("ipanema", truth, GRID | {
        "x": [-2.2, 2.2], "y": [-1.5, 1.5], "z": [2.3, 3.2]}, init=(0.0, 0.0, 2.7)))
    assert named(dg) == {"exit_point_offset"}, dg.report["mismatch"]["summary"]
    s = score(dg.report, sc.effects, sc.model)
    assert not s.failures and s.params_total > 0


@pytest.fixture(scope="module")
def continuous(tmp_path_factory):
    """A continuous recording at 10 Hz along straight moves between four targets, no dwells,
    with a state column: (scenario, recording directory)."""
    truth = {"exit_point_offset": {"dx_21": 0.03, "dy_32": -0.025}}
    poses = {"kind": "list", "visits": 2, "speed_m_s": 0.5, "init_s": 2.0,
             "list": [[5.0, 5.0, 1.0, 0, 0, 0], [15.0, 5.0, 1.2, 0, 0, 0],
                      [15.0, 12.0, 1.0, 0, 0, 0], [6.0, 12.0, 1.4, 0, 0, 0]]}
    sc = parse_scenario(scenario(truth=truth, poses=poses, recording={
        "kind": "continuous", "dwell_at_targets": False, "rate_hz": 10.0,
        "state_column": True}))
    # rest searches along a move from the extrapolated rest: the same rows within 1e-8 m
    return sc, run_campaign(sc, tmp_path_factory.mktemp("continuous") / "rec",
                            plant=campaign_plant(sc, predict=True))


@pytest.mark.parametrize("state", [True, False])
def test_continuous_recording(continuous, tmp_path, state):
    """Diagnosed from its quiet rows of moves, with the state column or without it (the same
    rows: the diagnosis must find the moves and dwells by itself)."""
    sc, rec = continuous
    if not state:
        rec = _edit_csv(rec, tmp_path / "stateless", _drop_column("state"))
    r = read_recording(rec)
    assert (r.state is not None) == state and r.n_samples > 300
    dg = diagnose(rec)
    info = dg.report["mismatch"]["samples"]
    assert info["path_samples"] > 20 and info["dwell_samples"] < 5
    assert named(dg) == {"exit_point_offset"}, dg.report["mismatch"]["summary"]
    assert not score(dg.report, sc.effects, sc.model).failures


def test_a_table_of_poses_one_row_per_pose(tmp_path):
    """A lab's table written one row per standing pose, seconds apart, without a state
    column (recording-format.md: "one row per sample"): every row is a standing measurement.
    Read as rows of a slow, jerky move, 0.3-1 m apart every 5 s, most were dropped as
    accelerating (an independent generator's recording kept 8 of 49 rows)."""
    truth = {"exit_point_offset": {"dx_21": 0.03, "dy_32": -0.025}}
    sc = parse_scenario(scenario(truth=truth))
    rec = run_campaign(sc, tmp_path / "rec")

    def table(rows):
        head, body = rows[0], rows[1:]
        st, t = head.index("state"), head.index("t")
        pose = [head.index(c) for c in ("x_des", "y_des", "z_des", "roll_des", "pitch_des",
                                        "yaw_des")]

        def key(r):
            return (r[st], *(r[c] for c in pose))

        # the last (settled) row of each standing run
        keep = [r for k, r in enumerate(body) if r[st] in ("init", "dwell")
                and (k + 1 == len(body) or key(body[k + 1]) != key(r))]
        for k, r in enumerate(keep):
            r[t] = f"{5.0 * k:.1f}"
        rows[:] = [[v for c, v in enumerate(r) if c != st] for r in [head, *keep]]

    tab = _edit_csv(rec, tmp_path / "table", table)
    r = read_recording(tab)
    assert r.state is None and 15 < r.n_samples < 25
    from bench.diagnosis.samples import prepare
    info = prepare(r).info
    assert info["dwell_samples"] >= r.n_samples - 2 and info["path_rows_accelerating"] == 0
    from bench.iso9283.segments import segment  # ISO 9283 takes each row as a visit

    assert len(segment(r).visits) == r.n_samples - len(r.init_rows)
    dg = diagnose(tab)
    assert named(dg) == {"exit_point_offset"}, dg.report["mismatch"]["summary"]
    assert not score(dg.report, sc.effects, sc.model).failures


def test_without_tensions(tmp_path):
    truth = {"exit_point_offset": {"dx_21": 0.03, "dy_32": -0.025}}
    sc, rec, dg = run(tmp_path, scenario(truth=truth, recording={"load_cells": False}))
    rep = dg.report
    assert not read_recording(rec).has("tau")
    assert named(dg) == {"exit_point_offset"}, rep["mismatch"]["summary"]
    assert "load_cell_calibration" in rep["mismatch"]["untested"]
    assert rep["baseline"]["tension_rms_n"] is None and rep["fitted"]["tension_rms_n"] is None


def test_without_tracker_four_load_cells_high(tmp_path):
    truth = {"load_cell_calibration": {f"gain_{c}": 1.04 for c in ("11", "21", "31", "42")}}
    sc, rec, dg = run(tmp_path, scenario(truth=truth, recording={"tracker": False}))
    rep = dg.report
    assert not read_recording(rec).has("pose_meas")
    assert named(dg) == {"load_cell_calibration"}, rep["mismatch"]["summary"]
    s = score(rep, sc.effects, sc.model)
    assert not s.failures and s.params_total >= 4
    assert rep["baseline"]["pose_rms_m"] is None and "exit_point_offset" in \
        rep["mismatch"]["untested"]


def test_one_softer_cable(tmp_path):
    truth = {"cable_elasticity": {"ea_21": 3.0e5}}
    sc, _, dg = run(tmp_path, scenario(truth=truth, poses=GRID | {"n": [4, 3, 1]}))
    assert named(dg) == {"cable_elasticity"}, dg.report["mismatch"]["summary"]
    e = dg.report["effects"][0]
    assert set(e["params"]) == {"ea_21"}
    assert abs(e["params"]["ea_21"] - 3.0e5) < 0.1 * 3.0e5


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A recording the model explains (ROCASPECT, a small grid)."""
    d = tmp_path_factory.mktemp("plain")
    return run_campaign(parse_scenario(scenario()), d / "rec")


def _edit_csv(src: Path, dst: Path, fn) -> Path:
    import shutil

    shutil.copytree(src, dst)
    rows = list(csv.reader((src / "recording.csv").open()))
    fn(rows)
    with (dst / "recording.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    return dst


def _drop_column(name: str):
    def drop(rows):
        k = rows[0].index(name)
        for r in rows:
            del r[k]
    return drop


def test_an_impossible_tension_is_excluded_by_line_and_column(plain, tmp_path):
    def spoil(rows):
        col = rows[0].index("tau_31")
        rows[40][col] = "1e300"

    rec = _edit_csv(plain, tmp_path / "spoilt", spoil)
    dg = diagnose(rec)
    ex = dg.report["mismatch"]["excluded"]
    assert [(e["row"], e["column"]) for e in ex] == [(41, "tau_31")]
    assert dg.report["effects"] == [] and dg.report["unexplained"] is None
    assert np.isfinite(dg.report["mismatch"]["noise"]["force"])


def test_a_pose_a_kilometre_away_is_excluded_and_its_other_coordinates_say_why(plain,
                                                                              tmp_path):
    """A tracker row with x = 1010 m: x_meas is named as the pose far from the robot; its
    y and z go with it, said so (not "more than 225 m from the robot" of 6.5 m)."""
    from bench.diagnosis.samples import check_values

    def spoil(rows):
        rows[40][rows[0].index("x_meas")] = "1010.0"

    rec = read_recording(_edit_csv(plain, tmp_path / "far", spoil))
    ex = {e["column"]: e for e in check_values(rec)}
    assert set(ex) == {"x_meas", "y_meas", "z_meas"} and ex["x_meas"]["row"] == 41
    assert "from the robot" in ex["x_meas"]["why"]
    assert ex["y_meas"]["why"].startswith("with the rest of its row's position")
    assert not np.isfinite(rec.pose_meas[39, :3]).any()


def test_sagging_hypotheses_are_continuous_with_straight_cables_at_slack_ones(plain):
    """A cable read as slack (its load cell about zero) says only that it is at least as long
    as the straight line, sagging model or not: a hypothesis with nearly weightless cables
    gives the residuals of straight ones (a sag fit starts there)."""
    from bench.diagnosis.residuals import ResidualModel
    from bench.diagnosis.samples import prepare

    rec = read_recording(plain)
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    assert (s.tau < rm.slack_threshold).any()  # the recording has slack cables
    r0 = rm.whitened(rec.robot)
    r1 = rm.whitened(rec.robot.replace(rho=1e-4))  # 0.1 g/m: 1.5 g for a 15 m cable
    assert np.max(np.abs(r1 - r0)) < 0.5 and abs(r1 @ r1 - r0 @ r0) < 0.02 * (r0 @ r0)


def test_tensions_in_the_wrong_unit_are_refused(plain, tmp_path, capsys):
    def scale(rows):
        cols = [k for k, c in enumerate(rows[0]) if c.startswith("tau_")]
        for r in rows[1:]:
            for k in cols:
                r[k] = repr(float(r[k]) * 1e6)

    rec = _edit_csv(plain, tmp_path / "micro", scale)
    with pytest.raises(RecordingError, match="tensions"):
        diagnose(rec)
    assert main(["diagnose", str(rec), "--json", "--quiet", "--jobs", "1"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert "tensions" in out["error"] and "recording.csv" in out["error"]


def test_outputs_are_checked_before_the_fit(plain, tmp_path, capsys):
    blocker = tmp_path / "a_file"  # a missing directory would be made: a file cannot be
    blocker.write_text("x")
    for opt, path in (("--write-model", blocker / "x.toml"),
                      ("--write-model", tmp_path),
                      ("--out", blocker / "r.json")):
        rc = main(["diagnose", str(plain), "--json", "--jobs", "1", opt, str(path)])
        out, err = capsys.readouterr()
        assert rc == 2 and opt in json.loads(out)["error"]
        assert "samples" not in err  # refused before the recording was even read
    (tmp_path / "file.png").write_text("not a directory")
    rc = main(["diagnose", str(plain), "--json", "--quiet", "--plots", str(tmp_path / "file.png")])
    assert rc == 2 and "--plots" in json.loads(capsys.readouterr().out)["error"]


def test_backlash_on_one_cable_is_declared_not_named(tmp_path):
    sc, _, dg = run(tmp_path, scenario(nuisance={"backlash_m": 0.003,
                                                 "backlash_cables": ["21"]},
                                       poses=GRID | {"n": [4, 3, 1], "visits": 3}))
    un = dg.report["unexplained"]
    assert un is not None, dg.report["mismatch"]["summary"]
    assert "21" in un["summary"]
    assert all(e.get("provisional") for e in dg.report["effects"])
    assert "does not explain" in dg.report["mismatch"]["summary"]
    # the lengths depend on the direction, the load cells do not
    assert "load_cell_direction_cables" not in un
    assert max(abs(v["z"]) for v in un["load_cell_direction"].values()) < 8.0


def test_friction_at_one_load_cell_is_declared_with_its_cable(tmp_path):
    """The cell of cable 21 reads 8 N less while its cable pays out, 8 N more while it reels
    in: the report says which load cell reads by the direction of motion, and how much."""
    sc, _, dg = run(tmp_path, scenario(nuisance={"friction_n": 8.0, "friction_cables": ["21"]},
                                       poses=GRID | {"n": [4, 3, 1], "visits": 3}))
    un = dg.report["unexplained"]
    assert un is not None, dg.report["mismatch"]["summary"]
    assert un["load_cell_direction_cables"] == ["21"], un["summary"]
    assert "load cell of cable 21" in un["summary"]
    assert 12.0 < un["load_cell_direction"]["21"]["difference_n"] < 20.0  # truth 16 N
    assert all(e.get("provisional") for e in dg.report["effects"])


@pytest.mark.parametrize("truth", [
    {"load_cell_calibration": {"gain_21": 1.04, "gain_32": 0.97, "offset_41": 8.0}},
    {"platform_mass": {"mass": 38.0, "com_x": 0.02}},
], ids=["load_cells", "mass"])
def test_no_direction_dependent_load_cell_without_friction(tmp_path, truth):
    """Miscalibrated load cells or another mass change the force balance by pose, never by
    the direction of motion: named, and nothing declared unexplained."""
    sc, _, dg = run(tmp_path, scenario(truth=truth))
    assert named(dg) == set(truth), dg.report["mismatch"]["summary"]
    assert dg.report["unexplained"] is None, dg.report["unexplained"]["summary"]


def test_thermal_drift_is_declared_not_named(tmp_path):
    sc, _, dg = run(tmp_path, scenario(nuisance={"thermal_strain_per_h": 1.5e-3},
                                       poses=GRID | {"n": [4, 3, 1], "visits": 3}))
    un = dg.report["unexplained"]
    assert un is not None, dg.report["mismatch"]["summary"]
    assert all(e.get("provisional") for e in dg.report["effects"])


def test_a_slip_never_applies_to_the_initialisation(tmp_path):
    truth = {"cable_length_offset": {"dl_31": 0.004}}
    sc, _, dg = run(tmp_path, scenario(truth=truth))
    rm = dg.rm
    assert np.all(rm.slip_times >= rm.init_end)
    assert named(dg) == {"cable_length_offset"}
    assert abs(dg.report["effects"][0]["params"]["dl_31"] - 0.004) < 5e-4
    # the initialisation sample keeps the reading as referenced: the fitted model leaves it
    # at the noise (with the offset applied there too it would stand 4 mm off)
    k = sc.model.cable_ids.index("31")
    init = np.flatnonzero(dg.samples.is_init)
    left = rm.blocks(dg.fitted_robot).length[init, k]
    assert np.all(np.abs(left) < 5 * rm.sd["length"][init]), left
    assert dg.report["unexplained"] is None, dg.report["unexplained"]["summary"]


def test_corrected_model_writes_only_what_the_report_names(tmp_path):
    truth = {"mast_compliance": {f"k{a}_{m}": 3e5 for m in "1234" for a in "xy"}}
    sc = parse_scenario(scenario(truth=truth, poses=GRID | {"n": [4, 3, 1]}))
    rec = run_campaign(sc, tmp_path / "rec")
    out = tmp_path / "corrected.toml"
    dg = diagnose(rec, write_model=out)
    text = out.read_text()
    assert "1e+15" not in text and "1e15" not in text
    from controller.robot import load_robot

    robot = load_robot(out)
    comp = next(e for e in dg.report["effects"] if e["name"] == "mast_compliance")
    for i, m in enumerate(robot.mast_ids):
        for a, ax in enumerate("xyz"):
            key = f"k{ax}_{m}"
            if key in comp["params"]:
                assert robot.stiffness[i, a] == pytest.approx(comp["params"][key])
            else:  # not named (undetermined or the model's): rigid as in the model, inf
                assert robot.stiffness[i, a] == np.inf, key


def test_a_rigid_axis_beside_named_stiffness_is_written_as_inf(tmp_path):
    """A mast with kx and ky named and kz left as the model had it (rigid) is written as
    ``[kx, ky, inf]`` (TOML's inf), read back as rigid about z, never a large stand-in."""
    from controller.robot import dumps_robot, load_robot, save_robot, shipped_robot_path

    model = load_robot(shipped_robot_path("rocaspect"))
    stiff = np.full((model.n_masts, 3), np.inf)
    stiff[0, :2] = [2.0e5, 5.0e5]
    text = dumps_robot(model.replace(stiffness=stiff))
    assert "1e+15" not in text and "inf" in text
    back = load_robot(save_robot(model.replace(stiffness=stiff), tmp_path / "r.toml"))
    assert back.stiffness[0].tolist() == [2.0e5, 5.0e5, np.inf]
    assert np.all(np.isinf(back.stiffness[1:]))
    # -inf or nan stays an error that names the field
    bad = (tmp_path / "r.toml").read_text().replace("inf", "nan", 1)
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(Exception, match="stiffness"):
        load_robot(tmp_path / "bad.toml")


def test_friction_on_every_load_cell_below_one_cells_bar_is_declared_together(tmp_path):
    """Every cell reads 8 N less while its cable pays out and 8 N more while it reels in, the
    cells' noise 4 N: no cell alone stands out (z 3 to 6), all together do (case 12986 of
    seed 12800, IPAnema: E*A and length offsets named at 60 to 90 N of friction, nothing
    declared). Declared, the effects named beside it provisional."""
    sc, _, dg = run(tmp_path, scenario(
        nuisance={"friction_n": 8.0, "friction_cables": ["11", "12", "21", "22", "31", "32",
                                                         "41", "42"]},
        poses=GRID | {"n": [4, 3, 1], "visits": 3}) | {"noise": {"load_cell_n": 4.0}})
    un = dg.report["unexplained"]
    assert un is not None, dg.report["mismatch"]["summary"]
    assert max(abs(v["z"]) for v in un["load_cell_direction"].values()) < 8.0
    assert un["load_cell_direction_joint_z"] > 8.0
    assert len(un["load_cell_direction_cables"]) >= 5, un["summary"]
    assert all(e.get("provisional") for e in dg.report["effects"])
