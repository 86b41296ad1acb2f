"""``cdpr evaluate``: generated cases on the local process pool and on a Dask cluster (an
in-process ``distributed.LocalCluster`` reached over TCP on 127.0.0.1), the summary, --out
resumption after an interruption, and a case that raises (recorded, the others go on).

Cases are small (a 3 x 2 x 1 pose grid, 2 visits, one concealed drum scale: about a
second each; what the diagnosis finds on every kind of case is ``cdpr evaluate``'s own
job). Replacement case functions are module-level so that worker processes can unpickle
them by name.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

import distributed  # the dev extra installs it
import pytest

from bench import evaluate
from bench.cli import main
from bench.commands.evaluate import OUT_FORMAT, read_results
from bench.parallel import run_each

SMALL = ["--grid", "3,2,1", "--visits", "2", "--robot", "rocaspect", "--kind", "dwell",
         "--sensors", "all", "--oov", "none"]
SMALL_KW = {"poses": {"n": [3, 2, 1], "visits": 2}, "robot": "rocaspect", "kind": "dwell",
            "sensors": "all", "oov": "none"}
#: one cheap concealed effect (the plumbing under test does not depend on which)
ONE = ["--effects", "drum_scale"]
ONE_KW = SMALL_KW | {"effects": ("drum_scale",)}
REAL_RUN_CASE = evaluate.run_case
FAILING_SEED = 6


def pid_case(seed: int, **kw) -> dict:
    """The real case, tagged with the id of the process that ran it."""
    return REAL_RUN_CASE(seed, **kw) | {"pid": os.getpid()}


def flaky_case(seed: int, **kw) -> dict:
    """The real case, except that seed FAILING_SEED raises."""
    if seed == FAILING_SEED:
        raise RuntimeError(f"plant exploded at seed {seed}")
    return REAL_RUN_CASE(seed, **kw)


def run_json(capsys, *argv: str) -> tuple[int, dict, str]:
    rc = main(["evaluate", *argv, "--json"])
    cap = capsys.readouterr()
    return rc, json.loads(cap.out), cap.err


def without_seconds(case: dict) -> dict:
    out = {k: v for k, v in case.items() if k not in ("seconds", "pid", "run")}
    if "info" in out:
        out["info"] = {k: v for k, v in out["info"].items()
                       if k not in ("case_seconds", "cpu_seconds", "record_seconds",
                                    "record_cpu_seconds")}
    return out


def plain(case: dict) -> dict:
    return json.loads(json.dumps(case, default=lambda o: o.item()))


def test_two_cases_on_the_local_process_pool(capsys, monkeypatch):
    monkeypatch.setattr(evaluate, "run_case", pid_case)
    rc, out, err = run_json(capsys, "--cases", "2", "--seed", "5", "--jobs", "2", *SMALL, *ONE)
    assert rc == 0
    assert [c["seed"] for c in out["cases"]] == [5, 6]
    assert out["errors"] == [] and out["summary"]["errors"] == 0
    # the cases ran in worker processes, not here
    assert all(c["pid"] != os.getpid() for c in out["cases"])
    # each case is what run_case gives in this process (but for the time it took)
    for c in out["cases"]:
        assert without_seconds(c) == without_seconds(plain(REAL_RUN_CASE(c["seed"], **ONE_KW)))
    s = out["summary"]
    assert s == json.loads(json.dumps(evaluate.summarise(out["cases"])
                                      | {"errors": 0, "requested": 2}))
    assert s["cases"] == 2 and s["median_case_s"] > 0
    # each record names where it was diagnosed (the evaluation page reads it)
    from bench.version import build_commit

    assert {c["run"]["commit"] for c in out["cases"]} == {build_commit()}
    assert all(c["run"]["date"].endswith("UTC") and c["run"]["cpu"] for c in out["cases"])
    assert out["config"] == {"robot": "rocaspect", "effects": ["drum_scale"],
                             "poses": {"n": [3, 2, 1], "visits": 2}, "kind": "dwell",
                             "sensors": "all", "oov": "none"}
    # progress: cases done, running exact-detection rate, ETA
    assert "case 1/2" in err and "case 2/2" in err and "exact detection" in err and "ETA" in err


def test_jobs_1_runs_in_this_process_and_effects_are_imposed(capsys, monkeypatch):
    monkeypatch.setattr(evaluate, "run_case", pid_case)
    rc, out, _ = run_json(capsys, "--cases", "2", "--jobs", "1", "--effects",
                          "exit_point_offset", *SMALL)
    assert rc == 0
    assert all(c["pid"] == os.getpid() for c in out["cases"])
    assert all(c["truth"] == ["exit_point_offset"] for c in out["cases"])
    assert set(out["summary"]["matrix"]) == {"exit_point_offset"}


def test_keep_holds_each_case_to_diagnose_again(tmp_path, capsys):
    from bench.diagnosis.report import diagnose

    keep = tmp_path / "kept"
    rc, out, _ = run_json(capsys, "--cases", "1", "--seed", "5", "--jobs", "1", "--keep",
                          str(keep), *SMALL, *ONE)
    assert rc == 0
    case = json.loads((keep / "5" / "case.json").read_text())
    assert case["seed"] == 5 and set(case["truth"]) == {"drum_scale"}
    # the kept recording diagnoses as the evaluation's did
    again = diagnose(keep / "5" / "rec").report
    assert sorted(e["name"] for e in again["effects"]) == sorted(out["cases"][0]["named"])


def _no_recording(*_a, **_k):
    raise AssertionError("recorded again")


def test_reuse_kept_diagnoses_the_kept_recording_again(tmp_path, capsys, monkeypatch):
    keep = tmp_path / "kept"
    args = ["--cases", "1", "--seed", "5", "--jobs", "1", "--keep", str(keep), *SMALL, *ONE]
    rc, first, _ = run_json(capsys, *args)
    assert rc == 0
    monkeypatch.setattr(evaluate, "record", _no_recording)
    rc, again, _ = run_json(capsys, *args, "--reuse-kept")
    assert rc == 0 and not again["errors"]
    a, b = first["cases"][0], again["cases"][0]
    for k in ("truth", "named", "exact", "z", "intervals"):
        assert a[k] == b[k]
    assert a["info"]["oracle"] == b["info"]["oracle"]
    # another configuration: the kept case is not taken for it (it is drawn and recorded)
    rc, other, _ = run_json(capsys, *args[:-2], "--effects", "platform_mass", "--reuse-kept")
    assert "recorded again" in other["errors"][0]["error"]


def test_reuse_kept_needs_keep(capsys):
    rc, out, err = run_json(capsys, "--cases", "1", "--reuse-kept", *SMALL, *ONE)
    assert rc == 2 and "--keep" in out["error"]


def test_keep_into_a_folder_that_cannot_be_made_exits_2(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    rc, out, err = run_json(capsys, "--cases", "1", "--keep", str(tmp_path / "file" / "x"),
                            *SMALL, *ONE)
    assert rc == 2 and "--keep" in out["error"] and "--keep" in err


def test_human_report(capsys):
    rc = main(["evaluate", "--cases", "2", "--seed", "5", "--jobs", "2", *SMALL, *ONE])
    cap = capsys.readouterr()
    assert rc == 0
    text = cap.out
    for words in ("2 cases (seeds 5..6)", "exact detection", "false positives", "95 % CI",
                  "parameters in tol.", "z-scores", "diagnosis seconds", "concealed \\ named"):
        assert words in text, words
    # one row of the detection matrix per effect the two cases conceal
    rows = {e for seed in (5, 6) for e in evaluate.make_case(seed, **ONE_KW)["truth"]} \
        or {"none"}
    for row in rows:
        assert any(line.strip().startswith(row) for line in text.splitlines()), row
    assert "columns: DS drum_scale" in text


def test_generated_cases_span_robots_kinds_sensors_and_physics_outside_the_vocabulary():
    """The case generator alone (no campaign): over many seeds every robot, perturbed or
    not, every recording kind and sensor set, and physics outside the vocabulary occur;
    every case's scenario parses and its poses are feasible for its model."""
    seen: dict[str, set] = {k: set() for k in ("robot", "kind", "sensors", "oov", "perturbed")}
    effects: set[str] = set()
    for seed in range(60):
        case = evaluate.make_case(seed)
        for k in seen:
            seen[k].add(case["case"][k])
        effects |= set(case["truth"])
        sc = evaluate.scenario_of({**case, "truth": {
            e: {k: v for k, v in p.items() if not k.startswith("slip_time_")}
            for e, p in case["truth"].items()}})
        assert all(evaluate.feasible(sc.model, p) for p in sc.poses.generate(None)[:3])
        if case["case"]["sensors"] != "all":
            assert set(case["truth"]) <= set(evaluate.WITHOUT[case["case"]["sensors"]])
    assert seen["robot"] == set(evaluate.ROBOTS) and seen["perturbed"] == {True, False}
    assert seen["kind"] == set(evaluate.KINDS) and seen["sensors"] == set(evaluate.SENSORS)
    assert seen["oov"] > {"none"}
    assert effects == set(evaluate.DRAWN)


def test_a_case_that_raises_is_an_error_and_hides_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(evaluate, "run_case", flaky_case)
    out_file = tmp_path / "cases.jsonl"
    rc, out, err = run_json(capsys, "--cases", "3", "--seed", "5", "--jobs", "2",
                            "--out", str(out_file), *SMALL, *ONE)
    assert rc == 1
    assert [c["seed"] for c in out["cases"]] == [5, 7]
    assert [(e["seed"], e["error"]) for e in out["errors"]] == [
        (FAILING_SEED, f"RuntimeError: plant exploded at seed {FAILING_SEED}")]
    assert "flaky_case" in out["errors"][0]["trace"]
    assert out["summary"]["cases"] == 2 and out["summary"]["errors"] == 1
    assert out["summary"]["requested"] == 3
    assert f"seed {FAILING_SEED}: error RuntimeError" in err
    _, records = read_results(out_file)
    assert sorted(records) == [5, 6, 7] and "error" in records[FAILING_SEED]
    # the human report lists it too
    monkeypatch.setattr(evaluate, "run_case", flaky_case)
    assert main(["evaluate", "--cases", "3", "--seed", "5", "--out", str(out_file), *SMALL,
                 *ONE]) == 1
    text = capsys.readouterr().out
    assert f"error: seed {FAILING_SEED}: RuntimeError: plant exploded" in text
    assert "2 scored, 1 raised" in text
    # --retry-errors runs it again (and only it); now it passes
    calls: list[int] = []
    monkeypatch.setattr(evaluate, "run_case",
                        lambda seed, **kw: calls.append(seed) or REAL_RUN_CASE(seed, **kw))
    rc, out, _ = run_json(capsys, "--cases", "3", "--seed", "5", "--jobs", "1",
                          "--out", str(out_file), "--retry-errors", *SMALL, *ONE)
    assert rc == 0 and calls == [FAILING_SEED]
    assert [c["seed"] for c in out["cases"]] == [5, 6, 7] and out["errors"] == []


def test_out_file_resumes_after_an_interruption(tmp_path, capsys, monkeypatch):
    out_file = tmp_path / "runs" / "cases.jsonl"
    calls: list[int] = []

    def interrupted_at_2(seed: int, **kw) -> dict:
        calls.append(seed)
        if seed == 2:
            raise KeyboardInterrupt
        return REAL_RUN_CASE(seed, **kw)

    monkeypatch.setattr(evaluate, "run_case", interrupted_at_2)
    argv = ["evaluate", "--cases", "4", "--jobs", "1", "--effects", "none",
            "--out", str(out_file), *SMALL]
    assert main(argv) == 130
    capsys.readouterr()
    lines = out_file.read_text(encoding="utf-8").splitlines()
    assert json.loads(lines[0])["format"] == OUT_FORMAT
    assert [json.loads(x)["seed"] for x in lines[1:]] == [0, 1]
    # a line cut short by the interruption is reported and its case run again
    with out_file.open("a", encoding="utf-8") as f:
        f.write('{"seed": 2, "truth": [], "nam')
    calls.clear()
    monkeypatch.setattr(evaluate, "run_case",
                        lambda seed, **kw: calls.append(seed) or REAL_RUN_CASE(seed, **kw))
    rc, out, err = run_json(capsys, *argv[1:])
    assert rc == 0
    assert calls == [2, 3]
    assert "2 of 4 seeds already in" in err and "not JSON" in err and ":4:" in err
    assert [c["seed"] for c in out["cases"]] == [0, 1, 2, 3]
    assert out["summary"]["matrix"] == {"none": out["summary"]["matrix"]["none"]}
    assert out["summary"]["matrix"]["none"]["cases"] == 4
    _, records = read_results(out_file)
    assert sorted(records) == [0, 1, 2, 3]
    # all done: a re-run runs nothing and reports the same cases
    calls.clear()
    rc, again, _ = run_json(capsys, *argv[1:])
    assert rc == 0 and calls == [] and again["cases"] == out["cases"]
    # more cases: only the new seeds
    rc, more, _ = run_json(capsys, argv[1], "5", *argv[3:])
    assert rc == 0 and calls == [4] and len(more["cases"]) == 5


def test_out_file_of_another_configuration_is_refused(tmp_path, capsys):
    out_file = tmp_path / "cases.jsonl"
    out_file.write_text(json.dumps({"format": OUT_FORMAT, "config": {
        "robot": "rocaspect", "effects": ["drum_scale"], "poses": {}, "kind": "dwell",
        "sensors": "all", "oov": "none"}}) + "\n", encoding="utf-8")
    rc, out, _ = run_json(capsys, "--cases", "1", "--out", str(out_file), *SMALL)
    assert rc == 2 and str(out_file) in out["error"]
    assert "another case configuration" in out["error"]
    other = tmp_path / "other.jsonl"
    other.write_text('{"seed": 1, "exact": true}\n', encoding="utf-8")
    rc, out, _ = run_json(capsys, "--cases", "1", "--out", str(other), *SMALL)
    assert rc == 2 and "header" in out["error"]


@pytest.mark.parametrize("argv, words", [
    (["--cases", "0"], "--cases 0"),
    (["--cases", "1", "--jobs", "0"], "--jobs 0"),
    (["--cases", "1", "--effects", "drum_scale,warp_drive"], "warp_drive"),
    (["--cases", "1", "--grid", "3,2"], "--grid 3,2"),
    (["--cases", "1", "--visits", "0"], "--visits 0"),
    (["--cases", "1", "--retry-errors"], "--retry-errors"),
    (["--cases", "1", "--robot", "no-such-robot"], "no-such-robot"),
])
def test_bad_arguments_exit_2(capsys, argv, words):
    rc, out, err = run_json(capsys, *argv)
    assert rc == 2 and words in out["error"] and words in err


# ----- the executor ---------------------------------------------------------------------------

def dies_at_2(x: int) -> int:
    """Kills its worker process at item 2 (as a segfault or the OOM killer would)."""
    if x == 2:
        os._exit(3)
    if x == 4:
        raise ValueError("four")
    return 10 * x


def test_a_worker_that_dies_is_reported_and_the_others_are_not_lost():
    outcomes = {o.item: o for o in run_each(dies_at_2, range(7), jobs=2)}
    assert sorted(outcomes) == list(range(7))
    assert outcomes[2].error.startswith("BrokenProcessPool: a worker process died")
    assert outcomes[4].error == "ValueError: four"
    assert {k: o.value for k, o in outcomes.items() if o.ok} == {
        k: 10 * k for k in (0, 1, 3, 5, 6)}


def test_run_each_in_process_reports_errors_in_order():
    got = [(o.item, o.value, o.error) for o in run_each(dies_at_2, [0, 4, 1], jobs=1)]
    assert got == [(0, 0, None), (4, None, "ValueError: four"), (1, 10, None)]


# ----- Dask ---------------------------------------------------------------------------------

@pytest.fixture
def dask_cluster():
    """A scheduler and one worker (2 threads) in this process, on TCP, closed after the test."""
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                       protocol="tcp://", host="127.0.0.1", scheduler_port=0,
                                       dashboard_address=None)
    try:
        yield cluster
    finally:
        cluster.close()


def test_cases_on_a_dask_cluster(dask_cluster, tmp_path, capsys, monkeypatch):
    address = dask_cluster.scheduler_address
    assert address.startswith("tcp://127.0.0.1:")
    monkeypatch.setattr(evaluate, "run_case", flaky_case)
    out_file = tmp_path / "dask.jsonl"
    rc, out, err = run_json(capsys, "--cases", "3", "--seed", "5", "--scheduler", address,
                            "--out", str(out_file), *SMALL, *ONE)
    assert rc == 1
    assert [c["seed"] for c in out["cases"]] == [5, 7]
    assert [e["seed"] for e in out["errors"]] == [FAILING_SEED]
    assert out["errors"][0]["error"] == f"RuntimeError: plant exploded at seed {FAILING_SEED}"
    for c in out["cases"]:
        assert without_seconds(c) == without_seconds(plain(REAL_RUN_CASE(c["seed"], **ONE_KW)))
    assert "case 3/3" in err
    # resumed on the cluster: only the failed seed again
    monkeypatch.setattr(evaluate, "run_case", REAL_RUN_CASE)
    rc, out, err = run_json(capsys, "--cases", "3", "--seed", "5", "--scheduler", address,
                            "--out", str(out_file), "--retry-errors", *SMALL, *ONE)
    assert rc == 0 and [c["seed"] for c in out["cases"]] == [5, 6, 7]
    assert "2 of 3 seeds already in" in err and "case 1/1 seed 6" in err


def test_unreachable_scheduler_message(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rc, out, _ = run_json(capsys, "--cases", "1", "--scheduler", f"tcp://127.0.0.1:{port}",
                          "--connect-timeout", "1", *SMALL)
    assert rc == 2
    assert f"tcp://127.0.0.1:{port}" in out["error"] and "cannot connect" in out["error"]


def test_read_results_ignores_blank_lines(tmp_path: Path):
    p = tmp_path / "r.jsonl"
    p.write_text(json.dumps({"format": OUT_FORMAT, "config": {}}) + "\n\n"
                 + json.dumps({"seed": 3, "error": "X: y"}) + "\n"
                 + json.dumps({"seed": 3, "exact": True}) + "\n", encoding="utf-8")
    header, records = read_results(p)
    assert header == {"format": OUT_FORMAT, "config": {}}
    assert records == {3: {"seed": 3, "exact": True}}  # the last line of a seed wins


BLAS_THREADS = """
import ctypes, json
from bench.parallel import single_blas_thread
from bench import evaluate
single_blas_thread()  # as `cdpr evaluate` and its workers do, before any case
evaluate.run_case(5, **json.loads({kw!r}))
out = {{}}
for lib in sorted({{line.split()[-1] for line in open("/proc/self/maps")
                   if "openblas" in line.lower() and ".so" in line}}):
    h = ctypes.CDLL(lib)
    for name in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                 "openblas_get_num_threads64_", "openblas_get_num_threads"):
        if hasattr(h, name):
            out[lib] = getattr(h, name)()
            break
print(json.dumps(out))
"""


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads /proc/self/maps")
def test_a_case_diagnoses_on_one_blas_thread_whatever_the_libraries_loaded_later():
    """SciPy loads its own OpenBLAS with the diagnosis, after the command limited the BLAS
    loaded at start: every OpenBLAS in the process must run one thread once a case ran
    (two threads spinning against each other doubled a diagnosis's processor time)."""
    import subprocess
    import sys

    kw = json.dumps(ONE_KW | {"effects": list(ONE_KW["effects"])})
    env = os.environ | {"OPENBLAS_NUM_THREADS": "2"}
    got = subprocess.run([sys.executable, "-c", BLAS_THREADS.format(kw=kw)], env=env,
                         capture_output=True, text=True, timeout=600, check=True)
    threads = json.loads(got.stdout.strip().splitlines()[-1])
    assert any("scipy_openblas" in lib for lib in threads), threads
    assert set(threads.values()) == {1}, threads


def test_score_counts_every_parameter_of_an_effect_named_right():
    """A parameter the report gives beside the truth's (a drum scale of a cable the truth
    leaves at 1) is scored against the model's value: its z-score and its tolerance count.
    One the report does not give is not invented; a rigid mast of the truth is not scored."""
    from bench.evaluate import score
    from controller.robot import load_robot, shipped_robot_path

    model = load_robot(shipped_robot_path("rocaspect"))
    c = model.cable_ids
    truth = {"drum_scale": {f"s_{c[0]}": 1.003}}
    report = {"effects": [{"name": "drum_scale",
                           "params": {f"s_{c[0]}": 1.0031, f"s_{c[1]}": 1.0004},
                           "stderr": {f"s_{c[0]}": 0.0001, f"s_{c[1]}": 0.0001}}],
              "fitted": {}, "mismatch": {}}
    s = score(report, truth, model)
    assert s.exact and s.params_total == 2
    assert sorted(round(z, 6) for z in s.z) == [1.0, 4.0]
    report["effects"][0]["params"].pop(f"s_{c[1]}")
    s = score(report, truth, model)
    assert s.params_total == 1 and [round(z, 6) for z in s.z] == [1.0]


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_progress_says_what_starts_before_any_case_finishes(capsys, jobs):
    rc, out, err = run_json(capsys, "--cases", "2", "--seed", "5", "--jobs", jobs,
                            *SMALL, *ONE)
    assert rc == 0
    lines = err.splitlines()
    where = "in this process (--jobs 1)" if jobs == "1" else \
        "on 2 local worker processes (--jobs 2)"
    assert lines[0] == f"cdpr evaluate: 2 cases (seeds 5..6, --seed 5) {where}"
    started = [i for i, ln in enumerate(lines) if " started (" in ln]
    first_done = next(i for i, ln in enumerate(lines) if "case 1/2 seed" in ln)
    assert len(started) == 2 and started[0] < first_done
    assert "seed 5 started" in lines[started[0]]
    # --quiet: nothing
    rc, _, err = run_json(capsys, "--cases", "1", "--seed", "5", "--jobs", jobs, "--quiet",
                          *SMALL, *ONE)
    assert rc == 0 and err == ""


def test_run_each_says_when_each_item_starts():
    started: list[int] = []
    outcomes = list(run_each(abs, [-1, -2, -3], jobs=2, on_start=started.append))
    assert sorted(started) == [-3, -2, -1]
    assert sorted(o.value for o in outcomes) == [1, 2, 3]
    started.clear()
    assert [o.value for o in run_each(abs, [-4], jobs=1, on_start=started.append)] == [4]
    assert started == [-4]


def test_tracker_error_cases_conceal_the_tracker_s_error_alone(capsys):
    """``--tracker-error``: each case's tracker carries that error and nothing else is
    concealed; the diagnosis is scored on it (here named exactly); combined with
    ``--effects`` it is refused naming both."""
    rc, out, _ = run_json(capsys, "--cases", "1", "--seed", "41000", "--jobs", "1",
                          "--tracker-error", "tracker_frame", "--robot", "rocaspect",
                          "--grid", "3,2,1", "--visits", "2", "--kind", "dwell")
    assert rc == 0 and out["config"]["tracker"] == "tracker_frame"
    (case,) = out["cases"]
    assert case["truth"] == ["tracker_frame"] and case["named"] == ["tracker_frame"]
    rc, out, _ = run_json(capsys, "--cases", "1", "--tracker-error", "tracker_frame",
                          "--effects", "drum_scale")
    assert rc == 2 and "--tracker-error" in out["error"] and "--effects" in out["error"]
