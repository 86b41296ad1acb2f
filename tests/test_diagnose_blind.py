"""The diagnosis on recordings with concealed effects: it is never told what the truth is.

Each scenario file in ``tests/data/scenarios`` conceals effects in the simulated
robot; its campaign is recorded on the plant (the truth solved by energy
minimisation, with hysteresis, drift and per-visit noise outside the vocabulary)
and diagnosed blind. The diagnosis must name exactly the concealed effects,
recover the key parameters (stiffness within 25 %, offsets within 5 mm, gains
within 1 %, EA within 10 %) and bring held-out poses down to the noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.campaign import run_campaign
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread, score
from firmware_sim.scenario import load_scenario


@pytest.fixture(scope="module", autouse=True)
def _one_blas_thread():
    """The diagnosis's small matrices run fastest on one BLAS thread (threads spin against
    each other and other jobs on a loaded machine), as in ``cdpr diagnose``."""
    one_blas_thread()

SCENARIOS = Path(__file__).parent / "data" / "scenarios"

CASES = {
    # file: concealed effects the report must name (exactly)
    "none.toml": set(),
    "none_corner.toml": set(),
    "model_has_compliance.toml": set(),
    "exit_point_offset.toml": {"exit_point_offset"},
    "mast_compliance.toml": {"mast_compliance"},
    "cable_elasticity.toml": {"cable_elasticity"},
    "cable_length_offset.toml": {"cable_length_offset"},
    "drum_scale.toml": {"drum_scale"},
    "load_cell_calibration.toml": {"load_cell_calibration"},
    "platform_mass.toml": {"platform_mass"},
    "pulley_kinematics.toml": {"pulley_kinematics"},
    "cable_sag.toml": {"cable_sag"},
    "paper.toml": {"exit_point_offset", "mast_compliance"},
    "elasticity_drum.toml": {"cable_elasticity", "drum_scale"},
    "loadcell_slip.toml": {"load_cell_calibration", "cable_length_offset"},
}


@pytest.fixture(scope="session")
def diagnosed(tmp_path_factory):
    """Record and diagnose a scenario once per session."""
    cache: dict[str, tuple] = {}

    def get(name: str):
        if name not in cache:
            sc = load_scenario(SCENARIOS / name)
            rec = run_campaign(sc, tmp_path_factory.mktemp(name.replace(".toml", "")) / "rec")
            cache[name] = (sc, rec, diagnose(rec, write_model=rec.parent / "corrected.toml"))
        return cache[name]

    return get


def expand(sc) -> dict[str, dict[str, float]]:
    truth = {e: dict(p) for e, p in sc.effects.items()}
    if "pulley_kinematics" in truth and "r" in truth["pulley_kinematics"]:
        r = truth["pulley_kinematics"].pop("r")
        truth["pulley_kinematics"].update({f"r_{c}": r for c in sc.model.cable_ids})
    return truth


@pytest.mark.parametrize("name", sorted(CASES))
def test_names_exactly_the_concealed_effects_and_recovers_them(diagnosed, name):
    sc, rec, dg = diagnosed(name)
    rep = dg.report
    named = {e["name"] for e in rep["effects"]}
    assert named == CASES[name], rep["mismatch"]["summary"]
    s = score(rep, expand(sc), sc.model)
    assert not s.failures, s.failures
    if CASES[name]:
        assert s.params_total > 0
        # held-out poses come down to the noise (the replicate spread of the tracker poses)
        noise = rep["mismatch"]["noise"]["pose_m"]
        assert rep["fitted"]["heldout_pose_rms_m"] < 1.6 * noise
        b, f = rep["baseline"], rep["fitted"]
        # the fit improves what the effect disturbs: poses, or tensions (load cells, mass)
        assert (b["pose_rms_m"] > 3 * f["pose_rms_m"]
                or b["tension_rms_n"] > 1.3 * f["tension_rms_n"])
        for e in rep["effects"]:
            assert e["evidence"]["delta_bic"] < -10
            before = e["evidence"]["heldout_pose_rms_before_m"]
            after = e["evidence"]["heldout_pose_rms_after_m"]
            assert after <= before * 1.05


def test_paper_case_stiffness_and_offsets(diagnosed):
    sc, rec, dg = diagnosed("paper.toml")
    comp = next(e for e in dg.report["effects"] if e["name"] == "mast_compliance")
    for m in "1234":
        assert abs(comp["params"][f"kx_{m}"] - 2e5) < 0.25 * 2e5
        assert abs(comp["params"][f"ky_{m}"] - 5e5) < 0.25 * 5e5
    off = next(e for e in dg.report["effects"] if e["name"] == "exit_point_offset")
    assert abs(off["params"]["dy_12"] - 0.088) < 5e-3


def test_corrected_model_loads_and_reproduces_the_fitted_figures(diagnosed):
    """The corrected robot.toml is a robot like any other; re-simulating the recording
    with it gives the fitted figures."""
    from controller.robot import load_robot

    sc, rec, dg = diagnosed("mast_compliance.toml")
    path = Path(dg.report["model"])
    robot = load_robot(path)
    assert np.all(np.isfinite(robot.stiffness[:, :2]))
    fw = dg.rm.forward(robot)
    d = np.linalg.norm(fw.pose_err[:, :3], axis=1)
    assert np.sqrt(np.nanmean(d**2)) == pytest.approx(dg.report["fitted"]["pose_rms_m"], rel=1e-6)


def test_a_slip_in_the_middle_is_located_in_time(diagnosed):
    sc, rec, dg = diagnosed("slip_mid_campaign.toml")
    steps = dg.report["mismatch"]["steps"]
    assert [s["cable"] for s in steps] == ["31"]
    assert abs(steps[0]["t_s"] - 300.0) < 40.0
    # step_m is the change of dl_31 (+5 mm): the reading itself jumped by -5 mm, and the
    # summary says so in the reading's sign
    assert abs(steps[0]["step_m"] - 0.005) < 5e-4
    assert "cable 31's length reading jumps by about -5." in dg.report["mismatch"]["summary"]
    named = [e["name"] for e in dg.report["effects"]]
    assert named == ["cable_length_offset"]
    e = dg.report["effects"][0]
    assert abs(e["params"]["dl_31"] - 0.005) < 5e-4
    assert "t = " in e["explains"]


def test_no_step_is_found_without_a_slip(diagnosed):
    for name in ("none.toml", "mast_compliance.toml", "drum_scale.toml"):
        assert diagnosed(name)[2].report["mismatch"]["steps"] == []


def test_forward_figures_converge_by_newton_under_a_model_far_from_the_truth(diagnosed):
    """The baseline figures solve each sample's equilibrium under the recording's model,
    centimetres from the truth: started where that model nearly balances (the commanded
    pose), Newton converges without the energy-descent fallback."""
    from controller import equilibrium

    sc, rec, dg = diagnosed("paper.toml")
    equilibrium.STATS.reset()
    fw = dg.rm.forward(dg.recording.robot)
    stats = equilibrium.STATS.as_dict()
    assert fw.ok.all() and stats["calls"] == dg.samples.n
    assert stats["fallbacks"] == 0 and stats["failures"] == 0, stats


def test_encoders_referenced_to_the_deflected_exits_are_read_so(diagnosed, tmp_path):
    """The conventions' d_model(p0), "the model's geometric length", is silent on a model
    with compliant masts: this project's controller measures it to the description's exit
    points, another may to the exits its masts take under the tensions at initialisation
    (centimetres apart on a large robot). The same null recording with its encoders
    referenced the other way (every reading shifted by the difference) is read the other
    way and names nothing; the recording as it is keeps this project's reading."""
    import csv
    import shutil

    from bench.recording import read_recording
    from controller.cycle import deflected_reference_lengths, reference_lengths

    sc, rec, dg = diagnosed("model_has_compliance.toml")
    assert dg.report["mismatch"]["encoder_reference"]["reading"] == "description"
    r = read_recording(rec)
    shift = deflected_reference_lengths(r.robot, r.init_pose, r.init_tensions) \
        - reference_lengths(r.robot, r.init_pose)
    assert np.abs(shift).max() > 5e-3  # (the masts bend by centimetres under 35 kg)
    other = tmp_path / "other"
    shutil.copytree(rec, other)
    rows = list(csv.reader((other / "recording.csv").open()))
    head = rows[0]
    for k, c in enumerate(r.robot.cable_ids):
        for col in (f"l_meas_{c}", f"l_cmd_{c}"):
            if col in head:
                j = head.index(col)
                for row in rows[1:]:
                    row[j] = repr(float(float(row[j]) + shift[k]))
    with (other / "recording.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    rep = diagnose(other).report
    assert rep["mismatch"]["encoder_reference"]["reading"] == "deflected"
    assert rep["effects"] == [], rep["mismatch"]["summary"]


def test_load_cells_at_the_platform_anchors_are_read_so(diagnosed, tmp_path):
    """Where a load cell sits along a sagging cable the format does not say: at the platform
    anchor it reads the tension at the exit point less the cable's weight between the ends
    (rho g dz, a few newtons that change with the pose). The sag recording (cells at the
    exit points, this project's plant) keeps its reading and names the sag alone; the same
    recording with every reading moved to the anchor is read there and names the sag alone
    too, not offsets on every cell beside it."""
    import csv
    import shutil

    from bench.recording import read_recording
    from controller.statics import weight_between_ends

    sc, rec, dg = diagnosed("cable_sag.toml")
    assert dg.report["mismatch"]["load_cells"] == {"at": "exit"}
    r = read_recording(rec)
    truth = r.robot.replace(rho=sc.effects["cable_sag"]["rho"])
    pose = np.where(np.isfinite(r.pose_meas), r.pose_meas, r.pose_des)
    drop = weight_between_ends(truth, pose)  # (rows, n) [N]
    assert 1.0 < np.nanmax(drop) < 30.0
    other = tmp_path / "other"
    shutil.copytree(rec, other)
    rows = list(csv.reader((other / "recording.csv").open()))
    head = rows[0]
    for k, c in enumerate(r.robot.cable_ids):
        j = head.index(f"tau_{c}")
        for i, row in enumerate(rows[1:]):
            row[j] = repr(float(float(row[j]) - drop[i, k]))
    with (other / "recording.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    rep = diagnose(other).report
    assert rep["mismatch"]["load_cells"] == {"at": "anchor"}
    assert [e["name"] for e in rep["effects"]] == ["cable_sag"], rep["mismatch"]["summary"]
    rho = rep["effects"][0]["params"]["rho"]
    assert abs(rho - 0.06) < 0.006
