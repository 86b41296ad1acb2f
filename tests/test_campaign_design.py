"""``cdpr campaign design``: D-optimal poses for the parameters, T-optimal ones for the
alternatives, on the diagnosis's own residual model; the path it writes is what ``cdpr
campaign --path`` visits."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from bench import campaign_design as cd
from bench.cli import main
from controller import design
from controller.paths import load_path
from controller.statics import pose_statics

SCENARIO = """
format = "cdpr-scenario/1"
robot = "rocaspect"
seed = 5
init_pose = [10.0, 8.56, 1.2, 0.0, 0.0, 0.0]

[noise]
tracker_m = 3.0e-5
tracker_rad = 2.0e-5
load_cell_n = 0.5
encoder_m = 1.0e-6
process_m = 2.0e-4
exit_m = 5.0e-5

[truth.pulley_kinematics]
r_11 = 0.06
r_22 = 0.06

[poses]
kind = "list"
list = [[8.0, 7.0, 1.2, 0, 0, 0], [12.0, 7.0, 1.2, 0, 0, 0], [10.0, 10.0, 1.2, 0, 0, 0]]
visits = 1
dwell_s = 1.0
rate_hz = 2.0
init_s = 2.0
"""

NOISE = {"length": 2e-4, "force": 0.5, "moment": 0.5, "exit": 1e-4}
RADII = {f"r_{c}": 0.06 for c in ("11", "12", "21", "22", "31", "32", "41", "42")}


def _report(effects: list[dict]) -> dict:
    return {"format": "cdpr-diagnosis/1", "recording": "", "effects": effects,
            "mismatch": {"noise": NOISE}}


def _pulley(alternatives: list[dict]) -> dict:
    return {"name": "pulley_kinematics", "params": RADII, "undetermined": [],
            "alternatives": alternatives}


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    p = tmp_path_factory.mktemp("design") / "sc.toml"
    p.write_text(SCENARIO)
    return p


@pytest.fixture(scope="module")
def ctx(scenario):
    return cd.context(_report([]), scenario, scenario=scenario)


@pytest.fixture(scope="module")
def candidates(ctx):
    return cd.candidate_poses(ctx.model, ctx, 24, np.random.default_rng(3))


def test_the_preferred_hypothesis_explains_its_own_synthetic_data(ctx, candidates):
    """One physics: the data made by the hypothesis leave it no residual in the diagnosis's
    residual model, and another hypothesis a large one."""
    hyp = cd.hypotheses(_report([_pulley([])]), ctx.model)
    rm, kept = cd.residual_model(hyp.robot, ctx, candidates[:8])
    assert len(kept) == 8
    r = rm.whitened(hyp.robot)
    assert np.max(np.abs(r)) < 0.05
    assert np.max(np.abs(rm.whitened(ctx.model))) > 10.0


def test_d_optimal_beats_random_poses_and_keeps_them_feasible(ctx, candidates):
    hyp = cd.hypotheses(_report([_pulley([])]), ctx.model)
    pc = cd.pieces(hyp, ctx, candidates)
    n = 6
    d = design.choose(pc.F, n)
    prior = np.eye(pc.F.shape[1]) * 1e-6
    rng = np.random.default_rng(0)
    rand = [design.logdet(design.information(pc.F, rng.choice(len(pc.F), n, replace=False),
                                             1, prior)) for _ in range(30)]
    assert d.logdet > max(rand)
    assert len(set(d.indices.tolist())) == n
    for p in pc.poses[d.indices]:
        ps = pose_statics(hyp.robot, p)
        assert ps.feasible and ps.tensions.max() <= ctx.model.tension_max


def test_discrimination_picks_the_poses_where_the_alternatives_differ():
    """Pure: ten candidates carry the same information; only candidates 3 and 7 show a
    difference the alternative cannot fit away. The T-criterion takes both, the D-criterion
    alone has no reason to."""
    C, p = 10, 2
    F = np.stack([np.eye(p)] * C)
    d = [np.zeros(3) for _ in range(C)]
    d[3], d[7] = np.array([0.0, 0.0, 4.0]), np.array([0.0, 3.0, 0.0])
    K = [np.array([[1.0], [0.0], [0.0]]) for _ in range(C)]
    alt = design.Alternative.from_rows("other", d, K, np.eye(1) * 1e-6)
    got = design.choose(F, 2, [alt], target=20.0)
    assert sorted(got.indices.tolist()) == [3, 7]
    assert got.delta["other"] == pytest.approx(25.0)
    assert got.separated["other"]
    # an alternative whose parameters make every difference (one shift fits them all) is
    # never separated, whichever poses
    same = [np.array([0.0, 3.0, 4.0]) if i in (3, 7) else np.zeros(3) for i in range(C)]
    K_all = [np.eye(3) if i in (3, 7) else np.zeros((3, 3)) for i in range(C)]
    fits = design.Alternative.from_rows("fits", same, K_all, np.eye(3) * 1e-6)
    got = design.choose(F, 2, [fits], target=20.0)
    assert got.delta["fits"] < 1e-3 and not got.separated["fits"]


def test_design_separates_pulleys_from_exit_offsets(ctx, candidates):
    rep = _report([_pulley([{"name": "exit_point_offset", "delta_bic": 1.5}])])
    res = cd.run_design(rep, ctx, 6, visits=2, candidates=40)
    label = "exit_point_offset instead of pulley_kinematics"
    assert res.design.separated[label]
    # the poses chosen for the alternative show more difference than a parameters-only design
    hyp = cd.hypotheses(rep, ctx.model)
    pc = cd.pieces(hyp, ctx, cd.candidate_poses(hyp.robot, ctx, 40,
                                                np.random.default_rng(0)))
    d_only = design.choose(pc.F, 6, visits=2)
    assert res.design.delta[label] >= design.discrimination(pc.alts[0], d_only.indices, 2) \
        * (1 - 1e-9)
    assert any("separates them" in n for n in res.notes)


def test_nothing_to_separate_gives_a_design_for_the_parameters_only(ctx):
    res = cd.run_design(_report([_pulley([])]), ctx, 4, candidates=30)
    assert res.design.delta == {}
    assert res.notes == ["the report names no alternative: a design for the parameters only "
                         "(D-optimal; nothing to separate)"]
    res = cd.run_design(_report([]), ctx, 4, candidates=30)
    assert "nothing to separate" in res.notes[0]
    assert {k.split("_")[0] for k in res.stderr} == {"dx", "dy", "dz", "kx", "ky", "kz"}


def test_cli_writes_a_path_that_the_campaign_visits(scenario, tmp_path, capsys):
    rep = tmp_path / "report.json"
    rep.write_text(json.dumps(_report([_pulley([{"name": "exit_point_offset",
                                                  "delta_bic": 1.5}])])))
    out = tmp_path / "designed.toml"
    rc = main(["campaign", "design", str(rep), "--scenario", str(scenario), "--poses", "3",
               "--candidates", "25", "--visits", "1", "--out", str(out), "--json"])
    got = json.loads(capsys.readouterr().out)
    assert rc == 0 and got["path"] == str(out) and len(got["poses"]) == 3
    assert got["path_check"] == "ok"  # the dry run's check of the whole path, from init
    assert got["alternatives"][0]["name"] == "exit_point_offset instead of pulley_kinematics"
    spec = load_path(out)
    assert np.allclose(np.array(spec.segments[0].poses), got["poses"], atol=1e-6)
    rc = main(["campaign", str(scenario), str(tmp_path / "rec"), "--path", str(out),
               "--quiet", "--json"])
    done = json.loads(capsys.readouterr().out)
    assert rc == 0 and done["poses"] == 3 and done["visits"] == 3


def test_a_visiting_order_that_passes_the_path_check_is_chosen(ctx, monkeypatch):
    """A straight move between two feasible poses can leave the workspace: another
    ``shuffle`` seed is tried; where none passes, the first seed's text and why."""
    res = cd.run_design(_report([_pulley([])]), ctx, 3, candidates=30)
    tried = []

    def check(text, ctx_):
        seed = int(re.search(r"^seed = (\d+)$", text, re.M).group(1))
        tried.append(seed)
        return "" if seed == good else f"fails at seed {seed}"

    monkeypatch.setattr(cd, "check_path", check)
    good = 7
    text, problem = cd.checked_document(res, 2, "r.json", ctx, seed=5)
    assert problem == "" and "seed = 7" in text and tried == [5, 6, 7]
    good, tried[:] = -1, []
    text, problem = cd.checked_document(res, 2, "r.json", ctx, seed=5)
    assert "seed = 5\n" in text and len(tried) == cd.ORDER_TRIES
    assert problem.startswith("fails at seed 5") and "seeds 5 to 20" in problem


def test_cli_refuses_what_it_cannot_use(scenario, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "other"}))
    rc = main(["campaign", "design", str(bad), "--scenario", str(scenario), "--poses", "3",
               "--json"])
    err = json.loads(capsys.readouterr().out)["error"]
    assert rc == 2 and str(bad) in err and "format" in err
    rep = tmp_path / "r.json"
    rep.write_text(json.dumps(_report([])))
    assert main(["campaign", "design", str(rep), "--poses", "3"]) == 2
    assert "exactly one of --site" in capsys.readouterr().err
    assert main(["campaign", "design", str(rep), "--scenario", str(scenario)]) == 2
    assert "--poses N is required" in capsys.readouterr().err
    assert main(["campaign", str(scenario), str(tmp_path / "x"), "--out", "y.toml"]) == 2
    assert "only with 'cdpr campaign design" in capsys.readouterr().err


def test_poses_to_match_stops_at_the_first_design_that_reaches_the_reference():
    """Pure: candidate i informs parameter i % 3 with weight i + 1; the reference is what the
    two most informative candidates of each parameter give once."""
    C, p = 12, 3
    F = np.zeros((C, p, p))
    for i in range(C):
        F[i, i % p, i % p] = i + 1.0
    ref = 1.0 / np.sqrt(np.array([10.0 + 7.0, 11.0 + 8.0, 12.0 + 9.0]))
    count, idx = design.poses_to_match(F, ref, np.arange(p), visits=1)
    se = design.standard_errors(F, idx, 1, np.eye(p) * 1e-6)  # the prior poses_to_match adds
    assert count == len(idx) and np.all(se <= ref)
    assert count == 6  # two per parameter: fewer cannot reach it
    # visits count as information: twice the visits, fewer poses
    count2, _ = design.poses_to_match(F, ref, np.arange(p), visits=2)
    assert count2 < count
    assert design.poses_to_match(F, ref / 100, np.arange(p), visits=1, n_max=5)[0] == -1


def test_the_load_cells_gauge_is_said_to_need_more_than_poses(ctx):
    """A gain shared by every load cell against the platform's mass: one in the statics, the
    stretch of the cables is all that differs (0.5 % of it): no set of poses separates them,
    and the design says what would."""
    gains = {f"gain_{c}": 1.005 for c in ("11", "12", "21", "22", "31", "32", "41", "42")}
    rep = _report([{"name": "load_cell_calibration", "params": gains, "undetermined": [],
                    "alternatives": [{"name": "platform_mass", "delta_bic": 2.0,
                                      "note": "a mass instead of a common gain"}]}])
    res = cd.run_design(rep, ctx, 4, candidates=30)
    (label, delta), = res.design.delta.items()
    assert label == "platform_mass instead of load_cell_calibration"
    assert delta < cd.TARGET and not res.design.separated[label]
    assert "poses alone do not tell them apart; a known extra mass" in res.notes[0]


@pytest.mark.slow
def test_a_designed_campaign_settles_what_the_first_diagnosis_left_open():
    """The whole flow on the simulator (bench.design_eval): concealed pulley radii, a first
    campaign of poses close together whose diagnosis names exit offsets as an alternative;
    the designed campaign's diagnosis names the pulleys alone."""
    from bench.design_eval import run_case

    got = run_case(9023, poses=8)
    assert got["alternatives"] == ["exit_point_offset for pulley_kinematics"]
    assert got["second"] == ["pulley_kinematics"] and got["left"] == []
    assert got["settled"]


def test_marginal_information_loses_only_what_the_nuisance_imitates():
    """Pure: parameter 0's rows are a nuisance's rows (it can fit them away): its information
    goes; parameter 1, orthogonal to the nuisance, keeps all of its own."""
    Jt = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 0.0]])
    Je = np.array([[1.0], [0.0], [1.0]])
    M = design.marginal_information(Jt, Je)
    assert M[0, 0] == pytest.approx(0.0, abs=1e-12) and M[1, 1] == pytest.approx(4.0)
    # no nuisance (every cable measured): nothing lost
    assert np.allclose(design.marginal_information(Jt, np.zeros((3, 0))), Jt.T @ Jt)
    Jp = [Jt, 2 * Jt]
    Jr = [np.hstack([Je, np.zeros((3, 1))]), np.zeros((3, 2))]
    G = design.measured_information(Jp, Jr, [np.zeros((3, 2))] * 2, np.array([True, True]))
    assert np.allclose(G, np.stack([j.T @ j for j in Jp]))
    # cable 0 unmeasured: candidate 0 loses parameter 0, candidate 1 (not moved by it) not
    G = design.measured_information(Jp, Jr, [np.zeros((3, 2))] * 2, np.array([False, True]))
    assert G.shape == (2, 3, 3)
    M = design.eliminate(G.sum(axis=0), 1)
    assert M[0, 0] == pytest.approx(8.0) and M[1, 1] == pytest.approx(4.0 + 16.0)


def _gauge_report(model) -> dict:
    gains = {f"gain_{c}": 1.0 for c in model.cable_ids}
    return _report([{"name": "load_cell_calibration", "params": gains, "undetermined": [],
                     "alternatives": []}])


def test_identifiability_with_only_some_cables_measured(ctx, candidates):
    """A cable without a load cell: its gain and offset cannot be fixed (they are lost), the
    others still are; with every cable measured nothing is lost."""
    hyp = cd.hypotheses(_gauge_report(ctx.model), ctx.model)
    poses = candidates[:8]
    every = cd.identifiability(hyp, ctx, poses, 2, cd.measured_mask(ctx.model, None))
    assert every["lost"] == [] and every["measured"] == every["all"]
    assert every["all"]["undetermined"] == []
    some = cd.identifiability(hyp, ctx, poses, 2,
                              cd.measured_mask(ctx.model, ["11", "22", "31", "42"]))
    off = ("12", "21", "32", "41")
    assert sorted(some["lost"]) == sorted([f"{k}_{c}" for c in off for k in ("gain", "offset")])
    se, se_all = some["measured"]["stderr"], some["all"]["stderr"]
    assert se["gain_11"] >= se_all["gain_11"]  # less data, never better
    assert se["gain_12"] > 100 * se_all["gain_12"]
    with pytest.raises(cd.DesignError, match="--load-cells: 99"):
        cd.measured_mask(ctx.model, ["11", "99"])


def test_cli_says_what_only_some_load_cells_fix(scenario, tmp_path, capsys):
    rep = tmp_path / "report.json"
    rep.write_text(json.dumps(_gauge_report(cd.context(_report([]), scenario,
                                                       scenario=scenario).model)))
    rc = main(["campaign", "design", str(rep), "--scenario", str(scenario), "--poses", "6",
               "--candidates", "20", "--load-cells", "11,12,21,22,31,32,41", "--json"])
    got = json.loads(capsys.readouterr().out)
    assert rc == 0 and got["identifiability"]["lost"] == ["gain_42", "offset_42"]
    assert any(n.startswith("with load cells on 11, 12, 21, 22, 31, 32, 41 only: "
                            "undetermined gain_42, offset_42") for n in got["notes"])
    rc = main(["campaign", "design", str(rep), "--scenario", str(scenario), "--poses", "3",
               "--candidates", "20", "--load-cells", "11,x", "--json"])
    assert rc == 2 and "--load-cells: x" in json.loads(capsys.readouterr().out)["error"]


def test_matching_design_brings_the_largest_ratio_down():
    """Pure: rank-one candidates in 4 parameters; the matching design (exchange, several
    starts) leaves a largest ratio to the reference no worse than the greedy A-design of
    the same size, and fewest_to_match never needs more poses than the greedy count."""
    rng = np.random.default_rng(7)
    C, p = 40, 4
    v = rng.normal(size=(C, p)) * np.array([1.0, 1.0, 0.3, 0.1])
    F = np.einsum("ci,cj->cij", v, v)
    keys = np.arange(p)
    prior = np.eye(p) * 1e-6
    ref = design.standard_errors(F, np.arange(C)[:20], 1, prior)  # 20 poses, in order
    greedy_n, greedy = design.poses_to_match(F, ref, keys, 1)
    assert greedy_n > 0
    n = max(greedy_n - 1, p)
    _, first = design.poses_to_match(F, ref * 1e-3, keys, 1, n_max=n)  # greedy, n poses
    got = design.choose_matching(F, n, keys, ref, 1)
    assert len(set(got.tolist())) == n
    worst = np.max(design.standard_errors(F, got, 1, prior) / ref)
    assert worst <= np.max(design.standard_errors(F, first, 1, prior) / ref) + 1e-12
    count, idx = design.fewest_to_match(F, ref, keys, 1)
    assert 0 < count < greedy_n and len(idx) == count  # exchange: 14 poses, greedy 17
    assert np.all(design.standard_errors(F, idx, 1, prior) <= ref)


def test_relaxed_design_bounds_every_exact_design_of_the_same_visits():
    """Pure property: the approximate design (weights) minimises the convex ratio cost over
    all weightings, so no exact set of n poses (n visits in all) has a lower cost than it
    (random sets, the greedy and the matching design); and its equivalence condition holds:
    no candidate's gain above the weighted mean by more than a few per cent."""
    rng = np.random.default_rng(11)
    C, p, n = 60, 5, 8
    v = rng.normal(size=(C, 2, p)) * np.array([1.0, 1.0, 0.4, 0.2, 0.1])
    F = np.einsum("cri,crj->cij", v, v)
    keys = np.array([0, 2, 3, 4])
    prior = np.eye(p) * 1e-6
    ref = design.standard_errors(F, np.arange(C)[:30], 1, prior)[keys]
    w = design.relaxed_weights(F, keys, ref, float(n), prior, iters=2000)
    assert np.all(w >= 0) and w.sum() == pytest.approx(1.0)
    relaxed = float(design.ratio_cost(prior + n * np.einsum("c,cij->ij", w, F), keys, ref))
    uniform = float(design.ratio_cost(prior + n * F.mean(axis=0), keys, ref))
    assert relaxed < uniform
    sets = [rng.choice(C, n, replace=False) for _ in range(200)]
    sets.append(design.choose_matching(F, n, keys, ref, 1))
    exact = [float(design.ratio_cost(design.information(F, S, 1, prior), keys, ref))
             for S in sets]
    assert relaxed <= min(exact) * (1 + 1e-3)
    # and the matching design is near the bound (within a few per cent here)
    assert exact[-1] <= relaxed * 1.25


def test_matching_design_uses_the_relaxed_start():
    """The exchange from the approximate design's heaviest candidates can only lower the
    cost the greedy start reaches (the best of the starts is kept)."""
    rng = np.random.default_rng(5)
    C, p, n = 50, 6, 9
    v = rng.normal(size=(C, p)) * np.geomspace(1.0, 0.05, p)
    F = np.einsum("ci,cj->cij", v, v)
    keys = np.arange(p)
    prior = np.eye(p) * 1e-6
    ref = design.standard_errors(F, np.arange(C)[:25], 1, prior)
    got = design.choose_matching(F, n, keys, ref, 1, starts=2)
    _, greedy = design.poses_to_match(F, ref * 1e-3, keys, 1, n_max=n)
    cost = [float(design.ratio_cost(design.information(F, S, 1, prior), keys, ref))
            for S in (got, greedy)]
    assert cost[0] <= cost[1] + 1e-12


def test_match_summary_groups_and_smallest_n():
    """Pure: per group the median over draws of each parameter, the group's median and worst
    of those; the smallest N is the upper median of the draws' counts (a draw that never
    reaches counts as infinitely many)."""
    from bench.design_eval import match_summary

    def draw(d, need, kx, dx):
        ratios = {"kx_1": kx, "dx_11": dx, "dy_11": 0.5}
        return {"draw": d, "poses_needed": need, "predicted": ratios, "diagnosed": ratios,
                "missing": []}

    res = [draw(0, 12, 0.8, 0.9), draw(1, 14, 1.2, 0.7), draw(2, -1, 0.9, 1.1)]
    s = match_summary(res)
    assert s["predicted"]["mast stiffnesses"] == {"parameters": 1, "median": 0.9,
                                                   "worst": 0.9, "worst_draw": 1.2}
    xy = s["predicted"]["exit offsets x, y"]
    assert xy["median"] == pytest.approx(0.7) and xy["worst"] == 0.9
    assert "exit offsets z" not in s["predicted"]
    assert s["smallest_n"] == 14
    assert match_summary(res[1:])["smallest_n"] is None


@pytest.mark.parametrize("robot", ["ipanema", "hexa6"])
def test_generated_cases_on_other_robots_lie_in_their_frame(robot):
    """A goal-(b) case on another shipped robot: its effect's keys are that robot's cables,
    its first campaign's 4-6 poses are feasible, at the init pose's height, inside the
    frame's middle; ROCASPECT's cases keep their fixed geometry."""
    from bench.design_eval import GEOMETRY, case_geometry, make_case
    from bench.evaluate import feasible
    from controller.paths import frame_box
    from controller.robot import resolve_robot

    model = resolve_robot(robot)
    lo, hi = frame_box(model)
    seen = set()
    for seed in range(6):
        case = make_case(seed, robot)
        (effect, truth), = case["truth"].items()
        seen.add(effect)
        if effect != "cable_elasticity":
            assert {k.split("_", 1)[1] for k in truth} == set(model.cable_ids)
        pts = np.array(case["poses"]["list"])
        assert 4 <= len(pts) <= 6 and all(feasible(model, p) for p in pts)
        assert np.allclose(pts[:, 2], case["init_pose"][2])
        mid = 0.5 * (lo + hi)
        assert np.all(np.abs(pts[:, :2] - mid[:2]) < 0.3 * (hi[:2] - lo[:2]))
    assert len(seen) >= 2
    assert case_geometry("rocaspect") == GEOMETRY["rocaspect"]
    assert make_case(9023)["init_pose"][:2] != make_case(9023, robot)["init_pose"][:2]


def test_cli_match_writes_the_poses_closest_to_a_reference_path(scenario, candidates,
                                                                tmp_path, capsys):
    """`--match PATH` with nothing to separate: the poses written are the matching design's
    (`at_poses`), its ratios are those of its standard errors to the reference's, and the
    fewest poses needed are counted on the same Fisher information."""
    ref = candidates[:6]
    path = tmp_path / "ref.toml"
    path.write_text('format = "cdpr-path/1"\nname = "ref"\n\n[[segment]]\nkind = "visits"\n'
                    'visits = 2\ndwell_s = 3.0\nposes = [\n'
                    + "".join("  [" + ", ".join(f"{v:.6f}" for v in p) + "],\n" for p in ref)
                    + "]\n")
    rep = tmp_path / "r.json"
    rep.write_text(json.dumps(_report([])))
    rc = main(["campaign", "design", str(rep), "--scenario", str(scenario), "--poses", "6",
               "--visits", "2", "--candidates", "16", "--match", str(path), "--json"])
    got = json.loads(capsys.readouterr().out)
    assert rc == 0
    m = got["match"]
    assert m["reference_poses"] == 6 and got["poses"] == m["at_poses"]["poses"]
    assert len(got["poses"]) == 6
    keys = list(m["stderr_reference"])
    assert keys and all(k.startswith(cd.MATCH_PREFIXES) for k in keys)
    ratio = [m["at_poses"]["stderr"][k] / m["stderr_reference"][k] for k in keys]
    assert max(ratio) == pytest.approx(m["at_poses"]["worst_ratio"], rel=1e-6)
    if m["poses_needed"] > 0:
        assert len(m["poses"]) == m["poses_needed"] and m["worst_ratio"] <= 1.0 + 1e-9
