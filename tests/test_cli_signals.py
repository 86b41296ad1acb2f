"""Ctrl-C and SIGTERM at the top level (bench/cli.py): one line on stderr, exit status 130
(interrupted) or 143 (terminated, 128 + 15), and under ``--json`` one JSON object on stdout
for any command (``cdpr evaluate``: with the cases finished so far).

The commands run in a separate Python process that replaces their long work by a wait
(module-level functions that the worker processes, forked, find by name); the test waits
for a line on stderr, never for a time, then sends the signal to that process alone.
Timeouts are generous and only keep a broken test from hanging.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bench.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "paper_tables"
SCENARIO = ROOT / "bench" / "data" / "paper_scenario.toml"
SMALL = ["--grid", "3,2,1", "--visits", "2", "--robot", "rocaspect", "--kind", "dwell",
         "--sensors", "all", "--oov", "none", "--effects", "drum_scale"]

EVALUATE = '''
import sys, time
from bench import evaluate
from bench.cli import main

REAL = evaluate.run_case

def case(seed, **kw):
    if seed == 0:
        return REAL(seed, **kw)
    time.sleep(600)

evaluate.run_case = case
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
'''

CAMPAIGN = '''
import sys, time
import bench.campaign
from bench.cli import main

def run_campaign(sc, out, progress=None, poses=None):
    print("campaign: waiting", file=sys.stderr, flush=True)
    time.sleep(600)

bench.campaign.run_campaign = run_campaign
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
'''

MESSAGE = {signal.SIGINT: (130, "interrupted (SIGINT)"),
           signal.SIGTERM: (143, "terminated (SIGTERM)")}


def _default_signals() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def run_until(tmp_path: Path, script: str, argv: list[str], marker: str,
              sig: int) -> tuple[int, str, str]:
    """Run ``script argv``, wait for ``marker`` on its stderr, send it ``sig``; returns the
    exit status, stdout and stderr."""
    src = tmp_path / "driver.py"
    src.write_text(textwrap.dedent(script))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    # default signal dispositions: a shell running the tests in the background leaves
    # SIGINT ignored, and Python then keeps ignoring it
    proc = subprocess.Popen([sys.executable, str(src), *argv], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=_default_signals)
    err = ""
    try:
        while marker not in err:
            line = proc.stderr.readline()
            if not line:  # ended before the marker
                break
            err += line
        assert marker in err, err
        proc.send_signal(sig)
        out, rest = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out, err + rest


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_evaluate_interrupted_prints_the_cases_finished_so_far(tmp_path, sig):
    code, msg = MESSAGE[sig]
    rc, out, err = run_until(tmp_path, EVALUATE, ["evaluate", "--cases", "4", "--jobs", "2",
                                                  "--json", *SMALL], "seed 0:", sig)
    assert rc == code, err
    obj = json.loads(out)  # one object
    assert obj["error"] == msg
    assert [c["seed"] for c in obj["cases"]] == [0]
    assert obj["summary"]["cases"] == 1 and obj["summary"]["not_run"] == 3
    assert f"cdpr evaluate: {msg}" in err
    assert "Traceback" not in err and "Terminated" not in err  # the workers end quietly


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_any_command_interrupted_under_json_prints_an_error_object(tmp_path, sig):
    code, msg = MESSAGE[sig]
    out_dir = tmp_path / "rec"
    rc, out, err = run_until(tmp_path, CAMPAIGN, ["campaign", str(SCENARIO), str(out_dir),
                                                  "--json"], "campaign: waiting", sig)
    assert rc == code, err
    assert json.loads(out) == {"error": msg}
    assert err.strip().splitlines()[-1] == f"cdpr campaign: {msg}"
    assert "Traceback" not in err
    # the scratch recording beside OUT_DIR is removed (the finally blocks ran)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["driver.py"]


def test_interrupted_without_json_prints_nothing_on_stdout(tmp_path):
    rc, out, err = run_until(tmp_path, CAMPAIGN, ["campaign", str(SCENARIO),
                                                  str(tmp_path / "rec")], "campaign: waiting",
                             signal.SIGTERM)
    assert rc == 143 and out == ""
    assert "cdpr campaign: terminated (SIGTERM)" in err


def test_diagnose_terminated_reports_one_line(capsys, monkeypatch):
    from bench.diagnosis import report
    from bench.parallel import Terminated

    def terminated(*a, **kw):
        raise Terminated(signal.SIGTERM)

    monkeypatch.setattr(report, "diagnose", terminated)
    assert main(["diagnose", str(EXAMPLE), "--json", "--jobs", "1", "--quiet"]) == 143
    cap = capsys.readouterr()
    assert json.loads(cap.out) == {"error": "terminated (SIGTERM)", "recording": str(EXAMPLE)}
    assert cap.err == "cdpr diagnose: terminated (SIGTERM)\n"


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_dry_run_signal_exit_status_last_line_and_recording(tmp_path, sig):
    """``cdpr dry-run paper-centre --record DIR`` stopped mid-run by SIGINT / SIGTERM: exit
    status 130 / 143, the last line on stderr says which, the recording is readable."""
    from bench.recording import read_recording

    code, msg = MESSAGE[sig]
    rec = tmp_path / "rec"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "dry-run", "paper-centre",
                             "--record", str(rec), "--json"], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=_default_signals)
    err = ""
    try:
        while "cycles/s" not in err:  # a progress line: the path is being run
            line = proc.stderr.readline()
            if not line:
                break
            err += line
        assert "cycles/s" in err, err
        proc.send_signal(sig)
        out, rest = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    err += rest
    assert proc.returncode == code, err
    assert err.strip().splitlines()[-1] == f"cdpr dry-run: {msg}"
    assert "Traceback" not in err
    res = json.loads(out)
    assert res["ended"] == "interrupted" and res["recording"] == str(rec)
    data = read_recording(rec)
    assert len(data.t) > 0


def _first_row_sign(monkeypatch):
    """An event set when ``cdpr commission monitor`` appends its first row to its
    recording (the monitor runs its loop, its signal handlers are in place)."""
    import threading

    from bench.mcap import recorders

    ready = threading.Event()
    real = recorders.open_writer

    def spy(*a, **kw):
        w = real(*a, **kw)
        append = w.append

        def first(*a2, **kw2):
            append(*a2, **kw2)
            ready.set()

        w.append = first
        return w

    monkeypatch.setattr(recorders, "open_writer", spy)
    return ready


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_commission_monitor_signal_keeps_its_output_and_exits_130_143(capsys, tmp_path, sig,
                                                                       monkeypatch):
    """``cdpr commission monitor`` ended by SIGINT / SIGTERM (in this process, on simulated
    drives and load cells): its JSON object and recording are kept, exit status 130 / 143,
    and the last line on stderr says which signal. The signal comes once the first row is
    recorded (a sign, not a time: generous timeout, the monitor's --duration longer)."""
    import threading

    from bench.recording import read_recording
    from tests.test_commission import Cells, Rig

    code, msg = MESSAGE[sig]
    got: list[int] = []
    old = signal.signal(sig, lambda s, f: got.append(s))  # a late signal kills no test
    rig, cells = Rig(), Cells()
    rec = tmp_path / "rec"
    ready, done = _first_row_sign(monkeypatch), threading.Event()
    sent: list[bool] = []

    def signal_when_ready() -> None:
        if ready.wait(120) and not done.is_set():
            sent.append(True)
            os.kill(os.getpid(), sig)

    sender = threading.Thread(target=signal_when_ready, daemon=True)
    try:
        capsys.readouterr()
        sender.start()
        rc = main(["commission", "monitor", "--can", rig.can, "--modbus", cells.spec,
                   "--duration", "150", "--rate", "10", "--record", str(rec), "--no-report",
                   "--json"])
    finally:
        done.set()
        ready.set()
        sender.join(10)
        signal.signal(sig, old)
        cells.close()
        rig.close()
    cap = capsys.readouterr()
    assert sent, "no first row within 120 s"
    assert rc == code, cap.err
    out = json.loads(cap.out.strip().splitlines()[-1])
    assert out["ended_by"] == ("Ctrl-C" if sig == signal.SIGINT else msg)
    assert cap.err.strip().splitlines()[-1] == f"cdpr commission monitor: {msg}"
    assert read_recording(rec).n_samples == out["rows"] > 0
