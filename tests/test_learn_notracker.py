"""``paper-paths --models learned_notracker``: learning from the nominal model with no tracker
fix ever (tensions and encoders only, warm-up and path); its runs planned and reported."""

from __future__ import annotations

from bench.dryrun import paper
from bench.dryrun.paper_report import CUT_MODELS, paths_result


def test_notracker_runs_start_nominal_and_never_use_the_tracker(tmp_path):
    opt = paper.PathsOptions(work=tmp_path, models=("nominal", "learned_notracker"),
                             planned=False)
    first, second = paper.paths_plan(opt)
    assert second == [] and len(first) == 2 * len(paper.CASES)
    sc = paper.load_named_scenario(paper.SCENARIO)
    for it in first:
        if it.tags["model"] == "learned_notracker":
            assert it.learn == {"tracker": False} and it.robot.name == sc.model.name
            assert it.warmup is paper.warmup_specs
    assert "learned_notracker" in paper.MODELS and "learned_notracker" in CUT_MODELS


def test_notracker_learner_never_uses_the_tracker():
    class World:
        tracker = None

    learner = paper._learner({"tracker": False}, World())
    assert not learner.use_tracker and learner.tracked_s is None
    assert learner.correlated == 0.5  # the hand-over's correlation rule on, as untracked


def test_notracker_cut_is_a_goal_in_the_report(tmp_path):
    opt = paper.PathsOptions(work=tmp_path, models=("nominal", "learned_notracker"),
                             planned=False)
    results = []
    for path, init in paper.CASES:
        for m, at in (("nominal", 0.05), ("learned_notracker", 0.049)):
            r = {"label": f"{m}_{path}-{init}", "tags": {"path": path, "init": init,
                                                        "model": m},
                 "at_max_m": at, "at_mean_m": at / 2, "slack_events": 0, "simulated_s": 1.0,
                 "wall_s": 1.0, "events": [], "recording": "", "model": m,
                 "mast_tensions": "measured"}
            if m != "nominal":
                r["learn"] = {"events": [], "updates": 3, "samples": 9, "rejected": 0,
                              "handovers": 0, "warmup_s": 50.0, "untracked_directions": 0,
                              "drift": {"detected_at_s": None, "detections": 0, "events": 0,
                                        "drifts": 0, "active": False,
                                        "length_change_mm": 0.0}}
            results.append(r)
    res = paths_result(results, [], opt, 1.0)
    g = res["goals"]
    assert abs(g["min_at_max_cut_learned_notracker"] - 0.02) < 1e-9
    assert g["learned_notracker_cuts_at_max_by_80pct_everywhere"] is False
    assert res["learning"][0]["untracked_directions"] == 0
    assert res["learning"][0]["drift"]["detections"] == 0
