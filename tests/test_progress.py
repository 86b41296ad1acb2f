"""bench.progress.Progress: the shared progress line (paper campaigns, evaluate, plots)."""

from __future__ import annotations

import time

from bench.progress import Progress


def test_line_counts_items_and_names_those_in_flight(tmp_path):
    frac = tmp_path / "a.progress"
    frac.write_text("0.4 simulated\n")
    p = Progress("evaluate", 4, unit="cases")
    p.done = 1
    p.running = {"a": str(frac), "seed 3": None, "b": str(tmp_path / "missing")}
    line = p.line()
    assert line.startswith("evaluate: 1/4 cases done, 0:0")
    assert line.endswith("; running a 40%, seed 3")


def test_default_unit_is_runs_and_paper_uses_this_class():
    from bench.dryrun import paper

    assert paper.Progress is Progress
    assert Progress("paper-paths", 2).line().startswith("paper-paths: 0/2 runs done")


def test_say_and_heartbeat_go_to_stderr_unless_quiet(capsys):
    err = ""
    with Progress("job", 1, period_s=0.01) as p:
        p.say("started")
        end = time.monotonic() + 60  # a generous bound, only against a hang
        while "job: 0/1 runs done" not in err and time.monotonic() < end:
            time.sleep(0.01)  # the heartbeat thread prints every period
            err += capsys.readouterr().err
    assert err.startswith("started\n") and "job: 0/1 runs done" in err
    assert capsys.readouterr().out == ""
    with Progress("job", 1, quiet=True, period_s=0.01) as q:
        q.say("nothing")
    assert capsys.readouterr().err == ""


def test_one_job_without_a_count():
    assert Progress("workspace sweep", None).line() == "workspace sweep: 0:00 elapsed"
