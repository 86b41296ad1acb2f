"""``cdpr dry-run paper-paths --models learned,learned_untracked``: the runs planned (nominal
start, learning on, the warm-up before the path as part of its approach) and the report."""

from __future__ import annotations

import numpy as np
import pytest

from bench.cli import main
from bench.dryrun import paper
from bench.dryrun.paper_report import paths_result
from controller.paths import load_path


def test_learned_runs_start_nominal_and_learn(tmp_path):
    opt = paper.PathsOptions(work=tmp_path, models=("nominal", "learned", "learned_warmup",
                                                    "learned_untracked"), planned=False)
    first, second = paper.paths_plan(opt)
    assert second == []
    by = {it.label: it for it in first}
    sc = paper.load_named_scenario(paper.SCENARIO)
    for case in paper.CASES:
        name = f"{case[0]}-path_{case[1]}-init"
        nom, lr, lw, lu = (by[f"{m}_{name}"] for m in ("nominal", "learned", "learned_warmup",
                                                        "learned_untracked"))
        assert nom.learn is None and nom.warmup is None
        assert lr.learn == {"tracker": True} and lu.learn == {"tracker": "warmup"}
        assert lw.learn == {"tracker": "warmup_only"}
        assert lr.robot.name == lw.robot.name == lu.robot.name == sc.model.name  # nominal
        assert lr.warmup is lw.warmup is lu.warmup is paper.warmup_specs


@pytest.mark.parametrize("init", sorted(paper.INIT_POSES))
def test_warmup_is_at_most_60_s_and_no_part_of_the_path(init):
    p0 = np.array(paper.INIT_POSES[init])
    path = load_path(paper.PATHS["centre"])
    traj = paper.with_warmup(path, paper.warmup_specs(p0), p0)
    plain = paper.with_warmup(path, (), p0)
    warm = [s for s in traj.segments if s.name.startswith(paper.WARMUP_NAME)]
    assert warm and all(s.cycle == -1 for s in warm)
    assert sum(s.duration_s for s in warm) <= 60.0
    assert paper._warmup_s(traj) == pytest.approx(sum(s.duration_s for s in warm))
    np.testing.assert_allclose(warm[-1].target, p0)  # back where it started
    # after the warm-up, the same trajectory as without it
    rest = [s for s in traj.segments if not s.name.startswith(paper.WARMUP_NAME)]
    assert [(s.kind, s.cycle) for s in rest] == [(s.kind, s.cycle) for s in plain.segments]
    lo, hi = np.array(paper.WARMUP_BOX)
    for s in warm:
        assert np.all(s.target[:3] >= lo - 1e-12) and np.all(s.target[:3] <= hi + 1e-12)


def test_learned_goal_in_the_report(tmp_path):
    opt = paper.PathsOptions(work=tmp_path, models=("nominal", "learned"), planned=False)
    results = []
    for case in paper.CASES:
        for m, at in (("nominal", 0.05), ("learned", 0.004 if case[0] == "centre" else 0.02)):
            r = {"label": f"{m}_{case}", "tags": {"path": case[0], "init": case[1], "model": m},
                 "at_max_m": at, "at_mean_m": at / 2, "slack_events": 0, "model": m,
                 "mast_tensions": "measured", "simulated_s": 1.0, "wall_s": 1.0,
                 "events": [], "recording": "x"}
            if m == "learned":
                r["learn"] = {"events": [{"kind": "drift"}], "updates": 3, "samples": 9,
                              "rejected": 0, "handovers": 3, "warmup_s": 54.7,
                              "identifiable": None}
            results.append(r)
    res = paths_result(results, [], opt, 1.0)
    g = res["goals"]
    assert g["min_at_max_cut_learned"] == pytest.approx(0.6)
    assert g["learned_cuts_at_max_by_80pct_everywhere"] is False
    assert res["learning"][0]["event_counts"] == {"drift": 1}


def test_learned_models_refused_in_paper_poses(capsys):
    assert main(["dry-run", "paper-poses", "--models", "learned", "--json", "--quiet"]) == 2
    assert "paper-paths" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--models", "learned"], ["--cases", "centre/centre"],
                                  ["--sets", "gold"]])
def test_paper_drift_refuses_options_of_the_other_campaigns(argv, capsys):
    assert main(["dry-run", "paper-drift", *argv, "--json", "--quiet"]) == 2
    assert "do not apply to paper-drift" in capsys.readouterr().out
